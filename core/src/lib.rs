//! # volwarp-core
//!
//! The vocabulary shared by every part of volwarp, after Zellmann, *Augmenting Image
//! Warping-Based Remote Volume Rendering with Ray Tracing* (2020):
//!
//! | module | concept of the paper |
//! |---|---|
//! | [`camera`] | the pinhole camera and its primary rays (one convention for marcher, tracers and shader) |
//! | [`sample`] | the object-space sample: quantized position + radius in 64 bits, RGBA8 color in 32 |
//! | [`method`] | the method (renderer and levers, its default) and the request policy: when a client asks for which camera |
//! | `show` (feature `alloc`) | the frame choice: which kept frame a client shows for the camera of now, exact, warped or unwarped |
//! | [`prediction`] | the camera expected when a requested frame arrives (orbit-aware extrapolation) |
//! | [`guard`] | guard bands: a wider requested view at the same pixel density |
//! | [`warp_radius`] | sphere radii sized by how far the view moved from the frame's camera |
//! | [`heuristics`] | the ZAL12 representative-depth heuristics, as state machines |
//! | [`compact_frame`] | the compact frame encoding: coverage mask, predicted depths, radii and colors, zstd (≈3 B/sample) |
//! | [`segments`] | layered samples: a ray cut into depth segments, their wire checks and compact form |
//! | [`compaction`] | stable removal of empty (radius 0) samples |
//! | [`morton`] | Morton codes of quantized positions and their radix sort |
//! | [`lbvh`] | Karras-style LBVH over the sorted codes, built into caller buffers |
//! | [`sphere`] | first-hit ray–sphere and ray–box intersection |
//! | [`stats`] | the median of measured figures |
//! | [`traversal`] | the scalar reference traversal: the oracle for every fast tracer |
//! | [`wire`] | the framed, versioned wire codec over `embedded-io` |
//! | `scene` (feature `alloc`) | an owned, traceable scene built from a received frame |
//! | `renderer` (feature `alloc`) | the one interface every way of drawing a scene implements |
//! | [`renderer_kind`] | the one registry of renderers: names, roles, window keys, capabilities |
//! | `image_diff` (feature `alloc`) | identical-pixel share and largest channel difference of two images |
//! | [`record`] | the record file of a received stream, for replay |
//! | `png` (feature `png`) | saving and loading [`Image`]s as PNG files |
//!
//! The crate is `#![no_std]` and needs no allocator; the `alloc` feature adds owned
//! conveniences and `std` only adds trait impls.
#![no_std]
#![deny(missing_docs)]
// `!(x > y)` is deliberate throughout: unlike `x <= y` it is also true when x is NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

#[cfg(feature = "alloc")]
extern crate alloc;
#[cfg(feature = "std")]
extern crate std;

#[cfg(feature = "zstd-c")]
pub mod byte_runs;
pub mod camera;
pub mod compact_frame;
pub mod compaction;
pub mod guard;
pub mod heuristics;
#[cfg(feature = "alloc")]
pub mod image_diff;
pub mod lbvh;
pub mod method;
pub mod morton;
#[cfg(feature = "png")]
pub mod png;
pub mod prediction;
pub mod record;
#[cfg(feature = "alloc")]
pub mod renderer;
pub mod renderer_kind;
pub mod sample;
#[cfg(feature = "alloc")]
pub mod scene;
pub mod segments;
#[cfg(feature = "alloc")]
pub mod show;
pub mod sphere;
pub mod stats;
pub mod traversal;
pub mod warp_radius;
pub mod wire;

#[cfg(feature = "alloc")]
mod compact_fast;
mod math;

pub use camera::{Camera, CameraError, Ray, RayBasis};
pub use heuristics::{DepthPicker, FirstPass, FirstPassAccumulator, Heuristic};
#[cfg(feature = "alloc")]
pub use image_diff::ImageDiff;
pub use lbvh::{Lbvh, Node};
#[cfg(feature = "alloc")]
pub use renderer::{Image, Renderer, BACKGROUND};
pub use renderer_kind::{RendererKind, Role, REGISTRY};
pub use sample::{Bounds, Dequantizer, Quantizer};
#[cfg(feature = "alloc")]
pub use scene::{Scene, SceneError};
pub use traversal::Hit;

pub use glam::Vec3;

/// The tests' pseudo-random numbers in `[0, 1)`: xorshift64 from `seed` (nonzero), the top 24
/// bits of each state as the fraction.
#[cfg(test)]
pub(crate) fn test_unit_rng(seed: u64) -> impl FnMut() -> f32 {
    let mut state = seed;
    move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// Whether this build of the crate has the `std` feature (tests check which build they run on:
/// the no_std + alloc build takes other code paths, ruzstd and libm among them).
pub const BUILT_WITH_STD: bool = cfg!(feature = "std");
