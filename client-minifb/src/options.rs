//! The command line of `volwarp-client` (`--help` prints it with the window controls).

use crate::error::ClientError;
use clap::Parser;
use std::path::PathBuf;
use volwarp_core::method::Method;
use volwarp_core::{Heuristic, RendererKind};

/// The window controls, printed by `--help`.
pub const CONTROLS: &str = "\
Window controls:
  left drag / arrow keys     orbit around the volume
  right drag / W A S D       pan
  wheel / + -                zoom
  1 (or 0)                   the default renderer, splat-layers
  2..9                       stale, points1, points2, points3, splat, spheres-gpu,
                             spheres-scalar, spheres (see --renderer)
  H / Shift+H                next / previous depth heuristic (sent to the server)
  [ ]                        smaller / larger sample radius (sent to the server)
  R                          reset the camera
  Ctrl + left drag           window/level: right widens the window, up raises the level
  P / Shift+P                next / previous transfer-function preset (the server's list,
                             then the function it started with)
  O / Shift+O                more / less opacity
  C                          crop box on / off (starts with the front half cut away)
  F / Shift+F                next / previous crop face (x min, y min, z min, x max, …)
  Page Up / Page Down        move that crop face towards the box's max / min side
  L                          lighting (gradient shading) on / off
  F12                        save the window as volwarp-shot-N.png (current folder)
  Esc / Q                    quit
The title shows display FPS, server frames per second, the age of the shown frame (time since
its camera was requested), its sample count, the renderer, the heuristic, the warp levers
that are on (predict, guard, adapt, frames kept), then the preset, window/level, opacity and
crop; 'updating…' while the frame of the newest visual edit has not arrived (until then the
window warps the frames of the state it has, never mixing two states).

Without --connect the client starts the real volwarp-server program (found beside this client,
on PATH or in $VOLWARP_SERVER) on 127.0.0.1 (random port); it serves the bundled dataset, or
--volume FILE, over real TCP and stops with the client. With --connect, a dropped connection
(server restarted, network gone) is retried with backoff while the window keeps warping the
last frames and its title says 'reconnecting in N s…'; a wrong token, another protocol version
or a refused TLS certificate stops the client with that error instead (--no-reconnect: stop on
any drop). --connect HOST:PORT --tls [--ca FILE] speaks TLS (certificate verified for HOST).

With no display (DISPLAY and WAYLAND_DISPLAY unset, or the window cannot be opened) the client
exits with an error: use --headless.";

