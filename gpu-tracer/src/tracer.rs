//! The GPU sphere tracer: the paper's client-side first-hit ray tracing of the object-space
//! samples, as a WGSL compute shader (`trace.wgsl`) over the core LBVH bytes.

use crate::buffers::{read_mapped, GrowBuffer};
use crate::lbvh::{LbvhBuilder, Outputs};
use crate::{GpuContext, GpuError};
use bytemuck::{Pod, Zeroable};
use std::time::{Duration, Instant};
use volwarp_core::renderer::{Image, Renderer, BACKGROUND};
use volwarp_core::sample::Dequantizer;
use volwarp_core::wire::Frame;
use volwarp_core::RendererKind;
use volwarp_core::{Camera, RayBasis, Scene, SceneError};

/// Largest viewport side the GPU renderers accept (the CPU renderers':
/// `volwarp_cpu_tracer::MAX_VIEWPORT`, which bounds what they allocate).
pub const MAX_GPU_VIEWPORT: u32 = 16384;

/// The trace shader's uniform block: the core [`RayBasis`] bytes as they are, then the
/// dequantizer and the sizes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(crate) struct TraceParams {
    pub basis: RayBasis,
    /// Dequantizer minimum; w = 0.0 ([`deq_uniforms`]).
    pub deq_min: [f32; 4],
    /// Dequantizer step; w = radius unit.
    pub deq_step: [f32; 4],
    pub width: u32,
    pub height: u32,
    pub n: u32,
    pub background: u32,
}

/// The dequantizer as the shaders' two uniform vectors: `min.xyz` with `w = 0.0`, and
/// `step.xyz` with `w` = the radius unit. `sample_center` xors the bits of the product
/// `q · step` with those of that `0.0`, a value the shader compiler cannot know: so it must
/// round the product before the add and cannot fuse the two into one `fma` (NVIDIA's compiler
/// does, and the CPU rounds both), and the GPU's sample centers, leaf boxes and fitted trees
/// equal the CPU's bit for bit.
pub(crate) fn deq_uniforms(d: &Dequantizer) -> ([f32; 4], [f32; 4]) {
    ([d.min.x, d.min.y, d.min.z, 0.0], [d.step.x, d.step.y, d.step.z, d.radius_unit])
}

/// What identifies an uploaded scene: where its arrays live, their length, the frame's sequence
/// number and a fingerprint of strided elements (so a new scene that reuses the same
/// allocation is not mistaken for the old one).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct SceneKey {
    samples: usize,
    nodes: usize,
    n: usize,
    seq: u64,
    fingerprint: u64,
}

impl SceneKey {
    pub(crate) fn of(scene: &Scene) -> SceneKey {
        let n = scene.samples.len();
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut mix = |v: u64| {
            h = (h ^ v).wrapping_mul(0x0000_0100_0000_01b3);
            h ^= h >> 29;
        };
        for v in scene.deq.min.to_array().iter().chain(scene.deq.step.to_array().iter()) {
            mix(v.to_bits() as u64);
        }
        mix(scene.deq.radius_unit.to_bits() as u64);
        let step = (n / 64).max(1);
        for i in (0..n).step_by(step) {
            mix(scene.samples[i]);
            mix(scene.colors.get(i).copied().unwrap_or(0) as u64);
            if let Some(node) = scene.nodes.get(i) {
                let words: [u64; 4] = bytemuck::cast(*node);
                mix(words[0]);
                mix(words[1]);
            }
        }
        if let Some(last) = scene.samples.last() {
            mix(*last);
        }
        SceneKey {
            samples: scene.samples.as_ptr() as usize,
            nodes: scene.nodes.as_ptr() as usize,
            n,
            seq: scene.header.seq,
            fingerprint: h,
        }
    }
}

pub use crate::lbvh::BuildTiming;

/// The wgpu compute tracer. Implements [`Renderer`] as `spheres-gpu`.
///
/// Scene buffers (nodes, samples, colors), the output and the readback buffer are reused
/// across frames and grown only when a frame needs more; a scene is uploaded once and then
/// rendered for any number of cameras.
pub struct GpuTracer {
    ctx: GpuContext,
    pipeline: wgpu::ComputePipeline,
    params: wgpu::Buffer,
    pub(crate) nodes: GrowBuffer,
    pub(crate) samples: GrowBuffer,
    pub(crate) colors: GrowBuffer,
    out: GrowBuffer,
    staging: GrowBuffer,
    bind_group: Option<wgpu::BindGroup>,
    uploaded: Option<SceneKey>,
    uploads: u64,
    builder: Option<LbvhBuilder>,
    last_build: BuildTiming,
    last_error: Option<String>,
}

