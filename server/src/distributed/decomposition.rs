//! The volume split across ranks: a k-d tree over the voxel box, each part with a one-voxel
//! apron for trilinear sampling, and each rank's part read from the file alone.
//!
//! **Ownership.** A part owns the continuous voxel coordinates `u = p / spacing` in
//! `[lo, hi)` per axis (the outermost parts extend to ±∞, so every sample of the global ray
//! grid belongs to exactly one part). A trilinear sample at `u` reads voxels `⌊u − ½⌋` and the
//! next one, so the part's voxels are `[lo − 1, hi + 1)` clamped to the volume (its apron).
//! Sampled in its own coordinates (`g − (lo − 1)`, an exact float subtraction of an integer)
//! a part gives the whole volume's bits: the same corners, the same fractions, the same
//! clamping at the volume's faces.
//!
//! **The split.** The box of `n` parts is cut across its longest axis into `⌊n/2⌋` and
//! `⌈n/2⌉` parts, at the voxel in proportion, rounded to a brick boundary
//! ([`BRICK_EDGE`] voxels) where that leaves both sides non-empty. A k-d tree gives one
//! visibility order of its leaves for every ray from one eye ([`Decomposition::order`]).

use crate::volume::bricks::{grid_from_values, Voxels, BRICK_EDGE};
use crate::volume::{LoadOptions, Volume, VolumeError, VolumeErrorKind, VoxelType};
use std::path::Path;
use volwarp_core::Vec3;

/// One part of the volume: the voxels it owns and the ones it holds (owned plus apron).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Part {
    /// First owned voxel per axis.
    pub lo: [u32; 3],
    /// One past the last owned voxel per axis.
    pub hi: [u32; 3],
    /// First held voxel (`lo − 1`, clamped to 0).
    pub held_lo: [u32; 3],
    /// One past the last held voxel (`hi + 1`, clamped to the volume).
    pub held_hi: [u32; 3],
}

impl Part {
    fn new(lo: [u32; 3], hi: [u32; 3], dims: [u32; 3]) -> Part {
        Part { lo, hi, held_lo: lo.map(|v| v.saturating_sub(1)), held_hi: [0, 1, 2].map(|a| (hi[a] + 1).min(dims[a])) }
    }

    /// Dimensions of the held block.
    pub fn held_dims(&self) -> [u32; 3] {
        [0, 1, 2].map(|a| self.held_hi[a] - self.held_lo[a])
    }

    /// Voxels owned.
    pub fn owned_voxels(&self) -> u64 {
        (0..3).map(|a| u64::from(self.hi[a] - self.lo[a])).product()
    }
}

/// A node of the k-d tree.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Node {
    /// Part index.
    Leaf(usize),
    /// Split across `axis` at voxel `at`: children below and above (node indices).
    Split { axis: usize, at: u32, below: usize, above: usize },
}

/// A k-d decomposition of a volume's voxel box into parts.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Decomposition {
    /// The volume's dimensions.
    pub dims: [u32; 3],
    /// The parts, in the tree's leaf order (rank `r` marches part `r`).
    pub parts: Vec<Part>,
    nodes: Vec<Node>,
}

impl Decomposition {
    /// Splits `dims` into `n` parts (see the module docs). An error where `n` is 0 or larger
    /// than the volume's bricks (a part must hold at least one brick's worth of work).
    pub fn new(dims: [u32; 3], n: usize) -> Result<Decomposition, String> {
        if n == 0 || dims.contains(&0) {
            return Err(format!("cannot split {dims:?} into {n} parts"));
        }
        let bricks: u64 = dims.iter().map(|&d| u64::from(d.div_ceil(BRICK_EDGE))).product();
        if n as u64 > bricks {
            return Err(format!(
                "{n} ranks for a {}x{}x{} volume of {bricks} bricks ({BRICK_EDGE}^3): launch at most {bricks} ranks",
                dims[0], dims[1], dims[2]
            ));
        }
        let mut d = Decomposition { dims, parts: Vec::new(), nodes: Vec::new() };
        d.build([0; 3], dims, n)?;
        Ok(d)
    }

