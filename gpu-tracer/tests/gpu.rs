//! GPU tests: they run for real on whatever adapter there is (lavapipe in CI) and FAIL when
//! there is none, unless `VOLWARP_SKIP_GPU=1` is set explicitly.

use volwarp_core::renderer::{Image, Renderer, BACKGROUND};
use volwarp_core::wire::Frame;
use volwarp_core::{Camera, Scene};
use volwarp_gpu_tracer::compare::{diff, ImageDiff};
use volwarp_gpu_tracer::reference::ScalarTracer;
use volwarp_gpu_tracer::synthetic::bumpy_surface;
use volwarp_gpu_tracer::GpuTracer;

/// The tracer, or `None` when the GPU tests are explicitly skipped.
fn tracer() -> Option<GpuTracer> {
    if std::env::var("VOLWARP_SKIP_GPU").is_ok_and(|v| v == "1") {
        eprintln!("VOLWARP_SKIP_GPU=1: GPU test skipped");
        return None;
    }
    let _ = env_logger::builder().is_test(true).try_init();
    match GpuTracer::new() {
        Ok(t) => Some(t),
        Err(e) => panic!("{e} (set VOLWARP_SKIP_GPU=1 to skip the GPU tests explicitly)"),
    }
}

fn cpu_image(scene: &Scene, cam: &Camera) -> Image {
    let mut img = Image::new(1, 1);
    ScalarTracer.render(scene, cam, &mut img);
    img
}

fn check_match(what: &str, cpu: &Image, gpu: &Image) -> ImageDiff {
    let d = diff(cpu, gpu).expect("same size");
    let hit = cpu.pixels.iter().filter(|&&p| p != BACKGROUND).count();
    eprintln!(
        "{what}: {:.4} % identical ({} of {}), max channel diff {}, {} hit pixels",
        100.0 * d.identical_share(),
        d.identical,
        d.pixels,
        d.max_channel_diff,
        hit
    );
    assert!(hit as u64 > d.pixels / 10, "{what}: the view should show the cloud");
    assert!(d.meets_target(), "{what}: only {:.4} % identical", 100.0 * d.identical_share());
    d
}

fn synthetic(size: u32) -> Frame {
    bumpy_surface(size, 1.5, 7)
}

#[test]
fn gpu_trace_matches_cpu_on_synthetic_cloud() {
    let Some(mut gpu) = tracer() else { return };
    eprintln!("adapter: {:?}", gpu.adapter_info());
    assert_eq!(gpu.name(), "spheres-gpu");
    let frame = synthetic(256);
    let scene = Scene::build(&frame);
    let base = frame.header.camera;
    for (yaw, pitch) in [(0.0, 0.0), (10.0, 0.0), (-25.0, 15.0), (40.0, -30.0)] {
        let cam = base.orbit(yaw, pitch).with_viewport(192, 160);
        let cpu = cpu_image(&scene, &cam);
        let mut img = Image::new(1, 1);
        gpu.try_render(&scene, &cam, &mut img).unwrap();
        check_match(&format!("synthetic yaw {yaw} pitch {pitch}"), &cpu, &img);
    }
    assert_eq!(gpu.scene_uploads(), 1, "the same scene is uploaded once for every camera");
}

#[test]
fn gpu_built_lbvh_is_valid_and_traces_the_same_image() {
    let Some(mut gpu) = tracer() else { return };
    let frame = synthetic(200);
    let cpu_scene = Scene::build(&frame);
    let gpu_scene = gpu.build_scene(&frame).unwrap();
    eprintln!("GPU build timing: {:?}", gpu.last_build_timing());
    let n = frame.samples.len();
    let mut seen = vec![0u8; 2 * n];
    gpu_scene.lbvh().check(&mut seen).expect("GPU-built tree is valid");
    // Same sort (all 54 code bits, stable) and the same Karras links: identical topology.
    assert_eq!(gpu_scene.samples, cpu_scene.samples);
    assert_eq!(gpu_scene.colors, cpu_scene.colors);
    let links = |s: &Scene| s.nodes.iter().map(|n| (n.left, n.right)).collect::<Vec<_>>();
    assert_eq!(links(&gpu_scene), links(&cpu_scene));
    let same_boxes = gpu_scene.nodes.iter().zip(&cpu_scene.nodes).filter(|(a, b)| a == b).count();
    eprintln!("{same_boxes} of {} node boxes bit-identical to the CPU build", n - 1);
    let cam = frame.header.camera.orbit(10.0, 5.0).with_viewport(160, 160);
    let cpu = cpu_image(&cpu_scene, &cam);
    let uploads = gpu.scene_uploads();
    let mut img = Image::new(1, 1);
    gpu.try_render(&gpu_scene, &cam, &mut img).unwrap();
    assert_eq!(gpu.scene_uploads(), uploads, "a GPU-built scene is already resident");
    check_match("GPU-built tree", &cpu, &img);
}
