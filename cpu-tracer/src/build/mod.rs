//! The parallel LBVH build: core's per-node steps driven by rayon, giving the same bytes as
//! the serial [`volwarp_core::Scene::build`] (tested). One file per step, driven and timed by
//! [`ParallelBuilder::build_into`] here:
//!
//! 1. Morton codes of the unsorted samples, in parallel chunks (`keys.rs`);
//! 2. the parallel stable radix sort ([`sort`], also public as `crate::parallel_sort`), order
//!    `(code, index)`; up to [`sort::PACKED_MAX_LEN`] samples it moves 8-byte packed keys
//!    ([`sort::par_sort_packed`]: the code without its lowest digit, and the input index), past
//!    that 16-byte [`SortKey`](volwarp_core::morton::SortKey)s (`keys.rs`);
//! 3. samples and colors gathered into sorted order, in parallel (`gather.rs`);
//! 4. the hierarchy and its boxes, by one of two [`Method`]s:
//!    * [`Method::Agglomerative`] (default, `agglomerative.rs`): Apetrei's bottom-up pass,
//!      which needs only δ of adjacent keys. Each of a few contiguous chunks of leaves first
//!      computes its δ(i, i + 1) (from the packed key and the sorted sample's low code bits),
//!      then walks up from each of its leaves in order, building — with plain memory, no
//!      atomics — every node whose range lies inside the chunk. The few walks that reach a
//!      chunk's start are resumed serially afterwards and build the nodes that straddle chunks;
//!    * [`Method::Karras`] (`karras.rs`):
//!      [`karras_node`](volwarp_core::lbvh::karras_node) for every internal node in parallel,
//!      each recording itself as its children's parent (every slot has exactly one parent, so
//!      the writes never collide); then (5.) bottom-up fitting from every leaf in parallel: a
//!      thread walking up stops at a node unless it is the second to arrive (an atomic counter
//!      per node), so each node is fitted exactly once, after both of its children — the union
//!      of the same two boxes as the serial build, hence the same bytes.
//!
//! A [`ParallelBuilder`] keeps its scratch buffers between frames, and
//! [`ParallelBuilder::build_into`] also reuses the previous scene's buffers: a client that
//! rebuilds every frame allocates (and page-faults) nothing in steady state.

mod agglomerative;
mod gather;
mod karras;
mod keys;
pub mod sort;

use crate::threads::Threads;
use agglomerative::Agglomerative;
use karras::Karras;
use keys::KeyBuffers;
use volwarp_core::lbvh::Node;
use volwarp_core::wire::Frame;
use volwarp_core::Scene;

/// Items per unit of parallel work.
const GRAIN: usize = 1 << 14;

/// Wall time of each step of the last build, in microseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BuildTimes {
    /// Morton codes (or 16-byte keys past [`sort::PACKED_MAX_LEN`] samples).
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
    /// Karras' per-node [`karras_node`](volwarp_core::lbvh::karras_node) for every internal node, then a bottom-up fit.
    Karras,
}

/// The parallel scene builder with its reusable scratch buffers.
#[derive(Debug)]
pub struct ParallelBuilder {
    method: Method,
    times: BuildTimes,
    threads: Threads,
    keys: KeyBuffers,
    agglomerative: Agglomerative,
    karras: Karras,
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
            times: BuildTimes::default(),
            threads: Threads::new(threads),
            keys: KeyBuffers::default(),
            agglomerative: Agglomerative::default(),
            karras: Karras::default(),
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
        let mut scene = Scene::empty(&frame.header);
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
        let deq = frame.header.dequantizer();
        scene.header = frame.header;
        scene.deq = deq;
        let threads = &self.threads;
        let mut clock = Clock::start();
        self.times = BuildTimes::default();

        // 1–2. Morton codes and sort
        let sorted = self.keys.sort(in_samples, threads, &mut clock, &mut self.times);

        // 3. gather
        scene.samples.resize(n, 0);
        scene.colors.resize(n, 0);
        gather::gather(sorted, in_samples, in_colors, &mut scene.samples, &mut scene.colors, threads);
        scene.nodes.resize(n.saturating_sub(1), Node::default());
        self.times.gather_us = clock.lap();
        if n <= 1 {
            return;
        }

        match self.method {
            Method::Agglomerative => {
                // 4. hierarchy and boxes in one pass
                self.agglomerative.build(sorted, &scene.samples, &deq, &mut scene.nodes, threads);
                self.times.hierarchy_us = clock.lap();
            }
            Method::Karras => {
                // 4. hierarchy, over 16-byte keys (core's `karras_node` takes them)
                let keys = self.keys.sort_keys(&scene.samples, threads);
                self.karras.link(keys, &mut scene.nodes, threads);
                self.times.hierarchy_us = clock.lap();
                // 5. bottom-up fit
                self.karras.fit(&scene.samples, &deq, &mut scene.nodes, threads);
                self.times.fit_us = clock.lap();
            }
        }
    }
}

/// The wall clock of the build's steps.
struct Clock(std::time::Instant);

impl Clock {
    fn start() -> Self {
        Clock(std::time::Instant::now())
    }

    /// Microseconds since the last lap (or the start).
    fn lap(&mut self) -> u64 {
        let now = std::time::Instant::now();
        let us = (now - self.0).as_micros() as u64;
        self.0 = now;
        us
    }
}
