//! The default sphere renderer (name `spheres`): the exact first-hit image by the cheaper route
//! for the frame at hand, chosen per frame by a cost model whose constants were measured on the
//! MRI benchmark frame (`examples/splat_timing.rs`, `docs/perf.md`, "The route's cost model"):
//!
//! * **splat** ([`TileSplat`]): cost grows with the spheres in view and the pixels their
//!   bounds cover, and needs no LBVH;
//! * **trace** ([`PacketTracer`]): cost grows with the pixels and, more slowly, with the
//!   spheres' size on screen; needs the LBVH.
//!
//! Both routes give the same sample per pixel (tested), so the choice never changes the image,
//! only the time. The estimate reads the screen bound of every `k`-th sphere (about 4096 of
//! them), a few hundred microseconds at most.
//!
//! **Lazy build.** A scene may come *unbuilt*: the frame's samples in arrival order with no
//! nodes ([`unbuilt_scene`]). The splatter draws it directly — equal distances are then broken
//! by the order the build would give, so the image is the built scene's — and the LBVH is
//! built (once per frame, kept) only when the tracer is chosen.

use crate::sphere_splat::View;
use crate::threads::Threads;
use crate::{PacketTracer, ParallelBuilder, TileSplat};
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::sample::Dequantizer;
use volwarp_core::wire::{Frame, FrameHeader};
use volwarp_core::RendererKind;
use volwarp_core::{Camera, Scene};

/// Spheres whose bounds the estimate reads (every `n / ESTIMATE_SPHERES`-th one).
const ESTIMATE_SPHERES: usize = 4096;

/// What the cost model knows of a frame: the estimated spheres in view and the pixels their
/// screen bounds cover, from a regular subsample.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Estimate {
    /// Spheres whose bound is not empty.
    pub spheres: f64,
    /// Sum of their bound areas in pixels (a sphere touching the eye plane counts the whole
    /// viewport).
    pub covered: f64,
    /// Pixels of the viewport.
    pub pixels: f64,
}

impl Estimate {
    /// Covered pixels per viewport pixel (the splatter's depth complexity).
    pub fn coverage(&self) -> f64 {
        self.covered / self.pixels.max(1.0)
    }
}

/// Estimates the splatter's work for `scene` seen from `camera` (a usable camera).
pub fn estimate(scene: &Scene, camera: &Camera) -> Estimate {
    let n = scene.samples.len();
    let pixels = camera.width as f64 * camera.height as f64;
    if n == 0 || camera.validate(crate::MAX_VIEWPORT).is_err() {
        return Estimate { spheres: 0.0, covered: 0.0, pixels };
    }
    let view = View::new(camera);
    let step = (n / ESTIMATE_SPHERES).max(1);
    let (mut spheres, mut covered) = (0usize, 0f64);
    let deq: &Dequantizer = &scene.deq;
    for &s in scene.samples.iter().step_by(step) {
        if let Some((x0, x1, y0, y1)) = crate::tile_splat::tight_bound(&view, deq.center(s), deq.radius(s)) {
            spheres += 1;
            covered += (x1 - x0 + 1) as f64 * (y1 - y0 + 1) as f64;
        }
    }
    let scale = n as f64 / n.div_ceil(step) as f64;
    Estimate { spheres: spheres as f64 * scale, covered: covered * scale, pixels }
}

/// The two routes to the same image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Route {
    /// Object order: [`TileSplat`].
    Splat,
    /// Image order: [`PacketTracer`] over the LBVH.
    Trace,
}

