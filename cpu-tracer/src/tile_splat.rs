//! The exact sphere splatter built for the cache (renderer name `splat-tiles`): the same image
//! as first-hit tracing — core's ray–sphere test for every covered pixel's own primary ray and
//! core's tie rule — with work that scales with the spheres and the pixels they cover, not with
//! the image.
//!
//! 1. **Bound** (parallel over runs of spheres): each sphere's screen rectangle — the pixels
//!    whose *centres* lie between the tangents from the eye (`tight_bound`), sixteen spheres at
//!    a time in AVX-512 lanes where the CPU has them, else eight, in f32 with a widened radius
//!    (the packed samples unpacked, the integer spans taken, the rectangles packed and the
//!    records stored in lanes too: `BoundLanes`), in f64 for spheres near the eye plane; one
//!    kernel call per run of groups (`bound_run`) — and,
//!    per [`GROUP`] consecutive spheres, the union of their rectangles. The scene's order is
//!    spatially coherent (Morton order when built, the server's image order when not), so a
//!    group covers a small patch of the screen. A *small* sphere (a rectangle of at most 2×2
//!    pixels, most spheres of a frame drawn at half its resolution) also gets its hits there:
//!    the ray–sphere test on the pixels of its 2×2 window, one sphere per lane
//!    (`small_hits`: full lanes, where a 4×2 block in step 3 would use one to four), kept in
//!    place of its centre.
//! 2. **Bin**: each group goes to the [`TILE`]×[`TILE`] tiles its rectangle overlaps (a serial
//!    counting sort over a few tens of thousands of groups). A sphere overlapping more than
//!    [`MAX_TILES`] tiles (large on screen, or touching the eye plane: its rectangle is then the
//!    whole viewport) goes to a list of large spheres instead, which every tile reads with a
//!    rectangle test. A group overlapping more than [`MAX_GROUP_TILES`] tiles (in the server's
//!    scanline order, the group that wraps from one row's end to the next row's start) is
//!    binned by runs of consecutive spheres that lie close, each entry with the mask of the
//!    group's spheres in its run, so no tile tests spheres that lie far from it. Memory: one
//!    entry (index and mask) per group per tile it overlaps (≤ [`MAX_GROUP_TILES`], or
//!    ≤ [`MAX_TILES`] per sphere of a split group), one per large sphere, 24 bytes per sphere
//!    (its rectangle, and its centre and radius as the bound decoded them); nothing per pixel
//!    besides the image, whatever the view.
//! 3. **Splat** (parallel over bands of tiles): per tile, the unit ray directions of its pixels
//!    (`RayBasis::dir`'s operations, eight at a time) and per pixel the distance and sample of
//!    its nearest hit so far (an f32 depth plane and a u32 id plane), all in a local buffer of
//!    about 90 KB that stays in L2 ([`TILE`]); each sphere of its groups whose rectangle overlaps the tile
//!    tests its pixels in the tile eight at a time with the packet tracer's SIMD ray–sphere
//!    kernel (`lanes::sphere_hits`, AVX2 dispatch): as 4×2 blocks when the rectangle is at most
//!    four pixels wide, as rows of 8 otherwise. The depth test runs in the same lanes (a nearer
//!    hit takes the pixel; a hit at equal depth goes to a cold scalar path with the tie rule).
//!    A small sphere only keeps its four hits by minimum, pixel by pixel (`splat_small`); the
//!    tile's ray directions are made before the first sphere that is not small, if any.
//!    A row block of a wider sphere is skipped when a conservative near distance of the sphere
//!    lies beyond the depth of all its pixels (occlusion culling,
//!    [`TileSplat::with_culling`]). The tile's ids or colors are then written straight into the
//!    image: no per-thread image and no merge.
//!
//! Tiles without spheres cost one background fill. A pixel's `(t, id)` orders as the key
//! `(t bits << 32) | id`, so its minimum is core's tie rule (equal `t`: the smaller index), and
//! the result does not depend on the order of the spheres in a tile, on culling or on the
//! thread count (tested). An *unbuilt* scene (the
//! frame's samples in arrival order, no nodes: [`crate::route::unbuilt_scene`]) is drawn too;
//! equal distances are then broken by the order the LBVH build would give (Morton code, then
//! index), so the image is the built scene's.

