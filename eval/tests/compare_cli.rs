//! `volwarp-compare` end to end on a small record file (synthetic frames plus displayed
//! cameras) and on a recorded stream of real server frames. Needs a GPU adapter (lavapipe in CI); `VOLWARP_SKIP_GPU=1` skips it explicitly.

use std::process::Command;
use volwarp_core::record::{write_entry, write_magic, Entry};
use volwarp_core::wire::{CameraRequest, VecWriter};
use volwarp_core::Heuristic;
use volwarp_gpu_tracer::synthetic::bumpy_surface;
use volwarp_server::{Dataset, Marcher};

#[test]
fn compare_replays_a_record_file() {
    if std::env::var("VOLWARP_SKIP_GPU").is_ok_and(|v| v == "1") {
        eprintln!("VOLWARP_SKIP_GPU=1: GPU test skipped");
        return;
    }
    let dir = std::env::temp_dir().join(format!("volwarp-compare-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut bytes = Vec::new();
    let mut w = VecWriter(&mut bytes);
    write_magic(&mut w).unwrap();
    // Frame 0 with two displayed cameras, frame 1 with none (its own camera orbited 10°).
    let f0 = bumpy_surface(96, 1.5, 1);
    let cam = f0.header.camera;
    write_entry(&mut w, &Entry::Frame { t_us: 0, frame: f0 }).unwrap();
    for (i, yaw) in [5.0f32, 12.0].into_iter().enumerate() {
        let request = CameraRequest {
            seq: 2 + i as u64,
            camera: cam.orbit(yaw, 3.0),
            heuristic: volwarp_core::Heuristic::Threshold,
            radius_scale: 1.0,
            layers: 0,
        };
        write_entry(&mut w, &Entry::Camera { t_us: 1000 * (i as u64 + 1), request }).unwrap();
    }
    write_entry(&mut w, &Entry::Frame { t_us: 5000, frame: bumpy_surface(80, 2.0, 4) }).unwrap();
    let file = dir.join("stream.vwrec");
    std::fs::write(&file, &bytes).unwrap();

    let out = Command::new(env!("CARGO_BIN_EXE_volwarp-compare"))
        .arg(&file)
        .arg("--out")
        .arg(dir.join("png"))
        .args(["--width", "96", "--height", "80"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    eprintln!("{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "status {:?}", out.status);
    assert!(stdout.contains("worst identical share"));
    let rows = stdout.lines().filter(|l| l.contains(" %  ")).count();
    assert_eq!(rows, 3, "two displayed cameras for frame 0, one orbit for frame 1");
    let mut pngs: Vec<_> = std::fs::read_dir(dir.join("png")).unwrap().map(|e| e.unwrap().file_name()).collect();
    pngs.sort();
    assert_eq!(pngs, ["frame0000_cam00.png", "frame0000_cam01.png", "frame0001_cam00.png"]);
    let png = image::open(dir.join("png/frame0000_cam00.png")).unwrap();
    assert_eq!((png.width(), png.height()), (3 * 96 + 8, 80));

    // A file that is not a record is a clear error, not a panic.
    std::fs::write(dir.join("bad"), b"not a record").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_volwarp-compare")).arg(dir.join("bad")).output().unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("not a volwarp record file"));

    // An adapter name that matches nothing: a clear error (status 1) naming it, no panic.
    let out = Command::new(env!("CARGO_BIN_EXE_volwarp-compare"))
        .arg(&file)
        .args(["--adapter", "no-such-adapter-3f9c"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("no GPU adapter"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}

fn request(seq: u64, camera: volwarp_core::Camera, heuristic: Heuristic) -> CameraRequest {
    CameraRequest { seq, camera, heuristic, radius_scale: 1.0, layers: 0 }
}

#[test]
fn compare_replays_a_recorded_real_stream() {
    if std::env::var("VOLWARP_SKIP_GPU").is_ok_and(|v| v == "1") {
        eprintln!("VOLWARP_SKIP_GPU=1: GPU test skipped");
        return;
    }
    let marcher = Marcher::from_dataset(&Dataset::default_bundled());
    let cam = marcher.default_camera(128, 128);
    let frames: Vec<_> = [(0.0, 0.0, Heuristic::Threshold), (35.0, 10.0, Heuristic::Gradient)]
        .iter()
        .enumerate()
        .map(|(i, &(yaw, pitch, h))| marcher.render_frame(&request(i as u64, cam.orbit(yaw, pitch), h)).0)
        .collect();
    let mut bytes = Vec::new();
    let mut w = VecWriter(&mut bytes);
    write_magic(&mut w).unwrap();
    for (i, f) in frames.iter().take(2).enumerate() {
        let cam = f.header.camera;
        write_entry(&mut w, &Entry::Frame { t_us: i as u64 * 100_000, frame: f.clone() }).unwrap();
        for k in 1..=2u64 {
            let req = request(10 + k, cam.orbit(4.0 * k as f32, 2.0), f.header.heuristic);
            write_entry(&mut w, &Entry::Camera { t_us: i as u64 * 100_000 + k * 16_000, request: req }).unwrap();
        }
    }
    let dir = std::env::temp_dir().join(format!("volwarp-compare-real-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("ct.vwrec");
    std::fs::write(&file, &bytes).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_volwarp-compare")).arg(&file).arg("--out").arg(&dir).output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    eprintln!("{stdout}{}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "{:?}", out.status);
    assert_eq!(stdout.lines().filter(|l| l.contains(" %  ")).count(), 4);
    assert!(dir.join("frame0001_cam01.png").is_file());
    let _ = std::fs::remove_dir_all(&dir);
}

/// The client's default renderer on a recorded stream of layered frames: `splat-layers-gpu`
/// against `splat-layers`, with the older frames kept (the multi-frame filling on both).
#[test]
fn compare_replays_layered_frames_with_the_older_frames_kept() {
    if std::env::var("VOLWARP_SKIP_GPU").is_ok_and(|v| v == "1") {
        eprintln!("VOLWARP_SKIP_GPU=1: GPU test skipped");
        return;
    }
    let marcher = Marcher::from_dataset(&Dataset::default_bundled());
    let cam = marcher.default_camera(96, 96);
    let mut bytes = Vec::new();
    let mut w = VecWriter(&mut bytes);
    write_magic(&mut w).unwrap();
    for i in 0..3u64 {
        let fc = cam.orbit(-16.0 + 8.0 * i as f32, 3.0);
        let frame = marcher.render_frame_layers(&request(i, fc, Heuristic::Threshold), 4).0;
        assert!(frame.layers() > 1);
        write_entry(&mut w, &Entry::Frame { t_us: i * 100_000, frame }).unwrap();
        // The camera turned on past the frame and back behind it, as a user drags.
        for (k, yaw) in [(1u64, 9.0f32), (2, -20.0)] {
            let req = request(10 * i + k, fc.orbit(yaw, 2.0), Heuristic::Threshold);
            write_entry(&mut w, &Entry::Camera { t_us: i * 100_000 + k * 16_000, request: req }).unwrap();
        }
    }
    let dir = std::env::temp_dir().join(format!("volwarp-compare-layers-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("layers.vwrec");
    std::fs::write(&file, &bytes).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_volwarp-compare"))
        .arg(&file)
        .args(["--renderer", "splat-layers-gpu", "--keep-frames", "3"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    eprintln!("{stdout}{}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "{:?}", out.status);
    assert!(stdout.contains("CPU splat-layers against GPU splat-layers-gpu"));
    let rows: Vec<&str> = stdout.lines().filter(|l| l.contains("within one step")).collect();
    assert_eq!(rows.len(), 6, "two cameras for each of three frames");
    assert!(rows[4].ends_with("3 frames") && rows[0].ends_with("1 frames"), "{rows:?}");
    assert!(stdout.contains("worst within-one-step share"));
    // Not a GPU renderer with a CPU twin: a clear usage error.
    let out = Command::new(env!("CARGO_BIN_EXE_volwarp-compare"))
        .arg(&file)
        .args(["--renderer", "points2"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("one of spheres-gpu, splat-gpu, splat-layers-gpu"));
    let _ = std::fs::remove_dir_all(&dir);
}
