//! Picking a GPU: any adapter wgpu can open (Vulkan, Metal, DX12, GL), a real GPU preferred,
//! a software one (lavapipe/llvmpipe, WARP) as the fallback, and a clear error when there is none.

use crate::scan::WgScanKind;
use crate::GpuError;
use std::sync::{Arc, Mutex};

/// An opened device and its queue, with what was chosen.
pub struct GpuContext {
    /// The adapter the device was opened on.
    pub adapter: wgpu::Adapter,
    /// The logical device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// Name, backend and type of the adapter.
    pub info: wgpu::AdapterInfo,
    /// The limits the device was opened with (the adapter's own).
    pub limits: wgpu::Limits,
    /// Errors wgpu reported outside any error scope since the last [`GpuContext::take_error`].
    uncaptured: Arc<Mutex<Option<String>>>,
    /// Whether the device was opened with subgroup operations.
    subgroups: bool,
    /// The workgroup scan the shaders compiled on this context use.
    scan: WgScanKind,
}

/// Preference order of device types: a discrete GPU first, a software rasterizer last.
fn rank(t: wgpu::DeviceType) -> u32 {
    match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    }
}

/// Preference among backends for the same device: the native APIs before GL.
fn backend_rank(b: wgpu::Backend) -> u32 {
    match b {
        wgpu::Backend::Vulkan | wgpu::Backend::Metal | wgpu::Backend::Dx12 => 0,
        _ => 1,
    }
}

impl GpuContext {
    /// Opens the best adapter there is. Honours wgpu's `WGPU_BACKEND` (e.g. `vulkan`, `gl`) and
    /// `WGPU_ADAPTER_NAME` environment variables.
    pub fn new() -> Result<GpuContext, GpuError> {
        Self::with_adapter(None)
    }

