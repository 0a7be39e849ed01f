//! [`Scene`]: proxies baked once and instances that place them, moved between steps without
//! re-baking; it builds the broad phase and checks the scene whenever poses change.
//!
//! (The built-in test scenes, meshes made in code, are [`crate::scenes`].)
//!
//! **Poses and steps.** Each instance holds the pose it had at the start of the next step and
//! the pose it will have at its end. [`Scene::move_to`] sets the end and keeps the start
//! where the last step left the instance; [`Scene::set_motion`] sets both (a cut, a
//! teleport); after a step, [`Scene::hold`] makes every end the next start (what
//! [`Scene::step`] does itself). A multi-step run is one call per step, with
//! the poses for that step set before it: the caller samples its animation at step ends.
//!
//! **Indices** are stable: [`Scene::add_instance`] always appends, and a removed instance
//! keeps its index, inactive, so no index is reused.
//!
//! # Example
//!
//! A box baked once and placed twice: one still, one sweeping through particles at rest at
//! twice its size a step. No particle tunnels through it; those it meets are batted ahead, and
//! their hit records say where and how fast.
//!
//! ```
//! use octoproxy_core::{Backend, Particle, Pose, StepParams};
//! use octoproxy_cpu::{bake, scenes, BuildParams, CpuBackend, MeshRef, Scene};
//!
//! let cube = scenes::cube([-0.5; 3], [0.5; 3]);
//! let (words, _) = bake(&[MeshRef::from(&cube)], &BuildParams { dmax: 6, ..Default::default() }, &())?;
//! let mut scene = Scene::new();
//! let proxy = scene.add_proxy(words)?;
//! let at = |x: f32| Pose { translation: [x, 0.0, 0.0], ..Pose::IDENTITY };
//! scene.add_instance(proxy, at(-8.0))?; // still, out of the way
//! let paddle = scene.add_instance(proxy, at(-2.0))?;
//!
//! // A row of particles at rest along the box's path.
//! let particles: Vec<Particle> = (0..40).map(|i| Particle::new([i as f32 * 0.25, 0.0, 0.0], [0.0; 3])).collect();
//! let mut cpu = CpuBackend::new();
//! cpu.upload_particles(&particles)?;
//! let params = StepParams { gravity: [0.0; 3], dt: 0.05, restitution: 1.0, friction: 0.0, ..Default::default() };
//! let mut hits = 0;
//! for step in 1..=6 {
//!     // Two units a step: the box's end pose for this step; its start is where it was.
//!     scene.move_to(paddle, at(-2.0 + 2.0 * step as f32))?;
//!     scene.step(&mut cpu, &params, true)?;
//!     hits += cpu.hits().iter().filter(|h| h.instance == paddle as i32).count();
//! }
//! // Every particle ahead of the box's face: none passed through it.
//! let face = -2.0 + 2.0 * 6.0 + 0.5;
//! assert!(cpu.particles().iter().all(|p| p.position[0] >= face - 0.05));
//! assert!(hits >= 40, "{hits} hits");
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use glam::Vec3;
use octoproxy_core::scene::{
    BroadNode, Instance, Pose, SceneError, SceneView, BROAD_INTERNAL, BROAD_LEAF, INSTANCE_LIVE,
    INSTANCE_SHOWN, MAX_INSTANCES, SIDE_SLOTS,
};
use octoproxy_core::{
    Aabb, Backend, FormatError, OwnedProxy, PairParams, ProxyView, SceneSubstep, StepParams,
};

use crate::bake::offset::{OffsetSurface, PlaceCounts};

