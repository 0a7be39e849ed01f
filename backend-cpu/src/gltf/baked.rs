//! The baked scene: every mesh's proxy, the meshes themselves, the instances and the node
//! hierarchy with its animation, and its file (`FORMAT.md` beside this module documents every
//! byte).
//!
//! [`BakedScene::new`] is the one gate: [`bake_scene`] and [`BakedScene::parse`] both go
//! through it, so a `BakedScene` always holds valid proxies (checked by
//! `octoproxy_core::ProxyView::new`), meshes whose indices are in range, and a valid
//! [`SceneGraph`] whose instances are rigid at every key; and everything in it fits the file.
//! The reader checks every count against the bytes left before it allocates, and never
//! panics; its errors name the file.

use std::path::Path;

use octoproxy_core::scene::Pose;
use octoproxy_core::{check_radius, FormatError, ProxyView, RADIUS_TOLERANCE};

use super::graph::{
    Channel, ChannelPath, GraphError, Interpolation, NodeTransform, PoseError, SceneGraph,
    SceneInstance, SceneNode, Trs,
};
use super::{SceneDescription, SceneMesh};
use crate::bake::offset::OffsetSurface;
use crate::bake::{BuildError, BuildParams, BuildProgress, BuildReport, MeshRef};
use crate::io::Mesh;
use crate::scene::{Scene, SceneBuildError};

/// The first 8 bytes of a baked scene file.
pub const SCENE_MAGIC: [u8; 8] = *b"OCTOSCN\0";
/// The version of the baked scene format this build writes and reads.
pub const SCENE_FORMAT_VERSION: u32 = 2;

/// Bytes of the header: magic, version, flags, five counts, the radius, the file's length.
const HEADER_BYTES: usize = 48;
/// Bytes of the checksum at the end.
const CHECKSUM_BYTES: usize = 8;
/// `parent` of a root node.
const NO_PARENT: u32 = u32::MAX;
/// The name of a scene made in memory, in messages.
const IN_MEMORY: &str = "(baked scene)";

/// A baked scene: the proxies and meshes, with the graph that places and moves them.
///
/// **Proxies.** Without a particle radius each mesh has one proxy, whatever scale its
/// instances have. Baked for a radius `R` ([`bake_scene_for_radius`]), a mesh has one proxy
/// per distinct world scale `s` of its instances, baked for `R / s`: the offset surface of a
/// scaled instance is then at `R` in the world. Such an instance's scale must not change over
/// the animation; its poses are sampled with exactly the scale its proxy was baked for.
#[derive(Clone, Debug, PartialEq)]
pub struct BakedScene {
    meshes: Vec<SceneMesh>,
    proxies: Vec<BakedProxy>,
    /// Each instance's proxy.
    instance_proxies: Vec<u32>,
    radius: f32,
    graph: SceneGraph,
}

/// One proxy of a [`BakedScene`]: what it was baked from and for.
#[derive(Clone, Debug, PartialEq)]
pub struct BakedProxy {
    /// The mesh it was baked from (an index into the scene's meshes).
    pub mesh: u32,
    /// The world scale of the instances that use it: it was baked for the scene's particle
    /// radius divided by this scale (1 in a scene without a radius).
    pub scale: f32,
    /// Its words, as core encodes a proxy.
    pub words: Vec<u32>,
}

/// Why a scene could not be baked.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BakeSceneError {
    /// A mesh did not bake.
    #[error("mesh {mesh}{}: {source}", super::graph::quoted(.mesh_name))]
    Build {
        /// The mesh (an index into the scene's meshes).
        mesh: u32,
        /// Its name.
        mesh_name: String,
        /// Why.
        source: BuildError,
    },
    /// The result did not hold together.
    #[error(transparent)]
    Scene(#[from] BakedSceneError),
    /// The particle radius is negative or not finite.
    #[error("the particle radius must be a finite number >= 0, got {0}")]
    BadRadius(f32),
}

