//! Footprints: a sample's source-pixel quadrilateral on the plane through its centre facing the
//! new eye, projected into the new camera ([`Setup`], one definition of the figures for the CPU
//! and GPU layered renderers; [`Quad`], the CPU rasterizer's edge functions), set up in SIMD
//! lanes.

use crate::key_list::key;
use crate::lanes::{self, Lanes};
use crate::sphere_splat::View;
use volwarp_core::sample::Dequantizer;
use volwarp_core::{Camera, Vec3};
use wide::f32x4;

/// A sample's footprint in the new image: the edge functions of its quadrilateral, depth key
/// and pixel bounds (`x[0] > x[1]`: none). 64 bytes, one cache line: the footprints of a 1024²
/// layered frame are about a million, set up in SIMD lanes and read back by the rasterizer.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
pub(crate) struct Quad {
    /// The four edges' coefficients `A`, `B`, `C` (`edges[k][e]`: coefficient `k` of edge
    /// `e`, so each coefficient of the four edges is one 4-lane vector): a pixel centre
    /// `(px, py)` is inside where `A·px + B·py + C ≥ 0` for all four.
    pub(crate) edges: [[f32; 4]; 3],
    pub(crate) key: u64,
    pub(crate) x: [u16; 2],
    pub(crate) y: [u16; 2],
}

impl Quad {
    pub(crate) const NONE: Quad = Quad { edges: [[0.0; 4]; 3], key: u64::MAX, x: [1, 0], y: [1, 0] };

    /// Whether pixel centre `(px, py)` is inside (no branch per edge): the reference of
    /// [`Quad::row`]'s test.
    #[cfg(test)]
    pub(crate) fn covers(&self, px: f32, py: f32) -> bool {
        let e = &self.edges;
        let f = |k: usize| e[0][k] * px + e[1][k] * py + e[2][k];
        (f(0) >= 0.0) & (f(1) >= 0.0) & (f(2) >= 0.0) & (f(3) >= 0.0)
    }

    /// The four edges at pixel row `py`, for [`QuadRow::covers`].
    #[inline(always)]
    pub(crate) fn row(&self, py: f32) -> QuadRow {
        let [a, b, c] = self.edges.map(f32x4::from);
        QuadRow { a, bpy: b * f32x4::splat(py), c }
    }
}

/// A footprint's four edge functions along one pixel row, as 4-lane vectors (one lane per
/// edge): the same operations as [`Quad::covers`] in the same order (`(A·px + B·py) + C`, no
/// fused multiply-add), so the same result, with one vector multiply, two adds and one
/// comparison per pixel.
#[derive(Clone, Copy)]
pub(crate) struct QuadRow {
    pub(crate) a: f32x4,
    pub(crate) bpy: f32x4,
    pub(crate) c: f32x4,
}

impl QuadRow {
    /// Whether pixel centre `px` of the row is inside.
    #[inline(always)]
    pub(crate) fn covers(&self, px: f32) -> bool {
        let f = (self.a * f32x4::splat(px) + self.bpy) + self.c;
        f.simd_ge(f32x4::ZERO).to_bitmask() == 0xF
    }
}

/// Four edges' `[A, B, C]` as [`Quad::edges`] keeps them (coefficient-major).
#[cfg(test)]
pub(crate) fn coefficient_major(e: [[f32; 3]; 4]) -> [[f32; 4]; 3] {
    core::array::from_fn(|k| core::array::from_fn(|i| e[i][k]))
}

