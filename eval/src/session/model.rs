//! The server, network and client models of a session, and the calibration file that holds
//! measured draw times.
//!
//! Times are in milliseconds of simulated time. The server renders one frame at a time for the
//! camera its [`ServerPolicy`] picks from the requests it has received, in `server_ms`; it then
//! writes the frame to the link (blocking, as a TCP write does), which carries the bytes the
//! server sends for it (`volwarp_server::encoding::encode_frame`) at `mbps`, and the frame arrives
//! `latency_ms` later. The client shows a new image every display tick; each method takes its
//! draw time from the calibration (or a fixed figure).

use crate::ErrorBox;
use std::collections::BTreeMap;
use std::path::Path;
use volwarp_core::Camera;

/// A camera request as the server sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Request {
    /// Display tick at which the client sent it.
    pub tick: usize,
    /// Simulated time it was sent, ms.
    pub sent_ms: f64,
    /// The camera the client displayed then.
    pub camera: Camera,
}

/// What the server renders for: given the requests received so far (oldest first, at least
/// one) and the time it starts rendering, the camera of the next frame. Later issues add
/// prediction and guard bands as new policies.
pub trait ServerPolicy {
    /// The policy's name (CSV and summaries).
    fn name(&self) -> &str;
    /// The camera to render for.
    fn camera(&mut self, received: &[Request], now_ms: f64) -> Camera;
}

/// Today's server: renders the camera it received last.
#[derive(Clone, Copy, Debug, Default)]
pub struct LastReceived;

impl ServerPolicy for LastReceived {
    fn name(&self) -> &str {
        "last-received"
    }
    fn camera(&mut self, received: &[Request], _now_ms: f64) -> Camera {
        received[received.len() - 1].camera
    }
}

/// The server policies by name (one entry per policy).
pub fn server_policy(name: &str) -> Result<Box<dyn ServerPolicy>, ErrorBox> {
    match name {
        "last-received" => Ok(Box::new(LastReceived)),
        _ => Err(format!("unknown server policy {name:?}; one of: last-received").into()),
    }
}

/// What a session's client asks the server for (defined with the methods that ask it).
pub use super::methods::SessionRequest;

/// The server and the network.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NetworkModel {
    /// Time to render one frame, ms (≥ 0).
    pub server_ms: f64,
    /// One-way latency, ms (≥ 0).
    pub latency_ms: f64,
    /// Bandwidth in Mbit/s (> 0; infinity for a link without transfer time).
    pub mbps: f64,
}

impl NetworkModel {
    /// The sessions' default setting: 500 ms per frame, 50 ms one way, 100 Mbit/s.
    pub const DEFAULT: NetworkModel = NetworkModel { server_ms: 500.0, latency_ms: 50.0, mbps: 100.0 };

    /// Checks the figures: a clear error for a bandwidth of 0, negative or NaN times.
    pub fn check(&self) -> Result<(), ErrorBox> {
        if self.mbps.is_nan() || self.mbps <= 0.0 {
            return Err(format!("bandwidth must be above 0 Mbit/s (got {})", self.mbps).into());
        }
        if !self.server_ms.is_finite() || self.server_ms < 0.0 {
            return Err(format!("server ms must be a finite figure ≥ 0 (got {})", self.server_ms).into());
        }
        if !self.latency_ms.is_finite() || self.latency_ms < 0.0 {
            return Err(format!("latency must be a finite figure ≥ 0 ms (got {})", self.latency_ms).into());
        }
        Ok(())
    }

    /// Time to put `bytes` on the link, ms.
    pub fn transfer_ms(&self, bytes: u64) -> f64 {
        if self.mbps.is_infinite() {
            0.0
        } else {
            bytes as f64 * 8.0 / (self.mbps * 1e3)
        }
    }
}

/// The client: display rate and draw times.
#[derive(Clone, Debug, PartialEq)]
pub struct ClientModel {
    /// Display rate, Hz.
    pub display_hz: f64,
    /// Draw time per method name, ms (methods not listed draw within a tick).
    pub draw_ms: BTreeMap<String, f64>,
}

