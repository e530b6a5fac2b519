//! The fast paths of the compact frame codec (issue 16, speed): [`build_planes`] and
//! [`decode_body`] give exactly what `compact_frame::build_planes_reference` and
//! `compact_frame::decode_body_reference` give (the same body bytes, the same decoded frame,
//! the same errors; tested in `core/tests/compact_fast.rs` on random frames and bodies and in
//! `server/tests/compact_fast.rs` on the marcher's), in about half the time or less
//! (`docs/perf.md`, "Issue 16 (speed)").
//!
//! What makes them fast, and why the result cannot differ:
//!
//! * **Neighbours from the mask.** Which MED neighbours exist is read from the coverage mask
//!   (left: the previously visited pixel is `idx − 1` in the same row; up and upper-left: mask
//!   bits `idx − w` and `idx − w − 1`), and their values from two row buffers, so no per-column
//!   tags or saved cells are kept. The rule is the one of `docs/wire-format.md`; "left only" and
//!   "no neighbour" both predict the previously visited pixel's values, and a full MED is
//!   `clamp(a + b − c, min(a, b), max(a, b))` (the LOCO-I identity), computed without branches,
//!   for the four color channels at once in the 16-bit lanes of a `u64`.
//! * **Two passes.** The sequential part (prediction, which depends on the previous pixel) only
//!   produces depth codes and colors; the geometry (ray direction with its square root, the
//!   position along the ray, quantization, the radius model) runs afterwards as an independent
//!   map over the samples, written branch-free so the compiler vectorizes it. Every float
//!   operation is the reference's, in the reference's order (no fused multiply-add, `1/sqrt`
//!   not an approximate reciprocal, divisions kept as divisions), so every bit is the same.
//! * **Encoder.** One branch-free map projects every sample to its pixel and measures its depth
//!   and `dir · forward` (kept for the radius model, so the square root is taken once). Anything
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

/// MED of one channel with all three neighbours present.
#[inline(always)]
fn med3(a: i32, b: i32, c: i32) -> i32 {
    (a + b - c).clamp(a.min(b), a.max(b))
}

// Colors are predicted four channels at once, one per 16-bit lane of a `u64` ("spread" form:
// channel k in bits 16k..16k+8). Lanes never carry into each other: every intermediate value
// stays below 2^15.
const LANE_LOW: u64 = 0x00ff_00ff_00ff_00ff;
const LANE_HIGH: u64 = 0x8000_8000_8000_8000;
const LANE_BIAS: u64 = 0x0100_0100_0100_0100;

/// RGBA8 to spread form.
#[inline(always)]
fn spread(c: u32) -> u64 {
    let x = c as u64;
    let x = (x | x << 16) & 0x0000_ffff_0000_ffff;
    (x | x << 8) & LANE_LOW
}

/// Spread form (lanes < 256) back to RGBA8.
#[inline(always)]
fn unspread(x: u64) -> u32 {
    let x = (x | x >> 8) & 0x0000_ffff_0000_ffff;
    (x | x >> 16) as u32
}

/// All-ones in the lanes where `a ≥ b`.
#[inline(always)]
fn lanes_ge(a: u64, b: u64) -> u64 {
    ((((a | LANE_HIGH) - b) & LANE_HIGH) >> 15) * 0xffff
}

/// Per-lane minimum and maximum.
#[inline(always)]
fn lanes_min_max(a: u64, b: u64) -> (u64, u64) {
    let ge = lanes_ge(a, b);
    let x = (a ^ b) & ge;
    (a ^ x, b ^ x)
}

/// Per-lane MED with all three neighbours present: `clamp(a + b − c, min, max)`.
#[inline(always)]
fn med3_lanes(a: u64, b: u64, c: u64) -> u64 {
    let (lo, hi) = lanes_min_max(a, b);
    let x = a + b + LANE_BIAS - c;
    let (y, _) = lanes_min_max(x, hi + LANE_BIAS);
    let (_, z) = lanes_min_max(y, lo + LANE_BIAS);
    z - LANE_BIAS
}

