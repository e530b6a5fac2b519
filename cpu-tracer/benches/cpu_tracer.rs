//! `cargo bench -p volwarp-cpu-tracer`: tracing (packet vs scalar, 1 and 2 threads, 1024² and
//! 512², 10° off the frame's camera), LBVH build (parallel vs serial), the baselines, and
//! resident bytes per sample. Before criterion's runs it prints a summary table of medians
//! (FPS, rays/s, ms) — the figures quoted in `docs/perf.md`.
//!
//! The frame is a server render of the MRI (`../shared/data`) when the server library and the
//! data are there, else the synthetic depth-image cloud of the same size. The packet tracer and
//! the exact splatter are also timed on the same view rendered with the paper's radius (half a voxel diagonal) instead
//! of the server's default (a pixel diagonal at the sample's depth).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use std::time::{Duration, Instant};
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::wire::Frame;
use volwarp_core::{Camera, Scene};
use volwarp_cpu_tracer::synthetic::depth_image_frame;
use volwarp_cpu_tracer::{
    AutoSpheres, PacketTracer, ParallelBuilder, PointSplat, ScalarTracer, SphereSplat, StaleImage, TileSplat,
};

#[path = "support/frames.rs"]
mod frames;

/// The benchmark frame and a description of it.
fn bench_frame() -> (Frame, String) {
    if let Some(f) = frames::mri_frame(1024) {
        return f;
    }
    let f = depth_image_frame(1024, 2.0, 1);
    let what = format!("synthetic depth-image cloud, {} samples (radius 2 grid steps)", f.samples.len());
    (f, what)
}

/// Median seconds of `f` over up to `max_runs` runs (stops after ~`budget`).
fn median_secs(max_runs: usize, budget: Duration, mut f: impl FnMut()) -> f64 {
    f(); // warm up
    let start = Instant::now();
    let mut t = Vec::new();
    while t.len() < max_runs && (t.len() < 3 || start.elapsed() < budget) {
        let s = Instant::now();
        f();
        t.push(s.elapsed().as_secs_f64());
    }
    volwarp_core::stats::median(&mut t).unwrap_or(f64::NAN)
}

fn warped(frame: &Frame, res: u32) -> Camera {
    frame.header.camera.orbit(10.0, 0.0).with_viewport(res, res)
}

fn summary(frame: &Frame, what: &str, scene: &Scene) {
    println!("\n## volwarp-cpu-tracer summary (medians)\nframe: {what}");
    let n = scene.samples.len();
    println!(
        "resident bytes per sample (samples + colors + nodes): {:.1} B ({} B for {} samples)",
        scene.resident_bytes() as f64 / n.max(1) as f64,
        scene.resident_bytes(),
        n
    );
    println!("| renderer | threads | viewport | ms | FPS | Mrays/s |\n|---|---|---|---|---|---|");
    let mut img = Image::new(1, 1);
    for res in [1024u32, 512] {
        let cam = warped(frame, res);
        for threads in [1usize, 2] {
            let mut rs: Vec<Box<dyn Renderer>> =
                vec![Box::new(PacketTracer::new(threads)), Box::new(ScalarTracer::new(threads))];
            for r in rs.iter_mut() {
                let s = median_secs(11, Duration::from_secs(4), || r.render(scene, &cam, &mut img));
                let rays = (res * res) as f64 / s / 1e6;
                println!("| {} | {threads} | {res}² | {:.1} | {:.1} | {rays:.1} |", r.name(), s * 1e3, 1.0 / s);
            }
        }
    }
    let cam = warped(frame, 1024);
    for threads in [1usize, 2] {
        let mut rs: Vec<Box<dyn Renderer>> = vec![
            Box::new(SphereSplat::new(threads)),
            Box::new(PointSplat::new(1, threads)),
            Box::new(PointSplat::new(2, threads)),
            Box::new(PointSplat::new(3, threads)),
            Box::new(StaleImage::new(threads)),
        ];
        for r in rs.iter_mut() {
            let s = median_secs(11, Duration::from_secs(3), || r.render(scene, &cam, &mut img));
            println!("| {} | {threads} | 1024² | {:.1} | {:.1} | — |", r.name(), s * 1e3, 1.0 / s);
        }
    }
    if let Some((paper, what)) = frames::mri_frame_with(1024, volwarp_server::RadiusModel::Voxel) {
        // The same view with the seed paper's radius (half a voxel diagonal): what the radius
        // model costs or saves the tracer.
        let ps = Scene::build(&paper);
        println!("\nthe paper's radius: {what}\n| renderer | threads | viewport | ms | FPS | Mrays/s |\n|---|---|---|---|---|---|");
        for res in [1024u32, 512] {
            let cam = warped(&paper, res);
            for threads in [1usize, 2] {
                let mut rs: Vec<Box<dyn Renderer>> =
                    vec![Box::new(PacketTracer::new(threads)), Box::new(SphereSplat::new(threads))];
                for r in rs.iter_mut() {
                    let s = median_secs(11, Duration::from_secs(4), || r.render(&ps, &cam, &mut img));
                    let rays = (res * res) as f64 / s / 1e6;
                    println!("| {} | {threads} | {res}² | {:.1} | {:.1} | {rays:.1} |", r.name(), s * 1e3, 1.0 / s);
                }
            }
        }
    }
    println!("\n| LBVH build of {n} samples | ms |\n|---|---|");
    let s = median_secs(11, Duration::from_secs(3), || drop(Scene::build(frame)));
    println!("| serial `Scene::build` | {:.2} |", s * 1e3);
    for threads in [1usize, 2] {
        let mut b = ParallelBuilder::new(threads);
        let mut sc = b.build(frame);
        let s = median_secs(11, Duration::from_secs(3), || b.build_into(frame, &mut sc));
        println!("| parallel, {threads} thread(s), buffers reused | {:.2} |", s * 1e3);
        let s = median_secs(11, Duration::from_secs(3), || drop(b.build(frame)));
        println!("| parallel, {threads} thread(s), fresh scene | {:.2} |", s * 1e3);
    }
    println!();
}