/// What can go wrong with a scene.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SceneBuildError {
    /// A proxy did not validate.
    #[error("proxy {index}: {source}")]
    Proxy {
        /// Its index in the scene.
        index: u32,
        /// Why.
        source: FormatError,
    },
    /// The scene did not validate.
    #[error("{0}")]
    Scene(#[from] SceneError),
    /// An instance index that the scene never had.
    #[error("instance {0} does not exist")]
    NoSuchInstance(u32),
    /// An instance that was removed.
    #[error("instance {0} was removed")]
    Removed(u32),
    /// A proxy index the scene does not have.
    #[error("proxy {0} does not exist")]
    NoSuchProxy(u32),
    /// More instances than a scene holds.
    #[error("a scene holds at most {MAX_INSTANCES} instances")]
    TooManyInstances,
    /// A pose that is not finite, has a negative scale or a rotation that is not a unit
    /// quaternion.
    #[error("instance {instance}: {why}")]
    BadPose {
        /// The instance.
        instance: u32,
        /// What is wrong.
        why: &'static str,
    },
    /// More shells overlap at one point than a particle can keep sides for.
    #[error(
        "instances {instances:?} overlap at one point within a leaf of their surfaces; a particle keeps its side for at most {SIDE_SLOTS} instances at once: move them apart"
    )]
    TooManyOverlapping {
        /// The instances whose shells share a point.
        instances: Vec<u32>,
    },
}

impl SceneBuildError {
    /// The instances the error is about (none where it names no instance), for a caller to
    /// say which nodes or objects they are.
    pub fn instances(&self) -> Vec<u32> {
        match self {
            SceneBuildError::Scene(e) => e.instance().into_iter().collect(),
            SceneBuildError::NoSuchInstance(k) | SceneBuildError::Removed(k) => vec![*k],
            SceneBuildError::BadPose { instance, .. } => vec![*instance],
            SceneBuildError::TooManyOverlapping { instances } => instances.clone(),
            SceneBuildError::Proxy { .. }
            | SceneBuildError::NoSuchProxy(_)
            | SceneBuildError::TooManyInstances => Vec::new(),
        }
    }
}

/// What [`Scene::step`] can report: the scene's own errors, or the backend's.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SceneStepError<E: std::error::Error + 'static> {
    /// The scene did not prepare (see [`Scene::prepare`]).
    #[error(transparent)]
    Scene(#[from] SceneBuildError),
    /// The backend failed.
    #[error(transparent)]
    Backend(E),
    /// The step or pass parameters are invalid ([`Scene::step_pairs`]).
    #[error("{0}")]
    Params(String),
}

/// A number no other scene of this process has, for [`Scene::proxies_key`].
fn next_scene_id() -> u64 {
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);
    NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
}

/// Proxies and the instances that place them, with the broad phase over them.
#[derive(Debug)]
pub struct Scene {
    /// This scene's number in the process (a clone gets its own).
    id: u64,
    proxies: Vec<OwnedProxy>,
    /// Per proxy: the box of its surface leaves grown by one finest leaf (its shell), in the
    /// proxy's frame.
    shells: Vec<Option<Aabb>>,
    instances: Vec<Instance>,
    nodes: Vec<BroadNode>,
    /// Whether poses changed since the broad phase was built and the scene checked.
    dirty: bool,
}

fn check_pose(instance: u32, pose: &Pose) -> Result<(), SceneBuildError> {
    let bad = |why| Err(SceneBuildError::BadPose { instance, why });
    if !Vec3::from_array(pose.translation).is_finite() {
        return bad("its translation is not finite");
    }
    if !pose.scale.is_finite() || pose.scale < 0.0 {
        return bad("its scale must be a finite number >= 0");
    }
    let q = pose.rotation;
    let len2: f32 = q.iter().map(|c| c * c).sum();
    if !len2.is_finite() || (len2 - 1.0).abs() > 1e-6 {
        return bad("its rotation must be a unit quaternion [x, y, z, w]");
    }
    Ok(())
}

/// `q` scaled to unit length (a rotation read from a file is rarely unit to the last bit).
pub fn normalize_rotation(q: [f32; 4]) -> Option<[f32; 4]> {
    let len = q
        .iter()
        .map(|c| (*c as f64) * (*c as f64))
        .sum::<f64>()
        .sqrt();
    if !len.is_finite() || len < 1e-6 {
        return None;
    }
    Some(q.map(|c| (c as f64 / len) as f32))
}

impl Default for Scene {
    fn default() -> Self {
        Self {
            id: next_scene_id(),
            proxies: Vec::new(),
            shells: Vec::new(),
            instances: Vec::new(),
            nodes: Vec::new(),
            dirty: false,
        }
    }
}

