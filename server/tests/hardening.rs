//! Hardening against garbage, hostile and slow clients: a real server on loopback
//! with short limits, attacked by bad clients, while a well-behaved client keeps checking
//! that its frames are exactly what the marcher renders; the server's memory (this process's
//! RSS) stays bounded. `docs/security.md` has the threat model these tests exercise.
//!
//! The file also holds the stable mirror of the `volume_header` fuzz target.

mod common;

#[allow(dead_code)]
#[path = "../../fuzz/src/volume_checks.rs"]
mod volume_checks;

use common::Client;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread;
use std::time::{Duration, Instant};
use volwarp_core::wire::{self, error_code, CameraRequest, Frame, Hello, Message, WireError};
use volwarp_core::Heuristic;
use volwarp_server::{Dataset, Marcher, Server, ServerConfig, ServerHandle};

/// The tests run one at a time: they measure this process's memory, time their timeouts and
/// read the server's log.
fn serial() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    static LOGGER: Capture = Capture;
    if log::set_logger(&LOGGER).is_ok() {
        log::set_max_level(log::LevelFilter::Info);
    }
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

/// Keeps every log line of the server, so tests can check that rejections name their reason.
struct Capture;

static LOG_LINES: std::sync::Mutex<Vec<String>> = std::sync::Mutex::new(Vec::new());

impl log::Log for Capture {
    fn enabled(&self, m: &log::Metadata) -> bool {
        m.level() <= log::Level::Info
    }
    fn log(&self, r: &log::Record) {
        if self.enabled(r.metadata()) {
            LOG_LINES.lock().unwrap_or_else(|e| e.into_inner()).push(r.args().to_string());
        }
    }
    fn flush(&self) {}
}

fn log_mark() -> usize {
    LOG_LINES.lock().unwrap_or_else(|e| e.into_inner()).len()
}

/// Asserts that a log line after `mark` contains every one of `words` (waits a little: the
/// server logs a closed connection after closing it).
fn assert_logged(mark: usize, words: &[&str]) {
    let t = Instant::now();
    loop {
        let found = LOG_LINES.lock().unwrap_or_else(|e| e.into_inner())[mark..]
            .iter()
            .any(|l| words.iter().all(|w| l.contains(w)));
        if found {
            return;
        }
        if t.elapsed() > Duration::from_secs(5) {
            let lines = LOG_LINES.lock().unwrap_or_else(|e| e.into_inner())[mark..].join("\n");
            panic!("no log line with {words:?} in:\n{lines}");
        }
        thread::sleep(Duration::from_millis(10));
    }
}

fn marcher() -> Arc<Marcher> {
    Arc::new(Marcher::from_dataset(&Dataset::marschner_lobb(32)))
}

/// Short limits so that every timeout fires within a second or two.
fn config() -> ServerConfig {
    ServerConfig {
        listen: SocketAddr::from(([127, 0, 0, 1], 0)),
        threads: 2,
        max_clients: 16,
        handshake_timeout: Duration::from_millis(800),
        idle_timeout: Duration::from_millis(1500),
        send_timeout: Duration::from_millis(1000),
        max_viewport: 1024,
        ..ServerConfig::default()
    }
}

fn start(cfg: ServerConfig, m: &Arc<Marcher>) -> ServerHandle {
    Server::with_marcher(cfg, m.clone()).unwrap().spawn()
}

fn request(m: &Marcher, seq: u64, size: u32) -> CameraRequest {
    let h = Heuristic::ALL[seq as usize % Heuristic::ALL.len()];
    CameraRequest {
        seq,
        camera: m.default_camera(size, size).orbit(seq as f32 * 17.0, 10.0),
        heuristic: h,
        radius_scale: 1.0,
        layers: 0,
    }
}

/// Resident memory of this process (server and test together), in bytes: measured on Linux
/// (where CI runs; a missing figure there fails the test), `None` elsewhere.
fn rss() -> Option<u64> {
    if !cfg!(target_os = "linux") {
        return None;
    }
    let s = std::fs::read_to_string("/proc/self/status").expect("/proc/self/status on Linux");
    let kb = s
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        .expect("VmRSS in /proc/self/status");
    Some(kb * 1024)
}

