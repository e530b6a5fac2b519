//! A feed server for benchmarking the client alone: frames of the bundled dataset are rendered
//! by the real server **before** the measurement (along the bench's orbit) and then served over loopback TCP at a
//! fixed pace, like a server that needs `interval` per frame — but without its ray marcher
//! competing with the client for the CPU. Each frame carries the sequence number of the newest
//! request, as a real server's would.

use crate::connection::{connect, read_message_bytes, send_bye, send_request, server_error};
use crate::error::ClientError;
use crate::server_process::{ServerProcess, ServerSpawn};
use std::io::Write;
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use volwarp_core::wire::{self, CameraRequest, Frame, Hello, Limits, Message};
use volwarp_core::Heuristic;

/// Prerendered frames and the volume's bounds.
pub struct Prerendered {
    /// The frames, in orbit order.
    pub frames: Vec<Frame>,
    /// The volume's bounds.
    pub bounds: volwarp_core::sample::Bounds,
}

/// What to prerender.
#[derive(Clone, Debug)]
pub struct PrerenderOptions {
    /// Viewport.
    pub width: u32,
    /// Viewport.
    pub height: u32,
    /// Depth heuristic.
    pub heuristic: Heuristic,
    /// Sphere radius scale.
    pub radius_scale: f32,
    /// Frames to render.
    pub count: usize,
    /// Degrees of orbit between frames.
    pub step_deg: f32,
    /// Marcher threads of the server (0: all cores).
    pub server_threads: usize,
    /// How long to wait for each frame.
    pub timeout: Duration,
}

/// Renders `count` frames of the bundled dataset for the home camera orbited by `k × step_deg`,
/// by the real `volwarp-server` (started as a child process and stopped again before the
/// measurement).
pub fn prerender(o: &PrerenderOptions) -> Result<Prerendered, ClientError> {
    let server = ServerProcess::spawn(&ServerSpawn { threads: o.server_threads, ..ServerSpawn::default() })?;
    let mut conn = connect(&server.addr().to_string(), None, o.timeout)?;
    let home = crate::controls::home_camera(&conn.bounds, o.width, o.height);
    let mut frames = Vec::with_capacity(o.count.max(1));
    for k in 0..o.count.max(1) {
        let seq = k as u64 + 1;
        let camera = home.orbit(k as f32 * o.step_deg, 0.0);
        let req = CameraRequest { seq, camera, heuristic: o.heuristic, radius_scale: o.radius_scale, layers: 0 };
        send_request(&mut conn.stream, &req).map_err(|e| ClientError::Io(format!("prerender: {e}")))?;
        loop {
            match read_message_bytes(&mut conn.stream, &conn.limits, "prerendering")?.1 {
                Message::Frame(f) if f.header.seq == seq => {
                    frames.push(f);
                    break;
                }
                Message::Frame(_) => {}
                Message::Error(e) => return Err(server_error(&e)),
                _ => return Err(ClientError::Protocol("prerender: unexpected message".into())),
            }
        }
    }
    send_bye(&mut conn.stream);
    Ok(Prerendered { frames, bounds: conn.bounds })
}

/// A running feed server.
pub struct FeedServer {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

/// The frame's wire bytes, as answering request `seq` (encoded by core's codec).
fn encoded(frame: &Frame, seq: u64) -> Vec<u8> {
    let header = wire::FrameHeader { seq, ..frame.header };
    let mut bytes = Vec::new();
    let _ = wire::write_frame(&mut wire::VecWriter(&mut bytes), &header, &frame.samples, &frame.colors);
    bytes
}

fn serve(listener: TcpListener, frames: Vec<Frame>, interval: Duration, stop: Arc<AtomicBool>) {
    let Ok((mut s, _)) = listener.accept() else { return };
    if stop.load(Ordering::SeqCst) || frames.is_empty() {
        return;
    }
    let _ = s.set_nodelay(true);
    let limits = Limits::for_requests(4096);
    let mut hello = Vec::new();
    let _ = wire::write_hello(&mut wire::VecWriter(&mut hello), &Hello::new(0));
    if !matches!(read_message_bytes(&mut s, &limits, "feed"), Ok((_, Message::Hello(_))))
        || s.write_all(&hello).is_err()
    {
        return;
    }
    if !matches!(read_message_bytes(&mut s, &limits, "feed"), Ok((_, Message::CameraRequest(_)))) {
        return;
    }
    if s.write_all(&encoded(&frames[0], 0)).is_err() {
        return;
    }
    // Track the newest request.
    let latest = Arc::new(AtomicU64::new(0));
    if let Ok(mut rs) = s.try_clone() {
        let latest = latest.clone();
        std::thread::spawn(move || {
            while let Ok((_, m)) = read_message_bytes(&mut rs, &limits, "feed") {
                match m {
                    Message::CameraRequest(r) => latest.store(r.seq, Ordering::SeqCst),
                    _ => break,
                }
            }
        });
    }
    let start = Instant::now();
    for k in 1usize.. {
        let due = start + interval * k as u32;
        while Instant::now() < due {
            if stop.load(Ordering::SeqCst) {
                return;
            }
            std::thread::sleep(due.saturating_duration_since(Instant::now()).min(Duration::from_millis(20)));
        }
        // The frame arriving now was rendered for the camera of one interval ago.
        let n = frames.len();
        let bytes = encoded(&frames[(k - 1) % n], latest.load(Ordering::SeqCst));
        if s.write_all(&bytes).is_err() {
            return;
        }
    }
}

impl FeedServer {
    /// Serves `frames` (one client) on a loopback port, one every `interval`.
    pub fn start(frames: Vec<Frame>, interval: Duration) -> Result<FeedServer, ClientError> {
        let listener = TcpListener::bind("127.0.0.1:0").map_err(|e| ClientError::Io(format!("feed server: {e}")))?;
        let addr = listener.local_addr().map_err(|e| ClientError::Io(format!("feed server: {e}")))?;
        let stop = Arc::new(AtomicBool::new(false));
        let st = stop.clone();
        let thread = std::thread::Builder::new()
            .name("volwarp-feed".into())
            .spawn(move || serve(listener, frames, interval, st))
            .map_err(|e| ClientError::Io(format!("feed server: {e}")))?;
        Ok(FeedServer { addr, stop, thread: Some(thread) })
    }

    /// Its address.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }
}

impl Drop for FeedServer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        // Wake a pending accept.
        let _ = TcpStream::connect_timeout(&self.addr, Duration::from_millis(200));
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