/// Predicted times of the two routes, in nanoseconds on one thread (both scale alike with
/// threads), from the estimate's spheres in view `S`, covered pixels `C` and viewport pixels
/// `P`:
///
/// * splat: `S · splat_sphere_ns + C · splat_covered_ns + P · splat_pixel_ns`;
/// * trace: `P · trace_pixel_ns + C · trace_covered_ns + S · trace_sphere_ns` (a ray visits
///   more nodes when more spheres share its pixel).
///
/// The default constants are a least-squares fit (relative error) to the twelve views of
/// `examples/splat_timing.rs` on the MRI benchmark frame (footprint and voxel radius, 10° off
/// and zoomed in ×0.5 and ×0.25, 1024² and 512²; `docs/perf.md`, "The route's cost model"); an
/// earlier form with the tracer growing with the bound's side mispredicted zoomed-in views.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CostModel {
    /// Splatter: per sphere in view (bound, binning, set-up, first SIMD test).
    pub splat_sphere_ns: f64,
    /// Splatter: per covered pixel (further SIMD pixel tests, depth test).
    pub splat_covered_ns: f64,
    /// Splatter: per viewport pixel (directions, clearing and writing the tiles).
    pub splat_pixel_ns: f64,
    /// Tracer: per viewport pixel.
    pub trace_pixel_ns: f64,
    /// Tracer: per covered pixel (depth complexity: more nodes and tests per ray).
    pub trace_covered_ns: f64,
    /// Tracer: per sphere in view.
    pub trace_sphere_ns: f64,
}

impl Default for CostModel {
    /// The constants measured on this project's 2-core benchmark machine.
    fn default() -> Self {
        CostModel {
            splat_sphere_ns: 38.0,
            splat_covered_ns: 1.87,
            splat_pixel_ns: 22.7,
            trace_pixel_ns: 90.2,
            trace_covered_ns: 1.31,
            trace_sphere_ns: 117.0,
        }
    }
}

impl CostModel {
    /// Predicted nanoseconds of each route, `(splat, trace)`.
    pub fn predict(&self, e: &Estimate) -> (f64, f64) {
        let splat =
            e.spheres * self.splat_sphere_ns + e.covered * self.splat_covered_ns + e.pixels * self.splat_pixel_ns;
        let trace =
            e.pixels * self.trace_pixel_ns + e.covered * self.trace_covered_ns + e.spheres * self.trace_sphere_ns;
        (splat, trace)
    }

    /// The cheaper route.
    pub fn choose(&self, e: &Estimate) -> Route {
        let (splat, trace) = self.predict(e);
        if splat <= trace {
            Route::Splat
        } else {
            Route::Trace
        }
    }
}

/// An unbuilt scene of `frame`: its samples and colors in arrival order and no nodes (what
/// [`TileSplat`] and [`AutoSpheres`] draw without an LBVH). A frame whose color count differs
/// from its sample count is cut to the shorter.
pub fn unbuilt_scene(frame: &Frame) -> Scene {
    let n = frame.samples.len().min(frame.colors.len());
    Scene {
        header: frame.header,
        deq: Dequantizer::new(frame.header.bounds, frame.header.radius_unit),
        samples: frame.samples[..n].to_vec(),
        colors: frame.colors[..n].to_vec(),
        nodes: Vec::new(),
    }
}

/// [`unbuilt_scene`] taking the frame's buffers (no copy): what a client does with a received
/// frame when its renderer needs no LBVH.
pub fn into_unbuilt_scene(frame: Frame) -> Scene {
    let Frame { header, mut samples, mut colors, .. } = frame;
    let n = samples.len().min(colors.len());
    samples.truncate(n);
    colors.truncate(n);
    Scene { header, deq: Dequantizer::new(header.bounds, header.radius_unit), samples, colors, nodes: Vec::new() }
}

/// Whether `scene` is unbuilt (see [`unbuilt_scene`]): no nodes although it has two samples or
/// more.
pub fn is_unbuilt(scene: &Scene) -> bool {
    scene.nodes.is_empty() && scene.samples.len() >= 2
}

/// What identifies the scene something was derived from (the unbuilt scene a kept LBVH was
/// built from, the frame a hole filler's stale image was splatted from).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct SceneId {
    header: FrameHeader,
    ptr: usize,
    len: usize,
    first: u64,
    last: u64,
}

impl SceneId {
    pub(crate) fn of(scene: &Scene) -> SceneId {
        SceneId {
            header: scene.header,
            ptr: scene.samples.as_ptr() as usize,
            len: scene.samples.len(),
            first: scene.samples.first().copied().unwrap_or(0),
            last: scene.samples.last().copied().unwrap_or(0),
        }
    }
}

