//! Scenes of moving and instanced colliders: proxies placed by rigid poses, a broad phase over
//! their boxes, each particle's side for every instance it is near, and the step against them.
//!
//! A scene is three flat arrays that both backends read as bytes (`FORMAT.md`, "Scenes"):
//! the proxies (each validated as a [`ProxyView`]), the instance table ([`Instance`]: a
//! proxy, the pose it had at the start of the step and the pose it has at the end) and the
//! broad phase ([`BroadNode`]: a bounding-volume hierarchy over the instances' swept boxes).
//! [`SceneView::new`] validates them together, once per change of poses; every step after
//! takes `&SceneView`.
//!
//! **The step** ([`step_particle_scene`]) marches a particle in each instance's own frame,
//! from its start in the start pose to its end in the end pose: the relative motion.
//! - A particle near one static instance only (the common case, and every particle of a
//!   one-proxy static scene) takes the whole step in that frame, as [`crate::step_particle_hinted`]
//!   does, with every rule of the march (pinch, shell, cages, slabs) and the leaf hint.
//! - Otherwise the step goes in **rounds**. Each round probes every instance the rest of the
//!   straight path can meet up to its first collision, takes the earliest (lowest instance
//!   order on a tie), brings every other instance's side up to that moment, responds there
//!   with the velocity relative to the collider's surface at the contact point, and starts
//!   the next round from the contact with the time left. A particle still colliding after
//!   [`MAX_ROUNDS`] rounds is pressed between colliders: it stays at its last contact, riding
//!   with the instance it touched, and is flagged [`FLAG_CRUSHED`]; it is never pushed through.
//! - A moving instance's frame turns and scales along the step (the slerp and lerp between
//!   its poses), so a straight world path is a curve in it. The march follows chords of that
//!   curve, [`substeps`] of them, chosen per particle so that the curve stays within a
//!   quarter of the proxy's finest leaf of its chords ([`SUBSTEP_MARGIN`]). Translation alone
//!   needs none: the chord is the curve.
//!
//! **Sides per instance** ([`SceneSides`]): a particle's side is relative to each instance it
//! is near. Outside an instance's shell it is the label of the empty leaf the particle is in
//! (a particle reaching the surface always crosses a labelled leaf first), so only the sides of
//! particles that end a step in a surface leaf, or caged in a solid one, must be kept: those
//! slots are *required*; the others are kept while there is room and save a descent. A
//! particle keeps [`SIDE_SLOTS`] slots; the host checks, whenever poses change, that no point
//! lies in more shells than that (`octoproxy_cpu::Scene`), and a particle that would need more
//! is flagged [`FLAG_SIDES_LOST`].

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use crate::math;
use crate::particle::*;
use crate::query::{Aabb, NO_LEAF};
use crate::step::{
    initial_side, march_after, pinch, step_hinted_observed, step_particle_hinted, LeafHint,
    MarchObserver, StepOutcome, StepParams,
};
use crate::view::{ulp, wide_length, ProxyView};

/// Flag: the last step's collisions with several instances did not resolve within
/// [`MAX_ROUNDS`] rounds (a particle pressed between converging colliders); it was left at its
/// last contact, moving with the instance it touched last.
pub const FLAG_CRUSHED: u32 = 1 << 3;
/// Flag: the last step ended with the particle in the shells of more instances than
/// [`SIDE_SLOTS`]; the sides beyond the slots were dropped (the scene check prevents it).
pub const FLAG_SIDES_LOST: u32 = 1 << 4;
/// The status flags a scene step recomputes, the static step's included.
pub const FLAG_SCENE_STATUS: u32 = FLAG_STEP_STATUS | FLAG_CRUSHED | FLAG_SIDES_LOST;

/// Rounds of collisions with several instances in reach one step may take before the
/// particle is taken as crushed ([`FLAG_CRUSHED`]).
pub const MAX_ROUNDS: u32 = 16;
/// Collisions one step may take in all (a particle carried by a turning instance collides
/// once a chord); past them the particle stays at its last contact, moving with the instance,
/// flagged [`FLAG_BOUND_HIT`].
pub const MAX_CONTACTS: u32 = 4 * MAX_ROUNDS;
/// Rounds in a row that one step may take with no time passing (each collides where the last
/// did, at the same moment: a particle pressed on by a turning instance); past them the
/// particle rides with the instance for the rest of the step, as past [`MAX_CONTACTS`], when
/// no other instance is on the way (else the rounds go on).
pub const MAX_STALLS: u32 = 32;
/// Chords a particle's path may be cut into against one turning or scaling instance in one
/// step ([`substeps`]).
pub const MAX_SUBSTEPS: u32 = 1024;
/// How far the curve of a path in a turning instance's frame may stray from its chords, in
/// the proxy's finest leaves (local units): a quarter of a leaf, within the guarantee's one
/// leaf diagonal.
pub const SUBSTEP_MARGIN: f32 = 0.25;
/// Depth bound of the broad phase's tree, which the step walks with a stack of this size.
pub const MAX_BROAD_DEPTH: u32 = 32;
/// Instances a scene may hold: indices below this fit a side slot.
pub const MAX_INSTANCES: u32 = (1 << 22) - 1;
/// Side slots per particle in [`SceneSides`].
pub const SIDE_SLOTS: usize = 8;

/// A rigid pose with uniform scale: a local point `l` is at `translation + R(rotation) *
/// (scale * l)` in the world. 32 bytes, a GPU struct as it is.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Pose {
    /// Where the local origin is.
    pub translation: [f32; 3],
    /// Uniform scale, `>= 0`; 0 hides the instance.
    pub scale: f32,
    /// Unit quaternion `[x, y, z, w]`.
    pub rotation: [f32; 4],
}

const _: () = assert!(core::mem::size_of::<Pose>() == 32);

impl Default for Pose {
    fn default() -> Self {
        Self::IDENTITY
    }
}

/// `v` rotated by the unit quaternion `q`: the rotation matrix, each entry a sum or difference
/// of two products, applied as three dot products. These shapes are what every backend
/// computes alike: a GPU compiler may reassociate a longer sum (Mesa's NIR turned
/// `v + w t + u × t`, the usual form, into other roundings on lavapipe), never these. A
/// quaternion with no vector part leaves `v` exactly as it is (an identity pose changes no
/// bit).
#[inline(always)]
fn rotate(q: [f32; 4], v: Vec3) -> Vec3 {
    let [x, y, z, w] = q;
    if x == 0.0 && y == 0.0 && z == 0.0 {
        return v;
    }
    let r0 = Vec3::new(
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - z * w),
        2.0 * (x * z + y * w),
    );
    let r1 = Vec3::new(
        2.0 * (x * y + z * w),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - x * w),
    );
    let r2 = Vec3::new(
        2.0 * (x * z - y * w),
        2.0 * (y * z + x * w),
        1.0 - 2.0 * (x * x + y * y),
    );
    Vec3::new(r0.dot(v), r1.dot(v), r2.dot(v))
}

/// The conjugate of a unit quaternion: the inverse rotation.
#[inline(always)]
fn conjugate(q: [f32; 4]) -> [f32; 4] {
    [-q[0], -q[1], -q[2], q[3]]
}

/// The coefficients of [`sin_poly`]: `1/11!`, `1/9!`, `1/7!`, `1/5!`, `1/3!` (WGSL's are
/// generated from these, bit for bit).
pub const SIN_POLY: [f32; 5] = [
    1.0 / 39_916_800.0,
    1.0 / 362_880.0,
    1.0 / 5_040.0,
    1.0 / 120.0,
    1.0 / 6.0,
];

/// Below this half turn (radians) the slerp weights are the lerp's: `sin` is its argument
/// to within rounding there.
pub const SLERP_LINEAR_BELOW: f32 = 1e-3;

/// The least pad of a box around a particle's path: a box of a particle at the origin still
/// has width.
pub const PATH_PAD: f32 = 1e-30;

/// `v` with every zero `+0.0`. A march in an instance's frame integrates a gravity of zero,
/// `v + 0 dt`, which makes a `-0.0` component `+0.0`; a GPU compiler that sees the constant
/// zero folds the sum away and keeps the `-0.0` (a face crossed on one side of it, or the
/// other). Velocities go into those marches with no `-0.0`, so both agree.
#[inline(always)]
fn plus_zero(v: Vec3) -> Vec3 {
    Vec3::new(
        if v.x == 0.0 { 0.0 } else { v.x },
        if v.y == 0.0 { 0.0 } else { v.y },
        if v.z == 0.0 { 0.0 } else { v.z },
    )
}

/// `a` if it is greater than `b`, else `b`: glam's `max` for one scalar, and WGSL's
/// `select(b, a, a > b)` (`f32::max` may give either zero for `-0.0` and `0.0`).
#[inline(always)]
fn max_of(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// `a` if it is less than `b`, else `b` (see [`max_of`]).
#[inline(always)]
fn min_of(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

/// `sin x` for `x` in `[0, π/2]`, by its Taylor polynomial to `x^11` (error below 6e-8), in
/// operations WGSL repeats exactly: a GPU's `sin` differs from libm's in the last bits.
#[inline(always)]
pub fn sin_poly(x: f32) -> f32 {
    let [c11, c9, c7, c5, c3] = SIN_POLY;
    let x2 = x * x;
    let p = c11;
    let p = p * -x2 + c9;
    let p = p * x2 - c7;
    let p = p * x2 + c5;
    let p = p * x2 - c3;
    let p = p * x2 + 1.0;
    x * p
}

impl Pose {
    /// No move, no turn, scale 1.
    pub const IDENTITY: Pose = Pose {
        translation: [0.0; 3],
        scale: 1.0,
        rotation: [0.0, 0.0, 0.0, 1.0],
    };

    /// The world point of local point `l`.
    #[inline(always)]
    pub fn to_world(&self, l: Vec3) -> Vec3 {
        Vec3::from_array(self.translation) + rotate(self.rotation, l * self.scale)
    }

    /// The local point of world point `x` (the pose's scale must not be 0).
    #[inline(always)]
    pub fn to_local(&self, x: Vec3) -> Vec3 {
        rotate(
            conjugate(self.rotation),
            x - Vec3::from_array(self.translation),
        ) / self.scale
    }

    /// A local direction (or velocity) in the world: rotated and scaled.
    #[inline(always)]
    pub fn vector_to_world(&self, l: Vec3) -> Vec3 {
        rotate(self.rotation, l * self.scale)
    }

    /// A world direction (or velocity) in the local frame.
    #[inline(always)]
    pub fn vector_to_local(&self, x: Vec3) -> Vec3 {
        rotate(conjugate(self.rotation), x) / self.scale
    }

    /// A local unit normal in the world (rotated only: still unit).
    #[inline(always)]
    pub fn normal_to_world(&self, n: Vec3) -> Vec3 {
        rotate(self.rotation, n)
    }

    /// Whether every field is finite, the scale `>= 0` and the rotation a unit quaternion
    /// (its squared length within `1e-6` of 1).
    pub fn is_valid(&self) -> bool {
        let q = Vec3::new(self.rotation[0], self.rotation[1], self.rotation[2]);
        let w = self.rotation[3];
        let len2 = q.dot(q) + w * w;
        Vec3::from_array(self.translation).is_finite()
            && self.scale.is_finite()
            && self.scale >= 0.0
            && q.is_finite()
            && w.is_finite()
            && math::abs(len2 - 1.0) <= 1e-6
    }
}

/// A pose's bits, to compare poses bit for bit in a few vector operations.
#[inline(always)]
fn pose_words(p: &Pose) -> [u32; 8] {
    bytemuck::cast(*p)
}

/// Half the angle between two unit quaternions' rotations as slerp takes it (the shorter
/// way): `acos |a · b|`, in `[0, π/2]`. The host computes it once per pose pair
/// ([`Instance::new`]); the step reads it from the instance, so both backends use the same
/// bits.
pub fn half_turn(a: [f32; 4], b: [f32; 4]) -> f32 {
    let d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3];
    libm::acosf(math::abs(d).min(1.0))
}

/// The most a rotation between unit quaternions `a` and `b` as slerp takes it (the shorter
/// way) moves a point, per unit of its distance from the origin: `2 sin α` for a half angle
/// `α` between them, at most 2. Bounded by `2 |b - a|` (with `b` on `a`'s side), since
/// `sin α ≤ 2 sin(α/2) = |b - a|`: from the components' differences, where `2 half_turn`
/// (an `acos` of a dot product that rounds near 1) reads a small turn as less than it is, or
/// as none. Every rotation slerp passes through on the way is on the arc between them, and
/// moves a point less. WGSL's `chord_per_length` mirrors it (`ride_is_clear`).
fn chord_per_length(a: [f32; 4], b: [f32; 4]) -> f32 {
    let d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3];
    let sign = if d < 0.0 { -1.0 } else { 1.0 };
    let e: [f32; 4] = core::array::from_fn(|i| b[i] * sign - a[i]);
    let gap = math::sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2] + e[3] * e[3]);
    // A few ulps of the components' rounding on top.
    min_of(2.0 * gap * (1.0 + 1e-6) + 4.0 * f32::EPSILON, 2.0)
}

/// Flag of [`Instance::flags`]: the instance exists (a removed one keeps its index, without
/// this flag, so that indices stay stable).
pub const INSTANCE_LIVE: u32 = 1 << 0;

/// Flag of [`Instance::flags`]: the step is the first the instance takes part in after one it
/// did not (hidden by a scale of 0, `Instance::is_active`). A particle may have moved anywhere
/// while it was hidden, so the side it kept for it is stale: each takes its side anew from
/// where it is ([`kept_side`]). The host's scene sets it.
pub const INSTANCE_SHOWN: u32 = 1 << 1;

/// An instance: a proxy placed in the world by the pose it had at the start of the step and
/// the pose it has at its end. 80 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Instance {
    /// The pose at the start of the step.
    pub start: Pose,
    /// The pose at the end of the step.
    pub end: Pose,
    /// Index of its proxy in the scene's proxies.
    pub proxy: u32,
    /// [`INSTANCE_LIVE`] and [`INSTANCE_SHOWN`]; the other bits are zero.
    pub flags: u32,
    /// The broad phase's leaf that holds it ([`BroadNode`]), when it is active.
    pub leaf: u32,
    /// [`half_turn`] of its two rotations.
    pub half_turn: f32,
}

