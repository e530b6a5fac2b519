//! Layered frames on the wire (version 3): round trips through the 12-byte form and
//! the LayeredCompactFrame, and every kind of bad segment data as a typed error.

use volwarp_core::compact_frame::{self, EncodeOptions, Encoding};
use volwarp_core::sample::{pack_color, Quantizer};
use volwarp_core::segments::{validate, LayerError, MAX_LAYERS};
use volwarp_core::wire::{self, Frame, FrameHeader, Hello, Limits, Message, WireError};
use volwarp_core::{Bounds, Camera, Heuristic, Vec3};

/// A 16×16 frame of up to `k` segments per pixel (pixel-dependent counts, some empty pixels),
/// each on its pixel's ray, 0.3 apart, with valid premultiplied colors.
fn layered(k: u8) -> Frame {
    let mut f = layered_big(k, 16);
    f.header.seq = 9;
    f
}

fn decode(bytes: &[u8], limits: &Limits) -> Result<Frame, WireError> {
    match wire::read_message(&mut &bytes[..], limits)? {
        Message::Frame(f) => Ok(f),
        other => panic!("not a frame: {other:?}"),
    }
}

fn raw(f: &Frame) -> Vec<u8> {
    wire::encode_to_vec(&Message::Frame(f.clone()))
}

#[test]
fn layered_frames_round_trip_in_both_encodings() {
    let f = layered(3);
    assert_eq!(f.layers(), 3);
    validate(&f.header, &f.samples, &f.colors, &f.segments, 3).unwrap();
    let bytes = raw(&f);
    assert_eq!(bytes[12 + 57], 3, "layer count in byte 57");
    assert_eq!(bytes.len(), 12 + 96 + 13 * f.samples.len());
    assert_eq!(decode(&bytes, &Limits::default()).unwrap(), f);

    let (compact, got) = compact_frame::encode_frame(&f, Encoding::Compact, &EncodeOptions::default());
    assert_eq!(got, Encoding::Compact, "the compact form carries segments");
    assert_eq!(compact[6], wire::MsgType::LayeredCompactFrame as u8);
    assert!(compact.len() < bytes.len() / 2, "{} compact bytes against {} raw", compact.len(), bytes.len());
    let back = decode(&compact, &Limits::default()).unwrap();
    assert_eq!(back.colors, f.colors);
    assert_eq!(back.segments, f.segments);
    assert_eq!(back.header, f.header);
    let (da, db) = (f.header.dequantizer(), back.header.dequantizer());
    for (a, b) in f.samples.iter().zip(&back.samples) {
        assert!((da.center(*a) - db.center(*b)).length() < 0.002, "positions move by less than a depth step");
        assert_eq!(volwarp_core::sample::radius_code(*a), volwarp_core::sample::radius_code(*b));
    }
    // A one-sample-per-pixel frame is written exactly as before (byte 57 zero, no plane).
    let plain = Frame::new(f.header, f.samples.clone(), f.colors.clone());
    let pb = raw(&plain);
    assert_eq!(pb[12 + 57], 0);
    assert_eq!(pb.len(), 12 + 96 + 12 * f.samples.len());
}

#[test]
fn hello_carries_the_layer_count() {
    let h = Hello::new(wire::CAP_COMPACT).with_layers(6);
    let b = wire::encode_to_vec(&Message::Hello(h.clone()));
    assert_eq!(u16::from_le_bytes([b[14], b[15]]), 6);
    assert_eq!(wire::read_message(&mut &b[..], &Limits::default()).unwrap(), Message::Hello(h));
    assert_eq!(Hello::new(0).with_layers(200).layers, MAX_LAYERS as u8);
}

#[test]
fn more_layers_than_negotiated_is_a_typed_error() {
    let f = layered(4);
    for bytes in [raw(&f), compact_frame::encode_frame(&f, Encoding::Compact, &EncodeOptions::default()).0] {
        let e = decode(&bytes, &Limits::default().with_layers(2)).unwrap_err();
        assert_eq!(e, WireError::Layers(LayerError::TooManyLayers { layers: 4, limit: 2 }));
        assert!(decode(&bytes, &Limits::default().with_layers(4)).is_ok());
    }
    // The allocation-free reader refuses a layered frame instead of misreading it.
    let bytes = raw(&f);
    let mut r = &bytes[..];
    let h = wire::read_header(&mut r, &Limits::default()).unwrap();
    let e = wire::read_frame_header(&mut r, &h, &Limits::default()).unwrap_err();
    assert_eq!(e, WireError::Layers(LayerError::Layered));
}

/// Offset of sample `i`'s color and segment index in a raw layered message.
fn offsets(f: &Frame, i: usize) -> (usize, usize) {
    let n = f.samples.len();
    (12 + 96 + 8 * n + 4 * i, 12 + 96 + 12 * n + i)
}

