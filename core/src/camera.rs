//! The pinhole camera and its primary rays.
//!
//! **Convention.** World space is right-handed. The camera looks from `eye` towards `target`;
//! `up` is a hint that need not be orthogonal to the view direction. The orthonormal basis is
//! `w = normalize(target - eye)` (forward), `u = normalize(w × up)` (image right) and
//! `v = u × w` (image up). Pixel `(0, 0)` is the **top-left** pixel, x grows to the right and
//! y grows **downwards**; a pixel's ray goes through its centre `(x + 0.5, y + 0.5)`. `fov_y_deg`
//! is the full vertical field of view; the horizontal one follows from `width / height`
//! (square pixels).
//!
//! Every renderer (the server's marcher, the CPU tracers, the WGSL shader) computes the ray
//! direction of pixel `(x, y)` the same way, from [`RayBasis`]:
//! `d = normalize(corner + du·(x + 0.5) + dv·(y + 0.5))`, evaluated component-wise as
//! `corner + du*px` then `+ dv*py`, and normalized as `d * (1 / sqrt(d·d))`.

use crate::math::{sqrt, tan};
use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// A pinhole camera with its viewport.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position in world (object) space.
    pub eye: Vec3,
    /// The point looked at; also the orbit centre.
    pub target: Vec3,
    /// Up hint.
    pub up: Vec3,
    /// Full vertical field of view in degrees, in (0, 180).
    pub fov_y_deg: f32,
    /// Viewport width in pixels.
    pub width: u32,
    /// Viewport height in pixels.
    pub height: u32,
}

/// Why a camera is unusable.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraError {
    /// A coordinate or the field of view is NaN or infinite.
    NotFinite,
    /// `eye == target` (no view direction).
    ZeroViewDirection,
    /// `up` is zero or parallel to the view direction.
    DegenerateUp,
    /// The field of view is not in (0, 180) degrees (limits: 0.01 to 179).
    BadFieldOfView,
    /// Width or height is 0 or above the allowed maximum.
    BadViewport,
}

impl core::fmt::Display for CameraError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let s = match self {
            CameraError::NotFinite => "camera has a NaN or infinite value",
            CameraError::ZeroViewDirection => "camera eye equals its target",
            CameraError::DegenerateUp => "camera up vector is zero or parallel to the view direction",
            CameraError::BadFieldOfView => "camera field of view is not within 0.01..179 degrees",
            CameraError::BadViewport => "camera viewport is empty or too large",
        };
        f.write_str(s)
    }
}

#[cfg(feature = "std")]
impl std::error::Error for CameraError {}

/// A ray `o + d·t` with unit-length `d`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Origin.
    pub origin: Vec3,
    /// Unit direction.
    pub dir: Vec3,
}

impl Ray {
    /// The point at parameter `t`.
    #[inline]
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }
}

/// Everything needed to generate primary rays; `#[repr(C)]` so the GPU reads the same bytes.
/// Each field is a `vec4<f32>` whose `w` is unused (0), except `eye.w` which holds the width
/// and `corner.w` the height (as f32) for the shader's convenience.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct RayBasis {
    /// Eye position; `w` = viewport width.
    pub eye: [f32; 4],
    /// Direction (unnormalized) through the top-left corner of the image plane; `w` = height.
    pub corner: [f32; 4],
    /// Step of the unnormalized direction per pixel to the right.
    pub du: [f32; 4],
    /// Step of the unnormalized direction per pixel downwards.
    pub dv: [f32; 4],
}

impl RayBasis {
    /// The unit direction through the centre of pixel `(x, y)` (the one formula every renderer
    /// uses).
    #[inline(always)]
    pub fn dir(&self, x: u32, y: u32) -> Vec3 {
        let px = x as f32 + 0.5;
        let py = y as f32 + 0.5;
        let dx = self.corner[0] + self.du[0] * px + self.dv[0] * py;
        let dy = self.corner[1] + self.du[1] * px + self.dv[1] * py;
        let dz = self.corner[2] + self.du[2] * px + self.dv[2] * py;
        let inv = 1.0 / sqrt(dx * dx + dy * dy + dz * dz);
        Vec3::new(dx * inv, dy * inv, dz * inv)
    }

    /// The primary ray of pixel `(x, y)`.
    #[inline(always)]
    pub fn ray(&self, x: u32, y: u32) -> Ray {
        Ray { origin: Vec3::new(self.eye[0], self.eye[1], self.eye[2]), dir: self.dir(x, y) }
    }

    /// The eye position.
    #[inline]
    pub fn origin(&self) -> Vec3 {
        Vec3::new(self.eye[0], self.eye[1], self.eye[2])
    }
}

impl Camera {
    /// A camera at `eye` looking at `target`.
    pub fn look_at(eye: Vec3, target: Vec3, up: Vec3, fov_y_deg: f32, width: u32, height: u32) -> Self {
        Camera { eye, target, up, fov_y_deg, width, height }
    }

