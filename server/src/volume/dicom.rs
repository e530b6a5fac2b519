//! DICOM series: a folder of DICOM files (or a list of files, or one multi-frame file), as
//! CT and MR scanners and PACS exports write them.
//!
//! **What is read.** DICOM objects without an image (a DICOMDIR, reports) are skipped; the
//! images are grouped by SeriesInstanceUID; where a folder holds several
//! series the one with the most slices is read and the others are logged. Slices (or the frames
//! of multi-frame files) are ordered by ImagePositionPatient projected on the normal of
//! ImageOrientationPatient; the slice spacing is the distance between consecutive positions
//! (not SliceThickness), and gaps that differ by more than 1 % are an error (a missing slice);
//! PixelSpacing gives the in-plane spacing. RescaleSlope/RescaleIntercept are applied per
//! slice. Multi-frame files take their positions, orientation, pixel spacing and rescale from
//! the per-frame and shared functional groups where the top level lacks them (else
//! SpacingBetweenSlices). Pixel data: one sample per pixel of 8, 16 or 32 bits, signed or
//! unsigned, in the uncompressed transfer syntaxes: implicit VR little endian, explicit VR
//! little and big endian; other syntaxes (JPEG, JPEG 2000, RLE, deflate …) are refused naming
//! the syntax.
//!
//! **Orientation.** DICOM patient space is LPS, the volume box's frame: the file axes (along a
//! row, down the columns, along the slice normal) are reordered so that the volume's x, y and z
//! run along +L, +P and +S where ImageOrientationPatient is axis-aligned (axial, coronal and
//! sagittal slices, any flips); oblique slices are refused.
//!
//! Headers are read with `dicom-object` (up to the pixel data; the pixels only for the chosen
//! series, after the voxel count is checked); native pixel data is decoded here, so that
//! `dicom-pixeldata` and its image codecs stay out of the build.

use super::orient::axis_aligned;
use super::{check_load, decode_voxels, voxel_bytes, LoadOptions, SourceInfo, Volume, VolumeError, VoxelType};
use dicom_dictionary_std::tags;
use dicom_object::mem::InMemDicomObject;
use dicom_object::{DefaultDicomObject, OpenFileOptions};
use std::path::{Path, PathBuf};

const FORMAT: &str = "DICOM";

/// The transfer syntaxes whose pixel data is read.
const NATIVE: [(&str, &str); 3] = [
    ("1.2.840.10008.1.2", "implicit VR little endian"),
    ("1.2.840.10008.1.2.1", "explicit VR little endian"),
    ("1.2.840.10008.1.2.2", "explicit VR big endian"),
];

fn bad(s: impl Into<String>) -> VolumeError {
    VolumeError::malformed(FORMAT, s)
}

/// True where `head` carries the DICOM part 10 magic (`DICM` at byte 128).
pub fn is_dicom(head: &[u8]) -> bool {
    head.get(128..132) == Some(b"DICM")
}

/// The DICOM files of a folder (those with the part 10 magic), in name order.
pub fn folder_files(dir: &Path) -> Result<Vec<PathBuf>, VolumeError> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| VolumeError::io(dir, e))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_file() && super::read_head(p, 132).is_ok_and(|h| is_dicom(&h)))
        .collect();
    files.sort();
    Ok(files)
}

/// One frame of the series: where it lies and how to read it.
#[derive(Clone, Debug)]
struct Frame {
    file: usize,
    index: usize,
    position: Option<[f64; 3]>,
    slope: f64,
    intercept: f64,
}

/// What a file's header says.
#[derive(Clone, Debug)]
struct Header {
    path: PathBuf,
    series: String,
    description: String,
    syntax: String,
    rows: u32,
    cols: u32,
    frames: usize,
    bits: u16,
    stored: u16,
    signed: bool,
    orientation: Option<[f64; 6]>,
    pixel_spacing: Option<[f64; 2]>,
    between: Option<f64>,
    frame_info: Vec<Frame>,
    /// Where the native pixel data lies in the file (offset, bytes), where the walk found it.
    pixels: Option<(u64, u64)>,
}

type Obj = InMemDicomObject;

fn floats(obj: &Obj, tag: dicom_object::Tag) -> Option<Vec<f64>> {
    obj.get(tag).and_then(|e| e.value().to_multi_float64().ok())
}

