//! Layered samples: a ray cut into at most K depth segments, each with its own
//! composited premultiplied color and opacity and a representative depth.
//!
//! The marcher feeds every sample it composites, front to back, with [`Segmenter::feed`]: the
//! ray parameter `t` and the accumulated premultiplied color `dst` **after** compositing it (so
//! the segmenter sees exactly the marcher's own arithmetic, and the segments composited front to
//! back give the ray's color again, up to rounding). [`Segmenter::finish`] closes the last
//! segment; early ray termination therefore never drops the segment being built.
//!
//! **Where a ray is cut.** A new segment starts before a sample when segments are left and
//! either
//! - the samples since the last one were empty (a gap of more than [`GAP_STEPS`] steps) and the
//!   open segment holds at least [`MIN_CUT_ALPHA`] of opacity: skin and the bone behind it
//!   become separate segments; or
//! - the accumulated opacity passed the next of the levels `j / K` (`j = 1 … K−1`): a thick
//!   layer is split into slabs of equal opacity, so each keeps its own parallax.
//!
//! **A segment's depth** is its opacity-weighted mean `t` (each sample weighted by what it added
//! to the accumulated opacity), so it lies inside the segment's sample interval and segments
//! come strictly front to back. Its color is `(dst_end − dst_start) / (1 − α_start)`: composited
//! front to back (`C += (1 − A)·c`, `A += (1 − A)·α`) the segments give `dst_end` exactly in
//! real arithmetic.

use crate::sample::{over_background, BACKGROUND};
pub use crate::wire::{LayerError, MAX_LAYERS};

mod pack_lanes;
pub use pack_lanes::{pack_colors_lanes, PackLanes, PACK_LANES};

/// The segments per pixel a client asks for by default with the `splat-layers` renderer,
/// chosen by measurement (`docs/perf.md` and `docs/results.md`, "Choosing K"): against K = 2 it
/// lowers the mean ꟻLIP at 10–30° by 10–12 % for about twice the samples and bytes.
pub const DEFAULT_LAYERS: usize = 4;

/// A gap of more than this many marcher steps without a visible sample separates segments.
pub const GAP_STEPS: f32 = 1.5;

/// Opacity a segment must hold before a gap may close it (smaller pieces are merged into the
/// next one, so noise does not use up the K segments).
pub const MIN_CUT_ALPHA: f32 = 0.02;

/// Total opacity at or below which a segment is dropped as empty (the heuristics' empty-ray
/// rule, [`crate::heuristics::EMPTY_ALPHA`]).
pub const EMPTY_ALPHA: f32 = crate::heuristics::EMPTY_ALPHA;

/// One depth segment of a ray.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Segment {
    /// Representative depth (ray parameter along the unit ray).
    pub t: f32,
    /// Premultiplied RGBA in `[0, 1]`, with `r, g, b ≤ a`.
    pub color: [f32; 4],
}

/// Cuts one ray into at most `k` segments (see the module docs).
#[derive(Clone, Copy, Debug)]
pub struct Segmenter {
    k: u8,
    gap: f32,
    count: u8,
    out: [Segment; MAX_LAYERS],
    start: [f32; 4],
    last: [f32; 4],
    last_t: f32,
    weight: f32,
    weighted_t: f32,
    open: bool,
}

impl Segmenter {
    /// A segmenter for at most `k` segments (clamped to `1..=MAX_LAYERS`) of a ray sampled every
    /// `step` (world units).
    pub fn new(k: u32, step: f32) -> Self {
        let k = k.clamp(1, MAX_LAYERS as u32) as u8;
        let gap = if step.is_finite() && step > 0.0 { GAP_STEPS * step } else { f32::INFINITY };
        Segmenter {
            k,
            gap,
            count: 0,
            out: [Segment::default(); MAX_LAYERS],
            start: [0.0; 4],
            last: [0.0; 4],
            last_t: f32::NEG_INFINITY,
            weight: 0.0,
            weighted_t: 0.0,
            open: false,
        }
    }

    /// Ready for the next ray, as [`Segmenter::new`] with the same `k` and step: the state
    /// reset, the kept segments' storage left as it is (only the first `count` are read), so
    /// a marcher reuses one segmenter instead of building (and copying) a new one per ray.
    #[inline]
    pub fn reset(&mut self) {
        self.count = 0;
        self.start = [0.0; 4];
        self.last = [0.0; 4];
        self.last_t = f32::NEG_INFINITY;
        self.weight = 0.0;
        self.weighted_t = 0.0;
        self.open = false;
    }

    /// Feeds one composited sample: its `t` and the accumulated premultiplied color after it.
    #[inline]
    pub fn feed(&mut self, t: f32, dst: [f32; 4]) {
        let prev_a = self.last[3];
        if self.open && self.count + 1 < self.k {
            let seg_a = prev_a - self.start[3];
            let level = (self.count + 1) as f32 / self.k as f32;
            let gap = t - self.last_t > self.gap && seg_a >= MIN_CUT_ALPHA;
            if gap || prev_a >= level {
                self.close();
            }
        }
        if !self.open {
            self.open = true;
            self.start = self.last;
            self.weight = 0.0;
            self.weighted_t = 0.0;
        }
        let w = dst[3] - prev_a;
        if w > 0.0 {
            self.weight += w;
            self.weighted_t += w * t;
        }
        self.last = dst;
        self.last_t = t;
    }

    fn close(&mut self) {
        self.open = false;
        self.push(self.start, self.last, self.weight, self.weighted_t);
    }

    /// Ends the open segment that went from the accumulated color `start` to `last`, its
    /// samples' opacity weights summing to `weight` and their weighted `t` to `weighted_t`:
    /// kept as the next segment unless it is empty or none is left. One definition for
    /// [`Segmenter`] and [`SegmenterLanes`].
    #[inline]
    fn push(&mut self, start: [f32; 4], last: [f32; 4], weight: f32, weighted_t: f32) {
        let a0 = start[3];
        let keep = 1.0 - a0;
        let alpha = last[3] - a0;
        if !(alpha > EMPTY_ALPHA && keep > 1e-6 && weight > 0.0) || self.count >= self.k {
            return;
        }
        let inv = 1.0 / keep;
        let a = (alpha * inv).clamp(0.0, 1.0);
        let c = |i: usize| ((last[i] - start[i]) * inv).clamp(0.0, a);
        let t = weighted_t / weight;
        // Rounding may put the mean a hair outside the interval; keep the order strict.
        let t = match self.count.checked_sub(1) {
            Some(p) if !(t > self.out[p as usize].t) => self.out[p as usize].t.next_up(),
            _ => t,
        };
        self.out[self.count as usize] = Segment { t, color: [c(0), c(1), c(2), a] };
        self.count += 1;
    }

    /// Closes the last segment and returns the ray's segments, front to back (none for an
    /// empty ray).
    pub fn finish(&mut self) -> &[Segment] {
        if self.open {
            self.close();
        }
        &self.out[..self.count as usize]
    }
}

/// Accumulated opacity at which a client stops compositing a pixel's segments (front to back,
/// [`composite_packed`]).
pub const OPAQUE: f32 = 0.999;

/// One front-to-back compositing step of a client over 8-bit premultiplied colors:
/// `C += (1 − A)·c / 255` (the arithmetic of every CPU renderer's compositing).
#[inline(always)]
pub fn composite_step(acc: &mut [f32; 4], c: [u8; 4]) {
    let wgt = (1.0 - acc[3]) * (1.0 / 255.0);
    for (a, c) in acc.iter_mut().zip(c) {
        *a += wgt * c as f32;
    }
}

