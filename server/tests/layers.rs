//! Layered samples from the marcher: the packet marcher's segments against the scalar
//! marcher's, K = 1 against today's frames, segments recomposited against the ground truth,
//! and the transparent and opaque extremes.

mod common;

use common::{for_each_lane_kind, widest_lanes};
use std::path::Path;
use std::sync::Arc;
use volwarp_core::sample::{over_background, pack_color_f32};
use volwarp_core::segments::{composite, validate};
use volwarp_core::wire::CameraRequest;
use volwarp_core::{Camera, Heuristic, Vec3, BACKGROUND};
use volwarp_server::transfer_function::TransferFunction;
use volwarp_server::{Dataset, MarchKernel, MarchOptions, Marcher, Volume};

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(name)
}

fn datasets() -> Vec<Dataset> {
    vec![
        Dataset::load(data("data/ct_head_quarter.nhdr"), None).unwrap(),
        Dataset::load(data("data/neghip_64x64x64_uint8.raw"), None).unwrap(),
        Dataset::marschner_lobb(41),
    ]
}

fn request(m: &Marcher, size: u32, yaw: f32) -> CameraRequest {
    CameraRequest {
        seq: 3,
        camera: m.default_camera(size, size).orbit(yaw, 10.0),
        heuristic: Heuristic::Threshold,
        radius_scale: 1.0,
        layers: 0,
    }
}

fn unpack(c: u32) -> [f32; 4] {
    c.to_le_bytes().map(|b| b as f32 / 255.0)
}

#[test]
fn packet_and_scalar_marchers_give_the_same_segments() {
    for ds in datasets() {
        let packet = Marcher::with_options(ds.volume.clone(), &ds.tf, MarchOptions::default());
        let scalar =
            packet.with_transfer_function(&ds.tf, MarchOptions { kernel: MarchKernel::Scalar, ..packet.options() });
        // Every lane kind: AVX-512's and AVX2's lane-wise segmenters (`SegmenterLanes`) and the
        // portable lanes' one `Segmenter` per lane.
        for_each_lane_kind(|kind| {
            for k in [1, 2, 4, 7, 16] {
                let req = request(&packet, 37, 20.0);
                let a = packet.march_layers(&req.camera, k);
                let b = scalar.march_layers(&req.camera, k);
                assert_eq!(a.count, b.count, "{kind:?} {} K={k}: segment counts", ds.name);
                assert_eq!(a.color, b.color, "{kind:?} {} K={k}: colors", ds.name);
                let same = a.t.iter().zip(&b.t).all(|(x, y)| x.to_bits() == y.to_bits());
                assert!(same, "{kind:?} {} K={k}: depths", ds.name);
                if k > 1 {
                    assert!(a.count.iter().any(|&c| c > 1), "{} K={k}: no pixel has two segments", ds.name);
                }
                assert!(a.count.iter().all(|&c| c as u32 <= k));
            }
        });
    }
}

#[test]
fn one_layer_is_todays_frame_bit_for_bit() {
    for ds in datasets() {
        let m = Marcher::from_dataset(&ds);
        for_each_lane_kind(|kind| {
            let req = request(&m, 48, 30.0);
            let (today, _) = m.render_frame(&req);
            let (mut one, _) = m.render_frame_layers(&req, 1);
            one.header.render_us = today.header.render_us;
            assert!(one == today, "{kind:?} {}: K = 1 differs from today's frame", ds.name);
            assert!(one.segments.is_empty());
        });
    }
}

