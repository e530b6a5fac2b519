//! Stable mirrors of the cargo-fuzz targets in `fuzz/` (see `docs/fuzzing.md`), run by plain
//! `cargo test`: proptest feeds the very same check functions (`fuzz/src/checks.rs`, included
//! below) with structured messages, mutated encodings and raw bytes; the committed seed corpora
//! and every crash the fuzzer found replay here as regression tests.

#[allow(dead_code)]
#[path = "../../fuzz/src/checks.rs"]
mod checks;

use proptest::prelude::*;
use std::path::PathBuf;
use volwarp_core::camera::Camera;
use volwarp_core::heuristics::Heuristic;
use volwarp_core::sample::{Bounds, Dequantizer};
use volwarp_core::scene::Scene;
use volwarp_core::traversal::brute_force;
use volwarp_core::wire::{
    encode_to_vec, preset_name, ErrorMsg, Frame, FrameHeader, Hello, Message, PresetName, TfPoints, VisualEdit,
    VisualState,
};
use volwarp_core::{Ray, Vec3};

#[global_allocator]
static ALLOC: checks::CountingAlloc = checks::CountingAlloc;

// ---------------------------------------------------------------- strategies

/// Mostly small exact values (so messages validate), sometimes any bit pattern.
fn float() -> impl Strategy<Value = f32> {
    prop_oneof![
        4 => (-64i32..=64).prop_map(|v| v as f32 * 0.25),
        1 => any::<u32>().prop_map(f32::from_bits),
    ]
}

fn vec3() -> impl Strategy<Value = Vec3> {
    (float(), float(), float()).prop_map(|(x, y, z)| Vec3::new(x, y, z))
}

fn camera() -> impl Strategy<Value = Camera> {
    let fov = prop_oneof![3 => (1u32..=179).prop_map(|v| v as f32), 1 => float()];
    let dim = prop_oneof![6 => 0u32..=80, 1 => any::<u32>()];
    (vec3(), vec3(), vec3(), fov, dim.clone(), dim).prop_map(|(eye, target, up, fov_y_deg, width, height)| Camera {
        eye,
        target,
        up,
        fov_y_deg,
        width,
        height,
    })
}

fn heuristic() -> impl Strategy<Value = Heuristic> {
    (0usize..8).prop_map(|i| Heuristic::ALL[i])
}

fn frame() -> impl Strategy<Value = Frame> {
    (
        prop::collection::vec((any::<u64>(), any::<u32>()), 0..40),
        any::<u64>(),
        camera(),
        heuristic(),
        vec3(),
        vec3(),
        float(),
        any::<u32>(),
    )
        .prop_map(|(sc, seq, camera, heuristic, min, max, radius_unit, render_us)| {
            let (samples, colors): (Vec<u64>, Vec<u32>) = sc.into_iter().unzip();
            let header = FrameHeader {
                seq,
                camera,
                heuristic,
                bounds: Bounds::new(min, max),
                radius_unit,
                render_us,
                // Any level of detail (drawn from the time's bits: the tuple is full).
                level: (render_us >> 24) as u8,
                count: samples.len() as u32,
            };
            Frame { header, samples, colors, segments: Vec::new() }
        })
}

fn message() -> impl Strategy<Value = Message> {
    prop_oneof![
        (any::<u16>(), any::<u32>(), prop::collection::vec(any::<u8>(), 0..=64)).prop_map(|(version, caps, token)| {
            Message::Hello(
                Hello { version, capabilities: caps, token: Default::default(), layers: 1 }.with_token(&token).unwrap(),
            )
        }),
        (any::<u64>(), camera(), heuristic(), float(), 0u8..=20)
            .prop_map(|(seq, cam, h, rs, layers)| checks::camera_request(seq, cam, h, rs, layers)),
        frame().prop_map(Message::Frame),
        (any::<u16>(), ".{0,80}").prop_map(|(code, text)| Message::Error(ErrorMsg::new(code, &text))),
        Just(Message::Bye),
        visual_edit().prop_map(Message::VisualEdit),
        visual_state().prop_map(Message::VisualState),
    ]
}

fn floats<const N: usize>() -> impl Strategy<Value = [f32; N]> {
    prop::collection::vec(float(), N).prop_map(|v| v.try_into().unwrap())
}

