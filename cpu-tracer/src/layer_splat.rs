//! Layered samples composited front to back (renderer `splat-layers`).
//!
//! A layered frame carries up to K samples per pixel of the frame's camera, one per depth
//! segment, each with its own premultiplied color and opacity. Where the exact splatter
//! ([`crate::sphere_splat`]) draws each sample as a sphere and keeps the first hit, this
//! renderer draws each sample as its **source pixel's footprint**: the quadrilateral the frame
//! camera's pixel frustum cuts from the plane through the sample's centre facing the new eye
//! (the supersegment of volumetric depth images, Frey, Sadlo and Ertl 2013, flattened to its
//! representative depth), widened by [`OWN_MARGIN`] pixels (none by default). The quad is
//! projected into the new camera and every output pixel whose centre lies inside it takes the
//! sample. (A plane facing the frame's camera instead shrinks footprints seen obliquely and
//! opens cracks between them.) Footprints of one depth tile the plane, so nothing is
//! counted twice where neighbouring segments lie at similar depths, and at the frame's own
//! camera every pixel takes exactly its own segments: the image is the server's render up to
//! 8-bit rounding. (A first version tested each pixel of the sphere's bound exactly and kept
//! the hits whose point nearest the centre projected into the sample's own pixel: the same rule
//! about 10× slower.) The spheres' radii are not used.
//!
//! Per output pixel the samples go to a short list (the nearest, at most [`LIST`], as
//! `(distance from the eye, sample id)` keys); the list is sorted (ties by id, so the result
//! does not depend on the order of the samples) and composited front to back,
//! `C += (1 − A)·c`, stopping once `A` ≥ [`OPAQUE`]. Zero-opacity segments add nothing (no
//! division by opacity anywhere, so no NaN). Pixels nothing covers show the background. The lists,
//! their sort and their compositing live in `key_list.rs` (AVX2 paths beside the scalar
//! reference: the compositing runs eight pixels at once, one per lane).
//!
//! **Watertight slabs** ([`LayerOptions::watertight`]): the `j`-th nearest segment of a pixel
//! belongs to slab `j`. Where the slab-`j` segments of the pixels around a corner of the source
//! pixel grid lie within [`WATERTIGHT`] source pixels of each other in depth, that corner is
//! shared: it sits on its ray at their mean depth, computed once per frame when it arrives
//! ([`SlabCorners`]) and used by every pixel around it, so the footprints of one slab meet
//! exactly instead of overlapping on one side and parting on the other (a semi-transparent
//! slab counted twice or not at all, in bands along the surface's iso-depth lines: the contour
//! lines `docs/results.md` traced). A segment takes its shared corners only where their
//! footprint covers at least [`LayerOptions::water_ratio`] of the plane footprint's area on
//! screen (a slab seen ever more edge-on thins to a sliver where the volume it stands for does
//! not), and only if it does not grow (adaptive sizing below). There its color is drawn with
//! its optical depth scaled by the plane footprint's area over the slab's
//! ([`LayerOptions::opacity_limit`], `footprints::drawn_color`): seen from the new eye a slab
//! turned away is crossed along a longer path and looks more opaque, one turned towards the eye
//! less (without it, the overlapping planes' double counting was what added that opacity, in
//! bands). At the frame's own camera a shared corner projects onto its pixel corner at any
//! depth and the areas are equal, so the frame is still reproduced there.
//!
//! **Hole filling** ([`LayerOptions::fill`]): pixels no segment covers,
//! inside the covered pixels' row and column spans, take the frame's own composited image for
//! their view direction (the stale frame, looked up as [`crate::hole_fill`]'s stage 3 does), so
//! what the warp knows nothing about shows what a send-image system would, not the background.
//! At its own camera every footprint is exactly its source pixel, so the frame's image at a
//! pixel is that pixel's own segments composited: when a frame arrives its samples are grouped
//! by source pixel once (`OwnPass`), and each hole composites the pixel it looks up on the
//! spot; the whole image is composited only when the frame's own camera is drawn.
//!
//! **Cracks** ([`LayerOptions::close_cracks`]): last, away from the frame's own camera, runs of
//! one or two pixels along a row or column that show the background through between two
//! like, solid pixels take what those cover (`layered::close_cracks`): a surface the frame saw
//! edge-on and the new camera sees broadside, whose footprints parted, or a semi-transparent
//! slab's footprints parted over deeper ones.
//!
//! **Older frames** ([`Renderer::render_set`], the multi-frame filling; the client keeps
//! 4 frames by default): pixels no segment of the newest frame covers first take the older
//! frames' segments, newest first, before the hole filling above. Only what the newest frame did
//! not see comes back: when a newest frame arrives, its [`Sight`] (per pixel of its camera, the
//! view depths of its nearest and farthest segment and its opacity) reduces each older frame
//! once to its *residual* (the previous newest whole, the others' residuals further), the
//! samples outside the newest frame's view or more than
//! [`RESIDUAL_TOLERANCE`] pixels behind the farthest segment of a pixel at least
//! [`RESIDUAL_OPAQUE`] opaque. So an older sample never stands where the newest frame saw empty
//! space or the same surface (on a steady orbit older frames change nothing), and a camera
//! turning back gets the surfaces the newest frame could not see. Turned more than 90° from
//! the newest frame's view, its footprints face away and draw nothing, so older frames are then
//! drawn whole. Residuals are drawn only
//! into pixels still empty, and footprints touching no tile with an empty pixel are skipped.
//!
//! **Warp-sized footprints** ([`Renderer::set_adaptive_radius`]): a surface seen from a new
//! direction spreads its pixels' footprints apart at grazing angles; with adaptive sizing on,
//! the half side grows by [`LayerOptions::grow_per_degree`] of the display's pixels per degree
//! of warp beyond [`LayerOptions::grow_from_deg`] (core's `warp_radius::warp_angle_deg`;
//! [`LayerOptions::grown`]) up to [`MAX_OWN`]
//! source pixels; at the frame's own camera it is
//! [`LayerOptions::own`], so the frame is still reproduced there.
//!
//! Work: the footprints are set up in parallel over samples (four projections per sample, in
//! `f32`, four more where a sample has shared corners), binned to bands of rows, rasterized in
//! parallel over bands (a few edge tests per covered pixel) and composited band by band.
//! Memory: 1 byte per output pixel (its count), `8 × LIST` bytes per pixel of one band per
//! thread, and per sample 64 bytes (its footprint) plus 4 for its band range and 4 per band it
//! touches; for the newest frame, 20 bytes per sample and 4 per pixel (`OwnPass`) and 20 per
//! sample for its shared corners (44 for a frame not in the server's order, which is sorted
//! first).

