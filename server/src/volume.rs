//! Scalar volumes: the data the server renders.
//!
//! **World space.** A volume of `dims` voxels with `spacing` sits in the box
//! `[0, dims · spacing]`; voxel `(i, j, k)` has its centre at `((i, j, k) + 0.5) · spacing`.
//! Sampling is trilinear between voxel centres and clamps to the nearest voxel within half a
//! voxel of the box faces.
//!
//! Values are stored normalized to `0..=1` over the data range of the file
//! ([`Volume::value_range`]), so a transfer function is a lookup over `0..=1`.
//!
//! Loaders ([`load_volume`]): headerless raw files named `name_XxYxZ_type.raw`
//! ([`parse_raw_name`]; dims, type and spacing may also come from [`LoadOptions`]) and NRRD
//! (`.nrrd` attached, `.nhdr` detached; raw or gzip; see [`crate::nrrd`]). Every failure is a
//! [`VolumeError`] naming the file and the problem, never a panic.

use crate::nrrd;
use std::fmt;
use std::io::Read;
use std::path::{Path, PathBuf};
use volwarp_core::sample::Bounds;
use volwarp_core::Vec3;

/// The voxel types the loaders understand (all little-endian in raw files).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VoxelType {
    /// Unsigned 8-bit.
    U8,
    /// Signed 8-bit.
    I8,
    /// Unsigned 16-bit.
    U16,
    /// Signed 16-bit.
    I16,
    /// Unsigned 32-bit.
    U32,
    /// Signed 32-bit.
    I32,
    /// 32-bit float.
    F32,
    /// 64-bit float.
    F64,
}

impl VoxelType {
    /// Bytes per voxel.
    pub fn size(self) -> usize {
        match self {
            VoxelType::U8 | VoxelType::I8 => 1,
            VoxelType::U16 | VoxelType::I16 => 2,
            VoxelType::U32 | VoxelType::I32 | VoxelType::F32 => 4,
            VoxelType::F64 => 8,
        }
    }

    /// The name used in raw file names (`uint8`, `int16`, `float32`, …).
    pub fn name(self) -> &'static str {
        match self {
            VoxelType::U8 => "uint8",
            VoxelType::I8 => "int8",
            VoxelType::U16 => "uint16",
            VoxelType::I16 => "int16",
            VoxelType::U32 => "uint32",
            VoxelType::I32 => "int32",
            VoxelType::F32 => "float32",
            VoxelType::F64 => "float64",
        }
    }

    /// Parses a type name as used in raw file names and NRRD headers (`uint8`, `u8`, `uchar`,
    /// `unsigned char`, `short`, `int16`, `float`, …).
    pub fn parse(s: &str) -> Option<VoxelType> {
        let s = s.trim().to_ascii_lowercase();
        Some(match s.as_str() {
            "uint8" | "u8" | "uchar" | "unsigned char" | "uint8_t" => VoxelType::U8,
            "int8" | "i8" | "signed char" | "int8_t" => VoxelType::I8,
            "uint16" | "u16" | "ushort" | "unsigned short" | "unsigned short int" | "uint16_t" => VoxelType::U16,
            "int16" | "i16" | "short" | "short int" | "signed short" | "signed short int" | "int16_t" => VoxelType::I16,
            "uint32" | "u32" | "uint" | "unsigned int" | "uint32_t" => VoxelType::U32,
            "int32" | "i32" | "int" | "signed int" | "int32_t" => VoxelType::I32,
            "float32" | "f32" | "float" => VoxelType::F32,
            "float64" | "f64" | "double" => VoxelType::F64,
            _ => return None,
        })
    }
}

/// What went wrong while loading a volume.
#[derive(Debug)]
pub enum VolumeErrorKind {
    /// The file could not be opened or read.
    Io(std::io::Error),
    /// The raw file name does not carry `_XxYxZ_type` and no options supplied them.
    BadName(String),
    /// The file holds a different number of bytes than the dims and type need.
    SizeMismatch {
        /// Bytes the header or name implies.
        expected: u64,
        /// Bytes found.
        actual: u64,
    },
    /// The voxel type is not one of [`VoxelType`].
    UnknownType(String),
    /// The NRRD header is malformed.
    BadHeader(String),
    /// A valid header asks for something this loader does not do (e.g. bzip2 encoding).
    Unsupported(String),
    /// More voxels than [`LoadOptions::max_voxels`].
    TooLarge {
        /// Voxels the file declares.
        voxels: u64,
        /// The limit.
        limit: u64,
    },
    /// Gzip data that does not decompress.
    Decompress(String),
    /// A dimension or spacing is zero, negative or not finite.
    BadGeometry(String),
}

