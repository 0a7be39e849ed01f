//! The step: one particle marched leaf by leaf along `x(t) → x(t + dt)`.
//!
//! Each leaf on the way is handled as the paper's section 4 says, plus one rule that makes
//! the surface shell hold where the averaged normals cannot (sharp features, thin walls):
//!
//! - an empty leaf with a label stamps the particle's side;
//! - a surface leaf collides when the velocity opposes its normal (flipped for back-side
//!   particles; a two-sided leaf is solid and uses the face the particle enters through), responding at the
//!   entry point with restitution and Coulomb friction, and the march goes on with the new
//!   velocity and the time left;
//! - **shell rule:** a particle that went into the shell of surface leaves from its own side
//!   may come out only into an empty leaf of that side. Coming out into a leaf labelled with
//!   the other side means it crossed the surface; it is put back where it entered the shell,
//!   its velocity reflected off the face it tried to cross, and the step ends;
//! - **pinch rule:** a collision at the very point of the previous one whose response still
//!   points into the previous surface (facing surfaces across a narrow gap, a sharp crease)
//!   keeps only the velocity along both surfaces ([`pinch`]); a second such collision at that
//!   point stops the particle there. Without it the particle reflected off each surface in
//!   turn, halving its speed across them each time, until the leaf bound stopped the step.
//!
//! The number of leaves a step visits is bounded by [`max_leaves_per_step`]; when the bound
//! is hit the particle is left at its last safe point.
//!
//! Most steps start and end inside one empty leaf. [`step_particle_hinted`] takes the leaf a
//! particle's last step ended in ([`LeafHint`]) and, while the particle is strictly inside it,
//! starts there instead of descending the tree; a step that also ends strictly inside it is
//! settled before the march is set up. The backends keep a hint beside every particle.

use bytemuck::{Pod, Zeroable};
use glam::{UVec3, Vec3, Vec3A};

use crate::format::{Label, MAX_DEPTH};
use crate::math;
use crate::particle::*;
use crate::query::{Aabb, LeafInfo, LeafKind};
use crate::view::ProxyView;

/// Bound on the leaves one step visits in a tree of depth `tree_depth`: a straight path
/// crosses at most `3 * 2^depth` cells of a `2^depth` grid, and an octree has no more cells
/// on a line than its finest grid. The rest is room for collisions and re-entries.
pub const fn max_leaves_per_step(tree_depth: u32) -> u32 {
    (4u32 << tree_depth) + 64
}

/// [`max_leaves_per_step`] at [`MAX_DEPTH`]: the largest bound any proxy can have.
pub const MAX_LEAVES_PER_STEP: u32 = max_leaves_per_step(MAX_DEPTH);

/// Parameters of one step, shared by every backend (a GPU uniform, hence `Pod`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct StepParams {
    /// Acceleration, units per second squared.
    pub gravity: [f32; 3],
    /// Time step, seconds.
    pub dt: f32,
    /// Fraction of normal speed kept by a collision, in `[0, 1]`.
    pub restitution: f32,
    /// Coulomb friction coefficient, `>= 0`.
    pub friction: f32,
    /// Padding to 32 bytes; must be zero.
    pub _pad: [u32; 2],
}

const _: () = assert!(core::mem::size_of::<StepParams>() == 32);

/// Why step parameters were rejected.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum ParamError {
    /// `dt` is NaN, infinite, zero or negative.
    BadDt(f32),
    /// A gravity component is NaN or infinite.
    BadGravity,
    /// Restitution is outside `[0, 1]`.
    BadRestitution(f32),
    /// Friction is negative, NaN or infinite.
    BadFriction(f32),
}

impl core::fmt::Display for ParamError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            ParamError::BadDt(dt) => write!(
                f,
                "dt must be a positive finite number of seconds, got {dt}"
            ),
            ParamError::BadGravity => write!(f, "gravity must be three finite numbers"),
            ParamError::BadRestitution(r) => write!(f, "restitution must be in [0, 1], got {r}"),
            ParamError::BadFriction(m) => {
                write!(f, "friction must be a finite number >= 0, got {m}")
            }
        }
    }
}