    fn build(&mut self, lo: [u32; 3], hi: [u32; 3], n: usize) -> Result<usize, String> {
        let id = self.nodes.len();
        if n == 1 {
            self.nodes.push(Node::Leaf(self.parts.len()));
            self.parts.push(Part::new(lo, hi, self.dims));
            return Ok(id);
        }
        let ext = [0, 1, 2].map(|a| hi[a] - lo[a]);
        let axis = (0..3).max_by_key(|&a| (ext[a], 3 - a)).unwrap_or(0);
        if ext[axis] < 2 {
            return Err(format!("cannot split a {ext:?} box into {n} parts"));
        }
        let nb = n / 2;
        let exact = lo[axis] as u64 + ext[axis] as u64 * nb as u64 / n as u64;
        let rounded = ((exact + BRICK_EDGE as u64 / 2) / BRICK_EDGE as u64) * BRICK_EDGE as u64;
        let at = if rounded > lo[axis] as u64 && rounded < hi[axis] as u64 { rounded } else { exact };
        let at = (at as u32).clamp(lo[axis] + 1, hi[axis] - 1);
        self.nodes.push(Node::Leaf(usize::MAX));
        let mut bhi = hi;
        bhi[axis] = at;
        let mut alo = lo;
        alo[axis] = at;
        let below = self.build(lo, bhi, nb)?;
        let above = self.build(alo, hi, n - nb)?;
        self.nodes[id] = Node::Split { axis, at, below, above };
        Ok(id)
    }

    /// The parts front to back for every ray from `eye_voxels` (the eye in continuous voxel
    /// coordinates `p / spacing`): at each split the side holding the eye first.
    pub fn order(&self, eye_voxels: Vec3) -> Vec<usize> {
        let mut out = Vec::with_capacity(self.parts.len());
        let mut stack = vec![0usize];
        while let Some(n) = stack.pop() {
            match self.nodes[n] {
                Node::Leaf(p) => out.push(p),
                Node::Split { axis, at, below, above } => {
                    let (near, far) = if eye_voxels[axis] < at as f32 { (below, above) } else { (above, below) };
                    stack.push(far);
                    stack.push(near);
                }
            }
        }
        out
    }

    /// Whether grid position `g` (voxel centres at integers) lies in part `p`'s owned box
    /// (continuous voxel coordinates `u = g + ½` in `[lo, hi)`, the outermost faces open to ±∞).
    /// Compared on the grid position `g = u − ½` itself (`lo − ½` is exact in `f32`), so a
    /// trilinear sample of an owned position never reads past the part's apron.
    #[inline]
    pub fn owns(&self, p: usize, g: Vec3) -> bool {
        let part = &self.parts[p];
        (0..3).all(|a| {
            (part.lo[a] == 0 || g[a] >= part.lo[a] as f32 - 0.5)
                && (part.hi[a] == self.dims[a] || g[a] < part.hi[a] as f32 - 0.5)
        })
    }
}

/// A part's stored values as read, before the volume-wide normalization is known.
#[derive(Clone, Debug)]
pub struct PartData {
    /// The volume's name.
    pub name: String,
    /// The whole volume's dims.
    pub dims: [u32; 3],
    /// Spacing.
    pub spacing: Vec3,
    /// The part.
    pub part: Part,
    values: PartValues,
    /// Least and greatest stored value over the owned voxels (source units for floats).
    pub range: (f32, f32),
    /// Source value of stored 0 (8- and 16-bit codes).
    bias: f32,
    /// The values are source values to be stored as codes `v − min` (what
    /// [`Volume::from_values`] does: a NRRD the loader reorders whole), not as read.
    codes_from_min: bool,
    /// The source range of values already normalized (a volume in memory, [`part_of`]).
    source_range: Option<(f32, f32)>,
}

#[derive(Clone, Debug)]
enum PartValues {
    U8(Vec<u8>),
    U16(Vec<u16>),
    F32(Vec<f32>),
}

/// The range of several parts' [`PartData::range`] (what an all-reduce gives every rank).
pub fn combine_ranges(ranges: impl IntoIterator<Item = (f32, f32)>) -> (f32, f32) {
    ranges.into_iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), (a, b)| (l.min(a), h.max(b)))
}

