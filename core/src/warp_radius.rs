//! Warp-sized radii ("samples sized by what is known"): how large a sphere a
//! client should draw depends on how far the view has moved from the frame's camera.
//!
//! At the frame's own camera a sphere half the default footprint (half a pixel diagonal)
//! reproduces the frame exactly: every pixel sees its own sample and none of its neighbours'
//! (`docs/results.md`, "Which sphere radius": footprint×0.5 has FLIP 0.0000 at 0°, footprint×1
//! 0.0166). As the view turns, neighbouring samples spread apart and small spheres open
//! cracks; the best radius measured grows with the angle (×0.71 at 2.5–5°, ×1 at 10°, ×1.41 at
//! 20°). [`radius_scale`] follows that: `0.5 + 0.05 · θ` for a warp of `θ` degrees, capped at
//! [`MAX_SCALE`] so that spheres never outgrow the bounds the frame's acceleration structure
//! was built with. A dolly also spreads samples at different depths apart (parallax along the
//! view): it counts as a turn of [`DOLLY_WEIGHT`] times its relative change of distance, in
//! radians (0.25 measured best of 0, 0.25, 0.5 and 1 on the session simulator's dolly, CT head
//! and MRI at 512²: mean FLIP 0.0223 / 0.0172 / 0.0182 / 0.0201 on the CT head). The scale is
//! applied by the client at draw time; the frame is unchanged.

use crate::camera::Camera;

/// The scale at the frame's own camera.
pub const MIN_SCALE: f32 = 0.5;
/// The largest scale (the frame's own radius: bounds built for it stay valid).
pub const MAX_SCALE: f32 = 1.0;
/// Scale added per degree of warp.
pub const PER_DEGREE: f32 = 0.05;

/// How much of a dolly's relative change of distance counts as a turn (radians per unit; see
/// the module docs for the measurement).
pub const DOLLY_WEIGHT: f32 = 0.25;

/// The angle in degrees the view turned from `from` to `to`, seen from `from`'s target: the
/// largest of the angle between the two eyes about that point, the angle between the two
/// viewing directions (a pan or a turn in place) and the dolly's equivalent turn. 0 for equal cameras; 180 for anything that
/// is not finite or degenerate (so a caller falls back to the largest radius).
pub fn warp_angle_deg(from: &Camera, to: &Camera) -> f32 {
    let p = from.target;
    let angle = |a: glam::Vec3, b: glam::Vec3| {
        let (a, b) = (a.normalize_or_zero(), b.normalize_or_zero());
        if a == glam::Vec3::ZERO || b == glam::Vec3::ZERO {
            return None;
        }
        Some(libm::acosf(a.dot(b).clamp(-1.0, 1.0)).to_degrees())
    };
    let about = angle(from.eye - p, to.eye - p);
    let view = angle(from.target - from.eye, to.target - to.eye);
    // A dolly moves the eye along the view: parallax as from a turn of ALONG_VIEW·Δd/d radians.
    let d = (from.eye - p).length();
    let along = (to.eye - p).length() - d;
    let dolly = if d > 0.0 && d.is_finite() { (DOLLY_WEIGHT * along.abs() / d).to_degrees() } else { f32::NAN };
    match (about, view) {
        (Some(a), Some(b)) if a.is_finite() && b.is_finite() && dolly.is_finite() => a.max(b).max(dolly),
        _ => 180.0,
    }
}

/// The radius scale for drawing a frame rendered for `from` with the camera `to` (see the
/// module docs): in `MIN_SCALE..=MAX_SCALE`, never NaN.
pub fn radius_scale(from: &Camera, to: &Camera) -> f32 {
    (MIN_SCALE + PER_DEGREE * warp_angle_deg(from, to)).clamp(MIN_SCALE, MAX_SCALE)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn scale_grows_with_the_turn_and_stays_bounded() {
        let c = Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y, 40.0, 64, 64);
        assert_eq!(warp_angle_deg(&c, &c), 0.0);
        assert_eq!(radius_scale(&c, &c), MIN_SCALE);
        let a = warp_angle_deg(&c, &c.orbit(4.0, 0.0));
        assert!((a - 4.0).abs() < 0.05, "{a}");
        assert!((radius_scale(&c, &c.orbit(4.0, 0.0)) - 0.7).abs() < 0.01);
        assert_eq!(radius_scale(&c, &c.orbit(30.0, 0.0)), MAX_SCALE);
        // A dolly counts DOLLY_WEIGHT of its relative change of distance; a pan turns the view.
        let want = (DOLLY_WEIGHT * 0.3f32).to_degrees();
        assert!((warp_angle_deg(&c, &c.dolly(0.7)) - want).abs() < 0.05, "{}", warp_angle_deg(&c, &c.dolly(0.7)));
        let pan = Camera { target: Vec3::new(0.3, 0.0, 0.0), ..c };
        assert!(warp_angle_deg(&c, &pan) > 5.0);
        let bad = Camera { eye: Vec3::NAN, ..c };
        assert_eq!(radius_scale(&c, &bad), MAX_SCALE);
        let degenerate = Camera { eye: c.target, ..c };
        assert_eq!(radius_scale(&c, &degenerate), MAX_SCALE);
    }
}
