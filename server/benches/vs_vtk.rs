//! `cargo bench -p volwarp-server --bench vs_vtk`: the marcher side by side with VTK's
//! `vtkFixedPointVolumeRayCastMapper` in one run, on the same volumes, transfer functions,
//! cameras and viewports (see `tools/vtk-bench/README.md`).
//!
//! For every volume of `../shared/data` (the MRI also at 1024²): the frame time of the packet
//! marcher (march + pack + compaction, what the server does per request) and of the scalar
//! marcher on a pool of `VTK_BENCH_THREADS` (default 2) threads, median of `VTK_BENCH_RUNS`
//! (default 5) after one warm-up; then VTK's render time for the same scenes, run by the
//! Python of `VTK_BENCH_PYTHON` (default `tools/vtk-bench/.venv/bin/python`, which
//! `tools/vtk-bench/run.sh` creates). Without that Python only our figures are printed.
//! Camera: the server's default camera orbited 20°/10° and moved to 0.68 of its distance
//! (`volwarp-server dump --zoom 0.68 --orbit 20,10`), the MRI benchmark view.
//!
//! `VTK_BENCH_SHADE=1` shades both sides: the marchers with gradient shading
//! (`Shading::DEFAULT`: ambient 0.3, diffuse 0.7, specular 0.2, exponent 32, light fixed to the
//! volume) and VTK with `ShadeOn()` and the same coefficients.
//!
//! `VTK_BENCH_VOLUME=/path/to/name_XxYxZ_type.raw` benches that one file instead (at 1024², with
//! its preset transfer function), e.g. a synthetic volume of `volwarp-server synth`.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;
use volwarp_core::wire::CameraRequest;
use volwarp_core::Heuristic;
use volwarp_server::marcher::Shading;
use volwarp_server::volume::parse_raw_name;
use volwarp_server::{Dataset, MarchKernel, MarchOptions, Marcher};

const DATA: &str = volwarp_server::testdata::SHARED_DATA;

struct Scene {
    name: String,
    path: PathBuf,
    ds: Dataset,
    size: u32,
}

fn median(mut v: Vec<f64>) -> f64 {
    volwarp_core::stats::median(&mut v).unwrap_or(f64::NAN)
}

fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name).ok().and_then(|s| s.parse().ok()).unwrap_or(default)
}

fn request(m: &Marcher, size: u32) -> CameraRequest {
    let camera = m.default_camera(size, size).orbit(20.0, 10.0).dolly(0.68);
    CameraRequest { seq: 0, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 }
}

