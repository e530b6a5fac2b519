//! The splatter in the samples' own order (`DirectSplat`) gives exactly the scalar reference's
//! sample ids: random, clustered, all-identical and real server frames, 1, 2 and 3 threads (row
//! bands, spheres handed between them), one and two windows for small rectangles, odd viewports,
//! spheres crossing the near plane or containing the eye, zoomed-in views; unbuilt scenes (the
//! server's order, no LBVH) give the built scene's image. The portable (non-AVX2) kernels are
//! checked in `portable_simd.rs`.

#[path = "../benches/support/frames.rs"]
mod frames;

use volwarp_core::morton::code_of_sample;
use volwarp_core::renderer::Image;
use volwarp_core::wire::Frame;
use volwarp_core::{Camera, Scene, Vec3};
use volwarp_cpu_tracer::route::unbuilt_scene;
use volwarp_cpu_tracer::synthetic::{clustered_cloud, depth_image_frame, one_point_cloud, random_cloud};
use volwarp_cpu_tracer::{build_scene, DirectSplat, ScalarTracer, NO_HIT};

/// The splatters under test: 1, 2 and 3 threads, the per-frame window choice and both forced.
fn splatters() -> Vec<(String, DirectSplat)> {
    let mut v = Vec::new();
    for threads in [1, 2, 3] {
        v.push((format!("{threads} thread(s)"), DirectSplat::new(threads)));
    }
    v.push(("one window, 2 threads".into(), DirectSplat::new(2).with_windows(false)));
    v.push(("two windows, 1 thread".into(), DirectSplat::new(1).with_windows(true)));
    v
}

/// Asserts every splatter of [`splatters`] gives the scalar tracer's ids exactly on the built
/// scene, and the same samples on the unbuilt one; returns the hit pixel count.
fn assert_direct_exact(frame: &Frame, scene: &Scene, cam: &Camera, what: &str) -> usize {
    let mut reference = Vec::new();
    assert!(ScalarTracer::new(2).trace_ids(scene, cam, &mut reference));
    // The unbuilt scene: frame order, no nodes. Its ids are frame indices; mapped to the built
    // scene's order (the build's stable sort by Morton code) they must be the same.
    let unbuilt = unbuilt_scene(frame);
    let mut order: Vec<u32> = (0..unbuilt.samples.len() as u32).collect();
    order.sort_by_key(|&i| (code_of_sample(unbuilt.samples[i as usize]), i));
    let mut rank = vec![0u32; order.len()];
    for (sorted, &i) in order.iter().enumerate() {
        rank[i as usize] = sorted as u32;
    }
    for (label, mut d) in splatters() {
        let mut ids = Vec::new();
        assert!(d.splat_ids(scene, cam, &mut ids), "{what}");
        let diff: Vec<usize> = (0..ids.len()).filter(|&i| ids[i] != reference[i]).collect();
        assert!(
            diff.is_empty(),
            "{what}, {label}: {} of {} pixels differ, first at {:?}: direct {} scalar {}",
            diff.len(),
            ids.len(),
            diff.first().map(|&i| (i as u32 % cam.width, i as u32 / cam.width)),
            ids[diff[0]],
            reference[diff[0]]
        );
        assert!(d.splat_ids(&unbuilt, cam, &mut ids), "{what}");
        let mapped: Vec<u32> = ids.iter().map(|&i| if i == NO_HIT { NO_HIT } else { rank[i as usize] }).collect();
        assert!(mapped == reference, "{what}, {label}: the unbuilt scene's splat differs from the built scene's trace");
    }
    reference.iter().filter(|&&i| i != NO_HIT).count()
}

fn check(frame: &Frame, cams: &[(&str, Camera)]) {
    let scene = build_scene(frame);
    for (what, cam) in cams {
        assert_direct_exact(frame, &scene, cam, what);
    }
}

#[test]
fn direct_random_clouds_and_odd_viewports() {
    for (seed, n, r) in [(1u64, 2000usize, 0.03f32), (2, 20_000, 0.01), (3, 50, 0.2), (4, 2, 0.3), (5, 1, 0.3)] {
        let f = random_cloud(n, r, seed, 160);
        let c = f.header.camera;
        check(
            &f,
            &[
                ("random", c),
                ("random 10°", c.orbit(10.0, 0.0)),
                ("random odd", c.orbit(-35.0, 20.0).with_viewport(131, 97)),
                ("random behind", c.orbit(180.0, 0.0).with_viewport(33, 65)),
                ("random 1×1", c.with_viewport(1, 1)),
                ("random 2 rows", c.with_viewport(9, 2)),
                ("random 7×300", c.orbit(5.0, 5.0).with_viewport(7, 300)),
            ],
        );
    }
}

