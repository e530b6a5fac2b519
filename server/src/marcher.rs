//! The CPU ray marcher: the server's renderer and the ground truth of the evaluation.
//!
//! For each pixel, the primary ray of [`volwarp_core::RayBasis::dir`] is clipped to the volume
//! box (see [`crate::volume`] for where the volume sits) and sampled at
//! `t_k = t_enter + (k + ½)·Δt`, `Δt = step × min(spacing)` (default step ½ voxel). Each sample is
//! trilinear, classified through the transfer function with opacity correction
//! `α' = 1 − (1 − α)^(Δt / min spacing)`, and composited front to back into a premultiplied color.
//! The ray stops once the accumulated opacity reaches the early-termination threshold
//! (default 0.99). Bricks of the [`crate::empty_space`] grid that the transfer function makes
//! invisible are skipped without changing any result.
//!
//! Every sample with non-zero opacity is fed to the requested [`Heuristic`]'s
//! [`DepthPicker`]; the two-pass heuristics march the ray twice (the first pass into a
//! [`FirstPassAccumulator`]). A frame's sample is `p = o + d·t` with radius `radius_scale` ×
//! the [`crate::radius`] model's (by default the pixel's footprint at depth `t`); empty pixels
//! get radius 0 and are compacted away.
//! Work is spread with rayon over bands of image rows.

use crate::compaction;
use crate::empty_space::{MinMaxGrid, Occupancy};
use crate::march_settings::MarchSetup;
pub use crate::march_settings::{Cut, MarchKernel, MarchOptions, Shading, RADIUS_CODE};
#[cfg(doc)]
use crate::radius::RadiusModel;
use crate::radius::{FrameRadius, RaySpread, Uncertainty};
use crate::transfer_function::{TransferFunction, LUT_SIZE};
use crate::volume::Volume;
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;
use volwarp_core::sample::{over_background, pack_color_f32, Quantizer};
use volwarp_core::segments::{pack_colors, Segment, Segmenter, MAX_LAYERS};
use volwarp_core::wire::{CameraRequest, Frame, FrameHeader};
use volwarp_core::{Camera, DepthPicker, FirstPassAccumulator, Heuristic, Image, Vec3, BACKGROUND};

/// The stop flag of a render that runs to its end (never set).
pub(crate) static NEVER: AtomicBool = AtomicBool::new(false);

/// Rows per parallel task (a multiple of the packet marcher's packet height).
const BAND_ROWS: usize = 8;

/// The uncompacted result of marching every pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct PixelBuffer {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Representative depth per pixel (ray parameter along the unit ray); `f32::INFINITY` for
    /// an empty pixel.
    pub t: Vec<f32>,
    /// Composited premultiplied RGBA8 per pixel (packed like sample colors).
    pub color: Vec<u32>,
}

impl PixelBuffer {
    /// Number of non-empty pixels.
    pub fn nonempty(&self) -> usize {
        self.t.iter().filter(|t| t.is_finite()).count()
    }
}

/// The uncompacted result of a layered march.
#[derive(Clone, Debug, PartialEq)]
pub struct LayerBuffer {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Slots per pixel (the most segments a pixel may have).
    pub layers: u32,
    /// Segments per pixel.
    pub count: Vec<u8>,
    /// Depth of segment `j` of pixel `i` at `i · layers + j` (`f32::INFINITY` in unused slots).
    pub t: Vec<f32>,
    /// Premultiplied RGBA8 of each segment, slots as `t`.
    pub color: Vec<u32>,
    /// Packed samples, slots as `t` (empty unless the march packed them).
    pub packed: Vec<u64>,
}

impl LayerBuffer {
    /// Pixel `i`'s segments as `(t, color)`, front to back.
    pub fn pixel(&self, i: usize) -> impl Iterator<Item = (f32, u32)> + '_ {
        let k = self.layers as usize;
        (0..self.count[i] as usize).map(move |j| (self.t[i * k + j], self.color[i * k + j]))
    }
}

/// Timings and counts of one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameStats {
    /// Ray marching, µs.
    pub march_us: u64,
    /// Parallel compaction, µs (positions are quantized during the march).
    pub compact_us: u64,
    /// Samples in the frame (non-empty pixels).
    pub samples: usize,
    /// Pixels of the viewport.
    pub pixels: usize,
}

/// The ray marcher over one volume and transfer function.
#[derive(Clone, Debug)]
pub struct Marcher {
    volume: Arc<Volume>,
    grid: Arc<MinMaxGrid>,
    occupancy: Occupancy,
    /// Opacity-corrected, premultiplied table.
    lut: Vec<[f32; 4]>,
    /// The same table as (a, r, g, b) entries, one after another, for the packet marcher's
    /// 64-bit gathers (opacity with red, green with blue).
    lut_argb: Arc<Vec<f32>>,
    /// [`Occupancy::look_table`], for the packet marcher's gathers.
    looks: Arc<Vec<f32>>,
    opts: MarchOptions,
    dt: f32,
    inv_spacing: Vec3,
    /// The level of detail its volume is (0: the volume itself; see
    /// [`crate::volume::pyramid`]), written into every frame header.
    level: u8,
    /// The thickness (world units) whose opacity the transfer function gives: a voxel of the
    /// smallest spacing of the volume itself, at every level of detail (so a coarser level is
    /// as opaque as the volume, not 2^level times as transparent).
    opacity_unit: f32,
    /// The crop box and clip plane (the whole volume unless [`Marcher::with_cut`]).
    cut: Cut,
    /// The transfer function the table was made of (the empty-space grid's occupancy is
    /// remade from it under a crop).
    tf: TransferFunction,
}

