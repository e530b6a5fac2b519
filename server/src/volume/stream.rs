//! Streaming loads: voxel data read slab by slab straight into bricks ([`super::bricks`]) in
//! the file's own type, so a load takes the bricks and one slab of the file, never the whole
//! file again as `f32`. The raw and NRRD loaders (raw and gzip encodings) and the NIfTI loader
//! (volumes in LPS order or mirrored in x and y, unscaled) read through here.

use super::bricks::{GridBuilder, Stored, Voxels};
use super::{code_scale, Volume, VolumeError, VolumeErrorKind, VoxelType};
use std::io::Read;
use std::path::Path;
use std::time::Instant;
use volwarp_core::Vec3;

/// Bytes read per slab (at least one slice).
const SLAB_BYTES: usize = 8 << 20;

/// Volumes from this many bytes on log their progress.
const PROGRESS_BYTES: u64 = 256 << 20;

/// Bytes per stored value for voxels of `ty` (what [`stream_volume`] keeps).
pub(crate) fn stored_size(ty: VoxelType) -> u64 {
    match ty {
        VoxelType::U8 | VoxelType::I8 => 1,
        VoxelType::U16 | VoxelType::I16 => 2,
        _ => 4,
    }
}

/// What a stream reads.
pub(crate) struct StreamSpec<'a> {
    /// The volume's name.
    pub name: &'a str,
    /// Dimensions.
    pub dims: [u32; 3],
    /// Spacing.
    pub spacing: Vec3,
    /// The stored type.
    pub ty: VoxelType,
    /// Whether multi-byte values are big-endian.
    pub big_endian: bool,
    /// Mirror x and y (a NRRD's negative space directions; z is never streamed mirrored).
    pub flip_xy: [bool; 2],
    /// The file, for errors and progress lines.
    pub path: &'a Path,
}

/// Reads `spec.dims` voxels of `spec.ty` from `reader` (exactly: fewer or more bytes are a
/// [`VolumeErrorKind::SizeMismatch`]) into bricks.
pub(crate) fn stream_volume(spec: &StreamSpec<'_>, reader: impl Read) -> Result<Volume, VolumeError> {
    let mut sink = SliceSink::new(spec)?;
    for_each_slice(spec, reader, |bytes| sink.push(bytes))?;
    sink.finish()
}

/// The bricks being built from slices pushed in z order, in the file's own type (8- and 16-bit
/// values stored as read, signed ones offset to unsigned; other types as `f32`, normalized over
/// their finite range when finished): what every streaming loader feeds, whatever its slices
/// come from (a byte stream, TIFF pages, DICOM files).
pub(crate) struct SliceSink<'a> {
    spec: &'a StreamSpec<'a>,
    slices: u32,
    kind: SinkKind,
}

enum SinkKind {
    U8 { grid: GridBuilder<u8>, slice: Vec<u8>, lo: u32, hi: u32 },
    U16 { grid: GridBuilder<u16>, slice: Vec<u16>, lo: u32, hi: u32 },
    F32 { grid: GridBuilder<f32>, slice: Vec<f32>, lo: f32, hi: f32 },
}