const _: () = assert!(core::mem::size_of::<Instance>() == 80);

impl Instance {
    /// A live instance of `proxy` moving from `start` to `end` (its broad-phase leaf is set
    /// when the broad phase is built).
    pub fn new(proxy: u32, start: Pose, end: Pose) -> Self {
        Self {
            start,
            end,
            proxy,
            flags: INSTANCE_LIVE,
            leaf: u32::MAX,
            half_turn: half_turn(start.rotation, end.rotation),
        }
    }

    /// Whether it takes part in the step: live, and not hidden by a scale of 0 at either
    /// end of the step (particles pass where it is).
    pub fn is_active(&self) -> bool {
        self.flags & INSTANCE_LIVE != 0 && self.start.scale > 0.0 && self.end.scale > 0.0
    }

    /// Whether it does not move in this step (the two poses are the same bits).
    #[inline(always)]
    pub fn is_static(&self) -> bool {
        pose_words(&self.start) == pose_words(&self.end)
    }

    /// Its pose at fraction `u` of the step: translation and scale interpolated linearly,
    /// rotation by slerp the shorter way; exactly the start at 0 and the end at 1.
    #[inline(always)]
    pub fn pose_at(&self, u: f32) -> Pose {
        if u <= 0.0 {
            return self.start;
        }
        if u >= 1.0 {
            return self.end;
        }
        let (a, b) = (&self.start, &self.end);
        let lerp = |x: f32, y: f32| x + (y - x) * u;
        let translation = core::array::from_fn(|i| lerp(a.translation[i], b.translation[i]));
        let scale = lerp(a.scale, b.scale);
        let (qa, mut qb) = (a.rotation, b.rotation);
        let d = qa[0] * qb[0] + qa[1] * qb[1] + qa[2] * qb[2] + qa[3] * qb[3];
        if d < 0.0 {
            qb = qb.map(|c| -c);
        }
        let phi = self.half_turn;
        let (wa, wb) = if phi < SLERP_LINEAR_BELOW {
            (1.0 - u, u)
        } else {
            let s = sin_poly(phi);
            (sin_poly((1.0 - u) * phi) / s, sin_poly(u * phi) / s)
        };
        let q: [f32; 4] = core::array::from_fn(|i| qa[i] * wa + qb[i] * wb);
        let len = math::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
        Pose {
            translation,
            scale,
            rotation: q.map(|c| c / len),
        }
    }

    /// The world box that holds its proxy's root cube at every pose of the step, padded for
    /// rounding. For a static instance, the box of the cube's eight corners. For a moving one,
    /// where two bounds overlap, each holding the cube at every pose of the step, with `k` the
    /// most the turn moves a point per unit of its distance from the local origin
    /// (`min(2 |b − a|, 2)` for the rotations `a` and `b`, `b` on `a`'s side):
    /// - the cube's centre path with the rotation held at the start (a segment), grown by the
    ///   cube's radius and by how far turning can move the centre (`|c| k`), both at the
    ///   larger scale: a ball about the centre, whatever the turn;
    /// - the box of the cube's corners with the rotation held at the start, at the start's and
    ///   the end's translation and scale, grown by how far turning can move a corner (`|l| k`
    ///   at the larger scale, `l` the corner farthest from the local origin). Translation and
    ///   scale change linearly, so with the rotation held each point of the cube moves along
    ///   a segment between its two ends, inside that box; the turn moves each point by at most
    ///   that. For a slow turn this is the cube's own box swept, where the ball is `√3` times
    ///   as wide.
    pub fn swept_box(&self, view: &ProxyView<'_>) -> Aabb {
        self.swept_box_of(&view.root_aabb())
    }

    /// [`Self::swept_box`] of any local box (the host checks how the instances' shells
    /// overlap with the boxes of their surface leaves).
    pub fn swept_box_of(&self, local: &Aabb) -> Aabb {
        let root = local;
        let corner = |k: u32| {
            Vec3::new(
                if k & 1 != 0 { root.max.x } else { root.min.x },
                if k & 2 != 0 { root.max.y } else { root.min.y },
                if k & 4 != 0 { root.max.z } else { root.min.z },
            )
        };
        let (bmin, bmax) = if self.is_static() {
            let mut lo = Vec3::splat(f32::INFINITY);
            let mut hi = Vec3::splat(f32::NEG_INFINITY);
            for k in 0..8u32 {
                let w = self.start.to_world(corner(k));
                lo = lo.min(w);
                hi = hi.max(w);
            }
            (lo, hi)
        } else {
            let c = (root.min + root.max) * 0.5;
            let radius = (root.max - root.min).length() * 0.5;
            let s_max = self.start.scale.max(self.end.scale);
            let turn = chord_per_length(self.start.rotation, self.end.rotation);
            let c0 = Vec3::from_array(self.start.translation)
                + rotate(self.start.rotation, c * self.start.scale);
            let c1 = Vec3::from_array(self.end.translation)
                + rotate(self.start.rotation, c * self.end.scale);
            let grow = s_max * (radius + c.length() * turn);
            let (ball_min, ball_max) = (c0.min(c1) - grow, c0.max(c1) + grow);
            let mut lo = Vec3::splat(f32::INFINITY);
            let mut hi = Vec3::splat(f32::NEG_INFINITY);
            let mut far = 0.0f32;
            for k in 0..8u32 {
                let l = corner(k);
                for pose in [&self.start, &self.end] {
                    let w = Vec3::from_array(pose.translation)
                        + rotate(self.start.rotation, l * pose.scale);
                    lo = lo.min(w);
                    hi = hi.max(w);
                }
                far = far.max(l.length());
            }
            let bend = s_max * far * turn;
            (ball_min.max(lo - bend), ball_max.min(hi + bend))
        };
        // Rounding of the transforms: a few ulps of the largest coordinate involved.
        let mag = bmin.abs().max(bmax.abs()).max_element();
        let pad = 16.0 * ulp(mag) + PATH_PAD;
        Aabb {
            min: bmin - pad,
            max: bmax + pad,
        }
    }
}

/// Value of [`BroadNode::kind`] for an internal node: its children are the next node and
/// node [`BroadNode::index`].
pub const BROAD_INTERNAL: u32 = 0;
/// Value of [`BroadNode::kind`] for a leaf: it holds instance [`BroadNode::index`].
pub const BROAD_LEAF: u32 = 1;

/// A node of the broad phase: a box and either two children or one instance. Nodes are in
/// depth-first order: node 0 is the root, an internal node's first child follows it and its
/// second is at `index`. 32 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct BroadNode {
    /// Minimum corner of a box holding everything below.
    pub min: [f32; 3],
    /// The second child (internal) or the instance (leaf).
    pub index: u32,
    /// Maximum corner.
    pub max: [f32; 3],
    /// [`BROAD_INTERNAL`] or [`BROAD_LEAF`].
    pub kind: u32,
}

const _: () = assert!(core::mem::size_of::<BroadNode>() == 32);

impl BroadNode {
    fn aabb(&self) -> Aabb {
        Aabb {
            min: Vec3::from_array(self.min),
            max: Vec3::from_array(self.max),
        }
    }
}

/// Why a scene was rejected.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum SceneError {
    /// More instances than [`MAX_INSTANCES`].
    TooManyInstances(usize),
    /// An instance names a proxy the scene does not have.
    BadProxy {
        /// The instance.
        instance: u32,
        /// The proxy it names.
        proxy: u32,
    },
    /// An instance's pose is not finite, has a negative scale, or a rotation that is not a
    /// unit quaternion; or its flags have unknown bits.
    BadPose {
        /// The instance.
        instance: u32,
    },
    /// An instance's stored half turn is not [`half_turn`] of its poses.
    BadTurn {
        /// The instance.
        instance: u32,
    },
    /// An instance turns too far in one step for its proxy's finest leaf.
    TurnsTooFast {
        /// The instance.
        instance: u32,
        /// Its turn in the step, degrees.
        degrees: f32,
        /// The most it may turn, degrees.
        max_degrees: f32,
    },
    /// An instance is so far from the origin, or so small, that `f32` cannot resolve a
    /// leaf of its proxy where it is.
    TooFarOut {
        /// The instance.
        instance: u32,
    },
    /// The broad phase is not a tree of the active instances in depth-first order.
    BadBroadPhase {
        /// The node where it went wrong.
        node: u32,
    },
    /// A broad-phase box does not hold what is below it.
    BroadBoxTooSmall {
        /// The node.
        node: u32,
    },
    /// The broad phase is deeper than [`MAX_BROAD_DEPTH`].
    BroadTooDeep,
    /// An active instance is not in the broad phase (or an inactive one is).
    NotInBroadPhase {
        /// The instance.
        instance: u32,
    },
    /// An instance's proxy, at its scale, was baked for another radius than the particles'.
    RadiusMismatch {
        /// The instance.
        instance: u32,
        /// Its proxy's radius times its scale.
        baked: f32,
        /// The particles' radius.
        radius: f32,
    },
    /// An instance of a proxy baked for a radius changes its scale in the step: the offset
    /// surface would have to change with it.
    ScaledRadius {
        /// The instance.
        instance: u32,
    },
}

impl SceneError {
    /// The instance the error is about, where it names one (a caller can then say which
    /// node or object that is).
    pub fn instance(&self) -> Option<u32> {
        match *self {
            SceneError::BadProxy { instance, .. }
            | SceneError::BadPose { instance }
            | SceneError::BadTurn { instance }
            | SceneError::TurnsTooFast { instance, .. }
            | SceneError::TooFarOut { instance }
            | SceneError::NotInBroadPhase { instance }
            | SceneError::RadiusMismatch { instance, .. }
            | SceneError::ScaledRadius { instance } => Some(instance),
            SceneError::TooManyInstances(_)
            | SceneError::BadBroadPhase { .. }
            | SceneError::BroadBoxTooSmall { .. }
            | SceneError::BroadTooDeep => None,
        }
    }
}

impl core::fmt::Display for SceneError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            SceneError::TooManyInstances(n) => {
                write!(f, "{n} instances; a scene holds at most {MAX_INSTANCES}")
            }
            SceneError::BadProxy { instance, proxy } => {
                write!(f, "instance {instance} names proxy {proxy}, which the scene does not have")
            }
            SceneError::BadPose { instance } => write!(
                f,
                "instance {instance}: a pose must be finite, with a scale >= 0 and a unit rotation quaternion"
            ),
            SceneError::BadTurn { instance } => write!(
                f,
                "instance {instance}: its stored half turn is not that of its poses (build it with Instance::new)"
            ),
            SceneError::TurnsTooFast {
                instance,
                degrees,
                max_degrees,
            } => write!(
                f,
                "instance {instance} turns {degrees:.1} degrees in one step; its proxy allows at most {max_degrees:.1}: use a smaller time step"
            ),
            SceneError::TooFarOut { instance } => write!(
                f,
                "instance {instance} is too far from the origin (or too small) for f32 to resolve a leaf of its proxy there"
            ),
            SceneError::BadBroadPhase { node } => {
                write!(f, "broad phase node {node}: not a tree of the active instances")
            }
            SceneError::BroadBoxTooSmall { node } => {
                write!(f, "broad phase node {node}: its box does not hold what is below it")
            }
            SceneError::BroadTooDeep => {
                write!(f, "the broad phase is deeper than {MAX_BROAD_DEPTH} levels")
            }
            SceneError::NotInBroadPhase { instance } => write!(
                f,
                "instance {instance} is active but not in the broad phase, or inactive and in it"
            ),
            SceneError::RadiusMismatch {
                instance,
                baked,
                radius,
            } => write!(
                f,
                "instance {instance}: the particles' radius is {radius} but its proxy at its scale was baked for radius {baked}: bake its mesh for radius {radius} divided by its scale"
            ),
            SceneError::ScaledRadius { instance } => write!(
                f,
                "instance {instance} changes its scale in the step, but its proxy was baked for a particle radius: a scaled offset surface is not the offset surface at the scaled radius; keep its scale fixed"
            ),
        }
    }
}

impl core::error::Error for SceneError {}

/// The largest turn an instance of a proxy may make in one step, in radians: the one whose
/// chords alone (no particle motion) need half of [`MAX_SUBSTEPS`] to stay within
/// [`SUBSTEP_MARGIN`] of the curve, up to half a turn.
pub fn max_turn(view: &ProxyView<'_>) -> f32 {
    let root = view.root_aabb();
    let r = local_radius(&root);
    let m = SUBSTEP_MARGIN * view.finest_leaf_size();
    // θ² r / 8 ≤ m (n/2)²  ⇒  θ ≤ (n/2) sqrt(8 m / r).
    let n = (MAX_SUBSTEPS / 2) as f32;
    (n * math::sqrt(8.0 * m / r)).min(core::f32::consts::PI)
}

/// The largest distance from the local origin to a point of the root cube.
fn local_radius(root: &Aabb) -> f32 {
    root.min.abs().max(root.max.abs()).length()
}

fn contains(outer: &Aabb, inner: &Aabb) -> bool {
    outer.min.cmple(inner.min).all() && outer.max.cmpge(inner.max).all()
}

/// A validated scene: proxies, instances and the broad phase over them.
#[derive(Clone, Copy)]
pub struct SceneView<'a> {
    proxies: &'a [ProxyView<'a>],
    instances: &'a [Instance],
    nodes: &'a [BroadNode],
    /// The one active instance, when the scene is one static instance at the identity pose:
    /// the plain step.
    plain: Option<u32>,
    /// The grid over the broad phase ([`SceneView::with_grid`]), if one was built.
    grid: Option<BroadGrid<'a>>,
}

impl core::fmt::Debug for SceneView<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("SceneView")
            .field("proxies", &self.proxies.len())
            .field("instances", &self.instances.len())
            .field("broad_nodes", &self.nodes.len())
            .finish()
    }
}

