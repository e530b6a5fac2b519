//! [`pack_colors`] for [`PACK_LANES`] rays at once: the same 8-bit colors bit for bit.
//!
//! The scalar packing is one long chain of dependent divisions and roundings per ray (each
//! segment's rounding is carried into the next), so one ray at a time leaves the core waiting
//! on latencies. With AVX2 the rays of a batch go through the common path side by side, one
//! lane each (`volwarp_lanes::Avx2`, written with its operations: the compiler does not
//! vectorize the saturating casts and selects of the scalar code): each segment rounded to
//! follow the ray's own composite, the last (or the one where the client stops) fitted under
//! its opacity, and the pixel that gives checked. Where it is not the ray's pixel (the rare
//! rays that need another opacity or an earlier segment refitted), or an input is not finite,
//! the ray is packed again by the scalar [`pack_colors`], so every ray's colors are exactly the
//! scalar function's. Without AVX2 (or `std`, which detects it) every ray is packed by
//! [`pack_colors`].

// Indexed loops over lanes and channels, one array per value (the kernels' form).
#![allow(clippy::needless_range_loop)]

use super::{pack_colors, Segment, MAX_LAYERS};

/// Rays packed together by [`PackLanes`].
pub const PACK_LANES: usize = 8;

type F = [f32; PACK_LANES];

/// Rays queued for packing: their segments' colors side by side, and where each ray's packed
/// colors go. [`PackLanes::push`] packs a full batch; [`PackLanes::flush`] packs what is left.
#[derive(Clone, Debug)]
pub struct PackLanes {
    queued: usize,
    /// Per lane: segment count, the ray's color and where its packed colors start.
    n: [usize; PACK_LANES],
    ray: [F; 4],
    at: [usize; PACK_LANES],
    /// Per segment and channel, the lanes' colors (past a lane's count, whatever was there:
    /// the kernel does not use them).
    col: [[F; 4]; MAX_LAYERS],
}

impl Default for PackLanes {
    fn default() -> Self {
        PackLanes {
            queued: 0,
            n: [0; PACK_LANES],
            ray: [[0.0; PACK_LANES]; 4],
            at: [0; PACK_LANES],
            col: [[[0.0; PACK_LANES]; 4]; MAX_LAYERS],
        }
    }
}

impl PackLanes {
    /// An empty batch.
    pub fn new() -> Self {
        Self::default()
    }

    /// Queues a ray whose segments (front to back) have the premultiplied `colors` (at most
    /// [`MAX_LAYERS`] are taken) and whose own color is `ray`; its packed colors go to
    /// `out[at..at + n]` (`n` the segments taken), as [`pack_colors`] would write them. Packs
    /// the batch into `out` when it is full. Slots of `out` that do not exist are left out.
    #[inline]
    pub fn push(&mut self, colors: impl IntoIterator<Item = [f32; 4]>, ray: [f32; 4], at: usize, out: &mut [u32]) {
        let l = self.queued;
        let mut n = 0;
        for (slot, c) in self.col.iter_mut().zip(colors) {
            for ch in 0..4 {
                slot[ch][l] = c[ch];
            }
            n += 1;
        }
        self.n[l] = n;
        for ch in 0..4 {
            self.ray[ch][l] = ray[ch];
        }
        self.at[l] = at;
        self.queued += 1;
        if self.queued == PACK_LANES {
            self.flush(out);
        }
    }

    /// Packs the queued rays into `out` and empties the batch.
    pub fn flush(&mut self, out: &mut [u32]) {
        if self.queued == 0 {
            return;
        }
        for l in self.queued..PACK_LANES {
            self.n[l] = 0;
        }
        let (packed, redo) = self.pack_lanes();
        for l in 0..self.queued {
            let n = self.n[l];
            let Some(dst) = out.get_mut(self.at[l]..self.at[l] + n) else {
                continue;
            };
            if redo & (1 << l) != 0 {
                let mut segs = [Segment::default(); MAX_LAYERS];
                for (j, s) in segs.iter_mut().enumerate().take(n) {
                    s.color = core::array::from_fn(|ch| self.col[j][ch][l]);
                }
                let ray = core::array::from_fn(|ch| self.ray[ch][l]);
                pack_colors(&segs[..n], ray, dst);
            } else {
                for (j, d) in dst.iter_mut().enumerate() {
                    *d = packed[j][l];
                }
            }
        }
        self.queued = 0;
    }

