//! The client's writer sends only the newest camera, throttled (against a scripted server).

mod common;

use common::*;
use std::io::Write;
use std::sync::mpsc;
use std::time::{Duration, Instant};
use volwarp_client::connection::connect;
use volwarp_client::controls::home_camera;
use volwarp_client::network::{Network, View, THROTTLE};
use volwarp_core::wire::{CameraRequest, Hello, Message};
use volwarp_core::Heuristic;

#[test]
fn writer_sends_only_the_newest_camera_throttled() {
    let (tx, rx) = mpsc::channel();
    let addr = fake_server(move |mut s| {
        greet(&mut s, Hello::new(0));
        // Never answer: count what the client sends in one second.
        let t0 = Instant::now();
        let mut got = Vec::new();
        while t0.elapsed() < Duration::from_secs(1) {
            match read_msg(&mut s) {
                Some(Message::CameraRequest(r)) => got.push((t0.elapsed(), r)),
                _ => break,
            }
        }
        tx.send(got).unwrap();
        std::thread::sleep(Duration::from_millis(500));
    });
    let conn = connect(&addr, None, Duration::from_secs(10)).unwrap();
    let home = home_camera(&conn.bounds, 32, 32);
    let net = Network::start(conn, net_config(), None).unwrap();
    let t0 = Instant::now();
    let mut last = home;
    let mut i = 0;
    while t0.elapsed() < Duration::from_millis(1300) {
        last = home.orbit(i as f32 * 0.01, 0.0);
        net.set_view(View { camera: last, heuristic: Heuristic::Peak, radius_scale: 2.0 });
        i += 1;
        std::thread::sleep(Duration::from_micros(500));
    }
    let got = rx.recv_timeout(Duration::from_secs(10)).unwrap();
    net.shutdown();
    assert!(i > 500, "the view changed {i} times");
    let max = (1000 / THROTTLE.as_millis() + 2) as usize;
    assert!(got.len() >= 5 && got.len() <= max, "{} requests in one second (at most {max})", got.len());
    for w in got.windows(2) {
        assert!(w[1].1.seq > w[0].1.seq, "sequence numbers increase");
    }
    // Arrival gaps, not send gaps: on a loaded machine one request can be delayed and the next
    // arrive right after it, so the throttle shows in the median gap (and in the count above).
    let mut gaps: Vec<f64> = got.windows(2).map(|w| (w[1].0 - w[0].0).as_secs_f64()).collect();
    let median = volwarp_core::stats::median(&mut gaps).unwrap();
    assert!(median >= (THROTTLE - Duration::from_millis(5)).as_secs_f64(), "median gap {median} s < {THROTTLE:?}");
    let r = got.last().unwrap().1;
    assert_eq!((r.heuristic, r.radius_scale), (Heuristic::Peak, 2.0));
    assert!(r.camera != home, "the newest camera is sent, not the first");
    let _ = last;
}

#[test]
fn a_moving_view_asks_for_the_hellos_layers_and_the_view_at_rest_for_one_sample() {
    // The default's rest request: while the view moves the requests carry layers 0 (the
    // Hello's); once it rests, the request a frame's arrival triggers carries 1.
    let (tx, rx) = mpsc::channel();
    let (still_tx, still_rx) = mpsc::channel::<()>();
    let addr = fake_server(move |mut s| {
        greet(&mut s, Hello::new(0).with_layers(4));
        // Every request as it comes, on its own thread (no read timeouts that could split one).
        let mut reader = s.try_clone().unwrap();
        std::thread::spawn(move || {
            while let Some(m) = read_msg(&mut reader) {
                if let Message::CameraRequest(r) = m {
                    if tx.send(r).is_err() {
                        break;
                    }
                }
            }
        });
        // Once the view holds still, a frame arrives: the client asks again, for the view at rest.
        if still_rx.recv_timeout(Duration::from_secs(30)).is_ok() {
            s.write_all(&encode(&empty_frame(0))).unwrap();
        }
        std::thread::sleep(Duration::from_secs(2));
    });
    let conn = connect(&addr, None, Duration::from_secs(10)).unwrap();
    let home = home_camera(&conn.bounds, 32, 32);
    let request = volwarp_core::method::RequestPolicy { rest_layers: 1, ..volwarp_core::method::RequestPolicy::NONE };
    let net = Network::start(conn, volwarp_client::network::NetConfig { request, ..net_config() }, None).unwrap();
    let view = |c| View { camera: c, heuristic: Heuristic::Peak, radius_scale: 1.0 };
    let t0 = Instant::now();
    let mut i = 0;
    while t0.elapsed() < Duration::from_millis(400) {
        net.set_view(view(home.orbit(i as f32 * 0.5, 0.0)));
        i += 1;
        std::thread::sleep(Duration::from_millis(5));
    }
    let rest = home.orbit((i - 1) as f32 * 0.5, 0.0);
    // The display shows the still view for the frames that make it rest (it publishes its view
    // every frame).
    for _ in 0..volwarp_client::network::STILL_AFTER {
        net.set_view(view(rest));
    }
    // Once the writer has sent the last moving camera (throttled; later under load), the view
    // is still: then the frame arrives.
    let mut got = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(30);
    while let Ok(r) = rx.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
        got.push(r);
        if r.camera == rest && got.len() > 1 {
            break;
        }
    }
    still_tx.send(()).unwrap();
    while let Ok(r) = rx.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
        got.push(r);
        if r.layers != 0 {
            break;
        }
    }
    net.shutdown();
    let (moving, resting): (Vec<&CameraRequest>, Vec<&CameraRequest>) = got.iter().partition(|r| r.layers == 0);
    assert!(moving.len() >= 2, "requests while moving: {got:?}");
    assert!(moving.iter().all(|r| r.layers == 0));
    let last = resting.last().unwrap_or_else(|| panic!("no request at rest: {got:?}"));
    assert_eq!((last.layers, last.camera), (1, rest), "the view at rest, one sample per pixel");
}

