//! The packet marcher: the rays of a block of pixels marched together in SIMD lanes, the widest
//! the CPU has ([`crate::LaneKind`], chosen at run time): sixty-four rays of an 8×8 block as
//! four AVX-512 registers per value, thirty-two of an 8×4 block as four AVX2 registers, or
//! sixteen rays of a 4×4 block
//! in `wide`'s portable lanes (two `f32x8` per value). Several registers per value make independent chains of dependent
//! gathers and blends that the core overlaps: the step is bound by their latency more than by
//! their throughput (on the MRI benchmark view, one thread: 8 AVX2 lanes 424 ms, 16 in two
//! registers 336 ms; 16 AVX-512 lanes 268 ms, 32 in two registers 243 ms; at the session's end,
//! 32 AVX2 lanes in four registers 211 ms against 258 in two; the portable lanes (SSE2 here)
//! 407–439 ms with 16 rays in two `f32x8` against 463–480 with 8 in one; 64 AVX-512 lanes in
//! four registers 145.8–148.3 ms against 177.7–180.2 with 32 in two). The packet's arrays
//! (rays, pickers, results) are sized for the instance's lanes by the const parameter `M`.
//!
//! Per step, every active lane computes its sample position, clamps it to the voxel lattice,
//! gathers the eight neighbours from the volume's bricks in its own type (four gathers of
//! x-neighbour pairs, `crate::volume::bricks`), blends them trilinearly and normalizes the blend, gathers the transfer function's
//! opacity and red (and, where any lane is visible, its green and blue) and composites front to
//! back, all in lanes. Each lane keeps its own sample index, so rays of different lengths, early
//! ray termination and empty-space leaps (done per lane when a lane reaches the face its last
//! look found, with the scalar marcher's rule, [`crate::empty_space::Occupancy::look`]) work as
//! in the scalar marcher. The depth heuristics stay the one scalar definition of
//! [`volwarp_core::heuristics`]: the samples a lane composites are fed to that lane's
//! [`DepthPicker`] (or [`FirstPassAccumulator`]) in order, or, for the threshold-like ones,
//! core's comparison is applied in lanes (`DepthPicker::threshold_target`).
//!
//! Every operation is the scalar marcher's ([`crate::marcher::Marcher::march_ray`]) in the same
//! order with the same IEEE rounding (no fused multiply-add), so the colors and depths are the
//! scalar marcher's bit for bit; the tests in `server/tests/packet_march.rs` check this on every
//! bundled dataset and heuristic.

use crate::distributed::partial::Seg;
use crate::lanes::{dispatch, Lanes, Mask};
use crate::march_settings::{MarchSetup, PartWindow};
use crate::radius::{FrameRadius, RaySpread, Uncertainty};
use crate::volume::bricks::{BRICK_EDGE, BRICK_SHIFT, BRICK_SPAN, BRICK_VALUES};
use crate::volume::Voxels;
use volwarp_core::sample::{over_background, pack_color_f32, Quantizer};
use volwarp_core::segments::{PackLanes, Segment, Segmenter, SegmenterLanes};
use volwarp_core::{DepthPicker, FirstPassAccumulator, Heuristic, RayBasis, Vec3, BACKGROUND};

/// Pixels per packet along x for `lanes` lanes (the packet is `pw × (lanes / pw)` pixels).
const fn pw(lanes: usize) -> usize {
    if lanes >= 32 {
        8
    } else {
        4
    }
}

/// What a pass does with the samples a lane composites.
trait Feed<const M: usize> {
    /// Whether [`Feed::feed`] does anything (the lanes are stored to arrays only if so).
    const ACTIVE: bool;
    /// Feeds lane `l`'s sample for every bit `l` of `bits`: its `t`, own opacity and
    /// accumulated opacity after compositing it.
    fn feed(&mut self, bits: u64, t: &[f32; M], src_a: &[f32; M], dst_a: &[f32; M]);
    /// Whether the pass wants the accumulated color too ([`Feed::feed_rgba`] instead of
    /// [`Feed::feed`]).
    const RGBA: bool = false;
    /// Feeds lane `l`'s sample for every bit `l` of `bits`: its `t` and the accumulated
    /// premultiplied color after compositing it (only called where [`Feed::RGBA`]).
    #[inline(always)]
    fn feed_rgba(&mut self, _bits: u64, _t: &[f32; M], _dst: [&[f32; M]; 4]) {}
    /// Whether the pass is a threshold-like depth picker applied in lanes: the kernel keeps
    /// each lane's first `t` with accumulated opacity above [`Feed::targets`] itself (no calls
    /// of [`Feed::feed`]) and hands the result to [`Feed::set_chosen`].
    const LANE_THRESHOLD: bool = false;
    /// Each lane's target (only read where [`Feed::LANE_THRESHOLD`]).
    #[inline(always)]
    fn targets(&self) -> [f32; M] {
        [f32::INFINITY; M]
    }
    /// Lane `l`'s chosen `t` for every bit `l` of `bits` (the lanes that found one).
    #[inline(always)]
    fn set_chosen(&mut self, _bits: u64, _chosen: &[f32; M]) {}
}

/// Calls `f(lane)` for every set bit of `bits` (lanes 0..64), lowest first.
#[inline(always)]
fn for_lanes(mut bits: u64, mut f: impl FnMut(usize)) {
    while bits != 0 {
        let l = bits.trailing_zeros() as usize;
        bits &= bits - 1;
        f(l);
    }
}

/// What cuts a packet's rays into segments: the segmenters and each lane's result.
trait LayerFeed<const M: usize>: Feed<M> {
    /// Segmenters for at most `k` segments per ray, sampled every `step`.
    fn new(k: u32, step: f32) -> Self;
    /// Ready for the next packet, as [`LayerFeed::new`] with the same `k` and step.
    fn reset(&mut self);
    /// Lane `l`'s segments, the last one closed.
    fn finish(&mut self, l: usize) -> &[Segment];
}

/// Layered samples, one `Segmenter` per lane fed lane by lane: the narrow lane kinds' form
/// (on the portable lanes it is the faster one: measured 522 against 553 ms at 1024²).
impl<const M: usize> Feed<M> for [Segmenter; M] {
    const ACTIVE: bool = true;
    const RGBA: bool = true;
    #[inline(always)]
    fn feed(&mut self, _: u64, _: &[f32; M], _: &[f32; M], _: &[f32; M]) {}
    #[inline(always)]
    fn feed_rgba(&mut self, bits: u64, t: &[f32; M], dst: [&[f32; M]; 4]) {
        for_lanes(bits, |l| {
            self[l].feed(t[l], [dst[0][l], dst[1][l], dst[2][l], dst[3][l]]);
        });
    }
}

impl<const M: usize> LayerFeed<M> for [Segmenter; M] {
    fn new(k: u32, step: f32) -> Self {
        [Segmenter::new(k, step); M]
    }
    #[inline(always)]
    fn reset(&mut self) {
        for s in self {
            s.reset();
        }
    }
    #[inline(always)]
    fn finish(&mut self, l: usize) -> &[Segment] {
        self.get_mut(l).map_or(&[], |s| s.finish())
    }
}

/// Layered samples, the bookkeeping over all lanes at once (core's `SegmenterLanes`:
/// `Segmenter`'s cuts bit for bit): the AVX2 and AVX-512 kinds' form.
impl<const M: usize> Feed<M> for SegmenterLanes<M> {
    const ACTIVE: bool = true;
    const RGBA: bool = true;
    #[inline(always)]
    fn feed(&mut self, _: u64, _: &[f32; M], _: &[f32; M], _: &[f32; M]) {}
    #[inline(always)]
    fn feed_rgba(&mut self, bits: u64, t: &[f32; M], dst: [&[f32; M]; 4]) {
        SegmenterLanes::feed(self, bits, t, dst);
    }
}

impl<const M: usize> LayerFeed<M> for SegmenterLanes<M> {
    fn new(k: u32, step: f32) -> Self {
        SegmenterLanes::new(k, step)
    }
    #[inline(always)]
    fn reset(&mut self) {
        SegmenterLanes::reset(self);
    }
    #[inline(always)]
    fn finish(&mut self, l: usize) -> &[Segment] {
        SegmenterLanes::finish(self, l)
    }
}

/// Colors only.
struct NoFeed;

impl<const M: usize> Feed<M> for NoFeed {
    const ACTIVE: bool = false;
    #[inline(always)]
    fn feed(&mut self, _: u64, _: &[f32; M], _: &[f32; M], _: &[f32; M]) {}
}

impl<const M: usize> Feed<M> for [FirstPassAccumulator; M] {
    const ACTIVE: bool = true;
    #[inline(always)]
    fn feed(&mut self, bits: u64, _: &[f32; M], src_a: &[f32; M], dst_a: &[f32; M]) {
        for_lanes(bits, |l| {
            self[l].feed(src_a[l], dst_a[l]);
        });
    }
}

impl<const M: usize> Feed<M> for [DepthPicker; M] {
    const ACTIVE: bool = true;
    #[inline(always)]
    fn feed(&mut self, bits: u64, t: &[f32; M], src_a: &[f32; M], dst_a: &[f32; M]) {
        for_lanes(bits, |l| {
            self[l].feed(t[l], src_a[l], dst_a[l]);
        });
    }
}

/// Threshold-like depth pickers ([`DepthPicker::threshold_target`]) applied in lanes: the same
/// comparison, `dst_a > target`, on the first sample that passes it.
struct LaneThreshold<const M: usize> {
    targets: [f32; M],
    chosen: [Option<f32>; M],
}

impl<const M: usize> Feed<M> for LaneThreshold<M> {
    const ACTIVE: bool = false;
    const LANE_THRESHOLD: bool = true;
    #[inline(always)]
    fn feed(&mut self, _: u64, _: &[f32; M], _: &[f32; M], _: &[f32; M]) {}
    #[inline(always)]
    fn targets(&self) -> [f32; M] {
        self.targets
    }
    #[inline(always)]
    fn set_chosen(&mut self, bits: u64, chosen: &[f32; M]) {
        for_lanes(bits, |l| self.chosen[l] = Some(chosen[l]));
    }
}

