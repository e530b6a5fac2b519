//! Synthetic frames for tests and benchmarks: a depth-image-like cloud (a grid of points on a
//! bumpy surface, as a server would send for an opaque surface), random and clustered clouds,
//! and degenerate ones. Deterministic for a seed.

use volwarp_core::sample::{pack_color_f32, Bounds, Quantizer, RADIUS_MAX};
use volwarp_core::wire::{Frame, FrameHeader};
use volwarp_core::{Camera, Heuristic, Vec3};

/// A small deterministic generator (SplitMix64).
#[derive(Clone, Debug)]
pub struct SplitMix64(pub u64);

impl SplitMix64 {
    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)`.
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.next_f32()
    }
}

/// One point of a cloud: centre, radius and premultiplied RGBA in 0..=1.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Point {
    /// Centre.
    pub center: Vec3,
    /// Radius (> 0).
    pub radius: f32,
    /// Premultiplied RGBA.
    pub color: [f32; 4],
}

/// Packs `points` into a frame rendered for `camera`: bounds of the centres, radius unit
/// sized for the largest radius. Empty (radius ≤ 0) points are dropped, like the server's
/// compaction.
pub fn frame_from_points(points: &[Point], camera: Camera) -> Frame {
    let bounds = Bounds::of_points(points.iter().map(|p| p.center)).unwrap_or(Bounds::new(Vec3::ZERO, Vec3::ONE));
    let max_r = points.iter().map(|p| p.radius).fold(0.0f32, f32::max);
    let radius_unit = if max_r > 0.0 { max_r / (RADIUS_MAX as f32 * 0.5) } else { 1.0 };
    let q = Quantizer::new(bounds, radius_unit);
    let (mut samples, mut colors) = (Vec::with_capacity(points.len()), Vec::with_capacity(points.len()));
    for p in points.iter().filter(|p| p.radius > 0.0) {
        samples.push(q.pack(p.center, p.radius));
        colors.push(pack_color_f32(p.color));
    }
    let header = FrameHeader {
        seq: 0,
        camera,
        heuristic: Heuristic::Threshold,
        bounds,
        radius_unit,
        render_us: 0,
        level: 0,
        count: samples.len() as u32,
    };
    Frame { header, samples, colors, segments: Vec::new() }
}

fn color_of(rng: &mut SplitMix64, base: Vec3) -> [f32; 4] {
    let a = rng.range(0.5, 1.0);
    [base.x * a, base.y * a, base.z * a, a]
}

/// The height of the bumpy surface at `(x, y)`.
fn height(x: f32, y: f32) -> f32 {
    0.08 * (6.0 * x).sin() * (5.0 * y).cos() + 0.03 * (23.0 * x + 17.0 * y).sin()
}

/// A depth-image-like frame: a `size`×`size` grid over `[-1, 1]²` on the surface
/// `z = height(x, y)`, kept inside a wavy disc (≈ 59.5 % of the grid: 623 k points for
/// `size = 1024`, like the paper's frame), each point a sphere of `radius_scale` grid
/// spacings. The frame's camera looks at it from `+z` with a `size`² viewport that the grid
/// about fills.
pub fn depth_image_frame(size: u32, radius_scale: f32, seed: u64) -> Frame {
    let mut rng = SplitMix64(seed);
    let step = 2.0 / size as f32;
    let mut pts = Vec::new();
    for j in 0..size {
        for i in 0..size {
            let x = -1.0 + (i as f32 + 0.5) * step;
            let y = 1.0 - (j as f32 + 0.5) * step;
            let ang = y.atan2(x);
            let rmax = 0.87 + 0.03 * (8.0 * ang).sin();
            if x * x + y * y >= rmax * rmax {
                continue;
            }
            let z = height(x, y);
            let base = Vec3::new(0.5 + 0.5 * (3.0 * x).sin(), 0.5 + 5.0 * z, 0.6 + 0.4 * (4.0 * y).cos())
                .clamp(Vec3::ZERO, Vec3::ONE);
            pts.push(Point {
                center: Vec3::new(x, y, z),
                radius: radius_scale * step,
                color: color_of(&mut rng, base),
            });
        }
    }
    // The grid fills the viewport: one point per pixel, roughly, like a real depth image.
    let camera = Camera::look_at(Vec3::new(0.0, 0.0, 2.55), Vec3::ZERO, Vec3::Y, 45.0, size, size);
    frame_from_points(&pts, camera)
}

/// `n` spheres uniformly in the unit cube with radii in `[r/2, r]`, framed by a camera.
pub fn random_cloud(n: usize, r: f32, seed: u64, viewport: u32) -> Frame {
    let mut rng = SplitMix64(seed);
    let pts: Vec<Point> = (0..n)
        .map(|_| {
            let c = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
            let radius = rng.range(0.5 * r, r);
            Point { center: c, radius, color: color_of(&mut rng, c) }
        })
        .collect();
    frame_from_points(&pts, Camera::framing(Vec3::ZERO, Vec3::ONE, 20.0, 15.0, 45.0, viewport, viewport))
}

/// `n` spheres in `clusters` tight Gaussian-ish clusters (many near-coincident centres and
/// equal quantized positions), framed by a camera.
pub fn clustered_cloud(n: usize, clusters: usize, r: f32, seed: u64, viewport: u32) -> Frame {
    let mut rng = SplitMix64(seed);
    let centres: Vec<Vec3> =
        (0..clusters.max(1)).map(|_| Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32())).collect();
    let pts: Vec<Point> = (0..n)
        .map(|i| {
            let c0 = centres[i % centres.len()];
            let off = Vec3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
            let c = c0 + off * off.abs() * 0.02;
            Point { center: c, radius: rng.range(0.5 * r, r), color: color_of(&mut rng, c0) }
        })
        .collect();
    frame_from_points(&pts, Camera::framing(Vec3::ZERO, Vec3::ONE, -30.0, 20.0, 45.0, viewport, viewport))
}

/// `n` spheres all at one point with one radius (every sample ties).
pub fn one_point_cloud(n: usize, viewport: u32) -> Frame {
    let mut rng = SplitMix64(7);
    let pts: Vec<Point> = (0..n)
        .map(|_| Point { center: Vec3::splat(0.5), radius: 0.25, color: color_of(&mut rng, Vec3::ONE) })
        .collect();
    let camera = Camera::framing(Vec3::ZERO, Vec3::ONE, 10.0, 5.0, 45.0, viewport, viewport);
    frame_from_points(&pts, camera)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_image_frame_has_paper_size() {
        let f = depth_image_frame(1024, 1.0, 1);
        let n = f.samples.len();
        assert!((600_000..650_000).contains(&n), "{n}");
        assert_eq!(f.colors.len(), n);
        assert_eq!(f.header.count as usize, n);
    }
}
