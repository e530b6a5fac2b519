//! The lane kind the kernels take fits the architecture the tests run on, and those kernels
//! give the scalar reference's sample ids. On aarch64 (the ARM thin clients; CI runs this under
//! qemu-user) that is the portable lanes (`wide` on NEON): this is what makes them *executed*
//! on ARM, not only compiled.

use volwarp_core::Vec3;
use volwarp_cpu_tracer::synthetic::{depth_image_frame, random_cloud};
use volwarp_cpu_tracer::{build_scene, lane_kind, PacketTracer, ScalarTracer, TileSplat, NO_HIT};

#[test]
fn the_lane_kind_fits_the_architecture_and_its_kernels_equal_the_scalar_reference() {
    let kind = lane_kind();
    eprintln!("{}: lane kind {kind}", std::env::consts::ARCH);
    #[cfg(target_arch = "aarch64")]
    assert_eq!(kind, "portable", "aarch64 has only the portable lanes");
    #[cfg(target_arch = "x86_64")]
    assert!(["portable", "avx2", "avx512"].contains(&kind), "{kind}");
    // Small enough for an emulated CPU.
    let r = random_cloud(4_000, 0.02, 71, 64);
    let d = depth_image_frame(64, 1.5, 72);
    let inside = volwarp_core::Camera::look_at(Vec3::splat(0.5), Vec3::new(0.9, 0.6, 0.1), Vec3::Y, 70.0, 45, 31);
    for (frame, cams) in [
        (&r, vec![r.header.camera, r.header.camera.orbit(20.0, 5.0).with_viewport(67, 41), inside]),
        (&d, vec![d.header.camera.orbit(10.0, 0.0).with_viewport(72, 50)]),
    ] {
        let scene = build_scene(frame);
        for cam in cams {
            let (mut s, mut t, mut p) = (Vec::new(), Vec::new(), Vec::new());
            assert!(ScalarTracer::new(1).trace_ids(&scene, &cam, &mut s));
            assert!(s.iter().any(|&i| i != NO_HIT));
            assert!(TileSplat::new(2).splat_ids(&scene, &cam, &mut t));
            assert!(t == s, "{kind} splatter");
            assert!(PacketTracer::new(2).trace_ids(&scene, &cam, &mut p));
            assert!(p == s, "{kind} packet tracer");
        }
    }
}