impl core::error::Error for ParamError {}

impl Default for StepParams {
    fn default() -> Self {
        Self {
            gravity: [0.0, -9.81, 0.0],
            dt: 1.0 / 60.0,
            restitution: 0.5,
            friction: 0.1,
            _pad: [0; 2],
        }
    }
}

impl StepParams {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), ParamError> {
        if !(self.dt > 0.0) || !self.dt.is_finite() {
            return Err(ParamError::BadDt(self.dt));
        }
        if !Vec3::from_array(self.gravity).is_finite() {
            return Err(ParamError::BadGravity);
        }
        if !(0.0..=1.0).contains(&self.restitution) {
            return Err(ParamError::BadRestitution(self.restitution));
        }
        if !(self.friction >= 0.0) || !self.friction.is_finite() {
            return Err(ParamError::BadFriction(self.friction));
        }
        Ok(())
    }
}

/// How a step ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StepOutcome {
    /// The particle used its whole time step.
    Done,
    /// The particle tried to leave the shell on the other side and was put back.
    Blocked,
    /// The leaf bound was hit; the particle was left at its last safe point.
    BoundHit,
    /// Position or velocity was not finite (on input, or after integrating); unchanged.
    Invalid,
}

/// The collision response: the normal part of `v` is reversed and scaled by `restitution`,
/// the tangential part loses up to `friction` times the normal impulse. `n` is unit length.
#[inline]
pub fn respond(v: Vec3, n: Vec3, restitution: f32, friction: f32) -> Vec3 {
    let vn = v.dot(n);
    if vn >= 0.0 {
        return v;
    }
    let v_n = n * vn;
    let v_t = v - v_n;
    let t_len = math::sqrt(v_t.dot(v_t));
    let impulse = friction * (1.0 + restitution) * -vn;
    let keep = if t_len > impulse {
        1.0 - impulse / t_len
    } else {
        0.0
    };
    v_t * keep - v_n * restitution
}

/// Below this squared length of `n × m`, [`pinch`] takes two unit normals as parallel (the
/// surfaces face each other or lie in one plane): about 0.06 degrees.
pub const PINCH_PARALLEL: f32 = 1e-6;

/// The velocity of a particle pinched between two surfaces with unit normals `n` and `m`: a
/// second collision at the very point of the last one whose response still points into the
/// last surface (a thin gap between facing surfaces, a sharp crease). Reflecting off each in
/// turn would only halve the velocity across them, some 300 times over, until the leaf bound
/// stopped the step; instead the velocity keeps only its part along both surfaces: along the
/// crease where they meet, or in their common plane when they face each other.
#[inline]
pub fn pinch(v: Vec3, n: Vec3, m: Vec3) -> Vec3 {
    // `n × m`, written out so that WGSL's mirror does the same operations.
    let c = Vec3::new(
        n.y * m.z - m.y * n.z,
        n.z * m.x - m.z * n.x,
        n.x * m.y - m.x * n.y,
    );
    let cc = c.dot(c);
    if cc > PINCH_PARALLEL {
        c * (v.dot(c) / cc)
    } else {
        v - n * v.dot(n)
    }
}

/// Unit normal of the face(s) in `axes` that a particle moving with signs `signs` crossed,
/// pointing back where it came from.
#[inline]
fn face_normal(axes: u32, signs: Vec3) -> Vec3 {
    let mut n = Vec3::ZERO;
    for a in 0..3 {
        if axes & (1 << a) != 0 {
            n[a] = if signs[a] >= 0.0 { -1.0 } else { 1.0 };
        }
    }
    let l2 = n.dot(n);
    if l2 > 0.0 {
        n * (1.0 / math::sqrt(l2))
    } else {
        n
    }
}

/// The faces of `b` that `x` lies on while `v` points into `b`: the faces a particle there
/// enters through. Empty when `x` is strictly inside.
#[inline]
fn entry_faces(b: &Aabb, x: Vec3, v: Vec3) -> u32 {
    let (bmin, bmax, xa, va) = (
        b.min.to_array(),
        b.max.to_array(),
        x.to_array(),
        v.to_array(),
    );
    let mut axes = 0;
    for a in 0..3 {
        if (xa[a] == bmin[a] && va[a] > 0.0) || (xa[a] == bmax[a] && va[a] < 0.0) {
            axes |= 1 << a;
        }
    }
    axes
}

