//! The files of `volwarp-eval session`: `session.csv` (one row per scored tick per method),
//! `frames.csv` (every frame's timeline), `summary.csv` and `summary.md`, and the PNG charts
//! and worst-tick strips.

use super::simulate::{SessionResult, TickRow};
use crate::charts::{self, Legend, Mark, Panel, Series, XAxis};
use crate::csv::{num, Table};
use crate::image_io::{downscale, strip};
use crate::metrics::diff::difference_image;
use crate::report::mean;
use crate::ErrorBox;
use std::path::Path;

/// The columns of `session.csv`, in order.
pub const SESSION_COLUMNS: [&str; 16] = [
    "dataset",
    "scenario",
    "policy",
    "size",
    "server_ms",
    "latency_ms",
    "mbps",
    "method",
    "tick",
    "time_s",
    "frame_seq",
    "frame_age_ms",
    "draw_ms",
    "psnr",
    "ssim",
    "flip",
];

/// Which session a result belongs to.
#[derive(Clone, Debug, PartialEq)]
pub struct RunKey {
    /// Dataset name.
    pub dataset: String,
    /// Scenario name.
    pub scenario: String,
    /// Server policy name.
    pub policy: String,
    /// Viewport side.
    pub size: u32,
    /// Server ms per frame.
    pub server_ms: f64,
    /// One-way latency, ms.
    pub latency_ms: f64,
    /// Bandwidth, Mbit/s.
    pub mbps: f64,
}

/// A finished session.
pub struct Run {
    /// Which one.
    pub key: RunKey,
    /// What it produced.
    pub result: SessionResult,
}

/// The statistics of one method in one session (or pooled over several).
#[derive(Clone, Debug, PartialEq)]
pub struct Summary {
    /// Method name.
    pub method: String,
    /// Mean FLIP.
    pub mean_flip: f64,
    /// 95th percentile FLIP (nearest rank).
    pub p95_flip: f64,
    /// Largest FLIP.
    pub max_flip: f64,
    /// Mean PSNR, dB.
    pub mean_psnr: f64,
    /// Mean frame age, ms.
    pub mean_age_ms: f64,
    /// Draw time, ms.
    pub draw_ms: f64,
    /// Scored ticks.
    pub ticks: usize,
}

/// Method names in first-seen order.
pub fn method_names<'a>(rows: impl Iterator<Item = &'a TickRow>) -> Vec<String> {
    let mut v: Vec<String> = Vec::new();
    for r in rows {
        if !v.contains(&r.method) {
            v.push(r.method.clone());
        }
    }
    v
}

