//! The parallel stable LSD radix sort of Morton keys: the same digits as core's serial
//! [`volwarp_core::morton::radix_sort`] ([`RADIX_BITS`] bits, [`RADIX_PASSES`] passes), each
//! pass split into contiguous chunks that count their digits in parallel, take a
//! digit-major/chunk-minor prefix sum, and scatter in parallel into disjoint slots. Each pass
//! is stable, so the result is ordered by `(code, index)` exactly like the serial sort.

use crate::threads::Threads;
use volwarp_core::morton::{radix_sort, SortKey, RADIX_BITS, RADIX_PASSES};

const BUCKETS: usize = 1 << RADIX_BITS;
const MASK: u64 = (BUCKETS - 1) as u64;

/// Below this many keys, the serial sort is faster.
const PARALLEL_MIN: usize = 1 << 14;

/// A raw pointer to a buffer that several threads write at provably disjoint indices.
#[derive(Clone, Copy)]
pub(crate) struct SharedMut<T> {
    ptr: *mut T,
    len: usize,
}

// SAFETY: the pointer is only used through `write`, whose callers guarantee that no two
// threads write the same index and that nothing reads the buffer until they are all done.
unsafe impl<T: Send> Send for SharedMut<T> {}
// SAFETY: as above.
unsafe impl<T: Send> Sync for SharedMut<T> {}

impl<T> SharedMut<T> {
    pub(crate) fn new(s: &mut [T]) -> Self {
        SharedMut { ptr: s.as_mut_ptr(), len: s.len() }
    }

    /// The pointer to element `i` (bounds-checked); what it may be used for is the caller's
    /// business (see the `unsafe` uses).
    #[inline(always)]
    pub(crate) fn ptr_at(&self, i: usize) -> *mut T {
        assert!(i < self.len, "index {i} out of {}", self.len);
        // SAFETY: in bounds of the allocation the pointer came from.
        unsafe { self.ptr.add(i) }
    }

    /// Writes `v` at `i` (bounds-checked).
    ///
    /// # Safety
    /// No other thread may access index `i` while the buffer is shared, and the slice the
    /// pointer came from must outlive every call.
    #[inline(always)]
    pub(crate) unsafe fn write(&self, i: usize, v: T) {
        assert!(i < self.len, "index {i} out of {}", self.len);
        // SAFETY: in bounds (checked above); exclusive per the caller's contract.
        unsafe { self.ptr.add(i).write(v) }
    }
}

/// Sorts `keys` by code, stably, with `scratch` (at least as long) as the second buffer:
/// the same result as `volwarp_core::morton::radix_sort`.
///
/// # Panics
/// If `scratch` is shorter than `keys`.
pub fn par_radix_sort(keys: &mut [SortKey], scratch: &mut [SortKey], threads: &Threads) {
    let n = keys.len();
    let scratch = &mut scratch[..n];
    if threads.is_serial() || n < PARALLEL_MIN || n > u32::MAX as usize {
        radix_sort(keys, scratch);
        return;
    }
    let chunks = threads.count() * 2;
    let chunk_len = n.div_ceil(chunks);
    let mut hists = vec![[0u32; BUCKETS]; chunks];
    let mut in_keys = true;
    for pass in 0..RADIX_PASSES {
        let shift = pass * RADIX_BITS;
        let (src, dst): (&[SortKey], &mut [SortKey]) =
            if in_keys { (&*keys, &mut *scratch) } else { (&*scratch, &mut *keys) };
        threads.for_each_chunk(&mut hists, 1, |c, h| {
            let h = &mut h[0];
            h.fill(0);
            for k in src.chunks(chunk_len).nth(c).unwrap_or(&[]) {
                h[((k.code >> shift) & MASK) as usize] += 1;
            }
        });
        // A pass where every key has the same digit would not move anything (the serial sort
        // skips it too; skipping is only faster, the order is the same either way).
        if (0..BUCKETS).any(|d| hists.iter().map(|h| h[d] as usize).sum::<usize>() == n) {
            continue;
        }
        let mut sum = 0u32;
        for d in 0..BUCKETS {
            for h in hists.iter_mut() {
                let c = h[d];
                h[d] = sum;
                sum += c;
            }
        }
        let out = SharedMut::new(dst);
        threads.for_each_chunk(&mut hists, 1, |c, h| {
            let offs = &mut h[0];
            for k in src.chunks(chunk_len).nth(c).unwrap_or(&[]) {
                let d = ((k.code >> shift) & MASK) as usize;
                // SAFETY: the prefix sums give every (digit, chunk) pair its own window of
                // `dst`, one slot per key counted, so each index is written exactly once by one
                // thread; `dst` outlives this scope and nobody reads it until the pass is over.
                unsafe { out.write(offs[d] as usize, *k) };
                offs[d] += 1;
            }
        });
        in_keys = !in_keys;
    }
    if !in_keys {
        keys.copy_from_slice(scratch);
    }
}
