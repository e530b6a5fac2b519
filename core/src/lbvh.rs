//! The linear BVH (Lauterbach et al. 2009) with Karras' (2012) fully parallel radix-tree
//! construction over sorted Morton codes, and bounds fitted bottom-up.
//!
//! **Building** needs no allocator: everything goes into caller-provided buffers, and each
//! step is exposed per node so a parallel driver (rayon in `volwarp-cpu-tracer`, a compute
//! shader in `volwarp-gpu-tracer`) can run it:
//!
//! 1. [`crate::morton::make_keys`] and [`crate::morton::radix_sort`]: codes sorted by
//!    `(code, index)`;
//! 2. [`reorder`]: samples and colors into sorted order (leaf `k` is sorted sample `k`);
//! 3. [`karras_node`] for every internal node `i` in `0..n-1` (independent), written by
//!    [`write_node_links`] with its parent pointers;
//! 4. [`fit_from_leaf`] for every leaf: walks up and fits a node when its second child is
//!    done (the first arrival stops), so each node is fitted exactly once.
//!
//! [`build`] runs all four serially.
//!
//! **Layout.** `n` samples give `n − 1` internal [`Node`]s; node 0 is the root. A child
//! reference with [`LEAF_BIT`] set is a leaf: the low 31 bits index the *sorted* sample array.
//! Leaves store nothing: their box comes from the packed sample. The GPU tracer uploads exactly
//! these bytes. A scene of one sample has no internal node (its root is leaf 0).
//!
//! **Ties.** Equal codes are told apart by their index (Karras' tie-break: `δ(i, j) = 64 +
//! clz(i ⊕ j)`), so thousands of identical positions build a valid, balanced tree.

use crate::morton::SortKey;
use crate::sample::Dequantizer;
use crate::sphere::sphere_box;
use bytemuck::{Pod, Zeroable};

/// Flag of a child reference that points at a leaf.
pub const LEAF_BIT: u32 = 0x8000_0000;

/// Depth of a traversal stack over the tree: the Karras tree over 54-bit codes plus 32-bit
/// tie-breaks is at most 97 levels deep, and near-first traversal keeps at most one entry per
/// level.
pub const STACK_SIZE: usize = 128;
/// Parent of the root.
pub const NO_PARENT: u32 = u32::MAX;

/// An internal node: its box and two child references. 32 bytes, `#[repr(C)]`; in WGSL
/// `struct Node { min: vec3<f32>, left: u32, max: vec3<f32>, right: u32 }`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Node {
    /// Box minimum.
    pub min: [f32; 3],
    /// Left child reference.
    pub left: u32,
    /// Box maximum.
    pub max: [f32; 3],
    /// Right child reference.
    pub right: u32,
}

/// Why a tree is invalid (see [`Lbvh::check`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LbvhError {
    /// Buffer sizes do not match the sample count.
    SizeMismatch,
    /// A child reference points outside the arrays.
    BadReference,
    /// A primitive is reached twice or never, or a node twice.
    NotATree,
    /// A child's box is not inside its parent's.
    BoxNotContained,
    /// A box has a NaN.
    NotFinite,
}

/// A read-only view of a built tree: what every tracer traverses.
#[derive(Clone, Copy, Debug)]
pub struct Lbvh<'a> {
    /// `n − 1` internal nodes (empty for `n <= 1`).
    pub nodes: &'a [Node],
    /// The `n` packed samples in sorted (leaf) order.
    pub samples: &'a [u64],
    /// Decoder of the packed samples.
    pub deq: Dequantizer,
}

/// Karras' δ: length of the common prefix of keys `i` and `j`, with the index as tie-break;
/// −1 when `j` is outside `0..n`.
#[inline(always)]
fn delta(keys: &[SortKey], i: i64, j: i64) -> i32 {
    if j < 0 || j >= keys.len() as i64 {
        return -1;
    }
    let a = keys[i as usize].code;
    let b = keys[j as usize].code;
    if a == b {
        64 + ((i as u32) ^ (j as u32)).leading_zeros() as i32
    } else {
        (a ^ b).leading_zeros() as i32
    }
}

