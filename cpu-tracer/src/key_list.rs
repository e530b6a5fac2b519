//! The short per-pixel lists of nearest depth keys the layered renderers keep
//! ([`crate::layer_splat`], [`crate::layer_trace`]): a key is a segment's distance from the eye
//! and its sample id; a pixel keeps its [`LIST`] nearest, sorts them (ties by id) and composites
//! their colors front to back, `C += (1 − A)·c`, stopping once `A` ≥ [`OPAQUE`].
//!
//! Every operation has a plain scalar definition, the reference, and the hot ones an AVX2 path
//! that gives the same result bit for bit (tested against the reference): the replacement of a
//! full list's farthest key ([`insert`]: the farthest found with four 64-bit comparisons
//! instead of a chain of sixteen), the sort ([`sort_keys`]: ranks counted with 64-bit
//! comparisons) and the compositing of eight pixels at once ([`composite_run`]: one pixel per
//! lane, the same multiply and add per channel as [`composite_keys`], so the latency of one
//! pixel's front-to-back chain overlaps seven others' instead of stalling the core; a lane past
//! its list's end or already opaque adds exactly zero).

use crate::frame_setup::over_background_fast;
#[cfg(target_arch = "x86_64")]
use crate::lanes;
use volwarp_core::sample::pack_color_f32;
use volwarp_core::BACKGROUND;

/// Most segments kept per output pixel (the nearest ones).
pub const LIST: usize = 16;

/// Accumulated opacity at which a pixel's compositing stops.
pub const OPAQUE: f32 = volwarp_core::segments::OPAQUE;

/// The depth key: the centre's distance from the eye (ordered bits of a non-negative float)
/// and the sample id.
#[inline(always)]
pub(crate) fn key(dist: f32, id: u32) -> u64 {
    ((dist.max(0.0).to_bits() as u64) << 32) | id as u64
}

/// Inserts `key` into a list of `cap` slots holding `n`, keeping the `cap` smallest.
#[inline(always)]
pub(crate) fn insert(slots: &mut [u64], n: &mut u8, key: u64) {
    let len = *n as usize;
    if len < slots.len() {
        slots[len] = key;
        *n += 1;
        return;
    }
    #[cfg(target_arch = "x86_64")]
    if let Ok(full) = <&mut [u64; LIST]>::try_from(&mut *slots) {
        if lanes::use_avx2() {
            // SAFETY: the CPU has AVX2 (`use_avx2` checks).
            unsafe { replace_farthest_avx2(full, key) };
            return;
        }
    }
    replace_farthest(slots, key);
}

/// The full list `slots` with its farthest key replaced by `key` if `key` is nearer (the
/// reference of [`replace_farthest_avx2`]).
#[inline(always)]
fn replace_farthest(slots: &mut [u64], key: u64) {
    let (mut worst, mut at) = (0u64, 0usize);
    for (i, &k) in slots.iter().enumerate() {
        if k >= worst {
            worst = k;
            at = i;
        }
    }
    if key < worst {
        slots[at] = key;
    }
}

/// A list of [`LIST`] keys in four AVX2 registers.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn load_list(keys: &[u64; LIST]) -> [core::arch::x86_64::__m256i; 4] {
    use core::arch::x86_64::*;
    let p = keys.as_ptr() as *const __m256i;
    // SAFETY: `keys` holds LIST = 16 u64, i.e. four unaligned 256-bit loads.
    unsafe {
        [
            _mm256_loadu_si256(p),
            _mm256_loadu_si256(p.add(1)),
            _mm256_loadu_si256(p.add(2)),
            _mm256_loadu_si256(p.add(3)),
        ]
    }
}

