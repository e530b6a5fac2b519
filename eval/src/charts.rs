//! The charts: plotters with the bitmap backend and the DejaVu Sans font embedded in the binary
//! (registered once with `plotters::style::register_font`; no system fonts are needed).
//!
//! A chart is one or more [`Panel`]s side by side; a panel holds line and/or point [`Series`].

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};
use std::path::Path;
use std::sync::Once;

/// Why a chart could not be drawn.
#[derive(Debug)]
pub struct ChartError(pub String);

impl std::fmt::Display for ChartError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ChartError {}

fn err<E: std::fmt::Debug>(e: E) -> ChartError {
    ChartError(format!("{e:?}"))
}

static FONT: Once = Once::new();

/// Registers the embedded DejaVu Sans as `sans-serif` (idempotent).
pub fn register_embedded_font() {
    FONT.call_once(|| {
        if register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular()).is_err() {
            log::error!("the embedded DejaVu font could not be registered; chart text will fail");
        }
        if register_font("sans-serif", FontStyle::Bold, dejavu::sans::bold()).is_err() {
            log::error!("the embedded DejaVu bold font could not be registered");
        }
    });
}

/// How a series is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mark {
    /// A line through the points, with small dots.
    Line,
    /// Filled dots only.
    Dots,
    /// Hollow circles only (e.g. to ring highlighted points).
    Rings,
    /// A dashed-looking thin line only (reference lines).
    Thin,
}

/// One data series.
#[derive(Clone, Debug)]
pub struct Series {
    /// Legend text (empty: no legend entry).
    pub name: String,
    /// `(x, y)` points; non-finite ones are skipped.
    pub points: Vec<(f64, f64)>,
    /// Drawing style.
    pub mark: Mark,
    /// Palette index.
    pub color: usize,
    /// Text next to each point (same length as `points`, or empty).
    pub labels: Vec<String>,
}

impl Series {
    /// A series without point labels.
    pub fn new(name: &str, points: Vec<(f64, f64)>, mark: Mark, color: usize) -> Series {
        Series { name: name.into(), points, mark, color, labels: Vec::new() }
    }
}

/// How x tick labels are written.
#[derive(Clone, Debug, PartialEq)]
pub enum XAxis {
    /// Plain numbers.
    Linear,
    /// x holds log10 of the value; ticks show the value.
    Log10,
    /// x holds indices 0, 1, …; ticks show these names.
    Categories(Vec<String>),
}

/// One plot area.
#[derive(Clone, Debug)]
pub struct Panel {
    /// Caption.
    pub title: String,
    /// x axis description.
    pub x_desc: String,
    /// y axis description.
    pub y_desc: String,
    /// The series.
    pub series: Vec<Series>,
    /// x tick labels.
    pub x_axis: XAxis,
    /// Fixed y range (else from the data, padded).
    pub y_range: Option<(f64, f64)>,
    /// y holds log10 of the value; ticks show the value.
    pub y_log: bool,
    /// Where the legend goes.
    pub legend: Legend,
}

/// Legend placement.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Legend {
    /// Upper left corner.
    #[default]
    UpperLeft,
    /// Upper right corner.
    UpperRight,
    /// Lower left corner.
    LowerLeft,
    /// Lower right corner.
    LowerRight,
}

/// A color of the chart palette (distinct for the first ten indices).
pub fn color(i: usize) -> RGBColor {
    const C: [RGBColor; 10] = [
        RGBColor(31, 119, 180),
        RGBColor(255, 127, 14),
        RGBColor(44, 160, 44),
        RGBColor(214, 39, 40),
        RGBColor(148, 103, 189),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(127, 127, 127),
        RGBColor(188, 189, 34),
        RGBColor(23, 190, 207),
    ];
    C[i % C.len()]
}

