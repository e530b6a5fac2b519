//! The layered splatter on the GPU (`splat-layers-gpu`), mirroring the CPU's
//! `volwarp_cpu_tracer::layer_splat::LayerSplat` (`layer_splat.wgsl`): each sample of a layered
//! frame is drawn as its source pixel's footprint quad, every pixel keeps the nearest
//! [`LIST`] `(dist², id)` keys of the footprints that cover its centre, sorts them and
//! composites them front to back over the background; with [`LayerOptions::fill`] the pixels
//! nothing covers inside the covered rows' and columns' spans take the frame's own composite
//! for their view direction; with adaptive sizing ([`Renderer::set_adaptive_radius`]) opaque
//! samples' footprints grow with the warp angle. Same options, same image as the CPU.
//!
//! Passes (one command buffer per draw, one readback): `setup` (per sample: the footprint's
//! edge functions, key and pixel bounds; each pixel whose centre it covers is counted), scans
//! (the pixels' list offsets), `scatter` (per sample again: its id into each covered pixel's
//! list), `raster` (per pixel: its list's nearest keys in a private 16-entry list of `(hi, lo)`
//! pairs, sorted, composited) and `fill` (the silhouette spans and the stale lookup). Binning
//! to pixels rather than screen tiles: a pixel then reads only the footprints that cover it
//! (about K), where an 8×8 tile made every pixel test its tile's few hundred (the first
//! version, 10× slower on lavapipe). The frame's own composite (the fill's stale image) is
//! drawn by the same passes at the frame camera, once per scene, and kept on the GPU.
//!
//! Every per-frame constant (camera bases, the footprint's half-pixel vectors in the new
//! camera's basis, the grow ratio, the focal plane) is computed here with the CPU's own `f32`
//! operations and passed in the uniform (`LayerParams`, declared once in `prelude.wgsl`), so
//! the shader starts from the CPU's values and repeats its per-sample arithmetic in the same
//! order. The lists' total is not known before the `scan`: they are sized from the last
//! frame (or `2n` entries), and a frame whose total exceeds that is drawn again with room.
//!
//! Watertight slabs: the corners a segment shares with its slab's neighbours are found on the
//! CPU with the CPU's own code (`SlabCorners`, once per uploaded scene) and uploaded beside the
//! samples; `setup` chooses between them and the plane with the CPU's area rule.
//!
//! Cracks: the CPU's own pass (`layered::close_cracks`) runs on the image read back, away from
//! the frame's own camera, on the CPU's threads (it reads each pixel's neighbours as finished:
//! on the GPU a second dispatch over the whole image, for 0.5–0.6 ms of CPU work per 512²
//! image on one thread).
//!
//! Memory on the GPU: 64 bytes per sample (footprints) + 12 (sample, color) + 16 (shared
//! corners), 4 per list entry (a sample per pixel it covers), 24 per output pixel (pixel,
//! count, list count and offset, readback) plus the frame's composite. The scan is
//! reduce-then-scan over blocks of 4096 counts (block sums, one workgroup over the sums, the
//! prefixes written in place).

use crate::buffers::{grid, read_mapped, GrowBuffer};
use crate::tracer::{deq_uniforms, SceneKey, MAX_GPU_VIEWPORT};
use crate::{GpuContext, GpuError};
use bytemuck::{Pod, Zeroable};
use std::time::{Duration, Instant};
use volwarp_core::renderer::{Image, Renderer, BACKGROUND};
use volwarp_core::{Camera, RayBasis, RendererKind, Scene, Vec3};
use volwarp_cpu_tracer::layered::{close_cracks_of, CrackScratch};
pub use volwarp_cpu_tracer::layered::{LayerOptions, LIST, OPAQUE};
use volwarp_cpu_tracer::layered::{OlderSets, Setup, SlabCorners, MAX_FRAMES};
use volwarp_cpu_tracer::Threads;

/// Words at the start of the work buffer before the pixels' counts (`COUNTS` in the shader).
const COUNTS: u32 = 16;

/// Uniform slots (frame draw, new-camera draw, then one per older frame) are this far apart.
const SLOT: u64 = 1024;

/// Older frames drawn at most (the CPU's bound: `hole_fill::MAX_FRAMES` kept in all).
const MAX_OLDER: usize = MAX_FRAMES - 1;

/// Uniform slots: the frame's composite, the new view, the older frames.
const SLOTS: u64 = 2 + MAX_OLDER as u64;

