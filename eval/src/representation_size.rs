//! How small can a sample be? Error against the representation's size ("model no more
//! than a scene needs").
//!
//! The frame's samples are taken before quantization (float positions `o + d·t` and the float
//! radius of the voxel model, half a voxel diagonal), then re-quantized in software: positions to `b` bits per axis over the volume box
//! (`q = round((p − min) / extent · (2ᵇ − 1))`, decoded at `min + q · extent / (2ᵇ − 1)`, as
//! the wire format does with b = 18), the radius to an `r`-bit code whose step spans the wire's
//! whole radius range (0 to 16× the default radius, as `CameraRequest::radius_scale` allows),
//! and the sample count by keeping one pixel in `s × s` (radius × s, so the kept spheres cover
//! the same area). The unquantized float samples are the reference.
//!
//! Every variant is drawn by the same exact float sphere splatter ([`render_spheres`]: per
//! pixel, the nearest `core::sphere::intersect` hit, ties to the smaller index, as every volwarp
//! tracer), so the only difference between variants is the representation.

use crate::charts::{self, Mark, Panel, Series, XAxis};
use crate::csv::{num, Table};
use crate::metrics::psnr;
use crate::{ErrorBox, Metrics};
use rayon::prelude::*;
use std::path::Path;
use volwarp_core::sample::over_background;
use volwarp_core::sphere::intersect;
use volwarp_core::traversal::{closer, Hit};
use volwarp_core::{Camera, Heuristic, Image, Vec3, BACKGROUND};
use volwarp_server::dataset::Dataset;
use volwarp_server::{MarchOptions, Marcher, RadiusModel};

/// Position bits per axis swept (10 to 21 asked for; the sweep starts lower to find
/// where the error sets in).
pub const POSITION_BITS: std::ops::RangeInclusive<u32> = 6..=21;
/// Radius code bits swept.
pub const RADIUS_BITS: std::ops::RangeInclusive<u32> = 2..=10;
/// Subsampling strides swept (1 keeps every sample).
pub const STRIDES: [u32; 4] = [1, 2, 3, 4];
/// Largest radius the radius code must represent, in default radii.
pub const RADIUS_RANGE: f32 = 16.0;
/// Allowed PSNR loss against the float reference, in dB.
pub const TOLERANCE_DB: f64 = 0.1;

/// Float samples of one frame.
#[derive(Clone, Debug, Default)]
pub struct FloatSamples {
    /// Centers.
    pub centers: Vec<Vec3>,
    /// Radius of each.
    pub radii: Vec<f32>,
    /// Premultiplied RGBA8 color of each.
    pub colors: Vec<u32>,
    /// Pixel of each (x, y) in the frame.
    pub pixels: Vec<(u32, u32)>,
}

/// The frame's samples before quantization: one per non-empty pixel of `c0`.
pub fn float_samples(marcher: &Marcher, c0: &Camera, heuristic: Heuristic) -> FloatSamples {
    let pb = marcher.march(c0, heuristic);
    let basis = c0.ray_basis();
    let o = basis.origin();
    let r = marcher.default_radius();
    let mut s = FloatSamples::default();
    for (i, &t) in pb.t.iter().enumerate() {
        if t.is_finite() {
            let (x, y) = (i as u32 % pb.width, i as u32 / pb.width);
            s.centers.push(o + basis.dir(x, y) * t);
            s.radii.push(r);
            s.colors.push(pb.color[i]);
            s.pixels.push((x, y));
        }
    }
    s
}

/// Re-quantizes positions to `bits` per axis over `[min, max]` (see the module docs).
pub fn quantize_positions(s: &FloatSamples, min: Vec3, max: Vec3, bits: u32) -> FloatSamples {
    let levels = ((1u64 << bits.min(31)) - 1) as f64;
    let d = |v: Vec3| [v.x as f64, v.y as f64, v.z as f64];
    let (lo, hi) = (d(min), d(max));
    let q = |v: f64, k: usize| -> f32 {
        let e = hi[k] - lo[k];
        if e <= 0.0 {
            return lo[k] as f32;
        }
        let n = ((v - lo[k]) / e * levels).round().clamp(0.0, levels);
        (lo[k] + n * e / levels) as f32
    };
    let centers = s
        .centers
        .iter()
        .map(|&c| {
            let c = d(c);
            Vec3::new(q(c[0], 0), q(c[1], 1), q(c[2], 2))
        })
        .collect();
    FloatSamples { centers, ..s.clone() }
}