/// [`replace_farthest`] for a list of [`LIST`] keys in four AVX2 registers: whether any key is
/// farther than `key` is one comparison per register; only then is the farthest found, by a
/// tree of maxima, and its slot by an equality mask. The keys are distinct (each holds its
/// sample's id) and below 2⁶³ (the distance's bits are those of a non-negative `f32`), so
/// the signed comparison orders them and the farthest is one slot: the one the reference
/// replaces.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn replace_farthest_avx2(slots: &mut [u64; LIST], key: u64) {
    use core::arch::x86_64::*;
    // SAFETY: the CPU supports AVX2 (this function's contract).
    let v = unsafe { load_list(slots) };
    let k = _mm256_set1_epi64x(key as i64);
    let farther = _mm256_or_si256(
        _mm256_or_si256(_mm256_cmpgt_epi64(v[0], k), _mm256_cmpgt_epi64(v[1], k)),
        _mm256_or_si256(_mm256_cmpgt_epi64(v[2], k), _mm256_cmpgt_epi64(v[3], k)),
    );
    if _mm256_testz_si256(farther, farther) != 0 {
        return;
    }
    let max = |a: __m256i, b: __m256i| _mm256_blendv_epi8(a, b, _mm256_cmpgt_epi64(b, a));
    let mut m = max(max(v[0], v[1]), max(v[2], v[3]));
    m = max(m, _mm256_permute4x64_epi64::<0b01_00_11_10>(m));
    m = max(m, _mm256_permute4x64_epi64::<0b10_11_00_01>(m));
    let at = |i: usize| _mm256_movemask_pd(_mm256_castsi256_pd(_mm256_cmpeq_epi64(v[i], m))) as u32;
    let mask = at(0) | at(1) << 4 | at(2) << 8 | at(3) << 12;
    if let Some(slot) = slots.get_mut(mask.trailing_zeros() as usize) {
        *slot = key;
    }
}

/// Sorts a short list (at most [`LIST`]) of distinct keys: with AVX2 where the CPU has it,
/// else [`sort_keys_scalar`]. (The keys are distinct: each holds its sample's id.)
#[inline(always)]
pub(crate) fn sort_keys(keys: &mut [u64]) {
    #[cfg(target_arch = "x86_64")]
    if lanes::use_avx2() {
        // SAFETY: the CPU has AVX2 (`use_avx2` checks).
        unsafe { sort_keys_avx2(keys) };
        return;
    }
    sort_keys_scalar(keys);
}

/// Sorts a short list of distinct keys by rank: each key goes to the place given by how many
/// keys are smaller (n² comparisons without a branch to mispredict; an insertion sort's
/// data-dependent branches cost more on these handfuls of keys, `docs/perf.md`).
#[inline(always)]
fn sort_keys_scalar(keys: &mut [u64]) {
    let n = keys.len().min(LIST);
    let mut tmp = [0u64; LIST];
    tmp[..n].copy_from_slice(&keys[..n]);
    for &k in &tmp[..n] {
        let rank = tmp[..n].iter().map(|&x| (x < k) as usize).sum::<usize>();
        keys[rank] = k;
    }
}

/// [`sort_keys_scalar`] with the ranks of all keys counted at once: for each key, one 64-bit
/// comparison against all sixteen slots (four AVX2 registers) adds one to the rank of every
/// larger key. Keys are below 2⁶³ (the distance's bits are those of a non-negative `f32`), so
/// the signed comparison orders them; the unused slots hold `i64::MAX` and are not read back.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn sort_keys_avx2(keys: &mut [u64]) {
    use core::arch::x86_64::*;
    let n = keys.len().min(LIST);
    let mut tmp = [i64::MAX as u64; LIST];
    tmp[..n].copy_from_slice(&keys[..n]);
    // SAFETY: the CPU supports AVX2 (this function's contract).
    let v = unsafe { load_list(&tmp) };
    let mut rank = [_mm256_setzero_si256(); 4];
    for &k in &tmp[..n] {
        let kk = _mm256_set1_epi64x(k as i64);
        for (r, &x) in rank.iter_mut().zip(&v) {
            // The comparison is −1 where the slot's key is larger.
            *r = _mm256_sub_epi64(*r, _mm256_cmpgt_epi64(x, kk));
        }
    }
    let mut ranks = [0u64; LIST];
    let q = ranks.as_mut_ptr() as *mut __m256i;
    // SAFETY: `ranks` holds LIST = 16 u64, i.e. four unaligned 256-bit stores.
    unsafe {
        for (i, &r) in rank.iter().enumerate() {
            _mm256_storeu_si256(q.add(i), r);
        }
    }
    for (&k, &r) in tmp[..n].iter().zip(&ranks) {
        if let Some(slot) = keys.get_mut(r as usize) {
            *slot = k;
        }
    }
}