    /// The queued rays packed in lanes, and the lanes (bits) to pack with [`pack_colors`]:
    /// every lane without AVX2.
    fn pack_lanes(&self) -> ([[u32; PACK_LANES]; MAX_LAYERS], u32) {
        #[cfg_attr(not(all(feature = "std", target_arch = "x86_64")), allow(unused_mut))]
        let mut packed = [[0u32; PACK_LANES]; MAX_LAYERS];
        #[cfg(all(feature = "std", target_arch = "x86_64"))]
        if let Some(t) = volwarp_lanes::Avx2Token::new() {
            let mut redo = 0;
            for l in 0..PACK_LANES {
                let n = self.n[l];
                let finite = (0..4).all(|ch| self.ray[ch][l].is_finite())
                    && self.col[..n].iter().all(|s| s.iter().all(|c| c[l].is_finite()));
                redo |= u32::from(!finite) << l;
            }
            // SAFETY: the token proves the CPU has AVX2 (and the lane level allows it).
            redo |= unsafe { avx2::pack8(t, &self.n, &self.ray, &self.col, &mut packed) };
            return (packed, redo);
        }
        (packed, u32::MAX)
    }
}

/// [`pack_colors`] of every ray `(lists[r], rays[r])` into `out[r][..n]` (`n` the segments
/// taken, at most [`MAX_LAYERS`]), [`PACK_LANES`] rays at a time.
pub fn pack_colors_lanes(lists: &[&[Segment]], rays: &[[f32; 4]], out: &mut [[u32; MAX_LAYERS]]) {
    let flat: &mut [u32] = bytemuck::cast_slice_mut(out);
    let mut batch = PackLanes::new();
    for (r, (segs, &ray)) in lists.iter().zip(rays).enumerate() {
        batch.push(segs.iter().map(|s| s.color), ray, r * MAX_LAYERS, flat);
    }
    batch.flush(flat);
}

/// The AVX2 kernel.
#[cfg(all(feature = "std", target_arch = "x86_64"))]
mod avx2 {
    use super::{F, MAX_LAYERS, PACK_LANES};
    use crate::sample::BACKGROUND;
    use crate::segments::OPAQUE;
    use volwarp_lanes::{Avx2, Avx2I, Avx2Token};

    // No closures below: a closure is not compiled with its function's target features, so
    // the intrinsics in it would not be inlined.
    macro_rules! s {
        ($t:expr, $v:expr) => {
            Avx2::splat($t, $v)
        };
    }

    /// `segments::round_clamp(x, 0, hi)` per lane (`hi` in `0..=255`): within `-2..=300` the
    /// same truncation of `x + 0.5` and correction, outside it the clamp's end either way; a
    /// NaN gives 0 (`max` drops it: −2, then the clamp at 0).
    #[inline(always)]
    fn round_clamp(t: Avx2Token, x: Avx2, hi: Avx2) -> Avx2 {
        let xc = x.max(s!(t, -2.0)).fast_min(s!(t, 300.0));
        let r = (xc + s!(t, 0.5)).trunc_int().to_float();
        let r = (r - s!(t, 0.5)).simd_gt(xc).select(r - s!(t, 1.0), r);
        r.fast_max(s!(t, 0.0)).fast_min(hi)
    }

    /// `segments::round8` per lane: `v·255 + 0.5` truncated within `0..=255` (a NaN gives 0:
    /// `maxps` returns its second operand).
    #[inline(always)]
    fn round8(t: Avx2Token, v: Avx2) -> Avx2 {
        (v * s!(t, 255.0) + s!(t, 0.5)).fast_max(s!(t, 0.0)).fast_min(s!(t, 255.0)).trunc_int().to_float()
    }

    /// `segments::fit_channel(acc, wgt, target, start, 0, hi)` per lane, for `wgt > 0`.
    #[inline(always)]
    fn fit_channel(t: Avx2Token, acc: Avx2, wgt: Avx2, target: Avx2, start: Avx2, hi: Avx2) -> Avx2 {
        let ideal = round_clamp(t, (target / s!(t, 255.0) - acc) / wgt, hi);
        let mut res = start.fast_max(s!(t, 0.0)).fast_min(hi);
        let mut found = s!(t, 0.0);
        for d in [0.0f32, -1.0, 1.0, -2.0, 2.0] {
            let q = (ideal + s!(t, d)).fast_max(s!(t, 0.0)).fast_min(hi);
            let hit = round8(t, acc + wgt * q).simd_eq(target).and_not(found);
            res = hit.select(q, res);
            found = found | hit;
        }
        res
    }

