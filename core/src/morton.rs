//! Morton codes of quantized sample positions, and the stable radix sort the LBVH build uses.
//!
//! The code interleaves the 18-bit quantized coordinates of a packed sample directly (no floats
//! involved): `x` in bits 0, 3, 6, …, `y` in 1, 4, …, `z` in 2, 5, …, 54 bits in all.

use crate::sample::unpack_position;

/// Bits of a Morton code.
pub const CODE_BITS: u32 = 54;

/// Spreads the low 21 bits of `v` so that bit `i` moves to bit `3i`.
#[inline(always)]
pub fn spread_bits(v: u32) -> u64 {
    let mut x = v as u64 & 0x1f_ffff;
    x = (x | x << 32) & 0x001f_0000_0000_ffff;
    x = (x | x << 16) & 0x001f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    x = (x | x << 2) & 0x1249_2492_4924_9249;
    x
}

/// The Morton code of three quantized coordinates.
#[inline(always)]
pub fn encode(x: u32, y: u32, z: u32) -> u64 {
    spread_bits(x) | spread_bits(y) << 1 | spread_bits(z) << 2
}

/// The Morton code of a packed sample's position.
#[inline(always)]
pub fn code_of_sample(s: u64) -> u64 {
    let (x, y, z) = unpack_position(s);
    encode(x, y, z)
}

/// A Morton code and the index of the sample it came from.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SortKey {
    /// Morton code.
    pub code: u64,
    /// Index of the sample in the unsorted input.
    pub index: u32,
    /// Padding (0).
    pub pad: u32,
}

/// Fills `keys[i]` with the code of `samples[i]` and index `i`.
///
/// # Panics
/// If the lengths differ.
pub fn make_keys(samples: &[u64], keys: &mut [SortKey]) {
    assert_eq!(samples.len(), keys.len());
    for (i, (k, &s)) in keys.iter_mut().zip(samples).enumerate() {
        *k = SortKey { code: code_of_sample(s), index: i as u32, pad: 0 };
    }
}

/// Radix digit width in bits.
pub const RADIX_BITS: u32 = 11;
/// Number of radix passes for [`CODE_BITS`].
pub const RADIX_PASSES: u32 = CODE_BITS.div_ceil(RADIX_BITS);
const BUCKETS: usize = 1 << RADIX_BITS;

/// Sorts keys by code, **stably** (equal codes keep their input order, so keys made by
/// [`make_keys`] end up ordered by `(code, index)`: the order is fully determined). LSD radix
/// sort over [`RADIX_PASSES`] digits, with `scratch` (same length) as the second buffer.
///
/// # Panics
/// If `scratch` is shorter than `keys`.
pub fn radix_sort(keys: &mut [SortKey], scratch: &mut [SortKey]) {
    let n = keys.len();
    let scratch = &mut scratch[..n];
    let mut in_keys = true;
    for pass in 0..RADIX_PASSES {
        let shift = pass * RADIX_BITS;
        let (src, dst): (&[SortKey], &mut [SortKey]) =
            if in_keys { (&*keys, &mut *scratch) } else { (&*scratch, &mut *keys) };
        let mut hist = [0usize; BUCKETS];
        for k in src.iter() {
            hist[((k.code >> shift) as usize) & (BUCKETS - 1)] += 1;
        }
        if hist.contains(&n) {
            continue; // every key has the same digit: the pass would not move anything
        }
        let mut sum = 0;
        for h in hist.iter_mut() {
            let c = *h;
            *h = sum;
            sum += c;
        }
        for k in src.iter() {
            let d = ((k.code >> shift) as usize) & (BUCKETS - 1);
            dst[hist[d]] = *k;
            hist[d] += 1;
        }
        in_keys = !in_keys;
    }
    if !in_keys {
        keys.copy_from_slice(scratch);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spread_places_bits() {
        assert_eq!(spread_bits(1), 1);
        assert_eq!(spread_bits(2), 8);
        assert_eq!(spread_bits(0b101), 0b1000001);
        assert_eq!(encode(1, 1, 1), 7);
        assert_eq!(encode(0x3ffff, 0x3ffff, 0x3ffff), (1u64 << 54) - 1);
        for i in 0..21 {
            assert_eq!(spread_bits(1 << i), 1u64 << (3 * i));
        }
    }

    #[test]
    fn radix_sort_is_stable_and_sorted() {
        let codes = [5u64, 3, 5, 1 << 53, 0, 3, 77 << 22, 5];
        let mut keys: [SortKey; 8] = core::array::from_fn(|i| SortKey { code: codes[i], index: i as u32, pad: 0 });
        let mut scratch = [SortKey::default(); 8];
        radix_sort(&mut keys, &mut scratch);
        for w in keys.windows(2) {
            assert!((w[0].code, w[0].index) < (w[1].code, w[1].index));
        }
    }
}
