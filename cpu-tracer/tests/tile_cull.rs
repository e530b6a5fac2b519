//! Occlusion culling in the tiled splatter (`TileSplat::with_culling`) never changes the image:
//! with it on and off the splatter gives the scalar reference's sample ids exactly on random,
//! clustered, all-identical and near-plane scenes, 1 and 2 threads, odd viewports, built and
//! unbuilt; and it does skip spheres where large ones hide others.

use volwarp_core::{Camera, Scene, Vec3};
use volwarp_cpu_tracer::route::unbuilt_scene;
use volwarp_cpu_tracer::synthetic::{clustered_cloud, depth_image_frame, one_point_cloud, random_cloud};
use volwarp_cpu_tracer::{build_scene, ScalarTracer, TileSplat};

/// The ids of the splatter with culling `cull` on `threads` threads, and the culled pairs.
fn splat(scene: &Scene, cam: &Camera, threads: usize, cull: bool) -> (Vec<u32>, u64) {
    let mut t = TileSplat::new(threads).with_culling(cull);
    let mut ids = Vec::new();
    assert!(t.splat_ids(scene, cam, &mut ids));
    let (pairs, culled) = t.culled();
    assert!(culled <= pairs);
    if !cull {
        assert_eq!(culled, 0);
    }
    (ids, culled)
}

/// Asserts culling on and off give the scalar reference's ids (built scene) and the same ids
/// as each other (unbuilt scene), on 1 and 2 threads; returns the pairs culled.
fn assert_same(frame: &volwarp_core::wire::Frame, cams: &[(&str, Camera)]) -> u64 {
    let scene = build_scene(frame);
    let unbuilt = unbuilt_scene(frame);
    let mut culled = 0;
    for (what, cam) in cams {
        let mut reference = Vec::new();
        assert!(ScalarTracer::new(2).trace_ids(&scene, cam, &mut reference));
        for threads in [1, 2] {
            for cull in [false, true] {
                let (ids, c) = splat(&scene, cam, threads, cull);
                let diff = (0..ids.len()).filter(|&i| ids[i] != reference[i]).count();
                assert_eq!(diff, 0, "{what}, {threads} thread(s), culling {cull}: {diff} pixels differ");
                culled += c;
            }
            let (off, _) = splat(&unbuilt, cam, threads, false);
            let (on, _) = splat(&unbuilt, cam, threads, true);
            assert!(off == on, "{what}, unbuilt, {threads} thread(s): culling changes the ids");
        }
    }
    culled
}

#[test]
fn random_clouds_odd_viewports_and_near_plane() {
    let mut culled = 0;
    for (seed, n, r) in [(1u64, 3000usize, 0.05f32), (2, 20_000, 0.01), (3, 300, 0.2)] {
        let f = random_cloud(n, r, seed, 160);
        let c = f.header.camera;
        // Inside the cloud: spheres cross the eye plane, some contain the eye.
        let inside = Camera::look_at(Vec3::splat(0.5), Vec3::new(0.9, 0.6, 0.1), Vec3::Y, 70.0, 131, 97);
        culled += assert_same(
            &f,
            &[
                ("random", c),
                ("random odd", c.orbit(-35.0, 20.0).with_viewport(131, 97)),
                ("random 7×300", c.orbit(5.0, 5.0).with_viewport(7, 300)),
                ("random zoom 0.3", c.dolly(0.3).with_viewport(101, 67)),
                ("random inside", inside),
            ],
        );
    }
    // Large overlapping spheres hide one another: culling must skip some.
    assert!(culled > 0);
}

#[test]
fn clustered_identical_and_depth_images() {
    for (seed, clusters) in [(11u64, 3usize), (12, 40)] {
        let f = clustered_cloud(30_000, clusters, 0.004, seed, 160);
        let c = f.header.camera;
        assert_same(&f, &[("clustered", c), ("clustered zoom", c.orbit(10.0, 0.0).dolly(0.2).with_viewport(150, 101))]);
    }
    // Every sphere the same: every hit ties, so the tie rule alone decides.
    let f = one_point_cloud(5000, 128);
    let c = f.header.camera;
    assert_same(&f, &[("identical", c), ("identical zoom", c.dolly(0.1).with_viewport(99, 77))]);
    let d = depth_image_frame(200, 1.5, 3);
    let dc = d.header.camera;
    assert_same(&d, &[("depth image", dc), ("depth image zoomed", dc.orbit(-25.0, 30.0).dolly(0.2))]);
}
