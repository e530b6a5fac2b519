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
    /// Gradient shading of every visible sample; default `None` (emission and absorption
    /// only).
    pub shading: Option<Shading>,
}

/// Gradient shading: ambient + diffuse + Blinn–Phong specular of a light fixed to the volume.
///
/// The gradient is taken on the fly by central differences of the normalized, trilinear scalar
/// one voxel either side along each axis ([`crate::volume::Volume::gradient_grid_in`]: the
/// shifted samples share the sample's stencil and fractions, reads clamped to the volume or
/// crop), scaled by `1 / spacing`; no gradient volume is stored. With `n = ∇s / |∇s|` (two-sided),
/// `L` the light direction and `H = normalize(L − d)` the half vector of the ray `d`, a sample's
/// premultiplied color `c` (opacity `α`) becomes
/// `min(c·(ambient + diffuse·|n·L|) + specular·|n·H|^32·α, α)`. Where the gradient is zero the
/// diffuse term is taken as 1 and the specular as 0 (a flat region is not darkened). The
/// diffuse term does not depend on the camera (the light is fixed to the volume), so a warped
/// sample's shading stays right; only the specular term is view-dependent.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shading {
    /// Ambient weight.
    pub ambient: f32,
    /// Diffuse weight.
    pub diffuse: f32,
    /// Specular weight (0: no specular term).
    pub specular: f32,
    /// Unit vector toward the light, in volume (world) coordinates.
    pub light: Vec3,
}

impl Shading {
    /// The default: ambient 0.3, diffuse 0.7, specular 0.2, the light above and in front of the
    /// default camera's side of the volume (`+y`, `+z`, slightly `+x`).
    pub const DEFAULT: Shading = Shading {
        ambient: 0.3,
        diffuse: 0.7,
        specular: 0.2,
        // normalize(0.3, 1.0, 0.6)
        light: Vec3::new(0.249_136_4, 0.830_454_6, 0.498_272_8),
    };

    /// The Blinn–Phong half vector of a ray along unit `d`: `normalize(light − d)` (`light`
    /// where that is zero). Both marchers take it from here, once per ray.
    #[inline(always)]
    pub fn half_vector(&self, d: Vec3) -> Vec3 {
        let h = Vec3::new(self.light.x - d.x, self.light.y - d.y, self.light.z - d.z);
        let l = (h.x * h.x + h.y * h.y + h.z * h.z).sqrt();
        if l > 0.0 {
            Vec3::new(h.x / l, h.y / l, h.z / l)
        } else {
            self.light
        }
    }

    /// The shaded premultiplied color of a sample of premultiplied `(cr, cg, cb)` and opacity
    /// `ca`, gradient `(gx, gy, gz)` (world units) and half vector `h` (see the type docs). The
    /// scalar marcher's definition; the packet marcher computes the same operations in lanes.
    #[inline(always)]
    pub fn shade(&self, [gx, gy, gz]: [f32; 3], h: Vec3, [cr, cg, cb, ca]: [f32; 4]) -> [f32; 4] {
        let g2 = gx * gx + gy * gy + gz * gz;
        let len = g2.sqrt();
        let l = self.light;
        let ndl = gx * l.x + gy * l.y + gz * l.z;
        let ndh = gx * h.x + gy * h.y + gz * h.z;
        // One division for both terms.
        let inv = 1.0 / len;
        let (diff, spec) = if g2 > 0.0 { (ndl.max(0.0 - ndl) * inv, ndh.max(0.0 - ndh) * inv) } else { (1.0, 0.0) };
        let s2 = spec * spec;
        let s4 = s2 * s2;
        let s8 = s4 * s4;
        let s16 = s8 * s8;
        let s32 = s16 * s16;
        let f = self.ambient + self.diffuse * diff;
        let sa = self.specular * s32 * ca;
        [(cr * f + sa).min(ca), (cg * f + sa).min(ca), (cb * f + sa).min(ca), ca]
    }
}

/// Where the marcher looks: the crop box and the clip plane, in world units (see
/// [`crate::visual`]). Rays are clipped to the crop box and the plane's kept half-space; samples
/// (and the gradient's neighbours) are clamped to the crop box's voxels, so a crop of whole
/// voxels renders as the volume cut to those voxels in memory would.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cut {
    /// The crop box's low corner (world units; `0` for the whole volume).
    pub lo: Vec3,
    /// The crop box's high corner (world units; the volume's extent for the whole volume).
    pub hi: Vec3,
    /// The clip plane: a point on it and its unit normal; the half-space the normal points
    /// into, `(p − point)·normal ≥ 0`, is kept.
    pub plane: Option<(Vec3, Vec3)>,
    /// The lowest continuous voxel coordinate a sample reads (set by [`Cut::for_volume`]).
    grid_lo: Vec3,
    /// The highest continuous voxel coordinate a sample reads (set by [`Cut::for_volume`]).
    grid_hi: Vec3,
}

impl Cut {
    /// A crop box `[lo, hi]` (world units) and an optional clip plane `(point, unit normal)`.
    pub fn new(lo: Vec3, hi: Vec3, plane: Option<(Vec3, Vec3)>) -> Cut {
        Cut { lo, hi, plane, grid_lo: Vec3::ZERO, grid_hi: Vec3::ZERO }
    }

