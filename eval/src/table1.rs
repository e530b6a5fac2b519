//! The paper's Table 1 on this machine: five views of the MRI at 1024², like Figure 3 — the
//! frame is rendered for view 1 and warped to views 1–5 (orbits of 0, 10, 20, 30 and 45° around
//! the head). Reported: samples after compaction, compaction time (serial, as the paper's, and
//! the server's parallel one), LBVH build time (serial reference, parallel CPU, GPU), and frames
//! per second per view for each tracer.
//!
//! CPU FPS are `1000 / median ms` of full renders (trace + shade into the image). GPU FPS are
//! the shader's throughput without readback (`GpuTracer::trace_only`, like a client that draws
//! straight to its window), here on whatever adapter opens — lavapipe (software Vulkan on the
//! CPU) on a machine without a GPU.

use crate::charts::{self, Legend, Mark, Panel, Series, XAxis};
use crate::csv::{num, Table};
use crate::quality::time_renderer;
use crate::{median, ErrorBox};
use std::path::Path;
use std::time::Instant;
use volwarp_core::wire::{CameraRequest, Frame};
use volwarp_core::{Camera, Heuristic, RendererKind, Scene};
use volwarp_server::dataset::Dataset;
use volwarp_server::Marcher;

/// Orbit of each view away from view 1, degrees.
pub const VIEW_DEGREES: [f32; 5] = [0.0, 10.0, 20.0, 30.0, 45.0];
/// The paper's FPS per view (RTX 2080, CUDA, 1024²).
pub const PAPER_FPS: [f64; 5] = [292.0, 276.0, 283.0, 229.0, 408.0];
/// The paper's sample count after compaction.
pub const PAPER_SAMPLES: usize = 623_584;
/// The paper's compaction time (serial), ms.
pub const PAPER_COMPACT_MS: f64 = 23.0;
/// The paper's LBVH build time, ms.
pub const PAPER_LBVH_MS: f64 = 11.0;
/// How far view 1 is dollied in from the default framing (the head fills the image, as in the
/// paper's figure).
pub const VIEW_DOLLY: f32 = 0.66;

/// Everything the table reports.
#[derive(Clone, Debug, Default)]
pub struct Table1 {
    /// Dataset name.
    pub dataset: String,
    /// Viewport side.
    pub size: u32,
    /// Heuristic.
    pub heuristic: String,
    /// Samples after compaction.
    pub samples: usize,
    /// Marching the frame, ms (server).
    pub march_ms: f64,
    /// Serial compaction, ms (median).
    pub compact_serial_ms: f64,
    /// Parallel compaction (server), ms (median).
    pub compact_parallel_ms: f64,
    /// Serial LBVH build (`Scene::build`), ms (median).
    pub lbvh_serial_ms: f64,
    /// Parallel CPU LBVH build, ms (median).
    pub lbvh_parallel_ms: f64,
    /// GPU LBVH build (compute passes only), ms, where a GPU adapter opened.
    pub lbvh_gpu_ms: Option<f64>,
    /// `(tracer name, FPS per view)`.
    pub fps: Vec<(String, [f64; 5])>,
    /// The GPU adapter, if any.
    pub gpu_adapter: Option<String>,
}

fn med(mut v: Vec<f64>) -> f64 {
    median(&mut v).unwrap_or(f64::NAN)
}

/// The five cameras.
pub fn views(marcher: &Marcher, size: u32) -> [Camera; 5] {
    let c0 = marcher.default_camera(size, size).dolly(VIEW_DOLLY);
    VIEW_DEGREES.map(|d| crate::camera_paths::orbit(&c0, d))
}

