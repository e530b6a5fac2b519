//! The base lane types of x86-64 (AVX2: eight lanes; AVX-512: sixteen) and the operations
//! every kernel shares: arithmetic, square root, minima and maxima, comparisons, selects,
//! loads and stores. The server's marcher lanes and the CPU tracer's lanes implement their
//! traits on these types and add their own operations (gathers, decodes, transposes) on
//! [`Avx2::raw`] registers.
//!
//! **Invariant**: a value of these types exists only on a CPU with their features (AVX2 for
//! [`Avx2`] and [`Avx2I`]; AVX2, AVX-512 F and DQ for [`Avx512`] and [`Avx512I`]). The safe
//! constructors take the feature's token ([`Avx2Token`], [`Avx512Token`]); [`Avx2::from_raw`]
//! is `unsafe` and its caller guarantees the features. So a method holding a value may use the
//! features: every `unsafe` block below relies on this.
//!
//! The methods are `#[inline(always)]`: inlined into a function compiled with the features
//! (the instances of [`crate::dispatch!`]) each is one instruction or a few. Every float
//! operation is the IEEE single-precision operation (no fused multiply-add).
//!
//! Masks are lanes with all bits set (true) or clear (false); [`Avx512`] also gives its
//! comparisons as mask registers ([`Avx512::cmp_mask`]).

use crate::{Avx2Token, Avx512Token};
use core::arch::x86_64::*;
use core::ops::{Add, BitAnd, BitOr, Div, Mul, Sub};

/// Eight `f32` lanes in one AVX register (see the module's invariant).
#[derive(Clone, Copy, Debug)]
pub struct Avx2(__m256);

/// Eight `i32` lanes in one AVX register (see the module's invariant).
#[derive(Clone, Copy, Debug)]
pub struct Avx2I(__m256i);

/// Sixteen `f32` lanes in one AVX-512 register (see the module's invariant).
#[derive(Clone, Copy, Debug)]
pub struct Avx512(__m512);

/// Sixteen `i32` lanes in one AVX-512 register (see the module's invariant).
#[derive(Clone, Copy, Debug)]
pub struct Avx512I(__m512i);

/// Binary operators, each one instruction on the register.
macro_rules! binops {
    ($t:ident: $($tr:ident $f:ident $intr:ident),*) => {$(
        impl $tr for $t {
            type Output = $t;
            #[inline(always)]
            fn $f(self, rhs: $t) -> $t {
                // SAFETY: the CPU has the type's features (the module's invariant).
                $t(unsafe { $intr(self.0, rhs.0) })
            }
        }
    )*};
}
binops!(Avx2: Add add _mm256_add_ps, Sub sub _mm256_sub_ps, Mul mul _mm256_mul_ps, Div div _mm256_div_ps,
    BitAnd bitand _mm256_and_ps, BitOr bitor _mm256_or_ps);
binops!(Avx512: Add add _mm512_add_ps, Sub sub _mm512_sub_ps, Mul mul _mm512_mul_ps, Div div _mm512_div_ps,
    BitAnd bitand _mm512_and_ps, BitOr bitor _mm512_or_ps);
binops!(Avx2I: Add add _mm256_add_epi32);
binops!(Avx512I: Add add _mm512_add_epi32);

