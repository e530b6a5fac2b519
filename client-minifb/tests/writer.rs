//! The client's writer sends only the newest camera, throttled (against a scripted server).

mod common;

use common::*;
use std::io::Write;
use std::sync::mpsc;
use std::time::{Duration, Instant};
use volwarp_client::connection::connect;
use volwarp_client::controls::home_camera;
use volwarp_client::network::{Network, View, THROTTLE};
use volwarp_core::wire::{Hello, Message};
use volwarp_core::Heuristic;

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
