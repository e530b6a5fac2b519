//! The object-space sample: a quantized position and a radius code in one little-endian `u64`,
//! and its color as 32-bit RGBA8.
//!
//! Layout of the `u64` (bit 0 is the least significant):
//!
//! | bits | field |
//! |---|---|
//! | 0..18 | x, quantized over the frame's bounds (0 = `min.x`, 2¹⁸−1 = `max.x`) |
//! | 18..36 | y |
//! | 36..54 | z |
//! | 54..64 | radius code r: radius = r × `radius_unit`; r = 0 marks an empty sample |
//!
//! A quantum is `(max − min) / (2¹⁸ − 1)` per axis, so the round-trip error is at most half a
//! quantum. `docs/wire-format.md` explains the choice of 18/18/18/10.
//!
//! Colors are **premultiplied** RGBA8 packed little-endian (`r | g << 8 | b << 16 | a << 24`),
//! i.e. the bytes R, G, B, A in memory: the front-to-back composited color of the pixel.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// Bits per position axis.
pub const POS_BITS: u32 = 18;
/// Bits of the radius code.
pub const RADIUS_BITS: u32 = 10;
/// Largest quantized coordinate.
pub const POS_MAX: u32 = (1 << POS_BITS) - 1;
/// Largest radius code.
pub const RADIUS_MAX: u32 = (1 << RADIUS_BITS) - 1;
const POS_MASK: u64 = POS_MAX as u64;

/// An axis-aligned box; the frame's scene bounds.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Bounds {
    /// Minimum corner.
    pub min: [f32; 3],
    /// Maximum corner.
    pub max: [f32; 3],
}

impl Bounds {
    /// A box from two corners.
    pub fn new(min: Vec3, max: Vec3) -> Self {
        Bounds { min: min.to_array(), max: max.to_array() }
    }
    /// Minimum corner.
    pub fn min(&self) -> Vec3 {
        Vec3::from_array(self.min)
    }
    /// Maximum corner.
    pub fn max(&self) -> Vec3 {
        Vec3::from_array(self.max)
    }
    /// Finite and `min <= max` on every axis, with an extent that does not overflow (zero
    /// extent is allowed: all samples on one plane or point), and every quantized position
    /// decodes ([`Dequantizer::center`]) to a finite point: near `f32::MAX` the rounding of
    /// `min + (2¹⁸ − 1) · step` can overflow to infinity (bounds `[0, f32::MAX]` did).
    pub fn is_valid(&self) -> bool {
        (0..3).all(|i| {
            let (a, b) = (self.min[i], self.max[i]);
            let top = a + POS_MAX as f32 * ((b - a) / POS_MAX as f32);
            a.is_finite() && b.is_finite() && a <= b && (b - a).is_finite() && top.is_finite()
        })
    }
    /// The box of a set of points; `None` if empty.
    pub fn of_points(points: impl IntoIterator<Item = Vec3>) -> Option<Bounds> {
        let mut it = points.into_iter();
        let first = it.next()?;
        let (mut lo, mut hi) = (first, first);
        for p in it {
            lo = lo.min(p);
            hi = hi.max(p);
        }
        Some(Bounds::new(lo, hi))
    }
}

/// Turns positions and radii into packed samples for one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Quantizer {
    pub(crate) min: Vec3,
    pub(crate) scale: Vec3,
    radius_unit: f32,
}

impl Quantizer {
    /// A quantizer over `bounds` (must be valid) with radius step `radius_unit` (> 0).
    pub fn new(bounds: Bounds, radius_unit: f32) -> Self {
        let ext = bounds.max() - bounds.min();
        let s = |e: f32| if e > 0.0 { POS_MAX as f32 / e } else { 0.0 };
        Quantizer { min: bounds.min(), scale: Vec3::new(s(ext.x), s(ext.y), s(ext.z)), radius_unit }
    }

