//! The AVX2 kernels of the compact frame codec's fast paths (x86-64 with std, chosen at run
//! time by `volwarp_lanes`: the CPU's level, clamped by `VOLWARP_LANES`): the same results as the portable code of the parent
//! module, bit for bit (every float operation is the same IEEE operation in the same order;
//! no fused multiply-add), written with intrinsics because the compiler's vectorization of
//! the portable code packs and unpacks lanes in the dependent chains.

use super::{Geo, Proj};
use crate::compact_frame::{CompactParams, DEPTH_CODE_MAX};
use crate::sample::{POS_MAX, RADIUS_MAX};
use alloc::vec;
use alloc::vec::Vec;
use core::arch::x86_64::*;

/// The sequential part of decoding (`decode_predicted` after its checks, the work of
/// [`super::undo_prediction_by_row`]): the `n` covered pixels of `mask` (exactly `n` bits,
/// checked) with their depth and color residuals become, in `samples`, `x | y << 24 | code << 48`
/// each (the layout [`place`] reads, not the portable code's) and, in `colors`, the colors.
///
/// A pixel's four channels and depth code travel in 32-bit lanes 0–4 of one AVX2 register; the
/// row above is kept as one 32-byte cell per column with a row tag in lane 5 (a cell counts for
/// row `y` iff its tag is `y`, so nothing is cleared between rows). Pixels with all three
/// neighbours (99.7 % of the MRI bench frame's) take the MED path, written as a function of the
/// left value `a` (the chain from one sample to the next: two operations and a blend); the
/// others take the generic one.
#[target_feature(enable = "avx2")]
pub(super) fn undo_prediction(
    w: u32,
    mask: &[u8],
    n: usize,
    samples: &mut Vec<u64>,
    d_res: [&[u8]; 2],
    c_res: [&[u8]; 4],
    colors: &mut Vec<u32>,
) {
    let [dlo, dhi] = d_res;
    let [cr, cg, cb, ca] = c_res;
    let (dlo, dhi) = (&dlo[..n], &dhi[..n]);
    // Two streams instead of seven for the sequential loop: each sample's pixel index (below
    // 2^48) with its depth residual in the top 16 bits, and its color residuals as one u32 in
    // `colors`, which the loop then overwrites with the decoded color. Written into the
    // vectors' spare capacity (the caller reserved `n`; the mask has exactly `n` bits).
    let out = samples.spare_capacity_mut().as_mut_ptr();
    let capacity = samples.capacity();
    assert!(capacity >= n, "the caller reserved n");
    let mut k = 0;
    for (bi, &bits) in mask.iter().enumerate() {
        if bits == 0 {
            continue;
        }
        let count = bits.count_ones() as usize;
        if k + 8 <= n {
            // Eight at once (those past this byte's `count` are overwritten by the next
            // byte's): the byte's bit positions from the table, the depth residuals of samples
            // `k..k + 8`.
            let base = _mm256_set1_epi64x(bi as i64 * 8);
            // SAFETY: the table entry is 8 bytes; `k + 8 ≤ n`: the loads of `dlo`/`dhi` (n
            // long) and the stores into `samples` (capacity ≥ n) stay inside.
            unsafe {
                let pos = _mm_loadl_epi64(BIT_POSITIONS[bits as usize].as_ptr().cast());
                let dw = _mm_unpacklo_epi8(
                    _mm_loadl_epi64(dlo.as_ptr().add(k).cast()),
                    _mm_loadl_epi64(dhi.as_ptr().add(k).cast()),
                );
                let d0 = _mm256_slli_epi64::<48>(_mm256_cvtepu16_epi64(dw));
                let d1 = _mm256_slli_epi64::<48>(_mm256_cvtepu16_epi64(_mm_srli_si128::<8>(dw)));
                let p0 = _mm256_add_epi64(_mm256_cvtepu8_epi64(pos), base);
                let p1 = _mm256_add_epi64(_mm256_cvtepu8_epi64(_mm_srli_si128::<4>(pos)), base);
                _mm256_storeu_si256(out.add(k).cast(), _mm256_or_si256(p0, d0));
                _mm256_storeu_si256(out.add(k + 4).cast(), _mm256_or_si256(p1, d1));
            }
        } else {
            let mut b = bits;
            for j in k..k + count {
                assert!(j < n, "the caller checked the mask's count");
                let dres = dlo[j] as u64 | (dhi[j] as u64) << 8;
                // SAFETY: `j < n ≤ capacity`.
                unsafe {
                    out.add(j)
                        .write(core::mem::MaybeUninit::new((bi as u64 * 8 + b.trailing_zeros() as u64) | dres << 48))
                };
                b &= b - 1;
            }
        }
        k += count;
    }
    assert_eq!(k, n, "the caller checked the mask's count");
    // SAFETY: every index below `n` was written above: each set bit wrote its own slot
    // (a vector step's slots past its byte's count are written again by the following
    // bytes, in order, before `n` is reached).
    unsafe { samples.set_len(n) };
    colors.extend(
        cr[..n]
            .iter()
            .zip(&cg[..n])
            .zip(&cb[..n])
            .zip(&ca[..n])
            .map(|(((&r, &g), &b), &a)| u32::from_le_bytes([r, g, b, a])),
    );
    let samples = &mut samples[..n];
    let colors = &mut colors[..n];
    let (w64, wu) = (w as u64, w as usize);
    // One cell per column (cell `x + 1` is column `x`; cell 0, left of column 0, is never
    // written): the pixel's four channels and depth code in 32-bit lanes 0–4, and in lane 5
    // the tag `r + 1` of the row `r` that wrote it. A cell of the row above row `y` holds a
    // sample iff its tag is `y`: stale cells (from older rows, or the sentinel the buffers
    // start with) never match, so no buffer is cleared between rows.
    const NEVER: [u32; 8] = [0, 0, 0, 0, 0, u32::MAX, 0, 0];
    let mut prev = vec![NEVER; wu + 1];
    let mut cur = vec![NEVER; wu + 1];
    let lanes = _mm256_setr_epi32(0xff, 0xff, 0xff, 0xff, 0xffff, 0, 0, 0);
    // Bytes 0, 4, 8, 12: the four channel lanes' low bytes back into one u32.
    let gather_low = _mm_setr_epi8(0, 4, 8, 12, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1);
    // The previously visited pixel's values.
    let mut last = _mm256_setzero_si256();
    let idx_mask = (1u64 << 48) - 1;
    let mut i0 = 0;
    while i0 < n {
        let (y, row_start, i1) = super::next_row(i0, n, w64, |i| samples[i] & idx_mask);
        core::mem::swap(&mut prev, &mut cur);
        // Rows are below 2^24 (the caller's check), so tags never wrap.
        let (above, tag) = (y as u32, y as u32 + 1);
        let tagv = _mm256_setr_epi32(0, 0, 0, 0, 0, tag as i32, 0, 0);
        let y24 = y << 24;
        let mut left = u64::MAX - 1;
        for (s, col) in samples[i0..i1].iter_mut().zip(&mut colors[i0..i1]) {
            let v = *s;
            let x = (v & idx_mask) - row_start;
            let xs = x as usize;
            // SAFETY: every index of this row lies in `row_start..row_start + w`, so `x < w` and
            // both cells exist (`prev` has `w + 1`).
            let (bcell, ccell) = unsafe { (prev.get_unchecked(xs + 1), prev.get_unchecked(xs)) };
            let (hb, hc) = (bcell[5] == above, ccell[5] == above);
            let ha = left.wrapping_add(1) == x;
            // SAFETY: both cells are 32 bytes.
            let (b, c) =
                unsafe { (_mm256_loadu_si256(bcell.as_ptr().cast()), _mm256_loadu_si256(ccell.as_ptr().cast())) };
            let res = _mm256_inserti128_si256::<1>(
                _mm256_castsi128_si256(_mm_cvtepu8_epi32(_mm_cvtsi32_si128(*col as i32))),
                _mm_cvtsi32_si128((v >> 48) as i32),
            );
            let p = if hb & ha & hc {
                // LOCO-I's MED as a function of the left value a, with b and c known: for
                // b ≥ c it is min(max(a, b), a + b − c), for b < c max(min(a, b), a + b − c)
                // (exact in 32-bit lanes), so the chain from a is two operations and a blend.
                let t = _mm256_add_epi32(last, _mm256_sub_epi32(b, c));
                let up = _mm256_min_epi32(_mm256_max_epi32(last, b), t);
                let down = _mm256_max_epi32(_mm256_min_epi32(last, b), t);
                _mm256_blendv_epi8(up, down, _mm256_cmpgt_epi32(c, b))
            } else if hb & ha {
                _mm256_srli_epi32::<1>(_mm256_add_epi32(last, b))
            } else if hb {
                b
            } else if !ha & hc {
                c
            } else {
                last
            };
            let d = _mm256_and_si256(_mm256_add_epi32(p, res), lanes);
            let code = _mm256_extract_epi32::<4>(d) as u32 as u64;
            *col = _mm_cvtsi128_si32(_mm_shuffle_epi8(_mm256_castsi256_si128(d), gather_low)) as u32;
            // The layout [`place`] reads: x, y and the code in bits 0, 24 and 48.
            *s = (x + y24) | code << 48;
            // SAFETY: the cell exists (see above) and is 32 bytes.
            unsafe { _mm256_storeu_si256(cur.get_unchecked_mut(xs + 1).as_mut_ptr().cast(), _mm256_or_si256(d, tagv)) };
            last = d;
            left = x;
        }
        i0 = i1;
    }
}

