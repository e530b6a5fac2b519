//! The parallel compaction equals core's serial one.

use volwarp_core::compaction::compact_in_place;
use volwarp_core::sample::RADIUS_BITS;
use volwarp_server::compaction::{compact, compact_into_vecs, CHUNK};

fn frame(n: usize, seed: u64, fill: u64) -> (Vec<u64>, Vec<u32>) {
    let mut x = seed | 1;
    let mut next = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    let samples = (0..n)
        .map(|i| {
            let full = next() % 100 < fill;
            (i as u64 & ((1 << 54) - 1)) | if full { (1 + next() % 1000) << (64 - RADIUS_BITS) } else { 0 }
        })
        .collect();
    let colors = (0..n).map(|i| i as u32 ^ 0x5a5a_5a5a).collect();
    (samples, colors)
}

#[test]
fn parallel_compaction_equals_serial() {
    for (n, fill) in [
        (0, 50),
        (1, 100),
        (1, 0),
        (CHUNK - 1, 60),
        (CHUNK, 60),
        (CHUNK + 1, 60),
        (3 * CHUNK + 17, 60),
        (1 << 20, 59),
        (100_000, 0),
        (100_000, 100),
    ] {
        let (s, c) = frame(n, n as u64 + 7, fill);
        let (ps, pc) = compact(&s, &c);
        let (mut ss, mut sc) = (s.clone(), c.clone());
        let k = compact_in_place(&mut ss, &mut sc);
        assert_eq!(ps.len(), k, "n {n}");
        assert_eq!(ps, ss[..k], "n {n}");
        assert_eq!(pc, sc[..k], "n {n}");
        // Reusing buffers gives the same.
        let (mut rs, mut rc) = (vec![9u64; 5], vec![9u32; 3]);
        assert_eq!(compact_into_vecs(&s, &c, &mut rs, &mut rc), k);
        assert_eq!(rs, ps);
        assert_eq!(rc, pc);
    }
}
