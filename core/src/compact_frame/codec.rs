//! The compact frame codec: building a frame's wire planes and undoing them, encoding and
//! decoding compact frame bodies (the format's types and constants are the parent module's).

use super::*;
use crate::camera::{Camera, RayBasis};
use crate::sample::{Dequantizer, Quantizer, RADIUS_MAX};
use crate::wire::Frame;
use alloc::vec;
use alloc::vec::Vec;
use glam::Vec3;

impl RadiusPrediction {
    /// A guess for a frame whose radius model is not known: the constant of a frame whose
    /// samples all share one radius code, else the median radius per depth (codes off the
    /// guess cost a few bits each, never correctness).
    pub fn fit(frame: &Frame) -> RadiusPrediction {
        let deq = Dequantizer::new(frame.header.bounds, frame.header.radius_unit);
        let Some(&first) = frame.samples.first() else { return RadiusPrediction::default() };
        if frame.samples.iter().all(|&s| crate::sample::radius_code(s) == crate::sample::radius_code(first)) {
            return RadiusPrediction { constant: deq.radius(first), per_depth: 0.0 };
        }
        let (_, _, w) = frame.header.camera.basis();
        let eye = frame.header.camera.eye;
        let stride = (frame.samples.len() / 1024).max(1);
        let mut ratios: Vec<f32> = frame
            .samples
            .iter()
            .step_by(stride)
            .filter_map(|&s| {
                let z = (deq.center(s) - eye).dot(w);
                let r = deq.radius(s) / z;
                (z > 0.0 && r.is_finite()).then_some(r)
            })
            .collect();
        if ratios.is_empty() {
            return RadiusPrediction::default();
        }
        let mid = ratios.len() / 2;
        ratios.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
        RadiusPrediction { constant: 0.0, per_depth: ratios[mid] }
    }
}

/// MED with all three neighbours present.
#[inline(always)]
fn med3(a: i32, b: i32, c: i32) -> i32 {
    if c >= a.max(b) {
        a.min(b)
    } else if c <= a.min(b) {
        a.max(b)
    } else {
        a + b - c
    }
}

/// The MED (LOCO-I median edge detector) prediction from the left `a`, upper `b` and
/// upper-left `c` neighbours, each present or not; `last` when none is (the statement of
/// the rule in `docs/wire-format.md`; `Context::predict` computes it for all channels at once).
#[cfg(test)]
fn med(a: Option<i32>, b: Option<i32>, c: Option<i32>, last: i32) -> i32 {
    match (a, b, c) {
        (Some(a), Some(b), Some(c)) => {
            if c >= a.max(b) {
                a.min(b)
            } else if c <= a.min(b) {
                a.max(b)
            } else {
                a + b - c
            }
        }
        (Some(a), Some(b), None) => (a + b) >> 1,
        (Some(a), None, _) => a,
        (None, Some(b), _) => b,
        (None, None, Some(c)) => c,
        (None, None, None) => last,
    }
}

/// What the predictors remember of one column: the last covered pixel's values and the row
/// (+1) it was in.
#[derive(Clone, Copy, Default)]
struct Cell {
    tag: u32,
    depth: u16,
    color: [u8; 4],
}

/// The neighbour context of the pixels of one frame, visited in pixel order (covered pixels
/// only): predicts a pixel's depth code and color, then records its true values.
struct Context {
    cells: Vec<Cell>,
    width: u32,
    /// Row and column of the previously visited pixel.
    last_x: u32,
    last_y: u32,
    /// The cell of the previous pixel's column as it was before that pixel overwrote it.
    saved: Cell,
    last: Cell,
}

struct Prediction {
    depth: i32,
    color: [i32; 4],
}

impl Context {
    fn new(width: u32) -> Self {
        Context {
            cells: vec![Cell::default(); width as usize],
            width,
            last_x: u32::MAX,
            last_y: u32::MAX,
            saved: Cell::default(),
            last: Cell::default(),
        }
    }

