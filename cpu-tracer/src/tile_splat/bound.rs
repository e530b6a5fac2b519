//! The bound and bin steps of the tiled splatter: each sphere's screen rectangle, the union
//! per group of spheres, the small spheres' hits, and the (tile, entry) pairs of each group.

use super::*;

/// The (tile, entry) pairs of group `g` (rectangle `grect`, its spheres' `rects`) into `out`:
/// each tile its rectangle overlaps with the whole group, or, for a group overlapping more
/// than [`MAX_GROUP_TILES`] tiles (in the server's scanline order, the group that wraps from
/// one row's end to the next row's start), [`split_group`]'s runs.
#[inline(always)]
pub(super) fn group_pairs(g: u32, grect: Rect, rects: &[Rect], grid: Grid, out: &mut Vec<(u32, u64)>) {
    if grect.is_empty() {
        return;
    }
    let (tx0, tx1, ty0, ty1) = grect.tiles();
    if (tx1 - tx0 + 1) * (ty1 - ty0 + 1) > MAX_GROUP_TILES {
        split_group(rects, grid, g, out);
    } else {
        for ty in ty0..=ty1 {
            for tx in tx0..=tx1 {
                out.push(((ty * grid.tx + tx) as u32, g as u64 | (u32::MAX as u64) << 32));
            }
        }
    }
}

/// A group's spheres (but the large and the empty ones) as runs of consecutive spheres whose
/// joint rectangle overlaps at most [`MAX_TILES`] tiles (a run holds at least one sphere, so
/// a group gives at most [`MAX_TILES`] entries per sphere): each tile of each run with the
/// entry (group `g`, the mask of the run's spheres) into `out`. The group that wraps from one
/// scanline's end to the next one's start splits into two runs.
pub(super) fn split_group(rects: &[Rect], grid: Grid, g: u32, out: &mut Vec<(u32, u64)>) {
    let mut j = 0;
    while j < rects.len() {
        let r = rects[j];
        if r.is_empty() || r.is_large() {
            j += 1;
            continue;
        }
        let (mut run, mut mask) = (r, 1u32 << j);
        j += 1;
        while j < rects.len() {
            let r = rects[j];
            if !r.is_empty() && !r.is_large() {
                let u = run.union(r);
                let (tx0, tx1, ty0, ty1) = u.tiles();
                if (tx1 - tx0 + 1) * (ty1 - ty0 + 1) > MAX_TILES {
                    break;
                }
                (run, mask) = (u, mask | 1 << j);
            }
            j += 1;
        }
        let (tx0, tx1, ty0, ty1) = run.tiles();
        for ty in ty0..=ty1 {
            for tx in tx0..=tx1 {
                out.push(((ty * grid.tx + tx) as u32, g as u64 | (mask as u64) << 32));
            }
        }
    }
}

/// The inclusive pixel ranges `(x0, x1, y0, y1)` whose pixel centres' rays may hit the sphere
/// `(c, r)`, `None` if none can: [`View::bound`]'s tangents from the eye (in f64, the radius
/// widened by a relative 10⁻⁵, far above the f32 rounding of the ray test), but only the pixels
/// whose *centres* lie within them (the earlier splatter's bound also takes every pixel the
/// tangents touch: about 25 pixels instead of 9 for a sphere three pixels wide).
#[inline(always)]
pub(crate) fn tight_bound(view: &View, c: Vec3, r: f32) -> Option<(u32, u32, u32, u32)> {
    view.bound_with(c, r, centre_span)
}

/// `|a|` per lane (`f32::max(a, −a)`).
#[inline(always)]
pub(super) fn lane_abs<L: Arith>(a: L) -> L {
    a.max(L::splat(0.0) - a)
}

/// [`View`]'s constants in f32, for the bounds of a lane's worth of spheres at once.
pub(crate) struct ViewF32 {
    pub(super) eye: [f32; 3],
    pub(super) u: [f32; 3],
    pub(super) v: [f32; 3],
    pub(super) w: [f32; 3],
    pub(super) px_x: f32,
    pub(super) px_y: f32,
    pub(super) half_w: f32,
    pub(super) half_h: f32,
}

