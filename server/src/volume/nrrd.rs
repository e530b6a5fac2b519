//! NRRD volumes (`.nrrd` with attached data, `.nhdr` with a detached data file), as ParaView,
//! 3D Slicer and teem write them: 3-D, raw or gzip encoding, little- or big-endian, spacing
//! from `spacings:` or the lengths of `space directions:`.
//!
//! [`parse_header`] takes the file's bytes and never panics (it is fuzzed); [`load`] reads the
//! voxels.

use super::orient::Reorient;
use super::stream::{stream_volume, StreamSpec};
use super::{decode_voxels, read_exactly, LoadOptions, Volume, VolumeError, VolumeErrorKind, VoxelType};
use std::path::{Path, PathBuf};
use volwarp_core::Vec3;

/// Longest header accepted, in bytes.
pub const MAX_HEADER: usize = 64 * 1024;

/// How the voxel data is encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    /// Plain bytes.
    Raw,
    /// A gzip stream.
    Gzip,
}

/// The fields of a NRRD header this loader uses.
#[derive(Clone, Debug, PartialEq)]
pub struct NrrdHeader {
    /// Voxel type.
    pub voxel_type: VoxelType,
    /// Sizes (x, y, z).
    pub dims: [u32; 3],
    /// Encoding.
    pub encoding: Encoding,
    /// Big-endian data (`endian: big`).
    pub big_endian: bool,
    /// Spacing, if the header gives one.
    pub spacing: Option<Vec3>,
    /// Axes to mirror so that the volume box is `[0, dims · spacing]` in the orientation of
    /// `space directions` (world axis `a` runs against its file axis `perm[a]`), in LPS
    /// (`space: right-anterior-superior` and the like are converted).
    pub flip: [bool; 3],
    /// `perm[a]`: the file axis that becomes world axis `a` (the axis-aligned `space
    /// directions` of a permuted volume; `[0, 1, 2]` without directions). Oblique directions are
    /// an error.
    pub perm: [usize; 3],
    /// The detached data file, if any (relative to the header's folder).
    pub data_file: Option<String>,
    /// Bytes to skip before the data (`byte skip:`; −1 = data is at the end of a raw file).
    pub byte_skip: i64,
    /// Where attached data starts in the file (just after the blank line ending the header).
    pub data_offset: usize,
}

fn bad(s: impl Into<String>) -> VolumeError {
    VolumeError::new(VolumeErrorKind::BadHeader(s.into()))
}

fn parse_f32_vec(s: &str) -> Option<Vec3> {
    // "(1,0,0)" → vector
    let s = s.trim().strip_prefix('(')?.strip_suffix(')')?;
    let mut it = s.split(',').map(|v| v.trim().parse::<f32>().ok());
    let v = Vec3::new(it.next()??, it.next()??, it.next()??);
    if it.next().is_some() {
        return None;
    }
    Some(v)
}