/// The positions of the set bits of each byte, lowest first (unused entries 0).
static BIT_POSITIONS: [[u8; 8]; 256] = {
    let mut t = [[0u8; 8]; 256];
    let mut b = 0;
    while b < 256 {
        let (mut j, mut bit) = (0, 0);
        while bit < 8 {
            if b >> bit & 1 == 1 {
                t[b][j] = bit as u8;
                j += 1;
            }
            bit += 1;
        }
        b += 1;
    }
    t
};

/// The low 32 bits of eight `u64` lanes (`a` then `b`), in order.
#[inline]
#[target_feature(enable = "avx2")]
fn low_dwords(a: __m256i, b: __m256i) -> __m256i {
    // Per 128-bit half: a's and b's even dwords, i.e. [a0 a1 b0 b1 | a2 a3 b2 b3] in u64
    // units; then the middle two 64-bit chunks swap.
    let sh = _mm256_shuffle_ps::<0x88>(_mm256_castsi256_ps(a), _mm256_castsi256_ps(b));
    _mm256_castpd_si256(_mm256_permute4x64_pd::<0xD8>(_mm256_castps_pd(sh)))
}

/// `a[0] * b[0] + a[1] * b[1] + a[2] * b[2]` in that order, lane by lane.
#[inline]
#[target_feature(enable = "avx2")]
fn dot(a: [__m256; 3], b: [__m256; 3]) -> __m256 {
    _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(a[0], b[0]), _mm256_mul_ps(a[1], b[1])), _mm256_mul_ps(a[2], b[2]))
}

