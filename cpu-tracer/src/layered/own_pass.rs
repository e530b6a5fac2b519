//! The own-image pass: a frame's samples grouped by their source pixel in its own camera (its
//! own composited image at any pixel, the newest frame's sight, the slabs' corners).

use super::footprints::*;
use super::options::*;
use crate::key_list::{composite_keys, key, sort_keys};
use crate::lanes::{self, Lanes};
use crate::route::SceneId;
use crate::sphere_splat::View;
use crate::threads::Threads;
use crate::MAX_VIEWPORT;
use volwarp_core::sample::Dequantizer;
use volwarp_core::{Scene, Vec3, BACKGROUND};

/// The pixel index of a point outside the view.
pub(crate) const NO_PIXEL: u32 = u32::MAX;

/// A frame's samples in its own camera, once per frame: per sample its pixel and view depth
/// (what [`Sight`] records) and its depth key, and the keys grouped by pixel (a counting sort).
/// At its own camera every footprint of the default width is exactly its source pixel, so the
/// frame's own composited image is each pixel's group sorted and composited: the image the
/// footprints would draw there, without setting up, binning and rasterizing a million of them
/// (measured: the first draw after a frame arrives, `docs/perf.md`). Memory: 20 bytes per
/// sample and 4 per pixel, reused frame to frame.
#[derive(Debug, Default)]
pub(crate) struct OwnPass {
    /// The scene projected.
    pub(crate) of: Option<SceneId>,
    /// Its camera's projection and viewport (`None`: unusable camera, nothing projected).
    pub(crate) proj: Option<(Proj, usize, usize)>,
    /// Per sample `pixel << 32 | view depth bits` (pixel [`NO_PIXEL`] outside the view).
    pub(crate) at: Vec<u64>,
    /// Per sample its depth key ([`key`]: squared distance from the eye, id).
    pub(crate) keys: Vec<u64>,
    /// The keys grouped by pixel (in sample order within a pixel) and, per pixel, where its
    /// group starts (one more entry: the end of the last).
    pub(crate) grouped: Vec<u64>,
    pub(crate) start: Vec<u32>,
    /// Per sample (by id) the source depths of its footprint's four corners where they are
    /// shared with the same slab of neighbouring pixels (NaN: not shared), and the tolerance
    /// they were found with ([`OwnPass::share_corners`]; `None`: not found for this scene).
    pub(crate) shared: Vec<[f32; 4]>,
    pub(crate) shared_tol: Option<f32>,
    /// Scratch: the groups sorted by depth key, their view depths and corners in that order.
    pub(crate) sorted: Vec<u64>,
    pub(crate) zs: Vec<f32>,
    pub(crate) corners: Vec<[f32; 4]>,
}

impl OwnPass {
    /// Projects `scene`'s samples into its own camera (nothing if that was the last scene).
    pub(crate) fn project(&mut self, scene: &Scene, threads: &Threads) {
        let id = SceneId::of(scene);
        if self.of == Some(id) {
            return;
        }
        self.of = Some(id);
        // What was found for the last scene goes with it.
        self.start.clear();
        self.shared.clear();
        self.shared_tol = None;
        let fc = scene.header.camera;
        let n = scene.samples.len();
        if fc.validate(MAX_VIEWPORT).is_err() {
            self.proj = None;
            self.at.clear();
            self.at.resize(n, (NO_PIXEL as u64) << 32);
            return;
        }
        let (w, h) = (fc.width as usize, fc.height as usize);
        let proj = Proj::new(&View::new(&fc));
        self.proj = Some((proj, w, h));
        self.at.resize(n, 0);
        self.keys.resize(n, 0);
        let (samples, deq) = (&scene.samples[..], &scene.deq);
        threads.for_each_chunk_pair(&mut self.at[..n], &mut self.keys[..n], QUAD_CHUNK, |chunk, at, keys| {
            let first = chunk * QUAD_CHUNK;
            let m = at.len();
            let (mut idx, mut zs, mut d2) = ([NO_PIXEL; QUAD_CHUNK], [0f32; QUAD_CHUNK], [0f32; QUAD_CHUNK]);
            project(&proj, (w, h), deq, &samples[first..first + m], &mut idx[..m], &mut zs[..m], &mut d2[..m]);
            for (k, (a, key_out)) in at.iter_mut().zip(keys.iter_mut()).enumerate() {
                *a = (idx[k] as u64) << 32 | zs[k].to_bits() as u64;
                *key_out = key(d2[k], (first + k) as u32);
            }
        });
    }

