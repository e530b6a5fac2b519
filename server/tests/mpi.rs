//! `mpiexec -n N volwarp-server …` end to end (feature `mpi`; needs MPICH's `mpiexec`): dumps
//! and renders against the one-process server, a client over loopback, a bad launch and a
//! rank killed mid-frame.
#![cfg(feature = "mpi")]

mod common;

use common::Client;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use volwarp_core::wire::{CameraRequest, Hello, Message};
use volwarp_core::Heuristic;

const BIN: &str = env!("CARGO_BIN_EXE_volwarp-server");

fn data(file: &str) -> PathBuf {
    volwarp_server::dataset::data_dir().expect("the bundled data/ folder").join(file)
}

/// Runs the server binary, under `mpiexec -n n` where `n` is given; panics with its output on
/// failure.
fn server(n: Option<usize>, args: &[&str]) -> std::process::Output {
    let mut c = match n {
        Some(n) => {
            let mut c = Command::new("mpiexec");
            c.args(["-n", &n.to_string(), BIN]);
            c
        }
        None => Command::new(BIN),
    };
    let out = c.args(args).env("RUST_LOG", "warn").output().expect("running mpiexec (MPICH installed?)");
    assert!(out.status.success(), "{n:?} {args:?}: {}", String::from_utf8_lossy(&out.stderr));
    out
}

/// A frame file decoded, its render time zeroed (the one field that differs from run to run).
fn frame_of(p: &Path) -> volwarp_core::wire::Frame {
    let bytes = std::fs::read(p).unwrap();
    let limits = volwarp_core::wire::Limits::for_frames(4096);
    match volwarp_core::wire::read_message(&mut &bytes[..], &limits) {
        Ok(Message::Frame(mut f)) => {
            f.header.render_us = 0;
            f
        }
        other => panic!("{}: {other:?}", p.display()),
    }
}

const DATASETS: [&str; 3] = ["ct_head_quarter.nhdr", "neghip_64x64x64_uint8.raw", "mri_colin27.nrrd"];

#[test]
fn one_rank_dumps_the_one_process_frame() {
    let dir = common::temp_dir("mpi-dump");
    for file in DATASETS {
        let vol = data(file);
        for (layers, enc) in [("4", "compact"), ("1", "raw12")] {
            let one = dir.join("one.vwf");
            let mpi = dir.join("mpi.vwf");
            let args = |out: &Path| {
                let v = vec!["dump", "--volume", vol.to_str().unwrap(), "--size", "96x80", "--orbit", "30,15"];
                let mut v: Vec<String> = v.into_iter().map(String::from).collect();
                v.extend(["--layers", layers, "--encoding", enc, "--out"].map(String::from));
                v.push(out.to_str().unwrap().to_string());
                v
            };
            let a: Vec<String> = args(&one);
            server(None, &a.iter().map(|s| s.as_str()).collect::<Vec<_>>());
            let a: Vec<String> = args(&mpi);
            server(Some(1), &a.iter().map(|s| s.as_str()).collect::<Vec<_>>());
            assert_eq!(frame_of(&one), frame_of(&mpi), "{file} K={layers} {enc}");
        }
    }
}

fn png(p: &Path) -> Vec<[u8; 4]> {
    image::open(p).unwrap().to_rgba8().pixels().map(|p| p.0).collect()
}

#[test]
fn two_to_four_ranks_render_the_one_process_image() {
    let dir = common::temp_dir("mpi-render");
    for file in DATASETS {
        let vol = data(file);
        let one = dir.join("one.png");
        let args = |out: &Path| -> Vec<String> {
            ["render", "--volume", vol.to_str().unwrap(), "--size", "96x96", "--orbit", "60,10", "--out"]
                .into_iter()
                .map(String::from)
                .chain([out.to_str().unwrap().to_string()])
                .collect()
        };
        let a = args(&one);
        server(None, &a.iter().map(|s| s.as_str()).collect::<Vec<_>>());
        let want = png(&one);
        for n in 1..=4 {
            let p = dir.join(format!("n{n}.png"));
            let a = args(&p);
            server(Some(n), &a.iter().map(|s| s.as_str()).collect::<Vec<_>>());
            let got = png(&p);
            let worst = got.iter().zip(&want).flat_map(|(a, b)| (0..4).map(move |i| a[i].abs_diff(b[i]))).max();
            let same = got.iter().zip(&want).filter(|(a, b)| a == b).count() as f64 / got.len() as f64;
            assert!(worst.unwrap_or(0) <= 3 && same > 0.6, "{file} n={n}: worst {worst:?}, identical {same}");
        }
    }
}

