//! Sixteen `f32` lanes in one AVX-512 register, for the kernels generic over
//! [`BoundLanes`](super::BoundLanes) (the tiled splatter's bound pass): twice the lanes of
//! [`Avx2`](super::Avx2) per instruction, and on this project's Zen 5 host the same time per
//! square root and division, which bound that pass. Every method has exactly the semantics of
//! the [`Avx2`](super::Avx2) method of the same name (the same instruction at twice the
//! width), so a kernel computes the same values on both (tested below against the eight-lane
//! instances, bit for bit).
//!
//! Masks are lanes with all bits set or clear, as for the eight-lane types: comparisons give
//! an AVX-512 mask register, widened to lanes (`vpmovm2d`), and selects narrow it back
//! (`vpmovd2m`); one instruction each.

use super::{avx512, decode_scalar_into, Avx512, BoundLanes, RectLanes, EMPTY_RECT};
use core::arch::x86_64::*;
use volwarp_core::sample::{Dequantizer, POS_BITS, RADIUS_BITS};
use volwarp_lanes::Avx512I;

// SAFETY (every `unsafe` block of this impl): AVX2, AVX-512 F and DQ are available
// (`volwarp_lanes`' invariant: a value proves them, and the methods without one run only in the
// AVX-512 instances); the loads and stores are of sixteen `i32` / `f32` or eight `u64`, as
// noted there.
impl BoundLanes for Avx512 {
    const N: usize = 16;

    /// `Avx2::decode8`'s unpacking for sixteen samples: the low and high 32 bits of each
    /// (`vpmovqd`), the fields by 32-bit shifts, then `Dequantizer::center`'s and `radius`'s
    /// f32 operations in the same order (`min + q·step`, `code·unit`); fewer than sixteen
    /// samples take the scalar decode.
    #[inline(always)]
    fn decode(deq: &Dequantizer, eye: [f32; 3], s: &[u64]) -> [Self; 4] {
        const _: () = assert!(POS_BITS == 18 && RADIUS_BITS == 10);
        let Some(s) = s.first_chunk::<16>() else {
            let mut a = [[0f32; 16]; 4];
            decode_scalar_into(deq, eye, s, &mut a);
            return a.map(|v| Avx512::load(avx512(), &v));
        };
        // SAFETY: AVX2, AVX-512 F and DQ are available (`volwarp_lanes`' invariant, see [`super::avx512`]); the loads read the 128 bytes of `s`.
        unsafe {
            // `s` is 128 readable bytes.
            let a = _mm512_loadu_si512(s.as_ptr().cast());
            let b = _mm512_loadu_si512(s[8..].as_ptr().cast());
            let join = |x: __m256i, y: __m256i| _mm512_inserti64x4::<1>(_mm512_castsi256_si512(x), y);
            let lo = join(_mm512_cvtepi64_epi32(a), _mm512_cvtepi64_epi32(b));
            let hi = join(
                _mm512_cvtepi64_epi32(_mm512_srli_epi64::<32>(a)),
                _mm512_cvtepi64_epi32(_mm512_srli_epi64::<32>(b)),
            );
            let fields = sample_fields!(Avx512, lo, hi; _mm512_and_si512 _mm512_or_si512 _mm512_srli_epi32
                _mm512_slli_epi32 _mm512_set1_epi32 _mm512_cvtepi32_ps);
            super::dequantize(deq, eye, fields)
        }
    }

    /// `Avx2::span_ints` on sixteen lanes: truncation (`vcvttps2dq`), plus one where it fell
    /// below `lo`, at least 0; `hi` truncated, at most `max`.
    #[inline(always)]
    fn spans(lo: Self, hi: Self, max: u32) -> ([i32; 16], [i32; 16]) {
        // SAFETY: AVX2, AVX-512 F and DQ are available (`volwarp_lanes`' invariant, see [`super::avx512`]).
        unsafe {
            let t = _mm512_cvttps_epi32(lo.raw());
            let below = _mm512_cmp_ps_mask::<_CMP_LT_OQ>(_mm512_cvtepi32_ps(t), lo.raw());
            let c = _mm512_max_epi32(_mm512_mask_add_epi32(t, below, t, _mm512_set1_epi32(1)), _mm512_setzero_si512());
            let h = _mm512_min_epi32(_mm512_cvttps_epi32(hi.raw()), _mm512_set1_epi32(max as i32));
            (Avx512I::from_raw(c).to_array(), Avx512I::from_raw(h).to_array())
        }
    }