use crate::depth_buffer::{key, key_prim, EMPTY};
use crate::lanes::{self, prefetch, ray_dirs, sphere_hits, Arith, BoundLanes, Lanes};
use crate::sphere_splat::View;
use crate::threads::Threads;
use crate::{begin_frame_overwritten, begin_frame_unbuilt_ok as begin_frame, shade, MAX_VIEWPORT, NO_HIT};
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};
use volwarp_core::morton::code_of_sample;
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::sample::Dequantizer;
use volwarp_core::RendererKind;
use volwarp_core::{Camera, Scene, Vec3, BACKGROUND};

mod bound;
mod kernel;

pub(crate) use bound::*;
pub(crate) use kernel::*;

/// Tile side in pixels: a tile's keys (33 KB) and ray directions (≈ 56 KB) stay in L2 (with 32,
/// which fit L1, the frame took 9–11 % longer: more spheres cut by tile borders and more groups
/// per tile list; `docs/perf.md`, "Measured and not built").
pub const TILE: usize = 64;
const _: () = assert!(TILE.is_power_of_two());

/// A sphere overlapping more tiles than this goes to the shared list of large spheres.
pub const MAX_TILES: usize = 4;

/// Consecutive spheres binned together (the scene's order is spatially coherent: Morton order
/// when built, the server's image order when not): a tile lists the groups whose rectangle
/// (the union of their spheres' but the large ones) overlaps it, and tests each sphere's own
/// rectangle.
pub const GROUP: usize = 32;
const _: () = assert!(GROUP <= 32 && MAX_VIEWPORT < 0x7FFF);

/// A group overlapping more tiles than this (its spheres far apart on screen) is binned by its
/// spheres' own tiles instead of its rectangle's.
pub const MAX_GROUP_TILES: usize = 16;

/// Row stride of a tile's direction planes: sixteen floats of padding so that a row's 8- or
/// 16-lane load may start at any column.
const STRIDE: usize = TILE + 16;
/// Rows of a direction plane: one of padding for the second row of a 4×2 block.
const PLANE: usize = STRIDE * (TILE + 1);

/// A sphere's inclusive pixel rectangle; `x0 > x1` when it covers no pixel. In memory as
/// [`Rect::bits`] (on a little-endian CPU), so rectangles made as words store as one.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(8))]
pub(crate) struct Rect {
    pub(crate) x0: u16,
    pub(crate) y0: u16,
    pub(crate) x1: u16,
    pub(crate) y1: u16,
}

/// The empty rectangle: `x0 > x1`, and `x0`, `y0` beyond every viewport ([`MAX_VIEWPORT`] <
/// 2¹⁵), so that [`TileTest::hits`] refuses it without a test of its own.
/// One definition with the bound pass's lanes ([`lanes::EMPTY_RECT`]).
pub(crate) const NO_RECT: Rect = Rect::from_bits(lanes::EMPTY_RECT);

impl Rect {
    pub(crate) fn is_empty(&self) -> bool {
        self.x0 > self.x1
    }

    /// Whether a non-empty rectangle overlaps more than [`MAX_TILES`] tiles (then it is drawn
    /// from the list of large spheres, not from its group); some value, without overflow, for
    /// an empty one.
    #[inline(always)]
    fn is_large(&self) -> bool {
        let t = |a: u16| (a as usize / TILE) as isize;
        let (tx, ty) = (t(self.x1) - t(self.x0) + 1, t(self.y1) - t(self.y0) + 1);
        tx.wrapping_mul(ty) > MAX_TILES as isize
    }

    /// The smallest rectangle holding both, with no branch: the empty rectangle (always
    /// [`NO_RECT`], whose corners lie beyond every viewport in the right order) is the identity
    /// of the componentwise minimum and maximum.
    #[inline(always)]
    fn union(self, o: Rect) -> Rect {
        Rect { x0: self.x0.min(o.x0), y0: self.y0.min(o.y0), x1: self.x1.max(o.x1), y1: self.y1.max(o.y1) }
    }

    /// The rectangle of [`Rect::bits`].
    #[inline(always)]
    const fn from_bits(b: u64) -> Rect {
        Rect { x0: b as u16, y0: (b >> 16) as u16, x1: (b >> 32) as u16, y1: (b >> 48) as u16 }
    }

    /// The four coordinates as one word: `x0` in the low 16 bits, then `y0`, `x1`, `y1`.
    #[inline(always)]
    fn bits(self) -> u64 {
        self.x0 as u64 | (self.y0 as u64) << 16 | (self.x1 as u64) << 32 | (self.y1 as u64) << 48
    }

