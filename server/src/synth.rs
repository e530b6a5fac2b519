//! Synthetic volumes of any size: a deterministic procedural scalar field written as a raw file
//! the loaders open by name (`synth_XxYxZ_uint8.raw`, `synth_XxYxZ_uint16.raw`), for trying
//! volumes of 1024³ or 2048³ voxels without a download.
//!
//! **Content.** Defined over normalized coordinates, so it looks alike at every size. Each
//! axis maps the voxel centre `(i + ½) / n` to `q ∈ [-1, 1]` inside a margin of 8 % of the axis
//! on either side; the margin, and everything outside the ball `|q| ≤ 1`, is exactly 0. Inside
//! that ball:
//!
//! - a semi-transparent fog of middle values (about 0.2 to 0.47 of full scale) varying smoothly,
//!   filling the ball of radius 0.86;
//! - an outer shell at radius 0.92 (full scale), perforated by the holes of a gyroid;
//! - a gyroid band (0.70) filling the ball of radius 0.62;
//! - three small balls: shells at 0.95, interiors at 0.58;
//! - a cutaway wedge (`q.x > 0`, `q.z > 0.3`) without fog or outer shell, where the band and a
//!   ball show;
//! - the features (all but the fog) are plateaus of their value with short edges, so that a
//!   transfer function can tell them apart by value;
//! - low-level noise from a hash of `(i, j, k)`: ±0.015 on the features, 0 to 0.025 elsewhere in
//!   the ball (below any opacity of the `synth` transfer-function preset, so empty for
//!   empty-space skipping).
//!
//! Values are quantized to the type's full scale (255 or 65,535). Every voxel is a pure function
//! of `(i, j, k, dims, type)` ([`synth_value`]) computed with IEEE arithmetic only (no `libm`
//! calls, no random-number state), so the bytes are the same on every platform and any range
//! of voxels can be produced on its own ([`synth_fill`], [`synth_slice`]).
//!
//! **Writing.** [`write_synth`] streams the file in slabs of at most [`SLAB_BYTES`] (whole
//! z-slices where a slice fits), so its memory is bounded whatever the volume's size; each slab
//! is filled in parallel with rayon. It logs its progress every 10 % for volumes of 64 MiB or
//! more.

use crate::volume::VoxelType;
use rayon::prelude::*;
use std::fmt;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The voxel types of synthetic volumes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SynthType {
    /// Unsigned 8-bit (full scale 255).
    U8,
    /// Unsigned 16-bit, little-endian (full scale 65,535).
    U16,
}

impl SynthType {
    /// Parses any spelling [`VoxelType::parse`] accepts for `uint8` or `uint16` (`u8`,
    /// `uint8`, `uchar`, `u16`, `ushort`, …).
    pub fn parse(s: &str) -> Option<SynthType> {
        match VoxelType::parse(s)? {
            VoxelType::U8 => Some(SynthType::U8),
            VoxelType::U16 => Some(SynthType::U16),
            _ => None,
        }
    }

    /// The loaders' voxel type.
    pub fn voxel_type(self) -> VoxelType {
        match self {
            SynthType::U8 => VoxelType::U8,
            SynthType::U16 => VoxelType::U16,
        }
    }

    /// Bytes per voxel.
    pub fn size(self) -> usize {
        self.voxel_type().size()
    }

    /// The full-scale value (what the normalized value 1 becomes).
    pub fn full_scale(self) -> u16 {
        match self {
            SynthType::U8 => u8::MAX as u16,
            SynthType::U16 => u16::MAX,
        }
    }
}

/// Most bytes of one slab [`write_synth`] fills and writes at a time (whole z-slices where a
/// slice fits, else part of one).
pub const SLAB_BYTES: usize = 32 << 20;

/// Voxels one rayon task fills.
const PIECE_VOXELS: usize = 1 << 14;

/// Longest row whose x axes [`synth_fill`] computes once (longer rows compute them per voxel).
const MAX_X_TABLE: u64 = 1 << 16;

/// Why a synthetic volume could not be written.
#[derive(Debug)]
pub enum SynthError {
    /// Dimensions with a zero, or whose bytes do not fit in 64 bits.
    Dims(String),
    /// The output folder is missing or not a folder.
    OutDir {
        /// The folder.
        path: PathBuf,
        /// What is wrong with it.
        why: String,
    },
    /// Creating, writing or renaming the file failed.
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
}

