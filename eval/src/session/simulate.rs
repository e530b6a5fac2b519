//! The simulated clock and the event loop of one session.
//!
//! Nothing here reads the wall clock: every time is simulated, in milliseconds, from the
//! models; the same inputs give the same rows, bit for bit.
//!
//! 1. **Display ticks** at `k / display_hz`; the camera of tick `k` is the path's. At time 0
//!    the client already holds a frame for the first camera (the user looks at a finished
//!    image, then starts to move), and a client asking for side views at rest
//!    (`RequestPolicy::prefetch`) holds theirs too. At every later tick whose camera differs
//!    from the last one sent, the client sends a request, which reaches the server
//!    `latency_ms` later; while the camera rests, at the first tick after a frame arrives with
//!    no request waiting, a client asking for side views asks for the next one its frames lack.
//! 2. **Server**: when idle, it takes the newest request that arrived and that it has not
//!    served yet (waiting for one if there is none), lets its [`ServerPolicy`] pick the camera,
//!    renders the frame (the real marcher, so the frame's real sample count and bytes) in
//!    `server_ms`, writes it to the link (blocking; the frame's bytes in the session's encoding
//!    as the server encodes it, `volwarp_server::encoding::encode_frame`, at `mbps`) and
//!    only then takes the next request. The frame arrives `latency_ms` after the write ends.
//! 3. **Client**: each method draws for the camera of a tick with the newest frame arrived by
//!    then. A draw of `d` ms takes `ceil(d / tick)` ticks (at least one); a draw that fits in one
//!    tick is shown at the tick it started at, a slower one is shown when done and its previous
//!    image stays up until then. Which of the frames the method keeps it shows, and how, is
//!    core's frame choice (`volwarp_core::show`, as the window's display loop makes it): a kept
//!    frame whose view equals the camera is shown as rendered (`exact_when_still`; warping
//!    starts when the camera moves), else the kept frames are warped nearest first, else
//!    (every frame beyond `show::FALLBACK_DEG`) the nearest frame is shown as rendered.
//! 4. **Scoring** every `score_every`-th tick: the truth (the marcher's image for that tick's
//!    camera and visual state, cached between methods and runs) against what each method shows.
//! 5. **Visual edits** (`wl-drag`): each tick has a visual state ([`Looks`]). A tick whose
//!    state changed sends a request (the window sends an edit before its next camera
//!    request); the server renders each frame with the state of the newest request it serves.
//!    The client shows what the window client shows: the newest frame that arrived, warped,
//!    even while its state is older than the tick's (the window says `updating…`), and never
//!    a drawing that mixes states (older frames of another state are not drawn with it).

use super::methods::{HeldFrame, Method, SessionRequest};
use super::model::{ClientModel, NetworkModel, Request, ServerPolicy};
use super::paths::{CameraPath, MAX_RECORDED_VIEWPORT, WL_FROM};
use super::peers::{self, ImageStream, ResolutionCost};
use crate::{ErrorBox, Metrics};
use rayon::prelude::*;
use std::collections::HashMap;
use volwarp_core::compact_frame::Encoding;
use volwarp_core::method::{Cadence, Requested, ViewEvents};
use volwarp_core::prediction::{Horizon, Predictor};
use volwarp_core::renderer::Renderer;
use volwarp_core::show::{self, Show};
use volwarp_core::wire::{self, CameraRequest};
use volwarp_core::{Camera, Heuristic, Image, RendererKind};
use volwarp_server::encoding::encode_frame;
use volwarp_server::visual::VisualState;
use volwarp_server::Marcher;

/// What a session runs with besides the dataset, the path and the methods.
#[derive(Clone, Debug, PartialEq)]
pub struct SessionConfig {
    /// Viewport side (square).
    pub size: u32,
    /// Length of the session, seconds (a recorded path uses its own length, at most this).
    pub duration_s: f64,
    /// Server and network.
    pub net: NetworkModel,
    /// Display rate and draw times.
    pub client: ClientModel,
    /// Score every n-th display tick (1: every tick).
    pub score_every: usize,
    /// The frames' depth heuristic.
    pub heuristic: Heuristic,
    /// Show the frame itself where the camera equals the frame's camera.
    pub exact_when_still: bool,
    /// The frames' wire encoding (the server's default is compact).
    pub encoding: Encoding,
    /// Segments per pixel of the frames (1: one sample per pixel).
    pub layers: u32,
    /// The server's time at reduced resolutions, as a fraction of the full one's (measured).
    pub resolution_cost: ResolutionCost,
}