/// Storage buffers bound in one stage (bindings 1–9 of `layer_splat.wgsl`).
const STORAGE_BINDINGS: u32 = 9;

/// Bytes of one footprint on the GPU (`Quad` in `layer_splat.wgsl`).
const QUAD_BYTES: u64 = 64;

/// The layered splatter's uniform (`LayerParams` in `prelude.wgsl`; fields described there).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(crate) struct LayerParams {
    pub eye: [f32; 4],
    pub u: [f32; 4],
    pub v: [f32; 4],
    pub w: [f32; 4],
    pub src_eye: [f32; 4],
    pub src_w: [f32; 4],
    pub su: [f32; 4],
    pub sv: [f32; 4],
    pub bu: [f32; 4],
    pub bv: [f32; 4],
    pub e: [f32; 4],
    pub proj: [f32; 4],
    pub deq_min: [f32; 4],
    pub deq_step: [f32; 4],
    pub basis: RayBasis,
    pub f_eye: [f32; 4],
    pub f_u: [f32; 4],
    pub f_v: [f32; 4],
    pub f_w: [f32; 4],
    pub f_proj: [f32; 4],
    pub k: [f32; 4],
    pub k2: [f32; 4],
    pub width: u32,
    pub height: u32,
    pub n: u32,
    pub min_alpha: u32,
    pub f_width: u32,
    pub f_height: u32,
    pub background: u32,
    pub cap: u32,
    pub off_spans: u32,
    pub off_sums: u32,
    pub only_empty: u32,
    pub opacity_limit: f32,
}

fn v4(v: Vec3) -> [f32; 4] {
    [v.x, v.y, v.z, 0.0]
}

/// Counts per block of the scan (256 invocations × 16; `SCAN_BLOCK` in the shader).
const SCAN_BLOCK: u32 = 4096;

/// Words of the work buffer a draw of `w × h` needs, and where its spans and the scan's block
/// sums start (after [`COUNTS`] words: a count per pixel, the spans, a sum per scan block).
fn work_layout(w: u32, h: u32) -> (u64, u32, u32) {
    let off_spans = COUNTS + w * h;
    let off_sums = off_spans + 2 * (w + h);
    (off_sums as u64 + (w * h).div_ceil(SCAN_BLOCK) as u64, off_spans, off_sums)
}

/// The scene's sample count if it can be drawn (the CPU's `begin_frame_unbuilt_ok`: a built
/// scene must pass [`Scene::check`]; an unbuilt one, no nodes, the same rules but the nodes').
fn check_scene(scene: &Scene) -> Result<u32, GpuError> {
    if !scene.nodes.is_empty() || scene.samples.len() < 2 {
        return crate::tracer::GpuTracer::check_scene(scene);
    }
    let d = &scene.deq;
    if scene.colors.len() != scene.samples.len() {
        return Err(GpuError::BadScene("sample and color counts do not match"));
    }
    if scene.samples.len() >= Scene::MAX_SAMPLES {
        return Err(GpuError::BadScene("more than 2^30 samples"));
    }
    if !(d.min.is_finite() && d.step.is_finite() && d.radius_unit.is_finite()) {
        return Err(GpuError::BadScene("dequantizer is not finite"));
    }
    Ok(scene.samples.len() as u32)
}

