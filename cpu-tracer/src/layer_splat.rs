//! Layered samples composited front to back (issue 14; renderer `splat-layers`).
//!
//! A layered frame carries up to K samples per pixel of the frame's camera, one per depth
//! segment, each with its own premultiplied color and opacity. Where the exact splatter
//! ([`crate::sphere_splat`]) draws each sample as a sphere and keeps the first hit, this
//! renderer draws each sample as its **source pixel's footprint**: the quadrilateral the frame
//! camera's pixel frustum cuts from the plane through the sample's centre facing the new eye
//! (the supersegment of volumetric depth images, Frey, Sadlo and Ertl 2013, flattened to its
//! representative depth), widened by [`OWN_MARGIN`] pixels (none by default). The quad is
//! projected into the new camera and every output pixel whose centre lies inside it takes the
//! sample. (A plane facing the frame's camera instead shrinks footprints seen obliquely and
//! opens cracks between them; `docs/perf.md`, issue 14.) Footprints of one depth tile the plane, so nothing is
//! counted twice where neighbouring segments lie at similar depths, and at the frame's own
//! camera every pixel takes exactly its own segments: the image is the server's render up to
//! 8-bit rounding. (A first version tested each pixel of the sphere's bound exactly and kept
//! the hits whose point nearest the centre projected into the sample's own pixel: the same rule
//! about 10× slower; `docs/perf.md`, issue 14.) The spheres' radii are not used.
//!
//! Per output pixel the samples go to a short list (the nearest, at most [`LIST`], as
//! `(distance from the eye, sample id)` keys); the list is sorted (ties by id, so the result
//! does not depend on the order of the samples) and composited front to back,
//! `C += (1 − A)·c`, stopping once `A` ≥ [`OPAQUE`]. Zero-opacity segments add nothing (no
//! division by opacity anywhere, so no NaN). Pixels nothing covers show the background.
//!
//! **Hole filling** ([`LayerOptions::fill`], issue 19's lever 5): pixels no segment covers,
//! inside the covered pixels' row and column spans, take the frame's own composited image for
//! their view direction (the stale frame, looked up as [`crate::hole_fill`]'s stage 3 does), so
//! what the warp knows nothing about shows what a send-image system would, not the background.
//! The frame's image is composited once per frame (the same footprints at the frame's camera).
//!
//! **Warp-sized footprints** ([`Renderer::set_adaptive_radius`]): a surface seen from a new
//! direction spreads its pixels' footprints apart at grazing angles; with adaptive sizing on,
//! the half side grows by [`LayerOptions::grow_per_degree`] per degree of warp (core's
//! `warp_radius::warp_angle_deg`) up to [`MAX_OWN`]; at the frame's own camera it is
//! [`LayerOptions::own`], so the frame is still reproduced there.
//!
//! Work: the footprints are set up in parallel over samples (four projections per sample, in
//! `f32`), binned to bands of rows, rasterized in parallel over bands (a few edge tests per
//! covered pixel) and the lists composited in parallel. Memory: `8 × LIST + 1` bytes per output
//! pixel and 48 bytes per sample (its footprint) plus 4 per band it touches.

use crate::hole_fill::{block_outside_silhouette, filled, stale_lookup, FILLED, UNFILLED};
use crate::route::SceneId;
use crate::sphere_splat::View;
use crate::threads::Threads;
use crate::{begin_frame_unbuilt_ok, MAX_VIEWPORT};
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::sample::{over_background, pack_color_f32};
use volwarp_core::warp_radius::warp_angle_deg;
use volwarp_core::{Camera, RendererKind, Scene, Vec3, BACKGROUND};

/// Most segments kept per output pixel (the nearest ones).
pub const LIST: usize = 16;

/// Accumulated opacity at which a pixel's compositing stops.
pub const OPAQUE: f32 = 0.999;

/// How far (in source pixels) beyond its own pixel a sample's footprint reaches. 0: a margin
/// against rounding cracks (0.05 in issue 14's first version) counts semi-transparent segments
/// twice along every footprint edge, a grid of bright lines once the view zooms in; without it
/// the session ꟻLIP of the iron protein's dolly fell from 0.0187 to 0.0064 and the MRI's orbit
/// from 0.0262 to 0.0200 (`docs/results.md`, "Layered frames as the default").
pub const OWN_MARGIN: f32 = 0.0;

/// The widest footprint adaptive sizing grows to by default (half side, source pixels).
pub const MAX_OWN: f32 = 2.0;

/// Output rows per rasterization task (the footprints are binned to bands of these rows).
const RASTER_BAND: usize = 32;

/// Samples per footprint set-up task.
const QUAD_CHUNK: usize = 4096;