impl SessionConfig {
    /// Checks the figures (a clear error for each bad one).
    pub fn check(&self) -> Result<(), ErrorBox> {
        self.net.check()?;
        if self.size == 0 || self.size > MAX_RECORDED_VIEWPORT {
            return Err(format!("size must be 1..={MAX_RECORDED_VIEWPORT} (got {})", self.size).into());
        }
        if !self.duration_s.is_finite() || self.duration_s <= 0.0 || self.duration_s > 3600.0 {
            return Err(format!("duration must be in (0, 3600] s (got {})", self.duration_s).into());
        }
        if !self.client.display_hz.is_finite() || self.client.display_hz <= 0.0 || self.client.display_hz > 1000.0 {
            return Err(format!("display rate must be in (0, 1000] Hz (got {})", self.client.display_hz).into());
        }
        if self.score_every == 0 {
            return Err("score-every must be at least 1".into());
        }
        Ok(())
    }
}

/// One frame the server sent.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameEvent {
    /// The visual state it was rendered with (an index into the session's [`Looks`]).
    pub state: usize,
    /// 0 for the frame the client holds at the start, then 1, 2, …
    pub seq: usize,
    /// The camera it was rendered for (guard band included).
    pub camera: Camera,
    /// The view it shows exactly: the (predicted) camera asked for, before the guard band.
    pub view: Camera,
    /// Where `view`'s pixels start in the frame's (`(0, 0)` without a guard band).
    pub guard_offset: (u32, u32),
    /// The viewport divisor per axis it was rendered with: 1 for the display's grid, more for
    /// adaptive resolution's coarser grids (and a peer's reduced images).
    pub divisor: u32,
    /// When the newest request it serves was sent, ms.
    pub request_ms: f64,
    /// When rendering started, ms.
    pub start_ms: f64,
    /// The server's time for it, ms (what its header reports as `render_us`).
    pub render_ms: f64,
    /// Encoded bytes on the wire.
    pub bytes: u64,
    /// When it arrived at the client, ms.
    pub arrive_ms: f64,
}

impl FrameEvent {
    /// Whether the client holds it at time 0 (the first frame, and with side views at rest
    /// theirs; [`FrameEvent::at_start`]) rather than the server sending it during the session.
    pub fn held_at_start(&self) -> bool {
        self.arrive_ms <= 0.0
    }

    /// The frame the client holds at time 0: rendered for the first camera as shown, in the
    /// first tick's visual state `state`, in `render_ms`, `bytes` long.
    pub fn at_start(camera: Camera, render_ms: f64, bytes: u64, state: usize) -> FrameEvent {
        FrameEvent {
            state,
            seq: 0,
            camera,
            view: camera,
            guard_offset: (0, 0),
            divisor: 1,
            request_ms: 0.0,
            start_ms: 0.0,
            render_ms,
            bytes,
            arrive_ms: 0.0,
        }
    }
}

/// What the volume looks like over a session: the distinct visual states the user set (the
/// window and level, fractions of the value range), each with its marcher, and each display
/// tick's state. A path that edits nothing has one state, the dataset's marcher itself.
pub struct Looks {
    states: Vec<([f32; 2], Marcher)>,
    at_tick: Vec<usize>,
}

impl Looks {
    /// One state for every tick: `marcher` as it is.
    pub fn fixed(marcher: &Marcher, ticks: usize) -> Looks {
        Looks { states: vec![(WL_FROM, marcher.clone())], at_tick: vec![0; ticks] }
    }

    /// The states of `path` over `ticks` display ticks at `display_hz`: the marcher for each
    /// distinct window and level is `marcher` showing them over its own transfer function,
    /// rebuilt as the server rebuilds it for an edit (`Marcher::with_visual`; the volume and
    /// its grid are shared).
    pub fn of(marcher: &Marcher, path: &CameraPath, ticks: usize, display_hz: f64) -> Result<Looks, ErrorBox> {
        let mut looks = Looks::fixed(marcher, ticks);
        let base = marcher.transfer_function().clone();
        for k in 0..ticks {
            let Some(wl) = path.window_level(k as f64 / display_hz) else { continue };
            let i = match looks.states.iter().position(|(s, _)| *s == wl) {
                Some(i) => i,
                None => {
                    let state = VisualState { window: wl[0], level: wl[1], ..VisualState::default() };
                    let m = marcher
                        .with_visual(&base, &state)
                        .map_err(|e| format!("scenario {}: window/level {wl:?}: {e}", path.name))?;
                    looks.states.push((wl, m));
                    looks.states.len() - 1
                }
            };
            looks.at_tick[k] = i;
        }
        Ok(looks)
    }

