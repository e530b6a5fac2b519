//! Camera prediction: the camera a client expects to show when the frame it
//! asks for now arrives, extrapolated from its two most recent cameras.
//!
//! **Orbit-aware.** A volwarp camera moves about its target (drag to orbit, wheel to dolly), so
//! the eye is extrapolated in spherical coordinates about the target, not along a straight
//! line: azimuth about the newest camera's up axis and elevation change at constant angular
//! velocity, the distance at [`ZOOM_GAIN`] of its recent *rate* (a dolly by a factor per step),
//! and the target itself at constant velocity. A camera that orbits at constant speed is
//! therefore predicted exactly, up to float rounding; a dolly is predicted at half its rate,
//! because dollies reverse (a wheel in, then out) and a frame predicted too far in shows
//! nothing beyond its narrower view once the camera backs out (measured below). Up, field of
//! view and viewport are the newest camera's.
//!
//! **Bounded.** The horizon is clamped to [`MAX_HORIZON_S`], the extrapolated turn to
//! [`MAX_TURN_DEG`] per axis and the zoom to [`MAX_ZOOM`]× either way; the elevation stays
//! [`POLE_MARGIN_DEG`] off the poles. Anything that is not finite, a non-positive time step or
//! a predicted camera that does not validate gives back the newest camera unchanged: never NaN.

use crate::camera::Camera;
use glam::Vec3;

/// The longest horizon extrapolated, in seconds.
pub const MAX_HORIZON_S: f32 = 1.0;
/// The largest extrapolated azimuth or elevation change, in degrees.
pub const MAX_TURN_DEG: f32 = 90.0;
/// The fraction of the recent zoom rate that is extrapolated (1: all of it). Measured in the
/// session simulator (`docs/results.md`, "Dolly prediction: half the zoom rate"; the dolly scenario, 512², all
/// five datasets, the default method): mean ꟻLIP 0.0140 with the full rate, 0.0127 with none,
/// 0.0116 with half, the lowest on every dataset.
pub const ZOOM_GAIN: f32 = 0.5;
/// The largest extrapolated zoom factor (either way).
pub const MAX_ZOOM: f32 = 4.0;
/// How far from straight above or below the target the predicted eye stays, in degrees.
pub const POLE_MARGIN_DEG: f32 = 1.0;

/// A camera and the time it was shown, in seconds on any clock.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimedCamera {
    /// The camera.
    pub camera: Camera,
    /// When, in seconds.
    pub t: f64,
}

/// The eye about the target in spherical coordinates over an orthonormal frame `(e1, e2, up)`.
struct Spherical {
    azimuth: f32,
    elevation: f32,
    distance: f32,
}

fn spherical(rel: Vec3, e1: Vec3, e2: Vec3, up: Vec3) -> Option<Spherical> {
    let distance = rel.length();
    if !(distance > 1e-20) || !distance.is_finite() {
        return None;
    }
    let s = (rel.dot(up) / distance).clamp(-1.0, 1.0);
    Some(Spherical { azimuth: libm::atan2f(rel.dot(e2), rel.dot(e1)), elevation: libm::asinf(s), distance })
}

/// An angle difference wrapped into `(-π, π]`.
fn wrap(a: f32) -> f32 {
    let two_pi = 2.0 * core::f32::consts::PI;
    let mut a = a % two_pi;
    if a > core::f32::consts::PI {
        a -= two_pi;
    } else if a <= -core::f32::consts::PI {
        a += two_pi;
    }
    a
}

