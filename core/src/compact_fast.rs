//! The fast paths of the compact frame codec: [`build_planes`] and
//! [`decode_body`] give exactly what `compact_frame::build_planes_reference` and
//! `compact_frame::decode_body_reference` give (the same body bytes, the same decoded frame,
//! the same errors; tested in `core/tests/compact_fast.rs` on random frames and bodies and in
//! `server/tests/compact_fast.rs` on the marcher's), in about half the time or less
//! (`docs/perf.md`, "The compact codec").
//!
//! What makes them fast, and why the result cannot differ:
//!
//! * **Rows, not pixels.** The MED context is kept a row at a time. The encoder scatters a
//!   row's samples into row buffers (depth codes, RGBA8 words, coverage), predicts every pixel
//!   of the row at once with branch-free maps (colors byte by byte, which the compiler
//!   vectorizes) and gathers the residuals back in sample order. The decoder, whose prediction
//!   depends on the pixel just decoded, keeps the row above in buffers (one column longer than
//!   the row, so column 0 needs no test; the AVX2 decoder in tagged 32-byte cells) and carries
//!   the left neighbour in registers. The rule is the one of `docs/wire-format.md`; "left only"
//!   and "no neighbour" both predict the previously visited pixel, which is the previous sample;
//!   the MED is computed in its select form or as `max(min(a, b), min(max(a, b), a + b − c))` in
//!   32-bit lanes, both exact.
//! * **Passes.** The geometry (ray direction with its square root, the position along the
//!   ray, quantization, the radius model) runs as independent maps over the samples. Every
//!   float operation is the reference's, in the reference's order (no fused multiply-add,
//!   `1/sqrt` not an approximate reciprocal, divisions kept as divisions), so every bit is the
//!   same.
//! * **AVX2 where the CPU has it** (x86-64 with std, detected at run time): the same passes
//!   compiled for AVX2, and the hot ones written with intrinsics (`compact_fast/avx2.rs`):
//!   projection, depth and radius codes, the residual gather and the decoder's sequential loop.
//!   Elsewhere (no_std, other CPUs) the portable code runs; tests compare both with the
//!   references.
//! * **Encoder.** One map projects every sample to its pixel and measures its depth and
//!   `dir · forward` (kept for the radius model, so the square root is taken once). Anything
//!   unusual (a sample off its pixel, out of pixel order, a non-finite depth) hands the frame to
//!   the reference encoder, which returns its exact error.

use crate::compact_frame::{
    build_planes_reference, depth_of, frame_params, mask_len, CompactError, CompactParams, EncodeError, EncodeOptions,
    Planes, DEPTH_CODE_MAX, PLANE_BYTES_PER_SAMPLE,
};
use crate::math::sqrt;
use crate::sample::{Dequantizer, Quantizer, POS_BITS, POS_MAX, RADIUS_MAX};
use crate::wire::{Frame, FrameHeader, WireError};
use alloc::vec;
use alloc::vec::Vec;

#[cfg(all(feature = "std", target_arch = "x86_64"))]
mod avx2;

/// The geometry of one frame as plain floats: the ray basis, the view direction and the
/// quantizer.
#[derive(Clone, Copy)]
struct Geo {
    corner: [f32; 3],
    du: [f32; 3],
    dv: [f32; 3],
    eye: [f32; 3],
    forward: [f32; 3],
    qmin: [f32; 3],
    qscale: [f32; 3],
    radius_unit: f32,
}

impl Geo {
    fn new(h: &FrameHeader) -> Geo {
        let b = h.camera.ray_basis();
        let (_, _, fwd) = h.camera.basis();
        let q = Quantizer::new(h.bounds, h.radius_unit);
        Geo {
            corner: [b.corner[0], b.corner[1], b.corner[2]],
            du: [b.du[0], b.du[1], b.du[2]],
            dv: [b.dv[0], b.dv[1], b.dv[2]],
            eye: [b.eye[0], b.eye[1], b.eye[2]],
            forward: fwd.to_array(),
            qmin: q.min.to_array(),
            qscale: q.scale.to_array(),
            radius_unit: h.radius_unit,
        }
    }

    /// `RayBasis::dir(x, y)`, the same operations in the same order.
    #[inline(always)]
    fn dir(&self, x: u32, y: u32) -> [f32; 3] {
        let px = x as f32 + 0.5;
        let py = y as f32 + 0.5;
        let dx = self.corner[0] + self.du[0] * px + self.dv[0] * py;
        let dy = self.corner[1] + self.du[1] * px + self.dv[1] * py;
        let dz = self.corner[2] + self.du[2] * px + self.dv[2] * py;
        let inv = 1.0 / sqrt(dx * dx + dy * dy + dz * dz);
        [dx * inv, dy * inv, dz * inv]
    }
}

/// `v as u32` for `v` in `[0, 2²³)` (callers clamp first), in float operations the compiler
/// vectorizes (Rust's saturating `as` stays scalar on SSE2): `(v + 2²³) − 2²³` is `v` rounded
/// to the nearest integer, one less if that rounded up, and the integer is then the low
/// mantissa bits of itself + 2²³. Exact for every such `v` (tested against `as`).
#[inline(always)]
fn trunc_small(v: f32) -> u32 {
    const M: f32 = 8_388_608.0;
    let r = (v + M) - M;
    let t = if r > v { r - 1.0 } else { r };
    (t + M).to_bits() & 0x7f_ffff
}

