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
//! division by opacity anywhere, so no NaN). Pixels nothing covers show the background. The lists,
//! their sort and their compositing live in `key_list.rs` (AVX2 paths beside the scalar
//! reference: the compositing runs eight pixels at once, one per lane).
//!
//! **Watertight slabs** ([`LayerOptions::watertight`]): the `j`-th nearest segment of a pixel
//! belongs to slab `j`. Where the slab-`j` segments of the pixels around a corner of the source
//! pixel grid lie within [`WATERTIGHT`] source pixels of each other in depth, that corner is
//! shared: it sits on its ray at their mean depth, computed once per frame when it arrives
//! ([`SlabCorners`]) and used by every pixel around it, so the footprints of one slab meet
//! exactly instead of overlapping on one side and parting on the other (a semi-transparent
//! slab counted twice or not at all, in bands along the surface's iso-depth lines: the contour
//! lines `docs/results.md` traced). A segment takes its shared corners only where their
//! footprint covers at least [`LayerOptions::water_ratio`] of the plane footprint's area on
//! screen (a slab seen ever more edge-on thins to a sliver where the volume it stands for does
//! not), and only if it does not grow (adaptive sizing below). At the frame's own camera a
//! shared corner projects onto its pixel corner at any depth, so the frame is still reproduced
//! there.
//!
//! **Hole filling** ([`LayerOptions::fill`], issue 19's lever 5): pixels no segment covers,
//! inside the covered pixels' row and column spans, take the frame's own composited image for
//! their view direction (the stale frame, looked up as [`crate::hole_fill`]'s stage 3 does), so
//! what the warp knows nothing about shows what a send-image system would, not the background.
//! At its own camera every footprint is exactly its source pixel, so the frame's image at a
//! pixel is that pixel's own segments composited: when a frame arrives its samples are grouped
//! by source pixel once (`OwnPass`), and each hole composites the pixel it looks up on the
//! spot; the whole image is composited only when the frame's own camera is drawn.
//!
//! **Older frames** ([`Renderer::render_set`], issue 19's multi-frame filling; the client keeps
//! 4 frames by default): pixels no segment of the newest frame covers first take the older
//! frames' segments, newest first, before the hole filling above. Only what the newest frame did
//! not see comes back: when a newest frame arrives, its [`Sight`] (per pixel of its camera, the
//! view depths of its nearest and farthest segment and its opacity) reduces each older frame
//! once to its *residual* (the previous newest whole, the others' residuals further), the
//! samples outside the newest frame's view or more than
//! [`RESIDUAL_TOLERANCE`] pixels behind the farthest segment of a pixel at least
//! [`RESIDUAL_OPAQUE`] opaque. So an older sample never stands where the newest frame saw empty
//! space or the same surface (on a steady orbit older frames change nothing), and a camera
//! turning back gets the surfaces the newest frame could not see. Turned more than 90° from
//! the newest frame's view, its footprints face away and draw nothing, so older frames are then
//! drawn whole. Residuals are drawn only
//! into pixels still empty, and footprints touching no tile with an empty pixel are skipped.
//!
//! **Warp-sized footprints** ([`Renderer::set_adaptive_radius`]): a surface seen from a new
//! direction spreads its pixels' footprints apart at grazing angles; with adaptive sizing on,
//! the half side grows by [`LayerOptions::grow_per_degree`] per degree of warp (core's
//! `warp_radius::warp_angle_deg`) up to [`MAX_OWN`]; at the frame's own camera it is
//! [`LayerOptions::own`], so the frame is still reproduced there.
//!
//! Work: the footprints are set up in parallel over samples (four projections per sample, in
//! `f32`, four more where a sample has shared corners), binned to bands of rows, rasterized in
//! parallel over bands (a few edge tests per covered pixel) and composited band by band.
//! Memory: 1 byte per output pixel (its count), `8 × LIST` bytes per pixel of one band per
//! thread, and per sample 64 bytes (its footprint) plus 4 for its band range and 4 per band it
//! touches; for the newest frame, 20 bytes per sample and 4 per pixel (`OwnPass`) and 20 per
//! sample for its shared corners (44 for a frame not in the server's order, which is sorted
//! first).

use crate::hole_fill::{block_outside_silhouette_on, filled, stale_lookup, FILLED, UNFILLED};
use crate::key_list::{composite_keys, composite_run, insert, key, sort_keys};
use crate::lanes::{self, Lanes};
use crate::route::SceneId;
use crate::sphere_splat::View;
use crate::threads::Threads;
use crate::{begin_frame_unbuilt_ok, MAX_VIEWPORT};
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::sample::Dequantizer;
use volwarp_core::warp_radius::warp_angle_deg;
use volwarp_core::{Camera, RendererKind, Scene, Vec3, BACKGROUND};
use wide::f32x4;

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

/// The default depth tolerance of watertight slabs, source pixels ([`LayerOptions::watertight`]):
/// the method's (core's `method::WATERTIGHT`).
pub use volwarp_core::method::WATERTIGHT;

/// The widest footprint adaptive sizing grows to by default (half side, source pixels).
pub const MAX_OWN: f32 = 2.0;

/// Output rows per rasterization task (the footprints are binned to bands of these rows).
const RASTER_BAND: usize = 8;

/// The band range of a sample without a footprint (first > last).
const NO_BANDS: u32 = 1;

/// How far behind the farthest segment of an opaque pixel of the newest frame (in that
/// frame's pixels at the sample's depth) an older frame's sample must lie to be drawn: the
/// segments' depths are representative, not exact. Measured insensitive between 1 and 6 (the
/// MRI's stop-and-go p95 0.0489 at all three).
pub const RESIDUAL_TOLERANCE: f32 = 3.0;

/// The opacity from which a pixel of the newest frame hides what lies behind its segments
/// (measured: 0.5 and 0.9 give the same sessions).
pub const RESIDUAL_OPAQUE: f32 = 0.9;

/// Rows per task of the shared-corner stencil (each task reads a row more above and below, and
/// keeps its own three rows of slab depths).
const CORNER_BAND: usize = 32;

/// Samples per footprint set-up task.
const QUAD_CHUNK: usize = 4096;

/// Rows per task of the per-pixel passes over the fill state (in parallel: at 1024² each pass
/// reads and writes 8 MB of state).
const PIXEL_PASS_ROWS: usize = 64;

/// A sample's footprint in the new image: the edge functions of its quadrilateral, depth key
/// and pixel bounds (`x[0] > x[1]`: none). 64 bytes, one cache line: the footprints of a 1024²
/// layered frame are about a million, set up in SIMD lanes and read back by the rasterizer.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
struct Quad {
    /// The four edges' coefficients `A`, `B`, `C` (`edges[k][e]`: coefficient `k` of edge
    /// `e`, so each coefficient of the four edges is one 4-lane vector): a pixel centre
    /// `(px, py)` is inside where `A·px + B·py + C ≥ 0` for all four.
    edges: [[f32; 4]; 3],
    key: u64,
    x: [u16; 2],
    y: [u16; 2],
}

impl Quad {
    const NONE: Quad = Quad { edges: [[0.0; 4]; 3], key: u64::MAX, x: [1, 0], y: [1, 0] };

    /// Whether pixel centre `(px, py)` is inside (no branch per edge): the reference of
    /// [`Quad::row`]'s test.
    #[cfg(test)]
    fn covers(&self, px: f32, py: f32) -> bool {
        let e = &self.edges;
        let f = |k: usize| e[0][k] * px + e[1][k] * py + e[2][k];
        (f(0) >= 0.0) & (f(1) >= 0.0) & (f(2) >= 0.0) & (f(3) >= 0.0)
    }

    /// The four edges at pixel row `py`, for [`QuadRow::covers`].
    #[inline(always)]
    fn row(&self, py: f32) -> QuadRow {
        let [a, b, c] = self.edges.map(f32x4::from);
        QuadRow { a, bpy: b * f32x4::splat(py), c }
    }
}

/// A footprint's four edge functions along one pixel row, as 4-lane vectors (one lane per
/// edge): the same operations as [`Quad::covers`] in the same order (`(A·px + B·py) + C`, no
/// fused multiply-add), so the same result, with one vector multiply, two adds and one
/// comparison per pixel.
#[derive(Clone, Copy)]
struct QuadRow {
    a: f32x4,
    bpy: f32x4,
    c: f32x4,
}

impl QuadRow {
    /// Whether pixel centre `px` of the row is inside.
    #[inline(always)]
    fn covers(&self, px: f32) -> bool {
        let f = (self.a * f32x4::splat(px) + self.bpy) + self.c;
        f.simd_ge(f32x4::ZERO).to_bitmask() == 0xF
    }
}

/// Four edges' `[A, B, C]` as [`Quad::edges`] keeps them (coefficient-major).
#[cfg(test)]
fn coefficient_major(e: [[f32; 3]; 4]) -> [[f32; 4]; 3] {
    core::array::from_fn(|k| core::array::from_fn(|i| e[i][k]))
}

/// The edge functions of the quadrilateral with corners `q` (in order around it), signed by
/// its orientation: `sign · ((b − a) × (p − a)) ≥ 0` for each edge `a → b`.
#[cfg(test)]
fn edges_of(q: [(f32, f32); 4]) -> [[f32; 3]; 4] {
    let area = (q[1].0 - q[0].0) * (q[2].1 - q[0].1) - (q[2].0 - q[0].0) * (q[1].1 - q[0].1);
    let sign = if area < 0.0 { -1.0 } else { 1.0 };
    core::array::from_fn(|e| {
        let (a, b) = (q[e], q[(e + 1) & 3]);
        let (ex, ny) = ((b.0 - a.0) * sign, (a.1 - b.1) * sign);
        // A = −(b − a).y, B = (b − a).x, C = −(A·a.x + B·a.y) written as (b − a).y·a.x − B·a.y.
        [ny, ex, (b.1 - a.1) * sign * a.0 - ex * a.1]
    })
}

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
    /// Watertight slabs: neighbouring pixels' segments of the same slab share their
    /// footprints' corners where their depths differ by at most this many source pixels (0:
    /// every footprint is its own plane). Only with footprints of the source pixel's size.
    /// Measured (`docs/results.md`, "Watertight slabs"): 1–3 all lower the sessions' ꟻLIP,
    /// 1.5 the most.
    pub watertight: f32,
    /// A segment takes its slab's shared corners only where their footprint covers at least
    /// this share of the plane footprint's area on screen: a slab seen ever more edge-on
    /// thins to a sliver where the volume it stands for does not (measured, `docs/results.md`).
    pub water_ratio: f32,
}

impl LayerOptions {
    /// The defaults (chosen by measurement, `docs/results.md`, layered samples).
    pub const DEFAULT: LayerOptions = LayerOptions {
        own: 0.5 + OWN_MARGIN,
        fill: true,
        grow_per_degree: 0.08,
        grow_min_alpha: 230,
        max_own: MAX_OWN,
        watertight: WATERTIGHT,
        water_ratio: 1.0,
    };

    /// Whether at the frame's own camera every footprint is exactly its source pixel (half
    /// side 0.5, the default): then the frame's own image is its samples grouped by pixel
    /// (`OwnPass`), with wider or narrower footprints it must be drawn.
    pub fn own_pixels(&self) -> bool {
        self.own == 0.5
    }

    /// Whether the newest frame's slabs are watertight: a tolerance, and footprints of the
    /// source pixel's size (what the shared corners are corners of).
    pub fn shares_corners(&self) -> bool {
        self.watertight > 0.0 && self.own_pixels()
    }

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
    /// Per output pixel the number of keys.
    count: Vec<u8>,
    /// Grow the footprints with the warp.
    adaptive: bool,
    /// The frame's own composited image (drawn at the frame's own camera; the hole lookups'
    /// source for footprints other than the default's) and the scene it was made from.
    frame: Image,
    frame_of: Option<SceneId>,
    /// Per output pixel the fill state (`hole_fill`'s encoding).
    state: Vec<u64>,
    /// Per sample its footprint.
    quads: Vec<Quad>,
    /// Per binning task (one per thread), per band of rows, the footprints of the task's run
    /// that touch it.
    bins: Vec<Vec<Vec<u32>>>,
    /// Per sample the first and last band of rows its footprint touches (`b0 | b1 << 16`).
    bands: Vec<u32>,
    /// An older frame's image (multi-frame filling).
    scratch: Image,
    /// The newest frame's samples in its own camera (its own image and its `Sight` use them).
    own: OwnPass,
    /// What the newest frame saw, and per older frame what it did not see.
    older: OlderFrames,
    /// Which tiles of the image still hold an unfilled pixel (see `Holes`).
    tiles: Vec<u8>,
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
            count: Vec::new(),
            adaptive: false,
            frame: Image::new(0, 0),
            frame_of: None,
            state: Vec::new(),
            quads: Vec::new(),
            bins: Vec::new(),
            bands: Vec::new(),
            scratch: Image::new(0, 0),
            own: OwnPass::default(),
            older: OlderFrames::default(),
            tiles: Vec::new(),
        }
    }

    /// The options it draws with.
    pub fn options(&self) -> LayerOptions {
        self.opts
    }
}

