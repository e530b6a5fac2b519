//! The interchangeable renderers of the client and their live switching (the window number
//! keys 1–9 of core's [`RendererKind`] registry, the default on 1). Every renderer draws the same scene for the same camera; the GPU
//! tracer is opened lazily the first time it is chosen, and if no adapter can be opened the
//! client says so and keeps the current renderer.

use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::{Camera, RendererKind, Scene};
use volwarp_cpu_tracer::layer_splat::LayerOptions;

/// All renderers of a client, created on first use.
pub struct Renderers {
    threads: usize,
    slots: Vec<Option<Box<dyn Renderer>>>,
    current: RendererKind,
    /// The LBVH of unbuilt scenes (see `NetConfig::lazy_build`) for renderers that need it.
    lazy: volwarp_cpu_tracer::LazyBuild,
    gpu_error: Option<String>,
    /// Warp-sized radii (`--adapt`) for the renderers that can.
    adaptive: bool,
}

/// The GPU adapter the client's `--adapter` asked for (set once, before any GPU renderer opens).
static ADAPTER: std::sync::OnceLock<Option<String>> = std::sync::OnceLock::new();

/// Makes the GPU renderers open the adapter whose name contains `name` (`None`: the best one).
/// Only the first call counts.
pub fn set_adapter(name: Option<String>) {
    let _ = ADAPTER.set(name);
}

/// The layered renderers' options the client's `--watertight` asked for (set once, before any
/// layered renderer is created).
static LAYERS: std::sync::OnceLock<LayerOptions> = std::sync::OnceLock::new();

/// Makes the layered renderers (`splat-layers`, `splat-layers-gpu`) draw with `opts` (the
/// defaults otherwise). Only the first call counts.
pub fn set_layer_options(opts: LayerOptions) {
    let _ = LAYERS.set(opts);
}

/// The layered renderers' options.
pub fn layer_options() -> LayerOptions {
    LAYERS.get().copied().unwrap_or_default()
}

/// Creates a renderer of the registry with `threads` CPU threads (0: all cores); the GPU tracer
/// opens an adapter (an error names what to install when none opens).
pub fn create(kind: RendererKind, threads: usize) -> Result<Box<dyn Renderer>, String> {
    if kind.info().caps.gpu {
        return create_gpu(kind);
    }
    match volwarp_cpu_tracer::create_with(kind, threads, layer_options()) {
        Some(r) => Ok(r),
        None => Err(format!("no CPU renderer `{kind}`")),
    }
}

#[cfg(feature = "gpu")]
fn create_gpu(kind: RendererKind) -> Result<Box<dyn Renderer>, String> {
    log::info!("opening {kind} ...");
    let t = std::time::Instant::now();
    let ctx = volwarp_gpu_tracer::GpuContext::with_adapter(ADAPTER.get().and_then(|a| a.as_deref()))
        .map_err(|e| e.to_string())?;
    log::info!("{kind} ready on {} ({:.0} ms)", ctx.describe_driver(), t.elapsed().as_secs_f64() * 1e3);
    volwarp_gpu_tracer::create(kind, ctx, layer_options()).map_err(|e| e.to_string())
}

#[cfg(not(feature = "gpu"))]
fn create_gpu(_kind: RendererKind) -> Result<Box<dyn Renderer>, String> {
    Err("this client was built without the `gpu` feature".into())
}

impl Renderers {
    /// The renderers, starting with `kind` (created now: an unusable GPU is an error here).
    pub fn new(kind: RendererKind, threads: usize) -> Result<Renderers, String> {
        let mut slots: Vec<Option<Box<dyn Renderer>>> = RendererKind::ALL.iter().map(|_| None).collect();
        slots[kind.index()] = Some(create(kind, threads)?);
        Ok(Renderers {
            threads,
            slots,
            current: kind,
            gpu_error: None,
            lazy: volwarp_cpu_tracer::LazyBuild::new(threads),
            adaptive: false,
        })
    }

    /// Sizes spheres by the warp (core's `warp_radius`) in every renderer that can, now and
    /// for those created later.
    pub fn set_adaptive_radius(&mut self, on: bool) {
        self.adaptive = on;
        for r in self.slots.iter_mut().flatten() {
            r.set_adaptive_radius(on);
        }
    }

    /// Whether the current renderer sizes spheres by the warp.
    pub fn adaptive_radius(&mut self) -> bool {
        let on = self.adaptive;
        self.slots[self.current.index()].as_mut().is_some_and(|r| on && r.set_adaptive_radius(on))
    }

