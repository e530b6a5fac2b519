//! Which wire encoding a frame goes out in: the 12-byte form (message type 3) or the compact
//! form of [`volwarp_core::compact_frame`] (message type 6), negotiated per client in the
//! Hello exchange ([`volwarp_core::wire::CAP_COMPACT`]).
//!
//! The server knows each frame's radius model exactly ([`crate::radius::FrameRadius`]), so
//! radius codes cost nothing in the compact form unless a depth rounds to the next code. The
//! body is entropy coded with the C zstd library (entropy level [`ZSTD_LEVEL`]) with the
//! body's runs of identical bytes as its only matches (`volwarp_core::byte_runs`): about 10×
//! faster than ruzstd's pure-Rust encoder (core's default) at a better ratio, and 2.4× faster
//! than the library's own level 1; clients decode either with ruzstd or C zstd
//! (`docs/perf.md`, "The compact codec").

use crate::marcher::Marcher;
use rayon::prelude::*;
use volwarp_core::compact_frame::{self, Coder, EncodeOptions, Encoding, RadiusPrediction};
use volwarp_core::wire::{self, CameraRequest, Frame, FrameHeader};

/// The zstd level of the compact body (1: fastest; higher levels gain little on residuals).
pub const ZSTD_LEVEL: i32 = 1;

/// The compact encoder's settings for a frame the marcher rendered for `req`: the frame's own
/// radius model, default depth precision, zstd, and colors coded against green where that is
/// smaller (a receiver that announced `CAP_COLOR_GREEN`; see [`encode_frame_for`]).
pub fn encode_options(marcher: &Marcher, req: &CameraRequest) -> EncodeOptions {
    let r = marcher.frame_radius(req);
    EncodeOptions {
        radius: Some(RadiusPrediction { constant: r.constant(), per_depth: r.per_depth() }),
        colors_against_green: true,
        ..EncodeOptions::default()
    }
}

/// The compact message (header included) of `frame` with C zstd at `level` over the byte-run
/// parse ([`compact_frame::compress_c`]), or `None` if the frame does not fit the compact form.
pub fn encode_compact(frame: &Frame, opts: &EncodeOptions, level: i32) -> Option<Vec<u8>> {
    if !frame.segments.is_empty() {
        // A layered frame: one compact part per layer, in a LayeredCompactFrame;
        // the parts are encoded in parallel (the same bytes as one after another).
        let layers = volwarp_core::segments::layer_frames(frame).ok()?;
        let msgs: Vec<Vec<u8>> =
            layers.par_iter().map(|layer| encode_compact(layer, opts, level)).collect::<Option<_>>()?;
        return volwarp_core::segments::assemble_layered(frame, &msgs).ok();
    }
    let planes = compact_frame::wire_planes(frame, opts).ok()?;
    let coded = match planes.params.coder {
        Coder::Zstd => compact_frame::compress_c(&planes.body, level),
        Coder::Stored => planes.body,
    };
    let header = FrameHeader { count: frame.samples.len() as u32, ..frame.header };
    compact_frame::assemble(&header, &planes.params, &coded).ok()
}

/// The message bytes (header included) of a frame the marcher rendered for `req`, in
/// `encoding`; a frame the compact form cannot hold (samples off their pixels' rays, e.g. at
/// extreme zoom) goes out in the 12-byte form. Returns the bytes and the form they are in.
pub fn encode_frame(marcher: &Marcher, req: &CameraRequest, frame: &Frame, encoding: Encoding) -> (Vec<u8>, Encoding) {
    encode_frame_for(marcher, req, frame, encoding, true)
}

/// [`encode_frame`] for a receiver that reads colors coded against green (`green`: it
/// announced [`wire::CAP_COLOR_GREEN`]) or not.
pub fn encode_frame_for(
    marcher: &Marcher,
    req: &CameraRequest,
    frame: &Frame,
    encoding: Encoding,
    green: bool,
) -> (Vec<u8>, Encoding) {
    if encoding == Encoding::Compact {
        let opts = EncodeOptions { colors_against_green: green, ..encode_options(marcher, req) };
        if let Some(b) = encode_compact(frame, &opts, ZSTD_LEVEL) {
            return (b, Encoding::Compact);
        }
    }
    (raw12_bytes(frame), Encoding::Raw12)
}

/// The message bytes (header included) of `frame` in the 12-byte form (a Frame message),
/// written from the frame as it is (no copy of its arrays).
pub fn raw12_bytes(frame: &Frame) -> Vec<u8> {
    let mut bytes = Vec::new();
    // Writing to a Vec cannot fail.
    let _ = wire::write_frame_layered(
        &mut wire::VecWriter(&mut bytes),
        &frame.header,
        &frame.samples,
        &frame.colors,
        &frame.segments,
    );
    bytes
}