/// The edge functions of the quadrilateral with corners `q` (in order around it), signed by
/// its orientation: `sign · ((b − a) × (p − a)) ≥ 0` for each edge `a → b`.
#[cfg(test)]
pub(crate) fn edges_of(q: [(f32, f32); 4]) -> [[f32; 3]; 4] {
    let area = (q[1].0 - q[0].0) * (q[2].1 - q[0].1) - (q[2].0 - q[0].0) * (q[1].1 - q[0].1);
    let sign = if area < 0.0 { -1.0 } else { 1.0 };
    core::array::from_fn(|e| {
        let (a, b) = (q[e], q[(e + 1) & 3]);
        let (ex, ny) = ((b.0 - a.0) * sign, (a.1 - b.1) * sign);
        // A = −(b − a).y, B = (b − a).x, C = −(A·a.x + B·a.y) written as (b − a).y·a.x − B·a.y.
        [ny, ex, (b.1 - a.1) * sign * a.0 - ex * a.1]
    })
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
    pub(crate) fn image(&self, c: Vec3) -> Option<(f32, f32)> {
        if !(c.z > 1e-6) {
            return None;
        }
        let inv = 1.0 / c.z;
        let (x, y) = (c.x * inv * self.px_x + self.half_w, self.half_h - c.y * inv * self.px_y);
        (x.is_finite() && y.is_finite()).then_some((x, y))
    }
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
    /// The most a sample's optical depth is scaled where it takes its slab's shared corners
    /// ([`drawn_color`]; at most 1: not scaled).
    pub opacity_limit: f32,
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
            opacity_limit: 1.0,
            last_x: camera.width as f32 - 1.0,
            last_y: camera.height as f32 - 1.0,
            view,
        }
    }

    /// How much the corners of sample `id` scale: `grow_ratio` where its color is at least
    /// `min_alpha` opaque, else 1.
    #[inline(always)]
    pub(crate) fn scale(&self, colors: &[u32], id: usize) -> f32 {
        let opaque = colors.get(id).is_some_and(|&c| (c >> 24) as u8 >= self.min_alpha);
        if opaque && self.grow_ratio > 1.0 {
            self.grow_ratio
        } else {
            1.0
        }
    }

    /// The footprint of sample `id` (packed `sample`) and the color it is drawn with, one at a
    /// time: the reference the lanes kernel [`footprint_group`] computes eight at a time, bit
    /// for bit.
    #[cfg(test)]
    pub(crate) fn quad(&self, sample: u64, colors: &[u32], id: usize, shared: Option<[f32; 4]>) -> (Quad, u32) {
        let color = colors.get(id).copied().unwrap_or(0);
        let view = &self.view;
        let c = self.deq.center(sample);
        let rel = c - self.src_eye;
        let z = rel.dot(self.src_w);
        // The plane's normal (not normalised: only ratios of dot products with it are used).
        let n = c - view.eye;
        let dist2 = n.length_squared();
        if !(z > 0.0 && dist2 > 0.0) {
            return (Quad::NONE, color);
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
        let (chosen, depth) = match (water, plane) {
            (Some(w), Some(p)) if area(&w) >= area(&p) * self.water_ratio => (Some(w), area(&p) / area(&w)),
            (Some(w), None) => (Some(w), 1.0),
            (_, p) => (p, 1.0),
        };
        let color = drawn_color(color, depth, self.opacity_limit);
        // Its corners, in order around it, in the new camera's image.
        let Some([q0, q1, q2, q3]) = chosen else {
            return (Quad::NONE, color);
        };
        let x0 = q0.0.min(q1.0).min(q2.0).min(q3.0);
        let x1 = q0.0.max(q1.0).max(q2.0).max(q3.0);
        let y0 = q0.1.min(q1.1).min(q2.1).min(q3.1);
        let y1 = q0.1.max(q1.1).max(q2.1).max(q3.1);
        // Pixel centres x + ½ within [x0, x1].
        let (xa, xb) = ((x0 - 0.5).ceil().max(0.0), (x1 - 0.5).floor().min(self.last_x));
        let (ya, yb) = ((y0 - 0.5).ceil().max(0.0), (y1 - 0.5).floor().min(self.last_y));
        if !(xa <= xb && ya <= yb) {
            return (Quad::NONE, color);
        }
        // Squared distance: the same order, no square root. (Bounds are within the viewport,
        // at most `MAX_VIEWPORT` < 2¹⁶.)
        let quad = Quad {
            edges: coefficient_major(edges_of([q0, q1, q2, q3])),
            key: key(dist2, id as u32),
            x: [xa as u16, xb as u16],
            y: [ya as u16, yb as u16],
        };
        (quad, color)
    }
}