/// A camera's projection in `f32`: a point's continuous image coordinates are
/// `(c.u/c.w · px_x + half_w, half_h − c.v/c.w · px_y)` for its offset `c` from the eye in the
/// camera's `(u, v, w)` basis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Proj {
    /// The eye.
    pub eye: Vec3,
    /// The camera's right, up and forward axes.
    pub u: Vec3,
    /// See `u`.
    pub v: Vec3,
    /// See `u`.
    pub w: Vec3,
    /// Pixels per unit slope along x and y.
    pub px_x: f32,
    /// See `px_x`.
    pub px_y: f32,
    /// Half the viewport's width and height, pixels.
    pub half_w: f32,
    /// See `half_w`.
    pub half_h: f32,
}

impl Proj {
    pub(crate) fn new(view: &View) -> Proj {
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
    #[cfg(test)]
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

/// The pixels a draw covered (`count` > 0) into the fill `state` with their color from
/// `pixels`, where still [`UNFILLED`]; with `fresh` the state is set anew (every other pixel
/// [`UNFILLED`]). In parallel over runs of `rows` pixels (each pixel on its own).
fn take_drawn(threads: &Threads, state: &mut [u64], count: &[u8], pixels: &[u32], rows: usize, fresh: bool) {
    threads.for_each_chunk(state, rows, |i, state| {
        let at = i * rows;
        for ((s, &n), &p) in state.iter_mut().zip(&count[at..]).zip(&pixels[at..]) {
            if n > 0 && (fresh || *s == UNFILLED) {
                *s = filled(p);
            } else if fresh {
                *s = UNFILLED;
            }
        }
    });
}

/// Per-frame constants of the footprint set-up: the source pixel's half sides and the frame's
/// eye expressed in the new camera's basis, so a corner's image coordinates are a few
/// multiply-adds and two divisions. The one definition of these figures: the GPU layered
/// splatter (`volwarp_gpu_tracer`) puts them in its uniform, so both draw the same footprints.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Setup {
    /// The frame's sample decoder.
    pub deq: Dequantizer,
    /// The new camera's projection.
    pub view: Proj,
    /// The frame camera's eye.
    pub src_eye: Vec3,
    /// The frame camera's viewing axis.
    pub src_w: Vec3,
    /// Half a source pixel along the frame camera's u per unit of its depth.
    pub su: Vec3,
    /// The same along its v.
    pub sv: Vec3,
    /// `su` in the new camera's basis.
    pub bu: Vec3,
    /// `sv` in the new camera's basis.
    pub bv: Vec3,
    /// The frame's eye relative to the new one, in the new camera's basis.
    pub e: Vec3,
    /// How much the corners of a growing (at least `min_alpha` opaque) sample scale (≥ 1).
    pub grow_ratio: f32,
    /// The 8-bit alpha from which samples grow.
    pub min_alpha: u8,
    /// A sample takes its slab's shared corners where their footprint covers at least this
    /// share of the plane footprint's area on screen.
    pub water_ratio: f32,
    /// The largest pixel index along x.
    pub last_x: f32,
    /// The largest pixel index along y.
    pub last_y: f32,
}

impl Setup {
    /// The constants for drawing a frame rendered for `frame_camera` (decoded by `deq`) for
    /// `camera`, with footprints of half side `own` source pixels, `grown` for samples at least
    /// `min_alpha` opaque.
    pub fn new(
        camera: &Camera,
        frame_camera: &Camera,
        deq: &Dequantizer,
        own: f32,
        grown: f32,
        min_alpha: u8,
    ) -> Setup {
        let view = Proj::new(&View::new(camera));
        let source = View::new(frame_camera);
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
        Setup {
            deq: *deq,
            src_eye: src.eye,
            src_w: src.w,
            su,
            sv,
            bu,
            bv,
            e,
            grow_ratio,
            min_alpha,
            water_ratio: 1.0,
            last_x: camera.width as f32 - 1.0,
            last_y: camera.height as f32 - 1.0,
            view,
        }
    }

    /// How much the corners of sample `id` scale: `grow_ratio` where its color is at least
    /// `min_alpha` opaque, else 1.
    #[inline(always)]
    fn scale(&self, colors: &[u32], id: usize) -> f32 {
        let opaque = colors.get(id).is_some_and(|&c| (c >> 24) as u8 >= self.min_alpha);
        if opaque && self.grow_ratio > 1.0 {
            self.grow_ratio
        } else {
            1.0
        }
    }

    /// The footprint of sample `id` (packed `sample`), one at a time: the reference the lanes
    /// kernel [`footprint_group`] computes eight at a time, bit for bit.
    #[cfg(test)]
    fn quad(&self, sample: u64, colors: &[u32], id: usize, shared: Option<[f32; 4]>) -> Quad {
        let view = &self.view;
        let c = self.deq.center(sample);
        let rel = c - self.src_eye;
        let z = rel.dot(self.src_w);
        // The plane's normal (not normalised: only ratios of dot products with it are used).
        let n = c - view.eye;
        let dist2 = n.length_squared();
        if !(z > 0.0 && dist2 > 0.0) {
            return Quad::NONE;
        }
        // The source pixel's frustum (the ray through the centre, ± half a pixel per axis)
        // cut by the plane through the centre facing the new eye: corner
        // `p = eye_s + λ·dir` with `λ = n·rel / n·dir`.
        let axis = rel / z;
        let num = n.dot(rel);
        let (an, un, vn) = (axis.dot(n), self.su.dot(n), self.sv.dot(n));
        // A corner ray within 5° of the plane (the new eye sees the footprint edge-on): skip
        // the sample (the corners' directions are the axis's within half a pixel).
        let edge_on = 0.0076 * dist2 * axis.length_squared();
        // Opaque samples may grow (adaptive sizing): the corners scale with the half side.
        let r = self.scale(colors, id);
        let ba = Vec3::new(axis.dot(view.u), axis.dot(view.v), axis.dot(view.w));
        // Two candidates: the plane facing the new eye, and the slab's shared corners (only on
        // a footprint that does not grow; each corner on its ray at the shared source depth
        // where it is shared, on the plane where not).
        let zc = shared.unwrap_or([f32::NAN; 4]);
        let steps = [(-r, -r), (r, -r), (r, r), (-r, r)];
        let plane_ok = |sx: f32, sy: f32| {
            let den = an + sx * un + sy * vn;
            (den > 0.0 && den * den > edge_on, num / den)
        };
        let at = |t: f32, sx: f32, sy: f32| view.image(self.e + (ba + self.bu * sx + self.bv * sy) * t);
        let plane: Option<[(f32, f32); 4]> = steps
            .iter()
            .map(|&(sx, sy)| {
                let (ok, t) = plane_ok(sx, sy);
                if ok {
                    at(t, sx, sy)
                } else {
                    None
                }
            })
            .collect::<Option<Vec<_>>>()
            .map(|v| [v[0], v[1], v[2], v[3]]);
        let water: Option<[(f32, f32); 4]> = if r == 1.0 && zc.iter().any(|z| z.is_finite()) {
            steps
                .iter()
                .zip(zc)
                .map(|(&(sx, sy), z)| {
                    let (ok, t) = plane_ok(sx, sy);
                    if z.is_finite() {
                        at(z, sx, sy)
                    } else if ok {
                        at(t, sx, sy)
                    } else {
                        None
                    }
                })
                .collect::<Option<Vec<_>>>()
                .map(|v| [v[0], v[1], v[2], v[3]])
        } else {
            None
        };
        let area = |q: &[(f32, f32); 4]| {
            let a = (q[2].0 - q[0].0) * (q[3].1 - q[1].1) - (q[3].0 - q[1].0) * (q[2].1 - q[0].1);
            a.max(-a)
        };
        let chosen = match (water, plane) {
            (Some(w), Some(p)) if area(&w) >= area(&p) * self.water_ratio => Some(w),
            (Some(w), None) => Some(w),
            (_, p) => p,
        };
        // Its corners, in order around it, in the new camera's image.
        let Some([q0, q1, q2, q3]) = chosen else {
            return Quad::NONE;
        };
        let x0 = q0.0.min(q1.0).min(q2.0).min(q3.0);
        let x1 = q0.0.max(q1.0).max(q2.0).max(q3.0);
        let y0 = q0.1.min(q1.1).min(q2.1).min(q3.1);
        let y1 = q0.1.max(q1.1).max(q2.1).max(q3.1);
        // Pixel centres x + ½ within [x0, x1].
        let (xa, xb) = ((x0 - 0.5).ceil().max(0.0), (x1 - 0.5).floor().min(self.last_x));
        let (ya, yb) = ((y0 - 0.5).ceil().max(0.0), (y1 - 0.5).floor().min(self.last_y));
        if !(xa <= xb && ya <= yb) {
            return Quad::NONE;
        }
        // Squared distance: the same order, no square root. (Bounds are within the viewport,
        // at most `MAX_VIEWPORT` < 2¹⁶.)
        Quad {
            edges: coefficient_major(edges_of([q0, q1, q2, q3])),
            key: key(dist2, id as u32),
            x: [xa as u16, xb as u16],
            y: [ya as u16, yb as u16],
        }
    }
}

/// [`Setup::quad`] for eight samples at once: the same operations in the same order on lanes,
/// so the same footprints bit for bit (the test `lanes_match_the_scalar_footprints`). `first`
/// is the id of `samples[0]`; `samples` holds at most eight.
#[inline(always)]
fn footprint_group<L: Lanes>(
    s: &Setup,
    samples: &[u64],
    colors: &[u32],
    shared: &[[f32; 4]],
    first: usize,
    out: &mut [Quad],
) {
    // The centres, decoded as the tile splatter's bound pass does (`Lanes::decode8`, the
    // scalar `Dequantizer::center` values; less a zero eye, which changes no bit).
    let [cx, cy, cz, _] = match samples.first_chunk::<8>() {
        Some(eight) => L::decode8(&s.deq, [0.0; 3], eight),
        None => lanes::decode_scalar(&s.deq, [0.0; 3], samples),
    };
    let mut rr = [1.0f32; 8];
    for (i, r) in rr.iter_mut().enumerate().take(samples.len().min(8)) {
        *r = s.scale(colors, first + i);
    }
    let sp = L::splat;
    let r = L::new(rr);
    let (rx, ry, rz) = (cx - sp(s.src_eye.x), cy - sp(s.src_eye.y), cz - sp(s.src_eye.z));
    let z = rx * sp(s.src_w.x) + ry * sp(s.src_w.y) + rz * sp(s.src_w.z);
    let v = &s.view;
    let (nx, ny, nz) = (cx - sp(v.eye.x), cy - sp(v.eye.y), cz - sp(v.eye.z));
    let dist2 = nx * nx + ny * ny + nz * nz;
    let zero = sp(0.0);
    let mut ok = z.simd_gt(zero) & dist2.simd_gt(zero);
    let (ax, ay, az) = (rx / z, ry / z, rz / z);
    let num = nx * rx + ny * ry + nz * rz;
    let an = ax * nx + ay * ny + az * nz;
    let un = sp(s.su.x) * nx + sp(s.su.y) * ny + sp(s.su.z) * nz;
    let vn = sp(s.sv.x) * nx + sp(s.sv.y) * ny + sp(s.sv.z) * nz;
    let edge_on = sp(0.0076) * dist2 * (ax * ax + ay * ay + az * az);
    // No closure doing lane arithmetic anywhere in this kernel: a closure is compiled without
    // the AVX2 target feature of its caller, and every lane operation in it becomes a call
    // (measured: the set-up 4× slower once the inliner stopped rescuing it).
    let ba_u = ax * sp(v.u.x) + ay * sp(v.u.y) + az * sp(v.u.z);
    let ba_v = ax * sp(v.v.x) + ay * sp(v.v.y) + az * sp(v.v.z);
    let ba_w = ax * sp(v.w.x) + ay * sp(v.w.y) + az * sp(v.w.z);
    let mut xs = [zero; 4];
    let mut ys = [zero; 4];
    let neg = zero - r;
    // The shared corner depths (NaN: not shared), used where the footprint does not grow.
    let mut zc = [[f32::NAN; 8]; 4];
    for (i, c) in shared.iter().enumerate().take(samples.len().min(8)) {
        for k in 0..4 {
            zc[k][i] = c[k];
        }
    }
    let unit = r.simd_eq(sp(1.0));
    // Two candidate footprints: the plane facing the new eye, and the slab's shared corners
    // (each corner shared where it is, on the plane where not).
    let (mut okp, mut okw, mut any_w) = (ok, ok & unit, zero.simd_gt(zero));
    let (mut wxs, mut wys) = ([zero; 4], [zero; 4]);
    for (k, (sx, sy)) in [(neg, neg), (r, neg), (r, r), (neg, r)].into_iter().enumerate() {
        let den = an + sx * un + sy * vn;
        let zk = L::new(zc[k]);
        let shared = zk.is_finite();
        any_w = any_w | shared;
        let plane_ok = den.simd_gt(zero) & (den * den).simd_gt(edge_on);
        let tp = num / den;
        let (rx, ry, rz) = (
            ba_u + sp(s.bu.x) * sx + sp(s.bv.x) * sy,
            ba_v + sp(s.bu.y) * sx + sp(s.bv.y) * sy,
            ba_w + sp(s.bu.z) * sx + sp(s.bv.z) * sy,
        );
        for (water, t) in [(false, tp), (true, shared.select(zk, tp))] {
            let px = sp(s.e.x) + rx * t;
            let py = sp(s.e.y) + ry * t;
            let pz = sp(s.e.z) + rz * t;
            let inv = sp(1.0) / pz;
            let x = px * inv * sp(v.px_x) + sp(v.half_w);
            let y = sp(v.half_h) - py * inv * sp(v.px_y);
            let fine = pz.simd_gt(sp(1e-6)) & x.is_finite() & y.is_finite();
            if water {
                okw = okw & fine & (shared | plane_ok);
                (wxs[k], wys[k]) = (x, y);
            } else {
                okp = okp & fine & plane_ok;
                (xs[k], ys[k]) = (x, y);
            }
        }
    }
    // The shared corners where the slab's footprint is at least `water_ratio` of the plane's
    // area on screen (a slab seen ever more edge-on thins to a sliver where the volume it
    // stands for does not), or where the plane has no footprint.
    let aw = (wxs[2] - wxs[0]) * (wys[3] - wys[1]) - (wxs[3] - wxs[1]) * (wys[2] - wys[0]);
    let ap = (xs[2] - xs[0]) * (ys[3] - ys[1]) - (xs[3] - xs[1]) * (ys[2] - ys[0]);
    let (aw, ap) = (aw.max(zero - aw), ap.max(zero - ap));
    let no_plane = okp.select(zero.simd_gt(zero), zero.simd_ge(zero));
    let use_w = okw & any_w & (no_plane | aw.simd_ge(ap * sp(s.water_ratio)));
    for k in 0..4 {
        xs[k] = use_w.select(wxs[k], xs[k]);
        ys[k] = use_w.select(wys[k], ys[k]);
    }
    ok = use_w | okp;
    let x0 = xs[0].min(xs[1]).min(xs[2]).min(xs[3]);
    let x1 = xs[0].max(xs[1]).max(xs[2]).max(xs[3]);
    let y0 = ys[0].min(ys[1]).min(ys[2]).min(ys[3]);
    let y1 = ys[0].max(ys[1]).max(ys[2]).max(ys[3]);
    let half = sp(0.5);
    let (xa, xb) = ((x0 - half).ceil().max(zero), (x1 - half).floor().min(sp(s.last_x)));
    let (ya, yb) = ((y0 - half).ceil().max(zero), (y1 - half).floor().min(sp(s.last_y)));
    ok = ok & xa.simd_le(xb) & ya.simd_le(yb);
    let mask = ok.to_bitmask();
    // The edge functions, as `edges_of` computes them.
    let area = (xs[1] - xs[0]) * (ys[2] - ys[0]) - (xs[2] - xs[0]) * (ys[1] - ys[0]);
    let sign = area.simd_lt(zero).select(sp(-1.0), sp(1.0));
    let mut edges = [[[0.0f32; 8]; 3]; 4];
    for (e, edge) in edges.iter_mut().enumerate() {
        let (ax, ay, bx, by) = (xs[e], ys[e], xs[(e + 1) & 3], ys[(e + 1) & 3]);
        let (ex, ny) = ((bx - ax) * sign, (ay - by) * sign);
        *edge = [ny.to_array(), ex.to_array(), ((by - ay) * sign * ax - ex * ay).to_array()];
    }
    let (xa, xb, ya, yb, d2) = (xa.to_array(), xb.to_array(), ya.to_array(), yb.to_array(), dist2.to_array());
    for (i, q) in out.iter_mut().enumerate().take(samples.len().min(8)) {
        *q = if mask >> i & 1 == 0 {
            Quad::NONE
        } else {
            Quad {
                edges: core::array::from_fn(|k| core::array::from_fn(|e| edges[e][k][i])),
                key: key(d2[i], (first + i) as u32),
                x: [xa[i] as u16, xb[i] as u16],
                y: [ya[i] as u16, yb[i] as u16],
            }
        };
    }
}

/// Every footprint of `samples` (ids from `first`) into `out`, eight at a time.
#[inline(always)]
fn footprint_lanes<L: Lanes>(
    s: &Setup,
    samples: &[u64],
    colors: &[u32],
    shared: &[[f32; 4]],
    first: usize,
    out: &mut [Quad],
) {
    for (g, (smp, q)) in samples.chunks(8).zip(out.chunks_mut(8)).enumerate() {
        let sh = shared.get(8 * g..(8 * g + smp.len()).min(shared.len())).unwrap_or(&[]);
        footprint_group::<L>(s, smp, colors, sh, first + 8 * g, q);
    }
}

lanes::dispatch! {
    /// [`footprint_lanes`] on the best lanes this CPU has (the same footprints either way).
    fn footprints / footprints_avx2 => footprint_lanes(
        s: &Setup,
        samples: &[u64],
        colors: &[u32],
        shared: &[[f32; 4]],
        first: usize,
        out: &mut [Quad],
    )
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
        self.render_set(&[scene], camera, out);
    }