impl PartData {
    /// The part as a volume of its held voxels, normalized over the whole volume's stored
    /// range `range` ([`combine_ranges`] of every part's): stored exactly as the whole volume's
    /// loader stores them, so samples come out with the same bits.
    pub fn into_volume(self, range: (f32, f32)) -> Result<Volume, VolumeError> {
        let dims = self.part.held_dims();
        let (lo, hi) = if range.0 > range.1 { (0.0, 0.0) } else { range };
        let (voxels, value_range, offset, scale) = match self.values {
            PartValues::U8(v) => {
                (Voxels::U8(grid_from_values(dims, &v)?), (lo + self.bias, hi + self.bias), lo, code(hi - lo))
            }
            PartValues::U16(v) => {
                (Voxels::U16(grid_from_values(dims, &v)?), (lo + self.bias, hi + self.bias), lo, code(hi - lo))
            }
            PartValues::F32(v) if self.codes_from_min && v.iter().all(|x| x.fract() == 0.0) && hi - lo <= 65_535.0 => {
                let scale = code(hi - lo);
                if hi - lo <= 255.0 {
                    let c: Vec<u8> = v.iter().map(|&x| (x - lo) as u8).collect();
                    (Voxels::U8(grid_from_values(dims, &c)?), (lo, hi), 0.0, scale)
                } else {
                    let c: Vec<u16> = v.iter().map(|&x| (x - lo) as u16).collect();
                    (Voxels::U16(grid_from_values(dims, &c)?), (lo, hi), 0.0, scale)
                }
            }
            PartValues::F32(mut v) => {
                let inv = if hi > lo { 1.0 / (hi as f64 - lo as f64) } else { 0.0 };
                for x in v.iter_mut() {
                    *x = if x.is_finite() { ((*x as f64 - lo as f64) * inv).clamp(0.0, 1.0) as f32 } else { 0.0 };
                }
                (Voxels::F32(grid_from_values(dims, &v)?), self.source_range.unwrap_or((lo, hi)), 0.0, 1.0)
            }
        };
        Ok(Volume::from_voxels(&self.name, self.spacing, voxels, value_range, offset, scale))
    }

    /// Bytes the part's values take.
    pub fn bytes(&self) -> u64 {
        match &self.values {
            PartValues::U8(v) => v.len() as u64,
            PartValues::U16(v) => 2 * v.len() as u64,
            PartValues::F32(v) => 4 * v.len() as u64,
        }
    }
}

fn code(range: f32) -> f32 {
    crate::volume::code_scale(range)
}

/// Where a file's voxels lie: a raw byte layout a part can be read from by ranges.
struct RawLayout {
    path: std::path::PathBuf,
    offset: u64,
    ty: VoxelType,
    big_endian: bool,
    name: String,
    dims: [u32; 3],
    spacing: Vec3,
    /// Axes stored mirrored (a NRRD's negative space directions): volume voxel `v` is file
    /// voxel `n − 1 − v` along them.
    flip: [bool; 3],
    /// The whole-volume loader stores this file's values as codes over their minimum (a NRRD
    /// mirrored in z, which it decodes whole).
    codes_from_min: bool,
}

fn io_err(path: &Path, e: std::io::Error) -> VolumeError {
    VolumeError::new(VolumeErrorKind::Io(e)).at(path)
}

/// The byte layout of a raw file or a NRRD with raw data (axes possibly mirrored); `None` for
/// anything else (gzip, permuted axes, other formats).
fn raw_layout(path: &Path, opts: &LoadOptions) -> Result<Option<RawLayout>, VolumeError> {
    use crate::volume::{detect_format, Format};
    match detect_format(path)? {
        Format::Raw => {
            let file_name = path.file_name().and_then(|s| s.to_str()).unwrap_or("");
            let (name, dims, ty) = match (crate::volume::parse_raw_name(file_name), opts.dims, opts.voxel_type) {
                (_, Some(d), Some(t)) => {
                    (path.file_stem().and_then(|s| s.to_str()).unwrap_or("volume").to_string(), d, t)
                }
                (Ok(n), d, t) => (n.name.clone(), d.unwrap_or(n.dims), t.unwrap_or(n.voxel_type)),
                (Err(e), _, _) => return Err(e.at(path)),
            };
            let spacing = opts.spacing.unwrap_or(Vec3::ONE);
            Ok(Some(RawLayout {
                path: path.to_path_buf(),
                offset: 0,
                ty,
                big_endian: false,
                name,
                dims,
                spacing,
                flip: [false; 3],
                codes_from_min: false,
            }))
        }
        Format::Nrrd => {
            use std::io::Read;
            let mut head = Vec::new();
            let f = std::fs::File::open(path).map_err(|e| io_err(path, e))?;
            f.take(1 << 16).read_to_end(&mut head).map_err(|e| io_err(path, e))?;
            let h = crate::volume::nrrd::parse_header(&head).map_err(|e| e.at(path))?;
            if h.encoding != crate::volume::nrrd::Encoding::Raw
                || h.perm != [0, 1, 2]
                || opts.dims.is_some()
                || h.byte_skip < 0
            {
                return Ok(None);
            }
            let (data, offset) = match &h.data_file {
                Some(f) => (path.parent().unwrap_or(Path::new(".")).join(f), h.byte_skip as u64),
                None => (path.to_path_buf(), h.data_offset as u64 + h.byte_skip as u64),
            };
            let name = path.file_stem().and_then(|s| s.to_str()).unwrap_or("volume").to_string();
            let ty = opts.voxel_type.unwrap_or(h.voxel_type);
            let spacing = opts.spacing.or(h.spacing).unwrap_or(Vec3::ONE);
            Ok(Some(RawLayout {
                path: data,
                offset,
                ty,
                big_endian: h.big_endian,
                name,
                dims: h.dims,
                spacing,
                flip: h.flip,
                codes_from_min: h.flip[2],
            }))
        }
        _ => Ok(None),
    }
}