/// [`BRICK_SHIFT`] as a lane shift count.
const SHIFT: i32 = BRICK_SHIFT as i32;

/// The eight stencil corners `[c000, c100, c010, c110, c001, c101, c011, c111]` whose lowest
/// corner is value `base` of chunk `chunk` (clamped to the last chunk), as `f32`: four gathers
/// of x-neighbour pairs, one per row of the stencil ([`crate::volume::bricks::Grid::corners`]
/// in lanes).
#[inline(always)]
fn corners<L: Lanes>(voxels: &Voxels, chunk: usize, base: L::I) -> [L; 8] {
    let (sy, sz) = (L::splat_i(BRICK_SPAN as i32), L::splat_i((BRICK_SPAN * BRICK_SPAN) as i32));
    let (r1, r2) = (base + sy, base + sz);
    let r3 = r2 + sy;
    let ((a, b), (c, d), (e, f), (g, h)) = match voxels {
        Voxels::U8(grid) => {
            let data = &grid.chunks()[chunk.min(grid.chunks().len() - 1)][..];
            (
                L::gather_byte_pairs(data, base),
                L::gather_byte_pairs(data, r1),
                L::gather_byte_pairs(data, r2),
                L::gather_byte_pairs(data, r3),
            )
        }
        Voxels::U16(grid) => {
            let data = &grid.chunks()[chunk.min(grid.chunks().len() - 1)][..];
            (
                L::gather_short_pairs(data, base),
                L::gather_short_pairs(data, r1),
                L::gather_short_pairs(data, r2),
                L::gather_short_pairs(data, r3),
            )
        }
        Voxels::F32(grid) => {
            let data = &grid.chunks()[chunk.min(grid.chunks().len() - 1)][..];
            (
                L::gather_pairs(data, base),
                L::gather_pairs(data, r1),
                L::gather_pairs(data, r2),
                L::gather_pairs(data, r3),
            )
        }
    };
    [a, b, c, d, e, f, g, h]
}

/// Every picker's [`DepthPicker::threshold_target`], if all have one.
fn threshold_targets<const M: usize>(pickers: &[DepthPicker; M]) -> Option<[f32; M]> {
    let mut t = [f32::INFINITY; M];
    for (t, p) in t.iter_mut().zip(pickers) {
        *t = p.threshold_target()?;
    }
    Some(t)
}

/// Depth pickers with the rays' spread collectors ([`crate::radius::RadiusModel::Uncertainty`]).
struct PickSpread<const M: usize> {
    pickers: [DepthPicker; M],
    spread: [RaySpread; M],
}

impl<const M: usize> Feed<M> for PickSpread<M> {
    const ACTIVE: bool = true;
    #[inline(always)]
    fn feed(&mut self, bits: u64, t: &[f32; M], src_a: &[f32; M], dst_a: &[f32; M]) {
        for_lanes(bits, |l| {
            self.pickers[l].feed(t[l], src_a[l], dst_a[l]);
            self.spread[l].feed(t[l], dst_a[l]);
        });
    }
}

/// The rays of a packet (lanes past the packet's width unused), set up exactly as the scalar marcher sets up one ray.
struct Rays<const M: usize> {
    /// Unit directions (lanes outside the image get the packet's first direction).
    d: [Vec3; M],
    /// `1 / d`.
    inv_d: [Vec3; M],
    /// Box entry.
    t_enter: [f32; M],
    /// Box exit (`None`: the lane misses the box or lies outside the image).
    t_exit: [Option<f32>; M],
    /// One past the last sample index (the sample count, or a part's last sample to test).
    n: [f32; M],
    /// The first sample index (0, or a part's first sample to test).
    k0: [f32; M],
    /// A part's exit ([`PartWindow::part_exit`]; the box exit for the whole volume).
    part_exit: [f32; M],
}

/// One axis of the packet's rays, for the empty-space leaps.
struct Axis<L: Lanes> {
    /// Lanes whose `1 / d` along the axis is finite and positive.
    positive: L::M,
    /// Lanes whose `1 / d` along the axis is finite and not positive.
    negative: L::M,
    /// `1 / d` along the axis.
    inv_d: L,
    /// The voxel spacing along the axis.
    spacing: L,
    /// The eye's coordinate.
    o: L,
}

impl<L: Lanes> Axis<L> {
    #[inline(always)]
    fn new<const M: usize>(rays: &Rays<M>, a: usize, spacing: Vec3, o: Vec3) -> Axis<L> {
        let inv: [f32; M] = core::array::from_fn(|l| rays.inv_d[l][a]);
        let bits = |f: fn(f32) -> bool| inv.iter().enumerate().fold(0u64, |b, (l, &v)| b | u64::from(f(v)) << l);
        Axis {
            positive: L::mask_from_bits(bits(|v| v.is_finite() && v > 0.0)),
            negative: L::mask_from_bits(bits(|v| v.is_finite() && v <= 0.0)),
            inv_d: L::new(&inv),
            spacing: L::splat(spacing[a]),
            o: L::splat(o[a]),
        }
    }
}

/// What a trilinear sample in lanes reads: the clamp range, the bricks' layout in lanes and the
/// normalization ([`crate::volume::Volume::sample_grid_in`] in lanes).
struct Sampler<'a, L: Lanes> {
    voxels: &'a Voxels,
    lo: [L; 3],
    hi: [L; 3],
    sbx: L::I,
    sby: L::I,
    span: L::I,
    span2: L::I,
    brick_values: L::I,
    edge_mask: L::I,
    chunks: usize,
    per_chunk: L,
    per_chunk_inv: L,
    offset: L,
    scale: L,
    /// The gradient's voxel clamp range, `floor(lo) + 1` and `ceil(hi)`
    /// ([`crate::volume::Volume::gradient_grid_in`]).
    ilo1: [L; 3],
    /// `floor(lo)`: the clamp range's low end itself.
    ilo: [L; 3],
    /// Per axis, what one brick further along it adds to an index (x: a brick's values).
    brick_stride: [L::I; 3],
    ihi: [L; 3],
    half: L,
    one: L,
    minus_one_i: L::I,
    /// Whether samples read 4-byte quads for the gradient where they can (shading on, 8-bit
    /// voxels in one chunk).
    quad_mode: bool,
    two: L,
    /// `BRICK_EDGE − 1.5`: above it a local coordinate is the brick's last.
    last_local: L,
    one_i: L::I,
    /// Per axis, what stepping a neighbour across a brick face adds to its index.
    cross: [L::I; 3],
    /// Per axis, the lower neighbour's index offset where it crosses the face.
    cross_back: [L::I; 3],
}

impl<'a, L: Lanes> Sampler<'a, L> {
    #[inline(always)]
    fn new(m: &MarchSetup<'a>, voxels: &'a Voxels) -> Self {
        let (glo, ghi) = (m.cut.grid_lo(), m.cut.grid_hi());
        // The bricks ([`crate::volume::bricks`]): per axis, and the chunks of brick z-slabs.
        let layout = *voxels.layout();
        let nbr = layout.bricks();
        let (offset, scale) = m.volume.normalization();
        // A brick one over along x, y, z (within a chunk's slab), against 32 voxels along the
        // axis in the same brick (i64: a chunk holds up to 2^31 values).
        let (bv, span, span2) = (BRICK_VALUES as i64, i64::from(BRICK_SPAN), i64::from(BRICK_SPAN * BRICK_SPAN));
        let cross =
            [bv - 32, i64::from(nbr[0]) * bv - 32 * span, i64::from(nbr[0]) * i64::from(nbr[1]) * bv - 32 * span2];
        let cross_back = [-1 - cross[0], -span - cross[1], -span2 - cross[2]];
        Sampler {
            voxels,
            lo: [L::splat(glo.x), L::splat(glo.y), L::splat(glo.z)],
            hi: [L::splat(ghi.x), L::splat(ghi.y), L::splat(ghi.z)],
            sbx: L::splat_i(nbr[0] as i32),
            sby: L::splat_i(nbr[1] as i32),
            span: L::splat_i(BRICK_SPAN as i32),
            span2: L::splat_i((BRICK_SPAN * BRICK_SPAN) as i32),
            brick_values: L::splat_i(BRICK_VALUES as i32),
            edge_mask: L::splat_i(BRICK_EDGE as i32 - 1),
            chunks: layout.chunks(),
            per_chunk: L::splat((1u32 << layout.slab_shift()) as f32),
            per_chunk_inv: L::splat(1.0 / (1u32 << layout.slab_shift()) as f32),
            offset: L::splat(offset),
            scale: L::splat(scale),
            ilo1: [L::splat(glo.x.floor() + 1.0), L::splat(glo.y.floor() + 1.0), L::splat(glo.z.floor() + 1.0)],
            ilo: [L::splat(glo.x.floor()), L::splat(glo.y.floor()), L::splat(glo.z.floor())],
            // Only read with one chunk (`Sampler::gradient_clamped`), whose indices fit `i32`.
            brick_stride: [
                L::splat_i(bv as i32),
                L::splat_i((i64::from(nbr[0]) * bv) as i32),
                L::splat_i((i64::from(nbr[0]) * i64::from(nbr[1]) * bv) as i32),
            ],
            ihi: [L::splat(ghi.x.ceil()), L::splat(ghi.y.ceil()), L::splat(ghi.z.ceil())],
            half: L::splat(0.5),
            one: L::splat(1.0),
            minus_one_i: L::splat_i(-1),
            quad_mode: m.opts.shading.is_some() && matches!(voxels, Voxels::U8(_)) && layout.chunks() == 1,
            two: L::splat(2.0),
            last_local: L::splat(BRICK_EDGE as f32 - 1.5),
            one_i: L::splat_i(1),
            cross: [L::splat_i(cross[0] as i32), L::splat_i(cross[1] as i32), L::splat_i(cross[2] as i32)],
            cross_back: [
                L::splat_i(cross_back[0] as i32),
                L::splat_i(cross_back[1] as i32),
                L::splat_i(cross_back[2] as i32),
            ],
        }
    }