/// What every lane type has: the raw register, its construction, the token and the lanes as
/// an array.
macro_rules! lane_type {
    ($($t:ident($raw:ty): $token:ident, [$e:ty; $n:literal], $set1:ident, $store:ident;)*) => {$(
        impl $t {
            /// The number of lanes.
            pub const LANES: usize = $n;

            /// Lanes from a register.
            ///
            /// # Safety
            /// The CPU must have the type's features (the module's invariant).
            #[inline(always)]
            pub unsafe fn from_raw(v: $raw) -> $t {
                $t(v)
            }
            /// The register.
            #[inline(always)]
            pub fn raw(self) -> $raw {
                self.0
            }
            /// The token of the features (a value proves them).
            #[inline(always)]
            pub fn token(self) -> $token {
                $token(())
            }
            /// All lanes `x`.
            #[inline(always)]
            pub fn splat(_: $token, x: $e) -> $t {
                // SAFETY: the token proves the CPU has the features.
                $t(unsafe { $set1(x) })
            }
            /// The lanes, lane 0 first.
            #[inline(always)]
            pub fn to_array(self) -> [$e; $n] {
                let mut a = [<$e>::default(); $n];
                // SAFETY: the module's invariant; `a` is writable (unaligned store).
                unsafe { $store(a.as_mut_ptr().cast(), self.0) };
                a
            }
        }
    )*};
}
lane_type! {
    Avx2(__m256): Avx2Token, [f32; 8], _mm256_set1_ps, _mm256_storeu_ps;
    Avx2I(__m256i): Avx2Token, [i32; 8], _mm256_set1_epi32, _mm256_storeu_si256;
    Avx512(__m512): Avx512Token, [f32; 16], _mm512_set1_ps, _mm512_storeu_ps;
    Avx512I(__m512i): Avx512Token, [i32; 16], _mm512_set1_epi32, _mm512_storeu_si512;
}

/// The conversions between a width's float and integer lanes, and the integer product.
macro_rules! conversions {
    ($($t:ident / $ti:ident: $trunc:ident, $float:ident, $mullo:ident;)*) => {$(
        impl $t {
            /// Truncation toward zero per lane (`x as i32` for lanes in `i32`'s range; others
            /// give `i32::MIN`).
            #[inline(always)]
            pub fn trunc_int(self) -> $ti {
                // SAFETY: the module's invariant.
                $ti(unsafe { $trunc(self.0) })
            }
        }
        impl $ti {
            /// The lanes as `f32`, rounded to nearest (`as f32`).
            #[inline(always)]
            pub fn to_float(self) -> $t {
                // SAFETY: the module's invariant.
                $t(unsafe { $float(self.0) })
            }
            /// Per lane `self * rhs`, the low 32 bits.
            #[inline(always)]
            pub fn mul_lo(self, rhs: $ti) -> $ti {
                // SAFETY: the module's invariant.
                $ti(unsafe { $mullo(self.0, rhs.0) })
            }
        }
    )*};
}
conversions! {
    Avx2 / Avx2I: _mm256_cvttps_epi32, _mm256_cvtepi32_ps, _mm256_mullo_epi32;
    Avx512 / Avx512I: _mm512_cvttps_epi32, _mm512_cvtepi32_ps, _mm512_mullo_epi32;
}

/// Comparison methods, each an ordered, non-signalling predicate (false if either lane is NaN).
macro_rules! compare_methods {
    ($t:ident: $($f:ident $p:ident $op:literal),*) => {$(
        #[doc = concat!("Mask of `self ", $op, " rhs` (false if either is NaN).")]
        #[inline(always)]
        pub fn $f(self, rhs: $t) -> $t {
            self.compare::<$p>(rhs)
        }
    )*};
}

