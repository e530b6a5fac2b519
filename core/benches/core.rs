//! `cargo bench -p volwarp-core`: the serial LBVH build over 623,584 samples from a
//! depth-image-like surface on a 1024×1024 grid (the paper's count), wire encode/decode
//! throughput, and the packing of layered colors over 100,000 pseudo-random rays of 1–4
//! segments, one ray at a time (`segments::pack_colors`) and eight side by side
//! (`segments::pack_colors_lanes`, the same colors).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use std::hint::black_box;
use volwarp_core::camera::Camera;
use volwarp_core::heuristics::Heuristic;
use volwarp_core::sample::{pack_color, Bounds, Quantizer};
use volwarp_core::segments::{composite, pack_colors, pack_colors_lanes, Segment, MAX_LAYERS};
use volwarp_core::wire::{self, Frame, FrameHeader, Limits, Message};
use volwarp_core::{Scene, Vec3};

/// The paper's sample count after compaction.
const PAPER_SAMPLES: usize = 623_584;

/// A bumpy height field seen from the front on a 1024² grid, keeping the first
/// `PAPER_SAMPLES` pixels inside a disc (pixel order, like a compacted server frame).
fn depth_image_frame() -> Frame {
    let n = 1024usize;
    let b = Bounds::new(Vec3::ZERO, Vec3::new(1.0, 1.0, 0.3));
    let radius = 0.5 * 1.732 / n as f32;
    let radius_unit = radius / 1023.0;
    let q = Quantizer::new(b, radius_unit);
    let mut samples = Vec::with_capacity(PAPER_SAMPLES);
    let mut colors = Vec::with_capacity(PAPER_SAMPLES);
    'outer: for y in 0..n {
        for x in 0..n {
            let (u, v) = ((x as f32 + 0.5) / n as f32, (y as f32 + 0.5) / n as f32);
            let (du, dv) = (u - 0.5, v - 0.5);
            if du * du + dv * dv > 0.2 {
                continue;
            }
            let h = 0.15 + 0.1 * (u * 23.0).sin() * (v * 17.0).cos() + 0.03 * (u * 97.0 + v * 41.0).sin();
            samples.push(q.pack(Vec3::new(u, 1.0 - v, h), radius));
            colors.push(pack_color((u * 255.0) as u8, (v * 255.0) as u8, 128, 255));
            if samples.len() == PAPER_SAMPLES {
                break 'outer;
            }
        }
    }
    let camera = Camera::look_at(Vec3::new(0.5, 0.5, 3.0), Vec3::new(0.5, 0.5, 0.15), Vec3::Y, 20.0, 1024, 1024);
    Frame {
        header: FrameHeader {
            seq: 1,
            camera,
            heuristic: Heuristic::Threshold,
            bounds: b,
            radius_unit,
            render_us: 0,
            level: 0,
            count: samples.len() as u32,
        },
        samples,
        colors,
        segments: Vec::new(),
    }
}

/// `n` pseudo-random rays of 1–4 segments (premultiplied colors) and their composites.
fn random_rays(n: usize) -> Vec<(Vec<Segment>, [f32; 4])> {
    let mut state = 0x2545_F491_4F6C_DD1Du64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    (0..n)
        .map(|_| {
            let k = 1 + (next() * 4.0) as usize % 4;
            let segs: Vec<Segment> = (0..k)
                .map(|j| {
                    let a = next();
                    Segment { t: j as f32, color: [next() * a, next() * a, next() * a, a] }
                })
                .collect();
            let ray = composite(segs.iter().map(|s| s.color));
            (segs, ray)
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let rays = random_rays(100_000);
    let mut g = c.benchmark_group("pack_colors");
    g.sample_size(20);
    g.throughput(Throughput::Elements(rays.len() as u64));
    g.bench_function("rays_1_to_4_segments", |b| {
        let mut out = [0u32; 4];
        b.iter(|| {
            let mut sum = 0u32;
            for (segs, ray) in &rays {
                pack_colors(black_box(segs), *ray, &mut out[..segs.len()]);
                sum = sum.wrapping_add(out[0]);
            }
            black_box(sum)
        })
    });
    g.bench_function("rays_1_to_4_segments_lanes", |b| {
        let lists: Vec<&[Segment]> = rays.iter().map(|(s, _)| &s[..]).collect();
        let colors: Vec<[f32; 4]> = rays.iter().map(|(_, r)| *r).collect();
        let mut out = vec![[0u32; MAX_LAYERS]; rays.len()];
        b.iter(|| {
            pack_colors_lanes(black_box(&lists), &colors, &mut out);
            black_box(out[0][0])
        })
    });
    g.finish();

    let frame = depth_image_frame();
    eprintln!("samples: {}", frame.samples.len());
    let mut g = c.benchmark_group("lbvh");
    g.sample_size(10);
    g.throughput(Throughput::Elements(frame.samples.len() as u64));
    g.bench_function(BenchmarkId::new("serial_build", frame.samples.len()), |b| {
        b.iter(|| black_box(Scene::build(black_box(&frame))))
    });
    g.finish();

    let msg = Message::Frame(frame);
    let bytes = wire::encode_to_vec(&msg);
    let mut g = c.benchmark_group("wire");
    g.sample_size(20);
    g.throughput(Throughput::Bytes(bytes.len() as u64));
    let mut buf = Vec::with_capacity(bytes.len());
    g.bench_function("encode_frame", |b| {
        b.iter(|| {
            buf.clear();
            wire::write_message(&mut wire::VecWriter(&mut buf), black_box(&msg)).unwrap();
            black_box(buf.len())
        })
    });
    g.bench_function("decode_frame", |b| {
        b.iter(|| black_box(wire::read_message(&mut black_box(&bytes[..]), &Limits::default()).unwrap()))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