#[inline(always)]
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The row of the samples from `i0` on (`key(i)`: sample `i`'s pixel index, increasing with
/// `i`; `n` samples, rows `w` pixels wide): its number, its first pixel index, and the end of
/// its samples.
#[inline(always)]
fn next_row(i0: usize, n: usize, w: u64, key: impl Fn(usize) -> u64) -> (u64, u64, usize) {
    let y = key(i0) / w;
    let row_start = y * w;
    let mut i1 = i0 + 1;
    while i1 < n && key(i1) < row_start + w {
        i1 += 1;
    }
    (y, row_start, i1)
}

// ---------------------------------------------------------------- decoding

/// Rebuilds the frame from the header, the parameters and the decompressed body: the fast
/// path of `compact_frame::decode_body_reference` (the same frame and the same errors).
pub(crate) fn decode_body(header: &FrameHeader, params: &CompactParams, body: &[u8]) -> Result<Frame, WireError> {
    #[cfg(all(feature = "std", target_arch = "x86_64"))]
    if volwarp_lanes::Avx2Token::new().is_some() {
        // SAFETY: the token proves the CPU has AVX2 (and the lane level allows it).
        return unsafe { decode_body_avx2(header, params, body) };
    }
    decode_body_lanes::<false>(header, params, body)
}

/// [`decode_body`] with the portable code only.
pub(crate) fn decode_body_portable(
    header: &FrameHeader,
    params: &CompactParams,
    body: &[u8],
) -> Result<Frame, WireError> {
    decode_body_lanes::<false>(header, params, body)
}

/// [`decode_body_lanes`] compiled for AVX2 (the lane maps then run 8 floats wide).
#[cfg(all(feature = "std", target_arch = "x86_64"))]
#[target_feature(enable = "avx2")]
fn decode_body_avx2(header: &FrameHeader, params: &CompactParams, body: &[u8]) -> Result<Frame, WireError> {
    decode_body_lanes::<true>(header, params, body)
}

/// The body of [`decode_body`], inlined into each instruction-set variant.
#[inline(always)]
fn decode_body_lanes<const AVX2: bool>(
    header: &FrameHeader,
    params: &CompactParams,
    body: &[u8],
) -> Result<Frame, WireError> {
    // Pixel coordinates travel between the passes in 24 bits each (viewports that wide exist
    // only under custom limits; the reference decodes them).
    if header.camera.width >= 1 << 24 || header.camera.height >= 1 << 24 {
        return crate::compact_frame::decode_body_reference(header, params, body);
    }
    let mut samples = Vec::new();
    let mut colors = Vec::new();
    let (rlo, rhi) = decode_predicted::<AVX2>(header, body, &mut samples, &mut colors)?;
    place::<AVX2>(header, params, rlo, rhi, &mut samples);
    Ok(Frame { header: *header, samples, colors, segments: Vec::new() })
}

/// The sequential part of decoding: checks the mask and the radius residuals, undoes the
/// prediction into `colors` (final) and `samples` (each `depth code | x << 16 | y << 40` for
/// [`place`]; the AVX2 decoder's own layout with `AVX2`), and returns the radius residual planes.
#[inline(always)]
fn decode_predicted<'a, const AVX2: bool>(
    header: &FrameHeader,
    body: &'a [u8],
    samples: &mut Vec<u64>,
    colors: &mut Vec<u32>,
) -> Result<(&'a [u8], &'a [u8]), WireError> {
    let n = header.count as usize;
    let (w, h) = (header.camera.width, header.camera.height);
    let pixels = w as u64 * h as u64;
    let mlen = mask_len(w, h) as usize;
    if body.len() != mlen + PLANE_BYTES_PER_SAMPLE * n {
        return Err(WireError::Compact(CompactError::Corrupt));
    }
    let (mask, planes) = body.split_at(mlen);
    // Count first: nothing is built from an inconsistent mask. Only the last byte can hold
    // bits past the last pixel.
    let tail = (pixels % 8) as u32;
    if tail != 0 && mask.last().is_some_and(|&b| b >> tail != 0) {
        return Err(WireError::Compact(CompactError::MaskCount { mask: u32::MAX, count: header.count }));
    }
    let ones: u64 = mask
        .chunks(8)
        .map(|c| {
            let mut word = [0u8; 8];
            word[..c.len()].copy_from_slice(c);
            u64::from_le_bytes(word).count_ones() as u64
        })
        .sum();
    if ones != n as u64 {
        return Err(WireError::Compact(CompactError::MaskCount {
            mask: ones.min(u32::MAX as u64) as u32,
            count: header.count,
        }));
    }
    let (dlo, rest) = planes.split_at(n);
    let (dhi, rest) = rest.split_at(n);
    let (rlo, rest) = rest.split_at(n);
    let (rhi, rest) = rest.split_at(n);
    let (cr, rest) = rest.split_at(n);
    let (cg, rest) = rest.split_at(n);
    let (cb, ca) = rest.split_at(n);
    // A residual above 10 bits is refused wherever it is (the reference refuses it at its
    // sample; no other error can come after the mask check, so the result is the same).
    if rhi.iter().fold(0u8, |m, &b| m | b) > (RADIUS_MAX >> 8) as u8 {
        return Err(WireError::Compact(CompactError::BadRadiusResidual));
    }
    // Filled by pushing, not zeroed first (the count was checked: exactly n pushes each).
    samples.clear();
    samples.reserve_exact(n);
    colors.clear();
    colors.reserve_exact(n);
    #[cfg(all(feature = "std", target_arch = "x86_64"))]
    if AVX2 {
        // SAFETY: only `decode_body_avx2` sets `AVX2`, on a CPU with AVX2.
        unsafe { avx2::undo_prediction(w, mask, n, samples, [dlo, dhi], [cr, cg, cb, ca], colors) };
        return Ok((rlo, rhi));
    }
    // The covered pixels' indices first, so the loop below runs over `0..n` with every plane
    // `n` long and no bounds to check.
    for (wi, chunk) in mask.chunks(8).enumerate() {
        let mut word = [0u8; 8];
        word[..chunk.len()].copy_from_slice(chunk);
        let mut bits = u64::from_le_bytes(word);
        while bits != 0 {
            samples.push(wi as u64 * 64 + bits.trailing_zeros() as u64);
            bits &= bits - 1;
        }
    }
    undo_prediction_by_row(w, &mut samples[..n], [dlo, dhi], [cr, cg, cb, ca], colors);
    Ok((rlo, rhi))
}