/// The camera expected `horizon_s` seconds after `newest`, extrapolating the motion from
/// `previous` to `newest` (see the module docs). Returns `newest.camera` for a zero horizon, a
/// stationary camera or anything unusable.
pub fn predict(previous: &TimedCamera, newest: &TimedCamera, horizon_s: f32) -> Camera {
    let cur = newest.camera;
    let dt = (newest.t - previous.t) as f32;
    let h = if horizon_s.is_finite() { horizon_s.clamp(0.0, MAX_HORIZON_S) } else { 0.0 };
    let still = previous.camera.eye == cur.eye && previous.camera.target == cur.target;
    if !(dt > 1e-6) || !dt.is_finite() || h == 0.0 || still {
        return cur;
    }
    let up = cur.up.normalize_or_zero();
    if up == Vec3::ZERO {
        return cur;
    }
    let e1 = up.any_orthonormal_vector();
    let e2 = up.cross(e1);
    let (Some(a), Some(b)) = (
        spherical(previous.camera.eye - previous.camera.target, e1, e2, up),
        spherical(cur.eye - cur.target, e1, e2, up),
    ) else {
        return cur;
    };
    let k = h / dt;
    let max_turn = MAX_TURN_DEG.to_radians();
    let d_az = (wrap(b.azimuth - a.azimuth) * k).clamp(-max_turn, max_turn);
    let d_el = ((b.elevation - a.elevation) * k).clamp(-max_turn, max_turn);
    let pole = core::f32::consts::FRAC_PI_2 - POLE_MARGIN_DEG.to_radians();
    let el = (b.elevation + d_el).clamp(-pole, pole);
    let az = b.azimuth + d_az;
    let zoom = libm::powf(b.distance / a.distance, k * ZOOM_GAIN).clamp(1.0 / MAX_ZOOM, MAX_ZOOM);
    let dist = b.distance * zoom;
    let target = cur.target + (cur.target - previous.camera.target) * k;
    let (ce, se) = (libm::cosf(el), libm::sinf(el));
    let dir = e1 * (ce * libm::cosf(az)) + e2 * (ce * libm::sinf(az)) + up * se;
    let predicted = Camera { eye: target + dir * dist, target, ..cur };
    match predicted.validate(u32::MAX) {
        Ok(()) => predicted,
        Err(_) => cur,
    }
}

/// The two most recent cameras of a moving view, for [`predict`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Predictor {
    previous: Option<TimedCamera>,
    newest: Option<TimedCamera>,
}

impl Predictor {
    /// No camera seen yet.
    pub const fn new() -> Self {
        Predictor { previous: None, newest: None }
    }

    /// Records the camera shown at `t` seconds. A camera equal to the newest one only moves
    /// the newest one's time forward when the view has stopped (so a still view predicts no
    /// motion); a time that does not increase is ignored.
    pub fn observe(&mut self, camera: Camera, t: f64) {
        if let Some(n) = self.newest {
            if !(t > n.t) {
                return;
            }
            if n.camera == camera {
                // Still: the motion from `previous` is over once the view has held still.
                self.previous = Some(n);
                self.newest = Some(TimedCamera { camera, t });
                return;
            }
        }
        self.previous = self.newest;
        self.newest = Some(TimedCamera { camera, t });
    }

    /// How fast the view turns, degrees per second: core's `warp_radius::warp_angle_deg`
    /// between the last two cameras seen over the time between them (0 with fewer than two, or
    /// where that is not finite).
    pub fn turn_rate_deg_s(&self) -> f32 {
        let (Some(p), Some(n)) = (self.previous, self.newest) else { return 0.0 };
        let rate = crate::warp_radius::warp_angle_deg(&p.camera, &n.camera) as f64 / (n.t - p.t);
        if rate.is_finite() && rate > 0.0 {
            rate as f32
        } else {
            0.0
        }
    }

    /// The camera expected `horizon_s` after the newest one (the newest itself with fewer than
    /// two cameras seen); `None` before any.
    pub fn predict(&self, horizon_s: f32) -> Option<Camera> {
        let n = self.newest?;
        Some(match self.previous {
            Some(p) => predict(&p, &n, horizon_s),
            None => n.camera,
        })
    }
}

/// How far ahead to predict: the time from sending a request to showing its frame, measured
/// from the frames that arrived, plus half the interval between frames.
///
/// A frame is shown from its arrival until the next one arrives, so the camera that minimises
/// the mean warp over that stretch is the one of its middle: `request→arrival + interval / 2`
/// (less half a display tick, see [`Horizon::seconds`]).
/// Both terms are exponential moving averages (weight [`Horizon::WEIGHT`] for the newest
/// measurement); before the first frame the horizon is 0 (no prediction). A client measures its
/// first frame too (the one it shows before the camera moves), so it predicts from the start.
///
/// Each frame also carries the server's own time for it (the frame header's `render_us`), which
/// splits a span into the render and the rest: the round trip and the transfer, taken to be
/// half each (the client cannot tell them apart from one frame).
///
/// The interval is measured between arrivals whose later frame was asked for before the
/// earlier arrived (the server had it in hand). Until such a pair of a class has arrived, the
/// interval is taken to be the render plus the transfer (a server that renders the newest
/// request as soon as the last frame is written delivers them that far apart):
/// `render + (span − render) / 2`, or the whole span where no render time was reported.
///
/// Frames at full resolution and frames on each coarser grid of adaptive resolution (2 and 4
/// times coarser per axis) are measured apart: a coarse frame is marched and sent in a fraction
/// of a full one's time. Until a frame of its grid has arrived, a coarse request's horizon comes
/// from the full frames': with a divisor `d`
/// per axis, the render and the transfer scale with the pixels (`1/d²`), the round trip does
/// not, and the first coarse frame corrects it. Without a reported render time, the full
/// frames' span and interval over `d` stand in. Over `d`, the fast flick's first coarse frame
/// (512², server 500 ms, 100 Mbit/s) was predicted 0.47 s ahead where it took 0.26 s to come
/// and was shown for 0.16 s, and overshot the flick's end; over `d²` for everything, the first
/// coarse frames were predicted too short and warped up to 10° on a steady turn
/// (`docs/results.md`, "Adaptive resolution").
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Horizon {
    /// Request-to-arrival, interval and render averages: of full-resolution frames, of frames
    /// on the grid 2 times coarser per axis, of those 4 times coarser ([`Horizon::class`]).
    classes: [Spans; 3],
    last_arrival_s: Option<f64>,
}