/// The empty-space occupancy of `grid` under `tf`, with the bricks outside `cut`'s voxels (and
/// the one voxel around them a trilinear stencil reaches) invisible too, so rays leap over them.
fn cut_occupancy(grid: &MinMaxGrid, tf: &TransferFunction, sp: Vec3, cut: &Cut, extent: Vec3) -> Occupancy {
    if cut.is_whole(extent) {
        return grid.occupancy(tf, sp);
    }
    let e = grid.brick() as f32;
    let (lo, hi) = ((cut.grid_lo() - 1.0).floor(), (cut.grid_hi() + 2.0).ceil());
    grid.occupancy_within(tf, sp, |b| {
        let b = Vec3::new(b[0] as f32, b[1] as f32, b[2] as f32);
        (b * e).cmple(hi).all() && ((b + 1.0) * e).cmpge(lo).all()
    })
}

impl Marcher {
    /// A marcher with default options.
    pub fn new(volume: Arc<Volume>, tf: &TransferFunction) -> Marcher {
        Marcher::with_options(volume, tf, MarchOptions::default())
    }

    /// A marcher of a [`crate::dataset::Dataset`] with default options.
    pub fn from_dataset(ds: &crate::dataset::Dataset) -> Marcher {
        Marcher::new(ds.volume.clone(), &ds.tf)
    }

    /// A marcher with options (a step below 0.01 voxel or non-finite is raised to 0.01).
    pub fn with_options(volume: Arc<Volume>, tf: &TransferFunction, opts: MarchOptions) -> Marcher {
        let grid = Arc::new(MinMaxGrid::new(&volume));
        Marcher::with_grid(volume, grid, tf, opts)
    }

    /// A marcher skipping empty space with `grid` (the volume's, e.g. [`MinMaxGrid::with_brick`]
    /// for another brick edge than [`MinMaxGrid::new`] picks).
    pub fn with_grid(volume: Arc<Volume>, grid: Arc<MinMaxGrid>, tf: &TransferFunction, opts: MarchOptions) -> Marcher {
        Marcher::with_grid_unit(volume, grid, tf, opts, None, None)
    }

    /// [`Marcher::with_grid`] whose transfer function's opacities are those of a slab
    /// `opacity_unit` world units thick (`None`: one voxel of the smallest spacing, the
    /// convention of the transfer functions; a coarser level of detail keeps its volume's),
    /// cropped and clipped by `cut` (world units, see [`Marcher::with_cut`]; `None`: the whole
    /// volume).
    fn with_grid_unit(
        volume: Arc<Volume>,
        grid: Arc<MinMaxGrid>,
        tf: &TransferFunction,
        mut opts: MarchOptions,
        opacity_unit: Option<f32>,
        cut: Option<Cut>,
    ) -> Marcher {
        if opts.step_voxels.is_nan() || opts.step_voxels < 0.01 {
            opts.step_voxels = 0.01;
        }
        opts.step_voxels = opts.step_voxels.min(16.0);
        let sp = volume.spacing();
        let dt = opts.step_voxels * sp.min_element();
        let opacity_unit = opacity_unit.unwrap_or(sp.min_element());
        // The step in opacity units (`opts.step_voxels` itself for the volume's own voxels).
        let steps = if opacity_unit == sp.min_element() { opts.step_voxels } else { dt / opacity_unit };
        let lut = tf
            .table()
            .iter()
            .map(|&[r, g, b, a]| {
                let a = 1.0 - (1.0 - a.clamp(0.0, 1.0)).powf(steps);
                [r * a, g * a, b * a, a]
            })
            .collect::<Vec<_>>();
        debug_assert_eq!(lut.len(), LUT_SIZE);
        let cut = match cut {
            Some(c) => c.for_volume(volume.dims(), sp),
            None => Cut::whole(volume.dims(), volume.extent()),
        };
        let occupancy = cut_occupancy(&grid, tf, sp, &cut, volume.extent());
        log::debug!("empty-space grid: {:.1} % of bricks visible", occupancy.fraction_occupied() * 100.0);
        let lut_argb = Arc::new(lut.iter().flat_map(|&[r, g, b, a]| [a, r, g, b]).collect::<Vec<f32>>());
        let looks = Arc::new(occupancy.look_table());
        Marcher {
            volume,
            grid,
            occupancy,
            lut,
            lut_argb,
            looks,
            opts,
            dt,
            inv_spacing: 1.0 / sp,
            level: 0,
            opacity_unit,
            cut,
            tf: tf.clone(),
        }
    }

