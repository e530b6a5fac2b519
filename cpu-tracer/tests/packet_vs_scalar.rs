//! The SIMD packet tracer gives exactly the scalar reference's sample ids.

mod common;

use common::assert_packet_equals_scalar;
use volwarp_core::{Camera, Scene, Vec3};
use volwarp_cpu_tracer::synthetic::{clustered_cloud, depth_image_frame, one_point_cloud, random_cloud};
use volwarp_cpu_tracer::{build_scene, PacketTracer, NO_HIT};

#[test]
fn random_clouds() {
    for (seed, n, r) in [(1u64, 2000usize, 0.03f32), (2, 20_000, 0.01), (3, 50, 0.2), (4, 2, 0.3), (5, 1, 0.3)] {
        let frame = random_cloud(n, r, seed, 160);
        let scene = build_scene(&frame);
        let cam = frame.header.camera;
        let hits = assert_packet_equals_scalar(&scene, &cam, &format!("random seed {seed}"));
        assert!(hits > 0, "seed {seed}: the cloud should be visible");
        // Warped views, including an odd viewport size (partial packets at the borders).
        for (yaw, pitch) in [(10.0, 0.0), (-35.0, 20.0), (90.0, -10.0), (180.0, 0.0)] {
            let c = cam.orbit(yaw, pitch).with_viewport(131, 97);
            assert_packet_equals_scalar(&scene, &c, &format!("random seed {seed} orbit {yaw} {pitch}"));
        }
    }
}

#[test]
fn clustered_clouds() {
    for (seed, clusters) in [(11u64, 3usize), (12, 40)] {
        let frame = clustered_cloud(30_000, clusters, 0.004, seed, 160);
        let scene = build_scene(&frame);
        let hits = assert_packet_equals_scalar(&scene, &frame.header.camera, "clustered");
        assert!(hits > 0);
        assert_packet_equals_scalar(&scene, &frame.header.camera.orbit(10.0, 0.0), "clustered, 10°");
    }
}

#[test]
fn all_identical_points() {
    let frame = one_point_cloud(5000, 128);
    let scene = build_scene(&frame);
    let hits = assert_packet_equals_scalar(&scene, &frame.header.camera, "identical points");
    assert!(hits > 100);
    let mut ids = Vec::new();
    PacketTracer::new(1).trace_ids(&scene, &frame.header.camera, &mut ids);
    // Every sample ties: the tie rule gives every hit pixel the smallest index, 0.
    assert!(ids.iter().all(|&i| i == 0 || i == NO_HIT));
}

#[test]
fn camera_inside_cloud_and_looking_away() {
    let frame = random_cloud(20_000, 0.01, 21, 128);
    let scene = build_scene(&frame);
    let inside = Camera::look_at(Vec3::splat(0.5), Vec3::new(0.9, 0.6, 0.1), Vec3::Y, 70.0, 128, 96);
    let hits = assert_packet_equals_scalar(&scene, &inside, "inside");
    assert!(hits > 1000, "inside a dense cloud most pixels hit: {hits}");
    let away = Camera::look_at(Vec3::new(0.5, 0.5, 3.0), Vec3::new(0.5, 0.5, 6.0), Vec3::Y, 45.0, 64, 64);
    assert_eq!(assert_packet_equals_scalar(&scene, &away, "away"), 0);
    // Axis-aligned rays (zero direction components, infinite inverses, NaN slabs).
    let axis = Camera::look_at(Vec3::new(0.5, 0.5, 4.0), Vec3::new(0.5, 0.5, 0.0), Vec3::Y, 30.0, 65, 65);
    assert_packet_equals_scalar(&scene, &axis, "axis-aligned centre rays");
}

#[test]
fn depth_image_frame_and_warps() {
    let frame = depth_image_frame(256, 1.0, 9);
    let scene = build_scene(&frame);
    let cam = frame.header.camera;
    let hits = assert_packet_equals_scalar(&scene, &cam, "depth image");
    assert!(hits as f64 > 0.5 * (256.0 * 256.0), "{hits}");
    assert_packet_equals_scalar(&scene, &cam.orbit(10.0, 0.0), "depth image 10°");
    assert_packet_equals_scalar(&scene, &cam.orbit(0.0, 40.0).dolly(0.5), "depth image close");
    let _ = Scene::build(&frame);
}