#[test]
fn direct_clustered_and_identical() {
    for (seed, clusters) in [(11u64, 3usize), (12, 40)] {
        let f = clustered_cloud(30_000, clusters, 0.004, seed, 160);
        let c = f.header.camera;
        check(&f, &[("clustered", c), ("clustered 10°", c.orbit(10.0, 0.0).with_viewport(150, 101))]);
    }
    // All spheres identical: every hit pixel is a tie, decided by the tie rule.
    let f = one_point_cloud(5000, 128);
    let scene = build_scene(&f);
    let hits = assert_direct_exact(&f, &scene, &f.header.camera, "identical");
    assert!(hits > 100);
}

#[test]
fn direct_near_plane_eye_inside_and_zoomed_in() {
    let f = random_cloud(20_000, 0.01, 21, 128);
    let c = f.header.camera;
    // Inside a dense cloud: spheres cross the eye plane, and some contain the eye (their
    // rectangle is the whole viewport: handed to every band).
    let inside = Camera::look_at(Vec3::splat(0.5), Vec3::new(0.9, 0.6, 0.1), Vec3::Y, 70.0, 128, 96);
    let big = random_cloud(300, 0.2, 22, 96);
    let bc = Camera::look_at(Vec3::splat(0.5), Vec3::new(0.1, 0.7, 0.2), Vec3::Y, 90.0, 97, 64);
    check(&f, &[("inside", inside), ("zoom 0.3", c.dolly(0.3)), ("zoom 0.1", c.orbit(20.0, 10.0).dolly(0.1))]);
    check(&big, &[("large spheres around the eye", bc), ("large spheres", big.header.camera.dolly(0.5))]);
    let d = depth_image_frame(200, 1.5, 3);
    let dc = d.header.camera;
    check(&d, &[("depth image", dc), ("depth image zoomed", dc.orbit(-25.0, 30.0).dolly(0.2))]);
}

#[test]
fn direct_real_frames() {
    if volwarp_server::testdata::shared_data(volwarp_server::testdata::MRI).is_none() {
        return;
    }
    let (frame, what) = frames::mri_frame(256).expect("the shared MRI renders a frame");
    let scene = build_scene(&frame);
    let c = frame.header.camera;
    for (label, cam) in [
        ("frame camera", c),
        ("10°", c.orbit(10.0, 0.0)),
        ("10° at 1024²", c.orbit(10.0, 0.0).with_viewport(1024, 1024)),
        ("10° at 128²", c.orbit(10.0, 0.0).with_viewport(128, 128)),
        ("30° up, closer", c.orbit(0.0, 30.0).dolly(0.7)),
        ("zoomed in", c.orbit(5.0, 0.0).dolly(0.4).with_viewport(301, 199)),
    ] {
        let hits = assert_direct_exact(&frame, &scene, &cam, &format!("{what}, {label}"));
        assert!(hits > 1000, "{label}: {hits}");
    }
}

#[test]
fn direct_bands_split_the_spheres_and_hand_over_few_in_scanline_order() {
    if volwarp_server::testdata::shared_data(volwarp_server::testdata::MRI).is_none() {
        return;
    }
    let (frame, _) = frames::mri_frame(256).expect("the shared MRI renders a frame");
    let unbuilt = unbuilt_scene(&frame);
    let cam = frame.header.camera.orbit(10.0, 0.0);
    let mut d = DirectSplat::new(2);
    let mut img = Image::new(1, 1);
    d.render(&unbuilt, &cam, &mut img);
    let rows = d.band_rows();
    assert_eq!(rows.len(), 3, "{rows:?}");
    assert!(rows[0] == 0 && rows[1] > 0 && rows[1] < rows[2] && rows[2] == cam.height as usize, "{rows:?}");
    // In the server's order the two shares of the samples fall mostly in their own bands.
    let handed = d.handed_over();
    assert!(handed > 0 && handed < unbuilt.samples.len() / 10, "{handed} of {}", unbuilt.samples.len());
    // The same image as one thread.
    let mut one = Image::new(1, 1);
    DirectSplat::new(1).render(&unbuilt, &cam, &mut one);
    assert_eq!(img, one);
}
