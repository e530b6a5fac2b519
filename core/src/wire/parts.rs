//! Frames in parts (version 6, [`CAP_PARTS`]): a server may send a frame message as
//! FramePart messages (type 10), each carrying the next bytes, at most [`PART_LEN`], of the
//! whole frame message (its own 12-byte header first), and may end it early with FrameDropped
//! (type 11, empty), after which the receiver throws the bytes away. Between two parts the
//! server can drop a frame the view's turn has made stale, where a frame written whole would
//! hold the link until its last byte.
//!
//! The frame message inside is checked as any message is: its header against the receiver's
//! [`Limits`] as soon as its 12 bytes are in (so no more is ever held than a whole frame the
//! limits allow), and it must be a frame (Frame, CompactFrame or LayeredCompactFrame). No other
//! message may come between the parts of one frame.

use super::{
    parse_header, read_payload, read_raw_header, write_header, Header, Limits, Message, MsgType, WireError, HEADER_LEN,
    PART_LEN,
};
use alloc::vec::Vec;
use embedded_io::{Read, Write};

/// A frame message being reassembled from its parts.
#[derive(Clone, Debug, Default)]
pub struct Assembly {
    bytes: Vec<u8>,
    /// The frame message's header, once its 12 bytes are in and checked.
    header: Option<Header>,
}

impl Assembly {
    /// An empty assembly.
    pub const fn new() -> Self {
        Assembly { bytes: Vec::new(), header: None }
    }

    /// Whether no part of a frame is held.
    pub fn is_empty(&self) -> bool {
        self.bytes.is_empty()
    }

    /// Throws away the parts held (the sender dropped the frame).
    pub fn clear(&mut self) {
        self.bytes.clear();
        self.header = None;
    }

    /// Adds a part; the whole frame message (header included) and its header once the last
    /// part is in. On an error the assembly is cleared.
    pub fn push(&mut self, part: &[u8], limits: &Limits) -> Result<Option<(Vec<u8>, Header)>, WireError> {
        let r = self.push_inner(part, limits);
        if !matches!(r, Ok(None)) {
            // Done or failed: start afresh (a finished message is handed over whole).
            self.header = None;
        }
        if r.is_err() {
            self.bytes = Vec::new();
        }
        r
    }

    fn push_inner(&mut self, part: &[u8], limits: &Limits) -> Result<Option<(Vec<u8>, Header)>, WireError> {
        if part.is_empty() || part.len() > PART_LEN {
            return Err(WireError::BadParts("a part of 0 or more than PART_LEN bytes"));
        }
        let mut part = part;
        if self.header.is_none() {
            // The frame message's header, which may itself come in pieces.
            let k = (HEADER_LEN - self.bytes.len()).min(part.len());
            self.bytes.extend_from_slice(&part[..k]);
            part = &part[k..];
            if self.bytes.len() < HEADER_LEN {
                return Ok(None);
            }
            let mut head = [0u8; HEADER_LEN];
            head.copy_from_slice(&self.bytes[..HEADER_LEN]);
            let h = parse_header(&head, limits)?;
            if !matches!(h.ty, MsgType::Frame | MsgType::CompactFrame | MsgType::LayeredCompactFrame) {
                return Err(WireError::BadParts("the parts carry no frame"));
            }
            // The header passed the limits: at most one frame the receiver allows.
            self.bytes.try_reserve_exact(h.len as usize).map_err(|_| WireError::BadParts("no memory for the frame"))?;
            self.header = Some(h);
        }
        let Some(h) = self.header else { return Ok(None) };
        let total = HEADER_LEN + h.len as usize;
        if self.bytes.len() + part.len() > total {
            return Err(WireError::BadParts("a part runs past the frame's end"));
        }
        self.bytes.extend_from_slice(part);
        if self.bytes.len() < total {
            return Ok(None);
        }
        Ok(Some((core::mem::take(&mut self.bytes), h)))
    }
}

/// Reads one whole message's bytes (header included, as sent) and its header: a message as it
/// comes, or a frame reassembled from its parts (FrameDropped throws a frame's parts away, and
/// the next message is read). A message other than FramePart or FrameDropped between the parts
/// of a frame is [`WireError::BadParts`]; a stream that ends inside a frame's parts,
/// [`WireError::UnexpectedEof`]. Allocates at most one message the `limits` allow.
pub fn read_message_bytes<R: Read>(r: &mut R, limits: &Limits) -> Result<(Vec<u8>, Header), WireError> {
    let mut parts = Assembly::new();
    loop {
        let head = match read_raw_header(r) {
            Err(WireError::Closed) if !parts.is_empty() => return Err(WireError::UnexpectedEof),
            h => h?,
        };
        let h = parse_header(&head, limits)?;
        if let Some(whole) = take_part(r, &h, limits, &mut parts)? {
            return Ok(whole);
        }
        if matches!(h.ty, MsgType::FramePart | MsgType::FrameDropped) {
            continue;
        }
        let mut bytes = Vec::new();
        bytes.try_reserve_exact(HEADER_LEN + h.len as usize).map_err(|_| WireError::BadParts("no memory"))?;
        bytes.extend_from_slice(&head);
        bytes.resize(HEADER_LEN + h.len as usize, 0);
        r.read_exact(&mut bytes[HEADER_LEN..])?;
        return Ok((bytes, h));
    }
}

/// What a message whose header `h` was read does to the frame being reassembled: a FramePart's
/// payload is read and added (the whole frame once its last part is in), FrameDropped clears
/// it; any other message must not come while parts are held (`BadParts`) and is left unread.
pub fn take_part<R: Read>(
    r: &mut R,
    h: &Header,
    limits: &Limits,
    parts: &mut Assembly,
) -> Result<Option<(Vec<u8>, Header)>, WireError> {
    match h.ty {
        MsgType::FramePart => {
            // At most PART_LEN bytes (`parse_header`).
            let mut part = alloc::vec![0u8; h.len as usize];
            r.read_exact(&mut part)?;
            parts.push(&part, limits)
        }
        MsgType::FrameDropped => {
            parts.clear();
            Ok(None)
        }
        _ if !parts.is_empty() => {
            parts.clear();
            Err(WireError::BadParts("another message between a frame's parts"))
        }
        _ => Ok(None),
    }
}

/// Decodes a whole message's bytes (as [`read_message_bytes`] gives them).
pub fn decode_message(bytes: &[u8], h: &Header, limits: &Limits) -> Result<Message, WireError> {
    let mut payload = bytes.get(HEADER_LEN..).ok_or(WireError::UnexpectedEof)?;
    read_payload(&mut payload, h, limits)
}

/// Writes the next part of a frame message (`part`: at most [`PART_LEN`] bytes of it, in order).
pub fn write_frame_part<W: Write>(w: &mut W, part: &[u8]) -> Result<(), WireError> {
    if part.is_empty() || part.len() > PART_LEN {
        return Err(WireError::BadParts("a part of 0 or more than PART_LEN bytes"));
    }
    write_header(w, MsgType::FramePart, part.len() as u32)?;
    w.write_all(part).map_err(|e| WireError::Io(embedded_io::Error::kind(&e)))
}

/// Writes FrameDropped: the frame whose parts were sent is dropped.
pub fn write_frame_dropped<W: Write>(w: &mut W) -> Result<(), WireError> {
    write_header(w, MsgType::FrameDropped, 0)
}