/// Time and point at which a ray from `x` (inside `b`) with velocity `v` leaves `b`, and the
/// axes whose face it leaves through. The exit point lies exactly on those faces.
#[inline]
fn exit_box(b: &Aabb, x: Vec3, v: Vec3) -> (f32, Vec3, u32) {
    // Selects, not branches: the signs of a velocity are coin tosses for the branch
    // predictor. Per axis this is `(bmax - x) / v` for `v > 0`, `(bmin - x) / v` for `v < 0`
    // and infinity for `v == 0`, clamped below at 0, exactly as written out with `if`s.
    let (bmin, bmax, xa, va) = (
        b.min.to_array(),
        b.max.to_array(),
        x.to_array(),
        v.to_array(),
    );
    let mut ts = [f32::INFINITY; 3];
    let mut far = [0.0f32; 3];
    for a in 0..3 {
        far[a] = if va[a] > 0.0 { bmax[a] } else { bmin[a] };
        let ta = (far[a] - xa[a]) / va[a];
        let ta = if ta > 0.0 { ta } else { 0.0 };
        ts[a] = if va[a] == 0.0 { f32::INFINITY } else { ta };
    }
    let mut t = f32::INFINITY;
    for &ta in &ts {
        t = if ta < t { ta } else { t };
    }
    let finite = t.is_finite();
    let mut axes = 0;
    let mut p = xa;
    for a in 0..3 {
        let on_face = (ts[a] == t) & finite;
        axes |= (on_face as u32) << a;
        let along = (xa[a] + va[a] * t).clamp(bmin[a], bmax[a]);
        p[a] = if on_face { far[a] } else { along };
    }
    (t, Vec3::from_array(p), axes)
}

/// Time and point at which a ray from `x` (outside `b`) with velocity `v` enters `b` within
/// `limit`, and the axes whose faces it enters through; `None` if it does not.
#[inline]
fn enter_box(b: &Aabb, x: Vec3, v: Vec3, limit: f32) -> Option<(f32, Vec3, u32)> {
    let mut near = f32::NEG_INFINITY;
    let mut far = f32::INFINITY;
    let mut axes = 0;
    for a in 0..3 {
        if v[a] == 0.0 {
            // Half-open on the upper side, as the tie rule of point location.
            if !(x[a] >= b.min[a] && x[a] < b.max[a]) {
                return None;
            }
            continue;
        }
        let t1 = (b.min[a] - x[a]) / v[a];
        let t2 = (b.max[a] - x[a]) / v[a];
        let (lo, hi) = if v[a] > 0.0 { (t1, t2) } else { (t2, t1) };
        if lo > near {
            near = lo;
            axes = 1 << a;
        } else if lo == near {
            axes |= 1 << a;
        }
        if hi < far {
            far = hi;
        }
    }
    if !(near >= 0.0 && near <= far && far > 0.0 && near < limit) {
        return None;
    }
    let mut p = x;
    for a in 0..3 {
        if axes & (1 << a) != 0 {
            p[a] = if v[a] > 0.0 { b.min[a] } else { b.max[a] };
        } else {
            p[a] = (x[a] + v[a] * near).clamp(b.min[a], b.max[a]);
        }
    }
    Some((near, p, axes))
}

#[inline]
fn side_of(label: Label) -> u32 {
    if label == Label::Back {
        SIDE_BACK
    } else {
        SIDE_FRONT
    }
}

const NO_LEAF: u32 = u32::MAX;