#[test]
fn a_frame_arriving_between_two_display_frames_of_a_moving_view_asks_for_the_coarse_grid() {
    // Adaptive resolution with a display slower than the writer's throttle (30 frames/s, as the
    // headless demo): a frame arrives after a request and before the next display frame, and the
    // request its arrival triggers is for a view that still moves, so on the coarse grid (a
    // full-resolution one would be dropped by the server at the next display frame). The first
    // view, shown before anything moved it, is at rest.
    let (tx, rx) = mpsc::channel();
    let addr = fake_server(move |mut s| {
        assert!(matches!(read_msg(&mut s), Some(Message::Hello(_))));
        s.write_all(&encode(&Message::Hello(Hello::new(0)))).unwrap();
        // Every request (the connection's probe first) is answered with a frame at once.
        while let Some(m) = read_msg(&mut s) {
            if let Message::CameraRequest(r) = m {
                if tx.send(r).is_err() || s.write_all(&encode(&empty_frame(r.seq))).is_err() {
                    break;
                }
            }
        }
    });
    let conn = connect(&addr, None, Duration::from_secs(10)).unwrap();
    let home = home_camera(&conn.bounds, 512, 512);
    let request = volwarp_core::method::RequestPolicy { coarse: 2, ..volwarp_core::method::RequestPolicy::NONE };
    let net = Network::start(conn, volwarp_client::network::NetConfig { request, ..net_config() }, None).unwrap();
    for i in 0..30 {
        net.set_view(View { camera: home.orbit(i as f32, 0.0), heuristic: Heuristic::Peak, radius_scale: 1.0 });
        std::thread::sleep(Duration::from_millis(33));
    }
    net.shutdown();
    let got: Vec<CameraRequest> = rx.try_iter().filter(|r| r.camera.width > 1).collect();
    let widths: Vec<u32> = got.iter().map(|r| r.camera.width).collect();
    // The first view, before the orbit moves it, is at rest: full resolution.
    assert_eq!(widths.first(), Some(&512), "the first view at rest: {widths:?}");
    let moves = widths.iter().position(|&w| w != 512).unwrap_or(widths.len());
    assert!(widths.len() - moves >= 10, "a request per display frame and per arrival: {widths:?}");
    assert!(
        widths[moves..].iter().all(|&w| w == 256),
        "every request of the moving view on the coarse grid: {widths:?}"
    );
}