/// Measures the table (see the module docs).
pub fn measure(ds: &Dataset, heuristic: Heuristic, size: u32, runs: usize, threads: usize, gpu: bool) -> Table1 {
    let marcher = Marcher::from_dataset(ds);
    let cams = views(&marcher, size);
    let runs = runs.max(1);
    log::info!("table1: marching view 1 of {} at {size}² ({})", ds.name, heuristic.name());
    let t = Instant::now();
    let req = CameraRequest { seq: 1, camera: cams[0], heuristic, radius_scale: 1.0, layers: 0 };
    let (frame, stats) = marcher.render_frame(&req);
    let march_ms = t.elapsed().as_secs_f64() * 1e3;
    // The uncompacted buffer, as the server has it before compaction.
    let pb = marcher.march(&cams[0], heuristic);
    let full = marcher.quantize(&req, &pb).0;
    let (mut os, mut oc) = (vec![0u64; full.len()], vec![0u32; full.len()]);
    let mut n_serial = 0;
    let compact_serial_ms = med((0..runs)
        .map(|_| {
            let t = Instant::now();
            n_serial = volwarp_core::compaction::compact_into(&full, &pb.color, &mut os, &mut oc);
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect());
    let compact_parallel_ms = med((0..runs)
        .map(|_| {
            let t = Instant::now();
            let r = volwarp_server::compaction::compact(&full, &pb.color);
            let ms = t.elapsed().as_secs_f64() * 1e3;
            drop(r);
            ms
        })
        .collect());
    if n_serial != stats.samples {
        log::warn!("serial compaction kept {n_serial} samples, the server's frame has {}", stats.samples);
    }
    log::info!("table1: {} samples; timing LBVH builds", stats.samples);
    let lbvh_serial_ms = med((0..runs)
        .map(|_| {
            let t = Instant::now();
            let s = Scene::build(&frame);
            let ms = t.elapsed().as_secs_f64() * 1e3;
            drop(s);
            ms
        })
        .collect());
    let mut pb_builder = volwarp_cpu_tracer::ParallelBuilder::new(threads);
    let mut scene = pb_builder.build(&frame);
    let lbvh_parallel_ms = med((0..runs)
        .map(|_| {
            let t = Instant::now();
            pb_builder.build_into(&frame, &mut scene);
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect());
    let mut out = Table1 {
        dataset: ds.name.clone(),
        size,
        heuristic: heuristic.name().into(),
        samples: stats.samples,
        march_ms,
        compact_serial_ms,
        compact_parallel_ms,
        lbvh_serial_ms,
        lbvh_parallel_ms,
        ..Default::default()
    };
    let mut cpu = volwarp_cpu_tracer::PacketTracer::new(threads);
    let mut fps = [0.0; 5];
    for (k, c) in cams.iter().enumerate() {
        fps[k] = 1000.0 / time_renderer(&mut cpu, &scene, c, runs);
        log::info!("table1: spheres-cpu view {} {:.1} FPS", k + 1, fps[k]);
    }
    out.fps.push((RendererKind::SpheresCpu.name().into(), fps));
    if gpu {
        gpu_part(&frame, &scene, &cams, runs, &mut out);
    }
    out
}

#[cfg(feature = "gpu")]
fn gpu_part(frame: &Frame, scene: &Scene, cams: &[Camera; 5], runs: usize, out: &mut Table1) {
    let mut g = match volwarp_gpu_tracer::GpuTracer::new() {
        Ok(g) => g,
        Err(e) => {
            log::warn!("table1: no GPU tracer: {e}");
            return;
        }
    };
    out.gpu_adapter = Some(g.context().describe());
    match g.build_scene(frame) {
        Ok(_) => {
            let mut b = vec![g.last_build_timing().build.as_secs_f64() * 1e3];
            for _ in 1..runs.min(3) {
                if g.build_scene(frame).is_ok() {
                    b.push(g.last_build_timing().build.as_secs_f64() * 1e3);
                }
            }
            out.lbvh_gpu_ms = Some(med(b));
        }
        Err(e) => log::warn!("table1: GPU LBVH build failed: {e}"),
    }
    let mut fps = [f64::NAN; 5];
    for (k, c) in cams.iter().enumerate() {
        let frames = runs.clamp(1, 5) as u32;
        match g.trace_only(scene, c, 1).and_then(|_| g.trace_only(scene, c, frames)) {
            Ok(d) => fps[k] = frames as f64 / d.as_secs_f64().max(1e-9),
            Err(e) => log::warn!("table1: GPU trace failed: {e}"),
        }
        log::info!("table1: spheres-gpu view {} {:.2} FPS", k + 1, fps[k]);
    }
    out.fps.push((RendererKind::SpheresGpu.name().into(), fps));
}

#[cfg(not(feature = "gpu"))]
fn gpu_part(_: &Frame, _: &Scene, _: &[Camera; 5], _: usize, _: &mut Table1) {
    log::info!("table1: built without the `gpu` feature; no GPU column");
}

impl Table1 {
    /// The markdown table next to the paper's figures.
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        s.push_str(&format!(
            "{} at {}², heuristic `{}`, frame rendered for view 1 and warped to views 1–5 (orbits of {}°).\n\n",
            self.dataset,
            self.size,
            self.heuristic,
            VIEW_DEGREES.iter().map(|d| format!("{d}")).collect::<Vec<_>>().join(", ")
        ));
        s.push_str("| | paper (RTX 2080, CUDA) | this machine |\n|---|---|---|\n");
        s.push_str(&format!("| samples after compaction | {PAPER_SAMPLES} | {} |\n", self.samples));
        s.push_str(&format!(
            "| compaction | {PAPER_COMPACT_MS} ms (serial) | {:.1} ms serial, {:.1} ms parallel (2 threads) |\n",
            self.compact_serial_ms, self.compact_parallel_ms
        ));
        let gpu = self.lbvh_gpu_ms.map_or(String::new(), |g| format!(", {g:.0} ms GPU build passes"));
        s.push_str(&format!(
            "| LBVH build | {PAPER_LBVH_MS} ms | {:.1} ms serial, {:.1} ms parallel CPU{gpu} |\n",
            self.lbvh_serial_ms, self.lbvh_parallel_ms
        ));
        s.push_str(&format!("| server march (not in the paper's table) | — | {:.0} ms |\n\n", self.march_ms));
        s.push_str("| FPS | View 1 | View 2 | View 3 | View 4 | View 5 |\n|---|---|---|---|---|---|\n");
        s.push_str(&format!(
            "| paper, RTX 2080 | {} |\n",
            PAPER_FPS.iter().map(|f| format!("{f:.0}")).collect::<Vec<_>>().join(" | ")
        ));
        for (name, fps) in &self.fps {
            let label = if name == RendererKind::SpheresGpu.name() {
                format!("spheres-gpu ({})", self.gpu_adapter.as_deref().unwrap_or("GPU"))
            } else {
                format!("{name} (2 cores)")
            };
            s.push_str(&format!(
                "| {label} | {} |\n",
                fps.iter().map(|f| num(Some(*f), if *f < 10.0 { 2 } else { 1 })).collect::<Vec<_>>().join(" | ")
            ));
        }
        s
    }

    /// The CSV (one row per tracer and view).
    pub fn csv(&self) -> Table {
        let mut t = Table::new(&[
            "dataset",
            "size",
            "samples",
            "compact_serial_ms",
            "compact_parallel_ms",
            "lbvh_serial_ms",
            "lbvh_parallel_ms",
            "lbvh_gpu_ms",
            "tracer",
            "view",
            "fps",
        ]);
        for (name, fps) in &self.fps {
            for (k, f) in fps.iter().enumerate() {
                t.push(vec![
                    self.dataset.clone(),
                    self.size.to_string(),
                    self.samples.to_string(),
                    num(Some(self.compact_serial_ms), 2),
                    num(Some(self.compact_parallel_ms), 2),
                    num(Some(self.lbvh_serial_ms), 2),
                    num(Some(self.lbvh_parallel_ms), 2),
                    num(self.lbvh_gpu_ms, 2),
                    name.clone(),
                    (k + 1).to_string(),
                    num(Some(*f), 3),
                ]);
            }
        }
        t
    }
}

const BEGIN: &str = "<!-- table1:begin (written by volwarp-eval table1) -->";
const END: &str = "<!-- table1:end -->";

/// Replaces the text between the table1 markers of a markdown file (appends them if absent).
pub fn splice(doc: &str, body: &str) -> String {
    let block = format!("{BEGIN}\n{}\n{END}", body.trim_end());
    match (doc.find(BEGIN), doc.find(END)) {
        (Some(a), Some(b)) if b > a => format!("{}{block}{}", &doc[..a], &doc[b + END.len()..]),
        _ => format!("{}\n\n{block}\n", doc.trim_end()),
    }
}

/// `volwarp-eval table1`: writes `table1.md`, `table1.csv` and `table1.png` into `out`, and the
/// table into `results` between its markers.
#[allow(clippy::too_many_arguments)]
pub fn run(
    ds: &Dataset,
    heuristic: Heuristic,
    size: u32,
    runs: usize,
    threads: usize,
    gpu: bool,
    out: &Path,
    results: Option<&Path>,
) -> Result<(), ErrorBox> {
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let t = measure(ds, heuristic, size, runs, threads, gpu);
    let md = t.markdown();
    std::fs::write(out.join("table1.md"), &md)?;
    t.csv().write(&out.join("table1.csv"))?;
    let mut series = vec![Series::new(
        "paper: RTX 2080 (CUDA)",
        PAPER_FPS.iter().enumerate().map(|(k, f)| (k as f64, f.log10())).collect(),
        Mark::Line,
        7,
    )];
    for (i, (name, fps)) in t.fps.iter().enumerate() {
        let pts = fps.iter().enumerate().filter(|(_, f)| **f > 0.0).map(|(k, f)| (k as f64, f.log10())).collect();
        series.push(Series::new(name, pts, Mark::Line, i));
    }
    let panel = Panel {
        title: format!("FPS per view at {}² ({} samples), log scale", size, t.samples),
        x_desc: "view".into(),
        y_desc: "frames per second".into(),
        series,
        x_axis: XAxis::Categories((1..=5).map(|k| format!("view {k}")).collect()),
        y_range: None,
        y_log: true,
        legend: Legend::LowerRight,
    };
    charts::draw(&out.join("table1.png"), 1000, 560, &[panel])?;
    if let Some(p) = results {
        let doc = std::fs::read_to_string(p).unwrap_or_default();
        std::fs::write(p, splice(&doc, &md))?;
        log::info!("table1 written into {}", p.display());
    }
    log::info!("\n{md}");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splice_replaces_between_markers() {
        let a = splice("# R\n", "x");
        assert!(a.contains(BEGIN) && a.contains("\nx\n"));
        let b = splice(&format!("{a}tail\n"), "y");
        assert!(b.contains("\ny\n") && !b.contains("\nx\n") && b.ends_with("tail\n"));
    }
}
