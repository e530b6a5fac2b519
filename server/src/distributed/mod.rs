//! The server across MPI ranks: the volume split by a k-d tree, each rank marching its part on
//! the global ray grid into per-pixel depth segments, composited sort-last.
//!
//! One file per step:
//! - [`decomposition`]: the k-d split into parts with a one-voxel apron, each rank reading only
//!   its part of the file;
//! - [`partial`]: a part's march on the global ray grid into at most K segments per pixel;
//! - [`composite`]: direct-send by bands of image rows, the merge by depth and the fuse to the
//!   client's K (the compositing rule is stated there);
//! - `mpi` (feature `mpi`): the front end over rsmpi: rank 0 serves TCP (or renders, or dumps)
//!   as the one-process server does; every rank marches and composites its band.
//!
//! This module (without `mpi`) also assembles the frame rank 0 sends ([`FrameGeometry`]) and
//! runs every part in one process ([`render_in_process`]), which the tests compare with the
//! one-process marcher.

pub mod composite;
pub mod decomposition;
#[cfg(feature = "mpi")]
pub mod mpi;
pub mod partial;

use crate::marcher::{MarchOptions, RADIUS_CODE};
use crate::radius::{FrameRadius, Uncertainty};
use composite::Band;
use partial::PartMarcher;
use rayon::prelude::*;
use volwarp_core::compact_frame::{EncodeOptions, Encoding, RadiusPrediction};
use volwarp_core::sample::{pack_color_f32, Bounds, Quantizer};
use volwarp_core::segments::{PackLanes, MAX_LAYERS};
use volwarp_core::wire::{CameraRequest, Frame, FrameHeader};
use volwarp_core::{Heuristic, Image, Vec3, BACKGROUND};

/// Whether frames of one sample per pixel (K = 1) with `heuristic` are composited across ranks,
/// and if not, why (the error a client gets). The composited depth is the nearest part's pick
/// ([`composite::reduce`]), which is the one-process pick for:
/// - **Entrance** always: the nearest part with a visible sample holds the ray's first one;
/// - **Threshold** wherever the nearest part with a visible sample crosses the threshold
///   itself (its accumulation is the ray's, bit for bit, as nothing in front of it is visible);
///   a ray that crosses only over several parts gets the depth where it leaves the nearest
///   visible part (the part's fallback), in front of the ray's crossing.
///
/// The others depend on the whole ray: Exit, Midpoint, Peak and Gradient on where the ray's
/// early termination falls (each part stops at its own, later, one), RelThreshold on the ray's
/// final opacity and EnExMean on its entrance and exit opacities, which no part knows.
pub fn one_sample_heuristic(heuristic: Heuristic) -> Result<(), String> {
    match heuristic {
        Heuristic::Entrance | Heuristic::Threshold => Ok(()),
        h => Err(format!(
            "the {h} heuristic is not composited across MPI ranks at one sample per pixel (its depth depends \
             on the whole ray, which no rank marches): ask for entrance or threshold, or for layered frames"
        )),
    }
}

/// What rank 0 needs of the whole volume to make frames without holding it: its box, its
/// voxel diagonal and the march options (the same values the one-process marcher reads of
/// its volume).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameGeometry {
    /// The whole volume's dims.
    pub dims: [u32; 3],
    /// Voxel spacing.
    pub spacing: Vec3,
    /// The march options.
    pub opts: MarchOptions,
}

impl FrameGeometry {
    /// The volume box.
    pub fn bounds(&self) -> Bounds {
        Bounds::new(Vec3::ZERO, Vec3::new(self.dims[0] as f32, self.dims[1] as f32, self.dims[2] as f32) * self.spacing)
    }

    /// [`crate::Marcher::frame_radius`] of the whole volume.
    pub fn frame_radius(&self, req: &CameraRequest) -> FrameRadius {
        let scale = crate::marcher::request_radius_scale(req);
        FrameRadius::with_params(
            self.opts.radius,
            self.opts.uncertainty,
            scale,
            &req.camera,
            &self.bounds(),
            0.5 * self.spacing.length(),
            RADIUS_CODE,
        )
    }

