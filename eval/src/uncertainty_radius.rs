//! Samples sized by what is known: single warps of frames whose spheres are
//! sized by different radius models ([`volwarp_server::radius`]: the footprint default and
//! `uncertainty` with its constants), drawn with the hole-filling splatter with warp-sized radii
//! (`splat-fill+adapt`) and with the plain splatter (`splat`), scored
//! against the marcher's truth.
//!
//! For each dataset, the C0 frame (the default camera at `size`²) is rendered once per variant
//! and warped to every orbit angle of [`ANGLES`]; the stale frame is scored once (it does not
//! depend on the radius). Each variant's frame is also encoded in the compact form, so its
//! bytes per sample show what the radii's residuals cost. Output: `uncertainty.csv` (one row
//! per dataset × variant × renderer × angle) and `uncertainty.md` (mean ꟻLIP over the datasets
//! per variant, renderer and angle, and the bytes per sample).

use crate::camera_paths::orbit;
use crate::csv::{num, Table};
use crate::{ErrorBox, Metrics};
use std::path::Path;
use volwarp_core::compact_frame::Encoding;
use volwarp_core::renderer::Renderer;
use volwarp_core::wire::CameraRequest;
use volwarp_core::{Heuristic, Image, RendererKind};
use volwarp_server::dataset::Dataset;
use volwarp_server::radius::{parse_spec, RadiusModel, UncertaintyParams};
use volwarp_server::{MarchOptions, Marcher};

/// Orbit angles of the study, degrees.
pub const ANGLES: [f32; 6] = [0.0, 2.5, 5.0, 10.0, 20.0, 30.0];

/// A radius variant: its spec as given (`footprint`, `uncertainty:gain=0.1:max=2`), the model
/// and the uncertainty constants.
#[derive(Clone, Debug, PartialEq)]
pub struct Variant {
    /// The spec, as in the CSV.
    pub spec: String,
    /// The model.
    pub model: RadiusModel,
    /// The uncertainty constants (used by [`RadiusModel::Uncertainty`] only).
    pub params: UncertaintyParams,
}

/// Parses a comma-separated list of radius specs ([`parse_spec`]).
pub fn parse_variants(list: &str) -> Result<Vec<Variant>, ErrorBox> {
    list.split(',')
        .filter(|s| !s.is_empty())
        .map(|s| {
            let (model, params) = parse_spec(s)?;
            Ok(Variant { spec: s.to_string(), model, params })
        })
        .collect()
}

/// One score.
#[derive(Clone, Debug)]
pub struct Row {
    /// Dataset name.
    pub dataset: String,
    /// Variant spec (`-` for the stale frame).
    pub variant: String,
    /// Renderer (`stale`, `splat`, `splat-fill+adapt`).
    pub renderer: String,
    /// Orbit angle, degrees.
    pub angle_deg: f32,
    /// ꟻLIP against the truth.
    pub flip: f64,
    /// Samples of the frame.
    pub samples: usize,
    /// Compact-encoded bytes per sample of the frame.
    pub bytes_per_sample: f64,
}

/// The client drawings compared: the plain splatter and the hole-filling one with warp-sized
/// radii.
fn renderers(threads: usize) -> Vec<(&'static str, Box<dyn Renderer + Send>)> {
    let splat = volwarp_cpu_tracer::create(RendererKind::Splat, threads).expect("the splatter");
    let mut fill = volwarp_cpu_tracer::create(RendererKind::SplatFill, threads).expect("the filling splatter");
    fill.set_adaptive_radius(true);
    vec![("splat", splat), (crate::roster::SPLAT_FILL_ADAPT, fill)]
}

/// Runs the study on one dataset (see the module docs).
pub fn study(ds: &Dataset, heuristic: Heuristic, size: u32, variants: &[Variant], threads: usize) -> Vec<Row> {
    let base = Marcher::from_dataset(ds);
    let c0 = base.default_camera(size, size);
    log::info!("{}: truth for {} angles at {size}²", ds.name, ANGLES.len());
    let truths: Vec<Image> = ANGLES.iter().map(|&a| base.render_image(&orbit(&c0, a))).collect();
    let req = CameraRequest { seq: 1, camera: c0, heuristic, radius_scale: 1.0, layers: 0 };
    let mut img = Image::new(0, 0);
    let mut rows = Vec::new();
    let score = |truth: &Image, img: &Image| Metrics::of(truth, img).map_or(1.0, |m| m.flip);
    let mut stale = volwarp_cpu_tracer::create(RendererKind::Stale, threads).expect("the stale renderer");
    let mut draw = renderers(threads);
    for (vi, v) in variants.iter().enumerate() {
        let opts = MarchOptions { radius: v.model, uncertainty: v.params, ..base.options() };
        let m = base.with_transfer_function(&ds.tf, opts);
        let frame = m.render_frame(&req).0;
        let n = frame.samples.len();
        // The bytes the server sends (its encoder, the frame's radius model).
        let bytes = volwarp_server::encoding::encode_frame(&m, &req, &frame, Encoding::Compact).0.len();
        let bps = bytes as f64 / n.max(1) as f64;
        let scene = volwarp_cpu_tracer::build_scene(&frame);
        if vi == 0 {
            for (&a, truth) in ANGLES.iter().zip(&truths) {
                stale.render(&scene, &orbit(&c0, a), &mut img);
                let flip = score(truth, &img);
                rows.push(Row {
                    dataset: ds.name.clone(),
                    variant: "-".into(),
                    renderer: "stale".into(),
                    angle_deg: a,
                    flip,
                    samples: n,
                    bytes_per_sample: bps,
                });
            }
        }
        let mut line = Vec::new();
        for (name, r) in draw.iter_mut() {
            for (&a, truth) in ANGLES.iter().zip(&truths) {
                r.render(&scene, &orbit(&c0, a), &mut img);
                let flip = score(truth, &img);
                line.push(format!("{flip:.4}"));
                rows.push(Row {
                    dataset: ds.name.clone(),
                    variant: v.spec.clone(),
                    renderer: (*name).into(),
                    angle_deg: a,
                    flip,
                    samples: n,
                    bytes_per_sample: bps,
                });
            }
        }
        log::info!("{} {}: {n} samples, {bps:.3} B/sample, FLIP {}", ds.name, v.spec, line.join(" "));
    }
    rows
}