/// The sphere image's target table: the tiled splatter, the default renderer (`spheres`, with
/// the route it took) and the packet tracer, footprint and paper radius, 10° off and zoomed in,
/// 1024² and 512², 1 and 2 threads; and the time from a frame's bytes to a drawable scene.
fn sphere_targets_summary(frame: &Frame, what: &str, scene: &Scene) {
    let simd = volwarp_cpu_tracer::lane_kind();
    println!("\n## sphere routes (medians, wall ms; SIMD: {simd})\nframe: {what}");
    println!("| radius | view | viewport | threads | splat-tiles | spheres (route) | spheres-cpu | splat | packet / spheres |");
    println!("|---|---|---|---|---|---|---|---|---|");
    let mut img = Image::new(1, 1);
    let paper = frames::mri_frame_with(1024, volwarp_server::RadiusModel::Voxel).map(|(f, _)| {
        let s = Scene::build(&f);
        (f, s)
    });
    let mut sets = vec![("footprint", frame, scene)];
    if let Some((f, s)) = &paper {
        sets.push(("paper (voxel)", f, s));
    }
    for (radius, frame, scene) in sets {
        for (view, dolly) in [("10° off", 1.0f32), ("zoomed in (dolly 0.3)", 0.3)] {
            for res in [1024u32, 512] {
                let cam = warped(frame, res).dolly(dolly);
                for threads in [1usize, 2] {
                    // Each renderer (and its thread pool) is made just before it is timed and
                    // dropped after: the threads of a pool made earlier and not yet idle would
                    // otherwise compete with the one being timed (the first column read 19.5
                    // against 16.2 ms for the same splatter on the same scene).
                    let st = {
                        let mut t = TileSplat::new(threads);
                        median_secs(11, Duration::from_secs(3), || t.render(scene, &cam, &mut img)) * 1e3
                    };
                    let mut a = AutoSpheres::new(threads);
                    let sa = median_secs(11, Duration::from_secs(3), || a.render(scene, &cam, &mut img)) * 1e3;
                    let sp = {
                        let mut p = PacketTracer::new(threads);
                        median_secs(11, Duration::from_secs(3), || p.render(scene, &cam, &mut img)) * 1e3
                    };
                    let old = if dolly == 1.0 && res == 1024 {
                        let mut o = SphereSplat::new(threads);
                        format!(
                            "{:.1}",
                            median_secs(11, Duration::from_secs(3), || o.render(scene, &cam, &mut img)) * 1e3
                        )
                    } else {
                        "—".into()
                    };
                    let e = a.last_estimate();
                    println!(
                        "| {radius} | {view} | {res}² | {threads} | {st:.1} ({:.1} FPS) | {sa:.1} ({:.1} FPS, {:?}, side {:.1} px) | {sp:.1} | {old} | {:.2} |",
                        1e3 / st,
                        1e3 / sa,
                        a.last_route().unwrap_or(volwarp_cpu_tracer::Route::Splat),
                        (e.covered / e.spheres.max(1.0)).sqrt(),
                        sp / sa
                    );
                }
            }
        }
    }
    // Frame arrival to a drawable scene: decode the wire bytes, then either nothing more
    // (the unbuilt scene `spheres` draws) or the parallel LBVH build on 2 threads.
    let bytes = volwarp_core::wire::encode_to_vec(&volwarp_core::wire::Message::Frame(frame.clone()));
    let limits = volwarp_core::wire::Limits::default();
    let decode = || match volwarp_core::wire::read_message(&mut &bytes[..], &limits) {
        Ok(volwarp_core::wire::Message::Frame(f)) => f,
        _ => panic!("the encoded frame decodes"),
    };
    let d = median_secs(11, Duration::from_secs(3), || drop(decode())) * 1e3;
    let u = median_secs(11, Duration::from_secs(3), || drop(unbuilt_scene_from(decode()))) * 1e3;
    let mut b = ParallelBuilder::new(2);
    let mut sc = b.build(frame);
    let bt = median_secs(11, Duration::from_secs(3), || b.build_into(&decode(), &mut sc)) * 1e3;
    println!(
        "\nframe bytes ({} B) to a drawable scene: decode {d:.2} ms; decode + unbuilt scene {u:.2} ms; decode + LBVH build (2 threads, buffers reused) {bt:.2} ms",
        bytes.len()
    );
}

