//! With no adapter at all (here: only a backend this OS does not have), opening a GPU renderer
//! is a clear error that names what to install, not a panic. Its own test binary: it sets
//! `WGPU_BACKEND` for the whole process.

use volwarp_gpu_tracer::{GpuError, GpuLayerSplat, GpuSplat, GpuTracer};

#[test]
fn no_adapter_is_a_clear_error_naming_what_to_install() {
    // Metal exists only on Apple systems, DX12 only on Windows.
    let missing = if cfg!(target_os = "macos") { "dx12" } else { "metal" };
    std::env::set_var("WGPU_BACKEND", missing);
    for e in [
        GpuTracer::new().map(|_| ()).unwrap_err(),
        GpuSplat::with_adapter(None).map(|_| ()).unwrap_err(),
        GpuLayerSplat::with_adapter(None).map(|_| ()).unwrap_err(),
    ] {
        let msg = e.to_string();
        eprintln!("{msg}");
        assert!(matches!(e, GpuError::NoAdapter(_)), "{e:?}");
        assert!(msg.contains("install"), "{msg}");
    }
}
