//! Which of the frames a client keeps it shows for the camera of now, and how: the frame
//! choice shared by the window client's display loop and the evaluation's session simulator.
//!
//! 1. **Exact**: where a kept frame was rendered for exactly the camera of now (the camera
//!    rests and the server answered the request for it), that frame is shown as it was
//!    rendered, whatever else arrived: no warp can do better than the server's own image.
//! 2. **Warp**: otherwise the kept frames are warped, the one nearest the camera of now
//!    first ([`warp_angle_deg`]: turn, pan and dolly in degrees) and the others filling what
//!    it does not cover. After a prediction overshot (the camera stopped short of where the
//!    client expected it) or a reversal, an older frame is often nearer than the newest one,
//!    and the nearest frame's warp opens the fewest holes. Frames equally near keep their
//!    order, newest first. Frames beyond [`FALLBACK_DEG`] fill nothing: what they saw that the
//!    nearer ones did not lies on the far side (the side view of the other way, after a turn
//!    from rest: at 64² it raised a flick's mean above the stale frame's).
//! 3. **Unwarped**: where even the nearest frame lies more than [`FALLBACK_DEG`] away (a
//!    turn beyond what any frame saw), the warp shows mostly holes and stretched slabs; the
//!    nearest frame is shown as it was rendered instead, resized to the view where its pixels
//!    differ (a frame on the coarser grid of adaptive resolution: warped that far it shows
//!    shreds and scored worse than the stale frame).
//!
//! Everything here is what the client knows: the cameras of the frames it holds and the camera
//! it shows; never the truth.

use crate::camera::Camera;
use crate::warp_radius::warp_angle_deg;
use alloc::vec::Vec;

/// Beyond this warp (degrees, [`warp_angle_deg`]) from the nearest kept frame, the frame is
/// shown unwarped rather than warped.
pub const FALLBACK_DEG: f32 = 60.0;

/// What a client shows for the camera of now.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Show {
    /// Show kept frame `i` (newest first) as rendered: it was rendered for this camera.
    Exact(usize),
    /// Warp the kept frames in this order (indices, newest first): the first is drawn, the
    /// others fill what it does not cover.
    Warp(Vec<usize>),
    /// Show kept frame `i` as rendered although the camera differs: every frame lies beyond
    /// [`FALLBACK_DEG`]; resized to the camera's viewport where its own differs.
    Unwarped(usize),
}

/// The choice for `camera` from the views of the kept frames (`views[i]`: the camera frame `i`
/// shows exactly, newest first). `fallback_deg` is the warp beyond which the nearest frame is
/// shown unwarped ([`FALLBACK_DEG`]; infinite: never). With no frame, an empty warp.
pub fn choose(views: &[Camera], camera: &Camera, fallback_deg: f32) -> Show {
    if let Some(i) = views.iter().position(|v| v == camera) {
        return Show::Exact(i);
    }
    let angles: Vec<f32> = views.iter().map(|v| warp_angle_deg(v, camera)).collect();
    let mut order: Vec<usize> = (0..views.len()).collect();
    // Stable: equally near frames stay newest first (`warp_angle_deg` is never NaN).
    order.sort_by(|&a, &b| angles[a].total_cmp(&angles[b]));
    match order.first() {
        Some(&i) if angles[i] > fallback_deg => Show::Unwarped(i),
        _ => {
            // A frame beyond the fallback angle fills nothing: what it saw that the nearer
            // ones did not lies on the far side (a side view of the other way, behind a turn).
            order.retain(|&i| angles[i] <= fallback_deg);
            Show::Warp(order)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use alloc::vec;
    use glam::Vec3;

    fn cam() -> Camera {
        Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y, 40.0, 64, 64)
    }

    #[test]
    fn an_exact_frame_is_shown_as_rendered_even_when_older() {
        let c = cam();
        let views = [c.orbit(10.0, 0.0), c, c.orbit(-5.0, 0.0)];
        assert_eq!(choose(&views, &c, FALLBACK_DEG), Show::Exact(1));
        // Another viewport or field of view is not the same camera.
        assert_ne!(choose(&[c.with_viewport(32, 32)], &c, FALLBACK_DEG), Show::Exact(0));
    }

    #[test]
    fn the_nearest_frame_is_warped_first_and_ties_keep_newest_first() {
        let c = cam();
        // The newest overshot by 12°, the one before is 3° short.
        let views = [c.orbit(12.0, 0.0), c.orbit(-3.0, 0.0), c.orbit(-20.0, 0.0)];
        assert_eq!(choose(&views, &c, FALLBACK_DEG), Show::Warp(vec![1, 0, 2]));
        let same = [c.orbit(5.0, 0.0), c.orbit(5.0, 0.0)];
        assert_eq!(choose(&same, &c, FALLBACK_DEG), Show::Warp(vec![0, 1]));
        assert_eq!(choose(&[], &c, FALLBACK_DEG), Show::Warp(vec![]));
    }

    #[test]
    fn beyond_the_fallback_the_nearest_frame_is_shown_unwarped() {
        let c = cam();
        let views = [c.orbit(-90.0, 0.0), c.orbit(-70.0, 0.0)];
        assert_eq!(choose(&views, &c, FALLBACK_DEG), Show::Unwarped(1));
        assert_eq!(choose(&views, &c, f32::INFINITY), Show::Warp(vec![1, 0]));
        // A nearest frame with other pixels (adaptive resolution's coarse grid) too: the client
        // shows it resized to the view.
        let coarse = [c.orbit(-90.0, 0.0), c.orbit(-70.0, 0.0).with_viewport(32, 32)];
        assert_eq!(choose(&coarse, &c, FALLBACK_DEG), Show::Unwarped(1));
        // A degenerate view counts as 180° away, never as near.
        let bad = Camera { eye: Vec3::NAN, ..c };
        assert_eq!(choose(&[bad, c.orbit(2.0, 0.0)], &c, FALLBACK_DEG), Show::Warp(vec![1]));
    }

    #[test]
    fn frames_beyond_the_fallback_fill_nothing() {
        // A turn from rest: the side view ahead is near, the rest frame within the fallback,
        // the side view the other way beyond it.
        let c = cam();
        let views = [c.orbit(-84.0, 0.0), c.orbit(-24.0, 0.0), c.orbit(-54.0, 0.0)];
        assert_eq!(choose(&views, &c, FALLBACK_DEG), Show::Warp(vec![1, 2]));
        assert_eq!(choose(&views, &c, f32::INFINITY), Show::Warp(vec![1, 2, 0]), "always warping: all of them");
    }
}