#[test]
fn a_fast_turn_asks_for_the_coarser_grid_and_a_slow_one_for_the_moving_grid() {
    // Adaptive resolution (2 times coarser while moving) against a server whose frame for the
    // view at rest took 0.3 s: a view that then turns 300°/s would turn far more than
    // `FAST_WARP_DEG` before a frame on the moving grid could come, so it asks for the grid 4
    // times coarser; turning 15°/s it asks for the moving grid.
    let (tx, rx) = mpsc::channel();
    let addr = fake_server(move |mut s| {
        greet(&mut s, Hello::new(0));
        // The view at rest: its frame comes 0.3 s after the request; then nothing.
        let Some(Message::CameraRequest(rest)) = read_msg(&mut s) else { return };
        tx.send(rest).unwrap();
        std::thread::sleep(Duration::from_millis(300));
        s.write_all(&encode(&empty_frame(rest.seq))).unwrap();
        while let Some(m) = read_msg(&mut s) {
            if let Message::CameraRequest(r) = m {
                if tx.send(r).is_err() {
                    break;
                }
            }
        }
    });
    let conn = connect(&addr, None, Duration::from_secs(10)).unwrap();
    let home = home_camera(&conn.bounds, 512, 512);
    let request = volwarp_core::method::RequestPolicy { coarse: 2, ..volwarp_core::method::RequestPolicy::NONE };
    let net = Network::start(conn, volwarp_client::network::NetConfig { request, ..net_config() }, None).unwrap();
    let view = |c| View { camera: c, heuristic: Heuristic::Peak, radius_scale: 1.0 };
    // At rest until its frame has come, then 10° per 33 ms display frame (300°/s: a loaded
    // machine's slower display still turns fast), then 0.5° per frame.
    for _ in 0..20 {
        net.set_view(view(home));
        std::thread::sleep(Duration::from_millis(33));
    }
    let mut yaw = 0.0;
    for i in 0..50 {
        yaw += if i < 20 { 10.0 } else { 0.5 };
        net.set_view(view(home.orbit(yaw, 0.0)));
        std::thread::sleep(Duration::from_millis(33));
    }
    net.shutdown();
    let widths: Vec<u32> = rx.try_iter().map(|r| r.camera.width).collect();
    assert_eq!(widths.first(), Some(&512), "the view at rest first: {widths:?}");
    let moving = &widths[widths.iter().position(|&w| w != 512).unwrap_or(widths.len())..];
    let fast = moving.iter().take_while(|&&w| w == 128).count();
    assert!(fast >= 5, "the fast turn on the grid 4 times coarser: {widths:?}");
    // The slow turn's: the moving grid (after one or two requests that still saw the fast turn).
    assert!(moving[fast..].iter().all(|&w| w == 256) && moving[fast..].len() >= 10, "the slow turn: {widths:?}");
}

#[test]
fn at_rest_each_side_view_is_asked_for_once_after_the_rest_frame() {
    // A server that answers every request at once with a frame for its camera: the view rests
    // at `home`; once its frame has arrived the client asks for the side views along the orbit
    // (one, then the other, each after the previous one's frame), and then only for the view
    // at rest again, never a side view twice.
    let (tx, rx) = mpsc::channel();
    let addr = fake_server(move |mut s| {
        greet(&mut s, Hello::new(0));
        while let Some(m) = read_msg(&mut s) {
            if let Message::CameraRequest(r) = m {
                let Message::Frame(mut f) = empty_frame(r.seq) else { unreachable!() };
                f.header.camera = r.camera;
                if tx.send(r).is_err() || s.write_all(&encode(&Message::Frame(f))).is_err() {
                    break;
                }
            }
        }
    });
    let conn = connect(&addr, None, Duration::from_secs(10)).unwrap();
    let home = home_camera(&conn.bounds, 64, 64);
    let request = volwarp_core::method::Method::DEFAULT.request();
    let sides = request.side_views(&home).expect("side views on by default");
    let net = Network::start(conn, volwarp_client::network::NetConfig { request, ..net_config() }, None).unwrap();
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_millis(1500) {
        net.set_view(View { camera: home, heuristic: Heuristic::Peak, radius_scale: 1.0 });
        while net.take_scene().is_some() {}
        std::thread::sleep(Duration::from_millis(16));
    }
    net.shutdown();
    let got: Vec<volwarp_core::Camera> = rx.try_iter().map(|r| r.camera).filter(|c| c.width > 1).collect();
    let at = |c: &volwarp_core::Camera| got.iter().position(|g| g == c);
    let (rest, first, second) = (at(&home), at(&sides[0]), at(&sides[1]));
    assert!(rest.is_some() && first.is_some() && second.is_some(), "the rest view and both side views: {got:?}");
    assert!(rest < first && first < second, "the rest view, then one side, then the other: {got:?}");
    for s in &sides {
        assert_eq!(got.iter().filter(|g| *g == s).count(), 1, "each side view once: {got:?}");
    }
    assert!(got.iter().all(|g| *g == home || sides.contains(g)), "nothing else at rest: {got:?}");
}
