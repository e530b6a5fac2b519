//! Property tests of volwarp-core: quantization round trip, wire round trip and rejection,
//! LBVH validity and traversal against brute force.

use proptest::prelude::*;
use volwarp_core::camera::Camera;
use volwarp_core::heuristics::Heuristic;
use volwarp_core::lbvh::Lbvh;
use volwarp_core::sample::{self, Bounds, Dequantizer, Quantizer, POS_MAX, RADIUS_MAX};
use volwarp_core::traversal::brute_force;
use volwarp_core::wire::{self, CameraRequest, Frame, FrameHeader, Hello, Limits, Message, WireError};
use volwarp_core::{Scene, Vec3};

fn vec3_in(lo: f32, hi: f32) -> impl Strategy<Value = Vec3> {
    (lo..hi, lo..hi, lo..hi).prop_map(|(x, y, z)| Vec3::new(x, y, z))
}

fn bounds() -> impl Strategy<Value = Bounds> {
    (vec3_in(-1000.0, 1000.0), vec3_in(0.0, 500.0)).prop_map(|(min, ext)| Bounds::new(min, min + ext))
}

fn camera() -> impl Strategy<Value = Camera> {
    (vec3_in(-50.0, 50.0), vec3_in(-5.0, 5.0), 10.0f32..120.0, 1u32..512, 1u32..512).prop_filter_map(
        "degenerate",
        |(eye, target, fov, w, h)| {
            let c = Camera::look_at(eye, target, Vec3::Y, fov, w, h);
            c.validate(4096).ok().map(|_| c)
        },
    )
}

/// A frame of `n` samples inside `b`.
fn frame_of(points: &[(Vec3, u32)], b: Bounds, radius_unit: f32, cam: Camera) -> Frame {
    let q = Quantizer::new(b, radius_unit);
    let samples: Vec<u64> = points.iter().map(|&(p, _)| q.pack(p, radius_unit * 3.0)).collect();
    let colors: Vec<u32> = points.iter().map(|&(_, c)| c | 0xff00_0000).collect();
    Frame {
        header: FrameHeader {
            seq: 7,
            camera: cam,
            heuristic: Heuristic::Threshold,
            bounds: b,
            radius_unit,
            render_us: 1234,
            level: 0,
            count: samples.len() as u32,
        },
        samples,
        colors,
        segments: Vec::new(),
    }
}

