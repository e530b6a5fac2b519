//! Writes the hand-made seed corpora under `fuzz/seeds/<target>/` (run from `fuzz/`:
//! `cargo run --example make_seeds`). Real frames dumped from the server are added beside them.

use std::fs;
use volwarp_core::camera::Camera;
use volwarp_core::heuristics::Heuristic;
use volwarp_core::sample::{pack_color, Bounds, Quantizer};
use volwarp_core::wire::{
    encode_to_vec, error_code, preset_name, ErrorMsg, Frame, FrameHeader, Hello, Message, TfPoints, VisualEdit,
    VisualState, CAP_GPU,
};
use volwarp_core::Vec3;

fn frame(n: usize, bounds: Bounds, radius_unit: f32, w: u32, h: u32) -> Message {
    let q = Quantizer::new(bounds, radius_unit);
    let (lo, hi) = (bounds.min(), bounds.max());
    let mut samples = Vec::new();
    let mut colors = Vec::new();
    for i in 0..n {
        let f = i as f32 / n.max(1) as f32;
        let p = lo + (hi - lo) * Vec3::new(f, (f * 7.0).fract(), (f * 13.0).fract());
        samples.push(q.pack(p, radius_unit * (1 + i % 5) as f32));
        colors.push(pack_color(i as u8, 2 * i as u8, 255 - i as u8, 200));
    }
    let camera = Camera::framing(lo, hi, 20.0, 10.0, 45.0, w, h);
    let header = FrameHeader {
        seq: n as u64,
        camera,
        heuristic: Heuristic::Threshold,
        bounds,
        radius_unit,
        render_us: 1234,
        level: 0,
        count: n as u32,
    };
    Message::Frame(Frame { header, samples, colors, segments: Vec::new() })
}