#[inline]
#[target_feature(enable = "avx2")]
fn splat3(v: [f32; 3]) -> [__m256; 3] {
    [_mm256_set1_ps(v[0]), _mm256_set1_ps(v[1]), _mm256_set1_ps(v[2])]
}

/// Pass 1 of `build_planes` (`Proj::project_lanes`) eight samples at a time: each sample's
/// pixel index (`y · w + x`, the caller has checked that every index fits in `u32`), depth
/// along that pixel's ray and `dir · forward`; whether every sample projected into the
/// viewport, in front, to a finite depth, with strictly increasing pixel indices (one sample
/// per pixel, in pixel order) — and if so, the smallest and largest depth. All four slices
/// have the same length.
#[target_feature(enable = "avx2")]
pub(super) fn project(
    proj: &Proj,
    geo: &Geo,
    s: &[u64],
    pix: &mut [u32],
    depth: &mut [f32],
    dfwd: &mut [f32],
) -> Option<(f32, f32)> {
    let n = s.len();
    let (pix, depth, dfwd) = (&mut pix[..n], &mut depth[..n], &mut dfwd[..n]);
    let pm = _mm256_set1_epi64x(POS_MAX as i64);
    let (dmin, dstep, eye) = (splat3(proj.dmin), splat3(proj.dstep), splat3(geo.eye));
    let (u, v, w) = (splat3(proj.u), splat3(proj.v), splat3(proj.w));
    let (corner, du, dv, fwd) = (splat3(geo.corner), splat3(geo.du), splat3(geo.dv), splat3(geo.forward));
    let (tan_x, tan_y) = (_mm256_set1_ps(proj.tan_x), _mm256_set1_ps(proj.tan_y));
    let (width, height) = (_mm256_set1_ps(proj.width), _mm256_set1_ps(proj.height));
    let cols = _mm256_set1_epi32(proj.columns as i32);
    let (zero, half, one) = (_mm256_setzero_ps(), _mm256_set1_ps(0.5), _mm256_set1_ps(1.0));
    let near = _mm256_set1_ps(1e-6);
    let abs = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fff_ffff));
    let inf = _mm256_set1_ps(f32::INFINITY);
    let mut ok = _mm256_castsi256_ps(_mm256_set1_epi32(-1));
    let (mut lo, mut hi) = (_mm256_set1_ps(f32::INFINITY), _mm256_set1_ps(f32::NEG_INFINITY));
    // Unsigned order through signed compares: flip the top bit of both sides.
    let flip = _mm256_set1_epi32(i32::MIN);
    let rotate = _mm256_setr_epi32(7, 0, 1, 2, 3, 4, 5, 6);
    // The previous chunk's last pixel, top bit flipped (none yet: below every index).
    let mut before = _mm256_set1_epi32(i32::MIN);
    let mut increasing = _mm256_set1_epi32(-1);
    let chunks = n / 8;
    for c in 0..chunks {
        let k = 8 * c;
        // SAFETY: AVX2 (the function's target feature); the loads and stores: `k + 8 ≤ n` and
        // every slice is `n` long.
        let (a, b) =
            unsafe { (_mm256_loadu_si256(s.as_ptr().add(k).cast()), _mm256_loadu_si256(s.as_ptr().add(k + 4).cast())) };
        let qx = low_dwords(_mm256_and_si256(a, pm), _mm256_and_si256(b, pm));
        let qy = low_dwords(
            _mm256_and_si256(_mm256_srli_epi64::<18>(a), pm),
            _mm256_and_si256(_mm256_srli_epi64::<18>(b), pm),
        );
        let qz = low_dwords(
            _mm256_and_si256(_mm256_srli_epi64::<36>(a), pm),
            _mm256_and_si256(_mm256_srli_epi64::<36>(b), pm),
        );
        let q = [_mm256_cvtepi32_ps(qx), _mm256_cvtepi32_ps(qy), _mm256_cvtepi32_ps(qz)];
        let rel: [__m256; 3] =
            core::array::from_fn(|i| _mm256_sub_ps(_mm256_add_ps(dmin[i], _mm256_mul_ps(q[i], dstep[i])), eye[i]));
        let z = dot(rel, w);
        let sx = _mm256_div_ps(dot(rel, u), _mm256_mul_ps(z, tan_x));
        let sy = _mm256_div_ps(dot(rel, v), _mm256_mul_ps(z, tan_y));
        let xf = _mm256_mul_ps(_mm256_mul_ps(_mm256_add_ps(sx, one), half), width);
        let yf = _mm256_mul_ps(_mm256_mul_ps(_mm256_sub_ps(one, sy), half), height);
        let inside = _mm256_and_ps(
            _mm256_and_ps(_mm256_cmp_ps::<_CMP_GT_OQ>(z, near), _mm256_cmp_ps::<_CMP_GE_OQ>(xf, zero)),
            _mm256_and_ps(
                _mm256_and_ps(_mm256_cmp_ps::<_CMP_GE_OQ>(yf, zero), _mm256_cmp_ps::<_CMP_LT_OQ>(xf, width)),
                _mm256_cmp_ps::<_CMP_LT_OQ>(yf, height),
            ),
        );
        // `max` with 0 second: a NaN lane becomes 0, as Rust's `f32::max` makes it.
        let xi = _mm256_cvttps_epi32(_mm256_min_ps(_mm256_max_ps(xf, zero), width));
        let yi = _mm256_cvttps_epi32(_mm256_min_ps(_mm256_max_ps(yf, zero), height));
        let px = _mm256_add_ps(_mm256_cvtepi32_ps(xi), half);
        let py = _mm256_add_ps(_mm256_cvtepi32_ps(yi), half);
        let dd: [__m256; 3] = core::array::from_fn(|i| {
            _mm256_add_ps(_mm256_add_ps(corner[i], _mm256_mul_ps(du[i], px)), _mm256_mul_ps(dv[i], py))
        });
        let inv = _mm256_div_ps(one, _mm256_sqrt_ps(dot(dd, dd)));
        let d = [_mm256_mul_ps(dd[0], inv), _mm256_mul_ps(dd[1], inv), _mm256_mul_ps(dd[2], inv)];
        let t = dot(rel, d);
        let finite = _mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_and_ps(t, abs), inf);
        ok = _mm256_and_ps(ok, _mm256_and_ps(inside, finite));
        let p = _mm256_add_epi32(_mm256_mullo_epi32(yi, cols), xi);
        let pf = _mm256_xor_si256(p, flip);
        // Each lane's predecessor: the lane before, or the previous chunk's last.
        let pred = _mm256_blend_epi32::<1>(_mm256_permutevar8x32_epi32(pf, rotate), before);
        increasing = _mm256_and_si256(increasing, _mm256_cmpgt_epi32(pf, pred));
        before = _mm256_permutevar8x32_epi32(pf, _mm256_set1_epi32(7));
        lo = _mm256_min_ps(lo, t);
        hi = _mm256_max_ps(hi, t);
        let f = dot(d, fwd);
        // SAFETY: as for the loads.
        unsafe {
            _mm256_storeu_si256(pix.as_mut_ptr().add(k).cast(), p);
            _mm256_storeu_ps(depth.as_mut_ptr().add(k), t);
            _mm256_storeu_ps(dfwd.as_mut_ptr().add(k), f);
        }
    }
    let mut all = _mm256_movemask_ps(ok) == 0xff && _mm256_movemask_epi8(increasing) == -1;
    for k in 8 * chunks..n {
        all &= proj.project_lanes::<1>(geo, &s[k..], &mut pix[k..], &mut depth[k..], &mut dfwd[k..]);
        all &= k == 0 || pix[k - 1] < pix[k];
    }
    if !all {
        return None;
    }
    // Every depth is finite here, so the order of the folds does not matter.
    let (mut l, mut h) = ([0f32; 8], [0f32; 8]);
    // SAFETY: two 8-float arrays.
    unsafe {
        _mm256_storeu_ps(l.as_mut_ptr(), lo);
        _mm256_storeu_ps(h.as_mut_ptr(), hi);
    }
    let fold = |v: &[f32], init: (f32, f32)| v.iter().fold(init, |(a, b), &t| (a.min(t), b.max(t)));
    let (l, _) = fold(&l, (f32::INFINITY, f32::NEG_INFINITY));
    let (_, h) = fold(&h, (f32::INFINITY, f32::NEG_INFINITY));
    Some(fold(&depth[8 * chunks..], (l, h)))
}

