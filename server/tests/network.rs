//! End to end over loopback: handshake, frames, heuristics, latest wins, limits, bad clients.

mod common;

use common::Client;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};
use volwarp_core::wire::{error_code, CameraRequest, Hello, Message, WireError};
use volwarp_core::{Camera, Heuristic};
use volwarp_server::{Dataset, Marcher, Server, ServerConfig, ServerHandle};

fn config() -> ServerConfig {
    ServerConfig { listen: SocketAddr::from(([127, 0, 0, 1], 0)), threads: 2, ..ServerConfig::default() }
}

fn start(cfg: ServerConfig) -> (ServerHandle, Arc<Marcher>) {
    let marcher = Arc::new(Marcher::from_dataset(&Dataset::default_bundled()));
    let server = Server::with_marcher(cfg, marcher.clone()).unwrap();
    (server.spawn(), marcher)
}

fn request(m: &Marcher, seq: u64, heuristic: Heuristic, yaw: f32) -> CameraRequest {
    CameraRequest { seq, camera: m.default_camera(64, 48).orbit(yaw, 10.0), heuristic, radius_scale: 1.0, layers: 0 }
}

fn wait_for_clients(server: &ServerHandle, n: usize) {
    let t = Instant::now();
    while server.active_clients() != n && t.elapsed() < Duration::from_secs(20) {
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(server.active_clients(), n);
}

fn expect_frame(c: &mut Client) -> volwarp_core::wire::Frame {
    match c.recv() {
        Ok(Message::Frame(f)) => f,
        other => panic!("expected a Frame, got {other:?}"),
    }
}

fn expect_error(c: &mut Client, code: u16) {
    match c.recv() {
        Ok(Message::Error(e)) => assert_eq!(e.code, code, "{}", e.text),
        other => panic!("expected Error {code}, got {other:?}"),
    }
    // Then the server closes.
    assert!(matches!(c.recv(), Err(WireError::Closed | WireError::Io(_) | WireError::UnexpectedEof)));
}

#[test]
fn frame_matches_request_and_heuristic_changes_take_effect() {
    let (server, m) = start(config());
    let mut c = Client::hello(server.local_addr(), None);
    let req = request(&m, 7, Heuristic::Entrance, 30.0);
    c.send(&Message::CameraRequest(req));
    let f = expect_frame(&mut c);
    assert_eq!(f.header.seq, 7);
    assert_eq!(f.header.camera, req.camera);
    assert_eq!(f.header.heuristic, Heuristic::Entrance);
    let pb = m.march(&req.camera, Heuristic::Entrance);
    assert!(pb.nonempty() > 300, "{}", pb.nonempty());
    assert_eq!(f.header.count as usize, pb.nonempty());
    assert_eq!(f.samples.len(), pb.nonempty());
    assert_eq!(f, Message::Frame(f.clone()).try_into_frame(), "round trip");
    let (local, _) = m.render_frame(&req);
    assert_eq!(f.samples, local.samples);
    assert_eq!(f.colors, local.colors);

    // Same camera, another heuristic: the frame follows it.
    let req2 = CameraRequest { seq: 8, heuristic: Heuristic::Exit, ..req };
    c.send(&Message::CameraRequest(req2));
    let f2 = expect_frame(&mut c);
    assert_eq!(f2.header.seq, 8);
    assert_eq!(f2.header.heuristic, Heuristic::Exit);
    assert_eq!(f2.samples, m.render_frame(&req2).0.samples);
    assert_ne!(f2.samples, f.samples, "exit depths differ from entrance depths");
    c.send(&Message::Bye);
    assert!(matches!(c.recv(), Err(WireError::Closed | WireError::Io(_))));
    server.shutdown();
}

trait IntoFrame {
    fn try_into_frame(self) -> volwarp_core::wire::Frame;
}
impl IntoFrame for Message {
    fn try_into_frame(self) -> volwarp_core::wire::Frame {
        let bytes = volwarp_core::wire::encode_to_vec(&self);
        match volwarp_core::wire::read_message(&mut &bytes[..], &volwarp_core::wire::Limits::default()) {
            Ok(Message::Frame(f)) => f,
            other => panic!("{other:?}"),
        }
    }
}

#[test]
fn latest_request_wins() {
    let (server, m) = start(ServerConfig { frame_delay: Some(Duration::from_millis(300)), ..config() });
    let mut c = Client::hello(server.local_addr(), None);
    for seq in 1..=6 {
        c.send(&Message::CameraRequest(request(&m, seq, Heuristic::Threshold, seq as f32 * 10.0)));
    }
    let mut seqs = Vec::new();
    while seqs.last() != Some(&6) {
        seqs.push(expect_frame(&mut c).header.seq);
    }
    assert!(seqs.len() <= 3, "stale requests were rendered: {seqs:?}");
    // Nothing else is queued.
    c.stream.set_read_timeout(Some(Duration::from_millis(800))).unwrap();
    assert!(matches!(c.recv(), Err(WireError::Io(_))), "no further frame");
    server.shutdown();
}

/// The seqs of the frames that arrive until one for `last` has (and none after it, within
/// 800 ms).
fn frames_until(c: &mut Client, last: u64) -> Vec<(u64, u32)> {
    let mut got = Vec::new();
    while got.last().map(|&(s, _)| s) != Some(last) {
        let f = expect_frame(c);
        got.push((f.header.seq, f.header.camera.width));
    }
    c.stream.set_read_timeout(Some(Duration::from_millis(800))).unwrap();
    assert!(matches!(c.recv(), Err(WireError::Io(_))), "no further frame after {got:?}");
    c.stream.set_read_timeout(None).unwrap();
    got
}

/// A request for another viewport (the view came to rest or started moving, with adaptive
/// resolution) drops the render under way: no frame of it is sent. The render after a dropped
/// one runs to its end, and a request for the same viewport never drops one.
#[test]
fn a_request_for_another_viewport_drops_the_render_under_way() {
    let (server, m) = start(ServerConfig { frame_delay: Some(Duration::from_millis(1500)), ..config() });
    let mut c = Client::hello(server.local_addr(), None);
    let full = |seq, yaw| request(&m, seq, Heuristic::Threshold, yaw);
    let coarse = |seq, yaw| {
        let r: CameraRequest = full(seq, yaw);
        CameraRequest { camera: r.camera.with_viewport(32, 24), ..r }
    };
    // (The pauses let the server take each request before the next one comes; on a machine
    // too slow for that the newest request wins anyway and the seqs are the same.)
    let pause = || std::thread::sleep(Duration::from_millis(300));

    // Full, then coarse while the full one renders: only the coarse one arrives.
    c.send(&Message::CameraRequest(full(1, 0.0)));
    pause();
    c.send(&Message::CameraRequest(coarse(2, 5.0)));
    assert_eq!(frames_until(&mut c, 2), vec![(2, 32)]);

    // Full, coarse, full: the coarse render follows a dropped one, so it is not dropped.
    c.send(&Message::CameraRequest(full(3, 10.0)));
    pause();
    c.send(&Message::CameraRequest(coarse(4, 15.0)));
    pause();
    c.send(&Message::CameraRequest(full(5, 20.0)));
    assert_eq!(frames_until(&mut c, 5), vec![(4, 32), (5, 64)]);

    // The same viewport, another camera: the render under way is finished and sent.
    c.send(&Message::CameraRequest(full(6, 25.0)));
    pause();
    c.send(&Message::CameraRequest(full(7, 30.0)));
    assert_eq!(frames_until(&mut c, 7), vec![(6, 64), (7, 64)]);
    server.shutdown();
}

/// What a client taking frames in parts reads up to the next whole frame, message by message:
/// the bytes of each frame's parts, whether a FrameDropped came, and the frame.
fn read_parts(c: &mut Client) -> (Vec<usize>, bool, volwarp_core::wire::Frame) {
    use embedded_io_adapters::std::FromStd;
    use volwarp_core::wire::{self, Limits, MsgType};
    let limits = Limits::for_frames(4096);
    let mut r = FromStd::new(&mut c.stream);
    let (mut sizes, mut dropped, mut parts) = (Vec::new(), false, wire::Assembly::new());
    loop {
        let h = wire::read_header(&mut r, &limits).unwrap();
        match h.ty {
            MsgType::FramePart => sizes.push(h.len as usize),
            MsgType::FrameDropped => dropped = true,
            other => panic!("a {other:?} between frame parts"),
        }
        if let Some((bytes, h)) = wire::take_part(&mut r, &h, &limits, &mut parts).unwrap() {
            match wire::decode_message(&bytes, &h, &limits).unwrap() {
                Message::Frame(f) => return (sizes, dropped, f),
                other => panic!("parts of a {other:?}"),
            }
        }
    }
}

/// For a client that takes frames in parts, the same request for another viewport that arrives
/// while a frame is written ends it after the part under way (FrameDropped), and the next frame
/// comes whole; a frame not dropped reassembles to the frame a whole-frame client gets.
#[test]
fn a_request_for_another_viewport_drops_the_frame_on_the_link() {
    let (server, m) = start(config());
    let mut c = Client::connect(server.local_addr());
    c.send(&Message::Hello(Hello::new(volwarp_core::wire::CAP_PARTS)));
    match c.recv() {
        Ok(Message::Hello(h)) => assert_ne!(h.capabilities & volwarp_core::wire::CAP_PARTS, 0, "parts granted"),
        other => panic!("expected Hello, got {other:?}"),
    }
    // About 1024² × 12 bytes at most: more than the socket holds while the client reads nothing.
    let full =
        |seq| CameraRequest { camera: m.default_camera(1024, 1024), ..request(&m, seq, Heuristic::Threshold, 0.0) };
    c.send(&Message::CameraRequest(full(1)));
    // Its first part has come: the render is done and the frame is being written. The client
    // reads nothing for a while (the server's writes block), then the view starts moving.
    let mut b = [0u8; 1];
    assert_eq!(c.stream.peek(&mut b).unwrap(), 1);
    std::thread::sleep(Duration::from_millis(300));
    let coarse = CameraRequest { camera: m.default_camera(64, 64), ..request(&m, 2, Heuristic::Threshold, 5.0) };
    c.send(&Message::CameraRequest(coarse));
    std::thread::sleep(Duration::from_millis(300));
    let (sizes, dropped, f) = read_parts(&mut c);
    assert!(dropped, "the full frame was dropped on the link");
    assert_eq!((f.header.seq, f.header.camera.width), (2, 64), "the coarse frame came next, whole");
    let message_len =
        |f: &volwarp_core::wire::Frame| volwarp_core::wire::HEADER_LEN + 96 + 12 * f.header.count as usize;
    let sent = sizes.iter().sum::<usize>() - message_len(&f);
    assert!(sizes.iter().all(|&n| n <= volwarp_core::wire::PART_LEN));

    // The render after a dropped frame is not dropped; its parts make the frame a whole-frame
    // client gets for the same request.
    c.send(&Message::CameraRequest(full(3)));
    let (sizes, dropped, f) = read_parts(&mut c);
    assert!(!dropped && sizes.len() > 1, "{} parts", sizes.len());
    let mut whole = Client::hello(server.local_addr(), None);
    whole.send(&Message::CameraRequest(full(3)));
    assert_eq!(expect_frame(&mut whole), f);
    let full_len = message_len(&f);
    assert!(sent < full_len / 2, "{sent} of the dropped frame's {full_len} bytes went out");
    eprintln!("{sent} of the dropped frame's {full_len} bytes went out");
    server.shutdown();
}

#[test]
fn bad_clients_do_not_disturb_a_good_one() {
    let (server, m) = start(config());
    let addr = server.local_addr();
    let mut good = Client::hello(addr, None);
    good.send(&Message::CameraRequest(request(&m, 1, Heuristic::Threshold, 0.0)));
    assert_eq!(expect_frame(&mut good).header.seq, 1);

    // Disconnects in the middle of a large frame.
    let mut quitter = Client::hello(addr, None);
    let big = CameraRequest { camera: m.default_camera(1024, 1024), ..request(&m, 1, Heuristic::Exit, 0.0) };
    quitter.send(&Message::CameraRequest(big));
    drop(quitter);

    // Garbage instead of a Hello.
    let mut garbage = Client::connect(addr);
    garbage.send_raw(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n");
    expect_error(&mut garbage, error_code::BAD_REQUEST);

    // Garbage after the handshake.
    let mut g2 = Client::hello(addr, None);
    g2.send_raw(&[0xAB; 64]);
    expect_error(&mut g2, error_code::BAD_REQUEST);

    // An oversized message.
    let mut huge = Client::hello(addr, None);
    let mut h = b"VWRP".to_vec();
    h.extend_from_slice(&1u16.to_le_bytes());
    h.extend_from_slice(&[2, 0]);
    h.extend_from_slice(&100_000_000u32.to_le_bytes());
    huge.send_raw(&h);
    expect_error(&mut huge, error_code::TOO_LARGE);

    // A viewport over the limit.
    let mut wide = Client::hello(addr, None);
    let mut req = request(&m, 1, Heuristic::Threshold, 0.0);
    req.camera = Camera { width: 5000, ..req.camera };
    wide.send(&Message::CameraRequest(req));
    expect_error(&mut wide, error_code::TOO_LARGE);

    // A frame sent to the server is a protocol error.
    let mut backwards = Client::hello(addr, None);
    backwards.send(&Message::Hello(Hello::new(0)));
    expect_error(&mut backwards, error_code::BAD_REQUEST);

    // The good client still gets every frame.
    for seq in 2..5 {
        good.send(&Message::CameraRequest(request(&m, seq, Heuristic::Peak, seq as f32 * 20.0)));
        let f = expect_frame(&mut good);
        assert_eq!(f.header.seq, seq);
        assert_eq!(f.header.heuristic, Heuristic::Peak);
    }
    // Connections of the bad clients are gone.
    wait_for_clients(&server, 1);
    server.shutdown();
}

#[test]
fn token_limits_and_timeouts() {
    // A token is required off loopback.
    let open = ServerConfig { listen: SocketAddr::from(([0, 0, 0, 0], 0)), ..config() };
    assert!(Server::bind(open, Dataset::marschner_lobb(8)).is_err());

    let cfg = ServerConfig {
        token: Some("s3cret".into()),
        max_clients: 2,
        handshake_timeout: Duration::from_millis(300),
        idle_timeout: Duration::from_millis(1500),
        ..config()
    };
    let (server, m) = start(cfg);
    let addr = server.local_addr();

    let mut wrong = Client::connect(addr);
    wrong.send(&Message::Hello(Hello::new(0).with_token(b"guess").unwrap()));
    expect_error(&mut wrong, error_code::UNAUTHORIZED);
    let mut none = Client::connect(addr);
    none.send(&Message::Hello(Hello::new(0)));
    expect_error(&mut none, error_code::UNAUTHORIZED);

    wait_for_clients(&server, 0);
    let t = Instant::now();
    let mut silent = Client::connect(addr);
    expect_error(&mut silent, error_code::TIMEOUT);
    assert!(t.elapsed() < Duration::from_secs(5));

    wait_for_clients(&server, 0);
    let mut a = Client::hello(addr, Some(b"s3cret"));
    a.send(&Message::CameraRequest(request(&m, 1, Heuristic::Gradient, 0.0)));
    assert_eq!(expect_frame(&mut a).header.seq, 1);
    let _b = Client::hello(addr, Some(b"s3cret"));
    let mut c = Client::connect(addr);
    expect_error(&mut c, error_code::BUSY);

    // An idle client is dropped with a TIMEOUT error.
    expect_error(&mut a, error_code::TIMEOUT);
    server.shutdown();
}

/// With levels of detail and a frame budget no frame can meet, a moving camera gets frames of
/// the coarsest level (each equal to that level's own render, in the same box) and a resting
/// camera the volume itself; without a budget every frame is the volume's.
#[test]
fn a_moving_camera_gets_coarser_levels_within_the_budget_and_a_resting_one_the_volume() {
    let ds = Dataset::default_bundled();
    let m = Marcher::from_dataset(&ds);
    let levels = m.levels(&ds.tf).unwrap();
    assert!(levels.len() >= 2, "{} levels", levels.len());
    for (l, lm) in levels.iter().enumerate() {
        assert_eq!(lm.level() as usize, l);
        assert_eq!(lm.volume().bounds(), m.volume().bounds(), "every level is in the same box");
        let d = m.volume().dims().map(|n| n.div_ceil(1 << l));
        assert_eq!(lm.volume().dims(), d);
    }
    let coarsest = levels.len() - 1;
    for budget in [Some(Duration::from_nanos(1)), None] {
        let server =
            Server::with_levels(ServerConfig { frame_budget: budget, ..config() }, levels.clone()).unwrap().spawn();
        let mut c = Client::hello(server.local_addr(), None);
        let mut ask = |seq: u64, yaw: f32| {
            let req = request(&m, seq, Heuristic::Threshold, yaw);
            c.send(&Message::CameraRequest(req));
            (req, expect_frame(&mut c))
        };
        let (_, first) = ask(1, 10.0);
        assert_eq!(first.header.level, 0, "the first view is not a moving one");
        for (seq, yaw) in [(2, 14.0), (3, 18.0)] {
            let (req, f) = ask(seq, yaw);
            let want = if budget.is_some() { coarsest } else { 0 };
            assert_eq!(f.header.level as usize, want, "moving, budget {budget:?}");
            let own = levels[want].render_frame(&req).0;
            assert_eq!((f.samples.clone(), f.colors.clone()), (own.samples, own.colors));
            assert_eq!(f.header.bounds, first.header.bounds);
        }
        let (req, rest) = ask(4, 18.0);
        assert_eq!(rest.header.level, 0, "a resting camera gets the volume itself");
        assert_eq!(rest.samples, m.render_frame(&req).0.samples);
        server.shutdown();
    }
}

/// One token guess on a new connection: `Some(code)` of the Error it got (`None`: the server
/// answered Hello, or the connection failed before an Error arrived).
fn guess(addr: SocketAddr, token: &[u8]) -> Option<u16> {
    let stream = std::net::TcpStream::connect(addr).ok()?;
    stream.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    let mut c = Client { stream };
    let mut bytes = Vec::new();
    volwarp_core::wire::write_message(
        &mut volwarp_core::wire::VecWriter(&mut bytes),
        &Message::Hello(Hello::new(0).with_token(token).unwrap()),
    )
    .unwrap();
    c.send_raw(&bytes);
    match c.recv() {
        Ok(Message::Error(e)) => Some(e.code),
        _ => None,
    }
}

#[test]
fn token_guessing_is_rate_limited_per_address_and_others_are_served() {
    let cfg = ServerConfig { token: Some("s3cret".into()), max_auth_failures: 10, ..config() };
    let (server, m) = start(cfg);
    let addr = server.local_addr();
    // A client with the right token, connected before the guessing, keeps getting frames.
    let mut good = Client::hello(addr, Some(b"s3cret"));
    let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let served = {
        let (stop, m) = (stop.clone(), m.clone());
        std::thread::spawn(move || {
            let mut frames = 0u32;
            let mut seq = 0;
            while !stop.load(std::sync::atomic::Ordering::SeqCst) {
                seq += 1;
                good.send(&Message::CameraRequest(request(&m, seq, Heuristic::Threshold, seq as f32)));
                assert_eq!(expect_frame(&mut good).header.seq, seq);
                frames += 1;
            }
            frames
        })
    };
    // The guesser: one wrong token per connection, about a thousand a second (faster would
    // only spend the machine's ephemeral ports).
    let t0 = Instant::now();
    let (mut checked, mut limited, mut other) = (0u32, 0u32, 0u32);
    while t0.elapsed() < Duration::from_secs(2) {
        match guess(addr, b"guess") {
            Some(error_code::UNAUTHORIZED) => checked += 1,
            Some(error_code::RATE_LIMITED) => limited += 1,
            _ => other += 1,
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    let secs = t0.elapsed().as_secs_f64();
    stop.store(true, std::sync::atomic::Ordering::SeqCst);
    let frames = served.join().expect("the good client was served throughout");
    eprintln!(
        "{checked} tokens checked, {limited} refused as rate-limited, {other} other in {secs:.2} s; \
         {frames} frames to the good client meanwhile"
    );
    // A burst of 10, then 10 per second.
    assert!(f64::from(checked) <= 10.0 + 10.0 * secs + 2.0, "{checked} tokens checked in {secs:.2} s");
    assert!(checked >= 10, "the first guesses are answered normally ({checked})");
    assert!(limited > checked, "most guesses are refused before the handshake ({limited} vs {checked})");
    assert!(frames >= 5, "the good client got {frames} frames while the guessing went on");
    // The address's bucket refills: a right token connects again shortly after.
    std::thread::sleep(Duration::from_millis(250));
    let mut again = Client::hello(addr, Some(b"s3cret"));
    again.send(&Message::CameraRequest(request(&m, 1, Heuristic::Threshold, 0.0)));
    assert_eq!(expect_frame(&mut again).header.seq, 1);
    // Right tokens never use up the budget.
    for _ in 0..30 {
        let _ = Client::hello(addr, Some(b"s3cret"));
    }
    assert_eq!(guess(addr, b"guess"), Some(error_code::UNAUTHORIZED));
    drop(again);
    server.shutdown();
}

/// `Server::bind` builds the levels of detail where the config sets a frame budget: a moving
/// camera then gets a coarser level than the volume.
#[test]
fn bind_with_a_frame_budget_serves_levels_of_detail() {
    let cfg = ServerConfig { frame_budget: Some(Duration::from_nanos(1)), ..config() };
    let server = Server::bind(cfg, Dataset::default_bundled()).unwrap().spawn();
    let m = Marcher::from_dataset(&Dataset::default_bundled());
    let mut c = Client::hello(server.local_addr(), None);
    c.send(&Message::CameraRequest(request(&m, 1, Heuristic::Threshold, 10.0)));
    assert_eq!(expect_frame(&mut c).header.level, 0);
    c.send(&Message::CameraRequest(request(&m, 2, Heuristic::Threshold, 14.0)));
    assert!(expect_frame(&mut c).header.level > 0, "a moving camera under a budget");
    server.shutdown();
}
