//! The compact frame body's zstd encoder (feature `zstd-c`): our own parse, the C library's
//! entropy stage.
//!
//! A compact body is a coverage mask and residual planes (`docs/wire-format.md`). Its
//! redundancy is of two kinds: long runs of zeros (radius residuals are zero almost
//! everywhere, color and depth residuals in flat regions) and skewed small values (most
//! residuals are 0, ±1 or ±2). zstd's own match finder at level 1 finds a great many short
//! matches in such data and then spends most of its time coding them (`ZSTD_compressBlock_fast`
//! and `ZSTD_encodeSequences` led the profile; negative levels were no faster), while the
//! skewed residuals are exactly what its Huffman literal coder is for.
//!
//! So the encoder parses the body itself: every run of at least [`MIN_RUN`] zero bytes becomes
//! one zstd sequence (a literal zero, then a match at offset 1 for the rest of the run), and
//! everything else is left as literals; `ZSTD_compressSequences` then Huffman-codes the
//! literals and FSE-codes the few sequences. The result is an ordinary zstd frame (RFC 8878):
//! the decoders (C zstd, ruzstd) and the wire format do not change. On the MRI 1024² bench
//! frame it is about 2× faster to encode, 2.2× faster to decode and 9 % smaller than zstd
//! level 1 (`docs/perf.md`, "Issue 16: encode ≤ 8 ms, decode ≤ 5 ms").
//!
//! The zstd crates expose `ZSTD_compressSequences` only as the raw binding (`zstd-sys`, feature
//! `experimental`), hence the `unsafe` block in [`compress`]. The parse reads 64 bytes at a
//! time as a mask of their zero bytes (SSE2 on x86-64, a byte loop elsewhere).

use alloc::vec::Vec;

/// Zero runs shorter than this stay literals. On the MRI 1024² body 12–16 gave the smallest
/// frames (1.421–1.430 B/sample), and fewer, longer sequences decode faster, so 16.
pub const MIN_RUN: usize = 16;

/// One zstd sequence: `lit` literals, then `len` bytes copied from `1` byte back.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ZeroRun {
    /// Literal bytes before the run's first (literal) zero, that zero included.
    pub lit: u32,
    /// The rest of the run, copied from offset 1.
    pub len: u32,
}

/// The body's runs of at least [`MIN_RUN`] zeros as sequences, in order: a run at
/// `start..end` is the literal zero at `start` (ending the sequence's literals) and a match of
/// `end − start − 1` bytes at offset 1. Bytes not in a run are literals.
pub fn zero_run_sequences(body: &[u8]) -> Vec<ZeroRun> {
    // 64 bytes at a time as a mask of their zero bytes (bit i: byte i is 0). `run` counts the
    // zeros just before the current chunk; runs inside a chunk are found on its mask, most
    // chunks with a few operations and no branch taken.
    let mut out = Vec::new();
    // End of the last run emitted (the next sequence's literals start here).
    let mut lit_start = 0usize;
    let mut emit = |start: usize, end: usize, out: &mut Vec<ZeroRun>| {
        out.push(ZeroRun { lit: (start + 1 - lit_start) as u32, len: (end - start - 1) as u32 });
        lit_start = end;
    };
    let mut run = 0usize;
    let (chunks, tail) = body.as_chunks::<64>();
    for (ci, chunk) in chunks.iter().enumerate() {
        let base = 64 * ci;
        let z = zero_mask(chunk);
        if z == u64::MAX {
            run += 64;
            continue;
        }
        // The run reaching into this chunk ends at its first non-zero byte.
        let low = z.trailing_ones() as usize;
        if run + low >= MIN_RUN {
            emit(base - run, base + low, &mut out);
        }
        // Runs inside the chunk: bit i of `long` is set where 16 zeros start at byte i.
        let mut rest = z & (u64::MAX << low); // from the first non-zero byte on
        let top = z.leading_ones() as usize;
        // The run at the top of the chunk carries into the next one.
        rest &= if top == 0 { u64::MAX } else { !(u64::MAX << (64 - top)) };
        let mut long = rest;
        let mut span = 1;
        while span < MIN_RUN {
            long &= long >> span;
            span *= 2;
        }
        while long != 0 {
            let start = long.trailing_zeros() as usize;
            let len = (rest >> start).trailing_ones() as usize;
            emit(base + start, base + start + len, &mut out);
            let cleared = if start + len >= 64 { 0 } else { u64::MAX << (start + len) };
            long &= cleared;
            rest &= cleared;
        }
        run = top;
    }
    // The tail (fewer than 64 bytes), byte by byte.
    let base = 64 * chunks.len();
    let mut i = 0;
    while i < tail.len() {
        if tail[i] != 0 {
            if run >= MIN_RUN {
                emit(base + i - run, base + i, &mut out);
            }
            run = 0;
        } else {
            run += 1;
        }
        i += 1;
    }
    if run >= MIN_RUN {
        emit(base + tail.len() - run, base + tail.len(), &mut out);
    }
    out
}

/// Bit `i` set where byte `i` of the chunk is 0.
#[inline(always)]
fn zero_mask(chunk: &[u8; 64]) -> u64 {
    #[cfg(target_arch = "x86_64")]
    {
        use core::arch::x86_64::*;
        let mut m = 0u64;
        for q in 0..4 {
            // SAFETY: SSE2 is part of x86-64; the load reads 16 of the chunk's 64 bytes.
            let bits = unsafe {
                let v = _mm_loadu_si128(chunk.as_ptr().add(16 * q).cast());
                _mm_movemask_epi8(_mm_cmpeq_epi8(v, _mm_setzero_si128())) as u32 as u64
            };
            m |= bits << (16 * q);
        }
        m
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        chunk.iter().enumerate().fold(0u64, |m, (i, &b)| m | ((b == 0) as u64) << i)
    }
}

