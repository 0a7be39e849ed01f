//! What the differential tests share: the GPU backend they compare against.

use octoproxy_wgpu::WgpuBackend;

/// The GPU backend, on any adapter (lavapipe included). Without one: a failure under
/// `CI=true`, a "skipped" message otherwise.
pub fn gpu_backend() -> Option<WgpuBackend> {
    match WgpuBackend::new() {
        Ok(gpu) => {
            eprintln!("GPU adapter: {}", gpu.description());
            Some(gpu)
        }
        Err(e) if std::env::var("CI").as_deref() == Ok("true") => {
            panic!("CI=true needs a GPU adapter (lavapipe: apt install mesa-vulkan-drivers libvulkan1): {e}")
        }
        Err(e) => {
            eprintln!("skipped: {e}");
            None
        }
    }
}

/// Whether the adapter is lavapipe (llvmpipe), where every bit must agree.
pub fn is_lavapipe(gpu: &WgpuBackend) -> bool {
    gpu.description().to_lowercase().contains("llvmpipe")
}
