//! The network thread outlives its server: a real `volwarp_server::Server` is shut down and a
//! new one started on the same port, and the client gets whole frames again without being
//! told; a wrong token is a permanent failure, not an endless retry.

mod common;

use common::{net_config, next_scene};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};
use volwarp_client::connection::connect_layers;
use volwarp_client::controls::home_camera;
use volwarp_client::network::{Backoff, ConnectionState, Network, Redial, View};
use volwarp_client::ClientError;
use volwarp_core::wire::error_code;
use volwarp_core::{Camera, Heuristic};
use volwarp_server::{Dataset, Marcher, Server, ServerConfig, ServerHandle};

const TOKEN: &str = "correct horse battery staple";

fn marcher() -> Arc<Marcher> {
    Arc::new(Marcher::from_dataset(&Dataset::default_bundled()))
}

fn config(port: u16) -> ServerConfig {
    ServerConfig {
        listen: SocketAddr::from(([127, 0, 0, 1], port)),
        threads: 2,
        token: Some(TOKEN.into()),
        ..ServerConfig::default()
    }
}

/// Binds `127.0.0.1:port`, trying again for a while if the port is not free yet.
fn bind_on(port: u16, m: &Arc<Marcher>) -> ServerHandle {
    let t0 = Instant::now();
    loop {
        match Server::with_marcher(config(port), m.clone()) {
            Ok(s) => return s.spawn(),
            Err(e) if t0.elapsed() < Duration::from_secs(5) => {
                eprintln!("bind 127.0.0.1:{port}: {e}; again");
                std::thread::sleep(Duration::from_millis(20));
            }
            Err(e) => panic!("cannot bind 127.0.0.1:{port} again: {e}"),
        }
    }
}

fn view(home: &Camera, i: u32) -> View {
    View { camera: home.orbit(i as f32 * 2.0, 0.0), heuristic: Heuristic::Threshold, radius_scale: 1.0 }
}

#[test]
fn the_client_gets_frames_again_from_a_restarted_server() {
    let m = marcher();
    let mut server = bind_on(0, &m);
    let addr = server.local_addr();
    let conn = connect_layers(&addr.to_string(), Some(TOKEN), Duration::from_secs(10), 1).unwrap();
    let home = home_camera(&conn.bounds, 64, 48);
    let redial =
        Redial { addr: addr.to_string(), token: Some(TOKEN.into()), layers: 1, backoff: Backoff::default(), tls: None };
    let net = Network::start_reconnecting(conn, net_config(), None, redial).unwrap();
    assert!(next_scene(&net, &home, view, Instant::now(), Duration::from_secs(10)).is_some(), "no first frame");
    assert_eq!(net.state(), ConnectionState::Connected);

    for round in 1..=2u64 {
        server.shutdown();
        let down = Instant::now();
        // No server: the network says it is reconnecting, and nothing fails or panics.
        let t = Instant::now();
        let mut saw = None;
        while t.elapsed() < Duration::from_millis(400) {
            net.set_view(view(&home, 0));
            if let ConnectionState::Reconnecting { attempt, reason, .. } = net.state() {
                saw = Some((attempt, reason));
            }
            assert!(net.error().is_none(), "{:?}", net.error());
            std::thread::sleep(Duration::from_millis(5));
        }
        let (attempt, reason) = saw.expect("the state shows the reconnecting");
        assert!(attempt >= 1 && !reason.is_empty());
        // A new server on the same port.
        server = bind_on(addr.port(), &m);
        let started = Instant::now();
        let back = next_scene(&net, &home, view, started, Duration::from_secs(10)).expect("frames again");
        let took = back.saturating_duration_since(started);
        eprintln!(
            "round {round}: server down {:?}; frames again {took:?} after the new server started",
            started - down
        );
        assert!(took < Duration::from_secs(2), "frames again after {took:?}");
        assert_eq!(net.state(), ConnectionState::Connected);
        assert_eq!(net.reconnects(), round);
    }
    net.shutdown();
    server.shutdown();
}

#[test]
fn a_wrong_token_after_a_restart_is_a_permanent_failure() {
    let m = marcher();
    let server = bind_on(0, &m);
    let addr = server.local_addr();
    let conn = connect_layers(&addr.to_string(), Some(TOKEN), Duration::from_secs(10), 1).unwrap();
    let home = home_camera(&conn.bounds, 64, 48);
    // The redial carries another token (as if the server had a new one): refused for good.
    let redial = Redial {
        addr: addr.to_string(),
        token: Some("guess".into()),
        layers: 1,
        backoff: Backoff::default(),
        tls: None,
    };
    let net = Network::start_reconnecting(conn, net_config(), None, redial).unwrap();
    assert!(next_scene(&net, &home, view, Instant::now(), Duration::from_secs(10)).is_some(), "no first frame");
    server.shutdown();
    let server = bind_on(addr.port(), &m);
    let t0 = Instant::now();
    while net.error().is_none() && t0.elapsed() < Duration::from_secs(10) {
        net.set_view(view(&home, 1));
        std::thread::sleep(Duration::from_millis(5));
    }
    let e = net.error().expect("a permanent failure, not an endless retry");
    assert!(matches!(e, ClientError::Server { code: error_code::UNAUTHORIZED, .. }), "{e}");
    assert!(matches!(net.state(), ConnectionState::Failed(_)));
    let label = net.state().label().unwrap();
    assert!(label.contains("wrong token"), "{label}");
    // It stays failed: no more attempts reach the server.
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(server.active_clients(), 0);
    net.shutdown();
    server.shutdown();
}

#[test]
fn without_redial_a_drop_stops_the_network() {
    let m = marcher();
    let server = bind_on(0, &m);
    let addr = server.local_addr();
    let conn = connect_layers(&addr.to_string(), Some(TOKEN), Duration::from_secs(10), 1).unwrap();
    let home = home_camera(&conn.bounds, 64, 48);
    let net = Network::start(conn, net_config(), None).unwrap();
    assert!(next_scene(&net, &home, view, Instant::now(), Duration::from_secs(10)).is_some(), "no first frame");
    server.shutdown();
    let t0 = Instant::now();
    while net.error().is_none() && t0.elapsed() < Duration::from_secs(10) {
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(matches!(net.error(), Some(ClientError::Gone(_))), "{:?}", net.error());
    assert!(matches!(net.state(), ConnectionState::Failed(_)));
    assert_eq!(net.reconnects(), 0);
    net.shutdown();
}
