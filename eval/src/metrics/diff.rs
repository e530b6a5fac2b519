//! Looking at how two images differ: a difference image and the `reference | test | difference`
//! strip `volwarp-compare` writes. The counts themselves are core's [`Image::diff`].

use crate::image_io::strip;
use std::path::Path;
use volwarp_core::image_diff::channel_diff;
use volwarp_core::png::PngError;
use volwarp_core::Image;

/// The difference image: black where identical, otherwise red scaled with the largest channel
/// difference (at least 96 so single-level differences stay visible); `None` if sizes differ.
pub fn difference_image(a: &Image, b: &Image) -> Option<Image> {
    a.diff(b)?;
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

/// Writes `reference | test | difference` as one PNG (4-pixel white gaps); `None` if the sizes
/// differ.
pub fn save_comparison(reference: &Image, test: &Image, path: &Path) -> Option<Result<(), PngError>> {
    let d = difference_image(reference, test)?;
    let all = strip(&[vec![reference, test, &d]], 4, u32::from_le_bytes([255, 255, 255, 255]));
    Some(all.save_png(path))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn img(w: u32, h: u32, v: u32) -> Image {
        Image { width: w, height: h, pixels: vec![v; (w * h) as usize] }
    }

    #[test]
    fn difference_marks_changed_pixels() {
        let a = img(2, 2, 1);
        let mut b = a.clone();
        b.pixels[3] = 2;
        let d = difference_image(&a, &b).unwrap();
        assert!(d.pixels[..3].iter().all(|&p| p == u32::from_le_bytes([0, 0, 0, 255])));
        assert_eq!(d.pixels[3].to_le_bytes()[0], 100);
        assert!(difference_image(&a, &img(1, 2, 1)).is_none());
    }
}
