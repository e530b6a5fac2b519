//! The packet (SIMD) marcher against the scalar marcher, its oracle.
//!
//! Tolerance: a per-channel difference of 1/255 at most and the same depth on at
//! least 99.9 % of the pixels; the packet marcher performs the scalar marcher's operations in
//! the same order and rounding, so these tests ask for more: identical colors and depths on
//! every pixel (they report the first difference, and the per-channel maximum and the share of
//! equal depths, should that ever change).

use std::path::Path;
use volwarp_core::wire::CameraRequest;
use volwarp_core::{Camera, Heuristic, Vec3};
use volwarp_server::empty_space::MinMaxGrid;
use volwarp_server::transfer_function::TransferFunction;
use volwarp_server::{Dataset, MarchKernel, MarchOptions, Marcher, PixelBuffer, Volume};

mod common;

use common::{datasets, for_each_lane_kind};

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(name)
}

fn pair(ds: &Dataset, opts: MarchOptions) -> (Marcher, Marcher) {
    let packet = Marcher::with_options(ds.volume.clone(), &ds.tf, MarchOptions { kernel: MarchKernel::Packet, ..opts });
    let scalar = packet.with_transfer_function(&ds.tf, MarchOptions { kernel: MarchKernel::Scalar, ..opts });
    (packet, scalar)
}

/// Asserts two pixel buffers are equal within the allowed tolerance and, beyond it, identical.
fn assert_same(what: &str, fast: &PixelBuffer, slow: &PixelBuffer) {
    assert_eq!((fast.width, fast.height), (slow.width, slow.height), "{what}");
    let n = slow.t.len();
    let max_channel = fast
        .color
        .iter()
        .zip(&slow.color)
        .flat_map(|(a, b)| a.to_le_bytes().into_iter().zip(b.to_le_bytes()).map(|(x, y)| x.abs_diff(y)))
        .max()
        .unwrap_or(0);
    let same_depth = fast.t.iter().zip(&slow.t).filter(|(a, b)| a.to_bits() == b.to_bits()).count();
    assert!(max_channel <= 1, "{what}: a channel differs by {max_channel}");
    assert!(same_depth as f64 >= 0.999 * n as f64, "{what}: {same_depth} of {n} depths equal");
    if let Some(i) = (0..n).find(|&i| fast.color[i] != slow.color[i] || fast.t[i].to_bits() != slow.t[i].to_bits()) {
        panic!(
            "{what}: pixel {i} ({}, {}): packet {:08x} t {} vs scalar {:08x} t {}",
            i % fast.width as usize,
            i / fast.width as usize,
            fast.color[i],
            fast.t[i],
            slow.color[i],
            slow.t[i]
        );
    }
}

/// Views of `m`'s volume: framed, orbited, close up, an odd viewport, inside looking along
/// and across, and looking away from the volume.
fn cameras(m: &Marcher) -> Vec<(&'static str, Camera)> {
    let b = m.volume().bounds();
    let (lo, hi) = (b.min(), b.max());
    let c = (lo + hi) * 0.5;
    let ext = hi - lo;
    vec![
        ("framed", m.default_camera(48, 40)),
        ("orbit", m.default_camera(45, 31).orbit(37.0, -21.0)),
        ("close", m.default_camera(33, 29).orbit(-70.0, 35.0).dolly(0.45)),
        ("odd 1x7", m.default_camera(1, 7).orbit(10.0, 5.0)),
        ("odd 13x1", m.default_camera(13, 1)),
        ("inside", Camera::look_at(c + ext * 0.1, c + Vec3::new(0.0, ext.y, 0.0), Vec3::Z, 70.0, 39, 27)),
        ("inside diag", Camera::look_at(lo + ext * 0.3, hi, Vec3::Z, 90.0, 31, 31)),
        (
            "away",
            Camera::look_at(
                c + Vec3::new(0.0, 3.0 * ext.y, 0.0),
                c + Vec3::new(0.0, 9.0 * ext.y, 0.0),
                Vec3::Z,
                30.0,
                21,
                17,
            ),
        ),
        (
            "grazing",
            Camera::look_at(Vec3::new(lo.x - 5.0, hi.y, c.z), Vec3::new(hi.x + 5.0, hi.y, c.z), Vec3::Z, 20.0, 23, 19),
        ),
    ]
}

