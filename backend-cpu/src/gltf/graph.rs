//! The node hierarchy, the instances that hang meshes on it and the animation channels that
//! move it: everything needed to sample the world pose of every instance at any time, shared
//! by a glTF scene ([`super::SceneDescription`]) and a baked scene ([`super::BakedScene`]) so
//! that both sample the very same bits.
//!
//! [`SceneGraph::new`] checks everything once (indices in range, parents acyclic, transforms
//! finite, key times finite and strictly increasing, values finite, at most one channel per
//! node and path); sampling then trusts the type. World transforms are composed in `f64`, and
//! each instance's must be a uniform scale times a rotation plus a translation
//! ([`SceneGraph::check_rigid`] tries the rest pose, every key time and every halfway point
//! between keys).

use glam::{DMat3, DMat4, DQuat, DVec3, DVec4};
use octoproxy_core::scene::Pose;

use crate::scene::normalize_rotation;

/// Relative tolerance on the world transform's column lengths and their orthogonality.
pub const RIGID_TOLERANCE: f64 = 1e-5;

/// A translation, a rotation (a quaternion `[x, y, z, w]`, not necessarily of unit length: it
/// is normalized when used) and a per-axis scale, applied scale first: glTF's TRS.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Trs {
    /// Translation.
    pub translation: [f32; 3],
    /// Rotation, a quaternion `[x, y, z, w]`.
    pub rotation: [f32; 4],
    /// Scale per axis.
    pub scale: [f32; 3],
}

impl Trs {
    /// No translation, no rotation, unit scale.
    pub const IDENTITY: Trs = Trs {
        translation: [0.0; 3],
        rotation: [0.0, 0.0, 0.0, 1.0],
        scale: [1.0; 3],
    };
}

impl Default for Trs {
    fn default() -> Self {
        Self::IDENTITY
    }
}

/// A node's transform relative to its parent.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum NodeTransform {
    /// Translation, rotation, scale (animation channels replace any of them).
    Trs(Trs),
    /// A 4×4 matrix, column-major as in glTF (never animated; its last row is `0 0 0 1`).
    Matrix([f32; 16]),
}

/// A node of the hierarchy.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneNode {
    /// Its name (empty when the file gives none).
    pub name: String,
    /// Its parent, `None` for a root (and for a node the scene does not reach).
    pub parent: Option<u32>,
    /// Its rest transform relative to the parent.
    pub transform: NodeTransform,
}

/// What an instance places: a mesh, hung on a node, with a transform of its own after the
/// node's (a copy of `EXT_mesh_gpu_instancing`; the identity otherwise).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneInstance {
    /// The node it hangs on.
    pub node: u32,
    /// Its mesh (an index into the scene's meshes, not the glTF mesh index).
    pub mesh: u32,
    /// Which copy of the node's mesh it is (0 unless the node uses `EXT_mesh_gpu_instancing`).
    pub copy: u32,
    /// Its transform within the node's frame (the copy's TRS; the identity for a plain node).
    pub local: Trs,
}

/// What a channel animates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ChannelPath {
    /// The node's translation (3 values a key).
    Translation,
    /// The node's rotation (4 values a key, a quaternion `[x, y, z, w]`).
    Rotation,
    /// The node's scale (3 values a key).
    Scale,
}

impl ChannelPath {
    /// Values per key (and per tangent).
    pub fn width(self) -> usize {
        match self {
            ChannelPath::Rotation => 4,
            _ => 3,
        }
    }

    /// The glTF name: `translation`, `rotation`, `scale`.
    pub fn name(self) -> &'static str {
        match self {
            ChannelPath::Translation => "translation",
            ChannelPath::Rotation => "rotation",
            ChannelPath::Scale => "scale",
        }
    }

    fn slot(self) -> usize {
        match self {
            ChannelPath::Translation => 0,
            ChannelPath::Rotation => 1,
            ChannelPath::Scale => 2,
        }
    }
}