fn check_scene(scene: &Scene, rays: &[(Vec3, Vec3)]) {
    let lbvh: Lbvh = scene.lbvh();
    let mut seen = vec![0u8; 2 * scene.samples.len()];
    lbvh.check(&mut seen).expect("valid tree");
    for &(o, d) in rays {
        let ray = volwarp_core::Ray { origin: o, dir: d.normalize() };
        let a = lbvh.trace(&ray);
        let b = brute_force(&scene.samples, &scene.deq, &ray);
        assert_eq!(a, b, "ray {o} {d}");
        // Every hit (the multi-hit traversal of layered frames), and the four nearest with a
        // pruning bound, against testing every sphere.
        let mut all: Vec<(u32, u32)> = (0..scene.samples.len() as u32)
            .filter_map(|k| {
                let s = scene.samples[k as usize];
                volwarp_core::sphere::intersect(ray.origin, ray.dir, scene.deq.center(s), scene.deq.radius(s))
                    .map(|t| (t.to_bits(), k))
            })
            .collect();
        all.sort_unstable();
        let mut got = Vec::new();
        lbvh.hits(&ray, |t, k| {
            got.push((t.to_bits(), k));
            f32::INFINITY
        });
        got.sort_unstable();
        assert_eq!(got, all, "every hit, ray {o} {d}");
        let mut near: Vec<(u32, u32)> = Vec::new();
        lbvh.hits(&ray, |t, k| {
            near.push((t.to_bits(), k));
            near.sort_unstable();
            near.truncate(4);
            if near.len() == 4 {
                f32::from_bits(near[3].0)
            } else {
                f32::INFINITY
            }
        });
        assert_eq!(near, all[..all.len().min(4)], "four nearest, ray {o} {d}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, .. ProptestConfig::default() })]

    #[test]
    fn quantization_error_is_at_most_half_a_quantum(b in bounds(), t in vec3_in(0.0, 1.0), r in 0.0f32..10.0) {
        let p = b.min() + (b.max() - b.min()) * t;
        let q = Quantizer::new(b, 0.01);
        let d = Dequantizer::new(b, 0.01);
        let s = q.pack(p, r);
        let back = d.center(s);
        let quantum = (b.max() - b.min()) / POS_MAX as f32;
        for a in 0..3 {
            // Half a quantum, plus float rounding of the decode itself.
            let tol = quantum[a] * 0.5 + (b.min()[a].abs() + b.max()[a].abs()) * 4.0 * f32::EPSILON;
            prop_assert!((back[a] - p[a]).abs() <= tol, "axis {a}: {} vs {} (tol {tol})", back[a], p[a]);
        }
        let code = sample::radius_code(s);
        if r > 0.0 {
            prop_assert!((1..=RADIUS_MAX).contains(&code));
            let rr = d.radius(s);
            prop_assert!(code == RADIUS_MAX || (rr - r).abs() <= 0.005 + 1e-6 || code == 1);
        } else {
            prop_assert_eq!(code, 0);
        }
    }

    #[test]
    fn points_exactly_on_the_bounds_round_trip(b in bounds(), corner in 0u8..8) {
        let pick = |bit: u8, a: usize| if corner & (1 << bit) != 0 { b.max[a] } else { b.min[a] };
        let p = Vec3::new(pick(0, 0), pick(1, 1), pick(2, 2));
        let s = Quantizer::new(b, 1.0).pack(p, 1.0);
        let (x, y, z) = sample::unpack_position(s);
        for (a, q) in [x, y, z].into_iter().enumerate() {
            let expect = if corner & (1 << a) != 0 && b.max[a] > b.min[a] { POS_MAX } else { 0 };
            prop_assert_eq!(q, expect);
        }
    }

    #[test]
    fn camera_request_round_trips(cam in camera(), seq in any::<u64>(), h in 0u8..8, rs in 0.01f32..16.0, layers in 0u8..=16) {
        let m = Message::CameraRequest(CameraRequest { seq, camera: cam, heuristic: Heuristic::from_code(h).unwrap(), radius_scale: rs, layers });
        let bytes = wire::encode_to_vec(&m);
        let back = wire::read_message(&mut &bytes[..], &Limits::default()).unwrap();
        prop_assert_eq!(back, m);
    }

    #[test]
    fn frame_round_trips(cam in camera(), b in bounds(), pts in prop::collection::vec((vec3_in(0.0, 1.0), any::<u32>()), 0..64)) {
        let pts: Vec<(Vec3, u32)> = pts.into_iter().map(|(t, c)| (b.min() + (b.max() - b.min()) * t, c)).collect();
        let cam = Camera { width: 64, height: 64, ..cam };
        let m = Message::Frame(frame_of(&pts, b, 0.01, cam));
        let bytes = wire::encode_to_vec(&m);
        prop_assert_eq!(bytes.len(), wire::HEADER_LEN + wire::FRAME_FIXED_LEN + 12 * pts.len());
        let back = wire::read_message(&mut &bytes[..], &Limits::default()).unwrap();
        prop_assert_eq!(back, m);
    }

    #[test]
    fn any_truncation_is_an_error_not_a_panic(cam in camera(), cut in 0usize..200) {
        let cam = Camera { width: 8, height: 8, ..cam };
        let b = Bounds::new(Vec3::ZERO, Vec3::ONE);
        let m = Message::Frame(frame_of(&[(Vec3::splat(0.5), 1), (Vec3::splat(0.25), 2)], b, 0.01, cam));
        let bytes = wire::encode_to_vec(&m);
        let cut = cut.min(bytes.len() - 1);
        let r = wire::read_message(&mut &bytes[..cut], &Limits::default());
        prop_assert!(matches!(r, Err(WireError::UnexpectedEof) | Err(WireError::Closed)), "{r:?}");
    }

    #[test]
    fn lbvh_is_valid_and_traces_like_brute_force(
        pts in prop::collection::vec(vec3_in(0.0, 1.0), 1..300),
        rays in prop::collection::vec((vec3_in(-2.0, 3.0), vec3_in(-1.0, 1.0)), 16),
    ) {
        let b = Bounds::new(Vec3::ZERO, Vec3::ONE);
        let pts: Vec<(Vec3, u32)> = pts.into_iter().enumerate().map(|(i, p)| (p, i as u32)).collect();
        let cam = Camera::look_at(Vec3::new(0.5, 0.5, 3.0), Vec3::splat(0.5), Vec3::Y, 45.0, 32, 32);
        let scene = Scene::build(&frame_of(&pts, b, 0.01, cam));
        let rays: Vec<_> = rays.into_iter().filter(|(_, d)| d.length() > 1e-3).collect();
        check_scene(&scene, &rays);
    }
}

fn camera_rays(cam: &Camera, step: u32) -> Vec<(Vec3, Vec3)> {
    let mut v = Vec::new();
    for y in (0..cam.height).step_by(step as usize) {
        for x in (0..cam.width).step_by(step as usize) {
            let r = cam.ray(x, y);
            v.push((r.origin, r.dir));
        }
    }
    v
}

#[test]
fn lbvh_on_a_clustered_cloud() {
    // Three tight clusters far apart plus a diffuse halo.
    let mut pts = Vec::new();
    let mut seed = 12345u32;
    let mut rnd = || {
        seed ^= seed << 13;
        seed ^= seed >> 17;
        seed ^= seed << 5;
        seed as f32 / u32::MAX as f32
    };
    for c in [Vec3::new(0.1, 0.1, 0.1), Vec3::new(0.9, 0.5, 0.2), Vec3::new(0.5, 0.9, 0.9)] {
        for _ in 0..1500 {
            pts.push((c + Vec3::new(rnd(), rnd(), rnd()) * 0.01, 1));
        }
    }
    for _ in 0..500 {
        pts.push((Vec3::new(rnd(), rnd(), rnd()), 2));
    }
    let b = Bounds::new(Vec3::ZERO, Vec3::ONE);
    let cam = Camera::look_at(Vec3::new(0.5, 0.5, 2.5), Vec3::splat(0.5), Vec3::Y, 50.0, 48, 48);
    let scene = Scene::build(&frame_of(&pts, b, 0.0005, cam));
    check_scene(&scene, &camera_rays(&cam, 1));
    check_scene(&scene, &camera_rays(&cam.orbit(77.0, 20.0), 1));
}

#[test]
fn lbvh_with_thousands_of_identical_points() {
    let pts = vec![(Vec3::splat(0.3), 5u32); 5000];
    let b = Bounds::new(Vec3::ZERO, Vec3::ONE);
    let cam = Camera::look_at(Vec3::new(0.3, 0.3, 2.0), Vec3::splat(0.3), Vec3::Y, 30.0, 24, 24);
    let scene = Scene::build(&frame_of(&pts, b, 0.01, cam));
    check_scene(&scene, &camera_rays(&cam, 1));
    // The tie rule makes the smallest index win.
    let hit = scene.lbvh().trace(&cam.ray(12, 12)).expect("centre ray hits");
    assert_eq!(hit.prim, 0);
    // Balanced despite equal codes: depth stays logarithmic-ish (the tie-break splits ranges).
    assert!(max_depth(&scene) < 40, "depth {}", max_depth(&scene));
}

#[test]
fn all_samples_in_zero_extent_bounds() {
    let p = Vec3::new(2.0, -1.0, 4.0);
    let pts = vec![(p, 5u32); 100];
    let b = Bounds::new(p, p);
    let cam = Camera::look_at(Vec3::new(2.0, -1.0, 9.0), p, Vec3::Y, 30.0, 16, 16);
    let scene = Scene::build(&frame_of(&pts, b, 0.1, cam));
    check_scene(&scene, &camera_rays(&cam, 1));
}

#[test]
fn empty_and_single_sample_scenes() {
    let b = Bounds::new(Vec3::ZERO, Vec3::ONE);
    let cam = Camera::look_at(Vec3::new(0.5, 0.5, 3.0), Vec3::splat(0.5), Vec3::Y, 45.0, 16, 16);
    let empty = Scene::build(&frame_of(&[], b, 0.01, cam));
    assert!(empty.nodes.is_empty());
    assert_eq!(empty.lbvh().trace(&cam.ray(8, 8)), None);
    let one = Scene::build(&frame_of(&[(Vec3::splat(0.5), 9)], b, 0.1, cam));
    assert!(one.nodes.is_empty());
    assert_eq!(one.lbvh().trace(&cam.ray(8, 8)).map(|h| h.prim), Some(0));
    check_scene(&one, &camera_rays(&cam, 1));
}

fn max_depth(scene: &Scene) -> usize {
    use volwarp_core::lbvh::LEAF_BIT;
    let mut best = 0;
    let mut stack = vec![(0u32, 1usize)];
    while let Some((n, d)) = stack.pop() {
        best = best.max(d);
        let node = scene.nodes[n as usize];
        for c in [node.left, node.right] {
            if c & LEAF_BIT == 0 {
                stack.push((c, d + 1));
            }
        }
    }
    best
}

#[test]
fn decoder_rejects_bad_input_with_typed_errors() {
    let lim = Limits::default();
    let cam = Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y, 45.0, 8, 8);
    let b = Bounds::new(Vec3::ZERO, Vec3::ONE);
    let good = wire::encode_to_vec(&Message::Frame(frame_of(&[(Vec3::splat(0.5), 1)], b, 0.01, cam)));

    let mut bad = good.clone();
    bad[0] = b'X';
    assert!(matches!(wire::read_message(&mut &bad[..], &lim), Err(WireError::BadMagic(_))));

    let mut bad = good.clone();
    bad[4] = 9;
    assert_eq!(wire::read_message(&mut &bad[..], &lim), Err(WireError::UnsupportedVersion(9)));

    let mut bad = good.clone();
    bad[6] = 77;
    assert_eq!(wire::read_message(&mut &bad[..], &lim), Err(WireError::UnknownType(77)));

    // A header promising 4 GiB is refused before anything is allocated.
    let mut bad = good.clone();
    bad[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(matches!(wire::read_message(&mut &bad[..], &lim), Err(WireError::TooLarge { .. })));

    // Count inconsistent with length.
    let mut bad = good.clone();
    let count_at = wire::HEADER_LEN + wire::FRAME_FIXED_LEN - 4;
    bad[count_at..count_at + 4].copy_from_slice(&2u32.to_le_bytes());
    assert!(matches!(wire::read_message(&mut &bad[..], &lim), Err(WireError::BadLength { .. })));

    // NaN in the camera eye.
    let mut bad = good.clone();
    let eye_at = wire::HEADER_LEN + 8;
    bad[eye_at..eye_at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    assert!(matches!(wire::read_message(&mut &bad[..], &lim), Err(WireError::BadCamera(_))));

    // Inverted bounds.
    let mut bad = good.clone();
    let bmin = wire::HEADER_LEN + 8 + wire::CAMERA_LEN + 4;
    bad[bmin..bmin + 4].copy_from_slice(&5.0f32.to_le_bytes());
    assert_eq!(wire::read_message(&mut &bad[..], &lim), Err(WireError::BadBounds));

    // Infinite radius unit.
    let mut bad = good.clone();
    let ru = bmin + 24;
    bad[ru..ru + 4].copy_from_slice(&f32::INFINITY.to_le_bytes());
    assert_eq!(wire::read_message(&mut &bad[..], &lim), Err(WireError::BadRadius));

    // More samples than pixels.
    let many: Vec<(Vec3, u32)> = (0..65).map(|i| (Vec3::splat(i as f32 / 65.0), 1)).collect();
    let big = wire::encode_to_vec(&Message::Frame(frame_of(&many, b, 0.01, cam)));
    assert!(matches!(wire::read_message(&mut &big[..], &lim), Err(WireError::TooManySamples { .. })));

    // A server reading requests refuses frames by size (a frame larger than its largest
    // request, a VisualEdit).
    let requests = Limits::for_requests(4096);
    let many: Vec<(Vec3, u32)> = (0..1000).map(|i| (Vec3::splat(i as f32 / 1000.0), 1)).collect();
    let huge = wire::encode_to_vec(&Message::Frame(frame_of(&many, b, 0.01, cam)));
    assert!(huge.len() > requests.max_payload as usize + wire::HEADER_LEN);
    assert!(matches!(wire::read_message(&mut &huge[..], &requests), Err(WireError::TooLarge { .. })));

    // Empty input is a clean close.
    assert_eq!(wire::read_message(&mut &[][..], &lim), Err(WireError::Closed));
}

#[test]
fn hello_error_bye_round_trip() {
    let lim = Limits::default();
    for m in [
        Message::Hello(Hello::new(wire::CAP_GPU).with_token(b"secret").unwrap()),
        Message::Hello(Hello::new(0)),
        Message::Error(wire::ErrorMsg::new(wire::error_code::UNAUTHORIZED, "wrong token")),
        Message::Error(wire::ErrorMsg::new(1, &"é".repeat(200))),
        Message::Bye,
    ] {
        let bytes = wire::encode_to_vec(&m);
        assert_eq!(wire::read_message(&mut &bytes[..], &lim).unwrap(), m);
    }
    assert_eq!(Hello::new(0).with_token(&[0u8; 65]), Err(WireError::BadToken));
    let long = wire::ErrorMsg::new(1, &"é".repeat(200));
    assert!(long.text.len() <= wire::MAX_ERROR_TEXT);
}

#[test]
fn record_entries_round_trip() {
    use volwarp_core::record::{self, Entry};
    let cam = Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y, 45.0, 8, 8);
    let b = Bounds::new(Vec3::ZERO, Vec3::ONE);
    let entries = vec![
        Entry::Frame { t_us: 5, frame: frame_of(&[(Vec3::splat(0.5), 1)], b, 0.01, cam) },
        Entry::Camera {
            t_us: 17,
            request: CameraRequest {
                seq: 3,
                camera: cam.orbit(5.0, 0.0),
                heuristic: Heuristic::Peak,
                radius_scale: 1.0,
                layers: 0,
            },
        },
    ];
    let mut bytes = Vec::new();
    let mut w = wire::VecWriter(&mut bytes);
    record::write_magic(&mut w).unwrap();
    for e in &entries {
        record::write_entry(&mut w, e).unwrap();
    }
    let mut r = &bytes[..];
    record::read_magic(&mut r).unwrap();
    let mut back = Vec::new();
    while let Some(e) = record::read_entry(&mut r, &Limits::default()).unwrap() {
        back.push(e);
    }
    assert_eq!(back, entries);
    assert_eq!(record::read_magic(&mut &b"VWRECXXX"[..]), Err(record::RecordError::BadMagic));
}

#[test]
fn a_requests_layers_wanted_sit_in_byte_57_and_older_requests_read_as_the_hellos() {
    let cam = Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y, 40.0, 64, 48);
    let req = CameraRequest { seq: 3, camera: cam, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 1 };
    let mut bytes = wire::encode_to_vec(&Message::CameraRequest(req));
    assert_eq!(bytes.len(), wire::HEADER_LEN + wire::CAMERA_REQUEST_LEN);
    assert_eq!(u16::from_le_bytes([bytes[4], bytes[5]]), wire::VERSION, "written as the current version");
    let at = wire::HEADER_LEN + 57;
    assert_eq!((bytes[at - 1], bytes[at], bytes[at + 1], bytes[at + 2]), (Heuristic::Threshold.code(), 1, 0, 0));
    let read = |b: &[u8]| wire::read_message(&mut &b[..], &Limits::default());
    assert_eq!(read(&bytes).unwrap(), Message::CameraRequest(req));
    // A version-4 request (byte 57 reserved, written 0) reads as asking for the Hello's count.
    bytes[4] = 4;
    bytes[at] = 0;
    assert_eq!(read(&bytes).unwrap(), Message::CameraRequest(CameraRequest { layers: 0, ..req }));
    bytes[4] = 1;
    assert!(read(&bytes).is_ok(), "version 1 still reads");
    // More than the wire's most segments per pixel is refused, not clamped.
    bytes[at] = wire::MAX_LAYERS as u8 + 1;
    assert!(matches!(read(&bytes), Err(WireError::Layers(_))), "{:?}", read(&bytes));
    bytes[at] = wire::MAX_LAYERS as u8;
    assert!(read(&bytes).is_ok());
}

/// A ray's segments as the marcher makes them: premultiplied colors, opacities from faint to
/// nearly opaque (`scale` shrinks a whole ray's opacities, as in faint, fuzzy volumes).
fn segment_list() -> impl Strategy<Value = Vec<volwarp_core::segments::Segment>> {
    let seg = (0.0f32..=1.0, 0.0f32..=1.0, 0.0f32..=1.0, 0.0f32..=1.0, 0.0f32..=1.0);
    (proptest::collection::vec(seg, 1..=16), prop_oneof![Just(1.0f32), 0.0f32..0.1]).prop_map(|(v, scale)| {
        v.into_iter()
            .enumerate()
            .map(|(j, (a, sat, r, g, b))| {
                let a = a * scale;
                let ch = |x: f32| a * (sat + (1.0 - sat) * x);
                volwarp_core::segments::Segment { t: j as f32, color: [ch(r), ch(g), ch(b), a] }
            })
            .collect()
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2048, ..ProptestConfig::default() })]

    /// At the frame's own camera a client compositing the packed segment colors shows the
    /// ray's own pixel (the server's image) over the background, and the colors stay
    /// premultiplied.
    #[test]
    fn packed_segments_show_the_rays_pixel(segs in segment_list()) {
        use volwarp_core::segments::{composite, pack_colors, shown_pixel};
        let ray = composite(segs.iter().map(|s| s.color));
        let mut packed = vec![0u32; segs.len()];
        pack_colors(&segs, ray, &mut packed);
        for c in &packed {
            let [r, g, b, a] = c.to_le_bytes();
            prop_assert!(r <= a && g <= a && b <= a, "premultiplied: {:08x}", c);
        }
        let shown = shown_pixel(&packed);
        let want = sample::over_background(sample::pack_color_f32(ray), volwarp_core::BACKGROUND);
        prop_assert_eq!(shown, want, "packed {:08x?}", packed);
    }
}

