//! Core of octoproxy: the encoded octree proxy, its validated zero-copy view, and the particle
//! step that every backend runs, the GPU included (its WGSL mirrors this crate).
//!
//! `no_std`, no allocation: the same code runs in a game engine, an embedded runtime or a
//! test. The proxy is a flat buffer of `u32` words (see `FORMAT.md`); [`ProxyView::new`]
//! checks it once, and everything after takes `&ProxyView`.
//!
//! # Example
//!
//! A proxy baked offline (here with `octoproxy-cpu`; `octoproxy bake` writes the same bytes
//! to a file) arrives as little-endian bytes, is validated once, and particles step against
//! it, each keeping the [`LeafHint`] of its last leaf between steps:
//!
//! ```
//! use octoproxy_core::{step_particle_hinted, LeafHint, LeafKind, Particle, ProxyView, StepParams};
//!
//! // A ramp: one triangle, sloping down toward +x, facing up.
//! let positions = [[-1.0, 0.5, -1.0], [-1.0, 0.5, 1.0], [1.0, -0.5, 0.0]];
//! let triangles = [[0, 1, 2]];
//! let mesh = octoproxy_cpu::MeshRef { positions: &positions, triangles: &triangles };
//! let (words, _) = octoproxy_cpu::bake(&[mesh], &Default::default(), &())?;
//! let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
//!
//! // What a runtime without `std` does with the file's bytes (4-byte aligned, as a `Vec<u32>`
//! // or a mapped buffer is): a hostile or truncated file is an error here, never later.
//! let stored: Vec<u32> = bytes.chunks_exact(4).map(|b| u32::from_le_bytes(b.try_into().unwrap())).collect();
//! let view = ProxyView::new(&stored)?;
//! assert!(ProxyView::new(&stored[..stored.len() - 1]).is_err());
//! assert_eq!(view.locate_leaf([0.0, 0.0, 0.0].into()).map(|l| l.kind), Some(LeafKind::Surface));
//!
//! // Dropped onto the ramp, a particle lands, slides down it toward +x, and never falls through.
//! let params = StepParams { dt: 1.0 / 120.0, restitution: 0.0, friction: 0.0, ..StepParams::default() };
//! let mut p = Particle::new([-0.5, 1.0, 0.0], [0.0; 3]);
//! let mut hint = LeafHint::NONE;
//! for _ in 0..120 {
//!     step_particle_hinted(&view, &mut p, &params, &mut hint);
//!     // The ramp's height under the particle: y = -x / 2.
//!     assert!(p.position[1] >= -0.5 * p.position[0] - view.finest_leaf_size());
//! }
//! assert!(p.collisions() > 0 && p.position[0] > -0.4, "it slid down to {:?}", p.position);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
#![cfg_attr(not(test), no_std)]
#![warn(missing_docs)]

#[cfg(feature = "alloc")]
extern crate alloc;

mod backend;
pub mod format;
mod math;
pub mod pairs;
mod particle;
mod query;
pub mod scene;
mod step;
mod view;

pub use backend::{Backend, EventCount, SceneStepReport, SceneSubstep};
pub use format::{Label, NodeRecord, FORMAT_VERSION, MAX_DEPTH, MAX_LUT_DEPTH};
pub use pairs::{
    collide_pairs, debias_pairs, pair_iterations_for, pair_probe_speed, pair_start_scene,
    pair_substep_range, pair_substeps, pair_substeps_for, pair_support_scene, PairBody,
    PairParamError, PairParams, PairProbe, PairReport, PairScratch, PairStep, PairVelocity,
};
pub use particle::*;
pub use query::{Aabb, LeafInfo, LeafKind, NO_LEAF};
pub use scene::{
    step_particle_scene, step_particle_scene_traced, BroadNode, Hit, HitEvent, HitEvents, Instance,
    Pose, SceneError, SceneHint, SceneSides, SceneSlots, SceneView,
};
pub use step::{
    check_radius, initial_side, max_leaves_per_step, pinch, respond, step_particle,
    step_particle_counted, step_particle_hinted, step_particle_profiled, step_particle_traced,
    LeafHint, MarchBranch, MarchCounts, ParamError, RadiusMismatch, StepKind, StepOutcome,
    StepParams, StepProfile, LEAF_BOUND_EXTRA, LEAF_BOUND_PER_CELL, MAX_LEAVES_PER_STEP,
    PINCH_PARALLEL, RADIUS_TOLERANCE,
};
#[cfg(feature = "alloc")]
pub use view::OwnedProxy;
pub use view::{lut_target, ulp, FormatError, Header, ProxyView};

#[cfg(test)]
mod tests;