impl std::fmt::Debug for GpuTracer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuTracer").field("adapter", &self.ctx.describe()).field("uploads", &self.uploads).finish()
    }
}

const STORAGE_DST: wgpu::BufferUsages = wgpu::BufferUsages::STORAGE.union(wgpu::BufferUsages::COPY_DST);

impl GpuTracer {
    /// Opens the best adapter there is (see [`GpuContext::new`]) and compiles the shaders.
    pub fn new() -> Result<GpuTracer, GpuError> {
        Self::with_context(GpuContext::new()?)
    }

    /// On the adapter whose name contains `name` (case-insensitive; `None`: the best there is,
    /// see [`GpuContext::with_adapter`]); a clear error when none matches or none exists.
    pub fn with_adapter(name: Option<&str>) -> Result<GpuTracer, GpuError> {
        Self::with_context(GpuContext::with_adapter(name)?)
    }

    /// A tracer on an already opened device.
    pub fn with_context(ctx: GpuContext) -> Result<GpuTracer, GpuError> {
        let scope = ctx.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = ctx.device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("trace.wgsl"),
            source: wgpu::ShaderSource::Wgsl(crate::layout::shader(include_str!("trace.wgsl")).into()),
        });
        let pipeline = ctx.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("trace"),
            layout: None,
            module: &module,
            entry_point: Some("trace"),
            compilation_options: Default::default(),
            cache: None,
        });
        let params = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("trace params"),
            size: std::mem::size_of::<TraceParams>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Shader(e.to_string()));
        }
        let storage_src = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC;
        Ok(GpuTracer {
            pipeline,
            params,
            nodes: GrowBuffer::new("lbvh nodes", STORAGE_DST | wgpu::BufferUsages::COPY_SRC),
            samples: GrowBuffer::new("sorted samples", STORAGE_DST | wgpu::BufferUsages::COPY_SRC),
            colors: GrowBuffer::new("sorted colors", STORAGE_DST | wgpu::BufferUsages::COPY_SRC),
            out: GrowBuffer::new("output pixels", storage_src),
            staging: GrowBuffer::new("readback", wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST),
            bind_group: None,
            uploaded: None,
            uploads: 0,
            builder: None,
            last_build: BuildTiming::default(),
            last_error: None,
            ctx,
        })
    }

    /// The adapter in use (name, backend, device type, driver).
    pub fn adapter_info(&self) -> &wgpu::AdapterInfo {
        &self.ctx.info
    }

    /// The device context.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// How many times a scene was uploaded (rendering the same scene again uploads nothing).
    pub fn scene_uploads(&self) -> u64 {
        self.uploads
    }

    /// How many times any of the tracer's buffers was (re)allocated.
    pub fn buffer_allocations(&self) -> u32 {
        [&self.nodes, &self.samples, &self.colors, &self.out, &self.staging].iter().map(|b| b.reallocations).sum()
    }

    /// Timings of the last [`GpuTracer::build_scene`].
    pub fn last_build_timing(&self) -> BuildTiming {
        self.last_build
    }

    pub(crate) fn check_scene(scene: &Scene) -> Result<u32, GpuError> {
        scene.check().map_err(|e| {
            GpuError::BadScene(match e {
                SceneError::CountMismatch => "sample, color and node counts do not match",
                SceneError::TooManySamples => "more than 2^30 samples",
                SceneError::NonFiniteDequantizer => "dequantizer is not finite",
            })
        })
    }

    fn ensure_scene_buffers(&mut self, n: usize) -> Result<(), GpuError> {
        let mut changed = self.nodes.ensure(&self.ctx, n.saturating_sub(1) as u64 * 32)?;
        changed |= self.samples.ensure(&self.ctx, n as u64 * 8)?;
        changed |= self.colors.ensure(&self.ctx, n as u64 * 4)?;
        if changed {
            self.bind_group = None;
            self.uploaded = None;
        }
        Ok(())
    }

    /// Uploads the scene unless it is the one already on the GPU.
    fn upload(&mut self, scene: &Scene) -> Result<(), GpuError> {
        let key = SceneKey::of(scene);
        if self.uploaded == Some(key) {
            return Ok(());
        }
        self.ensure_scene_buffers(scene.samples.len())?;
        let q = &self.ctx.queue;
        if !scene.nodes.is_empty() {
            q.write_buffer(self.nodes.get()?, 0, bytemuck::cast_slice(&scene.nodes));
        }
        if !scene.samples.is_empty() {
            q.write_buffer(self.samples.get()?, 0, bytemuck::cast_slice(&scene.samples));
            q.write_buffer(self.colors.get()?, 0, bytemuck::cast_slice(&scene.colors));
        }
        self.uploaded = Some(key);
        self.uploads += 1;
        log::debug!("uploaded scene of {} samples", scene.samples.len());
        Ok(())
    }

    fn prepare(&mut self, scene: &Scene, camera: &Camera) -> Result<(u32, u32), GpuError> {
        camera.validate(MAX_GPU_VIEWPORT).map_err(GpuError::BadCamera)?;
        let n = Self::check_scene(scene)?;
        self.upload(scene)?;
        let (w, h) = (camera.width, camera.height);
        let bytes = w as u64 * h as u64 * 4;
        if self.out.ensure(&self.ctx, bytes)? {
            self.bind_group = None;
        }
        self.staging.ensure(&self.ctx, bytes)?;
        let (deq_min, deq_step) = deq_uniforms(&scene.deq);
        let params = TraceParams {
            basis: camera.ray_basis(),
            deq_min,
            deq_step,
            width: w,
            height: h,
            n,
            background: BACKGROUND,
        };
        self.ctx.queue.write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        if self.bind_group.is_none() {
            let layout = self.pipeline.get_bind_group_layout(0);
            let entries = [
                (0, &self.params),
                (1, self.nodes.get()?),
                (2, self.samples.get()?),
                (3, self.colors.get()?),
                (4, self.out.get()?),
            ];
            let entries: Vec<wgpu::BindGroupEntry> = entries
                .iter()
                .map(|(b, buf)| wgpu::BindGroupEntry { binding: *b, resource: buf.as_entire_binding() })
                .collect();
            self.bind_group = Some(self.ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("trace"),
                layout: &layout,
                entries: &entries,
            }));
        }
        Ok((w, h))
    }

    fn encode_trace(&self, encoder: &mut wgpu::CommandEncoder, w: u32, h: u32) -> Result<(), GpuError> {
        let bg = self.bind_group.as_ref().ok_or(GpuError::Internal("bind group missing"))?;
        let mut pass =
            encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("trace"), timestamp_writes: None });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, bg, &[]);
        pass.dispatch_workgroups(w.div_ceil(8), h.div_ceil(8), 1);
        Ok(())
    }

    /// Renders `scene` for `camera` into `out` (resized to the viewport), reading the image back.
    ///
    /// Like the CPU renderers, an unusable camera whose viewport is still within
    /// [`MAX_GPU_VIEWPORT`] leaves a background image of that size, one with an unusable viewport an
    /// empty (0×0) image: a bad camera never makes it allocate.
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
        let (w, h) = self.prepare(scene, camera)?;
        let bytes = w as u64 * h as u64 * 4;
        let mut encoder = self.ctx.device.create_command_encoder(&Default::default());
        self.encode_trace(&mut encoder, w, h)?;
        encoder.copy_buffer_to_buffer(self.out.get()?, 0, self.staging.get()?, 0, bytes);
        self.ctx.queue.submit([encoder.finish()]);
        read_mapped(&self.ctx, self.staging.get()?, bytes, |data| {
            out.pixels.copy_from_slice(bytemuck::cast_slice(data));
        })
    }

    /// Traces `frames` images of `scene` for `camera` back to back without reading them back
    /// (the shader's throughput), and returns the time from first submit to completion.
    pub fn trace_only(&mut self, scene: &Scene, camera: &Camera, frames: u32) -> Result<Duration, GpuError> {
        let (w, h) = self.prepare(scene, camera)?;
        self.ctx.wait()?;
        let t0 = Instant::now();
        for _ in 0..frames {
            let mut encoder = self.ctx.device.create_command_encoder(&Default::default());
            self.encode_trace(&mut encoder, w, h)?;
            self.ctx.queue.submit([encoder.finish()]);
        }
        self.ctx.wait()?;
        Ok(t0.elapsed())
    }

    /// Builds the LBVH of `frame` on the GPU (Morton codes, radix sort, Karras hierarchy,
    /// bottom-up fit; see [`crate::lbvh`]) and reads it back as a [`Scene`]. The built scene
    /// stays resident: rendering the returned scene uploads nothing. Frames of 0 or 1 samples
    /// have no internal node and are built on the CPU.
    pub fn build_scene(&mut self, frame: &Frame) -> Result<Scene, GpuError> {
        let n = frame.samples.len();
        if frame.colors.len() != n {
            return Err(GpuError::BadScene("sample and color counts differ"));
        }
        if n <= 1 {
            return Ok(Scene::build(frame));
        }
        if n >= (1 << 30) {
            return Err(GpuError::BadScene("more than 2^30 samples"));
        }
        let deq = frame.header.dequantizer();
        if !(frame.header.bounds.is_valid() && deq.step.is_finite() && deq.radius_unit.is_finite()) {
            return Err(GpuError::BadScene("frame bounds or radius unit are not finite"));
        }
        if self.builder.is_none() {
            self.builder = Some(LbvhBuilder::new(&self.ctx)?);
        }
        self.ensure_scene_buffers(n)?;
        self.uploaded = None;
        let scope = self.ctx.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let result = match self.builder.as_mut() {
            Some(b) => {
                let out =
                    Outputs { samples: self.samples.get()?, colors: self.colors.get()?, nodes: self.nodes.get()? };
                b.build(&self.ctx, frame, &out, &mut self.staging)
            }
            None => Err(GpuError::Internal("no builder")),
        };
        if let Some(e) = pollster::block_on(scope.pop()).map(|e| e.to_string()).or_else(|| self.ctx.take_error()) {
            return Err(GpuError::Wgpu(e));
        }
        let (scene, timing) = result?;
        self.last_build = timing;
        self.uploaded = Some(SceneKey::of(&scene));
        Ok(scene)
    }

    /// Chooses the workgroup scan of the LBVH build's shaders (they are compiled again on the
    /// next build); an error when the device has no subgroup operations and `kind` needs them.
    /// The default, [`GpuContext::scan`], is the faster one; this is for comparing the two.
    pub fn set_scan(&mut self, kind: crate::WgScanKind) -> Result<(), GpuError> {
        self.ctx.set_scan(kind)?;
        if self.builder.as_ref().is_some_and(|b| b.scan() != kind) {
            self.builder = None;
        }
        Ok(())
    }

    /// The workgroup scan the LBVH build uses.
    pub fn scan(&self) -> crate::WgScanKind {
        self.ctx.scan()
    }

    /// Sorts `keys` on the GPU with the LBVH build's radix sort (stable, by the low 56 bits of
    /// the code in words 0 and 1; see [`LbvhBuilder::sort_keys`]): for tests and benchmarks.
    pub fn sort_keys(&mut self, keys: &[[u32; 4]]) -> Result<Vec<[u32; 4]>, GpuError> {
        if self.builder.is_none() {
            self.builder = Some(LbvhBuilder::new(&self.ctx)?);
        }
        let scope = self.ctx.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let result = match self.builder.as_mut() {
            Some(b) => b.sort_keys(&self.ctx, keys, &mut self.staging),
            None => Err(GpuError::Internal("no builder")),
        };
        if let Some(e) = pollster::block_on(scope.pop()).map(|e| e.to_string()).or_else(|| self.ctx.take_error()) {
            return Err(GpuError::Wgpu(e));
        }
        result
    }

    /// Runs only the GPU build of `frame` (its samples already uploaded by a previous
    /// [`GpuTracer::build_scene`] of the same frame), `repeats` times, and returns the mean
    /// time of one build from submit to completion.
    pub fn rebuild_only(&mut self, frame: &Frame, repeats: u32) -> Result<Duration, GpuError> {
        let n = frame.samples.len();
        if n <= 1 {
            return Ok(Duration::ZERO);
        }
        self.ensure_scene_buffers(n)?;
        self.uploaded = None;
        let out = Outputs { samples: self.samples.get()?, colors: self.colors.get()?, nodes: self.nodes.get()? };
        let b = self.builder.as_mut().ok_or(GpuError::Internal("build_scene must run first"))?;
        b.rebuild_only(&self.ctx, frame, &out, repeats)
    }
}

impl Renderer for GpuTracer {
    fn kind(&self) -> RendererKind {
        RendererKind::SpheresGpu
    }

    /// Renders; a failure leaves the background image and is logged once (again only when the
    /// error changes, so a display loop does not flood the log).
    fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) {
        match self.try_render(scene, camera, out) {
            Ok(()) => self.last_error = None,
            Err(e) => {
                let msg = e.to_string();
                if self.last_error.as_deref() != Some(msg.as_str()) {
                    log::error!("GPU tracer: {msg}");
                    self.last_error = Some(msg);
                }
            }
        }
    }
}
