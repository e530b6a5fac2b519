//! `cargo bench -p volwarp-server`: march the MRI head of `../shared/data` at 1024² and 512²
//! (framed to fill most of the view, threshold heuristic), render a whole frame, and compact
//! the 1024² frame's packed samples (the seed paper compacted serially in 23 ms): in parallel
//! into fresh vectors, in parallel into reused ones (what the server does per frame), and core's
//! serial `compact_in_place`.
//!
//! Skipped with a message when the shared data set is absent.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::hint::black_box;
use std::path::Path;
use std::time::Duration;
use volwarp_core::wire::CameraRequest;
use volwarp_core::Heuristic;
use volwarp_server::compaction::{compact, compact_into_vecs};
use volwarp_server::{Dataset, Marcher};

const MRI: &str = volwarp_server::testdata::MRI_PATH;

/// Dolly factor of the default camera that makes the head fill most of the view (about 620k
/// samples at 1024², like the seed paper's frames).
const ZOOM: f32 = 0.68;

fn request(m: &Marcher, size: u32) -> CameraRequest {
    let camera = m.default_camera(size, size).orbit(20.0, 10.0).dolly(ZOOM);
    CameraRequest { seq: 0, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 }
}

fn benches(c: &mut Criterion) {
    if !Path::new(MRI).exists() {
        eprintln!("volwarp-server bench skipped: {MRI} not found");
        return;
    }
    let ds = Dataset::load(MRI, None).expect("loading the MRI");
    let m = Marcher::from_dataset(&ds);
    let mut g = c.benchmark_group("march");
    g.sample_size(10).warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(8));
    for size in [1024u32, 512] {
        let req = request(&m, size);
        let (frame, stats) = m.render_frame(&req);
        eprintln!(
            "mri {size}x{size}: {} samples ({:.1} % of the pixels), march {:.1} ms",
            frame.samples.len(),
            100.0 * frame.samples.len() as f64 / (size * size) as f64,
            stats.march_us as f64 / 1e3
        );
        g.throughput(Throughput::Elements(frame.samples.len() as u64));
        g.bench_function(format!("mri_{size}"), |b| b.iter(|| black_box(m.march(&req.camera, req.heuristic))));
        g.bench_function(format!("frame_{size}"), |b| b.iter(|| black_box(m.render_frame(&req))));
    }
    g.finish();

    let req = request(&m, 1024);
    let pb = m.march(&req.camera, req.heuristic);
    let (samples, _) = m.quantize(&req, &pb);
    let mut g = c.benchmark_group("compaction");
    g.throughput(Throughput::Elements(samples.len() as u64));
    g.bench_function("parallel_1024", |b| b.iter(|| black_box(compact(&samples, &pb.color))));
    let (mut s, mut col) = (Vec::new(), Vec::new());
    g.bench_function("parallel_reuse_1024", |b| {
        b.iter(|| black_box(compact_into_vecs(&samples, &pb.color, &mut s, &mut col)))
    });
    g.bench_function("serial_1024", |b| {
        b.iter_batched_ref(
            || (samples.clone(), pb.color.clone()),
            |(s, c)| black_box(volwarp_core::compaction::compact_in_place(s, c)),
            criterion::BatchSize::LargeInput,
        )
    });
    g.finish();
}

criterion_group!(server, benches);
criterion_main!(server);
