//! Client draw time of the layered default against the one-sample splatter (the budget:
//! "client draw time at 512² on 1 thread ≤ 2× the one-sample splatter's for the default K"), on
//! every bundled dataset:
//!
//! ```sh
//! cargo run --release -p volwarp-eval --example layer_time -- ../shared/data [--size 512] [--runs 15] [--threads 1] [--only NAME] [--frames K] [--water-ratio R] [--watertight T] [--no-cracks]
//! ```
//!
//! With `--frames K` (the multi-frame filling) it also times the layered default keeping
//! `K` frames: the newest as above and `K − 1` older layered frames rendered 5°, 10°, … further
//! back along the orbit, which fill what the newest leaves uncovered (`LayerSplat::render_set`),
//! and what the first draw after a frame arrives costs more than the next draw of the same set,
//! once with one frame and once with `K` (the frames take turns as the newest: the one-frame
//! figure is the frame's own image, the `K`-frame one also what the newest did not see of each
//! older frame).
//!
//! Per dataset the server renders the default camera's one-sample frame (threshold heuristic)
//! and its layered frame (K = 4, the client's default); the client draws each 10° along the
//! orbit: `splat` the one-sample frame, `volwarp` the layered one with the default's options
//! (hole filling and warp-grown footprints, `LayerSplat::new` + adaptive sizing). With
//! `--threads 1` the figures are the measuring thread's on-CPU time (`CLOCK_THREAD_CPUTIME_ID`:
//! robust on a machine other builds keep busy), otherwise wall time; medians of `--runs`, the
//! two renderers alternated draw by draw so load changes hit both alike. The crack pass
//! (`layered::close_cracks`, part of every volwarp draw away from the frame's camera) is also
//! timed alone on the drawn image.

use std::time::Instant;
use volwarp_core::renderer::Renderer;
use volwarp_core::wire::CameraRequest;
use volwarp_core::{Heuristic, Image, RendererKind, Scene};
use volwarp_cpu_tracer::{create, route::unbuilt_scene, LayerSplat};
use volwarp_eval::camera_paths::orbit;
use volwarp_eval::example_args::{arg, datasets_or_exit, layer_options};
use volwarp_eval::median;
use volwarp_server::Marcher;

/// Nanoseconds this thread has run (`CLOCK_THREAD_CPUTIME_ID`), if the clock exists.
fn cpu_ns() -> Option<u64> {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid, writable timespec for the duration of the call.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    (rc == 0).then(|| ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64)
}

