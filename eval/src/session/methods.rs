//! What the client shows: the methods a session compares.
//!
//! A method is a CPU renderer of the registry (`stale`, `points2`, `splat`, `splat-fill`, …)
//! plus what the client asks the server for and how many frames it keeps, written as a **method
//! spec**:
//! `RENDERER[+predict][+guard=G][+frames=K][+adapt][+pp=L][+layers=K][+rest=K][+coarse=N][+prefetch=D][+no-preempt]`,
//! e.g. `splat-fill+predict+guard=0.1+frames=2` or `splat-layers+predict+adapt+layers=4`.
//!
//! - `+predict`: the client asks for the camera it expects to show when the frame is on screen
//!   (core's `prediction`, horizon from core's `prediction::Horizon`);
//! - `+guard=G`: it asks for a view widened by `G` of its size on every side at the same pixel
//!   density (core's `guard`);
//! - `+frames=K`: it keeps the `K` newest frames and fills what the newest does not cover from
//!   the older ones (the `*-fill` renderers: cpu-tracer's `hole_fill`; `splat-layers`:
//!   what each older frame saw that the newest did not, `layer_splat`);
//! - `+adapt`: it draws spheres sized by how far the view moved from the frame's camera (core's
//!   `warp_radius`: half the footprint at the frame's camera, growing to the frame's own radius
//!   by 10°; the splatters only; `splat-layers` grows its footprints instead);
//! - `+pp=L`: pull-push over `L` levels into the holes left inside the silhouette (only the
//!   `*-fill` renderers);
//! - `+layers=K`: it asks for frames of `K` segments per pixel (drawn by
//!   `splat-layers`), whatever the session's `--layers`;
//! - `+rest=K`: it asks for `K` segments per pixel for the view at rest (core's
//!   `method::RequestPolicy::layers`; without it, as many as while the camera moves);
//! - `+coarse=N`: adaptive resolution (core's `method::RequestPolicy::camera_at`): while the
//!   camera moves it asks for frames on a pixel grid `N` (2 or 4) times coarser per axis, which
//!   the server renders in its time times the marcher's measured ratio at that resolution
//!   (`session-calibrate`'s `DATASET/N` lines, [`super::peers::ResolutionCost`]) and encodes
//!   at that size; the full resolution at the first still tick.
//! - `+prefetch=D`: while the camera rests and its exact frame has arrived, it asks for the two
//!   side views `D` degrees along the orbit either way, one after the other (core's
//!   `method::RequestPolicy::prefetch`); at time 0 it holds them beside the first frame (the
//!   user looked at that image long enough for them to come);
//! - `+no-preempt`: the server finishes every render it starts and every frame it writes. By
//!   default, as the real server does, it drops the render in progress when a request for
//!   another viewport arrives (with adaptive resolution: the view came to rest or started
//!   moving), though never two in a row, and the frame being written, after the part under
//!   way, when one for a coarser viewport arrives (`volwarp_server::server`'s module docs).
//!
//! [`default_method`] (alias `volwarp`, core's `Method::DEFAULT`, which has `+coarse=2+prefetch=30`) is the
//! method the window client runs by default; `volwarp-adaptive` is the same and
//! `volwarp-adaptive=4` it with `+coarse=4`.
//! The `stale` method never predicts nor widens: it is what a send-image system shows.

use super::peers::ImagePeer;
use crate::ErrorBox;
use volwarp_core::guard::MAX_GUARD;
use volwarp_core::method::{Method as CoreMethod, MAX_PREFETCH_DEG};
use volwarp_core::renderer::Renderer;
use volwarp_core::segments::MAX_LAYERS;
use volwarp_core::wire::Frame;
use volwarp_core::{Camera, Image, RendererKind, Scene};
use volwarp_cpu_tracer::hole_fill::{FillOptions, HoleFill, SampleIds, MAX_FRAMES};
use volwarp_cpu_tracer::{PacketTracer, SphereSplat};

/// What a session's client asks the server for: core's request policy (the camera it shows, or
/// the one it expects to show when the frame is on screen, widened by a guard band) and the
/// segments per pixel. The request of each method of a session; the frames of each distinct
/// request are served separately.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SessionRequest {
    /// Ask for the predicted camera.
    pub predict: bool,
    /// Guard band fraction (0: none).
    pub guard: f32,
    /// Segments per pixel it asks for (0: the session's `--layers`).
    pub layers: u32,
    /// Viewport divisor per axis while the camera moves (1: always the full resolution).
    pub coarse: u8,
    /// Segments per pixel it asks for the view at rest (0: as while it moves).
    pub rest_layers: u8,
    /// Side views asked for while the camera rests, degrees along the orbit either way (0:
    /// none).
    pub prefetch_deg: f32,
    /// The server drops the render in progress, or the frame being written, when a request for
    /// another viewport arrives (the real server's rule; `false`: `+no-preempt`, every render
    /// finished and every frame written whole).
    pub preempt: bool,
}

