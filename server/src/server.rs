//! The TCP server: plain `std::net` and threads, one pair of threads per client.
//!
//! **Protocol per connection** (messages of [`volwarp_core::wire`]): the client sends Hello
//! (with the token if the server has one), the server answers Hello; then the client sends
//! CameraRequests whenever its camera changes and the server answers with Frames. A reader
//! thread keeps only the **newest** request; the render-and-send loop always renders the newest
//! one it has (latest wins: no queue of stale work, so a client's memory stays at about two
//! frames). Bye ends the connection.
//!
//! **A render the view's turn makes stale is dropped.** A client with adaptive resolution asks
//! for a coarser viewport while its view moves and the full one at rest, so a request whose
//! viewport differs from the one being rendered says the view has come to rest or started
//! moving: the reader sets the render's stop flag, the marcher leaves its remaining row bands
//! (and a `--server-delay-ms` wait ends), nothing of it is sent or published, and the newest
//! request is rendered at once. The render after a dropped one is never dropped, so a client
//! whose view flips between moving and still at every tick still gets every other frame.
//! (One-process server; MPI ranks finish every frame.)
//!
//! **So is a frame on the link when the view starts moving.** A client that reassembles frames
//! sent in parts (wire version 6, `CAP_PARTS`) gets each frame as parts of [`wire::PART_LEN`]
//! bytes; a request for a coarser viewport (the view started moving) that arrives while a
//! frame is written ends it after the part under way with FrameDropped, also right after a
//! dropped render: the coarse frame asked for is never dropped on the link (no request is
//! coarser), so frames keep coming however often the view turns. The socket keeps at most
//! [`NOTSENT_LOWAT`] bytes not yet sent (Linux's `TCP_NOTSENT_LOWAT`), so what the link still
//! carries of a dropped frame is that, the part and a round trip's bytes in flight: on a slow
//! link a full-resolution frame's megabytes no longer hold up the first frame of the move.
//!
//! **Several clients** share one marcher thread pool through a [`RenderQueue`]: each frame is
//! one job in the pool's first-in-first-out queue (no client starves another), and a request
//! identical to one being (or just) rendered gets a copy of that frame instead of a second
//! render.
//!
//! **Failure handling.** A handshake that does not finish within the handshake timeout, an idle
//! client (no message within the idle timeout), a wrong token, an oversized or malformed
//! message, or a viewport over the limit ends *that* connection: the server sends an Error
//! message where the socket still allows, logs the reason and closes. Other clients carry on.
//! Over `max_clients` a new client gets Error `BUSY`. Bound to a non-loopback address the
//! server refuses to start without a token; the token is compared in constant time.
//!
//! **Token guessing** is rate-limited per source address (IPv6: per /64): each handshake takes
//! one attempt from the address's bucket of `max_auth_failures` per second (as deep as its rate)
//! and gets it back unless its token was wrong. An address whose bucket is empty gets Error
//! `RATE_LIMITED` and a close at once, before any byte of its Hello is read.
//!
//! **TLS** ([`ServerConfig::tls`]): each connection's first byte tells a TLS ClientHello from a
//! plain volwarp Hello. A TLS client gets the handshake (within the handshake timeout), then the
//! same protocol inside it, its reader and writer threads sharing one rustls state
//! ([`volwarp_tls::TlsLink`]); a plain client gets a plain Error `BAD_REQUEST` saying the server
//! speaks TLS only. Refusals at accept time (`BUSY`, `RATE_LIMITED`) are sent in plain before any
//! handshake, so they cost no TLS work; volwarp clients read them either way.

use crate::dataset::Dataset;
use crate::marcher::{FrameStats, Marcher};
use crate::render_queue::{LevelPolicy, RenderCounts, RenderQueue};
use crate::transfer_function::TransferFunction;
use crate::visual::VisualState;
use std::collections::HashMap;
use std::io::{self, BufWriter, Read, Write};
use std::net::{IpAddr, Ipv6Addr, Shutdown, SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use volwarp_core::compact_frame::Encoding;
use volwarp_core::wire::{
    self, error_code, CameraRequest, ErrorMsg, Frame, Hello, Limits, Message, VisualEdit, WireError,
};
use volwarp_tls::{TlsLink, TlsReader, TlsWriter};

/// A server's TLS certificate chain and key, ready to serve (`--tls-cert`, `--tls-key`).
#[derive(Clone, Debug)]
pub struct TlsIdentity(pub Arc<volwarp_tls::rustls::ServerConfig>);

impl TlsIdentity {
    /// Reads a PEM certificate chain (leaf first) and its PEM private key.
    pub fn from_pem_files(cert: &std::path::Path, key: &std::path::Path) -> Result<TlsIdentity, String> {
        volwarp_tls::server_config(cert, key).map(TlsIdentity)
    }
}

impl PartialEq for TlsIdentity {
    /// The same identity: the same loaded config.
    fn eq(&self, other: &Self) -> bool {
        Arc::ptr_eq(&self.0, &other.0)
    }
}

/// Server settings (every limit has a command-line flag in the binary).
#[derive(Clone, Debug, PartialEq)]
pub struct ServerConfig {
    /// Address to listen on (default `127.0.0.1:7878`; port 0 picks a free port).
    pub listen: SocketAddr,
    /// Marcher threads shared by all clients (0 = one per core).
    pub threads: usize,
    /// Most clients served at once; more get Error `BUSY`.
    pub max_clients: usize,
    /// Largest client message payload accepted, in bytes (at most what an Error message needs).
    pub max_message: u32,
    /// Time a new client has to complete the Hello exchange.
    pub handshake_timeout: Duration,
    /// Time a client may send nothing before it is dropped.
    pub idle_timeout: Duration,
    /// Time a frame may take to send before the client is dropped.
    pub send_timeout: Duration,
    /// Largest viewport width or height a request may ask for.
    pub max_viewport: u32,
    /// Access token; required when `listen` is not a loopback address.
    pub token: Option<String>,
    /// Wrong tokens accepted per second from one source address (IPv6: one /64), in bursts of
    /// as many; beyond that the address's connections get Error `RATE_LIMITED` before the
    /// handshake. 0: no limit. Used only with a token. Default 10.
    pub max_auth_failures: u32,
    /// Serve over TLS with this identity (`None`, the default: plain TCP).
    pub tls: Option<TlsIdentity>,
    /// Artificial delay before each frame (latency demos and benchmarks).
    pub frame_delay: Option<Duration>,
    /// Send CompactFrames to clients that ask for them (`CAP_COMPACT` in their Hello);
    /// default true. Off, every client gets 12-byte Frames.
    pub compact: bool,
    /// Most segments per pixel the server renders for a client that asks for layered frames
    /// in its Hello (1: one sample per pixel for everyone). Default
    /// [`volwarp_core::segments::MAX_LAYERS`]: the client chooses.
    pub layers: u8,
    /// The frame time to keep within while a client's camera moves, by marching a coarser level
    /// of detail ([`crate::render_queue::LevelPolicy`]; used where the server has levels,
    /// [`Server::with_levels`]). Default `None`: always the volume itself.
    pub frame_budget: Option<Duration>,
}

impl Default for ServerConfig {
    fn default() -> Self {
        ServerConfig {
            listen: SocketAddr::from(([127, 0, 0, 1], 7878)),
            threads: 0,
            max_clients: 8,
            max_message: Limits::for_requests(4096).max_payload,
            handshake_timeout: Duration::from_secs(5),
            idle_timeout: Duration::from_secs(600),
            send_timeout: Duration::from_secs(30),
            max_viewport: 4096,
            token: None,
            max_auth_failures: 10,
            tls: None,
            frame_delay: None,
            compact: true,
            layers: volwarp_core::segments::MAX_LAYERS as u8,
            frame_budget: None,
        }
    }
}

/// Compares two byte strings in time that depends only on their lengths.
pub fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    let n = a.len().max(b.len());
    let mut diff = u8::from(a.len() != b.len());
    for i in 0..n {
        diff |= a.get(i).copied().unwrap_or(0) ^ b.get(i).copied().unwrap_or(0);
    }
    std::hint::black_box(diff) == 0
}

