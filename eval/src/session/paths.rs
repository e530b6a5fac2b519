//! Camera paths over time: what the user does with the mouse during a session.
//!
//! Every path starts at the dataset's default camera C0 (at the session's viewport size) and is
//! a function of time in seconds. Each built-in scenario takes a speed in degrees per second
//! (default [`DEFAULT_SPEED`]); a recorded path replays the cameras the window client displayed
//! (`volwarp-client --record`), holding each until the next one.

use crate::ErrorBox;
use std::path::{Path, PathBuf};
use volwarp_core::record::{read_entry, read_magic, Entry};
use volwarp_core::wire::Limits;
use volwarp_core::Camera;

/// The default speed of the built-in scenarios, degrees per second.
pub const DEFAULT_SPEED: f32 = 30.0;

/// The scenarios `--all` and the default run: steady orbit, stop-and-go, dolly, look-around.
pub const DEFAULT_SCENARIOS: [&str; 4] = ["orbit", "stop-and-go", "dolly", "look-around"];

/// The flick's default speed, degrees per second.
pub const FLICK_SPEED: f32 = 180.0;
/// How long the flick turns, seconds.
pub const FLICK_S: f64 = 0.5;
/// The distance the zoom ends at, as a fraction of the start's.
pub const ZOOM_TO: f64 = 0.35;
/// How long the zoom takes at speed 30, seconds.
pub const ZOOM_S: f64 = 1.5;

/// When the window/level drag of `wl-drag` starts, seconds.
pub const WL_DRAG_START_S: f64 = 1.0;
/// How long the window/level drag lasts, seconds.
pub const WL_DRAG_S: f64 = 1.0;
/// Window and level (fractions of the value range) before the drag: the whole range.
pub const WL_FROM: [f32; 2] = [1.0, 0.5];
/// Window and level at the end of the drag (then held).
pub const WL_TO: [f32; 2] = [0.6, 0.4];

/// The scenarios users produce besides the four: a fast flick (180°/s for 0.5 s, then rest),
/// a zoom into detail (then rest) and a window/level drag during an orbit.
pub const USER_SCENARIOS: [&str; 3] = ["flick", "zoom", "wl-drag"];

/// The largest viewport side a recorded camera may have (and the session size).
pub const MAX_RECORDED_VIEWPORT: u32 = 4096;

/// What the camera does.
#[derive(Clone, Debug, PartialEq)]
pub enum PathKind {
    /// Steady orbit around the volume's centre.
    Orbit,
    /// Orbit with stops and reversals: 1.5 s forward, 1 s still, 1.5 s backward, 0.5 s still,
    /// then forward again (a 6 s pattern that repeats).
    StopAndGo,
    /// Dolly in to 0.7× the distance and out to 1.3× (a sine of period 6 s at speed 30).
    Dolly,
    /// Yaw at the speed, pitch ±15° (period 4 s) and zoom ±15 % (period 3 s) at once.
    LookAround,
    /// A fast flick: orbit at the speed (default [`FLICK_SPEED`]) for [`FLICK_S`] seconds,
    /// then rest.
    Flick,
    /// A zoom into detail: dolly in to [`ZOOM_TO`] of the distance over [`ZOOM_S`] seconds
    /// (eased in and out; at speed 30), then rest.
    Zoom,
    /// A window/level drag during a steady orbit: the camera orbits at the speed while the
    /// window and level move linearly from [`WL_FROM`] to [`WL_TO`] between
    /// [`WL_DRAG_START_S`] and [`WL_DRAG_START_S`] + [`WL_DRAG_S`], then hold (what a user
    /// does with Ctrl+drag in the window while the view turns).
    WindowLevelDrag,
    /// Cameras recorded by the window client, `(seconds, camera)` in time order.
    Recorded(Vec<(f64, Camera)>),
}

/// A camera path: a scenario and its speed.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraPath {
    /// The scenario's name as given (`orbit`, `orbit:60`, `record:run.vwrec`).
    pub name: String,
    /// What the camera does.
    pub kind: PathKind,
    /// Degrees per second (or the time scale, speed / 30, of the dolly and look-around).
    pub speed: f32,
}

