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

/// The (tile, entry) pairs of group `g` (rectangle `grect`, its spheres' `rects`) into `out`:
/// each tile its rectangle overlaps with the whole group, or, for a group overlapping more
/// than [`MAX_GROUP_TILES`] tiles (in the server's scanline order, the group that wraps from
/// one row's end to the next row's start), [`split_group`]'s runs.
#[inline(always)]
fn group_pairs(g: u32, grect: Rect, rects: &[Rect], grid: Grid, out: &mut Vec<(u32, u64)>) {
    if grect.is_empty() {
        return;
    }
    let (tx0, tx1, ty0, ty1) = grect.tiles();
    if (tx1 - tx0 + 1) * (ty1 - ty0 + 1) > MAX_GROUP_TILES {
        split_group(rects, grid, g, out);
    } else {
        for ty in ty0..=ty1 {
            for tx in tx0..=tx1 {
                out.push(((ty * grid.tx + tx) as u32, g as u64 | (u32::MAX as u64) << 32));
            }
        }
    }
}

/// A group's spheres (but the large and the empty ones) as runs of consecutive spheres whose
/// joint rectangle overlaps at most [`MAX_TILES`] tiles (a run holds at least one sphere, so
/// a group gives at most [`MAX_TILES`] entries per sphere): each tile of each run with the
/// entry (group `g`, the mask of the run's spheres) into `out`. The group that wraps from one
/// scanline's end to the next one's start splits into two runs.
fn split_group(rects: &[Rect], grid: Grid, g: u32, out: &mut Vec<(u32, u64)>) {
    let mut j = 0;
    while j < rects.len() {
        let r = rects[j];
        if r.is_empty() || r.is_large() {
            j += 1;
            continue;
        }
        let (mut run, mut mask) = (r, 1u32 << j);
        j += 1;
        while j < rects.len() {
            let r = rects[j];
            if !r.is_empty() && !r.is_large() {
                let u = run.union(r);
                let (tx0, tx1, ty0, ty1) = u.tiles();
                if (tx1 - tx0 + 1) * (ty1 - ty0 + 1) > MAX_TILES {
                    break;
                }
                (run, mask) = (u, mask | 1 << j);
            }
            j += 1;
        }
        let (tx0, tx1, ty0, ty1) = run.tiles();
        for ty in ty0..=ty1 {
            for tx in tx0..=tx1 {
                out.push(((ty * grid.tx + tx) as u32, g as u64 | (mask as u64) << 32));
            }
        }
    }
}

/// The inclusive pixel ranges `(x0, x1, y0, y1)` whose pixel centres' rays may hit the sphere
/// `(c, r)`, `None` if none can: [`View::bound`]'s tangents from the eye (in f64, the radius
/// widened by a relative 10⁻⁵, far above the f32 rounding of the ray test), but only the pixels
/// whose *centres* lie within them (the earlier splatter's bound also takes every pixel the
/// tangents touch: about 25 pixels instead of 9 for a sphere three pixels wide).
#[inline(always)]
pub(crate) fn tight_bound(view: &View, c: Vec3, r: f32) -> Option<(u32, u32, u32, u32)> {
    view.bound_with(c, r, centre_span)
}

/// `|a|` per lane (`f32::max(a, −a)`).
#[inline(always)]
fn lane_abs<L: Arith>(a: L) -> L {
    a.max(L::splat(0.0) - a)
}

/// [`View`]'s constants in f32, for the bounds of a lane's worth of spheres at once.
pub(crate) struct ViewF32 {
    eye: [f32; 3],
    u: [f32; 3],
    v: [f32; 3],
    w: [f32; 3],
    px_x: f32,
    px_y: f32,
    half_w: f32,
    half_h: f32,
}

impl ViewF32 {
    pub(crate) fn new(v: &View) -> ViewF32 {
        let f = |a: [f64; 3]| [a[0] as f32, a[1] as f32, a[2] as f32];
        ViewF32 {
            eye: [v.eye.x, v.eye.y, v.eye.z],
            u: f(v.u),
            v: f(v.v),
            w: f(v.w),
            px_x: v.px_x as f32,
            px_y: v.px_y as f32,
            half_w: v.half_w as f32,
            half_h: v.half_h as f32,
        }
    }
}