    /// Predicts pixel `(x, y)` (the next covered pixel in pixel order).
    #[inline(always)]
    fn predict(&self, x: u32, y: u32) -> Prediction {
        let cells = &self.cells;
        let left = (x > 0 && self.last_y == y && self.last_x == x - 1).then(|| cells[x as usize - 1]);
        let up = cells[x as usize];
        let up = (up.tag == y && y > 0).then_some(up);
        let ul = if x > 0 && y > 0 {
            // The upper-left cell was overwritten in this row if the previous pixel was (x-1, y).
            let c = if left.is_some() { self.saved } else { cells[x as usize - 1] };
            (c.tag == y).then_some(c)
        } else {
            None
        };
        // Which neighbours exist is decided once per pixel, then every channel is
        // predicted the same way (the same values as `med` per channel).
        let v = |c: &Cell| [c.depth as i32, c.color[0] as i32, c.color[1] as i32, c.color[2] as i32, c.color[3] as i32];
        let p: [i32; 5] = match (left, up, ul) {
            (Some(a), Some(b), Some(c)) => {
                let (a, b, c) = (v(&a), v(&b), v(&c));
                core::array::from_fn(|k| med3(a[k], b[k], c[k]))
            }
            (Some(a), Some(b), None) => {
                let (a, b) = (v(&a), v(&b));
                core::array::from_fn(|k| (a[k] + b[k]) >> 1)
            }
            (Some(a), None, _) => v(&a),
            (None, Some(b), _) => v(&b),
            (None, None, Some(c)) => v(&c),
            (None, None, None) => v(&self.last),
        };
        let (depth, color) = (p[0], [p[1], p[2], p[3], p[4]]);
        Prediction { depth, color }
    }

    /// Records pixel `(x, y)`'s true values.
    #[inline(always)]
    fn record(&mut self, x: u32, y: u32, depth: u16, color: [u8; 4]) {
        let cell = Cell { tag: y + 1, depth, color };
        self.saved = self.cells[x as usize];
        self.cells[x as usize] = cell;
        self.last = cell;
        self.last_x = x;
        self.last_y = y;
        debug_assert!(x < self.width);
    }
}

/// The pieces of the decoded position and radius prediction of one frame.
struct Geometry {
    basis: RayBasis,
    eye: Vec3,
    forward: Vec3,
    quant: Quantizer,
}

impl Geometry {
    fn new(h: &FrameHeader) -> Self {
        let (_, _, forward) = h.camera.basis();
        let basis = h.camera.ray_basis();
        Geometry { eye: basis.origin(), basis, forward, quant: Quantizer::new(h.bounds, h.radius_unit) }
    }

    /// The radius code the model predicts for a sample at depth `t` along unit `d`.
    #[inline(always)]
    fn radius_code(&self, radius: &RadiusPrediction, d: Vec3, t: f32) -> u32 {
        self.quant.radius_code(radius.constant + radius.per_depth * (t * d.dot(self.forward)))
    }
}

// ---------------------------------------------------------------- encoding

/// Projects world points to pixels of a camera (the inverse of [`RayBasis::dir`], the same
/// arithmetic as [`Camera::project`] with the basis computed once).
struct Projector {
    eye: Vec3,
    u: Vec3,
    v: Vec3,
    w: Vec3,
    tan_x: f32,
    tan_y: f32,
    width: f32,
    height: f32,
}

impl Projector {
    fn new(c: &Camera) -> Self {
        let (u, v, w) = c.basis();
        let tan_y = crate::math::tan(c.fov_y_deg.to_radians() * 0.5);
        Projector {
            eye: c.eye,
            u,
            v,
            w,
            tan_x: tan_y * c.aspect(),
            tan_y,
            width: c.width as f32,
            height: c.height as f32,
        }
    }

    /// The pixel `(x, y)` the point projects into, if in the viewport and in front.
    #[inline(always)]
    fn pixel(&self, p: Vec3) -> Option<(u32, u32)> {
        let rel = p - self.eye;
        let z = rel.dot(self.w);
        if !(z > 1e-6) {
            return None;
        }
        let sx = rel.dot(self.u) / (z * self.tan_x);
        let sy = rel.dot(self.v) / (z * self.tan_y);
        let x = (sx + 1.0) * 0.5 * self.width;
        let y = (1.0 - sy) * 0.5 * self.height;
        if x >= 0.0 && y >= 0.0 && x < self.width && y < self.height {
            Some((x as u32, y as u32))
        } else {
            None
        }
    }
}

/// A frame taken apart for the compact form: its parameters and the uncompressed body (mask,
/// then the residual planes).
#[derive(Clone, Debug, PartialEq)]
pub struct Planes {
    /// The compact-specific header fields (`raw_len` = `body.len()`).
    pub params: CompactParams,
    /// Mask and residual planes, uncompressed.
    pub body: Vec<u8>,
}