    /// No cut: the whole volume of `dims` voxels spanning `[0, extent]`.
    pub fn whole(dims: [u32; 3], extent: Vec3) -> Cut {
        let [nx, ny, nz] = dims;
        Cut {
            lo: Vec3::ZERO,
            hi: extent,
            plane: None,
            grid_lo: Vec3::ZERO,
            grid_hi: Vec3::new((nx - 1) as f32, (ny - 1) as f32, (nz - 1) as f32),
        }
    }

    /// Whether it cuts nothing away from the box `[0, extent]`.
    pub fn is_whole(&self, extent: Vec3) -> bool {
        self.plane.is_none() && self.lo.cmple(Vec3::ZERO).all() && self.hi.cmpge(extent).all()
    }

    /// The cut with its sample range for a volume of `dims` voxels of `spacing`: voxel
    /// coordinates `lo / spacing ..= hi / spacing − 1` (a crop `[i0·s, (i1 + 1)·s]` of whole
    /// voxels reads voxels `i0 ..= i1`; coordinates within 10⁻³ of an integer are snapped to it),
    /// clamped into the volume.
    pub fn for_volume(self, dims: [u32; 3], spacing: Vec3) -> Cut {
        let whole = Cut::whole(dims, spacing);
        let snap = |v: Vec3| {
            let r = v.round();
            Vec3::select((v - r).abs().cmplt(Vec3::splat(1e-3)), r, v)
        };
        let grid_lo = snap(self.lo / spacing).max(whole.grid_lo).min(whole.grid_hi);
        let grid_hi = (snap(self.hi / spacing) - 1.0).max(grid_lo).min(whole.grid_hi);
        Cut { grid_lo, grid_hi, ..self }
    }

    /// The lowest continuous voxel coordinate a sample reads.
    pub fn grid_lo(&self) -> Vec3 {
        self.grid_lo
    }

    /// The highest continuous voxel coordinate a sample reads.
    pub fn grid_hi(&self) -> Vec3 {
        self.grid_hi
    }

    /// The ray's interval inside the crop box and the plane's half-space, or `None`.
    #[inline]
    fn clip(&self, o: Vec3, d: Vec3) -> Option<(f32, f32)> {
        let (mut enter, mut exit) = clip(o, 1.0 / d, self.lo, self.hi)?;
        if let Some((p, n)) = self.plane {
            let s0 = (o.x - p.x) * n.x + (o.y - p.y) * n.y + (o.z - p.z) * n.z;
            let sd = d.x * n.x + d.y * n.y + d.z * n.z;
            if sd > 0.0 {
                enter = enter.max(-s0 / sd);
            } else if sd < 0.0 {
                exit = exit.min(-s0 / sd);
            } else if s0 < 0.0 {
                return None;
            }
            if enter.partial_cmp(&exit) != Some(core::cmp::Ordering::Less) {
                return None;
            }
        }
        Some((enter, exit))
    }
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
            shading: None,
        }
    }
}

/// The ray's parameter interval inside the box `[lo, hi]`, or `None` if it misses.
#[inline]
fn clip(o: Vec3, inv_d: Vec3, lo: Vec3, hi: Vec3) -> Option<(f32, f32)> {
    let t0 = (lo - o) * inv_d;
    let t1 = (hi - o) * inv_d;
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
    /// The crop box and clip plane.
    pub(crate) cut: &'a Cut,
}

impl MarchSetup<'_> {
    /// A ray's samples in the volume box at this step: their count `n`, the box entry and exit
    /// (`None` if the ray misses the box); sample `k` lies at `t_enter + (k + ½)·Δt`.
    #[inline(always)]
    pub(crate) fn ray_setup(&self, o: Vec3, d: Vec3) -> (u32, f32, Option<f32>) {
        let Some((t_enter, t_exit)) = self.cut.clip(o, d) else {
            return (0, 0.0, None);
        };
        let n = ((t_exit - t_enter) / self.dt - 0.5).ceil().max(0.0);
        let n = if n < 1e7 { n as u32 } else { 10_000_000 };
        (n, t_enter, Some(t_exit))
    }
}

/// The next lattice sample index after skipping empty space up to `t_out`: the first `k' ≥ k + 1`
/// with `t_enter + (k' + ½)·dt ≥ t_out`, at most `n` (ceil done by hand: the libm call showed in
/// profiles); NaN or no progress steps by one. The scalar marcher's and the partial march's
/// resume, so both take the same samples.
#[inline]
pub(crate) fn resume_after(t_out: f32, t_enter: f32, dt: f32, k: u32, n: u32) -> u32 {
    let x = (t_out - t_enter) / dt - 0.5;
    if x >= n as f32 {
        n
    } else if x > (k + 1) as f32 {
        let c = x as u32;
        c + u32::from((c as f32) < x)
    } else {
        k + 1
    }
}

