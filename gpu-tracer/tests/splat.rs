//! The GPU exact sphere splatter (`splat-gpu`) against the CPU's exact splatter and the packet
//! tracer: synthetic clouds from several views, and real frames of the server's marcher (the
//! bundled CT head, the MRI from `../shared/data`, see `volwarp_server::testdata`). Needs a GPU adapter
//! (lavapipe in CI); `VOLWARP_SKIP_GPU=1` skips explicitly.

use volwarp_core::renderer::{Image, Renderer, BACKGROUND};
use volwarp_core::wire::{CameraRequest, Frame};
use volwarp_core::{Camera, Heuristic, RendererKind, Scene, Vec3};
use volwarp_cpu_tracer::{PacketTracer, ScalarTracer, SphereSplat};
use volwarp_gpu_tracer::adapter::required_identical_share;
use volwarp_gpu_tracer::synthetic::bumpy_surface;
use volwarp_gpu_tracer::{GpuError, GpuSplat};
use volwarp_server::{Dataset, Marcher};

fn splatter() -> Option<GpuSplat> {
    if std::env::var("VOLWARP_SKIP_GPU").is_ok_and(|v| v == "1") {
        eprintln!("VOLWARP_SKIP_GPU=1: GPU test skipped");
        return None;
    }
    let _ = env_logger::builder().is_test(true).try_init();
    match GpuSplat::new() {
        Ok(s) => Some(s),
        Err(e) => panic!("{e} (set VOLWARP_SKIP_GPU=1 to skip the GPU tests explicitly)"),
    }
}

/// GPU splat vs the CPU splatter and the packet tracer: identical pixels, every one on lavapipe
/// (`required_identical_share`).
fn compare(gpu: &mut GpuSplat, what: &str, scene: &Scene, cam: &Camera) {
    let (mut splat, mut traced, mut got) = (Image::new(1, 1), Image::new(1, 1), Image::new(1, 1));
    SphereSplat::new(0).render(scene, cam, &mut splat);
    PacketTracer::new(0).render(scene, cam, &mut traced);
    gpu.try_render(scene, cam, &mut got).unwrap();
    let hit = traced.pixels.iter().filter(|&&p| p != BACKGROUND).count();
    assert!(hit as u64 > (cam.width * cam.height) as u64 / 20, "{what}: the view should show the cloud ({hit})");
    for (against, want) in [("CPU splat", &splat), ("packet tracer", &traced)] {
        let d = want.diff(&got).unwrap();
        eprintln!(
            "{what}: splat-gpu vs {against}: {:.4} % identical ({} of {}), max diff {}, {hit} hit pixels",
            100.0 * d.identical_share(),
            d.identical,
            d.pixels,
            d.max_channel_diff
        );
        let need = required_identical_share(&gpu.context().info);
        assert!(d.identical_share() >= need, "{what} vs {against}: only {:.4} %", 100.0 * d.identical_share());
    }
}

#[test]
fn gpu_splat_matches_the_cpu_on_synthetic_clouds() {
    let Some(mut gpu) = splatter() else { return };
    assert_eq!(gpu.kind(), RendererKind::SplatGpu);
    assert_eq!(gpu.name(), "splat-gpu");
    // Radius ×1.5 (overlapping spheres: depth order and ties matter) and ×4 (large spheres).
    for (size, scale) in [(160u32, 1.5f32), (90, 4.0)] {
        let frame = bumpy_surface(size, scale, 3);
        let scene = Scene::build(&frame);
        for (yaw, pitch) in [(0.0, 0.0), (25.0, 10.0), (-40.0, -30.0), (70.0, 35.0)] {
            let cam = frame.header.camera.orbit(yaw, pitch).with_viewport(176, 144);
            compare(&mut gpu, &format!("synthetic {size}² ×{scale} yaw {yaw} pitch {pitch}"), &scene, &cam);
        }
    }
    assert_eq!(gpu.scene_uploads(), 2, "each scene is uploaded once for all its cameras");
}

#[test]
fn gpu_splat_equals_the_scalar_oracle_on_small_scenes_and_close_views() {
    let Some(mut gpu) = splatter() else { return };
    let mut scalar = ScalarTracer::new(0);
    for size in [1u32, 2, 3, 37] {
        let mut frame = bumpy_surface(size.max(2), 2.0, 1);
        let n = (size * size) as usize;
        frame.samples.truncate(n);
        frame.colors.truncate(n);
        frame.header.count = n as u32;
        let scene = Scene::build(&frame);
        // A far view, and one with the eye among the spheres (bounds touching the eye plane).
        for eye in [Vec3::new(0.3, 0.2, 3.0), Vec3::new(0.05, 0.02, 0.15)] {
            let cam = Camera::look_at(eye, Vec3::ZERO, Vec3::Y, 50.0, 48, 40);
            let (mut want, mut got) = (Image::new(1, 1), Image::new(1, 1));
            scalar.render(&scene, &cam, &mut want);
            gpu.try_render(&scene, &cam, &mut got).unwrap();
            assert_eq!(want.diff(&got).unwrap().identical, 48 * 40, "{n} samples, eye {eye:?}");
        }
    }
}

#[test]
fn gpu_splat_bad_input_is_a_clear_error_and_a_background_image() {
    let Some(mut gpu) = splatter() else { return };
    let frame = bumpy_surface(32, 1.5, 2);
    let scene = Scene::build(&frame);
    let cam = frame.header.camera;
    let mut img = Image::new(1, 1);
    let bad = Camera { fov_y_deg: f32::NAN, ..cam };
    assert!(matches!(gpu.try_render(&scene, &bad, &mut img), Err(GpuError::BadCamera(_))));
    let mut broken = scene.clone();
    broken.colors.pop();
    assert!(matches!(gpu.try_render(&broken, &cam, &mut img), Err(GpuError::BadScene(_))));
    assert!(img.pixels.iter().all(|&p| p == BACKGROUND));
    let empty = Scene::build(&Frame { samples: vec![], colors: vec![], ..frame.clone() });
    gpu.try_render(&empty, &cam.with_viewport(20, 10), &mut img).unwrap();
    assert_eq!(img.pixels.len(), 200);
    assert!(img.pixels.iter().all(|&p| p == BACKGROUND));
    gpu.try_render(&scene, &cam, &mut img).unwrap();
    assert!(img.pixels.iter().any(|&p| p != BACKGROUND));
}

fn request(seq: u64, camera: Camera, heuristic: Heuristic) -> CameraRequest {
    CameraRequest { seq, camera, heuristic, radius_scale: 1.0, layers: 0 }
}

#[test]
fn gpu_splat_matches_the_cpu_on_real_frames() {
    let Some(mut gpu) = splatter() else { return };
    let mut marchers = vec![("ct head", Marcher::from_dataset(&Dataset::default_bundled()))];
    if let Some(ds) = volwarp_server::testdata::shared_dataset(volwarp_server::testdata::MRI) {
        marchers.push(("mri", Marcher::from_dataset(&ds)));
    }
    for (name, marcher) in &marchers {
        let cam = marcher.default_camera(256, 256);
        for (i, &(yaw, pitch, h)) in
            [(0.0, 0.0, Heuristic::Threshold), (35.0, 10.0, Heuristic::Gradient), (-60.0, -20.0, Heuristic::Entrance)]
                .iter()
                .enumerate()
        {
            let frame = marcher.render_frame(&request(i as u64, cam.orbit(yaw, pitch), h)).0;
            let scene = Scene::build(&frame);
            compare(&mut gpu, &format!("{name} frame {i}"), &scene, &frame.header.camera.orbit(10.0, 0.0));
        }
    }
}
