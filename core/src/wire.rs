//! The framed, versioned wire codec over `embedded-io` (documented byte by byte in
//! `docs/wire-format.md`).
//!
//! Every message is a 12-byte [`Header`] (magic `VWRP`, version, type, reserved, payload
//! length) and a payload. All integers and floats are little-endian.
//!
//! The decoder never panics, never reads more than the header announced, never allocates
//! (or, with `alloc`, allocates at most what the caller's [`Limits`] allow), and returns a
//! typed [`WireError`] for bad magic or version, lengths over the limit, counts inconsistent
//! with the length, truncated input, and NaN/inf or degenerate cameras and bounds.

use crate::camera::{Camera, CameraError};
use crate::heuristics::Heuristic;
use crate::sample::{Bounds, RADIUS_MAX};
use embedded_io::{ErrorKind, Read, ReadExactError, Write};
use glam::Vec3;

mod errors;
pub use errors::{CompactError, LayerError};
mod visual;
pub use visual::*;

/// The four magic bytes that start every message.
pub const MAGIC: [u8; 4] = *b"VWRP";
/// The protocol version this crate speaks (and writes in every header). Version 6 added frames
/// in parts: the FramePart (type 10) and FrameDropped (type 11) messages and the [`CAP_PARTS`]
/// bit (`parts`). Version 5 gave a
/// CameraRequest's byte 57 (reserved before, always written 0) a meaning: the segments per pixel
/// the client wants for this request, 0 for the Hello's ([`CameraRequest::layers`]); every
/// version-1 to -4 request reads as before (0). Version 4 added the live
/// visual state: the VisualEdit (type 8) and VisualState (type 9) messages, the [`CAP_VISUAL`]
/// bit and the non-closing Error [`error_code::BAD_EDIT`]. Version 3 added layered frames: a
/// layer count in a Frame's byte 57 and a segment-index plane after its colors, the
/// LayeredCompactFrame message (type 7) and the layer count in the Hello.
pub const VERSION: u16 = 6;
/// The oldest version a receiver accepts: version 2 only added the CompactFrame message and the
/// [`CAP_COMPACT`] bit, so every version-1 message is read as it was (old record files replay).
pub const MIN_VERSION: u16 = 1;
/// Bytes of a message header.
pub const HEADER_LEN: usize = 12;
/// Bytes of an encoded camera.
pub const CAMERA_LEN: usize = 48;
/// Bytes of a CameraRequest payload.
pub const CAMERA_REQUEST_LEN: usize = 64;
/// Bytes of a Frame payload before the sample array.
pub const FRAME_FIXED_LEN: usize = 96;
/// Bytes of a CompactFrame payload before the compressed body (`crate::compact_frame`).
pub const COMPACT_FIXED_LEN: usize = FRAME_FIXED_LEN + 24;
/// Most segments per pixel a frame may carry (the wire's and the marcher's cap).
pub const MAX_LAYERS: usize = 16;
/// Bytes per sample in a Frame (8 position/radius + 4 color).
pub const BYTES_PER_SAMPLE: usize = 12;
/// Longest token a Hello carries.
pub const MAX_TOKEN: usize = 64;
/// Longest message an Error carries, in bytes of UTF-8.
pub const MAX_ERROR_TEXT: usize = 256;
/// Capability bit: the peer can trace on a GPU (informational).
pub const CAP_GPU: u32 = 1;
/// Capability bit: in a client's Hello, "send me CompactFrames"; in the server's answer, "I
/// will" (version 2). A server that answers without it sends only 12-byte Frames.
pub const CAP_COMPACT: u32 = 2;
/// Capability bit: the peer reads CompactFrames whose color residuals are coded against
/// green's (`compact_frame::ColorCoding::AgainstGreen`, byte 113); a sender uses that coding
/// only with peers that announced it (older receivers would misread the colors).
pub const CAP_COLOR_GREEN: u32 = 4;
/// Capability bit (version 6): in a client's Hello, "I reassemble frames sent in parts"; in the
/// server's answer, "I send them so" (FramePart, FrameDropped; `parts`).
pub const CAP_PARTS: u32 = 16;
/// Most bytes a FramePart carries (a server writes parts of this size; the last is shorter).
pub const PART_LEN: usize = 32 * 1024;

