//! First-hit ray–sphere and ray–box intersection, written out operation by operation so that
//! the SIMD and GPU tracers can mirror them exactly.

use crate::math::sqrt;
use glam::Vec3;

/// The nearest `t > 0` where the ray `o + d·t` (`d` unit length) meets the sphere of center `c`
/// and radius `r`, if any. A ray starting inside the sphere hits its far side.
///
/// Numerically robust form (Haines et al., *Ray Tracing Gems* ch. 7): with `oc = c − o`,
/// `b = oc·d`, `f = oc − b·d`, the discriminant is `r² − f·f`, which does not cancel
/// catastrophically for small spheres far away.
#[inline(always)]
pub fn intersect(o: Vec3, d: Vec3, c: Vec3, r: f32) -> Option<f32> {
    let ocx = c.x - o.x;
    let ocy = c.y - o.y;
    let ocz = c.z - o.z;
    let b = ocx * d.x + ocy * d.y + ocz * d.z;
    let fx = ocx - b * d.x;
    let fy = ocy - b * d.y;
    let fz = ocz - b * d.z;
    let disc = r * r - (fx * fx + fy * fy + fz * fz);
    if !(disc >= 0.0) {
        return None;
    }
    let s = sqrt(disc);
    let t0 = b - s;
    let t1 = b + s;
    if t0 > 0.0 {
        Some(t0)
    } else if t1 > 0.0 {
        Some(t1)
    } else {
        None
    }
}

/// Factor `1 + 2γ₃` (γₙ = nε / (1 − nε), ε = 2⁻²⁴) by which [`intersect_box`] widens its far
/// bound, so that rounding in the slab test never culls a box the ray touches (Ize, *Robust BVH
/// Ray Traversal*, JCGT 2013). Without it a sphere far smaller than the rounding of the ray
/// parameter (found by the `lbvh` fuzz target) is hit by brute force but culled by its box.
pub const BOX_T_FAR_SCALE: f32 = 1.000_000_4;

/// Slab test: the entry parameter of the ray into the box, if it enters before `t_max` and the
/// box is not behind the ray. `inv_d` is `1 / d` per component (may be infinite). Conservative:
/// the far bound (and `t_max`) are scaled by [`BOX_T_FAR_SCALE`].
#[inline(always)]
pub fn intersect_box(o: Vec3, inv_d: Vec3, min: [f32; 3], max: [f32; 3], t_max: f32) -> Option<f32> {
    let tx1 = (min[0] - o.x) * inv_d.x;
    let tx2 = (max[0] - o.x) * inv_d.x;
    let ty1 = (min[1] - o.y) * inv_d.y;
    let ty2 = (max[1] - o.y) * inv_d.y;
    let tz1 = (min[2] - o.z) * inv_d.z;
    let tz2 = (max[2] - o.z) * inv_d.z;
    let t_near = tx1.min(tx2).max(ty1.min(ty2)).max(tz1.min(tz2)).max(0.0);
    let t_far = (tx1.max(tx2).min(ty1.max(ty2)).min(tz1.max(tz2)) * BOX_T_FAR_SCALE).min(t_max * BOX_T_FAR_SCALE);
    if t_near <= t_far {
        Some(t_near)
    } else {
        None
    }
}

/// Conservative box of a sphere: `[c − r, c + r]` widened by a relative 2⁻²⁰ so that rounding
/// can never put a point of the sphere outside it.
#[inline]
pub fn sphere_box(c: Vec3, r: f32) -> ([f32; 3], [f32; 3]) {
    let pad = |v: f32| (v.abs() + r) * (1.0 / 1048576.0);
    let lo = [c.x - r - pad(c.x), c.y - r - pad(c.y), c.z - r - pad(c.z)];
    let hi = [c.x + r + pad(c.x), c.y + r + pad(c.y), c.z + r + pad(c.z)];
    (lo, hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hits_front_then_back_from_inside() {
        let o = Vec3::ZERO;
        let d = Vec3::Z;
        assert_eq!(intersect(o, d, Vec3::new(0.0, 0.0, 5.0), 1.0), Some(4.0));
        assert_eq!(intersect(o, d, Vec3::new(0.0, 0.0, 0.5), 1.0), Some(1.5), "origin inside");
        assert_eq!(intersect(o, d, Vec3::new(0.0, 0.0, -5.0), 1.0), None, "behind");
        assert_eq!(intersect(o, d, Vec3::new(0.0, 2.0, 5.0), 1.0), None, "beside");
        assert_eq!(intersect(o, d, Vec3::new(0.0, 0.0, 5.0), 0.0), Some(5.0), "radius 0 touches");
        assert_eq!(intersect(o, d, Vec3::new(0.0, 0.0, 5.0), f32::NAN), None);
    }

    #[test]
    fn box_test() {
        let o = Vec3::ZERO;
        let d = Vec3::new(0.0, 0.0, 1.0);
        let inv = d.recip();
        assert_eq!(intersect_box(o, inv, [-1.0, -1.0, 2.0], [1.0, 1.0, 3.0], f32::INFINITY), Some(2.0));
        assert_eq!(intersect_box(o, inv, [-1.0, -1.0, 2.0], [1.0, 1.0, 3.0], 1.5), None);
        assert_eq!(intersect_box(o, inv, [2.0, -1.0, 2.0], [3.0, 1.0, 3.0], f32::INFINITY), None);
        assert_eq!(intersect_box(o, inv, [-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], f32::INFINITY), Some(0.0), "inside");
    }
}