/// Asserts that resident memory grew by less than `limit` bytes since `before` (a [`rss`]
/// reading); returns the growth. Off Linux it says that memory is not checked.
fn assert_rss_grew_less(before: Option<u64>, limit: u64, what: &str) -> u64 {
    match (before, rss()) {
        (Some(a), Some(b)) => {
            let grown = b.saturating_sub(a);
            eprintln!("{what}: RSS grew by {} KiB", grown / 1024);
            assert!(grown < limit, "{what}: RSS grew by {grown} bytes (limit {limit})");
            grown
        }
        _ => {
            eprintln!("{what}: resident memory is measured on Linux only, not checked here");
            0
        }
    }
}

fn wait_for_clients(server: &ServerHandle, n: usize, within: Duration) {
    let t = Instant::now();
    while server.active_clients() != n && t.elapsed() < within {
        thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(server.active_clients(), n, "clients still connected after {within:?}");
}

/// Asserts the frame is exactly the marcher's render of the request (all but the timing).
fn assert_correct(m: &Marcher, req: &CameraRequest, f: &Frame) {
    let (want, _) = m.render_frame(req);
    assert_eq!(f.header.seq, req.seq);
    assert_eq!(f.header.camera, req.camera);
    assert_eq!(f.header.heuristic, req.heuristic);
    assert_eq!(f.header.bounds, want.header.bounds);
    assert_eq!(f.header.radius_unit, want.header.radius_unit);
    assert_eq!(f.header.count, want.header.count);
    assert!(f.samples == want.samples && f.colors == want.colors, "frame {} differs from the marcher's", req.seq);
}

fn expect_frame(c: &mut Client) -> Frame {
    match c.recv() {
        Ok(Message::Frame(f)) => f,
        other => panic!("expected a Frame, got {other:?}"),
    }
}

/// Reads until the server closes; returns the Error code it sent first, if any.
fn error_then_close(s: &mut TcpStream, within: Duration) -> Option<u16> {
    s.set_read_timeout(Some(within)).unwrap();
    let mut r = embedded_io_adapters::std::FromStd::new(&mut *s);
    let code = match wire::read_message(&mut r, &wire::Limits::for_frames(1024)) {
        Ok(Message::Error(e)) => Some(e.code),
        Ok(other) => panic!("expected Error or close, got {other:?}"),
        Err(WireError::Io(embedded_io::ErrorKind::TimedOut)) => panic!("not closed within {within:?}"),
        Err(_) => None,
    };
    let mut buf = [0u8; 256];
    loop {
        match s.read(&mut buf) {
            Ok(0) => return code,
            Ok(_) => continue,
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock || e.kind() == std::io::ErrorKind::TimedOut => {
                panic!("not closed within {within:?}")
            }
            Err(_) => return code,
        }
    }
}

/// A well-behaved client on its own thread that keeps requesting small frames and checks each
/// one, until stopped; returns how many frames it verified.
struct Watchdog {
    stop: Arc<AtomicBool>,
    frames: Arc<AtomicU64>,
    handle: thread::JoinHandle<()>,
}

impl Watchdog {
    fn start(addr: SocketAddr, m: &Arc<Marcher>) -> Watchdog {
        let stop = Arc::new(AtomicBool::new(false));
        let frames = Arc::new(AtomicU64::new(0));
        let (st, fr, m) = (stop.clone(), frames.clone(), m.clone());
        let handle = thread::spawn(move || {
            let mut c = Client::hello(addr, None);
            let mut seq = 1;
            while !st.load(Ordering::SeqCst) {
                let req = request(&m, seq, 48);
                c.send(&Message::CameraRequest(req));
                let f = expect_frame(&mut c);
                assert_correct(&m, &req, &f);
                fr.fetch_add(1, Ordering::SeqCst);
                seq += 1;
            }
            c.send(&Message::Bye);
        });
        Watchdog { stop, frames, handle }
    }

    fn wait_for(&self, n: u64) {
        let t = Instant::now();
        while self.frames.load(Ordering::SeqCst) < n && t.elapsed() < Duration::from_secs(30) {
            assert!(!self.handle.is_finished(), "the well-behaved client failed");
            thread::sleep(Duration::from_millis(5));
        }
        assert!(self.frames.load(Ordering::SeqCst) >= n, "the well-behaved client got no frames");
    }

    /// Checks it got at least `more` frames beyond now, then stops it.
    fn finish(self, more: u64) -> u64 {
        let now = self.frames.load(Ordering::SeqCst);
        self.wait_for(now + more);
        self.stop.store(true, Ordering::SeqCst);
        self.handle.join().expect("the well-behaved client failed");
        self.frames.load(Ordering::SeqCst)
    }
}

/// Deterministic garbage (xorshift), sometimes behind a valid-looking header.
fn garbage(seed: u64, len: usize) -> Vec<u8> {
    let mut x = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut v: Vec<u8> = (0..len)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x as u8
        })
        .collect();
    let prefix: &[u8] = match seed % 4 {
        0 => b"VWRP\x01\x00",
        1 => b"VWRP\x01\x00\x02\x00\x40\x00\x00\x00",
        _ => b"",
    };
    v.splice(0..0, prefix.iter().copied());
    v
}

