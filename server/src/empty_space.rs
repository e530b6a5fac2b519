//! Empty-space skipping: a coarse grid of bricks with the min/max of the values each brick can
//! interpolate, and, for a transfer function, which bricks can be visible at all.
//!
//! Brick `b` (per axis) owns the sample positions whose continuous voxel coordinate `g` lies in
//! `[b·B, (b+1)·B)` (the first and last brick extend to the clamped outside), `B` the grid's
//! brick edge ([`MinMaxGrid::brick`]: [`BRICK`] voxels, [`BRICK_BIG`] for volumes of more than
//! [`BIG_VOXELS`] voxels, so the grids stay a few percent of an 8-bit volume's bytes). These
//! skipping bricks are not the storage bricks of [`crate::volume::bricks`]. A trilinear
//! sample there reads voxels `b·B ..= (b+1)·B`; the recorded range covers one more voxel on
//! each side, so a sample that rounding puts a hair outside its brick is still covered.
//! A brick whose range maps to zero opacity everywhere is invisible. Each brick also stores
//! its Chebyshev distance (in bricks) to the nearest visible brick, so a ray in empty space
//! leaps over the whole cube of bricks known to be empty around it in one step; the marcher
//! then resumes on its regular sample lattice, so skipping changes no result.

use crate::transfer_function::TransferFunction;
use crate::volume::bricks::{Grid, Stored};
use crate::volume::{Volume, Voxels};
use volwarp_core::Vec3;

/// Brick edge in voxels of volumes up to [`BIG_VOXELS`] voxels.
pub const BRICK: u32 = 4;

/// Brick edge in voxels of bigger volumes (the grids then take 1/8 of the memory: about 0.04
/// bytes per voxel instead of 0.3).
pub const BRICK_BIG: u32 = 8;

/// Volumes of more voxels than this get [`BRICK_BIG`] bricks.
pub const BIG_VOXELS: u64 = 1 << 27;

/// The brick edge of the grid of a volume of `voxels` voxels: [`BRICK`], or [`BRICK_BIG`]
/// above [`BIG_VOXELS`].
pub fn brick_for(voxels: u64) -> u32 {
    if voxels > BIG_VOXELS {
        BRICK_BIG
    } else {
        BRICK
    }
}

/// Bricks a look in a visible brick reaches past the cube of visible bricks around it (see
/// [`Occupancy::look`]).
pub const VISIBLE_SLACK: u8 = 2;

/// Min/max of the normalized values per brick.
#[derive(Clone, Debug)]
pub struct MinMaxGrid {
    brick: u32,
    bricks: [u32; 3],
    ranges: Vec<(f32, f32)>,
    /// Per brick, the transfer-function table entries of its range's ends
    /// ([`TransferFunction::index`] of the low and the high end): made once, so a live edit's
    /// occupancy is two look-ups in a prefix count per brick, no arithmetic.
    spans: Vec<[u16; 2]>,
}

/// The voxels brick `b` of edge `e` records along one axis of `n` voxels: one before it to two
/// after it, clamped.
fn brick_span(b: u32, e: u32, n: u32) -> (u32, u32) {
    ((b * e).saturating_sub(1), ((b + 1) * e + 1).min(n - 1))
}

/// The normalized range of every brick of edge `brick` of `grid` (see
/// [`MinMaxGrid::with_brick`]).
fn ranges_of<T: Stored>(grid: &Grid<T>, brick: u32, bricks: [u32; 3], (offset, scale): (f32, f32)) -> Vec<(f32, f32)> {
    use rayon::prelude::*;
    let [nx, ny, nz] = grid.layout().dims();
    let per_slab = (bricks[0] * bricks[1]) as usize;
    let mut ranges = vec![(0.0, 0.0); per_slab * bricks[2] as usize];
    ranges.par_chunks_mut(per_slab.max(1)).enumerate().for_each(|(bz, slab)| {
        let (z0, z1) = brick_span(bz as u32, brick, nz);
        let (mut lo, mut hi) = (vec![T::default(); nx as usize], vec![T::default(); nx as usize]);
        for by in 0..bricks[1] {
            let (y0, y1) = brick_span(by, brick, ny);
            let mut first = true;
            for z in z0..=z1 {
                for y in y0..=y1 {
                    grid.for_each_run(y, z, |x0, run| {
                        let (l, h) = (&mut lo[x0..x0 + run.len()], &mut hi[x0..x0 + run.len()]);
                        if first {
                            l.copy_from_slice(run);
                            h.copy_from_slice(run);
                        } else {
                            for ((l, h), &v) in l.iter_mut().zip(h.iter_mut()).zip(run) {
                                *l = if v < *l { v } else { *l };
                                *h = if v > *h { v } else { *h };
                            }
                        }
                    });
                    first = false;
                }
            }
            let out = &mut slab[(by * bricks[0]) as usize..((by + 1) * bricks[0]) as usize];
            for (bx, o) in out.iter_mut().enumerate() {
                let (x0, x1) = brick_span(bx as u32, brick, nx);
                let (x0, x1) = (x0 as usize, x1 as usize);
                let l = lo[x0..=x1].iter().fold(f32::INFINITY, |m, &v| m.min(v.to_f32()));
                let h = hi[x0..=x1].iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v.to_f32()));
                // Stored values to normalized ones (a monotonic map: the range maps to the range).
                *o = ((l - offset) * scale, (h - offset) * scale);
            }
        }
    });
    ranges
}

