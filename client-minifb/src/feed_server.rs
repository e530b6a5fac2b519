//! A feed server for benchmarking the client alone: frames of the bundled dataset are rendered
//! **before** the measurement (along the bench's orbit) and then served over loopback TCP at a
//! fixed pace, like a server that needs `interval` per frame — but without its ray marcher
//! competing with the client for the CPU. Each frame carries the sequence number of the newest
//! request, as a real server's would.

use crate::connection::read_message_bytes;
use crate::error::ClientError;
use std::io::Write;
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use volwarp_core::wire::{self, CameraRequest, Hello, Limits, Message, HEADER_LEN};
use volwarp_core::{Camera, Heuristic};
use volwarp_server::{Dataset, Marcher};

/// Prerendered frames (exact message bytes) and the volume's home camera.
pub struct Prerendered {
    /// Frame messages, header included.
    pub frames: Vec<Vec<u8>>,
    /// The volume's bounds.
    pub bounds: volwarp_core::sample::Bounds,
}

/// Renders `count` frames of the bundled dataset for `home` orbited by `k × step_deg`.
pub fn prerender(
    width: u32,
    height: u32,
    heuristic: Heuristic,
    radius_scale: f32,
    count: usize,
    step_deg: f32,
) -> Prerendered {
    let marcher = Marcher::from_dataset(&Dataset::default_bundled());
    let bounds = marcher.volume().bounds();
    let home: Camera = crate::controls::home_camera(&bounds, width, height);
    let frames = (0..count.max(1))
        .map(|k| {
            let req = CameraRequest { seq: 0, camera: home.orbit(k as f32 * step_deg, 0.0), heuristic, radius_scale };
            let (frame, _) = marcher.render_frame(&req);
            wire::encode_to_vec(&Message::Frame(frame))
        })
        .collect();
    Prerendered { frames, bounds }
}

/// A running feed server.
pub struct FeedServer {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

fn set_seq(msg: &mut [u8], seq: u64) {
    if msg.len() >= HEADER_LEN + 8 {
        msg[HEADER_LEN..HEADER_LEN + 8].copy_from_slice(&seq.to_le_bytes());
    }
}

fn serve(listener: TcpListener, mut frames: Vec<Vec<u8>>, interval: Duration, stop: Arc<AtomicBool>) {
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
    set_seq(&mut frames[0], 0);
    if s.write_all(&frames[0]).is_err() {
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
        let f = &mut frames[(k - 1) % n];
        set_seq(f, latest.load(Ordering::SeqCst));
        if s.write_all(f).is_err() {
            return;
        }
    }
}

impl FeedServer {
    /// Serves `frames` (one client) on a loopback port, one every `interval`.
    pub fn start(frames: Vec<Vec<u8>>, interval: Duration) -> Result<FeedServer, ClientError> {
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