/// What both float lane types share, with the same semantics at either width.
macro_rules! float_lanes {
    ($t:ident, $token:ident, $n:literal, $load:ident, $store:ident, $sqrt:ident, $min:ident, $max:ident) => {
        impl $t {
            /// The lanes of `a`, lane 0 first.
            #[inline(always)]
            pub fn load(_: $token, a: &[f32; $n]) -> $t {
                // SAFETY: the token proves the features; `a` is readable (unaligned load).
                $t(unsafe { $load(a.as_ptr()) })
            }
            /// Stores the lanes into `out`, lane 0 first.
            #[inline(always)]
            pub fn store(self, out: &mut [f32; $n]) {
                // SAFETY: the module's invariant; `out` is writable (unaligned store).
                unsafe { $store(out.as_mut_ptr(), self.0) }
            }
            /// IEEE square root per lane (correctly rounded).
            #[inline(always)]
            pub fn sqrt(self) -> $t {
                // SAFETY: the module's invariant.
                $t(unsafe { $sqrt(self.0) })
            }
            /// `if self < rhs { self } else { rhs }` per lane (`minps`'s operand order).
            #[inline(always)]
            pub fn fast_min(self, rhs: $t) -> $t {
                // SAFETY: the module's invariant.
                $t(unsafe { $min(self.0, rhs.0) })
            }
            /// `if self > rhs { self } else { rhs }` per lane (`maxps`'s operand order).
            #[inline(always)]
            pub fn fast_max(self, rhs: $t) -> $t {
                // SAFETY: the module's invariant.
                $t(unsafe { $max(self.0, rhs.0) })
            }
            /// `f32::min` per lane (a NaN operand gives the other one), as `wide`'s `min`:
            /// `rhs.is_nan().select(self, self.fast_min(rhs))`.
            #[inline(always)]
            pub fn min(self, rhs: $t) -> $t {
                rhs.compare::<_CMP_UNORD_Q>(rhs).select(self, self.fast_min(rhs))
            }
            /// `f32::max` per lane (a NaN operand gives the other one), as `wide`'s `max`.
            #[inline(always)]
            pub fn max(self, rhs: $t) -> $t {
                rhs.compare::<_CMP_UNORD_Q>(rhs).select(self, self.fast_max(rhs))
            }
            compare_methods!($t: simd_lt _CMP_LT_OQ "<", simd_le _CMP_LE_OQ "<=", simd_gt _CMP_GT_OQ ">",
                simd_ge _CMP_GE_OQ ">=", simd_eq _CMP_EQ_OQ "==");
        }
    };
}
float_lanes!(Avx2, Avx2Token, 8, _mm256_loadu_ps, _mm256_storeu_ps, _mm256_sqrt_ps, _mm256_min_ps, _mm256_max_ps);
float_lanes!(Avx512, Avx512Token, 16, _mm512_loadu_ps, _mm512_storeu_ps, _mm512_sqrt_ps, _mm512_min_ps, _mm512_max_ps);

/// A 4×4 transpose in every 128-bit block.
macro_rules! transpose_blocks {
    ($($t:ident: $lo:ident $hi:ident $lopd:ident $hipd:ident $pd:ident $ps:ident;)*) => {$(
        impl $t {
            /// Four vectors `[a, b, x, r]` regrouped per 128-bit block: block k of `u_j` is lane
            /// j of block k of each, `[a_j b_j x_j r_j]` (the first step of storing the lanes
            /// as records of four).
            #[inline(always)]
            pub fn transpose_blocks(v: [$t; 4]) -> [$t; 4] {
                let [a, b, x, r] = [v[0].0, v[1].0, v[2].0, v[3].0];
                // SAFETY: the module's invariant.
                unsafe {
                    // t0 = [a0 b0 a1 b1], t1 = [a2 b2 a3 b3], t2, t3 likewise of x and r.
                    let (t0, t1) = ($lo(a, b), $hi(a, b));
                    let (t2, t3) = ($lo(x, r), $hi(x, r));
                    [
                        $t($ps($lopd($pd(t0), $pd(t2)))),
                        $t($ps($hipd($pd(t0), $pd(t2)))),
                        $t($ps($lopd($pd(t1), $pd(t3)))),
                        $t($ps($hipd($pd(t1), $pd(t3)))),
                    ]
                }
            }
        }
    )*};
}
transpose_blocks! {
    Avx2: _mm256_unpacklo_ps _mm256_unpackhi_ps _mm256_unpacklo_pd _mm256_unpackhi_pd _mm256_castps_pd
        _mm256_castpd_ps;
    Avx512: _mm512_unpacklo_ps _mm512_unpackhi_ps _mm512_unpacklo_pd _mm512_unpackhi_pd _mm512_castps_pd
        _mm512_castpd_ps;
}

