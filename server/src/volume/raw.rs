//! Headerless raw files: [`VoxelType`], the `name_XxYxZ_type.raw` naming convention, voxel
//! decoding (shared with the NRRD loader) and the raw loader.

use super::stream::{stream_volume, StreamSpec};
use super::{check_load, LoadOptions, Volume, VolumeError, VolumeErrorKind};
use std::io::Read;
use std::path::Path;
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

pub(super) fn load_raw(path: &Path, opts: &LoadOptions) -> Result<Volume, VolumeError> {
    let file_name = path.file_name().and_then(|s| s.to_str()).unwrap_or("");
    let from_name = parse_raw_name(file_name);
    let (name, dims, ty) = match (&from_name, opts.dims, opts.voxel_type) {
        (_, Some(d), Some(t)) => (path.file_stem().and_then(|s| s.to_str()).unwrap_or("volume").to_string(), d, t),
        (Ok(n), d, t) => (n.name.clone(), d.unwrap_or(n.dims), t.unwrap_or(n.voxel_type)),
        (Err(_), _, _) => return Err(from_name.unwrap_err().at(path)),
    };
    let spacing = opts.spacing.unwrap_or(Vec3::ONE);
    let voxels = check_load(dims, spacing, opts, super::stream::stored_size(ty), 0).map_err(|e| e.at(path))?;
    let expected = super::voxel_bytes(voxels, ty).map_err(|e| e.at(path))?;
    let meta = std::fs::metadata(path).map_err(|e| io_err(path, e))?;
    if meta.len() != expected {
        return Err(VolumeError::new(VolumeErrorKind::SizeMismatch { expected, actual: meta.len() }).at(path));
    }
    let file = std::fs::File::open(path).map_err(|e| io_err(path, e))?;
    let spec = StreamSpec { name: &name, dims, spacing, ty, big_endian: false, flip_xy: [false; 2], path };
    let source = super::SourceInfo { voxel_type: Some(ty), ..Default::default() };
    Ok(stream_volume(&spec, file)?.with_source(source))
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
}
