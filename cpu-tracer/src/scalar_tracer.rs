//! Core's scalar reference traversal ([`volwarp_core::Lbvh::trace`]) for every pixel, rows in
//! parallel: the oracle the packet tracer is compared with, and its speed baseline.

use crate::threads::Threads;
use crate::{begin_frame, shade, NO_HIT};
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::RendererKind;
use volwarp_core::{Camera, Scene};

/// Rows per unit of parallel work.
const BAND_ROWS: u32 = 8;

/// The scalar per-pixel tracer (renderer name `spheres-scalar`).
#[derive(Debug)]
pub struct ScalarTracer {
    threads: Threads,
}

impl ScalarTracer {
    /// A tracer on `threads` threads (0: one per core).
    pub fn new(threads: usize) -> Self {
        ScalarTracer { threads: Threads::new(threads) }
    }

    /// Like [`crate::PacketTracer::trace_ids`]: first-hit sample index per pixel.
    pub fn trace_ids(&self, scene: &Scene, camera: &Camera, ids: &mut Vec<u32>) -> bool {
        crate::trace_ids_with(scene, camera, ids, |ids| self.draw(scene, camera, ids, |id| id))
    }

    fn draw(&self, scene: &Scene, camera: &Camera, out: &mut [u32], map: impl Fn(u32) -> u32 + Sync) {
        let l = scene.lbvh();
        let basis = camera.ray_basis();
        let width = camera.width;
        self.threads.for_each_chunk(out, (width * BAND_ROWS) as usize, |band, rows| {
            for (i, px) in rows.iter_mut().enumerate() {
                let x = i as u32 % width;
                let y = band as u32 * BAND_ROWS + i as u32 / width;
                *px = map(l.trace(&basis.ray(x, y)).map_or(NO_HIT, |h| h.prim));
            }
        });
    }
}

impl Renderer for ScalarTracer {
    fn kind(&self) -> RendererKind {
        RendererKind::SpheresScalar
    }

    fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) {
        if begin_frame(scene, camera, out) {
            let colors = &scene.colors;
            self.draw(scene, camera, &mut out.pixels, |id| shade(colors, id));
        }
    }
}
