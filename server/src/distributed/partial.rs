//! One rank's march: the samples of its part on the **global** ray grid, cut into per-pixel
//! depth segments.
//!
//! A ray's samples are the one-process marcher's: `t_k = t_enter + (k + ½)·Δt` with `t_enter`
//! the entry into the whole volume's box ([`crate::marcher`]); a part takes those whose grid
//! position lies in its owned box ([`Decomposition::owns`]), samples them in its own held
//! voxels (the same bits as the whole volume, see [`super::decomposition`]), classifies them
//! through the same table and composites them front to back from an empty accumulation, with
//! early termination at the options' threshold of the part's own opacity. The part's
//! samples are cut by core's [`Segmenter`] into at most K segments; for K = 1 the segment's
//! depth is the requested heuristic's pick over the part's samples (two-pass heuristics take
//! their first pass over the part too; a threshold the part's own samples do not reach falls
//! back to where the ray leaves the part).
//!
//! With one part this is the scalar marcher's arithmetic step for step, so its segments are
//! the one-process frame's bit for bit (tested). Empty space is skipped as the marcher skips it,
//! with the part's own min/max grid (built over its held voxels) and the ray's origin in the
//! part's coordinates; skipping never changes a result, only the time.
//!
//! Two kernels march a part, as they march the whole volume (the options' [`MarchKernel`]):
//! the packet kernel ([`crate::packet_march`], the default) with the part's window in its lanes,
//! and the scalar one ([`PartMarcher::ray`]), its reference; both take the same samples with the
//! same operations, so their segments are equal bit for bit (tested).

use super::decomposition::Decomposition;
use crate::march_settings::PartWindow;
use crate::marcher::{MarchKernel, MarchOptions, Marcher};
use crate::transfer_function::{TransferFunction, LUT_SIZE};
use crate::volume::Volume;
use rayon::prelude::*;
use std::sync::Arc;
use volwarp_core::segments::{Segmenter, MAX_LAYERS};
use volwarp_core::{Camera, DepthPicker, FirstPassAccumulator, Heuristic, Vec3};

/// One depth segment as ranks exchange it: representative depth and premultiplied RGBA (sent
/// as its 20 bytes in memory order: ranks of one job share one byte order).
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct Seg {
    /// Depth (ray parameter along the unit ray).
    pub t: f32,
    /// Premultiplied RGBA in `[0, 1]`.
    pub c: [f32; 4],
}

/// Bytes of one [`Seg`] between ranks.
pub const SEG_BYTES: usize = 20;

/// A rank's segments of every pixel: `count[i]` segments of pixel `i` at slots `i·k ..`.
#[derive(Clone, Debug, PartialEq)]
pub struct PartFrame {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Slots per pixel.
    pub k: usize,
    /// Segments per pixel.
    pub count: Vec<u8>,
    /// Segment slots.
    pub segs: Vec<Seg>,
}

impl PartFrame {
    /// Pixel `i`'s segments, front to back.
    pub fn pixel(&self, i: usize) -> &[Seg] {
        &self.segs[i * self.k..i * self.k + self.count[i] as usize]
    }
}

/// The marcher of one part.
#[derive(Clone, Debug)]
pub struct PartMarcher {
    volume: Arc<Volume>,
    dec: Arc<Decomposition>,
    part: usize,
    /// The one-process marcher of the held block (its table, step, empty-space grid and packet
    /// kernel).
    m: Marcher,
    lut: Vec<[f32; 4]>,
    opts: MarchOptions,
    dt: f32,
    inv_spacing: Vec3,
    /// Where the part lies in the whole volume.
    win: PartWindow,
    /// The segment slots of the last frame given back ([`PartMarcher::recycle`]), reused by the
    /// next march: a 1024² frame's slots are 84 MB at K = 4, which allocated anew every frame
    /// cost the march a page fault per 4 KiB and the merge their unmapping.
    spare: Spare,
}

/// The largest buffer a rank keeps from one frame to the next (a 1024² frame's segment slots at
/// K = 4 take 84 MB).
pub const KEEP_BYTES: usize = 256 << 20;