#[test]
fn bad_segment_data_is_a_typed_error() {
    let f = layered(3);
    let lim = Limits::default();
    // A second segment (index 1) to corrupt.
    let i = f.segments.iter().position(|&s| s == 1).unwrap();
    let (color_at, seg_at) = offsets(&f, i);

    // Opacity above 1 once normalised: a color channel above alpha.
    let mut b = raw(&f);
    b[color_at] = b[color_at + 3].saturating_add(1).max(1);
    b[color_at + 3] = b[color_at] - 1;
    assert_eq!(decode(&b, &lim).unwrap_err(), WireError::Layers(LayerError::Opacity { index: i }));

    // Unsorted depths: swap the two segments of a pixel.
    let mut g = f.clone();
    g.samples.swap(i - 1, i);
    assert_eq!(decode(&raw(&g), &lim).unwrap_err(), WireError::Layers(LayerError::Unsorted { index: i }));

    // Overlapping depths: both segments at one depth.
    let mut g = f.clone();
    g.samples[i] = g.samples[i - 1];
    assert_eq!(decode(&raw(&g), &lim).unwrap_err(), WireError::Layers(LayerError::Unsorted { index: i }));

    // A segment on another pixel's ray.
    let mut g = f.clone();
    let other = f.samples.iter().rposition(|&s| s != f.samples[i - 1]).unwrap();
    g.samples[i] = f.samples[other];
    assert!(matches!(decode(&raw(&g), &lim), Err(WireError::Layers(LayerError::Unsorted { .. }))));

    // Segment indices: a gap, and one at or above the layer count.
    let mut b = raw(&f);
    b[seg_at] = 2;
    assert_eq!(decode(&b, &lim).unwrap_err(), WireError::Layers(LayerError::BadIndex { index: i }));
    let mut b = raw(&f);
    b[12 + 57] = 2;
    assert!(matches!(decode(&b, &lim), Err(WireError::Layers(LayerError::BadIndex { .. }))));

    // More samples than layers × pixels.
    let mut b = raw(&f);
    b[12 + 57] = 1;
    let n = (16 * 16 + 1) as u32;
    let mut big = b[..12 + 96].to_vec();
    big[12 + 92..12 + 96].copy_from_slice(&n.to_le_bytes());
    big.extend(std::iter::repeat_n(0u8, 13 * n as usize));
    let len = (big.len() - 12) as u32;
    big[8..12].copy_from_slice(&len.to_le_bytes());
    assert!(matches!(decode(&big, &lim), Err(WireError::TooManySamples { .. })));
}

#[test]
fn a_corrupt_layered_compact_frame_is_a_typed_error() {
    let f = layered(3);
    let (b, _) = compact_frame::encode_frame(&f, Encoding::Compact, &EncodeOptions::default());
    let lim = Limits::default();
    // Every truncation and every single-byte change: an error or a valid frame, never a panic.
    for cut in (0..b.len()).step_by(7) {
        let _ = decode(&b[..cut], &lim);
    }
    let mut errors = 0;
    for i in (12..b.len()).step_by(3) {
        let mut c = b.clone();
        c[i] ^= 0x5a;
        match decode(&c, &lim) {
            Ok(g) => validate(&g.header, &g.samples, &g.colors, &g.segments, g.layers()).unwrap(),
            Err(_) => errors += 1,
        }
    }
    assert!(errors > 0);
    // Layers whose masks are not nested: swap the first two layers' parts.
    let layers = b[12 + 57] as usize;
    assert_eq!(layers, 3);
    let mut parts = Vec::new();
    let mut at = 12 + 96;
    for _ in 0..layers {
        let len = u32::from_le_bytes(b[at..at + 4].try_into().unwrap()) as usize;
        parts.push(b[at..at + 4 + len].to_vec());
        at += 4 + len;
    }
    let mut swapped = b[..12 + 96].to_vec();
    for p in [&parts[1], &parts[0], &parts[2]] {
        swapped.extend_from_slice(p);
    }
    assert_eq!(decode(&swapped, &lim).unwrap_err(), WireError::Layers(LayerError::Inconsistent));
}

/// `layered` over `w × w` pixels (the pattern repeating every 16 columns; larger frames have
/// more samples than one block of `validate`'s).
fn layered_big(k: u8, w: u32) -> Frame {
    layered_frame(w, w, |x, y| ((x * 7 + y * 3) % (k as u32 + 1)) as u8)
}

/// A `w × h` layered frame with `count(x, y)` segments at pixel `(x, y)` (at most 4), each on
/// its pixel's ray, 0.3 apart, with valid premultiplied colors.
fn layered_frame(w: u32, h: u32, count: impl Fn(u32, u32) -> u8) -> Frame {
    let camera = Camera::look_at(Vec3::new(0.5, 0.5, 3.0), Vec3::splat(0.5), Vec3::Y, 30.0, w, h);
    let bounds = Bounds::new(Vec3::new(-1.0, -1.0, -1.0), Vec3::new(2.0, 2.0, 2.0));
    let q = Quantizer::new(bounds, 0.001);
    let basis = camera.ray_basis();
    let (mut samples, mut colors, mut segments) = (Vec::new(), Vec::new(), Vec::new());
    for y in 0..h {
        for x in 0..w {
            let n = count(x, y);
            let d = basis.dir(x, y);
            for j in 0..n {
                let t = 2.0 + 0.3 * j as f32 + 0.01 * (x % 16) as f32;
                samples.push(q.pack(camera.eye + d * t, 0.004));
                let a = 40 + 50 * j + (x % 16) as u8;
                colors.push(pack_color(a / 2, a / 3, a, a));
                segments.push(j);
            }
        }
    }
    let header = FrameHeader {
        seq: 1,
        camera,
        heuristic: Heuristic::Threshold,
        bounds,
        radius_unit: 0.001,
        render_us: 5,
        level: 0,
        count: samples.len() as u32,
    };
    Frame { header, samples, colors, segments }
}