impl MinMaxGrid {
    /// Builds the grid of a volume with the brick edge for its size ([`BRICK`] or
    /// [`BRICK_BIG`]).
    pub fn new(volume: &Volume) -> MinMaxGrid {
        let voxels = volume.dims().iter().map(|&d| u64::from(d)).product::<u64>();
        MinMaxGrid::with_brick(volume, brick_for(voxels))
    }

    /// Builds the grid of a volume with bricks of `brick` voxels (a power of two), in parallel
    /// over z slabs of bricks: for each row of bricks, the voxel rows of its span are reduced
    /// element by element in the stored type (runs of the storage bricks, vectorized), then the
    /// reduced row to each brick's x span.
    pub fn with_brick(volume: &Volume, brick: u32) -> MinMaxGrid {
        let brick = brick.max(1).next_power_of_two();
        let bricks = volume.dims().map(|d| d.div_ceil(brick));
        let ranges = match volume.voxels() {
            Voxels::U8(g) => ranges_of(g, brick, bricks, volume.normalization()),
            Voxels::U16(g) => ranges_of(g, brick, bricks, volume.normalization()),
            Voxels::F32(g) => ranges_of(g, brick, bricks, volume.normalization()),
        };
        let spans = ranges
            .iter()
            .map(|&(lo, hi)| [TransferFunction::index(lo.min(hi)) as u16, TransferFunction::index(hi.max(lo)) as u16])
            .collect();
        MinMaxGrid { brick, bricks, ranges, spans }
    }

    /// The brick edge in voxels.
    pub fn brick(&self) -> u32 {
        self.brick
    }

    /// Bricks per axis.
    pub fn bricks(&self) -> [u32; 3] {
        self.bricks
    }

    /// The value range of every brick, x fastest.
    pub fn ranges(&self) -> &[(f32, f32)] {
        &self.ranges
    }

    /// Which bricks a transfer function can make visible.
    pub fn occupancy(&self, tf: &TransferFunction, spacing: Vec3) -> Occupancy {
        self.occupancy_within(tf, spacing, |_| true)
    }

    /// [`MinMaxGrid::occupancy`] with every brick `keep` rejects (by brick index) invisible as
    /// well (a crop box): one pass, its distance transforms made once.
    pub fn occupancy_within(&self, tf: &TransferFunction, spacing: Vec3, keep: impl Fn([u32; 3]) -> bool) -> Occupancy {
        // `TransferFunction::visibility` with each brick's table entries made at build time.
        let visible = tf.visible_counts();
        let [nx, ny, nz] = self.bricks;
        let mut occupied = Vec::with_capacity(self.spans.len());
        let mut spans = self.spans.iter();
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let Some(&[a, b]) = spans.next() else { break };
                    occupied.push(visible[b as usize + 1] > visible[a as usize] && keep([x, y, z]));
                }
            }
        }
        Occupancy::of_flags(self.brick, self.bricks, occupied, spacing)
    }
}

/// The visible/invisible flag of every brick for one transfer function.
#[derive(Clone, Debug)]
pub struct Occupancy {
    /// The brick edge in voxels.
    brick: u32,
    bricks: [u32; 3],
    occupied: Vec<bool>,
    /// Chebyshev distance in bricks to the nearest visible brick (0: visible), capped at 255.
    dist: Vec<u8>,
    /// Per brick, the Chebyshev distance (in bricks, at most 255) to the nearest brick the
    /// transfer function keeps invisible: 0 for an invisible brick; every brick closer than that
    /// is visible.
    visible_reach: Vec<u8>,
    spacing: Vec3,
}

