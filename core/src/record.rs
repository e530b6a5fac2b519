//! The record file: a received stream saved for offline replay (documented in
//! `docs/record-format.md`).
//!
//! A file is the 8 magic bytes `VWREC\0\0\x01` followed by entries. Each entry is a 12-byte
//! prefix — kind (`u8`: 1 = a Frame as received, 2 = a camera as displayed), 3 reserved zero
//! bytes, the time in microseconds since the recording started (`u64` LE) — and one complete
//! wire message (header and payload, exactly the bytes of [`crate::wire`]): a `Frame` for kind
//! 1, a `CameraRequest` for kind 2.

use crate::wire::WireError;
use embedded_io::{Read, Write};

/// Magic bytes that start a record file.
pub const RECORD_MAGIC: [u8; 8] = *b"VWREC\0\0\x01";

/// Entry kinds.
#[repr(u8)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EntryKind {
    /// A Frame as received from the server.
    Frame = 1,
    /// The camera the client displayed (a CameraRequest message).
    Camera = 2,
}

/// Why a record file could not be read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RecordError {
    /// The file does not start with [`RECORD_MAGIC`].
    BadMagic,
    /// Unknown entry kind.
    BadKind(u8),
    /// The entry's message does not match its kind.
    WrongMessage,
    /// The message inside could not be decoded.
    Wire(WireError),
}

impl From<WireError> for RecordError {
    fn from(e: WireError) -> Self {
        RecordError::Wire(e)
    }
}

impl core::fmt::Display for RecordError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            RecordError::BadMagic => f.write_str("not a volwarp record file"),
            RecordError::BadKind(k) => write!(f, "unknown record entry kind {k}"),
            RecordError::WrongMessage => f.write_str("record entry holds the wrong message type"),
            RecordError::Wire(e) => write!(f, "record entry: {e}"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for RecordError {}

/// Writes the magic bytes.
pub fn write_magic<W: Write>(w: &mut W) -> Result<(), WireError> {
    w.write_all(&RECORD_MAGIC).map_err(|e| WireError::Io(embedded_io::Error::kind(&e)))
}

/// Reads and checks the magic bytes.
pub fn read_magic<R: Read>(r: &mut R) -> Result<(), RecordError> {
    let mut m = [0u8; 8];
    r.read_exact(&mut m).map_err(|e| RecordError::Wire(e.into()))?;
    if m == RECORD_MAGIC {
        Ok(())
    } else {
        Err(RecordError::BadMagic)
    }
}

/// Writes an entry prefix; the caller then writes the wire message itself (e.g. the exact
/// frame bytes as received).
pub fn write_entry_prefix<W: Write>(w: &mut W, kind: EntryKind, t_us: u64) -> Result<(), WireError> {
    let mut p = [0u8; 12];
    p[0] = kind as u8;
    p[4..12].copy_from_slice(&t_us.to_le_bytes());
    w.write_all(&p).map_err(|e| WireError::Io(embedded_io::Error::kind(&e)))
}

/// Reads an entry prefix: `Ok(None)` at a clean end of file.
pub fn read_entry_prefix<R: Read>(r: &mut R) -> Result<Option<(EntryKind, u64)>, RecordError> {
    let mut p = [0u8; 12];
    let mut got = 0;
    while got < p.len() {
        let n = r.read(&mut p[got..]).map_err(|e| RecordError::Wire(WireError::Io(embedded_io::Error::kind(&e))))?;
        if n == 0 {
            return if got == 0 { Ok(None) } else { Err(RecordError::Wire(WireError::UnexpectedEof)) };
        }
        got += n;
    }
    let kind = match p[0] {
        1 => EntryKind::Frame,
        2 => EntryKind::Camera,
        k => return Err(RecordError::BadKind(k)),
    };
    Ok(Some((kind, u64::from_le_bytes(p[4..12].try_into().unwrap_or([0; 8])))))
}

#[cfg(feature = "alloc")]
pub use owned::*;

#[cfg(feature = "alloc")]
mod owned {
    use super::*;
    use crate::wire::{self, CameraRequest, Frame, Limits, Message};

    /// One decoded entry.
    #[derive(Clone, Debug, PartialEq)]
    pub enum Entry {
        /// A frame received at `t_us`.
        Frame {
            /// Microseconds since the recording started.
            t_us: u64,
            /// The frame.
            frame: Frame,
        },
        /// A camera displayed at `t_us`.
        Camera {
            /// Microseconds since the recording started.
            t_us: u64,
            /// The displayed camera (as a request).
            request: CameraRequest,
        },
    }

    /// Reads the next entry; `Ok(None)` at a clean end of file.
    pub fn read_entry<R: Read>(r: &mut R, limits: &Limits) -> Result<Option<Entry>, RecordError> {
        let Some((kind, t_us)) = read_entry_prefix(r)? else { return Ok(None) };
        let msg = wire::read_message(r, limits)?;
        match (kind, msg) {
            (EntryKind::Frame, Message::Frame(frame)) => Ok(Some(Entry::Frame { t_us, frame })),
            (EntryKind::Camera, Message::CameraRequest(request)) => Ok(Some(Entry::Camera { t_us, request })),
            _ => Err(RecordError::WrongMessage),
        }
    }

    /// Writes a whole entry.
    pub fn write_entry<W: Write>(w: &mut W, e: &Entry) -> Result<(), WireError> {
        match e {
            Entry::Frame { t_us, frame } => {
                write_entry_prefix(w, EntryKind::Frame, *t_us)?;
                wire::write_frame(w, &frame.header, &frame.samples, &frame.colors)
            }
            Entry::Camera { t_us, request } => {
                write_entry_prefix(w, EntryKind::Camera, *t_us)?;
                wire::write_camera_request(w, request)
            }
        }
    }
}
