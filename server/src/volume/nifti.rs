//! NIfTI-1 and NIfTI-2 volumes (`.nii`, `.nii.gz`; either byte order), as FSL, SPM, AFNI,
//! FreeSurfer, ITK and nibabel write them.
//!
//! **What is read.** The first 3-D volume of the file (a 4-D series is read as its first
//! volume, with a log line); voxel types u8, i8, u16, i16, u32, i32, f32, f64; values scaled
//! by `scl_slope`/`scl_inter` (a slope of 0 or not finite means none); the spacing from the
//! orientation below (or the absolute `pixdim`).
//!
//! **Orientation.** NIfTI world space is RAS (+x right, +y anterior, +z superior); the volume
//! box is LPS, DICOM patient space, so world x and y are negated. The file axes' directions
//! come from the sform where `sform_code > 0`, else from the qform (quaternion, `pixdim` and
//! `qfac`) where `qform_code > 0`; an axis-aligned orientation (a permutation of the axes with
//! flips) is applied by reordering the voxels ([`super::orient`]), an oblique one is refused.
//! With neither code set (no orientation, "method 1") the stored order is kept and a negative
//! `pixdim` flips its axis.
//!
//! **Why a parser of its own.** The `nifti` crate reads NIfTI-1 only (no NIfTI-2 headers),
//! its writer needs `ndarray`, and its reader allocates what the header says before checking
//! it against the file; the two headers are fixed layouts of 348 and 540 bytes, read here with
//! every size checked (the product of the dims, the voxel limit, the file length)
//! before anything is allocated. [`parse_header`] never panics (it is fuzzed through
//! `load_volume`).

use super::orient::{axis_aligned, Reorient};
use super::{decode_voxels, LoadOptions, SourceInfo, Volume, VolumeError, VolumeErrorKind, VoxelType};
use std::io::Read;
use std::path::Path;
use volwarp_core::Vec3;

const FORMAT: &str = "NIfTI";

/// True where `head` (the start of a file, decompressed) carries a NIfTI magic: `n+1\0` or
/// `ni1\0` at byte 344 (NIfTI-1) or `n+2\0` at byte 4 (NIfTI-2).
pub fn is_nifti(head: &[u8]) -> bool {
    let v1 = head.get(344..348).is_some_and(|m| m == b"n+1\0" || m == b"ni1\0");
    let v2 = head.get(4..8).is_some_and(|m| m == b"n+2\0" || m == b"ni2\0");
    v1 || v2
}

/// Where the file axes point (the matrix the header chooses).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Orientation {
    /// No qform or sform: the stored order, `pixdim` spacing (signed).
    None([f64; 3]),
    /// The voxel steps of the file axes, in RAS, from the qform.
    Qform([[f64; 3]; 3]),
    /// The voxel steps of the file axes, in RAS, from the sform.
    Sform([[f64; 3]; 3]),
}

/// The fields of a NIfTI header this loader uses.
#[derive(Clone, Debug, PartialEq)]
pub struct NiftiHeader {
    /// 1 or 2.
    pub version: u8,
    /// Big-endian header and data.
    pub big_endian: bool,
    /// Voxels along the first three axes.
    pub dims: [u32; 3],
    /// Volumes of 3-D voxels in the file (the product of dims 4 to 7; only the first is read).
    pub volumes: u64,
    /// Voxel type.
    pub voxel_type: VoxelType,
    /// Where the voxel data starts.
    pub vox_offset: u64,
    /// `scl_slope` and `scl_inter`, where the slope is finite and not 0.
    pub scale: Option<(f64, f64)>,
    /// The orientation.
    pub orientation: Orientation,
    /// The data lies in a separate `.img` file (magic `ni1`/`ni2`).
    pub pair: bool,
}

fn bad(s: impl Into<String>) -> VolumeError {
    VolumeError::malformed(FORMAT, s)
}

/// Little- or big-endian reads at fixed offsets (callers check the length first).
struct Fields<'a> {
    b: &'a [u8],
    big: bool,
}

