//! Scalar volumes: the data the server renders.
//!
//! **World space.** A volume of `dims` voxels with `spacing` sits in the box
//! `[0, dims · spacing]`; voxel `(i, j, k)` has its centre at `((i, j, k) + 0.5) · spacing`.
//! Sampling is trilinear between voxel centres and clamps to the nearest voxel within half a
//! voxel of the box faces.
//!
//! **Storage.** The voxels are bricked in their own type ([`bricks`], [`Voxels`]): 8- and
//! 16-bit files keep 1 and 2 bytes per voxel (signed 16-bit offset by 32,768), other data is
//! kept as `f32` normalized to `0..=1`. A stored value, or a trilinear blend of stored values,
//! `s` normalizes to `(s − offset) · scale` ([`Volume::normalization`]; `scale` the largest
//! `f32` with `range · scale ≤ 1`, so an 8- or 16-bit value `min + code` normalizes to
//! `code · scale` exactly), so a transfer function is a lookup over `0..=1`
//! ([`Volume::value_range`] is the data range in the file's units). The scalar and the packet
//! marcher both blend the stored values first and normalize the blend, with the same
//! arithmetic, so they agree bit for bit. A load refuses a volume that would take more memory
//! than [`LoadOptions::memory`] allows before it allocates anything.
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
//! | [`bricks`] | bricked storage in the file's own type, the streaming brick builder |
//! | `sampling.rs` | voxel reads and trilinear sampling |
//! | `raw.rs` | [`VoxelType`], raw file names ([`parse_raw_name`]), voxel decoding, the raw loader |
//! | [`nrrd`] | NRRD headers and data |
//! | [`nifti`] | NIfTI-1 and NIfTI-2 headers and data |
//! | [`tiff_stack`] | multi-page TIFF files and folders of TIFF slices |
//! | [`vti`] | VTK XML image data |
//! | [`dicom`] | DICOM series and multi-frame files |
//! | [`orient`] | axis-aligned orientations: the reordering into LPS |
//! | [`pyramid`] | levels of detail: ever coarser copies in the same box |
//! | `stream.rs` | streaming loads: slab by slab into bricks (raw, NRRD) |

pub mod bricks;
pub mod dicom;
mod error;
pub mod nifti;
pub mod nrrd;
pub mod orient;
pub mod pyramid;
mod raw;
mod sampling;
mod stream;
pub mod tiff_stack;
pub mod vti;

pub use bricks::Voxels;
pub use error::{VolumeError, VolumeErrorKind};
pub(crate) use raw::read_exactly;
pub use raw::{decode_voxels, parse_dims, parse_raw_name, RawName, VoxelType};
pub use sampling::flat_sample;

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
    /// Most voxels accepted (default: no limit but memory; the fuzzers bound it).
    pub max_voxels: u64,
    /// The memory a volume may take (see [`MemoryLimit`]; default what the system has
    /// available).
    pub memory: MemoryLimit,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions {
            dims: None,
            voxel_type: None,
            spacing: None,
            max_voxels: u64::MAX,
            memory: MemoryLimit::Available,
        }
    }
}

/// How much memory a load may take; a volume that needs more is refused before anything is
/// allocated ([`VolumeErrorKind::OutOfMemory`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MemoryLimit {
    /// What the system has available now (`MemAvailable` of `/proc/meminfo`; no limit where
    /// that is unknown).
    Available,
    /// At most this many bytes.
    Bytes(u64),
    /// No limit: try the allocation whatever it needs (`--max-memory none`).
    Unlimited,
}

impl MemoryLimit {
    /// The limit in bytes (`None`: none known).
    pub fn bytes(self) -> Option<u64> {
        match self {
            MemoryLimit::Available => available_memory(),
            MemoryLimit::Bytes(b) => Some(b),
            MemoryLimit::Unlimited => None,
        }
    }

    /// Parses `auto` (available memory), `none` (no limit) or a size such as `20G`, `512M`,
    /// `1.5GiB`, `123456` (bytes).
    pub fn parse(s: &str) -> Result<MemoryLimit, String> {
        let t = s.trim().to_ascii_lowercase();
        match t.as_str() {
            "auto" | "available" => return Ok(MemoryLimit::Available),
            "none" | "unlimited" | "force" => return Ok(MemoryLimit::Unlimited),
            _ => {}
        }
        let t = t.trim_end_matches("ib").trim_end_matches('b');
        let (num, mul) = match t.chars().last() {
            Some('k') => (&t[..t.len() - 1], 1u64 << 10),
            Some('m') => (&t[..t.len() - 1], 1 << 20),
            Some('g') => (&t[..t.len() - 1], 1 << 30),
            Some('t') => (&t[..t.len() - 1], 1 << 40),
            _ => (t, 1),
        };
        let v: f64 = num.trim().parse().map_err(|_| format!("{s:?} is not a size (e.g. 20G, 512M), auto or none"))?;
        if !(v.is_finite() && v >= 0.0) {
            return Err(format!("{s:?} is not a size"));
        }
        Ok(MemoryLimit::Bytes((v * mul as f64).min(u64::MAX as f64) as u64))
    }