/// A loader error: the file (if known) and what is wrong with it.
#[derive(Debug)]
pub struct VolumeError {
    /// The file the error is about.
    pub path: Option<PathBuf>,
    /// What is wrong.
    pub kind: VolumeErrorKind,
}

impl VolumeError {
    /// An error without a path (yet).
    pub fn new(kind: VolumeErrorKind) -> Self {
        VolumeError { path: None, kind }
    }

    /// The same error about `path` (keeps an existing path).
    pub fn at(mut self, path: &Path) -> Self {
        if self.path.is_none() {
            self.path = Some(path.to_path_buf());
        }
        self
    }
}

impl fmt::Display for VolumeErrorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            VolumeErrorKind::Io(e) => write!(f, "cannot read: {e}"),
            VolumeErrorKind::BadName(s) => write!(f, "{s}"),
            VolumeErrorKind::SizeMismatch { expected, actual } => {
                write!(f, "size mismatch: expected {expected} bytes of voxel data, found {actual}")
            }
            VolumeErrorKind::UnknownType(t) => write!(f, "unknown voxel type {t:?}"),
            VolumeErrorKind::BadHeader(s) => write!(f, "bad NRRD header: {s}"),
            VolumeErrorKind::Unsupported(s) => write!(f, "unsupported: {s}"),
            VolumeErrorKind::TooLarge { voxels, limit } => {
                write!(f, "{voxels} voxels is over the limit of {limit}")
            }
            VolumeErrorKind::Decompress(s) => write!(f, "gzip data does not decompress: {s}"),
            VolumeErrorKind::BadGeometry(s) => write!(f, "{s}"),
        }
    }
}

impl fmt::Display for VolumeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.path {
            Some(p) => write!(f, "{}: {}", p.display(), self.kind),
            None => write!(f, "{}", self.kind),
        }
    }
}

impl std::error::Error for VolumeError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match &self.kind {
            VolumeErrorKind::Io(e) => Some(e),
            _ => None,
        }
    }
}

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

/// What a raw file name `name_XxYxZ_type.raw` says.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RawName {
    /// The `name` part.
    pub name: String,
    /// Dimensions (x, y, z).
    pub dims: [u32; 3],
    /// Voxel type.
    pub voxel_type: VoxelType,
}

/// Parses a raw file name `name_XxYxZ_type.raw` (directories and the extension are ignored).
/// Never panics.
pub fn parse_raw_name(file_name: &str) -> Result<RawName, VolumeError> {
    let base = file_name.rsplit(['/', '\\']).next().unwrap_or(file_name);
    let stem = base.strip_suffix(".raw").unwrap_or(base);
    let bad = |why: &str| {
        VolumeError::new(VolumeErrorKind::BadName(format!(
            "file name {base:?} is not name_XxYxZ_type.raw ({why}); pass --dims and --type"
        )))
    };
    let mut parts = stem.rsplitn(3, '_');
    let ty = parts.next().ok_or_else(|| bad("no type"))?;
    let dims_s = parts.next().ok_or_else(|| bad("no dimensions"))?;
    let name = parts.next().unwrap_or("volume").to_string();
    let voxel_type =
        VoxelType::parse(ty).ok_or_else(|| VolumeError::new(VolumeErrorKind::UnknownType(ty.to_string())))?;
    let dims = parse_dims(dims_s).ok_or_else(|| bad("dimensions are not XxYxZ positive integers"))?;
    Ok(RawName { name, dims, voxel_type })
}

/// Parses `XxYxZ` (positive integers).
pub fn parse_dims(s: &str) -> Option<[u32; 3]> {
    let mut it = s.split(['x', 'X']);
    let mut d = [0u32; 3];
    for v in d.iter_mut() {
        *v = it.next()?.trim().parse().ok().filter(|&v: &u32| v > 0)?;
    }
    if it.next().is_some() {
        return None;
    }
    Some(d)
}