/// A frame message written as FrameParts of the given sizes (cycled; each at most PART_LEN).
fn in_parts(message: &[u8], sizes: &[usize]) -> Vec<u8> {
    let mut out = Vec::new();
    let (mut at, mut i) = (0, 0);
    while at < message.len() {
        let n = sizes[i % sizes.len()].clamp(1, wire::PART_LEN).min(message.len() - at);
        wire::write_frame_part(&mut wire::VecWriter(&mut out), &message[at..at + n]).unwrap();
        at += n;
        i += 1;
    }
    out
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, .. ProptestConfig::default() })]

    /// A frame sent in parts of any sizes, after a frame dropped part-way, reads as the frame
    /// sent whole, byte for byte; a message between parts, a part past the frame's end and a
    /// stream ending inside the parts are typed errors.
    #[test]
    fn a_frame_in_parts_reads_as_the_frame_sent_whole(
        b in bounds(),
        n in 1usize..6000,
        sizes in prop::collection::vec(1usize..40_000, 1..6),
        cut in 1usize..100_000,
    ) {
        let cam = Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y, 40.0, 100, 100);
        let points: Vec<(Vec3, u32)> =
            (0..n).map(|i| (b.min() + (b.max() - b.min()) * (i as f32 / n as f32), i as u32)).collect();
        let frame = frame_of(&points, b, 0.01, cam);
        let whole = wire::encode_to_vec(&Message::Frame(frame.clone()));
        let limits = Limits::for_frames(100);
        let parts = in_parts(&whole, &sizes);
        // A dropped frame first: some of its parts, then FrameDropped.
        let cut = cut % whole.len();
        let mut stream = if cut > 0 { in_parts(&whole[..cut], &sizes) } else { Vec::new() };
        wire::write_frame_dropped(&mut wire::VecWriter(&mut stream)).unwrap();
        stream.extend_from_slice(&parts);
        let mut bye = Vec::new();
        wire::write_bye(&mut wire::VecWriter(&mut bye)).unwrap();
        stream.extend_from_slice(&bye);
        let mut r = &stream[..];
        prop_assert_eq!(wire::read_message(&mut r, &limits).unwrap(), Message::Frame(frame.clone()));
        prop_assert_eq!(wire::read_message(&mut r, &limits).unwrap(), Message::Bye);
        let mut r = &stream[..];
        let (bytes, h) = wire::read_message_bytes(&mut r, &limits).unwrap();
        prop_assert_eq!(&bytes, &whole);
        prop_assert_eq!(wire::decode_message(&bytes, &h, &limits).unwrap(), Message::Frame(frame));
        // Cut short inside the parts: the stream ended inside a message.
        if cut > 0 && cut < parts.len() {
            prop_assert!(matches!(
                wire::read_message(&mut &parts[..cut.max(wire::HEADER_LEN + 1)], &limits),
                Err(WireError::UnexpectedEof)
            ));
        }
        // Bye between two parts.
        let first = parts.len().min(wire::HEADER_LEN + sizes[0].min(wire::PART_LEN).min(whole.len()));
        if first < parts.len() {
            let mut bad = parts[..first].to_vec();
            bad.extend_from_slice(&bye);
            bad.extend_from_slice(&parts[first..]);
            prop_assert!(matches!(wire::read_message(&mut &bad[..], &limits), Err(WireError::BadParts(_))));
        }
    }
}

