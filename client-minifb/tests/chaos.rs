//! Chaos on the link, with the client's network thread as a headless client uses it:
//!
//! * the real `volwarp-server` program killed with SIGKILL while frames stream, and started
//!   again on the same port: the client keeps its frames meanwhile and gets new ones soon
//!   after the new server listens;
//! * a proxy between client and server that forwards a set number of bytes of the server's
//!   stream, then drops both sides (mid-Hello, mid-frame): no torn frame ever reaches the
//!   display, nothing panics, and the client reconnects.
//!
//! The reconnect-time figure of docs/perf.md (p95 over 20 kills):
//! `cargo test --release -p volwarp-client --test chaos -- --ignored --nocapture`.

mod common;

use common::{net_config, next_scene, server_program};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use volwarp_client::connection::connect_layers;
use volwarp_client::controls::home_camera;
use volwarp_client::network::{Backoff, ConnectionState, Network, Redial, View};
use volwarp_core::{Camera, Heuristic};

static PANICS: AtomicUsize = AtomicUsize::new(0);

/// Counts panics on every thread (a network thread's panic would otherwise go unseen).
fn count_panics() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let default = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            PANICS.fetch_add(1, Ordering::SeqCst);
            default(info);
        }));
    });
}

/// A free loopback port (bound, then released).
fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// The real server on `127.0.0.1:port`; returns it and the instant it said it listens.
fn start_server(port: u16) -> (Child, Instant) {
    let t0 = Instant::now();
    loop {
        let mut child = Command::new(server_program())
            .args(["--listen", &format!("127.0.0.1:{port}"), "--threads", "2"])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .stdin(Stdio::null())
            .spawn()
            .expect("starting volwarp-server");
        let mut out = BufReader::new(child.stdout.take().unwrap());
        let mut line = String::new();
        while out.read_line(&mut line).unwrap_or(0) > 0 {
            if line.starts_with("listening on") {
                let at = Instant::now();
                std::thread::spawn(move || std::io::copy(&mut out, &mut std::io::sink()));
                return (child, at);
            }
            line.clear();
        }
        // It could not bind (the port not free yet): try again for a while.
        let _ = child.wait();
        assert!(t0.elapsed() < Duration::from_secs(10), "the server cannot listen on port {port}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn view(home: &Camera, i: u32) -> View {
    View { camera: home.orbit(i as f32 * 3.0, 10.0), heuristic: Heuristic::Threshold, radius_scale: 1.0 }
}

fn redial(addr: &str) -> Redial {
    Redial { addr: addr.into(), token: None, layers: 4, backoff: Backoff::default(), tls: None }
}

/// Kills the server `kills` times mid-stream and restarts it after `down(k)` (the client's
/// backoff grows meanwhile); returns, per kill, the time from the new server's "listening" to
/// the client's first new frame.
fn kill_and_restart(kills: usize, down: impl Fn(usize) -> Duration) -> Vec<Duration> {
    count_panics();
    let port = free_port();
    let (mut child, _) = start_server(port);
    let addr = format!("127.0.0.1:{port}");
    let conn = connect_layers(&addr, None, Duration::from_secs(10), 4).unwrap();
    let home = home_camera(&conn.bounds, 96, 96);
    let net = Network::start_reconnecting(conn, net_config(), None, redial(&addr)).unwrap();
    assert!(next_scene(&net, &home, view, Instant::now(), Duration::from_secs(20)).is_some(), "no first frame");
    let mut back = Vec::new();
    for k in 0..kills {
        // Frames are streaming (each arrival asks for the next view): kill in the middle.
        let _ = next_scene(&net, &home, view, Instant::now(), Duration::from_secs(5));
        std::thread::sleep(Duration::from_millis(7 * (k as u64 % 5)));
        child.kill().unwrap(); // SIGKILL
        let _ = child.wait();
        // The client keeps showing and asking; it is reconnecting, not failed.
        let t = Instant::now();
        while !matches!(net.state(), ConnectionState::Reconnecting { .. }) && t.elapsed() < Duration::from_secs(5) {
            net.set_view(view(&home, k as u32));
            std::thread::sleep(Duration::from_millis(2));
        }
        assert!(matches!(net.state(), ConnectionState::Reconnecting { .. }), "{:?}", net.state());
        while t.elapsed() < down(k) {
            net.set_view(view(&home, k as u32));
            assert!(net.error().is_none(), "{:?}", net.error());
            std::thread::sleep(Duration::from_millis(5));
        }
        let (c, listening) = start_server(port);
        child = c;
        let at = next_scene(&net, &home, view, listening, Duration::from_secs(20)).expect("frames after the restart");
        back.push(at.saturating_duration_since(listening));
        assert_eq!(net.state(), ConnectionState::Connected);
    }
    assert!(net.reconnects() >= kills as u64);
    net.shutdown();
    let _ = child.kill();
    let _ = child.wait();
    assert_eq!(PANICS.load(Ordering::SeqCst), 0, "something panicked");
    back
}

#[test]
fn a_server_killed_mid_stream_and_restarted_is_back_soon() {
    // Restarted at once, and after 700 ms down (a few failed attempts first).
    let back = kill_and_restart(2, |k| Duration::from_millis(700 * k as u64));
    eprintln!("frames again after {back:?}");
    // The 2 s target is the figure's (p95 over 20 kills, the ignored test below); a loaded
    // test machine gets slack: the backoff's 2 s cap plus a slow first frame.
    for b in back {
        assert!(b < Duration::from_secs(4), "back after {b:?}");
    }
}

#[test]
#[ignore = "figure for docs/perf.md: reconnect time over 20 SIGKILLs"]
fn reconnect_time_over_twenty_kills() {
    // Down from 0 to 2.85 s (150 ms more each time): the backoff is at every stage of its
    // growth (100 ms doubling to 2 s) when the server comes back.
    let mut back = kill_and_restart(20, |k| Duration::from_millis(150 * k as u64));
    back.sort();
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    let p = |q: f64| back[((back.len() - 1) as f64 * q).round() as usize];
    println!(
        "reconnect after SIGKILL + restart (down 0 to 2.85 s), 20 kills: median {:.0} ms, p95 {:.0} ms, max {:.0} ms (from 'listening' to the first new frame)",
        ms(p(0.5)),
        ms(p(0.95)),
        ms(back[back.len() - 1])
    );
}

/// A proxy to `server` that, for its `i`-th connection, forwards `cuts[i]` bytes of the
/// server's stream and then drops both sides (connections past the list, and those whose
/// entry is `usize::MAX`, are passed whole).
fn cutting_proxy(server: SocketAddr, cuts: Vec<usize>) -> (SocketAddr, Arc<AtomicUsize>) {
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = l.local_addr().unwrap();
    let cut_done = Arc::new(AtomicUsize::new(0));
    let done = cut_done.clone();
    std::thread::spawn(move || {
        for (i, c) in l.incoming().enumerate() {
            let Ok(client) = c else { continue };
            let Ok(upstream) = TcpStream::connect(server) else { continue };
            let limit = cuts.get(i).copied();
            let (c2, u2) = (client.try_clone().unwrap(), upstream.try_clone().unwrap());
            // Client to server: whole.
            std::thread::spawn(move || {
                let (mut from, mut to) = (c2, u2);
                let _ = std::io::copy(&mut from, &mut to);
                let _ = to.shutdown(Shutdown::Both);
            });
            let done = done.clone();
            std::thread::spawn(move || {
                let (mut from, mut to) = (upstream, client);
                let mut sent = 0usize;
                let mut buf = [0u8; 4096];
                loop {
                    let want = limit.map_or(buf.len(), |l| (l - sent).min(buf.len()));
                    if want == 0 {
                        break;
                    }
                    match from.read(&mut buf[..want]) {
                        Ok(0) | Err(_) => break,
                        Ok(n) => {
                            if to.write_all(&buf[..n]).is_err() {
                                break;
                            }
                            sent += n;
                        }
                    }
                }
                if limit.is_some_and(|l| l != usize::MAX) {
                    done.fetch_add(1, Ordering::SeqCst);
                }
                let _ = to.shutdown(Shutdown::Both);
                let _ = from.shutdown(Shutdown::Both);
            });
        }
    });
    (addr, cut_done)
}

#[test]
fn a_connection_cut_mid_frame_never_yields_a_torn_frame_and_reconnects() {
    count_panics();
    let marcher = Arc::new(volwarp_server::Marcher::from_dataset(&volwarp_server::Dataset::default_bundled()));
    let cfg = volwarp_server::ServerConfig {
        listen: SocketAddr::from(([127, 0, 0, 1], 0)),
        threads: 2,
        ..volwarp_server::ServerConfig::default()
    };
    let server = volwarp_server::Server::with_marcher(cfg, marcher).unwrap().spawn();
    // The first connection is whole (it finds the bounds); then cuts inside the Hello (7 B),
    // right after the greeting, and inside frames of about 20–60 KB (a 160² layered frame).
    let cuts = vec![usize::MAX, 7, 300, 9_001, 25_000, 40_013, 61_000];
    let n_cuts = cuts.len() - 1;
    let (proxy, cut_done) = cutting_proxy(server.local_addr(), cuts);
    let addr = proxy.to_string();
    let conn = connect_layers(&addr, None, Duration::from_secs(10), 4).unwrap();
    let home = home_camera(&conn.bounds, 160, 160);
    drop(conn);
    let conn = connect_layers(&addr, None, Duration::from_secs(10), 4);
    // The second connection is cut in the Hello: connecting fails, cleanly.
    assert!(conn.is_err(), "a Hello cut short is an error");
    // The network starts on an open connection: retry until one opens (the proxy cuts the
    // next ones later, mid-stream).
    let t0 = Instant::now();
    let conn = loop {
        match connect_layers(&addr, None, Duration::from_secs(10), 4) {
            Ok(c) => break c,
            Err(e) => {
                assert!(t0.elapsed() < Duration::from_secs(10), "{e}");
                std::thread::sleep(Duration::from_millis(20));
            }
        }
    };
    let net = Network::start_reconnecting(conn, net_config(), None, redial(&addr)).unwrap();
    let t0 = Instant::now();
    let mut scenes = 0;
    while (cut_done.load(Ordering::SeqCst) < n_cuts || scenes < 5) && t0.elapsed() < Duration::from_secs(60) {
        if next_scene(&net, &home, view, Instant::now(), Duration::from_secs(10)).is_some() {
            scenes += 1;
        }
    }
    assert!(cut_done.load(Ordering::SeqCst) >= n_cuts, "every cut happened");
    assert!(scenes >= 5, "whole frames after the cuts");
    assert!(net.reconnects() >= 2, "reconnected after the cuts: {}", net.reconnects());
    assert_eq!(net.state(), ConnectionState::Connected);
    eprintln!(
        "{scenes} whole scenes, {} frames, {} reconnects through {n_cuts} cuts",
        net.frames_received(),
        net.reconnects()
    );
    net.shutdown();
    server.shutdown();
    assert_eq!(PANICS.load(Ordering::SeqCst), 0, "something panicked");
}
