//! Scalar volumes: the data the server renders.
//!
//! **World space.** A volume of `dims` voxels with `spacing` sits in the box
//! `[0, dims · spacing]`; voxel `(i, j, k)` has its centre at `((i, j, k) + 0.5) · spacing`.
//! Sampling is trilinear between voxel centres and clamps to the nearest voxel within half a
//! voxel of the box faces.
//!
//! Values are stored normalized to `0..=1` over the data range of the file
//! ([`Volume::value_range`]), so a transfer function is a lookup over `0..=1`. Integer values
//! at most 65,535 apart (every 8- and 16-bit volume) are *integer-coded*: code `value − min`,
//! normalized value `code as f32 · scale` in `f32` arithmetic (`scale` the largest `f32` with
//! `range · scale ≤ 1`), which the packet marcher reproduces bit for bit from the codes it
//! gathers (`CodeStencil`: bytes where the range is at most 255, else 16-bit codes); other values
//! (`f32` data, wider integers) are normalized in `f64`.
//!
//! Loaders ([`load_volume`], the format recognized by content and extension:
//! [`detect_format`]): headerless raw files named `name_XxYxZ_type.raw` ([`parse_raw_name`];
//! dims, type and spacing may also come from [`LoadOptions`]), NRRD (`.nrrd` attached, `.nhdr`
//! detached; raw or gzip; see [`nrrd`]), NIfTI-1/2 ([`nifti`]), TIFF stacks ([`tiff_stack`]),
//! VTK image data ([`vti`]) and DICOM series ([`dicom`]). The volume box's axes are DICOM
//! patient space LPS; loaders of oriented formats reorder axis-aligned volumes into it
//! ([`orient`]) and refuse oblique ones. [`Volume::source`] says what was read. Every failure
//! is a [`VolumeError`] naming the file and the problem, never a panic.
//!
//! | file | content |
//! |---|---|
//! | `mod.rs` | the [`Volume`] data model, [`LoadOptions`], [`load_volume`] |
//! | `error.rs` | [`VolumeError`] and [`VolumeErrorKind`] |
//! | `sampling.rs` | voxel reads and trilinear sampling |
//! | `raw.rs` | [`VoxelType`], raw file names ([`parse_raw_name`]), voxel decoding, the raw loader |
//! | [`nrrd`] | NRRD headers and data |
//! | [`nifti`] | NIfTI-1 and NIfTI-2 headers and data |
//! | [`tiff_stack`] | multi-page TIFF files and folders of TIFF slices |
//! | [`vti`] | VTK XML image data |
//! | [`dicom`] | DICOM series and multi-frame files |
//! | [`orient`] | axis-aligned orientations: the reordering into LPS |

pub mod dicom;
mod error;
pub mod nifti;
pub mod nrrd;
pub mod orient;
mod raw;
mod sampling;
pub mod tiff_stack;
pub mod vti;

pub use error::{VolumeError, VolumeErrorKind};
pub(crate) use raw::read_exactly;
pub use raw::{decode_voxels, parse_dims, parse_raw_name, RawName, VoxelType};

use std::path::Path;
use volwarp_core::sample::Bounds;
use volwarp_core::Vec3;

/// Options for [`load_volume`]; every field overrides what the file name or header says.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadOptions {
    /// Dimensions (x, y, z) of a raw file.
    pub dims: Option<[u32; 3]>,
    /// Voxel type of a raw file.
    pub voxel_type: Option<VoxelType>,
    /// Voxel spacing (default: from the NRRD header, else 1, 1, 1).
    pub spacing: Option<Vec3>,
    /// Most voxels accepted (default 2²⁸, i.e. 1 GiB as f32).
    pub max_voxels: u64,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions { dims: None, voxel_type: None, spacing: None, max_voxels: 1 << 28 }
    }
}