    /// The state of display tick `tick`.
    pub fn state_at(&self, tick: usize) -> usize {
        self.at_tick[tick.min(self.at_tick.len() - 1)]
    }

    /// The marcher of state `state`.
    pub fn marcher(&self, state: usize) -> &Marcher {
        &self.states[state].1
    }

    /// The window and level of state `state`.
    pub fn window_level(&self, state: usize) -> [f32; 2] {
        self.states[state].0
    }

    /// Distinct states.
    pub fn len(&self) -> usize {
        self.states.len()
    }

    /// Never true: a session has at least its start state.
    pub fn is_empty(&self) -> bool {
        self.states.is_empty()
    }
}

/// One scored tick of one method.
#[derive(Clone, Debug, PartialEq)]
pub struct TickRow {
    /// Method name.
    pub method: String,
    /// Display tick.
    pub tick: usize,
    /// Its time, s.
    pub time_s: f64,
    /// Sequence number of the frame shown.
    pub frame_seq: usize,
    /// Age of the frame shown: the tick's time minus when the camera it was rendered for was
    /// requested, ms.
    pub frame_age_ms: f64,
    /// The method's draw time, ms.
    pub draw_ms: f64,
    /// Scores against the truth.
    pub metrics: Metrics,
}

/// The tick of a method that went worst.
#[derive(Clone, Debug)]
pub struct Worst {
    /// Method name.
    pub method: String,
    /// Display tick.
    pub tick: usize,
    /// Its FLIP.
    pub flip: f64,
    /// The truth.
    pub truth: Image,
    /// What the method showed.
    pub shown: Image,
}

/// Everything one session produced.
#[derive(Clone, Debug, Default)]
pub struct SessionResult {
    /// The scored rows, tick by tick, methods in order.
    pub rows: Vec<TickRow>,
    /// The first method's frames (or images), in order of arrival.
    pub frames: Vec<FrameEvent>,
    /// The worst tick of each method.
    pub worst: Vec<Worst>,
}

/// Ground-truth images by camera and window/level (bit patterns), shared between methods and
/// runs of one dataset.
#[derive(Default)]
pub struct TruthCache {
    map: HashMap<[u32; 13], Image>,
    /// Truths rendered (misses).
    pub rendered: usize,
}

fn camera_key(c: &Camera, wl: [f32; 2]) -> [u32; 13] {
    let f = |v: f32| v.to_bits();
    [
        f(c.eye.x),
        f(c.eye.y),
        f(c.eye.z),
        f(c.target.x),
        f(c.target.y),
        f(c.target.z),
        f(c.up.x),
        f(c.up.y),
        f(c.up.z),
        f(c.fov_y_deg),
        c.width ^ (c.height << 16),
        f(wl[0]),
        f(wl[1]),
    ]
}

impl TruthCache {
    /// The truth for a camera with the dataset's own transfer function (rendered on a miss).
    pub fn get(&mut self, marcher: &Marcher, camera: &Camera) -> &Image {
        self.get_with(marcher, WL_FROM, camera)
    }

    /// The truth for a camera in state `state` of `looks` (rendered on a miss).
    pub fn get_in(&mut self, looks: &Looks, state: usize, camera: &Camera) -> &Image {
        self.get_with(looks.marcher(state), looks.window_level(state), camera)
    }

    fn get_with(&mut self, marcher: &Marcher, wl: [f32; 2], camera: &Camera) -> &Image {
        let key = camera_key(camera, wl);
        if !self.map.contains_key(&key) {
            self.rendered += 1;
            self.map.insert(key, marcher.render_image(camera));
        }
        &self.map[&key]
    }

    /// Forgets every truth (between datasets).
    pub fn clear(&mut self) {
        self.map.clear();
    }
}

/// The display ticks' cameras of a path (a clear error for an unusable camera).
pub fn tick_cameras(marcher: &Marcher, path: &CameraPath, cfg: &SessionConfig) -> Result<Vec<Camera>, ErrorBox> {
    let c0 = marcher.default_camera(cfg.size, cfg.size);
    let duration = path.recorded_duration().map_or(cfg.duration_s, |d| d.min(cfg.duration_s));
    let n = (duration * cfg.client.display_hz + 1e-9).floor() as usize + 1;
    (0..n)
        .map(|k| {
            let c = path.camera(&c0, k as f64 / cfg.client.display_hz);
            c.validate(MAX_RECORDED_VIEWPORT)
                .map_err(|e| format!("scenario {}: camera at tick {k}: {e}", path.name))?;
            Ok(c)
        })
        .collect()
}

