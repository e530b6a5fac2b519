//! TIFF stacks: one multi-page TIFF (a page per slice) or a folder of single-page TIFF slices,
//! as microscopes, micro-CT scanners and ImageJ/Fiji write them.
//!
//! **What is read.** Grayscale pages of 8 or 16 bits (signed or unsigned; 32-bit integer and
//! float pages too), uncompressed, LZW or deflate; every page the same width and height (else
//! an error naming the odd slice: `slice 17 is 512×500, the others 512×512`). A folder's slices
//! are its `.tif`/`.tiff` files in natural name order (`s2` before `s10`); where every name
//! carries a number, a gap in the numbering is an error (a missing slice). Slice `k` is
//! `z = k`, row 0 is `y = 0`: the stored order. TIFF carries no slice spacing: the spacing is
//! 1, 1, 1 unless [`LoadOptions::spacing`] says otherwise.

use super::stream::{stored_size, SliceSink, StreamSpec};
use super::{check_load, voxel_bytes, LoadOptions, SourceInfo, Volume, VolumeError, VoxelType};
use std::path::{Path, PathBuf};
use tiff::decoder::{Decoder, DecodingResult, Limits};
use tiff::ColorType;
use volwarp_core::Vec3;

const FORMAT: &str = "TIFF";

/// True where `head` starts with a TIFF or BigTIFF magic.
pub fn is_tiff(head: &[u8]) -> bool {
    head.starts_with(b"II*\0") || head.starts_with(b"MM\0*") || head.starts_with(b"II+\0") || head.starts_with(b"MM\0+")
}

/// Compares names in natural order: runs of digits by value, the rest by characters.
pub fn natural_cmp(a: &str, b: &str) -> std::cmp::Ordering {
    fn runs(s: &str) -> Vec<(bool, &str)> {
        let mut out = Vec::new();
        let mut start = 0;
        let b = s.as_bytes();
        for i in 1..=b.len() {
            if i == b.len() || b[i].is_ascii_digit() != b[start].is_ascii_digit() {
                out.push((b[start].is_ascii_digit(), &s[start..i]));
                start = i;
            }
        }
        out
    }
    let (ra, rb) = (runs(a), runs(b));
    for (x, y) in ra.iter().zip(&rb) {
        let o = match (x.0, y.0) {
            (true, true) => {
                let (tx, ty) = (x.1.trim_start_matches('0'), y.1.trim_start_matches('0'));
                tx.len().cmp(&ty.len()).then_with(|| tx.cmp(ty)).then_with(|| x.1.len().cmp(&y.1.len()))
            }
            _ => x.1.cmp(y.1),
        };
        if o.is_ne() {
            return o;
        }
    }
    ra.len().cmp(&rb.len())
}

/// The TIFF files of a folder (`.tif`/`.tiff`, else any file with a TIFF magic), in natural
/// name order; hidden files are skipped.
pub fn folder_slices(dir: &Path) -> Result<Vec<PathBuf>, VolumeError> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| VolumeError::io(dir, e))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_file() && !p.file_name().and_then(|n| n.to_str()).unwrap_or(".").starts_with('.'))
        .collect();
    let tif = |p: &PathBuf| {
        p.extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| e.eq_ignore_ascii_case("tif") || e.eq_ignore_ascii_case("tiff"))
    };
    if files.iter().any(tif) {
        files.retain(tif);
    } else {
        files.retain(|p| super::read_head(p, 4).is_ok_and(|h| is_tiff(&h)));
    }
    files.sort_by(|a, b| natural_cmp(&a.to_string_lossy(), &b.to_string_lossy()));
    Ok(files)
}

fn tiff_err(path: &Path, what: &str, e: tiff::TiffError) -> VolumeError {
    match e {
        tiff::TiffError::IoError(e) => VolumeError::io(path, e),
        tiff::TiffError::UnsupportedError(u) => VolumeError::unsupported(format!("TIFF {what}: {u}")).at(path),
        e => VolumeError::malformed(FORMAT, format!("{what}: {e}")).at(path),
    }
}

fn open(path: &Path, max_voxels: u64) -> Result<Page, VolumeError> {
    let f = std::fs::File::open(path).map_err(|e| VolumeError::io(path, e))?;
    let mut limits = Limits::default();
    // One page as f64 at most: the voxel limit bounds every decode buffer.
    limits.decoding_buffer_size = usize::try_from(max_voxels.saturating_mul(8)).unwrap_or(usize::MAX);
    Ok(Decoder::new(std::io::BufReader::new(f)).map_err(|e| tiff_err(path, "header", e))?.with_limits(limits))
}

/// The stored bytes per voxel of a page's colour type (before decoding it), for the memory check.
fn page_stored_bytes(path: &Path, what: &str, d: &mut Page) -> Result<u64, VolumeError> {
    Ok(match d.colortype().map_err(|e| tiff_err(path, what, e))? {
        ColorType::Gray(8) => 1,
        ColorType::Gray(16) => 2,
        _ => 4,
    })
}