fn main() {
    let unit = Bounds::new(Vec3::ZERO, Vec3::ONE);
    let cam = Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y, 45.0, 64, 64);
    let hello = Message::Hello(Hello::new(CAP_GPU));
    let hello_tok = Message::Hello(Hello::new(0).with_token(&[b'k'; 64]).unwrap());
    let req = volwarp_fuzz::checks::camera_request(7, cam, Heuristic::EnExMean, 1.0, 1);
    let err = Message::Error(ErrorMsg::new(error_code::UNAUTHORIZED, "wrong token ✗"));
    let mut tf = TfPoints::default();
    for i in 0..4 {
        let x = i as f32 / 3.0;
        tf.color.push([x, 1.0, x, 0.5]).unwrap();
        tf.opacity.push([x, x * x]).unwrap();
    }
    let edit = Message::VisualEdit(VisualEdit {
        id: 3,
        shade: Some(true),
        preset: preset_name("ct-bone"),
        window_level: Some([0.8, 0.45]),
        opacity_scale: Some(1.5),
        crop: Some([0.0, 0.5, 0.0, 1.0, 1.0, 1.0]),
        clip: Some(Some([0.5, 0.5, 0.5, -1.0, 0.0, 0.0])),
        transfer_function: Some(tf),
    });
    let mut state = VisualState {
        id: 3,
        preset: preset_name("ct-bone").unwrap(),
        window_level: [0.8, 0.45],
        opacity_scale: 1.0,
        crop: [0.0, 0.0, 0.0, 1.0, 1.0, 1.0],
        ..VisualState::default()
    };
    for n in ["grey", "ct-bone", "ct-soft-tissue", "mr-default", "cool-warm"] {
        state.presets.push(preset_name(n).unwrap()).unwrap();
    }
    let state = Message::VisualState(state);
    let frames = [
        ("frame_empty", frame(0, unit, 0.01, 64, 64)),
        ("frame_one", frame(1, unit, 0.01, 64, 64)),
        ("frame_64", frame(64, Bounds::new(Vec3::new(-1.0, -2.0, -3.0), Vec3::new(1.0, 2.0, 3.0)), 0.002, 16, 16)),
        ("frame_flat", frame(16, Bounds::new(Vec3::ZERO, Vec3::new(1.0, 1.0, 0.0)), 0.01, 8, 8)),
        ("frame_point", frame(9, Bounds::new(Vec3::ONE, Vec3::ONE), 1.0, 3, 3)),
        ("frame_huge_bounds", frame(8, Bounds::new(Vec3::ZERO, Vec3::splat(f32::MAX)), 1e30, 4, 4)),
    ];
    // Bounds up to f32::MAX behind a valid camera, a sample at the top corner (rejected since
    // `Bounds::is_valid` checks that corner decodes to a finite point).
    let mut max_bounds = frame(1, unit, 1.0, 16, 16);
    if let Message::Frame(f) = &mut max_bounds {
        f.header.bounds = Bounds::new(Vec3::ZERO, Vec3::splat(f32::MAX));
        f.samples[0] = 0x3f_ffff_ffff_ffff | (1 << 54);
    }
    let mut four_gib = b"VWRP\x01\x00\x03\x00".to_vec();
    four_gib.extend_from_slice(&u32::MAX.to_le_bytes());

    let mut stream = Vec::new();
    for m in [&hello, &req, &frames[2].1, &err, &Message::Bye] {
        stream.extend(encode_to_vec(m));
    }
    let mut files: Vec<(&str, String, Vec<u8>)> = Vec::new();
    let prefix = |pattern: &[u8], fail: u16, s: &[u8]| {
        let mut v = vec![pattern.len() as u8];
        v.extend_from_slice(pattern);
        v.extend_from_slice(&fail.to_le_bytes());
        v.extend_from_slice(s);
        v
    };
    for (name, m) in [
        ("hello", &hello),
        ("hello_token", &hello_tok),
        ("request", &req),
        ("error", &err),
        ("visual_edit", &edit),
        ("visual_state", &state),
    ] {
        files.push(("roundtrip", name.into(), encode_to_vec(m)));
        files.push(("wire_decode_chunked", name.into(), prefix(&[0], u16::MAX, &encode_to_vec(m))));
    }
    for (name, m) in &frames {
        let b = encode_to_vec(m);
        files.push(("frame_decode", name.to_string(), b.clone()));
        files.push(("roundtrip", name.to_string(), b.clone()));
        files.push(("frame_decode", format!("{name}_truncated"), b[..b.len() - 5.min(b.len() - 12)].to_vec()));
    }
    files.push(("roundtrip", "stream".into(), stream.clone()));
    files.push(("wire_decode_chunked", "stream_bytewise".into(), prefix(&[0], u16::MAX, &stream)));
    files.push(("wire_decode_chunked", "stream_chunks".into(), prefix(&[3, 11, 31, 0], u16::MAX, &stream)));
    files.push(("wire_decode_chunked", "stream_fault".into(), prefix(&[7], 100, &stream)));
    files.push(("wire_decode_chunked", "four_gib".into(), prefix(&[], u16::MAX, &four_gib)));
    files.push(("frame_decode", "four_gib".into(), four_gib.clone()));
    files.push(("frame_decode", "max_bounds_top_corner".into(), encode_to_vec(&max_bounds)));
    files.push(("roundtrip", "max_bounds_top_corner".into(), encode_to_vec(&max_bounds)));
    files.push(("wire_decode_chunked", "bad_magic".into(), prefix(&[1], u16::MAX, b"HTTP/1.1 200 OK\r\n")));
    files.push((
        "wire_decode_chunked",
        "bye_then_garbage".into(),
        prefix(&[], u16::MAX, b"VWRP\x01\x00\x05\x00\0\0\0\0VWRP\x02\x00"),
    ));

    // lbvh: the target's own layout (selector 0 = nice float: mantissa byte, exponent byte).
    let nice = |m: i8, e: u8| [0u8, m as u8, e];
    let mut lb = Vec::new();
    for v in [nice(0, 12), nice(0, 12), nice(0, 12), nice(16, 12), nice(16, 12), nice(16, 12), nice(1, 4)] {
        lb.extend_from_slice(&v);
    }
    let header = lb.clone();
    lb.push(64);
    for i in 0..64u8 {
        lb.extend_from_slice(&[1, i % 4, i / 4 % 4, i / 16, 40, 0]);
    }
    for k in 0..8u8 {
        lb.extend_from_slice(&[1, 0, 40, 12, 0, 30, 12, 0, 5, 12, k, 0]);
        lb.extend_from_slice(&[3, 32, 32, 0, 20, 12, 0, 10, 12, 16, 16]);
    }
    files.push(("lbvh", "grid64".into(), lb));
    let mut dup = header.clone();
    dup.push(40);
    dup.extend_from_slice(&[1, 1, 1, 1, 7, 0]);
    for i in 1..40u8 {
        dup.extend_from_slice(&[0, i]);
    }
    dup.extend_from_slice(&[2, 0, 0, 2, 0, 12]);
    files.push(("lbvh", "duplicates".into(), dup));
    let mut one = header;
    one.extend_from_slice(&[1, 3, 3, 3, 3, 100, 0, 2, 0, 0, 1, 8, 12]);
    files.push(("lbvh", "one".into(), one));

    for (t, name, data) in files {
        let dir = format!("seeds/{t}");
        fs::create_dir_all(&dir).unwrap();
        fs::write(format!("{dir}/{name}"), &data).unwrap();
    }
}