    /// The normalized trilinear sample at continuous voxel coordinates `(px, py, pz)`, clamped
    /// to the sampler's range: `Volume::sample_grid_in`, in lanes, bit for bit; and its
    /// stencil, for the gradient ([`Sampler::gradient`]).
    ///
    /// With `Sampler::quad_mode` and every lane of `lanes` at a local x of 1 to
    /// `BRICK_EDGE − 2`, the stencil's rows are read as 4-byte gathers at `x0 − 1` (the same
    /// count as the pairs), which hold the gradient's x stencils too (`Cell::x`).
    #[inline(always)]
    fn sample<const M: usize>(&self, px: L, py: L, pz: L, lanes: L::M) -> (L, Cell<L>) {
        let gx = px.max(self.lo[0]).min(self.hi[0]);
        let gy = py.max(self.lo[1]).min(self.hi[1]);
        let gz = pz.max(self.lo[2]).min(self.hi[2]);
        let (xi, yi, zi) = (gx.trunc_int(), gy.trunc_int(), gz.trunc_int());
        let (xf, yf, zf) = (L::int_to_float(xi), L::int_to_float(yi), L::int_to_float(zi));
        let (fx, fy, fz) = (gx - xf, gy - yf, gz - zf);
        // The stencil's brick and its lowest corner in it: the other corners are at +1,
        // +BRICK_SPAN and +BRICK_SPAN² (the brick's apron holds the far ones; past the
        // volume's last voxel it repeats it, where the fraction is exactly 0, so
        // `c + (far - c) * 0` is `c`, as the scalar marcher's read gives).
        let (sbx, sby, span, span2, brick_values) = (self.sbx, self.sby, self.span, self.span2, self.brick_values);
        let (bx, by, bz) = (L::shr_i::<SHIFT>(xi), L::shr_i::<SHIFT>(yi), L::shr_i::<SHIFT>(zi));
        let (lx, ly, lz) = (L::and_i(xi, self.edge_mask), L::and_i(yi, self.edge_mask), L::and_i(zi, self.edge_mask));
        let mut x = None;
        let (c000, c100, c010, c110, c001, c101, c011, c111, base, chunk, foreign) = if self.chunks == 1 {
            let brick = bx + L::mul_i(sbx, by + L::mul_i(sby, bz));
            let base = L::mul_i(brick, brick_values) + lx + L::mul_i(span, ly) + L::mul_i(span2, lz);
            let lxf = L::int_to_float(lx);
            let quads = lxf.simd_ge(self.one) & self.last_local.simd_gt(lxf);
            match self.voxels {
                Voxels::U8(grid) if self.quad_mode && !lanes.and_not(quads).any() => {
                    let data = &grid.chunks()[0][..];
                    let xm = base + self.minus_one_i;
                    let [a0, c000, c100, d0] = L::gather_byte_quads(data, xm);
                    let [a1, c010, c110, d1] = L::gather_byte_quads(data, xm + span);
                    let [a2, c001, c101, d2] = L::gather_byte_quads(data, xm + span2);
                    let [a3, c011, c111, d3] = L::gather_byte_quads(data, xm + span + span2);
                    // The gradient's x stencils (`Volume::gradient_grid_in`'s order).
                    let (l00, l10, l01, l11) =
                        (lerp(a0, c000, fx), lerp(a1, c010, fx), lerp(a2, c001, fx), lerp(a3, c011, fx));
                    let (h00, h10, h01, h11) =
                        (lerp(c100, d0, fx), lerp(c110, d1, fx), lerp(c101, d2, fx), lerp(c111, d3, fx));
                    let xlo = lerp(lerp(l00, l10, fy), lerp(l01, l11, fy), fz);
                    let xhi = lerp(lerp(h00, h10, fy), lerp(h01, h11, fy), fz);
                    x = Some(xhi - xlo);
                    (c000, c100, c010, c110, c001, c101, c011, c111, base, 0, L::mask_from_bits(0))
                }
                _ => {
                    let [c0, c1, c2, c3, c4, c5, c6, c7] = corners::<L>(self.voxels, 0, base);
                    (c0, c1, c2, c3, c4, c5, c6, c7, base, 0, L::mask_from_bits(0))
                }
            }
        } else {
            // Several chunks of brick z-slabs: each lane's chunk and slab in it.
            let bzf = L::int_to_float(bz);
            let czf = L::int_to_float((bzf * self.per_chunk_inv).trunc_int());
            let bzl = (bzf - czf * self.per_chunk).trunc_int();
            let brick = bx + L::mul_i(sbx, by + L::mul_i(sby, bzl));
            let base = L::mul_i(brick, brick_values) + lx + L::mul_i(span, ly) + L::mul_i(span2, lz);
            // Usually every lane is in the first lane's chunk: one set of gathers.
            let cs: [f32; M] = czf.to_array();
            let c0 = L::splat(cs[0]);
            let mut acc = corners::<L>(self.voxels, cs[0] as usize, base);
            if (czf.simd_gt(c0) | czf.simd_lt(c0)).any() {
                let (mut first, mut last) = (cs[0], cs[0]);
                for &c in &cs[1..] {
                    first = first.min(c);
                    last = last.max(c);
                }
                let mut c = first;
                while c <= last {
                    // The first lane's chunk is gathered already.
                    if c != cs[0] {
                        let cl = L::splat(c);
                        let here = czf.simd_ge(cl).and_not(czf.simd_gt(cl));
                        let part = corners::<L>(self.voxels, c as usize, base);
                        for (a, p) in acc.iter_mut().zip(part) {
                            *a = here.select(p, *a);
                        }
                    }
                    c += 1.0;
                }
            }
            let [c0, c1, c2, c3, c4, c5, c6, c7] = acc;
            // Lanes outside the first lane's chunk, or whose gradient's slices may lie in
            // another chunk (a z-neighbour across a brick slab): the gradient's gathers read
            // the first lane's chunk only, so these lanes take the scalar gradient.
            let lzf = L::int_to_float(lz);
            let foreign = czf.simd_gt(c0) | czf.simd_lt(c0) | lzf.simd_lt(self.half) | lzf.simd_gt(self.last_local);
            (c0, c1, c2, c3, c4, c5, c6, c7, base, cs[0] as usize, foreign)
        };
        let c00 = c000 + (c100 - c000) * fx;
        let c10 = c010 + (c110 - c010) * fx;
        let c01 = c001 + (c101 - c001) * fx;
        let c11 = c011 + (c111 - c011) * fx;
        let c0 = c00 + (c10 - c00) * fy;
        let c1 = c01 + (c11 - c01) * fy;
        let v = (c0 + (c1 - c0) * fz - self.offset) * self.scale;
        // Where the gradient's reads all lie in the clamp range (no voxel of it clamped) and in
        // the gathered chunk.
        let two = self.two;
        let inside_x = xf.simd_ge(self.ilo1[0]) & self.ihi[0].simd_ge(xf + two);
        let inside_y = yf.simd_ge(self.ilo1[1]) & self.ihi[1].simd_ge(yf + two);
        let inside_z = zf.simd_ge(self.ilo1[2]) & self.ihi[2].simd_ge(zf + two);
        let inside = (inside_x & inside_y & inside_z).and_not(foreign);
        (v, Cell { fx, fy, fz, lx, ly, lz, base, chunk, inside, rows: [c00, c10, c01, c11], c0, c1, x })
    }

    /// The gradient differences of [`crate::volume::Volume::gradient_grid_in`] (normalized,
    /// before `1 / spacing`) at the sample of `cell`, bit for bit, in the lanes of
    /// `cell.inside` (the others' lanes are garbage): sixteen gathers of voxel pairs from the
    /// neighbour bricks, addressed from the sample's own lowest corner.
    #[inline(always)]
    fn gradient(&self, cell: &Cell<L>) -> (L, L, L) {
        let (lx, ly, lz, base, chunk) = (cell.lx, cell.ly, cell.lz, cell.base, cell.chunk);
        let (span, span2) = (self.span, self.span2);
        // A neighbour's lowest voxel, one brick over where the step leaves the brick: `first`
        // is 1 where the local coordinate is 0, `last` where it is BRICK_EDGE − 1 (the brick's
        // apron holds local BRICK_EDGE, so only these cross).
        // (No closures here: see `band`.)
        let (em, one) = (self.edge_mask, self.one_i);
        let [kx, ky, kz] = self.cross;
        let [bx, by, bz] = self.cross_back;
        // x: the pairs (x0 − 1, x0) and (x0 + 1, x0 + 2) of the four rows.
        let xm = base + bx + L::mul_i(L::shr_i::<SHIFT>(lx + em), kx);
        let xp = base + one + L::mul_i(L::shr_i::<SHIFT>(lx + one), kx);
        // y: row y0 − 1 and row y0 + 2, on slices z0 and z0 + 1.
        let ym = base + by + L::mul_i(L::shr_i::<SHIFT>(ly + em), ky);
        let yp = base + span + span + L::mul_i(L::shr_i::<SHIFT>(ly + one), ky);
        // z: slice z0 − 1 and slice z0 + 2, rows y0 and y0 + 1.
        let zm = base + bz + L::mul_i(L::shr_i::<SHIFT>(lz + em), kz);
        let zp = base + span2 + span2 + L::mul_i(L::shr_i::<SHIFT>(lz + one), kz);
        // One copy of the blends per stored type; no arrays of lanes (copied with `memmove`
        // when they were).
        let (dx, dy, dz) = match self.voxels {
            Voxels::U8(grid) => {
                let data = &grid.chunks()[chunk.min(grid.chunks().len() - 1)][..];
                // Where no lane's x-neighbours leave its brick (local x in 1 ..= BRICK_EDGE − 2),
                // one 4-byte gather at x0 − 1 holds a row's x0 − 1 ..= x0 + 2: the x stencils'
                // rows in four gathers, not eight.
                let lxf = L::int_to_float(lx);
                let quads = lxf.simd_ge(self.one) & self.last_local.simd_gt(lxf);
                if let Some(dx) = cell.x {
                    let (dy, dz) = blend_gradient_yz::<L, u8>(data, cell, [ym, yp, zm, zp], span, span2);
                    (dx, dy, dz)
                } else if cell.inside.and_not(quads).any() {
                    blend_gradient::<L, u8>(data, cell, [xm, xp, ym, yp, zm, zp], span, span2)
                } else {
                    let (fx, fy, fz) = (cell.fx, cell.fy, cell.fz);
                    let [l00, h00] = quad_rows::<L>(data, xm, fx);
                    let [l10, h10] = quad_rows::<L>(data, xm + span, fx);
                    let [l01, h01] = quad_rows::<L>(data, xm + span2, fx);
                    let [l11, h11] = quad_rows::<L>(data, xm + span + span2, fx);
                    let xlo = lerp(lerp(l00, l10, fy), lerp(l01, l11, fy), fz);
                    let xhi = lerp(lerp(h00, h10, fy), lerp(h01, h11, fy), fz);
                    let (dy, dz) = blend_gradient_yz::<L, u8>(data, cell, [ym, yp, zm, zp], span, span2);
                    (xhi - xlo, dy, dz)
                }
            }
            Voxels::U16(grid) => {
                let data = &grid.chunks()[chunk.min(grid.chunks().len() - 1)][..];
                blend_gradient::<L, u16>(data, cell, [xm, xp, ym, yp, zm, zp], span, span2)
            }
            Voxels::F32(grid) => {
                let data = &grid.chunks()[chunk.min(grid.chunks().len() - 1)][..];
                blend_gradient::<L, f32>(data, cell, [xm, xp, ym, yp, zm, zp], span, span2)
            }
        };
        (dx * self.scale, dy * self.scale, dz * self.scale)
    }
}