/// The sequential part of [`decode_predicted`], a row at a time: `samples` holds the covered
/// pixels' indices in order and gets `code | x << 16 | y << 40`; `colors` gets the colors.
///
/// The row above is kept in buffers one column longer than the row (cell `x + 1` holds column
/// `x`, cell 0 is never covered), so the upper-left neighbour needs no test for column 0. The
/// left neighbour, when it exists, and "the previously visited pixel" are both the previous
/// sample, whose values are carried in registers; the upper neighbours' values are read from
/// the buffers. Each channel's MED is `max(min(a, b), min(max(a, b), a + (b − c)))` (exact: the
/// channels are 8 bits and depth codes 16, computed in `i32`).
#[inline(always)]
fn undo_prediction_by_row(w: u32, samples: &mut [u64], d_res: [&[u8]; 2], c_res: [&[u8]; 4], colors: &mut Vec<u32>) {
    let n = samples.len();
    let [dlo, dhi] = d_res;
    let [cr, cg, cb, ca] = c_res;
    let (dlo, dhi, cr, cg, cb, ca) = (&dlo[..n], &dhi[..n], &cr[..n], &cg[..n], &cb[..n], &ca[..n]);
    let (w64, wu) = (w as u64, w as usize);
    let mut prev_d = vec![0u16; wu + 1];
    let mut cur_d = vec![0u16; wu + 1];
    let mut prev_c = vec![0u32; wu + 1];
    let mut cur_c = vec![0u32; wu + 1];
    let mut prev_m = vec![0u8; wu + 1];
    let mut cur_m = vec![0u8; wu + 1];
    // The previously visited pixel's depth code and channels.
    let mut last_d = 0i32;
    let mut last_c = [0i32; 4];
    let mut last_y = u64::MAX;
    let mut i0 = 0;
    while i0 < n {
        let (y, row_start, i1) = next_row(i0, n, w64, |i| samples[i]);
        core::mem::swap(&mut prev_d, &mut cur_d);
        core::mem::swap(&mut prev_c, &mut cur_c);
        core::mem::swap(&mut prev_m, &mut cur_m);
        if last_y.wrapping_add(1) != y {
            prev_m.fill(0);
        }
        cur_m.fill(0);
        // The previous sample's column in this row (none yet: a value no column follows).
        let mut left = u64::MAX - 1;
        for i in i0..i1 {
            let x = samples[i] - row_start;
            let xs = x as usize;
            // Cells: x + 1 is this column, x the one to the left (0: outside the row).
            let (hb, hc) = (prev_m[xs + 1] != 0, prev_m[xs] != 0);
            let ha = left.wrapping_add(1) == x;
            let (bd, cd) = (prev_d[xs + 1] as i32, prev_d[xs] as i32);
            let (bc, cc) = (prev_c[xs + 1].to_le_bytes(), prev_c[xs].to_le_bytes());
            let res_c = [cr[i], cg[i], cb[i], ca[i]];
            let dres = dlo[i] as u16 | (dhi[i] as u16) << 8;
            let (pd, pc) = if hb & ha & hc {
                let med = |a: i32, b: i32, c: i32| a.min(b).max(a.max(b).min(a + b - c));
                (med(last_d, bd, cd), core::array::from_fn(|k| med(last_c[k], bc[k] as i32, cc[k] as i32)))
            } else if hb & ha {
                ((last_d + bd) >> 1, core::array::from_fn(|k| (last_c[k] + bc[k] as i32) >> 1))
            } else if hb {
                (bd, bc.map(|v| v as i32))
            } else if !ha & hc {
                (cd, cc.map(|v| v as i32))
            } else {
                (last_d, last_c)
            };
            let code = (pd as u16).wrapping_add(dres);
            let c: [u8; 4] = core::array::from_fn(|k| (pc[k] as u8).wrapping_add(res_c[k]));
            let packed = u32::from_le_bytes(c);
            colors.push(packed);
            samples[i] = code as u64 | x << 16 | y << 40;
            cur_d[xs + 1] = code;
            cur_c[xs + 1] = packed;
            cur_m[xs + 1] = 1;
            last_d = code as i32;
            last_c = c.map(|v| v as i32);
            left = x;
        }
        last_y = y;
        i0 = i1;
    }
}

