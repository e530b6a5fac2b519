//! Every step of the compact frame codec on the 1024² MRI bench frame, as
//! on-CPU time of the one measuring thread (`CLOCK_THREAD_CPUTIME_ID`: robust on a machine
//! other builds keep busy, where wall time is mostly waiting for a core):
//!
//! ```sh
//! cargo run --release -p volwarp-server --example compact_timing -- [RUNS]   # default 15
//! ```
//!
//! Prints the median of `RUNS` for the fast paths and the scalar references they replace
//! (planes, reconstruction) and the portable code, the entropy coders (the server's byte-run
//! parse with C zstd's entropy stage, the library's own level 1 for comparison; C zstd and
//! ruzstd decompression; lz4_flex for comparison), the whole encode and decode, and the 12-byte
//! form's decode; then bytes per sample. The frame is the `compact` bench's
//! (`cargo bench -p volwarp-server --bench compact`, which measures wall time).

use std::hint::black_box;
use std::time::Instant;
use volwarp_core::compact_frame;
use volwarp_core::wire::{self, CameraRequest, Limits, Message, HEADER_LEN};
use volwarp_core::Heuristic;
use volwarp_server::encoding::{encode_compact, encode_options, ZSTD_LEVEL};
use volwarp_server::{Dataset, Marcher};

const MRI: &str = volwarp_server::testdata::MRI_PATH;

/// Nanoseconds this thread has run (`CLOCK_THREAD_CPUTIME_ID`), if the clock exists.
fn cpu_ns() -> Option<u64> {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid, writable timespec for the duration of the call.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    (rc == 0).then(|| ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64)
}

/// Median on-CPU (or, without schedstat, wall) milliseconds of `runs` calls of `f`.
fn median_ms<R>(runs: usize, mut f: impl FnMut() -> R) -> f64 {
    black_box(f());
    let mut v: Vec<f64> = (0..runs)
        .map(|_| {
            let (c0, t0) = (cpu_ns(), Instant::now());
            black_box(f());
            match (c0, cpu_ns()) {
                (Some(a), Some(b)) => (b - a) as f64 / 1e6,
                _ => t0.elapsed().as_secs_f64() * 1e3,
            }
        })
        .collect();
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let runs: usize = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(15);
    let Ok(ds) = Dataset::load(MRI, None) else {
        eprintln!("compact_timing: {MRI} not found");
        return;
    };
    let m = Marcher::from_dataset(&ds);
    let camera = m.default_camera(1024, 1024).orbit(20.0, 10.0).dolly(0.68);
    let req = CameraRequest { seq: 0, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
    let (frame, _) = m.render_frame(&req);
    let n = frame.samples.len();
    let opts = encode_options(&m, &req);
    let planes = compact_frame::build_planes(&frame, &opts).expect("the frame fits the compact form");
    assert_eq!(Ok(&planes), compact_frame::build_planes_reference(&frame, &opts).as_ref());
    let params = planes.params;
    let bytes = encode_compact(&frame, &opts, ZSTD_LEVEL).expect("compact");
    let coded = &bytes[HEADER_LEN + compact_frame::COMPACT_FIXED_LEN..];
    let lz4 = lz4_flex::compress(&planes.body);
    let raw = wire::encode_to_vec(&Message::Frame(frame.clone()));
    let lim = Limits::default();
    let ms_per = |ms: f64| n as f64 / ms / 1e3;
    println!(
        "MRI 1024²: {n} samples, body {} B, byte-run parse + zstd entropy level {ZSTD_LEVEL} {} B ({:.3} B/sample with headers), lz4_flex {} B, raw12 {} B",
        planes.body.len(),
        coded.len(),
        bytes.len() as f64 / n as f64,
        lz4.len(),
        raw.len()
    );
    println!("on-CPU ms (one thread), median of {runs}:");
    let row = |name: &str, ms: f64| println!("  {name:<52} {ms:8.2} ms  {:7.1} M samples/s", ms_per(ms));
    row("planes (build_planes, fast)", median_ms(runs, || compact_frame::build_planes(&frame, &opts)));
    row("planes (build_planes_portable)", median_ms(runs, || compact_frame::build_planes_portable(&frame, &opts)));
    row("planes (build_planes_reference)", median_ms(runs, || compact_frame::build_planes_reference(&frame, &opts)));
    row("byte-run parse (run_sequences)", median_ms(runs, || volwarp_core::byte_runs::run_sequences(&planes.body)));
    row(
        "C zstd, byte-run parse, compress (the server's)",
        median_ms(runs, || compact_frame::compress_c(&planes.body, ZSTD_LEVEL)),
    );
    let lib1 = zstd::bulk::compress(&planes.body, 1).expect("zstd");
    row(
        &format!(
            "C zstd level 1 compress ({} B, {:.3} B/sample)",
            lib1.len(),
            (HEADER_LEN + compact_frame::COMPACT_FIXED_LEN + lib1.len()) as f64 / n as f64
        ),
        median_ms(runs, || zstd::bulk::compress(&planes.body, 1)),
    );
    row("C zstd level 1 decompress", median_ms(runs, || compact_frame::decompress_c(&lib1, &params)));
    row("lz4_flex compress", median_ms(runs, || lz4_flex::compress(&planes.body)));
    // Other zstd levels: size, compression and (C) decompression time.
    for level in [-4, -1, 3] {
        let z = zstd::bulk::compress(&planes.body, level).expect("zstd");
        let bps = (HEADER_LEN + compact_frame::COMPACT_FIXED_LEN + z.len()) as f64 / n as f64;
        row(
            &format!("C zstd level {level} compress ({} B, {bps:.3} B/sample)", z.len()),
            median_ms(runs, || zstd::bulk::compress(&planes.body, level)),
        );
        row(&format!("C zstd level {level} decompress"), median_ms(runs, || compact_frame::decompress_c(&z, &params)));
    }
    row("encode total (encode_compact)", median_ms(runs, || encode_compact(&frame, &opts, ZSTD_LEVEL)));
    row("ruzstd decompress", median_ms(runs, || compact_frame::decompress_ruzstd(coded, &params)));
    row("decompress (the build's: C zstd with std)", median_ms(runs, || compact_frame::decompress(coded, &params)));
    row("lz4_flex decompress", median_ms(runs, || lz4_flex::decompress(&lz4, planes.body.len())));
    row(
        "reconstruct (decode_body, fast)",
        median_ms(runs, || compact_frame::decode_body(&frame.header, &params, &planes.body)),
    );
    row(
        "reconstruct (decode_body_portable)",
        median_ms(runs, || compact_frame::decode_body_portable(&frame.header, &params, &planes.body)),
    );
    row(
        "reconstruct (decode_body_reference)",
        median_ms(runs, || compact_frame::decode_body_reference(&frame.header, &params, &planes.body)),
    );
    row("decode total (decode_payload)", median_ms(runs, || compact_frame::decode_payload(&bytes[HEADER_LEN..], &lim)));
    row("12-byte read_message", median_ms(runs, || wire::read_message(&mut &raw[..], &lim)));
}