/// The rectangles of `samples` (at most [`GROUP`]) into `rects`, `L::N` (8 or 16) at a time
/// in f32 lanes, and the union of those that are not large; with `centres` as long as
/// `samples`, each sphere's centre less the eye and radius into it, or for a small sphere its
/// hits ([`small_hits`]); and the masks of the small spheres (low 32 bits) and of those drawn
/// from the group (non-empty, not large; high 32 bits). [`tight_bound`]'s tangents with
/// the radius widened by a relative 2·10⁻⁵ of the L1 distance (instead of 10⁻⁵ of the
/// distance: the extra covers the f32 rounding of the bound itself, about 3·10⁻⁷ of the slope)
/// for spheres at least two (widened) radii in front of the eye plane; the others (near,
/// behind, NaN) take [`tight_bound`] in f64. Every instance computes the same values.
#[inline(always)]
pub(crate) fn bound_group<L: BoundLanes>(
    view: &View,
    vf: &ViewF32,
    deq: &Dequantizer,
    samples: &[u64],
    rects: &mut [Rect],
    centres: &mut [[f32; 4]],
) -> (Rect, bool, u64) {
    let (mut u, mut any_large, mut small_all, mut drawn) = (NO_RECT, false, 0u32, 0u32);
    let keep_centres = centres.len() == samples.len();
    for (k, (ss, rs)) in samples.chunks(L::N).zip(rects.chunks_mut(L::N)).enumerate() {
        let [rx, ry, rz, r] = L::decode(deq, vf.eye, ss);
        let cx = rx * L::splat(vf.u[0]) + ry * L::splat(vf.u[1]) + rz * L::splat(vf.u[2]);
        let cy = rx * L::splat(vf.v[0]) + ry * L::splat(vf.v[1]) + rz * L::splat(vf.v[2]);
        let cz = rx * L::splat(vf.w[0]) + ry * L::splat(vf.w[1]) + rz * L::splat(vf.w[2]);
        let rr = r + L::splat(2e-5) * (lane_abs(rx) + lane_abs(ry) + lane_abs(rz) + r);
        let far = cz.simd_gt(L::splat(2.0) * rr);
        let denom = cz * cz - rr * rr;
        let inv = L::splat(1.0) / denom;
        let (sx, sy) = ((cx * cx + denom).sqrt(), (cy * cy + denom).sqrt());
        let (xl, xh) = ((cx * cz - rr * sx) * inv, (cx * cz + rr * sx) * inv);
        let (yl, yh) = ((cy * cz - rr * sy) * inv, (cy * cz + rr * sy) * inv);
        let x0 = xl * L::splat(vf.px_x) + L::splat(vf.half_w);
        let x1 = xh * L::splat(vf.px_x) + L::splat(vf.half_w);
        let y0 = L::splat(vf.half_h) - yh * L::splat(vf.px_y);
        let y1 = L::splat(vf.half_h) - yl * L::splat(vf.px_y);
        // [`centre_span`] in f32 lanes, widened from 0.01 to 0.02 pixel so that the f32
        // rounding of the subtraction (≤ 0.001 pixel below 2¹⁴) never narrows it: the span
        // holds [`centre_span`]'s of the same bound.
        let (ax, bx) = (x0 - L::splat(0.52), x1 - L::splat(0.48));
        let (ay, by) = (y0 - L::splat(0.52), y1 - L::splat(0.48));
        let (nw, nh) = (L::splat(view.width as f32), L::splat(view.height as f32));
        let zero = L::splat(0.0);
        let ok_v = far
            & ax.simd_le(bx)
            & bx.simd_ge(zero)
            & ax.simd_lt(nw)
            & ay.simd_le(by)
            & by.simd_ge(zero)
            & ay.simd_lt(nh);
        // The integer spans in lanes (`BoundLanes::spans`: `ceil_clamped` and the truncating
        // clamp, for the lanes of `ok`, whose values lie in its domain).
        let (xs0, xs1) = L::spans(ax.fast_max(L::splat(-1.0)), bx.fast_min(nw), view.width - 1);
        let (ys0, ys1) = L::spans(ay.fast_max(L::splat(-1.0)), by.fast_min(nh), view.height - 1);
        let live = (1u32 << ss.len()) - 1;
        let (far, ok) = (far.to_bitmask(), ok_v.to_bitmask());
        // The lanes of `ok` with a non-empty span get their rectangle, the others the empty
        // one; with the large ones, the others, and the others' union.
        let tile_log2 = TILE.trailing_zeros();
        let mut rl = L::rects(ok, [&xs0, &xs1, &ys0, &ys1], tile_log2, MAX_TILES as i32);
        if keep_centres {
            // Spheres of at most 2×2 pixels (lanes of `ok`, non-empty spans at most two
            // wide): their pixels' hits now, `L::N` spheres per lane operation, in place of
            // their centres (`small_hits`); the others' centres.
            let (fx0, fx1) = (L::from_ints16(&xs0), L::from_ints16(&xs1));
            let (fy0, fy1) = (L::from_ints16(&ys0), L::from_ints16(&ys1));
            let (wx, wy) = (fx1 - fx0, fy1 - fy0);
            let one = L::splat(1.0);
            let small_v = ok_v & wx.simd_ge(zero) & wx.simd_le(one) & wy.simd_ge(zero) & wy.simd_le(one);
            let small = small_v.to_bitmask() & live;
            let mut c = [rx, ry, rz, r];
            if small != 0 {
                let hits = small_hits(&view.basis, c, fx0, fy0, small_v, wx.simd_gt(zero), wy.simd_gt(zero));
                for (c, h) in c.iter_mut().zip(hits) {
                    *c = small_v.select(h, *c);
                }
            }
            let n = ss.len();
            L::store_records(c, &mut centres[L::N * k..L::N * k + n]);
            small_all |= small << (L::N * k);
        }
        // Near the eye plane, behind it, or NaN (rare): the f64 bound, and the same rules.
        let mut slow = !ok & !far & live;
        let mut union = Rect::from_bits(rl.union);
        while slow != 0 {
            let l = slow.trailing_zeros() as usize;
            slow &= slow - 1;
            if let Some((x0, x1, y0, y1)) = tight_bound(view, deq.center(ss[l]), deq.radius(ss[l])) {
                let r = Rect { x0: x0 as u16, y0: y0 as u16, x1: x1 as u16, y1: y1 as u16 };
                rl.bits[l] = r.bits();
                if r.is_large() {
                    rl.large |= 1 << l;
                } else {
                    rl.drawn |= 1 << l;
                    union = union.union(r);
                }
            }
        }
        // Whole chunks as fixed-size copies (a copy of `rs.len()` words became a call of
        // `memcpy` per chunk).
        if rs.len() == 16 && L::N == 16 {
            if let Some(r16) = rs.first_chunk_mut::<16>() {
                *r16 = rl.bits.map(Rect::from_bits);
            }
        } else if rs.len() == 8 && L::N == 8 {
            if let Some(r8) = rs.first_chunk_mut::<8>() {
                *r8 = core::array::from_fn(|l| Rect::from_bits(rl.bits[l]));
            }
        } else {
            for (rect, &b) in rs.iter_mut().zip(&rl.bits) {
                *rect = Rect::from_bits(b);
            }
        }
        any_large |= rl.large & live != 0;
        drawn |= (rl.drawn & live) << (L::N * k);
        u = u.union(union);
    }
    (u, any_large, small_all as u64 | (drawn as u64) << 32)
}

/// The hits of a lane's worth of spheres (centres less the eye and radii `c`, the lanes of the mask
/// `small`) on the pixels of their 2×2 windows at `(x0, y0)` (pixel indices as `f32`; the
/// masks `wide`, `tall`: the rectangle's second column, row), as [`splat_sphere`] would find
/// them: per window pixel `(x0 + dx, y0 + dy)` (result `dx + 2·dy`), per lane, the distance
/// [`sphere_hits`] gives on that pixel's ray ([`ray_dirs`] of the same pixel centre, the same
/// operations, so the same bits), NaN where it misses or the pixel lies outside the rectangle
/// (which no comparison takes).
#[inline(always)]
fn small_hits<L: Arith>(
    b: &volwarp_core::camera::RayBasis,
    c: [L; 4],
    x0: L,
    y0: L,
    small: L,
    wide: L,
    tall: L,
) -> [L; 4] {
    let (px, py) = (x0 + L::splat(0.5), y0 + L::splat(0.5));
    let (px1, py1) = (px + L::splat(1.0), py + L::splat(1.0));
    let mut out = [L::splat(f32::NAN); 4];
    let windows = [(px, py, small), (px1, py, small & wide), (px, py1, small & tall), (px1, py1, small & wide & tall)];
    for (o, (x, y, on)) in out.iter_mut().zip(windows) {
        if on.any() {
            *o = lanes::sphere_hits_lanes(&ray_dirs(b, x, y), c, on);
        }
    }
    out
}

