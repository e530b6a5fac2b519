//! The measurement of the one-sample warp levers on single warps: for every dataset of a folder
//! (the first argument; `--only NAME` keeps those whose name contains NAME), the C0 frame
//! (default framing, 512², the heuristic the second argument names, `threshold` without it) is
//! warped along the orbit to 2.5–30° and scored (ꟻLIP) against the marcher's truth, for
//!
//! * `stale`, `points2`, `points3`, `spheres-cpu`, `spheres-fill` (the registry's),
//! * `fill+guard0.1`: `spheres-fill` of a frame rendered for a guard band of fraction 0.1,
//! * `fill-everywhere`: `spheres-fill` that also fills outside the silhouette,
//! * `fill K=2 steady`: `spheres-fill` with the previous frame (rendered at −20°) kept,
//! * `fill K=2 reversal`: the same with the previous frame at +20° (the camera came back),
//!
//! and `--time` (`--time-only`: nothing else) times `render_set` with K = 1, 2, 4 frames at
//! 512² and 1024², for the packet
//! tracer's fill and for `volwarp` (the window client's default: the splatter's fill with
//! warp-sized radii), beside plain `spheres-cpu` and `splat`.
//!
//! ```sh
//! cargo run --release -p volwarp-eval --example warps -- ../shared/data rel-threshold
//! ```

use std::time::Instant;
use volwarp_core::guard::GuardBand;
use volwarp_core::renderer::Renderer;
use volwarp_core::{Heuristic, Image, RendererKind, Scene};
use volwarp_cpu_tracer::{build_scene, create, FillOptions, HoleFill, PacketTracer, SampleIds, SphereSplat};
use volwarp_eval::camera_paths::orbit;
use volwarp_eval::example_args;
use volwarp_eval::quality::frame_for;
use volwarp_eval::{median, Metrics};
use volwarp_server::Marcher;

const ANGLES: [f32; 5] = [2.5, 5.0, 10.0, 20.0, 30.0];

fn flip(truth: &Image, img: &Image) -> f64 {
    Metrics::of(truth, img).map_or(1.0, |m| m.flip)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    // The heuristic: the second positional argument (after the folder), if there is one.
    let h: Heuristic = args
        .get(2)
        .filter(|a| example_args::folder(&args).is_some() && !a.starts_with('-'))
        .map_or(Heuristic::Threshold, |s| Heuristic::from_name(s).expect("a heuristic"));
    let time_only = args.iter().any(|a| a == "--time-only");
    let time = time_only || args.iter().any(|a| a == "--time");
    let size = 512;
    let datasets = example_args::datasets_or_exit(&args);
    if time_only {
        timings(&datasets[0], h);
        return;
    }
    let names = [
        "stale",
        "points2",
        "points3",
        "spheres-cpu",
        "spheres-fill",
        "fill-pp3",
        "fill+guard0.1",
        "fill-everywhere",
        "fill K=2 steady",
        "fill K=2 reversal",
    ];
    println!("dataset,heuristic,method,angle,flip");
    let mut sums = vec![[0.0f64; ANGLES.len()]; names.len()];
    for ds in &datasets {
        let m = Marcher::from_dataset(ds);
        let c0 = m.default_camera(size, size);
        let scene = build_scene(&frame_for(&m, &c0, h));
        let guards: Vec<(Scene, f32)> = [0.1f32]
            .iter()
            .map(|&g| {
                let gb = GuardBand::new(&c0, g, 8192).unwrap();
                let s = build_scene(&frame_for(&m, &gb.camera, h));
                (s, g)
            })
            .collect();
        let prev_steady = build_scene(&frame_for(&m, &orbit(&c0, -20.0), h));
        let prev_back = build_scene(&frame_for(&m, &orbit(&c0, 20.0), h));
        eprintln!(
            "{}: {} samples; guard 0.1: {} ({:.2}×)",
            ds.name,
            scene.samples.len(),
            guards[0].0.samples.len(),
            guards[0].0.samples.len() as f64 / scene.samples.len() as f64
        );
        let mut plain: Vec<Box<dyn Renderer + Send>> = [
            RendererKind::Stale,
            RendererKind::Points2,
            RendererKind::Points3,
            RendererKind::SpheresCpu,
            RendererKind::SpheresFill,
        ]
        .into_iter()
        .map(|k| create(k, 0).unwrap())
        .collect();
        let mut fill = HoleFill::new(PacketTracer::new(0), RendererKind::SpheresFill, FillOptions::DEFAULT, 0);
        let mut pp = HoleFill::new(
            PacketTracer::new(0),
            RendererKind::SpheresFill,
            FillOptions { stale: true, enclosed_only: true, pull_push_levels: 3 },
            0,
        );
        let mut everywhere = HoleFill::new(
            PacketTracer::new(0),
            RendererKind::SpheresFill,
            FillOptions { enclosed_only: false, ..FillOptions::DEFAULT },
            0,
        );
        for (ai, &a) in ANGLES.iter().enumerate() {
            let cam = orbit(&c0, a);
            let truth = m.render_image(&cam);
            let mut img = Image::new(0, 0);
            let mut scores = Vec::new();
            for r in plain.iter_mut() {
                r.render(&scene, &cam, &mut img);
                scores.push(flip(&truth, &img));
            }
            pp.render(&scene, &cam, &mut img);
            scores.push(flip(&truth, &img));
            for (gs, _) in &guards {
                fill.render(gs, &cam, &mut img);
                scores.push(flip(&truth, &img));
            }
            everywhere.render(&scene, &cam, &mut img);
            scores.push(flip(&truth, &img));
            fill.render_set(&[&scene, &prev_steady], &cam, &mut img);
            scores.push(flip(&truth, &img));
            fill.render_set(&[&scene, &prev_back], &cam, &mut img);
            scores.push(flip(&truth, &img));
            for (i, s) in scores.iter().enumerate() {
                println!("{},{h},{},{a},{s:.4}", ds.name, names[i]);
                sums[i][ai] += s / datasets.len() as f64;
            }
        }
    }
    println!("\n| method | {} |", ANGLES.map(|a| format!("{a}°")).join(" | "));
    println!("|---|{}", "---|".repeat(ANGLES.len()));
    for (i, n) in names.iter().enumerate() {
        println!("| {n} | {} |", sums[i].map(|v| format!("{v:.4}")).join(" | "));
    }
    if time {
        timings(&datasets[0], h);
    }
}