/// Splits a frame into the compact form's mask and residual planes (everything but the
/// entropy coding). Samples must be one per pixel of the frame's camera, in pixel order.
/// The fast path (`core/src/compact_fast.rs`): the same planes, or the same error, as
/// [`build_planes_reference`].
pub fn build_planes(frame: &Frame, opts: &EncodeOptions) -> Result<Planes, EncodeError> {
    crate::compact_fast::build_planes(frame, opts)
}

/// [`build_planes`] without the CPU-specific kernels: the portable code that runs where
/// AVX2 is missing (and without std), callable everywhere so tests compare it with the
/// reference too.
#[doc(hidden)]
pub fn build_planes_portable(frame: &Frame, opts: &EncodeOptions) -> Result<Planes, EncodeError> {
    crate::compact_fast::build_planes_portable(frame, opts)
}

/// The parameters of a frame's planes from the depth range `(t_lo, t_hi)` of its samples
/// (ignored for an empty frame), with the mask's and the whole body's length in bytes. One
/// definition for the reference and the fast encoder (`compact_fast`), so both write the same
/// bytes.
pub(crate) fn frame_params(
    frame: &Frame,
    opts: &EncodeOptions,
    (t_lo, t_hi): (f32, f32),
) -> Result<(CompactParams, usize, usize), EncodeError> {
    let h = &frame.header;
    let n = frame.samples.len();
    let (t_lo, t_hi) = if n == 0 { (0.0, 0.0) } else { (t_lo, t_hi) };
    let ext = (h.bounds.max() - h.bounds.min()).max_element();
    let bits = opts.depth_bits.clamp(1, 16);
    let mut step = ext / (1u32 << bits) as f32;
    step = step.max((t_hi - t_lo) / DEPTH_CODE_MAX as f32);
    if !(step > 0.0 && step.is_finite()) {
        step = if (t_hi - t_lo) > 0.0 { (t_hi - t_lo) / DEPTH_CODE_MAX as f32 } else { 1.0 };
    }
    let radius = opts.radius.unwrap_or_else(|| RadiusPrediction::fit(frame));
    let mlen = mask_len(h.camera.width, h.camera.height) as usize;
    let raw_len = mlen + PLANE_BYTES_PER_SAMPLE * n;
    let mut params = CompactParams {
        depth_min: t_lo,
        depth_step: step,
        radius,
        coder: opts.coder,
        colors: ColorCoding::Plain,
        color_scale: [0; 3],
        raw_len: u32::try_from(raw_len).map_err(|_| EncodeError::DepthRange)?,
    };
    if !params_valid(&params) {
        // A step that makes the top code overflow, or a model that is not finite: no model.
        params.radius = RadiusPrediction::default();
        if !params_valid(&params) {
            return Err(EncodeError::DepthRange);
        }
    }
    Ok((params, mlen, raw_len))
}