    #[inline(always)]
    fn from_ints16(a: &[i32; 16]) -> Self {
        // `a` is 64 readable bytes; `vcvtdq2ps` rounds to nearest as `as f32` does.
        // SAFETY: AVX2, AVX-512 F and DQ are available (`volwarp_lanes`' invariant, see [`super::avx512`]); `a` is 64 readable bytes.
        unsafe { Avx512::from_raw(_mm512_cvtepi32_ps(_mm512_loadu_si512(a.as_ptr().cast()))) }
    }

    #[inline(always)]
    fn lanes(self) -> [f32; 16] {
        self.to_array()
    }

    /// Sixteen records by a 4×16 transpose in registers (four 64-byte stores); fewer by the
    /// lanes one at a time.
    #[inline(always)]
    fn store_records(c: [Self; 4], out: &mut [[f32; 4]]) {
        let Some(out) = out.first_chunk_mut::<16>() else {
            let [a, b, x, r] = c.map(|v| v.lanes());
            for (l, o) in out.iter_mut().take(16).enumerate() {
                *o = [a[l], b[l], x[l], r[l]];
            }
            return;
        };
        // SAFETY: AVX2, AVX-512 F and DQ are available (`volwarp_lanes`' invariant, see [`super::avx512`]); the stores write the 256 bytes of `out` (noted below).
        unsafe {
            // Records 4k, 4k + 1, 4k + 2, 4k + 3 in block k of u0, u1, u2, u3.
            let [u0, u1, u2, u3] = Avx512::transpose_blocks(c);
            let (u0, u1, u2, u3) = (u0.raw(), u1.raw(), u2.raw(), u3.raw());
            // Block k of the result j (records 4j…4j + 3) is block j of u_k.
            let lo01 = _mm512_shuffle_f32x4::<0b01_00_01_00>(u0, u1); // u0.0 u0.1 u1.0 u1.1
            let lo23 = _mm512_shuffle_f32x4::<0b01_00_01_00>(u2, u3); // u2.0 u2.1 u3.0 u3.1
            let hi01 = _mm512_shuffle_f32x4::<0b11_10_11_10>(u0, u1); // u0.2 u0.3 u1.2 u1.3
            let hi23 = _mm512_shuffle_f32x4::<0b11_10_11_10>(u2, u3); // u2.2 u2.3 u3.2 u3.3
            let r0 = _mm512_shuffle_f32x4::<0b10_00_10_00>(lo01, lo23); // u0.0 u1.0 u2.0 u3.0
            let r1 = _mm512_shuffle_f32x4::<0b11_01_11_01>(lo01, lo23); // u0.1 u1.1 u2.1 u3.1
            let r2 = _mm512_shuffle_f32x4::<0b10_00_10_00>(hi01, hi23);
            let r3 = _mm512_shuffle_f32x4::<0b11_01_11_01>(hi01, hi23);
            // `out` is sixteen records of 16 bytes: four 64-byte stores.
            let p = out.as_mut_ptr().cast::<f32>();
            _mm512_storeu_ps(p, r0);
            _mm512_storeu_ps(p.add(16), r1);
            _mm512_storeu_ps(p.add(32), r2);
            _mm512_storeu_ps(p.add(48), r3);
        }
    }