/// A ray's packed segment colors composited front to back as a client does, stopping once the
/// opacity reaches [`OPAQUE`] (premultiplied, before the background).
pub fn composite_packed(colors: &[u32]) -> [f32; 4] {
    let mut acc = [0.0f32; 4];
    for &c in colors {
        composite_step(&mut acc, c.to_le_bytes());
        if acc[3] >= OPAQUE {
            break;
        }
    }
    acc
}

/// The pixel a client shows for a ray's packed segment colors: [`composite_packed`] rounded to
/// 8 bits over the background (the background where the ray has none).
pub fn shown_pixel(colors: &[u32]) -> u32 {
    over_background(crate::sample::pack_color_f32(composite_packed(colors)), BACKGROUND)
}

/// `libm::roundf(x).clamp(lo, hi) as i32` (a NaN gives 0), without the software round, which
/// the packing loop calls for every channel of every segment: `x + 0.5` truncated is the
/// rounded value or, where the addition rounded up past the next integer (`x = 0.5 − 2⁻²⁵`, odd
/// integers from 2²³), one more, which the exact comparison with `r − 0.5` takes back. Below
/// zero it may differ from `roundf` by one, which the clamp at `lo ≥ 0` hides.
#[inline(always)]
fn round_clamp(x: f32, lo: i32, hi: i32) -> i32 {
    if x.is_nan() {
        return 0;
    }
    let mut r = (x + 0.5) as i32;
    if r as f32 - 0.5 > x {
        r = r.saturating_sub(1);
    }
    r.clamp(lo, hi)
}

/// 8-bit rounding of one channel, as [`crate::sample::pack_color_f32`] rounds.
#[inline(always)]
fn round8(v: f32) -> u8 {
    (crate::sample::pack_color_f32([v, 0.0, 0.0, 0.0]) & 0xFF) as u8
}

/// The 8-bit value `q` within `lo..=hi` nearest `start` for which `acc + wgt·q / 255` rounds to
/// `target` (`start` where none does).
fn fit_channel(acc: f32, wgt: f32, target: u8, start: u8, lo: u8, hi: u8) -> u8 {
    if !(wgt > 0.0) || lo > hi {
        return start.clamp(lo.min(hi), hi);
    }
    let hits = |q: u8| round8(acc + wgt * q as f32) == target;
    // The value that lands on the target's centre, then its neighbours.
    let ideal = round_clamp((target as f32 / 255.0 - acc) / wgt, lo as i32, hi as i32);
    for d in [0, -1, 1, -2, 2] {
        let q = (ideal + d).clamp(lo as i32, hi as i32) as u8;
        if hits(q) {
            return q;
        }
    }
    start.clamp(lo, hi)
}

/// How many segments before the last [`pack_colors`] tries fitting with it (one at a time,
/// those that weigh most in the client's composite) where the last alone cannot give the
/// pixel: the default K = 4 reaches them all; each try is at most 7 × 33 opacity pairs ×
/// 3 channels × 7 values × one bisection.
const PAIR_REACH: usize = 4;

/// The first `q` in `0..=hi` with `f(q) ≥ v` (`hi + 1` where none), `f` non-decreasing.
fn first_at_least(f: &dyn Fn(u8) -> u8, v: u8, hi: u8) -> u16 {
    let (mut lo, mut top) = (0u16, hi as u16 + 1);
    while lo < top {
        let mid = (lo + top) / 2;
        if f(mid as u8) >= v {
            top = mid;
        } else {
            lo = mid + 1;
        }
    }
    lo
}

/// The 8-bit values `q` within `0..=hi` of one color channel of a segment composited over the
/// client's `acc` (`wgt = (1 − A)/255`) after which the pixel shows `want` over the background,
/// whose share (its channel times one minus the shown opacity) is `share`: one interval, since
/// `min(255, round8(acc + wgt·q) + share)` is non-decreasing in `q` (found by bisection).
fn channel_interval(acc: f32, wgt: f32, share: u16, want: u8, hi: u8) -> Option<(u16, u16)> {
    let f = |v: u8| (round8(acc + wgt * v as f32) as u16 + share).min(255) as u8;
    let lo = first_at_least(&f, want, hi);
    if lo > hi as u16 || f(lo as u8) != want {
        return None;
    }
    let top = if want == 255 { hi as u16 + 1 } else { first_at_least(&f, want + 1, hi) };
    Some((lo, top - 1))
}

/// The background's share of each color channel of a pixel whose 8-bit opacity is `shown_a`,
/// as [`over_background`] adds it.
fn background_share(shown_a: u8) -> [u16; 3] {
    let bg = BACKGROUND.to_le_bytes();
    let keep = 255 - shown_a as u32;
    core::array::from_fn(|i| ((keep * bg[i] as u32 + 127) / 255) as u16)
}

/// Opacities `a0`, `a0 + 1`, `a0 − 1`, `a0 + 2`, … within `0..=255` and `a0 ± reach`.
fn alphas_near(a0: u8, reach: i32) -> impl Iterator<Item = u8> {
    let a0 = a0 as i32;
    (0..=reach)
        .flat_map(move |d| [a0 + d, a0 - d].into_iter().take(if d == 0 { 1 } else { 2 }))
        .filter(|a| (0..=255).contains(a))
        .map(|a| a as u8)
}

/// The 8-bit color `q` (premultiplied: `r, g, b ≤ a`) of one more segment composited
/// ([`composite_step`]) over the client's `acc` (`wgt = (1 − A)/255`) after which the pixel
/// shown over the background is `want`, the opacity nearest `start`'s first (among those
/// `alpha_ok` allows), each color channel nearest `start`'s; `None` where no 8-bit color does.
///
/// Exhaustive over what the segment can show: given the segment's opacity, the shown opacity
/// and so the background's share are fixed, and each color channel's possible values form one
/// interval ([`channel_interval`]).
fn fit_shown(acc: [f32; 4], wgt: f32, want: u32, start: [u8; 4], alpha_ok: impl Fn(u8) -> bool) -> Option<[u8; 4]> {
    if !(wgt > 0.0) {
        return None;
    }
    let want = want.to_le_bytes();
    'alpha: for alpha in alphas_near(start[3], 255).filter(|&a| alpha_ok(a)) {
        let share = background_share(round8(acc[3] + wgt * alpha as f32));
        let mut q = [0u8, 0, 0, alpha];
        for i in 0..3 {
            let Some((lo, hi)) = channel_interval(acc[i], wgt, share[i], want[i], alpha) else {
                continue 'alpha;
            };
            q[i] = (start[i] as u16).clamp(lo, hi) as u8;
        }
        return Some(q);
    }
    None
}

