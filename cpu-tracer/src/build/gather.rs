//! Step 3 of the build: samples and colors gathered into sorted order, in parallel (one loop,
//! two random reads per key).

use super::keys::Sorted;
use super::GRAIN;
use crate::threads::Threads;
use rayon::prelude::*;

/// Writes `in_samples` and `in_colors` in the `sorted` order into `out_s` and `out_c` (all
/// of one length).
pub(super) fn gather(
    sorted: Sorted,
    in_samples: &[u64],
    in_colors: &[u32],
    out_s: &mut [u64],
    out_c: &mut [u32],
    threads: &Threads,
) {
    let gather = |start: usize, out_s: &mut [u64], out_c: &mut [u32]| {
        for (j, (s, c)) in out_s.iter_mut().zip(out_c.iter_mut()).enumerate() {
            let i = sorted.index(start + j);
            (*s, *c) = (in_samples[i], in_colors[i]);
        }
    };
    if threads.is_serial() {
        gather(0, out_s, out_c);
    } else {
        threads.install(|| {
            out_s
                .par_chunks_mut(GRAIN)
                .zip(out_c.par_chunks_mut(GRAIN))
                .enumerate()
                .for_each(|(c, (s, col))| gather(c * GRAIN, s, col))
        });
    }
}
