//! The method: how a client draws what it receives and what it asks the server for, defined
//! once. The window client's options, its writer thread and the evaluation's session simulator
//! all start from [`Method::DEFAULT`] and ask through one [`RequestPolicy`].
//!
//! A method is a renderer of the registry plus the levers around it: the segments per pixel it
//! asks for (`layers`), how many of the newest frames it keeps (`frames`), whether it asks for
//! the camera predicted for when the frame is shown (`predict`, [`crate::prediction`]), whether
//! it sizes footprints by how far the view moved (`adapt`, [`crate::warp_radius`]), the
//! watertight tolerance of the layered renderers (`watertight`) and the guard band it asks for
//! (`guard`, [`crate::guard`]).
//!
//! The request policy says **when** a client sends a camera request ([`RequestPolicy::due`])
//! and **which** camera it asks for ([`RequestPolicy::camera`]). What differs between callers
//! (the window client and the simulator) is explicit in a [`Cadence`]: the display tick the
//! horizon assumes, whether a frame's arrival alone triggers a request, whether the first still
//! display tick after motion does, and the largest viewport a guard band may widen to.
//!
//! **Adaptive resolution** (`coarse`): while the view moves, the client asks for its camera on
//! a pixel grid `coarse` times coarser per axis (the same field of view, `1/coarse²` of the
//! pixels, so the frame is marched, encoded and sent sooner) and warps it at display
//! resolution, each segment drawn as its coarse source pixel's footprint; the first request
//! after the view rests asks for the full resolution. While the view turns fast
//! ([`Motion::Fast`]: it would turn [`FAST_WARP_DEG`] or more before a frame on that grid could
//! come), requests ask for a grid [`FAST_COARSE`] times coarser again: every tick warps the
//! frame on screen further, so the sooner the next comes, the better. The client decides, not
//! the server: it
//! alone knows whether its view moves (a predicting client's still request differs from its
//! last predicted one, so a server comparing successive requests would call it moving).
//!
//! **Exact at rest** (`rest_layers`): the request for a view at rest may ask for `rest_layers`
//! segments per pixel (the CameraRequest's byte 57, wire version 5): 1, a one-sample frame, is
//! the server's own image at its camera, exact when shown there, and a fifth to a third of a
//! layered frame's bytes, so it arrives sooner; requests while the view moves ask for the
//! Hello's `layers`. The default asks for the Hello's at rest too ([`REST_LAYERS`]): the next
//! move warps the rest frame, and a one-sample frame warps worse.

use crate::camera::Camera;
use crate::guard::GuardBand;
use crate::prediction::{Horizon, Predictor};
use crate::renderer_kind::RendererKind;
use crate::segments::DEFAULT_LAYERS;

/// The default watertight tolerance of the layered renderers, in source pixels: where the
/// depths of neighbouring segments of one slab lie within it, they share their footprints'
/// corners (0: off). Measured with the slab's optical depth scaled by its footprint's area
/// (`docs/results.md`, "Watertight slabs").
pub const WATERTIGHT: f32 = 5.0;

/// The most frames a method keeps (the newest included); renderers given more use the newest
/// this many.
pub const MAX_FRAMES: usize = 8;

/// A method: a renderer and the levers of the client around it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Method {
    /// The renderer of the registry that draws.
    pub renderer: RendererKind,
    /// Segments per pixel the client asks the server for (1 to `segments::MAX_LAYERS`).
    pub layers: u8,
    /// How many of the newest frames it keeps (at least 1; renderers that do not keep frames
    /// draw the newest alone).
    pub frames: usize,
    /// Ask for the camera predicted for when the frame is shown.
    pub predict: bool,
    /// Size footprints by how far the view moved from the frame's camera.
    pub adapt: bool,
    /// Watertight tolerance of the layered renderers, in source pixels (0: off).
    pub watertight: f32,
    /// Guard band: the fraction of the view added on every side of the camera asked for.
    pub guard: f32,
    /// Adaptive resolution: the viewport divisor per axis while the view moves (1: always the
    /// full resolution; at most [`MAX_COARSE`]).
    pub coarse: u8,
    /// Segments per pixel asked for the view at rest (0: `layers`, as while it moves).
    pub rest_layers: u8,
    /// Side views asked for while the view rests, degrees along the orbit either way (0: none;
    /// [`RequestPolicy::prefetch`]).
    pub prefetch_deg: f32,
}

