//! The network thread(s): the part of the client that may wait, so that the display loop never
//! does (Zellmann 2020, Figure 2, client side).
//!
//! * **reader** — reads each message off the socket (its exact bytes go to the recorder),
//!   decodes Frames, stamps them with the time their camera was requested, and queues them;
//! * **builder** — waits until a frame is due (`--latency-ms` after it arrived), keeps only the
//!   newest due frame, builds its LBVH (the cpu-tracer's parallel build, reusing the buffers
//!   of the scene the display dropped) and puts the scene in a one-element slot;
//! * **writer** — sends the newest view (camera, heuristic, radius scale) as a CameraRequest:
//!   at most every [`THROTTLE`], only when it changed, and again whenever a frame arrives so
//!   the server always has work. Newest only: there is never a queue of cameras. With
//!   `--predict` it sends the camera core's `prediction` expects for when the frame will be
//!   shown (horizon: core's `prediction::Horizon`, the smoothed request-to-ready time the
//!   builder measures plus half the smoothed interval between frames); with `--guard G`
//!   the camera widened by a guard band (core's `guard`);
//! * **link** — owns the connection: starts the reader and writer on it, and when either ends
//!   (read or write error, end of stream, the server's Bye or Error) closes it and, with a
//!   [`Redial`], connects again after a capped, jittered exponential [`Backoff`] (Hello with
//!   the same capabilities, token and layers, then the current camera). Meanwhile the display
//!   keeps warping the frames it has (each carries its camera); [`Network::state`] says what
//!   the link is doing. Permanent refusals ([`is_permanent`]: wrong token, another protocol
//!   version, a request the server will never accept) end the network instead of looping.
//!
//! The display loop only ever `try_lock`s the slot ([`Network::take_scene`]); every lock the
//! display takes is held for a few instructions.

use crate::connection::{connect_secure, read_message_bytes_marked, send_bye, send_request, server_error, Connection};
use crate::error::ClientError;
use crate::link::{Throttled, TokenBucket};
use crate::record::RecordSink;
use std::collections::VecDeque;
use std::io::{Read, Write};
use std::net::{Shutdown, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use volwarp_core::method::{Cadence, RequestPolicy, ViewEvents};
use volwarp_core::prediction::{Horizon, Predictor};
use volwarp_core::wire::{error_code, CameraRequest, Frame, Limits, Message, VisualEdit, VisualState};
use volwarp_core::{Camera, Heuristic, Scene};
use volwarp_cpu_tracer::ParallelBuilder;
use volwarp_cpu_tracer::MAX_VIEWPORT;

/// Shortest time between two camera requests.
pub const THROTTLE: Duration = Duration::from_millis(30);

/// Display frames a view must hold still before it counts as at rest (adaptive resolution asks
/// for the full resolution, and a predicting client for the still view): 2, so one display
/// frame without a mouse event in a drag does not count, and at 60 frames/s about the
/// simulator's display tick (1/30 s).
pub const STILL_AFTER: u32 = 2;
/// Most received frames waiting for their latency to pass (older ones are dropped).
const MAX_PENDING: usize = 32;
/// Request send times kept to compute frame ages.
const MAX_SENT: usize = 256;

/// What the client asks the server to render.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    /// The camera (with the viewport).
    pub camera: Camera,
    /// The depth heuristic.
    pub heuristic: Heuristic,
    /// The radius scale.
    pub radius_scale: f32,
}

/// A built scene with what the display needs to know about it.
#[derive(Debug)]
pub struct ReadyScene {
    /// The scene.
    pub scene: Scene,
    /// The sequence number of the request it answers.
    pub seq: u64,
    /// When that request was sent (unknown for requests older than the last 256).
    pub requested_at: Option<Instant>,
    /// When the frame's last byte arrived.
    pub received_at: Instant,
    /// LBVH build time in ms.
    pub build_ms: f64,
    /// The id of the visual state it was rendered with (the last VisualState before it on the
    /// stream; 0: the server's start state, or a server without live edits).
    pub state: u32,
}

/// Network settings.
#[derive(Clone, Debug)]
pub struct NetConfig {
    /// Delay of every received frame before it is built.
    pub latency: Duration,
    /// LBVH build threads (0: all cores; 1: on the builder thread itself).
    pub build_threads: usize,
    /// Longest wait for the next message from the server.
    pub timeout: Duration,
    /// Hand frames over unbuilt (no LBVH: `volwarp_cpu_tracer::route::into_unbuilt_scene`), for
    /// a renderer that draws them directly (no `needs_lbvh` in the registry); the display
    /// builds the LBVH itself if it switches to one that needs it.
    pub lazy_build: bool,
    /// Link rate in Mbit/s that the socket's reads and writes are throttled to
    /// (`--bandwidth-mbps`; [`crate::link`]); `None`: loopback speed.
    pub bandwidth_mbps: Option<f64>,
    /// What the writer asks for (core's `method::RequestPolicy`, the method's `predict` and
    /// `guard`): the camera predicted for when the frame will be shown (orbit-aware, horizon:
    /// the measured request-to-ready time plus half the frame interval) or the current one,
    /// widened by a guard band of this fraction of the display on every side (0: none).
    pub request: RequestPolicy,
}

