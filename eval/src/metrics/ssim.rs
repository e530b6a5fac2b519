//! Structural similarity (Wang, Bovik, Sheikh, Simoncelli 2004) on luminance.
//!
//! The standard parameters of the paper: each image is reduced to its luminance
//! `Y = 0.299 R + 0.587 G + 0.114 B` (Rec. 601, as MATLAB's `rgb2gray`, in 8-bit units, not
//! rounded); local statistics use an 11 × 11 Gaussian window with σ = 1.5 (normalized to sum
//! 1); `C1 = (0.01 · 255)²`, `C2 = (0.03 · 255)²`; the population (not sample) covariance. The
//! SSIM map is evaluated only where the window lies entirely inside the image (MATLAB's
//! `'valid'`), and the result is its mean. This equals
//! `skimage.metrics.structural_similarity(ref_y, test_y, data_range=255, gaussian_weights=True,
//! sigma=1.5, use_sample_covariance=False)` (which crops the same 5-pixel border), checked
//! against it by the fixtures in `eval/fixtures/`.
//!
//! Images smaller than the window (under 11 pixels on a side) use one window over the whole
//! image with uniform weights.

use super::psnr::same_shape;
use rayon::prelude::*;
use volwarp_core::Image;

/// Window side.
pub const WINDOW: usize = 11;
/// Gaussian σ of the window, in pixels.
pub const SIGMA: f64 = 1.5;
const C1: f64 = (0.01 * 255.0) * (0.01 * 255.0);
const C2: f64 = (0.03 * 255.0) * (0.03 * 255.0);

/// Rec. 601 luminance of a packed RGBA8 pixel, in 0..=255.
#[inline]
pub fn luminance(p: u32) -> f64 {
    let [r, g, b, _] = p.to_le_bytes();
    0.299 * r as f64 + 0.587 * g as f64 + 0.114 * b as f64
}

fn gaussian_taps() -> [f64; WINDOW] {
    let mut k = [0.0; WINDOW];
    let r = (WINDOW / 2) as f64;
    for (i, v) in k.iter_mut().enumerate() {
        let x = i as f64 - r;
        *v = (-x * x / (2.0 * SIGMA * SIGMA)).exp();
    }
    let s: f64 = k.iter().sum();
    k.map(|v| v / s)
}

fn ssim_of(mx: f64, my: f64, vx: f64, vy: f64, cxy: f64) -> f64 {
    ((2.0 * mx * my + C1) * (2.0 * cxy + C2)) / ((mx * mx + my * my + C1) * (vx + vy + C2))
}

/// Mean SSIM of `test` against `reference` (1 for identical images); `None` if the sizes
/// differ or the images are empty.
pub fn ssim(reference: &Image, test: &Image) -> Option<f64> {
    if !same_shape(reference, test) || reference.pixels.is_empty() {
        return None;
    }
    let (w, h) = (reference.width as usize, reference.height as usize);
    let x: Vec<f64> = reference.pixels.iter().map(|&p| luminance(p)).collect();
    let y: Vec<f64> = test.pixels.iter().map(|&p| luminance(p)).collect();
    if w < WINDOW || h < WINDOW {
        let n = x.len() as f64;
        let mx = x.iter().sum::<f64>() / n;
        let my = y.iter().sum::<f64>() / n;
        let vx = x.iter().map(|v| (v - mx) * (v - mx)).sum::<f64>() / n;
        let vy = y.iter().map(|v| (v - my) * (v - my)).sum::<f64>() / n;
        let cxy = x.iter().zip(&y).map(|(a, b)| (a - mx) * (b - my)).sum::<f64>() / n;
        return Some(ssim_of(mx, my, vx, vy, cxy));
    }
    let k = gaussian_taps();
    // Horizontal pass over the five moment images, valid columns only.
    let ow = w - WINDOW + 1;
    let oh = h - WINDOW + 1;
    let mut horiz = vec![[0.0f64; 5]; ow * h];
    horiz.par_chunks_mut(ow).enumerate().for_each(|(row, out)| {
        let (xr, yr) = (&x[row * w..(row + 1) * w], &y[row * w..(row + 1) * w]);
        for (c, o) in out.iter_mut().enumerate() {
            let mut m = [0.0; 5];
            for (t, &kt) in k.iter().enumerate() {
                let (a, b) = (xr[c + t], yr[c + t]);
                m[0] += kt * a;
                m[1] += kt * b;
                m[2] += kt * a * a;
                m[3] += kt * b * b;
                m[4] += kt * a * b;
            }
            *o = m;
        }
    });
    let sum: f64 = (0..oh)
        .into_par_iter()
        .map(|row| {
            let mut acc = 0.0;
            for c in 0..ow {
                let mut m = [0.0; 5];
                for (t, &kt) in k.iter().enumerate() {
                    let v = &horiz[(row + t) * ow + c];
                    for j in 0..5 {
                        m[j] += kt * v[j];
                    }
                }
                let (mx, my) = (m[0], m[1]);
                acc += ssim_of(mx, my, m[2] - mx * mx, m[3] - my * my, m[4] - mx * my);
            }
            acc
        })
        .sum();
    Some(sum / (ow * oh) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use volwarp_core::sample::pack_color;

    fn img(w: u32, h: u32, f: impl Fn(u32, u32) -> u8) -> Image {
        let mut pixels = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let v = f(x, y);
                pixels.push(pack_color(v, v, v, 255));
            }
        }
        Image { width: w, height: h, pixels }
    }

    #[test]
    fn identical_is_one_and_constant_shift_follows_the_luminance_term() {
        let a = img(32, 24, |x, y| ((x * 7 + y * 3) % 200) as u8);
        assert!((ssim(&a, &a).unwrap() - 1.0).abs() < 1e-12);
        // Two constant images: SSIM is the luminance term only, (2·μx·μy + C1)/(μx² + μy² + C1).
        let (p, q) = (img(16, 16, |_, _| 100), img(16, 16, |_, _| 150));
        let expect = (2.0 * 100.0 * 150.0 + C1) / (100.0f64 * 100.0 + 150.0 * 150.0 + C1);
        assert!((ssim(&p, &q).unwrap() - expect).abs() < 1e-9);
        // Inverted structure gives a negative SSIM.
        let inv = img(32, 24, |x, y| 200 - ((x * 7 + y * 3) % 200) as u8);
        assert!(ssim(&a, &inv).unwrap() < 0.0);
    }

    #[test]
    fn small_images_use_one_window() {
        let a = img(5, 5, |x, _| (x * 40) as u8);
        assert!((ssim(&a, &a).unwrap() - 1.0).abs() < 1e-12);
        assert!(ssim(&a, &img(5, 5, |_, _| 0)).unwrap() < 0.5);
    }
}
