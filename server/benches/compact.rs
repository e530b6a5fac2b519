//! `cargo bench -p volwarp-server --bench compact`: the compact frame encoding of a
//! 1024² MRI frame (the framing of the `server` bench, about 630k samples), on one thread:
//! building the residual planes (the fast path — AVX2 where the CPU has it —, the portable code
//! and the scalar reference), entropy coding them (the server's byte-run parse with C zstd's
//! entropy stage; the C library's own level-1 parse; ruzstd's pure-Rust encoder, core's
//! default; lz4_flex), and decoding on the client (C zstd decompression, what std clients use,
//! and ruzstd, the no_std one; reconstruction, fast, portable and reference; the whole
//! `decode_payload`), against the 12-byte form's decode. `--example compact_timing` measures
//! the same steps in on-CPU time.
//!
//! Skipped with a message when the shared data set is absent.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::hint::black_box;
use std::path::Path;
use std::time::Duration;
use volwarp_core::compact_frame::{self, Coder};
use volwarp_core::wire::{self, CameraRequest, Limits, Message, HEADER_LEN};
use volwarp_core::Heuristic;
use volwarp_server::encoding::{encode_compact, encode_options};
use volwarp_server::{Dataset, Marcher};

const MRI: &str = volwarp_server::testdata::MRI_PATH;

fn benches(c: &mut Criterion) {
    if !Path::new(MRI).exists() {
        eprintln!("volwarp-server compact bench skipped: {MRI} not found");
        return;
    }
    let ds = Dataset::load(MRI, None).expect("loading the MRI");
    let m = Marcher::from_dataset(&ds);
    let camera = m.default_camera(1024, 1024).orbit(20.0, 10.0).dolly(0.68);
    let req = CameraRequest { seq: 0, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
    let (frame, _) = m.render_frame(&req);
    let n = frame.samples.len();
    let opts = encode_options(&m, &req);
    let planes = compact_frame::build_planes(&frame, &opts).expect("the frame fits the compact form");
    let bytes = encode_compact(&frame, &opts, 1).unwrap();
    let ruz = compact_frame::compress(&planes.body, Coder::Zstd);
    let lz4 = lz4_flex::compress(&planes.body);
    let raw = wire::encode_to_vec(&Message::Frame(frame.clone()));
    eprintln!(
        "MRI 1024²: {n} samples; body {} B; server (byte-run parse + zstd) {} B ({:.3} B/sample with header), ruzstd {} B, lz4_flex {} B, raw12 {} B",
        planes.body.len(),
        bytes.len() - HEADER_LEN - compact_frame::COMPACT_FIXED_LEN,
        bytes.len() as f64 / n as f64,
        ruz.len(),
        lz4.len(),
        raw.len()
    );
    let mut g = c.benchmark_group("compact_1024_mri");
    g.sample_size(20).warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(5));
    g.throughput(Throughput::Elements(n as u64));
    // Everything below is serial code (one thread).
    {
        g.bench_function("encode_planes", |b| {
            b.iter(|| compact_frame::build_planes(black_box(&frame), &opts).unwrap())
        });
        g.bench_function("encode_planes_portable", |b| {
            b.iter(|| compact_frame::build_planes_portable(black_box(&frame), &opts).unwrap())
        });
        g.bench_function("encode_planes_reference", |b| {
            b.iter(|| compact_frame::build_planes_reference(black_box(&frame), &opts).unwrap())
        });
        g.bench_function("encode_byte_runs_zstd", |b| b.iter(|| compact_frame::compress_c(black_box(&planes.body), 1)));
        g.bench_function("encode_zstd1_library_parse", |b| {
            b.iter(|| zstd::bulk::compress(black_box(&planes.body), 1).unwrap())
        });
        g.bench_function("encode_total", |b| b.iter(|| encode_compact(black_box(&frame), &opts, 1).unwrap()));
        g.bench_function("encode_ruzstd", |b| b.iter(|| compact_frame::compress(black_box(&planes.body), Coder::Zstd)));
        g.bench_function("encode_lz4_flex", |b| b.iter(|| lz4_flex::compress(black_box(&planes.body))));
        let params = planes.params;
        g.bench_function("decode_ruzstd", |b| {
            b.iter(|| compact_frame::decompress_ruzstd(black_box(&ruz), &params).unwrap())
        });
        g.bench_function("decode_ruzstd_of_server", |b| {
            let coded = &bytes[HEADER_LEN + compact_frame::COMPACT_FIXED_LEN..];
            b.iter(|| compact_frame::decompress_ruzstd(black_box(coded), &params).unwrap())
        });
        g.bench_function("decode_czstd_of_server", |b| {
            let coded = &bytes[HEADER_LEN + compact_frame::COMPACT_FIXED_LEN..];
            b.iter(|| compact_frame::decompress_c(black_box(coded), &params).unwrap())
        });
        g.bench_function("decode_czstd_of_zstd1_library_parse", |b| {
            let coded = zstd::bulk::compress(&planes.body, 1).unwrap();
            b.iter(|| compact_frame::decompress_c(black_box(&coded), &params).unwrap())
        });
        g.bench_function("decode_lz4_flex", |b| {
            b.iter(|| lz4_flex::decompress(black_box(&lz4), planes.body.len()).unwrap())
        });
        g.bench_function("decode_body", |b| {
            b.iter(|| compact_frame::decode_body(black_box(&frame.header), &params, &planes.body).unwrap())
        });
        g.bench_function("decode_body_portable", |b| {
            b.iter(|| compact_frame::decode_body_portable(black_box(&frame.header), &params, &planes.body).unwrap())
        });
        g.bench_function("decode_body_reference", |b| {
            b.iter(|| compact_frame::decode_body_reference(black_box(&frame.header), &params, &planes.body).unwrap())
        });
        let lim = Limits::default();
        g.bench_function("decode_total", |b| {
            b.iter(|| compact_frame::decode_payload(black_box(&bytes[HEADER_LEN..]), &lim).unwrap())
        });
        g.bench_function("decode_raw12", |b| b.iter(|| wire::read_message(&mut black_box(&raw[..]), &lim).unwrap()));
    }
    g.finish();
}

criterion_group!(b, benches);
criterion_main!(b);
