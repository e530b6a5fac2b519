//! The compact codec's fast paths on real frames of the marcher: the fast
//! encoder gives the scalar reference's planes byte for byte, the fast reconstruction the
//! reference's frame bit for bit, and C zstd (what std clients decompress with) the same body as
//! ruzstd (no_std clients), on the bundled CT head and, the MRI of `../shared/data`
//! (`volwarp_server::testdata`).

use volwarp_core::compact_frame::{
    build_planes, build_planes_reference, decode_body, decode_body_reference, decode_payload, decompress_c,
    decompress_ruzstd, read_params, COMPACT_FIXED_LEN,
};
use volwarp_core::wire::{CameraRequest, FrameHeader, Limits, HEADER_LEN};
use volwarp_core::Heuristic;
use volwarp_server::encoding::{encode_compact, encode_options, ZSTD_LEVEL};
use volwarp_server::{Dataset, Marcher};

fn check(m: &Marcher, name: &str) {
    let mut checked = 0;
    for (size, yaw, pitch, dolly, heuristic) in [
        (256, 0.0, 0.0, 1.0, Heuristic::Threshold),
        (320, 35.0, -20.0, 0.7, Heuristic::RelThreshold),
        (200, 170.0, 40.0, 0.5, Heuristic::Threshold),
    ] {
        let camera = m.default_camera(size, size * 3 / 4).orbit(yaw, pitch).dolly(dolly);
        let req = CameraRequest { seq: 1, camera, heuristic, radius_scale: 1.0, layers: 0 };
        let (frame, _) = m.render_frame(&req);
        assert!(frame.samples.len() > 1000, "{name}: a real frame");
        let opts = encode_options(m, &req);
        let fast = build_planes(&frame, &opts);
        assert_eq!(fast, build_planes_reference(&frame, &opts), "{name} {size} {yaw}: encoders differ");
        let Ok(planes) = fast else { continue };
        let header = FrameHeader { count: frame.samples.len() as u32, ..frame.header };
        let a = decode_body(&header, &planes.params, &planes.body).unwrap();
        let b = decode_body_reference(&header, &planes.params, &planes.body).unwrap();
        assert!(a == b, "{name} {size} {yaw}: decoders differ");
        assert_eq!(a.colors, frame.colors);
        // The server's message: both decompressors give the body, and the whole decode the frame.
        let bytes = encode_compact(&frame, &opts, ZSTD_LEVEL).unwrap();
        let (_, params) = read_params(&bytes[HEADER_LEN..], &Limits::default()).unwrap();
        let coded = &bytes[HEADER_LEN + COMPACT_FIXED_LEN..];
        // (Colors coded against green where the server chose it: undone, the planes again.)
        let n = frame.samples.len();
        for mut body in [decompress_c(coded, &params).unwrap(), decompress_ruzstd(coded, &params).unwrap()] {
            volwarp_core::compact_frame::undo_color_coding(&mut body, &params, n);
            assert!(body == planes.body, "{name} {size} {yaw}: the server's body differs from the planes");
        }
        assert!(decode_payload(&bytes[HEADER_LEN..], &Limits::default()).unwrap() == a);
        checked += 1;
    }
    assert!(checked >= 2, "{name}: most real frames fit the compact form");
}

#[test]
fn fast_codec_equals_the_reference_on_the_ct_head() {
    check(&Marcher::from_dataset(&Dataset::default_bundled()), "ct_head");
}

#[test]
fn fast_codec_equals_the_reference_on_the_mri() {
    let Some(ds) = volwarp_server::testdata::shared_dataset(volwarp_server::testdata::MRI) else { return };
    check(&Marcher::from_dataset(&ds), "mri");
}

/// A layered frame's parts are encoded in parallel: the same message, byte for byte, as
/// encoding them one after another (`segments::encode_layered_with`), and it decodes to the
/// frame's segments and colors.
#[test]
fn layered_frames_encode_in_parallel_as_in_sequence() {
    let m = Marcher::from_dataset(&Dataset::default_bundled());
    let camera = m.default_camera(256, 192).orbit(30.0, 10.0);
    let req = CameraRequest { seq: 3, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
    let (frame, _) = m.render_frame_layers(&req, 4);
    assert!(frame.layers() >= 2, "a layered frame");
    let opts = encode_options(&m, &req);
    let parallel = encode_compact(&frame, &opts, ZSTD_LEVEL).expect("encodes");
    let sequential = volwarp_core::segments::encode_layered_with(&frame, |layer| {
        encode_compact(layer, &opts, ZSTD_LEVEL).ok_or(volwarp_core::compact_frame::EncodeError::BadFrame)
    })
    .expect("encodes");
    assert_eq!(parallel, sequential);
    let back = volwarp_core::segments::decode_layered_payload(&parallel[HEADER_LEN..], &Limits::default()).unwrap();
    assert_eq!(back.segments, frame.segments);
    assert_eq!(back.colors, frame.colors);
}