/// Per group of a run, what the bound pass finds (`TileSplat`'s fields of the same names), and
/// the index of the run's first group.
struct Groups<'a> {
    rects: &'a mut [Rect],
    large: &'a mut [bool],
    small: &'a mut [u64],
    first: u32,
}

/// [`bound_group`] for a run of whole groups (`samples`, their `rects` and `centres`), and each
/// group's (tile, entry) pairs ([`group_pairs`]) into `pairs`: one call per run, so that the
/// kernel's constants are set up once, not per group.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn bound_run<L: BoundLanes>(
    view: &View,
    vf: &ViewF32,
    deq: &Dequantizer,
    samples: &[u64],
    rects: &mut [Rect],
    centres: &mut [[f32; 4]],
    groups: Groups,
    grid: Grid,
    pairs: &mut Vec<(u32, u64)>,
) {
    let each = rects.chunks_mut(GROUP).zip(centres.chunks_mut(GROUP)).zip(samples.chunks(GROUP));
    let per_group = groups.rects.iter_mut().zip(groups.large.iter_mut()).zip(groups.small.iter_mut());
    for (g, (((rects, centres), samples), ((grect, glarge), gsmall))) in each.zip(per_group).enumerate() {
        (*grect, *glarge, *gsmall) = bound_group::<L>(view, vf, deq, samples, rects, centres);
        group_pairs(groups.first + g as u32, *grect, rects, grid, pairs);
    }
}

lanes::dispatch! {
    /// [`bound_run`] on the best lanes this CPU has (sixteen with AVX-512, else eight).
    fn bound_dispatch / bound_avx2 / bound_avx512 => bound_run(
        view: &View,
        vf: &ViewF32,
        deq: &Dequantizer,
        samples: &[u64],
        rects: &mut [Rect],
        centres: &mut [[f32; 4]],
        groups: Groups,
        grid: Grid,
        pairs: &mut Vec<(u32, u64)>,
    )
}

/// The pixels `i < n` whose centre `i + 0.5` lies in `[a, b]`, widened by 0.01 pixel, as an
/// inclusive range; `None` if there are none (or `a`, `b` are NaN).
#[inline(always)]
fn centre_span(a: f64, b: f64, n: u32) -> Option<(u32, u32)> {
    // Clamp first (NaN fails the comparisons and gives `None`), then floor and ceil by
    // truncation of values ≥ −1.
    let lo = (a - 0.51).max(-1.0);
    let hi = (b - 0.49).min(n as f64);
    if !(lo <= hi) || !(hi >= 0.0) || !(lo < n as f64) {
        return None;
    }
    let l = lo as i64; // trunc; ceil below
    let l = if (l as f64) < lo { l + 1 } else { l }.max(0);
    let h = (hi as i64).min(n as i64 - 1); // hi ≥ 0: trunc is floor
    if l > h {
        return None;
    }
    Some((l as u32, h as u32))
}

/// Whether a rectangle overlaps one tile, as four 16-bit comparisons in one 64-bit
/// subtraction (SWAR): every coordinate is below 2¹⁵ ([`MAX_VIEWPORT`], [`NO_RECT`]), so with
/// bit 15 of each field of the minuend set no field borrows from the next, and a field's bit
/// 15 survives exactly where the minuend's field is at least the subtrahend's.
#[derive(Clone, Copy)]
struct TileTest {
    /// The tile's last column and row in the low fields.
    last: u64,
    /// The tile's first column and row in the high fields.
    first: u64,
}

/// Bit 15 of each 16-bit field.
const FIELD_SIGNS: u64 = 0x8000_8000_8000_8000;
/// The low two 16-bit fields.
const LOW_FIELDS: u64 = 0xFFFF_FFFF;

impl TileTest {
    fn new(tile: &Tile) -> TileTest {
        let (x1, y1) = ((tile.x0 + tile.w - 1) as u64, (tile.y0 + tile.h - 1) as u64);
        TileTest { last: x1 | y1 << 16, first: (tile.x0 as u64) << 32 | (tile.y0 as u64) << 48 }
    }

    /// Whether `r` overlaps the tile: `x0 ≤ last x`, `y0 ≤ last y`, `x1 ≥ first x`,
    /// `y1 ≥ first y` (false for an empty `r`, whose `x0` lies beyond every tile).
    #[inline(always)]
    fn hits(&self, r: Rect) -> bool {
        let a = r.bits();
        let minuend = self.last | (a & !LOW_FIELDS) | FIELD_SIGNS;
        let subtrahend = (a & LOW_FIELDS) | self.first;
        (minuend - subtrahend) & FIELD_SIGNS == FIELD_SIGNS
    }

    /// Whether a non-empty `r` lies inside the tile.
    #[inline(always)]
    fn contains(&self, r: Rect) -> bool {
        let (x1, y1) = (self.last as u16, (self.last >> 16) as u16);
        let (x0, y0) = ((self.first >> 32) as u16, (self.first >> 48) as u16);
        r.x0 >= x0 && r.y0 >= y0 && r.x1 <= x1 && r.y1 <= y1
    }

    /// The spheres of `rects` (at most 32) that overlap the tile, as bits.
    #[inline(always)]
    fn hits_of(&self, rects: &[Rect]) -> u32 {
        let mut m = 0u32;
        for (j, &r) in rects.iter().enumerate().take(32) {
            m |= (self.hits(r) as u32) << j;
        }
        m
    }
}

/// A tile's place in the image.
struct Tile {
    x0: usize,
    y0: usize,
    w: usize,
    h: usize,
}

/// A tile's local buffers: its pixels' keys and unit ray directions (three planes of
/// `TILE + 1` rows of [`STRIDE`] floats; padding holds zeros or the directions of pixels past
/// the tile, and is never tested).
struct TileBuf {
    /// Per pixel (row stride [`TILE`], one row and eight pixels of padding), the distance of
    /// the nearest hit so far, `+∞` where none.
    depth: Box<[f32; KEYS]>,
    /// Per pixel, the sample of that hit, [`NO_HIT`] where none: with `depth`, the pixel's
    /// key `(t, id)` ([`TileBuf::key`]).
    ids: Box<[u32; KEYS]>,
    dirs: Box<[f32; 3 * PLANE]>,
}