/// A tick label: a few significant digits, no trailing zeros.
pub fn tick(v: f64) -> String {
    let a = v.abs();
    let s = if a >= 100.0 {
        format!("{v:.0}")
    } else if a >= 10.0 {
        format!("{v:.1}")
    } else if a >= 1.0 {
        format!("{v:.2}")
    } else {
        format!("{v:.3}")
    };
    if s.contains('.') {
        let t = s.trim_end_matches('0').trim_end_matches('.');
        if t == "-0" {
            "0".into()
        } else {
            t.into()
        }
    } else {
        s
    }
}

fn finite(points: &[(f64, f64)]) -> impl Iterator<Item = (f64, f64)> + '_ {
    points.iter().copied().filter(|(x, y)| x.is_finite() && y.is_finite())
}

fn range(vals: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in vals {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() || !hi.is_finite() {
        return (0.0, 1.0);
    }
    if hi - lo < 1e-9 {
        return (lo - 0.5, hi + 0.5);
    }
    let pad = (hi - lo) * 0.06;
    (lo - pad, hi + pad)
}

fn draw_panel(area: &DrawingArea<BitMapBackend<'_>, Shift>, p: &Panel) -> Result<(), ChartError> {
    let all: Vec<(f64, f64)> = p.series.iter().flat_map(|s| finite(&s.points).collect::<Vec<_>>()).collect();
    let (x0, x1) = match &p.x_axis {
        XAxis::Categories(c) => (-0.5, c.len() as f64 - 0.5),
        // Room on the right for point labels.
        XAxis::Log10 => {
            let (a, b) = range(all.iter().map(|v| v.0));
            (a, b + (b - a) * 0.12)
        }
        XAxis::Linear => range(all.iter().map(|v| v.0)),
    };
    let (y0, y1) = p.y_range.unwrap_or_else(|| range(all.iter().map(|v| v.1)));
    let mut chart = ChartBuilder::on(area)
        .caption(&p.title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(48)
        .y_label_area_size(64)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(err)?;
    let cats = match &p.x_axis {
        XAxis::Categories(c) => c.clone(),
        _ => Vec::new(),
    };
    let log = p.x_axis == XAxis::Log10;
    let fmt = move |v: &f64| -> String {
        if !cats.is_empty() {
            let i = v.round();
            if (v - i).abs() < 1e-6 && i >= 0.0 && (i as usize) < cats.len() {
                return cats[i as usize].clone();
            }
            return String::new();
        }
        if log {
            tick(10f64.powf(*v))
        } else {
            tick(*v)
        }
    };
    let y_log = p.y_log;
    let yfmt = move |v: &f64| -> String {
        if y_log {
            tick(10f64.powf(*v))
        } else {
            tick(*v)
        }
    };
    let n_cat = match &p.x_axis {
        XAxis::Categories(c) => c.len(),
        _ => 8,
    };
    chart
        .configure_mesh()
        .x_desc(&p.x_desc)
        .y_desc(&p.y_desc)
        .x_labels(if n_cat > 0 { n_cat.max(2) } else { 8 })
        .x_label_formatter(&fmt)
        .y_label_formatter(&yfmt)
        .label_style(("sans-serif", 14))
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(err)?;
    for s in &p.series {
        let c = color(s.color);
        let pts: Vec<(f64, f64)> = finite(&s.points).collect();
        let legend = !s.name.is_empty();
        match s.mark {
            Mark::Line | Mark::Thin => {
                let w = if s.mark == Mark::Line { 2 } else { 1 };
                let ann = chart.draw_series(LineSeries::new(pts.clone(), c.stroke_width(w))).map_err(err)?;
                if legend {
                    ann.label(&s.name)
                        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(2)));
                }
                if s.mark == Mark::Line {
                    chart.draw_series(pts.iter().map(|&p| Circle::new(p, 3, c.filled()))).map_err(err)?;
                }
            }
            Mark::Dots => {
                let ann = chart.draw_series(pts.iter().map(|&p| Circle::new(p, 5, c.filled()))).map_err(err)?;
                if legend {
                    ann.label(&s.name).legend(move |(x, y)| Circle::new((x + 9, y), 5, c.filled()));
                }
            }
            Mark::Rings => {
                let ann = chart.draw_series(pts.iter().map(|&p| Circle::new(p, 9, c.stroke_width(2)))).map_err(err)?;
                if legend {
                    ann.label(&s.name).legend(move |(x, y)| Circle::new((x + 9, y), 7, c.stroke_width(2)));
                }
            }
        }
        if !s.labels.is_empty() {
            chart
                .draw_series(
                    pts.iter().zip(&s.labels).map(|(&p, l)| {
                        Text::new(l.clone(), p, ("sans-serif", 13).into_font().color(&BLACK)).into_dyn()
                    }),
                )
                .map_err(err)?;
        }
    }
    if p.series.iter().any(|s| !s.name.is_empty()) {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.4))
            .label_font(("sans-serif", 13))
            .position(match p.legend {
                Legend::UpperLeft => SeriesLabelPosition::UpperLeft,
                Legend::UpperRight => SeriesLabelPosition::UpperRight,
                Legend::LowerLeft => SeriesLabelPosition::LowerLeft,
                Legend::LowerRight => SeriesLabelPosition::LowerRight,
            })
            .draw()
            .map_err(err)?;
    }
    Ok(())
}