/// One class of frames' moving averages (0: nothing measured).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Spans {
    request_to_arrival_s: f64,
    interval_s: f64,
    /// The server's own time per frame (0: not reported).
    render_s: f64,
}

impl Spans {
    const NONE: Spans = Spans { request_to_arrival_s: 0.0, interval_s: 0.0, render_s: 0.0 };

    fn measured(&self) -> bool {
        self.request_to_arrival_s > 0.0 || self.interval_s > 0.0
    }

    /// The render time, where one was reported and it fits in the span.
    fn render(&self) -> Option<f64> {
        (self.render_s > 0.0 && self.render_s <= self.request_to_arrival_s).then_some(self.render_s)
    }

    /// `(request to arrival, interval)`, the interval estimated where it was not measured.
    fn span_and_interval(&self) -> (f64, f64) {
        let span = self.request_to_arrival_s;
        let interval =
            if self.interval_s > 0.0 { self.interval_s } else { self.render().map_or(span, |r| r + 0.5 * (span - r)) };
        (span, interval)
    }

    /// A class on a grid `divisor` times coarser per axis estimated from this one's (see
    /// [`Horizon`]).
    fn coarser(&self, divisor: u32) -> (f64, f64) {
        let d = f64::from(divisor.max(1));
        let (span, interval) = self.span_and_interval();
        match self.render() {
            Some(r) => {
                let pixels = 1.0 / (d * d);
                let rest = span - r;
                // The round trip (half the rest) stays; the render and the transfer scale.
                (r * pixels + rest * 0.5 * (1.0 + pixels), (r + 0.5 * rest) * pixels)
            }
            None => (span / d, interval / d),
        }
    }
}

impl Horizon {
    /// Weight of the newest measurement in the moving averages.
    pub const WEIGHT: f64 = 0.25;

    /// Nothing measured yet.
    pub const fn new() -> Self {
        Horizon { classes: [Spans::NONE; 3], last_arrival_s: None }
    }

    /// The class of frames on a grid `divisor` times coarser per axis: 0 for the full
    /// resolution, 1 for 2 (and 3), 2 for 4 and more.
    fn class(divisor: u32) -> usize {
        match divisor {
            0 | 1 => 0,
            2 | 3 => 1,
            _ => 2,
        }
    }

    /// Records a frame whose request was sent at `requested_s` and that arrived (is ready to
    /// show) at `arrived_s`, on any clock in seconds, which the server reported rendering in
    /// `render_s` seconds (the header's `render_us`; 0: not reported), on a grid `divisor` times
    /// coarser per axis than the view (1: full resolution; adaptive resolution's 2 or 4).
    /// Non-finite or negative spans and times are ignored.
    pub fn observe(&mut self, requested_s: f64, arrived_s: f64, render_s: f64, divisor: u32) {
        let ema = |old: f64, new: f64| if old == 0.0 { new } else { old + (new - old) * Self::WEIGHT };
        let c = &mut self.classes[Self::class(divisor)];
        let span = arrived_s - requested_s;
        if span.is_finite() && span >= 0.0 {
            c.request_to_arrival_s = ema(c.request_to_arrival_s, span);
            if render_s.is_finite() && render_s > 0.0 {
                c.render_s = ema(c.render_s, render_s);
            }
        }
        // The gap since the last arrival is an interval only if this frame's request was out
        // before it: otherwise it counts time the client asked for nothing (a view at rest).
        if let Some(last) = self.last_arrival_s.filter(|&last| requested_s < last) {
            let gap = arrived_s - last;
            if gap.is_finite() && gap > 0.0 {
                c.interval_s = ema(c.interval_s, gap);
            }
        }
        if arrived_s.is_finite() {
            self.last_arrival_s = Some(arrived_s);
        }
    }