/// Why a scenario could not be used.
#[derive(Debug)]
pub enum PathError {
    /// Not one of the known scenarios.
    Unknown(String),
    /// The speed after `:` is not a finite number.
    BadSpeed(String),
    /// The record file could not be read (truncated, not a record file).
    Record(PathBuf, String),
    /// A recorded camera is unusable (NaN, degenerate).
    BadCamera(PathBuf, usize, String),
    /// The record file holds no camera.
    NoCameras(PathBuf),
}

impl std::fmt::Display for PathError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PathError::Unknown(s) => write!(
                f,
                "unknown scenario {s:?}; one of {}, {}, each with an optional :SPEED (deg/s), or record:FILE",
                DEFAULT_SCENARIOS.join(", "),
                USER_SCENARIOS.join(", ")
            ),
            PathError::BadSpeed(s) => write!(f, "scenario {s:?}: the speed after ':' is not a finite number"),
            PathError::Record(p, e) => write!(f, "camera path {}: {e}", p.display()),
            PathError::BadCamera(p, i, e) => write!(f, "camera path {}: camera {i} is unusable: {e}", p.display()),
            PathError::NoCameras(p) => write!(f, "camera path {}: no camera entries", p.display()),
        }
    }
}

impl std::error::Error for PathError {}

impl CameraPath {
    /// Parses a scenario: `orbit`, `stop-and-go`, `dolly`, `look-around`, `flick`, `zoom`
    /// (each optionally `:SPEED` in deg/s; the dolly, look-around and zoom take it as a time
    /// scale, speed / 30), or `record:FILE` (a `--record` file of the window client).
    pub fn parse(spec: &str) -> Result<CameraPath, PathError> {
        if let Some(file) = spec.strip_prefix("record:") {
            return Ok(CameraPath { name: spec.into(), kind: read_recorded(Path::new(file))?, speed: DEFAULT_SPEED });
        }
        let (name, speed) = match spec.split_once(':') {
            Some((n, s)) => {
                let v: f32 = s.parse().map_err(|_| PathError::BadSpeed(spec.into()))?;
                if !v.is_finite() {
                    return Err(PathError::BadSpeed(spec.into()));
                }
                (n, v)
            }
            None if spec == "flick" => (spec, FLICK_SPEED),
            None => (spec, DEFAULT_SPEED),
        };
        let kind = match name {
            "orbit" => PathKind::Orbit,
            "stop-and-go" => PathKind::StopAndGo,
            "dolly" => PathKind::Dolly,
            "look-around" => PathKind::LookAround,
            "flick" => PathKind::Flick,
            "zoom" => PathKind::Zoom,
            "wl-drag" => PathKind::WindowLevelDrag,
            _ => return Err(PathError::Unknown(spec.into())),
        };
        Ok(CameraPath { name: spec.into(), kind, speed })
    }

    /// A path that never moves (an orbit at speed 0).
    pub fn still() -> CameraPath {
        CameraPath { name: "still".into(), kind: PathKind::Orbit, speed: 0.0 }
    }

    /// The camera at `t` seconds, starting from `c0` (whose viewport is kept).
    pub fn camera(&self, c0: &Camera, t: f64) -> Camera {
        let s = self.speed as f64;
        let t = t.max(0.0);
        match &self.kind {
            PathKind::Orbit | PathKind::WindowLevelDrag => c0.orbit((s * t) as f32, 0.0),
            PathKind::StopAndGo => c0.orbit((s * stop_and_go_position(t)) as f32, 0.0),
            PathKind::Dolly => {
                let u = t * s / DEFAULT_SPEED as f64;
                c0.dolly((1.0 - 0.3 * (std::f64::consts::TAU * u / 6.0).sin()) as f32)
            }
            PathKind::LookAround => {
                let u = t * s / DEFAULT_SPEED as f64;
                let yaw = DEFAULT_SPEED as f64 * u;
                let pitch = 15.0 * (std::f64::consts::TAU * u / 4.0).sin();
                let zoom = 1.0 - 0.15 * (std::f64::consts::TAU * u / 3.0).sin();
                c0.orbit(yaw as f32, pitch as f32).dolly(zoom as f32)
            }
            PathKind::Flick => c0.orbit((s * t.min(FLICK_S)) as f32, 0.0),
            PathKind::Zoom => {
                let u = (t * s / DEFAULT_SPEED as f64 / ZOOM_S).min(1.0);
                let eased = u * u * (3.0 - 2.0 * u);
                c0.dolly((1.0 - (1.0 - ZOOM_TO) * eased) as f32)
            }
            PathKind::Recorded(cams) => {
                let i = cams.partition_point(|(ct, _)| *ct <= t).saturating_sub(1);
                cams[i].1.with_viewport(c0.width, c0.height)
            }
        }
    }

