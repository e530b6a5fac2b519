//! Hole filling: what a sphere renderer shows where no sample of the newest frame covers a
//! pixel (older frames and hole filling). A post-pass over the sample-id buffer, so every CPU
//! renderer that yields ids ([`SampleIds`]: the packet tracer, the scalar tracer, the exact
//! splatter) can use it, and every one of them draws the same filled image (the ids are the
//! same, and every later stage is shared).
//!
//! A pixel's color comes from the first of these that has one:
//!
//! 1. **the newest frame**'s first hit (what the wrapped renderer draws);
//! 2. **older frames** (multi-frame filling, [`HoleFill::render_set`]): the first hit of the
//!    pixel's ray against each older scene in turn, newest first (core's scalar traversal, so
//!    the result does not depend on the wrapped renderer); an older sample never replaces a
//!    pixel the newest frame covers, even where it is closer;
//! 3. **the stale frame for that view direction** ([`FillOptions::stale`]): the newest frame
//!    as the server rendered it (its samples splatted one pixel each with the frame's own
//!    camera, what the `stale` renderer shows), looked up where the pixel's ray crosses the
//!    frame's focal plane (the plane through the frame camera's target, facing it). For a pure
//!    rotation of the camera this is exact; for an orbit about the target it is the stale image
//!    moved with the target. So a pixel the warp knows nothing about shows what a send-image
//!    system would show, never the background through the volume;
//! 4. **pull-push** ([`FillOptions::pull_push_levels`], Grossman and Dally 1998): the filled
//!    pixels averaged over 2ᴸ-pixel blocks and pushed back into the remaining holes, weighted
//!    by coverage and blended over the background, so cracks up to about 2ᴸ pixels close and
//!    silhouettes soften by at most as much;
//! 5. the background.
//!
//! Memory per pixel: a `u32` id, a `u64` fill state, a `u32` frame pixel and (with pull-push)
//! about 21 B of floats;
//! a client keeping `K` frames holds `K` scenes of ≈ 44 B per sample (`Scene::resident_bytes`).

use crate::depth_buffer::{DepthBuffer, Projector};
use crate::point_splat::splat_points;
use crate::route::SceneId;
use crate::threads::Threads;
use crate::{
    begin_frame_unbuilt_ok as begin_frame, shade, PacketTracer, ScalarTracer, SphereSplat, MAX_VIEWPORT, NO_HIT,
};
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::sample::pack_color_f32;
use volwarp_core::{Camera, RendererKind, Scene, BACKGROUND};

/// The most frames a client keeps (core's `method::MAX_FRAMES`).
pub use volwarp_core::method::MAX_FRAMES;

/// A renderer that can give the first-hit sample id of every pixel.
pub trait SampleIds: Send {
    /// Fills `ids` (resized to the camera's viewport) with the first-hit sorted sample index per
    /// pixel, [`NO_HIT`] where none; `false` if the camera or scene is unusable.
    fn sample_ids(&mut self, scene: &Scene, camera: &Camera, ids: &mut Vec<u32>) -> bool;
}

impl SampleIds for PacketTracer {
    fn sample_ids(&mut self, scene: &Scene, camera: &Camera, ids: &mut Vec<u32>) -> bool {
        self.trace_ids(scene, camera, ids)
    }
}

impl SampleIds for ScalarTracer {
    fn sample_ids(&mut self, scene: &Scene, camera: &Camera, ids: &mut Vec<u32>) -> bool {
        self.trace_ids(scene, camera, ids)
    }
}

impl SampleIds for SphereSplat {
    fn sample_ids(&mut self, scene: &Scene, camera: &Camera, ids: &mut Vec<u32>) -> bool {
        self.splat_ids(scene, camera, ids)
    }
}

/// Which fill stages run after the frames' own samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FillOptions {
    /// Fill from the stale frame for the pixel's view direction (stage 3).
    pub stale: bool,
    /// Fill (stages 2–4) only pixels inside the newest frame's silhouette: between the first and
    /// last pixel it covers in their row *and* in their column. Outside it, an empty pixel is
    /// more often empty space the warp got right than a hole (measured: `docs/results.md`).
    pub enclosed_only: bool,
    /// Pull-push levels (stage 4); 0 turns it off, at most [`FillOptions::MAX_LEVELS`].
    pub pull_push_levels: u32,
}