/// The radius after an `bits`-bit code spanning `0..=RADIUS_RANGE × default` (at least code 1).
pub fn quantize_radius(radius: f32, default_radius: f32, bits: u32) -> f32 {
    let levels = ((1u64 << bits.min(31)) - 1) as f32;
    let unit = RADIUS_RANGE * default_radius / levels;
    let code = (radius / unit).round().clamp(1.0, levels);
    code * unit
}

/// Keeps one sample per `stride × stride` pixel block (its top-left pixel) and scales radii by
/// `stride`.
pub fn subsample(s: &FloatSamples, stride: u32) -> FloatSamples {
    let st = stride.max(1);
    let mut out = FloatSamples::default();
    for i in 0..s.centers.len() {
        let (x, y) = s.pixels[i];
        if x % st == 0 && y % st == 0 {
            out.centers.push(s.centers[i]);
            out.radii.push(s.radii[i] * st as f32);
            out.colors.push(s.colors[i]);
            out.pixels.push((x, y));
        }
    }
    out
}

/// Draws spheres exactly (object order: each sphere's conservative screen rectangle, per pixel
/// the nearest hit of the pixel's ray, ties to the smaller index). Parallel over row bands.
pub fn render_spheres(s: &FloatSamples, camera: &Camera) -> Image {
    let (w, h) = (camera.width, camera.height);
    let mut img = Image::new(w, h);
    if camera.validate(16384).is_err() {
        return img;
    }
    let basis = camera.ray_basis();
    let o = basis.origin();
    let (_, _, fwd) = camera.basis();
    let f = (h as f32 * 0.5) / (camera.fov_y_deg.to_radians() * 0.5).tan();
    const BAND: u32 = 16;
    let bands = h.div_ceil(BAND) as usize;
    let mut buckets: Vec<Vec<(u32, [u32; 4])>> = vec![Vec::new(); bands];
    for (i, (&c, &r)) in s.centers.iter().zip(&s.radii).enumerate() {
        let z = (c - o).dot(fwd);
        let rect = if z > r * 1.01 {
            match camera.project(c) {
                Some((px, py, _)) => {
                    let pr = r / (z - r) * f * 1.05 + 2.0;
                    let clampx = |v: f32| v.clamp(0.0, w as f32 - 1.0) as u32;
                    let clampy = |v: f32| v.clamp(0.0, h as f32 - 1.0) as u32;
                    if px + pr < 0.0 || py + pr < 0.0 || px - pr > w as f32 || py - pr > h as f32 {
                        continue;
                    }
                    [clampx(px - pr), clampy(py - pr), clampx(px + pr), clampy(py + pr)]
                }
                None => continue,
            }
        } else if z + r > 0.0 {
            [0, 0, w - 1, h - 1]
        } else {
            continue;
        };
        for b in (rect[1] / BAND)..=(rect[3] / BAND) {
            buckets[b as usize].push((i as u32, rect));
        }
    }
    img.pixels.par_chunks_mut((w * BAND) as usize).enumerate().for_each(|(b, px)| {
        let y0 = b as u32 * BAND;
        let rows = px.len() as u32 / w;
        let mut best: Vec<Option<Hit>> = vec![None; px.len()];
        for &(i, rect) in &buckets[b] {
            let (c, r) = (s.centers[i as usize], s.radii[i as usize]);
            for y in rect[1].max(y0)..=rect[3].min(y0 + rows - 1) {
                for x in rect[0]..=rect[2] {
                    let d = basis.dir(x, y);
                    if let Some(t) = intersect(o, d, c, r) {
                        let k = ((y - y0) * w + x) as usize;
                        if closer(t, i, &best[k]) {
                            best[k] = Some(Hit { t, prim: i });
                        }
                    }
                }
            }
        }
        for (p, hit) in px.iter_mut().zip(&best) {
            *p = match hit {
                Some(hh) => over_background(s.colors[hh.prim as usize], BACKGROUND),
                None => BACKGROUND,
            };
        }
    });
    img
}

/// One variant's result.
#[derive(Clone, Debug)]
pub struct Variant {
    /// Which sweep (`position`, `radius`, `stride`, `float`).
    pub sweep: &'static str,
    /// The swept value (bits or stride; 0 for float).
    pub value: u32,
    /// Bits per sample on the wire (3 positions + radius code + 32-bit color).
    pub bits_per_sample: u32,
    /// Samples.
    pub samples: usize,
    /// Scores at each evaluated angle.
    pub metrics: Vec<Metrics>,
}

