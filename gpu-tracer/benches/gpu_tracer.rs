//! `cargo bench -p volwarp-gpu-tracer --bench gpu_tracer [-- --quick]`: frames per second of the
//! GPU tracer and the GPU exact splatter (`splat-gpu`) at 1024×1024 on a ~620k-sample cloud (the
//! paper's Table 1 size) and the GPU LBVH build time, on whatever adapter there is (or the one
//! `-- --adapter NAME` names; device and driver are printed); the CPU packet tracer and CPU build
//! for context. Prints medians over repeated runs.

use std::time::{Duration, Instant};
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::wire::Frame;
use volwarp_core::{Camera, Heuristic, Scene};
use volwarp_cpu_tracer::PacketTracer;
use volwarp_gpu_tracer::synthetic::bumpy_surface;
use volwarp_gpu_tracer::{GpuSplat, GpuTracer, WgScanKind};

fn median(v: Vec<Duration>) -> Duration {
    let mut secs: Vec<f64> = v.iter().map(Duration::as_secs_f64).collect();
    Duration::from_secs_f64(volwarp_core::stats::median(&mut secs).unwrap_or(0.0))
}

fn time<T>(reps: usize, mut f: impl FnMut() -> T) -> Duration {
    median(
        (0..reps)
            .map(|_| {
                let t = Instant::now();
                std::hint::black_box(f());
                t.elapsed()
            })
            .collect(),
    )
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

fn bench_splat(splat: &mut GpuSplat, scene: &Scene, cam: &Camera, reps: usize) {
    let mut img = Image::new(1, 1);
    splat.try_render(scene, cam, &mut img).expect("splat"); // upload + warm-up
    let with_readback = time(reps, || splat.try_render(scene, cam, &mut img).expect("splat"));
    let frames = reps as u32;
    let only = median((0..3).map(|_| splat.splat_only(scene, cam, frames).expect("splat") / frames).collect());
    println!(
        "render: GPU splat {:.2} FPS with readback ({:.1} ms), {:.2} FPS without ({:.1} ms)",
        1.0 / with_readback.as_secs_f64(),
        ms(with_readback),
        1.0 / only.as_secs_f64(),
        ms(only)
    );
}

fn bench(gpu: &mut GpuTracer, splat: &mut GpuSplat, name: &str, frame: &Frame, cam: &Camera, reps: usize) {
    let n = frame.samples.len();
    println!("\n## {name}: {n} samples, {}x{} view", cam.width, cam.height);
    let cpu_build = time(reps, || Scene::build(frame));
    let scene = Scene::build(frame);
    // The build with each workgroup scan the device offers (the default, faster one last, so
    // it stays selected), its tree checked against the CPU's byte for byte.
    let default_scan = gpu.scan();
    for kind in WgScanKind::ALL.into_iter().rev().filter(|&k| k != default_scan).chain([default_scan]) {
        if gpu.set_scan(kind).is_err() {
            continue;
        }
        let gpu_scene = gpu.build_scene(frame).expect("GPU build");
        let t = gpu.last_build_timing();
        let rebuild = median((0..reps).map(|_| gpu.rebuild_only(frame, 1).expect("GPU rebuild")).collect());
        println!(
            "LBVH build ({} scan): GPU {:.2} ms (compute passes, median of {reps}); first build: upload {:.1} ms, passes {:.1} ms, readback {:.1} ms; CPU serial Scene::build {:.1} ms",
            kind.name(),
            ms(rebuild),
            ms(t.upload),
            ms(t.build),
            ms(t.readback),
            ms(cpu_build)
        );
        // Reported, not asserted (the tests assert it): the timings below still hold.
        let differ = gpu_scene.nodes.iter().zip(&scene.nodes).filter(|(a, b)| a != b).count();
        println!(
            "GPU tree ({} scan) against the CPU tree: samples {}, {differ} of {} nodes differ",
            kind.name(),
            if gpu_scene.samples == scene.samples { "equal" } else { "DIFFER" },
            scene.nodes.len()
        );
    }
    let mut img = Image::new(1, 1);
    gpu.try_render(&scene, cam, &mut img).expect("render"); // upload + warm-up
    let with_readback = time(reps, || gpu.try_render(&scene, cam, &mut img).expect("render"));
    let frames = reps as u32;
    let trace_only = median((0..3).map(|_| gpu.trace_only(&scene, cam, frames).expect("trace") / frames).collect());
    let mut cpu = PacketTracer::new(0);
    let mut cimg = Image::new(1, 1);
    cpu.render(&scene, cam, &mut cimg);
    let cpu_t = time(reps, || cpu.render(&scene, cam, &mut cimg));
    bench_splat(splat, &scene, cam, reps);
    println!(
        "render: GPU {:.2} FPS with readback ({:.1} ms), {:.2} FPS trace only ({:.1} ms); CPU packet tracer ({} threads) {:.2} FPS ({:.1} ms)",
        1.0 / with_readback.as_secs_f64(),
        ms(with_readback),
        1.0 / trace_only.as_secs_f64(),
        ms(trace_only),
        cpu.threads(),
        1.0 / cpu_t.as_secs_f64(),
        ms(cpu_t)
    );
}

fn main() {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    let quick = std::env::args().any(|a| a == "--quick");
    let reps = if quick { 3 } else { 7 };
    // `--adapter NAME`: the adapter whose name contains NAME (default: the best there is).
    let argv: Vec<String> = std::env::args().collect();
    let adapter = argv.iter().position(|a| a == "--adapter").and_then(|i| argv.get(i + 1)).cloned();
    let mut gpu = match GpuTracer::with_adapter(adapter.as_deref()) {
        Ok(g) => g,
        Err(e) => {
            eprintln!("gpu_tracer bench: {e}");
            std::process::exit(1);
        }
    };
    println!(
        "adapter: {}; workgroup scans: {}",
        gpu.context().describe_driver(),
        gpu.scan().describe(&gpu.context().info)
    );
    let mut splat = match GpuSplat::with_adapter(adapter.as_deref()) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("gpu_tracer bench: {e}");
            std::process::exit(1);
        }
    };
    // 790² grid points minus the empty corners: about the paper's 623,584 samples.
    let frame = bumpy_surface(790, 1.5, 1);
    let cam = frame.header.camera.orbit(10.0, 0.0).with_viewport(1024, 1024);
    bench(&mut gpu, &mut splat, "synthetic bumpy surface", &frame, &cam, reps);

    // A real frame where the shared data is there: the MRI marched at 1024² by the server.
    if let Ok(ds) = volwarp_server::Dataset::load(volwarp_server::testdata::MRI_PATH, None) {
        let marcher = volwarp_server::Marcher::from_dataset(&ds);
        let cam = marcher.default_camera(1024, 1024);
        let req = volwarp_core::wire::CameraRequest {
            seq: 1,
            camera: cam,
            heuristic: Heuristic::Threshold,
            radius_scale: 1.0,
            layers: 0,
        };
        let frame = marcher.render_frame(&req).0;
        bench(&mut gpu, &mut splat, "MRI (colin27), threshold heuristic", &frame, &cam.orbit(10.0, 0.0), reps);
    }
}