    /// The window and level (fractions of the value range) the user has set at `t` seconds;
    /// `None` where the path changes no visual state (every path but `wl-drag`).
    pub fn window_level(&self, t: f64) -> Option<[f32; 2]> {
        if self.kind != PathKind::WindowLevelDrag {
            return None;
        }
        let u = ((t - WL_DRAG_START_S) / WL_DRAG_S).clamp(0.0, 1.0) as f32;
        Some([WL_FROM[0] + (WL_TO[0] - WL_FROM[0]) * u, WL_FROM[1] + (WL_TO[1] - WL_FROM[1]) * u])
    }

    /// The recorded path's length in seconds (`None` for the built-in ones, which go on).
    pub fn recorded_duration(&self) -> Option<f64> {
        match &self.kind {
            PathKind::Recorded(c) => c.last().map(|(t, _)| *t),
            _ => None,
        }
    }
}

/// Time spent moving forward minus backward up to `t` in the stop-and-go pattern, in seconds
/// of motion (multiply by the speed for degrees).
fn stop_and_go_position(t: f64) -> f64 {
    // (duration, direction) of the 6 s pattern.
    const PATTERN: [(f64, f64); 5] = [(1.5, 1.0), (1.0, 0.0), (1.5, -1.0), (0.5, 0.0), (1.5, 1.0)];
    let period: f64 = PATTERN.iter().map(|p| p.0).sum();
    let per_period: f64 = PATTERN.iter().map(|p| p.0 * p.1).sum();
    let n = (t / period).floor();
    let mut pos = n * per_period;
    let mut rest = t - n * period;
    for (d, dir) in PATTERN {
        let step = rest.min(d);
        pos += step * dir;
        rest -= step;
        if rest <= 0.0 {
            break;
        }
    }
    pos
}

fn read_recorded(path: &Path) -> Result<PathKind, PathError> {
    let bytes = std::fs::read(path).map_err(|e| PathError::Record(path.into(), e.to_string()))?;
    let mut r: &[u8] = &bytes;
    let rec = |e: volwarp_core::record::RecordError| PathError::Record(path.into(), e.to_string());
    read_magic(&mut r).map_err(rec)?;
    let limits = Limits::for_frames(MAX_RECORDED_VIEWPORT);
    let mut cams: Vec<(f64, Camera)> = Vec::new();
    while let Some(e) = read_entry(&mut r, &limits).map_err(rec)? {
        if let Entry::Camera { t_us, request } = e {
            request
                .camera
                .validate(MAX_RECORDED_VIEWPORT)
                .map_err(|e| PathError::BadCamera(path.into(), cams.len(), e.to_string()))?;
            cams.push((t_us as f64 * 1e-6, request.camera));
        }
    }
    if cams.is_empty() {
        return Err(PathError::NoCameras(path.into()));
    }
    // Times relative to the first camera, in order.
    let t0 = cams[0].0;
    for c in &mut cams {
        c.0 -= t0;
    }
    cams.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(PathKind::Recorded(cams))
}

