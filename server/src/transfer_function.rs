//! Transfer functions: a 1-D RGBA lookup table over the normalized data range `0..=1`.
//!
//! Colors are straight (not premultiplied) RGB in `0..=1`. Opacity is the opacity of a slab
//! **one reference step thick**, where the reference step is one voxel (the smallest spacing);
//! the marcher corrects it for its actual step (`1 − (1 − α)^(Δt / ref)`).
//!
//! A table is built from piecewise-linear control points ([`TransferFunction::from_points`]),
//! from a preset ([`TransferFunction::preset`]), or loaded from a file
//! ([`TransferFunction::load`]):
//!
//! - **ParaView JSON** (`.json`, *Save colormap* / exported transfer function): the first object
//!   (or the object itself) with `RGBPoints` (`x, r, g, b` quadruples) and optional opacity
//!   `Points` (`x, α, midpoint, sharpness` quadruples; midpoint and sharpness ignored). `x` is in
//!   data units, or in fractions of the value range where the object has `"Normalized": true`
//!   (the bundled presets, [`crate::visual::PRESETS`]).
//! - **Text** (any other extension), one control point per line, `#` starts a comment:
//!   `x r g b a` (color and opacity point), `x r g b` (color point), `x a` (opacity point).
//!   `x` is in data units unless the file has a line `normalized`, then it is in `0..=1`.
//!   Values between points are linear; outside them the end values hold. Without color points
//!   the color is white; without opacity points the opacity is a ramp from 0 to 1.

use std::fmt;
use std::path::Path;

/// Entries of the lookup table.
pub const LUT_SIZE: usize = 1024;

/// A transfer-function loading error, naming the file.
#[derive(Debug)]
pub struct TfError {
    /// The file.
    pub path: String,
    /// What is wrong.
    pub msg: String,
}

impl fmt::Display for TfError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.path, self.msg)
    }
}

impl std::error::Error for TfError {}

/// A 1-D RGBA lookup table (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct TransferFunction {
    /// A short name (preset or file stem).
    pub name: String,
    lut: Vec<[f32; 4]>,
}

fn interp<const N: usize>(points: &[(f32, [f32; N])], x: f32, default: [f32; N]) -> [f32; N] {
    match points {
        [] => default,
        [(_, v)] => *v,
        _ => {
            if x <= points[0].0 {
                return points[0].1;
            }
            for w in points.windows(2) {
                let ((x0, a), (x1, b)) = (w[0], w[1]);
                if x <= x1 {
                    let f = if x1 > x0 { (x - x0) / (x1 - x0) } else { 1.0 };
                    let mut out = [0.0; N];
                    for i in 0..N {
                        out[i] = a[i] + (b[i] - a[i]) * f;
                    }
                    return out;
                }
            }
            points[points.len() - 1].1
        }
    }
}

impl TransferFunction {
    /// A table from piecewise-linear control points over normalized `x` (sorted here; non-finite
    /// points dropped; values clamped to `0..=1`).
    pub fn from_points(name: &str, color: &[(f32, [f32; 3])], opacity: &[(f32, f32)]) -> TransferFunction {
        let clean3 = |v: [f32; 3]| v.map(|c| if c.is_finite() { c.clamp(0.0, 1.0) } else { 0.0 });
        let mut color: Vec<(f32, [f32; 3])> =
            color.iter().filter(|(x, _)| x.is_finite()).map(|&(x, c)| (x, clean3(c))).collect();
        let mut opacity: Vec<(f32, [f32; 1])> = opacity
            .iter()
            .filter(|(x, a)| x.is_finite() && a.is_finite())
            .map(|&(x, a)| (x, [a.clamp(0.0, 1.0)]))
            .collect();
        color.sort_by(|a, b| a.0.total_cmp(&b.0));
        opacity.sort_by(|a, b| a.0.total_cmp(&b.0));
        if opacity.is_empty() {
            opacity = vec![(0.0, [0.0]), (1.0, [1.0])];
        }
        let lut = (0..LUT_SIZE)
            .map(|i| {
                let x = i as f32 / (LUT_SIZE - 1) as f32;
                let [r, g, b] = interp(&color, x, [1.0; 3]);
                let [a] = interp(&opacity, x, [0.0]);
                [r, g, b, a]
            })
            .collect();
        TransferFunction { name: name.to_string(), lut }
    }