impl<'a> SliceSink<'a> {
    /// A sink for the slices of `spec` (allocates the bricks).
    pub(crate) fn new(spec: &'a StreamSpec<'a>) -> Result<SliceSink<'a>, VolumeError> {
        let plane = spec.dims[0] as usize * spec.dims[1] as usize;
        let at = |e: VolumeError| e.at(spec.path);
        let kind = match spec.ty {
            VoxelType::U8 | VoxelType::I8 => SinkKind::U8 {
                grid: GridBuilder::new(spec.dims).map_err(at)?,
                slice: vec![0; plane],
                lo: u32::MAX,
                hi: 0,
            },
            VoxelType::U16 | VoxelType::I16 => SinkKind::U16 {
                grid: GridBuilder::new(spec.dims).map_err(at)?,
                slice: vec![0; plane],
                lo: u32::MAX,
                hi: 0,
            },
            _ => SinkKind::F32 {
                grid: GridBuilder::new(spec.dims).map_err(at)?,
                slice: Vec::with_capacity(plane),
                lo: f32::INFINITY,
                hi: f32::NEG_INFINITY,
            },
        };
        Ok(SliceSink { spec, slices: 0, kind })
    }

    /// Adds the next slice: `nx·ny` values of the spec's type as bytes in its byte order
    /// (slices past the last one are ignored).
    pub(crate) fn push(&mut self, bytes: &[u8]) {
        let spec = self.spec;
        if self.slices >= spec.dims[2] {
            return;
        }
        self.slices += 1;
        let be = spec.big_endian;
        let short =
            move |b: &[u8]| if be { u16::from_be_bytes([b[0], b[1]]) } else { u16::from_le_bytes([b[0], b[1]]) };
        let nx = spec.dims[0] as usize;
        match &mut self.kind {
            SinkKind::U8 { grid, slice, lo, hi } => {
                let flip = if spec.ty == VoxelType::I8 { 0x80 } else { 0 };
                slice.iter_mut().zip(bytes).for_each(|(o, &v)| *o = v ^ flip);
                add_slice(grid, slice, nx, spec.flip_xy, lo, hi);
            }
            SinkKind::U16 { grid, slice, lo, hi } => {
                let flip = if spec.ty == VoxelType::I16 { 0x8000 } else { 0 };
                slice.iter_mut().zip(bytes.chunks_exact(2)).for_each(|(o, v)| *o = short(v) ^ flip);
                add_slice(grid, slice, nx, spec.flip_xy, lo, hi);
            }
            SinkKind::F32 { grid, slice, lo, hi } => {
                slice.clear();
                slice.extend(super::decode_voxels(bytes, spec.ty, spec.big_endian));
                for &v in slice.iter().filter(|v| v.is_finite()) {
                    *lo = lo.min(v);
                    *hi = hi.max(v);
                }
                mirror(slice, nx, spec.flip_xy);
                grid.push_slice(slice);
            }
        }
    }

    /// The volume, once every slice is in (fewer slices are a
    /// [`VolumeErrorKind::SizeMismatch`]).
    pub(crate) fn finish(self) -> Result<Volume, VolumeError> {
        let spec = self.spec;
        let slice_bytes = spec.dims[0] as u64 * spec.dims[1] as u64 * spec.ty.size() as u64;
        if self.slices < spec.dims[2] {
            return Err(VolumeError::new(VolumeErrorKind::SizeMismatch {
                expected: slice_bytes * u64::from(spec.dims[2]),
                actual: slice_bytes * u64::from(self.slices),
            })
            .at(spec.path));
        }
        let at = |e: VolumeError| e.at(spec.path);
        let ints = |lo: u32, hi: u32, bias: f32| {
            let (lo, hi) = if lo > hi { (0.0, 0.0) } else { (lo as f32, hi as f32) };
            ((lo + bias, hi + bias), lo, code_scale(hi - lo))
        };
        let signed = matches!(spec.ty, VoxelType::I8 | VoxelType::I16);
        let (voxels, range, offset, scale) = match self.kind {
            SinkKind::U8 { grid, lo, hi, .. } => {
                let (range, offset, scale) = ints(lo, hi, if signed { -128.0 } else { 0.0 });
                (Voxels::U8(grid.finish().map_err(at)?), range, offset, scale)
            }
            SinkKind::U16 { grid, lo, hi, .. } => {
                let (range, offset, scale) = ints(lo, hi, if signed { -32_768.0 } else { 0.0 });
                (Voxels::U16(grid.finish().map_err(at)?), range, offset, scale)
            }
            SinkKind::F32 { grid, mut lo, mut hi, .. } => {
                let mut grid = grid.finish().map_err(at)?;
                if lo > hi {
                    (lo, hi) = (0.0, 0.0);
                }
                let inv_range = if hi > lo { 1.0 / (hi as f64 - lo as f64) } else { 0.0 };
                grid.map_in_place(|v| {
                    if v.is_finite() {
                        ((v as f64 - lo as f64) * inv_range).clamp(0.0, 1.0) as f32
                    } else {
                        0.0
                    }
                });
                (Voxels::F32(grid), (lo, hi), 0.0, 1.0)
            }
        };
        Ok(Volume::from_voxels(spec.name, spec.spacing, voxels, range, offset, scale))
    }
}

/// Adds an 8- or 16-bit slice to `grid`, widening `lo..=hi` to its values.
fn add_slice<T: Stored + Ord + Into<u32>>(
    grid: &mut GridBuilder<T>,
    slice: &mut [T],
    nx: usize,
    flip: [bool; 2],
    lo: &mut u32,
    hi: &mut u32,
) {
    if let Some((l, h)) = min_max(slice) {
        *lo = (*lo).min(l.into());
        *hi = (*hi).max(h.into());
    }
    mirror(slice, nx, flip);
    grid.push_slice(slice);
}