/// Decodes the current page of `d` into `buf` (reused between pages; native byte order) and
/// returns its voxel type.
fn decode_page(path: &Path, what: &str, d: &mut Page, buf: &mut DecodingResult) -> Result<VoxelType, VolumeError> {
    match d.colortype().map_err(|e| tiff_err(path, what, e))? {
        ColorType::Gray(_) => {}
        other => {
            return Err(
                VolumeError::unsupported(format!("TIFF {what} is {other:?}: only grayscale pages are read")).at(path)
            )
        }
    }
    d.read_image_to_buffer(buf).map_err(|e| tiff_err(path, what, e))?;
    Ok(match buf {
        DecodingResult::U8(_) => VoxelType::U8,
        DecodingResult::I8(_) => VoxelType::I8,
        DecodingResult::U16(_) => VoxelType::U16,
        DecodingResult::I16(_) => VoxelType::I16,
        DecodingResult::U32(_) => VoxelType::U32,
        DecodingResult::I32(_) => VoxelType::I32,
        DecodingResult::F32(_) => VoxelType::F32,
        DecodingResult::F64(_) => VoxelType::F64,
        _ => {
            return Err(
                VolumeError::unsupported(format!("TIFF {what}: 64-bit integer or 16-bit float samples")).at(path)
            )
        }
    })
}

/// A TIFF decoder over a file.
type Page = Decoder<std::io::BufReader<std::fs::File>>;

/// Streams `dims[2]` pages into bricks: `page(k, buf)` decodes page `k` into `buf` and returns
/// its type and its label and file for errors. Every page must hold the first page's type.
fn stream_pages(
    name: &str,
    path: &Path,
    dims: [u32; 3],
    opts: &LoadOptions,
    files: usize,
    mut page: impl FnMut(usize, &mut DecodingResult) -> Result<(VoxelType, String, PathBuf), VolumeError>,
) -> Result<Volume, VolumeError> {
    let spacing = opts.spacing.unwrap_or(Vec3::ONE);
    let mut buf = DecodingResult::U8(Vec::new());
    let (ty, first, _) = page(0, &mut buf)?;
    let voxels = check_load(dims, spacing, opts, stored_size(ty), 0).map_err(|e| e.at(path))?;
    // The decoder's values are in this machine's byte order.
    let big_endian = cfg!(target_endian = "big");
    let spec = StreamSpec { name, dims, spacing, ty, big_endian, flip_xy: [false; 2], path };
    let mut sink = SliceSink::new(&spec)?;
    sink.push(buf.as_buffer(0).as_bytes());
    for k in 1..dims[2] as usize {
        let (t, what, file) = page(k, &mut buf)?;
        if t != ty {
            return Err(VolumeError::malformed(FORMAT, format!("{what} holds {t:?} samples, {first} {ty:?}")).at(&file));
        }
        sink.push(buf.as_buffer(0).as_bytes());
    }
    let source = SourceInfo {
        format: "TIFF".into(),
        voxel_type: Some(ty),
        orientation: "none (slice k is z = k, row 0 is y = 0)".into(),
        data_bytes: voxel_bytes(voxels, ty).map_err(|e| e.at(path))?,
        files,
    };
    Ok(sink.finish()?.with_source(source))
}

/// The most common page size, or the first page of another size and an error naming it and
/// both sizes.
fn check_sizes(sizes: &[(u32, u32)], label: impl Fn(usize) -> String) -> Result<(u32, u32), (usize, VolumeError)> {
    let mut counts: Vec<((u32, u32), usize)> = Vec::new();
    for &s in sizes {
        match counts.iter_mut().find(|c| c.0 == s) {
            Some(c) => c.1 += 1,
            None => counts.push((s, 1)),
        }
    }
    let (common, n_common) = counts.iter().copied().max_by_key(|c| c.1).unwrap_or(((0, 0), 0));
    match sizes.iter().position(|&s| s != common) {
        None => Ok(common),
        Some(odd) => {
            let (w, h) = sizes[odd];
            let others = if sizes.len() - n_common == 1 { "the others" } else { "most" };
            let msg = format!(
                "{} is {w}×{h}, {others} {}×{}: every slice must be the same size",
                label(odd),
                common.0,
                common.1
            );
            Err((odd, VolumeError::malformed(FORMAT, msg)))
        }
    }
}