/// The default sphere renderer (name `spheres`): [`TileSplat`] or [`PacketTracer`], whichever
/// the [`CostModel`] predicts faster for the frame; the same image either way.
#[derive(Debug)]
pub struct AutoSpheres {
    splat: TileSplat,
    tracer: PacketTracer,
    model: CostModel,
    forced: Option<Route>,
    last: Option<Route>,
    last_estimate: Estimate,
    lazy: LazyBuild,
}

impl AutoSpheres {
    /// The renderer on `threads` threads (0: one per core) with the measured [`CostModel`].
    pub fn new(threads: usize) -> Self {
        let threads = Threads::new(threads).count();
        AutoSpheres {
            splat: TileSplat::new(threads),
            tracer: PacketTracer::new(threads),
            model: CostModel::default(),
            forced: None,
            last: None,
            last_estimate: Estimate::default(),
            lazy: LazyBuild::new(threads),
        }
    }

    /// The same renderer with another cost model.
    pub fn with_model(mut self, model: CostModel) -> Self {
        self.model = model;
        self
    }

    /// The same renderer always taking `route` (for tests and measurements).
    pub fn with_route(mut self, route: Route) -> Self {
        self.forced = Some(route);
        self
    }

    /// The route the last frame took (`None` before the first, or when nothing was drawn).
    pub fn last_route(&self) -> Option<Route> {
        self.last
    }

    /// The estimate the last choice was made on.
    pub fn last_estimate(&self) -> Estimate {
        self.last_estimate
    }

    /// The route for `scene` from `camera`.
    pub fn choose(&mut self, scene: &Scene, camera: &Camera) -> Route {
        if let Some(r) = self.forced {
            return r;
        }
        self.last_estimate = estimate(scene, camera);
        self.model.choose(&self.last_estimate)
    }
}

/// Builds the LBVH of unbuilt scenes on demand, once per scene (kept while the same unbuilt
/// scene is drawn again): for renderers that need the LBVH when a client hands them unbuilt
/// scenes ([`AutoSpheres`] on its tracing route, or a client whose renderer was switched).
#[derive(Debug)]
pub struct LazyBuild {
    threads: usize,
    builder: Option<ParallelBuilder>,
    kept: Option<(SceneId, Scene)>,
    /// The copy of the scene's samples the builder reads (kept for its buffers).
    frame: Option<Frame>,
}

impl LazyBuild {
    /// Builds on `threads` threads (0: one per core) when needed.
    pub fn new(threads: usize) -> Self {
        LazyBuild { threads, builder: None, kept: None, frame: None }
    }

    /// `scene` itself if it is built, else its built form (built now unless kept).
    pub fn built<'a>(&'a mut self, scene: &'a Scene) -> &'a Scene {
        if !is_unbuilt(scene) {
            return scene;
        }
        let id = SceneId::of(scene);
        if self.kept.as_ref().map(|(k, _)| *k) != Some(id) {
            let frame = self.frame.get_or_insert_with(|| Frame {
                header: scene.header,
                samples: Vec::new(),
                colors: Vec::new(),
                segments: Vec::new(),
            });
            frame.header = scene.header;
            frame.samples.clear();
            frame.samples.extend_from_slice(&scene.samples);
            frame.colors.clear();
            frame.colors.extend_from_slice(&scene.colors);
            let threads = self.threads;
            let builder = self.builder.get_or_insert_with(|| ParallelBuilder::new(threads));
            let mut s = match self.kept.take() {
                Some((_, s)) => s,
                None => unbuilt_scene(&Frame {
                    header: scene.header,
                    samples: Vec::new(),
                    colors: Vec::new(),
                    segments: Vec::new(),
                }),
            };
            builder.build_into(frame, &mut s);
            self.kept = Some((id, s));
        }
        match &self.kept {
            Some((_, s)) => s,
            None => scene,
        }
    }
}

impl Renderer for AutoSpheres {
    fn kind(&self) -> RendererKind {
        RendererKind::Spheres
    }

    fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) {
        let route = self.choose(scene, camera);
        self.last = Some(route);
        match route {
            Route::Splat => self.splat.render(scene, camera, out),
            Route::Trace => {
                let built = self.lazy.built(scene);
                self.tracer.render(built, camera, out);
            }
        }
    }
}