impl fmt::Display for SynthError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SynthError::Dims(why) => write!(f, "synthetic volume: {why}"),
            SynthError::OutDir { path, why } => write!(f, "output folder {}: {why}", path.display()),
            SynthError::Io { path, source } => write!(f, "{}: {source}", path.display()),
        }
    }
}

impl std::error::Error for SynthError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            SynthError::Io { source, .. } => Some(source),
            _ => None,
        }
    }
}

/// The file name of a synthetic volume: `synth_XxYxZ_uint8.raw` or `synth_XxYxZ_uint16.raw`
/// (the raw naming convention, so the loaders need no `--dims` or `--type`).
pub fn synth_file_name(dims: [u32; 3], ty: SynthType) -> String {
    format!("synth_{}x{}x{}_{}.raw", dims[0], dims[1], dims[2], ty.voxel_type().name())
}

/// The bytes of a synthetic volume; an error for a zero dimension or more than 2⁶⁴ bytes.
pub fn synth_bytes(dims: [u32; 3], ty: SynthType) -> Result<u64, SynthError> {
    if dims.contains(&0) {
        return Err(SynthError::Dims(format!("dimensions {}x{}x{} contain a zero", dims[0], dims[1], dims[2])));
    }
    dims.iter().try_fold(ty.size() as u64, |n, &d| n.checked_mul(u64::from(d))).ok_or_else(|| {
        SynthError::Dims(format!("{}x{}x{} voxels of {} bytes overflow 64 bits", dims[0], dims[1], dims[2], ty.size()))
    })
}

// ---- the field --------------------------------------------------------------------------------

/// Margin (fraction of each axis, on either side) left at 0.
const MARGIN: f64 = 0.08;
/// Gyroid frequencies (periods per unit of `q`) of the shell's holes and of the band; the
/// fog's slow variation.
const F_HOLES: f32 = 2.2;
const F_BAND: f32 = 1.4;
const F_FOG: f32 = 0.6;
/// Radii (in `q`) of the fog, the outer shell and the band's ball; half-width of the shell.
const R_FOG: f32 = 0.86;
const R_SHELL: f32 = 0.92;
const W_SHELL: f32 = 0.035;
const R_BAND: f32 = 0.62;
/// Half-width of the band, in gyroid units (its gradient is about 9 per unit of `q`).
const W_BAND: f32 = 0.25;
/// The small balls: centres and radius (in `q`), shell half-width.
const BALLS: [[f32; 3]; 3] = [[0.42, 0.30, 0.42], [-0.45, 0.40, -0.20], [0.05, -0.50, -0.35]];
const R_BALL: f32 = 0.17;
const W_BALL: f32 = 0.03;
/// Width (in `q`) of the edges of the features' plateaus: short against their thickness, so
/// that a feature's value is mostly its own and the transitions between values are thin.
const EDGE: f32 = 0.01;

/// A periodic wave of period 1 close to `sin(2πt)` (within 0.001), in basic IEEE arithmetic
/// only, so it gives the same bits everywhere.
#[inline(always)]
fn wave(t: f32) -> f32 {
    let x = t - (t + 0.5).floor(); // [-0.5, 0.5)
    let y = 8.0 * x * (1.0 - 2.0 * x.abs());
    0.225 * (y * y.abs() - y) + y
}

/// 0 below 0, 1 above 1, smooth between.
#[inline(always)]
fn smoothstep(t: f32) -> f32 {
    let s = t.clamp(0.0, 1.0);
    s * s * (3.0 - 2.0 * s)
}

/// What the field needs of one axis coordinate: `q` and the waves of its gyroids.
#[derive(Clone, Copy)]
struct Axis {
    q: f32,
    /// In the margin.
    outside: bool,
    /// sin- and cos-like waves at the holes', the band's and the fog's frequencies.
    s_holes: f32,
    c_holes: f32,
    s_band: f32,
    c_band: f32,
    s_fog: f32,
    c_fog: f32,
}

#[inline(always)]
fn axis(i: u64, n: u32) -> Axis {
    let u = (i as f64 + 0.5) / f64::from(n);
    let q = ((u - 0.5) / (0.5 - MARGIN)) as f32;
    let w = |f: f32| (wave(q * f), wave(q * f + 0.25));
    let ((s_holes, c_holes), (s_band, c_band), (s_fog, c_fog)) = (w(F_HOLES), w(F_BAND), w(F_FOG));
    Axis { q, outside: q.abs() > 1.0, s_holes, c_holes, s_band, c_band, s_fog, c_fog }
}