    /// The frame of merged per-pixel segments (`rows` of them, row bands in image order, each
    /// pixel's segments front to back), as the one-process marcher assembles it: `layers` > 1
    /// gives a layered frame (each segment a sample, its index in `Frame::segments`), 1 one
    /// sample per non-empty pixel.
    pub fn frame(&self, req: &CameraRequest, layers: u32, bands: &[Band], render_us: u32) -> Frame {
        // Each band's samples in parallel, then joined in image order.
        let first: Vec<u32> = bands
            .iter()
            .scan(0u32, |at, b| {
                let f = *at;
                *at += b.count.len() as u32;
                Some(f)
            })
            .collect();
        let parts: Vec<FramePart> = bands
            .par_iter()
            .zip(first.par_iter())
            .map(|(b, &first)| self.frame_part(req, layers, b, first, 0..b.count.len()))
            .collect();
        self.frame_of_parts(req, &parts, render_us)
    }

    /// The samples of pixels `range` of a merged band whose first pixel is pixel `first` of the
    /// image: their share of [`FrameGeometry::frame`] (what a band's owner assembles).
    pub fn frame_part(
        &self,
        req: &CameraRequest,
        layers: u32,
        band: &Band,
        first: u32,
        range: std::ops::Range<usize>,
    ) -> FramePart {
        let a = self.assembler(req, layers);
        let mut out = PartBuilder::default();
        for p in range {
            a.push(first + p as u32, band.pixel(p), &mut out);
        }
        a.finish(out)
    }

    /// What assembles a frame's samples pixel by pixel ([`Assembler::push`]).
    pub fn assembler(&self, req: &CameraRequest, layers: u32) -> Assembler {
        let radius = self.frame_radius(req);
        let basis = req.camera.ray_basis();
        Assembler {
            q: Quantizer::new(self.bounds(), radius.unit()),
            radius,
            o: basis.origin(),
            basis,
            w: req.camera.width.max(1),
            layered: layers > 1,
        }
    }

    /// A frame for `req` of `n` samples, all zero, to be filled in place ([`FrameSlots`]): how
    /// rank 0 receives the band owners' samples straight into the frame it sends.
    pub fn frame_of_count(&self, req: &CameraRequest, layers: u32, n: usize, render_us: u32) -> Frame {
        Frame {
            header: self.header(req, n, render_us),
            samples: vec![0; n],
            colors: vec![0; n],
            segments: vec![0; if layers > 1 { n } else { 0 }],
        }
    }

    /// The frame of its parts, in image order (see [`FrameGeometry::frame`]).
    pub fn frame_of_parts(&self, req: &CameraRequest, parts: &[FramePart], render_us: u32) -> Frame {
        let n: usize = parts.iter().map(|p| p.samples.len()).sum();
        let mut frame = Frame {
            header: self.header(req, n, render_us),
            samples: Vec::with_capacity(n),
            colors: Vec::with_capacity(n),
            segments: Vec::new(),
        };
        for p in parts {
            frame.samples.extend_from_slice(&p.samples);
            frame.colors.extend_from_slice(&p.colors);
            frame.segments.extend_from_slice(&p.segments);
        }
        frame
    }

    /// The header of a frame of `n` samples for `req`.
    fn header(&self, req: &CameraRequest, n: usize, render_us: u32) -> FrameHeader {
        FrameHeader {
            seq: req.seq,
            camera: req.camera,
            heuristic: req.heuristic,
            bounds: self.bounds(),
            radius_unit: self.frame_radius(req).unit(),
            render_us,
            level: 0,
            count: n as u32,
        }
    }

    /// [`crate::encoding::encode_frame_for`] of a frame made by [`FrameGeometry::frame`].
    pub fn encode(&self, req: &CameraRequest, frame: &Frame, encoding: Encoding, green: bool) -> (Vec<u8>, Encoding) {
        if encoding == Encoding::Compact {
            let r = self.frame_radius(req);
            let opts = EncodeOptions {
                radius: Some(RadiusPrediction { constant: r.constant(), per_depth: r.per_depth() }),
                colors_against_green: green,
                ..EncodeOptions::default()
            };
            if let Some(b) = crate::encoding::encode_compact(frame, &opts, crate::encoding::ZSTD_LEVEL) {
                return (b, Encoding::Compact);
            }
        }
        (crate::encoding::raw12_bytes(frame), Encoding::Raw12)
    }
}

