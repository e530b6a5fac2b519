//! The layered tracer (renderer name `spheres-layers`, "for the tracer, multi-hit
//! traversal"): per pixel, every segment sphere its ray hits through the LBVH
//! ([`volwarp_core::Lbvh::hits`]), the nearest [`LIST`] kept, sorted by hit distance and
//! composited front to back over the background — the same compositing as `splat-layers`
//! (`layer_splat::composite_keys`), with spheres and per-pixel hit distances instead of
//! footprint quadrilaterals and per-sample depths.
//!
//! **Ownership.** A layered frame's segment spheres overlap their neighbours' (the footprint
//! radius spans more than a pixel), so a ray would composite the segments of several source
//! pixels. A hit counts only where the output ray passes through the segment's own source
//! pixel: the point of the ray nearest the sphere's centre, projected with the frame's camera,
//! must fall in the same pixel as the centre itself. At the frame's own camera every ray is its
//! pixel's source ray, so each pixel composites exactly its own segments, as the server did
//! (tested: ≥ 40 dB against the frame's own image); away from it the rule keeps each segment to
//! about its pixel's cone. A frame whose camera is unusable draws every hit.
//!
//! It is the reference, not the fast path: one scalar traversal per pixel (`spheres-scalar`'s
//! cost, more for the hits it keeps), in parallel over rows. `splat-layers` is the default.

use crate::key_list::{composite_keys, insert, key};
use crate::layered::{pixel, Proj, LIST};
use crate::sphere_splat::View;
use crate::threads::Threads;
use crate::{begin_frame, MAX_VIEWPORT};
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::{Camera, RendererKind, Scene, Vec3};

/// Rows per unit of parallel work.
const BAND_ROWS: usize = 8;

/// A source pixel that owns nothing in particular: the sample is drawn by every ray that hits
/// it (its centre does not project into the frame's viewport, or the frame's camera is
/// unusable).
const ANY: u32 = u32::MAX;

/// The multi-hit layered tracer (renderer name `spheres-layers`).
#[derive(Debug)]
pub struct LayerTrace {
    threads: Threads,
    /// Per sample (scene order), the frame pixel its centre projects into, [`ANY`] for none.
    owner: Vec<u32>,
}

impl LayerTrace {
    /// A tracer on `threads` threads (0: one per core).
    pub fn new(threads: usize) -> Self {
        LayerTrace { threads: Threads::new(threads), owner: Vec::new() }
    }
}

impl Renderer for LayerTrace {
    fn kind(&self) -> RendererKind {
        RendererKind::SpheresLayers
    }

    fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) {
        if !begin_frame(scene, camera, out) {
            return;
        }
        let (samples, deq, colors) = (&scene.samples[..], &scene.deq, &scene.colors[..]);
        let fc = scene.header.camera;
        // The frame's projection, as `splat-layers` assigns samples their source pixels.
        let frame = fc
            .validate(MAX_VIEWPORT)
            .is_ok()
            .then(|| (Proj::new(&View::new(&fc)), fc.width as usize, fc.height as usize));
        let pixel_of = |(p, w, h): &(Proj, usize, usize), c: Vec3| pixel(p, *w, *h, c).map(|(i, _)| i as u32);
        self.owner.clear();
        self.owner
            .extend(samples.iter().map(|&s| frame.as_ref().and_then(|f| pixel_of(f, deq.center(s))).unwrap_or(ANY)));
        let (owner, frame) = (&self.owner[..], frame.as_ref());
        let lbvh = scene.lbvh();
        let basis = camera.ray_basis();
        let width = camera.width as usize;
        self.threads.for_each_chunk(&mut out.pixels, width * BAND_ROWS, |band, rows| {
            let mut keys = [u64::MAX; LIST];
            for (i, px) in rows.iter_mut().enumerate() {
                let (x, y) = ((i % width) as u32, (band * BAND_ROWS + i / width) as u32);
                let ray = basis.ray(x, y);
                let mut n = 0u8;
                lbvh.hits(&ray, |t, k| {
                    let own = owner.get(k as usize).copied().unwrap_or(ANY);
                    let owned = own == ANY
                        || frame.is_some_and(|f| {
                            let c = deq.center(samples[k as usize]);
                            let nearest = ray.origin + ray.dir * (c - ray.origin).dot(ray.dir);
                            pixel_of(f, nearest) == Some(own)
                        });
                    if owned {
                        insert(&mut keys, &mut n, key(t, k));
                    }
                    // Once the list is full, only hits up to its farthest can still enter.
                    match n as usize {
                        LIST => keys.iter().map(|&k| f32::from_bits((k >> 32) as u32)).fold(0.0, f32::max),
                        _ => f32::INFINITY,
                    }
                });
                let list = &mut keys[..n as usize];
                list.sort_unstable();
                *px = composite_keys(list, colors);
            }
        });
    }
}
