//! The compact frame encoding against the 12-byte form: exact round trip of colors and radius
//! codes, positions within the stated bound, the same traced image, and typed errors for
//! truncated, oversized, inconsistent and random input.

use proptest::prelude::*;
use volwarp_core::camera::Camera;
use volwarp_core::compact_frame::{
    self as cf, assemble, build_planes, compress, decode_payload, encode, encode_frame, encoded_size, position_bound,
    Coder, CompactError, EncodeError, EncodeOptions, Encoding, RadiusPrediction,
};
use volwarp_core::heuristics::Heuristic;
use volwarp_core::sample::{self, Bounds, Dequantizer, Quantizer};
use volwarp_core::traversal::brute_force;
use volwarp_core::wire::{self, Frame, FrameHeader, Limits, Message, MsgType, WireError, HEADER_LEN};
use volwarp_core::Vec3;

/// A server-like frame: every pixel of a `w × h` camera whose ray hits a bumpy sphere gets one
/// sample at the hit (radius a pixel diagonal at its depth, as the footprint model), colors
/// smooth with some texture; `cut` drops pixels whose index is a multiple of it (holes).
fn sphere_frame(w: u32, h: u32, yaw: f32, cut: usize) -> (Frame, RadiusPrediction) {
    let bounds = Bounds::new(Vec3::splat(-1.0), Vec3::splat(1.0));
    let cam = Camera::framing(bounds.min(), bounds.max(), yaw, 10.0, 30.0, w, h);
    let basis = cam.ray_basis();
    let (_, _, fwd) = cam.basis();
    let pitch = Vec3::from_slice(&basis.du[..3]).length().max(Vec3::from_slice(&basis.dv[..3]).length());
    let per_depth = std::f32::consts::SQRT_2 * pitch;
    let z_max = (bounds.max() - cam.eye).length() + 2.0;
    let unit = per_depth * z_max / sample::RADIUS_MAX as f32;
    let q = Quantizer::new(bounds, unit);
    let (mut samples, mut colors) = (Vec::new(), Vec::new());
    for y in 0..h {
        for x in 0..w {
            if cut > 0 && (y as usize * w as usize + x as usize).is_multiple_of(cut) {
                continue;
            }
            let r = basis.ray(x, y);
            // Ray against a sphere of radius 0.8 with a bump.
            let oc = r.origin;
            let b = oc.dot(r.dir);
            let c = oc.length_squared() - 0.64;
            let disc = b * b - c;
            if disc < 0.0 {
                continue;
            }
            let t = -b - disc.sqrt();
            let p = r.at(t);
            let t = t + 0.01 * (p.x * 40.0).sin() * (p.y * 30.0).cos();
            let p = r.at(t);
            let radius = per_depth * (t * r.dir.dot(fwd));
            samples.push(q.pack(p, radius));
            let shade = (0.5 + 0.5 * p.normalize().dot(Vec3::new(0.3, 0.8, 0.5))).clamp(0.0, 1.0);
            let a = 200 + ((x * 7 + y * 3) % 56) as u8;
            let k = |v: f32| (v * shade * a as f32) as u8;
            colors.push(sample::pack_color(k(0.9), k(0.6 + 0.2 * (p.z * 9.0).sin()), k(0.4), a));
        }
    }
    let header = FrameHeader {
        seq: 42,
        camera: cam,
        heuristic: Heuristic::RelThreshold,
        bounds,
        radius_unit: unit,
        render_us: 777,
        level: 0,
        count: samples.len() as u32,
    };
    (Frame { header, samples, colors, segments: Vec::new() }, RadiusPrediction { constant: 0.0, per_depth })
}

fn decode_msg(bytes: &[u8], limits: &Limits) -> Result<Frame, WireError> {
    match wire::read_message(&mut &bytes[..], limits)? {
        Message::Frame(f) => Ok(f),
        other => panic!("decoded {other:?}"),
    }
}

fn payload_params(bytes: &[u8]) -> cf::CompactParams {
    cf::read_params(&bytes[HEADER_LEN..], &Limits::default()).unwrap().1
}

