//! The `volwarp-eval` commands: they run the evaluation modules and write CSV files, charts,
//! image strips and markdown into an output folder.

use crate::charts::{self, Mark, Panel, Series, XAxis};
use crate::csv::{num, Table};
use crate::failure_modes::{run_case, CASES};
use crate::image_io::{downscale, strip};
use crate::quality::{self, DatasetResult, QualityOptions, Row, QUALITY_COLUMNS};
use crate::roster::Entry;
use crate::ErrorBox;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use volwarp_core::{Heuristic, Image};
use volwarp_server::dataset::{data_dir, Dataset};
use volwarp_server::Marcher;

/// The MRI of the paper-like Table 1, relative to the repository root.
pub const MRI: &str = "../shared/data/mri_colin27_181x217x181_uint8.raw";

/// Side of the tiles of image strips (pictures are downscaled to about this size).
pub const TILE: u32 = 200;

/// Top of the PSNR axes (higher values, i.e. identical images, are drawn there).
const PSNR_AXIS_TOP: f64 = 50.0;

fn info(s: &str) {
    log::info!("{s}");
}

/// Every volume of a shared data folder (`*.raw`), with its preset transfer function. Where the
/// bundled `data/` folder has an NRRD header for the same volume (it knows the spacing and
/// orientation), that is used instead.
pub fn shared_datasets(dir: &Path) -> Result<Vec<Dataset>, ErrorBox> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| format!("{}: {e}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "raw"))
        .collect();
    files.sort();
    let bundled = data_dir();
    let mut out = Vec::new();
    for f in files {
        let stem = f.file_name().and_then(|s| s.to_str()).unwrap_or("").to_string();
        let header = bundled.as_ref().and_then(|d| {
            std::fs::read_dir(d).ok()?.filter_map(|e| e.ok().map(|e| e.path())).find(|p| {
                p.extension().is_some_and(|x| x == "nhdr")
                    && p.file_stem().and_then(|s| s.to_str()).is_some_and(|s| stem.starts_with(s))
            })
        });
        let path = header.unwrap_or(f);
        info(&format!("dataset {}", path.display()));
        out.push(Dataset::load(&path, None)?);
    }
    if out.is_empty() {
        return Err(format!("no *.raw volume in {}", dir.display()).into());
    }
    Ok(out)
}

fn quality_table(rows: &[Row]) -> Table {
    let mut t = Table::new(&QUALITY_COLUMNS);
    for r in rows {
        t.push(vec![
            r.dataset.clone(),
            r.heuristic.name().into(),
            r.renderer.clone(),
            format!("{}", r.angle_deg),
            num(Some(r.metrics.psnr), 3),
            num(Some(r.metrics.ssim), 4),
            num(Some(r.metrics.flip), 4),
            num(r.ms[0], 2),
            num(r.ms[1], 2),
        ]);
    }
    t
}

/// The mean of `v` (NaN when empty).
pub(crate) fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for x in v {
        s += x;
        n += 1;
    }
    if n == 0 {
        f64::NAN
    } else {
        s / n as f64
    }
}

/// Renderer names in first-seen order.
fn renderers(rows: &[Row]) -> Vec<String> {
    let mut v: Vec<String> = Vec::new();
    for r in rows {
        if !v.contains(&r.renderer) {
            v.push(r.renderer.clone());
        }
    }
    v
}

/// Runs `volwarp-eval quality` over datasets and writes `quality.csv`, `dolly.csv`,
/// `samples.csv` and the charts into `out`.
pub fn quality(
    datasets: &[Dataset],
    heuristics: &[Heuristic],
    roster: &mut [Entry],
    opts: &QualityOptions,
    out: &Path,
) -> Result<(), ErrorBox> {
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let mut results: Vec<(String, DatasetResult)> = Vec::new();
    for (i, ds) in datasets.iter().enumerate() {
        info(&format!("== dataset {}/{}: {}", i + 1, datasets.len(), ds.name));
        let marcher = Marcher::from_dataset(ds);
        let r = quality::evaluate(&ds.name, &marcher, heuristics, roster, opts, &mut |s| info(s));
        results.push((ds.name.clone(), r));
        // Write what is there after each dataset, so a long run leaves usable files.
        write_quality(&results, heuristics, out)?;
    }
    Ok(())
}

