//! Timing of the single-threaded renderers and builders on the MRI frame (`mri`) or the
//! synthetic one, in on-CPU time of the
//! calling thread (robust on a busy machine): `cargo run --release -p volwarp-cpu-tracer
//! --example trace_timing [res] [radius_scale | mri]`.

use std::time::Instant;
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::Scene;
use volwarp_cpu_tracer::synthetic::depth_image_frame;
use volwarp_cpu_tracer::{Method, PacketTracer, ParallelBuilder, PointSplat, ScalarTracer, SphereSplat, StaleImage};

#[path = "../benches/support/frames.rs"]
mod frames;

/// Nanoseconds this thread has run (Linux `/proc/thread-self/schedstat`), if available.
fn cpu_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat").ok()?.split_whitespace().next()?.parse().ok()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let res: u32 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(1024);
    let radius: f32 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(2.0);
    let _ = Instant::now();
    let frame = match args.get(2).map(String::as_str) {
        Some("mri") => {
            let f = frames::mri_frame(1024).expect("the MRI of ../shared/data").0;
            if let Ok(path) = std::env::var("VOLWARP_DUMP_FRAME") {
                let msg = volwarp_core::wire::Message::Frame(f.clone());
                std::fs::write(&path, volwarp_core::wire::encode_to_vec(&msg)).expect("writing the frame");
            }
            f
        }
        _ => depth_image_frame(1024, radius, 1),
    };
    let t = (cpu_ns(), Instant::now());
    let scene = Scene::build(&frame);
    println!(
        "serial build: cpu {:.1} ms, {} samples",
        (cpu_ns().unwrap_or(0) - t.0.unwrap_or(0)) as f64 / 1e6,
        scene.samples.len()
    );
    let mut sc = Scene::build(&frame);
    for method in [Method::Agglomerative, Method::Karras] {
        let mut b = ParallelBuilder::new(1).with_method(method);
        let mut v = Vec::new();
        for _ in 0..5 {
            let c0 = cpu_ns().unwrap_or(0);
            b.build_into(&frame, &mut sc);
            v.push((cpu_ns().unwrap_or(0) - c0) as f64 / 1e6);
        }
        v.sort_by(f64::total_cmp);
        println!("parallel build ({method:?}), 1 thread, reused buffers: cpu {:.1} ms, {:?}", v[2], b.last_times());
    }
    let mut b2 = ParallelBuilder::new(2);
    for _ in 0..3 {
        let w = Instant::now();
        b2.build_into(&frame, &mut sc);
        println!("parallel build, 2 threads: wall {:.1} ms {:?}", w.elapsed().as_secs_f64() * 1e3, b2.last_times());
    }
    let cam = frame.header.camera.orbit(10.0, 0.0).with_viewport(res, res);
    let mut img = Image::new(1, 1);
    let mut rs: Vec<Box<dyn Renderer>> = vec![
        Box::new(PacketTracer::new(1)),
        Box::new(ScalarTracer::new(1)),
        Box::new(SphereSplat::new(1)),
        Box::new(PointSplat::new(1, 1)),
        Box::new(PointSplat::new(2, 1)),
        Box::new(PointSplat::new(3, 1)),
        Box::new(StaleImage::new(1)),
    ];
    for r in rs.iter_mut() {
        let mut cpu = Vec::new();
        let mut wall = Vec::new();
        for _ in 0..5 {
            let (c0, w0) = (cpu_ns(), Instant::now());
            r.render(&scene, &cam, &mut img);
            wall.push(w0.elapsed().as_secs_f64() * 1e3);
            if let (Some(a), Some(b)) = (c0, cpu_ns()) {
                cpu.push((b - a) as f64 / 1e6);
            }
        }
        cpu.sort_by(f64::total_cmp);
        wall.sort_by(f64::total_cmp);
        let c = cpu.get(cpu.len() / 2).copied().unwrap_or(f64::NAN);
        println!(
            "{:15} {res}²: cpu {c:7.1} ms ({:5.1} FPS, {:5.2} Mrays/s)  wall {:7.1} ms",
            r.name(),
            1e3 / c,
            (res * res) as f64 / c / 1e3,
            wall[2]
        );
    }
}