/// How a channel interpolates between keys.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Interpolation {
    /// Linear: lerp, and for rotations slerp the shorter way.
    Linear,
    /// The value of the key before, held until the next.
    Step,
    /// Cubic Hermite spline: each key holds an in-tangent, a value and an out-tangent, and
    /// the tangents are scaled by the key interval (glTF 2.0, Appendix C); rotations are
    /// normalized after.
    CubicSpline,
}

impl Interpolation {
    /// The glTF name: `LINEAR`, `STEP`, `CUBICSPLINE`.
    pub fn name(self) -> &'static str {
        match self {
            Interpolation::Linear => "LINEAR",
            Interpolation::Step => "STEP",
            Interpolation::CubicSpline => "CUBICSPLINE",
        }
    }

    /// Entries per key: 3 for a cubic spline (in-tangent, value, out-tangent), else 1.
    pub fn entries_per_key(self) -> usize {
        match self {
            Interpolation::CubicSpline => 3,
            _ => 1,
        }
    }
}

/// One animated property of one node.
#[derive(Clone, Debug, PartialEq)]
pub struct Channel {
    /// The node it moves.
    pub node: u32,
    /// What it animates.
    pub path: ChannelPath,
    /// How it interpolates.
    pub interpolation: Interpolation,
    /// Key times in seconds: finite, strictly increasing, at least one.
    pub times: Vec<f32>,
    /// The values, key after key, [`ChannelPath::width`] floats each; for a cubic spline
    /// each key is an in-tangent, a value and an out-tangent.
    pub values: Vec<f32>,
}

/// Why a [`SceneGraph`] does not hold together.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum GraphError {
    /// A node's parent does not exist.
    #[error("node {node}: its parent {parent} does not exist ({nodes} nodes)")]
    ParentOutOfRange {
        /// The node.
        node: u32,
        /// Its parent as given.
        parent: u32,
        /// How many nodes there are.
        nodes: usize,
    },
    /// A node is its own ancestor.
    #[error("node {node} is its own ancestor (the hierarchy has a cycle)")]
    Cycle {
        /// A node on the cycle.
        node: u32,
    },
    /// A node's transform is not finite or not affine.
    #[error("node {node}: {why}")]
    BadTransform {
        /// The node.
        node: u32,
        /// What is wrong.
        why: &'static str,
    },
    /// An instance refers to a node or mesh that does not exist, or has a bad transform.
    #[error("instance {instance}: {why}")]
    BadInstance {
        /// The instance.
        instance: u32,
        /// What is wrong.
        why: String,
    },
    /// A channel is malformed.
    #[error("channel {channel}: {why}")]
    BadChannel {
        /// The channel.
        channel: u32,
        /// What is wrong.
        why: String,
    },
}

/// Why a pose could not be sampled.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum PoseError {
    /// The instance does not exist.
    #[error("instance {instance} does not exist (the scene has {count})")]
    NoSuchInstance {
        /// The instance asked for.
        instance: u32,
        /// How many there are.
        count: usize,
    },
    /// The time is NaN or infinite.
    #[error("time {time} is not finite")]
    BadTime {
        /// The time asked for.
        time: f64,
    },
    /// The instance's world transform is not a uniform scale times a rotation.
    #[error("instance {instance} (node {node}{}) {}: its world transform {why}: deforming meshes (non-rigid transforms) are not supported yet", quoted(.node_name), at(*.time))]
    NonRigid {
        /// The instance.
        instance: u32,
        /// Its node.
        node: u32,
        /// The node's name.
        node_name: String,
        /// The time (`None`: the rest pose).
        time: Option<f64>,
        /// What is wrong (`has a non-uniform scale`, `shears`, `mirrors`).
        why: &'static str,
    },
    /// A node's interpolated rotation has no length (a cubic spline through zero).
    #[error("node {node}{} {}: its rotation has zero length", quoted(.node_name), at(*.time))]
    ZeroRotation {
        /// The node.
        node: u32,
        /// Its name.
        node_name: String,
        /// The time.
        time: Option<f64>,
    },
    /// The pose does not fit `f32` (a translation or scale beyond its range).
    #[error("instance {instance} (node {node}{}) {}: its world pose is beyond f32's range", quoted(.node_name), at(*.time))]
    Overflow {
        /// The instance.
        instance: u32,
        /// Its node.
        node: u32,
        /// The node's name.
        node_name: String,
        /// The time.
        time: Option<f64>,
    },
}