impl<'a> SceneView<'a> {
    /// Checks every live, visible instance against particles of `radius`: its proxy's radius
    /// times its scale must match it ([`crate::check_radius`]), and an instance of a proxy
    /// baked for a radius must keep its scale through the step.
    pub fn check_radius(&self, radius: f32) -> Result<(), SceneError> {
        for (i, inst) in self.instances.iter().enumerate() {
            let instance = i as u32;
            if inst.flags & INSTANCE_LIVE == 0 {
                continue;
            }
            let Some(view) = self.proxies.get(inst.proxy as usize) else {
                continue;
            };
            let baked = view.header().radius;
            let (s0, s1) = (inst.start.scale, inst.end.scale);
            if s0 == 0.0 && s1 == 0.0 {
                continue;
            }
            if baked > 0.0 && s0 != s1 {
                return Err(SceneError::ScaledRadius { instance });
            }
            let baked = baked * s1;
            if crate::check_radius(baked, radius).is_err() {
                return Err(SceneError::RadiusMismatch {
                    instance,
                    baked,
                    radius,
                });
            }
        }
        Ok(())
    }

    /// Validates a scene: every instance's proxy index, poses, flags and half turn; every
    /// pose near enough to the origin for `f32` to resolve its proxy's finest leaf; the
    /// broad phase a tree in depth-first order (each internal node's first child right after
    /// it, its second further on and before the end of the node's range), at most
    /// [`MAX_BROAD_DEPTH`] deep, whose leaves are the active instances, each once (an active
    /// instance's `leaf` names the leaf that holds it), and whose boxes hold the swept boxes
    /// of the instances below them. No allocation; linear in the sizes.
    pub fn new(
        proxies: &'a [ProxyView<'a>],
        instances: &'a [Instance],
        nodes: &'a [BroadNode],
    ) -> Result<Self, SceneError> {
        if instances.len() > MAX_INSTANCES as usize {
            return Err(SceneError::TooManyInstances(instances.len()));
        }
        let mut active = 0usize;
        for (i, inst) in instances.iter().enumerate() {
            let instance = i as u32;
            if inst.flags & !(INSTANCE_LIVE | INSTANCE_SHOWN) != 0
                || !inst.start.is_valid()
                || !inst.end.is_valid()
            {
                return Err(SceneError::BadPose { instance });
            }
            if inst.half_turn.to_bits()
                != half_turn(inst.start.rotation, inst.end.rotation).to_bits()
            {
                return Err(SceneError::BadTurn { instance });
            }
            let Some(view) = proxies.get(inst.proxy as usize) else {
                return Err(SceneError::BadProxy {
                    instance,
                    proxy: inst.proxy,
                });
            };
            if !inst.is_active() {
                continue;
            }
            active += 1;
            let turn = 2.0 * inst.half_turn;
            let max = max_turn(view);
            if turn > max {
                return Err(SceneError::TurnsTooFast {
                    instance,
                    degrees: turn.to_degrees(),
                    max_degrees: max.to_degrees(),
                });
            }
            // A finest leaf in the world must stay many ulps of the coordinates there wide
            // (the static format asks 4 ulps of a cell at the tree depth of the root).
            let b = inst.swept_box(view);
            let leaf = view.finest_leaf_size() * inst.start.scale.min(inst.end.scale);
            let mag = b.min.abs().max(b.max.abs()).max_element();
            if !b.min.is_finite() || !b.max.is_finite() || !(leaf >= 64.0 * ulp(mag)) {
                return Err(SceneError::TooFarOut { instance });
            }
        }
        if nodes.is_empty() {
            if active > 0 {
                let instance = instances.iter().position(|i| i.is_active()).unwrap_or(0);
                return Err(SceneError::NotInBroadPhase {
                    instance: instance as u32,
                });
            }
            return Ok(Self {
                proxies,
                instances,
                nodes,
                plain: None,
                grid: None,
            });
        }
        // Depth first, with an explicit stack of (node, end of its range, depth).
        let mut stack = [(0u32, 0u32, 0u32); MAX_BROAD_DEPTH as usize + 2];
        let mut top = 1usize;
        stack[0] = (0, nodes.len() as u32, 1);
        let mut leaves = 0usize;
        while top > 0 {
            top -= 1;
            let (i, end, depth) = stack[top];
            if depth > MAX_BROAD_DEPTH {
                return Err(SceneError::BroadTooDeep);
            }
            let node = &nodes[i as usize];
            let b = node.aabb();
            if !b.min.is_finite() || !b.max.is_finite() || b.min.cmpgt(b.max).any() {
                return Err(SceneError::BroadBoxTooSmall { node: i });
            }
            match node.kind {
                BROAD_LEAF => {
                    if end != i + 1 {
                        return Err(SceneError::BadBroadPhase { node: i });
                    }
                    let Some(inst) = instances.get(node.index as usize) else {
                        return Err(SceneError::BadBroadPhase { node: i });
                    };
                    if !inst.is_active() || inst.leaf != i {
                        return Err(SceneError::NotInBroadPhase {
                            instance: node.index,
                        });
                    }
                    let view = &proxies[inst.proxy as usize];
                    if !contains(&b, &inst.swept_box(view)) {
                        return Err(SceneError::BroadBoxTooSmall { node: i });
                    }
                    leaves += 1;
                }
                BROAD_INTERNAL => {
                    let second = node.index;
                    if !(i + 1 < second && second < end) {
                        return Err(SceneError::BadBroadPhase { node: i });
                    }
                    for child in [i + 1, second] {
                        if !contains(&b, &nodes[child as usize].aabb()) {
                            return Err(SceneError::BroadBoxTooSmall { node: i });
                        }
                    }
                    stack[top] = (second, end, depth + 1);
                    stack[top + 1] = (i + 1, second, depth + 1);
                    top += 2;
                }
                _ => return Err(SceneError::BadBroadPhase { node: i }),
            }
        }
        if leaves != active {
            // Every node was visited once, and every leaf names an active instance that names
            // it back: some active instance names no leaf that holds it.
            let missing = instances.iter().enumerate().position(|(i, inst)| {
                inst.is_active()
                    && nodes
                        .get(inst.leaf as usize)
                        .is_none_or(|n| n.kind != BROAD_LEAF || n.index != i as u32)
            });
            return Err(SceneError::NotInBroadPhase {
                instance: missing.unwrap_or(0) as u32,
            });
        }
        let plain = if active == 1 && nodes.len() == 1 {
            let c = nodes[0].index;
            let inst = &instances[c as usize];
            let identity = pose_words(&inst.start) == pose_words(&Pose::IDENTITY);
            // A shown instance's kept sides are not read: the general path asks `kept_side`.
            (inst.is_static() && identity && inst.flags & INSTANCE_SHOWN == 0).then_some(c)
        } else {
            None
        };
        Ok(Self {
            proxies,
            instances,
            nodes,
            plain,
            grid: None,
        })
    }

    /// The words a grid over this scene's broad phase takes ([`Self::with_grid`]): its cell
    /// starts and its entries; `None` when no grid is built for it (fewer than two active
    /// instances, or cells too small for the coordinates' rounding).
    pub fn grid_sizes(&self) -> Option<(usize, usize)> {
        let shape = GridShape::of(self.nodes)?;
        let mut entries = 0usize;
        shape.for_each_entry(self.nodes, |_, _| entries += 1);
        Some((shape.cells() + 1, entries))
    }

    /// This view with a uniform grid over its broad phase, built into `starts` and `entries`
    /// (sized by [`Self::grid_sizes`]; otherwise, or with no grid for the scene, the view is
    /// returned as it is). Each cell lists the broad phase's leaves whose boxes meet it grown
    /// by a quarter cell, in the walk's order; a step's first query whose box lies inside one
    /// grown cell filters that list instead of walking the tree: the walk's answer in its
    /// order (a leaf's box meets a box inside a larger one only if it meets the larger), where
    /// most particles of a scene of many instances find an empty list at once. Built from the
    /// validated broad phase, so it holds every leaf it must. Host-only: WGSL walks (the same
    /// answers). Allocates nothing.
    pub fn with_grid(mut self, starts: &'a mut [u32], entries: &'a mut [u32]) -> Self {
        let Some(shape) = GridShape::of(self.nodes) else {
            return self;
        };
        if starts.len() != shape.cells() + 1 {
            return self;
        }
        // A counting sort by cell: counts, then each cell's start as a cursor, then shifted
        // back to starts. Leaves come in node order, the walk's, within each cell.
        starts.fill(0);
        shape.for_each_entry(self.nodes, |k, _| starts[k + 1] += 1);
        for k in 1..starts.len() {
            starts[k] += starts[k - 1];
        }
        if starts[starts.len() - 1] as usize != entries.len() {
            return self;
        }
        shape.for_each_entry(self.nodes, |k, leaf| {
            entries[starts[k] as usize] = leaf;
            starts[k] += 1;
        });
        for k in (1..starts.len()).rev() {
            starts[k] = starts[k - 1];
        }
        starts[0] = 0;
        self.grid = Some(BroadGrid {
            shape,
            starts,
            entries,
        });
        self
    }

    /// The one instance and its proxy when the scene is one static instance at the identity
    /// pose: its particles take the plain step ([`step_plain`]).
    #[inline(always)]
    pub fn plain_proxy(&self) -> Option<(u32, &ProxyView<'a>)> {
        let c = self.plain?;
        Some((c, &self.proxies[self.instances[c as usize].proxy as usize]))
    }

    /// The proxies.
    pub fn proxies(&self) -> &'a [ProxyView<'a>] {
        self.proxies
    }

    /// The instances.
    pub fn instances(&self) -> &'a [Instance] {
        self.instances
    }

    /// The broad phase's nodes.
    pub fn nodes(&self) -> &'a [BroadNode] {
        self.nodes
    }

    /// How many active instances' swept boxes meet `b`, and the first of them in the broad
    /// phase's order (0 when none).
    #[inline(always)]
    fn count_candidates(&self, b: &Aabb) -> (u32, u32) {
        let (mut count, mut first) = (0u32, 0u32);
        self.for_each_candidate(b, |c| {
            if count == 0 {
                first = c;
            }
            count += 1;
        });
        (count, first)
    }

    /// Calls `f` with every active instance whose swept box meets `b`, in the broad phase's
    /// depth-first order (the order ties between instances are broken in).
    #[inline(always)]
    pub fn for_each_candidate(&self, b: &Aabb, mut f: impl FnMut(u32)) {
        let mut walk = BroadWalk::new(self.nodes);
        while let Some(c) = walk.next(self.nodes, b) {
            f(c);
        }
    }

    /// [`Self::count_candidates`] of `b`, keeping what the walk found as [`Nearby`] for the
    /// step's later queries; from the grid's cell when `b` lies inside one (the same answer).
    #[inline(always)]
    fn count_nearby(&self, b: &Aabb) -> (u32, u32, Nearby) {
        let mut near = Nearby {
            within: *b,
            leaves: [0; NEARBY],
            len: 0,
        };
        let (mut count, mut first) = (0u32, 0u32);
        let mut keep = |i: u32| {
            if count == 0 {
                first = self.nodes[i as usize].index;
            }
            if (count as usize) < NEARBY {
                near.leaves[count as usize] = i;
            }
            count += 1;
        };
        if let Some(list) = self.grid.as_ref().and_then(|g| g.cell_holding(b)) {
            for &i in list {
                if meets(&self.nodes[i as usize], b) {
                    keep(i);
                }
            }
        } else {
            let mut walk = BroadWalk::new(self.nodes);
            while let Some(i) = walk.next_leaf(self.nodes, b) {
                keep(i);
            }
        }
        near.len = count;
        (count, first, near)
    }

    /// [`Self::for_each_candidate`], from `near` when `b` lies inside the box it was found
    /// for and it holds every instance found there: the same instances in the same order
    /// (see [`Nearby`]), without a walk.
    #[inline(always)]
    fn for_each_nearby(&self, near: &Nearby, b: &Aabb, mut f: impl FnMut(u32)) {
        if !near.holds(b) {
            self.for_each_candidate(b, f);
            return;
        }
        for &i in &near.leaves[..near.len as usize] {
            let node = &self.nodes[i as usize];
            if meets(node, b) {
                f(node.index);
            }
        }
    }

    /// [`Self::count_candidates`], from `near` as [`Self::for_each_nearby`] says.
    #[inline(always)]
    fn count_in_nearby(&self, near: &Nearby, b: &Aabb) -> (u32, u32) {
        if !near.holds(b) {
            return self.count_candidates(b);
        }
        let (mut count, mut first) = (0u32, 0u32);
        for &i in &near.leaves[..near.len as usize] {
            let node = &self.nodes[i as usize];
            if meets(node, b) {
                if count == 0 {
                    first = node.index;
                }
                count += 1;
            }
        }
        (count, first)
    }
}

/// The most cells the grid over a broad phase has ([`SceneView::with_grid`]).
pub const GRID_MAX_CELLS: usize = 1 << 18;

/// Where a grid's cells are: `dims` cubes of edge `cell` from `origin`, each grown by a
/// quarter of its edge on every side.
#[derive(Clone, Copy, Debug)]
struct GridShape {
    origin: Vec3,
    cell: f32,
    dims: [u32; 3],
}

impl GridShape {
    /// The grid for a validated broad phase: about 8 cells a leaf over the root's box, or
    /// `None` for fewer than two leaves or cells under 1024 ulps of the coordinates (where
    /// the rounding of a cell's planes would matter when enumerating the cells a box meets).
    fn of(nodes: &[BroadNode]) -> Option<GridShape> {
        let root = nodes.first()?;
        let leaves = nodes.iter().filter(|n| n.kind == BROAD_LEAF).count();
        if leaves < 2 {
            return None;
        }
        let (lo, hi) = (Vec3::from_array(root.min), Vec3::from_array(root.max));
        let ext = hi - lo;
        let target = (8 * leaves).min(GRID_MAX_CELLS / 2) as f32;
        let volume = ext.x * ext.y * ext.z;
        let cell = libm::cbrtf(volume / target).max(ext.max_element() / 64.0);
        let mag = lo.abs().max(hi.abs()).max_element();
        if !(cell.is_finite() && cell > 0.0 && cell >= 1024.0 * ulp(mag)) {
            return None;
        }
        let mut dims = [1u32; 3];
        for (a, d) in dims.iter_mut().enumerate() {
            *d = (math::floor(ext[a] / cell) as u32).saturating_add(1);
        }
        let cells = dims.iter().map(|&d| d as usize).product::<usize>();
        (cells <= GRID_MAX_CELLS).then_some(GridShape {
            origin: lo,
            cell,
            dims,
        })
    }