    /// The marcher with its frames marked as coming from level of detail `level` (its volume
    /// downsampled `2^level` times per axis, [`crate::volume::pyramid`]).
    pub fn at_level(mut self, level: u8) -> Marcher {
        self.level = level;
        self
    }

    /// The level of detail its frames are marked with.
    pub fn level(&self) -> u8 {
        self.level
    }

    /// Marchers of the levels of detail of this marcher's volume with `tf` and this marcher's
    /// options: this volume first, then coarser copies ([`crate::volume::pyramid`]) down to 16
    /// voxels on the largest axis (at most 9 levels). Logs the levels, their memory and the time
    /// taken.
    pub fn levels(&self, tf: &TransferFunction) -> Result<Vec<Arc<Marcher>>, crate::volume::VolumeError> {
        let t = std::time::Instant::now();
        // The levels take about a seventh of the volume's bricks: refused before building where
        // the memory there is cannot hold them.
        crate::volume::MemoryLimit::Available.check(self.volume.memory_bytes() / 7)?;
        let volumes = crate::volume::pyramid::pyramid(self.volume.clone(), 16, 9)?;
        let extra: u64 = volumes[1..].iter().map(|v| v.memory_bytes()).sum();
        let mut out = vec![Arc::new(self.clone())];
        for (l, v) in volumes.into_iter().enumerate().skip(1) {
            let grid = Arc::new(MinMaxGrid::new(&v));
            let m = Marcher::with_grid_unit(v, grid, tf, self.opts, Some(self.opacity_unit), None);
            let m = if self.cut.is_whole(self.volume.extent()) { m } else { m.with_cut(self.cut) };
            out.push(Arc::new(m.at_level(l as u8)));
        }
        log::info!(
            "levels of detail: {} ({}), +{:.1} MiB ({:.1} % of the volume), built in {:.2} s",
            out.len(),
            out.iter().map(|m| format!("{:?}", m.volume.dims())).collect::<Vec<_>>().join(", "),
            extra as f64 / (1u64 << 20) as f64,
            extra as f64 * 100.0 / self.volume.memory_bytes().max(1) as f64,
            t.elapsed().as_secs_f64()
        );
        Ok(out)
    }

    /// The same volume and grid with another transfer function or options (no rebuild of the
    /// min/max grid).
    pub fn with_transfer_function(&self, tf: &TransferFunction, opts: MarchOptions) -> Marcher {
        let cut = (!self.cut.is_whole(self.volume.extent())).then_some(self.cut);
        Marcher::with_grid_unit(self.volume.clone(), self.grid.clone(), tf, opts, Some(self.opacity_unit), cut)
            .at_level(self.level)
    }

    /// The marcher cropped and clipped by `cut` (world units, see [`Cut`]; its voxel range is
    /// clamped into this marcher's volume).
    ///
    /// Bricks of the empty-space grid outside the crop box's voxels (and the one voxel around
    /// them a trilinear stencil reaches) count as empty, so rays leap over them.
    pub fn with_cut(mut self, cut: Cut) -> Marcher {
        let sp = self.volume.spacing();
        self.cut = cut.for_volume(self.volume.dims(), sp);
        self.occupancy = cut_occupancy(&self.grid, &self.tf, sp, &self.cut, self.volume.extent());
        self.looks = Arc::new(self.occupancy.look_table());
        self
    }

    /// This marcher's volume and grid showing `state` over `base`, the transfer function given at
    /// start (see [`crate::visual`]): the transfer-function tables and the empty-space
    /// occupancy are rebuilt, the volume and its min/max grid are shared. A bad state is an
    /// error naming what is wrong.
    pub fn with_visual(
        &self,
        base: &TransferFunction,
        state: &crate::visual::VisualState,
    ) -> Result<Marcher, crate::visual::VisualError> {
        let tf = state.transfer_function(base, self.volume.value_range())?;
        Ok(self.with_visual_tf(&tf, state))
    }

    /// [`Marcher::with_visual`] with the state's transfer function already made (`tf`, from
    /// [`crate::visual::VisualState::transfer_function`]; the levels of detail share the one of
    /// the volume itself): its tables and the empty-space occupancy are built, the volume and
    /// its min/max grid are shared.
    pub fn with_visual_tf(&self, tf: &TransferFunction, state: &crate::visual::VisualState) -> Marcher {
        let opts = MarchOptions { shading: state.shade.then_some(Shading::DEFAULT), ..self.opts };
        let cut = state.cut(&self.volume);
        let cut = (!cut.is_whole(self.volume.extent())).then_some(cut);
        Marcher::with_grid_unit(self.volume.clone(), self.grid.clone(), tf, opts, Some(self.opacity_unit), cut)
            .at_level(self.level)
    }

    /// This marcher with `state`'s shading and cut and its own transfer-function tables (for a
    /// state whose function is this marcher's, [`crate::visual::VisualState::same_function`]):
    /// only the empty-space occupancy is made again, and only where the cut changes.
    pub fn with_visual_cut(&self, state: &crate::visual::VisualState) -> Marcher {
        let mut m = self.clone();
        m.opts.shading = state.shade.then_some(Shading::DEFAULT);
        let cut = state.cut(&self.volume).for_volume(self.volume.dims(), self.volume.spacing());
        if cut == self.cut {
            return m;
        }
        m.with_cut(cut)
    }