#[test]
fn round_trip_keeps_colors_radii_and_order_and_positions_within_the_bound() {
    for (w, h, cut) in [(96, 64, 0), (64, 64, 7), (77, 51, 3)] {
        let (frame, model) = sphere_frame(w, h, 20.0, cut);
        assert!(frame.samples.len() > 200);
        for radius in [Some(model), None] {
            let opts = EncodeOptions { radius, ..EncodeOptions::default() };
            let bytes = encode(&frame, &opts).unwrap();
            assert_eq!(bytes[6], MsgType::CompactFrame as u8);
            let back = decode_msg(&bytes, &Limits::default()).unwrap();
            assert_eq!(back.header, frame.header);
            assert!(back.colors == frame.colors, "colors are lossless");
            let codes = |f: &Frame| f.samples.iter().map(|&s| sample::radius_code(s)).collect::<Vec<_>>();
            assert!(codes(&back) == codes(&frame), "radius codes are lossless");
            let bound = position_bound(&frame.header, &payload_params(&bytes));
            let deq = Dequantizer::new(frame.header.bounds, frame.header.radius_unit);
            let mut worst = 0.0f32;
            for (&a, &b) in frame.samples.iter().zip(&back.samples) {
                worst = worst.max((deq.center(a) - deq.center(b)).length());
            }
            assert!(worst <= bound, "{w}x{h}: position moved {worst} > bound {bound}");
            // The stated bound is tight enough to mean something: under a pixel at this depth.
            assert!(bound < 0.01, "bound {bound}");
        }
    }
}

#[test]
fn stored_and_zstd_bodies_decode_to_the_same_frame_and_compact_is_under_4_bytes_per_sample() {
    let (frame, model) = sphere_frame(128, 128, 0.0, 0);
    let z = encode(&frame, &EncodeOptions { radius: Some(model), ..Default::default() }).unwrap();
    let s = encode(&frame, &EncodeOptions { radius: Some(model), coder: Coder::Stored, ..Default::default() }).unwrap();
    assert!(decode_msg(&z, &Limits::default()).unwrap() == decode_msg(&s, &Limits::default()).unwrap());
    let per_sample = z.len() as f64 / frame.samples.len() as f64;
    assert!(per_sample < 4.0, "{per_sample} bytes per sample");
    assert_eq!(
        encoded_size(&frame, Encoding::Compact, &EncodeOptions::default()),
        encode_frame(&frame, Encoding::Compact, &EncodeOptions::default()).0.len()
    );
    assert_eq!(encoded_size(&frame, Encoding::Raw12, &EncodeOptions::default()), 12 + 96 + 12 * frame.samples.len());
    assert_eq!(
        encoded_size(&frame, Encoding::Raw12, &EncodeOptions::default()),
        wire::encode_to_vec(&Message::Frame(frame.clone())).len()
    );
}

#[test]
fn decoding_twice_is_a_fixed_point_of_positions_up_to_one_depth_code() {
    // Re-encoding a decoded frame does not drift: every position stays within the bound of the
    // first decode.
    let (frame, model) = sphere_frame(80, 60, 35.0, 5);
    let opts = EncodeOptions { radius: Some(model), ..Default::default() };
    let once = decode_msg(&encode(&frame, &opts).unwrap(), &Limits::default()).unwrap();
    let bytes = encode(&once, &opts).unwrap();
    let twice = decode_msg(&bytes, &Limits::default()).unwrap();
    assert_eq!(twice.colors, once.colors);
    let bound = position_bound(&once.header, &payload_params(&bytes));
    let deq = Dequantizer::new(frame.header.bounds, frame.header.radius_unit);
    for (&a, &b) in once.samples.iter().zip(&twice.samples) {
        assert!((deq.center(a) - deq.center(b)).length() <= bound);
    }
}