/// Command-line options.
#[derive(Parser, Debug, Clone)]
#[command(
    name = "volwarp-client",
    version,
    about = "volwarp thin client: receives object-space samples, builds an LBVH and ray traces them for the camera of now",
    after_help = CONTROLS
)]
pub struct Options {
    /// Server address (host:port). Default: start a `volwarp-server` child process on loopback.
    #[arg(long, value_name = "ADDR")]
    pub connect: Option<String>,
    /// Access token for the server (also $VOLWARP_TOKEN).
    #[arg(long, conflicts_with = "token_file")]
    pub token: Option<String>,
    /// Read the access token from FILE (surrounding whitespace trimmed), so it does not show in
    /// `ps` output.
    #[arg(long, value_name = "FILE")]
    pub token_file: Option<std::path::PathBuf>,
    /// With --connect: stop when the connection drops instead of connecting again (by default
    /// the client keeps warping the frames it has and retries, 100 ms doubling to 2 s apart).
    #[arg(long, requires = "connect")]
    pub no_reconnect: bool,
    /// With --connect: speak TLS to a server started with --tls-cert/--tls-key. Its certificate
    /// is verified for the host of --connect against --ca, or the Mozilla roots without it.
    #[arg(long, requires = "connect")]
    pub tls: bool,
    /// With --tls: trust the CA certificates of this PEM file (or pin the server's own
    /// self-signed certificate) instead of the Mozilla roots.
    #[arg(long, value_name = "FILE", requires = "tls")]
    pub ca: Option<PathBuf>,
    /// Render to PNG files instead of a window (needs --out unless --bench).
    #[arg(long)]
    pub headless: bool,
    /// Display frames to render (headless: default 60; window: quit after N frames, 0 = never).
    #[arg(long, value_name = "N")]
    pub frames: Option<u32>,
    /// Headless: degrees the scripted camera orbits over all frames (yaw around the up axis).
    #[arg(long, value_name = "DEG", default_value_t = 90.0)]
    pub orbit: f32,
    /// Headless / replay: folder for the PNG frames and timings.csv.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Viewport (window) size.
    #[arg(long, value_name = "WxH", default_value = "512x512", value_parser = parse_size)]
    pub size: (u32, u32),
    /// Save the received frames and the displayed cameras to FILE (docs/client.md).
    #[arg(long, value_name = "FILE")]
    pub record: Option<PathBuf>,
    /// Play a recorded FILE back offline (no server) through --renderer.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["connect", "record"])]
    pub replay: Option<PathBuf>,
    /// Tracer threads (0: all cores but one, at least one).
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub threads: usize,
    /// Threads of the network thread's LBVH build (0: all cores).
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub build_threads: usize,
    /// Renderer: the product, splat-layers (layered frames composited front to back, holes
    /// filled: the default, window key 1; it asks the server for 4 segments per pixel) and
    /// splat-layers-gpu (its wgpu twin); the baselines stale (unwarped frame, key 2), points1,
    /// points2, points3 (2.5D points, keys 3–5), splat (exact sphere splatting, key 6),
    /// spheres-gpu (GPU opened on first use, key 7), spheres (the fastest exact route: tiles or
    /// tracer, key 9), spheres-cpu, splat-tiles, splat-gpu, spheres-fill and splat-fill (holes
    /// filled from the stale frame); the reference oracles spheres-scalar (key 8) and
    /// spheres-layers.
    #[arg(long, value_name = "NAME", default_value_t = Method::DEFAULT.renderer, value_parser = parse_renderer)]
    pub renderer: RendererKind,
    /// GPU renderers: the adapter whose name contains NAME (case-insensitive; default: the best
    /// there is, a real GPU before a software one). The adapter opened is logged.
    #[arg(long, value_name = "NAME")]
    pub adapter: Option<String>,
    /// Depth heuristic the server uses: entrance, exit, midpoint, threshold, peak, gradient,
    /// rel-threshold, en-ex-mean.
    #[arg(long, value_name = "NAME", default_value = "threshold", value_parser = parse_heuristic)]
    pub heuristic: Heuristic,
    /// Sphere radius as a multiple of the server's radius model (by default a pixel diagonal
    /// at the sample's depth), in (0, 16].
    #[arg(long, value_name = "X", default_value_t = 1.0)]
    pub radius_scale: f32,
    /// Child server (no --connect): the volume it serves (raw or NRRD path, as `volwarp-server
    /// --volume`). Default: the bundled dataset.
    #[arg(long, value_name = "FILE", conflicts_with = "connect")]
    pub volume: Option<String>,
    /// Child server (no --connect): delay before each frame, in ms (slows the server down).
    #[arg(long, value_name = "MS", default_value_t = 0)]
    pub server_delay_ms: u64,
    /// Child server (no --connect): marcher threads (0: all cores).
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub server_threads: usize,
    /// Extra delay of every received frame before it is built and shown, in ms.
    #[arg(long, value_name = "MS", default_value_t = 0)]
    pub latency_ms: u64,
    /// Throttle the connection to a link of this many Mbit/s (a token bucket on the socket's
    /// reads and writes; 0: unthrottled): shows what a slow network does to frame age.
    #[arg(long, value_name = "MBPS", default_value_t = 0.0)]
    pub bandwidth_mbps: f64,
    /// Ask the server for the camera predicted for when its frame will be shown (orbit-aware
    /// extrapolation over the measured request-to-display time plus half the frame interval)
    /// instead of the current one: `--predict false` turns it off.
    #[arg(long, value_name = "BOOL", default_value_t = Method::DEFAULT.predict, action = clap::ArgAction::Set)]
    pub predict: bool,
    /// Guard band: ask for a view wider by this fraction of the window on every side (same
    /// pixel density, (1 + 2G)² the pixels), so turns reveal samples already sent; 0..=0.5.
    #[arg(long, value_name = "G", default_value_t = Method::DEFAULT.guard, value_parser = parse_guard)]
    pub guard: f32,
    /// Size spheres by how far the view moved from the frame's camera (half the footprint at
    /// the frame's own camera, so it is shown exactly; the frame's radius from a 10° turn on;
    /// the splatters only; `splat-layers` grows the footprints of opaque segments instead):
    /// `--adapt false` draws the frame's radii.
    #[arg(long, value_name = "BOOL", default_value_t = Method::DEFAULT.adapt, action = clap::ArgAction::Set)]
    pub adapt: bool,
    /// Keep the K newest frames and fill what the newest does not cover from what the older
    /// ones saw that it did not (renderers that keep frames: `splat-layers`; the others draw
    /// the newest alone); 1..=8.
    #[arg(long, value_name = "K", default_value_t = Method::DEFAULT.frames, value_parser = parse_keep_frames)]
    pub keep_frames: usize,
    /// Watertight slabs (`splat-layers`, `splat-layers-gpu`): neighbouring segments of one slab
    /// share their footprints' corners where their depths lie within T source pixels, so a
    /// semi-transparent layer shows no contour lines where it faces the view; 0 turns it off;
    /// 0..=8.
    #[arg(
        long,
        value_name = "T",
        default_value_t = Method::DEFAULT.watertight,
        value_parser = parse_watertight
    )]
    pub watertight: f32,
    /// Adaptive resolution: while the view moves, ask for frames on a pixel grid N times
    /// coarser per axis (fewer pixels to march and send, so fresher frames, warped at display
    /// resolution), twice as coarse again (at most 4) while it turns fast, and for the full
    /// resolution once it rests; 1, 2 (the default) or 4; 1 always asks for the full resolution.
    #[arg(long, value_name = "N", default_value_t = Method::DEFAULT.coarse, value_parser = parse_coarse)]
    pub coarse: u8,
    /// Segments per pixel to ask for once the view rests, 0–16 (0, the default: as many as
    /// `--layers`, as while it moves). 1 is the server's own image for the resting view: exact
    /// there, and it arrives sooner than a layered frame, but the next move warps it.
    #[arg(long, value_name = "K", default_value_t = Method::DEFAULT.rest_layers, value_parser = clap::value_parser!(u8).range(0..=16))]
    pub rest_layers: u8,
    /// Side views: while the view rests and its exact frame has arrived, ask for the views
    /// DEG degrees along the orbit either way, one after the other, so a turn that starts
    /// from rest warps the nearer side view until the move's first frame arrives; 0 turns it
    /// off (default: 30).
    #[arg(long, value_name = "DEG", default_value_t = Method::DEFAULT.prefetch_deg, value_parser = parse_prefetch)]
    pub prefetch_deg: f32,
    /// Display frame rate limit (0: none). Default: 60 in the window, none headless.
    #[arg(long)]
    pub fps: Option<u32>,
    /// Measure the display rate while frames arrive (headless, prints a summary).
    #[arg(long)]
    pub bench: bool,
    /// With --bench: serve frames prerendered along the bench orbit over loopback TCP, one per
    /// --server-delay-ms (default 500), so no ray marcher competes with the client for the CPU.
    #[arg(long, requires = "bench", conflicts_with = "connect")]
    pub prerender: bool,
    /// Length of --bench in seconds.
    #[arg(long, value_name = "S", default_value_t = 20.0)]
    pub seconds: f64,
    /// Seconds to wait for the server (connect, handshake, each frame).
    #[arg(long, value_name = "S", default_value_t = 30)]
    pub timeout_s: u64,
    /// Layered samples: ask the server for up to K depth segments per pixel, 1–16
    /// (renderers `splat-layers` and `splat-layers-gpu` composite them front to back). Default:
    /// 4 with `--renderer splat-layers`, `splat-layers-gpu` or `spheres-layers`, else 1 (one
    /// sample per pixel).
    #[arg(long, value_name = "K", value_parser = clap::value_parser!(u8).range(1..=16))]
    pub layers: Option<u8>,
}