/// [`fit_shown`] for an earlier segment and the last together, where the last alone cannot
/// reach `want` (the client's composite nearly opaque before it, so its weight is less than a
/// level, and the rounding carried from before is more): `prev` composited over `acc`, then the
/// packed `middle` segments as they are, then `last`; `prev` within a few levels of its start
/// (color ±3, opacity ±3) and not stopping the client, `last`'s opacity within ±16 and one
/// `alpha_ok(A, wgt, a)` allows over the composite `A` before it, its color anywhere. Per pair
/// of opacities the color channels are independent: each is searched on its own.
fn fit_shown_pair(
    acc: [f32; 4],
    want: u32,
    prev: [u8; 4],
    middle: &[u32],
    last: [u8; 4],
    alpha_ok: impl Fn(f32, f32, u8) -> bool,
) -> Option<([u8; 4], [u8; 4])> {
    let want = want.to_le_bytes();
    let w0 = (1.0 - acc[3]) * (1.0 / 255.0);
    if !(w0 > 0.0) {
        return None;
    }
    let mut weights = [0.0f32; MAX_LAYERS];
    let weights = &mut weights[..middle.len()];
    for pa in alphas_near(prev[3], 3) {
        // The opacity after `prev` and the middle segments, and the middle's weights.
        let mut a1 = acc[3] + w0 * pa as f32;
        let mut stops = a1 >= OPAQUE;
        for (w, m) in weights.iter_mut().zip(middle) {
            *w = (1.0 - a1) * (1.0 / 255.0);
            a1 += *w * m.to_le_bytes()[3] as f32;
            stops |= a1 >= OPAQUE;
        }
        let w1 = (1.0 - a1) * (1.0 / 255.0);
        if stops || !(w1 > 0.0) {
            continue;
        }
        'last: for la in alphas_near(last[3], 16).filter(|&a| alpha_ok(a1, w1, a)) {
            let share = background_share(round8(a1 + w1 * la as f32));
            let (mut p, mut l) = ([0u8, 0, 0, pa], [0u8, 0, 0, la]);
            'channel: for i in 0..3 {
                for pq in alphas_near(prev[i].min(pa), 3).filter(|&q| q <= pa) {
                    let mut acc1 = acc[i] + w0 * pq as f32;
                    for (w, m) in weights.iter().zip(middle) {
                        acc1 += w * m.to_le_bytes()[i] as f32;
                    }
                    if let Some((lo, hi)) = channel_interval(acc1, w1, share[i], want[i], la) {
                        p[i] = pq;
                        l[i] = (last[i] as u16).clamp(lo, hi) as u8;
                        continue 'channel;
                    }
                }
                continue 'last;
            }
            return Some((p, l));
        }
    }
    None
}

/// The 8-bit colors of a ray's segments (front to back) into `out`, rounded so that a client
/// compositing them ([`composite_packed`]) over the background gets the pixel of the server's
/// image: the ray's own color `ray` (premultiplied, what the marcher composited) rounded to
/// 8 bits, over the background. Each segment is rounded so that the client's composite so far
/// follows the segments' real composite (the rounding error of one carried into the next), and
/// the last one the client composites (the last, or the one where it stops) lands on the pixel:
/// first its color fitted under the rounded opacity; where a channel cannot get there under
/// that opacity (premultiplied: `r, g, b ≤ a`), every opacity, nearest first, with each channel
/// fitted exactly ([`fit_shown`]: only the pixel over the background is asked of it, so an
/// opacity far off is still right at the frame's own camera; faint, fuzzy rays need one); and
/// where the composite before it is so nearly opaque that it weighs less than a level, it and
/// an earlier segment together ([`fit_shown_pair`]). Without it the rounding of up to K
/// segments adds up to ±2 levels per channel at the frame's own camera, which a frame shown
/// where the camera rests must not have. Every random ray of the tests is exact (any opacity,
/// faint ones, up to 16 segments); where none of the searches finds colors, the nearest fit
/// is kept. Colors stay premultiplied.
pub fn pack_colors(segs: &[Segment], ray: [f32; 4], out: &mut [u32]) {
    let n = segs.len().min(out.len());
    let target = crate::sample::pack_color_f32(ray).to_le_bytes();
    let mut acc = [0.0f32; 4];
    // The segments' own composite so far (real colors): each segment is rounded so that the
    // client's composite follows it (the error of one step carried into the next).
    let mut real = [0.0f32; 4];
    let mut adjusting = true;
    // The client's composite before each segment (for an earlier one fitted with the last).
    let mut before = [[0.0f32; 4]; MAX_LAYERS];
    for j in 0..n {
        let c = segs[j].color;
        let keep = 1.0 - real[3];
        for (r, c) in real.iter_mut().zip(c) {
            *r += keep * c;
        }
        let mut q = crate::sample::pack_color_f32(c).to_le_bytes();
        if adjusting {
            let wgt = (1.0 - acc[3]) * (1.0 / 255.0);
            if wgt > 0.0 {
                let follow = |i: usize, hi: u8| round_clamp((real[i] - acc[i]) / wgt, 0, hi as i32) as u8;
                q[3] = follow(3, 255);
                for i in 0..3 {
                    q[i] = follow(i, q[3]);
                }
            }
            let last = j + 1 == n;
            let stops = acc[3] + wgt * q[3] as f32 >= OPAQUE;
            if last || stops {
                // The last segment (or the one where the client stops) takes the error.
                let fit_rgb = |mut q: [u8; 4]| {
                    for i in 0..3 {
                        q[i] = fit_channel(acc[i], wgt, target[i], q[i].min(q[3]), 0, q[3]);
                    }
                    q
                };
                // Where a color channel cannot reach its target under the opacity
                // (premultiplied), another opacity may still give the same pixel over the
                // background: the nearest that does (higher first), else the nearest fit. Only
                // the pixel shown at the frame's own camera is asked of it, so an opacity far
                // off is still right there; a few rays of faint, fuzzy volumes need one. One
                // where the client stops keeps stopping there.
                let a = if last { fit_channel(acc[3], wgt, target[3], q[3], 0, 255) } else { q[3] };
                let want = over_background(u32::from_le_bytes(target), BACKGROUND);
                let shown = |q: [u8; 4]| {
                    let mut after = acc;
                    composite_step(&mut after, q);
                    over_background(crate::sample::pack_color_f32(after), BACKGROUND)
                };
                let first = fit_rgb([q[0], q[1], q[2], a]);
                q = first;
                if shown(first) != want {
                    let may_stop = |alpha: u8| last || acc[3] + wgt * alpha as f32 >= OPAQUE;
                    if let Some(c) = fit_shown(acc, wgt, want, first, may_stop) {
                        q = c;
                    } else {
                        // Nearly opaque before it (a weight under one level), the last cannot
                        // undo the rounding carried from before: it and an earlier segment
                        // together: the `PAIR_REACH` that weigh most in the client's composite
                        // (whose rounding is the most), the heaviest first, which bounds the
                        // search where no colors can give the pixel.
                        let may_stop = |a1: f32, w1: f32, alpha: u8| last || a1 + w1 * alpha as f32 >= OPAQUE;
                        let mut order = [0usize; MAX_LAYERS];
                        for (i, o) in order.iter_mut().enumerate().take(j) {
                            *o = i;
                        }
                        let weight = |p: usize| (1.0 - before[p][3]) * (out[p] >> 24) as f32;
                        order[..j].sort_unstable_by(|&x, &y| weight(y).total_cmp(&weight(x)).then(y.cmp(&x)));
                        for &p in order[..j].iter().take(PAIR_REACH) {
                            let prev = out[p].to_le_bytes();
                            if let Some((pc, c)) =
                                fit_shown_pair(before[p], want, prev, &out[p + 1..j], first, may_stop)
                            {
                                out[p] = u32::from_le_bytes(pc);
                                acc = before[p];
                                for &m in &out[p..j] {
                                    composite_step(&mut acc, m.to_le_bytes());
                                }
                                q = c;
                                break;
                            }
                        }
                    }
                }
                adjusting = false;
            }
            before[j] = acc;
            composite_step(&mut acc, q);
        }
        out[j] = u32::from_le_bytes(q);
    }
}