/// The fill's draw times with K = 1, 2, 4 frames (see the module docs).
fn timings(ds: &volwarp_server::dataset::Dataset, h: Heuristic) {
    {
        let m = Marcher::from_dataset(ds);
        for size in [512u32, 1024] {
            let c0 = m.default_camera(size, size);
            let scenes: Vec<Scene> =
                [0.0f32, -10.0, -20.0, -30.0].iter().map(|&a| build_scene(&frame_for(&m, &orbit(&c0, a), h))).collect();
            let cam = orbit(&c0, 10.0);
            // The fill around the packet tracer (`spheres-fill`) and the window client's default
            // drawing (`volwarp`: the splatter with warp-sized radii), K = 1, 2, 4 frames.
            let makers: [(&str, MakeFill); 2] = [
                ("spheres-fill", || {
                    Box::new(HoleFill::new(PacketTracer::new(0), RendererKind::SpheresFill, FillOptions::DEFAULT, 0))
                }),
                ("volwarp", || {
                    let mut f = HoleFill::new(SphereSplat::new(0), RendererKind::SplatFill, FillOptions::DEFAULT, 0);
                    f.set_adaptive_radius(true);
                    Box::new(f)
                }),
            ];
            for (name, make) in makers {
                for k in [1usize, 2, 4] {
                    let set: Vec<&Scene> = scenes.iter().take(k).collect();
                    let mut fill = make();
                    let mut img = Image::new(0, 0);
                    fill.draw(&set, &cam, &mut img);
                    let mut ms: Vec<f64> = (0..7)
                        .map(|_| {
                            let t = Instant::now();
                            fill.draw(&set, &cam, &mut img);
                            t.elapsed().as_secs_f64() * 1e3
                        })
                        .collect();
                    let bytes: usize = set.iter().map(|s| s.resident_bytes()).sum();
                    let n: usize = set.iter().map(|s| s.samples.len()).sum();
                    println!(
                        "time {} {size}² {name} K={k}: {:.1} ms median of 7; {n} samples, {:.1} MB resident, {:.1} B/sample",
                        ds.name,
                        median(&mut ms).unwrap_or(0.0),
                        bytes as f64 / 1e6,
                        bytes as f64 / n.max(1) as f64
                    );
                }
            }
            let mut sp = SphereSplat::new(0);
            let mut img = Image::new(0, 0);
            sp.render(&scenes[0], &cam, &mut img);
            let mut ms: Vec<f64> = (0..7)
                .map(|_| {
                    let s = Instant::now();
                    sp.render(&scenes[0], &cam, &mut img);
                    s.elapsed().as_secs_f64() * 1e3
                })
                .collect();
            println!("time {} {size}² splat: {:.1} ms", ds.name, median(&mut ms).unwrap_or(0.0));
            let mut t = PacketTracer::new(0);
            let mut img = Image::new(0, 0);
            t.render(&scenes[0], &cam, &mut img);
            let mut ms: Vec<f64> = (0..7)
                .map(|_| {
                    let s = Instant::now();
                    t.render(&scenes[0], &cam, &mut img);
                    s.elapsed().as_secs_f64() * 1e3
                })
                .collect();
            println!("time {} {size}² spheres-cpu: {:.1} ms", ds.name, median(&mut ms).unwrap_or(0.0));
        }
    }
}

/// Makes a hole-filling renderer.
type MakeFill = fn() -> Box<dyn FillSet>;

/// A hole-filling renderer drawing a set of frames (the tracer's and the splatter's).
trait FillSet {
    fn draw(&mut self, scenes: &[&Scene], camera: &volwarp_core::Camera, out: &mut Image);
}

impl<R: SampleIds + Renderer> FillSet for HoleFill<R> {
    fn draw(&mut self, scenes: &[&Scene], camera: &volwarp_core::Camera, out: &mut Image) {
        self.render_set(scenes, camera, out);
    }
}
