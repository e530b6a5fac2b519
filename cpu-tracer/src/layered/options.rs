//! The layered model's options, limits and work sizes: what the CPU and GPU layered renderers
//! share (`LayerOptions`, the list length and opacity at which compositing stops, the frames
//! kept) and the CPU's band and chunk sizes.

pub use crate::key_list::{LIST, OPAQUE};
pub use volwarp_core::method::MAX_FRAMES;
use volwarp_core::warp_radius::warp_angle_deg;
use volwarp_core::Camera;

/// How far (in source pixels) beyond its own pixel a sample's footprint reaches. 0: a margin
/// against rounding cracks (0.05 in the first version) counts semi-transparent segments
/// twice along every footprint edge, a grid of bright lines once the view zooms in; without it
/// the session ꟻLIP of the iron protein's dolly fell from 0.0187 to 0.0064 and the MRI's orbit
/// from 0.0262 to 0.0200 (`docs/results.md`, "Layered frames as the default").
pub const OWN_MARGIN: f32 = 0.0;

/// The default depth tolerance of watertight slabs, source pixels ([`LayerOptions::watertight`]):
/// the method's (core's `method::WATERTIGHT`).
pub use volwarp_core::method::WATERTIGHT;

/// The widest footprint adaptive sizing grows to by default (half side, source pixels).
pub const MAX_OWN: f32 = 2.0;

/// Output rows per rasterization task (the footprints are binned to bands of these rows).
pub(crate) const RASTER_BAND: usize = 8;

/// The band range of a sample without a footprint (first > last).
pub(crate) const NO_BANDS: u32 = 1;

/// How far behind the farthest segment of an opaque pixel of the newest frame (in that
/// frame's pixels at the sample's depth) an older frame's sample must lie to be drawn: the
/// segments' depths are representative, not exact. Measured insensitive between 1 and 6 (the
/// MRI's stop-and-go p95 0.0489 at all three).
pub const RESIDUAL_TOLERANCE: f32 = 3.0;

/// The opacity from which a pixel of the newest frame hides what lies behind its segments
/// (measured: 0.5 and 0.9 give the same sessions).
pub const RESIDUAL_OPAQUE: f32 = 0.9;

/// Rows per task of the shared-corner stencil (each task reads a row more above and below, and
/// keeps its own three rows of slab depths).
pub(crate) const CORNER_BAND: usize = 32;

/// Samples per footprint set-up task.
pub(crate) const QUAD_CHUNK: usize = 4096;

/// Rows per task of the per-pixel passes over the fill state (in parallel: at 1024² each pass
/// reads and writes 8 MB of state).
pub(crate) const PIXEL_PASS_ROWS: usize = 64;

/// How wide a sample's footprint is (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayerOptions {
    /// Half the footprint's side, in source pixels: 0.5 is the source pixel itself; the default
    /// adds [`OWN_MARGIN`]. Measured (`docs/perf.md`, layered samples): 0.7 double-counts more than it
    /// fills.
    pub own: f32,
    /// Fill the pixels no segment covers from the frame's image (see the module docs).
    pub fill: bool,
    /// With adaptive sizing on, the half side added per degree of warp beyond
    /// [`LayerOptions::grow_from_deg`] (the display's pixels; see [`LayerOptions::grown`]).
    pub grow_per_degree: f32,
    /// The warp (degrees) up to which footprints keep their own size with adaptive sizing on:
    /// a small warp parts few footprints, and grown ones, dropping their slab's shared corners,
    /// cover a neighbour's semi-transparent front segment (a lattice of bright dots on the
    /// skin). Measured (`docs/results.md`, "The layered levers"): 1 against 0, 2, 5 and 8.
    pub grow_from_deg: f32,
    /// Only samples at least this opaque (8-bit alpha) grow: growing a semi-transparent
    /// segment counts its color twice where footprints overlap.
    pub grow_min_alpha: u8,
    /// The widest a grown footprint gets (half side, source pixels).
    pub max_own: f32,
    /// Watertight slabs: neighbouring pixels' segments of the same slab share their
    /// footprints' corners where their depths differ by at most this many source pixels (0:
    /// every footprint is its own plane). Only with footprints of the source pixel's size.
    /// Measured (`docs/results.md`, "Watertight slabs"): with the optical depth scaled by
    /// area ([`LayerOptions::opacity_limit`]) 5, with planes alone 1.5.
    pub watertight: f32,
    /// A segment takes its slab's shared corners only where their footprint covers at least
    /// this share of the plane footprint's area on screen: a slab seen ever more edge-on
    /// thins to a sliver where the volume it stands for does not. Measured (`docs/results.md`,
    /// "Watertight slabs"): 0.5 against 1 and 0.25, with the optical depth scaled by area.
    pub water_ratio: f32,
    /// On its slab's shared corners a segment's optical depth is scaled by the plane
    /// footprint's area over the slab's (the longer or shorter path through a slab seen from
    /// the new eye), by at most this factor either way (at most 1: not scaled; see
    /// `footprints::drawn_color`). Measured (`docs/results.md`, "Watertight slabs").
    pub opacity_limit: f32,
    /// Close the cracks a warp opens between footprints on the drawn image (`cracks`:
    /// [`crate::layered::close_cracks`]); never at the frame's own camera.
    pub close_cracks: bool,
}

