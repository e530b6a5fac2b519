//! Camera controls: orbit, pan and zoom around the volume, from mouse drags, the wheel and keys.
//! Pure functions of the input, so they are tested without a window.

use volwarp_core::sample::Bounds;
use volwarp_core::{Camera, Vec3};

/// Degrees of orbit per pixel of mouse drag.
pub const ORBIT_DEG_PER_PIXEL: f32 = 0.4;
/// Degrees of orbit per second while an arrow key is held.
pub const ORBIT_DEG_PER_SECOND: f32 = 90.0;
/// Zoom factor per wheel step (distance is multiplied by it, or divided when zooming out).
pub const ZOOM_PER_STEP: f32 = 0.9;

/// The home view of a volume box: framed entirely, seen from its `+y` side with `+z` up and a
/// 30° field of view — the same view as the server's `default_camera` (the front of a head in
/// RAS orientation).
pub fn home_camera(bounds: &Bounds, width: u32, height: u32) -> Camera {
    let f = Camera::framing(bounds.min(), bounds.max(), 0.0, 0.0, 30.0, width, height);
    let dist = (f.eye - f.target).length();
    Camera::look_at(f.target + Vec3::Y * dist, f.target, Vec3::Z, 30.0, width, height)
}

/// The interactive camera.
#[derive(Clone, Debug)]
pub struct Controls {
    /// The current camera.
    pub camera: Camera,
    home: Camera,
    min_dist: f32,
    max_dist: f32,
}

impl Controls {
    /// Controls starting at (and resetting to) `home`.
    pub fn new(home: Camera) -> Controls {
        let d = (home.eye - home.target).length().max(1e-6);
        Controls { camera: home, home, min_dist: d * 0.05, max_dist: d * 20.0 }
    }

    /// Back to the home view (keeping the viewport).
    pub fn reset(&mut self) {
        self.camera = self.home.with_viewport(self.camera.width, self.camera.height);
    }

    /// A new viewport size.
    pub fn resize(&mut self, width: u32, height: u32) {
        self.camera = self.camera.with_viewport(width.max(1), height.max(1));
    }

    /// Orbits by a mouse drag of `(dx, dy)` pixels (drag right turns the volume right, drag
    /// down looks from higher up).
    pub fn orbit_pixels(&mut self, dx: f32, dy: f32) {
        self.orbit_deg(-dx * ORBIT_DEG_PER_PIXEL, dy * ORBIT_DEG_PER_PIXEL);
    }

    /// Orbits by `yaw` and `pitch` degrees.
    pub fn orbit_deg(&mut self, yaw: f32, pitch: f32) {
        if yaw.is_finite() && pitch.is_finite() {
            self.camera = self.camera.orbit(yaw, pitch);
        }
    }

    /// World size of one pixel at the target's distance.
    fn pixel_size(&self) -> f32 {
        let dist = (self.camera.eye - self.camera.target).length();
        2.0 * dist * (self.camera.fov_y_deg.to_radians() * 0.5).tan() / self.camera.height.max(1) as f32
    }

    /// Pans by a mouse drag of `(dx, dy)` pixels: the volume follows the mouse.
    pub fn pan_pixels(&mut self, dx: f32, dy: f32) {
        let s = self.pixel_size();
        if (dx * s).is_finite() && (dy * s).is_finite() {
            self.camera = self.camera.pan(-dx * s, dy * s);
        }
    }

    /// Zooms by wheel `steps` (positive: closer), keeping the distance within 0.05× to 20× of
    /// the home distance.
    pub fn zoom(&mut self, steps: f32) {
        if !steps.is_finite() || steps == 0.0 {
            return;
        }
        let d = (self.camera.eye - self.camera.target).length();
        let nd = (d * ZOOM_PER_STEP.powf(steps.clamp(-20.0, 20.0))).clamp(self.min_dist, self.max_dist);
        self.camera = self.camera.dolly(nd / d);
    }

    /// Applies held keys for `dt` seconds: arrows orbit, WASD pans (a fifth of the view per
    /// second), `zoom_in`/`zoom_out` zoom two steps per second.
    pub fn keys(&mut self, dt: f32, held: &HeldKeys) {
        let dt = dt.clamp(0.0, 0.25);
        let a = ORBIT_DEG_PER_SECOND * dt;
        let axis = |neg: bool, pos: bool| (pos as i32 - neg as i32) as f32;
        self.orbit_deg(axis(held.left, held.right) * -a, axis(held.down, held.up) * a);
        let p = self.camera.height as f32 * 0.2 * dt;
        self.pan_pixels(axis(held.a, held.d) * -p, axis(held.w, held.s) * -p);
        self.zoom(axis(held.zoom_out, held.zoom_in) * 2.0 * dt);
    }
}

/// Which movement keys are held.
#[derive(Clone, Copy, Debug, Default)]
pub struct HeldKeys {
    /// Left arrow.
    pub left: bool,
    /// Right arrow.
    pub right: bool,
    /// Up arrow.
    pub up: bool,
    /// Down arrow.
    pub down: bool,
    /// W (pan up).
    pub w: bool,
    /// A (pan left).
    pub a: bool,
    /// S (pan down).
    pub s: bool,
    /// D (pan right).
    pub d: bool,
    /// `+` / `=`.
    pub zoom_in: bool,
    /// `-`.
    pub zoom_out: bool,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn home() -> Camera {
        home_camera(&Bounds::new(Vec3::ZERO, Vec3::new(1.0, 1.0, 1.5)), 200, 100)
    }

    #[test]
    fn home_frames_the_box_from_plus_y() {
        let c = home();
        assert!(c.validate(4096).is_ok());
        assert!((c.target - Vec3::new(0.5, 0.5, 0.75)).length() < 1e-5);
        assert!(c.eye.y > 1.0 && (c.eye.x - 0.5).abs() < 1e-5);
        for i in 0..8 {
            let p = Vec3::new((i & 1) as f32, ((i >> 1) & 1) as f32, 1.5 * ((i >> 2) & 1) as f32);
            let (x, y, _) = c.project(p).unwrap();
            assert!((0.0..=200.0).contains(&x) && (0.0..=100.0).contains(&y));
        }
    }

    #[test]
    fn orbit_pan_zoom_move_the_camera_as_expected() {
        let mut k = Controls::new(home());
        let d0 = (k.camera.eye - k.camera.target).length();
        k.orbit_pixels(50.0, 0.0);
        assert!(((k.camera.eye - k.camera.target).length() - d0).abs() < 1e-4, "orbit keeps the distance");
        assert!(k.camera.eye != home().eye);
        k.reset();
        assert_eq!(k.camera, home());
        // Pan: the target point moves with the mouse (drag right: the target goes left).
        let before = k.camera.project(home().target).unwrap();
        k.pan_pixels(10.0, 0.0);
        let after = k.camera.project(home().target).unwrap();
        assert!((after.0 - before.0 - 10.0).abs() < 0.05, "{before:?} {after:?}");
        k.reset();
        k.zoom(1.0);
        assert!(((k.camera.eye - k.camera.target).length() - d0 * ZOOM_PER_STEP).abs() < 1e-4);
        k.zoom(1000.0);
        assert!((k.camera.eye - k.camera.target).length() >= d0 * 0.05 - 1e-4);
        k.zoom(f32::NAN);
        assert!(k.camera.validate(4096).is_ok());
        k.resize(64, 32);
        assert_eq!((k.camera.width, k.camera.height), (64, 32));
        let before = k.camera;
        k.keys(0.1, &HeldKeys { right: true, ..Default::default() });
        assert!(k.camera.eye != before.eye);
    }
}