impl Occupancy {
    /// The occupancy of these visible/invisible flags: both distance transforms (to the nearest
    /// visible and the nearest invisible brick), made side by side on two threads.
    fn of_flags(brick: u32, bricks: [u32; 3], occupied: Vec<bool>, spacing: Vec3) -> Occupancy {
        let (dist, visible_reach) = rayon::join(
            || chebyshev_distance(bricks, &occupied),
            || {
                let empty: Vec<bool> = occupied.iter().map(|&o| !o).collect();
                chebyshev_distance(bricks, &empty)
            },
        );
        Occupancy { brick, bricks, occupied, dist, visible_reach, spacing }
    }
}

/// Chebyshev (26-neighbour) distance of every brick to the nearest `true` one, capped at 255,
/// in sweeps one axis at a time, each a vector operation over whole planes or rows:
///
/// 1. along z, forward then backward: each plane takes the minimum of itself and its
///    predecessor's 3×3 window minimum plus one (a step in z may move x and y by one too);
/// 2. along y in every plane, forward then backward: each row takes its predecessor's 3-wide
///    window minimum plus one;
/// 3. along x in every row, forward then backward: `d[x] = min(d[x], d[x ∓ 1] + 1)`.
///
/// Exact for the chessboard distance: a shortest chessboard path from a `true` brick to a
/// target with offsets `(dx, dy, dz)` takes `|dz|` steps along z that also cover up to `|dz|`
/// of x and y, then the y steps left (covering x too), then the x steps left: `max(|dx|, |dy|,
/// |dz|)` steps in the sweeps' order, and every sweep only adds steps of one (so nothing is
/// lower than the distance). A live edit remakes two of these; Rosenfeld and Pfaltz's two
/// raster passes over the 13 neighbours before each brick, row by row, took 3–4× as long on the
/// MRI's 46×55×46 bricks (`docs/perf.md`).
pub fn chebyshev_distance(bricks: [u32; 3], occupied: &[bool]) -> Vec<u8> {
    let [nx, ny, nz] = bricks.map(|b| b as usize);
    let mut d: Vec<u8> = occupied.iter().map(|&o| if o { 0 } else { 255 }).collect();
    let plane = nx * ny;
    if d.is_empty() || d.len() != plane * nz {
        return d;
    }
    // 1. Along z.
    let (mut rows, mut win) = (vec![255u8; plane], vec![255u8; plane]);
    for backward in [false, true] {
        for zi in 1..nz {
            let (z, prev) = if backward { (nz - 1 - zi, nz - zi) } else { (zi, zi - 1) };
            window_3x3(&d[prev * plane..(prev + 1) * plane], nx, &mut rows, &mut win);
            step_into(&mut d[z * plane..(z + 1) * plane], &win);
        }
    }
    // 2. Along y.
    let mut w3 = vec![255u8; nx];
    for p in d.chunks_exact_mut(plane) {
        for backward in [false, true] {
            for yi in 1..ny {
                let (y, prev) = if backward { (ny - 1 - yi, ny - yi) } else { (yi, yi - 1) };
                window_3(&p[prev * nx..(prev + 1) * nx], &mut w3);
                step_into(&mut p[y * nx..(y + 1) * nx], &w3);
            }
        }
    }
    // 3. Along x.
    for row in d.chunks_exact_mut(nx) {
        for x in 1..nx {
            row[x] = row[x].min(row[x - 1].saturating_add(1));
        }
        for x in (0..nx - 1).rev() {
            row[x] = row[x].min(row[x + 1].saturating_add(1));
        }
    }
    d
}

/// `d = min(d, w + 1)` (saturating).
#[inline]
fn step_into(d: &mut [u8], w: &[u8]) {
    for (v, &w) in d.iter_mut().zip(w) {
        *v = (*v).min(w.saturating_add(1));
    }
}

/// `out[x] = min(src[x − 1 ..= x + 1])` within the row (the ends take the two they have).
#[inline]
fn window_3(src: &[u8], out: &mut [u8]) {
    let n = src.len();
    if n < 2 {
        out.copy_from_slice(src);
        return;
    }
    for (((o, &a), &b), &c) in out[1..n - 1].iter_mut().zip(src).zip(&src[1..]).zip(&src[2..]) {
        *o = a.min(b).min(c);
    }
    out[0] = src[0].min(src[1]);
    out[n - 1] = src[n - 2].min(src[n - 1]);
}