/// Length of a tile's depth and id planes.
const KEYS: usize = (TILE + 1) * TILE + 8;

impl TileBuf {
    fn new() -> TileBuf {
        // Fixed lengths, so that the kernel's indices (below `TILE` by construction, masked to
        // show it) need no bounds checks.
        TileBuf {
            depth: Box::new([f32::INFINITY; KEYS]),
            ids: Box::new([NO_HIT; KEYS]),
            dirs: Box::new([0.0; 3 * PLANE]),
        }
    }
}

/// The key of a pixel whose planes hold `(t, id)`.
#[inline(always)]
fn key_of(t: f32, id: u32) -> u64 {
    if id == NO_HIT {
        EMPTY
    } else {
        key(t, id)
    }
}

/// The first eight floats of `s` (at least eight long): one bounds check, one load.
#[inline(always)]
fn load<L: Lanes>(s: &[f32]) -> L {
    match s.first_chunk::<8>() {
        Some(a) => L::new(*a),
        None => L::splat(0.0),
    }
}

/// Four floats from `s` and four from `s[STRIDE..]`: a 4×2 block of a direction plane.
#[inline(always)]
fn load_4x2<L: Lanes>(s: &[f32]) -> L {
    L::new(quad::<f32, STRIDE>(s))
}

/// Four values from `s` and four from `s[S..]` (a 4×2 block of a plane of row stride `S`);
/// zeros if `s` is too short.
#[inline(always)]
fn quad<T: Copy + Default, const S: usize>(s: &[T]) -> [T; 8] {
    match (s.first_chunk::<4>(), s.get(S..).and_then(|r| r.first_chunk::<4>())) {
        (Some(a), Some(b)) => [a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3]],
        _ => [T::default(); 8],
    }
}

/// The first eight values of `s`, zeros if it is shorter.
#[inline(always)]
fn eight<T: Copy + Default>(s: &[T]) -> [T; 8] {
    s.first_chunk::<8>().copied().unwrap_or([T::default(); 8])
}

/// Writes `a` where [`quad`] (with `S` = [`TILE`]) or [`eight`] read it.
#[inline(always)]
fn put<T: Copy>(s: &mut [T], a: [T; 8], is_quad: bool) {
    if is_quad {
        if let Some(r) = s.first_chunk_mut::<4>() {
            r.copy_from_slice(&a[..4]);
        }
        if let Some(r) = s.get_mut(TILE..).and_then(|r| r.first_chunk_mut::<4>()) {
            r.copy_from_slice(&a[4..]);
        }
    } else if let Some(r) = s.first_chunk_mut::<8>() {
        *r = a;
    }
}

/// Step 3 for one tile: its directions, then every sphere of `list` and every sphere of
/// `large` that overlaps it, into `buf.keys`.
#[inline(always)]
fn splat_tile<L: Lanes>(
    view: &View,
    tile: &Tile,
    samples: &[u64],
    scene: &Scene,
    lists: &Lists,
    buf: &mut TileBuf,
) -> (u64, u64) {
    // Rows of sixteen for wide spheres: from the AVX2 instance, where the CPU has AVX-512.
    #[cfg(target_arch = "x86_64")]
    let wide = L::AVX2 && lanes::use_avx512();
    #[cfg(not(target_arch = "x86_64"))]
    let wide = false;
    buf.depth.fill(f32::INFINITY);
    buf.ids.fill(NO_HIT);
    // The centres are stored less the eye (exactly `sphere_hits`' `c − o`), so the rays start
    // at the origin.
    let o = [0.0; 3];
    let lane = L::new([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]);
    let lane4 = L::new([0.0, 1.0, 2.0, 3.0, 0.0, 1.0, 2.0, 3.0]);
    let row2 = L::new([0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0]);
    let (tx1, ty1) = (tile.x0 + tile.w - 1, tile.y0 + tile.h - 1);
    let ties = if scene.nodes.is_empty() { Ties::Sorted(samples) } else { Ties::Index };
    let k = Kernel { ties, centres: lists.centres, o, lane, lane4, row2, tx1, ty1, cull: lists.cull, wide };
    let (mut pairs, mut culled) = (0u64, 0u64);
    let rects = lists.rects;
    let n = samples.len();
    let tt = TileTest::new(tile);
    // The pixels' ray directions, made before the first sphere that needs them (small
    // spheres bring their hits).
    let mut dirs_ready = false;
    for (at, &e) in lists.groups.iter().enumerate() {
        // The group two entries ahead: its centres and rectangles on their way to the cache.
        if let Some(&ahead) = lists.groups.get(at + 2) {
            let a = (ahead as u32 as usize) * GROUP;
            prefetch(lists.centres.get(a..a + GROUP).unwrap_or(&[]));
            prefetch(rects.get(a..a + GROUP).unwrap_or(&[]));
        }
        let g = e as u32 as usize;
        if !tt.hits(lists.group_rects[g]) {
            continue;
        }
        let first = g * GROUP;
        // Large spheres' rectangles are empty here (drawn from `large` below).
        let group = &rects[first..(first + GROUP).min(n)];
        let masks = lists.group_small[g];
        // A group inside the tile (most, with 64-pixel tiles) needs no test per sphere.
        let inside = tt.contains(lists.group_rects[g]);
        let hits = if inside { (masks >> 32) as u32 } else { tt.hits_of(group) };
        let hits = hits & (e >> 32) as u32;
        // The group's colors (two or three cache lines) on their way to the cache, for when
        // the tile's pixels are shaded.
        if hits != 0 {
            prefetch(scene.colors.get(first..(first + GROUP).min(n)).unwrap_or(&[]));
        }
        let small = masks as u32;
        let (mut few, mut other) = (hits & small, hits & !small);
        pairs += few.count_ones() as u64;
        let whole = (group.first_chunk::<GROUP>(), lists.centres.get(first..).and_then(|c| c.first_chunk::<GROUP>()));
        match whole {
            // A whole group inside the tile (most): no test per sphere, no bounds checks.
            (Some(rs), Some(cs)) if inside => {
                while few != 0 {
                    let j = few.trailing_zeros() as usize & (GROUP - 1);
                    few &= few - 1;
                    let r = rs[j];
                    let p = ((r.y0 as usize - tile.y0) * TILE + (r.x0 as usize - tile.x0)) & (TILE * TILE - 1);
                    splat_small_at(&mut buf.depth, &mut buf.ids, p, cs[j], (first + j) as u32, k.ties);
                }
            }
            _ => {
                while few != 0 {
                    let j = few.trailing_zeros() as usize;
                    few &= few - 1;
                    splat_small(&k, tile, group[j], (first + j) as u32, buf);
                }
            }
        }
        if other != 0 && !dirs_ready {
            tile_dirs::<L>(view, tile, buf);
            dirs_ready = true;
        }
        while other != 0 {
            let j = other.trailing_zeros() as usize;
            other &= other - 1;
            pairs += 1;
            culled += splat_sphere(&k, tile, group[j], (first + j) as u32, buf) as u64;
        }
    }
    for (&i, &r) in lists.large.iter().zip(lists.large_rects) {
        if tt.hits(r) {
            if !dirs_ready {
                tile_dirs::<L>(view, tile, buf);
                dirs_ready = true;
            }
            pairs += 1;
            culled += splat_sphere(&k, tile, r, i, buf) as u64;
        }
    }
    (pairs, culled)
}