/// The geometric part of decoding, a map over the samples: each `code | x << 16 | y << 40` (with
/// `AVX2`, `avx2::undo_prediction`'s layout) becomes the packed sample on pixel `(x, y)`'s ray
/// at the code's depth, with the model's radius code plus the residual.
#[inline(always)]
fn place<const AVX2: bool>(header: &FrameHeader, params: &CompactParams, rlo: &[u8], rhi: &[u8], samples: &mut [u64]) {
    let geo = Geo::new(header);
    #[cfg(all(feature = "std", target_arch = "x86_64"))]
    if AVX2 {
        // SAFETY: only `decode_body_avx2` sets `AVX2`, on a CPU with AVX2.
        unsafe { avx2::place(&geo, params, rlo, rhi, samples) };
        return;
    }
    let mut s = samples.chunks_exact_mut(LANES);
    let mut lo = rlo.chunks_exact(LANES);
    let mut hi = rhi.chunks_exact(LANES);
    for ((s, lo), hi) in (&mut s).zip(&mut lo).zip(&mut hi) {
        place_lanes::<LANES>(&geo, params, lo, hi, s);
    }
    for ((s, &lo), &hi) in s.into_remainder().iter_mut().zip(lo.remainder()).zip(hi.remainder()) {
        place_lanes::<1>(&geo, params, &[lo], &[hi], core::slice::from_mut(s));
    }
}

/// Samples placed per step of [`place`]: the geometry is written lane by lane over arrays of
/// this many samples, which the compiler turns into vector instructions.
const LANES: usize = 8;

/// [`place`] for `L` samples (`s`, `lo`, `hi` are `L` long).
#[inline(always)]
fn place_lanes<const L: usize>(geo: &Geo, params: &CompactParams, lo: &[u8], hi: &[u8], s: &mut [u64]) {
    let (s, lo, hi) = (&mut s[..L], &lo[..L], &hi[..L]);
    let mut t = [0f32; L];
    let mut d = [[0f32; L]; 3];
    for l in 0..L {
        let v = s[l];
        let px = ((v >> 16) as u32 & 0xff_ffff) as f32 + 0.5;
        let py = (v >> 40) as u32 as f32 + 0.5;
        let dx = geo.corner[0] + geo.du[0] * px + geo.dv[0] * py;
        let dy = geo.corner[1] + geo.du[1] * px + geo.dv[1] * py;
        let dz = geo.corner[2] + geo.du[2] * px + geo.dv[2] * py;
        let inv = 1.0 / sqrt(dx * dx + dy * dy + dz * dz);
        d[0][l] = dx * inv;
        d[1][l] = dy * inv;
        d[2][l] = dz * inv;
        t[l] = depth_of(params, (v & 0xffff) as u32);
    }
    // Floats first, then conversions, then integers: each loop of one type, so the compiler
    // vectorizes each (a loop that mixes them stays scalar).
    let model = params.radius;
    let mut qf = [[0f32; L]; 3];
    let mut rf = [0f32; L];
    for l in 0..L {
        for k in 0..3 {
            let p = geo.eye[k] + d[k][l] * t[l];
            let f = (p - geo.qmin[k]) * geo.qscale[k] + 0.5;
            // `max` first: NaN goes to 0 as in the reference.
            qf[k][l] = f.max(0.0).min(POS_MAX as f32);
        }
        let dfwd = d[0][l] * geo.forward[0] + d[1][l] * geo.forward[1] + d[2][l] * geo.forward[2];
        let r = model.constant + model.per_depth * (t[l] * dfwd);
        let f = r / geo.radius_unit + 0.5;
        rf[l] = if r > 0.0 { f.max(1.0).min(RADIUS_MAX as f32) } else { 0.0 };
    }
    let mut qi = [[0u32; L]; 3];
    let mut ri = [0u32; L];
    for l in 0..L {
        for k in 0..3 {
            qi[k][l] = trunc_small(qf[k][l]);
        }
        ri[l] = trunc_small(rf[l]);
    }
    for l in 0..L {
        let rcode = ri[l].wrapping_add(lo[l] as u32 | (hi[l] as u32) << 8) & RADIUS_MAX;
        s[l] = qi[0][l] as u64
            | (qi[1][l] as u64) << POS_BITS
            | (qi[2][l] as u64) << (2 * POS_BITS)
            | (rcode as u64) << (3 * POS_BITS);
    }
}

// ---------------------------------------------------------------- encoding

/// The reference's `Projector` (world point to pixel) with the dequantizer, as plain floats.
struct Proj {
    u: [f32; 3],
    v: [f32; 3],
    w: [f32; 3],
    tan_x: f32,
    tan_y: f32,
    width: f32,
    height: f32,
    columns: u64,
    dmin: [f32; 3],
    dstep: [f32; 3],
}