/// The CSV of rows.
pub fn table(rows: &[Row]) -> Table {
    let mut t = Table::new(&["dataset", "radius", "renderer", "angle_deg", "flip", "samples", "bytes_per_sample"]);
    for r in rows {
        t.push(vec![
            r.dataset.clone(),
            r.variant.clone(),
            r.renderer.clone(),
            r.angle_deg.to_string(),
            num(Some(r.flip), 4),
            r.samples.to_string(),
            num(Some(r.bytes_per_sample), 3),
        ]);
    }
    t
}

/// Mean of `f` over the rows that `keep`.
fn mean(rows: &[Row], keep: impl Fn(&Row) -> bool, f: impl Fn(&Row) -> f64) -> Option<f64> {
    let v: Vec<f64> = rows.iter().filter(|r| keep(r)).map(f).collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// The markdown summary: mean ꟻLIP over the datasets per (renderer, variant) and angle, with
/// the mean bytes per sample; then the same per dataset.
pub fn summary(rows: &[Row]) -> String {
    let mut keys: Vec<(String, String)> = Vec::new();
    for r in rows {
        let k = (r.renderer.clone(), r.variant.clone());
        if !keys.contains(&k) {
            keys.push(k);
        }
    }
    let mut datasets: Vec<String> = Vec::new();
    for r in rows {
        if !datasets.contains(&r.dataset) {
            datasets.push(r.dataset.clone());
        }
    }
    let head = |first: &str| {
        let angles: Vec<String> = ANGLES.iter().map(|a| format!("{a}°")).collect();
        format!("| {first} | {} | B/sample |\n|---|{}---|\n", angles.join(" | "), "---|".repeat(ANGLES.len()))
    };
    let line = |label: String, keep: &dyn Fn(&Row) -> bool| {
        let cells: Vec<String> =
            ANGLES.iter().map(|&a| num(mean(rows, |r| keep(r) && r.angle_deg == a, |r| r.flip), 4)).collect();
        let bps = num(mean(rows, keep, |r| r.bytes_per_sample), 3);
        format!("| {label} | {} | {bps} |\n", cells.join(" | "))
    };
    let mut s = format!("Mean ꟻLIP over {} datasets\n\n", datasets.len());
    s += &head("renderer / radius");
    for (r, v) in &keys {
        s += &line(format!("{r} {v}"), &|x: &Row| x.renderer == *r && x.variant == *v);
    }
    for d in &datasets {
        s += &format!("\n{d}\n\n");
        s += &head("renderer / radius");
        for (r, v) in &keys {
            s += &line(format!("{r} {v}"), &|x: &Row| x.dataset == *d && x.renderer == *r && x.variant == *v);
        }
    }
    s
}

/// Runs the study over datasets and writes `uncertainty.csv` and `uncertainty.md` into `out`
/// (after each dataset, so a long run leaves usable files).
pub fn run(
    datasets: &[Dataset],
    heuristic: Heuristic,
    size: u32,
    variants: &[Variant],
    threads: usize,
    out: &Path,
) -> Result<(), ErrorBox> {
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let mut rows = Vec::new();
    for ds in datasets {
        rows.extend(study(ds, heuristic, size, variants, threads));
        table(&rows).write(&out.join("uncertainty.csv"))?;
        std::fs::write(out.join("uncertainty.md"), summary(&rows))?;
    }
    log::info!("wrote {}", out.join("uncertainty.csv").display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn variants_parse() {
        let v = parse_variants("footprint,uncertainty,uncertainty:gain=0.2:max=3:measure=span").unwrap();
        assert_eq!(v.len(), 3);
        assert_eq!(v[0].model, RadiusModel::Footprint);
        assert_eq!(v[1].params, UncertaintyParams::DEFAULT);
        assert_eq!(v[2].params.gain, 0.2);
        assert_eq!(v[2].params.max, 3.0);
        assert!(parse_variants("footprint:gain=1").is_err());
        assert!(parse_variants("uncertainty:max=0.5").is_err());
        assert!(parse_variants("uncertainty:gain=nan").is_err());
    }

    #[test]
    fn summary_means_over_datasets() {
        let row = |d: &str, a: f32, flip: f64| Row {
            dataset: d.into(),
            variant: "footprint".into(),
            renderer: "splat".into(),
            angle_deg: a,
            flip,
            samples: 10,
            bytes_per_sample: 2.0,
        };
        let rows: Vec<Row> = ANGLES.iter().flat_map(|&a| [row("a", a, 0.1), row("b", a, 0.3)]).collect();
        let s = summary(&rows);
        assert!(s.contains("| splat footprint | 0.2000 | 0.2000"), "{s}");
        assert!(s.contains("| 2.000 |"), "{s}");
    }
}