/// A tile's unit ray directions into `buf.dirs`: exactly `RayBasis::dir` (pixel centres
/// `x + l + 0.5`, exact in f32).
#[inline(always)]
fn tile_dirs<L: Lanes>(view: &View, tile: &Tile, buf: &mut TileBuf) {
    let b = &view.basis;
    let lane_c = L::new([0.5, 1.5, 2.5, 3.5, 4.5, 5.5, 6.5, 7.5]);
    for y in 0..tile.h {
        let py = L::splat((tile.y0 + y) as f32 + 0.5);
        for x in (0..tile.w).step_by(8) {
            let d = ray_dirs(b, L::splat((tile.x0 + x) as f32) + lane_c, py);
            // All eight lanes, also past a narrow tile's last column (into the row's padding):
            // those pixels are never active, so their directions are never used.
            for (a, d) in d.iter().enumerate() {
                let at = a * PLANE + (y & (TILE - 1)) * STRIDE + (x & (TILE - 1));
                if let Some(s) = buf.dirs.get_mut(at..at + 8) {
                    s.copy_from_slice(&d.to_array());
                }
            }
        }
    }
}

/// A small sphere `i` (rectangle `r`, at most 2×2 pixels) into a tile's keys from the hits
/// the bound pass found on its window's four pixels ([`small_hits`], NaN for none): per
/// pixel, without a branch, a nearer hit takes it; a hit at equal depth (rare) takes
/// [`small_ties`]. The four pixels are read and written one by one (two spheres in a row
/// usually share pixels: a wider load over a narrower store would wait on store forwarding).
#[inline(always)]
fn splat_small<L>(k: &Kernel<'_, L>, tile: &Tile, r: Rect, i: u32, buf: &mut TileBuf) {
    let t4 = k.centres[i as usize];
    let (depth, ids): (&mut [f32; KEYS], &mut [u32; KEYS]) = (&mut buf.depth, &mut buf.ids);
    let (x0, y0) = (r.x0 as usize, r.y0 as usize);
    if x0 >= tile.x0 && y0 >= tile.y0 && (r.x1 as usize) <= k.tx1 && (r.y1 as usize) <= k.ty1 {
        // Inside the tile: the window's pixels `p`, `p + 1`, `p + TILE`, `p + TILE + 1` lie
        // in the planes (a window pixel past the rectangle, in the next row or the padding
        // row, has no hit and keeps its key).
        let p = ((y0 - tile.y0) * TILE + (x0 - tile.x0)) & (TILE * TILE - 1);
        splat_small_at(depth, ids, p, t4, i, k.ties);
    } else {
        // Across the tile's border (rare): the window's pixels inside it.
        for (l, &t) in t4.iter().enumerate() {
            let (x, y) = (x0 + (l & 1), y0 + (l >> 1));
            if x < tile.x0 || y < tile.y0 || x > k.tx1 || y > k.ty1 {
                continue;
            }
            let q = ((y - tile.y0) * TILE + (x - tile.x0)) & (TILE * TILE - 1);
            if keep_pixel(&mut depth[q], &mut ids[q], t, i) {
                small_ties(depth, ids, [q; 4], &[t, f32::NAN, f32::NAN, f32::NAN], i, k.ties);
            }
        }
    }
}

/// [`splat_small`] of a window inside the tile, at pixel `p` (`y·TILE + x`, below
/// `TILE²`).
#[inline(always)]
fn splat_small_at(depth: &mut [f32; KEYS], ids: &mut [u32; KEYS], p: usize, t4: [f32; 4], i: u32, ties: Ties) {
    let (Some(d), Some(id)) = (depth.get_mut(p..p + TILE + 2), ids.get_mut(p..p + TILE + 2)) else {
        return;
    };
    // Unrolled, with the offsets as constants: no bounds checks, nothing through memory.
    let tie = keep_pixel(&mut d[0], &mut id[0], t4[0], i)
        | keep_pixel(&mut d[1], &mut id[1], t4[1], i)
        | keep_pixel(&mut d[TILE], &mut id[TILE], t4[2], i)
        | keep_pixel(&mut d[TILE + 1], &mut id[TILE + 1], t4[3], i);
    if tie {
        small_ties(depth, ids, [p, p + 1, p + TILE, p + TILE + 1], &t4, i, ties);
    }
}

/// One pixel of [`splat_small`]: a hit `t` nearer than the pixel's depth `d` takes it, by
/// selects, not branches (which would guess wrong about half the time); whether `t` equals
/// `d` (a tie for [`small_ties`]; never for a NaN, no hit).
#[inline(always)]
fn keep_pixel(d: &mut f32, id: &mut u32, t: f32, i: u32) -> bool {
    let win = t < *d;
    let tie = t == *d;
    *d = std::hint::select_unpredictable(win, t, *d);
    *id = std::hint::select_unpredictable(win, i, *id);
    tie
}

/// [`splat_small`]'s pixels `q[l]` whose key (after the depth test) has the hit `t4[l]`'s
/// distance: the smaller key of `(t4[l], i)` and the pixel's, the tie rule as [`keep_ties`]
/// applies it (a pixel the hit just took holds `(t4[l], i)` itself, and keeps it).
#[inline(never)]
#[cold]
fn small_ties(depth: &mut [f32; KEYS], ids: &mut [u32; KEYS], q: [usize; 4], t4: &[f32; 4], i: u32, ties: Ties) {
    for (&q, &t) in q.iter().zip(t4) {
        if t == depth[q] {
            keep_ties(&mut depth[q..=q], &mut ids[q..=q], 1, &[t], i, false, ties);
        }
    }
}

