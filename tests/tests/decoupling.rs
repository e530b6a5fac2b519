//! The network side never holds the display up: a slow server and added latency delay what is
//! shown, not how often it is shown; the writer sends only the newest camera, throttled.

mod common;

use common::*;
use std::io::Write;
use std::sync::mpsc;
use std::time::{Duration, Instant};
use volwarp_client::connection::connect;
use volwarp_client::controls::home_camera;
use volwarp_client::display::Display;
use volwarp_client::local_server::LocalServer;
use volwarp_client::network::{NetConfig, Network, View, THROTTLE};
use volwarp_client::renderers::Renderers;
use volwarp_core::wire::{Hello, Message};
use volwarp_core::Heuristic;

#[test]
fn display_keeps_running_while_a_slow_server_and_latency_delay_frames() {
    let delay = Duration::from_millis(300);
    let latency = Duration::from_millis(200);
    let server = LocalServer::start(Some(delay), 1).unwrap();
    let conn = connect(&server.addr().to_string(), None, Duration::from_secs(20)).unwrap();
    let home = home_camera(&conn.bounds, 96, 72);
    let cfg = NetConfig { latency, build_threads: 1, timeout: Duration::from_secs(20) };
    let net = Network::start(conn, cfg, None).unwrap();
    let mut d = Display::new(net, Renderers::new("spheres-cpu", 1).unwrap(), None);
    let view = |yaw: f32| View { camera: home.orbit(yaw, 0.0), heuristic: Heuristic::Threshold, radius_scale: 1.0 };

    let t0 = Instant::now();
    d.wait_first_scene(&view(0.0), Duration::from_secs(60)).unwrap();
    assert!(t0.elapsed() >= delay + latency, "the first frame cannot be shown before delay + latency");

    let mut display_frames = 0u64;
    let mut new_frames = 0u64;
    let run = Instant::now();
    while run.elapsed() < Duration::from_millis(1500) {
        let r = d.frame(&view(display_frames as f32 * 0.5));
        display_frames += 1;
        new_frames += u64::from(r.new_frame);
        let age = r.age_ms.expect("the shown frame's request time is known");
        assert!(age >= (delay + latency).as_secs_f64() * 1e3, "frame age {age} ms below delay + latency");
        assert_eq!(d.image.width * d.image.height, 96 * 72);
        d.check().unwrap();
    }
    let server_frames = d.network().frames_received();
    assert!(server_frames <= 1 + 1800 / 300, "the server is slowed to 1 frame per 300 ms: {server_frames}");
    assert!(new_frames >= 1, "new frames are swapped in while the display runs");
    assert!(
        display_frames > 5 * server_frames.max(1),
        "display frames ({display_frames}) do not wait for server frames ({server_frames})"
    );
    d.shutdown();
    server.shutdown();
}

#[test]
fn writer_sends_only_the_newest_camera_throttled() {
    let (tx, rx) = mpsc::channel();
    let addr = fake_server(move |mut s| {
        assert!(matches!(read_msg(&mut s), Some(Message::Hello(_))));
        s.write_all(&encode(&Message::Hello(Hello::new(0)))).unwrap();
        assert!(matches!(read_msg(&mut s), Some(Message::CameraRequest(_))));
        s.write_all(&encode(&empty_frame(0))).unwrap();
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
    let net = Network::start(
        conn,
        NetConfig { latency: Duration::ZERO, build_threads: 1, timeout: Duration::from_secs(10) },
        None,
    )
    .unwrap();
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
        assert!(w[1].0 - w[0].0 >= THROTTLE - Duration::from_millis(5), "requests at least {THROTTLE:?} apart");
    }
    let r = got.last().unwrap().1;
    assert_eq!((r.heuristic, r.radius_scale), (Heuristic::Peak, 2.0));
    assert!(r.camera != home, "the newest camera is sent, not the first");
    let _ = last;
}
