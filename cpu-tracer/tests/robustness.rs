//! Bad input never panics and never leaks NaN: unusable cameras and inconsistent scenes draw
//! the background, degenerate scenes draw what they can.

use volwarp_core::renderer::Image;
use volwarp_core::wire::Frame;
use volwarp_core::{Camera, Scene, Vec3, BACKGROUND};
use volwarp_cpu_tracer::synthetic::{one_point_cloud, random_cloud};
use volwarp_cpu_tracer::{build_scene, cpu_kinds, create, PacketTracer};

fn all_renderers() -> Vec<Box<dyn volwarp_core::Renderer + Send>> {
    cpu_kinds().flat_map(|k| [create(k, 1).unwrap(), create(k, 2).unwrap()]).collect()
}

#[test]
fn unusable_cameras_draw_background() {
    let frame = random_cloud(2000, 0.02, 1, 64);
    let scene = build_scene(&frame);
    let good = frame.header.camera;
    let bad = [
        Camera { fov_y_deg: f32::NAN, ..good },
        Camera { eye: Vec3::new(f32::INFINITY, 0.0, 0.0), ..good },
        Camera { eye: good.target, ..good },
        Camera { up: (good.target - good.eye), ..good },
        Camera { fov_y_deg: 0.0, ..good },
    ];
    for mut r in all_renderers() {
        for cam in bad {
            let mut img = Image::new(3, 3);
            r.render(&scene, &cam, &mut img);
            assert_eq!((img.width, img.height), (64, 64), "{}", r.name());
            assert!(img.pixels.iter().all(|&p| p == BACKGROUND), "{}", r.name());
        }
        for (w, h) in [(0, 10), (10, 0), (100_000, 100_000)] {
            let mut img = Image::new(3, 3);
            r.render(&scene, &good.with_viewport(w, h), &mut img);
            assert_eq!((img.width, img.height, img.pixels.len()), (0, 0, 0), "{}", r.name());
        }
    }
}

#[test]
fn inconsistent_scene_draws_background() {
    let frame = random_cloud(500, 0.05, 2, 32);
    let mut scene = build_scene(&frame);
    scene.colors.pop();
    let mut no_nodes = build_scene(&frame);
    no_nodes.nodes.truncate(10);
    for mut r in all_renderers() {
        for s in [&scene, &no_nodes] {
            let mut img = Image::new(1, 1);
            r.render(s, &frame.header.camera, &mut img);
            assert!(img.pixels.iter().all(|&p| p == BACKGROUND), "{}", r.name());
        }
    }
}

#[test]
fn degenerate_scenes_and_views() {
    let empty = build_scene(&Frame { samples: vec![], colors: vec![], ..random_cloud(0, 0.1, 1, 32) });
    let one = build_scene(&random_cloud(1, 0.2, 1, 32));
    let same = build_scene(&one_point_cloud(10_000, 48));
    let cloud = build_scene(&random_cloud(10_000, 0.02, 5, 48));
    let cams = [
        one_point_cloud(1, 48).header.camera,
        // Inside the cloud, and right at the common point of `same`.
        Camera::look_at(Vec3::splat(0.5), Vec3::new(0.2, 0.9, 0.5), Vec3::Y, 90.0, 40, 30),
        Camera::look_at(Vec3::splat(0.5001), Vec3::new(0.5, 0.5, -3.0), Vec3::Y, 60.0, 40, 30),
        // Looking away, far away, and nearly straight down the up axis.
        Camera::look_at(Vec3::new(0.5, 0.5, 5.0), Vec3::new(0.5, 0.5, 9.0), Vec3::Y, 45.0, 33, 17),
        Camera::look_at(Vec3::new(0.5, 0.5, 1e6), Vec3::splat(0.5), Vec3::Y, 1.0, 20, 20),
        Camera::look_at(Vec3::new(0.5, 3.0, 0.5001), Vec3::splat(0.5), Vec3::Y, 170.0, 21, 22),
    ];
    for mut r in all_renderers() {
        for s in [&empty, &one, &same, &cloud] {
            for cam in &cams {
                let mut img = Image::new(1, 1);
                r.render(s, cam, &mut img);
                assert_eq!(img.pixels.len(), (cam.width * cam.height) as usize);
                assert!(img.pixels.iter().all(|&p| p >> 24 == 255), "{}: opaque pixels only", r.name());
            }
        }
    }
    // Inside the one-point scene every sphere contains the eye: the far side is hit.
    let mut ids = Vec::new();
    PacketTracer::new(1).trace_ids(&same, &cams[2], &mut ids);
    assert!(ids.iter().all(|&i| i == 0), "{:?}", &ids[..4]);
    let _ = Scene::build(&random_cloud(0, 0.1, 1, 8));
}