impl Proj {
    fn new(cam: &crate::camera::Camera, deq: &Dequantizer) -> Proj {
        let (u, v, w) = cam.basis();
        let tan_y = crate::math::tan(cam.fov_y_deg.to_radians() * 0.5);
        Proj {
            u: u.to_array(),
            v: v.to_array(),
            w: w.to_array(),
            tan_x: tan_y * cam.aspect(),
            tan_y,
            width: cam.width as f32,
            height: cam.height as f32,
            columns: cam.width as u64,
            dmin: deq.min.to_array(),
            dstep: deq.step.to_array(),
        }
    }

    /// Pass 1 of [`build_planes`] for `L` samples: pixel index, depth along the pixel's ray
    /// and `dir · forward` of each; whether every sample projected into the viewport, in front,
    /// to a finite depth.
    #[inline(always)]
    fn project_lanes<const L: usize>(
        &self,
        geo: &Geo,
        s: &[u64],
        pix: &mut [u32],
        depth: &mut [f32],
        dfwd: &mut [f32],
    ) -> bool {
        let (s, pix, depth, dfwd) = (&s[..L], &mut pix[..L], &mut depth[..L], &mut dfwd[..L]);
        let mut rel = [[0f32; L]; 3];
        let mut xf = [0f32; L];
        let mut yf = [0f32; L];
        let mut inside = [false; L];
        for l in 0..L {
            let (qx, qy, qz) = crate::sample::unpack_position(s[l]);
            let q = [qx as f32, qy as f32, qz as f32];
            for k in 0..3 {
                rel[k][l] = (self.dmin[k] + q[k] * self.dstep[k]) - geo.eye[k];
            }
            let r = [rel[0][l], rel[1][l], rel[2][l]];
            let z = dot(r, self.w);
            let sx = dot(r, self.u) / (z * self.tan_x);
            let sy = dot(r, self.v) / (z * self.tan_y);
            xf[l] = (sx + 1.0) * 0.5 * self.width;
            yf[l] = (1.0 - sy) * 0.5 * self.height;
            inside[l] = z > 1e-6 && xf[l] >= 0.0 && yf[l] >= 0.0 && xf[l] < self.width && yf[l] < self.height;
        }
        // Inside the viewport `as i32` truncates as the reference's `as u32`; outside, the
        // value is never used (the reference encoder takes over).
        let mut xi = [0i32; L];
        let mut yi = [0i32; L];
        for l in 0..L {
            xi[l] = xf[l].max(0.0).min(self.width) as i32;
            yi[l] = yf[l].max(0.0).min(self.height) as i32;
        }
        let mut ok = true;
        for l in 0..L {
            let d = geo.dir(xi[l] as u32, yi[l] as u32);
            let r = [rel[0][l], rel[1][l], rel[2][l]];
            let t = dot(r, d);
            ok &= inside[l] & t.is_finite();
            // Below 2^32: `build_planes` checks `w · h` first.
            pix[l] = (yi[l] as u64 * self.columns + xi[l] as u64) as u32;
            depth[l] = t;
            dfwd[l] = dot(d, geo.forward);
        }
        ok
    }
}

/// Pass 2 of [`build_planes`] for `L` samples: depth codes and radius residuals (a map,
/// written type by type so the compiler vectorizes it).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn code_lanes<const L: usize>(
    geo: &Geo,
    params: &CompactParams,
    s: &[u64],
    t: &[f32],
    f: &[f32],
    codes: &mut [u16],
    rlo: &mut [u8],
    rhi: &mut [u8],
) {
    let (s, t, f, codes, rlo, rhi) = (&s[..L], &t[..L], &f[..L], &mut codes[..L], &mut rlo[..L], &mut rhi[..L]);
    // The reference's `clamp(0, 65535) as u32`: `max` first sends NaN to 0 as it does.
    let mut ci = [0u32; L];
    for l in 0..L {
        ci[l] = trunc_small(((t[l] - params.depth_min) / params.depth_step + 0.5).max(0.0).min(DEPTH_CODE_MAX as f32));
    }
    let model = params.radius;
    let mut rf = [0f32; L];
    for l in 0..L {
        let td = depth_of(params, ci[l]);
        let r = model.constant + model.per_depth * (td * f[l]);
        let x = r / geo.radius_unit + 0.5;
        rf[l] = if r > 0.0 { x.max(1.0).min(RADIUS_MAX as f32) } else { 0.0 };
    }
    for l in 0..L {
        codes[l] = ci[l] as u16;
        let rres = crate::sample::radius_code(s[l]).wrapping_sub(trunc_small(rf[l])) & RADIUS_MAX;
        rlo[l] = rres as u8;
        rhi[l] = (rres >> 8) as u8;
    }
}

/// Splits a frame into the compact form's mask and residual planes: the fast path of
/// `compact_frame::build_planes_reference` (the same planes, or the reference's error).
pub(crate) fn build_planes(frame: &Frame, opts: &EncodeOptions) -> Result<Planes, EncodeError> {
    #[cfg(all(feature = "std", target_arch = "x86_64"))]
    if volwarp_lanes::Avx2Token::new().is_some() {
        // SAFETY: the token proves the CPU has AVX2 (and the lane level allows it).
        return unsafe { build_planes_avx2(frame, opts) };
    }
    build_planes_lanes::<false>(frame, opts)
}