/// A scalar volume, normalized to `0..=1` (see the module docs for its place in world space).
#[derive(Clone, Debug)]
pub struct Volume {
    /// A short name (file stem).
    pub name: String,
    dims: [u32; 3],
    spacing: Vec3,
    value_range: (f32, f32),
    /// The values, then [`Volume::padding`] zeros (so that reads of a trilinear neighbourhood
    /// need no clamping of its far corners; see `padded_data`).
    data: Vec<f32>,
    /// For integer-coded volumes, the packet marcher's stencil (see [`CodeStencil`]).
    stencil: Option<CodeStencil>,
    /// What the loader read.
    source: SourceInfo,
}

/// What a loader read: the format, the stored voxel type and the reordering it applied (what
/// `volwarp-server info` prints besides dims, spacing and value range).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SourceInfo {
    /// The format (`raw`, `NRRD`, `NIfTI-1`, `NIfTI-2`, `TIFF`, `VTK image data`, `DICOM`);
    /// empty for a volume made in memory.
    pub format: String,
    /// The stored voxel type, where it is one of [`VoxelType`].
    pub voxel_type: Option<VoxelType>,
    /// The reordering applied to put the volume in LPS order (see [`orient`]), or what was
    /// left as stored.
    pub orientation: String,
    /// Bytes of voxel data read (decompressed).
    pub data_bytes: u64,
    /// Files read.
    pub files: usize,
}

/// The voxels of a volume of integer values at most 65,535 apart (every 8- and 16-bit volume),
/// as codes `value − min` with the normalized value `code as f32 * scale` (exactly what
/// [`Volume::data`] holds for them), arranged for the packet marcher's gathers: element `i`
/// holds the codes of voxels `i`, `i + 1`, `i + nx` and `i + nx + 1` (the x–y square of a
/// trilinear stencil), so two gathers (this slice and the next) read all eight corners, where
/// `f32` values take four gathers of pairs. Reads past the volume's rows or end give codes whose
/// weight is 0.
#[derive(Clone, Debug)]
pub(crate) struct CodeStencil {
    /// The squares, one per voxel, then [`Volume::padding`] more.
    pub(crate) squares: Squares,
    /// The normalized value of code 1.
    pub(crate) scale: f32,
}

/// The x–y squares of codes of a [`CodeStencil`].
#[derive(Clone, Debug)]
pub(crate) enum Squares {
    /// Values at most 255 apart: byte codes, voxel `i`, `i + 1`, `i + nx`, `i + nx + 1` in bytes
    /// 0 to 3 of a word.
    Bytes(Vec<u32>),
    /// Values at most 65,535 apart: 16-bit codes, in 16-bit fields 0 to 3 of a 64-bit word.
    Shorts(Vec<u64>),
}

/// Most voxels a [`CodeStencil`] is built for (4 bytes per voxel for byte codes, as the values
/// take; 8 for 16-bit codes).
const MAX_STENCIL_VOXELS: u64 = 1 << 26;

/// The largest `f32` scale with `range · scale ≤ 1` in `f32` arithmetic (so codes normalize
/// into `0 ..= 1` without clamping), 0 for an empty range.
fn code_scale(range: f32) -> f32 {
    if range <= 0.0 {
        return 0.0;
    }
    let mut s = (1.0 / range as f64) as f32;
    while range * s > 1.0 {
        s = f32::from_bits(s.to_bits() - 1);
    }
    s
}

/// Checks dims and spacing and returns the number of voxels (at most `max_voxels`).
pub(crate) fn check_geometry(dims: [u32; 3], spacing: Vec3, max_voxels: u64) -> Result<u64, VolumeError> {
    if dims.contains(&0) {
        return Err(VolumeError::new(VolumeErrorKind::BadGeometry(format!("dimensions {dims:?} contain a zero"))));
    }
    if !spacing.is_finite()
        || spacing.min_element() <= 0.0
        || (Vec3::from(dims.map(|d| d as f32)) * spacing).max_element() > 1e12
    {
        return Err(VolumeError::new(VolumeErrorKind::BadGeometry(format!(
            "spacing {spacing} must be positive and finite"
        ))));
    }
    let voxels = voxel_count(dims)?;
    if voxels > max_voxels {
        return Err(VolumeError::new(VolumeErrorKind::TooLarge { voxels, limit: max_voxels }));
    }
    Ok(voxels)
}