/// The 3×3 window minimum of a plane of rows of `nx` (the edges take what they have) into
/// `win`, `rows` the rows' own 3-wide minima: both over the whole plane at once, then the
/// row ends fixed.
#[inline]
fn window_3x3(src: &[u8], nx: usize, rows: &mut [u8], win: &mut [u8]) {
    let n = src.len();
    if nx < 2 {
        rows.copy_from_slice(src);
    } else {
        // Across the plane as one row, then each row's first and last brick.
        window_3(src, rows);
        for (r, s) in rows.chunks_exact_mut(nx).zip(src.chunks_exact(nx)) {
            r[0] = s[0].min(s[1]);
            r[nx - 1] = s[nx - 2].min(s[nx - 1]);
        }
    }
    if n <= nx {
        win.copy_from_slice(rows);
        return;
    }
    for (((o, &a), &b), &c) in win[nx..n - nx].iter_mut().zip(rows.iter()).zip(&rows[nx..]).zip(&rows[2 * nx..]) {
        *o = a.min(b).min(c);
    }
    for x in 0..nx {
        win[x] = rows[x].min(rows[nx + x]);
        win[n - nx + x] = rows[n - 2 * nx + x].min(rows[n - nx + x]);
    }
}

impl Occupancy {
    /// The brick of continuous voxel coordinate `g` (clamped).
    #[inline(always)]
    pub fn brick_of(&self, g: Vec3) -> [u32; 3] {
        let f = |v: f32, n: u32| {
            let b = v * (1.0 / self.brick as f32);
            if b >= (n - 1) as f32 {
                n - 1
            } else if b > 0.0 {
                b as u32
            } else {
                0
            }
        };
        [f(g.x, self.bricks[0]), f(g.y, self.bricks[1]), f(g.z, self.bricks[2])]
    }

    /// Whether brick `b` can be visible.
    #[inline(always)]
    pub fn occupied(&self, b: [u32; 3]) -> bool {
        self.distance(b) == 0
    }

    /// Chebyshev distance in bricks from brick `b` to the nearest visible one (0: visible):
    /// every brick closer than that is invisible.
    #[inline(always)]
    pub fn distance(&self, b: [u32; 3]) -> u8 {
        self.dist.get(self.index(b)).copied().unwrap_or(0)
    }

    /// The index of brick `b` in the per-brick arrays (x fastest).
    #[inline(always)]
    fn index(&self, b: [u32; 3]) -> usize {
        b[0] as usize + self.bricks[0] as usize * (b[1] as usize + self.bricks[1] as usize * b[2] as usize)
    }

    /// [`Occupancy::distance`]'s counterpart for visible bricks: the Chebyshev distance to the
    /// nearest invisible brick (0 for an invisible one, 255 if there is none within 254).
    #[inline(always)]
    pub fn visible_reach(&self, b: [u32; 3]) -> u8 {
        self.visible_reach.get(self.index(b)).copied().unwrap_or(0)
    }

    /// What a look at brick `b` finds: its [`Occupancy::distance`] `r` and the reach to pass to
    /// [`Occupancy::leap_exit_t`] — `r` for an invisible brick (leap past the empty cube), and
    /// for a visible one its [`Occupancy::visible_reach`] plus [`VISIBLE_SLACK`]: the next look
    /// is due where the ray leaves that cube. The cube may then hold invisible bricks, whose
    /// samples the marchers take needlessly but harmlessly (their opacity is 0, so they change
    /// nothing); fewer looks pay for more than that (−13 to −15 % march time on the bundled
    /// datasets with a slack of 2 against none).
    #[inline(always)]
    pub fn look(&self, b: [u32; 3]) -> (u8, u8) {
        self.look_at(self.index(b))
    }

    /// [`Occupancy::look`] of the brick at index `i` (an index outside the grid reads 0 for both
    /// distances, as [`Occupancy::distance`] and [`Occupancy::visible_reach`] do).
    #[inline(always)]
    fn look_at(&self, i: usize) -> (u8, u8) {
        let r = self.dist.get(i).copied().unwrap_or(0);
        (
            r,
            if r > 0 {
                r
            } else {
                self.visible_reach.get(i).copied().unwrap_or(0).max(1).saturating_add(VISIBLE_SLACK)
            },
        )
    }