use crate::hole_fill::{block_outside_silhouette_on, filled, stale_lookup, FILLED, UNFILLED};
use crate::key_list::{composite_run, insert, sort_keys};
use crate::layered::*;
pub use crate::layered::{
    LayerOptions, OlderSets, Proj, Setup, Sight, SlabCorners, LIST, MAX_OWN, OPAQUE, OWN_MARGIN, RESIDUAL_OPAQUE,
    RESIDUAL_TOLERANCE, WATERTIGHT,
};
use crate::route::SceneId;
use crate::threads::Threads;
use crate::{begin_frame_unbuilt_ok, MAX_VIEWPORT};
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::{Camera, RendererKind, Scene, BACKGROUND};

mod raster;
use raster::Holes;
#[cfg(test)]
mod tests;

/// The layered splatter (renderer name `splat-layers`).
#[derive(Debug)]
pub struct LayerSplat {
    threads: Threads,
    opts: LayerOptions,
    /// Per output pixel the number of keys.
    count: Vec<u8>,
    /// Grow the footprints with the warp.
    adaptive: bool,
    /// The frame's own composited image (drawn at the frame's own camera; the hole lookups'
    /// source for footprints other than the default's) and the scene it was made from.
    frame: Image,
    frame_of: Option<SceneId>,
    /// Per output pixel the fill state (`hole_fill`'s encoding).
    state: Vec<u64>,
    /// Per sample its footprint.
    quads: Vec<Quad>,
    /// Per binning task (one per thread), per band of rows, the footprints of the task's run
    /// that touch it.
    bins: Vec<Vec<Vec<u32>>>,
    /// Per sample the first and last band of rows its footprint touches (`b0 | b1 << 16`).
    bands: Vec<u32>,
    /// An older frame's image (multi-frame filling).
    scratch: Image,
    /// The newest frame's samples in its own camera (its own image and its `Sight` use them).
    own: OwnPass,
    /// What the newest frame saw, and per older frame what it did not see.
    older: OlderFrames,
    /// Which tiles of the image still hold an unfilled pixel (see `Holes`).
    tiles: Vec<u8>,
    /// Per sample its color as drawn (see `footprints::drawn_color`).
    drawn: Vec<u32>,
    /// The crack pass's per-pixel distances and found pixels (`close_cracks`).
    cracks: CrackScratch,
}