impl Fields<'_> {
    fn arr<const N: usize>(&self, at: usize) -> [u8; N] {
        let mut a = [0u8; N];
        a.copy_from_slice(&self.b[at..at + N]);
        if self.big {
            a.reverse();
        }
        a
    }
    fn i16(&self, at: usize) -> i16 {
        i16::from_le_bytes(self.arr(at))
    }
    fn i32(&self, at: usize) -> i32 {
        i32::from_le_bytes(self.arr(at))
    }
    fn i64(&self, at: usize) -> i64 {
        i64::from_le_bytes(self.arr(at))
    }
    fn f32(&self, at: usize) -> f64 {
        f32::from_le_bytes(self.arr(at)) as f64
    }
    fn f64(&self, at: usize) -> f64 {
        f64::from_le_bytes(self.arr(at))
    }
}

/// Parses a NIfTI-1 (348-byte) or NIfTI-2 (540-byte) header at the start of `bytes`. Never
/// panics.
pub fn parse_header(bytes: &[u8]) -> Result<NiftiHeader, VolumeError> {
    let size_le = bytes.get(..4).map(|b| i32::from_le_bytes([b[0], b[1], b[2], b[3]]));
    let size_be = bytes.get(..4).map(|b| i32::from_be_bytes([b[0], b[1], b[2], b[3]]));
    let (version, big) = match (size_le, size_be) {
        (Some(348), _) => (1u8, false),
        (_, Some(348)) => (1, true),
        (Some(540), _) => (2, false),
        (_, Some(540)) => (2, true),
        _ => return Err(bad("the header size (bytes 0 to 3) is neither 348 (NIfTI-1) nor 540 (NIfTI-2)")),
    };
    let hsize = if version == 1 { 348 } else { 540 };
    if bytes.len() < hsize {
        return Err(bad(format!(
            "the file holds {} bytes, fewer than a NIfTI-{version} header ({hsize})",
            bytes.len()
        )));
    }
    let f = Fields { b: bytes, big };
    let magic = if version == 1 { &bytes[344..348] } else { &bytes[4..8] };
    let pair = match (version, magic) {
        (1, b"n+1\0") | (2, b"n+2\0") => false,
        (1, b"ni1\0") | (2, b"ni2\0") => true,
        _ => return Err(bad(format!("no NIfTI-{version} magic (found {:?})", String::from_utf8_lossy(magic)))),
    };
    // dim[0..8], datatype, bitpix, pixdim[0..8], vox_offset, scl_slope, scl_inter, qform_code,
    // sform_code, quatern b c d, qoffset, srow_x/y/z.
    let (dim, datatype, bitpix, pixdim, vox_offset, slope, inter, qcode, scode, quat, srow);
    if version == 1 {
        dim = std::array::from_fn::<i64, 8, _>(|i| f.i16(40 + 2 * i) as i64);
        datatype = f.i16(70) as i32;
        bitpix = f.i16(72) as i32;
        pixdim = std::array::from_fn::<f64, 8, _>(|i| f.f32(76 + 4 * i));
        vox_offset = f.f32(108);
        slope = f.f32(112);
        inter = f.f32(116);
        qcode = f.i16(252) as i32;
        scode = f.i16(254) as i32;
        quat = [f.f32(256), f.f32(260), f.f32(264)];
        srow = std::array::from_fn::<[f64; 4], 3, _>(|r| std::array::from_fn(|c| f.f32(280 + 16 * r + 4 * c)));
    } else {
        dim = std::array::from_fn::<i64, 8, _>(|i| f.i64(16 + 8 * i));
        datatype = f.i16(12) as i32;
        bitpix = f.i16(14) as i32;
        pixdim = std::array::from_fn::<f64, 8, _>(|i| f.f64(104 + 8 * i));
        vox_offset = f.i64(168) as f64;
        slope = f.f64(176);
        inter = f.f64(184);
        qcode = f.i32(344);
        scode = f.i32(348);
        quat = [f.f64(352), f.f64(360), f.f64(368)];
        srow = std::array::from_fn::<[f64; 4], 3, _>(|r| std::array::from_fn(|c| f.f64(400 + 32 * r + 8 * c)));
    }
    let ndim = dim[0];
    if !(1..=7).contains(&ndim) {
        return Err(bad(format!("dim[0] = {ndim}: the number of dimensions must be 1 to 7")));
    }
    let mut dims = [1u32; 3];
    let mut volumes = 1u64;
    for (i, &d) in dim.iter().enumerate().skip(1).take(ndim as usize) {
        if d < 1 {
            return Err(bad(format!("dim[{i}] = {d}: every dimension must be at least 1")));
        }
        if i <= 3 {
            dims[i - 1] = u32::try_from(d).map_err(|_| bad(format!("dim[{i}] = {d} is over 2^32")))?;
        } else {
            volumes = volumes.checked_mul(d as u64).ok_or_else(|| bad("dims 4 to 7 overflow"))?;
        }
    }
    let voxel_type = match datatype {
        2 => VoxelType::U8,
        4 => VoxelType::I16,
        8 => VoxelType::I32,
        16 => VoxelType::F32,
        64 => VoxelType::F64,
        256 => VoxelType::I8,
        512 => VoxelType::U16,
        768 => VoxelType::U32,
        other => {
            let name = match other {
                1 => "binary (1-bit)",
                32 => "complex64",
                128 => "RGB24",
                1024 => "int64",
                1280 => "uint64",
                1536 => "float128",
                1792 => "complex128",
                2048 => "complex256",
                2304 => "RGBA32",
                _ => "unknown",
            };
            return Err(VolumeError::unsupported(format!(
                "NIfTI datatype {other} ({name}); only u8, i8, u16, i16, u32, i32, f32 and f64 scalars"
            )));
        }
    };
    if bitpix != 0 && bitpix as usize != 8 * voxel_type.size() {
        return Err(bad(format!("bitpix {bitpix} does not match datatype {datatype} ({})", voxel_type.name())));
    }
    if !(vox_offset.is_finite() && vox_offset >= 0.0 && vox_offset.fract() == 0.0 && vox_offset < 1e15) {
        return Err(bad(format!("vox_offset {vox_offset} is not a byte offset")));
    }
    let vox_offset = vox_offset as u64;
    if !pair && vox_offset < hsize as u64 {
        return Err(bad(format!("vox_offset {vox_offset} lies inside the {hsize}-byte header")));
    }
    let scale = (slope.is_finite() && slope != 0.0).then_some((slope, if inter.is_finite() { inter } else { 0.0 }));
    let orientation = if scode > 0 {
        let cols = std::array::from_fn(|c| [srow[0][c], srow[1][c], srow[2][c]]);
        Orientation::Sform(cols)
    } else if qcode > 0 {
        let [b, c, d] = quat;
        let (mut a, mut b, mut c, mut d) = (1.0 - (b * b + c * c + d * d), b, c, d);
        if a < 1e-7 {
            // A 180° rotation: a is 0 and (b, c, d) a unit vector (as nifti1_io).
            let n = (b * b + c * c + d * d).sqrt();
            if !(n.is_finite() && n > 0.0) {
                return Err(bad("the qform quaternion is not finite"));
            }
            (a, b, c, d) = (0.0, b / n, c / n, d / n);
        } else {
            a = a.sqrt();
        }
        let r = [
            [a * a + b * b - c * c - d * d, 2.0 * (b * c - a * d), 2.0 * (b * d + a * c)],
            [2.0 * (b * c + a * d), a * a + c * c - b * b - d * d, 2.0 * (c * d - a * b)],
            [2.0 * (b * d - a * c), 2.0 * (c * d + a * b), a * a + d * d - c * c - b * b],
        ];
        let qfac = if pixdim[0] < 0.0 { -1.0 } else { 1.0 };
        let step = [pixdim_or_1(pixdim[1]), pixdim_or_1(pixdim[2]), pixdim_or_1(pixdim[3]) * qfac];
        Orientation::Qform(std::array::from_fn(|col| {
            [r[0][col] * step[col], r[1][col] * step[col], r[2][col] * step[col]]
        }))
    } else {
        Orientation::None([pixdim_or_1(pixdim[1]), pixdim_or_1(pixdim[2]), pixdim_or_1(pixdim[3])])
    };
    Ok(NiftiHeader { version, big_endian: big, dims, volumes, voxel_type, vox_offset, scale, orientation, pair })
}

