//! The ray marcher against volumes whose color and depth are known in closed form, and its
//! fast paths (empty-space skipping, parallel compaction) against the plain ones.

use std::sync::Arc;
use volwarp_core::sample::{over_background, pack_color_f32};
use volwarp_core::wire::CameraRequest;
use volwarp_core::{Camera, Heuristic, Vec3, BACKGROUND};
use volwarp_server::transfer_function::TransferFunction;
use volwarp_server::{Dataset, MarchOptions, Marcher, RadiusModel, Volume};

mod common;

/// A 16³ volume of one value, unit spacing: the box [0, 16]³.
fn constant_box(alpha: f32) -> Marcher {
    let vol = Volume::from_values("box", [16; 3], Vec3::ONE, vec![7.0; 16 * 16 * 16]).unwrap();
    let tf = TransferFunction::from_points("c", &[(0.0, [1.0, 0.5, 0.25])], &[(0.0, alpha)]);
    Marcher::new(Arc::new(vol), &tf)
}

/// Looks down -z at the box centre; the centre pixel (16, 16) of 33×33 runs exactly along -z.
fn box_camera() -> Camera {
    Camera::look_at(Vec3::new(8.0, 8.0, 40.0), Vec3::new(8.0, 8.0, 0.0), Vec3::Y, 60.0, 33, 33)
}

#[test]
fn constant_box_color_and_every_heuristic_in_closed_form() {
    let a = 0.1f64;
    let m = constant_box(a as f32);
    let cam = box_camera();
    // Along the centre ray: enters at t = 24, leaves at t = 40; step 0.5 → 32 samples at
    // t_k = 24 + (k + ½)/2, each of opacity 1 − 0.9^½; accumulated after k: 1 − 0.9^((k+1)/2).
    let dst = |k: usize| 1.0 - (1.0 - a).powf((k + 1) as f64 * 0.5);
    let t_of = |k: usize| 24.0 + (k as f64 + 0.5) * 0.5;
    let final_a = dst(31);
    let first_k = |pred: &dyn Fn(usize) -> bool| (0..32).find(|&k| pred(k));
    let expect = |h: Heuristic| -> f64 {
        match h {
            Heuristic::Entrance | Heuristic::Peak | Heuristic::Gradient => t_of(0),
            Heuristic::Exit => t_of(31),
            Heuristic::Midpoint => (t_of(0) + t_of(31)) * 0.5,
            Heuristic::Threshold => first_k(&|k| dst(k) > 0.8).map_or(40.0, t_of),
            Heuristic::RelThreshold => first_k(&|k| dst(k) > 0.8 * final_a).map_or(40.0, t_of),
            Heuristic::EnExMean => 40.0, // all samples equal: none exceeds the mean → box exit
        }
    };
    for h in Heuristic::ALL {
        let pb = m.march(&cam, h);
        let i = 16 * 33 + 16;
        assert!((pb.t[i] as f64 - expect(h)).abs() < 1e-3, "{h}: {} vs {}", pb.t[i], expect(h));
        let want = pack_color_f32([final_a as f32, 0.5 * final_a as f32, 0.25 * final_a as f32, final_a as f32]);
        let got = pb.color[i].to_le_bytes();
        for (g, w) in got.iter().zip(want.to_le_bytes()) {
            assert!((*g as i32 - w as i32).abs() <= 1, "{h}: color {got:?} vs {:?}", want.to_le_bytes());
        }
        // The corners of the image miss the box.
        assert_eq!(pb.t[0], f32::INFINITY);
        assert_eq!(pb.color[0], 0);
    }
}

#[test]
fn early_termination_stops_an_opaque_ray() {
    let m = constant_box(0.9);
    let pb = m.march(&box_camera(), Heuristic::Exit);
    let i = 16 * 33 + 16;
    // Each step has α' = 1 − 0.1^½ ≈ 0.684; after 4 steps 1 − 0.1² = 0.99 → stop at k = 3.
    assert!((pb.t[i] - (24.0 + 3.5 * 0.5)).abs() < 1e-4, "{}", pb.t[i]);
    assert_eq!(pb.color[i] >> 24, 252, "alpha 0.99");
}

/// A sphere of radius 16 around the centre of a 48³ volume, with a one-voxel linear edge,
/// classified opaque white above 0.5: a surface at exactly |p − c| = 16.
fn sphere() -> (Marcher, Vec3, f32) {
    let c = Vec3::splat(24.0);
    let r = 16.0;
    let vol = Volume::from_fn("sphere", [48; 3], Vec3::ONE, |p| (r - (p - c).length() + 0.5).clamp(0.0, 1.0)).unwrap();
    let tf = TransferFunction::from_points("s", &[(0.0, [1.0, 1.0, 1.0])], &[(0.499, 0.0), (0.5, 1.0)]);
    (Marcher::new(Arc::new(vol), &tf), c, r)
}