    /// A function of a whole table of [`LUT_SIZE`] entries (straight RGB, reference-step
    /// opacity; non-finite values become 0, all clamped to `0..=1`; a table of another length
    /// is resampled by nearest entry).
    pub fn from_table(name: &str, table: Vec<[f32; 4]>) -> TransferFunction {
        let clean = |e: [f32; 4]| e.map(|c| if c.is_finite() { c.clamp(0.0, 1.0) } else { 0.0 });
        let lut = if table.len() == LUT_SIZE {
            table.into_iter().map(clean).collect()
        } else if table.is_empty() {
            vec![[1.0, 1.0, 1.0, 0.0]; LUT_SIZE]
        } else {
            let n = table.len();
            (0..LUT_SIZE).map(|i| clean(table[(i * n / LUT_SIZE).min(n - 1)])).collect()
        };
        TransferFunction { name: name.to_string(), lut }
    }

    /// The table entry for a normalized value (nearest entry; out-of-range values clamp).
    #[inline(always)]
    pub fn index(v: f32) -> usize {
        let f = v * (LUT_SIZE - 1) as f32 + 0.5;
        if f >= (LUT_SIZE - 1) as f32 {
            LUT_SIZE - 1
        } else if f > 0.0 {
            f as usize
        } else {
            0
        }
    }

    /// RGBA (straight color, reference-step opacity) of a normalized value.
    #[inline(always)]
    pub fn lookup(&self, v: f32) -> [f32; 4] {
        self.lut[Self::index(v)]
    }

    /// The table.
    pub fn table(&self) -> &[[f32; 4]] {
        &self.lut
    }

