//! The sphere radius of a sample: how large the server makes the sphere of each pixel.
//!
//! * [`RadiusModel::Voxel`] — the seed paper's: half a voxel diagonal, the same for every
//!   sample. Where a voxel covers several pixels (a volume smaller than the viewport) these
//!   spheres are several pixels wide, so neighbours occlude each other even without motion and
//!   a tracer wades through many overlapping spheres.
//! * [`RadiusModel::Footprint`] — the pixel's own footprint at the sample's depth: a sample
//!   stands for one pixel, so its sphere is `FOOTPRINT_FACTOR × z × pitch`, where `z` is the
//!   sample's distance along the view direction and `pitch` the width of a pixel at unit
//!   distance. The factor is √2: the sphere's radius is a pixel diagonal, so it reaches the
//!   centres of all eight neighbouring pixels. From the frame's own camera every pixel still
//!   sees its own sample almost everywhere, and the holes a turning camera opens between
//!   samples stay closed up to about 10°. `volwarp-eval radius` chose it (docs/results.md):
//!   over five datasets its mean FLIP against the truth is lower than the voxel model's at
//!   every angle up to 20°; a smaller footprint (one pixel) is slightly better up to 5° and
//!   worse beyond.
//!
//! A request's `radius_scale` multiplies either. Both are encoded with the wire's per-sample
//! 10-bit radius code: the voxel model spends a fixed code ([`crate::marcher::RADIUS_CODE`]),
//! the footprint model a unit that gives the farthest corner of the volume box the largest code.

use core::fmt;
use core::str::FromStr;
use volwarp_core::sample::RADIUS_MAX;
use volwarp_core::{Bounds, Camera, Vec3};

/// The footprint radius in pixel pitches at the sample's depth: a pixel diagonal (see the module
/// docs).
pub const FOOTPRINT_FACTOR: f32 = core::f32::consts::SQRT_2;

/// How the server sizes each sample's sphere (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum RadiusModel {
    /// Half a voxel diagonal for every sample (the seed paper's).
    Voxel,
    /// A pixel diagonal at the sample's depth.
    #[default]
    Footprint,
}

impl RadiusModel {
    /// Both models.
    pub const ALL: [RadiusModel; 2] = [RadiusModel::Voxel, RadiusModel::Footprint];

    /// The model's name on the command line and in CSV files.
    pub fn name(self) -> &'static str {
        match self {
            RadiusModel::Voxel => "voxel",
            RadiusModel::Footprint => "footprint",
        }
    }
}

impl fmt::Display for RadiusModel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for RadiusModel {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        RadiusModel::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| format!("unknown radius model {s:?}; one of voxel, footprint"))
    }
}

/// The radius of every sample of one frame: `constant + per_depth × z` with `z = t · (d · w)`
/// for the sample at `o + d·t` (`w` the camera's unit view direction), and the frame's radius
/// unit (the step of the 10-bit code).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameRadius {
    constant: f32,
    per_depth: f32,
    forward: Vec3,
    unit: f32,
}

impl FrameRadius {
    /// The radius of `model` × `scale` for `camera`'s frame of a volume with box `bounds` and
    /// voxel radius `voxel_radius` (half a voxel diagonal). `voxel_code` is the code the voxel
    /// model gives a radius of `voxel_radius × scale`.
    pub fn new(
        model: RadiusModel,
        scale: f32,
        camera: &Camera,
        bounds: &Bounds,
        voxel_radius: f32,
        voxel_code: f32,
    ) -> FrameRadius {
        let voxel = |scale: f32| {
            let r = voxel_radius * scale;
            FrameRadius { constant: r, per_depth: 0.0, forward: Vec3::ZERO, unit: r / voxel_code }
        };
        match model {
            RadiusModel::Voxel => voxel(scale),
            RadiusModel::Footprint => {
                let (_, _, w) = camera.basis();
                let b = camera.ray_basis();
                let len = |v: [f32; 4]| Vec3::new(v[0], v[1], v[2]).length();
                let pitch = len(b.du).max(len(b.dv));
                let per_depth = FOOTPRINT_FACTOR * pitch * scale;
                let (lo, hi) = (bounds.min(), bounds.max());
                let z_max = (0..8)
                    .map(|i| {
                        let c = Vec3::new(
                            if i & 1 == 0 { lo.x } else { hi.x },
                            if i & 2 == 0 { lo.y } else { hi.y },
                            if i & 4 == 0 { lo.z } else { hi.z },
                        );
                        (c - camera.eye).dot(w)
                    })
                    .fold(0.0f32, f32::max);
                let unit = per_depth * z_max / RADIUS_MAX as f32;
                if unit > 0.0 && unit.is_finite() && w.is_finite() {
                    FrameRadius { constant: 0.0, per_depth, forward: w, unit }
                } else {
                    // The box lies behind the eye or the camera is degenerate: no sample can
                    // be placed anyway; keep a valid unit.
                    voxel(scale)
                }
            }
        }
    }