/// The blocked `validate` gives the one-sample-at-a-time reference's result (the same first
/// error, or `Ok`) on valid frames and on every kind of damage at every position, across its
/// blocks of 256.
#[test]
fn blocked_validation_equals_the_reference() {
    use volwarp_core::segments::validate_reference;
    let f = layered_big(4, 40);
    assert!(f.samples.len() > 2000, "{}", f.samples.len());
    let check = |g: &Frame, layers: u8| {
        let a = validate(&g.header, &g.samples, &g.colors, &g.segments, layers);
        let b = validate_reference(&g.header, &g.samples, &g.colors, &g.segments, layers);
        assert_eq!(a, b);
        a
    };
    assert_eq!(check(&f, 4), Ok(()));
    let n = f.samples.len();
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut rnd = move |m: usize| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state % m as u64) as usize
    };
    let mut errors = 0;
    for case in 0..600 {
        let mut g = f.clone();
        let i = if case < 40 { (case * 64) % n } else { rnd(n) };
        match case % 6 {
            0 => g.samples.swap(i, (i + 1) % n),
            1 => g.segments[i] = g.segments[i].wrapping_add(1 + rnd(3) as u8),
            2 => g.colors[i] = pack_color(200, 0, 0, 10),
            3 => g.samples[i] ^= 1 << rnd(54),
            4 => g.samples[i] = g.samples[(i + n - 1) % n],
            _ => g.segments[i] = 0,
        }
        errors += check(&g, 4).is_err() as u32;
        let _ = check(&g, 2);
    }
    assert!(errors > 300, "the damage is found: {errors} of 600");
}

/// A LayeredCompactFrame whose pixels mostly have every layer (whole mask bytes covered by all
/// layers: the merge's fast path) and sometimes fewer, round trips like the 12-byte form.
#[test]
fn layered_compact_frames_with_full_coverage_round_trip() {
    // Three layers almost everywhere; a few pixels with one or two, a few empty.
    let f = layered_frame(48, 40, |x, y| match (x * 13 + y * 7) % 29 {
        0 => 0,
        1 => 1,
        2 => 2,
        _ => 3,
    });
    let (compact, got) = compact_frame::encode_frame(&f, Encoding::Compact, &EncodeOptions::default());
    assert_eq!(got, Encoding::Compact);
    let back = decode(&compact, &Limits::default()).unwrap();
    assert_eq!(back.segments, f.segments);
    assert_eq!(back.colors, f.colors);
    let (da, db) = (f.header.dequantizer(), back.header.dequantizer());
    for (a, b) in f.samples.iter().zip(&back.samples) {
        assert!((da.center(*a) - db.center(*b)).length() < 0.002);
    }
}

/// The layers' parts decoded by the caller (std clients do it on several threads): decoded in
/// any order and handed back in layer order, the same frame as the serial decoder; handed back
/// short, out of order or failing, a typed error and never a panic.
#[test]
fn layered_parts_decoded_by_the_caller_give_the_same_frame() {
    use volwarp_core::segments::{decode_layered_part, decode_layered_payload_with};
    let f = layered_big(4, 40);
    let (b, _) = compact_frame::encode_frame(&f, Encoding::Compact, &EncodeOptions::default());
    let lim = Limits::default();
    let payload = &b[12..];
    let serial = decode(&b, &lim).unwrap();
    assert!(serial.samples.len() == f.samples.len() && serial.segments == f.segments);
    let reversed = decode_layered_payload_with(payload, &lim, |parts| {
        let mut v: Vec<_> = parts.iter().rev().map(|p| decode_layered_part(p, &lim)).collect();
        v.reverse();
        v
    })
    .unwrap();
    assert!(reversed == serial, "decoded out of order, the frame differs");
    let inconsistent = WireError::Layers(LayerError::Inconsistent);
    let short = decode_layered_payload_with(payload, &lim, |parts| {
        parts[1..].iter().map(|p| decode_layered_part(p, &lim)).collect()
    });
    assert_eq!(short.unwrap_err(), inconsistent);
    let swapped = decode_layered_payload_with(payload, &lim, |parts| {
        let mut v: Vec<_> = parts.iter().map(|p| decode_layered_part(p, &lim)).collect();
        v.swap(0, 1);
        v
    });
    assert_eq!(swapped.unwrap_err(), inconsistent);
    let failing = decode_layered_payload_with(payload, &lim, |parts| {
        parts.iter().map(|p| decode_layered_part(&p[..p.len() / 2], &lim)).collect()
    });
    assert!(failing.is_err());
}
