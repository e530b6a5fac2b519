//! The eight-lane vector types the SIMD kernels (the packet tracer and the exact sphere
//! splatter) are generic over, and the two operations they share: primary ray directions and
//! the ray–sphere test, each exactly as core's scalar code computes them.
//!
//! `wide` chooses its `f32x8` representation when *it* is compiled (two SSE halves on baseline
//! x86-64), so enabling AVX2 on the calling function does not widen it. `Avx2` (x86-64 only,
//! `volwarp_lanes`' base type, which also gives the lane level and the dispatch macro) wraps
//! the 256-bit registers directly; once its `#[inline(always)]` methods are inlined into a
//! function compiled with AVX2 they are single ymm instructions. Every method has exactly the
//! semantics of the `wide` operation it replaces (noted per method), so both kernels compute
//! the same values: the same bits, except that a NaN's sign and payload are unspecified in Rust
//! and may differ, which only NaN-aware operations (comparisons, `min`/`max`) ever see.
//!
//! Masks are lanes with all bits set (true) or clear (false), as `wide`'s comparisons give.

use volwarp_core::sample::Dequantizer;
use volwarp_core::{RayBasis, Vec3};
use wide::{f32x8, u32x8};

/// Defines `$name`, which runs the kernel `$kernel::<L>` on the lanes
/// [`volwarp_lanes::level`] picks (with [`volwarp_lanes::dispatch!`]): the instance `$avx2`,
/// compiled with AVX2 on [`Avx2`] lanes, where the level is AVX2 or wider, and the portable
/// `wide::f32x8` instance elsewhere. With a third name, `fn name / avx2 / avx512 => kernel(…)`,
/// also the instance `$avx512`, compiled with AVX2, AVX-512 F and DQ on [`Avx512`] lanes
/// (sixteen), taken where the level is AVX-512 (for kernels generic over [`BoundLanes`]). All
/// compute the same values (see the module docs), so the choice only changes the speed.
macro_rules! dispatch {
    ($(#[$doc:meta])* $vis:vis fn $name:ident / $avx2:ident / $avx512:ident => $($kernel:tt)*) => {
        volwarp_lanes::dispatch! {
            $(#[$doc])*
            $vis fn $name / $avx2 / $avx512 => $($kernel)*;
            portable = [wide::f32x8], avx2 = [$crate::lanes::Avx2], avx512 = [$crate::lanes::Avx512]
        }
    };
    ($(#[$doc:meta])* $vis:vis fn $name:ident / $avx2:ident => $($kernel:tt)*) => {
        volwarp_lanes::dispatch! {
            $(#[$doc])*
            $vis fn $name / $avx2 => $($kernel)*;
            portable = [wide::f32x8], avx2 = [$crate::lanes::Avx2]
        }
    };
}
pub(crate) use dispatch;

/// Whether the kernels take their AVX2 instances: the lane level
/// ([`volwarp_lanes::lane_kind`]: the CPU's, clamped by `VOLWARP_LANES` and
/// [`volwarp_lanes::limit_lanes`]) is AVX2 or wider.
#[cfg(target_arch = "x86_64")]
pub(crate) fn use_avx2() -> bool {
    volwarp_lanes::Avx2Token::new().is_some()
}

/// Whether the kernels that have an AVX-512 instance (sixteen lanes: the tiled splatter's
/// bound pass) take it: the lane level is AVX-512 (`VOLWARP_LANES=avx2` times the AVX2
/// instances on a CPU with AVX-512).
#[cfg(target_arch = "x86_64")]
pub(crate) fn use_avx512() -> bool {
    volwarp_lanes::Avx512Token::new().is_some()
}

/// The lane kind the kernels take on this CPU (as `VOLWARP_LANES` names them): `avx512`
/// where the bound pass takes its AVX-512 instance, `avx2`, or `portable`.
pub fn lane_kind() -> &'static str {
    volwarp_lanes::lane_kind().name()
}

/// Asks the CPU to bring the cache lines of `s` closer (a hint: no effect on any result; on
/// x86-64 a `prefetcht0` per 64 bytes, nothing elsewhere).
#[inline(always)]
pub(crate) fn prefetch<T>(s: &[T]) {
    #[cfg(target_arch = "x86_64")]
    {
        let p = s.as_ptr().cast::<i8>();
        for off in (0..core::mem::size_of_val(s)).step_by(64) {
            // SAFETY: a prefetch reads nothing architecturally and cannot fault (SSE, which
            // every x86-64 CPU has); the address lies in `s`.
            unsafe { core::arch::x86_64::_mm_prefetch::<{ core::arch::x86_64::_MM_HINT_T0 }>(p.add(off)) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = s;
}

/// `RayBasis::dir` for eight pixels whose centres are `(px, py)` (pixel index + 0.5): the same
/// operations (`corner + du·px + dv·py`, then `d · (1 / sqrt(d·d))`), so the same unit
/// directions bit for bit.
#[inline(always)]
pub(crate) fn ray_dirs<L: Arith>(b: &RayBasis, px: L, py: L) -> [L; 3] {
    // No closure: one would be compiled without the caller's AVX2 target feature.
    let dx = L::splat(b.corner[0]) + L::splat(b.du[0]) * px + L::splat(b.dv[0]) * py;
    let dy = L::splat(b.corner[1]) + L::splat(b.du[1]) * px + L::splat(b.dv[1]) * py;
    let dz = L::splat(b.corner[2]) + L::splat(b.du[2]) * px + L::splat(b.dv[2]) * py;
    let inv_len = L::splat(1.0) / (dx * dx + dy * dy + dz * dz).sqrt();
    [dx * inv_len, dy * inv_len, dz * inv_len]
}

/// `sphere::intersect` of the sphere `(c, r)` for eight rays from `o` along unit `d`, for the
/// `active` lanes: the hit distances and the mask of lanes that hit, `None` if none does. The
/// same operations as core's scalar code, so the same `t` bit for bit.
#[inline(always)]
pub(crate) fn sphere_hits<L: Arith>(o: &[f32; 3], d: &[L; 3], c: Vec3, r: f32, active: L) -> Option<(L, L)> {
    let oc = [L::splat(c.x - o[0]), L::splat(c.y - o[1]), L::splat(c.z - o[2])];
    let (b, disc) = closest_approach(d, oc, L::splat(r));
    let ok = disc.simd_ge(L::splat(0.0)) & active;
    if !ok.any() {
        return None;
    }
    Some(nearest_hit(b, disc, ok))
}

/// [`sphere_hits`] for eight spheres at once, one per lane (centres less the rays' origin
/// and radii `c`), each on its own unit ray `d`, for the `active` lanes: the hit distance per
/// lane, NaN where the ray misses (or the lane is not active: no comparison takes a NaN, so a
/// miss never wins a depth test nor ties). The same operations per lane as [`sphere_hits`]
/// with the origin at zero (`c − 0` is `c`), so the same `t` bit for bit.
#[inline(always)]
pub(crate) fn sphere_hits_lanes<L: Arith>(d: &[L; 3], c: [L; 4], active: L) -> L {
    let [ox, oy, oz, r] = c;
    let (b, disc) = closest_approach(d, [ox, oy, oz], r);
    let (t, hit) = nearest_hit(b, disc, disc.simd_ge(L::splat(0.0)) & active);
    hit.select(t, L::splat(f32::NAN))
}

/// `sphere::intersect`'s first half: the distance `b` along the unit ray `d` to the point
/// nearest the centre (`oc`: centre less origin) and the discriminant `r² − |oc − b·d|²`.
#[inline(always)]
fn closest_approach<L: Arith>(d: &[L; 3], oc: [L; 3], r: L) -> (L, L) {
    let [ox, oy, oz] = oc;
    let b = ox * d[0] + oy * d[1] + oz * d[2];
    let fx = ox - b * d[0];
    let fy = oy - b * d[1];
    let fz = oz - b * d[2];
    (b, r * r - (fx * fx + fy * fy + fz * fz))
}

/// `sphere::intersect`'s second half for the lanes `ok` (discriminant at least zero): the
/// nearer root in front of the origin, else the farther, and the mask of lanes with a hit in
/// front.
#[inline(always)]
fn nearest_hit<L: Arith>(b: L, disc: L, ok: L) -> (L, L) {
    let zero = L::splat(0.0);
    let sq = disc.sqrt();
    let t0 = b - sq;
    let t1 = b + sq;
    let front = t0.simd_gt(zero);
    (front.select(t0, t1), ok & (front | t1.simd_gt(zero)))
}

/// The centres less `eye` and the radii of up to eight packed samples (lanes past `s` are
/// zero): `Dequantizer::center` and `radius` and one subtraction per axis, in scalar code.
#[inline(always)]
pub(crate) fn decode_scalar<L: Lanes>(deq: &Dequantizer, eye: [f32; 3], s: &[u64]) -> [L; 4] {
    let mut a = [[0f32; 16]; 4];
    decode_scalar_into(deq, eye, &s[..s.len().min(8)], &mut a);
    a.map(|v| L::new(first8(&v)))
}

/// The fields of packed samples as float lanes `[x, y, z, radius code]`, from the samples' low
/// and high 32-bit words `lo`, `hi` in integer lanes, with one width's intrinsics (no
/// closures: one would be compiled without the kernel's target features, every intrinsic a
/// call). The layout is `volwarp_core::sample`'s: x in bits 0–17, y in 18–35, z in 36–53, the
/// radius code in 54–63. Used inside `unsafe` blocks of the lanes' methods.
#[cfg(target_arch = "x86_64")]
macro_rules! sample_fields {
    ($t:ident, $lo:expr, $hi:expr; $and:ident $or:ident $srli:ident $slli:ident $set1:ident $cvt:ident) => {{
        let (lo, hi) = ($lo, $hi);
        let m = $set1(0x3ffff);
        let x = $and(lo, m);
        let y = $or($srli::<18>(lo), $slli::<14>($and(hi, $set1(0xf))));
        let z = $and($srli::<4>(hi), m);
        let r = $srli::<22>(hi);
        [$t::from_raw($cvt(x)), $t::from_raw($cvt(y)), $t::from_raw($cvt(z)), $t::from_raw($cvt(r))]
    }};
}

/// The centres less `eye` and the radii from the fields of packed samples as lanes
/// (`[x, y, z, radius code]`): `Dequantizer::center`'s and `radius`'s f32 operations in the
/// same order (`min + q·step`, `code·unit`), then one subtraction per axis.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn dequantize<L: Arith>(deq: &Dequantizer, eye: [f32; 3], q: [L; 4]) -> [L; 4] {
    let [fx, fy, fz, fr] = q;
    [
        (L::splat(deq.min.x) + fx * L::splat(deq.step.x)) - L::splat(eye[0]),
        (L::splat(deq.min.y) + fy * L::splat(deq.step.y)) - L::splat(eye[1]),
        (L::splat(deq.min.z) + fz * L::splat(deq.step.z)) - L::splat(eye[2]),
        fr * L::splat(deq.radius_unit),
    ]
}

/// [`decode_scalar`]'s values of up to sixteen samples into `out` (x, y, z, radius; entries
/// past `s` unchanged).
#[inline(always)]
pub(crate) fn decode_scalar_into(deq: &Dequantizer, eye: [f32; 3], s: &[u64], out: &mut [[f32; 16]; 4]) {
    for (l, &s) in s.iter().take(16).enumerate() {
        let c = deq.center(s);
        (out[0][l], out[1][l], out[2][l], out[3][l]) = (c.x - eye[0], c.y - eye[1], c.z - eye[2], deq.radius(s));
    }
}

/// The lane operations the shared kernels need whatever the lane count (eight for [`Lanes`],
/// sixteen for the AVX-512 bound pass): arithmetic, square root, comparisons (masks are lanes
/// with all bits set or clear), selects. Every implementation has exactly the semantics noted
/// per method, so a kernel generic over it computes the same values on every implementation.
pub(crate) trait Arith: volwarp_lanes::Ops {
    /// All lanes `x`.
    fn splat(x: f32) -> Self;
    /// IEEE square root per lane.
    fn sqrt(self) -> Self;
    /// `f32::max` per lane (a NaN operand gives the other one).
    fn max(self, rhs: Self) -> Self;
    /// `if self < rhs { self } else { rhs }` per lane (`minps`).
    fn fast_min(self, rhs: Self) -> Self;
    /// `if self > rhs { self } else { rhs }` per lane (`maxps`).
    fn fast_max(self, rhs: Self) -> Self;
    /// Mask of `self < rhs` (false if either is NaN); likewise the next four.
    fn simd_lt(self, rhs: Self) -> Self;
    /// Mask of `self <= rhs`.
    fn simd_le(self, rhs: Self) -> Self;
    /// Mask of `self > rhs`.
    fn simd_gt(self, rhs: Self) -> Self;
    /// Mask of `self >= rhs`.
    fn simd_ge(self, rhs: Self) -> Self;
    /// Mask of `self == rhs`.
    fn simd_eq(self, rhs: Self) -> Self;
    /// Per lane, `if_true` where the mask `self` is set, else `if_false`.
    fn select(self, if_true: Self, if_false: Self) -> Self;
    /// Bit `l` is lane `l`'s sign bit (for a mask: whether it is set).
    fn to_bitmask(self) -> u32;
    /// Whether any lane of the mask is set.
    fn any(self) -> bool;
}

/// [`Arith`] lanes for the tiled splatter's bound pass, `N` of them (8, or 16 with AVX-512):
/// the packed samples' decode, the integer pixel spans, and the lanes as arrays (their first
/// `N` entries).
pub(crate) trait BoundLanes: Arith {
    /// Lanes per value.
    const N: usize;
    /// [`decode_scalar`]'s values for up to `N` samples (lanes past `s`: zero).
    fn decode(deq: &Dequantizer, eye: [f32; 3], s: &[u64]) -> [Self; 4];
    /// [`Lanes::span_ints`] on `N` lanes.
    fn spans(lo: Self, hi: Self, max: u32) -> ([i32; 16], [i32; 16]);
    /// [`Lanes::from_ints`] on `N` lanes.
    fn from_ints16(a: &[i32; 16]) -> Self;
    /// The lanes, lane 0 first (entries past `N`: zero).
    fn lanes(self) -> [f32; 16];
    /// `c[0..4]`'s lanes as records: `out[l] = [c[0][l], c[1][l], c[2][l], c[3][l]]` for each
    /// `l < out.len()` (at most `N`).
    #[inline(always)]
    fn store_records(c: [Self; 4], out: &mut [[f32; 4]]) {
        store_records_scalar(c, out)
    }
    /// The rectangles of the lanes of `ok` (bit `l`: lane `l`) with the inclusive pixel spans
    /// `x0..=x1`, `y0..=y1` (`spans`: `[x0, x1, y0, y1]`; non-empty ones only), and what binning needs of them
    /// ([`RectLanes`]); tiles are `1 << tile_log2` pixels wide, and a rectangle over more
    /// than `max_tiles` of them is large.
    #[inline(always)]
    fn rects(ok: u32, spans: [&[i32; 16]; 4], tile_log2: u32, max_tiles: i32) -> RectLanes {
        rects_scalar::<Self>(ok, spans, tile_log2, max_tiles)
    }
}

/// [`BoundLanes::store_records`] lane by lane.
#[inline(always)]
pub(crate) fn store_records_scalar<L: BoundLanes>(c: [L; 4], out: &mut [[f32; 4]]) {
    let [a, b, x, r] = [c[0].lanes(), c[1].lanes(), c[2].lanes(), c[3].lanes()];
    for (l, o) in out.iter_mut().take(L::N).enumerate() {
        *o = [a[l], b[l], x[l], r[l]];
    }
}

/// [`BoundLanes::rects`] lane by lane (spans `[x0, x1, y0, y1]`).
#[inline(always)]
pub(crate) fn rects_scalar<L: BoundLanes>(
    ok: u32,
    spans: [&[i32; 16]; 4],
    tile_log2: u32,
    max_tiles: i32,
) -> RectLanes {
    let [x0, x1, y0, y1] = spans;
    let mut out = RectLanes { bits: [EMPTY_RECT; 16], large: 0, drawn: 0, union: EMPTY_RECT };
    let [mut ux0, mut uy0, mut ux1, mut uy1] = [0x7FFF, 0x7FFF, 0, 0];
    for l in 0..L::N {
        let (a, b, c, d) = (x0[l], x1[l], y0[l], y1[l]);
        if ok >> l & 1 == 0 || a > b || c > d {
            continue;
        }
        out.bits[l] = rect_word(a, c, b, d);
        let tiles = ((b >> tile_log2) - (a >> tile_log2) + 1) * ((d >> tile_log2) - (c >> tile_log2) + 1);
        if tiles > max_tiles {
            out.large |= 1 << l;
        } else {
            out.drawn |= 1 << l;
            (ux0, uy0, ux1, uy1) = (ux0.min(a), uy0.min(c), ux1.max(b), uy1.max(d));
        }
    }
    if out.drawn != 0 {
        out.union = rect_word(ux0, uy0, ux1, uy1);
    }
    out
}

/// The word of the rectangle `x0..=x1`, `y0..=y1` (each below 2¹⁵): `x0` in the low 16 bits,
/// then `y0`, `x1`, `y1`.
#[inline(always)]
fn rect_word(x0: i32, y0: i32, x1: i32, y1: i32) -> u64 {
    x0 as u64 | (y0 as u64) << 16 | (x1 as u64) << 32 | (y1 as u64) << 48
}

/// The empty rectangle's bits (`x0 = y0 = 0x7FFF`, `x1 = y1 = 0`: beyond every viewport, and
/// the identity of the union).
pub(crate) const EMPTY_RECT: u64 = 0x7FFF | 0x7FFF << 16;

/// A chunk's rectangles, as [`BoundLanes::rects`] gives them.
pub(crate) struct RectLanes {
    /// Per lane, `x0 | y0 << 16 | x1 << 32 | y1 << 48`; [`EMPTY_RECT`] where the lane is not
    /// in the mask or its span is empty.
    pub(crate) bits: [u64; 16],
    /// Lanes with a large rectangle.
    pub(crate) large: u32,
    /// Lanes with a rectangle that is not large.
    pub(crate) drawn: u32,
    /// The smallest rectangle holding the drawn ones ([`EMPTY_RECT`] if none).
    pub(crate) union: u64,
}

/// The operands of the lanes' tests: every pair of NaNs, signed zeros, infinities, subnormals
/// and ordinary values, `N` pairs at a time (as two arrays of lanes).
#[cfg(all(test, target_arch = "x86_64"))]
pub(crate) fn test_operands<const N: usize>() -> Vec<([f32; N], [f32; N])> {
    let vals = [0.0, -0.0, 1.0, -1.0, 0.5, 3.0, 1e-40, f32::MAX, f32::INFINITY, -f32::INFINITY, f32::NAN, -f32::NAN];
    let pairs: Vec<(f32, f32)> = vals.iter().flat_map(|&a| vals.iter().map(move |&b| (a, b))).collect();
    pairs.chunks_exact(N).map(|c| (core::array::from_fn(|l| c[l].0), core::array::from_fn(|l| c[l].1))).collect()
}

/// The dequantizer of the lanes' decode tests.
#[cfg(all(test, target_arch = "x86_64"))]
pub(crate) fn test_dequantizer() -> Dequantizer {
    use volwarp_core::sample::Bounds;
    Dequantizer::new(Bounds::new(Vec3::new(-1.5, 0.25, 3.0), Vec3::new(2.0, 7.0, 3.5)), 0.0123)
}

/// `N` packed samples for the lanes' decode tests, from the xorshift state `x`: every bit
/// pattern class (random, all ones, zero, no radius bits) by turns.
#[cfg(all(test, target_arch = "x86_64"))]
pub(crate) fn test_samples<const N: usize>(round: usize, x: &mut u64) -> [u64; N] {
    core::array::from_fn(|l| {
        *x ^= *x << 13;
        *x ^= *x >> 7;
        *x ^= *x << 17;
        match (round + l) % 4 {
            0 => *x,
            1 => u64::MAX,
            2 => 0,
            _ => *x & 0x0000_000f_ffff_ffff,
        }
    })
}

/// The first eight entries of `a`.
#[inline(always)]
fn first8<T: Copy>(a: &[T; 16]) -> [T; 8] {
    [a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7]]
}

/// `a` in the first eight of sixteen entries, the rest `z`.
#[inline(always)]
fn pad16<T: Copy>(a: [T; 8], z: T) -> [T; 16] {
    [a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], z, z, z, z, z, z, z, z]
}

impl<L: Lanes> BoundLanes for L {
    const N: usize = 8;
    #[inline(always)]
    fn decode(deq: &Dequantizer, eye: [f32; 3], s: &[u64]) -> [Self; 4] {
        // Eight at once in lanes where the CPU has them (`Lanes::decode8`: the same values).
        match s.first_chunk::<8>() {
            Some(eight) => L::decode8(deq, eye, eight),
            None => decode_scalar(deq, eye, s),
        }
    }
    #[inline(always)]
    fn spans(lo: Self, hi: Self, max: u32) -> ([i32; 16], [i32; 16]) {
        let (a, b) = L::span_ints(lo, hi, max);
        (pad16(a, 0), pad16(b, 0))
    }
    #[inline(always)]
    fn from_ints16(a: &[i32; 16]) -> Self {
        L::from_ints(&first8(a))
    }
    #[inline(always)]
    fn lanes(self) -> [f32; 16] {
        pad16(self.to_array(), 0.0)
    }
    #[inline(always)]
    fn store_records(c: [Self; 4], out: &mut [[f32; 4]]) {
        L::store_records8(c, out)
    }
    #[inline(always)]
    fn rects(ok: u32, spans: [&[i32; 16]; 4], tile_log2: u32, max_tiles: i32) -> RectLanes {
        L::rects8(ok, spans, tile_log2, max_tiles)
    }
}

/// Eight `f32` lanes (also used as masks) and their companion eight `u32` lanes.
pub(crate) trait Lanes: Arith {
    /// Eight `u32` lanes.
    type U: Copy;
    /// Whether these are the AVX2 lanes (whose kernels may call AVX-512 functions where the CPU
    /// has AVX-512).
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    const AVX2: bool = false;

    /// The lanes of `a`, lane 0 first.
    fn new(a: [f32; 8]) -> Self;
    /// `f32::floor` per lane.
    fn floor(self) -> Self;
    /// `f32::ceil` per lane.
    fn ceil(self) -> Self;
    /// `f32::min` per lane (a NaN operand gives the other one).
    fn min(self, rhs: Self) -> Self;
    /// Mask of the finite lanes.
    fn is_finite(self) -> Self;
    /// Whether all lanes of the mask are set.
    fn all(self) -> bool;
    /// All `u32` lanes `x`.
    fn splat_u(x: u32) -> Self::U;
    /// Mask of `a < b` (unsigned).
    fn lt_u(a: Self::U, b: Self::U) -> Self;
    /// Per lane, `if_true` where the mask `self` is set, else `if_false`.
    fn select_u(self, if_true: Self::U, if_false: Self::U) -> Self::U;
    /// The `u32` lanes, lane 0 first.
    fn u_to_array(u: Self::U) -> [u32; 8];
    /// `u32` lanes from `a`, lane 0 first.
    fn new_u(a: [u32; 8]) -> Self::U;
    /// The lanes, lane 0 first.
    fn to_array(self) -> [f32; 8];
    /// Lane `l` of the result is lane `idx[l] & 7` of `self` (`vpermps`; only the splatter in
    /// the samples' own order, feature `direct-splat`, uses the permutes).
    #[cfg(any(test, feature = "direct-splat"))]
    fn permute(self, idx: Self::U) -> Self;
    /// Lane `l` of the result is lane `idx[l] & 7` of `a` (`vpermd`).
    #[cfg(any(test, feature = "direct-splat"))]
    fn permute_u(a: Self::U, idx: Self::U) -> Self::U;
    /// [`decode_scalar`] of eight samples (the same values; AVX2 unpacks the eight in lanes).
    #[inline(always)]
    fn decode8(deq: &Dequantizer, eye: [f32; 3], s: &[u64; 8]) -> [Self; 4] {
        decode_scalar(deq, eye, s)
    }
    /// Per lane, `⌈lo⌉` at least 0 and `⌊hi⌋` at most `max`, as integers, for lanes with
    /// `−1 ≤ lo < 2³¹` and `0 ≤ hi < 2³¹` (other lanes: unspecified values): the scalar
    /// `ceil_clamped(lo)` (truncation, plus one where it fell below) and `(hi as u32).min(max)`.
    /// The integers `a` as `f32` lanes (`as f32`, rounding to nearest).
    #[inline(always)]
    fn from_ints(a: &[i32; 8]) -> Self {
        Self::new([
            a[0] as f32,
            a[1] as f32,
            a[2] as f32,
            a[3] as f32,
            a[4] as f32,
            a[5] as f32,
            a[6] as f32,
            a[7] as f32,
        ])
    }
    #[inline(always)]
    fn span_ints(lo: Self, hi: Self, max: u32) -> ([i32; 8], [i32; 8]) {
        let (lo, hi) = (lo.to_array(), hi.to_array());
        let c = lo.map(|a| {
            let l = a as i32;
            (if (l as f32) < a { l + 1 } else { l }).max(0)
        });
        (c, hi.map(|b| (b as u32).min(max) as i32))
    }
    /// [`BoundLanes::store_records`] of eight lanes (AVX2: a 4×8 transpose in registers).
    #[inline(always)]
    fn store_records8(c: [Self; 4], out: &mut [[f32; 4]]) {
        store_records_scalar(c, out)
    }
    /// [`BoundLanes::rects`] of eight lanes (spans `[x0, x1, y0, y1]`; AVX2: in lanes).
    #[inline(always)]
    fn rects8(ok: u32, spans: [&[i32; 16]; 4], tile_log2: u32, max_tiles: i32) -> RectLanes {
        rects_scalar::<Self>(ok, spans, tile_log2, max_tiles)
    }
}

/// [`Arith`] on lane types whose own methods of the same names have its semantics: `wide`'s
/// `f32x8` (the portable lanes, whatever `wide` was compiled for) and the base types of
/// `volwarp_lanes` (whose `splat` takes their token, `$token()`).
macro_rules! arith_by_methods {
    ($($t:ident $(($token:ident))?),*) => {$(
        impl Arith for $t {
            #[inline(always)]
            fn splat(x: f32) -> Self {
                $t::splat($($token(),)? x)
            }
            by_methods!($t: unary sqrt; binary max fast_min fast_max simd_lt simd_le simd_gt simd_ge simd_eq);
            #[inline(always)]
            fn select(self, if_true: Self, if_false: Self) -> Self {
                $t::select(self, if_true, if_false)
            }
            #[inline(always)]
            fn to_bitmask(self) -> u32 {
                $t::to_bitmask(self)
            }
            #[inline(always)]
            fn any(self) -> bool {
                $t::any(self)
            }
        }
    )*};
}

/// Trait methods that are the type's own methods of the same names: `unary` ones taking
/// `self`, `binary` ones `self` and `rhs`.
macro_rules! by_methods {
    ($t:ident: unary $($u:ident)*; binary $($b:ident)*) => {
        $(
            #[inline(always)]
            fn $u(self) -> Self {
                $t::$u(self)
            }
        )*
        $(
            #[inline(always)]
            fn $b(self, rhs: Self) -> Self {
                $t::$b(self, rhs)
            }
        )*
    };
}
arith_by_methods!(f32x8);
#[cfg(target_arch = "x86_64")]
arith_by_methods!(Avx2(avx2), Avx512(avx512));

impl Lanes for f32x8 {
    type U = u32x8;
    #[inline(always)]
    fn new(a: [f32; 8]) -> Self {
        f32x8::new(a)
    }
    by_methods!(f32x8: unary floor ceil is_finite; binary min);
    #[inline(always)]
    fn all(self) -> bool {
        f32x8::all(self)
    }
    #[inline(always)]
    fn splat_u(x: u32) -> u32x8 {
        u32x8::splat(x)
    }
    #[inline(always)]
    fn lt_u(a: u32x8, b: u32x8) -> Self {
        bytemuck::cast(u32x8::simd_lt(a, b))
    }
    #[inline(always)]
    fn select_u(self, if_true: u32x8, if_false: u32x8) -> u32x8 {
        bytemuck::cast::<f32x8, u32x8>(self).select(if_true, if_false)
    }
    #[inline(always)]
    fn new_u(a: [u32; 8]) -> u32x8 {
        u32x8::new(a)
    }
    #[inline(always)]
    fn u_to_array(u: u32x8) -> [u32; 8] {
        u.to_array()
    }
    #[inline(always)]
    fn to_array(self) -> [f32; 8] {
        f32x8::to_array(self)
    }
    #[cfg(any(test, feature = "direct-splat"))]
    #[inline(always)]
    fn permute(self, idx: u32x8) -> Self {
        let (a, i) = (f32x8::to_array(self), idx.to_array());
        f32x8::new(core::array::from_fn(|l| a[(i[l] & 7) as usize]))
    }
    #[cfg(any(test, feature = "direct-splat"))]
    #[inline(always)]
    fn permute_u(a: u32x8, idx: u32x8) -> u32x8 {
        let (a, i) = (a.to_array(), idx.to_array());
        u32x8::new(core::array::from_fn(|l| a[(i[l] & 7) as usize]))
    }
}

#[cfg(target_arch = "x86_64")]
pub(crate) use volwarp_lanes::{Avx2, Avx512};

/// The AVX2 token inside the AVX2 lanes' methods and kernels.
///
/// `volwarp_lanes`' invariant (a value of its lane types exists only where the CPU has their
/// features) holds for every value made in this crate too: the `Arith`, `Lanes` and
/// `BoundLanes` methods of [`Avx2`] and [`Avx512`] run only inside the instances of
/// [`dispatch!`] compiled for their features, which run only where `volwarp_lanes::level()`
/// gave the token (tests: a token's `detected()`).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn avx2() -> volwarp_lanes::Avx2Token {
    // SAFETY: called only where the CPU has AVX2 (see above).
    unsafe { volwarp_lanes::Avx2Token::new_unchecked() }
}

/// The AVX-512 token inside the AVX-512 lanes' methods (see [`avx2`]).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn avx512() -> volwarp_lanes::Avx512Token {
    // SAFETY: called only where the CPU has AVX2, AVX-512 F and DQ (see [`avx2`]).
    unsafe { volwarp_lanes::Avx512Token::new_unchecked() }
}

#[cfg(target_arch = "x86_64")]
mod avx512;

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{avx2, Avx2, Lanes, RectLanes};
    use core::arch::x86_64::*;
    use volwarp_core::sample::{Dequantizer, POS_BITS, RADIUS_BITS};
    use volwarp_lanes::Avx2I;

    // SAFETY (every `unsafe` block of this impl): AVX2 is available (`volwarp_lanes`'
    // invariant: a value proves it, and the methods without one run only in the AVX2
    // instances); the loads and stores are of the sizes noted there.
    impl Lanes for Avx2 {
        type U = __m256i;
        const AVX2: bool = true;

        #[inline(always)]
        fn new(a: [f32; 8]) -> Self {
            Avx2::load(avx2(), &a)
        }
        #[inline(always)]
        fn floor(self) -> Self {
            // `vroundps` toward −∞, as `wide`'s AVX path and `f32::floor`.
            // SAFETY: AVX2 is available (`volwarp_lanes`' invariant, see [`super::avx2`]).
            unsafe { Avx2::from_raw(_mm256_floor_ps(self.raw())) }
        }
        #[inline(always)]
        fn ceil(self) -> Self {
            // `vroundps` toward +∞, as `wide`'s AVX path and `f32::ceil`.
            // SAFETY: AVX2 is available (`volwarp_lanes`' invariant, see [`super::avx2`]).
            unsafe { Avx2::from_raw(_mm256_ceil_ps(self.raw())) }
        }
        #[inline(always)]
        fn min(self, rhs: Self) -> Self {
            // `wide`: `rhs.is_nan().select(self, self.fast_min(rhs))`.
            Avx2::min(self, rhs)
        }
        #[inline(always)]
        fn is_finite(self) -> Self {
            // |x| < ∞: false for ±∞ and NaN, as `wide`'s exponent test.
            let abs = self.and_not(Avx2::splat(avx2(), -0.0));
            abs.simd_lt(Avx2::splat(avx2(), f32::INFINITY))
        }
        #[inline(always)]
        fn all(self) -> bool {
            self.to_bitmask() == 0xff
        }
        #[inline(always)]
        fn splat_u(x: u32) -> __m256i {
            // SAFETY: AVX2 is available (`volwarp_lanes`' invariant, see [`super::avx2`]).
            unsafe { _mm256_set1_epi32(x as i32) }
        }
        #[inline(always)]
        fn lt_u(a: __m256i, b: __m256i) -> Self {
            // Unsigned `a < b` is signed `b > a` with the top bits flipped (`wide` does the same).
            // SAFETY: AVX2 is available (`volwarp_lanes`' invariant, see [`super::avx2`]).
            unsafe {
                let h = _mm256_set1_epi32(i32::MIN);
                Avx2::from_raw(_mm256_castsi256_ps(_mm256_cmpgt_epi32(_mm256_xor_si256(b, h), _mm256_xor_si256(a, h))))
            }
        }
        #[inline(always)]
        fn select_u(self, if_true: __m256i, if_false: __m256i) -> __m256i {
            // SAFETY: AVX2 is available (`volwarp_lanes`' invariant, see [`super::avx2`]).
            unsafe {
                let (t, f) = (_mm256_castsi256_ps(if_true), _mm256_castsi256_ps(if_false));
                _mm256_castps_si256(_mm256_blendv_ps(f, t, self.raw()))
            }
        }
        #[inline(always)]
        fn new_u(a: [u32; 8]) -> __m256i {
            // `a` is 32 readable bytes; the load needs no alignment.
            // SAFETY: AVX2 is available (`volwarp_lanes`' invariant, see [`super::avx2`]); `a` is 32 readable bytes.
            unsafe { _mm256_loadu_si256(a.as_ptr().cast()) }
        }
        #[inline(always)]
        fn u_to_array(u: __m256i) -> [u32; 8] {
            let mut a = [0u32; 8];
            // `a` is 32 writable bytes; the store needs no alignment.
            // SAFETY: AVX2 is available (`volwarp_lanes`' invariant, see [`super::avx2`]); `a` is 32 writable bytes.
            unsafe { _mm256_storeu_si256(a.as_mut_ptr().cast(), u) };
            a
        }
        #[inline(always)]
        fn to_array(self) -> [f32; 8] {
            Avx2::to_array(self)
        }
        #[cfg(any(test, feature = "direct-splat"))]
        #[inline(always)]
        fn permute(self, idx: __m256i) -> Self {
            // `vpermps` reads the low three bits of each index.
            // SAFETY: AVX2 is available (`volwarp_lanes`' invariant, see [`super::avx2`]).
            unsafe { Avx2::from_raw(_mm256_permutevar8x32_ps(self.raw(), idx)) }
        }
        #[cfg(any(test, feature = "direct-splat"))]
        #[inline(always)]
        fn permute_u(a: __m256i, idx: __m256i) -> __m256i {
            // SAFETY: AVX2 is available (`volwarp_lanes`' invariant, see [`super::avx2`]).
            unsafe { _mm256_permutevar8x32_epi32(a, idx) }
        }
        /// Eight records by a 4×8 transpose in registers (four 32-byte stores); fewer by the
        /// lanes one at a time.
        #[inline(always)]
        fn store_records8(c: [Self; 4], out: &mut [[f32; 4]]) {
            let Some(out) = out.first_chunk_mut::<8>() else {
                return super::store_records_scalar(c, out);
            };
            // SAFETY: AVX2 is available (`volwarp_lanes`' invariant, see [`super::avx2`]); the stores write the 128 bytes of `out` (noted below).
            unsafe {
                // Records l and l + 4 in the halves of u_l.
                let [u0, u1, u2, u3] = Avx2::transpose_blocks(c);
                let (u0, u1, u2, u3) = (u0.raw(), u1.raw(), u2.raw(), u3.raw());
                // `out` is eight records of 16 bytes: four 32-byte stores.
                let p = out.as_mut_ptr().cast::<f32>();
                _mm256_storeu_ps(p, _mm256_permute2f128_ps::<0x20>(u0, u1));
                _mm256_storeu_ps(p.add(8), _mm256_permute2f128_ps::<0x20>(u2, u3));
                _mm256_storeu_ps(p.add(16), _mm256_permute2f128_ps::<0x31>(u0, u1));
                _mm256_storeu_ps(p.add(24), _mm256_permute2f128_ps::<0x31>(u2, u3));
            }
        }

        /// `rects_scalar`'s rules on eight lanes at once: the fields packed in pairs of 16 bits
        /// and interleaved to 64-bit words, the tile counts by shifts and a 32-bit product,
        /// the union as the minimum of packed 16-bit fields (`0x7FFF − x1`, `0x7FFF − y1` for
        /// the maxima; every field is below 2¹⁵, so no field borrows from the next).
        #[inline(always)]
        fn rects8(ok: u32, spans: [&[i32; 16]; 4], tile_log2: u32, max_tiles: i32) -> RectLanes {
            // SAFETY: AVX2 is available (`volwarp_lanes`' invariant, see [`super::avx2`]); the loads read the 64 bytes of the spans, the stores write `bits` (noted below).
            unsafe {
                let load = |v: &[i32; 16]| _mm256_loadu_si256(v.as_ptr().cast());
                let (a, b, c, d) = (load(spans[0]), load(spans[1]), load(spans[2]), load(spans[3]));
                let bit = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
                let okv = _mm256_cmpeq_epi32(_mm256_and_si256(_mm256_set1_epi32(ok as i32), bit), bit);
                let empty = _mm256_or_si256(_mm256_cmpgt_epi32(a, b), _mm256_cmpgt_epi32(c, d));
                let fast = _mm256_andnot_si256(empty, okv);
                let s = _mm_cvtsi32_si128(tile_log2 as i32);
                let one = _mm256_set1_epi32(1);
                let tx = _mm256_add_epi32(_mm256_sub_epi32(_mm256_sra_epi32(b, s), _mm256_sra_epi32(a, s)), one);
                let ty = _mm256_add_epi32(_mm256_sub_epi32(_mm256_sra_epi32(d, s), _mm256_sra_epi32(c, s)), one);
                let over = _mm256_cmpgt_epi32(_mm256_mullo_epi32(tx, ty), _mm256_set1_epi32(max_tiles));
                let large = _mm256_and_si256(fast, over);
                let drawn = _mm256_andnot_si256(over, fast);
                let top = _mm256_set1_epi32(0x7FFF_7FFF);
                let lo = _mm256_or_si256(a, _mm256_slli_epi32::<16>(c));
                let hi = _mm256_or_si256(b, _mm256_slli_epi32::<16>(d));
                let lo_f = _mm256_blendv_epi8(_mm256_set1_epi32(super::EMPTY_RECT as i32), lo, fast);
                let hi_f = _mm256_and_si256(hi, fast);
                let (p0, p1) = (_mm256_unpacklo_epi32(lo_f, hi_f), _mm256_unpackhi_epi32(lo_f, hi_f));
                let mut bits = [super::EMPTY_RECT; 16];
                // `bits` is 128 writable bytes: two 32-byte stores into its first 64.
                _mm256_storeu_si256(bits.as_mut_ptr().cast(), _mm256_permute2x128_si256::<0x20>(p0, p1));
                _mm256_storeu_si256(bits[4..].as_mut_ptr().cast(), _mm256_permute2x128_si256::<0x31>(p0, p1));
                let mins = _mm256_blendv_epi8(top, lo, drawn);
                let maxs = _mm256_blendv_epi8(top, _mm256_sub_epi32(top, hi), drawn);
                let w = _mm256_min_epu16(
                    _mm256_permute2x128_si256::<0x20>(mins, maxs),
                    _mm256_permute2x128_si256::<0x31>(mins, maxs),
                );
                let w = _mm256_min_epu16(w, _mm256_shuffle_epi32::<0b01_00_11_10>(w));
                let w = _mm256_min_epu16(w, _mm256_shuffle_epi32::<0b10_11_00_01>(w));
                let low = _mm256_cvtsi256_si32(w) as u32 as u64;
                let high = 0x7FFF_7FFF - _mm256_extract_epi32::<4>(w) as u32 as u64;
                let mask = |m: __m256i| _mm256_movemask_ps(_mm256_castsi256_ps(m)) as u32;
                let drawn = mask(drawn);
                let union = if drawn == 0 { super::EMPTY_RECT } else { low | high << 32 };
                RectLanes { bits, large: mask(large), drawn, union }
            }
        }

        #[inline(always)]
        fn from_ints(a: &[i32; 8]) -> Self {
            // `a` is 32 readable bytes; `vcvtdq2ps` rounds to nearest as `as f32` does.
            // SAFETY: AVX2 is available (`volwarp_lanes`' invariant, see [`super::avx2`]); `a` is 32 readable bytes.
            unsafe { Avx2::from_raw(_mm256_cvtepi32_ps(_mm256_loadu_si256(a.as_ptr().cast()))) }
        }
        #[inline(always)]
        fn span_ints(lo: Self, hi: Self, max: u32) -> ([i32; 8], [i32; 8]) {
            // `vcvttps2dq` truncates as `as i32` does in range; the comparison and the
            // integer max/min are the scalar ones per lane.
            // SAFETY: AVX2 is available (`volwarp_lanes`' invariant, see [`super::avx2`]).
            unsafe {
                let t = _mm256_cvttps_epi32(lo.raw());
                let below = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_cvtepi32_ps(t), lo.raw()));
                let c = _mm256_max_epi32(_mm256_sub_epi32(t, below), _mm256_setzero_si256());
                let h = _mm256_min_epi32(_mm256_cvttps_epi32(hi.raw()), _mm256_set1_epi32(max as i32));
                (Avx2I::from_raw(c).to_array(), Avx2I::from_raw(h).to_array())
            }
        }
        /// The sample layout (`volwarp_core::sample`): x in bits 0–17, y in 18–35, z in
        /// 36–53, the radius code in 54–63; split into the low and high 32 bits of the eight
        /// samples, then the fields by 32-bit shifts, then `Dequantizer::center`'s and
        /// `radius`'s f32 operations in the same order (`min + q·step`, `code·unit`).
        #[inline(always)]
        fn decode8(deq: &Dequantizer, eye: [f32; 3], s: &[u64; 8]) -> [Self; 4] {
            const _: () = assert!(POS_BITS == 18 && RADIUS_BITS == 10);
            // SAFETY: AVX2 is available (`volwarp_lanes`' invariant, see [`super::avx2`]); `s` is
            // 64 readable bytes; the loads need no alignment.
            unsafe {
                let a = _mm256_loadu_si256(s.as_ptr().cast());
                let b = _mm256_loadu_si256(s[4..].as_ptr().cast());
                let idx = _mm256_setr_epi32(0, 2, 4, 6, 1, 3, 5, 7);
                let (pa, pb) = (_mm256_permutevar8x32_epi32(a, idx), _mm256_permutevar8x32_epi32(b, idx));
                let lo = _mm256_permute2x128_si256::<0x20>(pa, pb);
                let hi = _mm256_permute2x128_si256::<0x31>(pa, pb);
                let fields = sample_fields!(Avx2, lo, hi; _mm256_and_si256 _mm256_or_si256 _mm256_srli_epi32
                    _mm256_slli_epi32 _mm256_set1_epi32 _mm256_cvtepi32_ps);
                super::dequantize(deq, eye, fields)
            }
        }
    }

    #[cfg(test)]
    mod tests {
        use crate::lanes::decode_scalar;
        use crate::lanes::{Arith, Avx2, Lanes};
        use core::arch::x86_64::{__m256, __m256i};
        use wide::{f32x8, u32x8};

        fn bits(x: Avx2) -> [u32; 8] {
            // SAFETY: `__m256` is 32 bytes of plain data, as is `[u32; 8]`.
            unsafe { core::mem::transmute::<__m256, [u32; 8]>(x.raw()) }
        }

        fn wbits(x: f32x8) -> [u32; 8] {
            bytemuck::cast(x)
        }

        /// Every `Lanes` method of `Avx2` against `wide`'s on NaNs, signed zeros, infinities,
        /// subnormals and ordinary values, compiled as the kernel is (inlined into an AVX2
        /// function).
        #[target_feature(enable = "avx2")]
        fn check() {
            for (a, b) in crate::lanes::test_operands::<8>() {
                let (x, y) = (<Avx2 as Lanes>::new(a), <Avx2 as Lanes>::new(b));
                let (p, q) = (f32x8::new(a), f32x8::new(b));
                let eq = |what: &str, r: Avx2, s: f32x8| assert_eq!(bits(r), wbits(s), "{what}: {a:?} {b:?}");
                // Arithmetic: the same values; a NaN's sign and payload are unspecified in Rust
                // (LLVM may commute an addition), and only ever reach NaN-aware operations.
                let same = |what: &str, r: Avx2, s: f32x8| {
                    let (r, s) = (bits(r).map(f32::from_bits), wbits(s).map(f32::from_bits));
                    let ok = (0..8).all(|l| r[l].to_bits() == s[l].to_bits() || (r[l].is_nan() && s[l].is_nan()));
                    assert!(ok, "{what}: {a:?} {b:?}: {r:?} {s:?}");
                };
                eq("new", x, p);
                eq("splat", <Avx2 as Arith>::splat(a[3]), <f32x8 as Arith>::splat(a[3]));
                same("add", x + y, p + q);
                same("sub", x - y, p - q);
                same("mul", x * y, p * q);
                same("div", x / y, p / q);
                same("sqrt", x.sqrt(), Arith::sqrt(p));
                eq("min", Lanes::min(x, y), Lanes::min(p, q));
                eq("max", Arith::max(x, y), Arith::max(p, q));
                eq("fast_min", x.fast_min(y), Arith::fast_min(p, q));
                eq("fast_max", x.fast_max(y), Arith::fast_max(p, q));
                let (lt, wlt) = (x.simd_lt(y), Arith::simd_lt(p, q));
                let (ge, wge) = (x.simd_ge(y), Arith::simd_ge(p, q));
                eq("lt", lt, wlt);
                eq("le", x.simd_le(y), Arith::simd_le(p, q));
                eq("gt", x.simd_gt(y), Arith::simd_gt(p, q));
                eq("ge", ge, wge);
                eq("eq", x.simd_eq(y), Arith::simd_eq(p, q));
                eq("is_finite", x.is_finite(), Lanes::is_finite(p));
                eq("and", lt & ge, wlt & wge);
                eq("or", lt | ge, wlt | wge);
                eq("select", lt.select(x, y), Arith::select(wlt, p, q));
                assert_eq!(lt.to_bitmask(), Arith::to_bitmask(wlt));
                assert_eq!(x.to_bitmask(), Arith::to_bitmask(p));
                for m in [lt, ge, lt & ge, lt | ge] {
                    let w = f32x8::new(bytemuck::cast(bits(m)));
                    assert_eq!(m.any(), Arith::any(w));
                    assert_eq!(m.all(), Lanes::all(w));
                }
            }
            let us = [0, 1, 2, 0x7fff_ffff, 0x8000_0000, 0x8000_0001, u32::MAX - 1, u32::MAX];
            // SAFETY: both are 32 bytes of plain data.
            let v = unsafe { core::mem::transmute::<[u32; 8], __m256i>(us) };
            let wv = u32x8::new(us);
            for &s in &us {
                let (u, wu) = (Avx2::splat_u(s), <f32x8 as Lanes>::splat_u(s));
                for (m, wm) in [
                    (Avx2::lt_u(u, v), <f32x8 as Lanes>::lt_u(wu, wv)),
                    (Avx2::lt_u(v, u), <f32x8 as Lanes>::lt_u(wv, wu)),
                ] {
                    assert_eq!(bits(m), wbits(wm), "lt_u {s}");
                    assert_eq!(Avx2::u_to_array(m.select_u(u, v)), wm.select_u(wu, wv).to_array());
                }
                assert_eq!(Avx2::u_to_array(u), wu.to_array());
            }
            // decode8: the lanes' unpacking against the scalar decode, every bit pattern class.
            let deq = crate::lanes::test_dequantizer();
            let mut x = 0x9e37_79b9_7f4a_7c15u64;
            for round in 0..200 {
                let s: [u64; 8] = crate::lanes::test_samples(round, &mut x);
                let eye = [0.5, -2.0, 10.0];
                let (a, w) = (Avx2::decode8(&deq, eye, &s), decode_scalar::<f32x8>(&deq, eye, &s));
                for (p, q) in a.iter().zip(&w) {
                    assert_eq!(bits(*p), wbits(*q), "decode8 {s:x?}");
                }
            }
            // span_ints over the whole documented domain's edges and a sweep.
            let los = [
                -1.0f32, -0.999, -0.5, -0.0, 0.0, 1e-7, 0.5, 1.0, 1.0001, 2.5, 3.0, 1023.99, 8191.5, 8192.0,
                16777215.0, 2e9,
            ];
            let his = [
                0.0f32, 1e-7, 0.5, 0.999, 1.0, 2.0, 2.5, 7.99, 1023.0, 1023.99, 1024.0, 8191.9, 8192.0, 9000.5,
                16777215.0, 2e9,
            ];
            let mut sweep: Vec<f32> = (0..2000).map(|i| i as f32 * 0.37 - 1.0).collect();
            sweep.extend_from_slice(&los);
            for c in sweep.chunks_exact(8) {
                let lo: [f32; 8] = core::array::from_fn(|l| c[l]);
                let hi: [f32; 8] = core::array::from_fn(|l| his[(l * 3 + c.len()) % his.len()].max(c[l].max(0.0)));
                for max in [0u32, 1, 511, 1023, 8191] {
                    let a = Avx2::span_ints(<Avx2 as Lanes>::new(lo), <Avx2 as Lanes>::new(hi), max);
                    let w = <f32x8 as Lanes>::span_ints(f32x8::new(lo), f32x8::new(hi), max);
                    assert_eq!(a, w, "span_ints {lo:?} {hi:?} {max}");
                }
            }
            for k in 0..8u32 {
                let idx = core::array::from_fn(|l| (l as u32 * 3 + k) ^ (k << 3));
                let (i, wi) = (Avx2::new_u(idx), <f32x8 as Lanes>::new_u(idx));
                let x = <Avx2 as Lanes>::new(core::array::from_fn(|l| l as f32 - 2.5));
                let w = f32x8::new(core::array::from_fn(|l| l as f32 - 2.5));
                assert_eq!(bits(x.permute(i)), wbits(Lanes::permute(w, wi)), "permute {k}");
                assert_eq!(Avx2::u_to_array(Avx2::permute_u(v, i)), <f32x8 as Lanes>::permute_u(wv, wi).to_array());
            }
        }

        #[test]
        fn avx2_lanes_equal_wide_bit_for_bit() {
            if volwarp_lanes::Avx2Token::detected().is_some() {
                // SAFETY: the token proves the CPU supports AVX2.
                unsafe { check() }
            }
        }
    }
}