    /// Inclusive tile ranges `(tx0, tx1, ty0, ty1)`.
    #[inline(always)]
    fn tiles(&self) -> (usize, usize, usize, usize) {
        (self.x0 as usize / TILE, self.x1 as usize / TILE, self.y0 as usize / TILE, self.y1 as usize / TILE)
    }
}

/// The tiled exact sphere splatter (renderer name `splat-tiles`).
#[derive(Debug)]
pub struct TileSplat {
    threads: Threads,
    rects: Vec<Rect>,
    /// Per sphere, its centre less the eye and its radius, as the bound pass decoded them
    /// (the kernel's ray–sphere test starts from exactly these values).
    centres: Vec<[f32; 4]>,
    /// Whether a sphere whose near distance lies behind every pixel it could cover is skipped.
    cull: bool,
    /// (sphere–tile pairs drawn, of which skipped whole by the depth test) in the last frame.
    culled: (u64, u64),
    /// Per group of [`GROUP`] spheres, the union of its spheres' rectangles but the large ones.
    group_rects: Vec<Rect>,
    /// Tile by tile, the groups binned to it: the group's index in the low 32 bits, in the
    /// high 32 the mask of its spheres that may overlap the tile (all ones but for a group
    /// binned by its spheres' tiles).
    lists: Vec<u64>,
    /// Start of each tile's list in `lists` (`tiles + 2` entries).
    starts: Vec<u32>,
    /// The binning's (tile, entry) pairs, per task of the bound pass in the groups' order
    /// (reused from frame to frame).
    task_pairs: Vec<Vec<(u32, u64)>>,
    /// Spheres overlapping more than [`MAX_TILES`] tiles.
    large: Vec<u32>,
    /// Their rectangles (their entries of `rects` are emptied, so a group skips them without
    /// a test).
    large_rects: Vec<Rect>,
    /// Per group, whether it holds a large sphere.
    group_large: Vec<bool>,
    /// Per group, the mask of its small spheres (at most 2×2 pixels, not near the eye
    /// plane), whose entry of `centres` holds their pixels' hits instead ([`small_hits`]), in
    /// the low 32 bits; in the high 32, the mask of its spheres drawn from the group (a
    /// non-empty rectangle, not large).
    group_small: Vec<u64>,
    /// Small spheres in the last frame.
    small: usize,
}

/// The tile grid of a viewport.
#[derive(Clone, Copy)]
struct Grid {
    tx: usize,
    ty: usize,
}

impl Grid {
    fn new(camera: &Camera) -> Grid {
        Grid { tx: (camera.width as usize).div_ceil(TILE), ty: (camera.height as usize).div_ceil(TILE) }
    }

    fn tiles(&self) -> usize {
        self.tx * self.ty
    }
}

impl TileSplat {
    /// A splatter on `threads` threads (0: one per core).
    pub fn new(threads: usize) -> Self {
        TileSplat {
            threads: Threads::new(threads),
            rects: Vec::new(),
            centres: Vec::new(),
            cull: true,
            culled: (0, 0),
            group_rects: Vec::new(),
            lists: Vec::new(),
            starts: Vec::new(),
            task_pairs: Vec::new(),
            large: Vec::new(),
            large_rects: Vec::new(),
            group_large: Vec::new(),
            group_small: Vec::new(),
            small: 0,
        }
    }

    /// The same splatter with occlusion culling on (the default) or off. With it on, a sphere
    /// is skipped in a block of pixels (its 4×2 block, or 8 pixels of a row) when a conservative
    /// lower bound of its hit distances, computed in the bound pass (`√(|c−e|² − r'²) − r'`
    /// less a relative 10⁻⁴ of the distance, with `r'` the widened radius), lies beyond the
    /// depth of every pixel of the block: its hits there could only be farther, so the image
    /// is the same either way (tested); only the time changes.
    pub fn with_culling(mut self, cull: bool) -> Self {
        self.cull = cull;
        self
    }

    /// Of the last frame: the sphere–tile pairs drawn and how many of them occlusion culling
    /// skipped whole (no ray test).
    pub fn culled(&self) -> (u64, u64) {
        self.culled
    }