impl Options {
    /// The segments per pixel to ask the server for (see `--layers`).
    pub fn layers(&self) -> u8 {
        self.layers.unwrap_or(Method::layers_for(self.renderer))
    }

    /// The method the options ask for (core's [`Method`]; with no options
    /// [`Method::DEFAULT`]).
    pub fn method(&self) -> Method {
        Method {
            renderer: self.renderer,
            layers: self.layers(),
            frames: self.keep_frames,
            predict: self.predict,
            adapt: self.adapt,
            watertight: self.watertight,
            guard: self.guard,
            coarse: self.coarse,
            rest_layers: self.rest_layers,
            prefetch_deg: self.prefetch_deg,
        }
    }
}

/// Parses the side views' angle: 0 (off) to `method::MAX_PREFETCH_DEG` degrees.
pub fn parse_prefetch(s: &str) -> Result<f32, String> {
    let max = volwarp_core::method::MAX_PREFETCH_DEG;
    match s.trim().parse::<f32>() {
        Ok(d) if (0.0..=max).contains(&d) => Ok(d),
        _ => Err(format!("--prefetch-deg `{s}`: degrees from 0 (off) to {max}")),
    }
}

/// Parses the adaptive resolution's divisor: 1, 2 or 4.
pub fn parse_coarse(s: &str) -> Result<u8, String> {
    match s.trim().parse::<u8>() {
        Ok(n @ (1 | 2 | 4)) => Ok(n),
        _ => Err(format!("--coarse `{s}`: 1, 2 or 4")),
    }
}

