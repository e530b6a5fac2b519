//! The visual state: what of the volume is visible and how it is lit, as one value the marcher
//! applies ([`crate::Marcher::with_visual`]): shading on or off, the transfer function (a bundled
//! preset or the one loaded at start), window/level and a global opacity scale over it, a crop
//! box and one clip plane.
//!
//! - **Window/level** are fractions of the volume's value range: the transfer function's whole
//!   domain (`0..=1` of the range) is laid over `[level − window/2, level + window/2]`; values
//!   below and above take its end entries. `1,0.5` (the default) leaves it as it is.
//! - **Opacity scale** multiplies every opacity of the function (clamped to 1) before the
//!   marcher's step correction.
//! - **Crop box** `X0,Y0,Z0,X1,Y1,Z1` in fractions of the volume box (`0,0,0,1,1,1`: the whole
//!   volume); see [`Cut`] for how samples are clamped to it.
//! - **Clip plane** `PX,PY,PZ,NX,NY,NZ`: a point in fractions of the volume box and a normal in
//!   volume coordinates; the half-space the normal points into is kept.
//!
//! The presets ([`PRESETS`]) are ParaView JSON files bundled from `data/presets/` (provenance in
//! `data/README.md`), their points in fractions of the value range (`"Normalized": true`, which
//! ParaView ignores); `--tf data/presets/NAME.json` loads the same function.

use crate::march_settings::Cut;
use crate::transfer_function::{TransferFunction, LUT_SIZE};
use crate::volume::Volume;
use std::fmt;
use volwarp_core::wire::{self, TfPoints, VisualEdit};
use volwarp_core::Vec3;

/// The bundled presets: name, ParaView JSON, and whether shading is on by default with it.
pub const PRESETS: [(&str, &str, bool); 5] = [
    ("grey", include_str!("../../data/presets/grey.json"), false),
    ("ct-bone", include_str!("../../data/presets/ct-bone.json"), true),
    ("ct-soft-tissue", include_str!("../../data/presets/ct-soft-tissue.json"), true),
    ("mr-default", include_str!("../../data/presets/mr-default.json"), true),
    ("cool-warm", include_str!("../../data/presets/cool-warm.json"), false),
];

/// The preset names, in [`PRESETS`] order.
pub fn preset_names() -> impl Iterator<Item = &'static str> {
    PRESETS.iter().map(|p| p.0)
}

/// A bad visual state: what is wrong, in words.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct VisualError(pub String);

impl fmt::Display for VisualError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for VisualError {}

fn err<T>(msg: impl Into<String>) -> Result<T, VisualError> {
    Err(VisualError(msg.into()))
}

/// The largest opacity scale accepted.
pub const MAX_OPACITY_SCALE: f32 = 100.0;
/// The smallest window accepted (a fraction of the value range).
pub const MIN_WINDOW: f32 = 1e-3;

/// What is visible and how it is lit (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct VisualState {
    /// Gradient shading ([`crate::march_settings::Shading::DEFAULT`]).
    pub shade: bool,
    /// A bundled preset by name; `None`: the transfer function given at start.
    pub preset: Option<String>,
    /// Window: the width of the value range the transfer function spans, a fraction of the
    /// volume's value range, in `[MIN_WINDOW, 100]`.
    pub window: f32,
    /// Level: the centre of that span, a fraction of the value range, in `[-10, 10]`.
    pub level: f32,
    /// Every opacity times this, in `[0, MAX_OPACITY_SCALE]`.
    pub opacity_scale: f32,
    /// Crop box `[x0, y0, z0, x1, y1, z1]` in fractions of the volume box, `0 ≤ low < high ≤ 1`.
    pub crop: [f32; 6],
    /// Clip plane `[px, py, pz, nx, ny, nz]`: point in fractions of the box (each in
    /// `[-1, 2]`), normal (not zero) in volume coordinates; `None`: no plane.
    pub clip: Option<[f32; 6]>,
    /// A transfer function sent by a client (ParaView-style points over fractions of the value
    /// range), shown instead of the preset or the one given at start.
    pub points: Option<TfPoints>,
}

impl Default for VisualState {
    fn default() -> Self {
        VisualState {
            shade: false,
            preset: None,
            window: 1.0,
            level: 0.5,
            opacity_scale: 1.0,
            crop: [0.0, 0.0, 0.0, 1.0, 1.0, 1.0],
            clip: None,
            points: None,
        }
    }
}

