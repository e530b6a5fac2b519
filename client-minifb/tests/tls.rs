//! TLS between a real `volwarp_server::Server` (`ServerConfig::tls`) and the client library:
//! frames arrive and decode as over plain TCP, the network reconnects over TLS, a certificate
//! that is unknown or for another name is refused with a clear, permanent error, and a plain
//! client on a TLS server (or a TLS client on a plain one) is told so while the server keeps
//! serving the others.

mod common;

use common::{net_config, scratch};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};
use volwarp_client::connection::{connect_layers, connect_secure, read_message_bytes, send_request, Connection};
use volwarp_client::controls::home_camera;
use volwarp_client::network::{is_permanent, Backoff, ConnectionState, Network, Redial, View};
use volwarp_client::ClientError;
use volwarp_core::wire::{error_code, CameraRequest, Message};
use volwarp_core::Heuristic;
use volwarp_server::{Dataset, Marcher, Server, ServerConfig, ServerHandle, TlsIdentity};
use volwarp_tls::rustls::ClientConfig;

const TIMEOUT: Duration = Duration::from_secs(10);

/// A self-signed certificate for `names` and its key, as PEM files in `dir`.
fn certificate(dir: &std::path::Path, tag: &str, names: &[&str]) -> (PathBuf, PathBuf) {
    let key = rcgen::KeyPair::generate().unwrap();
    let params = rcgen::CertificateParams::new(names.iter().map(|s| s.to_string()).collect::<Vec<_>>()).unwrap();
    let cert = params.self_signed(&key).unwrap();
    let (c, k) = (dir.join(format!("{tag}.pem")), dir.join(format!("{tag}.key")));
    std::fs::write(&c, cert.pem()).unwrap();
    std::fs::write(&k, key.serialize_pem()).unwrap();
    (c, k)
}

struct Setup {
    _dir: PathBuf,
    marcher: Arc<Marcher>,
    identity: TlsIdentity,
    /// Trusts the server's certificate (pinned through `--ca`).
    trusted: Arc<ClientConfig>,
    /// The PEM file of another self-signed certificate for the same names.
    other_cert: PathBuf,
}

fn setup(tag: &str) -> Setup {
    let dir = scratch(&format!("tls-{tag}"));
    let (cert, key) = certificate(&dir, "server", &["localhost", "127.0.0.1"]);
    let (other_cert, _) = certificate(&dir, "other", &["localhost", "127.0.0.1"]);
    Setup {
        marcher: Arc::new(Marcher::from_dataset(&Dataset::default_bundled())),
        identity: TlsIdentity::from_pem_files(&cert, &key).unwrap(),
        trusted: volwarp_tls::client_config(Some(&cert)).unwrap(),
        other_cert,
        _dir: dir,
    }
}

fn serve(s: &Setup, port: u16, tls: bool, max_clients: usize) -> ServerHandle {
    let cfg = ServerConfig {
        listen: SocketAddr::from(([127, 0, 0, 1], port)),
        threads: 2,
        max_clients,
        tls: tls.then(|| s.identity.clone()),
        ..ServerConfig::default()
    };
    let t0 = Instant::now();
    loop {
        match Server::with_marcher(cfg.clone(), s.marcher.clone()) {
            Ok(server) => return server.spawn(),
            Err(e) if t0.elapsed() < Duration::from_secs(5) => {
                eprintln!("bind 127.0.0.1:{port}: {e}; again");
                std::thread::sleep(Duration::from_millis(20));
            }
            Err(e) => panic!("cannot bind 127.0.0.1:{port}: {e}"),
        }
    }
}

fn request(seq: u64, camera: volwarp_core::Camera) -> CameraRequest {
    CameraRequest { seq, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 }
}

