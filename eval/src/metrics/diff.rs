//! CPU vs GPU: how many pixels of two images are identical, the largest channel difference,
//! and a side-by-side PNG (CPU | GPU | difference) for looking at the rest.

use std::path::Path;
use volwarp_core::renderer::Image;

/// The identical-pixel share the GPU tracer must reach against the CPU tracer.
pub const TARGET_IDENTICAL: f64 = 0.999;

/// How two images of the same size differ.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImageDiff {
    /// Pixels compared.
    pub pixels: u64,
    /// Pixels that are bit-identical.
    pub identical: u64,
    /// Largest absolute difference of one channel over all pixels (0..=255).
    pub max_channel_diff: u8,
}

impl ImageDiff {
    /// Share of identical pixels (1 for empty images).
    pub fn identical_share(&self) -> f64 {
        if self.pixels == 0 {
            1.0
        } else {
            self.identical as f64 / self.pixels as f64
        }
    }

    /// Whether the share reaches [`TARGET_IDENTICAL`].
    pub fn meets_target(&self) -> bool {
        self.identical_share() >= TARGET_IDENTICAL
    }
}

fn channel_diff(a: u32, b: u32) -> u8 {
    let (a, b) = (a.to_le_bytes(), b.to_le_bytes());
    (0..4).map(|i| a[i].abs_diff(b[i])).max().unwrap_or(0)
}

/// Compares two images; `None` when their sizes differ.
pub fn diff(a: &Image, b: &Image) -> Option<ImageDiff> {
    if a.width != b.width || a.height != b.height || a.pixels.len() != b.pixels.len() {
        return None;
    }
    let mut d = ImageDiff { pixels: a.pixels.len() as u64, identical: 0, max_channel_diff: 0 };
    for (&p, &q) in a.pixels.iter().zip(&b.pixels) {
        if p == q {
            d.identical += 1;
        } else {
            d.max_channel_diff = d.max_channel_diff.max(channel_diff(p, q));
        }
    }
    Some(d)
}

/// The difference image: black where identical, otherwise red scaled with the largest channel
/// difference (at least 96 so single-level differences stay visible).
pub fn difference_image(a: &Image, b: &Image) -> Option<Image> {
    diff(a, b)?;
    let pixels = a
        .pixels
        .iter()
        .zip(&b.pixels)
        .map(|(&p, &q)| {
            if p == q {
                u32::from_le_bytes([0, 0, 0, 255])
            } else {
                let v = (96 + channel_diff(p, q) as u32 * 4).min(255) as u8;
                u32::from_le_bytes([v, 0, 0, 255])
            }
        })
        .collect();
    Some(Image { width: a.width, height: a.height, pixels })
}

/// Images side by side, left to right, with a 4-pixel gap (all must have the same height).
pub fn side_by_side(images: &[&Image]) -> Option<Image> {
    let h = images.first()?.height;
    if images.iter().any(|i| i.height != h) {
        return None;
    }
    let gap = 4;
    let w: u32 = images.iter().map(|i| i.width).sum::<u32>() + gap * (images.len() as u32 - 1);
    let mut out =
        Image { width: w, height: h, pixels: vec![u32::from_le_bytes([255, 255, 255, 255]); (w * h) as usize] };
    let mut x0 = 0;
    for img in images {
        for y in 0..h {
            let src = &img.pixels[(y * img.width) as usize..((y + 1) * img.width) as usize];
            let dst = (y * w + x0) as usize;
            out.pixels[dst..dst + img.width as usize].copy_from_slice(src);
        }
        x0 += img.width + gap;
    }
    Some(out)
}

/// Writes an image as an RGBA PNG.
pub fn save_png(img: &Image, path: &Path) -> Result<(), image::ImageError> {
    image::save_buffer(path, img.as_rgba_bytes(), img.width, img.height, image::ExtendedColorType::Rgba8)
}

/// Writes `CPU | GPU | difference` as one PNG; `None` if the sizes differ.
pub fn save_comparison(cpu: &Image, gpu: &Image, path: &Path) -> Option<Result<(), image::ImageError>> {
    let d = difference_image(cpu, gpu)?;
    let all = side_by_side(&[cpu, gpu, &d])?;
    Some(save_png(&all, path))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn img(w: u32, h: u32, v: u32) -> Image {
        Image { width: w, height: h, pixels: vec![v; (w * h) as usize] }
    }

    #[test]
    fn diff_counts_and_max() {
        let a = img(4, 2, 0xff10_2030);
        let mut b = a.clone();
        b.pixels[3] = 0xff10_2035;
        b.pixels[5] = 0xff00_2030;
        let d = diff(&a, &b).unwrap();
        assert_eq!(d, ImageDiff { pixels: 8, identical: 6, max_channel_diff: 16 });
        assert_eq!(d.identical_share(), 0.75);
        assert!(!d.meets_target());
        assert!(diff(&a, &img(2, 4, 0)).is_none());
    }

    #[test]
    fn side_by_side_places_images() {
        let a = img(2, 2, 1);
        let b = img(3, 2, 2);
        let s = side_by_side(&[&a, &b]).unwrap();
        assert_eq!((s.width, s.height), (9, 2));
        assert_eq!(s.get(1, 1), 1);
        assert_eq!(s.get(6, 0), 2);
        assert_eq!(s.get(8, 1), 2);
        let d = difference_image(&a, &img(2, 2, 1)).unwrap();
        assert!(d.pixels.iter().all(|&p| p == u32::from_le_bytes([0, 0, 0, 255])));
    }
}