#[test]
fn layered_frames_are_valid_and_recomposite_to_the_ground_truth() {
    let _lanes = widest_lanes();
    for ds in datasets() {
        let m = Marcher::from_dataset(&ds);
        let req = request(&m, 40, -15.0);
        let (frame, stats) = m.render_frame_layers(&req, 4);
        assert_eq!(stats.samples, frame.samples.len());
        validate(&frame.header, &frame.samples, &frame.colors, &frame.segments, frame.layers()).unwrap();
        assert!(frame.layers() > 1, "{}", ds.name);
        // Per pixel, the 8-bit segments composited front to back against the marcher's image.
        let truth = m.render_image(&req.camera);
        let lb = m.march_layers(&req.camera, 4);
        let mut worst = 0u8;
        for (i, &px) in truth.pixels.iter().enumerate() {
            let c = composite(lb.pixel(i).map(|(_, c)| unpack(c)));
            let shown = over_background(pack_color_f32(c), BACKGROUND);
            for (a, b) in shown.to_le_bytes().into_iter().zip(px.to_le_bytes()) {
                worst = worst.max(a.abs_diff(b));
            }
        }
        assert!(worst <= 3, "{}: a recomposited channel is {worst} steps off", ds.name);
        // As a client composites them (core's `composite_packed`), the packed colors give the
        // marcher's own pixel: the frame shown where the camera rests is the server's image.
        let inexact = inexact_pixels(&truth.pixels, &lb);
        assert!(inexact.is_empty(), "{}: {} of {} pixels not exact", ds.name, inexact.len(), truth.pixels.len());
    }
}

/// The pixels where a client compositing the packed segment colors (core's `composite_packed`)
/// over the background does not get the server's image.
fn inexact_pixels(truth: &[u32], lb: &volwarp_server::LayerBuffer) -> Vec<usize> {
    (0..truth.len())
        .filter(|&i| {
            let cols: Vec<u32> = lb.pixel(i).map(|(_, c)| c).collect();
            volwarp_core::segments::shown_pixel(&cols) != truth[i]
        })
        .collect()
}

#[test]
fn layered_frames_at_their_own_camera_are_the_servers_image() {
    // Every dataset the marcher tests run on (the iron protein's faint, fuzzy rays included),
    // two sizes and two views, K = 4 and 16: the frame a client shows where the camera rests is
    // the server's image, pixel for pixel (core's `segments::pack_colors`).
    let _lanes = widest_lanes();
    for ds in common::datasets() {
        let m = Marcher::from_dataset(&ds);
        for (size, yaw, k) in [(128u32, 0.0f32, 4u32), (128, 40.0, 16), (256, 0.0, 4)] {
            let req = request(&m, size, yaw);
            let truth = m.render_image(&req.camera);
            let lb = m.march_layers(&req.camera, k);
            let bad = inexact_pixels(&truth.pixels, &lb);
            assert!(
                bad.is_empty(),
                "{} {size}² yaw {yaw} K={k}: {} pixels not exact, first {:?}",
                ds.name,
                bad.len(),
                &bad[..bad.len().min(4)]
            );
        }
    }
}

#[test]
fn a_transparent_volume_has_no_segments_and_an_opaque_one_one_per_pixel() {
    let vol = Arc::new(Volume::from_values("box", [16; 3], Vec3::ONE, vec![7.0; 16 * 16 * 16]).unwrap());
    let cam = Camera::look_at(Vec3::new(8.0, 8.0, 40.0), Vec3::new(8.0, 8.0, 0.0), Vec3::Y, 20.0, 24, 24);
    let _lanes = widest_lanes();
    for kernel in [MarchKernel::Packet, MarchKernel::Scalar] {
        let opts = MarchOptions { kernel, ..MarchOptions::default() };
        let clear = TransferFunction::from_points("c", &[(0.0, [1.0, 0.5, 0.25])], &[(0.0, 0.0)]);
        let lb = Marcher::with_options(vol.clone(), &clear, opts).march_layers(&cam, 8);
        assert!(lb.count.iter().all(|&c| c == 0), "{kernel:?}: transparent volume made segments");
        let solid = TransferFunction::from_points("o", &[(0.0, [1.0, 0.5, 0.25])], &[(0.0, 1.0)]);
        let m = Marcher::with_options(vol.clone(), &solid, opts);
        let lb = m.march_layers(&cam, 8);
        let truth = m.march(&cam, Heuristic::Threshold);
        for (i, &c) in lb.count.iter().enumerate() {
            let hit = truth.t[i].is_finite();
            assert_eq!(c, u8::from(hit), "{kernel:?}: pixel {i}");
        }
        assert!(lb.count.contains(&1));
    }
}
