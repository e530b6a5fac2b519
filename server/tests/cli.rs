//! The `volwarp-server` binary: `render`, `dump`, serving, and clear errors.

mod common;

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use volwarp_core::wire::{self, Limits, Message};
use volwarp_core::Heuristic;

const BIN: &str = env!("CARGO_BIN_EXE_volwarp-server");

#[test]
fn dump_writes_one_frame_and_render_a_png() {
    let dir = common::temp_dir("cli");
    let frame = dir.join("f.vwf");
    let out = Command::new(BIN)
        .args(["dump", "--size", "40x30", "--orbit", "-20,15", "--heuristic", "gradient", "--out"])
        .arg(&frame)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let bytes = std::fs::read(&frame).unwrap();
    match wire::read_message(&mut &bytes[..], &Limits::default()) {
        Ok(Message::Frame(f)) => {
            assert_eq!((f.header.camera.width, f.header.camera.height), (40, 30));
            assert_eq!(f.header.heuristic, Heuristic::Gradient);
            assert!(f.samples.len() > 100 && f.samples.len() < 1200, "{}", f.samples.len());
        }
        other => panic!("{other:?}"),
    }
    let png = dir.join("i.png");
    let out = Command::new(BIN).args(["render", "--size", "24x20", "--out"]).arg(&png).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(std::fs::read(&png).unwrap().starts_with(b"\x89PNG"));
}

#[test]
fn bad_arguments_fail_with_a_message() {
    for args in [
        &["render", "--volume", "/nonexistent/v_2x2x2_uint8.raw", "--out", "x.png"][..],
        &["dump", "--heuristic", "nope", "--out", "x"],
        &["render", "--size", "0x10", "--out", "x.png"],
        &["render", "--orbit", "abc", "--out", "x.png"],
        &["--listen", "0.0.0.0:0"],
    ] {
        let out = Command::new(BIN).args(args).output().unwrap();
        assert!(!out.status.success(), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("volwarp-server: "), "{args:?}: {err}");
    }
}

/// The visual-state flags: a preset renders as its JSON file given with `--tf`; crop, clip,
/// window/level and opacity change the image; bad values fail with a message naming the flag.
#[test]
fn visual_flags_render_and_bad_values_fail_clearly() {
    let dir = common::temp_dir("cli-visual");
    let render = |name: &str, args: &[&str]| {
        let png = dir.join(name);
        let out = Command::new(BIN)
            .args(["render", "--volume", "data/mri_colin27.nrrd", "--size", "40x40", "--orbit", "20,10"])
            .current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
            .args(args)
            .arg("--out")
            .arg(&png)
            .output()
            .unwrap();
        assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
        std::fs::read(&png).unwrap()
    };
    let preset = render("p.png", &["--preset", "ct-bone", "--shade", "true"]);
    assert_eq!(preset, render("f.png", &["--tf", "data/presets/ct-bone.json", "--shade", "true"]));
    assert_eq!(preset, render("d.png", &["--preset", "ct-bone"]), "the CT presets shade by default");
    let plain = render("n.png", &[]);
    for args in [
        &["--crop", "0,0,0,1,0.5,1"][..],
        &["--clip", "0.5,0.5,0.5,0,-1,0"],
        &["--window-level", "0.5,0.6"],
        &["--opacity-scale", "0.3"],
        &["--shade", "true"],
    ] {
        assert_ne!(render("x.png", args), plain, "{args:?}");
    }
    for (args, want) in [
        (&["--window-level", "0,0.5"][..], "--window-level"),
        (&["--window-level", "nan,0.5"], "--window-level"),
        (&["--window-level", "1"], "--window-level"),
        (&["--opacity-scale", "-2"], "--opacity-scale"),
        (&["--crop", "0,0,0,1,1,1.5"], "--crop"),
        (&["--crop", "0.6,0,0,0.4,1,1"], "--crop"),
        (&["--clip", "0.5,0.5,0.5,0,0,0"], "--clip"),
        (&["--preset", "bone"], "--preset"),
        (&["--shade", "maybe"], "--shade"),
    ] {
        let out = Command::new(BIN).args(["render", "--out", "x.png"]).args(args).output().unwrap();
        assert!(!out.status.success(), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(want), "{args:?}: {err}");
    }
}

/// Starts the server on a free loopback port with the small procedural volume and `extra`
/// arguments; returns it and the address it printed.
fn serve(extra: &[&std::ffi::OsStr]) -> (std::process::Child, std::net::SocketAddr) {
    let mut child = Command::new(BIN)
        .args(["--listen", "127.0.0.1:0", "--volume", "marschner-lobb:16"])
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
    let addr = line.trim().strip_prefix("listening on ").unwrap_or_else(|| panic!("{line:?}")).parse().unwrap();
    (child, addr)
}

#[test]
fn serve_prints_the_bound_address() {
    let (mut child, addr) = serve(&[]);
    let _c = common::Client::hello(addr, None);
    child.kill().unwrap();
    child.wait().unwrap();
}

#[test]
fn serve_reads_the_token_from_a_file() {
    let dir = common::temp_dir("token-file");
    let path = dir.join("token");
    std::fs::write(&path, "  s3cret file token\n").unwrap();
    // A missing or empty file is an error before anything is loaded.
    let missing = dir.join("missing");
    let empty = dir.join("empty");
    std::fs::write(&empty, " \n").unwrap();
    for (file, says) in [(&missing, "--token-file"), (&empty, "holds no token")] {
        let out = Command::new(BIN).args(["--listen", "127.0.0.1:0"]).arg("--token-file").arg(file).output().unwrap();
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(says), "{err}");
    }
    let (mut child, addr) = serve(&["--token-file".as_ref(), path.as_os_str()]);
    // The trimmed file content is the token.
    let mut wrong = common::Client::connect(addr);
    wrong.send(&Message::Hello(wire::Hello::new(0).with_token(b"  s3cret file token\n").unwrap()));
    assert!(matches!(wrong.recv(), Ok(Message::Error(e)) if e.code == wire::error_code::UNAUTHORIZED));
    let _c = common::Client::hello(addr, Some(b"s3cret file token"));
    child.kill().unwrap();
    child.wait().unwrap();
}
