//! The LBVH build on the GPU (the paper's 11 ms step): compute shaders in `lbvh.wgsl` for
//! Morton codes, a stable radix sort, Karras' per-node hierarchy and the bottom-up fit.
//!
//! **Same tree as the CPU.** The Morton code keeps all 54 bits (two `u32` words) and the sort is
//! a stable LSD radix sort (7 passes of 8 bits) of keys laid out exactly like
//! [`volwarp_core::morton::SortKey`], so the sorted order — `(code, index)` — and therefore
//! every child link equal those of [`volwarp_core::Scene::build`]. Boxes are the same
//! `sphere_box`/union arithmetic; a GPU that fuses `min + q·step` into an FMA can move a box
//! coordinate by one ulp (still a valid tree: each box is the union of its children's).
//!
//! **Sort.** Reduce-then-scan over blocks of 1024 keys (a workgroup of 256 invocations × 4
//! keys), 8-bit digits. Per pass: `radix_upsweep` counts the block's digits in a
//! workgroup-shared histogram into column `block` of a digit-major histogram; a device-wide
//! exclusive scan (multi-level block scan) gives every (digit, block) its first output
//! position; `radix_downsweep` orders the block stably by digit in shared memory (four 2-bit
//! splits, each a workgroup prefix sum) and scatters. No invocation walks keys serially beyond
//! its own four. Every workgroup prefix sum is the context's [`crate::WgScanKind`]: subgroup
//! operations where the device has them (two barriers per scan), workgroup memory and barriers
//! where not (sixteen); [`LbvhBuilder::scan`] says which was compiled.
//!
//! **Fit.** One invocation per leaf walks up; an atomic counter per node lets the second
//! arrival fit it. Fitted boxes are exchanged through a separate buffer, cleared first and read
//! and written only with atomics; WGSL atomics are relaxed, so a reader waits until each word it
//! needs has been stored (a stored word is never 0) instead of relying on an ordering WGSL does
//! not promise.

use crate::buffers::{grid, read_mapped, GrowBuffer};
use crate::{GpuContext, GpuError};
use bytemuck::{Pod, Zeroable};
use std::num::NonZeroU64;
use std::time::{Duration, Instant};
use volwarp_core::lbvh::Node;
use volwarp_core::wire::Frame;
use volwarp_core::Scene;

/// Keys per radix block, one workgroup (the shader's `SORT_BLOCK`).
const SORT_BLOCK: u32 = 1024;
/// Radix passes of 8 bits over the 54-bit code.
const PASSES: u32 = 7;
/// Values per scan block (the shader's `SCAN_BLOCK`: 256 invocations × 8).
const SCAN_BLOCK: u32 = 2048;
/// Uniform slots are this far apart (the largest `min_uniform_buffer_offset_alignment`).
const SLOT: u64 = 256;
const MAX_SLOTS: u64 = 32;

/// The build's uniform (`BuildParams` in `prelude.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(crate) struct BuildParams {
    pub n: u32,
    pub shift: u32,
    pub blocks: u32,
    pub count: u32,
    pub deq_min: [f32; 4],
    pub deq_step: [f32; 4],
}

struct Pipelines {
    make_keys: wgpu::ComputePipeline,
    radix_upsweep: wgpu::ComputePipeline,
    radix_downsweep: wgpu::ComputePipeline,
    scan_blocks: wgpu::ComputePipeline,
    scan_add: wgpu::ComputePipeline,
    reorder: wgpu::ComputePipeline,
    karras: wgpu::ComputePipeline,
    fit: wgpu::ComputePipeline,
}

/// Where a build leaves its result: the tracer's own scene buffers.
pub(crate) struct Outputs<'a> {
    /// Sorted packed samples (`n × 8` bytes).
    pub samples: &'a wgpu::Buffer,
    /// Sorted colors (`n × 4` bytes).
    pub colors: &'a wgpu::Buffer,
    /// Internal nodes (`(n − 1) × 32` bytes).
    pub nodes: &'a wgpu::Buffer,
}

/// Timings of the last GPU LBVH build.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BuildTiming {
    /// Uploading the unsorted samples and colors.
    pub upload: Duration,
    /// The compute passes (keys, sort, reorder, hierarchy, fit), submit to completion.
    pub build: Duration,
    /// Reading the sorted samples, colors and nodes back into a [`Scene`].
    pub readback: Duration,
}

