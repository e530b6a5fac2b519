//! The sphere radius of a sample: how large the server makes the sphere of each pixel.
//!
//! * [`RadiusModel::Voxel`] — the seed paper's: half a voxel diagonal, the same for every
//!   sample. Where a voxel covers several pixels (a volume smaller than the viewport) these
//!   spheres are several pixels wide, so neighbours occlude each other even without motion and
//!   a tracer wades through many overlapping spheres.
//! * [`RadiusModel::Footprint`] — the pixel's own footprint at the sample's depth: a sample
//!   stands for one pixel, so its sphere is `FOOTPRINT_FACTOR × z × pitch`, where `z` is the
//!   sample's distance along the view direction and `pitch` the width of a pixel at unit
//!   distance. The factor is √2: the sphere's radius is a pixel diagonal, so it reaches the
//!   centres of all eight neighbouring pixels. From the frame's own camera every pixel still
//!   sees its own sample almost everywhere, and the holes a turning camera opens between
//!   samples stay closed up to about 10°. `volwarp-eval radius` chose it (docs/results.md):
//!   over five datasets its mean FLIP against the truth is lower than the voxel model's at
//!   every angle up to 20°; a smaller footprint (one pixel) is slightly better up to 5° and
//!   worse beyond.
//! * [`RadiusModel::Uncertainty`] — "samples sized by what is known": the
//!   footprint radius × [`uncertainty_factor`], a factor ≥ 1 that grows with how unsure the
//!   ray is about *where* its color lies: the spread of the ray's color along it
//!   ([`RaySpread`]: the opacity-weighted standard deviation of the depths that contributed,
//!   or the distance from the entrance into visible material to the exit, [`SpreadMeasure`]),
//!   in pixels at the sample's depth, and optionally how transparent the ray stayed. An opaque
//!   surface (all the color at one depth) keeps exactly the footprint radius; the factor is
//!   capped at [`UncertaintyParams::max`], and the frame's radius unit grows by that cap so the
//!   largest radius still fits the 10-bit code. Layered frames size every segment by
//!   the footprint: a segment already says where its color lies.
//!
//! A request's `radius_scale` multiplies either. Both are encoded with the wire's per-sample
//! 10-bit radius code: the voxel model spends a fixed code ([`crate::marcher::RADIUS_CODE`]),
//! the footprint model a unit that gives the farthest corner of the volume box the largest code.

use core::fmt;
use core::str::FromStr;
use volwarp_core::sample::RADIUS_MAX;
use volwarp_core::{Bounds, Camera, Vec3};

/// The footprint radius in pixel pitches at the sample's depth: a pixel diagonal (see the module
/// docs).
pub const FOOTPRINT_FACTOR: f32 = core::f32::consts::SQRT_2;

/// How the server sizes each sample's sphere (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum RadiusModel {
    /// Half a voxel diagonal for every sample (the seed paper's).
    Voxel,
    /// A pixel diagonal at the sample's depth.
    #[default]
    Footprint,
    /// The footprint grown by the ray's depth uncertainty ([`uncertainty_factor`]).
    Uncertainty,
}

impl RadiusModel {
    /// Every model.
    pub const ALL: [RadiusModel; 3] = [RadiusModel::Voxel, RadiusModel::Footprint, RadiusModel::Uncertainty];

    /// The model's name on the command line and in CSV files.
    pub fn name(self) -> &'static str {
        match self {
            RadiusModel::Voxel => "voxel",
            RadiusModel::Footprint => "footprint",
            RadiusModel::Uncertainty => "uncertainty",
        }
    }
}

impl fmt::Display for RadiusModel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for RadiusModel {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        RadiusModel::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| format!("unknown radius model {s:?}; one of voxel, footprint, uncertainty"))
    }
}

/// What the march of one ray says about where its color lies: the input of
/// [`uncertainty_factor`] (see [`RaySpread`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Uncertainty {
    /// Standard deviation of the depths `t` of the ray's visible samples, each weighted by its
    /// contribution to the accumulated opacity (world units; 0 for a single sample).
    pub sigma: f32,
    /// Distance along the ray from the first visible sample (the entrance into visible
    /// material) to the last one composited (the exit, or where early termination stopped).
    pub span: f32,
    /// The ray's final accumulated opacity.
    pub alpha: f32,
}