/// [`build_planes`] with the portable code only.
pub(crate) fn build_planes_portable(frame: &Frame, opts: &EncodeOptions) -> Result<Planes, EncodeError> {
    build_planes_lanes::<false>(frame, opts)
}

/// [`build_planes_lanes`] compiled for AVX2 (the lane maps then run 8 floats wide).
#[cfg(all(feature = "std", target_arch = "x86_64"))]
#[target_feature(enable = "avx2")]
fn build_planes_avx2(frame: &Frame, opts: &EncodeOptions) -> Result<Planes, EncodeError> {
    build_planes_lanes::<true>(frame, opts)
}

/// The body of [`build_planes`], inlined into each instruction-set variant.
#[inline(always)]
fn build_planes_lanes<const AVX2: bool>(frame: &Frame, opts: &EncodeOptions) -> Result<Planes, EncodeError> {
    let h = &frame.header;
    let cam = &h.camera;
    let n = frame.samples.len();
    if frame.colors.len() != n
        || cam.validate(u32::MAX).is_err()
        || !h.bounds.is_valid()
        || !(h.radius_unit > 0.0 && (h.radius_unit * RADIUS_MAX as f32).is_finite())
        || n > cam.width as usize * cam.height as usize
    {
        return Err(EncodeError::BadFrame);
    }
    if cam.width as u64 * cam.height as u64 > 1 << 32 {
        // Pixel indices travel in 32 bits here (such viewports exist only under custom
        // limits; the reference encodes them).
        return build_planes_reference(frame, opts);
    }
    let w = cam.width;
    let geo = Geo::new(h);
    let deq = Dequantizer::new(h.bounds, h.radius_unit);
    let proj = Proj::new(cam, &deq);
    // Pass 1, a branch-free map: each sample's pixel, depth along that pixel's ray and
    // `dir · forward` (the reference's `Projector::pixel` and `RayBasis::dir`, op for op).
    let mut pix = vec![0u32; n];
    let mut depth = vec![0f32; n];
    let mut dfwd = vec![0f32; n];
    let mut range = None;
    #[cfg(all(feature = "std", target_arch = "x86_64"))]
    if AVX2 {
        // SAFETY: only `build_planes_avx2` sets `AVX2`, on a CPU with AVX2.
        range = unsafe { avx2::project(&proj, &geo, &frame.samples, &mut pix, &mut depth, &mut dfwd) };
    }
    if !AVX2 {
        let mut ok = true;
        let mut s = frame.samples.chunks_exact(LANES);
        let mut px = pix.chunks_exact_mut(LANES);
        let mut t = depth.chunks_exact_mut(LANES);
        let mut f = dfwd.chunks_exact_mut(LANES);
        for (((s, px), t), f) in (&mut s).zip(&mut px).zip(&mut t).zip(&mut f) {
            ok &= proj.project_lanes::<LANES>(&geo, s, px, t, f);
        }
        let (s, px, t, f) = (s.remainder(), px.into_remainder(), t.into_remainder(), f.into_remainder());
        for k in 0..s.len() {
            ok &= proj.project_lanes::<1>(&geo, &s[k..], &mut px[k..], &mut t[k..], &mut f[k..]);
        }
        // Strictly increasing pixels (one sample per pixel, in pixel order).
        ok &= pix.windows(2).all(|p| p[0] < p[1]);
        range =
            ok.then(|| depth.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &t| (lo.min(t), hi.max(t))));
    }
    let Some(range) = range else {
        return build_planes_reference(frame, opts);
    };
    let (params, mlen, raw_len) = frame_params(frame, opts, range)?;
    // Pass 2, a map: depth codes and radius residuals (neither depends on a neighbour).
    let mut codes = vec![0u16; n];
    let mut body = vec![0u8; raw_len];
    let (mask, planes) = body.split_at_mut(mlen);
    let (dlo, rest) = planes.split_at_mut(n);
    let (dhi, rest) = rest.split_at_mut(n);
    let (rlo, rest) = rest.split_at_mut(n);
    let (rhi, rest) = rest.split_at_mut(n);
    let (cr, rest) = rest.split_at_mut(n);
    let (cg, rest) = rest.split_at_mut(n);
    let (cb, ca) = rest.split_at_mut(n);
    #[cfg(all(feature = "std", target_arch = "x86_64"))]
    if AVX2 {
        // SAFETY: only `build_planes_avx2` sets `AVX2`, on a CPU with AVX2.
        unsafe { avx2::code(&geo, &params, &frame.samples, &depth, &dfwd, &mut codes, rlo, rhi) };
    }
    if !AVX2 {
        let mut it = frame
            .samples
            .chunks_exact(LANES)
            .zip(depth.chunks_exact(LANES))
            .zip(dfwd.chunks_exact(LANES))
            .zip(codes.chunks_exact_mut(LANES))
            .zip(rlo.chunks_exact_mut(LANES).zip(rhi.chunks_exact_mut(LANES)));
        for ((((s, t), f), c), (lo, hi)) in &mut it {
            code_lanes::<LANES>(&geo, &params, s, t, f, c, lo, hi);
        }
        let k = n - n % LANES;
        for i in k..n {
            let (lo, hi) = (&mut rlo[i..], &mut rhi[i..]);
            code_lanes::<1>(&geo, &params, &frame.samples[i..], &depth[i..], &dfwd[i..], &mut codes[i..], lo, hi);
        }
    }
    // Pass 3, row by row: the MED residuals of depth codes and colors.
    residuals_by_row::<AVX2>(w, &pix, &codes, &frame.colors, mask, [dlo, dhi], [cr, cg, cb, ca]);
    Ok(Planes { params, body })
}