/// Parses `WxH`.
pub fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(|| format!("size `{s}` is not WxH"))?;
    let w: u32 = w.trim().parse().map_err(|_| format!("bad width in `{s}`"))?;
    let h: u32 = h.trim().parse().map_err(|_| format!("bad height in `{s}`"))?;
    if !(1..=4096).contains(&w) || !(1..=4096).contains(&h) {
        return Err(format!("size `{s}`: width and height must be 1 to 4096"));
    }
    Ok((w, h))
}

/// Parses a renderer name of the registry.
pub fn parse_renderer(s: &str) -> Result<RendererKind, String> {
    s.parse::<RendererKind>().map_err(|e| format!("`{s}`: {e}"))
}

/// Parses a heuristic name.
pub fn parse_heuristic(s: &str) -> Result<Heuristic, String> {
    Heuristic::from_name(s).ok_or_else(|| {
        let names: Vec<&str> = Heuristic::ALL.iter().map(|h| h.name()).collect();
        format!("unknown heuristic `{s}` (one of {})", names.join(", "))
    })
}

impl Options {
    /// The access token: `--token`, else `--token-file` (trimmed), else `$VOLWARP_TOKEN`; an
    /// unreadable or empty token file is a usage error.
    pub fn access_token(&self) -> Result<Option<String>, ClientError> {
        if let Some(t) = &self.token {
            return Ok(Some(t.clone()));
        }
        if let Some(path) = &self.token_file {
            let text = std::fs::read_to_string(path)
                .map_err(|e| ClientError::Usage(format!("--token-file {}: {e}", path.display())))?;
            let t = text.trim();
            if t.is_empty() {
                return Err(ClientError::Usage(format!("--token-file {}: the file holds no token", path.display())));
            }
            return Ok(Some(t.to_string()));
        }
        Ok(std::env::var("VOLWARP_TOKEN").ok().filter(|t| !t.is_empty()))
    }

