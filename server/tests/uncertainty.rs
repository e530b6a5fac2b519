//! The uncertainty radius model: opaque surfaces keep the footprint
//! radius, fuzzy rays get a larger one within the cap, nothing overflows or turns NaN, and the
//! packet marcher's frames equal the scalar marcher's.

mod common;

use common::{for_each_lane_kind, widest_lanes};
use std::path::Path;
use volwarp_core::sample::{radius_code, RADIUS_MAX};
use volwarp_core::wire::{CameraRequest, Frame};
use volwarp_core::{Heuristic, Vec3};
use volwarp_server::radius::{uncertainty_factor, FrameRadius, RadiusModel, SpreadMeasure, UncertaintyParams};
use volwarp_server::transfer_function::{TransferFunction, LUT_SIZE};
use volwarp_server::{Dataset, MarchKernel, MarchOptions, Marcher, Volume};

/// Spread only (no opacity term), gain 0.1, cap 2: the base the tests vary.
const SPREAD: UncertaintyParams =
    UncertaintyParams { measure: SpreadMeasure::Sigma, gain: 0.1, opacity_gain: 0.0, max: 2.0 };

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(name)
}

fn marcher(ds: &Dataset, radius: RadiusModel, uncertainty: UncertaintyParams, kernel: MarchKernel) -> Marcher {
    Marcher::with_options(ds.volume.clone(), &ds.tf, MarchOptions { radius, uncertainty, kernel, ..Default::default() })
}

fn frame(m: &Marcher, heuristic: Heuristic, size: u32) -> (Frame, CameraRequest) {
    let req = CameraRequest {
        seq: 1,
        camera: m.default_camera(size, size).orbit(20.0, 10.0),
        heuristic,
        radius_scale: 1.0,
        layers: 0,
    };
    (m.render_frame(&req).0, req)
}

/// A 24³ volume: value 1 in the block `6..18` on every axis, 0 elsewhere.
fn block() -> Volume {
    let n = 24u32;
    let values = (0..n * n * n)
        .map(|i| {
            let (x, y, z) = (i % n, i / n % n, i / (n * n));
            let inside = |c: u32| (6..18).contains(&c);
            if inside(x) && inside(y) && inside(z) {
                1.0
            } else {
                0.0
            }
        })
        .collect();
    Volume::from_values("block", [n, n, n], Vec3::ONE, values).unwrap()
}

/// Every visible table entry fully opaque: a ray stops at its first visible sample.
fn opaque_tf() -> TransferFunction {
    let step = 1.0 / (LUT_SIZE - 1) as f32;
    TransferFunction::from_points("opaque", &[(0.0, [1.0, 0.5, 0.2])], &[(0.0, 0.0), (step, 1.0), (1.0, 1.0)])
}

/// Every visible entry faint: rays through the block collect color all along it.
fn fuzzy_tf() -> TransferFunction {
    TransferFunction::from_points(
        "fuzzy",
        &[(0.0, [0.2, 0.5, 1.0])],
        &[(0.0, 0.0), (0.5, 0.0), (0.9, 0.03), (1.0, 0.03)],
    )
}

/// The footprint frame's radius of each sample, decoded, beside the uncertainty frame's.
fn radii(ds: &Dataset, params: UncertaintyParams, h: Heuristic) -> Vec<(f32, f32, f32, f32)> {
    let fp = marcher(ds, RadiusModel::Footprint, params, MarchKernel::Packet);
    let un = marcher(ds, RadiusModel::Uncertainty, params, MarchKernel::Packet);
    let (a, _) = frame(&fp, h, 48);
    let (b, _) = frame(&un, h, 48);
    assert_eq!(a.samples.len(), b.samples.len(), "the radius changes no sample's presence");
    assert!(!a.samples.is_empty());
    let (da, db) = (a.header.dequantizer(), b.header.dequantizer());
    a.samples
        .iter()
        .zip(&b.samples)
        .map(|(&sa, &sb)| {
            assert_eq!(da.center(sa), db.center(sb), "positions do not depend on the radius");
            (da.radius(sa), db.radius(sb), a.header.radius_unit, b.header.radius_unit)
        })
        .collect()
}