/// The dims of the volume at `path` as [`read_part`] sees them (without reading its voxels
/// where the format allows).
pub fn volume_dims(path: &Path, opts: &LoadOptions) -> Result<[u32; 3], VolumeError> {
    match raw_layout(path, opts)? {
        Some(l) => Ok(l.dims),
        None => Ok(crate::volume::load_volume(path, opts)?.dims()),
    }
}

/// Reads part `p` of `decomposition` from the volume at `path`. Raw files and NRRD files with
/// raw data (axes mirrored or not, not permuted) are read by byte ranges (one read per row of the held block; the
/// memory check counts the held block only); other files (gzip, reoriented NRRD, other
/// formats) are loaded whole and the part copied out.
pub fn read_part(
    path: &Path,
    opts: &LoadOptions,
    decomposition: &Decomposition,
    p: usize,
) -> Result<PartData, VolumeError> {
    let part = decomposition.parts[p];
    let hd = part.held_dims();
    let held: u64 = hd.iter().map(|&d| u64::from(d)).product();
    if let Some(l) = raw_layout(path, opts)? {
        if l.dims != decomposition.dims {
            return Err(VolumeError::new(VolumeErrorKind::BadGeometry(format!(
                "the file holds {:?} voxels, the decomposition was made for {:?}",
                l.dims, decomposition.dims
            )))
            .at(path));
        }
        crate::volume::check_geometry(l.dims, l.spacing, opts.max_voxels).map_err(|e| e.at(path))?;
        let stored = match l.ty.size() {
            1 => 1,
            2 => 2,
            _ => 4,
        };
        opts.memory.check(held * stored + held * l.ty.size() as u64)?;
        let size = l.ty.size() as u64;
        let total: u64 = l.dims.iter().map(|&d| u64::from(d)).product::<u64>() * size;
        let file = std::fs::File::open(&l.path).map_err(|e| io_err(&l.path, e))?;
        let len = file.metadata().map_err(|e| io_err(&l.path, e))?.len();
        if len < l.offset + total {
            return Err(
                VolumeError::new(VolumeErrorKind::SizeMismatch { expected: l.offset + total, actual: len }).at(&l.path)
            );
        }
        let [nx, ny, _] = l.dims.map(u64::from);
        let row = u64::from(hd[0]) * size;
        let mut bytes = vec![0u8; (held * size) as usize];
        {
            use std::os::unix::fs::FileExt;
            let mut at = 0usize;
            let file_of = |a: usize, v: u32| if l.flip[a] { l.dims[a] - 1 - v } else { v };
            // The file's first x of the held row (its last where x is mirrored).
            let x0 = if l.flip[0] { l.dims[0] - part.held_hi[0] } else { part.held_lo[0] };
            for z in part.held_lo[2]..part.held_hi[2] {
                for y in part.held_lo[1]..part.held_hi[1] {
                    let (fz, fy) = (u64::from(file_of(2, z)), u64::from(file_of(1, y)));
                    let off = l.offset + ((fz * ny + fy) * nx + u64::from(x0)) * size;
                    let dst = &mut bytes[at..at + row as usize];
                    file.read_exact_at(dst, off).map_err(|e| io_err(&l.path, e))?;
                    if l.flip[0] {
                        // Reverse the row's values (each `size` bytes).
                        let n = dst.len() / size as usize;
                        for i in 0..n / 2 {
                            let (a, b) = (i * size as usize, (n - 1 - i) * size as usize);
                            for k in 0..size as usize {
                                dst.swap(a + k, b + k);
                            }
                        }
                    }
                    at += row as usize;
                }
            }
        }
        let owned = |i: usize| {
            let x = i as u32 % hd[0] + part.held_lo[0];
            let y = (i as u32 / hd[0]) % hd[1] + part.held_lo[1];
            let z = i as u32 / (hd[0] * hd[1]) + part.held_lo[2];
            (0..3).all(|a| [x, y, z][a] >= part.lo[a] && [x, y, z][a] < part.hi[a])
        };
        let be = l.big_endian;
        let short = |b: &[u8]| if be { u16::from_be_bytes([b[0], b[1]]) } else { u16::from_le_bytes([b[0], b[1]]) };
        let (values, bias) = match l.ty {
            ty if l.codes_from_min => (PartValues::F32(crate::volume::decode_voxels(&bytes, ty, be)), 0.0),
            VoxelType::U8 => (PartValues::U8(bytes), 0.0),
            VoxelType::I8 => (PartValues::U8(bytes.iter().map(|&b| b ^ 0x80).collect()), -128.0),
            VoxelType::U16 => (PartValues::U16(bytes.chunks_exact(2).map(short).collect()), 0.0),
            VoxelType::I16 => (PartValues::U16(bytes.chunks_exact(2).map(|b| short(b) ^ 0x8000).collect()), -32_768.0),
            ty => (PartValues::F32(crate::volume::decode_voxels(&bytes, ty, be)), 0.0),
        };
        let range = owned_range(&values, owned);
        let codes_from_min = l.codes_from_min;
        return Ok(PartData {
            name: l.name,
            dims: l.dims,
            spacing: l.spacing,
            part,
            values,
            range,
            bias,
            codes_from_min,
            source_range: None,
        });
    }
    let whole = crate::volume::load_volume(path, opts)?;
    Ok(part_of(&whole, decomposition, p))
}

