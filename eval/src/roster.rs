//! Every renderer the evaluation compares, under its CSV name: the stale image, points with
//! N = 1, 2, 3, the CPU sphere tracer (and its radius variants ×0.5 and ×2), the GPU sphere
//! tracer where an adapter opens, the exact sphere splatter and its GPU twin (`splat-gpu`)
//! where an adapter opens, the hole-filling tracer (`spheres-fill`) with its variants, and
//! `splat-fill+adapt`, the single-frame warp of the hole-filling splatter with warp-sized radii
//! (the client's drawing before layered frames; a single warp of one frame, so not the
//! sessions' `volwarp` method, which keeps frames and asks for layered, predicted ones).

use volwarp_core::renderer::Renderer;
use volwarp_core::wire::Frame;
use volwarp_core::{RendererKind, Scene};
use volwarp_cpu_tracer::{FillOptions, HoleFill, PacketTracer};

/// The radius scales of the sphere-size variants (`spheres-cpu-r0.5`, `spheres-cpu-r2`).
pub const RADIUS_VARIANTS: [f32; 2] = [0.5, 2.0];

/// One renderer of the comparison.
pub struct Entry {
    /// The CSV name (`stale`, `points1`, …, `spheres-cpu-r0.5`).
    pub name: String,
    /// Which scene it draws: the sphere radius as a multiple of the frame's.
    pub radius_scale: f32,
    /// Whether it runs on the GPU (slow on a software adapter).
    pub gpu: bool,
    /// The renderer.
    pub renderer: Box<dyn Renderer>,
}

/// Options of [`roster`].
#[derive(Clone, Copy, Debug)]
pub struct RosterOptions {
    /// Threads per CPU renderer (0: all cores).
    pub threads: usize,
    /// Try to open the GPU tracer.
    pub gpu: bool,
}

impl Default for RosterOptions {
    fn default() -> Self {
        RosterOptions { threads: 0, gpu: true }
    }
}

/// A CPU renderer of the registry under its own name, at radius ×1.
fn entry(kind: RendererKind, threads: usize) -> Entry {
    let renderer = volwarp_cpu_tracer::create(kind, threads).expect("a CPU renderer");
    Entry { name: kind.name().into(), radius_scale: 1.0, gpu: false, renderer }
}

/// The renderers, in the order of the CSV. The GPU tracer is included only if it is built in
/// (feature `gpu`) and an adapter opens; otherwise a log line says why.
pub fn roster(opts: RosterOptions) -> Vec<Entry> {
    use RendererKind::*;
    let t = opts.threads;
    let mut v: Vec<Entry> = [Stale, Points1, Points2, Points3, SpheresCpu].into_iter().map(|k| entry(k, t)).collect();
    if opts.gpu {
        v.extend(gpu_entry(SpheresGpu));
    }
    v.push(entry(Splat, t));
    if opts.gpu {
        v.extend(gpu_entry(SplatGpu));
    }
    for s in RADIUS_VARIANTS {
        v.push(Entry { name: format!("{SpheresCpu}-r{s}"), radius_scale: s, ..entry(SpheresCpu, t) });
    }
    v.push(entry(SpheresFill, t));
    // The single-frame warp of the hole-filling splatter with warp-sized radii.
    let mut renderer = volwarp_cpu_tracer::create(SplatFill, t).expect("a CPU renderer");
    renderer.set_adaptive_radius(true);
    v.push(Entry { name: SPLAT_FILL_ADAPT.into(), radius_scale: 1.0, gpu: false, renderer });
    for (name, opts) in FILL_VARIANTS {
        let renderer = Box::new(HoleFill::new(PacketTracer::new(t), SpheresFill, opts, t));
        v.push(Entry { name: name.into(), radius_scale: 1.0, gpu: false, renderer });
    }
    v
}

/// The CSV name of the single-frame warp of the hole-filling splatter with warp-sized radii
/// (core's `warp_radius`), written as the sessions' method spec of the same drawing. It used
/// to be called `volwarp`; the sessions' `volwarp` (core's `Method::DEFAULT`) is the layered
/// method, which a single warp of one frame cannot show.
pub const SPLAT_FILL_ADAPT: &str = "splat-fill+adapt";

/// The hole-filling variants measured beside `spheres-fill`: the stale frame plus
/// 3 levels of pull-push, and pull-push alone.
pub const FILL_VARIANTS: [(&str, FillOptions); 2] = [
    ("spheres-fill-pp3", FillOptions { stale: true, enclosed_only: true, pull_push_levels: 3 }),
    ("spheres-pp3", FillOptions { stale: false, enclosed_only: true, pull_push_levels: 3 }),
];

/// A GPU renderer of the registry (`spheres-gpu`, `splat-gpu`, `splat-layers-gpu`), if an
/// adapter opens.
#[cfg(feature = "gpu")]
fn gpu_entry(kind: RendererKind) -> Option<Entry> {
    let made = volwarp_gpu_tracer::GpuContext::new().and_then(|ctx| {
        let on = ctx.describe();
        let r = volwarp_gpu_tracer::create(kind, ctx, volwarp_cpu_tracer::layer_splat::LayerOptions::DEFAULT)?;
        log::info!("{kind} on {on}");
        Ok(r)
    });
    match made {
        Ok(renderer) => Some(Entry { name: kind.name().into(), radius_scale: 1.0, gpu: true, renderer }),
        Err(e) => {
            log::warn!("{kind} left out: {e}");
            None
        }
    }
}

#[cfg(not(feature = "gpu"))]
fn gpu_entry(kind: RendererKind) -> Option<Entry> {
    log::info!("{kind} left out: built without the `gpu` feature");
    None
}

/// The frame with every sphere's radius scaled by `s` (the radius codes stay; the unit changes).
pub fn scaled_frame(frame: &Frame, s: f32) -> Frame {
    let mut f = frame.clone();
    f.header.radius_unit *= s;
    f
}

/// A frame's scene at radius ×1 and at each of [`RADIUS_VARIANTS`].
pub struct SceneSet {
    /// `(radius scale, scene)`, the ×1 scene first.
    pub scenes: Vec<(f32, Scene)>,
}

impl SceneSet {
    /// Builds the scenes (parallel LBVH builds).
    pub fn build(frame: &Frame) -> SceneSet {
        let mut scenes = vec![(1.0, volwarp_cpu_tracer::build_scene(frame))];
        for s in RADIUS_VARIANTS {
            scenes.push((s, volwarp_cpu_tracer::build_scene(&scaled_frame(frame, s))));
        }
        SceneSet { scenes }
    }

    /// The scene of a radius scale (the ×1 scene for an unknown one).
    pub fn get(&self, radius_scale: f32) -> &Scene {
        self.scenes.iter().find(|(s, _)| *s == radius_scale).map_or(&self.scenes[0].1, |(_, sc)| sc)
    }
}
