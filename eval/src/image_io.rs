//! Image strips (side-by-side tiles with gaps) and downscaling; PNG files are core's
//! [`Image::save_png`] and [`Image::load_png`].

use volwarp_core::Image;

/// Tiles `rows` of equally sized images into one image with `gap` pixels of `gap_color`
/// between tiles. Missing or differently sized tiles are left as gap color.
pub fn strip(rows: &[Vec<&Image>], gap: u32, gap_color: u32) -> Image {
    let tw = rows.iter().flatten().map(|i| i.width).max().unwrap_or(0);
    let th = rows.iter().flatten().map(|i| i.height).max().unwrap_or(0);
    let cols = rows.iter().map(|r| r.len()).max().unwrap_or(0) as u32;
    let w = cols * tw + cols.saturating_sub(1) * gap;
    let h = rows.len() as u32 * th + (rows.len() as u32).saturating_sub(1) * gap;
    let mut out = Image { width: w, height: h, pixels: vec![gap_color; w as usize * h as usize] };
    for (r, row) in rows.iter().enumerate() {
        for (c, tile) in row.iter().enumerate() {
            if tile.width != tw || tile.height != th || tile.pixels.len() != (tw * th) as usize {
                continue;
            }
            let (ox, oy) = (c as u32 * (tw + gap), r as u32 * (th + gap));
            for y in 0..th {
                let dst = ((oy + y) * w + ox) as usize;
                out.pixels[dst..dst + tw as usize]
                    .copy_from_slice(&tile.pixels[(y * tw) as usize..((y + 1) * tw) as usize]);
            }
        }
    }
    out
}

/// Nearest-neighbour downscale by an integer factor (at least 1).
pub fn downscale(img: &Image, factor: u32) -> Image {
    let f = factor.max(1);
    let (w, h) = ((img.width / f).max(1), (img.height / f).max(1));
    let mut pixels = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let (sx, sy) = ((x * f + f / 2).min(img.width - 1), (y * f + f / 2).min(img.height - 1));
            pixels.push(img.pixels[(sy * img.width + sx) as usize]);
        }
    }
    Image { width: w, height: h, pixels }
}

#[cfg(test)]
mod tests {
    use super::*;
    use volwarp_core::sample::pack_color;

    #[test]
    fn strip_layout() {
        let a = Image { width: 3, height: 2, pixels: (0..6).map(|i| pack_color(i as u8 * 40, 1, 2, 255)).collect() };
        let s = strip(&[vec![&a, &a], vec![&a]], 1, 0);
        assert_eq!((s.width, s.height), (7, 5));
        assert_eq!(s.get(4, 0), a.get(0, 0));
        assert_eq!(s.get(4, 3), 0, "missing tile stays gap color");
    }
}