fn string(obj: &Obj, tag: dicom_object::Tag) -> Option<String> {
    obj.get(tag).and_then(|e| e.value().to_str().ok()).map(|s| s.trim_end_matches(['\0', ' ']).trim().to_string())
}

fn int(obj: &Obj, tag: dicom_object::Tag) -> Option<i64> {
    obj.get(tag).and_then(|e| e.value().to_int::<i64>().ok())
}

/// `tag` inside one of the functional group sequences of `group` (a per-frame or shared item).
fn in_group(group: &Obj, tag: dicom_object::Tag) -> Option<Vec<f64>> {
    group.iter().filter_map(|e| e.items()).flat_map(|items| items.first()).find_map(|item| floats(item, tag))
}

/// `tag` at the top level, else in the frame's functional groups, else the shared ones.
fn lookup(obj: &Obj, tag: dicom_object::Tag, frame: usize) -> Option<Vec<f64>> {
    floats(obj, tag)
        .or_else(|| {
            let per = obj.get(tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE)?.items()?.get(frame)?;
            in_group(per, tag)
        })
        .or_else(|| {
            let shared = obj.get(tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE)?.items()?.first()?;
            in_group(shared, tag)
        })
}

/// The VRs with a 4-byte length in explicit VR encodings.
const LONG_VRS: [&[u8; 2]; 13] =
    [b"OB", b"OD", b"OF", b"OL", b"OV", b"OW", b"SQ", b"UC", b"UR", b"UT", b"UN", b"SV", b"UV"];
/// The VRs with a 2-byte length.
const SHORT_VRS: [&[u8; 2]; 21] = [
    b"AE", b"AS", b"AT", b"CS", b"DA", b"DS", b"DT", b"FL", b"FD", b"IS", b"LO", b"LT", b"PN", b"SH", b"SL", b"SS",
    b"ST", b"TM", b"UI", b"UL", b"US",
];

/// Where a walk over a file's elements ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Walked {
    /// At the data set's own (not a sequence item's) PixelData with a defined length: where its
    /// value starts in the file and its length.
    Pixels { offset: u64, len: u64 },
    /// At the end of the file, without native pixel data at the top level.
    End,
    /// The bytes given (a prefix of the file) end before either.
    NeedMore,
}

/// Walks the elements of a DICOM file (`b`, its first bytes, of a file of `file_len` bytes) and
/// checks that every defined length fits in what is left of the file, before `dicom-object`
/// reads it: its parser allocates what a length says (a 600-byte file claiming a 4 GiB element
/// cost 4 GiB and seconds). Returns the transfer syntax and where the walk ended (it stops at
/// the top-level PixelData, so a prefix that holds everything before the pixels is enough); a
/// deflated data set (which this walk cannot see into) is refused here.
fn check_lengths(b: &[u8], file_len: u64) -> Result<(String, Walked), VolumeError> {
    if b.get(128..132) != Some(b"DICM") {
        return Err(bad("no DICM magic at byte 128"));
    }
    let mut at = 132;
    let (meta, walked) = walk(b, file_len, &mut at, true, false, true)?;
    if walked == Walked::NeedMore {
        return Ok((String::new(), walked));
    }
    let ts = meta.unwrap_or_default();
    let (explicit, big) = match ts.as_str() {
        "1.2.840.10008.1.2" => (false, false),
        "1.2.840.10008.1.2.2" => (true, true),
        "1.2.840.10008.1.2.1.99" | "1.2.840.10008.1.2.4.95" => {
            return Err(VolumeError::unsupported(format!("transfer syntax {ts} ({})", syntax_name(&ts))))
        }
        _ => (true, false),
    };
    let (_, walked) = walk(b, file_len, &mut at, explicit, big, false)?;
    Ok((ts, walked))
}