/// The simple scalar form of [`build_planes`], one sample at a time (the oracle the fast
/// path is tested against).
pub fn build_planes_reference(frame: &Frame, opts: &EncodeOptions) -> Result<Planes, EncodeError> {
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
    let geo = Geometry::new(h);
    let proj = Projector::new(cam);
    let deq = Dequantizer::new(h.bounds, h.radius_unit);
    // Pass 1: every sample's pixel and depth along that pixel's ray.
    let mut pix = Vec::with_capacity(n);
    let mut depth = Vec::with_capacity(n);
    let (mut t_lo, mut t_hi) = (f32::INFINITY, f32::NEG_INFINITY);
    let mut next = 0u64;
    for (i, &s) in frame.samples.iter().enumerate() {
        let p = deq.center(s);
        let (x, y) = proj.pixel(p).ok_or(EncodeError::NotPixelAligned { index: i })?;
        let idx = y as u64 * w as u64 + x as u64;
        if idx < next {
            return Err(EncodeError::NotPixelAligned { index: i });
        }
        next = idx + 1;
        let t = (p - geo.eye).dot(geo.basis.dir(x, y));
        if !t.is_finite() {
            return Err(EncodeError::DepthRange);
        }
        t_lo = t_lo.min(t);
        t_hi = t_hi.max(t);
        pix.push((x, y));
        depth.push(t);
    }
    let (params, mlen, raw_len) = frame_params(frame, opts, (t_lo, t_hi))?;
    // Pass 2: the planes.
    let mut body = vec![0u8; raw_len];
    let (mask, planes) = body.split_at_mut(mlen);
    let (dlo, rest) = planes.split_at_mut(n);
    let (dhi, rest) = rest.split_at_mut(n);
    let (rlo, rest) = rest.split_at_mut(n);
    let (rhi, rest) = rest.split_at_mut(n);
    let (cr, rest) = rest.split_at_mut(n);
    let (cg, rest) = rest.split_at_mut(n);
    let (cb, ca) = rest.split_at_mut(n);
    let mut ctx = Context::new(w);
    for i in 0..n {
        let (x, y) = pix[i];
        let idx = y as usize * w as usize + x as usize;
        mask[idx >> 3] |= 1 << (idx & 7);
        let code =
            ((depth[i] - params.depth_min) / params.depth_step + 0.5).clamp(0.0, DEPTH_CODE_MAX as f32) as u32 as u16;
        let pred = ctx.predict(x, y);
        let dres = code.wrapping_sub(pred.depth as u16);
        dlo[i] = dres as u8;
        dhi[i] = (dres >> 8) as u8;
        let d = geo.basis.dir(x, y);
        let rpred = geo.radius_code(&params.radius, d, depth_of(&params, code as u32));
        let rcode = crate::sample::radius_code(frame.samples[i]);
        let rres = (rcode.wrapping_sub(rpred)) & RADIUS_MAX;
        rlo[i] = rres as u8;
        rhi[i] = (rres >> 8) as u8;
        let c = frame.colors[i].to_le_bytes();
        cr[i] = c[0].wrapping_sub(pred.color[0] as u8);
        cg[i] = c[1].wrapping_sub(pred.color[1] as u8);
        cb[i] = c[2].wrapping_sub(pred.color[2] as u8);
        ca[i] = c[3].wrapping_sub(pred.color[3] as u8);
        ctx.record(x, y, code, c);
    }
    Ok(Planes { params, body })
}

/// Entropy codes a body with `coder` (ruzstd's compressor for zstd).
pub fn compress(body: &[u8], coder: Coder) -> Vec<u8> {
    match coder {
        Coder::Stored => body.to_vec(),
        Coder::Zstd => ruzstd::encoding::compress_to_vec(body, ruzstd::encoding::CompressionLevel::Fastest),
    }
}

/// Entropy codes a body as one zstd frame with the C zstd library at entropy `level`, with
/// the body's runs of identical bytes as its only matches (`crate::byte_runs`: what
/// `volwarp-server` sends; faster both ways than the library's own match finder on residual
/// planes and smaller on most frames, and about 10× ruzstd's encoder's speed).
#[cfg(feature = "zstd-c")]
pub fn compress_c(body: &[u8], level: i32) -> Vec<u8> {
    // Only allocation failure can make the library fail on a buffer of its own bound.
    crate::byte_runs::compress(body, level)
        .or_else(|| zstd::bulk::compress(body, level).ok())
        .unwrap_or_else(|| compress(body, Coder::Zstd))
}

/// The whole CompactFrame message (12-byte header and payload) from the frame's header, the
/// parameters and the entropy-coded body.
pub fn assemble(header: &FrameHeader, params: &CompactParams, coded: &[u8]) -> Result<Vec<u8>, EncodeError> {
    let len = COMPACT_FIXED_LEN + coded.len();
    let len32 = u32::try_from(len).map_err(|_| EncodeError::DepthRange)?;
    let mut out = Vec::with_capacity(HEADER_LEN + len);
    out.extend_from_slice(&crate::wire::MAGIC);
    out.extend_from_slice(&crate::wire::VERSION.to_le_bytes());
    out.push(MsgType::CompactFrame as u8);
    out.push(0);
    out.extend_from_slice(&len32.to_le_bytes());
    out.extend_from_slice(&encode_frame_fixed(header));
    for v in [params.depth_min, params.depth_step, params.radius.constant, params.radius.per_depth] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    let [kr, kb, ka] = params.color_scale.map(|k| (k & 31) as u16);
    let scales = (kr | kb << 5 | ka << 10).to_le_bytes();
    out.extend_from_slice(&[params.coder as u8, params.colors as u8, scales[0], scales[1]]);
    out.extend_from_slice(&params.raw_len.to_le_bytes());
    out.extend_from_slice(coded);
    Ok(out)
}

