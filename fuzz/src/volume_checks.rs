//! Properties of target `volume_header`: the server's NRRD header parser and raw file name
//! parser on arbitrary input. Shared with the deterministic stable mirror in
//! `server/tests/hardening.rs` (included there with `#[path]`); depends only on
//! `volwarp-server`.

use volwarp_server::nrrd::{parse_header, Encoding, MAX_HEADER};
use volwarp_server::volume::parse_raw_name;

/// Target `volume_header`: byte 0 picks the parser (even: NRRD header of the rest, odd: raw
/// file name of the rest, lossily as UTF-8). No panic; error messages format; an accepted NRRD
/// header has positive sizes, a positive finite spacing if any, `byte skip >= -1` (−1 only
/// raw), attached data starting inside the input, and parses the same from its header bytes
/// alone (the parser never looks past the blank line); an accepted raw name has positive
/// dimensions and does not depend on the folder in front of it.
pub fn volume_header(data: &[u8]) {
    let Some((&sel, rest)) = data.split_first() else { return };
    if sel % 2 == 0 {
        match parse_header(rest) {
            Ok(h) => {
                assert!(h.dims.iter().all(|&d| d > 0), "size 0 accepted: {h:?}");
                if let Some(s) = h.spacing {
                    assert!(s.is_finite() && s.min_element() > 0.0, "spacing {s} accepted");
                }
                assert!(h.byte_skip >= -1);
                assert!(h.byte_skip != -1 || h.encoding == Encoding::Raw);
                assert!(h.data_offset <= rest.len(), "data offset past the input");
                assert!(h.data_offset <= MAX_HEADER + 2, "header longer than the limit");
                let again = parse_header(&rest[..h.data_offset]);
                assert_eq!(again.as_ref().ok(), Some(&h), "the header parse depends on the data after it");
            }
            Err(e) => {
                let _ = e.to_string();
            }
        }
    } else {
        let name = String::from_utf8_lossy(rest);
        match parse_raw_name(&name) {
            Ok(r) => {
                assert!(r.dims.iter().all(|&d| d > 0), "dimension 0 accepted: {r:?}");
                let in_dir = format!("some/dir\\{name}");
                if !name.contains(['/', '\\']) {
                    assert_eq!(parse_raw_name(&in_dir).ok(), Some(r), "the folder changed the result");
                }
            }
            Err(e) => {
                let _ = e.to_string();
            }
        }
    }
}