/// The number of voxels of `dims`, an error where the product does not fit in 64 bits (a
/// header's dims must never wrap around to a small count that passes the size checks).
pub(crate) fn voxel_count(dims: [u32; 3]) -> Result<u64, VolumeError> {
    dims.iter().try_fold(1u64, |n, &d| n.checked_mul(u64::from(d))).ok_or_else(|| {
        VolumeError::new(VolumeErrorKind::BadGeometry(format!(
            "dimensions {}x{}x{} give more than 2^64 voxels",
            dims[0], dims[1], dims[2]
        )))
    })
}

/// The bytes of `voxels` voxels of `ty`, an error where that does not fit in 64 bits.
pub(crate) fn voxel_bytes(voxels: u64, ty: VoxelType) -> Result<u64, VolumeError> {
    voxels.checked_mul(ty.size() as u64).ok_or_else(|| {
        VolumeError::new(VolumeErrorKind::BadGeometry(format!("{voxels} voxels of {ty:?} give more than 2^64 bytes")))
    })
}

impl Volume {
    /// A volume from values in x-fastest order (`dims` product long). Non-finite values become
    /// the data minimum; the values are normalized over their range (integer-coded where they are
    /// integers at most 65,535 apart, see the module docs).
    pub fn from_values(name: &str, dims: [u32; 3], spacing: Vec3, mut values: Vec<f32>) -> Result<Volume, VolumeError> {
        let n = check_geometry(dims, spacing, u64::MAX)?;
        if values.len() as u64 != n {
            return Err(VolumeError::new(VolumeErrorKind::SizeMismatch {
                expected: n * 4,
                actual: values.len() as u64 * 4,
            }));
        }
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for &v in values.iter().filter(|v| v.is_finite()) {
            lo = lo.min(v);
            hi = hi.max(v);
        }
        if lo > hi {
            (lo, hi) = (0.0, 0.0);
        }
        // Integer values at most 65,535 apart: codes, normalized in f32 arithmetic so that the
        // packet marcher can normalize the codes it gathers to the same bits.
        let coded = hi - lo <= 65_535.0
            && n <= MAX_STENCIL_VOXELS >> u32::from(hi - lo > 255.0)
            && values.iter().all(|v| v.is_finite() && v.fract() == 0.0 && v.abs() < 16_777_216.0);
        let mut codes: Vec<u16> = Vec::new();
        let scale = code_scale(hi - lo);
        if coded {
            codes = values.iter().map(|&v| (v - lo) as u16).collect();
            for (v, &c) in values.iter_mut().zip(&codes) {
                *v = c as f32 * scale;
            }
        } else {
            let inv_range = if hi > lo { 1.0 / (hi as f64 - lo as f64) } else { 0.0 };
            for v in values.iter_mut() {
                *v = if v.is_finite() { ((*v as f64 - lo as f64) * inv_range).clamp(0.0, 1.0) as f32 } else { 0.0 };
            }
        }
        values.resize(values.len() + Volume::padding(dims), 0.0);
        let stencil = coded.then(|| {
            let nx = dims[0] as usize;
            let code = |i: usize| codes.get(i).copied().unwrap_or(0) as u64;
            let square = |i: usize| [code(i), code(i + 1), code(i + nx), code(i + nx + 1)];
            let squares = if hi - lo <= 255.0 {
                let word = |c: [u64; 4]| (c[0] | c[1] << 8 | c[2] << 16 | c[3] << 24) as u32;
                Squares::Bytes((0..values.len()).map(|i| word(square(i))).collect())
            } else {
                let word = |c: [u64; 4]| c[0] | c[1] << 16 | c[2] << 32 | c[3] << 48;
                Squares::Shorts((0..values.len()).map(|i| word(square(i))).collect())
            };
            CodeStencil { squares, scale }
        });
        Ok(Volume {
            name: name.to_string(),
            dims,
            spacing,
            value_range: (lo, hi),
            data: values,
            stencil,
            source: SourceInfo::default(),
        })
    }

    /// What the loader read (empty for a volume made in memory).
    pub fn source(&self) -> &SourceInfo {
        &self.source
    }

    /// The volume with `source` as what was read.
    pub fn with_source(mut self, source: SourceInfo) -> Volume {
        self.source = source;
        self
    }

