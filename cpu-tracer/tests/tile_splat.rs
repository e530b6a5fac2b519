//! The tiled splatter and the default renderer (`spheres`) give exactly the scalar reference's
//! sample ids: random, clustered, all-identical and real server frames, 1 and 2 threads, odd
//! viewports, spheres crossing the near plane or containing the eye, zoomed-in views; unbuilt
//! scenes (no LBVH) give the built scene's image; the route never changes the image.

mod common;

#[path = "../benches/support/frames.rs"]
mod frames;

use volwarp_core::morton::code_of_sample;
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::wire::Frame;
use volwarp_core::{Camera, Scene, Vec3};
use volwarp_cpu_tracer::route::{estimate, unbuilt_scene};
use volwarp_cpu_tracer::synthetic::{clustered_cloud, depth_image_frame, one_point_cloud, random_cloud};
use volwarp_cpu_tracer::tile_splat::{GROUP, MAX_GROUP_TILES, MAX_TILES};
use volwarp_cpu_tracer::{build_scene, AutoSpheres, Route, ScalarTracer, TileSplat, NO_HIT};

/// Asserts the tiled splatter (1 and 2 threads) gives the scalar tracer's ids exactly on the
/// built scene, and the same samples on the unbuilt one; returns the hit pixel count.
fn assert_splat_exact(frame: &Frame, scene: &Scene, cam: &Camera, what: &str) -> usize {
    let mut reference = Vec::new();
    assert!(ScalarTracer::new(2).trace_ids(scene, cam, &mut reference));
    for threads in [1, 2] {
        let mut ids = Vec::new();
        assert!(TileSplat::new(threads).splat_ids(scene, cam, &mut ids), "{what}");
        let diff: Vec<usize> = (0..ids.len()).filter(|&i| ids[i] != reference[i]).collect();
        assert!(
            diff.is_empty(),
            "{what}, {threads} thread(s): {} of {} pixels differ, first at {:?}: splat {} scalar {}",
            diff.len(),
            ids.len(),
            diff.first().map(|&i| (i as u32 % cam.width, i as u32 / cam.width)),
            ids[diff[0]],
            reference[diff[0]]
        );
    }
    // The unbuilt scene: frame order, no nodes. Its ids are frame indices; mapped to the
    // built scene's order (the build's stable sort by Morton code) they must be the same.
    let unbuilt = unbuilt_scene(frame);
    let mut order: Vec<u32> = (0..unbuilt.samples.len() as u32).collect();
    order.sort_by_key(|&i| (code_of_sample(unbuilt.samples[i as usize]), i));
    let mut rank = vec![0u32; order.len()];
    for (sorted, &i) in order.iter().enumerate() {
        rank[i as usize] = sorted as u32;
    }
    let mut ids = Vec::new();
    assert!(TileSplat::new(2).splat_ids(&unbuilt, cam, &mut ids), "{what}");
    let mapped: Vec<u32> = ids.iter().map(|&i| if i == NO_HIT { NO_HIT } else { rank[i as usize] }).collect();
    assert!(mapped == reference, "{what}: the unbuilt scene's splat differs from the built scene's trace");
    reference.iter().filter(|&&i| i != NO_HIT).count()
}

fn check(frame: &Frame, cams: &[(&str, Camera)]) {
    let scene = build_scene(frame);
    for (what, cam) in cams {
        assert_splat_exact(frame, &scene, cam, what);
    }
}

#[test]
fn random_clouds_and_odd_viewports() {
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
                ("random 7×300", c.orbit(5.0, 5.0).with_viewport(7, 300)),
            ],
        );
    }
}

#[test]
fn clustered_and_identical() {
    for (seed, clusters) in [(11u64, 3usize), (12, 40)] {
        let f = clustered_cloud(30_000, clusters, 0.004, seed, 160);
        let c = f.header.camera;
        check(&f, &[("clustered", c), ("clustered 10°", c.orbit(10.0, 0.0).with_viewport(150, 101))]);
    }
    let f = one_point_cloud(5000, 128);
    let scene = build_scene(&f);
    let hits = assert_splat_exact(&f, &scene, &f.header.camera, "identical");
    assert!(hits > 100);
}

