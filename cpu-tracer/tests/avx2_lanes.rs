//! With `VOLWARP_LANES=avx2` (read once per process: this file holds one test, so it runs in
//! its own process) a CPU with AVX-512 takes the eight-lane AVX2 instances of every kernel,
//! as a CPU without AVX-512 does, and they give the scalar reference's sample ids.

use volwarp_cpu_tracer::synthetic::{depth_image_frame, random_cloud};
use volwarp_cpu_tracer::{build_scene, lane_kind, ScalarTracer, TileSplat, NO_HIT};

#[test]
fn avx2_instances_equal_the_scalar_reference() {
    // SAFETY: set before any other thread of this process exists or reads the environment.
    unsafe { std::env::set_var("VOLWARP_LANES", "avx2") };
    let avx2 = volwarp_lanes::detected() >= volwarp_lanes::LaneKind::Avx2;
    assert_eq!(lane_kind(), if avx2 { "avx2" } else { "portable" });
    let r = random_cloud(20_000, 0.004, 71, 128);
    let d = depth_image_frame(160, 1.5, 72);
    for (frame, cams) in [
        (&r, vec![r.header.camera, r.header.camera.orbit(20.0, 5.0).with_viewport(131, 77)]),
        (&d, vec![d.header.camera.orbit(10.0, 0.0).with_viewport(80, 80), d.header.camera.dolly(0.3)]),
    ] {
        let scene = build_scene(frame);
        for cam in cams {
            let (mut s, mut t) = (Vec::new(), Vec::new());
            assert!(ScalarTracer::new(1).trace_ids(&scene, &cam, &mut s));
            assert!(s.iter().any(|&i| i != NO_HIT));
            for threads in [1, 2] {
                let mut splat = TileSplat::new(threads);
                assert!(splat.splat_ids(&scene, &cam, &mut t));
                assert!(t == s, "AVX2 splatter, {threads} thread(s)");
            }
        }
    }
}
