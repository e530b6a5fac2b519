//! Synthetic frames for tests and benchmarks: a bumpy height-field surface sampled like a
//! server frame (one sample per pixel of a `size × size` depth image, quantized with core's
//! [`Quantizer`], empty pixels compacted away).

use volwarp_core::sample::{pack_color_f32, Bounds, Quantizer};
use volwarp_core::wire::{Frame, FrameHeader};
use volwarp_core::{Camera, Heuristic, Vec3};

/// A frame of about `size²` samples (a few corner pixels are empty) on the surface
/// `z = 0.15·sin(7x)·cos(5y) + 0.05·sin(23(x+y))` over `[-1, 1]²`, seen from `+z`, with a
/// radius of `radius_scale` × half the sample spacing diagonal and semi-transparent colors.
pub fn bumpy_surface(size: u32, radius_scale: f32, seq: u64) -> Frame {
    let size = size.max(2);
    let spacing = 2.0 / (size - 1) as f32;
    let height = |x: f32, y: f32| 0.15 * (7.0 * x).sin() * (5.0 * y).cos() + 0.05 * (23.0 * (x + y)).sin();
    let mut pts = Vec::with_capacity((size * size) as usize);
    for j in 0..size {
        for i in 0..size {
            let x = -1.0 + i as f32 * spacing;
            let y = 1.0 - j as f32 * spacing;
            // Leave the disc corners empty, like rays that miss the volume.
            if x * x + y * y > 1.9 {
                continue;
            }
            let z = height(x, y);
            let a = 0.35 + 0.65 * (0.5 + 0.5 * (3.0 * x * y).cos());
            let c = [(0.5 + 0.5 * x) * a, (0.5 + 0.5 * y) * a, (0.5 + 2.0 * z).clamp(0.0, 1.0) * a, a];
            pts.push((Vec3::new(x, y, z), pack_color_f32(c)));
        }
    }
    let bounds = Bounds::of_points(pts.iter().map(|p| p.0)).unwrap_or(Bounds::new(Vec3::ZERO, Vec3::ONE));
    let radius = radius_scale * spacing * std::f32::consts::SQRT_2 * 0.5;
    let radius_unit = radius / 64.0;
    let q = Quantizer::new(bounds, radius_unit);
    let samples: Vec<u64> = pts.iter().map(|p| q.pack(p.0, radius)).collect();
    let colors: Vec<u32> = pts.iter().map(|p| p.1).collect();
    let camera = Camera::look_at(Vec3::new(0.0, 0.0, 3.2), Vec3::ZERO, Vec3::Y, 45.0, size, size);
    Frame {
        header: FrameHeader {
            seq,
            camera,
            heuristic: Heuristic::Threshold,
            bounds,
            radius_unit,
            render_us: 0,
            level: 0,
            count: samples.len() as u32,
        },
        samples,
        colors,
        segments: Vec::new(),
    }
}