/// The largest viewport divisor of adaptive resolution.
pub const MAX_COARSE: u8 = 4;

/// While the view turns fast ([`FAST_WARP_DEG`]), requests ask for a grid this many times
/// coarser than [`Method::coarse`] (at most [`MAX_COARSE`]; only with adaptive resolution on):
/// a fast flick from rest warped the rest frame 36° and more before the first half-grid frame
/// came, and the last one 28° before the next. Measured (`docs/results.md`, "Adaptive
/// resolution").
pub const FAST_COARSE: u8 = 2;

/// How far (degrees) the view must turn before a frame on the moving grid could come (the
/// predictor's turn rate times that grid's horizon) for a request to ask for the coarser grid
/// of [`FAST_COARSE`]: a slower move keeps the sharper grid (at 512² the 30°/s sessions turn
/// 8–15° in that time, and the quarter grid's blur cost more there than its fresher frames
/// gained: `docs/results.md`, "Adaptive resolution").
pub const FAST_WARP_DEG: f32 = 20.0;

/// How the view moves when a request is sent: what adaptive resolution's grid depends on
/// ([`RequestPolicy::motion`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Motion {
    /// The view holds still: the full resolution.
    Rest,
    /// The view moves: the moving grid.
    Moving,
    /// The view turns fast: the coarser grid of [`FAST_COARSE`].
    Fast,
}

impl Motion {
    /// Whether the view moves.
    pub fn moving(self) -> bool {
        self != Motion::Rest
    }
}

/// The segments per pixel the default method asks for the view at rest: 0, the Hello's, as
/// while it moves. Measured against 1 (`docs/results.md`, "Against the image-sending peers",
/// 20 sessions at 512²): the one-sample rest frame arrives sooner and is exact, but the next move
/// warps it, and the pooled p95 ꟻLIP rose from 0.0357 to 0.0385 at 100 Mbit/s (equal at 20).
pub const REST_LAYERS: u8 = 0;

/// The default's adaptive resolution: while the view moves, frames on a grid 2 times coarser
/// per axis (a quarter of the pixels), at rest the full one. Measured (`docs/results.md`,
/// "Adaptive resolution"): over 20 sessions at 512² the pooled ꟻLIP falls from 0.153× to 0.128×
/// the stale frame's at 100 Mbit/s and from 0.185× to 0.140× at 20, at 1024² from 0.171× to
/// 0.114× and from 0.318× to 0.138×.
pub const DEFAULT_COARSE: u8 = 2;

impl Method {
    /// The method a client runs by default, chosen on the session results (`docs/results.md`,
    /// "Layered frames as the default" and "Adaptive resolution"): the layered splatter on 4
    /// segments per pixel, the 4 newest frames kept, prediction and warp-grown footprints on,
    /// watertight slabs, no guard band, frames on a grid half as fine per axis while the view
    /// moves ([`DEFAULT_COARSE`]).
    pub const DEFAULT: Method = Method {
        renderer: RendererKind::DEFAULT,
        layers: Method::layers_for(RendererKind::DEFAULT),
        frames: 4,
        predict: true,
        adapt: true,
        watertight: WATERTIGHT,
        guard: 0.0,
        coarse: DEFAULT_COARSE,
        rest_layers: REST_LAYERS,
        prefetch_deg: PREFETCH_DEG,
    };

    /// The segments per pixel a renderer asks for unless told otherwise: the layered renderers
    /// `segments::DEFAULT_LAYERS`, the others one.
    pub const fn layers_for(renderer: RendererKind) -> u8 {
        if renderer.draws_layers() {
            DEFAULT_LAYERS as u8
        } else {
            1
        }
    }

    /// What it asks the server for.
    pub const fn request(&self) -> RequestPolicy {
        RequestPolicy {
            predict: self.predict,
            guard: self.guard,
            coarse: self.coarse,
            rest_layers: self.rest_layers,
            prefetch_deg: self.prefetch_deg,
        }
    }
}

/// What a client asks the server for: the camera it shows or the one it expects to show when
/// the frame is on screen (`predict`), widened by a guard band of `guard` of its size on every
/// side.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RequestPolicy {
    /// Ask for the predicted camera.
    pub predict: bool,
    /// Guard band fraction (0: none).
    pub guard: f32,
    /// Viewport divisor per axis while the view moves (0 and 1: always full resolution).
    pub coarse: u8,
    /// Segments per pixel asked for the view at rest (0: the Hello's, as while it moves).
    pub rest_layers: u8,
    /// Side views asked for while the view rests, degrees along the orbit either way (0:
    /// none; [`RequestPolicy::prefetch`]).
    pub prefetch_deg: f32,
}