/// The pixel of a sorted list of keys: their samples' colors composited front to back over the
/// background.
pub(crate) fn composite_keys(keys: &[u64], colors: &[u32]) -> u32 {
    if keys.is_empty() {
        return BACKGROUND;
    }
    let mut acc = [0.0f32; 4];
    for &k in keys {
        let Some(&c) = colors.get(k as u32 as usize) else { continue };
        let c = c.to_le_bytes();
        let wgt = (1.0 - acc[3]) * (1.0 / 255.0);
        for i in 0..4 {
            acc[i] += wgt * c[i] as f32;
        }
        if acc[3] >= OPAQUE {
            break;
        }
    }
    over_background_fast(pack_color_f32(acc))
}

/// The pixels of a run: each pixel's sorted list of keys composited over the background into
/// `out` (a pixel whose count is 0 is left as it is). Pixel `i`'s list is
/// `keys[i·LIST..i·LIST + count[i]]`. Runs of eight with AVX2 where the CPU has it, the rest
/// with [`composite_keys`]; the same pixels either way.
pub(crate) fn composite_run(keys: &[u64], count: &[u8], colors: &[u32], out: &mut [u32]) {
    let n = out.len().min(count.len()).min(keys.len() / LIST);
    #[cfg_attr(not(target_arch = "x86_64"), allow(unused_mut))]
    let mut i = 0;
    #[cfg(target_arch = "x86_64")]
    if lanes::use_avx2() {
        while i + 8 <= n {
            let c: [u8; 8] = core::array::from_fn(|k| count[i + k]);
            if c != [0; 8] {
                let lists = &keys[i * LIST..(i + 8) * LIST];
                let o = &mut out[i..i + 8];
                // SAFETY: the CPU has AVX2 (`use_avx2` checks); the slices have the lengths
                // the kernel reads and writes.
                unsafe {
                    composite8_avx2(lists.try_into().expect("8 lists"), &c, colors, o.try_into().expect("8 pixels"))
                };
            }
            i += 8;
        }
    }
    for k in i..n {
        let m = (count[k] as usize).min(LIST);
        if m > 0 {
            out[k] = composite_keys(&keys[k * LIST..k * LIST + m], colors);
        }
    }
}