/// Message types.
#[repr(u8)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MsgType {
    /// Version and capabilities (and the access token), both ways.
    Hello = 1,
    /// Client to server: render this camera.
    CameraRequest = 2,
    /// Server to client: one compacted frame of samples.
    Frame = 3,
    /// Either way: something went wrong; the sender closes.
    Error = 4,
    /// Either way: orderly goodbye.
    Bye = 5,
    /// Server to client: one frame in the compact encoding (version 2; `crate::compact_frame`).
    CompactFrame = 6,
    /// Server to client: a layered frame in the compact encoding, one CompactFrame per layer
    /// (version 3; `crate::segments`).
    LayeredCompactFrame = 7,
    /// Client to server: change the visual state (version 4; [`VisualEdit`]).
    VisualEdit = 8,
    /// Server to client: the visual state the following frames are rendered with, and the
    /// presets (version 4; [`VisualState`]).
    VisualState = 9,
    /// Server to client: the next bytes of a frame message sent in parts (version 6; `parts`).
    FramePart = 10,
    /// Server to client: the frame whose parts came so far is dropped (version 6; empty).
    FrameDropped = 11,
}

impl MsgType {
    /// The type with this code.
    pub fn from_code(c: u8) -> Option<MsgType> {
        Some(match c {
            1 => MsgType::Hello,
            2 => MsgType::CameraRequest,
            3 => MsgType::Frame,
            4 => MsgType::Error,
            5 => MsgType::Bye,
            6 => MsgType::CompactFrame,
            7 => MsgType::LayeredCompactFrame,
            8 => MsgType::VisualEdit,
            9 => MsgType::VisualState,
            10 => MsgType::FramePart,
            11 => MsgType::FrameDropped,
            _ => return None,
        })
    }
}

/// A decoded message header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    /// Message type.
    pub ty: MsgType,
    /// Payload length in bytes.
    pub len: u32,
}

/// What the decoder accepts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Largest payload in bytes.
    pub max_payload: u32,
    /// Most samples in a Frame.
    pub max_samples: u32,
    /// Largest viewport width or height.
    pub max_viewport: u32,
    /// Most segments per pixel a layered frame may carry (the negotiated maximum; 1: only
    /// one-sample-per-pixel frames).
    pub max_layers: u8,
}

impl Limits {
    /// Limits for a client receiving frames up to `max_viewport`² samples.
    pub const fn for_frames(max_viewport: u32) -> Limits {
        let max_samples = max_viewport.saturating_mul(max_viewport);
        let raw = max_samples as u64 * BYTES_PER_SAMPLE as u64 + FRAME_FIXED_LEN as u64;
        // A CompactFrame holds a mask and 8 bytes per sample, which zstd can grow a little.
        let body = (max_samples as u64).div_ceil(8) + 8 * max_samples as u64;
        let compact = COMPACT_FIXED_LEN as u64 + body + body / 64 + 1024;
        let max_payload = if compact > raw { compact } else { raw };
        Limits {
            max_payload: if max_payload > u32::MAX as u64 { u32::MAX } else { max_payload as u32 },
            max_samples,
            max_viewport,
            max_layers: MAX_LAYERS as u8,
        }
    }

    /// These limits with at most `layers` segments per pixel (clamped to
    /// `1..=`[`MAX_LAYERS`]).
    pub const fn with_layers(mut self, layers: u8) -> Limits {
        self.max_layers = if layers == 0 {
            1
        } else if layers as usize > MAX_LAYERS {
            MAX_LAYERS as u8
        } else {
            layers
        };
        self
    }

    /// Limits for a server reading client messages: nothing larger than the largest
    /// VisualEdit (the largest message a client sends).
    pub const fn for_requests(max_viewport: u32) -> Limits {
        let max = if VISUAL_EDIT_MAX_LEN > 4 + MAX_ERROR_TEXT { VISUAL_EDIT_MAX_LEN } else { 4 + MAX_ERROR_TEXT };
        Limits { max_payload: max as u32, max_samples: 0, max_viewport, max_layers: 1 }
    }
}

impl Default for Limits {
    /// Frames up to 4096 × 4096.
    fn default() -> Self {
        Limits::for_frames(4096)
    }
}

/// Why a message could not be decoded (or encoded).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WireError {
    /// The transport failed.
    Io(ErrorKind),
    /// The input ended inside a message.
    UnexpectedEof,
    /// The input ended cleanly between messages.
    Closed,
    /// The first four bytes are not `VWRP`.
    BadMagic([u8; 4]),
    /// The peer speaks another protocol version.
    UnsupportedVersion(u16),
    /// Unknown message type code.
    UnknownType(u8),
    /// The payload length is over the limit.
    TooLarge {
        /// Announced length.
        len: u32,
        /// Limit.
        limit: u32,
    },
    /// The payload length does not fit the message type or its counts.
    BadLength {
        /// Message type.
        ty: MsgType,
        /// Announced length.
        len: u32,
    },
    /// A Frame has more samples than allowed (or than its viewport has pixels).
    TooManySamples {
        /// Announced count.
        count: u32,
        /// Limit.
        limit: u32,
    },
    /// The camera is NaN, infinite or degenerate.
    BadCamera(CameraError),
    /// The bounds are NaN, infinite or inverted.
    BadBounds,
    /// The radius unit or radius scale is not a positive finite number.
    BadRadius,
    /// Unknown heuristic code.
    BadHeuristic(u8),
    /// The token is longer than [`MAX_TOKEN`].
    BadToken,
    /// Caller-provided buffers are too small for the frame.
    BufferTooSmall,
    /// A CompactFrame's own fields or body are invalid.
    Compact(CompactError),
    /// A layered frame's segments are invalid (version 3).
    Layers(LayerError),
    /// A VisualEdit or VisualState is malformed (version 4). The whole payload was read: the
    /// stream is at the next message.
    BadVisual(VisualWireError),
    /// Frame parts that do not make one frame message (version 6): what is wrong.
    BadParts(&'static str),
}

