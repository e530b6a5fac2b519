//! Bricked voxel storage in the file's own type: what a [`Volume`](super::Volume) keeps of its
//! voxels.
//!
//! The volume is cut into bricks of [`BRICK_EDGE`]³ voxels; each brick is stored as
//! [`BRICK_SPAN`]³ values, x fastest: its own voxels and a one-voxel *apron* on its far side in
//! x, y and z (the first voxels of the next bricks), so the eight corners of a trilinear stencil
//! whose lowest corner lies in a brick are all in that brick. Positions past the volume's last
//! voxel (the apron of the last bricks, the rest of bricks the volume does not fill) hold the
//! nearest voxel's value, so a read there gives what a clamped read gives. Bricks are in x, y,
//! z order, so the brick table is implicit: brick `(bx, by, bz)` starts at value
//! `(bx + nbx·(by + nby·bz))·BRICK_SPAN³`. A brick of 32³ voxels in 33³ values costs 1.097× its
//! voxels (plus the part of the last bricks the volume does not fill).
//!
//! The values are the file's own (`u8`, `u16`, or `f32`, see [`Voxels`]): a volume costs about
//! what its file holds, not 4 bytes per voxel. The packet marcher gathers them with `i32`
//! indices, so the bricks live in *chunks* of at most [`CHUNK_LIMIT`] values each: whole z-slabs
//! of bricks, a power of two of them per chunk (the chunk of brick slab `bz` is `bz >> shift`).
//! Volumes below 2³¹ stored values have one chunk.

use super::{VolumeError, VolumeErrorKind};

/// The edge of a brick in voxels (a power of two: the marchers split coordinates with shifts).
pub const BRICK_EDGE: u32 = 32;
/// `log2(BRICK_EDGE)`.
pub const BRICK_SHIFT: u32 = 5;
/// Values per brick edge: the brick's voxels and the apron.
pub const BRICK_SPAN: u32 = BRICK_EDGE + 1;
const _: () = assert!(BRICK_SPAN == 33, "GridBuilder::write_slab copies runs of 33 values");
/// Values per brick.
pub const BRICK_VALUES: usize = (BRICK_SPAN * BRICK_SPAN * BRICK_SPAN) as usize;
/// Most values in one chunk (the packet marcher's gathers index a chunk with `i32` lanes; a
/// byte gather reads 4 bytes from its index).
pub const CHUNK_LIMIT: usize = (1 << 31) - 64;
/// Values after the last brick of a chunk, so that a 4-byte gather at any brick value stays
/// inside the chunk.
const CHUNK_PAD: usize = 4;

/// A type the bricks store.
pub trait Stored: Copy + Default + PartialOrd + Send + Sync + std::fmt::Debug + 'static {
    /// The value as `f32` (exact for `u8` and `u16`).
    fn to_f32(self) -> f32;
    /// The stored value nearest `v` (rounded to nearest for integers, saturating).
    fn from_f32(v: f32) -> Self;
}

impl Stored for u8 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
    #[inline(always)]
    fn from_f32(v: f32) -> u8 {
        v.round() as u8
    }
}

impl Stored for u16 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
    #[inline(always)]
    fn from_f32(v: f32) -> u16 {
        v.round() as u16
    }
}

impl Stored for f32 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self
    }
    #[inline(always)]
    fn from_f32(v: f32) -> f32 {
        v
    }
}

/// Where bricks and their values lie: the dims, the bricks per axis and the chunks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    dims: [u32; 3],
    bricks: [u32; 3],
    /// `log2` of the brick z-slabs per chunk.
    slab_shift: u32,
}

impl Layout {
    /// The layout of a volume of `dims` voxels (none zero); an error where one z-slab of bricks
    /// holds more than [`CHUNK_LIMIT`] values (an x–y extent of more than about 7,700² voxels).
    pub fn new(dims: [u32; 3]) -> Result<Layout, VolumeError> {
        Layout::with_chunk_limit(dims, CHUNK_LIMIT)
    }