/// Per-lane `(a + b) >> 1`.
#[inline(always)]
fn avg_lanes(a: u64, b: u64) -> u64 {
    ((a + b) >> 1) & LANE_LOW
}

/// Bit `j` of the coverage mask.
#[inline(always)]
fn bit(mask: &[u8], j: u64) -> bool {
    (mask[(j >> 3) as usize] >> (j & 7)) & 1 != 0
}

/// The MED context of the covered pixels, visited in pixel order: the previous and the current
/// row's depth codes and colors (valid where the mask has a bit), and the previously visited
/// pixel.
struct Rows {
    w: u64,
    prev_d: Vec<u16>,
    cur_d: Vec<u16>,
    prev_c: Vec<u64>,
    cur_c: Vec<u64>,
    last_d: u16,
    last_c: u64,
    last_idx: u64,
    y: u64,
    row_start: u64,
}

impl Rows {
    fn new(w: u32) -> Rows {
        Rows {
            w: w as u64,
            prev_d: vec![0; w as usize],
            cur_d: vec![0; w as usize],
            prev_c: vec![0; w as usize],
            cur_c: vec![0; w as usize],
            last_d: 0,
            last_c: 0,
            last_idx: u64::MAX,
            y: 0,
            row_start: 0,
        }
    }

    /// Moves to the row of pixel `idx` (≥ every pixel visited before) and returns its column.
    #[inline(always)]
    fn seek(&mut self, idx: u64) -> u64 {
        let mut x = idx - self.row_start;
        if x >= self.w {
            let dy = x / self.w;
            self.y += dy;
            self.row_start += dy * self.w;
            x -= dy * self.w;
            // The old current row becomes the previous one; when rows were skipped, the
            // previous row is empty and its values are never read.
            core::mem::swap(&mut self.prev_d, &mut self.cur_d);
            core::mem::swap(&mut self.prev_c, &mut self.cur_c);
        }
        x
    }

    /// The predicted depth code and color (spread form) of pixel `idx` at column `x` of the
    /// current row.
    #[inline(always)]
    fn predict(&self, mask: &[u8], idx: u64, x: u64) -> (u16, u64) {
        let xs = x as usize;
        let has_left = x > 0 && self.last_idx.wrapping_add(1) == idx;
        let has_up = self.y > 0 && bit(mask, idx - self.w);
        if has_up {
            let (bd, bc) = (self.prev_d[xs], self.prev_c[xs]);
            if has_left {
                let (ad, ac) = (self.last_d, self.last_c);
                if bit(mask, idx - self.w - 1) {
                    let (cd, cc) = (self.prev_d[xs - 1], self.prev_c[xs - 1]);
                    (med3(ad as i32, bd as i32, cd as i32) as u16, med3_lanes(ac, bc, cc))
                } else {
                    (((ad as u32 + bd as u32) >> 1) as u16, avg_lanes(ac, bc))
                }
            } else {
                (bd, bc)
            }
        } else if !has_left && x > 0 && self.y > 0 && bit(mask, idx - self.w - 1) {
            (self.prev_d[xs - 1], self.prev_c[xs - 1])
        } else {
            // Left only, or no neighbour at all: the previously visited pixel.
            (self.last_d, self.last_c)
        }
    }

    /// Records pixel `idx` (column `x`)'s true depth code and color (spread form).
    #[inline(always)]
    fn record(&mut self, idx: u64, x: u64, d: u16, c: u64) {
        self.cur_d[x as usize] = d;
        self.cur_c[x as usize] = c;
        self.last_d = d;
        self.last_c = c;
        self.last_idx = idx;
    }
}

// ---------------------------------------------------------------- decoding