/// The simulated client's side of core's request policy for a display ticking every
/// `tick_ms`: the horizon takes off that tick, a frame's arrival alone asks for nothing (the
/// client asks when its view moves), and a predicting client asks once more at the first tick
/// the view holds still (so the server renders the still view, not the overshoot of the last
/// prediction); guard bands widen to at most [`MAX_RECORDED_VIEWPORT`].
pub fn cadence(tick_ms: f64) -> Cadence {
    Cadence {
        display_tick_s: (tick_ms * 1e-3) as f32,
        on_frame_arrival: false,
        on_first_still: true,
        max_viewport: MAX_RECORDED_VIEWPORT,
    }
}

/// The requests a client with `policy` sends over the ticks' cameras: one at every tick the
/// request policy finds due on the simulator's [`cadence`] (the tick's camera or visual state
/// differs from the previous tick's, or it is the first still tick of a predicting client).
/// Their cameras are the ticks' own; [`serve`] predicts and widens them.
fn requests(cams: &[Camera], looks: &Looks, tick_ms: f64, policy: SessionRequest) -> Vec<Request> {
    let cadence = cadence(tick_ms);
    let mut out = Vec::new();
    for k in 1..cams.len() {
        let moved = cams[k] != cams[k - 1] || looks.state_at(k) != looks.state_at(k - 1);
        let first_still = !moved && (k < 2 || cams[k - 1] != cams[k - 2]);
        if policy.policy().due(&cadence, ViewEvents { moved, first_still, frame_arrived: false }) {
            out.push(Request { tick: k, sent_ms: k as f64 * tick_ms, camera: cams[k] });
        }
    }
    out
}