    /// Refuses `needed` bytes where they are over the limit.
    pub(crate) fn check(self, needed: u64) -> Result<(), VolumeError> {
        match self.bytes() {
            Some(available) if needed > available => {
                Err(VolumeError::new(VolumeErrorKind::OutOfMemory { needed, available: Some(available) }))
            }
            _ => Ok(()),
        }
    }
}

/// `MemAvailable` of `/proc/meminfo` in bytes (`None` where it cannot be read).
pub fn available_memory() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    kib.checked_mul(1024)
}

/// A scalar volume (see the module docs for its place in world space): its voxels bricked in
/// their own type ([`Voxels`]), and how a stored value normalizes to `0..=1`.
#[derive(Clone, Debug)]
pub struct Volume {
    /// A short name (file stem).
    pub name: String,
    dims: [u32; 3],
    spacing: Vec3,
    value_range: (f32, f32),
    /// The voxels.
    voxels: Voxels,
    /// Normalization: a stored value (or a trilinear blend of stored values) `s` is
    /// `(s − offset) · scale` normalized.
    offset: f32,
    /// See `offset`.
    scale: f32,
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

/// The largest `f32` scale with `range · scale ≤ 1` in `f32` arithmetic (so codes normalize
/// into `0 ..= 1` without clamping), 0 for an empty range.
pub(crate) fn code_scale(range: f32) -> f32 {
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

/// Checks dims and spacing like [`check_geometry`] and refuses a volume whose loading needs
/// more memory than `opts.memory` allows: the bricks of `stored_bytes` per value and
/// `decoded_bytes` per voxel of temporary decoded values (0 for the streaming loaders). Returns
/// the number of voxels.
pub(crate) fn check_load(
    dims: [u32; 3],
    spacing: Vec3,
    opts: &LoadOptions,
    stored_bytes: u64,
    decoded_bytes: u64,
) -> Result<u64, VolumeError> {
    let voxels = check_geometry(dims, spacing, opts.max_voxels)?;
    // The bricks, one slab of slices while they are built, any decoding buffer, and the
    // empty-space grids (15 bytes per skipping brick: its range, flags, distances and look).
    let slab = u64::from(dims[0]) * u64::from(dims[1]) * u64::from(bricks::BRICK_SPAN) * stored_bytes;
    let cell = u64::from(crate::empty_space::brick_for(voxels));
    let grids = dims.iter().map(|&d| u64::from(d).div_ceil(cell)).product::<u64>() * 15;
    let needed = bricks::Layout::stored_bytes(dims, stored_bytes)
        .and_then(|b| b.checked_add(slab))
        .and_then(|b| voxels.checked_mul(decoded_bytes)?.checked_add(b))
        .and_then(|n| n.checked_add(grids))
        .ok_or_else(|| {
            VolumeError::new(VolumeErrorKind::BadGeometry(format!(
                "dimensions {}x{}x{} give more than 2^64 bytes",
                dims[0], dims[1], dims[2]
            )))
        })?;
    opts.memory.check(needed)?;
    bricks::Layout::new(dims)?;
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
    /// the data minimum; integer values at most 65,535 apart are stored as 8- or 16-bit codes
    /// `value − min` (normalized `code · scale`, `scale` the largest `f32` with `range · scale ≤ 1`), others as `f32` normalized
    /// over their range in `f64`.
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
        let coded =
            hi - lo <= 65_535.0 && values.iter().all(|v| v.is_finite() && v.fract() == 0.0 && v.abs() < 16_777_216.0);
        let (voxels, scale) = if coded && hi - lo <= 255.0 {
            (Voxels::U8(bricks::grid_from_fn(dims, &values, |v| (v - lo) as u8)?), code_scale(hi - lo))
        } else if coded {
            (Voxels::U16(bricks::grid_from_fn(dims, &values, |v| (v - lo) as u16)?), code_scale(hi - lo))
        } else {
            let inv_range = if hi > lo { 1.0 / (hi as f64 - lo as f64) } else { 0.0 };
            for v in values.iter_mut() {
                *v = if v.is_finite() { ((*v as f64 - lo as f64) * inv_range).clamp(0.0, 1.0) as f32 } else { 0.0 };
            }
            (Voxels::F32(bricks::grid_from_values(dims, &values)?), 1.0)
        };
        Ok(Volume::from_voxels(name, spacing, voxels, (lo, hi), 0.0, scale))
    }

    /// A volume of bricked `voxels`: a stored value `s` normalizes to `(s − offset) · scale`;
    /// `value_range` is the data range in the source's units.
    pub(crate) fn from_voxels(
        name: &str,
        spacing: Vec3,
        voxels: Voxels,
        value_range: (f32, f32),
        offset: f32,
        scale: f32,
    ) -> Volume {
        Volume {
            name: name.to_string(),
            dims: voxels.layout().dims(),
            spacing,
            value_range,
            voxels,
            offset,
            scale,
            source: SourceInfo::default(),
        }
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

    /// The stored voxels.
    pub fn voxels(&self) -> &Voxels {
        &self.voxels
    }

    /// The normalization of stored values: `(offset, scale)`, a stored value `s` normalizes to
    /// `(s − offset) · scale`.
    pub fn normalization(&self) -> (f32, f32) {
        (self.offset, self.scale)
    }

    /// The same volume with its bricks in chunks of at most `limit` values (see
    /// [`bricks::Layout::with_chunk_limit`]): how tests make a small volume take the chunked
    /// gathers of volumes beyond 2³¹ values.
    pub fn rechunked(&self, limit: usize) -> Result<Volume, VolumeError> {
        Ok(Volume { voxels: self.voxels.rechunked(limit)?, ..self.clone() })
    }

    /// Bytes the voxels take in memory.
    pub fn memory_bytes(&self) -> u64 {
        self.voxels.bytes()
    }

    /// The normalized values, x fastest (allocates 4 bytes per voxel: for tests and small
    /// volumes).
    pub fn values(&self) -> Vec<f32> {
        let [nx, ny, nz] = self.dims;
        let mut out = Vec::with_capacity(nx as usize * ny as usize * nz as usize);
        for k in 0..nz {
            for j in 0..ny {
                out.extend((0..nx).map(|i| self.voxel(i, j, k)));
            }
        }
        out
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
    fn integer_values_are_stored_as_codes_that_normalize_exactly() {
        // 8-bit codes, 16-bit codes (a 16-bit range), a flat volume; fractions and wide ranges
        // as normalized f32.
        let cases: [(Vec<f32>, &str); 6] = [
            (vec![1000.0, 1200.0, 1100.0, 1001.0, 1254.0, 1000.0], "u8"),
            ((0..24).map(|i| (i * 37 % 256) as f32).chain([0.0, 255.0]).collect(), "u8"),
            (vec![7.0; 6], "u8"),
            ((0..30).map(|i| (i * 4099 % 65_536) as f32 - 32_768.0).chain([-32_768.0, 32_767.0]).collect(), "u16"),
            (vec![0.0, 65_536.0], "f32"),
            (vec![0.0, 0.5], "f32"),
        ];
        for (values, ty) in cases {
            let dims = [values.len() as u32 / 2, 2, 1];
            let v = Volume::from_values("b", dims, Vec3::ONE, values.clone()).unwrap();
            assert_eq!(v.voxels().type_name(), ty, "{values:?}");
            let (lo, hi) = v.value_range();
            let (offset, scale) = v.normalization();
            for (&x, n) in values.iter().zip(v.values()) {
                assert!((0.0..=1.0).contains(&n));
                if ty != "f32" {
                    assert_eq!(offset, 0.0);
                    assert!((hi - lo) * scale <= 1.0);
                    assert_eq!(n.to_bits(), ((x - lo) * scale).to_bits(), "{x}");
                } else {
                    assert_eq!(n, ((x as f64 - lo as f64) / (hi as f64 - lo as f64)) as f32);
                }
            }
        }
        let nan = Volume::from_values("n", [2, 1, 1], Vec3::ONE, vec![3.0, f32::NAN]).unwrap();
        assert_eq!(nan.voxels().type_name(), "f32");
        assert_eq!(nan.values(), vec![0.0, 0.0]);
    }

    #[test]
    fn memory_limits_parse_and_refuse() {
        assert_eq!(MemoryLimit::parse("20G"), Ok(MemoryLimit::Bytes(20 << 30)));
        assert_eq!(MemoryLimit::parse("512MiB"), Ok(MemoryLimit::Bytes(512 << 20)));
        assert_eq!(MemoryLimit::parse("1.5g"), Ok(MemoryLimit::Bytes(3 << 29)));
        assert_eq!(MemoryLimit::parse("123"), Ok(MemoryLimit::Bytes(123)));
        assert_eq!(MemoryLimit::parse("none"), Ok(MemoryLimit::Unlimited));
        assert_eq!(MemoryLimit::parse("auto"), Ok(MemoryLimit::Available));
        assert!(MemoryLimit::parse("lots").is_err());
        assert!(MemoryLimit::parse("-1G").is_err());
        let e = MemoryLimit::Bytes(1000).check(1001).unwrap_err();
        assert!(matches!(e.kind, VolumeErrorKind::OutOfMemory { needed: 1001, available: Some(1000) }));
        assert!(e.to_string().contains("--max-memory"), "{e}");
        assert!(MemoryLimit::Unlimited.check(u64::MAX).is_ok());
        assert!(available_memory().is_some_and(|b| b > 0));
    }

    #[test]
    fn marschner_lobb_is_in_range() {
        let v = Volume::marschner_lobb(16);
        assert_eq!(v.dims(), [16; 3]);
        assert!(v.values().iter().all(|x| (0.0..=1.0).contains(x)));
    }
}
