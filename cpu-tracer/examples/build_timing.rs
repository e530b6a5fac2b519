//! Timing of the parallel LBVH build alone on the MRI frame (or the synthetic one without
//! `../shared`): median wall time and per-step breakdown over many builds, reusing buffers:
//! `cargo run --release -p volwarp-cpu-tracer --example build_timing [threads] [builds]`.

use std::time::Instant;
use volwarp_core::Scene;
use volwarp_cpu_tracer::synthetic::depth_image_frame;
use volwarp_cpu_tracer::{BuildTimes, ParallelBuilder};

#[path = "../benches/support/frames.rs"]
mod frames;

fn median(mut v: Vec<f64>) -> f64 {
    volwarp_core::stats::median(&mut v).unwrap_or(f64::NAN)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let threads: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(2);
    let builds: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(41).max(1);
    let frame = frames::mri_frame(1024).map(|f| f.0).unwrap_or_else(|| depth_image_frame(1024, 2.0, 1));
    let reference = Scene::build(&frame);
    let mut b = ParallelBuilder::new(threads);
    let mut sc = b.build(&frame);
    assert!(sc.nodes == reference.nodes && sc.samples == reference.samples && sc.colors == reference.colors);
    let (mut wall, mut times) = (Vec::new(), Vec::<BuildTimes>::new());
    for _ in 0..builds {
        let w = Instant::now();
        b.build_into(&frame, &mut sc);
        wall.push(w.elapsed().as_secs_f64() * 1e3);
        times.push(b.last_times());
    }
    let step = |f: fn(&BuildTimes) -> u64| median(times.iter().map(|t| f(t) as f64 / 1e3).collect());
    println!(
        "{} samples, {threads} threads, {builds} builds: median wall {:.2} ms (min {:.2}); steps (median ms): \
         keys {:.2}, sort {:.2}, gather {:.2}, hierarchy {:.2}, fit {:.2}",
        frame.samples.len(),
        median(wall.clone()),
        wall.iter().copied().fold(f64::INFINITY, f64::min),
        step(|t| t.keys_us),
        step(|t| t.sort_us),
        step(|t| t.gather_us),
        step(|t| t.hierarchy_us),
        step(|t| t.fit_us),
    );
}
