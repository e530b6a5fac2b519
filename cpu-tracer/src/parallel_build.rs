//! The parallel LBVH build: core's per-node steps driven by rayon, giving the same bytes as
//! the serial [`volwarp_core::Scene::build`] (tested).
//!
//! 1. Morton codes of the unsorted samples, in parallel chunks;
//! 2. the parallel stable radix sort ([`crate::parallel_sort`]) — order `(code, index)`; up to
//!    [`PACKED_MAX_LEN`] samples it moves 8-byte packed keys ([`par_sort_packed`]: the code
//!    without its lowest digit, and the input index), past that 16-byte [`SortKey`]s;
//! 3. samples and colors gathered into sorted order, in parallel;
//! 4. the hierarchy and its boxes, by one of two [`Method`]s:
//!    * [`Method::Agglomerative`] (default): Apetrei's bottom-up pass, which needs only δ of
//!      adjacent keys. Each of a few contiguous chunks of leaves first computes its δ(i, i + 1)
//!      (from the packed key and the sorted sample's low code bits), then walks up from each
//!      of its leaves in order, building — with plain memory, no atomics — every node whose
//!      range lies inside the chunk. The few walks that reach a chunk's start are resumed
//!      serially afterwards and build the nodes that straddle chunks;
//!    * [`Method::Karras`]: [`karras_node`] for every internal node in parallel, each recording
//!      itself as its children's parent (every slot has exactly one parent, so the writes never
//!      collide); then bottom-up fitting from every leaf in parallel: a thread walking up stops
//!      at a node unless it is the second to arrive (an atomic counter per node), so each node
//!      is fitted exactly once, after both of its children — the union of the same two boxes as
//!      the serial build, hence the same bytes.
//!
//! A [`ParallelBuilder`] keeps its scratch buffers between frames, and
//! [`ParallelBuilder::build_into`] also reuses the previous scene's buffers: a client that
//! rebuilds every frame allocates (and page-faults) nothing in steady state.

use crate::parallel_sort::{
    packed_index, par_radix_sort, par_sort_packed, SharedMut, PACKED_INDEX_BITS, PACKED_MAX_LEN,
};
use crate::threads::Threads;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, Ordering};
use volwarp_core::lbvh::{karras_node, leaf_box, parent_slot, union, Node, LEAF_BIT, NO_PARENT};
use volwarp_core::morton::{code_of_sample, SortKey, RADIX_BITS};
use volwarp_core::sample::{Dequantizer, POS_BITS};
use volwarp_core::wire::Frame;
use volwarp_core::Scene;

/// Items per unit of parallel work.
const GRAIN: usize = 1 << 14;

/// Wall time of each step of the last build, in microseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BuildTimes {
    /// Morton codes (or 16-byte keys past [`PACKED_MAX_LEN`] samples).
    pub keys_us: u64,
    /// Radix sort.
    pub sort_us: u64,
    /// Gathering samples and colors into sorted order.
    pub gather_us: u64,
    /// The hierarchy: links and boxes with [`Method::Agglomerative`]; links and parent
    /// pointers only with [`Method::Karras`].
    pub hierarchy_us: u64,
    /// Bottom-up fitting ([`Method::Karras`] only; 0 with [`Method::Agglomerative`]).
    pub fit_us: u64,
}

/// How the hierarchy is built; both give the serial build's bytes (tested).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Method {
    /// Apetrei's (2014) agglomerative bottom-up pass: one walk up from every leaf builds the
    /// links *and* fits the boxes, with no binary searches; chunks of leaves build their inner
    /// nodes without atomics (the default: fastest).
    #[default]
    Agglomerative,
    /// Karras' per-node [`karras_node`] for every internal node, then a bottom-up fit.
    Karras,
}

/// An empty slot of the agglomerative pass.
const EMPTY: u32 = u32::MAX;

/// Chunks of leaves per thread in the agglomerative pass (a few, for load balance: the nodes
/// straddling chunks are built serially afterwards, about a tree depth per chunk).
const CHUNKS_PER_THREAD: usize = 4;

/// The parallel scene builder with its reusable scratch buffers.
#[derive(Debug)]
pub struct ParallelBuilder {
    method: Method,
    bounds: Vec<u32>,
    times: BuildTimes,
    threads: Threads,
    keys: Vec<SortKey>,
    scratch: Vec<SortKey>,
    codes: Vec<u64>,
    packed: Vec<u64>,
    packed_scratch: Vec<u64>,
    deltas: Vec<u8>,
    parents: Vec<AtomicU32>,
    flags: Vec<AtomicU32>,
}