/// Runs the three sweeps; `angles` are the orbit angles (degrees) scored.
pub fn sweep(marcher: &Marcher, c0: &Camera, heuristic: Heuristic, angles: &[f32]) -> Vec<Variant> {
    let s = float_samples(marcher, c0, heuristic);
    let b = marcher.volume().bounds();
    let (min, max) = (b.min(), b.max());
    let r0 = marcher.default_radius();
    let cams: Vec<Camera> = angles.iter().map(|&a| crate::camera_paths::orbit(c0, a)).collect();
    let truths: Vec<Image> = cams.iter().map(|c| marcher.render_image(c)).collect();
    let score = |v: &FloatSamples| -> Vec<Metrics> {
        cams.iter()
            .zip(&truths)
            .map(|(c, t)| Metrics::of(t, &render_spheres(v, c)).unwrap_or(Metrics { psnr: 0.0, ssim: 0.0, flip: 1.0 }))
            .collect()
    };
    let wire = |pos: u32, rad: u32| 3 * pos + rad + 32;
    let mut out = vec![Variant {
        sweep: "float",
        value: 0,
        bits_per_sample: 3 * 32 + 32 + 32,
        samples: s.centers.len(),
        metrics: score(&s),
    }];
    for bits in POSITION_BITS {
        let v = quantize_positions(&s, min, max, bits);
        out.push(Variant {
            sweep: "position",
            value: bits,
            bits_per_sample: wire(bits, 32),
            samples: v.centers.len(),
            metrics: score(&v),
        });
    }
    for bits in RADIUS_BITS {
        let mut v = s.clone();
        for r in &mut v.radii {
            *r = quantize_radius(*r, r0, bits);
        }
        out.push(Variant {
            sweep: "radius",
            value: bits,
            bits_per_sample: wire(32, bits),
            samples: v.centers.len(),
            metrics: score(&v),
        });
    }
    for st in STRIDES {
        let v = subsample(&s, st);
        out.push(Variant {
            sweep: "stride",
            value: st,
            bits_per_sample: wire(18, 10),
            samples: v.centers.len(),
            metrics: score(&v),
        });
    }
    out
}

/// The smallest value `v` of a sweep such that every swept value `≥ v` keeps PSNR within
/// [`TOLERANCE_DB`] of the float reference at every angle (PSNR wobbles by a few hundredths of a
/// dB from one bit count to the next, so a lone passing value below a failing one does not
/// count).
pub fn smallest_within(variants: &[Variant], sweep: &str) -> Option<u32> {
    let float = variants.iter().find(|v| v.sweep == "float")?;
    let passes = |v: &Variant| {
        v.metrics.iter().zip(&float.metrics).all(|(m, f)| {
            let (a, b) = (m.psnr.min(psnr::PSNR_IDENTICAL), f.psnr.min(psnr::PSNR_IDENTICAL));
            a >= b - TOLERANCE_DB
        })
    };
    let mut mine: Vec<&Variant> = variants.iter().filter(|v| v.sweep == sweep).collect();
    mine.sort_by_key(|v| std::cmp::Reverse(v.value));
    let mut best = None;
    for v in mine {
        if !passes(v) {
            break;
        }
        best = Some(v.value);
    }
    best
}