/// Eight `i32` lanes (each in `0..=65535`) as eight `u16`, in order.
#[inline]
#[target_feature(enable = "avx2")]
fn to_u16x8(v: __m256i) -> __m128i {
    // packus works within 128-bit halves: [v0..v3 v0..v3 | v4..v7 v4..v7]; 64-bit chunks 0
    // and 2 hold v0..v3 and v4..v7.
    _mm256_castsi256_si128(_mm256_permute4x64_epi64::<0x08>(_mm256_packus_epi32(v, v)))
}

/// Eight `i32` lanes (each in `0..=255`) as eight bytes, in order, in the low 64 bits.
#[inline]
#[target_feature(enable = "avx2")]
fn to_u8x8(v: __m256i) -> __m128i {
    let w = to_u16x8(v);
    _mm_packus_epi16(w, w)
}

/// Pass 2 of `build_planes` (`code_lanes`) eight samples at a time: depth codes and radius
/// residuals. All slices are as long as `s`.
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
pub(super) fn code(
    geo: &Geo,
    params: &CompactParams,
    s: &[u64],
    t: &[f32],
    f: &[f32],
    codes: &mut [u16],
    rlo: &mut [u8],
    rhi: &mut [u8],
) {
    let n = s.len();
    let (t, f, codes, rlo, rhi) = (&t[..n], &f[..n], &mut codes[..n], &mut rlo[..n], &mut rhi[..n]);
    let (dmin, dstep) = (_mm256_set1_ps(params.depth_min), _mm256_set1_ps(params.depth_step));
    let (rc, rk) = (_mm256_set1_ps(params.radius.constant), _mm256_set1_ps(params.radius.per_depth));
    let unit = _mm256_set1_ps(geo.radius_unit);
    let (zero, half, one) = (_mm256_setzero_ps(), _mm256_set1_ps(0.5), _mm256_set1_ps(1.0));
    let (code_max, radius_max) = (_mm256_set1_ps(DEPTH_CODE_MAX as f32), _mm256_set1_ps(RADIUS_MAX as f32));
    let (rmask, low) = (_mm256_set1_epi32(RADIUS_MAX as i32), _mm256_set1_epi32(0xff));
    let chunks = n / 8;
    for c in 0..chunks {
        let k = 8 * c;
        // SAFETY: AVX2 (the function's target feature); the loads and stores: `k + 8 ≤ n` and
        // every slice is `n` long.
        let (a, b, tv, fv) = unsafe {
            (
                _mm256_loadu_si256(s.as_ptr().add(k).cast()),
                _mm256_loadu_si256(s.as_ptr().add(k + 4).cast()),
                _mm256_loadu_ps(t.as_ptr().add(k)),
                _mm256_loadu_ps(f.as_ptr().add(k)),
            )
        };
        // `max` with 0 second sends NaN to 0, as the reference's clamp does.
        let q = _mm256_add_ps(_mm256_div_ps(_mm256_sub_ps(tv, dmin), dstep), half);
        let ci = _mm256_cvttps_epi32(_mm256_min_ps(_mm256_max_ps(q, zero), code_max));
        let td = _mm256_add_ps(dmin, _mm256_mul_ps(_mm256_cvtepi32_ps(ci), dstep));
        let r = _mm256_add_ps(rc, _mm256_mul_ps(rk, _mm256_mul_ps(td, fv)));
        let x = _mm256_add_ps(_mm256_div_ps(r, unit), half);
        let rf = _mm256_and_ps(_mm256_cmp_ps::<_CMP_GT_OQ>(r, zero), _mm256_min_ps(_mm256_max_ps(x, one), radius_max));
        let model = _mm256_cvttps_epi32(rf);
        let stored = low_dwords(_mm256_srli_epi64::<54>(a), _mm256_srli_epi64::<54>(b));
        let res = _mm256_and_si256(_mm256_sub_epi32(stored, model), rmask);
        // SAFETY: as for the loads.
        unsafe {
            _mm_storeu_si128(codes.as_mut_ptr().add(k).cast(), to_u16x8(ci));
            _mm_storel_epi64(rlo.as_mut_ptr().add(k).cast(), to_u8x8(_mm256_and_si256(res, low)));
            _mm_storel_epi64(rhi.as_mut_ptr().add(k).cast(), to_u8x8(_mm256_srli_epi32::<8>(res)));
        }
    }
    for i in 8 * chunks..n {
        super::code_lanes::<1>(geo, params, &s[i..], &t[i..], &f[i..], &mut codes[i..], &mut rlo[i..], &mut rhi[i..]);
    }
}