/// Runs the server and the network over the ticks' cameras for a client asking with
/// `request`: the frames in order of arrival, each with its rendered frame. The first is the
/// frame the client holds at time 0 (rendered for the first camera as shown, no guard band;
/// requested a round trip, a render and its transfer before).
///
/// With `request.predict`, the request sent at a tick carries the camera core's
/// [`Predictor`] expects after the [`Horizon`] the client has measured from the frames that
/// arrived before it was sent (the predictor has observed the camera of every tick up to it,
/// as the window client's display does); with a guard band, that camera widened
/// (core's `guard::GuardBand`), all by core's request policy ([`cadence`]). Each frame is
/// rendered with the visual state of the newest request it serves (`looks`). With adaptive
/// resolution (`request.coarse`), a request sent at a tick the camera moved asks for a coarser
/// viewport, rendered in `server_ms` times the measured ratio (`cfg.resolution_cost`).
pub fn serve(
    looks: &Looks,
    cams: &[Camera],
    cfg: &SessionConfig,
    policy: &mut dyn ServerPolicy,
    request: SessionRequest,
) -> Vec<(FrameEvent, volwarp_core::wire::Frame)> {
    let tick_ms = 1e3 / cfg.client.display_hz;
    let end_ms = (cams.len() - 1) as f64 * tick_ms;
    let net = cfg.net;
    let layers = stream_layers(cfg, request);
    // Each frame with the bytes the server sends for it: its own encoder and radius model
    // (`volwarp_server::encoding::encode_frame`).
    // `wanted`: the request's segments per pixel (core's `Requested::layers`; 0: the stream's),
    // capped at the stream's as the server caps them at the Hello's.
    let render = |camera: Camera, seq: usize, state: usize, wanted: u8| {
        let marcher = looks.marcher(state);
        let k = if wanted > 0 { u32::from(wanted).min(layers) } else { layers };
        let req =
            CameraRequest { seq: seq as u64, camera, heuristic: cfg.heuristic, radius_scale: 1.0, layers: wanted };
        let frame = marcher.render_frame_layers(&req, k).0;
        let bytes = encode_frame(marcher, &req, &frame, cfg.encoding).0.len() as u64;
        (frame, bytes)
    };
    // Adaptive resolution: a request sent while the camera moved asks for a coarser grid (the
    // coarser still while the view turns fast: core's `RequestPolicy::motion`), which the
    // server renders in its time times the marcher's measured ratio.
    let moving = |r: &Request| r.tick > 0 && cams[r.tick] != cams[r.tick - 1];
    // The first frame is layered: the first moves warp it (one sample per pixel there raised
    // the MRI orbit's p95 from 0.044 to 0.065).
    let (first, first_bytes) = render(cams[0], 0, looks.state_at(0), 0);
    let mut out = vec![(FrameEvent::at_start(cams[0], net.server_ms, first_bytes, looks.state_at(0)), first)];
    let first_ms = 2.0 * net.latency_ms + net.server_ms + net.transfer_ms(out[0].0.bytes);
    // Side views at rest: the client holds them beside the first frame (the user looked at
    // that image long enough for them to come, as for the first frame itself).
    while let Some(side) = request.policy().prefetch(&cams[0], &held_views(&out)) {
        let state = looks.state_at(0);
        let (frame, bytes) = render(side.camera, out.len(), state, side.layers);
        out.push((
            FrameEvent { seq: out.len(), ..FrameEvent::at_start(side.camera, net.server_ms, bytes, state) },
            frame,
        ));
    }
    let at_start = out.len();
    let mut requests = requests(cams, looks, tick_ms, request);
    let cadence = cadence(tick_ms);
    // The client side: what each request asks for, in the order they are sent.
    let mut predictor = Predictor::new();
    let mut observed = 0usize; // ticks the predictor has seen
                               // Per request once asked: what it asks for.
    let mut asked: Vec<Option<Requested>> = vec![None; requests.len()];
    let mut ask = |i: usize,
                   requests: &mut [Request],
                   out: &[(FrameEvent, volwarp_core::wire::Frame)],
                   asked: &mut Vec<Option<Requested>>| {
        // Requests are asked in order; catch the predictor up to request i.
        let first_unasked = asked.iter().position(Option::is_none).unwrap_or(asked.len());
        for r in first_unasked..=i {
            if asked[r].is_some() {
                continue; // a side view at rest, asked as it was sent
            }
            let sent = requests[r].sent_ms;
            let shown = requests[r].camera;
            // The display's predictor sees every camera shown, up to the request's tick, and the
            // horizon every frame arrived (both also say how fast the view turns for adaptive
            // resolution, with or without prediction, as in the window client).
            let mut horizon = Horizon::new();
            for (k, c) in cams.iter().enumerate().take(requests[r].tick + 1).skip(observed) {
                predictor.observe(*c, k as f64 * tick_ms * 1e-3);
            }
            observed = observed.max(requests[r].tick + 1);
            // The first frame: requested one round trip, render and transfer before 0.
            horizon.observe(-first_ms * 1e-3, 0.0, net.server_ms * 1e-3, 1);
            for (f, _) in out.iter().skip(at_start).filter(|(f, _)| f.arrive_ms <= sent) {
                horizon.observe(f.request_ms * 1e-3, f.arrive_ms * 1e-3, f.render_ms * 1e-3, f.divisor);
            }
            let policy = request.policy();
            let motion = policy.motion(moving(&requests[r]), &predictor, &horizon, &cadence);
            let asks = policy.camera_at(shown, motion, &predictor, &horizon, &cadence);
            asked[r] = Some(asks);
            requests[r].camera = asks.camera;
        }
        asked[i].expect("asked above")
    };
    let arrival = |r: &Request| r.sent_ms + net.latency_ms;
    let mut s = 0.0f64;
    let mut served = 0usize; // requests[..served] were seen by the server
    let mut dropped_last = false; // the last render or write was dropped
    let mut link_free = 0.0f64; // when the link has sent what the server wrote
    while served < requests.len() {
        // The newest request arrived by `s`, else wait for the next one.
        let mut j = served;
        while j + 1 < requests.len() && arrival(&requests[j + 1]) <= s {
            j += 1;
        }
        s = s.max(arrival(&requests[j]));
        let Requested { view, guard_offset, layers: wanted, divisor, .. } = ask(j, &mut requests, &out, &mut asked);
        let render_ms = net.server_ms * cfg.resolution_cost.ratio(divisor);
        if s + render_ms + net.latency_ms > end_ms {
            break; // it would arrive after the session
        }
        // Preemption, the real server's rule: a request for another viewport (adaptive
        // resolution's, the view came to rest or started moving) that arrives while this one
        // renders ends the render there, unless the one before was dropped; one for a coarser
        // viewport (the view started moving) that arrives while it is written ends the write.
        // The server takes the newest request. `turn(from, to, coarser)`: the arrival of such a
        // request in that span.
        // (The requests arriving in the span are asked first: their grids are the client's.)
        let turn = |from: f64, to: f64, coarser: bool, requests: &[Request], asked: &[Option<Requested>]| {
            if !request.preempt {
                return None;
            }
            let other = |v: u32| if coarser { v > divisor } else { v != divisor };
            (j + 1..requests.len())
                .map(|r| (arrival(&requests[r]), r))
                .find(|&(a, r)| a > from && a < to && asked[r].is_some_and(|q| other(q.divisor)))
                .map(|(a, _)| a)
        };
        if let Some(last) = requests.iter().rposition(|r| arrival(r) < s + render_ms) {
            ask(last, &mut requests, &out, &mut asked);
        }
        if let Some(a) = turn(s, s + render_ms, false, &requests, &asked).filter(|_| !dropped_last) {
            served = j + 1;
            s = a;
            dropped_last = true;
            continue;
        }
        let camera = policy.camera(&requests[..=j], s);
        served = j + 1;
        let seq = out.len();
        let state = looks.state_at(requests[j].tick);
        let wanted = if camera == requests[j].camera { wanted } else { 0 };
        let (frame, bytes) = render(camera, seq, state, wanted);
        let write_start = (s + render_ms).max(link_free);
        let write_end = write_start + net.transfer_ms(bytes);
        // While the frame is written (in parts) the server stops after the part under way, and
        // the link still carries what the kernel holds: the part, the unsent bytes the socket
        // keeps and a round trip of bytes in flight. (The coarse frame asked for next is never
        // dropped on the link, so frames keep coming however often the view turns.)
        if let Some(last) = requests.iter().rposition(|r| arrival(r) < write_end) {
            ask(last, &mut requests, &out, &mut asked);
        }
        if let Some(a) = turn(write_start, write_end, true, &requests, &asked) {
            s = a;
            let in_flight = net.mbps * 1e6 / 8.0 * 2.0 * net.latency_ms * 1e-3;
            let tail = (wire::PART_LEN + volwarp_server::server::NOTSENT_LOWAT) as f64 + in_flight;
            link_free = write_end.min(s + net.transfer_ms(tail as u64));
            dropped_last = true;
            continue;
        }
        dropped_last = false;
        link_free = write_end;
        let arrive_ms = write_end + net.latency_ms;
        if arrive_ms <= end_ms {
            let view = if camera == requests[j].camera { view } else { camera };
            let guard_offset = if camera == requests[j].camera { guard_offset } else { (0, 0) };
            out.push((
                FrameEvent {
                    state,
                    seq,
                    camera,
                    view,
                    guard_offset,
                    divisor,
                    request_ms: requests[j].sent_ms,
                    start_ms: s,
                    render_ms,
                    bytes,
                    arrive_ms,
                },
                frame,
            ));
            // Side views at rest (core's `RequestPolicy::prefetch`): at the first tick after
            // the frame arrives, where the view still rests and no request waits for its frame,
            // the client asks for the next side view its frames lack.
            let k = (arrive_ms / tick_ms).ceil() as usize;
            let resting =
                k > 0 && k < cams.len() && cams[k] == cams[k - 1] && looks.state_at(k) == looks.state_at(k - 1);
            let waiting = requests[served..].iter().any(|r| r.sent_ms <= k as f64 * tick_ms);
            if let Some(side) = request
                .policy()
                .prefetch(&cams[k.min(cams.len() - 1)], &held_views(&out))
                .filter(|_| resting && !waiting)
            {
                let sent_ms = k as f64 * tick_ms;
                let at = served + requests[served..].partition_point(|r| r.sent_ms <= sent_ms);
                requests.insert(at, Request { tick: k, sent_ms, camera: side.camera });
                asked.insert(at, Some(side));
            }
        }
        s = write_end;
    }
    out
}