    fn cells(&self) -> usize {
        self.dims.iter().map(|&d| d as usize).product()
    }

    /// Cell `k`'s box, grown by a quarter cell.
    #[inline(always)]
    fn grown(&self, k: [u32; 3]) -> Aabb {
        let m = self.cell * 0.25;
        let kf = Vec3::new(k[0] as f32, k[1] as f32, k[2] as f32);
        Aabb {
            min: self.origin + kf * self.cell - m,
            max: self.origin + (kf + 1.0) * self.cell + m,
        }
    }

    #[inline(always)]
    fn index(&self, k: [u32; 3]) -> usize {
        (k[2] as usize * self.dims[1] as usize + k[1] as usize) * self.dims[0] as usize
            + k[0] as usize
    }

    /// The cell whose lower corner `x` is nearest below, if it is in the grid (truncation is
    /// the floor of a coordinate not below the origin; `libm`'s `floorf` is a call).
    #[inline(always)]
    fn cell_of(&self, x: Vec3) -> Option<[u32; 3]> {
        let q = (x - self.origin) / self.cell;
        let dims = Vec3::new(
            self.dims[0] as f32,
            self.dims[1] as f32,
            self.dims[2] as f32,
        );
        if !(q.cmpge(Vec3::ZERO) & q.cmplt(dims)).all() {
            return None;
        }
        Some([q.x as u32, q.y as u32, q.z as u32])
    }

    /// Calls `f(cell index, leaf node)` for every cell whose grown box a leaf's box meets,
    /// leaves in node order. The cells are looked for one beyond the range its box's corners
    /// fall in on each axis, which holds every cell whose grown box it meets: the rounding of
    /// those corners' cells is far below the three quarters of a cell that separate the next
    /// one's grown box from them (cells of 1024 ulps at least).
    fn for_each_entry(&self, nodes: &[BroadNode], mut f: impl FnMut(usize, u32)) {
        for (i, node) in nodes.iter().enumerate() {
            if node.kind != BROAD_LEAF {
                continue;
            }
            let mut lo = [0u32; 3];
            let mut hi = [0u32; 3];
            for a in 0..3 {
                let last = self.dims[a] as f32 - 1.0;
                let at = |x: f32| math::floor((x - self.origin[a]) / self.cell);
                lo[a] = (at(node.min[a]) - 1.0).clamp(0.0, last) as u32;
                hi[a] = (at(node.max[a]) + 1.0).clamp(0.0, last) as u32;
            }
            for z in lo[2]..=hi[2] {
                for y in lo[1]..=hi[1] {
                    for x in lo[0]..=hi[0] {
                        if meets(node, &self.grown([x, y, z])) {
                            f(self.index([x, y, z]), i as u32);
                        }
                    }
                }
            }
        }
    }
}

/// A uniform grid over a scene's broad phase ([`SceneView::with_grid`]): each cell's list of
/// the leaves whose boxes meet it grown by a quarter cell, in node order.
#[derive(Clone, Copy, Debug)]
struct BroadGrid<'a> {
    shape: GridShape,
    starts: &'a [u32],
    entries: &'a [u32],
}

impl<'a> BroadGrid<'a> {
    /// The list of the grown cell that holds `b`, if one does: every leaf whose box meets
    /// `b` meets that cell, so it is in the list.
    #[inline(always)]
    fn cell_holding(&self, b: &Aabb) -> Option<&'a [u32]> {
        let k = self.shape.cell_of(b.min)?;
        if !contains(&self.shape.grown(k), b) {
            return None;
        }
        let i = self.shape.index(k);
        let (s, e) = (*self.starts.get(i)?, *self.starts.get(i + 1)?);
        self.entries.get(s as usize..e as usize)
    }
}

/// How many broad-phase leaves [`Nearby`] holds.
const NEARBY: usize = 8;

/// The broad-phase leaves whose boxes meet a box (`within`), in the walk's order: what the
/// first query of a scene step found, kept for the step's later queries. A walk yields
/// exactly the leaves whose boxes meet its box, in depth-first order (every node's box holds
/// the boxes below it, as validation proved, so no leaf that meets the box is cut off above
/// it), and a leaf meets a box inside `within` only if it meets `within`: so for a box inside
/// `within`, these leaves filtered by the same test are the walk's answer. A particle among
/// moving instances walked the broad phase three times a round; it now walks once a step
/// while its queries stay inside its first. Host-only: WGSL walks each time (the same
/// answers).
#[derive(Clone, Copy)]
struct Nearby {
    within: Aabb,
    /// The leaves' node indices: the first [`NEARBY`] of them.
    leaves: [u32; NEARBY],
    /// How many leaves met `within`: more than [`NEARBY`] means not all are kept.
    len: u32,
}

impl Nearby {
    /// Whether these are every leaf that meets `b`, and more: all that met `within` are
    /// kept, and `b` lies inside it.
    #[inline(always)]
    fn holds(&self, b: &Aabb) -> bool {
        self.len as usize <= NEARBY && contains(&self.within, b)
    }
}

/// Whether a broad-phase node's box meets `b` (closed boxes): the walk's test.
#[inline(always)]
fn meets(node: &BroadNode, b: &Aabb) -> bool {
    !(Vec3::from_array(node.min).cmpgt(b.max).any()
        || Vec3::from_array(node.max).cmplt(b.min).any())
}

/// A walk of a validated broad phase that yields, one at a time, the instances whose swept
/// boxes meet a box, in depth-first order ([`SceneView::for_each_candidate`]; WGSL, which has
/// no closures, walks with it directly).
struct BroadWalk {
    stack: [u32; MAX_BROAD_DEPTH as usize + 1],
    top: usize,
}

impl BroadWalk {
    #[inline(always)]
    fn new(nodes: &[BroadNode]) -> Self {
        Self {
            stack: [0; MAX_BROAD_DEPTH as usize + 1],
            top: (!nodes.is_empty()) as usize,
        }
    }

    /// The next instance whose swept box meets `b`, or `None` when the walk is over.
    #[inline(always)]
    fn next(&mut self, nodes: &[BroadNode], b: &Aabb) -> Option<u32> {
        self.next_leaf(nodes, b).map(|i| nodes[i as usize].index)
    }

    /// [`Self::next`]'s leaf node (its index in `nodes`), not its instance.
    #[inline(always)]
    fn next_leaf(&mut self, nodes: &[BroadNode], b: &Aabb) -> Option<u32> {
        while self.top > 0 {
            self.top -= 1;
            let i = self.stack[self.top];
            let node = &nodes[i as usize];
            if !meets(node, b) {
                continue;
            }
            if node.kind == BROAD_LEAF {
                return Some(i);
            }
            // Validation proved the depth: the stack holds every pending second child. The
            // first child is visited first.
            self.stack[self.top] = node.index;
            self.stack[self.top + 1] = i + 1;
            self.top += 2;
        }
        None
    }
}

/// A side slot that holds nothing.
pub const EMPTY_SLOT: u32 = u32::MAX;
/// Bits of a slot that hold the side word (as [`Particle::side`]: the side and a cage).
pub const SLOT_SIDE_MASK: u32 = SIDE_MASK | SIDE_CAGE_MASK;
/// Bit of a slot set when its side must be kept: the particle ended its last step in a
/// surface leaf of the instance, or caged in a solid one.
pub const SLOT_REQUIRED: u32 = 1 << 9;
/// Shift of the instance index in a slot.
pub const SLOT_INSTANCE_SHIFT: u32 = 10;
const _: () = assert!(SLOT_SIDE_MASK < SLOT_REQUIRED);
// Indices are below `MAX_INSTANCES`, so no slot of an instance reads as `EMPTY_SLOT`.
const _: () = assert!(MAX_INSTANCES < (1 << (32 - SLOT_INSTANCE_SHIFT)));

/// No instance (a [`SceneSides::hint_instance`] that names none).
pub const NO_INSTANCE: u32 = u32::MAX;

/// A particle's state in a scene, beside it in a side buffer: its side for each instance it
/// is near, and one leaf hint. 48 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub struct SceneSides {
    /// The leaf the last step ended in, in the proxy of [`Self::hint_instance`].
    pub hint: LeafHint,
    /// The instance the hint is for, or [`NO_INSTANCE`].
    pub hint_instance: u32,
    /// Slots: [`EMPTY_SLOT`], or `instance << SLOT_INSTANCE_SHIFT`, [`SLOT_REQUIRED`] and the
    /// side word. (The hint and the first slot come first: a one-proxy scene reads 16 bytes.)
    pub slots: [u32; SIDE_SLOTS],
    /// Zero.
    pub _pad: u32,
}

const _: () = assert!(core::mem::size_of::<SceneSides>() == 48);

/// The part of a particle's [`SceneSides`] every scene step reads: the hint and the first
/// slot. A one-proxy static scene reads only this, 16 bytes (the plain step reads its 8-byte
/// hint); the other slots are [`SceneSlots`], in a buffer of their own.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub struct SceneHint {
    /// [`SceneSides::hint`].
    pub hint: LeafHint,
    /// [`SceneSides::hint_instance`].
    pub hint_instance: u32,
    /// [`SceneSides::slots`]`[0]`.
    pub first_slot: u32,
}

const _: () = assert!(core::mem::size_of::<SceneHint>() == 16);

/// The rest of a particle's [`SceneSides`]: slots 1 to 7. 32 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub struct SceneSlots {
    /// [`SceneSides::slots`]`[1..]`.
    pub slots: [u32; SIDE_SLOTS - 1],
    /// Zero.
    pub _pad: u32,
}

const _: () = assert!(core::mem::size_of::<SceneSlots>() == 32);

impl Default for SceneHint {
    fn default() -> Self {
        SceneSides::EMPTY.split().0
    }
}

impl Default for SceneSlots {
    fn default() -> Self {
        SceneSides::EMPTY.split().1
    }
}

impl Default for SceneSides {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl SceneSides {
    /// No sides, no hint.
    pub const EMPTY: SceneSides = SceneSides {
        hint: LeafHint::NONE,
        hint_instance: NO_INSTANCE,
        slots: [EMPTY_SLOT; SIDE_SLOTS],
        _pad: 0,
    };

    /// The two parts the step reads, each in a buffer of its own.
    pub fn split(&self) -> (SceneHint, SceneSlots) {
        let mut rest = [EMPTY_SLOT; SIDE_SLOTS - 1];
        rest.copy_from_slice(&self.slots[1..]);
        (
            SceneHint {
                hint: self.hint,
                hint_instance: self.hint_instance,
                first_slot: self.slots[0],
            },
            SceneSlots {
                slots: rest,
                _pad: 0,
            },
        )
    }

    /// The sides from their two parts.
    pub fn join(hint: &SceneHint, slots: &SceneSlots) -> Self {
        let mut all = [EMPTY_SLOT; SIDE_SLOTS];
        all[0] = hint.first_slot;
        all[1..].copy_from_slice(&slots.slots);
        SceneSides {
            hint: hint.hint,
            hint_instance: hint.hint_instance,
            slots: all,
            _pad: 0,
        }
    }

    /// The side word kept for `instance`, if any.
    pub fn side_of(&self, instance: u32) -> Option<u32> {
        slot_side(&self.slots, instance)
    }

    /// Sets the side word for `instance` (a starting side, from the mesh or a file), kept as
    /// required. `false` when every slot holds another required side.
    pub fn set_side(&mut self, instance: u32, side: u32) -> bool {
        commit(&mut self.slots, instance, side, true)
    }

    /// The instances with a side, and their side words, in slot order.
    pub fn iter(&self) -> impl Iterator<Item = (u32, u32)> + '_ {
        self.slots
            .iter()
            .filter(|&&s| s != EMPTY_SLOT)
            .map(|&s| (s >> SLOT_INSTANCE_SHIFT, s & SLOT_SIDE_MASK))
    }
}

/// Puts `instance`'s side into `slots`: in its own slot, else an empty one, else (when
/// `required`) over the last slot that is not required. `false` when a required side found
/// no room.
fn commit(slots: &mut [u32; SIDE_SLOTS], instance: u32, side: u32, required: bool) -> bool {
    let word = instance << SLOT_INSTANCE_SHIFT
        | if required { SLOT_REQUIRED } else { 0 }
        | (side & SLOT_SIDE_MASK);
    let mut free = None;
    let mut optional = None;
    for (k, &s) in slots.iter().enumerate() {
        if s == EMPTY_SLOT {
            free = free.or(Some(k));
        } else if s >> SLOT_INSTANCE_SHIFT == instance {
            slots[k] = word;
            return true;
        } else if s & SLOT_REQUIRED == 0 {
            optional = Some(k);
        }
    }
    match (free, optional) {
        (Some(k), _) => {
            slots[k] = word;
            true
        }
        (None, Some(k)) if required => {
            slots[k] = word;
            true
        }
        // No room for a side that may be derived again: dropping it loses nothing.
        _ => !required,
    }
}

/// `slots` with none required: a step starts so, and marks again the ones it must keep.
fn optional(mut slots: [u32; SIDE_SLOTS]) -> [u32; SIDE_SLOTS] {
    for s in slots.iter_mut() {
        if *s != EMPTY_SLOT {
            *s &= !SLOT_REQUIRED;
        }
    }
    slots
}

/// The side a particle kept for instance `c` (`inst`), unless the instance was just shown
/// ([`INSTANCE_SHOWN`]): then none, and the particle's side is taken anew where it is.
#[inline]
pub fn kept_side(inst: &Instance, slots: &[u32; SIDE_SLOTS], c: u32) -> Option<u32> {
    if inst.flags & INSTANCE_SHOWN != 0 {
        return None;
    }
    slot_side(slots, c)
}