    /// `sample::over_background(c, BACKGROUND)`'s color channels per lane, of 8-bit values
    /// held as `f32`: `min(255, c + ⌊((255 − a)·bg + 127) / 255⌋)` (the numerator below 2¹⁶,
    /// so the quotient's float is exact enough to truncate).
    #[inline(always)]
    fn over_background(t: Avx2Token, c: [Avx2; 4]) -> [Avx2; 3] {
        let bg = BACKGROUND.to_le_bytes();
        let k = s!(t, 255.0) - c[3];
        let mut out = [k; 3];
        for ch in 0..3 {
            let share = ((k * s!(t, bg[ch] as f32) + s!(t, 127.0)) / s!(t, 255.0)).trunc_int().to_float();
            out[ch] = (c[ch] + share).fast_min(s!(t, 255.0));
        }
        out
    }

    /// `u32::from_le_bytes` of four lanes of 8-bit values held as `f32`.
    #[inline(always)]
    fn pack_bytes(t: Avx2Token, q: &[Avx2; 4]) -> [u32; PACK_LANES] {
        let mut packed = q[0].trunc_int();
        for (ch, by) in [(1, 1 << 8), (2, 1 << 16), (3, 1 << 24)] {
            packed = packed + q[ch].trunc_int().mul_lo(Avx2I::splat(t, by));
        }
        let a = packed.to_array();
        let mut out = [0u32; PACK_LANES];
        for l in 0..PACK_LANES {
            out[l] = a[l] as u32;
        }
        out
    }