/// Median frame time in ms and the sample count.
fn time_ours(m: &Marcher, req: &CameraRequest, runs: usize) -> (f64, usize) {
    let (mut frame, _) = m.render_frame(req);
    let times = (0..runs)
        .map(|_| {
            let t = Instant::now();
            m.render_frame_into(req, &mut frame);
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    (median(times), frame.samples.len())
}

fn scene_json(s: &Scene, m: &Marcher, threads: usize, runs: usize) -> serde_json::Value {
    let req = request(m, s.size);
    let c = req.camera;
    let vol = &s.ds.volume;
    let (lo, hi) = vol.value_range();
    let n = s.ds.tf.table().len();
    let tf: Vec<[f32; 5]> =
        s.ds.tf
            .table()
            .iter()
            .enumerate()
            .map(|(i, &[r, g, b, a])| [lo + (hi - lo) * i as f32 / (n - 1) as f32, r, g, b, a])
            .collect();
    let file = s.path.file_name().and_then(|f| f.to_str()).unwrap_or("");
    let ty = volwarp_server::volume::parse_raw_name(file).map(|r| r.voxel_type.name()).unwrap_or("uint8");
    let sp = vol.spacing();
    serde_json::json!({
        "name": s.name,
        "volume": s.path,
        "dims": vol.dims(),
        "voxel_type": ty,
        "spacing": [sp.x, sp.y, sp.z],
        "tf": tf,
        "opacity_unit": sp.min_element(),
        "eye": [c.eye.x, c.eye.y, c.eye.z],
        "target": [c.target.x, c.target.y, c.target.z],
        "up": [c.up.x, c.up.y, c.up.z],
        "fov_y_deg": c.fov_y_deg,
        "width": s.size,
        "height": s.size,
        "sample_distance": m.step(),
        "threads": threads,
        "runs": runs,
        "shade": m.options().shading.is_some(),
    })
}

/// The scene of `VTK_BENCH_VOLUME`: that raw file at 1024², with its preset.
fn volume_scene(path: PathBuf) -> Result<Scene, String> {
    let file = path.file_name().and_then(|f| f.to_str()).unwrap_or("");
    parse_raw_name(file)
        .map_err(|_| format!("VTK_BENCH_VOLUME {}: not a raw file named name_XxYxZ_type.raw", path.display()))?;
    let ds = Dataset::load(&path, None).map_err(|e| format!("VTK_BENCH_VOLUME {e}"))?;
    let stem = file.strip_suffix(".raw").unwrap_or(file);
    Ok(Scene { name: format!("{stem} 1024²"), path, ds, size: 1024 })
}

/// The scenes of every raw volume of [`DATA`] whose name contains one of `filter` (all where
/// it is empty); `None` where the folder is missing.
fn shared_scenes(filter: &[String]) -> Option<Vec<Scene>> {
    let Ok(dir) = std::fs::read_dir(DATA) else {
        eprintln!("vs_vtk skipped: {DATA} not found");
        return None;
    };
    let mut files: Vec<PathBuf> =
        dir.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.extension().is_some_and(|x| x == "raw")).collect();
    files.sort_by_key(|p| std::fs::metadata(p).map(|m| m.len()).unwrap_or(0));
    let mut scenes = Vec::new();
    for path in files {
        let ds = Dataset::load(&path, None).expect("loading a shared volume");
        if !filter.is_empty() && !filter.iter().any(|f| ds.name.contains(f.as_str())) {
            continue;
        }
        let sizes: &[u32] = if ds.name.starts_with("mri") { &[1024, 512] } else { &[512] };
        for &size in sizes {
            scenes.push(Scene { name: format!("{} {size}²", ds.name), path: path.clone(), ds: ds.clone(), size });
        }
    }
    Some(scenes)
}

fn main() {
    // `cargo bench` passes `--bench`; a filter argument picks volumes by name.
    let filter: Vec<String> = std::env::args().skip(1).filter(|a| !a.starts_with("--")).collect();
    let threads = env_usize("VTK_BENCH_THREADS", 2);
    volwarp_server::limit_lanes_from_env();
    let runs = env_usize("VTK_BENCH_RUNS", 5).max(1);
    let scenes = match std::env::var_os("VTK_BENCH_VOLUME").filter(|v| !v.is_empty()) {
        Some(path) => match volume_scene(PathBuf::from(path)) {
            Ok(s) => vec![s],
            Err(e) => {
                eprintln!("vs_vtk: {e}");
                std::process::exit(1);
            }
        },
        None => match shared_scenes(&filter) {
            Some(s) => s,
            None => return,
        },
    };
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    eprintln!(
        "vs_vtk: {threads} threads, {:?} lanes, shading {}, median of {runs} runs; load {}",
        volwarp_server::lane_kind(),
        std::env::var("VTK_BENCH_SHADE").as_deref() == Ok("1"),
        load.trim()
    );
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool");
    let mut ours = Vec::new();
    let mut json = Vec::new();
    for s in &scenes {
        let shading = (std::env::var("VTK_BENCH_SHADE").as_deref() == Ok("1")).then_some(Shading::DEFAULT);
        let packet =
            Marcher::with_options(s.ds.volume.clone(), &s.ds.tf, MarchOptions { shading, ..MarchOptions::default() });
        let scalar =
            packet.with_transfer_function(&s.ds.tf, MarchOptions { kernel: MarchKernel::Scalar, ..packet.options() });
        let req = request(&packet, s.size);
        let (fast, samples) = pool.install(|| time_ours(&packet, &req, runs));
        let (slow, _) = pool.install(|| time_ours(&scalar, &req, runs.min(3)));
        eprintln!("{:<34} {samples:>8} samples  packet {fast:>8.1} ms  scalar {slow:>8.1} ms", s.name);
        ours.push((fast, slow, samples));
        json.push(scene_json(s, &packet, threads, runs));
    }
    let python = std::env::var_os("VTK_BENCH_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../tools/vtk-bench/.venv/bin/python"));
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tools/vtk-bench/vtk_bench.py");
    let mut vtk: Vec<Option<f64>> = vec![None; scenes.len()];
    if python.exists() {
        let scenes_file = std::env::temp_dir().join(format!("volwarp-vtk-scenes-{}.json", std::process::id()));
        std::fs::File::create(&scenes_file)
            .and_then(|mut f| f.write_all(serde_json::Value::Array(json).to_string().as_bytes()))
            .expect("writing the VTK scenes");
        match std::process::Command::new(&python).arg(&script).arg(&scenes_file).output() {
            Ok(out) if out.status.success() => {
                for (line, slot) in String::from_utf8_lossy(&out.stdout).lines().zip(vtk.iter_mut()) {
                    let v: serde_json::Value = serde_json::from_str(line).unwrap_or_default();
                    *slot = v["wall_ms_median"].as_f64();
                }
            }
            Ok(out) => eprintln!("vtk_bench.py failed: {}", String::from_utf8_lossy(&out.stderr)),
            Err(e) => eprintln!("cannot run {}: {e}", python.display()),
        }
        let _ = std::fs::remove_file(&scenes_file);
    } else {
        eprintln!("no VTK Python at {} (run tools/vtk-bench/run.sh once): our figures only", python.display());
    }
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!("\n| scene | samples | packet marcher, ms | scalar marcher, ms | VTK fixed-point, ms | VTK / packet | VTK / scalar |");
    println!("|---|---|---|---|---|---|---|");
    for (s, ((fast, slow, samples), v)) in scenes.iter().zip(ours.iter().zip(&vtk)) {
        let (vs, ratio, ratio_s) = match v {
            Some(v) => (format!("{v:.1}"), format!("{:.2}", v / fast), format!("{:.2}", v / slow)),
            None => ("–".into(), "–".into(), "–".into()),
        };
        println!("| {} | {samples} | {fast:.1} | {slow:.1} | {vs} | {ratio} | {ratio_s} |", s.name);
    }
    println!("\n{threads} threads, medians of {runs} runs (scalar: {}); load at the end {}", runs.min(3), load.trim());
}