/// Milliseconds of one call of `f`: on-CPU time of this thread when `cpu`, else wall time.
fn ms(cpu: bool, f: impl FnOnce()) -> f64 {
    let (c0, t0) = (cpu_ns(), Instant::now());
    f();
    match (cpu, c0, cpu_ns()) {
        (true, Some(a), Some(b)) => (b - a) as f64 / 1e6,
        _ => t0.elapsed().as_secs_f64() * 1e3,
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let size: u32 = arg(&args, "--size").map_or(512, |s| s.parse().expect("a size"));
    let runs: usize = arg(&args, "--runs").map_or(15, |s| s.parse().expect("a run count"));
    let threads: usize = arg(&args, "--threads").map_or(1, |s| s.parse().expect("a thread count"));
    let layers: u32 = arg(&args, "--layers").map_or(4, |s| s.parse().expect("a layer count"));
    let frames: usize = arg(&args, "--frames").map_or(1, |s| s.parse().expect("a frame count"));
    let cpu = threads == 1;
    // Footprint options other than the default's, to time a lever (`layers`' flags:
    // `--water-ratio R`, `--watertight T`, `--no-cracks`, …).
    let lopts = layer_options(&args).expect("footprint options");
    let datasets = datasets_or_exit(&args);
    println!(
        "{size}², {threads} thread(s), {} ms, median of {runs}; volwarp = splat-layers K={layers}, fill, adaptive",
        if cpu { "on-CPU" } else { "wall" }
    );
    println!(
        "| dataset | samples K=1 | samples K={layers} | splat ms | volwarp ms | of which cracks ms | ratio | volwarp, {frames} frames kept, ms | arrival adds, 1 / {frames} frames, ms |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    let mut ratios = Vec::new();
    for ds in &datasets {
        let m = Marcher::from_dataset(ds);
        let c0 = m.default_camera(size, size);
        let req = CameraRequest { seq: 1, camera: c0, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
        let one = unbuilt_scene(&m.render_frame(&req).0);
        let lay = unbuilt_scene(&m.render_frame_layers(&req, layers).0);
        let cam = orbit(&c0, 10.0);
        let older: Vec<_> = (1..frames)
            .map(|i| {
                let req = CameraRequest { camera: orbit(&c0, -5.0 * i as f32), ..req };
                unbuilt_scene(&m.render_frame_layers(&req, layers).0)
            })
            .collect();
        let set: Vec<_> = core::iter::once(&lay).chain(older.iter()).collect();
        let mut kept = LayerSplat::with_options(threads, lopts);
        kept.set_adaptive_radius(true);
        let mut c = Image::new(0, 0);
        kept.render_set(&set, &cam, &mut c);
        let mut splat = create(RendererKind::Splat, threads).expect("the CPU splatter");
        let mut volwarp = LayerSplat::with_options(threads, lopts);
        volwarp.set_adaptive_radius(true);
        let (mut a, mut b) = (Image::new(0, 0), Image::new(0, 0));
        // Warm-up: the layered renderer composites the frame's own image once per frame.
        splat.render(&one, &cam, &mut a);
        volwarp.render(&lay, &cam, &mut b);
        let (mut ta, mut tb, mut tc) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..runs {
            ta.push(ms(cpu, || splat.render(&one, &cam, &mut a)));
            tb.push(ms(cpu, || volwarp.render(&lay, &cam, &mut b)));
            if frames > 1 {
                tc.push(ms(cpu, || kept.render_set(&set, &cam, &mut c)));
            }
        }
        // The crack pass alone (`layered::close_cracks`, part of the volwarp draw) on the drawn
        // image, the same thread count.
        let crack_threads = volwarp_cpu_tracer::Threads::new(threads);
        let (mut scratch, mut td) = (volwarp_cpu_tracer::layered::CrackScratch::default(), Vec::new());
        for _ in 0..runs {
            let mut px = b.pixels.clone();
            let (w, h) = (b.width as usize, b.height as usize);
            td.push(ms(cpu, || volwarp_cpu_tracer::layered::close_cracks(&mut px, w, h, &mut scratch, &crack_threads)));
        }
        let cracks = median(&mut td).unwrap_or(f64::NAN);
        let (sa, sb) = (median(&mut ta).unwrap_or(f64::NAN), median(&mut tb).unwrap_or(f64::NAN));
        let sc = if frames > 1 { median(&mut tc).unwrap_or(f64::NAN) } else { sb };
        // Arrivals: each draw has another newest frame.
        let (mut t1, mut tk) = (Vec::new(), Vec::new());
        for r in 0..runs {
            // As in the client: the previous newest is now the first older frame.
            let rot: Vec<&Scene> = (0..set.len()).map(|j| set[(r + set.len() - j) % set.len()]).collect();
            // What the arrival adds: the first draw of the new set less the next one, the same.
            let first = ms(cpu, || volwarp.render(rot[0], &cam, &mut b));
            t1.push(first - ms(cpu, || volwarp.render(rot[0], &cam, &mut b)));
            let first = ms(cpu, || kept.render_set(&rot, &cam, &mut c));
            tk.push(first - ms(cpu, || kept.render_set(&rot, &cam, &mut c)));
        }
        let (a1, ak) = (median(&mut t1).unwrap_or(f64::NAN), median(&mut tk).unwrap_or(f64::NAN));
        ratios.push(sb / sa);
        println!(
            "| {} | {} | {} | {sa:.2} | {sb:.2} | {cracks:.2} | {:.2}× | {sc:.2} | {a1:.2} / {ak:.2} |",
            ds.name,
            one.samples.len(),
            lay.samples.len(),
            sb / sa
        );
    }
    println!("ratio median over datasets: {:.2}×", median(&mut ratios).unwrap_or(f64::NAN));
}