impl FillOptions {
    /// The most pull-push levels (holes up to 2⁶ = 64 pixels).
    pub const MAX_LEVELS: u32 = 6;

    /// The default of the `*-fill` renderers (chosen by measurement, `docs/results.md`).
    pub const DEFAULT: FillOptions = FillOptions { stale: true, enclosed_only: true, pull_push_levels: 0 };
}

impl Default for FillOptions {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// A sphere renderer with hole filling (renderer names `spheres-fill`, `splat-fill`).
#[derive(Debug)]
pub struct HoleFill<R> {
    inner: R,
    kind: RendererKind,
    opts: FillOptions,
    threads: Threads,
    ids: Vec<u32>,
    /// Per pixel: [`UNFILLED`], or the color a frame's sample or a fill stage gave it.
    state: Vec<u64>,
    depth: DepthBuffer,
    frame: Vec<u32>,
    /// The scene `frame` (its stale image) was splatted from: it depends on the frame only,
    /// so it is made once per frame, not per draw.
    frame_of: Option<SceneId>,
    pyramid: Vec<Vec<[f32; 4]>>,
}

/// The packet tracer with hole filling (`spheres-fill`).
pub type SpheresFill = HoleFill<PacketTracer>;

impl<R: SampleIds> HoleFill<R> {
    /// Wraps `inner`, reporting itself as `kind`, filling with `opts` on `threads` threads.
    pub fn new(inner: R, kind: RendererKind, opts: FillOptions, threads: usize) -> Self {
        let opts = FillOptions { pull_push_levels: opts.pull_push_levels.min(FillOptions::MAX_LEVELS), ..opts };
        HoleFill {
            inner,
            kind,
            opts,
            threads: Threads::new(threads),
            ids: Vec::new(),
            state: Vec::new(),
            depth: DepthBuffer::default(),
            frame: Vec::new(),
            frame_of: None,
            pyramid: Vec::new(),
        }
    }

    /// The wrapped renderer (e.g. to set the splatter's radius scale).
    pub fn inner_mut(&mut self) -> &mut R {
        &mut self.inner
    }

    /// The fill stages it runs.
    pub fn options(&self) -> FillOptions {
        self.opts
    }

    /// Changes the fill stages.
    pub fn set_options(&mut self, opts: FillOptions) {
        self.opts = FillOptions { pull_push_levels: opts.pull_push_levels.min(FillOptions::MAX_LEVELS), ..opts };
    }

    /// Draws the newest scene `scenes[0]` for `camera` and fills the pixels it leaves empty
    /// from the older scenes `scenes[1..]` (newest first; at most [`MAX_FRAMES`] in all), then
    /// with the enabled fill stages. An older scene that is inconsistent ([`Scene::check`]) is
    /// skipped; an unusable newest scene or camera draws the background like every renderer.
    pub fn render_set(&mut self, scenes: &[&Scene], camera: &Camera, out: &mut Image) {
        let Some(newest) = scenes.first() else {
            out.reset_for_unusable(camera, MAX_VIEWPORT);
            return;
        };
        if !begin_frame(newest, camera, out) || !self.inner.sample_ids(newest, camera, &mut self.ids) {
            return;
        }
        let w = camera.width as usize;
        // 1. The newest frame.
        self.state.clear();
        let colors = &newest.colors;
        self.state.extend(self.ids.iter().map(|&id| if id == NO_HIT { UNFILLED } else { filled(shade(colors, id)) }));
        if self.opts.enclosed_only {
            block_outside_silhouette_on(&mut self.state, w, camera.height as usize, &self.threads);
        }
        // 2. Older frames, newest first, only where nothing is yet.
        let basis = camera.ray_basis();
        for older in scenes.iter().take(MAX_FRAMES).skip(1) {
            if older.check().is_err() || older.samples.is_empty() {
                continue;
            }
            let l = older.lbvh();
            let colors = &older.colors;
            self.threads.for_each_chunk(&mut self.state, w * BAND, |band, px| {
                for (i, p) in px.iter_mut().enumerate().filter(|(_, p)| **p == UNFILLED) {
                    let j = band * w * BAND + i;
                    if let Some(hit) = l.trace(&basis.ray((j % w) as u32, (j / w) as u32)) {
                        *p = filled(shade(colors, hit.prim));
                    }
                }
            });
        }
        // 3. The stale frame for the view direction.
        if self.opts.stale {
            self.stale_fill(newest, camera);
        }
        // 4. Pull-push.
        if self.opts.pull_push_levels > 0 && self.state.contains(&UNFILLED) {
            self.pull_push(camera.width as usize, camera.height as usize);
        }
        for (p, &s) in out.pixels.iter_mut().zip(&self.state) {
            if s & FILLED != 0 {
                *p = s as u32;
            }
        }
    }