#[test]
fn packet_marcher_equals_scalar_on_every_dataset_heuristic_and_view() {
    let datasets = datasets();
    let pairs: Vec<(Marcher, Marcher)> = datasets.iter().map(|ds| pair(ds, MarchOptions::default())).collect();
    let truth: Vec<Vec<_>> = pairs
        .iter()
        .map(|(fast, slow)| {
            cameras(fast)
                .into_iter()
                .map(|(_, cam)| {
                    let depths: Vec<PixelBuffer> = Heuristic::ALL.iter().map(|&h| slow.march(&cam, h)).collect();
                    (depths, slow.render_image(&cam))
                })
                .collect()
        })
        .collect();
    for_each_lane_kind(|kind| {
        for ((ds, (fast, _)), truth) in datasets.iter().zip(&pairs).zip(&truth) {
            for ((view, cam), (depths, image)) in cameras(fast).into_iter().zip(truth) {
                for (&h, slow) in Heuristic::ALL.iter().zip(depths) {
                    let what = format!("{kind:?} {} {view} {h}", ds.name);
                    assert_same(&what, &fast.march(&cam, h), slow);
                }
                let a = fast.render_image(&cam);
                assert!(a.pixels == image.pixels, "{kind:?} {} {view}: ground-truth images differ", ds.name);
            }
        }
    });
}

#[test]
fn packet_marcher_equals_scalar_without_skipping_or_early_termination_and_at_other_steps() {
    let ds = Dataset::load(data("data/ct_head_quarter.nhdr"), None).unwrap();
    for opts in [
        MarchOptions { skip_empty: false, ..MarchOptions::default() },
        MarchOptions { early_termination: 1.0, ..MarchOptions::default() },
        MarchOptions { step_voxels: 1.7, ..MarchOptions::default() },
        MarchOptions { step_voxels: 0.2, early_termination: 0.5, ..MarchOptions::default() },
    ] {
        let (fast, slow) = pair(&ds, opts);
        for_each_lane_kind(|kind| {
            for (view, cam) in cameras(&fast).into_iter().take(4) {
                for h in [Heuristic::Threshold, Heuristic::Exit, Heuristic::RelThreshold] {
                    assert_same(&format!("{kind:?} {opts:?} {view} {h}"), &fast.march(&cam, h), &slow.march(&cam, h));
                }
            }
        });
    }
}

#[test]
fn skipping_changes_no_packet_image() {
    for ds in datasets() {
        let (fast, _) = pair(&ds, MarchOptions::default());
        let plain = fast.with_transfer_function(&ds.tf, MarchOptions { skip_empty: false, ..MarchOptions::default() });
        for_each_lane_kind(|kind| {
            for (view, cam) in cameras(&fast).into_iter().take(6) {
                for h in [Heuristic::Threshold, Heuristic::Entrance, Heuristic::EnExMean] {
                    let what = format!("{kind:?} {} {view} {h} skip", ds.name);
                    assert_same(&what, &fast.march(&cam, h), &plain.march(&cam, h));
                }
            }
        });
    }
}

#[test]
fn packet_frames_equal_scalar_frames() {
    let ds = Dataset::load(data("data/neghip_64x64x64_uint8.raw"), None).unwrap();
    let (fast, slow) = pair(&ds, MarchOptions::default());
    for_each_lane_kind(|kind| {
        for h in Heuristic::ALL {
            let req = CameraRequest {
                seq: 3,
                camera: fast.default_camera(57, 43).orbit(25.0, 15.0),
                heuristic: h,
                radius_scale: 1.5,
                layers: 0,
            };
            let (a, _) = fast.render_frame(&req);
            let (b, _) = slow.render_frame(&req);
            assert!(!a.samples.is_empty(), "{h}");
            assert_eq!(a.samples, b.samples, "{kind:?} {h}");
            assert_eq!(a.colors, b.colors, "{kind:?} {h}");
        }
    });
}

