//! The fast paths of the compact codec (`core/src/compact_fast.rs`) against the simple scalar
//! references they replace: the same planes (bytes and parameters) or the same error from the
//! encoder, the same frame (every bit) or the same error from the decoder, on random frames,
//! random bodies and frames that break the encoder's rules.

use proptest::prelude::*;
use volwarp_core::camera::Camera;
use volwarp_core::compact_frame::{
    build_planes, build_planes_portable, build_planes_reference, decode_body, decode_body_portable,
    decode_body_reference, CompactParams, EncodeError, EncodeOptions, RadiusPrediction,
};
use volwarp_core::heuristics::Heuristic;
use volwarp_core::sample::{self, Bounds, Quantizer};
use volwarp_core::wire::{Frame, FrameHeader};
use volwarp_core::Vec3;

/// A tiny deterministic generator (xorshift) so a failing case replays from its seed.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn f(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n.max(1)
    }
}

/// A frame as a server makes one: samples on their pixels' rays at a smooth depth with noise
/// and steps, pixels dropped at random (`hole` in 0..=1, in runs and alone), colors smooth
/// with noise, radius codes from a footprint model with some off it.
fn random_frame(seed: u64, w: u32, h: u32, hole: f32) -> (Frame, RadiusPrediction) {
    let mut rng = Rng(seed | 1);
    let bounds = Bounds::new(Vec3::new(-1.0, -0.7, -0.9), Vec3::new(1.2, 0.8, 1.0));
    let yaw = rng.f() * 360.0;
    let pitch = rng.f() * 60.0 - 30.0;
    let cam = Camera::framing(bounds.min(), bounds.max(), yaw, pitch, 20.0 + rng.f() * 40.0, w, h);
    let basis = cam.ray_basis();
    let (_, _, fwd) = cam.basis();
    let per_depth = 1.5 * Vec3::from_slice(&basis.du[..3]).length();
    let unit = per_depth * 8.0 / sample::RADIUS_MAX as f32;
    let q = Quantizer::new(bounds, unit);
    let (mut samples, mut colors) = (Vec::new(), Vec::new());
    let mut run = 0u32;
    for y in 0..h {
        for x in 0..w {
            if run > 0 {
                run -= 1;
                continue;
            }
            if rng.f() < hole {
                run = rng.below(2 * w as u64) as u32 * (rng.below(4) == 0) as u32;
                continue;
            }
            let r = basis.ray(x, y);
            // Inside the bounds: between where the ray enters and leaves them.
            let (mut t0, mut t1) = (0.0f32, f32::INFINITY);
            for k in 0..3 {
                let inv = 1.0 / r.dir[k];
                let (a, b) = ((bounds.min[k] - r.origin[k]) * inv, (bounds.max[k] - r.origin[k]) * inv);
                t0 = t0.max(a.min(b));
                t1 = t1.min(a.max(b));
            }
            if t0.partial_cmp(&t1) != Some(std::cmp::Ordering::Less) {
                continue;
            }
            let smooth = 0.5 + (x as f32 * 0.05).sin() * 0.2 + (y as f32 * 0.03).cos() * 0.15;
            let step = if (x / 9 + y / 7) % 5 == 0 { 0.1 } else { 0.0 };
            let frac = (smooth + step + (rng.f() - 0.5) * 0.01).clamp(0.01, 0.99);
            let t = t0 + (t1 - t0) * frac;
            let p = r.at(t);
            let mut radius = per_depth * (t * r.dir.dot(fwd));
            if rng.below(50) == 0 {
                radius *= 0.5 + rng.f() * 3.0;
            }
            samples.push(q.pack(p, radius));
            let base = |k: u32| ((x * (3 + k) + y * (5 - k)) % 200) as f32;
            let mut c = |k: u32| (base(k) + rng.f() * 20.0) as u8;
            colors.push(sample::pack_color(c(0), c(1), c(2), 55 + c(3) / 2));
        }
    }
    let header = FrameHeader {
        seq: seed,
        camera: cam,
        heuristic: Heuristic::Threshold,
        bounds,
        radius_unit: unit,
        render_us: 5,
        level: 0,
        count: samples.len() as u32,
    };
    (Frame { header, samples, colors, segments: Vec::new() }, RadiusPrediction { constant: 0.0, per_depth })
}