/// The gather step of `residuals_by_row` for the samples `i0..i1` of one row (pixel indices
/// `pix`, first index of the row `row_start`), eight at a time: each sample's prediction read
/// from the row's predictions (`pred_m` non-zero: the previous sample's values instead) and
/// its residuals written to the planes. `pred_d` has one cell more than the row (a 32-bit
/// gather of a 16-bit cell reads the next cell's bytes too). `range` starts after sample 0.
/// Returns the first sample not done (the caller finishes the last few).
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
pub(super) fn gather_row(
    pix: &[u32],
    row_start: u32,
    range: core::ops::Range<usize>,
    codes: &[u16],
    colors: &[u32],
    pred: (&[u16], &[u32], &[u32]),
    d_out: [&mut [u8]; 2],
    c_out: [&mut [u8]; 4],
) -> usize {
    let (pred_d, pred_c, pred_m) = pred;
    let w = pred_c.len();
    assert!(pred_d.len() > w && pred_m.len() == w);
    let n = pix.len();
    assert!(codes.len() == n && colors.len() == n && range.end <= n);
    assert!(d_out.iter().all(|p| p.len() == n) && c_out.iter().all(|p| p.len() == n));
    let [dlo, dhi] = d_out;
    let [cr, cg, cb, ca] = c_out;
    assert!(range.start >= 1, "the first sample of the frame has no previous sample");
    let base = _mm256_set1_epi32(row_start as i32);
    let (low, word) = (_mm256_set1_epi32(0xff), _mm256_set1_epi32(0xffff));
    // Within each 128-bit half: the four samples' R bytes, then G, B, A.
    let transpose = _mm256_setr_epi8(
        0, 4, 8, 12, 1, 5, 9, 13, 2, 6, 10, 14, 3, 7, 11, 15, 0, 4, 8, 12, 1, 5, 9, 13, 2, 6, 10, 14, 3, 7, 11, 15,
    );
    // Then the halves' R dwords together, G, B, A: R0–7 | G0–7 | B0–7 | A0–7 as 64-bit chunks.
    let halves = _mm256_setr_epi32(0, 4, 1, 5, 2, 6, 3, 7);
    let mut i = range.start;
    while i + 8 <= range.end {
        // SAFETY: `1 ≤ i` and `i + 8 ≤ range.end ≤ n`, so every load and store of eight
        // elements at `i` or `i − 1` is inside its slice; each pixel index lies in the row
        // (`x < w`, the caller's row split), so every gather reads inside `pred_*` (`pred_d`
        // one cell more).
        unsafe {
            let x = _mm256_sub_epi32(_mm256_loadu_si256(pix.as_ptr().add(i).cast()), base);
            let m = _mm256_i32gather_epi32::<4>(pred_m.as_ptr().cast(), x);
            let pc = _mm256_i32gather_epi32::<4>(pred_c.as_ptr().cast(), x);
            let pd = _mm256_and_si256(_mm256_i32gather_epi32::<2>(pred_d.as_ptr().cast(), x), word);
            let last = _mm256_cmpgt_epi32(m, _mm256_setzero_si256());
            let prev_d = _mm256_cvtepu16_epi32(_mm_loadu_si128(codes.as_ptr().add(i - 1).cast()));
            let prev_c = _mm256_loadu_si256(colors.as_ptr().add(i - 1).cast());
            let pd = _mm256_blendv_epi8(pd, prev_d, last);
            let pc = _mm256_blendv_epi8(pc, prev_c, last);
            let d = _mm256_cvtepu16_epi32(_mm_loadu_si128(codes.as_ptr().add(i).cast()));
            let c = _mm256_loadu_si256(colors.as_ptr().add(i).cast());
            let dres = _mm256_and_si256(_mm256_sub_epi32(d, pd), word);
            _mm_storel_epi64(dlo.as_mut_ptr().add(i).cast(), to_u8x8(_mm256_and_si256(dres, low)));
            _mm_storel_epi64(dhi.as_mut_ptr().add(i).cast(), to_u8x8(_mm256_srli_epi32::<8>(dres)));
            let r = _mm256_permutevar8x32_epi32(_mm256_shuffle_epi8(_mm256_sub_epi8(c, pc), transpose), halves);
            let (lo, hi) = (_mm256_castsi256_si128(r), _mm256_extracti128_si256::<1>(r));
            _mm_storel_epi64(cr.as_mut_ptr().add(i).cast(), lo);
            _mm_storel_epi64(cg.as_mut_ptr().add(i).cast(), _mm_unpackhi_epi64(lo, lo));
            _mm_storel_epi64(cb.as_mut_ptr().add(i).cast(), hi);
            _mm_storel_epi64(ca.as_mut_ptr().add(i).cast(), _mm_unpackhi_epi64(hi, hi));
        }
        i += 8;
    }
    i
}