    /// Stage 3: unfilled pixels take the newest frame's stale color where their ray crosses the
    /// frame's focal plane (the frame's background where it had nothing there).
    fn stale_fill(&mut self, scene: &Scene, camera: &Camera) {
        let fc = scene.header.camera;
        if fc.validate(MAX_VIEWPORT).is_err() {
            return;
        }
        let (fw, fh) = (fc.width, fc.height);
        let len = fw as usize * fh as usize;
        let proj = Projector::new(&fc);
        let id = SceneId::of(scene);
        if self.frame_of != Some(id) || self.frame.len() != len {
            self.depth.reset(len, &self.threads);
            splat_points(scene, &proj, 1, fw, fh, &self.depth, &self.threads);
            self.frame.resize(len, 0);
            self.depth.resolve(&scene.colors, &mut self.frame, &self.threads);
            self.frame_of = Some(id);
        }
        let frame = &self.frame[..];
        stale_lookup(|i| frame[i], &fc, camera, &mut self.state, &self.threads);
    }

    /// Stage 4: pull-push over the filled pixels into the unfilled ones.
    fn pull_push(&mut self, w: usize, h: usize) {
        let levels = self.opts.pull_push_levels as usize;
        self.pyramid.resize_with(levels + 1, Vec::new);
        let mut dims = vec![(w, h)];
        for k in 0..levels {
            let (pw, ph) = dims[k];
            dims.push((pw.div_ceil(2), ph.div_ceil(2)));
        }
        // Level 0: RGB (opaque pixels) and weight 1 where filled.
        let l0 = &mut self.pyramid[0];
        l0.clear();
        l0.extend(self.state.iter().map(|&s| {
            let c = rgb(s as u32);
            [c[0], c[1], c[2], if s & FILLED != 0 { 1.0 } else { 0.0 }]
        }));
        // Pull: the weighted mean color of the children; weight min(1, Σw / 2), so a block
        // half covered counts as covered.
        for k in 0..levels {
            let (cw, ch) = dims[k];
            let (pw, ph) = dims[k + 1];
            let (lo, hi) = self.pyramid.split_at_mut(k + 1);
            let (child, parent) = (&lo[k], &mut hi[0]);
            parent.clear();
            parent.resize(pw * ph, [0.0; 4]);
            for py in 0..ph {
                for px in 0..pw {
                    let mut acc = [0.0f32; 4];
                    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (x, y) = (2 * px + dx, 2 * py + dy);
                        if x < cw && y < ch {
                            let c = child[y * cw + x];
                            for (a, v) in acc.iter_mut().zip(&c[..3]) {
                                *a += v * c[3];
                            }
                            acc[3] += c[3];
                        }
                    }
                    if acc[3] > 0.0 {
                        let inv = 1.0 / acc[3];
                        parent[py * pw + px] = [acc[0] * inv, acc[1] * inv, acc[2] * inv, (acc[3] * 0.5).min(1.0)];
                    }
                }
            }
        }
        // Push: each level's partly covered pixels take the rest of their weight from their
        // parent (already pushed), coarsest first.
        for k in (0..levels).rev() {
            let (cw, ch) = dims[k];
            let pw = dims[k + 1].0;
            let (lo, hi) = self.pyramid.split_at_mut(k + 1);
            let (child, parent) = (&mut lo[k], &hi[0]);
            for y in 0..ch {
                for x in 0..cw {
                    let c = &mut child[y * cw + x];
                    if c[3] >= 1.0 {
                        continue;
                    }
                    let p = parent[(y / 2) * pw + x / 2];
                    let (wc, wp) = (c[3], p[3] * (1.0 - c[3]));
                    let sum = wc + wp;
                    if sum > 0.0 {
                        for (v, pv) in c[..3].iter_mut().zip(&p[..3]) {
                            *v = (*v * wc + pv * wp) / sum;
                        }
                        c[3] = sum;
                    }
                }
            }
        }
        // Holes: the pushed color over the background by its weight.
        let bg = rgb(BACKGROUND);
        for (s, c) in self.state.iter_mut().zip(&self.pyramid[0]) {
            if *s != UNFILLED || !(c[3] > 0.0) {
                continue;
            }
            let a = c[3].min(1.0);
            let mix = |i: usize| c[i] * a + bg[i] * (1.0 - a);
            *s = filled(pack_color_f32([mix(0), mix(1), mix(2), 1.0]));
        }
    }
}