/// The planes a frame is sent as: [`build_planes`], then, where the receiver reads it
/// (`opts.colors_against_green`), the colors coded against green where smaller
/// ([`code_colors`]). What every encoder entropy codes.
pub fn wire_planes(frame: &Frame, opts: &EncodeOptions) -> Result<Planes, EncodeError> {
    let mut planes = build_planes(frame, opts)?;
    if opts.colors_against_green {
        code_colors(&mut planes, frame.samples.len());
    }
    Ok(planes)
}

/// Encodes a frame as one CompactFrame message (header and payload). The frame's `count` is
/// taken from its samples.
pub fn encode(frame: &Frame, opts: &EncodeOptions) -> Result<Vec<u8>, EncodeError> {
    let planes = wire_planes(frame, opts)?;
    let coded = compress(&planes.body, planes.params.coder);
    let header = FrameHeader { count: frame.samples.len() as u32, ..frame.header };
    assemble(&header, &planes.params, &coded)
}

/// The message bytes of `frame` in `encoding` (header included). A frame the compact form
/// cannot hold ([`EncodeError`]) is sent in the 12-byte form, as a server does; the second
/// value says which form the bytes are in.
pub fn encode_frame(frame: &Frame, encoding: Encoding, opts: &EncodeOptions) -> (Vec<u8>, Encoding) {
    if encoding == Encoding::Compact {
        // A layered frame goes as one CompactFrame per layer.
        let layered = !frame.segments.is_empty();
        let compact = if layered { crate::segments::encode_layered(frame, opts) } else { encode(frame, opts) };
        if let Ok(b) = compact {
            return (b, Encoding::Compact);
        }
    }
    (crate::wire::encode_to_vec(&crate::wire::Message::Frame(frame.clone())), Encoding::Raw12)
}

/// The bytes `frame` takes on the wire in `encoding` (message header included) with core's
/// own encoder ([`encode_frame`]: ruzstd, `opts`). The bytes the server sends for its frames
/// (C zstd, the frame's radius model), which link models and the session simulator charge,
/// are `volwarp_server::encoding::encode_frame`'s.
pub fn encoded_size(frame: &Frame, encoding: Encoding, opts: &EncodeOptions) -> usize {
    match encoding {
        Encoding::Raw12 => {
            HEADER_LEN + FRAME_FIXED_LEN + frame.samples.len() * crate::wire::BYTES_PER_SAMPLE + frame.segments.len()
        }
        Encoding::Compact => encode_frame(frame, encoding, opts).0.len(),
    }
}

// ---------------------------------------------------------------- decoding

/// Decodes a CompactFrame payload (the bytes after the 12-byte message header) into an
/// ordinary frame. Allocates at most the payload's decompressed length (`⌈w·h/8⌉ + 8·count`,
/// both bounded by the validated header and `limits`), the 12 bytes per sample of the result,
/// and two rows of predictor state (at most `64 · (width + 1)` bytes).
pub fn decode_payload(payload: &[u8], limits: &Limits) -> Result<Frame, WireError> {
    let len = payload.len() as u32;
    let bad_len = WireError::BadLength { ty: MsgType::CompactFrame, len };
    if payload.len() < COMPACT_FIXED_LEN {
        return Err(bad_len);
    }
    let fixed: &[u8; FRAME_FIXED_LEN] = payload[..FRAME_FIXED_LEN].try_into().map_err(|_| bad_len)?;
    let header = decode_frame_fixed(fixed, limits)?;
    let cb: &[u8; 24] = payload[FRAME_FIXED_LEN..COMPACT_FIXED_LEN].try_into().map_err(|_| bad_len)?;
    let params = parse_params(cb, &header)?;
    let coded = &payload[COMPACT_FIXED_LEN..];
    let body = decompress_planes(coded, &params, header.count as usize)?;
    decode_body(&header, &params, &body)
}

/// Undoes the entropy coding into a buffer of exactly `params.raw_len` bytes: with the C
/// zstd library where the feature `zstd-c` is on (std clients; [`decompress_c`]), else with
/// ruzstd ([`decompress_ruzstd`]). Both give the same body for any frame both accept.
pub fn decompress(coded: &[u8], params: &CompactParams) -> Result<Vec<u8>, WireError> {
    #[cfg(feature = "zstd-c")]
    {
        decompress_c(coded, params)
    }
    #[cfg(not(feature = "zstd-c"))]
    {
        decompress_ruzstd(coded, params)
    }
}