    /// A volume from a function of the world position of each voxel centre.
    pub fn from_fn(name: &str, dims: [u32; 3], spacing: Vec3, f: impl Fn(Vec3) -> f32) -> Result<Volume, VolumeError> {
        let n = check_geometry(dims, spacing, 1 << 28)?;
        let mut values = Vec::with_capacity(n as usize);
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    values.push(f((Vec3::new(i as f32, j as f32, k as f32) + 0.5) * spacing));
                }
            }
        }
        Volume::from_values(name, dims, spacing, values)
    }

    /// The Marschner–Lobb test signal (f_M = 6, α = 0.25) sampled at `n³` voxels over
    /// `[-1, 1]³`, with unit spacing (so the box is `[0, n]³`).
    pub fn marschner_lobb(n: u32) -> Volume {
        let n = n.clamp(2, 512);
        let (fm, alpha) = (6.0f64, 0.25f64);
        let pi = std::f64::consts::PI;
        Volume::from_fn("marschner-lobb", [n; 3], Vec3::ONE, |p| {
            let q = [p.x, p.y, p.z].map(|c| c as f64 / n as f64 * 2.0 - 1.0);
            let r = (q[0] * q[0] + q[1] * q[1]).sqrt();
            let rho_r = (2.0 * pi * fm * (pi * r / 2.0).cos()).cos();
            ((1.0 - (pi * q[2] / 2.0).sin() + alpha * (1.0 + rho_r)) / (2.0 * (1.0 + alpha))) as f32
        })
        .expect("a clamped Marschner-Lobb size is always valid")
    }

    /// Dimensions (x, y, z) in voxels.
    pub fn dims(&self) -> [u32; 3] {
        self.dims
    }

    /// Voxel spacing.
    pub fn spacing(&self) -> Vec3 {
        self.spacing
    }

    /// The data range of the source, in its own units (normalized 0 and 1 map to these).
    pub fn value_range(&self) -> (f32, f32) {
        self.value_range
    }

    /// The volume box's size, `dims · spacing`.
    pub fn extent(&self) -> Vec3 {
        Vec3::new(self.dims[0] as f32, self.dims[1] as f32, self.dims[2] as f32) * self.spacing
    }

    /// The volume box `[0, dims · spacing]`: the bounds of every frame.
    pub fn bounds(&self) -> Bounds {
        Bounds::new(Vec3::ZERO, self.extent())
    }

    /// Length of one voxel's diagonal, `|spacing|`.
    pub fn voxel_diagonal(&self) -> f32 {
        self.spacing.length()
    }

    /// The normalized values, x fastest.
    pub fn data(&self) -> &[f32] {
        &self.data[..self.data.len() - Volume::padding(self.dims)]
    }

    /// Zeros stored after the values: one slice, one row and two values, so that the eight
    /// neighbours `base + {0, 1} + {0, nx} + {0, nx·ny}` of any voxel `base` can be read
    /// without bounds (the packet marcher's gathers; a far neighbour past the volume's edge
    /// is read where its weight is exactly 0, so its value never matters).
    fn padding(dims: [u32; 3]) -> usize {
        dims[0] as usize * dims[1] as usize + dims[0] as usize + 2
    }

    /// [`Volume::data`] followed by the padding zeros.
    pub(crate) fn padded_data(&self) -> &[f32] {
        &self.data
    }

    /// The codes of an integer-coded volume, arranged for the packet marcher.
    pub(crate) fn code_stencil(&self) -> Option<&CodeStencil> {
        self.stencil.as_ref()
    }
}

/// The formats [`load_volume`] reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Headerless raw voxels.
    Raw,
    /// NRRD (`.nrrd`, `.nhdr`).
    Nrrd,
    /// NIfTI-1 or NIfTI-2 (`.nii`, `.nii.gz`).
    Nifti,
    /// A multi-page TIFF file.
    Tiff,
    /// A folder of single-page TIFF slices.
    TiffFolder,
    /// VTK XML image data (`.vti`).
    Vti,
    /// One DICOM file (a multi-frame volume or a single slice).
    Dicom,
    /// A folder of DICOM files (a series).
    DicomFolder,
}

