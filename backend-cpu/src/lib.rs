//! octoproxy on the CPU: everything host-side.
//!
//! - [`bake`](mod@bake): baking triangle meshes into an encoded proxy (subdivision, normals,
//!   view-visible labelling, encoding, lookup table), in parallel with rayon.
//! - [`io`]: reading OBJ, STL and PLY meshes (each also gzipped), and particle point clouds
//!   in PLY, in and out.
//! - [`emit`]: particles in a box or on a mesh's surface.
//! - [`sides`]: exact starting sides from the mesh ([`starting_sides`], beside [`bake()`]).
//! - [`ground_truth`], [`harness`], [`scenes`]: checking a scene the way the tests do: exact
//!   winding numbers and segment crossings, the penetration harness, procedural meshes.
//! - [`gltf`](mod@gltf): glTF 2.0 scenes (meshes, node hierarchy, animation) read into a
//!   scene description, baked once per mesh, and the baked scene file.
//! - [`Scene`]: proxies placed by moving instances, stepped by [`Scene::step`] on any backend.
//! - [`CpuBackend`]: the core step over particles with rayon, behind the core `Backend` trait.
//!
//! # Example
//!
//! A closed cube read from OBJ text, baked, 10,000 particles dropped inside it and stepped on
//! every core for two seconds, then written out as a binary PLY point cloud:
//!
//! ```
//! use octoproxy_core::{initial_side, Backend, Particle, ProxyView, StepParams, SIDE_BACK};
//! use octoproxy_cpu::io::{parse_mesh, MeshFormat};
//! use octoproxy_cpu::io::{encode_particles, ParticleCloud, PlyEncoding};
//! use octoproxy_cpu::{bake, BuildParams, CpuBackend, MeshRef};
//!
//! // A unit cube, faces wound outward (`io::load_mesh` reads a file, gzipped or not).
//! let obj = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n\
//!            f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 4 8 7 3\nf 1 5 8 4\nf 2 3 7 6\n";
//! let (mesh, _) = parse_mesh("cube.obj", obj.as_bytes(), Some(MeshFormat::Obj))?;
//! let (words, report) = bake(&[MeshRef::from(&mesh)], &BuildParams::default(), &())?;
//! assert_eq!(report.closed_triangles, 12);
//!
//! // Particles on a grid inside the cube, thrown sideways. A particle's side is its leaf's
//! // label (front where unlabelled, far from the surface); the labelled leaves along the
//! // walls stamp the back side on every particle before it reaches them.
//! let view = ProxyView::new(&words)?;
//! let particles: Vec<Particle> = (0..10_000)
//!     .map(|i| {
//!         let (x, y, z) = ((i % 100) as f32, ((i / 100) % 10) as f32, (i / 1000) as f32);
//!         let mut p = Particle::new([0.05 + 0.009 * x, 0.5 + 0.04 * y, 0.05 + 0.09 * z], [3.0, 0.0, -1.0]);
//!         p.side = initial_side(&view, p.position);
//!         p
//!     })
//!     .collect();
//!
//! let mut cpu = CpuBackend::new();
//! cpu.upload_proxy(&words)?;
//! cpu.upload_particles(&particles)?;
//! cpu.step(&StepParams { dt: 1.0 / 60.0, restitution: 0.5, ..StepParams::default() }, 120)?;
//! let mut out = vec![Particle::default(); cpu.particle_count()];
//! cpu.download_particles(&mut out)?;
//!
//! // Every particle is still in the box (to within a leaf's rounding), on the back side of its
//! // walls, and most came to rest on the floor.
//! let leaf = view.finest_leaf_size();
//! assert!(out.iter().all(|p| p.position.iter().all(|&c| (-leaf..=1.0 + leaf).contains(&c))));
//! assert!(out.iter().all(|p| p.side == SIDE_BACK));
//! assert!(out.iter().filter(|p| p.position[1] < 0.05).count() > 9_000);
//!
//! let ply = encode_particles(&ParticleCloud::from_particles(out), PlyEncoding::BinaryLittleEndian);
//! assert!(ply.starts_with(b"ply\nformat binary_little_endian 1.0\n"));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod backend;
pub mod bake;
pub mod emit;
pub mod gltf;
pub mod ground_truth;
pub mod harness;
pub mod io;
pub mod scene;
pub mod scenes;
pub mod sides;

pub use backend::{CpuBackend, CpuError, PairTimings};
pub use bake::{
    bake, bake_offset, bake_with_radius, BuildError, BuildParams, BuildProgress, BuildReport,
    MeshRef,
};
pub use octoproxy_core::SceneStepReport;
pub use scene::{place_in_bands, starting_scene_sides, Scene, SceneBuildError, SceneStepError};
pub use sides::{starting_sides, CageCounts, Sides, StartCounts, StartSides};

/// The README's examples, compiled and run as doctests.
#[doc = include_str!("../../README.md")]
#[cfg(doctest)]
pub struct ReadmeDoctests;