/// The views of the frames a client asking for side views at rest holds for them: the newest
/// frames of the newest frame's visual state, as many as the rest frame and its side views
/// (core's `method::PREFETCH_HELD`).
fn held_views(out: &[(FrameEvent, volwarp_core::wire::Frame)]) -> Vec<Camera> {
    let state = out.last().map_or(0, |(f, _)| f.state);
    out.iter()
        .rev()
        .take_while(|(f, _)| f.state == state)
        .take(volwarp_core::method::PREFETCH_HELD)
        .map(|(f, _)| f.view)
        .collect()
}

/// Segments per pixel of the frames served to a client asking with `request`.
fn stream_layers(cfg: &SessionConfig, request: SessionRequest) -> u32 {
    if request.layers > 0 {
        request.layers
    } else {
        cfg.layers
    }
}

/// The frame's own image for its [`FrameEvent::view`]: the frame as rendered, cropped to the
/// view where a guard band widened it.
fn exact_view(exact: &mut dyn Renderer, held: &HeldFrame, f: &FrameEvent, out: &mut Image, tmp: &mut Image) {
    if f.camera == f.view {
        exact.render(&held.scene, &f.view, out);
        return;
    }
    exact.render(&held.scene, &f.camera, tmp);
    let (w, h) = (f.view.width, f.view.height);
    out.reset_for(&f.view);
    for y in 0..h {
        let src = ((y + f.guard_offset.1) * tmp.width + f.guard_offset.0) as usize;
        let dst = (y * w) as usize;
        out.pixels[dst..dst + w as usize].copy_from_slice(&tmp.pixels[src..src + w as usize]);
    }
}