/// A `pixdim` as a signed step: 0 or not finite (unset) is 1.
fn pixdim_or_1(p: f64) -> f64 {
    if p.is_finite() && p != 0.0 {
        p
    } else {
        1.0
    }
}

impl NiftiHeader {
    /// The reordering into LPS and a description of where it came from.
    pub fn reorient(&self) -> Result<(Reorient, String), VolumeError> {
        let ras_to_lps = |cols: [[f64; 3]; 3]| cols.map(|c| [-c[0], -c[1], c[2]]);
        Ok(match self.orientation {
            Orientation::None(p) => {
                let r = Reorient {
                    perm: [0, 1, 2],
                    flip: p.map(|s| s < 0.0),
                    spacing: Vec3::new(p[0].abs() as f32, p[1].abs() as f32, p[2].abs() as f32),
                };
                let what = if r.is_identity() {
                    "none (no qform or sform: the stored order)".to_string()
                } else {
                    let axes: Vec<&str> = (0..3).filter(|&a| r.flip[a]).map(|a| ["x", "y", "z"][a]).collect();
                    format!("{} flipped (negative pixdim; no qform or sform)", axes.join(", "))
                };
                (r, what)
            }
            Orientation::Qform(c) => {
                let r = axis_aligned(ras_to_lps(c))?;
                let what = format!("{} (qform, RAS to LPS)", r.describe());
                (r, what)
            }
            Orientation::Sform(c) => {
                let r = axis_aligned(ras_to_lps(c))?;
                let what = format!("{} (sform, RAS to LPS)", r.describe());
                (r, what)
            }
        })
    }
}