#[test]
fn frame_parts_carry_only_frames_within_the_limits() {
    let limits = Limits::for_frames(64);
    let mut hello = Vec::new();
    wire::write_hello(&mut wire::VecWriter(&mut hello), &Hello::new(0)).unwrap();
    let parts = in_parts(&hello, &[5]);
    assert!(matches!(wire::read_message(&mut &parts[..], &limits), Err(WireError::BadParts(_))));
    // A frame over the receiver's limit is refused at its header, before more is held.
    let cam = Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y, 40.0, 100, 100);
    let b = Bounds::new(Vec3::ZERO, Vec3::ONE);
    let big: Vec<(Vec3, u32)> = (0..5000).map(|i| (Vec3::splat(i as f32 / 5000.0), 7)).collect();
    let whole = wire::encode_to_vec(&Message::Frame(frame_of(&big, b, 0.01, cam)));
    let parts = in_parts(&whole, &[wire::PART_LEN]);
    assert!(matches!(wire::read_message(&mut &parts[..], &limits), Err(WireError::TooLarge { .. })));
    // Empty and oversized parts are refused at their header; a part read alone is refused.
    let mut empty = Vec::new();
    wire::write_header(&mut wire::VecWriter(&mut empty), wire::MsgType::FramePart, 0).unwrap();
    assert!(matches!(wire::read_message(&mut &empty[..], &limits), Err(WireError::BadLength { .. })));
    assert!(wire::write_frame_part(&mut wire::VecWriter(&mut Vec::new()), &vec![0; wire::PART_LEN + 1]).is_err());
    let one = in_parts(&whole[..100], &[100]);
    let h = wire::read_header(&mut &one[..], &Limits::for_frames(100)).unwrap();
    assert!(matches!(wire::read_payload(&mut &one[wire::HEADER_LEN..], &h, &limits), Err(WireError::BadParts(_))));
}
