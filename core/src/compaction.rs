//! Stable removal of empty samples (radius code 0), keeping pixel order.
//!
//! These work on slices. A parallel driver (the server) splits the frame into chunks, counts
//! each chunk with [`count_nonempty`], takes an exclusive prefix sum of the counts and lets each
//! chunk [`compact_into`] its own window of the output: the result is the same as the serial
//! [`compact_in_place`].

use crate::sample::is_empty;

/// The number of non-empty samples.
#[inline]
pub fn count_nonempty(samples: &[u64]) -> usize {
    samples.iter().filter(|&&s| !is_empty(s)).count()
}

/// Moves the non-empty samples (and their colors) to the front, in order, and returns how many
/// there are. What is left behind the returned count is unspecified.
///
/// # Panics
/// If `samples` and `colors` differ in length.
pub fn compact_in_place(samples: &mut [u64], colors: &mut [u32]) -> usize {
    assert_eq!(samples.len(), colors.len(), "one color per sample");
    let mut w = 0;
    for r in 0..samples.len() {
        let s = samples[r];
        if !is_empty(s) {
            samples[w] = s;
            colors[w] = colors[r];
            w += 1;
        }
    }
    w
}

/// Copies the non-empty samples (and their colors), in order, to the front of `out_samples` /
/// `out_colors` and returns how many were written.
///
/// # Panics
/// If the inputs differ in length or the outputs are shorter than the number of non-empty
/// samples.
pub fn compact_into(samples: &[u64], colors: &[u32], out_samples: &mut [u64], out_colors: &mut [u32]) -> usize {
    assert_eq!(samples.len(), colors.len(), "one color per sample");
    let mut w = 0;
    for (&s, &c) in samples.iter().zip(colors) {
        if !is_empty(s) {
            out_samples[w] = s;
            out_colors[w] = c;
            w += 1;
        }
    }
    w
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sample::RADIUS_BITS;

    fn s(id: u64, full: bool) -> u64 {
        id | if full { 1u64 << (64 - RADIUS_BITS) } else { 0 }
    }

    #[test]
    fn keeps_order_and_colors() {
        let mut samples = [s(0, false), s(1, true), s(2, false), s(3, true), s(4, true), s(5, false)];
        let mut colors = [10, 11, 12, 13, 14, 15];
        let mut out_s = [0u64; 6];
        let mut out_c = [0u32; 6];
        let n2 = compact_into(&samples, &colors, &mut out_s, &mut out_c);
        let n = compact_in_place(&mut samples, &mut colors);
        assert_eq!(n, 3);
        assert_eq!(n2, 3);
        assert_eq!(count_nonempty(&[s(1, true), s(2, false)]), 1);
        assert_eq!(&samples[..3], &[s(1, true), s(3, true), s(4, true)]);
        assert_eq!(&colors[..3], &[11, 13, 14]);
        assert_eq!(&out_s[..3], &samples[..3]);
        assert_eq!(&out_c[..3], &colors[..3]);
    }

    #[test]
    fn all_empty_and_all_full() {
        let mut a = [s(1, false); 4];
        let mut c = [0u32; 4];
        assert_eq!(compact_in_place(&mut a, &mut c), 0);
        let mut a = [s(1, true); 4];
        assert_eq!(compact_in_place(&mut a, &mut c), 4);
        assert_eq!(compact_in_place(&mut [], &mut []), 0);
    }
}