impl LayerSplat {
    /// A layered splatter on `threads` threads (0: one per core).
    pub fn new(threads: usize) -> Self {
        LayerSplat::with_options(threads, LayerOptions::default())
    }

    /// A layered splatter with another footprint width.
    pub fn with_options(threads: usize, opts: LayerOptions) -> Self {
        LayerSplat {
            threads: Threads::new(threads),
            opts,
            count: Vec::new(),
            adaptive: false,
            frame: Image::new(0, 0),
            frame_of: None,
            state: Vec::new(),
            quads: Vec::new(),
            bins: Vec::new(),
            bands: Vec::new(),
            scratch: Image::new(0, 0),
            own: OwnPass::default(),
            older: OlderFrames::default(),
            tiles: Vec::new(),
            drawn: Vec::new(),
            cracks: CrackScratch::default(),
        }
    }

    /// The options it draws with.
    pub fn options(&self) -> LayerOptions {
        self.opts
    }
}

/// The pixels a draw covered (`count` > 0) into the fill `state` with their color from
/// `pixels`, where still [`UNFILLED`]; with `fresh` the state is set anew (every other pixel
/// [`UNFILLED`]). In parallel over runs of `rows` pixels (each pixel on its own).
fn take_drawn(threads: &Threads, state: &mut [u64], count: &[u8], pixels: &[u32], rows: usize, fresh: bool) {
    threads.for_each_chunk(state, rows, |i, state| {
        let at = i * rows;
        for ((s, &n), &p) in state.iter_mut().zip(&count[at..]).zip(&pixels[at..]) {
            if n > 0 && (fresh || *s == UNFILLED) {
                *s = filled(p);
            } else if fresh {
                *s = UNFILLED;
            }
        }
    });
}

impl Renderer for LayerSplat {
    fn kind(&self) -> RendererKind {
        RendererKind::SplatLayers
    }

    fn set_adaptive_radius(&mut self, on: bool) -> bool {
        self.adaptive = on;
        true
    }

    fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) {
        self.render_set(&[scene], camera, out);
    }

    fn keeps_frames(&self) -> bool {
        true
    }

    /// Draws the newest of `scenes` (newest first) for `camera` and fills what it leaves
    /// uncovered from the older ones in turn (what each saw that the newest did not), then
    /// from the newest frame's own image (see the module docs).
    fn render_set(&mut self, scenes: &[&Scene], camera: &Camera, out: &mut Image) {
        let Some((&scene, older)) = scenes.split_first() else {
            out.reset_for_unusable(camera, MAX_VIEWPORT);
            return;
        };
        if !begin_frame_unbuilt_ok(scene, camera, out) {
            return;
        }
        let fc = scene.header.camera;
        let fill = self.opts.fill && fc.validate(MAX_VIEWPORT).is_ok();
        // At the frame's own camera the filled image is the frame's own (nothing is a hole
        // there, and footprints do not grow): composited once, then copied.
        if fill && *camera == fc {
            self.cache_own_image(scene);
            if self.frame.pixels.len() == out.pixels.len() {
                out.pixels.copy_from_slice(&self.frame.pixels);
                return;
            }
        }
        let grown = self.opts.half_side(self.adaptive, &fc, camera);
        // Watertight slabs: the newest frame's corners shared between neighbouring pixels.
        let shared = if self.opts.shares_corners() {
            if self.own.prepare(scene, &self.threads) {
                self.own.share_corners(self.opts.watertight, &self.threads);
            }
            core::mem::take(&mut self.own.shared)
        } else {
            Vec::new()
        };
        self.draw(scene, camera, grown, &shared, out, None);
        self.own.shared = shared;
        if !fill && older.is_empty() {
            close_cracks_of(&self.opts, &fc, camera, out, &mut self.cracks, &self.threads);
            return;
        }
        let (w, h) = (camera.width as usize, camera.height as usize);
        // The per-pixel passes below run in parallel over runs of rows (each pixel on its own).
        let rows = PIXEL_PASS_ROWS * w;
        self.state.resize(w * h, UNFILLED);
        take_drawn(&self.threads, &mut self.state[..w * h], &self.count, &out.pixels, rows, true);
        // Older frames, newest first, only where nothing is yet: what
        // each saw that the newest frame did not (see [`Sight`]), so an older sample never
        // stands where the newest frame saw empty space or the same surface.
        let mut older_frames = core::mem::take(&mut self.older);
        older_frames.update(&mut self.own, scene, older, &self.threads);
        let mut scratch = core::mem::replace(&mut self.scratch, Image::new(0, 0));
        let mut tiles = core::mem::take(&mut self.tiles);
        let sets = older_frames.sets(&fc, camera, older);
        // The tiles holding an unfilled pixel, once: a superset of those left after each older
        // frame, so nothing is missed.
        let tiles_w =
            if sets.iter().any(|o| !o.samples.is_empty()) { Holes::mark(&self.state, w, &mut tiles) } else { 0 };
        let holes = tiles_w > 0 && tiles.contains(&1);
        for &o in sets.iter().filter(|o| holes && !o.samples.is_empty()) {
            // The older frame's pixels are read only where it has segments: no clearing.
            scratch.width = camera.width;
            scratch.height = camera.height;
            scratch.pixels.resize(w * h, BACKGROUND);
            let oc = o.header.camera;
            // Older frames grow with their own warp too (measured: without it the MRI's
            // stop-and-go p95 rose from 0.0489 to 0.0545).
            let g = self.opts.half_side(self.adaptive, &oc, camera);
            let state = core::mem::take(&mut self.state);
            self.draw(o, camera, g, &[], &mut scratch, Some(Holes { state: &state, tiles: &tiles, tiles_w }));
            self.state = state;
            take_drawn(&self.threads, &mut self.state[..w * h], &self.count, &scratch.pixels, rows, false);
        }
        self.older = older_frames;
        self.scratch = scratch;
        self.tiles = tiles;
        if fill {
            block_outside_silhouette_on(&mut self.state, w, h, &self.threads);
            // The frame's own image where a hole looks it up: each such pixel's own segments
            // composited on the spot (a few thousand, against a million for the whole image).
            if self.opts.own_pixels() {
                self.own.prepare(scene, &self.threads);
                let (own, colors) = (&self.own, &scene.colors[..]);
                stale_lookup(|i| own.pixel(i, colors), &fc, camera, &mut self.state, &self.threads);
            } else {
                self.cache_own_image(scene);
                let frame = &self.frame.pixels[..];
                stale_lookup(
                    |i| frame.get(i).copied().unwrap_or(BACKGROUND),
                    &fc,
                    camera,
                    &mut self.state,
                    &self.threads,
                );
            }
        }
        let state = &self.state[..];
        self.threads.for_each_chunk(&mut out.pixels, rows, |i, pixels| {
            for (p, &s) in pixels.iter_mut().zip(&state[i * rows..]) {
                if s & FILLED != 0 {
                    *p = s as u32;
                }
            }
        });
        close_cracks_of(&self.opts, &fc, camera, out, &mut self.cracks, &self.threads);
    }
}

impl LayerSplat {
    /// Makes [`LayerSplat::frame`] the frame's own composited image, unless it already is.
    fn cache_own_image(&mut self, scene: &Scene) {
        if self.frame_of == Some(SceneId::of(scene)) {
            return;
        }
        let mut frame = core::mem::replace(&mut self.frame, Image::new(0, 0));
        if begin_frame_unbuilt_ok(scene, &scene.header.camera, &mut frame) {
            self.own_image(scene, &mut frame);
        }
        self.frame = frame;
        self.frame_of = Some(SceneId::of(scene));
    }

    /// The frame's own composited image into `out` (sized to the frame's camera and cleared
    /// to the background): with the default footprint width, each pixel's own segments sorted
    /// and composited ([`OwnPass`]); with another width, the footprints drawn at the frame's
    /// camera.
    fn own_image(&mut self, scene: &Scene, out: &mut Image) {
        let fc = scene.header.camera;
        if !self.opts.own_pixels() {
            self.draw(scene, &fc, self.opts.own, &[], out, None);
            return;
        }
        if !self.own.prepare(scene, &self.threads) {
            return;
        }
        let w = fc.width as usize;
        let (own, colors) = (&self.own, &scene.colors[..]);
        self.threads.for_each_chunk(&mut out.pixels, RASTER_BAND * w, |band, px| {
            let first = band * RASTER_BAND * w;
            for (j, p) in px.iter_mut().enumerate() {
                *p = own.pixel(first + j, colors);
            }
        });
    }
}