/// A sample's footprint in the new image: its corners in order around it, depth key and pixel
/// bounds (`x[0] > x[1]`: none). 48 bytes: the footprints of a 1024² layered frame are about a
/// million, and writing and reading them back is a large part of the draw.
#[derive(Clone, Copy, Debug)]
struct Quad {
    corners: [(f32, f32); 4],
    key: u64,
    x: [u16; 2],
    y: [u16; 2],
}

impl Quad {
    const NONE: Quad = Quad { corners: [(0.0, 0.0); 4], key: u64::MAX, x: [1, 0], y: [1, 0] };

    /// Its edge functions, signed by its orientation: a pixel centre `(px, py)` is inside
    /// where `a·px + b·py + c ≥ 0` for all four.
    #[inline(always)]
    fn edges(&self) -> [(f32, f32, f32); 4] {
        let q = &self.corners;
        let area = (q[1].0 - q[0].0) * (q[2].1 - q[0].1) - (q[2].0 - q[0].0) * (q[1].1 - q[0].1);
        let sign = if area < 0.0 { -1.0 } else { 1.0 };
        core::array::from_fn(|e| {
            let (a, b) = (q[e], q[(e + 1) & 3]);
            // sign · ((b − a) × (p − a)) ≥ 0  ⇔  A·px + B·py + C ≥ 0
            let (ex, ey) = ((b.0 - a.0) * sign, (b.1 - a.1) * sign);
            (-ey, ex, ey * a.0 - ex * a.1)
        })
    }
}

/// Output rows per compositing task.
const BAND: usize = 16;

/// How wide a sample's footprint is (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayerOptions {
    /// Half the footprint's side, in source pixels: 0.5 is the source pixel itself; the default
    /// adds [`OWN_MARGIN`]. Measured (`docs/perf.md`, issue 14): 0.7 double-counts more than it
    /// fills.
    pub own: f32,
    /// Fill the pixels no segment covers from the frame's image (see the module docs).
    pub fill: bool,
    /// With adaptive sizing on, the half side added per degree of warp (source pixels).
    pub grow_per_degree: f32,
    /// Only samples at least this opaque (8-bit alpha) grow: growing a semi-transparent
    /// segment counts its color twice where footprints overlap.
    pub grow_min_alpha: u8,
    /// The widest a grown footprint gets (half side, source pixels).
    pub max_own: f32,
}

impl LayerOptions {
    /// The defaults (chosen by measurement, `docs/results.md`, layered samples).
    pub const DEFAULT: LayerOptions = LayerOptions {
        own: 0.5 + OWN_MARGIN,
        fill: true,
        grow_per_degree: 0.08,
        grow_min_alpha: 230,
        max_own: MAX_OWN,
    };

    /// The half side of the footprint for a warp of `deg` degrees (adaptive sizing on).
    pub fn own_at(&self, deg: f32) -> f32 {
        let grow = if self.grow_per_degree.is_finite() { self.grow_per_degree.max(0.0) } else { 0.0 };
        let cap = if self.max_own.is_finite() { self.max_own.min(4.0) } else { MAX_OWN };
        (self.own + grow * deg).min(cap.max(self.own))
    }
}

impl Default for LayerOptions {
    fn default() -> Self {
        LayerOptions::DEFAULT
    }
}

/// The layered splatter (renderer name `splat-layers`).
#[derive(Debug)]
pub struct LayerSplat {
    threads: Threads,
    opts: LayerOptions,
    /// Per output pixel `cap` keys.
    keys: Vec<u64>,
    /// Per output pixel the number of keys.
    count: Vec<u8>,
    /// Grow the footprints with the warp.
    adaptive: bool,
    /// The frame's own composited image (for the fill) and the scene it was made from.
    frame: Image,
    frame_of: Option<SceneId>,
    /// Per output pixel the fill state (`hole_fill`'s encoding).
    state: Vec<u64>,
    /// Per sample its footprint, and per band of rows the footprints that touch it.
    quads: Vec<Quad>,
    bins: Vec<Vec<u32>>,
}

impl LayerSplat {
    /// A layered splatter on `threads` threads (0: one per core).
    pub fn new(threads: usize) -> Self {
        LayerSplat::with_options(threads, LayerOptions::default())
    }

    /// A layered splatter with another footprint width.
    pub fn with_options(threads: usize, opts: LayerOptions) -> Self {
        LayerSplat {
            threads: Threads::new(threads),
            opts,
            keys: Vec::new(),
            count: Vec::new(),
            adaptive: false,
            frame: Image::new(0, 0),
            frame_of: None,
            state: Vec::new(),
            quads: Vec::new(),
            bins: Vec::new(),
        }
    }

