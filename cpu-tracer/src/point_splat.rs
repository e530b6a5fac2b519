//! The 2.5D point baseline of ZAL12: every sample's centre is reprojected to the current
//! camera (`Camera::project`) and drawn as a fixed N×N pixel square (N = 1, 2, 3) with a depth
//! test on the view depth — what `GL_POINTS` of a fixed size does. The square covers the N×N
//! pixels whose centres are nearest the projected point. Equal depths go to the smaller sample
//! index, so the image does not depend on the thread count.

use crate::begin_frame_unbuilt_ok as begin_frame;
use crate::depth_buffer::{key, DepthBuffer, Projector};
use crate::threads::Threads;
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::RendererKind;
use volwarp_core::{Camera, Scene};

/// Samples per unit of parallel work.
const GRAIN: usize = 8192;

/// The point-splat baseline (renderer names `points1`, `points2`, `points3`).
#[derive(Debug)]
pub struct PointSplat {
    size: u32,
    threads: Threads,
    depth: DepthBuffer,
}

/// The first pixel index of an N-wide square centred on continuous coordinate `c`, if the
/// square can touch `0..n`.
#[inline(always)]
pub(crate) fn square_start(c: f32, size: u32, n: u32) -> Option<i64> {
    let s = (c - size as f32 * 0.5 + 0.5).floor();
    if !(s > -(size as f32) && s < n as f32) {
        return None; // off screen, or NaN
    }
    Some(s as i64)
}

impl PointSplat {
    /// Squares of `size`×`size` pixels (clamped to 1..=3) on `threads` threads (0: all cores).
    pub fn new(size: u32, threads: usize) -> Self {
        PointSplat { size: size.clamp(1, 3), threads: Threads::new(threads), depth: DepthBuffer::default() }
    }

    /// The square size N.
    pub fn size(&self) -> u32 {
        self.size
    }
}

/// Splats every sample of `scene` projected by `proj` as a `size`² square into `depth`
/// (`width`×`height`).
pub(crate) fn splat_points(
    scene: &Scene,
    proj: &Projector,
    size: u32,
    width: u32,
    height: u32,
    depth: &DepthBuffer,
    threads: &Threads,
) {
    let (samples, deq) = (&scene.samples, &scene.deq);
    threads.for_each_range(samples.len(), GRAIN, |range| {
        for k in range {
            let Some((x, y, z)) = proj.project(deq.center(samples[k])) else { continue };
            let (Some(x0), Some(y0)) = (square_start(x, size, width), square_start(y, size, height)) else {
                continue;
            };
            let kk = key(z, k as u32);
            for py in y0.max(0)..(y0 + size as i64).min(height as i64) {
                for px in x0.max(0)..(x0 + size as i64).min(width as i64) {
                    depth.test(py as usize * width as usize + px as usize, kk);
                }
            }
        }
    });
}

impl Renderer for PointSplat {
    fn kind(&self) -> RendererKind {
        RendererKind::points(self.size).unwrap_or(RendererKind::Points3)
    }

    fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) {
        if begin_frame(scene, camera, out) {
            self.depth.reset(camera.width as usize * camera.height as usize, &self.threads);
            let proj = Projector::new(camera);
            splat_points(scene, &proj, self.size, camera.width, camera.height, &self.depth, &self.threads);
            self.depth.resolve(&scene.colors, &mut out.pixels, &self.threads);
        }
    }
}