/// Walks elements from `at` (the meta group only where `meta`: it returns its transfer syntax),
/// descending into sequences and items, until the top-level PixelData or the end of `b`.
fn walk(
    b: &[u8],
    file_len: u64,
    at: &mut usize,
    explicit: bool,
    big: bool,
    meta: bool,
) -> Result<(Option<String>, Walked), VolumeError> {
    let u16_at = |i: usize| {
        let a = [b[i], b[i + 1]];
        if big {
            u16::from_be_bytes(a)
        } else {
            u16::from_le_bytes(a)
        }
    };
    let u32_at = |i: usize| {
        let a = [b[i], b[i + 1], b[i + 2], b[i + 3]];
        if big {
            u32::from_be_bytes(a)
        } else {
            u32::from_le_bytes(a)
        }
    };
    let prefix = (b.len() as u64) < file_len;
    let ended = move || if prefix { Walked::NeedMore } else { Walked::End };
    let mut ts = None;
    // Inside encapsulated pixel data: items are fragments (bytes, not elements).
    let mut fragments = false;
    // The open sequences: where each with a defined length ends (`None`: a delimiter ends it).
    let mut open: Vec<Option<usize>> = Vec::new();
    loop {
        while open.last().is_some_and(|e| e.is_some_and(|end| *at >= end)) {
            open.pop();
        }
        if *at + 8 > b.len() {
            return Ok((ts, ended()));
        }
        let (group, elem) = (u16_at(*at), u16_at(*at + 2));
        if meta && group != 0x0002 {
            return Ok((ts, Walked::End));
        }
        let (len, header, seq) = if group == 0xFFFE {
            let len = u32_at(*at + 4);
            if elem == 0xE0DD {
                if !fragments {
                    open.pop();
                }
                fragments = false;
            }
            // A fragment's bytes are skipped like a value; an item's elements are walked.
            (len, 8, !(fragments && elem == 0xE000))
        } else if explicit {
            let vr = [b[*at + 4], b[*at + 5]];
            if LONG_VRS.contains(&&vr) {
                if *at + 12 > b.len() {
                    if prefix {
                        return Ok((ts, Walked::NeedMore));
                    }
                    return Err(bad("the file ends inside an element header"));
                }
                (u32_at(*at + 8), 12, &vr == b"SQ")
            } else if SHORT_VRS.contains(&&vr) {
                (u16_at(*at + 6) as u32, 8, false)
            } else {
                return Err(bad(format!(
                    "element ({group:04X},{elem:04X}) has the unknown VR {:?}",
                    String::from_utf8_lossy(&vr)
                )));
            }
        } else {
            let len = u32_at(*at + 4);
            // Implicit VR: a value that starts with an item tag is a sequence.
            let item = b.get(*at + 8..*at + 12).is_some_and(|t| t == [0xFE, 0xFF, 0x00, 0xE0]);
            (len, 8, item)
        };
        *at += header;
        let pixels = (group, elem) == (0x7FE0, 0x0010);
        if pixels && len == u32::MAX {
            fragments = true;
        }
        let left = file_len.saturating_sub(*at as u64);
        if len != u32::MAX && !seq && u64::from(len) > left {
            return Err(bad(format!(
                "element ({group:04X},{elem:04X}) claims {len} bytes, {left} are left in the file (truncated?)"
            )));
        }
        if pixels && !meta && open.is_empty() && len != u32::MAX {
            return Ok((ts, Walked::Pixels { offset: *at as u64, len: u64::from(len) }));
        }
        if group != 0xFFFE && (seq || (len == u32::MAX && !pixels)) {
            // A sequence: its items' elements follow, up to its end or its delimiter.
            open.push((len != u32::MAX).then(|| *at + len as usize));
        }
        if len == u32::MAX || seq {
            continue; // a sequence or item: its elements follow
        }
        if meta && (group, elem) == (0x0002, 0x0010) {
            let Some(v) = b.get(*at..*at + len as usize) else {
                return Ok((ts, ended()));
            };
            ts = Some(String::from_utf8_lossy(v).trim_end_matches(['\0', ' ']).to_string());
        }
        *at += len as usize;
    }
}

/// Bytes read first from each file: the elements before the pixel data fit in them in files
/// as scanners write them (else the whole file is read).
const HEAD_BYTES: u64 = 64 << 10;

/// The header of an image file, `None` for a DICOM object that is no image (a DICOMDIR, a
/// report, a presentation state: no Rows).
fn read_header(path: &Path, file: usize) -> Result<Option<Header>, VolumeError> {
    use std::io::Read;
    let f = std::fs::File::open(path).map_err(|e| VolumeError::io(path, e))?;
    let file_len = f.metadata().map_err(|e| VolumeError::io(path, e))?.len();
    let mut bytes = Vec::with_capacity(file_len.min(HEAD_BYTES) as usize);
    f.take(HEAD_BYTES).read_to_end(&mut bytes).map_err(|e| VolumeError::io(path, e))?;
    let (_, mut walked) = check_lengths(&bytes, file_len).map_err(|e| e.at(path))?;
    if walked == Walked::NeedMore {
        bytes = std::fs::read(path).map_err(|e| VolumeError::io(path, e))?;
        (_, walked) = check_lengths(&bytes, bytes.len() as u64).map_err(|e| e.at(path))?;
    }
    // The part 10 stream after the preamble, from memory, up to the pixel data.
    let obj = OpenFileOptions::new()
        .read_until(tags::PIXEL_DATA)
        .from_reader(&bytes[128..])
        .map_err(|e| bad(format!("cannot parse: {e}")).at(path))?;
    if obj.get(tags::ROWS).is_none() && obj.get(tags::PIXEL_DATA).is_none() {
        return Ok(None);
    }
    let mut h = header_of(path, file, &obj).map_err(|e| e.at(path))?;
    if let Walked::Pixels { offset, len } = walked {
        h.pixels = Some((offset, len));
    }
    Ok(Some(h))
}