fn slot_side(slots: &[u32; SIDE_SLOTS], instance: u32) -> Option<u32> {
    slots
        .iter()
        .find(|&&s| s != EMPTY_SLOT && s >> SLOT_INSTANCE_SHIFT == instance)
        .map(|&s| s & SLOT_SIDE_MASK)
}

/// Where and how a particle's last step last collided, in the world. 36 bytes, as the hit
/// records of `sim --hits` are.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Hit {
    /// The instance, or -1 when the step had no collision.
    pub instance: i32,
    /// World position of the collision response.
    pub position: [f32; 3],
    /// World unit normal the response used, facing the particle.
    pub normal: [f32; 3],
    /// Fraction of the whole step at which it happened.
    pub t: f32,
    /// Normal speed relative to the collider just before it, world units per second, `>= 0`.
    pub speed: f32,
}

const _: () = assert!(core::mem::size_of::<Hit>() == 36);

impl Hit {
    /// No collision.
    pub const NONE: Hit = Hit {
        instance: -1,
        position: [0.0; 3],
        normal: [0.0; 3],
        t: 0.0,
        speed: 0.0,
    };

    /// This hit of substep `substep` of `substeps` with its `t` a fraction of the whole step,
    /// `(substep + t) / substeps` (a step of one substep, or no hit, as it is).
    #[inline]
    pub fn in_whole_step(self, substep: u32, substeps: u32) -> Hit {
        if substeps <= 1 || self.instance < 0 {
            return self;
        }
        Hit {
            t: (substep as f32 + self.t) / substeps as f32,
            ..self
        }
    }
}

impl Default for Hit {
    fn default() -> Self {
        Self::NONE
    }
}

/// One collision response of a scene step in the event buffer: the step it happened in (the
/// backend's count of scene steps since the particles were uploaded, from 0), the particle
/// (its index in upload order) and its hit record. 44 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct HitEvent {
    /// The step.
    pub step: u32,
    /// The particle.
    pub particle: u32,
    /// Where and how it collided.
    pub hit: Hit,
}

const _: () = assert!(core::mem::size_of::<HitEvent>() == 44);

/// Receives the straight pieces of a particle's world path in a scene step, with the
/// fractions of the step at their ends ([`step_particle_scene_traced`]; `()` receives nothing).
pub trait PathTrace {
    /// Whether pieces are wanted: `false` skips the work of making them (a ride's chords).
    const ON: bool = true;

    /// The particle moved from `a` at fraction `ua` of the step to `b` at `ub`.
    fn piece(&mut self, a: Vec3, b: Vec3, ua: f32, ub: f32);
}

impl PathTrace for () {
    const ON: bool = false;

    #[inline(always)]
    fn piece(&mut self, _: Vec3, _: Vec3, _: f32, _: f32) {}
}

/// A carried particle's ride with instance `inst` from `x` at fraction `u` of the step to
/// `end` at its end, holding its point in the instance's frame, as chords of that path: each
/// off the path by at most a tenth of `diagonal` (world units), at most 256 of them.
fn trace_ride<T: PathTrace>(
    trace: &mut T,
    inst: &Instance,
    x: Vec3,
    u: f32,
    end: Vec3,
    diagonal: f32,
) {
    if !T::ON {
        return;
    }
    let local = inst.pose_at(u).to_local(x);
    // The turn left, and the largest distance of the point from the instance's origin.
    let turn = 2.0 * inst.half_turn * (1.0 - u);
    let r = local.length() * inst.start.scale.max(inst.end.scale);
    // A chord of angle `a` at radius `r` is off its arc by `r (1 - cos(a / 2)) <= r a² / 8`.
    let tol = 0.1 * diagonal;
    let a = if r > 0.0 {
        math::sqrt(8.0 * tol / r)
    } else {
        turn
    };
    let n = if a > 0.0 && turn > 0.0 {
        (turn / a).min(256.0) as u32 + 1
    } else {
        1
    };
    let mut from = x;
    for k in 1..=n {
        let uk = u + (1.0 - u) * k as f32 / n as f32;
        let to = if k == n {
            end
        } else {
            inst.pose_at(uk).to_world(local)
        };
        let uf = u + (1.0 - u) * (k - 1) as f32 / n as f32;
        trace.piece(from, to, uf, uk);
        from = to;
    }
}

impl<F: FnMut(Vec3, Vec3, f32, f32)> PathTrace for F {
    #[inline(always)]
    fn piece(&mut self, a: Vec3, b: Vec3, ua: f32, ub: f32) {
        self(a, b, ua, ub)
    }
}

/// A static instance's march traced into the world: its pose, the fraction of the step the
/// march starts at and how much of the step it spans, the step's length in seconds, and the
/// particle's speed (local units per second) and fraction of the step now, which each piece
/// advances by its length over the speed and each collision sets exactly.
#[derive(Clone, Copy)]
struct FrameTrace {
    pose: Pose,
    start: f32,
    span: f32,
    dt: f32,
    speed: f32,
    now: f32,
}

impl FrameTrace {
    fn new(pose: Pose, start: f32, end: f32, dt: f32, v: Vec3) -> Self {
        Self {
            pose,
            start,
            span: end - start,
            dt,
            speed: v.length(),
            now: start,
        }
    }
}

/// Receives every collision response of a particle's scene step as it happens, in the world
/// (the event buffer's input): pinches and shell blocks included, probes of instances that
/// were not the earliest hit left out. `()` receives nothing.
pub trait HitEvents {
    /// Whether anything is received: a step with no hit record to fill and an inactive
    /// sink takes the plain step's unobserved path.
    const ACTIVE: bool = true;
    /// One collision response.
    fn hit(&mut self, hit: &Hit);
}

impl HitEvents for () {
    const ACTIVE: bool = false;
    #[inline(always)]
    fn hit(&mut self, _: &Hit) {}
}

/// Where a march's collisions are in the world: in instance `c`'s frame over a chord from
/// fraction `ua` to `ub` of a step of `dt` seconds, `h` seconds long; at `pose` for a static
/// instance, else (`moving`) at the instance's pose at each collision's moment.
#[derive(Clone, Copy)]
struct HitFrame<'i> {
    c: u32,
    pose: Pose,
    moving: Option<&'i Instance>,
    ua: f32,
    ub: f32,
    h: f32,
    dt: f32,
}

impl<'i> HitFrame<'i> {
    /// A march over the whole step at a static `pose`.
    fn whole_step(c: u32, pose: Pose, dt: f32) -> Self {
        Self {
            c,
            pose,
            moving: None,
            ua: 0.0,
            ub: 1.0,
            h: dt,
            dt,
        }
    }

    /// The hit record of a collision at local `x` with local unit normal `n` and local
    /// velocity `before` just before it, with `remaining` seconds of the chord left.
    #[inline(always)]
    fn hit(&self, x: Vec3, n: Vec3, before: Vec3, remaining: f32) -> Hit {
        let u = min_of(self.ua + (self.h - remaining) / self.dt, self.ub);
        let pose = match self.moving {
            Some(inst) => inst.pose_at(u),
            None => self.pose,
        };
        Hit {
            instance: self.c as i32,
            position: pose.to_world(x).to_array(),
            normal: pose.normal_to_world(n).to_array(),
            t: u,
            speed: max_of(-before.dot(n) * pose.scale, 0.0),
        }
    }
}

/// The observer of a march in an instance's frame: the last collision in the world (`stop`:
/// the first, and the march stops there), every collision to `events` when the march is the
/// particle's path (`emit`; a probe's are not), and, for a static instance, the march's pieces
/// in the world (`frame`), less the jumps back that the shell rule and the leaf bound make
/// (not travelled).
struct HitObserver<'t, 'i, T: PathTrace, E: HitEvents> {
    stop: bool,
    emit: bool,
    count: u32,
    last: Hit,
    remaining: f32,
    leaf: u32,
    at: HitFrame<'i>,
    trace: &'t mut T,
    events: &'t mut E,
    frame: Option<FrameTrace>,
    jump_next: bool,
}

impl<'t, 'i, T: PathTrace, E: HitEvents> HitObserver<'t, 'i, T, E> {
    fn new(
        stop: bool,
        emit: bool,
        at: HitFrame<'i>,
        trace: &'t mut T,
        events: &'t mut E,
        frame: Option<FrameTrace>,
    ) -> Self {
        Self {
            stop,
            emit,
            count: 0,
            last: Hit::NONE,
            remaining: 0.0,
            leaf: NO_LEAF,
            at,
            trace,
            events,
            frame,
            jump_next: false,
        }
    }

    /// The hit record of the march: its last collision ([`Hit::NONE`] when it had none).
    fn record(&self) -> Hit {
        self.last
    }
}

impl<T: PathTrace, E: HitEvents> MarchObserver for HitObserver<'_, '_, T, E> {
    #[inline(always)]
    fn piece(&mut self, a: Vec3, b: Vec3) {
        if let Some(f) = self.frame.as_mut() {
            if core::mem::take(&mut self.jump_next) {
                return;
            }
            let seconds = if f.speed > 0.0 {
                (b - a).length() / f.speed
            } else {
                0.0
            };
            let then = (f.now + seconds / f.dt).min(f.start + f.span);
            self.trace
                .piece(f.pose.to_world(a), f.pose.to_world(b), f.now, then);
            f.now = then;
        }
    }
    #[inline(always)]
    fn branch(&mut self, b: crate::step::MarchBranch) {
        use crate::step::MarchBranch;
        if matches!(b, MarchBranch::ShellBlock | MarchBranch::LeafBoundInShell) {
            self.jump_next = true;
        }
    }
    #[inline(always)]
    fn hit(
        &mut self,
        x: Vec3,
        n: Vec3,
        before: Vec3,
        after: Vec3,
        remaining: f32,
        leaf: u32,
    ) -> bool {
        self.count += 1;
        self.last = self.at.hit(x, n, before, remaining);
        (self.remaining, self.leaf) = (remaining, leaf);
        if self.emit {
            self.events.hit(&self.last);
        }
        if let Some(f) = self.frame.as_mut() {
            // `remaining` is of the march's time, which spans `span` of the step.
            f.now = f.start + f.span - remaining / f.dt;
            f.speed = after.length();
        }
        self.stop
    }
}

/// Chords of a particle's path against a turning or scaling instance between fractions `u0`
/// and `u1` of the step, world velocity `v`: enough that the path in the instance's frame
/// stays within [`SUBSTEP_MARGIN`] finest leaves of them, up to [`MAX_SUBSTEPS`]; 1 for an
/// instance that only translates (the path in its frame is then straight).
///
/// The bound: in the frame, the path is `l(t) = R(t)ᵀ y(t) / s(t)` with `y = x − T` moving
/// by `Δy` (the relative displacement), the rotation turning by `θ` at a steady rate and the
/// scale changing by `Δs` linearly; a chord of a piece of length `h` strays from the curve by
/// at most `h² max|l''| / 8`, and over the whole interval cut into `n` pieces
/// `max|l''| h² ≤ [(2θ|Δy| + θ²|y|)/s + 2(θ|y| + |Δy|)Δs/s² + 2|y|Δs²/s³] / n²`, with `s` the
/// smaller scale and `|y| ≤ s_max r + |Δy|` (`r`: the root cube's farthest point from the
/// local origin; the path matters only where it is near the cube).
pub fn substeps(inst: &Instance, view: &ProxyView<'_>, v: Vec3, u0: f32, u1: f32, dt: f32) -> u32 {
    let f = u1 - u0;
    let theta = 2.0 * inst.half_turn * f;
    let sigma = math::abs(inst.end.scale - inst.start.scale) * f;
    if theta == 0.0 && sigma == 0.0 {
        return 1;
    }
    let d_t =
        (Vec3::from_array(inst.end.translation) - Vec3::from_array(inst.start.translation)) * f;
    let d = (v * (dt * f) - d_t).length();
    let s = min_of(inst.start.scale, inst.end.scale);
    let s_max = max_of(inst.start.scale, inst.end.scale);
    let y = s_max * local_radius(&view.root_aabb()) + d;
    let c = ((2.0 * theta * d + theta * theta * y) / s
        + 2.0 * (theta * y + d) * sigma / (s * s)
        + 2.0 * y * sigma * sigma / (s * s * s))
        * 0.125;
    let m = SUBSTEP_MARGIN * view.finest_leaf_size();
    let n = math::sqrt(c / m);
    if !(n < MAX_SUBSTEPS as f32) {
        return MAX_SUBSTEPS;
    }
    (math::floor(n) as u32 + 1).min(MAX_SUBSTEPS)
}

/// The last collision of a march in an instance's frame, in the world.
#[derive(Clone, Copy)]
struct FrameHit {
    /// Its hit record (the fraction of the step, the world position and unit normal, the
    /// normal speed before it relative to the collider).
    hit: Hit,
    /// The surface leaf it was in (its record), or [`NO_LEAF`] for a shell block.
    leaf: u32,
    blocked: bool,
}

/// How a march in an instance's frame goes on after a collision.
#[derive(Clone, Copy, PartialEq, Eq)]
enum AfterHit {
    /// It stops at the first collision (probing several instances for the earliest).
    Stop,
    /// Every collision of the chord is taken, and the chord marched to its end; the frame
    /// march ends there (one static instance alone within the particle's reach: its one
    /// chord is the rest of the step).
    FinishChord,
}

/// What a march in an instance's frame left: the side word and whether it must be kept;
/// after a collision, the particle in the world where the march stopped (fraction of the
/// step, position, velocity: the collider's surface velocity added back), the collisions and
/// the last of them; and how the march ended.
struct FrameMarch {
    side: u32,
    required: bool,
    moved: Option<(f32, Vec3, Vec3)>,
    collisions: u32,
    hit: Option<FrameHit>,
    outcome: StepOutcome,
}

