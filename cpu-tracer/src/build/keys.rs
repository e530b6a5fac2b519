//! Steps 1 and 2 of the build: the Morton codes of the unsorted samples, in parallel chunks,
//! and their parallel stable radix sort ([`super::sort`]) into the order `(code, index)`. Up to
//! [`PACKED_MAX_LEN`] samples the sort moves 8-byte packed keys ([`par_sort_packed`]: the code
//! without its lowest digit, and the input index), past that 16-byte [`SortKey`]s.

use super::sort::{packed_index, par_radix_sort, par_sort_packed, PACKED_INDEX_BITS, PACKED_MAX_LEN};
use super::{BuildTimes, Clock, GRAIN};
use crate::threads::Threads;
use volwarp_core::morton::{code_of_sample, SortKey, RADIX_BITS};
use volwarp_core::sample::POS_BITS;

/// The sort's buffers, kept between frames.
#[derive(Debug, Default)]
pub(super) struct KeyBuffers {
    keys: Vec<SortKey>,
    scratch: Vec<SortKey>,
    codes: Vec<u64>,
    packed: Vec<u64>,
    packed_scratch: Vec<u64>,
}

impl KeyBuffers {
    /// Steps 1 and 2: codes the `n` samples and sorts them; sets `times.keys_us` and
    /// `times.sort_us`.
    pub(super) fn sort(
        &mut self,
        in_samples: &[u64],
        threads: &Threads,
        clock: &mut Clock,
        times: &mut BuildTimes,
    ) -> Sorted<'_> {
        let n = in_samples.len();
        // 1. Morton codes of the unsorted samples (16-byte keys past the packed sort's limit)
        let sorted = if n <= PACKED_MAX_LEN {
            self.codes.resize(n, 0);
            threads.for_each_chunk(&mut self.codes, GRAIN, |c, codes| {
                for (o, &s) in codes.iter_mut().zip(&in_samples[c * GRAIN..]) {
                    *o = code_of_sample(s);
                }
            });
            times.keys_us = clock.lap();
            // 2. sort
            self.packed.resize(n, 0);
            self.packed_scratch.resize(n, 0);
            par_sort_packed(&self.codes, &mut self.packed, &mut self.packed_scratch, threads);
            Sorted::Packed(&self.packed)
        } else {
            self.keys.resize(n, SortKey::default());
            threads.for_each_chunk(&mut self.keys, GRAIN, |c, ks| {
                for (j, k) in ks.iter_mut().enumerate() {
                    let i = c * GRAIN + j;
                    *k = SortKey { code: code_of_sample(in_samples[i]), index: i as u32, pad: 0 };
                }
            });
            times.keys_us = clock.lap();
            self.scratch.resize(n, SortKey::default());
            par_radix_sort(&mut self.keys, &mut self.scratch, threads);
            Sorted::Keys(&self.keys)
        };
        times.sort_us = clock.lap();
        sorted
    }

    /// The sorted order as 16-byte keys (what core's `karras_node` takes), rebuilt from the
    /// packed keys and the sorted `samples` if the packed sort was used.
    pub(super) fn sort_keys(&mut self, samples: &[u64], threads: &Threads) -> &[SortKey] {
        let n = samples.len();
        if n <= PACKED_MAX_LEN {
            let packed = &self.packed[..];
            self.keys.resize(n, SortKey::default());
            threads.for_each_chunk(&mut self.keys, GRAIN, |c, ks| {
                for (j, k) in ks.iter_mut().enumerate() {
                    let i = c * GRAIN + j;
                    let code = packed_code(packed[i], samples[i]);
                    *k = SortKey { code, index: packed_index(packed[i]) as u32, pad: 0 };
                }
            });
        }
        &self.keys
    }
}

/// The sorted order: packed keys (with the sorted samples, they give the codes), or 16-byte
/// keys past [`PACKED_MAX_LEN`].
#[derive(Clone, Copy)]
pub(super) enum Sorted<'a> {
    Packed(&'a [u64]),
    Keys(&'a [SortKey]),
}

impl Sorted<'_> {
    /// The input index of sorted key `k`.
    #[inline(always)]
    pub(super) fn index(&self, k: usize) -> usize {
        match self {
            Sorted::Packed(p) => packed_index(p[k]),
            Sorted::Keys(keys) => keys[k].index as usize,
        }
    }
}

/// The low [`RADIX_BITS`] bits of a sample's Morton code (the digit a packed key lacks),
/// from a table: `x` bits 0–3 go to 0, 3, 6, 9, `y` bits 0–3 to 1, 4, 7, 10, `z` bits 0–2 to
/// 2, 5, 8.
#[inline(always)]
fn low_code_bits(s: u64) -> u64 {
    const SPREAD4: [u16; 16] = {
        let mut t = [0u16; 16];
        let mut v = 0;
        while v < 16 {
            t[v] = ((v & 1) | (v & 2) << 2 | (v & 4) << 4 | (v & 8) << 6) as u16;
            v += 1;
        }
        t
    };
    let (x, y, z) = (s as usize & 15, (s >> POS_BITS) as usize & 15, (s >> (2 * POS_BITS)) as usize & 15);
    (SPREAD4[x] as u64 | (SPREAD4[y] as u64) << 1 | (SPREAD4[z] as u64) << 2) & ((1 << RADIX_BITS) - 1)
}

/// The Morton code of a packed key whose sample is `s`.
#[inline(always)]
pub(super) fn packed_code(key: u64, s: u64) -> u64 {
    (key >> PACKED_INDEX_BITS) << RADIX_BITS | low_code_bits(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn low_code_bits_are_the_codes_low_digit() {
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..10_000 {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let s = x >> 8;
            assert_eq!(low_code_bits(s), code_of_sample(s) & ((1 << RADIX_BITS) - 1), "{s:#x}");
            let key = (code_of_sample(s) >> RADIX_BITS) << PACKED_INDEX_BITS | 12345;
            assert_eq!(packed_code(key, s), code_of_sample(s));
        }
    }
}
