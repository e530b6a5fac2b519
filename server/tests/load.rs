//! Many clients on one real `volwarp-server` process (the binary, so its memory is measured
//! alone): each client orbits on its own camera and asks for its next frame as soon as one
//! arrives, for a fixed time; the server must serve every client (fairness: min/max frames per
//! client), with no error, and memory per client bounded. Clients that send requests and never
//! read must not grow the server's memory without bound.
//!
//! The short versions run in `cargo test`. The figures for docs/perf.md:
//!
//! ```text
//! cargo test --release -p volwarp-server --test load -- --ignored --nocapture --test-threads 1
//! LOAD_CLIENTS=64 LOAD_SECS=60 cargo test --release -p volwarp-server --test load many_clients_figures -- --ignored --nocapture
//! ```

use std::io::{BufRead, BufReader, Write};
use std::net::{SocketAddr, TcpStream};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use volwarp_core::wire::{self, CameraRequest, Hello, Limits, Message, VecWriter};
use volwarp_core::{Camera, Heuristic};

/// The real server as a child process on a free loopback port.
struct ServerChild {
    child: Child,
    addr: SocketAddr,
}

impl ServerChild {
    fn start(extra: &[&str]) -> ServerChild {
        // Owned by a ServerChild at once: dropped on any way out, it is killed and waited for.
        let mut server = ServerChild {
            child: Command::new(env!("CARGO_BIN_EXE_volwarp-server"))
                .args(["--listen", "127.0.0.1:0", "--threads", "2", "--max-clients", "200"])
                .args(extra)
                .stdout(Stdio::piped())
                .stderr(Stdio::null())
                .stdin(Stdio::null())
                .spawn()
                .expect("starting volwarp-server"),
            addr: SocketAddr::from(([127, 0, 0, 1], 0)),
        };
        let mut out = BufReader::new(server.child.stdout.take().unwrap());
        let mut line = String::new();
        loop {
            line.clear();
            assert!(out.read_line(&mut line).unwrap() > 0, "the server ended before listening");
            if let Some(a) = line.trim().strip_prefix("listening on ") {
                server.addr = a.parse().unwrap();
                // Keep draining its stdout so it never blocks on a full pipe.
                std::thread::spawn(move || std::io::copy(&mut out, &mut std::io::sink()));
                return server;
            }
        }
    }

    /// The process's resident memory in KiB.
    fn rss_kib(&self) -> u64 {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.child.id())).unwrap_or_default();
        status
            .lines()
            .find_map(|l| l.strip_prefix("VmRSS:"))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
            .unwrap_or(0)
    }
}