/// What a tile reads of the binning.
struct Lists<'a> {
    /// The groups binned to the tile (index and mask, as in `TileSplat::lists`).
    groups: &'a [u64],
    large: &'a [u32],
    large_rects: &'a [Rect],
    rects: &'a [Rect],
    /// Per sphere, its centre less the eye and its radius (`TileSplat::centres`).
    centres: &'a [[f32; 4]],
    group_rects: &'a [Rect],
    /// Per group, the masks of its small and its drawn spheres (`TileSplat::group_small`).
    group_small: &'a [u64],
    /// Whether to skip spheres hidden in a block ([`TileSplat::with_culling`]).
    cull: bool,
}

/// The per-tile constants of [`splat_sphere`].
struct Kernel<'a, L> {
    ties: Ties<'a>,
    /// Per sphere, its centre less the eye and its radius.
    centres: &'a [[f32; 4]],
    /// The rays' origin: zero, as the centres are less the eye.
    o: [f32; 3],
    lane: L,
    lane4: L,
    row2: L,
    tx1: usize,
    ty1: usize,
    cull: bool,
    /// Whether spheres wider than eight pixels take rows of sixteen ([`rows16`]; set where the
    /// CPU has AVX-512).
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    wide: bool,
}

/// One sphere `i` into a tile's keys (no closures here: they would be compiled without the
/// caller's AVX2 target feature); `true` if culling skipped every block of it.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn splat_sphere<L: Lanes>(k: &Kernel<'_, L>, tile: &Tile, r: Rect, i: u32, buf: &mut TileBuf) -> bool {
    let TileBuf { depth, ids, dirs } = buf;
    let (depth, ids, dirs): (&mut [f32; KEYS], &mut [u32; KEYS], &[f32; 3 * PLANE]) = (depth, ids, dirs);
    let mut all_culled = true;
    // The rectangle clipped to the tile, in tile coordinates.
    // (Masked with `TILE − 1`, which keeps them: it tells the compiler they lie in the tile.)
    let x0 = ((r.x0 as usize).max(tile.x0) - tile.x0) & (TILE - 1);
    let x1 = ((r.x1 as usize).min(k.tx1) - tile.x0) & (TILE - 1);
    let y0 = ((r.y0 as usize).max(tile.y0) - tile.y0) & (TILE - 1);
    let y1 = ((r.y1 as usize).min(k.ty1) - tile.y0) & (TILE - 1);
    let [x, y, z, rad] = k.centres[i as usize];
    let c = Vec3::new(x, y, z);
    if x1 - x0 < 4 {
        // 4×2 blocks: lane l is pixel (x0 + l % 4, y + l / 4).
        let wmask = k.lane4.simd_lt(L::splat((x1 - x0 + 1) as f32));
        for y in (y0..=y1).step_by(2) {
            let active = wmask & k.row2.simd_lt(L::splat((y1 - y + 1).min(2) as f32));
            all_culled = false;
            let at = y * STRIDE + x0;
            let d = [load_4x2(&dirs[at..]), load_4x2(&dirs[PLANE + at..]), load_4x2(&dirs[2 * PLANE + at..])];
            if let Some((t, m)) = sphere_hits(&k.o, &d, c, rad, active) {
                keep(depth, ids, m, t, i, y * TILE + x0, true, k.ties);
            }
        }
    } else {
        // Culling: a block of lanes whose depths all lie nearer than `near` is skipped.
        let near_t = if k.cull { near_distance(&k.o, c, rad) } else { 0.0 };
        #[cfg(target_arch = "x86_64")]
        if k.wide && x1 - x0 >= 8 {
            // Rows of sixteen: a sphere 9 to 16 pixels wide takes one block per row, not two.
            let rect = [x0, x1, y0, y1];
            // SAFETY: `wide` is set only where the CPU has AVX2, AVX-512 F and DQ
            // (`use_avx512`).
            return unsafe { rows16(dirs, depth, ids, rect, (c, rad, i), near_t, k.cull, k.ties) };
        }
        let near = L::splat(near_t);
        for y in y0..=y1 {
            for x in (x0..=x1).step_by(8) {
                let active = k.lane.simd_lt(L::splat((x1 - x + 1).min(8) as f32));
                if k.cull && !(active & near.simd_le(depth_at(depth, y * TILE + x, false))).any() {
                    continue;
                }
                all_culled = false;
                let at = y * STRIDE + x;
                let d = [load(&dirs[at..]), load(&dirs[PLANE + at..]), load(&dirs[2 * PLANE + at..])];
                if let Some((t, m)) = sphere_hits(&k.o, &d, c, rad, active) {
                    keep(depth, ids, m, t, i, y * TILE + x, false, k.ties);
                }
            }
        }
    }
    all_culled
}

/// A distance that no hit `t` of [`sphere_hits`] from `o` on the sphere `(c, r)` can be nearer
/// than (0 if the sphere is within two radii of the eye). With `oc = c − o` as `sphere_hits`
/// computes it, a hitting ray passes within `r' = r·(1 + 10⁻⁵) + 10⁻⁵·|oc|` of the centre
/// once rounding is counted (its f32 errors are a few 10⁻⁸·|oc|), so its exact distances are at
/// least `√(|oc|² − r'²) − r'` and the f32 ones less at most ≈ 10⁻⁶·|oc|; the result keeps a
/// margin of 10⁻⁴·|oc|.
#[inline(always)]
pub(crate) fn near_distance(o: &[f32; 3], c: Vec3, r: f32) -> f32 {
    let (x, y, z) = (c.x - o[0], c.y - o[1], c.z - o[2]);
    let d2 = x * x + y * y + z * z;
    let d = d2.sqrt();
    let rr = r + 1e-5 * (r + d);
    if d > 2.0 * rr {
        (d2 - rr * rr).sqrt() - rr - 1e-4 * d
    } else {
        0.0
    }
}

/// The depths of a 4×2 block (`is_quad`) or of 8 pixels of a row at `at` (`+∞` if out of the
/// plane, which never culls).
#[inline(always)]
fn depth_at<L: Lanes>(depth: &[f32; KEYS], at: usize, is_quad: bool) -> L {
    match depth.get(at..) {
        Some(s) if s.len() >= TILE + 8 => L::new(if is_quad { quad::<f32, TILE>(s) } else { eight(s) }),
        _ => L::splat(f32::INFINITY),
    }
}