/// The empty leaf a particle ended its last step in, kept by a backend beside the particle so
/// that the next step can start there instead of descending the tree. Two words, zero when
/// there is none ([`LeafHint::NONE`], also `LeafHint::default()`).
///
/// A hint only saves work: a step uses it only when the particle lies strictly inside the
/// hinted leaf's box, where the descent would find that very leaf, so a step gives the same
/// bits with or without it. A hint belongs to the proxy that made it: reset hints to
/// [`LeafHint::NONE`] whenever the proxy changes (moving or reordering particles needs no
/// reset; the box check catches it).
///
/// Give a step only [`LeafHint::NONE`] or a hint a step left with the same proxy. A hint made
/// up by hand is checked for shape (depth, cell range, label) and for holding the particle,
/// never against the tree: one that names a cell which is not an empty leaf is memory-safe,
/// but the step believes it, and may miss the surface there.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct LeafHint {
    /// `cell.x | cell.y << 16`.
    pub xy: u32,
    /// `cell.z | depth << DEPTH_SHIFT | label bits << LABEL_SHIFT | VALID`.
    pub z_depth_label: u32,
}

const _: () = assert!(core::mem::size_of::<LeafHint>() == 8);

impl LeafHint {
    /// No hint: the step descends from the lookup table (or the root).
    pub const NONE: LeafHint = LeafHint {
        xy: 0,
        z_depth_label: 0,
    };
    /// Set in `z_depth_label` when the hint holds a leaf.
    pub const VALID: u32 = 1 << 31;
    /// Mask of one cell coordinate (a leaf is at most [`MAX_DEPTH`] = 16 deep).
    pub const CELL_MASK: u32 = 0xffff;
    /// Shift of the cell's `y` in `xy`.
    pub const Y_SHIFT: u32 = 16;
    /// Shift of the 5-bit depth in `z_depth_label`.
    pub const DEPTH_SHIFT: u32 = 16;
    /// Shift of the 2 label bits in `z_depth_label`.
    pub const LABEL_SHIFT: u32 = 21;
    /// Mask of the depth, after shifting.
    pub const DEPTH_MASK: u32 = 0x1f;

    /// The hint for `leaf`: its cell, depth and label if it is empty; none for a surface leaf.
    fn of(leaf: &LeafInfo) -> LeafHint {
        if leaf.kind != LeafKind::Empty {
            return LeafHint::NONE;
        }
        LeafHint {
            xy: leaf.cell.x | leaf.cell.y << Self::Y_SHIFT,
            z_depth_label: leaf.cell.z
                | leaf.depth << Self::DEPTH_SHIFT
                | leaf.label.bits() << Self::LABEL_SHIFT
                | Self::VALID,
        }
    }

    /// The hinted leaf, if the hint is well formed and `x` lies strictly inside its box.
    #[inline]
    fn leaf(self, view: &ProxyView<'_>, x: Vec3) -> Option<LeafInfo> {
        let w = self.z_depth_label;
        let depth = (w >> Self::DEPTH_SHIFT) & Self::DEPTH_MASK;
        // Depth 0 would be the root, which is never a leaf.
        if w & Self::VALID == 0 || depth == 0 || depth > MAX_DEPTH {
            return None;
        }
        let cell = UVec3::new(
            self.xy & Self::CELL_MASK,
            self.xy >> Self::Y_SHIFT,
            w & Self::CELL_MASK,
        );
        if (cell.x | cell.y | cell.z) >> depth != 0 {
            return None;
        }
        let label = Label::from_bits((w >> Self::LABEL_SHIFT) & 3)?;
        let leaf = view.empty_leaf(cell, depth, NO_LEAF, label);
        if !(x.cmpgt(leaf.aabb.min).all() && x.cmplt(leaf.aabb.max).all()) {
            return None;
        }
        Some(leaf)
    }
}

/// Advances one particle by `params.dt`: integrates gravity (semi-implicit Euler), then
/// marches the path through the proxy, colliding as the module documentation says.
/// Allocates nothing; visits at most `view.max_leaves_per_step()` leaves.
#[inline]
pub fn step_particle(view: &ProxyView<'_>, p: &mut Particle, params: &StepParams) -> StepOutcome {
    march(view, p, params, &mut LeafHint::default(), &mut |_, _| {})
}