#[test]
fn the_reference_tracer_draws_the_same_image_from_both_encodings() {
    // Trace both frames (brute force: the reference every tracer is tested against) at the
    // frame's camera and 10° away; the hit sample ids agree where the positions are equal, and
    // nearly everywhere else.
    let (frame, model) = sphere_frame(64, 48, 10.0, 0);
    let back = decode_msg(
        &encode(&frame, &EncodeOptions { radius: Some(model), ..Default::default() }).unwrap(),
        &Limits::default(),
    )
    .unwrap();
    let deq = Dequantizer::new(frame.header.bounds, frame.header.radius_unit);
    for angle in [0.0f32, 10.0] {
        let cam = frame.header.camera.orbit(angle, 0.0);
        let basis = cam.ray_basis();
        let (mut same, mut total) = (0, 0);
        for y in 0..cam.height {
            for x in 0..cam.width {
                let ray = basis.ray(x, y);
                let a = brute_force(&frame.samples, &deq, &ray);
                let b = brute_force(&back.samples, &deq, &ray);
                total += 1;
                let (ia, ib) = (a.map(|h| h.prim), b.map(|h| h.prim));
                if ia == ib {
                    same += 1;
                } else if let (Some(i), Some(j)) = (ia, ib) {
                    // A different sample may win only if one of the two moved.
                    let moved = |k: u32| frame.samples[k as usize] != back.samples[k as usize];
                    assert!(moved(i) || moved(j), "pixel ({x}, {y}) differs though both samples are unchanged");
                }
            }
        }
        let frac = same as f64 / total as f64;
        assert!(frac > 0.97, "{angle}°: only {:.1} % of pixels hit the same sample", frac * 100.0);
    }
}

#[test]
fn frames_not_on_their_pixels_rays_are_refused_by_the_encoder() {
    let (mut frame, _) = sphere_frame(32, 32, 0.0, 0);
    frame.samples.swap(3, 10);
    frame.colors.swap(3, 10);
    assert!(matches!(encode(&frame, &EncodeOptions::default()), Err(EncodeError::NotPixelAligned { .. })));
    // ... and `encode_frame` falls back to the 12-byte form.
    let (bytes, enc) = encode_frame(&frame, Encoding::Compact, &EncodeOptions::default());
    assert_eq!(enc, Encoding::Raw12);
    assert!(decode_msg(&bytes, &Limits::default()).unwrap() == frame);
    let (mut frame, _) = sphere_frame(32, 32, 0.0, 0);
    frame.colors.pop();
    assert_eq!(encode(&frame, &EncodeOptions::default()), Err(EncodeError::BadFrame));
}

#[test]
fn empty_and_single_sample_frames_round_trip() {
    let (frame, _) = sphere_frame(16, 16, 0.0, 0);
    for n in [0usize, 1] {
        let f = Frame {
            header: FrameHeader { count: n as u32, ..frame.header },
            samples: frame.samples[..n].to_vec(),
            colors: frame.colors[..n].to_vec(),
            segments: Vec::new(),
        };
        let back = decode_msg(&encode(&f, &EncodeOptions::default()).unwrap(), &Limits::default()).unwrap();
        assert_eq!(back.colors, f.colors);
        assert_eq!(back.samples.len(), n);
    }
}

/// A compact message with a hand-made body (stored coder) and parameters.
fn with_body(frame: &Frame, edit: impl FnOnce(&mut cf::Planes)) -> Vec<u8> {
    let mut planes = build_planes(frame, &EncodeOptions { coder: Coder::Stored, ..Default::default() }).unwrap();
    edit(&mut planes);
    let coded = compress(&planes.body, planes.params.coder);
    assemble(&frame.header, &planes.params, &coded).unwrap()
}