    /// The horizon in seconds of a request on a grid `divisor` times coarser per axis (1: full
    /// resolution) for a display that shows a new image every `display_s` seconds (clamped to
    /// [`MAX_HORIZON_S`]): a frame is on screen at the display ticks from its arrival until the
    /// next frame's, on average `(interval − display_s) / 2` after its arrival (0 when frames
    /// come at least once per tick). Where the class's interval or the class itself was not
    /// measured yet, they are estimated as [`Horizon`] says.
    pub fn seconds(&self, display_s: f32, divisor: u32) -> f32 {
        let class = Self::class(divisor);
        let own = self.classes[class];
        let (span, interval) = if own.measured() {
            own.span_and_interval()
        } else if class > 0 && self.classes[0].measured() {
            self.classes[0].coarser(divisor)
        } else {
            // Nothing of this grid or the full one: another grid's as it is.
            self.classes.iter().find(|c| c.measured()).copied().unwrap_or(Spans::NONE).span_and_interval()
        };
        let display = if display_s.is_finite() { display_s.max(0.0) as f64 } else { 0.0 };
        let shown = 0.5 * (interval - display).max(0.0);
        ((span + shown) as f32).clamp(0.0, MAX_HORIZON_S)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: &Camera, b: &Camera, tol: f32) -> bool {
        (a.eye - b.eye).length() <= tol && (a.target - b.target).length() <= tol && a.up == b.up
    }

    fn base() -> Camera {
        Camera::framing(Vec3::ZERO, Vec3::new(2.0, 3.0, 1.5), 30.0, 20.0, 40.0, 64, 48)
    }

    #[test]
    fn exact_on_constant_velocity_orbits_and_dollies_at_the_zoom_gain() {
        let c0 = base();
        // 30 °/s yaw, 10 °/s pitch, zoom by 0.9 per 0.1 s, each on its own and, for yaw, with a
        // dolly at the same time: (yaw °/s, pitch °/s, zoom factor per 0.1 s).
        let paths = [
            ("yaw", 30.0, 0.0, 1.0),
            ("pitch", 0.0, 10.0, 1.0),
            ("dolly", 0.0, 0.0, 0.9),
            ("yaw+dolly", -45.0, 0.0, 1.1),
        ];
        for (name, yaw, pitch, zoom) in paths {
            // The turn at time `t`, the dolly at time `z`.
            let at = |t: f32, z: f32| c0.orbit(yaw * t, pitch * t).dolly(libm::powf(zoom, z / 0.1));
            for (t0, t1, h) in [(0.0, 0.033, 0.1), (0.2, 0.25, 0.55), (1.0, 1.1, 0.2)] {
                let prev = TimedCamera { camera: at(t0, t0), t: t0 as f64 };
                let cur = TimedCamera { camera: at(t1, t1), t: t1 as f64 };
                let got = predict(&prev, &cur, h);
                // The turn extrapolated in full, the dolly at `ZOOM_GAIN` of its rate.
                let want = at(t1 + h, t1 + h * ZOOM_GAIN);
                let scale = (want.eye - want.target).length();
                assert!(close(&got, &want, 2e-4 * scale), "{name} {t0}->{t1} +{h}: {got:?} vs {want:?}");
            }
        }
    }

    #[test]
    fn moving_target_is_extrapolated_linearly() {
        let c0 = base();
        let shift = |c: &Camera, d: Vec3| Camera { eye: c.eye + d, target: c.target + d, ..*c };
        let prev = TimedCamera { camera: c0, t: 0.0 };
        let cur = TimedCamera { camera: shift(&c0, Vec3::new(0.1, 0.0, -0.2)), t: 0.1 };
        let got = predict(&prev, &cur, 0.2);
        assert!(close(&got, &shift(&c0, Vec3::new(0.3, 0.0, -0.6)), 1e-4), "{got:?}");
    }