    /// [`Layout::new`] with chunks of at most `limit` values (at most [`CHUNK_LIMIT`]): small
    /// limits make small volumes take several chunks, for tests of the chunked gathers.
    pub fn with_chunk_limit(dims: [u32; 3], limit: usize) -> Result<Layout, VolumeError> {
        let limit = limit.min(CHUNK_LIMIT);
        if dims.contains(&0) {
            return Err(VolumeError::new(VolumeErrorKind::BadGeometry(format!("dimensions {dims:?} contain a zero"))));
        }
        let bricks = dims.map(|d| d.div_ceil(BRICK_EDGE));
        let slab = bricks[0] as usize * bricks[1] as usize * BRICK_VALUES;
        if slab + CHUNK_PAD > limit {
            return Err(VolumeError::unsupported(format!(
                "an x-y extent of {}x{} voxels (one z-slab of {BRICK_EDGE}-voxel bricks holds more than 2^31 values)",
                dims[0], dims[1]
            )));
        }
        let mut slab_shift = 0;
        while slab_shift < 31
            && (1usize << (slab_shift + 1)) <= bricks[2].next_power_of_two() as usize
            && (slab << (slab_shift + 1)) + CHUNK_PAD <= limit
        {
            slab_shift += 1;
        }
        Ok(Layout { dims, bricks, slab_shift })
    }

    /// Dimensions in voxels.
    pub fn dims(&self) -> [u32; 3] {
        self.dims
    }

    /// Bricks per axis.
    pub fn bricks(&self) -> [u32; 3] {
        self.bricks
    }

    /// `log2` of the brick z-slabs per chunk.
    pub fn slab_shift(&self) -> u32 {
        self.slab_shift
    }

    /// Number of chunks.
    pub fn chunks(&self) -> usize {
        self.bricks[2].div_ceil(1 << self.slab_shift) as usize
    }

    /// Bricks in one z-slab.
    fn slab_bricks(&self) -> usize {
        self.bricks[0] as usize * self.bricks[1] as usize
    }

    /// The brick z-slabs of chunk `c`.
    fn chunk_slabs(&self, c: usize) -> std::ops::Range<u32> {
        let per = 1u32 << self.slab_shift;
        let start = c as u32 * per;
        start..(start + per).min(self.bricks[2])
    }

    /// Values of chunk `c`, with its padding.
    pub fn chunk_len(&self, c: usize) -> usize {
        self.chunk_slabs(c).len() * self.slab_bricks() * BRICK_VALUES + CHUNK_PAD
    }

    /// Values stored in all chunks.
    pub fn stored_values(&self) -> u64 {
        (0..self.chunks()).map(|c| self.chunk_len(c) as u64).sum()
    }

    /// Bytes the bricks of a volume of `dims` take with values of `bytes_per_value` bytes
    /// (`None` where that does not fit in 64 bits), whether or not [`Layout::new`] accepts the
    /// dims.
    pub fn stored_bytes(dims: [u32; 3], bytes_per_value: u64) -> Option<u64> {
        let bricks = dims.iter().try_fold(1u64, |n, &d| n.checked_mul(u64::from(d.div_ceil(BRICK_EDGE))))?;
        bricks
            .checked_mul(BRICK_VALUES as u64)?
            .checked_add(u64::from(dims[2].div_ceil(BRICK_EDGE)) * CHUNK_PAD as u64)?
            .checked_mul(bytes_per_value)
    }

    /// The chunk and the index in it of voxel `(x, y, z)` (each below its dim): the value of
    /// the voxel; the values at `+1`, `+BRICK_SPAN` and `+BRICK_SPAN²` from it are its
    /// neighbours in x, y and z (clamped to the volume's last voxel).
    #[inline(always)]
    pub fn locate(&self, x: u32, y: u32, z: u32) -> (usize, usize) {
        let (bx, by, bz) = (x >> BRICK_SHIFT, y >> BRICK_SHIFT, z >> BRICK_SHIFT);
        let m = BRICK_EDGE - 1;
        let (lx, ly, lz) = (x & m, y & m, z & m);
        let chunk = (bz >> self.slab_shift) as usize;
        let bzl = bz & ((1 << self.slab_shift) - 1);
        let brick = bx as usize + self.bricks[0] as usize * (by as usize + self.bricks[1] as usize * bzl as usize);
        let local = lx + BRICK_SPAN * (ly + BRICK_SPAN * lz);
        (chunk, brick * BRICK_VALUES + local as usize)
    }
}

