//! Empty-space skipping: a coarse grid of bricks with the min/max of the values each brick can
//! interpolate, and, for a transfer function, which bricks can be visible at all.
//!
//! Brick `b` (per axis) owns the sample positions whose continuous voxel coordinate `g` lies in
//! `[b·B, (b+1)·B)` (the first and last brick extend to the clamped outside). A trilinear
//! sample there reads voxels `b·B ..= (b+1)·B`; the recorded range covers one more voxel on
//! each side, so a sample that rounding puts a hair outside its brick is still covered.
//! A brick whose range maps to zero opacity everywhere is skipped in one step, and the
//! marcher resumes on its regular sample lattice, so skipping changes no result.

use crate::transfer_function::TransferFunction;
use crate::volume::Volume;
use volwarp_core::Vec3;

/// Brick edge in voxels.
pub const BRICK: u32 = 8;

/// Min/max of the normalized values per brick.
#[derive(Clone, Debug)]
pub struct MinMaxGrid {
    bricks: [u32; 3],
    ranges: Vec<(f32, f32)>,
}

impl MinMaxGrid {
    /// Builds the grid of a volume (parallel over z slabs of bricks).
    pub fn new(volume: &Volume) -> MinMaxGrid {
        use rayon::prelude::*;
        let dims = volume.dims();
        let bricks = dims.map(|d| d.div_ceil(BRICK));
        let per_slab = (bricks[0] * bricks[1]) as usize;
        let mut ranges = vec![(0.0f32, 0.0f32); per_slab * bricks[2] as usize];
        ranges.par_chunks_mut(per_slab.max(1)).enumerate().for_each(|(bz, slab)| {
            for by in 0..bricks[1] {
                for bx in 0..bricks[0] {
                    let b = [bx, by, bz as u32];
                    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
                    let r = |a: usize| {
                        let start = (b[a] * BRICK).saturating_sub(1);
                        let end = ((b[a] + 1) * BRICK + 1).min(dims[a] - 1);
                        start..=end
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
                    slab[(bx + by * bricks[0]) as usize] = (lo, hi);
                }
            }
        });
        MinMaxGrid { bricks, ranges }
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
        let occupied = self.ranges.iter().map(|&(lo, hi)| tf.max_opacity(lo, hi) > 0.0).collect();
        Occupancy { bricks: self.bricks, occupied, spacing }
    }
}

/// The visible/invisible flag of every brick for one transfer function.
#[derive(Clone, Debug)]
pub struct Occupancy {
    bricks: [u32; 3],
    occupied: Vec<bool>,
    spacing: Vec3,
}

impl Occupancy {
    /// The brick of continuous voxel coordinate `g` (clamped).
    #[inline(always)]
    pub fn brick_of(&self, g: Vec3) -> [u32; 3] {
        let f = |v: f32, n: u32| {
            let b = v * (1.0 / BRICK as f32);
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
        let i = b[0] as usize + self.bricks[0] as usize * (b[1] as usize + self.bricks[1] as usize * b[2] as usize);
        self.occupied.get(i).copied().unwrap_or(true)
    }

    /// The fraction of bricks that can be visible.
    pub fn fraction_occupied(&self) -> f32 {
        self.occupied.iter().filter(|&&o| o).count() as f32 / self.occupied.len().max(1) as f32
    }

    /// The ray parameter where a ray `o + d·t` leaves brick `b` (world space, `t` ≥ `t_min`).
    #[inline]
    pub fn exit_t(&self, b: [u32; 3], o: Vec3, inv_d: Vec3) -> f32 {
        let mut t = f32::INFINITY;
        for a in 0..3 {
            let d_pos = inv_d[a] > 0.0;
            let last = b[a] + 1 >= self.bricks[a];
            let plane = if d_pos {
                if last {
                    continue;
                }
                ((b[a] + 1) * BRICK) as f32 + 0.5
            } else {
                if b[a] == 0 {
                    continue;
                }
                (b[a] * BRICK) as f32 + 0.5
            };
            if !inv_d[a].is_finite() {
                continue;
            }
            let tp = (plane * self.spacing[a] - o[a]) * inv_d[a];
            t = t.min(tp);
        }
        t
    }
}