    fn keeps_frames(&self) -> bool {
        true
    }

    /// Draws the newest of `scenes` (newest first) for `camera` and fills what it leaves
    /// uncovered from the older ones in turn (what each saw that the newest did not), then
    /// from the newest frame's own image (see the module docs).
    fn render_set(&mut self, scenes: &[&Scene], camera: &Camera, out: &mut Image) {
        let Some((&scene, older)) = scenes.split_first() else {
            out.reset_for_unusable(camera, MAX_VIEWPORT);
            return;
        };
        if !begin_frame_unbuilt_ok(scene, camera, out) {
            return;
        }
        let fc = scene.header.camera;
        let fill = self.opts.fill && fc.validate(MAX_VIEWPORT).is_ok();
        // At the frame's own camera the filled image is the frame's own (nothing is a hole
        // there, and footprints do not grow): composited once, then copied.
        if fill && *camera == fc {
            self.cache_own_image(scene);
            if self.frame.pixels.len() == out.pixels.len() {
                out.pixels.copy_from_slice(&self.frame.pixels);
                return;
            }
        }
        let grown = if self.adaptive { self.opts.own_at(warp_angle_deg(&fc, camera)) } else { self.opts.own };
        // Watertight slabs: the newest frame's corners shared between neighbouring pixels.
        let shared = if self.opts.shares_corners() {
            if self.own.prepare(scene, &self.threads) {
                self.own.share_corners(self.opts.watertight, &self.threads);
            }
            core::mem::take(&mut self.own.shared)
        } else {
            Vec::new()
        };
        self.draw(scene, camera, grown, &shared, out, None);
        self.own.shared = shared;
        if !fill && older.is_empty() {
            return;
        }
        let (w, h) = (camera.width as usize, camera.height as usize);
        // The per-pixel passes below run in parallel over runs of rows (each pixel on its own).
        let rows = PIXEL_PASS_ROWS * w;
        self.state.resize(w * h, UNFILLED);
        take_drawn(&self.threads, &mut self.state[..w * h], &self.count, &out.pixels, rows, true);
        // Older frames, newest first, only where nothing is yet (issue 19's lever 3): what
        // each saw that the newest frame did not (see [`Sight`]), so an older sample never
        // stands where the newest frame saw empty space or the same surface.
        let mut older_frames = core::mem::take(&mut self.older);
        older_frames.update(&mut self.own, scene, older, &self.threads);
        let mut scratch = core::mem::replace(&mut self.scratch, Image::new(0, 0));
        let mut tiles = core::mem::take(&mut self.tiles);
        let sets = older_frames.sets(&fc, camera, older);
        // The tiles holding an unfilled pixel, once: a superset of those left after each older
        // frame, so nothing is missed.
        let tiles_w =
            if sets.iter().any(|o| !o.samples.is_empty()) { Holes::mark(&self.state, w, &mut tiles) } else { 0 };
        let holes = tiles_w > 0 && tiles.contains(&1);
        for &o in sets.iter().filter(|o| holes && !o.samples.is_empty()) {
            // The older frame's pixels are read only where it has segments: no clearing.
            scratch.width = camera.width;
            scratch.height = camera.height;
            scratch.pixels.resize(w * h, BACKGROUND);
            let oc = o.header.camera;
            // Older frames grow with their own warp too (measured: without it the MRI's
            // stop-and-go p95 rose from 0.0489 to 0.0545).
            let g = if self.adaptive { self.opts.own_at(warp_angle_deg(&oc, camera)) } else { self.opts.own };
            let state = core::mem::take(&mut self.state);
            self.draw(o, camera, g, &[], &mut scratch, Some(Holes { state: &state, tiles: &tiles, tiles_w }));
            self.state = state;
            take_drawn(&self.threads, &mut self.state[..w * h], &self.count, &scratch.pixels, rows, false);
        }
        self.older = older_frames;
        self.scratch = scratch;
        self.tiles = tiles;
        if fill {
            block_outside_silhouette_on(&mut self.state, w, h, &self.threads);
            // The frame's own image where a hole looks it up: each such pixel's own segments
            // composited on the spot (a few thousand, against a million for the whole image).
            if self.opts.own_pixels() {
                self.own.prepare(scene, &self.threads);
                let (own, colors) = (&self.own, &scene.colors[..]);
                stale_lookup(|i| own.pixel(i, colors), &fc, camera, &mut self.state, &self.threads);
            } else {
                self.cache_own_image(scene);
                let frame = &self.frame.pixels[..];
                stale_lookup(
                    |i| frame.get(i).copied().unwrap_or(BACKGROUND),
                    &fc,
                    camera,
                    &mut self.state,
                    &self.threads,
                );
            }
        }
        let state = &self.state[..];
        self.threads.for_each_chunk(&mut out.pixels, rows, |i, pixels| {
            for (p, &s) in pixels.iter_mut().zip(&state[i * rows..]) {
                if s & FILLED != 0 {
                    *p = s as u32;
                }
            }
        });
    }
}

/// Issue 19's older frames, each reduced to what the newest frame did not see (its *residual*,
/// see the module docs): one definition for [`LayerSplat`] and the GPU's layered splatter,
/// which draws the same sets in the same order (through [`OlderSets`]).
#[derive(Debug, Default)]
pub(crate) struct OlderFrames {
    /// What the newest frame saw.
    sight: Sight,
    /// The newest frame the residuals are for.
    residual_for: Option<SceneId>,
    /// Per older frame (newest first) its residual.
    residuals: Vec<(SceneId, Scene)>,
}