impl<'a, L: Lanes> Sampler<'a, L> {
    /// The index offset of voxel coordinate `c` (per lane, `c` in the clamp range) along axis
    /// `a`: its brick's stride and its place in the brick.
    #[inline(always)]
    fn axis_offset(&self, c: L, a: usize, local_stride: L::I) -> L::I {
        let c = c.trunc_int();
        L::mul_i(L::shr_i::<SHIFT>(c), self.brick_stride[a]) + L::mul_i(L::and_i(c, self.edge_mask), local_stride)
    }

    /// [`crate::volume::Volume::gradient_grid_in`] in lanes, bit for bit, scaled as
    /// [`Sampler::gradient`]'s, for every lane at `(px, py, pz)` ([`Sampler::gradient_clamped`]);
    /// `None` with several chunks (the scalar definition serves those lanes).
    #[inline(always)]
    fn gradient_edge(&self, px: L, py: L, pz: L) -> Option<(L, L, L)> {
        if self.chunks != 1 {
            return None;
        }
        let (dx, dy, dz) = match self.voxels {
            Voxels::U8(grid) => self.gradient_clamped::<u8>(&grid.chunks()[0][..], px, py, pz),
            Voxels::U16(grid) => self.gradient_clamped::<u16>(&grid.chunks()[0][..], px, py, pz),
            Voxels::F32(grid) => self.gradient_clamped::<f32>(&grid.chunks()[0][..], px, py, pz),
        };
        Some((dx * self.scale, dy * self.scale, dz * self.scale))
    }

    /// [`crate::volume::Volume::gradient_grid_in`] in lanes, bit for bit, for every lane
    /// (before the scale, as [`Sampler::gradient`]), each voxel read at its clamped
    /// coordinates: what the lanes at the volume's or crop's edge take. One chunk only (the
    /// indices address the first).
    ///
    /// The stencil's 32 voxels are single gathers (the low value of a pair gather at the
    /// clamped voxel's index: the brick's apron keeps the pair inside the brick), the blends
    /// are the scalar definition's in its order.
    #[inline(always)]
    fn gradient_clamped<T: Pairs>(&self, data: &[T], px: L, py: L, pz: L) -> (L, L, L) {
        let gx = px.max(self.lo[0]).min(self.hi[0]);
        let gy = py.max(self.lo[1]).min(self.hi[1]);
        let gz = pz.max(self.lo[2]).min(self.hi[2]);
        let (x0, y0, z0) =
            (L::int_to_float(gx.trunc_int()), L::int_to_float(gy.trunc_int()), L::int_to_float(gz.trunc_int()));
        let (fx, fy, fz) = (gx - x0, gy - y0, gz - z0);
        let (m1, one, two) = (L::splat(-1.0), self.one, self.two);
        // The clamped coordinates x0 − 1 ..= x0 + 2 per axis as index offsets.
        // (No closures here: see `band`.)
        let (lo, hi) = (self.ilo, self.ihi);
        let unit = self.one_i;
        let ox = [
            self.axis_offset((x0 + m1).max(lo[0]).min(hi[0]), 0, unit),
            self.axis_offset(x0.max(lo[0]).min(hi[0]), 0, unit),
            self.axis_offset((x0 + one).max(lo[0]).min(hi[0]), 0, unit),
            self.axis_offset((x0 + two).max(lo[0]).min(hi[0]), 0, unit),
        ];
        let oy = [
            self.axis_offset((y0 + m1).max(lo[1]).min(hi[1]), 1, self.span),
            self.axis_offset(y0.max(lo[1]).min(hi[1]), 1, self.span),
            self.axis_offset((y0 + one).max(lo[1]).min(hi[1]), 1, self.span),
            self.axis_offset((y0 + two).max(lo[1]).min(hi[1]), 1, self.span),
        ];
        let oz = [
            self.axis_offset((z0 + m1).max(lo[2]).min(hi[2]), 2, self.span2),
            self.axis_offset(z0.max(lo[2]).min(hi[2]), 2, self.span2),
            self.axis_offset((z0 + one).max(lo[2]).min(hi[2]), 2, self.span2),
            self.axis_offset((z0 + two).max(lo[2]).min(hi[2]), 2, self.span2),
        ];
        // The voxels x0 − 1 ..= x0 + 2 of the stencil's own four rows, x0 and x0 + 1 of the
        // rows around them (inline functions, no closures: see `band`).
        let [r00, r10, r01, r11] = [oy[1] + oz[1], oy[2] + oz[1], oy[1] + oz[2], oy[2] + oz[2]];
        let q00 = voxel_quad::<L, T>(data, &ox, r00);
        let q10 = voxel_quad::<L, T>(data, &ox, r10);
        let q01 = voxel_quad::<L, T>(data, &ox, r01);
        let q11 = voxel_quad::<L, T>(data, &ox, r11);
        // The stencil's own rows, and the rows one voxel lower and higher along x.
        let (m00, m10, m01, m11) =
            (lerp(q00[1], q00[2], fx), lerp(q10[1], q10[2], fx), lerp(q01[1], q01[2], fx), lerp(q11[1], q11[2], fx));
        let xlo = lerp(
            lerp(lerp(q00[0], q00[1], fx), lerp(q10[0], q10[1], fx), fy),
            lerp(lerp(q01[0], q01[1], fx), lerp(q11[0], q11[1], fx), fy),
            fz,
        );
        let xhi = lerp(
            lerp(lerp(q00[2], q00[3], fx), lerp(q10[2], q10[3], fx), fy),
            lerp(lerp(q01[2], q01[3], fx), lerp(q11[2], q11[3], fx), fy),
            fz,
        );
        // y: rows y0 − 1 and y0 + 2 on slices z0 and z0 + 1.
        let a0 = clamped_row::<L, T>(data, &ox, oy[0] + oz[1], fx);
        let a1 = clamped_row::<L, T>(data, &ox, oy[0] + oz[2], fx);
        let b0 = clamped_row::<L, T>(data, &ox, oy[3] + oz[1], fx);
        let b1 = clamped_row::<L, T>(data, &ox, oy[3] + oz[2], fx);
        let ylo = lerp(lerp(a0, m00, fy), lerp(a1, m01, fy), fz);
        let yhi = lerp(lerp(m10, b0, fy), lerp(m11, b1, fy), fz);
        // z: slices z0 − 1 and z0 + 2, rows y0 and y0 + 1.
        let e = lerp(
            clamped_row::<L, T>(data, &ox, oy[1] + oz[0], fx),
            clamped_row::<L, T>(data, &ox, oy[2] + oz[0], fx),
            fy,
        );
        let f = lerp(
            clamped_row::<L, T>(data, &ox, oy[1] + oz[3], fx),
            clamped_row::<L, T>(data, &ox, oy[2] + oz[3], fx),
            fy,
        );
        let (c0, c1) = (lerp(m00, m10, fy), lerp(m01, m11, fy));
        (xhi - xlo, yhi - ylo, lerp(c1, f, fz) - lerp(e, c0, fz))
    }
}

/// Per lane the voxels at `ox[i] + yz`, `i` = 0 ..= 3 ([`Sampler::gradient_clamped`]).
#[inline(always)]
fn voxel_quad<L: Lanes, T: Pairs>(data: &[T], ox: &[L::I; 4], yz: L::I) -> [L; 4] {
    [
        T::pairs::<L>(data, ox[0] + yz).0,
        T::pairs::<L>(data, ox[1] + yz).0,
        T::pairs::<L>(data, ox[2] + yz).0,
        T::pairs::<L>(data, ox[3] + yz).0,
    ]
}

/// Per lane the row of voxels `ox[1] + yz` and `ox[2] + yz` (x0 and x0 + 1, clamped) blended
/// at `fx` ([`Sampler::gradient_clamped`]).
#[inline(always)]
fn clamped_row<L: Lanes, T: Pairs>(data: &[T], ox: &[L::I; 4], yz: L::I, fx: L) -> L {
    lerp(T::pairs::<L>(data, ox[1] + yz).0, T::pairs::<L>(data, ox[2] + yz).0, fx)
}