/// The mask and residual planes of a CompactFrame of `n` samples from its entropy-coded
/// body: [`decompress`], then [`undo_color_coding`]. What every decoder reconstructs from.
pub fn decompress_planes(coded: &[u8], params: &CompactParams, n: usize) -> Result<Vec<u8>, WireError> {
    let mut body = decompress(coded, params)?;
    undo_color_coding(&mut body, params, n);
    Ok(body)
}

/// The color residual planes of a body of `n` samples: red, green, blue, alpha, `n` bytes
/// each, the body's last `4n` bytes (none if the body is shorter).
fn color_planes(body: &mut [u8], n: usize) -> Option<[&mut [u8]; 4]> {
    let at = body.len().checked_sub(n.checked_mul(4)?)?;
    let (r, rest) = body[at..].split_at_mut(n);
    let (g, rest) = rest.split_at_mut(n);
    let (b, a) = rest.split_at_mut(n);
    Some([r, g, b, a])
}

/// What channel residual `x` is coded against: green's residual `g` times `k`/8, rounded
/// (both read as signed steps), as a byte.
#[inline(always)]
fn scaled_green(g: u8, k: u8) -> u8 {
    ((g as i8 as i32 * k as i32 + 4).div_euclid(8)) as u8
}

/// Undoes [`ColorCoding::AgainstGreen`] on a decompressed body of `n` samples (nothing for
/// [`ColorCoding::Plain`]): red's, blue's and alpha's residuals plus green's times their
/// scales ([`CompactParams::color_scale`]), mod 256.
pub fn undo_color_coding(body: &mut [u8], params: &CompactParams, n: usize) {
    if params.colors != ColorCoding::AgainstGreen {
        return;
    }
    let [kr, kb, ka] = params.color_scale;
    if let Some([r, g, b, a]) = color_planes(body, n) {
        for (((r, &g), b), a) in r.iter_mut().zip(g.iter()).zip(b.iter_mut()).zip(a.iter_mut()) {
            *r = r.wrapping_add(scaled_green(g, kr));
            *b = b.wrapping_add(scaled_green(g, kb));
            *a = a.wrapping_add(scaled_green(g, ka));
        }
    }
}

/// Codes the color residual planes of `planes` (a frame of `n` samples) against green's
/// ([`ColorCoding::AgainstGreen`]) where that is smaller by a cheap estimate, and leaves them
/// plain otherwise; returns the coding chosen. Per channel (red, blue, alpha) the scale
/// `k`/8 is the least-squares fit of its residuals to green's (clamped to 0 … 31 eighths);
/// a channel keeps it only if it lowers the sum of its residuals' magnitudes (each byte read
/// as a signed step), else 0 (the channel as it is).
pub fn code_colors(planes: &mut Planes, n: usize) -> ColorCoding {
    let Some([r, g, b, a]) = color_planes(&mut planes.body, n) else { return ColorCoding::Plain };
    let s = |v: u8| v as i8 as i64;
    let gg: i64 = g.iter().map(|&v| s(v) * s(v)).sum();
    let mut scale = [0u8; 3];
    for (k, x) in scale.iter_mut().zip([&*r, &*b, &*a]) {
        if gg == 0 {
            break;
        }
        let xg: i64 = x.iter().zip(g.iter()).map(|(&x, &g)| s(x) * s(g)).sum();
        // (libm: no_std + alloc has no `f64::round`.)
        let fit = libm::round((8 * xg) as f64 / gg as f64).clamp(0.0, 31.0) as u8;
        let mag = |k: u8| -> u64 {
            x.iter()
                .zip(g.iter())
                .map(|(&x, &g)| (x.wrapping_sub(scaled_green(g, k)) as i8).unsigned_abs() as u64)
                .sum()
        };
        if fit > 0 && mag(fit) < mag(0) {
            *k = fit;
        }
    }
    if scale == [0; 3] {
        return ColorCoding::Plain;
    }
    let [kr, kb, ka] = scale;
    for (((r, &g), b), a) in r.iter_mut().zip(g.iter()).zip(b.iter_mut()).zip(a.iter_mut()) {
        *r = r.wrapping_sub(scaled_green(g, kr));
        *b = b.wrapping_sub(scaled_green(g, kb));
        *a = a.wrapping_sub(scaled_green(g, ka));
    }
    planes.params.colors = ColorCoding::AgainstGreen;
    planes.params.color_scale = scale;
    ColorCoding::AgainstGreen
}