impl ViewF32 {
    pub(crate) fn new(v: &View) -> ViewF32 {
        let f = |a: [f64; 3]| [a[0] as f32, a[1] as f32, a[2] as f32];
        ViewF32 {
            eye: [v.eye.x, v.eye.y, v.eye.z],
            u: f(v.u),
            v: f(v.v),
            w: f(v.w),
            px_x: v.px_x as f32,
            px_y: v.px_y as f32,
            half_w: v.half_w as f32,
            half_h: v.half_h as f32,
        }
    }
}

/// The rectangles of `samples` (at most [`GROUP`]) into `rects`, `L::N` (8 or 16) at a time
/// in f32 lanes, and the union of those that are not large; with `centres` as long as
/// `samples`, each sphere's centre less the eye and radius into it, or for a small sphere its
/// hits ([`small_hits`]); and the masks of the small spheres (low 32 bits) and of those drawn
/// from the group (non-empty, not large; high 32 bits). [`tight_bound`]'s tangents with
/// the radius widened by a relative 2·10⁻⁵ of the L1 distance (instead of 10⁻⁵ of the
/// distance: the extra covers the f32 rounding of the bound itself, about 3·10⁻⁷ of the slope)
/// for spheres at least two (widened) radii in front of the eye plane; the others (near,
/// behind, NaN) take [`tight_bound`] in f64. Every instance computes the same values.
#[inline(always)]
pub(crate) fn bound_group<L: BoundLanes>(
    view: &View,
    vf: &ViewF32,
    deq: &Dequantizer,
    samples: &[u64],
    rects: &mut [Rect],
    centres: &mut [[f32; 4]],
) -> (Rect, bool, u64) {
    let (mut u, mut any_large, mut small_all, mut drawn) = (NO_RECT, false, 0u32, 0u32);
    let keep_centres = centres.len() == samples.len();
    for (k, (ss, rs)) in samples.chunks(L::N).zip(rects.chunks_mut(L::N)).enumerate() {
        let [rx, ry, rz, r] = L::decode(deq, vf.eye, ss);
        let cx = rx * L::splat(vf.u[0]) + ry * L::splat(vf.u[1]) + rz * L::splat(vf.u[2]);
        let cy = rx * L::splat(vf.v[0]) + ry * L::splat(vf.v[1]) + rz * L::splat(vf.v[2]);
        let cz = rx * L::splat(vf.w[0]) + ry * L::splat(vf.w[1]) + rz * L::splat(vf.w[2]);
        let rr = r + L::splat(2e-5) * (lane_abs(rx) + lane_abs(ry) + lane_abs(rz) + r);
        let far = cz.simd_gt(L::splat(2.0) * rr);
        let denom = cz * cz - rr * rr;
        let inv = L::splat(1.0) / denom;
        let (sx, sy) = ((cx * cx + denom).sqrt(), (cy * cy + denom).sqrt());
        let (xl, xh) = ((cx * cz - rr * sx) * inv, (cx * cz + rr * sx) * inv);
        let (yl, yh) = ((cy * cz - rr * sy) * inv, (cy * cz + rr * sy) * inv);
        let x0 = xl * L::splat(vf.px_x) + L::splat(vf.half_w);
        let x1 = xh * L::splat(vf.px_x) + L::splat(vf.half_w);
        let y0 = L::splat(vf.half_h) - yh * L::splat(vf.px_y);
        let y1 = L::splat(vf.half_h) - yl * L::splat(vf.px_y);
        // [`centre_span`] in f32 lanes, widened from 0.01 to 0.02 pixel so that the f32
        // rounding of the subtraction (≤ 0.001 pixel below 2¹⁴) never narrows it: the span
        // holds [`centre_span`]'s of the same bound.
        let (ax, bx) = (x0 - L::splat(0.52), x1 - L::splat(0.48));
        let (ay, by) = (y0 - L::splat(0.52), y1 - L::splat(0.48));
        let (nw, nh) = (L::splat(view.width as f32), L::splat(view.height as f32));
        let zero = L::splat(0.0);
        let ok_v = far
            & ax.simd_le(bx)
            & bx.simd_ge(zero)
            & ax.simd_lt(nw)
            & ay.simd_le(by)
            & by.simd_ge(zero)
            & ay.simd_lt(nh);
        // The integer spans in lanes (`BoundLanes::spans`: `ceil_clamped` and the truncating
        // clamp, for the lanes of `ok`, whose values lie in its domain).
        let (xs0, xs1) = L::spans(ax.fast_max(L::splat(-1.0)), bx.fast_min(nw), view.width - 1);
        let (ys0, ys1) = L::spans(ay.fast_max(L::splat(-1.0)), by.fast_min(nh), view.height - 1);
        let live = (1u32 << ss.len()) - 1;
        let (far, ok) = (far.to_bitmask(), ok_v.to_bitmask());
        // The lanes of `ok` with a non-empty span get their rectangle, the others the empty
        // one; with the large ones, the others, and the others' union.
        let tile_log2 = TILE.trailing_zeros();
        let mut rl = L::rects(ok, [&xs0, &xs1, &ys0, &ys1], tile_log2, MAX_TILES as i32);
        if keep_centres {
            // Spheres of at most 2×2 pixels (lanes of `ok`, non-empty spans at most two
            // wide): their pixels' hits now, `L::N` spheres per lane operation, in place of
            // their centres (`small_hits`); the others' centres.
            let (fx0, fx1) = (L::from_ints16(&xs0), L::from_ints16(&xs1));
            let (fy0, fy1) = (L::from_ints16(&ys0), L::from_ints16(&ys1));
            let (wx, wy) = (fx1 - fx0, fy1 - fy0);
            let one = L::splat(1.0);
            let small_v = ok_v & wx.simd_ge(zero) & wx.simd_le(one) & wy.simd_ge(zero) & wy.simd_le(one);
            let small = small_v.to_bitmask() & live;
            let mut c = [rx, ry, rz, r];
            if small != 0 {
                let hits = small_hits(&view.basis, c, fx0, fy0, small_v, wx.simd_gt(zero), wy.simd_gt(zero));
                for (c, h) in c.iter_mut().zip(hits) {
                    *c = small_v.select(h, *c);
                }
            }
            let n = ss.len();
            L::store_records(c, &mut centres[L::N * k..L::N * k + n]);
            small_all |= small << (L::N * k);
        }
        // Near the eye plane, behind it, or NaN (rare): the f64 bound, and the same rules.
        let mut slow = !ok & !far & live;
        let mut union = Rect::from_bits(rl.union);
        while slow != 0 {
            let l = slow.trailing_zeros() as usize;
            slow &= slow - 1;
            if let Some((x0, x1, y0, y1)) = tight_bound(view, deq.center(ss[l]), deq.radius(ss[l])) {
                let r = Rect { x0: x0 as u16, y0: y0 as u16, x1: x1 as u16, y1: y1 as u16 };
                rl.bits[l] = r.bits();
                if r.is_large() {
                    rl.large |= 1 << l;
                } else {
                    rl.drawn |= 1 << l;
                    union = union.union(r);
                }
            }
        }
        // Whole chunks as fixed-size copies (a copy of `rs.len()` words became a call of
        // `memcpy` per chunk).
        if rs.len() == 16 && L::N == 16 {
            if let Some(r16) = rs.first_chunk_mut::<16>() {
                *r16 = rl.bits.map(Rect::from_bits);
            }
        } else if rs.len() == 8 && L::N == 8 {
            if let Some(r8) = rs.first_chunk_mut::<8>() {
                *r8 = core::array::from_fn(|l| Rect::from_bits(rl.bits[l]));
            }
        } else {
            for (rect, &b) in rs.iter_mut().zip(&rl.bits) {
                *rect = Rect::from_bits(b);
            }
        }
        any_large |= rl.large & live != 0;
        drawn |= (rl.drawn & live) << (L::N * k);
        u = u.union(union);
    }
    (u, any_large, small_all as u64 | (drawn as u64) << 32)
}

