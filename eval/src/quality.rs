//! The accuracy/speed sweep: for a dataset and each heuristic, the server renders one frame for
//! camera C0; for each camera of the orbit (and dolly) path the marcher renders the ground
//! truth, every renderer of the [`crate::roster`] warps the C0 frame to that camera, and the
//! result is scored against the truth ([`Metrics`]). Each renderer is also timed at 512² and
//! 1024² (the client's draw call only; the scene is built beforehand): the median of
//! `runs` renders after one warm-up, each drawing its own frame of that viewport size.

use crate::camera_paths::{dolly, orbit, DOLLY_FACTORS, ORBIT_DEGREES};
use crate::roster::{Entry, SceneSet};
use crate::{median, Metrics};
use std::time::Instant;
use volwarp_core::renderer::Renderer;
use volwarp_core::wire::{CameraRequest, Frame};
use volwarp_core::{Camera, Heuristic, Image, Scene};
use volwarp_server::Marcher;

/// The columns of `quality.csv`, in order.
pub const QUALITY_COLUMNS: [&str; 9] =
    ["dataset", "heuristic", "renderer", "angle_deg", "psnr", "ssim", "flip", "ms_512", "ms_1024"];

/// The viewport sizes of the timing columns.
pub const TIME_SIZES: [u32; 2] = [512, 1024];

/// What to evaluate.
#[derive(Clone, Debug)]
pub struct QualityOptions {
    /// Viewport side of the accuracy comparison.
    pub size: u32,
    /// Renders per timing (their median is reported); 0 disables timing.
    pub runs: usize,
    /// Time every heuristic (otherwise only the first one of the list; the others' time cells
    /// stay empty: the client's cost hardly depends on the heuristic).
    pub time_all_heuristics: bool,
    /// Largest viewport side at which the GPU tracer is timed (it may run on a slow software
    /// adapter).
    pub gpu_max_time_size: u32,
    /// Orbit angles in degrees.
    pub angles: Vec<f32>,
    /// Dolly factors.
    pub dolly: Vec<f32>,
}

impl Default for QualityOptions {
    fn default() -> Self {
        QualityOptions {
            size: 512,
            runs: 3,
            time_all_heuristics: false,
            gpu_max_time_size: 512,
            angles: ORBIT_DEGREES.to_vec(),
            dolly: DOLLY_FACTORS.to_vec(),
        }
    }
}

/// One row of `quality.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    /// Dataset name.
    pub dataset: String,
    /// Depth heuristic of the frame.
    pub heuristic: Heuristic,
    /// Renderer name.
    pub renderer: String,
    /// Orbit angle away from C0, degrees.
    pub angle_deg: f32,
    /// Scores against the truth.
    pub metrics: Metrics,
    /// Median client ms at 512² and 1024² (`None`: not timed).
    pub ms: [Option<f64>; 2],
}

/// One row of `dolly.csv`: the same scores along the dolly path.
#[derive(Clone, Debug, PartialEq)]
pub struct DollyRow {
    /// Dataset name.
    pub dataset: String,
    /// Depth heuristic of the frame.
    pub heuristic: Heuristic,
    /// Renderer name.
    pub renderer: String,
    /// New distance over old.
    pub factor: f32,
    /// Scores against the truth.
    pub metrics: Metrics,
}

/// The pictures of the paper's Figure 3 (first heuristic only), one per orbit angle.
#[derive(Clone, Debug, Default)]
pub struct StripImages {
    /// The marcher's truth.
    pub truth: Vec<Image>,
    /// The CPU sphere tracer.
    pub spheres: Vec<Image>,
    /// One-pixel points.
    pub points: Vec<Image>,
}

/// Everything measured for one dataset.
#[derive(Clone, Debug, Default)]
pub struct DatasetResult {
    /// Orbit rows.
    pub rows: Vec<Row>,
    /// Dolly rows.
    pub dolly_rows: Vec<DollyRow>,
    /// Figure 3 pictures.
    pub strip: StripImages,
    /// Samples of each heuristic's C0 frame.
    pub samples: Vec<(Heuristic, usize)>,
}

/// The frame the server sends for `camera` with `heuristic` (radius ×1).
pub fn frame_for(marcher: &Marcher, camera: &Camera, heuristic: Heuristic) -> Frame {
    marcher.render_frame(&CameraRequest { seq: 1, camera: *camera, heuristic, radius_scale: 1.0, layers: 0 }).0
}