#[test]
fn inconsistent_and_damaged_messages_get_typed_errors() {
    let (frame, _) = sphere_frame(40, 30, 0.0, 0);
    let lim = Limits::default();
    let n = frame.samples.len() as u32;
    // Mask with one pixel more than the count.
    let bytes = with_body(&frame, |p| {
        let i = p.body[..150].iter().position(|&b| b != 0xff).unwrap();
        p.body[i] |= !p.body[i] & p.body[i].wrapping_add(1);
    });
    assert_eq!(refused(&bytes, &lim), (WireError::Compact(CompactError::MaskCount { mask: n + 1, count: n })));
    // A bit past the last pixel (40·30 = 1200 bits fill 150 bytes exactly: use a 41-wide frame).
    let (f41, _) = sphere_frame(41, 30, 0.0, 0);
    let bytes = with_body(&f41, |p| {
        let last = cf::mask_len(41, 30) as usize - 1;
        p.body[last] |= 0x80;
    });
    assert!(matches!(decode_msg(&bytes, &lim), Err(WireError::Compact(CompactError::MaskCount { .. }))));
    // Stated body length not matching the count.
    let bytes = with_body(&frame, |p| p.params.raw_len += 1);
    assert!(matches!(decode_msg(&bytes, &lim), Err(WireError::Compact(CompactError::BadRawLength { .. }))));
    // Bad depth parameters, radius model, coder, radius residual.
    let bytes = with_body(&frame, |p| p.params.depth_step = f32::NAN);
    assert_eq!(refused(&bytes, &lim), (WireError::Compact(CompactError::BadDepth)));
    let bytes = with_body(&frame, |p| p.params.depth_step = 0.0);
    assert_eq!(refused(&bytes, &lim), (WireError::Compact(CompactError::BadDepth)));
    let bytes = with_body(&frame, |p| p.params.depth_step = f32::MAX / 100.0);
    assert_eq!(refused(&bytes, &lim), (WireError::Compact(CompactError::BadDepth)));
    let bytes = with_body(&frame, |p| p.params.radius.per_depth = f32::INFINITY);
    assert_eq!(refused(&bytes, &lim), (WireError::Compact(CompactError::BadRadiusModel)));
    let mut bytes = with_body(&frame, |_| {});
    bytes[HEADER_LEN + 96 + 16] = 9;
    assert_eq!(refused(&bytes, &lim), (WireError::Compact(CompactError::BadCoder(9))));
    let bytes = with_body(&frame, |p| {
        let at = cf::mask_len(40, 30) as usize + 3 * n as usize + 5;
        p.body[at] = 4;
    });
    assert_eq!(refused(&bytes, &lim), (WireError::Compact(CompactError::BadRadiusResidual)));
    // More samples than pixels, and over the limits: refused from the fixed part.
    let mut h = frame.header;
    h.count = 40 * 30 + 1;
    let planes = build_planes(&frame, &EncodeOptions { coder: Coder::Stored, ..Default::default() }).unwrap();
    let bytes = assemble(&h, &planes.params, &planes.body).unwrap();
    assert!(matches!(decode_msg(&bytes, &lim), Err(WireError::TooManySamples { .. } | WireError::Compact(_))));
    let small = Limits::for_frames(16);
    let good = encode(&frame, &EncodeOptions::default()).unwrap();
    assert!(matches!(decode_msg(&good, &small), Err(WireError::BadCamera(_) | WireError::TooLarge { .. })));
}

#[test]
fn truncated_and_oversized_bodies_get_typed_errors() {
    let (frame, _) = sphere_frame(48, 32, 5.0, 0);
    let lim = Limits::default();
    for coder in [Coder::Zstd, Coder::Stored] {
        let bytes = encode(&frame, &EncodeOptions { coder, ..Default::default() }).unwrap();
        // Every truncation of the stream: EOF (the header promises more than there is).
        for cut in (0..bytes.len()).step_by(7) {
            let r = decode_msg(&bytes[..cut], &lim);
            assert!(matches!(r, Err(WireError::UnexpectedEof | WireError::Closed)), "cut {cut}: {r:?}");
        }
        // A payload shortened or lengthened consistently (header length adjusted): the body no
        // longer decodes to the stated length.
        for delta in [-1i64, -20, 1, 64] {
            let mut b = bytes.clone();
            if delta < 0 {
                b.truncate((b.len() as i64 + delta) as usize);
            } else {
                b.extend(std::iter::repeat_n(0u8, delta as usize));
            }
            let len = (b.len() - HEADER_LEN) as u32;
            b[8..12].copy_from_slice(&len.to_le_bytes());
            assert_eq!(refused(&b, &lim), (WireError::Compact(CompactError::Corrupt)), "{coder:?} {delta}");
        }
    }
    // Shorter than the fixed part.
    let mut b = encode(&frame, &EncodeOptions::default()).unwrap();
    b.truncate(HEADER_LEN + 100);
    b[8..12].copy_from_slice(&100u32.to_le_bytes());
    assert!(matches!(decode_msg(&b, &lim), Err(WireError::BadLength { ty: MsgType::CompactFrame, .. })));
    assert!(decode_payload(&b[HEADER_LEN..], &lim).is_err());
}

