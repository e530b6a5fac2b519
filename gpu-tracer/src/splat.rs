//! The exact sphere splatter on the GPU (`splat-gpu`), mirroring the CPU's
//! `volwarp_cpu_tracer::SphereSplat` (`splat.wgsl`): no BVH; each sphere's conservative
//! screen-space bound is tested pixel by pixel with the tracers' ray and ray–sphere test, and
//! each pixel keeps the nearest hit with core's tie rule, so it draws the tracers' image.
//!
//! WGSL has no 64-bit atomics, so the CPU's `(depth, id)` key is resolved in two 32-bit passes:
//! a depth pass (nearest `t` per pixel), an id pass (the smallest index among the hits at that
//! `t`), then a shading pass. The scene needs no LBVH: only samples and colors are uploaded,
//! once per scene (the same scene cache as [`crate::GpuTracer`]).

use crate::buffers::{grid, read_mapped, GrowBuffer};
use crate::tracer::{deq_uniforms, SceneKey, TraceParams, MAX_GPU_VIEWPORT};
use crate::{GpuContext, GpuError};
use bytemuck::{Pod, Zeroable};
use std::time::{Duration, Instant};
use volwarp_core::renderer::{Image, Renderer, BACKGROUND};
use volwarp_core::{Camera, RendererKind, Scene};

/// The splatter's uniform (`SplatParams` in `prelude.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(crate) struct SplatParams {
    pub trace: TraceParams,
    pub u: [f32; 4],
    pub v: [f32; 4],
    pub w: [f32; 4],
    /// Pixels per unit slope along x and y, half width, half height.
    pub px: [f32; 4],
    pub mode: u32,
    pub pad0: u32,
    pub pad1: u32,
    pub pad2: u32,
}

/// Uniform slots (depth pass, id pass) are this far apart.
const SLOT: u64 = 256;

/// The GPU exact sphere splatter. Implements [`Renderer`] as `splat-gpu`.
pub struct GpuSplat {
    ctx: GpuContext,
    splat: wgpu::ComputePipeline,
    resolve: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    params: wgpu::Buffer,
    samples: GrowBuffer,
    colors: GrowBuffer,
    depth: GrowBuffer,
    ids: GrowBuffer,
    out: GrowBuffer,
    staging: GrowBuffer,
    bind_groups: Option<[wgpu::BindGroup; 2]>,
    uploaded: Option<SceneKey>,
    uploads: u64,
    last_error: Option<String>,
}

impl std::fmt::Debug for GpuSplat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuSplat").field("adapter", &self.ctx.describe()).field("uploads", &self.uploads).finish()
    }
}

impl GpuSplat {
    /// Opens the best adapter there is (see [`GpuContext::new`]) and compiles the shaders.
    pub fn new() -> Result<GpuSplat, GpuError> {
        Self::with_context(GpuContext::new()?)
    }

    /// On the adapter whose name contains `name` (any adapter when `None`; see
    /// [`GpuContext::with_adapter`]).
    pub fn with_adapter(name: Option<&str>) -> Result<GpuSplat, GpuError> {
        Self::with_context(GpuContext::with_adapter(name)?)
    }

