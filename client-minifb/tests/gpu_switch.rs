//! Switching to the GPU tracer: where an adapter opens (lavapipe counts), it draws the CPU
//! tracer's image; where none does (allowed only with `VOLWARP_SKIP_GPU=1`), the switch fails
//! with a clear message and the current renderer stays. Never a panic.
#![cfg(feature = "gpu")]

use volwarp_client::renderers::Renderers;
use volwarp_core::renderer::Image;
use volwarp_core::RendererKind;
use volwarp_core::Scene;
use volwarp_cpu_tracer::synthetic::depth_image_frame;

#[test]
fn gpu_switch_draws_the_cpu_image_or_explains_why_not() {
    let frame = depth_image_frame(64, 1.0, 3);
    let scene = Scene::build(&frame);
    let cam = frame.header.camera.orbit(10.0, 5.0);
    let mut r = Renderers::new(RendererKind::SpheresCpu, 1).unwrap();
    let mut cpu = Image::new(1, 1);
    r.render(&scene, &cam, &mut cpu);
    match r.select(RendererKind::SpheresGpu) {
        Ok(()) => {
            assert_eq!(r.name(), "spheres-gpu");
            let mut gpu = Image::new(1, 1);
            r.render(&scene, &cam, &mut gpu);
            assert_eq!((gpu.width, gpu.height), (cpu.width, cpu.height));
            let same = gpu.pixels.iter().zip(&cpu.pixels).filter(|(a, b)| a == b).count();
            // Every pixel on a software rasterizer (lavapipe in CI), 99.9 % on a hardware GPU.
            let info = volwarp_gpu_tracer::GpuContext::new().expect("the adapter opened a moment ago").info;
            let need = volwarp_gpu_tracer::adapter::required_identical_share(&info);
            assert!(
                same as f64 >= need * cpu.pixels.len() as f64,
                "GPU and CPU images agree on only {same} of {} pixels",
                cpu.pixels.len()
            );
            // Switching back and forth keeps the opened tracer.
            r.select(RendererKind::SpheresCpu).unwrap();
            r.select_key(7).unwrap();
            assert_eq!(r.name(), "spheres-gpu");
        }
        Err(e) => {
            // CI has lavapipe: the GPU path must be what runs there.
            let skip = std::env::var("VOLWARP_SKIP_GPU").is_ok_and(|v| v == "1");
            assert!(skip, "no GPU adapter opened ({e}); set VOLWARP_SKIP_GPU=1 to test only the refusal");
            eprintln!("no GPU adapter here: {e}");
            assert!(e.contains("unavailable") && e.contains("staying on spheres-cpu"), "{e}");
            assert_eq!(r.name(), "spheres-cpu");
            // A second try answers at once with the same reason.
            assert_eq!(r.select(RendererKind::SpheresGpu).unwrap_err(), e);
        }
    }
}
