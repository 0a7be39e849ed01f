//! octoproxy on the CPU: everything host-side.
//!
//! - [`build`]: baking triangle meshes into an encoded proxy (subdivision, normals,
//!   view-visible labelling, encoding, lookup table), in parallel with rayon.
//! - [`mesh`]: reading PLY, OBJ and STL meshes (each also gzipped).
//! - [`particles`]: particle point clouds in PLY, in and out.
//! - [`CpuBackend`]: the core step over particles with rayon, behind the core `Backend` trait.

pub mod backend;
pub mod build;
pub mod emit;

pub use backend::{CpuBackend, CpuError};
pub use build::{bake, BuildError, BuildParams, BuildProgress, BuildReport, MeshRef};
pub mod mesh;
pub mod particles;
pub mod ply;

/// The README's examples, compiled and run as doctests.
#[doc = include_str!("../../README.md")]
#[cfg(doctest)]
pub struct ReadmeDoctests;
