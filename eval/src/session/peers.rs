//! The peers: what users would pick instead of warping, charged with real costs.
//!
//! Remote renderers that send images (ParaView/trame remote rendering, vtk.js, VTK's level of
//! detail) hide latency one way: *while the camera moves, render smaller and compress harder*,
//! then show the newest image upscaled. Two of them run in a session beside the warping
//! methods:
//!
//! - `send-image`: the server's full-resolution image as JPEG at quality 90 (trame's still
//!   quality), for the camera shown at every tick it moved;
//! - `downscale` (`downscale=4`): while the camera moves the server renders at 1/2 (1/4) of the
//!   resolution and sends it as JPEG at quality 50 (trame's `interactive_ratio` and
//!   `interactive_quality`); at the first tick the camera rests the client asks once more and
//!   the server sends the full-resolution image at quality 90.
//!
//! The images are encoded by a real JPEG encoder (`image`'s), their bytes charged on the
//! simulated link like a frame's, and decoded by a real decoder (`zune-jpeg` through `image`)
//! before they are scored; the client shows the newest image upscaled bilinearly to the
//! viewport. A reduced image's server time is `server_ms` times the real marcher's measured
//! ratio ([`ResolutionCost`], from `session-calibrate`).

use super::model::{NetworkModel, Request, ServerPolicy};
use super::simulate::{FrameEvent, Looks, TruthCache};
use crate::ErrorBox;
use image::codecs::jpeg::JpegEncoder;
use image::{ImageFormat, RgbImage};
use volwarp_core::{Camera, Image};

/// JPEG quality of a full-resolution image (the camera rests, or `send-image`).
pub const STILL_QUALITY: u8 = 90;
/// JPEG quality of a reduced image while the camera moves (trame's `interactive_quality`).
pub const INTERACTIVE_QUALITY: u8 = 50;

/// An image-sending peer: the resolution divisor and JPEG quality while the camera moves.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImagePeer {
    /// Resolution divisor while moving (1: full resolution always, `send-image`).
    pub factor: u32,
    /// JPEG quality while moving.
    pub moving_quality: u8,
    /// JPEG quality at rest (and of `send-image`).
    pub still_quality: u8,
}

impl ImagePeer {
    /// `send-image`: full resolution at quality 90.
    pub const SEND_IMAGE: ImagePeer =
        ImagePeer { factor: 1, moving_quality: STILL_QUALITY, still_quality: STILL_QUALITY };

    /// Parses `send-image`, `downscale` (1/2) or `downscale=N` (N = 2 or 4); `None` if the name
    /// is not a peer's, an error for a bad divisor.
    pub fn parse(spec: &str) -> Option<Result<ImagePeer, ErrorBox>> {
        let spec = spec.trim();
        if spec == "send-image" {
            return Some(Ok(ImagePeer::SEND_IMAGE));
        }
        let factor = match spec.strip_prefix("downscale") {
            Some("") => Ok(2),
            Some(rest) => match rest.strip_prefix('=').map(str::parse::<u32>) {
                Some(Ok(f @ (2 | 4))) => Ok(f),
                Some(_) => Err(format!("{spec}: downscale=N takes N = 2 or 4").into()),
                None => return None,
            },
            None => return None,
        };
        Some(factor.map(|factor| ImagePeer {
            factor,
            moving_quality: INTERACTIVE_QUALITY,
            still_quality: STILL_QUALITY,
        }))
    }

    /// The canonical name (`send-image`, `downscale`, `downscale=4`).
    pub fn name(&self) -> String {
        match self.factor {
            1 => "send-image".into(),
            2 => "downscale".into(),
            f => format!("downscale={f}"),
        }
    }

    /// Whether the client asks once more at the first tick the camera rests (to get the
    /// full-resolution image after reduced ones).
    pub fn asks_when_still(&self) -> bool {
        self.factor > 1
    }
}

/// The server's time to render at a reduced resolution, as a fraction of the full
/// resolution's: the real marcher's measured ratio.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ResolutionCost {
    /// Time at 1/2 of the resolution ÷ time at full resolution.
    pub half: f64,
    /// Time at 1/4 of the resolution ÷ time at full resolution.
    pub quarter: f64,
}

impl ResolutionCost {
    /// The ratios measured on the development machine when no calibration gives the dataset's
    /// own: the median over the five datasets of `session-calibrate --all --size 512 --runs 5`
    /// (`server` against `server/2` and `server/4` lines; `docs/results.md`, Peers).
    pub const MEASURED_512: ResolutionCost = ResolutionCost { half: 0.35, quarter: 0.10 };