    /// Checks combinations clap cannot express.
    pub fn validate(&self) -> Result<(), ClientError> {
        if !(self.radius_scale > 0.0 && self.radius_scale <= 16.0) {
            return Err(ClientError::Usage("--radius-scale must be in (0, 16]".into()));
        }
        if self.headless && !self.bench && self.out.is_none() {
            return Err(ClientError::Usage("--headless needs --out DIR".into()));
        }
        if !self.orbit.is_finite() {
            return Err(ClientError::Usage("--orbit must be a finite number of degrees".into()));
        }
        if !(self.seconds > 0.0 && self.seconds < 3600.0) {
            return Err(ClientError::Usage("--seconds must be in (0, 3600)".into()));
        }
        if !(self.bandwidth_mbps >= 0.0 && self.bandwidth_mbps.is_finite()) {
            return Err(ClientError::Usage("--bandwidth-mbps must be a finite number ≥ 0 (0: unthrottled)".into()));
        }
        Ok(())
    }

    /// The layered renderers' options (`--watertight`).
    pub fn layer_options(&self) -> volwarp_cpu_tracer::layer_splat::LayerOptions {
        volwarp_cpu_tracer::layer_splat::LayerOptions { watertight: self.watertight, ..Default::default() }
    }

    /// Extra arguments of the child server (`--volume FILE`).
    pub fn server_args(&self) -> Vec<String> {
        self.volume.iter().flat_map(|v| ["--volume".to_string(), v.clone()]).collect()
    }

    /// The TLS settings of `--tls` and `--ca` (`None` without `--tls`).
    pub fn tls_config(&self) -> Result<Option<std::sync::Arc<volwarp_tls::rustls::ClientConfig>>, ClientError> {
        if !self.tls {
            return Ok(None);
        }
        volwarp_tls::client_config(self.ca.as_deref()).map(Some).map_err(|e| ClientError::Usage(format!("--ca: {e}")))
    }

    /// The tracer thread count actually used.
    pub fn tracer_threads(&self) -> usize {
        if self.threads > 0 {
            self.threads
        } else {
            std::thread::available_parallelism().map_or(1, |n| n.get()).saturating_sub(1).max(1)
        }
    }
}

/// A frame count in `1..=`[`volwarp_cpu_tracer::hole_fill::MAX_FRAMES`].
fn parse_keep_frames(s: &str) -> Result<usize, String> {
    let max = volwarp_cpu_tracer::hole_fill::MAX_FRAMES;
    match s.parse::<usize>() {
        Ok(k) if (1..=max).contains(&k) => Ok(k),
        _ => Err(format!("frames kept must be a count within 1..={max}")),
    }
}

/// A guard fraction in `0..=0.5` (core's `guard::MAX_GUARD`).
fn parse_guard(s: &str) -> Result<f32, String> {
    let g: f32 = s.parse().map_err(|e| format!("{e}"))?;
    if (0.0..=volwarp_core::guard::MAX_GUARD).contains(&g) {
        Ok(g)
    } else {
        Err(format!("guard must be within 0..={}", volwarp_core::guard::MAX_GUARD))
    }
}

