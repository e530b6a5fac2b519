//! The scalar reference traversal: first hit of one ray against the LBVH's spheres. Every fast
//! tracer (SIMD packets, the GPU shader) is tested against it, and [`brute_force`] tests it.
//!
//! **Tie rule.** A hit replaces the best one if it is closer, or equally close with a smaller
//! primitive index ([`closer`]). The result therefore does not depend on traversal order, so
//! tracers that visit nodes in another order still agree exactly.

use crate::camera::Ray;
use crate::lbvh::{child_box, Lbvh, LEAF_BIT};
use crate::sample::Dequantizer;
use crate::sphere::{intersect, intersect_box};
use glam::Vec3;

/// Depth of the traversal stack (the tree's, [`crate::lbvh::STACK_SIZE`]).
pub use crate::lbvh::STACK_SIZE;

/// A first hit: ray parameter and primitive (sorted sample) index.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter of the hit.
    pub t: f32,
    /// Index of the hit sample in the scene's (sorted) sample array.
    pub prim: u32,
}

/// The tie rule: whether a hit at `t` on `prim` beats `best`.
#[inline(always)]
pub fn closer(t: f32, prim: u32, best: &Option<Hit>) -> bool {
    match best {
        None => true,
        Some(b) => t < b.t || (t == b.t && prim < b.prim),
    }
}

#[inline(always)]
fn test_leaf(samples: &[u64], deq: &Dequantizer, ray: &Ray, k: u32, best: &mut Option<Hit>) {
    let s = samples[k as usize];
    if let Some(t) = intersect(ray.origin, ray.dir, deq.center(s), deq.radius(s)) {
        if closer(t, k, best) {
            *best = Some(Hit { t, prim: k });
        }
    }
}

impl Lbvh<'_> {
    /// The first hit of `ray` (unit direction), if any: [`Lbvh::hits`] keeping the nearest by
    /// the tie rule, the subtrees beyond it skipped.
    pub fn trace(&self, ray: &Ray) -> Option<Hit> {
        let mut best = None;
        self.hits(ray, |t, prim| {
            if closer(t, prim, &best) {
                best = Some(Hit { t, prim });
            }
            best.map_or(f32::INFINITY, |h| h.t)
        });
        best
    }
}

impl Lbvh<'_> {
    /// Every hit of `ray` (unit direction) nearer than a bound the caller keeps: `visit(t,
    /// prim)` is called for each sphere the ray hits (in no particular order) and returns the
    /// distance beyond which the caller wants no more hits (`f32::INFINITY` for all); subtrees
    /// whose box the ray enters only beyond it are skipped (the box test keeps a hit at exactly
    /// that distance). The multi-hit traversal of layered frames (`spheres-layers`).
    pub fn hits(&self, ray: &Ray, mut visit: impl FnMut(f32, u32) -> f32) {
        let n = self.samples.len();
        let mut bound = f32::INFINITY;
        let mut leaf = |k: u32, bound: &mut f32| {
            let s = self.samples[k as usize];
            if let Some(t) = intersect(ray.origin, ray.dir, self.deq.center(s), self.deq.radius(s)) {
                if t <= *bound {
                    *bound = visit(t, k);
                }
            }
        };
        if n == 1 {
            leaf(0, &mut bound);
        }
        if n < 2 {
            return;
        }
        let inv = Vec3::ONE / ray.dir;
        let root = &self.nodes[0];
        if intersect_box(ray.origin, inv, root.min, root.max, f32::INFINITY).is_none() {
            return;
        }
        let mut stack = [0u32; STACK_SIZE];
        let mut sp = 1;
        while sp > 0 {
            sp -= 1;
            let node = self.nodes[stack[sp] as usize];
            let mut near: [(u32, f32); 2] = [(0, 0.0); 2];
            let mut m = 0;
            for child in [node.left, node.right] {
                if child & LEAF_BIT != 0 {
                    leaf(child & !LEAF_BIT, &mut bound);
                } else {
                    let (lo, hi) = child_box(self.nodes, self.samples, &self.deq, child);
                    if let Some(t) = intersect_box(ray.origin, inv, lo, hi, bound) {
                        near[m] = (child, t);
                        m += 1;
                    }
                }
            }
            if m == 2 && near[1].1 < near[0].1 {
                near.swap(0, 1);
            }
            // Push far first so the near child is popped first.
            for &(child, _) in near[..m].iter().rev() {
                if sp < STACK_SIZE {
                    stack[sp] = child;
                    sp += 1;
                }
            }
        }
    }
}

/// The first hit by testing every sphere: the oracle for [`Lbvh::trace`].
pub fn brute_force(samples: &[u64], deq: &Dequantizer, ray: &Ray) -> Option<Hit> {
    let mut best = None;
    for k in 0..samples.len() as u32 {
        test_leaf(samples, deq, ray, k, &mut best);
    }
    best
}