/// The side a particle at world `x` at fraction `u` has for instance `c` with no kept side:
/// the label of the empty leaf it is in, the side of the mean plane in a surface leaf, front
/// outside the root cube ([`initial_side`]).
fn derived_side(inst: &Instance, view: &ProxyView<'_>, x: Vec3, u: f32) -> u32 {
    initial_side(view, inst.pose_at(u).to_local(x).to_array())
}

/// Marches a particle at world `x` with world velocity `v` (gravity integrated), side word
/// `side`, in instance `c`'s frame from fraction `u0` to `u1` of the step, until a collision
/// (`after` says how far past it). A static instance's frame is one transform; a moving one's
/// is cut into [`substeps`] chords, each marched from the particle's world point at its start
/// in the pose there to its world point at its end in the pose there. `collided`: the surface
/// leaf it has just collided in and not left (see `march_after`). A march that finishes its
/// chord is the particle's path, and tells `events` every collision; one that stops at its
/// first is a probe, and tells nothing (the rounds tell the collision they take).
#[allow(clippy::too_many_arguments)]
fn march_in_frame(
    c: u32,
    inst: &Instance,
    view: &ProxyView<'_>,
    x: Vec3,
    v: Vec3,
    u0: f32,
    u1: f32,
    mut side: u32,
    params: &StepParams,
    after: AfterHit,
    mut collided: u32,
    trace: &mut impl PathTrace,
    events: &mut impl HitEvents,
) -> FrameMarch {
    let dt = params.dt;
    let fixed = inst.is_static();
    let n = if fixed {
        1
    } else {
        substeps(inst, view, v, u0, u1, dt)
    };
    let mut required = false;
    let mut outcome = StepOutcome::Done;
    // The chord's ends as offsets from `u0`, never as `(u0 + f) - u0`: a GPU compiler may
    // fold that to `f` (Mesa's NIR does), and the backends must round alike.
    let span = u1 - u0;
    for k in 0..n {
        let fa = span * (k as f32 / n as f32);
        let last = k + 1 == n;
        let fb = if last {
            span
        } else {
            span * ((k + 1) as f32 / n as f32)
        };
        let ua = u0 + fa;
        let ub = if last { u1 } else { u0 + fb };
        let h = (fb - fa) * dt;
        if !(h > 0.0) {
            continue;
        }
        let (pa, pb) = (inst.pose_at(ua), inst.pose_at(ub));
        let la = pa.to_local(x + v * (fa * dt));
        let lv = plus_zero(if fixed {
            pa.vector_to_local(v)
        } else {
            (pb.to_local(x + v * (fb * dt)) - la) / h
        });
        let mut lp = Particle {
            position: la.to_array(),
            side,
            velocity: lv.to_array(),
            flags: 0,
        };
        // A static instance's pieces are the march's, through its pose; a moving one's are
        // traced by the rounds, straight in the world up to the collision it stops at.
        let frame = fixed.then(|| FrameTrace::new(pa, ua, ub, dt, lv));
        let at = HitFrame {
            c,
            pose: pa,
            moving: (!fixed).then_some(inst),
            ua,
            ub,
            h,
            dt,
        };
        let stop = after == AfterHit::Stop;
        let mut obs = HitObserver::new(stop, !stop, at, &mut *trace, &mut *events, frame);
        let mut hint = LeafHint::NONE;
        let local = StepParams {
            gravity: [0.0; 3],
            dt: h,
            ..*params
        };
        outcome = march_after(view, &mut lp, &local, &mut hint, &mut obs, collided);
        collided = NO_LEAF;
        side = lp.side;
        required = must_keep(view, &lp, hint);
        if outcome == StepOutcome::Invalid || outcome == StepOutcome::BoundHit {
            break;
        }
        if obs.count == 0 {
            continue;
        }
        // Where the march stopped: at the hit, or at the chord's end.
        let (u_end, p_end) = if stop {
            let u = min_of(ua + (h - obs.remaining) / dt, ub);
            (u, inst.pose_at(u))
        } else {
            (ub, pb)
        };
        let l_end = Vec3::from_array(lp.position);
        let hit = FrameHit {
            hit: obs.record(),
            leaf: obs.leaf,
            blocked: outcome == StepOutcome::Blocked,
        };
        // The collider's surface velocity at the end point over this chord, added back (none
        // for a static one: a sum with a zero a GPU compiler folds, see `plus_zero`).
        let velocity = p_end.vector_to_world(Vec3::from_array(lp.velocity));
        let v_end = if fixed {
            velocity
        } else {
            (pb.to_world(l_end) - pa.to_world(l_end)) / h + velocity
        };
        return FrameMarch {
            side,
            required: true,
            moved: Some((u_end, p_end.to_world(l_end), v_end)),
            collisions: obs.count,
            hit: Some(hit),
            outcome,
        };
    }
    FrameMarch {
        side,
        required,
        moved: None,
        collisions: 0,
        hit: None,
        outcome,
    }
}

/// Advances one particle by `params.dt` through a scene: gravity integrated in the world,
/// then marched against every instance its path can meet, in each instance's frame (see the
/// module documentation). `hint` and `slots` are the particle's [`SceneSides`] in their two
/// parts ([`SceneSides::split`]); `hit`, when asked for,
/// receives the step's last collision ([`Hit::NONE`] when it had none). Allocates nothing.
///
/// A particle near one static instance whose pose is the identity steps exactly as
/// [`crate::step_particle_hinted`] steps it against that proxy, bit for bit: a one-proxy static
/// scene is the plain step.
#[inline(always)]
pub fn step_particle_scene(
    scene: &SceneView<'_>,
    p: &mut Particle,
    hint: &mut SceneHint,
    slots: &mut SceneSlots,
    params: &StepParams,
    hit: Option<&mut Hit>,
    events: &mut impl HitEvents,
) -> StepOutcome {
    if let Some((c, view)) = scene.plain_proxy() {
        if hint.first_slot >> SLOT_INSTANCE_SHIFT == c && hint.hint_instance == c {
            return step_plain(view, c, p, hint, params, hit, events);
        }
    }
    let mut unused = Hit::NONE;
    let mut sides = SceneSides::join(hint, slots);
    let outcome = step_particle_scene_general(
        scene,
        p,
        &mut sides,
        params,
        hit.unwrap_or(&mut unused),
        &mut (),
        events,
    );
    (*hint, *slots) = sides.split();
    outcome
}

/// [`step_particle_scene`], telling `trace` every straight piece of the particle's world path
/// with the fractions of the step at its ends, for ground-truth checks of the path in each
/// instance's frame. Pieces within a static instance's march are the march's (less the jumps
/// back of the shell rule and the leaf bound, which the particle does not travel); a round
/// against moving instances is one piece, straight in the world up to its contact. The same
/// bits as [`step_particle_scene`].
pub fn step_particle_scene_traced(
    scene: &SceneView<'_>,
    p: &mut Particle,
    hint: &mut SceneHint,
    slots: &mut SceneSlots,
    params: &StepParams,
    hit: &mut Hit,
    trace: &mut impl FnMut(Vec3, Vec3, f32, f32),
) -> StepOutcome {
    let mut sides = SceneSides::join(hint, slots);
    let outcome = step_particle_scene_general(scene, p, &mut sides, params, hit, trace, &mut ());
    (*hint, *slots) = sides.split();
    outcome
}

/// A one-proxy static scene at the identity ([`SceneView::plain_proxy`]: instance `c` of
/// proxy `view`), for a particle whose first slot and hint are that instance's (the caller
/// checks: `hint.first_slot >> SLOT_INSTANCE_SHIFT == c && hint.hint_instance == c`; else
/// [`step_particle_scene`]): the plain step on the slot's side word, what the general path
/// does for it too, without its queries and copies. A backend calls it in its own loop with
/// the proxy hoisted out, as the plain step is called.
#[inline(always)]
pub fn step_plain<E: HitEvents>(
    view: &ProxyView<'_>,
    c: u32,
    p: &mut Particle,
    sides: &mut SceneHint,
    params: &StepParams,
    hit: Option<&mut Hit>,
    events: &mut E,
) -> StepOutcome {
    p.side = sides.first_slot & SLOT_SIDE_MASK;
    let outcome = match hit {
        None if !E::ACTIVE => step_particle_hinted(view, p, params, &mut sides.hint),
        hit => {
            let mut untraced = ();
            let at = HitFrame::whole_step(c, Pose::IDENTITY, params.dt);
            let mut obs = HitObserver::new(false, true, at, &mut untraced, events, None);
            let outcome = step_hinted_observed(view, p, params, &mut sides.hint, &mut obs);
            if let Some(hit) = hit {
                *hit = obs.record();
            }
            outcome
        }
    };
    if outcome == StepOutcome::Invalid {
        return outcome;
    }
    sides.first_slot = plain_first_slot(view, c, p, sides.hint);
    p.flags &= !(FLAG_CRUSHED | FLAG_SIDES_LOST);
    outcome
}

/// The first slot [`step_plain`] leaves for instance `c` after a step that was not invalid,
/// from the particle and the hint the step left: the instance, whether the side must be
/// kept ([`SLOT_REQUIRED`]) and the particle's side. A backend that steps such particles as
/// the plain step, with the side in the particle and an 8-byte hint, makes the slot with it
/// when the scene's form is asked for.
#[inline(always)]
pub fn plain_first_slot(view: &ProxyView<'_>, c: u32, p: &Particle, hint: LeafHint) -> u32 {
    let required = must_keep(view, p, hint);
    c << SLOT_INSTANCE_SHIFT | if required { SLOT_REQUIRED } else { 0 } | p.side
}

/// [`step_particle_scene`] for every particle and scene.
#[inline(never)]
fn step_particle_scene_general<T: PathTrace, E: HitEvents>(
    scene: &SceneView<'_>,
    p: &mut Particle,
    sides: &mut SceneSides,
    params: &StepParams,
    hit: &mut Hit,
    trace: &mut T,
    events: &mut E,
) -> StepOutcome {
    *hit = Hit::NONE;
    let x0 = Vec3::from_array(p.position);
    let v0 = Vec3::from_array(p.velocity);
    let dt = params.dt;
    let v = v0 + Vec3::from_array(params.gravity) * dt;
    let reach = wide_length(v) * dt;
    if !x0.is_finite() || !v0.is_finite() || !reach.is_finite() || !(dt > 0.0) {
        p.flags |= FLAG_INVALID;
        return StepOutcome::Invalid;
    }
    // Every point the particle can reach against static colliders (no response speeds it
    // up): the ball of radius `|v| dt` around its start.
    let pad = 4.0 * ulp(x0.abs().max_element() + reach) + PATH_PAD;
    let ball = Aabb {
        min: x0 - (reach + pad),
        max: x0 + (reach + pad),
    };
    let (count, first, near) = scene.count_nearby(&ball);
    let status_kept = p.flags & FLAG_STATUS_MASK & !FLAG_SCENE_STATUS;
    if count == 0 {
        // Nothing to meet: the straight path (the march's operations for a miss).
        trace.piece(x0, x0 + v * dt, 0.0, 1.0);
        p.position = (x0 + v * dt).to_array();
        p.velocity = v.to_array();
        p.side &= SIDE_MASK;
        p.flags = status_kept | p.flags & !FLAG_STATUS_MASK;
        sides.slots = optional(sides.slots);
        return StepOutcome::Done;
    }
    if count == 1 && scene.instances[first as usize].is_static() {
        return step_near_one_static(scene, first, p, sides, params, hit, trace, events);
    }
    step_in_rounds(scene, &near, p, sides, params, hit, trace, events)
}

/// [`step_particle_scene`] for a particle that can meet one static instance only: the whole
/// step in its frame, with every rule of the march and the hint.
#[allow(clippy::too_many_arguments)]
fn step_near_one_static<T: PathTrace, E: HitEvents>(
    scene: &SceneView<'_>,
    c: u32,
    p: &mut Particle,
    sides: &mut SceneSides,
    params: &StepParams,
    hit: &mut Hit,
    trace: &mut T,
    events: &mut E,
) -> StepOutcome {
    let inst = &scene.instances[c as usize];
    let view = &scene.proxies[inst.proxy as usize];
    let pose = inst.start;
    let identity = pose_words(&pose) == pose_words(&Pose::IDENTITY);
    let x0 = Vec3::from_array(p.position);
    let mut slots = optional(sides.slots);
    let side = match kept_side(inst, &slots, c) {
        Some(s) => s,
        None => initial_side(view, pose.to_local(x0).to_array()),
    };
    let mut hint = if sides.hint_instance == c {
        sides.hint
    } else {
        LeafHint::NONE
    };
    let mut lp = if identity {
        Particle { side, ..*p }
    } else {
        Particle {
            position: pose.to_local(x0).to_array(),
            side,
            velocity: pose
                .vector_to_local(Vec3::from_array(p.velocity))
                .to_array(),
            flags: p.flags,
        }
    };
    let local_params = if identity {
        *params
    } else {
        StepParams {
            gravity: pose
                .vector_to_local(Vec3::from_array(params.gravity))
                .to_array(),
            ..*params
        }
    };
    let v_start =
        Vec3::from_array(lp.velocity) + Vec3::from_array(local_params.gravity) * local_params.dt;
    let frame = FrameTrace::new(pose, 0.0, 1.0, params.dt, v_start);
    let at = HitFrame::whole_step(c, pose, params.dt);
    let mut obs = HitObserver::new(false, true, at, trace, events, Some(frame));
    let outcome = step_hinted_observed(view, &mut lp, &local_params, &mut hint, &mut obs);
    if outcome == StepOutcome::Invalid {
        p.flags |= FLAG_INVALID;
        return outcome;
    }
    let required = must_keep(view, &lp, hint);
    let kept = commit(&mut slots, c, lp.side, required);
    if identity {
        *p = lp;
    } else if obs.count == 0 && outcome == StepOutcome::Done {
        // No collision: the straight world path, not its round trip through the frame.
        let v = Vec3::from_array(p.velocity) + Vec3::from_array(params.gravity) * params.dt;
        p.position = (x0 + v * params.dt).to_array();
        p.velocity = v.to_array();
        p.flags = lp.flags;
    } else {
        p.position = pose.to_world(Vec3::from_array(lp.position)).to_array();
        p.velocity = pose
            .vector_to_world(Vec3::from_array(lp.velocity))
            .to_array();
        p.flags = lp.flags;
    }
    *hit = obs.record();
    sides.slots = slots;
    sides.hint = hint;
    sides.hint_instance = c;
    p.side = first_side(&slots, lp.side);
    p.flags &= !(FLAG_CRUSHED | FLAG_SIDES_LOST);
    if !kept {
        p.flags |= FLAG_SIDES_LOST;
    }
    outcome
}