/// The depth test of the hit lanes `m` (distances `t`) of sphere `i`: lane `l` is pixel
/// `base + l` of a row, or of a 4×2 block (`is_quad`) `base + (l / 4)·TILE + l % 4`. In lanes:
/// a hit nearer than the pixel's depth takes the pixel (its key is then smaller whatever the
/// ids), and the eight lanes are written back without branches (the planes are padded for the
/// lanes past the tile, which write back what they read); a hit at *equal* depth takes
/// [`keep_ties`] (the tie rule, rare).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn keep<L: Lanes>(
    depth: &mut [f32; KEYS],
    ids: &mut [u32; KEYS],
    m: L,
    t: L,
    i: u32,
    base: usize,
    is_quad: bool,
    ties: Ties,
) {
    let (Some(ds), Some(is)) = (depth.get_mut(base..base + TILE + 8), ids.get_mut(base..base + TILE + 8)) else {
        return;
    };
    let (d, id) = if is_quad {
        (L::new(quad::<f32, TILE>(ds)), L::new_u(quad::<u32, TILE>(is)))
    } else {
        (L::new(eight(ds)), L::new_u(eight(is)))
    };
    let win = m & t.simd_lt(d);
    let tie = (m & t.simd_eq(d)).to_bitmask();
    put(ds, win.select(t, d).to_array(), is_quad);
    put(is, L::u_to_array(win.select_u(L::splat_u(i), id)), is_quad);
    if tie != 0 {
        keep_ties(ds, is, tie, &t.to_array(), i, is_quad, ties);
    }
}

/// [`keep`]'s lanes `bits` whose hit is at the pixel's depth: the smaller key wins (core's tie
/// rule, or the built scene's order for an unbuilt scene).
#[inline(never)]
#[cold]
fn keep_ties(ds: &mut [f32], is: &mut [u32], bits: u32, t: &[f32], i: u32, is_quad: bool, ties: Ties) {
    for (l, &t) in t.iter().enumerate() {
        if bits >> l & 1 == 0 {
            continue;
        }
        let p = if is_quad { (l >> 2) * TILE + (l & 3) } else { l };
        let (k, old) = (key(t, i), key_of(ds[p], is[p]));
        let new = match ties {
            Ties::Sorted(samples) if (k ^ old) >> 32 == 0 => {
                if sorted_before(samples, i, old as u32) {
                    k
                } else {
                    old
                }
            }
            _ => k.min(old),
        };
        if let Some(id) = key_prim(new) {
            (ds[p], is[p]) = (f32::from_bits((new >> 32) as u32), id);
        }
    }
}

/// How equal distances are broken.
#[derive(Clone, Copy)]
pub(crate) enum Ties<'a> {
    /// By sample index (core's tie rule on the scene as given).
    Index,
    /// The samples (of an unbuilt scene, in frame order) as the LBVH build would order them:
    /// by `(Morton code, index)`, so the same sphere wins as in the built scene.
    Sorted(&'a [u64]),
}

/// Whether sample `a` comes before sample `b` in the built scene's order (`(code, index)`,
/// the stable sort of the build).
#[inline(never)]
#[cold]
pub(crate) fn sorted_before(samples: &[u64], a: u32, b: u32) -> bool {
    let code = |i: u32| samples.get(i as usize).map_or(u64::MAX, |&s| code_of_sample(s));
    (code(a), a) < (code(b), b)
}

lanes::dispatch! {
    /// [`splat_tile`] on the best lanes this CPU has: AVX2 widens the vectors, and where the
    /// CPU has AVX-512 spheres wider than eight pixels take rows of sixteen ([`rows16`], the
    /// only function compiled with AVX-512: the whole kernel compiled so drew the small
    /// spheres 5 % slower). The operations, and so the image, stay the same.
    fn tile_dispatch / tile_avx2 => splat_tile(
        view: &View,
        tile: &Tile,
        samples: &[u64],
        scene: &Scene,
        lists: &Lists,
        buf: &mut TileBuf,
    ) -> (u64, u64)
}