/// The caller's side of the request policy: what the policy assumes about the display and
/// which events trigger a request.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cadence {
    /// The display tick, in seconds, that the prediction horizon takes off (`Horizon::seconds`).
    pub display_tick_s: f32,
    /// A frame's arrival alone triggers a request (so the server always has work).
    pub on_frame_arrival: bool,
    /// A predicting client sends one more request at the first still display tick after
    /// motion (so the server renders the still view, not the overshoot of the last prediction).
    pub on_first_still: bool,
    /// The largest viewport a guard band may widen the camera to.
    pub max_viewport: u32,
}

/// What happened since the client's last request.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ViewEvents {
    /// The view shown changed.
    pub moved: bool,
    /// The view holds still for the first display tick after it moved.
    pub first_still: bool,
    /// A frame arrived.
    pub frame_arrived: bool,
}

/// The camera a request carries, with the view it shows exactly.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Requested {
    /// The camera sent (guard band included).
    pub camera: Camera,
    /// The (predicted) view asked for, before the guard band.
    pub view: Camera,
    /// Where `view`'s pixels start in `camera`'s (`(0, 0)` without a guard band).
    pub guard_offset: (u32, u32),
    /// Segments per pixel asked for (the CameraRequest's `layers`; 0: the Hello's).
    pub layers: u8,
    /// The divisor per axis of the grid `view` is on (1: the full resolution;
    /// [`RequestPolicy::divisor_for`]).
    pub divisor: u32,
}

impl RequestPolicy {
    /// Asks for the camera shown, as it is (what a send-image system does).
    pub const NONE: RequestPolicy =
        RequestPolicy { predict: false, guard: 0.0, coarse: 1, rest_layers: 0, prefetch_deg: 0.0 };

    /// Whether the client sends a request now: when the view moved; when a frame arrived, if
    /// the cadence says so; and when the view holds still for the first tick after motion, if
    /// the cadence says so and the client predicts.
    pub fn due(&self, cadence: &Cadence, events: ViewEvents) -> bool {
        events.moved
            || (cadence.on_frame_arrival && events.frame_arrived)
            || (cadence.on_first_still && self.predict && events.first_still)
    }

    /// The camera to ask for when the view shown is `shown`: with `predict`, what the
    /// `predictor` (which has seen every camera shown) expects after the measured `horizon`
    /// (less the cadence's display tick); with a guard band, that camera widened (where it
    /// fits the cadence's largest viewport).
    pub fn camera(&self, shown: Camera, predictor: &Predictor, horizon: &Horizon, cadence: &Cadence) -> Requested {
        self.camera_at(shown, Motion::Rest, predictor, horizon, cadence)
    }

    /// The motion of a request for a view that is `moving` or not: [`Motion::Fast`] where it
    /// would turn at least [`FAST_WARP_DEG`] before a frame on the moving grid could come (the
    /// `predictor`'s turn rate times the `horizon` of that grid), else [`Motion::Moving`].
    pub fn motion(&self, moving: bool, predictor: &Predictor, horizon: &Horizon, cadence: &Cadence) -> Motion {
        if !moving {
            return Motion::Rest;
        }
        let wait_s = horizon.seconds(cadence.display_tick_s, self.divisor(Motion::Moving));
        if predictor.turn_rate_deg_s() * wait_s >= FAST_WARP_DEG {
            Motion::Fast
        } else {
            Motion::Moving
        }
    }

    /// The viewport divisor per axis of a request: `coarse` while the view moves,
    /// [`FAST_COARSE`] times that (at most [`MAX_COARSE`]) while it turns fast, 1 at rest.
    pub fn divisor(&self, motion: Motion) -> u32 {
        let coarse = u32::from(self.coarse.clamp(1, MAX_COARSE));
        match motion {
            Motion::Rest => 1,
            Motion::Moving => coarse,
            Motion::Fast if coarse > 1 => (coarse * u32::from(FAST_COARSE)).min(u32::from(MAX_COARSE)),
            Motion::Fast => 1,
        }
    }

