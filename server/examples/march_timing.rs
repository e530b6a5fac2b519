//! `cargo run --release -p volwarp-server --example march_timing -- [N] [SIZE] [DATASET]`:
//! marches the MRI benchmark view (the `server` bench's camera) N times and prints the median
//! wall and on-CPU (process CPU time, all threads) milliseconds; `RAYON_NUM_THREADS` picks the
//! threads, `VOLWARP_LANES` (`portable`, `avx2`, `avx512`) the widest lanes the packet marcher
//! may use, `VOLWARP_MARCH_LAYERS=K` (K > 1) the layered frame of K segments per pixel as the
//! server makes it (march, segments, pack; the split printed), `VOLWARP_MARCH_SHADE=1` with
//! gradient shading (`Shading::DEFAULT`), `VOLWARP_MARCH_SHADE=both` unshaded and shaded runs
//! alternated in one process (both medians printed). A steadier figure than
//! criterion's on a shared machine, and a loop to profile.

use std::time::Instant;
use volwarp_core::wire::CameraRequest;
use volwarp_core::Heuristic;
use volwarp_server::marcher::Shading;
use volwarp_server::{Dataset, MarchOptions, Marcher};

/// Process CPU time (all threads) in ms.
fn cpu_ms() -> f64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: a valid, writable timespec.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 * 1e3 + ts.tv_nsec as f64 / 1e6
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(5);
    let size: u32 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1024);
    let path = args.get(3).cloned().unwrap_or_else(|| volwarp_server::testdata::MRI_PATH.to_string());
    volwarp_server::limit_lanes_from_env();
    let ds = Dataset::load(&path, None).expect("loading the volume");
    let plain = Marcher::from_dataset(&ds);
    let shaded =
        plain.with_transfer_function(&ds.tf, MarchOptions { shading: Some(Shading::DEFAULT), ..plain.options() });
    let which = std::env::var("VOLWARP_MARCH_SHADE").unwrap_or_default();
    let marchers: Vec<(&str, &Marcher)> = match which.as_str() {
        "1" => vec![("shaded", &shaded)],
        "both" => vec![("unshaded", &plain), ("shaded", &shaded)],
        _ => vec![("unshaded", &plain)],
    };
    let camera = plain.default_camera(size, size).orbit(20.0, 10.0).dolly(0.68);
    // `VOLWARP_MARCH_LAYERS=K` (K > 1): the layered frame of K segments per pixel instead.
    let layers: u32 = std::env::var("VOLWARP_MARCH_LAYERS").ok().and_then(|s| s.parse().ok()).unwrap_or(1);
    let req0 = CameraRequest { seq: 1, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
    let mut frame = plain.render_frame(&req0).0;
    let mut wall = vec![Vec::new(); marchers.len()];
    let mut cpu = vec![Vec::new(); marchers.len()];
    let mut split = Vec::new();
    let mut samples = 0;
    for _ in 0..n {
        for (i, (_, m)) in marchers.iter().enumerate() {
            let (w0, c0) = (Instant::now(), cpu_ms());
            if layers > 1 {
                // The layered frame as the server makes it: the march with its segments and the pack.
                let st = m.render_frame_layers_into(&req0, layers, &mut frame);
                samples = frame.samples.len();
                split.push((st.march_us as f64 / 1e3, st.compact_us as f64 / 1e3));
            } else {
                let s = m.march(&camera, Heuristic::Threshold);
                samples = s.t.iter().filter(|t| t.is_finite()).count();
            }
            cpu[i].push(cpu_ms() - c0);
            wall[i].push(w0.elapsed().as_secs_f64() * 1e3);
        }
    }
    for (i, (label, _)) in marchers.iter().enumerate() {
        println!(
            "{path} {size}², K = {layers}, {label}, {:?} lanes: {samples} samples, wall {:.1} ms, cpu {:.1} ms (medians of {n})",
            volwarp_server::lane_kind(),
            median(wall[i].clone()),
            median(cpu[i].clone())
        );
    }
    if !split.is_empty() {
        let march = median(split.iter().map(|s| s.0).collect());
        let gather = median(split.iter().map(|s| s.1).collect());
        println!("  of which the march (segments and pack included) {march:.1} ms, gathering the frame {gather:.1} ms");
    }
}
