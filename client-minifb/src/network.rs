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
//!   the camera widened by a guard band (core's `guard`).
//!
//! The display loop only ever `try_lock`s the slot ([`Network::take_scene`]); every lock the
//! display takes is held for a few instructions.

use crate::connection::{read_message_bytes_marked, send_bye, send_request, server_error, Connection};
use crate::error::ClientError;
use crate::link::{Throttled, TokenBucket};
use crate::record::RecordSink;
use std::collections::VecDeque;
use std::io::{Read, Write};
use std::net::{Shutdown, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use volwarp_core::method::{Cadence, RequestPolicy, ViewEvents};
use volwarp_core::prediction::{Horizon, Predictor};
use volwarp_core::wire::{CameraRequest, Frame, Limits, Message};
use volwarp_core::{Camera, Heuristic, Scene};
use volwarp_cpu_tracer::ParallelBuilder;
use volwarp_cpu_tracer::MAX_VIEWPORT;

/// Shortest time between two camera requests.
pub const THROTTLE: Duration = Duration::from_millis(30);
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
/// ~16 ms) and a frame's arrival alone triggers a request, so the server always has work; no
/// extra request when the view stops (the arrival of the next frame asks for the still view).
pub const CADENCE: Cadence =
    Cadence { display_tick_s: 1.0 / 60.0, on_frame_arrival: true, on_first_still: false, max_viewport: MAX_VIEWPORT };

struct Pending {
    frame: Frame,
    requested_at: Option<Instant>,
    received_at: Instant,
}

#[derive(Default)]
struct ViewSlot {
    view: Option<View>,
    changed: bool,
    frame_arrived: bool,
    /// Every camera the display showed, timed (so motion that starts after a still spell is
    /// measured from the last still display frame, not from the last request).
    predictor: Predictor,
    /// The predictor's clock.
    t0: Option<Instant>,
}

struct Shared {
    stop: AtomicBool,
    view: Mutex<ViewSlot>,
    view_cv: Condvar,
    pending: Mutex<VecDeque<Pending>>,
    pending_cv: Condvar,
    ready: Mutex<Option<ReadyScene>>,
    recycle: Mutex<Option<Scene>>,
    sent: Mutex<VecDeque<(u64, Instant)>>,
    error: Mutex<Option<ClientError>>,
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
    fn fail(&self, e: ClientError) {
        if self.stop.load(Ordering::SeqCst) {
            return;
        }
        log::debug!("network: {e}");
        let mut g = lock(&self.error);
        if g.is_none() {
            *g = Some(e);
        }
        drop(g);
        self.stop.store(true, Ordering::SeqCst);
        self.view_cv.notify_all();
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
    stream: TcpStream,
    threads: Vec<JoinHandle<()>>,
}

impl Network {
    /// Starts the reader, builder and writer threads on an open connection.
    pub fn start(conn: Connection, cfg: NetConfig, recorder: Option<RecordSink>) -> Result<Network, ClientError> {
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
            frames: AtomicU64::new(0),
            built: AtomicU64::new(0),
            work_gen: AtomicU64::new(0),
            horizon: Mutex::new((Horizon::new(), Instant::now())),
        });
        let stream = conn.stream;
        let _ = stream.set_read_timeout(Some(cfg.timeout.max(Duration::from_millis(10))));
        let clone = || stream.try_clone().map_err(|e| ClientError::Connect(format!("cannot share the socket: {e}")));
        let (rs, ws) = (clone()?, clone()?);
        let spawn_err = |e: std::io::Error| ClientError::Io(format!("cannot start a network thread: {e}"));
        let mut threads = Vec::new();
        let (sh, limits) = (shared.clone(), conn.limits);
        let (read_mbps, write_mbps) = (cfg.bandwidth_mbps, cfg.bandwidth_mbps);
        threads.push(
            std::thread::Builder::new()
                .name("volwarp-net-read".into())
                .spawn(move || match link(read_mbps) {
                    Some(b) => read_loop(&sh, Throttled::new(rs, b), limits, recorder),
                    None => read_loop(&sh, rs, limits, recorder),
                })
                .map_err(spawn_err)?,
        );
        let sh = shared.clone();
        let build_cfg = cfg.clone();
        threads.push(
            std::thread::Builder::new()
                .name("volwarp-net-build".into())
                .spawn(move || build_loop(&sh, &build_cfg))
                .map_err(spawn_err)?,
        );
        let sh = shared.clone();
        let request = cfg.request;
        threads.push(
            std::thread::Builder::new()
                .name("volwarp-net-write".into())
                .spawn(move || match link(write_mbps) {
                    Some(b) => write_loop(&sh, Throttled::new(ws, b), request),
                    None => write_loop(&sh, ws, request),
                })
                .map_err(spawn_err)?,
        );
        Ok(Network { shared, stream, threads })
    }

    /// Publishes the view the display shows now; the writer sends it (throttled) if it
    /// differs from the last one. Never waits on the network.
    pub fn set_view(&self, view: View) {
        let mut g = lock(&self.shared.view);
        let now = Instant::now();
        let t0 = *g.t0.get_or_insert(now);
        g.predictor.observe(view.camera, now.saturating_duration_since(t0).as_secs_f64());
        if g.view != Some(view) {
            g.view = Some(view);
            g.changed = true;
            drop(g);
            self.shared.view_cv.notify_one();
        }
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
        self.shared.view_cv.notify_all();
        self.shared.pending_cv.notify_all();
        // The writer sends Bye on its way out; then the socket is closed to wake the reader.
        let writer = self.threads.pop();
        if let Some(w) = writer {
            let _ = w.join();
        }
        let _ = self.stream.shutdown(Shutdown::Both);
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

fn read_loop(sh: &Shared, mut stream: impl Read, limits: Limits, recorder: Option<RecordSink>) {
    loop {
        let got = read_message_bytes_marked(&mut stream, &limits, "waiting for a frame", || Busy::new(&sh.work_gen));
        if sh.stop.load(Ordering::SeqCst) {
            return;
        }
        let (bytes, msg) = match got {
            Ok(m) => m,
            Err(e) => return sh.fail(e),
        };
        match msg {
            Message::Frame(frame) => {
                let received_at = Instant::now();
                let requested_at = lock(&sh.sent).iter().rev().find(|(s, _)| *s == frame.header.seq).map(|(_, t)| *t);
                if let Some(r) = &recorder {
                    r.frame(bytes);
                }
                sh.frames.fetch_add(1, Ordering::Relaxed);
                {
                    let mut q = lock(&sh.pending);
                    if q.len() >= MAX_PENDING {
                        q.pop_front();
                    }
                    q.push_back(Pending { frame, requested_at, received_at });
                }
                sh.pending_cv.notify_one();
                lock(&sh.view).frame_arrived = true;
                sh.view_cv.notify_one();
            }
            Message::Error(e) => return sh.fail(server_error(&e)),
            Message::Bye => return sh.fail(ClientError::Gone("the server said goodbye".into())),
            Message::Hello(_) | Message::CameraRequest(_) => {
                return sh.fail(ClientError::Protocol("the server sent an unexpected message".into()))
            }
        }
    }
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
            h.0.observe(secs(r), secs(Instant::now()));
        }
        log::debug!("built scene seq {} ({} samples) in {build_ms:.1} ms", scene.header.seq, scene.samples.len());
        let ready = ReadyScene {
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
    let mut seq = 0u64;
    let mut last_send: Option<Instant> = None;
    loop {
        let (view, predictor) = {
            let mut g = lock(&sh.view);
            loop {
                if sh.stop.load(Ordering::SeqCst) {
                    drop(g);
                    send_bye(&mut stream);
                    return;
                }
                let events = ViewEvents { moved: g.changed, first_still: false, frame_arrived: g.frame_arrived };
                if let Some(v) = g.view.filter(|_| request.due(&CADENCE, events)) {
                    let now = Instant::now();
                    match last_send.map(|t| t + THROTTLE).filter(|next| *next > now) {
                        Some(next) => {
                            g = sh.view_cv.wait_timeout(g, next - now).unwrap_or_else(|e| e.into_inner()).0;
                            continue;
                        }
                        None => {
                            g.changed = false;
                            g.frame_arrived = false;
                            break (v, g.predictor);
                        }
                    }
                }
                g = sh.view_cv.wait(g).unwrap_or_else(|e| e.into_inner());
            }
        };
        seq += 1;
        let horizon = lock(&sh.horizon).0;
        let camera = request.camera(view.camera, &predictor, &horizon, &CADENCE).camera;
        let req = CameraRequest { seq, camera, heuristic: view.heuristic, radius_scale: view.radius_scale };
        let now = Instant::now();
        {
            let mut s = lock(&sh.sent);
            if s.len() >= MAX_SENT {
                s.pop_front();
            }
            s.push_back((seq, now));
        }
        last_send = Some(now);
        if let Err(e) = send_request(&mut stream, &req) {
            return sh.fail(ClientError::Gone(format!("cannot send the camera: {e}")));
        }
    }
}