/// The hits of a lane's worth of spheres (centres less the eye and radii `c`, the lanes of the mask
/// `small`) on the pixels of their 2×2 windows at `(x0, y0)` (pixel indices as `f32`; the
/// masks `wide`, `tall`: the rectangle's second column, row), as [`splat_sphere`] would find
/// them: per window pixel `(x0 + dx, y0 + dy)` (result `dx + 2·dy`), per lane, the distance
/// [`sphere_hits`] gives on that pixel's ray ([`ray_dirs`] of the same pixel centre, the same
/// operations, so the same bits), NaN where it misses or the pixel lies outside the rectangle
/// (which no comparison takes).
#[inline(always)]
pub(super) fn small_hits<L: Arith>(
    b: &volwarp_core::camera::RayBasis,
    c: [L; 4],
    x0: L,
    y0: L,
    small: L,
    wide: L,
    tall: L,
) -> [L; 4] {
    let (px, py) = (x0 + L::splat(0.5), y0 + L::splat(0.5));
    let (px1, py1) = (px + L::splat(1.0), py + L::splat(1.0));
    let mut out = [L::splat(f32::NAN); 4];
    let windows = [(px, py, small), (px1, py, small & wide), (px, py1, small & tall), (px1, py1, small & wide & tall)];
    for (o, (x, y, on)) in out.iter_mut().zip(windows) {
        if on.any() {
            *o = lanes::sphere_hits_lanes(&ray_dirs(b, x, y), c, on);
        }
    }
    out
}