fn parse_watertight(s: &str) -> Result<f32, String> {
    let t: f32 = s.parse().map_err(|e| format!("{e}"))?;
    if (0.0..=8.0).contains(&t) {
        Ok(t)
    } else {
        Err("watertight tolerance must be within 0..=8 source pixels".into())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_and_heuristics_parse() {
        assert_eq!(parse_size("640x480"), Ok((640, 480)));
        assert!(parse_size("640").is_err());
        assert!(parse_size("0x10").is_err());
        assert!(parse_size("99999x10").is_err());
        assert_eq!(parse_heuristic("rel-threshold"), Ok(Heuristic::RelThreshold));
        assert!(parse_heuristic("nope").unwrap_err().contains("threshold"));
    }

    #[test]
    fn frame_counts_are_bounded() {
        assert_eq!(parse_watertight("1.5"), Ok(1.5));
        assert_eq!(parse_watertight("0"), Ok(0.0));
        for bad in ["-1", "9", "NaN", "x"] {
            assert!(parse_watertight(bad).is_err(), "{bad}");
        }
        assert_eq!(parse_keep_frames("4"), Ok(4));
        assert_eq!(parse_keep_frames("1"), Ok(1));
        for bad in ["0", "9", "-1", "x", ""] {
            assert!(parse_keep_frames(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn guard_fractions_are_bounded() {
        assert_eq!(parse_guard("0.2"), Ok(0.2));
        assert_eq!(parse_guard("0"), Ok(0.0));
        for bad in ["-0.1", "0.6", "NaN", "inf", "x"] {
            assert!(parse_guard(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn validation_catches_bad_combinations() {
        let o = Options::parse_from(["volwarp-client", "--headless"]);
        assert!(matches!(o.validate(), Err(ClientError::Usage(_))));
        assert!(Options::try_parse_from(["volwarp-client", "--renderer", "nope"]).is_err());
        let o = Options::parse_from(["volwarp-client", "--headless", "--out", "x", "--renderer", "splat"]);
        assert_eq!(o.validate(), Ok(()));
    }

    #[test]
    fn the_layered_renderers_ask_for_layers() {
        let k = volwarp_core::segments::DEFAULT_LAYERS as u8;
        for (renderer, want) in [("splat-layers", k), ("splat-layers-gpu", k), ("splat", 1)] {
            let o = Options::parse_from(["volwarp-client", "--renderer", renderer]);
            assert_eq!(o.layers(), want, "{renderer}");
        }
        let o = Options::parse_from(["volwarp-client", "--renderer", "splat-layers-gpu", "--layers", "2"]);
        assert_eq!(o.layers(), 2);
    }

    #[test]
    fn no_options_ask_for_the_default_method() {
        assert_eq!(Options::parse_from(["volwarp-client"]).method(), Method::DEFAULT);
        assert_eq!(
            Options::parse_from(["volwarp-client", "--coarse", "2"])
                .method()
                .request()
                .divisor(volwarp_core::method::Motion::Moving),
            2
        );
        assert!(Options::try_parse_from(["volwarp-client", "--coarse", "3"]).is_err());
        assert_eq!(Options::parse_from(["volwarp-client"]).method().request().layers(false), 0, "the Hello's");
        let one = Options::parse_from(["volwarp-client", "--rest-layers", "1"]).method().request();
        assert_eq!((one.layers(false), one.layers(true)), (1, 0), "one sample at rest, the Hello's while moving");
        assert!(Options::try_parse_from(["volwarp-client", "--rest-layers", "17"]).is_err());
        let off = Options::parse_from(["volwarp-client", "--prefetch-deg", "0"]).method().request();
        assert_eq!(off.prefetch_deg, 0.0);
        assert_eq!(
            Options::parse_from(["volwarp-client"]).method().request().prefetch_deg,
            Method::DEFAULT.prefetch_deg
        );
        for bad in ["-1", "91", "NaN", "x"] {
            assert!(Options::try_parse_from(["volwarp-client", "--prefetch-deg", bad]).is_err(), "{bad}");
        }
        let o = Options::parse_from(["volwarp-client", "--predict", "false", "--guard", "0.1", "--keep-frames", "2"]);
        let m = o.method();
        assert_eq!((m.predict, m.guard, m.frames), (false, 0.1, 2));
    }
}