/// The first `n` bytes of a file (fewer where it is shorter).
pub(crate) fn read_head(path: &Path, n: u64) -> Result<Vec<u8>, VolumeError> {
    use std::io::Read;
    let mut head = Vec::new();
    let f = std::fs::File::open(path).map_err(|e| VolumeError::io(path, e))?;
    f.take(n).read_to_end(&mut head).map_err(|e| VolumeError::io(path, e))?;
    Ok(head)
}

/// The format of `path`, from its content where that is telling (magic numbers) and else its
/// extension; a file of no known format is raw.
pub fn detect_format(path: &Path) -> Result<Format, VolumeError> {
    if path.is_dir() {
        return detect_folder(path);
    }
    let name = path.file_name().and_then(|s| s.to_str()).unwrap_or("").to_ascii_lowercase();
    let ext = path.extension().and_then(|s| s.to_str()).unwrap_or("").to_ascii_lowercase();
    let head = read_head(path, 548)?;
    if head.starts_with(b"NRRD000") {
        return Ok(Format::Nrrd);
    }
    // A gzip stream: look at the start of what it holds.
    let inner = if head.starts_with(&[0x1f, 0x8b]) {
        use std::io::Read;
        let f = std::fs::File::open(path).map_err(|e| VolumeError::io(path, e))?;
        let mut inner = Vec::new();
        let _ = flate2::read::MultiGzDecoder::new(f).take(548).read_to_end(&mut inner);
        inner
    } else {
        Vec::new()
    };
    if nifti::is_nifti(&head) || nifti::is_nifti(&inner) || name.ends_with(".nii") || name.ends_with(".nii.gz") {
        return Ok(Format::Nifti);
    }
    if tiff_stack::is_tiff(&head) {
        return Ok(Format::Tiff);
    }
    if dicom::is_dicom(&head) || ext == "dcm" {
        return Ok(Format::Dicom);
    }
    if vti::is_vti(&head) || ext == "vti" {
        return Ok(Format::Vti);
    }
    Ok(match ext.as_str() {
        "nrrd" | "nhdr" => Format::Nrrd,
        "tif" | "tiff" => Format::Tiff,
        _ => Format::Raw,
    })
}

/// The format of a folder's slices: DICOM where its files are DICOM (`DICM` at byte 128), TIFF
/// where they are TIFF.
fn detect_folder(dir: &Path) -> Result<Format, VolumeError> {
    if !dicom::folder_files(dir)?.is_empty() {
        return Ok(Format::DicomFolder);
    }
    if !tiff_stack::folder_slices(dir)?.is_empty() {
        return Ok(Format::TiffFolder);
    }
    Err(VolumeError::unsupported("a folder of neither TIFF slices nor DICOM files".to_string()).at(dir))
}