/// Most source addresses the token-guessing limiter remembers; beyond that, the ones whose
/// bucket has refilled are forgotten.
const MAX_TRACKED_ADDRESSES: usize = 4096;

/// The token-guessing limiter: a token bucket of wrong-token attempts per source address.
struct AuthLimiter {
    rate: f64,
    buckets: Mutex<HashMap<IpAddr, (f64, Instant)>>,
}

impl AuthLimiter {
    fn new(per_second: u32) -> Self {
        AuthLimiter { rate: f64::from(per_second), buckets: Mutex::new(HashMap::new()) }
    }

    /// The bucket an address uses: IPv4 (also IPv4-mapped IPv6) as is, IPv6 by its /64 (one
    /// host usually owns a whole /64).
    fn key(ip: IpAddr) -> IpAddr {
        match ip.to_canonical() {
            IpAddr::V6(v6) => {
                let s = v6.segments();
                IpAddr::V6(Ipv6Addr::new(s[0], s[1], s[2], s[3], 0, 0, 0, 0))
            }
            v4 => v4,
        }
    }

    /// Takes one attempt from `ip`'s bucket; false (nothing taken) when it is empty.
    fn charge(&self, ip: IpAddr) -> bool {
        let now = Instant::now();
        let mut b = self.buckets.lock().unwrap_or_else(|e| e.into_inner());
        if b.len() >= MAX_TRACKED_ADDRESSES {
            let rate = self.rate;
            b.retain(|_, (tokens, last)| *tokens + now.duration_since(*last).as_secs_f64() * rate < rate);
        }
        let (tokens, last) = b.entry(Self::key(ip)).or_insert((self.rate, now));
        *tokens = (*tokens + now.duration_since(*last).as_secs_f64() * self.rate).min(self.rate);
        *last = now;
        if *tokens < 1.0 {
            return false;
        }
        *tokens -= 1.0;
        true
    }

    /// Gives back the attempt a handshake took (its token was right, or never compared).
    fn refund(&self, ip: IpAddr) {
        let mut b = self.buckets.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((tokens, _)) = b.get_mut(&Self::key(ip)) {
            *tokens = (*tokens + 1.0).min(self.rate);
        }
    }
}

/// One handshake's attempt from its address's bucket: given back when dropped, unless the
/// token turned out wrong.
struct AuthCharge<'a> {
    limiter: &'a AuthLimiter,
    ip: IpAddr,
    spent: bool,
}

impl Drop for AuthCharge<'_> {
    fn drop(&mut self) {
        if !self.spent {
            self.limiter.refund(self.ip);
        }
    }
}

/// Renders and encodes a server's frames in place of its marcher (the MPI front end,
/// [`crate::distributed`]): rank 0 serves clients exactly as a one-process server does.
pub trait FrameSource: Send + Sync {
    /// Renders `req` with at most `layers` segments per pixel into `frame`; an error (a rank
    /// failed) is sent to the client, which is then disconnected.
    fn render(&self, req: &CameraRequest, layers: u32, frame: &mut Frame) -> Result<FrameStats, String>;
    /// The message bytes (header included) of a frame it rendered, in `encoding` where the
    /// frame fits it, for a receiver of colors coded against green (`green`) or not.
    fn encode(&self, req: &CameraRequest, frame: &Frame, encoding: Encoding, green: bool) -> (Vec<u8>, Encoding);
    /// Why the source can render no more frames (a rank failed), or `None` while it can: every
    /// client, waiting for a frame or idle, is then sent this as an `INTERNAL` error and
    /// disconnected (an idle client within [`SOURCE_POLL`]).
    fn failed(&self) -> Option<String> {
        None
    }
}

/// How often an idle client's thread asks a [`FrameSource`] whether it failed.
pub const SOURCE_POLL: Duration = Duration::from_millis(100);

struct Shared {
    config: ServerConfig,
    /// Where frames come from instead of the render queue, if set.
    source: Option<Arc<dyn FrameSource>>,
    /// The token-guessing limiter (with a token and a nonzero `max_auth_failures` only).
    auth: Option<AuthLimiter>,
    marcher: Arc<Marcher>,
    queue: RenderQueue,
    /// What clients' visual edits start from.
    visual: LiveVisual,
    /// The next id of a client's own marchers ([`RenderQueue::render_view_until`]).
    next_generation: AtomicU32,
    stop: AtomicBool,
    active: AtomicUsize,
    next_id: AtomicU64,
    conns: Mutex<HashMap<u64, TcpStream>>,
    threads: Mutex<Vec<JoinHandle<()>>>,
}

/// What a client's visual edits apply to: the transfer function given at start (shown where
/// the state names no preset) and the state the server started with (every client's first).
#[derive(Clone, Debug)]
struct LiveVisual {
    base: TransferFunction,
    start: VisualState,
}

/// A bound server, not yet serving.
pub struct Server {
    listener: TcpListener,
    addr: SocketAddr,
    shared: Arc<Shared>,
}

/// A server running on a background thread; [`ServerHandle::shutdown`] (or drop) stops it.
pub struct ServerHandle {
    addr: SocketAddr,
    shared: Arc<Shared>,
    accept: Option<JoinHandle<()>>,
}