/// With `VOLWARP_HUGE_PAGES=1`, asks the kernel to back the whole 2 MiB pages inside `v` with
/// transparent huge pages (Linux, where they are enabled as `madvise`; a hint, ignored
/// elsewhere). Off by default: measured on this machine, huge pages load 1024³ u8 in 0.43
/// instead of 0.52 s, but 2048²×1024 in 5.8 instead of 2.3 s (with most memory in the page
/// cache the kernel compacts memory for every 2 MiB fault), and the march is no faster.
fn advise_huge_pages<T>(v: &mut [T]) {
    #[cfg(target_os = "linux")]
    {
        const HUGE: usize = 2 << 20;
        if std::env::var_os("VOLWARP_HUGE_PAGES").is_none_or(|v| v != "1") {
            return;
        }
        let start = v.as_mut_ptr() as usize;
        let (first, end) = (start.next_multiple_of(HUGE), (start + std::mem::size_of_val(v)) / HUGE * HUGE);
        if end > first {
            // SAFETY: the range lies inside `v`'s allocation, which this function borrows
            // mutably; MADV_HUGEPAGE only advises the kernel and changes no content.
            unsafe {
                libc::madvise(first as *mut libc::c_void, end - first, libc::MADV_HUGEPAGE);
            }
        }
    }
}

/// Bricked values of one type.
#[derive(Clone, Debug)]
pub struct Grid<T> {
    layout: Layout,
    chunks: Vec<Vec<T>>,
}

impl<T: Stored> Grid<T> {
    /// The layout.
    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// The chunks' values (each with its padding).
    pub fn chunks(&self) -> &[Vec<T>] {
        &self.chunks
    }

    /// The value of voxel `(x, y, z)` (each below its dim).
    #[inline(always)]
    pub fn get(&self, x: u32, y: u32, z: u32) -> T {
        let (c, i) = self.layout.locate(x, y, z);
        self.chunks[c][i]
    }

    /// The eight corners `[c000, c100, c010, c110, c001, c101, c011, c111]` (x fastest) of the
    /// stencil whose lowest corner is voxel `(x, y, z)` (each below its dim; corners past the
    /// volume read its last voxel), as `f32`.
    #[inline(always)]
    pub fn corners(&self, x: u32, y: u32, z: u32) -> [f32; 8] {
        let (c, i) = self.layout.locate(x, y, z);
        let (sy, sz) = (BRICK_SPAN as usize, (BRICK_SPAN * BRICK_SPAN) as usize);
        let d = &self.chunks[c];
        [i, i + 1, i + sy, i + sy + 1, i + sz, i + sz + 1, i + sz + sy, i + sz + sy + 1].map(|j| d[j].to_f32())
    }

    /// Calls `f(x0, run)` for the runs of row `y` of slice `z` (each below its dim) that lie in
    /// one storage brick each, `x0` the first voxel of the run, in x order.
    #[inline]
    pub fn for_each_run(&self, y: u32, z: u32, mut f: impl FnMut(usize, &[T])) {
        let nx = self.layout.dims[0];
        let mut x = 0;
        while x < nx {
            let n = (nx - x).min(BRICK_EDGE) as usize;
            let (c, i) = self.layout.locate(x, y, z);
            f(x as usize, &self.chunks[c][i..i + n]);
            x += BRICK_EDGE;
        }
    }

    /// Row `y` of slice `z` (each below its dim) as `f32`, into `out` (replacing its content).
    pub fn read_row(&self, y: u32, z: u32, out: &mut Vec<f32>) {
        out.clear();
        self.for_each_run(y, z, |_, run| out.extend(run.iter().map(|v| v.to_f32())));
    }

    /// Bytes the values take.
    pub fn bytes(&self) -> u64 {
        self.chunks.iter().map(|c| c.len() as u64).sum::<u64>() * std::mem::size_of::<T>() as u64
    }

    /// Every value, brick padding included, changed by `f` (in parallel).
    pub(crate) fn map_in_place(&mut self, f: impl Fn(T) -> T + Sync) {
        use rayon::prelude::*;
        for c in &mut self.chunks {
            c.par_chunks_mut(1 << 16).for_each(|part| part.iter_mut().for_each(|v| *v = f(*v)));
        }
    }

    /// The same voxels in chunks of at most `limit` values ([`Layout::with_chunk_limit`]).
    pub fn rechunked(&self, limit: usize) -> Result<Grid<T>, VolumeError> {
        let mut b = GridBuilder::with_layout(Layout::with_chunk_limit(self.layout.dims, limit)?)?;
        let [nx, ny, nz] = self.layout.dims;
        let mut slice = Vec::with_capacity(nx as usize * ny as usize);
        for z in 0..nz {
            slice.clear();
            for y in 0..ny {
                slice.extend((0..nx).map(|x| self.get(x, y, z)));
            }
            b.push_slice(&slice);
        }
        b.finish()
    }

