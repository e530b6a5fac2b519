//! The display side of the client: each display frame takes the newest ready scene (if the
//! network thread has one — never waiting), publishes the current view for the writer, and
//! draws the scene for the camera of *now* with the current renderer. The window, headless and
//! bench modes all drive this one loop body.

use crate::network::{Network, ReadyScene, View};
use crate::record::RecordSink;
use crate::renderers::Renderers;
use std::collections::VecDeque;
use std::time::{Duration, Instant};
use volwarp_core::renderer::Image;
use volwarp_core::show::{self, Show};
use volwarp_core::wire::CameraRequest;
use volwarp_core::Camera;

/// What one display frame did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameReport {
    /// Time to draw the scene, in ms.
    pub render_ms: f64,
    /// Time since the shown frame's camera was requested, in ms (`None` before the first
    /// frame, or when its request time is unknown).
    pub age_ms: Option<f64>,
    /// Samples in the shown scene.
    pub samples: usize,
    /// Sequence number of the shown frame (0: none yet).
    pub frame_seq: u64,
    /// A new scene was swapped in this display frame.
    pub new_frame: bool,
    /// A frame was being decoded or built while this display frame ran.
    pub during_build: bool,
    /// LBVH build time of the scene swapped in this display frame, in ms.
    pub build_ms: Option<f64>,
    /// The visual state id of the shown frame (0: the server's start state).
    pub state: u32,
}

/// Frames per second over a sliding window of one second.
#[derive(Debug, Default)]
pub struct RateMeter {
    times: VecDeque<Instant>,
}

impl RateMeter {
    /// Counts `n` events now.
    pub fn add(&mut self, n: u64, now: Instant) {
        for _ in 0..n.min(1000) {
            self.times.push_back(now);
        }
        self.trim(now);
    }

    fn trim(&mut self, now: Instant) {
        while self.times.front().is_some_and(|t| now.duration_since(*t) > Duration::from_secs(1)) {
            self.times.pop_front();
        }
    }

    /// Events in the last second.
    pub fn rate(&mut self, now: Instant) -> f64 {
        self.trim(now);
        self.times.len() as f64
    }
}

/// The display loop's state.
pub struct Display {
    net: Network,
    shown: Option<ReadyScene>,
    /// Older frames kept for multi-frame filling, newest first (at most `keep − 1`).
    older: VecDeque<ReadyScene>,
    keep: usize,
    /// The shown scene was drawn at least once (only drawn frames are kept as older ones, so
    /// a replay, whose camera entries name the drawn frames, keeps the same).
    drawn: bool,
    /// The renderers and the current one.
    pub renderers: Renderers,
    /// The last drawn image.
    pub image: Image,
    recorder: Option<RecordSink>,
    seen_frames: u64,
    server_rate: RateMeter,
}

impl Display {
    /// A display fed by `net`.
    pub fn new(net: Network, renderers: Renderers, recorder: Option<RecordSink>) -> Display {
        Display {
            net,
            shown: None,
            older: VecDeque::new(),
            keep: 1,
            drawn: false,
            renderers,
            image: Image::new(1, 1),
            recorder,
            seen_frames: 0,
            server_rate: RateMeter::default(),
        }
    }

    /// Keeps the `k` newest frames (at least 1): the current renderer fills what the newest
    /// does not cover from the older ones where it can ([`Renderers::render_set`]).
    pub fn set_keep_frames(&mut self, k: usize) {
        self.keep = k.clamp(1, volwarp_cpu_tracer::hole_fill::MAX_FRAMES);
        self.trim_older();
    }

    /// Hands the older frames beyond `keep − 1` back to the network.
    fn trim_older(&mut self) {
        while self.older.len() >= self.keep {
            if let Some(old) = self.older.pop_back() {
                self.net.recycle(old.scene);
            }
        }
    }

    /// How many frames the current drawing uses at most (1 where the renderer keeps none).
    pub fn frames_used(&self) -> usize {
        if self.renderers.keeps_frames() {
            self.keep
        } else {
            1
        }
    }

    /// Swaps in the newest ready scene, if any; `true` if one was swapped in.
    pub fn poll_scene(&mut self) -> bool {
        match self.net.take_scene() {
            Some(ready) => {
                // Frames of another visual state are never drawn beside the new one (their
                // colors would fill its holes): a state change drops them.
                let state = ready.state;
                let camera = ready.scene.header.camera;
                if let Some(old) = self.shown.replace(ready) {
                    // A frame for the same camera and state as the new one adds nothing beside
                    // it (the server's copy for a repeated request at rest): it would only push
                    // an older frame, a side view at rest, out of the kept ones.
                    if self.drawn && old.state == state && old.scene.header.camera != camera {
                        self.older.push_front(old);
                    } else {
                        self.net.recycle(old.scene);
                    }
                }
                if self.older.iter().any(|o| o.state != state || o.scene.header.camera == camera) {
                    for o in std::mem::take(&mut self.older) {
                        if o.state == state && o.scene.header.camera != camera {
                            self.older.push_back(o);
                        } else {
                            self.net.recycle(o.scene);
                        }
                    }
                }
                self.drawn = false;
                self.trim_older();
                true
            }
            None => false,
        }
    }

    /// Whether a scene is shown.
    pub fn has_scene(&self) -> bool {
        self.shown.is_some()
    }