/// Parses a NRRD header from the start of a file (`bytes` may hold the whole file). Never
/// panics; unknown fields and `key:=value` pairs are ignored.
pub fn parse_header(bytes: &[u8]) -> Result<NrrdHeader, VolumeError> {
    if !bytes.starts_with(b"NRRD") {
        return Err(bad("does not start with the NRRD magic"));
    }
    // The header ends at the first empty line (or at the end of a detached header).
    let limit = bytes.len().min(MAX_HEADER);
    let mut end = None;
    let mut i = 0;
    while i < limit {
        if bytes[i] == b'\n' {
            let next = i + 1;
            if bytes.get(next) == Some(&b'\n') {
                end = Some((next, next + 1));
                break;
            }
            if bytes.get(next) == Some(&b'\r') && bytes.get(next + 1) == Some(&b'\n') {
                end = Some((next, next + 2));
                break;
            }
        }
        i += 1;
    }
    let (header_end, data_offset) = match end {
        Some(e) => e,
        None if bytes.len() <= MAX_HEADER => (bytes.len(), bytes.len()),
        None => return Err(bad(format!("no end of header within {MAX_HEADER} bytes"))),
    };
    let text = std::str::from_utf8(&bytes[..header_end]).map_err(|_| bad("header is not text"))?;
    let mut lines = text.lines();
    let magic = lines.next().unwrap_or("").trim();
    if !(magic.len() == 8 && magic.starts_with("NRRD000") && magic.as_bytes()[7].is_ascii_digit()) {
        return Err(bad(format!("unknown magic {magic:?}")));
    }
    let (mut ty, mut dimension, mut sizes, mut encoding) = (None, None, None, None);
    let (mut big_endian, mut spacing, mut data_file, mut byte_skip) = (false, None, None, 0i64);
    let mut directions: Option<[[f64; 3]; 3]> = None;
    // The sign of x and y to put `space` into LPS.
    let mut to_lps = [1.0f64, 1.0, 1.0];
    for line in lines {
        let line = line.trim_end_matches('\r');
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if line.contains(":=") && line.find(":=") < line.find(": ") {
            continue; // key/value pair
        }
        let Some((field, value)) = line.split_once(':') else {
            return Err(bad(format!("line {line:?} is not `field: value`")));
        };
        let value = value.trim();
        match field.trim().to_ascii_lowercase().as_str() {
            "type" => {
                ty =
                    Some(VoxelType::parse(value).ok_or_else(|| {
                        VolumeError::new(VolumeErrorKind::UnknownType(value.chars().take(40).collect()))
                    })?)
            }
            "dimension" => dimension = Some(value.parse::<u32>().map_err(|_| bad(format!("dimension {value:?}")))?),
            "sizes" => {
                let v: Result<Vec<u32>, _> = value.split_whitespace().take(17).map(|s| s.parse::<u32>()).collect();
                sizes = Some(v.map_err(|_| bad(format!("sizes {value:?}")))?);
            }
            "encoding" => {
                encoding = Some(match value.to_ascii_lowercase().as_str() {
                    "raw" => Encoding::Raw,
                    "gzip" | "gz" => Encoding::Gzip,
                    other => {
                        return Err(VolumeError::new(VolumeErrorKind::Unsupported(format!(
                            "NRRD encoding {:?} (only raw and gzip)",
                            other.chars().take(20).collect::<String>()
                        ))))
                    }
                })
            }
            "endian" => {
                big_endian = match value.to_ascii_lowercase().as_str() {
                    "little" => false,
                    "big" => true,
                    _ => return Err(bad(format!("endian {value:?}"))),
                }
            }
            "spacings" => {
                let v: Vec<f32> = value.split_whitespace().take(17).filter_map(|s| s.parse::<f32>().ok()).collect();
                if v.len() == 3 {
                    spacing = Some(Vec3::new(v[0], v[1], v[2]));
                } else {
                    return Err(bad(format!("spacings {value:?}")));
                }
            }
            "space" => {
                to_lps = match value.to_ascii_lowercase().as_str() {
                    "right-anterior-superior" | "ras" => [-1.0, -1.0, 1.0],
                    "left-anterior-superior" | "las" => [1.0, -1.0, 1.0],
                    _ => [1.0, 1.0, 1.0], // LPS, scanner and 3-D spaces: taken as they are
                }
            }
            "space directions" => {
                let v: Vec<&str> = value.split_whitespace().take(17).collect();
                if v.len() != 3 {
                    return Err(bad(format!("space directions {value:?}")));
                }
                let mut cols = [[0f64; 3]; 3];
                for (c, t) in cols.iter_mut().zip(&v) {
                    let dir = parse_f32_vec(t).ok_or_else(|| bad(format!("space direction {t:?}")))?;
                    *c = [dir.x as f64, dir.y as f64, dir.z as f64];
                }
                directions = Some(cols);
            }
            "data file" | "datafile" => {
                if value.split_whitespace().count() > 1 || value.eq_ignore_ascii_case("list") {
                    return Err(VolumeError::new(VolumeErrorKind::Unsupported(
                        "NRRD data file lists and format strings (one data file only)".into(),
                    )));
                }
                data_file = Some(value.to_string());
            }
            "byte skip" | "byteskip" => {
                byte_skip =
                    value.parse::<i64>().ok().filter(|&b| b >= -1).ok_or_else(|| bad(format!("byte skip {value:?}")))?
            }
            "line skip" | "lineskip" if value != "0" => {
                return Err(VolumeError::new(VolumeErrorKind::Unsupported("NRRD line skip".into())));
            }
            _ => {}
        }
    }
    let voxel_type = ty.ok_or_else(|| bad("missing `type`"))?;
    let dimension = dimension.ok_or_else(|| bad("missing `dimension`"))?;
    let sizes = sizes.ok_or_else(|| bad("missing `sizes`"))?;
    if dimension != 3 || sizes.len() != 3 {
        return Err(VolumeError::new(VolumeErrorKind::Unsupported(format!(
            "{dimension}-D NRRD (only 3-D scalar volumes)"
        ))));
    }
    if sizes.contains(&0) {
        return Err(bad("a size is 0"));
    }
    let encoding = encoding.ok_or_else(|| bad("missing `encoding`"))?;
    // Axis-aligned directions (in LPS) reorder the volume; oblique ones are refused.
    let (mut flip, mut perm) = ([false; 3], [0, 1, 2]);
    if let Some(cols) = directions {
        let lps = cols.map(|c| [c[0] * to_lps[0], c[1] * to_lps[1], c[2] * to_lps[2]]);
        let r = super::orient::axis_aligned(lps)?;
        (flip, perm) = (r.flip, r.perm);
        // Spacing along the file axes: the directions' lengths.
        let len = |c: [f64; 3]| (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt() as f32;
        spacing = spacing.or(Some(Vec3::new(len(cols[0]), len(cols[1]), len(cols[2]))));
    }
    if let Some(s) = spacing {
        if !s.is_finite() || s.min_element() <= 0.0 {
            return Err(bad(format!("spacing {s} is not positive and finite")));
        }
    }
    if byte_skip == -1 && encoding != Encoding::Raw {
        return Err(bad("byte skip -1 needs raw encoding"));
    }
    Ok(NrrdHeader {
        voxel_type,
        dims: [sizes[0], sizes[1], sizes[2]],
        encoding,
        big_endian,
        spacing,
        flip,
        perm,
        data_file,
        byte_skip,
        data_offset,
    })
}

/// Loads a `.nrrd` or `.nhdr` volume.
pub fn load(path: &Path, opts: &LoadOptions) -> Result<Volume, VolumeError> {
    let io = |p: &Path, e| VolumeError::new(VolumeErrorKind::Io(e)).at(p);
    let mut head = Vec::new();
    {
        use std::io::Read;
        let f = std::fs::File::open(path).map_err(|e| io(path, e))?;
        f.take(MAX_HEADER as u64).read_to_end(&mut head).map_err(|e| io(path, e))?;
    }
    let h = parse_header(&head).map_err(|e| e.at(path))?;
    let dims = opts.dims.unwrap_or(h.dims);
    let ty = opts.voxel_type.unwrap_or(h.voxel_type);
    // The header's orientation, unless the options override the dims.
    let (flip, perm) = if opts.dims.is_none() { (h.flip, h.perm) } else { ([false; 3], [0, 1, 2]) };
    // Spacing along the world axes (the header's is along the file axes).
    let spacing = opts.spacing.or(h.spacing.map(|s| Vec3::from(perm.map(|p| s[p])))).unwrap_or(Vec3::ONE);
    let reorient = Reorient { perm, flip, spacing };
    // Streamed into bricks unless the z axis is mirrored or the axes permuted (then decoded
    // whole and reordered).
    let whole_volume = flip[2] || perm != [0, 1, 2];
    let decoded = if whole_volume { 4 + ty.size() as u64 } else { 0 };
    let voxels =
        super::check_load(dims, spacing, opts, super::stream::stored_size(ty), decoded).map_err(|e| e.at(path))?;
    let expected = super::voxel_bytes(voxels, ty).map_err(|e| e.at(path))?;
    let (data_path, offset): (PathBuf, u64) = match &h.data_file {
        Some(f) => (path.parent().unwrap_or(Path::new(".")).join(f), 0),
        None => (path.to_path_buf(), h.data_offset as u64),
    };
    let file = std::fs::File::open(&data_path).map_err(|e| io(&data_path, e))?;
    let len = file.metadata().map_err(|e| io(&data_path, e))?.len();
    let mut reader = std::io::BufReader::new(file);
    let skip = match h.byte_skip {
        -1 => len.checked_sub(expected).ok_or_else(|| {
            VolumeError::new(VolumeErrorKind::SizeMismatch { expected, actual: len.saturating_sub(offset) })
                .at(&data_path)
        })?,
        b => offset + if h.encoding == Encoding::Raw { b as u64 } else { 0 },
    };
    {
        use std::io::Seek;
        reader.seek(std::io::SeekFrom::Start(skip)).map_err(|e| io(&data_path, e))?;
    }
    let name = path.file_stem().and_then(|s| s.to_str()).unwrap_or("volume");
    let orientation = if reorient.is_identity() { "none (stored order)".to_string() } else { reorient.describe() };
    let source = super::SourceInfo { voxel_type: Some(ty), orientation, ..Default::default() };
    let spec =
        StreamSpec { name, dims, spacing, ty, big_endian: h.big_endian, flip_xy: [flip[0], flip[1]], path: &data_path };
    // A volume mirrored in z (its slices arrive last first) or permuted is decoded whole and
    // reordered.
    let whole = |reader: &mut dyn std::io::Read| -> Result<Volume, VolumeError> {
        let bytes = read_exactly(reader, expected, &data_path)?;
        let values = decode_voxels(&bytes, ty, h.big_endian);
        let values = reorient.apply(values, dims);
        Volume::from_values(name, reorient.dims(dims), spacing, values).map_err(|e| e.at(path))
    };
    let vol = match h.encoding {
        Encoding::Raw => {
            if len.saturating_sub(skip) != expected {
                return Err(VolumeError::new(VolumeErrorKind::SizeMismatch {
                    expected,
                    actual: len.saturating_sub(skip),
                })
                .at(&data_path));
            }
            if whole_volume {
                whole(&mut reader)?
            } else {
                stream_volume(&spec, reader)?
            }
        }
        Encoding::Gzip => {
            use std::io::Read;
            let mut dec = flate2::bufread::MultiGzDecoder::new(reader);
            if h.byte_skip > 0 {
                std::io::copy(&mut dec.by_ref().take(h.byte_skip as u64), &mut std::io::sink())
                    .map_err(|e| VolumeError::new(VolumeErrorKind::Decompress(e.to_string())).at(&data_path))?;
            }
            let r = if whole_volume { whole(&mut dec) } else { stream_volume(&spec, dec) };
            r.map_err(|e| match e.kind {
                VolumeErrorKind::Io(io) => VolumeError::new(VolumeErrorKind::Decompress(io.to_string())).at(&data_path),
                _ => e,
            })?
        }
    };
    Ok(vol.with_source(source))
}

/// Writes a 3-D NRRD file with attached data (`gzip` selects the encoding) or, when
/// `detached` names a data file, a `.nhdr` header next to it. Used by tests and for exporting.
pub fn write(
    path: &Path,
    volume_bytes: &[u8],
    ty: VoxelType,
    dims: [u32; 3],
    spacing: Vec3,
    gzip: bool,
    detached: Option<&str>,
) -> std::io::Result<()> {
    use std::io::Write;
    let tyname = match ty {
        VoxelType::U8 => "uint8",
        VoxelType::I8 => "int8",
        VoxelType::U16 => "uint16",
        VoxelType::I16 => "int16",
        VoxelType::U32 => "uint32",
        VoxelType::I32 => "int32",
        VoxelType::F32 => "float",
        VoxelType::F64 => "double",
    };
    let mut head = format!(
        "NRRD0004\n# written by volwarp-server\ntype: {tyname}\ndimension: 3\nsizes: {} {} {}\nspacings: {} {} {}\nencoding: {}\nendian: little\n",
        dims[0],
        dims[1],
        dims[2],
        spacing.x,
        spacing.y,
        spacing.z,
        if gzip { "gzip" } else { "raw" }
    );
    let payload = if gzip {
        let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
        e.write_all(volume_bytes)?;
        e.finish()?
    } else {
        volume_bytes.to_vec()
    };
    match detached {
        Some(df) => {
            head.push_str(&format!("data file: {df}\n"));
            std::fs::write(path, head)?;
            std::fs::write(path.parent().unwrap_or(Path::new(".")).join(df), payload)
        }
        None => {
            head.push('\n');
            let mut f = std::fs::File::create(path)?;
            f.write_all(head.as_bytes())?;
            f.write_all(&payload)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_a_typical_header() {
        let h = parse_header(
            b"NRRD0004\n# c\ntype: short\ndimension: 3\nspace: left-posterior-superior\nsizes: 64 64 93\n\
space directions: (3.2,0,0) (0,3.2,0) (0,0,1.5)\nkinds: domain domain domain\nendian: little\n\
encoding: raw\nspace origin: (0,0,0)\nfoo:=bar\n\nDATA",
        )
        .unwrap();
        assert_eq!(h.voxel_type, VoxelType::I16);
        assert_eq!(h.dims, [64, 64, 93]);
        assert_eq!(h.encoding, Encoding::Raw);
        assert_eq!(h.spacing, Some(Vec3::new(3.2, 3.2, 1.5)));
        assert_eq!(h.data_file, None);
        assert_eq!(h.flip, [false; 3]);
        let h2 = parse_header(b"NRRD0005\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: gzip\nspace directions: (1,0,0) (0,-2,0) (0,0,-3)\n\n").unwrap();
        assert_eq!(h2.flip, [false, true, true]);
        assert_eq!(h2.spacing, Some(Vec3::new(1.0, 2.0, 3.0)));
    }

    #[test]
    fn rejects_bad_headers_without_panicking() {
        for bad in [
            &b""[..],
            b"NRRD",
            b"NRRD0004\n",
            b"NRRD0004\ntype: complex\n\n",
            b"NRRD0004\ntype: uchar\ndimension: 2\nsizes: 4 4\nencoding: raw\n\n",
            b"NRRD0004\ntype: uchar\ndimension: 3\nsizes: 4 4 0\nencoding: raw\n\n",
            b"NRRD0004\ntype: uchar\ndimension: 3\nsizes: 4 4 4\nencoding: bzip2\n\n",
            b"NRRD0004\ntype: uchar\ndimension: 3\nsizes: 4 4 4\nencoding: raw\nspacings: 1 nan 1\n\n",
            b"NRRD0004\ntype: uchar\ndimension: 3\nsizes: 4 4 x\nencoding: raw\n\n",
            b"NRRD0004\nno colon here\n\n",
            b"NRRD0004\n\xff\xfe\n\n",
            b"NRRDxxxx\n\n",
        ] {
            assert!(parse_header(bad).is_err(), "{:?}", String::from_utf8_lossy(bad));
        }
    }
}