/// Median ms of `runs` renders after one warm-up.
pub fn time_renderer(r: &mut dyn Renderer, scene: &Scene, camera: &Camera, runs: usize) -> f64 {
    let mut img = Image::new(0, 0);
    r.render(scene, camera, &mut img);
    let mut ms: Vec<f64> = (0..runs.max(1))
        .map(|_| {
            let t = Instant::now();
            r.render(scene, camera, &mut img);
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    median(&mut ms).unwrap_or(0.0)
}

/// Runs the sweep for one dataset (see the module docs). `progress` gets a line per step.
pub fn evaluate(
    dataset: &str,
    marcher: &Marcher,
    heuristics: &[Heuristic],
    roster: &mut [Entry],
    opts: &QualityOptions,
    progress: &mut dyn FnMut(&str),
) -> DatasetResult {
    let mut out = DatasetResult::default();
    let c0 = marcher.default_camera(opts.size, opts.size);
    let cams: Vec<Camera> = opts.angles.iter().map(|&a| orbit(&c0, a)).collect();
    let dollies: Vec<Camera> = opts.dolly.iter().map(|&f| dolly(&c0, f)).collect();
    progress(&format!("{dataset}: ground truth for {} orbit and {} dolly cameras", cams.len(), dollies.len()));
    let truths: Vec<Image> = cams.iter().map(|c| marcher.render_image(c)).collect();
    let dolly_truths: Vec<Image> = dollies.iter().map(|c| marcher.render_image(c)).collect();
    let total = heuristics.len();
    for (hi, &h) in heuristics.iter().enumerate() {
        let frame = frame_for(marcher, &c0, h);
        out.samples.push((h, frame.samples.len()));
        progress(&format!(
            "{dataset} [{}/{total}] {h}: C0 frame {} samples; warping to {} cameras with {} renderers",
            hi + 1,
            frame.samples.len(),
            cams.len() + dollies.len(),
            roster.len()
        ));
        let scenes = SceneSet::build(&frame);
        let timed = opts.runs > 0 && (hi == 0 || opts.time_all_heuristics);
        let mut img = Image::new(0, 0);
        let first_row = out.rows.len();
        for (ai, (cam, truth)) in cams.iter().zip(&truths).enumerate() {
            for e in roster.iter_mut() {
                let scene = scenes.get(e.radius_scale);
                e.renderer.render(scene, cam, &mut img);
                let m = Metrics::of(truth, &img).unwrap_or(Metrics { psnr: 0.0, ssim: 0.0, flip: 1.0 });
                out.rows.push(Row {
                    dataset: dataset.into(),
                    heuristic: h,
                    renderer: e.name.clone(),
                    angle_deg: opts.angles[ai],
                    metrics: m,
                    ms: [None, None],
                });
                if hi == 0 {
                    match e.name.as_str() {
                        "spheres-cpu" => out.strip.spheres.push(img.clone()),
                        "points1" => out.strip.points.push(img.clone()),
                        _ => {}
                    }
                }
            }
            progress(&format!("{dataset} {h}: {}° scored", opts.angles[ai]));
        }
        if hi == 0 {
            out.strip.truth = truths.clone();
        }
        for (di, (cam, truth)) in dollies.iter().zip(&dolly_truths).enumerate() {
            for e in roster.iter_mut() {
                e.renderer.render(scenes.get(e.radius_scale), cam, &mut img);
                let m = Metrics::of(truth, &img).unwrap_or(Metrics { psnr: 0.0, ssim: 0.0, flip: 1.0 });
                out.dolly_rows.push(DollyRow {
                    dataset: dataset.into(),
                    heuristic: h,
                    renderer: e.name.clone(),
                    factor: opts.dolly[di],
                    metrics: m,
                });
            }
        }
        if timed {
            for (si, &size) in TIME_SIZES.iter().enumerate() {
                let (owned, scenes_at): (Option<SceneSet>, &SceneSet) = if size == opts.size {
                    (None, &scenes)
                } else {
                    let c = c0.with_viewport(size, size);
                    progress(&format!("{dataset} {h}: frame at {size}² for timing"));
                    let s = SceneSet::build(&frame_for(marcher, &c, h));
                    (Some(s), &scenes)
                };
                let scenes_at = owned.as_ref().unwrap_or(scenes_at);
                // Rows of one angle are contiguous, one per renderer.
                let n = roster.len();
                for (ai, &a) in opts.angles.iter().enumerate() {
                    let cam = orbit(&c0.with_viewport(size, size), a);
                    for (ei, e) in roster.iter_mut().enumerate() {
                        if e.gpu && size > opts.gpu_max_time_size {
                            continue;
                        }
                        let ms = time_renderer(e.renderer.as_mut(), scenes_at.get(e.radius_scale), &cam, opts.runs);
                        let row = &mut out.rows[first_row + ai * n + ei];
                        row.ms[si] = Some(ms);
                    }
                }
                progress(&format!("{dataset} {h}: timed at {size}²"));
            }
        }
    }
    out
}