/// Opens `path`, gunzipping where it starts with the gzip magic (and says whether it did).
fn open_maybe_gz(path: &Path) -> Result<(Box<dyn Read>, bool), VolumeError> {
    let mut f = std::io::BufReader::new(std::fs::File::open(path).map_err(|e| VolumeError::io(path, e))?);
    let gz = {
        use std::io::BufRead;
        f.fill_buf().map_err(|e| VolumeError::io(path, e))?.starts_with(&[0x1f, 0x8b])
    };
    Ok((if gz { Box::new(flate2::bufread::MultiGzDecoder::new(f)) } else { Box::new(f) }, gz))
}

/// Reads up to `n` bytes (fewer at the end of the stream).
fn read_up_to(r: &mut dyn Read, n: u64, path: &Path) -> Result<Vec<u8>, VolumeError> {
    let mut buf = Vec::new();
    r.take(n).read_to_end(&mut buf).map_err(|e| decompress_or_io(path, e))?;
    Ok(buf)
}

fn decompress_or_io(path: &Path, e: std::io::Error) -> VolumeError {
    if e.kind() == std::io::ErrorKind::InvalidInput || e.kind() == std::io::ErrorKind::InvalidData {
        VolumeError::new(VolumeErrorKind::Decompress(e.to_string())).at(path)
    } else {
        VolumeError::io(path, e)
    }
}