#[test]
fn sphere_depth_matches_the_analytic_surface() {
    let (m, c, r) = sphere();
    let cam = Camera::look_at(Vec3::new(30.0, 20.0, 100.0), c, Vec3::Y, 30.0, 48, 40);
    let basis = cam.ray_basis();
    let (mut hits, mut misses) = (0, 0);
    for h in [Heuristic::Entrance, Heuristic::Threshold, Heuristic::Peak, Heuristic::Gradient] {
        let pb = m.march(&cam, h);
        let img = m.render_image(&cam);
        for y in 0..cam.height {
            for x in 0..cam.width {
                let i = (y * cam.width + x) as usize;
                let d = basis.dir(x, y);
                let oc = cam.eye - c;
                let b = oc.dot(d);
                let miss_dist = (oc - d * b).length();
                if miss_dist < r - 1.5 {
                    let t_hit = -b - (b * b - (oc.length_squared() - r * r)).sqrt();
                    // Trilinear edge and a half-voxel step: within one voxel of the surface.
                    assert!((pb.t[i] - t_hit).abs() < 1.0, "{h} ({x},{y}): {} vs {t_hit}", pb.t[i]);
                    assert!(pb.color[i] >> 24 >= 252, "opaque");
                    assert_eq!(img.pixels[i], over_background(pb.color[i], BACKGROUND));
                    hits += 1;
                } else if miss_dist > r + 1.5 {
                    assert_eq!(pb.t[i], f32::INFINITY, "{h} ({x},{y}) should miss");
                    assert_eq!(img.pixels[i], BACKGROUND);
                    misses += 1;
                }
            }
        }
    }
    assert!(hits > 1000 && misses > 1000, "{hits} {misses}");
}

#[test]
fn empty_space_skipping_changes_nothing() {
    let ds = Dataset::default_bundled();
    let fast = Marcher::from_dataset(&ds);
    let slow = fast.with_transfer_function(&ds.tf, MarchOptions { skip_empty: false, ..MarchOptions::default() });
    for (yaw, pitch, h) in
        [(0.0, 0.0, Heuristic::Threshold), (40.0, 25.0, Heuristic::Exit), (200.0, -30.0, Heuristic::RelThreshold)]
    {
        let cam = fast.default_camera(72, 64).orbit(yaw, pitch);
        let a = fast.march(&cam, h);
        let b = slow.march(&cam, h);
        assert!(a.nonempty() > 500, "{}", a.nonempty());
        assert_eq!(a, b, "yaw {yaw} pitch {pitch} {h}");
    }
    // Also with a transfer function where only a narrow band of values is visible.
    let tf = TransferFunction::from_points("band", &[(0.0, [1.0, 1.0, 1.0])], &[(0.3, 0.0), (0.32, 0.5), (0.34, 0.0)]);
    let fast = fast.with_transfer_function(&tf, MarchOptions::default());
    let slow = fast.with_transfer_function(&tf, MarchOptions { skip_empty: false, ..MarchOptions::default() });
    let cam = fast.default_camera(64, 64).orbit(15.0, 10.0);
    assert_eq!(fast.march(&cam, Heuristic::Entrance), slow.march(&cam, Heuristic::Entrance));
}

#[test]
fn frame_samples_sit_on_their_rays() {
    let ds = Dataset::default_bundled();
    let base = Marcher::from_dataset(&ds);
    let cam = base.default_camera(64, 48).orbit(30.0, 10.0);
    for (h, scale, model) in [
        (Heuristic::Threshold, 1.0, RadiusModel::Voxel),
        (Heuristic::Midpoint, 2.5, RadiusModel::Voxel),
        (Heuristic::Threshold, 1.0, RadiusModel::Footprint),
        (Heuristic::Peak, 0.5, RadiusModel::Footprint),
        (Heuristic::Threshold, 1.0, RadiusModel::Uncertainty),
        (Heuristic::RelThreshold, 0.5, RadiusModel::Uncertainty),
    ] {
        let m = base.with_transfer_function(&ds.tf, MarchOptions { radius: model, ..MarchOptions::default() });
        let req = CameraRequest { seq: 3, camera: cam, heuristic: h, radius_scale: scale, layers: 0 };
        let (frame, stats) = m.render_frame(&req);
        let pb = m.march(&cam, h);
        // The frame equals quantizing every pixel, then compacting serially.
        let (mut all, unit) = m.quantize(&req, &pb);
        let mut cols = pb.color.clone();
        let k = volwarp_core::compaction::compact_in_place(&mut all, &mut cols);
        assert_eq!(frame.samples, all[..k]);
        assert_eq!(frame.colors, cols[..k]);
        assert_eq!(frame.header.radius_unit, unit);
        assert_eq!(frame.header.count as usize, pb.nonempty());
        assert_eq!(frame.samples.len(), pb.nonempty());
        assert_eq!(stats.samples, pb.nonempty());
        assert_eq!(frame.header.camera, cam);
        assert_eq!(frame.header.seq, 3);
        assert_eq!(frame.header.bounds, ds.volume.bounds());
        let deq = frame.header.dequantizer();
        let quantum = ds.volume.extent().max_element() / 262143.0;
        let basis = cam.ray_basis();
        let mut j = 0;
        for (i, &t) in pb.t.iter().enumerate() {
            if !t.is_finite() {
                continue;
            }
            let (x, y) = (i as u32 % cam.width, i as u32 / cam.width);
            let p = cam.eye + basis.dir(x, y) * t;
            assert!((deq.center(frame.samples[j]) - p).abs().max_element() <= quantum, "{h} pixel {i}");
            let r = deq.radius(frame.samples[j]);
            match model {
                RadiusModel::Voxel => {
                    let want_r = 0.5 * ds.volume.voxel_diagonal() * scale;
                    assert!((r - want_r).abs() < want_r * 1e-3);
                }
                RadiusModel::Footprint | RadiusModel::Uncertainty => {
                    // A pixel diagonal at the sample's depth: √2 × the distance between this
                    // pixel's and its right neighbour's rays at the sample's view depth (the
                    // uncertainty model: that, times a factor in 1..=max).
                    let (_, _, w) = cam.basis();
                    let z = (p - cam.eye).dot(w);
                    let (d0, d1) = (basis.dir(x, y), basis.dir(x + 1, y));
                    let pitch = (d1 * (z / d1.dot(w)) - d0 * (z / d0.dot(w))).length();
                    let want_r = std::f32::consts::SQRT_2 * pitch * scale;
                    let tol = 0.5 * frame.header.radius_unit + want_r * 1e-3;
                    let max = if model == RadiusModel::Uncertainty { m.options().uncertainty.max } else { 1.0 };
                    assert!(r >= want_r - tol && r <= max * want_r + tol, "{r} vs {want_r} (×1..={max})");
                }
            }
            assert_eq!(frame.colors[j], pb.color[i]);
            j += 1;
        }
    }
}