    #[test]
    fn stationary_reversal_and_bad_input_give_finite_cameras() {
        let c0 = base();
        let t = |camera, t| TimedCamera { camera, t };
        // Stationary: exactly the newest camera.
        assert_eq!(predict(&t(c0, 0.0), &t(c0, 0.1), 0.3), c0);
        // A reversal: the last step's direction is extrapolated, never NaN, within the limit.
        let a = c0.orbit(5.0, 0.0);
        let got = predict(&t(a, 0.0), &t(c0, 0.05), 0.5);
        assert!(got.validate(u32::MAX).is_ok());
        assert!(close(&got, &c0.orbit(-50.0, 0.0), 1e-3 * (c0.eye - c0.target).length()), "{got:?}");
        let got = predict(&t(a, 0.0), &t(c0, 0.01), 0.5);
        assert!(close(&got, &c0.orbit(-MAX_TURN_DEG, 0.0), 1e-3 * (c0.eye - c0.target).length()), "{got:?}");
        // Zero, negative, NaN or infinite time steps and horizons: the newest camera.
        for (t0, t1, h) in
            [(0.0, 0.0, 0.1), (1.0, 0.5, 0.1), (f64::NAN, 0.1, 0.1), (0.0, 0.1, f32::NAN), (0.0, 0.1, -1.0)]
        {
            assert_eq!(predict(&t(a, t0), &t(c0, t1), h), c0);
        }
        // A huge horizon is clamped; a far zoom is bounded.
        let got = predict(&t(c0.dolly(0.01), 0.0), &t(c0, 0.01), f32::INFINITY);
        assert_eq!(got, c0, "an infinite horizon is not extrapolated");
        let got = predict(&t(c0.dolly(0.01), 0.0), &t(c0, 0.01), 10.0);
        let d = (got.eye - got.target).length() / (c0.eye - c0.target).length();
        assert!((d - MAX_ZOOM).abs() < 1e-3, "{d}");
        // Over the pole: the elevation stays off it.
        let high = c0.orbit(0.0, 80.0);
        let got = predict(&t(c0, 0.0), &t(high, 0.1), 0.5);
        assert!(got.validate(u32::MAX).is_ok(), "{got:?}");
        // A NaN camera (which validate rejects upstream) still gives a finite answer.
        let nan = Camera { eye: Vec3::NAN, ..c0 };
        assert_eq!(predict(&t(nan, 0.0), &t(c0, 0.1), 0.2), c0);
    }

    #[test]
    fn predictor_keeps_two_cameras_and_stops_with_the_view() {
        let c0 = base();
        let mut p = Predictor::new();
        assert_eq!(p.predict(0.1), None);
        p.observe(c0, 0.0);
        assert_eq!(p.predict(0.1), Some(c0));
        let c1 = c0.orbit(3.0, 0.0);
        p.observe(c1, 0.1);
        let got = p.predict(0.1).unwrap();
        assert!(close(&got, &c0.orbit(6.0, 0.0), 1e-3), "{got:?}");
        p.observe(c1, 0.05); // time going back: ignored
        assert!(close(&p.predict(0.1).unwrap(), &got, 0.0));
        p.observe(c1, 0.2); // held still: no motion predicted
        assert_eq!(p.predict(0.1), Some(c1));
    }

    #[test]
    fn horizon_is_request_to_arrival_plus_half_the_interval() {
        let mut h = Horizon::new();
        assert_eq!(h.seconds(0.0, 1), 0.0);
        // One frame: its request-to-arrival stands in for the interval too.
        h.observe(-0.6, 0.0, 0.0, 1);
        assert!((h.seconds(0.0, 1) - 0.9).abs() < 1e-6, "{}", h.seconds(0.0, 1));
        assert!((h.seconds(0.2, 1) - 0.8).abs() < 1e-6, "{}", h.seconds(0.2, 1));
        let mut h = Horizon::new();
        // Frames requested every 0.5 s, each arriving 0.6 s later: 0.6 + 0.25.
        for k in 0..40 {
            let t = k as f64 * 0.5;
            h.observe(t, t + 0.6, 0.0, 1);
        }
        assert!((h.seconds(0.0, 1) - 0.85).abs() < 1e-4, "{}", h.seconds(0.0, 1));
        // Frames at least once per display tick: request-to-arrival only.
        assert!((h.seconds(0.5, 1) - 0.6).abs() < 1e-4, "{}", h.seconds(0.5, 1));
        assert!((h.seconds(f32::NAN, 1) - 0.85).abs() < 1e-4);
        // Garbage is ignored, and a huge latency is clamped.
        h.observe(f64::NAN, 1.0, f64::NAN, 1);
        h.observe(5.0, 4.0, -1.0, 1);
        assert!(h.seconds(0.0, 1).is_finite());
        // A frame asked for after the last one arrived (the view rested in between): its gap
        // is not an interval.
        let mut idle = Horizon::new();
        idle.observe(-0.6, 0.0, 0.0, 1);
        idle.observe(5.0, 5.6, 0.0, 1);
        assert!((idle.seconds(0.0, 1) - 0.9).abs() < 1e-6, "{}", idle.seconds(0.0, 1));
        let mut slow = Horizon::new();
        slow.observe(0.0, 30.0, 0.0, 1);
        assert_eq!(slow.seconds(0.016, 1), MAX_HORIZON_S);
    }