#[test]
fn hundred_garbage_connections_do_not_disturb_a_good_client() {
    let _serial = serial();
    let m = marcher();
    let server = start(ServerConfig { max_clients: 24, ..config() }, &m);
    let addr = server.local_addr();
    let dog = Watchdog::start(addr, &m);
    dog.wait_for(2);
    let rss0 = rss();
    let mark = log_mark();
    let t = Instant::now();
    let attackers: Vec<_> = (0..100u64)
        .map(|i| {
            thread::spawn(move || {
                let mut s = TcpStream::connect(addr).unwrap();
                if i % 3 == 0 {
                    // Garbage after a proper handshake.
                    let mut w = embedded_io_adapters::std::FromStd::new(&mut s);
                    wire::write_hello(&mut w, &Hello::new(0)).unwrap();
                    let mut r = embedded_io_adapters::std::FromStd::new(&mut s);
                    match wire::read_message(&mut r, &wire::Limits::for_frames(16)) {
                        Ok(Message::Hello(_)) => {}
                        Ok(Message::Error(e)) => assert_eq!(e.code, error_code::BUSY),
                        other => panic!("{other:?}"),
                    }
                }
                let _ = s.write_all(&garbage(i, 16 + (i as usize * 37) % 2000));
                // Busy, bad request, too large or timeout: always an answer and a close.
                error_then_close(&mut s, Duration::from_secs(10))
            })
        })
        .collect();
    let mut codes = std::collections::BTreeMap::new();
    for a in attackers {
        *codes.entry(a.join().expect("an attacker thread failed")).or_insert(0) += 1;
    }
    eprintln!("100 garbage connections answered in {:?}: {codes:?}", t.elapsed());
    assert!(!codes.contains_key(&Some(error_code::INTERNAL)));
    assert_logged(mark, &["closed: handshake failed: not a volwarp stream"]);
    wait_for_clients(&server, 1, Duration::from_secs(10));
    let frames = dog.finish(3);
    assert_rss_grew_less(rss0, 64 << 20, "garbage connections");
    eprintln!("watchdog verified {frames} frames");
    server.shutdown();
}