/// Loads a `.nii` or `.nii.gz` file (or a `.hdr` whose data is in the `.img` beside it).
pub fn load(path: &Path, opts: &LoadOptions) -> Result<Volume, VolumeError> {
    let (mut r, gz) = open_maybe_gz(path)?;
    let head = read_up_to(&mut r, 540, path)?;
    let h = parse_header(&head).map_err(|e| e.at(path))?;
    if h.volumes > 1 {
        log::info!("{}: {} volumes; reading the first", path.display(), h.volumes);
    }
    let (reorient, orientation) = h.reorient().map_err(|e| e.at(path))?;
    let spacing = opts.spacing.unwrap_or(reorient.spacing);
    // Streamed into bricks where the stored order is LPS's but for mirrored x and y and the
    // values are not scaled; else decoded whole (8 bytes per voxel while loading).
    let stream = reorient.perm == [0, 1, 2] && !reorient.flip[2] && h.scale.is_none();
    let (stored, decoded) = if stream { (super::stream::stored_size(h.voxel_type), 0) } else { (4, 8) };
    let voxels = super::check_load(h.dims, reorient.spacing, opts, stored, decoded).map_err(|e| e.at(path))?;
    let expected = super::voxel_bytes(voxels, h.voxel_type).map_err(|e| e.at(path))?;
    // The data: in this file after the header, or in the `.img` beside a `.hdr`.
    let (data_path, (mut data, is_gz), consumed) = if h.pair {
        let stem = path.to_string_lossy();
        let stem = stem.strip_suffix(".gz").unwrap_or(&stem);
        let stem = stem.strip_suffix(".hdr").unwrap_or(stem);
        let candidates = [format!("{stem}.img"), format!("{stem}.img.gz")];
        let img = candidates.iter().map(Path::new).find(|p| p.is_file()).ok_or_else(|| {
            bad(format!("a header of a .hdr/.img pair (magic ni{}) without its {stem}.img", h.version)).at(path)
        })?;
        (img.to_path_buf(), open_maybe_gz(img)?, 0u64)
    } else {
        (path.to_path_buf(), (r, gz), head.len() as u64)
    };
    // A plain file's length says whether the data is all there before anything is read.
    let file_len = std::fs::metadata(&data_path).map_err(|e| VolumeError::io(&data_path, e))?.len();
    let truncated = |found: u64| VolumeError::new(VolumeErrorKind::SizeMismatch { expected, actual: found });
    if !is_gz && file_len < h.vox_offset.saturating_add(expected) {
        return Err(truncated(file_len.saturating_sub(h.vox_offset)).at(&data_path));
    }
    let prefix: &[u8] = if h.pair { &[] } else { &head };
    let file_name = path.file_name().and_then(|s| s.to_str()).unwrap_or("volume");
    let name = file_name.split('.').next().filter(|s| !s.is_empty()).unwrap_or("volume");
    let source = SourceInfo {
        format: format!("NIfTI-{}", h.version),
        voxel_type: Some(h.voxel_type),
        orientation: match h.scale {
            Some((s, i)) => format!("{orientation}; values scaled by {s} and offset by {i}"),
            None => orientation,
        },
        data_bytes: expected,
        files: 1 + h.pair as usize,
    };
    if stream {
        // The data from the header's bytes already read, then the rest of the stream, exactly
        // the first volume's bytes (later volumes of a 4-D file are not read).
        let from_head = prefix.get(h.vox_offset.min(consumed) as usize..).unwrap_or(&[]);
        let skip = h.vox_offset.saturating_sub(consumed);
        let skipped = std::io::copy(&mut data.by_ref().take(skip), &mut std::io::sink())
            .map_err(|e| decompress_or_io(&data_path, e))?;
        if skipped < skip {
            return Err(truncated(0).at(&data_path));
        }
        let reader = from_head.chain(data).take(expected);
        let spec = super::stream::StreamSpec {
            name,
            dims: h.dims,
            spacing,
            ty: h.voxel_type,
            big_endian: h.big_endian,
            flip_xy: [reorient.flip[0], reorient.flip[1]],
            path: &data_path,
        };
        let vol = super::stream::stream_volume(&spec, reader).map_err(|e| match e.kind {
            VolumeErrorKind::Io(io) => decompress_or_io(&data_path, io),
            _ => e,
        })?;
        return Ok(vol.with_source(source));
    }
    let bytes = if h.vox_offset < consumed {
        let from_head = &prefix[h.vox_offset as usize..];
        let mut buf = from_head[..from_head.len().min(expected as usize)].to_vec();
        let rest = read_up_to(&mut data, expected - buf.len() as u64, &data_path)?;
        buf.extend_from_slice(&rest);
        buf
    } else {
        let skip = h.vox_offset - consumed;
        let skipped = std::io::copy(&mut data.by_ref().take(skip), &mut std::io::sink())
            .map_err(|e| decompress_or_io(&data_path, e))?;
        if skipped < skip {
            return Err(truncated(0).at(&data_path));
        }
        read_up_to(&mut data, expected, &data_path)?
    };
    if (bytes.len() as u64) < expected {
        return Err(truncated(bytes.len() as u64).at(&data_path));
    }
    let mut values = decode_voxels(&bytes, h.voxel_type, h.big_endian);
    if let Some((slope, inter)) = h.scale {
        for v in &mut values {
            *v = (*v as f64 * slope + inter) as f32;
        }
    }
    let values = reorient.apply(values, h.dims);
    let dims = reorient.dims(h.dims);
    Ok(Volume::from_values(name, dims, spacing, values).map_err(|e| e.at(path))?.with_source(source))
}