/// [`composite_keys`] for eight pixels, one per lane: step `j` takes each pixel's `j`-th key,
/// gathers its color and adds `wgt · c` with `wgt = (1 − A) · (1/255)` — the reference's
/// operations in its order, no fused multiply-add — where the lane is *live* (`j` below its
/// count, the sample id inside `colors`, and `A` still below [`OPAQUE`]), else exactly zero,
/// which leaves the lane's sums as they are. The loop ends once no lane is live.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn composite8_avx2(lists: &[u64; 8 * LIST], count: &[u8; 8], colors: &[u32], out: &mut [u32; 8]) {
    use core::arch::x86_64::*;
    let n = _mm256_setr_epi32(
        count[0] as i32,
        count[1] as i32,
        count[2] as i32,
        count[3] as i32,
        count[4] as i32,
        count[5] as i32,
        count[6] as i32,
        count[7] as i32,
    );
    let n = _mm256_min_epi32(n, _mm256_set1_epi32(LIST as i32));
    let steps = count.iter().map(|&c| (c as usize).min(LIST)).max().unwrap_or(0);
    // The low half of key `j` of lane `k` (its sample id), as 32-bit index into `lists`.
    let first = _mm256_setr_epi32(
        0,
        2 * LIST as i32,
        4 * LIST as i32,
        6 * LIST as i32,
        8 * LIST as i32,
        10 * LIST as i32,
        12 * LIST as i32,
        14 * LIST as i32,
    );
    let len = colors.len().min(i32::MAX as usize) as i32;
    let last = _mm256_set1_epi32(len.wrapping_sub(1));
    let byte = _mm256_set1_epi32(0xFF);
    let (one, inv, opaque) = (_mm256_set1_ps(1.0), _mm256_set1_ps(1.0 / 255.0), _mm256_set1_ps(OPAQUE));
    let mut acc = [_mm256_setzero_ps(); 4];
    for j in 0..steps {
        let jj = _mm256_set1_epi32(j as i32);
        // SAFETY: every index is 2·(k·LIST + j) < 2·8·LIST, inside `lists` read as u32.
        let id = unsafe {
            _mm256_i32gather_epi32::<4>(lists.as_ptr() as *const i32, _mm256_add_epi32(first, _mm256_add_epi32(jj, jj)))
        };
        // Inside `colors`: 0 ≤ id ≤ len − 1 as unsigned (nothing is when `colors` is empty).
        let inside = if len > 0 { _mm256_cmpeq_epi32(_mm256_min_epu32(id, last), id) } else { _mm256_setzero_si256() };
        let listed = _mm256_cmpgt_epi32(n, jj);
        let open = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_LT_OQ>(acc[3], opaque));
        if _mm256_testz_si256(listed, open) != 0 {
            break;
        }
        // The gather does not wait for the sums (its mask does not depend on them): the next
        // steps' colors load while this step's chain runs.
        let valid = _mm256_and_si256(inside, listed);
        // SAFETY: only lanes with an id inside `colors` read.
        let c = unsafe {
            _mm256_mask_i32gather_epi32::<4>(_mm256_setzero_si256(), colors.as_ptr() as *const i32, id, valid)
        };
        let live = _mm256_and_si256(valid, open);
        let ch = [
            _mm256_cvtepi32_ps(_mm256_and_si256(c, byte)),
            _mm256_cvtepi32_ps(_mm256_and_si256(_mm256_srli_epi32::<8>(c), byte)),
            _mm256_cvtepi32_ps(_mm256_and_si256(_mm256_srli_epi32::<16>(c), byte)),
            _mm256_cvtepi32_ps(_mm256_srli_epi32::<24>(c)),
        ];
        let wgt = _mm256_and_ps(_mm256_mul_ps(_mm256_sub_ps(one, acc[3]), inv), _mm256_castsi256_ps(live));
        for (a, c) in acc.iter_mut().zip(ch) {
            *a = _mm256_add_ps(*a, _mm256_mul_ps(wgt, c));
        }
    }
    let mut sums = [[0.0f32; 8]; 4];
    for (s, a) in sums.iter_mut().zip(acc) {
        // SAFETY: eight f32, one unaligned 256-bit store.
        unsafe { _mm256_storeu_ps(s.as_mut_ptr(), a) };
    }
    for (k, o) in out.iter_mut().enumerate() {
        if count[k] > 0 {
            *o = over_background_fast(pack_color_f32([sums[0][k], sums[1][k], sums[2][k], sums[3][k]]));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::SplitMix64;

    /// A full list's farthest key is replaced as the reference replaces it, on random full
    /// lists (distinct keys, equal distances) and keys nearer, farther and in between.
    #[test]
    fn the_farthest_is_replaced_like_the_reference() {
        let mut rng = SplitMix64(5);
        for round in 0..5000u32 {
            let mut list = [0u64; LIST];
            for (i, k) in list.iter_mut().enumerate() {
                let dist = match round % 3 {
                    0 => (rng.next_u64() % 1000) as f32 * 0.25,
                    1 => 2.5,
                    _ => f32::INFINITY,
                };
                *k = key(dist, round * 64 + i as u32);
            }
            let probe = key((rng.next_u64() % 1100) as f32 * 0.25, round * 64 + 40);
            let mut want = list;
            replace_farthest(&mut want, probe);
            let mut got = list;
            let mut n = LIST as u8;
            insert(&mut got, &mut n, probe);
            assert_eq!(got, want, "round {round}");
            assert_eq!(n as usize, LIST);
        }
    }

    /// Runs of pixels composite as [`composite_keys`] composites each: every count from 0 to
    /// LIST, ids outside the colors, opaque and transparent colors, runs not a multiple of 8.
    #[test]
    fn runs_composite_like_the_reference() {
        let mut rng = SplitMix64(9);
        for round in 0..300usize {
            let pixels = 1 + round % 37;
            let colors: Vec<u32> = (0..50)
                .map(|_| {
                    let c = rng.next_u64() as u32;
                    match rng.next_u64() % 4 {
                        0 => c | 0xFF00_0000,
                        1 => c & 0x00FF_FFFF,
                        _ => c,
                    }
                })
                .collect();
            // Slots past a pixel's count hold stale keys with valid ids, as a reused buffer does.
            let mut keys: Vec<u64> = (0..pixels * LIST).map(|_| key(0.5, (rng.next_u64() % 50) as u32)).collect();
            let mut count = vec![0u8; pixels];
            for (p, c) in count.iter_mut().enumerate() {
                *c = (rng.next_u64() % (LIST as u64 + 1)) as u8;
                for j in 0..*c as usize {
                    // Ids up to 59 (some outside the 50 colors), sorted by distance.
                    keys[p * LIST + j] = key(j as f32 + 1.0, (rng.next_u64() % 60) as u32);
                }
            }
            let mut want = vec![0x1234_5678u32; pixels];
            for p in 0..pixels {
                if count[p] > 0 {
                    want[p] = composite_keys(&keys[p * LIST..p * LIST + count[p] as usize], &colors);
                }
            }
            let mut got = vec![0x1234_5678u32; pixels];
            composite_run(&keys, &count, &colors, &mut got);
            assert_eq!(got, want, "round {round}");
            let mut none = vec![7u32; pixels];
            composite_run(&keys, &count, &[], &mut none);
            for p in 0..pixels {
                assert_eq!(none[p], if count[p] > 0 { BACKGROUND } else { 7 });
            }
        }
    }

    #[test]
    fn the_short_list_keeps_the_nearest() {
        let mut slots = [0u64; 6];
        let mut n = 0u8;
        for k in (0..40u64).rev() {
            insert(&mut slots, &mut n, k * 3);
        }
        slots.sort_unstable();
        assert_eq!(n, 6);
        assert_eq!(slots.to_vec(), (0..6u64).map(|k| k * 3).collect::<Vec<_>>());
    }

    /// Short lists of distinct keys (0 to LIST long, in every order the generator gives, with
    /// keys near 2⁶³ and equal distances) sort as `sort_unstable` sorts them, on both paths.
    #[test]
    fn short_lists_sort_like_the_standard_sort() {
        let mut rng = SplitMix64(11);
        for round in 0..2000 {
            let n = round % (LIST + 1);
            let list: Vec<u64> = (0..n)
                .map(|i| match round % 3 {
                    0 => rng.next_u64() >> 1,
                    1 => key(f32::INFINITY, (rng.next_u64() % 1000) as u32 * 20 + i as u32),
                    _ => key(1.5, i as u32 * 7 + 1) ^ (rng.next_u64() & 0xffff_0000_0000_0000 >> 1),
                })
                .collect();
            let mut distinct = list.clone();
            distinct.sort_unstable();
            distinct.dedup();
            if distinct.len() != list.len() {
                continue;
            }
            let mut a = list.clone();
            sort_keys_scalar(&mut a);
            assert_eq!(a, distinct);
            let mut b = list.clone();
            sort_keys(&mut b);
            assert_eq!(b, distinct);
        }
    }

    #[test]
    fn compositing_zero_opacity_gives_the_background_and_no_nan() {
        let colors = [0u32, 0, 0];
        assert_eq!(composite_keys(&[key(1.0, 0), key(2.0, 1), key(3.0, 2)], &colors), BACKGROUND);
        assert_eq!(composite_keys(&[], &colors), BACKGROUND);
    }
}
