//! The compact frame body's zstd encoder (feature `zstd-c`): our own parse, the C library's
//! entropy stage.
//!
//! A compact body is a coverage mask and residual planes (`docs/wire-format.md`). Its
//! redundancy is of two kinds: long runs of one byte value (radius residuals are zero almost
//! everywhere, color and depth residuals in flat regions, the mask 0x00 or 0xff over empty and
//! covered stretches) and skewed small values (most residuals are 0, ±1 or ±2). zstd's own
//! match finder at level 1 finds a great many short matches in such data and then spends most
//! of its time coding them (`ZSTD_compressBlock_fast` and `ZSTD_encodeSequences` led the
//! profile; negative levels were no faster), while the skewed residuals are exactly what its
//! Huffman literal coder is for.
//!
//! So the encoder parses the body itself: every run of at least [`MIN_RUN`] identical bytes
//! becomes one zstd sequence (the run's first byte as a literal, then a match at offset 1 for
//! the rest), and everything else is left as literals; `ZSTD_compressSequences` then
//! Huffman-codes the literals and FSE-codes the few sequences. The result is an ordinary zstd
//! frame (RFC 8878): the decoders (C zstd, ruzstd) and the wire format do not change. On the
//! MRI 1024² bench frame it is about 2.4× faster to encode, 2.2× faster to decode and 10 %
//! smaller than zstd level 1 (`docs/perf.md`, "The compact codec").
//!
//! The zstd crates expose `ZSTD_compressSequences` only as the raw binding (`zstd-sys`, feature
//! `experimental`), hence the `unsafe` block in [`compress`]. The parse reads 64 bytes at a
//! time as a mask of the bytes equal to the one before (SSE2 on x86-64, a byte loop
//! elsewhere).

use alloc::vec::Vec;

/// Runs of identical bytes shorter than this stay literals. On the MRI 1024² body 12–16 gave
/// the smallest frames, and fewer, longer sequences decode faster, so 16.
pub const MIN_RUN: usize = 16;

/// One zstd sequence: `lit` literals, then `len` bytes copied from `1` byte back.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Run {
    /// Literal bytes before the run's first byte, that byte included.
    pub lit: u32,
    /// The rest of the run, copied from offset 1.
    pub len: u32,
}

/// The body's runs of at least [`MIN_RUN`] identical bytes as sequences, in order: a run at
/// `start..end` is the literal byte at `start` (ending the sequence's literals) and a match of
/// `end − start − 1` bytes at offset 1. Bytes not in a run are literals.
pub fn run_sequences(body: &[u8]) -> Vec<Run> {
    // A run of identical bytes `start..end` is a run of "repeat" bits `start + 1..end` (bit i:
    // byte i equals byte i − 1), found 64 bytes at a time on their repeat mask. `run` counts
    // the repeat bits just before the current chunk; runs inside a chunk are found on its
    // mask, most chunks with a few operations and no branch taken.
    const REPEATS: usize = MIN_RUN - 1;
    let mut out = Vec::new();
    // End of the last run emitted (the next sequence's literals start here).
    let mut lit_start = 0usize;
    let mut emit = |start: usize, end: usize, out: &mut Vec<Run>| {
        out.push(Run { lit: (start + 1 - lit_start) as u32, len: (end - start - 1) as u32 });
        lit_start = end;
    };
    let mut run = 0usize;
    let whole = body.len() / 64 * 64;
    for base in (0..whole).step_by(64) {
        let z = repeat_mask(body, base);
        if z == u64::MAX {
            run += 64;
            continue;
        }
        // The run reaching into this chunk ends at its first byte that differs.
        let low = z.trailing_ones() as usize;
        if run + low >= REPEATS {
            emit(base - run - 1, base + low, &mut out);
        }
        // Runs inside the chunk: bit i of `long` is set where `REPEATS` repeat bits start.
        let mut rest = z & (u64::MAX << low); // from the first differing byte on
        let top = z.leading_ones() as usize;
        // The run at the top of the chunk carries into the next one.
        rest &= if top == 0 { u64::MAX } else { !(u64::MAX << (64 - top)) };
        let mut long = rest;
        let mut have = 1;
        while have * 2 <= REPEATS {
            long &= long >> have;
            have *= 2;
        }
        if have < REPEATS {
            long &= long >> (REPEATS - have);
        }
        while long != 0 {
            let start = long.trailing_zeros() as usize;
            let len = (rest >> start).trailing_ones() as usize;
            emit(base + start - 1, base + start + len, &mut out);
            let cleared = if start + len >= 64 { 0 } else { u64::MAX << (start + len) };
            long &= cleared;
            rest &= cleared;
        }
        run = top;
    }
    // The tail (fewer than 64 bytes), byte by byte.
    for j in whole..body.len() {
        if j == 0 || body[j] != body[j - 1] {
            if run >= REPEATS {
                emit(j - run - 1, j, &mut out);
            }
            run = 0;
        } else {
            run += 1;
        }
    }
    if run >= REPEATS {
        emit(body.len() - run - 1, body.len(), &mut out);
    }
    out
}

/// Bit `i` set where byte `base + i` equals the byte before it (never for byte 0).
#[inline(always)]
fn repeat_mask(body: &[u8], base: usize) -> u64 {
    #[cfg(target_arch = "x86_64")]
    if base > 0 {
        use core::arch::x86_64::*;
        let mut m = 0u64;
        for q in 0..4 {
            // SAFETY: bytes base - 1 .. base + 64 lie in `body` (base ≥ 64, a whole chunk follows).
            let bits = unsafe {
                let p = body.as_ptr().add(base + 16 * q);
                let v = _mm_loadu_si128(p.cast());
                let u = _mm_loadu_si128(p.sub(1).cast());
                _mm_movemask_epi8(_mm_cmpeq_epi8(v, u)) as u32 as u64
            };
            m |= bits << (16 * q);
        }
        return m;
    }
    (0..64).fold(0u64, |m, i| m | ((base + i > 0 && body[base + i] == body[base + i - 1]) as u64) << i)
}

/// One zstd frame of `body` at entropy `level` with the sequences of [`run_sequences`],
/// or `None` if the library refuses (only allocation failure should make it).
pub fn compress(body: &[u8], level: i32) -> Option<Vec<u8>> {
    let seqs: Vec<zstd_sys::ZSTD_Sequence> = run_sequences(body)
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

    /// The runs of at least MIN_RUN identical bytes, found byte by byte.
    fn reference(body: &[u8]) -> Vec<Run> {
        let mut out = Vec::new();
        let (mut i, mut lit_start) = (0, 0);
        while i < body.len() {
            let mut j = i;
            while j < body.len() && body[j] == body[i] {
                j += 1;
            }
            if j - i >= MIN_RUN {
                out.push(Run { lit: (i + 1 - lit_start) as u32, len: (j - i - 1) as u32 });
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
            // Runs of every length at every alignment (of zeros, 0xff or another value, some
            // back to back), between random bytes.
            let mut i = 0;
            while i < len {
                let run = (rnd() % 40) as usize;
                let value = [0u8, 0xff, rnd() as u8][(rnd() % 3) as usize];
                let lit = (rnd() % 12) as usize;
                for b in body.iter_mut().skip(i).take(run) {
                    *b = value;
                }
                i += run;
                for b in body.iter_mut().skip(i).take(lit) {
                    *b = (rnd() % 4) as u8;
                }
                i += lit;
            }
            if case % 7 == 0 {
                body.iter_mut().for_each(|b| *b = 0);
            }
            assert_eq!(run_sequences(&body), reference(&body), "case {case}: {body:?}");
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
