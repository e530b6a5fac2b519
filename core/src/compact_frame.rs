//! The compact frame encoding (feature `alloc`): a Frame in about 3 bytes per sample instead of
//! 12, documented byte by byte in `docs/wire-format.md` (message type 6, `CompactFrame`).
//!
//! Every sample of a server frame came from one pixel of the camera that travels with the
//! frame, so the compact form sends what the client cannot derive itself:
//!
//! * a **coverage mask** of the pixels that have a sample (one bit per pixel, row-major);
//! * each sample's **depth along its pixel's ray**, quantized to a step of the largest bounds
//!   extent / 2¹² (`EncodeOptions::depth_bits`; the bits study in `docs/results.md` found 10 bits
//!   per axis indistinguishable from floats at 512² and 1024², so 12 keeps a 4× margin), coded
//!   as the residual from the MED (LOCO-I) prediction of the left, upper and upper-left
//!   neighbour's depth codes;
//! * each sample's **radius code as the residual from the radius model** (`constant +
//!   per_depth × z` at the decoded depth; the server's default footprint model and the voxel
//!   model are both of this form), so only samples off the model cost anything;
//! * each **color as the per-channel residual from the MED prediction** of the neighbours'
//!   colors (lossless).
//!
//! The mask and the residual planes go through one zstd frame (decoded by `ruzstd`, pure Rust,
//! no_std + alloc). The decoded sample sits on its pixel's ray ([`crate::RayBasis::dir`]) at the
//! dequantized depth and is quantized again to the usual packed `u64`, so a decoded compact
//! frame is an ordinary [`Frame`](crate::wire::Frame) (same sample order: pixel order) and every
//! renderer works unchanged. Colors and radius codes round-trip exactly; positions move by at most
//! [`position_bound`] from the 12-byte form's.
//!
//! **Bounded decoding.** Every size the decoder allocates follows from the header after it was
//! validated (viewport ≤ the limits, sample count ≤ pixels and ≤ the limits): the decompressed
//! length must equal `⌈w·h/8⌉ + 8·count` exactly (stated in the header and checked before
//! decompressing), zstd writes into a buffer of exactly that size (`TargetTooSmall` otherwise)
//! with its window capped at that size (or [`MIN_ZSTD_WINDOW`], whichever is larger), drained
//! every [`DECODE_STEP`] bytes, so no input can make it allocate more than
//! [`decode_alloc_bound`].

use crate::sample::Dequantizer;
use crate::wire::{decode_frame_fixed, FrameHeader, Limits, MsgType, WireError, FRAME_FIXED_LEN};
#[cfg(feature = "alloc")]
use crate::wire::{encode_frame_fixed, HEADER_LEN};
pub use crate::wire::{CompactError, COMPACT_FIXED_LEN};

/// The zstd window a decoder allows even for a body shorter than it (ruzstd's encoder always
/// declares 128 KiB); otherwise the window may not exceed the body.
pub const MIN_ZSTD_WINDOW: u64 = 128 << 10;
/// Bytes ruzstd decodes per step before they are drained into the body.
pub const DECODE_STEP: usize = 64 << 10;
/// Default depth precision: the depth step is the largest bounds extent / 2^this.
pub const DEFAULT_DEPTH_BITS: u32 = 12;
/// Largest depth code (depth codes are `u16`).
pub const DEPTH_CODE_MAX: u32 = u16::MAX as u32;
/// Bytes per sample in the decompressed body: depth residual (2), radius residual (2), color
/// residual (4).
pub const PLANE_BYTES_PER_SAMPLE: usize = 8;

/// How the body is entropy coded.
#[repr(u8)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Coder {
    /// The body is stored as is (for tests and debugging).
    Stored = 0,
    /// One zstd frame.
    Zstd = 1,
}

impl Coder {
    /// The coder with this code.
    pub fn from_code(c: u8) -> Option<Coder> {
        match c {
            0 => Some(Coder::Stored),
            1 => Some(Coder::Zstd),
            _ => None,
        }
    }
}

/// Why a frame could not be put in compact form (the sender then sends the 12-byte form).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EncodeError {
    /// Sample `index` does not project into its own pixel of the frame's camera after the
    /// previous sample's (samples must come one per pixel, in pixel order, as a server's do).
    NotPixelAligned {
        /// The sample.
        index: usize,
    },
    /// The depths of the frame do not fit the depth code (more than 2¹⁶ steps, or not finite).
    DepthRange,
    /// The frame's own header is invalid (camera, bounds or radius unit), or samples and colors
    /// differ in length.
    BadFrame,
}