impl Drop for ServerChild {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn send(s: &mut TcpStream, m: &Message) -> std::io::Result<()> {
    let mut buf = Vec::new();
    let _ = wire::write_message(&mut VecWriter(&mut buf), m);
    s.write_all(&buf)
}

/// Connects and greets as the real client does (compact, layered frames: 4 segments per pixel).
fn hello(addr: SocketAddr) -> Result<TcpStream, String> {
    let mut s = TcpStream::connect(addr).map_err(|e| format!("connect: {e}"))?;
    s.set_nodelay(true).ok();
    s.set_read_timeout(Some(Duration::from_secs(60))).ok();
    let caps = wire::CAP_COMPACT | wire::CAP_COLOR_GREEN;
    send(&mut s, &Message::Hello(Hello::new(caps).with_layers(4))).map_err(|e| format!("hello: {e}"))?;
    match wire::read_message(&mut embedded_io_adapters::std::FromStd::new(&mut s), &Limits::for_frames(4096)) {
        Ok(Message::Hello(_)) => Ok(s),
        other => Err(format!("expected Hello, got {other:?}")),
    }
}

/// The camera of client `id`'s frame `seq`: its own orbit around the bundled volume (the one
/// the server serves by default).
fn camera(id: usize, seq: u64, size: u32) -> Camera {
    static VOLUME: std::sync::OnceLock<volwarp_server::Dataset> = std::sync::OnceLock::new();
    let ds = VOLUME.get_or_init(volwarp_server::Dataset::default_bundled);
    volwarp_server::default_camera(&ds.volume, size, size).orbit(id as f32 * 37.0 + seq as f32 * 3.0, 10.0)
}

/// Client `id`'s request `seq` (threshold heuristic, the Hello's layer count).
fn request(id: usize, seq: u64, size: u32) -> CameraRequest {
    CameraRequest { seq, camera: camera(id, seq, size), heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 }
}

/// One orbiting client until `stop`: frames received, or the first error.
fn orbit(addr: SocketAddr, id: usize, size: u32, stop: Arc<AtomicBool>) -> Result<u64, String> {
    let mut s = hello(addr)?;
    let limits = Limits::for_frames(4096).with_layers(4);
    let mut frames = 0;
    for seq in 1.. {
        if stop.load(Ordering::SeqCst) {
            break;
        }
        let req = request(id, seq, size);
        send(&mut s, &Message::CameraRequest(req)).map_err(|e| format!("client {id}: request: {e}"))?;
        match wire::read_message(&mut embedded_io_adapters::std::FromStd::new(&mut s), &limits) {
            Ok(Message::Frame(f)) if f.header.seq == seq && f.samples.len() == f.header.count as usize => frames += 1,
            other => return Err(format!("client {id}: expected frame {seq}, got {other:?}")),
        }
    }
    let _ = send(&mut s, &Message::Bye);
    Ok(frames)
}

struct LoadRun {
    clients: usize,
    secs: f64,
    per_client: Vec<u64>,
    errors: Vec<String>,
    rss_idle_kib: u64,
    rss_peak_kib: u64,
}

impl LoadRun {
    fn fairness(&self) -> f64 {
        let (min, max) = (self.per_client.iter().min(), self.per_client.iter().max());
        match (min, max) {
            (Some(&a), Some(&b)) if b > 0 => a as f64 / b as f64,
            _ => 0.0,
        }
    }

