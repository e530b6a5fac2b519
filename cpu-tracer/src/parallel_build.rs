//! The parallel LBVH build: core's per-node steps driven by rayon, giving the same bytes as
//! the serial [`volwarp_core::Scene::build`] (tested).
//!
//! 1. Morton keys of the unsorted samples, in parallel chunks;
//! 2. the parallel stable radix sort ([`crate::parallel_sort`]) — order `(code, index)`;
//! 3. samples and colors gathered into sorted order, in parallel;
//! 4. [`karras_node`] for every internal node in parallel, each recording itself as its
//!    children's parent (every slot has exactly one parent, so the writes never collide);
//! 5. bottom-up fitting from every leaf in parallel: a thread walking up stops at a node
//!    unless it is the second to arrive (an atomic counter per node), so each node is fitted
//!    exactly once, after both of its children — the union of the same two boxes as the serial
//!    build, hence the same bytes.
//!
//! A [`ParallelBuilder`] keeps its scratch buffers between frames, and
//! [`ParallelBuilder::build_into`] also reuses the previous scene's buffers: a client that
//! rebuilds every frame allocates (and page-faults) nothing in steady state.

use crate::parallel_sort::{par_radix_sort, SharedMut};
use crate::threads::Threads;
use std::sync::atomic::{AtomicU32, Ordering};
use volwarp_core::lbvh::{karras_node, leaf_box, parent_slot, union, Node, LEAF_BIT, NO_PARENT};
use volwarp_core::morton::{code_of_sample, SortKey};
use volwarp_core::sample::Dequantizer;
use volwarp_core::wire::Frame;
use volwarp_core::Scene;

/// Items per unit of parallel work.
const GRAIN: usize = 1 << 14;

/// Wall time of each step of the last build, in microseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BuildTimes {
    /// Morton keys.
    pub keys_us: u64,
    /// Radix sort.
    pub sort_us: u64,
    /// Gathering samples and colors into sorted order.
    pub gather_us: u64,
    /// Karras hierarchy and parent links.
    pub hierarchy_us: u64,
    /// Bottom-up fitting.
    pub fit_us: u64,
}

/// How the hierarchy is built; both give the serial build's bytes (tested).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Method {
    /// Apetrei's (2014) agglomerative bottom-up pass: one walk up from every leaf builds the
    /// links *and* fits the boxes, with no binary searches (the default: fastest).
    #[default]
    Agglomerative,
    /// Karras' per-node [`karras_node`] for every internal node, then a bottom-up fit.
    Karras,
}

/// An empty slot of the agglomerative pass.
const EMPTY: u32 = u32::MAX;

/// The parallel scene builder with its reusable scratch buffers.
#[derive(Debug)]
pub struct ParallelBuilder {
    method: Method,
    bounds: Vec<AtomicU32>,
    times: BuildTimes,
    threads: Threads,
    keys: Vec<SortKey>,
    scratch: Vec<SortKey>,
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

        // 1. keys
        self.keys.resize(n, SortKey::default());
        threads.for_each_chunk(&mut self.keys, GRAIN, |c, ks| {
            for (j, k) in ks.iter_mut().enumerate() {
                let i = c * GRAIN + j;
                *k = SortKey { code: code_of_sample(in_samples[i]), index: i as u32, pad: 0 };
            }
        });
        self.times.keys_us = lap();
        // 2. sort
        self.scratch.resize(n, SortKey::default());
        par_radix_sort(&mut self.keys, &mut self.scratch, threads);
        self.times.sort_us = lap();
        let keys = &self.keys[..];

        // 3. gather
        scene.samples.resize(n, 0);
        scene.colors.resize(n, 0);
        threads.for_each_chunk(&mut scene.samples, GRAIN, |c, out| {
            for (o, k) in out.iter_mut().zip(&keys[c * GRAIN..]) {
                *o = in_samples[k.index as usize];
            }
        });
        threads.for_each_chunk(&mut scene.colors, GRAIN, |c, out| {
            for (o, k) in out.iter_mut().zip(&keys[c * GRAIN..]) {
                *o = in_colors[k.index as usize];
            }
        });
        scene.nodes.resize(n.saturating_sub(1), Node::default());
        self.times.gather_us = lap();
        if n <= 1 {
            return;
        }