fn name() -> impl Strategy<Value = PresetName> {
    "[a-z-]{0,32}".prop_map(|s| preset_name(&s).unwrap())
}

fn visual_edit() -> impl Strategy<Value = VisualEdit> {
    let tf = (prop::collection::vec(floats::<4>(), 0..=8), prop::collection::vec(floats::<2>(), 0..=8))
        .prop_map(|(c, o)| TfPoints { color: c.into_iter().collect(), opacity: o.into_iter().collect() });
    (
        any::<u32>(),
        prop::option::of(any::<bool>()),
        prop::option::of(name()),
        prop::option::of(floats::<2>()),
        prop::option::of(float()),
        prop::option::of(floats::<6>()),
        prop::option::of(prop::option::of(floats::<6>())),
        prop::option::of(tf),
    )
        .prop_map(|(id, shade, preset, window_level, opacity_scale, crop, clip, transfer_function)| VisualEdit {
            id,
            shade,
            preset,
            window_level,
            opacity_scale,
            crop,
            clip,
            transfer_function,
        })
}

fn visual_state() -> impl Strategy<Value = VisualState> {
    (
        any::<u32>(),
        any::<(bool, bool)>(),
        name(),
        floats::<2>(),
        float(),
        floats::<6>(),
        prop::option::of(floats::<6>()),
        prop::collection::vec(name(), 0..=16),
    )
        .prop_map(|(id, (shade, custom), preset, window_level, opacity_scale, crop, clip, presets)| VisualState {
            id,
            shade,
            preset,
            custom,
            window_level,
            opacity_scale,
            crop,
            clip,
            presets: presets.into_iter().collect(),
        })
}

/// A mutation of an encoded stream: flip a byte, overwrite a little-endian `u32` with an
/// interesting value, or truncate.
#[derive(Clone, Debug)]
enum Mutation {
    Flip(usize, u8),
    Word(usize, u32),
    Truncate(usize),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    let word = prop_oneof![Just(0u32), Just(u32::MAX), Just(0x7fc0_0000), Just(0x7f80_0000), any::<u32>()];
    prop_oneof![
        3 => (any::<usize>(), 1u8..=255).prop_map(|(p, x)| Mutation::Flip(p, x)),
        2 => (any::<usize>(), word).prop_map(|(p, w)| Mutation::Word(p, w)),
        1 => any::<usize>().prop_map(Mutation::Truncate),
    ]
}

fn apply(bytes: &mut Vec<u8>, muts: &[Mutation]) {
    for m in muts {
        if bytes.is_empty() {
            return;
        }
        let n = bytes.len();
        match *m {
            Mutation::Flip(p, x) => bytes[p % n] ^= x,
            Mutation::Word(p, w) => {
                let p = p % n;
                for (i, b) in w.to_le_bytes().into_iter().enumerate() {
                    if p + i < n {
                        bytes[p + i] = b;
                    }
                }
            }
            Mutation::Truncate(p) => bytes.truncate(p % (n + 1)),
        }
    }
}

fn stream(msgs: &[Message]) -> Vec<u8> {
    msgs.iter().flat_map(encode_to_vec).collect()
}

/// The `wire_decode_chunked` input layout: pattern length, pattern, fault position, stream.
fn chunked_input(pattern: &[u8], fail_at: Option<u16>, stream: &[u8]) -> Vec<u8> {
    let mut v = vec![pattern.len() as u8];
    v.extend_from_slice(pattern);
    v.extend_from_slice(&fail_at.unwrap_or(u16::MAX).to_le_bytes());
    v.extend_from_slice(stream);
    v
}

