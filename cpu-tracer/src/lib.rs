//! # volwarp-cpu-tracer
//!
//! Every CPU way of drawing a volwarp [`Scene`](volwarp_core::Scene) for a camera, behind the one
//! [`Renderer`] interface of `volwarp-core`, and the parallel LBVH build a CPU-only client
//! uses to turn a received frame into a scene.
//!
//! | module | concept | renderer ([`RendererKind`]) |
//! |---|---|---|
//! | [`route`] | the default: tiled splatting or packet tracing, chosen per frame by a measured cost model | `spheres` |
//! | [`tile_splat`] | exact object-order sphere splatting in cache-sized screen tiles (no BVH) | `splat-tiles` |
//! | `direct_splat` (feature `direct-splat`) | the same exact splatting in the samples' own order, no binning: a superseded experiment (measured slower; not in the registry), built for its tests only | — |
//! | [`packet_tracer`] | first-hit sphere tracing with 8-ray SIMD packets (`wide::f32x8`) | `spheres-cpu` |
//! | [`scalar_tracer`] | core's scalar reference traversal per pixel | `spheres-scalar` |
//! | [`point_splat`] | ZAL12 2.5D points: fixed N×N squares with a depth test | `points1`, `points2`, `points3` |
//! | [`sphere_splat`] | exact object-order sphere splatting (no BVH) | `splat` |
//! | [`layer_splat`] | layered samples: segments owned per output ray, composited front to back | `splat-layers` |
//! | [`layer_trace`] | the same layered compositing by multi-hit LBVH traversal (the reference tracer) | `spheres-layers` |
//! | [`stale_image`] | the frame as it was rendered, not warped | `stale` |
//! | [`build`] (also `parallel_build`) | rayon LBVH build, byte-identical to `Scene::build` | — |
//! | [`build::sort`] (also `parallel_sort`) | the parallel stable radix sort it uses | — |
//! | [`hole_fill`] | sphere renderers whose empty pixels are filled (older frames, the stale frame by direction, pull-push) | `spheres-fill`, `splat-fill` |
//! | [`synthetic`] | synthetic frames and clouds for tests and benchmarks | — |
//! | [`threads`] | a renderer's own thread count | — |
//! | `key_list` | the layered renderers' per-pixel lists of nearest keys: insert, sort, composite (AVX2 paths beside the scalar reference) | — |
//! | `frame_setup` | what every renderer does first: validate camera and scene, size and clear the output | — |
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

pub mod build;
#[cfg(feature = "direct-splat")]
pub mod direct_splat;
pub mod hole_fill;
pub mod layer_splat;
pub mod layer_trace;
pub mod layered;
pub mod packet_tracer;
pub mod point_splat;
pub mod route;
pub mod scalar_tracer;
pub mod sphere_splat;
pub mod stale_image;
pub mod synthetic;
pub mod threads;
pub mod tile_splat;

mod depth_buffer;
mod frame_setup;
mod key_list;
mod lanes;

pub(crate) use frame_setup::{begin_frame, begin_frame_overwritten, begin_frame_unbuilt_ok, shade, trace_ids_with};

/// The parallel LBVH build under its earlier path.
pub use build as parallel_build;
/// The parallel radix sorts under their earlier path.
pub use build::sort as parallel_sort;

pub use build::{build_scene, BuildTimes, Method, ParallelBuilder};

#[cfg(feature = "direct-splat")]
pub use direct_splat::DirectSplat;
pub use hole_fill::{FillOptions, HoleFill, SampleIds};
pub use lanes::lane_kind;
pub use layer_splat::LayerSplat;
pub use layer_trace::LayerTrace;
pub use packet_tracer::PacketTracer;
pub use point_splat::PointSplat;
pub use route::{AutoSpheres, CostModel, LazyBuild, Route};
pub use scalar_tracer::ScalarTracer;
pub use sphere_splat::SphereSplat;
pub use stale_image::StaleImage;
pub use threads::Threads;
pub use tile_splat::TileSplat;

use volwarp_core::renderer::Renderer;
use volwarp_core::RendererKind;

/// The largest viewport width or height any renderer here draws (bounds what a renderer
/// allocates: at most 8192² pixels of image and depth buffer).
pub const MAX_VIEWPORT: u32 = 8192;

/// The pixel value for "no hit" in sample-id buffers.
pub const NO_HIT: u32 = u32::MAX;

/// A CPU renderer of the registry, drawing with `threads` threads (0: all cores) and the
/// layered renderer's default options; `None` for a renderer that is not a CPU one
/// ([`RendererKind::SpheresGpu`]).
pub fn create(kind: RendererKind, threads: usize) -> Option<Box<dyn Renderer + Send>> {
    create_with(kind, threads, layer_splat::LayerOptions::DEFAULT)
}

/// The one factory of the CPU renderers of the registry: [`create`] with the layered
/// renderer's options `layers` (the GPU renderers: `volwarp_gpu_tracer::create`).
pub fn create_with(
    kind: RendererKind,
    threads: usize,
    layers: layer_splat::LayerOptions,
) -> Option<Box<dyn Renderer + Send>> {
    Some(match kind {
        RendererKind::SpheresCpu => Box::new(PacketTracer::new(threads)),
        RendererKind::SpheresScalar => Box::new(ScalarTracer::new(threads)),
        RendererKind::Splat => Box::new(SphereSplat::new(threads)),
        RendererKind::Points1 => Box::new(PointSplat::new(1, threads)),
        RendererKind::Points2 => Box::new(PointSplat::new(2, threads)),
        RendererKind::Points3 => Box::new(PointSplat::new(3, threads)),
        RendererKind::Stale => Box::new(StaleImage::new(threads)),
        RendererKind::Spheres => Box::new(AutoSpheres::new(threads)),
        RendererKind::SplatTiles => Box::new(TileSplat::new(threads)),
        RendererKind::SpheresFill => {
            Box::new(HoleFill::new(PacketTracer::new(threads), kind, FillOptions::DEFAULT, threads))
        }
        RendererKind::SplatFill => {
            Box::new(HoleFill::new(SphereSplat::new(threads), kind, FillOptions::DEFAULT, threads))
        }
        RendererKind::SplatLayers => Box::new(LayerSplat::with_options(threads, layers)),
        RendererKind::SpheresLayers => Box::new(LayerTrace::new(threads)),
        RendererKind::SpheresGpu | RendererKind::SplatGpu | RendererKind::SplatLayersGpu => return None,
    })
}

/// The kinds [`create`] makes, in the registry's order.
pub fn cpu_kinds() -> impl Iterator<Item = RendererKind> {
    RendererKind::ALL.into_iter().filter(|k| !k.info().caps.gpu)
}