impl core::fmt::Display for EncodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            EncodeError::NotPixelAligned { index } => {
                write!(f, "sample {index} is not on its own pixel's ray of the frame's camera")
            }
            EncodeError::DepthRange => f.write_str("frame depths do not fit the depth code"),
            EncodeError::BadFrame => f.write_str("invalid frame header"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for EncodeError {}

/// The radius every sample is predicted to have: `constant + per_depth × z`, `z` the sample's
/// distance along the camera's view direction (what `volwarp-server`'s radius models produce).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RadiusPrediction {
    /// World radius at any depth.
    pub constant: f32,
    /// World radius per unit of depth along the view direction.
    pub per_depth: f32,
}

/// How the color residual planes are coded (byte 113 of a CompactFrame).
#[repr(u8)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ColorCoding {
    /// Each channel's residual as it is.
    Plain = 0,
    /// Green's residual as it is; red's, blue's and alpha's minus green's times a scale per
    /// channel ([`CompactParams::color_scale`], in eighths), mod 256: the channels of a transfer
    /// function with one hue move together, so their residuals do too (LOCO-I's modular color
    /// transform on the residuals, with a gain). Only sent to receivers that announced
    /// [`crate::wire::CAP_COLOR_GREEN`].
    AgainstGreen = 1,
}

impl ColorCoding {
    /// The coding with wire code `c`.
    pub fn from_code(c: u8) -> Option<ColorCoding> {
        match c {
            0 => Some(ColorCoding::Plain),
            1 => Some(ColorCoding::AgainstGreen),
            _ => None,
        }
    }
}

/// Encoder settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EncodeOptions {
    /// Depth step = largest bounds extent / 2^`depth_bits` (1..=16; default
    /// [`DEFAULT_DEPTH_BITS`]). A frame whose depth range needs more than 2¹⁶ such steps gets a
    /// coarser step (range / 65535).
    pub depth_bits: u32,
    /// The radius model to code radii against; `None` fits one ([`RadiusPrediction::fit`]).
    pub radius: Option<RadiusPrediction>,
    /// Entropy coder of the body.
    pub coder: Coder,
    /// Whether the receiver reads [`ColorCoding::AgainstGreen`] (it announced
    /// [`crate::wire::CAP_COLOR_GREEN`]): then [`code_colors`] takes it where it is smaller.
    pub colors_against_green: bool,
}

impl Default for EncodeOptions {
    fn default() -> Self {
        EncodeOptions { depth_bits: DEFAULT_DEPTH_BITS, radius: None, coder: Coder::Zstd, colors_against_green: false }
    }
}

/// The compact-specific fields of a CompactFrame (after the Frame's fixed 96 bytes).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CompactParams {
    /// Depth (ray parameter) of depth code 0.
    pub depth_min: f32,
    /// Depth per code step (> 0).
    pub depth_step: f32,
    /// The radius model radii are coded against.
    pub radius: RadiusPrediction,
    /// Entropy coder of the body.
    pub coder: Coder,
    /// How the color residual planes are coded.
    pub colors: ColorCoding,
    /// With [`ColorCoding::AgainstGreen`]: red's, blue's and alpha's scale of green's
    /// residual, in eighths (0 … 31; 0: that channel as it is); zero otherwise. Bytes 114–115:
    /// red in bits 0–4, blue in bits 5–9, alpha in bits 10–14, bit 15 zero.
    pub color_scale: [u8; 3],
    /// Decompressed body length: `⌈w·h/8⌉ + 8·count`.
    pub raw_len: u32,
}

/// Largest distance between a sample's center decoded from the compact form and from the
/// 12-byte form it was encoded from: half a depth step along the ray, the 12-byte form's own
/// rounding (up to half a quantum per axis) twice, and f32 rounding of `eye + dir · depth`.
pub fn position_bound(header: &FrameHeader, params: &CompactParams) -> f32 {
    let deq = Dequantizer::new(header.bounds, header.radius_unit);
    let q = deq.step.length();
    let far = params.depth_min.abs() + params.depth_step * DEPTH_CODE_MAX as f32;
    let scale = header.camera.eye.abs().max_element() + far + header.bounds.max().abs().max_element();
    0.5 * params.depth_step + q + 8.0 * f32::EPSILON * scale
}

// ---------------------------------------------------------------- shared by both sides

/// The depth of a code.
#[inline(always)]
pub(crate) fn depth_of(params: &CompactParams, code: u32) -> f32 {
    params.depth_min + code as f32 * params.depth_step
}

