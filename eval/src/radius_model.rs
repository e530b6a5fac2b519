//! Which sphere radius? Accuracy against tracing speed for the server's radius models
//! ([`volwarp_server::radius`]): half a voxel diagonal (the seed paper's) and the pixel's
//! footprint at the sample's depth, each at a few scales.
//!
//! For each dataset, the server renders the C0 frame once per variant (model × scale) at
//! `size`²; the packet tracer warps it to each orbit angle and the result is scored against the
//! marcher's truth for that camera. The tracer is timed on one thread at the 10° camera (the
//! median of `runs` renders after a warm-up). Output: `radius.csv`, `radius.png` (FLIP at 10°
//! against ms, and FLIP against angle) and `radius.md`.

use crate::camera_paths::orbit;
use crate::charts::{self, Legend, Mark, Panel, Series, XAxis};
use crate::csv::{num, Table};
use crate::quality::time_renderer;
use crate::{ErrorBox, Metrics};
use std::path::Path;
use volwarp_core::renderer::Renderer;
use volwarp_core::wire::CameraRequest;
use volwarp_core::{Heuristic, Image, Scene};
use volwarp_cpu_tracer::PacketTracer;
use volwarp_server::dataset::Dataset;
use volwarp_server::{MarchOptions, Marcher, RadiusModel};

/// The variants: a model and a scale of its radius.
pub const VARIANTS: [(RadiusModel, f32); 7] = [
    (RadiusModel::Voxel, 0.25),
    (RadiusModel::Voxel, 0.5),
    (RadiusModel::Voxel, 1.0),
    (RadiusModel::Footprint, 0.5),
    (RadiusModel::Footprint, 0.71),
    (RadiusModel::Footprint, 1.0),
    (RadiusModel::Footprint, 1.41),
];

/// Orbit angles of the study, degrees.
pub const ANGLES: [f32; 5] = [0.0, 2.5, 5.0, 10.0, 20.0];

/// The angle at which the tracer is timed.
pub const TIMED_ANGLE: f32 = 10.0;

/// A variant's label: `voxel×0.5`, `footprint×1`.
pub fn label(model: RadiusModel, scale: f32) -> String {
    format!("{}×{}", model.name(), scale)
}

/// One variant's result on one dataset.
#[derive(Clone, Debug)]
pub struct VariantResult {
    /// Dataset name.
    pub dataset: String,
    /// Radius model.
    pub model: RadiusModel,
    /// Scale of the model's radius.
    pub scale: f32,
    /// Samples of the frame.
    pub samples: usize,
    /// Scores per angle of [`ANGLES`].
    pub metrics: Vec<Metrics>,
    /// Median single-thread tracing ms at [`TIMED_ANGLE`] (`None`: not timed).
    pub ms: Option<f64>,
}

/// Runs the study on one dataset at `size`² (see the module docs).
pub fn study(ds: &Dataset, heuristic: Heuristic, size: u32, runs: usize) -> Vec<VariantResult> {
    let base = Marcher::from_dataset(ds);
    let c0 = base.default_camera(size, size);
    log::info!("{}: radius study at {size}², truth for {} angles", ds.name, ANGLES.len());
    let truths: Vec<Image> = ANGLES.iter().map(|&a| base.render_image(&orbit(&c0, a))).collect();
    let mut tracer = PacketTracer::new(1);
    let mut img = Image::new(0, 0);
    let mut out = Vec::new();
    for (model, scale) in VARIANTS {
        let m = base.with_transfer_function(&ds.tf, MarchOptions { radius: model, ..base.options() });
        let frame = m.render_frame(&CameraRequest { seq: 1, camera: c0, heuristic, radius_scale: scale, layers: 0 }).0;
        let scene = Scene::build(&frame);
        let metrics: Vec<Metrics> = ANGLES
            .iter()
            .zip(&truths)
            .map(|(&a, truth)| {
                tracer.render(&scene, &orbit(&c0, a), &mut img);
                Metrics::of(truth, &img).unwrap_or(Metrics { psnr: 0.0, ssim: 0.0, flip: 1.0 })
            })
            .collect();
        let ms = (runs > 0).then(|| time_renderer(&mut tracer, &scene, &orbit(&c0, TIMED_ANGLE), runs));
        log::info!(
            "{} {}: {} samples, FLIP {} , {} ms",
            ds.name,
            label(model, scale),
            frame.samples.len(),
            metrics.iter().map(|m| format!("{:.4}", m.flip)).collect::<Vec<_>>().join(" "),
            ms.map_or("-".into(), |v| format!("{v:.1}"))
        );
        out.push(VariantResult { dataset: ds.name.clone(), model, scale, samples: frame.samples.len(), metrics, ms });
    }
    out
}

