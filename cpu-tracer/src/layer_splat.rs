//! Layered samples composited front to back (issue 14; renderer `splat-layers`).
//!
//! A layered frame carries up to K samples per pixel of the frame's camera, one per depth
//! segment, each with its own premultiplied color and opacity. Where the exact splatter
//! ([`crate::sphere_splat`]) draws each sample as a sphere and keeps the first hit, this
//! renderer draws each sample as its **source pixel's footprint**: the rectangle the frame
//! camera's pixel frustum cuts from the plane through the sample's centre facing the frame
//! camera (the supersegment of volumetric depth images, Frey, Sadlo and Ertl 2013, flattened
//! to its representative depth), widened by [`OWN_MARGIN`] pixels against rounding cracks. The
//! rectangle is projected into the new camera and every output pixel whose centre lies inside
//! the projected quad takes the sample. Footprints of one depth tile the plane, so nothing is
//! counted twice where neighbouring segments lie at similar depths, and at the frame's own
//! camera every pixel takes exactly its own segments: the image is the server's render up to
//! 8-bit rounding. (A first version tested each pixel of the sphere's bound exactly and kept
//! the hits whose point nearest the centre projected into the sample's own pixel: the same rule
//! about 10× slower; `docs/perf.md`, issue 14.) The spheres' radii are not used.
//!
//! Per output pixel the samples go to a short list (the nearest, at most [`LIST`], as
//! `(distance from the eye, sample id)` keys); the list is sorted (ties by id, so the result
//! does not depend on the order of the samples) and composited front to back,
//! `C += (1 − A)·c`, stopping once `A` ≥ [`OPAQUE`]. Zero-opacity segments add nothing (no
//! division by opacity anywhere, so no NaN). Pixels nothing covers show the background.
//!
//! Work: the footprints are drawn serially (a few operations per sample), the lists composited
//! in parallel. Memory: `8 × cap + 1` bytes per output pixel, `cap` = twice the most segments
//! any source pixel has (4 to [`LIST`]), and 1 byte per source pixel.

use crate::begin_frame_unbuilt_ok;
use crate::sphere_splat::{dot, View};
use crate::threads::Threads;
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::sample::{over_background, pack_color_f32};
use volwarp_core::{Camera, RendererKind, Scene, Vec3, BACKGROUND};

/// Most segments kept per output pixel (the nearest ones).
pub const LIST: usize = 16;

/// Accumulated opacity at which a pixel's compositing stops.
pub const OPAQUE: f32 = 0.999;

/// How far (in source pixels) beyond its own pixel a sample's footprint reaches: closes the
/// cracks rounding would leave between neighbouring pixels' footprints.
pub const OWN_MARGIN: f32 = 0.05;

/// Output rows per compositing task.
const BAND: usize = 16;

/// How wide a sample's footprint is (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayerOptions {
    /// Half the footprint's side, in source pixels: 0.5 is the source pixel itself; the default
    /// adds [`OWN_MARGIN`]. Measured (`docs/perf.md`, issue 14): 0.7 double-counts more than it
    /// fills.
    pub own: f32,
}

impl Default for LayerOptions {
    fn default() -> Self {
        LayerOptions { own: 0.5 + OWN_MARGIN }
    }
}

/// The layered splatter (renderer name `splat-layers`).
#[derive(Debug)]
pub struct LayerSplat {
    threads: Threads,
    opts: LayerOptions,
    /// Per output pixel `cap` keys.
    keys: Vec<u64>,
    /// Per output pixel the number of keys.
    count: Vec<u8>,
    /// Per source pixel its number of samples.
    per_source: Vec<u8>,
}

impl LayerSplat {
    /// A layered splatter on `threads` threads (0: one per core).
    pub fn new(threads: usize) -> Self {
        LayerSplat::with_options(threads, LayerOptions::default())
    }

    /// A layered splatter with another footprint width.
    pub fn with_options(threads: usize, opts: LayerOptions) -> Self {
        LayerSplat { threads: Threads::new(threads), opts, keys: Vec::new(), count: Vec::new(), per_source: Vec::new() }
    }
}