/// [`step_particle`], starting from the leaf in `hint` when the particle is still strictly
/// inside it, and leaving in `hint` the empty leaf the step ended in (or [`LeafHint::NONE`]).
/// With [`LeafHint::NONE`] or a hint this function left with the same proxy, the result is
/// [`step_particle`]'s, bit for bit; only the work differs (see [`LeafHint`]).
#[inline(always)]
pub fn step_particle_hinted(
    view: &ProxyView<'_>,
    p: &mut Particle,
    params: &StepParams,
    hint: &mut LeafHint,
) -> StepOutcome {
    if settle_in_hinted_leaf(view, p, params, *hint) {
        return StepOutcome::Done;
    }
    // A particle outside the root has no hint; one moving away from the root stays outside.
    if *hint == LeafHint::NONE && settle_leaving_root(view, p, params) {
        return StepOutcome::Done;
    }
    march_from_hint(view, p, params, hint)
}

/// The other common case of [`step_particle_hinted`]: a particle outside the root cube, beyond
/// one of its faces and not moving back toward it (particles that fly off a scene keep going).
/// The segment stays in the half-space beyond that face, so the march would find that it
/// never enters the root and move the particle to the end point; this does the same in the
/// same operations. `true` when settled; the hint stays [`LeafHint::NONE`].
#[inline(always)]
fn settle_leaving_root(view: &ProxyView<'_>, p: &mut Particle, params: &StepParams) -> bool {
    let x0 = Vec3::from_array(p.position);
    let v = Vec3::from_array(p.velocity) + Vec3::from_array(params.gravity) * params.dt;
    let end = x0 + v * params.dt;
    let root = view.root_aabb();
    let zero = Vec3::ZERO;
    // Strictly beyond a face, so that the tie rule of `root_contains` cannot put it inside.
    let leaving = (x0.cmplt(root.min) & v.cmple(zero)) | (x0.cmpgt(root.max) & v.cmpge(zero));
    // A finite `v` means a finite starting velocity too; a non-finite end would be
    // `Invalid` in the march; `dt > 0` is the march's loop condition.
    let settled =
        leaving.any() & x0.is_finite() & v.is_finite() & end.is_finite() & (params.dt > 0.0);
    if !settled {
        return false;
    }
    p.position = end.to_array();
    p.velocity = v.to_array();
    p.side = (p.side == SIDE_BACK) as u32;
    p.flags &= !FLAG_STEP_STATUS;
    true
}

/// The common case of [`step_particle_hinted`], settled before the march is set up: the
/// particle stays strictly inside its hinted empty leaf for the whole step. It does what the
/// march does for such a particle, in the same operations (the integration, the leaf's box,
/// the end-point test, the label, the flags), with one branch where the march has many: the
/// label and the checks are folded into values, not tested one by one. `true` when settled;
/// the hint is then still the particle's.
#[inline(always)]
fn settle_in_hinted_leaf(
    view: &ProxyView<'_>,
    p: &mut Particle,
    params: &StepParams,
    hint: LeafHint,
) -> bool {
    let w = hint.z_depth_label;
    let depth = (w >> LeafHint::DEPTH_SHIFT) & LeafHint::DEPTH_MASK;
    let label_bits = (w >> LeafHint::LABEL_SHIFT) & 3;
    let cell = UVec3::new(
        hint.xy & LeafHint::CELL_MASK,
        hint.xy >> LeafHint::Y_SHIFT,
        w & LeafHint::CELL_MASK,
    );
    // `LeafHint::leaf`'s shape checks; `depth - 1 < MAX_DEPTH` is `1 <= depth <= MAX_DEPTH`.
    let shape_ok = (w & LeafHint::VALID != 0)
        & (depth.wrapping_sub(1) < MAX_DEPTH)
        & ((cell.x | cell.y | cell.z) >> depth == 0)
        & (label_bits != 3);
    if !shape_ok {
        return false;
    }
    // SIMD vectors: lane for lane the march's scalar operations, so the same floats.
    let (bmin, bmax) = view.cell_box(cell, depth);
    let x0 = Vec3A::from_array(p.position);
    let v = Vec3A::from_array(p.velocity) + Vec3A::from_array(params.gravity) * params.dt;
    let end = x0 + v * params.dt;
    // A start strictly inside the box is finite; a finite `v` with `dt > 0` (the march's loop
    // condition: unvalidated parameters take the march) and an end strictly inside is the
    // march's first leaf ending the step.
    let settled = (x0.cmpgt(bmin) & x0.cmplt(bmax) & end.cmpgt(bmin) & end.cmplt(bmax)).all()
        & v.is_finite()
        & (params.dt > 0.0);
    if !settled {
        return false;
    }
    p.position = end.to_array();
    p.velocity = v.to_array();
    // An unlabelled leaf keeps the side (normalised as the march does); a labelled one stamps
    // it: label bits 1 (front) and 2 (back) are sides 0 and 1.
    const _: () =
        assert!(SIDE_FRONT == Label::Front.bits() - 1 && SIDE_BACK == Label::Back.bits() - 1);
    let kept = (p.side == SIDE_BACK) as u32;
    p.side = if label_bits == 0 {
        kept
    } else {
        label_bits - 1
    };
    p.flags &= !FLAG_STEP_STATUS;
    true
}