fn header_of(path: &Path, file: usize, obj: &DefaultDicomObject) -> Result<Header, VolumeError> {
    let syntax = obj.meta().transfer_syntax().trim_end_matches(['\0', ' ']).to_string();
    let need = |tag, what: &str| int(obj, tag).ok_or_else(|| bad(format!("no {what}")));
    let rows = need(tags::ROWS, "Rows")?;
    let cols = need(tags::COLUMNS, "Columns")?;
    let frames = int(obj, tags::NUMBER_OF_FRAMES).unwrap_or(1);
    let bits = need(tags::BITS_ALLOCATED, "BitsAllocated")?;
    let stored = int(obj, tags::BITS_STORED).unwrap_or(bits);
    let samples = int(obj, tags::SAMPLES_PER_PIXEL).unwrap_or(1);
    if samples != 1 {
        return Err(VolumeError::unsupported(format!("{samples} samples per pixel (one, grayscale, is read)")));
    }
    let (rows, cols) = match (u32::try_from(rows), u32::try_from(cols)) {
        (Ok(r), Ok(c)) if r > 0 && c > 0 => (r, c),
        _ => return Err(bad(format!("{rows} rows and {cols} columns"))),
    };
    let frames = usize::try_from(frames)
        .ok()
        .filter(|&f| f > 0 && f <= 1 << 20)
        .ok_or_else(|| bad(format!("NumberOfFrames {frames}")))?;
    if ![8, 16, 32].contains(&bits) {
        return Err(VolumeError::unsupported(format!("BitsAllocated {bits} (8, 16 or 32)")));
    }
    let stored = u16::try_from(stored).ok().filter(|&s| s > 0 && s as i64 <= bits).unwrap_or(bits as u16);
    let signed = int(obj, tags::PIXEL_REPRESENTATION).unwrap_or(0) == 1;
    let orientation = lookup(obj, tags::IMAGE_ORIENTATION_PATIENT, 0).and_then(|v| <[f64; 6]>::try_from(v).ok());
    let pixel_spacing = lookup(obj, tags::PIXEL_SPACING, 0).and_then(|v| <[f64; 2]>::try_from(v).ok());
    let between = lookup(obj, tags::SPACING_BETWEEN_SLICES, 0).and_then(|v| v.first().copied());
    let top_pos = floats(obj, tags::IMAGE_POSITION_PATIENT).and_then(|v| <[f64; 3]>::try_from(v).ok());
    let mut frame_info = Vec::with_capacity(frames);
    for f in 0..frames {
        let position = if frames == 1 {
            top_pos
        } else {
            let per =
                obj.get(tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE).and_then(|e| e.items()).and_then(|i| i.get(f));
            per.and_then(|g| in_group(g, tags::IMAGE_POSITION_PATIENT)).and_then(|v| <[f64; 3]>::try_from(v).ok())
        };
        let slope =
            lookup(obj, tags::RESCALE_SLOPE, f).and_then(|v| v.first().copied()).filter(|s| s.is_finite() && *s != 0.0);
        let intercept =
            lookup(obj, tags::RESCALE_INTERCEPT, f).and_then(|v| v.first().copied()).filter(|s| s.is_finite());
        frame_info.push(Frame {
            file,
            index: f,
            position,
            slope: slope.unwrap_or(1.0),
            intercept: intercept.unwrap_or(0.0),
        });
    }
    Ok(Header {
        path: path.to_path_buf(),
        series: string(obj, tags::SERIES_INSTANCE_UID).unwrap_or_default(),
        description: string(obj, tags::SERIES_DESCRIPTION).unwrap_or_default(),
        syntax,
        rows,
        cols,
        frames,
        bits: bits as u16,
        stored,
        signed,
        orientation,
        pixel_spacing,
        between,
        frame_info,
        pixels: None,
    })
}