impl SessionRequest {
    /// Asks for the camera shown (what a send-image system does).
    pub const NONE: SessionRequest = SessionRequest {
        predict: false,
        guard: 0.0,
        layers: 0,
        coarse: 1,
        rest_layers: 0,
        prefetch_deg: 0.0,
        preempt: true,
    };

    /// Its request policy (core's `method::RequestPolicy`).
    pub const fn policy(&self) -> volwarp_core::method::RequestPolicy {
        volwarp_core::method::RequestPolicy {
            predict: self.predict,
            guard: self.guard,
            coarse: self.coarse,
            rest_layers: self.rest_layers,
            prefetch_deg: self.prefetch_deg,
        }
    }
}

/// A frame the client holds, with its scene built once for every method.
pub struct HeldFrame {
    /// The frame as received.
    pub frame: Frame,
    /// Its sphere scene (LBVH built once).
    pub scene: Scene,
}

impl HeldFrame {
    /// Builds the scene of a frame.
    pub fn new(frame: Frame) -> HeldFrame {
        let scene = volwarp_cpu_tracer::build_scene(&frame);
        HeldFrame { frame, scene }
    }
}

/// One way of showing the frames the client holds.
pub trait Method {
    /// The method's name (CSV, charts): its spec.
    fn name(&self) -> &str;
    /// What the client asks the server for.
    fn request(&self) -> SessionRequest {
        SessionRequest::NONE
    }
    /// How many of the newest frames it keeps (at least 1).
    fn frames_kept(&self) -> usize {
        1
    }
    /// Draws the frames for `camera`; `frames` holds the frames kept, newest last.
    fn draw(&mut self, frames: &[&HeldFrame], camera: &Camera, out: &mut Image);
    /// The image-sending peer it is (`send-image`, `downscale`), which the simulator serves
    /// images instead of frames ([`super::peers`]); `None` for the frame-warping methods.
    fn image_peer(&self) -> Option<ImagePeer> {
        None
    }
}

/// An image-sending peer ([`super::peers`]): the simulator serves it JPEG images and shows the
/// newest upscaled; it draws no frame.
pub struct PeerMethod {
    name: String,
    peer: ImagePeer,
}

impl Method for PeerMethod {
    fn name(&self) -> &str {
        &self.name
    }
    fn draw(&mut self, _frames: &[&HeldFrame], camera: &Camera, out: &mut Image) {
        out.reset_for(camera);
    }
    fn image_peer(&self) -> Option<ImagePeer> {
        Some(self.peer)
    }
}

/// A method that is one renderer of the registry drawing the frames it keeps
/// (`Renderer::render_set`: the newest alone unless the renderer keeps frames, as
/// `splat-layers` does).
pub struct RendererMethod {
    name: String,
    request: SessionRequest,
    frames: usize,
    renderer: Box<dyn Renderer + Send>,
}

impl Method for RendererMethod {
    fn name(&self) -> &str {
        &self.name
    }
    fn request(&self) -> SessionRequest {
        self.request
    }
    fn frames_kept(&self) -> usize {
        self.frames
    }
    fn draw(&mut self, frames: &[&HeldFrame], camera: &Camera, out: &mut Image) {
        let scenes: Vec<&Scene> = frames.iter().rev().take(self.frames).map(|f| &f.scene).collect();
        match scenes.first() {
            Some(_) => self.renderer.render_set(&scenes, camera, out),
            None => out.reset_for(camera),
        }
    }
}

/// A renderer with the client-side levers: hole filling from several frames (`+frames=K`), or
/// none (`FillOptions` all off), and warp-sized radii (`+adapt`).
pub struct FillMethod<R: SampleIds + Renderer> {
    name: String,
    request: SessionRequest,
    frames: usize,
    fill: HoleFill<R>,
}