impl OlderFrames {
    /// Brings the residuals up to date for `newest` (whose samples in its own camera are
    /// `own`) and `older` (newest first; none: nothing kept): per older frame the samples the
    /// newest frame did not see.
    ///
    /// When the set has moved on by one frame (the previous newest is now the first older
    /// frame), an older frame's residual is what is left of its last one: what the previous
    /// newest saw of it is already drawn before it, from the previous newest's own samples, so
    /// only the new newest's sight is applied to the (small) residuals, and only the previous
    /// newest is reduced whole. Any other change of the set reduces every older frame whole.
    fn update(&mut self, own: &mut OwnPass, newest: &Scene, older: &[&Scene], threads: &Threads) {
        if older.is_empty() {
            self.residuals.clear();
            return;
        }
        let id = SceneId::of(newest);
        let older = &older[..older.len().min(crate::hole_fill::MAX_FRAMES - 1)];
        let mut fresh = false;
        if self.residual_for != Some(id) {
            let shifted = self.residual_for.is_some() && older.first().map(|o| SceneId::of(o)) == self.residual_for;
            if !shifted {
                self.residuals.clear();
            }
            own.prepare(newest, threads);
            self.sight.update(newest, own, threads);
            self.residual_for = Some(id);
            fresh = true;
        }
        let mut next = Vec::with_capacity(older.len());
        for &o in older {
            let oid = SceneId::of(o);
            let r = match self.residuals.iter().position(|(i, _)| *i == oid) {
                Some(i) if fresh => self.sight.residual(&self.residuals.swap_remove(i).1, threads),
                Some(i) => self.residuals.swap_remove(i).1,
                // An inconsistent scene adds nothing.
                None if !crate::frame_setup::unbuilt_ok(o) => Scene::empty(&o.header),
                None => self.sight.residual(o, threads),
            };
            next.push((oid, r));
        }
        self.residuals = next;
    }

    /// The scenes to draw after the newest (whose frame camera is `fc`) for `camera`, in
    /// order, each into the pixels still empty: the residuals of [`OlderFrames::update`]'s
    /// `older`. Turned more than 90° from the newest frame's view, its footprints face away
    /// and draw nothing: what it saw is then no reason to leave an older sample out, so the
    /// older frames are drawn whole.
    fn sets<'a>(&'a self, fc: &Camera, camera: &Camera, older: &[&'a Scene]) -> Vec<&'a Scene> {
        let back_facing = (fc.target - fc.eye).dot(camera.target - camera.eye) < 0.0;
        if back_facing {
            older.iter().take(self.residuals.len()).copied().filter(|o| crate::frame_setup::unbuilt_ok(o)).collect()
        } else {
            self.residuals.iter().map(|(_, r)| r).collect()
        }
    }
}

/// What a renderer other than [`LayerSplat`] (the GPU's `splat-layers-gpu`) needs to draw
/// issue 19's older frames as [`LayerSplat::render_set`] does: the scenes to draw after the
/// newest, in order, each into the pixels still empty, made by the CPU's own code (the
/// residuals are made once per arriving frame, on the CPU, and are small).
#[derive(Debug)]
pub struct OlderSets {
    frames: OlderFrames,
    own: OwnPass,
    threads: Threads,
}

impl OlderSets {
    /// On `threads` threads (0: one per core).
    pub fn new(threads: usize) -> Self {
        OlderSets { frames: OlderFrames::default(), own: OwnPass::default(), threads: Threads::new(threads) }
    }

    /// The scenes to draw for `camera` after `newest`, given the `older` frames kept (newest
    /// first; at most `hole_fill::MAX_FRAMES − 1` are used) and whether holes are filled
    /// (`fill`, [`LayerOptions::fill`]): each older frame's residual (or the older frames whole
    /// when the camera has turned more than 90° from the newest frame's view). Empty where
    /// [`LayerSplat::render_set`] draws no older frame (none kept; or the frame's own image at
    /// its own camera, with the fill), and then, as there, the residuals are not touched: the
    /// same calls leave both renderers with the same residuals. The caller has checked that
    /// `newest` and `camera` can be drawn.
    pub fn sets<'a>(&'a mut self, newest: &Scene, older: &[&'a Scene], camera: &Camera, fill: bool) -> Vec<&'a Scene> {
        let fc = newest.header.camera;
        let fill = fill && fc.validate(MAX_VIEWPORT).is_ok();
        if (fill && *camera == fc) || (!fill && older.is_empty()) {
            return Vec::new();
        }
        self.frames.update(&mut self.own, newest, older, &self.threads);
        self.frames.sets(&fc, camera, older)
    }
}

/// A scene's copy without its LBVH.
fn unbuilt_copy(s: &Scene) -> Scene {
    Scene { header: s.header, deq: s.deq, samples: s.samples.clone(), colors: s.colors.clone(), nodes: Vec::new() }
}

/// What a frame saw, per pixel of its camera: the view depth beyond which a point is hidden
/// from it (behind the farthest segment of a pixel at least [`RESIDUAL_OPAQUE`] opaque, by
/// [`RESIDUAL_TOLERANCE`] pixels at that depth), infinite where the pixel is empty or seen
/// through (4 bytes per pixel, reused frame to frame).
#[derive(Debug, Default)]
pub struct Sight {
    proj: Option<Proj>,
    w: usize,
    h: usize,
    hidden: Vec<f32>,
}

impl Sight {
    /// Records what `scene` saw (nothing for an unusable camera: then every sample of an older
    /// frame counts as unseen), from its samples grouped by pixel of its own camera (`own`,
    /// after [`OwnPass::group`]), in parallel over rows.
    fn update(&mut self, scene: &Scene, own: &OwnPass, threads: &Threads) {
        self.proj = None;
        let Some((proj, w, h)) = own.proj else { return };
        if own.start.len() != w * h + 1 {
            return;
        }
        (self.w, self.h) = (w, h);
        self.proj = Some(proj);
        self.hidden.resize(w * h, 0.0);
        // z > zmax + tol·z / px  ⟺  z > zmax / (1 − tol / px).
        let k = 1.0 / (1.0 - RESIDUAL_TOLERANCE / proj.px_x).max(1e-3);
        let (start, grouped, at, colors) = (&own.start[..], &own.grouped[..], &own.at[..], &scene.colors[..]);
        threads.for_each_chunk(&mut self.hidden, RASTER_BAND * w, |band, hidden| {
            let first = band * RASTER_BAND * w;
            for (j, out) in hidden.iter_mut().enumerate() {
                let (a, b) = (start[first + j] as usize, start[first + j + 1] as usize);
                // The pixel's transmittance and farthest depth, its samples in their order.
                let (mut trans, mut far) = (1.0f32, f32::NEG_INFINITY);
                for &key in &grouped[a..b] {
                    let id = key as u32 as usize;
                    if let (Some(&c), Some(&p)) = (colors.get(id), at.get(id)) {
                        trans *= 1.0 - (c >> 24) as f32 / 255.0;
                        far = far.max(f32::from_bits(p as u32));
                    }
                }
                *out = if 1.0 - trans >= RESIDUAL_OPAQUE && far.is_finite() { far * k } else { f32::INFINITY };
            }
        });
    }

    /// The samples of `o` this frame did not see: those outside its view, and those behind
    /// the farthest segment of an opaque pixel (by more than [`RESIDUAL_TOLERANCE`] pixels at
    /// their depth). A sample on a ray that found nothing, or within the span of what the ray
    /// saw, or behind what it saw through, is left out: the newest frame knows better there.
    fn residual(&self, o: &Scene, threads: &Threads) -> Scene {
        let Some(proj) = self.proj else {
            return unbuilt_copy(o);
        };
        let (w, h) = (self.w, self.h);
        let mut keep = vec![0u8; o.samples.len()];
        threads.for_each_chunk(&mut keep, QUAD_CHUNK, |chunk, keep| {
            let first = chunk * QUAD_CHUNK;
            let (mut idx, mut zs) = ([NO_PIXEL; QUAD_CHUNK], [0f32; QUAD_CHUNK]);
            let n = keep.len();
            project(&proj, (w, h), &o.deq, &o.samples[first..first + n], &mut idx[..n], &mut zs[..n], &mut []);
            for ((k, &i), &z) in keep.iter_mut().zip(&idx).zip(&zs) {
                // Outside the view (no pixel): unseen.
                *k = self.hidden.get(i as usize).is_none_or(|&hz| z > hz) as u8;
            }
        });
        let n = keep.iter().filter(|&&k| k != 0).count();
        let mut r = Scene {
            header: o.header,
            deq: o.deq,
            samples: Vec::with_capacity(n),
            colors: Vec::with_capacity(n),
            nodes: Vec::new(),
        };
        for ((&k, &smp), &c) in keep.iter().zip(&o.samples).zip(&o.colors) {
            if k != 0 {
                r.samples.push(smp);
                r.colors.push(c);
            }
        }
        r
    }
}

/// The shared corners of the segments (the `LIST` nearest of each pixel) of the pixel rows
/// `rows` (of a `w × h` frame whose view depths, grouped by pixel front to back, are `zs`, pixel
/// `i`'s from `start[i]`), into `part` (the rows' segments, the first at `base`), slab by slab
/// as a stencil over dense rows: per slab `j` three rows of depths (NaN where a pixel has no
/// `j`-th segment, and one NaN on each side), and per pixel the eight neighbours' slab-`j`
/// depths that lie within `per_px · (z + z')` of its own joining each corner they touch: the
/// corner is the mean of the four pixels around it that join (its own always does), summed in
/// one fixed order (rows, then columns) by every pixel around it. Straight-line float code over
/// rows, which the compiler vectorizes.
#[inline(always)]
fn band_corners_lanes<L: Lanes>(
    start: &[u32],
    zs: Depths,
    (w, h): (usize, usize),
    per_px: f32,
    rows: core::ops::Range<usize>,
    part: &mut [[f32; 4]],
    base: usize,
) {
    let wp = w + 2;
    let count = |i: usize| (start[i + 1] - start[i]) as usize;
    let (r0, r1) = (rows.start.saturating_sub(1), (rows.end + 1).min(h));
    // At most `LIST` slabs (a pixel keeps no more segments than that; a frame that puts more
    // samples on one pixel gets no shared corners for them, and no larger buffers).
    let k = (r0 * w..r1 * w).map(count).max().unwrap_or(0).min(LIST);
    if k == 0 || rows.is_empty() {
        return;
    }
    // Row `y`'s slab depths, `k` padded rows of `wp` (all NaN outside the frame).
    let fill = |y: usize, slabs: &mut [f32]| {
        slabs.fill(f32::NAN);
        if y >= h {
            return;
        }
        for x in 0..w {
            let i = y * w + x;
            let a = start[i] as usize;
            for j in 0..count(i).min(k) {
                slabs[j * wp + x + 1] = zs.get(a + j);
            }
        }
    };
    let (mut up, mut mid, mut down) = (vec![f32::NAN; k * wp], vec![f32::NAN; k * wp], vec![f32::NAN; k * wp]);
    if rows.start > 0 {
        fill(rows.start - 1, &mut up);
    }
    fill(rows.start, &mut mid);
    // Per slab its four corner rows.
    let mut out = vec![0f32; 4 * k * w];
    for y in rows {
        fill(y + 1, &mut down);
        // Only the span of the row's pixels with segments, and as many slabs as they have.
        let row = &start[y * w..=(y + 1) * w];
        let Some(x0) = (0..w).find(|&x| row[x + 1] > row[x]) else {
            core::mem::swap(&mut up, &mut mid);
            core::mem::swap(&mut mid, &mut down);
            continue;
        };
        let x1 = (0..w).rfind(|&x| row[x + 1] > row[x]).unwrap_or(x0) + 1;
        let kr = (x0..x1).map(|x| (row[x + 1] - row[x]) as usize).max().unwrap_or(0).min(k);
        for (j, o) in out.chunks_exact_mut(4 * w).take(kr).enumerate() {
            let (u, m, d) = (&up[j * wp..(j + 1) * wp], &mid[j * wp..(j + 1) * wp], &down[j * wp..(j + 1) * wp]);
            let (o0, rest) = o.split_at_mut(w);
            let (o1, rest) = rest.split_at_mut(w);
            let (o2, o3) = rest.split_at_mut(w);
            let (u, m, d) = (&u[x0..x1 + 2], &m[x0..x1 + 2], &d[x0..x1 + 2]);
            slab_row_corners(u, m, d, per_px, [&mut o0[x0..x1], &mut o1[x0..x1], &mut o2[x0..x1], &mut o3[x0..x1]]);
        }
        // Each pixel's segments, in order.
        for x in x0..x1 {
            let i = y * w + x;
            let a = start[i] as usize - base;
            for (j, c) in part[a..a + count(i).min(k)].iter_mut().enumerate() {
                let o = &out[4 * j * w..];
                *c = [o[x], o[w + x], o[2 * w + x], o[3 * w + x]];
            }
        }
        core::mem::swap(&mut up, &mut mid);
        core::mem::swap(&mut mid, &mut down);
    }
}

lanes::dispatch! {
    /// [`band_corners_lanes`] compiled for the best vector instructions this CPU has (the
    /// stencil is plain float code the compiler vectorizes; the same values either way).
    fn band_corners / band_corners_avx2 => band_corners_lanes(
        start: &[u32],
        zs: Depths,
        size: (usize, usize),
        per_px: f32,
        rows: core::ops::Range<usize>,
        part: &mut [[f32; 4]],
        base: usize,
    )
}

/// Where the corner stencil reads the segments' view depths, in pixel order.
#[derive(Clone, Copy, Debug)]
enum Depths<'a> {
    /// As they are (a frame not in the server's order, once sorted: `OwnPass::zs`).
    Plain(&'a [f32]),
    /// In the low bits of `OwnPass::at` (a frame in the server's order: pixel order is the
    /// samples' own).
    Packed(&'a [u64]),
}

impl Depths<'_> {
    /// The depth at position `g`.
    #[inline(always)]
    fn get(&self, g: usize) -> f32 {
        match self {
            Depths::Plain(z) => z[g],
            Depths::Packed(a) => f32::from_bits(a[g] as u32),
        }
    }
}

/// One slab's corners along a row (see [`band_corners`]): `u`, `m`, `d` the rows above, at and
/// below (padded, `w + 2` long), the four corners in the order [`footprint_group`] visits them
/// (the steps `(sx, sy)` = (−1, −1), (1, −1), (1, 1), (−1, 1) along the source camera's right
/// and up): each corner's four pixels are those of the 3 × 3 block around the pixel (row-major,
/// 4 its own) that the step puts `(sx > 0)` columns and `(sy < 0)` rows into it.
#[inline(always)]
fn slab_row_corners(u: &[f32], m: &[f32], d: &[f32], per_px: f32, out: [&mut [f32]; 4]) {
    let w = out[0].len();
    let (u, m, d) = (&u[..w + 2], &m[..w + 2], &d[..w + 2]);
    let [o0, o1, o2, o3] = out;
    let (o1, o2, o3) = (&mut o1[..w], &mut o2[..w], &mut o3[..w]);
    for x in 0..w {
        let z = m[x + 1];
        let (z0, j0) = join(u[x], z, per_px);
        let (z1, j1) = join(u[x + 1], z, per_px);
        let (z2, j2) = join(u[x + 2], z, per_px);
        let (z3, j3) = join(m[x], z, per_px);
        let (z5, j5) = join(m[x + 2], z, per_px);
        let (z6, j6) = join(d[x], z, per_px);
        let (z7, j7) = join(d[x + 1], z, per_px);
        let (z8, j8) = join(d[x + 2], z, per_px);
        // The corners' pixels: [3, 4, 6, 7], [4, 5, 7, 8], [1, 2, 4, 5], [0, 1, 3, 4].
        o0[x] = corner(z3 + z + z6 + z7, j3 + 1.0 + j6 + j7);
        o1[x] = corner(z + z5 + z7 + z8, 1.0 + j5 + j7 + j8);
        o2[x] = corner(z1 + z2 + z + z5, j1 + j2 + 1.0 + j5);
        o3[x] = corner(z0 + z1 + z3 + z, j0 + j1 + j3 + 1.0);
    }
}

/// A neighbour's slab depth `v` where it joins a corner of the segment at depth `z` (else 0),
/// and 1 where it does (else 0); NaN (no such segment) never joins.
#[inline(always)]
fn join(v: f32, z: f32, per_px: f32) -> (f32, f32) {
    let j = (v - z).abs() <= per_px * (v + z);
    (if j { v } else { 0.0 }, if j { 1.0 } else { 0.0 })
}

/// The shared corner from the sum and number of the depths that join it: their mean, NaN unless
/// at least two join and the mean is a positive finite depth.
#[inline(always)]
fn corner(sum: f32, count: f32) -> f32 {
    let zc = sum / count;
    if count >= 2.0 && zc.is_finite() && zc > 0.0 {
        zc
    } else {
        f32::NAN
    }
}

/// The slab-shared corner depths of layered frames, as [`LayerSplat`] finds them for its newest
/// frame (see [`LayerOptions::watertight`]): what the GPU layered splatter uploads beside the
/// samples, so both sides draw the same footprints. Keeps its buffers from frame to frame.
#[derive(Debug, Default)]
pub struct SlabCorners {
    own: OwnPass,
    threads: Threads,
}

impl SlabCorners {
    /// A finder on `threads` threads (0: one per core).
    pub fn new(threads: usize) -> Self {
        SlabCorners { own: OwnPass::default(), threads: Threads::new(threads) }
    }