#[test]
fn packet_marcher_handles_tiny_and_flat_volumes() {
    let tf = TransferFunction::from_points("t", &[(0.0, [1.0, 0.2, 0.1])], &[(0.0, 0.0), (1.0, 0.7)]);
    for dims in [[1, 1, 1], [2, 1, 1], [1, 3, 1], [5, 1, 4], [3, 3, 2]] {
        let n = (dims[0] * dims[1] * dims[2]) as usize;
        let values: Vec<f32> = (0..n).map(|i| (i * 7 % 5) as f32).collect();
        let vol = Volume::from_values("flat", dims, Vec3::new(1.0, 0.5, 2.0), values).unwrap();
        let ds = Dataset::new(vol, tf.clone());
        let (fast, slow) = pair(&ds, MarchOptions::default());
        for_each_lane_kind(|kind| {
            for (view, cam) in cameras(&fast) {
                assert_same(
                    &format!("{kind:?} {dims:?} {view}"),
                    &fast.march(&cam, Heuristic::Midpoint),
                    &slow.march(&cam, Heuristic::Midpoint),
                );
            }
        });
    }
}

/// Odd and non-cubic dims (1, 2, 33 and 65 voxels per axis, across brick edges), anisotropic
/// spacing, each stored type (8-bit, 16-bit, f32) and bricks spread over several chunks (the
/// gathers of volumes beyond 2³¹ values): packet equals scalar on every lane kind.
#[test]
fn packet_marcher_equals_scalar_on_odd_dims_types_and_chunks() {
    let tf = TransferFunction::from_points(
        "t",
        &[(0.0, [1.0, 0.2, 0.1]), (0.5, [0.2, 0.9, 0.3]), (1.0, [0.1, 0.3, 1.0])],
        &[(0.0, 0.0), (0.3, 0.0), (0.6, 0.4), (1.0, 0.9)],
    );
    let cases: [([u32; 3], Vec3, u32); 5] = [
        ([33, 65, 2], Vec3::new(1.0, 0.5, 3.0), 0),
        ([65, 2, 33], Vec3::new(0.7, 1.0, 1.0), 1),
        ([1, 65, 33], Vec3::ONE, 2),
        ([2, 33, 65], Vec3::new(1.0, 1.0, 0.4), 0),
        ([40, 37, 70], Vec3::new(1.0, 1.2, 0.8), 1),
    ];
    for (dims, spacing, kind) in cases {
        let [nx, ny, nz] = dims;
        let vol = Volume::from_fn("odd", dims, spacing, |p| {
            let e = Vec3::new(nx as f32, ny as f32, nz as f32) * spacing;
            let q = p / e - 0.5;
            let v = (1.0 - 2.2 * q.length()).max(0.0) + 0.2 * (p.x * 0.9).sin() * (p.y * 0.7).cos();
            match kind {
                0 => (v * 200.0).round().clamp(0.0, 255.0),
                1 => (v * 3000.0).round().clamp(0.0, 4000.0),
                _ => v,
            }
        })
        .unwrap();
        assert_eq!(vol.voxels().type_name(), ["u8", "u16", "f32"][kind as usize]);
        let slab = (nx.div_ceil(32) * ny.div_ceil(32)) as usize * volwarp_server::volume::bricks::BRICK_VALUES;
        let chunked = vol.rechunked(slab + 4).unwrap();
        assert_eq!(chunked.voxels().layout().chunks(), nz.div_ceil(32) as usize);
        for (what, v) in [("one chunk", vol.clone()), ("chunked", chunked)] {
            let ds = Dataset::new(v, tf.clone());
            let (fast, slow) = pair(&ds, MarchOptions::default());
            let shading = Some(volwarp_server::marcher::Shading::DEFAULT);
            let (sfast, sslow) = pair(&ds, MarchOptions { shading, ..MarchOptions::default() });
            // Skipping bricks of 8 voxels, as volumes of more than 2^27 voxels get.
            let grid = std::sync::Arc::new(MinMaxGrid::with_brick(&ds.volume, 8));
            let big = Marcher::with_grid(ds.volume.clone(), grid, &tf, MarchOptions::default());
            for_each_lane_kind(|lanes| {
                let cam = &cameras(&fast)[0].1;
                assert_same(
                    &format!("{lanes:?} {dims:?} {what} 8-voxel skipping bricks"),
                    &big.march(cam, Heuristic::Threshold),
                    &slow.march(cam, Heuristic::Threshold),
                );
                for (view, cam) in cameras(&fast) {
                    assert_same(
                        &format!("{lanes:?} {dims:?} {what} {view} shaded"),
                        &sfast.march(&cam, Heuristic::Threshold),
                        &sslow.march(&cam, Heuristic::Threshold),
                    );
                    for h in [Heuristic::Threshold, Heuristic::Midpoint] {
                        assert_same(
                            &format!("{lanes:?} {dims:?} {what} {view} {h:?}"),
                            &fast.march(&cam, h),
                            &slow.march(&cam, h),
                        );
                    }
                }
            });
        }
    }
}