/// ` "name"` for a non-empty name, else nothing.
pub(crate) fn quoted(name: &str) -> String {
    if name.is_empty() {
        String::new()
    } else {
        format!(" \"{}\"", name.escape_debug())
    }
}

fn at(time: Option<f64>) -> String {
    match time {
        Some(t) => format!("at t = {t} s"),
        None => "at rest".to_string(),
    }
}

/// A validated node hierarchy with its instances and animation channels.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneGraph {
    nodes: Vec<SceneNode>,
    instances: Vec<SceneInstance>,
    channels: Vec<Channel>,
    /// Per node, the channel animating its translation, rotation and scale.
    node_channels: Vec<[Option<u32>; 3]>,
    /// Nodes with every ancestor before its descendants.
    order: Vec<u32>,
}

fn finite(v: &[f32]) -> bool {
    v.iter().all(|x| x.is_finite())
}

fn quat_len2(q: [f32; 4]) -> f64 {
    q.iter().map(|&c| c as f64 * c as f64).sum()
}

fn check_trs(t: &Trs) -> Result<(), &'static str> {
    if !finite(&t.translation) {
        return Err("its translation is not finite");
    }
    if !finite(&t.scale) {
        return Err("its scale is not finite");
    }
    if !finite(&t.rotation) {
        return Err("its rotation is not finite");
    }
    if !(quat_len2(t.rotation) > 1e-24) {
        return Err("its rotation quaternion has zero length");
    }
    Ok(())
}

/// Checks a node transform: finite, and a matrix's last row `0 0 0 1`.
pub(crate) fn check_transform(t: &NodeTransform) -> Result<(), &'static str> {
    match t {
        NodeTransform::Trs(trs) => check_trs(trs),
        NodeTransform::Matrix(m) => {
            if !finite(m) {
                return Err("its matrix is not finite");
            }
            if m[3] != 0.0 || m[7] != 0.0 || m[11] != 0.0 || m[15] != 1.0 {
                return Err("its matrix is not affine (its last row must be 0 0 0 1)");
            }
            Ok(())
        }
    }
}

/// Checks a channel's shape on its own: keys, values, and that the values are finite.
pub(crate) fn check_channel(ch: &Channel) -> Result<(), String> {
    if ch.times.is_empty() {
        return Err("it has no keys".into());
    }
    for (k, t) in ch.times.iter().enumerate() {
        if !t.is_finite() {
            return Err(format!("key time {k} is not finite ({t})"));
        }
        if k > 0 && !(ch.times[k - 1] < *t) {
            return Err(format!(
                "key times must strictly increase, but key {k} ({t}) does not come after key {} ({})",
                k - 1,
                ch.times[k - 1]
            ));
        }
    }
    let width = ch.path.width();
    let need = ch
        .times
        .len()
        .checked_mul(width * ch.interpolation.entries_per_key());
    if need != Some(ch.values.len()) {
        return Err(format!(
            "{} keys of {} {} need {} values, but it has {}",
            ch.times.len(),
            ch.interpolation.name(),
            ch.path.name(),
            need.map_or_else(|| "too many".to_string(), |n| n.to_string()),
            ch.values.len()
        ));
    }
    if let Some(v) = ch.values.iter().position(|x| !x.is_finite()) {
        return Err(format!(
            "value {} of key {} is not finite",
            v,
            v / (width * ch.interpolation.entries_per_key())
        ));
    }
    if ch.path == ChannelPath::Rotation && ch.interpolation != Interpolation::CubicSpline {
        for (k, q) in ch.values.chunks_exact(4).enumerate() {
            if let [x, y, z, w] = q {
                if !(quat_len2([*x, *y, *z, *w]) > 1e-24) {
                    return Err(format!("the rotation of key {k} has zero length"));
                }
            }
        }
    }
    Ok(())
}