fn owned_range(values: &PartValues, owned: impl Fn(usize) -> bool) -> (f32, f32) {
    let mut r = (f32::INFINITY, f32::NEG_INFINITY);
    let mut put = |i: usize, v: f32| {
        if v.is_finite() && owned(i) {
            r = (r.0.min(v), r.1.max(v));
        }
    };
    match values {
        PartValues::U8(v) => v.iter().enumerate().for_each(|(i, &x)| put(i, f32::from(x))),
        PartValues::U16(v) => v.iter().enumerate().for_each(|(i, &x)| put(i, f32::from(x))),
        PartValues::F32(v) => v.iter().enumerate().for_each(|(i, &x)| put(i, x)),
    }
    r
}

/// Part `p` of a volume in memory, as [`read_part`] would read it: its stored values, and the
/// whole volume's stored range (so [`PartData::into_volume`] with [`PartData::range`]
/// normalizes exactly as `whole` does).
pub fn part_of(whole: &Volume, decomposition: &Decomposition, p: usize) -> PartData {
    let part = decomposition.parts[p];
    let hd = part.held_dims();
    let n = hd.iter().map(|&d| d as usize).product::<usize>();
    let (offset, scale) = whole.normalization();
    let at = |i: usize| {
        let x = i as u32 % hd[0] + part.held_lo[0];
        let y = (i as u32 / hd[0]) % hd[1] + part.held_lo[1];
        let z = i as u32 / (hd[0] * hd[1]) + part.held_lo[2];
        whole.voxels().get(x, y, z)
    };
    let (vlo, _) = whole.value_range();
    let (values, range, bias) = match whole.voxels() {
        Voxels::U8(_) => {
            let lo = offset;
            let hi = lo + code_range(scale);
            (PartValues::U8((0..n).map(|i| at(i) as u8).collect()), (lo, hi), vlo - lo)
        }
        Voxels::U16(_) => {
            let lo = offset;
            let hi = lo + code_range(scale);
            (PartValues::U16((0..n).map(|i| at(i) as u16).collect()), (lo, hi), vlo - lo)
        }
        // Already normalized: a [0, 1] range keeps them as they are.
        Voxels::F32(_) => (PartValues::F32((0..n).map(at).collect()), (0.0, 1.0), 0.0),
    };
    let mut d = PartData {
        name: whole.name.clone(),
        dims: whole.dims(),
        spacing: whole.spacing(),
        part,
        values,
        range,
        bias,
        codes_from_min: false,
        source_range: None,
    };
    if let PartValues::F32(_) = d.values {
        // Normalized values over [0, 1] stay the same bits: (v − 0) · 1 in f64 and back.
        d.range = (0.0, 1.0);
        d.source_range = Some(whole.value_range());
    }
    d
}

/// The stored range whose [`code`] is `scale` (the inverse of the loaders' normalization).
fn code_range(scale: f32) -> f32 {
    if scale <= 0.0 {
        return 0.0;
    }
    let mut r = (1.0 / scale as f64).round() as f32;
    while r > 0.0 && code(r) != scale {
        r -= 1.0;
    }
    r
}