    /// [`OwnPass::project`] and [`OwnPass::group`] (each done once per scene); false for an
    /// unusable camera.
    pub(crate) fn prepare(&mut self, scene: &Scene, threads: &Threads) -> bool {
        self.project(scene, threads);
        self.group(threads)
    }

    /// Pixel `i`'s own segments composited over the background (after [`OwnPass::group`]; the
    /// background for a pixel without segments or outside the view).
    pub(crate) fn pixel(&self, i: usize, colors: &[u32]) -> u32 {
        let (Some(&a), Some(&b)) = (self.start.get(i), self.start.get(i + 1)) else { return BACKGROUND };
        let Some(keys) = self.grouped.get(a as usize..b as usize) else { return BACKGROUND };
        let n = keys.len();
        if n <= LIST {
            let mut list = [0u64; LIST];
            list[..n].copy_from_slice(keys);
            sort_keys(&mut list[..n]);
            composite_keys(&list[..n], colors)
        } else {
            // More segments than a list keeps: the nearest LIST, as the lists keep.
            let mut long = keys.to_vec();
            long.sort_unstable();
            composite_keys(&long[..LIST], colors)
        }
    }

    /// Groups the keys by pixel (after [`OwnPass::project`]); false for an unusable camera.
    pub(crate) fn group(&mut self, threads: &Threads) -> bool {
        let Some((_, w, h)) = self.proj else { return false };
        if !self.start.is_empty() {
            return true;
        }
        // A server's frame comes in pixel order (samples outside the view, `NO_PIXEL`, can
        // only come last then): the groups are the keys in their order, and a pixel's start is
        // the number of samples on earlier pixels, found per band of pixels in parallel.
        let pixel = |a: u64| (a >> 32) as usize;
        if self.at.windows(2).all(|p| pixel(p[0]) <= pixel(p[1])) {
            self.start.resize(w * h + 1, 0);
            let at = &self.at[..];
            let valid = at.partition_point(|&a| pixel(a) < w * h);
            threads.for_each_chunk(&mut self.start[..w * h], PIXEL_PASS_ROWS * w, |band, start| {
                let p0 = band * PIXEL_PASS_ROWS * w;
                let mut j = at[..valid].partition_point(|&a| pixel(a) < p0);
                for (i, s) in start.iter_mut().enumerate() {
                    while j < valid && pixel(at[j]) < p0 + i {
                        j += 1;
                    }
                    *s = j as u32;
                }
            });
            self.start[w * h] = valid as u32;
            self.grouped.clear();
            self.grouped.extend_from_slice(&self.keys[..valid]);
            return true;
        }
        self.group_any_order();
        true
    }

    /// [`OwnPass::group`] for samples in any order: counts, then their running sums (each
    /// pixel's end), then every key placed backwards at its pixel's end, so the ends become the
    /// starts and a pixel keeps its samples' order.
    pub(crate) fn group_any_order(&mut self) {
        let Some((_, w, h)) = self.proj else { return };
        self.start.clear();
        self.start.resize(w * h + 1, 0);
        for &a in &self.at {
            if let Some(c) = self.start.get_mut((a >> 32) as usize) {
                *c += 1;
            }
        }
        let mut sum = 0u32;
        for c in &mut self.start[..w * h] {
            sum += *c;
            *c = sum;
        }
        self.start[w * h] = sum;
        self.grouped.resize(sum as usize, 0);
        for (&a, &k) in self.at.iter().zip(&self.keys).rev() {
            let i = (a >> 32) as usize;
            if i < w * h {
                self.start[i] -= 1;
                self.grouped[self.start[i] as usize] = k;
            }
        }
    }
}

