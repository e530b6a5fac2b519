//! GPU tests: they run for real on whatever adapter there is (lavapipe in CI) and FAIL when
//! there is none, unless `VOLWARP_SKIP_GPU=1` is set explicitly.

use volwarp_core::renderer::{Image, Renderer, BACKGROUND};
use volwarp_core::wire::Frame;
use volwarp_core::ImageDiff;
use volwarp_core::{Camera, Scene};
use volwarp_cpu_tracer::{PacketTracer, ScalarTracer};
use volwarp_gpu_tracer::adapter::required_identical_share;
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
        Ok(t) => {
            NEED.get_or_init(|| required_identical_share(t.adapter_info()));
            Some(t)
        }
        Err(e) => panic!("{e} (set VOLWARP_SKIP_GPU=1 to skip the GPU tests explicitly)"),
    }
}

/// The share of identical pixels this adapter must reach (`required_identical_share`: every
/// pixel on lavapipe).
static NEED: std::sync::OnceLock<f64> = std::sync::OnceLock::new();

fn cpu_image(scene: &Scene, cam: &Camera) -> Image {
    let mut img = Image::new(1, 1);
    PacketTracer::new(0).render(scene, cam, &mut img);
    img
}

fn check_match(what: &str, cpu: &Image, gpu: &Image) -> ImageDiff {
    let d = cpu.diff(gpu).expect("same size");
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
    let need = *NEED.get().expect("a tracer was opened");
    assert!(d.identical_share() >= need, "{what}: only {:.4} % identical", 100.0 * d.identical_share());
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

#[test]
fn gpu_trace_matches_the_scalar_oracle_exactly_on_small_scenes() {
    let Some(mut gpu) = tracer() else { return };
    let mut scalar = ScalarTracer::new(0);
    // 1 sample (no internal node), 2, 3, and a cloud whose size is not a tile multiple.
    for size in [1u32, 2, 3, 37] {
        let mut frame = synthetic(size.max(2));
        frame.samples.truncate((size * size) as usize);
        frame.colors.truncate((size * size) as usize);
        frame.header.count = frame.samples.len() as u32;
        let scene = Scene::build(&frame);
        let cam = Camera::look_at(
            volwarp_core::Vec3::new(0.3, 0.2, 3.0),
            volwarp_core::Vec3::ZERO,
            volwarp_core::Vec3::Y,
            50.0,
            48,
            40,
        );
        let mut want = Image::new(1, 1);
        scalar.render(&scene, &cam, &mut want);
        let mut got = Image::new(1, 1);
        gpu.try_render(&scene, &cam, &mut got).unwrap();
        assert_eq!(want.diff(&got).unwrap().identical, 48 * 40, "{} samples", scene.samples.len());
    }
}

#[test]
fn bad_input_is_a_clear_error_and_a_background_image() {
    let Some(mut gpu) = tracer() else { return };
    let frame = synthetic(32);
    let scene = Scene::build(&frame);
    let mut img = Image::new(1, 1);
    let cam = frame.header.camera;
    let bad_cam = Camera { fov_y_deg: f32::NAN, ..cam };
    assert!(matches!(gpu.try_render(&scene, &bad_cam, &mut img), Err(volwarp_gpu_tracer::GpuError::BadCamera(_))));
    let huge = cam.with_viewport(100_000, 100_000);
    assert!(gpu.try_render(&scene, &huge, &mut img).is_err());
    assert_eq!((img.width, img.height, img.pixels.len()), (0, 0, 0), "no allocation for a bad viewport");
    let mut broken = scene.clone();
    broken.nodes.pop();
    let r = gpu.try_render(&broken, &cam, &mut img);
    assert!(matches!(r, Err(volwarp_gpu_tracer::GpuError::BadScene(_))), "{r:?}");
    assert!(img.pixels.iter().all(|&p| p == BACKGROUND));
    // The Renderer interface logs instead of failing and still gives a full background image.
    gpu.render(&broken, &cam.with_viewport(20, 10), &mut img);
    assert_eq!(img.pixels.len(), 200);
    assert!(img.pixels.iter().all(|&p| p == BACKGROUND));
    // An empty scene draws the background; a good scene still renders after the errors.
    let empty = Scene::build(&Frame { samples: vec![], colors: vec![], ..frame.clone() });
    gpu.try_render(&empty, &cam, &mut img).unwrap();
    assert!(img.pixels.iter().all(|&p| p == BACKGROUND));
    gpu.try_render(&scene, &cam, &mut img).unwrap();
    assert!(img.pixels.iter().any(|&p| p != BACKGROUND));
    let mut bad_frame = frame.clone();
    bad_frame.colors.pop();
    assert!(gpu.build_scene(&bad_frame).is_err());
    let mut nan_frame = frame.clone();
    nan_frame.header.bounds.max[1] = f32::NAN;
    assert!(matches!(gpu.build_scene(&nan_frame), Err(volwarp_gpu_tracer::GpuError::BadScene(_))));
}

#[test]
fn buffers_are_reused_and_new_scenes_are_uploaded() {
    let Some(mut gpu) = tracer() else { return };
    let big = Scene::build(&synthetic(64));
    let cam = big.header.camera.with_viewport(64, 64);
    let mut img = Image::new(1, 1);
    gpu.try_render(&big, &cam, &mut img).unwrap();
    let allocs = gpu.buffer_allocations();
    // Same length and sequence number, different content: must be uploaded, not mistaken.
    let mut other_frame = synthetic(64);
    other_frame.colors.iter_mut().for_each(|c| *c = 0xff00_00ff);
    let other = Scene::build(&other_frame);
    gpu.try_render(&other, &cam, &mut img).unwrap();
    assert_eq!(gpu.scene_uploads(), 2);
    assert!(img.pixels.contains(&0xff00_00ff), "the new scene's colors are shown");
    // Smaller scenes and viewports fit in the buffers already there.
    let small = Scene::build(&synthetic(40));
    gpu.try_render(&small, &cam.with_viewport(50, 40), &mut img).unwrap();
    gpu.try_render(&big, &cam, &mut img).unwrap();
    assert_eq!(gpu.buffer_allocations(), allocs, "no reallocation for smaller frames");
}

#[test]
fn gpu_build_handles_duplicates_and_odd_sizes() {
    let Some(mut gpu) = tracer() else { return };
    let base = synthetic(48);
    for n in [2usize, 3, 129, 1000] {
        let mut frame = base.clone();
        frame.samples.truncate(n);
        frame.colors.truncate(n);
        // Many identical positions: the index tie-break must still give a valid tree.
        for i in (0..n).step_by(3) {
            frame.samples[i] = frame.samples[0];
        }
        let cpu = Scene::build(&frame);
        let g = gpu.build_scene(&frame).unwrap();
        let mut seen = vec![0u8; 2 * n];
        g.lbvh().check(&mut seen).unwrap_or_else(|e| panic!("n = {n}: {e:?}"));
        assert_eq!(g.samples, cpu.samples, "n = {n}");
        let links = |s: &Scene| s.nodes.iter().map(|n| (n.left, n.right)).collect::<Vec<_>>();
        assert_eq!(links(&g), links(&cpu), "n = {n}");
    }
}

#[test]
fn gpu_build_of_two_million_samples_equals_the_cpu_build() {
    let Some(mut gpu) = tracer() else { return };
    // 256 × ceil(n / 1024) histogram entries > 2048: a two-level device-wide scan.
    let frame = bumpy_surface(1500, 1.0, 3);
    let n = frame.samples.len();
    assert!(n > 2_200_000, "{n}");
    let cpu = Scene::build(&frame);
    let g = gpu.build_scene(&frame).unwrap();
    eprintln!("{n} samples: GPU build {:?}", gpu.last_build_timing());
    assert!(g.samples == cpu.samples && g.colors == cpu.colors, "GPU sort differs from the CPU sort");
    assert!(g.nodes == cpu.nodes, "GPU nodes differ from the CPU nodes");
    let mut seen = vec![0u8; 2 * n];
    g.lbvh().check(&mut seen).unwrap();
}

#[test]
fn the_tracer_can_move_to_another_thread() {
    fn assert_send<T: Send>() {}
    assert_send::<GpuTracer>();
    assert_send::<Box<dyn Renderer + Send>>();
    let _boxed: Option<Box<dyn Renderer + Send>> = tracer().map(|t| Box::new(t) as Box<dyn Renderer + Send>);
}

#[test]
fn an_adapter_name_that_matches_nothing_is_a_clear_error() {
    // No GPU needed: either adapters exist (lavapipe in CI) and the error lists them, or none
    // does and the error says what to install. Never a panic.
    let name = "no-such-adapter-3f9c";
    for e in [
        GpuTracer::with_adapter(Some(name)).map(|_| ()).unwrap_err(),
        volwarp_gpu_tracer::GpuSplat::with_adapter(Some(name)).map(|_| ()).unwrap_err(),
    ] {
        let msg = e.to_string();
        eprintln!("{msg}");
        assert!(matches!(e, volwarp_gpu_tracer::GpuError::NoAdapter(_)), "{e:?}");
        if msg.contains("found:") {
            assert!(msg.contains(name), "{msg}");
        } else {
            assert!(msg.contains("apt-get install mesa-vulkan-drivers"), "{msg}");
        }
    }
}