impl core::fmt::Display for WireError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            WireError::Io(k) => write!(f, "i/o error: {k:?}"),
            WireError::UnexpectedEof => f.write_str("connection closed in the middle of a message"),
            WireError::Closed => f.write_str("connection closed"),
            WireError::BadMagic(m) => write!(f, "not a volwarp stream (magic {m:02x?})"),
            WireError::UnsupportedVersion(v) => {
                write!(f, "peer speaks protocol version {v}, this build speaks {VERSION}")
            }
            WireError::UnknownType(t) => write!(f, "unknown message type {t}"),
            WireError::TooLarge { len, limit } => write!(f, "message of {len} bytes is over the limit of {limit}"),
            WireError::BadLength { ty, len } => write!(f, "{ty:?} message with inconsistent length {len}"),
            WireError::TooManySamples { count, limit } => {
                write!(f, "frame with {count} samples is over the limit of {limit}")
            }
            WireError::BadCamera(e) => write!(f, "bad camera: {e}"),
            WireError::BadBounds => f.write_str("bad scene bounds (NaN, infinite or inverted)"),
            WireError::BadRadius => f.write_str("bad radius unit or scale"),
            WireError::BadHeuristic(h) => write!(f, "unknown heuristic code {h}"),
            WireError::BadToken => f.write_str("token too long"),
            WireError::BufferTooSmall => f.write_str("buffers too small for the frame"),
            WireError::Compact(e) => write!(f, "{e}"),
            WireError::Layers(e) => write!(f, "{e}"),
            WireError::BadVisual(e) => write!(f, "{e}"),
            WireError::BadParts(e) => write!(f, "bad frame parts: {e}"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for WireError {}

impl<E: embedded_io::Error> From<ReadExactError<E>> for WireError {
    fn from(e: ReadExactError<E>) -> Self {
        match e {
            ReadExactError::UnexpectedEof => WireError::UnexpectedEof,
            ReadExactError::Other(e) => WireError::Io(e.kind()),
        }
    }
}

fn io<E: embedded_io::Error>(e: E) -> WireError {
    WireError::Io(e.kind())
}

/// Hello: protocol version, capabilities and an optional access token.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Hello {
    /// Protocol version of the sender.
    pub version: u16,
    /// Capability bits ([`CAP_GPU`], …).
    pub capabilities: u32,
    /// Access token (empty if none).
    pub token: heapless::Vec<u8, MAX_TOKEN>,
    /// Layered frames (version 3): in a client's Hello the most segments per pixel it accepts
    /// and asks for, in the server's answer the count it will render (1: one sample per pixel,
    /// as before; 0 on the wire reads as 1).
    pub layers: u8,
}

impl Hello {
    /// A Hello of this version with no token.
    pub fn new(capabilities: u32) -> Self {
        Hello { version: VERSION, capabilities, token: heapless::Vec::new(), layers: 1 }
    }
    /// Sets the layer count (clamped to `1..=`[`MAX_LAYERS`]).
    pub fn with_layers(mut self, layers: u8) -> Self {
        self.layers = layers.clamp(1, MAX_LAYERS as u8);
        self
    }
    /// Sets the token; `Err` if it is longer than [`MAX_TOKEN`].
    pub fn with_token(mut self, token: &[u8]) -> Result<Self, WireError> {
        self.token = heapless::Vec::from_slice(token).map_err(|_| WireError::BadToken)?;
        Ok(self)
    }
}

/// CameraRequest: the client's current camera and what to render.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraRequest {
    /// Client's sequence number, echoed in the Frame.
    pub seq: u64,
    /// Camera including the viewport.
    pub camera: Camera,
    /// Depth heuristic.
    pub heuristic: Heuristic,
    /// Sphere radius as a multiple of the server's radius model (by default a pixel
    /// diagonal at the sample's depth), in (0, 16].
    pub radius_scale: f32,
    /// Segments per pixel wanted for this request (version 5, byte 57): 0 for the count the
    /// Hello negotiated; otherwise 1 to [`MAX_LAYERS`], which the server caps at the Hello's
    /// (e.g. 1, a one-sample frame, exact at its own camera, for a view at rest).
    pub layers: u8,
}