#[test]
fn opaque_surfaces_keep_the_footprint_radius() {
    let _lanes = widest_lanes();
    let ds = Dataset::new(block(), opaque_tf());
    let m = marcher(&ds, RadiusModel::Uncertainty, UncertaintyParams::DEFAULT, MarchKernel::Scalar);
    // The ray through the centre: one opaque sample, no spread, factor exactly 1.
    let cam = m.default_camera(9, 9);
    let basis = cam.ray_basis();
    let (c, t, u) = m.pixel_spread(basis.origin(), basis.dir(4, 4), Heuristic::Threshold);
    assert!(c[3] >= 0.99 && t.is_some());
    assert_eq!((u.sigma, u.span, u.alpha), (0.0, 0.0, 1.0));
    assert_eq!(uncertainty_factor(&u, 0.01, &UncertaintyParams::DEFAULT), 1.0);
    // Every sample of a frame: the footprint radius within half a code step of each frame.
    for p in [UncertaintyParams::DEFAULT, SPREAD] {
        for h in [Heuristic::Threshold, Heuristic::RelThreshold] {
            for (fp, un, ua, ub) in radii(&ds, p, h) {
                assert!((fp - un).abs() <= 0.5 * (ua + ub) * 1.001, "{h}: {un} against the footprint {fp}");
            }
        }
    }
}

#[test]
fn fuzzy_rays_get_larger_spheres_within_the_cap() {
    let _lanes = widest_lanes();
    let ds = Dataset::new(block(), fuzzy_tf());
    let params = UncertaintyParams { gain: 0.2, max: 3.0, ..SPREAD };
    let m = marcher(&ds, RadiusModel::Uncertainty, params, MarchKernel::Scalar);
    let cam = m.default_camera(9, 9);
    let basis = cam.ray_basis();
    let (c, _, u) = m.pixel_spread(basis.origin(), basis.dir(4, 4), Heuristic::Threshold);
    assert!(c[3] > 0.0 && c[3] < 0.99, "the ray stays semi-transparent: {}", c[3]);
    // Color spread evenly through a 12-voxel block: sigma ≈ 12 / √12 ≈ 3.5, span ≈ 12.
    assert!(u.sigma > 2.5 && u.sigma < 4.0, "{u:?}");
    assert!(u.span > 10.0 && u.span <= 12.0 * 3f32.sqrt(), "{u:?}");
    let rs = radii(&ds, params, Heuristic::Threshold);
    let grown = rs.iter().filter(|(fp, un, ..)| *un > 1.5 * fp).count();
    // Rays through the block's middle grow; those clipping its edges see little spread.
    assert!(grown * 4 > rs.len(), "a quarter of the samples grow by half: {grown} of {}", rs.len());
    for (fp, un, ua, ub) in rs {
        let tol = 0.5 * (ua + ub) * 1.001;
        assert!(un >= fp - tol && un <= params.max * fp + tol, "{un} against the footprint {fp}");
    }
    // The span measure and an opacity term grow the radius too; a zero gain does not.
    let span = UncertaintyParams { measure: SpreadMeasure::Span, ..params };
    assert!(uncertainty_factor(&u, 1.0, &span) > uncertainty_factor(&u, 1.0, &params));
    let faint = UncertaintyParams { gain: 0.0, opacity_gain: 1.0, ..params };
    assert!(uncertainty_factor(&u, 1.0, &faint) > 1.0);
    assert_eq!(uncertainty_factor(&u, 1.0, &UncertaintyParams { gain: 0.0, ..params }), 1.0);
}

#[test]
fn extreme_inputs_give_valid_codes() {
    let _lanes = widest_lanes();
    // Empty rays have no sample; huge gains and caps clamp to the code range, never NaN.
    let ds = Dataset::new(block(), fuzzy_tf());
    let wild = UncertaintyParams { gain: 1e30, opacity_gain: 1e30, max: 16.0, ..SPREAD };
    let m = marcher(&ds, RadiusModel::Uncertainty, wild, MarchKernel::Packet);
    let (f, req) = frame(&m, Heuristic::Midpoint, 40);
    assert!(!f.samples.is_empty());
    let deq = f.header.dequantizer();
    for &s in &f.samples {
        let c = radius_code(s);
        assert!((1..=RADIUS_MAX).contains(&c));
        assert!(deq.radius(s).is_finite());
    }
    let r = m.frame_radius(&req);
    assert!(r.unit().is_finite() && r.unit() > 0.0);
    // A camera looking away from the volume: an empty frame.
    let away = CameraRequest {
        camera: volwarp_core::Camera::look_at(Vec3::splat(-50.0), Vec3::splat(-100.0), Vec3::Y, 30.0, 16, 16),
        ..req
    };
    assert!(m.render_frame(&away).0.samples.is_empty());
    // Tiny and flat volumes, and a huge one in world units.
    for (dims, sp) in [([1, 1, 1], 1.0), ([3, 1, 2], 1.0), ([4, 4, 4], 1e6)] {
        let n = (dims[0] * dims[1] * dims[2]) as usize;
        let values = (0..n).map(|i| (i % 3) as f32).collect();
        let vol = Volume::from_values("tiny", dims, Vec3::splat(sp), values).unwrap();
        let ds = Dataset::new(vol, fuzzy_tf());
        for kernel in [MarchKernel::Packet, MarchKernel::Scalar] {
            let m = marcher(&ds, RadiusModel::Uncertainty, wild, kernel);
            let (f, _) = frame(&m, Heuristic::Threshold, 16);
            let deq = f.header.dequantizer();
            assert!(f.samples.iter().all(|&s| deq.radius(s).is_finite() && radius_code(s) <= RADIUS_MAX));
        }
    }
    // The factor itself.
    let u = volwarp_server::radius::Uncertainty { sigma: f32::NAN, span: 1.0, alpha: 1.0 };
    assert_eq!(uncertainty_factor(&u, 1.0, &SPREAD), 1.0);
    let u = volwarp_server::radius::Uncertainty { sigma: 1.0, span: 1.0, alpha: f32::NAN };
    assert_eq!(uncertainty_factor(&u, 1.0, &UncertaintyParams::DEFAULT), 1.0);
    let p = UncertaintyParams { gain: 0.1, max: 3.0, ..SPREAD };
    let u = volwarp_server::radius::Uncertainty { sigma: 1.0, span: 1.0, alpha: 1.0 };
    assert_eq!(uncertainty_factor(&u, 0.0, &p), 3.0);
    let inf = volwarp_server::radius::Uncertainty { sigma: f32::INFINITY, span: 1.0, alpha: 1.0 };
    assert_eq!(uncertainty_factor(&inf, 1.0, &p), 3.0);
    assert_eq!(uncertainty_factor(&inf, 0.0, &UncertaintyParams { gain: 0.0, ..p }), 1.0);
}

