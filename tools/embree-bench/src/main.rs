//! Exports the packet tracer's benchmark scene for `embree_bench.c`, and times our
//! `PacketTracer` on it, so both tracers are measured on the same machine in the same run.
//!
//! * `volwarp-embree-bench export OUT_DIR` marches the MRI with both radius models (exactly as
//!   `cpu-tracer/benches/support/frames.rs`: default camera orbited 20°/10°, dolly 0.66, 1024²,
//!   threshold heuristic) and writes per model `M` (`footprint`, `voxel`):
//!   - `frame_M.vwf`: the frame in the wire format (what `time` reads back);
//!   - `scene_M.bin`: the spheres, dequantized by the scene's `Dequantizer` in the scene's
//!     (Morton) leaf order, so an Embree `primID` is our sample index, and the ray bases of
//!     the traced cameras (`frame.header.camera.orbit(10, 0).with_viewport(res, res)`,
//!     res 1024 and 512) with our tracer's hit count (format below);
//!   - `ids_M_RES.u32`: our tracer's first-hit sample index per pixel (row-major, `u32::MAX`
//!     for none), for a per-pixel comparison.
//! * `volwarp-embree-bench time OUT_DIR [RUNS] [MODELS]` times `PacketTracer::render` (the
//!   figure trace_timing reports) and `PacketTracer::trace_ids`, the default renderer
//!   (`AutoSpheres::render` on the unbuilt scene, as a client draws a frame) and
//!   `TileSplat::splat_ids` on the built scene (checked equal to the tracer's ids) on 1 and 2
//!   threads at 1024²
//!   and 512² (wall clock, median of `RUNS` ≥ 7 after one warm-up render), and the LBVH build
//!   (`ParallelBuilder`, 1 and 2 threads), for the models (default both, comma separated).
//!
//! `scene_M.bin`, little-endian:
//! ```text
//! magic  b"VWEMB001"
//! u32    n (spheres)
//! u32    v (views, 2)
//! v ×    { u32 width, u32 height, u32 our_hits, u32 0,
//!          f32 eye[4], f32 corner[4], f32 du[4], f32 dv[4] }   (RayBasis, verbatim)
//! n ×    f32 [x, y, z, r]
//! ```

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::wire::{self, CameraRequest, Frame, Limits, Message};
use volwarp_core::{Camera, Heuristic, Scene};
use volwarp_cpu_tracer::route::unbuilt_scene;
use volwarp_cpu_tracer::{AutoSpheres, PacketTracer, ParallelBuilder, TileSplat};
use volwarp_server::{Dataset, MarchOptions, Marcher, RadiusModel};

/// The MRI beside the checkout (the same file as `cpu-tracer/benches/support/frames.rs`).
const MRI: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data/mri_colin27_181x217x181_uint8.raw");

/// The resolutions traced.
const RES: [u32; 2] = [1024, 512];

/// `frames::mri_frame_with(1024, model)` of cpu-tracer's benchmark support, verbatim but for
/// the data path.
fn mri_frame_with(res: u32, model: RadiusModel) -> Frame {
    let ds = Dataset::load(MRI, None).unwrap_or_else(|e| panic!("cannot load {MRI}: {e}"));
    let m = Marcher::from_dataset(&ds)
        .with_transfer_function(&ds.tf, MarchOptions { radius: model, ..MarchOptions::default() });
    let camera = m.default_camera(res, res).orbit(20.0, 10.0).dolly(0.66);
    let req = CameraRequest { seq: 0, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
    m.render_frame(&req).0
}

/// The traced camera at `res`², as trace_timing.rs.
fn traced_camera(frame: &Frame, res: u32) -> Camera {
    frame.header.camera.orbit(10.0, 0.0).with_viewport(res, res)
}

fn frame_path(dir: &Path, model: RadiusModel) -> PathBuf {
    dir.join(format!("frame_{model}.vwf"))
}

fn read_frame(path: &Path) -> Frame {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("reading {}: {e} (run `export` first)", path.display()));
    match wire::read_message(&mut &bytes[..], &Limits::for_frames(4096)) {
        Ok(Message::Frame(f)) => f,
        other => panic!("{}: not a frame: {other:?}", path.display()),
    }
}

fn models(arg: Option<&String>) -> Vec<RadiusModel> {
    match arg {
        None => vec![RadiusModel::Footprint, RadiusModel::Voxel],
        Some(s) => s.split(',').map(|m| m.parse().expect("radius model")).collect(),
    }
}