/// The fixed part of a Frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameHeader {
    /// The request's sequence number.
    pub seq: u64,
    /// The camera the frame was rendered for.
    pub camera: Camera,
    /// The heuristic it was rendered with.
    pub heuristic: Heuristic,
    /// Scene bounds the positions are quantized to.
    pub bounds: Bounds,
    /// World size of one radius code step.
    pub radius_unit: f32,
    /// Server time to march and compact, in microseconds.
    pub render_us: u32,
    /// The level of detail the frame was marched from: 0 the volume itself, `l` the volume
    /// downsampled `2^l` times per axis (a server keeping its frame time within a budget while
    /// the camera moves). Clients need nothing of it: the samples are in the same box.
    pub level: u8,
    /// Number of samples that follow.
    pub count: u32,
}

impl FrameHeader {
    /// The decoder of this frame's packed samples (its bounds and radius unit).
    pub fn dequantizer(&self) -> crate::sample::Dequantizer {
        crate::sample::Dequantizer::new(self.bounds, self.radius_unit)
    }
}

/// An Error message.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ErrorMsg {
    /// Error code (see [`error_code`]).
    pub code: u16,
    /// Human-readable text (UTF-8, possibly lossy-truncated).
    pub text: heapless::String<MAX_ERROR_TEXT>,
}

/// Error codes.
pub mod error_code {
    /// The request was malformed.
    pub const BAD_REQUEST: u16 = 1;
    /// The protocol version is not supported.
    pub const UNSUPPORTED_VERSION: u16 = 2;
    /// Missing or wrong token.
    pub const UNAUTHORIZED: u16 = 3;
    /// The server has too many clients.
    pub const BUSY: u16 = 4;
    /// Handshake or idle timeout.
    pub const TIMEOUT: u16 = 5;
    /// A message or viewport was over a limit.
    pub const TOO_LARGE: u16 = 6;
    /// The server failed.
    pub const INTERNAL: u16 = 7;
    /// Too many failed Hellos (wrong tokens) from this address lately: refused before the
    /// handshake; try again later.
    pub const RATE_LIMITED: u16 = 8;
    /// A VisualEdit was refused (version 4): the text says why; the state is unchanged and,
    /// unlike every other code, the connection stays open.
    pub const BAD_EDIT: u16 = 9;
}

impl ErrorMsg {
    /// An error with `text` (truncated at a char boundary to [`MAX_ERROR_TEXT`] bytes).
    pub fn new(code: u16, text: &str) -> Self {
        let mut end = text.len().min(MAX_ERROR_TEXT);
        while !text.is_char_boundary(end) {
            end -= 1;
        }
        let mut s = heapless::String::new();
        let _ = s.push_str(&text[..end]);
        ErrorMsg { code, text: s }
    }
}

// ---------------------------------------------------------------- little-endian cursor

struct Cur<'a> {
    b: &'a [u8],
    p: usize,
}

impl<'a> Cur<'a> {
    fn new(b: &'a [u8]) -> Self {
        Cur { b, p: 0 }
    }
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut a = [0u8; N];
        a.copy_from_slice(&self.b[self.p..self.p + N]);
        self.p += N;
        a
    }
    fn u8(&mut self) -> u8 {
        self.take::<1>()[0]
    }
    fn u16(&mut self) -> u16 {
        u16::from_le_bytes(self.take())
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }
    fn f32(&mut self) -> f32 {
        f32::from_le_bytes(self.take())
    }
    fn vec3(&mut self) -> Vec3 {
        Vec3::new(self.f32(), self.f32(), self.f32())
    }
}

struct Out<const N: usize> {
    b: [u8; N],
    p: usize,
}

impl<const N: usize> Out<N> {
    fn new() -> Self {
        Out { b: [0; N], p: 0 }
    }
    fn put(&mut self, s: &[u8]) {
        self.b[self.p..self.p + s.len()].copy_from_slice(s);
        self.p += s.len();
    }
    fn vec3(&mut self, v: Vec3) {
        for c in v.to_array() {
            self.put(&c.to_le_bytes());
        }
    }
    fn bytes(&self) -> &[u8] {
        &self.b[..self.p]
    }
}

fn encode_camera<const N: usize>(o: &mut Out<N>, c: &Camera) {
    o.vec3(c.eye);
    o.vec3(c.target);
    o.vec3(c.up);
    o.put(&c.fov_y_deg.to_le_bytes());
    o.put(&c.width.to_le_bytes());
    o.put(&c.height.to_le_bytes());
}

fn decode_camera(c: &mut Cur, limits: &Limits) -> Result<Camera, WireError> {
    let cam =
        Camera { eye: c.vec3(), target: c.vec3(), up: c.vec3(), fov_y_deg: c.f32(), width: c.u32(), height: c.u32() };
    cam.validate(limits.max_viewport).map_err(WireError::BadCamera)?;
    Ok(cam)
}