// ---------------------------------------------------------------- mirrors of the targets

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// Mirror of `wire_decode_chunked`: mutated streams of valid messages, any chunking, an
    /// optional I/O fault.
    #[test]
    fn wire_decode_chunked_mirror(
        msgs in prop::collection::vec(message(), 0..5),
        muts in prop::collection::vec(mutation(), 0..4),
        pattern in prop::collection::vec(any::<u8>(), 0..8),
        fail_at in prop::option::of(any::<u16>()),
    ) {
        let mut s = stream(&msgs);
        apply(&mut s, &muts);
        let fail_at = fail_at.map(|f| f % (s.len() as u16 + 8));
        checks::wire_decode_chunked(&chunked_input(&pattern, fail_at, &s));
    }

    /// Mirror of `wire_decode_chunked` on raw bytes behind a valid header prefix.
    #[test]
    fn wire_decode_chunked_raw_mirror(data in prop::collection::vec(any::<u8>(), 0..512)) {
        checks::wire_decode_chunked(&data);
        let mut v = b"\x03\x01\x05\x20\xff\xffVWRP\x01\x00".to_vec();
        v.extend_from_slice(&data);
        checks::wire_decode_chunked(&v);
    }

    /// Mirror of `frame_decode`: mutated frames.
    #[test]
    fn frame_decode_mirror(f in frame(), muts in prop::collection::vec(mutation(), 0..3)) {
        let mut s = encode_to_vec(&Message::Frame(f));
        apply(&mut s, &muts);
        checks::frame_decode(&s);
    }

    /// Mirror of `roundtrip`, structured half.
    #[test]
    fn roundtrip_message_mirror(m in message()) {
        checks::roundtrip_message(&m, &checks::LIMITS);
    }

    /// Mirror of `roundtrip`, bytes half: mutated streams.
    #[test]
    fn roundtrip_bytes_mirror(
        msgs in prop::collection::vec(message(), 0..5),
        muts in prop::collection::vec(mutation(), 0..3),
    ) {
        let mut s = stream(&msgs);
        apply(&mut s, &muts);
        checks::roundtrip_bytes(&s);
    }

    /// Mirror of `lbvh` on raw bytes (the target's own input layout), behind a header of
    /// valid bounds and radius unit so that most cases build a scene.
    #[test]
    fn lbvh_mirror(
        axes in prop::collection::vec((-128i8..=127, 0u8..=127, 0u8..24), 3),
        unit in (1u8..=127, 0u8..20),
        data in prop::collection::vec(any::<u8>(), 0..1200),
    ) {
        let mut v = Vec::new();
        for &(m, _, e) in &axes {
            v.extend_from_slice(&[0, m as u8, e]); // nice float: m · 2^(e − 12)
        }
        for &(m, d, e) in &axes {
            v.extend_from_slice(&[0, m.saturating_add(d.min(127) as i8) as u8, e]);
        }
        v.extend_from_slice(&[0, unit.0, unit.1]);
        v.extend_from_slice(&data);
        checks::lbvh(&data);
        checks::lbvh(&v);
    }

    /// Mirror of `lbvh` with structured input: clustered samples in nice bounds, rays aimed at
    /// samples.
    #[test]
    fn lbvh_structured_mirror(
        cells in prop::collection::vec((0u64..6, 0u64..6, 0u64..6, 1u64..1024), 0..120),
        lo in (-8i32..8, -8i32..8, -8i32..8),
        ext in (0u32..16, 0u32..16, 0u32..16),
        unit_exp in -20i32..0,
        rays in prop::collection::vec((vec3(), any::<u16>()), 1..8),
    ) {
        let min = Vec3::new(lo.0 as f32, lo.1 as f32, lo.2 as f32);
        let max = min + Vec3::new(ext.0 as f32, ext.1 as f32, ext.2 as f32) * 0.5;
        let samples: Vec<u64> =
            cells.iter().map(|&(x, y, z, r)| (x * 9000) | ((y * 7000) << 18) | ((z * 5000) << 36) | (r << 54)).collect();
        let colors = (0..samples.len() as u32).collect();
        let header = FrameHeader {
            seq: 0,
            camera: Camera::look_at(Vec3::Z, Vec3::ZERO, Vec3::Y, 60.0, 16, 16),
            heuristic: Heuristic::Threshold,
            bounds: Bounds::new(min, max),
            radius_unit: (2.0f32).powi(unit_exp),
            render_us: 0,
            level: 0,
            count: samples.len() as u32,
        };
        let frame = Frame { header, samples, colors, segments: Vec::new() };
        checks::check_scene(&frame);
        let scene = Scene::build(&frame);
        for (o, k) in rays {
            if scene.samples.is_empty() || !o.is_finite() {
                continue;
            }
            let c = scene.deq.center(scene.samples[k as usize % scene.samples.len()]);
            let d = (c - o).normalize_or_zero();
            if d == Vec3::ZERO {
                continue;
            }
            let ray = Ray { origin: o, dir: d };
            prop_assert_eq!(scene.lbvh().trace(&ray), brute_force(&scene.samples, &scene.deq, &ray));
        }
    }
}