/// Collects a ray's [`Uncertainty`] from the samples the marcher composites, fed front to back
/// as the depth heuristics are: the ray parameter `t` and the accumulated opacity `dst_a`
/// after the sample. Both marchers (scalar and packet) feed it the same values in the same
/// order, so their results are equal bit for bit.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RaySpread {
    entrance: f32,
    exit: f32,
    prev_a: f32,
    /// Sums of `w`, `w·x`, `w·x²` with `x = t − entrance` (shifted for precision) and `w` the
    /// sample's step of accumulated opacity.
    s0: f32,
    s1: f32,
    s2: f32,
    seen: bool,
}

impl RaySpread {
    /// An empty ray.
    pub fn new() -> RaySpread {
        RaySpread::default()
    }

    /// Feeds one composited sample (`src_a > 0`): its `t` and the accumulated opacity after it.
    #[inline]
    pub fn feed(&mut self, t: f32, dst_a: f32) {
        if !self.seen {
            self.seen = true;
            self.entrance = t;
        }
        self.exit = t;
        let w = dst_a - self.prev_a;
        self.prev_a = dst_a;
        let x = t - self.entrance;
        self.s0 += w;
        self.s1 += w * x;
        self.s2 += w * x * x;
    }

    /// The ray's uncertainty (all zero for an empty ray; never NaN for finite input).
    pub fn finish(&self) -> Uncertainty {
        if !self.seen {
            return Uncertainty::default();
        }
        let sigma = if self.s0 > 0.0 {
            let mean = self.s1 / self.s0;
            let var = self.s2 / self.s0 - mean * mean;
            if var > 0.0 {
                var.sqrt()
            } else {
                0.0
            }
        } else {
            0.0
        };
        Uncertainty { sigma, span: (self.exit - self.entrance).max(0.0), alpha: self.prev_a }
    }
}

/// Which spread [`uncertainty_factor`] grows the radius by.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum SpreadMeasure {
    /// [`Uncertainty::sigma`]: the opacity-weighted standard deviation of the depths.
    #[default]
    Sigma,
    /// [`Uncertainty::span`]: entrance to exit of the visible material.
    Span,
}

/// The constants of [`uncertainty_factor`]. Written `gain=G:max=M:opacity=O:measure=sigma|span`
/// (any subset, `:`-separated; a gain not given is 0, `max` 2 and the measure `sigma`; the
/// empty string is [`UncertaintyParams::DEFAULT`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UncertaintyParams {
    /// Which spread counts.
    pub measure: SpreadMeasure,
    /// Factor added per pixel of spread at the sample's depth.
    pub gain: f32,
    /// Factor added at zero final opacity (times `1 − alpha`).
    pub opacity_gain: f32,
    /// The largest factor (1 to 16).
    pub max: f32,
}

impl Default for UncertaintyParams {
    fn default() -> Self {
        UncertaintyParams::DEFAULT
    }
}

impl UncertaintyParams {
    /// The constants `--radius uncertainty` uses: the least harmful of the variants measured
    /// (`docs/results.md`, "Samples sized by their spread along the ray": growing by the spread along the ray
    /// lost to the footprint at every gain, so only the opacity term is on; the footprint
    /// model stays the default).
    pub const DEFAULT: UncertaintyParams =
        UncertaintyParams { measure: SpreadMeasure::Sigma, gain: 0.0, opacity_gain: 1.0, max: 2.0 };

    /// The parameters with gains made finite and non-negative and `max` in `1..=16`.
    pub fn sanitized(self) -> UncertaintyParams {
        let gain = |g: f32| if g.is_finite() && g > 0.0 { g } else { 0.0 };
        let max = if self.max.is_finite() { self.max.clamp(1.0, 16.0) } else { 1.0 };
        UncertaintyParams { measure: self.measure, gain: gain(self.gain), opacity_gain: gain(self.opacity_gain), max }
    }
}