/// The CSV of results.
pub fn table(results: &[VariantResult]) -> Table {
    let mut t =
        Table::new(&["dataset", "model", "scale", "samples", "angle_deg", "psnr", "ssim", "flip", "ms_1thread"]);
    for r in results {
        for (k, m) in r.metrics.iter().enumerate() {
            t.push(vec![
                r.dataset.clone(),
                r.model.name().into(),
                r.scale.to_string(),
                r.samples.to_string(),
                ANGLES[k].to_string(),
                num(Some(m.psnr), 3),
                num(Some(m.ssim), 4),
                num(Some(m.flip), 4),
                num(r.ms.filter(|_| ANGLES[k] == TIMED_ANGLE), 2),
            ]);
        }
    }
    t
}

/// Per dataset, the variant with the lowest FLIP at [`TIMED_ANGLE`].
pub fn best_per_dataset(results: &[VariantResult]) -> Vec<&VariantResult> {
    let k = ANGLES.iter().position(|&a| a == TIMED_ANGLE).unwrap_or(0);
    let mut names: Vec<&str> = results.iter().map(|r| r.dataset.as_str()).collect();
    names.dedup();
    names
        .iter()
        .filter_map(|n| {
            results.iter().filter(|r| r.dataset == *n).min_by(|a, b| a.metrics[k].flip.total_cmp(&b.metrics[k].flip))
        })
        .collect()
}