/// Per group of a run, what the bound pass finds (`TileSplat`'s fields of the same names), and
/// the index of the run's first group.
pub(super) struct Groups<'a> {
    pub(super) rects: &'a mut [Rect],
    pub(super) large: &'a mut [bool],
    pub(super) small: &'a mut [u64],
    pub(super) first: u32,
}

/// [`bound_group`] for a run of whole groups (`samples`, their `rects` and `centres`), and each
/// group's (tile, entry) pairs ([`group_pairs`]) into `pairs`: one call per run, so that the
/// kernel's constants are set up once, not per group.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn bound_run<L: BoundLanes>(
    view: &View,
    vf: &ViewF32,
    deq: &Dequantizer,
    samples: &[u64],
    rects: &mut [Rect],
    centres: &mut [[f32; 4]],
    groups: Groups,
    grid: Grid,
    pairs: &mut Vec<(u32, u64)>,
) {
    let each = rects.chunks_mut(GROUP).zip(centres.chunks_mut(GROUP)).zip(samples.chunks(GROUP));
    let per_group = groups.rects.iter_mut().zip(groups.large.iter_mut()).zip(groups.small.iter_mut());
    for (g, (((rects, centres), samples), ((grect, glarge), gsmall))) in each.zip(per_group).enumerate() {
        (*grect, *glarge, *gsmall) = bound_group::<L>(view, vf, deq, samples, rects, centres);
        group_pairs(groups.first + g as u32, *grect, rects, grid, pairs);
    }
}

lanes::dispatch! {
    /// [`bound_run`] on the best lanes this CPU has (sixteen with AVX-512, else eight).
    pub(super) fn bound_dispatch / bound_avx2 / bound_avx512 => bound_run(
        view: &View,
        vf: &ViewF32,
        deq: &Dequantizer,
        samples: &[u64],
        rects: &mut [Rect],
        centres: &mut [[f32; 4]],
        groups: Groups,
        grid: Grid,
        pairs: &mut Vec<(u32, u64)>,
    )
}