    /// The fraction of the full resolution's server time at divisor `factor` (1: 1).
    pub fn ratio(&self, factor: u32) -> f64 {
        match factor {
            0 | 1 => 1.0,
            2 => self.half,
            _ => self.quarter,
        }
    }
}

/// The calibration name of a dataset's server time at divisor `factor` (`mri_colin27/2`).
pub fn scaled_name(dataset: &str, factor: u32) -> String {
    format!("{dataset}/{factor}")
}

/// One image the server sent, decoded by the client.
pub struct HeldImage {
    /// The decoded image, at the resolution it was rendered at.
    pub image: Image,
}

/// The images served to one peer: their timeline and the decoded images.
pub struct ImageStream {
    /// The peer.
    pub peer: ImagePeer,
    /// Every image's timeline (bytes: the JPEG's).
    pub frames: Vec<FrameEvent>,
    /// The decoded images, in the same order.
    pub held: Vec<HeldImage>,
}

/// Encodes an opaque image as baseline JPEG (RGB) at `quality` with `image`'s encoder.
pub fn encode_jpeg(img: &Image, quality: u8) -> Result<Vec<u8>, ErrorBox> {
    let rgb: Vec<u8> = img.pixels.iter().flat_map(|p| p.to_le_bytes().into_iter().take(3)).collect();
    let mut out = Vec::new();
    JpegEncoder::new_with_quality(&mut out, quality).encode(
        &rgb,
        img.width,
        img.height,
        image::ExtendedColorType::Rgb8,
    )?;
    Ok(out)
}

/// Decodes a JPEG into an opaque image (a clear error for bytes that are not one).
pub fn decode_jpeg(bytes: &[u8]) -> Result<Image, ErrorBox> {
    let rgb = image::load_from_memory_with_format(bytes, ImageFormat::Jpeg)?.to_rgb8();
    Ok(from_rgb(&rgb))
}

fn from_rgb(rgb: &RgbImage) -> Image {
    let pixels = rgb.pixels().map(|p| u32::from_le_bytes([p[0], p[1], p[2], 255])).collect();
    Image { width: rgb.width(), height: rgb.height(), pixels }
}

/// The requests of a peer over the ticks' cameras: one at every tick the camera moved
/// (reduced), and for a downscaling peer one at the first tick it rests (full resolution).
/// The `bool` says whether the request is for a reduced image.
fn requests(cams: &[Camera], looks: &Looks, tick_ms: f64, peer: ImagePeer) -> Vec<(Request, bool)> {
    let mut out = Vec::new();
    for k in 1..cams.len() {
        let moved = cams[k] != cams[k - 1];
        let first_still = !moved && (k < 2 || cams[k - 1] != cams[k - 2]);
        let edited = looks.state_at(k) != looks.state_at(k - 1);
        if moved || edited || (first_still && peer.asks_when_still()) {
            out.push((Request { tick: k, sent_ms: k as f64 * tick_ms, camera: cams[k] }, moved));
        }
    }
    out
}

