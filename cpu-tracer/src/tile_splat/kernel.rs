//! The splat step of the tiled splatter: per tile, its pixels' ray directions and nearest
//! hits, each sphere's pixels tested in SIMD lanes with the depth test and the tie rule.

use super::*;

/// Whether a rectangle overlaps one tile, as four 16-bit comparisons in one 64-bit
/// subtraction (SWAR): every coordinate is below 2¹⁵ ([`MAX_VIEWPORT`], [`NO_RECT`]), so with
/// bit 15 of each field of the minuend set no field borrows from the next, and a field's bit
/// 15 survives exactly where the minuend's field is at least the subtrahend's.
#[derive(Clone, Copy)]
pub(super) struct TileTest {
    /// The tile's last column and row in the low fields.
    pub(super) last: u64,
    /// The tile's first column and row in the high fields.
    pub(super) first: u64,
}

/// Bit 15 of each 16-bit field.
pub(super) const FIELD_SIGNS: u64 = 0x8000_8000_8000_8000;
/// The low two 16-bit fields.
pub(super) const LOW_FIELDS: u64 = 0xFFFF_FFFF;

impl TileTest {
    pub(super) fn new(tile: &Tile) -> TileTest {
        let (x1, y1) = ((tile.x0 + tile.w - 1) as u64, (tile.y0 + tile.h - 1) as u64);
        TileTest { last: x1 | y1 << 16, first: (tile.x0 as u64) << 32 | (tile.y0 as u64) << 48 }
    }

    /// Whether `r` overlaps the tile: `x0 ≤ last x`, `y0 ≤ last y`, `x1 ≥ first x`,
    /// `y1 ≥ first y` (false for an empty `r`, whose `x0` lies beyond every tile).
    #[inline(always)]
    pub(super) fn hits(&self, r: Rect) -> bool {
        let a = r.bits();
        let minuend = self.last | (a & !LOW_FIELDS) | FIELD_SIGNS;
        let subtrahend = (a & LOW_FIELDS) | self.first;
        (minuend - subtrahend) & FIELD_SIGNS == FIELD_SIGNS
    }

    /// Whether a non-empty `r` lies inside the tile.
    #[inline(always)]
    pub(super) fn contains(&self, r: Rect) -> bool {
        let (x1, y1) = (self.last as u16, (self.last >> 16) as u16);
        let (x0, y0) = ((self.first >> 32) as u16, (self.first >> 48) as u16);
        r.x0 >= x0 && r.y0 >= y0 && r.x1 <= x1 && r.y1 <= y1
    }

    /// The spheres of `rects` (at most 32) that overlap the tile, as bits.
    #[inline(always)]
    pub(super) fn hits_of(&self, rects: &[Rect]) -> u32 {
        let mut m = 0u32;
        for (j, &r) in rects.iter().enumerate().take(32) {
            m |= (self.hits(r) as u32) << j;
        }
        m
    }
}

/// A tile's place in the image.
pub(super) struct Tile {
    pub(super) x0: usize,
    pub(super) y0: usize,
    pub(super) w: usize,
    pub(super) h: usize,
}

/// A tile's local buffers: its pixels' keys and unit ray directions (three planes of
/// `TILE + 1` rows of [`STRIDE`] floats; padding holds zeros or the directions of pixels past
/// the tile, and is never tested).
pub(super) struct TileBuf {
    /// Per pixel (row stride [`TILE`], one row and eight pixels of padding), the distance of
    /// the nearest hit so far, `+∞` where none.
    pub(super) depth: Box<[f32; KEYS]>,
    /// Per pixel, the sample of that hit, [`NO_HIT`] where none: with `depth`, the pixel's
    /// key `(t, id)` ([`TileBuf::key`]).
    pub(super) ids: Box<[u32; KEYS]>,
    pub(super) dirs: Box<[f32; 3 * PLANE]>,
}

/// Length of a tile's depth and id planes.
pub(super) const KEYS: usize = (TILE + 1) * TILE + 8;