/// [`Setup::quad`] for eight samples at once: the same operations in the same order on lanes,
/// so the same footprints and drawn colors bit for bit (the test
/// `lanes_match_the_scalar_footprints`). `first` is the id of `samples[0]`; `samples` holds at
/// most eight; each one's color as drawn goes to `drawn`.
#[inline(always)]
pub(crate) fn footprint_group<L: Lanes>(
    s: &Setup,
    samples: &[u64],
    colors: &[u32],
    shared: &[[f32; 4]],
    first: usize,
    out: &mut [Quad],
    drawn: &mut [u32],
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
    // On its slab's shared corners a sample carries its optical depth over the footprint's
    // area on screen: the plane's area over the slab's (1 where it is drawn on the plane).
    let depth = (use_w & okp).select(ap / aw, sp(1.0));
    // The colors as drawn, `drawn_color`'s operations on lanes (its `2^n` and the cases it
    // returns the color unchanged lane by lane).
    let n = samples.len().min(8);
    let (mut c8, mut a8, mut t8) = ([0u32; 8], [1.0f32; 8], [0.0f32; 8]);
    for i in 0..n {
        let c = colors.get(first + i).copied().unwrap_or(0);
        c8[i] = c;
        a8[i] = (c >> 24) as f32 * (1.0 / 255.0);
        t8[i] = LOG2_TRANSMITTANCE[(c >> 24) as usize];
    }
    let limit = s.opacity_limit;
    let lo = 1.0 / limit;
    let y = depth.max(sp(lo)).min(sp(limit)) * L::new(t8);
    let below = y.to_array();
    let y = y.min(sp(127.0));
    let whole = y.floor();
    let series = exp2_series_lanes(y - whole).to_array();
    let (whole, d) = (whole.to_array(), depth.to_array());
    let mut e8 = [0.0f32; 8];
    for i in 0..n {
        e8[i] = if below[i] >= -126.0 { series[i] * pow2(whole[i]) } else { 0.0 };
    }
    let scale = (sp(1.0) - L::new(e8)) / L::new(a8);
    let mut levels = [[0u32; 8]; 4];
    for (k, level) in levels.iter_mut().enumerate() {
        let ch = L::new(core::array::from_fn(|i| ((c8[i] >> (8 * k)) & 0xff) as f32));
        let v = (ch * scale + sp(0.5)).min(sp(255.0)).to_array();
        for i in 0..n {
            level[i] = (v[i] as u32) << (8 * k);
        }
    }
    for (i, a) in drawn.iter_mut().enumerate().take(n) {
        let c = c8[i];
        *a =
            if drawn_unchanged(c, d[i], limit) { c } else { levels[0][i] | levels[1][i] | levels[2][i] | levels[3][i] };
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

/// Every footprint of `samples` (ids from `first`) into `out` and its color as drawn into
/// `drawn`, eight at a time.
#[inline(always)]
pub(crate) fn footprint_lanes<L: Lanes>(
    s: &Setup,
    samples: &[u64],
    colors: &[u32],
    shared: &[[f32; 4]],
    first: usize,
    out: &mut [Quad],
    drawn: &mut [u32],
) {
    for (g, ((smp, q), d)) in samples.chunks(8).zip(out.chunks_mut(8)).zip(drawn.chunks_mut(8)).enumerate() {
        let sh = shared.get(8 * g..(8 * g + smp.len()).min(shared.len())).unwrap_or(&[]);
        footprint_group::<L>(s, smp, colors, sh, first + 8 * g, q, d);
    }
}

lanes::dispatch! {
    /// [`footprint_lanes`] on the best lanes this CPU has (the same footprints either way).
    fn footprints_on_best_lanes / footprints_avx2 => footprint_lanes(
        s: &Setup,
        samples: &[u64],
        colors: &[u32],
        shared: &[[f32; 4]],
        first: usize,
        out: &mut [Quad],
        drawn: &mut [u32],
    )
}

/// `footprints` for the other steps of the layered model and the rasterizer (the dispatch
/// macro's functions are private to their module).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(crate) fn footprints(
    s: &Setup,
    samples: &[u64],
    colors: &[u32],
    shared: &[[f32; 4]],
    first: usize,
    out: &mut [Quad],
    drawn: &mut [u32],
) {
    footprints_on_best_lanes(s, samples, colors, shared, first, out, drawn)
}

/// `log2(x)` of a positive normal `x` with additions, multiplications and one division only
/// (the GPU layered splatter computes it with the same operations in the same order, so both
/// draw the same colors; within 2·10⁻⁶ of `log2`): the exponent from the bits, the mantissa
/// `m` in `[1, 2)` by `2/ln 2 · atanh((m − 1)/(m + 1))`, its series to the ninth power.
pub const fn log2_poly(x: f32) -> f32 {
    let bits = x.to_bits();
    let e = ((bits >> 23) & 0xff) as i32 - 127;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000);
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let p = s * (2.885_39 + s2 * (0.961_796_7 + s2 * (0.577_078 + s2 * (0.412_198_5 + s2 * 0.320_598_8))));
    e as f32 + p
}