/// Puts `buf` in `slot` for the next frame to reuse, unless it holds more than [`KEEP_BYTES`]
/// (one huge frame does not pin its memory).
pub fn keep_for_next_frame<T>(slot: &mut Vec<T>, buf: Vec<T>) {
    if buf.capacity() * std::mem::size_of::<T>() <= KEEP_BYTES {
        *slot = buf;
    }
}

/// [`PartMarcher`]'s buffer kept between frames; a clone starts without one.
#[derive(Debug, Default)]
struct Spare(std::sync::Mutex<Vec<Seg>>);

impl Clone for Spare {
    fn clone(&self) -> Self {
        Spare::default()
    }
}

impl PartMarcher {
    /// The marcher of part `part` of `dec`, whose held voxels are `volume` (from
    /// [`super::decomposition::PartData::into_volume`]), with transfer function `tf`.
    pub fn new(
        volume: Arc<Volume>,
        dec: Arc<Decomposition>,
        part: usize,
        tf: &TransferFunction,
        opts: MarchOptions,
    ) -> Result<PartMarcher, String> {
        let p = dec.parts.get(part).ok_or_else(|| format!("no part {part} of {}", dec.parts.len()))?;
        if volume.dims() != p.held_dims() {
            return Err(format!("part {part} holds {:?} voxels, its volume {:?}", p.held_dims(), volume.dims()));
        }
        // The table and step exactly as the one-process marcher makes them (same spacing);
        // no shading (its gradient would read a voxel past the apron).
        let m = Marcher::with_options(volume.clone(), tf, MarchOptions { shading: None, ..opts });
        let lut = m.lut_table().to_vec();
        debug_assert_eq!(lut.len(), LUT_SIZE);
        let sp = volume.spacing();
        let win = PartWindow::new(dec.dims, p.lo, p.hi, p.held_lo, sp);
        let opts = m.options();
        Ok(PartMarcher {
            volume,
            dec,
            part,
            lut,
            opts,
            dt: m.step(),
            inv_spacing: 1.0 / sp,
            m,
            win,
            spare: Spare::default(),
        })
    }

    /// The march options.
    pub fn options(&self) -> MarchOptions {
        self.opts
    }

    /// The part's held voxels.
    pub fn volume(&self) -> &Volume {
        &self.volume
    }

    /// The part index.
    pub fn part(&self) -> usize {
        self.part
    }

    /// The decomposition.
    pub fn decomposition(&self) -> &Arc<Decomposition> {
        &self.dec
    }

