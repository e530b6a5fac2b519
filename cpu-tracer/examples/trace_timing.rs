//! Quick timing of the single-threaded renderers on the synthetic frame, in on-CPU time of the
//! calling thread (robust on a busy machine): `cargo run --release -p volwarp-cpu-tracer
//! --example trace_timing [res] [radius_scale]`.

use std::time::Instant;
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::Scene;
use volwarp_cpu_tracer::synthetic::depth_image_frame;
use volwarp_cpu_tracer::{PacketTracer, ScalarTracer, SphereSplat};

/// Nanoseconds this thread has run (Linux `/proc/thread-self/schedstat`), if available.
fn cpu_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat").ok()?.split_whitespace().next()?.parse().ok()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let res: u32 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(1024);
    let radius: f32 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(2.0);
    let frame = depth_image_frame(1024, radius, 1);
    let scene = Scene::build(&frame);
    let cam = frame.header.camera.orbit(10.0, 0.0).with_viewport(res, res);
    let mut img = Image::new(1, 1);
    let mut rs: Vec<Box<dyn Renderer>> =
        vec![Box::new(PacketTracer::new(1)), Box::new(ScalarTracer::new(1)), Box::new(SphereSplat::new(1))];
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
            "{:15} {res}²: cpu {c:7.1} ms ({:5.2} Mrays/s)  wall {:7.1} ms",
            r.name(),
            (res * res) as f64 / c / 1e3,
            wall[2]
        );
    }
}