    /// Asks for `view` and waits (polling) until the first scene is ready, the network fails,
    /// or `timeout` passes.
    pub fn wait_first_scene(&mut self, view: &View, timeout: Duration) -> Result<(), crate::ClientError> {
        self.net.set_view(*view);
        let t0 = Instant::now();
        while !self.has_scene() {
            self.check()?;
            if !self.poll_scene() {
                if t0.elapsed() > timeout {
                    let state = self.net.state().label().map(|l| format!(" ({l})")).unwrap_or_default();
                    return Err(crate::ClientError::Gone(format!(
                        "no frame from the server within {} s{state}",
                        timeout.as_secs_f64()
                    )));
                }
                std::thread::sleep(Duration::from_millis(2));
            }
        }
        Ok(())
    }

    /// The network's error, if it stopped.
    pub fn check(&self) -> Result<(), crate::ClientError> {
        match self.net.error() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// Server frames received per second (over the last second).
    pub fn server_fps(&mut self) -> f64 {
        let now = Instant::now();
        let n = self.net.frames_received();
        self.server_rate.add(n - self.seen_frames.min(n), now);
        self.seen_frames = n;
        self.server_rate.rate(now)
    }

    /// The network.
    pub fn network(&self) -> &Network {
        &self.net
    }

    /// One display frame for `view`: swap in a new scene if ready, publish the view, draw.
    pub fn frame(&mut self, view: &View) -> FrameReport {
        let gen0 = self.net.work_generation();
        let new_frame = self.poll_scene();
        self.net.set_view(*view);
        let t0 = Instant::now();
        match &self.shown {
            Some(s) => {
                let scenes: Vec<&volwarp_core::Scene> =
                    core::iter::once(&s.scene).chain(self.older.iter().map(|o| &o.scene)).collect();
                draw_kept(&mut self.renderers, &scenes, &view.camera, &mut self.image);
                self.drawn = true;
            }
            None => self.image.reset_for(&view.camera),
        }
        let render_ms = t0.elapsed().as_secs_f64() * 1e3;
        let frame_seq = self.shown.as_ref().map_or(0, |s| s.seq);
        if let Some(r) = &self.recorder {
            r.camera(CameraRequest {
                seq: frame_seq,
                camera: view.camera,
                heuristic: view.heuristic,
                radius_scale: view.radius_scale,
                layers: 0,
            });
        }
        let gen1 = self.net.work_generation();
        let now = Instant::now();
        FrameReport {
            render_ms,
            age_ms: self
                .shown
                .as_ref()
                .and_then(|s| s.requested_at)
                .map(|t| now.saturating_duration_since(t).as_secs_f64() * 1e3),
            samples: self.shown.as_ref().map_or(0, |s| s.scene.samples.len()),
            frame_seq,
            new_frame,
            during_build: gen0 % 2 == 1 || gen1 != gen0,
            build_ms: if new_frame { self.shown.as_ref().map(|s| s.build_ms) } else { None },
            state: self.shown.as_ref().map_or(0, |s| s.state),
        }
    }

    /// Stops the network (sends Bye) and drops the recorder sink.
    pub fn shutdown(self) {
        self.net.shutdown();
    }
}

/// Draws the kept frames (`scenes`, newest first) for `camera` as core's frame choice says
/// ([`volwarp_core::show`], the choice the session simulator scores): a frame rendered for
/// exactly this camera alone, as rendered; else the frames warped, the nearest first; else,
/// beyond the fallback angle, the nearest frame as rendered, resized where it has other pixels
/// than the view (a coarse frame, a resized window). Frames the current renderer does not keep
/// are not drawn ([`Renderers::render_set`] draws the first alone).
pub fn draw_kept(renderers: &mut Renderers, scenes: &[&volwarp_core::Scene], camera: &Camera, out: &mut Image) {
    let kept = if renderers.keeps_frames() { scenes.len() } else { scenes.len().min(1) };
    let views: Vec<Camera> = scenes[..kept].iter().map(|s| s.header.camera).collect();
    match show::choose(&views, camera, show::FALLBACK_DEG) {
        Show::Exact(i) => renderers.render_set(&[scenes[i]], camera, out),
        Show::Unwarped(i) if (views[i].width, views[i].height) == (camera.width, camera.height) => {
            renderers.render_set(&[scenes[i]], &views[i], out)
        }
        Show::Unwarped(i) => {
            // A coarse frame (or one for another window size): as rendered, resized.
            let mut own = Image::new(0, 0);
            renderers.render_set(&[scenes[i]], &views[i], &mut own);
            own.resize_into(camera.width, camera.height, out);
        }
        Show::Warp(order) => {
            let ordered: Vec<&volwarp_core::Scene> = order.iter().map(|&i| scenes[i]).collect();
            renderers.render_set(&ordered, camera, out)
        }
    }
}

/// Converts an RGBA8 image (R in the low byte) to minifb's `0RGB` pixels.
pub fn to_0rgb(image: &Image, out: &mut Vec<u32>) {
    out.clear();
    out.extend(image.pixels.iter().map(|&p| ((p & 0xff) << 16) | (p & 0xff00) | ((p >> 16) & 0xff)));
}

#[cfg(test)]
mod tests {
    use super::*;
    use volwarp_core::sample::pack_color;

    #[test]
    fn rgba_to_0rgb_swaps_red_and_blue_and_drops_alpha() {
        let img = Image { width: 2, height: 1, pixels: vec![pack_color(1, 2, 3, 255), pack_color(255, 0, 128, 7)] };
        let mut out = Vec::new();
        to_0rgb(&img, &mut out);
        assert_eq!(out, vec![0x010203, 0xff0080]);
    }

    #[test]
    fn rate_meter_counts_the_last_second() {
        let mut m = RateMeter::default();
        let t = Instant::now();
        m.add(3, t);
        assert_eq!(m.rate(t), 3.0);
        m.add(1, t + Duration::from_millis(1500));
        assert_eq!(m.rate(t + Duration::from_millis(1500)), 1.0);
    }
}