/// Whether a particle's side for an instance must be kept after a march in its frame that
/// left it as `lp` (local) with `hint`: caged, or in the root cube and not known to be in an
/// empty leaf (whose label is its side).
fn must_keep(view: &ProxyView<'_>, lp: &Particle, hint: LeafHint) -> bool {
    if lp.side & SIDE_CAGE_MASK != 0 {
        return true;
    }
    // In an empty leaf (the common case): its label is the side.
    if hint != LeafHint::NONE && hint.z_depth_label & LeafHint::SURFACE == 0 {
        return false;
    }
    let root = view.root_aabb();
    let l = Vec3::from_array(lp.position);
    l.cmpge(root.min).all() && l.cmple(root.max).all()
}

/// Whether a particle at world `x` at fraction `u` of the step, riding with instance `c` for
/// the rest of the step (its local point held), meets no other instance's swept box. The ride
/// strays from the straight way to its end by at most the arc its point turns through and
/// what the change of scale moves it.
fn ride_is_clear(scene: &SceneView<'_>, near: &Nearby, c: u32, x: Vec3, u: f32) -> bool {
    let inst = &scene.instances[c as usize];
    let l = inst.pose_at(u).to_local(x);
    let end = inst.end.to_world(l);
    let r = l.length();
    let turn = chord_per_length(inst.start.rotation, inst.end.rotation);
    let stray = r * max_of(inst.start.scale, inst.end.scale) * turn
        + r * math::abs(inst.end.scale - inst.start.scale);
    let pad = 4.0 * ulp(x.abs().max(end.abs()).max_element()) + PATH_PAD + stray;
    let ride = Aabb {
        min: x.min(end) - pad,
        max: x.max(end) + pad,
    };
    let (count, first) = scene.count_in_nearby(near, &ride);
    count == 0 || (count == 1 && first == c)
}

/// The side word [`Particle::side`] shows after a scene step: the first slot's.
fn first_side(slots: &[u32; SIDE_SLOTS], otherwise: u32) -> u32 {
    match slots.iter().find(|&&s| s != EMPTY_SLOT) {
        Some(&s) => s & SLOT_SIDE_MASK,
        None => otherwise,
    }
}

