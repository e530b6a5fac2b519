//! Watertight slabs: the corners the slab-`j` segments of neighbouring pixels share where their
//! depths lie within a tolerance ([`SlabCorners`]), computed once per frame.

use super::options::*;
use super::own_pass::*;
use crate::key_list::sort_keys;
use crate::lanes::{self, Lanes};
use crate::threads::Threads;
use volwarp_core::Scene;

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
pub(crate) fn band_corners_lanes<L: Lanes>(
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
    fn band_corners_on_best_lanes / band_corners_avx2 => band_corners_lanes(
        start: &[u32],
        zs: Depths,
        size: (usize, usize),
        per_px: f32,
        rows: core::ops::Range<usize>,
        part: &mut [[f32; 4]],
        base: usize,
    )
}

/// `band_corners` for the other steps of the layered model and the rasterizer (the dispatch
/// macro's functions are private to their module).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(crate) fn band_corners(
    start: &[u32],
    zs: Depths,
    size: (usize, usize),
    per_px: f32,
    rows: core::ops::Range<usize>,
    part: &mut [[f32; 4]],
    base: usize,
) {
    band_corners_on_best_lanes(start, zs, size, per_px, rows, part, base)
}

/// Where the corner stencil reads the segments' view depths, in pixel order.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Depths<'a> {
    /// As they are (a frame not in the server's order, once sorted: `OwnPass::zs`).
    Plain(&'a [f32]),
    /// In the low bits of `OwnPass::at` (a frame in the server's order: pixel order is the
    /// samples' own).
    Packed(&'a [u64]),
}

impl Depths<'_> {
    /// The depth at position `g`.
    #[inline(always)]
    pub(crate) fn get(&self, g: usize) -> f32 {
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
pub(crate) fn slab_row_corners(u: &[f32], m: &[f32], d: &[f32], per_px: f32, out: [&mut [f32]; 4]) {
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
pub(crate) fn join(v: f32, z: f32, per_px: f32) -> (f32, f32) {
    let j = (v - z).abs() <= per_px * (v + z);
    (if j { v } else { 0.0 }, if j { 1.0 } else { 0.0 })
}

/// The shared corner from the sum and number of the depths that join it: their mean, NaN unless
/// at least two join and the mean is a positive finite depth.
#[inline(always)]
pub(crate) fn corner(sum: f32, count: f32) -> f32 {
    let zc = sum / count;
    if count >= 2.0 && zc.is_finite() && zc > 0.0 {
        zc
    } else {
        f32::NAN
    }
}

/// The slab-shared corner depths of layered frames, as [`LayerSplat`](crate::LayerSplat) finds them for its newest
/// frame (see [`LayerOptions::watertight`]): what the GPU layered splatter uploads beside the
/// samples, so both sides draw the same footprints. Keeps its buffers from frame to frame.
#[derive(Debug, Default)]
pub struct SlabCorners {
    pub(crate) own: OwnPass,
    pub(crate) threads: Threads,
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

/// The shared corners are a step of their own: computed from the own-image pass's grouping.
impl OwnPass {
    /// Finds [`OwnPass::shared`] (after [`OwnPass::group`]): the `j`-th nearest segment of a
    /// pixel belongs to slab `j`, and a corner of its footprint is shared with the slab-`j`
    /// segments of the (up to three) other pixels around that corner whose depth differs from
    /// its own by at most `tol` source pixels at that depth (a depth step larger than that is an
    /// edge, not a surface). A shared corner sits at the mean depth of the segments sharing it,
    /// summed in the same order by every pixel around it, so neighbouring footprints of one
    /// slab meet exactly: no overlap counts a semi-transparent slab twice and no gap lets the
    /// slab behind show (the contour lines of `docs/results.md`). At the frame's own camera a
    /// corner projects onto its pixel corner at any depth, so the frame's image is unchanged.
    pub(crate) fn share_corners(&mut self, tol: f32, threads: &Threads) {
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
}