    /// The default's rules on sixteen lanes at once: the rectangle fields packed in pairs of
    /// 16 bits and interleaved to 64-bit words, the tile counts by shifts and a 32-bit
    /// product, the union by masked reductions.
    #[inline(always)]
    fn rects(ok: u32, spans: [&[i32; 16]; 4], tile_log2: u32, max_tiles: i32) -> RectLanes {
        // SAFETY: AVX2, AVX-512 F and DQ are available (`volwarp_lanes`' invariant, see [`super::avx512`]); the loads read the spans, the stores write `bits` (noted below).
        unsafe {
            let load = |a: &[i32; 16]| _mm512_loadu_si512(a.as_ptr().cast());
            let [x0, x1, y0, y1] = spans;
            let (a, b, c, d) = (load(x0), load(x1), load(y0), load(y1));
            let fast = ok as __mmask16 & _mm512_cmple_epi32_mask(a, b) & _mm512_cmple_epi32_mask(c, d);
            let s = _mm_cvtsi32_si128(tile_log2 as i32);
            let one = _mm512_set1_epi32(1);
            let tx = _mm512_add_epi32(_mm512_sub_epi32(_mm512_sra_epi32(b, s), _mm512_sra_epi32(a, s)), one);
            let ty = _mm512_add_epi32(_mm512_sub_epi32(_mm512_sra_epi32(d, s), _mm512_sra_epi32(c, s)), one);
            let large = fast & _mm512_cmpgt_epi32_mask(_mm512_mullo_epi32(tx, ty), _mm512_set1_epi32(max_tiles));
            let drawn = fast & !large;
            let lo = _mm512_or_si512(a, _mm512_slli_epi32::<16>(c));
            let hi = _mm512_or_si512(b, _mm512_slli_epi32::<16>(d));
            let lo = _mm512_mask_blend_epi32(fast, _mm512_set1_epi32(EMPTY_RECT as i32), lo);
            let hi = _mm512_maskz_mov_epi32(fast, hi);
            let first = _mm512_setr_epi32(0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23);
            let second = _mm512_setr_epi32(8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31);
            let mut bits = [0u64; 16];
            // `bits` is 128 writable bytes: two 64-byte stores.
            _mm512_storeu_si512(bits.as_mut_ptr().cast(), _mm512_permutex2var_epi32(lo, first, hi));
            _mm512_storeu_si512(bits[8..].as_mut_ptr().cast(), _mm512_permutex2var_epi32(lo, second, hi));
            let union = if drawn == 0 {
                EMPTY_RECT
            } else {
                let (ux0, uy0) = (_mm512_mask_reduce_min_epi32(drawn, a), _mm512_mask_reduce_min_epi32(drawn, c));
                let (ux1, uy1) = (_mm512_mask_reduce_max_epi32(drawn, b), _mm512_mask_reduce_max_epi32(drawn, d));
                ux0 as u64 | (uy0 as u64) << 16 | (ux1 as u64) << 32 | (uy1 as u64) << 48
            };
            RectLanes { bits, large: large as u32, drawn: drawn as u32, union }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{Avx512, BoundLanes};
    use crate::lanes::{decode_scalar_into, Arith, Avx2, Lanes};
    use core::arch::x86_64::__m512;

    fn bits(x: Avx512) -> [u32; 16] {
        // SAFETY: `__m512` is 64 bytes of plain data, as is `[u32; 16]`.
        unsafe { core::mem::transmute::<__m512, [u32; 16]>(x.raw()) }
    }

    fn halves(x: [f32; 16]) -> [Avx2; 2] {
        let h = |o: usize| <Avx2 as Lanes>::new(core::array::from_fn(|l| x[o + l]));
        [h(0), h(8)]
    }

    fn bits2(x: [Avx2; 2]) -> [u32; 16] {
        let (a, b) = (x[0].to_array(), x[1].to_array());
        core::array::from_fn(|l| if l < 8 { a[l] } else { b[l - 8] }.to_bits())
    }

    /// Every method against `Avx2`'s on each half, on NaNs, signed zeros, infinities,
    /// subnormals and ordinary values, compiled as the kernel is.
    #[target_feature(enable = "avx2,avx512f,avx512dq")]
    fn check(t: volwarp_lanes::Avx512Token) {
        for (a, b) in crate::lanes::test_operands::<16>() {
            let load = |v: [f32; 16]| Avx512::load(t, &v);
            let (x, y) = (load(a), load(b));
            let ([p0, p1], [q0, q1]) = (halves(a), halves(b));
            let two = |f: &dyn Fn(Avx2, Avx2) -> Avx2| [f(p0, q0), f(p1, q1)];
            let eq = |what: &str, r: Avx512, s: [Avx2; 2]| assert_eq!(bits(r), bits2(s), "{what}: {a:?} {b:?}");
            // Arithmetic: a NaN's sign and payload are unspecified in Rust.
            let same = |what: &str, r: Avx512, s: [Avx2; 2]| {
                let (r, s) = (bits(r), bits2(s));
                let nan = |u: u32| f32::from_bits(u).is_nan();
                assert!((0..16).all(|l| r[l] == s[l] || (nan(r[l]) && nan(s[l]))), "{what}: {a:?} {b:?}");
            };
            eq("lanes", load(x.lanes()), [p0, p1]);
            eq("splat", <Avx512 as Arith>::splat(a[3]), [<Avx2 as Arith>::splat(a[3]); 2]);
            same("add", x + y, two(&|p, q| p + q));
            same("sub", x - y, two(&|p, q| p - q));
            same("mul", x * y, two(&|p, q| p * q));
            same("div", x / y, two(&|p, q| p / q));
            same("sqrt", x.sqrt(), two(&|p, _| p.sqrt()));
            eq("max", x.max(y), two(&|p, q| p.max(q)));
            eq("fast_min", x.fast_min(y), two(&|p, q| p.fast_min(q)));
            eq("fast_max", x.fast_max(y), two(&|p, q| p.fast_max(q)));
            eq("lt", x.simd_lt(y), two(&|p, q| p.simd_lt(q)));
            eq("le", x.simd_le(y), two(&|p, q| p.simd_le(q)));
            eq("gt", x.simd_gt(y), two(&|p, q| p.simd_gt(q)));
            eq("ge", x.simd_ge(y), two(&|p, q| p.simd_ge(q)));
            eq("eq", x.simd_eq(y), two(&|p, q| p.simd_eq(q)));
            let (m, n) = (x.simd_lt(y), x.simd_ge(y));
            let (wm, wn) = (two(&|p, q| p.simd_lt(q)), two(&|p, q| p.simd_ge(q)));
            eq("and", m & n, [wm[0] & wn[0], wm[1] & wn[1]]);
            eq("or", m | n, [wm[0] | wn[0], wm[1] | wn[1]]);
            eq("select", m.select(x, y), [wm[0].select(p0, q0), wm[1].select(p1, q1)]);
            for (v, w) in [(m, wm), (x, [p0, p1])] {
                assert_eq!(v.to_bitmask(), w[0].to_bitmask() | w[1].to_bitmask() << 8);
                assert_eq!(v.any(), w[0].any() || w[1].any());
            }
        }
        // decode: sixteen samples in lanes, and fewer by the scalar decode.
        let deq = crate::lanes::test_dequantizer();
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        for round in 0..200 {
            let s: [u64; 16] = crate::lanes::test_samples(round, &mut x);
            let eye = [0.5, -2.0, 10.0];
            for n in [16, 15, 9, 1, 0] {
                let mut want = [[0f32; 16]; 4];
                decode_scalar_into(&deq, eye, &s[..n], &mut want);
                let got = Avx512::decode(&deq, eye, &s[..n]);
                for (g, w) in got.iter().zip(&want) {
                    assert_eq!(g.lanes().map(f32::to_bits), w.map(f32::to_bits), "decode {n}: {s:x?}");
                }
            }
        }
        // spans and from_ints16 against the eight-lane ones, on each half.
        let mut sweep: Vec<f32> = (0..4000).map(|i| i as f32 * 0.37 - 1.0).collect();
        sweep.extend_from_slice(&[-1.0, -0.999, -0.0, 0.0, 1e-7, 8191.5, 8192.0, 16777215.0, 2e9, 2e9]);
        for c in sweep.chunks_exact(16) {
            let lo: [f32; 16] = core::array::from_fn(|l| c[l]);
            let hi: [f32; 16] = core::array::from_fn(|l| (c[(l * 7) % 16] + 0.75).max(0.0));
            for max in [0u32, 1, 511, 1023, 8191] {
                let load = |v: [f32; 16]| Avx512::load(t, &v);
                let (a, b) = Avx512::spans(load(lo), load(hi), max);
                let ([l0, l1], [h0, h1]) = (halves(lo), halves(hi));
                let (w0, w1) = (Avx2::span_ints(l0, h0, max), Avx2::span_ints(l1, h1, max));
                assert_eq!(a[..8], w0.0, "spans {lo:?} {max}");
                assert_eq!(a[8..], w1.0, "spans {lo:?} {max}");
                assert_eq!(b[..8], w0.1, "spans {hi:?} {max}");
                assert_eq!(b[8..], w1.1, "spans {hi:?} {max}");
                let f = Avx512::from_ints16(&a).lanes();
                assert_eq!(f, a.map(|v| v as f32));
            }
        }
    }

    #[test]
    fn avx512_lanes_equal_avx2_bit_for_bit() {
        if let Some(t) = volwarp_lanes::Avx512Token::detected() {
            // SAFETY: the token proves AVX2, AVX-512 F and DQ.
            unsafe { check(t) }
        } else {
            eprintln!("notice: this CPU has no AVX-512 F and DQ; the AVX-512 lanes were not run");
        }
    }
}
