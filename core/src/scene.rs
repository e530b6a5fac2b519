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

/// Why a scene's buffers cannot be drawn (what [`Scene::check`] rejects).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SceneError {
    /// Sample, color and node counts do not match (`n`, `n`, `n − 1`).
    CountMismatch,
    /// More samples than [`Scene::MAX_SAMPLES`].
    TooManySamples,
    /// The dequantizer has a non-finite origin, step or radius unit.
    NonFiniteDequantizer,
}

impl core::fmt::Display for SceneError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            SceneError::CountMismatch => "sample, color and node counts do not match",
            SceneError::TooManySamples => "more than 2^30 samples",
            SceneError::NonFiniteDequantizer => "dequantizer is not finite",
        })
    }
}

#[cfg(feature = "std")]
impl std::error::Error for SceneError {}

impl Scene {
    /// The most samples a scene may hold: sample ids (and the GPU's packed keys) need the top
    /// bits of a `u32` free.
    pub const MAX_SAMPLES: usize = 1 << 30;

    /// A scene with the frame's header and dequantizer but no samples: what a builder fills, and
    /// what a renderer draws as background.
    pub fn empty(header: &FrameHeader) -> Scene {
        Scene { header: *header, deq: header.dequantizer(), samples: Vec::new(), colors: Vec::new(), nodes: Vec::new() }
    }

    /// The rules every renderer and builder relies on: one color per sample, `n − 1` nodes, at
    /// most [`Scene::MAX_SAMPLES`] samples and a finite dequantizer. Returns the sample count.
    pub fn check(&self) -> Result<u32, SceneError> {
        let n = self.samples.len();
        if self.colors.len() != n || self.nodes.len() != n.saturating_sub(1) {
            return Err(SceneError::CountMismatch);
        }
        if n >= Self::MAX_SAMPLES {
            return Err(SceneError::TooManySamples);
        }
        let d = &self.deq;
        if !(d.min.is_finite() && d.step.is_finite() && d.radius_unit.is_finite()) {
            return Err(SceneError::NonFiniteDequantizer);
        }
        Ok(n as u32)
    }

    /// Builds the scene serially (the reference for parallel and GPU builders).
    pub fn build(frame: &Frame) -> Scene {
        let n = frame.samples.len();
        let deq = frame.header.dequantizer();
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