    /// Whether some entry over `[lo, hi]` is visible (`max_opacity(lo, hi) > 0`), as a test
    /// of constant time per range: a prefix count of the table's visible entries, made once.
    /// The empty-space occupancy asks it of every brick, and a live edit remakes the occupancy:
    /// scanning the table per brick took 22 ms on the MRI's bricks (`docs/perf.md`).
    pub fn visibility(&self) -> impl Fn(f32, f32) -> bool + '_ {
        let prefix = self.visible_counts();
        move |lo: f32, hi: f32| {
            let (a, b) = (Self::index(lo.min(hi)), Self::index(hi.max(lo)));
            prefix[b + 1] > prefix[a]
        }
    }

    /// The prefix count of the visible table entries: entry `i + 1` counts those of `0..=i`
    /// (so some entry of `a..=b` is visible where `counts[b + 1] > counts[a]`).
    pub fn visible_counts(&self) -> Vec<u32> {
        let mut prefix = Vec::with_capacity(self.lut.len() + 1);
        prefix.push(0u32);
        for e in &self.lut {
            prefix.push(prefix[prefix.len() - 1] + u32::from(e[3] > 0.0));
        }
        prefix
    }

    /// The largest opacity any value in `lo..=hi` (normalized) can look up.
    pub fn max_opacity(&self, lo: f32, hi: f32) -> f32 {
        let (a, b) = (Self::index(lo.min(hi)), Self::index(hi.max(lo)));
        self.lut[a..=b].iter().fold(0.0f32, |m, e| m.max(e[3]))
    }

    /// A grey ramp: transparent below 10 % of the range, then rising opacity.
    pub fn grey_ramp() -> TransferFunction {
        TransferFunction::from_points(
            "grey-ramp",
            &[(0.0, [0.2, 0.2, 0.2]), (1.0, [1.0, 1.0, 1.0])],
            &[(0.1, 0.0), (1.0, 0.6)],
        )
    }

    /// The preset for a dataset name (`mri_colin27`, `ct_head_quarter`, `neghip`,
    /// `iron_protein`, `tooth`, `marschner-lobb`, `synth`; a name is matched by prefix), or the
    /// grey ramp. The `synth` preset's opacities are those of a 1024³ volume; see
    /// [`TransferFunction::preset_for`].
    pub fn preset(dataset: &str) -> TransferFunction {
        let n = dataset.to_ascii_lowercase();
        let tf = |c: &[(f32, [f32; 3])], o: &[(f32, f32)]| TransferFunction::from_points(&n, c, o);
        if n.starts_with("mri") {
            // Skin and soft tissue from ~30/254, the brain's grey/white matter brighter.
            tf(
                &[
                    (0.10, [0.55, 0.30, 0.22]),
                    (0.25, [0.90, 0.65, 0.50]),
                    (0.45, [0.95, 0.85, 0.75]),
                    (0.7, [1.0, 1.0, 0.95]),
                ],
                &[(0.08, 0.0), (0.14, 0.04), (0.30, 0.10), (0.45, 0.35), (0.7, 0.8)],
            )
        } else if n.starts_with("ct_head") || n.starts_with("ct-head") {
            // 0..3926: air < 600, soft tissue ~900..1300, bone > 1400.
            tf(
                &[
                    (0.18, [0.75, 0.45, 0.35]),
                    (0.30, [0.9, 0.7, 0.6]),
                    (0.36, [0.95, 0.92, 0.85]),
                    (1.0, [1.0, 1.0, 1.0]),
                ],
                &[(0.16, 0.0), (0.22, 0.03), (0.32, 0.04), (0.38, 0.7), (1.0, 0.95)],
            )
        } else if n.starts_with("neghip") {
            tf(
                &[(0.0, [0.1, 0.2, 0.9]), (0.4, [0.2, 0.9, 0.4]), (0.7, [1.0, 0.8, 0.1]), (1.0, [1.0, 0.2, 0.1])],
                &[(0.1, 0.0), (0.3, 0.05), (0.7, 0.3), (1.0, 0.9)],
            )
        } else if n.starts_with("iron") {
            // After VTK's SimpleRayCast: opacity (20, 0) to (255, 0.2), black-red-blue-green.
            tf(
                &[
                    (0.0, [0.0, 0.0, 0.0]),
                    (64.0 / 255.0, [1.0, 0.0, 0.0]),
                    (128.0 / 255.0, [0.0, 0.0, 1.0]),
                    (192.0 / 255.0, [0.0, 1.0, 0.0]),
                    (1.0, [0.0, 0.2, 0.0]),
                ],
                &[(20.0 / 255.0, 0.0), (1.0, 0.2)],
            )
        } else if n.starts_with("tooth") {
            // Background ~70/255, dentin ~150, enamel ~230.
            tf(
                &[(0.4, [0.8, 0.5, 0.4]), (0.6, [0.95, 0.85, 0.7]), (0.9, [1.0, 1.0, 1.0])],
                &[(0.38, 0.0), (0.5, 0.05), (0.6, 0.3), (0.9, 0.9)],
            )
        } else if n.starts_with("marschner") {
            tf(
                &[(0.0, [0.2, 0.4, 1.0]), (0.5, [0.9, 0.9, 0.9]), (1.0, [1.0, 0.4, 0.2])],
                &[(0.45, 0.0), (0.5, 0.6), (0.55, 0.0)],
            )
        } else if n.starts_with("synth") {
            // The synthetic volumes of `crate::synth`: background noise < 0.03, fog 0.2..0.47
            // (faint), ball interiors 0.58 (semi-transparent), the gyroid band 0.70 (a
            // semi-transparent surface), ball shells 0.95 and the outer shell 1 (opaque, one
            // color, so the depth a ray enters them at does not show). Nearly transparent in
            // between, where only the edges of features pass. Opacities for a volume 1024 voxels
            // wide.
            tf(
                &[
                    (0.10, [0.10, 0.20, 0.60]),
                    (0.30, [0.20, 0.50, 0.90]),
                    (0.45, [0.30, 0.85, 0.80]),
                    (0.58, [1.00, 0.55, 0.20]),
                    (0.66, [0.55, 0.90, 0.30]),
                    (0.76, [0.55, 0.90, 0.30]),
                    (0.88, [0.95, 0.92, 0.85]),
                ],
                &[
                    (0.10, 0.0),
                    (0.20, 0.0008),
                    (0.47, 0.003),
                    (0.52, 0.004),
                    (0.55, 0.012),
                    (0.62, 0.012),
                    (0.66, 0.08),
                    (0.74, 0.08),
                    (0.77, 0.005),
                    (0.87, 0.005),
                    (0.92, 0.85),
                    (1.0, 0.9),
                ],
            )
        } else {
            TransferFunction::grey_ramp()
        }
    }

    /// The preset of `dataset` ([`TransferFunction::preset`]) for a volume of `dims` voxels.
    /// The same as the preset except for synthetic volumes (`synth`), whose content scales with
    /// the volume: their opacities (per voxel) are converted from 1024 voxels to the volume's
    /// geometric mean size, `1 − (1 − α)^(1024 / n)`, so that every size looks alike.
    pub fn preset_for(dataset: &str, dims: [u32; 3]) -> TransferFunction {
        let mut tf = TransferFunction::preset(dataset);
        if dataset.to_ascii_lowercase().starts_with("synth") {
            let n = dims.iter().map(|&d| f64::from(d.max(1))).product::<f64>().cbrt();
            let e = (1024.0 / n) as f32;
            for entry in &mut tf.lut {
                entry[3] = 1.0 - (1.0 - entry[3]).powf(e);
            }
        }
        tf
    }

    /// Loads a ParaView JSON (`.json`) or text transfer function; `value_range` is the volume's
    /// data range, which maps data units to the normalized table.
    pub fn load(path: impl AsRef<Path>, value_range: (f32, f32)) -> Result<TransferFunction, TfError> {
        let path = path.as_ref();
        let err = |msg: String| TfError { path: path.display().to_string(), msg };
        let meta = std::fs::metadata(path).map_err(|e| err(format!("cannot read: {e}")))?;
        if meta.len() > 16 << 20 {
            return Err(err(format!("{} bytes is too large for a transfer function", meta.len())));
        }
        let text = std::fs::read_to_string(path).map_err(|e| err(format!("cannot read: {e}")))?;
        let name = path.file_stem().and_then(|s| s.to_str()).unwrap_or("tf");
        let is_json = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("json"));
        let r = if is_json {
            Self::parse_paraview_json(name, &text, value_range)
        } else {
            Self::parse_text(name, &text, value_range)
        };
        r.map_err(err)
    }

    fn normalizer(range: (f32, f32)) -> impl Fn(f32) -> f32 {
        let (lo, hi) = range;
        let span = hi - lo;
        move |x| if span > 0.0 { (x - lo) / span } else { 0.0 }
    }

    /// Parses ParaView's JSON (see the module docs).
    pub fn parse_paraview_json(name: &str, text: &str, value_range: (f32, f32)) -> Result<TransferFunction, String> {
        let v: serde_json::Value = serde_json::from_str(text).map_err(|e| format!("not JSON: {e}"))?;
        let obj = match &v {
            serde_json::Value::Array(a) => a.first().ok_or("empty JSON array")?,
            o => o,
        };
        let nums = |key: &str| -> Result<Option<Vec<f32>>, String> {
            match obj.get(key) {
                None => Ok(None),
                Some(serde_json::Value::Array(a)) => a
                    .iter()
                    .map(|x| x.as_f64().map(|f| f as f32).ok_or_else(|| format!("{key} holds a non-number")))
                    .collect::<Result<Vec<_>, _>>()
                    .map(Some),
                Some(_) => Err(format!("{key} is not an array")),
            }
        };
        // `"Normalized": true` (volwarp's presets; ParaView ignores the key): points in
        // fractions of the value range.
        let normalized = obj.get("Normalized").and_then(|n| n.as_bool()).unwrap_or(false);
        let norm = Self::normalizer(if normalized { (0.0, 1.0) } else { value_range });
        let rgb = nums("RGBPoints")?.ok_or("no RGBPoints")?;
        if rgb.len() % 4 != 0 || rgb.is_empty() {
            return Err(format!("RGBPoints has {} numbers, not a multiple of 4", rgb.len()));
        }
        let color: Vec<_> = rgb.chunks_exact(4).map(|c| (norm(c[0]), [c[1], c[2], c[3]])).collect();
        let opacity: Vec<_> = match nums("Points")? {
            Some(p) if p.len() % 4 == 0 && !p.is_empty() => p.chunks_exact(4).map(|c| (norm(c[0]), c[1])).collect(),
            Some(p) => return Err(format!("Points has {} numbers, not a multiple of 4", p.len())),
            None => Vec::new(),
        };
        let name = obj.get("Name").and_then(|n| n.as_str()).unwrap_or(name);
        Ok(TransferFunction::from_points(name, &color, &opacity))
    }

    /// Parses the text format (see the module docs).
    pub fn parse_text(name: &str, text: &str, value_range: (f32, f32)) -> Result<TransferFunction, String> {
        let mut normalized = false;
        let (mut color, mut opacity) = (Vec::new(), Vec::new());
        for (i, line) in text.lines().enumerate() {
            let line = line.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            if line.eq_ignore_ascii_case("normalized") {
                normalized = true;
                continue;
            }
            let v: Result<Vec<f32>, _> = line.split_whitespace().take(6).map(|s| s.parse::<f32>()).collect();
            let v = v.map_err(|_| format!("line {}: {line:?} is not numbers", i + 1))?;
            if v.iter().any(|x| !x.is_finite()) {
                return Err(format!("line {}: non-finite number", i + 1));
            }
            match v.len() {
                5 => {
                    color.push((v[0], [v[1], v[2], v[3]]));
                    opacity.push((v[0], v[4]));
                }
                4 => color.push((v[0], [v[1], v[2], v[3]])),
                2 => opacity.push((v[0], v[1])),
                n => return Err(format!("line {}: {n} numbers (want `x r g b a`, `x r g b` or `x a`)", i + 1)),
            }
            if color.len() + opacity.len() > 100_000 {
                return Err("too many control points".into());
            }
        }
        if color.is_empty() && opacity.is_empty() {
            return Err("no control points".into());
        }
        if !normalized {
            let norm = Self::normalizer(value_range);
            color.iter_mut().for_each(|p| p.0 = norm(p.0));
            opacity.iter_mut().for_each(|p| p.0 = norm(p.0));
        }
        Ok(TransferFunction::from_points(name, &color, &opacity))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_interpolate_and_clamp() {
        let tf = TransferFunction::from_points(
            "t",
            &[(0.0, [0.0, 0.0, 0.0]), (1.0, [1.0, 0.5, 0.0])],
            &[(0.5, 0.0), (1.0, 1.0)],
        );
        assert_eq!(tf.lookup(0.0), [0.0, 0.0, 0.0, 0.0]);
        assert_eq!(tf.lookup(1.0), [1.0, 0.5, 0.0, 1.0]);
        assert_eq!(tf.lookup(0.25)[3], 0.0);
        assert!((tf.lookup(0.75)[3] - 0.5).abs() < 2e-3);
        assert_eq!(tf.lookup(f32::NAN)[3], 0.0);
        assert_eq!(tf.max_opacity(0.0, 0.49), 0.0);
        assert!(tf.max_opacity(0.0, 0.6) > 0.0);
    }

    #[test]
    fn the_synth_preset_keeps_its_look_at_every_size() {
        let at = |n: u32| TransferFunction::preset_for("synth", [n; 3]);
        let same = |a: &TransferFunction, b: &TransferFunction| {
            a.table().iter().zip(b.table()).all(|(x, y)| x.iter().zip(y).all(|(u, v)| (u - v).abs() < 1e-6))
        };
        assert!(same(&at(1024), &TransferFunction::preset("synth")));
        assert_eq!(TransferFunction::preset_for("mri_colin27", [64; 3]), TransferFunction::preset("mri_colin27"));
        let (small, big) = (at(128), at(2048));
        // Transparent stays transparent (empty-space skipping); elsewhere the transmittance of
        // a path through the whole volume is the same.
        assert_eq!(small.max_opacity(0.0, 0.1), 0.0);
        assert_eq!(big.max_opacity(0.0, 0.1), 0.0);
        for x in [0.3f32, 0.5, 0.6, 0.7] {
            let t = |tf: &TransferFunction, n: f32| (1.0 - tf.lookup(x)[3]).powf(n);
            assert!(small.lookup(x)[3] > big.lookup(x)[3], "{x}");
            assert!((t(&small, 128.0) - t(&big, 2048.0)).abs() < 1e-3, "{x}");
        }
    }

    #[test]
    fn text_and_json_formats() {
        let t = TransferFunction::parse_text("t", "# c\n0 0 0 0 0\n100 1 1 1 1\n", (0.0, 200.0)).unwrap();
        assert!((t.lookup(0.5)[3] - 1.0).abs() < 1e-6);
        assert!((t.lookup(0.25)[3] - 0.5).abs() < 2e-3);
        let n = TransferFunction::parse_text("t", "normalized\n0 0\n1 1\n", (0.0, 200.0)).unwrap();
        assert!((n.lookup(0.5)[3] - 0.5).abs() < 2e-3);
        assert!(TransferFunction::parse_text("t", "1 2 3\n", (0.0, 1.0)).is_err());
        assert!(TransferFunction::parse_text("t", "", (0.0, 1.0)).is_err());
        assert!(TransferFunction::parse_text("t", "0 nan\n", (0.0, 1.0)).is_err());
        let j = r#"[{"Name":"x","RGBPoints":[0,1,0,0, 255,0,0,1],"Points":[0,0,0.5,0, 255,1,0.5,0]}]"#;
        let j = TransferFunction::parse_paraview_json("t", j, (0.0, 255.0)).unwrap();
        assert_eq!(j.name, "x");
        assert_eq!(j.lookup(1.0), [0.0, 0.0, 1.0, 1.0]);
        assert!(TransferFunction::parse_paraview_json("t", "{}", (0.0, 1.0)).is_err());
        assert!(TransferFunction::parse_paraview_json("t", r#"{"RGBPoints":[1,2]}"#, (0.0, 1.0)).is_err());
        assert!(TransferFunction::parse_paraview_json("t", "nope", (0.0, 1.0)).is_err());
    }
}