/// Why a baked scene could not be read (or assembled). Every message starts with the file
/// name.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BakedSceneError {
    /// The file could not be read or written.
    #[error("{file}: {source}")]
    Io {
        /// The file.
        file: String,
        /// The cause.
        source: std::io::Error,
    },
    /// Not a baked scene file.
    #[error("{file}: not an octoproxy scene file (its first bytes are not `OCTOSCN\\0`)")]
    Magic {
        /// The file.
        file: String,
    },
    /// A format version this build does not read.
    #[error("{file}: scene format version {found}, but this build reads version {SCENE_FORMAT_VERSION}: bake the scene again")]
    Version {
        /// The file.
        file: String,
        /// The version in the file.
        found: u32,
    },
    /// The file's length is not the one its header gives (truncated, or bytes after its end).
    #[error("{file}: the header says the file has {header} bytes, but it has {actual}{}", if .actual < .header { " (truncated)" } else { " (trailing bytes)" })]
    Length {
        /// The file.
        file: String,
        /// The length in the header.
        header: u64,
        /// The actual length.
        actual: u64,
    },
    /// The file ends inside a section, or a count is larger than the bytes left.
    #[error("{file}: byte {at}: {what} needs {needed} bytes, but only {left} are left")]
    Truncated {
        /// The file.
        file: String,
        /// Where.
        at: usize,
        /// What was being read.
        what: String,
        /// Bytes it needs.
        needed: u64,
        /// Bytes left before the checksum.
        left: usize,
    },
    /// A value that cannot be.
    #[error("{file}: byte {at}: {message}")]
    Malformed {
        /// The file.
        file: String,
        /// Where.
        at: usize,
        /// What is wrong.
        message: String,
    },
    /// The sections end before the checksum does not begin.
    #[error("{file}: {count} bytes between the last section and the checksum")]
    TrailingBytes {
        /// The file.
        file: String,
        /// How many.
        count: usize,
    },
    /// A proxy did not validate.
    #[error("{file}: proxy {proxy}: {source}")]
    Proxy {
        /// The file.
        file: String,
        /// The proxy (= the mesh) index.
        proxy: u32,
        /// Why.
        source: FormatError,
    },
    /// A mesh is malformed.
    #[error("{file}: mesh {mesh}: {message}")]
    Mesh {
        /// The file.
        file: String,
        /// The mesh.
        mesh: u32,
        /// What is wrong.
        message: String,
    },
    /// The graph did not validate.
    #[error("{file}: {source}")]
    Graph {
        /// The file.
        file: String,
        /// Why.
        source: GraphError,
    },
    /// An instance is not rigid somewhere in the animation.
    #[error("{file}: {source}")]
    Pose {
        /// The file.
        file: String,
        /// Where and what.
        source: PoseError,
    },
    /// In a scene baked for a particle radius, an instance's world scale changes over the
    /// animation: the offset surface of its proxy would have to change with it.
    #[error("{file}: instance {instance} (node {node}{}): its world scale changes over the animation ({min} at {min_at} s, {max} at {max_at} s), but the scene is baked for particles of radius {radius}, and an offset surface does not scale with its mesh: keep the scale of this node and its parents fixed, or bake without a radius", super::graph::quoted(.node_name))]
    AnimatedScale {
        /// The file.
        file: String,
        /// The instance.
        instance: u32,
        /// Its node.
        node: u32,
        /// The node's name.
        node_name: String,
        /// The particle radius.
        radius: f32,
        /// The smallest world scale sampled.
        min: f32,
        /// When (seconds).
        min_at: f64,
        /// The largest.
        max: f32,
        /// When (seconds).
        max_at: f64,
    },
    /// A proxy, or an instance's proxy, does not fit the scene.
    #[error("{file}: {message}")]
    Proxies {
        /// The file.
        file: String,
        /// What is wrong.
        message: String,
    },
    /// The checksum does not match: the file is damaged.
    #[error("{file}: checksum mismatch (stored {stored:#018x}, computed {computed:#018x}): the file is damaged")]
    Checksum {
        /// The file.
        file: String,
        /// The stored checksum.
        stored: u64,
        /// The checksum of the bytes.
        computed: u64,
    },
}

