//! The camera paths away from the camera a frame was rendered for (C0): an orbit around the
//! volume's centre and a dolly in and out along the view direction.

use volwarp_core::Camera;

/// Orbit angles of the evaluation, in degrees (yaw around the camera's up axis).
pub const ORBIT_DEGREES: [f32; 6] = [0.0, 2.5, 5.0, 10.0, 20.0, 30.0];

/// Dolly factors of the evaluation: the new distance to the target over the old one (< 1 moves
/// in, > 1 moves out).
pub const DOLLY_FACTORS: [f32; 4] = [0.7, 0.85, 1.2, 1.5];

/// C0 orbited by `deg` degrees around its target.
pub fn orbit(c0: &Camera, deg: f32) -> Camera {
    if deg == 0.0 {
        *c0
    } else {
        c0.orbit(deg, 0.0)
    }
}

/// C0 moved along its view direction to `factor` times its distance.
pub fn dolly(c0: &Camera, factor: f32) -> Camera {
    c0.dolly(factor)
}

#[cfg(test)]
mod tests {
    use super::*;
    use volwarp_core::Vec3;

    #[test]
    fn orbit_turns_by_the_angle_and_dolly_scales_distance() {
        let c0 = Camera::look_at(Vec3::new(0.0, 0.0, 4.0), Vec3::ZERO, Vec3::Y, 30.0, 8, 8);
        let c = orbit(&c0, 30.0);
        let cos = (c.eye - c.target).normalize().dot((c0.eye - c0.target).normalize());
        assert!((cos - 30f32.to_radians().cos()).abs() < 1e-5);
        assert_eq!(orbit(&c0, 0.0), c0);
        assert!(((dolly(&c0, 0.5).eye - c0.target).length() - 2.0).abs() < 1e-5);
    }
}