#[test]
fn ground_truth_equals_marched_colors_over_the_background() {
    let ds = Dataset::marschner_lobb(32);
    let m = Marcher::from_dataset(&ds);
    let cam = m.default_camera(40, 30).orbit(20.0, 20.0);
    let img = m.render_image(&cam);
    let pb = m.march(&cam, Heuristic::Gradient);
    assert!(pb.nonempty() > 100, "{}", pb.nonempty());
    for (p, c) in img.pixels.iter().zip(&pb.color) {
        assert_eq!(*p, over_background(*c, BACKGROUND));
    }
}

/// The scalar marcher's samples read through the bricks equal a flat reference (the stored
/// values in x-fastest order, clamped corners, blended then normalized) bit for bit on every
/// bundled and shared dataset (the packet marcher equals the scalar one: `packet_march.rs`).
#[test]
fn bricked_samples_equal_the_flat_reference_on_every_dataset() {
    let sets = common::datasets();
    let mut seed = 0x2545_f491u32;
    let mut r = move || {
        seed ^= seed << 13;
        seed ^= seed >> 17;
        seed ^= seed << 5;
        seed as f32 / u32::MAX as f32
    };
    for ds in &sets {
        let v = &ds.volume;
        let [nx, ny, nz] = v.dims();
        let mut flat = Vec::with_capacity((nx * ny * nz) as usize);
        for z in 0..nz {
            for y in 0..ny {
                flat.extend((0..nx).map(|x| v.voxels().get(x, y, z)));
            }
        }
        for _ in 0..50_000 {
            let g = Vec3::new(r() * (nx + 2) as f32 - 1.5, r() * (ny + 2) as f32 - 1.5, r() * (nz + 2) as f32 - 1.5);
            let want = volwarp_server::volume::flat_sample(&flat, v.dims(), v.normalization(), g);
            assert_eq!(v.sample_grid(g).to_bits(), want.to_bits(), "{} at {g}", ds.name);
        }
    }
    assert!(sets.len() >= 2);
}

/// A coarser level of detail is as opaque as the volume: its transfer function's opacities
/// stay those of the volume's voxel thickness (not of its own, 2^level times thicker, voxel),
/// so the constant box's centre ray composites the same opacity at every level.
#[test]
fn levels_of_detail_keep_the_volumes_opacity() {
    let vol = Volume::from_values("box", [64; 3], Vec3::ONE, vec![7.0; 64 * 64 * 64]).unwrap();
    let tf = TransferFunction::from_points("c", &[(0.0, [1.0, 0.5, 0.25])], &[(0.0, 0.01)]);
    let m = Marcher::new(Arc::new(vol), &tf);
    let levels = m.levels(&tf).unwrap();
    assert_eq!(levels.len(), 3, "64, 32 and 16 voxels");
    let cam = Camera::look_at(Vec3::new(32.0, 32.0, 150.0), Vec3::new(32.0, 32.0, 0.0), Vec3::Y, 30.0, 33, 33);
    let alpha = |m: &Marcher| (m.march(&cam, Heuristic::Midpoint).color[16 * 33 + 16] >> 24) as f32 / 255.0;
    // 64 voxels of opacity 0.01 each: 1 - 0.99^64 = 0.474 at every level.
    let want = 1.0 - 0.99f32.powi(64);
    for (l, lm) in levels.iter().enumerate() {
        assert!((alpha(lm) - want).abs() <= 2.0 / 255.0, "level {l}: {} against {want}", alpha(lm));
    }
}
