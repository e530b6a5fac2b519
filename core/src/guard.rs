//! Guard bands: the client asks the server for a wider view than it
//! displays, at the same pixel density, so that a turn reveals samples already sent instead of
//! empty space.
//!
//! A guard of fraction `g` adds `round(g · width)` pixels left and right and `round(g · height)`
//! above and below, and widens the field of view so each pixel keeps its angular size: the
//! displayed region is the guard camera's pixels `x0..x0 + width`, `y0..y0 + height`, whose rays
//! are the display camera's (up to float rounding). The request camera itself carries the wider
//! view, so the wire needs no change; the cost is `(1 + 2g)²` times the pixels (and about as
//! many more samples and bytes where the volume fills the view; fewer where the band is empty
//! space, which compaction drops).

use crate::camera::Camera;

/// The largest guard fraction per side (the request then has 4× the pixels).
pub const MAX_GUARD: f32 = 0.5;

/// Why a guard band cannot be made.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GuardError {
    /// The fraction is NaN, negative or above [`MAX_GUARD`].
    BadFraction,
    /// The widened viewport would exceed the allowed maximum.
    ViewportTooLarge,
    /// The widened field of view would reach 179° (or the camera is unusable).
    FieldOfViewTooWide,
}

impl core::fmt::Display for GuardError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            GuardError::BadFraction => "guard fraction is not within 0..=0.5",
            GuardError::ViewportTooLarge => "guard band makes the viewport too large",
            GuardError::FieldOfViewTooWide => "guard band makes the field of view too wide",
        })
    }
}

#[cfg(feature = "std")]
impl std::error::Error for GuardError {}

/// A display camera widened by a guard band.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GuardBand {
    /// The camera to request: same eye, target and up, wider view, more pixels.
    pub camera: Camera,
    /// Left edge of the displayed region in the guard camera's pixels.
    pub x0: u32,
    /// Top edge of the displayed region.
    pub y0: u32,
}

impl GuardBand {
    /// `display` widened by `fraction` of its size on every side (see the module docs);
    /// `max_viewport` bounds the widened width and height.
    pub fn new(display: &Camera, fraction: f32, max_viewport: u32) -> Result<GuardBand, GuardError> {
        if !(0.0..=MAX_GUARD).contains(&fraction) {
            return Err(GuardError::BadFraction);
        }
        display.validate(max_viewport).map_err(|_| GuardError::FieldOfViewTooWide)?;
        let gx = libm::roundf(fraction * display.width as f32) as u32;
        let gy = libm::roundf(fraction * display.height as f32) as u32;
        let (w, h) = (display.width + 2 * gx, display.height + 2 * gy);
        if w > max_viewport || h > max_viewport {
            return Err(GuardError::ViewportTooLarge);
        }
        let tan_y = libm::tanf(display.fov_y_deg.to_radians() * 0.5) * h as f32 / display.height as f32;
        let fov = (2.0 * libm::atanf(tan_y)).to_degrees();
        if !(fov < 179.0) {
            return Err(GuardError::FieldOfViewTooWide);
        }
        Ok(GuardBand { camera: Camera { fov_y_deg: fov, width: w, height: h, ..*display }, x0: gx, y0: gy })
    }

    /// Extra pixels over the display's, as a factor (`(1 + 2g)²` up to rounding).
    pub fn pixel_factor(&self, display: &Camera) -> f32 {
        (self.camera.width as f32 * self.camera.height as f32) / (display.width as f32 * display.height as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    fn cam(w: u32, h: u32) -> Camera {
        Camera::look_at(Vec3::new(0.3, 0.2, 3.0), Vec3::ZERO, Vec3::Y, 40.0, w, h)
    }

    #[test]
    fn displayed_region_has_the_display_cameras_rays() {
        for (w, h, g) in [(64, 48, 0.1), (100, 100, 0.25), (33, 71, 0.5), (64, 64, 0.0)] {
            let c = cam(w, h);
            let gb = GuardBand::new(&c, g, 8192).unwrap();
            assert_eq!(gb.camera.width, w + 2 * gb.x0);
            assert_eq!(gb.camera.height, h + 2 * gb.y0);
            let (a, b) = (c.ray_basis(), gb.camera.ray_basis());
            for (x, y) in [(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1), (w / 2, h / 3)] {
                let (d0, d1) = (a.dir(x, y), b.dir(x + gb.x0, y + gb.y0));
                assert!((d0 - d1).length() < 2e-6, "{w}×{h} g={g} ({x},{y}): {d0} vs {d1}");
            }
            let f = gb.pixel_factor(&c);
            assert!((f - (1.0 + 2.0 * g) * (1.0 + 2.0 * g)).abs() < 0.1, "{f}");
        }
    }

    #[test]
    fn bad_fractions_and_limits_are_errors() {
        let c = cam(64, 64);
        for g in [-0.1, 0.51, f32::NAN, f32::INFINITY] {
            assert_eq!(GuardBand::new(&c, g, 8192), Err(GuardError::BadFraction));
        }
        assert_eq!(GuardBand::new(&c, 0.5, 100), Err(GuardError::ViewportTooLarge));
        let wide = Camera { fov_y_deg: 178.5, ..c };
        assert_eq!(GuardBand::new(&wide, 0.5, 8192), Err(GuardError::FieldOfViewTooWide));
        let bad = Camera { eye: Vec3::NAN, ..c };
        assert!(GuardBand::new(&bad, 0.1, 8192).is_err());
    }
}