/// The most bytes one `wire::read_message` may allocate under `limits` when the message is a
/// CompactFrame: the payload, the decompressed body (mask and 8 bytes per sample), the
/// frame's 12 bytes per sample, two rows of predictor state (at most 64 bytes per column: the
/// AVX2 decoder's 32-byte cells, one column more than the row), and
/// ruzstd's buffers (a window of at most max(body, [`MIN_ZSTD_WINDOW`]), one [`DECODE_STEP`],
/// one 128 KiB block and its tables; with the feature `zstd-c` the C library instead holds a
/// fixed ~160 KiB context, outside Rust's allocator). The fuzz targets check every decode
/// against it.
pub fn decode_alloc_bound(limits: &Limits) -> u64 {
    let samples = limits.max_samples as u64;
    let vp = limits.max_viewport as u64;
    let body = (vp * vp).div_ceil(8) + PLANE_BYTES_PER_SAMPLE as u64 * samples;
    limits.max_payload as u64
        + body
        + 12 * samples
        + 64 * (vp + 1)
        + body.max(MIN_ZSTD_WINDOW)
        + DECODE_STEP as u64
        + (256 << 10)
}

/// Bytes of the coverage mask of a `w × h` viewport.
#[inline]
pub fn mask_len(width: u32, height: u32) -> u64 {
    (width as u64 * height as u64).div_ceil(8)
}

#[cfg(feature = "alloc")]
pub(crate) fn params_valid(p: &CompactParams) -> bool {
    p.depth_min.is_finite()
        && p.depth_step > 0.0
        && p.depth_step.is_finite()
        && depth_of(p, DEPTH_CODE_MAX).is_finite()
        && p.radius.constant.is_finite()
        && p.radius.per_depth.is_finite()
}

/// The wire encodings of a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Encoding {
    /// Message type 3: 12 bytes per sample.
    Raw12,
    /// Message type 6: this module's form.
    Compact,
}

impl Encoding {
    /// The name on command lines (`raw12`, `compact`).
    pub fn name(self) -> &'static str {
        match self {
            Encoding::Raw12 => "raw12",
            Encoding::Compact => "compact",
        }
    }

    /// The encoding with this name.
    pub fn from_name(s: &str) -> Option<Encoding> {
        match s {
            "raw12" => Some(Encoding::Raw12),
            "compact" => Some(Encoding::Compact),
            _ => None,
        }
    }
}

/// Parses the compact fields and checks them against the frame header.
fn parse_params(b: &[u8; 24], header: &FrameHeader) -> Result<CompactParams, WireError> {
    let f = |i: usize| f32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
    let coder = Coder::from_code(b[16]).ok_or(WireError::Compact(CompactError::BadCoder(b[16])))?;
    let colors = ColorCoding::from_code(b[17]).ok_or(WireError::Compact(CompactError::BadColorCoding(b[17])))?;
    let scales = u16::from_le_bytes([b[18], b[19]]);
    if scales & 0x8000 != 0 || (colors == ColorCoding::Plain && scales != 0) {
        return Err(WireError::Compact(CompactError::BadColorCoding(b[17])));
    }
    let color_scale = [(scales & 31) as u8, ((scales >> 5) & 31) as u8, ((scales >> 10) & 31) as u8];
    let raw_len = u32::from_le_bytes([b[20], b[21], b[22], b[23]]);
    let p = CompactParams {
        depth_min: f(0),
        depth_step: f(4),
        radius: RadiusPrediction { constant: f(8), per_depth: f(12) },
        coder,
        colors,
        color_scale,
        raw_len,
    };
    if !(p.depth_min.is_finite()
        && p.depth_step > 0.0
        && p.depth_step.is_finite()
        && depth_of(&p, DEPTH_CODE_MAX).is_finite())
    {
        return Err(WireError::Compact(CompactError::BadDepth));
    }
    if !(p.radius.constant.is_finite() && p.radius.per_depth.is_finite()) {
        return Err(WireError::Compact(CompactError::BadRadiusModel));
    }
    let expected =
        mask_len(header.camera.width, header.camera.height) + PLANE_BYTES_PER_SAMPLE as u64 * header.count as u64;
    if raw_len as u64 != expected {
        return Err(WireError::Compact(CompactError::BadRawLength { stated: raw_len, expected }));
    }
    Ok(p)
}

/// The compact parameters of a CompactFrame message's payload (for tools: bounds, statistics).
pub fn read_params(payload: &[u8], limits: &Limits) -> Result<(FrameHeader, CompactParams), WireError> {
    if payload.len() < COMPACT_FIXED_LEN {
        return Err(WireError::BadLength { ty: MsgType::CompactFrame, len: payload.len() as u32 });
    }
    let fixed: &[u8; FRAME_FIXED_LEN] = payload[..FRAME_FIXED_LEN].try_into().unwrap_or(&[0; FRAME_FIXED_LEN]);
    let header = decode_frame_fixed(fixed, limits)?;
    let cb: &[u8; 24] = payload[FRAME_FIXED_LEN..COMPACT_FIXED_LEN].try_into().unwrap_or(&[0; 24]);
    Ok((header, parse_params(cb, &header)?))
}

/// The encoder and decoder proper (they need an allocator).
#[cfg(feature = "alloc")]
mod codec;
#[cfg(feature = "alloc")]
pub use codec::*;