    /// [`RequestPolicy::divisor`] for a `width × height` view, halved (down to 1) while the
    /// coarse grid would be less than [`MIN_COARSE_SIDE`] pixels on its shorter side.
    pub fn divisor_for(&self, motion: Motion, width: u32, height: u32) -> u32 {
        let mut d = self.divisor(motion).max(1);
        while d > 1 && width.min(height) / d < MIN_COARSE_SIDE {
            d /= 2;
        }
        d
    }

    /// [`RequestPolicy::camera`] for a view in `motion` (moving: it changed since the last
    /// request): while moving, the camera asked for (the guard band's too) is on a pixel grid
    /// [`RequestPolicy::divisor_for`] times coarser per axis ([`coarse_viewport`]); at rest it
    /// asks for [`RequestPolicy::layers`] segments per pixel.
    pub fn camera_at(
        &self,
        shown: Camera,
        motion: Motion,
        predictor: &Predictor,
        horizon: &Horizon,
        cadence: &Cadence,
    ) -> Requested {
        let mut view = shown;
        let d = self.divisor_for(motion, shown.width, shown.height);
        if self.predict {
            view = predictor.predict(horizon.seconds(cadence.display_tick_s, d)).unwrap_or(shown);
        }
        if d > 1 {
            let (w, h) = coarse_viewport(view.width, view.height, d);
            view = view.with_viewport(w, h);
        }
        let layers = self.layers(motion.moving());
        match GuardBand::new(&view, self.guard, cadence.max_viewport) {
            Ok(g) if self.guard > 0.0 => {
                Requested { camera: g.camera, view, guard_offset: (g.x0, g.y0), layers, divisor: d }
            }
            _ => Requested { camera: view, view, guard_offset: (0, 0), layers, divisor: d },
        }
    }

    /// The side views of a view at rest: `rest` orbited [`RequestPolicy::prefetch_deg`]
    /// one way along its orbit, then the other (`None` where prefetching is off or the angle
    /// is not a finite positive number).
    pub fn side_views(&self, rest: &Camera) -> Option<[Camera; 2]> {
        let d = self.prefetch_deg;
        if !(d.is_finite() && d > 0.0) {
            return None;
        }
        let d = d.min(MAX_PREFETCH_DEG);
        Some([rest.orbit(d, 0.0), rest.orbit(-d, 0.0)])
    }

    /// What to ask for next while the view `rest` holds still and the client holds frames for
    /// the views `held` (newest first): where one shows `rest` exactly (its frame has arrived),
    /// the first of its [`RequestPolicy::side_views`] no held frame shows, at full resolution
    /// and with the segments a moving view asks for ([`RequestPolicy::layers`]: a side view is
    /// there to be warped, whatever `rest_layers` asks for the view at rest); `None` where the rest frame has
    /// not arrived, every side view is held, or prefetching is off. A turn that starts from
    /// rest then warps the side view nearest the camera (core's `show::choose`) instead of the
    /// rest frame, until the move's first frame arrives.
    pub fn prefetch(&self, rest: &Camera, held: &[Camera]) -> Option<Requested> {
        if !held.contains(rest) {
            return None;
        }
        let side = self.side_views(rest)?.into_iter().find(|s| s != rest && !held.contains(s))?;
        Some(Requested { camera: side, view: side, guard_offset: (0, 0), layers: self.layers(true), divisor: 1 })
    }

    /// The segments per pixel a request asks for (the CameraRequest's `layers`, 0: the
    /// Hello's): `rest_layers` when the view is not `moving`, else 0.
    pub fn layers(&self, moving: bool) -> u8 {
        if moving {
            0
        } else {
            self.rest_layers.min(crate::wire::MAX_LAYERS as u8)
        }
    }
}

/// The side views a client asks for while the view rests lie this many degrees along the
/// orbit either way ([`RequestPolicy::prefetch`]): until a turn's first frame arrives (0.15 s
/// after the first moving request at 512², 500 ms server, 100 Mbit/s) the client warps the
/// frame it had, and a fast flick (180°/s) has turned 30° by then; the side view there is
/// nearly its camera. Measured (`docs/results.md`, "Side views at rest").
pub const PREFETCH_DEG: f32 = 30.0;

/// The largest angle of the side views.
pub const MAX_PREFETCH_DEG: f32 = 90.0;

/// How many of the newest frames' views a client passes to [`RequestPolicy::prefetch`]: the
/// resting view's and its two side views'.
pub const PREFETCH_HELD: usize = 3;