impl Clone for Scene {
    fn clone(&self) -> Self {
        Self {
            id: next_scene_id(),
            proxies: self.proxies.clone(),
            shells: self.shells.clone(),
            instances: self.instances.clone(),
            nodes: self.nodes.clone(),
            dirty: self.dirty,
        }
    }
}

impl Scene {
    /// An empty scene.
    pub fn new() -> Self {
        Self::default()
    }

    /// A key no other set of proxies in this process has: this scene's number and how many
    /// proxies it holds (proxies are only ever added). A backend holding proxies under this
    /// key holds these ([`Backend::upload_scene_proxies`]).
    pub fn proxies_key(&self) -> u64 {
        self.id << 32 | self.proxies.len() as u64
    }

    /// Gives `backend` this scene's proxies, unless it holds them already.
    pub fn upload_proxies<B: Backend>(&self, backend: &mut B) -> Result<(), B::Error> {
        let key = self.proxies_key();
        if backend.scene_proxies_key() == Some(key) {
            return Ok(());
        }
        let words: Vec<&[u32]> = self.proxies.iter().map(|p| p.words()).collect();
        backend.upload_scene_proxies(key, &words)
    }

    /// One step of `backend`'s particles through the scene: it prepares the scene (the
    /// broad phase, the checks), gives the backend the proxies if it does not hold them,
    /// steps (each instance from its start pose to its end pose; with `hits`, each
    /// particle's last collision is kept), and then holds every instance at its end pose
    /// ([`Scene::hold`]), ready for the next [`Scene::move_to`].
    pub fn step<B: Backend>(
        &mut self,
        backend: &mut B,
        params: &StepParams,
        hits: bool,
    ) -> Result<(), SceneStepError<B::Error>> {
        self.prepare()?;
        self.upload_proxies(backend)
            .map_err(SceneStepError::Backend)?;
        backend
            .step_scene(&self.instances, &self.nodes, params, hits)
            .map_err(SceneStepError::Backend)?;
        self.hold();
        Ok(())
    }