    /// Quantizes one coordinate value to `0..=POS_MAX`, rounding to nearest and clamping.
    #[inline]
    fn q(v: f32, min: f32, scale: f32) -> u64 {
        let f = (v - min) * scale + 0.5;
        // NaN and negatives go to 0; clamp the top.
        if f >= POS_MAX as f32 {
            POS_MAX as u64
        } else if f > 0.0 {
            f as u64
        } else {
            0
        }
    }

    /// The radius code of `radius` (rounded, clamped to `1..=RADIUS_MAX`; 0 only for radius <= 0).
    #[inline]
    pub fn radius_code(&self, radius: f32) -> u32 {
        if !(radius > 0.0) || !(self.radius_unit > 0.0) {
            return 0;
        }
        let f = radius / self.radius_unit + 0.5;
        if f >= RADIUS_MAX as f32 {
            RADIUS_MAX
        } else if f >= 1.0 {
            f as u32
        } else {
            1
        }
    }

    /// Packs a position and radius (radius <= 0 gives an empty sample).
    #[inline]
    pub fn pack(&self, p: Vec3, radius: f32) -> u64 {
        let x = Self::q(p.x, self.min.x, self.scale.x);
        let y = Self::q(p.y, self.min.y, self.scale.y);
        let z = Self::q(p.z, self.min.z, self.scale.z);
        let r = self.radius_code(radius) as u64;
        x | y << POS_BITS | z << (2 * POS_BITS) | r << (3 * POS_BITS)
    }

    /// [`Quantizer::pack`] of eight positions (`p[axis][lane]`) and radii, bit for bit: in
    /// AVX2 lanes where the lane level allows it (the scalar code's float-to-integer casts
    /// saturate, which the compiler does not vectorize), else one at a time.
    pub fn pack8(&self, p: &[[f32; 8]; 3], radius: &[f32; 8]) -> [u64; 8] {
        #[cfg(all(feature = "std", target_arch = "x86_64"))]
        if let (Some(t), true) = (volwarp_lanes::Avx2Token::new(), self.radius_unit > 0.0) {
            // SAFETY: the token proves the CPU has AVX2 (and the lane level allows it).
            return unsafe { pack8_avx2(t, self, p, radius) };
        }
        core::array::from_fn(|l| self.pack(Vec3::new(p[0][l], p[1][l], p[2][l]), radius[l]))
    }
}

/// [`Quantizer::pack8`] in AVX2 lanes, for `q.radius_unit > 0`: per axis `(v − min)·scale +
/// 0.5` truncated within `0..=POS_MAX` (`maxps` returns its second operand for a NaN, so a
/// NaN gives 0 as the scalar code's comparisons do); the radius code `r / unit + 0.5`
/// truncated within `1..=RADIUS_MAX`, 0 where the radius is not above 0.
#[cfg(all(feature = "std", target_arch = "x86_64"))]
#[target_feature(enable = "avx2")]
fn pack8_avx2(t: volwarp_lanes::Avx2Token, q: &Quantizer, p: &[[f32; 8]; 3], radius: &[f32; 8]) -> [u64; 8] {
    use volwarp_lanes::Avx2;
    // No closures: a closure is not compiled with its function's target features.
    let (min, scale) = (q.min.to_array(), q.scale.to_array());
    let mut axes = [[0i32; 8]; 3];
    for a in 0..3 {
        let f = (Avx2::load(t, &p[a]) - Avx2::splat(t, min[a])) * Avx2::splat(t, scale[a]) + Avx2::splat(t, 0.5);
        let f = f.fast_max(Avx2::splat(t, 0.0)).fast_min(Avx2::splat(t, POS_MAX as f32));
        axes[a] = f.trunc_int().to_array();
    }
    let r = Avx2::load(t, radius);
    let f = r / Avx2::splat(t, q.radius_unit) + Avx2::splat(t, 0.5);
    let code = f.fast_max(Avx2::splat(t, 1.0)).fast_min(Avx2::splat(t, RADIUS_MAX as f32)).trunc_int().to_float();
    let code = r.simd_gt(Avx2::splat(t, 0.0)).select(code, Avx2::splat(t, 0.0)).trunc_int().to_array();
    let mut out = [0u64; 8];
    for l in 0..8 {
        out[l] = axes[0][l] as u64
            | (axes[1][l] as u64) << POS_BITS
            | (axes[2][l] as u64) << (2 * POS_BITS)
            | (code[l] as u64) << (3 * POS_BITS);
    }
    out
}

