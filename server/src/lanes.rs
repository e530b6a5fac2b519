//! The vector types (8 to 64 lanes) the packet marcher ([`crate::packet_march`]) is generic over:
//! `f32` lanes (also used as masks), `i32` lanes, and gathers from `f32` slices.
//!
//! The lane level, its tokens, the dispatch macro and the base types [`Avx2`] and [`Avx512`]
//! are `volwarp_lanes`' (shared with the CPU tracer and core's codec); this module adds the
//! operations a marcher needs (truncation to integers, integer index arithmetic, gathers) as
//! the [`Lanes`] trait. `wide` picks its representation when *it* is compiled (two SSE halves
//! on baseline x86-64), so the AVX types wrap the registers directly; their
//! `#[inline(always)]` methods become single instructions once inlined into a function
//! compiled with the features. Every method computes exactly what the scalar marcher's operation does
//! (IEEE single precision, no fused multiply-add), so the packet marcher's results are the
//! scalar marcher's bit for bit.
//!
//! Masks are lanes with all bits set (true) or clear (false).

use core::ops::{Add, BitAnd, BitOr, Div, Mul, Sub};
use wide::{f32x8, i32x8};

pub use volwarp_lanes::{lane_kind, limit_lanes, LaneKind};

/// Warns (in the log) where `VOLWARP_LANES` is set to no known lane kind; a known one already
/// clamps every kernel's lanes ([`volwarp_lanes::lane_kind`] reads it once). The server, its
/// benches and `march_timing` call this.
pub fn limit_lanes_from_env() {
    if let Ok(v) = std::env::var("VOLWARP_LANES") {
        if let Err(e) = v.parse::<LaneKind>() {
            log::warn!("VOLWARP_LANES: {v:?}: {e}");
        }
    }
}