impl<R: SampleIds + Renderer> Method for FillMethod<R> {
    fn name(&self) -> &str {
        &self.name
    }
    fn request(&self) -> SessionRequest {
        self.request
    }
    fn frames_kept(&self) -> usize {
        self.frames
    }
    fn draw(&mut self, frames: &[&HeldFrame], camera: &Camera, out: &mut Image) {
        let scenes: Vec<&Scene> = frames.iter().rev().take(self.frames).map(|f| &f.scene).collect();
        self.fill.render_set(&scenes, camera, out);
    }
}

/// A parsed method spec (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MethodSpec {
    /// The renderer.
    pub renderer: RendererKind,
    /// What the client asks for.
    pub request: SessionRequest,
    /// Frames kept (1 unless a `*-fill` renderer or `splat-layers`).
    pub frames: usize,
    /// Warp-sized radii (core's `warp_radius`; the splatters only).
    pub adapt: bool,
    /// Pull-push levels after the other fill stages (`*-fill` renderers only; 0: none).
    pub pull_push: u32,
}

/// The method the window client runs by default and the sessions' `volwarp` alias (core's
/// `Method::DEFAULT`), as a spec: `splat-layers+predict+frames=4+adapt+layers=4+coarse=2+prefetch=30`.
/// Without adaptive resolution it is `splat-layers+predict+frames=4+adapt+layers=4+prefetch=30`.
pub fn default_method() -> String {
    MethodSpec::of(&CoreMethod::DEFAULT).name()
}

/// The methods named by an alias, which sessions keep as the CSV name: `volwarp` (core's
/// `Method::DEFAULT`, with its adaptive resolution: 1/2 per axis while the camera moves),
/// `volwarp-adaptive` (the same, by its older name) and `volwarp-adaptive=4` (1/4); `None` for
/// any other name.
pub fn alias(name: &str) -> Option<MethodSpec> {
    let coarse = match name.trim() {
        "volwarp" => CoreMethod::DEFAULT.coarse,
        "volwarp-adaptive" | "volwarp-adaptive=2" => 2,
        "volwarp-adaptive=4" => 4,
        _ => return None,
    };
    Some(MethodSpec::of(&CoreMethod { coarse, ..CoreMethod::DEFAULT }))
}

/// The methods of `all`: what a send-image system shows, the 2.5D points of ZAL12, the exact
/// sphere renderers, and volwarp's default.
pub const ALL: [&str; 7] = ["stale", "points1", "points2", "points3", "spheres-cpu", "splat", "volwarp"];