impl SceneGraph {
    /// Checks and assembles a graph for a scene of `mesh_count` meshes.
    pub fn new(
        nodes: Vec<SceneNode>,
        instances: Vec<SceneInstance>,
        channels: Vec<Channel>,
        mesh_count: usize,
    ) -> Result<SceneGraph, GraphError> {
        let n = nodes.len();
        if n > u32::MAX as usize - 1 {
            return Err(GraphError::BadTransform {
                node: u32::MAX,
                why: "too many nodes",
            });
        }
        for (k, node) in nodes.iter().enumerate() {
            if let Some(p) = node.parent {
                if p as usize >= n {
                    return Err(GraphError::ParentOutOfRange {
                        node: k as u32,
                        parent: p,
                        nodes: n,
                    });
                }
            }
            check_transform(&node.transform).map_err(|why| GraphError::BadTransform {
                node: k as u32,
                why,
            })?;
        }
        let order = topological_order(&nodes)?;
        for (k, inst) in instances.iter().enumerate() {
            let bad = |why: String| GraphError::BadInstance {
                instance: k as u32,
                why,
            };
            if inst.node as usize >= n {
                return Err(bad(format!("its node {} does not exist", inst.node)));
            }
            if inst.mesh as usize >= mesh_count {
                return Err(bad(format!(
                    "its mesh {} does not exist ({mesh_count} meshes)",
                    inst.mesh
                )));
            }
            check_trs(&inst.local).map_err(|why| bad(format!("its copy transform: {why}")))?;
        }
        let mut node_channels = vec![[None; 3]; n];
        for (k, ch) in channels.iter().enumerate() {
            let bad = |why: String| GraphError::BadChannel {
                channel: k as u32,
                why,
            };
            let Some(slots) = node_channels.get_mut(ch.node as usize) else {
                return Err(bad(format!("its node {} does not exist", ch.node)));
            };
            if let Some(node) = nodes.get(ch.node as usize) {
                if matches!(node.transform, NodeTransform::Matrix(_)) {
                    return Err(bad(format!(
                        "its node {} has a matrix, which cannot be animated",
                        ch.node
                    )));
                }
            }
            let slot = &mut slots[ch.path.slot()];
            if let Some(other) = *slot {
                return Err(bad(format!(
                    "channel {other} animates the {} of node {} too",
                    ch.path.name(),
                    ch.node
                )));
            }
            *slot = Some(k as u32);
            check_channel(ch).map_err(bad)?;
        }
        Ok(SceneGraph {
            nodes,
            instances,
            channels,
            node_channels,
            order,
        })
    }

    /// The nodes, by index.
    pub fn nodes(&self) -> &[SceneNode] {
        &self.nodes
    }

    /// The instances, by index.
    pub fn instances(&self) -> &[SceneInstance] {
        &self.instances
    }

    /// The animation channels.
    pub fn channels(&self) -> &[Channel] {
        &self.channels
    }

    /// The name of instance `instance`'s node (empty for an unnamed node or no such instance).
    pub fn node_name(&self, instance: u32) -> &str {
        self.instances
            .get(instance as usize)
            .and_then(|i| self.nodes.get(i.node as usize))
            .map_or("", |n| n.name.as_str())
    }

    /// The animation's length in seconds: the largest last key time (0 without animation).
    pub fn duration(&self) -> f64 {
        self.channels
            .iter()
            .filter_map(|c| c.times.last())
            .fold(0.0f64, |d, &t| d.max(t as f64))
    }