/// The march of [`step_particle_hinted`], out of line: the settled case above is the hot
/// loop's, and stays small without it.
#[inline(never)]
fn march_from_hint(
    view: &ProxyView<'_>,
    p: &mut Particle,
    params: &StepParams,
    hint: &mut LeafHint,
) -> StepOutcome {
    march(view, p, params, hint, &mut |_, _| {})
}

/// [`step_particle`], calling `trace(from, to)` for every straight piece of the particle's
/// path in order, and last, when the shell rule or the leaf bound stops the step inside the
/// shell, the jump back to the shell entry: a piece that ends where an earlier one began. The
/// particle is put there and does not travel it (after a long slide along a curved wall its
/// chord may cut through the mesh); it is traced so that crossings counted along the pieces
/// still add up to the side the particle ends on.
/// Ground-truth checks use it to test the real path against the mesh.
pub fn step_particle_traced<F: FnMut(Vec3, Vec3)>(
    view: &ProxyView<'_>,
    p: &mut Particle,
    params: &StepParams,
    trace: &mut F,
) -> StepOutcome {
    march(view, p, params, &mut LeafHint::default(), trace)
}

/// The leaf a step that starts at `x` (with velocity `v`, on side `side`) starts in, given the
/// leaf point location found, `leaf`. A step that starts on a face between a surface leaf and
/// an empty leaf labelled with the other side starts in the surface leaf, so that the shell
/// rule decides whether it may come out there. Point location alone would put it in the
/// empty leaf whenever its velocity does not point into the surface leaf, and stamp the other
/// side with no crossing to stop: a particle can sit on such a face after a step that moved it
/// along the face while its velocity pointed into the shell (far from the origin a slow
/// velocity component does not move a coordinate at all), and turn its velocity there.
/// Found by a campaign on scenes at 2e5 from the origin; elsewhere it takes a step ending
/// exactly on a cell plane. Solid (two-sided) leaves too: a particle pinched to a stop on the
/// corner of one, inside the shell and past the surface, would otherwise start its next step
/// in the empty leaf beyond, labelled with the side it had crossed to, and be stamped with it
/// (found by a campaign on the teapot scaled by 1e-3, where gravity moves a particle half the
/// scene per step). Such a start is not "sliding along the solid leaf's face": the march does
/// not move it out of the leaf again.
#[inline]
fn start_beside_shell(
    view: &ProxyView<'_>,
    leaf: LeafInfo,
    x: Vec3,
    v: Vec3,
    side: u32,
) -> LeafInfo {
    if leaf.kind != LeafKind::Empty || leaf.label == Label::None || side_of(leaf.label) == side {
        return leaf;
    }
    for a in 0..3 {
        let below = x[a] == leaf.aabb.min[a];
        if !below && x[a] != leaf.aabb.max[a] {
            continue;
        }
        let mut dir = v;
        dir[a] = if below { -1.0 } else { 1.0 };
        if view.root_contains(x, dir) {
            let across = view.locate_inside(x, dir);
            if across.kind == LeafKind::Surface {
                return across;
            }
        }
    }
    leaf
}