        match self.method {
            Method::Agglomerative => {
                self.bounds.resize_with(n - 1, || AtomicU32::new(EMPTY));
                threads.for_each_chunk(&mut self.bounds, GRAIN, |_, f| f.iter_mut().for_each(|x| *x.get_mut() = EMPTY));
                let nodes = SharedMut::new(&mut scene.nodes);
                let (bounds, samples) = (&self.bounds[..], &scene.samples[..]);
                threads.for_each_range(n, GRAIN, |range| {
                    for k in range {
                        // SAFETY: `bounds` was reset to EMPTY above and `nodes` is not
                        // otherwise accessed during this step.
                        unsafe { agglomerate(keys, bounds, &nodes, samples, &deq, k) };
                    }
                });
                self.times.hierarchy_us = lap();
            }
            Method::Karras => {
                // 4. hierarchy
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

/// Karras' δ, exactly as core computes it: common prefix length of sorted keys `i` and `j`,
/// ties broken by position; −1 outside the array.
#[inline(always)]
fn delta(keys: &[SortKey], i: usize, j: isize) -> i32 {
    if j < 0 || j as usize >= keys.len() {
        return -1;
    }
    let (a, b) = (keys[i].code, keys[j as usize].code);
    if a == b {
        64 + ((i as u32) ^ (j as u32)).leading_zeros() as i32
    } else {
        (a ^ b).leading_zeros() as i32
    }
}

/// Whether the node covering sorted keys `[l, r]` (not the root) is its parent's left child:
/// it merges with the neighbour that shares the longer prefix (the two are never equal in a
/// radix tree).
#[inline(always)]
fn is_left_child(keys: &[SortKey], l: usize, r: usize) -> bool {
    l == 0 || (r + 1 < keys.len() && delta(keys, r, r as isize + 1) > delta(keys, l - 1, l as isize))
}

/// The agglomerative walk from leaf `k`. A node covering `[l, r]` joins its parent, whose
/// split is `r` (left child) or `l − 1` (right child); the first of the two children to
/// arrive leaves its outer bound in `bounds[split]` and stops, the second completes the
/// parent. In Karras' numbering (which the serial build uses) the node split at `γ` has
/// children `γ` and `γ + 1` (leaves when their range is a single key), and is itself numbered
/// `r` if it is a left child, `l` if a right child, 0 if the root: this writes exactly the
/// nodes `karras_node` and `fit_node` give.
///
/// # Safety
/// `bounds` (`n − 1` long) must hold [`EMPTY`] everywhere when the pass starts, this must run
/// once for every leaf, and nothing else may access the nodes during the pass.
unsafe fn agglomerate(
    keys: &[SortKey],
    bounds: &[AtomicU32],
    nodes: &SharedMut<Node>,
    samples: &[u64],
    deq: &Dequantizer,
    k: usize,
) {
    let n = keys.len();
    let (mut l, mut r) = (k, k);
    let mut left = is_left_child(keys, l, r);
    loop {
        let split = if left { r } else { l - 1 };
        let mine = if left { l } else { r } as u32;
        // AcqRel: the second arrival sees the node its sibling wrote before leaving its bound.
        let other = bounds[split].swap(mine, Ordering::AcqRel);
        if other == EMPTY {
            return;
        }
        let (pl, pr) = if left { (l, other as usize) } else { (other as usize, r) };
        let lref = if pl == split { split as u32 | LEAF_BIT } else { split as u32 };
        let rref = if pr == split + 1 { (split + 1) as u32 | LEAF_BIT } else { (split + 1) as u32 };
        let child = |c: u32| {
            if c & LEAF_BIT != 0 {
                leaf_box(samples, deq, (c & !LEAF_BIT) as usize)
            } else {
                // SAFETY: internal child `c` was written by this thread or by the sibling's
                // thread before its release above; nobody writes it again.
                unsafe { nodes.read_box(c as usize) }
            }
        };
        let b = union(child(lref), child(rref));
        let root = pl == 0 && pr == n - 1;
        let p_left = !root && is_left_child(keys, pl, pr);
        let idx = if root {
            0
        } else if p_left {
            pr
        } else {
            pl
        };
        // SAFETY: every internal node is completed exactly once (by the second arrival at
        // its split), so no other thread writes node `idx`; it is read only by the thread
        // completing its parent, after the release of the swap that follows (or by this one).
        unsafe { nodes.ptr_at(idx).write(Node { min: b.0, left: lref, max: b.1, right: rref }) };
        if root {
            return;
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