impl Server {
    /// Checks the config, builds the marcher of `dataset` (and its levels of detail where
    /// `config.frame_budget` is set) and binds the listener.
    pub fn bind(config: ServerConfig, dataset: Dataset) -> io::Result<Server> {
        let server = Server::with_transfer_function(config, Marcher::from_dataset(&dataset), &dataset.tf)?;
        Ok(server.with_visual(dataset.tf.clone(), VisualState::default()))
    }

    /// Like [`Server::bind`] with a ready marcher of transfer function `tf`: its levels of
    /// detail are built where `config.frame_budget` asks for them.
    pub fn with_transfer_function(
        config: ServerConfig,
        marcher: Marcher,
        tf: &crate::transfer_function::TransferFunction,
    ) -> io::Result<Server> {
        // A frame budget needs the levels of detail to choose from.
        let levels = match config.frame_budget {
            Some(_) => marcher.levels(tf).map_err(|e| io::Error::other(e.to_string()))?,
            None => vec![Arc::new(marcher)],
        };
        Server::with_levels(config, levels)
    }

    /// Like [`Server::bind`] with a ready marcher.
    pub fn with_marcher(config: ServerConfig, marcher: Arc<Marcher>) -> io::Result<Server> {
        Server::with_levels(config, vec![marcher])
    }

    /// Like [`Server::with_marcher`] with a marcher per level of detail, the volume itself
    /// first ([`Marcher::levels`]); `config.frame_budget` says when a coarser one is marched.
    pub fn with_levels(config: ServerConfig, levels: Vec<Arc<Marcher>>) -> io::Result<Server> {
        let invalid = |m: &str| io::Error::new(io::ErrorKind::InvalidInput, m.to_string());
        if config.token.is_none() && !config.listen.ip().is_loopback() {
            return Err(invalid("a token (--token) is required to listen on a non-loopback address"));
        }
        if let Some(t) = &config.token {
            if t.is_empty() || t.len() > wire::MAX_TOKEN {
                return Err(invalid("the token must be 1 to 64 bytes"));
            }
        }
        let Some(marcher) = levels.first().cloned() else {
            return Err(invalid("a server needs a marcher"));
        };
        if config.max_viewport == 0 || config.max_clients == 0 {
            return Err(invalid("max viewport and max clients must be at least 1"));
        }
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(config.threads)
            .thread_name(|i| format!("volwarp-march-{i}"))
            .build()
            .map_err(|e| io::Error::other(e.to_string()))?;
        let listener = TcpListener::bind(config.listen)?;
        let addr = listener.local_addr()?;
        let policy = LevelPolicy { budget: config.frame_budget };
        let auth = (config.token.is_some() && config.max_auth_failures > 0)
            .then(|| AuthLimiter::new(config.max_auth_failures));
        let visual = LiveVisual { base: marcher.transfer_function().clone(), start: VisualState::default() };
        let shared = Arc::new(Shared {
            config,
            source: None,
            auth,
            visual,
            next_generation: AtomicU32::new(1),
            queue: RenderQueue::with_levels(levels, policy, pool),
            marcher,
            stop: AtomicBool::new(false),
            active: AtomicUsize::new(0),
            next_id: AtomicU64::new(1),
            conns: Mutex::new(HashMap::new()),
            threads: Mutex::new(Vec::new()),
        });
        Ok(Server { listener, addr, shared })
    }

    /// The bound address (with the real port when the config asked for port 0).
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// The server with its frames rendered and encoded by `source` (its marcher then only
    /// names the volume in the log).
    pub fn with_source(self, source: Arc<dyn FrameSource>) -> Server {
        let mut shared = match Arc::try_unwrap(self.shared) {
            Ok(s) => s,
            Err(_) => unreachable!("a server not yet serving holds its state alone"),
        };
        shared.source = Some(source);
        Server { listener: self.listener, addr: self.addr, shared: Arc::new(shared) }
    }

    /// The server's visual state for clients' live edits (VisualEdit messages): `base` is the
    /// transfer function given at start (shown where a state names no preset), `start` the
    /// state its marchers were built with (`Marcher::with_visual`), every client's first.
    /// Without it, edits apply over the marcher's own function from the default state.
    pub fn with_visual(self, base: TransferFunction, start: VisualState) -> Server {
        let mut shared = match Arc::try_unwrap(self.shared) {
            Ok(s) => s,
            Err(_) => unreachable!("a server not yet serving holds its state alone"),
        };
        shared.visual = LiveVisual { base, start };
        Server { listener: self.listener, addr: self.addr, shared: Arc::new(shared) }
    }

    /// Serves on a background thread.
    pub fn spawn(self) -> ServerHandle {
        let (addr, shared) = (self.addr, self.shared.clone());
        let accept = std::thread::Builder::new()
            .name("volwarp-accept".into())
            .spawn(move || self.run())
            .expect("spawning the accept thread");
        ServerHandle { addr, shared, accept: Some(accept) }
    }

    /// Serves until shut down (blocking).
    pub fn run(self) {
        log::info!("serving {} on {}", self.shared.marcher.volume().name, self.addr);
        for stream in self.listener.incoming() {
            if self.shared.stop.load(Ordering::SeqCst) {
                break;
            }
            match stream {
                Ok(s) => accept(&self.shared, s),
                Err(e) => {
                    log::warn!("accept failed: {e}");
                    std::thread::sleep(Duration::from_millis(20));
                }
            }
            self.shared.threads.lock().unwrap_or_else(|e| e.into_inner()).retain(|h| !h.is_finished());
        }
        // Stop every connection and wait for its threads.
        for s in self.shared.conns.lock().unwrap_or_else(|e| e.into_inner()).values() {
            let _ = s.shutdown(Shutdown::Both);
        }
        let threads = std::mem::take(&mut *self.shared.threads.lock().unwrap_or_else(|e| e.into_inner()));
        for t in threads {
            let _ = t.join();
        }
        log::info!("server on {} stopped", self.addr);
    }
}

impl ServerHandle {
    /// The bound address.
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// Clients being served now.
    pub fn active_clients(&self) -> usize {
        self.shared.active.load(Ordering::SeqCst)
    }

    /// Frames rendered and requests answered with an identical request's frame so far.
    pub fn render_counts(&self) -> RenderCounts {
        self.shared.queue.counts()
    }

    /// Stops accepting, closes every connection and waits for all threads.
    pub fn shutdown(mut self) {
        self.stop();
    }

    fn stop(&mut self) {
        let Some(accept) = self.accept.take() else { return };
        self.shared.stop.store(true, Ordering::SeqCst);
        // Wake the blocking accept.
        let mut wake = self.addr;
        if wake.ip().is_unspecified() {
            wake.set_ip(if wake.is_ipv4() { [127, 0, 0, 1].into() } else { std::net::Ipv6Addr::LOCALHOST.into() });
        }
        let _ = TcpStream::connect_timeout(&wake, Duration::from_secs(1));
        let _ = accept.join();
    }
}

