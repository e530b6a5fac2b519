//! Image metrics against the truth: PSNR, SSIM and LDR-ꟻLIP, checked against their reference
//! implementations on the committed fixtures (`eval/fixtures/`), and difference images.
//!
//! | module | metric |
//! |---|---|
//! | [`psnr`] | peak signal-to-noise ratio |
//! | [`ssim`] | structural similarity (Wang et al. 2004) on luminance |
//! | [`flip`] | NVIDIA's LDR-ꟻLIP (Andersson et al. 2020), as the reference implementation |
//! | [`diff`] | difference images and `reference | test | difference` strips |

pub mod diff;
pub mod flip;
pub mod psnr;
pub mod ssim;

use volwarp_core::Image;

/// PSNR, SSIM and mean FLIP of one image against the truth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Metrics {
    /// PSNR in dB (capped at [`psnr::PSNR_IDENTICAL`]).
    pub psnr: f64,
    /// Mean SSIM on luminance.
    pub ssim: f64,
    /// Mean LDR-ꟻLIP error (lower is better).
    pub flip: f64,
}

impl Metrics {
    /// All three metrics of `test` against `truth`; `None` if the sizes differ or are empty.
    pub fn of(truth: &Image, test: &Image) -> Option<Metrics> {
        Some(Metrics { psnr: psnr::psnr(truth, test)?, ssim: ssim::ssim(truth, test)?, flip: flip::flip(truth, test)? })
    }
}

/// Whether an image is *defined*: the right size for `(w, h)` and every pixel opaque.
pub fn is_defined(img: &Image, w: u32, h: u32) -> bool {
    img.width == w
        && img.height == h
        && img.pixels.len() == w as usize * h as usize
        && img.pixels.iter().all(|p| p.to_le_bytes()[3] == 255)
}