    /// The world pose of instance `instance` at time `t` (seconds; poses hold before the
    /// first key and after the last).
    pub fn pose_at(&self, instance: u32, t: f64) -> Result<Pose, PoseError> {
        check_time(t)?;
        self.pose_of(instance, Some(t))
    }

    /// The world poses of every instance at time `t`, by instance index.
    pub fn poses_at(&self, t: f64) -> Result<Vec<Pose>, PoseError> {
        check_time(t)?;
        self.all_poses(Some(t))
    }

    /// The world poses of every instance at the rest pose (no animation applied).
    pub fn rest_poses(&self) -> Result<Vec<Pose>, PoseError> {
        self.all_poses(None)
    }

    fn all_poses(&self, t: Option<f64>) -> Result<Vec<Pose>, PoseError> {
        let mut world = vec![DMat4::IDENTITY; self.nodes.len()];
        for &n in &self.order {
            let local = self.local_matrix(n, t)?;
            world[n as usize] = match self.nodes[n as usize].parent {
                Some(p) => world[p as usize] * local,
                None => local,
            };
        }
        (0..self.instances.len())
            .map(|k| {
                let inst = &self.instances[k];
                self.instance_pose(k as u32, world[inst.node as usize], t)
            })
            .collect()
    }

    fn pose_of(&self, instance: u32, t: Option<f64>) -> Result<Pose, PoseError> {
        let inst = self
            .instances
            .get(instance as usize)
            .ok_or(PoseError::NoSuchInstance {
                instance,
                count: self.instances.len(),
            })?;
        let world = self.node_world(inst.node, t)?;
        self.instance_pose(instance, world, t)
    }

    /// Node `node`'s world matrix at `t`, walking up its chain.
    fn node_world(&self, node: u32, t: Option<f64>) -> Result<DMat4, PoseError> {
        let mut m = self.local_matrix(node, t)?;
        let mut cur = node;
        // The graph is acyclic, so this walk ends within `nodes.len()` steps.
        while let Some(p) = self.nodes[cur as usize].parent {
            m = self.local_matrix(p, t)? * m;
            cur = p;
        }
        Ok(m)
    }

    fn instance_pose(
        &self,
        instance: u32,
        node_world: DMat4,
        t: Option<f64>,
    ) -> Result<Pose, PoseError> {
        let inst = &self.instances[instance as usize];
        let world = if inst.local == Trs::IDENTITY {
            node_world
        } else {
            node_world * trs_matrix(&inst.local)
        };
        let node_name = || self.nodes[inst.node as usize].name.clone();
        similarity_pose(&world).map_err(|why| match why {
            Decompose::NonRigid(why) => PoseError::NonRigid {
                instance,
                node: inst.node,
                node_name: node_name(),
                time: t,
                why,
            },
            Decompose::Overflow => PoseError::Overflow {
                instance,
                node: inst.node,
                node_name: node_name(),
                time: t,
            },
        })
    }

    /// Node `n`'s transform relative to its parent at `t` (`None`: at rest).
    fn local_matrix(&self, n: u32, t: Option<f64>) -> Result<DMat4, PoseError> {
        let node = &self.nodes[n as usize];
        let trs = match &node.transform {
            NodeTransform::Matrix(m) => return Ok(DMat4::from_cols_array(&m.map(|x| x as f64))),
            NodeTransform::Trs(trs) => trs,
        };
        let mut translation = dvec3(trs.translation);
        let mut rotation = DVec4::from_array(trs.rotation.map(|x| x as f64));
        let mut scale = dvec3(trs.scale);
        if let Some(t) = t {
            for (slot, ch) in self.node_channels[n as usize].iter().enumerate() {
                if let Some(c) = ch {
                    let v = sample(&self.channels[*c as usize], t);
                    match slot {
                        0 => translation = v.truncate(),
                        1 => rotation = v,
                        _ => scale = v.truncate(),
                    }
                }
            }
        }
        let len = rotation.length();
        if !(len > 1e-12) || !len.is_finite() {
            return Err(PoseError::ZeroRotation {
                node: n,
                node_name: node.name.clone(),
                time: t,
            });
        }
        let q = rotation / len;
        Ok(DMat4::from_scale_rotation_translation(
            scale,
            DQuat::from_xyzw(q.x, q.y, q.z, q.w),
            translation,
        ))
    }