/// One frame for `req` on an open connection (through its TLS halves where it has them).
fn frame_of(conn: &mut Connection, req: &CameraRequest) -> volwarp_core::wire::Frame {
    let msg = match &mut conn.tls {
        Some(t) => {
            let mut w = t.link.writer(conn.stream.try_clone().unwrap());
            send_request(&mut w, req).unwrap();
            read_message_bytes(&mut t.reader, &conn.limits, "test").unwrap().1
        }
        None => {
            send_request(&mut conn.stream, req).unwrap();
            read_message_bytes(&mut conn.stream, &conn.limits, "test").unwrap().1
        }
    };
    match msg {
        Message::Frame(f) => f,
        other => panic!("expected a frame, got {other:?}"),
    }
}

/// Shows views until a whole scene answering a request sent after `after` arrives.
fn next_scene(net: &Network, home: &volwarp_core::Camera, after: Instant, limit: Duration) -> bool {
    let t0 = Instant::now();
    let mut i = 0u32;
    while t0.elapsed() < limit {
        net.set_view(View {
            camera: home.orbit(i as f32 * 2.0, 0.0),
            heuristic: Heuristic::Threshold,
            radius_scale: 1.0,
        });
        i += 1;
        if let Some(s) = net.take_scene() {
            let h = &s.scene.header;
            assert_eq!((h.camera.width, h.camera.height), (64, 48));
            assert_eq!(s.scene.samples.len(), h.count as usize, "every sample of the frame");
            assert!(!s.scene.samples.is_empty());
            if s.received_at > after {
                return true;
            }
            net.recycle(s.scene);
        }
        assert!(net.error().is_none(), "the network failed: {:?}", net.error());
        std::thread::sleep(Duration::from_millis(5));
    }
    false
}

#[test]
fn frames_over_tls_equal_the_plain_ones_and_reconnect_works() {
    let s = setup("roundtrip");
    let mut tls_server = serve(&s, 0, true, 8);
    let plain_server = serve(&s, 0, false, 8);
    let addr = tls_server.local_addr().to_string();
    let mut tls = connect_secure(&addr, None, TIMEOUT, 4, Some(&s.trusted)).unwrap();
    assert!(tls.tls.is_some(), "the connection is TLS");
    let mut plain = connect_layers(&plain_server.local_addr().to_string(), None, TIMEOUT, 4).unwrap();
    assert!(plain.tls.is_none());
    assert_eq!(tls.bounds, plain.bounds);
    // Layered compact frames: the same bytes decode to the same frame on both links.
    for (seq, yaw) in [(1u64, 10.0f32), (2, 75.0), (3, 200.0)] {
        let camera = home_camera(&tls.bounds, 160, 120).orbit(yaw, 15.0);
        let (a, b) = (frame_of(&mut tls, &request(seq, camera)), frame_of(&mut plain, &request(seq, camera)));
        assert_eq!(a.header.seq, seq);
        assert!(!a.samples.is_empty(), "the volume is in view");
        assert_eq!(a.samples, b.samples, "yaw {yaw}");
        assert_eq!(a.colors, b.colors);
        assert_eq!(a.segments, b.segments);
    }
    tls.bye();
    plain.bye();
    plain_server.shutdown();

    // The network thread over TLS, through a server restart on the same port.
    let conn = connect_secure(&addr, None, TIMEOUT, 1, Some(&s.trusted)).unwrap();
    let home = home_camera(&conn.bounds, 64, 48);
    let redial = Redial {
        addr: addr.clone(),
        token: None,
        layers: 1,
        backoff: Backoff::default(),
        tls: Some(s.trusted.clone()),
    };
    let net = Network::start_reconnecting(conn, net_config(), None, redial).unwrap();
    assert!(next_scene(&net, &home, Instant::now(), TIMEOUT), "no first frame over TLS");
    let port = tls_server.local_addr().port();
    tls_server.shutdown();
    std::thread::sleep(Duration::from_millis(300));
    assert!(matches!(net.state(), ConnectionState::Reconnecting { .. }), "{:?}", net.state());
    tls_server = serve(&s, port, true, 8);
    let started = Instant::now();
    assert!(next_scene(&net, &home, started, TIMEOUT), "no frame over TLS after the restart");
    eprintln!("frames again over TLS {:?} after the new server started", started.elapsed());
    assert_eq!(net.state(), ConnectionState::Connected);
    assert_eq!(net.reconnects(), 1);
    net.shutdown();
    tls_server.shutdown();
}

