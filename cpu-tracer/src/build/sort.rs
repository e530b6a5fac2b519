//! The parallel stable LSD radix sorts of Morton keys: the same digits as core's serial
//! [`volwarp_core::morton::radix_sort`] ([`RADIX_BITS`] bits, [`RADIX_PASSES`] passes), each
//! pass split into contiguous chunks that count their digits in parallel, take a
//! digit-major/chunk-minor prefix sum, and scatter in parallel into disjoint slots. Each pass
//! is stable, so the result is ordered by `(code, index)` exactly like the serial sort.
//!
//! * [`par_radix_sort`] sorts 16-byte [`SortKey`]s, like core;
//! * [`par_sort_packed`] (what the builder uses, up to [`PACKED_MAX_LEN`] keys) sorts plain
//!   codes and moves only 8 bytes a key: its first pass sorts on the lowest digit and packs what
//!   the later passes still need — the code's other [`PACKED_CODE_BITS`] bits above the
//!   [`PACKED_INDEX_BITS`]-bit input index — into one `u64`. A pass whose digit is the same in
//!   every code (known from the OR and AND of all codes) is skipped without a histogram.

use crate::threads::Threads;
use volwarp_core::morton::{radix_sort, SortKey, CODE_BITS, RADIX_BITS, RADIX_PASSES};

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

/// Bits of the input index in a packed key (its low bits).
pub const PACKED_INDEX_BITS: u32 = 21;
/// Bits of the code in a packed key (its high bits): all but the first pass's digit.
pub const PACKED_CODE_BITS: u32 = CODE_BITS - RADIX_BITS;
/// The most codes [`par_sort_packed`] sorts.
pub const PACKED_MAX_LEN: usize = 1 << PACKED_INDEX_BITS;
const _: () = assert!(PACKED_CODE_BITS + PACKED_INDEX_BITS <= 64);

/// Chunks per thread of the packed sort's passes.
const CHUNKS_PER_THREAD: usize = 2;

/// The input index of a packed key.
#[inline(always)]
pub fn packed_index(key: u64) -> usize {
    (key & ((1 << PACKED_INDEX_BITS) - 1)) as usize
}

/// Sorts `codes` (Morton codes, below 2^[`CODE_BITS`]) by `(code, index)`, stably, into
/// packed keys: `out[k] = (codes[i] >> RADIX_BITS) << PACKED_INDEX_BITS | i` for the `k`-th
/// smallest `(codes[i], i)` (recover `i` with [`packed_index`], and the code as `codes[i]`).
/// `scratch` (at least as long) is the second buffer; the order is exactly
/// [`par_radix_sort`]'s, with 8 bytes moved a key instead of 16.
///
/// # Panics
/// If `out` or `scratch` is shorter than `codes`, or there are more than [`PACKED_MAX_LEN`].
pub fn par_sort_packed(codes: &[u64], out: &mut [u64], scratch: &mut [u64], threads: &Threads) {
    let n = codes.len();
    assert!(n <= PACKED_MAX_LEN, "{n} keys: at most {PACKED_MAX_LEN} can be packed");
    let (out, scratch) = (&mut out[..n], &mut scratch[..n]);
    let chunks = if threads.is_serial() || n < PARALLEL_MIN { 1 } else { threads.count() * CHUNKS_PER_THREAD };
    let chunk_len = n.div_ceil(chunks).max(1);
    let chunks = n.div_ceil(chunk_len);
    let mut hists = vec![([0u32; BUCKETS], 0u64, !0u64); chunks];
    // Pass 0, on the lowest digit, packs: it always runs (the order is the identity if the
    // digit is the same everywhere). Its histograms also give the OR and AND of all codes.
    threads.for_each_chunk(&mut hists, 1, |c, h| {
        let (h, or, and) = &mut h[0];
        h.fill(0);
        for &code in codes.chunks(chunk_len).nth(c).unwrap_or(&[]) {
            debug_assert!(code >> CODE_BITS == 0, "code {code:#x} has more than {CODE_BITS} bits");
            h[(code & MASK) as usize] += 1;
            *or |= code;
            *and &= code;
        }
    });
    let varying = hists.iter().fold(0, |v, h| v | h.1) ^ hists.iter().fold(!0, |v, h| v & h.2);
    scatter(
        codes,
        out,
        &mut hists,
        chunk_len,
        threads,
        |code| (code & MASK) as usize,
        |i, code| (code >> RADIX_BITS) << PACKED_INDEX_BITS | i as u64,
    );
    let mut in_out = true;
    for pass in 1..RADIX_PASSES {
        let shift = PACKED_INDEX_BITS + (pass - 1) * RADIX_BITS;
        if (varying >> (pass * RADIX_BITS)) & MASK == 0 {
            continue; // every code has the same digit: the pass would not move anything
        }
        let (src, dst): (&[u64], &mut [u64]) = if in_out { (&*out, &mut *scratch) } else { (&*scratch, &mut *out) };
        let digit = move |k: u64| ((k >> shift) & MASK) as usize;
        threads.for_each_chunk(&mut hists, 1, |c, h| {
            let h = &mut h[0].0;
            h.fill(0);
            for &k in src.chunks(chunk_len).nth(c).unwrap_or(&[]) {
                h[digit(k)] += 1;
            }
        });
        scatter(src, dst, &mut hists, chunk_len, threads, digit, |_, k| k);
        in_out = !in_out;
    }
    if !in_out {
        out.copy_from_slice(scratch);
    }
}

/// One stable scatter of `src` into `dst` by `digit`, writing `value(index, item)`, given
/// each chunk's digit counts in `hists` (which become its running offsets).
fn scatter<S: Copy + Sync>(
    src: &[S],
    dst: &mut [u64],
    hists: &mut [([u32; BUCKETS], u64, u64)],
    chunk_len: usize,
    threads: &Threads,
    digit: impl Fn(S) -> usize + Sync + Send,
    value: impl Fn(usize, S) -> u64 + Sync + Send,
) {
    let mut sum = 0u32;
    for d in 0..BUCKETS {
        for h in hists.iter_mut() {
            let c = h.0[d];
            h.0[d] = sum;
            sum += c;
        }
    }
    let out = SharedMut::new(dst);
    threads.for_each_chunk(hists, 1, |c, h| {
        let offs = &mut h[0].0;
        let start = c * chunk_len;
        for (i, &k) in src.chunks(chunk_len).nth(c).unwrap_or(&[]).iter().enumerate() {
            let d = digit(k);
            // SAFETY: the prefix sums give every (digit, chunk) pair its own window of `dst`,
            // one slot per item counted, so each index is written exactly once by one thread;
            // `dst` outlives this scope and nobody reads it until the pass is over.
            unsafe { out.write(offs[d] as usize, value(start + i, k)) };
            offs[d] += 1;
        }
    });
}
