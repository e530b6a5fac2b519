//! Peak signal-to-noise ratio of an 8-bit RGB image against a reference.
//!
//! `PSNR = 10 · log10(255² / MSE)`, the mean squared error taken over the R, G and B channels of
//! every pixel (alpha ignored: every renderer's output is opaque). This is what
//! `skimage.metrics.peak_signal_noise_ratio(ref, test, data_range=255)` computes on the RGB
//! arrays. Identical images (MSE 0) get [`PSNR_IDENTICAL`] instead of infinity, so that CSV
//! files and charts only ever hold finite numbers.

use volwarp_core::Image;

/// The PSNR reported for identical images, in dB.
pub const PSNR_IDENTICAL: f64 = 100.0;

/// Mean squared error over the RGB channels, in 8-bit units². `None` if the sizes differ or
/// the images are empty.
pub fn mse(reference: &Image, test: &Image) -> Option<f64> {
    if !same_shape(reference, test) || reference.pixels.is_empty() {
        return None;
    }
    let mut sum = 0u64;
    for (&a, &b) in reference.pixels.iter().zip(&test.pixels) {
        let (a, b) = (a.to_le_bytes(), b.to_le_bytes());
        for c in 0..3 {
            let d = a[c] as i64 - b[c] as i64;
            sum += (d * d) as u64;
        }
    }
    Some(sum as f64 / (reference.pixels.len() * 3) as f64)
}

/// PSNR in dB (see the module docs); `None` if the sizes differ or the images are empty.
pub fn psnr(reference: &Image, test: &Image) -> Option<f64> {
    let m = mse(reference, test)?;
    if m <= 0.0 {
        return Some(PSNR_IDENTICAL);
    }
    Some((10.0 * (255.0f64 * 255.0 / m).log10()).min(PSNR_IDENTICAL))
}

/// Whether two images have the same size and a consistent pixel buffer.
pub fn same_shape(a: &Image, b: &Image) -> bool {
    a.width == b.width
        && a.height == b.height
        && a.pixels.len() == a.width as usize * a.height as usize
        && b.pixels.len() == a.pixels.len()
}

#[cfg(test)]
mod tests {
    use super::*;
    use volwarp_core::sample::pack_color;

    fn solid(w: u32, h: u32, c: u32) -> Image {
        Image { width: w, height: h, pixels: vec![c; (w * h) as usize] }
    }

    #[test]
    fn closed_form_values() {
        let a = solid(4, 4, pack_color(100, 100, 100, 255));
        assert_eq!(psnr(&a, &a), Some(PSNR_IDENTICAL));
        // Every channel off by 10: MSE 100, PSNR = 10 log10(65025 / 100) = 28.1308 dB.
        let b = solid(4, 4, pack_color(110, 90, 110, 255));
        assert_eq!(mse(&a, &b), Some(100.0));
        assert!((psnr(&a, &b).unwrap() - 28.130803608679106).abs() < 1e-9);
        // Alpha does not count.
        let c = solid(4, 4, pack_color(100, 100, 100, 0));
        assert_eq!(mse(&a, &c), Some(0.0));
    }

    #[test]
    fn mismatched_sizes_are_rejected() {
        let a = solid(4, 4, 0);
        assert_eq!(psnr(&a, &solid(4, 5, 0)), None);
        assert_eq!(psnr(&solid(0, 0, 0), &solid(0, 0, 0)), None);
    }
}