/// Builds a scene with one thread per core (creates a thread pool per call: keep a
/// [`ParallelBuilder`] to build repeatedly).
pub fn build_scene(frame: &Frame) -> Scene {
    ParallelBuilder::new(0).build(frame)
}

impl ParallelBuilder {
    /// A builder on `threads` threads (0: one per core; 1 builds on the caller's thread).
    pub fn new(threads: usize) -> Self {
        ParallelBuilder {
            method: Method::default(),
            bounds: Vec::new(),
            times: BuildTimes::default(),
            threads: Threads::new(threads),
            keys: Vec::new(),
            scratch: Vec::new(),
            codes: Vec::new(),
            packed: Vec::new(),
            packed_scratch: Vec::new(),
            deltas: Vec::new(),
            parents: Vec::new(),
            flags: Vec::new(),
        }
    }

    /// The number of threads it builds with.
    pub fn threads(&self) -> usize {
        self.threads.count()
    }

    /// The same builder with another hierarchy method.
    pub fn with_method(mut self, method: Method) -> Self {
        self.method = method;
        self
    }

    /// Step times of the last build.
    pub fn last_times(&self) -> BuildTimes {
        self.times
    }

    /// Builds the scene of `frame` into new buffers. A frame whose color count differs from
    /// its sample count (never one read by the wire codec) is cut to the shorter (logged).
    pub fn build(&mut self, frame: &Frame) -> Scene {
        let mut scene = Scene {
            header: frame.header,
            deq: Dequantizer::new(frame.header.bounds, frame.header.radius_unit),
            samples: Vec::new(),
            colors: Vec::new(),
            nodes: Vec::new(),
        };
        self.build_into(frame, &mut scene);
        scene
    }