impl fmt::Display for UncertaintyParams {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let m = match self.measure {
            SpreadMeasure::Sigma => "sigma",
            SpreadMeasure::Span => "span",
        };
        write!(f, "gain={}:max={}:opacity={}:measure={m}", self.gain, self.max, self.opacity_gain)
    }
}

impl FromStr for UncertaintyParams {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s.is_empty() {
            return Ok(UncertaintyParams::DEFAULT);
        }
        let mut p = UncertaintyParams { measure: SpreadMeasure::Sigma, gain: 0.0, opacity_gain: 0.0, max: 2.0 };
        for part in s.split(':').filter(|x| !x.is_empty()) {
            let (k, v) =
                part.split_once('=').ok_or_else(|| format!("uncertainty parameter {part:?}: want KEY=VALUE"))?;
            let num = || v.parse::<f32>().map_err(|e| format!("uncertainty parameter {k}: {e}"));
            match k {
                "gain" => p.gain = num()?,
                "max" => p.max = num()?,
                "opacity" => p.opacity_gain = num()?,
                "measure" => {
                    p.measure = match v {
                        "sigma" => SpreadMeasure::Sigma,
                        "span" => SpreadMeasure::Span,
                        _ => return Err(format!("uncertainty measure {v:?}; sigma or span")),
                    }
                }
                _ => return Err(format!("unknown uncertainty parameter {k:?}; gain, max, opacity, measure")),
            }
        }
        let clean = p.sanitized();
        if clean != p {
            return Err(format!("uncertainty parameters out of range: {s:?} (gains ≥ 0, max in 1..=16)"));
        }
        Ok(p)
    }
}

/// A radius model with its uncertainty constants, as the evaluation's `--radius` takes it:
/// `voxel`, `footprint`, `uncertainty` or `uncertainty:PARAMS` ([`UncertaintyParams`]'s form).
pub fn parse_spec(s: &str) -> Result<(RadiusModel, UncertaintyParams), String> {
    match s.split_once(':') {
        Some(("uncertainty", params)) => Ok((RadiusModel::Uncertainty, params.parse()?)),
        Some(_) => Err(format!("radius spec {s:?}: only `uncertainty` takes parameters")),
        None => Ok((s.parse()?, UncertaintyParams::DEFAULT)),
    }
}

/// How much larger than its footprint a sample's sphere is: `1 + gain × spread / pixel +
/// opacity_gain × (1 − alpha)`, clamped to `1..=max`, where `spread` is the ray's
/// [`SpreadMeasure`] and `pixel` the width of a pixel at the sample's depth (both world units).
/// A ray whose color sits at one depth and that is opaque gets exactly 1. Never NaN: a NaN
/// input gives 1, a zero `pixel` with any spread the cap.
///
/// Why it should help: warped by `θ`, color spread along the ray over `spread` lands over
/// `spread · sin θ` on screen, which one sample at one depth cannot show; a larger sphere
/// covers part of that smear (and occludes more of its neighbours, hence the cap).
#[inline]
pub fn uncertainty_factor(u: &Uncertainty, pixel: f32, p: &UncertaintyParams) -> f32 {
    let spread = match p.measure {
        SpreadMeasure::Sigma => u.sigma,
        SpreadMeasure::Span => u.span,
    };
    let grow = if spread > 0.0 && p.gain > 0.0 { p.gain * (spread / pixel) } else { 0.0 };
    let faint = p.opacity_gain * (1.0 - u.alpha).clamp(0.0, 1.0);
    let f = 1.0 + grow + faint;
    if f.is_nan() {
        1.0
    } else {
        f.clamp(1.0, p.max.max(1.0))
    }
}

/// The radius of every sample of one frame: `constant + per_depth × z` with `z = t · (d · w)`
/// for the sample at `o + d·t` (`w` the camera's unit view direction), and the frame's radius
/// unit (the step of the 10-bit code).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameRadius {
    constant: f32,
    per_depth: f32,
    forward: Vec3,
    unit: f32,
    /// Width of a pixel per unit of view depth (0 for the voxel model).
    pitch: f32,
    /// The uncertainty model's constants (`None` for the other models).
    uncertainty: Option<UncertaintyParams>,
}