/// Starts `mpiexec -n n … serve` on a free loopback port (`extra`: mpiexec's options, `env`:
/// the ranks' environment); returns the child and the address.
fn serve(
    n: usize,
    extra: &[&str],
    env: &[(&str, &str)],
) -> (std::process::Child, std::net::SocketAddr, BufReader<std::process::ChildStderr>) {
    let vol = data("ct_head_quarter.nhdr");
    let mut child = Command::new("mpiexec")
        .args(extra)
        .args(["-n", &n.to_string(), BIN, "--volume", vol.to_str().unwrap(), "--listen", "127.0.0.1:0"])
        .args(["--rank-timeout", "4"])
        .env("RUST_LOG", "info")
        .envs(env.iter().copied())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("running mpiexec");
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    out.read_line(&mut line).unwrap();
    let addr = line.trim().strip_prefix("listening on ").unwrap_or_else(|| panic!("{line:?}")).parse().unwrap();
    std::thread::spawn(move || std::io::copy(&mut out, &mut std::io::sink()));
    let err = BufReader::new(child.stderr.take().unwrap());
    (child, addr, err)
}

#[test]
fn a_client_over_loopback_gets_the_composited_frames() {
    use std::sync::Arc;
    use volwarp_server::distributed::{decomposition, partial::PartMarcher, render_in_process, FrameGeometry};
    let path = data("ct_head_quarter.nhdr");
    let ds = volwarp_server::Dataset::load(&path, None).unwrap();
    let opts = volwarp_server::MarchOptions { kernel: volwarp_server::MarchKernel::Scalar, ..Default::default() };
    let m = volwarp_server::Marcher::with_options(ds.volume.clone(), &ds.tf, opts);
    for n in [2, 3] {
        // The same parts in this process: what the ranks must send, bit for bit.
        let load = volwarp_server::LoadOptions::default();
        let dec = Arc::new(decomposition::Decomposition::new(ds.volume.dims(), n).unwrap());
        let data: Vec<_> = (0..n).map(|p| decomposition::read_part(&path, &load, &dec, p).unwrap()).collect();
        let range = decomposition::combine_ranges(data.iter().map(|d| d.range));
        let parts: Vec<_> = data
            .into_iter()
            .enumerate()
            .map(|(p, d)| {
                PartMarcher::new(Arc::new(d.into_volume(range).unwrap()), dec.clone(), p, &ds.tf, opts).unwrap()
            })
            .collect();
        let geo = FrameGeometry { dims: ds.volume.dims(), spacing: ds.volume.spacing(), opts };
        let (mut child, addr, _err) = serve(n, &[], &[]);
        // A client without the compact encoding gets the 12-byte samples: exact positions.
        let mut c = Client::connect(addr);
        c.send(&Message::Hello(Hello::new(0).with_layers(4)));
        assert!(matches!(c.recv(), Ok(Message::Hello(h)) if h.layers == 4));
        for (seq, yaw, layers) in [(1u64, 0.0f32, 4), (2, 45.0, 4)] {
            let camera = m.default_camera(64, 48).orbit(yaw, 10.0);
            let req = CameraRequest { seq, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
            c.send(&Message::CameraRequest(req));
            let Ok(Message::Frame(f)) = c.recv() else { panic!("expected a frame") };
            let want = geo.frame(&req, layers, &render_in_process(&parts, &req, layers, n), f.header.render_us);
            assert_eq!(f.header, want.header, "n={n}");
            assert_eq!(f.samples, want.samples, "n={n}");
            assert_eq!(f.colors, want.colors, "n={n}");
            assert_eq!(f.segments, want.segments, "n={n}");
            assert!(f.samples.len() > 500);
        }
        c.send(&Message::Bye);
        // A frame whose segments could pass 2 GiB is refused with a clear error, not wrapped.
        let mut big = Client::connect(addr);
        big.send(&Message::Hello(Hello::new(0).with_layers(16)));
        assert!(matches!(big.recv(), Ok(Message::Hello(h)) if h.layers == 16));
        let camera = m.default_camera(4096, 4096);
        big.send(&Message::CameraRequest(CameraRequest {
            seq: 9,
            camera,
            heuristic: Heuristic::Threshold,
            radius_scale: 1.0,
            layers: 0,
        }));
        match big.recv() {
            Ok(Message::Error(e)) => assert!(e.text.contains("too large for the exchange"), "{}", e.text),
            other => panic!("expected an error, got {other:?}"),
        }
        // One sample per pixel: threshold is composited, peak (whole-ray) is refused with why.
        let mut one = Client::connect(addr);
        one.send(&Message::Hello(Hello::new(0).with_layers(1)));
        assert!(matches!(one.recv(), Ok(Message::Hello(h)) if h.layers == 1));
        let camera = m.default_camera(32, 32);
        for (seq, heuristic) in [(1, Heuristic::Threshold), (2, Heuristic::Peak)] {
            one.send(&Message::CameraRequest(CameraRequest { seq, camera, heuristic, radius_scale: 1.0, layers: 0 }));
            match (heuristic, one.recv()) {
                (Heuristic::Threshold, Ok(Message::Frame(f))) => assert!(f.samples.len() > 100),
                (Heuristic::Peak, Ok(Message::Error(e))) => {
                    assert!(e.text.contains("not composited across MPI ranks"), "{}", e.text)
                }
                (h, other) => panic!("{h}: got {other:?}"),
            }
        }
        let _ = child.kill();
        let _ = child.wait();
    }
}

#[test]
fn more_ranks_than_bricks_is_a_clear_error() {
    let out = Command::new("mpiexec")
        .args(["-n", "9", BIN, "dump", "--volume", data("neghip_64x64x64_uint8.raw").to_str().unwrap()])
        .args(["--out", "/dev/null"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("at most 8 ranks"), "{err}");
}

#[test]
fn visual_state_flags_are_refused_across_ranks() {
    let vol = data("neghip_64x64x64_uint8.raw");
    for flag in [["--preset", "ct-bone"], ["--crop", "0,0,0,1,0.5,1"], ["--shade", "true"]] {
        let out = Command::new("mpiexec")
            .args(["-n", "2", BIN, "render", "--volume", vol.to_str().unwrap(), "--out", "/dev/null"])
            .args(flag)
            .output()
            .unwrap();
        assert!(!out.status.success(), "{flag:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("not applied across MPI ranks"), "{flag:?}: {err}");
    }
}

/// What a fault test saw: the answers of the client that asked for the failing frame and of
/// an idle client, how long the first took, and mpiexec's exit status.
struct Fault {
    asked: Result<Message, volwarp_core::wire::WireError>,
    idle: Result<Message, volwarp_core::wire::WireError>,
    took: Duration,
    status: std::process::ExitStatus,
}

/// Serves on 3 ranks with rank 2 failing (`what`: `abort` or `hang`, `VOLWARP_MPI_FAULT`) after
/// marching the second frame, under `mpiexec` with `extra` options; one client asks for two
/// frames while another is connected and idle.
fn fault_mid_frame(what: &str, extra: &[&str]) -> Fault {
    let fault = format!("2:2:{what}");
    let (mut child, addr, err) = serve(3, extra, &[("VOLWARP_MPI_FAULT", &fault)]);
    std::thread::spawn(move || err.lines().map_while(Result::ok).for_each(drop));
    let hello = |c: &mut Client| {
        c.stream.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
        c.send(&Message::Hello(Hello::new(0).with_layers(4)));
        assert!(matches!(c.recv(), Ok(Message::Hello(_))));
    };
    let mut idle = Client::connect(addr);
    hello(&mut idle);
    let mut c = Client::connect(addr);
    hello(&mut c);
    let ds = volwarp_server::Dataset::load(data("ct_head_quarter.nhdr"), None).unwrap();
    let camera = volwarp_server::default_camera(&ds.volume, 64, 64);
    let req = |seq| CameraRequest { seq, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
    c.send(&Message::CameraRequest(req(1)));
    assert!(matches!(c.recv(), Ok(Message::Frame(_))), "the first frame arrives");
    let t = Instant::now();
    c.send(&Message::CameraRequest(req(2)));
    let asked = c.recv();
    let took = t.elapsed();
    let idle = idle.recv();
    // mpiexec ends by itself (a hung rank is killed with the job), within a bound.
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if t.elapsed() > Duration::from_secs(60) {
            let _ = child.kill();
            panic!("mpiexec still runs 60 s after the fault");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    Fault { asked, idle, took, status }
}

/// Asserts `got` is the failed-rank error.
fn assert_rank_error(who: &str, got: &Result<Message, volwarp_core::wire::WireError>) {
    match got {
        Ok(Message::Error(e)) => {
            assert_eq!(e.code, volwarp_core::wire::error_code::INTERNAL, "{who}");
            assert!(e.text.contains("rank"), "{who}: {}", e.text);
        }
        other => panic!("{who}: expected an error message, got {other:?}"),
    }
}

#[test]
fn a_rank_that_hangs_mid_frame_is_reported_to_the_clients() {
    let f = fault_mid_frame("hang", &[]);
    assert_rank_error("the client asking", &f.asked);
    assert_rank_error("the idle client", &f.idle);
    if let Ok(Message::Error(e)) = &f.asked {
        assert!(e.text.contains("a rank died or hangs"), "{}", e.text);
    }
    // --rank-timeout 4 and the time to tell the clients.
    assert!(f.took < Duration::from_secs(15), "{:?}", f.took);
    assert!(!f.status.success());
}

#[test]
fn a_rank_that_fails_mid_frame_is_reported_to_the_clients() {
    // A march that panics: the rank sends bands that do not decode, rank 0 tells its clients
    // and ends the job.
    let f = fault_mid_frame("panic", &[]);
    assert_rank_error("the client asking", &f.asked);
    assert_rank_error("the idle client", &f.idle);
    assert!(f.took < Duration::from_secs(15), "{:?}", f.took);
    assert!(!f.status.success());
}

#[test]
fn a_rank_that_dies_mid_frame_ends_the_job() {
    // MPICH kills every rank (rank 0 too) when one dies: the clients' connections close,
    // never a silent hang, and mpiexec fails.
    let f = fault_mid_frame("abort", &[]);
    assert!(!matches!(f.asked, Ok(Message::Frame(_))), "{:?}", f.asked);
    assert!(f.took < Duration::from_secs(15), "{:?}", f.took);
    assert!(!f.status.success());
}

#[test]
fn ranks_reading_different_files_is_a_clear_error() {
    let dir = common::temp_dir("mpi-mismatch");
    let other = dir.join("other_64x64x32_uint8.raw");
    std::fs::write(&other, vec![7u8; 64 * 64 * 32]).unwrap();
    let one = data("neghip_64x64x64_uint8.raw");
    let out = Command::new("mpiexec")
        .args(["-n", "1", BIN, "dump", "--volume", one.to_str().unwrap(), "--out", "/dev/null", ":"])
        .args(["-n", "1", BIN, "dump", "--volume", other.to_str().unwrap(), "--out", "/dev/null"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("every rank must read the same file"), "{err}");
}

#[test]
fn a_volume_one_process_refuses_for_memory_renders_on_four_ranks() {
    let vol = data("neghip_64x64x64_uint8.raw");
    let dir = common::temp_dir("mpi-memory");
    let png = dir.join("four.png");
    let args = ["render", "--volume", vol.to_str().unwrap(), "--max-memory", "200K", "--size", "64x64", "--out"];
    let one = Command::new(BIN).args(args).arg(&png).output().unwrap();
    assert!(!one.status.success());
    assert!(String::from_utf8_lossy(&one.stderr).contains("--max-memory"));
    server(Some(4), &[&args[..], &[png.to_str().unwrap()]].concat());
    assert!(png.is_file());
}