#[test]
fn small_spheres_take_the_bound_pass_hits() {
    // Spheres of at most 2×2 pixels are drawn from the hits the bound pass finds: on tile
    // borders, at ties (identical spheres) and in a real-sized cloud, the reference's ids.
    let identical = one_point_cloud(300, 128);
    let cloud = random_cloud(20_000, 0.004, 31, 160);
    let mut small = 0;
    for (f, res) in [(&identical, 3u32), (&identical, 4), (&identical, 6), (&cloud, 160), (&cloud, 131)] {
        let scene = build_scene(f);
        for cam in [f.header.camera.with_viewport(res, res), f.header.camera.orbit(7.0, 3.0).with_viewport(res, res)] {
            assert_splat_exact(f, &scene, &cam, &format!("small spheres at {res}²"));
            let mut t = TileSplat::new(1);
            assert!(t.splat_ids(&scene, &cam, &mut Vec::new()));
            small += t.small_spheres();
            if f.samples.len() == 300 {
                // All identical: where one is small, all are.
                assert!(t.small_spheres() == 0 || t.small_spheres() == 300, "{}", t.small_spheres());
            }
        }
    }
    assert!(small > 20_000, "{small}");
}

#[test]
fn near_plane_eye_inside_and_zoomed_in() {
    let f = random_cloud(20_000, 0.01, 21, 128);
    let c = f.header.camera;
    // Inside a dense cloud: spheres cross the eye plane, and some contain the eye.
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
fn real_frames() {
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
        ("30° up, closer", c.orbit(0.0, 30.0).dolly(0.7)),
        ("zoomed in", c.orbit(5.0, 0.0).dolly(0.4).with_viewport(301, 199)),
    ] {
        let hits = assert_splat_exact(&frame, &scene, &cam, &format!("{what}, {label}"));
        assert!(hits > 1000, "{label}: {hits}");
    }
}

fn render(r: &mut dyn Renderer, scene: &Scene, cam: &Camera) -> Image {
    let mut img = Image::new(1, 1);
    r.render(scene, cam, &mut img);
    img
}

#[test]
fn the_route_never_changes_the_image() {
    let f = random_cloud(20_000, 0.01, 31, 128);
    let scene = build_scene(&f);
    let unbuilt = unbuilt_scene(&f);
    let c = f.header.camera;
    let inside = Camera::look_at(Vec3::splat(0.5), Vec3::new(0.9, 0.6, 0.1), Vec3::Y, 70.0, 120, 90);
    for cam in [c, c.orbit(30.0, 10.0).with_viewport(99, 77), c.dolly(0.2), inside] {
        let reference = render(&mut ScalarTracer::new(1), &scene, &cam);
        for threads in [1, 2] {
            for route in [Route::Splat, Route::Trace] {
                for s in [&scene, &unbuilt] {
                    let mut r = AutoSpheres::new(threads).with_route(route);
                    let img = render(&mut r, s, &cam);
                    assert_eq!(r.last_route(), Some(route));
                    assert!(img.pixels == reference.pixels, "{route:?}, {threads} thread(s)");
                }
            }
            let mut auto = AutoSpheres::new(threads);
            assert!(render(&mut auto, &unbuilt, &cam).pixels == reference.pixels);
            assert!(auto.last_route().is_some());
        }
    }
}

#[test]
fn the_cost_model_picks_tracing_for_large_spheres_and_splatting_for_small() {
    let small = random_cloud(50_000, 0.002, 41, 512);
    let s = build_scene(&small);
    let mut auto = AutoSpheres::new(1);
    render(&mut auto, &s, &small.header.camera);
    assert_eq!(auto.last_route(), Some(Route::Splat), "{:?}", auto.last_estimate());
    // The camera inside a cloud of large spheres: every one crosses the eye plane.
    let inside = Camera::look_at(Vec3::splat(0.5), Vec3::new(0.9, 0.6, 0.1), Vec3::Y, 70.0, 256, 256);
    let large = build_scene(&random_cloud(20_000, 0.2, 42, 256));
    render(&mut auto, &large, &inside);
    assert_eq!(auto.last_route(), Some(Route::Trace), "{:?}", auto.last_estimate());
    let e = estimate(&large, &inside);
    assert!(e.coverage() > 100.0 && e.coverage().is_finite(), "{e:?}");
}