    /// The options it draws with.
    pub fn options(&self) -> LayerOptions {
        self.opts
    }
}

/// A camera's projection in `f32`.
struct Proj {
    eye: Vec3,
    u: Vec3,
    v: Vec3,
    w: Vec3,
    px_x: f32,
    px_y: f32,
    half_w: f32,
    half_h: f32,
}

impl Proj {
    fn new(view: &View) -> Proj {
        let f = |a: [f64; 3]| Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32);
        Proj {
            eye: view.eye,
            u: f(view.u),
            v: f(view.v),
            w: f(view.w),
            px_x: view.px_x as f32,
            px_y: view.px_y as f32,
            half_w: view.half_w as f32,
            half_h: view.half_h as f32,
        }
    }

    /// Continuous image coordinates (pixel `(x, y)` spans `[x, x + 1) × [y, y + 1)`) of the point
    /// whose offset from the eye has components `c` along the camera's (u, v, w); `None` at or
    /// behind the eye plane or for a non-finite point.
    #[inline(always)]
    fn image(&self, c: Vec3) -> Option<(f32, f32)> {
        if !(c.z > 1e-6) {
            return None;
        }
        let inv = 1.0 / c.z;
        let (x, y) = (c.x * inv * self.px_x + self.half_w, self.half_h - c.y * inv * self.px_y);
        (x.is_finite() && y.is_finite()).then_some((x, y))
    }
}

/// The depth key: the centre's distance from the eye (ordered bits of a non-negative float)
/// and the sample id.
#[inline(always)]
fn key(dist: f32, id: u32) -> u64 {
    ((dist.max(0.0).to_bits() as u64) << 32) | id as u64
}

/// Inserts `key` into a list of `cap` slots holding `n`, keeping the `cap` smallest.
#[inline(always)]
fn insert(slots: &mut [u64], n: &mut u8, key: u64) {
    let len = *n as usize;
    if len < slots.len() {
        slots[len] = key;
        *n += 1;
        return;
    }
    let (mut worst, mut at) = (0u64, 0usize);
    for (i, &k) in slots.iter().enumerate() {
        if k >= worst {
            worst = k;
            at = i;
        }
    }
    if key < worst {
        slots[at] = key;
    }
}

impl Renderer for LayerSplat {
    fn kind(&self) -> RendererKind {
        RendererKind::SplatLayers
    }

    fn set_adaptive_radius(&mut self, on: bool) -> bool {
        self.adaptive = on;
        true
    }

    fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) {
        if !begin_frame_unbuilt_ok(scene, camera, out) {
            return;
        }
        let fc = scene.header.camera;
        let fill = self.opts.fill && fc.validate(MAX_VIEWPORT).is_ok();
        // The frame's own image first (it uses the same per-pixel lists).
        if fill && self.frame_of != Some(SceneId::of(scene)) {
            let mut frame = core::mem::replace(&mut self.frame, Image::new(0, 0));
            if begin_frame_unbuilt_ok(scene, &fc, &mut frame) {
                self.draw(scene, &fc, self.opts.own, &mut frame);
            }
            self.frame = frame;
            self.frame_of = Some(SceneId::of(scene));
        }
        // At the frame's own camera the filled image is the frame's own (nothing is a hole
        // there, and footprints do not grow): no second draw.
        if fill && *camera == fc && self.frame.pixels.len() == out.pixels.len() {
            out.pixels.copy_from_slice(&self.frame.pixels);
            return;
        }
        let grown = if self.adaptive { self.opts.own_at(warp_angle_deg(&fc, camera)) } else { self.opts.own };
        self.draw(scene, camera, grown, out);
        if !fill {
            return;
        }
        let (w, h) = (camera.width as usize, camera.height as usize);
        self.state.clear();
        self.state.extend(self.count.iter().zip(&out.pixels).map(|(&n, &p)| if n == 0 { UNFILLED } else { filled(p) }));
        block_outside_silhouette(&mut self.state, w, h);
        stale_lookup(&self.frame.pixels, &fc, camera, &mut self.state, &self.threads);
        for (p, &s) in out.pixels.iter_mut().zip(&self.state) {
            if s & FILLED != 0 {
                *p = s as u32;
            }
        }
    }
}