impl Drop for ServerHandle {
    fn drop(&mut self) {
        self.stop();
    }
}

fn accept(shared: &Arc<Shared>, stream: TcpStream) {
    let id = shared.next_id.fetch_add(1, Ordering::SeqCst);
    let peer = stream.peer_addr().map(|a| a.to_string()).unwrap_or_else(|_| "?".into());
    if shared.stop.load(Ordering::SeqCst) {
        return;
    }
    // Token guessing: an address out of attempts is refused before its Hello is read.
    let charged = match (&shared.auth, stream.peer_addr()) {
        (Some(limiter), Ok(a)) => {
            if !limiter.charge(a.ip()) {
                log::warn!("client {id} ({peer}) refused: too many wrong tokens from {}", a.ip());
                let _ = stream.set_write_timeout(Some(Duration::from_secs(1)));
                send_error(
                    &mut &stream,
                    error_code::RATE_LIMITED,
                    "too many wrong tokens from this address; try later",
                );
                let _ = stream.shutdown(Shutdown::Both);
                return;
            }
            Some(a.ip())
        }
        _ => None,
    };
    let refund = || {
        if let (Some(limiter), Some(ip)) = (&shared.auth, charged) {
            limiter.refund(ip);
        }
    };
    if shared.active.load(Ordering::SeqCst) >= shared.config.max_clients {
        log::warn!("client {id} ({peer}) refused: {} clients already", shared.config.max_clients);
        let _ = stream.set_write_timeout(Some(Duration::from_secs(1)));
        send_error(&mut &stream, error_code::BUSY, "server busy: too many clients");
        let _ = stream.shutdown(Shutdown::Both);
        refund();
        return;
    }
    log::info!("client {id} ({peer}) connected");
    shared.active.fetch_add(1, Ordering::SeqCst);
    if let Ok(c) = stream.try_clone() {
        shared.conns.lock().unwrap_or_else(|e| e.into_inner()).insert(id, c);
    }
    let sh = shared.clone();
    let spawned = std::thread::Builder::new().name(format!("volwarp-client-{id}")).spawn(move || {
        let reason = serve(&sh, &stream, id, charged);
        log::info!("client {id} ({peer}) closed: {reason}");
        let _ = stream.shutdown(Shutdown::Both);
        sh.conns.lock().unwrap_or_else(|e| e.into_inner()).remove(&id);
        sh.active.fetch_sub(1, Ordering::SeqCst);
    });
    match spawned {
        Ok(h) => shared.threads.lock().unwrap_or_else(|e| e.into_inner()).push(h),
        Err(e) => {
            refund();
            log::error!("client {id}: cannot spawn a thread: {e}");
            shared.conns.lock().unwrap_or_else(|e| e.into_inner()).remove(&id);
            shared.active.fetch_sub(1, Ordering::SeqCst);
        }
    }
}

/// An `embedded_io` reader over a socket that reports read timeouts as `TimedOut`. With a
/// deadline, every read waits at most until it: a client trickling one byte at a time cannot
/// stretch a message past the handshake or idle timeout (a per-read timeout restarts on
/// every byte).
///
/// It reads from `src`: the socket itself, or the TLS reader over it (whose socket reads the
/// timeouts set on `stream` bound, since both are handles of one socket).
struct SocketReader<'a, R> {
    stream: &'a TcpStream,
    src: &'a mut R,
    deadline: Option<Instant>,
}

impl<'a, R: Read> SocketReader<'a, R> {
    /// A reader of `src` whose reads all end by `deadline`.
    fn until(stream: &'a TcpStream, src: &'a mut R, deadline: Instant) -> Self {
        SocketReader { stream, src, deadline: Some(deadline) }
    }
}

/// What a connection reads from: the socket, or the TLS stream over it.
enum Source<S> {
    Plain(S),
    Tls(TlsReader<S>),
}

impl<S: Read> Source<S> {
    fn new(raw: S, tls: Option<&TlsLink>) -> Self {
        match tls {
            Some(l) => Source::Tls(l.reader(raw)),
            None => Source::Plain(raw),
        }
    }
}

impl<S: Read> Read for Source<S> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self {
            Source::Plain(s) => s.read(buf),
            Source::Tls(t) => t.read(buf),
        }
    }
}

/// What a connection writes to: the socket, or the TLS stream over it.
enum Sink<S: Write> {
    Plain(S),
    Tls(TlsWriter<S>),
}

impl<S: Write> Sink<S> {
    fn new(raw: S, tls: Option<&TlsLink>) -> Self {
        match tls {
            Some(l) => Sink::Tls(l.writer(raw)),
            None => Sink::Plain(raw),
        }
    }

    /// Ends a TLS stream with close_notify (best effort).
    fn close(&mut self) {
        if let Sink::Tls(t) = self {
            t.close();
        }
    }
}

impl<S: Write> Write for Sink<S> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        match self {
            Sink::Plain(s) => s.write(buf),
            Sink::Tls(t) => t.write(buf),
        }
    }

    fn flush(&mut self) -> io::Result<()> {
        match self {
            Sink::Plain(s) => s.flush(),
            Sink::Tls(t) => t.flush(),
        }
    }
}

#[derive(Debug)]
struct SocketError(embedded_io::ErrorKind);

impl std::fmt::Display for SocketError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "socket error: {:?}", self.0)
    }
}

impl std::error::Error for SocketError {}

impl embedded_io::Error for SocketError {
    fn kind(&self) -> embedded_io::ErrorKind {
        self.0
    }
}

impl<R> embedded_io::ErrorType for SocketReader<'_, R> {
    type Error = SocketError;
}

impl<R: Read> embedded_io::Read for SocketReader<'_, R> {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, SocketError> {
        loop {
            if let Some(d) = self.deadline {
                let left = d.saturating_duration_since(Instant::now());
                if left.is_zero() {
                    return Err(SocketError(embedded_io::ErrorKind::TimedOut));
                }
                let _ = self.stream.set_read_timeout(Some(left.max(Duration::from_millis(1))));
            }
            match self.src.read(buf) {
                Ok(n) => return Ok(n),
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => {
                    return Err(SocketError(match e.kind() {
                        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut => embedded_io::ErrorKind::TimedOut,
                        // A TLS stream ended without close_notify, or not TLS at all.
                        io::ErrorKind::UnexpectedEof => embedded_io::ErrorKind::ConnectionReset,
                        k => k.into(),
                    }));
                }
            }
        }
    }
}