/// Defines `$name`, which runs the kernel `$kernel::<L, M>` on the lanes
/// [`volwarp_lanes::level`] picks (with [`volwarp_lanes::dispatch!`]): the instance `$avx512`,
/// compiled with AVX-512 F and DQ on `X2<X2<Avx512>>` (64 lanes); the instance `$avx2`,
/// compiled with AVX2 on `X2<X2<Avx2>>` (32); or the portable `X2<wide::f32x8>` instance (16).
/// Each instance's packet arrays are sized for its lanes (the kernel's const `M`). All compute
/// the same values.
macro_rules! dispatch {
    ($(#[$doc:meta])* fn $name:ident / $avx2:ident / $avx512:ident => $($kernel:tt)*) => {
        volwarp_lanes::dispatch! {
            $(#[$doc])*
            pub(crate) fn $name / $avx2 / $avx512 => $($kernel)*;
            portable = [$crate::lanes::X2<wide::f32x8>, 16],
            avx2 = [$crate::lanes::X2<$crate::lanes::X2<$crate::lanes::Avx2>>, 32],
            avx512 = [$crate::lanes::X2<$crate::lanes::X2<$crate::lanes::Avx512>>, 64]
        }
    };
}
pub(crate) use dispatch;

/// A mask of [`Lanes`]: a lane vector with all bits set or clear per lane (AVX2, `wide`) or a
/// mask register (AVX-512).
pub(crate) trait Mask: Copy + BitAnd<Output = Self> + BitOr<Output = Self> {
    /// The number of lanes.
    const LANES: usize;
    /// Bit `l` is lane `l`.
    fn to_bitmask(self) -> u64;
    /// Whether any lane is set.
    fn any(self) -> bool;
    /// `self` and not `rhs`.
    fn and_not(self, rhs: Self) -> Self;
    /// Per lane, `if_true` where the mask is set, else `if_false`.
    #[inline(always)]
    fn select<L: Lanes<M = Self>>(self, if_true: L, if_false: L) -> L {
        L::blend(self, if_true, if_false)
    }
}

/// `N` `f32` lanes and their companion `N` `i32` lanes and mask (`N` = 8, 16 or 32).
pub(crate) trait Lanes: volwarp_lanes::Ops {
    /// `i32` lanes, as many.
    type I: Copy + Add<Output = Self::I>;
    /// A mask of as many lanes.
    type M: Mask;
    /// The number of lanes (at most 64: a mask's bits are a `u64`).
    const N: usize;

    /// All lanes `x`.
    fn splat(x: f32) -> Self;
    /// The lanes of `a[..N]`, lane 0 first (`a` holds at least `N` values).
    fn new(a: &[f32]) -> Self;
    /// `f32::min` per lane where `rhs` is not NaN (a NaN `self` gives `rhs`); `rhs` where it is
    /// (`minps`: one instruction, the kernel's bounds are never NaN).
    fn min(self, rhs: Self) -> Self;
    /// `f32::max` per lane where `rhs` is not NaN (a NaN `self` gives `rhs`); `rhs` where it is.
    fn max(self, rhs: Self) -> Self;
    /// Mask of `self < rhs` (false if either is NaN).
    fn simd_lt(self, rhs: Self) -> Self::M;
    /// Mask of `self > rhs` (false if either is NaN).
    fn simd_gt(self, rhs: Self) -> Self::M;
    /// Mask of `self >= rhs` (false if either is NaN).
    fn simd_ge(self, rhs: Self) -> Self::M;
    /// Per lane, `if_true` where `m` is set, else `if_false`.
    fn blend(m: Self::M, if_true: Self, if_false: Self) -> Self;
    /// The mask whose lane `l` is bit `l` of `bits`.
    fn mask_from_bits(bits: u64) -> Self::M;
    /// Stores the lanes into `out[..N]`, lane 0 first (`out` holds at least `N` values).
    fn store(self, out: &mut [f32]);
    /// The lanes as the start of an `M`-long array (`M ≥ N`; the rest zero).
    #[inline(always)]
    fn to_array<const M: usize>(self) -> [f32; M] {
        let mut a = [0.0; M];
        self.store(&mut a);
        a
    }
    /// Truncation toward zero of lanes in `0 ..= 2³¹ − 128` (`x as i32` there).
    fn trunc_int(self) -> Self::I;
    /// The `i32` lanes as `f32` (exact below 2²⁴).
    fn int_to_float(i: Self::I) -> Self;
    /// All `i32` lanes `x`.
    fn splat_i(x: i32) -> Self::I;
    /// Per lane `a * b`, the low 32 bits.
    fn mul_i(a: Self::I, b: Self::I) -> Self::I;
    /// Per lane `data[idx]`, each index clamped to `0 ..= data.len() − 1` first (an empty
    /// slice gives zeros).
    fn gather(data: &[f32], idx: Self::I) -> Self;
    /// Per lane `(data[idx], data[idx + 1])`, each index clamped to `0 ..= data.len() − 2`
    /// first (a slice shorter than 2 gives zeros).
    fn gather_pairs(data: &[f32], idx: Self::I) -> (Self, Self);
    /// Per lane `a & b`.
    fn and_i(a: Self::I, b: Self::I) -> Self::I;
    /// Per lane `a >> N` (logical; the kernel shifts non-negative lanes only).
    fn shr_i<const N: i32>(a: Self::I) -> Self::I;
    /// Per lane `(data[idx], data[idx + 1])` as `f32` (exact), each index clamped to
    /// `0 ..= data.len() − 4` first (the gather reads 4 bytes; a slice shorter than 4 gives
    /// zeros).
    fn gather_byte_pairs(data: &[u8], idx: Self::I) -> (Self, Self);
    /// Per lane `data[idx ..= idx + 3]` as `f32` (exact), each index clamped to
    /// `0 ..= data.len() − 4` first (a slice shorter than 4 gives zeros): the same gather as
    /// [`Lanes::gather_byte_pairs`], all four bytes kept.
    fn gather_byte_quads(data: &[u8], idx: Self::I) -> [Self; 4];
    /// Per lane `(data[idx], data[idx + 1])` as `f32` (exact), each index clamped to
    /// `0 ..= data.len() − 2` first (a slice shorter than 2 gives zeros).
    fn gather_short_pairs(data: &[u16], idx: Self::I) -> (Self, Self);
    /// Per lane the square root, correctly rounded (IEEE, as `f32::sqrt`).
    fn sqrt(self) -> Self;
}

/// The portable lanes: `wide`'s, whatever it was compiled for.
impl Mask for f32x8 {
    const LANES: usize = 8;
    #[inline(always)]
    fn to_bitmask(self) -> u64 {
        f32x8::to_bitmask(self) as u64
    }
    #[inline(always)]
    fn any(self) -> bool {
        f32x8::any(self)
    }
    #[inline(always)]
    fn and_not(self, rhs: Self) -> Self {
        self & !rhs
    }
}

impl Lanes for f32x8 {
    type I = i32x8;
    type M = f32x8;
    const N: usize = 8;

    #[inline(always)]
    fn splat(x: f32) -> Self {
        f32x8::splat(x)
    }
    #[inline(always)]
    fn new(a: &[f32]) -> Self {
        let a: &[f32; 8] = a[..8].try_into().expect("eight lanes");
        f32x8::new(*a)
    }
    #[inline(always)]
    fn min(self, rhs: Self) -> Self {
        f32x8::fast_min(self, rhs)
    }
    #[inline(always)]
    fn max(self, rhs: Self) -> Self {
        f32x8::fast_max(self, rhs)
    }
    #[inline(always)]
    fn simd_lt(self, rhs: Self) -> Self {
        f32x8::simd_lt(self, rhs)
    }
    #[inline(always)]
    fn simd_gt(self, rhs: Self) -> Self {
        f32x8::simd_gt(self, rhs)
    }
    #[inline(always)]
    fn simd_ge(self, rhs: Self) -> Self {
        f32x8::simd_ge(self, rhs)
    }
    #[inline(always)]
    fn blend(m: f32x8, if_true: Self, if_false: Self) -> Self {
        f32x8::select(m, if_true, if_false)
    }
    #[inline(always)]
    fn mask_from_bits(bits: u64) -> f32x8 {
        f32x8::new(core::array::from_fn(|l| if bits >> l & 1 == 1 { f32::from_bits(!0) } else { 0.0 }))
    }
    #[inline(always)]
    fn store(self, out: &mut [f32]) {
        out[..8].copy_from_slice(&f32x8::to_array(self));
    }
    #[inline(always)]
    fn trunc_int(self) -> i32x8 {
        f32x8::trunc_int(self)
    }
    #[inline(always)]
    fn int_to_float(i: i32x8) -> Self {
        i.round_float()
    }
    #[inline(always)]
    fn splat_i(x: i32) -> i32x8 {
        i32x8::splat(x)
    }
    #[inline(always)]
    fn mul_i(a: i32x8, b: i32x8) -> i32x8 {
        a * b
    }
    #[inline(always)]
    fn gather(data: &[f32], idx: i32x8) -> Self {
        let last = data.len().saturating_sub(1);
        let i = idx.to_array();
        f32x8::new(core::array::from_fn(|l| data.get((i[l].max(0) as usize).min(last)).copied().unwrap_or(0.0)))
    }
    #[inline(always)]
    fn gather_pairs(data: &[f32], idx: i32x8) -> (Self, Self) {
        if data.len() < 2 {
            return (f32x8::splat(0.0), f32x8::splat(0.0));
        }
        let last = data.len() - 2;
        let i = idx.to_array().map(|i| (i.max(0) as usize).min(last));
        (f32x8::new(core::array::from_fn(|l| data[i[l]])), f32x8::new(core::array::from_fn(|l| data[i[l] + 1])))
    }
    #[inline(always)]
    fn and_i(a: i32x8, b: i32x8) -> i32x8 {
        a & b
    }
    #[inline(always)]
    fn shr_i<const N: i32>(a: i32x8) -> i32x8 {
        i32x8::new(a.to_array().map(|v| (v as u32 >> N) as i32))
    }
    #[inline(always)]
    fn gather_byte_pairs(data: &[u8], idx: i32x8) -> (Self, Self) {
        if data.len() < 4 {
            return (f32x8::splat(0.0), f32x8::splat(0.0));
        }
        let last = data.len() - 4;
        let i = idx.to_array().map(|i| (i.max(0) as usize).min(last));
        // One 16-bit load per lane, split in lanes (as the AVX kinds split their 32-bit gather).
        let w = i32x8::new(i.map(|i| u16::from_le_bytes([data[i], data[i + 1]]) as i32));
        let m = i32x8::splat(255);
        ((w & m).round_float(), (w >> 8i32).round_float())
    }
    #[inline(always)]
    fn gather_byte_quads(data: &[u8], idx: i32x8) -> [Self; 4] {
        if data.len() < 4 {
            return [f32x8::splat(0.0); 4];
        }
        let last = data.len() - 4;
        let i = idx.to_array().map(|i| (i.max(0) as usize).min(last));
        let w = i32x8::new(i.map(|i| u32::from_le_bytes([data[i], data[i + 1], data[i + 2], data[i + 3]]) as i32));
        let m = i32x8::splat(255);
        [
            (w & m).round_float(),
            ((w >> 8i32) & m).round_float(),
            ((w >> 16i32) & m).round_float(),
            ((w >> 24i32) & m).round_float(),
        ]
    }
    #[inline(always)]
    fn gather_short_pairs(data: &[u16], idx: i32x8) -> (Self, Self) {
        if data.len() < 2 {
            return (f32x8::splat(0.0), f32x8::splat(0.0));
        }
        let last = data.len() - 2;
        let i = idx.to_array().map(|i| (i.max(0) as usize).min(last));
        (
            f32x8::new(core::array::from_fn(|l| data[i[l]] as f32)),
            f32x8::new(core::array::from_fn(|l| data[i[l] + 1] as f32)),
        )
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f32x8::sqrt(self)
    }
}

/// Twice the lanes of `L` as two halves (`X2<Avx2>`: sixteen lanes in two AVX registers per
/// value; `X2<X2<Avx2>>` thirty-two in four). Every operation is its halves' operation, so the
/// values are those of `L` lane for lane; the halves are independent chains of work, which a
/// core overlaps (the packet marcher's step is bound by the latency of its gathers and blends,
/// not by their throughput).
#[derive(Clone, Copy)]
pub(crate) struct X2<L>(L, L);

/// The `i32` lanes of [`X2`].
#[derive(Clone, Copy)]
pub(crate) struct X2I<I>(I, I);

impl<I: Add<Output = I>> Add for X2I<I> {
    type Output = X2I<I>;
    #[inline(always)]
    fn add(self, rhs: X2I<I>) -> X2I<I> {
        X2I(self.0 + rhs.0, self.1 + rhs.1)
    }
}

macro_rules! x2_binop {
    ($tr:ident, $f:ident) => {
        impl<L: $tr<Output = L>> $tr for X2<L> {
            type Output = X2<L>;
            #[inline(always)]
            fn $f(self, rhs: X2<L>) -> X2<L> {
                X2(self.0.$f(rhs.0), self.1.$f(rhs.1))
            }
        }
    };
}
x2_binop!(Add, add);
x2_binop!(Sub, sub);
x2_binop!(Mul, mul);
x2_binop!(Div, div);
x2_binop!(BitAnd, bitand);
x2_binop!(BitOr, bitor);

impl<M: Mask> Mask for X2<M> {
    const LANES: usize = 2 * M::LANES;
    #[inline(always)]
    fn to_bitmask(self) -> u64 {
        self.0.to_bitmask() | self.1.to_bitmask() << M::LANES
    }
    #[inline(always)]
    fn any(self) -> bool {
        (self.0 | self.1).any()
    }
    #[inline(always)]
    fn and_not(self, rhs: Self) -> Self {
        X2(self.0.and_not(rhs.0), self.1.and_not(rhs.1))
    }
}

impl<L: Lanes> Lanes for X2<L> {
    type I = X2I<L::I>;
    type M = X2<L::M>;
    const N: usize = 2 * L::N;

    #[inline(always)]
    fn splat(x: f32) -> Self {
        X2(L::splat(x), L::splat(x))
    }
    #[inline(always)]
    fn new(a: &[f32]) -> Self {
        X2(L::new(a), L::new(&a[L::N..]))
    }
    #[inline(always)]
    fn min(self, rhs: Self) -> Self {
        X2(self.0.min(rhs.0), self.1.min(rhs.1))
    }
    #[inline(always)]
    fn max(self, rhs: Self) -> Self {
        X2(self.0.max(rhs.0), self.1.max(rhs.1))
    }
    #[inline(always)]
    fn simd_lt(self, rhs: Self) -> Self::M {
        X2(self.0.simd_lt(rhs.0), self.1.simd_lt(rhs.1))
    }
    #[inline(always)]
    fn simd_gt(self, rhs: Self) -> Self::M {
        X2(self.0.simd_gt(rhs.0), self.1.simd_gt(rhs.1))
    }
    #[inline(always)]
    fn simd_ge(self, rhs: Self) -> Self::M {
        X2(self.0.simd_ge(rhs.0), self.1.simd_ge(rhs.1))
    }
    #[inline(always)]
    fn blend(m: Self::M, if_true: Self, if_false: Self) -> Self {
        X2(L::blend(m.0, if_true.0, if_false.0), L::blend(m.1, if_true.1, if_false.1))
    }
    #[inline(always)]
    fn mask_from_bits(bits: u64) -> Self::M {
        X2(L::mask_from_bits(bits), L::mask_from_bits(bits >> L::N))
    }
    #[inline(always)]
    fn store(self, out: &mut [f32]) {
        self.0.store(out);
        self.1.store(&mut out[L::N..]);
    }
    #[inline(always)]
    fn trunc_int(self) -> Self::I {
        X2I(self.0.trunc_int(), self.1.trunc_int())
    }
    #[inline(always)]
    fn int_to_float(i: Self::I) -> Self {
        X2(L::int_to_float(i.0), L::int_to_float(i.1))
    }
    #[inline(always)]
    fn splat_i(x: i32) -> Self::I {
        X2I(L::splat_i(x), L::splat_i(x))
    }
    #[inline(always)]
    fn mul_i(a: Self::I, b: Self::I) -> Self::I {
        X2I(L::mul_i(a.0, b.0), L::mul_i(a.1, b.1))
    }
    #[inline(always)]
    fn gather(data: &[f32], idx: Self::I) -> Self {
        X2(L::gather(data, idx.0), L::gather(data, idx.1))
    }
    #[inline(always)]
    fn gather_pairs(data: &[f32], idx: Self::I) -> (Self, Self) {
        let ((a0, b0), (a1, b1)) = (L::gather_pairs(data, idx.0), L::gather_pairs(data, idx.1));
        (X2(a0, a1), X2(b0, b1))
    }
    #[inline(always)]
    fn and_i(a: Self::I, b: Self::I) -> Self::I {
        X2I(L::and_i(a.0, b.0), L::and_i(a.1, b.1))
    }
    #[inline(always)]
    fn shr_i<const N: i32>(a: Self::I) -> Self::I {
        X2I(L::shr_i::<N>(a.0), L::shr_i::<N>(a.1))
    }
    #[inline(always)]
    fn gather_byte_pairs(data: &[u8], idx: Self::I) -> (Self, Self) {
        let ((a0, b0), (a1, b1)) = (L::gather_byte_pairs(data, idx.0), L::gather_byte_pairs(data, idx.1));
        (X2(a0, a1), X2(b0, b1))
    }
    #[inline(always)]
    fn gather_short_pairs(data: &[u16], idx: Self::I) -> (Self, Self) {
        let ((a0, b0), (a1, b1)) = (L::gather_short_pairs(data, idx.0), L::gather_short_pairs(data, idx.1));
        (X2(a0, a1), X2(b0, b1))
    }
    #[inline(always)]
    fn gather_byte_quads(data: &[u8], idx: Self::I) -> [Self; 4] {
        let ([a0, b0, c0, d0], [a1, b1, c1, d1]) =
            (L::gather_byte_quads(data, idx.0), L::gather_byte_quads(data, idx.1));
        [X2(a0, a1), X2(b0, b1), X2(c0, c1), X2(d0, d1)]
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        X2(self.0.sqrt(), self.1.sqrt())
    }
}

#[cfg(target_arch = "x86_64")]
pub(crate) use volwarp_lanes::{Avx2, Avx512};

/// The lanes of AVX2 and AVX-512 (x86-64): the base types of `volwarp_lanes` with the packet
/// marcher's operations.
///
/// `volwarp_lanes`' invariant (a value exists only where the CPU has the type's features)
/// holds for every value made here too: this crate calls the `Lanes` and `Mask` methods of
/// these types only inside the instances of [`dispatch!`] compiled for their features, which
/// run only where `volwarp_lanes::level()` gave the token (tests: a token's `detected()`).
#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::{Lanes, Mask};
    use core::arch::x86_64::*;
    use core::ops::{BitAnd, BitOr};
    use volwarp_lanes::{Avx2, Avx2I, Avx2Token, Avx512, Avx512I, Avx512Token};

    /// The `Lanes` methods that are the base type's own operations (the same at both widths);
    /// `$token()` gives the type's token.
    macro_rules! base_methods {
        ($t:ident, $ti:ident, $token:ident) => {
            #[inline(always)]
            fn splat(x: f32) -> Self {
                $t::splat($token(), x)
            }
            #[inline(always)]
            fn new(a: &[f32]) -> Self {
                $t::load($token(), a.first_chunk().expect("a whole vector"))
            }
            #[inline(always)]
            fn min(self, rhs: Self) -> Self {
                // `vminps(self, rhs)`: `self < rhs ? self : rhs`, as `wide`'s `fast_min`.
                self.fast_min(rhs)
            }
            #[inline(always)]
            fn max(self, rhs: Self) -> Self {
                self.fast_max(rhs)
            }
            #[inline(always)]
            fn store(self, out: &mut [f32]) {
                $t::store(self, out.first_chunk_mut().expect("a whole vector"))
            }
            #[inline(always)]
            fn trunc_int(self) -> $ti {
                // `vcvttps2dq`: truncation, exact for the documented range.
                $t::trunc_int(self)
            }
            #[inline(always)]
            fn int_to_float(i: $ti) -> Self {
                i.to_float()
            }
            #[inline(always)]
            fn splat_i(x: i32) -> $ti {
                $ti::splat($token(), x)
            }
            #[inline(always)]
            fn mul_i(a: $ti, b: $ti) -> $ti {
                a.mul_lo(b)
            }
            #[inline(always)]
            fn sqrt(self) -> Self {
                $t::sqrt(self)
            }
        };
    }

    /// `Lanes::and_i`, `shr_i`, `gather_byte_pairs` and `gather_short_pairs` with one width's
    /// intrinsics: the clamped indices (`$clamp`), one 32-bit gather at byte scale 1 or 2, each
    /// field by an `and` and a logical shift right, converted to `f32` exactly.
    macro_rules! int_methods {
        ($t:ident, $ti:ident, $token:ident, $clamp:ident:
         $and:ident $srli:ident $srl:ident $set1:ident $cvt:ident |$i:ident, $p:ident, $scale:ident| $gather:expr) => {
            #[inline(always)]
            fn and_i(a: $ti, b: $ti) -> $ti {
                // SAFETY: `a` proves the type's features (`volwarp_lanes`' invariant).
                unsafe { $ti::from_raw($and(a.raw(), b.raw())) }
            }
            #[inline(always)]
            fn shr_i<const N: i32>(a: $ti) -> $ti {
                // SAFETY: `a` proves the type's features (`volwarp_lanes`' invariant).
                unsafe { $ti::from_raw($srl(a.raw(), _mm_cvtsi32_si128(N))) }
            }
            #[inline(always)]
            fn gather_byte_pairs(data: &[u8], idx: $ti) -> (Self, Self) {
                if data.len() < 4 {
                    return ($t::splat($token(), 0.0), $t::splat($token(), 0.0));
                }
                let $i = $clamp(idx, last_index(data.len(), 4));
                let $p = data.as_ptr().cast::<i32>();
                // SAFETY: `idx` proves the features; every index is in 0 ..= len − 4 (just
                // above), so the 4 bytes read at byte offset `index` (scale 1; gathers need no
                // alignment) lie inside `data`.
                unsafe {
                    const $scale: i32 = 1;
                    let (w, m) = ($gather, $set1(255));
                    ($t::from_raw($cvt($and(w, m))), $t::from_raw($cvt($and($srli::<8>(w), m))))
                }
            }
            #[inline(always)]
            fn gather_byte_quads(data: &[u8], idx: $ti) -> [Self; 4] {
                if data.len() < 4 {
                    return [$t::splat($token(), 0.0); 4];
                }
                let $i = $clamp(idx, last_index(data.len(), 4));
                let $p = data.as_ptr().cast::<i32>();
                // SAFETY: as `gather_byte_pairs`: every index is in 0 ..= len − 4.
                unsafe {
                    const $scale: i32 = 1;
                    let (w, m) = ($gather, $set1(255));
                    [
                        $t::from_raw($cvt($and(w, m))),
                        $t::from_raw($cvt($and($srli::<8>(w), m))),
                        $t::from_raw($cvt($and($srli::<16>(w), m))),
                        $t::from_raw($cvt($srli::<24>(w))),
                    ]
                }
            }
            #[inline(always)]
            fn gather_short_pairs(data: &[u16], idx: $ti) -> (Self, Self) {
                if data.len() < 2 {
                    return ($t::splat($token(), 0.0), $t::splat($token(), 0.0));
                }
                let $i = $clamp(idx, last_index(data.len(), 2));
                let $p = data.as_ptr().cast::<i32>();
                // SAFETY: `idx` proves the features; every index is in 0 ..= len − 2 (just
                // above), so the 4 bytes read at byte offset 2·index lie inside `data`.
                unsafe {
                    const $scale: i32 = 2;
                    let (w, m) = ($gather, $set1(0xffff));
                    ($t::from_raw($cvt($and(w, m))), $t::from_raw($cvt($srli::<16>(w))))
                }
            }
        };
    }

    /// The AVX2 token inside the AVX2 lanes' methods.
    #[inline(always)]
    fn avx2() -> Avx2Token {
        // SAFETY: these methods run only where the CPU has AVX2 (the module's docs).
        unsafe { Avx2Token::new_unchecked() }
    }

    /// The AVX-512 token inside the AVX-512 lanes' methods.
    #[inline(always)]
    fn avx512() -> Avx512Token {
        // SAFETY: these methods run only where the CPU has AVX-512 F and DQ (the module's docs).
        unsafe { Avx512Token::new_unchecked() }
    }

    impl Mask for Avx2 {
        const LANES: usize = 8;
        #[inline(always)]
        fn to_bitmask(self) -> u64 {
            Avx2::to_bitmask(self) as u64
        }
        #[inline(always)]
        fn any(self) -> bool {
            Avx2::any(self)
        }
        #[inline(always)]
        fn and_not(self, rhs: Self) -> Self {
            Avx2::and_not(self, rhs)
        }
    }

    /// Every index of `idx` clamped to `0 ..= last` (signed max with 0, then min with `last`).
    #[inline(always)]
    fn clamp8(idx: Avx2I, last: i32) -> __m256i {
        // SAFETY: `idx` proves AVX2 (`volwarp_lanes`' invariant).
        unsafe { _mm256_min_epi32(_mm256_max_epi32(idx.raw(), _mm256_setzero_si256()), _mm256_set1_epi32(last)) }
    }

    /// The last index of a slice of `len` elements less `less` (lengths above `i32::MAX` are
    /// never passed: a chunk of bricks holds at most `bricks::CHUNK_LIMIT` values).
    #[inline(always)]
    fn last_index(len: usize, less: usize) -> i32 {
        (len - less).min(i32::MAX as usize) as i32
    }

    impl Lanes for Avx2 {
        type I = Avx2I;
        type M = Avx2;
        const N: usize = 8;

        base_methods!(Avx2, Avx2I, avx2);
        #[inline(always)]
        fn simd_lt(self, rhs: Self) -> Self {
            Avx2::simd_lt(self, rhs)
        }
        #[inline(always)]
        fn simd_gt(self, rhs: Self) -> Self {
            Avx2::simd_gt(self, rhs)
        }
        #[inline(always)]
        fn simd_ge(self, rhs: Self) -> Self {
            Avx2::simd_ge(self, rhs)
        }
        #[inline(always)]
        fn blend(m: Self, if_true: Self, if_false: Self) -> Self {
            Avx2::select(m, if_true, if_false)
        }
        #[inline(always)]
        fn mask_from_bits(bits: u64) -> Self {
            let a: [f32; 8] = core::array::from_fn(|l| if bits >> l & 1 == 1 { f32::from_bits(!0) } else { 0.0 });
            Avx2::load(avx2(), &a)
        }
        #[inline(always)]
        fn gather(data: &[f32], idx: Avx2I) -> Self {
            if data.is_empty() {
                return Avx2::splat(avx2(), 0.0);
            }
            let i = clamp8(idx, last_index(data.len(), 1));
            // SAFETY: `idx` proves AVX2; every index is in 0 ..= len − 1 (just above), scale 4
            // is `f32`'s size, so each gathered element lies inside `data`.
            unsafe { Avx2::from_raw(_mm256_i32gather_ps::<4>(data.as_ptr(), i)) }
        }
        #[inline(always)]
        fn gather_pairs(data: &[f32], idx: Avx2I) -> (Self, Self) {
            if data.len() < 2 {
                return (Avx2::splat(avx2(), 0.0), Avx2::splat(avx2(), 0.0));
            }
            let i = clamp8(idx, last_index(data.len(), 2));
            // SAFETY: `idx` proves AVX2; every index is in 0 ..= len − 2 (just above), so each
            // 8-byte element (two `f32`, read as one `f64` at byte offset 4·index; gathers need
            // no alignment) lies inside `data`.
            unsafe {
                let p = data.as_ptr().cast::<f64>();
                let lo = _mm256_castpd_ps(_mm256_i32gather_pd::<4>(p, _mm256_castsi256_si128(i)));
                let hi = _mm256_castpd_ps(_mm256_i32gather_pd::<4>(p, _mm256_extracti128_si256::<1>(i)));
                // lo = a0 b0 a1 b1 | a2 b2 a3 b3, hi = a4 b4 a5 b5 | a6 b6 a7 b7.
                let a = _mm256_shuffle_ps::<0b10_00_10_00>(lo, hi); // a0 a1 a4 a5 | a2 a3 a6 a7
                let b = _mm256_shuffle_ps::<0b11_01_11_01>(lo, hi); // b0 b1 b4 b5 | b2 b3 b6 b7
                let order = |v: __m256| _mm256_castpd_ps(_mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_castps_pd(v)));
                (Avx2::from_raw(order(a)), Avx2::from_raw(order(b)))
            }
        }
        int_methods!(Avx2, Avx2I, avx2, clamp8: _mm256_and_si256 _mm256_srli_epi32 _mm256_srl_epi32 _mm256_set1_epi32 _mm256_cvtepi32_ps
            |i, p, SCALE| _mm256_i32gather_epi32::<SCALE>(p, i));
    }

    /// A mask of sixteen lanes: an AVX-512 mask register (`k`), bit `l` lane `l`.
    #[derive(Clone, Copy)]
    pub(crate) struct K16(__mmask16);

    impl BitAnd for K16 {
        type Output = K16;
        #[inline(always)]
        fn bitand(self, rhs: K16) -> K16 {
            K16(self.0 & rhs.0)
        }
    }

    impl BitOr for K16 {
        type Output = K16;
        #[inline(always)]
        fn bitor(self, rhs: K16) -> K16 {
            K16(self.0 | rhs.0)
        }
    }

    impl Mask for K16 {
        const LANES: usize = 16;
        #[inline(always)]
        fn to_bitmask(self) -> u64 {
            self.0 as u64
        }
        #[inline(always)]
        fn any(self) -> bool {
            self.0 != 0
        }
        #[inline(always)]
        fn and_not(self, rhs: K16) -> K16 {
            K16(self.0 & !rhs.0)
        }
    }

    /// Every index of `idx` clamped to `0 ..= last` (as [`clamp8`]).
    #[inline(always)]
    fn clamp16(idx: Avx512I, last: i32) -> __m512i {
        // SAFETY: `idx` proves AVX-512 F (`volwarp_lanes`' invariant).
        unsafe { _mm512_min_epi32(_mm512_max_epi32(idx.raw(), _mm512_setzero_si512()), _mm512_set1_epi32(last)) }
    }

    /// The even and the odd 32-bit elements of `lo` then `hi` (eight 64-bit elements each).
    #[inline(always)]
    fn deinterleave(_: Avx512Token, lo: __m512i, hi: __m512i) -> (__m512i, __m512i) {
        // SAFETY: the token proves AVX-512 F.
        unsafe {
            let even = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
            let odd = _mm512_setr_epi32(1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31);
            (_mm512_permutex2var_epi32(lo, even, hi), _mm512_permutex2var_epi32(lo, odd, hi))
        }
    }

    impl Lanes for Avx512 {
        type I = Avx512I;
        type M = K16;
        const N: usize = 16;

        base_methods!(Avx512, Avx512I, avx512);
        #[inline(always)]
        fn simd_lt(self, rhs: Self) -> K16 {
            K16(self.cmp_mask::<_CMP_LT_OQ>(rhs))
        }
        #[inline(always)]
        fn simd_gt(self, rhs: Self) -> K16 {
            K16(self.cmp_mask::<_CMP_GT_OQ>(rhs))
        }
        #[inline(always)]
        fn simd_ge(self, rhs: Self) -> K16 {
            K16(self.cmp_mask::<_CMP_GE_OQ>(rhs))
        }
        #[inline(always)]
        fn blend(m: K16, if_true: Self, if_false: Self) -> Self {
            if_true.blend_mask(m.0, if_false)
        }
        #[inline(always)]
        fn mask_from_bits(bits: u64) -> K16 {
            K16(bits as u16)
        }
        #[inline(always)]
        fn gather(data: &[f32], idx: Avx512I) -> Self {
            if data.is_empty() {
                return Avx512::splat(avx512(), 0.0);
            }
            let i = clamp16(idx, last_index(data.len(), 1));
            // SAFETY: `idx` proves AVX-512 F; every index is in 0 ..= len − 1 (just above),
            // scale 4 is `f32`'s size.
            unsafe { Avx512::from_raw(_mm512_i32gather_ps::<4>(i, data.as_ptr())) }
        }
        #[inline(always)]
        fn gather_pairs(data: &[f32], idx: Avx512I) -> (Self, Self) {
            if data.len() < 2 {
                return (Avx512::splat(avx512(), 0.0), Avx512::splat(avx512(), 0.0));
            }
            let i = clamp16(idx, last_index(data.len(), 2));
            // SAFETY: `idx` proves AVX-512 F; every index is in 0 ..= len − 2 (just above), so
            // each 8-byte element (two `f32`, read as one `f64` at byte offset 4·index) lies
            // inside `data`.
            unsafe {
                let p = data.as_ptr().cast::<f64>();
                let lo = _mm512_castpd_si512(_mm512_i32gather_pd::<4>(_mm512_castsi512_si256(i), p));
                let hi = _mm512_castpd_si512(_mm512_i32gather_pd::<4>(_mm512_extracti64x4_epi64::<1>(i), p));
                // lo = a0 b0 … a7 b7, hi = a8 b8 … a15 b15: the even and the odd elements.
                let (a, b) = deinterleave(avx512(), lo, hi);
                (Avx512::from_raw(_mm512_castsi512_ps(a)), Avx512::from_raw(_mm512_castsi512_ps(b)))
            }
        }
        int_methods!(Avx512, Avx512I, avx512, clamp16: _mm512_and_si512 _mm512_srli_epi32 _mm512_srl_epi32 _mm512_set1_epi32 _mm512_cvtepi32_ps
            |i, p, SCALE| _mm512_i32gather_epi32::<SCALE>(i, p));
    }
}