impl MethodSpec {
    /// Parses `RENDERER[+predict][+guard=G][+frames=K][+adapt][+pp=L][+layers=K][+rest=K][+coarse=N][+prefetch=D][+no-preempt]`
    /// or an alias ([`alias`]).
    pub fn parse(spec: &str) -> Result<MethodSpec, ErrorBox> {
        let spec = spec.trim();
        if let Some(m) = alias(spec) {
            return Ok(m);
        }
        let mut parts = spec.split('+');
        let base = parts.next().unwrap_or_default();
        let renderer = RendererKind::from_name(base)
            .filter(|k| !k.info().caps.gpu)
            .ok_or_else(|| format!("unknown method {base:?}: not a CPU renderer of the registry"))?;
        let mut m = MethodSpec { renderer, request: SessionRequest::NONE, frames: 1, adapt: false, pull_push: 0 };
        for p in parts {
            match p.split_once('=') {
                None if p == "predict" => m.request.predict = true,
                None if p == "adapt" => m.adapt = true,
                None if p == "no-preempt" => m.request.preempt = false,
                Some(("guard", g)) => {
                    let g: f32 = g.parse().map_err(|_| format!("{spec}: guard {g:?} is not a number"))?;
                    if !(0.0..=MAX_GUARD).contains(&g) {
                        return Err(format!("{spec}: guard must be within 0..={MAX_GUARD}").into());
                    }
                    m.request.guard = g;
                }
                Some(("pp", l)) => {
                    let l: u32 = l.parse().map_err(|_| format!("{spec}: pp {l:?} is not a count"))?;
                    if l > FillOptions::MAX_LEVELS {
                        return Err(format!("{spec}: pp must be within 0..={}", FillOptions::MAX_LEVELS).into());
                    }
                    m.pull_push = l;
                }
                Some(("layers", k)) => {
                    let k: u32 = k.parse().map_err(|_| format!("{spec}: layers {k:?} is not a count"))?;
                    if !(1..=MAX_LAYERS as u32).contains(&k) {
                        return Err(format!("{spec}: layers must be within 1..={MAX_LAYERS}").into());
                    }
                    m.request.layers = k;
                }
                Some(("rest", k)) => {
                    let k: u8 = k.parse().map_err(|_| format!("{spec}: rest {k:?} is not a count"))?;
                    if usize::from(k) > MAX_LAYERS {
                        return Err(format!("{spec}: rest must be within 0..={MAX_LAYERS}").into());
                    }
                    m.request.rest_layers = k;
                }
                Some(("coarse", n)) => {
                    m.request.coarse = match n.parse::<u8>() {
                        Ok(n @ (1 | 2 | 4)) => n,
                        _ => return Err(format!("{spec}: coarse=N takes N = 1, 2 or 4").into()),
                    };
                }
                Some(("prefetch", d)) => {
                    let d: f32 = d.parse().map_err(|_| format!("{spec}: prefetch {d:?} is not a number"))?;
                    if !(0.0..=MAX_PREFETCH_DEG).contains(&d) {
                        return Err(format!("{spec}: prefetch must be within 0..={MAX_PREFETCH_DEG} degrees").into());
                    }
                    m.request.prefetch_deg = d;
                }
                Some(("frames", k)) => {
                    let k: usize = k.parse().map_err(|_| format!("{spec}: frames {k:?} is not a count"))?;
                    if !(1..=MAX_FRAMES).contains(&k) {
                        return Err(format!("{spec}: frames must be within 1..={MAX_FRAMES}").into());
                    }
                    m.frames = k;
                }
                _ => {
                    return Err(format!(
                        "{spec}: unknown option {p:?} (predict, guard=G, frames=K, adapt, pp=L, layers=K, rest=K, coarse=N, prefetch=D, no-preempt)"
                    )
                    .into())
                }
            }
        }
        let fills = matches!(renderer, RendererKind::SpheresFill | RendererKind::SplatFill);
        if (m.frames > 1 && !fills && renderer != RendererKind::SplatLayers) || (m.pull_push > 0 && !fills) {
            return Err(format!(
                "{spec}: frames=K and pp=L need a hole-filling renderer (splat-fill, spheres-fill, splat-layers)"
            )
            .into());
        }
        if m.adapt && !matches!(renderer, RendererKind::Splat | RendererKind::SplatFill | RendererKind::SplatLayers) {
            return Err(
                format!("{spec}: adapt (warp-sized radii) needs a splatter (splat, splat-fill, splat-layers)").into()
            );
        }
        if renderer == RendererKind::Stale && m.request != SessionRequest::NONE {
            return Err(
                format!("{spec}: the stale frame shows the frame as rendered; it cannot predict or widen").into()
            );
        }
        Ok(m)
    }

    /// The spec of core's method `m` (a spec has no watertight lever: sessions draw the
    /// layered frames with the renderer's default, core's `method::WATERTIGHT`; segments per
    /// pixel are written for the layered renderers only).
    pub fn of(m: &CoreMethod) -> MethodSpec {
        let layers = if m.renderer.draws_layers() { u32::from(m.layers) } else { 0 };
        let rest_layers = if m.renderer.draws_layers() { m.rest_layers } else { 0 };
        MethodSpec {
            renderer: m.renderer,
            request: SessionRequest {
                predict: m.predict,
                guard: m.guard,
                layers,
                coarse: m.coarse.max(1),
                rest_layers,
                prefetch_deg: m.prefetch_deg,
                preempt: true,
            },
            frames: m.frames,
            adapt: m.adapt,
            pull_push: 0,
        }
    }

    /// Core's method of the spec, for a session that asks for `session_layers` segments per
    /// pixel unless the spec says `+layers=K`.
    pub fn method(&self, session_layers: u8) -> CoreMethod {
        CoreMethod {
            renderer: self.renderer,
            layers: if self.request.layers > 0 { self.request.layers as u8 } else { session_layers },
            frames: self.frames,
            predict: self.request.predict,
            adapt: self.adapt,
            watertight: volwarp_core::method::WATERTIGHT,
            guard: self.request.guard,
            coarse: self.request.coarse,
            rest_layers: self.request.rest_layers,
            prefetch_deg: self.request.prefetch_deg,
        }
    }