/// Continuous image coordinates of `p` in `view`'s camera (pixel `(x, y)` spans
/// `[x, x + 1) × [y, y + 1)`), `None` at or behind the eye plane.
#[inline(always)]
fn project(view: &View, p: [f64; 3]) -> Option<(f64, f64)> {
    let rel = [p[0] - view.eye.x as f64, p[1] - view.eye.y as f64, p[2] - view.eye.z as f64];
    let z = dot(rel, view.w);
    if !(z > 1e-9) {
        return None;
    }
    let inv = 1.0 / z;
    Some((dot(rel, view.u) * inv * view.px_x + view.half_w, view.half_h - dot(rel, view.v) * inv * view.px_y))
}

/// The depth key: the centre's distance from the eye (ordered bits of a non-negative float)
/// and the sample id.
#[inline(always)]
fn key(dist: f32, id: u32) -> u64 {
    ((dist.max(0.0).to_bits() as u64) << 32) | id as u64
}

/// Inserts `key` into a list of `cap` slots holding `n`, keeping the `cap` smallest.
#[inline(always)]
fn insert(slots: &mut [u64], n: &mut u8, key: u64) {
    let len = *n as usize;
    if len < slots.len() {
        slots[len] = key;
        *n += 1;
        return;
    }
    let (mut worst, mut at) = (0u64, 0usize);
    for (i, &k) in slots.iter().enumerate() {
        if k >= worst {
            worst = k;
            at = i;
        }
    }
    if key < worst {
        slots[at] = key;
    }
}

impl Renderer for LayerSplat {
    fn kind(&self) -> RendererKind {
        RendererKind::SplatLayers
    }

    fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) {
        if !begin_frame_unbuilt_ok(scene, camera, out) {
            return;
        }
        let (w, h) = (camera.width as usize, camera.height as usize);
        let view = View::new(camera);
        let source = View::new(&scene.header.camera);
        let deq = &scene.deq;
        let (sw, sh) = (source.width as usize, source.height as usize);
        // Each sample's source pixel, and the most samples any source pixel has.
        self.per_source.clear();
        self.per_source.resize(sw * sh, 0);
        let f = |v: Vec3| [v.x as f64, v.y as f64, v.z as f64];
        let pixel_of = |c: Vec3| match project(&source, f(c)) {
            Some((x, y)) if x >= 0.0 && y >= 0.0 && x < sw as f64 && y < sh as f64 => Some((x as usize, y as usize)),
            _ => None,
        };
        for &s in &scene.samples {
            if let Some((x, y)) = pixel_of(deq.center(s)) {
                let c = &mut self.per_source[y * sw + x];
                *c = c.saturating_add(1);
            }
        }
        let most = self.per_source.iter().copied().max().unwrap_or(0) as usize;
        let cap = (2 * most).clamp(4, LIST);
        self.count.clear();
        self.count.resize(w * h, 0);
        self.keys.resize(w * h * cap, u64::MAX);
        // Half the footprint's side at unit depth, per axis, as a vector of the source basis.
        let half = self.opts.own.clamp(0.0, 4.0) as f64;
        let (hx, hy) = (half / source.px_x, half / source.px_y);
        let eye = f(view.eye);
        for (id, &s) in scene.samples.iter().enumerate() {
            let c = deq.center(s);
            if pixel_of(c).is_none() {
                continue;
            }
            let cf = f(c);
            let rel = [cf[0] - source.eye.x as f64, cf[1] - source.eye.y as f64, cf[2] - source.eye.z as f64];
            let z = dot(rel, source.w);
            let (ux, vy) = (source.u.map(|a| a * z * hx), source.v.map(|a| a * z * hy));
            // The footprint's corners, in order around it, projected into the new camera.
            let corner = |sx: f64, sy: f64| project(&view, [0, 1, 2].map(|i| cf[i] + sx * ux[i] + sy * vy[i]));
            let (Some(q0), Some(q1), Some(q2), Some(q3)) =
                (corner(-1.0, -1.0), corner(1.0, -1.0), corner(1.0, 1.0), corner(-1.0, 1.0))
            else {
                continue;
            };
            let quad = [q0, q1, q2, q3];
            let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
            for &(x, y) in &quad {
                x0 = x0.min(x);
                x1 = x1.max(x);
                y0 = y0.min(y);
                y1 = y1.max(y);
            }
            // Pixel centres x + ½ within [x0, x1].
            let (xa, xb) = ((x0 - 0.5).ceil().max(0.0), (x1 - 0.5).floor().min(w as f64 - 1.0));
            let (ya, yb) = ((y0 - 0.5).ceil().max(0.0), (y1 - 0.5).floor().min(h as f64 - 1.0));
            if !(xa <= xb && ya <= yb) {
                continue;
            }
            // Edge functions, signed by the quad's orientation.
            let area = (q1.0 - q0.0) * (q2.1 - q0.1) - (q2.0 - q0.0) * (q1.1 - q0.1);
            let sign = if area < 0.0 { -1.0 } else { 1.0 };
            let dist = {
                let d = [cf[0] - eye[0], cf[1] - eye[1], cf[2] - eye[2]];
                dot(d, d).sqrt() as f32
            };
            let k = key(dist, id as u32);
            for y in ya as usize..=yb as usize {
                let py = y as f64 + 0.5;
                for x in xa as usize..=xb as usize {
                    let px = x as f64 + 0.5;
                    let inside = (0..4).all(|e| {
                        let (a, b) = (quad[e], quad[(e + 1) & 3]);
                        sign * ((b.0 - a.0) * (py - a.1) - (b.1 - a.1) * (px - a.0)) >= 0.0
                    });
                    if inside {
                        let i = y * w + x;
                        insert(&mut self.keys[i * cap..(i + 1) * cap], &mut self.count[i], k);
                    }
                }
            }
        }
        let (keys, count, colors) = (&self.keys[..], &self.count[..], &scene.colors[..]);
        self.threads.for_each_chunk(&mut out.pixels, BAND * w, |band, px| {
            for (j, p) in px.iter_mut().enumerate() {
                let i = band * BAND * w + j;
                let mut list = [0u64; LIST];
                let n = count[i] as usize;
                list[..n].copy_from_slice(&keys[i * cap..i * cap + n]);
                let list = &mut list[..n];
                list.sort_unstable();
                *p = composite_keys(list, colors);
            }
        });
    }
}

/// The pixel of a sorted list of keys: their samples' colors composited front to back over the
/// background.
fn composite_keys(keys: &[u64], colors: &[u32]) -> u32 {
    if keys.is_empty() {
        return BACKGROUND;
    }
    let mut acc = [0.0f32; 4];
    for &k in keys {
        let Some(&c) = colors.get(k as u32 as usize) else { continue };
        let c = c.to_le_bytes();
        let wgt = (1.0 - acc[3]) * (1.0 / 255.0);
        for i in 0..4 {
            acc[i] += wgt * c[i] as f32;
        }
        if acc[3] >= OPAQUE {
            break;
        }
    }
    over_background(pack_color_f32(acc), BACKGROUND)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_short_list_keeps_the_nearest() {
        let mut slots = [0u64; 6];
        let mut n = 0u8;
        for k in (0..40u64).rev() {
            insert(&mut slots, &mut n, k * 3);
        }
        slots.sort_unstable();
        assert_eq!(n, 6);
        assert_eq!(slots.to_vec(), (0..6u64).map(|k| k * 3).collect::<Vec<_>>());
    }

    #[test]
    fn compositing_zero_opacity_gives_the_background_and_no_nan() {
        let colors = [0u32, 0, 0];
        assert_eq!(composite_keys(&[key(1.0, 0), key(2.0, 1), key(3.0, 2)], &colors), BACKGROUND);
        assert_eq!(composite_keys(&[], &colors), BACKGROUND);
    }
}