impl VisualState {
    /// A clear error for the first bad value (non-finite, out of range, an empty crop box, a
    /// zero clip normal, an unknown preset).
    pub fn validate(&self) -> Result<(), VisualError> {
        if let Some(p) = &self.preset {
            if !preset_names().any(|n| n == p) {
                return err(format!("unknown preset {p:?}; one of {}", preset_names().collect::<Vec<_>>().join(", ")));
            }
        }
        if !(self.window.is_finite() && (MIN_WINDOW..=100.0).contains(&self.window)) {
            return err(format!(
                "window {} is not in [{MIN_WINDOW}, 100] (a fraction of the value range)",
                self.window
            ));
        }
        if !(self.level.is_finite() && (-10.0..=10.0).contains(&self.level)) {
            return err(format!("level {} is not in [-10, 10] (a fraction of the value range)", self.level));
        }
        if !(self.opacity_scale.is_finite() && (0.0..=MAX_OPACITY_SCALE).contains(&self.opacity_scale)) {
            return err(format!("opacity scale {} is not in [0, {MAX_OPACITY_SCALE}]", self.opacity_scale));
        }
        let c = self.crop;
        if c.iter().any(|v| !v.is_finite()) {
            return err(format!("crop box {c:?} holds a non-finite number"));
        }
        for a in 0..3 {
            if !(0.0 <= c[a] && c[a] < c[a + 3] && c[a + 3] <= 1.0) {
                return err(format!(
                    "crop box {c:?} is not inside the volume: each axis needs 0 <= low < high <= 1 (fractions of the box)"
                ));
            }
        }
        if let Some(p) = self.clip {
            if p.iter().any(|v| !v.is_finite()) {
                return err(format!("clip plane {p:?} holds a non-finite number"));
            }
            if p[..3].iter().any(|v| !(-1.0..=2.0).contains(v)) {
                return err(format!("clip plane point {:?} is not in [-1, 2] (fractions of the box)", &p[..3]));
            }
            if Vec3::new(p[3], p[4], p[5]).length_squared() < 1e-12 {
                return err("clip plane normal is zero");
            }
        }
        if let Some(t) = &self.points {
            validate_points(t)?;
        }
        Ok(())
    }

    /// This state with `edit` applied, checked ([`VisualState::validate`]): a preset replaces a
    /// custom function and brings its shading default unless the edit sets shading; a custom
    /// function replaces the preset.
    pub fn apply(&self, edit: &VisualEdit) -> Result<VisualState, VisualError> {
        let mut s = self.clone();
        if let Some(p) = &edit.preset {
            s = s.with_preset(Some(p.as_str().to_string()), edit.shade);
            s.points = None;
        }
        if let Some(shade) = edit.shade {
            s.shade = shade;
        }
        if let Some([w, l]) = edit.window_level {
            (s.window, s.level) = (w, l);
        }
        if let Some(o) = edit.opacity_scale {
            s.opacity_scale = o;
        }
        if let Some(c) = edit.crop {
            s.crop = c;
        }
        if let Some(c) = edit.clip {
            s.clip = c;
        }
        if let Some(t) = &edit.transfer_function {
            s.points = Some(t.clone());
            s.preset = None;
        }
        s.validate()?;
        Ok(s)
    }

    /// Whether `other` shows the same transfer function (preset or points, window, level,
    /// opacity scale): then only the shading and the cut differ, and the tables can be kept.
    pub fn same_function(&self, other: &VisualState) -> bool {
        self.preset == other.preset
            && self.points == other.points
            && self.window == other.window
            && self.level == other.level
            && self.opacity_scale == other.opacity_scale
    }

    /// The state as the wire's VisualState message of edit `id`, listing the bundled presets.
    pub fn to_wire(&self, id: u32) -> wire::VisualState {
        let mut presets = wire::PresetNames::new();
        for n in preset_names() {
            let _ = presets.push(wire::preset_name(n).unwrap_or_default());
        }
        wire::VisualState {
            id,
            shade: self.shade,
            preset: self.preset.as_deref().and_then(wire::preset_name).unwrap_or_default(),
            custom: self.points.is_some(),
            window_level: [self.window, self.level],
            opacity_scale: self.opacity_scale,
            crop: self.crop,
            clip: self.clip,
            presets,
        }
    }

