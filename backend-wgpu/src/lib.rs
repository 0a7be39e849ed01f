//! octoproxy on the GPU: core's step mirrored in WGSL and run through wgpu, on the very
//! bytes [`octoproxy_core::ProxyView`] validated.
//!
//! The proxy is uploaded as core encodes it and the particles as core's
//! [`Particle`](octoproxy_core::Particle) records; the WGSL structs, constants and functions
//! mirror core's with the same names ([`shader`] joins them). Particles stay on the GPU
//! between steps and are split into chunks by the device's binding limit.
//!
//! ```no_run
//! use octoproxy_core::{Backend, Particle, StepParams};
//! use octoproxy_wgpu::WgpuBackend;
//!
//! # fn run(proxy_words: &[u32]) -> Result<(), octoproxy_wgpu::WgpuError> {
//! let mut gpu = WgpuBackend::new()?;
//! gpu.upload_proxy(proxy_words)?;
//! gpu.upload_particles(&[Particle::new([0.0, 1.0, 0.0], [0.0, 0.0, 0.0])])?;
//! gpu.step(&StepParams::default(), 60)?; // 60 steps, no read-back in between
//! let mut out = vec![Particle::default(); gpu.particle_count()];
//! gpu.download_particles(&mut out)?;
//! # Ok(()) }
//! ```
#![warn(missing_docs)]

mod backend;
mod pairs;
mod scene;
pub mod shader;

pub use backend::{
    ChunkParams, RunParams, WgpuBackend, WgpuError, DEFAULT_CHUNK_PARTICLES, HINT_BYTES,
    PARTICLE_BYTES, STEPS_PER_SUBMIT,
};
pub use pairs::{PairPassParams, PairSortParams, PairState, PAIR_SORT_BLOCK, PAIR_STORAGE_BUFFERS};
pub use scene::{SceneParams, OUT_HEADER_WORDS as SCENE_OUT_HEADER_WORDS, SCENE_STORAGE_BUFFERS};
pub use wgpu;