/// The fast encoder gives the reference's planes, and the fast decoder the reference's frame
/// from them; whether the frame was encodable.
fn check_frame(frame: &Frame, opts: &EncodeOptions) -> bool {
    let fast = build_planes(frame, opts);
    let slow = build_planes_reference(frame, opts);
    assert_eq!(fast, slow, "encoders differ");
    // The portable code too (on an AVX2 machine the fast path above is the AVX2 one).
    assert_eq!(build_planes_portable(frame, opts), slow, "portable encoder differs");
    if let Ok(p) = fast {
        let h = FrameHeader { count: frame.samples.len() as u32, ..frame.header };
        let a = decode_body(&h, &p.params, &p.body).expect("the fast decoder refused a body");
        let b = decode_body_reference(&h, &p.params, &p.body).expect("the reference refused a body");
        assert!(a == b, "decoders differ");
        assert!(decode_body_portable(&h, &p.params, &p.body).as_ref() == Ok(&b), "portable decoder differs");
        assert_eq!(a.colors, frame.colors);
        return true;
    }
    false
}

#[test]
fn fast_codec_equals_the_reference_on_random_frames() {
    let mut encoded = 0;
    for seed in 1..40u64 {
        let mut rng = Rng(seed * 7919);
        let (w, h) = (1 + rng.below(140) as u32, 1 + rng.below(90) as u32);
        let hole = [0.0, 0.02, 0.3, 0.7, 0.97][rng.below(5) as usize];
        let (frame, model) = random_frame(seed, w, h, hole);
        for radius in [Some(model), None, Some(RadiusPrediction { constant: 0.01, per_depth: 0.0 })] {
            for depth_bits in [12, 4, 16] {
                encoded +=
                    check_frame(&frame, &EncodeOptions { radius, depth_bits, ..EncodeOptions::default() }) as u32;
            }
        }
    }
    assert_eq!(encoded, 39 * 9, "every random frame is encodable");
}

#[test]
fn fast_codec_equals_the_reference_on_a_large_frame() {
    let (frame, model) = random_frame(99, 640, 480, 0.002);
    assert!(frame.samples.len() > 50_000, "{}", frame.samples.len());
    assert!(check_frame(&frame, &EncodeOptions { radius: Some(model), ..EncodeOptions::default() }));
}

#[test]
fn fast_encoder_gives_the_reference_error_for_frames_off_the_rules() {
    let (frame, model) = random_frame(5, 64, 48, 0.1);
    let opts = EncodeOptions { radius: Some(model), ..EncodeOptions::default() };
    let n = frame.samples.len();
    // Two samples swapped (out of pixel order), one duplicated (two on a pixel), one moved far
    // off its pixel, and colors of another length.
    let mut swapped = frame.clone();
    swapped.samples.swap(n / 2, n / 2 + 1);
    let mut dup = frame.clone();
    dup.samples[n / 3] = dup.samples[n / 3 - 1];
    let mut moved = frame.clone();
    moved.samples[n - 5] ^= 0x3_0000;
    let mut short = frame.clone();
    short.colors.pop();
    for (name, f) in [("swapped", &swapped), ("duplicated", &dup), ("moved", &moved), ("short", &short)] {
        let fast = build_planes(f, &opts);
        assert!(fast.is_err(), "{name}: accepted");
        assert_eq!(fast, build_planes_reference(f, &opts), "{name}");
    }
    assert!(matches!(build_planes(&swapped, &opts), Err(EncodeError::NotPixelAligned { .. })));
    // Out of order at every position within and across the AVX2 encoder's chunks of eight.
    for k in 0..17 {
        let mut f = frame.clone();
        f.samples.swap(k, k + 1);
        assert_eq!(build_planes(&f, &opts), build_planes_reference(&f, &opts), "swap at {k}");
        assert!(build_planes(&f, &opts).is_err() && build_planes_portable(&f, &opts).is_err(), "swap at {k}");
    }
    assert_eq!(build_planes(&short, &opts), Err(EncodeError::BadFrame));
}

/// A consistent or inconsistent body from random bytes: mask bits at `density`, planes of random
/// residuals (radius residuals mostly in range), sample count right or off by `count_off`.
fn random_body(rng: &mut Rng, w: u32, h: u32, density: f32, count_off: i64) -> (FrameHeader, CompactParams, Vec<u8>) {
    let pixels = (w * h) as usize;
    let mlen = pixels.div_ceil(8);
    let mut body = vec![0u8; mlen];
    let mut n = 0usize;
    for i in 0..pixels {
        if rng.f() < density {
            body[i / 8] |= 1 << (i % 8);
            n += 1;
        }
    }
    for plane in 0..8 {
        for _ in 0..n {
            let v = rng.next() as u8;
            body.push(if plane == 3 && rng.below(200) != 0 { v & 3 } else { v });
        }
    }
    let bounds = Bounds::new(Vec3::splat(-1.0), Vec3::splat(1.0));
    let camera = Camera::framing(bounds.min(), bounds.max(), rng.f() * 360.0, 10.0, 40.0, w, h);
    let count = (n as i64 + count_off).max(0) as u32;
    let header = FrameHeader {
        seq: 1,
        camera,
        heuristic: Heuristic::Threshold,
        bounds,
        radius_unit: 1e-3,
        render_us: 0,
        level: 0,
        count,
    };
    let params = CompactParams {
        depth_min: rng.f() * 5.0,
        depth_step: 1e-5 + rng.f() * 1e-3,
        radius: RadiusPrediction { constant: rng.f() * 0.02, per_depth: rng.f() * 0.01 },
        coder: volwarp_core::compact_frame::Coder::Stored,
        colors: volwarp_core::compact_frame::ColorCoding::Plain,
        color_scale: [0; 3],
        raw_len: body.len() as u32,
    };
    (header, params, body)
}