/// The GPU LBVH builder: pipelines and scratch buffers, reused across frames.
pub struct LbvhBuilder {
    pipes: Pipelines,
    scan: crate::WgScanKind,
    params: wgpu::Buffer,
    samples_in: GrowBuffer,
    colors_in: GrowBuffer,
    keys: [GrowBuffer; 2],
    /// Scan levels: 0 is the radix histogram, then the block sums, then a one-word sink.
    levels: Vec<GrowBuffer>,
    parents: GrowBuffer,
    flags: GrowBuffer,
    boxes: GrowBuffer,
}

/// The counts of the scan levels for a histogram of `count` entries: each next level holds the
/// block totals of the previous one, until one block remains.
fn scan_counts(count: u32) -> Vec<u32> {
    let mut v = vec![count];
    while let Some(&last) = v.last() {
        if last <= SCAN_BLOCK {
            break;
        }
        v.push(last.div_ceil(SCAN_BLOCK));
    }
    v
}

impl LbvhBuilder {
    /// Compiles the build shaders, with the context's workgroup scan ([`GpuContext::scan`]).
    pub fn new(ctx: &GpuContext) -> Result<LbvhBuilder, GpuError> {
        let scan = ctx.scan();
        let scope = ctx.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = ctx.device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("lbvh.wgsl"),
            source: wgpu::ShaderSource::Wgsl(crate::layout::shader_with_scan(include_str!("lbvh.wgsl"), scan).into()),
        });
        let pipe = |entry: &'static str| {
            ctx.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: None,
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        let pipes = Pipelines {
            make_keys: pipe("make_keys"),
            radix_upsweep: pipe("radix_upsweep"),
            radix_downsweep: pipe("radix_downsweep"),
            scan_blocks: pipe("scan_blocks"),
            scan_add: pipe("scan_add"),
            reorder: pipe("reorder"),
            karras: pipe("karras"),
            fit: pipe("fit"),
        };
        let params = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("lbvh params"),
            size: SLOT * MAX_SLOTS,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Shader(e.to_string()));
        }
        let st = wgpu::BufferUsages::STORAGE;
        let st_dst = st | wgpu::BufferUsages::COPY_DST;
        let st_io = st_dst | wgpu::BufferUsages::COPY_SRC;
        Ok(LbvhBuilder {
            pipes,
            scan,
            params,
            samples_in: GrowBuffer::new("unsorted samples", st_dst),
            colors_in: GrowBuffer::new("unsorted colors", st_dst),
            keys: [GrowBuffer::new("sort keys A", st_io), GrowBuffer::new("sort keys B", st_io)],
            levels: Vec::new(),
            parents: GrowBuffer::new("parents", st),
            flags: GrowBuffer::new("fit flags", st_dst),
            boxes: GrowBuffer::new("fit boxes", st_dst),
        })
    }

    /// The workgroup scan its shaders were compiled with.
    pub fn scan(&self) -> crate::WgScanKind {
        self.scan
    }

    /// Sizes the sort's buffers for `n` keys and writes the uniform slots; the scan levels.
    fn prepare_sort(
        &mut self,
        ctx: &GpuContext,
        n: u32,
        deq_min: [f32; 4],
        deq_step: [f32; 4],
    ) -> Result<Vec<u32>, GpuError> {
        let blocks = n.div_ceil(SORT_BLOCK);
        let hist_count = blocks
            .checked_mul(256)
            .filter(|&c| c < u32::MAX / 2)
            .ok_or(GpuError::BadScene("too many samples for the GPU sort"))?;
        let counts = scan_counts(hist_count);
        if 1 + PASSES as u64 + counts.len() as u64 > MAX_SLOTS {
            return Err(GpuError::Internal("too many scan levels"));
        }
        let n64 = n as u64;
        self.keys[0].ensure(ctx, n64 * 16)?;
        self.keys[1].ensure(ctx, n64 * 16)?;
        while self.levels.len() < counts.len() + 1 {
            self.levels.push(GrowBuffer::new("scan level", wgpu::BufferUsages::STORAGE));
        }
        for (l, &c) in counts.iter().enumerate() {
            self.levels[l].ensure(ctx, c as u64 * 4)?;
        }
        self.levels[counts.len()].ensure(ctx, 4)?;

        let base = BuildParams { n, shift: 0, blocks, count: 0, deq_min, deq_step };
        let mut slots = vec![0u8; (SLOT * MAX_SLOTS) as usize];
        let mut put = |slot: usize, p: BuildParams| {
            let o = slot * SLOT as usize;
            slots[o..o + std::mem::size_of::<BuildParams>()].copy_from_slice(bytemuck::bytes_of(&p));
        };
        put(0, base);
        for p in 0..PASSES {
            put(1 + p as usize, BuildParams { shift: 8 * p, ..base });
        }
        for (l, &c) in counts.iter().enumerate() {
            put(1 + PASSES as usize + l, BuildParams { count: c, ..base });
        }
        ctx.queue.write_buffer(&self.params, 0, &slots);
        Ok(counts)
    }

    /// Sizes every scratch buffer for the frame's `n >= 2` samples and writes the uniform slots.
    fn prepare(&mut self, ctx: &GpuContext, frame: &Frame) -> Result<Vec<u32>, GpuError> {
        let n = frame.samples.len() as u32;
        let (deq_min, deq_step) = crate::tracer::deq_uniforms(&frame.header.dequantizer());
        let counts = self.prepare_sort(ctx, n, deq_min, deq_step)?;
        let n64 = n as u64;
        self.samples_in.ensure(ctx, n64 * 8)?;
        self.colors_in.ensure(ctx, n64 * 4)?;
        self.parents.ensure(ctx, (2 * n64 - 1) * 4)?;
        self.flags.ensure(ctx, (n64 - 1) * 4)?;
        self.boxes.ensure(ctx, (n64 - 1) * 24)?;
        Ok(counts)
    }

    fn bind(
        &self,
        ctx: &GpuContext,
        pipe: &wgpu::ComputePipeline,
        slot: u64,
        entries: &[(u32, &wgpu::Buffer)],
    ) -> wgpu::BindGroup {
        let mut e = vec![wgpu::BindGroupEntry {
            binding: 0,
            resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer: &self.params,
                offset: slot * SLOT,
                size: NonZeroU64::new(std::mem::size_of::<BuildParams>() as u64),
            }),
        }];
        e.extend(
            entries.iter().map(|(b, buf)| wgpu::BindGroupEntry { binding: *b, resource: buf.as_entire_binding() }),
        );
        ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: pipe_label(pipe),
            layout: &pipe.get_bind_group_layout(0),
            entries: &e,
        })
    }

    /// Records the whole build into `encoder`.
    fn encode(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        n: u32,
        counts: &[u32],
        out: &Outputs,
    ) -> Result<(), GpuError> {
        let (samples_out, colors_out, nodes) = (out.samples, out.colors, out.nodes);
        let p = &self.pipes;
        let keys = [self.keys[0].get()?, self.keys[1].get()?];
        let flags = self.flags.get()?;
        encoder.clear_buffer(flags, 0, Some((n as u64 - 1) * 4));
        encoder.clear_buffer(self.boxes.get()?, 0, Some((n as u64 - 1) * 24));

        let mut steps: Vec<Step> = Vec::new();
        steps.push((
            &p.make_keys,
            self.bind(ctx, &p.make_keys, 0, &[(1, self.samples_in.get()?), (4, keys[0])]),
            n.div_ceil(64),
        ));
        self.sort_steps(ctx, n, counts, &mut steps)?;
        let sorted = keys[PASSES as usize % 2];
        steps.push((
            &p.reorder,
            self.bind(
                ctx,
                &p.reorder,
                0,
                &[
                    (1, self.samples_in.get()?),
                    (2, self.colors_in.get()?),
                    (3, sorted),
                    (8, samples_out),
                    (9, colors_out),
                ],
            ),
            n.div_ceil(64),
        ));
        let parents = self.parents.get()?;
        steps.push((
            &p.karras,
            self.bind(ctx, &p.karras, 0, &[(3, sorted), (10, nodes), (11, parents)]),
            (n - 1).div_ceil(64),
        ));
        steps.push((
            &p.fit,
            self.bind(
                ctx,
                &p.fit,
                0,
                &[(8, samples_out), (10, nodes), (11, parents), (12, flags), (13, self.boxes.get()?)],
            ),
            n.div_ceil(64),
        ));

        run_steps(ctx, encoder, "lbvh build", &steps);
        Ok(())
    }

    /// The dispatches of the radix sort of the `n` keys in `keys[0]` (the result lands in
    /// `keys[PASSES % 2]`).
    fn sort_steps<'a>(
        &'a self,
        ctx: &GpuContext,
        n: u32,
        counts: &[u32],
        steps: &mut Vec<Step<'a>>,
    ) -> Result<(), GpuError> {
        let p = &self.pipes;
        let blocks = n.div_ceil(SORT_BLOCK);
        let keys = [self.keys[0].get()?, self.keys[1].get()?];
        let hist = self.levels[0].get()?;
        let scan_slot = 1 + PASSES as u64;
        let mut scan_up = Vec::new();
        let mut scan_down = Vec::new();
        for (l, &c) in counts.iter().enumerate() {
            let data = self.levels[l].get()?;
            let sums = self.levels[l + 1].get()?;
            scan_up.push((
                self.bind(ctx, &p.scan_blocks, scan_slot + l as u64, &[(6, data), (7, sums)]),
                c.div_ceil(SCAN_BLOCK),
            ));
            if l + 1 < counts.len() {
                scan_down.push((
                    self.bind(ctx, &p.scan_add, scan_slot + l as u64, &[(6, data), (7, sums)]),
                    c.div_ceil(256),
                ));
            }
        }
        for pass in 0..PASSES {
            let (src, dst) = (keys[pass as usize % 2], keys[(pass as usize + 1) % 2]);
            let slot = 1 + pass as u64;
            steps.push((&p.radix_upsweep, self.bind(ctx, &p.radix_upsweep, slot, &[(3, src), (5, hist)]), blocks));
            for (bg, g) in &scan_up {
                steps.push((&p.scan_blocks, bg.clone(), *g));
            }
            for (bg, g) in scan_down.iter().rev() {
                steps.push((&p.scan_add, bg.clone(), *g));
            }
            steps.push((
                &p.radix_downsweep,
                self.bind(ctx, &p.radix_downsweep, slot, &[(3, src), (4, dst), (5, hist)]),
                blocks,
            ));
        }
        Ok(())
    }

    /// Sorts `keys` (laid out like [`volwarp_core::morton::SortKey`]: code low word, code high
    /// word, payload, 0) on the GPU by their 56 low code bits (the Morton code has 54), stably:
    /// the sort of the build, on its own, for tests and benchmarks.
    pub fn sort_keys(
        &mut self,
        ctx: &GpuContext,
        keys: &[[u32; 4]],
        staging: &mut GrowBuffer,
    ) -> Result<Vec<[u32; 4]>, GpuError> {
        let n =
            u32::try_from(keys.len()).ok().filter(|&n| n < 1 << 30).ok_or(GpuError::BadScene("more than 2^30 keys"))?;
        if n == 0 {
            return Ok(Vec::new());
        }
        let counts = self.prepare_sort(ctx, n, [0.0; 4], [0.0; 4])?;
        ctx.queue.write_buffer(self.keys[0].get()?, 0, bytemuck::cast_slice(keys));
        let mut steps = Vec::new();
        self.sort_steps(ctx, n, &counts, &mut steps)?;
        let bytes = n as u64 * 16;
        staging.ensure(ctx, bytes)?;
        let mut encoder = ctx.device.create_command_encoder(&Default::default());
        run_steps(ctx, &mut encoder, "radix sort", &steps);
        encoder.copy_buffer_to_buffer(self.keys[PASSES as usize % 2].get()?, 0, staging.get()?, 0, bytes);
        ctx.queue.submit([encoder.finish()]);
        read_mapped(ctx, staging.get()?, bytes, bytemuck::pod_collect_to_vec::<u8, [u32; 4]>)
    }

    fn upload(&mut self, ctx: &GpuContext, frame: &Frame) -> Result<Vec<u32>, GpuError> {
        let counts = self.prepare(ctx, frame)?;
        ctx.queue.write_buffer(self.samples_in.get()?, 0, bytemuck::cast_slice(&frame.samples));
        ctx.queue.write_buffer(self.colors_in.get()?, 0, bytemuck::cast_slice(&frame.colors));
        Ok(counts)
    }

    /// Builds the tree of `frame` (`n >= 2`) into `samples_out`, `colors_out` and `nodes` and
    /// reads the result back into a [`Scene`] through `staging`.
    pub(crate) fn build(
        &mut self,
        ctx: &GpuContext,
        frame: &Frame,
        out: &Outputs,
        staging: &mut GrowBuffer,
    ) -> Result<(Scene, BuildTiming), GpuError> {
        let n = frame.samples.len();
        let t0 = Instant::now();
        let counts = self.upload(ctx, frame)?;
        ctx.queue.submit([]);
        ctx.wait()?;
        let t1 = Instant::now();
        let mut encoder = ctx.device.create_command_encoder(&Default::default());
        self.encode(ctx, &mut encoder, n as u32, &counts, out)?;
        ctx.queue.submit([encoder.finish()]);
        ctx.wait()?;
        let t2 = Instant::now();

        let (sb, cb, nb) = (n as u64 * 8, n as u64 * 4, (n as u64 - 1) * 32);
        staging.ensure(ctx, sb + cb + nb)?;
        let st = staging.get()?;
        let mut encoder = ctx.device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(out.samples, 0, st, 0, sb);
        encoder.copy_buffer_to_buffer(out.colors, 0, st, sb, cb);
        encoder.copy_buffer_to_buffer(out.nodes, 0, st, sb + cb, nb);
        ctx.queue.submit([encoder.finish()]);
        let (samples, colors, nodes_v) = read_mapped(ctx, st, sb + cb + nb, |d| {
            let (s, rest) = d.split_at(sb as usize);
            let (c, nd) = rest.split_at(cb as usize);
            (
                bytemuck::pod_collect_to_vec::<u8, u64>(s),
                bytemuck::pod_collect_to_vec::<u8, u32>(c),
                bytemuck::pod_collect_to_vec::<u8, Node>(nd),
            )
        })?;
        let t3 = Instant::now();
        let scene = Scene { samples, colors, nodes: nodes_v, ..Scene::empty(&frame.header) };
        let timing = BuildTiming { upload: t1 - t0, build: t2 - t1, readback: t3 - t2 };
        log::debug!("GPU LBVH build of {n} samples: {timing:?}");
        Ok((scene, timing))
    }

    /// Re-runs the build of the already uploaded `frame` `repeats` times; the mean time of one.
    pub(crate) fn rebuild_only(
        &mut self,
        ctx: &GpuContext,
        frame: &Frame,
        out: &Outputs,
        repeats: u32,
    ) -> Result<Duration, GpuError> {
        let counts = self.prepare(ctx, frame)?;
        let n = frame.samples.len() as u32;
        ctx.queue.submit([]);
        ctx.wait()?;
        let mut total = Duration::ZERO;
        for _ in 0..repeats.max(1) {
            let t = Instant::now();
            let mut encoder = ctx.device.create_command_encoder(&Default::default());
            self.encode(ctx, &mut encoder, n, &counts, out)?;
            ctx.queue.submit([encoder.finish()]);
            ctx.wait()?;
            total += t.elapsed();
        }
        Ok(total / repeats.max(1))
    }
}