    /// One step of `backend`'s particles through the scene with the particle–particle pass
    /// ([`Backend::step_scene_pairs`]): the step's motion of every moving instance cut into
    /// the pass's substeps (`S` from [`Backend::pair_substeps_now`], which follows the
    /// fastest particle; each instance posed at `k / S` and `(k + 1) / S` of the step,
    /// `Instance::pose_at`), each substep's broad phase built and checked (a scene where
    /// nothing moves is the same in every substep, built once), then the step, then every
    /// instance held at its end pose, as [`Scene::step`] does.
    pub fn step_pairs<B: Backend>(
        &mut self,
        backend: &mut B,
        params: &StepParams,
        pairs: &PairParams,
        hits: bool,
    ) -> Result<(), SceneStepError<B::Error>> {
        params
            .validate()
            .map_err(|e| SceneStepError::Params(e.to_string()))?;
        pairs
            .validate(params)
            .map_err(|e| SceneStepError::Params(e.to_string()))?;
        self.prepare()?;
        self.upload_proxies(backend)
            .map_err(SceneStepError::Backend)?;
        let count = backend
            .pair_substeps_now(params, pairs)
            .map_err(SceneStepError::Backend)?;
        let moving = self.instances.iter().any(|i| !i.is_static());
        // A scene where nothing moves is the same scene in every substep.
        let cut = if moving { count } else { 0 };
        let whole = self.instances.clone();
        let whole_nodes = if moving {
            self.nodes.clone()
        } else {
            Vec::new()
        };
        let mut substeps: Vec<(Vec<Instance>, Vec<BroadNode>)> = Vec::with_capacity(cut as usize);
        let mut result = Ok(());
        for k in 0..cut {
            let (u0, u1) = (k as f32 / count as f32, (k + 1) as f32 / count as f32);
            for (i, w) in self.instances.iter_mut().zip(&whole) {
                if !w.is_static() {
                    *i = Instance {
                        flags: w.flags,
                        ..Instance::new(w.proxy, w.pose_at(u0), w.pose_at(u1))
                    };
                }
            }
            self.dirty = true;
            if let Err(e) = self.prepare() {
                result = Err(e);
                break;
            }
            substeps.push((self.instances.clone(), self.nodes.clone()));
        }
        // The whole step again, whatever happened: as it was built before the cuts.
        if moving {
            (self.instances, self.nodes) = (whole, whole_nodes);
            self.dirty = false;
        }
        result?;
        let views: Vec<SceneSubstep<'_>> = if moving {
            substeps
                .iter()
                .map(|(instances, broad)| SceneSubstep { instances, broad })
                .collect()
        } else {
            let still = SceneSubstep {
                instances: &self.instances,
                broad: &self.nodes,
            };
            vec![still; count as usize]
        };
        backend
            .step_scene_pairs(&views, params, pairs, hits)
            .map_err(SceneStepError::Backend)?;
        self.hold();
        Ok(())
    }

    /// Adds a proxy (validated here) and returns its index.
    pub fn add_proxy(&mut self, words: Vec<u32>) -> Result<u32, SceneBuildError> {
        let index = self.proxies.len() as u32;
        let proxy =
            OwnedProxy::new(words).map_err(|source| SceneBuildError::Proxy { index, source })?;
        let view = proxy.view();
        let leaf = Vec3::splat(view.finest_leaf_size());
        self.shells.push(view.surface_box().map(|b| Aabb {
            min: b.min - leaf,
            max: b.max + leaf,
        }));
        self.proxies.push(proxy);
        Ok(index)
    }

    /// Places proxy `proxy` at `pose`, not moving; returns the new instance's index (never
    /// one used before).
    pub fn add_instance(&mut self, proxy: u32, pose: Pose) -> Result<u32, SceneBuildError> {
        if proxy as usize >= self.proxies.len() {
            return Err(SceneBuildError::NoSuchProxy(proxy));
        }
        let index = self.instances.len() as u32;
        if index >= MAX_INSTANCES {
            return Err(SceneBuildError::TooManyInstances);
        }
        check_pose(index, &pose)?;
        self.instances.push(Instance::new(proxy, pose, pose));
        self.dirty = true;
        Ok(index)
    }

    fn live(&mut self, instance: u32) -> Result<&mut Instance, SceneBuildError> {
        match self.instances.get_mut(instance as usize) {
            None => Err(SceneBuildError::NoSuchInstance(instance)),
            Some(i) if i.flags & INSTANCE_LIVE == 0 => Err(SceneBuildError::Removed(instance)),
            Some(i) => Ok(i),
        }
    }

    /// The next step moves `instance` from where it is to `pose`.
    pub fn move_to(&mut self, instance: u32, pose: Pose) -> Result<(), SceneBuildError> {
        check_pose(instance, &pose)?;
        let i = self.live(instance)?;
        // The flags carry whether the last step had it hidden (`INSTANCE_SHOWN`, set by
        // `hold`).
        *i = Instance {
            flags: i.flags,
            ..Instance::new(i.proxy, i.end, pose)
        };
        self.dirty = true;
        Ok(())
    }

    /// The next step moves `instance` from `start` to `end` (a cut: the start need not be
    /// where the last step left it).
    pub fn set_motion(
        &mut self,
        instance: u32,
        start: Pose,
        end: Pose,
    ) -> Result<(), SceneBuildError> {
        check_pose(instance, &start)?;
        check_pose(instance, &end)?;
        let i = self.live(instance)?;
        *i = Instance {
            flags: i.flags,
            ..Instance::new(i.proxy, start, end)
        };
        self.dirty = true;
        Ok(())
    }

    /// Every instance holds still where the last step left it: each end pose becomes the
    /// start and the end of the next step. Call it after each step (`Scene::step` does):
    /// an instance the step had hidden (scale 0) is marked [`INSTANCE_SHOWN`] for the next
    /// steps until one has it shown, in which the particles' sides kept for it are taken anew
    /// (they may have moved anywhere meanwhile); that step's `hold` clears the mark.
    pub fn hold(&mut self) {
        for i in &mut self.instances {
            let hidden = i.flags & INSTANCE_LIVE != 0 && !i.is_active();
            let flags = i.flags & INSTANCE_LIVE | if hidden { INSTANCE_SHOWN } else { 0 };
            if !i.is_static() {
                *i = Instance {
                    flags,
                    ..Instance::new(i.proxy, i.end, i.end)
                };
                self.dirty = true;
            } else if i.flags != flags {
                i.flags = flags;
                self.dirty = true;
            }
        }
    }

    /// Removes `instance`; its index stays taken.
    pub fn remove(&mut self, instance: u32) -> Result<(), SceneBuildError> {
        let i = self.live(instance)?;
        i.flags &= !INSTANCE_LIVE;
        self.dirty = true;
        Ok(())
    }

    /// The instances, removed ones included (inactive), by index.
    pub fn instances(&self) -> &[Instance] {
        &self.instances
    }

    /// The proxies, by index.
    pub fn proxies(&self) -> &[OwnedProxy] {
        &self.proxies
    }

    /// The broad phase as it was last built.
    pub fn broad_phase(&self) -> &[BroadNode] {
        &self.nodes
    }

    /// Builds the broad phase if poses changed, and checks the scene: the core validation
    /// ([`SceneView::new`]) and that no point lies within the shells of more instances than a
    /// particle keeps sides for ([`SIDE_SLOTS`]).
    pub fn prepare(&mut self) -> Result<(), SceneBuildError> {
        if !self.dirty {
            return Ok(());
        }
        self.build_broad_phase();
        let views: Vec<ProxyView<'_>> = self.proxies.iter().map(|p| p.view()).collect();
        let view = SceneView::new(&views, &self.instances, &self.nodes)?;
        self.check_overlap(&view)?;
        self.dirty = false;
        Ok(())
    }

    /// Calls `f` with the validated scene (after [`Scene::prepare`]).
    pub fn with_view<R>(
        &mut self,
        f: impl FnOnce(&SceneView<'_>) -> R,
    ) -> Result<R, SceneBuildError> {
        self.prepare()?;
        let views: Vec<ProxyView<'_>> = self.proxies.iter().map(|p| p.view()).collect();
        let view = SceneView::new(&views, &self.instances, &self.nodes)?;
        Ok(f(&view))
    }

    /// A bounding-volume hierarchy over the active instances' swept boxes, split at the
    /// median of the boxes' centres along the widest axis, in depth-first order.
    fn build_broad_phase(&mut self) {
        let mut items: Vec<(u32, Aabb)> = Vec::new();
        for (k, inst) in self.instances.iter_mut().enumerate() {
            inst.leaf = u32::MAX;
            if inst.is_active() {
                let view = self.proxies[inst.proxy as usize].view();
                items.push((k as u32, inst.swept_box(&view)));
            }
        }
        self.nodes.clear();
        if items.is_empty() {
            return;
        }
        build_node(&mut items, &mut self.nodes);
        for (k, node) in self.nodes.iter().enumerate() {
            if node.kind == BROAD_LEAF {
                self.instances[node.index as usize].leaf = k as u32;
            }
        }
    }

    /// The shells' overlap: the largest set of instances whose shell boxes (swept over the
    /// step) share a point must fit the side slots.
    fn check_overlap(&self, view: &SceneView<'_>) -> Result<(), SceneBuildError> {
        let boxes: Vec<Option<Aabb>> = self
            .instances
            .iter()
            .map(|inst| {
                if !inst.is_active() {
                    return None;
                }
                self.shells[inst.proxy as usize].map(|s| inst.swept_box_of(&s))
            })
            .collect();
        for (b, own) in boxes.iter().enumerate() {
            let Some(own) = own else { continue };
            // The instances whose shells meet this one's (the broad phase's boxes hold them).
            let mut near = vec![b as u32];
            view.for_each_candidate(own, |c| {
                if c as usize != b && boxes[c as usize].is_some_and(|o| overlaps(&o, own)) {
                    near.push(c);
                }
            });
            if near.len() <= SIDE_SLOTS {
                continue;
            }
            if let Some(clique) = deepest_point(&near, &boxes, SIDE_SLOTS + 1) {
                return Err(SceneBuildError::TooManyOverlapping { instances: clique });
            }
        }
        Ok(())
    }
}