    /// The lanes' colors packed as `segments::pack_colors` packs them where the fitted last
    /// segment gives the ray's pixel; returns the lanes (bits) where it does not, to pack
    /// again with the scalar function. Lanes with `n[l] == 0` are left alone.
    #[target_feature(enable = "avx2")]
    pub(super) fn pack8(
        t: Avx2Token,
        n: &[usize; PACK_LANES],
        ray: &[F; 4],
        col: &[[F; 4]; MAX_LAYERS],
        out: &mut [[u32; PACK_LANES]; MAX_LAYERS],
    ) -> u32 {
        let zero = s!(t, 0.0);
        let mut nl = [0.0f32; PACK_LANES];
        for l in 0..PACK_LANES {
            nl[l] = n[l].min(MAX_LAYERS) as f32;
        }
        let nf = Avx2::load(t, &nl);
        let mut target = [zero; 4];
        for ch in 0..4 {
            target[ch] = round8(t, Avx2::load(t, &ray[ch]));
        }
        let want = over_background(t, target);
        let mut acc = [zero; 4];
        let mut real = [zero; 4];
        let mut adjusting = zero.simd_lt(nf);
        let mut redo = 0u32;
        let max_n = n.iter().copied().max().unwrap_or(0).min(MAX_LAYERS);
        for j in 0..max_n {
            let mut c = [zero; 4];
            for ch in 0..4 {
                c[ch] = Avx2::load(t, &col[j][ch]);
            }
            let adj = adjusting & s!(t, j as f32).simd_lt(nf);
            let keep = s!(t, 1.0) - real[3];
            for ch in 0..4 {
                real[ch] = real[ch] + keep * c[ch];
            }
            let wgt = (s!(t, 1.0) - acc[3]) * s!(t, 1.0 / 255.0);
            redo |= adj.and_not(wgt.simd_gt(zero)).to_bitmask();
            let qa = round_clamp(t, (real[3] - acc[3]) / wgt, s!(t, 255.0));
            let mut q = [qa; 4];
            for ch in 0..3 {
                q[ch] = round_clamp(t, (real[ch] - acc[ch]) / wgt, qa);
            }
            let last = s!(t, (j + 1) as f32).simd_eq(nf);
            let stops = (acc[3] + wgt * qa).simd_ge(s!(t, OPAQUE));
            let fitting = adj & (last | stops);
            if fitting.any() {
                let a = last.select(fit_channel(t, acc[3], wgt, target[3], qa, s!(t, 255.0)), qa);
                for ch in 0..3 {
                    let f = fit_channel(t, acc[ch], wgt, target[ch], q[ch].fast_min(a), a);
                    q[ch] = fitting.select(f, q[ch]);
                }
                q[3] = fitting.select(a, qa);
                // The pixel the client shows after these colors, against the ray's.
                let mut after = [zero; 4];
                for ch in 0..4 {
                    after[ch] = round8(t, acc[ch] + wgt * q[ch]);
                }
                let shown = over_background(t, after);
                let same = shown[0].simd_eq(want[0]) & shown[1].simd_eq(want[1]) & shown[2].simd_eq(want[2]);
                redo |= fitting.and_not(same).to_bitmask();
            }
            // Lanes past their adjusting segments take their colors rounded as they are.
            for ch in 0..4 {
                q[ch] = adj.select(q[ch], round8(t, c[ch]));
                acc[ch] = adj.select(acc[ch] + wgt * q[ch], acc[ch]);
            }
            adjusting = adjusting.and_not(fitting);
            out[j] = pack_bytes(t, &q);
        }
        redo
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::segments::composite;

    /// Pseudo-random rays of the scalar packing's own test families, and odd ones: no
    /// segments, more than [`MAX_LAYERS`], colors above their opacity or out of range, NaN and
    /// infinite values. Each is `(segments, how many, the ray's color)`.
    fn ray_source(seed: u64) -> impl FnMut() -> ([Segment; 20], usize, [f32; 4]) {
        let mut next = crate::test_unit_rng(seed);
        move || {
            let family = (next() * 8.0) as usize % 8;
            let (amax, kmax) =
                [(1.0f32, 4usize), (0.05, 4), (0.05, 16), (0.005, 4), (0.3, 8), (1.0, 20), (1.0, 4), (1.0, 4)][family];
            let k = (next() * (kmax + 1) as f32) as usize % (kmax + 1);
            let mut segs = [Segment::default(); 20];
            crate::segments::tests::random_segments(&mut next, amax, &mut segs[..k]);
            if family == 6 {
                // Not premultiplied, or out of range.
                for sg in &mut segs[..k] {
                    sg.color = [next() * 1.5 - 0.2, next(), next() * 2.0, next() * 1.2 - 0.1];
                }
            }
            let mut ray = composite(segs[..k].iter().map(|s| s.color));
            if family == 7 && k > 0 {
                let odd = [f32::NAN, f32::INFINITY, -f32::INFINITY, 1e30];
                let v = odd[(next() * 4.0) as usize % 4];
                if next() < 0.5 {
                    segs[(next() * k as f32) as usize % k].color[(next() * 4.0) as usize % 4] = v;
                } else {
                    ray[(next() * 4.0) as usize % 4] = v;
                }
            }
            (segs, k, ray)
        }
    }

    /// Whether the packing runs in AVX2 lanes here.
    fn avx2() -> bool {
        #[cfg(all(feature = "std", target_arch = "x86_64"))]
        return volwarp_lanes::Avx2Token::new().is_some();
        #[cfg(not(all(feature = "std", target_arch = "x86_64")))]
        false
    }

    #[test]
    fn lanes_pack_every_ray_as_the_scalar_packing() {
        let mut gen = ray_source(0x9E37_79B9_7F4A_7C15);
        let mut redone = 0usize;
        let total = 40_000;
        let mut batch_rays = [([Segment::default(); 20], 0usize, [0.0f32; 4]); 13];
        for round in 0..total / 13 {
            for r in batch_rays.iter_mut() {
                *r = gen();
            }
            let lists: [&[Segment]; 13] = core::array::from_fn(|r| &batch_rays[r].0[..batch_rays[r].1]);
            let colors: [[f32; 4]; 13] = core::array::from_fn(|r| batch_rays[r].2);
            let mut out = [[0u32; MAX_LAYERS]; 13];
            pack_colors_lanes(&lists, &colors, &mut out);
            for r in 0..13 {
                let n = lists[r].len().min(MAX_LAYERS);
                let mut want = [0u32; MAX_LAYERS];
                pack_colors(&lists[r][..n], colors[r], &mut want[..n]);
                assert_eq!(out[r][..n], want[..n], "round {round}, ray {r}: {:?}, ray {:?}", lists[r], colors[r]);
            }
            // How many the scalar packing redid (a check that the lanes do the work).
            let mut b = PackLanes::new();
            let mut sink = [0u32; MAX_LAYERS * PACK_LANES];
            for l in 0..PACK_LANES - 1 {
                b.push(lists[l].iter().map(|s| s.color), colors[l], l * MAX_LAYERS, &mut sink);
            }
            redone += b.pack_lanes().1.count_ones() as usize;
        }
        // With AVX2, only rays with odd values (a quarter of these) and the rare searches go
        // to the scalar packing; without it, every ray.
        let rays = total / 13 * (PACK_LANES - 1);
        if avx2() {
            assert!(redone < rays * 3 / 10, "{redone} of {rays} rays redone");
        } else {
            assert_eq!(redone, total / 13 * 32, "every lane to the scalar packing");
        }
    }

    #[test]
    fn slots_outside_the_output_are_left_out() {
        let segs = [Segment { t: 0.0, color: [0.2, 0.1, 0.1, 0.5] }; 3];
        let ray = composite(segs.iter().map(|s| s.color));
        let mut out = [7u32; 4];
        let mut b = PackLanes::new();
        b.push(segs.iter().map(|s| s.color), ray, 2, &mut out);
        b.push(segs.iter().map(|s| s.color), ray, 0, &mut out);
        b.flush(&mut out);
        let mut want = [0u32; 3];
        pack_colors(&segs, ray, &mut want);
        assert_eq!(out[..3], want);
        assert_eq!(out[3], 7);
    }
}
