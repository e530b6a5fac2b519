//! Streaming loads: voxel data read slab by slab straight into bricks ([`super::bricks`]) in
//! the file's own type, so a load takes the bricks and one slab of the file, never the whole
//! file again as `f32`. The raw and NRRD loaders (raw and gzip encodings) and the NIfTI loader
//! (volumes in LPS order or mirrored in x and y, unscaled) read through here.

use super::bricks::{Grid, GridBuilder, Stored, Voxels};
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
    let be = spec.big_endian;
    let short = move |b: &[u8]| if be { u16::from_be_bytes([b[0], b[1]]) } else { u16::from_le_bytes([b[0], b[1]]) };
    match spec.ty {
        VoxelType::U8 => stream_ints::<u8>(spec, reader, |b, out| out.copy_from_slice(b), Voxels::U8, 0.0),
        VoxelType::I8 => stream_ints::<u8>(
            spec,
            reader,
            |b, out| out.iter_mut().zip(b).for_each(|(o, &v)| *o = v ^ 0x80),
            Voxels::U8,
            -128.0,
        ),
        VoxelType::U16 => stream_ints::<u16>(
            spec,
            reader,
            |b, out: &mut [u16]| out.iter_mut().zip(b.chunks_exact(2)).for_each(|(o, v)| *o = short(v)),
            Voxels::U16,
            0.0,
        ),
        VoxelType::I16 => stream_ints::<u16>(
            spec,
            reader,
            |b, out: &mut [u16]| out.iter_mut().zip(b.chunks_exact(2)).for_each(|(o, v)| *o = short(v) ^ 0x8000),
            Voxels::U16,
            -32_768.0,
        ),
        _ => stream_floats(spec, reader),
    }
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

/// 8- and 16-bit values: stored as read (`decode` gives the stored values of a slice's bytes:
/// signed ones offset to unsigned, `wrap` the [`Voxels`] of their grid); `bias` is the source
/// value of stored 0.
fn stream_ints<T: Stored + Ord + Into<u32>>(
    spec: &StreamSpec<'_>,
    reader: impl Read,
    decode: impl Fn(&[u8], &mut [T]),
    wrap: fn(Grid<T>) -> Voxels,
    bias: f32,
) -> Result<Volume, VolumeError> {
    let [nx, ny, _] = spec.dims;
    let mut builder = GridBuilder::<T>::new(spec.dims).map_err(|e| e.at(spec.path))?;
    let mut slice = vec![T::default(); nx as usize * ny as usize];
    let (mut lo, mut hi) = (u32::MAX, 0u32);
    for_each_slice(spec, reader, |bytes| {
        decode(bytes, &mut slice);
        if let Some((l, h)) = min_max(&slice) {
            lo = lo.min(l.into());
            hi = hi.max(h.into());
        }
        mirror(&mut slice, nx as usize, spec.flip_xy);
        builder.push_slice(&slice);
    })?;
    let grid = builder.finish().map_err(|e| e.at(spec.path))?;
    let voxels = wrap(grid);
    let (lo, hi) = (lo as f32, hi as f32);
    Ok(Volume::from_voxels(spec.name, spec.spacing, voxels, (lo + bias, hi + bias), lo, code_scale(hi - lo)))
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

/// Other types: read as `f32` (as the loaders always converted them), then normalized over
/// their finite range in place (non-finite values become 0, the minimum).
fn stream_floats(spec: &StreamSpec<'_>, reader: impl Read) -> Result<Volume, VolumeError> {
    let [nx, ny, _] = spec.dims;
    let mut builder = GridBuilder::<f32>::new(spec.dims).map_err(|e| e.at(spec.path))?;
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    let mut slice = Vec::with_capacity(nx as usize * ny as usize);
    for_each_slice(spec, reader, |bytes| {
        slice.clear();
        slice.extend(super::decode_voxels(bytes, spec.ty, spec.big_endian));
        for &v in slice.iter().filter(|v| v.is_finite()) {
            lo = lo.min(v);
            hi = hi.max(v);
        }
        mirror(&mut slice, nx as usize, spec.flip_xy);
        builder.push_slice(&slice);
    })?;
    let mut grid = builder.finish().map_err(|e| e.at(spec.path))?;
    if lo > hi {
        (lo, hi) = (0.0, 0.0);
    }
    let inv_range = if hi > lo { 1.0 / (hi as f64 - lo as f64) } else { 0.0 };
    grid.map_in_place(
        |v| if v.is_finite() { ((v as f64 - lo as f64) * inv_range).clamp(0.0, 1.0) as f32 } else { 0.0 },
    );
    Ok(Volume::from_voxels(spec.name, spec.spacing, Voxels::F32(grid), (lo, hi), 0.0, 1.0))
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