    /// Splats `camera`'s viewport into `ids` (row-major, resized): the first-hit sample index
    /// per pixel, [`NO_HIT`] where none. `false` if the camera or scene is unusable.
    pub fn splat_ids(&mut self, scene: &Scene, camera: &Camera, ids: &mut Vec<u32>) -> bool {
        let mut img = Image { width: 0, height: 0, pixels: std::mem::take(ids) };
        let ok = begin_frame(scene, camera, &mut img);
        *ids = img.pixels;
        ids.fill(NO_HIT);
        if ok {
            self.draw(scene, camera, ids, |_, id| id);
        }
        ok
    }

    /// Entries of the tile lists of the last frame: group indices (at most
    /// [`MAX_GROUP_TILES`] per group, at most [`MAX_TILES`] per sphere of a group binned by its
    /// spheres' tiles) and large spheres (one each).
    pub fn binned_entries(&self) -> usize {
        self.lists.len() + self.large.len()
    }

    /// Spheres of the last frame drawn from the hits the bound pass found (at most 2×2
    /// pixels, away from the eye plane; most spheres of a frame drawn at half its resolution).
    pub fn small_spheres(&self) -> usize {
        self.small
    }

    /// The number of threads it draws with.
    pub fn threads(&self) -> usize {
        self.threads.count()
    }

    /// Bins and splats the scene, writing `out_of(colors, id)` for every pixel of `out` (`id`:
    /// the pixel's first-hit sample, [`NO_HIT`] where none)
    /// (`width × height` long).
    fn draw(&mut self, scene: &Scene, camera: &Camera, out: &mut [u32], out_of: impl Fn(&[u32], u32) -> u32 + Sync) {
        let view = View::new(camera);
        let grid = Grid::new(camera);
        self.bin(scene, &view, grid);
        let (w, h) = (camera.width as usize, camera.height as usize);
        let (samples, colors) = (&scene.samples[..], &scene.colors[..]);
        let (lists, starts, rects) = (&self.lists[..], &self.starts[..], &self.rects[..]);
        let (pairs, culled) = (AtomicU64::new(0), AtomicU64::new(0));
        let cull = self.cull;
        let (large, group_rects, group_small) = (&self.large[..], &self.group_rects[..], &self.group_small[..]);
        let large_rects = &self.large_rects[..];
        let centres = &self.centres[..];
        let band = |ty: usize, rows: &mut [u32]| {
            let mut buf = TileBuf::new();
            let mut counts = (0u64, 0u64);
            for tx in 0..grid.tx {
                let t = ty * grid.tx + tx;
                let list = &lists[starts[t] as usize..starts[t + 1] as usize];
                let (x0, y0) = (tx * TILE, ty * TILE);
                let tile = Tile { x0, y0, w: TILE.min(w - x0), h: TILE.min(h - y0) };
                let (tw, tt) = (tile.w, TileTest::new(&tile));
                let any_large = large_rects.iter().any(|&r| tt.hits(r));
                if list.is_empty() && !any_large {
                    let empty = out_of(colors, NO_HIT);
                    for row in rows.chunks_mut(w) {
                        row[x0..x0 + tw].fill(empty);
                    }
                    continue;
                }
                let lists = Lists { groups: list, large, large_rects, rects, centres, group_rects, group_small, cull };
                let (p, c) = tile_dispatch(&view, &tile, samples, scene, &lists, &mut buf);
                counts = (counts.0 + p, counts.1 + c);
                for (y, row) in rows.chunks_mut(w).enumerate() {
                    for (p, &id) in row[x0..x0 + tw].iter_mut().zip(&buf.ids[y * TILE..y * TILE + tw]) {
                        *p = out_of(colors, id);
                    }
                }
            }
            pairs.fetch_add(counts.0, Ordering::Relaxed);
            culled.fetch_add(counts.1, Ordering::Relaxed);
        };
        if self.threads.is_serial() {
            out.chunks_mut(TILE * w).enumerate().for_each(|(ty, rows)| band(ty, rows));
        } else {
            self.threads.install(|| out.par_chunks_mut(TILE * w).enumerate().for_each(|(ty, rows)| band(ty, rows)));
        }
        self.culled = (pairs.into_inner(), culled.into_inner());
    }