/// Draws panels side by side into a PNG of `width × height` pixels.
pub fn draw(path: &Path, width: u32, height: u32, panels: &[Panel]) -> Result<(), ChartError> {
    register_embedded_font();
    if panels.is_empty() {
        return Err(ChartError("no panels".into()));
    }
    let root = BitMapBackend::new(path, (width, height)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let areas = root.split_evenly((1, panels.len()));
    for (a, p) in areas.iter().zip(panels) {
        draw_panel(a, p)?;
    }
    root.present().map_err(|e| ChartError(format!("{}: {e:?}", path.display())))?;
    Ok(())
}

/// Indices of the Pareto-optimal points when both coordinates are to be minimized (a point is
/// kept if no other point is at most as large in both and smaller in one), sorted by x.
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<usize> {
    let mut idx: Vec<usize> =
        (0..points.len()).filter(|&i| points[i].0.is_finite() && points[i].1.is_finite()).collect();
    idx.sort_by(|&a, &b| points[a].0.total_cmp(&points[b].0).then(points[a].1.total_cmp(&points[b].1)));
    let mut front = Vec::new();
    let mut best = f64::INFINITY;
    for i in idx {
        if points[i].1 < best {
            best = points[i].1;
            front.push(i);
        }
    }
    front
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_labels_are_short() {
        assert_eq!(tick(0.30000000001), "0.3");
        assert_eq!(tick(-0.1), "-0.1");
        assert_eq!(tick(12.345), "12.3");
        assert_eq!(tick(250.0), "250");
        assert_eq!(tick(-0.0001), "0");
    }

    #[test]
    fn pareto_front_keeps_the_non_dominated_points() {
        let p = [(1.0, 5.0), (2.0, 3.0), (3.0, 4.0), (4.0, 1.0), (0.5, 9.0), (f64::NAN, 0.0)];
        assert_eq!(pareto_front(&p), vec![4, 0, 1, 3]);
    }

    #[test]
    fn draws_a_chart_with_the_embedded_font() {
        let dir = std::env::temp_dir().join(format!("volwarp-chart-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("c.png");
        let panel = Panel {
            title: "t".into(),
            x_desc: "x".into(),
            y_desc: "y".into(),
            series: vec![
                Series::new("a", vec![(0.0, 1.0), (1.0, 2.0)], Mark::Line, 0),
                Series::new("b", vec![(0.5, 1.5)], Mark::Dots, 1),
            ],
            x_axis: XAxis::Categories(vec!["p".into(), "q".into()]),
            y_range: None,
            y_log: false,
            legend: Legend::UpperLeft,
        };
        draw(&path, 300, 200, &[panel.clone(), Panel { x_axis: XAxis::Log10, ..panel }]).unwrap();
        let img = image::open(&path).unwrap();
        assert_eq!((img.width(), img.height()), (300, 200));
        std::fs::remove_dir_all(&dir).ok();
    }
}