/// A sample's stencil in lanes ([`Sampler::sample`]): what its gradient reads.
#[derive(Clone, Copy)]
struct Cell<L: Lanes> {
    fx: L,
    fy: L,
    fz: L,
    /// The lowest corner's coordinates in its brick.
    lx: L::I,
    ly: L::I,
    lz: L::I,
    /// The lowest corner's index in its chunk.
    base: L::I,
    /// The chunk the gradient's gathers read.
    chunk: usize,
    /// Lanes whose gradient [`Sampler::gradient`] computes.
    inside: L::M,
    /// The stencil's rows blended along x: `[c00, c10, c01, c11]`.
    rows: [L; 4],
    /// Its slices blended along x and y.
    c0: L,
    c1: L,
    /// The gradient's x difference (before the scale) where the sample read it already.
    x: Option<L>,
}

/// A stored type the lanes gather in x-neighbour pairs.
trait Pairs: Sized {
    /// Per lane `(data[i], data[i + 1])` as `f32`.
    fn pairs<L: Lanes>(data: &[Self], i: L::I) -> (L, L);
}

impl Pairs for u8 {
    #[inline(always)]
    fn pairs<L: Lanes>(data: &[u8], i: L::I) -> (L, L) {
        L::gather_byte_pairs(data, i)
    }
}

impl Pairs for u16 {
    #[inline(always)]
    fn pairs<L: Lanes>(data: &[u16], i: L::I) -> (L, L) {
        L::gather_short_pairs(data, i)
    }
}

impl Pairs for f32 {
    #[inline(always)]
    fn pairs<L: Lanes>(data: &[f32], i: L::I) -> (L, L) {
        L::gather_pairs(data, i)
    }
}

/// A row of voxel pairs at `i` blended along x at `fx`.
#[inline(always)]
fn row<L: Lanes, T: Pairs>(data: &[T], i: L::I, fx: L) -> L {
    let (a, b) = T::pairs::<L>(data, i);
    a + (b - a) * fx
}

/// The rows `x0 − 1, x0` and `x0 + 1, x0 + 2` of one 4-byte gather at `i` (`x0 − 1`),
/// blended along x at `fx`.
#[inline(always)]
fn quad_rows<L: Lanes>(data: &[u8], i: L::I, fx: L) -> [L; 2] {
    let [a, b, c, d] = L::gather_byte_quads(data, i);
    [a + (b - a) * fx, c + (d - c) * fx]
}

/// [`Sampler::gradient`]'s gathers and blends from `data`, the neighbours' lowest indices
/// `[xm, xp, ym, yp, zm, zp]` given.
#[inline(always)]
fn blend_gradient<L: Lanes, T: Pairs>(data: &[T], cell: &Cell<L>, n: [L::I; 6], span: L::I, span2: L::I) -> (L, L, L) {
    let (fx, fy, fz) = (cell.fx, cell.fy, cell.fz);
    let [xm, xp, ym, yp, zm, zp] = n;
    // x: the stencils one voxel lower and higher, in trilinear's order.
    let (l00, l10) = (row::<L, T>(data, xm, fx), row::<L, T>(data, xm + span, fx));
    let (l01, l11) = (row::<L, T>(data, xm + span2, fx), row::<L, T>(data, xm + span + span2, fx));
    let xlo = lerp(lerp(l00, l10, fy), lerp(l01, l11, fy), fz);
    let (h00, h10) = (row::<L, T>(data, xp, fx), row::<L, T>(data, xp + span, fx));
    let (h01, h11) = (row::<L, T>(data, xp + span2, fx), row::<L, T>(data, xp + span + span2, fx));
    let xhi = lerp(lerp(h00, h10, fy), lerp(h01, h11, fy), fz);
    let (dy, dz) = blend_gradient_yz::<L, T>(data, cell, [ym, yp, zm, zp], span, span2);
    (xhi - xlo, dy, dz)
}

/// [`blend_gradient`]'s y and z differences.
#[inline(always)]
fn blend_gradient_yz<L: Lanes, T: Pairs>(data: &[T], cell: &Cell<L>, n: [L::I; 4], span: L::I, span2: L::I) -> (L, L) {
    let (fx, fy, fz) = (cell.fx, cell.fy, cell.fz);
    let [m00, m10, m01, m11] = cell.rows;
    let [ym, yp, zm, zp] = n;
    // y: rows y0 − 1 and y0 + 2 against the stencil's own.
    let (a0, a1) = (row::<L, T>(data, ym, fx), row::<L, T>(data, ym + span2, fx));
    let ylo = lerp(lerp(a0, m00, fy), lerp(a1, m01, fy), fz);
    let (b0, b1) = (row::<L, T>(data, yp, fx), row::<L, T>(data, yp + span2, fx));
    let yhi = lerp(lerp(m10, b0, fy), lerp(m11, b1, fy), fz);
    // z: slices z0 − 1 and z0 + 2 against the stencil's own.
    let e = lerp(row::<L, T>(data, zm, fx), row::<L, T>(data, zm + span, fx), fy);
    let zlo = lerp(e, cell.c0, fz);
    let f = lerp(row::<L, T>(data, zp, fx), row::<L, T>(data, zp + span, fx), fy);
    let zhi = lerp(cell.c1, f, fz);
    (yhi - ylo, zhi - zlo)
}

/// `a + (b − a)·f`: the marchers' blend.
#[inline(always)]
fn lerp<L: Lanes>(a: L, b: L, f: L) -> L {
    a + (b - a) * f
}

/// The march settings the kernel reads, borrowed from a [`crate::marcher::Marcher`].
pub(crate) struct Kernel<'a> {
    /// The options, step and volume box.
    pub(crate) m: MarchSetup<'a>,
    /// The volume's bricked voxels.
    pub(crate) voxels: &'a Voxels,
    /// The opacity-corrected, premultiplied transfer function as (a, r, g, b) entries.
    pub(crate) lut: &'a [f32],
    /// [`crate::empty_space::Occupancy::look_table`].
    pub(crate) looks: &'a [f32],
    /// A part of a volume split across ranks: the rays on the whole volume's grid, samples
    /// where the part owns them (`None`: the whole volume is the marcher's).
    pub(crate) part: Option<&'a PartWindow>,
}