// ---------------------------------------------------------------- corpora and regressions

fn fuzz_dir(sub: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../fuzz").join(sub)
}

/// Runs `check` on every file under `fuzz/<sub>/<target>/` (seeds and kept crash inputs).
fn replay(sub: &str, target: &str, check: fn(&[u8])) -> usize {
    let dir = fuzz_dir(sub).join(target);
    let Ok(entries) = std::fs::read_dir(&dir) else { return 0 };
    let mut n = 0;
    for e in entries.flatten() {
        let data = std::fs::read(e.path()).unwrap();
        check(&data);
        n += 1;
    }
    n
}

fn roundtrip(data: &[u8]) {
    checks::roundtrip_bytes(data);
}

#[test]
fn seed_corpora_replay() {
    let n = replay("seeds", "wire_decode_chunked", checks::wire_decode_chunked)
        + replay("seeds", "frame_decode", checks::frame_decode)
        + replay("seeds", "roundtrip", roundtrip)
        + replay("seeds", "lbvh", checks::lbvh)
        + replay("seeds", "compact_decode", checks::compact_decode);
    assert!(n >= 8, "expected the committed seed corpora under fuzz/seeds, found {n} files");
}

#[test]
fn kept_crash_inputs_replay() {
    replay("regressions", "wire_decode_chunked", checks::wire_decode_chunked);
    replay("regressions", "frame_decode", checks::frame_decode);
    replay("regressions", "roundtrip", roundtrip);
    replay("regressions", "lbvh", checks::lbvh);
    replay("regressions", "compact_decode", checks::compact_decode);
}

/// Mirror of `compact_decode`: consistent compact frames from random bytes (mode 1), and
/// streams of real compact messages with random bytes changed (mode 0).
mod compact_decode_mirror {
    use super::checks;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig { cases: 256, .. ProptestConfig::default() })]

        #[test]
        fn consistent_frames(data in proptest::collection::vec(any::<u8>(), 12..1200)) {
            let mut v = vec![1u8];
            v.extend(data);
            checks::compact_decode(&v);
        }

        #[test]
        fn edited_real_messages(data in proptest::collection::vec(any::<u8>(), 12..600), edits in proptest::collection::vec((any::<u16>(), any::<u8>()), 0..6)) {
            // A valid compact message from the bytes, then edited anywhere (header included).
            let Some((mut msg, _)) = checks::compact_frame_from(&data) else { return Ok(()) };
            for (at, v) in edits {
                let i = at as usize % msg.len();
                msg[i] = v;
            }
            let mut v = vec![0u8];
            v.extend(msg);
            checks::compact_decode(&v);
        }

        #[test]
        fn random_streams(data in proptest::collection::vec(any::<u8>(), 0..400)) {
            let mut v = vec![0u8];
            v.extend(b"VWRP\x02\x00\x06\x00");
            v.extend(data);
            checks::compact_decode(&v);
        }
    }
}

/// Found by `lbvh` (crash-f09201c7…): a sphere of radius ~1e-34, far smaller than the rounding
/// of the ray parameter at t ≈ 208, was hit by brute force but its box was culled because the
/// x and y slab intervals (each a single rounded point) did not overlap. Fixed in core by the
/// conservative far bound of `intersect_box` (`BOX_T_FAR_SCALE`, Ize 2013).
#[test]
fn regression_tiny_sphere_culled_by_rounding_in_the_slab_test() {
    let bounds = Bounds::new(Vec3::ZERO, Vec3::new(1024.0, 0.0, 0.091796875));
    let radius_unit = 3.8500897e-37;
    let samples = vec![0x4d00001000040001u64, 0x7640001000040001, 0x2140000000000303];
    let frame = Frame {
        header: FrameHeader {
            seq: 0,
            camera: Camera::look_at(Vec3::Z, Vec3::ZERO, Vec3::Y, 60.0, 16, 16),
            heuristic: Heuristic::Threshold,
            bounds,
            radius_unit,
            render_us: 0,
            level: 0,
            count: 3,
        },
        samples,
        colors: vec![1, 2, 3],
        segments: Vec::new(),
    };
    checks::check_scene(&frame);
    let scene = Scene::build(&frame);
    let origin = Vec3::new(208.0, -0.00024414063, 0.0);
    // The fuzzer's ray, aimed at the center of the first sample.
    let ray = Ray { origin, dir: Vec3::new(-1.0, 1.1737751e-6, 1.6835827e-9) };
    let slow = brute_force(&scene.samples, &scene.deq, &ray);
    assert!(slow.is_some_and(|h| h.t > 207.0 && h.t < 209.0), "the aimed ray hits by brute force: {slow:?}");
    assert_eq!(scene.lbvh().trace(&ray), slow);
    // Before the fix, the plain slab test culled the sample's own box.
    let deq = Dequantizer::new(bounds, radius_unit);
    let (lo, hi) = volwarp_core::sphere::sphere_box(deq.center(0x4d00001000040001), deq.radius(0x4d00001000040001));
    assert!(volwarp_core::sphere::intersect_box(ray.origin, Vec3::ONE / ray.dir, lo, hi, f32::INFINITY).is_some());
}

