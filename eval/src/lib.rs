//! # volwarp-eval
//!
//! The evaluation of volwarp: how accurate each way of warping a frame is
//! against the ground truth, how fast it is, where each method breaks down, and how small the
//! representation of a sample can be. The `volwarp-eval` binary drives it; the integration tests
//! in `tests/` run the same code on small bundled volumes.
//!
//! | module | concept |
//! |---|---|
//! | [`metrics`] | PSNR, SSIM, NVIDIA's LDR-ꟻLIP, and difference images |
//! | [`image_io`] | image strips and downscaling (PNG files are core's `Image::save_png`) |
//! | [`roster`] | every renderer the evaluation compares, by its CSV name |
//! | [`camera_paths`] | the orbit and dolly paths away from the frame's camera |
//! | [`quality`] | the accuracy/speed sweep behind `quality.csv` |
//! | [`charts`] | the charts (plotters, embedded DejaVu font) |
//! | [`table1`] | the paper's Table 1: samples, compaction, LBVH, FPS per view |
//! | [`representation_size`] | error against position bits, radius bits and samples kept |
//! | [`radius_model`] | accuracy against tracing speed for the server's sphere radius models |
//! | [`failure_modes`] | the cases where the methods break down |
//! | [`session`] | the session simulator: latency hiding over time as a user sees it |
//! | [`csv`] | small CSV writer |
//! | [`demo_strip`] | the README demo's truth / stale / volwarp strip from a recorded session |
//! | [`report`] | the `volwarp-eval` commands: files, charts, markdown |
#![deny(missing_docs)]
#![forbid(unsafe_code)]

pub mod camera_paths;
pub mod charts;
pub mod csv;
pub mod demo_strip;
pub mod example_args;
pub mod failure_modes;
pub mod image_io;
pub mod metrics;
pub mod quality;
pub mod radius_model;
pub mod report;
pub mod representation_size;
pub mod roster;
pub mod session;
pub mod table1;
pub mod uncertainty_radius;

pub use metrics::{is_defined, Metrics};
pub use volwarp_core::stats::median;

/// The error type of the evaluation commands.
pub type ErrorBox = Box<dyn std::error::Error + Send + Sync>;
