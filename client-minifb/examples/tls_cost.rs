//! What TLS costs: frames per second and CPU time per frame over plain TCP and over TLS, side
//! by side, on loopback.
//!
//! ```text
//! cargo run --release -p volwarp-client --example tls_cost [SIZE] [SECONDS_PER_ROUND] [ROUNDS]
//! ```
//!
//! Two in-process servers on the bundled volume (2 marcher threads each, one busy at a time),
//! one plain and one with a fresh self-signed certificate (rcgen); a client on each asks for
//! layered compact frames (4 segments per pixel, as the real client) of an orbiting camera at
//! SIZE² (default 1024), the next as soon as one arrived. The rounds alternate plain and TLS
//! (default 6 rounds of 6 s each) and the medians are printed: frames per second, the whole
//! process's CPU per frame (server march, encode and send, client receive and decode, TLS on
//! both ends), and the client thread's own CPU per frame (receive, decrypt, decode).

use std::sync::Arc;
use std::time::{Duration, Instant};
use volwarp_client::connection::{connect_secure, read_message_bytes, send_request, Connection};
use volwarp_client::controls::home_camera;
use volwarp_core::wire::{CameraRequest, Message};
use volwarp_core::Heuristic;
use volwarp_server::{Dataset, Marcher, Server, ServerConfig, TlsIdentity};

/// CPU time of this process (all threads) and of the calling thread, from /proc.
fn cpu() -> (Duration, Duration) {
    let ticks = |path: &str| -> Duration {
        // Fields 14 and 15 of stat (after the parenthesized name): user and system ticks.
        let s = std::fs::read_to_string(path).unwrap_or_default();
        let rest = s.rsplit_once(')').map_or("", |(_, r)| r);
        // After the name: the state (a letter, skipped), then ppid, pgrp, session, tty, tpgid
        // (may be -1), flags, four fault counts, utime, stime: the 11th and 12th numbers.
        let f: Vec<i64> = rest.split_whitespace().filter_map(|x| x.parse().ok()).collect();
        let t = (f.get(10).copied().unwrap_or(0) + f.get(11).copied().unwrap_or(0)).max(0);
        Duration::from_secs_f64(t as f64 / 100.0)
    };
    let thread_ns = std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next().and_then(|x| x.parse::<u64>().ok()))
        .unwrap_or(0);
    (ticks("/proc/self/stat"), Duration::from_nanos(thread_ns))
}

struct Round {
    fps: f64,
    process_ms: f64,
    client_ms: f64,
}

fn round(conn: &mut Connection, size: u32, secs: f64, seq: &mut u64) -> Round {
    let home = home_camera(&conn.bounds, size, size);
    let (p0, t0c) = cpu();
    let t0 = Instant::now();
    let mut frames = 0u32;
    while t0.elapsed().as_secs_f64() < secs {
        *seq += 1;
        let req = CameraRequest {
            seq: *seq,
            camera: home.orbit(*seq as f32 * 2.0, 10.0),
            heuristic: Heuristic::Threshold,
            radius_scale: 1.0,
            layers: 0,
        };
        let msg = match &mut conn.tls {
            Some(t) => {
                let mut w = t.link.writer(conn.stream.try_clone().expect("socket"));
                send_request(&mut w, &req).expect("request");
                read_message_bytes(&mut t.reader, &conn.limits, "frame").expect("frame").1
            }
            None => {
                send_request(&mut conn.stream, &req).expect("request");
                read_message_bytes(&mut conn.stream, &conn.limits, "frame").expect("frame").1
            }
        };
        assert!(matches!(msg, Message::Frame(ref f) if f.header.seq == *seq && !f.samples.is_empty()));
        frames += 1;
    }
    let dt = t0.elapsed().as_secs_f64();
    let (p1, t1c) = cpu();
    let per = |d: Duration| d.as_secs_f64() * 1e3 / frames as f64;
    Round { fps: frames as f64 / dt, process_ms: per(p1 - p0), client_ms: per(t1c - t0c) }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let size: u32 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(1024);
    let secs: f64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(6.0);
    let rounds: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(6);

    let dir = std::env::temp_dir().join(format!("volwarp-tls-cost-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let key = rcgen::KeyPair::generate().expect("key");
    let cert = rcgen::CertificateParams::new(vec!["localhost".to_string(), "127.0.0.1".to_string()])
        .expect("params")
        .self_signed(&key)
        .expect("certificate");
    let (cert_path, key_path) = (dir.join("cert.pem"), dir.join("key.pem"));
    std::fs::write(&cert_path, cert.pem()).expect("write");
    std::fs::write(&key_path, key.serialize_pem()).expect("write");
    let identity = TlsIdentity::from_pem_files(&cert_path, &key_path).expect("identity");
    let client_tls = volwarp_tls::client_config(Some(&cert_path)).expect("client config");

    let marcher = Arc::new(Marcher::from_dataset(&Dataset::default_bundled()));
    let cfg = |tls: Option<TlsIdentity>| ServerConfig {
        listen: "127.0.0.1:0".parse().unwrap(),
        threads: 2,
        tls,
        ..ServerConfig::default()
    };
    let plain_server = Server::with_marcher(cfg(None), marcher.clone()).expect("server").spawn();
    let tls_server = Server::with_marcher(cfg(Some(identity)), marcher).expect("server").spawn();
    let timeout = Duration::from_secs(30);
    let mut plain =
        connect_secure(&plain_server.local_addr().to_string(), None, timeout, 4, None).expect("plain connection");
    let mut tls = connect_secure(&tls_server.local_addr().to_string(), None, timeout, 4, Some(&client_tls))
        .expect("TLS connection");
    if let Some(t) = &tls.tls {
        println!("TLS: {}", t.link.describe());
    }
    // Warm-up: the first frames of each.
    let (mut seq_p, mut seq_t) = (0u64, 0u64);
    round(&mut plain, size, 1.0, &mut seq_p);
    round(&mut tls, size, 1.0, &mut seq_t);
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!(
        "tls_cost: bundled volume at {size}², 4 segments per pixel, {rounds} alternating rounds of {secs} s; load {}",
        load.trim()
    );
    let (mut p, mut t) = (Vec::new(), Vec::new());
    for r in 0..rounds {
        let a = round(&mut plain, size, secs, &mut seq_p);
        let b = round(&mut tls, size, secs, &mut seq_t);
        println!(
            "round {r}: plain {:.2} fps, {:.1} / {:.2} ms CPU per frame; TLS {:.2} fps, {:.1} / {:.2} ms",
            a.fps, a.process_ms, a.client_ms, b.fps, b.process_ms, b.client_ms
        );
        p.push(a);
        t.push(b);
    }
    let med = |v: &[Round], f: fn(&Round) -> f64| median(v.iter().map(f).collect());
    println!("| link | frames/s | process CPU ms/frame | client thread CPU ms/frame |");
    println!("|---|---|---|---|");
    for (name, v) in [("plain TCP", &p), ("TLS 1.3", &t)] {
        println!(
            "| {name} | {:.2} | {:.1} | {:.2} |",
            med(v, |r| r.fps),
            med(v, |r| r.process_ms),
            med(v, |r| r.client_ms)
        );
    }
    let (fp, ft) = (med(&p, |r| r.fps), med(&t, |r| r.fps));
    println!("TLS: {:+.1} % frames per second", (ft / fp - 1.0) * 100.0);
    plain.bye();
    tls.bye();
    plain_server.shutdown();
    tls_server.shutdown();
    let _ = std::fs::remove_dir_all(&dir);
}