impl Avx2 {
    /// Ordered or unordered, non-signalling comparison `P` (a `_CMP_*`) as a mask: with an
    /// `_OQ` predicate false where either lane is NaN, as `wide`'s comparisons.
    #[inline(always)]
    pub fn compare<const P: i32>(self, rhs: Avx2) -> Avx2 {
        // SAFETY: the module's invariant.
        Avx2(unsafe { _mm256_cmp_ps::<P>(self.0, rhs.0) })
    }
    /// Per lane, `if_true` where the mask `self` is set, else `if_false` (`vblendvps` reads
    /// the sign bit, i.e. the whole lane of a mask).
    #[inline(always)]
    pub fn select(self, if_true: Avx2, if_false: Avx2) -> Avx2 {
        // SAFETY: the module's invariant.
        Avx2(unsafe { _mm256_blendv_ps(if_false.0, if_true.0, self.0) })
    }
    /// `self` and not `rhs`, bitwise.
    #[inline(always)]
    pub fn and_not(self, rhs: Avx2) -> Avx2 {
        // SAFETY: the module's invariant.
        Avx2(unsafe { _mm256_andnot_ps(rhs.0, self.0) })
    }
    /// Bit `l` is lane `l`'s sign bit (for a mask: whether it is set).
    #[inline(always)]
    pub fn to_bitmask(self) -> u32 {
        // SAFETY: the module's invariant.
        (unsafe { _mm256_movemask_ps(self.0) }) as u32
    }
    /// Whether any lane of the mask `self` is set (`vtestps`: ZF is set when no sign bit is).
    #[inline(always)]
    pub fn any(self) -> bool {
        // SAFETY: the module's invariant.
        unsafe { _mm256_testz_ps(self.0, self.0) == 0 }
    }
}