/// [`step_particle_scene`] in rounds. A round takes the rest of the straight path: with one
/// instance to meet, the whole of it in that instance's frame, up to the end of the first
/// chord with a collision; with several, it probes each up to its first collision, takes the
/// earliest, and brings every other's side up to that moment. The next round goes on from
/// there with the new velocity.
#[allow(clippy::too_many_arguments)]
fn step_in_rounds<T: PathTrace, E: HitEvents>(
    scene: &SceneView<'_>,
    near: &Nearby,
    p: &mut Particle,
    sides: &mut SceneSides,
    params: &StepParams,
    hit: &mut Hit,
    trace: &mut T,
    events: &mut E,
) -> StepOutcome {
    let dt = params.dt;
    let mut x = Vec3::from_array(p.position);
    let mut v = Vec3::from_array(p.velocity) + Vec3::from_array(params.gravity) * dt;
    let mut u = 0.0f32;
    let mut slots = optional(sides.slots);
    let mut status = 0u32;
    let mut collisions = 0u32;
    let mut lost = false;
    // The instance and surface leaf of the last collision, which the next round starts in.
    let mut last: Option<(u32, u32)> = None;
    // The last collision between static instances, for the pinch rule across instances: its
    // point, normal, and whether it pinched.
    let mut last_static: Option<(Vec3, Vec3, bool)> = None;
    let side_for = |slots: &[u32; SIDE_SLOTS], c: u32, x: Vec3, u: f32| {
        let inst = &scene.instances[c as usize];
        kept_side(inst, slots, c)
            .unwrap_or_else(|| derived_side(inst, &scene.proxies[inst.proxy as usize], x, u))
    };
    let collided_in = |last: Option<(u32, u32)>, c: u32| match last {
        Some((i, leaf)) if i == c && scene.instances[c as usize].is_static() => leaf,
        _ => NO_LEAF,
    };
    // Rounds with several instances in reach (pressed between them past `MAX_ROUNDS`), every
    // round (a particle carried by one turning instance collides once a chord; past
    // `MAX_CONTACTS` the step ends as if the leaf bound were hit), and the rounds in a row
    // that took no time (past `MAX_STALLS`, the same).
    let (mut rounds, mut contacts, mut stalls) = (0u32, 0u32, 0u32);
    loop {
        if stalls == MAX_STALLS {
            stalls = 0;
            if let Some((c, _)) = last {
                if ride_is_clear(scene, near, c, x, u) {
                    contacts = MAX_CONTACTS;
                }
            }
        }
        if rounds == MAX_ROUNDS || contacts == MAX_CONTACTS {
            // At its last contact, moving with what it touched: carried, or crushed where
            // another instance is on the way.
            let carried = rounds < MAX_ROUNDS
                && last.is_none_or(|(c, _)| ride_is_clear(scene, near, c, x, u));
            status |= if carried {
                FLAG_BOUND_HIT
            } else {
                FLAG_CRUSHED
            };
            if let Some((c, _)) = last {
                let inst = &scene.instances[c as usize];
                let end = inst.end.to_world(inst.pose_at(u).to_local(x));
                let rest = (1.0 - u) * dt;
                v = if rest > 0.0 {
                    (end - x) / rest
                } else {
                    Vec3::ZERO
                };
                let view = &scene.proxies[inst.proxy as usize];
                let diagonal =
                    1.732_050_8 * view.finest_leaf_size() * inst.start.scale.min(inst.end.scale);
                trace_ride(trace, inst, x, u, end, diagonal);
                x = end;
            }
            break;
        }
        contacts += 1;
        let rest = (1.0 - u) * dt;
        let end = x + v * rest;
        let pad = 4.0 * ulp(x.abs().max(end.abs()).max_element()) + PATH_PAD;
        // Against static colliders a particle stays within `|v| rest` of where it is (no
        // response speeds it up): with one static instance there, the whole rest of the step
        // is marched in its frame.
        let reach = wide_length(v) * rest + pad;
        let ball = Aabb {
            min: x - reach,
            max: x + reach,
        };
        let (in_reach, mut only) = scene.count_in_nearby(near, &ball);
        let one_static = in_reach == 1 && scene.instances[only as usize].is_static();
        let seg = Aabb {
            min: x.min(end) - pad,
            max: x.max(end) + pad,
        };
        let mut count = 0u32;
        if !one_static {
            (count, only) = scene.count_in_nearby(near, &seg);
        }
        if in_reach == 0 || (!one_static && count == 0) {
            trace.piece(x, end, u, 1.0);
            x = end;
            break;
        }
        if count > 1 {
            rounds += 1;
        }
        // The round's outcome: how far it went, and the collision it ended with.
        let mut moved: Option<(f32, Vec3, Vec3)> = None;
        let mut round_hit: Option<(u32, FrameHit, u32)> = None;
        let mut bound = false;
        let mut invalid = false;
        if one_static || count == 1 {
            // One instance: its march is the round (to the end of the step for a static one
            // alone in reach, else to its first collision, where the next round looks again).
            let c = only;
            let inst = &scene.instances[c as usize];
            let view = &scene.proxies[inst.proxy as usize];
            let side = side_for(&slots, c, x, u);
            let after = if one_static {
                AfterHit::FinishChord
            } else {
                AfterHit::Stop
            };
            // A static instance's march traces its own pieces; a moving one's path is straight
            // in the world up to where it stops.
            let fixed = inst.is_static();
            let collided = collided_in(last, c);
            let m = if fixed {
                march_in_frame(
                    c,
                    inst,
                    view,
                    x,
                    v,
                    u,
                    1.0,
                    side,
                    params,
                    after,
                    collided,
                    &mut *trace,
                    &mut *events,
                )
            } else {
                march_in_frame(
                    c,
                    inst,
                    view,
                    x,
                    v,
                    u,
                    1.0,
                    side,
                    params,
                    after,
                    collided,
                    &mut (),
                    &mut *events,
                )
            };
            if !fixed && m.outcome != StepOutcome::BoundHit {
                let (ue, xe) = m.moved.map_or((1.0, end), |(ue, xe, _)| (ue, xe));
                trace.piece(x, xe, u, ue);
            }
            invalid = m.outcome == StepOutcome::Invalid;
            bound = m.outcome == StepOutcome::BoundHit;
            lost |= !commit(&mut slots, c, m.side, m.required);
            moved = m.moved;
            if let Some(h) = m.hit {
                round_hit = Some((c, h, m.collisions));
            }
        } else {
            // The earliest first collision, ties to the first in the broad phase's order.
            let mut best: Option<(f32, u32)> = None;
            scene.for_each_nearby(near, &seg, |c| {
                let inst = &scene.instances[c as usize];
                let view = &scene.proxies[inst.proxy as usize];
                let side = side_for(&slots, c, x, u);
                let m = march_in_frame(
                    c,
                    inst,
                    view,
                    x,
                    v,
                    u,
                    1.0,
                    side,
                    params,
                    AfterHit::Stop,
                    collided_in(last, c),
                    &mut (),
                    &mut (),
                );
                invalid |= m.outcome == StepOutcome::Invalid;
                if let Some(h) = m.hit {
                    if best.is_none_or(|(bu, _)| h.hit.t < bu) {
                        best = Some((h.hit.t, c));
                    }
                }
            });
            let until = best.map_or(1.0, |(bu, _)| bu);
            scene.for_each_nearby(near, &seg, |c| {
                let inst = &scene.instances[c as usize];
                let view = &scene.proxies[inst.proxy as usize];
                let side = side_for(&slots, c, x, u);
                let is_best = best.is_some_and(|(_, b)| b == c);
                let to = if is_best { 1.0 } else { until };
                let collided = collided_in(last, c);
                // The path is the best instance's march: its pieces when it is static.
                let m = if is_best && inst.is_static() {
                    march_in_frame(
                        c,
                        inst,
                        view,
                        x,
                        v,
                        u,
                        to,
                        side,
                        params,
                        AfterHit::Stop,
                        collided,
                        &mut *trace,
                        &mut (),
                    )
                } else {
                    march_in_frame(
                        c,
                        inst,
                        view,
                        x,
                        v,
                        u,
                        to,
                        side,
                        params,
                        AfterHit::Stop,
                        collided,
                        &mut (),
                        &mut (),
                    )
                };
                invalid |= m.outcome == StepOutcome::Invalid;
                bound |= m.outcome == StepOutcome::BoundHit;
                if is_best {
                    moved = m.moved;
                    if let Some(h) = m.hit {
                        round_hit = Some((c, h, m.collisions));
                    }
                }
                lost |= !commit(&mut slots, c, m.side, m.required);
            });
            match best {
                None => trace.piece(x, end, u, 1.0),
                Some((_, b)) if !scene.instances[b as usize].is_static() && !bound => {
                    if let Some((ue, xe, _)) = moved {
                        trace.piece(x, xe, u, ue);
                    }
                }
                _ => {}
            }
        }
        if invalid {
            p.flags |= FLAG_INVALID;
            return StepOutcome::Invalid;
        }
        if bound {
            // A march hit its leaf bound: the particle stays where this round started, a
            // safe point (the step's start or a contact).
            status |= FLAG_BOUND_HIT;
            v = Vec3::ZERO;
            break;
        }
        match (moved, round_hit) {
            (Some((u_end, x_end, v_end)), Some((c, h, n))) => {
                collisions += n;
                if h.blocked {
                    status |= FLAG_BLOCKED;
                }
                *hit = h.hit;
                // A march that finished its chord told every collision; a probe told none.
                if !one_static {
                    events.hit(&h.hit);
                }
                stalls = if u_end == u { stalls + 1 } else { 0 };
                x = x_end;
                v = v_end;
                u = u_end;
                last = Some((c, h.leaf));
                // The pinch rule across static instances (a crease where two parts meet):
                // a collision next to the last one whose response still points into the last
                // surface keeps only the velocity along both; pinched again, it stops.
                if scene.instances[c as usize].is_static() && !h.blocked {
                    let inst = &scene.instances[c as usize];
                    let view = &scene.proxies[inst.proxy as usize];
                    let reach = view.finest_leaf_size() * inst.start.scale * 2.0;
                    let (hx, hn) = (
                        Vec3::from_array(h.hit.position),
                        Vec3::from_array(h.hit.normal),
                    );
                    let mut pinched = false;
                    if let Some((px, pn, was)) = last_static {
                        if (hx - px).length() <= reach && v.dot(pn) < 0.0 {
                            v = if was { Vec3::ZERO } else { pinch(v, hn, pn) };
                            pinched = true;
                        }
                    }
                    last_static = Some((hx, hn, pinched));
                } else {
                    last_static = None;
                }
                if !(u < 1.0) {
                    break;
                }
            }
            _ => {
                x = end;
                break;
            }
        }
    }
    if !x.is_finite() || !v.is_finite() {
        p.flags |= FLAG_INVALID;
        return StepOutcome::Invalid;
    }
    p.position = x.to_array();
    p.velocity = v.to_array();
    p.side = first_side(&slots, p.side & SIDE_MASK);
    if lost {
        status |= FLAG_SIDES_LOST;
    }
    let count = (p.collisions() + collisions).min(MAX_COLLISIONS);
    p.flags = (p.flags & FLAG_STATUS_MASK & !FLAG_SCENE_STATUS) | status | count << COLLISION_SHIFT;
    sides.slots = slots;
    sides.hint = LeafHint::NONE;
    sides.hint_instance = NO_INSTANCE;
    if status & FLAG_CRUSHED != 0 {
        StepOutcome::BoundHit
    } else if status & FLAG_BLOCKED != 0 {
        StepOutcome::Blocked
    } else {
        StepOutcome::Done
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ride_is_traced_as_chords_of_its_arc() {
        // An instance 2 units out turning 170 degrees about y in one step (and moving, and
        // growing): a point carried from a third of the step keeps its place in the frame.
        // The pieces join up, end where the ride ends, and every end and midpoint is within
        // a tenth of the diagonal of the point the frame carries; one straight piece from
        // `x` to `end` would pass 2 units from it.
        let turn = 170f32.to_radians();
        let start = Pose {
            translation: [2.0, 0.0, 0.0],
            scale: 1.0,
            rotation: [0.0, 0.0, 0.0, 1.0],
        };
        let end = Pose {
            translation: [2.5, 0.3, 0.0],
            scale: 1.2,
            rotation: [0.0, (turn / 2.0).sin(), 0.0, (turn / 2.0).cos()],
        };
        let inst = Instance::new(0, start, end);
        let u = 1.0 / 3.0;
        let local = Vec3::new(0.0, 0.5, 1.5);
        let x = inst.pose_at(u).to_world(local);
        let ride_end = inst.end.to_world(local);
        let diagonal = 0.05;
        let mut pieces: std::vec::Vec<(Vec3, Vec3, f32, f32)> = std::vec::Vec::new();
        let mut trace = |a, b, ua, ub| pieces.push((a, b, ua, ub));
        trace_ride(&mut trace, &inst, x, u, ride_end, diagonal);
        assert!(pieces.len() > 10, "{} pieces", pieces.len());
        assert_eq!(pieces[0].0, x);
        assert_eq!(pieces[0].2, u);
        assert_eq!(pieces.last().unwrap().1, ride_end);
        assert_eq!(pieces.last().unwrap().3, 1.0);
        for w in pieces.windows(2) {
            assert_eq!((w[0].1, w[0].3), (w[1].0, w[1].2));
        }
        for &(a, b, ua, ub) in &pieces {
            for (point, t) in [(a, ua), (b, ub), ((a + b) * 0.5, (ua + ub) * 0.5)] {
                let off = inst.pose_at(t).to_world(local).distance(point);
                assert!(off <= 0.1 * diagonal * 1.2 + 1e-5, "{off} off at {t}");
            }
        }
        // Nothing is made for a trace that wants nothing.
        trace_ride(&mut (), &inst, x, u, ride_end, diagonal);
    }

    /// A broad phase over `items` (instance, swept box) in depth-first order, split at the
    /// median of the boxes' centres along `x`, `y`, `z` in turn.
    fn build(items: &mut [(u32, Aabb)], axis: usize, nodes: &mut std::vec::Vec<BroadNode>) {
        let (min, max) = items.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), (_, b)| (lo.min(b.min), hi.max(b.max)),
        );
        let i = nodes.len();
        let (index, kind) = if items.len() == 1 {
            (items[0].0, BROAD_LEAF)
        } else {
            (0, BROAD_INTERNAL)
        };
        nodes.push(BroadNode {
            min: min.to_array(),
            index,
            max: max.to_array(),
            kind,
        });
        if items.len() == 1 {
            return;
        }
        items.sort_by(|a, b| {
            let (ca, cb) = (a.1.min + a.1.max, b.1.min + b.1.max);
            ca[axis].total_cmp(&cb[axis])
        });
        let (first, second) = items.split_at_mut(items.len() / 2);
        build(first, (axis + 1) % 3, nodes);
        nodes[i].index = nodes.len() as u32;
        build(second, (axis + 1) % 3, nodes);
    }

    /// A uniform value in `[0, 1)` from the tests' xorshift generator.
    fn unit(s: &mut u64) -> f32 {
        (crate::tests::xorshift(s) >> 40) as f32 / (1u64 << 24) as f32
    }

    /// A broad phase over `instances` (all of `view`'s proxy), each told its leaf.
    fn broad_phase(instances: &mut [Instance], view: &ProxyView<'_>) -> std::vec::Vec<BroadNode> {
        let mut items: std::vec::Vec<(u32, Aabb)> = instances
            .iter()
            .enumerate()
            .map(|(k, inst)| (k as u32, inst.swept_box(view)))
            .collect();
        let mut nodes = std::vec::Vec::new();
        build(&mut items, 0, &mut nodes);
        for (k, node) in nodes.iter().enumerate() {
            if node.kind == BROAD_LEAF {
                instances[node.index as usize].leaf = k as u32;
            }
        }
        nodes
    }

    fn random_box(s: &mut u64, lo: Vec3, hi: Vec3, most: f32) -> Aabb {
        let mut r = || unit(s);
        let a = Vec3::new(r(), r(), r());
        let e = Vec3::new(r(), r(), r()) * most;
        let min = lo + a * (hi - lo);
        Aabb {
            min,
            max: (min + e).min(hi),
        }
    }

    /// A moving instance's swept box holds every point of its local box at every pose of
    /// the step (`pose_at`), whatever it does: turns from none to half a turn, scales up or
    /// down, translates, with local boxes off the origin. With no turn it is the box swept
    /// by translation and scale alone, not the ball about the centre.
    #[test]
    fn a_moving_instances_swept_box_holds_it_at_every_pose() {
        let mut s = 0x2545_f491_4f6c_dd1du64;
        let mut r = move || unit(&mut s);
        let mut tight = 0;
        for case in 0..4000 {
            let direction = |r: &mut dyn FnMut() -> f32| {
                let v = Vec3::new(r() - 0.5, r() - 0.5, r() - 0.5);
                if v.length() < 1e-3 {
                    Vec3::X
                } else {
                    v.normalize()
                }
            };
            let axis = direction(&mut r);
            let a = r() * core::f32::consts::TAU;
            let q0 = glam::Quat::from_axis_angle(axis, a).to_array();
            // No turn in a quarter of the cases; else up to half a turn, mostly small.
            let turn = if case % 4 == 0 {
                0.0
            } else {
                core::f32::consts::PI * r() * r() * r()
            };
            let q1 = if turn == 0.0 {
                q0
            } else {
                let d = glam::Quat::from_axis_angle(direction(&mut r), turn);
                (d * glam::Quat::from_array(q0)).normalize().to_array()
            };
            let t0 = Vec3::new(r(), r(), r()) * 100.0 - 50.0;
            let t1 = t0 + (Vec3::new(r(), r(), r()) - 0.5) * 4.0 * r();
            let s0 = 0.2 + 2.8 * r();
            let s1 = if case % 3 == 0 { s0 } else { 0.2 + 2.8 * r() };
            let lo = Vec3::new(r(), r(), r()) * 6.0 - 3.0;
            let local = Aabb {
                min: lo,
                max: lo + Vec3::new(0.1, 0.1, 0.1) + Vec3::new(r(), r(), r()) * 4.0,
            };
            let pose = |t: Vec3, sc: f32, q: [f32; 4]| Pose {
                translation: t.to_array(),
                scale: sc,
                rotation: q,
            };
            let inst = Instance::new(0, pose(t0, s0, q0), pose(t1, s1, q1));
            if inst.is_static() {
                continue;
            }
            let b = inst.swept_box_of(&local);
            for k in 0..64 {
                let u = match k {
                    0 => 0.0,
                    1 => 1.0,
                    _ => r(),
                };
                let p = inst.pose_at(u);
                for c in 0..12u32 {
                    let f = if c < 8 {
                        Vec3::new((c & 1) as f32, ((c >> 1) & 1) as f32, ((c >> 2) & 1) as f32)
                    } else {
                        Vec3::new(r(), r(), r())
                    };
                    let l = local.min + f * (local.max - local.min);
                    let w = p.to_world(l);
                    assert!(
                        w.cmpge(b.min).all() && w.cmple(b.max).all(),
                        "case {case}: {w} at u = {u} outside {b:?}"
                    );
                }
            }
            if turn == 0.0 {
                // The box of the local box's corners at both ends, and rounding's pad.
                let mut lo = Vec3::splat(f32::INFINITY);
                let mut hi = Vec3::splat(f32::NEG_INFINITY);
                for c in 0..8u32 {
                    let f = Vec3::new((c & 1) as f32, ((c >> 1) & 1) as f32, ((c >> 2) & 1) as f32);
                    let l = local.min + f * (local.max - local.min);
                    for p in [inst.start, inst.end] {
                        lo = lo.min(p.to_world(l));
                        hi = hi.max(p.to_world(l));
                    }
                }
                // The bound's bend: for a rotation equal at both ends, a few ulps.
                let far = [local.min, local.max]
                    .iter()
                    .map(|v| v.abs())
                    .fold(Vec3::ZERO, Vec3::max)
                    .length();
                let bend = s0.max(s1) * far * chord_per_length(q0, q1);
                let slack = (b.max - b.min) - (hi - lo);
                assert!(
                    slack.max_element() <= 2.0 * bend + 1e-3,
                    "case {case}: {slack}"
                );
                tight += 1;
            }
        }
        assert!(tight > 900, "{tight}");
    }

    /// A grid over the broad phase gives the step's first query the walk's answer in the
    /// walk's order, for boxes of every size (inside one cell, across cells, outside the
    /// grid), and a grid not sized as `grid_sizes` says is not used.
    #[test]
    fn the_grid_answers_as_the_walk_does() {
        let w = crate::tests::tiny();
        let views = [ProxyView::new(&w).unwrap()];
        let mut s = 0x5851_f42d_4c95_7f2du64;
        let mut instances = std::vec::Vec::new();
        for k in 0..80 {
            let at = random_box(&mut s, Vec3::ZERO, Vec3::splat(8.0), 0.0).min;
            let start = Pose {
                translation: at.to_array(),
                ..Pose::IDENTITY
            };
            // Every other one moving: their boxes are larger.
            let end = Pose {
                translation: (at + Vec3::new(0.3, -0.2, 0.1) * (k % 2) as f32).to_array(),
                ..start
            };
            instances.push(Instance::new(0, start, end));
        }
        let nodes = broad_phase(&mut instances, &views[0]);
        let plain = SceneView::new(&views, &instances, &nodes).unwrap();
        let (n_starts, n_entries) = plain.grid_sizes().unwrap();
        let (mut starts, mut entries) = (vec![0u32; n_starts], vec![0u32; n_entries]);
        let grid = plain.with_grid(&mut starts, &mut entries);
        let mut wrong = vec![0u32; n_starts + 1];
        let mut entries2 = vec![0u32; n_entries];
        assert!(plain.with_grid(&mut wrong, &mut entries2).grid.is_none());
        let g = grid.grid.unwrap();
        let (mut from_cells, mut found, mut walked) = (0, 0, 0);
        for k in 0..20000 {
            let most = [0.05, 0.3, 1.5, 6.0][k % 4];
            let b = random_box(&mut s, Vec3::splat(-1.0), Vec3::splat(10.0), most);
            let (count, first, near) = grid.count_nearby(&b);
            let (count0, first0, near0) = plain.count_nearby(&b);
            assert_eq!((count, first), (count0, first0), "{b:?}");
            let kept = count.min(NEARBY as u32) as usize;
            assert_eq!(near.leaves[..kept], near0.leaves[..kept], "{b:?}");
            if g.cell_holding(&b).is_some() {
                from_cells += 1;
                found += (count > 0) as u32;
            } else {
                walked += 1;
            }
        }
        // Answers from a cell (some finding instances) and walks both came up.
        assert!(from_cells > 4000, "{from_cells}");
        assert!(found > 500, "{found}");
        assert!(walked > 4000, "{walked}");
    }

    /// What a step's later queries take from [`Nearby`] is the walk's answer, in the walk's
    /// order: for boxes inside the first query's box (the kept leaves filtered), outside it,
    /// and after more than [`NEARBY`] leaves met the first (both walk).
    #[test]
    fn nearby_answers_as_the_walk_does() {
        let w = crate::tests::tiny();
        let views = [ProxyView::new(&w).unwrap()];
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut instances = std::vec::Vec::new();
        for _ in 0..60 {
            let at = random_box(&mut s, Vec3::ZERO, Vec3::splat(12.0), 0.0).min;
            let pose = Pose {
                translation: at.to_array(),
                ..Pose::IDENTITY
            };
            instances.push(Instance::new(0, pose, pose));
        }
        let nodes = broad_phase(&mut instances, &views[0]);
        let scene = SceneView::new(&views, &instances, &nodes).unwrap();
        let (mut filtered, mut overflowed, mut outside) = (0, 0, 0);
        for _ in 0..3000 {
            let within = random_box(&mut s, Vec3::splat(-1.0), Vec3::splat(14.0), 8.0);
            let (count, first, near) = scene.count_nearby(&within);
            assert_eq!((count, first), scene.count_candidates(&within));
            for k in 0..8 {
                // Half inside the first box, half anywhere.
                let b = if k % 2 == 0 {
                    random_box(&mut s, within.min, within.max, 2.0)
                } else {
                    random_box(&mut s, Vec3::splat(-1.0), Vec3::splat(14.0), 3.0)
                };
                let mut walked = std::vec::Vec::new();
                scene.for_each_candidate(&b, |c| walked.push(c));
                let mut kept = std::vec::Vec::new();
                scene.for_each_nearby(&near, &b, |c| kept.push(c));
                assert_eq!(kept, walked);
                let expected = (walked.len() as u32, walked.first().copied().unwrap_or(0));
                assert_eq!(scene.count_in_nearby(&near, &b), expected);
                if near.holds(&b) {
                    filtered += !walked.is_empty() as u32;
                } else if count as usize > NEARBY {
                    overflowed += 1;
                } else {
                    outside += 1;
                }
            }
        }
        // Every case came up: answers filtered from the kept leaves (some not empty), and
        // walks after an overflow and for boxes outside.
        assert!(filtered > 300, "{filtered}");
        assert!(overflowed > 300, "{overflowed}");
        assert!(outside > 5000, "{outside}");
    }
}
