//! Older frames: what the newest frame saw ([`Sight`]) and, per older frame, its residual, the
//! samples the newest frame did not see ([`OlderSets`]).

use super::footprints::*;
use super::options::*;
use super::own_pass::*;
use crate::route::SceneId;
use crate::threads::Threads;
use crate::MAX_VIEWPORT;
use volwarp_core::{Camera, Scene};

/// The older frames kept, each reduced to what the newest frame did not see (its *residual*,
/// see `crate::layer_splat`): one definition for [`LayerSplat`](crate::LayerSplat) and the GPU's layered splatter,
/// which draws the same sets in the same order (through [`OlderSets`]).
#[derive(Debug, Default)]
pub(crate) struct OlderFrames {
    /// What the newest frame saw.
    pub(crate) sight: Sight,
    /// The newest frame the residuals are for.
    pub(crate) residual_for: Option<SceneId>,
    /// Per older frame (newest first) its residual.
    pub(crate) residuals: Vec<(SceneId, Scene)>,
}

impl OlderFrames {
    /// Brings the residuals up to date for `newest` (whose samples in its own camera are
    /// `own`) and `older` (newest first; none: nothing kept): per older frame the samples the
    /// newest frame did not see.
    ///
    /// When the set has moved on by one frame (the previous newest is now the first older
    /// frame), an older frame's residual is what is left of its last one: what the previous
    /// newest saw of it is already drawn before it, from the previous newest's own samples, so
    /// only the new newest's sight is applied to the (small) residuals, and only the previous
    /// newest is reduced whole. Any other change of the set reduces every older frame whole.
    pub(crate) fn update(&mut self, own: &mut OwnPass, newest: &Scene, older: &[&Scene], threads: &Threads) {
        if older.is_empty() {
            self.residuals.clear();
            return;
        }
        let id = SceneId::of(newest);
        let older = &older[..older.len().min(crate::hole_fill::MAX_FRAMES - 1)];
        let mut fresh = false;
        if self.residual_for != Some(id) {
            let shifted = self.residual_for.is_some() && older.first().map(|o| SceneId::of(o)) == self.residual_for;
            if !shifted {
                self.residuals.clear();
            }
            own.prepare(newest, threads);
            self.sight.update(newest, own, threads);
            self.residual_for = Some(id);
            fresh = true;
        }
        let mut next = Vec::with_capacity(older.len());
        for &o in older {
            let oid = SceneId::of(o);
            let r = match self.residuals.iter().position(|(i, _)| *i == oid) {
                Some(i) if fresh => self.sight.residual(&self.residuals.swap_remove(i).1, threads),
                Some(i) => self.residuals.swap_remove(i).1,
                // An inconsistent scene adds nothing.
                None if !crate::frame_setup::unbuilt_ok(o) => Scene::empty(&o.header),
                None => self.sight.residual(o, threads),
            };
            next.push((oid, r));
        }
        self.residuals = next;
    }

    /// The scenes to draw after the newest (whose frame camera is `fc`) for `camera`, in
    /// order, each into the pixels still empty: the residuals of [`OlderFrames::update`]'s
    /// `older`. Turned more than 90° from the newest frame's view, its footprints face away
    /// and draw nothing: what it saw is then no reason to leave an older sample out, so the
    /// older frames are drawn whole.
    pub(crate) fn sets<'a>(&'a self, fc: &Camera, camera: &Camera, older: &[&'a Scene]) -> Vec<&'a Scene> {
        let back_facing = (fc.target - fc.eye).dot(camera.target - camera.eye) < 0.0;
        if back_facing {
            older.iter().take(self.residuals.len()).copied().filter(|o| crate::frame_setup::unbuilt_ok(o)).collect()
        } else {
            self.residuals.iter().map(|(_, r)| r).collect()
        }
    }
}

/// What a renderer other than [`LayerSplat`](crate::LayerSplat) (the GPU's `splat-layers-gpu`) needs to draw
/// the older frames kept as [`LayerSplat::render_set`](crate::LayerSplat) does: the scenes to draw after the
/// newest, in order, each into the pixels still empty, made by the CPU's own code (the
/// residuals are made once per arriving frame, on the CPU, and are small).
#[derive(Debug)]
pub struct OlderSets {
    pub(crate) frames: OlderFrames,
    pub(crate) own: OwnPass,
    pub(crate) threads: Threads,
}

impl OlderSets {
    /// On `threads` threads (0: one per core).
    pub fn new(threads: usize) -> Self {
        OlderSets { frames: OlderFrames::default(), own: OwnPass::default(), threads: Threads::new(threads) }
    }