/// The two child references of internal node `i` (`0 <= i < n − 1`) of the radix tree over the
/// sorted keys (Karras 2012, Figure 4).
pub fn karras_node(keys: &[SortKey], i: usize) -> (u32, u32) {
    let i = i as i64;
    let d: i64 = if delta(keys, i, i + 1) - delta(keys, i, i - 1) >= 0 { 1 } else { -1 };
    let d_min = delta(keys, i, i - d);
    let mut l_max: i64 = 2;
    while delta(keys, i, i + l_max * d) > d_min {
        l_max *= 2;
    }
    let mut l: i64 = 0;
    let mut t = l_max / 2;
    while t >= 1 {
        if delta(keys, i, i + (l + t) * d) > d_min {
            l += t;
        }
        t /= 2;
    }
    let j = i + l * d;
    let d_node = delta(keys, i, j);
    let mut s: i64 = 0;
    let mut div: i64 = 2;
    loop {
        let t = (l + div - 1) / div;
        if delta(keys, i, i + (s + t) * d) > d_node {
            s += t;
        }
        if t <= 1 {
            break;
        }
        div *= 2;
    }
    let gamma = i + s * d + d.min(0);
    let left = if i.min(j) == gamma { gamma as u32 | LEAF_BIT } else { gamma as u32 };
    let right = if i.max(j) == gamma + 1 { (gamma + 1) as u32 | LEAF_BIT } else { (gamma + 1) as u32 };
    (left, right)
}

/// Index into the parents buffer (`2n − 1` long) of a child reference: internal node `k` at
/// `k`, leaf `k` at `n − 1 + k`.
#[inline(always)]
pub fn parent_slot(child: u32, n: usize) -> usize {
    if child & LEAF_BIT != 0 {
        n - 1 + (child & !LEAF_BIT) as usize
    } else {
        child as usize
    }
}

/// Stores node `i`'s children and records `i` as their parent.
#[inline]
pub fn write_node_links(nodes: &mut [Node], parents: &mut [u32], i: usize, children: (u32, u32)) {
    let n = nodes.len() + 1;
    nodes[i].left = children.0;
    nodes[i].right = children.1;
    parents[parent_slot(children.0, n)] = i as u32;
    parents[parent_slot(children.1, n)] = i as u32;
}

/// Copies samples and colors into sorted order: `out[k] = in[keys[k].index]`.
///
/// # Panics
/// If lengths differ.
pub fn reorder(keys: &[SortKey], samples: &[u64], colors: &[u32], out_samples: &mut [u64], out_colors: &mut [u32]) {
    assert!(samples.len() == keys.len() && colors.len() == keys.len());
    for ((k, s), c) in keys.iter().zip(out_samples.iter_mut()).zip(out_colors.iter_mut()) {
        *s = samples[k.index as usize];
        *c = colors[k.index as usize];
    }
}

/// The (conservative) box of leaf `k`.
#[inline]
pub fn leaf_box(samples: &[u64], deq: &Dequantizer, k: usize) -> ([f32; 3], [f32; 3]) {
    let s = samples[k];
    sphere_box(deq.center(s), deq.radius(s))
}

/// The box of a child reference (leaf boxes from samples, node boxes from `nodes`).
#[inline]
pub fn child_box(nodes: &[Node], samples: &[u64], deq: &Dequantizer, child: u32) -> ([f32; 3], [f32; 3]) {
    if child & LEAF_BIT != 0 {
        leaf_box(samples, deq, (child & !LEAF_BIT) as usize)
    } else {
        let c = &nodes[child as usize];
        (c.min, c.max)
    }
}

/// Union of two boxes.
#[inline]
pub fn union(a: ([f32; 3], [f32; 3]), b: ([f32; 3], [f32; 3])) -> ([f32; 3], [f32; 3]) {
    (
        [a.0[0].min(b.0[0]), a.0[1].min(b.0[1]), a.0[2].min(b.0[2])],
        [a.1[0].max(b.1[0]), a.1[1].max(b.1[1]), a.1[2].max(b.1[2])],
    )
}

/// Fits node `i`'s box from its two children (which must be fitted already).
#[inline]
pub fn fit_node(nodes: &mut [Node], samples: &[u64], deq: &Dequantizer, i: usize) {
    let (l, r) = (nodes[i].left, nodes[i].right);
    let b = union(child_box(nodes, samples, deq, l), child_box(nodes, samples, deq, r));
    nodes[i].min = b.0;
    nodes[i].max = b.1;
}

/// Serial bottom-up step for leaf `k`: walks up from the leaf, fitting each node whose second
/// child arrives (`flags`, `n − 1` zeros at the start, counts arrivals). Run for every leaf, in
/// any order, it fits every node exactly once.
pub fn fit_from_leaf(
    nodes: &mut [Node],
    parents: &[u32],
    flags: &mut [u32],
    samples: &[u64],
    deq: &Dequantizer,
    k: usize,
) {
    let n = samples.len();
    let mut p = parents[n - 1 + k];
    while p != NO_PARENT {
        let pi = p as usize;
        flags[pi] += 1;
        if flags[pi] < 2 {
            return;
        }
        fit_node(nodes, samples, deq, pi);
        p = parents[pi];
    }
}

