//! Real frames: the server's ray marcher on the bundled CT head (and the MRI from
//! `../shared/data`, see `volwarp_server::testdata`), traced on the GPU and on the CPU (`volwarp-eval`'s tests
//! replay a recorded real stream through `volwarp-compare`). Needs a GPU adapter (lavapipe in CI);
//! `VOLWARP_SKIP_GPU=1` skips explicitly.

use volwarp_core::renderer::{Image, Renderer, BACKGROUND};
use volwarp_core::wire::{CameraRequest, Frame};
use volwarp_core::{Camera, Heuristic, Scene};
use volwarp_cpu_tracer::PacketTracer;
use volwarp_gpu_tracer::adapter::required_identical_share;
use volwarp_gpu_tracer::GpuTracer;
use volwarp_server::{Dataset, Marcher};

fn skip() -> bool {
    let s = std::env::var("VOLWARP_SKIP_GPU").is_ok_and(|v| v == "1");
    if s {
        eprintln!("VOLWARP_SKIP_GPU=1: GPU test skipped");
    }
    s
}

fn request(seq: u64, camera: Camera, heuristic: Heuristic) -> CameraRequest {
    CameraRequest { seq, camera, heuristic, radius_scale: 1.0, layers: 0 }
}

/// Frames of the marcher for a few views and heuristics.
fn frames(marcher: &Marcher, size: u32) -> Vec<Frame> {
    let cam = marcher.default_camera(size, size);
    [(0.0, 0.0, Heuristic::Threshold), (35.0, 10.0, Heuristic::Gradient), (-60.0, -20.0, Heuristic::Entrance)]
        .iter()
        .enumerate()
        .map(|(i, &(yaw, pitch, h))| marcher.render_frame(&request(i as u64, cam.orbit(yaw, pitch), h)).0)
        .collect()
}

fn compare_frames(gpu: &mut GpuTracer, name: &str, frames: &[Frame]) {
    let mut cpu = PacketTracer::new(0);
    for (i, frame) in frames.iter().enumerate() {
        let n = frame.samples.len();
        assert!(n > 1000, "{name} frame {i}: only {n} samples");
        let scene = Scene::build(frame);
        let gpu_scene = gpu.build_scene(frame).unwrap();
        let mut seen = vec![0u8; 2 * n];
        // The GPU rounds every step of the leaf boxes as the CPU does (no fused or reassociated
        // arithmetic), so its fitted boxes equal the CPU's bit for bit.
        let differ = gpu_scene.nodes.iter().zip(&scene.nodes).filter(|(g, c)| g.min != c.min || g.max != c.max);
        if let Some((g, c)) = differ.clone().next() {
            panic!("{name} frame {i}: {} node boxes differ from the CPU's, e.g. {g:?} against {c:?}", differ.count());
        }
        gpu_scene.lbvh().check(&mut seen).unwrap();
        let links = |s: &Scene| s.nodes.iter().map(|n| (n.left, n.right)).collect::<Vec<_>>();
        assert_eq!(links(&gpu_scene), links(&scene), "{name} frame {i}: GPU tree topology");
        let cam = frame.header.camera.orbit(10.0, 0.0);
        let (mut want, mut got, mut got_gpu_built) = (Image::new(1, 1), Image::new(1, 1), Image::new(1, 1));
        cpu.render(&scene, &cam, &mut want);
        gpu.try_render(&scene, &cam, &mut got).unwrap();
        gpu.try_render(&gpu_scene, &cam, &mut got_gpu_built).unwrap();
        let hit = want.pixels.iter().filter(|&&p| p != BACKGROUND).count();
        for (what, img) in [("CPU-built tree", &got), ("GPU-built tree", &got_gpu_built)] {
            let d = want.diff(img).unwrap();
            eprintln!(
                "{name} frame {i} ({n} samples, {hit} hit pixels), {what}: {:.4} % identical, max diff {}",
                100.0 * d.identical_share(),
                d.max_channel_diff
            );
            let need = required_identical_share(gpu.adapter_info());
            assert!(d.identical_share() >= need, "{name} frame {i}, {what}: {:.4} %", 100.0 * d.identical_share());
        }
        assert!(hit > 1000);
    }
}

#[test]
fn gpu_matches_cpu_on_real_frames_of_the_bundled_ct_head() {
    if skip() {
        return;
    }
    let _ = env_logger::builder().is_test(true).try_init();
    let mut gpu = GpuTracer::new().unwrap_or_else(|e| panic!("{e} (VOLWARP_SKIP_GPU=1 skips explicitly)"));
    let marcher = Marcher::from_dataset(&Dataset::default_bundled());
    compare_frames(&mut gpu, "ct head", &frames(&marcher, 256));
}

#[test]
fn gpu_matches_cpu_on_a_real_frame_of_the_mri_where_available() {
    if skip() {
        return;
    }
    let Some(ds) = volwarp_server::testdata::shared_dataset(volwarp_server::testdata::MRI) else { return };
    let mut gpu = GpuTracer::new().unwrap_or_else(|e| panic!("{e} (VOLWARP_SKIP_GPU=1 skips explicitly)"));
    let marcher = Marcher::from_dataset(&ds);
    let cam = marcher.default_camera(256, 256);
    let frame = marcher.render_frame(&request(1, cam, Heuristic::Threshold)).0;
    compare_frames(&mut gpu, "mri", &[frame]);
}