    /// Checks that every instance's world transform is rigid (a uniform scale times a
    /// rotation, plus a translation) at the rest pose, at every key time of every channel on
    /// its node's chain, and halfway between consecutive keys of each.
    pub fn check_rigid(&self) -> Result<(), PoseError> {
        self.all_poses(None)?;
        // Instances grouped by node: each node's chain is sampled once per time.
        let mut by_node: Vec<Vec<u32>> = vec![Vec::new(); self.nodes.len()];
        for (k, inst) in self.instances.iter().enumerate() {
            by_node[inst.node as usize].push(k as u32);
        }
        let mut times: Vec<f64> = Vec::new();
        for (node, instances) in by_node.iter().enumerate() {
            if instances.is_empty() {
                continue;
            }
            self.chain_times(node as u32, &mut times);
            for &t in &times {
                let world = self.node_world(node as u32, Some(t))?;
                for &i in instances {
                    self.instance_pose(i, world, Some(t))?;
                }
            }
        }
        Ok(())
    }
}

impl SceneGraph {
    /// The times [`SceneGraph::check_rigid`] samples node `node` at: every key time of every
    /// channel on its chain and halfway between consecutive keys, sorted, each once.
    fn chain_times(&self, node: u32, times: &mut Vec<f64>) {
        times.clear();
        let mut cur = Some(node);
        while let Some(c) = cur {
            for ch in self.node_channels[c as usize].iter().flatten() {
                let keys = &self.channels[*ch as usize].times;
                times.extend(keys.iter().map(|&t| t as f64));
                times.extend(keys.windows(2).map(|w| 0.5 * (w[0] as f64 + w[1] as f64)));
            }
            cur = self.nodes[c as usize].parent;
        }
        times.sort_by(f64::total_cmp);
        times.dedup();
    }

    /// Instance `instance`'s world scale at time 0 with the smallest and largest it takes at
    /// the times [`SceneGraph::check_rigid`] samples (every key of its chain and halfway
    /// between keys): a scale that never changes gives three equal values, whatever its
    /// animation does otherwise.
    pub fn scale_range(&self, instance: u32) -> Result<ScaleRange, PoseError> {
        let at_zero = self.pose_at(instance, 0.0)?.scale;
        let node = self.instances[instance as usize].node;
        let mut times = Vec::new();
        self.chain_times(node, &mut times);
        let (mut min, mut max, mut min_at, mut max_at) = (at_zero, at_zero, 0.0, 0.0);
        for &t in &times {
            let s = self.pose_of(instance, Some(t))?.scale;
            if s < min {
                (min, min_at) = (s, t);
            }
            if s > max {
                (max, max_at) = (s, t);
            }
        }
        Ok(ScaleRange {
            at_zero,
            min,
            min_at,
            max,
            max_at,
        })
    }
}

/// An instance's world scale over its animation ([`SceneGraph::scale_range`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScaleRange {
    /// At time 0.
    pub at_zero: f32,
    /// The smallest sampled, and when.
    pub min: f32,
    /// When it is smallest (seconds).
    pub min_at: f64,
    /// The largest sampled.
    pub max: f32,
    /// When it is largest (seconds).
    pub max_at: f64,
}

impl ScaleRange {
    /// Whether the scale holds within `tolerance` of the largest (relative).
    pub fn is_fixed(&self, tolerance: f32) -> bool {
        self.max - self.min <= tolerance * self.max
    }
}