/// [`Segmenter`] for `M` rays at once, as the marcher's SIMD packets feed them: the same cuts,
/// depths and colors bit for bit (the server's tests compare its packet kernel with its scalar
/// one, which feeds [`Segmenter`]), with the per-sample bookkeeping as straight-line code over
/// the `M` lanes (selects, no branches, so the compiler vectorizes it) and only the rare closing
/// of a segment done lane by lane (`Segmenter::push`, one definition). Lanes are fed only
/// where their bit of `bits` is set.
#[derive(Clone, Debug)]
pub struct SegmenterLanes<const M: usize> {
    k: f32,
    gap: f32,
    /// Per lane: segments kept so far (as `f32`: small integers, exact), whether a segment is
    /// open, the accumulated color where it opened and after the last sample, that sample's
    /// `t`, and the open segment's opacity weights and weighted `t`.
    count: [f32; M],
    open: [u32; M],
    start: [[f32; M]; 4],
    last: [[f32; M]; 4],
    last_t: [f32; M],
    weight: [f32; M],
    weighted_t: [f32; M],
    /// Per lane its kept segments.
    segs: [Segmenter; M],
}

impl<const M: usize> SegmenterLanes<M> {
    /// `M` segmenters as [`Segmenter::new`]`(k, step)`.
    pub fn new(k: u32, step: f32) -> Self {
        let one = Segmenter::new(k, step);
        SegmenterLanes {
            k: one.k as f32,
            gap: one.gap,
            count: [0.0; M],
            open: [0; M],
            start: [[0.0; M]; 4],
            last: [[0.0; M]; 4],
            last_t: [f32::NEG_INFINITY; M],
            weight: [0.0; M],
            weighted_t: [0.0; M],
            segs: [one; M],
        }
    }

    /// [`Segmenter::feed`] for each lane `l` whose bit `l` of `bits` is set: its sample's `t[l]`
    /// and the accumulated color after it, `dst[c][l]`.
    // Indexed loops over the lanes, one array per value: the form the compiler vectorizes.
    #[allow(clippy::needless_range_loop)]
    #[inline(always)]
    pub fn feed(&mut self, bits: u64, t: &[f32; M], dst: [&[f32; M]; 4]) {
        // Masks are all ones or zero per lane (u32), so every loop below is lane-wise selects.
        let active: [u32; M] = core::array::from_fn(|l| (((bits >> (l & 63)) & 1) as u32).wrapping_neg());
        // Which lanes end their open segment before this sample (Segmenter::feed's test).
        let mut close = [0u32; M];
        for l in 0..M {
            let prev_a = self.last[3][l];
            let seg_a = prev_a - self.start[3][l];
            let level = (self.count[l] + 1.0) / self.k;
            let gap = mask(t[l] - self.last_t[l] > self.gap) & mask(seg_a >= MIN_CUT_ALPHA);
            let left = mask(self.count[l] + 1.0 < self.k);
            close[l] = active[l] & self.open[l] & left & (gap | mask(prev_a >= level));
        }
        if close.iter().fold(0, |a, &c| a | c) != 0 {
            for l in (0..M).filter(|&l| close[l] != 0) {
                self.close(l);
            }
        }
        // Open where none is, weigh the sample (with the opacity before it), remember it.
        let mut opening = [0u32; M];
        for l in 0..M {
            opening[l] = active[l] & !self.open[l];
            let weight = sel(opening[l], 0.0, self.weight[l]);
            let weighted_t = sel(opening[l], 0.0, self.weighted_t[l]);
            let w = dst[3][l] - self.last[3][l];
            let add = active[l] & mask(w > 0.0);
            self.weight[l] = sel(add, weight + w, weight);
            self.weighted_t[l] = sel(add, weighted_t + w * t[l], weighted_t);
            self.last_t[l] = sel(active[l], t[l], self.last_t[l]);
            self.open[l] |= active[l];
        }
        for c in 0..4 {
            for l in 0..M {
                self.start[c][l] = sel(opening[l], self.last[c][l], self.start[c][l]);
                self.last[c][l] = sel(active[l], dst[c][l], self.last[c][l]);
            }
        }
    }

    /// Ready for the next rays, as [`SegmenterLanes::new`] with the same `k` and step
    /// ([`Segmenter::reset`] per lane): a packet marcher reuses one instead of building (and
    /// copying, some 12 KB for 32 lanes) a new one per packet.
    #[inline]
    pub fn reset(&mut self) {
        self.count = [0.0; M];
        self.open = [0; M];
        self.start = [[0.0; M]; 4];
        self.last = [[0.0; M]; 4];
        self.last_t = [f32::NEG_INFINITY; M];
        self.weight = [0.0; M];
        self.weighted_t = [0.0; M];
        for s in &mut self.segs {
            s.reset();
        }
    }

    /// [`Segmenter::finish`] of lane `l` (none for a lane out of range).
    pub fn finish(&mut self, l: usize) -> &[Segment] {
        if l >= M {
            return &[];
        }
        if self.open[l] != 0 {
            self.close(l);
        }
        let seg = &self.segs[l];
        &seg.out[..seg.count as usize]
    }

    /// Ends lane `l`'s open segment (`Segmenter::close` for one lane).
    fn close(&mut self, l: usize) {
        let start = [self.start[0][l], self.start[1][l], self.start[2][l], self.start[3][l]];
        let last = [self.last[0][l], self.last[1][l], self.last[2][l], self.last[3][l]];
        self.segs[l].push(start, last, self.weight[l], self.weighted_t[l]);
        self.count[l] = self.segs[l].count as f32;
        self.open[l] = 0;
    }
}

/// All ones where `c`, else zero.
#[inline(always)]
fn mask(c: bool) -> u32 {
    (c as u32).wrapping_neg()
}

/// `a` where `m` is all ones, `b` where it is zero (bit for bit).
#[inline(always)]
fn sel(m: u32, a: f32, b: f32) -> f32 {
    f32::from_bits((a.to_bits() & m) | (b.to_bits() & !m))
}

/// Composites premultiplied segment colors front to back: `C += (1 − A)·c`. The order of the
/// slice is the compositing order.
pub fn composite(colors: impl IntoIterator<Item = [f32; 4]>) -> [f32; 4] {
    let mut acc = [0.0f32; 4];
    for c in colors {
        let w = 1.0 - acc[3];
        for i in 0..4 {
            acc[i] += w * c[i];
        }
    }
    acc
}

/// Checks a layered frame's segments (what every receiver relies on): one index per sample; a
/// pixel's samples consecutive with indices 0, 1, 2, … below `layers`; each strictly farther
/// from the camera's eye than the previous one of its pixel and on its ray (within a tenth of
/// the distance); premultiplied colors with no channel above the opacity.
pub fn validate(
    header: &crate::wire::FrameHeader,
    samples: &[u64],
    colors: &[u32],
    segments: &[u8],
    layers: u8,
) -> Result<(), LayerError> {
    #[cfg(all(feature = "std", target_arch = "x86_64"))]
    if volwarp_lanes::Avx2Token::new().is_some() {
        // SAFETY: the token proves the CPU has AVX2 (and the lane level allows it).
        return unsafe { validate_avx2(header, samples, colors, segments, layers) };
    }
    validate_blocks(header, samples, colors, segments, layers)
}