/// One image row of the encoder's MED context: depth codes, colors (RGBA8) and coverage
/// (`0x0101_0101` where the pixel has a sample, one 1 per channel byte; other cells hold stale
/// values that are never used).
struct RowPlanes {
    d: Vec<u16>,
    c: Vec<u32>,
    m: Vec<u32>,
}

impl RowPlanes {
    fn new(w: usize) -> RowPlanes {
        // One depth cell more than the row: the AVX2 gather of a 16-bit cell reads two.
        RowPlanes { d: vec![0; w + 1], c: vec![0; w], m: vec![0; w] }
    }
}

/// Coverage of a pixel in [`RowPlanes::m`].
const COVERED4: u32 = 0x0101_0101;

/// LOCO-I's MED of one value with all three neighbours present, in the select form that is
/// exact in wrapping arithmetic (`a + b − c` lies between `a` and `b` when it is chosen).
macro_rules! med_select {
    ($a:expr, $b:expr, $c:expr) => {{
        let (a, b, c) = ($a, $b, $c);
        let (mn, mx) = (a.min(b), a.max(b));
        if c >= mx {
            mn
        } else if c <= mn {
            mx
        } else {
            a.wrapping_add(b).wrapping_sub(c)
        }
    }};
}

/// One prediction plane of [`predict_row`]: `out[j]` from the left (`a`, `cur[j − s]`), upper
/// (`b`, `prev[j]`) and upper-left (`c`, `prev[j − s]`) cells, whose coverage is in `cm` /
/// `pm` at the same indices, for `j ≥ s` (`s` cells per pixel).
macro_rules! predict_plane {
    ($out:expr, $cur:expr, $prev:expr, $cm:expr, $pm:expr, $s:expr) => {{
        let (s, len) = ($s, $out.len());
        let (a, b, c) = (&$cur[..len - s], &$prev[s..], &$prev[..len - s]);
        let (ha, hb, hc) = (&$cm[..len - s], &$pm[s..], &$pm[..len - s]);
        let it = $out[s..].iter_mut().zip(a).zip(b).zip(c).zip(ha).zip(hb).zip(hc);
        for ((((((o, &a), &b), &c), &ha), &hb), &hc) in it {
            let med = med_select!(a, b, c);
            let avg = (a >> 1) + (b >> 1) + (a & b & 1);
            let both = if hc != 0 { med } else { avg };
            let up = if ha != 0 { both } else { b };
            *o = if hb != 0 { up } else { c };
        }
    }};
}

/// The prediction of every pixel of a row whose true values are known (`cur`, the encoder's
/// case) from that row and the one above (`prev`, coverage 0 where that row is empty or does
/// not exist): `out` gets the predicted depth code and color, and `out.m[x]` is non-zero where
/// the rule predicts the previously visited pixel (left only, or no neighbour), which the
/// caller takes from the previous sample. Branch-free maps over the row (colors byte by byte),
/// which the compiler vectorizes.
#[inline(always)]
fn predict_row(prev: &RowPlanes, cur: &RowPlanes, out: &mut RowPlanes) {
    let w = out.m.len();
    if w == 0 {
        return;
    }
    // Column 0: no left or upper-left neighbour.
    out.m[0] = if prev.m[0] == 0 { COVERED4 } else { 0 };
    out.d[0] = prev.d[0];
    out.c[0] = prev.c[0];
    let it = out.m[1..].iter_mut().zip(&cur.m[..w - 1]).zip(&prev.m[1..]).zip(&prev.m[..w - 1]);
    for (((o, &ha), &hb), &hc) in it {
        *o = if (hb == 0) & ((ha != 0) | (hc == 0)) { COVERED4 } else { 0 };
    }
    predict_plane!(out.d, cur.d, prev.d, cur.m, prev.m, 1);
    let (cm, pm): (&[u8], &[u8]) = (bytemuck::cast_slice(&cur.m), bytemuck::cast_slice(&prev.m));
    let (cc, pc): (&[u8], &[u8]) = (bytemuck::cast_slice(&cur.c), bytemuck::cast_slice(&prev.c));
    let oc: &mut [u8] = bytemuck::cast_slice_mut(out.c.as_mut_slice());
    predict_plane!(oc, cc, pc, cm, pm, 4);
    // Column 0's color was set above (bytes 0..4 are not written by the plane).
}

