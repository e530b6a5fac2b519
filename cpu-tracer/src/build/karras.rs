//! Steps 4 and 5 of the build with [`Method::Karras`](super::Method::Karras):
//! [`karras_node`] for every internal node in parallel, each recording itself as its children's
//! parent (every slot has exactly one parent, so the writes never collide); then bottom-up
//! fitting from every leaf in parallel: a thread walking up stops at a node unless it is the
//! second to arrive (an atomic counter per node), so each node is fitted exactly once, after
//! both of its children — the union of the same two boxes as the serial build, hence the same
//! bytes.

use super::sort::SharedMut;
use super::GRAIN;
use crate::threads::Threads;
use std::sync::atomic::{AtomicU32, Ordering};
use volwarp_core::lbvh::{karras_node, leaf_box, parent_slot, union, Node, LEAF_BIT, NO_PARENT};
use volwarp_core::morton::SortKey;
use volwarp_core::sample::Dequantizer;

/// The method's scratch, kept between frames: parent pointers and arrival counters.
#[derive(Debug, Default)]
pub(super) struct Karras {
    parents: Vec<AtomicU32>,
    flags: Vec<AtomicU32>,
}

impl Karras {
    /// Step 4: the links of the `n − 1` nodes of the sorted `keys` (`n ≥ 2`), and the parent
    /// of every slot.
    pub(super) fn link(&mut self, keys: &[SortKey], nodes: &mut [Node], threads: &Threads) {
        let n = keys.len();
        self.parents.resize_with(2 * n - 1, || AtomicU32::new(0));
        let parents = &self.parents[..];
        parents[0].store(NO_PARENT, Ordering::Relaxed);
        threads.for_each_chunk(nodes, GRAIN, |c, nodes| {
            for (j, node) in nodes.iter_mut().enumerate() {
                let i = c * GRAIN + j;
                let (l, r) = karras_node(keys, i);
                node.left = l;
                node.right = r;
                parents[parent_slot(l, n)].store(i as u32, Ordering::Relaxed);
                parents[parent_slot(r, n)].store(i as u32, Ordering::Relaxed);
            }
        });
    }

    /// Step 5: the boxes of the nodes [`Karras::link`] linked, bottom-up.
    pub(super) fn fit(&mut self, samples: &[u64], deq: &Dequantizer, nodes: &mut [Node], threads: &Threads) {
        let n = samples.len();
        let parents = &self.parents[..];
        self.flags.resize_with(n - 1, || AtomicU32::new(0));
        let flags = &mut self.flags[..];
        threads.for_each_chunk(flags, GRAIN, |_, f| f.iter_mut().for_each(|x| *x.get_mut() = 0));
        let flags = &self.flags[..];
        let nodes = SharedMut::new(nodes);
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
                    unsafe { fit(&nodes, samples, deq, p as usize) };
                    p = parents[p as usize].load(Ordering::Relaxed);
                }
            }
        });
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