/// [`validate_blocks`] compiled for AVX2 (its maps then run 8 lanes wide; the same results).
#[cfg(all(feature = "std", target_arch = "x86_64"))]
#[target_feature(enable = "avx2")]
fn validate_avx2(
    header: &crate::wire::FrameHeader,
    samples: &[u64],
    colors: &[u32],
    segments: &[u8],
    layers: u8,
) -> Result<(), LayerError> {
    validate_blocks(header, samples, colors, segments, layers)
}

/// The checks [`validate`] and [`validate_reference`] start with: one color and one segment
/// index per sample, and at most [`MAX_LAYERS`] layers.
#[inline(always)]
fn check_shape(samples: &[u64], colors: &[u32], segments: &[u8], layers: u8) -> Result<(), LayerError> {
    if segments.len() != samples.len() || colors.len() != samples.len() {
        return Err(LayerError::Inconsistent);
    }
    if layers as usize > MAX_LAYERS {
        return Err(LayerError::TooManyLayers { layers, limit: MAX_LAYERS as u8 });
    }
    Ok(())
}

/// The body of [`validate`].
#[inline(always)]
fn validate_blocks(
    header: &crate::wire::FrameHeader,
    samples: &[u64],
    colors: &[u32],
    segments: &[u8],
    layers: u8,
) -> Result<(), LayerError> {
    check_shape(samples, colors, segments, layers)?;
    let deq = header.dequantizer();
    let eye = header.camera.eye;
    // A block at a time: first the geometry of every sample and of it against the sample before
    // (maps the compiler vectorizes; the same operations in the same order as on one sample:
    // `Dequantizer::center`, `Vec3::length`), then the checks in order. The sample a segment
    // is compared with is always the one just before it (a later segment must follow its
    // predecessor), so that is the pair computed.
    const B: usize = 256;
    let (mut rx, mut ry, mut rz, mut dist) = ([0f32; B], [0f32; B], [0f32; B], [0f32; B]);
    let (mut behind, mut on_ray) = ([false; B], [false; B]);
    // The sample before the block: its offset from the eye and distance.
    let mut before = [0f32; 4];
    for start in (0..samples.len()).step_by(B) {
        let end = (start + B).min(samples.len());
        let m = end - start;
        for (k, &s) in samples[start..end].iter().enumerate() {
            // `Dequantizer::center`, the coordinates (below 2^18) converted through `i32`: the
            // same floats as from `u32`, in one instruction.
            let (qx, qy, qz) = crate::sample::unpack_position(s);
            let x = (deq.min.x + qx as i32 as f32 * deq.step.x) - eye.x;
            let y = (deq.min.y + qy as i32 as f32 * deq.step.y) - eye.y;
            let z = (deq.min.z + qz as i32 as f32 * deq.step.z) - eye.z;
            rx[k] = x;
            ry[k] = y;
            rz[k] = z;
            dist[k] = crate::math::sqrt((x * x) + (y * y) + (z * z));
        }
        for k in 0..m {
            let [px, py, pz, pd] = if k == 0 { before } else { [rx[k - 1], ry[k - 1], rz[k - 1], dist[k - 1]] };
            let f = dist[k] / pd;
            let (ox, oy, oz) = (rx[k] - px * f, ry[k] - py * f, rz[k] - pz * f);
            behind[k] = dist[k] > pd;
            on_ray[k] = crate::math::sqrt((ox * ox) + (oy * oy) + (oz * oz)) <= 0.1 * dist[k];
        }
        // Whether the whole block passes, as one reduction; only a failing block is walked in
        // order for its first error.
        let segs = &segments[start..end];
        let before_seg =
            |k: usize| if k == 0 { segments.get(start.wrapping_sub(1)).copied() } else { Some(segs[k - 1]) };
        let mut pass = true;
        for k in 0..m {
            pass &= check_sample(start + k, colors[start + k], segs[k], before_seg(k), layers, behind[k], on_ray[k])
                .is_ok();
        }
        if !pass {
            for k in 0..m {
                check_sample(start + k, colors[start + k], segs[k], before_seg(k), layers, behind[k], on_ray[k])?;
            }
        }
        before = [rx[m - 1], ry[m - 1], rz[m - 1], dist[m - 1]];
    }
    Ok(())
}

/// The checks of sample `i` (its color, its segment index, the segment index of the sample
/// before it if any, and whether it lies behind that sample on the same ray), in the order
/// [`validate`] reports them. A later segment must directly follow its predecessor, which
/// itself passed, so the sample before is the one it is compared with.
#[inline(always)]
fn check_sample(
    i: usize,
    color: u32,
    seg: u8,
    before: Option<u8>,
    layers: u8,
    behind: bool,
    on_ray: bool,
) -> Result<(), LayerError> {
    let [r, g, b, a] = color.to_le_bytes();
    if r > a || g > a || b > a {
        return Err(LayerError::Opacity { index: i });
    }
    if seg >= layers.max(1) {
        return Err(LayerError::BadIndex { index: i });
    }
    if seg == 0 {
        return Ok(());
    }
    if before != Some(seg - 1) {
        return Err(LayerError::BadIndex { index: i });
    }
    // Strictly behind, and on the same ray from the eye: the previous point's direction
    // reaches this one's within a tenth of the distance.
    if !behind || !on_ray {
        return Err(LayerError::Unsorted { index: i });
    }
    Ok(())
}

/// [`validate`] one sample at a time: the reference the blocked form is tested against.
#[doc(hidden)]
pub fn validate_reference(
    header: &crate::wire::FrameHeader,
    samples: &[u64],
    colors: &[u32],
    segments: &[u8],
    layers: u8,
) -> Result<(), LayerError> {
    check_shape(samples, colors, segments, layers)?;
    let deq = header.dequantizer();
    let eye = header.camera.eye;
    let mut prev: Option<(glam::Vec3, f32)> = None;
    for (i, (&seg, (&s, &c))) in segments.iter().zip(samples.iter().zip(colors)).enumerate() {
        let [r, g, b, a] = c.to_le_bytes();
        if r > a || g > a || b > a {
            return Err(LayerError::Opacity { index: i });
        }
        if seg >= layers.max(1) {
            return Err(LayerError::BadIndex { index: i });
        }
        let rel = deq.center(s) - eye;
        let dist = rel.length();
        if seg == 0 {
            prev = Some((rel, dist));
            continue;
        }
        let Some((prel, pdist)) = prev else { return Err(LayerError::BadIndex { index: i }) };
        if i == 0 || segments[i - 1] != seg - 1 {
            return Err(LayerError::BadIndex { index: i });
        }
        // Strictly behind, and on the same ray from the eye: the previous point's direction
        // reaches this one's within a tenth of the distance.
        let on_ray = (rel - prel * (dist / pdist)).length() <= 0.1 * dist;
        if !(dist > pdist) || !on_ray {
            return Err(LayerError::Unsorted { index: i });
        }
        prev = Some((rel, dist));
    }
    Ok(())
}

#[cfg(feature = "alloc")]
pub use layered_compact::*;

