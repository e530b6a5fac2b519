//! The shared machinery of the object-order renderers: a lock-free depth buffer whose pixels
//! hold `(depth, sample id)` keys, and a projection that mirrors `Camera::project`.

use crate::shade;
use crate::threads::Threads;
use std::sync::atomic::{AtomicU64, Ordering};
use volwarp_core::{Camera, Vec3, BACKGROUND};

/// Empty pixel.
pub(crate) const EMPTY: u64 = u64::MAX;

/// The depth-test key of a hit at positive depth `t` on sample `prim`: the smaller key is the
/// closer hit, and equal depths go to the smaller id (core's tie rule), because the bits of a
/// positive float order like the float.
#[inline(always)]
pub(crate) fn key(t: f32, prim: u32) -> u64 {
    ((t.to_bits() as u64) << 32) | prim as u64
}

/// The sample id of a key, `None` for [`EMPTY`].
#[inline(always)]
pub(crate) fn key_prim(k: u64) -> Option<u32> {
    (k != EMPTY).then_some(k as u32)
}

/// Per-pixel atomic minimum of keys; threads splat concurrently without locks.
#[derive(Debug, Default)]
pub(crate) struct DepthBuffer {
    keys: Vec<AtomicU64>,
}

impl DepthBuffer {
    /// Clears to `len` empty pixels (reusing the allocation).
    pub(crate) fn reset(&mut self, len: usize, threads: &Threads) {
        if self.keys.len() != len {
            self.keys.clear();
            self.keys.resize_with(len, || AtomicU64::new(EMPTY));
        } else {
            threads.for_each_chunk(&mut self.keys, 1 << 16, |_, c| {
                for k in c {
                    *k.get_mut() = EMPTY;
                }
            });
        }
    }

    /// Keeps `key` at pixel `i` if it is smaller (out-of-range pixels are ignored).
    #[inline(always)]
    pub(crate) fn test(&self, i: usize, key: u64) {
        if let Some(p) = self.keys.get(i) {
            if key < p.load(Ordering::Relaxed) {
                p.fetch_min(key, Ordering::Relaxed);
            }
        }
    }

    /// The sample id at pixel `i`, if any.
    #[inline(always)]
    pub(crate) fn prim(&self, i: usize) -> Option<u32> {
        key_prim(self.keys.get(i)?.load(Ordering::Relaxed))
    }

    /// Writes the shaded pixels (`out.len()` must equal the buffer's length).
    pub(crate) fn resolve(&self, colors: &[u32], out: &mut [u32], threads: &Threads) {
        threads.for_each_chunk(out, 1 << 14, |c, px| {
            for (j, p) in px.iter_mut().enumerate() {
                *p = self.prim((c << 14) + j).map_or(BACKGROUND, |id| shade(colors, id));
            }
        });
    }
}

/// `Camera::project` with its per-camera set-up done once: the same operations in the same
/// order, so the same results (tested).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Projector {
    eye: Vec3,
    u: Vec3,
    v: Vec3,
    w: Vec3,
    tan_x: f32,
    tan_y: f32,
    width: f32,
    height: f32,
}

impl Projector {
    pub(crate) fn new(c: &Camera) -> Self {
        let (u, v, w) = c.basis();
        // core computes the tangent with `libm::tanf`: so do we.
        let tan_y = libm::tanf(c.fov_y_deg.to_radians() * 0.5);
        let tan_x = tan_y * c.aspect();
        Projector { eye: c.eye, u, v, w, tan_x, tan_y, width: c.width as f32, height: c.height as f32 }
    }

    /// Continuous pixel coordinates and view depth, `None` behind or on the eye plane.
    #[inline(always)]
    pub(crate) fn project(&self, p: Vec3) -> Option<(f32, f32, f32)> {
        let rel = p - self.eye;
        let z = rel.dot(self.w);
        if !(z > 1e-6) {
            return None;
        }
        let sx = rel.dot(self.u) / (z * self.tan_x);
        let sy = rel.dot(self.v) / (z * self.tan_y);
        let x = (sx + 1.0) * 0.5 * self.width;
        let y = (1.0 - sy) * 0.5 * self.height;
        Some((x, y, z))
    }
}

/// Pixel index range `[lo, hi]` (inclusive, clamped to `0..n`) of pixel centres within
/// `[a, b]` in continuous coordinates, padded by `pad` pixels; `None` if empty.
#[inline(always)]
pub(crate) fn pixel_span(a: f64, b: f64, pad: f64, n: u32) -> Option<(u32, u32)> {
    if !(a <= b) {
        return None;
    }
    let lo = (a - 0.5 - pad).floor().max(0.0);
    let hi = (b - 0.5 + pad).ceil().min(n as f64 - 1.0);
    if !(lo <= hi) {
        return None;
    }
    Some((lo as u32, hi as u32))
}