/// Runs the study on every dataset; writes the CSV, the chart and a markdown summary to `out`.
pub fn run(datasets: &[Dataset], heuristic: Heuristic, size: u32, runs: usize, out: &Path) -> Result<(), ErrorBox> {
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let mut results = Vec::new();
    for ds in datasets {
        results.extend(study(ds, heuristic, size, runs));
    }
    table(&results).write(&out.join("radius.csv"))?;
    let k10 = ANGLES.iter().position(|&a| a == TIMED_ANGLE).unwrap_or(0);
    let mut names: Vec<&str> = results.iter().map(|r| r.dataset.as_str()).collect();
    names.dedup();
    // Left: mean FLIP at 10° against mean ms over the datasets, one point per variant.
    let mean = |v: Vec<f64>| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let speed = VARIANTS
        .iter()
        .enumerate()
        .map(|(i, &(m, s))| {
            let of: Vec<&VariantResult> = results.iter().filter(|r| r.model == m && r.scale == s).collect();
            let ms = mean(of.iter().filter_map(|r| r.ms).collect());
            let flip = mean(of.iter().map(|r| r.metrics[k10].flip).collect());
            let mut series = Series::new(&label(m, s), vec![(ms.log10(), flip)], Mark::Dots, i);
            series.labels = vec![label(m, s)];
            series
        })
        .collect();
    // Right: FLIP against angle for each variant, averaged over the datasets.
    let angle = VARIANTS
        .iter()
        .enumerate()
        .map(|(i, &(m, s))| {
            let of: Vec<&VariantResult> = results.iter().filter(|r| r.model == m && r.scale == s).collect();
            let pts = (0..ANGLES.len())
                .map(|k| (ANGLES[k] as f64, of.iter().map(|r| r.metrics[k].flip).sum::<f64>() / of.len().max(1) as f64))
                .collect();
            Series::new(&label(m, s), pts, Mark::Line, i)
        })
        .collect();
    let panels = [
        Panel {
            title: format!("FLIP at {TIMED_ANGLE}° vs tracing time, {size}², 1 thread (means)"),
            x_desc: "packet tracer ms (log)".into(),
            y_desc: "mean FLIP (lower is better)".into(),
            series: speed,
            x_axis: XAxis::Log10,
            y_range: None,
            y_log: false,
            legend: Legend::UpperRight,
        },
        Panel {
            title: format!("FLIP vs orbit angle, mean of {} datasets", names.len()),
            x_desc: "orbit angle (degrees)".into(),
            y_desc: "mean FLIP".into(),
            series: angle,
            x_axis: XAxis::Linear,
            y_range: None,
            y_log: false,
            legend: Legend::UpperLeft,
        },
    ];
    charts::draw(&out.join("radius.png"), 1600, 600, &panels)?;
    let mut md = format!(
        "Radius study at {size}², heuristic {}, packet tracer on 1 thread (median of {runs} at {TIMED_ANGLE}°).\n\n\
         | dataset | variant | samples | FLIP 0° | FLIP 5° | FLIP 10° | FLIP 20° | ms |\n|---|---|---|---|---|---|---|---|\n",
        heuristic.name()
    );
    let at = |r: &VariantResult, a: f32| ANGLES.iter().position(|&x| x == a).map_or(f64::NAN, |k| r.metrics[k].flip);
    for r in &results {
        md += &format!(
            "| {} | {} | {} | {:.4} | {:.4} | {:.4} | {:.4} | {} |\n",
            r.dataset,
            label(r.model, r.scale),
            r.samples,
            at(r, 0.0),
            at(r, 5.0),
            at(r, 10.0),
            at(r, 20.0),
            r.ms.map_or("-".into(), |v| format!("{v:.1}"))
        );
    }
    md += "\nLowest FLIP at 10° per dataset: ";
    md += &best_per_dataset(&results)
        .iter()
        .map(|r| format!("{} {}", r.dataset, label(r.model, r.scale)))
        .collect::<Vec<_>>()
        .join(", ");
    md += "\n";
    std::fs::write(out.join("radius.md"), &md)?;
    log::info!("{}", md.trim());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn result(dataset: &str, model: RadiusModel, scale: f32, flip10: f64) -> VariantResult {
        let metrics = ANGLES
            .iter()
            .map(|&a| Metrics { psnr: 30.0, ssim: 0.9, flip: if a == TIMED_ANGLE { flip10 } else { 0.5 } })
            .collect();
        VariantResult { dataset: dataset.into(), model, scale, samples: 10, metrics, ms: Some(1.0) }
    }

    #[test]
    fn best_variant_per_dataset_by_flip_at_ten_degrees() {
        let rs = vec![
            result("a", RadiusModel::Voxel, 1.0, 0.2),
            result("a", RadiusModel::Footprint, 1.0, 0.1),
            result("b", RadiusModel::Voxel, 1.0, 0.05),
            result("b", RadiusModel::Footprint, 1.0, 0.1),
        ];
        let best: Vec<(String, RadiusModel)> =
            best_per_dataset(&rs).iter().map(|r| (r.dataset.clone(), r.model)).collect();
        assert_eq!(best, vec![("a".into(), RadiusModel::Footprint), ("b".into(), RadiusModel::Voxel)]);
        let t = table(&rs).to_csv();
        assert_eq!(t.lines().count(), 1 + rs.len() * ANGLES.len());
        assert!(t.lines().nth(1).unwrap().starts_with("a,voxel,1,10,0,"));
    }
}