impl Kernel<'_> {
    /// The rays of the `lanes`-pixel packet at `(x0, y0)`.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn rays<const M: usize>(
        &self,
        lanes: usize,
        basis: &RayBasis,
        o: Vec3,
        x0: u32,
        y0: u32,
        w: u32,
        h: u32,
    ) -> Rays<M> {
        let mut r = Rays {
            d: [Vec3::ZERO; M],
            inv_d: [Vec3::ZERO; M],
            t_enter: [0.0; M],
            t_exit: [None; M],
            n: [0.0; M],
            k0: [0.0; M],
            part_exit: [0.0; M],
        };
        let first = basis.dir(x0, y0);
        for l in 0..lanes {
            let (x, y) = (x0 + (l % pw(lanes)) as u32, y0 + (l / pw(lanes)) as u32);
            if x >= w || y >= h {
                r.d[l] = first;
                r.inv_d[l] = 1.0 / first;
                continue;
            }
            let d = basis.dir(x, y);
            let (te, tx, k0, k1) = match self.part {
                None => {
                    let (ray_n, te, tx) = self.m.ray_setup(o, d);
                    (te, tx, 0, ray_n)
                }
                Some(w) => {
                    let (_, te, tx, k0, k1) = w.ray(o, d, self.m.dt);
                    if let Some(tx) = tx {
                        r.part_exit[l] = w.part_exit(o, d, tx);
                    }
                    (te, tx, k0, k1)
                }
            };
            r.d[l] = d;
            r.inv_d[l] = 1.0 / d;
            if let Some(tx) = tx {
                r.t_enter[l] = te;
                r.t_exit[l] = Some(tx);
                r.n[l] = k1 as f32;
                r.k0[l] = k0 as f32;
            }
        }
        r
    }

    /// Marches the packet's rays, feeding `feed`; returns each lane's premultiplied color.
    #[inline(always)]
    fn march<L: Lanes, F: Feed<M>, const M: usize>(&self, o: Vec3, rays: &Rays<M>, feed: &mut F) -> [[f32; 4]; M] {
        self.march_in::<L, F, M, false>(o, rays, feed)
    }

    /// [`Kernel::march`]; with `P`, of the kernel's part ([`Kernel::part`]): a lane samples
    /// only the grid positions the part owns, in the part's held block (the offset subtracted,
    /// an exact operation), and its empty-space leaps run in the block's coordinates. The
    /// positions, compositing and early termination are otherwise the same operations (so a
    /// part's samples are the whole volume's bit for bit).
    #[inline(always)]
    fn march_in<L: Lanes, F: Feed<M>, const M: usize, const P: bool>(
        &self,
        o: Vec3,
        rays: &Rays<M>,
        feed: &mut F,
    ) -> [[f32; 4]; M] {
        let m = self.m;
        let vol = m.volume;
        let dt = m.dt;
        let opts = m.opts;
        let occ = m.occupancy;
        let inv_spacing = m.inv_spacing;
        let og = o * inv_spacing - 0.5;
        let dg: [Vec3; M] = core::array::from_fn(|l| rays.d[l] * inv_spacing);
        let dgx = L::new(&core::array::from_fn::<f32, M, _>(|l| dg[l].x));
        let dgy = L::new(&core::array::from_fn::<f32, M, _>(|l| dg[l].y));
        let dgz = L::new(&core::array::from_fn::<f32, M, _>(|l| dg[l].z));
        let (ogx, ogy, ogz) = (L::splat(og.x), L::splat(og.y), L::splat(og.z));
        let te = L::new(&rays.t_enter);
        let n = L::new(&rays.n);
        let (dtl, half, one, zero) = (L::splat(dt), L::splat(0.5), L::splat(1.0), L::splat(0.0));
        let sampler = Sampler::<L>::new(&m, self.voxels);
        let (glo, ghi) = (m.cut.grid_lo(), m.cut.grid_hi());
        // Shading: the weights, the light, each lane's half vector and `1 / spacing`.
        let shading = opts.shading;
        let sh = shading.unwrap_or(crate::march_settings::Shading::DEFAULT);
        let (ka, kd, ks) = (L::splat(sh.ambient), L::splat(sh.diffuse), L::splat(sh.specular));
        let (lx, ly, lz) = (L::splat(sh.light.x), L::splat(sh.light.y), L::splat(sh.light.z));
        let hv: [Vec3; M] = core::array::from_fn(|l| sh.half_vector(rays.d[l]));
        let hx = L::new(&core::array::from_fn::<f32, M, _>(|l| hv[l].x));
        let hy = L::new(&core::array::from_fn::<f32, M, _>(|l| hv[l].y));
        let hz = L::new(&core::array::from_fn::<f32, M, _>(|l| hv[l].z));
        let (isx, isy, isz) = (L::splat(inv_spacing.x), L::splat(inv_spacing.y), L::splat(inv_spacing.z));
        // TransferFunction::index scales by the last entry's index and clamps to it.
        let lut_max = L::splat((self.lut.len() / 4).max(1) as f32 - 1.0);
        let ert = L::splat(opts.early_termination);
        // No closure calls a lane method here (see `band`).
        let nb = occ.bricks();
        let (nbx, nby, nbz) = (L::splat(nb[0] as f32), L::splat(nb[1] as f32), L::splat(nb[2] as f32));
        let (nbx_m1, nby_m1, nbz_m1) =
            (L::splat((nb[0] - 1) as f32), L::splat((nb[1] - 1) as f32), L::splat((nb[2] - 1) as f32));
        let (snbx, snby) = (L::splat_i(nb[0] as i32), L::splat_i(nb[1] as i32));
        let brick = L::splat(occ.brick() as f32);
        let sp = vol.spacing();
        // The part's window in lanes (the whole volume's: no offset, every position owned).
        let (inf, ninf) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        let (off, own_lo, own_hi, o_axes) = match self.part {
            Some(w) if P => (w.off, w.own_lo, w.own_hi, o - w.origin),
            _ => (Vec3::ZERO, ninf, inf, o),
        };
        let (offx, offy, offz) = (L::splat(off.x), L::splat(off.y), L::splat(off.z));
        let (olx, oly, olz) = (L::splat(own_lo.x), L::splat(own_lo.y), L::splat(own_lo.z));
        let (ohx, ohy, ohz) = (L::splat(own_hi.x), L::splat(own_hi.y), L::splat(own_hi.z));
        let axes =
            [Axis::<L>::new(rays, 0, sp, o_axes), Axis::new(rays, 1, sp, o_axes), Axis::new(rays, 2, sp, o_axes)];
        let skip = opts.skip_empty;

        let mut k = L::new(&rays.k0);
        let mut alive = zero.simd_lt(n);
        // `Feed::LANE_THRESHOLD`: each lane's target, whether it is still unmet, and the `t`
        // where it was met.
        let target = if F::LANE_THRESHOLD { L::new(&feed.targets()) } else { zero };
        let (mut unmet, mut chosen) = (one.simd_gt(zero), zero);
        let mut t_check = L::splat(f32::NEG_INFINITY);
        let (mut r, mut g, mut b, mut a) = (zero, zero, zero, zero);
        loop {
            // Lanes with samples left. A lane stopped by early termination keeps stepping
            // (masked out of compositing by `alive`): so the next sample's position depends only
            // on `k`, not on this sample's gathers, and consecutive steps overlap in the core.
            let mut running = k.simd_lt(n);
            let mut t = te + (k + half) * dtl;
            if skip {
                // The scalar marcher's skip step, in lanes: lanes at or past the brick face they
                // last checked look up their brick's distance to the nearest visible brick; a
                // lane in an invisible brick leaps to its first sample past the empty cube
                // around it and is checked again there, a lane in a visible one samples (as the
                // scalar marcher, whatever `t_out` says) and next checks at `t_out`.
                let mut check = alive & running & t.simd_ge(t_check);
                if P {
                    // A part looks only at samples it owns (the others it steps over).
                    let (px, py, pz) = (ogx + dgx * t, ogy + dgy * t, ogz + dgz * t);
                    let own = px.simd_ge(olx) & px.simd_lt(ohx) & py.simd_ge(oly);
                    check = check & own & py.simd_lt(ohy) & pz.simd_ge(olz) & pz.simd_lt(ohz);
                }
                while check.any() {
                    let (px, py, pz) = (ogx + dgx * t, ogy + dgy * t, ogz + dgz * t);
                    let (px, py, pz) = if P { (px - offx, py - offy, pz - offz) } else { (px, py, pz) };
                    let per_brick = L::splat(1.0 / occ.brick() as f32);
                    let bx = (px * per_brick).max(zero).min(nbx_m1).trunc_int();
                    let by = (py * per_brick).max(zero).min(nby_m1).trunc_int();
                    let bz = (pz * per_brick).max(zero).min(nbz_m1).trunc_int();
                    let bi = bx + L::mul_i(snbx, by + L::mul_i(snby, bz));
                    // The look's result: an invisible brick's distance, or minus a visible one's
                    // reach (`Occupancy::look_table`).
                    let dist = L::gather(self.looks, bi);
                    let reach = dist.max(zero - dist) - one;
                    let (bxf, byf, bzf) = (L::int_to_float(bx), L::int_to_float(by), L::int_to_float(bz));
                    let mut t_out = L::splat(f32::INFINITY);
                    for (bf, nb, ax) in [(bxf, nbx, &axes[0]), (byf, nby, &axes[1]), (bzf, nbz, &axes[2])] {
                        let hi = bf + reach + one;
                        let lo = bf - reach;
                        let up = ax.positive & hi.simd_lt(nb);
                        let down = ax.negative & bf.simd_ge(reach + one);
                        let plane = up.select(hi, lo) * brick + half;
                        let ta = (plane * ax.spacing - ax.o) * ax.inv_d;
                        t_out = (up | down).select(t_out.min(ta), t_out);
                    }
                    let empty = check & dist.simd_gt(zero);
                    // Resume at the first lattice sample at or after t_out (no progress: one step).
                    let x = (t_out - te) / dtl - half;
                    let c = L::int_to_float(x.max(zero).min(n).trunc_int());
                    let ceil = c + c.simd_lt(x).select(one, zero);
                    let next = x.simd_ge(n).select(n, x.simd_gt(k + one).select(ceil, k + one));
                    k = empty.select(next, k);
                    t_check = check.and_not(empty).select(t_out, t_check);
                    running = k.simd_lt(n);
                    t = te + (k + half) * dtl;
                    check = empty & alive & running & t.simd_ge(t_check);
                    if P {
                        let (px, py, pz) = (ogx + dgx * t, ogy + dgy * t, ogz + dgz * t);
                        let own = px.simd_ge(olx) & px.simd_lt(ohx) & py.simd_ge(oly);
                        check = check & own & py.simd_lt(ohy) & pz.simd_ge(olz) & pz.simd_lt(ohz);
                    }
                }
            }
            let live = alive & running;
            if !live.any() {
                break;
            }
            // Volume::sample_grid_in, in lanes.
            let (px, py, pz) = (ogx + dgx * t, ogy + dgy * t, ogz + dgz * t);
            // A part composites the samples it owns, read from its held block.
            let (active, px, py, pz) = if P {
                let own = px.simd_ge(olx) & px.simd_lt(ohx) & py.simd_ge(oly);
                let own = own & py.simd_lt(ohy) & pz.simd_ge(olz) & pz.simd_lt(ohz);
                (live & own, px - offx, py - offy, pz - offz)
            } else {
                (live, px, py, pz)
            };
            let (v, cell) = sampler.sample::<M>(px, py, pz, active);
            // TransferFunction::index, in lanes.
            let idx = (v * lut_max + half).max(zero).min(lut_max).trunc_int();
            // The table's entries are (a, r, g, b): opacity and red in one 64-bit gather.
            let q = idx + idx;
            let q = q + q;
            let (ca, cr) = L::gather_pairs(self.lut, q);
            let vis = active & ca.simd_gt(zero);
            if vis.any() {
                let (cg, cb) = L::gather_pairs(self.lut, q + L::splat_i(2));
                let (cr, cg, cb) = if shading.is_some() {
                    // Shading::shade, in lanes: central differences (Volume::gradient_grid_in),
                    // then Blinn–Phong.
                    let (dx, dy, dz) = sampler.gradient(&cell);
                    // Visible lanes whose gradient reads a clamped voxel take the definition with
                    // every read clamped, in lanes; with several chunks (a lane whose gradient
                    // may read another chunk), the scalar definition. Rare: a sample at the
                    // volume's, crop's or chunk's edge.
                    let slow = vis.and_not(cell.inside);
                    let (dx, dy, dz) = if !slow.any() {
                        (dx, dy, dz)
                    } else {
                        let (qx, qy, qz) = (px.to_array::<M>(), py.to_array::<M>(), pz.to_array::<M>());
                        let (mut ax, mut ay, mut az) = (dx.to_array::<M>(), dy.to_array::<M>(), dz.to_array::<M>());
                        let slow = slow.to_bitmask();
                        if sampler.chunks == 1 {
                            // Out of line: 32 gathers inlined into every instance of this loop
                            // made the crate take minutes longer to compile (see `edge_gradient`).
                            // The slow lanes packed first: usually a few, one vector of the kind's
                            // single width (their gathers are per vector, not per lane).
                            let (mut q, mut n) = ([[0.0; EDGE_LANES]; 3], 0);
                            for_lanes(slow, |l| {
                                (q[0][n], q[1][n], q[2][n]) = (qx[l], qy[l], qz[l]);
                                n += 1;
                            });
                            let mut e = [[0.0; EDGE_LANES]; 3];
                            edge_gradient(self, n, &q, &mut e);
                            let mut i = 0;
                            for_lanes(slow, |l| {
                                (ax[l], ay[l], az[l]) = (e[0][i], e[1][i], e[2][i]);
                                i += 1;
                            });
                        } else {
                            for_lanes(slow, |l| {
                                let d = vol.gradient_grid_in(Vec3::new(qx[l], qy[l], qz[l]), glo, ghi);
                                (ax[l], ay[l], az[l]) = (d.x, d.y, d.z);
                            });
                        }
                        (L::new(&ax), L::new(&ay), L::new(&az))
                    };
                    let gx = dx * isx;
                    let gy = dy * isy;
                    let gz = dz * isz;
                    let g2 = gx * gx + gy * gy + gz * gz;
                    let len = g2.sqrt();
                    let ndl = gx * lx + gy * ly + gz * lz;
                    let ndh = gx * hx + gy * hy + gz * hz;
                    let some = g2.simd_gt(zero);
                    let inv = one / len;
                    let diff = some.select(ndl.max(zero - ndl) * inv, one);
                    let spec = some.select(ndh.max(zero - ndh) * inv, zero);
                    let s2 = spec * spec;
                    let s4 = s2 * s2;
                    let s8 = s4 * s4;
                    let s16 = s8 * s8;
                    let s32 = s16 * s16;
                    let f = ka + kd * diff;
                    let sa = ks * s32 * ca;
                    ((cr * f + sa).min(ca), (cg * f + sa).min(ca), (cb * f + sa).min(ca))
                } else {
                    (cr, cg, cb)
                };
                let w = one - a;
                r = vis.select(r + w * cr, r);
                g = vis.select(g + w * cg, g);
                b = vis.select(b + w * cb, b);
                a = vis.select(a + w * ca, a);
                if F::ACTIVE && F::RGBA {
                    let dst = [&r.to_array(), &g.to_array(), &b.to_array(), &a.to_array()];
                    feed.feed_rgba(vis.to_bitmask(), &t.to_array(), dst);
                } else if F::ACTIVE {
                    feed.feed(vis.to_bitmask(), &t.to_array(), &ca.to_array(), &a.to_array());
                } else if F::LANE_THRESHOLD {
                    let met = vis & unmet & a.simd_gt(target);
                    chosen = met.select(t, chosen);
                    unmet = unmet.and_not(met);
                }
                alive = alive.and_not(vis & a.simd_ge(ert));
            }
            k = running.select(k + one, k);
        }
        if F::LANE_THRESHOLD {
            feed.set_chosen(one.simd_gt(zero).and_not(unmet).to_bitmask(), &chosen.to_array());
        }
        let (r, g, b, a) = (r.to_array::<M>(), g.to_array::<M>(), b.to_array::<M>(), a.to_array::<M>());
        core::array::from_fn(|l| [r[l], g[l], b[l], a[l]])
    }

    /// The colors, the depths `hr` picks and (with `spread`) the spreads of a packet's rays;
    /// with `P`, over the samples of the kernel's part ([`Kernel::march_in`]).
    #[inline(always)]
    #[allow(clippy::type_complexity)]
    fn pick<L: Lanes, const M: usize, const P: bool>(
        &self,
        o: Vec3,
        rays: &Rays<M>,
        hr: Heuristic,
        spread: bool,
    ) -> ([[f32; 4]; M], [Option<f32>; M], [Uncertainty; M]) {
        let mut depth = [None; M];
        let mut unc = [Uncertainty::default(); M];
        // No closure here: one would be compiled without the caller's AVX2
        // target feature, and the lanes' methods would not inline into it.
        let first = if hr.needs_first_pass() {
            let mut acc = [FirstPassAccumulator::new(); M];
            self.march_in::<L, _, M, P>(o, rays, &mut acc);
            Some(acc.map(|a| a.finish()))
        } else {
            None
        };
        // A one-pass heuristic's pickers all start alike: one call, copied (a call per lane, each
        // result moved through the stack, was 4 % of a shaded frame at 512²).
        let pickers: [DepthPicker; M] = match &first {
            None => [DepthPicker::new(hr, None); M],
            Some(f) => core::array::from_fn(|l| DepthPicker::new(hr, Some(f[l]))),
        };
        let c = if spread {
            let mut ps = PickSpread { pickers, spread: [RaySpread::new(); M] };
            let c = self.march_in::<L, _, M, P>(o, rays, &mut ps);
            for l in 0..L::N {
                depth[l] = rays.t_exit[l].and_then(|te| ps.pickers[l].finish(te));
                unc[l] = ps.spread[l].finish();
            }
            c
        } else if let Some(targets) = threshold_targets(&pickers) {
            let mut lt = LaneThreshold { targets, chosen: [None; M] };
            let c = self.march_in::<L, _, M, P>(o, rays, &mut lt);
            for l in 0..L::N {
                let picker = pickers[l].with_outcome(lt.chosen[l], c[l][3]);
                // A part that does not cross falls back to its own exit, not the box exit
                // (`crate::distributed::partial::PartMarcher::ray`).
                let fallback = if P { rays.t_exit[l].map(|_| rays.part_exit[l]) } else { rays.t_exit[l] };
                depth[l] = fallback.and_then(|te| picker.finish(te));
            }
            c
        } else {
            let mut pickers = pickers;
            let c = self.march_in::<L, _, M, P>(o, rays, &mut pickers);
            for l in 0..L::N {
                depth[l] = rays.t_exit[l].and_then(|te| pickers[l].finish(te));
            }
            c
        };
        (c, depth, unc)
    }

    /// Marches rows `y0 .. y0 + rows` of the image (rows a multiple of the packet height, or the
    /// image's last rows) into `t`, `color` and, with `pack`, `packed` (each `w × rows` long or
    /// empty). `heuristic` `None` renders colors over the background (the ground-truth image).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn band<L: Lanes, const M: usize>(
        &self,
        basis: &RayBasis,
        heuristic: Option<Heuristic>,
        pack: Option<(&Quantizer, FrameRadius)>,
        y0: u32,
        t: &mut [f32],
        color: &mut [u32],
        packed: &mut [u64],
    ) {
        let o = basis.origin();
        let (w, h) = (basis.eye[3] as u32, basis.corner[3] as u32);
        let rows = (color.len() / (w as usize).max(1)) as u32;
        for py in (y0..y0 + rows).step_by(L::N / pw(L::N)) {
            for px in (0..w).step_by(pw(L::N)) {
                let rays = self.rays(L::N, basis, o, px, py, w, h);
                let spread = pack.is_some_and(|(_, r)| r.uses_spread());
                let (c, depth, unc) = match heuristic {
                    None => (self.march::<L, _, M>(o, &rays, &mut NoFeed), [None; M], [Uncertainty::default(); M]),
                    Some(hr) => self.pick::<L, M, false>(o, &rays, hr, spread),
                };
                for l in 0..L::N {
                    let (x, y) = (px + (l % pw(L::N)) as u32, py + (l / pw(L::N)) as u32);
                    if x >= w || y >= y0 + rows {
                        continue;
                    }
                    let i = ((y - y0) * w + x) as usize;
                    let packed_color = pack_color_f32(c[l]);
                    if heuristic.is_none() {
                        if let Some(p) = color.get_mut(i) {
                            *p = over_background(packed_color, BACKGROUND);
                        }
                        continue;
                    }
                    if let Some(p) = color.get_mut(i) {
                        *p = packed_color;
                    }
                    if let Some(p) = t.get_mut(i) {
                        *p = depth[l].unwrap_or(f32::INFINITY);
                    }
                    if let (Some((q, radius)), Some(tl), Some(s)) = (pack, depth[l], packed.get_mut(i)) {
                        let d = rays.d[l];
                        *s = q.pack(o + d * tl, radius.at_ray(d, tl, &unc[l]));
                    }
                }
            }
        }
    }
}