/// Runs the server and the network for a peer: as [`super::simulate::serve`] does for frames
/// (the server takes the newest request that arrived, its policy picks the camera, it renders
/// in its time and writes the bytes to the link, blocking), but each render is the marcher's
/// image at the request's resolution, in `net.server_ms × cost.ratio(factor)`, sent as JPEG.
/// Full-resolution images come from the truth cache (the same marcher image). Each image is
/// rendered with the visual state of the newest request it serves (`looks`).
#[allow(clippy::too_many_arguments)]
pub fn serve_images(
    looks: &Looks,
    cams: &[Camera],
    tick_ms: f64,
    net: NetworkModel,
    cost: ResolutionCost,
    policy: &mut dyn ServerPolicy,
    peer: ImagePeer,
    truths: &mut TruthCache,
) -> Result<ImageStream, ErrorBox> {
    let end_ms = (cams.len() - 1) as f64 * tick_ms;
    let mut render = |camera: &Camera, reduced: bool, state: usize| -> Result<(Image, u64), ErrorBox> {
        let (factor, quality) =
            if reduced && peer.factor > 1 { (peer.factor, peer.moving_quality) } else { (1, peer.still_quality) };
        let bytes = if factor == 1 {
            encode_jpeg(truths.get_in(looks, state, camera), quality)?
        } else {
            let small = camera.with_viewport((camera.width / factor).max(1), (camera.height / factor).max(1));
            encode_jpeg(&looks.marcher(state).render_image(&small), quality)?
        };
        Ok((decode_jpeg(&bytes)?, bytes.len() as u64))
    };
    let (first, first_bytes) = render(&cams[0], false, looks.state_at(0))?;
    let mut stream = ImageStream {
        peer,
        frames: vec![FrameEvent::at_start(cams[0], net.server_ms, first_bytes, looks.state_at(0))],
        held: vec![HeldImage { image: first }],
    };
    let requests = requests(cams, looks, tick_ms, peer);
    let plain: Vec<Request> = requests.iter().map(|r| r.0).collect();
    let arrival = |r: &Request| r.sent_ms + net.latency_ms;
    let (mut s, mut served) = (0.0f64, 0usize);
    while served < requests.len() {
        let mut j = served;
        while j + 1 < requests.len() && arrival(&plain[j + 1]) <= s {
            j += 1;
        }
        s = s.max(arrival(&plain[j]));
        let reduced = requests[j].1 && peer.factor > 1;
        let server_ms = net.server_ms * if reduced { cost.ratio(peer.factor) } else { 1.0 };
        if s + server_ms + net.latency_ms > end_ms {
            break; // it would arrive after the session
        }
        let camera = policy.camera(&plain[..=j], s);
        served = j + 1;
        let state = looks.state_at(plain[j].tick);
        let (image, bytes) = render(&camera, reduced, state)?;
        let write_end = s + server_ms + net.transfer_ms(bytes);
        let arrive_ms = write_end + net.latency_ms;
        if arrive_ms <= end_ms {
            stream.frames.push(FrameEvent {
                state,
                seq: stream.frames.len(),
                camera,
                view: camera,
                guard_offset: (0, 0),
                divisor: if reduced { peer.factor } else { 1 },
                request_ms: plain[j].sent_ms,
                start_ms: s,
                render_ms: server_ms,
                bytes,
                arrive_ms,
            });
            stream.held.push(HeldImage { image });
        }
        s = write_end;
    }
    Ok(stream)
}

/// What a peer shows for `camera`: its newest image `held`, upscaled bilinearly to the viewport.
pub fn show(held: &HeldImage, camera: &Camera, out: &mut Image) {
    held.image.resize_into(camera.width, camera.height, out);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn peers_parse_and_name_canonically() {
        assert_eq!(ImagePeer::parse("send-image").unwrap().unwrap(), ImagePeer::SEND_IMAGE);
        let d = ImagePeer::parse("downscale").unwrap().unwrap();
        assert_eq!((d.factor, d.moving_quality, d.still_quality), (2, 50, 90));
        assert_eq!(d.name(), "downscale");
        let q = ImagePeer::parse("downscale=4").unwrap().unwrap();
        assert_eq!((q.factor, q.name().as_str()), (4, "downscale=4"));
        assert_eq!(ImagePeer::parse("downscale=2").unwrap().unwrap(), d);
        assert!(ImagePeer::parse("downscale=3").unwrap().is_err());
        assert!(ImagePeer::parse("downscale=x").unwrap().is_err());
        assert!(ImagePeer::parse("splat").is_none());
        assert!(ImagePeer::parse("downscaler").is_none());
    }

    #[test]
    fn jpeg_round_trips_close_and_smaller_at_lower_quality() {
        // A smooth gradient: JPEG keeps it within a few levels.
        let (w, h) = (64u32, 48u32);
        let pixels = (0..w * h).map(|i| u32::from_le_bytes([(i % w * 4) as u8, (i / w * 5) as u8, 100, 255])).collect();
        let img = Image { width: w, height: h, pixels };
        let q90 = encode_jpeg(&img, 90).unwrap();
        let q50 = encode_jpeg(&img, 50).unwrap();
        assert!(q50.len() < q90.len(), "{} vs {}", q50.len(), q90.len());
        assert_eq!(&q90[..2], &[0xFF, 0xD8], "a JPEG stream (SOI)");
        let back = decode_jpeg(&q90).unwrap();
        assert_eq!((back.width, back.height), (w, h));
        let worst = img
            .pixels
            .iter()
            .zip(&back.pixels)
            .flat_map(|(a, b)| {
                let (a, b) = (a.to_le_bytes(), b.to_le_bytes());
                (0..3).map(move |c| a[c].abs_diff(b[c]))
            })
            .max()
            .unwrap();
        assert!(worst <= 8, "q90 of a gradient within 8 levels: {worst}");
        assert!(back.pixels.iter().all(|p| p.to_le_bytes()[3] == 255));
        assert!(decode_jpeg(&q90[..q90.len() / 3]).is_err() || decode_jpeg(b"not a jpeg").is_err());
        assert!(decode_jpeg(b"not a jpeg").is_err());
    }
}