/// `2^y` with additions and multiplications only ([`log2_poly`]'s counterpart, the same on the
/// GPU, whose shader spells `ln 2` as the literal 0.6931472, the same `f32`; within 10⁻⁶
/// relative): the integer part into the exponent bits, the fraction by the series of
/// `e^(f·ln 2)` to the seventh power; 0 below the smallest normal.
pub fn exp2_poly(y: f32) -> f32 {
    if !(y >= -126.0) {
        return 0.0;
    }
    let y = y.min(127.0);
    // `y.floor()` without the library call (the baseline x86-64 has no rounding instruction):
    // the same value for every `y` in [−126, 127].
    let t = y as i32 as f32;
    let n = if t > y { t - 1.0 } else { t };
    exp2_series(y - n) * pow2(n)
}

/// `2^n` for a whole `n` in [−126, 127], from the exponent bits.
#[inline]
fn pow2(n: f32) -> f32 {
    f32::from_bits(((n as i32 + 127) as u32) << 23)
}

/// [`exp2_series`] on lanes: the same operations in the same order.
#[inline(always)]
fn exp2_series_lanes<L: Lanes>(f: L) -> L {
    let sp = L::splat;
    sp(1.0)
        + f * (sp(core::f32::consts::LN_2)
            + f * (sp(0.240_226_5)
                + f * (sp(0.055_504_11)
                    + f * (sp(0.009_618_129)
                        + f * (sp(0.001_333_355) + f * (sp(0.000_154_035_3) + f * sp(0.000_015_252_73)))))))
}

/// `2^f` for `f` in [0, 1): the series of `e^(f·ln 2)` to the seventh power ([`exp2_poly`]'s).
#[inline]
fn exp2_series(f: f32) -> f32 {
    1.0 + f
        * (core::f32::consts::LN_2
            + f * (0.240_226_5
                + f * (0.055_504_11
                    + f * (0.009_618_129 + f * (0.001_333_355 + f * (0.000_154_035_3 + f * 0.000_015_252_73))))))
}

/// Per 8-bit opacity `o`, [`log2_poly`] of the transmittance `1 − o/255` ([`drawn_color`]'s
/// first step, the same `f32` operations evaluated once at compile time: the same values).
const LOG2_TRANSMITTANCE: [f32; 256] = {
    let mut t = [0.0f32; 256];
    let mut o = 1;
    while o < 255 {
        t[o] = log2_poly(1.0 - o as f32 * (1.0 / 255.0));
        o += 1;
    }
    t
};

/// Where [`drawn_color`] returns the color as it is: `depth` 1 or not finite, a limit of at most
/// 1, a transparent or opaque sample.
#[inline]
fn drawn_unchanged(c: u32, depth: f32, limit: f32) -> bool {
    let o = c >> 24;
    !(limit > 1.0) || depth == 1.0 || !depth.is_finite() || o == 0 || o == 255
}