/// Where a layered band's segments go: per pixel of the band its segment count, and per pixel
/// `layers` slots of depth, color and (with a quantizer) packed sample.
pub(crate) struct LayerOut<'a> {
    pub(crate) layers: usize,
    pub(crate) count: &'a mut [u8],
    pub(crate) t: &'a mut [f32],
    pub(crate) color: &'a mut [u32],
    pub(crate) packed: &'a mut [u64],
}

impl Kernel<'_> {
    /// [`Kernel::band`] for layered samples: rows `y0 ..` of the image (as many as `out.count`
    /// holds), each ray cut by a [`Segmenter`] into at most `out.layers` segments (all lanes at
    /// once where the lanes are 32 or more wide, lane by lane on the portable ones).
    #[inline(always)]
    fn band_layers<L: Lanes, const M: usize>(
        &self,
        basis: &RayBasis,
        pack: Option<(&Quantizer, FrameRadius)>,
        y0: u32,
        out: &mut LayerOut<'_>,
    ) {
        if L::N >= 32 {
            self.band_layers_with::<L, SegmenterLanes<M>, M>(basis, pack, y0, out)
        } else {
            self.band_layers_with::<L, [Segmenter; M], M>(basis, pack, y0, out)
        }
    }

    // The lane index `l` picks the lane of several per-lane arrays (rays, colors, segmenters).
    #[allow(clippy::needless_range_loop)]
    #[inline(always)]
    fn band_layers_with<L: Lanes, S: LayerFeed<M>, const M: usize>(
        &self,
        basis: &RayBasis,
        pack: Option<(&Quantizer, FrameRadius)>,
        y0: u32,
        out: &mut LayerOut<'_>,
    ) {
        let o = basis.origin();
        let (w, h) = (basis.eye[3] as u32, basis.corner[3] as u32);
        let k = out.layers;
        let rows = (out.count.len() / (w as usize).max(1)) as u32;
        let step = self.m.dt;
        let mut colors = PackLanes::new();
        // One set of segmenters for every packet (reset per packet, not built anew).
        let mut segs = S::new(k as u32, step);
        for py in (y0..y0 + rows).step_by(L::N / pw(L::N)) {
            for px in (0..w).step_by(pw(L::N)) {
                let rays = self.rays(L::N, basis, o, px, py, w, h);
                segs.reset();
                let rays_color = self.march::<L, _, M>(o, &rays, &mut segs);
                for l in 0..L::N.min(M) {
                    let (x, y) = (px + (l % pw(L::N)) as u32, py + (l / pw(L::N)) as u32);
                    if x >= w || y >= y0 + rows || rays.t_exit[l].is_none() {
                        continue;
                    }
                    let i = ((y - y0) * w + x) as usize;
                    let list = segs.finish(l);
                    if let Some(c) = out.count.get_mut(i) {
                        *c = list.len() as u8;
                    }
                    // Packed with the packet's other rays, in lanes (core's `PackLanes`).
                    colors.push(list.iter().map(|s| s.color), rays_color[l], i * k, out.color);
                    for (j, sgm) in list.iter().enumerate() {
                        let slot = i * k + j;
                        if let Some(p) = out.t.get_mut(slot) {
                            *p = sgm.t;
                        }
                        if let (Some((q, radius)), Some(s)) = (pack, out.packed.get_mut(slot)) {
                            let d = rays.d[l];
                            *s = q.pack(o + d * sgm.t, radius.at(d, sgm.t));
                        }
                    }
                }
                colors.flush(out.color);
            }
        }
    }
}