// ---------------------------------------------------------------- writing

/// Writes a message header.
pub fn write_header<W: Write>(w: &mut W, ty: MsgType, len: u32) -> Result<(), WireError> {
    let mut h = [0u8; HEADER_LEN];
    h[..4].copy_from_slice(&MAGIC);
    h[4..6].copy_from_slice(&VERSION.to_le_bytes());
    h[6] = ty as u8;
    h[8..12].copy_from_slice(&len.to_le_bytes());
    w.write_all(&h).map_err(io)
}

/// Writes a Hello.
pub fn write_hello<W: Write>(w: &mut W, h: &Hello) -> Result<(), WireError> {
    let mut o = Out::<{ 9 + MAX_TOKEN }>::new();
    o.put(&h.version.to_le_bytes());
    o.put(&(h.layers as u16).to_le_bytes());
    o.put(&h.capabilities.to_le_bytes());
    o.put(&[h.token.len() as u8]);
    o.put(&h.token);
    write_header(w, MsgType::Hello, o.p as u32)?;
    w.write_all(o.bytes()).map_err(io)
}

/// Writes a CameraRequest.
pub fn write_camera_request<W: Write>(w: &mut W, r: &CameraRequest) -> Result<(), WireError> {
    let mut o = Out::<CAMERA_REQUEST_LEN>::new();
    o.put(&r.seq.to_le_bytes());
    encode_camera(&mut o, &r.camera);
    o.put(&[r.heuristic.code(), r.layers, 0, 0]);
    o.put(&r.radius_scale.to_le_bytes());
    write_header(w, MsgType::CameraRequest, CAMERA_REQUEST_LEN as u32)?;
    w.write_all(o.bytes()).map_err(io)
}

/// Writes a Frame: header, then `samples` and `colors` (equal length, at most `u32::MAX`; the
/// header's `count` is taken from them).
pub fn write_frame<W: Write>(w: &mut W, fh: &FrameHeader, samples: &[u64], colors: &[u32]) -> Result<(), WireError> {
    write_frame_layered(w, fh, samples, colors, &[])
}

/// Writes a Frame with its segment indices (version 3): an empty `segments` writes the
/// one-sample-per-pixel Frame of [`write_frame`]; otherwise one index per sample follows the
/// colors and byte 57 holds the layer count (the largest index + 1).
pub fn write_frame_layered<W: Write>(
    w: &mut W,
    fh: &FrameHeader,
    samples: &[u64],
    colors: &[u32],
    segments: &[u8],
) -> Result<(), WireError> {
    if samples.len() != colors.len() || !(segments.is_empty() || segments.len() == samples.len()) {
        return Err(WireError::BufferTooSmall);
    }
    let count =
        u32::try_from(samples.len()).map_err(|_| WireError::TooManySamples { count: u32::MAX, limit: u32::MAX })?;
    let layers = if segments.is_empty() { 0 } else { segments.iter().max().map_or(1, |&m| m.saturating_add(1)) };
    let per = BYTES_PER_SAMPLE as u64 + u64::from(layers > 0);
    let len = FRAME_FIXED_LEN as u64 + count as u64 * per;
    let len = u32::try_from(len).map_err(|_| WireError::TooLarge { len: u32::MAX, limit: u32::MAX })?;
    let mut b = encode_frame_fixed(&FrameHeader { count, ..*fh });
    b[57] = layers;
    write_header(w, MsgType::Frame, len)?;
    w.write_all(&b).map_err(io)?;
    write_le_u64s(w, samples)?;
    write_le_u32s(w, colors)?;
    w.write_all(segments).map_err(io)
}

fn write_le_u64s<W: Write>(w: &mut W, v: &[u64]) -> Result<(), WireError> {
    #[cfg(target_endian = "little")]
    {
        w.write_all(bytemuck::cast_slice(v)).map_err(io)
    }
    #[cfg(not(target_endian = "little"))]
    {
        for chunk in v.chunks(64) {
            let mut buf = [0u8; 512];
            for (i, x) in chunk.iter().enumerate() {
                buf[i * 8..i * 8 + 8].copy_from_slice(&x.to_le_bytes());
            }
            w.write_all(&buf[..chunk.len() * 8]).map_err(io)?;
        }
        Ok(())
    }
}

fn write_le_u32s<W: Write>(w: &mut W, v: &[u32]) -> Result<(), WireError> {
    #[cfg(target_endian = "little")]
    {
        w.write_all(bytemuck::cast_slice(v)).map_err(io)
    }
    #[cfg(not(target_endian = "little"))]
    {
        for chunk in v.chunks(64) {
            let mut buf = [0u8; 256];
            for (i, x) in chunk.iter().enumerate() {
                buf[i * 4..i * 4 + 4].copy_from_slice(&x.to_le_bytes());
            }
            w.write_all(&buf[..chunk.len() * 4]).map_err(io)?;
        }
        Ok(())
    }
}