/// The LayeredCompactFrame message (type 7): a layered frame as one CompactFrame per layer.
#[cfg(feature = "alloc")]
mod layered_compact {
    use super::*;
    use crate::compact_frame::{self, EncodeError, EncodeOptions, COMPACT_FIXED_LEN};
    use crate::wire::{decode_frame_fixed, encode_frame_fixed, Frame, Limits, MsgType, WireError};
    use crate::wire::{FRAME_FIXED_LEN, HEADER_LEN};
    use alloc::vec;
    use alloc::vec::Vec;

    /// Every layer of a layered frame, split in one pass: layer `l` holds the samples with
    /// segment index `l`, in pixel order (a frame whose planes differ in length gives
    /// `BadFrame`).
    pub fn layer_frames(frame: &Frame) -> Result<Vec<Frame>, EncodeError> {
        if frame.segments.len() != frame.samples.len() || frame.samples.len() != frame.colors.len() {
            return Err(EncodeError::BadFrame);
        }
        let layers = frame.layers() as usize;
        let mut counts = vec![0usize; layers];
        for &seg in &frame.segments {
            if let Some(c) = counts.get_mut(seg as usize) {
                *c += 1;
            }
        }
        let mut parts: Vec<(Vec<u64>, Vec<u32>)> =
            counts.iter().map(|&c| (Vec::with_capacity(c), Vec::with_capacity(c))).collect();
        for ((&s, &c), &seg) in frame.samples.iter().zip(&frame.colors).zip(&frame.segments) {
            if let Some((samples, colors)) = parts.get_mut(seg as usize) {
                samples.push(s);
                colors.push(c);
            }
        }
        Ok(parts
            .into_iter()
            .map(|(samples, colors)| {
                let header = crate::wire::FrameHeader { count: samples.len() as u32, ..frame.header };
                Frame::new(header, samples, colors)
            })
            .collect())
    }

    /// Encodes a layered frame (non-empty `segments`) as one LayeredCompactFrame message
    /// (header included): the frame's fixed part with the layer count in byte 57, then per layer
    /// a `u32` length and that layer's CompactFrame payload.
    pub fn encode_layered(frame: &Frame, opts: &EncodeOptions) -> Result<Vec<u8>, EncodeError> {
        encode_layered_with(frame, |layer| compact_frame::encode(layer, opts))
    }

    /// [`encode_layered`] with `encode` making each layer's CompactFrame message (header
    /// included), e.g. with another zstd implementation.
    pub fn encode_layered_with(
        frame: &Frame,
        encode: impl FnMut(&Frame) -> Result<Vec<u8>, EncodeError>,
    ) -> Result<Vec<u8>, EncodeError> {
        let msgs = layer_frames(frame)?.iter().map(encode).collect::<Result<Vec<_>, _>>()?;
        assemble_layered(frame, &msgs)
    }

    /// The LayeredCompactFrame message of `frame` from its layers' CompactFrame messages
    /// (header included; layer 0 first, as [`layer_frames`] splits them), however they were
    /// made (e.g. in parallel).
    pub fn assemble_layered(frame: &Frame, msgs: &[Vec<u8>]) -> Result<Vec<u8>, EncodeError> {
        let layers = frame.layers();
        if msgs.len() != layers as usize {
            return Err(EncodeError::BadFrame);
        }
        let mut fixed =
            encode_frame_fixed(&crate::wire::FrameHeader { count: frame.samples.len() as u32, ..frame.header });
        fixed[57] = layers;
        let mut payload = Vec::from(fixed);
        for msg in msgs {
            if msg.len() < HEADER_LEN {
                return Err(EncodeError::BadFrame);
            }
            let part = &msg[HEADER_LEN..];
            payload.extend_from_slice(&(part.len() as u32).to_le_bytes());
            payload.extend_from_slice(part);
        }
        let len = u32::try_from(payload.len()).map_err(|_| EncodeError::DepthRange)?;
        let mut out = Vec::with_capacity(HEADER_LEN + payload.len());
        out.extend_from_slice(&crate::wire::MAGIC);
        out.extend_from_slice(&crate::wire::VERSION.to_le_bytes());
        out.push(MsgType::LayeredCompactFrame as u8);
        out.push(0);
        out.extend_from_slice(&len.to_le_bytes());
        out.extend_from_slice(&payload);
        Ok(out)
    }

    /// Decodes a LayeredCompactFrame payload (after the 12-byte header) into a layered frame:
    /// each layer's CompactFrame is decoded as usual (same bounds on what it allocates), must
    /// carry the frame's own fixed part (but its count) and a coverage mask inside the previous
    /// layer's, the counts must add up, and the merged frame must pass [`validate`].
    pub fn decode_layered_payload(payload: &[u8], limits: &Limits) -> Result<Frame, WireError> {
        decode_layered_payload_with(payload, limits, |parts| {
            parts.iter().map(|part| decode_layered_part(part, limits)).collect()
        })
    }

    /// One layer of a LayeredCompactFrame, decoded ([`decode_layered_part`]): its coverage mask
    /// and its samples in pixel order.
    #[derive(Debug)]
    pub struct LayerPart {
        mask: Vec<u8>,
        frame: Frame,
    }

    /// Decodes one layer's CompactFrame payload (one of the parts
    /// [`decode_layered_payload_with`] hands out): decompression and reconstruction, bounded
    /// by `limits` as any CompactFrame's.
    pub fn decode_layered_part(part: &[u8], limits: &Limits) -> Result<LayerPart, WireError> {
        let (sub, params) = compact_frame::read_params(part, limits)?;
        let body = compact_frame::decompress_planes(&part[COMPACT_FIXED_LEN..], &params, sub.count as usize)?;
        let frame = compact_frame::decode_body(&sub, &params, &body)?;
        let mlen = compact_frame::mask_len(sub.camera.width, sub.camera.height) as usize;
        let mask = body.get(..mlen).ok_or(WireError::Layers(LayerError::Inconsistent))?.to_vec();
        Ok(LayerPart { mask, frame })
    }