/// The color sample color `c` (premultiplied RGBA8) is drawn with where its footprint stands
/// for `depth` times the optical depth of its own ray: a slab seen more edge-on than from the
/// frame's camera is crossed along a longer path (its footprint on the shared corners covers
/// less of the screen than the plane's, and `depth` = the plane's area over the slab's is more
/// than 1), one turned towards the eye along a shorter one. The opacity `α` becomes
/// `1 − (1 − α)^depth`, `depth` clamped to `[1/limit, limit]`, and the color channels scale
/// with it (premultiplied, so each stays at most the opacity; rounded to the nearest level, so
/// a `depth` within a rounding error of 1 changes nothing). `depth` 1, a limit of at most 1,
/// or a transparent or opaque sample: `c` itself, so a frame drawn at its own camera is its own
/// image.
pub fn drawn_color(c: u32, depth: f32, limit: f32) -> u32 {
    let b = c.to_le_bytes();
    if drawn_unchanged(c, depth, limit) {
        return c;
    }
    let d = depth.clamp(1.0 / limit, limit);
    let a = b[3] as f32 * (1.0 / 255.0);
    let scale = (1.0 - exp2_poly(d * LOG2_TRANSMITTANCE[b[3] as usize])) / a;
    // Rounded to the nearest level; a premultiplied channel (at most the opacity) stays so.
    // (Channel by channel in plain registers: as a byte array the compiler shuffled lanes.)
    let level = |k: u32| ((((c >> (8 * k)) & 0xff) as f32 * scale + 0.5).min(255.0) as u32) << (8 * k);
    level(0) | level(1) | level(2) | level(3)
}

/// The AVX2 kernel of [`footprints`], for the tests that hold it against the portable lanes.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(all(test, target_arch = "x86_64"))]
pub(crate) unsafe fn footprints_avx2_for_tests(
    s: &Setup,
    samples: &[u64],
    colors: &[u32],
    shared: &[[f32; 4]],
    first: usize,
    out: &mut [Quad],
    drawn: &mut [u32],
) {
    // SAFETY: the caller guarantees AVX2.
    unsafe { footprints_avx2(s, samples, colors, shared, first, out, drawn) }
}

#[cfg(test)]
mod drawn_color_tests {
    use super::*;

    #[test]
    fn the_transmittance_table_holds_log2_polys_values() {
        for o in 1..255u32 {
            let want = log2_poly(1.0 - o as f32 * (1.0 / 255.0));
            assert_eq!(LOG2_TRANSMITTANCE[o as usize].to_bits(), want.to_bits(), "opacity {o}");
        }
    }

    /// [`exp2_poly`] with the library's `floor` (the series is shared).
    fn exp2_with_floor(y: f32) -> f32 {
        if !(y >= -126.0) {
            return 0.0;
        }
        let y = y.min(127.0);
        let n = y.floor();
        exp2_series(y - n) * pow2(n)
    }

    /// [`drawn_color`] as first written: `log2_poly` per call, `floor`, the channels as bytes.
    fn drawn_color_reference(c: u32, depth: f32, limit: f32) -> u32 {
        let b = c.to_le_bytes();
        if !(limit > 1.0) || depth == 1.0 || !depth.is_finite() || b[3] == 0 || b[3] == 255 {
            return c;
        }
        let d = depth.clamp(1.0 / limit, limit);
        let a = b[3] as f32 * (1.0 / 255.0);
        let scale = (1.0 - exp2_with_floor(d * log2_poly(1.0 - a))) / a;
        let level = |x: u8| (x as f32 * scale + 0.5).min(255.0) as u8;
        u32::from_le_bytes(b.map(level))
    }

    #[test]
    fn drawn_colors_are_the_references() {
        for alpha in 0..=255u32 {
            for depth in [0.1, 0.25, 0.5, 0.9, 0.999_9, 1.0, 1.000_1, 1.3, 2.0, 3.7, 4.0, 9.0, f32::NAN] {
                for ch in [0, 1, alpha / 3, alpha / 2, alpha.saturating_sub(1), alpha] {
                    let c = ch | (alpha / 2) << 8 | alpha << 16 | alpha << 24;
                    for limit in [1.0, 2.0, 4.0] {
                        assert_eq!(
                            drawn_color(c, depth, limit),
                            drawn_color_reference(c, depth, limit),
                            "{c:08x} {depth}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn exp2_poly_floors_as_the_library_does() {
        let mut y = -130.0f32;
        while y < 130.0 {
            for v in [y, y + f32::EPSILON, y - 1e-7, -y] {
                assert_eq!(exp2_poly(v).to_bits(), exp2_with_floor(v).to_bits(), "{v}");
            }
            y += 0.013;
        }
        for v in [-126.0, -125.999_99, -0.0, 0.0, -1e-30, 1e-30, -1.0, -0.5, 126.999_99, 127.0, f32::NAN, f32::INFINITY]
        {
            assert_eq!(exp2_poly(v).to_bits(), exp2_with_floor(v).to_bits(), "{v}");
        }
    }
}