/// The uniform of one draw of `scene` for `camera` (its frame camera `fc`) with footprints of
/// half side `own`, `grown` for the opaque samples: the CPU's footprint constants
/// (`layered::Setup`) and the stale lookup's projection.
fn params(
    scene: &Scene,
    camera: &Camera,
    fc: &Camera,
    opts: &LayerOptions,
    grown: f32,
    cap: u32,
    shared: bool,
) -> LayerParams {
    // The footprint constants are the CPU's own (`layered::Setup`), so both sides set up
    // the same footprints.
    let s = Setup::new(camera, fc, &scene.deq, opts.own, grown, opts.grow_min_alpha);
    let view = &s.view;
    // The stale lookup's frame projection (`depth_buffer::Projector`) and focal plane.
    let (fu, fv, fwd) = fc.basis();
    let tan_y = libm::tanf(fc.fov_y_deg.to_radians() * 0.5);
    let tan_x = tan_y * fc.aspect();
    let plane = fc.target.dot(fwd);
    let t_num = plane - camera.eye.dot(fwd);
    let (deq_min, deq_step) = deq_uniforms(&scene.deq);
    let (w, h) = (camera.width, camera.height);
    let (_, off_spans, off_sums) = work_layout(w, h);
    LayerParams {
        eye: v4(view.eye),
        u: v4(view.u),
        v: v4(view.v),
        w: v4(view.w),
        src_eye: v4(s.src_eye),
        src_w: v4(s.src_w),
        su: v4(s.su),
        sv: v4(s.sv),
        bu: v4(s.bu),
        bv: v4(s.bv),
        e: v4(s.e),
        proj: [view.px_x, view.px_y, view.half_w, view.half_h],
        deq_min,
        deq_step,
        basis: camera.ray_basis(),
        f_eye: v4(fc.eye),
        f_u: v4(fu),
        f_v: v4(fv),
        f_w: v4(fwd),
        f_proj: [tan_x, tan_y, fc.width as f32, fc.height as f32],
        k: [s.grow_ratio, 0.0076, 1e-6, 1.0 / 255.0],
        k2: [OPAQUE, t_num, opts.water_ratio, if shared { 1.0 } else { 0.0 }],
        width: w,
        height: h,
        n: scene.samples.len() as u32,
        min_alpha: s.min_alpha as u32,
        f_width: fc.width,
        f_height: fc.height,
        background: BACKGROUND,
        cap,
        off_spans,
        off_sums,
        only_empty: 0,
        opacity_limit: opts.opacity_limit,
    }
}

/// The GPU layered splatter. Implements [`Renderer`] as `splat-layers-gpu`.
pub struct GpuLayerSplat {
    ctx: GpuContext,
    opts: LayerOptions,
    adaptive: bool,
    setup: wgpu::ComputePipeline,
    scan_blocks: wgpu::ComputePipeline,
    scan_sums: wgpu::ComputePipeline,
    scan_apply: wgpu::ComputePipeline,
    scatter: wgpu::ComputePipeline,
    raster: wgpu::ComputePipeline,
    fill: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    params: wgpu::Buffer,
    samples: GrowBuffer,
    colors: GrowBuffer,
    quads: GrowBuffer,
    work: GrowBuffer,
    list: GrowBuffer,
    out: GrowBuffer,
    count: GrowBuffer,
    frame: GrowBuffer,
    dummy: GrowBuffer,
    /// Per sample its slab-shared corner depths (16 bytes), found on the CPU.
    shared: GrowBuffer,
    corners: SlabCorners,
    /// Whether the uploaded scene has shared corners.
    has_shared: bool,
    staging: GrowBuffer,
    /// List entries (all pixels together) the list buffer is sized for.
    cap: u32,
    bind_groups: Option<[wgpu::BindGroup; 2]>,
    uploaded: Option<SceneKey>,
    uploads: u64,
    /// The scene and frame camera whose composite `frame` holds.
    frame_of: Option<(SceneKey, Camera)>,
    redraws: u64,
    last_error: Option<String>,
    /// The older frames: what to draw after the newest (the CPU's own residuals; taken
    /// out while in use).
    older_sets: Option<OlderSets>,
    /// Per older-frame slot its samples and colors on the GPU and the scene they hold.
    older: Vec<OlderBuffers>,
    /// Per older frame drawn in the last call its bind group (uniform slot `2 + i`).
    older_groups: Vec<wgpu::BindGroup>,
    /// The CPU threads and scratch of the crack pass.
    crack_threads: Threads,
    cracks: CrackScratch,
}

/// One older frame's samples and colors on the GPU.
struct OlderBuffers {
    samples: GrowBuffer,
    colors: GrowBuffer,
    uploaded: Option<SceneKey>,
}

impl std::fmt::Debug for GpuLayerSplat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuLayerSplat")
            .field("adapter", &self.ctx.describe())
            .field("opts", &self.opts)
            .field("adaptive", &self.adaptive)
            .field("uploads", &self.uploads)
            .finish()
    }
}

/// What one [`GpuLayerSplat`] call draws: the frame composite, the new camera's image.
#[derive(Clone, Copy, Debug)]
struct Plan {
    draw_frame: bool,
    draw_view: bool,
    fill: bool,
}

impl GpuLayerSplat {
    /// Opens the best adapter there is (see [`GpuContext::new`]) with the CPU's default
    /// options.
    pub fn new() -> Result<GpuLayerSplat, GpuError> {
        Self::with_context(GpuContext::new()?, LayerOptions::DEFAULT)
    }

