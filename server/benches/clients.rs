//! `cargo bench -p volwarp-server --bench clients`: frames per second delivered to 1, 2 and 4
//! clients of one server (2 marcher threads; `CLIENTS_BENCH_THREADS`) rendering the MRI of
//! `../shared/data` at 512² (`CLIENTS_BENCH_SIZE`), each client orbiting on its own (distinct
//! cameras: no request is shared) and asking for its next frame as soon as one arrives, for
//! `CLIENTS_BENCH_SECS` (default 8) seconds per client count. Prints, per count, the total
//! frames per second and each client's.

use embedded_io_adapters::std::FromStd;
use std::net::{SocketAddr, TcpStream};
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};
use volwarp_core::wire::{self, CameraRequest, Hello, Limits, Message};
use volwarp_core::Heuristic;
use volwarp_server::{Dataset, Marcher, Server, ServerConfig};

const MRI: &str = volwarp_server::testdata::MRI_PATH;

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name).ok().and_then(|s| s.parse().ok()).unwrap_or(default)
}

fn client(addr: SocketAddr, m: Arc<Marcher>, id: usize, size: u32, until: Instant) -> usize {
    let mut s = TcpStream::connect(addr).expect("connect");
    s.set_nodelay(true).ok();
    wire::write_message(&mut FromStd::new(&mut s), &Message::Hello(Hello::new(0))).expect("hello");
    let limits = Limits::for_frames(4096);
    let _ = wire::read_message(&mut FromStd::new(&mut s), &limits).expect("hello back");
    let mut frames = 0;
    for seq in 0.. {
        if Instant::now() >= until {
            break;
        }
        let camera = m.default_camera(size, size).orbit(20.0 + id as f32 * 7.0 + seq as f32 * 0.5, 10.0).dolly(0.68);
        let req = CameraRequest { seq, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
        wire::write_message(&mut FromStd::new(&mut s), &Message::CameraRequest(req)).expect("request");
        match wire::read_message(&mut FromStd::new(&mut s), &limits) {
            Ok(Message::Frame(_)) => frames += 1,
            other => panic!("expected a frame, got {other:?}"),
        }
    }
    let _ = wire::write_message(&mut FromStd::new(&mut s), &Message::Bye);
    frames
}

fn main() {
    if !Path::new(MRI).exists() {
        eprintln!("clients bench skipped: {MRI} not found");
        return;
    }
    let threads = env_or("CLIENTS_BENCH_THREADS", 2usize);
    let size = env_or("CLIENTS_BENCH_SIZE", 512u32);
    let secs = env_or("CLIENTS_BENCH_SECS", 8.0f64);
    let ds = Dataset::load(MRI, None).expect("loading the MRI");
    let m = Arc::new(Marcher::from_dataset(&ds));
    let cfg = ServerConfig { listen: SocketAddr::from(([127, 0, 0, 1], 0)), threads, ..ServerConfig::default() };
    let server = Server::with_marcher(cfg, m.clone()).expect("server").spawn();
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!("clients: MRI {size}², {threads} marcher threads, {secs} s per row; load {}", load.trim());
    println!("| clients | frames/s in all | frames/s per client |");
    println!("|---|---|---|");
    for n in [1usize, 2, 4] {
        let until = Instant::now() + Duration::from_secs_f64(secs);
        let t0 = Instant::now();
        let handles: Vec<_> = (0..n)
            .map(|id| {
                let (addr, m) = (server.local_addr(), m.clone());
                std::thread::spawn(move || client(addr, m, id, size, until))
            })
            .collect();
        let frames: Vec<usize> = handles.into_iter().map(|h| h.join().expect("client")).collect();
        let dt = t0.elapsed().as_secs_f64();
        let per: Vec<String> = frames.iter().map(|&f| format!("{:.2}", f as f64 / dt)).collect();
        println!("| {n} | {:.2} | {} |", frames.iter().sum::<usize>() as f64 / dt, per.join(", "));
    }
    println!("render counts {:?}", server.render_counts());
    server.shutdown();
}