impl TileBuf {
    pub(super) fn new() -> TileBuf {
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
pub(super) fn key_of(t: f32, id: u32) -> u64 {
    if id == NO_HIT {
        EMPTY
    } else {
        key(t, id)
    }
}

/// The first eight floats of `s` (at least eight long): one bounds check, one load.
#[inline(always)]
pub(super) fn load<L: Lanes>(s: &[f32]) -> L {
    match s.first_chunk::<8>() {
        Some(a) => L::new(*a),
        None => L::splat(0.0),
    }
}

/// Four floats from `s` and four from `s[STRIDE..]`: a 4×2 block of a direction plane.
#[inline(always)]
pub(super) fn load_4x2<L: Lanes>(s: &[f32]) -> L {
    L::new(quad::<f32, STRIDE>(s))
}

/// Four values from `s` and four from `s[S..]` (a 4×2 block of a plane of row stride `S`);
/// zeros if `s` is too short.
#[inline(always)]
pub(super) fn quad<T: Copy + Default, const S: usize>(s: &[T]) -> [T; 8] {
    match (s.first_chunk::<4>(), s.get(S..).and_then(|r| r.first_chunk::<4>())) {
        (Some(a), Some(b)) => [a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3]],
        _ => [T::default(); 8],
    }
}

/// The first eight values of `s`, zeros if it is shorter.
#[inline(always)]
pub(super) fn eight<T: Copy + Default>(s: &[T]) -> [T; 8] {
    s.first_chunk::<8>().copied().unwrap_or([T::default(); 8])
}

/// Writes `a` where [`quad`] (with `S` = [`TILE`]) or [`eight`] read it.
#[inline(always)]
pub(super) fn put<T: Copy>(s: &mut [T], a: [T; 8], is_quad: bool) {
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
pub(super) fn splat_tile<L: Lanes>(
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
pub(super) fn tile_dirs<L: Lanes>(view: &View, tile: &Tile, buf: &mut TileBuf) {
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
pub(super) fn splat_small<L>(k: &Kernel<'_, L>, tile: &Tile, r: Rect, i: u32, buf: &mut TileBuf) {
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
pub(super) fn splat_small_at(
    depth: &mut [f32; KEYS],
    ids: &mut [u32; KEYS],
    p: usize,
    t4: [f32; 4],
    i: u32,
    ties: Ties,
) {
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
pub(super) fn keep_pixel(d: &mut f32, id: &mut u32, t: f32, i: u32) -> bool {
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
pub(super) fn small_ties(
    depth: &mut [f32; KEYS],
    ids: &mut [u32; KEYS],
    q: [usize; 4],
    t4: &[f32; 4],
    i: u32,
    ties: Ties,
) {
    for (&q, &t) in q.iter().zip(t4) {
        if t == depth[q] {
            keep_ties(&mut depth[q..=q], &mut ids[q..=q], 1, &[t], i, false, ties);
        }
    }
}

/// What a tile reads of the binning.
pub(super) struct Lists<'a> {
    /// The groups binned to the tile (index and mask, as in `TileSplat::lists`).
    pub(super) groups: &'a [u64],
    pub(super) large: &'a [u32],
    pub(super) large_rects: &'a [Rect],
    pub(super) rects: &'a [Rect],
    /// Per sphere, its centre less the eye and its radius (`TileSplat::centres`).
    pub(super) centres: &'a [[f32; 4]],
    pub(super) group_rects: &'a [Rect],
    /// Per group, the masks of its small and its drawn spheres (`TileSplat::group_small`).
    pub(super) group_small: &'a [u64],
    /// Whether to skip spheres hidden in a block ([`TileSplat::with_culling`]).
    pub(super) cull: bool,
}

/// The per-tile constants of [`splat_sphere`].
pub(super) struct Kernel<'a, L> {
    pub(super) ties: Ties<'a>,
    /// Per sphere, its centre less the eye and its radius.
    pub(super) centres: &'a [[f32; 4]],
    /// The rays' origin: zero, as the centres are less the eye.
    pub(super) o: [f32; 3],
    pub(super) lane: L,
    pub(super) lane4: L,
    pub(super) row2: L,
    pub(super) tx1: usize,
    pub(super) ty1: usize,
    pub(super) cull: bool,
    /// Whether spheres wider than eight pixels take rows of sixteen ([`rows16`]; set where the
    /// CPU has AVX-512).
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    pub(super) wide: bool,
}

/// One sphere `i` into a tile's keys (no closures here: they would be compiled without the
/// caller's AVX2 target feature); `true` if culling skipped every block of it.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn splat_sphere<L: Lanes>(k: &Kernel<'_, L>, tile: &Tile, r: Rect, i: u32, buf: &mut TileBuf) -> bool {
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
pub(super) fn depth_at<L: Lanes>(depth: &[f32; KEYS], at: usize, is_quad: bool) -> L {
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
pub(super) fn keep<L: Lanes>(
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
pub(super) fn keep_ties(ds: &mut [f32], is: &mut [u32], bits: u32, t: &[f32], i: u32, is_quad: bool, ties: Ties) {
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
    pub(super) fn tile_dispatch / tile_avx2 => splat_tile(
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
pub(super) unsafe fn rows16(
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