    /// Per sample of `scene` (by id) the source depths of its footprint's corners shared within
    /// `tol` source pixels, NaN where not shared; empty for a `tol` ≤ 0 or an unusable camera.
    pub fn corners(&mut self, scene: &Scene, tol: f32) -> &[[f32; 4]] {
        if !(tol > 0.0) {
            return &[];
        }
        if !self.own.prepare(scene, &self.threads) {
            return &[];
        }
        self.own.share_corners(tol, &self.threads);
        &self.own.shared
    }
}

/// The pixel index of a point outside the view.
const NO_PIXEL: u32 = u32::MAX;

/// A frame's samples in its own camera, once per frame: per sample its pixel and view depth
/// (what [`Sight`] records) and its depth key, and the keys grouped by pixel (a counting sort).
/// At its own camera every footprint of the default width is exactly its source pixel, so the
/// frame's own composited image is each pixel's group sorted and composited: the image the
/// footprints would draw there, without setting up, binning and rasterizing a million of them
/// (measured: the first draw after a frame arrives, `docs/perf.md`). Memory: 20 bytes per
/// sample and 4 per pixel, reused frame to frame.
#[derive(Debug, Default)]
struct OwnPass {
    /// The scene projected.
    of: Option<SceneId>,
    /// Its camera's projection and viewport (`None`: unusable camera, nothing projected).
    proj: Option<(Proj, usize, usize)>,
    /// Per sample `pixel << 32 | view depth bits` (pixel [`NO_PIXEL`] outside the view).
    at: Vec<u64>,
    /// Per sample its depth key ([`key`]: squared distance from the eye, id).
    keys: Vec<u64>,
    /// The keys grouped by pixel (in sample order within a pixel) and, per pixel, where its
    /// group starts (one more entry: the end of the last).
    grouped: Vec<u64>,
    start: Vec<u32>,
    /// Per sample (by id) the source depths of its footprint's four corners where they are
    /// shared with the same slab of neighbouring pixels (NaN: not shared), and the tolerance
    /// they were found with ([`OwnPass::share_corners`]; `None`: not found for this scene).
    shared: Vec<[f32; 4]>,
    shared_tol: Option<f32>,
    /// Scratch: the groups sorted by depth key, their view depths and corners in that order.
    sorted: Vec<u64>,
    zs: Vec<f32>,
    corners: Vec<[f32; 4]>,
}

impl OwnPass {
    /// Projects `scene`'s samples into its own camera (nothing if that was the last scene).
    fn project(&mut self, scene: &Scene, threads: &Threads) {
        let id = SceneId::of(scene);
        if self.of == Some(id) {
            return;
        }
        self.of = Some(id);
        // What was found for the last scene goes with it.
        self.start.clear();
        self.shared.clear();
        self.shared_tol = None;
        let fc = scene.header.camera;
        let n = scene.samples.len();
        if fc.validate(MAX_VIEWPORT).is_err() {
            self.proj = None;
            self.at.clear();
            self.at.resize(n, (NO_PIXEL as u64) << 32);
            return;
        }
        let (w, h) = (fc.width as usize, fc.height as usize);
        let proj = Proj::new(&View::new(&fc));
        self.proj = Some((proj, w, h));
        self.at.resize(n, 0);
        self.keys.resize(n, 0);
        let (samples, deq) = (&scene.samples[..], &scene.deq);
        threads.for_each_chunk_pair(&mut self.at[..n], &mut self.keys[..n], QUAD_CHUNK, |chunk, at, keys| {
            let first = chunk * QUAD_CHUNK;
            let m = at.len();
            let (mut idx, mut zs, mut d2) = ([NO_PIXEL; QUAD_CHUNK], [0f32; QUAD_CHUNK], [0f32; QUAD_CHUNK]);
            project(&proj, (w, h), deq, &samples[first..first + m], &mut idx[..m], &mut zs[..m], &mut d2[..m]);
            for (k, (a, key_out)) in at.iter_mut().zip(keys.iter_mut()).enumerate() {
                *a = (idx[k] as u64) << 32 | zs[k].to_bits() as u64;
                *key_out = key(d2[k], (first + k) as u32);
            }
        });
    }

    /// [`OwnPass::project`] and [`OwnPass::group`] (each done once per scene); false for an
    /// unusable camera.
    fn prepare(&mut self, scene: &Scene, threads: &Threads) -> bool {
        self.project(scene, threads);
        self.group(threads)
    }

    /// Pixel `i`'s own segments composited over the background (after [`OwnPass::group`]; the
    /// background for a pixel without segments or outside the view).
    fn pixel(&self, i: usize, colors: &[u32]) -> u32 {
        let (Some(&a), Some(&b)) = (self.start.get(i), self.start.get(i + 1)) else { return BACKGROUND };
        let Some(keys) = self.grouped.get(a as usize..b as usize) else { return BACKGROUND };
        let n = keys.len();
        if n <= LIST {
            let mut list = [0u64; LIST];
            list[..n].copy_from_slice(keys);
            sort_keys(&mut list[..n]);
            composite_keys(&list[..n], colors)
        } else {
            // More segments than a list keeps: the nearest LIST, as the lists keep.
            let mut long = keys.to_vec();
            long.sort_unstable();
            composite_keys(&long[..LIST], colors)
        }
    }

    /// Finds [`OwnPass::shared`] (after [`OwnPass::group`]): the `j`-th nearest segment of a
    /// pixel belongs to slab `j`, and a corner of its footprint is shared with the slab-`j`
    /// segments of the (up to three) other pixels around that corner whose depth differs from
    /// its own by at most `tol` source pixels at that depth (a depth step larger than that is an
    /// edge, not a surface). A shared corner sits at the mean depth of the segments sharing it,
    /// summed in the same order by every pixel around it, so neighbouring footprints of one
    /// slab meet exactly: no overlap counts a semi-transparent slab twice and no gap lets the
    /// slab behind show (the contour lines of `docs/results.md`). At the frame's own camera a
    /// corner projects onto its pixel corner at any depth, so the frame's image is unchanged.
    fn share_corners(&mut self, tol: f32, threads: &Threads) {
        let Some((proj, w, h)) = self.proj else { return };
        if self.start.len() != w * h + 1 || self.shared_tol == Some(tol) {
            return;
        }
        self.shared_tol = Some(tol);
        let n = self.at.len();
        let total = self.grouped.len();
        // The bands of rows and where their samples end in the grouped order.
        let ends: Vec<usize> =
            (0..h.div_ceil(CORNER_BAND)).map(|b| self.start[((b + 1) * CORNER_BAND).min(h) * w] as usize).collect();
        let start = &self.start[..];
        // A server's frame comes pixel by pixel, each pixel's segments front to back: then the
        // grouped order is the samples' own and the corners are written straight by id.
        let in_order = total == n
            && self.at.windows(2).zip(self.keys.windows(2)).all(|(a, k)| {
                let (p, q) = (a[0] >> 32, a[1] >> 32);
                p < q || (p == q && k[0] < k[1])
            });
        // 1. Otherwise each pixel's segments sorted front to back.
        if !in_order {
            self.sorted.clear();
            self.sorted.extend_from_slice(&self.grouped);
            threads.for_each_part(&mut self.sorted, &ends, |b, part| {
                let base = start[b * CORNER_BAND * w] as usize;
                for i in b * CORNER_BAND * w..((b + 1) * CORNER_BAND).min(h) * w {
                    let g = &mut part[start[i] as usize - base..start[i + 1] as usize - base];
                    if g.len() <= LIST {
                        sort_keys(g);
                    } else {
                        g.sort_unstable();
                    }
                }
            });
            // Their view depths in that order (in the server's order they are read where they
            // are, in `at`).
            self.zs.resize(total, 0.0);
            let (order, at) = (&self.sorted[..], &self.at[..]);
            threads.for_each_chunk(&mut self.zs, QUAD_CHUNK, |c, zs| {
                for (z, &k) in zs.iter_mut().zip(&order[c * QUAD_CHUNK..]) {
                    *z = at.get(k as u32 as usize).map_or(f32::NAN, |&a| f32::from_bits(a as u32));
                }
            });
        }
        // 2. Each segment's corners, in that order.
        let corners = if in_order { &mut self.shared } else { &mut self.corners };
        // Not shared (NaN) unless found: set per band, in parallel, not in one serial pass.
        corners.resize(total, [f32::NAN; 4]);
        let zs = if in_order { Depths::Packed(&self.at) } else { Depths::Plain(&self.zs) };
        let per_px = tol.max(0.0) * 0.5 / proj.px_y;
        threads.for_each_part(corners, &ends, |b, part| {
            part.fill([f32::NAN; 4]);
            let base = start[b * CORNER_BAND * w] as usize;
            let rows = b * CORNER_BAND..((b + 1) * CORNER_BAND).min(h);
            band_corners(start, zs, (w, h), per_px, rows, part, base);
        });
        if in_order {
            return;
        }
        // 3. By sample id.
        self.shared.clear();
        self.shared.resize(n, [f32::NAN; 4]);
        for (&k, c) in self.sorted.iter().zip(&self.corners) {
            if let Some(s) = self.shared.get_mut(k as u32 as usize) {
                *s = *c;
            }
        }
    }

