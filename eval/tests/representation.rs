//! The representation-size sweep's float sphere splatter against the CPU packet tracer: on the
//! same (dequantized) samples in the same order they must draw the same image, so the sweep
//! measures the representation and not a renderer difference.

use volwarp_core::renderer::Renderer;
use volwarp_core::{Heuristic, Image};
use volwarp_eval::camera_paths::orbit;
use volwarp_eval::quality::frame_for;
use volwarp_eval::representation_size::{render_spheres, sweep, FloatSamples};
use volwarp_server::{Dataset, Marcher};

#[test]
fn float_splatter_draws_what_the_packet_tracer_draws() {
    let ds = Dataset::default_bundled();
    let m = Marcher::from_dataset(&ds);
    let c0 = m.default_camera(96, 96);
    let frame = frame_for(&m, &c0, Heuristic::Threshold);
    let scene = volwarp_cpu_tracer::build_scene(&frame);
    let s = FloatSamples {
        centers: scene.samples.iter().map(|&q| scene.deq.center(q)).collect(),
        radii: scene.samples.iter().map(|&q| scene.deq.radius(q)).collect(),
        colors: scene.colors.clone(),
        pixels: vec![(0, 0); scene.samples.len()],
    };
    let mut tracer = volwarp_cpu_tracer::PacketTracer::new(2);
    for a in [0.0, 10.0, 30.0] {
        let cam = orbit(&c0, a);
        let mut want = Image::new(0, 0);
        tracer.render(&scene, &cam, &mut want);
        let got = render_spheres(&s, &cam);
        let same = want.pixels.iter().zip(&got.pixels).filter(|(a, b)| a == b).count();
        assert_eq!(
            same,
            want.pixels.len(),
            "angle {a}: {} of {} pixels differ",
            want.pixels.len() - same,
            want.pixels.len()
        );
    }
}

#[test]
fn finer_quantization_converges_to_float() {
    let ds = Dataset::default_bundled();
    let m = Marcher::from_dataset(&ds);
    let c0 = m.default_camera(64, 64);
    let vs = sweep(&m, &c0, Heuristic::Threshold, &[10.0]);
    let float = vs.iter().find(|v| v.sweep == "float").unwrap().metrics[0].psnr;
    let at =
        |sweep: &str, value: u32| vs.iter().find(|v| v.sweep == sweep && v.value == value).unwrap().metrics[0].psnr;
    assert!((at("position", 21) - float).abs() < 0.05, "21 bits {} vs float {float}", at("position", 21));
    assert!((at("radius", 10) - float).abs() < 0.5);
    // Coarse positions cost accuracy (6 bits: 1 dB less); from 15 bits on, the image is the
    // float one up to single pixels (PSNR within 0.05 dB), and so it is from 9 radius bits on.
    assert!(at("position", 6) < float - 0.5, "6 bits {} vs float {float}", at("position", 6));
    for bits in 15..=21 {
        assert!((at("position", bits) - float).abs() < 0.05, "{bits} bits {} vs float {float}", at("position", bits));
    }
    for bits in [9, 10] {
        assert!((at("radius", bits) - float).abs() < 1e-9, "{bits} radius bits");
    }
    assert!(vs.iter().all(|v| v.metrics.iter().all(|x| x.psnr.is_finite())));
}
