//! glTF 2.0 scenes: meshes placed by a node hierarchy and moved by animation, read into a
//! [`SceneDescription`]; baked once into a [`BakedScene`] (one proxy per mesh, or per mesh and
//! world scale for particles of a radius) and written to
//! a file that a simulation reads back without baking again.
//!
//! # What is read
//!
//! `.gltf` (JSON, with buffers embedded as `data:` URIs or in files beside it) and `.glb`
//! (binary), through the `gltf` crate's JSON model. Images and materials are never looked at.
//! Every error is a [`GltfError`] that names the file and the glTF node, mesh or animation (by
//! index and name) and says what is wrong; nothing panics on any input.
//!
//! - **The scene**: the document's default scene (scene 0 when none is named). Its node tree
//!   is walked depth first, children in the order listed; a node reached twice (two parents,
//!   or a cycle) is an error.
//! - **Instances** are the nodes with a mesh, numbered in that pre-order; a scene of top-level
//!   nodes that each hold a mesh numbers its instances as its nodes. A node with
//!   `EXT_mesh_gpu_instancing` gives one instance per copy, in order, each copy's
//!   `TRANSLATION`/`ROTATION`/`SCALE` applied after the node's world transform.
//! - **Meshes**: each glTF mesh used by an instance becomes one mesh to bake (all its triangle
//!   primitives joined; strips and fans triangulated; points and lines skipped with a
//!   [`GltfWarning`]; indexed or not; sparse accessors applied). Nodes sharing a glTF mesh
//!   share one mesh, so one proxy. Meshes no instance uses are not read. Positions must be
//!   `FLOAT` `VEC3`: `KHR_mesh_quantization`, `KHR_draco_mesh_compression` and
//!   `EXT_meshopt_compression` are errors naming the mesh.
//! - **Transforms** (TRS or `matrix`) compose down the hierarchy in `f64`. Each instance's
//!   world transform must be a uniform scale times a rotation plus a translation (relative
//!   tolerance [`RIGID_TOLERANCE`]); a non-uniform, shearing or mirroring composition is an
//!   error naming the node, checked at the rest pose, at every key time and halfway between
//!   keys. A world scale of exactly zero gives `Pose { scale: 0.0, .. }` (a hidden instance).
//! - **Animation**: channels on `translation`, `rotation` and `scale` with `LINEAR` (slerp
//!   the shorter way for rotations), `STEP` and `CUBICSPLINE` (Hermite, tangents scaled by the
//!   key interval, rotations normalized after). All animations play together from time 0;
//!   poses hold before the first key and after the last. Two channels on one node's same path
//!   are an error naming the node; key times must be finite and strictly increasing.
//! - **Not supported yet** (each an error naming the node or mesh): skins, morph targets
//!   (a primitive with `targets`) and `weights` channels, that is deforming meshes.
//! - **External files**: a buffer URI is a path relative to the glTF file's folder
//!   (percent-encoding decoded). Absolute paths, other URI schemes and paths that climb out
//!   with `..` are refused: a scene file may read only files at or below its own folder.
//!
//! # The baked scene
//!
//! [`bake_scene`] bakes each mesh once ([`crate::bake()`]) into a [`BakedScene`], which holds
//! the proxies, the meshes (for exact starting sides), the instances and the node hierarchy
//! with its animation. For particles of a radius, [`bake_scene_for_radius`] bakes each mesh
//! once per distinct world scale of its instances (the offset surface at the radius divided
//! by the scale), and refuses, naming the node, an instance whose scale is animated; [`BakedScene::encode`]/[`BakedScene::write`] and
//! [`BakedScene::parse`]/[`BakedScene::read`] move it to and from a file whose format is in
//! `FORMAT.md` beside this module. A [`BakedScene`] samples exactly the poses of the
//! [`SceneDescription`] it came from: both sample through one [`SceneGraph`].
//!
//! # Example
//!
//! ```
//! use octoproxy_cpu::gltf::{bake_scene, parse_gltf, BakedScene};
//! use octoproxy_cpu::BuildParams;
//!
//! // A tetrahedron placed twice: node 1 is node 0's child, moved one unit along x.
//! let positions: [[f32; 3]; 4] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
//! let indices: [u16; 12] = [0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3];
//! let mut bin: Vec<u8> = positions.iter().flatten().flat_map(|c| c.to_le_bytes()).collect();
//! bin.extend(indices.iter().flat_map(|i| i.to_le_bytes()));
//! let json = format!(
//!     r#"{{"asset": {{"version": "2.0"}}, "scene": 0, "scenes": [{{"nodes": [0]}}],
//!     "nodes": [{{"name": "a", "mesh": 0, "children": [1]}}, {{"name": "b", "mesh": 0, "translation": [1, 0, 0]}}],
//!     "meshes": [{{"name": "tet", "primitives": [{{"attributes": {{"POSITION": 0}}, "indices": 1}}]}}],
//!     "accessors": [{{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"}},
//!                   {{"bufferView": 1, "componentType": 5123, "count": 12, "type": "SCALAR"}}],
//!     "bufferViews": [{{"buffer": 0, "byteLength": 48}}, {{"buffer": 0, "byteOffset": 48, "byteLength": 24}}],
//!     "buffers": [{{"byteLength": 72, "uri": "data:application/octet-stream;base64,{}"}}]}}"#,
//!     octoproxy_cpu::gltf::encode_base64(&bin)
//! );
//! let (scene, warnings) = parse_gltf("two.gltf", json.as_bytes(), None)?;
//! assert!(warnings.is_empty());
//! assert_eq!(scene.meshes.len(), 1); // shared
//! assert_eq!(scene.poses_at(0.0)?[1].translation, [1.0, 0.0, 0.0]);
//!
//! let (baked, _) = bake_scene(&scene, &BuildParams { dmax: 5, ..Default::default() }, &())?;
//! let bytes = baked.encode();
//! let back = BakedScene::parse("two.oscn", &bytes)?;
//! assert_eq!(back, baked);
//! let (sim, instances) = back.build_scene()?;
//! assert_eq!(instances, [0, 1]);
//! assert_eq!(sim.instances().len(), 2);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod baked;
mod base64;
mod graph;
mod load;