/// The fewest pixels the coarse grid of adaptive resolution keeps on its shorter side: a
/// smaller view stays at full resolution while it moves (its frame is marched and sent in a few
/// milliseconds, and a coarser one would blur it; the default's adaptive resolution was
/// measured at 512² and 1024²).
pub const MIN_COARSE_SIDE: u32 = 128;

/// The viewport `width × height` divided by `divisor` per axis, rounded to the nearest pixel
/// and at least 1 (the same field of view on the coarser grid; the aspect ratio is kept to
/// within half a coarse pixel).
pub fn coarse_viewport(width: u32, height: u32, divisor: u32) -> (u32, u32) {
    let d = divisor.max(1);
    let div = |v: u32| ((v + d / 2) / d).max(1);
    (div(width), div(height))
}

#[cfg(test)]
mod tests {
    use super::*;

    const CLIENT: Cadence =
        Cadence { display_tick_s: 1.0 / 60.0, on_frame_arrival: true, on_first_still: false, max_viewport: 4096 };
    const SIMULATOR: Cadence =
        Cadence { display_tick_s: 1.0 / 30.0, on_frame_arrival: false, on_first_still: true, max_viewport: 4096 };

    #[test]
    fn the_default_is_the_layered_method() {
        let d = Method::DEFAULT;
        assert_eq!(d.renderer, RendererKind::SplatLayers);
        assert_eq!(d.layers as usize, DEFAULT_LAYERS);
        assert_eq!((d.frames, d.predict, d.adapt, d.guard), (4, true, true, 0.0));
        assert_eq!(
            d.request(),
            RequestPolicy { predict: true, guard: 0.0, coarse: 2, rest_layers: 0, prefetch_deg: PREFETCH_DEG }
        );
        assert_eq!(Method::layers_for(RendererKind::Splat), 1);
    }

    #[test]
    fn requests_are_due_on_the_cadences_events() {
        let p = Method::DEFAULT.request();
        let moved = ViewEvents { moved: true, ..ViewEvents::default() };
        let arrived = ViewEvents { frame_arrived: true, ..ViewEvents::default() };
        let still = ViewEvents { first_still: true, ..ViewEvents::default() };
        for c in [CLIENT, SIMULATOR] {
            assert!(p.due(&c, moved));
            assert!(!p.due(&c, ViewEvents::default()));
        }
        assert!(p.due(&CLIENT, arrived) && !p.due(&SIMULATOR, arrived));
        assert!(!p.due(&CLIENT, still) && p.due(&SIMULATOR, still));
        assert!(!RequestPolicy::NONE.due(&SIMULATOR, still), "only a predicting client asks again when still");
    }

    #[test]
    fn without_prediction_or_guard_the_shown_camera_is_asked_for() {
        let cam = Camera::look_at(glam::Vec3::new(0.0, 0.0, 3.0), glam::Vec3::ZERO, glam::Vec3::Y, 45.0, 64, 48);
        let mut predictor = Predictor::new();
        predictor.observe(cam, 0.0);
        let r = RequestPolicy::NONE.camera(cam, &predictor, &Horizon::new(), &CLIENT);
        assert_eq!((r.camera, r.view, r.guard_offset, r.layers), (cam, cam, (0, 0), 0));
        let wide =
            RequestPolicy { guard: 0.25, ..RequestPolicy::NONE }.camera(cam, &predictor, &Horizon::new(), &CLIENT);
        assert_eq!(wide.view, cam);
        assert!(wide.camera.width > cam.width && wide.guard_offset.0 > 0);
    }