/// A sphere wider than eight pixels (`(c, r)`, sample `i`) over the rows `y0..=y1` of its
/// rectangle clipped to the tile (`rect = [x0, x1, y0, y1]`, tile coordinates), sixteen pixels
/// per block, as [`splat_sphere`]'s row blocks test eight: the cull test against the near
/// distance `near`, [`sphere_hits`] in sixteen lanes, the depth test with masked stores of the
/// winning lanes, [`keep_ties`] for equal depths. The same operations per lane, so the same
/// image; `true` if culling skipped every block. One call per sphere.
///
/// # Safety
/// The CPU must support AVX2, AVX-512 F and DQ.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f,avx512dq")]
#[inline(never)]
#[allow(clippy::too_many_arguments)]
unsafe fn rows16(
    dirs: &[f32; 3 * PLANE],
    depth: &mut [f32; KEYS],
    ids: &mut [u32; KEYS],
    rect: [usize; 4],
    sphere: (Vec3, f32, u32),
    near: f32,
    cull: bool,
    ties: Ties,
) -> bool {
    use lanes::Avx512;
    // SAFETY: the caller guarantees AVX2, AVX-512 F and DQ (this function's contract).
    let t = unsafe { volwarp_lanes::Avx512Token::new_unchecked() };
    let [x0, x1, y0, y1] = rect;
    let (c, r, i) = sphere;
    let near = Avx512::splat(t, near);
    let mut all_culled = true;
    for y in y0..=y1 {
        for x in (x0..=x1).step_by(16) {
            let n = (x1 - x + 1).min(16);
            let active = if n >= 16 { 0xFFFF } else { (1u32 << n) - 1 };
            let at = y * TILE + x;
            let (Some(ds), Some(is)) = (
                depth.get_mut(at..).and_then(|s| s.first_chunk_mut::<16>()),
                ids.get_mut(at..).and_then(|s| s.first_chunk_mut::<16>()),
            ) else {
                continue;
            };
            let d = Avx512::load(t, ds);
            if cull && (near.simd_le(d).to_bitmask() & active) == 0 {
                continue;
            }
            all_culled = false;
            let at = y * STRIDE + x;
            let plane = |k: usize| dirs.get(k * PLANE + at..).and_then(|s| s.first_chunk::<16>());
            let (Some(dx), Some(dy), Some(dz)) = (plane(0), plane(1), plane(2)) else {
                continue;
            };
            let dirs = [Avx512::load(t, dx), Avx512::load(t, dy), Avx512::load(t, dz)];
            if let Some((hit, m)) = sphere_hits(&[0.0; 3], &dirs, c, r, Avx512::of_bits(t, active)) {
                let win = (m & hit.simd_lt(d)).to_bitmask();
                let tie = (m & hit.simd_eq(d)).to_bitmask();
                hit.store_masked(ds, win);
                Avx512::store_u32_masked(t, is, win, i);
                if tie != 0 {
                    keep_ties(ds, is, tie, &hit.lanes(), i, false, ties);
                }
            }
        }
    }
    all_culled
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
mod tests {
    use super::*;

    /// A kernel with no centres (the small path reads a sphere's hits from `centres`).
    fn kernel<'a>(centres: &'a [[f32; 4]], ties: Ties<'a>) -> Kernel<'a, wide::f32x8> {
        let z = <wide::f32x8 as Arith>::splat(0.0);
        Kernel { ties, centres, o: [0.0; 3], lane: z, lane4: z, row2: z, tx1: 63, ty1: 63, cull: false, wide: false }
    }

    #[test]
    fn small_spheres_keep_the_nearer_hit_and_the_tie_rule() {
        let tile = Tile { x0: 0, y0: 0, w: TILE, h: TILE };
        let mut buf = TileBuf::new();
        // Sphere 9 first: hits at 2.0 on (10, 5) and 3.0 on (11, 6); none on the other two.
        let (inf, no) = (f32::INFINITY, f32::NAN);
        let mut centres = vec![[0.0; 4]; 10];
        centres[9] = [2.0, no, no, 3.0];
        // Sphere 3: the same distance on (10, 5) (a tie: the smaller index wins), nearer on
        // (11, 5), farther on (11, 6).
        centres[3] = [2.0, 1.0, no, 4.0];
        let r = Rect { x0: 10, y0: 5, x1: 11, y1: 6 };
        let k = kernel(&centres, Ties::Index);
        splat_small(&k, &tile, r, 9, &mut buf);
        splat_small(&k, &tile, r, 3, &mut buf);
        let at = |x: usize, y: usize| (buf.depth[y * TILE + x], buf.ids[y * TILE + x]);
        assert_eq!(at(10, 5), (2.0, 3));
        assert_eq!(at(11, 5), (1.0, 3));
        assert_eq!(at(10, 6), (inf, NO_HIT));
        assert_eq!(at(11, 6), (3.0, 9));
        // A window past a 12×7 tile's right and bottom edges, hitting all four pixels,
        // writes only its pixel inside the tile, (11, 6).
        let tile = Tile { x0: 0, y0: 0, w: 12, h: 7 };
        let centres = [[1.0f32; 4]; 10];
        let k = Kernel { tx1: 11, ty1: 6, ..kernel(&centres, Ties::Index) };
        let mut buf = TileBuf::new();
        splat_small(&k, &tile, Rect { x0: 11, y0: 6, x1: 12, y1: 7 }, 9, &mut buf);
        let written: Vec<usize> = (0..KEYS).filter(|&p| buf.ids[p] != NO_HIT).collect();
        assert_eq!(written, vec![6 * TILE + 11]);
    }

    /// The bound pass's instances (portable, AVX2, AVX-512 where the CPU has them) give the
    /// same rectangles, centres or hits (bit for bit), unions and masks, on whole and partial
    /// groups, near the eye plane and far.
    #[test]
    fn bound_instances_agree() {
        type Out = (Vec<u64>, Vec<[u32; 4]>, Vec<(u64, bool, u64)>, Vec<(u32, u64)>);
        let f = crate::synthetic::random_cloud(5000, 0.004, 41, 160);
        let eye_inside = Camera::look_at(Vec3::splat(0.5), Vec3::new(0.9, 0.6, 0.1), Vec3::Y, 70.0, 128, 96);
        let (c, deq) = (f.header.camera, f.header.dequantizer());
        let cams = [c, c.with_viewport(40, 40), c.orbit(30.0, 10.0).with_viewport(97, 61), eye_inside, c.dolly(0.2)];
        let mut small = 0;
        for cam in cams {
            let (view, grid) = (View::new(&cam), Grid::new(&cam));
            let vf = ViewF32::new(&view);
            // A run of many groups ending in a partial one (5000 = 156·32 + 8), and one partial.
            for s in [&f.samples[..], &f.samples[..13]] {
                let run = |k: usize| -> Option<Out> {
                    let (mut rects, mut centres) = (vec![NO_RECT; s.len()], vec![[0f32; 4]; s.len()]);
                    let ng = s.len().div_ceil(GROUP);
                    let (mut gr, mut gl, mut gs) = (vec![NO_RECT; ng], vec![false; ng], vec![0u64; ng]);
                    let mut pairs = Vec::new();
                    let groups = Groups { rects: &mut gr, large: &mut gl, small: &mut gs, first: 0 };
                    let (r, c, p) = (&mut rects[..], &mut centres[..], &mut pairs);
                    match k {
                        0 => bound_run::<wide::f32x8>(&view, &vf, &deq, s, r, c, groups, grid, p),
                        #[cfg(target_arch = "x86_64")]
                        1 if volwarp_lanes::Avx2Token::detected().is_some() => {
                            // SAFETY: the CPU has AVX2 (checked).
                            unsafe { bound_avx2(&view, &vf, &deq, s, r, c, groups, grid, p) }
                        }
                        #[cfg(target_arch = "x86_64")]
                        2 if volwarp_lanes::Avx512Token::detected().is_some() => {
                            // SAFETY: the CPU has AVX2, AVX-512 F and DQ (checked).
                            unsafe { bound_avx512(&view, &vf, &deq, s, r, c, groups, grid, p) }
                        }
                        _ => return None,
                    };
                    let c = centres.iter().map(|c| c.map(f32::to_bits)).collect();
                    let g = (0..ng).map(|i| (gr[i].bits(), gl[i], gs[i])).collect();
                    Some((rects.iter().map(|r| r.bits()).collect(), c, g, pairs))
                };
                let portable = run(0).expect("the portable instance");
                small += portable.2.iter().map(|g| (g.2 as u32).count_ones()).sum::<u32>();
                for k in [1, 2] {
                    if let Some(o) = run(k) {
                        assert!(o == portable, "instance {k}, {} spheres", s.len());
                    }
                }
            }
        }
        assert!(small > 1000, "{small}");
    }
}