impl LayerOptions {
    /// The defaults (chosen by measurement, `docs/results.md`, layered samples).
    pub const DEFAULT: LayerOptions = LayerOptions {
        own: 0.5 + OWN_MARGIN,
        fill: true,
        grow_per_degree: 0.08,
        grow_from_deg: 1.0,
        grow_min_alpha: 230,
        max_own: MAX_OWN,
        watertight: WATERTIGHT,
        water_ratio: 0.5,
        opacity_limit: 4.0,
        close_cracks: true,
    };

    /// Whether at the frame's own camera every footprint is exactly its source pixel (half
    /// side 0.5, the default): then the frame's own image is its samples grouped by pixel
    /// (`OwnPass`), with wider or narrower footprints it must be drawn.
    pub fn own_pixels(&self) -> bool {
        self.own == 0.5
    }

    /// Whether the newest frame's slabs are watertight: a tolerance, and footprints of the
    /// source pixel's size (what the shared corners are corners of).
    pub fn shares_corners(&self) -> bool {
        self.watertight > 0.0 && self.own_pixels()
    }

    /// The half side of the footprints of a frame rendered for `frame` drawn for `camera`:
    /// [`LayerOptions::grown`] with `adaptive` sizing on, else [`LayerOptions::own`].
    pub fn half_side(&self, adaptive: bool, frame: &Camera, camera: &Camera) -> f32 {
        if adaptive {
            self.grown(frame, camera)
        } else {
            self.own
        }
    }

    /// The half side of the footprints of a frame rendered for `frame` drawn for `camera`
    /// (adaptive sizing on): [`LayerOptions::own_at`] the warp's degrees (core's
    /// `warp_radius::warp_angle_deg`) over [`source_pixel_scale`]. The growth per degree is in
    /// the display's pixels: a frame on the coarser grid of adaptive resolution, whose pixel
    /// spans two of the display's, grows half as many of its own pixels (growing as many blurred
    /// its small warps: the 512² sessions' pooled mean was 5–7 % higher, `docs/results.md`, "The
    /// layered levers"). Full-resolution frames grow as before.
    pub fn grown(&self, frame: &Camera, camera: &Camera) -> f32 {
        self.own_at(warp_angle_deg(frame, camera) / source_pixel_scale(frame, camera))
    }

    /// The half side of the footprint for a warp of `deg` degrees (adaptive sizing on), in
    /// source pixels: [`LayerOptions::own`] up to [`LayerOptions::grow_from_deg`], then
    /// [`LayerOptions::grow_per_degree`] more per degree, up to [`LayerOptions::max_own`].
    pub fn own_at(&self, deg: f32) -> f32 {
        let grow = if self.grow_per_degree.is_finite() { self.grow_per_degree.max(0.0) } else { 0.0 };
        let from = if self.grow_from_deg.is_finite() { self.grow_from_deg.max(0.0) } else { 0.0 };
        let cap = if self.max_own.is_finite() { self.max_own.min(4.0) } else { MAX_OWN };
        let beyond = (deg - from).max(0.0);
        (self.own + grow * beyond).min(cap.max(self.own))
    }
}

/// How many of `camera`'s pixels one pixel of `frame` spans: the ratio of their pixels'
/// angular sizes, at least 1 (2 for a frame on the half-resolution grid of adaptive
/// resolution; 1 for a full-resolution frame, with or without a guard band).
pub fn source_pixel_scale(frame: &Camera, camera: &Camera) -> f32 {
    let pitch = |c: &Camera| (c.fov_y_deg.to_radians() * 0.5).tan() / c.height.max(1) as f32;
    let s = pitch(frame) / pitch(camera);
    if s.is_finite() {
        s.max(1.0)
    } else {
        1.0
    }
}

impl Default for LayerOptions {
    fn default() -> Self {
        LayerOptions::DEFAULT
    }
}