/// Parses a comma-separated list of scenarios.
pub fn parse_list(list: &str) -> Result<Vec<CameraPath>, ErrorBox> {
    list.split(',').filter(|s| !s.trim().is_empty()).map(|s| Ok(CameraPath::parse(s.trim())?)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use volwarp_core::Vec3;

    fn c0() -> Camera {
        Camera::look_at(Vec3::new(0.0, 0.0, 4.0), Vec3::ZERO, Vec3::Y, 30.0, 8, 8)
    }

    fn angle(a: &Camera, b: &Camera) -> f32 {
        let (x, y) = ((a.eye - a.target).normalize(), (b.eye - b.target).normalize());
        x.dot(y).clamp(-1.0, 1.0).acos().to_degrees()
    }

    #[test]
    fn orbit_turns_at_its_speed_and_stop_and_go_stops_and_reverses() {
        let o = CameraPath::parse("orbit:60").unwrap();
        assert!((angle(&o.camera(&c0(), 0.5), &c0()) - 30.0).abs() < 1e-3);
        let s = CameraPath::parse("stop-and-go").unwrap();
        assert!((stop_and_go_position(1.5) - 1.5).abs() < 1e-12);
        assert_eq!(s.camera(&c0(), 1.8), s.camera(&c0(), 2.4), "still between 1.5 and 2.5 s");
        assert!((stop_and_go_position(4.0) - 0.0).abs() < 1e-12, "back at the start after the reversal");
        assert!((stop_and_go_position(12.0) - 2.0 * 1.5).abs() < 1e-12);
        assert_eq!(CameraPath::still().camera(&c0(), 3.0), c0());
    }

    #[test]
    fn the_flick_turns_fast_then_rests_and_the_zoom_closes_in_then_rests() {
        let f = CameraPath::parse("flick").unwrap();
        assert_eq!(f.speed, FLICK_SPEED);
        assert!((angle(&f.camera(&c0(), 0.25), &c0()) - 45.0).abs() < 1e-3);
        assert!((angle(&f.camera(&c0(), 0.5), &c0()) - 90.0).abs() < 1e-3);
        assert_eq!(f.camera(&c0(), 0.5), f.camera(&c0(), 4.0), "rests after 0.5 s");
        assert!((angle(&CameraPath::parse("flick:90").unwrap().camera(&c0(), 1.0), &c0()) - 45.0).abs() < 1e-3);
        let z = CameraPath::parse("zoom").unwrap();
        let dist = |c: &Camera| (c.eye - c.target).length();
        let d0 = dist(&c0());
        assert!(dist(&z.camera(&c0(), 0.75)) < d0 && dist(&z.camera(&c0(), 0.75)) > ZOOM_TO as f32 * d0);
        assert!((dist(&z.camera(&c0(), 1.5)) / d0 - ZOOM_TO as f32).abs() < 1e-5);
        assert_eq!(z.camera(&c0(), 1.5), z.camera(&c0(), 5.0), "rests after the zoom");
    }

    #[test]
    fn the_window_level_drag_orbits_and_moves_window_and_level_only_while_dragging() {
        let d = CameraPath::parse("wl-drag").unwrap();
        let o = CameraPath::parse("orbit").unwrap();
        for t in [0.0, 0.7, 1.5, 3.0] {
            assert_eq!(d.camera(&c0(), t), o.camera(&c0(), t), "the camera orbits as `orbit` does");
            assert_eq!(o.window_level(t), None);
        }
        assert_eq!(d.window_level(0.0), Some(WL_FROM));
        assert_eq!(d.window_level(WL_DRAG_START_S), Some(WL_FROM));
        let mid = d.window_level(WL_DRAG_START_S + 0.5 * WL_DRAG_S).unwrap();
        assert!(mid[0] < WL_FROM[0] && mid[0] > WL_TO[0] && mid[1] < WL_FROM[1] && mid[1] > WL_TO[1], "{mid:?}");
        assert_eq!(d.window_level(WL_DRAG_START_S + WL_DRAG_S), Some(WL_TO));
        assert_eq!(d.window_level(10.0), Some(WL_TO), "held after the drag");
    }

    #[test]
    fn unknown_scenarios_and_bad_speeds_are_errors() {
        assert!(matches!(CameraPath::parse("spin"), Err(PathError::Unknown(_))));
        assert!(matches!(CameraPath::parse("orbit:fast"), Err(PathError::BadSpeed(_))));
        assert!(matches!(CameraPath::parse("orbit:NaN"), Err(PathError::BadSpeed(_))));
    }
}