/// Builds the tree serially.
///
/// * `keys` must hold [`crate::morton::make_keys`] of the **unsorted** samples on entry; they
///   are sorted in place with `scratch` (same length).
/// * `out_samples`/`out_colors` (length `n`) receive the sorted samples and colors;
/// * `nodes` (`n − 1`, or 0 for `n <= 1`), `parents` (`2n − 1`, or 0 for `n == 0`) and `flags`
///   (`n − 1`) are overwritten.
///
/// # Panics
/// If a buffer has the wrong length.
#[allow(clippy::too_many_arguments)]
pub fn build(
    samples: &[u64],
    colors: &[u32],
    deq: &Dequantizer,
    keys: &mut [SortKey],
    scratch: &mut [SortKey],
    out_samples: &mut [u64],
    out_colors: &mut [u32],
    nodes: &mut [Node],
    parents: &mut [u32],
    flags: &mut [u32],
) {
    let n = samples.len();
    assert!(keys.len() == n && out_samples.len() == n && out_colors.len() == n);
    assert_eq!(nodes.len(), n.saturating_sub(1));
    assert_eq!(flags.len(), n.saturating_sub(1));
    assert_eq!(parents.len(), (2 * n).saturating_sub(1));
    crate::morton::radix_sort(keys, scratch);
    reorder(keys, samples, colors, out_samples, out_colors);
    if n == 0 {
        return;
    }
    parents[0] = NO_PARENT;
    for i in 0..n - 1 {
        write_node_links(nodes, parents, i, karras_node(keys, i));
    }
    flags.fill(0);
    for k in 0..n {
        fit_from_leaf(nodes, parents, flags, out_samples, deq, k);
    }
}

impl<'a> Lbvh<'a> {
    /// A view of a built tree.
    pub fn new(nodes: &'a [Node], samples: &'a [u64], deq: Dequantizer) -> Self {
        Lbvh { nodes, samples, deq }
    }

    /// Number of primitives.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether there is nothing to hit.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// Checks the tree: sizes match, every node and every primitive is reached exactly once
    /// from the root, every child's box lies inside its parent's, nothing is NaN. `seen` is a
    /// scratch buffer of at least `2n − 1` bytes.
    pub fn check(&self, seen: &mut [u8]) -> Result<(), LbvhError> {
        let n = self.samples.len();
        if n == 0 {
            return if self.nodes.is_empty() { Ok(()) } else { Err(LbvhError::SizeMismatch) };
        }
        if self.nodes.len() != n - 1 || seen.len() < 2 * n - 1 {
            return Err(LbvhError::SizeMismatch);
        }
        let seen = &mut seen[..2 * n - 1];
        seen.fill(0);
        if n == 1 {
            return Ok(());
        }
        let mut stack = [0u32; STACK_SIZE];
        let mut sp = 1;
        stack[0] = 0;
        seen[0] = 1;
        while sp > 0 {
            sp -= 1;
            let node = self.nodes[stack[sp] as usize];
            for v in node.min.iter().chain(node.max.iter()) {
                if v.is_nan() {
                    return Err(LbvhError::NotFinite);
                }
            }
            for child in [node.left, node.right] {
                let idx = child & !LEAF_BIT;
                let limit = if child & LEAF_BIT != 0 { n } else { n - 1 };
                if idx as usize >= limit {
                    return Err(LbvhError::BadReference);
                }
                let slot = parent_slot(child, n);
                if seen[slot] != 0 {
                    return Err(LbvhError::NotATree);
                }
                seen[slot] = 1;
                let (cmin, cmax) = child_box(self.nodes, self.samples, &self.deq, child);
                for a in 0..3 {
                    if !(cmin[a] >= node.min[a] && cmax[a] <= node.max[a]) {
                        return Err(LbvhError::BoxNotContained);
                    }
                }
                if child & LEAF_BIT == 0 {
                    if sp >= stack.len() {
                        return Err(LbvhError::NotATree);
                    }
                    stack[sp] = child;
                    sp += 1;
                }
            }
        }
        if seen.iter().all(|&s| s == 1) {
            Ok(())
        } else {
            Err(LbvhError::NotATree)
        }
    }
}