#[test]
fn fast_decoder_equals_the_reference_on_random_bodies() {
    let mut rng = Rng(0x5eed);
    for case in 0..400 {
        let (w, h) = (1 + rng.below(70) as u32, 1 + rng.below(50) as u32);
        let density = [0.0, 0.05, 0.5, 0.9, 1.0][case % 5];
        let off = if case % 7 == 0 { 1 } else { 0 };
        let (header, params, mut body) = random_body(&mut rng, w, h, density, off);
        if case % 11 == 0 {
            // Bits past the last pixel, or a body of the wrong length.
            if (w * h) % 8 != 0 {
                let m = (w * h).div_ceil(8) as usize - 1;
                body[m] |= 0x80;
            } else {
                body.pop();
            }
        }
        let a = decode_body(&header, &params, &body);
        let b = decode_body_reference(&header, &params, &body);
        assert!(a == b, "case {case} ({w}x{h}): {:?} against {:?}", a.as_ref().err(), b.as_ref().err());
        assert!(decode_body_portable(&header, &params, &body) == b, "case {case}: portable decoder differs");
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn fast_codec_equals_the_reference_for_any_seed(seed in 1u64.., w in 1u32..48, h in 1u32..48, hole in 0.0f32..1.0) {
        let (frame, model) = random_frame(seed, w, h, hole);
        let encoded = check_frame(&frame, &EncodeOptions { radius: Some(model), ..EncodeOptions::default() });
        prop_assert!(encoded);
    }
}

/// C zstd (feature `zstd-c`, what std clients use) and ruzstd (no_std) decompress every body
/// (from the library's match finder, ruzstd's encoder or the server's byte-run parse)
/// to the same bytes and refuse frames that do not fill exactly the stated length; changed bytes
/// give a typed error or a body of exactly that length (no checksum: zstd cannot tell every
/// change, and the two libraries then need not agree on the bytes: measured, a few in 300).
#[test]
fn c_zstd_and_ruzstd_decompress_the_same_bodies() {
    use volwarp_core::compact_frame::{compress, compress_c, decompress, decompress_c, decompress_ruzstd, Coder};
    let (frame, model) = random_frame(7, 200, 150, 0.01);
    let planes = build_planes(&frame, &EncodeOptions { radius: Some(model), ..EncodeOptions::default() }).unwrap();
    let params = planes.params;
    let c_coded = zstd::bulk::compress(&planes.body, 1).unwrap();
    let r_coded = compress(&planes.body, Coder::Zstd);
    // The server's: the byte-run parse with C zstd's entropy stage.
    let runs_coded = compress_c(&planes.body, 1);
    for coded in [&c_coded, &r_coded, &runs_coded] {
        assert_eq!(decompress_c(coded, &params).unwrap(), planes.body);
        assert_eq!(decompress_ruzstd(coded, &params).unwrap(), planes.body);
        assert_eq!(decompress(coded, &params).unwrap(), planes.body);
        // Two frames back to back, a frame with a byte more or less, a wrong stated length.
        let twice = [&coded[..], &coded[..]].concat();
        assert!(decompress_c(&twice, &params).is_err() && decompress_ruzstd(&twice, &params).is_err());
        let longer = [&coded[..], &[0u8][..]].concat();
        assert!(decompress_c(&longer, &params).is_err() && decompress_ruzstd(&longer, &params).is_err());
        let shorter = &coded[..coded.len() - 1];
        assert!(decompress_c(shorter, &params).is_err() && decompress_ruzstd(shorter, &params).is_err());
        for delta in [-1i64, 1] {
            let p = CompactParams { raw_len: (params.raw_len as i64 + delta) as u32, ..params };
            assert!(decompress_c(coded, &p).is_err() && decompress_ruzstd(coded, &p).is_err(), "{delta}");
        }
        let mut rng = Rng(11);
        for _ in 0..300 {
            let mut bad = coded.clone();
            for _ in 0..1 + rng.below(3) {
                let at = rng.below(bad.len() as u64) as usize;
                bad[at] ^= 1 << rng.below(8);
            }
            for body in [decompress_c(&bad, &params), decompress_ruzstd(&bad, &params)].into_iter().flatten() {
                assert_eq!(body.len(), params.raw_len as usize);
            }
        }
    }
}