/// The window client's side of the request policy: the display runs at about 60 Hz (a tick of
/// ~16 ms) and a frame's arrival alone triggers a request, so the server always has work; when
/// the view stops where the last request did not ask for it (a predicting client's overshoot),
/// it asks for the still view at once rather than at the next frame's arrival, so the server's
/// next frame is the exact one the display then shows as rendered (`volwarp_core::show`).
pub const CADENCE: Cadence =
    Cadence { display_tick_s: 1.0 / 60.0, on_frame_arrival: true, on_first_still: true, max_viewport: MAX_VIEWPORT };

/// How long one redial may take at most (connect, Hello, probe frame), whatever `--timeout-s`
/// says: a server that is down answers at once, one that does not answer is tried again.
pub const REDIAL_TIMEOUT: Duration = Duration::from_secs(5);

/// Waits between redials: `first`, doubling per failed attempt up to `cap`, each scaled by a
/// jitter factor in [0.5, 1] drawn from a deterministic sequence of `seed` (clients with
/// different seeds do not retry in lockstep after a server restart).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Backoff {
    /// Wait before the first attempt.
    pub first: Duration,
    /// Longest wait.
    pub cap: Duration,
    /// Seed of the jitter.
    pub seed: u64,
}

impl Default for Backoff {
    /// 100 ms doubling to a 2 s cap.
    fn default() -> Self {
        Backoff { first: Duration::from_millis(100), cap: Duration::from_secs(2), seed: 0x0076_6f6c_7761_7270 }
    }
}

impl Backoff {
    /// The wait before attempt `attempt` (1: the first after a drop).
    pub fn delay(&self, attempt: u32) -> Duration {
        let doublings = attempt.saturating_sub(1).min(30);
        let full = self.first.saturating_mul(1u32 << doublings).min(self.cap);
        full.mul_f64(0.5 + 0.5 * unit(splitmix64(self.seed ^ u64::from(attempt))))
    }
}

/// SplitMix64: a well-mixed 64-bit value of `x`.
fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The top 53 bits of `x` as a number in [0, 1).
fn unit(x: u64) -> f64 {
    (x >> 11) as f64 / (1u64 << 53) as f64
}

/// Where and how to connect again when the connection drops.
#[derive(Clone, Debug)]
pub struct Redial {
    /// The server address (`host:port`, resolved again on every attempt).
    pub addr: String,
    /// The access token sent in Hello.
    pub token: Option<String>,
    /// Segments per pixel asked for in Hello.
    pub layers: u8,
    /// Waits between attempts.
    pub backoff: Backoff,
    /// TLS settings (`--tls`): every attempt verifies the server's certificate again.
    pub tls: Option<std::sync::Arc<volwarp_tls::rustls::ClientConfig>>,
}

/// Whether a connection error will not go away by trying again: a wrong or missing token,
/// another protocol version, a request the server refuses as malformed or too large, a
/// refused TLS certificate or a server that does not speak TLS, a bad address or command line. Everything else (refused or reset connections, timeouts, a busy
/// or rate-limiting server, a server that went away) is worth another attempt.
pub fn is_permanent(e: &ClientError) -> bool {
    match e {
        ClientError::Version(_) | ClientError::Usage(_) | ClientError::BadAddress(_) | ClientError::Tls(_) => true,
        ClientError::Server { code, .. } => matches!(
            *code,
            error_code::UNAUTHORIZED
                | error_code::UNSUPPORTED_VERSION
                | error_code::BAD_REQUEST
                | error_code::TOO_LARGE
        ),
        _ => false,
    }
}

/// What the network's link to the server is doing.
#[derive(Clone, Debug, PartialEq)]
pub enum ConnectionState {
    /// Connected: frames arrive.
    Connected,
    /// The connection dropped; the next attempt starts in `next_in` (zero: under way).
    Reconnecting {
        /// Attempts since the drop, counting the next one.
        attempt: u32,
        /// Time until that attempt.
        next_in: Duration,
        /// Why the connection (or the last attempt) failed.
        reason: String,
    },
    /// The network stopped for good (a permanent error, or a drop without a [`Redial`]).
    Failed(ClientError),
}

impl ConnectionState {
    /// A short line for a title or HUD; `None` while connected.
    pub fn label(&self) -> Option<String> {
        match self {
            ConnectionState::Connected => None,
            ConnectionState::Reconnecting { attempt, next_in, reason } if next_in.is_zero() => {
                Some(format!("reconnecting… (attempt {attempt}; {reason})"))
            }
            ConnectionState::Reconnecting { attempt, next_in, reason } => {
                Some(format!("reconnecting in {:.1} s… (attempt {attempt}; {reason})", next_in.as_secs_f64()))
            }
            ConnectionState::Failed(e) => Some(format!("disconnected: {e}")),
        }
    }
}

/// The link's state as the link thread keeps it.
#[derive(Clone, Debug)]
enum LinkStatus {
    Connected,
    Reconnecting { attempt: u32, at: Instant, reason: String },
    Failed(ClientError),
}

#[derive(Debug)]
struct LinkSlot {
    status: LinkStatus,
    /// Why the current connection ended (set by its reader or writer).
    down: Option<ClientError>,
}

struct Pending {
    frame: Frame,
    state: u32,
    requested_at: Option<Instant>,
    /// The divisor per axis of the grid it was asked for on (1: full resolution; adaptive
    /// resolution's grids have their horizons measured apart).
    divisor: u32,
    received_at: Instant,
}