/// `volwarp-eval bits`: runs [`sweep`] at angles 0° and 10° and writes `bits.csv`,
/// `error_vs_size.png` and `bits.md` (the chosen defaults).
pub fn run(ds: &Dataset, heuristic: Heuristic, size: u32, out: &Path) -> Result<(), ErrorBox> {
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    // The voxel radius model: one radius for the whole frame, which the radius-bits sweep
    // quantizes against (the footprint model's per-sample radii are studied by `radius`).
    let marcher = Marcher::from_dataset(ds)
        .with_transfer_function(&ds.tf, MarchOptions { radius: RadiusModel::Voxel, ..MarchOptions::default() });
    let c0 = marcher.default_camera(size, size);
    let angles = [0.0f32, 10.0];
    log::info!("{}: representation sweep at {size}², angles {angles:?}", ds.name);
    let vs = sweep(&marcher, &c0, heuristic, &angles);
    let mut t = Table::new(&[
        "dataset",
        "sweep",
        "value",
        "bits_per_sample",
        "samples",
        "frame_kib",
        "angle_deg",
        "psnr",
        "psnr_minus_float",
        "ssim",
        "flip",
    ]);
    let float = vs[0].clone();
    for v in &vs {
        for (k, m) in v.metrics.iter().enumerate() {
            t.push(vec![
                ds.name.clone(),
                v.sweep.into(),
                v.value.to_string(),
                v.bits_per_sample.to_string(),
                v.samples.to_string(),
                num(Some(v.samples as f64 * v.bits_per_sample as f64 / 8.0 / 1024.0), 1),
                format!("{}", angles[k]),
                num(Some(m.psnr), 3),
                num(Some(m.psnr - float.metrics[k].psnr), 3),
                num(Some(m.ssim), 4),
                num(Some(m.flip), 4),
            ]);
        }
    }
    t.write(&out.join("bits.csv"))?;
    let mut panels = Vec::new();
    for (sweep, title, xd) in [
        ("position", "position bits per axis", "bits per axis"),
        ("radius", "radius code bits", "radius code bits"),
        ("stride", "samples kept (1 in s×s)", "stride s"),
    ] {
        let mut series = Vec::new();
        for (k, a) in angles.iter().enumerate() {
            let pts = vs
                .iter()
                .filter(|v| v.sweep == sweep)
                .map(|v| (v.value as f64, v.metrics[k].psnr - float.metrics[k].psnr))
                .collect();
            series.push(Series::new(&format!("{a}° orbit"), pts, Mark::Line, k));
        }
        let xs: Vec<f64> = vs.iter().filter(|v| v.sweep == sweep).map(|v| v.value as f64).collect();
        let (lo, hi) =
            (xs.iter().cloned().fold(f64::INFINITY, f64::min), xs.iter().cloned().fold(f64::NEG_INFINITY, f64::max));
        series.push(Series::new("−0.1 dB", vec![(lo, -TOLERANCE_DB), (hi, -TOLERANCE_DB)], Mark::Thin, 3));
        panels.push(Panel {
            title: format!("{}: {title}", ds.name),
            x_desc: xd.into(),
            y_desc: "PSNR − PSNR(float) dB".into(),
            series,
            x_axis: XAxis::Linear,
            y_range: None,
            y_log: false,
            legend: charts::Legend::UpperLeft,
        });
    }
    charts::draw(&out.join("error_vs_size.png"), 1800, 600, &panels)?;
    let pos = smallest_within(&vs, "position");
    let rad = smallest_within(&vs, "radius");
    let md = format!(
        "dataset {} at {size}², heuristic {}: float reference PSNR {:.2} dB (0°) / {:.2} dB (10°).\n\
         Smallest position bits within {TOLERANCE_DB} dB of float at both angles: {}; smallest radius code bits: {}.\n",
        ds.name,
        heuristic.name(),
        float.metrics[0].psnr,
        float.metrics[1].psnr,
        pos.map_or("none".into(), |b| b.to_string()),
        rad.map_or("none".into(), |b| b.to_string()),
    );
    std::fs::write(out.join("bits.md"), &md)?;
    log::info!("{}", md.trim());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantization_steps() {
        let s = FloatSamples {
            centers: vec![Vec3::new(0.3, 0.5, 0.99)],
            radii: vec![1.0],
            colors: vec![0],
            pixels: vec![(0, 0)],
        };
        let q = quantize_positions(&s, Vec3::ZERO, Vec3::ONE, 2);
        // 2 bits: levels 0, 1/3, 2/3, 1.
        assert!((q.centers[0] - Vec3::new(1.0 / 3.0, 2.0 / 3.0, 1.0)).length() < 1e-6);
        assert_eq!(quantize_radius(1.0, 1.0, 4), 16.0 / 15.0);
        assert!((quantize_radius(1.0, 1.0, 10) - 1.0).abs() < 0.01);
        let big = FloatSamples {
            centers: vec![Vec3::ZERO; 16],
            radii: vec![1.0; 16],
            colors: vec![0; 16],
            pixels: (0..16).map(|i| (i % 4, i / 4)).collect(),
        };
        let m = |p: f64| Metrics { psnr: p, ssim: 1.0, flip: 0.0 };
        let var = |sweep: &'static str, value: u32, p: f64| Variant {
            sweep,
            value,
            bits_per_sample: 0,
            samples: 1,
            metrics: vec![m(p)],
        };
        let vs = vec![
            var("float", 0, 30.0),
            var("position", 7, 30.0),
            var("position", 8, 29.5),
            var("position", 9, 29.95),
            var("position", 10, 30.02),
        ];
        assert_eq!(smallest_within(&vs, "position"), Some(9), "a lone pass below a failure does not count");
        assert_eq!(smallest_within(&vs, "radius"), None);
        let sub = subsample(&big, 2);
        assert_eq!(sub.centers.len(), 4);
        assert_eq!(sub.radii[0], 2.0);
    }
}