    #[test]
    fn adaptive_resolution_is_coarse_while_moving_and_full_at_rest() {
        let cam = Camera::look_at(glam::Vec3::new(0.0, 0.0, 3.0), glam::Vec3::ZERO, glam::Vec3::Y, 45.0, 512, 384);
        let mut predictor = Predictor::new();
        predictor.observe(cam, 0.0);
        let h = Horizon::new();
        let p = RequestPolicy { coarse: 2, ..RequestPolicy::NONE };
        let moving = p.camera_at(cam, Motion::Moving, &predictor, &h, &CLIENT);
        assert_eq!((moving.camera.width, moving.camera.height), (256, 192));
        assert_eq!(moving.camera, cam.with_viewport(256, 192), "the same view on a coarser grid");
        assert_eq!(moving.view, moving.camera);
        let still = p.camera_at(cam, Motion::Rest, &predictor, &h, &CLIENT);
        assert_eq!((moving.divisor, still.divisor), (2, 1), "the grid each asks for");
        assert_eq!(still.camera, cam, "at rest: the full resolution");
        assert_eq!(p.camera(cam, &predictor, &h, &CLIENT), still);
        assert_eq!((p.divisor(Motion::Moving), p.divisor(Motion::Rest)), (2, 1));
        assert_eq!(RequestPolicy { coarse: 9, ..p }.divisor(Motion::Moving), u32::from(MAX_COARSE));
        assert_eq!(RequestPolicy { coarse: 0, ..p }.divisor(Motion::Moving), 1);
        assert_eq!(Method::DEFAULT.request().divisor(Motion::Moving), 2, "the default is coarse while moving");
        // A small view stays at full resolution.
        assert_eq!(p.divisor_for(Motion::Moving, 512, 384), 2);
        assert_eq!(p.divisor_for(Motion::Moving, 255, 1000), 1);
        assert_eq!(p.divisor_for(Motion::Moving, 256, 256), 2);
        assert_eq!(p.divisor_for(Motion::Rest, 1024, 1024), 1);
        // While the view turns fast: twice as coarse again, at most 4, and halved while the grid
        // would be too small.
        assert_eq!(p.divisor(Motion::Fast), 4);
        assert_eq!(RequestPolicy { coarse: 4, ..p }.divisor(Motion::Fast), 4);
        assert_eq!(RequestPolicy { coarse: 1, ..p }.divisor(Motion::Fast), 1, "adaptive resolution off");
        assert_eq!(p.divisor_for(Motion::Fast, 512, 512), 4);
        assert_eq!(p.divisor_for(Motion::Fast, 384, 300), 2);
        assert_eq!(p.divisor_for(Motion::Fast, 255, 255), 1);
        assert_eq!(p.camera_at(cam, Motion::Fast, &predictor, &h, &CLIENT).camera, cam.with_viewport(256, 192));
        let square = cam.with_viewport(512, 512);
        let starting = p.camera_at(square, Motion::Fast, &predictor, &h, &CLIENT);
        assert_eq!(starting.camera, square.with_viewport(128, 128));
        assert_eq!(starting.divisor, 4);
        assert_eq!(starting.layers, 0, "turning fast: the Hello's layers");
        let small = cam.with_viewport(200, 150);
        assert_eq!(p.camera_at(small, Motion::Moving, &predictor, &h, &CLIENT).camera, small);
        // A guard band on the coarse grid keeps its fraction of the coarse view.
        let g = RequestPolicy { guard: 0.25, ..p }.camera_at(cam, Motion::Moving, &predictor, &h, &CLIENT);
        assert_eq!((g.view.width, g.view.height), (256, 192));
        assert!(g.camera.width > 256 && g.guard_offset.0 > 0 && g.guard_offset.0 < 128);
        assert_eq!(coarse_viewport(801, 601, 2), (401, 301));
        assert_eq!(coarse_viewport(3, 1, 4), (1, 1));
        assert_eq!(coarse_viewport(64, 48, 1), (64, 48));
    }

    #[test]
    fn a_fast_turn_asks_for_the_coarser_grid() {
        let cam = Camera::look_at(glam::Vec3::new(0.0, 0.0, 3.0), glam::Vec3::ZERO, glam::Vec3::Y, 45.0, 512, 512);
        let turned = |deg: f32| {
            let r = deg.to_radians();
            Camera::look_at(
                glam::Vec3::new(3.0 * r.sin(), 0.0, 3.0 * r.cos()),
                glam::Vec3::ZERO,
                glam::Vec3::Y,
                45.0,
                512,
                512,
            )
        };
        // A frame 0.6 s from request to arrival: the moving grid's horizon is about 0.44 s (half
        // the span, and half of half the interval).
        let mut h = Horizon::new();
        h.observe(-0.6, 0.0, 0.0, 1);
        let p = Method::DEFAULT.request();
        let motion = |rate: f32, h: &Horizon| {
            let mut predictor = Predictor::new();
            predictor.observe(cam, 0.0);
            predictor.observe(turned(rate / 30.0), 1.0 / 30.0);
            p.motion(true, &predictor, h, &CLIENT)
        };
        assert_eq!(motion(180.0, &h), Motion::Fast);
        assert_eq!(motion(30.0, &h), Motion::Moving, "30°/s turns 13° in 0.44 s");
        // Frames on the moving grid that come in 0.1 s (horizon about 0.14 s): 180°/s turns 25°,
        // 120°/s 17°.
        let mut quick = h;
        quick.observe(0.9, 1.0, 0.0, 2);
        assert_eq!((motion(180.0, &quick), motion(120.0, &quick)), (Motion::Fast, Motion::Moving));
        let still = Predictor::new();
        assert_eq!(p.motion(false, &still, &h, &CLIENT), Motion::Rest);
        assert_eq!(p.motion(true, &still, &h, &CLIENT), Motion::Moving, "no turn rate yet");
        // Without adaptive resolution every grid is the full one.
        let full = RequestPolicy { coarse: 1, ..p };
        assert_eq!(full.divisor(motion(180.0, &h)), 1);
    }