/// A scalar volume, normalized to `0..=1` (see the module docs for its place in world space).
#[derive(Clone, Debug)]
pub struct Volume {
    /// A short name (file stem).
    pub name: String,
    dims: [u32; 3],
    spacing: Vec3,
    value_range: (f32, f32),
    data: Vec<f32>,
}

fn check_geometry(dims: [u32; 3], spacing: Vec3, max_voxels: u64) -> Result<u64, VolumeError> {
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
    let voxels = dims.iter().map(|&d| d as u64).product::<u64>();
    if voxels > max_voxels {
        return Err(VolumeError::new(VolumeErrorKind::TooLarge { voxels, limit: max_voxels }));
    }
    Ok(voxels)
}

impl Volume {
    /// A volume from values in x-fastest order (`dims` product long). Non-finite values become
    /// the data minimum; the values are normalized over their range.
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
        let scale = if hi > lo { 1.0 / (hi as f64 - lo as f64) } else { 0.0 };
        for v in values.iter_mut() {
            *v = if v.is_finite() { ((*v as f64 - lo as f64) * scale).clamp(0.0, 1.0) as f32 } else { 0.0 };
        }
        Ok(Volume { name: name.to_string(), dims, spacing, value_range: (lo, hi), data: values })
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
        &self.data
    }

    /// The normalized value of voxel `(i, j, k)` (clamped to the volume).
    #[inline]
    pub fn voxel(&self, i: u32, j: u32, k: u32) -> f32 {
        let [nx, ny, nz] = self.dims;
        let (i, j, k) = (i.min(nx - 1) as usize, j.min(ny - 1) as usize, k.min(nz - 1) as usize);
        self.data[i + nx as usize * (j + ny as usize * k)]
    }

    /// Trilinear sample at continuous voxel coordinates `g` (voxel centres at integers),
    /// clamped to the volume.
    #[inline(always)]
    pub fn sample_grid(&self, g: Vec3) -> f32 {
        let [nx, ny, nz] = self.dims;
        // Fast path: strictly inside the lattice of voxel centres, all eight neighbours exist.
        if g.x >= 0.0
            && g.y >= 0.0
            && g.z >= 0.0
            && g.x < (nx - 1) as f32
            && g.y < (ny - 1) as f32
            && g.z < (nz - 1) as f32
        {
            let (x0, y0, z0) = (g.x as u32 as usize, g.y as u32 as usize, g.z as u32 as usize);
            let (fx, fy, fz) = (g.x - x0 as f32, g.y - y0 as f32, g.z - z0 as f32);
            let sy = nx as usize;
            let sz = nx as usize * ny as usize;
            let base = x0 + sy * y0 + sz * z0;
            if let Some(c) = self.data.get(base..base + sz + sy + 2) {
                let corners = [c[0], c[1], c[sy], c[sy + 1], c[sz], c[sz + 1], c[sz + sy], c[sz + sy + 1]];
                return trilinear(corners, fx, fy, fz);
            }
        }
        self.sample_grid_clamped(g)
    }

    /// [`Volume::sample_grid`] without the fast path for points strictly inside the lattice of
    /// voxel centres (same arithmetic, so the same result; the reference in tests).
    #[inline]
    pub fn sample_grid_clamped(&self, g: Vec3) -> f32 {
        let [nx, ny, nz] = self.dims;
        let gx = g.x.max(0.0).min((nx - 1) as f32); // NaN -> 0
        let gy = g.y.max(0.0).min((ny - 1) as f32); // NaN -> 0
        let gz = g.z.max(0.0).min((nz - 1) as f32); // NaN -> 0
        let (x0, y0, z0) = (gx as usize, gy as usize, gz as usize);
        let (fx, fy, fz) = (gx - x0 as f32, gy - y0 as f32, gz - z0 as f32);
        let sx = usize::from(x0 + 1 < nx as usize);
        let sy = if y0 + 1 < ny as usize { nx as usize } else { 0 };
        let sz = if z0 + 1 < nz as usize { nx as usize * ny as usize } else { 0 };
        let base = x0 + nx as usize * (y0 + ny as usize * z0);
        let d = &self.data;
        let (Some(&c000), Some(&c100), Some(&c010), Some(&c110)) =
            (d.get(base), d.get(base + sx), d.get(base + sy), d.get(base + sy + sx))
        else {
            return 0.0;
        };
        let b2 = base + sz;
        let (Some(&c001), Some(&c101), Some(&c011), Some(&c111)) =
            (d.get(b2), d.get(b2 + sx), d.get(b2 + sy), d.get(b2 + sy + sx))
        else {
            return 0.0;
        };
        trilinear([c000, c100, c010, c110, c001, c101, c011, c111], fx, fy, fz)
    }

    /// Trilinear sample at world position `p`.
    #[inline]
    pub fn sample(&self, p: Vec3) -> f32 {
        self.sample_grid(p / self.spacing - 0.5)
    }
}