fn overlaps(a: &Aabb, b: &Aabb) -> bool {
    a.min.cmple(b.max).all() && b.min.cmple(a.max).all()
}

/// Among the boxes of `set` (whose first is the one they all meet), `want` that share a
/// point, if any. Boxes share a point when they overlap pairwise (boxes have Helly's
/// property), and the deepest point's coordinates are some boxes' minima: for each candidate
/// `x` and `y` among the minima, the boxes holding that `(x, y)` line are counted along `z`.
fn deepest_point(set: &[u32], boxes: &[Option<Aabb>], want: usize) -> Option<Vec<u32>> {
    let own = boxes[set[0] as usize]?;
    let get = |i: u32| boxes[i as usize].expect("only active instances are in the set");
    let xs: Vec<f32> = set.iter().map(|&i| get(i).min.x.max(own.min.x)).collect();
    let ys: Vec<f32> = set.iter().map(|&i| get(i).min.y.max(own.min.y)).collect();
    for &x in &xs {
        let at_x: Vec<u32> = set
            .iter()
            .copied()
            .filter(|&i| get(i).min.x <= x && x <= get(i).max.x)
            .collect();
        if at_x.len() < want {
            continue;
        }
        for &y in &ys {
            let at_xy: Vec<u32> = at_x
                .iter()
                .copied()
                .filter(|&i| get(i).min.y <= y && y <= get(i).max.y)
                .collect();
            if at_xy.len() < want {
                continue;
            }
            // Along z: open at each minimum, closed after each maximum.
            let mut events: Vec<(f32, bool, u32)> = at_xy
                .iter()
                .flat_map(|&i| [(get(i).min.z, false, i), (get(i).max.z, true, i)])
                .collect();
            events.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let mut open: Vec<u32> = Vec::new();
            for (_, closes, i) in events {
                if closes {
                    open.retain(|&o| o != i);
                } else {
                    open.push(i);
                    if open.len() >= want && open.contains(&set[0]) {
                        let mut clique = open.clone();
                        clique.sort_unstable();
                        return Some(clique);
                    }
                }
            }
        }
    }
    None
}