/// Reads the slices of `spec` from `reader` (each `nx·ny·size` bytes) and hands each to `f`
/// with its index; an error where the data holds fewer or more bytes.
fn for_each_slice(spec: &StreamSpec<'_>, mut reader: impl Read, mut f: impl FnMut(&[u8])) -> Result<(), VolumeError> {
    let [nx, ny, nz] = spec.dims;
    let slice_bytes = nx as usize * ny as usize * spec.ty.size();
    let per_slab = (SLAB_BYTES / slice_bytes.max(1)).clamp(1, nz as usize);
    let total = slice_bytes as u64 * u64::from(nz);
    let mut buf = vec![0u8; per_slab * slice_bytes];
    let (start, mut next_report) = (Instant::now(), total / 10);
    let mut done = 0u64;
    let mut z = 0usize;
    while z < nz as usize {
        let n = per_slab.min(nz as usize - z);
        let part = &mut buf[..n * slice_bytes];
        let mut got = 0;
        while got < part.len() {
            match reader.read(&mut part[got..]) {
                Ok(0) => break,
                Ok(k) => got += k,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(VolumeError::io(spec.path, e)),
            }
        }
        if got < part.len() {
            return Err(VolumeError::new(VolumeErrorKind::SizeMismatch { expected: total, actual: done + got as u64 })
                .at(spec.path));
        }
        for s in part.chunks_exact(slice_bytes) {
            f(s);
        }
        z += n;
        done += part.len() as u64;
        if total >= PROGRESS_BYTES && done >= next_report {
            let secs = start.elapsed().as_secs_f64().max(1e-9);
            log::info!(
                "loading {}: {:.0} % ({} of {} MiB, {:.0} MB/s)",
                spec.path.display(),
                done as f64 * 100.0 / total as f64,
                done >> 20,
                total >> 20,
                done as f64 / secs / 1e6
            );
            next_report += total / 10;
        }
    }
    let mut extra = [0u8; 1];
    let more = loop {
        match reader.read(&mut extra) {
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            r => break r.map_err(|e| VolumeError::io(spec.path, e))?,
        }
    };
    if more != 0 {
        return Err(
            VolumeError::new(VolumeErrorKind::SizeMismatch { expected: total, actual: total + 1 }).at(spec.path)
        );
    }
    Ok(())
}

/// Mirrors a slice of `nx × ny` values in x and/or y in place.
fn mirror<T>(slice: &mut [T], nx: usize, flip: [bool; 2]) {
    if flip[0] {
        slice.chunks_exact_mut(nx).for_each(|row| row.reverse());
    }
    if flip[1] {
        let ny = slice.len() / nx.max(1);
        for y in 0..ny / 2 {
            let (a, b) = slice.split_at_mut((ny - 1 - y) * nx);
            a[y * nx..(y + 1) * nx].swap_with_slice(&mut b[..nx]);
        }
    }
}

/// The least and the greatest of `s` (`None` if empty), over 32 independent lanes so that the
/// compiler vectorizes it (`Iterator::min` keeps a scalar chain).
fn min_max<T: Copy + PartialOrd>(s: &[T]) -> Option<(T, T)> {
    let first = *s.first()?;
    let (mut lo, mut hi) = ([first; 32], [first; 32]);
    let mut chunks = s.chunks_exact(32);
    for c in &mut chunks {
        for i in 0..32 {
            lo[i] = if c[i] < lo[i] { c[i] } else { lo[i] };
            hi[i] = if c[i] > hi[i] { c[i] } else { hi[i] };
        }
    }
    let pick = |a: T, b: T, less: bool| if (b < a) == less { b } else { a };
    let l = chunks.remainder().iter().chain(&lo).fold(first, |m, &v| pick(m, v, true));
    let h = chunks.remainder().iter().chain(&hi).fold(first, |m, &v| pick(m, v, false));
    Some((l, h))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn streamed_volumes_equal_in_memory_ones() {
        let dims = [33, 5, 34];
        let n = dims.iter().product::<u32>() as usize;
        for ty in [VoxelType::U8, VoxelType::I8, VoxelType::U16, VoxelType::I16, VoxelType::F32, VoxelType::I32] {
            for big_endian in [false, true] {
                let bytes: Vec<u8> = (0..n * ty.size()).map(|i| (i * 7919 % 251) as u8).collect();
                let values = super::super::decode_voxels(&bytes, ty, big_endian);
                let want = Volume::from_values("m", dims, Vec3::ONE, values).unwrap();
                let p = Path::new("mem");
                let spec =
                    StreamSpec { name: "s", dims, spacing: Vec3::ONE, ty, big_endian, flip_xy: [false; 2], path: p };
                let got = stream_volume(&spec, &bytes[..]).unwrap();
                assert_eq!(got.value_range(), want.value_range(), "{ty:?}");
                assert_eq!(got.values(), want.values(), "{ty:?} {big_endian}");
                // Short and long data are size mismatches.
                let e = stream_volume(&spec, &bytes[..bytes.len() - 1]).unwrap_err();
                assert!(matches!(e.kind, VolumeErrorKind::SizeMismatch { .. }), "{e}");
                let mut long = bytes.clone();
                long.push(0);
                assert!(matches!(
                    stream_volume(&spec, &long[..]).unwrap_err().kind,
                    VolumeErrorKind::SizeMismatch { .. }
                ));
            }
        }
    }

    #[test]
    fn min_max_over_lanes_equals_the_plain_fold() {
        for n in [0usize, 1, 31, 32, 33, 100, 1000] {
            let v: Vec<u16> = (0..n).map(|i| (i * 7919 % 1009) as u16).collect();
            assert_eq!(min_max(&v), v.iter().min().zip(v.iter().max()).map(|(&a, &b)| (a, b)), "{n}");
        }
    }

    #[test]
    fn mirrors_rows_and_columns() {
        let mut s: Vec<u8> = (0..6).collect();
        mirror(&mut s, 3, [true, false]);
        assert_eq!(s, [2, 1, 0, 5, 4, 3]);
        mirror(&mut s, 3, [false, true]);
        assert_eq!(s, [5, 4, 3, 2, 1, 0]);
    }
}