/// Stage 3 of the fill (shared with the layered splatter): every [`UNFILLED`] pixel of `state`
/// (laid out for `camera`) takes the color `frame` gives for the pixel (index `y · width + x`)
/// of the frame camera `fc` where the pixel's ray crosses `fc`'s focal plane; where the frame
/// shows background the pixel stays unfilled.
pub(crate) fn stale_lookup(
    frame: impl Fn(usize) -> u32 + Sync,
    fc: &Camera,
    camera: &Camera,
    state: &mut [u64],
    threads: &Threads,
) {
    let (fw, fh) = (fc.width, fc.height);
    let proj = Projector::new(fc);
    let (_, _, fwd) = fc.basis();
    // The focal plane: points q with q·fwd = target·fwd.
    let plane = fc.target.dot(fwd);
    let basis = camera.ray_basis();
    let eye = camera.eye;
    let w = camera.width as usize;
    threads.for_each_chunk(state, w * BAND, |band, px| {
        for (i, p) in px.iter_mut().enumerate().filter(|(_, p)| **p == UNFILLED) {
            let j = band * w * BAND + i;
            let d = basis.dir((j % w) as u32, (j / w) as u32);
            let denom = d.dot(fwd);
            let t = (plane - eye.dot(fwd)) / denom;
            // A ray that does not reach the plane ahead: take its direction from the
            // frame's eye instead (exact for a rotation about the eye).
            let q = if denom > 1e-6 && t > 0.0 { eye + d * t } else { fc.eye + d };
            let Some((x, y, _)) = proj.project(q) else { continue };
            if x >= 0.0 && y >= 0.0 && x < fw as f32 && y < fh as f32 {
                // Where the frame showed background too, the pixel stays a hole (for
                // pull-push; the background otherwise, as before).
                let c = frame(y as usize * fw as usize + x as usize);
                if c != BACKGROUND {
                    *p = filled(c);
                }
            }
        }
    });
}

/// Rows per parallel work unit of the fill passes.
const BAND: usize = 8;

/// A pixel no stage has filled yet (a filled pixel has bit 32 set).
pub(crate) const UNFILLED: u64 = 0;
/// The bit of a filled pixel.
pub(crate) const FILLED: u64 = 1 << 32;
/// An empty pixel the fill stages leave alone (outside the silhouette): the background.
const BLOCKED: u64 = 1 << 33;

/// A filled pixel of color `c`.
#[inline(always)]
pub(crate) fn filled(c: u32) -> u64 {
    FILLED | c as u64
}

/// Per row (or column) the first and last covered column (row), `(usize::MAX, 0)` where none.
type Spans = Vec<(usize, usize)>;