    /// The state with `preset`'s shading default (shading on for the CT and MR presets) unless
    /// `shade` says otherwise.
    pub fn with_preset(mut self, preset: Option<String>, shade: Option<bool>) -> VisualState {
        let preset_shades = preset.as_deref().and_then(|p| PRESETS.iter().find(|e| e.0 == p)).is_some_and(|e| e.2);
        self.shade = shade.unwrap_or(preset_shades);
        self.preset = preset;
        self
    }

    /// The transfer function this state shows: `base` (the one given at start) or the preset,
    /// windowed and opacity-scaled.
    pub fn transfer_function(
        &self,
        base: &TransferFunction,
        value_range: (f32, f32),
    ) -> Result<TransferFunction, VisualError> {
        self.validate()?;
        let tf = match (&self.points, &self.preset) {
            (Some(t), _) => {
                let color: Vec<(f32, [f32; 3])> = t.color.iter().map(|p| (p[0], [p[1], p[2], p[3]])).collect();
                let opacity: Vec<(f32, f32)> = t.opacity.iter().map(|p| (p[0], p[1])).collect();
                TransferFunction::from_points("custom", &color, &opacity)
            }
            (None, Some(p)) => preset(p, value_range)?,
            (None, None) => base.clone(),
        };
        Ok(tf.windowed(self.window, self.level, self.opacity_scale))
    }

    /// The crop box and clip plane in world units for `volume`.
    pub fn cut(&self, volume: &Volume) -> Cut {
        let ext = volume.extent();
        let c = self.crop;
        let lo = Vec3::new(c[0], c[1], c[2]) * ext;
        let hi = Vec3::new(c[3], c[4], c[5]) * ext;
        let plane = self.clip.map(|p| (Vec3::new(p[0], p[1], p[2]) * ext, Vec3::new(p[3], p[4], p[5]).normalize()));
        Cut::new(lo, hi, plane)
    }
}

/// Checks a client's transfer function: 1 to [`wire::MAX_TF_POINTS`] points of each kind, `x`
/// finite, in `[0, 1]` and non-decreasing (ParaView's order; equal `x` make a step), colors and
/// opacities in `[0, 1]`.
pub fn validate_points(t: &TfPoints) -> Result<(), VisualError> {
    if t.color.is_empty() || t.opacity.is_empty() {
        return err("a transfer function needs at least one color point and one opacity point");
    }
    let check = |what: &str, pts: &mut dyn Iterator<Item = &[f32]>| -> Result<(), VisualError> {
        let mut last = f32::NEG_INFINITY;
        for (i, p) in pts.enumerate() {
            if p.iter().any(|v| !v.is_finite()) {
                return err(format!("{what} point {i} holds a non-finite number"));
            }
            if !(0.0..=1.0).contains(&p[0]) {
                return err(format!("{what} point {i}: x {} is not in [0, 1] (a fraction of the value range)", p[0]));
            }
            if p[0] < last {
                return err(format!("{what} points are not sorted: point {i} at x {} comes after x {last}", p[0]));
            }
            if p[1..].iter().any(|v| !(0.0..=1.0).contains(v)) {
                return err(format!("{what} point {i}: {:?} is not in [0, 1]", &p[1..]));
            }
            last = p[0];
        }
        Ok(())
    };
    check("color", &mut t.color.iter().map(|p| &p[..]))?;
    check("opacity", &mut t.opacity.iter().map(|p| &p[..]))
}

/// A bundled preset's transfer function (points in fractions of `value_range`).
pub fn preset(name: &str, value_range: (f32, f32)) -> Result<TransferFunction, VisualError> {
    let Some((_, json, _)) = PRESETS.iter().find(|p| p.0 == name) else {
        return err(format!("unknown preset {name:?}; one of {}", preset_names().collect::<Vec<_>>().join(", ")));
    };
    TransferFunction::parse_paraview_json(name, json, value_range)
        .map_err(|e| VisualError(format!("preset {name}: {e}")))
}

/// Parses `N` comma-separated finite numbers (`what` names the flag in the error).
pub fn parse_numbers<const N: usize>(s: &str, what: &str) -> Result<[f32; N], VisualError> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|_| VisualError(format!("{what} {s:?} is not {N} comma-separated numbers")))?;
    let a: [f32; N] =
        v.try_into().map_err(|v: Vec<f32>| VisualError(format!("{what} {s:?} has {} numbers, not {N}", v.len())))?;
    if a.iter().any(|x| !x.is_finite()) {
        return err(format!("{what} {s:?} holds a non-finite number"));
    }
    Ok(a)
}