/// Loads a multi-page TIFF file (a single page is a volume one slice deep).
pub fn load_file(path: &Path, opts: &LoadOptions) -> Result<Volume, VolumeError> {
    // First the page sizes (directories only), then the pixels.
    let mut d = open(path, opts.max_voxels)?;
    let mut sizes = Vec::new();
    loop {
        let what = format!("page {}", sizes.len() + 1);
        sizes.push(d.dimensions().map_err(|e| tiff_err(path, &what, e))?);
        if sizes.len() as u64 > opts.max_voxels {
            return Err(VolumeError::new(super::VolumeErrorKind::TooLarge {
                voxels: sizes.len() as u64,
                limit: opts.max_voxels,
            })
            .at(path));
        }
        if !d.more_images() {
            break;
        }
        d.next_image().map_err(|e| tiff_err(path, &what, e))?;
    }
    let (w, h) = check_sizes(&sizes, |i| format!("page {}", i + 1)).map_err(|(_, e)| e.at(path))?;
    let dims = [w, h, sizes.len() as u32];
    let mut d = open(path, opts.max_voxels)?;
    let stored = page_stored_bytes(path, "page 1", &mut d)?;
    check_load(dims, opts.spacing.unwrap_or(Vec3::ONE), opts, stored, 0).map_err(|e| e.at(path))?;
    let name = path.file_stem().and_then(|s| s.to_str()).unwrap_or("volume");
    stream_pages(name, path, dims, opts, 1, |k, buf| {
        let what = format!("page {}", k + 1);
        if k > 0 {
            d.next_image().map_err(|e| tiff_err(path, &what, e))?;
        }
        Ok((decode_page(path, &what, &mut d, buf)?, what, path.to_path_buf()))
    })
}

/// The trailing number of a file stem (`slice_017` → 17).
fn slice_number(p: &Path) -> Option<u64> {
    let stem = p.file_stem()?.to_str()?;
    let digits: String = stem.chars().rev().take_while(|c| c.is_ascii_digit()).collect();
    digits.chars().rev().collect::<String>().parse().ok()
}

/// Loads a folder of single-page TIFF slices ([`folder_slices`]).
pub fn load_folder(dir: &Path, opts: &LoadOptions) -> Result<Volume, VolumeError> {
    let files = folder_slices(dir)?;
    if files.is_empty() {
        return Err(VolumeError::malformed(FORMAT, "the folder holds no TIFF files").at(dir));
    }
    load_files(dir, &files, opts)
}

/// Loads single-page TIFF slices in the given order (`dir` names the stack in errors).
pub fn load_files(dir: &Path, files: &[PathBuf], opts: &LoadOptions) -> Result<Volume, VolumeError> {
    // A gap in the slices' numbering is a missing slice.
    let numbers: Option<Vec<u64>> = files.iter().map(|p| slice_number(p)).collect();
    if let Some(n) = numbers.filter(|n| n.len() > 2) {
        let step = n[1].wrapping_sub(n[0]);
        if let Some(i) = (1..n.len()).find(|&i| n[i].wrapping_sub(n[i - 1]) != step) {
            return Err(VolumeError::malformed(
                FORMAT,
                format!(
                    "slice numbers step by {step} but {} follows {} ({} after {}): a slice is missing or extra",
                    n[i],
                    n[i - 1],
                    files[i].file_name().unwrap_or_default().to_string_lossy(),
                    files[i - 1].file_name().unwrap_or_default().to_string_lossy()
                ),
            )
            .at(dir));
        }
    }
    if files.len() as u64 > opts.max_voxels {
        return Err(VolumeError::new(super::VolumeErrorKind::TooLarge {
            voxels: files.len() as u64,
            limit: opts.max_voxels,
        })
        .at(dir));
    }
    let mut sizes = Vec::with_capacity(files.len());
    for (k, f) in files.iter().enumerate() {
        let mut d = open(f, opts.max_voxels)?;
        sizes.push(d.dimensions().map_err(|e| tiff_err(f, &format!("slice {}", k + 1), e))?);
    }
    let label = |i: usize| format!("slice {} ({})", i + 1, files[i].file_name().unwrap_or_default().to_string_lossy());
    let (w, h) = check_sizes(&sizes, label).map_err(|(odd, e)| e.at(&files[odd]))?;
    let dims = [w, h, files.len() as u32];
    let stored = page_stored_bytes(&files[0], "slice 1", &mut open(&files[0], opts.max_voxels)?)?;
    check_load(dims, opts.spacing.unwrap_or(Vec3::ONE), opts, stored, 0).map_err(|e| e.at(dir))?;
    let name = dir.file_name().and_then(|s| s.to_str()).unwrap_or("volume");
    stream_pages(name, dir, dims, opts, files.len(), |k, buf| {
        let (what, f) = (format!("slice {}", k + 1), &files[k]);
        let mut d = open(f, opts.max_voxels)?;
        Ok((decode_page(f, &what, &mut d, buf)?, what, f.clone()))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn natural_order() {
        let mut v = vec!["s10.tif", "s2.tif", "s1.tif", "s01.tif", "a.tif", "s100.tif"];
        v.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(v, ["a.tif", "s1.tif", "s01.tif", "s2.tif", "s10.tif", "s100.tif"]);
        assert_eq!(slice_number(Path::new("x/slice_017.tif")), Some(17));
        assert_eq!(slice_number(Path::new("x/slice.tif")), None);
    }
}