    /// Steps 1 and 2: every sphere's rectangle, every group's, and the per-tile lists of
    /// groups.
    fn bin(&mut self, scene: &Scene, view: &View, grid: Grid) {
        let samples = &scene.samples[..];
        let n = samples.len();
        let deq = &scene.deq;
        let groups = n.div_ceil(GROUP);
        self.rects.resize(n, NO_RECT);
        self.centres.resize(n, [0.0; 4]);
        self.group_rects.resize(groups, NO_RECT);
        self.group_large.resize(groups, false);
        self.group_small.resize(groups, 0);
        // 1. rectangles, in parallel over runs of whole groups
        let per_task = (groups.div_ceil(self.threads.count() * 8)).max(1);
        let vf = ViewF32::new(view);
        // Each task also lists its groups' (tile, entry) pairs, in the groups' order.
        // (One list when serial: the one task then takes every group. Cleared here too, as a
        // scene without groups runs no task.)
        let tasks = if self.threads.is_serial() { 1 } else { groups.div_ceil(per_task).max(1) };
        self.task_pairs.resize_with(tasks, Vec::new);
        self.task_pairs.iter_mut().for_each(Vec::clear);
        let bound = |c: usize,
                     rects: &mut [Rect],
                     centres: &mut [[f32; 4]],
                     grects: &mut [Rect],
                     glarge: &mut [bool],
                     gsmall: &mut [u64],
                     pairs: &mut Vec<(u32, u64)>| {
            pairs.clear();
            let first = c * per_task;
            let samples = &samples[first * GROUP..first * GROUP + rects.len()];
            let groups = Groups { rects: grects, large: glarge, small: gsmall, first: first as u32 };
            bound_dispatch(view, &vf, deq, samples, rects, centres, groups, grid, pairs);
        };
        if self.threads.is_serial() {
            let pairs = &mut self.task_pairs[0];
            let (r, c, g) = (&mut self.rects, &mut self.centres, &mut self.group_rects);
            bound(0, r, c, g, &mut self.group_large, &mut self.group_small, pairs);
        } else {
            self.threads.install(|| {
                self.rects
                    .par_chunks_mut(per_task * GROUP)
                    .zip(self.centres.par_chunks_mut(per_task * GROUP))
                    .zip(self.group_rects.par_chunks_mut(per_task))
                    .zip(self.group_large.par_chunks_mut(per_task))
                    .zip(self.group_small.par_chunks_mut(per_task))
                    .zip(self.task_pairs.par_iter_mut())
                    .enumerate()
                    .for_each(|(c, (((((r, cs), g), l), sm), p))| bound(c, r, cs, g, l, sm, p))
            });
        }
        self.small = self.group_small.iter().map(|&m| (m as u32).count_ones() as usize).sum();
        // 2. the pairs to per-tile lists (a counting sort, serial: a few tens of thousands of
        // pairs; each tile's list keeps the groups' order), and the large spheres to their own
        // list.
        let nt = grid.tiles();
        self.starts.clear();
        self.starts.resize(nt + 2, 0);
        self.large.clear();
        let task_pairs = &self.task_pairs[..];
        for &(t, _) in task_pairs.iter().flatten() {
            self.starts[t as usize + 1] += 1;
        }
        for t in 0..nt {
            self.starts[t + 1] += self.starts[t];
        }
        self.starts[nt + 1] = self.starts[nt];
        self.lists.resize(self.starts[nt] as usize, 0);
        let mut fill = self.starts[..nt].to_vec();
        for &(t, e) in task_pairs.iter().flatten() {
            let f = &mut fill[t as usize];
            self.lists[*f as usize] = e;
            *f += 1;
        }
        self.large_rects.clear();
        for (g, _) in self.group_large.iter().enumerate().filter(|(_, &l)| l) {
            for i in g * GROUP..(g * GROUP + GROUP).min(n) {
                let r = self.rects[i];
                if !r.is_empty() && r.is_large() {
                    self.large.push(i as u32);
                    self.large_rects.push(r);
                    self.rects[i] = NO_RECT;
                }
            }
        }
    }
}

impl Renderer for TileSplat {
    fn kind(&self) -> RendererKind {
        RendererKind::SplatTiles
    }

    fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) {
        // Every tile writes all its pixels (a tile without spheres the background), so the
        // image is not cleared first.
        if begin_frame_overwritten(scene, camera, out) {
            self.draw(
                scene,
                camera,
                &mut out.pixels,
                |colors, id| {
                    if id == NO_HIT {
                        BACKGROUND
                    } else {
                        shade(colors, id)
                    }
                },
            );
        }
    }
}

#[cfg(test)]
mod tests;
