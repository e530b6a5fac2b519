//! Failures a user meets: bad address, nothing listening, server gone, another protocol
//! version, a server Error, no display. Each is one clear line and a nonzero exit, never a
//! panic.

mod common;

use common::*;
use std::time::Duration;
use volwarp_core::wire::{self, error_code, ErrorMsg, Hello, Message};

const LIMIT: Duration = Duration::from_secs(60);

fn headless(addr: &str) -> Vec<String> {
    let out = std::env::temp_dir().join(format!("volwarp-client-errors-{}", std::process::id()));
    vec![
        "--headless".into(),
        "--connect".into(),
        addr.into(),
        "--out".into(),
        out.to_str().unwrap().into(),
        "--frames".into(),
        "2".into(),
        "--timeout-s".into(),
        "5".into(),
    ]
}

fn run_headless(addr: &str) -> std::process::Output {
    let args = headless(addr);
    let args: Vec<&str> = args.iter().map(|s| s.as_str()).collect();
    run(&args, LIMIT)
}

fn assert_clean_failure(out: &std::process::Output, expect: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "stderr:\n{stderr}");
    assert!(!stderr.contains("panicked"), "stderr:\n{stderr}");
    let line = error_line(out);
    assert!(line.contains(expect), "expected `{expect}` in `{line}`\nstderr:\n{stderr}");
}

#[test]
fn bad_address_and_nothing_listening() {
    let out = run_headless("not an address");
    assert_clean_failure(&out, "bad server address");
    let out = run_headless("127.0.0.1:99999");
    assert_clean_failure(&out, "bad server address");
    // A port nobody listens on.
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let out = run_headless(&format!("127.0.0.1:{port}"));
    assert_clean_failure(&out, "cannot connect");
}

/// A server that dies after the first real request (and never listens again).
fn dying_server() -> String {
    fake_server(|mut s| {
        greet(&mut s, Hello::new(0));
        // The first real request arrives, then the server dies.
        let _ = read_msg(&mut s);
    })
}

#[test]
fn server_gone_after_the_handshake() {
    // --no-reconnect: the drop ends the client at once.
    let mut args = headless(&dying_server());
    args.push("--no-reconnect".into());
    let args: Vec<&str> = args.iter().map(|s| s.as_str()).collect();
    let out = run(&args, LIMIT);
    assert_clean_failure(&out, "server gone");
    // By default the client keeps trying until its first frame is overdue, and says so.
    let out = run_headless(&dying_server());
    assert_clean_failure(&out, "server gone");
    let line = error_line(&out);
    assert!(line.contains("reconnecting") && line.contains("cannot connect"), "{line}");
}

#[test]
fn server_speaking_another_version() {
    let addr = fake_server(|mut s| {
        use std::io::Write;
        let _ = read_msg(&mut s);
        let mut hello = encode(&Message::Hello(Hello::new(0)));
        hello[4..6].copy_from_slice(&(wire::VERSION + 1).to_le_bytes());
        hello[10..12].copy_from_slice(&[0, 0]);
        s.write_all(&hello).unwrap();
        std::thread::sleep(Duration::from_millis(500));
    });
    let out = run_headless(&addr);
    assert_clean_failure(&out, &format!("protocol version {}", wire::VERSION + 1));
}

#[test]
fn server_error_messages_are_shown() {
    let addr = fake_server(|mut s| {
        use std::io::Write;
        let _ = read_msg(&mut s);
        let e = ErrorMsg::new(error_code::UNAUTHORIZED, "missing or wrong token");
        s.write_all(&encode(&Message::Error(e))).unwrap();
        std::thread::sleep(Duration::from_millis(500));
    });
    let out = run_headless(&addr);
    assert_clean_failure(&out, "missing or wrong token");
}

#[test]
fn not_a_volwarp_server() {
    let addr = fake_server(|mut s| {
        use std::io::Write;
        let _ = read_msg(&mut s);
        s.write_all(b"HTTP/1.1 400 Bad Request\r\n\r\n").unwrap();
        std::thread::sleep(Duration::from_millis(500));
    });
    let out = run_headless(&addr);
    assert_clean_failure(&out, "not a volwarp stream");
    let _ = wire::VERSION;
}

#[test]
fn no_display_says_so_and_suggests_headless() {
    let out = std::process::Command::new(bin())
        .args(["--frames", "1"])
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let line = error_line(&out);
    assert!(line.contains("no display") && line.contains("--headless"), "{line}");
}

#[test]
fn usage_errors_exit_with_2() {
    let out = run(&["--headless"], LIMIT);
    assert_eq!(out.status.code(), Some(2));
    assert!(error_line(&out).contains("--out"));
    let out = run(&["--headless", "--out", "x", "--renderer", "nope"], LIMIT);
    assert_eq!(out.status.code(), Some(2));
    // clap rejects the name while parsing, listing the registry's names.
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("unknown renderer") && err.contains("spheres-cpu"), "{err}");
}

/// `--token-file`: the token read from the file (whitespace trimmed) is what the Hello carries;
/// an empty or missing file is a usage error naming the flag; `--token` and `--token-file`
/// together are refused.
#[test]
fn the_token_file_is_sent_and_a_bad_one_is_a_usage_error() {
    let dir = std::env::temp_dir().join(format!("volwarp-client-token-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("token");
    std::fs::write(&file, "  s3cret-from-a-file \n").unwrap();
    let addr = fake_server(|mut s| {
        use std::io::Write;
        let Some(Message::Hello(h)) = read_msg(&mut s) else { panic!("no Hello") };
        let got = String::from_utf8_lossy(&h.token).into_owned();
        let e = ErrorMsg::new(error_code::UNAUTHORIZED, &format!("the Hello carried [{got}]"));
        s.write_all(&encode(&Message::Error(e))).unwrap();
        std::thread::sleep(Duration::from_millis(500));
    });
    let mut args = headless(&addr);
    args.extend(["--token-file".into(), file.to_str().unwrap().into()]);
    let args: Vec<&str> = args.iter().map(|s| s.as_str()).collect();
    assert_clean_failure(&run(&args, LIMIT), "the Hello carried [s3cret-from-a-file]");

    std::fs::write(&file, " \n").unwrap();
    let out = run(&args, LIMIT);
    assert_eq!(out.status.code(), Some(2));
    assert!(error_line(&out).contains("--token-file") && error_line(&out).contains("no token"), "{}", error_line(&out));
    std::fs::remove_file(&file).unwrap();
    let out = run(&args, LIMIT);
    assert_eq!(out.status.code(), Some(2));
    assert!(error_line(&out).contains("--token-file"), "{}", error_line(&out));

    let out = run(&["--token", "a", "--token-file", "b", "--headless", "--out", "x"], LIMIT);
    assert_eq!(out.status.code(), Some(2), "both token flags are refused");
    std::fs::remove_dir_all(&dir).ok();
}