/// Writes an Error.
pub fn write_error<W: Write>(w: &mut W, e: &ErrorMsg) -> Result<(), WireError> {
    let mut o = Out::<{ 4 + MAX_ERROR_TEXT }>::new();
    o.put(&e.code.to_le_bytes());
    o.put(&(e.text.len() as u16).to_le_bytes());
    o.put(e.text.as_bytes());
    write_header(w, MsgType::Error, o.p as u32)?;
    w.write_all(o.bytes()).map_err(io)
}

/// Writes a Bye.
pub fn write_bye<W: Write>(w: &mut W) -> Result<(), WireError> {
    write_header(w, MsgType::Bye, 0)
}

// ---------------------------------------------------------------- reading

/// Reads and checks a message header. A stream that ends before the first byte gives
/// [`WireError::Closed`].
pub fn read_header<R: Read>(r: &mut R, limits: &Limits) -> Result<Header, WireError> {
    parse_header(&read_raw_header(r)?, limits)
}

/// Reads a message header's 12 bytes, checking only the magic. A stream that ends before the
/// first byte gives [`WireError::Closed`].
pub fn read_raw_header<R: Read>(r: &mut R) -> Result<[u8; HEADER_LEN], WireError> {
    let mut h = [0u8; HEADER_LEN];
    // Tell a clean close (0 bytes) from a truncated header.
    let mut got = 0;
    while got < HEADER_LEN {
        let n = r.read(&mut h[got..]).map_err(io)?;
        if n == 0 {
            return Err(if got == 0 { WireError::Closed } else { WireError::UnexpectedEof });
        }
        got += n;
        if got >= 4 && h[..4] != MAGIC {
            return Err(WireError::BadMagic([h[0], h[1], h[2], h[3]]));
        }
    }
    Ok(h)
}

/// Checks a 12-byte header already in memory.
pub fn parse_header(h: &[u8; HEADER_LEN], limits: &Limits) -> Result<Header, WireError> {
    if h[..4] != MAGIC {
        return Err(WireError::BadMagic([h[0], h[1], h[2], h[3]]));
    }
    let version = u16::from_le_bytes([h[4], h[5]]);
    if !(MIN_VERSION..=VERSION).contains(&version) {
        return Err(WireError::UnsupportedVersion(version));
    }
    let ty = MsgType::from_code(h[6]).ok_or(WireError::UnknownType(h[6]))?;
    let len = u32::from_le_bytes([h[8], h[9], h[10], h[11]]);
    let ok_len = match ty {
        MsgType::Hello => (9..=9 + MAX_TOKEN as u32).contains(&len),
        MsgType::CameraRequest => len == CAMERA_REQUEST_LEN as u32,
        MsgType::Frame => {
            len >= FRAME_FIXED_LEN as u32
                && ((len - FRAME_FIXED_LEN as u32).is_multiple_of(BYTES_PER_SAMPLE as u32)
                    || (len - FRAME_FIXED_LEN as u32).is_multiple_of(BYTES_PER_SAMPLE as u32 + 1))
        }
        MsgType::Error => (4..=4 + MAX_ERROR_TEXT as u32).contains(&len),
        MsgType::Bye => len == 0,
        MsgType::CompactFrame => len >= COMPACT_FIXED_LEN as u32,
        MsgType::LayeredCompactFrame => len >= FRAME_FIXED_LEN as u32,
        MsgType::VisualEdit => (VISUAL_EDIT_FIXED_LEN as u32..=VISUAL_EDIT_MAX_LEN as u32).contains(&len),
        MsgType::VisualState => (VISUAL_STATE_FIXED_LEN as u32..=VISUAL_STATE_MAX_LEN as u32).contains(&len),
        MsgType::FramePart => (1..=PART_LEN as u32).contains(&len),
        MsgType::FrameDropped => len == 0,
    };
    if len > limits.max_payload {
        return Err(WireError::TooLarge { len, limit: limits.max_payload });
    }
    if !ok_len {
        return Err(WireError::BadLength { ty, len });
    }
    Ok(Header { ty, len })
}

fn read_fixed<R: Read, const N: usize>(r: &mut R, len: usize) -> Result<[u8; N], WireError> {
    let mut b = [0u8; N];
    r.read_exact(&mut b[..len])?;
    Ok(b)
}