/// [`decompress`] with the C zstd library: one zstd frame that fills a buffer of exactly
/// `params.raw_len` bytes, decoded in one call straight into it (no window buffer; the
/// library's own state is a fixed ~160 KiB decompression context, outside Rust's
/// allocator). Anything but exactly one frame whose stated content size (if any) is the
/// body length is refused before decoding.
#[cfg(feature = "zstd-c")]
pub fn decompress_c(coded: &[u8], params: &CompactParams) -> Result<Vec<u8>, WireError> {
    use zstd::zstd_safe;
    let raw_len = params.raw_len as usize;
    let corrupt = WireError::Compact(CompactError::Corrupt);
    if params.coder != Coder::Zstd {
        return decompress_ruzstd(coded, params);
    }
    if coded.is_empty() {
        return if raw_len == 0 { Ok(Vec::new()) } else { Err(corrupt) };
    }
    if zstd_safe::find_frame_compressed_size(coded) != Ok(coded.len()) {
        return Err(corrupt);
    }
    match zstd_safe::get_frame_content_size(coded) {
        Ok(Some(size)) if size != raw_len as u64 => return Err(corrupt),
        Ok(_) => {}
        Err(_) => return Err(corrupt),
    }
    let mut dctx = zstd_safe::DCtx::try_create().ok_or(corrupt)?;
    // zstd writes into the spare capacity (nothing is zeroed first) and sets the length.
    let mut body = Vec::with_capacity(raw_len);
    match dctx.decompress(&mut body, coded) {
        Ok(written) if written == raw_len => Ok(body),
        _ => Err(corrupt),
    }
}

/// [`decompress`] with ruzstd (pure Rust, no_std + alloc): decoded a step at a time into a
/// buffer of exactly `params.raw_len` bytes, the window capped at the body's length.
pub fn decompress_ruzstd(coded: &[u8], params: &CompactParams) -> Result<Vec<u8>, WireError> {
    let raw_len = params.raw_len as usize;
    let corrupt = WireError::Compact(CompactError::Corrupt);
    match params.coder {
        Coder::Stored => {
            if coded.len() != raw_len {
                return Err(corrupt);
            }
            Ok(coded.to_vec())
        }
        Coder::Zstd => {
            let mut body = vec![0u8; raw_len];
            if coded.is_empty() {
                return if raw_len == 0 { Ok(body) } else { Err(corrupt) };
            }
            use ruzstd::decoding::{BlockDecodingStrategy, FrameDecoder};
            use ruzstd::io::Read as _;
            let mut dec = FrameDecoder::new();
            // The window never needs to exceed the content (or ruzstd's encoder's fixed
            // 128 KiB); a frame that asks for more is refused before its buffers are
            // allocated.
            dec.set_max_window_size((raw_len as u64).max(MIN_ZSTD_WINDOW));
            let mut input = coded;
            dec.init(&mut input).map_err(|_| corrupt)?;
            // Decode a little at a time and drain into the body at once, so ruzstd's own
            // buffer never holds more than the window and one step: a body that would
            // decompress past the stated length is caught within a step, not after it.
            let mut written = 0;
            loop {
                dec.decode_blocks(&mut input, BlockDecodingStrategy::UptoBytes(DECODE_STEP)).map_err(|_| corrupt)?;
                written += dec.read(&mut body[written..]).map_err(|_| corrupt)?;
                if dec.can_collect() != 0 {
                    return Err(corrupt);
                }
                if dec.is_finished() {
                    break;
                }
            }
            if written != raw_len || !input.is_empty() {
                return Err(corrupt);
            }
            Ok(body)
        }
    }
}

/// Rebuilds the frame from the header, the parameters and the decompressed body. The fast
/// path (`core/src/compact_fast.rs`): the same frame, or the same error, as
/// [`decode_body_reference`].
pub fn decode_body(header: &FrameHeader, params: &CompactParams, body: &[u8]) -> Result<Frame, WireError> {
    crate::compact_fast::decode_body(header, params, body)
}

/// [`decode_body`] without the CPU-specific kernels (see [`build_planes_portable`]).
#[doc(hidden)]
pub fn decode_body_portable(header: &FrameHeader, params: &CompactParams, body: &[u8]) -> Result<Frame, WireError> {
    crate::compact_fast::decode_body_portable(header, params, body)
}