    /// The voxels in x-fastest order (allocates `dims` product values: for tests and small
    /// volumes).
    pub fn to_vec(&self) -> Vec<T> {
        let [nx, ny, nz] = self.layout.dims;
        let mut out = Vec::with_capacity(nx as usize * ny as usize * nz as usize);
        for z in 0..nz {
            for y in 0..ny {
                out.extend((0..nx).map(|x| self.get(x, y, z)));
            }
        }
        out
    }
}

/// Fills a [`Grid`] slice by slice (z ascending, each slice x fastest): what the streaming
/// loaders feed. Memory: the grid and the slices of one z-slab of bricks ([`BRICK_SPAN`]
/// slices, its own and the apron's), kept until the slab is whole and then written brick row
/// by brick row (each row of bricks, a few MiB, filled completely while it is in cache).
pub struct GridBuilder<T> {
    grid: Grid<T>,
    next_z: u32,
    /// The slices of the slab being gathered, from `slab_z`.
    slab: Vec<T>,
    slab_z: u32,
}

impl<T: Stored> GridBuilder<T> {
    /// A builder for `dims` voxels: allocates the grid (zeroed pages: the memory is taken as
    /// slices arrive).
    pub fn new(dims: [u32; 3]) -> Result<GridBuilder<T>, VolumeError> {
        GridBuilder::with_layout(Layout::new(dims)?)
    }

    /// A builder for the voxels of `layout`.
    pub fn with_layout(layout: Layout) -> Result<GridBuilder<T>, VolumeError> {
        // Zeroed allocations (calloc): pages are taken as slices are written, not twice. The
        // loaders checked the memory before ([`super::check_load`]).
        let chunks = (0..layout.chunks())
            .map(|c| {
                let mut v = vec![T::default(); layout.chunk_len(c)];
                advise_huge_pages(&mut v);
                v
            })
            .collect();
        Ok(GridBuilder { grid: Grid { layout, chunks }, next_z: 0, slab: Vec::new(), slab_z: 0 })
    }

    /// Slices received so far.
    pub fn slices_done(&self) -> u32 {
        self.next_z
    }

    /// Adds the next z-slice (`nx·ny` values, x fastest); slices past the last are ignored.
    pub fn push_slice(&mut self, slice: &[T]) {
        let [nx, ny, nz] = self.grid.layout.dims;
        let z = self.next_z;
        let n = nx as usize * ny as usize;
        if z >= nz || slice.len() != n {
            return;
        }
        self.slab.extend_from_slice(slice);
        self.next_z += 1;
        if z == self.slab_z + BRICK_EDGE {
            // The slab's own slices and its apron (the next slab's first slice): write it, and
            // keep that slice for the next slab.
            write_slab(&mut self.grid, self.slab_z >> BRICK_SHIFT, &self.slab);
            // The buffer is kept (no new pages to fault in for the next slab).
            let keep = self.slab.len() - n;
            self.slab.drain(..keep);
            self.slab_z = z;
        }
        if z == nz - 1 {
            // The last slab: its missing slices repeat the last one.
            write_slab(&mut self.grid, self.slab_z >> BRICK_SHIFT, &self.slab);
            self.slab = Vec::new();
        }
    }
}

/// Writes the bricks of slab `bz` of `grid` from its slices (x fastest, `BRICK_SPAN` of them or
/// fewer: the missing ones repeat the last), in parallel over rows of bricks.
fn write_slab<T: Stored>(grid: &mut Grid<T>, bz: u32, slices: &[T]) {
    use rayon::prelude::*;
    let layout = grid.layout;
    let [nx, ny, _] = layout.dims;
    let [nbx, nby, _] = layout.bricks;
    let n = nx as usize * ny as usize;
    let count = slices.len() / n.max(1);
    if count == 0 {
        return;
    }
    let chunk = (bz >> layout.slab_shift) as usize;
    let bzl = (bz & ((1 << layout.slab_shift) - 1)) as usize;
    let row_bricks = nbx as usize * BRICK_VALUES;
    let slab_start = bzl * layout.slab_bricks() * BRICK_VALUES;
    let dst = &mut grid.chunks[chunk][slab_start..slab_start + nby as usize * row_bricks];
    let span = BRICK_SPAN as usize;
    let nx = nx as usize;
    dst.par_chunks_mut(row_bricks).enumerate().for_each(|(by, row)| {
        for lz in 0..span {
            let slice = &slices[lz.min(count - 1) * n..][..n];
            for ly in 0..span {
                let y = (by * BRICK_EDGE as usize + ly).min(ny as usize - 1);
                let src = &slice[y * nx..(y + 1) * nx];
                let last = src[nx - 1];
                for bx in 0..nbx as usize {
                    let x0 = bx * BRICK_EDGE as usize;
                    let off = bx * BRICK_VALUES + span * (ly + span * lz);
                    let d = &mut row[off..off + span];
                    if let (Some(d), Some(s)) = (d.first_chunk_mut::<33>(), src.get(x0..x0 + span)) {
                        // A whole run (a copy of constant length, inlined).
                        d.copy_from_slice(s.first_chunk::<33>().expect("33 values"));
                    } else {
                        let k = (nx - x0).min(span);
                        d[..k].copy_from_slice(&src[x0..x0 + k]);
                        d[k..].iter_mut().for_each(|v| *v = last);
                    }
                }
            }
        }
    });
}