    /// The spec's canonical text.
    pub fn name(&self) -> String {
        let mut s = self.renderer.name().to_string();
        if self.request.predict {
            s.push_str("+predict");
        }
        if self.request.guard > 0.0 {
            s.push_str(&format!("+guard={}", self.request.guard));
        }
        if self.frames > 1 {
            s.push_str(&format!("+frames={}", self.frames));
        }
        if self.adapt {
            s.push_str("+adapt");
        }
        if self.pull_push > 0 {
            s.push_str(&format!("+pp={}", self.pull_push));
        }
        if self.request.layers > 0 {
            s.push_str(&format!("+layers={}", self.request.layers));
        }
        if self.request.rest_layers > 0 {
            s.push_str(&format!("+rest={}", self.request.rest_layers));
        }
        if self.request.coarse > 1 {
            s.push_str(&format!("+coarse={}", self.request.coarse));
        }
        if self.request.prefetch_deg > 0.0 {
            s.push_str(&format!("+prefetch={}", self.request.prefetch_deg));
        }
        if !self.request.preempt {
            s.push_str("+no-preempt");
        }
        s
    }

    /// Makes the method with `threads` threads per renderer; `name` is what the CSV calls it.
    pub fn make(&self, name: &str, threads: usize) -> Box<dyn Method> {
        let (name, request, frames, adapt, t) = (name.to_string(), self.request, self.frames, self.adapt, threads);
        // `splat+adapt` is the splatter with every fill stage off.
        let none = FillOptions { stale: false, enclosed_only: false, pull_push_levels: 0 };
        let fill_opts = FillOptions { pull_push_levels: self.pull_push, ..FillOptions::DEFAULT };
        let fill_method = |renderer, kind, opts| -> Box<dyn Method> {
            let mut fill = HoleFill::new(renderer, kind, opts, t);
            fill.set_adaptive_radius(adapt);
            Box::new(FillMethod { name: name.clone(), request, frames, fill })
        };
        match (self.renderer, adapt) {
            (RendererKind::SplatFill, _) => fill_method(SphereSplat::new(t), RendererKind::SplatFill, fill_opts),
            (RendererKind::Splat, true) => fill_method(SphereSplat::new(t), RendererKind::Splat, none),
            (RendererKind::SpheresFill, _) => Box::new(FillMethod {
                name,
                request,
                frames,
                fill: HoleFill::new(PacketTracer::new(t), RendererKind::SpheresFill, fill_opts, t),
            }),
            (kind, _) => {
                let mut renderer = volwarp_cpu_tracer::create(kind, t).expect("parse admits only CPU renderers");
                renderer.set_adaptive_radius(adapt);
                Box::new(RendererMethod { name, request, frames, renderer })
            }
        }
    }
}