fn send_error(out: &mut impl Write, code: u16, text: &str) {
    let mut w = embedded_io_adapters::std::FromStd::new(&mut *out);
    let _ = wire::write_error(&mut w, &ErrorMsg::new(code, text));
    let _ = out.flush();
}

/// Ends the sending side and reads what the peer still sends (at most 64 KiB, 250 ms) before
/// the socket closes. Closing with unread input makes the kernel send a reset, and a reset can
/// throw away the reply the peer has not read yet (an Error message to a TLS client, whose
/// ClientHello the server read only the first bytes of).
fn drain_before_close(stream: &TcpStream) {
    let _ = stream.shutdown(std::net::Shutdown::Write);
    let until = Instant::now() + Duration::from_millis(250);
    let mut buf = [0u8; 4096];
    let mut left_bytes = 64 * 1024usize;
    while left_bytes > 0 {
        let left = until.saturating_duration_since(Instant::now());
        if left.is_zero() || stream.set_read_timeout(Some(left)).is_err() {
            return;
        }
        match (&mut &*stream).read(&mut buf) {
            Ok(0) | Err(_) => return,
            Ok(n) => left_bytes = left_bytes.saturating_sub(n),
        }
    }
}

/// The first byte the peer sends, waiting at most until `deadline` (`None`: it closed).
fn first_byte(stream: &TcpStream, deadline: Instant) -> io::Result<Option<u8>> {
    let mut b = [0u8; 1];
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(io::ErrorKind::TimedOut.into());
        }
        let _ = stream.set_read_timeout(Some(left.max(Duration::from_millis(1))));
        match stream.peek(&mut b) {
            Ok(0) => return Ok(None),
            Ok(_) => return Ok(Some(b[0])),
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        }
    }
}

/// Runs the TLS handshake of a new connection on a TLS server; a plain volwarp client is
/// told in plain to connect with TLS. `Err`: why the connection ends.
fn tls_accept(id: &TlsIdentity, stream: &TcpStream, deadline: Instant) -> Result<TlsLink, String> {
    match first_byte(stream, deadline) {
        Ok(Some(b)) if volwarp_tls::looks_like_tls(b) => {}
        Ok(Some(b)) => {
            if b == wire::MAGIC[0] {
                let text = "this server speaks TLS only: connect with --tls";
                send_error(&mut &*stream, error_code::BAD_REQUEST, text);
                return Err(format!("a plain client on a TLS server ({text})"));
            }
            return Err(format!("neither TLS nor volwarp (first byte {b:#04x})"));
        }
        Ok(None) => return Err("closed before the handshake".into()),
        Err(e) => return Err(format!("handshake failed: {e}")),
    }
    TlsLink::accept(id.0.clone(), stream, Some(deadline)).map_err(|e| format!("TLS handshake failed: {e}"))
}

/// The error code and text to send for a decoding error, or `None` when the peer is gone.
fn wire_error_reply(e: &WireError) -> Option<(u16, String)> {
    let code = match e {
        WireError::Closed | WireError::UnexpectedEof => return None,
        WireError::Io(k) if *k == embedded_io::ErrorKind::TimedOut => error_code::TIMEOUT,
        WireError::Io(_) => return None,
        WireError::TooLarge { .. } | WireError::TooManySamples { .. } => error_code::TOO_LARGE,
        WireError::BadCamera(volwarp_core::CameraError::BadViewport) => error_code::TOO_LARGE,
        WireError::UnsupportedVersion(_) => error_code::UNSUPPORTED_VERSION,
        _ => error_code::BAD_REQUEST,
    };
    Some((code, e.to_string()))
}

/// How the reader ended.
enum End {
    /// Bye from the client.
    Bye,
    /// The socket is gone (reason).
    Gone(String),
    /// A protocol error: send this Error, then close.
    Error(u16, String),
}

#[derive(Default)]
struct Slot {
    latest: Option<CameraRequest>,
    /// The viewport of the render under way, where a request for another one stops it.
    rendering: Option<(u32, u32)>,
    /// Visual edits not yet applied, in order (`Err`: a malformed one, refused with this text).
    edits: Vec<Result<VisualEdit, String>>,
    dropped: u64,
    end: Option<End>,
}

/// Most bytes the socket of a client that takes frames in parts keeps unsent (Linux's
/// `TCP_NOTSENT_LOWAT`; bytes in flight do not count): a write blocks until the queue is below
/// it, so the server sees a turn after a part while the rest of a stale frame is still its own.
pub const NOTSENT_LOWAT: usize = 64 * 1024;