/// Turns packed samples back into positions and radii: the one decode every tracer mirrors
/// (`min + q * step`, a multiply then an add, no fused multiply-add).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dequantizer {
    /// Bounds minimum.
    pub min: Vec3,
    /// World size of one quantum per axis.
    pub step: Vec3,
    /// World size of one radius code step.
    pub radius_unit: f32,
}

impl Dequantizer {
    /// The decoder for a frame's bounds and radius unit.
    pub fn new(bounds: Bounds, radius_unit: f32) -> Self {
        let ext = bounds.max() - bounds.min();
        Dequantizer { min: bounds.min(), step: ext / POS_MAX as f32, radius_unit }
    }

    /// The sample's center.
    #[inline(always)]
    pub fn center(&self, s: u64) -> Vec3 {
        let (x, y, z) = unpack_position(s);
        Vec3::new(
            self.min.x + x as f32 * self.step.x,
            self.min.y + y as f32 * self.step.y,
            self.min.z + z as f32 * self.step.z,
        )
    }

    /// The sample's radius.
    #[inline(always)]
    pub fn radius(&self, s: u64) -> f32 {
        radius_code(s) as f32 * self.radius_unit
    }
}

/// The three quantized coordinates of a packed sample.
#[inline(always)]
pub fn unpack_position(s: u64) -> (u32, u32, u32) {
    ((s & POS_MASK) as u32, ((s >> POS_BITS) & POS_MASK) as u32, ((s >> (2 * POS_BITS)) & POS_MASK) as u32)
}

/// The radius code of a packed sample.
#[inline(always)]
pub fn radius_code(s: u64) -> u32 {
    (s >> (3 * POS_BITS)) as u32
}

/// Whether the sample is empty (radius code 0).
#[inline(always)]
pub fn is_empty(s: u64) -> bool {
    radius_code(s) == 0
}

/// Packs premultiplied RGBA8.
#[inline]
pub const fn pack_color(r: u8, g: u8, b: u8, a: u8) -> u32 {
    u32::from_le_bytes([r, g, b, a])
}

/// The opaque background every renderer (and the ground-truth marcher) shows where nothing is.
pub const BACKGROUND: u32 = pack_color(24, 24, 32, 255);

/// Packs a premultiplied color given as floats in 0..=1 (clamped; NaN becomes 0).
#[inline]
pub fn pack_color_f32(c: [f32; 4]) -> u32 {
    let q = |v: f32| {
        let f = v * 255.0 + 0.5;
        if f >= 255.0 {
            255
        } else if f > 0.0 {
            f as u8
        } else {
            0
        }
    };
    pack_color(q(c[0]), q(c[1]), q(c[2]), q(c[3]))
}