    /// Per brick, x fastest, the look's result as one number for the packet marcher's gathers:
    /// the distance `r` of an invisible brick, minus the reach of a visible one (with the slack).
    pub fn look_table(&self) -> Vec<f32> {
        // `Occupancy::look_at` of every index, brick by brick in one pass (it vectorizes).
        self.dist
            .iter()
            .zip(&self.visible_reach)
            .map(|(&r, &v)| if r > 0 { r as f32 } else { -(v.max(1).saturating_add(VISIBLE_SLACK) as f32) })
            .collect()
    }

    /// Where a ray `o + d·t` leaves the cube of bricks within Chebyshev distance `r − 1` of brick
    /// `b` (all invisible when `r` = [`Occupancy::distance`] of `b`); faces on the grid's outer
    /// boundary do not count (the clamped outside belongs to the edge bricks).
    #[inline]
    pub fn leap_exit_t(&self, b: [u32; 3], r: u8, o: Vec3, inv_d: Vec3) -> f32 {
        let reach = r.saturating_sub(1) as u32;
        let mut t = f32::INFINITY;
        for a in 0..3 {
            if !inv_d[a].is_finite() {
                continue;
            }
            let plane = if inv_d[a] > 0.0 {
                let hi = b[a] + reach + 1;
                if hi >= self.bricks[a] {
                    continue;
                }
                (hi * self.brick) as f32 + 0.5
            } else {
                if b[a] < reach + 1 {
                    continue;
                }
                ((b[a] - reach) * self.brick) as f32 + 0.5
            };
            t = t.min((plane * self.spacing[a] - o[a]) * inv_d[a]);
        }
        t
    }

    /// Bricks per axis.
    pub fn bricks(&self) -> [u32; 3] {
        self.bricks
    }

    /// The brick edge in voxels.
    pub fn brick(&self) -> u32 {
        self.brick
    }

    /// [`Occupancy::distance`] of every brick, x fastest.
    pub fn distances(&self) -> &[u8] {
        &self.dist
    }