/// Rebuilds the frame from the header, the parameters and the decompressed body: the fast
/// path of `compact_frame::decode_body_reference` (the same frame and the same errors).
pub(crate) fn decode_body(header: &FrameHeader, params: &CompactParams, body: &[u8]) -> Result<Frame, WireError> {
    // Pixel coordinates travel between the passes in 24 bits each (viewports that wide exist
    // only under custom limits; the reference decodes them).
    if header.camera.width >= 1 << 24 || header.camera.height >= 1 << 24 {
        return crate::compact_frame::decode_body_reference(header, params, body);
    }
    let mut samples = Vec::new();
    let mut colors = Vec::new();
    let (rlo, rhi) = decode_predicted(header, body, &mut samples, &mut colors)?;
    place(header, params, rlo, rhi, &mut samples);
    Ok(Frame { header: *header, samples, colors, segments: Vec::new() })
}

/// The sequential part of decoding: checks the mask and the radius residuals, undoes the
/// prediction into `colors` (final) and `samples` (each `depth code | x << 16 | y << 40`, for
/// [`place`]), and returns the radius residual planes.
#[inline(never)]
fn decode_predicted<'a>(
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
    let mut rows = Rows::new(w);
    let samples = &mut samples[..n];
    for i in 0..n {
        let idx = samples[i];
        let x = rows.seek(idx);
        let (pd, pc) = rows.predict(mask, idx, x);
        let code = pd.wrapping_add(dlo[i] as u16 | (dhi[i] as u16) << 8);
        let res = spread(u32::from_le_bytes([cr[i], cg[i], cb[i], ca[i]]));
        let c = (pc + res) & LANE_LOW;
        colors.push(unspread(c));
        samples[i] = code as u64 | x << 16 | rows.y << 40;
        rows.record(idx, x, code, c);
    }
    Ok((rlo, rhi))
}

/// The geometric part of decoding, a map over the samples: each `code | x << 16 | y << 40`
/// becomes the packed sample on pixel `(x, y)`'s ray at the code's depth, with the model's
/// radius code plus the residual.
#[inline(never)]
fn place(header: &FrameHeader, params: &CompactParams, rlo: &[u8], rhi: &[u8], samples: &mut [u64]) {
    let geo = Geo::new(header);
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
        pix: &mut [u64],
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
            pix[l] = yi[l] as u64 * self.columns + xi[l] as u64;
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
#[inline(never)]
pub(crate) fn build_planes(frame: &Frame, opts: &EncodeOptions) -> Result<Planes, EncodeError> {
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
    let w = cam.width;
    let geo = Geo::new(h);
    let deq = Dequantizer::new(h.bounds, h.radius_unit);
    let proj = Proj::new(cam, &deq);
    // Pass 1, a branch-free map: each sample's pixel, depth along that pixel's ray and
    // `dir · forward` (the reference's `Projector::pixel` and `RayBasis::dir`, op for op).
    let mut pix = vec![0u64; n];
    let mut depth = vec![0f32; n];
    let mut dfwd = vec![0f32; n];
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
    if !ok {
        return build_planes_reference(frame, opts);
    }
    let range = depth.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &t| (lo.min(t), hi.max(t)));
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
    {
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
    for &idx in &pix {
        mask[(idx >> 3) as usize] |= 1 << (idx & 7);
    }
    // Pass 3, sequential: the MED residuals of depth codes and colors.
    let mut rows = Rows::new(w);
    for i in 0..n {
        let idx = pix[i];
        let x = rows.seek(idx);
        let (pd, pc) = rows.predict(mask, idx, x);
        let dres = codes[i].wrapping_sub(pd);
        dlo[i] = dres as u8;
        dhi[i] = (dres >> 8) as u8;
        let c = spread(frame.colors[i]);
        let r = unspread((c + LANE_BIAS - pc) & LANE_LOW).to_le_bytes();
        cr[i] = r[0];
        cg[i] = r[1];
        cb[i] = r[2];
        ca[i] = r[3];
        rows.record(idx, x, codes[i], c);
    }
    Ok(Planes { params, body })
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
