//! Exact object-order sphere splatting: no BVH. Each sphere's screen-space bound is computed
//! analytically (the tangent lines from the eye to the sphere, per image axis), and every pixel
//! in it is tested with core's ray–sphere intersection for that pixel's own primary ray; a
//! per-pixel atomic depth test keeps the nearest hit with core's tie rule. The image is the
//! first-hit tracing image wherever the bound covers the hit pixels (padded by a pixel: in
//! practice every pixel, tested at ≥ 99.9 %). It tells what the BVH costs and buys.

use crate::depth_buffer::{key, pixel_span, DepthBuffer};
use crate::threads::Threads;
use crate::{begin_frame, NO_HIT};
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::sphere::intersect;
use volwarp_core::{Camera, RayBasis, Scene, Vec3};

/// Spheres per unit of parallel work.
const GRAIN: usize = 4096;

/// The exact sphere splatter (renderer name `splat`).
#[derive(Debug)]
pub struct SphereSplat {
    threads: Threads,
    depth: DepthBuffer,
}

/// Per-camera constants of the screen-space bound.
struct View {
    basis: RayBasis,
    eye: Vec3,
    u: [f64; 3],
    v: [f64; 3],
    w: [f64; 3],
    tan_x: f64,
    tan_y: f64,
    width: u32,
    height: u32,
}

#[inline(always)]
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Range of `a / z` over a disc of centre `(a, z)` and radius `r` with `z > r`: the slopes of
/// the two tangents from the origin.
#[inline(always)]
fn slopes(a: f64, z: f64, r: f64) -> (f64, f64) {
    let denom = z * z - r * r;
    let sq = (a * a + denom).sqrt();
    ((a * z - r * sq) / denom, (a * z + r * sq) / denom)
}

impl View {
    fn new(camera: &Camera) -> View {
        let (u, v, w) = camera.basis();
        let f = |x: Vec3| [x.x as f64, x.y as f64, x.z as f64];
        let tan_y = (camera.fov_y_deg as f64).to_radians() * 0.5;
        let tan_y = tan_y.tan();
        View {
            basis: camera.ray_basis(),
            eye: camera.eye,
            u: f(u),
            v: f(v),
            w: f(w),
            tan_x: tan_y * camera.aspect() as f64,
            tan_y,
            width: camera.width,
            height: camera.height,
        }
    }

    /// Inclusive pixel ranges `(x0, x1, y0, y1)` that may see the sphere, `None` if none can.
    #[inline(always)]
    fn bound(&self, c: Vec3, r: f32) -> Option<(u32, u32, u32, u32)> {
        let rel = [(c.x - self.eye.x) as f64, (c.y - self.eye.y) as f64, (c.z - self.eye.z) as f64];
        let (cx, cy, cz) = (dot(rel, self.u), dot(rel, self.v), dot(rel, self.w));
        // Widen by a relative margin far above f32 rounding of the centre and directions.
        let r = r as f64 + 1e-5 * (dot(rel, rel).sqrt() + r as f64);
        if cz + r < 0.0 {
            return None; // entirely behind the eye: rays (t > 0) cannot reach it
        }
        if cz <= r * 1.001 {
            // Touches the eye plane: the projection is unbounded; test the whole viewport.
            return Some((0, self.width - 1, 0, self.height - 1));
        }
        let (xl, xh) = slopes(cx, cz, r);
        let (yl, yh) = slopes(cy, cz, r);
        let (w, h) = (self.width as f64, self.height as f64);
        let (x0, x1) =
            pixel_span((xl / self.tan_x + 1.0) * 0.5 * w, (xh / self.tan_x + 1.0) * 0.5 * w, 1.0, self.width)?;
        let (y0, y1) =
            pixel_span((1.0 - yh / self.tan_y) * 0.5 * h, (1.0 - yl / self.tan_y) * 0.5 * h, 1.0, self.height)?;
        Some((x0, x1, y0, y1))
    }
}

impl SphereSplat {
    /// A splatter on `threads` threads (0: one per core).
    pub fn new(threads: usize) -> Self {
        SphereSplat { threads: Threads::new(threads), depth: DepthBuffer::default() }
    }

    /// Splats `camera`'s viewport into `ids` (row-major, resized): the first-hit sample index
    /// per pixel, [`NO_HIT`] where none. `false` if the camera or scene is unusable.
    pub fn splat_ids(&mut self, scene: &Scene, camera: &Camera, ids: &mut Vec<u32>) -> bool {
        let mut img = Image { width: 0, height: 0, pixels: std::mem::take(ids) };
        let ok = begin_frame(scene, camera, &mut img);
        *ids = img.pixels;
        ids.fill(NO_HIT);
        if ok {
            self.splat(scene, camera);
            for (i, id) in ids.iter_mut().enumerate() {
                *id = self.depth.prim(i).unwrap_or(NO_HIT);
            }
        }
        ok
    }

    fn splat(&mut self, scene: &Scene, camera: &Camera) {
        let view = View::new(camera);
        let o = view.basis.origin();
        self.depth.reset(camera.width as usize * camera.height as usize, &self.threads);
        let depth = &self.depth;
        let (samples, deq) = (&scene.samples, &scene.deq);
        self.threads.for_each_range(samples.len(), GRAIN, |range| {
            for k in range {
                let s = samples[k];
                let (c, r) = (deq.center(s), deq.radius(s));
                let Some((x0, x1, y0, y1)) = view.bound(c, r) else { continue };
                for y in y0..=y1 {
                    let row = y as usize * view.width as usize;
                    for x in x0..=x1 {
                        if let Some(t) = intersect(o, view.basis.dir(x, y), c, r) {
                            depth.test(row + x as usize, key(t, k as u32));
                        }
                    }
                }
            }
        });
    }
}

impl Renderer for SphereSplat {
    fn name(&self) -> String {
        "splat".into()
    }

    fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) {
        if begin_frame(scene, camera, out) {
            self.splat(scene, camera);
            self.depth.resolve(&scene.colors, &mut out.pixels, &self.threads);
        }
    }
}