    /// The fraction of bricks that can be visible.
    pub fn fraction_occupied(&self) -> f32 {
        self.occupied.iter().filter(|&&o| o).count() as f32 / self.occupied.len().max(1) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The grid's definition voxel by voxel: each brick's range over the voxels one before it
    /// to two after it (clamped), normalized.
    fn reference(volume: &Volume, brick: u32) -> Vec<(f32, f32)> {
        let dims = volume.dims();
        let bricks = dims.map(|d| d.div_ceil(brick));
        let mut out = Vec::new();
        for bz in 0..bricks[2] {
            for by in 0..bricks[1] {
                for bx in 0..bricks[0] {
                    let b = [bx, by, bz];
                    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
                    let r = |a: usize| {
                        let (s, e) = brick_span(b[a], brick, dims[a]);
                        s..=e
                    };
                    for k in r(2) {
                        for j in r(1) {
                            for i in r(0) {
                                let v = volume.voxel(i, j, k);
                                lo = lo.min(v);
                                hi = hi.max(v);
                            }
                        }
                    }
                    out.push((lo, hi));
                }
            }
        }
        out
    }

    #[test]
    fn row_wise_ranges_equal_the_voxel_by_voxel_definition() {
        for (dims, kind) in [([1, 1, 1], 0), ([9, 17, 5], 1), ([33, 2, 65], 0), ([65, 34, 3], 2), ([4, 8, 16], 1)] {
            let n = dims.iter().product::<u32>() as usize;
            let values: Vec<f32> = (0..n)
                .map(|i| match kind {
                    0 => (i * 7919 % 251) as f32,
                    1 => (i * 7919 % 60_000) as f32,
                    _ => (i as f32 * 0.37).sin(),
                })
                .collect();
            let v = Volume::from_values("g", dims, Vec3::ONE, values).unwrap();
            for brick in [BRICK, BRICK_BIG] {
                let g = MinMaxGrid::with_brick(&v, brick);
                assert_eq!(g.brick(), brick);
                assert_eq!(g.bricks(), dims.map(|d| d.div_ceil(brick)));
                assert_eq!(g.ranges(), &reference(&v, brick)[..], "{dims:?} brick {brick}");
            }
        }
    }

    /// The distances by breadth-first search from every `true` brick at once (the definition).
    fn chebyshev_reference(bricks: [u32; 3], occupied: &[bool]) -> Vec<u8> {
        let [nx, ny, nz] = bricks.map(|b| b as i64);
        let mut dist = vec![255u8; occupied.len()];
        let mut queue = std::collections::VecDeque::new();
        for (i, &o) in occupied.iter().enumerate() {
            if o {
                dist[i] = 0;
                queue.push_back(i);
            }
        }
        while let Some(i) = queue.pop_front() {
            let d = dist[i];
            if d == 254 {
                continue;
            }
            let (x, y, z) = ((i as i64) % nx, (i as i64 / nx) % ny, i as i64 / (nx * ny));
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let (a, b, c) = (x + dx, y + dy, z + dz);
                        if a < 0 || b < 0 || c < 0 || a >= nx || b >= ny || c >= nz {
                            continue;
                        }
                        let j = (a + nx * (b + ny * c)) as usize;
                        if dist[j] > d + 1 {
                            dist[j] = d + 1;
                            queue.push_back(j);
                        }
                    }
                }
            }
        }
        dist
    }

    /// What a live edit rebuilds (the occupancy of a windowed function under a crop, both
    /// distance transforms and the packet marcher's look table) equals its definition brick by
    /// brick: the flags from each range and `TransferFunction::visibility`, the distances by
    /// breadth-first search, the table from `Occupancy::look_at`.
    #[test]
    fn an_edits_occupancy_equals_its_definition() {
        let dims = [70, 45, 83];
        let v = Volume::from_fn("e", dims, Vec3::new(1.0, 0.8, 1.2), |p| {
            let q = p / Vec3::new(70.0, 36.0, 99.6) - 0.5;
            ((1.0 - 2.0 * q.length()) * 180.0 + 40.0 * (p.x * 0.3).sin() * (p.z * 0.2).cos()).clamp(0.0, 255.0).round()
        })
        .unwrap();
        for brick in [BRICK, BRICK_BIG] {
            let g = MinMaxGrid::with_brick(&v, brick);
            let [nx, ny, _] = g.bricks();
            for (window, level, crop) in [(1.0, 0.5, false), (0.3, 0.6, false), (0.5, 0.35, true), (0.05, 0.9, true)] {
                let tf = TransferFunction::grey_ramp().windowed(window, level, 1.0);
                let keep = |b: [u32; 3]| !crop || (b[0] % 3 != 1 && b[2] > 1 && b[1] < ny - 1);
                let occ = g.occupancy_within(&tf, Vec3::ONE, keep);
                let visible = tf.visibility();
                let flags: Vec<bool> = g
                    .ranges()
                    .iter()
                    .enumerate()
                    .map(|(i, &(lo, hi))| {
                        let i = i as u32;
                        visible(lo, hi) && keep([i % nx, i / nx % ny, i / (nx * ny)])
                    })
                    .collect();
                let what = format!("brick {brick} window {window} level {level} crop {crop}");
                assert!(flags.iter().any(|&f| f) && flags.iter().any(|&f| !f), "{what}: a trivial case");
                assert_eq!(occ.occupied, flags, "{what}");
                assert_eq!(occ.dist, chebyshev_reference(g.bricks(), &flags), "{what}");
                let empty: Vec<bool> = flags.iter().map(|&f| !f).collect();
                assert_eq!(occ.visible_reach, chebyshev_reference(g.bricks(), &empty), "{what}");
                let looks: Vec<f32> = (0..flags.len())
                    .map(|i| match occ.look_at(i) {
                        (0, reach) => -(reach as f32),
                        (r, _) => r as f32,
                    })
                    .collect();
                assert_eq!(occ.look_table(), looks, "{what}");
            }
        }
    }

    #[test]
    fn sweeps_equal_the_breadth_first_distances() {
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        for bricks in [
            [1, 1, 1],
            [7, 1, 1],
            [1, 9, 4],
            [13, 11, 7],
            [30, 3, 40],
            [5, 64, 5],
            [300, 1, 2],
            [2, 2, 2],
            [1, 1, 9],
            [3, 300, 2],
        ] {
            let n = bricks.iter().product::<u32>() as usize;
            // Empty, full, one brick, and sparse to dense random sets.
            let mut sets = vec![vec![false; n], vec![true; n]];
            let mut one = vec![false; n];
            one[(next() % n as u64) as usize] = true;
            sets.push(one);
            for per_mille in [1u64, 2, 20, 300, 900] {
                sets.push((0..n).map(|_| next() % 1000 < per_mille).collect());
            }
            for occupied in sets {
                assert_eq!(chebyshev_distance(bricks, &occupied), chebyshev_reference(bricks, &occupied), "{bricks:?}");
            }
        }
    }
}