impl ClientModel {
    /// Display ticks a draw of `ms` takes (at least 1: a draw within one tick is shown at the
    /// tick it started at).
    pub fn ticks_per_draw(&self, ms: f64) -> usize {
        let tick = 1e3 / self.display_hz;
        ((ms / tick).ceil() as usize).max(1)
    }
}

/// Measured figures: the server's frame time per dataset and size, each method's draw time per
/// size. A CSV file with the columns `kind,name,size,ms` (`kind` is `server` with a dataset name
/// or `client` with a method name), written by `volwarp-eval session-calibrate`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Calibration {
    /// `(kind, name, size) → ms`.
    pub ms: BTreeMap<(String, String, u32), f64>,
}

/// The client draw times at 512² used when no calibration file is given: the medians of
/// `docs/results.md` (2 threads; "One-sample renderers against angle"), scaled with the
/// pixel count at other sizes.
/// `splat-fill` (with warp-sized radii) is splat's figure times 1.57, the ratio of the two
/// measured in one `session-calibrate` run (tooth, 512², 2 threads; `docs/perf.md`);
/// `splat-layers` (4 segments per pixel, hole filling, warp-grown footprints: `volwarp`) is
/// splat-fill's figure times 1.50, the median ratio of the two in three `session-calibrate
/// --all` runs (512², 2 threads; `docs/perf.md`; 2.74 before the
/// SIMD set-up and band-at-a-time compositing).
pub const DEFAULT_DRAW_MS_512: [(&str, f64); 8] = [
    ("stale", 0.9),
    ("points1", 0.7),
    ("points2", 1.1),
    ("points3", 1.3),
    ("spheres-cpu", 4.4),
    ("splat", 2.8),
    ("splat-fill", 4.4),
    ("splat-layers", 6.6),
];

/// What each older frame a `splat-layers` method keeps adds to its draw time, as a fraction of
/// the one-frame draw: the median over the five datasets of `layer_time --frames 4` (512², one
/// thread; `docs/perf.md`).
pub const OLDER_FRAME_COST: f64 = 0.06;