#[test]
fn a_header_promising_4_gib_is_refused_without_allocating() {
    let _serial = serial();
    let m = marcher();
    let server = start(config(), &m);
    let addr = server.local_addr();
    let rss0 = rss();
    let mark = log_mark();
    for (handshake, ty) in [(false, 1u8), (true, 2), (true, 3), (true, 4)] {
        let mut c = if handshake { Client::hello(addr, None) } else { Client::connect(addr) };
        let mut h = b"VWRP\x01\x00".to_vec();
        h.extend_from_slice(&[ty, 0]);
        h.extend_from_slice(&u32::MAX.to_le_bytes());
        c.send_raw(&h);
        // Then keep streaming: the server must not wait for (or buffer) 4 GiB.
        let _ = c.stream.write_all(&[0u8; 4096]);
        let code = error_then_close(&mut c.stream, Duration::from_secs(5));
        assert_eq!(code, Some(error_code::TOO_LARGE), "type {ty}");
    }
    assert_logged(mark, &["closed", "4294967295 bytes is over the limit"]);
    assert_rss_grew_less(rss0, 32 << 20, "4 GiB headers");
    wait_for_clients(&server, 0, Duration::from_secs(5));
    let mut c = Client::hello(addr, None);
    let req = request(&m, 1, 32);
    c.send(&Message::CameraRequest(req));
    assert_correct(&m, &req, &expect_frame(&mut c));
    server.shutdown();
}

/// Sends `bytes` one at a time, `gap` apart (after a proper handshake if `after_hello`),
/// until the server closes; returns how long that took and the Error code it sent.
fn trickle(addr: SocketAddr, after_hello: bool, bytes: &[u8], gap: Duration) -> (Duration, Option<u16>) {
    let mut s = if after_hello { Client::hello(addr, None).stream } else { TcpStream::connect(addr).unwrap() };
    let t = Instant::now();
    let mut closed = false;
    for b in bytes {
        thread::sleep(gap);
        if s.write_all(&[*b]).is_err() {
            closed = true;
            break;
        }
        // Has the server answered (Error) or closed already?
        s.set_nonblocking(true).unwrap();
        let mut probe = [0u8; 1];
        let gone = !matches!(s.peek(&mut probe), Err(ref e) if e.kind() == std::io::ErrorKind::WouldBlock);
        s.set_nonblocking(false).unwrap();
        if gone {
            closed = true;
            break;
        }
    }
    let at = t.elapsed();
    assert!(closed, "the server never dropped a client sending one byte every {gap:?}");
    (at, error_then_close(&mut s, Duration::from_secs(5)))
}

#[test]
fn a_client_sending_one_byte_at_a_time_is_dropped_at_the_deadline() {
    let _serial = serial();
    let m = marcher();
    let cfg = config();
    let server = start(cfg.clone(), &m);
    let addr = server.local_addr();
    let dog = Watchdog::start(addr, &m);
    dog.wait_for(1);
    let gap = Duration::from_millis(250);

    // During the handshake: a Hello trickled in at 4 bytes/s (21 bytes would take 5 s).
    let hello = wire::encode_to_vec(&Message::Hello(Hello::new(0)));
    let mark = log_mark();
    let (at, code) = trickle(addr, false, &hello, gap);
    assert_logged(mark, &["closed: handshake failed", "TimedOut"]);
    eprintln!("slow handshake dropped after {at:?} with {code:?}");
    assert!(at < cfg.handshake_timeout + Duration::from_millis(1200), "dropped only after {at:?}");
    assert_eq!(code, Some(error_code::TIMEOUT));

    // After the handshake: a CameraRequest trickled in (76 bytes would take 19 s).
    let req = wire::encode_to_vec(&Message::CameraRequest(request(&m, 1, 32)));
    let mark = log_mark();
    let (at, code) = trickle(addr, true, &req, gap);
    assert_logged(mark, &["closed", "TimedOut"]);
    eprintln!("slow request dropped after {at:?} with {code:?}");
    assert!(at < cfg.idle_timeout + Duration::from_millis(1200), "dropped only after {at:?}");
    assert_eq!(code, Some(error_code::TIMEOUT));

    dog.finish(2);
    wait_for_clients(&server, 0, Duration::from_secs(5));
    server.shutdown();
}