    fn row(&self) -> String {
        let total: u64 = self.per_client.iter().sum();
        let per = total as f64 / self.secs / self.clients as f64;
        let (min, max) = (self.per_client.iter().min().unwrap_or(&0), self.per_client.iter().max().unwrap_or(&0));
        format!(
            "| {} | {:.0} | {:.2} | {:.3} | {min} / {max} = {:.2} | {:.1} | {:.0} | {} |",
            self.clients,
            self.secs,
            total as f64 / self.secs,
            per,
            self.fairness(),
            self.rss_peak_kib as f64 / 1024.0,
            self.rss_peak_kib.saturating_sub(self.rss_idle_kib) as f64 / self.clients as f64,
            self.errors.len()
        )
    }
}

/// `n` orbiting clients at `size`² for `secs` seconds on a fresh server.
fn load(n: usize, size: u32, secs: f64) -> LoadRun {
    let server = ServerChild::start(&[]);
    let rss_idle_kib = server.rss_kib();
    let stop = Arc::new(AtomicBool::new(false));
    let handles: Vec<_> = (0..n)
        .map(|id| {
            let (addr, stop) = (server.addr, stop.clone());
            std::thread::spawn(move || orbit(addr, id, size, stop))
        })
        .collect();
    let t0 = Instant::now();
    let mut rss_peak_kib = rss_idle_kib;
    while t0.elapsed().as_secs_f64() < secs {
        std::thread::sleep(Duration::from_millis(100));
        rss_peak_kib = rss_peak_kib.max(server.rss_kib());
    }
    stop.store(true, Ordering::SeqCst);
    let secs = t0.elapsed().as_secs_f64();
    let (mut per_client, mut errors) = (Vec::new(), Vec::new());
    for h in handles {
        match h.join() {
            Ok(Ok(f)) => per_client.push(f),
            Ok(Err(e)) => errors.push(e),
            Err(_) => errors.push("a client thread panicked".into()),
        }
    }
    LoadRun { clients: n, secs, per_client, errors, rss_idle_kib, rss_peak_kib }
}

const HEADER: &str = "| clients | s | frames/s in all | frames/s per client | fairness min/max | server RSS peak MiB | RSS per client KiB | errors |\n|---|---|---|---|---|---|---|---|";

#[test]
fn eight_orbiting_clients_all_get_frames_without_errors() {
    let run = load(8, 128, 3.0);
    println!("{HEADER}\n{}", run.row());
    assert!(run.errors.is_empty(), "{:?}", run.errors);
    assert_eq!(run.per_client.len(), 8);
    assert!(run.per_client.iter().all(|&f| f > 0), "a client starved: {:?}", run.per_client);
    // Loose: the marcher pool is FIFO, so clients alternate; a loaded CI box still stays well
    // above this.
    assert!(run.fairness() >= 0.3, "fairness {:.2}: {:?}", run.fairness(), run.per_client);
}

/// `n` clients that greet, send `requests` requests for `size`² frames, then never read, held
/// for `secs`; the server's RSS before, its peak over the first half and over the whole time
/// (equal peaks: it stopped growing), and the frames a reading client got meanwhile.
fn never_reading(n: usize, size: u32, requests: u64, secs: f64, extra: &[&str]) -> (u64, u64, u64, u64) {
    let server = ServerChild::start(extra);
    let idle = server.rss_kib();
    let mut silent = Vec::new();
    for id in 0..n {
        let mut s = hello(server.addr).expect("greeting");
        for seq in 1..=requests {
            let req = request(id, seq, size);
            if send(&mut s, &Message::CameraRequest(req)).is_err() {
                break;
            }
        }
        silent.push(s);
    }
    let stop = Arc::new(AtomicBool::new(false));
    let reader = {
        let (addr, stop) = (server.addr, stop.clone());
        std::thread::spawn(move || orbit(addr, 999, 128, stop))
    };
    let t0 = Instant::now();
    let (mut half, mut peak) = (idle, idle);
    while t0.elapsed().as_secs_f64() < secs {
        std::thread::sleep(Duration::from_millis(100));
        peak = peak.max(server.rss_kib());
        if t0.elapsed().as_secs_f64() < secs / 2.0 {
            half = peak;
        }
    }
    stop.store(true, Ordering::SeqCst);
    let served = reader.join().unwrap().expect("the reading client is served");
    drop(silent);
    (idle, half, peak, served)
}

#[test]
fn clients_that_never_read_do_not_grow_the_server_without_bound() {
    let (idle, _, peak, served) = never_reading(8, 256, 40, 3.0, &[]);
    let per_client = peak.saturating_sub(idle) / 8;
    println!("8 never-reading clients at 256²: RSS {idle} -> {peak} KiB ({per_client} KiB per client); a reading client got {served} frames");
    assert!(served > 0, "a reading client starved next to silent ones");
    // Each silent client holds at most its latest request, one frame and a 64 KiB send buffer:
    // a 256² layered frame is well under 4 MiB.
    assert!(per_client < 4 * 1024, "{per_client} KiB per never-reading client");
}

#[test]
#[ignore = "figures for docs/perf.md: 1, 8, 32 and 64 clients at 512² (LOAD_SECS each, default 20)"]
fn many_clients_figures() {
    let secs: f64 = std::env::var("LOAD_SECS").ok().and_then(|s| s.parse().ok()).unwrap_or(20.0);
    let counts: Vec<usize> = std::env::var("LOAD_CLIENTS")
        .ok()
        .map(|s| s.split(',').filter_map(|c| c.trim().parse().ok()).collect())
        .unwrap_or_else(|| vec![1, 8, 32, 64]);
    let load_avg = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!("many clients: bundled volume at 512², 4 segments per pixel, 2 marcher threads; load {}", load_avg.trim());
    println!("{HEADER}");
    for n in counts {
        let run = load(n, 512, secs);
        println!("{}", run.row());
        for e in run.errors.iter().take(3) {
            println!("  error: {e}");
        }
    }
}

#[test]
#[ignore = "figures for docs/perf.md: 32 clients that never read, 512² frames (LOAD_SECS, default 20)"]
fn never_reading_figures() {
    let secs: f64 = std::env::var("LOAD_SECS").ok().and_then(|s| s.parse().ok()).unwrap_or(20.0);
    let (idle, half, peak, served) = never_reading(32, 512, 200, secs, &[]);
    println!(
        "32 never-reading clients, 200 requests each for 512² frames, held {secs} s: server RSS {:.1} -> {:.1} MiB peak in the first half, {:.1} MiB over all, {:.0} KiB per client; a reading client (128²) got {served} frames meanwhile",
        idle as f64 / 1024.0,
        half as f64 / 1024.0,
        peak as f64 / 1024.0,
        peak.saturating_sub(idle) as f64 / 32.0
    );
}