/// A hash of a voxel's indices in `[0, 1)`.
#[inline(always)]
fn noise(i: u64, j: u64, k: u64) -> f32 {
    let mut h = i.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ j.wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ k.wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^= h >> 33;
    h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
    h ^= h >> 33;
    h = h.wrapping_mul(0xC4CE_B9FE_1A85_EC53);
    h ^= h >> 33;
    (h >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
}

/// The normalized value in `[0, 1]` of the voxel with axes `x`, `y`, `z` and noise `h`.
#[inline(always)]
fn field(x: &Axis, y: &Axis, z: &Axis, h: f32) -> f32 {
    if x.outside || y.outside || z.outside {
        return 0.0;
    }
    let r2 = x.q * x.q + y.q * y.q + z.q * z.q;
    if r2 > 1.0 {
        return 0.0;
    }
    let r = r2.sqrt();
    let cut = x.q > 0.0 && z.q > 0.3;
    let mut v = 0.0f32;
    if !cut && r < R_FOG {
        // Fog: smooth middle values, denser towards the centre, fading out at its radius.
        let g = (x.s_fog * y.c_fog + y.s_fog * z.c_fog + z.s_fog * x.c_fog) * (1.0 / 1.5);
        let fog = 0.30 + 0.09 * g + 0.08 * (1.0 - r);
        v = fog * smoothstep((R_FOG - r) * (1.0 / 0.04));
    }
    let d = (r - R_SHELL).abs();
    if !cut && d < W_SHELL {
        // The outer shell at full scale, with the holes of a gyroid.
        let g = x.s_holes * y.c_holes + y.s_holes * z.c_holes + z.s_holes * x.c_holes;
        let shell = smoothstep((W_SHELL - d) * (1.0 / EDGE)) * (1.0 - smoothstep((g - 0.45) * 10.0));
        v = v.max(shell);
    }
    if r < R_BAND {
        let g = x.s_band * y.c_band + y.s_band * z.c_band + z.s_band * x.c_band;
        let band = 0.70 * smoothstep((W_BAND - g.abs()) * (1.0 / 0.08)) * smoothstep((R_BAND - r) * (1.0 / EDGE));
        v = v.max(band);
    }
    for c in BALLS {
        let (dx, dy, dz) = (x.q - c[0], y.q - c[1], z.q - c[2]);
        let d2 = dx * dx + dy * dy + dz * dz;
        if d2 < (R_BALL + W_BALL) * (R_BALL + W_BALL) {
            let d = d2.sqrt();
            let inside = 0.58 * smoothstep((R_BALL - d) * (1.0 / EDGE));
            let shell = 0.95 * smoothstep((W_BALL - (d - R_BALL).abs()) * (1.0 / EDGE));
            v = v.max(inside).max(shell);
        }
    }
    let v = if v > 0.0 { v + (h - 0.5) * 0.03 } else { h * 0.025 };
    v.clamp(0.0, 1.0)
}

#[inline(always)]
fn quantize(v: f32, ty: SynthType) -> u16 {
    let full = f32::from(ty.full_scale());
    (v * full + 0.5).min(full) as u16
}

/// The value of voxel `(i, j, k)` of a synthetic volume of `dims` and type `ty` (at most
/// [`SynthType::full_scale`]). Indices past `dims` continue the field (into the margin, 0).
pub fn synth_value(i: u32, j: u32, k: u32, dims: [u32; 3], ty: SynthType) -> u16 {
    let (i, j, k) = (u64::from(i), u64::from(j), u64::from(k));
    let v = field(&axis(i, dims[0]), &axis(j, dims[1]), &axis(k, dims[2]), noise(i, j, k));
    quantize(v, ty)
}

/// Fills `out` with the voxels of a synthetic volume from the voxel of linear index `first`
/// (x fastest, then y, then z) on, in the file's bytes (little-endian), in parallel.
///
/// # Panics
/// If a dimension is 0, `out.len()` is not a multiple of the voxel size, or the voxels run past
/// the volume's end.
pub fn synth_fill(dims: [u32; 3], ty: SynthType, first: u64, out: &mut [u8]) {
    let size = ty.size();
    assert!(!dims.contains(&0), "dimensions {dims:?} contain a zero");
    assert!(out.len().is_multiple_of(size), "{} bytes are no whole number of {size}-byte voxels", out.len());
    let total = dims.iter().map(|&d| u128::from(d)).product::<u128>();
    assert!(
        u128::from(first) + (out.len() / size) as u128 <= total,
        "voxels {first}.. ({} of them) run past the volume's {total}",
        out.len() / size
    );
    let (nx, ny) = (u64::from(dims[0]), u64::from(dims[1]));
    // The x axes of a row, computed once (the same values `axis` gives per voxel).
    let xs: Vec<Axis> = if nx <= MAX_X_TABLE { (0..nx).map(|i| axis(i, dims[0])).collect() } else { Vec::new() };
    let x_axis = |i: u64| xs.get(i as usize).copied().unwrap_or_else(|| axis(i, dims[0]));
    out.par_chunks_mut(PIECE_VOXELS * size).enumerate().for_each(|(p, piece)| {
        let start = first + (p * PIECE_VOXELS) as u64;
        let (mut i, row) = (start % nx, start / nx);
        let (mut j, mut k) = (row % ny, row / ny);
        let (mut ay, mut az) = (axis(j, dims[1]), axis(k, dims[2]));
        for voxel in piece.chunks_exact_mut(size) {
            let v = quantize(field(&x_axis(i), &ay, &az, noise(i, j, k)), ty);
            match ty {
                SynthType::U8 => voxel[0] = v as u8,
                SynthType::U16 => voxel.copy_from_slice(&v.to_le_bytes()),
            }
            i += 1;
            if i == nx {
                i = 0;
                j += 1;
                if j == ny {
                    j = 0;
                    k += 1;
                    az = axis(k, dims[2]);
                }
                ay = axis(j, dims[1]);
            }
        }
    });
}

/// Fills `out` (`X·Y` voxels, `X·Y·size` bytes) with z-slice `k` of a synthetic volume: the
/// same bytes as that slice of the file [`write_synth`] writes.
///
/// # Panics
/// If `out` is not one slice long or `k` is not below `dims[2]`.
pub fn synth_slice(dims: [u32; 3], ty: SynthType, k: u32, out: &mut [u8]) {
    let slice = u64::from(dims[0]) * u64::from(dims[1]);
    assert_eq!(out.len() as u64, slice * ty.size() as u64, "a slice of {dims:?} {ty:?} voxels");
    assert!(k < dims[2], "slice {k} of {}", dims[2]);
    synth_fill(dims, ty, u64::from(k) * slice, out);
}

/// Writes the synthetic volume of `dims` and `ty` into the folder `out_dir` as
/// [`synth_file_name`] and returns its path. Streams slabs of at most [`SLAB_BYTES`] (whole
/// z-slices where a slice fits) through a buffered writer, filling each in parallel; the file
/// appears under its name only once complete (it is written as `NAME.part` and renamed).
///
/// Errors: a zero dimension or a size past 64 bits, a missing or non-folder `out_dir`, and any
/// failure to create, write or rename the file (the partial file is removed).
pub fn write_synth(dims: [u32; 3], ty: SynthType, out_dir: &Path) -> Result<PathBuf, SynthError> {
    write_in_slabs(dims, ty, out_dir, SLAB_BYTES as u64)
}

/// [`write_synth`] with slabs of at most `slab` bytes (rounded down to whole voxels).
fn write_in_slabs(dims: [u32; 3], ty: SynthType, out_dir: &Path, slab: u64) -> Result<PathBuf, SynthError> {
    let total = synth_bytes(dims, ty)?;
    match std::fs::metadata(out_dir) {
        Ok(m) if m.is_dir() => {}
        Ok(_) => return Err(SynthError::OutDir { path: out_dir.into(), why: "not a folder".into() }),
        Err(e) => return Err(SynthError::OutDir { path: out_dir.into(), why: e.to_string() }),
    }
    let size = ty.size() as u64;
    let slice_bytes = u64::from(dims[0]) * u64::from(dims[1]) * size;
    // Whole slices where they fit.
    let slab = (slab / size * size).max(size);
    let slab_bytes = if slice_bytes >= slab { slab } else { slab / slice_bytes * slice_bytes }.min(total) as usize;
    let path = out_dir.join(synth_file_name(dims, ty));
    let part = out_dir.join(format!("{}.part", synth_file_name(dims, ty)));
    let io = |p: &Path| {
        let p = p.to_path_buf();
        move |source| SynthError::Io { path: p, source }
    };
    let file = std::fs::File::create(&part).map_err(io(&part))?;
    let result = (|| {
        let mut w = std::io::BufWriter::with_capacity(1 << 20, file);
        let mut buf = vec![0u8; slab_bytes];
        let (t0, mut written, mut next_report) = (Instant::now(), 0u64, 1u64);
        let report = total >= 64 << 20;
        log::info!("writing {} ({} bytes)", path.display(), total);
        while written < total {
            let n = (total - written).min(slab_bytes as u64) as usize;
            synth_fill(dims, ty, written / size, &mut buf[..n]);
            w.write_all(&buf[..n]).map_err(io(&part))?;
            written += n as u64;
            if report && u128::from(written) * 10 >= u128::from(next_report) * u128::from(total) {
                let s = t0.elapsed().as_secs_f64();
                log::info!(
                    "{}%: {written} of {total} bytes, {:.0} MB/s",
                    u128::from(written) * 100 / u128::from(total),
                    written as f64 / 1e6 / s.max(1e-9)
                );
                next_report = (u128::from(written) * 10 / u128::from(total)) as u64 + 1;
            }
        }
        w.flush().map_err(io(&part))?;
        drop(w);
        std::fs::rename(&part, &path).map_err(io(&path))?;
        let s = t0.elapsed().as_secs_f64();
        log::info!(
            "wrote {}: {total} bytes in {s:.2} s ({:.0} MB/s)",
            path.display(),
            total as f64 / 1e6 / s.max(1e-9)
        );
        Ok(path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&part);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wave_is_close_to_a_sine_and_periodic() {
        for n in -400..=400 {
            let t = n as f32 / 100.0;
            let s = (t * std::f32::consts::TAU).sin();
            assert!((wave(t) - s).abs() < 2e-3, "{t}: {} vs {s}", wave(t));
        }
    }

    #[test]
    fn names_sizes_and_types() {
        assert_eq!(synth_file_name([1024, 2, 3], SynthType::U16), "synth_1024x2x3_uint16.raw");
        let n = crate::volume::parse_raw_name(&synth_file_name([5, 6, 7], SynthType::U8)).unwrap();
        assert_eq!((n.name.as_str(), n.dims, n.voxel_type), ("synth", [5, 6, 7], VoxelType::U8));
        assert_eq!(synth_bytes([2, 3, 4], SynthType::U16).unwrap(), 48);
        assert!(synth_bytes([0, 3, 4], SynthType::U8).is_err());
        assert!(synth_bytes([u32::MAX; 3], SynthType::U16).is_err());
        assert_eq!(SynthType::parse("u8"), Some(SynthType::U8));
        assert_eq!(SynthType::parse("uint16"), Some(SynthType::U16));
        assert_eq!(SynthType::parse("float32"), None);
    }

    #[test]
    fn slabs_of_any_size_write_the_same_file() {
        let dir = std::env::temp_dir().join(format!("volwarp-synth-slabs-{}", std::process::id()));
        let dims = [13, 7, 5];
        for ty in [SynthType::U8, SynthType::U16] {
            let mut files = Vec::new();
            for slab in [1, 2, 30, 91 * 2, 1000, SLAB_BYTES as u64] {
                let d = dir.join(format!("{slab}"));
                std::fs::create_dir_all(&d).unwrap();
                files.push(std::fs::read(write_in_slabs(dims, ty, &d, slab).unwrap()).unwrap());
            }
            assert_eq!(files[0].len(), 13 * 7 * 5 * ty.size());
            assert!(files.iter().all(|f| *f == files[0]), "{ty:?}");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn fill_from_any_voxel_matches_single_voxels() {
        let dims = [7, 5, 9];
        let mut buf = vec![0u8; 2 * 100];
        synth_fill(dims, SynthType::U16, 123, &mut buf);
        for (n, b) in buf.chunks_exact(2).enumerate() {
            let l = 123 + n as u32;
            let (i, j, k) = (l % 7, l / 7 % 5, l / 35);
            assert_eq!(u16::from_le_bytes([b[0], b[1]]), synth_value(i, j, k, dims, SynthType::U16));
        }
    }
}