/// Marks the unfilled pixels outside the covered pixels' row and column spans [`BLOCKED`].
///
/// In parallel over bands of rows: each band finds its rows' spans and its part of the
/// columns' spans, the columns' parts are merged (first and last covered row), then each band
/// blocks its pixels. The same result on any thread count (tested against the per-pixel rule).
pub(crate) fn block_outside_silhouette_on(state: &mut [u64], w: usize, h: usize, threads: &Threads) {
    if w == 0 || h == 0 || state.len() < w * h {
        return;
    }
    let band = h.div_ceil(threads.count().max(1) * 4).max(1);
    let bands = h.div_ceil(band);
    // Per band: its rows' (first, last) covered column, and the columns' (first, last)
    // covered row within the band.
    let mut parts: Vec<(Spans, Spans)> = vec![(Vec::new(), Vec::new()); bands];
    let state_ro = &state[..w * h];
    threads.for_each_chunk(&mut parts, 1, |b, part| {
        let (rows, cols) = &mut part[0];
        rows.clear();
        rows.resize(band, (usize::MAX, 0));
        cols.clear();
        cols.resize(w, (usize::MAX, 0));
        let y0 = b * band;
        for (dy, row) in state_ro[y0 * w..((y0 + band).min(h)) * w].chunks_exact(w).enumerate() {
            let y = y0 + dy;
            for (x, _) in row.iter().enumerate().filter(|(_, &s)| s & FILLED != 0) {
                cols[x] = (cols[x].0.min(y), y);
                rows[dy] = (rows[dy].0.min(x), x);
            }
        }
    });
    let mut cols = vec![(usize::MAX, 0usize); w];
    for (_, part) in &parts {
        for (c, &(lo, hi)) in cols.iter_mut().zip(part) {
            if lo != usize::MAX {
                *c = (c.0.min(lo), hi);
            }
        }
    }
    let (cols, parts) = (&cols, &parts);
    threads.for_each_chunk(&mut state[..w * h], band * w, |b, rows_of_band| {
        let y0 = b * band;
        for (dy, row) in rows_of_band.chunks_exact_mut(w).enumerate() {
            let y = y0 + dy;
            let (x0, x1) = parts[b].0[dy];
            for (x, s) in row.iter_mut().enumerate() {
                let inside = x0 <= x && x <= x1 && cols[x].0 <= y && y <= cols[x].1;
                if *s == UNFILLED && !inside {
                    *s = BLOCKED;
                }
            }
        }
    });
}

/// RGB of a packed color in 0..=1.
#[inline(always)]
fn rgb(c: u32) -> [f32; 3] {
    let [r, g, b, _] = c.to_le_bytes();
    [r as f32 / 255.0, g as f32 / 255.0, b as f32 / 255.0]
}

impl<R: SampleIds + Renderer> Renderer for HoleFill<R> {
    fn kind(&self) -> RendererKind {
        self.kind
    }

    fn set_adaptive_radius(&mut self, on: bool) -> bool {
        self.inner.set_adaptive_radius(on)
    }

    fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) {
        self.render_set(&[scene], camera, out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::SplitMix64;

    /// The silhouette rule pixel by pixel, as first written (a division per pixel).
    fn block_reference(state: &mut [u64], w: usize, h: usize) {
        let mut cols = vec![(usize::MAX, 0usize); w];
        let mut rows = vec![(usize::MAX, 0usize); h];
        for (j, &s) in state.iter().enumerate() {
            if s & FILLED != 0 {
                let (x, y) = (j % w, j / w);
                cols[x] = (cols[x].0.min(y), cols[x].1.max(y));
                rows[y] = (rows[y].0.min(x), rows[y].1.max(x));
            }
        }
        for (j, s) in state.iter_mut().enumerate() {
            let (x, y) = (j % w, j / w);
            let inside = rows[y].0 <= x && x <= rows[y].1 && cols[x].0 <= y && y <= cols[x].1;
            if *s == UNFILLED && !inside {
                *s = BLOCKED;
            }
        }
    }

    #[test]
    fn silhouette_blocking_matches_the_per_pixel_rule() {
        let mut rng = SplitMix64(5);
        for (w, h, density) in [(1, 1, 0.5), (7, 5, 0.3), (64, 48, 0.05), (33, 90, 0.6), (16, 16, 0.0)] {
            let state: Vec<u64> = (0..w * h)
                .map(|_| if rng.next_f32() < density { filled(rng.next_u64() as u32) } else { UNFILLED })
                .collect();
            let mut b = state.clone();
            block_reference(&mut b, w, h);
            for threads in [1, 2, 3] {
                let mut a = state.clone();
                block_outside_silhouette_on(&mut a, w, h, &Threads::new(threads));
                assert_eq!(a, b, "{w}×{h}, {threads} thread(s)");
            }
        }
    }
}