/// The step itself, for every public entry point above.
#[inline(always)]
fn march<F: FnMut(Vec3, Vec3)>(
    view: &ProxyView<'_>,
    p: &mut Particle,
    params: &StepParams,
    hint: &mut LeafHint,
    trace: &mut F,
) -> StepOutcome {
    let start_hint = core::mem::take(hint);
    let x0 = Vec3::from_array(p.position);
    let v0 = Vec3::from_array(p.velocity);
    if !x0.is_finite() || !v0.is_finite() {
        p.flags |= FLAG_INVALID;
        return StepOutcome::Invalid;
    }
    let (e, mu) = (params.restitution, params.friction);
    let mut v = v0 + Vec3::from_array(params.gravity) * params.dt;
    let mut x = x0;
    let mut side = if p.side == SIDE_BACK {
        SIDE_BACK
    } else {
        SIDE_FRONT
    };
    let mut hinted = start_hint.leaf(view, x0);
    let mut remaining = params.dt;
    let mut collisions = 0u32;
    let mut in_shell = false;
    let mut shell_entry = x0;
    let mut last_collided = NO_LEAF;
    // Where the last collision was (when `collisions > 0`) and the normal it used, and
    // whether it pinched (`pinch`).
    let (mut hit_x, mut hit_n, mut pinched) = (x0, Vec3::ZERO, false);
    // The face the particle last crossed (axes) and the signs of its velocity then.
    let mut cross_axes = 0u32;
    let mut cross_signs = Vec3::ZERO;
    // The leaf the particle was last in, while it is on that leaf's closed box.
    let mut last_leaf: Option<LeafInfo> = None;
    let mut outcome = StepOutcome::Done;
    let budget = view.max_leaves_per_step();
    let mut visited = 0u32;
    while remaining > 0.0 {
        if visited >= budget {
            outcome = StepOutcome::BoundHit;
            if in_shell {
                trace(x, shell_entry);
                x = shell_entry;
            }
            break;
        }
        visited += 1;
        // Whether this leaf is the shell beside the point the step starts on.
        let mut beside_shell = false;
        // Only the first leaf of a step can come from the hint: the particle has not moved yet.
        // After it, the particle is on the closed box of the leaf it was last in, and the next
        // leaf is found from that leaf's cell.
        let mut leaf = if let Some(leaf) = hinted.take() {
            leaf
        } else if let Some(leaf) = last_leaf
            .as_ref()
            .and_then(|from| view.locate_next(from, x, v))
        {
            leaf
        } else {
            if !view.root_contains(x, v) {
                match enter_box(&view.root_aabb(), x, v, remaining) {
                    Some((t, entry, axes)) => {
                        trace(x, entry);
                        x = entry;
                        remaining -= t;
                        cross_axes = axes;
                        cross_signs = v;
                        last_collided = NO_LEAF;
                        last_leaf = None;
                        continue;
                    }
                    None => {
                        let end = x + v * remaining;
                        trace(x, end);
                        x = end;
                        break;
                    }
                }
            }
            let leaf = view.locate_inside(x, v);
            if visited == 1 {
                let start = start_beside_shell(view, leaf, x, v, side);
                beside_shell = start.kind != leaf.kind;
                start
            } else {
                leaf
            }
        };
        if leaf.two_sided && !beside_shell && entry_faces(&leaf.aabb, x, v) == 0 {
            // A particle sliding along a face of a solid leaf (no velocity across it), and not
            // entering through another, is not in the leaf: locate it on the face's outer side.
            let mut dir = v;
            for a in 0..3 {
                if v[a] == 0.0 && x[a] == leaf.aabb.min[a] {
                    dir[a] = -1.0;
                } else if v[a] == 0.0 && x[a] == leaf.aabb.max[a] {
                    dir[a] = 1.0;
                }
            }
            if dir != v {
                leaf = view.locate_inside(x, dir);
            }
        }
        last_leaf = Some(leaf);
        match leaf.kind {
            LeafKind::Empty => {
                // Selects, not a branch on the label: labelled or not is a coin toss for the
                // branch predictor; coming out of the shell on the other side is rare.
                let labelled = leaf.label != Label::None;
                let label_side = side_of(leaf.label);
                if (labelled as u32 & in_shell as u32 & (label_side != side) as u32) != 0 {
                    trace(x, shell_entry);
                    x = shell_entry;
                    v = respond(v, face_normal(cross_axes, cross_signs), e, mu);
                    collisions += 1;
                    outcome = StepOutcome::Blocked;
                    break;
                }
                side = if labelled { label_side } else { side };
                in_shell = false;
            }
            LeafKind::Surface => {
                if !in_shell {
                    in_shell = true;
                    shell_entry = x;
                }
                if leaf.node != last_collided {
                    let n = if leaf.two_sided {
                        // Solid from every side: the faces it is entering through, found from
                        // the box, so a particle resting on one at the start of a step counts.
                        face_normal(entry_faces(&leaf.aabb, x, v), v)
                    } else if side == SIDE_BACK {
                        -leaf.normal
                    } else {
                        leaf.normal
                    };
                    if v.dot(n) < 0.0 {
                        v = respond(v, n, e, mu);
                        if collisions > 0 && x == hit_x && v.dot(hit_n) < 0.0 {
                            // Pinched; pinched again at the same point (rounding left the
                            // velocity a hair into a surface), it stops there.
                            v = if pinched {
                                Vec3::ZERO
                            } else {
                                pinch(v, n, hit_n)
                            };
                            pinched = true;
                        } else {
                            pinched = false;
                        }
                        (hit_x, hit_n) = (x, n);
                        collisions += 1;
                        last_collided = leaf.node;
                        continue;
                    }
                }
            }
        }
        // Most steps end in the leaf they start in: an end point strictly inside the box
        // settles it without the exit time (the segment stays in the convex box).
        let end = x + v * remaining;
        // One test of a mask, not six short-circuit branches.
        if (end.cmpgt(leaf.aabb.min) & end.cmplt(leaf.aabb.max)).bitmask() == 0b111 {
            trace(x, end);
            x = end;
            *hint = LeafHint::of(&leaf);
            break;
        }
        let (t_exit, exit, axes) = exit_box(&leaf.aabb, x, v);
        if t_exit >= remaining {
            let end = (x + v * remaining).clamp(leaf.aabb.min, leaf.aabb.max);
            trace(x, end);
            x = end;
            *hint = LeafHint::of(&leaf);
            break;
        }
        trace(x, exit);
        x = exit;
        remaining -= t_exit;
        cross_axes = axes;
        cross_signs = v;
        last_collided = NO_LEAF;
    }
    if !x.is_finite() || !v.is_finite() {
        p.flags |= FLAG_INVALID;
        return StepOutcome::Invalid;
    }
    p.position = x.to_array();
    p.velocity = v.to_array();
    p.side = side;
    let count = (p.collisions() + collisions).min(MAX_COLLISIONS);
    let mut status = p.flags & FLAG_STATUS_MASK & !FLAG_STEP_STATUS;
    match outcome {
        StepOutcome::Blocked => status |= FLAG_BLOCKED,
        StepOutcome::BoundHit => status |= FLAG_BOUND_HIT,
        _ => {}
    }
    p.flags = status | count << COLLISION_SHIFT;
    outcome
}

/// Initial side of a particle that has none: in an empty leaf, the leaf's label (front when
/// unlabelled); in a surface leaf, the side of the surface's mean plane it is on.
pub fn initial_side(view: &ProxyView<'_>, position: [f32; 3]) -> u32 {
    let p = Vec3::from_array(position);
    match view.locate_leaf(p) {
        Some(leaf) if leaf.kind == LeafKind::Surface => {
            let center = (leaf.aabb.min + leaf.aabb.max) * 0.5;
            if leaf.normal.dot(p - center) >= leaf.plane_offset {
                SIDE_FRONT
            } else {
                SIDE_BACK
            }
        }
        Some(leaf) => side_of(leaf.label),
        None => SIDE_FRONT,
    }
}