fn check_time(t: f64) -> Result<(), PoseError> {
    if t.is_finite() {
        Ok(())
    } else {
        Err(PoseError::BadTime { time: t })
    }
}

/// Nodes ordered so that every parent comes before its children; an error on a cycle.
fn topological_order(nodes: &[SceneNode]) -> Result<Vec<u32>, GraphError> {
    // 0: not placed, 1: being walked up, 2: placed.
    let mut state = vec![0u8; nodes.len()];
    let mut order = Vec::with_capacity(nodes.len());
    let mut chain = Vec::new();
    for start in 0..nodes.len() {
        if state[start] == 2 {
            continue;
        }
        chain.clear();
        let mut cur = Some(start as u32);
        while let Some(c) = cur {
            match state[c as usize] {
                2 => break,
                1 => return Err(GraphError::Cycle { node: c }),
                _ => {
                    state[c as usize] = 1;
                    chain.push(c);
                    cur = nodes[c as usize].parent;
                }
            }
        }
        for &c in chain.iter().rev() {
            state[c as usize] = 2;
            order.push(c);
        }
    }
    Ok(order)
}

fn dvec3(v: [f32; 3]) -> DVec3 {
    DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64)
}

/// A TRS as a matrix in `f64` (the rotation normalized; [`check_trs`] keeps it non-zero).
pub(crate) fn trs_matrix(t: &Trs) -> DMat4 {
    let q = DVec4::from_array(t.rotation.map(|x| x as f64));
    let q = q / q.length();
    DMat4::from_scale_rotation_translation(
        dvec3(t.scale),
        DQuat::from_xyzw(q.x, q.y, q.z, q.w),
        dvec3(t.translation),
    )
}

/// Channel `ch` at time `t`, as up to four values (a vector's `w` is 0).
fn sample(ch: &Channel, t: f64) -> DVec4 {
    let w = ch.path.width();
    let e = ch.interpolation.entries_per_key();
    // Entry `j` (0: in-tangent, 1: value, 2: out-tangent for a spline) of key `k`.
    let entry = |k: usize, j: usize| -> DVec4 {
        let start = (k * e + j) * w;
        let mut out = [0.0f64; 4];
        for (o, v) in out.iter_mut().zip(&ch.values[start..start + w]) {
            *o = *v as f64;
        }
        DVec4::from_array(out)
    };
    let value_slot = if e == 3 { 1 } else { 0 };
    let last = ch.times.len() - 1;
    // Keys are found at the keys' own precision: a time that rounds to a key's f32 is at that
    // key (a step at `13.0 / 24.0` seconds happens at the f32 key written for it), and so is
    // one within 4 f32 ulps of it: step times carry the rounding of an f32 `dt` (about 1e-7 of
    // the time), and a step meant to land on a key gets its value exactly (a scale keyed to
    // 0 hides its instance there, where 1e-6 of the next key's would be refused as too small
    // to resolve).
    let at_key = |key: f32| {
        (t - key as f64).abs()
            <= 4.0 * f32::EPSILON as f64 * key.abs().max(f32::MIN_POSITIVE) as f64
    };
    let t32 = t as f32;
    if t32 <= ch.times[0] || at_key(ch.times[0]) {
        return entry(0, value_slot);
    }
    if t32 >= ch.times[last] || at_key(ch.times[last]) {
        return entry(last, value_slot);
    }
    // times[k] <= t32 < times[k + 1], with k < last.
    let k = ch.times.partition_point(|&x| x <= t32).saturating_sub(1);
    if at_key(ch.times[k + 1]) {
        return entry(k + 1, value_slot);
    }
    let (t0, t1) = (ch.times[k] as f64, ch.times[k + 1] as f64);
    let td = t1 - t0;
    let u = if at_key(ch.times[k]) {
        0.0
    } else {
        ((t - t0) / td).clamp(0.0, 1.0)
    };
    let rotation = ch.path == ChannelPath::Rotation;
    match ch.interpolation {
        Interpolation::Step => entry(k, 0),
        Interpolation::Linear => {
            let (a, b) = (entry(k, 0), entry(k + 1, 0));
            if rotation {
                slerp(a, b, u)
            } else {
                a + (b - a) * u
            }
        }
        Interpolation::CubicSpline => {
            let (v0, b0) = (entry(k, 1), entry(k, 2));
            let (a1, v1) = (entry(k + 1, 0), entry(k + 1, 1));
            let u2 = u * u;
            let u3 = u2 * u;
            v0 * (2.0 * u3 - 3.0 * u2 + 1.0)
                + b0 * (td * (u3 - 2.0 * u2 + u))
                + v1 * (-2.0 * u3 + 3.0 * u2)
                + a1 * (td * (u3 - u2))
        }
    }
}