/// Shaded (gradient, Blinn–Phong) marching: packet equals scalar bit for bit on every lane kind,
/// on every dataset and view, across brick edges and chunks (the gradient's neighbours lie in
/// other bricks), and cropped and clipped (samples and neighbours clamped to the crop).
#[test]
fn shaded_packet_marcher_equals_scalar() {
    use volwarp_server::marcher::{Cut, Shading};
    let shaded = MarchOptions { shading: Some(Shading::DEFAULT), ..MarchOptions::default() };
    for ds in datasets() {
        let (fast, slow) = pair(&ds, shaded);
        let ext = ds.volume.extent();
        let [nx, ny, nz] = ds.volume.dims();
        let sp = ds.volume.spacing();
        // A crop of whole voxels plus a clip plane through the middle, tilted.
        let (i0, i1) = (
            Vec3::new((nx / 4) as f32, (ny / 5) as f32, 0.0),
            Vec3::new((nx - 3) as f32, (ny - 1) as f32, (nz / 2) as f32),
        );
        let plane = Some((ext * 0.5, Vec3::new(0.3, -0.8, 0.5).normalize()));
        let cut = Cut::new(i0 * sp, (i1 + 1.0) * sp, plane);
        let (cfast, cslow) = (fast.clone().with_cut(cut), slow.clone().with_cut(cut));
        let views: Vec<_> = cameras(&fast).into_iter().take(7).collect();
        let truth: Vec<_> = views
            .iter()
            .map(|(_, cam)| (slow.march(cam, Heuristic::Threshold), slow.render_image(cam), cslow.render_image(cam)))
            .collect();
        let unshaded = Marcher::with_options(ds.volume.clone(), &ds.tf, MarchOptions::default());
        assert!(
            views.iter().zip(&truth).any(|((_, cam), t)| unshaded.render_image(cam).pixels != t.1.pixels),
            "{}: shading changes nothing",
            ds.name
        );
        for_each_lane_kind(|kind| {
            for ((view, cam), (pb, image, cropped)) in views.iter().zip(&truth) {
                let what = format!("{kind:?} {} {view} shaded", ds.name);
                assert_same(&what, &fast.march(cam, Heuristic::Threshold), pb);
                assert!(fast.render_image(cam).pixels == image.pixels, "{what}: images differ");
                assert!(cfast.render_image(cam).pixels == cropped.pixels, "{what} cropped: images differ");
            }
        });
    }
}