#[derive(Default)]
struct ViewSlot {
    view: Option<View>,
    changed: bool,
    /// Display frames the view has held still since it last changed (the display publishes
    /// its view every frame; the first view counts as still): it moves until [`STILL_AFTER`].
    still_frames: u32,
    frame_arrived: bool,
    /// The view the last request asked for (before any guard band): where it differs from a
    /// view that holds still (a prediction overshot), the still view is asked for once more.
    asked: Option<Camera>,
    /// The view came to rest ([`STILL_AFTER`] display frames still) since the last request,
    /// which asked for another.
    first_still: bool,
    /// The cameras of the newest frames received, distinct, newest first (at most
    /// core's `method::PREFETCH_HELD`): what side views at rest are asked for against
    /// (`RequestPolicy::prefetch`).
    held: VecDeque<Camera>,
    /// Every camera the display showed, timed (so motion that starts after a still spell is
    /// measured from the last still display frame, not from the last request).
    predictor: Predictor,
    /// The predictor's clock.
    t0: Option<Instant>,
    /// Visual edits to send before the next request.
    edits: VecDeque<VisualEdit>,
    /// The last edit sent or queued: sent again on a new connection (each edit carries the
    /// whole state the client wants, and a new connection starts from the server's).
    last_edit: Option<VisualEdit>,
}

/// What the server said of the visual state.
#[derive(Default)]
struct VisualSlot {
    /// Its last VisualState (`None`: it applies no live edits).
    state: Option<VisualState>,
    /// Its last refusal of an edit (Error `BAD_EDIT`), not yet taken.
    refused: Option<String>,
}

struct Shared {
    stop: AtomicBool,
    view: Mutex<ViewSlot>,
    view_cv: Condvar,
    pending: Mutex<VecDeque<Pending>>,
    pending_cv: Condvar,
    ready: Mutex<Option<ReadyScene>>,
    recycle: Mutex<Option<Scene>>,
    /// Per request sent: its sequence number, when, and its grid's divisor per axis.
    sent: Mutex<VecDeque<(u64, Instant, u32)>>,
    error: Mutex<Option<ClientError>>,
    /// The link's state and the current connection's end, and its wake-ups.
    link: Mutex<LinkSlot>,
    link_cv: Condvar,
    /// Set when the current connection ended: its reader and writer stop.
    down: AtomicBool,
    /// The last request sequence number sent (over all connections).
    seq: AtomicU64,
    /// The server's visual state and refusals.
    visual: Mutex<VisualSlot>,
    /// The id of the server's last VisualState on the current connection: frames read after it
    /// were rendered with it.
    state_id: AtomicU32,
    /// Connections made again after a drop.
    reconnects: AtomicU64,
    frames: AtomicU64,
    built: AtomicU64,
    /// Odd while a frame is being decoded or built.
    work_gen: AtomicU64,
    /// The prediction horizon measured from the frames built (request-to-ready, frame
    /// interval), and the instant its clock starts.
    horizon: Mutex<(Horizon, Instant)>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Shared {
    /// Stops the network for good with `e`.
    fn fail(&self, e: ClientError) {
        if self.stop.load(Ordering::SeqCst) {
            return;
        }
        log::debug!("network: {e}");
        let mut g = lock(&self.error);
        if g.is_none() {
            *g = Some(e.clone());
        }
        drop(g);
        lock(&self.link).status = LinkStatus::Failed(e);
        self.stop.store(true, Ordering::SeqCst);
        self.wake_all();
    }

    /// Ends the current connection with `e` (the first reason wins); the link thread decides
    /// whether to connect again.
    fn drop_link(&self, e: ClientError) {
        let mut g = lock(&self.link);
        if g.down.is_none() {
            log::debug!("network: connection ended: {e}");
            g.down = Some(e);
        }
        self.down.store(true, Ordering::SeqCst);
        drop(g);
        self.link_cv.notify_all();
        self.view_cv.notify_all();
    }

    /// Whether the current connection's reader and writer should stop.
    fn ended(&self) -> bool {
        self.stop.load(Ordering::SeqCst) || self.down.load(Ordering::SeqCst)
    }

    fn wake_all(&self) {
        // Taking each lock once orders this wake-up after any check-then-wait in progress.
        drop(lock(&self.link));
        self.link_cv.notify_all();
        drop(lock(&self.view));
        self.view_cv.notify_all();
        drop(lock(&self.pending));
        self.pending_cv.notify_all();
    }
}

/// Marks a decode or build as in progress for as long as it lives.
struct Busy<'a>(&'a AtomicU64);

impl<'a> Busy<'a> {
    fn new(g: &'a AtomicU64) -> Self {
        g.fetch_add(1, Ordering::SeqCst);
        Busy(g)
    }
}

impl Drop for Busy<'_> {
    fn drop(&mut self) {
        self.0.fetch_add(1, Ordering::SeqCst);
    }
}

/// The running network side of a client.
pub struct Network {
    shared: Arc<Shared>,
    threads: Vec<JoinHandle<()>>,
}

impl Network {
    /// Starts the link, reader, builder and writer threads on an open connection; when it
    /// drops the network stops with the reason ([`Network::error`]).
    pub fn start(conn: Connection, cfg: NetConfig, recorder: Option<RecordSink>) -> Result<Network, ClientError> {
        Network::start_with(conn, cfg, recorder, None)
    }