impl<T: Stored> GridBuilder<T> {
    /// The grid, once every slice is in (an error naming how many arrived otherwise).
    pub fn finish(self) -> Result<Grid<T>, VolumeError> {
        let nz = self.grid.layout.dims[2];
        if self.next_z != nz {
            return Err(VolumeError::new(VolumeErrorKind::SizeMismatch {
                expected: u64::from(nz),
                actual: u64::from(self.next_z),
            }));
        }
        Ok(self.grid)
    }
}

/// A volume's voxels as stored: the file's own type where it is an 8- or 16-bit integer
/// (signed 16-bit values offset by 32,768), else `f32` values normalized to `0..=1`.
#[derive(Clone, Debug)]
pub enum Voxels {
    /// 8-bit values.
    U8(Grid<u8>),
    /// 16-bit values.
    U16(Grid<u16>),
    /// `f32` values.
    F32(Grid<f32>),
}

impl Voxels {
    /// The layout.
    pub fn layout(&self) -> &Layout {
        match self {
            Voxels::U8(g) => g.layout(),
            Voxels::U16(g) => g.layout(),
            Voxels::F32(g) => g.layout(),
        }
    }

    /// The stored value of voxel `(x, y, z)` as `f32` (each coordinate below its dim).
    #[inline(always)]
    pub fn get(&self, x: u32, y: u32, z: u32) -> f32 {
        match self {
            Voxels::U8(g) => g.get(x, y, z).to_f32(),
            Voxels::U16(g) => g.get(x, y, z).to_f32(),
            Voxels::F32(g) => g.get(x, y, z),
        }
    }

    /// [`Grid::corners`] of the stored grid.
    #[inline(always)]
    pub fn corners(&self, x: u32, y: u32, z: u32) -> [f32; 8] {
        match self {
            Voxels::U8(g) => g.corners(x, y, z),
            Voxels::U16(g) => g.corners(x, y, z),
            Voxels::F32(g) => g.corners(x, y, z),
        }
    }

    /// Bytes the values take.
    pub fn bytes(&self) -> u64 {
        match self {
            Voxels::U8(g) => g.bytes(),
            Voxels::U16(g) => g.bytes(),
            Voxels::F32(g) => g.bytes(),
        }
    }

    /// The same voxels in chunks of at most `limit` values ([`Grid::rechunked`]).
    pub fn rechunked(&self, limit: usize) -> Result<Voxels, VolumeError> {
        Ok(match self {
            Voxels::U8(g) => Voxels::U8(g.rechunked(limit)?),
            Voxels::U16(g) => Voxels::U16(g.rechunked(limit)?),
            Voxels::F32(g) => Voxels::F32(g.rechunked(limit)?),
        })
    }

    /// The stored type's name (`u8`, `u16`, `f32`).
    pub fn type_name(&self) -> &'static str {
        match self {
            Voxels::U8(_) => "u8",
            Voxels::U16(_) => "u16",
            Voxels::F32(_) => "f32",
        }
    }
}

/// Bricks a grid of `f(value)` for `values` in x-fastest order (`dims` product long), a slice
/// at a time (no second copy of the volume).
pub fn grid_from_fn<T: Stored>(dims: [u32; 3], values: &[f32], f: impl Fn(f32) -> T) -> Result<Grid<T>, VolumeError> {
    let mut b = GridBuilder::new(dims)?;
    let n = (dims[0] as usize * dims[1] as usize).max(1);
    let mut slice = Vec::with_capacity(n);
    for s in values.chunks(n) {
        slice.clear();
        slice.extend(s.iter().map(|&v| f(v)));
        b.push_slice(&slice);
    }
    b.finish()
}