impl TransferFunction {
    /// The function laid over `[level − window/2, level + window/2]` of the normalized range
    /// (entries read by linear interpolation of this table, ends held) with every opacity times
    /// `opacity_scale` (clamped to 1). `(1, 0.5, 1)` gives this function's table exactly.
    pub fn windowed(&self, window: f32, level: f32, opacity_scale: f32) -> TransferFunction {
        let table = self.table();
        let last = (LUT_SIZE - 1) as f32;
        let lo = level - 0.5 * window;
        let identity = window == 1.0 && level == 0.5;
        let lut = (0..LUT_SIZE)
            .map(|i| {
                let mut e = if identity {
                    table[i]
                } else {
                    let x = ((i as f32 / last - lo) / window).clamp(0.0, 1.0) * last;
                    let j = (x as usize).min(LUT_SIZE - 2);
                    let f = x - j as f32;
                    let (a, b) = (table[j], table[j + 1]);
                    core::array::from_fn(|c| a[c] + (b[c] - a[c]) * f)
                };
                if opacity_scale != 1.0 {
                    e[3] = (e[3] * opacity_scale).clamp(0.0, 1.0);
                }
                e
            })
            .collect();
        TransferFunction::from_table(&self.name, lut)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_parse_and_differ() {
        let tfs: Vec<_> = preset_names().map(|n| preset(n, (0.0, 255.0)).unwrap()).collect();
        for (i, a) in tfs.iter().enumerate() {
            assert!(a.max_opacity(0.0, 1.0) > 0.0, "{}", a.name);
            for b in &tfs[i + 1..] {
                assert_ne!(a.table(), b.table(), "{} and {}", a.name, b.name);
            }
        }
        assert!(preset("bone", (0.0, 1.0)).unwrap_err().0.contains("ct-bone"));
    }

    #[test]
    fn window_level_moves_the_function() {
        let tf = TransferFunction::from_points("t", &[(0.0, [1.0, 1.0, 1.0])], &[(0.0, 0.0), (1.0, 1.0)]);
        assert_eq!(tf.windowed(1.0, 0.5, 1.0), tf);
        // Half the window around 0.25: the ramp spans 0..0.5.
        let w = tf.windowed(0.5, 0.25, 1.0);
        assert!((w.lookup(0.25)[3] - 0.5).abs() < 2e-3);
        assert_eq!(w.lookup(0.6)[3], 1.0);
        assert_eq!(w.lookup(0.0)[3], 0.0);
        let s = tf.windowed(1.0, 0.5, 0.5);
        assert!((s.lookup(1.0)[3] - 0.5).abs() < 1e-6);
        assert_eq!(tf.windowed(1.0, 0.5, 3.0).lookup(0.5)[3], 1.0);
    }

    #[test]
    fn bad_states_get_clear_errors() {
        let ok = VisualState::default();
        assert!(ok.validate().is_ok());
        let bad = |f: fn(&mut VisualState), want: &str| {
            let mut v = VisualState::default();
            f(&mut v);
            let e = v.validate().unwrap_err().0;
            assert!(e.contains(want), "{e:?} lacks {want:?}");
        };
        bad(|v| v.window = f32::NAN, "window");
        bad(|v| v.window = 0.0, "window");
        bad(|v| v.level = f32::INFINITY, "level");
        bad(|v| v.opacity_scale = -1.0, "opacity scale");
        bad(|v| v.crop = [0.0, 0.0, 0.0, 1.5, 1.0, 1.0], "not inside the volume");
        bad(|v| v.crop = [0.5, 0.0, 0.0, 0.5, 1.0, 1.0], "not inside the volume");
        bad(|v| v.crop[2] = f32::NAN, "non-finite");
        bad(|v| v.clip = Some([0.5, 0.5, 0.5, 0.0, 0.0, 0.0]), "normal is zero");
        bad(|v| v.clip = Some([0.5, 9.0, 0.5, 1.0, 0.0, 0.0]), "clip plane point");
        bad(|v| v.preset = Some("nope".into()), "unknown preset");
        assert!(parse_numbers::<2>("1,2,3", "--window-level").unwrap_err().0.contains("3 numbers"));
        assert!(parse_numbers::<2>("1,x", "--window-level").is_err());
        assert!(parse_numbers::<2>("1,inf", "--window-level").is_err());
        assert_eq!(parse_numbers::<2>(" 0.5, 0.25", "w").unwrap(), [0.5, 0.25]);
    }
}