/// Per-byte `a − b` (mod 256) of two RGBA8 words.
#[inline(always)]
fn sub_bytes(a: u32, b: u32) -> u32 {
    const H: u32 = 0x8080_8080;
    ((a | H).wrapping_sub(b & !H)) ^ ((a ^ !b) & H)
}

/// Pass 3 of [`build_planes`]: the MED residuals of depth codes and colors, a row at a time.
/// The samples of a row are scattered into row buffers, every pixel's prediction is computed
/// as maps over the row ([`predict_row`]), and the residuals are gathered back in sample order.
/// "The previously visited pixel" of the rule is the previous sample.
#[inline(always)]
fn residuals_by_row<const AVX2: bool>(
    w: u32,
    pix: &[u32],
    codes: &[u16],
    colors: &[u32],
    mask: &mut [u8],
    d_out: [&mut [u8]; 2],
    c_out: [&mut [u8]; 4],
) {
    let n = pix.len();
    let (codes, colors) = (&codes[..n], &colors[..n]);
    let [dlo, dhi] = d_out;
    let [cr, cg, cb, ca] = c_out;
    let (dlo, dhi, cr, cg, cb, ca) =
        (&mut dlo[..n], &mut dhi[..n], &mut cr[..n], &mut cg[..n], &mut cb[..n], &mut ca[..n]);
    let (w64, wu) = (w as u64, w as usize);
    let mut prev = RowPlanes::new(wu);
    let mut cur = RowPlanes::new(wu);
    let mut pred = RowPlanes::new(wu);
    let mut last_y = u64::MAX;
    let mut i0 = 0;
    while i0 < n {
        let (y, row_start, i1) = next_row(i0, n, w64, |i| pix[i] as u64);
        core::mem::swap(&mut prev, &mut cur);
        if last_y.wrapping_add(1) != y {
            // The row above has no samples (or this is the first row).
            prev.m.fill(0);
        }
        cur.m.fill(0);
        for i in i0..i1 {
            let x = (pix[i] as u64 - row_start) as usize;
            cur.d[x] = codes[i];
            cur.c[x] = colors[i];
            cur.m[x] = COVERED4;
        }
        // The row's coverage bits: whole bytes from the row's flags where rows start on a
        // byte, else bit by bit.
        if wu % 8 == 0 {
            let bytes = &mut mask[(row_start / 8) as usize..][..wu / 8];
            for (b, f) in bytes.iter_mut().zip(cur.m.chunks_exact(8)) {
                *b = f.iter().enumerate().fold(0, |acc, (k, &m)| acc | ((m & 1) as u8) << k);
            }
        } else {
            for &p in &pix[i0..i1] {
                mask[(p >> 3) as usize] |= 1 << (p & 7);
            }
        }
        predict_row(&prev, &cur, &mut pred);
        // The samples the AVX2 gather leaves (all of them without it).
        #[cfg(all(feature = "std", target_arch = "x86_64"))]
        let first = if AVX2 && i0 >= 1 {
            // SAFETY: only `build_planes_avx2` sets `AVX2`, on a CPU with AVX2.
            unsafe {
                avx2::gather_row(
                    pix,
                    row_start as u32,
                    i0..i1,
                    codes,
                    colors,
                    (&pred.d, &pred.c, &pred.m),
                    [&mut *dlo, &mut *dhi],
                    [&mut *cr, &mut *cg, &mut *cb, &mut *ca],
                )
            }
        } else {
            i0
        };
        #[cfg(not(all(feature = "std", target_arch = "x86_64")))]
        let first = i0;
        for i in first..i1 {
            let x = (pix[i] as u64 - row_start) as usize;
            let (pd, pc) = if pred.m[x] != 0 {
                // The previous sample (none before the first: zeros).
                match i.checked_sub(1) {
                    Some(j) => (codes[j], colors[j]),
                    None => (0, 0),
                }
            } else {
                (pred.d[x], pred.c[x])
            };
            let dres = codes[i].wrapping_sub(pd);
            dlo[i] = dres as u8;
            dhi[i] = (dres >> 8) as u8;
            let r = sub_bytes(colors[i], pc).to_le_bytes();
            cr[i] = r[0];
            cg[i] = r[1];
            cb[i] = r[2];
            ca[i] = r[3];
        }
        last_y = y;
        i0 = i1;
    }
}

#[cfg(test)]
mod tests {
    use super::trunc_small;

    #[test]
    fn trunc_small_is_as_u32_below_2_pow_23() {
        let mut v = 0.0f32;
        while v < 300_000.0 {
            for x in [v, f32::from_bits(v.to_bits() + 1), v + 0.5, v + 0.25, v + 0.75, v + 0.999] {
                assert_eq!(trunc_small(x), x as u32, "{x}");
            }
            v += 1.0;
        }
        for x in [0.0, 1e-30, 0.49999997, 0.5, 0.50000006, 8_388_606.5, 8_388_607.0] {
            assert_eq!(trunc_small(x), x as u32, "{x}");
        }
        // Every float in [0, 2^23) with a fractional part near .5 or .0, across all exponents.
        let mut bits = 0u32;
        while f32::from_bits(bits) < 8_388_608.0 {
            let x = f32::from_bits(bits);
            assert_eq!(trunc_small(x), x as u32, "{x}");
            bits += 4093;
        }
    }
}