pub use baked::{
    bake_scene, bake_scene_for_radius, BakeSceneError, BakedProxy, BakedScene, BakedSceneError,
    SceneSetupError, SCENE_FORMAT_VERSION, SCENE_MAGIC,
};
pub use base64::{decode_base64, encode_base64};
pub use graph::{
    Channel, ChannelPath, GraphError, Interpolation, NodeTransform, PoseError, ScaleRange,
    SceneGraph, SceneInstance, SceneNode, Trs, RIGID_TOLERANCE,
};
pub use load::{load_gltf, parse_gltf};

use crate::io::Mesh;
use graph::quoted;
use octoproxy_core::scene::Pose;

/// A mesh of a scene: what one proxy is baked from.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SceneMesh {
    /// The glTF mesh's name (empty when it has none).
    pub name: String,
    /// Its triangles.
    pub mesh: Mesh,
}

/// A glTF scene: its meshes and the graph that places and moves them.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneDescription {
    /// The meshes, in the order instances first use them.
    pub meshes: Vec<SceneMesh>,
    /// For each mesh, the index of the glTF mesh it was read from.
    pub gltf_meshes: Vec<u32>,
    /// The nodes (every node of the document, by glTF index), instances and channels.
    pub graph: SceneGraph,
}

/// One line of [`SceneDescription::list_instances`]: an instance, what it places and where.
#[derive(Clone, Debug, PartialEq)]
pub struct InstanceInfo {
    /// The instance's index.
    pub index: u32,
    /// Its node's index in the glTF document.
    pub node: u32,
    /// Its node's name.
    pub node_name: String,
    /// Its copy within the node (`EXT_mesh_gpu_instancing`), else 0.
    pub copy: u32,
    /// Its mesh (an index into the scene's meshes).
    pub mesh: u32,
    /// The mesh's name.
    pub mesh_name: String,
    /// Its pose at time 0.
    pub pose: Pose,
}

fn list_instances(
    graph: &SceneGraph,
    meshes: &[SceneMesh],
) -> Result<Vec<InstanceInfo>, PoseError> {
    let poses = graph.poses_at(0.0)?;
    Ok(graph
        .instances()
        .iter()
        .zip(poses)
        .enumerate()
        .map(|(k, (inst, pose))| InstanceInfo {
            index: k as u32,
            node: inst.node,
            node_name: graph.node_name(k as u32).to_string(),
            copy: inst.copy,
            mesh: inst.mesh,
            mesh_name: meshes
                .get(inst.mesh as usize)
                .map_or_else(String::new, |m| m.name.clone()),
            pose,
        })
        .collect())
}

