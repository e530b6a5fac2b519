//! PNG files of [`Image`]s (feature `png`): the one place every crate saves and loads them,
//! and resizes them ([`Image::resize_into`]).
//!
//! `no_std` builds leave this module out; it wraps the `image` crate (PNG codec only).

use crate::renderer::Image;
use crate::sample::pack_color;
use std::path::Path;
use std::string::{String, ToString};
use std::vec::Vec;

/// Why an image could not be read or written (the text names the file).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PngError(pub String);

impl core::fmt::Display for PngError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for PngError {}

impl Image {
    /// Writes the image as an RGBA PNG; an inconsistent buffer is an error, not a panic.
    pub fn save_png(&self, path: &Path) -> Result<(), PngError> {
        if self.pixels.len() != self.width as usize * self.height as usize {
            return Err(PngError(std::format!("{}: inconsistent image buffer", path.display())));
        }
        image::save_buffer(path, self.as_rgba_bytes(), self.width, self.height, image::ExtendedColorType::Rgba8)
            .map_err(|e| PngError(std::format!("{}: {e}", path.display())))
    }

    /// The image resized bilinearly to `width × height` into `out` (`image`'s triangle filter,
    /// which is bilinear interpolation when enlarging; opaque); a copy where the size is
    /// already right; an inconsistent or empty image gives the background. What a downscaling
    /// system shows, and a coarse frame shown unwarped.
    pub fn resize_into(&self, width: u32, height: u32, out: &mut Image) {
        if (self.width, self.height) == (width, height) {
            out.clone_from(self);
            return;
        }
        if self.pixels.len() != self.width as usize * self.height as usize || self.pixels.is_empty() {
            *out = Image::new(width, height);
            return;
        }
        let rgb = image::RgbImage::from_fn(self.width, self.height, |x, y| {
            let b = self.pixels[(y * self.width + x) as usize].to_le_bytes();
            image::Rgb([b[0], b[1], b[2]])
        });
        let big = image::imageops::resize(&rgb, width, height, image::imageops::FilterType::Triangle);
        out.width = width;
        out.height = height;
        out.pixels.clear();
        out.pixels.extend(big.pixels().map(|p| pack_color(p[0], p[1], p[2], 255)));
    }

    /// Reads a PNG (any color type, converted to RGBA8) of at most `max_pixels` pixels.
    pub fn load_png(path: &Path, max_pixels: u64) -> Result<Image, PngError> {
        let err = |e: String| PngError(std::format!("{}: {e}", path.display()));
        let reader = image::ImageReader::open(path).map_err(|e| err(e.to_string()))?;
        let reader = reader.with_guessed_format().map_err(|e| err(e.to_string()))?;
        let (w, h) = reader.into_dimensions().map_err(|e| err(e.to_string()))?;
        if w as u64 * h as u64 > max_pixels {
            return Err(err(std::format!("{w}x{h} is larger than {max_pixels} pixels")));
        }
        let img = image::open(path).map_err(|e| err(e.to_string()))?.to_rgba8();
        let pixels: Vec<u32> = img.pixels().map(|p| pack_color(p[0], p[1], p[2], p[3])).collect();
        Ok(Image { width: img.width(), height: img.height(), pixels })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn upscaling_is_bilinear() {
        // A 2×1 image black | white enlarged to 8×1: a ramp, monotone, ends near the sources.
        let img = Image { width: 2, height: 1, pixels: std::vec![0xFF00_0000, 0xFFFF_FFFF] };
        let mut out = Image::new(0, 0);
        img.resize_into(8, 1, &mut out);
        let r: Vec<u8> = out.pixels.iter().map(|p| p.to_le_bytes()[0]).collect();
        assert!(r.windows(2).all(|w| w[0] <= w[1]), "{r:?}");
        assert!(r[0] < 40 && r[7] > 215 && r[3] > 40 && r[3] < 215, "{r:?}");
        img.resize_into(2, 1, &mut out);
        assert_eq!(out.pixels, img.pixels, "same size: a copy");
        // A broken buffer: the background, no panic.
        Image { width: 5, height: 5, pixels: std::vec![0; 3] }.resize_into(4, 2, &mut out);
        assert_eq!(out, Image::new(4, 2));
    }

    #[test]
    fn round_trip_limit_and_bad_buffer() {
        let a = Image { width: 3, height: 2, pixels: (0..6).map(|i| pack_color(i as u8 * 40, 1, 2, 255)).collect() };
        let dir = std::env::temp_dir().join(std::format!("volwarp-png-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("a.png");
        a.save_png(&p).unwrap();
        assert_eq!(Image::load_png(&p, 100).unwrap(), a);
        assert!(Image::load_png(&p, 5).is_err(), "size limit");
        let bad = Image { width: 4, height: 4, pixels: std::vec![0; 3] };
        assert!(bad.save_png(&dir.join("b.png")).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }
}