/// Appends the subtree over `items` to `nodes` in depth-first order; returns its box.
fn build_node(items: &mut [(u32, Aabb)], nodes: &mut Vec<BroadNode>) -> Aabb {
    let at = nodes.len();
    if let [(instance, b)] = items {
        nodes.push(BroadNode {
            min: b.min.to_array(),
            index: *instance,
            max: b.max.to_array(),
            kind: BROAD_LEAF,
        });
        return *b;
    }
    nodes.push(BroadNode {
        min: [0.0; 3],
        index: 0,
        max: [0.0; 3],
        kind: BROAD_INTERNAL,
    });
    let centre = |b: &Aabb| (b.min + b.max) * 0.5;
    let (lo, hi) = items.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), (_, b)| (lo.min(centre(b)), hi.max(centre(b))),
    );
    let extent = hi - lo;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    let mid = items.len() / 2;
    items.select_nth_unstable_by(mid, |a, b| {
        centre(&a.1)[axis]
            .total_cmp(&centre(&b.1)[axis])
            .then(a.0.cmp(&b.0))
    });
    let (left, right) = items.split_at_mut(mid);
    let a = build_node(left, nodes);
    let second = nodes.len() as u32;
    let b = build_node(right, nodes);
    let (min, max) = (a.min.min(b.min), a.max.max(b.max));
    nodes[at] = BroadNode {
        min: min.to_array(),
        index: second,
        max: max.to_array(),
        kind: BROAD_INTERNAL,
    };
    Aabb { min, max }
}