#[test]
fn a_zstd_body_that_would_decompress_past_the_stated_length_is_refused() {
    // A decompression bomb: a tiny zstd frame of 64 MiB of zeros in place of a 1 KiB body.
    let (frame, _) = sphere_frame(16, 16, 0.0, 0);
    let planes = build_planes(&frame, &EncodeOptions::default()).unwrap();
    let bomb = compress(&vec![0u8; 64 << 20], Coder::Zstd);
    assert!(bomb.len() < 64 << 10);
    let bytes = assemble(&frame.header, &planes.params, &bomb).unwrap();
    assert_eq!(refused(&bytes, &Limits::default()), (WireError::Compact(CompactError::Corrupt)));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, .. ProptestConfig::default() })]

    /// Random bytes after a valid fixed part: never a panic; an accepted frame is consistent.
    #[test]
    fn random_bodies_never_panic(body in proptest::collection::vec(any::<u8>(), 0..600), coder in 0u8..3, raw in any::<bool>()) {
        let (frame, _) = sphere_frame(12, 10, 0.0, 0);
        let planes = build_planes(&frame, &EncodeOptions { coder: Coder::Stored, ..Default::default() }).unwrap();
        let mut bytes = assemble(&frame.header, &planes.params, &body).unwrap();
        bytes[HEADER_LEN + 96 + 16] = coder;
        if raw {
            // Random raw length too.
            let l = (body.len() as u32).to_le_bytes();
            bytes[HEADER_LEN + 116..HEADER_LEN + 120].copy_from_slice(&l);
        }
        if let Ok(f) = decode_msg(&bytes, &Limits::default()) {
            prop_assert_eq!(f.samples.len(), frame.samples.len());
            let deq = Dequantizer::new(f.header.bounds, f.header.radius_unit);
            for &s in &f.samples {
                prop_assert!(deq.center(s).is_finite());
            }
        }
    }

    /// Random bytes anywhere in a valid message (the header length kept): typed errors only.
    #[test]
    fn random_edits_never_panic(edits in proptest::collection::vec((any::<u16>(), any::<u8>()), 1..8)) {
        let (frame, _) = sphere_frame(20, 12, 0.0, 4);
        let mut bytes = encode(&frame, &EncodeOptions::default()).unwrap();
        for (at, v) in edits {
            let i = HEADER_LEN + at as usize % (bytes.len() - HEADER_LEN);
            bytes[i] = v;
        }
        if let Ok(f) = decode_msg(&bytes, &Limits::default()) {
            prop_assert_eq!(f.samples.len(), f.header.count as usize);
            prop_assert!(f.header.count <= f.header.camera.width * f.header.camera.height);
        }
    }

    /// Fully random payloads behind a CompactFrame header.
    #[test]
    fn random_payloads_never_panic(payload in proptest::collection::vec(any::<u8>(), 0..400)) {
        let _ = decode_payload(&payload, &Limits::for_frames(64));
    }
}

/// The error a message is refused with (panics, without printing the frame, if accepted).
fn refused(bytes: &[u8], limits: &Limits) -> WireError {
    match decode_msg(bytes, limits) {
        Ok(f) => panic!("accepted a frame of {} samples", f.samples.len()),
        Err(e) => e,
    }
}