    /// A camera that frames the box `[min, max]` entirely, looking along `-z` rotated by
    /// `yaw_deg` around `+y` and `pitch_deg` upwards, with `+y` up.
    pub fn framing(
        min: Vec3,
        max: Vec3,
        yaw_deg: f32,
        pitch_deg: f32,
        fov_y_deg: f32,
        width: u32,
        height: u32,
    ) -> Self {
        let center = (min + max) * 0.5;
        let radius = ((max - min) * 0.5).length().max(1e-6);
        let aspect = width.max(1) as f32 / height.max(1) as f32;
        let half_v = (fov_y_deg.to_radians() * 0.5).min(1.5);
        let half_min = if aspect < 1.0 { libm::atanf(tan(half_v) * aspect) } else { half_v };
        let dist = radius / libm::sinf(half_min);
        let cam = Camera::look_at(center + Vec3::new(0.0, 0.0, dist), center, Vec3::Y, fov_y_deg, width, height);
        cam.orbit(yaw_deg, pitch_deg)
    }

    /// Checks the camera is usable; `max_dim` bounds width and height.
    pub fn validate(&self, max_dim: u32) -> Result<(), CameraError> {
        let vals = [
            self.eye.x,
            self.eye.y,
            self.eye.z,
            self.target.x,
            self.target.y,
            self.target.z,
            self.up.x,
            self.up.y,
            self.up.z,
            self.fov_y_deg,
        ];
        if vals.iter().any(|v| !v.is_finite()) {
            return Err(CameraError::NotFinite);
        }
        if !(0.01..=179.0).contains(&self.fov_y_deg) {
            return Err(CameraError::BadFieldOfView);
        }
        if self.width == 0 || self.height == 0 || self.width > max_dim || self.height > max_dim {
            return Err(CameraError::BadViewport);
        }
        let w = self.target - self.eye;
        let wl = w.length();
        if !(wl > 1e-20) || !wl.is_finite() {
            return Err(CameraError::ZeroViewDirection);
        }
        let ul = self.up.length();
        if !(ul > 1e-20) || !ul.is_finite() {
            return Err(CameraError::DegenerateUp);
        }
        let c = (w / wl).cross(self.up / ul).length();
        if !(c > 1e-4) {
            return Err(CameraError::DegenerateUp);
        }
        let basis = self.ray_basis();
        let all: [f32; 16] = bytemuck::cast(basis);
        if all.iter().any(|v| !v.is_finite()) {
            return Err(CameraError::NotFinite);
        }
        Ok(())
    }

    /// The orthonormal basis `(u, v, w)`: image right, image up, forward.
    pub fn basis(&self) -> (Vec3, Vec3, Vec3) {
        let w = (self.target - self.eye).normalize_or_zero();
        let u = w.cross(self.up).normalize_or_zero();
        let v = u.cross(w);
        (u, v, w)
    }

    /// Width over height.
    pub fn aspect(&self) -> f32 {
        self.width.max(1) as f32 / self.height.max(1) as f32
    }

    /// The ray generator every renderer uses.
    pub fn ray_basis(&self) -> RayBasis {
        let (u, v, w) = self.basis();
        let tan_y = tan(self.fov_y_deg.to_radians() * 0.5);
        let tan_x = tan_y * self.aspect();
        let corner = w - u * tan_x + v * tan_y;
        let du = u * (2.0 * tan_x / self.width.max(1) as f32);
        let dv = -v * (2.0 * tan_y / self.height.max(1) as f32);
        RayBasis {
            eye: [self.eye.x, self.eye.y, self.eye.z, self.width as f32],
            corner: [corner.x, corner.y, corner.z, self.height as f32],
            du: [du.x, du.y, du.z, 0.0],
            dv: [dv.x, dv.y, dv.z, 0.0],
        }
    }

    /// The primary ray through the centre of pixel `(x, y)`.
    pub fn ray(&self, x: u32, y: u32) -> Ray {
        self.ray_basis().ray(x, y)
    }

    /// Projects a world point to continuous pixel coordinates (pixel centres at `i + 0.5`) and
    /// its distance along the view direction. `None` behind (or on) the eye plane.
    pub fn project(&self, p: Vec3) -> Option<(f32, f32, f32)> {
        let (u, v, w) = self.basis();
        let rel = p - self.eye;
        let z = rel.dot(w);
        if !(z > 1e-6) {
            return None;
        }
        let tan_y = tan(self.fov_y_deg.to_radians() * 0.5);
        let tan_x = tan_y * self.aspect();
        let sx = rel.dot(u) / (z * tan_x);
        let sy = rel.dot(v) / (z * tan_y);
        let x = (sx + 1.0) * 0.5 * self.width as f32;
        let y = (1.0 - sy) * 0.5 * self.height as f32;
        Some((x, y, z))
    }