impl Avx512 {
    /// Comparison `P` (a `_CMP_*`) as a mask register, bit `l` lane `l`: with an `_OQ`
    /// predicate false where either lane is NaN.
    #[inline(always)]
    pub fn cmp_mask<const P: i32>(self, rhs: Avx512) -> __mmask16 {
        // SAFETY: the module's invariant.
        unsafe { _mm512_cmp_ps_mask::<P>(self.0, rhs.0) }
    }
    /// [`Avx512::cmp_mask`] as a mask of lanes, as [`Avx2::compare`].
    #[inline(always)]
    pub fn compare<const P: i32>(self, rhs: Avx512) -> Avx512 {
        Avx512::of_mask(self.token(), self.cmp_mask::<P>(rhs))
    }
    /// The mask register of a mask's lanes (their sign bits, `vpmovd2m`).
    #[inline(always)]
    pub fn mask(self) -> __mmask16 {
        // SAFETY: the module's invariant (AVX-512 DQ).
        unsafe { _mm512_movepi32_mask(_mm512_castps_si512(self.0)) }
    }
    /// A mask register as lanes with all bits set or clear (`vpmovm2d`).
    #[inline(always)]
    pub fn of_mask(_: Avx512Token, k: __mmask16) -> Avx512 {
        // SAFETY: the token proves AVX-512 DQ.
        Avx512(unsafe { _mm512_castsi512_ps(_mm512_movm_epi32(k)) })
    }
    /// The mask of the lanes of `bits` (bit `l`: lane `l`).
    #[inline(always)]
    pub fn of_bits(t: Avx512Token, bits: u32) -> Avx512 {
        Avx512::of_mask(t, bits as __mmask16)
    }
    /// Per lane, `if_true` where the mask `self` is set (by the sign bit of each lane, as
    /// `vblendvps`), else `if_false`.
    #[inline(always)]
    pub fn select(self, if_true: Avx512, if_false: Avx512) -> Avx512 {
        if_true.blend_mask(self.mask(), if_false)
    }
    /// Per lane, `self` where the mask register `k` is set, else `if_false`.
    #[inline(always)]
    pub fn blend_mask(self, k: __mmask16, if_false: Avx512) -> Avx512 {
        // SAFETY: the module's invariant.
        Avx512(unsafe { _mm512_mask_blend_ps(k, if_false.0, self.0) })
    }
    /// Bit `l` is lane `l`'s sign bit (for a mask: whether it is set).
    #[inline(always)]
    pub fn to_bitmask(self) -> u32 {
        self.mask() as u32
    }
    /// Whether any lane of the mask `self` is set.
    #[inline(always)]
    pub fn any(self) -> bool {
        self.mask() != 0
    }
    /// Writes the lanes of `bits` into `out` (the others keep what they hold).
    #[inline(always)]
    pub fn store_masked(self, out: &mut [f32; 16], bits: u32) {
        // SAFETY: the module's invariant; `out` is 64 writable bytes.
        unsafe { _mm512_mask_storeu_ps(out.as_mut_ptr(), bits as __mmask16, self.0) }
    }
    /// Writes `x` into the entries of `out` of the lanes of `bits`.
    #[inline(always)]
    pub fn store_u32_masked(_: Avx512Token, out: &mut [u32; 16], bits: u32, x: u32) {
        // SAFETY: the token proves AVX-512 F; `out` is 64 writable bytes.
        unsafe { _mm512_mask_storeu_epi32(out.as_mut_ptr().cast(), bits as __mmask16, _mm512_set1_epi32(x as i32)) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shared operations at both widths against the scalar operations they stand for.
    #[test]
    fn both_widths_match_scalar() {
        let Some(t) = Avx512Token::detected() else {
            return;
        };
        // SAFETY: the token proves the features of the function.
        unsafe { check(t) }
    }

    #[target_feature(enable = "avx2,avx512f,avx512dq")]
    fn check(t: Avx512Token) {
        let vals = [0.0, -0.0, 1.0, -1.0, 0.5, 3.0, 1e-40, f32::MAX, f32::INFINITY, -f32::INFINITY, f32::NAN];
        for (i, &a) in vals.iter().enumerate() {
            for &b in &vals[i..] {
                let (x8, y8) = (Avx2::splat(t.avx2(), a), Avx2::splat(t.avx2(), b));
                let (x16, y16) = (Avx512::splat(t, a), Avx512::splat(t, b));
                // `f32::min` and `max` may give either zero of `min(0, -0)`.
                let same = |r: f32, s: f32| r.to_bits() == s.to_bits() || (r.is_nan() && s.is_nan()) || r == s;
                for (r8, r16, s) in [
                    (x8 + y8, x16 + y16, a + b),
                    (x8 - y8, x16 - y16, a - b),
                    (x8 * y8, x16 * y16, a * b),
                    (x8 / y8, x16 / y16, a / b),
                    (x8.sqrt(), x16.sqrt(), a.sqrt()),
                    (x8.min(y8), x16.min(y16), a.min(b)),
                    (x8.max(y8), x16.max(y16), a.max(b)),
                    (x8.fast_min(y8), x16.fast_min(y16), if a < b { a } else { b }),
                    (x8.fast_max(y8), x16.fast_max(y16), if a > b { a } else { b }),
                ] {
                    assert!(r8.to_array().iter().all(|&r| same(r, s)), "{a} {b}");
                    assert!(r16.to_array().iter().all(|&r| same(r, s)), "{a} {b}");
                }
                for (m8, m16, s) in [
                    (x8.simd_lt(y8), x16.simd_lt(y16), a < b),
                    (x8.simd_le(y8), x16.simd_le(y16), a <= b),
                    (x8.simd_gt(y8), x16.simd_gt(y16), a > b),
                    (x8.simd_ge(y8), x16.simd_ge(y16), a >= b),
                    (x8.simd_eq(y8), x16.simd_eq(y16), a == b),
                ] {
                    assert_eq!(m8.to_bitmask(), if s { 0xff } else { 0 });
                    assert_eq!(m16.to_bitmask(), if s { 0xffff } else { 0 });
                    assert_eq!((m8.any(), m16.any()), (s, s));
                    assert_eq!(m8.select(x8, y8).to_array()[0].to_bits(), if s { a } else { b }.to_bits());
                    assert_eq!(m16.select(x16, y16).to_array()[0].to_bits(), if s { a } else { b }.to_bits());
                }
            }
        }
    }
}
