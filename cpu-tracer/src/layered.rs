//! The layered model, renderer-neutral: what the CPU layered splatter
//! ([`crate::layer_splat`]) and the GPU one (`volwarp_gpu_tracer::layer_splat`) both draw from.
//!
//! | module | step |
//! |---|---|
//! | `options` | options, limits and work sizes ([`LayerOptions`], [`LIST`], [`OPAQUE`], [`MAX_FRAMES`]) |
//! | `footprints` | per sample its source pixel's footprint in the new camera and its color as drawn ([`Setup`], [`Proj`], [`drawn_color`]) |
//! | `own_pass` | a frame's samples grouped by source pixel in its own camera |
//! | `slabs` | watertight slabs: the corners neighbouring segments share ([`SlabCorners`]) |
//! | `older` | older frames: what the newest frame did not see ([`OlderSets`], [`Sight`]) |
//! | `cracks` | the cracks a warp opens between footprints, closed on the drawn image ([`close_cracks`]) |
//!
//! The algorithm as a whole is described in [`crate::layer_splat`].

mod cracks;
mod footprints;
mod older;
mod options;
mod own_pass;
mod slabs;

pub use cracks::*;
pub use footprints::*;
pub use older::*;
pub use options::*;
pub(crate) use own_pass::*;
pub use slabs::*;