/// Loads the DICOM files of a folder ([`folder_files`]).
pub fn load_folder(dir: &Path, opts: &LoadOptions) -> Result<Volume, VolumeError> {
    let files = folder_files(dir)?;
    if files.is_empty() {
        return Err(bad("the folder holds no DICOM files").at(dir));
    }
    load_files(dir, &files, opts)
}

/// Loads a series from DICOM files in any order (`name` names the volume and its errors:
/// their folder, or the file where there is one).
pub fn load_files(name: &Path, files: &[PathBuf], opts: &LoadOptions) -> Result<Volume, VolumeError> {
    let mut headers = Vec::with_capacity(files.len());
    for (i, f) in files.iter().enumerate() {
        match read_header(f, i)? {
            Some(h) => headers.push(h),
            None => log::info!("{}: not an image (no Rows); skipped", f.display()),
        }
    }
    if headers.is_empty() {
        return Err(bad("no image among the DICOM files (none has Rows)").at(name));
    }
    // Group by series; read the largest.
    let mut series: Vec<(String, Vec<usize>)> = Vec::new();
    for (i, h) in headers.iter().enumerate() {
        match series.iter_mut().find(|s| s.0 == h.series) {
            Some(s) => s.1.push(i),
            None => series.push((h.series.clone(), vec![i])),
        }
    }
    let frames_of = |s: &(String, Vec<usize>)| s.1.iter().map(|&i| headers[i].frames).sum::<usize>();
    series.sort_by(|a, b| frames_of(b).cmp(&frames_of(a)).then_with(|| a.0.cmp(&b.0)));
    let chosen = &series[0];
    for s in &series[1..] {
        let h = &headers[s.1[0]];
        log::warn!(
            "{}: also holds series {} ({:?}, {} slices); reading series {} ({} slices)",
            name.display(),
            s.0,
            h.description,
            frames_of(s),
            chosen.0,
            frames_of(chosen)
        );
    }
    let hs: Vec<&Header> = chosen.1.iter().map(|&i| &headers[i]).collect();
    let first = hs[0];
    for h in &hs {
        if !NATIVE.iter().any(|(uid, _)| *uid == h.syntax) {
            return Err(VolumeError::unsupported(format!(
                "transfer syntax {} ({}); only uncompressed syntaxes are read (implicit VR little endian, explicit VR \
                 little or big endian)",
                h.syntax,
                syntax_name(&h.syntax)
            ))
            .at(&h.path));
        }
        if (h.rows, h.cols) != (first.rows, first.cols) {
            return Err(bad(format!(
                "{}×{} pixels, {} has {}×{}: every slice of a series must be the same size",
                h.cols,
                h.rows,
                first.path.file_name().unwrap_or_default().to_string_lossy(),
                first.cols,
                first.rows
            ))
            .at(&h.path));
        }
        if (h.bits, h.signed) != (first.bits, first.signed) {
            return Err(bad("the slices' pixel types differ").at(&h.path));
        }
        let (o1, o2) = (h.orientation, first.orientation);
        if let (Some(a), Some(b)) = (o1, o2) {
            if a.iter().zip(&b).any(|(x, y)| (x - y).abs() > 1e-4) {
                return Err(bad("the slices' ImageOrientationPatient differ").at(&h.path));
            }
        }
    }
    // Geometry: the in-plane directions and the slice normal.
    let iop = first.orientation.unwrap_or([1.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
    let row = [iop[0], iop[1], iop[2]];
    let col = [iop[3], iop[4], iop[5]];
    let normal =
        [row[1] * col[2] - row[2] * col[1], row[2] * col[0] - row[0] * col[2], row[0] * col[1] - row[1] * col[0]];
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let mut frames: Vec<Frame> = hs.iter().flat_map(|h| h.frame_info.iter().cloned()).collect();
    let nz = frames.len();
    let have_pos = frames.iter().all(|f| f.position.is_some());
    let dz = if have_pos && nz > 1 {
        frames.sort_by(|a, b| {
            dot(a.position.unwrap_or_default(), normal).total_cmp(&dot(b.position.unwrap_or_default(), normal))
        });
        let z: Vec<f64> = frames.iter().map(|f| dot(f.position.unwrap_or_default(), normal)).collect();
        let gaps: Vec<f64> = z.windows(2).map(|w| w[1] - w[0]).collect();
        let mean = (z[nz - 1] - z[0]) / (nz - 1) as f64;
        let label = |k: usize| {
            let f = &frames[k];
            let file = headers
                .iter()
                .find(|h| h.frame_info.first().is_some_and(|x| x.file == f.file))
                .map_or(String::new(), |h| h.path.file_name().unwrap_or_default().to_string_lossy().into_owned());
            if hs.iter().any(|h| h.frames > 1) {
                format!("{file} frame {}", f.index + 1)
            } else {
                file
            }
        };
        if let Some(k) = gaps.iter().position(|&g| g.abs() < 1e-6 * mean.abs().max(1e-3)) {
            return Err(bad(format!(
                "{} and {} lie at the same position (two slices in one place)",
                label(k),
                label(k + 1)
            ))
            .at(name));
        }
        if let Some(k) = gaps.iter().position(|&g| (g - mean).abs() > 0.01 * mean.abs()) {
            let k0 = gaps.iter().position(|&g| (g - gaps[k]).abs() > 0.01 * mean.abs()).unwrap_or(0);
            return Err(bad(format!(
                "inconsistent slice gaps: {:.4} between {} and {}, {:.4} between {} and {} (a missing slice?)",
                gaps[k0],
                label(k0),
                label(k0 + 1),
                gaps[k],
                label(k),
                label(k + 1)
            ))
            .at(name));
        }
        mean
    } else {
        if nz > 1 {
            log::warn!(
                "{}: slices without ImagePositionPatient: file order, SpacingBetweenSlices or 1",
                name.display()
            );
        }
        first.between.filter(|b| b.is_finite() && *b > 0.0).unwrap_or(1.0)
    };
    let ps = first.pixel_spacing.unwrap_or([1.0, 1.0]);
    // PixelSpacing is (between rows, between columns): a step along a row is a column step.
    let cols_dir = [row.map(|c| c * ps[1]), col.map(|c| c * ps[0]), normal.map(|c| c * dz)];
    let r = axis_aligned(cols_dir).map_err(|e| e.at(name))?;
    let dims = [first.cols, first.rows, u32::try_from(nz).map_err(|_| bad("too many slices").at(name))?];
    let ty = match (first.bits, first.signed) {
        (8, false) => VoxelType::U8,
        (8, true) => VoxelType::I8,
        (16, false) => VoxelType::U16,
        (16, true) => VoxelType::I16,
        (32, false) => VoxelType::U32,
        _ => VoxelType::I32,
    };
    let frame_bytes = first.rows as usize * first.cols as usize * ty.size();
    let vol_name = name.file_stem().and_then(|s| s.to_str()).unwrap_or("dicom");
    let big = |h: &Header| h.syntax == NATIVE[2].0;
    // Streamed into bricks in the stored type where the slices share one integer rescale
    // intercept and a slope of 1, 8 or 16 bits in one byte order, the pixel data was found by
    // the header walk, and the slices are not permuted (flips are read in mirrored order);
    // else decoded whole as values (8 bytes per voxel while loading).
    let intercept = frames[0].intercept;
    let stream = frames.iter().all(|f| f.slope == 1.0 && f.intercept == intercept)
        && intercept.fract() == 0.0
        && intercept.abs() < 16_777_216.0
        && (first.bits == 16 || first.bits == 8 && !big(first))
        && hs.iter().all(|h| big(h) == big(first) && h.pixels.is_some())
        && r.perm == [0, 1, 2];
    let stored = if stream { super::stream::stored_size(ty) } else { 4 };
    let voxels = check_load(dims, r.spacing, opts, stored, if stream { 0 } else { 8 }).map_err(|e| e.at(name))?;
    let source = SourceInfo {
        format: "DICOM".into(),
        voxel_type: Some(ty),
        orientation: format!("{} (ImageOrientationPatient; slices ordered by position)", r.describe()),
        data_bytes: voxel_bytes(voxels, ty).map_err(|e| e.at(name))?,
        files: hs.len(),
    };
    let spacing = opts.spacing.unwrap_or(r.spacing);
    if stream {
        let spec = super::stream::StreamSpec {
            name: vol_name,
            dims,
            spacing,
            ty,
            big_endian: big(first),
            flip_xy: [r.flip[0], r.flip[1]],
            path: name,
        };
        let by_file: std::collections::HashMap<usize, &Header> =
            hs.iter().map(|h| (h.frame_info[0].file, *h)).collect();
        let mut sink = super::stream::SliceSink::new(&spec)?;
        let mut buf = vec![0u8; frame_bytes];
        let mut file: Option<(usize, std::fs::File)> = None;
        let order: Box<dyn Iterator<Item = &Frame>> =
            if r.flip[2] { Box::new(frames.iter().rev()) } else { Box::new(frames.iter()) };
        for f in order {
            let h = by_file[&f.file];
            let (offset, len) = h.pixels.unwrap_or_default();
            let need = (h.frames * frame_bytes) as u64;
            if len < need {
                return Err(
                    VolumeError::new(super::VolumeErrorKind::SizeMismatch { expected: need, actual: len }).at(&h.path)
                );
            }
            if file.as_ref().is_none_or(|(i, _)| *i != f.file) {
                file = Some((f.file, std::fs::File::open(&h.path).map_err(|e| VolumeError::io(&h.path, e))?));
            }
            if let Some((_, fd)) = file.as_mut() {
                use std::io::{Read, Seek, SeekFrom};
                fd.seek(SeekFrom::Start(offset + (f.index * frame_bytes) as u64))
                    .and_then(|_| fd.read_exact(&mut buf))
                    .map_err(|e| VolumeError::io(&h.path, e))?;
            }
            if h.stored < h.bits {
                mask_bytes(&mut buf, h.bits, h.stored, h.signed, big(h));
            }
            sink.push(&buf);
        }
        let mut vol = sink.finish()?;
        let (lo, hi) = vol.value_range;
        vol.value_range = ((f64::from(lo) + intercept) as f32, (f64::from(hi) + intercept) as f32);
        return Ok(vol.with_source(source));
    }
    // Pixels, file by file (each file read once), placed at their frame's slice.
    let mut values = vec![0f32; voxels as usize];
    let plane = first.rows as usize * first.cols as usize;
    for h in &hs {
        let bytes = std::fs::read(&h.path).map_err(|e| VolumeError::io(&h.path, e))?;
        check_lengths(&bytes, bytes.len() as u64).map_err(|e| e.at(&h.path))?;
        let obj = OpenFileOptions::new()
            .from_reader(&bytes[128..])
            .map_err(|e| bad(format!("cannot parse: {e}")).at(&h.path))?;
        drop(bytes);
        let px = obj.get(tags::PIXEL_DATA).ok_or_else(|| bad("no PixelData").at(&h.path))?;
        let bytes = native_bytes(px.value()).map_err(|e| e.at(&h.path))?;
        let need = h.frames * frame_bytes;
        if bytes.len() < need {
            return Err(VolumeError::new(super::VolumeErrorKind::SizeMismatch {
                expected: need as u64,
                actual: bytes.len() as u64,
            })
            .at(&h.path));
        }
        for (z, f) in frames.iter().enumerate().filter(|(_, f)| f.file == h.frame_info[0].file) {
            let raw = &bytes[f.index * frame_bytes..(f.index + 1) * frame_bytes];
            let v = decode_voxels(raw, ty, false);
            let out = &mut values[z * plane..(z + 1) * plane];
            for (o, x) in out.iter_mut().zip(v) {
                *o = (mask(x, h.stored, h.bits, h.signed) * f.slope + f.intercept) as f32;
            }
        }
    }
    let values = r.apply(values, dims);
    let out_dims = r.dims(dims);
    Ok(Volume::from_values(vol_name, out_dims, spacing, values).map_err(|e| e.at(name))?.with_source(source))
}

/// Keeps the `stored` low bits of each `bits`-bit (8 or 16) value of `bytes` in place:
/// unsigned values masked, signed ones sign-extended (as [`mask`] does for one value).
fn mask_bytes(bytes: &mut [u8], bits: u16, stored: u16, signed: bool, big: bool) {
    let (m, sign) = ((1u32 << stored) - 1, 1u32 << (stored - 1));
    let fix = |v: u32| {
        let u = v & m;
        if signed && u & sign != 0 {
            u | !m
        } else {
            u
        }
    };
    if bits == 8 {
        bytes.iter_mut().for_each(|b| *b = fix(u32::from(*b)) as u8);
    } else {
        for p in bytes.chunks_exact_mut(2) {
            let v = if big { u16::from_be_bytes([p[0], p[1]]) } else { u16::from_le_bytes([p[0], p[1]]) };
            let w = fix(u32::from(v)) as u16;
            p.copy_from_slice(&if big { w.to_be_bytes() } else { w.to_le_bytes() });
        }
    }
}

/// The value of a pixel with `stored` significant bits of `bits`: unsigned values masked, signed
/// ones sign-extended.
fn mask(x: f32, stored: u16, bits: u16, signed: bool) -> f64 {
    if stored >= bits || bits == 32 {
        return x as f64;
    }
    let v = x as i64;
    let m = (1i64 << stored) - 1;
    if signed {
        let u = v & m;
        (if u >> (stored - 1) & 1 == 1 { u - (1 << stored) } else { u }) as f64
    } else {
        (v & m) as f64
    }
}

/// Native pixel data as little-endian bytes (whatever VR it was parsed as).
fn native_bytes(v: &dicom_core::DicomValue<Obj, dicom_object::mem::InMemFragment>) -> Result<Vec<u8>, VolumeError> {
    use dicom_core::PrimitiveValue as P;
    let le = |it: &mut dyn Iterator<Item = Vec<u8>>| it.flatten().collect::<Vec<u8>>();
    Ok(match v.primitive() {
        Some(P::U8(b)) => b.to_vec(),
        Some(P::U16(x)) => le(&mut x.iter().map(|v| v.to_le_bytes().to_vec())),
        Some(P::I16(x)) => le(&mut x.iter().map(|v| v.to_le_bytes().to_vec())),
        Some(P::U32(x)) => le(&mut x.iter().map(|v| v.to_le_bytes().to_vec())),
        Some(P::I32(x)) => le(&mut x.iter().map(|v| v.to_le_bytes().to_vec())),
        Some(P::F32(x)) => le(&mut x.iter().map(|v| v.to_le_bytes().to_vec())),
        Some(_) => return Err(bad("PixelData holds neither bytes nor words")),
        None => return Err(VolumeError::unsupported("encapsulated (compressed) PixelData")),
    })
}

fn syntax_name(uid: &str) -> &'static str {
    match uid {
        "1.2.840.10008.1.2.1.99" => "deflated explicit VR little endian",
        "1.2.840.10008.1.2.4.50" => "JPEG baseline",
        "1.2.840.10008.1.2.4.51" => "JPEG extended",
        "1.2.840.10008.1.2.4.57" | "1.2.840.10008.1.2.4.70" => "JPEG lossless",
        "1.2.840.10008.1.2.4.80" | "1.2.840.10008.1.2.4.81" => "JPEG-LS",
        "1.2.840.10008.1.2.4.90" | "1.2.840.10008.1.2.4.91" => "JPEG 2000",
        "1.2.840.10008.1.2.4.201" | "1.2.840.10008.1.2.4.202" | "1.2.840.10008.1.2.4.203" => "HTJ2K",
        "1.2.840.10008.1.2.5" => "RLE lossless",
        _ => "not an uncompressed syntax",
    }
}

/// Loads one DICOM file (a multi-frame volume, or a single slice).
pub fn load_file(path: &Path, opts: &LoadOptions) -> Result<Volume, VolumeError> {
    load_files(path, &[path.to_path_buf()], opts)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn masking_bytes_equals_masking_values() {
        for bits in [8u16, 16] {
            for stored in 2..bits {
                for signed in [false, true] {
                    for big in [false, true] {
                        let values: Vec<u32> = (0..300u32).map(|i| i.wrapping_mul(2_654_435_761) >> 16).collect();
                        let mut bytes: Vec<u8> = if bits == 8 {
                            values.iter().map(|&v| v as u8).collect()
                        } else {
                            values
                                .iter()
                                .flat_map(|&v| if big { (v as u16).to_be_bytes() } else { (v as u16).to_le_bytes() })
                                .collect()
                        };
                        mask_bytes(&mut bytes, bits, stored, signed, big);
                        let ty = match (bits, signed) {
                            (8, false) => VoxelType::U8,
                            (8, true) => VoxelType::I8,
                            (_, false) => VoxelType::U16,
                            _ => VoxelType::I16,
                        };
                        let got = decode_voxels(&bytes, ty, big);
                        for (k, &v) in values.iter().enumerate() {
                            let x = if bits == 8 { v as u8 as f32 } else { v as u16 as f32 };
                            assert_eq!(
                                got[k] as f64,
                                mask(x, stored, bits, signed),
                                "{bits} {stored} {signed} {big} {v}"
                            );
                        }
                    }
                }
            }
        }
    }
}
