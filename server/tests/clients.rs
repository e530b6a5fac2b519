//! Several clients on one server: the shared render queue is fair (no client starves another)
//! and identical requests are rendered once.

mod common;

use common::Client;
use std::net::SocketAddr;
use std::sync::Arc;
use volwarp_core::wire::{CameraRequest, Message};
use volwarp_core::Heuristic;
use volwarp_server::{Dataset, Marcher, Server, ServerConfig, ServerHandle};

fn start() -> (ServerHandle, Arc<Marcher>) {
    let cfg = ServerConfig { listen: SocketAddr::from(([127, 0, 0, 1], 0)), threads: 2, ..ServerConfig::default() };
    let marcher = Arc::new(Marcher::from_dataset(&Dataset::default_bundled()));
    let server = Server::with_marcher(cfg, marcher.clone()).unwrap();
    (server.spawn(), marcher)
}

fn frame(c: &mut Client) -> volwarp_core::wire::Frame {
    match c.recv() {
        Ok(Message::Frame(f)) => f,
        other => panic!("expected a Frame, got {other:?}"),
    }
}

#[test]
fn two_busy_clients_each_receive_frames() {
    let (server, m) = start();
    let total = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let clients: Vec<_> = (0..2)
        .map(|id| {
            let (addr, m, total) = (server.local_addr(), m.clone(), total.clone());
            std::thread::spawn(move || {
                let mut c = Client::hello(addr, None);
                let mut got = 0usize;
                // Each client always has a request pending until 24 frames went out in all.
                for seq in 0.. {
                    let yaw = id as f32 * 90.0 + seq as f32 * 3.0;
                    let camera = m.default_camera(160, 120).orbit(yaw, 10.0);
                    c.send(&Message::CameraRequest(CameraRequest {
                        seq,
                        camera,
                        heuristic: Heuristic::Threshold,
                        radius_scale: 1.0,
                        layers: 0,
                    }));
                    let f = frame(&mut c);
                    assert_eq!(f.header.seq, seq);
                    got += 1;
                    if total.fetch_add(1, std::sync::atomic::Ordering::SeqCst) + 1 >= 24 {
                        break;
                    }
                }
                c.send(&Message::Bye);
                got
            })
        })
        .collect();
    let got: Vec<usize> = clients.into_iter().map(|h| h.join().unwrap()).collect();
    // First come, first served: while both wait, they alternate; neither starves.
    assert!(got.iter().all(|&g| g >= 6), "frames per client {got:?}");
    assert_eq!(server.render_counts().shared, 0, "distinct cameras are never shared");
    server.shutdown();
}

#[test]
fn two_clients_asking_for_the_same_camera_get_one_render() {
    let (server, m) = start();
    let camera = m.default_camera(96, 80).orbit(30.0, 15.0);
    let req = |seq| CameraRequest { seq, camera, heuristic: Heuristic::Midpoint, radius_scale: 1.0, layers: 0 };
    let (mut a, mut b) = (Client::hello(server.local_addr(), None), Client::hello(server.local_addr(), None));
    a.send(&Message::CameraRequest(req(5)));
    b.send(&Message::CameraRequest(req(9)));
    let (fa, fb) = (frame(&mut a), frame(&mut b));
    assert_eq!((fa.header.seq, fb.header.seq), (5, 9), "each client gets its own sequence number");
    assert!(!fa.samples.is_empty());
    assert_eq!(fa.samples, fb.samples);
    assert_eq!(fa.colors, fb.colors);
    assert_eq!(fa.samples, m.render_frame(&req(0)).0.samples);
    let counts = server.render_counts();
    assert_eq!((counts.rendered, counts.shared), (1, 1), "{counts:?}");
    // Another camera is rendered again.
    b.send(&Message::CameraRequest(CameraRequest { seq: 10, heuristic: Heuristic::Exit, ..req(10) }));
    assert_eq!(frame(&mut b).header.heuristic, Heuristic::Exit);
    assert_eq!(server.render_counts().rendered, 2);
    server.shutdown();
}
