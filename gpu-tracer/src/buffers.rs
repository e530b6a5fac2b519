//! GPU buffers that are reused across frames and only reallocated when a frame needs more,
//! and the blocking readback of a buffer into host memory.

use crate::{GpuContext, GpuError};

/// Smallest allocation: wgpu rejects zero-sized bindings.
const MIN_BYTES: u64 = 256;

/// A buffer with a capacity that only grows.
#[derive(Debug)]
pub struct GrowBuffer {
    label: &'static str,
    usage: wgpu::BufferUsages,
    buf: Option<wgpu::Buffer>,
    /// Number of reallocations so far (tests check buffers are reused).
    pub reallocations: u32,
}

impl GrowBuffer {
    /// An empty buffer of the given usage; nothing is allocated until [`GrowBuffer::ensure`].
    pub fn new(label: &'static str, usage: wgpu::BufferUsages) -> Self {
        GrowBuffer { label, usage, buf: None, reallocations: 0 }
    }

    /// Makes the buffer hold at least `bytes` (rounded up to 256 B and grown by 1/8 ahead so a
    /// slowly growing stream does not reallocate every frame). Returns whether it was
    /// reallocated (bind groups that used it must then be recreated). Fails cleanly when the
    /// size is over the device's limit.
    pub fn ensure(&mut self, ctx: &GpuContext, bytes: u64) -> Result<bool, GpuError> {
        let need = bytes.max(MIN_BYTES).next_multiple_of(MIN_BYTES);
        if let Some(b) = &self.buf {
            if b.size() >= need {
                return Ok(false);
            }
        }
        let limit = if self.usage.contains(wgpu::BufferUsages::STORAGE) {
            ctx.max_binding()
        } else {
            ctx.limits.max_buffer_size
        };
        if need > limit {
            return Err(GpuError::TooLarge { what: self.label, bytes: need, limit });
        }
        let size = (need + need / 8).next_multiple_of(MIN_BYTES).min(limit / MIN_BYTES * MIN_BYTES).max(need);
        if let Some(old) = self.buf.take() {
            old.destroy();
        }
        self.buf = Some(ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(self.label),
            size,
            usage: self.usage,
            mapped_at_creation: false,
        }));
        self.reallocations += 1;
        Ok(true)
    }

    /// The buffer. [`GrowBuffer::ensure`] must have been called.
    pub fn get(&self) -> Result<&wgpu::Buffer, GpuError> {
        self.buf.as_ref().ok_or(GpuError::Internal("buffer used before allocation"))
    }

    /// Capacity in bytes (0 before the first allocation).
    pub fn capacity(&self) -> u64 {
        self.buf.as_ref().map_or(0, |b| b.size())
    }
}

/// Maps `staging` (MAP_READ), hands its first `bytes` to `f`, and unmaps. The copies into
/// `staging` must have been submitted already.
pub fn read_mapped<R>(
    ctx: &GpuContext,
    staging: &wgpu::Buffer,
    bytes: u64,
    f: impl FnOnce(&[u8]) -> R,
) -> Result<R, GpuError> {
    if bytes == 0 {
        return Ok(f(&[]));
    }
    let slice = staging.slice(..bytes);
    let (tx, rx) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    ctx.wait()?;
    match rx.recv() {
        Ok(Ok(())) => {}
        Ok(Err(e)) => return Err(GpuError::Readback(e.to_string())),
        Err(_) => return Err(GpuError::Readback("map callback never ran".into())),
    }
    let out = {
        let view = slice.get_mapped_range().map_err(|e| GpuError::Readback(e.to_string()))?;
        f(&view)
    };
    staging.unmap();
    Ok(out)
}

/// Splits `groups` workgroups into an `(x, y)` grid within the per-dimension limit; kernels fold
/// it back with `wid.y * num_workgroups.x + wid.x`.
pub fn grid(ctx: &GpuContext, groups: u32) -> (u32, u32) {
    let max = ctx.limits.max_compute_workgroups_per_dimension.clamp(1, 32768);
    if groups <= max {
        (groups.max(1), 1)
    } else {
        (max, groups.div_ceil(max))
    }
}

/// A bind group of `layout`: binding 0 the `size` bytes of the uniform `params` at `offset` (one
/// slot of a buffer of uniforms), then each `(binding, buffer)` whole.
pub(crate) fn slot_bind_group(
    ctx: &GpuContext,
    label: &'static str,
    layout: &wgpu::BindGroupLayout,
    params: (&wgpu::Buffer, u64, u64),
    storage: &[(u32, &GrowBuffer)],
) -> Result<wgpu::BindGroup, GpuError> {
    let (buffer, offset, size) = params;
    let mut entries = vec![wgpu::BindGroupEntry {
        binding: 0,
        resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
            buffer,
            offset,
            size: std::num::NonZeroU64::new(size),
        }),
    }];
    for &(binding, buf) in storage {
        entries.push(wgpu::BindGroupEntry { binding, resource: buf.get()?.as_entire_binding() });
    }
    Ok(ctx.device.create_bind_group(&wgpu::BindGroupDescriptor { label: Some(label), layout, entries: &entries }))
}