/// Reads a Hello payload (after its header).
pub fn read_hello<R: Read>(r: &mut R, h: &Header) -> Result<Hello, WireError> {
    if h.ty != MsgType::Hello {
        return Err(WireError::BadLength { ty: h.ty, len: h.len });
    }
    let len = h.len as usize;
    let b: [u8; 9 + MAX_TOKEN] = read_fixed(r, len)?;
    let mut c = Cur::new(&b[..len]);
    let version = c.u16();
    let layers = c.u16().clamp(1, MAX_LAYERS as u16) as u8;
    let capabilities = c.u32();
    let tlen = c.u8() as usize;
    if 9 + tlen != len {
        return Err(WireError::BadLength { ty: h.ty, len: h.len });
    }
    let token = heapless::Vec::from_slice(&b[9..9 + tlen]).map_err(|_| WireError::BadToken)?;
    Ok(Hello { version, capabilities, token, layers })
}

/// Reads a CameraRequest payload (after its header).
pub fn read_camera_request<R: Read>(r: &mut R, h: &Header, limits: &Limits) -> Result<CameraRequest, WireError> {
    if h.ty != MsgType::CameraRequest || h.len as usize != CAMERA_REQUEST_LEN {
        return Err(WireError::BadLength { ty: h.ty, len: h.len });
    }
    let b: [u8; CAMERA_REQUEST_LEN] = read_fixed(r, CAMERA_REQUEST_LEN)?;
    let mut c = Cur::new(&b);
    let seq = c.u64();
    let camera = decode_camera(&mut c, limits)?;
    let hcode = c.u8();
    let heuristic = Heuristic::from_code(hcode).ok_or(WireError::BadHeuristic(hcode))?;
    // Byte 57: the layers wanted (version 5; reserved and 0 before, which reads as the Hello's).
    let [layers, _, _] = c.take::<3>();
    if usize::from(layers) > MAX_LAYERS {
        return Err(WireError::Layers(LayerError::TooManyLayers { layers, limit: MAX_LAYERS as u8 }));
    }
    let radius_scale = c.f32();
    if !(radius_scale > 0.0 && radius_scale <= 16.0) {
        return Err(WireError::BadRadius);
    }
    Ok(CameraRequest { seq, camera, heuristic, radius_scale, layers })
}

/// Reads the fixed part of a one-sample-per-pixel Frame payload (after its header), checking it
/// against the header's length and the limits. The samples follow; read them with
/// [`read_frame_body`]. A layered frame (version 3, byte 57 non-zero) is refused with
/// [`LayerError::Layered`]: read it with [`read_message`] (feature `alloc`).
pub fn read_frame_header<R: Read>(r: &mut R, h: &Header, limits: &Limits) -> Result<FrameHeader, WireError> {
    let (fh, layers) = read_frame_header_layered(r, h, limits)?;
    if layers != 0 {
        return Err(WireError::Layers(LayerError::Layered));
    }
    Ok(fh)
}

/// [`read_frame_header`] for any Frame: the header and its layer count (byte 57; 0 for a
/// one-sample-per-pixel frame, else the count of the segment-index plane that follows the
/// colors), checked against the length and the limits (layers ≤ `max_layers`, count ≤
/// layers × pixels).
pub fn read_frame_header_layered<R: Read>(
    r: &mut R,
    h: &Header,
    limits: &Limits,
) -> Result<(FrameHeader, u8), WireError> {
    if h.ty != MsgType::Frame || (h.len as usize) < FRAME_FIXED_LEN {
        return Err(WireError::BadLength { ty: h.ty, len: h.len });
    }
    let b: [u8; FRAME_FIXED_LEN] = read_fixed(r, FRAME_FIXED_LEN)?;
    let fh = decode_frame_fixed(&b, limits)?;
    let layers = b[57];
    let per = BYTES_PER_SAMPLE as u64 + u64::from(layers > 0);
    let expect = FRAME_FIXED_LEN as u64 + fh.count as u64 * per;
    if expect != h.len as u64 {
        return Err(WireError::BadLength { ty: h.ty, len: h.len });
    }
    check_count_layers(&fh, layers, limits)?;
    Ok((fh, layers))
}

/// [`check_count`] for a frame of `layers` segments per pixel (0 or 1: one sample per pixel):
/// the layer count against `limits.max_layers`, the count against `layers × pixels`.
pub fn check_count_layers(fh: &FrameHeader, layers: u8, limits: &Limits) -> Result<(), WireError> {
    if layers > limits.max_layers.max(1) {
        return Err(WireError::Layers(LayerError::TooManyLayers { layers, limit: limits.max_layers.max(1) }));
    }
    let pixels = fh.camera.width as u64 * fh.camera.height as u64 * layers.max(1) as u64;
    let limit = (limits.max_samples as u64).min(pixels) as u32;
    if fh.count > limit {
        return Err(WireError::TooManySamples { count: fh.count, limit });
    }
    Ok(())
}