    #[test]
    fn a_view_at_rest_may_ask_for_one_sample_and_a_moving_view_asks_for_the_hellos_layers() {
        let cam = Camera::look_at(glam::Vec3::new(0.0, 0.0, 3.0), glam::Vec3::ZERO, glam::Vec3::Y, 45.0, 64, 48);
        let mut predictor = Predictor::new();
        predictor.observe(cam, 0.0);
        let h = Horizon::new();
        let p = RequestPolicy { rest_layers: 1, ..Method::DEFAULT.request() };
        assert_eq!(p.camera_at(cam, Motion::Rest, &predictor, &h, &SIMULATOR).layers, 1, "at rest: a one-sample frame");
        assert_eq!(
            p.camera_at(cam, Motion::Moving, &predictor, &h, &SIMULATOR).layers,
            0,
            "moving: the Hello's layers"
        );
        assert_eq!(p.camera(cam, &predictor, &h, &CLIENT).layers, 1);
        let layered = Method::DEFAULT.request();
        assert_eq!(
            layered.camera_at(cam, Motion::Rest, &predictor, &h, &SIMULATOR).layers,
            0,
            "the default: the Hello's, at rest too"
        );
        assert_eq!(RequestPolicy { rest_layers: 200, ..p }.layers(false), crate::wire::MAX_LAYERS as u8);
    }

    #[test]
    fn side_views_are_asked_for_once_the_rest_frame_is_held_one_at_a_time() {
        let rest = Camera::look_at(glam::Vec3::new(0.0, 0.0, 3.0), glam::Vec3::ZERO, glam::Vec3::Y, 40.0, 64, 64);
        let p = Method::DEFAULT.request();
        let sides = p.side_views(&rest).unwrap();
        assert_eq!(sides, [rest.orbit(PREFETCH_DEG, 0.0), rest.orbit(-PREFETCH_DEG, 0.0)]);
        for s in &sides {
            assert!((crate::warp_radius::warp_angle_deg(&rest, s) - PREFETCH_DEG).abs() < 0.5);
        }
        // Not before the rest frame has arrived.
        assert_eq!(p.prefetch(&rest, &[]), None);
        assert_eq!(p.prefetch(&rest, &[rest.orbit(5.0, 0.0)]), None);
        // Then one side after the other, each exact at full resolution, layered as a moving
        // view's frames even where the view at rest asks for one sample per pixel.
        let first = RequestPolicy { rest_layers: 1, ..p }.prefetch(&rest, &[rest]).unwrap();
        assert_eq!((first.camera, first.view, first.divisor, first.guard_offset), (sides[0], sides[0], 1, (0, 0)));
        assert_eq!(first.layers, 0, "the Hello's segments per pixel");
        assert_eq!(p.prefetch(&rest, &[sides[0], rest]).unwrap().view, sides[1]);
        assert_eq!(p.prefetch(&rest, &[sides[1], sides[0], rest]), None, "both held: nothing more");
        // Off, or a nonsense angle: none.
        let off = RequestPolicy { prefetch_deg: 0.0, ..p };
        assert!(off.side_views(&rest).is_none() && off.prefetch(&rest, &[rest]).is_none());
        assert!(RequestPolicy { prefetch_deg: f32::NAN, ..p }.side_views(&rest).is_none());
        let wide = RequestPolicy { prefetch_deg: 1e9, ..p }.side_views(&rest).unwrap();
        assert!((crate::warp_radius::warp_angle_deg(&rest, &wide[0]) - MAX_PREFETCH_DEG).abs() < 0.5);
    }
}