/// Composites a premultiplied sample color over an opaque background color (both packed),
/// giving an opaque packed color: `c + (1 − c.a) · bg`, per channel, rounded. Every renderer
/// shows a hit this way.
#[inline]
pub fn over_background(c: u32, bg: u32) -> u32 {
    let [r, g, b, a] = c.to_le_bytes();
    let [br, bgc, bb, _] = bg.to_le_bytes();
    let k = 255 - a as u32;
    let ch = |s: u8, d: u8| -> u8 { (s as u32 + (k * d as u32 + 127) / 255).min(255) as u8 };
    pack_color(ch(r, br), ch(g, bgc), ch(b, bb), 255)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eight_at_once_pack_as_one_at_a_time() {
        // Positions inside, on and outside the bounds, radii of every code, and odd values.
        let b = Bounds::new(Vec3::new(-1.0, 2.0, 3.0), Vec3::new(5.0, 2.5, 100.0));
        let mut next = crate::test_unit_rng(0x853C_49E6_748F_EA9B);
        let odd = [f32::NAN, f32::INFINITY, -f32::INFINITY, 0.0, -0.0, 1e30, -1e30, f32::MIN_POSITIVE];
        for unit in [0.01f32, 1e-6, 3.0, 0.0, -1.0] {
            let q = Quantizer::new(b, unit);
            for round in 0..20_000 {
                let mut p = [[0.0f32; 8]; 3];
                let mut r = [0.0f32; 8];
                for l in 0..8 {
                    for (a, lo, hi) in [(0, -1.0f32, 5.0f32), (1, 2.0, 2.5), (2, 3.0, 100.0)] {
                        p[a][l] = lo + (hi - lo) * (next() * 1.2 - 0.1);
                    }
                    r[l] = next() * unit.abs() * 1100.0 - unit.abs() * 2.0;
                    if round % 7 == 0 {
                        let v = odd[(next() * 8.0) as usize % 8];
                        if next() < 0.5 {
                            r[l] = v;
                        } else {
                            p[(next() * 3.0) as usize % 3][l] = v;
                        }
                    }
                }
                let want: [u64; 8] = core::array::from_fn(|l| q.pack(Vec3::new(p[0][l], p[1][l], p[2][l]), r[l]));
                assert_eq!(q.pack8(&p, &r), want, "unit {unit}: {p:?} {r:?}");
            }
        }
    }

    #[test]
    fn bounds_corners_are_exact() {
        let b = Bounds::new(Vec3::new(-1.0, 2.0, 3.0), Vec3::new(5.0, 2.5, 100.0));
        let q = Quantizer::new(b, 0.01);
        let d = Dequantizer::new(b, 0.01);
        let s = q.pack(b.min(), 0.5);
        assert_eq!(unpack_position(s), (0, 0, 0));
        assert_eq!(d.center(s), b.min());
        let s = q.pack(b.max(), 0.5);
        assert_eq!(unpack_position(s), (POS_MAX, POS_MAX, POS_MAX));
        assert!((d.center(s) - b.max()).abs().max_element() < 1e-5);
    }

    #[test]
    fn radius_zero_and_max() {
        let b = Bounds::new(Vec3::ZERO, Vec3::ONE);
        let q = Quantizer::new(b, 0.001);
        assert!(is_empty(q.pack(Vec3::splat(0.5), 0.0)));
        assert!(is_empty(q.pack(Vec3::splat(0.5), -1.0)));
        assert!(is_empty(q.pack(Vec3::splat(0.5), f32::NAN)));
        assert_eq!(radius_code(q.pack(Vec3::splat(0.5), 1e9)), RADIUS_MAX);
        assert_eq!(radius_code(q.pack(Vec3::splat(0.5), 1e-9)), 1, "tiny radius stays non-empty");
    }

    #[test]
    fn nan_position_clamps_instead_of_leaking() {
        let b = Bounds::new(Vec3::ZERO, Vec3::ONE);
        let s = Quantizer::new(b, 0.1).pack(Vec3::new(f32::NAN, 2.0, -3.0), 0.1);
        assert_eq!(unpack_position(s), (0, POS_MAX, 0));
    }

    #[test]
    fn zero_extent_axis() {
        let b = Bounds::new(Vec3::new(1.0, 1.0, 1.0), Vec3::new(1.0, 2.0, 1.0));
        let q = Quantizer::new(b, 0.1);
        let d = Dequantizer::new(b, 0.1);
        let p = Vec3::new(1.0, 1.5, 1.0);
        let c = d.center(q.pack(p, 0.1));
        assert_eq!(c.x, 1.0);
        assert!((c.y - 1.5).abs() < 1e-5);
    }

    #[test]
    fn over_background_is_exact_at_the_ends() {
        let bg = pack_color(10, 20, 30, 255);
        assert_eq!(over_background(pack_color(0, 0, 0, 0), bg), bg);
        assert_eq!(over_background(pack_color(200, 100, 50, 255), bg), pack_color(200, 100, 50, 255));
        assert_eq!(
            over_background(pack_color(100, 0, 0, 128), pack_color(255, 255, 255, 255)),
            pack_color(227, 127, 127, 255)
        );
    }
}