    /// [`Network::start`] that connects again as `redial` says when the connection drops
    /// (until a permanent error, [`is_permanent`]).
    pub fn start_reconnecting(
        conn: Connection,
        cfg: NetConfig,
        recorder: Option<RecordSink>,
        redial: Redial,
    ) -> Result<Network, ClientError> {
        Network::start_with(conn, cfg, recorder, Some(redial))
    }

    fn start_with(
        conn: Connection,
        cfg: NetConfig,
        recorder: Option<RecordSink>,
        redial: Option<Redial>,
    ) -> Result<Network, ClientError> {
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            view: Mutex::new(ViewSlot::default()),
            view_cv: Condvar::new(),
            pending: Mutex::new(VecDeque::new()),
            pending_cv: Condvar::new(),
            ready: Mutex::new(None),
            recycle: Mutex::new(None),
            sent: Mutex::new(VecDeque::new()),
            error: Mutex::new(None),
            link: Mutex::new(LinkSlot { status: LinkStatus::Connected, down: None }),
            link_cv: Condvar::new(),
            down: AtomicBool::new(false),
            seq: AtomicU64::new(0),
            visual: Mutex::new(VisualSlot::default()),
            state_id: AtomicU32::new(0),
            reconnects: AtomicU64::new(0),
            frames: AtomicU64::new(0),
            built: AtomicU64::new(0),
            work_gen: AtomicU64::new(0),
            horizon: Mutex::new((Horizon::new(), Instant::now())),
        });
        let spawn_err = |e: std::io::Error| ClientError::Io(format!("cannot start a network thread: {e}"));
        let mut threads = Vec::new();
        let sh = shared.clone();
        let build_cfg = cfg.clone();
        threads.push(
            std::thread::Builder::new()
                .name("volwarp-net-build".into())
                .spawn(move || build_loop(&sh, &build_cfg))
                .map_err(spawn_err)?,
        );
        // The first connection's threads start here, so that failing to start them is an error
        // of `start`.
        let session = Session::start(&shared, conn, &cfg, recorder.clone())?;
        let sh = shared.clone();
        let started = std::thread::Builder::new()
            .name("volwarp-net-link".into())
            .spawn(move || link_loop(&sh, session, &cfg, recorder, redial));
        match started {
            Ok(t) => threads.push(t),
            Err(e) => {
                let mut net = Network { shared, threads };
                net.stop();
                return Err(spawn_err(e));
            }
        }
        Ok(Network { shared, threads })
    }

    /// What the link to the server is doing now.
    pub fn state(&self) -> ConnectionState {
        match &lock(&self.shared.link).status {
            LinkStatus::Connected => ConnectionState::Connected,
            LinkStatus::Reconnecting { attempt, at, reason } => ConnectionState::Reconnecting {
                attempt: *attempt,
                next_in: at.saturating_duration_since(Instant::now()),
                reason: reason.clone(),
            },
            LinkStatus::Failed(e) => ConnectionState::Failed(e.clone()),
        }
    }

    /// Connections made again after a drop so far.
    pub fn reconnects(&self) -> u64 {
        self.shared.reconnects.load(Ordering::Relaxed)
    }

    /// Publishes the view the display shows now, once per display frame (whether the view
    /// moves is read from successive calls); the writer sends it (throttled) if it differs from
    /// the last one. Never waits on the network.
    pub fn set_view(&self, view: View) {
        let mut g = lock(&self.shared.view);
        let now = Instant::now();
        let t0 = *g.t0.get_or_insert(now);
        g.predictor.observe(view.camera, now.saturating_duration_since(t0).as_secs_f64());
        let changed = g.view != Some(view);
        g.still_frames = match g.view {
            None => STILL_AFTER,
            Some(_) if changed => 0,
            Some(_) => g.still_frames.saturating_add(1),
        };
        if changed {
            g.view = Some(view);
            g.changed = true;
            drop(g);
            self.shared.view_cv.notify_one();
        } else if !g.changed
            && g.still_frames >= STILL_AFTER
            && g.asked.is_some_and(|a| a != view.camera)
            && !g.first_still
        {
            // The view holds still where the last request did not ask (a prediction that
            // overshot): ask for exactly this view, so its exact frame comes a frame sooner.
            g.first_still = true;
            drop(g);
            self.shared.view_cv.notify_one();
        }
    }

    /// Queues a visual edit (sent before the next camera request). It should carry the whole
    /// state the client wants: it is sent again after a reconnect.
    pub fn send_edit(&self, edit: VisualEdit) {
        let mut g = lock(&self.shared.view);
        g.last_edit = Some(edit.clone());
        g.edits.push_back(edit);
        drop(g);
        self.shared.view_cv.notify_one();
    }

    /// The server's last VisualState (its presets, the state it renders with now); `None`
    /// where it applies no live edits.
    pub fn visual_state(&self) -> Option<VisualState> {
        lock(&self.shared.visual).state.clone()
    }

    /// The server's last refusal of an edit, once.
    pub fn take_refusal(&self) -> Option<String> {
        lock(&self.shared.visual).refused.take()
    }

    /// The newest built scene, if one is ready and the slot is free right now (never waits).
    pub fn take_scene(&self) -> Option<ReadyScene> {
        self.shared.ready.try_lock().ok().and_then(|mut g| g.take())
    }

    /// Hands a scene the display no longer shows back to the builder, to reuse its buffers.
    pub fn recycle(&self, scene: Scene) {
        if let Ok(mut g) = self.shared.recycle.try_lock() {
            if g.is_none() {
                *g = Some(scene);
            }
        }
    }

    /// The error that stopped the network, if any.
    pub fn error(&self) -> Option<ClientError> {
        lock(&self.shared.error).clone()
    }

    /// Frames received so far.
    pub fn frames_received(&self) -> u64 {
        self.shared.frames.load(Ordering::Relaxed)
    }

    /// Scenes built so far.
    pub fn scenes_built(&self) -> u64 {
        self.shared.built.load(Ordering::Relaxed)
    }

    /// A counter that is odd while a frame is being decoded or built, and changes whenever
    /// such work starts or ends: a display frame overlapped that work if the counter was odd
    /// at its start or changed during it.
    pub fn work_generation(&self) -> u64 {
        self.shared.work_gen.load(Ordering::SeqCst)
    }

    /// Sends Bye, closes the socket and joins the threads.
    pub fn shutdown(mut self) {
        self.stop();
    }

    fn stop(&mut self) {
        if self.threads.is_empty() {
            return;
        }
        self.shared.stop.store(true, Ordering::SeqCst);
        self.shared.wake_all();
        // The link thread lets the writer send Bye, closes the socket and joins the reader.
        // One in the middle of a redial is left to finish it on its own (at most
        // [`REDIAL_TIMEOUT`]) and drop what it got.
        let redialing = matches!(lock(&self.shared.link).status, LinkStatus::Reconnecting { .. });
        let link = self.threads.pop();
        if let Some(l) = link {
            if !redialing {
                let _ = l.join();
            }
        }
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

impl Drop for Network {
    fn drop(&mut self) {
        self.stop();
    }
}

/// The token bucket of `--bandwidth-mbps` (one per direction).
fn link(mbps: Option<f64>) -> Option<TokenBucket> {
    mbps.and_then(TokenBucket::from_mbps)
}

/// One connection's reader and writer threads.
struct Session {
    stream: TcpStream,
    reader: JoinHandle<()>,
    writer: JoinHandle<()>,
    /// Frames received when it started.
    frames0: u64,
}

impl Session {
    /// Starts the reader and writer on `conn`; the writer sends the current view at once.
    fn start(
        sh: &Arc<Shared>,
        conn: Connection,
        cfg: &NetConfig,
        recorder: Option<RecordSink>,
    ) -> Result<Session, ClientError> {
        let stream = conn.stream;
        // The new connection renders with the server's start state until our edit is applied.
        sh.state_id.store(conn.visual.as_ref().map_or(0, |v| v.id), Ordering::SeqCst);
        lock(&sh.visual).state = conn.visual.clone();
        {
            let mut v = lock(&sh.view);
            if conn.visual.is_some() && v.edits.is_empty() {
                if let Some(e) = v.last_edit.clone() {
                    v.edits.push_back(e);
                }
            }
        }
        let (tls_link, tls_reader) = match conn.tls {
            Some(t) => (Some(t.link), Some(t.reader)),
            None => (None, None),
        };
        let _ = stream.set_read_timeout(Some(cfg.timeout.max(Duration::from_millis(10))));
        let clone = || stream.try_clone().map_err(|e| ClientError::Connect(format!("cannot share the socket: {e}")));
        let (rs, ws) = (clone()?, clone()?);
        sh.down.store(false, Ordering::SeqCst);
        lock(&sh.link).down = None;
        // A new connection has no request of ours yet: ask for the current view at once.
        lock(&sh.view).changed = true;
        let spawn_err = |e: std::io::Error| ClientError::Io(format!("cannot start a network thread: {e}"));
        let (sh_r, limits, read_mbps) = (sh.clone(), conn.limits, cfg.bandwidth_mbps);
        // The link model throttles the bytes on the wire (TLS records with TLS).
        let reader = std::thread::Builder::new()
            .name("volwarp-net-read".into())
            .spawn(move || {
                let raw: Box<dyn Read + Send> = match link(read_mbps) {
                    Some(b) => Box::new(Throttled::new(rs, b)),
                    None => Box::new(rs),
                };
                let src: Box<dyn Read + Send> = match tls_reader {
                    Some(t) => Box::new(t.with_raw(raw)),
                    None => raw,
                };
                read_loop(&sh_r, src, limits, recorder.as_ref())
            })
            .map_err(spawn_err)?;
        let (sh_w, request, write_mbps) = (sh.clone(), cfg.request, cfg.bandwidth_mbps);
        let writer = std::thread::Builder::new().name("volwarp-net-write".into()).spawn(move || {
            let raw: Box<dyn Write + Send> = match link(write_mbps) {
                Some(b) => Box::new(Throttled::new(ws, b)),
                None => Box::new(ws),
            };
            match tls_link {
                Some(l) => {
                    let mut w = l.writer(raw);
                    write_loop(&sh_w, &mut w, request);
                    // After the Bye of a client stopping (not on a dead connection).
                    if sh_w.stop.load(Ordering::SeqCst) {
                        w.close();
                    }
                }
                None => write_loop(&sh_w, raw, request),
            }
        });
        let writer = match writer {
            Ok(w) => w,
            Err(e) => {
                sh.drop_link(ClientError::Io(format!("cannot start a network thread: {e}")));
                let _ = stream.shutdown(Shutdown::Both);
                let _ = reader.join();
                return Err(spawn_err(e));
            }
        };
        Ok(Session { stream, reader, writer, frames0: sh.frames.load(Ordering::Relaxed) })
    }

    /// Waits until the connection ends or the network stops; then lets the writer finish
    /// (it sends Bye when stopping), closes the socket and joins the reader. Returns why the
    /// connection ended (`None`: the network was stopped) and whether it delivered a frame.
    fn finish(self, sh: &Shared) -> (Option<ClientError>, bool) {
        let mut g = lock(&sh.link);
        while g.down.is_none() && !sh.stop.load(Ordering::SeqCst) {
            g = sh.link_cv.wait_timeout(g, Duration::from_millis(200)).unwrap_or_else(|e| e.into_inner()).0;
        }
        let why = if sh.stop.load(Ordering::SeqCst) { None } else { g.down.clone() };
        drop(g);
        sh.down.store(true, Ordering::SeqCst);
        drop(lock(&sh.view));
        sh.view_cv.notify_all();
        let _ = self.writer.join();
        let _ = self.stream.shutdown(Shutdown::Both);
        let _ = self.reader.join();
        (why, sh.frames.load(Ordering::Relaxed) > self.frames0)
    }
}

/// Runs connections one after the other: the first, then (with `redial`) a new one after each
/// drop, until the network is stopped or fails for good.
fn link_loop(sh: &Arc<Shared>, first: Session, cfg: &NetConfig, recorder: Option<RecordSink>, redial: Option<Redial>) {
    let mut session = first;
    let mut attempt = 0u32;
    loop {
        let (why, delivered) = session.finish(sh);
        let Some(why) = why else { return };
        let Some(r) = &redial else { return sh.fail(why) };
        if is_permanent(&why) {
            return sh.fail(why);
        }
        if delivered {
            attempt = 0;
        }
        log::warn!("connection to {} lost: {why}; reconnecting", r.addr);
        let mut reason = why.to_string();
        session = loop {
            attempt = attempt.saturating_add(1);
            let wait = r.backoff.delay(attempt);
            let at = Instant::now() + wait;
            {
                let mut g = lock(&sh.link);
                g.status = LinkStatus::Reconnecting { attempt, at, reason: reason.clone() };
                while !sh.stop.load(Ordering::SeqCst) {
                    let left = at.saturating_duration_since(Instant::now());
                    if left.is_zero() {
                        break;
                    }
                    g = sh.link_cv.wait_timeout(g, left).unwrap_or_else(|e| e.into_inner()).0;
                }
            }
            if sh.stop.load(Ordering::SeqCst) {
                return;
            }
            let timeout = cfg.timeout.clamp(Duration::from_millis(10), REDIAL_TIMEOUT);
            let got = connect_secure(&r.addr, r.token.as_deref(), timeout, r.layers, r.tls.as_ref());
            if sh.stop.load(Ordering::SeqCst) {
                if let Ok(mut c) = got {
                    c.bye();
                }
                return;
            }
            let started = got.and_then(|c| {
                // Connected before the first frame of the new connection can arrive.
                lock(&sh.link).status = LinkStatus::Connected;
                sh.reconnects.fetch_add(1, Ordering::Relaxed);
                Session::start(sh, c, cfg, recorder.clone())
            });
            match started {
                Ok(s) => {
                    log::info!("reconnected to {} (attempt {attempt})", r.addr);
                    break s;
                }
                Err(e) if is_permanent(&e) => return sh.fail(e),
                Err(e) => {
                    log::debug!("reconnect attempt {attempt} to {}: {e}", r.addr);
                    reason = e.to_string();
                }
            }
        };
    }
}

fn read_loop(sh: &Shared, mut stream: impl Read, limits: Limits, recorder: Option<&RecordSink>) {
    loop {
        let got = read_message_bytes_marked(&mut stream, &limits, "waiting for a frame", || Busy::new(&sh.work_gen));
        if sh.ended() {
            return;
        }
        let (bytes, msg) = match got {
            Ok(m) => m,
            Err(e) => return sh.drop_link(e),
        };
        match msg {
            Message::Frame(frame) => {
                let received_at = Instant::now();
                let camera = frame.header.camera;
                let asked = lock(&sh.sent).iter().rev().find(|(s, ..)| *s == frame.header.seq).map(|&(_, t, d)| (t, d));
                let (requested_at, divisor) = (asked.map(|a| a.0), asked.map_or(1, |a| a.1));
                if let Some(r) = recorder {
                    r.frame(bytes);
                }
                sh.frames.fetch_add(1, Ordering::Relaxed);
                {
                    let mut q = lock(&sh.pending);
                    if q.len() >= MAX_PENDING {
                        q.pop_front();
                    }
                    let state = sh.state_id.load(Ordering::SeqCst);
                    q.push_back(Pending { frame, state, requested_at, divisor, received_at });
                }
                sh.pending_cv.notify_one();
                {
                    let mut g = lock(&sh.view);
                    g.frame_arrived = true;
                    g.held.retain(|c| *c != camera);
                    g.held.push_front(camera);
                    g.held.truncate(volwarp_core::method::PREFETCH_HELD);
                }
                sh.view_cv.notify_one();
            }
            Message::VisualState(v) => {
                log::info!("server: visual state {} ({})", v.id, describe_state(&v));
                sh.state_id.store(v.id, Ordering::SeqCst);
                lock(&sh.visual).state = Some(v);
            }
            // A refused edit: the connection stays, the state is unchanged.
            Message::Error(e) if e.code == error_code::BAD_EDIT => {
                log::warn!("server: {}", e.text);
                lock(&sh.visual).refused = Some(e.text.to_string());
            }
            Message::Error(e) => return sh.drop_link(server_error(&e)),
            Message::Bye => return sh.drop_link(ClientError::Gone("the server said goodbye".into())),
            Message::Hello(_) | Message::CameraRequest(_) | Message::VisualEdit(_) => {
                return sh.drop_link(ClientError::Protocol("the server sent an unexpected message".into()))
            }
        }
    }
}

/// A visual state in a few words, for logs and titles: the preset (or the function), window and
/// level, opacity, crop and clip where set.
pub fn describe_state(v: &VisualState) -> String {
    let tf = if v.custom {
        "custom function"
    } else if v.preset.is_empty() {
        "start function"
    } else {
        v.preset.as_str()
    };
    let mut s = format!("{tf} W {:.2} L {:.2}", v.window_level[0], v.window_level[1]);
    if v.opacity_scale != 1.0 {
        s.push_str(&format!(" opacity {:.2}", v.opacity_scale));
    }
    if v.crop != [0.0, 0.0, 0.0, 1.0, 1.0, 1.0] {
        let c = v.crop;
        s.push_str(&format!(" crop {:.2},{:.2},{:.2}-{:.2},{:.2},{:.2}", c[0], c[1], c[2], c[3], c[4], c[5]));
    }
    if v.clip.is_some() {
        s.push_str(" clip");
    }
    if v.shade {
        s.push_str(" lit");
    }
    s
}

fn build_loop(sh: &Shared, cfg: &NetConfig) {
    let mut builder = ParallelBuilder::new(cfg.build_threads);
    loop {
        let next = {
            let mut q = lock(&sh.pending);
            loop {
                if sh.stop.load(Ordering::SeqCst) {
                    return;
                }
                let now = Instant::now();
                match q.front() {
                    Some(p) if p.received_at + cfg.latency <= now => {
                        // Keep the newest frame that is due; drop older ones.
                        let mut newest = q.pop_front();
                        while q.front().is_some_and(|p| p.received_at + cfg.latency <= now) {
                            newest = q.pop_front();
                        }
                        break newest;
                    }
                    Some(p) => {
                        let wait = (p.received_at + cfg.latency).saturating_duration_since(now);
                        q = sh.pending_cv.wait_timeout(q, wait).unwrap_or_else(|e| e.into_inner()).0;
                    }
                    None => q = sh.pending_cv.wait(q).unwrap_or_else(|e| e.into_inner()),
                }
            }
        };
        let Some(p) = next else { continue };
        let busy = Busy::new(&sh.work_gen);
        let t0 = Instant::now();
        // The server's own time for the frame, which splits the prediction horizon's span.
        let render_s = f64::from(p.frame.header.render_us) * 1e-6;
        let scene = if cfg.lazy_build {
            volwarp_cpu_tracer::route::into_unbuilt_scene(p.frame)
        } else {
            let mut scene = lock(&sh.recycle).take().unwrap_or_else(|| Scene::empty(&p.frame.header));
            builder.build_into(&p.frame, &mut scene);
            drop(p.frame);
            scene
        };
        let build_ms = t0.elapsed().as_secs_f64() * 1e3;
        drop(busy);
        sh.built.fetch_add(1, Ordering::Relaxed);
        if let Some(r) = p.requested_at {
            // The prediction horizon: request-to-ready plus half the interval between frames
            // (core's `prediction::Horizon`), on the clock of the horizon's creation.
            let mut h = lock(&sh.horizon);
            let t0 = h.1;
            let secs = |t: Instant| t.saturating_duration_since(t0).as_secs_f64();
            h.0.observe(secs(r), secs(Instant::now()), render_s, p.divisor);
        }
        log::debug!("built scene seq {} ({} samples) in {build_ms:.1} ms", scene.header.seq, scene.samples.len());
        let ready = ReadyScene {
            state: p.state,
            seq: scene.header.seq,
            scene,
            requested_at: p.requested_at,
            received_at: p.received_at,
            build_ms,
        };
        // A scene the display has not picked up yet is replaced; its buffers are reused.
        let old = lock(&sh.ready).replace(ready);
        if let Some(old) = old {
            let mut r = lock(&sh.recycle);
            if r.is_none() {
                *r = Some(old.scene);
            }
        }
    }
}

/// Sends a request whenever core's request policy says one is due on the [`CADENCE`] (at most
/// every [`THROTTLE`]), for the camera it picks: predicted for the measured horizon by the
/// display's own predictor (which has seen every camera shown), widened by a guard band.
fn write_loop(sh: &Shared, mut stream: impl Write, request: RequestPolicy) {
    let mut last_send: Option<Instant> = None;
    loop {
        let (view, predictor, moving, side) = {
            let mut g = lock(&sh.view);
            loop {
                if sh.stop.load(Ordering::SeqCst) {
                    drop(g);
                    send_bye(&mut stream);
                    return;
                }
                if sh.down.load(Ordering::SeqCst) {
                    return;
                }
                // Edits first, unthrottled: the server applies them to its next frame.
                if !g.edits.is_empty() {
                    let edits: Vec<VisualEdit> = g.edits.drain(..).collect();
                    drop(g);
                    for e in &edits {
                        if let Err(err) = crate::connection::send_edit(&mut stream, e) {
                            return sh.drop_link(ClientError::Gone(format!("cannot send the visual edit: {err}")));
                        }
                        log::debug!("sent visual edit {}", e.id);
                    }
                    g = lock(&sh.view);
                    continue;
                }
                let events =
                    ViewEvents { moved: g.changed, first_still: g.first_still, frame_arrived: g.frame_arrived };
                if let Some(v) = g.view.filter(|_| request.due(&CADENCE, events)) {
                    let now = Instant::now();
                    match last_send.map(|t| t + THROTTLE).filter(|next| *next > now) {
                        Some(next) => {
                            g = sh.view_cv.wait_timeout(g, next - now).unwrap_or_else(|e| e.into_inner()).0;
                            continue;
                        }
                        None => {
                            // Moving until it has held still for `STILL_AFTER` display frames
                            // (so the request a frame's arrival triggers between two display
                            // frames of an orbit or a drag is coarse too); the request for the
                            // view come to rest asks for that view.
                            let moving = !g.first_still && g.still_frames < STILL_AFTER;
                            // At rest, a frame's arrival asks for the next side view the
                            // frames lack once the view's own frame is there.
                            let resting = !moving && !g.changed && !g.first_still;
                            let side =
                                if resting { request.prefetch(&v.camera, g.held.make_contiguous()) } else { None };
                            g.changed = false;
                            g.frame_arrived = false;
                            g.first_still = false;
                            break (v, g.predictor, moving, side);
                        }
                    }
                }
                g = sh.view_cv.wait(g).unwrap_or_else(|e| e.into_inner());
            }
        };
        let seq = sh.seq.fetch_add(1, Ordering::SeqCst) + 1;
        let horizon = lock(&sh.horizon).0;
        // While the view moves, on the coarser grid of adaptive resolution (`--coarse`), coarser
        // still while it turns fast; a coarse view differs from the view at rest, so resting
        // asks again at full resolution.
        let motion = request.motion(moving, &predictor, &horizon, &CADENCE);
        let asks = match side {
            // A side view leaves `asked` the resting view's: it is no overshoot to correct.
            Some(side) => {
                log::debug!("asking for a side view at rest");
                side
            }
            None => {
                let asks = request.camera_at(view.camera, motion, &predictor, &horizon, &CADENCE);
                lock(&sh.view).asked = Some(asks.view);
                asks
            }
        };
        let camera = asks.camera;
        // At rest, the segments per pixel of `--rest-layers` (a one-sample frame by default).
        let req = CameraRequest {
            seq,
            camera,
            heuristic: view.heuristic,
            radius_scale: view.radius_scale,
            layers: asks.layers,
        };
        let now = Instant::now();
        {
            let mut s = lock(&sh.sent);
            if s.len() >= MAX_SENT {
                s.pop_front();
            }
            s.push_back((seq, now, asks.divisor));
        }
        last_send = Some(now);
        if let Err(e) = send_request(&mut stream, &req) {
            return sh.drop_link(ClientError::Gone(format!("cannot send the camera: {e}")));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_doubles_to_its_cap_with_bounded_deterministic_jitter() {
        let b = Backoff::default();
        for attempt in 1..40 {
            let full =
                Duration::from_millis(100).saturating_mul(1 << (attempt - 1).min(20)).min(Duration::from_secs(2));
            let d = b.delay(attempt);
            assert!(d >= full / 2 && d <= full, "attempt {attempt}: {d:?} outside [{:?}, {full:?}]", full / 2);
            assert_eq!(d, b.delay(attempt), "the same seed gives the same wait");
        }
        assert!(b.delay(u32::MAX) <= Duration::from_secs(2));
        let other = Backoff { seed: 7, ..b };
        assert!((1..10).any(|a| other.delay(a) != b.delay(a)), "another seed, other waits");
    }

    #[test]
    fn only_refusals_that_cannot_change_are_permanent() {
        let server = |code| ClientError::Server { code, text: String::new() };
        for e in [
            server(error_code::UNAUTHORIZED),
            server(error_code::UNSUPPORTED_VERSION),
            server(error_code::BAD_REQUEST),
            server(error_code::TOO_LARGE),
            ClientError::Version("v".into()),
        ] {
            assert!(is_permanent(&e), "{e}");
        }
        for e in [
            server(error_code::BUSY),
            server(error_code::TIMEOUT),
            server(error_code::INTERNAL),
            server(error_code::RATE_LIMITED),
            ClientError::Connect("refused".into()),
            ClientError::Gone("bye".into()),
            ClientError::Protocol("junk".into()),
        ] {
            assert!(!is_permanent(&e), "{e}");
        }
    }

    #[test]
    fn the_state_reads_as_a_title_line() {
        assert_eq!(ConnectionState::Connected.label(), None);
        let r = ConnectionState::Reconnecting {
            attempt: 3,
            next_in: Duration::from_millis(1500),
            reason: "cannot connect: refused".into(),
        };
        assert_eq!(r.label().unwrap(), "reconnecting in 1.5 s… (attempt 3; cannot connect: refused)");
        let f = ConnectionState::Failed(ClientError::Server { code: 3, text: "missing or wrong token".into() });
        assert!(f.label().unwrap().contains("missing or wrong token"));
    }
}
