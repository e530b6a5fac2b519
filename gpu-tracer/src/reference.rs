//! The scalar CPU renderer built on core's reference traversal [`volwarp_core::Lbvh::trace`]:
//! the oracle the GPU image is compared with (rows split over the available cores).

use volwarp_core::renderer::{Image, Renderer, BACKGROUND};
use volwarp_core::sample::over_background;
use volwarp_core::{Camera, Scene};

/// Renders with [`volwarp_core::Lbvh::trace`] per pixel. Named `spheres-scalar`.
#[derive(Clone, Copy, Debug, Default)]
pub struct ScalarTracer;

/// The color of pixel `(x, y)` as every sphere renderer shows it.
pub fn trace_pixel(scene: &Scene, basis: &volwarp_core::RayBasis, x: u32, y: u32) -> u32 {
    match scene.lbvh().trace(&basis.ray(x, y)) {
        Some(hit) => over_background(scene.colors[hit.prim as usize], BACKGROUND),
        None => BACKGROUND,
    }
}

impl Renderer for ScalarTracer {
    fn name(&self) -> String {
        "spheres-scalar".into()
    }

    fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) {
        out.reset_for(camera);
        if camera.validate(crate::tracer::MAX_VIEWPORT).is_err() {
            log::error!("scalar tracer: invalid camera");
            return;
        }
        let basis = camera.ray_basis();
        let w = camera.width as usize;
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).max(1);
        let rows_per = (camera.height as usize).div_ceil(threads).max(1);
        std::thread::scope(|s| {
            for (chunk_i, chunk) in out.pixels.chunks_mut(rows_per * w).enumerate() {
                let basis = &basis;
                s.spawn(move || {
                    for (i, px) in chunk.iter_mut().enumerate() {
                        let y = (chunk_i * rows_per + i / w) as u32;
                        *px = trace_pixel(scene, basis, (i % w) as u32, y);
                    }
                });
            }
        });
    }
}