/// Trilinear blend of the corners `[c000, c100, c010, c110, c001, c101, c011, c111]` (x
/// fastest) at fractions `(fx, fy, fz)`: along x, then y, then z.
#[inline(always)]
fn trilinear(c: [f32; 8], fx: f32, fy: f32, fz: f32) -> f32 {
    let c00 = c[0] + (c[1] - c[0]) * fx;
    let c10 = c[2] + (c[3] - c[2]) * fx;
    let c01 = c[4] + (c[5] - c[4]) * fx;
    let c11 = c[6] + (c[7] - c[6]) * fx;
    let c0 = c00 + (c10 - c00) * fy;
    let c1 = c01 + (c11 - c01) * fy;
    c0 + (c1 - c0) * fz
}

/// Converts little- or big-endian voxel bytes to f32 (`bytes.len()` a multiple of the size).
pub fn decode_voxels(bytes: &[u8], ty: VoxelType, big_endian: bool) -> Vec<f32> {
    macro_rules! conv {
        ($t:ty, $n:expr) => {
            bytes
                .chunks_exact($n)
                .map(|c| {
                    let a: [u8; $n] = c.try_into().unwrap_or([0; $n]);
                    (if big_endian { <$t>::from_be_bytes(a) } else { <$t>::from_le_bytes(a) }) as f32
                })
                .collect()
        };
    }
    match ty {
        VoxelType::U8 => bytes.iter().map(|&b| b as f32).collect(),
        VoxelType::I8 => bytes.iter().map(|&b| b as i8 as f32).collect(),
        VoxelType::U16 => conv!(u16, 2),
        VoxelType::I16 => conv!(i16, 2),
        VoxelType::U32 => conv!(u32, 4),
        VoxelType::I32 => conv!(i32, 4),
        VoxelType::F32 => conv!(f32, 4),
        VoxelType::F64 => conv!(f64, 8),
    }
}

fn io_err(path: &Path, e: std::io::Error) -> VolumeError {
    VolumeError::new(VolumeErrorKind::Io(e)).at(path)
}

/// Reads exactly `expected` bytes from `r` (an error if it holds fewer or more).
pub(crate) fn read_exactly(mut r: impl Read, expected: u64, path: &Path) -> Result<Vec<u8>, VolumeError> {
    let mut buf = Vec::with_capacity(expected.min(1 << 32) as usize);
    r.by_ref().take(expected).read_to_end(&mut buf).map_err(|e| io_err(path, e))?;
    let mut extra = [0u8; 1];
    let more = r.read(&mut extra).map_err(|e| io_err(path, e))?;
    let actual = buf.len() as u64 + more as u64;
    if buf.len() as u64 != expected || more != 0 {
        return Err(VolumeError::new(VolumeErrorKind::SizeMismatch {
            expected,
            actual: if more != 0 { actual } else { buf.len() as u64 },
        })
        .at(path));
    }
    Ok(buf)
}

fn load_raw(path: &Path, opts: &LoadOptions) -> Result<Volume, VolumeError> {
    let file_name = path.file_name().and_then(|s| s.to_str()).unwrap_or("");
    let from_name = parse_raw_name(file_name);
    let (name, dims, ty) = match (&from_name, opts.dims, opts.voxel_type) {
        (_, Some(d), Some(t)) => (path.file_stem().and_then(|s| s.to_str()).unwrap_or("volume").to_string(), d, t),
        (Ok(n), d, t) => (n.name.clone(), d.unwrap_or(n.dims), t.unwrap_or(n.voxel_type)),
        (Err(_), _, _) => return Err(from_name.unwrap_err().at(path)),
    };
    let spacing = opts.spacing.unwrap_or(Vec3::ONE);
    let voxels = check_geometry(dims, spacing, opts.max_voxels).map_err(|e| e.at(path))?;
    let expected = voxels * ty.size() as u64;
    let meta = std::fs::metadata(path).map_err(|e| io_err(path, e))?;
    if meta.len() != expected {
        return Err(VolumeError::new(VolumeErrorKind::SizeMismatch { expected, actual: meta.len() }).at(path));
    }
    let file = std::fs::File::open(path).map_err(|e| io_err(path, e))?;
    let bytes = read_exactly(std::io::BufReader::new(file), expected, path)?;
    let values = decode_voxels(&bytes, ty, false);
    Volume::from_values(&name, dims, spacing, values).map_err(|e| e.at(path))
}