impl LayerSplat {
    /// Composites `scene` for `camera` into `out` (already sized and cleared to the background)
    /// with footprints of half side [`LayerOptions::own`] source pixels, `grown` for samples at
    /// least [`LayerOptions::grow_min_alpha`] opaque; leaves `count` with each output pixel's
    /// number of segments.
    fn draw(&mut self, scene: &Scene, camera: &Camera, grown: f32, out: &mut Image) {
        let own = self.opts.own;
        let (w, h) = (camera.width as usize, camera.height as usize);
        let deq = &scene.deq;
        let cap = LIST;
        self.count.clear();
        self.count.resize(w * h, 0);
        self.keys.resize(w * h * cap, u64::MAX);
        let view = Proj::new(&View::new(camera));
        let source = View::new(&scene.header.camera);
        let src = Proj::new(&source);
        // Half the footprint's side per unit of source depth, along the source's u and v.
        let half = if own.is_finite() { own.clamp(0.0, 4.0) } else { 0.5 };
        let grow_ratio = if half > 0.0 && grown.is_finite() { (grown.clamp(0.0, 4.0) / half).max(1.0) } else { 1.0 };
        let (hx, hy) = (half / source.px_x as f32, half / source.px_y as f32);
        let (su, sv) = (src.u * hx, src.v * hy);
        // Everything is expressed in the new camera's basis: a point's image coordinates are
        // its (u, v, w) components relative to the new eye. A corner ray's direction is
        // `axis ± su ± sv`, so its components are the axis's plus per-frame constants.
        let basis = |x: Vec3| Vec3::new(x.dot(view.u), x.dot(view.v), x.dot(view.w));
        let (bu, bv, e) = (basis(su), basis(sv), basis(src.eye - view.eye));
        let min_alpha = self.opts.grow_min_alpha;
        let colors = &scene.colors[..];
        // 1. Every sample's footprint in the new image (in parallel over samples).
        // Every footprint is written below (NONE where there is none): no clearing pass.
        if self.quads.len() != scene.samples.len() {
            self.quads.resize(scene.samples.len(), Quad::NONE);
        }
        let samples = &scene.samples[..];
        self.threads.for_each_chunk(&mut self.quads, QUAD_CHUNK, |chunk, quads| {
            for (j, q) in quads.iter_mut().enumerate() {
                *q = Quad::NONE;
                let id = chunk * QUAD_CHUNK + j;
                let c = deq.center(samples[id]);
                let rel = c - src.eye;
                let z = rel.dot(src.w);
                // The plane's normal (not normalised: only ratios of dot products with it are used).
                let n = c - view.eye;
                let dist2 = n.length_squared();
                if !(z > 0.0 && dist2 > 0.0) {
                    continue;
                }
                // The source pixel's frustum (the ray through the centre, ± half a pixel per
                // axis) cut by the plane through the centre facing the new eye: corner
                // `p = eye_s + λ·dir` with `λ = n·rel / n·dir`.
                let axis = rel / z;
                let num = n.dot(rel);
                let (an, un, vn) = (axis.dot(n), su.dot(n), sv.dot(n));
                // A corner ray within 5° of the plane (the new eye sees the footprint edge-on):
                // skip the sample (the corners' directions are the axis's within half a pixel).
                let edge_on = 0.0076 * dist2 * axis.length_squared();
                // Opaque samples may grow (adaptive sizing): the corners scale with the half side.
                let opaque = colors.get(id).is_some_and(|&c| (c >> 24) as u8 >= min_alpha);
                let r = if opaque && grow_ratio > 1.0 { grow_ratio } else { 1.0 };
                let ba = basis(axis);
                let corner = |sx: f32, sy: f32| {
                    let den = an + sx * un + sy * vn;
                    if !(den > 0.0 && den * den > edge_on) {
                        return None;
                    }
                    let p = e + (ba + bu * sx + bv * sy) * (num / den);
                    view.image(p)
                };
                // Its corners, in order around it, in the new camera's image.
                let (Some(q0), Some(q1), Some(q2), Some(q3)) =
                    (corner(-r, -r), corner(r, -r), corner(r, r), corner(-r, r))
                else {
                    continue;
                };
                let quad = [q0, q1, q2, q3];
                let x0 = q0.0.min(q1.0).min(q2.0).min(q3.0);
                let x1 = q0.0.max(q1.0).max(q2.0).max(q3.0);
                let y0 = q0.1.min(q1.1).min(q2.1).min(q3.1);
                let y1 = q0.1.max(q1.1).max(q2.1).max(q3.1);
                // Pixel centres x + ½ within [x0, x1].
                let (xa, xb) = ((x0 - 0.5).ceil().max(0.0), (x1 - 0.5).floor().min(w as f32 - 1.0));
                let (ya, yb) = ((y0 - 0.5).ceil().max(0.0), (y1 - 0.5).floor().min(h as f32 - 1.0));
                if !(xa <= xb && ya <= yb) {
                    continue;
                }
                // Squared distance: the same order, no square root. (Bounds are within the
                // viewport, at most `MAX_VIEWPORT` < 2¹⁶.)
                *q = Quad {
                    corners: quad,
                    key: key(dist2, id as u32),
                    x: [xa as u16, xb as u16],
                    y: [ya as u16, yb as u16],
                };
            }
        });
        // 2. Each footprint to the row bands it touches.
        let bands = h.div_ceil(RASTER_BAND);
        self.bins.resize_with(bands, Vec::new);
        self.bins.iter_mut().for_each(Vec::clear);
        for (id, q) in self.quads.iter().enumerate() {
            if q.x[0] <= q.x[1] {
                for b in q.y[0] as usize / RASTER_BAND..=q.y[1] as usize / RASTER_BAND {
                    self.bins[b].push(id as u32);
                }
            }
        }
        // 3. The bands' pixels take their footprints' keys (in parallel over bands: the lists
        // keep the nearest keys whatever the order, so the image does not depend on it).
        let (quads, bins) = (&self.quads[..], &self.bins[..]);
        let raster = |b: usize, keys: &mut [u64], count: &mut [u8]| {
            let y_lo = b * RASTER_BAND;
            for &id in &bins[b] {
                let q = &quads[id as usize];
                let edges = q.edges();
                let (ya, yb) = ((q.y[0] as usize).max(y_lo), (q.y[1] as usize).min(y_lo + RASTER_BAND - 1));
                for y in ya..=yb {
                    let py = y as f32 + 0.5;
                    for x in q.x[0] as usize..=q.x[1] as usize {
                        let px = x as f32 + 0.5;
                        if edges.iter().all(|&(a, b, c)| a * px + b * py + c >= 0.0) {
                            let i = (y - y_lo) * w + x;
                            insert(&mut keys[i * cap..(i + 1) * cap], &mut count[i], q.key);
                        }
                    }
                }
            }
        };
        let (keys, count) = (&mut self.keys[..w * h * cap], &mut self.count[..]);
        if self.threads.is_serial() {
            for (b, (k, c)) in keys.chunks_mut(RASTER_BAND * w * cap).zip(count.chunks_mut(RASTER_BAND * w)).enumerate()
            {
                raster(b, k, c);
            }
        } else {
            use rayon::prelude::*;
            self.threads.install(|| {
                keys.par_chunks_mut(RASTER_BAND * w * cap)
                    .zip(count.par_chunks_mut(RASTER_BAND * w))
                    .enumerate()
                    .for_each(|(b, (k, c))| raster(b, k, c))
            });
        }
        let (keys, count) = (&self.keys[..], &self.count[..]);
        self.threads.for_each_chunk(&mut out.pixels, BAND * w, |band, px| {
            for (j, p) in px.iter_mut().enumerate() {
                let i = band * BAND * w + j;
                let mut list = [0u64; LIST];
                let n = count[i] as usize;
                if n == 0 {
                    continue;
                }
                list[..n].copy_from_slice(&keys[i * cap..i * cap + n]);
                let list = &mut list[..n];
                list.sort_unstable();
                *p = composite_keys(list, colors);
            }
        });
    }
}