/// Keeps at most `bytes` unsent in the socket's queue (Linux; elsewhere the kernel's buffer
/// size applies and a dropped frame's buffered bytes still travel).
fn limit_unsent(stream: &TcpStream, bytes: usize) -> io::Result<()> {
    #[cfg(target_os = "linux")]
    {
        use std::os::fd::AsRawFd;
        let v = bytes as libc::c_int;
        // SAFETY: a valid socket and a c_int option value of the size given.
        let r = unsafe {
            libc::setsockopt(
                stream.as_raw_fd(),
                libc::IPPROTO_TCP,
                libc::TCP_NOTSENT_LOWAT,
                (&v as *const libc::c_int).cast(),
                std::mem::size_of::<libc::c_int>() as libc::socklen_t,
            )
        };
        if r != 0 {
            return Err(io::Error::last_os_error());
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = (stream, bytes);
    Ok(())
}

/// How a frame's write ended.
enum Written {
    /// Every byte was written.
    Whole,
    /// A turn stopped it after this many of its bytes (FrameDropped sent).
    Dropped(usize),
}

/// Writes a frame message (`bytes`, header included) to `out`: whole, or for a client that
/// takes parts as FrameParts, flushed one by one, ending with FrameDropped once `stale()` says
/// so before a part.
fn write_frame_message(
    out: &mut impl Write,
    bytes: &[u8],
    parts: bool,
    stale: impl Fn() -> bool,
) -> io::Result<Written> {
    let wire_io = |e: WireError| io::Error::other(e.to_string());
    if !parts {
        out.write_all(bytes)?;
        out.flush()?;
        return Ok(Written::Whole);
    }
    let mut sent = 0;
    for part in bytes.chunks(wire::PART_LEN) {
        let mut w = embedded_io_adapters::std::FromStd::new(&mut *out);
        if stale() {
            wire::write_frame_dropped(&mut w).map_err(wire_io)?;
            out.flush()?;
            return Ok(Written::Dropped(sent));
        }
        wire::write_frame_part(&mut w, part).map_err(wire_io)?;
        out.flush()?;
        sent += part.len();
    }
    Ok(Written::Whole)
}

/// Most visual edits waiting for the next frame; more end the connection (a client sends one
/// per display frame at most, and each frame takes them all).
const MAX_PENDING_EDITS: usize = 256;

/// A client's own visual state and the marchers showing it (`None`: the server's own, the
/// start state).
struct ClientVisual {
    state: VisualState,
    levels: Option<Vec<Arc<Marcher>>>,
    generation: u32,
}

impl ClientVisual {
    /// Applies `state` (checked): rebuilds the transfer-function tables and the empty-space
    /// occupancy of every level (only the occupancy, or nothing, where the function is the same);
    /// never the volume or its min/max grid. Returns what was rebuilt.
    fn switch(&mut self, sh: &Shared, state: VisualState) -> Result<&'static str, String> {
        if state == sh.visual.start {
            *self = ClientVisual { state, levels: None, generation: 0 };
            return Ok("the start state's marchers");
        }
        let (levels, what) = match &self.levels {
            Some(cur) if state.same_function(&self.state) => {
                (cur.iter().map(|m| Arc::new(m.with_visual_cut(&state))).collect(), "shading and cut")
            }
            _ => {
                let start = sh.queue.levels();
                let tf = state
                    .transfer_function(&sh.visual.base, start[0].volume().value_range())
                    .map_err(|e| e.to_string())?;
                (start.iter().map(|m| Arc::new(m.with_visual_tf(&tf, &state))).collect(), "tables and occupancy")
            }
        };
        let generation = sh.next_generation.fetch_add(1, Ordering::Relaxed).max(1);
        *self = ClientVisual { state, levels: Some(levels), generation };
        Ok(what)
    }
}

/// Serves one connection (`charged`: the address whose token-guessing bucket paid for this
/// handshake); returns the reason it ended.
fn serve(sh: &Shared, stream: &TcpStream, id: u64, charged: Option<IpAddr>) -> String {
    let cfg = &sh.config;
    // Given back on every way out but a wrong token.
    let mut charge = charged.and_then(|ip| sh.auth.as_ref().map(|limiter| AuthCharge { limiter, ip, spent: false }));
    let _ = stream.set_nodelay(true);
    let _ = stream.set_read_timeout(Some(cfg.handshake_timeout.max(Duration::from_millis(1))));
    let _ = stream.set_write_timeout(Some(cfg.send_timeout.max(Duration::from_millis(1))));
    let limits = Limits {
        max_payload: cfg.max_message.min(Limits::for_requests(cfg.max_viewport).max_payload),
        max_samples: 0,
        max_viewport: cfg.max_viewport,
        max_layers: 1,
    };
    // Handshake (TLS first on a TLS server, within the same deadline).
    let handshake_deadline = Instant::now() + cfg.handshake_timeout.max(Duration::from_millis(1));
    let tls = match &cfg.tls {
        Some(identity) => match tls_accept(identity, stream, handshake_deadline) {
            Ok(link) => {
                log::info!("client {id}: TLS {}", link.describe());
                Some(link)
            }
            Err(reason) => return reason,
        },
        None => None,
    };
    let mut src = Source::new(stream, tls.as_ref());
    let mut sink = Sink::new(stream, tls.as_ref());
    let hello = match wire::read_message(&mut SocketReader::until(stream, &mut src, handshake_deadline), &limits) {
        Ok(Message::Hello(h)) => h,
        Ok(other) => {
            let text = format!("expected Hello, got {}", msg_name(&other));
            send_error(&mut sink, error_code::BAD_REQUEST, &text);
            return text;
        }
        // A TLS client on a plain server: say so, in plain (its TLS layer hands it over).
        Err(WireError::BadMagic(m)) if tls.is_none() && volwarp_tls::looks_like_tls(m[0]) => {
            let text = "this server does not speak TLS: connect without --tls";
            send_error(&mut sink, error_code::BAD_REQUEST, text);
            drain_before_close(stream);
            return format!("a TLS client on a plain server ({text})");
        }
        Err(e) => {
            let text = format!("handshake failed: {e}");
            if let Some((code, t)) = wire_error_reply(&e) {
                send_error(&mut sink, code, &t);
            }
            return text;
        }
    };
    if let Some(token) = &cfg.token {
        if !constant_time_eq(token.as_bytes(), &hello.token) {
            if let Some(c) = &mut charge {
                c.spent = true;
            }
            send_error(&mut sink, error_code::UNAUTHORIZED, "missing or wrong token");
            sink.close();
            return "missing or wrong token".into();
        }
    }
    drop(charge);
    // The encoding: compact if the client asks and the server allows it.
    let compact = cfg.compact && hello.capabilities & wire::CAP_COMPACT != 0;
    let encoding = if compact { Encoding::Compact } else { Encoding::Raw12 };
    // Colors coded against green only for clients that read them.
    let green = compact && hello.capabilities & wire::CAP_COLOR_GREEN != 0;
    // Layered frames: as many segments per pixel as the client asks, up to ours.
    let layers = hello.layers.clamp(1, cfg.layers.max(1));
    // Live visual edits: for clients that send them, on a server whose marchers it owns.
    let live = hello.capabilities & wire::CAP_VISUAL != 0 && sh.source.is_none();
    // Frames in parts, which a turn can stop: for clients that reassemble them.
    let parts = hello.capabilities & wire::CAP_PARTS != 0;
    if parts {
        if let Err(e) = limit_unsent(stream, NOTSENT_LOWAT) {
            log::warn!("client {id}: cannot limit the socket's unsent bytes ({e}): a dropped frame's queue still goes");
        }
    }
    {
        let mut w = embedded_io_adapters::std::FromStd::new(&mut sink);
        let caps = if compact { wire::CAP_COMPACT } else { 0 }
            | if green { wire::CAP_COLOR_GREEN } else { 0 }
            | if live { wire::CAP_VISUAL } else { 0 }
            | if parts { wire::CAP_PARTS } else { 0 };
        let answer = Hello::new(caps).with_layers(layers);
        if let Err(e) = wire::write_hello(&mut w, &answer) {
            return format!("cannot send Hello: {e}");
        }
        if live {
            if let Err(e) = wire::write_visual_state(&mut w, &sh.visual.start.to_wire(0)) {
                return format!("cannot send the visual state: {e}");
            }
        }
        if let Err(e) = sink.flush() {
            return format!("cannot send Hello: {e}");
        }
    }
    log::info!(
        "client {id}: hello (version {}, capabilities {:#x}, {layers} segments per pixel)",
        hello.version,
        hello.capabilities
    );
    let _ = stream.set_read_timeout(Some(cfg.idle_timeout.max(Duration::from_millis(1))));

    let slot = Arc::new((Mutex::new(Slot::default()), Condvar::new()));
    // Set by the reader to drop the render under way (see the module docs).
    let stop = Arc::new(AtomicBool::new(false));
    let reader = {
        let slot = slot.clone();
        let stop = stop.clone();
        let Ok(rs) = stream.try_clone() else { return "cannot clone the socket".into() };
        let idle = cfg.idle_timeout.max(Duration::from_millis(1));
        let Ok(raw) = rs.try_clone() else { return "cannot clone the socket".into() };
        // The TLS reader keeps the ciphertext the Hello's reads left over.
        let src = match src {
            Source::Plain(_) => Source::Plain(raw),
            Source::Tls(t) => Source::Tls(t.with_raw(raw)),
        };
        std::thread::Builder::new()
            .name(format!("volwarp-read-{id}"))
            .spawn(move || read_loop(rs, src, limits, idle, slot, stop))
    };
    let Ok(reader) = reader else { return "cannot spawn the reader thread".into() };

    let mut out = BufWriter::with_capacity(64 * 1024, sink);
    // One frame per client, its vectors reused from frame to frame.
    let mut frame = sh.marcher.empty_frame();
    // The camera of the client's last request: a different one is a moving camera.
    let mut last_camera = None;
    // The last request rendered: rendered again after a visual edit that came alone.
    let mut last_req: Option<CameraRequest> = None;
    let mut visual = ClientVisual { state: sh.visual.start.clone(), levels: None, generation: 0 };
    // Whether the last render was dropped: the next one runs to its end.
    let mut stopped_last = false;
    let reason = loop {
        let (req, edits) = {
            let (lock, cv) = &*slot;
            let mut s = lock.lock().unwrap_or_else(|e| e.into_inner());
            let mut failed = None;
            while s.latest.is_none() && s.edits.is_empty() && s.end.is_none() {
                s = match &sh.source {
                    // A source that fails tells idle clients too.
                    Some(source) => {
                        failed = source.failed();
                        if failed.is_some() {
                            break;
                        }
                        cv.wait_timeout(s, SOURCE_POLL).unwrap_or_else(|e| e.into_inner()).0
                    }
                    None => cv.wait(s).unwrap_or_else(|e| e.into_inner()),
                };
            }
            if let Some(e) = failed {
                break End::Error(error_code::INTERNAL, e);
            }
            if s.end.is_some() {
                break s.end.take().unwrap_or(End::Gone("reader ended".into()));
            }
            (s.latest.take(), std::mem::take(&mut s.edits))
        };
        let applied = apply_edits(sh, id, &mut visual, edits, &mut out);
        if let Some(state_id) = applied {
            let mut w = embedded_io_adapters::std::FromStd::new(&mut out);
            if let Err(e) = wire::write_visual_state(&mut w, &visual.state.to_wire(state_id)) {
                break End::Gone(format!("cannot send the visual state: {e}"));
            }
        }
        let Some(req) = req.or(last_req.filter(|_| applied.is_some())) else {
            if let Err(e) = io::Write::flush(&mut out) {
                break End::Gone(format!("cannot send: {e}"));
            }
            continue;
        };
        last_req = Some(req);
        let viewport = (req.camera.width, req.camera.height);
        {
            let mut s = slot.0.lock().unwrap_or_else(|e| e.into_inner());
            let stoppable = sh.source.is_none() && !stopped_last;
            s.rendering = stoppable.then_some(viewport);
            // A request for another viewport that came in since this one was taken.
            let turned = s.latest.is_some_and(|l| (l.camera.width, l.camera.height) != viewport);
            stop.store(stoppable && turned, Ordering::Relaxed);
            if let Some(d) = cfg.frame_delay {
                // The slowed server's wait, which a stop ends too.
                let until = Instant::now() + d;
                while !stop.load(Ordering::Relaxed) {
                    let Some(left) = until.checked_duration_since(Instant::now()).filter(|l| !l.is_zero()) else {
                        break;
                    };
                    s = slot.1.wait_timeout(s, left).unwrap_or_else(|e| e.into_inner()).0;
                }
            }
        }
        let moving = last_camera.is_some_and(|c| c != req.camera);
        last_camera = Some(req.camera);
        // The request's own segment count (wire version 5), capped at the Hello's; 0: the Hello's.
        let wanted = if req.layers > 0 { req.layers.min(layers) } else { layers };
        let stats = match &sh.source {
            Some(source) => match source.render(&req, wanted as u32, &mut frame) {
                Ok(stats) => stats,
                Err(e) => break End::Error(error_code::INTERNAL, e),
            },
            None => {
                let stats = match stop.load(Ordering::Relaxed) {
                    true => None,
                    false => sh.queue.render_view_until(
                        visual.levels.as_deref().unwrap_or(&[]),
                        visual.generation,
                        &req,
                        wanted as u32,
                        moving,
                        &mut frame,
                        &stop,
                    ),
                };
                slot.0.lock().unwrap_or_else(|e| e.into_inner()).rendering = None;
                stopped_last = stats.is_none();
                let Some(stats) = stats else {
                    log::info!(
                        "client {id}: frame seq {} {}x{} dropped: the view's turn made it stale",
                        req.seq,
                        viewport.0,
                        viewport.1
                    );
                    continue;
                };
                stats
            }
        };
        let t_send = Instant::now();
        let bytes = match &sh.source {
            Some(source) => source.encode(&req, &frame, encoding, green).0,
            None => crate::encoding::encode_frame_for(&sh.marcher, &req, &frame, encoding, green).0,
        };
        // A frame written in parts is dropped before a part once the newest request is for a
        // coarser viewport (the view started moving; also after a dropped render: the coarse
        // frame asked for is never dropped on the link, so frames keep coming).
        let pixels = |c: &volwarp_core::Camera| u64::from(c.width) * u64::from(c.height);
        let stale = || {
            let s = slot.0.lock().unwrap_or_else(|e| e.into_inner());
            sh.source.is_none() && s.latest.is_some_and(|l| pixels(&l.camera) < pixels(&req.camera))
        };
        match write_frame_message(&mut out, &bytes, parts, stale) {
            Err(e) => break End::Gone(format!("cannot send frame: {e}")),
            Ok(Written::Dropped(at)) => {
                stopped_last = true;
                log::info!(
                    "client {id}: frame seq {} {}x{} dropped on the link after {at} of {} bytes: the view's turn made it stale",
                    req.seq,
                    viewport.0,
                    viewport.1,
                    bytes.len()
                );
                continue;
            }
            Ok(Written::Whole) => {}
        }
        let dropped = std::mem::take(&mut slot.0.lock().unwrap_or_else(|e| e.into_inner()).dropped);
        log::info!(
            "client {id}: frame seq {} {}x{} {}: {} samples, march {:.1} ms, compact {:.2} ms, send {:.1} ms{}",
            req.seq,
            req.camera.width,
            req.camera.height,
            req.heuristic,
            stats.samples,
            stats.march_us as f64 / 1e3,
            stats.compact_us as f64 / 1e3,
            t_send.elapsed().as_secs_f64() * 1e3,
            if dropped > 0 { format!(", {dropped} stale requests skipped") } else { String::new() }
        );
    };
    // Only a connection that ends cleanly gets TLS's close_notify: a dead or stalled socket
    // would hold this thread up to another send timeout.
    let clean = !matches!(reason, End::Gone(_));
    let reason = match reason {
        End::Bye => "bye".to_string(),
        End::Gone(r) => r,
        End::Error(code, text) => {
            send_error(&mut out, code, &text);
            text
        }
    };
    if clean {
        if let Ok(mut sink) = out.into_inner() {
            sink.close();
        }
    }
    let _ = stream.shutdown(Shutdown::Both);
    let _ = reader.join();
    reason
}

/// Applies a client's visual edits in order to its state: each bad one is answered with a
/// non-closing Error `BAD_EDIT` (the state stays as it was before it); then, if any applied, the
/// marchers are rebuilt once. Returns the id of the last edit applied.
fn apply_edits(
    sh: &Shared,
    client: u64,
    visual: &mut ClientVisual,
    edits: Vec<Result<VisualEdit, String>>,
    out: &mut impl Write,
) -> Option<u32> {
    if edits.is_empty() {
        return None;
    }
    let mut state = visual.state.clone();
    let mut applied = None;
    for e in edits {
        let result = match e {
            Ok(_) if sh.source.is_some() => Err("live visual edits are not applied across MPI ranks: give the state \
                                                 with --preset, --window-level, --opacity-scale, --crop, --clip or --tf \
                                                 at start, on one process"
                .to_string()),
            Ok(e) => state.apply(&e).map(|s| (e.id, s)).map_err(|e| e.to_string()),
            Err(text) => Err(text),
        };
        match result {
            Ok((id, s)) => {
                state = s;
                applied = Some(id);
            }
            Err(text) => {
                log::warn!("client {client}: visual edit refused: {text}");
                send_error(out, error_code::BAD_EDIT, &format!("visual edit refused: {text}"));
            }
        }
    }
    let id = applied?;
    let t = Instant::now();
    match visual.switch(sh, state) {
        Ok(what) => {
            log::info!(
                "client {client}: visual state {id} applied ({what} rebuilt in {:.2} ms)",
                t.elapsed().as_secs_f64() * 1e3
            );
            Some(id)
        }
        Err(text) => {
            send_error(out, error_code::BAD_EDIT, &format!("visual edit refused: {text}"));
            None
        }
    }
}

fn msg_name(m: &Message) -> &'static str {
    match m {
        Message::Hello(_) => "Hello",
        Message::CameraRequest(_) => "CameraRequest",
        Message::Frame(_) => "Frame",
        Message::Error(_) => "Error",
        Message::Bye => "Bye",
        Message::VisualEdit(_) => "VisualEdit",
        Message::VisualState(_) => "VisualState",
    }
}

