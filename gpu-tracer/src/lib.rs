//! # volwarp-gpu-tracer
//!
//! The GPU path of volwarp's client (Zellmann 2020, §4): first-hit ray tracing of the
//! object-space samples as spheres through the core LBVH, and the LBVH build itself, as wgpu
//! compute shaders. Runs on any adapter wgpu can open (Vulkan, Metal, DX12, GL), including
//! software Vulkan (lavapipe) where there is no GPU.
//!
//! | module | concept |
//! |---|---|
//! | [`adapter`] | picking a GPU (a real one first, a software one as the fallback) |
//! | [`tracer`] | [`GpuTracer`]: the sphere tracer (`trace.wgsl`), a [`Renderer`] named `spheres-gpu` |
//! | [`splat`] | [`GpuSplat`]: the exact sphere splatter (`splat.wgsl`), a [`Renderer`] named `splat-gpu` |
//! | [`layer_splat`] | [`GpuLayerSplat`]: the layered splatter (`layer_splat.wgsl`), a [`Renderer`] named `splat-layers-gpu` |
//! | [`lbvh`] | the LBVH build on the GPU (`lbvh.wgsl`): Morton codes, radix sort, Karras, fit |
//! | [`layout`] | the shared WGSL prelude (`prelude.wgsl`): one definition of every shared layout |
//! | [`buffers`] | buffers reused across frames, readback |
//! | [`synthetic`] | synthetic sample clouds (a bumpy surface) for tests and benchmarks |
//!
//! The shader mirrors core's ray formula, sample decoding, `sphere::intersect` operation by
//! operation and the tie rule (equal `t`: the smaller primitive index wins), so it draws the
//! CPU's image on all but the rare pixels where a GPU fuses a multiply-add (see
//! `docs/gpu-tracer.md`).
//!
//! [`Renderer`]: volwarp_core::Renderer
#![deny(missing_docs)]
#![forbid(unsafe_code)]

pub mod adapter;
pub mod buffers;
pub mod layer_splat;
pub mod layout;
pub mod lbvh;
pub mod scan;
pub mod splat;
pub mod synthetic;
pub mod tracer;

pub use adapter::GpuContext;
pub use layer_splat::GpuLayerSplat;
pub use scan::WgScanKind;
pub use splat::GpuSplat;
pub use tracer::{BuildTiming, GpuTracer};

/// The one factory of the GPU renderers of the registry (`spheres-gpu`, `splat-gpu`,
/// `splat-layers-gpu`) on an opened device, the layered one drawing with `layers` (the CPU
/// renderers: `volwarp_cpu_tracer::create_with`). A CPU kind is [`GpuError::Internal`].
pub fn create(
    kind: volwarp_core::RendererKind,
    ctx: GpuContext,
    layers: volwarp_cpu_tracer::layer_splat::LayerOptions,
) -> Result<Box<dyn volwarp_core::Renderer>, GpuError> {
    use volwarp_core::RendererKind;
    Ok(match kind {
        RendererKind::SpheresGpu => Box::new(GpuTracer::with_context(ctx)?),
        RendererKind::SplatGpu => Box::new(GpuSplat::with_context(ctx)?),
        RendererKind::SplatLayersGpu => Box::new(GpuLayerSplat::with_context(ctx, layers)?),
        _ => return Err(GpuError::Internal("not a GPU renderer of the registry")),
    })
}

/// Why the GPU tracer could not do its work.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum GpuError {
    /// No usable adapter (the text says what to install).
    NoAdapter(String),
    /// The device could not be opened or waited on.
    Device(String),
    /// A shader did not compile or a pipeline was invalid.
    Shader(String),
    /// wgpu reported a validation or out-of-memory error.
    Wgpu(String),
    /// A buffer would exceed the device's limit.
    TooLarge {
        /// Which buffer.
        what: &'static str,
        /// Bytes needed.
        bytes: u64,
        /// The device limit.
        limit: u64,
    },
    /// The camera is unusable.
    BadCamera(volwarp_core::CameraError),
    /// The scene or frame is inconsistent.
    BadScene(&'static str),
    /// Mapping a buffer for readback failed.
    Readback(String),
    /// A bug: an invariant of this crate did not hold.
    Internal(&'static str),
}

impl std::fmt::Display for GpuError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            GpuError::NoAdapter(s) => write!(f, "no GPU adapter: {s}"),
            GpuError::Device(s) => write!(f, "GPU device: {s}"),
            GpuError::Shader(s) => write!(f, "GPU shader: {s}"),
            GpuError::Wgpu(s) => write!(f, "wgpu: {s}"),
            GpuError::TooLarge { what, bytes, limit } => {
                write!(f, "{what} needs {bytes} bytes, over the device's limit of {limit}")
            }
            GpuError::BadCamera(e) => write!(f, "camera: {e}"),
            GpuError::BadScene(s) => write!(f, "scene: {s}"),
            GpuError::Readback(s) => write!(f, "GPU readback: {s}"),
            GpuError::Internal(s) => write!(f, "internal error: {s}"),
        }
    }
}

impl std::error::Error for GpuError {}