#[test]
fn clients_disconnecting_mid_message_and_mid_frame_are_cleaned_up() {
    let _serial = serial();
    let m = marcher();
    let server = start(config(), &m);
    let addr = server.local_addr();
    let dog = Watchdog::start(addr, &m);
    dog.wait_for(1);
    for i in 0..6u64 {
        let mut c = Client::hello(addr, None);
        if i % 2 == 0 {
            // Half a CameraRequest, then gone.
            let req = wire::encode_to_vec(&Message::CameraRequest(request(&m, i, 64)));
            c.send_raw(&req[..req.len() / 2]);
        } else {
            // A large frame, read a little of it, then gone.
            c.send(&Message::CameraRequest(request(&m, i, 1024)));
            let mut buf = [0u8; 100];
            c.stream.read_exact(&mut buf).unwrap();
        }
        drop(c);
    }
    wait_for_clients(&server, 1, Duration::from_secs(10));
    dog.finish(3);
    server.shutdown();
}

#[test]
fn a_client_that_never_reads_costs_bounded_memory_and_is_dropped() {
    let _serial = serial();
    let m = marcher();
    let server = start(config(), &m);
    let addr = server.local_addr();
    let dog = Watchdog::start(addr, &m);
    dog.wait_for(1);
    let rss0 = rss();
    let mark = log_mark();
    let mut c = Client::hello(addr, None);
    c.stream.set_write_timeout(Some(Duration::from_secs(5))).unwrap();
    // Thousands of requests for large frames it never reads: latest wins, nothing queues.
    let t = Instant::now();
    let mut sent = 0;
    for seq in 0..5000 {
        let msg = wire::encode_to_vec(&Message::CameraRequest(request(&m, seq, 512)));
        if c.stream.write_all(&msg).is_err() {
            break;
        }
        sent += 1;
        if t.elapsed() > Duration::from_secs(4) {
            break;
        }
    }
    let peak = rss();
    // Dropped by the send timeout once its socket buffers are full, or by the idle timeout
    // after its last request, whichever comes first.
    wait_for_clients(&server, 1, Duration::from_secs(10));
    // Latest wins: thousands of requests, a handful of frames.
    assert_logged(mark, &["stale requests skipped"]);
    eprintln!("never-reading client: {sent} requests sent");
    match (rss0, peak) {
        (Some(a), Some(b)) => {
            let grown = b.saturating_sub(a);
            eprintln!("never-reading client: RSS grew by {} KiB", grown / 1024);
            assert!(grown < 96 << 20, "RSS grew by {grown} bytes");
        }
        _ => eprintln!("never-reading client: resident memory is measured on Linux only, not checked here"),
    }
    dog.finish(3);
    drop(c);
    server.shutdown();
}

#[test]
fn eight_well_behaved_clients_at_once_get_correct_frames() {
    let _serial = serial();
    let m = marcher();
    let server = start(ServerConfig { max_clients: 8, ..config() }, &m);
    let addr = server.local_addr();
    let clients: Vec<_> = (0..8u64)
        .map(|k| {
            let m = m.clone();
            thread::spawn(move || {
                let mut c = Client::hello(addr, None);
                for j in 0..4 {
                    let req = request(&m, k * 100 + j, 32 + 8 * k as u32);
                    c.send(&Message::CameraRequest(req));
                    assert_correct(&m, &req, &expect_frame(&mut c));
                }
                c.send(&Message::Bye);
            })
        })
        .collect();
    for c in clients {
        c.join().expect("a client failed");
    }
    wait_for_clients(&server, 0, Duration::from_secs(5));
    server.shutdown();
}

