//! Properties of targets `volume_header` (the server's NRRD header parser and raw file name
//! parser on arbitrary input) and `volume_load` (the whole load of a file, header and data). Shared with the deterministic stable mirror in
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

/// Most voxels `volume_load` lets a file declare: small, so that an accepted volume costs at
/// most a few hundred kilobytes and a declared size past it is refused before any allocation.
pub const LOAD_MAX_VOXELS: u64 = 1 << 16;

/// Target `volume_load`: the whole load of a volume file, header and data, through
/// `volwarp_server::volume::load_volume` with a small voxel limit ([`LOAD_MAX_VOXELS`]). Byte 0
/// even: the rest is a NRRD file (`v.nrrd`; the same bytes also lie in `d.raw` and `d.raw.gz`
/// beside it, for headers naming a detached data file); odd: the rest up to its first newline is
/// a raw file's name (letters, digits, `_`, `.` and `-` kept, at most 100) and what follows is the
/// file's content, in whichever format `load_volume` recognizes by name and content (the seeds
/// hold raw, NRRD, NIfTI, `.vti`, TIFF and DICOM files). No panic, no allocation past the limit; an accepted volume has at most
/// [`LOAD_MAX_VOXELS`] voxels, positive dims and finite normalized values in `0..=1`; errors name
/// the file.
pub fn volume_load(data: &[u8]) {
    use std::sync::OnceLock;
    use volwarp_server::volume::{load_volume, LoadOptions};
    static DIR: OnceLock<std::path::PathBuf> = OnceLock::new();
    let dir = DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("volwarp-fuzz-load-{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("a temporary folder for volume_load");
        d
    });
    let Some((&sel, rest)) = data.split_first() else { return };
    let path = if sel % 2 == 0 {
        // A header naming another data file would read a file of this machine: not this target's.
        if parse_header(rest).is_ok_and(|h| h.data_file.as_deref().is_some_and(|f| f != "d.raw" && f != "d.raw.gz")) {
            return;
        }
        for name in ["d.raw", "d.raw.gz"] {
            std::fs::write(dir.join(name), rest).expect("write a detached data file");
        }
        let p = dir.join("v.nrrd");
        std::fs::write(&p, rest).expect("write the NRRD file");
        p
    } else {
        let cut = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        let name: String = String::from_utf8_lossy(&rest[..cut])
            .chars()
            .filter(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '.' | '-'))
            .take(100)
            .collect();
        let name = if name.is_empty() || name.starts_with('.') { format!("v{name}") } else { name };
        let p = dir.join(name);
        std::fs::write(&p, rest.get(cut + 1..).unwrap_or(&[])).expect("write the raw file");
        p
    };
    let opts = LoadOptions { max_voxels: LOAD_MAX_VOXELS, ..LoadOptions::default() };
    match load_volume(&path, &opts) {
        Ok(v) => {
            let dims = v.dims();
            assert!(dims.iter().all(|&d| d > 0), "dimension 0 accepted: {dims:?}");
            let n = dims.iter().map(|&d| d as u64).product::<u64>();
            assert!(n <= LOAD_MAX_VOXELS, "{dims:?} accepted past the limit");
            assert_eq!(v.values().len() as u64, n, "values for {dims:?}");
            assert!(v.values().iter().all(|x| (0.0..=1.0).contains(x)), "a value outside 0..=1 (or NaN)");
            let s = v.spacing();
            assert!(s.is_finite() && s.min_element() > 0.0, "spacing {s} accepted");
        }
        Err(e) => {
            assert!(e.path.is_some(), "the error names no file: {e}");
            let _ = e.to_string();
        }
    }
    std::fs::remove_file(&path).ok();
}