    /// Orbits the eye around `target`: `yaw_deg` around the up axis, then `pitch_deg` around the
    /// image-right axis (positive looks from higher up). Distance to the target is kept.
    pub fn orbit(&self, yaw_deg: f32, pitch_deg: f32) -> Camera {
        let (u, _, _) = self.basis();
        let up = self.up.normalize_or_zero();
        let rel = self.eye - self.target;
        let yaw = glam::Quat::from_axis_angle(up, yaw_deg.to_radians());
        let rel = yaw * rel;
        let u = yaw * u;
        let pitch = glam::Quat::from_axis_angle(u, -pitch_deg.to_radians());
        let rel2 = pitch * rel;
        // Do not flip over the pole: keep the new view direction off the up axis.
        let rel = if rel2.normalize_or_zero().cross(up).length() > 0.02 { rel2 } else { rel };
        Camera { eye: self.target + rel, ..*self }
    }

    /// Moves the eye along the view direction: the new distance to the target is
    /// `distance * factor` (factor < 1 moves closer).
    pub fn dolly(&self, factor: f32) -> Camera {
        let rel = self.eye - self.target;
        Camera { eye: self.target + rel * factor, ..*self }
    }

    /// Moves eye and target together by `dx` image-right and `dy` image-up, in world units.
    pub fn pan(&self, dx: f32, dy: f32) -> Camera {
        let (u, v, _) = self.basis();
        let d = u * dx + v * dy;
        Camera { eye: self.eye + d, target: self.target + d, ..*self }
    }

    /// The same camera with another viewport size.
    pub fn with_viewport(&self, width: u32, height: u32) -> Camera {
        Camera { width, height, ..*self }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        Camera::look_at(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 60.0, 64, 32)
    }

    #[test]
    fn centre_ray_points_at_target_and_y_goes_down() {
        let c = Camera { width: 65, height: 33, ..cam() };
        let r = c.ray(32, 16);
        assert!((r.dir - Vec3::new(0.0, 0.0, -1.0)).length() < 1e-6);
        let top = c.ray(32, 0).dir;
        assert!(top.y > 0.0, "row 0 is the top row");
        let left = c.ray(0, 16).dir;
        assert!(left.x < 0.0, "column 0 is on the left");
    }

    #[test]
    fn project_inverts_ray() {
        let c = cam();
        for (x, y) in [(0u32, 0u32), (10, 20), (63, 31)] {
            let r = c.ray(x, y);
            let p = r.at(3.7);
            let (px, py, _) = c.project(p).unwrap();
            assert!((px - (x as f32 + 0.5)).abs() < 1e-3, "{px}");
            assert!((py - (y as f32 + 0.5)).abs() < 1e-3, "{py}");
        }
        assert!(c.project(Vec3::new(0.0, 0.0, 10.0)).is_none());
    }

    #[test]
    fn validation_rejects_degenerate_cameras() {
        assert_eq!(cam().validate(4096), Ok(()));
        assert_eq!(Camera { eye: Vec3::ZERO, ..cam() }.validate(4096), Err(CameraError::ZeroViewDirection));
        assert_eq!(Camera { up: Vec3::Z, ..cam() }.validate(4096), Err(CameraError::DegenerateUp));
        assert_eq!(Camera { fov_y_deg: f32::NAN, ..cam() }.validate(4096), Err(CameraError::NotFinite));
        assert_eq!(Camera { fov_y_deg: 180.0, ..cam() }.validate(4096), Err(CameraError::BadFieldOfView));
        assert_eq!(Camera { width: 0, ..cam() }.validate(4096), Err(CameraError::BadViewport));
        assert_eq!(Camera { width: 5000, ..cam() }.validate(4096), Err(CameraError::BadViewport));
        assert!(Camera { eye: Vec3::new(1e38, 0.0, 0.0), target: Vec3::new(-1e38, 0.0, 0.0), ..cam() }
            .validate(4096)
            .is_err());
    }

    #[test]
    fn orbit_keeps_distance_and_framing_contains_box() {
        let c = cam();
        let o = c.orbit(30.0, 10.0);
        assert!(((o.eye - o.target).length() - 5.0).abs() < 1e-4);
        assert!(o.eye.x > 0.0 && o.eye.y > 0.0);
        let f = Camera::framing(Vec3::ZERO, Vec3::new(2.0, 3.0, 4.0), 20.0, 10.0, 45.0, 100, 50);
        for corner in 0..8 {
            let p = Vec3::new(
                if corner & 1 == 0 { 0.0 } else { 2.0 },
                if corner & 2 == 0 { 0.0 } else { 3.0 },
                if corner & 4 == 0 { 0.0 } else { 4.0 },
            );
            let (x, y, _) = f.project(p).unwrap();
            assert!((0.0..=100.0).contains(&x) && (0.0..=50.0).contains(&y), "{x} {y}");
        }
    }
}
