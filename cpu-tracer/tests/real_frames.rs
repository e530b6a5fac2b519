//! Real frames from the server's marcher (the MRI of `../shared/data`): packet == scalar,
//! parallel build == serial build, splat == trace. A missing MRI fails the test unless
//! `VOLWARP_NO_SHARED_DATA=1` (`volwarp_server::testdata`).

mod common;

#[path = "../benches/support/frames.rs"]
mod frames;

use common::assert_packet_equals_scalar;
use volwarp_core::Scene;
use volwarp_cpu_tracer::{PacketTracer, ParallelBuilder, SphereSplat, NO_HIT};

#[test]
fn mri_frames_trace_exactly() {
    if volwarp_server::testdata::shared_data(volwarp_server::testdata::MRI).is_none() {
        return;
    }
    let (frame, what) = frames::mri_frame(256).expect("the shared MRI renders a frame");
    assert!(frame.samples.len() > 10_000, "{what}");
    let serial = Scene::build(&frame);
    let par = ParallelBuilder::new(2).build(&frame);
    assert_eq!(par.samples, serial.samples);
    assert_eq!(par.colors, serial.colors);
    assert!(par.nodes == serial.nodes, "parallel build differs on {what}");
    let cam = frame.header.camera;
    for (label, c) in
        [("frame camera", cam), ("10°", cam.orbit(10.0, 0.0)), ("30° up, closer", cam.orbit(0.0, 30.0).dolly(0.7))]
    {
        let hits = assert_packet_equals_scalar(&par, &c, &format!("{what}, {label}"));
        assert!(hits > 10_000, "{label}: {hits}");
        let (mut t, mut s) = (Vec::new(), Vec::new());
        PacketTracer::new(2).trace_ids(&par, &c, &mut t);
        SphereSplat::new(2).splat_ids(&par, &c, &mut s);
        let same = t.iter().zip(&s).filter(|(a, b)| a == b).count() as f64 / t.len() as f64;
        eprintln!("{label}: splat == trace on {:.4} % of the pixels", same * 100.0);
        assert!(same >= 0.999, "{label}: splat == trace on {:.4} %", same * 100.0);
        assert!(t.iter().any(|&i| i != NO_HIT));
    }
}