/// A frame's samples pixel by pixel, as the one-process marcher makes them.
pub struct Assembler {
    radius: FrameRadius,
    q: Quantizer,
    basis: volwarp_core::RayBasis,
    o: Vec3,
    w: u32,
    layered: bool,
}

impl Assembler {
    /// Appends image pixel `i`'s samples: its merged segments `segs`, front to back. Their
    /// positions are quantized eight samples at a time and a layered frame's colors packed
    /// eight pixels at a time, in lanes (core's `Quantizer::pack8` and `PackLanes`, as the
    /// one-process marcher does); [`Assembler::finish`] does the rest.
    #[inline]
    pub fn push(&self, i: u32, segs: &[partial::Seg], out: &mut PartBuilder) {
        if segs.is_empty() {
            return;
        }
        let d = self.basis.dir(i % self.w, i / self.w);
        if self.layered {
            // The segments' colors rounded so their composite is the ray's own pixel.
            let part = &mut out.part;
            let n = segs.len().min(MAX_LAYERS);
            let at = part.colors.len();
            part.colors.resize(at + n, 0);
            part.colors.extend(segs[n..].iter().map(|s| pack_color_f32(s.c)));
            out.colors.push(segs[..n].iter().map(|s| s.c), composite(segs), at, &mut part.colors);
        }
        for (j, s) in segs.iter().enumerate() {
            let r =
                if self.layered { self.radius.at(d, s.t) } else { self.radius.at_ray(d, s.t, &Uncertainty::default()) };
            let p = self.o + d * s.t;
            let l = out.queued;
            for (a, v) in p.to_array().into_iter().enumerate() {
                out.position[a][l] = v;
            }
            out.radius[l] = r;
            out.queued += 1;
            out.part.samples.push(0);
            if out.queued == 8 {
                self.flush_positions(out);
            }
            if self.layered {
                out.part.segments.push(j as u8);
            } else {
                out.part.colors.push(pack_color_f32(s.c));
            }
        }
    }

    /// The part `b` was building, every sample's position and color filled in.
    pub fn finish(&self, mut b: PartBuilder) -> FramePart {
        self.flush_positions(&mut b);
        b.colors.flush(&mut b.part.colors);
        b.part
    }

    /// Fills in the queued samples' positions (the last `queued` samples of the part).
    fn flush_positions(&self, b: &mut PartBuilder) {
        let n = b.queued;
        if n == 0 {
            return;
        }
        let packed = self.q.pack8(&b.position, &b.radius);
        let len = b.part.samples.len();
        b.part.samples[len - n..].copy_from_slice(&packed[..n]);
        b.queued = 0;
    }
}

/// A [`FramePart`] being assembled ([`Assembler::push`], then [`Assembler::finish`]): the
/// part, the samples whose positions wait to be quantized together and the pixels whose
/// colors wait to be packed together.
#[derive(Default)]
pub struct PartBuilder {
    part: FramePart,
    /// Per axis and lane the queued samples' positions, and their radii.
    position: [[f32; 8]; 3],
    radius: [f32; 8],
    queued: usize,
    colors: PackLanes,
}

/// A run of a frame's samples, in pixel order: packed positions and radii, colors and (layered
/// frames) segment indices.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FramePart {
    /// Packed samples.
    pub samples: Vec<u64>,
    /// Packed colors.
    pub colors: Vec<u32>,
    /// Segment indices (empty for one sample per pixel).
    pub segments: Vec<u8>,
}

impl FramePart {
    /// The parts joined, in order.
    pub fn join(parts: &[FramePart]) -> FramePart {
        let mut out = FramePart::default();
        for p in parts {
            out.samples.extend_from_slice(&p.samples);
            out.colors.extend_from_slice(&p.colors);
            out.segments.extend_from_slice(&p.segments);
        }
        out
    }
}

/// A frame's sample arrays cut in consecutive runs, as bytes, to be filled in place: by a copy
/// of a band owner's [`FramePart`]s or by a receive from its rank (the ranks of one job share
/// one byte order).
#[derive(Debug)]
pub struct FrameSlots<'a> {
    /// The run's packed samples.
    pub samples: &'a mut [u8],
    /// The run's packed colors.
    pub colors: &'a mut [u8],
    /// The run's segment indices (empty for one sample per pixel).
    pub segments: &'a mut [u8],
}