    /// Groups the keys by pixel (after [`OwnPass::project`]); false for an unusable camera.
    fn group(&mut self, threads: &Threads) -> bool {
        let Some((_, w, h)) = self.proj else { return false };
        if !self.start.is_empty() {
            return true;
        }
        // A server's frame comes in pixel order (samples outside the view, `NO_PIXEL`, can
        // only come last then): the groups are the keys in their order, and a pixel's start is
        // the number of samples on earlier pixels, found per band of pixels in parallel.
        let pixel = |a: u64| (a >> 32) as usize;
        if self.at.windows(2).all(|p| pixel(p[0]) <= pixel(p[1])) {
            self.start.resize(w * h + 1, 0);
            let at = &self.at[..];
            let valid = at.partition_point(|&a| pixel(a) < w * h);
            threads.for_each_chunk(&mut self.start[..w * h], PIXEL_PASS_ROWS * w, |band, start| {
                let p0 = band * PIXEL_PASS_ROWS * w;
                let mut j = at[..valid].partition_point(|&a| pixel(a) < p0);
                for (i, s) in start.iter_mut().enumerate() {
                    while j < valid && pixel(at[j]) < p0 + i {
                        j += 1;
                    }
                    *s = j as u32;
                }
            });
            self.start[w * h] = valid as u32;
            self.grouped.clear();
            self.grouped.extend_from_slice(&self.keys[..valid]);
            return true;
        }
        self.group_any_order();
        true
    }

    /// [`OwnPass::group`] for samples in any order: counts, then their running sums (each
    /// pixel's end), then every key placed backwards at its pixel's end, so the ends become the
    /// starts and a pixel keeps its samples' order.
    fn group_any_order(&mut self) {
        let Some((_, w, h)) = self.proj else { return };
        self.start.clear();
        self.start.resize(w * h + 1, 0);
        for &a in &self.at {
            if let Some(c) = self.start.get_mut((a >> 32) as usize) {
                *c += 1;
            }
        }
        let mut sum = 0u32;
        for c in &mut self.start[..w * h] {
            sum += *c;
            *c = sum;
        }
        self.start[w * h] = sum;
        self.grouped.resize(sum as usize, 0);
        for (&a, &k) in self.at.iter().zip(&self.keys).rev() {
            let i = (a >> 32) as usize;
            if i < w * h {
                self.start[i] -= 1;
                self.grouped[self.start[i] as usize] = k;
            }
        }
    }
}

impl LayerSplat {
    /// Makes [`LayerSplat::frame`] the frame's own composited image, unless it already is.
    fn cache_own_image(&mut self, scene: &Scene) {
        if self.frame_of == Some(SceneId::of(scene)) {
            return;
        }
        let mut frame = core::mem::replace(&mut self.frame, Image::new(0, 0));
        if begin_frame_unbuilt_ok(scene, &scene.header.camera, &mut frame) {
            self.own_image(scene, &mut frame);
        }
        self.frame = frame;
        self.frame_of = Some(SceneId::of(scene));
    }

    /// The frame's own composited image into `out` (sized to the frame's camera and cleared
    /// to the background): with the default footprint width, each pixel's own segments sorted
    /// and composited ([`OwnPass`]); with another width, the footprints drawn at the frame's
    /// camera.
    fn own_image(&mut self, scene: &Scene, out: &mut Image) {
        let fc = scene.header.camera;
        if !self.opts.own_pixels() {
            self.draw(scene, &fc, self.opts.own, &[], out, None);
            return;
        }
        if !self.own.prepare(scene, &self.threads) {
            return;
        }
        let w = fc.width as usize;
        let (own, colors) = (&self.own, &scene.colors[..]);
        self.threads.for_each_chunk(&mut out.pixels, RASTER_BAND * w, |band, px| {
            let first = band * RASTER_BAND * w;
            for (j, p) in px.iter_mut().enumerate() {
                *p = own.pixel(first + j, colors);
            }
        });
    }
}

lanes::dispatch! {
    /// [`project_lanes`] on the best lanes this CPU has (the same values either way).
    fn project / project_avx2 => project_lanes(
        p: &Proj,
        size: (usize, usize),
        deq: &Dequantizer,
        samples: &[u64],
        idx: &mut [u32],
        zs: &mut [f32],
        d2: &mut [f32],
    )
}

/// Per packed sample its pixel index in a `w × h` view (`size`) with projection `p` ([`NO_PIXEL`]
/// outside it) and its view depth: [`pixel`] eight samples at a time (bit for bit: the same
/// decode and `f32` operations in the same order). Unless `d2` is empty, also its squared
/// distance from the eye, as the footprint set-up computes it for the depth key.
#[inline(always)]
fn project_lanes<L: Lanes>(
    p: &Proj,
    (w, h): (usize, usize),
    deq: &Dequantizer,
    samples: &[u64],
    idx: &mut [u32],
    zs: &mut [f32],
    d2: &mut [f32],
) {
    let with_d2 = !d2.is_empty();
    let eye = [p.eye.x, p.eye.y, p.eye.z];
    let (u, v, a) = (p.u, p.v, p.w);
    for (g, ((s, ix), zo)) in samples.chunks(8).zip(idx.chunks_mut(8)).zip(zs.chunks_mut(8)).enumerate() {
        let [x, y, z, _] = match <&[u64; 8]>::try_from(s) {
            Ok(s8) => L::decode8(deq, eye, s8),
            Err(_) => lanes::decode_scalar(deq, eye, s),
        };
        if with_d2 {
            let dd = (x * x + y * y + z * z).to_array();
            for (o, &v) in d2[g * 8..].iter_mut().zip(&dd[..s.len()]) {
                *o = v;
            }
        }
        let zc = x * L::splat(a.x) + y * L::splat(a.y) + z * L::splat(a.z);
        let uc = x * L::splat(u.x) + y * L::splat(u.y) + z * L::splat(u.z);
        let vc = x * L::splat(v.x) + y * L::splat(v.y) + z * L::splat(v.z);
        let inv = L::splat(1.0) / zc;
        let px = uc * inv * L::splat(p.px_x) + L::splat(p.half_w);
        let py = L::splat(p.half_h) - vc * inv * L::splat(p.px_y);
        let (za, xa, ya) = (zc.to_array(), px.to_array(), py.to_array());
        for l in 0..ix.len() {
            let (zl, xl, yl) = (za[l], xa[l], ya[l]);
            let inside = zl > 1e-6 && xl >= 0.0 && yl >= 0.0 && (xl as usize) < w && (yl as usize) < h;
            ix[l] = if inside { (yl as usize * w + xl as usize) as u32 } else { NO_PIXEL };
            zo[l] = zl;
        }
    }
}

/// The pixel (of a `w × h` view with projection `p`) and view depth of point `c`, if in the
/// view: the scalar reference of [`project_lanes`], and the layered tracer's projection
/// (`layer_trace`), so both renderers give a sample the same source pixel.
pub(crate) fn pixel(p: &Proj, w: usize, h: usize, c: Vec3) -> Option<(usize, f32)> {
    let r = c - p.eye;
    let z = r.dot(p.w);
    if !(z > 1e-6) {
        return None;
    }
    let inv = 1.0 / z;
    let (x, y) = (r.dot(p.u) * inv * p.px_x + p.half_w, p.half_h - r.dot(p.v) * inv * p.px_y);
    (x >= 0.0 && y >= 0.0 && (x as usize) < w && (y as usize) < h).then(|| (y as usize * w + x as usize, z))
}

impl LayerSplat {
    /// Composites `scene` for `camera` into `out` (already sized and cleared to the background)
    /// with footprints of half side [`LayerOptions::own`] source pixels, `grown` for samples at
    /// least [`LayerOptions::grow_min_alpha`] opaque; leaves `count` with each output pixel's
    /// number of segments.
    fn draw(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        grown: f32,
        shared: &[[f32; 4]],
        out: &mut Image,
        only: Option<Holes>,
    ) {
        let own = self.opts.own;
        let (w, h) = (camera.width as usize, camera.height as usize);
        let deq = &scene.deq;
        let cap = LIST;
        self.count.clear();
        self.count.resize(w * h, 0);
        let mut setup = Setup::new(camera, &scene.header.camera, deq, own, grown, self.opts.grow_min_alpha);
        setup.water_ratio = self.opts.water_ratio;
        let colors = &scene.colors[..];
        // 1. Every sample's footprint in the new image (in parallel over samples, eight at a
        // time in SIMD lanes). Every footprint is written (NONE where there is none): no
        // clearing pass.
        // The buffers only grow (an older frame's few samples between two newest frames must not
        // make the next draw rewrite them whole).
        let n = scene.samples.len();
        if self.quads.len() < n {
            self.quads.resize(n, Quad::NONE);
        }
        if self.bands.len() < n {
            self.bands.resize(n, NO_BANDS);
        }
        let samples = &scene.samples[..];
        self.threads.for_each_chunk_pair(
            &mut self.quads[..n],
            &mut self.bands[..n],
            QUAD_CHUNK,
            |chunk, quads, bands| {
                let first = chunk * QUAD_CHUNK;
                let sh = shared.get(first..(first + quads.len()).min(shared.len())).unwrap_or(&[]);
                footprints(&setup, &samples[first..first + quads.len()], colors, sh, first, quads);
                if let Some(holes) = only {
                    for q in quads.iter_mut().filter(|q| q.x[0] <= q.x[1] && !holes.near(q)) {
                        *q = Quad::NONE;
                    }
                }
                // The bands each footprint touches, for the binning below (4 bytes a sample to
                // read there instead of the 64-byte footprint).
                for (b, q) in bands.iter_mut().zip(quads.iter()) {
                    *b = if q.x[0] <= q.x[1] {
                        (q.y[0] as usize / RASTER_BAND) as u32 | ((q.y[1] as usize / RASTER_BAND) as u32) << 16
                    } else {
                        NO_BANDS
                    };
                }
            },
        );
        // 2. Each footprint to the row bands it touches: one task per thread, each over its
        // run of footprints into its own lists, so band `b`'s footprints are the tasks' lists
        // `b` one after the other (in the footprints' order).
        let bands = h.div_ceil(RASTER_BAND);
        let tasks = self.threads.count().max(1);
        self.bins.resize_with(tasks, Vec::new);
        let per_task = n.div_ceil(tasks).max(1);
        let footprint_bands = &self.bands[..n];
        self.threads.for_each_chunk(&mut self.bins, 1, |t, task| {
            let bins = &mut task[0];
            bins.resize_with(bands, Vec::new);
            bins.iter_mut().for_each(Vec::clear);
            let first = (t * per_task).min(n);
            for (id, &b) in footprint_bands[first..(first + per_task).min(n)].iter().enumerate() {
                for bin in &mut bins[(b & 0xffff) as usize..=(b >> 16) as usize] {
                    bin.push((first + id) as u32);
                }
            }
        });
        // 3. Per band of rows: its pixels take their footprints' keys, then the band is
        // composited while its lists are still in the cache (in parallel over bands: the lists
        // keep the nearest keys whatever the order, so the image does not depend on it). The
        // lists live in a band-sized buffer per thread, not one for the whole image.
        let (quads, bins) = (&self.quads[..], &self.bins[..]);
        let band = |b: usize, px: &mut [u32], count: &mut [u8]| {
            // A band no footprint touches keeps its pixels (their counts are 0): an older
            // frame's few samples touch few bands.
            if bins.iter().all(|task| task[b].is_empty()) {
                return;
            }
            LISTS.with_borrow_mut(|keys| {
                if keys.len() < RASTER_BAND * w * cap {
                    keys.resize(RASTER_BAND * w * cap, u64::MAX);
                }
                let y_lo = b * RASTER_BAND;
                for list in bins.iter().map(|task| &task[b]) {
                    for (k, &id) in list.iter().enumerate() {
                        // The footprints are read in their order but scattered over ~60 MB:
                        // the one PREFETCH ahead is asked for now.
                        if let Some(&ahead) = list.get(k + PREFETCH) {
                            prefetch(&quads[ahead as usize]);
                        }
                        let q = &quads[id as usize];
                        let (ya, yb) = ((q.y[0] as usize).max(y_lo), (q.y[1] as usize).min(y_lo + RASTER_BAND - 1));
                        for y in ya..=yb {
                            let row = q.row(y as f32 + 0.5);
                            for x in q.x[0] as usize..=q.x[1] as usize {
                                let px = x as f32 + 0.5;
                                if row.covers(px) && only.is_none_or(|h| h.state[y * w + x] == UNFILLED) {
                                    let i = (y - y_lo) * w + x;
                                    insert(&mut keys[i * cap..(i + 1) * cap], &mut count[i], q.key);
                                }
                            }
                        }
                    }
                }
                for (i, &n) in count.iter().enumerate().filter(|(_, &n)| n > 1) {
                    sort_keys(&mut keys[i * cap..i * cap + n as usize]);
                }
                composite_run(keys, count, colors, px);
            })
        };
        let count = &mut self.count[..];
        self.threads.for_each_chunk_pair(&mut out.pixels, count, RASTER_BAND * w, band);
    }
}

/// Where an older frame may still draw: the fill state of every pixel and which tiles of
/// [`HOLE_TILE`]² pixels hold an unfilled one (footprints touching none are skipped whole).
#[derive(Clone, Copy)]
struct Holes<'a> {
    state: &'a [u64],
    tiles: &'a [u8],
    tiles_w: usize,
}

/// The side of [`Holes`]' tiles, pixels.
const HOLE_TILE: usize = 8;

impl Holes<'_> {
    /// Marks in `tiles` the tiles of a `w`-wide image holding an unfilled pixel.
    fn mark(state: &[u64], w: usize, tiles: &mut Vec<u8>) -> usize {
        let tw = w.div_ceil(HOLE_TILE);
        let th = (state.len() / w.max(1)).div_ceil(HOLE_TILE);
        tiles.clear();
        tiles.resize(tw * th, 0);
        for (y, row) in state.chunks_exact(w.max(1)).enumerate() {
            for (x, _) in row.iter().enumerate().filter(|(_, &s)| s == UNFILLED) {
                tiles[(y / HOLE_TILE) * tw + x / HOLE_TILE] = 1;
            }
        }
        tw
    }

