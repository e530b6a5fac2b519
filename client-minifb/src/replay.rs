//! `--replay FILE`: plays a recorded stream back offline, through any renderer. Each camera
//! entry is drawn with the frame that was on screen when it was recorded (the entry's `seq`,
//! see [`crate::record`]), so replaying with the renderer of the recording reproduces the
//! recorded display frames exactly. Headless, every camera entry becomes a PNG (same names as
//! `--headless`) and a line of `timings.csv`; in a window the entries play at their recorded
//! times.

use crate::display::{FrameReport, RateMeter};
use crate::error::ClientError;
use crate::headless::{csv_line, frame_file, CSV_HEADER};
use crate::options::Options;
use crate::renderers::Renderers;
use crate::window::{title, Screen, TITLE_EVERY};
use embedded_io_adapters::std::FromStd;
use std::collections::VecDeque;
use std::fs::File;
use std::io::BufReader;
use std::path::Path;
use std::time::{Duration, Instant};
use volwarp_core::record::{self, Entry};
use volwarp_core::renderer::Image;
use volwarp_core::wire::{CameraRequest, Frame, Limits};
use volwarp_core::Scene;
use volwarp_cpu_tracer::ParallelBuilder;

/// Decoded frames kept to find the one a camera entry names.
const KEEP_FRAMES: usize = 8;

/// A record file being played.
pub struct Replay {
    reader: FromStd<BufReader<File>>,
    limits: Limits,
    frames: VecDeque<Frame>,
    scene: Option<Scene>,
    /// The frames drawn before the shown one, newest first (at most `keep − 1`; only for
    /// unbuilt scenes, what the renderers that keep frames draw).
    older: VecDeque<Scene>,
    keep: usize,
    builder: ParallelBuilder,
    /// Hand scenes over unbuilt (as the live client does for a renderer that needs no LBVH),
    /// so that replay draws the very same images.
    lazy: bool,
    warned: bool,
}

impl Replay {
    /// Opens `path` and checks its magic bytes.
    pub fn open(path: &Path, build_threads: usize) -> Result<Replay, ClientError> {
        let f = File::open(path).map_err(|e| ClientError::Io(format!("cannot open {}: {e}", path.display())))?;
        let mut reader = FromStd::new(BufReader::with_capacity(1 << 20, f));
        record::read_magic(&mut reader).map_err(|e| ClientError::Record(format!("{}: {e}", path.display())))?;
        Ok(Replay {
            reader,
            limits: Limits::default(),
            frames: VecDeque::new(),
            scene: None,
            older: VecDeque::new(),
            keep: 1,
            builder: ParallelBuilder::new(build_threads),
            lazy: false,
            warned: false,
        })
    }

    /// Hands scenes over unbuilt (`true`) or built, as the live client does for the renderer.
    pub fn set_lazy_build(&mut self, lazy: bool) {
        self.lazy = lazy;
        self.scene = None;
        self.older.clear();
    }

    /// Keeps the `k` newest frames up to the shown one, as the live client's `--keep-frames`.
    pub fn set_keep_frames(&mut self, k: usize) {
        self.keep = k.clamp(1, KEEP_FRAMES);
    }

    /// The next camera entry (time in µs and the request), storing the frames before it.
    pub fn next_camera(&mut self) -> Result<Option<(u64, CameraRequest)>, ClientError> {
        loop {
            match record::read_entry(&mut self.reader, &self.limits) {
                Ok(None) => return Ok(None),
                Ok(Some(Entry::Frame { frame, .. })) => {
                    if self.frames.len() >= KEEP_FRAMES {
                        self.frames.pop_front();
                    }
                    self.frames.push_back(frame);
                }
                Ok(Some(Entry::Camera { t_us, request })) => return Ok(Some((t_us, request))),
                Err(e) => return Err(ClientError::Record(e.to_string())),
            }
        }
    }

    /// The scene shown with a camera entry naming frame `seq` (`None` before any frame).
    pub fn scene_for(&mut self, seq: u64) -> Option<&Scene> {
        if seq == 0 {
            return None;
        }
        if self.scene.as_ref().is_some_and(|s| s.header.seq == seq) {
            return self.scene.as_ref();
        }
        let frame = match self.frames.iter().rev().find(|f| f.header.seq == seq) {
            Some(f) => f,
            None => {
                if !self.warned {
                    log::warn!("replay: frame {seq} is not in the record; using the newest frame before it");
                    self.warned = true;
                }
                self.frames.back()?
            }
        };
        let fresh = frame.header.seq;
        if self.scene.as_ref().is_some_and(|s| s.header.seq == fresh) {
            return self.scene.as_ref();
        }
        // The live display keeps the frames it drew before (the camera entries name them).
        let camera = frame.header.camera;
        if self.lazy && self.keep > 1 {
            if let Some(prev) = self.scene.take() {
                self.older.push_front(prev);
            }
            // As the live display: a frame for the new frame's camera adds nothing beside it.
            self.older.retain(|s| s.header.camera != camera);
            self.older.truncate(self.keep - 1);
        }
        match self.scene.as_mut() {
            _ if self.lazy => self.scene = Some(volwarp_cpu_tracer::route::unbuilt_scene(frame)),
            Some(s) => self.builder.build_into(frame, s),
            None => self.scene = Some(self.builder.build(frame)),
        }
        self.scene.as_ref()
    }