/// Spherical interpolation from `a` to `b` the shorter way (both normalized first); `u = 0`
/// gives `a` normalized.
fn slerp(a: DVec4, b: DVec4, u: f64) -> DVec4 {
    let a = a / a.length();
    let mut b = b / b.length();
    let mut d = a.dot(b);
    if d < 0.0 {
        b = -b;
        d = -d;
    }
    if d > 0.9995 {
        let q = a + (b - a) * u;
        return q / q.length();
    }
    let theta = d.min(1.0).acos();
    let s = theta.sin();
    a * (((1.0 - u) * theta).sin() / s) + b * ((u * theta).sin() / s)
}

enum Decompose {
    NonRigid(&'static str),
    Overflow,
}

/// A similarity transform as a pose: `world` must be a uniform scale times a rotation plus a
/// translation (within [`RIGID_TOLERANCE`]), or a zero scale (the identity rotation then).
fn similarity_pose(world: &DMat4) -> Result<Pose, Decompose> {
    let c = [
        world.x_axis.truncate(),
        world.y_axis.truncate(),
        world.z_axis.truncate(),
    ];
    let translation = world.w_axis.truncate();
    let l = [c[0].length(), c[1].length(), c[2].length()];
    let lmax = l[0].max(l[1]).max(l[2]);
    if !lmax.is_finite() || !translation.is_finite() {
        return Err(Decompose::Overflow);
    }
    let to_f32 = |v: DVec3| [v.x as f32, v.y as f32, v.z as f32];
    let t32 = to_f32(translation);
    if !finite(&t32) {
        return Err(Decompose::Overflow);
    }
    if lmax == 0.0 {
        return Ok(Pose {
            translation: t32,
            scale: 0.0,
            rotation: [0.0, 0.0, 0.0, 1.0],
        });
    }
    let tol2 = RIGID_TOLERANCE * lmax * lmax;
    if c[0].dot(c[1]).abs() > tol2 || c[1].dot(c[2]).abs() > tol2 || c[0].dot(c[2]).abs() > tol2 {
        return Err(Decompose::NonRigid("shears"));
    }
    let tol = RIGID_TOLERANCE * lmax;
    if (l[0] - l[1]).abs() > tol || (l[1] - l[2]).abs() > tol || (l[0] - l[2]).abs() > tol {
        return Err(Decompose::NonRigid("has a non-uniform scale"));
    }
    let r = DMat3::from_cols(c[0] / l[0], c[1] / l[1], c[2] / l[2]);
    if !(r.determinant() > 0.0) {
        return Err(Decompose::NonRigid(
            "mirrors (a negative scale or a reflection)",
        ));
    }
    let scale = (l[0] + l[1] + l[2]) / 3.0;
    let q = DQuat::from_mat3(&r);
    let q = [q.x as f32, q.y as f32, q.z as f32, q.w as f32];
    let rotation = normalize_rotation(q).ok_or(Decompose::Overflow)?;
    let scale = scale as f32;
    if !scale.is_finite() {
        return Err(Decompose::Overflow);
    }
    Ok(Pose {
        translation: t32,
        scale,
        rotation,
    })
}