#[cfg(test)]
#[cfg(target_arch = "x86_64")]
mod tests {
    use super::{Avx2, Avx512, Lanes, Mask, X2};

    /// The most lanes a tested type has.
    const MAX_LANES: usize = 64;
    use wide::f32x8;

    /// Every `Lanes` method of `A` against `W`'s (the same width), inlined into the caller.
    #[inline(always)]
    fn check_against<A: Lanes, W: Lanes>() {
        assert_eq!(A::N, W::N);
        let n = A::N;
        let vals = [0.0, -0.0, 1.0, -1.0, 0.5, 3.7, 1e-40, 1e7, f32::INFINITY, -f32::INFINITY, f32::NAN, 1023.5];
        let pairs: Vec<(f32, f32)> = vals.iter().flat_map(|&a| vals.iter().map(move |&b| (a, b))).collect();
        let data: Vec<f32> = (0..100).map(|i| i as f32 * 0.25).collect();
        for c in pairs.chunks_exact(n) {
            let a: [f32; MAX_LANES] = core::array::from_fn(|l| if l < n { c[l].0 } else { 0.0 });
            let b: [f32; MAX_LANES] = core::array::from_fn(|l| if l < n { c[l].1 } else { 0.0 });
            let (x, y) = (A::new(&a), A::new(&b));
            let (p, q) = (W::new(&a), W::new(&b));
            let eq = |what: &str, r: A, s: W| {
                let (r, s) = (r.to_array::<MAX_LANES>(), s.to_array::<MAX_LANES>());
                let ok = (0..n).all(|l| r[l].to_bits() == s[l].to_bits() || (r[l].is_nan() && s[l].is_nan()));
                assert!(ok, "{what}: {a:?} {b:?}: {r:?} {s:?}");
            };
            eq("new", x, p);
            eq("add", x + y, p + q);
            eq("sub", x - y, p - q);
            eq("mul", x * y, p * q);
            eq("div", x / y, p / q);
            eq("min", x.min(y), p.min(q));
            eq("max", x.max(y), p.max(q));
            let (lt, wlt) = (x.simd_lt(y), p.simd_lt(q));
            let (ge, wge) = (x.simd_ge(y), p.simd_ge(q));
            let lane_bits = if n == 64 { u64::MAX } else { (1u64 << n) - 1 };
            let expect = |f: &dyn Fn(f32, f32) -> bool| (0..n).fold(0u64, |m, l| m | u64::from(f(a[l], b[l])) << l);
            assert_eq!(lt.to_bitmask(), expect(&|u, v| u < v));
            assert_eq!(wlt.to_bitmask(), expect(&|u, v| u < v));
            assert_eq!(ge.to_bitmask(), wge.to_bitmask());
            assert_eq!(x.simd_gt(y).to_bitmask(), p.simd_gt(q).to_bitmask());
            assert_eq!((lt | ge).to_bitmask(), (wlt | wge).to_bitmask());
            assert_eq!((lt & ge).to_bitmask(), (wlt & wge).to_bitmask());
            assert_eq!(lt.and_not(ge).to_bitmask(), wlt.and_not(wge).to_bitmask());
            eq("select", lt.select(x, y), wlt.select(p, q));
            assert_eq!(lt.any(), wlt.any());
            for m in [0u64, 1, 0b1010_0110_0101, 1 << (n - 1), lane_bits, 0x5a5a_5a5a_5a5a_5a5a] {
                let m = m & lane_bits;
                assert_eq!(A::mask_from_bits(m).to_bitmask(), m);
                assert_eq!(W::mask_from_bits(m).to_bitmask(), m);
                assert_eq!(A::mask_from_bits(m).any(), m != 0);
            }
            // Truncation and gathers on the documented range (clamped like the kernel does).
            let (g, wg) = (x.max(A::splat(0.0)).min(A::splat(120.0)), p.max(W::splat(0.0)).min(W::splat(120.0)));
            let (ti, wti) = (g.trunc_int(), wg.trunc_int());
            eq("trunc", A::int_to_float(ti), W::int_to_float(wti));
            let k = A::mul_i(ti, A::splat_i(3)) + A::splat_i(-20);
            let wk = W::mul_i(wti, W::splat_i(3)) + W::splat_i(-20);
            eq("gather", A::gather(&data, k), W::gather(&data, wk));
            eq("gather empty", A::gather(&[], k), W::gather(&[], wk));
            let ((p0, p1), (w0, w1)) = (A::gather_pairs(&data, k), W::gather_pairs(&data, wk));
            eq("pairs 0", p0, w0);
            eq("pairs 1", p1, w1);
            let ((p0, _), (w0, _)) = (A::gather_pairs(&data[..1], k), W::gather_pairs(&data[..1], wk));
            eq("pairs short", p0, w0);
            let bytes: Vec<u8> = (0..100u32).map(|i| i.wrapping_mul(2_654_435_761) as u8).collect();
            for data in [&bytes[..], &bytes[..3], &[]] {
                let ((a0, a1), (w0, w1)) = (A::gather_byte_pairs(data, k), W::gather_byte_pairs(data, wk));
                eq("bytes 0", a0, w0);
                eq("bytes 1", a1, w1);
                let (aq, wq) = (A::gather_byte_quads(data, k), W::gather_byte_quads(data, wk));
                for (j, (a, w)) in aq.into_iter().zip(wq).enumerate() {
                    eq(["quad 0", "quad 1", "quad 2", "quad 3"][j], a, w);
                }
                eq("quad 0 is pair 0", aq[0], w0);
                eq("quad 1 is pair 1", aq[1], w1);
            }
            let shorts: Vec<u16> = (0..100u32).map(|i| i.wrapping_mul(2_654_435_761) as u16).collect();
            for data in [&shorts[..], &shorts[..1], &[]] {
                let ((a0, a1), (w0, w1)) = (A::gather_short_pairs(data, k), W::gather_short_pairs(data, wk));
                eq("shorts 0", a0, w0);
                eq("shorts 1", a1, w1);
            }
            let (s, ws) = (A::shr_i::<5>(ti), W::shr_i::<5>(wti));
            eq("shr", A::int_to_float(s), W::int_to_float(ws));
            let (m, wm) = (A::and_i(ti, A::splat_i(31)), W::and_i(wti, W::splat_i(31)));
            eq("and", A::int_to_float(m), W::int_to_float(wm));
            let t: [f32; MAX_LANES] = A::int_to_float(ti).to_array();
            let want: [f32; MAX_LANES] = core::array::from_fn(|l| ((t[l] as i32) >> 5) as f32);
            let got: [f32; MAX_LANES] = A::int_to_float(s).to_array();
            assert!((0..n).all(|l| got[l] == want[l]), "shr: {t:?} {got:?}");
        }
    }

