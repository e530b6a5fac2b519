//! Step 4 of the build with [`Method::Agglomerative`](super::Method::Agglomerative):
//! Apetrei's bottom-up pass, which needs only δ of adjacent keys. Each of a few contiguous
//! chunks of leaves first computes its δ(i, i + 1) (from the packed key and the sorted sample's
//! low code bits), then walks up from each of its leaves in order, building — with plain
//! memory, no atomics — every node whose range lies inside the chunk. The few walks that reach
//! a chunk's start are resumed serially afterwards and build the nodes that straddle chunks.

use super::keys::{packed_code, Sorted};
use crate::threads::Threads;
use rayon::prelude::*;
use volwarp_core::lbvh::{leaf_box, union, Node, LEAF_BIT};
use volwarp_core::sample::Dequantizer;

/// An empty slot of the agglomerative pass.
const EMPTY: u32 = u32::MAX;

/// Chunks of leaves per thread in the agglomerative pass (a few, for load balance: the nodes
/// straddling chunks are built serially afterwards, about a tree depth per chunk).
const CHUNKS_PER_THREAD: usize = 4;

/// The pass's scratch, kept between frames: per node, the outer bound the first child to
/// arrive leaves, and δ of adjacent keys.
#[derive(Debug, Default)]
pub(super) struct Agglomerative {
    bounds: Vec<u32>,
    deltas: Vec<u8>,
}

impl Agglomerative {
    /// Builds the `n − 1` nodes (links and boxes) of the sorted `samples` (`n ≥ 2`) into
    /// `nodes`.
    pub(super) fn build(
        &mut self,
        sorted: Sorted,
        samples: &[u64],
        deq: &Dequantizer,
        nodes: &mut [Node],
        threads: &Threads,
    ) {
        let n = samples.len();
        self.bounds.resize(n - 1, EMPTY);
        self.deltas.resize(n - 1, 0);
        let (bounds, deltas) = (&mut self.bounds[..], &mut self.deltas[..]);
        // Phase 1: every chunk of leaves builds the nodes inside it, on one thread, with
        // plain memory; each stops where a walk would cross into the chunk before it.
        let chunk = if threads.is_serial() { n - 1 } else { (n - 1).div_ceil(threads.count() * CHUNKS_PER_THREAD) };
        let run = |c: usize, nodes: &mut [Node], bounds: &mut [u32], deltas: &mut [u8]| {
            let leaves = Leaves { sorted, samples, deq };
            agglomerate_chunk(&leaves, c * chunk, nodes, bounds, deltas)
        };
        let deferred: Vec<Option<(usize, usize)>> = if threads.is_serial() {
            vec![run(0, nodes, bounds, deltas)]
        } else {
            threads.install(|| {
                nodes
                    .par_chunks_mut(chunk)
                    .zip(bounds.par_chunks_mut(chunk))
                    .zip(deltas.par_chunks_mut(chunk))
                    .enumerate()
                    .map(|(c, ((nodes, bounds), deltas))| run(c, nodes, bounds, deltas))
                    .collect()
            })
        };
        // Phase 2: the walks that stopped at a chunk's start go on, serially, over the
        // whole arrays: they build the few nodes that straddle chunks.
        let leaves = Leaves { sorted, samples, deq };
        let deltas = Deltas { d: deltas, base: 0, before: 0 };
        for (l, r) in deferred.into_iter().flatten() {
            agglomerate_walk(&leaves, &deltas, 0, nodes, bounds, l, r, false);
        }
    }
}

/// What the agglomerative pass reads: the sorted order, samples and their decoder.
struct Leaves<'a> {
    sorted: Sorted<'a>,
    samples: &'a [u64],
    deq: &'a Dequantizer,
}

impl Leaves<'_> {
    /// The Morton code of sorted key `k`.
    #[inline(always)]
    fn code(&self, k: usize) -> u64 {
        match self.sorted {
            Sorted::Packed(p) => packed_code(p[k], self.samples[k]),
            Sorted::Keys(keys) => keys[k].code,
        }
    }

    fn len(&self) -> usize {
        self.samples.len()
    }
}

/// Karras' δ of adjacent sorted keys `i` and `i + 1` with codes `a` and `b`, exactly as core
/// computes it: their common prefix length, ties broken by position.
#[inline(always)]
fn delta_next(a: u64, b: u64, i: usize) -> u8 {
    if a == b {
        64 + ((i as u32) ^ (i as u32 + 1)).leading_zeros() as u8
    } else {
        (a ^ b).leading_zeros() as u8
    }
}

/// δ(i, i + 1) of the slots `base..` (`d`), and of slot `base − 1` (`before`).
struct Deltas<'a> {
    d: &'a [u8],
    base: usize,
    before: u8,
}