    /// Marches one ray through the part, feeding `(t, src_a, dst)` for every visible sample
    /// (the part's own accumulation); returns the ray's exit from the whole volume's box
    /// (`None` where it misses the box).
    #[inline]
    fn march_ray(&self, o: Vec3, d: Vec3, mut feed: impl FnMut(f32, f32, [f32; 4])) -> Option<f32> {
        let inv_d = 1.0 / d;
        let dt = self.dt;
        let (_, t_enter, t_exit, k0, k1) = self.win.ray(o, d, dt);
        let t_exit = t_exit?;
        let og = o * self.inv_spacing - 0.5;
        let dg = d * self.inv_spacing;
        let ert = self.opts.early_termination;
        let (mut r, mut g, mut b, mut a) = (0.0f32, 0.0f32, 0.0f32, 0.0f32);
        let skip = self.opts.skip_empty;
        let occ = self.m.occupancy();
        // The ray's origin in the part's own world coordinates (what its grid's leaps use).
        let o_part = o - self.win.origin;
        let mut t_check = f32::NEG_INFINITY;
        let mut k = k0;
        while k < k1 {
            let t = t_enter + (k as f32 + 0.5) * dt;
            let gp = og + dg * t;
            if !self.win.owns(gp) {
                k += 1;
                continue;
            }
            let gl = gp - self.win.off;
            if skip && t >= t_check {
                let br = occ.brick_of(gl);
                let (r, reach) = occ.look(br);
                let t_out = occ.leap_exit_t(br, reach, o_part, inv_d);
                if r > 0 {
                    // The marcher's resume: the first lattice sample at or after t_out.
                    k = crate::march_settings::resume_after(t_out, t_enter, dt, k, k1);
                    continue;
                }
                t_check = t_out;
            }
            k += 1;
            let v = self.volume.sample_grid(gl);
            let [cr, cg, cb, ca] = self.lut[TransferFunction::index(v)];
            if ca > 0.0 {
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
        }
        Some(t_exit)
    }

    /// One ray's segments in this part: at most `layers` of them; with `layers` ≤ 1 one
    /// segment: the part's accumulated color at `heuristic`'s pick over the part's samples
    /// (the picker's fallback being where the ray leaves the part's owned box for the
    /// threshold-like heuristics, so the parts' segments stay in visibility order, else the
    /// ray's exit from the whole box, as in the one-process marcher), none where the picker
    /// finds the part's samples empty.
    pub fn ray(&self, o: Vec3, d: Vec3, layers: u32, heuristic: Heuristic, out: &mut [Seg]) -> usize {
        if layers <= 1 {
            let first = heuristic.needs_first_pass().then(|| {
                let mut acc = FirstPassAccumulator::new();
                self.march_ray(o, d, |_, sa, dst| acc.feed(sa, dst[3]));
                acc.finish()
            });
            let mut picker = DepthPicker::new(heuristic, first);
            let mut last = [0.0f32; 4];
            let Some(t_exit) = self.march_ray(o, d, |t, sa, dst| {
                picker.feed(t, sa, dst[3]);
                last = dst;
            }) else {
                return 0;
            };
            // A threshold-like pick that the part's own samples do not meet falls back to where
            // the ray leaves the part (between its samples and the next part's, so the parts'
            // segments stay in visibility order when merged by depth; the box exit for a part
            // that is the whole volume), not to the box exit.
            let fallback = if picker.threshold_target().is_some() { self.win.part_exit(o, d, t_exit) } else { t_exit };
            return match picker.finish(fallback) {
                Some(t) if last[3] > 0.0 => {
                    out[0] = Seg { t, c: last };
                    1
                }
                _ => 0,
            };
        }
        let mut seg = Segmenter::new(layers, self.dt);
        if self.march_ray(o, d, |t, _, dst| seg.feed(t, dst)).is_none() {
            return 0;
        }
        let s = seg.finish();
        for (o, s) in out.iter_mut().zip(s) {
            *o = Seg { t: s.t, c: s.color };
        }
        s.len()
    }

    /// Gives a marched frame's buffers back for the next [`PartMarcher::march`] to reuse
    /// ([`keep_for_next_frame`]).
    pub fn recycle(&self, frame: PartFrame) {
        keep_for_next_frame(&mut self.spare.0.lock().unwrap_or_else(|e| e.into_inner()), frame.segs);
    }

    /// Marches every pixel of `camera` (parallel over rows).
    pub fn march(&self, camera: &Camera, layers: u32, heuristic: Heuristic) -> PartFrame {
        let k = layers.clamp(1, MAX_LAYERS as u32) as usize;
        let (w, h) = (camera.width as usize, camera.height as usize);
        let basis = camera.ray_basis();
        let o = basis.origin();
        let mut count = vec![0u8; w * h];
        // Slots past a pixel's count are never read, so the last frame's need no clearing.
        let mut segs = std::mem::take(&mut *self.spare.0.lock().unwrap_or_else(|e| e.into_inner()));
        segs.resize(w * h * k, Seg::default());
        if self.opts.kernel == MarchKernel::Packet {
            // Bands of rows a multiple of every lane kind's packet height.
            let rows = 8;
            let kernel = self.m.part_kernel(&self.win);
            count.par_chunks_mut(w.max(1) * rows).zip(segs.par_chunks_mut(w.max(1) * rows * k)).enumerate().for_each(
                |(b, (count, segs))| {
                    let mut out = crate::packet_march::PartOut { k, count, segs };
                    crate::packet_march::march_band_part(&kernel, &basis, heuristic, (b * rows) as u32, &mut out);
                },
            );
        } else {
            count.par_chunks_mut(w.max(1)).zip(segs.par_chunks_mut(w.max(1) * k)).enumerate().for_each(
                |(y, (c, s))| {
                    for (x, c) in c.iter_mut().enumerate() {
                        let d = basis.dir(x as u32, y as u32);
                        *c = self.ray(o, d, k as u32, heuristic, &mut s[x * k..x * k + k]) as u8;
                    }
                },
            );
        }
        PartFrame { width: camera.width, height: camera.height, k, count, segs }
    }
}