/// Why a baked scene could not be placed in a [`Scene`].
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SceneSetupError {
    /// A pose could not be sampled.
    #[error(transparent)]
    Pose(#[from] PoseError),
    /// The scene refused a proxy or an instance.
    #[error(transparent)]
    Scene(#[from] SceneBuildError),
}

/// Bakes every mesh of `scene` once, with `params`, reporting to `progress` (each mesh's bake
/// in turn); returns the baked scene and one report per mesh.
pub fn bake_scene(
    scene: &SceneDescription,
    params: &BuildParams,
    progress: &dyn BuildProgress,
) -> Result<(BakedScene, Vec<BuildReport>), BakeSceneError> {
    bake_scene_for_radius(scene, params, 0.0, progress).map(|(baked, reports, _)| (baked, reports))
}

/// Bakes `scene` for particles of `radius` (0: [`bake_scene`]): each mesh once per distinct
/// world scale `s` of its instances (equal within [`RADIUS_TOLERANCE`]), for the offset
/// surface at `radius / s` ([`crate::bake_with_radius`]), so that every instance's offset
/// surface is at `radius` in the world. A hidden instance (scale 0 throughout) shares its
/// mesh's proxy at scale 1. An instance whose world scale changes over the animation (at
/// its keys and halfway between them) is an error naming its node, found before anything is
/// baked. Returns the scene, one report per proxy, and each proxy's offset surface (empty
/// without a radius), which moves starting particles out of the band and gives their sides.
pub fn bake_scene_for_radius(
    scene: &SceneDescription,
    params: &BuildParams,
    radius: f32,
    progress: &dyn BuildProgress,
) -> Result<(BakedScene, Vec<BuildReport>, Vec<OffsetSurface>), BakeSceneError> {
    if !(radius >= 0.0) || !radius.is_finite() {
        return Err(BakeSceneError::BadRadius(radius));
    }
    let (groups, instance_proxies) =
        proxy_groups(IN_MEMORY, &scene.graph, scene.meshes.len(), radius)?;
    let mut proxies = Vec::with_capacity(groups.len());
    let mut reports = Vec::with_capacity(groups.len());
    let mut surfaces = Vec::new();
    for &(mesh, scale) in &groups {
        let m = &scene.meshes[mesh as usize];
        let (words, report, surface) = crate::bake::bake_keeping_surface(
            &[MeshRef::from(&m.mesh)],
            params,
            radius / scale,
            progress,
        )
        .map_err(|source| BakeSceneError::Build {
            mesh,
            mesh_name: m.name.clone(),
            source,
        })?;
        proxies.push(BakedProxy { mesh, scale, words });
        reports.push(report);
        surfaces.extend(surface);
    }
    let baked = BakedScene::with_proxies(
        scene.meshes.clone(),
        proxies,
        instance_proxies,
        radius,
        scene.graph.clone(),
    )?;
    Ok((baked, reports, surfaces))
}

/// The proxies a scene needs, as (mesh, world scale), and each instance's proxy.
type ProxyGroups = (Vec<(u32, f32)>, Vec<u32>);

/// The proxies a scene needs, as (mesh, world scale), and each instance's: one per mesh
/// without a radius; with one, one per mesh and distinct fixed world scale.
fn proxy_groups(
    file: &str,
    graph: &SceneGraph,
    meshes: usize,
    radius: f32,
) -> Result<ProxyGroups, BakedSceneError> {
    if radius == 0.0 {
        let groups = (0..meshes as u32).map(|m| (m, 1.0)).collect();
        return Ok((groups, graph.instances().iter().map(|i| i.mesh).collect()));
    }
    let mut groups: Vec<(u32, f32)> = Vec::new();
    let mut of_instance = Vec::with_capacity(graph.instances().len());
    for (k, inst) in graph.instances().iter().enumerate() {
        let scale = fixed_scale(file, graph, k as u32, radius)?;
        let p = match groups
            .iter()
            .position(|&(m, s)| m == inst.mesh && same_scale(s, scale))
        {
            Some(p) => p,
            None => {
                groups.push((inst.mesh, scale));
                groups.len() - 1
            }
        };
        of_instance.push(p as u32);
    }
    Ok((groups, of_instance))
}

/// Instance `instance`'s world scale, which must hold through the animation (1 for an
/// instance hidden throughout, at scale 0).
fn fixed_scale(
    file: &str,
    graph: &SceneGraph,
    instance: u32,
    radius: f32,
) -> Result<f32, BakedSceneError> {
    let range = graph
        .scale_range(instance)
        .map_err(|source| BakedSceneError::Pose {
            file: file.to_string(),
            source,
        })?;
    if !range.is_fixed(RADIUS_TOLERANCE) {
        let node = graph.instances()[instance as usize].node;
        return Err(BakedSceneError::AnimatedScale {
            file: file.to_string(),
            instance,
            node,
            node_name: graph.node_name(instance).to_string(),
            radius,
            min: range.min,
            min_at: range.min_at,
            max: range.max,
            max_at: range.max_at,
        });
    }
    Ok(if range.max == 0.0 { 1.0 } else { range.at_zero })
}

/// Two world scales one proxy serves.
fn same_scale(a: f32, b: f32) -> bool {
    (a - b).abs() <= RADIUS_TOLERANCE * a.max(b)
}

/// FNV-1a, 64-bit: the file's checksum (any one changed byte changes it).
pub(super) fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for &b in bytes {
        h = (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

impl BakedScene {
    /// Checks and assembles a baked scene without a particle radius, proxy `k` baked from
    /// mesh `k` and serving every instance of it: see [`BakedScene::with_proxies`].
    pub fn new(
        meshes: Vec<SceneMesh>,
        proxies: Vec<Vec<u32>>,
        graph: SceneGraph,
    ) -> Result<BakedScene, BakedSceneError> {
        let proxies: Vec<BakedProxy> = proxies
            .into_iter()
            .enumerate()
            .map(|(k, words)| BakedProxy {
                mesh: k as u32,
                scale: 1.0,
                words,
            })
            .collect();
        let instance_proxies = graph.instances().iter().map(|i| i.mesh).collect();
        Self::assemble(IN_MEMORY, meshes, proxies, instance_proxies, 0.0, graph)
    }

    /// Checks and assembles a baked scene for particles of `radius` (0 for none): meshes
    /// non-empty, finite, with indices in range; each proxy valid, of an existing mesh, baked
    /// for `radius` at its scale (for no radius, at scale 1); each instance's proxy one of
    /// its mesh's, and with a radius the instance's world scale fixed over the animation and
    /// the proxy's (or 0 throughout); the graph's instances rigid at every key; and every
    /// count within the file format's `u32`.
    pub fn with_proxies(
        meshes: Vec<SceneMesh>,
        proxies: Vec<BakedProxy>,
        instance_proxies: Vec<u32>,
        radius: f32,
        graph: SceneGraph,
    ) -> Result<BakedScene, BakedSceneError> {
        Self::assemble(IN_MEMORY, meshes, proxies, instance_proxies, radius, graph)
    }

    fn assemble(
        file: &str,
        meshes: Vec<SceneMesh>,
        proxies: Vec<BakedProxy>,
        instance_proxies: Vec<u32>,
        radius: f32,
        graph: SceneGraph,
    ) -> Result<BakedScene, BakedSceneError> {
        let mesh_err = |mesh: usize, message: String| BakedSceneError::Mesh {
            file: file.to_string(),
            mesh: mesh as u32,
            message,
        };
        let proxy_err = |message: String| BakedSceneError::Proxies {
            file: file.to_string(),
            message,
        };
        if !(radius >= 0.0) || !radius.is_finite() {
            return Err(proxy_err(format!(
                "the particle radius is {radius}: it must be a finite number >= 0"
            )));
        }
        let too_many = |n: usize| n > u32::MAX as usize;
        if too_many(meshes.len())
            || too_many(proxies.len())
            || too_many(graph.nodes().len())
            || too_many(graph.channels().len())
        {
            return Err(mesh_err(0, "more items than the file format counts".into()));
        }
        for (k, m) in meshes.iter().enumerate() {
            if too_many(m.name.len())
                || too_many(m.mesh.positions.len())
                || too_many(m.mesh.triangles.len())
            {
                return Err(mesh_err(k, "too large for the file format".into()));
            }
            check_mesh(&m.mesh).map_err(|message| mesh_err(k, message))?;
        }
        for (k, p) in proxies.iter().enumerate() {
            if too_many(p.words.len()) {
                return Err(proxy_err(format!(
                    "proxy {k} is too large for the file format"
                )));
            }
            if p.mesh as usize >= meshes.len() {
                return Err(proxy_err(format!(
                    "proxy {k} is of mesh {}, which does not exist ({} meshes)",
                    p.mesh,
                    meshes.len()
                )));
            }
            let view = ProxyView::new(&p.words).map_err(|source| BakedSceneError::Proxy {
                file: file.to_string(),
                proxy: k as u32,
                source,
            })?;
            let baked = view.header().radius;
            let fits = if radius == 0.0 {
                baked == 0.0 && p.scale == 1.0
            } else {
                p.scale.is_finite()
                    && p.scale > 0.0
                    && check_radius(baked * p.scale, radius).is_ok()
            };
            if !fits {
                return Err(proxy_err(format!(
                    "proxy {k} is baked for radius {baked} at scale {}, which is not the scene's particle radius {radius}{}",
                    p.scale,
                    if radius == 0.0 { " (a scene without a radius has proxies without one, at scale 1)" } else { "" }
                )));
            }
        }
        if graph.nodes().iter().any(|n| too_many(n.name.len()))
            || graph.channels().iter().any(|c| too_many(c.times.len()))
        {
            return Err(mesh_err(
                0,
                "a name or channel is too large for the file format".into(),
            ));
        }
        if let Some((k, inst)) = graph
            .instances()
            .iter()
            .enumerate()
            .find(|(_, i)| i.mesh as usize >= meshes.len())
        {
            return Err(BakedSceneError::Graph {
                file: file.to_string(),
                source: GraphError::BadInstance {
                    instance: k as u32,
                    why: format!(
                        "its mesh {} does not exist ({} meshes)",
                        inst.mesh,
                        meshes.len()
                    ),
                },
            });
        }
        if instance_proxies.len() != graph.instances().len() {
            return Err(proxy_err(format!(
                "{} instances but {} instance proxies",
                graph.instances().len(),
                instance_proxies.len()
            )));
        }
        for (k, (inst, &p)) in graph.instances().iter().zip(&instance_proxies).enumerate() {
            if proxies.get(p as usize).is_none_or(|p| p.mesh != inst.mesh) {
                return Err(proxy_err(format!(
                    "instance {k} of mesh {} has proxy {p}, which is not one of that mesh's",
                    inst.mesh
                )));
            }
        }
        graph
            .check_rigid()
            .map_err(|source| BakedSceneError::Pose {
                file: file.to_string(),
                source,
            })?;
        if radius > 0.0 {
            for (k, &p) in instance_proxies.iter().enumerate() {
                let scale = fixed_scale(file, &graph, k as u32, radius)?;
                if !same_scale(scale, proxies[p as usize].scale) {
                    return Err(proxy_err(format!(
                        "instance {k} has world scale {scale}, but its proxy {p} is baked for scale {}",
                        proxies[p as usize].scale
                    )));
                }
            }
        }
        Ok(BakedScene {
            meshes,
            proxies,
            instance_proxies,
            radius,
            graph,
        })
    }

    /// The meshes, by index.
    pub fn meshes(&self) -> &[SceneMesh] {
        &self.meshes
    }

    /// The proxies: one per mesh without a radius, else one per mesh and world scale.
    pub fn proxies(&self) -> &[BakedProxy] {
        &self.proxies
    }

    /// Each instance's proxy (an index into [`BakedScene::proxies`]).
    pub fn instance_proxies(&self) -> &[u32] {
        &self.instance_proxies
    }

    /// The particle radius the scene is baked for (0 for none).
    pub fn radius(&self) -> f32 {
        self.radius
    }

    /// Each proxy's offset surface, built again from its mesh for the scene's radius at the
    /// proxy's scale and `dmax` (what [`bake_scene_for_radius`] returns beside the scene):
    /// it moves starting particles out of the band and gives their sides. Empty without a
    /// radius.
    pub fn offset_surfaces(
        &self,
        progress: &dyn BuildProgress,
    ) -> Result<Vec<OffsetSurface>, BakeSceneError> {
        if self.radius == 0.0 {
            return Ok(Vec::new());
        }
        self.proxies
            .iter()
            .map(|p| {
                let m = &self.meshes[p.mesh as usize];
                // Valid since assembly.
                let dmax = ProxyView::new(&p.words).map_or(0, |v| v.header().dmax);
                OffsetSurface::new(
                    &[MeshRef::from(&m.mesh)],
                    self.radius / p.scale,
                    dmax,
                    progress,
                )
                .map_err(|source| BakeSceneError::Build {
                    mesh: p.mesh,
                    mesh_name: m.name.clone(),
                    source,
                })
            })
            .collect()
    }

    /// The nodes, instances and channels.
    pub fn graph(&self) -> &SceneGraph {
        &self.graph
    }

    /// The instances.
    pub fn instances(&self) -> &[SceneInstance] {
        self.graph.instances()
    }

    /// The world pose of instance `instance` at time `t` in seconds (with a radius, at
    /// exactly the scale its proxy was baked for: see [`BakedScene::poses_at`]).
    pub fn pose_at(&self, instance: u32, t: f64) -> Result<Pose, PoseError> {
        let pose = self.graph.pose_at(instance, t)?;
        Ok(self.at_baked_scale(instance as usize, pose))
    }

    /// The world poses of every instance at time `t`, by instance index. In a scene baked
    /// for a radius, a scale within [`RADIUS_TOLERANCE`] of the one its proxy was baked for
    /// (as assembly checked at every key) is that scale exactly, so that its rounding never
    /// reads as a change of scale in a step.
    pub fn poses_at(&self, t: f64) -> Result<Vec<Pose>, PoseError> {
        let mut poses = self.graph.poses_at(t)?;
        for (k, pose) in poses.iter_mut().enumerate() {
            *pose = self.at_baked_scale(k, *pose);
        }
        Ok(poses)
    }

    fn at_baked_scale(&self, instance: usize, mut pose: Pose) -> Pose {
        if self.radius > 0.0 && pose.scale != 0.0 {
            if let Some(p) = self
                .instance_proxies
                .get(instance)
                .and_then(|&p| self.proxies.get(p as usize))
            {
                if same_scale(pose.scale, p.scale) {
                    pose.scale = p.scale;
                }
            }
        }
        pose
    }

    /// The animation's length in seconds (0 without animation).
    pub fn duration(&self) -> f64 {
        self.graph.duration()
    }

    /// A [`Scene`] holding every proxy once and every instance at its pose at time 0; returns
    /// it with the scene's instance indices, which are the glTF instance indices.
    pub fn build_scene(&self) -> Result<(Scene, Vec<u32>), SceneSetupError> {
        let mut scene = Scene::new();
        let mut proxy_ids = Vec::with_capacity(self.proxies.len());
        for p in &self.proxies {
            proxy_ids.push(scene.add_proxy(p.words.clone())?);
        }
        let poses = self.poses_at(0.0)?;
        let mut ids = Vec::with_capacity(poses.len());
        for (&p, pose) in self.instance_proxies.iter().zip(poses) {
            ids.push(scene.add_instance(proxy_ids[p as usize], pose)?);
        }
        Ok((scene, ids))
    }

    /// The file's bytes (the format is in `FORMAT.md`).
    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer::default();
        w.bytes.extend_from_slice(&SCENE_MAGIC);
        w.u32(SCENE_FORMAT_VERSION);
        w.u32(0);
        let g = &self.graph;
        for n in [
            self.meshes.len(),
            self.proxies.len(),
            g.nodes().len(),
            g.instances().len(),
            g.channels().len(),
        ] {
            w.u32(n as u32);
        }
        w.f32s(&[self.radius]);
        // The length, filled in at the end.
        w.u64(0);
        for m in &self.meshes {
            w.name(&m.name);
            w.u32(m.mesh.positions.len() as u32);
            w.u32(m.mesh.triangles.len() as u32);
            for p in &m.mesh.positions {
                w.f32s(p);
            }
            for t in &m.mesh.triangles {
                for &i in t {
                    w.u32(i);
                }
            }
        }
        for p in &self.proxies {
            w.u32(p.mesh);
            w.f32s(&[p.scale]);
            w.u32(p.words.len() as u32);
            for &x in &p.words {
                w.u32(x);
            }
        }
        for n in g.nodes() {
            w.name(&n.name);
            w.u32(n.parent.unwrap_or(NO_PARENT));
            match &n.transform {
                NodeTransform::Trs(t) => {
                    w.u32(0);
                    w.trs(t);
                }
                NodeTransform::Matrix(m) => {
                    w.u32(1);
                    w.f32s(m);
                }
            }
        }
        for (i, &p) in g.instances().iter().zip(&self.instance_proxies) {
            w.u32(i.node);
            w.u32(i.mesh);
            w.u32(i.copy);
            w.u32(p);
            w.trs(&i.local);
        }
        for c in g.channels() {
            w.u32(c.node);
            w.u32(match c.path {
                ChannelPath::Translation => 0,
                ChannelPath::Rotation => 1,
                ChannelPath::Scale => 2,
            });
            w.u32(match c.interpolation {
                Interpolation::Linear => 0,
                Interpolation::Step => 1,
                Interpolation::CubicSpline => 2,
            });
            w.u32(c.times.len() as u32);
            w.f32s(&c.times);
            w.f32s(&c.values);
        }
        let total = (w.bytes.len() + CHECKSUM_BYTES) as u64;
        w.bytes[40..48].copy_from_slice(&total.to_le_bytes());
        let sum = fnv1a64(&w.bytes);
        w.u64(sum);
        w.bytes
    }

    /// Writes the file.
    pub fn write(&self, path: &Path) -> Result<(), BakedSceneError> {
        std::fs::write(path, self.encode()).map_err(|source| BakedSceneError::Io {
            file: path.display().to_string(),
            source,
        })
    }

    /// Reads a baked scene file.
    pub fn read(path: &Path) -> Result<BakedScene, BakedSceneError> {
        let file = path.display().to_string();
        let bytes = std::fs::read(path).map_err(|source| BakedSceneError::Io {
            file: file.clone(),
            source,
        })?;
        Self::parse(&file, &bytes)
    }

    /// Parses the bytes of a baked scene file; `name` is used in messages.
    pub fn parse(name: &str, bytes: &[u8]) -> Result<BakedScene, BakedSceneError> {
        let file = name.to_string();
        if bytes.len() < SCENE_MAGIC.len() || bytes[..SCENE_MAGIC.len()] != SCENE_MAGIC {
            return Err(BakedSceneError::Magic { file });
        }
        let mut r = Reader {
            file: name,
            bytes,
            at: SCENE_MAGIC.len(),
            end: bytes.len(),
        };
        let version = r.u32("the format version")?;
        if version != SCENE_FORMAT_VERSION {
            return Err(BakedSceneError::Version {
                file,
                found: version,
            });
        }
        if bytes.len() < HEADER_BYTES + CHECKSUM_BYTES {
            return Err(BakedSceneError::Truncated {
                file,
                at: r.at,
                what: "the header and checksum".into(),
                needed: (HEADER_BYTES + CHECKSUM_BYTES - r.at) as u64,
                left: bytes.len() - r.at,
            });
        }
        let flags = r.u32("the flags")?;
        if flags != 0 {
            return Err(r.malformed(r.at - 4, format!("flags {flags:#x}: no flags are defined")));
        }
        let mesh_count = r.u32("the mesh count")?;
        let proxy_count = r.u32("the proxy count")?;
        let node_count = r.u32("the node count")?;
        let instance_count = r.u32("the instance count")?;
        let channel_count = r.u32("the channel count")?;
        let radius = r.f32()?;
        let total = r.u64("the file length")?;
        if total != bytes.len() as u64 {
            return Err(BakedSceneError::Length {
                file,
                header: total,
                actual: bytes.len() as u64,
            });
        }
        r.end = bytes.len() - CHECKSUM_BYTES;

        // Meshes: a name and two counts at least, per mesh.
        r.room(mesh_count as u64, 12, "the meshes")?;
        let mut meshes = Vec::with_capacity(mesh_count as usize);
        for k in 0..mesh_count {
            let name = r.name(&format!("the name of mesh {k}"))?;
            let vertices = r.u32("a vertex count")?;
            let triangles = r.u32("a triangle count")?;
            r.room(
                vertices as u64,
                12,
                &format!("the {vertices} vertices of mesh {k}"),
            )?;
            let positions: Vec<[f32; 3]> = (0..vertices)
                .map(|_| Ok([r.f32()?, r.f32()?, r.f32()?]))
                .collect::<Result<_, BakedSceneError>>()?;
            r.room(
                triangles as u64,
                12,
                &format!("the {triangles} triangles of mesh {k}"),
            )?;
            let tris: Vec<[u32; 3]> = (0..triangles)
                .map(|_| Ok([r.u32("")?, r.u32("")?, r.u32("")?]))
                .collect::<Result<_, BakedSceneError>>()?;
            meshes.push(SceneMesh {
                name,
                mesh: Mesh {
                    positions,
                    triangles: tris,
                },
            });
        }

        // Proxies: a mesh, a scale and a word count at least, per proxy.
        r.room(proxy_count as u64, 12, "the proxies")?;
        let mut proxies = Vec::with_capacity(proxy_count as usize);
        for k in 0..proxy_count {
            let mesh = r.u32("a proxy's mesh")?;
            let scale = r.f32()?;
            let words = r.u32("a proxy word count")?;
            r.room(words as u64, 4, &format!("the {words} words of proxy {k}"))?;
            let words: Vec<u32> = (0..words)
                .map(|_| r.u32(""))
                .collect::<Result<_, BakedSceneError>>()?;
            proxies.push(BakedProxy { mesh, scale, words });
        }

        // Nodes: a name, a parent, a kind and ten floats at least.
        r.room(node_count as u64, 52, "the nodes")?;
        let mut nodes = Vec::with_capacity(node_count as usize);
        for k in 0..node_count {
            let name = r.name(&format!("the name of node {k}"))?;
            let parent = r.u32("a parent")?;
            let kind_at = r.at;
            let transform = match r.u32("a transform kind")? {
                0 => NodeTransform::Trs(r.trs()?),
                1 => {
                    let mut m = [0.0f32; 16];
                    for x in &mut m {
                        *x = r.f32()?;
                    }
                    NodeTransform::Matrix(m)
                }
                other => {
                    return Err(r.malformed(
                        kind_at,
                        format!("node {k}: transform kind {other} (0 is TRS, 1 a matrix)"),
                    ))
                }
            };
            nodes.push(SceneNode {
                name,
                parent: (parent != NO_PARENT).then_some(parent),
                transform,
            });
        }

        // Instances: 14 words each.
        r.room(instance_count as u64, 56, "the instances")?;
        let mut instances = Vec::with_capacity(instance_count as usize);
        let mut instance_proxies = Vec::with_capacity(instance_count as usize);
        for _ in 0..instance_count {
            let node = r.u32("an instance's node")?;
            let mesh = r.u32("an instance's mesh")?;
            let copy = r.u32("an instance's copy")?;
            instance_proxies.push(r.u32("an instance's proxy")?);
            let local = r.trs()?;
            instances.push(SceneInstance {
                node,
                mesh,
                copy,
                local,
            });
        }

        // Channels: four words and at least one key each.
        r.room(channel_count as u64, 20, "the channels")?;
        let mut channels = Vec::with_capacity(channel_count as usize);
        for k in 0..channel_count {
            let node = r.u32("a channel's node")?;
            let path_at = r.at;
            let path = match r.u32("a channel's path")? {
                0 => ChannelPath::Translation,
                1 => ChannelPath::Rotation,
                2 => ChannelPath::Scale,
                other => {
                    return Err(r.malformed(
                        path_at,
                        format!("channel {k}: path {other} (0 translation, 1 rotation, 2 scale)"),
                    ))
                }
            };
            let interp_at = r.at;
            let interpolation = match r.u32("a channel's interpolation")? {
                0 => Interpolation::Linear,
                1 => Interpolation::Step,
                2 => Interpolation::CubicSpline,
                other => {
                    return Err(r.malformed(
                        interp_at,
                        format!(
                            "channel {k}: interpolation {other} (0 LINEAR, 1 STEP, 2 CUBICSPLINE)"
                        ),
                    ))
                }
            };
            let keys = r.u32("a key count")?;
            let per_key = 1 + path.width() * interpolation.entries_per_key();
            r.room(
                keys as u64,
                4 * per_key as u64,
                &format!("the {keys} keys of channel {k}"),
            )?;
            let times: Vec<f32> = (0..keys).map(|_| r.f32()).collect::<Result<_, _>>()?;
            let values: Vec<f32> = (0..keys as usize * (per_key - 1))
                .map(|_| r.f32())
                .collect::<Result<_, _>>()?;
            channels.push(Channel {
                node,
                path,
                interpolation,
                times,
                values,
            });
        }
        if r.at != r.end {
            return Err(BakedSceneError::TrailingBytes {
                file,
                count: r.end - r.at,
            });
        }

        let graph =
            SceneGraph::new(nodes, instances, channels, meshes.len()).map_err(|source| {
                BakedSceneError::Graph {
                    file: file.clone(),
                    source,
                }
            })?;
        let scene = Self::assemble(name, meshes, proxies, instance_proxies, radius, graph)?;

        // The checksum last, so that damage the structure shows keeps its own message.
        let body = &bytes[..bytes.len() - CHECKSUM_BYTES];
        let mut stored = [0u8; 8];
        stored.copy_from_slice(&bytes[bytes.len() - CHECKSUM_BYTES..]);
        let stored = u64::from_le_bytes(stored);
        let computed = fnv1a64(body);
        if stored != computed {
            return Err(BakedSceneError::Checksum {
                file,
                stored,
                computed,
            });
        }
        Ok(scene)
    }
}

/// A mesh must have a triangle, finite positions and indices in range.
fn check_mesh(m: &Mesh) -> Result<(), String> {
    if m.triangles.is_empty() {
        return Err("it has no triangles".into());
    }
    if let Some(v) = m
        .positions
        .iter()
        .position(|p| !p.iter().all(|c| c.is_finite()))
    {
        return Err(format!("vertex {v} is not finite"));
    }
    let n = m.positions.len();
    if let Some((t, i)) = m
        .triangles
        .iter()
        .enumerate()
        .find_map(|(t, tri)| tri.iter().find(|&&i| i as usize >= n).map(|&i| (t, i)))
    {
        return Err(format!(
            "triangle {t} uses vertex {i}, but the mesh has {n} vertices"
        ));
    }
    Ok(())
}

#[derive(Default)]
struct Writer {
    bytes: Vec<u8>,
}

impl Writer {
    fn u32(&mut self, x: u32) {
        self.bytes.extend_from_slice(&x.to_le_bytes());
    }
    fn u64(&mut self, x: u64) {
        self.bytes.extend_from_slice(&x.to_le_bytes());
    }
    fn f32s(&mut self, xs: &[f32]) {
        for x in xs {
            self.bytes.extend_from_slice(&x.to_bits().to_le_bytes());
        }
    }
    fn trs(&mut self, t: &Trs) {
        self.f32s(&t.translation);
        self.f32s(&t.rotation);
        self.f32s(&t.scale);
    }
    /// A length, the UTF-8 bytes, zeros to a multiple of 4.
    fn name(&mut self, s: &str) {
        self.u32(s.len() as u32);
        self.bytes.extend_from_slice(s.as_bytes());
        while !self.bytes.len().is_multiple_of(4) {
            self.bytes.push(0);
        }
    }
}

struct Reader<'a> {
    file: &'a str,
    bytes: &'a [u8],
    at: usize,
    /// Where the sections end (the checksum's start, once the header is read).
    end: usize,
}

impl<'a> Reader<'a> {
    fn malformed(&self, at: usize, message: String) -> BakedSceneError {
        BakedSceneError::Malformed {
            file: self.file.to_string(),
            at,
            message,
        }
    }

    /// Room for `count` items of `size` bytes, before allocating for them.
    fn room(&self, count: u64, size: u64, what: &str) -> Result<(), BakedSceneError> {
        let needed = count.saturating_mul(size);
        let left = self.end.saturating_sub(self.at);
        if needed > left as u64 {
            return Err(BakedSceneError::Truncated {
                file: self.file.to_string(),
                at: self.at,
                what: what.to_string(),
                needed,
                left,
            });
        }
        Ok(())
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], BakedSceneError> {
        self.room(n as u64, 1, if what.is_empty() { "a value" } else { what })?;
        let bytes: &'a [u8] = self.bytes;
        let s = &bytes[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }

    fn u32(&mut self, what: &str) -> Result<u32, BakedSceneError> {
        let b = self.take(4, what)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn u64(&mut self, what: &str) -> Result<u64, BakedSceneError> {
        let b = self.take(8, what)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(u64::from_le_bytes(a))
    }

    fn f32(&mut self) -> Result<f32, BakedSceneError> {
        Ok(f32::from_bits(self.u32("a float")?))
    }

    fn trs(&mut self) -> Result<Trs, BakedSceneError> {
        let mut f = [0.0f32; 10];
        for x in &mut f {
            *x = self.f32()?;
        }
        Ok(Trs {
            translation: [f[0], f[1], f[2]],
            rotation: [f[3], f[4], f[5], f[6]],
            scale: [f[7], f[8], f[9]],
        })
    }

    fn name(&mut self, what: &str) -> Result<String, BakedSceneError> {
        let len = self.u32(what)? as usize;
        let start = self.at;
        let padded = len.div_ceil(4) * 4;
        let b = self.take(padded, what)?;
        let (text, pad) = b.split_at(len);
        if pad.iter().any(|&x| x != 0) {
            return Err(self.malformed(start + len, format!("{what}: its padding is not zero")));
        }
        match std::str::from_utf8(text) {
            Ok(s) => Ok(s.to_string()),
            Err(_) => Err(self.malformed(start, format!("{what} is not valid UTF-8"))),
        }
    }
}