    #[test]
    fn coarse_frames_have_their_own_horizon() {
        let mut h = Horizon::new();
        // The first frame at full resolution: 0.6 s from request to arrival.
        h.observe(-0.6, 0.0, 0.0, 1);
        // A coarse request before any coarse frame: the full frame's time over d (0.3 s,
        // interval alike), plus half the interval.
        assert!((h.seconds(0.0, 2) - 0.45).abs() < 1e-6, "{}", h.seconds(0.0, 2));
        assert!((h.seconds(0.0, 4) - 0.225).abs() < 1e-6, "{}", h.seconds(0.0, 4));
        assert!((h.seconds(0.0, 1) - 0.9).abs() < 1e-6);
        // Coarse frames measured: their own figures, the full frames' unchanged.
        for k in 1..40 {
            let t = k as f64 * 0.2;
            h.observe(t - 0.3, t, 0.0, 2);
        }
        assert!((h.seconds(0.0, 2) - 0.4).abs() < 1e-3, "{}", h.seconds(0.0, 2));
        assert!((h.seconds(0.0, 1) - 0.9).abs() < 1e-6, "{}", h.seconds(0.0, 1));
        // The grid 4 times coarser is measured apart: until one of its frames came, the full
        // frames' over 4; then its own.
        assert!((h.seconds(0.0, 4) - 0.225).abs() < 1e-6, "{}", h.seconds(0.0, 4));
        h.observe(7.9, 8.0, 0.0, 4);
        // 0.1 s from request to arrival, and as the interval (none measured on this grid).
        assert!((h.seconds(0.0, 4) - 0.15).abs() < 1e-6, "{}", h.seconds(0.0, 4));
        assert!((h.seconds(0.0, 2) - 0.4).abs() < 1e-3, "the other grid's unchanged: {}", h.seconds(0.0, 2));
        // Only coarse frames measured: a full request takes theirs.
        let mut c = Horizon::new();
        c.observe(0.0, 0.3, 0.0, 2);
        assert!((c.seconds(0.0, 1) - 0.45).abs() < 1e-6);
        assert!((c.seconds(0.0, 4) - 0.45).abs() < 1e-6, "{}", c.seconds(0.0, 4));
    }

    #[test]
    fn a_reported_render_time_splits_the_span() {
        // The first frame: 0.656 s from request to arrival, 0.5 s of it the server's render.
        let mut h = Horizon::new();
        h.observe(-0.656, 0.0, 0.5, 1);
        // Its own class: the interval is the render and half the rest (the transfer).
        let full = 0.656 + 0.5 * (0.5 + 0.078);
        assert!((h.seconds(0.0, 1) - full as f32).abs() < 1e-6, "{}", h.seconds(0.0, 1));
        // A coarse request (d = 2): the render and the transfer at a quarter, the round trip
        // (half the rest) whole: span 0.125 + 0.078 + 0.0195, interval 0.125 + 0.0195.
        let (span, interval) = (0.125 + 0.078 + 0.0195, 0.125 + 0.0195);
        let want = span + 0.5 * (interval - 1.0 / 30.0);
        assert!((h.seconds(1.0 / 30.0, 2) - want as f32).abs() < 1e-6, "{} vs {want}", h.seconds(1.0 / 30.0, 2));
        // Shorter than the full frame's span over d, which overshot a fast flick's end.
        let mut plain = Horizon::new();
        plain.observe(-0.656, 0.0, 0.0, 1);
        assert!(h.seconds(1.0 / 30.0, 2) < plain.seconds(1.0 / 30.0, 2) - 0.1);
        // A render time longer than the span, or not finite, is not used.
        for bad in [0.9, f64::NAN, f64::INFINITY] {
            let mut b = Horizon::new();
            b.observe(-0.656, 0.0, bad, 1);
            assert_eq!(b.seconds(1.0 / 30.0, 2), plain.seconds(1.0 / 30.0, 2), "{bad}");
        }
    }
}