    /// The scenes to draw for `camera` after `newest`, given the `older` frames kept (newest
    /// first; at most `hole_fill::MAX_FRAMES − 1` are used) and whether holes are filled
    /// (`fill`, [`LayerOptions::fill`]): each older frame's residual (or the older frames whole
    /// when the camera has turned more than 90° from the newest frame's view). Empty where
    /// [`LayerSplat::render_set`](crate::LayerSplat) draws no older frame (none kept; or the frame's own image at
    /// its own camera, with the fill), and then, as there, the residuals are not touched: the
    /// same calls leave both renderers with the same residuals. The caller has checked that
    /// `newest` and `camera` can be drawn.
    pub fn sets<'a>(&'a mut self, newest: &Scene, older: &[&'a Scene], camera: &Camera, fill: bool) -> Vec<&'a Scene> {
        let fc = newest.header.camera;
        let fill = fill && fc.validate(MAX_VIEWPORT).is_ok();
        if (fill && *camera == fc) || (!fill && older.is_empty()) {
            return Vec::new();
        }
        self.frames.update(&mut self.own, newest, older, &self.threads);
        self.frames.sets(&fc, camera, older)
    }
}

/// A scene's copy without its LBVH.
pub(crate) fn unbuilt_copy(s: &Scene) -> Scene {
    Scene { header: s.header, deq: s.deq, samples: s.samples.clone(), colors: s.colors.clone(), nodes: Vec::new() }
}

/// What a frame saw, per pixel of its camera: the view depth beyond which a point is hidden
/// from it (behind the farthest segment of a pixel at least [`RESIDUAL_OPAQUE`] opaque, by
/// [`RESIDUAL_TOLERANCE`] pixels at that depth), infinite where the pixel is empty or seen
/// through (4 bytes per pixel, reused frame to frame).
#[derive(Debug, Default)]
pub struct Sight {
    pub(crate) proj: Option<Proj>,
    pub(crate) w: usize,
    pub(crate) h: usize,
    pub(crate) hidden: Vec<f32>,
}

impl Sight {
    /// Records what `scene` saw (nothing for an unusable camera: then every sample of an older
    /// frame counts as unseen), from its samples grouped by pixel of its own camera (`own`,
    /// after [`OwnPass::group`]), in parallel over rows.
    pub(crate) fn update(&mut self, scene: &Scene, own: &OwnPass, threads: &Threads) {
        self.proj = None;
        let Some((proj, w, h)) = own.proj else { return };
        if own.start.len() != w * h + 1 {
            return;
        }
        (self.w, self.h) = (w, h);
        self.proj = Some(proj);
        self.hidden.resize(w * h, 0.0);
        // z > zmax + tol·z / px  ⟺  z > zmax / (1 − tol / px).
        let k = 1.0 / (1.0 - RESIDUAL_TOLERANCE / proj.px_x).max(1e-3);
        let (start, grouped, at, colors) = (&own.start[..], &own.grouped[..], &own.at[..], &scene.colors[..]);
        threads.for_each_chunk(&mut self.hidden, RASTER_BAND * w, |band, hidden| {
            let first = band * RASTER_BAND * w;
            for (j, out) in hidden.iter_mut().enumerate() {
                let (a, b) = (start[first + j] as usize, start[first + j + 1] as usize);
                // The pixel's transmittance and farthest depth, its samples in their order.
                let (mut trans, mut far) = (1.0f32, f32::NEG_INFINITY);
                for &key in &grouped[a..b] {
                    let id = key as u32 as usize;
                    if let (Some(&c), Some(&p)) = (colors.get(id), at.get(id)) {
                        trans *= 1.0 - (c >> 24) as f32 / 255.0;
                        far = far.max(f32::from_bits(p as u32));
                    }
                }
                *out = if 1.0 - trans >= RESIDUAL_OPAQUE && far.is_finite() { far * k } else { f32::INFINITY };
            }
        });
    }

    /// The samples of `o` this frame did not see: those outside its view, and those behind
    /// the farthest segment of an opaque pixel (by more than [`RESIDUAL_TOLERANCE`] pixels at
    /// their depth). A sample on a ray that found nothing, or within the span of what the ray
    /// saw, or behind what it saw through, is left out: the newest frame knows better there.
    pub(crate) fn residual(&self, o: &Scene, threads: &Threads) -> Scene {
        let Some(proj) = self.proj else {
            return unbuilt_copy(o);
        };
        let (w, h) = (self.w, self.h);
        let mut keep = vec![0u8; o.samples.len()];
        threads.for_each_chunk(&mut keep, QUAD_CHUNK, |chunk, keep| {
            let first = chunk * QUAD_CHUNK;
            let (mut idx, mut zs) = ([NO_PIXEL; QUAD_CHUNK], [0f32; QUAD_CHUNK]);
            let n = keep.len();
            project(&proj, (w, h), &o.deq, &o.samples[first..first + n], &mut idx[..n], &mut zs[..n], &mut []);
            for ((k, &i), &z) in keep.iter_mut().zip(&idx).zip(&zs) {
                // Outside the view (no pixel): unseen.
                *k = self.hidden.get(i as usize).is_none_or(|&hz| z > hz) as u8;
            }
        });
        let n = keep.iter().filter(|&&k| k != 0).count();
        let mut r = Scene {
            header: o.header,
            deq: o.deq,
            samples: Vec::with_capacity(n),
            colors: Vec::with_capacity(n),
            nodes: Vec::new(),
        };
        for ((&k, &smp), &c) in keep.iter().zip(&o.samples).zip(&o.colors) {
            if k != 0 {
                r.samples.push(smp);
                r.colors.push(c);
            }
        }
        r
    }
}