/// The sample count of a frame header against its viewport and the limits.
pub fn check_count(fh: &FrameHeader, limits: &Limits) -> Result<(), WireError> {
    let pixels = fh.camera.width as u64 * fh.camera.height as u64;
    let limit = (limits.max_samples as u64).min(pixels) as u32;
    if fh.count > limit {
        return Err(WireError::TooManySamples { count: fh.count, limit });
    }
    Ok(())
}

/// The fixed 96 bytes of a Frame (also the start of a CompactFrame), encoded.
pub fn encode_frame_fixed(fh: &FrameHeader) -> [u8; FRAME_FIXED_LEN] {
    let mut o = Out::<FRAME_FIXED_LEN>::new();
    o.put(&fh.seq.to_le_bytes());
    encode_camera(&mut o, &fh.camera);
    o.put(&[fh.heuristic.code(), 0, fh.level, 0]);
    for v in fh.bounds.min.iter().chain(fh.bounds.max.iter()) {
        o.put(&v.to_le_bytes());
    }
    o.put(&fh.radius_unit.to_le_bytes());
    o.put(&fh.render_us.to_le_bytes());
    o.put(&fh.count.to_le_bytes());
    o.b
}

/// Decodes and validates the fixed 96 bytes of a Frame (camera, heuristic, bounds, radius
/// unit), without checking the count (see [`check_count`]) or the message length.
pub fn decode_frame_fixed(b: &[u8; FRAME_FIXED_LEN], limits: &Limits) -> Result<FrameHeader, WireError> {
    let mut c = Cur::new(b);
    let seq = c.u64();
    let camera = decode_camera(&mut c, limits)?;
    let hcode = c.u8();
    let heuristic = Heuristic::from_code(hcode).ok_or(WireError::BadHeuristic(hcode))?;
    let [_layers, level, _] = c.take::<3>();
    let min = c.vec3();
    let max = c.vec3();
    let bounds = Bounds::new(min, max);
    if !bounds.is_valid() {
        return Err(WireError::BadBounds);
    }
    let radius_unit = c.f32();
    if !(radius_unit > 0.0 && (radius_unit * RADIUS_MAX as f32).is_finite()) {
        return Err(WireError::BadRadius);
    }
    let render_us = c.u32();
    let count = c.u32();
    Ok(FrameHeader { seq, camera, heuristic, bounds, radius_unit, render_us, level, count })
}

/// Reads a Frame's samples and colors into the first `count` entries of the buffers.
pub fn read_frame_body<R: Read>(
    r: &mut R,
    fh: &FrameHeader,
    samples: &mut [u64],
    colors: &mut [u32],
) -> Result<(), WireError> {
    let n = fh.count as usize;
    if samples.len() < n || colors.len() < n {
        return Err(WireError::BufferTooSmall);
    }
    let s = &mut samples[..n];
    r.read_exact(bytemuck::cast_slice_mut(s))?;
    let c = &mut colors[..n];
    r.read_exact(bytemuck::cast_slice_mut(c))?;
    #[cfg(not(target_endian = "little"))]
    {
        for x in s.iter_mut() {
            *x = u64::from_le(*x);
        }
        for x in c.iter_mut() {
            *x = u32::from_le(*x);
        }
    }
    Ok(())
}

/// Reads an Error payload (after its header). Invalid UTF-8 is replaced, not rejected.
pub fn read_error<R: Read>(r: &mut R, h: &Header) -> Result<ErrorMsg, WireError> {
    if h.ty != MsgType::Error {
        return Err(WireError::BadLength { ty: h.ty, len: h.len });
    }
    let len = h.len as usize;
    let b: [u8; 4 + MAX_ERROR_TEXT] = read_fixed(r, len)?;
    let mut c = Cur::new(&b[..len]);
    let code = c.u16();
    let tlen = c.u16() as usize;
    if 4 + tlen != len {
        return Err(WireError::BadLength { ty: h.ty, len: h.len });
    }
    let text = &b[4..4 + tlen];
    let mut s: heapless::String<MAX_ERROR_TEXT> = heapless::String::new();
    for chunk in text.utf8_chunks() {
        let _ = s.push_str(chunk.valid());
        if !chunk.invalid().is_empty() {
            let _ = s.push('?');
        }
    }
    Ok(ErrorMsg { code, text: s })
}

/// Skips a payload the caller does not want.
pub fn skip_payload<R: Read>(r: &mut R, h: &Header) -> Result<(), WireError> {
    let mut left = h.len as usize;
    let mut buf = [0u8; 256];
    while left > 0 {
        let k = left.min(buf.len());
        r.read_exact(&mut buf[..k])?;
        left -= k;
    }
    Ok(())
}

#[cfg(feature = "alloc")]
mod message;
#[cfg(feature = "alloc")]
pub use message::*;
#[cfg(feature = "alloc")]
mod parts;
#[cfg(feature = "alloc")]
pub use parts::*;