/// Colors coded against green (`ColorCoding::AgainstGreen`, byte 113): the same frame as the
/// plain coding, bit for bit, whichever the encoder picks, also with a forced choice on a frame
/// where the estimate says plain; undoing is the exact inverse on any bytes; an unknown code is
/// a typed error; and a receiver that did not ask (the default options) never gets it.
#[test]
fn colors_coded_against_green_decode_to_the_same_frame() {
    use volwarp_core::compact_frame::{code_colors, undo_color_coding, ColorCoding};
    let lim = Limits::default();
    for (w, h, yaw, cut) in [(64, 48, 10.0, 0), (40, 30, 200.0, 7)] {
        let (frame, model) = sphere_frame(w, h, yaw, cut);
        let n = frame.samples.len();
        let opts = EncodeOptions { radius: Some(model), ..Default::default() };
        let plain = encode(&frame, &opts).unwrap();
        assert_eq!(plain[HEADER_LEN + 113], 0, "default options: plain colors");
        let want = decode_msg(&plain, &lim).unwrap();
        let green = encode(&frame, &EncodeOptions { colors_against_green: true, ..opts }).unwrap();
        assert!(green[HEADER_LEN + 113] <= 1);
        assert!(decode_msg(&green, &lim).unwrap() == want, "{w}×{h}: the chosen coding decodes differently");
        // Forced against green, whatever the estimate says.
        let mut planes = build_planes(&frame, &opts).unwrap();
        let before = planes.body.clone();
        if code_colors(&mut planes, n) == ColorCoding::Plain {
            // Against green with scale 8/8 on every channel: minus green's residual.
            planes.params.colors = ColorCoding::AgainstGreen;
            planes.params.color_scale = [8; 3];
            let at = planes.body.len() - 4 * n;
            let (r, rest) = planes.body[at..].split_at_mut(n);
            let (g, rest) = rest.split_at_mut(n);
            let (b, a) = rest.split_at_mut(n);
            for i in 0..n {
                r[i] = r[i].wrapping_sub(g[i]);
                b[i] = b[i].wrapping_sub(g[i]);
                a[i] = a[i].wrapping_sub(g[i]);
            }
        }
        assert_ne!(planes.body, before, "the color planes changed");
        let mut undone = planes.body.clone();
        undo_color_coding(&mut undone, &planes.params, n);
        assert_eq!(undone, before, "undoing is the exact inverse");
        let coded = compress(&planes.body, planes.params.coder);
        let forced = assemble(&frame.header, &planes.params, &coded).unwrap();
        assert_eq!(forced[HEADER_LEN + 113], 1);
        assert!(decode_msg(&forced, &lim).unwrap() == want, "{w}×{h}: forced coding decodes differently");
        // An unknown coding, a set reserved bit of the scales, scales with plain colors.
        let mut bad = forced.clone();
        bad[HEADER_LEN + 113] = 2;
        assert_eq!(decode_msg(&bad, &lim).unwrap_err(), WireError::Compact(CompactError::BadColorCoding(2)));
        let mut bad = forced.clone();
        bad[HEADER_LEN + 115] |= 0x80;
        assert_eq!(decode_msg(&bad, &lim).unwrap_err(), WireError::Compact(CompactError::BadColorCoding(1)));
        let mut bad = plain.clone();
        bad[HEADER_LEN + 114] = 1;
        assert_eq!(decode_msg(&bad, &lim).unwrap_err(), WireError::Compact(CompactError::BadColorCoding(0)));
        // Every scale round-trips: each channel against green at k/8 for k = 0 … 31.
        for k in [0u8, 1, 5, 8, 13, 31] {
            let mut p = build_planes(&frame, &opts).unwrap();
            let plain_body = p.body.clone();
            let at = p.body.len() - 4 * n;
            let (r, rest) = p.body[at..].split_at_mut(n);
            let (g, rest) = rest.split_at_mut(n);
            let (b, a) = rest.split_at_mut(n);
            let pred = |g: u8| ((g as i8 as i32 * k as i32 + 4).div_euclid(8)) as u8;
            for i in 0..n {
                r[i] = r[i].wrapping_sub(pred(g[i]));
                b[i] = b[i].wrapping_sub(pred(g[i]));
                a[i] = a[i].wrapping_sub(pred(g[i]));
            }
            p.params.colors = ColorCoding::AgainstGreen;
            p.params.color_scale = [k; 3];
            let mut undone = p.body.clone();
            undo_color_coding(&mut undone, &p.params, n);
            assert_eq!(undone, plain_body, "k = {k}: undoing is the exact inverse");
            let coded = compress(&p.body, p.params.coder);
            let msg = assemble(&frame.header, &p.params, &coded).unwrap();
            assert!(decode_msg(&msg, &lim).unwrap() == want, "k = {k}: decodes differently");
        }
    }
}