impl Calibration {
    /// Reads a calibration file (a clear error for a malformed line).
    pub fn load(path: &Path) -> Result<Calibration, ErrorBox> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        Calibration::parse(&text).map_err(|e| format!("{}: {e}", path.display()).into())
    }

    /// Parses the CSV text.
    pub fn parse(text: &str) -> Result<Calibration, ErrorBox> {
        let mut c = Calibration::default();
        for (i, line) in text.lines().enumerate() {
            let f: Vec<&str> = line.split(',').map(str::trim).collect();
            if i == 0 && f.first() == Some(&"kind") || line.trim().is_empty() {
                continue;
            }
            let bad = || format!("line {}: expected kind,name,size,ms", i + 1);
            if f.len() != 4 || !(f[0] == "server" || f[0] == "client") {
                return Err(bad().into());
            }
            let size: u32 = f[2].parse().map_err(|_| bad())?;
            let ms: f64 = f[3].parse().map_err(|_| bad())?;
            if !ms.is_finite() || ms < 0.0 {
                return Err(format!("line {}: ms must be finite and ≥ 0", i + 1).into());
            }
            c.ms.insert((f[0].into(), f[1].into(), size), ms);
        }
        Ok(c)
    }

    /// The CSV text.
    pub fn to_csv(&self) -> String {
        let mut s = String::from("kind,name,size,ms\n");
        for ((k, n, size), ms) in &self.ms {
            s.push_str(&format!("{k},{n},{size},{ms:.3}\n"));
        }
        s
    }

    /// The server's frame time for a dataset at a size, if measured.
    pub fn server_ms(&self, dataset: &str, size: u32) -> Option<f64> {
        self.ms.get(&("server".into(), dataset.into(), size)).copied()
    }

    /// The server's measured time at 1/2 and 1/4 of the resolution as fractions of its full
    /// resolution's, for a dataset at a size (`server` lines `DATASET`, `DATASET/2` and
    /// `DATASET/4`, [`super::peers::scaled_name`]), if all three were measured.
    pub fn resolution_cost(&self, dataset: &str, size: u32) -> Option<super::peers::ResolutionCost> {
        let full = self.server_ms(dataset, size).filter(|&ms| ms > 0.0)?;
        let at = |f| self.server_ms(&super::peers::scaled_name(dataset, f), size).map(|ms| ms / full);
        Some(super::peers::ResolutionCost { half: at(2)?, quarter: at(4)? })
    }

    /// A method's draw time at a size: measured, else the default figure scaled by pixels.
    /// A method spec not measured takes its renderer's figure (the part before the first `+`;
    /// an alias (`volwarp`, `volwarp-adaptive`): its spec's).
    pub fn draw_ms(&self, method: &str, size: u32) -> f64 {
        if let Some(ms) = self.ms.get(&("client".into(), method.into(), size)) {
            return *ms;
        }
        let aliased = super::methods::alias(method).map(|m| m.name());
        let spec = aliased.as_deref().unwrap_or(method);
        let renderer = spec.split('+').next().unwrap_or(spec);
        if renderer != method {
            // The layered splatter draws what the newest frame did not see of each older frame
            // it keeps, on top of its own draw.
            let older = super::methods::MethodSpec::parse(spec)
                .ok()
                .filter(|m| m.renderer == volwarp_core::RendererKind::SplatLayers)
                .map_or(0, |m| m.frames - 1);
            return self.draw_ms(renderer, size) * (1.0 + OLDER_FRAME_COST * older as f64);
        }
        let base = DEFAULT_DRAW_MS_512.iter().find(|(n, _)| *n == method).map_or(1.0, |x| x.1);
        base * (size as f64 / 512.0).powi(2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn calibration_round_trips_and_rejects_bad_lines() {
        let mut c = Calibration::default();
        c.ms.insert(("server".into(), "mri".into(), 512), 231.5);
        c.ms.insert(("client".into(), "splat".into(), 512), 2.75);
        let back = Calibration::parse(&c.to_csv()).unwrap();
        assert_eq!(back, c);
        assert_eq!(back.server_ms("mri", 512), Some(231.5));
        assert_eq!(back.draw_ms("splat", 512), 2.75);
        assert!((back.draw_ms("splat", 1024) - 11.2).abs() < 1e-9, "default figure scaled by pixels");
        // Older frames of a layered method add their share; other renderers' specs do not.
        let one = back.draw_ms("splat-layers+predict+adapt+layers=4", 512);
        let four = back.draw_ms("splat-layers+predict+frames=4+adapt+layers=4", 512);
        assert!((four / one - (1.0 + 3.0 * OLDER_FRAME_COST)).abs() < 1e-9, "{four} / {one}");
        assert_eq!(back.draw_ms("volwarp", 512), four, "the default keeps four frames");
        assert_eq!(back.draw_ms("splat-fill+frames=3", 512), back.draw_ms("splat-fill", 512));
        assert!(Calibration::parse("kind,name,size,ms\nserver,mri,512,NaN\n").is_err());
        assert!(Calibration::parse("gpu,mri,512,1\n").is_err());
        assert!(Calibration::parse("server,mri,x,1\n").is_err());
    }

    #[test]
    fn network_checks_and_transfer_time() {
        let n = NetworkModel { mbps: 100.0, ..NetworkModel::DEFAULT };
        assert!((n.transfer_ms(1_250_000) - 100.0).abs() < 1e-9, "10 Mbit at 100 Mbit/s is 100 ms");
        assert!(NetworkModel { mbps: 0.0, ..n }.check().is_err());
        assert!(NetworkModel { mbps: f64::NAN, ..n }.check().is_err());
        assert!(NetworkModel { latency_ms: -1.0, ..n }.check().is_err());
        assert!(NetworkModel { mbps: f64::INFINITY, ..n }.check().is_ok());
    }
}