    /// On the adapter whose name contains `name` (any adapter when `None`).
    pub fn with_adapter(name: Option<&str>) -> Result<GpuLayerSplat, GpuError> {
        Self::with_context(GpuContext::with_adapter(name)?, LayerOptions::DEFAULT)
    }

    /// A layered splatter on an already opened device, drawing with `opts` (those of the CPU's
    /// `LayerSplat::with_options`).
    pub fn with_context(ctx: GpuContext, opts: LayerOptions) -> Result<GpuLayerSplat, GpuError> {
        // Nine storage buffers in one stage: one more than WebGPU's default limit, within what
        // every native backend offers (the device is opened with the adapter's own limits).
        if ctx.limits.max_storage_buffers_per_shader_stage < STORAGE_BINDINGS {
            return Err(GpuError::Device(format!(
                "the layered splatter needs {STORAGE_BINDINGS} storage buffers per shader stage, this adapter offers {}",
                ctx.limits.max_storage_buffers_per_shader_stage
            )));
        }
        let scope = ctx.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let consts = format!("const LIST: u32 = {LIST}u;\nconst SCAN_BLOCK: u32 = {SCAN_BLOCK}u;\n");
        let module = ctx.device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("layer_splat.wgsl"),
            source: wgpu::ShaderSource::Wgsl(
                crate::layout::shader_with_scan(&(consts + include_str!("layer_splat.wgsl")), ctx.scan()).into(),
            ),
        });
        let buffer = |binding: u32, ty: wgpu::BufferBindingType| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer { ty, has_dynamic_offset: false, min_binding_size: None },
            count: None,
        };
        let read = wgpu::BufferBindingType::Storage { read_only: true };
        let write = wgpu::BufferBindingType::Storage { read_only: false };
        let bgl = ctx.device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("layer splat"),
            entries: &[
                buffer(0, wgpu::BufferBindingType::Uniform),
                buffer(1, read),
                buffer(2, read),
                buffer(3, write),
                buffer(4, write),
                buffer(5, write),
                buffer(6, write),
                buffer(7, write),
                buffer(8, read),
                buffer(9, read),
            ],
        });
        let layout = ctx.device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("layer splat"),
            bind_group_layouts: &[Some(&bgl)],
            immediate_size: 0,
        });
        let pipe = |entry: &'static str| {
            ctx.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        let (setup, scatter, raster, fill) = (pipe("setup"), pipe("scatter"), pipe("raster"), pipe("fill"));
        let (scan_blocks, scan_sums, scan_apply) = (pipe("scan_blocks"), pipe("scan_sums"), pipe("scan_apply"));
        let params = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("layer splat params"),
            size: SLOTS * SLOT,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Shader(e.to_string()));
        }
        let st = wgpu::BufferUsages::STORAGE;
        let st_dst = st | wgpu::BufferUsages::COPY_DST;
        let st_all = st_dst | wgpu::BufferUsages::COPY_SRC;
        Ok(GpuLayerSplat {
            opts,
            adaptive: false,
            setup,
            scan_blocks,
            scan_sums,
            scan_apply,
            scatter,
            raster,
            fill,
            layout: bgl,
            params,
            samples: GrowBuffer::new("layer samples", st_dst),
            colors: GrowBuffer::new("layer colors", st_dst),
            quads: GrowBuffer::new("layer footprints", st),
            work: GrowBuffer::new("layer counts and offsets", st_all),
            list: GrowBuffer::new("layer pixel lists", st),
            out: GrowBuffer::new("layer pixels", st_all),
            count: GrowBuffer::new("layer counts", st),
            frame: GrowBuffer::new("layer frame", st_all),
            dummy: GrowBuffer::new("layer dummy", st),
            shared: GrowBuffer::new("layer shared corners", st_dst),
            corners: SlabCorners::new(0),
            has_shared: false,
            staging: GrowBuffer::new("layer readback", wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST),
            cap: 0,
            bind_groups: None,
            uploaded: None,
            uploads: 0,
            frame_of: None,
            redraws: 0,
            last_error: None,
            older_sets: Some(OlderSets::new(0)),
            older: Vec::new(),
            older_groups: Vec::new(),
            crack_threads: Threads::new(0),
            cracks: CrackScratch::default(),
            ctx,
        })
    }

    /// The device context.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// The options it draws with.
    pub fn options(&self) -> LayerOptions {
        self.opts
    }

    /// How many times a scene was uploaded (drawing the same scene again uploads nothing).
    pub fn scene_uploads(&self) -> u64 {
        self.uploads
    }

    /// How many draws were repeated because the pixels' lists needed more room than the last
    /// frame's.
    pub fn list_regrowths(&self) -> u64 {
        self.redraws
    }

    /// Uploads the scene, sizes the buffers (the footprints for at least `quads_for` samples:
    /// the older frames'), writes the uniforms; what to draw.
    fn prepare(&mut self, scene: &Scene, camera: &Camera, quads_for: u64) -> Result<Plan, GpuError> {
        camera.validate(MAX_GPU_VIEWPORT).map_err(GpuError::BadCamera)?;
        let n = check_scene(scene)?;
        let key = SceneKey::of(scene);
        let len = scene.samples.len() as u64;
        let mut changed = self.samples.ensure(&self.ctx, len * 8)?;
        changed |= self.colors.ensure(&self.ctx, len * 4)?;
        changed |= self.shared.ensure(&self.ctx, (len * 16).max(16))?;
        if changed {
            self.uploaded = None;
        }
        if self.uploaded != Some(key) {
            if n > 0 {
                self.ctx.queue.write_buffer(self.samples.get()?, 0, bytemuck::cast_slice(&scene.samples));
                self.ctx.queue.write_buffer(self.colors.get()?, 0, bytemuck::cast_slice(&scene.colors));
            }
            // Watertight slabs: the corners the CPU shares, where it shares them.
            self.has_shared = false;
            if self.opts.shares_corners() {
                let corners = self.corners.corners(scene, self.opts.watertight);
                if n > 0 && corners.len() == scene.samples.len() {
                    self.ctx.queue.write_buffer(self.shared.get()?, 0, bytemuck::cast_slice(corners));
                    self.has_shared = true;
                }
            }
            self.uploaded = Some(key);
            self.uploads += 1;
        }
        let fc = scene.header.camera;
        let fill = self.opts.fill && fc.validate(volwarp_cpu_tracer::MAX_VIEWPORT).is_ok();
        let at_frame = fill && *camera == fc;
        let (w, h) = (camera.width, camera.height);
        let (fw, fh) = if fill { (fc.width, fc.height) } else { (0, 0) };
        let px = (w as u64 * h as u64).max(fw as u64 * fh as u64);
        changed |= self.quads.ensure(&self.ctx, len.max(quads_for) * QUAD_BYTES)?;
        changed |= self.work.ensure(&self.ctx, 4 * work_layout(w, h).0.max(work_layout(fw, fh).0))?;
        if self.cap == 0 {
            self.cap = (2 * n).max(4096);
        }
        changed |= self.list.ensure(&self.ctx, 4 * self.cap as u64)?;
        changed |= self.out.ensure(&self.ctx, 4 * w as u64 * h as u64)?;
        changed |= self.count.ensure(&self.ctx, 4 * px)?;
        changed |= self.dummy.ensure(&self.ctx, 4)?;
        if self.frame.ensure(&self.ctx, 4 * fw as u64 * fh as u64)? {
            changed = true;
            self.frame_of = None;
        }
        self.staging.ensure(&self.ctx, 4 * w as u64 * h as u64 + 256)?;
        if changed {
            self.bind_groups = None;
        }
        let draw_frame = fill && self.frame_of != Some((key, fc));
        let plan = Plan { draw_frame, draw_view: !at_frame, fill };

        let grown = self.opts.half_side(self.adaptive, &fc, camera);
        let size = std::mem::size_of::<LayerParams>();
        let mut slots = [0u8; 2 * SLOT as usize];
        if draw_frame {
            let p = params(scene, &fc, &fc, &self.opts, self.opts.own, self.cap, false);
            slots[..size].copy_from_slice(bytemuck::bytes_of(&p));
        }
        if plan.draw_view {
            let p = params(scene, camera, &fc, &self.opts, grown, self.cap, self.has_shared);
            slots[SLOT as usize..SLOT as usize + size].copy_from_slice(bytemuck::bytes_of(&p));
        }
        self.ctx.queue.write_buffer(&self.params, 0, &slots);

        if self.bind_groups.is_none() {
            // Slot 0 draws the frame's composite into `frame`; slot 1 the new view into `out`,
            // reading `frame` for the fill.
            let make = |slot: u64| {
                let (target, stale) = if slot == 0 { (&self.frame, &self.dummy) } else { (&self.out, &self.frame) };
                self.bind_group(slot, &self.samples, &self.colors, target, stale)
            };
            self.bind_groups = Some([make(0)?, make(1)?]);
        }
        Ok(plan)
    }

    /// The bind group of uniform slot `slot`: the scene's `samples` and `colors`, drawing into
    /// `target` with `stale` as the fill's frame composite.
    fn bind_group(
        &self,
        slot: u64,
        samples: &GrowBuffer,
        colors: &GrowBuffer,
        target: &GrowBuffer,
        stale: &GrowBuffer,
    ) -> Result<wgpu::BindGroup, GpuError> {
        let storage = [
            (1, samples),
            (2, colors),
            (3, &self.quads),
            (4, &self.work),
            (5, &self.list),
            (6, target),
            (7, &self.count),
            (8, stale),
            (9, &self.shared),
        ];
        let uniform = (&self.params, slot * SLOT, std::mem::size_of::<LayerParams>() as u64);
        crate::buffers::slot_bind_group(&self.ctx, "layer splat", &self.layout, uniform, &storage)
    }

    /// Writes the uniforms of the older frames' draws (`sets`, in order) for `camera`, uploads
    /// their samples where they changed and makes their bind groups (after [`Self::prepare`]).
    fn prepare_older(&mut self, sets: &[&Scene], camera: &Camera) -> Result<(), GpuError> {
        self.older_groups.clear();
        while self.older.len() < sets.len() {
            let st_dst = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
            self.older.push(OlderBuffers {
                samples: GrowBuffer::new("older layer samples", st_dst),
                colors: GrowBuffer::new("older layer colors", st_dst),
                uploaded: None,
            });
        }
        for (i, &o) in sets.iter().enumerate() {
            let b = &mut self.older[i];
            let len = o.samples.len() as u64;
            let key = SceneKey::of(o);
            let grew = b.samples.ensure(&self.ctx, len * 8)? | b.colors.ensure(&self.ctx, len * 4)?;
            if grew || b.uploaded != Some(key) {
                self.ctx.queue.write_buffer(b.samples.get()?, 0, bytemuck::cast_slice(&o.samples));
                self.ctx.queue.write_buffer(b.colors.get()?, 0, bytemuck::cast_slice(&o.colors));
                b.uploaded = Some(key);
            }
            // Older frames grow with their own warp, and never share corners (the CPU's rule).
            let oc = o.header.camera;
            let g = self.opts.half_side(self.adaptive, &oc, camera);
            let p = LayerParams { only_empty: 1, ..params(o, camera, &oc, &self.opts, g, self.cap, false) };
            let slot = 2 + i as u64;
            self.ctx.queue.write_buffer(&self.params, slot * SLOT, bytemuck::bytes_of(&p));
            let b = &self.older[i];
            let group = self.bind_group(slot, &b.samples, &b.colors, &self.out, &self.frame)?;
            self.older_groups.push(group);
        }
        Ok(())
    }

    /// Encodes one draw (the four passes) of a `w × h` viewport with the bind group `bg`: a
    /// first draw clears the spans, an older frame's (`keep_spans`) adds to them.
    fn encode_draw(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        bg: &wgpu::BindGroup,
        w: u32,
        h: u32,
        n: u32,
        keep_spans: bool,
    ) {
        let Ok(work) = self.work.get() else { return };
        let (words, off_spans, off_sums) = work_layout(w, h);
        // The counts, the spans (zero: empty) and the block sums.
        if keep_spans {
            encoder.clear_buffer(work, 4 * COUNTS as u64, Some(4 * (off_spans - COUNTS) as u64));
            encoder.clear_buffer(work, 4 * off_sums as u64, Some(4 * (words - off_sums as u64)));
        } else {
            encoder.clear_buffer(work, 4 * COUNTS as u64, Some(4 * (words - COUNTS as u64)));
        }
        let (gx, gy) = grid(&self.ctx, n.div_ceil(64));
        let mut pass = encoder
            .begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("layer splat"), timestamp_writes: None });
        pass.set_bind_group(0, bg, &[]);
        if n > 0 {
            pass.set_pipeline(&self.setup);
            pass.dispatch_workgroups(gx, gy, 1);
        }
        let (bx, by) = grid(&self.ctx, (w * h).div_ceil(SCAN_BLOCK));
        pass.set_pipeline(&self.scan_blocks);
        pass.dispatch_workgroups(bx, by, 1);
        pass.set_pipeline(&self.scan_sums);
        pass.dispatch_workgroups(1, 1, 1);
        pass.set_pipeline(&self.scan_apply);
        pass.dispatch_workgroups(bx, by, 1);
        if n > 0 {
            pass.set_pipeline(&self.scatter);
            pass.dispatch_workgroups(gx, gy, 1);
        }
        pass.set_pipeline(&self.raster);
        pass.dispatch_workgroups(w.div_ceil(8), h.div_ceil(8), 1);
    }

    /// Encodes everything `plan` asks for (the work buffer's first word cleared first): the
    /// frame's composite, the new view of the newest frame, each older frame of
    /// [`Self::prepare_older`] into the pixels still empty, then the fill.
    fn encode(&self, encoder: &mut wgpu::CommandEncoder, plan: Plan, scene: &Scene, camera: &Camera, older: &[u32]) {
        let Some(bgs) = self.bind_groups.as_ref() else { return };
        if let Ok(work) = self.work.get() {
            encoder.clear_buffer(work, 0, Some(4 * COUNTS as u64));
        }
        let n = scene.samples.len() as u32;
        let fc = scene.header.camera;
        if plan.draw_frame {
            self.encode_draw(encoder, &bgs[0], fc.width, fc.height, n, false);
        }
        if plan.draw_view {
            let (w, h) = (camera.width, camera.height);
            self.encode_draw(encoder, &bgs[1], w, h, n, false);
            for (bg, &on) in self.older_groups.iter().zip(older) {
                self.encode_draw(encoder, bg, w, h, on, true);
            }
            if plan.fill {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("layer fill"),
                    timestamp_writes: None,
                });
                pass.set_bind_group(0, &bgs[1], &[]);
                pass.set_pipeline(&self.fill);
                pass.dispatch_workgroups(w.div_ceil(8), h.div_ceil(8), 1);
            }
        }
    }

    /// Renders `scene` (a layered frame's samples, built or not) for `camera` into `out`
    /// (resized to the viewport), reading the image back. Errors as
    /// [`crate::GpuTracer::try_render`]: a background image and a typed error.
    pub fn try_render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) -> Result<(), GpuError> {
        self.try_render_set(&[scene], camera, out)
    }

    /// Renders the newest of `scenes` (newest first) for `camera` and fills what it leaves
    /// uncovered from the older ones, as the CPU's `LayerSplat::render_set` does (the
    /// multi-frame filling: each older frame's residual, made on the CPU, drawn into the
    /// pixels still empty, newest first, then the fill). No scene: an empty image. Errors as
    /// [`Self::try_render`].
    pub fn try_render_set(&mut self, scenes: &[&Scene], camera: &Camera, out: &mut Image) -> Result<(), GpuError> {
        let Some((&scene, older)) = scenes.split_first() else {
            out.reset_for_unusable(camera, 0);
            return Ok(());
        };
        if let Err(e) = camera.validate(MAX_GPU_VIEWPORT) {
            out.reset_for_unusable(camera, MAX_GPU_VIEWPORT);
            return Err(GpuError::BadCamera(e));
        }
        out.reset_for(camera);
        let mut older_sets = self.older_sets.take().unwrap_or_else(|| OlderSets::new(0));
        // The older frames only count where the newest frame can be drawn (the CPU's order).
        let sets: Vec<&Scene> = if check_scene(scene).is_err() {
            Vec::new()
        } else {
            let sets = older_sets.sets(scene, older, camera, self.opts.fill);
            sets.into_iter().filter(|o| check_scene(o).is_ok_and(|n| n > 0)).collect()
        };
        let scope = self.ctx.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let result = self.render_inner(scene, &sets, camera, out);
        drop(sets);
        self.older_sets = Some(older_sets);
        let err = pollster::block_on(scope.pop());
        if let Some(e) = err.map(|e| e.to_string()).or_else(|| self.ctx.take_error()) {
            out.pixels.fill(BACKGROUND);
            self.frame_of = None;
            return Err(GpuError::Wgpu(e));
        }
        if result.is_err() {
            out.pixels.fill(BACKGROUND);
            self.frame_of = None;
        }
        result
    }

    fn render_inner(
        &mut self,
        scene: &Scene,
        sets: &[&Scene],
        camera: &Camera,
        out: &mut Image,
    ) -> Result<(), GpuError> {
        let sets = &sets[..sets.len().min(MAX_OLDER)];
        let older_n: Vec<u32> = sets.iter().map(|o| o.samples.len() as u32).collect();
        let quads_for = older_n.iter().copied().max().unwrap_or(0) as u64;
        loop {
            let plan = self.prepare(scene, camera, quads_for)?;
            let older: &[u32] = if plan.draw_view { &older_n } else { &[] };
            if plan.draw_view {
                self.prepare_older(sets, camera)?;
            }
            let bytes = 4 * camera.width as u64 * camera.height as u64;
            let mut encoder = self.ctx.device.create_command_encoder(&Default::default());
            self.encode(&mut encoder, plan, scene, camera, older);
            let src = if plan.draw_view { self.out.get()? } else { self.frame.get()? };
            encoder.copy_buffer_to_buffer(src, 0, self.staging.get()?, 0, bytes);
            encoder.copy_buffer_to_buffer(self.work.get()?, 0, self.staging.get()?, bytes, 4);
            self.ctx.queue.submit([encoder.finish()]);
            let total = read_mapped(&self.ctx, self.staging.get()?, bytes + 4, |data| {
                let (px, total) = data.split_at(bytes as usize);
                out.pixels.copy_from_slice(bytemuck::cast_slice(px));
                u32::from_le_bytes([total[0], total[1], total[2], total[3]])
            })?;
            if total <= self.cap {
                if plan.fill {
                    self.frame_of = Some((SceneKey::of(scene), scene.header.camera));
                }
                if plan.draw_view {
                    let fc = scene.header.camera;
                    close_cracks_of(&self.opts, &fc, camera, out, &mut self.cracks, &self.crack_threads);
                }
                return Ok(());
            }
            // The lists overflowed: grow them and draw again.
            let limit = (self.ctx.max_binding() / 4).min(u32::MAX as u64) as u32;
            if total > limit {
                return Err(GpuError::TooLarge {
                    what: "layer pixel lists",
                    bytes: 4 * total as u64,
                    limit: 4 * limit as u64,
                });
            }
            self.cap = total.saturating_add(total / 4).min(limit);
            self.frame_of = None;
            self.redraws += 1;
        }
    }

    /// Draws `frames` images of `scene` for `camera` back to back without reading them back
    /// (the frame composite, where the fill needs it, drawn once before), and returns the time
    /// from first submit to completion.
    pub fn draw_only(&mut self, scene: &Scene, camera: &Camera, frames: u32) -> Result<Duration, GpuError> {
        let mut img = Image::new(1, 1);
        self.try_render(scene, camera, &mut img)?;
        let plan = self.prepare(scene, camera, 0)?;
        self.older_groups.clear();
        self.ctx.wait()?;
        let t0 = Instant::now();
        for _ in 0..frames {
            let mut encoder = self.ctx.device.create_command_encoder(&Default::default());
            self.encode(&mut encoder, plan, scene, camera, &[]);
            self.ctx.queue.submit([encoder.finish()]);
        }
        self.ctx.wait()?;
        Ok(t0.elapsed())
    }
}

impl Renderer for GpuLayerSplat {
    fn kind(&self) -> RendererKind {
        RendererKind::SplatLayersGpu
    }

    fn set_adaptive_radius(&mut self, on: bool) -> bool {
        self.adaptive = on;
        true
    }

    /// Renders; a failure leaves the background image and is logged once per distinct error.
    fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) {
        self.render_set(&[scene], camera, out);
    }

    fn keeps_frames(&self) -> bool {
        true
    }

    /// [`GpuLayerSplat::try_render_set`]; a failure leaves the background image and is logged
    /// once per distinct error.
    fn render_set(&mut self, scenes: &[&Scene], camera: &Camera, out: &mut Image) {
        match self.try_render_set(scenes, camera, out) {
            Ok(()) => self.last_error = None,
            Err(e) => {
                let msg = e.to_string();
                if self.last_error.as_deref() != Some(msg.as_str()) {
                    log::error!("GPU layered splatter: {msg}");
                    self.last_error = Some(msg);
                }
            }
        }
    }
}
