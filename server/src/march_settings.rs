//! What both marching kernels march with: the options ([`MarchOptions`]) and the settings a
//! kernel reads of a marcher, with a ray's samples in the volume box (`MarchSetup`). The
//! scalar marcher ([`crate::marcher`]) and the packet marcher ([`crate::packet_march`]) both
//! import this module, so neither imports the other's types.

use crate::empty_space::Occupancy;
use crate::radius::{RadiusModel, UncertaintyParams};
use crate::volume::Volume;
use volwarp_core::Vec3;

/// Which implementation marches the rays; both give the same colors and depths bit for bit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MarchKernel {
    /// A block of 16 to 64 pixels' rays at once in SIMD lanes ([`crate::packet_march`]); the
    /// default.
    #[default]
    Packet,
    /// One ray at a time ([`crate::marcher::Marcher::march_ray`]): the reference the packet marcher is
    /// tested against.
    Scalar,
}

/// Radius code every sample of a frame gets under [`RadiusModel::Voxel`] (the frame's
/// `radius_unit` is `radius / this`).
pub const RADIUS_CODE: f32 = 512.0;

/// Marcher settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MarchOptions {
    /// Step in voxels (of the smallest spacing); default 0.5.
    pub step_voxels: f32,
    /// Accumulated opacity at which a ray stops; default 0.99 (1 or more disables it).
    pub early_termination: f32,
    /// Skip bricks the transfer function makes invisible; default true.
    pub skip_empty: bool,
    /// How each sample's sphere radius is chosen; default the pixel footprint.
    pub radius: RadiusModel,
    /// The constants of [`RadiusModel::Uncertainty`] (ignored by the other models).
    pub uncertainty: UncertaintyParams,
    /// Packet (SIMD) or scalar marching; default [`MarchKernel::Packet`].
    pub kernel: MarchKernel,
}

impl Default for MarchOptions {
    fn default() -> Self {
        MarchOptions {
            step_voxels: 0.5,
            early_termination: 0.99,
            skip_empty: true,
            radius: RadiusModel::Footprint,
            uncertainty: UncertaintyParams::DEFAULT,
            kernel: MarchKernel::Packet,
        }
    }
}

/// The ray's parameter interval inside the box `[0, ext]`, or `None` if it misses.
#[inline]
fn clip(o: Vec3, inv_d: Vec3, ext: Vec3) -> Option<(f32, f32)> {
    let t0 = (Vec3::ZERO - o) * inv_d;
    let t1 = (ext - o) * inv_d;
    let tmin = t0.min(t1);
    let tmax = t0.max(t1);
    // NaN (0 · inf on a face) is ignored by max/min of f32.
    let enter = tmin.x.max(tmin.y).max(tmin.z).max(0.0);
    let exit = tmax.x.min(tmax.y).min(tmax.z);
    (enter < exit && exit.is_finite()).then_some((enter, exit))
}

/// The settings the packet kernel reads of a marcher (borrowed from it).
#[derive(Clone, Copy)]
pub(crate) struct MarchSetup<'a> {
    /// The volume marched.
    pub(crate) volume: &'a Volume,
    /// Which bricks the transfer function can make visible.
    pub(crate) occupancy: &'a Occupancy,
    /// The marcher's options.
    pub(crate) opts: MarchOptions,
    /// The step in world units.
    pub(crate) dt: f32,
    /// `1 / spacing`: world to voxel units.
    pub(crate) inv_spacing: Vec3,
}

impl MarchSetup<'_> {
    /// A ray's samples in the volume box at this step: their count `n`, the box entry and exit
    /// (`None` if the ray misses the box); sample `k` lies at `t_enter + (k + ½)·Δt`.
    #[inline(always)]
    pub(crate) fn ray_setup(&self, o: Vec3, d: Vec3) -> (u32, f32, Option<f32>) {
        let Some((t_enter, t_exit)) = clip(o, 1.0 / d, self.volume.extent()) else {
            return (0, 0.0, None);
        };
        let n = ((t_exit - t_enter) / self.dt - 0.5).ceil().max(0.0);
        let n = if n < 1e7 { n as u32 } else { 10_000_000 };
        (n, t_enter, Some(t_exit))
    }
}
