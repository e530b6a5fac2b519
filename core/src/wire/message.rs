//! Whole messages with their payloads (feature `alloc`): reading a message dispatches its
//! payload to its codec (the 12-byte frame here, the compact and layered codecs above the
//! framing), writing one sends the 12-byte forms.

use super::*;
use alloc::vec::Vec;

/// A whole Frame with its samples.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// The fixed part.
    pub header: FrameHeader,
    /// Packed samples.
    pub samples: Vec<u64>,
    /// Premultiplied RGBA8 colors, one per sample.
    pub colors: Vec<u32>,
    /// Layered frames (version 3, `crate::segments`): each sample's index among its pixel's
    /// segments, front to back (a pixel's samples are consecutive, its first has index 0).
    /// Empty for a one-sample-per-pixel frame.
    pub segments: Vec<u8>,
}

impl Frame {
    /// A one-sample-per-pixel frame.
    pub fn new(header: FrameHeader, samples: Vec<u64>, colors: Vec<u32>) -> Frame {
        Frame { header, samples, colors, segments: Vec::new() }
    }

    /// The most segments any pixel has (1 for a one-sample-per-pixel frame).
    pub fn layers(&self) -> u8 {
        self.segments.iter().max().map_or(1, |&m| m.saturating_add(1))
    }
}

/// Any message.
// The visual messages hold their bounded points and names inline (heapless, so the codec stays
// allocation-free on no_std); 1.7 KB is nothing beside a frame's buffers, and a message is read
// and handled one at a time, so boxing would only add an allocation per edit.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq)]
pub enum Message {
    /// Hello.
    Hello(Hello),
    /// CameraRequest.
    CameraRequest(CameraRequest),
    /// Frame.
    Frame(Frame),
    /// Error.
    Error(ErrorMsg),
    /// Bye.
    Bye,
    /// VisualEdit (version 4).
    VisualEdit(VisualEdit),
    /// VisualState (version 4).
    VisualState(VisualState),
}

/// Reads one whole message. Allocates at most `count × 12` bytes for a Frame, and only
/// after its header passed the limits.
pub fn read_message<R: Read>(r: &mut R, limits: &Limits) -> Result<Message, WireError> {
    let mut parts = Assembly::new();
    loop {
        let h = match read_header(r, limits) {
            Err(WireError::Closed) if !parts.is_empty() => return Err(WireError::UnexpectedEof),
            h => h?,
        };
        // A frame sent in parts (version 6) is decoded once its last part is in.
        if let Some((bytes, h)) = take_part(r, &h, limits, &mut parts)? {
            return decode_message(&bytes, &h, limits);
        }
        if !matches!(h.ty, MsgType::FramePart | MsgType::FrameDropped) {
            return read_payload(r, &h, limits);
        }
    }
}

/// Reads the payload of a message whose header was read already.
pub fn read_payload<R: Read>(r: &mut R, h: &Header, limits: &Limits) -> Result<Message, WireError> {
    Ok(match h.ty {
        MsgType::Hello => Message::Hello(read_hello(r, h)?),
        MsgType::CameraRequest => Message::CameraRequest(read_camera_request(r, h, limits)?),
        MsgType::Frame => {
            let (header, layers) = read_frame_header_layered(r, h, limits)?;
            let n = header.count as usize;
            let mut samples = alloc::vec![0u64; n];
            let mut colors = alloc::vec![0u32; n];
            read_frame_body(r, &header, &mut samples, &mut colors)?;
            let mut segments = Vec::new();
            if layers > 0 {
                segments = alloc::vec![0u8; n];
                r.read_exact(&mut segments)?;
                crate::segments::validate(&header, &samples, &colors, &segments, layers).map_err(WireError::Layers)?;
            }
            Message::Frame(Frame { header, samples, colors, segments })
        }
        MsgType::Error => Message::Error(read_error(r, h)?),
        MsgType::Bye => Message::Bye,
        MsgType::VisualEdit => Message::VisualEdit(read_visual_edit(r, h)?),
        MsgType::VisualState => Message::VisualState(read_visual_state(r, h)?),
        MsgType::CompactFrame => {
            // The length passed the limit in `read_header`; the decoder bounds the rest.
            let mut payload = alloc::vec![0u8; h.len as usize];
            r.read_exact(&mut payload)?;
            Message::Frame(crate::compact_frame::decode_payload(&payload, limits)?)
        }
        MsgType::LayeredCompactFrame => {
            let mut payload = alloc::vec![0u8; h.len as usize];
            r.read_exact(&mut payload)?;
            Message::Frame(crate::segments::decode_layered_payload(&payload, limits)?)
        }
        // Read through `read_message` or `read_message_bytes`, which reassemble them.
        MsgType::FramePart | MsgType::FrameDropped => return Err(WireError::BadParts("a frame part read alone")),
    })
}

/// Writes any message.
pub fn write_message<W: Write>(w: &mut W, m: &Message) -> Result<(), WireError> {
    match m {
        Message::Hello(h) => write_hello(w, h),
        Message::CameraRequest(c) => write_camera_request(w, c),
        Message::Frame(f) => write_frame_layered(w, &f.header, &f.samples, &f.colors, &f.segments),
        Message::Error(e) => write_error(w, e),
        Message::Bye => write_bye(w),
        Message::VisualEdit(e) => write_visual_edit(w, e),
        Message::VisualState(s) => write_visual_state(w, s),
    }
}

/// Encodes a message into a new buffer.
pub fn encode_to_vec(m: &Message) -> Vec<u8> {
    let mut v = Vec::new();
    write_message(&mut VecWriter(&mut v), m).expect("writing to a Vec cannot fail");
    v
}

/// An `embedded_io::Write` into a `Vec<u8>`.
pub struct VecWriter<'a>(pub &'a mut Vec<u8>);

impl embedded_io::ErrorType for VecWriter<'_> {
    type Error = core::convert::Infallible;
}

impl Write for VecWriter<'_> {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.0.extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}