impl FrameRadius {
    /// The radius of `model` × `scale` for `camera`'s frame of a volume with box `bounds` and
    /// voxel radius `voxel_radius` (half a voxel diagonal). `voxel_code` is the code the voxel
    /// model gives a radius of `voxel_radius × scale`.
    pub fn new(
        model: RadiusModel,
        scale: f32,
        camera: &Camera,
        bounds: &Bounds,
        voxel_radius: f32,
        voxel_code: f32,
    ) -> FrameRadius {
        FrameRadius::with_params(model, UncertaintyParams::DEFAULT, scale, camera, bounds, voxel_radius, voxel_code)
    }

    /// [`FrameRadius::new`] with the uncertainty model's constants (ignored by the other
    /// models): its unit is the footprint's × `params.max`, so the largest radius still fits.
    pub fn with_params(
        model: RadiusModel,
        params: UncertaintyParams,
        scale: f32,
        camera: &Camera,
        bounds: &Bounds,
        voxel_radius: f32,
        voxel_code: f32,
    ) -> FrameRadius {
        let voxel = |scale: f32| {
            let r = voxel_radius * scale;
            FrameRadius {
                constant: r,
                per_depth: 0.0,
                forward: Vec3::ZERO,
                unit: r / voxel_code,
                pitch: 0.0,
                uncertainty: None,
            }
        };
        match model {
            RadiusModel::Voxel => voxel(scale),
            RadiusModel::Footprint | RadiusModel::Uncertainty => {
                let (_, _, w) = camera.basis();
                let b = camera.ray_basis();
                let len = |v: [f32; 4]| Vec3::new(v[0], v[1], v[2]).length();
                let pitch = len(b.du).max(len(b.dv));
                let per_depth = FOOTPRINT_FACTOR * pitch * scale;
                let (lo, hi) = (bounds.min(), bounds.max());
                let z_max = (0..8)
                    .map(|i| {
                        let c = Vec3::new(
                            if i & 1 == 0 { lo.x } else { hi.x },
                            if i & 2 == 0 { lo.y } else { hi.y },
                            if i & 4 == 0 { lo.z } else { hi.z },
                        );
                        (c - camera.eye).dot(w)
                    })
                    .fold(0.0f32, f32::max);
                let uncertainty = (model == RadiusModel::Uncertainty).then(|| params.sanitized());
                let cap = uncertainty.map_or(1.0, |p| p.max);
                let unit = per_depth * z_max * cap / RADIUS_MAX as f32;
                if unit > 0.0 && unit.is_finite() && w.is_finite() {
                    FrameRadius { constant: 0.0, per_depth, forward: w, unit, pitch, uncertainty }
                } else {
                    // The box lies behind the eye or the camera is degenerate: no sample can
                    // be placed anyway; keep a valid unit.
                    voxel(scale)
                }
            }
        }
    }

    /// The radius of the sample at `o + d·t` (unit `d`).
    #[inline(always)]
    pub fn at(&self, d: Vec3, t: f32) -> f32 {
        self.constant + self.per_depth * (t * d.dot(self.forward))
    }

    /// The radius of the sample at `o + d·t` of a ray whose march gave `u`: [`FrameRadius::at`]
    /// × [`uncertainty_factor`] under the uncertainty model, [`FrameRadius::at`] otherwise.
    #[inline]
    pub fn at_ray(&self, d: Vec3, t: f32, u: &Uncertainty) -> f32 {
        let r = self.at(d, t);
        match &self.uncertainty {
            None => r,
            Some(p) => r * uncertainty_factor(u, self.pitch * (t * d.dot(self.forward)), p),
        }
    }

    /// Whether the radius depends on the ray's [`Uncertainty`] (the marcher then collects it).
    pub fn uses_spread(&self) -> bool {
        self.uncertainty.is_some()
    }

    /// World size of one step of the radius code.
    pub fn unit(&self) -> f32 {
        self.unit
    }