fn export(dir: &Path) {
    std::fs::create_dir_all(dir).expect("creating the output directory");
    for model in models(None) {
        let t = Instant::now();
        let frame = mri_frame_with(1024, model);
        eprintln!("{model}: marched {} samples in {:.1} s", frame.samples.len(), t.elapsed().as_secs_f64());
        std::fs::write(frame_path(dir, model), wire::encode_to_vec(&Message::Frame(frame.clone()))).expect("writing the frame");
        let scene = Scene::build(&frame);
        let mut out = Vec::new();
        out.extend_from_slice(b"VWEMB001");
        out.extend_from_slice(&(scene.samples.len() as u32).to_le_bytes());
        out.extend_from_slice(&(RES.len() as u32).to_le_bytes());
        let tracer = PacketTracer::new(1);
        for res in RES {
            let cam = traced_camera(&frame, res);
            let mut ids = Vec::new();
            assert!(tracer.trace_ids(&scene, &cam, &mut ids), "unusable camera or scene");
            let hits = ids.iter().filter(|&&i| i != volwarp_cpu_tracer::NO_HIT).count() as u32;
            let mut f = std::io::BufWriter::new(std::fs::File::create(dir.join(format!("ids_{model}_{res}.u32"))).unwrap());
            for id in &ids {
                f.write_all(&id.to_le_bytes()).unwrap();
            }
            f.flush().unwrap();
            let b = cam.ray_basis();
            for v in [res, res, hits, 0] {
                out.extend_from_slice(&v.to_le_bytes());
            }
            for a in [b.eye, b.corner, b.du, b.dv] {
                for x in a {
                    out.extend_from_slice(&x.to_le_bytes());
                }
            }
            eprintln!("{model}: {res}² ours: {hits} hit pixels of {}", res * res);
        }
        for &s in &scene.samples {
            let c = scene.deq.center(s);
            let r = scene.deq.radius(s);
            for x in [c.x, c.y, c.z, r] {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
        std::fs::write(dir.join(format!("scene_{model}.bin")), out).expect("writing the scene");
        eprintln!("{model}: wrote {} spheres", scene.samples.len());
    }
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Median wall milliseconds of `runs` calls of `f` after one warm-up call, and the min/max.
fn time(runs: usize, mut f: impl FnMut()) -> (f64, f64, f64) {
    f();
    let mut v: Vec<f64> = (0..runs)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    let m = median(&mut v);
    (m, v[0], v[v.len() - 1])
}

fn time_ours(dir: &Path, runs: usize, models: &[RadiusModel]) {
    for &model in models {
        let frame = read_frame(&frame_path(dir, model));
        let n = frame.samples.len();
        let mut scene = Scene::build(&frame);
        for threads in [1, 2] {
            let mut b = ParallelBuilder::new(threads);
            let (m, lo, hi) = time(runs, || b.build_into(&frame, &mut scene));
            println!(
                "RESULT tracer=ours-lbvh model={model} res=- threads={threads} what=build n={n} median_ms={m:.2} min_ms={lo:.2} max_ms={hi:.2}"
            );
        }
        let scene = Scene::build(&frame);
        let unbuilt = unbuilt_scene(&frame);
        for res in RES {
            let cam = traced_camera(&frame, res);
            let rays = (res * res) as f64;
            for threads in [1, 2] {
                let mut tracer = PacketTracer::new(threads);
                let mut ids = Vec::new();
                tracer.trace_ids(&scene, &cam, &mut ids);
                let hits = ids.iter().filter(|&&i| i != volwarp_cpu_tracer::NO_HIT).count();
                let mut img = Image::new(1, 1);
                let r = time(runs, || tracer.render(&scene, &cam, &mut img));
                let t = time(runs, || {
                    tracer.trace_ids(&scene, &cam, &mut ids);
                });
                for (what, (m, lo, hi)) in [("render", r), ("ids", t)] {
                    println!(
                        "RESULT tracer=ours-packet model={model} res={res} threads={threads} what={what} n={n} median_ms={m:.3} min_ms={lo:.3} max_ms={hi:.3} fps={:.1} mrays={:.2} hits={hits}",
                        1e3 / m,
                        rays / m / 1e3
                    );
                }
                // The default renderer (`spheres`: the cost model's route, the tiled splatter
                // on these views) as a client draws a frame: on the unbuilt scene (the frame's
                // samples in arrival order, no LBVH), with shading; and the tiled splatter's
                // first-hit ids on the built scene, which must equal the packet tracer's.
                let mut auto = AutoSpheres::new(threads);
                let r = time(runs, || auto.render(&unbuilt, &cam, &mut img));
                let mut tiles = TileSplat::new(threads);
                let mut splat_ids = Vec::new();
                let t = time(runs, || {
                    tiles.splat_ids(&scene, &cam, &mut splat_ids);
                });
                assert!(splat_ids == ids, "the splatter's ids equal the packet tracer's");
                for (what, (m, lo, hi)) in [("render", r), ("ids", t)] {
                    println!(
                        "RESULT tracer=ours-spheres model={model} res={res} threads={threads} what={what} n={n} median_ms={m:.3} min_ms={lo:.3} max_ms={hi:.3} fps={:.1} mrays={:.2} hits={hits} route={:?}",
                        1e3 / m,
                        rays / m / 1e3,
                        auto.last_route()
                    );
                }
            }
        }
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    match args.get(1).map(String::as_str) {
        Some("export") => export(Path::new(args.get(2).expect("OUT_DIR"))),
        Some("time") => {
            let runs = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(11usize);
            assert!(runs >= 7, "at least 7 runs");
            time_ours(Path::new(args.get(2).expect("OUT_DIR")), runs, &models(args.get(4)));
        }
        _ => {
            eprintln!("usage: volwarp-embree-bench export OUT_DIR | time OUT_DIR [RUNS] [MODELS]");
            std::process::exit(2);
        }
    }
}