/// Queues a visual edit for the render loop; `Some`: too many are waiting, the connection ends.
fn push_edit(slot: &(Mutex<Slot>, Condvar), e: Result<VisualEdit, String>) -> Option<End> {
    let mut s = slot.0.lock().unwrap_or_else(|e| e.into_inner());
    if s.edits.len() >= MAX_PENDING_EDITS {
        return Some(End::Error(error_code::TOO_LARGE, format!("over {MAX_PENDING_EDITS} visual edits waiting")));
    }
    s.edits.push(e);
    slot.1.notify_one();
    None
}

/// Reads the client's messages; each must arrive complete within `idle` of the previous one.
fn read_loop(
    stream: TcpStream,
    mut src: Source<TcpStream>,
    limits: Limits,
    idle: Duration,
    slot: Arc<(Mutex<Slot>, Condvar)>,
    stop: Arc<AtomicBool>,
) {
    let end = loop {
        match wire::read_message(&mut SocketReader::until(&stream, &mut src, Instant::now() + idle), &limits) {
            Ok(Message::CameraRequest(r)) => {
                let mut s = slot.0.lock().unwrap_or_else(|e| e.into_inner());
                if s.rendering.is_some_and(|v| v != (r.camera.width, r.camera.height)) {
                    stop.store(true, Ordering::Relaxed);
                }
                if s.latest.replace(r).is_some() {
                    s.dropped += 1;
                }
                slot.1.notify_one();
            }
            Ok(Message::VisualEdit(e)) => {
                if let Some(end) = push_edit(&slot, Ok(e)) {
                    break end;
                }
            }
            // A malformed edit was read whole: refuse it, keep reading.
            Err(WireError::BadVisual(e)) => {
                if let Some(end) = push_edit(&slot, Err(e.to_string())) {
                    break end;
                }
            }
            Ok(Message::Bye) => break End::Bye,
            Ok(Message::Error(e)) => break End::Gone(format!("client sent Error {}: {}", e.code, e.text)),
            Ok(other) => break End::Error(error_code::BAD_REQUEST, format!("unexpected {} message", msg_name(&other))),
            Err(e) => match wire_error_reply(&e) {
                Some((code, text)) => break End::Error(code, text),
                None => break End::Gone(e.to_string()),
            },
        }
    };
    let mut s = slot.0.lock().unwrap_or_else(|e| e.into_inner());
    s.end = Some(end);
    slot.1.notify_one();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_guessing_limiter_keys_hosts_and_refills() {
        let v4: IpAddr = "192.0.2.7".parse().unwrap();
        let mapped: IpAddr = "::ffff:192.0.2.7".parse().unwrap();
        assert_eq!(AuthLimiter::key(mapped), v4, "an IPv4-mapped address is its IPv4 host");
        let a: IpAddr = "2001:db8:1:2:aaaa::1".parse().unwrap();
        let b: IpAddr = "2001:db8:1:2:bbbb::9".parse().unwrap();
        let c: IpAddr = "2001:db8:1:3::1".parse().unwrap();
        assert_eq!(AuthLimiter::key(a), AuthLimiter::key(b), "one /64, one bucket");
        assert_ne!(AuthLimiter::key(a), AuthLimiter::key(c));

        let l = AuthLimiter::new(3);
        assert!((0..3).all(|_| l.charge(v4)), "a burst as deep as the rate");
        assert!(!l.charge(mapped), "the same host, out of attempts");
        assert!(l.charge(a), "another host has its own bucket");
        l.refund(v4);
        assert!(l.charge(v4), "a refunded attempt can be used again");
        assert!(!l.charge(v4));
        std::thread::sleep(Duration::from_millis(400));
        assert!(l.charge(v4), "refilled at 3 per second");
    }
}