    /// Opens the best adapter whose name contains `name` (case-insensitive; `None`: any, or the
    /// one `WGPU_ADAPTER_NAME` names). When nothing matches, the error lists the adapters that
    /// were found; when there are none at all, it says what to install.
    pub fn with_adapter(name: Option<&str>) -> Result<GpuContext, GpuError> {
        // Native APIs first; GL (through EGL) only when they offer nothing, which also keeps
        // EGL's start-up complaints out of the log on machines with Vulkan.
        let mut adapters = Vec::new();
        for backends in [wgpu::Backends::PRIMARY, wgpu::Backends::SECONDARY] {
            let desc = wgpu::InstanceDescriptor { backends, ..wgpu::InstanceDescriptor::new_without_display_handle() };
            let desc = desc.with_env();
            let instance = wgpu::Instance::new(desc);
            adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all()));
            if !adapters.is_empty() {
                break;
            }
        }
        let found: Vec<String> = adapters.iter().map(|a| describe_info(&a.get_info())).collect();
        let wanted_name = name.map(str::to_string).or_else(|| std::env::var("WGPU_ADAPTER_NAME").ok());
        if let Some(w) = wanted_name.as_deref().map(str::to_lowercase) {
            adapters.retain(|a| a.get_info().name.to_lowercase().contains(w.as_str()));
            if adapters.is_empty() && !found.is_empty() {
                return Err(GpuError::NoAdapter(format!(
                    "no adapter's name contains {:?}; found: {}",
                    wanted_name.unwrap_or_default(),
                    found.join("; ")
                )));
            }
        }
        // Compute shaders are all we need; drop adapters that cannot run them.
        adapters.retain(|a| a.get_downlevel_capabilities().flags.contains(wgpu::DownlevelFlags::COMPUTE_SHADERS));
        for a in &adapters {
            let i = a.get_info();
            log::debug!("found adapter {:?} ({:?}, {:?})", i.name, i.backend, i.device_type);
        }
        adapters.sort_by_key(|a| {
            let i = a.get_info();
            (rank(i.device_type), backend_rank(i.backend))
        });
        let mut last_err = None;
        for adapter in adapters {
            match Self::open(adapter) {
                Ok(ctx) => return Ok(ctx),
                Err(e) => {
                    log::warn!("{e}");
                    last_err = Some(e);
                }
            }
        }
        Err(last_err.unwrap_or_else(|| {
            GpuError::NoAdapter(
                "no GPU adapter with compute shaders found (wgpu tried Vulkan, Metal, DX12 and GL); on Linux \
                 without a GPU install a software driver, e.g. `apt-get install mesa-vulkan-drivers libvulkan1` \
                 (lavapipe)"
                    .into(),
            )
        }))
    }

    fn open(adapter: wgpu::Adapter) -> Result<GpuContext, GpuError> {
        let info = adapter.get_info();
        let limits = adapter.limits();
        let subgroups = WgScanKind::subgroups_usable(&adapter);
        let desc = wgpu::DeviceDescriptor {
            label: Some("volwarp-gpu-tracer"),
            required_features: if subgroups { wgpu::Features::SUBGROUP } else { wgpu::Features::empty() },
            required_limits: limits.clone(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&desc))
            .map_err(|e| GpuError::Device(format!("adapter {:?} ({:?}): {e}", info.name, info.backend)))?;
        let uncaptured = Arc::new(Mutex::new(None));
        let sink = uncaptured.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            log::error!("wgpu: {e}");
            if let Ok(mut s) = sink.lock() {
                s.get_or_insert_with(|| e.to_string());
            }
        }));
        let scan = if subgroups { WgScanKind::Subgroup } else { WgScanKind::Portable };
        log::info!(
            "GPU adapter: {} ({:?}, {:?}, driver {} {}), workgroup scans: {}",
            info.name,
            info.backend,
            info.device_type,
            info.driver,
            info.driver_info,
            scan.describe(&info)
        );
        Ok(GpuContext { adapter, device, queue, info, limits, uncaptured, subgroups, scan })
    }

    /// The workgroup scan the shaders compiled on this context use: [`WgScanKind::Subgroup`]
    /// where the device has subgroup operations, else [`WgScanKind::Portable`].
    pub fn scan(&self) -> WgScanKind {
        self.scan
    }

    /// Chooses the workgroup scan of the shaders compiled on this context from now on (the
    /// portable one always works; the subgroup one needs a device opened with subgroup
    /// operations). For comparing the two; [`GpuContext::scan`] is already the faster one.
    pub fn set_scan(&mut self, kind: WgScanKind) -> Result<(), GpuError> {
        if kind == WgScanKind::Subgroup && !self.subgroups {
            return Err(GpuError::Device(format!(
                "adapter {:?} was opened without subgroup operations (it lacks them, or VOLWARP_GPU_SUBGROUPS=0)",
                self.info.name
            )));
        }
        self.scan = kind;
        Ok(())
    }

    /// A one-line description: name, backend and type.
    pub fn describe(&self) -> String {
        describe_info(&self.info)
    }

    /// Name, backend, type and driver (for benchmark reports).
    pub fn describe_driver(&self) -> String {
        format!("{}, driver {} {}", self.describe(), self.info.driver, self.info.driver_info)
    }

    /// Takes the first error wgpu reported outside an error scope, if any.
    pub fn take_error(&self) -> Option<String> {
        self.uncaptured.lock().ok().and_then(|mut s| s.take())
    }

    /// Blocks until the queue is idle.
    pub fn wait(&self) -> Result<(), GpuError> {
        self.device.poll(wgpu::PollType::wait_indefinitely()).map(|_| ()).map_err(|e| GpuError::Device(e.to_string()))
    }

    /// Largest storage buffer binding, in bytes.
    pub fn max_binding(&self) -> u64 {
        self.limits.max_storage_buffer_binding_size.min(self.limits.max_buffer_size)
    }
}

/// `name (backend, type)`.
fn describe_info(i: &wgpu::AdapterInfo) -> String {
    format!("{} ({:?}, {:?})", i.name, i.backend, i.device_type)
}

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuContext").field("adapter", &self.describe()).finish()
    }
}

/// The share of pixels a GPU renderer's image must have identical to the CPU renderer's on an
/// adapter of `info`, in the tests that compare them: all of them on a software rasterizer
/// (lavapipe, llvmpipe, WARP: the shaders' single-precision operations in the CPU renderers'
/// order, measured 100.0000 % identical on every test view, the layered splatter included),
/// [`TARGET_IDENTICAL`](volwarp_core::image_diff::TARGET_IDENTICAL) on a hardware GPU, whose
/// driver may fuse a multiply and an add or reassociate a blend (there the layered splatter is
/// held to pixels within one 8-bit step; `volwarp-compare` and the benches report the figures).
pub fn required_identical_share(info: &wgpu::AdapterInfo) -> f64 {
    if info.device_type == wgpu::DeviceType::Cpu {
        1.0
    } else {
        volwarp_core::image_diff::TARGET_IDENTICAL
    }
}
