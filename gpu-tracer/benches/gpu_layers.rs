//! `cargo bench -p volwarp-gpu-tracer --bench gpu_layers [-- --quick] [-- --adapter NAME]`: draw
//! time of the GPU layered splatter (`splat-layers-gpu`) beside the CPU's (`splat-layers`, one
//! thread and all cores) on the same real frame: the MRI from `../shared/data` (the bundled CT
//! head where it is missing) marched by the server with K = 4 segments per pixel at 512², drawn
//! 10° off with the defaults (fill on) and adaptive growth on, as the client draws it; then with
//! three older frames kept (the multi-frame filling; the client's default keeps 4 frames).
//! Prints medians over repeated runs and the adapter, device and driver.

use std::time::{Duration, Instant};
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::wire::CameraRequest;
use volwarp_core::Heuristic;
use volwarp_cpu_tracer::route::unbuilt_scene;
use volwarp_cpu_tracer::LayerSplat;
use volwarp_gpu_tracer::GpuLayerSplat;
use volwarp_server::{Dataset, Marcher};

fn median(v: Vec<Duration>) -> Duration {
    let mut secs: Vec<f64> = v.iter().map(Duration::as_secs_f64).collect();
    Duration::from_secs_f64(volwarp_core::stats::median(&mut secs).unwrap_or(0.0))
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

fn main() {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    let argv: Vec<String> = std::env::args().collect();
    let reps = if argv.iter().any(|a| a == "--quick") { 3 } else { 7 };
    let adapter = argv.iter().position(|a| a == "--adapter").and_then(|i| argv.get(i + 1)).cloned();
    let mut gpu = match GpuLayerSplat::with_adapter(adapter.as_deref()) {
        Ok(g) => g,
        Err(e) => {
            eprintln!("gpu_layers bench: {e}");
            std::process::exit(1);
        }
    };
    println!("adapter: {}", gpu.context().describe_driver());
    let (name, ds) = match Dataset::load(volwarp_server::testdata::MRI_PATH, None) {
        Ok(ds) => ("MRI (colin27)", ds),
        Err(_) => ("CT head (bundled; the MRI is missing)", Dataset::default_bundled()),
    };
    let marcher = Marcher::from_dataset(&ds);
    let cam = marcher.default_camera(512, 512);
    let req = CameraRequest { seq: 1, camera: cam, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
    let frame = marcher.render_frame_layers(&req, 4).0;
    let scene = unbuilt_scene(&frame);
    let view = cam.orbit(10.0, 0.0);
    println!("\n## {name}: K = 4, {} samples, 512x512 frame drawn 10° off, fill on, adaptive on", frame.samples.len());
    let mut img = Image::new(1, 1);
    for threads in [1, 0] {
        let mut cpu = LayerSplat::new(threads);
        cpu.set_adaptive_radius(true);
        cpu.render(&scene, &view, &mut img); // the frame composite, cached
        let t = median(
            (0..reps)
                .map(|_| {
                    let t = Instant::now();
                    cpu.render(&scene, &view, &mut img);
                    t.elapsed()
                })
                .collect(),
        );
        let label = if threads == 0 { "all cores".to_string() } else { format!("{threads} thread") };
        println!("CPU splat-layers ({label}): {:.1} ms", ms(t));
    }
    gpu.set_adaptive_radius(true);
    gpu.try_render(&scene, &view, &mut img).expect("draw"); // upload, frame composite, list sizing
    let with_readback = median(
        (0..reps)
            .map(|_| {
                let t = Instant::now();
                gpu.try_render(&scene, &view, &mut img).expect("draw");
                t.elapsed()
            })
            .collect(),
    );
    let frames = reps as u32;
    let only = median((0..3).map(|_| gpu.draw_only(&scene, &view, frames).expect("draw") / frames).collect());
    println!(
        "GPU splat-layers-gpu: {:.1} ms with readback, {:.1} ms draw only (lists regrown {} times)",
        ms(with_readback),
        ms(only),
        gpu.list_regrowths()
    );

    // The client's default keeps 4 frames: three older ones 5°, 10° and 15° back along the
    // orbit, each drawn into the pixels the newest leaves empty (their residuals made once,
    // in the warm-up draw).
    let older: Vec<_> = (1..=3)
        .map(|i| {
            let req = CameraRequest { seq: 1 + i, camera: cam.orbit(-5.0 * i as f32, 0.0), ..req };
            unbuilt_scene(&marcher.render_frame_layers(&req, 4).0)
        })
        .collect();
    let set: Vec<_> = std::iter::once(&scene).chain(&older).collect();
    let view = cam.orbit(-20.0, 0.0);
    println!("\n## the same frame with 3 older frames kept (5°, 10°, 15° back), drawn 20° back");
    for threads in [1, 0] {
        let mut cpu = LayerSplat::new(threads);
        cpu.set_adaptive_radius(true);
        cpu.render_set(&set, &view, &mut img);
        let t = median(
            (0..reps)
                .map(|_| {
                    let t = Instant::now();
                    cpu.render_set(&set, &view, &mut img);
                    t.elapsed()
                })
                .collect(),
        );
        let label = if threads == 0 { "all cores".to_string() } else { format!("{threads} thread") };
        println!("CPU splat-layers, 4 frames ({label}): {:.1} ms", ms(t));
    }
    gpu.try_render_set(&set, &view, &mut img).expect("draw");
    let with_readback = median(
        (0..reps)
            .map(|_| {
                let t = Instant::now();
                gpu.try_render_set(&set, &view, &mut img).expect("draw");
                t.elapsed()
            })
            .collect(),
    );
    println!("GPU splat-layers-gpu, 4 frames: {:.1} ms with readback", ms(with_readback));
}