/// Nearest-rank percentile `p` (0..=100) of values (NaN for none).
pub fn percentile(v: &[f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let rank = ((p / 100.0) * s.len() as f64).ceil().max(1.0) as usize;
    s[rank.min(s.len()) - 1]
}

/// Per-method statistics over rows (pooled).
pub fn summarize(rows: &[&TickRow]) -> Vec<Summary> {
    method_names(rows.iter().copied())
        .into_iter()
        .map(|m| {
            let r: Vec<&TickRow> = rows.iter().copied().filter(|r| r.method == m).collect();
            let flips: Vec<f64> = r.iter().map(|r| r.metrics.flip).collect();
            Summary {
                mean_flip: mean(flips.iter().copied()),
                p95_flip: percentile(&flips, 95.0),
                max_flip: flips.iter().copied().fold(f64::NAN, f64::max),
                mean_psnr: mean(r.iter().map(|r| r.metrics.psnr)),
                mean_age_ms: mean(r.iter().map(|r| r.frame_age_ms)),
                draw_ms: r.first().map_or(f64::NAN, |r| r.draw_ms),
                ticks: r.len(),
                method: m,
            }
        })
        .collect()
}

/// The columns of a [`RunKey`], first in every table of a run ([`key_fields`] fills them).
const KEY_COLUMNS: [&str; 7] = ["dataset", "scenario", "policy", "size", "server_ms", "latency_ms", "mbps"];

/// [`KEY_COLUMNS`] followed by `rest`.
fn with_key_columns(rest: &[&'static str]) -> Vec<&'static str> {
    KEY_COLUMNS.iter().chain(rest).copied().collect()
}

fn key_fields(k: &RunKey) -> Vec<String> {
    vec![
        k.dataset.clone(),
        k.scenario.clone(),
        k.policy.clone(),
        k.size.to_string(),
        num(Some(k.server_ms), 1),
        num(Some(k.latency_ms), 1),
        if k.mbps.is_infinite() { "inf".into() } else { num(Some(k.mbps), 1) },
    ]
}

/// The `session.csv` table.
pub fn session_table(runs: &[Run]) -> Table {
    let mut t = Table::new(&SESSION_COLUMNS);
    for run in runs {
        for r in &run.result.rows {
            let mut f = key_fields(&run.key);
            f.extend([
                r.method.clone(),
                r.tick.to_string(),
                num(Some(r.time_s), 4),
                r.frame_seq.to_string(),
                num(Some(r.frame_age_ms), 1),
                num(Some(r.draw_ms), 2),
                num(Some(r.metrics.psnr), 3),
                num(Some(r.metrics.ssim), 4),
                num(Some(r.metrics.flip), 4),
            ]);
            t.push(f);
        }
    }
    t
}

fn frames_table(runs: &[Run]) -> Table {
    let mut t = Table::new(&with_key_columns(&["seq", "request_ms", "start_ms", "bytes", "arrive_ms"]));
    for run in runs {
        for f in &run.result.frames {
            let mut v = key_fields(&run.key);
            v.extend([
                f.seq.to_string(),
                num(Some(f.request_ms), 1),
                num(Some(f.start_ms), 1),
                f.bytes.to_string(),
                num(Some(f.arrive_ms), 1),
            ]);
            t.push(v);
        }
    }
    t
}

fn summary_table(runs: &[Run]) -> Table {
    let mut t = Table::new(&with_key_columns(&[
        "method",
        "mean_flip",
        "p95_flip",
        "max_flip",
        "mean_psnr",
        "mean_age_ms",
        "draw_ms",
        "ticks",
    ]));
    for run in runs {
        let rows: Vec<&TickRow> = run.result.rows.iter().collect();
        for s in summarize(&rows) {
            let mut v = key_fields(&run.key);
            v.extend([
                s.method,
                num(Some(s.mean_flip), 4),
                num(Some(s.p95_flip), 4),
                num(Some(s.max_flip), 4),
                num(Some(s.mean_psnr), 2),
                num(Some(s.mean_age_ms), 1),
                num(Some(s.draw_ms), 2),
                s.ticks.to_string(),
            ]);
            t.push(v);
        }
    }
    t
}

fn distinct<T: PartialEq + Clone>(v: impl Iterator<Item = T>) -> Vec<T> {
    let mut out: Vec<T> = Vec::new();
    for x in v {
        if !out.contains(&x) {
            out.push(x);
        }
    }
    out
}

/// The markdown summary: per scenario, each method pooled over datasets (mean, p95, max FLIP,
/// mean PSNR, mean frame age), then per dataset and scenario the best method against stale.
pub fn summary_markdown(runs: &[Run]) -> String {
    let mut s = String::new();
    let configs = distinct(runs.iter().map(|r| (r.key.size, r.key.server_ms.to_bits(), r.key.mbps.to_bits())));
    for (size, sms, mbps) in configs {
        let (sms, mbps) = (f64::from_bits(sms), f64::from_bits(mbps));
        let sel: Vec<&Run> =
            runs.iter().filter(|r| r.key.size == size && r.key.server_ms == sms && r.key.mbps == mbps).collect();
        let lat = sel.first().map_or(0.0, |r| r.key.latency_ms);
        s.push_str(&format!(
            "### {size}², server {sms} ms per frame, {lat} ms one way, {mbps} Mbit/s ({} datasets)\n\n",
            distinct(sel.iter().map(|r| r.key.dataset.clone())).len()
        ));
        s.push_str("| scenario | method | mean FLIP | p95 FLIP | max FLIP | mean PSNR | mean age ms | × stale (mean) | × stale (p95) |\n");
        s.push_str("|---|---|---|---|---|---|---|---|---|\n");
        for sc in distinct(sel.iter().map(|r| r.key.scenario.clone())) {
            let rows: Vec<&TickRow> =
                sel.iter().filter(|r| r.key.scenario == sc).flat_map(|r| r.result.rows.iter()).collect();
            let sum = summarize(&rows);
            let stale = sum.iter().find(|x| x.method == "stale").cloned();
            for x in &sum {
                let (rm, rp) = stale
                    .as_ref()
                    .map_or((f64::NAN, f64::NAN), |st| (x.mean_flip / st.mean_flip, x.p95_flip / st.p95_flip));
                s.push_str(&format!(
                    "| {sc} | {} | {:.4} | {:.4} | {:.4} | {:.2} | {:.0} | {:.2} | {:.2} |\n",
                    x.method, x.mean_flip, x.p95_flip, x.max_flip, x.mean_psnr, x.mean_age_ms, rm, rp
                ));
            }
        }
        s.push_str("\nBest method (lowest mean FLIP) per dataset and scenario, against stale:\n\n");
        s.push_str("| dataset | scenario | best | its mean FLIP | stale mean FLIP | best / stale |\n|---|---|---|---|---|---|\n");
        for r in &sel {
            let rows: Vec<&TickRow> = r.result.rows.iter().collect();
            let sum = summarize(&rows);
            let Some(best) = sum.iter().min_by(|a, b| a.mean_flip.total_cmp(&b.mean_flip)) else { continue };
            let st = sum.iter().find(|x| x.method == "stale").map_or(f64::NAN, |x| x.mean_flip);
            s.push_str(&format!(
                "| {} | {} | {} | {:.4} | {:.4} | {:.2} |\n",
                r.key.dataset,
                r.key.scenario,
                best.method,
                best.mean_flip,
                st,
                best.mean_flip / st
            ));
        }
        s.push('\n');
    }
    s
}

fn safe(s: &str) -> String {
    s.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '_' { c } else { '_' }).collect()
}

/// FLIP over time per method, one panel per scenario, frame arrivals as dots at FLIP 0.
pub fn flip_over_time_chart(runs: &[&Run], path: &Path) -> Result<(), ErrorBox> {
    let mut panels = Vec::new();
    for run in runs {
        let rows: Vec<&TickRow> = run.result.rows.iter().collect();
        let mut series: Vec<Series> = method_names(rows.iter().copied())
            .iter()
            .enumerate()
            .map(|(i, m)| {
                let pts = rows.iter().filter(|r| &r.method == m).map(|r| (r.time_s, r.metrics.flip)).collect();
                Series::new(m, pts, Mark::Line, i)
            })
            .collect();
        let arrivals =
            run.result.frames.iter().filter(|f| !f.held_at_start()).map(|f| (f.arrive_ms * 1e-3, 0.0)).collect();
        series.push(Series::new("frame arrives", arrivals, Mark::Rings, 7));
        panels.push(Panel {
            title: format!("{} · {}", run.key.dataset, run.key.scenario),
            x_desc: "time (s)".into(),
            y_desc: "FLIP vs truth".into(),
            series,
            x_axis: XAxis::Linear,
            y_range: None,
            y_log: false,
            legend: Legend::UpperLeft,
        });
    }
    if panels.is_empty() {
        return Ok(());
    }
    let cols = panels.len().min(2);
    let rows = panels.len().div_ceil(cols);
    // charts::draw puts panels side by side; stack rows by drawing each row to its own file
    // would lose the overview, so use one wide row of at most two panels per file row.
    if rows == 1 {
        charts::draw(path, 620 * cols as u32, 440, &panels)?;
    } else {
        let tmp: Vec<std::path::PathBuf> = (0..rows).map(|r| path.with_extension(format!("row{r}.png"))).collect();
        for (r, chunk) in panels.chunks(cols).enumerate() {
            charts::draw(&tmp[r], 620 * cols as u32, 440, chunk)?;
        }
        let imgs: Result<Vec<volwarp_core::Image>, _> =
            tmp.iter().map(|p| volwarp_core::Image::load_png(p, 1 << 26)).collect();
        let imgs = imgs.map_err(|e| format!("{e:?}"))?;
        let grid: Vec<Vec<&volwarp_core::Image>> = imgs.iter().map(|i| vec![i]).collect();
        strip(&grid, 0, u32::MAX).save_png(path).map_err(|e| format!("{}: {e:?}", path.display()))?;
        for t in tmp {
            std::fs::remove_file(t).ok();
        }
    }
    Ok(())
}

/// Session mean FLIP against client draw ms per method (pooled over the runs).
pub fn speed_accuracy_chart(runs: &[Run], title: &str, path: &Path) -> Result<(), ErrorBox> {
    let rows: Vec<&TickRow> = runs.iter().flat_map(|r| r.result.rows.iter()).collect();
    let sum = summarize(&rows);
    let pts: Vec<(f64, f64)> = sum.iter().map(|s| (s.draw_ms.max(1e-3).log10(), s.mean_flip)).collect();
    let front: Vec<(f64, f64)> = charts::pareto_front(&pts).into_iter().map(|i| pts[i]).collect();
    let mut dots = Series::new("method", pts, Mark::Dots, 0);
    dots.labels = sum.iter().map(|s| format!("  {}", s.method)).collect();
    let panel = Panel {
        title: title.into(),
        x_desc: "client draw ms (log)".into(),
        y_desc: "session mean FLIP".into(),
        series: vec![dots, Series::new("Pareto front", front, Mark::Thin, 3)],
        x_axis: XAxis::Log10,
        y_range: None,
        y_log: false,
        legend: Legend::UpperRight,
    };
    charts::draw(path, 760, 480, &[panel])?;
    Ok(())
}

/// Mean FLIP per method against a swept figure (x on a log axis), one panel per group.
pub fn sweep_chart(
    runs: &[Run],
    x_of: fn(&RunKey) -> f64,
    x_desc: &str,
    group_of: fn(&RunKey) -> String,
    path: &Path,
) -> Result<(), ErrorBox> {
    let mut panels = Vec::new();
    for g in distinct(runs.iter().map(|r| group_of(&r.key))) {
        let sel: Vec<&Run> = runs.iter().filter(|r| group_of(&r.key) == g).collect();
        let methods = method_names(sel.iter().flat_map(|r| r.result.rows.iter()));
        let xs = distinct(sel.iter().map(|r| x_of(&r.key).to_bits()));
        let series = methods
            .iter()
            .enumerate()
            .map(|(i, m)| {
                let pts = xs
                    .iter()
                    .map(|&xb| {
                        let x = f64::from_bits(xb);
                        let f = mean(
                            sel.iter()
                                .filter(|r| x_of(&r.key) == x)
                                .flat_map(|r| r.result.rows.iter())
                                .filter(|r| &r.method == m)
                                .map(|r| r.metrics.flip),
                        );
                        (x.log10(), f)
                    })
                    .collect();
                Series::new(m, pts, Mark::Line, i)
            })
            .collect();
        panels.push(Panel {
            title: g,
            x_desc: x_desc.into(),
            y_desc: "session mean FLIP".into(),
            series,
            x_axis: XAxis::Log10,
            y_range: None,
            y_log: false,
            legend: Legend::UpperLeft,
        });
    }
    if !panels.is_empty() {
        charts::draw(path, 620 * panels.len() as u32, 440, &panels)?;
    }
    Ok(())
}

/// A strip of the worst tick of each method: one row per method, truth | shown | difference.
pub fn worst_strip(run: &Run, path: &Path) -> Result<(), ErrorBox> {
    let factor = (run.key.size / 256).max(1);
    let tiles: Vec<[volwarp_core::Image; 3]> = run
        .result
        .worst
        .iter()
        .map(|w| {
            let d = difference_image(&w.truth, &w.shown).unwrap_or_else(|| w.shown.clone());
            [downscale(&w.truth, factor), downscale(&w.shown, factor), downscale(&d, factor)]
        })
        .collect();
    if tiles.is_empty() {
        return Ok(());
    }
    let rows: Vec<Vec<&volwarp_core::Image>> = tiles.iter().map(|t| t.iter().collect()).collect();
    strip(&rows, 4, u32::MAX).save_png(path).map_err(|e| format!("{}: {e:?}", path.display()))?;
    let mut legend = String::from("row,method,tick,flip\n");
    for (i, w) in run.result.worst.iter().enumerate() {
        legend.push_str(&format!("{i},{},{},{:.4}\n", w.method, w.tick, w.flip));
    }
    std::fs::write(path.with_extension("csv"), legend)?;
    Ok(())
}

/// Reads a `session.csv` back into runs (their rows; no frame timelines or worst ticks), in
/// the order the sessions appear. With `calibration`, every row's draw time is replaced by the
/// calibration's figure for its method and size (to redraw the speed chart with measured
/// draw times: the scores do not depend on them while every draw fits a display tick).
pub fn load_session_csv(path: &Path, calibration: Option<&super::model::Calibration>) -> Result<Vec<Run>, ErrorBox> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    if header != SESSION_COLUMNS {
        return Err(format!("{}: not a session.csv (columns {:?})", path.display(), header).into());
    }
    let mut runs: Vec<Run> = Vec::new();
    for (i, line) in lines.enumerate() {
        let f: Vec<&str> = line.split(',').collect();
        let bad = || format!("{}: line {}: malformed", path.display(), i + 2);
        if f.len() != SESSION_COLUMNS.len() {
            return Err(bad().into());
        }
        let p = |j: usize| -> Result<f64, ErrorBox> {
            match f[j] {
                "inf" => Ok(f64::INFINITY),
                v => v.parse::<f64>().map_err(|_| bad().into()),
            }
        };
        let key = RunKey {
            dataset: f[0].into(),
            scenario: f[1].into(),
            policy: f[2].into(),
            size: f[3].parse().map_err(|_| bad())?,
            server_ms: p(4)?,
            latency_ms: p(5)?,
            mbps: p(6)?,
        };
        let draw_ms = match calibration {
            Some(c) => c.draw_ms(f[7], key.size),
            None => p(12)?,
        };
        let row = TickRow {
            method: f[7].into(),
            tick: f[8].parse().map_err(|_| bad())?,
            time_s: p(9)?,
            frame_seq: f[10].parse().map_err(|_| bad())?,
            frame_age_ms: p(11)?,
            draw_ms,
            metrics: crate::Metrics { psnr: p(13)?, ssim: p(14)?, flip: p(15)? },
        };
        match runs.last_mut() {
            Some(r) if r.key == key => r.result.rows.push(row),
            _ => runs.push(Run { key, result: SessionResult { rows: vec![row], ..Default::default() } }),
        }
    }
    Ok(runs)
}

/// Redraws the summaries and the speed-vs-accuracy (or sweep) chart of a session run from its
/// `session.csv` (see [`load_session_csv`]) into `out`.
pub fn replot(csv: &Path, calibration: Option<&super::model::Calibration>, out: &Path) -> Result<(), ErrorBox> {
    let runs = load_session_csv(csv, calibration)?;
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    summary_table(&runs).write(&out.join("summary.csv"))?;
    std::fs::write(out.join("summary.md"), summary_markdown(&runs))?;
    let size = runs.first().map_or(0, |r| r.key.size);
    speed_accuracy_chart(
        &runs,
        &format!("speed vs accuracy, {size}², every dataset and scenario"),
        &out.join("speed_accuracy.png"),
    )
}

/// Writes every file of a run into `out`.
pub fn write_all(runs: &[Run], out: &Path, sweep: Option<&str>) -> Result<(), ErrorBox> {
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    session_table(runs).write(&out.join("session.csv"))?;
    frames_table(runs).write(&out.join("frames.csv"))?;
    summary_table(runs).write(&out.join("summary.csv"))?;
    std::fs::write(out.join("summary.md"), summary_markdown(runs))?;
    match sweep {
        Some("server") => sweep_chart(
            runs,
            |k| k.server_ms,
            "server ms per frame (log)",
            |k| format!("{}², {} Mbit/s", k.size, k.mbps),
            &out.join("sweep_server.png"),
        )?,
        Some("bandwidth") => sweep_chart(
            runs,
            |k| k.mbps,
            "bandwidth Mbit/s (log)",
            |k| format!("{}², server {} ms", k.size, k.server_ms),
            &out.join("sweep_bandwidth.png"),
        )?,
        _ => {
            for ds in distinct(runs.iter().map(|r| r.key.dataset.clone())) {
                let sel: Vec<&Run> = runs.iter().filter(|r| r.key.dataset == ds).collect();
                flip_over_time_chart(&sel, &out.join(format!("flip_time_{}.png", safe(&ds))))?;
                for r in &sel {
                    worst_strip(r, &out.join(format!("worst_{}_{}.png", safe(&ds), safe(&r.key.scenario))))?;
                }
            }
            let size = runs.first().map_or(0, |r| r.key.size);
            speed_accuracy_chart(
                runs,
                &format!("speed vs accuracy, {size}², every dataset and scenario"),
                &out.join("speed_accuracy.png"),
            )?;
        }
    }
    Ok(())
}
