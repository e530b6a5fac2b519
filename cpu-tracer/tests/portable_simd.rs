//! The portable (`wide`, non-AVX2) kernels, forced with `VOLWARP_PORTABLE_SIMD` (read once per
//! process: this file holds one test, so it runs in its own process), give the scalar
//! reference's sample ids too: the tiled splatter, the direct splatter (feature `direct-splat`),
//! the default renderer and the packet tracer.

use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::Vec3;
use volwarp_cpu_tracer::synthetic::{depth_image_frame, random_cloud};
use volwarp_cpu_tracer::{build_scene, AutoSpheres, PacketTracer, ScalarTracer, TileSplat, NO_HIT};

#[test]
fn portable_kernels_equal_the_scalar_reference() {
    // SAFETY: set before any other thread of this process exists or reads the environment.
    unsafe { std::env::set_var("VOLWARP_PORTABLE_SIMD", "1") };
    let r = random_cloud(20_000, 0.01, 61, 128);
    let d = depth_image_frame(160, 1.5, 62);
    let inside = volwarp_core::Camera::look_at(Vec3::splat(0.5), Vec3::new(0.9, 0.6, 0.1), Vec3::Y, 70.0, 97, 64);
    for (frame, cams) in [
        (&r, vec![r.header.camera, r.header.camera.orbit(20.0, 5.0).with_viewport(131, 77), inside]),
        (&d, vec![d.header.camera.orbit(10.0, 0.0), d.header.camera.dolly(0.3).with_viewport(200, 150)]),
    ] {
        let scene = build_scene(frame);
        for cam in cams {
            let (mut s, mut t, mut p) = (Vec::new(), Vec::new(), Vec::new());
            assert!(ScalarTracer::new(1).trace_ids(&scene, &cam, &mut s));
            assert!(s.iter().any(|&i| i != NO_HIT));
            assert!(TileSplat::new(2).splat_ids(&scene, &cam, &mut t));
            assert!(t == s, "portable splatter");
            #[cfg(feature = "direct-splat")]
            for (threads, two) in [(1, false), (2, true), (3, false)] {
                let mut dd = Vec::new();
                let mut direct = volwarp_cpu_tracer::DirectSplat::new(threads).with_windows(two);
                assert!(direct.splat_ids(&scene, &cam, &mut dd));
                assert!(dd == s, "portable direct splatter, {threads} thread(s)");
            }
            assert!(PacketTracer::new(2).trace_ids(&scene, &cam, &mut p));
            assert!(p == s, "portable packet tracer");
            let (mut a, mut b) = (Image::new(1, 1), Image::new(1, 1));
            AutoSpheres::new(1).render(&scene, &cam, &mut a);
            ScalarTracer::new(1).render(&scene, &cam, &mut b);
            assert_eq!(a, b);
        }
    }
}
