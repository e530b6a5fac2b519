//! # volwarp-tests
//!
//! The evaluation of volwarp (GitHub issue 7): how accurate each way of warping a frame is
//! against the ground truth, how fast it is, where each method breaks down, and how small the
//! representation of a sample can be. The `volwarp-eval` binary drives it; the integration tests
//! in `tests/` run the same code on small bundled volumes.
//!
//! | module | concept |
//! |---|---|
//! | [`psnr`] | peak signal-to-noise ratio |
//! | [`ssim`] | structural similarity (Wang et al. 2004) on luminance |
//! | [`flip`] | NVIDIA's LDR-ꟻLIP (Andersson et al. 2020), as the reference implementation |
//! | [`image_io`] | PNG files and image strips |
//! | [`roster`] | every renderer the evaluation compares, by its CSV name |
//! | [`camera_paths`] | the orbit and dolly paths away from the frame's camera |
//! | [`quality`] | the accuracy/speed sweep behind `quality.csv` |
//! | [`charts`] | the charts (plotters, embedded DejaVu font) |
//! | [`table1`] | the paper's Table 1: samples, compaction, LBVH, FPS per view |
//! | [`representation_size`] | error against position bits, radius bits and samples kept |
//! | [`radius_model`] | accuracy against tracing speed for the server's sphere radius models |
//! | [`failure_modes`] | the cases where the methods break down |
//! | [`csv`] | small CSV writer |
//! | [`report`] | the `volwarp-eval` commands: files, charts, markdown |
#![deny(missing_docs)]

pub mod camera_paths;
pub mod charts;
pub mod csv;
pub mod failure_modes;
pub mod flip;
pub mod image_io;
pub mod psnr;
pub mod quality;
pub mod radius_model;
pub mod report;
pub mod representation_size;
pub mod roster;
pub mod ssim;
pub mod table1;

use volwarp_core::Image;

/// The error type of the evaluation commands.
pub type ErrorBox = Box<dyn std::error::Error + Send + Sync>;

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

/// The median of some values (NaN-free input assumed; `None` if empty).
pub fn median(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(|a, b| a.total_cmp(b));
    let n = values.len();
    Some(if n % 2 == 1 { values[n / 2] } else { 0.5 * (values[n / 2 - 1] + values[n / 2]) })
}