/// Loads a volume: raw (`.raw` or any other extension), NRRD (`.nrrd`, `.nhdr`), NIfTI
/// (`.nii`, `.nii.gz`), a multi-page TIFF or a folder of TIFF slices, VTK image data (`.vti`),
/// a DICOM file or a folder holding a DICOM series, recognized by content
/// and extension ([`detect_format`]).
pub fn load_volume(path: impl AsRef<Path>, opts: &LoadOptions) -> Result<Volume, VolumeError> {
    let path = path.as_ref();
    let format = detect_format(path)?;
    let vol = match format {
        Format::Nrrd => {
            let mut v = nrrd::load(path, opts)?;
            v.source.data_bytes = voxel_bytes(voxel_count(v.dims)?, v.source.voxel_type.unwrap_or(VoxelType::U8))?;
            v.source.format = "NRRD".into();
            v.source.files = 1;
            v
        }
        Format::Nifti => nifti::load(path, opts)?,
        Format::Tiff => tiff_stack::load_file(path, opts)?,
        Format::TiffFolder => tiff_stack::load_folder(path, opts)?,
        Format::Vti => vti::load(path, opts)?,
        Format::Dicom => dicom::load_file(path, opts)?,
        Format::DicomFolder => dicom::load_folder(path, opts)?,
        Format::Raw => {
            let mut v = raw::load_raw(path, opts)?;
            v.source.data_bytes = voxel_bytes(voxel_count(v.dims)?, v.source.voxel_type.unwrap_or(VoxelType::U8))?;
            v.source.format = "raw".into();
            v.source.files = 1;
            v.source.orientation = "none (stored order)".into();
            v
        }
    };
    log::info!(
        "loaded {} ({}): {}x{}x{} voxels, spacing {}, value range {:?}",
        path.display(),
        vol.source.format,
        vol.dims[0],
        vol.dims[1],
        vol.dims[2],
        vol.spacing,
        vol.value_range
    );
    Ok(vol)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integer_coded_volumes_normalize_their_codes_exactly() {
        // 16-bit values of small range (an unseen-volume case), 8-bit values, a flat volume.
        for values in [
            vec![1000.0, 1200.0, 1100.0, 1001.0, 1254.0, 1000.0],
            (0..24).map(|i| (i * 37 % 256) as f32).chain([0.0, 255.0]).collect(),
            vec![7.0; 6],
        ] {
            let range =
                values.iter().copied().fold(0.0, f32::max) - values.iter().copied().fold(f32::INFINITY, f32::min);
            let dims = [values.len() as u32 / 2, 2, 1];
            let v = Volume::from_values("b", dims, Vec3::ONE, values.clone()).unwrap();
            let st = v.code_stencil().expect("integer-coded");
            let Squares::Bytes(words) = &st.squares else { panic!("byte codes expected") };
            assert!(range * st.scale <= 1.0);
            let lo = values.iter().copied().fold(f32::INFINITY, f32::min);
            let nx = dims[0] as usize;
            for (i, (&x, &n)) in values.iter().zip(v.data()).enumerate() {
                let code = (x - lo) as u32;
                assert_eq!(n.to_bits(), (code as f32 * st.scale).to_bits());
                assert!((0.0..=1.0).contains(&n));
                assert_eq!(words[i] & 255, code);
                if i + nx + 1 < values.len() {
                    let c = |j: usize| (values[j] - lo) as u32;
                    assert_eq!(words[i], c(i) | c(i + 1) << 8 | c(i + nx) << 16 | c(i + nx + 1) << 24);
                }
            }
            if range > 0.0 {
                assert_eq!(v.data().iter().copied().fold(0.0, f32::max), range * st.scale);
            }
        }
        // 16-bit ranges: 16-bit codes.
        let values: Vec<f32> =
            (0..30).map(|i| (i * 4099 % 65_536) as f32 - 32_768.0).chain([-32_768.0, 32_767.0]).collect();
        let v = Volume::from_values("s", [8, 4, 1], Vec3::ONE, values.clone()).unwrap();
        let st = v.code_stencil().expect("integer-coded");
        let Squares::Shorts(words) = &st.squares else { panic!("16-bit codes expected") };
        assert!(65_535.0 * st.scale <= 1.0);
        for (i, (&x, &n)) in values.iter().zip(v.data()).enumerate() {
            let c = |j: usize| (values[j] + 32_768.0) as u64;
            assert_eq!(n.to_bits(), (c(i) as f32 * st.scale).to_bits());
            if i + 9 < values.len() {
                assert_eq!(words[i], c(i) | c(i + 1) << 16 | c(i + 8) << 32 | c(i + 9) << 48, "{x}");
            }
        }
        assert_eq!(v.data().iter().copied().fold(0.0, f32::max), 65_535.0 * st.scale);
        // Wider ranges and fractions keep the f64 normalization and no codes.
        for values in [vec![0.0, 65_536.0], vec![0.0, 0.5], vec![0.0, f32::NAN]] {
            let v = Volume::from_values("f", [2, 1, 1], Vec3::ONE, values).unwrap();
            assert!(v.code_stencil().is_none());
        }
    }

    #[test]
    fn marschner_lobb_is_in_range() {
        let v = Volume::marschner_lobb(16);
        assert_eq!(v.dims(), [16; 3]);
        assert!(v.data().iter().all(|x| (0.0..=1.0).contains(x)));
    }
}