    /// The radius at depth 0 (the voxel model's radius; 0 for the footprint model).
    pub fn constant(&self) -> f32 {
        self.constant
    }

    /// The radius per unit of depth along the view direction (0 for the voxel model).
    pub fn per_depth(&self) -> f32 {
        self.per_depth
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use volwarp_core::sample::{radius_code, Dequantizer, Quantizer};

    fn cam() -> Camera {
        Camera::look_at(Vec3::new(0.5, 0.5, 3.0), Vec3::splat(0.5), Vec3::Y, 30.0, 200, 100)
    }

    fn unit_box() -> Bounds {
        Bounds::new(Vec3::ZERO, Vec3::ONE)
    }

    #[test]
    fn names_round_trip() {
        for m in RadiusModel::ALL {
            assert_eq!(m.name().parse::<RadiusModel>(), Ok(m));
        }
        assert!("pixel".parse::<RadiusModel>().is_err());
        assert_eq!(RadiusModel::default(), RadiusModel::Footprint);
    }

    #[test]
    fn ray_spread_is_the_weighted_deviation_of_the_depths() {
        assert_eq!(RaySpread::new().finish(), Uncertainty::default());
        // One opaque sample: no spread.
        let mut one = RaySpread::new();
        one.feed(3.0, 1.0);
        assert_eq!(one.finish(), Uncertainty { sigma: 0.0, span: 0.0, alpha: 1.0 });
        // Two equal contributions (0.4 each) at t = 1 and t = 3: mean 2, deviation 1.
        let mut two = RaySpread::new();
        two.feed(1.0, 0.4);
        two.feed(3.0, 0.8);
        let u = two.finish();
        assert!((u.sigma - 1.0).abs() < 1e-6, "{u:?}");
        assert_eq!((u.span, u.alpha), (2.0, 0.8));
        // A faint tail far behind barely moves sigma but stretches the span.
        let mut tail = two;
        tail.feed(50.0, 0.801);
        let v = tail.finish();
        assert!(v.sigma < 2.0 && v.span == 49.0, "{v:?}");
    }

    #[test]
    fn uncertainty_factor_grows_with_spread_in_pixels_and_is_capped() {
        let p = UncertaintyParams { gain: 0.1, max: 3.0, ..UncertaintyParams::DEFAULT };
        let u = |sigma: f32| Uncertainty { sigma, span: 2.0 * sigma, alpha: 1.0 };
        assert_eq!(uncertainty_factor(&u(0.0), 0.01, &p), 1.0);
        assert!((uncertainty_factor(&u(0.1), 0.01, &p) - 2.0).abs() < 1e-5);
        assert!((uncertainty_factor(&u(0.1), 0.02, &p) - 1.5).abs() < 1e-5);
        assert_eq!(uncertainty_factor(&u(10.0), 0.01, &p), 3.0);
        assert_eq!(uncertainty_factor(&u(f32::NAN), 0.01, &p), 1.0);
        let faint = Uncertainty { sigma: 0.0, span: 0.0, alpha: 0.25 };
        let o = UncertaintyParams { opacity_gain: 1.0, ..p };
        assert!((uncertainty_factor(&faint, 0.01, &o) - 1.75).abs() < 1e-6);
    }

    #[test]
    fn uncertainty_params_parse_and_print() {
        assert_eq!("".parse::<UncertaintyParams>(), Ok(UncertaintyParams::DEFAULT));
        let p: UncertaintyParams = "gain=0.2:max=4:opacity=0.5:measure=span".parse().unwrap();
        assert_eq!(p, UncertaintyParams { measure: SpreadMeasure::Span, gain: 0.2, opacity_gain: 0.5, max: 4.0 });
        assert_eq!(p.to_string().parse::<UncertaintyParams>(), Ok(p));
        for bad in ["gain", "gain=x", "max=0.5", "max=17", "gain=-1", "size=2", "measure=mean", "gain=inf"] {
            assert!(bad.parse::<UncertaintyParams>().is_err(), "{bad}");
        }
        assert_eq!(parse_spec("footprint"), Ok((RadiusModel::Footprint, UncertaintyParams::DEFAULT)));
        let three = parse_spec("uncertainty:max=3").map(|(m, p)| (m, p.max, p.gain, p.opacity_gain));
        assert_eq!(three, Ok((RadiusModel::Uncertainty, 3.0, 0.0, 0.0)));
        assert!(parse_spec("voxel:gain=1").is_err());
        assert!(parse_spec("nope").is_err());
    }

    #[test]
    fn voxel_radius_is_constant() {
        let r = FrameRadius::new(RadiusModel::Voxel, 2.0, &cam(), &unit_box(), 0.01, 512.0);
        assert_eq!(r.at(Vec3::Z, 1.0), 0.02);
        assert_eq!(r.at(Vec3::X, 7.0), 0.02);
        assert_eq!(r.unit(), 0.02 / 512.0);
    }

    #[test]
    fn footprint_is_half_a_pixel_diagonal_at_the_sample_depth() {
        let c = cam();
        let r = FrameRadius::new(RadiusModel::Footprint, 1.0, &c, &unit_box(), 0.01, 512.0);
        // Pixel (100, 50) at distance 2.5: project the neighbouring pixel's ray to the same
        // depth; their distance is one pixel pitch at that depth.
        let b = c.ray_basis();
        let (d0, d1) = (b.dir(100, 50), b.dir(101, 50));
        let (_, _, w) = c.basis();
        let z = 2.5f32;
        let p0 = c.eye + d0 * (z / d0.dot(w));
        let p1 = c.eye + d1 * (z / d1.dot(w));
        let pitch = (p1 - p0).length();
        let got = r.at(d0, z / d0.dot(w));
        assert!((got - FOOTPRINT_FACTOR * pitch).abs() < 1e-4 * pitch, "{got} vs {}", FOOTPRINT_FACTOR * pitch);
        // Twice as far, twice as large; the scale multiplies.
        assert!((r.at(d0, 2.0 * z / d0.dot(w)) - 2.0 * got).abs() < 1e-5);
        let r2 = FrameRadius::new(RadiusModel::Footprint, 0.5, &c, &unit_box(), 0.01, 512.0);
        assert!((r2.at(d0, z / d0.dot(w)) - 0.5 * got).abs() < 1e-6);
    }

    #[test]
    fn footprint_codes_fit_the_box() {
        // Every sample inside the box gets a code within the 10-bit range, the farthest one
        // close to the top, and the decoded radius is within half a code step.
        let c = cam();
        let bounds = unit_box();
        let r = FrameRadius::new(RadiusModel::Footprint, 1.0, &c, &bounds, 0.01, 512.0);
        let q = Quantizer::new(bounds, r.unit());
        let deq = Dequantizer::new(bounds, r.unit());
        let mut top = 0;
        for i in 0..27 {
            // Points on a 3×3×3 grid of the box, corners included.
            let p = Vec3::new((i % 3) as f32, (i / 3 % 3) as f32, (i / 9) as f32) * 0.5;
            let (d, t) = ((p - c.eye).normalize(), (p - c.eye).length());
            let rad = r.at(d, t);
            let s = q.pack(p, rad);
            let code = radius_code(s);
            assert!(
                (1..RADIUS_MAX).contains(&code) || (code == RADIUS_MAX && rad <= r.unit() * (RADIUS_MAX as f32 + 0.5))
            );
            top = top.max(code);
            assert!((deq.radius(s) - rad).abs() <= 0.5 * r.unit() * 1.001, "{} vs {rad}", deq.radius(s));
        }
        assert!(top > RADIUS_MAX * 3 / 4, "the far samples use the top of the code range: {top}");
    }

    #[test]
    fn box_behind_the_eye_keeps_a_valid_unit() {
        let c = Camera::look_at(Vec3::new(0.5, 0.5, -3.0), Vec3::new(0.5, 0.5, -6.0), Vec3::Y, 30.0, 64, 64);
        let r = FrameRadius::new(RadiusModel::Footprint, 1.0, &c, &unit_box(), 0.01, 512.0);
        assert!(r.unit() > 0.0 && r.unit().is_finite());
    }
}
