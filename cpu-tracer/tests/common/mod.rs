//! Helpers shared by the integration tests.
#![allow(dead_code)]

use volwarp_core::{Camera, Scene};
use volwarp_cpu_tracer::{PacketTracer, ScalarTracer, NO_HIT};

/// Sample ids of the packet tracer (`threads` threads) and the scalar reference.
pub fn ids_both(scene: &Scene, camera: &Camera, threads: usize) -> (Vec<u32>, Vec<u32>) {
    let (mut a, mut b) = (Vec::new(), Vec::new());
    assert!(PacketTracer::new(threads).trace_ids(scene, camera, &mut a));
    assert!(ScalarTracer::new(threads).trace_ids(scene, camera, &mut b));
    (a, b)
}

/// Asserts both tracers give identical ids, and returns the number of hit pixels.
pub fn assert_packet_equals_scalar(scene: &Scene, camera: &Camera, what: &str) -> usize {
    let (p, s) = ids_both(scene, camera, 2);
    assert_eq!(p.len(), (camera.width * camera.height) as usize);
    let diff: Vec<usize> = (0..p.len()).filter(|&i| p[i] != s[i]).collect();
    assert!(
        diff.is_empty(),
        "{what}: {} pixels differ, first at {:?}: packet {} scalar {}",
        diff.len(),
        diff.first().map(|&i| (i as u32 % camera.width, i as u32 / camera.width)),
        p[diff[0]],
        s[diff[0]]
    );
    let (p1, _) = ids_both(scene, camera, 1);
    assert_eq!(p1, p, "{what}: one thread and two threads differ");
    p.iter().filter(|&&i| i != NO_HIT).count()
}