/// The high 32 bits of eight `u64` lanes (`a` then `b`), in order.
#[inline]
#[target_feature(enable = "avx2")]
fn high_dwords(a: __m256i, b: __m256i) -> __m256i {
    let sh = _mm256_shuffle_ps::<0xDD>(_mm256_castsi256_ps(a), _mm256_castsi256_ps(b));
    _mm256_castpd_si256(_mm256_permute4x64_pd::<0xD8>(_mm256_castps_pd(sh)))
}

/// `place` of the parent module (`place_lanes`) eight samples at a time, on the layout
/// [`undo_prediction`] writes: each sample becomes the packed sample on pixel `(x, y)`'s ray
/// at the code's depth, with the model's radius code plus the residual. `rlo` and `rhi` are as
/// long as `samples`.
#[target_feature(enable = "avx2")]
pub(super) fn place(geo: &Geo, params: &CompactParams, rlo: &[u8], rhi: &[u8], samples: &mut [u64]) {
    let n = samples.len();
    let (rlo, rhi) = (&rlo[..n], &rhi[..n]);
    let (corner, du, dv, eye, fwd) =
        (splat3(geo.corner), splat3(geo.du), splat3(geo.dv), splat3(geo.eye), splat3(geo.forward));
    let (qmin, qscale) = (splat3(geo.qmin), splat3(geo.qscale));
    let (dmin, dstep) = (_mm256_set1_ps(params.depth_min), _mm256_set1_ps(params.depth_step));
    let (rc, rk) = (_mm256_set1_ps(params.radius.constant), _mm256_set1_ps(params.radius.per_depth));
    let unit = _mm256_set1_ps(geo.radius_unit);
    let (zero, half, one) = (_mm256_setzero_ps(), _mm256_set1_ps(0.5), _mm256_set1_ps(1.0));
    let (pos_max, radius_max) = (_mm256_set1_ps(POS_MAX as f32), _mm256_set1_ps(RADIUS_MAX as f32));
    let (low24, rmask) = (_mm256_set1_epi32(0xff_ffff), _mm256_set1_epi32(RADIUS_MAX as i32));
    let low16 = _mm256_set1_epi32(0xffff);
    let chunks = n / 8;
    for c in 0..chunks {
        let k = 8 * c;
        // SAFETY: AVX2 (the function's target feature); the loads and stores: `k + 8 ≤ n` and
        // every slice is `n` long.
        let (a, b, lo8, hi8) = unsafe {
            (
                _mm256_loadu_si256(samples.as_ptr().add(k).cast()),
                _mm256_loadu_si256(samples.as_ptr().add(k + 4).cast()),
                _mm256_cvtepu8_epi32(_mm_loadl_epi64(rlo.as_ptr().add(k).cast())),
                _mm256_cvtepu8_epi32(_mm_loadl_epi64(rhi.as_ptr().add(k).cast())),
            )
        };
        // x in bits 0–23, y in 24–47, the depth code in 48–63.
        let (l, h) = (low_dwords(a, b), high_dwords(a, b));
        let code = _mm256_srli_epi32::<16>(h);
        let y = _mm256_or_si256(_mm256_srli_epi32::<24>(l), _mm256_slli_epi32::<8>(_mm256_and_si256(h, low16)));
        let px = _mm256_add_ps(_mm256_cvtepi32_ps(_mm256_and_si256(l, low24)), half);
        let py = _mm256_add_ps(_mm256_cvtepi32_ps(y), half);
        let dd: [__m256; 3] = core::array::from_fn(|i| {
            _mm256_add_ps(_mm256_add_ps(corner[i], _mm256_mul_ps(du[i], px)), _mm256_mul_ps(dv[i], py))
        });
        let inv = _mm256_div_ps(one, _mm256_sqrt_ps(dot(dd, dd)));
        let d = [_mm256_mul_ps(dd[0], inv), _mm256_mul_ps(dd[1], inv), _mm256_mul_ps(dd[2], inv)];
        let t = _mm256_add_ps(dmin, _mm256_mul_ps(_mm256_cvtepi32_ps(code), dstep));
        let q: [__m256i; 3] = core::array::from_fn(|i| {
            let p = _mm256_add_ps(eye[i], _mm256_mul_ps(d[i], t));
            let f = _mm256_add_ps(_mm256_mul_ps(_mm256_sub_ps(p, qmin[i]), qscale[i]), half);
            // `max` with 0 second: NaN goes to 0 as in the reference.
            _mm256_cvttps_epi32(_mm256_min_ps(_mm256_max_ps(f, zero), pos_max))
        });
        let r = _mm256_add_ps(rc, _mm256_mul_ps(rk, _mm256_mul_ps(t, dot(d, fwd))));
        let x = _mm256_add_ps(_mm256_div_ps(r, unit), half);
        let rf = _mm256_and_ps(_mm256_cmp_ps::<_CMP_GT_OQ>(r, zero), _mm256_min_ps(_mm256_max_ps(x, one), radius_max));
        let res = _mm256_or_si256(lo8, _mm256_slli_epi32::<8>(hi8));
        let rcode = _mm256_and_si256(_mm256_add_epi32(_mm256_cvttps_epi32(rf), res), rmask);
        // The packed samples' low and high 32 bits (qx | qy << 18 | qz << 36 | rcode << 54),
        // then interleaved into 64-bit lanes.
        let lo = _mm256_or_si256(q[0], _mm256_slli_epi32::<18>(q[1]));
        let hi = _mm256_or_si256(
            _mm256_or_si256(_mm256_srli_epi32::<14>(q[1]), _mm256_slli_epi32::<4>(q[2])),
            _mm256_slli_epi32::<22>(rcode),
        );
        let (ul, uh) = (_mm256_unpacklo_epi32(lo, hi), _mm256_unpackhi_epi32(lo, hi));
        let (first, second) = (_mm256_permute2x128_si256::<0x20>(ul, uh), _mm256_permute2x128_si256::<0x31>(ul, uh));
        // SAFETY: as for the loads.
        unsafe {
            _mm256_storeu_si256(samples.as_mut_ptr().add(k).cast(), first);
            _mm256_storeu_si256(samples.as_mut_ptr().add(k + 4).cast(), second);
        }
    }
    for i in 8 * chunks..n {
        // Back to the portable layout for the portable code.
        let v = samples[i];
        samples[i] = v >> 48 | (v & 0xff_ffff) << 16 | ((v >> 24) & 0xff_ffff) << 40;
        super::place_lanes::<1>(geo, params, &rlo[i..], &rhi[i..], &mut samples[i..]);
    }
}