/// The pixel of a sorted list of keys: their samples' colors composited front to back over the
/// background.
fn composite_keys(keys: &[u64], colors: &[u32]) -> u32 {
    if keys.is_empty() {
        return BACKGROUND;
    }
    let mut acc = [0.0f32; 4];
    for &k in keys {
        let Some(&c) = colors.get(k as u32 as usize) else { continue };
        let c = c.to_le_bytes();
        let wgt = (1.0 - acc[3]) * (1.0 / 255.0);
        for i in 0..4 {
            acc[i] += wgt * c[i] as f32;
        }
        if acc[3] >= OPAQUE {
            break;
        }
    }
    over_background(pack_color_f32(acc), BACKGROUND)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_short_list_keeps_the_nearest() {
        let mut slots = [0u64; 6];
        let mut n = 0u8;
        for k in (0..40u64).rev() {
            insert(&mut slots, &mut n, k * 3);
        }
        slots.sort_unstable();
        assert_eq!(n, 6);
        assert_eq!(slots.to_vec(), (0..6u64).map(|k| k * 3).collect::<Vec<_>>());
    }

    #[test]
    fn compositing_zero_opacity_gives_the_background_and_no_nan() {
        let colors = [0u32, 0, 0];
        assert_eq!(composite_keys(&[key(1.0, 0), key(2.0, 1), key(3.0, 2)], &colors), BACKGROUND);
        assert_eq!(composite_keys(&[], &colors), BACKGROUND);
    }
}