#[test]
fn lists_stay_bounded_whatever_the_view() {
    // Every sphere covers the whole viewport: each goes to the shared list once.
    let f = random_cloud(5000, 0.3, 51, 256);
    let scene = build_scene(&f);
    let inside = Camera::look_at(Vec3::splat(0.5), Vec3::new(0.9, 0.6, 0.1), Vec3::Y, 100.0, 1024, 1024);
    let mut t = TileSplat::new(2);
    let mut ids = Vec::new();
    assert!(t.splat_ids(&scene, &inside, &mut ids));
    assert!(t.binned_entries() <= MAX_TILES * scene.samples.len(), "{}", t.binned_entries());
    assert!(ids.iter().all(|&i| i != NO_HIT));
    // Small spheres in random order: every group of consecutive spheres spans the screen, so
    // each is binned by its spheres' own tiles (more entries than whole groups could give),
    // still at most MAX_TILES per sphere, and the image is the reference's.
    let f = random_cloud(20_000, 0.004, 52, 512);
    let unbuilt = unbuilt_scene(&f);
    let n = unbuilt.samples.len();
    assert!(t.splat_ids(&unbuilt, &f.header.camera, &mut ids));
    let entries = t.binned_entries();
    assert!(entries <= MAX_TILES * n && entries > n.div_ceil(GROUP) * MAX_GROUP_TILES, "{entries} for {n}");
    assert_splat_exact(&f, &build_scene(&f), &f.header.camera, "random order, split groups");
}

#[test]
fn every_pixel_is_written_without_clearing_the_image_first() {
    // The tiled splatter sizes the image but does not clear it: every tile must write all its
    // pixels, the ones no sphere covers included (background), whatever the image held.
    let f = random_cloud(3000, 0.01, 61, 200);
    let c = f.header.camera;
    for (scene, what) in [(build_scene(&f), "built"), (unbuilt_scene(&f), "unbuilt")] {
        for cam in [c.orbit(15.0, 5.0).with_viewport(131, 97), c.dolly(0.5).with_viewport(64, 64)] {
            let fresh = render(&mut TileSplat::new(1), &scene, &cam);
            for threads in [1, 2] {
                let mut img = Image::new(cam.width, cam.height);
                img.pixels.fill(0x1234_5678);
                TileSplat::new(threads).render(&scene, &cam, &mut img);
                assert!(img == fresh, "{what}, {threads} thread(s): stale pixels left");
                // A smaller image before: resized, then every pixel written.
                let mut small = Image::new(7, 3);
                small.pixels.fill(0x1234_5678);
                TileSplat::new(threads).render(&scene, &cam, &mut small);
                assert!(small == fresh, "{what}, {threads} thread(s): resized");
            }
        }
    }
    // A scene without samples after one with many: nothing of the last frame's binning is
    // left (it draws the background, with any thread count).
    for threads in [1, 2] {
        let mut t = TileSplat::new(threads);
        let mut img = Image::new(0, 0);
        t.render(&build_scene(&f), &c, &mut img);
        let empty = unbuilt_scene(&random_cloud(0, 0.01, 62, 200));
        assert!(empty.samples.is_empty());
        t.render(&empty, &c, &mut img);
        assert!(img.pixels.iter().all(|&p| p == volwarp_core::BACKGROUND), "{threads} thread(s)");
    }
    // An unusable camera still clears to the background, as every renderer does.
    let mut img = Image::new(5, 5);
    img.pixels.fill(0x1234_5678);
    let bad = Camera { fov_y_deg: f32::NAN, ..c.with_viewport(5, 5) };
    TileSplat::new(1).render(&build_scene(&f), &bad, &mut img);
    assert!(img.pixels.iter().all(|&p| p == volwarp_core::BACKGROUND));
}