    /// Whether footprint `q`'s bounds touch a tile with an unfilled pixel.
    #[inline]
    fn near(&self, q: &Quad) -> bool {
        let (x0, x1) = (q.x[0] as usize / HOLE_TILE, q.x[1] as usize / HOLE_TILE);
        let (y0, y1) = (q.y[0] as usize / HOLE_TILE, q.y[1] as usize / HOLE_TILE);
        (y0..=y1)
            .any(|ty| self.tiles.get(ty * self.tiles_w + x0..=ty * self.tiles_w + x1).is_some_and(|r| r.contains(&1)))
    }
}

/// How many footprints ahead the rasterizer asks for a footprint's cache line.
const PREFETCH: usize = 24;

/// Asks the CPU to bring `q`'s cache line closer (a hint: no effect on any result).
#[inline(always)]
fn prefetch(q: &Quad) {
    crate::lanes::prefetch(core::slice::from_ref(q));
}

thread_local! {
    /// The per-pixel key lists of the band a thread is drawing (`RASTER_BAND` rows × `LIST`).
    static LISTS: core::cell::RefCell<Vec<u64>> = const { core::cell::RefCell::new(Vec::new()) };
}

#[cfg(test)]
mod tests {
    use super::*;
    #[test]
    fn the_row_test_is_the_pixel_test() {
        // Quadrilaterals around random points, pixel centres on and near their edges (exact
        // zeros of an edge function included), and non-finite coefficients.
        let mut x = 0x9E37_79B9u32;
        let mut rnd = move || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            (x >> 8) as f32 / (1 << 24) as f32
        };
        let mut tested = [0usize; 2];
        for i in 0..20_000 {
            let (cx, cy) = (rnd() * 64.0, rnd() * 64.0);
            let q: [(f32, f32); 4] = core::array::from_fn(|k| {
                let a = (k as f32 + rnd() * 0.8) * core::f32::consts::FRAC_PI_2;
                let r = 0.5 + rnd() * 3.0;
                (cx + r * a.cos(), cy + r * a.sin())
            });
            let mut quad = Quad { edges: coefficient_major(edges_of(q)), ..Quad::NONE };
            if i % 97 == 0 {
                quad.edges[(i / 97) % 3][i % 4] = [f32::NAN, f32::INFINITY, -f32::INFINITY][i % 3];
            }
            for _ in 0..16 {
                let (px, py) = ((cx + rnd() * 8.0 - 4.0).floor() + 0.5, (cy + rnd() * 8.0 - 4.0).floor() + 0.5);
                let want = quad.covers(px, py);
                assert_eq!(quad.row(py).covers(px), want, "{quad:?} at ({px}, {py})");
                tested[want as usize] += 1;
            }
            // A corner itself: every edge through it is zero there.
            let (px, py) = q[0];
            assert_eq!(quad.row(py).covers(px), quad.covers(px, py));
        }
        assert!(tested[0] > 10_000 && tested[1] > 10_000, "{tested:?}");
    }

    /// The footprints of a synthetic surface (plus random samples, some behind the eye, some
    /// degenerate) for `frame_camera`, set up for `camera` by the scalar reference and by the
    /// lanes kernel on both lane types: the same quads bit for bit.
    #[test]
    fn lanes_match_the_scalar_footprints() {
        use crate::synthetic::{depth_image_frame, SplitMix64};
        let frame = depth_image_frame(96, 1.0, 7);
        let fc = frame.header.camera;
        let deq = Dequantizer::new(frame.header.bounds, frame.header.radius_unit);
        let mut samples = frame.samples.clone();
        let mut rng = SplitMix64(3);
        samples.extend((0..300).map(|_| rng.next_u64()));
        let colors: Vec<u32> = (0..samples.len()).map(|_| rng.next_u64() as u32).collect();
        let same = |a: &Quad, b: &Quad| {
            a.key == b.key
                && a.x == b.x
                && a.y == b.y
                && (a.x[0] > a.x[1]
                    || a.edges.iter().flatten().zip(b.edges.iter().flatten()).all(|(p, q)| p.to_bits() == q.to_bits()))
        };
        let mut drawn = 0;
        for (deg, grown, size) in
            [(0.0, 0.5, (96, 96)), (10.0, 1.3, (96, 96)), (35.0, 2.0, (131, 77)), (170.0, 0.5, (96, 96))]
        {
            let mut camera = fc.orbit(deg, deg * 0.3);
            (camera.width, camera.height) = size;
            let mut setup = Setup::new(&camera, &fc, &deq, 0.5, grown, 230);
            // Without shared corners, and with some (each sample's own depth, a little off per
            // corner, some corners and samples not shared), at two area ratios.
            let none: Vec<[f32; 4]> = Vec::new();
            let some: Vec<[f32; 4]> = samples
                .iter()
                .enumerate()
                .map(|(i, &smp)| {
                    let z = (deq.center(smp) - setup.src_eye).dot(setup.src_w);
                    core::array::from_fn(|k| match (i + k) % 5 {
                        0 => f32::NAN,
                        j => z * (1.0 + 0.01 * j as f32 - 0.02),
                    })
                })
                .map(|c| if rng.next_u64().is_multiple_of(4) { [f32::NAN; 4] } else { c })
                .collect();
            for (shared, ratio) in [(&none, 1.0), (&some, 1.0), (&some, 0.0), (&some, 1.5)] {
                setup.water_ratio = ratio;
                let reference: Vec<Quad> = samples
                    .iter()
                    .enumerate()
                    .map(|(i, &smp)| setup.quad(smp, &colors, i, shared.get(i).copied()))
                    .collect();
                drawn += reference.iter().filter(|q| q.x[0] <= q.x[1]).count();
                let mut portable = vec![Quad::NONE; samples.len()];
                footprint_lanes::<wide::f32x8>(&setup, &samples, &colors, shared, 0, &mut portable);
                assert!(reference.iter().zip(&portable).all(|(a, b)| same(a, b)), "portable lanes differ at {deg}°");
                #[cfg(target_arch = "x86_64")]
                if lanes::use_avx2() {
                    let mut avx = vec![Quad::NONE; samples.len()];
                    // SAFETY: the CPU has AVX2 (`use_avx2`).
                    unsafe { footprints_avx2(&setup, &samples, &colors, shared, 0, &mut avx) };
                    assert!(reference.iter().zip(&avx).all(|(a, b)| same(a, b)), "AVX2 lanes differ at {deg}°");
                }
                if shared.is_empty() {
                    continue;
                }
                // The shared corners change footprints (else this compares nothing new).
                let plain: Vec<Quad> =
                    samples.iter().enumerate().map(|(i, &smp)| setup.quad(smp, &colors, i, None)).collect();
                let changed = plain.iter().zip(&reference).filter(|(a, b)| !same(a, b)).count();
                assert!(ratio > 1.0 || changed > samples.len() / 10, "{changed} footprints changed at {deg}°");
            }
        }
        assert!(drawn > 6 * frame.samples.len(), "too few footprints drawn: {drawn}");
    }

    #[test]
    fn lanes_project_like_the_scalar_reference() {
        use crate::synthetic::{depth_image_frame, SplitMix64};
        let frame = depth_image_frame(64, 1.0, 5);
        let deq = Dequantizer::new(frame.header.bounds, frame.header.radius_unit);
        let mut samples = frame.samples.clone();
        let mut rng = SplitMix64(11);
        samples.extend((0..301).map(|_| rng.next_u64()));
        let mut inside = 0;
        for (deg, size) in [(0.0, (64, 64)), (25.0, (97, 53)), (180.0, (64, 64))] {
            let mut camera = frame.header.camera.orbit(deg, deg * 0.2);
            (camera.width, camera.height) = size;
            let p = Proj::new(&View::new(&camera));
            let (w, h) = (size.0 as usize, size.1 as usize);
            let reference: Vec<(u32, Option<u32>)> = samples
                .iter()
                .map(|&smp| match pixel(&p, w, h, deq.center(smp)) {
                    Some((i, z)) => (i as u32, Some(z.to_bits())),
                    None => (NO_PIXEL, None),
                })
                .collect();
            inside += reference.iter().filter(|r| r.0 != NO_PIXEL).count();
            let check = |idx: &[u32], zs: &[f32], what: &str| {
                for (k, (&i, &z)) in idx.iter().zip(zs).enumerate() {
                    assert_eq!(i, reference[k].0, "{what} at {deg}°, sample {k}");
                    if let Some(bits) = reference[k].1 {
                        assert_eq!(z.to_bits(), bits, "{what} depth at {deg}°, sample {k}");
                    }
                }
            };
            let (mut idx, mut zs) = (vec![0; samples.len()], vec![0.0; samples.len()]);
            let mut d2 = vec![0.0; samples.len()];
            project_lanes::<wide::f32x8>(&p, (w, h), &deq, &samples, &mut idx, &mut zs, &mut d2);
            check(&idx, &zs, "portable lanes");
            for (k, &smp) in samples.iter().enumerate() {
                let n = deq.center(smp) - p.eye;
                assert_eq!(d2[k].to_bits(), (n.x * n.x + n.y * n.y + n.z * n.z).to_bits(), "distance of {k}");
            }
            let mut d2_dispatched = vec![0.0; samples.len()];
            project(&p, (w, h), &deq, &samples, &mut idx, &mut zs, &mut d2_dispatched);
            check(&idx, &zs, "dispatched lanes");
            assert!(d2.iter().zip(&d2_dispatched).all(|(a, b)| a.to_bits() == b.to_bits()));
        }
        assert!(inside > frame.samples.len(), "too few samples in view: {inside}");
    }

    /// A frame in pixel order is grouped by the parallel path exactly as the counting sort
    /// groups it, with samples outside the view (last, as the projection sorts them) or not.
    #[test]
    fn pixel_order_groups_like_the_counting_sort() {
        use crate::synthetic::{frame_from_points, Point};
        let frame = two_slab_frame();
        // A small frame in pixel order whose last two samples lie behind the eye.
        let camera = Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y, 40.0, 8, 8);
        let basis = camera.ray_basis();
        let mut pts: Vec<Point> = (0..64)
            .map(|i| Point {
                center: camera.eye + basis.dir(i % 8, i / 8) * 2.0,
                radius: 0.01,
                color: [0.2, 0.2, 0.2, 0.5],
            })
            .collect();
        pts.extend((0..2).map(|k| Point {
            center: camera.eye + Vec3::new(0.0, 0.0, 1.0 + k as f32),
            radius: 0.01,
            color: [0.1; 4],
        }));
        let away = frame_from_points(&pts, camera);
        for (f, n) in [(&frame, 1), (&frame, 3), (&away, 2)] {
            let threads = Threads::new(n);
            let scene = crate::route::unbuilt_scene(f);
            let mut own = OwnPass::default();
            own.project(&scene, &threads);
            assert!(own.at.windows(2).all(|p| p[0] >> 32 <= p[1] >> 32), "the frame is in pixel order");
            assert!(own.group(&threads));
            let (start, grouped) = (own.start.clone(), own.grouped.clone());
            own.group_any_order();
            assert_eq!(own.start, start);
            assert_eq!(own.grouped, grouped);
            // The frame behind the eye keeps its 64 samples in view, not the two behind.
            let in_view = if n == 2 { 64 } else { f.samples.len() };
            assert_eq!(grouped.len(), in_view);
        }
    }

    /// A layer of two semi-transparent slabs on a tilted, gently curved surface, one segment
    /// per slab on every pixel's ray of a 96² camera.
    fn two_slab_frame() -> volwarp_core::wire::Frame {
        use crate::synthetic::{frame_from_points, Point};
        let camera = Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y, 40.0, 96, 96);
        let basis = camera.ray_basis();
        let eye = camera.eye;
        let mut pts = Vec::new();
        for y in 0..96 {
            for x in 0..96 {
                let d = basis.dir(x, y);
                // The surface z = 0.5·x + 0.1·y² (tilted about 27° to the view, curved).
                let (mut t, mut hit) = (0.0, None);
                for _ in 0..40 {
                    let p = eye + d * t;
                    let f = p.z - (0.5 * p.x + 0.1 * p.y * p.y);
                    if f.abs() < 1e-6 {
                        hit = Some(t);
                        break;
                    }
                    t += f / (-d.z + 0.5 * d.x + 0.2 * p.y * d.y);
                }
                let Some(t) = hit else { continue };
                for (k, dt) in [0.0f32, 0.02].into_iter().enumerate() {
                    let a = 0.4;
                    let c = if k == 0 { [0.35, 0.2, 0.1, a] } else { [0.1, 0.3, 0.35, a] };
                    pts.push(Point { center: eye + d * (t + dt), radius: 0.01, color: c });
                }
            }
        }
        frame_from_points(&pts, camera)
    }

    /// Drawn 12° around the frame's camera, the slabs' footprints cover every pixel inside
    /// the layer once per slab with shared corners; without, neighbouring footprints of one
    /// slab overlap (a pixel takes it twice) and part (it misses it).
    #[test]
    fn shared_corners_make_each_slab_watertight() {
        let frame = two_slab_frame();
        let scene = crate::route::unbuilt_scene(&frame);
        let cam = frame.header.camera.orbit(12.0, 4.0);
        let mut out = Image::new(0, 0);
        let mut counts = Vec::new();
        for tol in [0.0, 3.0] {
            let opts = LayerOptions { fill: false, watertight: tol, water_ratio: 0.0, ..LayerOptions::DEFAULT };
            let mut r = LayerSplat::with_options(1, opts);
            r.render(&scene, &cam, &mut out);
            // Pixels inside the layer: between the first and last covered pixel of their row
            // and of their column, two pixels in.
            let (w, h) = (96usize, 96usize);
            let c = |x: usize, y: usize| r.count[y * w + x];
            let span = |v: Vec<u8>| {
                let first = v.iter().position(|&n| n > 0).unwrap_or(v.len());
                let last = v.iter().rposition(|&n| n > 0).unwrap_or(0);
                (first + 2, last.saturating_sub(2))
            };
            let mut hist = [0usize; 4];
            for y in 0..h {
                let (x0, x1) = span((0..w).map(|x| c(x, y)).collect());
                for x in x0..=x1.min(w - 1) {
                    let (y0, y1) = span((0..h).map(|yy| c(x, yy)).collect());
                    if (y0..=y1).contains(&y) {
                        hist[(c(x, y) as usize).min(3)] += 1;
                    }
                }
            }
            counts.push(hist);
        }
        // The same frame with its samples in reverse order (each pixel's segments back to
        // front): the corners are found by sorting and moved to the samples' ids, and the
        // image is the same.
        let mut reversed = frame.clone();
        reversed.samples.reverse();
        reversed.colors.reverse();
        let opts = LayerOptions { fill: false, watertight: 3.0, water_ratio: 0.0, ..LayerOptions::DEFAULT };
        let (mut a, mut b) = (Image::new(0, 0), Image::new(0, 0));
        LayerSplat::with_options(1, opts).render(&scene, &cam, &mut a);
        LayerSplat::with_options(1, opts).render(&crate::route::unbuilt_scene(&reversed), &cam, &mut b);
        let same = a.pixels.iter().zip(&b.pixels).filter(|(p, q)| p == q).count();
        assert!(same * 1000 >= a.pixels.len() * 999, "{same} of {} pixels equal in reverse order", a.pixels.len());
        let (plain, tight) = (counts[0], counts[1]);
        let inside: usize = tight.iter().sum();
        assert!(inside > 3000, "the layer covers too little: {tight:?}");
        // Watertight: each pixel inside takes both slabs, once each.
        assert!(tight[2] * 1000 >= inside * 998, "shared corners: {tight:?} (count 0, 1, 2, 3+)");
        // Plain footprints: overlaps and gaps.
        assert!(plain[1] + plain[3] > inside / 50, "plain footprints: {plain:?}");
    }

    /// The shared corners as the definition states them, one segment and corner at a time:
    /// the four pixels around the corner in row-then-column order, each joining with its
    /// `j`-th segment where that lies within the tolerance of the segment's own depth.
    fn corners_reference(own: &OwnPass, tol: f32) -> Vec<[f32; 4]> {
        let (proj, w, h) = own.proj.unwrap();
        let per_px = tol * 0.5 / proj.px_y;
        // Each pixel's depths front to back.
        let depths = |i: usize| -> Vec<f32> {
            let mut keys = own.grouped[own.start[i] as usize..own.start[i + 1] as usize].to_vec();
            keys.sort_unstable();
            keys.iter().map(|&k| f32::from_bits(own.at[k as u32 as usize] as u32)).collect()
        };
        let mut out = vec![[f32::NAN; 4]; own.at.len()];
        for y in 0..h {
            for x in 0..w {
                let mut keys = own.grouped[own.start[y * w + x] as usize..own.start[y * w + x + 1] as usize].to_vec();
                keys.sort_unstable();
                for (j, &key) in keys.iter().enumerate() {
                    let z = f32::from_bits(own.at[key as u32 as usize] as u32);
                    for (k, (sx, sy)) in [(-1i64, -1i64), (1, -1), (1, 1), (-1, 1)].into_iter().enumerate() {
                        let (cx, cy) = (x as i64 + (sx > 0) as i64, y as i64 + (sy < 0) as i64);
                        let (mut sum, mut count) = (0.0f32, 0.0f32);
                        for (px, py) in [(cx - 1, cy - 1), (cx, cy - 1), (cx - 1, cy), (cx, cy)] {
                            if px < 0 || py < 0 || px >= w as i64 || py >= h as i64 {
                                continue;
                            }
                            let d = depths(py as usize * w + px as usize);
                            let own_pixel = (px, py) == (x as i64, y as i64);
                            if let Some(&v) = d.get(j) {
                                if own_pixel || (v - z).abs() <= per_px * (v + z) {
                                    sum += v;
                                    count += 1.0;
                                }
                            }
                        }
                        out[key as u32 as usize][k] = corner(sum, count);
                    }
                }
            }
        }
        out
    }

    /// The row stencil (on both lane types, on one thread and in parallel over bands of rows)
    /// finds exactly the corners of the plain definition, on a frame in the server's order and
    /// on the same frame shuffled.
    #[test]
    fn shared_corners_match_the_plain_definition() {
        let frame = two_slab_frame();
        let mut shuffled = frame.clone();
        let mut rng = crate::synthetic::SplitMix64(5);
        for i in (1..shuffled.samples.len()).rev() {
            let j = (rng.next_u64() % (i as u64 + 1)) as usize;
            shuffled.samples.swap(i, j);
            shuffled.colors.swap(i, j);
        }
        for (f, threads) in [(&frame, 1), (&shuffled, 1), (&frame, 2), (&shuffled, 3)] {
            let threads = Threads::new(threads);
            let scene = crate::route::unbuilt_scene(f);
            for tol in [1.5, 6.0] {
                let mut own = OwnPass::default();
                own.project(&scene, &threads);
                assert!(own.group(&threads));
                own.share_corners(tol, &threads);
                let reference = corners_reference(&own, tol);
                let same = |a: &[[f32; 4]], b: &[[f32; 4]]| {
                    a.len() == b.len()
                        && a.iter().flatten().zip(b.iter().flatten()).all(|(p, q)| p.to_bits() == q.to_bits())
                };
                assert!(same(&own.shared, &reference), "tolerance {tol}");
                let shared = own.shared.iter().flatten().filter(|z| z.is_finite()).count();
                assert!(shared > own.shared.len(), "too few shared corners: {shared}");
                // The portable instance of the stencil, row band by row band (a frame in the
                // server's order: the corners are written by id).
                if core::ptr::eq(f, &frame) {
                    let (proj, w, h) = own.proj.unwrap();
                    let mut portable = vec![[f32::NAN; 4]; own.at.len()];
                    band_corners_lanes::<wide::f32x8>(
                        &own.start,
                        Depths::Packed(&own.at),
                        (w, h),
                        tol * 0.5 / proj.px_y,
                        0..h,
                        &mut portable,
                        0,
                    );
                    assert!(same(&portable, &reference), "portable, tolerance {tol}");
                }
            }
        }
    }

    /// A frame that puts thousands of samples on one pixel: no panic, no buffer sized by them,
    /// shared corners only for the nearest `LIST` of them, and an image without NaN colors.
    #[test]
    fn a_crowded_pixel_shares_only_its_nearest_slabs() {
        let mut frame = two_slab_frame();
        let (s0, c0) = (frame.samples[1000], frame.colors[1000]);
        let at = 1001;
        for _ in 0..5000 {
            frame.samples.insert(at, s0);
            frame.colors.insert(at, c0);
        }
        let scene = crate::route::unbuilt_scene(&frame);
        let threads = Threads::new(1);
        let mut own = OwnPass::default();
        own.project(&scene, &threads);
        assert!(own.group(&threads));
        own.share_corners(3.0, &threads);
        let (_, w, _) = own.proj.unwrap();
        let crowded = (0..own.start.len() - 1).max_by_key(|&i| own.start[i + 1] - own.start[i]).unwrap();
        let (a, e) = (own.start[crowded] as usize, own.start[crowded + 1] as usize);
        assert!(e - a > 5000, "{} samples on the crowded pixel {crowded} of a {w}-wide frame", e - a);
        let mut keys = own.grouped[a..e].to_vec();
        keys.sort_unstable();
        let far = keys[LIST..].iter().filter(|&&k| own.shared[k as u32 as usize].iter().any(|z| z.is_finite())).count();
        assert_eq!(far, 0, "segments past the nearest {LIST} share corners");
        let mut img = Image::new(0, 0);
        let cam = frame.header.camera.orbit(10.0, 0.0);
        LayerSplat::new(1).render(&scene, &cam, &mut img);
        assert!(img.pixels.iter().any(|&p| p != BACKGROUND));
    }
}
