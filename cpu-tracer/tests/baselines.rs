//! The baselines: exact splatting equals tracing, points and the stale image behave as
//! specified, and every renderer shows the same colors for the same hits.

mod common;

use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::sample::over_background;
use volwarp_core::RendererKind;
use volwarp_core::{Camera, Scene, Vec3, BACKGROUND};
use volwarp_cpu_tracer::synthetic::{depth_image_frame, one_point_cloud, random_cloud};
use volwarp_cpu_tracer::{build_scene, cpu_kinds, create, PacketTracer, PointSplat, SphereSplat, StaleImage, NO_HIT};

fn render(r: &mut dyn Renderer, scene: &Scene, cam: &Camera) -> Image {
    let mut img = Image::new(1, 1);
    r.render(scene, cam, &mut img);
    assert_eq!((img.width, img.height), (cam.width, cam.height));
    img
}

/// Fraction of equal pixels.
fn agreement(a: &[u32], b: &[u32]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).filter(|(x, y)| x == y).count() as f64 / a.len() as f64
}

#[test]
fn splat_equals_trace() {
    let cases: Vec<(&str, Scene, Vec<Camera>)> = {
        let f = depth_image_frame(200, 1.5, 3);
        let c = f.header.camera;
        let r = random_cloud(20_000, 0.01, 8, 150);
        let rc = r.header.camera;
        let inside = Camera::look_at(Vec3::splat(0.5), Vec3::new(0.1, 0.7, 0.9), Vec3::Y, 80.0, 120, 90);
        vec![
            ("depth image", build_scene(&f), vec![c, c.orbit(10.0, 0.0), c.orbit(-25.0, 30.0).dolly(0.6)]),
            ("random", build_scene(&r), vec![rc, rc.orbit(40.0, 10.0).with_viewport(97, 131), inside]),
            ("identical", build_scene(&one_point_cloud(3000, 100)), vec![one_point_cloud(1, 100).header.camera]),
        ]
    };
    let tracer = PacketTracer::new(2);
    let mut splat = SphereSplat::new(2);
    let mut splat1 = SphereSplat::new(1);
    for (what, scene, cams) in &cases {
        for cam in cams {
            let (mut t, mut s, mut s1) = (Vec::new(), Vec::new(), Vec::new());
            assert!(tracer.trace_ids(scene, cam, &mut t));
            assert!(splat.splat_ids(scene, cam, &mut s));
            assert!(splat1.splat_ids(scene, cam, &mut s1));
            assert_eq!(s, s1, "{what}: splatting depends on the thread count");
            let a = agreement(&t, &s);
            assert!(a >= 0.999, "{what}: splat agrees with tracing on only {:.4} %", a * 100.0);
            assert!(t.iter().any(|&i| i != NO_HIT), "{what}: something is visible");
            // The rendered colors agree too.
            let (ti, si) = (render(&mut PacketTracer::new(1), scene, cam), render(&mut splat, scene, cam));
            assert!(agreement(&ti.pixels, &si.pixels) >= 0.999);
        }
    }
}

#[test]
fn renderers_share_colors_and_names() {
    let frame = random_cloud(5000, 0.02, 4, 96);
    let scene = build_scene(&frame);
    let cam = frame.header.camera.orbit(10.0, 0.0);
    let mut ids = Vec::new();
    PacketTracer::new(1).trace_ids(&scene, &cam, &mut ids);
    let traced = render(&mut PacketTracer::new(2), &scene, &cam);
    for (i, &id) in ids.iter().enumerate() {
        let want = if id == NO_HIT { BACKGROUND } else { over_background(scene.colors[id as usize], BACKGROUND) };
        assert_eq!(traced.pixels[i], want);
    }
    let scalar = render(&mut *create(RendererKind::SpheresScalar, 2).unwrap(), &scene, &cam);
    assert_eq!(scalar, traced);
    for kind in cpu_kinds() {
        let mut r = create(kind, 2).unwrap();
        assert_eq!(r.kind(), kind);
        let name = kind.name();
        let img = render(&mut *r, &scene, &cam);
        assert!(img.pixels.iter().any(|&p| p != BACKGROUND), "{name} draws something");
        assert!(img.pixels.iter().all(|&p| p >> 24 == 255), "{name}: opaque pixels");
    }
    assert!(create(RendererKind::SpheresGpu, 1).is_none());
}

#[test]
fn points_draw_squares_with_a_depth_test() {
    let frame = random_cloud(1, 0.01, 1, 64);
    let scene = build_scene(&frame);
    let cam = frame.header.camera;
    for n in 1..=3u32 {
        let img = render(&mut PointSplat::new(n, 1), &scene, &cam);
        let lit = img.pixels.iter().filter(|&&p| p != BACKGROUND).count();
        assert_eq!(lit, (n * n) as usize, "points{n}");
    }
    // Thread count does not change the image (ties go to the smaller index).
    let frame = one_point_cloud(4000, 80);
    let scene = build_scene(&frame);
    let a = render(&mut PointSplat::new(3, 1), &scene, &frame.header.camera.orbit(5.0, 5.0));
    let b = render(&mut PointSplat::new(3, 2), &scene, &frame.header.camera.orbit(5.0, 5.0));
    assert_eq!(a, b);
}

#[test]
fn stale_image_ignores_the_current_camera() {
    let frame = depth_image_frame(128, 1.0, 2);
    let scene = build_scene(&frame);
    let fc = frame.header.camera;
    let at_frame = render(&mut StaleImage::new(2), &scene, &fc);
    let warped = render(&mut StaleImage::new(1), &scene, &fc.orbit(30.0, 10.0));
    assert_eq!(at_frame, warped, "the stale image does not move with the camera");
    // At the frame's own camera it is points1.
    assert_eq!(at_frame, render(&mut PointSplat::new(1, 2), &scene, &fc));
    // The samples land on (about) one pixel each: the grid fills most of its disc.
    let lit = at_frame.pixels.iter().filter(|&&p| p != BACKGROUND).count();
    assert!(lit as f64 > 0.4 * 128.0 * 128.0, "{lit}");
    // Resized to another viewport: nearest pixel.
    let half = render(&mut StaleImage::new(1), &scene, &fc.with_viewport(64, 32));
    for y in 0..32 {
        for x in 0..64 {
            assert_eq!(half.get(x, y), at_frame.get(2 * x + 1, 4 * y + 2));
        }
    }
}