    /// The radius of the sample at `o + d·t` (unit `d`).
    #[inline(always)]
    pub fn at(&self, d: Vec3, t: f32) -> f32 {
        self.constant + self.per_depth * (t * d.dot(self.forward))
    }

    /// World size of one step of the radius code.
    pub fn unit(&self) -> f32 {
        self.unit
    }

    /// The radius at depth 0 (the voxel model's radius; 0 for the footprint model).
    pub fn constant(&self) -> f32 {
        self.constant
    }

    /// The radius per unit of depth along the view direction (0 for the voxel model).
    pub fn per_depth(&self) -> f32 {
        self.per_depth
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use volwarp_core::sample::{radius_code, Dequantizer, Quantizer};

    fn cam() -> Camera {
        Camera::look_at(Vec3::new(0.5, 0.5, 3.0), Vec3::splat(0.5), Vec3::Y, 30.0, 200, 100)
    }

    fn unit_box() -> Bounds {
        Bounds::new(Vec3::ZERO, Vec3::ONE)
    }

    #[test]
    fn names_round_trip() {
        for m in RadiusModel::ALL {
            assert_eq!(m.name().parse::<RadiusModel>(), Ok(m));
        }
        assert!("pixel".parse::<RadiusModel>().is_err());
        assert_eq!(RadiusModel::default(), RadiusModel::Footprint);
    }

    #[test]
    fn voxel_radius_is_constant() {
        let r = FrameRadius::new(RadiusModel::Voxel, 2.0, &cam(), &unit_box(), 0.01, 512.0);
        assert_eq!(r.at(Vec3::Z, 1.0), 0.02);
        assert_eq!(r.at(Vec3::X, 7.0), 0.02);
        assert_eq!(r.unit(), 0.02 / 512.0);
    }

    #[test]
    fn footprint_is_half_a_pixel_diagonal_at_the_sample_depth() {
        let c = cam();
        let r = FrameRadius::new(RadiusModel::Footprint, 1.0, &c, &unit_box(), 0.01, 512.0);
        // Pixel (100, 50) at distance 2.5: project the neighbouring pixel's ray to the same
        // depth; their distance is one pixel pitch at that depth.
        let b = c.ray_basis();
        let (d0, d1) = (b.dir(100, 50), b.dir(101, 50));
        let (_, _, w) = c.basis();
        let z = 2.5f32;
        let p0 = c.eye + d0 * (z / d0.dot(w));
        let p1 = c.eye + d1 * (z / d1.dot(w));
        let pitch = (p1 - p0).length();
        let got = r.at(d0, z / d0.dot(w));
        assert!((got - FOOTPRINT_FACTOR * pitch).abs() < 1e-4 * pitch, "{got} vs {}", FOOTPRINT_FACTOR * pitch);
        // Twice as far, twice as large; the scale multiplies.
        assert!((r.at(d0, 2.0 * z / d0.dot(w)) - 2.0 * got).abs() < 1e-5);
        let r2 = FrameRadius::new(RadiusModel::Footprint, 0.5, &c, &unit_box(), 0.01, 512.0);
        assert!((r2.at(d0, z / d0.dot(w)) - 0.5 * got).abs() < 1e-6);
    }

    #[test]
    fn footprint_codes_fit_the_box() {
        // Every sample inside the box gets a code within the 10-bit range, the farthest one
        // close to the top, and the decoded radius is within half a code step.
        let c = cam();
        let bounds = unit_box();
        let r = FrameRadius::new(RadiusModel::Footprint, 1.0, &c, &bounds, 0.01, 512.0);
        let q = Quantizer::new(bounds, r.unit());
        let deq = Dequantizer::new(bounds, r.unit());
        let mut top = 0;
        for i in 0..27 {
            // Points on a 3×3×3 grid of the box, corners included.
            let p = Vec3::new((i % 3) as f32, (i / 3 % 3) as f32, (i / 9) as f32) * 0.5;
            let (d, t) = ((p - c.eye).normalize(), (p - c.eye).length());
            let rad = r.at(d, t);
            let s = q.pack(p, rad);
            let code = radius_code(s);
            assert!(
                (1..RADIUS_MAX).contains(&code) || (code == RADIUS_MAX && rad <= r.unit() * (RADIUS_MAX as f32 + 0.5))
            );
            top = top.max(code);
            assert!((deq.radius(s) - rad).abs() <= 0.5 * r.unit() * 1.001, "{} vs {rad}", deq.radius(s));
        }
        assert!(top > RADIUS_MAX * 3 / 4, "the far samples use the top of the code range: {top}");
    }

    #[test]
    fn box_behind_the_eye_keeps_a_valid_unit() {
        let c = Camera::look_at(Vec3::new(0.5, 0.5, -3.0), Vec3::new(0.5, 0.5, -6.0), Vec3::Y, 30.0, 64, 64);
        let r = FrameRadius::new(RadiusModel::Footprint, 1.0, &c, &unit_box(), 0.01, 512.0);
        assert!(r.unit() > 0.0 && r.unit().is_finite());
    }
}