    /// [`decode_layered_payload`] with the layers' parts decoded by `decode_parts`, which gets
    /// each layer's CompactFrame payload, layer 0 first, and returns
    /// [`decode_layered_part`] of each in the same order — in parallel, for instance (std
    /// clients decode the parts on several threads). The parts have passed the checks that need
    /// no decoding (lengths, each part's fixed part against the frame's, the counts adding up to
    /// the frame's, which bounds what all parts together may allocate) before it is called.
    pub fn decode_layered_payload_with(
        payload: &[u8],
        limits: &Limits,
        decode_parts: impl FnOnce(&[&[u8]]) -> Vec<Result<LayerPart, WireError>>,
    ) -> Result<Frame, WireError> {
        let bad_len = WireError::BadLength { ty: MsgType::LayeredCompactFrame, len: payload.len() as u32 };
        let inconsistent = WireError::Layers(LayerError::Inconsistent);
        let fixed: &[u8; FRAME_FIXED_LEN] =
            payload.get(..FRAME_FIXED_LEN).ok_or(bad_len)?.try_into().map_err(|_| bad_len)?;
        let header = decode_frame_fixed(fixed, limits)?;
        let layers = fixed[57];
        if layers == 0 {
            return Err(WireError::Layers(LayerError::BadIndex { index: 0 }));
        }
        crate::wire::check_count_layers(&header, layers, limits)?;
        let mlen = compact_frame::mask_len(header.camera.width, header.camera.height) as usize;
        let mut rest = &payload[FRAME_FIXED_LEN..];
        let mut raw_parts: Vec<&[u8]> = Vec::with_capacity(layers as usize);
        let mut total = 0u64;
        for _ in 0..layers {
            let len_bytes: [u8; 4] = rest.get(..4).ok_or(bad_len)?.try_into().map_err(|_| bad_len)?;
            let len = u32::from_le_bytes(len_bytes) as usize;
            let part = rest.get(4..4 + len).ok_or(bad_len)?;
            rest = &rest[4 + len..];
            // The layer's fixed part is the frame's but the layer count (byte 57) and the count.
            if part.len() < COMPACT_FIXED_LEN || part[..57] != fixed[..57] || part[58..92] != fixed[58..92] {
                return Err(inconsistent);
            }
            let (sub, _) = compact_frame::read_params(part, limits)?;
            total += sub.count as u64;
            if total > header.count as u64 {
                return Err(inconsistent);
            }
            raw_parts.push(part);
        }
        if !rest.is_empty() || total != header.count as u64 {
            return Err(inconsistent);
        }
        let decoded = decode_parts(&raw_parts);
        if decoded.len() != raw_parts.len() {
            return Err(inconsistent);
        }
        let mut parts: Vec<(Vec<u8>, Frame)> = Vec::with_capacity(layers as usize);
        for d in decoded {
            let LayerPart { mask, frame: f } = d?;
            if mask.len() != mlen {
                return Err(inconsistent);
            }
            if let Some((prev, _)) = parts.last() {
                if mask.iter().zip(prev).any(|(m, p)| m & !p != 0) {
                    return Err(inconsistent);
                }
            }
            parts.push((mask, f));
        }
        // Merge in pixel order, each pixel's layers front to back.
        let n = header.count as usize;
        let (mut samples, mut colors, mut segments) = (vec![0u64; n], vec![0u32; n], vec![0u8; n]);
        let mut cursor = vec![0usize; layers as usize];
        let mut i = 0;
        let (first_mask, _) = &parts[0];
        let nl = parts.len();
        for (byte_i, &byte) in first_mask.iter().enumerate() {
            // Eight pixels with every layer (the common case inside an object): each layer's
            // next eight samples, interleaved pixel by pixel, with no bit tests.
            if byte == 0xff && parts.iter().all(|(m, _)| m[byte_i] == 0xff) && i + 8 * nl <= n {
                for (l, (_, f)) in parts.iter().enumerate() {
                    let k = cursor[l];
                    let (Some(src), Some(col)) = (f.samples.get(k..k + 8), f.colors.get(k..k + 8)) else {
                        return Err(inconsistent);
                    };
                    for p in 0..8 {
                        samples[i + p * nl + l] = src[p];
                        colors[i + p * nl + l] = col[p];
                        segments[i + p * nl + l] = l as u8;
                    }
                    cursor[l] += 8;
                }
                i += 8 * nl;
                continue;
            }
            let mut bits = byte;
            while bits != 0 {
                let bit = bits.trailing_zeros() as usize;
                bits &= bits - 1;
                let px = byte_i * 8 + bit;
                for (l, (mask, f)) in parts.iter().enumerate() {
                    if mask[px >> 3] & (1 << (px & 7)) == 0 {
                        break;
                    }
                    let k = cursor[l];
                    cursor[l] += 1;
                    let (Some(&s), Some(&c), Some(slot)) = (f.samples.get(k), f.colors.get(k), samples.get_mut(i))
                    else {
                        return Err(inconsistent);
                    };
                    *slot = s;
                    colors[i] = c;
                    segments[i] = l as u8;
                    i += 1;
                }
            }
        }
        if i != n {
            return Err(inconsistent);
        }
        validate(&header, &samples, &colors, &segments, layers).map_err(WireError::Layers)?;
        Ok(Frame { header, samples, colors, segments })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_round_is_libms_round_clamped() {
        // Every f32 bit pattern in steps of 251 (both signs, NaNs and infinities among them),
        // and every value within 64 ulps of each half-integer and integer up to 300.
        let reference = |x: f32, lo: i32, hi: i32| libm::roundf(x).clamp(lo as f32, hi as f32) as i32;
        let check = |x: f32| {
            for (lo, hi) in [(0, 255), (0, 7), (3, 200), (255, 255)] {
                assert_eq!(round_clamp(x, lo, hi), reference(x, lo, hi), "x = {x:e} ({:#x}), {lo}..={hi}", x.to_bits());
            }
        };
        let mut bits = 0u32;
        while let Some(next) = bits.checked_add(251) {
            check(f32::from_bits(bits));
            bits = next;
        }
        for k in 0..600 {
            let c = (k as f32 * 0.5).to_bits();
            for d in 0..64 {
                check(f32::from_bits(c + d));
                check(f32::from_bits(c.saturating_sub(d)));
                check(-f32::from_bits(c + d));
            }
        }
        for x in [0.5 - 2f32.powi(-25), 8_388_609.0, f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -0.5, 0.5, 254.5] {
            check(x);
        }
    }

    /// Fills `segs` with pseudo-random premultiplied segments at depths 0, 1, …: each an
    /// opacity below `amax` and color channels between a random saturation of it and it (the
    /// packing tests' rays).
    pub(super) fn random_segments(next: &mut impl FnMut() -> f32, amax: f32, segs: &mut [Segment]) {
        for (j, sg) in segs.iter_mut().enumerate() {
            let a = next() * amax;
            let sat = next();
            let mut ch = || a * (sat + (1.0 - sat) * next());
            *sg = Segment { t: j as f32, color: [ch(), ch(), ch(), a] };
        }
    }

    #[test]
    fn packed_segments_composite_to_the_rays_own_pixel() {
        // Pseudo-random rays: the client's composite of the packed colors over the background is
        // the ray's own pixel (the server's image) on every ray, and plain rounding of each
        // segment is not. Families: any opacity (nearly opaque rays, where the last segments
        // weigh less than a level and an earlier one must carry the rounding), faint and fuzzy
        // (the iron protein: low opacity, up to 16 segments, saturated colors) and mid.
        let mut next = crate::test_unit_rng(0x2545_F491_4F6C_DD1D);
        for (family, amax, kmax) in
            [("any", 1.0f32, 4usize), ("faint", 0.05, 4), ("faint16", 0.05, 16), ("tiny", 0.005, 4), ("mid", 0.3, 8)]
        {
            let (mut plain, n) = (0, 20_000);
            for _ in 0..n {
                let k = 1 + (next() * kmax as f32) as usize % kmax;
                let mut segs = [Segment::default(); MAX_LAYERS];
                random_segments(&mut next, amax, &mut segs[..k]);
                let segs = &segs[..k];
                let ray = composite(segs.iter().map(|s| s.color));
                let want = over_background(crate::sample::pack_color_f32(ray), BACKGROUND);
                let mut packed = [0u32; MAX_LAYERS];
                pack_colors(segs, ray, &mut packed[..k]);
                for c in &packed[..k] {
                    let [r, g, b, a] = c.to_le_bytes();
                    assert!(r <= a && g <= a && b <= a, "{family}: premultiplied: {c:08x}");
                }
                assert_eq!(shown_pixel(&packed[..k]), want, "{family}: {segs:?}, packed {:08x?}", &packed[..k]);
                let mut rounded = [0u32; MAX_LAYERS];
                for (r, sg) in rounded.iter_mut().zip(segs) {
                    *r = crate::sample::pack_color_f32(sg.color);
                }
                plain += usize::from(shown_pixel(&rounded[..k]) == want);
            }
            if family == "any" {
                assert!((plain as f64) < 0.9 * n as f64, "plain rounding: {plain} of {n}");
            }
        }
    }

    #[test]
    fn a_nearly_opaque_ray_is_exact_through_an_earlier_segment() {
        // Found by the random search: the second segment makes the ray 0.979 opaque, the last two
        // weigh under a level each, and the rounding of the first two is more than they can undo.
        let segs = [
            Segment { t: 0.0, color: [0.9384782, 0.59993505, 0.87598944, 0.97908205] },
            Segment { t: 1.0, color: [0.7713785, 0.8165903, 0.8660723, 0.8699847] },
            Segment { t: 2.0, color: [0.8472313, 0.84252125, 0.8329043, 0.85296404] },
            Segment { t: 3.0, color: [0.26625288, 0.2289804, 0.19865182, 0.3233636] },
        ];
        let ray = composite(segs.iter().map(|s| s.color));
        let mut packed = [0u32; 4];
        pack_colors(&segs, ray, &mut packed);
        assert_eq!(shown_pixel(&packed), over_background(crate::sample::pack_color_f32(ray), BACKGROUND));
    }

    /// Composites a profile of (t, premultiplied rgba) samples as the marcher does and
    /// segments it.
    fn run(k: u32, samples: &[(f32, [f32; 4])]) -> (Segs, [f32; 4]) {
        let mut s = Segmenter::new(k, 1.0);
        let mut acc = [0.0f32; 4];
        for &(t, c) in samples {
            let w = 1.0 - acc[3];
            for i in 0..4 {
                acc[i] += w * c[i];
            }
            s.feed(t, acc);
        }
        let segs = s.finish();
        let mut out = Segs { n: segs.len(), s: [Segment::default(); MAX_LAYERS] };
        out.s[..segs.len()].copy_from_slice(segs);
        (out, acc)
    }

    struct Segs {
        n: usize,
        s: [Segment; MAX_LAYERS],
    }

    #[test]
    fn segments_recomposite_to_the_ray_and_split_at_gaps() {
        let c = |a: f32| [0.5 * a, 0.25 * a, 0.1 * a, a];
        let profile = [(1.0, c(0.1)), (2.0, c(0.2)), (6.0, c(0.3)), (7.0, c(0.3)), (12.0, c(0.5))];
        let (segs, acc) = run(4, &profile);
        assert_eq!(segs.n, 3, "three runs separated by gaps");
        let back = composite(segs.s[..segs.n].iter().map(|s| s.color));
        for i in 0..4 {
            assert!((back[i] - acc[i]).abs() < 1e-6, "{back:?} vs {acc:?}");
        }
        for w in segs.s[..segs.n].windows(2) {
            assert!(w[0].t < w[1].t);
        }
        assert!(segs.s[0].t > 1.0 && segs.s[0].t < 2.0);
    }

    /// `SegmenterLanes` against one `Segmenter` per lane, bit for bit: 16 lanes of random
    /// profiles (runs of visible samples, gaps, thick and thin layers), each lane fed only at
    /// the steps its bit is set, for K = 1 … 16; then a second round of rays after `reset`,
    /// each lane also against a segmenter built new.
    #[test]
    fn lanes_cut_rays_as_one_segmenter_per_lane() {
        let mut x = 0x2545_f491_4f6c_dd1du64;
        let mut rnd = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f32 / (1u64 << 53) as f32
        };
        for k in 1..=MAX_LAYERS as u32 {
            const M: usize = 16;
            let step = 0.5;
            let mut lanes = SegmenterLanes::<M>::new(k, step);
            let mut each = [Segmenter::new(k, step); M];
            // A second round of rays after `reset`, against segmenters built new for it.
            for round in 0..2 {
                if round == 1 {
                    lanes.reset();
                    each.iter_mut().for_each(Segmenter::reset);
                }
                let mut fresh = [Segmenter::new(k, step); M];
                let mut acc = [[0.0f32; 4]; M];
                for s in 0..200 {
                    let t: [f32; M] = core::array::from_fn(|_| s as f32 * step);
                    let mut bits = 0u64;
                    for (l, a) in acc.iter_mut().enumerate() {
                        // Lane l sees material in bursts, with gaps of a few steps between.
                        let visible = (s / (3 + l)) % 2 == 0 && rnd() < 0.9;
                        if visible && a[3] < 0.99 {
                            let alpha = 0.02 + 0.2 * rnd();
                            let c = [alpha * rnd(), alpha * rnd(), alpha * rnd(), alpha];
                            let w = 1.0 - a[3];
                            for i in 0..4 {
                                a[i] += w * c[i];
                            }
                            bits |= 1 << l;
                        }
                    }
                    let dst: [[f32; M]; 4] = core::array::from_fn(|c| core::array::from_fn(|l| acc[l][c]));
                    lanes.feed(bits, &t, [&dst[0], &dst[1], &dst[2], &dst[3]]);
                    for (l, (seg, new)) in each.iter_mut().zip(&mut fresh).enumerate() {
                        if bits >> l & 1 != 0 {
                            seg.feed(t[l], acc[l]);
                            new.feed(t[l], acc[l]);
                        }
                    }
                }
                for (l, (seg, new)) in each.iter_mut().zip(&mut fresh).enumerate() {
                    let want = seg.finish();
                    assert_eq!(want, new.finish(), "K={k} lane {l} round {round}: reset against new");
                    let got = lanes.finish(l);
                    assert_eq!(got.len(), want.len(), "K={k} lane {l}");
                    for (a, b) in got.iter().zip(want) {
                        assert_eq!(a.t.to_bits(), b.t.to_bits(), "K={k} lane {l}");
                        assert_eq!(a.color.map(f32::to_bits), b.color.map(f32::to_bits), "K={k} lane {l}");
                    }
                    assert!(k < 2 || l > 0 || want.len() > 1, "K={k}: lane 0 should have several segments");
                }
            }
        }
    }

    #[test]
    fn one_layer_is_the_whole_ray_and_k_caps_the_count() {
        let c = |a: f32| [a, a, a, a];
        let profile: [(f32, [f32; 4]); 8] = core::array::from_fn(|i| (i as f32 * 3.0, c(0.2)));
        let (one, acc) = run(1, &profile);
        assert_eq!(one.n, 1);
        assert!((one.s[0].color[3] - acc[3]).abs() < 1e-6);
        for k in 2..6 {
            let (segs, _) = run(k, &profile);
            assert_eq!(segs.n, k as usize);
        }
    }

    #[test]
    fn an_opaque_first_sample_gives_one_segment_and_an_empty_ray_none() {
        let (segs, _) = run(8, &[(0.5, [1.0, 0.0, 0.0, 1.0])]);
        assert_eq!(segs.n, 1);
        assert_eq!(segs.s[0].color, [1.0, 0.0, 0.0, 1.0]);
        let (none, _) = run(8, &[]);
        assert_eq!(none.n, 0);
        let (zero, _) = run(8, &[(1.0, [0.0; 4]), (5.0, [0.0; 4])]);
        assert_eq!(zero.n, 0, "zero-opacity samples make no segment");
    }
}
