//! `cargo run --release -p volwarp-server --example big_volume -- FILE [SIZE] [BUDGET_MS]`: a
//! big volume end to end on this machine, the figures of `docs/perf.md`'s big-volume tables:
//!
//! 1. the load (bricks) and the empty-space grid: seconds and bytes;
//! 2. the levels of detail (`Marcher::levels`): seconds and bytes;
//! 3. the benchmark view at SIZE² (default 1024; the default camera orbited 20°/10°, zoom
//!    0.68), the volume itself, median of 3;
//! 4. a moving camera through the server's render queue with a BUDGET_MS frame budget (default
//!    50): twelve orbit steps of 2°, each frame's level and time, then the camera at rest;
//! 5. time per sample without skipping or early termination (every sample in the box taken), the
//!    cost the marcher pays per sample at this size.
//!
//! `RAYON_NUM_THREADS` picks the threads; `VOLWARP_LANES` the lanes.

use std::time::{Duration, Instant};
use volwarp_core::wire::CameraRequest;
use volwarp_core::Heuristic;
use volwarp_server::empty_space::MinMaxGrid;
use volwarp_server::render_queue::{LevelPolicy, RenderQueue};
use volwarp_server::{Dataset, MarchOptions, Marcher};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn gib(b: u64) -> f64 {
    b as f64 / (1u64 << 30) as f64
}

fn main() {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    volwarp_server::limit_lanes_from_env();
    let args: Vec<String> = std::env::args().collect();
    let Some(path) = args.get(1).cloned() else {
        eprintln!("usage: big_volume FILE [SIZE] [BUDGET_MS]");
        std::process::exit(2);
    };
    let size: u32 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1024);
    let budget_ms: f64 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(50.0);
    let threads = rayon::current_num_threads();

    let t = Instant::now();
    let ds = Dataset::load(&path, None).expect("loading the volume");
    let load_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let m = Marcher::from_dataset(&ds);
    let marcher_s = t.elapsed().as_secs_f64();
    let grid = MinMaxGrid::new(&ds.volume);
    let d = ds.volume.dims();
    println!(
        "{path}: {}x{}x{} {}, {} threads, {:?} lanes",
        d[0],
        d[1],
        d[2],
        ds.volume.voxels().type_name(),
        threads,
        volwarp_server::lane_kind()
    );
    println!(
        "load (bricks) {load_s:.2} s, marcher (grid + occupancy) {marcher_s:.2} s; bricks {:.3} GiB, grid ranges {:.3} GiB",
        gib(ds.volume.memory_bytes()),
        gib(std::mem::size_of_val(grid.ranges()) as u64)
    );
    drop(grid);

    let t = Instant::now();
    let levels = m.levels(&ds.tf).expect("building the levels");
    let levels_s = t.elapsed().as_secs_f64();
    let extra: u64 = levels[1..].iter().map(|l| l.volume().memory_bytes()).sum();
    println!(
        "levels: {} ({}), built in {levels_s:.2} s ({:.2} s per GiB of bricks), +{:.3} GiB ({:.1} %)",
        levels.len(),
        levels.iter().map(|l| l.volume().dims()[0].to_string()).collect::<Vec<_>>().join(", "),
        levels_s / gib(ds.volume.memory_bytes()),
        gib(extra),
        extra as f64 * 100.0 / ds.volume.memory_bytes() as f64
    );

    let view = |yaw: f32| m.default_camera(size, size).orbit(20.0 + yaw, 10.0).dolly(0.68);
    let req = |seq: u64, yaw: f32| CameraRequest {
        seq,
        camera: view(yaw),
        heuristic: Heuristic::Threshold,
        radius_scale: 1.0,
        layers: 0,
    };
    let mut rest = Vec::new();
    for i in 0..3 {
        let t = Instant::now();
        let (f, _) = m.render_frame(&req(i, 0.0));
        rest.push(t.elapsed().as_secs_f64() * 1e3);
        std::hint::black_box(f);
    }
    println!("the view at {size}², the volume itself: {:.1} ms (median of 3)", median(rest));

    let pool = rayon::ThreadPoolBuilder::new().build().expect("a thread pool");
    let policy = LevelPolicy { budget: Some(Duration::from_secs_f64(budget_ms / 1e3)) };
    let queue = RenderQueue::with_levels(levels.clone(), policy, pool);
    let mut frame = m.empty_frame();
    let mut line = String::new();
    let mut seq = 10;
    let mut moving_ms = Vec::new();
    // The first frame is at rest (it measures level 0), then twelve moving steps, then rest.
    for (step, moving) in std::iter::once((0, false)).chain((1..=12).map(|s| (s, true))).chain([(12, false)]) {
        seq += 1;
        let t = Instant::now();
        queue.render_view(&req(seq, step as f32 * 2.0), 1, moving, &mut frame);
        let ms = t.elapsed().as_secs_f64() * 1e3;
        if moving {
            moving_ms.push(ms);
        }
        line += &format!(" {}{}:{ms:.0}", if moving { "" } else { "rest " }, frame.header.level);
    }
    println!(
        "budget {budget_ms} ms, level:ms per frame:{line}; moving frames median {:.1} ms, max {:.1} ms",
        median(moving_ms.clone()),
        moving_ms.iter().copied().fold(0.0, f64::max)
    );

    let plain = MarchOptions { skip_empty: false, early_termination: 2.0, ..MarchOptions::default() };
    let all = m.with_transfer_function(&ds.tf, plain);
    let cam = view(0.0);
    let samples = all.box_samples(&cam);
    let t = Instant::now();
    std::hint::black_box(all.march(&cam, Heuristic::Threshold));
    let s = t.elapsed().as_secs_f64();
    println!(
        "every sample in the box: {samples} samples in {:.1} ms, {:.2} ns per sample ({:.2} ns x threads)",
        s * 1e3,
        s * 1e9 / samples as f64,
        s * 1e9 * threads as f64 / samples as f64
    );
}
