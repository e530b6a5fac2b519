//! The parallel LBVH build gives the serial build's bytes.

use volwarp_core::morton::{make_keys, radix_sort, SortKey};
use volwarp_core::wire::Frame;
use volwarp_core::Scene;
use volwarp_cpu_tracer::parallel_sort::{
    packed_index, par_radix_sort, par_sort_packed, PACKED_INDEX_BITS, PACKED_MAX_LEN,
};
use volwarp_cpu_tracer::synthetic::{clustered_cloud, depth_image_frame, one_point_cloud, random_cloud, SplitMix64};
use volwarp_cpu_tracer::{Method, ParallelBuilder, Threads};

fn assert_same(a: &Scene, b: &Scene, what: &str) {
    assert_eq!(a.samples, b.samples, "{what}: samples");
    assert_eq!(a.colors, b.colors, "{what}: colors");
    let (na, nb): (&[u8], &[u8]) = (bytemuck::cast_slice(&a.nodes), bytemuck::cast_slice(&b.nodes));
    assert!(na == nb, "{what}: node bytes differ");
    assert_eq!(a.header, b.header);
    assert_eq!(a.deq, b.deq);
}

fn frames() -> Vec<(&'static str, Frame)> {
    vec![
        ("empty", random_cloud(0, 0.1, 1, 64)),
        ("one", random_cloud(1, 0.1, 1, 64)),
        ("two", random_cloud(2, 0.1, 1, 64)),
        ("random 40k", random_cloud(40_000, 0.01, 2, 64)),
        ("clustered 60k", clustered_cloud(60_000, 7, 0.003, 3, 64)),
        ("identical 30k", one_point_cloud(30_000, 64)),
        ("depth image 512", depth_image_frame(512, 1.0, 4)),
    ]
}

#[test]
fn parallel_build_equals_serial_build() {
    let mut builders = [
        ParallelBuilder::new(1),
        ParallelBuilder::new(2),
        ParallelBuilder::new(3),
        ParallelBuilder::new(1).with_method(Method::Karras),
        ParallelBuilder::new(2).with_method(Method::Karras),
    ];
    for (what, frame) in frames() {
        let serial = Scene::build(&frame);
        let mut seen = vec![0u8; (2 * serial.samples.len()).max(1)];
        serial.lbvh().check(&mut seen).expect("serial tree is valid");
        for b in builders.iter_mut() {
            let par = b.build(&frame);
            assert_same(&par, &serial, &format!("{what}, {} threads", b.threads()));
        }
    }
}

#[test]
fn builder_reuses_buffers_across_frames() {
    let mut b = ParallelBuilder::new(2);
    let mut k = ParallelBuilder::new(2).with_method(Method::Karras);
    let mut scene2 = k.build(&depth_image_frame(300, 1.0, 1));
    let mut scene = b.build(&depth_image_frame(300, 1.0, 1));
    for (what, frame) in frames().into_iter().rev() {
        b.build_into(&frame, &mut scene);
        k.build_into(&frame, &mut scene2);
        let serial = Scene::build(&frame);
        assert_same(&scene, &serial, what);
        assert_same(&scene2, &serial, what);
    }
}

#[test]
fn parallel_radix_sort_equals_serial() {
    let mut rng = SplitMix64(5);
    for (n, bits) in [(0usize, 54u32), (17, 54), (100_000, 54), (70_000, 3), (50_000, 30)] {
        let samples: Vec<u64> = (0..n).map(|_| rng.next_u64() & ((1u64 << bits) - 1)).collect();
        // Keys straight from random codes (not only Morton codes of positions).
        let keys: Vec<SortKey> =
            samples.iter().enumerate().map(|(i, &c)| SortKey { code: c, index: i as u32, pad: 0 }).collect();
        let mut serial = keys.clone();
        radix_sort(&mut serial, &mut vec![SortKey::default(); n]);
        for t in [1, 2, 4] {
            let mut par = keys.clone();
            par_radix_sort(&mut par, &mut vec![SortKey::default(); n], &Threads::new(t));
            assert_eq!(par, serial, "n {n} bits {bits} threads {t}");
        }
        let mut from_samples = vec![SortKey::default(); n];
        make_keys(&samples, &mut from_samples);
        let mut s2 = from_samples.clone();
        radix_sort(&mut s2, &mut vec![SortKey::default(); n]);
        par_radix_sort(&mut from_samples, &mut vec![SortKey::default(); n], &Threads::new(2));
        assert_eq!(from_samples, s2);
    }
}

#[test]
fn packed_sort_equals_serial() {
    let mut rng = SplitMix64(9);
    // Codes of up to 54 bits; few bits: most passes skipped; many equal codes.
    for (n, bits) in [(0usize, 54u32), (1, 54), (17, 54), (100_000, 54), (70_000, 3), (50_000, 30), (40_000, 12)] {
        let codes: Vec<u64> = (0..n).map(|_| rng.next_u64() & ((1u64 << bits) - 1)).collect();
        let mut serial: Vec<SortKey> =
            codes.iter().enumerate().map(|(i, &c)| SortKey { code: c, index: i as u32, pad: 0 }).collect();
        radix_sort(&mut serial, &mut vec![SortKey::default(); n]);
        for t in [1, 2, 3] {
            let (mut out, mut scratch) = (vec![0u64; n], vec![0u64; n]);
            par_sort_packed(&codes, &mut out, &mut scratch, &Threads::new(t));
            for (k, s) in out.iter().zip(&serial) {
                assert_eq!(packed_index(*k), s.index as usize, "n {n} bits {bits} threads {t}");
                assert_eq!(k >> PACKED_INDEX_BITS, s.code >> 11, "n {n} bits {bits} threads {t}");
            }
        }
    }
}

#[test]
fn frame_past_the_packed_sort_limit_uses_16_byte_keys() {
    let frame = random_cloud(PACKED_MAX_LEN + 3_000, 0.002, 7, 64);
    let serial = Scene::build(&frame);
    for b in [ParallelBuilder::new(2), ParallelBuilder::new(2).with_method(Method::Karras)].iter_mut() {
        assert_same(&b.build(&frame), &serial, &format!("{} samples", frame.samples.len()));
    }
}