/// The unbuilt scene of a decoded frame, taking its buffers (no copy).
fn unbuilt_scene_from(frame: Frame) -> Scene {
    volwarp_cpu_tracer::route::into_unbuilt_scene(frame)
}

fn benches(c: &mut Criterion) {
    let (frame, what) = bench_frame();
    let scene = Scene::build(&frame);
    sphere_targets_summary(&frame, &what, &scene);
    if std::env::var_os("VOLWARP_BENCH_SPHERE_TARGETS_ONLY").is_some() {
        return;
    }
    if std::env::var_os("VOLWARP_BENCH_NO_SUMMARY").is_none() {
        summary(&frame, &what, &scene);
    }
    let mut img = Image::new(1, 1);

    let mut g = c.benchmark_group("trace");
    g.sample_size(10).warm_up_time(Duration::from_millis(300)).measurement_time(Duration::from_secs(2));
    for res in [1024u32, 512] {
        let cam = warped(&frame, res);
        g.throughput(Throughput::Elements((res * res) as u64));
        for threads in [1usize, 2] {
            let mut p = PacketTracer::new(threads);
            g.bench_function(BenchmarkId::new(format!("packet/{threads}t"), res), |b| {
                b.iter(|| p.render(&scene, &cam, &mut img))
            });
            let mut s = ScalarTracer::new(threads);
            g.bench_function(BenchmarkId::new(format!("scalar/{threads}t"), res), |b| {
                b.iter(|| s.render(&scene, &cam, &mut img))
            });
        }
    }
    g.finish();

    let mut g = c.benchmark_group("lbvh_build");
    g.sample_size(10).warm_up_time(Duration::from_millis(300)).measurement_time(Duration::from_secs(2));
    g.throughput(Throughput::Elements(frame.samples.len() as u64));
    g.bench_function("serial", |b| b.iter(|| Scene::build(&frame)));
    for threads in [1usize, 2] {
        let mut builder = ParallelBuilder::new(threads);
        let mut sc = builder.build(&frame);
        g.bench_function(BenchmarkId::new("parallel_reuse", threads), |b| {
            b.iter(|| builder.build_into(&frame, &mut sc))
        });
        g.bench_function(BenchmarkId::new("parallel_fresh", threads), |b| b.iter(|| builder.build(&frame)));
    }
    g.finish();

    let mut g = c.benchmark_group("baselines");
    g.sample_size(10).warm_up_time(Duration::from_millis(300)).measurement_time(Duration::from_secs(2));
    let cam = warped(&frame, 1024);
    for threads in [1usize, 2] {
        let mut rs: Vec<Box<dyn Renderer>> = vec![
            Box::new(SphereSplat::new(threads)),
            Box::new(PointSplat::new(1, threads)),
            Box::new(PointSplat::new(3, threads)),
            Box::new(StaleImage::new(threads)),
        ];
        for r in rs.iter_mut() {
            g.bench_function(BenchmarkId::new(r.name(), format!("{threads}t")), |b| {
                b.iter(|| r.render(&scene, &cam, &mut img))
            });
        }
    }
    g.finish();
}

criterion_group!(cpu_tracer, benches);
criterion_main!(cpu_tracer);