    /// Switches to `kind`, creating it on first use. On failure (no GPU adapter) the current
    /// renderer stays and the reason is returned (and logged once).
    pub fn select(&mut self, kind: RendererKind) -> Result<(), String> {
        let i = kind.index();
        if self.slots[i].is_none() {
            if let (true, Some(e)) = (kind.info().caps.gpu, &self.gpu_error) {
                return Err(e.clone());
            }
            match create(kind, self.threads) {
                Ok(mut r) => {
                    r.set_adaptive_radius(self.adaptive);
                    self.slots[i] = Some(r);
                }
                Err(e) => {
                    let e = format!("{kind} unavailable: {e}; staying on {}", self.name());
                    log::warn!("{e}");
                    if kind.info().caps.gpu {
                        self.gpu_error = Some(e.clone());
                    }
                    return Err(e);
                }
            }
        }
        if kind != self.current {
            log::info!("renderer: {kind}");
        }
        self.current = kind;
        Ok(())
    }

    /// Switches to the renderer of window number key `1..=9` (core's
    /// [`RendererKind::window_key`]).
    pub fn select_key(&mut self, key: u8) -> Result<(), String> {
        match RendererKind::from_window_key(key) {
            Some(kind) => self.select(kind),
            None => Err(format!("no renderer on key {key}")),
        }
    }

    /// The current renderer.
    pub fn kind(&self) -> RendererKind {
        self.current
    }