impl<'a> FrameSlots<'a> {
    /// `frame`'s samples cut into runs of `counts` samples each, in order; `None` if they do not
    /// add up to the frame's samples.
    pub fn split(frame: &'a mut Frame, counts: &[usize]) -> Option<Vec<FrameSlots<'a>>> {
        let (n, layered) = (frame.samples.len(), !frame.segments.is_empty());
        if counts.iter().sum::<usize>() != n || frame.colors.len() != n || (layered && frame.segments.len() != n) {
            return None;
        }
        let mut s = bytemuck::cast_slice_mut::<u64, u8>(&mut frame.samples);
        let mut c = bytemuck::cast_slice_mut::<u32, u8>(&mut frame.colors);
        let mut g = &mut frame.segments[..];
        let mut out = Vec::with_capacity(counts.len());
        for &n in counts {
            let (a, rest) = std::mem::take(&mut s).split_at_mut(8 * n);
            s = rest;
            let (b, rest) = std::mem::take(&mut c).split_at_mut(4 * n);
            c = rest;
            let (d, rest) = std::mem::take(&mut g).split_at_mut(if layered { n } else { 0 });
            g = rest;
            out.push(FrameSlots { samples: a, colors: b, segments: d });
        }
        Some(out)
    }

    /// Copies `runs` into the slots, in order; false (and nothing copied) if they do not hold
    /// exactly as many samples (and segment indices) as the slots.
    pub fn fill(&mut self, runs: &[FramePart]) -> bool {
        let n: usize = runs.iter().map(|p| p.samples.len()).sum();
        let g: usize = runs.iter().map(|p| p.segments.len()).sum();
        if 8 * n != self.samples.len()
            || runs.iter().any(|p| p.colors.len() != p.samples.len())
            || g != self.segments.len()
        {
            return false;
        }
        let (mut at, mut ag) = (0, 0);
        for p in runs {
            let m = p.samples.len();
            self.samples[8 * at..8 * (at + m)].copy_from_slice(bytemuck::cast_slice(&p.samples));
            self.colors[4 * at..4 * (at + m)].copy_from_slice(bytemuck::cast_slice(&p.colors));
            self.segments[ag..ag + p.segments.len()].copy_from_slice(&p.segments);
            at += m;
            ag += p.segments.len();
        }
        true
    }
}

/// A pixel's merged segments composited front to back (premultiplied), as core composites them.
fn composite(segs: &[partial::Seg]) -> [f32; 4] {
    volwarp_core::segments::composite(segs.iter().map(|s| s.c))
}

/// The composited image of merged bands (each pixel's segments over [`BACKGROUND`], as the
/// one-process `render_image` shows a pixel).
pub fn image(width: u32, height: u32, bands: &[Band]) -> Image {
    let mut img = Image::new(width, height);
    let mut i = 0;
    for b in bands {
        for p in 0..b.count.len() {
            let c = composite(b.pixel(p));
            img.pixels[i] = volwarp_core::sample::over_background(pack_color_f32(c), BACKGROUND);
            i += 1;
        }
    }
    img
}

/// Every part marched and composited in one process, with `bands` bands of rows (what `N`
/// ranks compute between them): the merged bands, in image order.
pub fn render_in_process(parts: &[PartMarcher], req: &CameraRequest, layers: u32, bands: usize) -> Vec<Band> {
    let cam = &req.camera;
    let k = layers.clamp(1, volwarp_core::segments::MAX_LAYERS as u32) as usize;
    let ert = parts.first().map_or(0.99, |p| p.options().early_termination);
    let frames: Vec<_> = parts.iter().map(|p| p.march(cam, layers, req.heuristic)).collect();
    (0..bands)
        .map(|b| {
            let rows = composite::band_rows(cam.height, bands, b);
            let pixels = (rows.end - rows.start) as usize * cam.width as usize;
            let sent: Vec<Band> = frames
                .iter()
                .map(|f| composite::decode_band(&composite::encode_band(f, rows.clone()), pixels, f.k))
                .collect::<Result<_, _>>()
                .expect("bands this process encoded decode");
            composite::merge_bands(&sent, pixels, k, ert)
        })
        .collect()
}