/// The `lbvh` target's domain excludes what no box test can agree with (documented in
/// `docs/fuzzing.md`): radius units below 2⁻⁴⁰ (crash-56ba5028…: squared radii underflow and a
/// radius-1e-37 sphere is "hit" through rounding) and magnitudes over 2⁴⁰ (crash-02f6e1ac…:
/// squared radii overflow, hits at t = ∞). Radius-0 samples are traced as radius code 1
/// (crash-49d7e2f8…: a point "hit" because `f·f` underflowed to 0).
#[test]
fn regression_lbvh_domain_excludes_float_extremes() {
    let frame_input = |min: [f32; 3], max: [f32; 3], unit: f32| {
        let mut v = Vec::new();
        for x in min.iter().chain(max.iter()).chain([unit].iter()) {
            v.push(1u8); // raw float
            v.extend_from_slice(&x.to_le_bytes());
        }
        v.push(4); // four samples
        v.extend_from_slice(&[2; 40]);
        v
    };
    let ok = frame_input([0.0; 3], [1.0; 3], 1e-3);
    assert!(checks::lbvh_frame(&mut checks::Bytes(&ok)).is_some());
    let tiny = frame_input([0.0; 3], [1.0; 3], 2.7e-40);
    assert!(checks::lbvh_frame(&mut checks::Bytes(&tiny)).is_none());
    let huge_unit = frame_input([0.0; 3], [1.0; 3], 7e25);
    assert!(checks::lbvh_frame(&mut checks::Bytes(&huge_unit)).is_none());
    let huge_bounds = frame_input([-1e30; 3], [1.0; 3], 1e-3);
    assert!(checks::lbvh_frame(&mut checks::Bytes(&huge_bounds)).is_none());
    // Frames outside the domain still build without a panic and never trace to NaN.
    let f = Frame {
        header: FrameHeader {
            seq: 0,
            camera: Camera::look_at(Vec3::Z, Vec3::ZERO, Vec3::Y, 60.0, 16, 16),
            heuristic: Heuristic::Threshold,
            bounds: Bounds::new(Vec3::splat(-1.5e38), Vec3::splat(1.5e38)),
            radius_unit: 3e35,
            render_us: 0,
            level: 0,
            count: 3,
        },
        samples: vec![0, u64::MAX, 0x3f_ffff_ffff_ffff],
        colors: vec![0, 0, 0],
        segments: Vec::new(),
    };
    let scene = Scene::build(&f);
    let mut seen = vec![0u8; 5];
    let _ = scene.lbvh().check(&mut seen);
    let ray = Ray { origin: Vec3::ZERO, dir: Vec3::X };
    if let Some(h) = scene.lbvh().trace(&ray) {
        assert!(!h.t.is_nan());
    }
}

/// A frame header promising 4 GiB is refused before anything is allocated.
#[test]
fn four_gib_header_is_refused_without_allocating() {
    let mut v = b"VWRP\x01\x00\x03\x00".to_vec();
    v.extend_from_slice(&u32::MAX.to_le_bytes());
    let (r, peak) = checks::peak_alloc(|| volwarp_core::wire::read_message(&mut &v[..], &checks::LIMITS));
    assert!(matches!(r, Err(volwarp_core::wire::WireError::TooLarge { .. })), "{r:?}");
    assert!(peak < 1024, "allocated {peak} bytes");
}