/// Where a part's band goes ([`Kernel::part`]): per pixel of the band its segment count, and
/// per pixel `k` slots of segments.
pub(crate) struct PartOut<'a> {
    pub(crate) k: usize,
    pub(crate) count: &'a mut [u8],
    pub(crate) segs: &'a mut [Seg],
}

impl Kernel<'_> {
    /// Rows `y0 ..` (as many as `out.count` holds) of the kernel's part: each ray's samples in
    /// the part cut into at most `out.k` segments, or with `out.k` = 1 one segment, the part's
    /// color at `hr`'s pick over the part's samples (none where the part's samples are empty
    /// or the picker finds no depth) — `crate::distributed::partial::PartMarcher::ray` in lanes.
    #[inline(always)]
    fn band_part<L: Lanes, const M: usize>(&self, basis: &RayBasis, hr: Heuristic, y0: u32, out: &mut PartOut<'_>) {
        if out.k > 1 {
            if L::N >= 32 {
                self.band_part_layers::<L, SegmenterLanes<M>, M>(basis, y0, out)
            } else {
                self.band_part_layers::<L, [Segmenter; M], M>(basis, y0, out)
            }
            return;
        }
        let o = basis.origin();
        let (w, h) = (basis.eye[3] as u32, basis.corner[3] as u32);
        let rows = (out.count.len() / (w as usize).max(1)) as u32;
        for py in (y0..y0 + rows).step_by(L::N / pw(L::N)) {
            for px in (0..w).step_by(pw(L::N)) {
                let rays = self.rays(L::N, basis, o, px, py, w, h);
                let (c, depth, _) = self.pick::<L, M, true>(o, &rays, hr, false);
                for l in 0..L::N.min(M) {
                    let (x, y) = (px + (l % pw(L::N)) as u32, py + (l / pw(L::N)) as u32);
                    if x >= w || y >= y0 + rows {
                        continue;
                    }
                    let i = ((y - y0) * w + x) as usize;
                    let seg = depth[l].filter(|_| c[l][3] > 0.0).map(|t| Seg { t, c: c[l] });
                    if let (Some(n), Some(s)) = (out.count.get_mut(i), out.segs.get_mut(i)) {
                        *n = u8::from(seg.is_some());
                        *s = seg.unwrap_or_default();
                    }
                }
            }
        }
    }

    #[inline(always)]
    fn band_part_layers<L: Lanes, S: LayerFeed<M>, const M: usize>(
        &self,
        basis: &RayBasis,
        y0: u32,
        out: &mut PartOut<'_>,
    ) {
        let o = basis.origin();
        let (w, h) = (basis.eye[3] as u32, basis.corner[3] as u32);
        let k = out.k;
        let rows = (out.count.len() / (w as usize).max(1)) as u32;
        let step = self.m.dt;
        // One set of segmenters for every packet (reset per packet, not built anew).
        let mut segs = S::new(k as u32, step);
        for py in (y0..y0 + rows).step_by(L::N / pw(L::N)) {
            for px in (0..w).step_by(pw(L::N)) {
                let rays = self.rays(L::N, basis, o, px, py, w, h);
                segs.reset();
                self.march_in::<L, _, M, true>(o, &rays, &mut segs);
                for l in 0..L::N.min(M) {
                    let (x, y) = (px + (l % pw(L::N)) as u32, py + (l / pw(L::N)) as u32);
                    if x >= w || y >= y0 + rows {
                        continue;
                    }
                    let i = ((y - y0) * w + x) as usize;
                    let list = if rays.t_exit[l].is_some() { segs.finish(l) } else { &[] };
                    if let Some(c) = out.count.get_mut(i) {
                        *c = list.len() as u8;
                    }
                    for (j, sgm) in list.iter().enumerate() {
                        if let Some(p) = out.segs.get_mut(i * k + j) {
                            *p = Seg { t: sgm.t, c: sgm.color };
                        }
                    }
                }
            }
        }
    }
}

/// The most lanes a packet has: [`edge_gradient`]'s arrays.
const EDGE_LANES: usize = 64;

#[inline(always)]
fn edge_gradient_kernel<L: Lanes, const M: usize>(
    k: &Kernel<'_>,
    lanes: usize,
    p: &[[f32; EDGE_LANES]; 3],
    out: &mut [[f32; EDGE_LANES]; 3],
) {
    let sampler = Sampler::<L>::new(&k.m, k.voxels);
    // As many vectors as cover the caller's packed lanes.
    for c in (0..lanes.min(EDGE_LANES)).step_by(L::N) {
        let (x, y, z) = (L::new(&p[0][c..]), L::new(&p[1][c..]), L::new(&p[2][c..]));
        if let Some((dx, dy, dz)) = sampler.gradient_edge(x, y, z) {
            dx.store(&mut out[0][c..]);
            dy.store(&mut out[1][c..]);
            dz.store(&mut out[2][c..]);
        }
    }
}

volwarp_lanes::dispatch! {
    /// The gradient of [`crate::volume::Volume::gradient_grid_in`] with every read clamped, at
    /// the positions `p` (continuous voxel coordinates, x, y and z arrays; the first `lanes`, up
    /// to 64, are computed, in vectors of the kind's single width, 8 or 16 lanes: the caller
    /// packs the lanes it needs first) into `out`, bit for bit, in lanes ([`Sampler::gradient_edge`]);
    /// one chunk only (`out` is left as it is with several). What the packet marcher's lanes
    /// at the volume's or crop's edge take: a function of its own, so these 32 gathers are
    /// compiled once per lane kind, not into every instance of [`Kernel::march_in`]. The lanes
    /// compute the same values whatever their kind, so a caller of another kind gets the same
    /// result.
    pub(crate) fn edge_gradient / edge_gradient_avx2 / edge_gradient_avx512 => edge_gradient_kernel(
        k: &Kernel<'_>,
        lanes: usize,
        p: &[[f32; EDGE_LANES]; 3],
        out: &mut [[f32; EDGE_LANES]; 3],
    );
    portable = [wide::f32x8, 8],
    avx2 = [crate::lanes::Avx2, 8],
    avx512 = [crate::lanes::Avx512, 16]
}

#[inline(always)]
fn band_part_kernel<L: Lanes, const M: usize>(
    k: &Kernel<'_>,
    basis: &RayBasis,
    hr: Heuristic,
    y0: u32,
    out: &mut PartOut<'_>,
) {
    k.band_part::<L, M>(basis, hr, y0, out)
}

dispatch! {
    /// Marches the rows of one band of a part ([`Kernel::part`]) with the best lanes this CPU
    /// has (see [`Kernel::band_part`]).
    fn march_band_part / march_band_part_avx2 / march_band_part_avx512 => band_part_kernel(
        k: &Kernel<'_>,
        basis: &RayBasis,
        hr: Heuristic,
        y0: u32,
        out: &mut PartOut<'_>,
    )
}

#[inline(always)]
fn band_layers_kernel<L: Lanes, const M: usize>(
    k: &Kernel<'_>,
    basis: &RayBasis,
    pack: Option<(&Quantizer, FrameRadius)>,
    y0: u32,
    out: &mut LayerOut<'_>,
) {
    k.band_layers::<L, M>(basis, pack, y0, out)
}

dispatch! {
    /// Marches the rows of one band into layered samples with the best lanes this CPU has (see
    /// [`Kernel::band_layers`]).
    fn march_band_layers / march_band_layers_avx2 / march_band_layers_avx512 => band_layers_kernel(
        k: &Kernel<'_>,
        basis: &RayBasis,
        pack: Option<(&Quantizer, FrameRadius)>,
        y0: u32,
        out: &mut LayerOut<'_>,
    )
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn band_kernel<L: Lanes, const M: usize>(
    k: &Kernel<'_>,
    basis: &RayBasis,
    heuristic: Option<Heuristic>,
    pack: Option<(&Quantizer, FrameRadius)>,
    y0: u32,
    t: &mut [f32],
    color: &mut [u32],
    packed: &mut [u64],
) {
    k.band::<L, M>(basis, heuristic, pack, y0, t, color, packed)
}

dispatch! {
    /// Marches the rows of one band with the best lanes this CPU has (see [`Kernel::band`]).
    #[allow(clippy::too_many_arguments)]
    fn march_band / march_band_avx2 / march_band_avx512 => band_kernel(
        k: &Kernel<'_>,
        basis: &RayBasis,
        heuristic: Option<Heuristic>,
        pack: Option<(&Quantizer, FrameRadius)>,
        y0: u32,
        t: &mut [f32],
        color: &mut [u32],
        packed: &mut [u64],
    )
}