/// Writes the files of a finished sweep into `out` (what `quality` does after each dataset;
/// public for the tests).
pub fn write_quality_for_test(results: &[(String, DatasetResult)], out: &Path) -> Result<(), ErrorBox> {
    std::fs::create_dir_all(out)?;
    let hs: Vec<Heuristic> = results.iter().flat_map(|(_, r)| r.samples.iter().map(|(h, _)| *h)).collect();
    write_quality(results, &hs, out)
}

fn write_quality(results: &[(String, DatasetResult)], heuristics: &[Heuristic], out: &Path) -> Result<(), ErrorBox> {
    let rows: Vec<Row> = results.iter().flat_map(|(_, r)| r.rows.clone()).collect();
    quality_table(&rows).write(&out.join("quality.csv"))?;
    let mut dolly = Table::new(&["dataset", "heuristic", "renderer", "dolly", "psnr", "ssim", "flip"]);
    for (_, r) in results {
        for d in &r.dolly_rows {
            dolly.push(vec![
                d.dataset.clone(),
                d.heuristic.name().into(),
                d.renderer.clone(),
                format!("{}", d.factor),
                num(Some(d.metrics.psnr), 3),
                num(Some(d.metrics.ssim), 4),
                num(Some(d.metrics.flip), 4),
            ]);
        }
    }
    dolly.write(&out.join("dolly.csv"))?;
    let mut samples = Table::new(&["dataset", "heuristic", "samples"]);
    for (name, r) in results {
        for (h, n) in &r.samples {
            samples.push(vec![name.clone(), h.name().into(), n.to_string()]);
        }
    }
    samples.write(&out.join("samples.csv"))?;
    let primary = heuristics.first().copied().unwrap_or(Heuristic::Threshold);
    error_vs_angle_chart(&rows, primary, &out.join("error_vs_angle.png"))?;
    speed_vs_accuracy_chart(&rows, primary, &out.join("speed_vs_accuracy.png"))?;
    heuristics_chart(&rows, &out.join("heuristics.png"))?;
    // Figure 3 from the MRI if it is there, else the first dataset.
    let pick = results.iter().find(|(n, _)| n.starts_with("mri")).or(results.first());
    if let Some((_, r)) = pick {
        write_strip(r, &out.join("strip.png"))?;
    }
    info(&format!("wrote {} rows to {}", rows.len(), out.join("quality.csv").display()));
    Ok(())
}

/// Parses a `quality.csv` written by [`quality()`] (rows with unknown heuristics or unparsable
/// numbers are an error naming the line).
pub fn parse_quality_csv(text: &str) -> Result<Vec<Row>, ErrorBox> {
    let mut lines = text.lines();
    if lines.next().map(str::trim) != Some(QUALITY_COLUMNS.join(",").as_str()) {
        return Err("not a quality.csv: unexpected header".into());
    }
    let mut rows = Vec::new();
    for (i, line) in lines.enumerate().filter(|(_, l)| !l.trim().is_empty()) {
        let bad = || format!("quality.csv line {}: {line:?}", i + 2);
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != QUALITY_COLUMNS.len() {
            return Err(bad().into());
        }
        let num = |s: &str| -> Result<f64, String> { s.parse::<f64>().map_err(|_| bad()) };
        let opt = |s: &str| -> Result<Option<f64>, String> {
            if s.is_empty() {
                Ok(None)
            } else {
                num(s).map(Some)
            }
        };
        rows.push(Row {
            dataset: f[0].into(),
            heuristic: Heuristic::from_name(f[1]).ok_or_else(bad)?,
            renderer: f[2].into(),
            angle_deg: num(f[3])? as f32,
            metrics: crate::Metrics { psnr: num(f[4])?, ssim: num(f[5])?, flip: num(f[6])? },
            ms: [opt(f[7])?, opt(f[8])?],
        });
    }
    Ok(rows)
}

