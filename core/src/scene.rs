//! An owned, traceable scene: a received frame with its LBVH (feature `alloc`).

use crate::camera::Camera;
use crate::heuristics::Heuristic;
use crate::lbvh::{self, Lbvh, Node};
use crate::morton::{make_keys, SortKey};
use crate::sample::{Bounds, Dequantizer};
use crate::wire::{Frame, FrameHeader};
use alloc::vec;
use alloc::vec::Vec;

/// A frame ready to trace: samples and colors in leaf (Morton) order and the tree over them.
/// What a client keeps resident per sample: 8 B sample + 4 B color + 32 B node ≈ 44 B.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The fixed part of the frame it came from (camera it was rendered for, bounds, …).
    pub header: FrameHeader,
    /// Decoder of the packed samples.
    pub deq: Dequantizer,
    /// Packed samples, sorted.
    pub samples: Vec<u64>,
    /// Colors, in the same order.
    pub colors: Vec<u32>,
    /// `n − 1` internal nodes.
    pub nodes: Vec<Node>,
}

impl Scene {
    /// Builds the scene serially (the reference for parallel and GPU builders).
    pub fn build(frame: &Frame) -> Scene {
        let n = frame.samples.len();
        let deq = Dequantizer::new(frame.header.bounds, frame.header.radius_unit);
        let mut keys = vec![SortKey::default(); n];
        let mut scratch = vec![SortKey::default(); n];
        make_keys(&frame.samples, &mut keys);
        let mut samples = vec![0u64; n];
        let mut colors = vec![0u32; n];
        let mut nodes = vec![Node::default(); n.saturating_sub(1)];
        let mut parents = vec![0u32; (2 * n).saturating_sub(1)];
        let mut flags = vec![0u32; n.saturating_sub(1)];
        lbvh::build(
            &frame.samples,
            &frame.colors,
            &deq,
            &mut keys,
            &mut scratch,
            &mut samples,
            &mut colors,
            &mut nodes,
            &mut parents,
            &mut flags,
        );
        Scene { header: frame.header, deq, samples, colors, nodes }
    }

    /// The camera the frame was rendered for.
    pub fn camera(&self) -> &Camera {
        &self.header.camera
    }

    /// The heuristic the frame was rendered with.
    pub fn heuristic(&self) -> Heuristic {
        self.header.heuristic
    }

    /// The scene bounds.
    pub fn bounds(&self) -> Bounds {
        self.header.bounds
    }

    /// The tree view every tracer traverses.
    pub fn lbvh(&self) -> Lbvh<'_> {
        Lbvh::new(&self.nodes, &self.samples, self.deq)
    }

    /// Bytes held per the scene (samples, colors, nodes).
    pub fn resident_bytes(&self) -> usize {
        self.samples.len() * 8 + self.colors.len() * 4 + self.nodes.len() * core::mem::size_of::<Node>()
    }
}