    /// The scene shown with a camera entry naming frame `seq` and the older frames kept with
    /// it, newest first (empty before any frame).
    pub fn scenes_for(&mut self, seq: u64) -> Vec<&Scene> {
        if self.scene_for(seq).is_none() {
            return Vec::new();
        }
        self.scene.iter().chain(self.older.iter()).collect()
    }
}

/// Draws one camera entry.
pub fn draw(replay: &mut Replay, renderers: &mut Renderers, req: &CameraRequest, image: &mut Image) -> FrameReport {
    let t0 = Instant::now();
    let scenes = replay.scenes_for(req.seq);
    let samples = scenes.first().map_or(0, |s| s.samples.len());
    // As the live display draws them: core's frame choice among the kept frames.
    match scenes.first() {
        Some(_) => crate::display::draw_kept(renderers, &scenes, &req.camera, image),
        None => image.reset_for(&req.camera),
    }
    FrameReport {
        render_ms: t0.elapsed().as_secs_f64() * 1e3,
        age_ms: None,
        samples,
        frame_seq: req.seq,
        new_frame: false,
        during_build: false,
        build_ms: None,
        state: 0,
    }
}

/// Replays `path`: to PNG files with `--headless --out DIR`, else in a window.
pub fn run(opts: &Options, path: &Path) -> Result<(), ClientError> {
    let mut replay = Replay::open(path, opts.build_threads)?;
    crate::renderers::set_layer_options(opts.layer_options());
    let mut renderers = Renderers::new(opts.renderer, opts.tracer_threads()).map_err(ClientError::Renderer)?;
    renderers.set_adaptive_radius(opts.adapt);
    replay.set_lazy_build(!opts.renderer.info().caps.needs_lbvh);
    replay.set_keep_frames(opts.keep_frames);
    if !opts.headless {
        return run_window(opts, &mut replay, &mut renderers);
    }
    let out = opts.out.as_deref().ok_or_else(|| ClientError::Usage("--headless --replay needs --out DIR".into()))?;
    std::fs::create_dir_all(out).map_err(|e| ClientError::Io(format!("cannot create {}: {e}", out.display())))?;
    let mut csv = String::from(CSV_HEADER);
    csv.push('\n');
    let mut image = Image::new(1, 1);
    let mut i = 0usize;
    let limit = opts.frames.map_or(usize::MAX, |n| n as usize);
    while i < limit {
        let Some((_, req)) = replay.next_camera()? else { break };
        let t0 = Instant::now();
        let r = draw(&mut replay, &mut renderers, &req, &mut image);
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        image.save_png(&out.join(frame_file(i))).map_err(|e| ClientError::Io(e.to_string()))?;
        csv_line(&mut csv, i, ms, &r, renderers.name());
        i += 1;
    }
    let p = out.join("timings.csv");
    std::fs::write(&p, csv).map_err(|e| ClientError::Io(format!("cannot write {}: {e}", p.display())))?;
    log::info!("replay: {i} frames written to {}", out.display());
    Ok(())
}

/// Sleeps until `t_us` after `start` (at most a second per entry, so long pauses stay short).
pub fn wait_until(start: Instant, t_us: u64) {
    let due = start + Duration::from_micros(t_us);
    std::thread::sleep(due.saturating_duration_since(Instant::now()).min(Duration::from_secs(1)));
}

/// Plays a record file in a window at its recorded pace; the number keys switch the renderer.
fn run_window(opts: &Options, replay: &mut Replay, renderers: &mut Renderers) -> Result<(), ClientError> {
    let mut screen = Screen::open("volwarp replay", opts.size.0, opts.size.1, opts.fps.unwrap_or(60))?;
    let mut image = Image::new(1, 1);
    let mut meter = RateMeter::default();
    let mut last_title = Instant::now() - TITLE_EVERY;
    let mut start: Option<(Instant, u64)> = None;
    let mut done = false;
    while !screen.quit() {
        if let Some(k) = screen.renderer_key() {
            let _ = renderers.select_key(k);
        }
        if done {
            screen.present(&image)?;
            continue;
        }
        let Some((t_us, req)) = replay.next_camera()? else {
            log::info!("replay finished; close the window to quit");
            done = true;
            continue;
        };
        let (t0, first_us) = *start.get_or_insert((Instant::now(), t_us));
        wait_until(t0, t_us.saturating_sub(first_us));
        let r = draw(replay, renderers, &req, &mut image);
        screen.present(&image)?;
        meter.add(1, Instant::now());
        if last_title.elapsed() >= TITLE_EVERY {
            last_title = Instant::now();
            let t = title(meter.rate(last_title), 0.0, None, r.samples, renderers.name(), req.heuristic);
            screen.window.set_title(&format!("{t} | replay"));
        }
    }
    Ok(())
}