/// The simple scalar form of [`decode_body`], one sample at a time (the oracle the fast
/// path is tested against).
pub fn decode_body_reference(header: &FrameHeader, params: &CompactParams, body: &[u8]) -> Result<Frame, WireError> {
    let n = header.count as usize;
    let (w, h) = (header.camera.width, header.camera.height);
    let pixels = w as u64 * h as u64;
    let mlen = mask_len(w, h) as usize;
    if body.len() != mlen + PLANE_BYTES_PER_SAMPLE * n {
        return Err(WireError::Compact(CompactError::Corrupt));
    }
    let (mask, planes) = body.split_at(mlen);
    // Count first: nothing is built from an inconsistent mask.
    let mut ones = 0u64;
    for (i, &b) in mask.iter().enumerate() {
        let valid = pixels - (i as u64 * 8).min(pixels);
        let b = if valid < 8 {
            if b >> valid != 0 {
                return Err(WireError::Compact(CompactError::MaskCount { mask: u32::MAX, count: header.count }));
            }
            b
        } else {
            b
        };
        ones += b.count_ones() as u64;
    }
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
    let geo = Geometry::new(header);
    let mut samples = vec![0u64; n];
    let mut colors = vec![0u32; n];
    let mut ctx = Context::new(w);
    let mut i = 0usize;
    for (wi, chunk) in mask.chunks(8).enumerate() {
        let mut word = [0u8; 8];
        word[..chunk.len()].copy_from_slice(chunk);
        let mut bits = u64::from_le_bytes(word);
        while bits != 0 {
            let idx = wi as u64 * 64 + bits.trailing_zeros() as u64;
            bits &= bits - 1;
            let (x, y) = ((idx % w as u64) as u32, (idx / w as u64) as u32);
            let pred = ctx.predict(x, y);
            let code = (pred.depth as u16).wrapping_add(dlo[i] as u16 | (dhi[i] as u16) << 8);
            let rres = rlo[i] as u32 | (rhi[i] as u32) << 8;
            if rres > RADIUS_MAX {
                return Err(WireError::Compact(CompactError::BadRadiusResidual));
            }
            let d = geo.basis.dir(x, y);
            let t = depth_of(params, code as u32);
            let rcode = (geo.radius_code(&params.radius, d, t).wrapping_add(rres)) & RADIUS_MAX;
            let p = geo.eye + d * t;
            samples[i] = geo.quant.pack(p, 0.0) | (rcode as u64) << (3 * crate::sample::POS_BITS);
            let c = [
                (pred.color[0] as u8).wrapping_add(cr[i]),
                (pred.color[1] as u8).wrapping_add(cg[i]),
                (pred.color[2] as u8).wrapping_add(cb[i]),
                (pred.color[3] as u8).wrapping_add(ca[i]),
            ];
            colors[i] = u32::from_le_bytes(c);
            ctx.record(x, y, code, c);
            i += 1;
        }
    }
    debug_assert_eq!(i, n);
    Ok(Frame::new(*header, samples, colors))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_context_predicts_the_med_of_the_neighbours_that_exist() {
        // Pixel (1, 1) of a 3-wide frame under every pattern of present upper-left (0, 0),
        // upper (1, 0) and left (0, 1) neighbours, against `med` per channel.
        let vals = [(700u16, [10u8, 200, 30, 255]), (650, [40, 180, 90, 128]), (690, [25, 150, 60, 7])];
        for pattern in 0..8u32 {
            let mut ctx = Context::new(3);
            let mut cells: [Option<(u16, [u8; 4])>; 3] = [None; 3];
            for (k, &(x, y)) in [(0u32, 0u32), (1, 0), (0, 1)].iter().enumerate() {
                if pattern & (1 << k) != 0 {
                    ctx.record(x, y, vals[k].0, vals[k].1);
                    cells[k] = Some(vals[k]);
                }
            }
            let last = cells.iter().rev().flatten().next().copied().unwrap_or((0, [0; 4]));
            let p = ctx.predict(1, 1);
            let [ul, up, left] = cells;
            assert_eq!(
                p.depth,
                med(left.map(|c| c.0 as i32), up.map(|c| c.0 as i32), ul.map(|c| c.0 as i32), last.0 as i32),
                "pattern {pattern}"
            );
            for k in 0..4 {
                let ch = |c: Option<(u16, [u8; 4])>| c.map(|c| c.1[k] as i32);
                assert_eq!(p.color[k], med(ch(left), ch(up), ch(ul), last.1[k] as i32), "pattern {pattern}");
            }
        }
    }
}
