//! # volwarp-cpu-tracer
//!
//! Every CPU way of drawing a volwarp [`Scene`] for a camera, behind the one
//! [`Renderer`] interface of `volwarp-core`, and the parallel LBVH build a CPU-only client
//! uses to turn a received frame into a scene.
//!
//! | module | concept | renderer name |
//! |---|---|---|
//! | [`packet_tracer`] | first-hit sphere tracing with 8-ray SIMD packets (`wide::f32x8`) | `spheres-cpu` |
//! | [`scalar_tracer`] | core's scalar reference traversal per pixel | `spheres-scalar` |
//! | [`point_splat`] | ZAL12 2.5D points: fixed N×N squares with a depth test | `points1`, `points2`, `points3` |
//! | [`sphere_splat`] | exact object-order sphere splatting (no BVH) | `splat` |
//! | [`stale_image`] | the frame as it was rendered, not warped | `stale` |
//! | [`parallel_build`] | rayon LBVH build, byte-identical to `Scene::build` | — |
//! | [`parallel_sort`] | the parallel stable radix sort it uses | — |
//! | [`synthetic`] | synthetic frames and clouds for tests and benchmarks | — |
//! | [`threads`] | a renderer's own thread count | — |
//!
//! All sphere renderers give the **same** image: they mirror core's ray generation
//! ([`volwarp_core::RayBasis::dir`]), sphere intersection and tie rule operation by operation.
//! A hit pixel shows `over_background(color, BACKGROUND)`.
//!
//! Every renderer draws the background (and logs one warning) for a camera that does not
//! validate or a scene whose buffers are inconsistent: no panic and no NaN from bad input.
#![deny(missing_docs)]
// `!(a <= b)` is how NaN is rejected on purpose here, as in core.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod packet_tracer;
pub mod parallel_build;
pub mod parallel_sort;
pub mod point_splat;
pub mod scalar_tracer;
pub mod sphere_splat;
pub mod stale_image;
pub mod synthetic;
pub mod threads;

mod depth_buffer;
mod lanes;

pub use packet_tracer::PacketTracer;
pub use parallel_build::{build_scene, BuildTimes, Method, ParallelBuilder};
pub use point_splat::PointSplat;
pub use scalar_tracer::ScalarTracer;
pub use sphere_splat::SphereSplat;
pub use stale_image::StaleImage;
pub use threads::Threads;

use std::sync::atomic::{AtomicBool, Ordering};
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::sample::over_background;
use volwarp_core::{Camera, Scene, BACKGROUND};

/// The largest viewport width or height any renderer here draws (bounds what a renderer
/// allocates: at most 8192² pixels of image and depth buffer).
pub const MAX_VIEWPORT: u32 = 8192;

/// The pixel value for "no hit" in sample-id buffers.
pub const NO_HIT: u32 = u32::MAX;

/// The names [`renderer_by_name`] knows, in the order the client cycles through them.
pub const RENDERER_NAMES: [&str; 7] =
    ["spheres-cpu", "spheres-scalar", "splat", "points1", "points2", "points3", "stale"];

/// A renderer by its [`Renderer::name`], drawing with `threads` threads (0: all cores).
pub fn renderer_by_name(name: &str, threads: usize) -> Option<Box<dyn Renderer + Send>> {
    Some(match name {
        "spheres-cpu" => Box::new(PacketTracer::new(threads)),
        "spheres-scalar" => Box::new(ScalarTracer::new(threads)),
        "splat" => Box::new(SphereSplat::new(threads)),
        "points1" => Box::new(PointSplat::new(1, threads)),
        "points2" => Box::new(PointSplat::new(2, threads)),
        "points3" => Box::new(PointSplat::new(3, threads)),
        "stale" => Box::new(StaleImage::new(threads)),
        _ => return None,
    })
}

/// Whether the scene's buffers are consistent (what every renderer here relies on): one color
/// per sample and `n − 1` nodes.
pub fn scene_is_consistent(scene: &Scene) -> bool {
    let n = scene.samples.len();
    scene.colors.len() == n && scene.nodes.len() == n.saturating_sub(1) && n < (1usize << 31)
}

static WARNED_CAMERA: AtomicBool = AtomicBool::new(false);
static WARNED_SCENE: AtomicBool = AtomicBool::new(false);

fn warn_once(flag: &AtomicBool, msg: &str) {
    if !flag.swap(true, Ordering::Relaxed) {
        log::warn!("{msg} (drawing the background; warned once)");
    }
}

/// The common body of the tracers' `trace_ids`: sizes `ids` to the camera's viewport, fills it
/// with [`NO_HIT`] and, if camera and scene are usable, lets `draw` write the first-hit ids.
pub(crate) fn trace_ids_with(
    scene: &Scene,
    camera: &Camera,
    ids: &mut Vec<u32>,
    draw: impl FnOnce(&mut [u32]),
) -> bool {
    let mut img = Image { width: 0, height: 0, pixels: std::mem::take(ids) };
    let ok = begin_frame(scene, camera, &mut img);
    *ids = img.pixels;
    ids.fill(NO_HIT);
    if ok {
        draw(ids);
    }
    ok
}

/// Prepares `out` for drawing `scene` from `camera`: resizes and clears it. Returns `false`
/// (after drawing the background, or an empty image for an unusable viewport) if the camera
/// does not validate or the scene is inconsistent.
pub(crate) fn begin_frame(scene: &Scene, camera: &Camera, out: &mut Image) -> bool {
    if let Err(e) = camera.validate(MAX_VIEWPORT) {
        warn_once(&WARNED_CAMERA, &format!("unusable camera: {e}"));
        out.reset_for_unusable(camera, MAX_VIEWPORT);
        return false;
    }
    out.reset_for(camera);
    if !scene_is_consistent(scene) {
        warn_once(&WARNED_SCENE, "inconsistent scene buffers");
        return false;
    }
    true
}

/// The color a renderer shows for a sample-id pixel.
#[inline(always)]
pub(crate) fn shade(colors: &[u32], prim: u32) -> u32 {
    match colors.get(prim as usize) {
        Some(&c) => over_background(c, BACKGROUND),
        None => BACKGROUND,
    }
}