/// One zstd frame of `body` at entropy `level` with the sequences of [`zero_run_sequences`],
/// or `None` if the library refuses (only allocation failure should make it).
pub fn compress(body: &[u8], level: i32) -> Option<Vec<u8>> {
    let seqs: Vec<zstd_sys::ZSTD_Sequence> = zero_run_sequences(body)
        .into_iter()
        .map(|r| zstd_sys::ZSTD_Sequence { offset: 1, litLength: r.lit, matchLength: r.len, rep: 0 })
        .collect();
    let cap = zstd::zstd_safe::compress_bound(body.len());
    let mut dst: Vec<u8> = Vec::with_capacity(cap);
    // SAFETY: the context is created, used and freed here; `dst` has `cap` bytes of capacity
    // and the library writes at most `cap`, of which the returned length is initialized;
    // `seqs` and `body` are valid for their lengths. The library validates the sequences
    // (`ZSTD_c_validateSequences`): every match is at offset 1 after at least one literal, at
    // least `MIN_RUN − 1 ≥ 3` long (the minimum match set below), and all of them lie within
    // `body`.
    unsafe {
        use zstd_sys::ZSTD_cParameter as P;
        let cctx = zstd_sys::ZSTD_createCCtx();
        if cctx.is_null() {
            return None;
        }
        let mut ok =
            zstd_sys::ZSTD_isError(zstd_sys::ZSTD_CCtx_setParameter(cctx, P::ZSTD_c_compressionLevel, level)) == 0;
        ok &= zstd_sys::ZSTD_isError(zstd_sys::ZSTD_CCtx_setParameter(cctx, P::ZSTD_c_minMatch, 3)) == 0;
        // ZSTD_c_validateSequences (an experimental parameter, not named by the bindings).
        ok &= zstd_sys::ZSTD_isError(zstd_sys::ZSTD_CCtx_setParameter(cctx, P::ZSTD_c_experimentalParam12, 1)) == 0;
        let n = if ok {
            zstd_sys::ZSTD_compressSequences(
                cctx,
                dst.as_mut_ptr().cast(),
                cap,
                seqs.as_ptr(),
                seqs.len(),
                body.as_ptr().cast(),
                body.len(),
            )
        } else {
            usize::MAX
        };
        zstd_sys::ZSTD_freeCCtx(cctx);
        if !ok || zstd_sys::ZSTD_isError(n) != 0 {
            return None;
        }
        dst.set_len(n);
    }
    Some(dst)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The runs of at least MIN_RUN zeros, found byte by byte.
    fn reference(body: &[u8]) -> Vec<ZeroRun> {
        let mut out = Vec::new();
        let (mut i, mut lit_start) = (0, 0);
        while i < body.len() {
            if body[i] != 0 {
                i += 1;
                continue;
            }
            let mut j = i;
            while j < body.len() && body[j] == 0 {
                j += 1;
            }
            if j - i >= MIN_RUN {
                out.push(ZeroRun { lit: (i + 1 - lit_start) as u32, len: (j - i - 1) as u32 });
                lit_start = j;
            }
            i = j;
        }
        out
    }

    #[test]
    fn finds_the_runs_a_byte_scan_finds() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut rnd = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for case in 0..400 {
            let len = (rnd() % 700) as usize;
            let mut body = alloc::vec![0u8; len];
            // Runs of every length at every alignment, between random bytes.
            let mut i = 0;
            while i < len {
                let run = (rnd() % 40) as usize;
                let lit = (rnd() % 12) as usize;
                i += run;
                for b in body.iter_mut().skip(i).take(lit) {
                    *b = (rnd() % 4) as u8;
                }
                i += lit;
            }
            if case % 7 == 0 {
                body.iter_mut().for_each(|b| *b = 0);
            }
            assert_eq!(zero_run_sequences(&body), reference(&body), "case {case}: {body:?}");
        }
    }

    #[test]
    fn round_trips_through_both_decoders() {
        let mut body = alloc::vec![0u8; 300_000];
        for (i, b) in body.iter_mut().enumerate() {
            if (i / 97) % 3 != 0 {
                *b = ((i * 2654435761) >> 13) as u8 & 3;
            }
        }
        let coded = compress(&body, 1).expect("compresses");
        assert!(coded.len() < body.len() / 3);
        assert_eq!(zstd::bulk::decompress(&coded, body.len()).expect("C zstd"), body);
        // ruzstd with the window core's decoder allows (the body's length): the frame is
        // single-segment, its window its content.
        let mut dec = ruzstd::decoding::FrameDecoder::new();
        dec.set_max_window_size(body.len() as u64);
        let mut out = alloc::vec![0u8; body.len()];
        assert_eq!(dec.decode_all(&coded, &mut out).expect("ruzstd"), body.len());
        assert_eq!(out, body);
        // The empty body and one without runs are frames too.
        for b in [Vec::new(), (0..1000u32).map(|i| (i % 251 + 1) as u8).collect()] {
            assert_eq!(zstd::bulk::decompress(&compress(&b, 1).expect("compresses"), b.len()).unwrap(), b);
        }
    }
}