#[test]
fn the_token_is_checked_and_a_wrong_one_gets_an_error_and_a_close() {
    let _serial = serial();
    let m = marcher();
    // Off loopback a token is mandatory.
    let open = ServerConfig { listen: SocketAddr::from(([0, 0, 0, 0], 0)), ..config() };
    assert!(Server::with_marcher(open.clone(), m.clone()).is_err());
    let server = start(ServerConfig { token: Some("correct horse".into()), ..open }, &m);
    let addr = SocketAddr::from(([127, 0, 0, 1], server.local_addr().port()));
    let mark = log_mark();
    for token in [&b""[..], b"correct hors", b"correct horse ", b"Correct horse", &[0xff; 64]] {
        let mut c = Client::connect(addr);
        c.send(&Message::Hello(Hello::new(0).with_token(token).unwrap()));
        assert_eq!(error_then_close(&mut c.stream, Duration::from_secs(5)), Some(error_code::UNAUTHORIZED));
    }
    assert_logged(mark, &["closed: missing or wrong token"]);
    let mut c = Client::hello(addr, Some(b"correct horse"));
    let req = request(&m, 9, 32);
    c.send(&Message::CameraRequest(req));
    assert_correct(&m, &req, &expect_frame(&mut c));
    server.shutdown();
}

// ---------------------------------------------------------------- volume fuzz mirrors

/// The committed seeds of fuzz target `target`, sorted.
fn fuzz_seeds(target: &str) -> Vec<Vec<u8>> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/seeds").join(target);
    let mut seeds: Vec<Vec<u8>> =
        std::fs::read_dir(&dir).map(|d| d.flatten().map(|e| std::fs::read(e.path()).unwrap()).collect()).unwrap();
    seeds.sort();
    assert!(seeds.len() >= 5, "seed corpus missing under {}", dir.display());
    seeds
}

/// Runs `check` on every seed, then on `rounds` deterministic mutations of them (xorshift):
/// byte flips, insertions of `tokens`, digits changed into other digits (sizes and names that
/// grow and wrap), truncations and a flip of byte 0 (the target's selector), 1 to 4 at a time.
fn mirror(seeds: &[Vec<u8>], tokens: &[&[u8]], rounds: usize, mut x: u64, check: fn(&[u8])) {
    let mut next = |n: usize| {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        (x % n.max(1) as u64) as usize
    };
    for s in seeds {
        check(s);
    }
    for _ in 0..rounds {
        let mut v = seeds[next(seeds.len())].clone();
        for _ in 0..1 + next(4) {
            let n = v.len();
            match next(5) {
                0 if n > 1 => {
                    let i = 1 + next(n - 1);
                    v[i] ^= 1 << next(8);
                }
                1 => {
                    let t = tokens[next(tokens.len())];
                    let i = (1 + next(n)).min(n);
                    v.splice(i..i, t.iter().copied());
                }
                2 if n > 1 => {
                    let start = 1 + next(n - 1);
                    if let Some(i) = (start..n).chain(1..start).find(|&i| v[i].is_ascii_digit()) {
                        v[i] = b'0' + next(10) as u8;
                    }
                }
                3 => v.truncate(next(n + 1)),
                _ => v[0] ^= 1,
            }
            if v.is_empty() {
                v.push(0);
            }
        }
        check(&v);
    }
}

/// Stable mirror of the `volume_header` fuzz target: its seeds, then 20,000 deterministic
/// mutations of them.
#[test]
fn volume_header_mirror() {
    let tokens: [&[u8]; 10] =
        [b"\n\n", b"\r\n", b": ", b":=", b"sizes: 0 1 2", b"spacings: nan 1 1", b"byte skip: -2", b"(1,0", b"_", b"x"];
    mirror(&fuzz_seeds("volume_header"), &tokens, 20_000, 0x2545_F491_4F6C_DD1D, volume_checks::volume_header);
}

/// Stable mirror of the `volume_load` fuzz target: its seeds (among them the dims that wrap a
/// 64-bit voxel count to 0), then 3,000 deterministic mutations of them (each a load from a file).
#[test]
fn volume_load_mirror() {
    let tokens: [&[u8]; 10] = [
        b"4194304",
        b"65536",
        b"sizes: 65536 65536 65536\n",
        b"encoding: gzip\n",
        b"data file: d.raw\n",
        b"byte skip: -1\n",
        b"type: double\n",
        b"\n\n",
        b"x",
        b"_float32.raw\n",
    ];
    mirror(&fuzz_seeds("volume_load"), &tokens, 3_000, 0x9E37_79B9_7F4A_7C15, volume_checks::volume_load);
}