/// The pixels `i < n` whose centre `i + 0.5` lies in `[a, b]`, widened by 0.01 pixel, as an
/// inclusive range; `None` if there are none (or `a`, `b` are NaN).
#[inline(always)]
pub(super) fn centre_span(a: f64, b: f64, n: u32) -> Option<(u32, u32)> {
    // Clamp first (NaN fails the comparisons and gives `None`), then floor and ceil by
    // truncation of values ≥ −1.
    let lo = (a - 0.51).max(-1.0);
    let hi = (b - 0.49).min(n as f64);
    if !(lo <= hi) || !(hi >= 0.0) || !(lo < n as f64) {
        return None;
    }
    let l = lo as i64; // trunc; ceil below
    let l = if (l as f64) < lo { l + 1 } else { l }.max(0);
    let h = (hi as i64).min(n as i64 - 1); // hi ≥ 0: trunc is floor
    if l > h {
        return None;
    }
    Some((l as u32, h as u32))
}

#[cfg(test)]
mod tests {
    use super::*;
    use volwarp_core::Camera;

    /// The bound pass's instances (portable, AVX2, AVX-512 where the CPU has them) give the
    /// same rectangles, centres or hits (bit for bit), unions and masks, on whole and partial
    /// groups, near the eye plane and far.
    #[test]
    fn bound_instances_agree() {
        type Out = (Vec<u64>, Vec<[u32; 4]>, Vec<(u64, bool, u64)>, Vec<(u32, u64)>);
        let f = crate::synthetic::random_cloud(5000, 0.004, 41, 160);
        let eye_inside = Camera::look_at(Vec3::splat(0.5), Vec3::new(0.9, 0.6, 0.1), Vec3::Y, 70.0, 128, 96);
        let (c, deq) = (f.header.camera, f.header.dequantizer());
        let cams = [c, c.with_viewport(40, 40), c.orbit(30.0, 10.0).with_viewport(97, 61), eye_inside, c.dolly(0.2)];
        let mut small = 0;
        for cam in cams {
            let (view, grid) = (View::new(&cam), Grid::new(&cam));
            let vf = ViewF32::new(&view);
            // A run of many groups ending in a partial one (5000 = 156·32 + 8), and one partial.
            for s in [&f.samples[..], &f.samples[..13]] {
                let run = |k: usize| -> Option<Out> {
                    let (mut rects, mut centres) = (vec![NO_RECT; s.len()], vec![[0f32; 4]; s.len()]);
                    let ng = s.len().div_ceil(GROUP);
                    let (mut gr, mut gl, mut gs) = (vec![NO_RECT; ng], vec![false; ng], vec![0u64; ng]);
                    let mut pairs = Vec::new();
                    let groups = Groups { rects: &mut gr, large: &mut gl, small: &mut gs, first: 0 };
                    let (r, c, p) = (&mut rects[..], &mut centres[..], &mut pairs);
                    match k {
                        0 => bound_run::<wide::f32x8>(&view, &vf, &deq, s, r, c, groups, grid, p),
                        #[cfg(target_arch = "x86_64")]
                        1 if volwarp_lanes::Avx2Token::detected().is_some() => {
                            // SAFETY: the CPU has AVX2 (checked).
                            unsafe { bound_avx2(&view, &vf, &deq, s, r, c, groups, grid, p) }
                        }
                        #[cfg(target_arch = "x86_64")]
                        2 if volwarp_lanes::Avx512Token::detected().is_some() => {
                            // SAFETY: the CPU has AVX2, AVX-512 F and DQ (checked).
                            unsafe { bound_avx512(&view, &vf, &deq, s, r, c, groups, grid, p) }
                        }
                        _ => return None,
                    };
                    let c = centres.iter().map(|c| c.map(f32::to_bits)).collect();
                    let g = (0..ng).map(|i| (gr[i].bits(), gl[i], gs[i])).collect();
                    Some((rects.iter().map(|r| r.bits()).collect(), c, g, pairs))
                };
                let portable = run(0).expect("the portable instance");
                small += portable.2.iter().map(|g| (g.2 as u32).count_ones()).sum::<u32>();
                for k in [1, 2] {
                    if let Some(o) = run(k) {
                        assert!(o == portable, "instance {k}, {} spheres", s.len());
                    }
                }
            }
        }
        assert!(small > 1000, "{small}");
    }
}