/// The allocation accounting the checks rely on sees allocations.
#[test]
fn allocation_accounting_works() {
    let (v, peak) = checks::peak_alloc(|| vec![0u8; 100_000]);
    assert_eq!(v.len(), 100_000);
    assert!(peak >= 100_000, "peak {peak}");
}

/// The real frames dumped from the server (seeds of `frame_decode`) build valid trees, and
/// `trace` equals `brute_force` for the pixel rays of a camera 10° off the frame's.
#[test]
fn real_frames_trace_like_brute_force() {
    let dir = fuzz_dir("seeds").join("frame_decode");
    let mut n = 0;
    for e in std::fs::read_dir(&dir).unwrap().flatten() {
        if !e.file_name().to_string_lossy().starts_with("real_") {
            continue;
        }
        let data = std::fs::read(e.path()).unwrap();
        let Ok(Message::Frame(f)) = volwarp_core::wire::read_message(&mut &data[..], &checks::LIMITS) else {
            panic!("{} is not a frame", e.path().display())
        };
        checks::check_scene(&f);
        let scene = Scene::build(&f);
        let cam = f.header.camera.orbit(10.0, 5.0).with_viewport(24, 24);
        for y in 0..24 {
            for x in 0..24 {
                let ray = cam.ray(x, y);
                assert_eq!(scene.lbvh().trace(&ray), brute_force(&scene.samples, &scene.deq, &ray));
            }
        }
        n += 1;
    }
    assert!(n >= 3, "expected real frames under {}", dir.display());
}

/// Found by reasoning about `frame_decode`'s invariant (then kept as a seed): bounds
/// `[0, f32::MAX]` passed `Bounds::is_valid`, but `min + (2¹⁸ − 1) · step` rounds past
/// `f32::MAX`, so the top quantized position decoded to an infinite center. `is_valid` now also
/// requires that corner to be finite: every valid bounds decode every position to a finite
/// point, and the wire decoder rejects the frame with `BadBounds`.
#[test]
fn regression_extreme_bounds_decode_to_finite_centers_or_are_rejected() {
    let m = f32::MAX;
    let cases = [
        (0.0, m),
        (-m, 0.0),
        (m / 2.0, m),
        (-m / 2.0, m / 2.0),
        (m - m / 1024.0, m),
        (1.0, m),
        (-m, -1.0),
        (f32::MIN_POSITIVE, m),
        (-1e38, 1e38),
        (0.0, 1e38),
    ];
    let mut accepted = 0;
    for (lo, hi) in cases {
        let b = Bounds::new(Vec3::splat(lo), Vec3::splat(hi));
        if !b.is_valid() {
            continue;
        }
        accepted += 1;
        let deq = Dequantizer::new(b, 1.0);
        for q in [0u64, 1, 131071, 262142, 262143] {
            let s = q | (q << 18) | (q << 36) | (1 << 54);
            let c = deq.center(s);
            assert!(c.is_finite(), "bounds {lo}..{hi}, q {q}: center {c:?}");
        }
    }
    assert!(accepted >= 3, "only {accepted} of the extreme bounds are valid");
    assert!(!Bounds::new(Vec3::ZERO, Vec3::splat(m)).is_valid());
    // On the wire: a frame with those bounds and a valid camera is refused.
    let f = Frame {
        header: FrameHeader {
            seq: 0,
            camera: Camera::look_at(Vec3::Z, Vec3::ZERO, Vec3::Y, 60.0, 16, 16),
            heuristic: Heuristic::Threshold,
            bounds: Bounds::new(Vec3::ZERO, Vec3::splat(m)),
            radius_unit: 1.0,
            render_us: 0,
            level: 0,
            count: 1,
        },
        samples: vec![0x3f_ffff_ffff_ffff | (1 << 54)],
        colors: vec![0],
        segments: Vec::new(),
    };
    let bytes = encode_to_vec(&Message::Frame(f));
    assert_eq!(
        volwarp_core::wire::read_message(&mut &bytes[..], &checks::LIMITS),
        Err(volwarp_core::wire::WireError::BadBounds)
    );
    checks::frame_decode(&bytes);
}