/// See [`BakedScene::describe_instances`].
fn describe_instances(graph: &SceneGraph, meshes: &[SceneMesh], ids: &[u32]) -> String {
    let one = |k: u32| {
        let Some(inst) = graph.instances().get(k as usize) else {
            return format!("instance {k} does not exist");
        };
        let copy = if inst.copy > 0 {
            format!(", copy {}", inst.copy)
        } else {
            String::new()
        };
        let mesh = meshes
            .get(inst.mesh as usize)
            .map_or("", |m| m.name.as_str());
        let mesh = if mesh.is_empty() {
            format!("mesh {}", inst.mesh)
        } else {
            format!("mesh{}", quoted(mesh))
        };
        format!(
            "instance {k} is node {}{}{copy}, {mesh}",
            inst.node,
            quoted(graph.node_name(k))
        )
    };
    ids.iter().map(|&k| one(k)).collect::<Vec<_>>().join("; ")
}

impl SceneDescription {
    /// The world pose of instance `instance` at time `t` in seconds.
    pub fn pose_at(&self, instance: u32, t: f64) -> Result<Pose, PoseError> {
        self.graph.pose_at(instance, t)
    }

    /// The world poses of every instance at time `t`, by instance index.
    pub fn poses_at(&self, t: f64) -> Result<Vec<Pose>, PoseError> {
        self.graph.poses_at(t)
    }

    /// The animation's length in seconds (0 without animation).
    pub fn duration(&self) -> f64 {
        self.graph.duration()
    }

    /// The instances.
    pub fn instances(&self) -> &[SceneInstance] {
        self.graph.instances()
    }

    /// Every instance with its node, mesh and pose at time 0 (for `--list-instances`).
    pub fn list_instances(&self) -> Result<Vec<InstanceInfo>, PoseError> {
        list_instances(&self.graph, &self.meshes)
    }
}

impl BakedScene {
    /// Every instance with its node, mesh and pose at time 0 (for `--list-instances`).
    pub fn list_instances(&self) -> Result<Vec<InstanceInfo>, PoseError> {
        list_instances(self.graph(), self.meshes())
    }

    /// Which nodes instances `ids` hang on, for an error that names instances by number:
    /// `instance 0 is node 4 "wheel", mesh "tyre"`, joined by `; `.
    pub fn describe_instances(&self, ids: &[u32]) -> String {
        describe_instances(self.graph(), self.meshes(), ids)
    }
}

/// What loading a glTF file found besides the scene.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum GltfWarning {
    /// A primitive that is not made of triangles (points or lines) was left out.
    #[error("{file}: mesh {mesh}{}: primitive {primitive} skipped: its mode is {mode}, not triangles", quoted(.mesh_name))]
    SkippedPrimitive {
        /// The file.
        file: String,
        /// The glTF mesh.
        mesh: u32,
        /// Its name.
        mesh_name: String,
        /// The primitive within the mesh.
        primitive: u32,
        /// Its mode: `POINTS`, `LINES`, `LINE_LOOP` or `LINE_STRIP`.
        mode: &'static str,
    },
}

/// Why a glTF file could not be read. Every message starts with the file name.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GltfError {
    /// The file (or a file it refers to) could not be read.
    #[error("{file}: cannot read the file: {source}")]
    Io {
        /// The file.
        file: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The file as a whole is malformed: its GLB container, its JSON, its version, its scene.
    #[error("{file}: {message}")]
    Format {
        /// The file.
        file: String,
        /// What is wrong.
        message: String,
    },
    /// A node is malformed or unsupported.
    #[error("{file}: node {node}{}: {message}", quoted(.node_name))]
    Node {
        /// The file.
        file: String,
        /// The glTF node.
        node: u32,
        /// Its name (empty when it has none).
        node_name: String,
        /// What is wrong.
        message: String,
    },
    /// A mesh is malformed or unsupported.
    #[error("{file}: mesh {mesh}{}: {message}", quoted(.mesh_name))]
    Mesh {
        /// The file.
        file: String,
        /// The glTF mesh.
        mesh: u32,
        /// Its name (empty when it has none).
        mesh_name: String,
        /// What is wrong.
        message: String,
    },
    /// An animation is malformed or unsupported.
    #[error("{file}: animation {animation}{}: {message}", quoted(.animation_name))]
    Animation {
        /// The file.
        file: String,
        /// The glTF animation.
        animation: u32,
        /// Its name (empty when it has none).
        animation_name: String,
        /// What is wrong (it names the channel and node).
        message: String,
    },
    /// An instance's world transform is not rigid somewhere in the animation.
    #[error("{file}: {source}")]
    Pose {
        /// The file.
        file: String,
        /// Where and what.
        source: PoseError,
    },
    /// The graph did not hold together (a check the loader's own should have made first).
    #[error("{file}: {source}")]
    Graph {
        /// The file.
        file: String,
        /// What is wrong.
        source: GraphError,
    },
}

#[cfg(test)]
mod tests;