lanes::dispatch! {
    /// [`project_lanes`] on the best lanes this CPU has (the same values either way).
    fn project_on_best_lanes / project_avx2 => project_lanes(
        p: &Proj,
        size: (usize, usize),
        deq: &Dequantizer,
        samples: &[u64],
        idx: &mut [u32],
        zs: &mut [f32],
        d2: &mut [f32],
    )
}

/// `project` for the other steps of the layered model and the rasterizer (the dispatch
/// macro's functions are private to their module).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(crate) fn project(
    p: &Proj,
    size: (usize, usize),
    deq: &Dequantizer,
    samples: &[u64],
    idx: &mut [u32],
    zs: &mut [f32],
    d2: &mut [f32],
) {
    project_on_best_lanes(p, size, deq, samples, idx, zs, d2)
}

/// Per packed sample its pixel index in a `w × h` view (`size`) with projection `p` ([`NO_PIXEL`]
/// outside it) and its view depth: [`pixel`] eight samples at a time (bit for bit: the same
/// decode and `f32` operations in the same order). Unless `d2` is empty, also its squared
/// distance from the eye, as the footprint set-up computes it for the depth key.
#[inline(always)]
pub(crate) fn project_lanes<L: Lanes>(
    p: &Proj,
    (w, h): (usize, usize),
    deq: &Dequantizer,
    samples: &[u64],
    idx: &mut [u32],
    zs: &mut [f32],
    d2: &mut [f32],
) {
    let with_d2 = !d2.is_empty();
    let eye = [p.eye.x, p.eye.y, p.eye.z];
    let (u, v, a) = (p.u, p.v, p.w);
    for (g, ((s, ix), zo)) in samples.chunks(8).zip(idx.chunks_mut(8)).zip(zs.chunks_mut(8)).enumerate() {
        let [x, y, z, _] = match <&[u64; 8]>::try_from(s) {
            Ok(s8) => L::decode8(deq, eye, s8),
            Err(_) => lanes::decode_scalar(deq, eye, s),
        };
        if with_d2 {
            let dd = (x * x + y * y + z * z).to_array();
            for (o, &v) in d2[g * 8..].iter_mut().zip(&dd[..s.len()]) {
                *o = v;
            }
        }
        let zc = x * L::splat(a.x) + y * L::splat(a.y) + z * L::splat(a.z);
        let uc = x * L::splat(u.x) + y * L::splat(u.y) + z * L::splat(u.z);
        let vc = x * L::splat(v.x) + y * L::splat(v.y) + z * L::splat(v.z);
        let inv = L::splat(1.0) / zc;
        let px = uc * inv * L::splat(p.px_x) + L::splat(p.half_w);
        let py = L::splat(p.half_h) - vc * inv * L::splat(p.px_y);
        let (za, xa, ya) = (zc.to_array(), px.to_array(), py.to_array());
        for l in 0..ix.len() {
            let (zl, xl, yl) = (za[l], xa[l], ya[l]);
            let inside = zl > 1e-6 && xl >= 0.0 && yl >= 0.0 && (xl as usize) < w && (yl as usize) < h;
            ix[l] = if inside { (yl as usize * w + xl as usize) as u32 } else { NO_PIXEL };
            zo[l] = zl;
        }
    }
}

/// The pixel (of a `w × h` view with projection `p`) and view depth of point `c`, if in the
/// view: the scalar reference of [`project_lanes`], and the layered tracer's projection
/// (`layer_trace`), so both renderers give a sample the same source pixel.
pub(crate) fn pixel(p: &Proj, w: usize, h: usize, c: Vec3) -> Option<(usize, f32)> {
    let r = c - p.eye;
    let z = r.dot(p.w);
    if !(z > 1e-6) {
        return None;
    }
    let inv = 1.0 / z;
    let (x, y) = (r.dot(p.u) * inv * p.px_x + p.half_w, p.half_h - r.dot(p.v) * inv * p.px_y);
    (x >= 0.0 && y >= 0.0 && (x as usize) < w && (y as usize) < h).then(|| (y as usize * w + x as usize, z))
}