#[test]
fn unknown_or_misnamed_certificates_are_refused_for_good() {
    let s = setup("refused");
    let server = serve(&s, 0, true, 8);
    let port = server.local_addr().port();
    let cases = [
        (
            "the Mozilla roots do not know a self-signed certificate",
            volwarp_tls::client_config(None).unwrap(),
            "localhost",
        ),
        ("another certificate pinned", volwarp_tls::client_config(Some(&s.other_cert)).unwrap(), "127.0.0.1"),
    ];
    for (what, cfg, host) in cases {
        let e = connect_secure(&format!("{host}:{port}"), None, TIMEOUT, 1, Some(&cfg)).unwrap_err();
        let text = e.to_string();
        assert!(matches!(e, ClientError::Tls(_)), "{what}: {e:?}");
        assert!(text.contains("certificate") && text.contains("--ca"), "{what}: {text}");
        assert!(is_permanent(&e), "{what}: a refused certificate is not retried");
        eprintln!("{what}: {text}");
    }
    // A certificate for localhost only, reached by its IP address: the name is wrong.
    let dir = scratch("tls-name");
    let (cert, key) = certificate(&dir, "named", &["localhost"]);
    let named = Setup { identity: TlsIdentity::from_pem_files(&cert, &key).unwrap(), ..setup("named") };
    let named_server = serve(&named, 0, true, 8);
    let trusting = volwarp_tls::client_config(Some(&cert)).unwrap();
    let e = connect_secure(&named_server.local_addr().to_string(), None, TIMEOUT, 1, Some(&trusting)).unwrap_err();
    assert!(matches!(e, ClientError::Tls(_)) && e.to_string().contains("NotValidForName"), "{e}");
    // The same certificate, reached by its name, is fine.
    let ok =
        connect_secure(&format!("localhost:{}", named_server.local_addr().port()), None, TIMEOUT, 1, Some(&trusting));
    assert!(ok.is_ok(), "{:?}", ok.err());
    // The server carried on through the refused handshakes.
    assert!(connect_secure(&format!("127.0.0.1:{port}"), None, TIMEOUT, 1, Some(&s.trusted)).is_ok());
    named_server.shutdown();
    server.shutdown();
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn mixed_plain_and_tls_peers_are_told_and_the_server_keeps_serving() {
    let s = setup("mixed");
    let server = serve(&s, 0, true, 2);
    let addr = server.local_addr().to_string();
    // A TLS client receiving frames the whole time.
    let conn = connect_secure(&addr, None, TIMEOUT, 1, Some(&s.trusted)).unwrap();
    let home = home_camera(&conn.bounds, 64, 48);
    let net = Network::start(conn, net_config(), None).unwrap();
    assert!(next_scene(&net, &home, Instant::now(), TIMEOUT));

    // A plain client: the server says, in plain, to use TLS; not worth retrying.
    let e = connect_layers(&addr, None, TIMEOUT, 1).unwrap_err();
    match &e {
        ClientError::Server { code: error_code::BAD_REQUEST, text } => assert!(text.contains("--tls"), "{text}"),
        other => panic!("expected the server's BAD_REQUEST, got {other:?}"),
    }
    assert!(is_permanent(&e));
    // Garbage that is neither TLS nor volwarp: closed, nothing else.
    {
        use std::io::Write;
        let mut g = std::net::TcpStream::connect(&addr).unwrap();
        let _ = g.write_all(b"GET / HTTP/1.0\r\n\r\n");
    }
    // A TLS client on a plain server.
    let plain_server = serve(&s, 0, false, 8);
    let e = connect_secure(&plain_server.local_addr().to_string(), None, TIMEOUT, 1, Some(&s.trusted)).unwrap_err();
    match &e {
        ClientError::Server { code: error_code::BAD_REQUEST, text } => {
            assert!(text.contains("does not speak TLS") && text.contains("without --tls"), "{text}")
        }
        other => panic!("expected the plain server's BAD_REQUEST, got {other:?}"),
    }
    assert!(is_permanent(&e));
    plain_server.shutdown();
    // A full TLS server (2 slots: the network's and this one) refuses in plain before any
    // handshake; the TLS client reads it as the server's BUSY, which is worth retrying.
    // The refused and garbage connections above free their slots when their handler threads
    // end, which may be a moment after the clients see the refusal: wait for a free slot.
    let until = Instant::now() + TIMEOUT;
    let second = loop {
        match connect_secure(&addr, None, TIMEOUT, 1, Some(&s.trusted)) {
            Err(ClientError::Server { code: error_code::BUSY, .. }) if Instant::now() < until => {
                std::thread::sleep(Duration::from_millis(20))
            }
            other => break other.unwrap(),
        }
    };
    let e = connect_secure(&addr, None, TIMEOUT, 1, Some(&s.trusted)).unwrap_err();
    assert!(matches!(e, ClientError::Server { code: error_code::BUSY, .. }), "{e:?}");
    assert!(!is_permanent(&e));
    drop(second);
    // The first client kept getting frames.
    assert!(next_scene(&net, &home, Instant::now(), TIMEOUT), "the TLS client still gets frames");
    net.shutdown();
    server.shutdown();
}

/// The real programs: `volwarp-server --tls-cert --tls-key` and `volwarp-client --connect
/// --tls --ca` (headless), and the client's error for a certificate it does not trust.
#[test]
fn the_programs_speak_tls_end_to_end() {
    use std::io::BufRead;
    let dir = scratch("tls-programs");
    let (cert, key) = certificate(&dir, "server", &["localhost", "127.0.0.1"]);
    let (other, _) = certificate(&dir, "other", &["localhost"]);
    let mut server = std::process::Command::new(common::server_program())
        .args(["--listen", "127.0.0.1:0", "--threads", "2", "--tls-cert"])
        .arg(&cert)
        .arg("--tls-key")
        .arg(&key)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut out = std::io::BufReader::new(server.stdout.take().unwrap());
    let mut line = String::new();
    out.read_line(&mut line).unwrap();
    let addr = line.trim().strip_prefix("listening on ").expect("the server listens").to_string();
    let frames = dir.join("frames");
    let (cert_s, other_s, frames_s) = (cert.to_str().unwrap(), other.to_str().unwrap(), frames.to_str().unwrap());
    let ok = common::run(
        &[
            "--connect",
            &addr,
            "--tls",
            "--ca",
            cert_s,
            "--headless",
            "--out",
            frames_s,
            "--frames",
            "4",
            "--size",
            "96x96",
        ],
        Duration::from_secs(120),
    );
    assert!(ok.status.success(), "{}", String::from_utf8_lossy(&ok.stderr));
    assert_eq!(common::pngs(&frames).len(), 4, "four frames over TLS");
    let refused = common::run(
        &["--connect", &addr, "--tls", "--ca", other_s, "--headless", "--out", frames_s, "--frames", "4"],
        Duration::from_secs(60),
    );
    assert_eq!(refused.status.code(), Some(1));
    let err = common::error_line(&refused);
    assert!(err.contains("TLS") && err.contains("certificate") && err.contains("--ca"), "{err}");
    let usage = common::run(&["--tls", "--headless", "--out", frames_s], Duration::from_secs(60));
    assert_eq!(usage.status.code(), Some(2), "--tls needs --connect");
    let _ = server.kill();
    let _ = server.wait();
    let _ = std::fs::remove_dir_all(dir);
}