/// Starting sides for particles in a scene, from each instance's own mesh: for every active
/// instance whose surface leaf a particle starts in (in the instance's frame at its start
/// pose), the side of the mesh there by [the rule of starting sides](crate::sides), and its
/// cage when it starts strictly inside a solid leaf. Elsewhere the empty leaf's label is the
/// side, and the step takes it from there. `sides[proxy]` prepares proxy `proxy`'s meshes
/// ([`crate::Sides::new`] on what was baked into it; for proxies baked for a radius, their
/// [`crate::bake::offset::OffsetSurface`]s, which answer from the band). Returns each particle's
/// [`octoproxy_core::SceneSides`] and how many sides came from a mesh.
pub fn starting_scene_sides<S: crate::sides::StartSides>(
    scene: &Scene,
    sides: &[S],
    particles: &[octoproxy_core::Particle],
) -> (Vec<octoproxy_core::SceneSides>, usize) {
    use octoproxy_core::{LeafKind, SceneSides};
    use rayon::prelude::*;
    let views: Vec<ProxyView<'_>> = scene.proxies.iter().map(|p| p.view()).collect();
    let out: Vec<(SceneSides, usize)> = particles
        .par_iter()
        .map(|p| {
            let mut s = SceneSides::EMPTY;
            let mut from_mesh = 0;
            let x = Vec3::from_array(p.position);
            if !x.is_finite() {
                return (s, 0);
            }
            for (k, inst) in scene.instances.iter().enumerate() {
                let (Some(view), Some(mesh)) = (
                    views.get(inst.proxy as usize),
                    sides.get(inst.proxy as usize),
                ) else {
                    continue;
                };
                if !inst.is_active() {
                    continue;
                }
                let l = inst.start.to_local(x);
                let in_surface = view
                    .locate_leaf(l)
                    .is_some_and(|leaf| leaf.kind == LeafKind::Surface);
                if in_surface {
                    let side = mesh.side(l.to_array());
                    let side = side | mesh.cage(view, l.to_array(), side);
                    if s.set_side(k as u32, side) {
                        from_mesh += 1;
                    }
                }
            }
            (s, from_mesh)
        })
        .collect();
    let count = out.iter().map(|(_, n)| n).sum();
    (out.into_iter().map(|(s, _)| s).collect(), count)
}

/// Moves every particle that starts inside an instance's band (nearer its mesh than its
/// offset surface, at the instance's start pose) out of it: instance by instance, in the
/// instance's frame, by [`OffsetSurface::place`] (away from the nearest surface point, not
/// into one of its solid leaves). `offsets[proxy]` is the offset surface proxy `proxy` was
/// baked from (`crate::gltf::bake_scene_for_radius` returns them). Velocities are kept.
/// Returns how many particles were moved, and how many are still inside some instance's band
/// afterwards (wedged where bands of several instances meet, or moved into another's): those
/// start behind that offset surface, where the radius is not kept.
pub fn place_in_bands(
    scene: &Scene,
    offsets: &[OffsetSurface],
    particles: &mut [octoproxy_core::Particle],
) -> PlaceCounts {
    use rayon::prelude::*;
    let inside = |inst: &Instance, x: Vec3| {
        let (Some(offset), Some(proxy)) = (
            offsets.get(inst.proxy as usize),
            scene.proxies.get(inst.proxy as usize),
        ) else {
            return false;
        };
        let root = proxy.view().root_aabb();
        let l = inst.start.to_local(x);
        l.is_finite()
            && l.cmpge(root.min).all()
            && l.cmple(root.max).all()
            && !offset.outside(l.to_array())
    };
    let mut moved = vec![false; particles.len()];
    for inst in scene.instances.iter().filter(|i| i.is_active()) {
        let (Some(offset), Some(proxy)) = (
            offsets.get(inst.proxy as usize),
            scene.proxies.get(inst.proxy as usize),
        ) else {
            continue;
        };
        let view = proxy.view();
        let which: Vec<usize> = particles
            .par_iter()
            .enumerate()
            .filter(|(_, p)| inside(inst, Vec3::from_array(p.position)))
            .map(|(k, _)| k)
            .collect();
        let mut local: Vec<octoproxy_core::Particle> = which
            .iter()
            .map(|&k| {
                let mut q = particles[k];
                q.position = inst.start.to_local(Vec3::from_array(q.position)).to_array();
                q
            })
            .collect();
        offset.place(&mut local, Some(&view));
        for (&k, q) in which.iter().zip(&local) {
            let x = inst.start.to_world(Vec3::from_array(q.position)).to_array();
            if x != particles[k].position {
                particles[k].position = x;
                moved[k] = true;
            }
        }
    }
    let stuck = particles
        .par_iter()
        .filter(|p| {
            let x = Vec3::from_array(p.position);
            scene
                .instances
                .iter()
                .any(|inst| inst.is_active() && inside(inst, x))
        })
        .count();
    PlaceCounts {
        moved: moved.iter().filter(|&&m| m).count(),
        stuck,
    }
}