#[test]
fn uncertainty_frames_of_the_packet_marcher_equal_the_scalar_marchers() {
    let mut sets = vec![
        Dataset::load(data("data/neghip_64x64x64_uint8.raw"), None).unwrap(),
        Dataset::load(data("data/ct_head_quarter.nhdr"), None).unwrap(),
        Dataset::new(block(), fuzzy_tf()),
    ];
    sets.extend(volwarp_server::testdata::shared_dataset("iron_protein_68x68x68_uint8.raw"));
    let params = UncertaintyParams { gain: 0.1, opacity_gain: 0.5, max: 4.0, ..SPREAD };
    for ds in &sets {
        for p in [params, UncertaintyParams { measure: SpreadMeasure::Span, ..params }] {
            let fast = marcher(ds, RadiusModel::Uncertainty, p, MarchKernel::Packet);
            let slow = marcher(ds, RadiusModel::Uncertainty, p, MarchKernel::Scalar);
            let want: Vec<Frame> = Heuristic::ALL.iter().map(|&h| frame(&slow, h, 45).0).collect();
            for_each_lane_kind(|kind| {
                for (&h, b) in Heuristic::ALL.iter().zip(&want) {
                    let (a, req) = frame(&fast, h, 45);
                    assert!(!a.samples.is_empty(), "{} {h}", ds.name);
                    assert_eq!(a.samples, b.samples, "{kind:?} {} {h}", ds.name);
                    assert_eq!(a.colors, b.colors, "{kind:?} {} {h}", ds.name);
                    assert_eq!(a.header.radius_unit, b.header.radius_unit);
                    // Quantizing the marched buffer (re-marching each ray for its spread) gives
                    // the same samples.
                    let pb = fast.march(&req.camera, h);
                    let (mut all, unit) = fast.quantize(&req, &pb);
                    let mut cols = pb.color.clone();
                    let k = volwarp_core::compaction::compact_in_place(&mut all, &mut cols);
                    assert_eq!(a.samples, all[..k], "{kind:?} {} {h}: quantize", ds.name);
                    assert_eq!(a.header.radius_unit, unit);
                }
            });
        }
    }
}

#[test]
fn the_frame_unit_makes_room_for_the_cap() {
    let ds = Dataset::load(data("data/neghip_64x64x64_uint8.raw"), None).unwrap();
    let m = Marcher::from_dataset(&ds);
    let cam = m.default_camera(64, 64);
    let b = ds.volume.bounds();
    let p = UncertaintyParams { max: 3.0, ..SPREAD };
    let fp = FrameRadius::with_params(RadiusModel::Footprint, p, 1.0, &cam, &b, 0.1, 512.0);
    let un = FrameRadius::with_params(RadiusModel::Uncertainty, p, 1.0, &cam, &b, 0.1, 512.0);
    assert!((un.unit() - 3.0 * fp.unit()).abs() <= 1e-6 * fp.unit());
    assert!(un.uses_spread() && !fp.uses_spread());
    assert_eq!(un.per_depth(), fp.per_depth());
}