    /// Builds the scene of `frame` into `scene`, reusing its buffers.
    pub fn build_into(&mut self, frame: &Frame, scene: &mut Scene) {
        let mut n = frame.samples.len();
        if frame.colors.len() != n {
            log::warn!("frame has {} samples but {} colors; using the shorter", n, frame.colors.len());
            n = n.min(frame.colors.len());
        }
        let in_samples = &frame.samples[..n];
        let in_colors = &frame.colors[..n];
        let deq = Dequantizer::new(frame.header.bounds, frame.header.radius_unit);
        scene.header = frame.header;
        scene.deq = deq;
        let threads = &self.threads;
        let mut clock = std::time::Instant::now();
        let mut lap = || {
            let now = std::time::Instant::now();
            let us = (now - clock).as_micros() as u64;
            clock = now;
            us
        };
        self.times = BuildTimes::default();

        // 1. Morton codes of the unsorted samples (16-byte keys past the packed sort's limit)
        let sorted = if n <= PACKED_MAX_LEN {
            self.codes.resize(n, 0);
            threads.for_each_chunk(&mut self.codes, GRAIN, |c, codes| {
                for (o, &s) in codes.iter_mut().zip(&in_samples[c * GRAIN..]) {
                    *o = code_of_sample(s);
                }
            });
            self.times.keys_us = lap();
            // 2. sort
            self.packed.resize(n, 0);
            self.packed_scratch.resize(n, 0);
            par_sort_packed(&self.codes, &mut self.packed, &mut self.packed_scratch, threads);
            Sorted::Packed(&self.packed)
        } else {
            self.keys.resize(n, SortKey::default());
            threads.for_each_chunk(&mut self.keys, GRAIN, |c, ks| {
                for (j, k) in ks.iter_mut().enumerate() {
                    let i = c * GRAIN + j;
                    *k = SortKey { code: code_of_sample(in_samples[i]), index: i as u32, pad: 0 };
                }
            });
            self.times.keys_us = lap();
            self.scratch.resize(n, SortKey::default());
            par_radix_sort(&mut self.keys, &mut self.scratch, threads);
            Sorted::Keys(&self.keys)
        };
        self.times.sort_us = lap();

        // 3. gather
        scene.samples.resize(n, 0);
        scene.colors.resize(n, 0);
        let gather = |start: usize, out_s: &mut [u64], out_c: &mut [u32]| {
            for (j, (s, c)) in out_s.iter_mut().zip(out_c.iter_mut()).enumerate() {
                let i = sorted.index(start + j);
                (*s, *c) = (in_samples[i], in_colors[i]);
            }
        };
        let (out_s, out_c) = (&mut scene.samples[..], &mut scene.colors[..]);
        if threads.is_serial() {
            gather(0, out_s, out_c);
        } else {
            threads.install(|| {
                out_s
                    .par_chunks_mut(GRAIN)
                    .zip(out_c.par_chunks_mut(GRAIN))
                    .enumerate()
                    .for_each(|(c, (s, col))| gather(c * GRAIN, s, col))
            });
        }
        scene.nodes.resize(n.saturating_sub(1), Node::default());
        self.times.gather_us = lap();
        if n <= 1 {
            return;
        }

        match self.method {
            Method::Agglomerative => {
                self.bounds.resize(n - 1, EMPTY);
                self.deltas.resize(n - 1, 0);
                let (samples, nodes) = (&scene.samples[..], &mut scene.nodes[..]);
                let (bounds, deltas) = (&mut self.bounds[..], &mut self.deltas[..]);
                // Phase 1: every chunk of leaves builds the nodes inside it, on one thread, with
                // plain memory; each stops where a walk would cross into the chunk before it.
                let chunk =
                    if threads.is_serial() { n - 1 } else { (n - 1).div_ceil(threads.count() * CHUNKS_PER_THREAD) };
                let run = |c: usize, nodes: &mut [Node], bounds: &mut [u32], deltas: &mut [u8]| {
                    let leaves = Leaves { sorted, samples, deq: &deq };
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
                let leaves = Leaves { sorted, samples, deq: &deq };
                let deltas = Deltas { d: deltas, base: 0, before: 0 };
                for (l, r) in deferred.into_iter().flatten() {
                    agglomerate_walk(&leaves, &deltas, 0, nodes, bounds, l, r, false);
                }
                self.times.hierarchy_us = lap();
            }
            Method::Karras => {
                // 4. hierarchy, over 16-byte keys (core's `karras_node` takes them)
                if n <= PACKED_MAX_LEN {
                    let (packed, samples) = (&self.packed[..], &scene.samples[..]);
                    self.keys.resize(n, SortKey::default());
                    threads.for_each_chunk(&mut self.keys, GRAIN, |c, ks| {
                        for (j, k) in ks.iter_mut().enumerate() {
                            let i = c * GRAIN + j;
                            let code = packed_code(packed[i], samples[i]);
                            *k = SortKey { code, index: packed_index(packed[i]) as u32, pad: 0 };
                        }
                    });
                }
                let keys = &self.keys[..];
                self.parents.resize_with(2 * n - 1, || AtomicU32::new(0));
                let parents = &self.parents[..];
                parents[0].store(NO_PARENT, Ordering::Relaxed);
                threads.for_each_chunk(&mut scene.nodes, GRAIN, |c, nodes| {
                    for (j, node) in nodes.iter_mut().enumerate() {
                        let i = c * GRAIN + j;
                        let (l, r) = karras_node(keys, i);
                        node.left = l;
                        node.right = r;
                        parents[parent_slot(l, n)].store(i as u32, Ordering::Relaxed);
                        parents[parent_slot(r, n)].store(i as u32, Ordering::Relaxed);
                    }
                });

                self.times.hierarchy_us = lap();
                // 5. bottom-up fit
                self.flags.resize_with(n - 1, || AtomicU32::new(0));
                let flags = &mut self.flags[..];
                threads.for_each_chunk(flags, GRAIN, |_, f| f.iter_mut().for_each(|x| *x.get_mut() = 0));
                let flags = &self.flags[..];
                let samples = &scene.samples[..];
                let nodes = SharedMut::new(&mut scene.nodes);
                threads.for_each_range(n, GRAIN, |range| {
                    for k in range {
                        let mut p = parents[n - 1 + k].load(Ordering::Relaxed);
                        while p != NO_PARENT {
                            // AcqRel: the second arrival sees the box its sibling's fitter wrote.
                            if flags[p as usize].fetch_add(1, Ordering::AcqRel) == 0 {
                                break;
                            }
                            // SAFETY: only the second thread to arrive at `p` gets here, once, and
                            // both children of `p` are fitted (by this thread, or by the first arrival
                            // whose writes the AcqRel counter made visible). Node `p`'s box is read by
                            // the fitter of its parent only after that parent's counter is
                            // incremented by this thread, after the write. The links were written
                            // in step 4, before this step started, and are only read now.
                            unsafe { fit(&nodes, samples, &deq, p as usize) };
                            p = parents[p as usize].load(Ordering::Relaxed);
                        }
                    }
                });
                self.times.fit_us = lap();
            }
        }
    }
}

/// The sorted order: packed keys (with the sorted samples, they give the codes), or 16-byte
/// keys past [`PACKED_MAX_LEN`].
#[derive(Clone, Copy)]
enum Sorted<'a> {
    Packed(&'a [u64]),
    Keys(&'a [SortKey]),
}

impl Sorted<'_> {
    /// The input index of sorted key `k`.
    #[inline(always)]
    fn index(&self, k: usize) -> usize {
        match self {
            Sorted::Packed(p) => packed_index(p[k]),
            Sorted::Keys(keys) => keys[k].index as usize,
        }
    }
}

/// The low [`RADIX_BITS`] bits of a sample's Morton code (the digit a packed key lacks),
/// from a table: `x` bits 0–3 go to 0, 3, 6, 9, `y` bits 0–3 to 1, 4, 7, 10, `z` bits 0–2 to
/// 2, 5, 8.
#[inline(always)]
fn low_code_bits(s: u64) -> u64 {
    const SPREAD4: [u16; 16] = {
        let mut t = [0u16; 16];
        let mut v = 0;
        while v < 16 {
            t[v] = ((v & 1) | (v & 2) << 2 | (v & 4) << 4 | (v & 8) << 6) as u16;
            v += 1;
        }
        t
    };
    let (x, y, z) = (s as usize & 15, (s >> POS_BITS) as usize & 15, (s >> (2 * POS_BITS)) as usize & 15);
    (SPREAD4[x] as u64 | (SPREAD4[y] as u64) << 1 | (SPREAD4[z] as u64) << 2) & ((1 << RADIX_BITS) - 1)
}

/// The Morton code of a packed key whose sample is `s`.
#[inline(always)]
fn packed_code(key: u64, s: u64) -> u64 {
    (key >> PACKED_INDEX_BITS) << RADIX_BITS | low_code_bits(s)
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

/// Fits node `i` from its children, reading and writing the node array through `nodes`:
/// `lbvh::fit_node`'s union of the same two boxes.
///
/// # Safety
/// Both children of `i` must be fitted with their writes visible to this thread, no other
/// thread may access node `i`'s box during the call, and node links must not change.
unsafe fn fit(nodes: &SharedMut<Node>, samples: &[u64], deq: &Dequantizer, i: usize) {
    // SAFETY: per the function's contract.
    unsafe {
        let (l, r) = nodes.read_links(i);
        let child = |c: u32| {
            if c & LEAF_BIT != 0 {
                leaf_box(samples, deq, (c & !LEAF_BIT) as usize)
            } else {
                nodes.read_box(c as usize)
            }
        };
        let b = union(child(l), child(r));
        nodes.write_box(i, b);
    }
}

impl SharedMut<Node> {
    /// The child links of node `i`.
    ///
    /// # Safety
    /// No thread may write node `i`'s links concurrently.
    unsafe fn read_links(&self, i: usize) -> (u32, u32) {
        let p = self.ptr_at(i);
        // SAFETY: in bounds (ptr_at checks); links are not written concurrently.
        unsafe { ((*p).left, (*p).right) }
    }

    /// The box of node `i`.
    ///
    /// # Safety
    /// Node `i`'s box must be written and visible, and not written concurrently.
    unsafe fn read_box(&self, i: usize) -> ([f32; 3], [f32; 3]) {
        let p = self.ptr_at(i);
        // SAFETY: as above; raw field reads, no reference to the whole node is formed.
        unsafe { (std::ptr::addr_of!((*p).min).read(), std::ptr::addr_of!((*p).max).read()) }
    }

    /// Writes the box of node `i`.
    ///
    /// # Safety
    /// No other thread may access node `i`'s box concurrently.
    unsafe fn write_box(&self, i: usize, b: ([f32; 3], [f32; 3])) {
        let p = self.ptr_at(i);
        // SAFETY: as above; raw field writes only.
        unsafe {
            std::ptr::addr_of_mut!((*p).min).write(b.0);
            std::ptr::addr_of_mut!((*p).max).write(b.1);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn low_code_bits_are_the_codes_low_digit() {
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..10_000 {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let s = x >> 8;
            assert_eq!(low_code_bits(s), code_of_sample(s) & ((1 << RADIX_BITS) - 1), "{s:#x}");
            let key = (code_of_sample(s) >> RADIX_BITS) << PACKED_INDEX_BITS | 12345;
            assert_eq!(packed_code(key, s), code_of_sample(s));
        }
    }
}