/// What [`write()`] writes besides the voxels.
#[derive(Clone, Debug)]
pub struct WriteOptions {
    /// 1 or 2.
    pub version: u8,
    /// `pixdim[1..4]` (signed: with no sform a negative one flips its axis on reading).
    pub pixdim: [f32; 3],
    /// `scl_slope` and `scl_inter` (slope 0: none).
    pub scale: (f32, f32),
    /// The sform rows (RAS), `sform_code` 1 (scanner) where given, else no orientation.
    pub sform: Option<[[f32; 4]; 3]>,
    /// Gzip the file (`.nii.gz`).
    pub gzip: bool,
}

/// Writes a single-file NIfTI-1 or NIfTI-2 volume (little-endian, data at byte 352 or 544).
/// Used by tests and for exporting.
pub fn write(path: &Path, volume_bytes: &[u8], ty: VoxelType, dims: [u32; 3], o: &WriteOptions) -> std::io::Result<()> {
    use std::io::Write;
    let datatype: i16 = match ty {
        VoxelType::U8 => 2,
        VoxelType::I16 => 4,
        VoxelType::I32 => 8,
        VoxelType::F32 => 16,
        VoxelType::F64 => 64,
        VoxelType::I8 => 256,
        VoxelType::U16 => 512,
        VoxelType::U32 => 768,
    };
    let bitpix = 8 * ty.size() as i16;
    let mut h;
    if o.version == 2 {
        h = vec![0u8; 544];
        h[0..4].copy_from_slice(&540i32.to_le_bytes());
        h[4..12].copy_from_slice(b"n+2\0\r\n\x1a\n");
        h[12..14].copy_from_slice(&datatype.to_le_bytes());
        h[14..16].copy_from_slice(&bitpix.to_le_bytes());
        let dim = [3i64, dims[0] as i64, dims[1] as i64, dims[2] as i64, 1, 1, 1, 1];
        for (i, d) in dim.iter().enumerate() {
            h[16 + 8 * i..24 + 8 * i].copy_from_slice(&d.to_le_bytes());
        }
        let pix = [1.0, o.pixdim[0] as f64, o.pixdim[1] as f64, o.pixdim[2] as f64, 0.0, 0.0, 0.0, 0.0];
        for (i, p) in pix.iter().enumerate() {
            h[104 + 8 * i..112 + 8 * i].copy_from_slice(&p.to_le_bytes());
        }
        h[168..176].copy_from_slice(&544i64.to_le_bytes());
        h[176..184].copy_from_slice(&(o.scale.0 as f64).to_le_bytes());
        h[184..192].copy_from_slice(&(o.scale.1 as f64).to_le_bytes());
        if let Some(s) = o.sform {
            h[348..352].copy_from_slice(&1i32.to_le_bytes());
            for (r, row) in s.iter().enumerate() {
                for (c, v) in row.iter().enumerate() {
                    h[400 + 32 * r + 8 * c..408 + 32 * r + 8 * c].copy_from_slice(&(*v as f64).to_le_bytes());
                }
            }
        }
    } else {
        h = vec![0u8; 352];
        h[0..4].copy_from_slice(&348i32.to_le_bytes());
        let dim = [3i16, dims[0] as i16, dims[1] as i16, dims[2] as i16, 1, 1, 1, 1];
        for (i, d) in dim.iter().enumerate() {
            h[40 + 2 * i..42 + 2 * i].copy_from_slice(&d.to_le_bytes());
        }
        h[70..72].copy_from_slice(&datatype.to_le_bytes());
        h[72..74].copy_from_slice(&bitpix.to_le_bytes());
        let pix = [1.0f32, o.pixdim[0], o.pixdim[1], o.pixdim[2], 0.0, 0.0, 0.0, 0.0];
        for (i, p) in pix.iter().enumerate() {
            h[76 + 4 * i..80 + 4 * i].copy_from_slice(&p.to_le_bytes());
        }
        h[108..112].copy_from_slice(&352f32.to_le_bytes());
        h[112..116].copy_from_slice(&o.scale.0.to_le_bytes());
        h[116..120].copy_from_slice(&o.scale.1.to_le_bytes());
        if let Some(s) = o.sform {
            h[254..256].copy_from_slice(&1i16.to_le_bytes());
            for (r, row) in s.iter().enumerate() {
                for (c, v) in row.iter().enumerate() {
                    h[280 + 16 * r + 4 * c..284 + 16 * r + 4 * c].copy_from_slice(&v.to_le_bytes());
                }
            }
        }
        h[344..348].copy_from_slice(b"n+1\0");
    }
    let f = std::fs::File::create(path)?;
    if o.gzip {
        let mut e = flate2::write::GzEncoder::new(f, flate2::Compression::fast());
        e.write_all(&h)?;
        e.write_all(volume_bytes)?;
        e.finish()?.flush()
    } else {
        let mut f = std::io::BufWriter::new(f);
        f.write_all(&h)?;
        f.write_all(volume_bytes)?;
        f.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_bad_headers_without_panicking() {
        let mut h = vec![0u8; 352];
        h[0..4].copy_from_slice(&348i32.to_le_bytes());
        h[344..348].copy_from_slice(b"n+1\0");
        // dim[0] = 0
        assert!(parse_header(&h).is_err());
        h[40..42].copy_from_slice(&3i16.to_le_bytes());
        for i in 1..4 {
            h[40 + 2 * i..42 + 2 * i].copy_from_slice(&2i16.to_le_bytes());
        }
        h[70..72].copy_from_slice(&2i16.to_le_bytes());
        h[108..112].copy_from_slice(&352f32.to_le_bytes());
        let ok = parse_header(&h).unwrap();
        assert_eq!(ok.dims, [2, 2, 2]);
        assert_eq!(ok.orientation, Orientation::None([1.0; 3]));
        for cut in [0, 3, 100, 347] {
            assert!(parse_header(&h[..cut]).is_err());
        }
        let mut neg = h.clone();
        neg[42..44].copy_from_slice(&(-2i16).to_le_bytes());
        assert!(parse_header(&neg).is_err());
        let mut cplx = h.clone();
        cplx[70..72].copy_from_slice(&32i16.to_le_bytes());
        assert!(matches!(parse_header(&cplx).unwrap_err().kind, VolumeErrorKind::Unsupported(_)));
        let mut big = h.clone();
        big[0..4].copy_from_slice(&348i32.to_be_bytes());
        assert!(parse_header(&big).is_err(), "big-endian fields read as such");
    }
}
