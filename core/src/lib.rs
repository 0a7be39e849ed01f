//! Core of octoproxy: the encoded octree proxy, its validated zero-copy view, and the particle
//! step that every backend runs, the GPU included (its WGSL mirrors this crate).
//!
//! `no_std`, no allocation: the same code runs in a game engine, an embedded runtime or a
//! test. The proxy is a flat buffer of `u32` words (see `FORMAT.md`); [`ProxyView::new`]
//! checks it once, and everything after takes `&ProxyView`.
#![cfg_attr(not(test), no_std)]
#![warn(missing_docs)]

#[cfg(feature = "alloc")]
extern crate alloc;

mod backend;
pub mod format;
mod math;
mod particle;
mod query;
mod step;
mod view;

pub use backend::Backend;
pub use format::{Label, NodeRecord, FORMAT_VERSION, MAX_DEPTH, MAX_LUT_DEPTH};
pub use particle::*;
pub use query::{Aabb, LeafInfo, LeafKind};
pub use step::{
    initial_side, max_leaves_per_step, pinch, respond, step_particle, step_particle_hinted, step_particle_traced, LeafHint,
    ParamError, StepOutcome, StepParams, MAX_LEAVES_PER_STEP, PINCH_PARALLEL,
};
pub use view::{lut_target, ulp, FormatError, Header, ProxyView};
#[cfg(feature = "alloc")]
pub use view::OwnedProxy;

#[cfg(test)]
mod tests;