/// Bricks a grid from values in x-fastest order (`dims` product long).
pub fn grid_from_values<T: Stored>(dims: [u32; 3], values: &[T]) -> Result<Grid<T>, VolumeError> {
    let mut b = GridBuilder::new(dims)?;
    let slice = dims[0] as usize * dims[1] as usize;
    for s in values.chunks(slice.max(1)) {
        b.push_slice(s);
    }
    b.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bricks_hold_every_voxel_and_clamped_aprons() {
        for dims in [[1, 1, 1], [2, 3, 1], [33, 2, 65], [65, 33, 34], [32, 32, 32]] {
            let n = dims.iter().map(|&d| d as usize).product::<usize>();
            let values: Vec<u16> = (0..n).map(|i| (i * 7919 % 65_521) as u16).collect();
            let g = grid_from_values(dims, &values).unwrap();
            assert_eq!(g.to_vec(), values, "{dims:?}");
            let mut row = Vec::new();
            g.read_row(dims[1] - 1, dims[2] - 1, &mut row);
            let last = values.len() - dims[0] as usize;
            assert_eq!(row, values[last..].iter().map(|&v| v as f32).collect::<Vec<_>>());
            let at = |x: u32, y: u32, z: u32| {
                let [nx, ny, nz] = dims;
                let (x, y, z) = (x.min(nx - 1) as usize, y.min(ny - 1) as usize, z.min(nz - 1) as usize);
                values[x + nx as usize * (y + ny as usize * z)] as f32
            };
            for z in 0..dims[2] {
                for y in 0..dims[1] {
                    for x in 0..dims[0] {
                        let want = super::super::sampling::stencil(at, x, y, z);
                        assert_eq!(g.corners(x, y, z), want, "{dims:?} at {x},{y},{z}");
                    }
                }
            }
        }
    }

    #[test]
    fn chunks_split_big_volumes_by_whole_brick_slabs() {
        // 2048³: 64 bricks per axis, 4096 per slab of 147 M values; 8 slabs per chunk.
        let l = Layout::new([2048; 3]).unwrap();
        assert_eq!(l.bricks(), [64; 3]);
        assert_eq!(l.slab_shift(), 3);
        assert_eq!(l.chunks(), 8);
        assert!((0..l.chunks()).all(|c| l.chunk_len(c) <= CHUNK_LIMIT));
        let (c, i) = l.locate(2047, 2047, 2047);
        assert_eq!(c, 7);
        assert!(i + 1 + (BRICK_SPAN * BRICK_SPAN + BRICK_SPAN) as usize + 3 < l.chunk_len(c));
        // Small volumes: one chunk; x-y planes too wide for a chunk are refused.
        assert_eq!(Layout::new([181, 217, 181]).unwrap().chunks(), 1);
        assert!(Layout::new([1 << 14, 1 << 14, 1]).is_err());
        // A small limit: one brick slab per chunk, the same voxels.
        let values: Vec<u8> = (0..40 * 7 * 70).map(|i| (i % 251) as u8).collect();
        let g = grid_from_values([40, 7, 70], &values).unwrap();
        let r = g.rechunked(2 * BRICK_VALUES + 4).unwrap();
        assert_eq!((g.layout().chunks(), r.layout().chunks()), (1, 3));
        assert_eq!(r.to_vec(), values);
        assert_eq!(r.corners(39, 6, 69), g.corners(39, 6, 69));
        // 1.097x the voxels for whole bricks.
        let l = Layout::new([1024; 3]).unwrap();
        let ratio = l.stored_values() as f64 / (1u64 << 30) as f64;
        assert!((1.09..1.10).contains(&ratio), "{ratio}");
        assert!(Layout::stored_bytes([1024; 3], 2).is_some_and(|b| b >= 2 * l.stored_values()));
        assert_eq!(Layout::stored_bytes([u32::MAX; 3], 4), None);
    }

    #[test]
    fn missing_slices_are_an_error() {
        let mut b = GridBuilder::<u8>::new([4, 4, 3]).unwrap();
        b.push_slice(&[1; 16]);
        b.push_slice(&[1; 15]); // wrong length: ignored
        assert_eq!(b.slices_done(), 1);
        assert!(b.finish().is_err());
    }
}