    /// The transfer function its tables were made of.
    pub fn transfer_function(&self) -> &TransferFunction {
        &self.tf
    }

    /// The crop box and clip plane in use.
    pub fn cut(&self) -> &Cut {
        &self.cut
    }

    /// The volume.
    pub fn volume(&self) -> &Volume {
        &self.volume
    }

    /// The opacity-corrected, premultiplied table the scalar kernel classifies with (what a
    /// part of a distributed volume marches with, [`crate::distributed`]).
    pub(crate) fn lut_table(&self) -> &[[f32; 4]] {
        &self.lut
    }

    /// The options in use.
    pub fn options(&self) -> MarchOptions {
        self.opts
    }

    /// The step in world units.
    pub fn step(&self) -> f32 {
        self.dt
    }

    /// Which bricks the transfer function can make visible.
    pub fn occupancy(&self) -> &Occupancy {
        &self.occupancy
    }

    /// A ray's samples: their count `n`, the box entry and exit (`None` if the ray misses the
    /// box); sample `k` lies at `t_enter + (k + ½)·Δt`.
    #[inline(always)]
    pub(crate) fn ray_setup(&self, o: Vec3, d: Vec3) -> (u32, f32, Option<f32>) {
        self.setup().ray_setup(o, d)
    }

    /// What the packet kernel reads of this marcher.
    fn setup(&self) -> MarchSetup<'_> {
        MarchSetup {
            volume: &self.volume,
            occupancy: &self.occupancy,
            opts: self.opts,
            dt: self.dt,
            inv_spacing: self.inv_spacing,
            cut: &self.cut,
        }
    }

    fn kernel(&self) -> crate::packet_march::Kernel<'_> {
        crate::packet_march::Kernel {
            m: self.setup(),
            voxels: self.volume.voxels(),
            lut: &self.lut_argb,
            looks: &self.looks,
            part: None,
        }
    }

    /// The packet kernel marching this marcher's volume as the held block of a part of a larger
    /// volume (`part`; what [`crate::distributed::partial`] marches with).
    pub(crate) fn part_kernel<'a>(
        &'a self,
        part: &'a crate::march_settings::PartWindow,
    ) -> crate::packet_march::Kernel<'a> {
        crate::packet_march::Kernel { part: Some(part), ..self.kernel() }
    }

    /// The samples the rays of `cam` have in the volume box (what a march without skipping or
    /// early termination takes).
    pub fn box_samples(&self, cam: &Camera) -> u64 {
        let basis = cam.ray_basis();
        let mut n = 0u64;
        for y in 0..cam.height {
            for x in 0..cam.width {
                n += u64::from(self.ray_setup(cam.eye, basis.dir(x, y)).0);
            }
        }
        n
    }

    /// Radius of a sample at `radius_scale` 1 under [`RadiusModel::Voxel`]: half a voxel
    /// diagonal.
    pub fn default_radius(&self) -> f32 {
        0.5 * self.volume.voxel_diagonal()
    }

    /// A camera framing the whole volume box from the front (`-z` view, `+y` up), 30° field of
    /// view, orbited by `yaw`/`pitch` degrees.
    pub fn default_camera(&self, width: u32, height: u32) -> Camera {
        default_camera(&self.volume, width, height)
    }

    /// Marches one ray from `o` along unit `d`, feeding every sample with non-zero opacity as
    /// `(t, src_a, dst_a)`; returns the premultiplied color and the box exit `t` (`None` if the
    /// ray misses the box).
    #[inline]
    pub fn march_ray(&self, o: Vec3, d: Vec3, mut feed: impl FnMut(f32, f32, f32)) -> ([f32; 4], Option<f32>) {
        self.march_ray_rgba(o, d, |t, sa, dst| feed(t, sa, dst[3]))
    }

    /// [`Marcher::march_ray`] feeding `(t, src_a, dst)` with the whole accumulated
    /// premultiplied color `dst` after the sample (what [`Segmenter`] needs).
    #[inline]
    pub fn march_ray_rgba(
        &self,
        o: Vec3,
        d: Vec3,
        mut feed: impl FnMut(f32, f32, [f32; 4]),
    ) -> ([f32; 4], Option<f32>) {
        let vol = &*self.volume;
        let inv_d = 1.0 / d;
        let (n, t_enter, Some(t_exit)) = self.ray_setup(o, d) else {
            return ([0.0; 4], None);
        };
        let dt = self.dt;
        let og = o * self.inv_spacing - 0.5;
        let dg = d * self.inv_spacing;
        let ert = self.opts.early_termination;
        let (mut r, mut g, mut b, mut a) = (0.0f32, 0.0f32, 0.0f32, 0.0f32);
        let skip = self.opts.skip_empty;
        let occ = &self.occupancy;
        let (glo, ghi) = (self.cut.grid_lo(), self.cut.grid_hi());
        let shading = self.opts.shading;
        let half = shading.map_or(Vec3::ZERO, |s| s.half_vector(d));
        let isp = self.inv_spacing;
        // Samples before `t_check` lie in a brick already found visible: no need to look again.
        // (A sample a rounding error past that brick's face may then be sampled needlessly; that
        // is harmless, skipping is the only thing that must be exact.)
        let mut t_check = f32::NEG_INFINITY;
        let mut k = 0u32;
        while k < n {
            let t = t_enter + (k as f32 + 0.5) * dt;
            let gp = og + dg * t;
            if skip && t >= t_check {
                let br = occ.brick_of(gp);
                let (r, reach) = occ.look(br);
                let t_out = occ.leap_exit_t(br, reach, o, inv_d);
                if r > 0 {
                    // Resume at the first lattice sample at or after t_out (ceil, done by hand:
                    // the libm call showed in profiles); NaN or no progress steps by one.
                    k = crate::march_settings::resume_after(t_out, t_enter, dt, k, n);
                    continue;
                }
                t_check = t_out;
            }
            let v = vol.sample_grid_in(gp, glo, ghi);
            let [cr, cg, cb, ca] = self.lut[TransferFunction::index(v)];
            if ca > 0.0 {
                let [cr, cg, cb, ca] = match &shading {
                    None => [cr, cg, cb, ca],
                    Some(sh) => {
                        let d = vol.gradient_grid_in(gp, glo, ghi);
                        sh.shade([d.x * isp.x, d.y * isp.y, d.z * isp.z], half, [cr, cg, cb, ca])
                    }
                };
                let w = 1.0 - a;
                r += w * cr;
                g += w * cg;
                b += w * cb;
                a += w * ca;
                feed(t, ca, [r, g, b, a]);
                if a >= ert {
                    break;
                }
            }
            k += 1;
        }
        ([r, g, b, a], Some(t_exit))
    }

    /// The color and representative depth of one ray (`None` for an empty ray).
    #[inline]
    pub fn pixel(&self, o: Vec3, d: Vec3, heuristic: Heuristic) -> ([f32; 4], Option<f32>) {
        let first = heuristic.needs_first_pass().then(|| {
            let mut acc = FirstPassAccumulator::new();
            self.march_ray(o, d, |_, sa, da| acc.feed(sa, da));
            acc.finish()
        });
        let mut picker = DepthPicker::new(heuristic, first);
        let (c, t_exit) = self.march_ray(o, d, |t, sa, da| picker.feed(t, sa, da));
        let t = t_exit.and_then(|te| picker.finish(te));
        (c, t)
    }

    /// [`Marcher::pixel`] and the ray's [`Uncertainty`] (what [`RadiusModel::Uncertainty`]
    /// sizes the sample by), collected over the samples the depth picker sees.
    pub fn pixel_spread(&self, o: Vec3, d: Vec3, heuristic: Heuristic) -> ([f32; 4], Option<f32>, Uncertainty) {
        let first = heuristic.needs_first_pass().then(|| {
            let mut acc = FirstPassAccumulator::new();
            self.march_ray(o, d, |_, sa, da| acc.feed(sa, da));
            acc.finish()
        });
        let mut picker = DepthPicker::new(heuristic, first);
        let mut spread = RaySpread::new();
        let (c, t_exit) = self.march_ray(o, d, |t, sa, da| {
            picker.feed(t, sa, da);
            spread.feed(t, da);
        });
        let t = t_exit.and_then(|te| picker.finish(te));
        (c, t, spread.finish())
    }

    /// One ray's layered samples: at most `layers` segments, front to back (the
    /// scalar reference of the packet marcher's layered path).
    pub fn segments(&self, o: Vec3, d: Vec3, layers: u32) -> Vec<Segment> {
        self.segments_and_color(o, d, layers).0
    }

    /// [`Marcher::segments`] and the ray's composited premultiplied color.
    fn segments_and_color(&self, o: Vec3, d: Vec3, layers: u32) -> (Vec<Segment>, [f32; 4]) {
        let mut seg = Segmenter::new(layers, self.dt);
        let (c, exit) = self.march_ray_rgba(o, d, |t, _, dst| seg.feed(t, dst));
        if exit.is_none() {
            return (Vec::new(), c);
        }
        (seg.finish().to_vec(), c)
    }

    /// Marches every pixel of `camera` into at most `layers` segments each (parallel over row
    /// bands, the options' kernel).
    pub fn march_layers(&self, camera: &Camera, layers: u32) -> LayerBuffer {
        self.march_layers_impl(camera, layers, None, &NEVER)
    }

    /// The march of every pixel into at most `layers` segments; once `stop` is set the row bands
    /// not yet started are left empty.
    fn march_layers_impl(
        &self,
        camera: &Camera,
        layers: u32,
        pack: Option<(&Quantizer, FrameRadius)>,
        stop: &AtomicBool,
    ) -> LayerBuffer {
        let k = layers.clamp(1, MAX_LAYERS as u32) as usize;
        let (w, h) = (camera.width as usize, camera.height as usize);
        let basis = camera.ray_basis();
        let o = basis.origin();
        let mut count = vec![0u8; w * h];
        let mut t = vec![f32::INFINITY; w * h * k];
        let mut color = vec![0u32; w * h * k];
        let mut packed = if pack.is_some() { vec![0u64; w * h * k] } else { Vec::new() };
        let band = w.max(1) * BAND_ROWS;
        let mut packed_bands: Vec<&mut [u64]> =
            if pack.is_some() { packed.chunks_mut(band * k).collect() } else { Vec::new() };
        packed_bands.resize_with(count.len().div_ceil(band), || &mut []);
        let kernel = self.kernel();
        count
            .par_chunks_mut(band)
            .zip(t.par_chunks_mut(band * k))
            .zip(color.par_chunks_mut(band * k))
            .zip(packed_bands.into_par_iter())
            .enumerate()
            .for_each(|(b, (((cb, tb), colb), sb))| {
                if stop.load(Ordering::Relaxed) {
                    return;
                }
                if self.opts.kernel == MarchKernel::Packet {
                    let y0 = (b * BAND_ROWS) as u32;
                    let mut out =
                        crate::packet_march::LayerOut { layers: k, count: cb, t: tb, color: colb, packed: sb };
                    crate::packet_march::march_band_layers(&kernel, &basis, pack, y0, &mut out);
                    return;
                }
                for (i, c) in cb.iter_mut().enumerate() {
                    let (x, y) = ((i % w) as u32, (b * BAND_ROWS + i / w) as u32);
                    let d = basis.dir(x, y);
                    let (segs, ray) = self.segments_and_color(o, d, k as u32);
                    *c = segs.len() as u8;
                    pack_colors(&segs, ray, &mut colb[i * k..i * k + segs.len()]);
                    for (j, sg) in segs.iter().enumerate() {
                        tb[i * k + j] = sg.t;
                        if let (Some((q, radius)), Some(s)) = (pack, sb.get_mut(i * k + j)) {
                            *s = q.pack(o + d * sg.t, radius.at(d, sg.t));
                        }
                    }
                }
            });
        LayerBuffer { width: camera.width, height: camera.height, layers: k as u32, count, t, color, packed }
    }

    /// Marches every pixel of `camera` with `heuristic` (parallel over row bands).
    pub fn march(&self, camera: &Camera, heuristic: Heuristic) -> PixelBuffer {
        self.march_impl(camera, heuristic, None, &NEVER).0
    }

    /// Marches every pixel and, with `pack`, also packs each non-empty pixel's sample (the same
    /// values as [`Marcher::quantize`], computed while the ray direction is at hand); once
    /// `stop` is set the row bands not yet started are left empty.
    fn march_impl(
        &self,
        camera: &Camera,
        heuristic: Heuristic,
        pack: Option<(&Quantizer, FrameRadius)>,
        stop: &AtomicBool,
    ) -> (PixelBuffer, Vec<u64>) {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let basis = camera.ray_basis();
        let o = basis.origin();
        let mut t = vec![f32::INFINITY; w * h];
        let mut color = vec![0u32; w * h];
        let mut packed = if pack.is_some() { vec![0u64; w * h] } else { Vec::new() };
        let band = w.max(1) * BAND_ROWS;
        let mut packed_bands: Vec<&mut [u64]> =
            if pack.is_some() { packed.chunks_mut(band).collect() } else { Vec::new() };
        packed_bands.resize_with(t.len().div_ceil(band), || &mut []);
        let kernel = self.kernel();
        t.par_chunks_mut(band).zip(color.par_chunks_mut(band)).zip(packed_bands.into_par_iter()).enumerate().for_each(
            |(b, ((tb, cb), sb))| {
                if stop.load(Ordering::Relaxed) {
                    return;
                }
                if self.opts.kernel == MarchKernel::Packet {
                    let y0 = (b * BAND_ROWS) as u32;
                    crate::packet_march::march_band(&kernel, &basis, Some(heuristic), pack, y0, tb, cb, sb);
                    return;
                }
                let spread = pack.is_some_and(|(_, r)| r.uses_spread());
                for (i, (tp, cp)) in tb.iter_mut().zip(cb.iter_mut()).enumerate() {
                    let (x, y) = ((i % w) as u32, (b * BAND_ROWS + i / w) as u32);
                    let d = basis.dir(x, y);
                    let (c, depth, u) = if spread {
                        self.pixel_spread(o, d, heuristic)
                    } else {
                        let (c, depth) = self.pixel(o, d, heuristic);
                        (c, depth, Uncertainty::default())
                    };
                    *cp = pack_color_f32(c);
                    *tp = depth.unwrap_or(f32::INFINITY);
                    if let (Some((q, radius)), Some(t), Some(s)) = (pack, depth, sb.get_mut(i)) {
                        *s = q.pack(o + d * t, radius.at_ray(d, t, &u));
                    }
                }
            },
        );
        (PixelBuffer { width: camera.width, height: camera.height, t, color }, packed)
    }

    /// The ground-truth image: each pixel's composited color over [`BACKGROUND`] (exactly as a
    /// renderer shows a sample's color).
    pub fn render_image(&self, camera: &Camera) -> Image {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let basis = camera.ray_basis();
        let o = basis.origin();
        let mut img = Image::new(camera.width, camera.height);
        let kernel = self.kernel();
        img.pixels.par_chunks_mut(w.max(1) * BAND_ROWS).enumerate().for_each(|(band, px)| {
            if self.opts.kernel == MarchKernel::Packet {
                let y0 = (band * BAND_ROWS) as u32;
                crate::packet_march::march_band(&kernel, &basis, None, None, y0, &mut [], px, &mut []);
                return;
            }
            for (i, p) in px.iter_mut().enumerate() {
                let (x, y) = ((i % w) as u32, (band * BAND_ROWS + i / w) as u32);
                let (c, _) = self.march_ray(o, basis.dir(x, y), |_, _, _| {});
                *p = over_background(pack_color_f32(c), BACKGROUND);
            }
        });
        debug_assert_eq!(img.pixels.len(), w * h);
        img
    }

    /// The uncompacted packed samples of a marched [`PixelBuffer`] (radius 0 for empty pixels)
    /// and the frame's radius unit: each non-empty pixel's sample at `o + d·t` with radius
    /// `radius_scale` × the options' [`RadiusModel`], quantized over the volume box. Under
    /// [`RadiusModel::Uncertainty`] each non-empty pixel's ray is marched again (scalar, with
    /// the request's heuristic) for its [`Uncertainty`].
    pub fn quantize(&self, req: &CameraRequest, pb: &PixelBuffer) -> (Vec<u64>, f32) {
        let (q, radius) = self.quantizer(req);
        let radius_unit = radius.unit();
        let basis = req.camera.ray_basis();
        let o = basis.origin();
        let w = (pb.width as usize).max(1);
        let mut samples = vec![0u64; pb.t.len()];
        samples.par_chunks_mut(w * BAND_ROWS).zip(pb.t.par_chunks(w * BAND_ROWS)).enumerate().for_each(
            |(band, (s, t))| {
                for (i, (s, &t)) in s.iter_mut().zip(t).enumerate() {
                    if t.is_finite() {
                        let (x, y) = ((i % w) as u32, (band * BAND_ROWS + i / w) as u32);
                        let d = basis.dir(x, y);
                        let u = if radius.uses_spread() {
                            self.pixel_spread(o, d, req.heuristic).2
                        } else {
                            Uncertainty::default()
                        };
                        *s = q.pack(o + d * t, radius.at_ray(d, t, &u));
                    }
                }
            },
        );
        (samples, radius_unit)
    }

    /// Renders one compacted frame for a request: march with its heuristic, place each
    /// non-empty pixel's sample at `o + d·t` with radius `radius_scale` × the options'
    /// [`RadiusModel`],
    /// quantize over the volume box, compact in parallel.
    pub fn render_frame(&self, req: &CameraRequest) -> (Frame, FrameStats) {
        let mut frame =
            Frame { header: self.empty_header(req), samples: Vec::new(), colors: Vec::new(), segments: Vec::new() };
        let stats = self.render_frame_into(req, &mut frame);
        (frame, stats)
    }

    /// A layered frame: each pixel's ray cut into at most `layers` segments, each
    /// one sample at its segment's depth with the segment's own color and opacity, in pixel
    /// order and front to back within a pixel (`Frame::segments` holds each sample's index).
    /// `layers` ≤ 1 gives [`Marcher::render_frame`]'s frame exactly (the heuristic's depth).
    pub fn render_frame_layers(&self, req: &CameraRequest, layers: u32) -> (Frame, FrameStats) {
        let mut frame = self.empty_frame();
        let stats = self.render_frame_layers_into(req, layers, &mut frame);
        (frame, stats)
    }

    /// [`Marcher::render_frame_layers`] into an existing frame, reusing its memory.
    pub fn render_frame_layers_into(&self, req: &CameraRequest, layers: u32, frame: &mut Frame) -> FrameStats {
        self.render_frame_layers_until(req, layers, frame, &NEVER).unwrap_or_default()
    }

    /// [`Marcher::render_frame_layers_into`] that gives up once `stop` is set (tested before
    /// each row band is marched): `None`, and `frame` holds no frame to send.
    pub fn render_frame_layers_until(
        &self,
        req: &CameraRequest,
        layers: u32,
        frame: &mut Frame,
        stop: &AtomicBool,
    ) -> Option<FrameStats> {
        frame.segments.clear();
        if layers <= 1 {
            return self.render_frame_until(req, frame, stop);
        }
        let t0 = Instant::now();
        let (q, radius) = self.quantizer(req);
        let radius_unit = radius.unit();
        let lb = self.march_layers_impl(&req.camera, layers, Some((&q, radius)), stop);
        if stop.load(Ordering::Relaxed) {
            return None;
        }
        let t1 = Instant::now();
        let k = lb.layers as usize;
        frame.samples.clear();
        frame.colors.clear();
        for (i, &c) in lb.count.iter().enumerate() {
            for j in 0..c as usize {
                frame.samples.push(lb.packed[i * k + j]);
                frame.colors.push(lb.color[i * k + j]);
                frame.segments.push(j as u8);
            }
        }
        let n = frame.samples.len();
        let t2 = Instant::now();
        Some(self.finish_frame(req, frame, radius_unit, [t0, t1, t2], n, lb.count.len()))
    }

    /// [`Marcher::render_frame`] into an existing frame, reusing the memory of its sample and
    /// color vectors (a server keeps one frame per client).
    pub fn render_frame_into(&self, req: &CameraRequest, frame: &mut Frame) -> FrameStats {
        self.render_frame_until(req, frame, &NEVER).unwrap_or_default()
    }

    /// [`Marcher::render_frame_into`] that gives up once `stop` is set (`None`).
    fn render_frame_until(&self, req: &CameraRequest, frame: &mut Frame, stop: &AtomicBool) -> Option<FrameStats> {
        frame.segments.clear();
        let t0 = Instant::now();
        let (q, radius) = self.quantizer(req);
        let radius_unit = radius.unit();
        let (pb, packed) = self.march_impl(&req.camera, req.heuristic, Some((&q, radius)), stop);
        if stop.load(Ordering::Relaxed) {
            return None;
        }
        let t1 = Instant::now();
        let n = compaction::compact_into_vecs(&packed, &pb.color, &mut frame.samples, &mut frame.colors);
        let t2 = Instant::now();
        Some(self.finish_frame(req, frame, radius_unit, [t0, t1, t2], n, pb.t.len()))
    }

    /// Fills the header of a frame whose `n` samples are in place and says what rendering it
    /// took: the instants are the start, the end of the march and the end of compaction;
    /// `pixels` is the viewport's pixel count.
    fn finish_frame(
        &self,
        req: &CameraRequest,
        frame: &mut Frame,
        radius_unit: f32,
        [t0, t1, t2]: [Instant; 3],
        n: usize,
        pixels: usize,
    ) -> FrameStats {
        frame.header = FrameHeader {
            radius_unit,
            render_us: (t2 - t0).as_micros().min(u32::MAX as u128) as u32,
            count: n as u32,
            ..self.empty_header(req)
        };
        FrameStats {
            march_us: (t1 - t0).as_micros() as u64,
            compact_us: (t2 - t1).as_micros() as u64,
            samples: n,
            pixels,
        }
    }

    /// The frame's sphere radius for a request (its model from the options, its scale from
    /// the request).
    pub fn frame_radius(&self, req: &CameraRequest) -> FrameRadius {
        let scale = request_radius_scale(req);
        FrameRadius::with_params(
            self.opts.radius,
            self.opts.uncertainty,
            scale,
            &req.camera,
            &self.volume.bounds(),
            self.default_radius(),
            RADIUS_CODE,
        )
    }

    fn quantizer(&self, req: &CameraRequest) -> (Quantizer, FrameRadius) {
        let radius = self.frame_radius(req);
        (Quantizer::new(self.volume.bounds(), radius.unit()), radius)
    }

    /// A frame with no samples (for the default camera at 1×1), to render into with
    /// [`Marcher::render_frame_into`].
    pub fn empty_frame(&self) -> Frame {
        let req = CameraRequest {
            seq: 0,
            camera: self.default_camera(1, 1),
            heuristic: Heuristic::Threshold,
            radius_scale: 1.0,
            layers: 0,
        };
        Frame { header: self.empty_header(&req), samples: Vec::new(), colors: Vec::new(), segments: Vec::new() }
    }

    fn empty_header(&self, req: &CameraRequest) -> FrameHeader {
        FrameHeader {
            seq: req.seq,
            camera: req.camera,
            heuristic: req.heuristic,
            bounds: self.volume.bounds(),
            radius_unit: self.default_radius() / RADIUS_CODE,
            render_us: 0,
            level: self.level,
            count: 0,
        }
    }
}

/// A camera framing the whole box of `volume` (its bounding sphere fits the view; 30° vertical
/// field of view) from the volume's `+y` side, looking along `−y` with `+z` up: the front view
/// of a head stored in RAS orientation (x to the right, y anterior, z superior), as medical
/// volumes usually are. [`Camera::orbit`] turns it around the box centre.
pub fn default_camera(volume: &Volume, width: u32, height: u32) -> Camera {
    let b = volume.bounds();
    let f = Camera::framing(b.min(), b.max(), 0.0, 0.0, 30.0, width, height);
    let dist = (f.eye - f.target).length();
    Camera::look_at(f.target + Vec3::Y * dist, f.target, Vec3::Z, 30.0, width, height)
}

/// A request's radius scale as frames use it: at most 16, 1 where it is not a positive number.
pub(crate) fn request_radius_scale(req: &CameraRequest) -> f32 {
    if req.radius_scale.is_finite() && req.radius_scale > 0.0 {
        req.radius_scale.min(16.0)
    } else {
        1.0
    }
}