/// The methods of a comma-separated list of specs (`all`: [`ALL`]) and image-sending peers
/// (`send-image`, `downscale`, `downscale=4`: [`super::peers`]). An [`alias`] keeps its name
/// in the CSV; every other spec is named canonically.
pub fn make_methods(list: &str, threads: usize) -> Result<Vec<Box<dyn Method>>, ErrorBox> {
    let names: Vec<&str> = if list.trim() == "all" { ALL.to_vec() } else { list.split(',').collect() };
    let mut out: Vec<Box<dyn Method>> = Vec::new();
    for n in names {
        if let Some(peer) = ImagePeer::parse(n) {
            let peer = peer?;
            let name = peer.name();
            if out.iter().any(|m| m.name() == name) {
                return Err(format!("method {name} is listed twice").into());
            }
            out.push(Box::new(PeerMethod { name, peer }));
            continue;
        }
        let spec = MethodSpec::parse(n)?;
        let name = if alias(n).is_some() { n.trim().to_string() } else { spec.name() };
        if out.iter().any(|m| m.name() == name) {
            return Err(format!("method {name} is listed twice").into());
        }
        out.push(spec.make(&name, threads));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs_parse_and_name_canonically() {
        let m = MethodSpec::parse("splat-fill+frames=3+guard=0.2+predict").unwrap();
        assert_eq!(m.renderer, RendererKind::SplatFill);
        assert_eq!(
            m.request,
            SessionRequest {
                predict: true,
                guard: 0.2,
                layers: 0,
                coarse: 1,
                rest_layers: 0,
                prefetch_deg: 0.0,
                preempt: true
            }
        );
        assert_eq!(m.frames, 3);
        assert_eq!(m.name(), "splat-fill+predict+guard=0.2+frames=3");
        let a = MethodSpec::parse("splat+adapt+predict").unwrap();
        assert!(a.adapt && a.request.predict);
        assert_eq!(a.name(), "splat+predict+adapt");
        assert_eq!(MethodSpec::parse(&m.name()).unwrap(), m);
        assert_eq!(MethodSpec::parse("volwarp").unwrap(), MethodSpec::parse(&default_method()).unwrap());
        assert_eq!(MethodSpec::parse("points2").unwrap().request, SessionRequest::NONE);
        let l = MethodSpec::parse("splat-layers+layers=4+adapt+predict").unwrap();
        assert_eq!(
            l.request,
            SessionRequest {
                predict: true,
                guard: 0.0,
                layers: 4,
                coarse: 1,
                rest_layers: 0,
                prefetch_deg: 0.0,
                preempt: true
            }
        );
        assert_eq!(l.name(), "splat-layers+predict+adapt+layers=4");
        assert_eq!(MethodSpec::parse(&l.name()).unwrap(), l);
        let p = MethodSpec::parse(&format!("{}+no-preempt", default_method())).unwrap();
        assert!(!p.request.preempt && MethodSpec::parse("volwarp").unwrap().request.preempt);
        assert_eq!(p.name(), format!("{}+no-preempt", default_method()));
        assert_eq!(MethodSpec::parse(&p.name()).unwrap(), p);
        let d = MethodSpec::parse("volwarp").unwrap();
        assert_eq!((d.renderer, d.frames, d.adapt), (RendererKind::SplatLayers, 4, true));
        assert_eq!(MethodSpec::parse(&d.name()).unwrap(), d);
        assert_eq!(d.name(), default_method(), "the default is written canonically");
        assert_eq!(
            default_method(),
            "splat-layers+predict+frames=4+adapt+layers=4+coarse=2+prefetch=30",
            "the sessions' CSV name"
        );
        assert_eq!(d.method(1), CoreMethod::DEFAULT);
        let a = MethodSpec::parse("volwarp-adaptive").unwrap();
        assert_eq!(a, MethodSpec { request: SessionRequest { coarse: 2, ..d.request }, ..d });
        assert_eq!(a.name(), "splat-layers+predict+frames=4+adapt+layers=4+coarse=2+prefetch=30");
        assert_eq!(MethodSpec::parse(&a.name()).unwrap(), a);
        assert_eq!(MethodSpec::parse("volwarp-adaptive=4").unwrap().request.coarse, 4);
        assert_eq!(a.method(1).request().divisor(volwarp_core::method::Motion::Moving), 2);
        let r = MethodSpec::parse("splat-layers+predict+layers=4+rest=1").unwrap();
        assert_eq!((r.request.rest_layers, r.method(4).request().layers(false)), (1, 1));
        assert_eq!(r.name(), "splat-layers+predict+layers=4+rest=1");
        assert_eq!(MethodSpec::parse("splat-layers+rest=2").unwrap().name(), "splat-layers+rest=2");
        assert!(MethodSpec::parse("splat-layers+rest=17").is_err());
        let f = MethodSpec::parse("splat-layers+predict+prefetch=20").unwrap();
        assert_eq!((f.request.prefetch_deg, f.method(4).request().prefetch_deg), (20.0, 20.0));
        assert_eq!(f.name(), "splat-layers+predict+prefetch=20");
        assert_eq!(MethodSpec::parse(&f.name()).unwrap(), f);
        for bad in ["splat-layers+prefetch=-1", "splat-layers+prefetch=91", "splat-layers+prefetch=x"] {
            assert!(MethodSpec::parse(bad).is_err(), "{bad}");
        }
        let names: Vec<String> =
            make_methods("volwarp,volwarp-adaptive", 1).unwrap().iter().map(|m| m.name().to_string()).collect();
        assert_eq!(names, ["volwarp", "volwarp-adaptive"], "aliases keep their names");
    }

    #[test]
    fn bad_specs_are_clear_errors() {
        for bad in [
            "nope",
            "spheres-gpu",
            "splat+guard=0.7",
            "splat+guard=x",
            "splat+frames=2",
            "splat-fill+frames=0",
            "splat-fill+frames=99",
            "splat+zoom",
            "stale+predict",
            "points2+adapt",
            "spheres-fill+adapt",
            "splat+pp=2",
            "splat-fill+pp=9",
            "splat-layers+layers=0",
            "splat-layers+layers=17",
            "splat-layers+layers=x",
            "splat-layers+pp=2",
            "splat-layers+frames=9",
            "points2+frames=2",
            "splat-layers+coarse=3",
            "splat-layers+coarse=x",
            "stale+coarse=2",
        ] {
            assert!(MethodSpec::parse(bad).is_err(), "{bad}");
        }
        assert!(make_methods("splat,splat", 1).is_err());
    }
}