    /// A splatter on an already opened device.
    pub fn with_context(ctx: GpuContext) -> Result<GpuSplat, GpuError> {
        let scope = ctx.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = ctx.device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("splat.wgsl"),
            source: wgpu::ShaderSource::Wgsl(crate::layout::shader(include_str!("splat.wgsl")).into()),
        });
        // One explicit layout for both entry points (derived layouts would hold only the
        // bindings each one uses), so one bind group serves both.
        let buffer = |binding: u32, ty: wgpu::BufferBindingType| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer { ty, has_dynamic_offset: false, min_binding_size: None },
            count: None,
        };
        let read = wgpu::BufferBindingType::Storage { read_only: true };
        let write = wgpu::BufferBindingType::Storage { read_only: false };
        let bgl = ctx.device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("splat"),
            entries: &[
                buffer(0, wgpu::BufferBindingType::Uniform),
                buffer(1, read),
                buffer(2, read),
                buffer(3, write),
                buffer(4, write),
                buffer(5, write),
            ],
        });
        let layout = ctx.device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("splat"),
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
        let (splat, resolve) = (pipe("splat"), pipe("resolve"));
        let params = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("splat params"),
            size: 2 * SLOT,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Shader(e.to_string()));
        }
        let st = wgpu::BufferUsages::STORAGE;
        let st_dst = st | wgpu::BufferUsages::COPY_DST;
        Ok(GpuSplat {
            splat,
            resolve,
            layout: bgl,
            params,
            samples: GrowBuffer::new("splat samples", st_dst),
            colors: GrowBuffer::new("splat colors", st_dst),
            depth: GrowBuffer::new("splat depth", st_dst),
            ids: GrowBuffer::new("splat ids", st_dst),
            out: GrowBuffer::new("splat pixels", st | wgpu::BufferUsages::COPY_SRC),
            staging: GrowBuffer::new("splat readback", wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST),
            bind_groups: None,
            uploaded: None,
            uploads: 0,
            last_error: None,
            ctx,
        })
    }

    /// The device context.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// How many times a scene was uploaded (rendering the same scene again uploads nothing).
    pub fn scene_uploads(&self) -> u64 {
        self.uploads
    }

    fn prepare(&mut self, scene: &Scene, camera: &Camera) -> Result<(u32, u32, u32), GpuError> {
        camera.validate(MAX_GPU_VIEWPORT).map_err(GpuError::BadCamera)?;
        let n = crate::tracer::GpuTracer::check_scene(scene)?;
        let key = SceneKey::of(scene);
        let len = scene.samples.len() as u64;
        let mut changed = self.samples.ensure(&self.ctx, len * 8)?;
        changed |= self.colors.ensure(&self.ctx, len * 4)?;
        if changed {
            self.uploaded = None;
        }
        if self.uploaded != Some(key) {
            if !scene.samples.is_empty() {
                self.ctx.queue.write_buffer(self.samples.get()?, 0, bytemuck::cast_slice(&scene.samples));
                self.ctx.queue.write_buffer(self.colors.get()?, 0, bytemuck::cast_slice(&scene.colors));
            }
            self.uploaded = Some(key);
            self.uploads += 1;
        }
        let (w, h) = (camera.width, camera.height);
        let px = w as u64 * h as u64 * 4;
        changed |= self.depth.ensure(&self.ctx, px)?;
        changed |= self.ids.ensure(&self.ctx, px)?;
        changed |= self.out.ensure(&self.ctx, px)?;
        self.staging.ensure(&self.ctx, px)?;
        if changed {
            self.bind_groups = None;
        }

        let (deq_min, deq_step) = deq_uniforms(&scene.deq);
        let trace = TraceParams {
            basis: camera.ray_basis(),
            deq_min,
            deq_step,
            width: w,
            height: h,
            n,
            background: BACKGROUND,
        };
        // `View::new` of the CPU splatter, in f64, then rounded.
        let (u, v, wv) = camera.basis();
        let tan_y = ((camera.fov_y_deg as f64).to_radians() * 0.5).tan();
        let p = SplatParams {
            trace,
            u: [u.x, u.y, u.z, 0.0],
            v: [v.x, v.y, v.z, 0.0],
            w: [wv.x, wv.y, wv.z, 0.0],
            px: [
                (0.5 * w as f64 / (tan_y * camera.aspect() as f64)) as f32,
                (0.5 * h as f64 / tan_y) as f32,
                0.5 * w as f32,
                0.5 * h as f32,
            ],
            mode: 0,
            pad0: 0,
            pad1: 0,
            pad2: 0,
        };
        let mut slots = [0u8; 2 * SLOT as usize];
        let size = std::mem::size_of::<SplatParams>();
        slots[..size].copy_from_slice(bytemuck::bytes_of(&p));
        slots[SLOT as usize..SLOT as usize + size].copy_from_slice(bytemuck::bytes_of(&SplatParams { mode: 1, ..p }));
        self.ctx.queue.write_buffer(&self.params, 0, &slots);

        if self.bind_groups.is_none() {
            let storage = [(1, &self.samples), (2, &self.colors), (3, &self.depth), (4, &self.ids), (5, &self.out)];
            let make = |slot: u64| {
                let uniform = (&self.params, slot * SLOT, size as u64);
                crate::buffers::slot_bind_group(&self.ctx, "splat", &self.layout, uniform, &storage)
            };
            self.bind_groups = Some([make(0)?, make(1)?]);
        }
        Ok((w, h, n))
    }

    fn encode(&self, encoder: &mut wgpu::CommandEncoder, w: u32, h: u32, n: u32) -> Result<(), GpuError> {
        let bgs = self.bind_groups.as_ref().ok_or(GpuError::Internal("bind groups missing"))?;
        let px = w as u64 * h as u64 * 4;
        encoder.clear_buffer(self.depth.get()?, 0, Some(px));
        encoder.clear_buffer(self.ids.get()?, 0, Some(px));
        let (gx, gy) = grid(&self.ctx, n.div_ceil(64));
        let mut pass =
            encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("splat"), timestamp_writes: None });
        if n > 0 {
            pass.set_pipeline(&self.splat);
            for bg in bgs {
                pass.set_bind_group(0, bg, &[]);
                pass.dispatch_workgroups(gx, gy, 1);
            }
        }
        pass.set_pipeline(&self.resolve);
        pass.set_bind_group(0, &bgs[0], &[]);
        pass.dispatch_workgroups(w.div_ceil(8), h.div_ceil(8), 1);
        Ok(())
    }

    /// Renders `scene` for `camera` into `out` (resized to the viewport), reading the image
    /// back. Errors as [`crate::GpuTracer::try_render`]: a background image and a typed error.
    pub fn try_render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) -> Result<(), GpuError> {
        if let Err(e) = camera.validate(MAX_GPU_VIEWPORT) {
            out.reset_for_unusable(camera, MAX_GPU_VIEWPORT);
            return Err(GpuError::BadCamera(e));
        }
        out.reset_for(camera);
        let scope = self.ctx.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let result = self.render_inner(scene, camera, out);
        let err = pollster::block_on(scope.pop());
        if let Some(e) = err.map(|e| e.to_string()).or_else(|| self.ctx.take_error()) {
            out.pixels.fill(BACKGROUND);
            return Err(GpuError::Wgpu(e));
        }
        if result.is_err() {
            out.pixels.fill(BACKGROUND);
        }
        result
    }

    fn render_inner(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) -> Result<(), GpuError> {
        let (w, h, n) = self.prepare(scene, camera)?;
        let bytes = w as u64 * h as u64 * 4;
        let mut encoder = self.ctx.device.create_command_encoder(&Default::default());
        self.encode(&mut encoder, w, h, n)?;
        encoder.copy_buffer_to_buffer(self.out.get()?, 0, self.staging.get()?, 0, bytes);
        self.ctx.queue.submit([encoder.finish()]);
        read_mapped(&self.ctx, self.staging.get()?, bytes, |data| {
            out.pixels.copy_from_slice(bytemuck::cast_slice(data));
        })
    }

    /// Splats `frames` images of `scene` for `camera` back to back without reading them back,
    /// and returns the time from first submit to completion.
    pub fn splat_only(&mut self, scene: &Scene, camera: &Camera, frames: u32) -> Result<Duration, GpuError> {
        let (w, h, n) = self.prepare(scene, camera)?;
        self.ctx.wait()?;
        let t0 = Instant::now();
        for _ in 0..frames {
            let mut encoder = self.ctx.device.create_command_encoder(&Default::default());
            self.encode(&mut encoder, w, h, n)?;
            self.ctx.queue.submit([encoder.finish()]);
        }
        self.ctx.wait()?;
        Ok(t0.elapsed())
    }
}

impl Renderer for GpuSplat {
    fn kind(&self) -> RendererKind {
        RendererKind::SplatGpu
    }

    /// Renders; a failure leaves the background image and is logged once per distinct error.
    fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) {
        match self.try_render(scene, camera, out) {
            Ok(()) => self.last_error = None,
            Err(e) => {
                let msg = e.to_string();
                if self.last_error.as_deref() != Some(msg.as_str()) {
                    log::error!("GPU splatter: {msg}");
                    self.last_error = Some(msg);
                }
            }
        }
    }
}