/// One dispatch: pipeline, bind group, workgroups.
type Step<'a> = (&'a wgpu::ComputePipeline, wgpu::BindGroup, u32);

/// Records `steps` as one compute pass (wgpu orders the dispatches' storage accesses).
fn run_steps(ctx: &GpuContext, encoder: &mut wgpu::CommandEncoder, label: &str, steps: &[Step]) {
    let mut pass =
        encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some(label), timestamp_writes: None });
    for (pipe, bg, groups) in steps {
        let (x, y) = grid(ctx, *groups);
        pass.set_pipeline(pipe);
        pass.set_bind_group(0, bg, &[]);
        pass.dispatch_workgroups(x, y, 1);
    }
}

fn pipe_label(_p: &wgpu::ComputePipeline) -> Option<&'static str> {
    Some("lbvh")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scan_levels_shrink_to_one_block() {
        assert_eq!(scan_counts(10), vec![10]);
        assert_eq!(scan_counts(2048), vec![2048]);
        assert_eq!(scan_counts(2049), vec![2049, 2]);
        assert_eq!(scan_counts(256 * 4869), vec![256 * 4869, 609]);
        // 2.2 M keys: 2149 blocks of 1024, 256 digits each.
        assert_eq!(scan_counts(256 * 2149), vec![256 * 2149, 269]);
        assert_eq!(scan_counts(1 << 25), vec![1 << 25, 1 << 14, 8]);
    }
}
