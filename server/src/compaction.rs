//! Parallel compaction: the frame's empty samples (radius 0) removed, pixel order kept.
//!
//! Three steps over chunks of the frame (rayon): count each chunk's non-empty samples, take
//! the exclusive prefix sum of the counts, and let every chunk copy its samples into its own
//! window of the output. The result equals core's serial
//! [`volwarp_core::compaction::compact_in_place`] (tested). The seed paper compacted serially
//! in 23 ms at 1024²; see `docs/perf.md` for this one.

use rayon::prelude::*;
use volwarp_core::compaction::count_nonempty;
use volwarp_core::sample::is_empty;

/// Samples per chunk (a chunk is one rayon task).
pub const CHUNK: usize = 32 * 1024;

/// Compacts into new vectors: `(samples, colors)` of the non-empty samples, in order.
///
/// # Panics
/// If `samples` and `colors` differ in length.
pub fn compact(samples: &[u64], colors: &[u32]) -> (Vec<u64>, Vec<u32>) {
    let (mut s, mut c) = (Vec::new(), Vec::new());
    compact_into_vecs(samples, colors, &mut s, &mut c);
    (s, c)
}

/// Compacts into `out_samples` / `out_colors` (resized to the count; their memory is reused,
/// so a server that keeps them from frame to frame neither allocates nor zeroes) and returns
/// the count.
///
/// # Panics
/// If `samples` and `colors` differ in length.
pub fn compact_into_vecs(
    samples: &[u64],
    colors: &[u32],
    out_samples: &mut Vec<u64>,
    out_colors: &mut Vec<u32>,
) -> usize {
    assert_eq!(samples.len(), colors.len(), "one color per sample");
    let counts: Vec<usize> = samples.par_chunks(CHUNK).map(count_nonempty).collect();
    let total: usize = counts.iter().sum();
    // Every slot below `total` is overwritten: keep what is there rather than zeroing it.
    out_samples.truncate(total);
    out_colors.truncate(total);
    out_samples.resize(total, 0);
    out_colors.resize(total, 0);
    let mut windows = Vec::with_capacity(counts.len());
    let (mut rs, mut rc) = (&mut out_samples[..], &mut out_colors[..]);
    for &n in &counts {
        let (ws, s2) = rs.split_at_mut(n);
        let (wc, c2) = rc.split_at_mut(n);
        windows.push((ws, wc));
        rs = s2;
        rc = c2;
    }
    windows.into_par_iter().zip(samples.par_chunks(CHUNK).zip(colors.par_chunks(CHUNK))).for_each(
        |((ws, wc), (s, c))| {
            // The same as core's `compact_into`, written as iterators so there is no bounds
            // check per element (the window holds exactly this chunk's non-empty samples).
            let kept = s.iter().zip(c).filter(|(s, _)| !is_empty(**s));
            for ((os, oc), (s, c)) in ws.iter_mut().zip(wc.iter_mut()).zip(kept) {
                *os = *s;
                *oc = *c;
            }
        },
    );
    total
}