/// Redraws the charts of a quality run from its `quality.csv` (primary heuristic: the first
/// one in the file).
pub fn replot(dir: &Path) -> Result<(), ErrorBox> {
    let path = dir.join("quality.csv");
    let meta = std::fs::metadata(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    if meta.len() > 256 << 20 {
        return Err(format!("{}: too large", path.display()).into());
    }
    let rows = parse_quality_csv(&std::fs::read_to_string(&path)?)?;
    let primary = rows.first().map_or(Heuristic::Threshold, |r| r.heuristic);
    error_vs_angle_chart(&rows, primary, &dir.join("error_vs_angle.png"))?;
    speed_vs_accuracy_chart(&rows, primary, &dir.join("speed_vs_accuracy.png"))?;
    heuristics_chart(&rows, &dir.join("heuristics.png"))?;
    info(&format!("redrew the charts of {} rows in {}", rows.len(), dir.display()));
    Ok(())
}

fn error_vs_angle_chart(rows: &[Row], h: Heuristic, path: &Path) -> Result<(), ErrorBox> {
    let rows: Vec<&Row> = rows.iter().filter(|r| r.heuristic == h).collect();
    let datasets: Vec<&str> = {
        let mut v: Vec<&str> = rows.iter().map(|r| r.dataset.as_str()).collect();
        v.dedup();
        v
    };
    let names = renderers(&rows.iter().map(|r| (*r).clone()).collect::<Vec<_>>());
    let psnr_lo = rows.iter().map(|r| r.metrics.psnr).fold(PSNR_AXIS_TOP, f64::min);
    let mut panels = Vec::new();
    for (metric, label) in [(0usize, "mean FLIP (lower is better)"), (1, "PSNR dB (higher is better)")] {
        let mut series = Vec::new();
        for (i, name) in names.iter().enumerate() {
            let mut by_angle: BTreeMap<i64, Vec<f64>> = BTreeMap::new();
            for r in rows.iter().filter(|r| &r.renderer == name) {
                // Identical images score 100 dB; draw them at the top of a 50 dB axis.
                let v = if metric == 0 { r.metrics.flip } else { r.metrics.psnr.min(PSNR_AXIS_TOP) };
                by_angle.entry((r.angle_deg * 1000.0) as i64).or_default().push(v);
            }
            let pts = by_angle.iter().map(|(a, v)| (*a as f64 / 1000.0, mean(v.iter().copied()))).collect();
            series.push(Series::new(name, pts, Mark::Line, i));
        }
        panels.push(Panel {
            title: format!("{label}, {} heuristic, mean of {} dataset(s)", h.name(), datasets.len()),
            x_desc: "orbit angle away from C0 (degrees)".into(),
            y_desc: label.split(" (").next().unwrap_or(label).into(),
            series,
            x_axis: XAxis::Linear,
            y_range: if metric == 1 { Some((psnr_lo.floor() - 1.0, PSNR_AXIS_TOP + 1.0)) } else { None },
            y_log: false,
            legend: if metric == 0 { charts::Legend::UpperLeft } else { charts::Legend::UpperRight },
        });
    }
    charts::draw(path, 1600, 650, &panels)?;
    Ok(())
}

/// Per renderer: (median ms at 512², mean FLIP over the angles > 0, averaged over datasets).
pub fn speed_accuracy_points(rows: &[Row], h: Heuristic) -> Vec<(String, f64, f64)> {
    let rows: Vec<Row> = rows.iter().filter(|r| r.heuristic == h).cloned().collect();
    renderers(&rows)
        .into_iter()
        .map(|name| {
            let mine: Vec<&Row> = rows.iter().filter(|r| r.renderer == name).collect();
            let mut ms: Vec<f64> = mine.iter().filter_map(|r| r.ms[0]).collect();
            let flip = mean(mine.iter().filter(|r| r.angle_deg > 0.0).map(|r| r.metrics.flip));
            (name, crate::median(&mut ms).unwrap_or(f64::NAN), flip)
        })
        .collect()
}

fn speed_vs_accuracy_chart(rows: &[Row], h: Heuristic, path: &Path) -> Result<(), ErrorBox> {
    let pts = speed_accuracy_points(rows, h);
    let xy: Vec<(f64, f64)> = pts.iter().map(|(_, ms, f)| (ms.max(1e-3).log10(), *f)).collect();
    let front = charts::pareto_front(&xy);
    let mut series: Vec<Series> = pts
        .iter()
        .zip(&xy)
        .enumerate()
        .map(|(i, ((name, _, _), &p))| Series {
            name: name.clone(),
            points: vec![p],
            mark: Mark::Dots,
            color: i,
            labels: vec![format!("  {name}")],
        })
        .collect();
    series.push(Series::new("Pareto front", front.iter().map(|&i| xy[i]).collect(), Mark::Thin, 7));
    series.push(Series::new("", front.iter().map(|&i| xy[i]).collect(), Mark::Rings, 3));
    let panel = Panel {
        title: format!("client time at 512² vs FLIP (mean over 2.5–30° orbits), {} heuristic", h.name()),
        x_desc: "client ms per frame at 512² (log scale; median)".into(),
        y_desc: "mean FLIP (lower is better)".into(),
        series,
        x_axis: XAxis::Log10,
        y_range: None,
        y_log: false,
        legend: charts::Legend::LowerRight,
    };
    charts::draw(path, 1100, 700, &[panel])?;
    Ok(())
}

fn heuristics_chart(rows: &[Row], path: &Path) -> Result<(), ErrorBox> {
    let mut hs: Vec<Heuristic> = rows.iter().map(|r| r.heuristic).collect();
    hs.sort();
    hs.dedup();
    let mut datasets: Vec<String> = rows.iter().map(|r| r.dataset.clone()).collect();
    datasets.dedup();
    let mut series = Vec::new();
    for (i, d) in datasets.iter().enumerate() {
        let pts = hs
            .iter()
            .enumerate()
            .map(|(k, h)| {
                let f = mean(
                    rows.iter()
                        .filter(|r| {
                            &r.dataset == d && r.heuristic == *h && r.renderer == "spheres-cpu" && r.angle_deg > 0.0
                        })
                        .map(|r| r.metrics.flip),
                );
                (k as f64, f)
            })
            .collect();
        series.push(Series::new(d, pts, Mark::Line, i));
    }
    let panel = Panel {
        title: "depth heuristic vs error: spheres-cpu, mean FLIP over 2.5–30° orbits".into(),
        x_desc: "heuristic".into(),
        y_desc: "mean FLIP (lower is better)".into(),
        series,
        x_axis: XAxis::Categories(hs.iter().map(|h| h.name().to_string()).collect()),
        y_range: None,
        y_log: false,
        legend: charts::Legend::UpperLeft,
    };
    charts::draw(path, 1300, 650, &[panel])?;
    Ok(())
}

fn tile(img: &Image) -> Image {
    downscale(img, img.width.div_ceil(TILE).max(1))
}

fn write_strip(r: &DatasetResult, path: &Path) -> Result<(), ErrorBox> {
    let rows: Vec<Vec<Image>> =
        [&r.strip.truth, &r.strip.spheres, &r.strip.points].iter().map(|v| v.iter().map(tile).collect()).collect();
    let refs: Vec<Vec<&Image>> = rows.iter().map(|v| v.iter().collect()).collect();
    strip(&refs, 4, volwarp_core::sample::pack_color(255, 255, 255, 255)).save_png(path)?;
    Ok(())
}

/// Runs every failure case at `size`² and writes `failures.csv` and `failures.png` (rows:
/// cases; columns: truth, then each renderer).
pub fn failures(
    base: &Marcher,
    dataset: &str,
    heuristic: Heuristic,
    size: u32,
    roster: &mut [Entry],
    out: &Path,
) -> Result<(), ErrorBox> {
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let mut t =
        Table::new(&["dataset", "case", "samples", "renderer", "defined", "psnr", "ssim", "flip", "flip_vs_baseline"]);
    let mut baseline: BTreeMap<String, f64> = BTreeMap::new();
    let mut pictures: Vec<Vec<Image>> = Vec::new();
    let mut names = vec!["truth".to_string()];
    for (i, case) in CASES.iter().enumerate() {
        info(&format!("failure case {}/{}: {} ({})", i + 1, CASES.len(), case.name, case.what));
        let r = run_case(case, base, heuristic, size, roster);
        let mut row_pics = vec![tile(&r.truth)];
        for o in &r.outcomes {
            if i == 0 {
                baseline.insert(o.renderer.clone(), o.metrics.flip);
                names.push(o.renderer.clone());
            }
            let ratio = baseline.get(&o.renderer).map(|b| o.metrics.flip / b.max(1e-9));
            t.push(vec![
                dataset.into(),
                case.name.into(),
                r.samples.to_string(),
                o.renderer.clone(),
                o.defined.to_string(),
                num(Some(o.metrics.psnr), 3),
                num(Some(o.metrics.ssim), 4),
                num(Some(o.metrics.flip), 4),
                num(ratio, 2),
            ]);
            if !o.defined {
                log::warn!("{}: {} produced an undefined image", case.name, o.renderer);
            }
            if ["stale", "points1", "spheres-cpu", "spheres-cpu-r2"].contains(&o.renderer.as_str()) {
                row_pics.push(tile(&o.image));
            }
        }
        pictures.push(row_pics);
    }
    t.write(&out.join("failures.csv"))?;
    let refs: Vec<Vec<&Image>> = pictures.iter().map(|v| v.iter().collect()).collect();
    strip(&refs, 3, volwarp_core::sample::pack_color(255, 255, 255, 255)).save_png(&out.join("failures.png"))?;
    info(&format!(
        "wrote {} and failures.png (rows: {}; columns: truth, stale, points1, spheres-cpu, spheres-cpu-r2)",
        out.join("failures.csv").display(),
        CASES.iter().map(|c| c.name).collect::<Vec<_>>().join(", ")
    ));
    Ok(())
}

/// Writes 64² image pairs (truth and a warped render) for the metric reference tests.
pub fn fixtures(out: &Path) -> Result<(), ErrorBox> {
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let dir = data_dir().ok_or("the bundled data/ folder was not found")?;
    let mut r = crate::roster::roster(crate::roster::RosterOptions { threads: 0, gpu: false });
    let cases: [(&str, &str, f32, &str); 4] = [
        ("ct_head_quarter.nhdr", "points1", 10.0, "ct_points1_10"),
        ("ct_head_quarter.nhdr", "spheres-cpu", 20.0, "ct_spheres_20"),
        ("neghip_64x64x64_uint8.raw", "stale", 5.0, "neghip_stale_5"),
        ("neghip_64x64x64_uint8.raw", "splat", 30.0, "neghip_splat_30"),
    ];
    for (vol, renderer, angle, name) in cases {
        let ds = Dataset::load(dir.join(vol), None)?;
        let m = Marcher::from_dataset(&ds);
        let c0 = m.default_camera(64, 64);
        let frame = quality::frame_for(&m, &c0, Heuristic::Threshold);
        let scene = volwarp_cpu_tracer::build_scene(&frame);
        let cam = crate::camera_paths::orbit(&c0, angle);
        let truth = m.render_image(&cam);
        let e = r.iter_mut().find(|e| e.name == renderer).ok_or("renderer missing")?;
        let mut img = Image::new(0, 0);
        e.renderer.render(&scene, &cam, &mut img);
        truth.save_png(&out.join(format!("{name}_ref.png")))?;
        img.save_png(&out.join(format!("{name}_test.png")))?;
        info(&format!("fixture {name}"));
    }
    Ok(())
}
