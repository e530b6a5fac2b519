//! The stale image: the frame as the server rendered it, not warped — what a system that
//! sends images shows until the next one arrives. Each sample's centre is projected with the
//! **frame's** camera (`scene.header.camera`) to its own pixel (nearest to the viewer wins,
//! ties to the smaller index), whatever the current camera is; the frame's viewport is then
//! resized (nearest pixel) to the requested one.

use crate::depth_buffer::{DepthBuffer, Projector};
use crate::point_splat::splat_points;
use crate::threads::Threads;
use crate::{begin_frame_unbuilt_ok as begin_frame, MAX_VIEWPORT};
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::RendererKind;
use volwarp_core::{Camera, Scene};

/// The stale-image baseline (renderer name `stale`).
#[derive(Debug)]
pub struct StaleImage {
    threads: Threads,
    depth: DepthBuffer,
    frame: Vec<u32>,
}

impl StaleImage {
    /// A stale-image renderer on `threads` threads (0: all cores).
    pub fn new(threads: usize) -> Self {
        StaleImage { threads: Threads::new(threads), depth: DepthBuffer::default(), frame: Vec::new() }
    }
}

/// Source index along an axis of `src` pixels for destination pixel `i` of `dst` (nearest,
/// centre to centre): how the stale image is resized to the requested viewport.
#[inline(always)]
pub fn nearest(i: u32, dst: u32, src: u32) -> usize {
    (((2 * i as u64 + 1) * src as u64) / (2 * dst as u64)).min(src as u64 - 1) as usize
}

impl Renderer for StaleImage {
    fn kind(&self) -> RendererKind {
        RendererKind::Stale
    }

    fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) {
        if !begin_frame(scene, camera, out) {
            return;
        }
        let fc = scene.header.camera;
        if fc.validate(MAX_VIEWPORT).is_err() {
            log::debug!("stale: the frame's camera is unusable; drawing the background");
            return;
        }
        let (fw, fh) = (fc.width, fc.height);
        let len = fw as usize * fh as usize;
        self.depth.reset(len, &self.threads);
        splat_points(scene, &Projector::new(&fc), 1, fw, fh, &self.depth, &self.threads);
        self.frame.resize(len, 0);
        self.depth.resolve(&scene.colors, &mut self.frame, &self.threads);
        let (w, frame) = (out.width, &self.frame);
        self.threads.for_each_chunk(&mut out.pixels, w as usize, |y, row| {
            let sy = nearest(y as u32, camera.height, fh);
            for (x, p) in row.iter_mut().enumerate() {
                *p = frame[sy * fw as usize + nearest(x as u32, w, fw)];
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::nearest;

    #[test]
    fn nearest_maps_centres() {
        assert_eq!((0..4).map(|i| nearest(i, 4, 4)).collect::<Vec<_>>(), [0, 1, 2, 3]);
        assert_eq!((0..4).map(|i| nearest(i, 4, 2)).collect::<Vec<_>>(), [0, 0, 1, 1]);
        assert_eq!((0..2).map(|i| nearest(i, 2, 4)).collect::<Vec<_>>(), [1, 3]);
    }
}
