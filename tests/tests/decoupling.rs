//! The real server and the client library together: the network side never holds the display
//! up; a slow server and added latency delay what is shown, not how often it is shown.

use std::time::{Duration, Instant};
use volwarp_client::connection::connect;
use volwarp_client::controls::home_camera;
use volwarp_client::display::Display;
use volwarp_client::network::{NetConfig, Network, View};
use volwarp_client::renderers::Renderers;
use volwarp_core::Heuristic;

#[test]
fn display_keeps_running_while_a_slow_server_and_latency_delay_frames() {
    let delay = Duration::from_millis(300);
    let latency = Duration::from_millis(200);
    let config = volwarp_server::ServerConfig {
        listen: std::net::SocketAddr::from(([127, 0, 0, 1], 0)),
        threads: 1,
        max_clients: 2,
        frame_delay: Some(delay),
        ..volwarp_server::ServerConfig::default()
    };
    let server = volwarp_server::Server::bind(config, volwarp_server::Dataset::default_bundled()).unwrap().spawn();
    let conn = connect(&server.local_addr().to_string(), None, Duration::from_secs(20)).unwrap();
    let home = home_camera(&conn.bounds, 96, 72);
    let cfg = NetConfig {
        latency,
        build_threads: 1,
        timeout: Duration::from_secs(20),
        lazy_build: false,
        bandwidth_mbps: None,
        request: volwarp_core::method::RequestPolicy::NONE,
    };
    let net = Network::start(conn, cfg, None).unwrap();
    let mut d = Display::new(net, Renderers::new(volwarp_core::RendererKind::SpheresCpu, 1).unwrap(), None);
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