impl Deltas<'_> {
    #[inline(always)]
    fn at(&self, i: usize) -> u8 {
        if i + 1 == self.base {
            self.before
        } else {
            self.d[i - self.base]
        }
    }

    /// Whether the node covering sorted keys `[l, r]` (not the root) of `n` is its parent's
    /// left child: it merges with the neighbour that shares the longer prefix (the two are
    /// never equal in a radix tree).
    #[inline(always)]
    fn is_left_child(&self, n: usize, l: usize, r: usize) -> bool {
        l == 0 || (r + 1 < n && self.at(r) > self.at(l - 1))
    }
}

/// Phase 1 of the agglomerative pass over the chunk of leaves that starts at `base`:
/// `nodes`, `bounds` and `deltas` are the whole arrays' entries `base..` (`n − 1` in all, so
/// the last chunk also owns leaf `n − 1`). Fills the chunk's δ(i, i + 1), runs the walk of
/// every leaf of the chunk, in order, and returns the one walk (if any) that reached a slot
/// before `base`: a node `[base, r]` that is a right child, to be resumed over the whole arrays
/// once every chunk is done.
///
/// Every node a chunk completes has both children, hence its whole range, inside the chunk,
/// and it only touches slots inside it: chunks run concurrently on disjoint memory.
fn agglomerate_chunk(
    leaves: &Leaves,
    base: usize,
    nodes: &mut [Node],
    bounds: &mut [u32],
    deltas: &mut [u8],
) -> Option<(usize, usize)> {
    let n = leaves.len();
    bounds.fill(EMPTY);
    let mut next = leaves.code(base);
    for (j, d) in deltas.iter_mut().enumerate() {
        let code = next;
        next = leaves.code(base + j + 1);
        *d = delta_next(code, next, base + j);
    }
    let before = if base == 0 { 0 } else { delta_next(leaves.code(base - 1), leaves.code(base), base - 1) };
    let deltas = Deltas { d: deltas, base, before };
    let end = if base + nodes.len() + 1 == n { n } else { base + nodes.len() };
    let mut deferred = None;
    for k in base..end {
        let left = deltas.is_left_child(n, k, k);
        if let Some(d) = agglomerate_walk(leaves, &deltas, base, nodes, bounds, k, k, left) {
            deferred = Some(d);
        }
    }
    deferred
}

/// The agglomerative walk up from node `[l, r]` (`left`: whether it is its parent's left
/// child), over `nodes` and `bounds` holding the whole arrays' entries `base..`. A node joins
/// its parent, whose split is `r` (left child) or `l − 1` (right child); the first of the two
/// children to arrive leaves its outer bound in `bounds[split]` and stops, the second
/// completes the parent and walks on. In Karras' numbering (which the serial build uses) the
/// node split at `γ` has children `γ` and `γ + 1` (leaves when their range is a single key),
/// and is itself numbered `r` if it is a left child, `l` if a right child, 0 if the root: this
/// writes exactly the nodes `karras_node` and `fit_node` give.
///
/// Returns `Some((l, r))` without arriving if the split is before `base` (the walk is resumed
/// later with `base` 0). Run once for every leaf (in any order, `bounds` all [`EMPTY`] at the
/// start), the walks complete every node exactly once.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn agglomerate_walk(
    leaves: &Leaves,
    deltas: &Deltas,
    base: usize,
    nodes: &mut [Node],
    bounds: &mut [u32],
    mut l: usize,
    mut r: usize,
    mut left: bool,
) -> Option<(usize, usize)> {
    let n = leaves.len();
    loop {
        let split = if left { r } else { l - 1 };
        if split < base {
            return Some((l, r));
        }
        let slot = &mut bounds[split - base];
        if *slot == EMPTY {
            *slot = if left { l } else { r } as u32;
            return None;
        }
        let (pl, pr) = if left { (l, *slot as usize) } else { (*slot as usize, r) };
        let lref = if pl == split { split as u32 | LEAF_BIT } else { split as u32 };
        let rref = if pr == split + 1 { (split + 1) as u32 | LEAF_BIT } else { (split + 1) as u32 };
        let child = |c: u32| {
            if c & LEAF_BIT != 0 {
                leaf_box(leaves.samples, leaves.deq, (c & !LEAF_BIT) as usize)
            } else {
                let node = &nodes[c as usize - base];
                (node.min, node.max)
            }
        };
        let b = union(child(lref), child(rref));
        let root = pl == 0 && pr == n - 1;
        let p_left = !root && deltas.is_left_child(n, pl, pr);
        let idx = if root {
            0
        } else if p_left {
            pr
        } else {
            pl
        };
        nodes[idx - base] = Node { min: b.0, left: lref, max: b.1, right: rref };
        if root {
            return None;
        }
        (l, r, left) = (pl, pr, p_left);
    }
}