    /// `Avx2`, `X2<Avx2>` and the kernel's thirty-two-lane `X2<X2<Avx2>>` against the portable lanes, inlined
    /// into an AVX2 function as the kernel is.
    #[target_feature(enable = "avx2")]
    fn check() {
        check_against::<Avx2, f32x8>();
        check_against::<X2<Avx2>, X2<f32x8>>();
        check_against::<X2<X2<Avx2>>, X2<X2<f32x8>>>();
    }

    #[test]
    fn avx2_lanes_equal_portable_lanes() {
        if volwarp_lanes::Avx2Token::detected().is_some() {
            // SAFETY: the token proves the CPU supports AVX2.
            unsafe { check() }
        }
    }

    /// `Avx512` and the kernel's thirty-two-lane `X2<Avx512>` against the portable lanes,
    /// inlined into a function compiled with AVX-512 F and DQ as the kernel is.
    #[target_feature(enable = "avx512f,avx512dq")]
    fn check512() {
        check_against::<Avx512, X2<f32x8>>();
        check_against::<X2<Avx512>, X2<X2<f32x8>>>();
        check_against::<X2<X2<Avx512>>, X2<X2<X2<f32x8>>>>();
    }

    #[test]
    fn avx512_lanes_equal_portable_lanes() {
        if volwarp_lanes::Avx512Token::detected().is_some() {
            // SAFETY: the token proves the CPU supports AVX-512 F and DQ.
            unsafe { check512() }
        } else {
            eprintln!("this CPU lacks AVX-512 F/DQ: the AVX-512 lanes are not tested here");
        }
    }
}