/// The frames served to the clients of one request policy, built once for every method of it.
struct Stream {
    request: SessionRequest,
    frames: Vec<FrameEvent>,
    held: Vec<HeldFrame>,
}

/// Which stream a method shows: frames (warped) or a peer's images.
#[derive(Clone, Copy)]
enum StreamOf {
    Frames(usize),
    Images(usize),
}

/// Runs one session. `progress` gets a line per scored tick.
#[allow(clippy::too_many_arguments)]
pub fn run_session(
    marcher: &Marcher,
    path: &CameraPath,
    cfg: &SessionConfig,
    policy: &mut dyn ServerPolicy,
    methods: &mut [Box<dyn Method>],
    truths: &mut TruthCache,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<SessionResult, ErrorBox> {
    cfg.check()?;
    let cams = tick_cameras(marcher, path, cfg)?;
    let looks = Looks::of(marcher, path, cams.len(), cfg.client.display_hz)?;
    let tick_ms = 1e3 / cfg.client.display_hz;
    // One stream of frames per distinct request policy, one of images per peer.
    let mut streams: Vec<Stream> = Vec::new();
    let mut image_streams: Vec<ImageStream> = Vec::new();
    let mut stream_of = Vec::with_capacity(methods.len());
    for m in methods.iter() {
        if let Some(peer) = m.image_peer() {
            let i = match image_streams.iter().position(|s| s.peer == peer) {
                Some(i) => i,
                None => {
                    let s = peers::serve_images(
                        &looks,
                        &cams,
                        tick_ms,
                        cfg.net,
                        cfg.resolution_cost,
                        policy,
                        peer,
                        truths,
                    )?;
                    image_streams.push(s);
                    image_streams.len() - 1
                }
            };
            stream_of.push(StreamOf::Images(i));
            continue;
        }
        let r = m.request();
        let i = match streams.iter().position(|s| s.request == r) {
            Some(i) => i,
            None => {
                let served = serve(&looks, &cams, cfg, policy, r);
                let frames = served.iter().map(|(e, _)| *e).collect();
                let held = served.into_iter().map(|(_, f)| HeldFrame::new(f)).collect();
                streams.push(Stream { request: r, frames, held });
                streams.len() - 1
            }
        };
        stream_of.push(StreamOf::Frames(i));
    }
    // Layered frames are shown as they were rendered by compositing their segments.
    let mut exact_one = volwarp_cpu_tracer::create(RendererKind::Stale, 0).ok_or("the stale renderer is missing")?;
    let mut exact_layers =
        volwarp_cpu_tracer::create(RendererKind::SplatLayers, 0).ok_or("the layered splatter is missing")?;
    let mut tmp = Image::new(0, 0);
    let draw: Vec<(f64, usize)> = methods
        .iter()
        .map(|m| {
            let ms = cfg.client.draw_ms.get(m.name()).copied().unwrap_or(0.0);
            (ms, cfg.client.ticks_per_draw(ms))
        })
        .collect();
    let scored: Vec<usize> = (0..cams.len()).step_by(cfg.score_every).collect();
    // The result's frames: the first method's stream.
    let frames = match stream_of.first() {
        Some(StreamOf::Frames(i)) => streams[*i].frames.clone(),
        Some(StreamOf::Images(i)) => image_streams[*i].frames.clone(),
        None => Vec::new(),
    };
    let mut result = SessionResult { frames, ..Default::default() };
    let mut worst: Vec<Option<Worst>> = vec![None; methods.len()];
    let mut images: Vec<Image> = (0..methods.len()).map(|_| Image::new(0, 0)).collect();
    for (done, &j) in scored.iter().enumerate() {
        let mut shown_frame = Vec::with_capacity(methods.len());
        for (mi, m) in methods.iter_mut().enumerate() {
            let n = draw[mi].1;
            // The newest draw finished by tick j started at a multiple of n.
            let k = if j + 1 >= n { ((j + 1) / n - 1) * n } else { 0 };
            let t_k = k as f64 * tick_ms;
            let st = match stream_of[mi] {
                StreamOf::Frames(i) => &streams[i],
                StreamOf::Images(i) => {
                    let st = &image_streams[i];
                    let fi = st.frames.partition_point(|f| f.arrive_ms <= t_k).saturating_sub(1);
                    peers::show(&st.held[fi], &cams[k], &mut images[mi]);
                    shown_frame.push(fi);
                    continue;
                }
            };
            let fi = st.frames.partition_point(|f| f.arrive_ms <= t_k).saturating_sub(1);
            let cam = &cams[k];
            // The kept frames, newest first, of the newest frame's visual state (the window drops
            // older frames of another state when a frame of a new state arrives: no drawing
            // mixes two states), and core's choice among them (as the window's display loop
            // makes it).
            let state = st.frames[fi].state;
            let kept: Vec<usize> = (0..m.frames_kept().max(1).min(fi + 1))
                .map(|d| fi - d)
                .filter(|&i| st.frames[i].state == state)
                .collect();
            let views: Vec<Camera> = kept.iter().map(|&i| st.frames[i].view).collect();
            // Always warping (`--always-warp`): no exact frame, no unwarped fallback.
            let fallback = if cfg.exact_when_still { show::FALLBACK_DEG } else { f32::INFINITY };
            let show = match show::choose(&views, cam, fallback) {
                Show::Exact(i) if !cfg.exact_when_still => {
                    Show::Warp(std::iter::once(i).chain((0..kept.len()).filter(|&j| j != i)).collect())
                }
                s => s,
            };
            match show {
                Show::Exact(i) | Show::Unwarped(i) => {
                    // As rendered: a layered frame's segments composited, a one-sample frame (the
                    // rest request's) its samples' colors; a coarse frame resized to the view
                    // (as the window client shows it).
                    let f = kept[i];
                    let exact = if st.held[f].frame.segments.is_empty() { &mut exact_one } else { &mut exact_layers };
                    exact_view(exact.as_mut(), &st.held[f], &st.frames[f], &mut images[mi], &mut tmp);
                    if (images[mi].width, images[mi].height) != (cam.width, cam.height) {
                        std::mem::swap(&mut tmp, &mut images[mi]);
                        tmp.resize_into(cam.width, cam.height, &mut images[mi]);
                    }
                    shown_frame.push(f);
                }
                Show::Warp(order) => {
                    // `Method::draw` takes the frames oldest first: the one to draw last.
                    let held: Vec<&HeldFrame> = order.iter().rev().map(|&i| &st.held[kept[i]]).collect();
                    m.draw(&held, cam, &mut images[mi]);
                    shown_frame.push(order.first().map_or(fi, |&i| kept[i]));
                }
            }
        }
        let truth = truths.get_in(&looks, looks.state_at(j), &cams[j]);
        let metrics: Vec<Metrics> = images
            .par_iter()
            .map(|img| Metrics::of(truth, img).unwrap_or(Metrics { psnr: 0.0, ssim: 0.0, flip: 1.0 }))
            .collect();
        let t_j = j as f64 * tick_ms;
        for (mi, m) in methods.iter().enumerate() {
            let f = match stream_of[mi] {
                StreamOf::Frames(i) => &streams[i].frames[shown_frame[mi]],
                StreamOf::Images(i) => &image_streams[i].frames[shown_frame[mi]],
            };
            result.rows.push(TickRow {
                method: m.name().into(),
                tick: j,
                time_s: t_j * 1e-3,
                frame_seq: f.seq,
                frame_age_ms: t_j - f.request_ms,
                draw_ms: draw[mi].0,
                metrics: metrics[mi],
            });
            if worst[mi].as_ref().is_none_or(|w| metrics[mi].flip > w.flip) {
                worst[mi] = Some(Worst {
                    method: m.name().into(),
                    tick: j,
                    flip: metrics[mi].flip,
                    truth: truth.clone(),
                    shown: images[mi].clone(),
                });
            }
        }
        progress(done + 1, scored.len());
    }
    result.worst = worst.into_iter().flatten().collect();
    Ok(result)
}