/// A part of a volume split across MPI ranks ([`crate::distributed`]) as both kernels march it:
/// rays on the whole volume's sample grid, samples taken only where the part owns the grid
/// position, and read from the part's held block (its first voxel at grid offset `off`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct PartWindow {
    /// The whole volume's box `[0, extent]` (world units): every ray's entry, exit and samples.
    pub(crate) extent: Vec3,
    /// The held block's first voxel, as a grid offset (a sample at grid position `g` reads the
    /// block at `g − off`, an exact subtraction of integers).
    pub(crate) off: Vec3,
    /// The owned grid positions are `own_lo ≤ g < own_hi` per axis (`−∞` / `+∞` at the
    /// volume's outer faces).
    pub(crate) own_lo: Vec3,
    /// See `own_lo`.
    pub(crate) own_hi: Vec3,
    /// The owned box widened by a voxel (world units): where a ray's samples to test lie.
    pub(crate) near_lo: Vec3,
    /// See `near_lo`.
    pub(crate) near_hi: Vec3,
    /// The held block's origin in world units (the empty-space leaps run in the block's own
    /// coordinates).
    pub(crate) origin: Vec3,
    /// The owned box in world units, clipped to the volume box (the whole box `[0, extent]`
    /// for a part that is the whole volume): where a threshold a part does not reach falls
    /// back to.
    pub(crate) own_box_lo: Vec3,
    /// See `own_box_lo`.
    pub(crate) own_box_hi: Vec3,
}

impl PartWindow {
    /// The window of the part owning voxels `[lo, hi)` and holding `[held_lo, ..)` of a volume
    /// of `dims` voxels of `spacing`.
    pub(crate) fn new(dims: [u32; 3], lo: [u32; 3], hi: [u32; 3], held_lo: [u32; 3], spacing: Vec3) -> PartWindow {
        let v = |a: [u32; 3]| Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32);
        let own_lo =
            Vec3::from_array([0, 1, 2].map(|a| if lo[a] == 0 { f32::NEG_INFINITY } else { lo[a] as f32 - 0.5 }));
        let own_hi =
            Vec3::from_array([0, 1, 2].map(|a| if hi[a] == dims[a] { f32::INFINITY } else { hi[a] as f32 - 0.5 }));
        // `1 / (1 / spacing)`: the value the partial march has always used here.
        let sp = 1.0 / (1.0 / spacing);
        let extent = v(dims) * spacing;
        Self {
            extent,
            off: v(held_lo),
            own_lo,
            own_hi,
            near_lo: (v(lo) - 1.0).max(Vec3::ZERO) * sp,
            near_hi: ((v(hi) + 1.0) * sp).min(extent + sp),
            origin: v(held_lo) * sp,
            own_box_lo: Vec3::from_array([0, 1, 2].map(|a| if lo[a] == 0 { 0.0 } else { lo[a] as f32 * spacing[a] })),
            own_box_hi: Vec3::from_array([0, 1, 2].map(|a| {
                if hi[a] == dims[a] {
                    extent[a]
                } else {
                    hi[a] as f32 * spacing[a]
                }
            })),
        }
    }

    /// Whether the part owns grid position `g`.
    #[inline(always)]
    pub(crate) fn owns(&self, g: Vec3) -> bool {
        g.cmpge(self.own_lo).all() && g.cmplt(self.own_hi).all()
    }

    /// A ray's samples on the whole volume's grid at step `dt`: their count `n`, the box
    /// entry and exit (`None` where the ray misses the box), and the index range `[k0, k1)`
    /// (within `0..n`) outside which the part owns none of them.
    #[inline(always)]
    pub(crate) fn ray(&self, o: Vec3, d: Vec3, dt: f32) -> (u32, f32, Option<f32>, u32, u32) {
        let inv_d = 1.0 / d;
        let Some((t_enter, t_exit)) = clip(o, inv_d, Vec3::ZERO, self.extent) else {
            return (0, 0.0, None, 0, 0);
        };
        let n = ((t_exit - t_enter) / dt - 0.5).ceil().max(0.0);
        let n = if n < 1e7 { n as u32 } else { 10_000_000 };
        let Some((t0, t1)) = clip(o, inv_d, self.near_lo, self.near_hi) else {
            return (n, t_enter, Some(t_exit), n, n);
        };
        let k0 = (((t0 - t_enter) / dt - 0.5).floor() - 1.0).max(0.0);
        let k1 = (((t1 - t_enter) / dt - 0.5).ceil() + 2.0).max(0.0);
        let k0 = if k0 < 1e7 { (k0 as u32).min(n) } else { n };
        let k1 = if k1 < 1e7 { (k1 as u32).min(n) } else { n };
        (n, t_enter, Some(t_exit), k0, k1)
    }

    /// Where a ray leaves the part's owned box (the box exit `t_exit` where it misses it; for
    /// a part that is the whole volume, the box exit bit for bit): the depth a threshold-like
    /// heuristic that the part's own samples do not meet falls back to, between the part's
    /// samples and the next part's.
    #[inline(always)]
    pub(crate) fn part_exit(&self, o: Vec3, d: Vec3, t_exit: f32) -> f32 {
        clip(o, 1.0 / d, self.own_box_lo, self.own_box_hi).map_or(t_exit, |(_, x)| x)
    }
}