    /// The current renderer's name.
    pub fn name(&self) -> &'static str {
        self.current.name()
    }

    /// The watertight-slab tolerance the current renderer draws with (0: off, or not a
    /// layered renderer).
    pub fn watertight(&self) -> f32 {
        match self.current {
            RendererKind::SplatLayers | RendererKind::SplatLayersGpu => layer_options().watertight,
            _ => 0.0,
        }
    }

    /// Whether the current renderer uses older frames ([`Renderer::keeps_frames`]).
    pub fn keeps_frames(&self) -> bool {
        self.slots[self.current.index()].as_ref().is_some_and(|r| r.keeps_frames())
    }

    /// Draws the newest of `scenes` (newest first) for `camera`, filling from the older ones
    /// where the current renderer keeps frames; otherwise as [`Renderers::render`] the newest.
    pub fn render_set(&mut self, scenes: &[&Scene], camera: &Camera, out: &mut Image) {
        match scenes.first() {
            Some(newest) if scenes.len() == 1 || !self.keeps_frames() => self.render(newest, camera, out),
            Some(_) => match self.slots[self.current.index()].as_mut() {
                Some(r) => r.render_set(scenes, camera, out),
                None => out.reset_for(camera),
            },
            None => out.reset_for(camera),
        }
    }

    /// Draws `scene` for `camera` with the current renderer (building the LBVH of an unbuilt
    /// scene first if the renderer needs one).
    pub fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) {
        let scene = if self.current.info().caps.needs_lbvh { self.lazy.built(scene) } else { scene };
        match self.slots[self.current.index()].as_mut() {
            Some(r) => r.render(scene, camera, out),
            None => out.reset_for(camera),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use volwarp_cpu_tracer::synthetic::depth_image_frame;

    #[test]
    fn switching_keeps_names_and_draws_the_same_spheres() {
        let frame = depth_image_frame(48, 1.0, 7);
        let scene = Scene::build(&frame);
        let cam = frame.header.camera.orbit(8.0, 4.0);
        let mut r = Renderers::new(RendererKind::SpheresCpu, 1).unwrap();
        let mut a = Image::new(1, 1);
        r.render(&scene, &cam, &mut a);
        r.select_key(8).unwrap();
        assert_eq!(r.kind(), RendererKind::SpheresScalar);
        let mut b = Image::new(1, 1);
        r.render(&scene, &cam, &mut b);
        assert_eq!(a, b, "packet and scalar tracers draw the same image");
        assert!(a.pixels.iter().any(|&p| p != volwarp_core::BACKGROUND));
        for k in 1..=9 {
            r.select_key(k).unwrap();
            assert_eq!(r.kind().window_key(), Some(k));
        }
        r.select_key(1).unwrap();
        assert_eq!(r.kind(), RendererKind::DEFAULT, "the default is on key 1");
        r.select_key(9).unwrap();
        assert_eq!(r.kind(), RendererKind::Spheres);
        let mut c = Image::new(1, 1);
        r.render(&scene, &cam, &mut c);
        assert_eq!(a, c, "the default renderer draws the same image");
        // An unbuilt scene (lazy build): the exact renderers draw the built scene's image.
        let unbuilt = volwarp_cpu_tracer::route::unbuilt_scene(&frame);
        for key in [9, 8, 6] {
            r.select_key(key).unwrap();
            let mut d = Image::new(1, 1);
            r.render(&unbuilt, &cam, &mut d);
            assert_eq!(a, d, "{} on the unbuilt scene", r.name());
        }
        assert!(r.select_key(10).is_err());
        assert!(r.select_key(0).is_err());
    }

    #[test]
    fn the_layered_renderer_uses_older_frames_and_the_others_draw_the_newest() {
        // The newest frame zoomed in (a narrow view), an older one of the whole surface: what
        // the older frame holds outside the newest frame's view fills the pixels around it.
        let mut zoomed = depth_image_frame(48, 1.0, 7);
        zoomed.header.camera.fov_y_deg /= 3.0;
        let whole = depth_image_frame(48, 1.0, 9);
        let (newest, older) =
            (volwarp_cpu_tracer::route::unbuilt_scene(&zoomed), volwarp_cpu_tracer::route::unbuilt_scene(&whole));
        let cam = whole.header.camera.orbit(5.0, 0.0);
        let mut r = Renderers::new(RendererKind::SplatLayers, 1).unwrap();
        assert!(r.keeps_frames());
        let (mut one, mut two) = (Image::new(1, 1), Image::new(1, 1));
        r.render(&newest, &cam, &mut one);
        r.render_set(&[&newest, &older], &cam, &mut two);
        let changed = one.pixels.iter().zip(&two.pixels).filter(|(a, b)| a != b).count();
        assert!(changed > 100, "older frames fill {changed} pixels");
        r.select(RendererKind::Splat).unwrap();
        assert!(!r.keeps_frames());
        r.render(&newest, &cam, &mut one);
        r.render_set(&[&newest, &older], &cam, &mut two);
        assert!(one == two, "a renderer that keeps no frames draws the newest alone");
    }

    /// The GPU layered splatter opens by name where there is an adapter (lavapipe in CI) and
    /// draws the CPU's layered image; without one (or without the `gpu` feature) creating it
    /// is an error that says why, not a panic.
    #[test]
    fn the_gpu_layered_splatter_is_created_by_kind() {
        let frame = depth_image_frame(40, 1.0, 3);
        let scene = volwarp_cpu_tracer::route::unbuilt_scene(&frame);
        let cam = frame.header.camera.orbit(6.0, 2.0);
        match create(RendererKind::SplatLayersGpu, 1) {
            Ok(mut gpu) => {
                assert_eq!(gpu.name(), "splat-layers-gpu");
                assert!(gpu.set_adaptive_radius(true));
                let mut cpu = create(RendererKind::SplatLayers, 1).unwrap();
                cpu.set_adaptive_radius(true);
                let (mut a, mut b) = (Image::new(1, 1), Image::new(1, 1));
                cpu.render(&scene, &cam, &mut a);
                gpu.render(&scene, &cam, &mut b);
                assert!(a.diff(&b).unwrap().meets_target());
                assert!(a.pixels.iter().any(|&p| p != volwarp_core::BACKGROUND));
                // It keeps frames too, and fills from them as the CPU does.
                assert!(gpu.keeps_frames());
                let mut zoomed = depth_image_frame(48, 1.0, 7);
                zoomed.header.camera.fov_y_deg /= 3.0;
                let whole = depth_image_frame(48, 1.0, 9);
                let (newest, older) = (
                    volwarp_cpu_tracer::route::unbuilt_scene(&zoomed),
                    volwarp_cpu_tracer::route::unbuilt_scene(&whole),
                );
                let cam = whole.header.camera.orbit(5.0, 0.0);
                cpu.render_set(&[&newest, &older], &cam, &mut a);
                gpu.render_set(&[&newest, &older], &cam, &mut b);
                assert!(a.diff(&b).unwrap().meets_target());
                let mut alone = Image::new(1, 1);
                gpu.render(&newest, &cam, &mut alone);
                assert!(alone.pixels.iter().zip(&b.pixels).filter(|(x, y)| x != y).count() > 100);
            }
            Err(e) => {
                assert!(!cfg!(feature = "gpu") || e.contains("adapter"), "{e}");
                eprintln!("splat-layers-gpu not opened: {e}");
            }
        }
    }
}