/// Loads a raw (`.raw` or any other extension) or NRRD (`.nrrd`, `.nhdr`) volume.
pub fn load_volume(path: impl AsRef<Path>, opts: &LoadOptions) -> Result<Volume, VolumeError> {
    let path = path.as_ref();
    let ext = path.extension().and_then(|s| s.to_str()).unwrap_or("").to_ascii_lowercase();
    let vol = match ext.as_str() {
        "nrrd" | "nhdr" => nrrd::load(path, opts)?,
        _ => load_raw(path, opts)?,
    };
    log::info!(
        "loaded {} : {}x{}x{} voxels, spacing {}, value range {:?}",
        path.display(),
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
    fn raw_names() {
        let n = parse_raw_name("data/mri_colin27_181x217x181_uint8.raw").unwrap();
        assert_eq!(n.name, "mri_colin27");
        assert_eq!(n.dims, [181, 217, 181]);
        assert_eq!(n.voxel_type, VoxelType::U8);
        assert_eq!(parse_raw_name("ct_64x64x93_int16.raw").unwrap().voxel_type, VoxelType::I16);
        assert_eq!(parse_raw_name("a_2x3x4_float32.raw").unwrap().voxel_type, VoxelType::F32);
        for bad in
            ["", "x.raw", "a_2x3_uint8.raw", "a_0x1x1_uint8.raw", "a_2x3x4x5_uint8.raw", "a_1x1x1_complex.raw", "_._"]
        {
            assert!(parse_raw_name(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn trilinear_between_centres_and_clamped_outside() {
        let v = Volume::from_values("t", [2, 1, 1], Vec3::ONE, vec![0.0, 10.0]).unwrap();
        assert_eq!(v.value_range(), (0.0, 10.0));
        assert_eq!(v.sample(Vec3::new(0.5, 0.5, 0.5)), 0.0);
        assert_eq!(v.sample(Vec3::new(1.0, 0.5, 0.5)), 0.5);
        assert_eq!(v.sample(Vec3::new(1.5, 0.5, 0.5)), 1.0);
        assert_eq!(v.sample(Vec3::new(2.0, 0.0, 0.0)), 1.0);
        assert_eq!(v.sample(Vec3::new(-5.0, 9.0, f32::NAN)), 0.0);
    }

    #[test]
    fn fast_path_equals_clamped_path() {
        let v = Volume::from_fn("t", [7, 5, 4], Vec3::new(1.0, 2.0, 0.5), |p| (p.x * 3.1 + p.y * p.z).sin()).unwrap();
        let mut x = 12345u32;
        let mut r = || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x as f32 / u32::MAX as f32
        };
        for _ in 0..20000 {
            let g = Vec3::new(r() * 8.0 - 0.5, r() * 6.0 - 0.5, r() * 5.0 - 0.5);
            assert_eq!(v.sample_grid(g).to_bits(), v.sample_grid_clamped(g).to_bits(), "{g}");
        }
        for g in [Vec3::ZERO, Vec3::new(6.0, 4.0, 3.0), Vec3::new(5.999, 3.999, 2.999), Vec3::new(0.0, 4.0, 1.5)] {
            assert_eq!(v.sample_grid(g).to_bits(), v.sample_grid_clamped(g).to_bits(), "{g}");
        }
    }

    #[test]
    fn marschner_lobb_is_in_range() {
        let v = Volume::marschner_lobb(16);
        assert_eq!(v.dims(), [16; 3]);
        assert!(v.data().iter().all(|x| (0.0..=1.0).contains(x)));
    }
}
