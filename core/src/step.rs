//! The step: one particle marched leaf by leaf along `x(t) → x(t + dt)`.
//!
//! Each leaf on the way is handled as the paper's section 4 says, plus one rule that makes
//! the surface shell hold where the averaged normals cannot (sharp features, thin walls):
//!
//! - an empty leaf with a label stamps the particle's side;
//! - a surface leaf collides when the velocity opposes its normal (flipped for back-side
//!   particles; a two-sided leaf is solid and uses the face the particle enters through),
//!   with restitution and Coulomb friction, and the march goes on with the new velocity and
//!   the time left. A one-sided leaf collides where the path meets its stored plane
//!   (`reach_plane`: contact where the surface is, within about a leaf of it), a solid leaf at
//!   the entry point, or, entered through one face with clearance, at the inner side of the
//!   slab by that face, which holds no triangle (**slabs**: `slab_entry`, `walk_in_slab`,
//!   [`SIDE_SLAB`]);
//! - **shell rule:** a particle that went into the shell of surface leaves from its own side
//!   may come out only into an empty leaf of that side. Coming out into a leaf labelled with
//!   the other side means it crossed the surface; it is put back where it entered the shell,
//!   its velocity reflected off the face it tried to cross, and goes on from there with the
//!   time left, as after a collision; blocked a second time in a step, it stays there and the
//!   step ends (a particle that ended its step at every block stood still while its velocity
//!   slid along the wall: two grains wedged in a corner never parted);
//! - **pinch rule:** a collision at the very point of the previous one, or against a surface
//!   facing the previous one within a leaf's diagonal of it, whose response still points into
//!   the previous surface (facing surfaces across a narrow gap, a sharp crease)
//!   keeps only the velocity along both surfaces ([`pinch`]); a second such collision at that
//!   point stops the particle there. Without it the particle reflected off each surface in
//!   turn, halving its speed across them each time, until the leaf bound stopped the step.
//!
//! - **cages:** a particle that starts strictly inside a solid leaf, caged there by the host
//!   from the mesh ([`SIDE_CAGED`]), moves freely in it and leaves it only through its exit
//!   faces; the others are walls (`walk_in_cage`). One side bit cannot say which of the
//!   surfaces in a solid leaf a particle is behind; the host can, and says where it may go.
//!
//! The number of leaves a step visits is bounded by [`max_leaves_per_step`]; when the bound
//! is hit the particle is left at its last safe point.
//!
//! Most steps start and end inside one empty leaf. [`step_particle_hinted`] takes the leaf a
//! particle's last step ended in ([`LeafHint`]) and, while the particle is strictly inside it,
//! starts there instead of descending the tree; a step that also ends strictly inside an empty one is
//! settled before the march is set up (`settle_in_hinted_leaf`; `settle_leaving_root` for
//! particles flying away outside the root). The backends keep a hint beside every particle.
//!
//! The march (`march`, out of line) keeps its loop state in one `MarchState`, and each turn
//! of its loop is a sentence of steps: find the next leaf (`find_next_leaf`; outside the
//! root, `enter_root`), step off a solid leaf's face it slides along
//! (`slide_off_solid_face`), then, in an empty leaf, stamp its side or be blocked by the shell
//! rule (`enter_empty_leaf`, `block_at_shell`), in a surface leaf, collide (`enter_surface_leaf`,
//! `collision_normal`, `reach_plane`, `collide`), and last end the step in the leaf or cross to its exit
//! (`travel_through_leaf`); `stop_at_leaf_bound` and `finish_march` close it. WGSL's
//! `step.wgsl` has each of these functions under the same name, taking
//! `ptr<function, MarchState>`. The march reports to an observer, which is nothing for the
//! step itself, the path's pieces for [`step_particle_traced`], and the rare branches
//! ([`MarchBranch`]) for [`step_particle_counted`], which the differential tests use to show
//! that their scenes reach them.

use bytemuck::{Pod, Zeroable};
use glam::{UVec3, Vec3, Vec3A};

use crate::format::{Label, CLEARANCE_STEPS, MAX_DEPTH};
use crate::math;
use crate::particle::*;
use crate::query::{Aabb, LeafInfo, LeafKind, NO_LEAF};
use crate::view::ProxyView;

/// Leaves a step may visit per cell along an axis of its tree's finest grid, in
/// [`max_leaves_per_step`]: a straight path crosses at most `3 * 2^depth` cells of a
/// `2^depth` grid, and an octree has no more cells on a line than its finest grid.
pub const LEAF_BOUND_PER_CELL: u32 = 4;

/// Leaves a step may visit beyond [`LEAF_BOUND_PER_CELL`]'s, in [`max_leaves_per_step`].
pub const LEAF_BOUND_EXTRA: u32 = 64;

/// Bound on the leaves one step visits in a tree of depth `tree_depth`: `3 * 2^depth` for a
/// straight crossing (see [`LEAF_BOUND_PER_CELL`]); the rest is room for collisions and
/// re-entries. WGSL's twin reads both constants, generated from these.
pub const fn max_leaves_per_step(tree_depth: u32) -> u32 {
    (LEAF_BOUND_PER_CELL << tree_depth) + LEAF_BOUND_EXTRA
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
    /// The particles' radius, `>= 0` and finite: `0` for points. A proxy is baked for one
    /// radius (its header's `RADIUS`; `bake --radius`), and backends refuse to step
    /// particles of another radius against it. The step itself does not read it: the
    /// proxy's surface is already the offset surface at this distance from the mesh.
    pub radius: f32,
    /// Padding to 32 bytes; must be zero.
    pub _pad: u32,
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
    /// The radius is negative, NaN or infinite.
    BadRadius(f32),
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
            ParamError::BadRadius(r) => {
                write!(f, "radius must be a finite number >= 0, got {r}")
            }
        }
    }
}

impl core::error::Error for ParamError {}

/// Particles of one radius stepped against a proxy baked for another
/// ([`check_radius`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RadiusMismatch {
    /// The radius the proxy was baked for (times the instance's scale, in a scene).
    pub baked: f32,
    /// The particles' radius ([`StepParams::radius`]).
    pub radius: f32,
}

impl core::fmt::Display for RadiusMismatch {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "the particles' radius is {} but the proxy was baked for radius {}: bake it with that radius (bake --radius), or step with the radius it was baked for",
            self.radius, self.baked
        )
    }
}

impl core::error::Error for RadiusMismatch {}

/// Relative tolerance of [`check_radius`]: a scale applied to a proxy's radius in `f32`.
pub const RADIUS_TOLERANCE: f32 = 1e-5;

/// Whether particles of `radius` may step against a proxy baked for `baked`: both zero, or
/// equal within a relative [`RADIUS_TOLERANCE`].
pub fn check_radius(baked: f32, radius: f32) -> Result<(), RadiusMismatch> {
    let diff = if baked > radius {
        baked - radius
    } else {
        radius - baked
    };
    let big = if baked > radius { baked } else { radius };
    if diff <= big * RADIUS_TOLERANCE {
        Ok(())
    } else {
        Err(RadiusMismatch { baked, radius })
    }
}

impl Default for StepParams {
    fn default() -> Self {
        Self {
            gravity: [0.0, -9.81, 0.0],
            dt: 1.0 / 60.0,
            restitution: 0.5,
            friction: 0.1,
            radius: 0.0,
            _pad: 0,
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
        if !(self.radius >= 0.0) || !self.radius.is_finite() {
            return Err(ParamError::BadRadius(self.radius));
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
#[inline(always)]
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

/// `f32::clamp` for a box's bounds (`lo <= hi`), without its assertion: the step does not
/// panic, and a panic path kept the march from inlining it. The same value: `lo` below it,
/// `hi` above it, `x` otherwise (NaN included).
#[inline(always)]
fn clamp(x: f32, lo: f32, hi: f32) -> f32 {
    let x = if x < lo { lo } else { x };
    if x > hi {
        hi
    } else {
        x
    }
}

/// Where a ray crosses a box's boundary: after time `t`, at `point` (exactly on the faces of
/// the axes in `axes`, clamped into the box on the others). WGSL's `BoxCrossing` is this
/// struct, and its `BoxCrossingOption` is [`enter_box`]'s `Option`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct BoxCrossing {
    t: f32,
    point: Vec3,
    axes: u32,
}

/// Where a ray from `x` (inside `b`) with velocity `v` leaves `b`, and the axes whose face it
/// leaves through. The exit point lies exactly on those faces.
#[inline(always)]
fn exit_box(b: &Aabb, x: Vec3, v: Vec3) -> BoxCrossing {
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
        let along = clamp(xa[a] + va[a] * t, bmin[a], bmax[a]);
        p[a] = if on_face { far[a] } else { along };
    }
    BoxCrossing {
        t,
        point: Vec3::from_array(p),
        axes,
    }
}

/// Where a ray from `x` (outside `b`) with velocity `v` enters `b` within `limit`, and the
/// axes whose faces it enters through; `None` if it does not.
#[inline(always)]
fn enter_box(b: &Aabb, x: Vec3, v: Vec3, limit: f32) -> Option<BoxCrossing> {
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
            p[a] = clamp(x[a] + v[a] * near, b.min[a], b.max[a]);
        }
    }
    Some(BoxCrossing {
        t: near,
        point: p,
        axes,
    })
}

#[inline]
fn side_of(label: Label) -> u32 {
    if label == Label::Back {
        SIDE_BACK
    } else {
        SIDE_FRONT
    }
}

/// The leaf a particle ended its last step in, kept by a backend beside the particle so that
/// the next step can start there instead of descending the tree: an empty leaf, or a
/// one-sided surface leaf (where particles rest, on its plane). Two words, zero when there is
/// none ([`LeafHint::NONE`], also `LeafHint::default()`).
///
/// - **Empty leaf:** `xy = cell.x | cell.y << 16`, `z_depth_label = cell.z | depth << 16 |
///   label bits << 21 | VALID`; bits 23–30 zero.
/// - **One-sided surface leaf** no deeper than [`LeafHint::MAX_SURFACE_DEPTH`] (10):
///   `xy = record index | depth << 27`, `z_depth_label = cell.x | cell.y << 10 | cell.z << 20 |
///   SURFACE | VALID`. Deeper surface leaves and solid ones get no hint.
///
/// A hint only saves work: a step uses it only when the particle lies strictly inside the
/// hinted leaf's box, where the descent would find that very leaf, so a step gives the same
/// bits with or without it. A hint belongs to the proxy that made it: reset hints to
/// [`LeafHint::NONE`] whenever the proxy changes (moving or reordering particles needs no
/// reset; the box check catches it).
///
/// Give a step only [`LeafHint::NONE`] or a hint a step left with the same proxy. A hint made
/// up by hand is checked for shape (depth, cell range, label; a surface hint's record is a
/// one-sided surface leaf of the proxy) and for holding the particle, never against the
/// tree: one that names a cell which is not that leaf is memory-safe, but the step believes
/// it, and may miss the surface there.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct LeafHint {
    /// Empty leaf: `cell.x | cell.y << 16`; surface leaf: `record | depth << 27`.
    pub xy: u32,
    /// Empty leaf: `cell.z | depth << DEPTH_SHIFT | label bits << LABEL_SHIFT | VALID`;
    /// surface leaf: the cell in 10 bits an axis, `SURFACE | VALID`.
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
    /// Set in `z_depth_label` when the leaf is a one-sided surface leaf.
    pub const SURFACE: u32 = 1 << 30;
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
    /// The deepest surface leaf a hint holds: its cell takes 10 bits an axis.
    pub const MAX_SURFACE_DEPTH: u32 = 10;
    /// Bits of one axis of a surface leaf's cell in `z_depth_label`.
    pub const SURFACE_CELL_BITS: u32 = 10;
    /// Shift of a surface leaf's depth in `xy`, above its record index.
    pub const RECORD_DEPTH_SHIFT: u32 = 27;
    /// Mask of a surface leaf's record index in `xy` (a proxy has fewer than `2^27` records).
    pub const RECORD_MASK: u32 = (1 << Self::RECORD_DEPTH_SHIFT) - 1;

    /// The hint for `leaf`: its cell, depth and label if it is empty; its record, depth and
    /// cell if it is a one-sided surface leaf no deeper than [`Self::MAX_SURFACE_DEPTH`]; none
    /// otherwise.
    fn of(leaf: &LeafInfo) -> LeafHint {
        if leaf.kind == LeafKind::Surface {
            if leaf.two_sided || leaf.depth > Self::MAX_SURFACE_DEPTH {
                return LeafHint::NONE;
            }
            let b = Self::SURFACE_CELL_BITS;
            return LeafHint {
                xy: leaf.node | leaf.depth << Self::RECORD_DEPTH_SHIFT,
                z_depth_label: leaf.cell.x
                    | leaf.cell.y << b
                    | leaf.cell.z << (2 * b)
                    | Self::SURFACE
                    | Self::VALID,
            };
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
    #[inline(always)]
    pub(crate) fn leaf(self, view: &ProxyView<'_>, x: Vec3) -> Option<LeafInfo> {
        let w = self.z_depth_label;
        if w & Self::VALID == 0 {
            return None;
        }
        let leaf = if w & Self::SURFACE != 0 {
            let depth = self.xy >> Self::RECORD_DEPTH_SHIFT;
            let node = self.xy & Self::RECORD_MASK;
            let (b, mask) = (Self::SURFACE_CELL_BITS, (1 << Self::SURFACE_CELL_BITS) - 1);
            let cell = UVec3::new(w & mask, (w >> b) & mask, (w >> (2 * b)) & mask);
            if depth == 0
                || depth > Self::MAX_SURFACE_DEPTH
                || (cell.x | cell.y | cell.z) >> depth != 0
            {
                return None;
            }
            let rec = *view.nodes().get(node as usize)?;
            if !rec.is_leaf() || rec.is_two_sided() {
                return None;
            }
            view.surface_leaf(cell, depth, node, rec)
        } else {
            let depth = (w >> Self::DEPTH_SHIFT) & Self::DEPTH_MASK;
            // Depth 0 would be the root, which is never a leaf.
            if depth == 0 || depth > MAX_DEPTH {
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
            view.empty_leaf(cell, depth, NO_LEAF, label)
        };
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
    march(view, p, params, &mut LeafHint::default(), &mut Unobserved)
}

/// [`step_particle`], starting from the leaf in `hint` when the particle is still strictly
/// inside it, and leaving in `hint` the leaf the step ended in (or [`LeafHint::NONE`]).
/// With [`LeafHint::NONE`] or a hint this function left with the same proxy, the result is
/// [`step_particle`]'s, bit for bit; only the work differs (see [`LeafHint`]).
#[inline(always)]
pub fn step_particle_hinted(
    view: &ProxyView<'_>,
    p: &mut Particle,
    params: &StepParams,
    hint: &mut LeafHint,
) -> StepOutcome {
    step_hinted_observed(view, p, params, hint, &mut Unobserved)
}

/// [`step_particle_hinted`] reporting its collisions to `obs` (the scene step's hit records).
#[inline(always)]
pub(crate) fn step_hinted_observed<O: MarchObserver>(
    view: &ProxyView<'_>,
    p: &mut Particle,
    params: &StepParams,
    hint: &mut LeafHint,
    obs: &mut O,
) -> StepOutcome {
    if settle_in_hinted_leaf(view, p, params, *hint) {
        return StepOutcome::Done;
    }
    // A particle outside the root has no hint; one moving away from the root stays outside.
    if *hint == LeafHint::NONE && settle_leaving_root(view, p, params) {
        return StepOutcome::Done;
    }
    march_from_hint(view, p, params, hint, obs)
}

/// The other common case of [`step_particle_hinted`]: a particle outside the root cube whose
/// path stays beyond one of its faces. Either it is beyond the face and not moving back
/// toward it (particles that fly off a scene keep going), or both ends of its path are beyond
/// the face by a margin (rain falling toward a scene from above). The march would find that
/// it never enters the root and move the particle to the end point; this does the same in
/// the same operations. `true` when settled; the hint stays [`LeafHint::NONE`].
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
    let valid = x0.is_finite() & v.is_finite() & end.is_finite() & (params.dt > 0.0);
    if !valid {
        return false;
    }
    // Both ends beyond one face by a margin far above the rounding of `x0`, `end` and the
    // face (2^-12 of their magnitudes): the segment stays beyond it, and `enter_box` (the
    // test `enter_root` makes) computes an entry time past the step on that axis, so finds
    // none; the march then moves the particle to the end. Nearer the face, the march decides.
    let margin = (x0.abs() + end.abs() + root.min.abs() + root.max.abs()) * (1.0 / 4096.0);
    let beyond = (x0.cmplt(root.min) & end.cmplt(root.min - margin))
        | (x0.cmpgt(root.max) & end.cmpgt(root.max + margin));
    if !(leaving | beyond).any() {
        return false;
    }
    p.position = end.to_array();
    p.velocity = v.to_array();
    p.side &= SIDE_MASK;
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
    let shape_ok = (w & (LeafHint::VALID | LeafHint::SURFACE) == LeafHint::VALID)
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
    // An unlabelled leaf keeps the side (normalised as the march does: no cage, for an empty
    // leaf is none); a labelled one stamps it: label bits 1 (front) and 2 (back) are sides 0
    // and 1.
    const _: () =
        assert!(SIDE_FRONT == Label::Front.bits() - 1 && SIDE_BACK == Label::Back.bits() - 1);
    let kept = p.side & SIDE_MASK;
    p.side = if label_bits == 0 {
        kept
    } else {
        label_bits - 1
    };
    p.flags &= !FLAG_STEP_STATUS;
    true
}

/// The march of [`step_particle_hinted`], out of line: the settled case above is the hot
/// loop's, and stays small without it. A particle whose hint is a surface leaf tries
/// `settle_on_plane` first.
#[inline(never)]
fn march_from_hint<O: MarchObserver>(
    view: &ProxyView<'_>,
    p: &mut Particle,
    params: &StepParams,
    hint: &mut LeafHint,
    obs: &mut O,
) -> StepOutcome {
    // Decoded once, for both: `settle_on_plane` and the march's first leaf.
    let hinted = hint.leaf(view, Vec3::from_array(p.position));
    if settle_on_plane(p, params, hinted.as_ref(), obs) {
        return StepOutcome::Done;
    }
    march_hinted(view, p, params, hint, obs, NO_LEAF, hinted)
}

/// The common case of a particle in a one-sided surface leaf, settled without the march: it
/// rests on the leaf's plane or moves inside the leaf, colliding with the plane at most once,
/// and ends the step strictly inside the leaf (sand on a floor, or settling into a bowl). It
/// does what the march does for such a particle, in the same operations (`collision_normal`,
/// `reach_plane`, `respond`, the end point, the flags), and leaves the hint as it is, the
/// march's hint for that leaf. `false`, with the particle untouched, for anything else (a
/// caged particle, the path leaving the leaf, a collision on the leaf's boundary): the march
/// takes it. Contact on the plane put resting particles inside surface leaves, where every
/// step marched (the bunny under the bench's gravity: 34 % more instructions per step).
#[inline(always)]
fn settle_on_plane<O: MarchObserver>(
    p: &mut Particle,
    params: &StepParams,
    hinted: Option<&LeafInfo>,
    obs: &mut O,
) -> bool {
    // A surface hint names only one-sided surface leaves.
    let Some(leaf) = hinted.filter(|l| l.kind == LeafKind::Surface && !l.two_sided) else {
        return false;
    };
    if p.side & !SIDE_MASK != 0 {
        return false;
    }
    let x0 = Vec3::from_array(p.position);
    let v = Vec3::from_array(p.velocity) + Vec3::from_array(params.gravity) * params.dt;
    // The march's loop condition, and a finite velocity (a finite start: it is in the box).
    if !(params.dt > 0.0) || !v.is_finite() {
        return false;
    }
    let strictly_in = |x: Vec3| (x.cmpgt(leaf.aabb.min) & x.cmplt(leaf.aabb.max)).all();
    // `collision_normal` for a particle strictly inside a one-sided leaf.
    let n = if p.side == SIDE_BACK {
        -leaf.normal
    } else {
        leaf.normal
    };
    let (mut x, mut vel, mut remaining, mut collided) = (x0, v, params.dt, 0);
    // The collision's report, made only once the step is known to settle here.
    let mut report = None;
    if v.dot(n) < 0.0 {
        // `reach_plane`.
        let centre = (leaf.aabb.min + leaf.aabb.max) * 0.5;
        let above = leaf.normal.dot(x - centre) - leaf.plane_offset;
        let t = -above / leaf.normal.dot(v);
        let reached = if !(t > 0.0) {
            true
        } else {
            let hit = x + v * t;
            let in_leaf = (hit.cmpge(leaf.aabb.min) & hit.cmple(leaf.aabb.max)).bitmask() == 0b111;
            if !(t < remaining) || !in_leaf {
                false
            } else {
                x = hit;
                remaining -= t;
                true
            }
        };
        if reached {
            // `collide`'s first collision of a step: no pinch. The march goes on in the leaf,
            // where it collided already, when the point is strictly inside it.
            vel = respond(v, n, params.restitution, params.friction);
            collided = 1;
            report = Some((x, n, v, vel, remaining, leaf.node));
            if !strictly_in(x) || !(remaining > 0.0) {
                return false;
            }
        }
    }
    // `travel_through_leaf`'s end point, strictly inside the leaf.
    let end = x + vel * remaining;
    if !strictly_in(end) {
        return false;
    }
    if let Some((x, n, before, after, remaining, node)) = report {
        // The march's observer would not stop here: the collision leaves the particle
        // strictly inside the leaf with time left, where the march goes on.
        obs.hit(x, n, before, after, remaining, node);
    }
    p.position = end.to_array();
    p.velocity = vel.to_array();
    // `finish_march`'s flags, for a step that ends as it should.
    let count = (p.collisions() + collided).min(MAX_COLLISIONS);
    let status = p.flags & FLAG_STATUS_MASK & !FLAG_STEP_STATUS;
    p.flags = status | count << COLLISION_SHIFT;
    true
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
    march(
        view,
        p,
        params,
        &mut LeafHint::default(),
        &mut Pieces(trace),
    )
}

/// [`step_particle`], adding to `counts` every rare branch the march takes ([`MarchBranch`]).
/// Host-only, for tests: the differential tests assert that the scenes built to reach a rare
/// branch do reach it, so that a mirror drifting in that branch cannot pass unseen. The same
/// march as [`step_particle`]'s, so the same bits.
pub fn step_particle_counted(
    view: &ProxyView<'_>,
    p: &mut Particle,
    params: &StepParams,
    counts: &mut MarchCounts,
) -> StepOutcome {
    march(view, p, params, &mut LeafHint::default(), counts)
}

/// What kind of step a particle took, as [`step_particle_profiled`] tells it: the classes the
/// bench times apart.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum StepKind {
    /// Settled before the march: strictly inside its hinted empty leaf for the whole step, or
    /// outside the root with a path that stays beyond one of its faces. (One settled on its
    /// surface leaf's plane is [`StepKind::InSurface`].)
    Settled,
    /// Marched, and stayed in the leaf it started in (or outside the root: no leaf).
    OneLeaf,
    /// Marched into one more leaf.
    TwoLeaves,
    /// Marched through three leaves or more.
    Several,
    /// Collided (a shell block included), wherever it started.
    Colliding,
    /// Started inside a surface leaf and did not collide (settled on the leaf's plane or
    /// marched out).
    InSurface,
}

impl StepKind {
    /// Every kind, in the order of the variants.
    pub const ALL: [StepKind; 6] = [
        StepKind::Settled,
        StepKind::OneLeaf,
        StepKind::TwoLeaves,
        StepKind::Several,
        StepKind::Colliding,
        StepKind::InSurface,
    ];

    /// A short name: `settled`, `one leaf`, `two leaves`, `several`, `colliding`, `in surface`.
    pub fn name(self) -> &'static str {
        match self {
            StepKind::Settled => "settled",
            StepKind::OneLeaf => "one leaf",
            StepKind::TwoLeaves => "two leaves",
            StepKind::Several => "several",
            StepKind::Colliding => "colliding",
            StepKind::InSurface => "in surface",
        }
    }
}

/// [`step_particle_profiled`]'s account of one step: its kind and the leaves it visited (1
/// for a step settled in its hinted leaf or on its surface leaf's plane, 0 outside the root).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StepProfile {
    /// The kind of step.
    pub kind: StepKind,
    /// Leaves entered, the first included.
    pub leaves: u32,
}

/// [`step_particle_hinted`], telling what kind of step it was and how many leaves it visited
/// ([`StepProfile`]). Host-only, for the bench's profile; the same step, so the same bits
/// and the same hint, plus one point location of the start (whether it is in a surface
/// leaf).
pub fn step_particle_profiled(
    view: &ProxyView<'_>,
    p: &mut Particle,
    params: &StepParams,
    hint: &mut LeafHint,
) -> (StepOutcome, StepProfile) {
    let in_surface = Vec3::from_array(p.position).is_finite()
        && view
            .locate_leaf(Vec3::from_array(p.position))
            .is_some_and(|l| l.kind == LeafKind::Surface);
    let hinted = *hint != LeafHint::NONE;
    let mut obs = Profiler::default();
    let outcome = step_hinted_observed(view, p, params, hint, &mut obs);
    let leaves = match obs.visited {
        Some(v) => v,
        // No march: settled in its hinted leaf (or on the plane of its surface leaf), or
        // outside the root without a hint.
        None => u32::from(hinted),
    };
    let kind = if obs.collisions > 0 {
        StepKind::Colliding
    } else if in_surface {
        StepKind::InSurface
    } else if obs.visited.is_none() {
        StepKind::Settled
    } else {
        match leaves {
            0 | 1 => StepKind::OneLeaf,
            2 => StepKind::TwoLeaves,
            _ => StepKind::Several,
        }
    };
    (outcome, StepProfile { kind, leaves })
}

/// [`step_particle_profiled`]'s observer: whether the march ran, the leaves it visited, and
/// the collisions.
#[derive(Default)]
struct Profiler {
    visited: Option<u32>,
    collisions: u32,
}

impl MarchObserver for Profiler {
    #[inline(always)]
    fn piece(&mut self, _: Vec3, _: Vec3) {}
    #[inline(always)]
    fn branch(&mut self, _: MarchBranch) {}
    fn hit(
        &mut self,
        _x: Vec3,
        _n: Vec3,
        _before: Vec3,
        _after: Vec3,
        _remaining: f32,
        _leaf: u32,
    ) -> bool {
        self.collisions += 1;
        false
    }
    fn finished(&mut self, visited: u32) {
        self.visited = Some(visited);
    }
}

/// The rare branches of a march, as [`step_particle_counted`] counts them. Each is a place
/// where the WGSL mirror could drift without the common paths noticing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MarchBranch {
    /// The particle was outside the root cube and its path entered it (`enter_root`).
    RootEntry,
    /// The particle was outside the root cube and its path missed it (`enter_root`; the march,
    /// not `settle_leaving_root`, which settles only particles moving away).
    RootMiss,
    /// A step started on a face between an empty leaf labelled with the other side and the
    /// shell, and starts in the shell (`start_beside_shell`).
    StartBesideShell,
    /// A particle sliding along a face of a solid (two-sided) leaf was located on the face's
    /// outer side (`slide_off_solid_face`).
    SlideOffSolid,
    /// The shell rule put a particle back where it entered the shell (`block_at_shell`).
    ShellBlock,
    /// A collision with a solid (two-sided) leaf, whose normal comes from the faces entered
    /// (`collision_normal`).
    SolidCollision,
    /// A collision at the point of the last one, still into its surface: pinched (`collide`).
    Pinch,
    /// Pinched again at that point: stopped there (`collide`).
    PinchStop,
    /// The step ended on the leaf's boundary, not strictly inside it, before the exit
    /// (`travel_through_leaf`'s clamped end).
    EndOnFace,
    /// The leaf bound stopped the step (`stop_at_leaf_bound`).
    LeafBound,
    /// ... inside the shell, so the particle went back to where it entered it.
    LeafBoundInShell,
    /// A caged particle ([`SIDE_CAGED`]) was not strictly inside a solid leaf at the start of
    /// its step, and lost its cage (`walk_in_cage`).
    CageLost,
    /// A caged particle reached a face of its cage that is not one of its exits (or is one,
    /// but the leaf beyond is not empty: a stale cage), and bounced off it as off a wall
    /// (`walk_in_cage`).
    CageWall,
    /// A caged particle left its cage through one of its exits (`walk_in_cage`).
    CageExit,
    /// A caged particle ended its step on its cage's boundary and was moved strictly inside
    /// (`finish_march`).
    CageNudge,
    /// A particle entered a solid leaf through one face with clearance, into its slab
    /// ([`SIDE_SLAB`]; `slab_entry`), instead of colliding at the face.
    SlabEntry,
    /// A particle in a slab reached one of its sides and was put back onto the face it came
    /// in by (`walk_in_slab`).
    SlabSide,
    /// A non-finite position or velocity on input.
    InvalidStart,
    /// A non-finite position or velocity at the end of the march.
    InvalidEnd,
}

impl MarchBranch {
    /// Every branch, in the order of the variants.
    pub const ALL: [MarchBranch; 19] = [
        MarchBranch::RootEntry,
        MarchBranch::RootMiss,
        MarchBranch::StartBesideShell,
        MarchBranch::SlideOffSolid,
        MarchBranch::ShellBlock,
        MarchBranch::SolidCollision,
        MarchBranch::Pinch,
        MarchBranch::PinchStop,
        MarchBranch::EndOnFace,
        MarchBranch::LeafBound,
        MarchBranch::LeafBoundInShell,
        MarchBranch::CageLost,
        MarchBranch::CageWall,
        MarchBranch::CageExit,
        MarchBranch::CageNudge,
        MarchBranch::SlabEntry,
        MarchBranch::SlabSide,
        MarchBranch::InvalidStart,
        MarchBranch::InvalidEnd,
    ];
}

/// How often each [`MarchBranch`] was taken, indexed by the branch.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MarchCounts([u64; MarchBranch::ALL.len()]);

impl MarchCounts {
    /// Adds `other`'s counts to these.
    pub fn add(&mut self, other: &MarchCounts) {
        for (a, b) in self.0.iter_mut().zip(other.0) {
            *a += b;
        }
    }
}

impl core::ops::Index<MarchBranch> for MarchCounts {
    type Output = u64;
    fn index(&self, branch: MarchBranch) -> &u64 {
        &self.0[branch as usize]
    }
}

/// What a march reports besides its result: the straight pieces of the path and the rare
/// branches taken. The step's own entry points observe nothing ([`Unobserved`] inlines to
/// nothing); the host-only ones trace pieces ([`Pieces`]) or count branches
/// ([`MarchCounts`]). WGSL has no observer.
pub(crate) trait MarchObserver {
    /// The particle moved (or, for a jump back to the shell entry, was put) from `from` to `to`.
    fn piece(&mut self, from: Vec3, to: Vec3);
    /// The march took `branch`.
    fn branch(&mut self, branch: MarchBranch);
    /// A collision response (a pinch and a shell block included): at `x`, with unit normal
    /// `n` facing the particle, velocity `before` just before it and `after` just after, with
    /// `remaining` of the step's time left, in surface leaf `leaf` (its record; [`NO_LEAF`]
    /// for a shell block). `true` stops the march there, as if its time were
    /// up (the scene step's probes: the earliest hit over several instances is taken first).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn hit(
        &mut self,
        _x: Vec3,
        _n: Vec3,
        _before: Vec3,
        _after: Vec3,
        _remaining: f32,
        _leaf: u32,
    ) -> bool {
        false
    }
    /// The march ended, having entered `visited` leaves (the first included).
    #[inline(always)]
    fn finished(&mut self, _visited: u32) {}
}

/// The observer of the step itself: nothing.
pub(crate) struct Unobserved;

impl MarchObserver for Unobserved {
    #[inline(always)]
    fn piece(&mut self, _: Vec3, _: Vec3) {}
    #[inline(always)]
    fn branch(&mut self, _: MarchBranch) {}
}

/// [`step_particle_traced`]'s observer: the pieces, to a closure.
struct Pieces<'a, F>(&'a mut F);

impl<F: FnMut(Vec3, Vec3)> MarchObserver for Pieces<'_, F> {
    #[inline(always)]
    fn piece(&mut self, from: Vec3, to: Vec3) {
        (self.0)(from, to)
    }
    #[inline(always)]
    fn branch(&mut self, _: MarchBranch) {}
}

impl MarchObserver for MarchCounts {
    #[inline(always)]
    fn piece(&mut self, _: Vec3, _: Vec3) {}
    #[inline(always)]
    fn branch(&mut self, branch: MarchBranch) {
        self.0[branch as usize] += 1;
    }
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
#[inline(always)]
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

/// A march between two leaves: where the particle is, how it moves and how long it has left,
/// and what the rules remember of the leaves behind it. WGSL's `MarchState` has the same
/// fields in the same order (an `Option<LeafInfo>` is a `LeafOption` there).
struct MarchState {
    /// Where the particle is.
    x: Vec3,
    /// Its velocity, gravity integrated.
    v: Vec3,
    /// The side it is on, normalised: [`SIDE_FRONT`] or [`SIDE_BACK`].
    side: u32,
    /// Time left in the step.
    remaining: f32,
    /// Collisions in this step (a shell block counts as one).
    collisions: u32,
    /// Whether the particle went into the shell of surface leaves and has not come out.
    in_shell: bool,
    /// Where it went in.
    shell_entry: Vec3,
    /// The surface leaf it last collided in, since it last crossed a face ([`NO_LEAF`]: none).
    last_collided: u32,
    /// Where the last collision was (when `collisions > 0`), the normal it used, and whether
    /// it pinched ([`pinch`]).
    hit_x: Vec3,
    hit_n: Vec3,
    pinched: bool,
    /// The face the particle last crossed (axes) and the signs of its velocity then.
    cross_axes: u32,
    cross_signs: Vec3,
    /// The leaf the particle was last in, while it is on that leaf's closed box.
    last_leaf: Option<LeafInfo>,
    /// A leaf the particle is strictly inside, the next leaf without a descent, until the
    /// march takes it: the hinted leaf for the first leaf (the particle has not moved yet),
    /// the leaf it collided in when it is still strictly inside it (contact on the leaf's
    /// plane), or the leaf beyond a slab's face.
    hinted: Option<LeafInfo>,
    /// A caged particle's cage bits ([`SIDE_CAGE_MASK`] of its side word), zero when it is not
    /// caged, or no more.
    exits: u32,
    /// Leaves visited, against [`ProxyView::max_leaves_per_step`].
    visited: u32,
    /// How the step ends, unless the particle turns out invalid.
    outcome: StepOutcome,
    /// Whether the shell rule blocked the particle once in this step (a second block ends it).
    blocked_once: bool,
}

/// The leaf the march goes through next, and whether it is the shell beside the point the
/// step starts on (`start_beside_shell`).
struct NextLeaf {
    leaf: LeafInfo,
    beside_shell: bool,
}

/// The march set up for a particle with a finite position and velocity: gravity integrated,
/// the side normalised, and `hinted` (its hint's leaf, if the hint holds the particle) as the
/// first leaf.
#[inline(always)]
fn start_march(p: &Particle, params: &StepParams, hinted: Option<LeafInfo>) -> MarchState {
    let x0 = Vec3::from_array(p.position);
    let v0 = Vec3::from_array(p.velocity);
    MarchState {
        x: x0,
        v: v0 + Vec3::from_array(params.gravity) * params.dt,
        side: p.side & SIDE_MASK,
        remaining: params.dt,
        collisions: 0,
        in_shell: false,
        shell_entry: x0,
        last_collided: NO_LEAF,
        hit_x: x0,
        hit_n: Vec3::ZERO,
        pinched: false,
        cross_axes: 0,
        cross_signs: Vec3::ZERO,
        last_leaf: None,
        hinted,
        exits: if p.side & SIDE_CAGED != 0 {
            p.side & SIDE_CAGE_MASK
        } else {
            0
        },
        visited: 0,
        outcome: StepOutcome::Done,
        blocked_once: false,
    }
}

/// The leaf bound was hit: the particle stays at its last safe point, which is where it
/// entered the shell if it is in it.
#[inline(always)]
fn stop_at_leaf_bound<O: MarchObserver>(st: &mut MarchState, obs: &mut O) {
    obs.branch(MarchBranch::LeafBound);
    st.outcome = StepOutcome::BoundHit;
    if st.in_shell {
        obs.branch(MarchBranch::LeafBoundInShell);
        obs.piece(st.x, st.shell_entry);
        st.x = st.shell_entry;
    }
}

/// The leaf the particle is in now; `None` when it is outside the root cube. Only the first
/// leaf of a step can come from the hint: the particle has not moved yet. After it, the
/// particle is on the closed box of the leaf it was last in, and the next leaf is found from
/// that leaf's cell; otherwise (the first leaf, or just after entering the root) by point
/// location, and for the first leaf of all, beside the shell as `start_beside_shell` says.
#[inline(always)]
fn find_next_leaf<O: MarchObserver>(
    view: &ProxyView<'_>,
    st: &mut MarchState,
    obs: &mut O,
) -> Option<NextLeaf> {
    let leaf = if let Some(leaf) = st.hinted.take() {
        leaf
    } else if let Some(leaf) = st
        .last_leaf
        .as_ref()
        .and_then(|from| view.locate_next(from, st.x, st.v))
    {
        leaf
    } else {
        if !view.root_contains(st.x, st.v) {
            return None;
        }
        let leaf = view.locate_inside(st.x, st.v);
        if st.visited == 1 {
            let start = start_beside_shell(view, leaf, st.x, st.v, st.side);
            let beside_shell = start.kind != leaf.kind;
            if beside_shell {
                obs.branch(MarchBranch::StartBesideShell);
            }
            return Some(NextLeaf {
                leaf: start,
                beside_shell,
            });
        }
        leaf
    };
    Some(NextLeaf {
        leaf,
        beside_shell: false,
    })
}

/// The particle is outside the root cube: it enters the root within the time left (`true`,
/// the march goes on from the entry point) or flies past it to the end of the step (`false`).
#[inline(always)]
fn enter_root<O: MarchObserver>(view: &ProxyView<'_>, st: &mut MarchState, obs: &mut O) -> bool {
    match enter_box(&view.root_aabb(), st.x, st.v, st.remaining) {
        Some(entry) => {
            obs.branch(MarchBranch::RootEntry);
            obs.piece(st.x, entry.point);
            st.x = entry.point;
            st.remaining -= entry.t;
            st.cross_axes = entry.axes;
            st.cross_signs = st.v;
            st.last_collided = NO_LEAF;
            st.last_leaf = None;
            true
        }
        None => {
            obs.branch(MarchBranch::RootMiss);
            let end = st.x + st.v * st.remaining;
            obs.piece(st.x, end);
            st.x = end;
            false
        }
    }
}

/// The leaf the march is in: `next`'s, unless the particle slides along a face of a solid leaf
/// (no velocity across it) and does not enter through another, when it is not in the leaf
/// but in the one on the face's outer side. On the face it is on the shell: a step that
/// starts there is in the shell from there (as `start_beside_shell` puts it for a face
/// beside a one-sided leaf), so that it cannot come off the face into an empty leaf labelled
/// with the other side. A particle that had passed a surface within a leaf by less than the
/// tolerance and ended its step on a solid leaf's edge was otherwise stamped there, and went
/// on on the wrong side (found by the starts campaign on the bunny, at `dmax` 6).
#[inline(always)]
fn slide_off_solid_face<O: MarchObserver>(
    view: &ProxyView<'_>,
    st: &mut MarchState,
    next: NextLeaf,
    obs: &mut O,
) -> LeafInfo {
    let (x, v) = (st.x, st.v);
    let mut leaf = next.leaf;
    if leaf.two_sided && !next.beside_shell && entry_faces(&leaf.aabb, x, v) == 0 {
        let mut dir = v;
        for a in 0..3 {
            if v[a] == 0.0 && x[a] == leaf.aabb.min[a] {
                dir[a] = -1.0;
            } else if v[a] == 0.0 && x[a] == leaf.aabb.max[a] {
                dir[a] = 1.0;
            }
        }
        if dir != v {
            obs.branch(MarchBranch::SlideOffSolid);
            if !st.in_shell {
                st.in_shell = true;
                st.shell_entry = x;
            }
            leaf = view.locate_inside(x, dir);
        }
    }
    leaf
}

/// Into an empty leaf: a labelled one stamps its side and the particle is out of the shell,
/// unless it came out of the shell on the other side, which the shell rule blocks (`true`:
/// the march goes on from the shell entry, or ends; `block_at_shell`).
#[inline(always)]
fn enter_empty_leaf<O: MarchObserver>(
    st: &mut MarchState,
    leaf: &LeafInfo,
    params: &StepParams,
    obs: &mut O,
) -> bool {
    // Selects, not a branch on the label: labelled or not is a coin toss for the branch
    // predictor; coming out of the shell on the other side is rare.
    let labelled = leaf.label != Label::None;
    let label_side = side_of(leaf.label);
    if (labelled as u32 & st.in_shell as u32 & (label_side != st.side) as u32) != 0 {
        block_at_shell(st, params, obs);
        return true;
    }
    st.side = if labelled { label_side } else { st.side };
    st.in_shell = false;
    false
}

/// The shell rule: the particle would leave the shell on the other side. It goes back to where
/// it entered the shell, its velocity reflected off the face it tried to cross, and goes on
/// from there with the time left, still in the shell, as it would after a collision: its
/// motion along the wall is kept. The step ends there (its time is up) at a second block, or
/// when the observer stops the march at the hit.
#[inline(always)]
fn block_at_shell<O: MarchObserver>(st: &mut MarchState, params: &StepParams, obs: &mut O) {
    obs.branch(MarchBranch::ShellBlock);
    obs.piece(st.x, st.shell_entry);
    st.x = st.shell_entry;
    let n = face_normal(st.cross_axes, st.cross_signs);
    let before = st.v;
    st.v = respond(st.v, n, params.restitution, params.friction);
    st.collisions += 1;
    st.outcome = StepOutcome::Blocked;
    let stop = obs.hit(st.x, n, before, st.v, st.remaining, NO_LEAF);
    if stop || st.blocked_once {
        // Every loop of the march ends when the time is up.
        st.remaining = 0.0;
    }
    st.blocked_once = true;
    // From the shell entry, the next leaf is found anew by point location, in the new
    // direction.
    st.last_leaf = None;
    st.hinted = None;
    st.last_collided = NO_LEAF;
}

/// Into a surface leaf: the particle is in the shell (from here, if it was not), and collides
/// when its velocity opposes the leaf's normal for its side, once per leaf between face
/// crossings (`true`: it collided, and the march finds its leaf again with the new velocity).
#[inline(always)]
fn enter_surface_leaf<O: MarchObserver>(
    view: &ProxyView<'_>,
    st: &mut MarchState,
    leaf: &LeafInfo,
    params: &StepParams,
    obs: &mut O,
) -> bool {
    if !st.in_shell {
        st.in_shell = true;
        st.shell_entry = st.x;
    }
    if leaf.node == st.last_collided {
        return false;
    }
    let n = collision_normal(st, leaf);
    if !(st.v.dot(n) < 0.0) {
        return false;
    }
    if !reach_plane(st, leaf, obs) {
        return false;
    }
    if leaf.two_sided {
        let slab = slab_entry(view, st.x, st.v, *leaf);
        if slab != 0 {
            // Into the slab: the march walks it next (`walk_in_slab`).
            obs.branch(MarchBranch::SlabEntry);
            st.exits = slab;
            return true;
        }
        obs.branch(MarchBranch::SolidCollision);
    }
    collide(st, leaf, n, params, obs);
    // Still strictly inside the leaf (it collided on the leaf's plane, or started inside a
    // solid leaf): the march goes on in this leaf, which point location would find again.
    if (st.x.cmpgt(leaf.aabb.min) & st.x.cmplt(leaf.aabb.max)).all() {
        st.hinted = Some(*leaf);
    }
    true
}

/// Contact nearer the surface in a solid leaf: a particle entering it through one face, at a
/// point strictly inside that face (not on an edge or a corner), that has clearance goes into
/// the slab of the leaf by that face, which holds no triangle, and collides at the slab's
/// inner side (`walk_in_slab`). The cage bits of that slab ([`SIDE_CAGED`], [`SIDE_SLAB`] and
/// the face's exit bit), or 0 to collide at the face. On an edge of the face the particle
/// would be at a side of the slab at once, and be put back onto the face with no time spent:
/// where solid leaves meet at an edge, two such slabs handed a particle back and forth until
/// the leaf bound stopped the step (found by profiling the bench: 544 slab entries in each of
/// 55 of 1.2 million steps on the ogre), so there it collides at the face. Out of line: only
/// collisions with solid leaves come here.
#[inline(never)]
fn slab_entry(view: &ProxyView<'_>, x: Vec3, v: Vec3, leaf: LeafInfo) -> u32 {
    let axes = entry_faces(&leaf.aabb, x, v);
    if axes.count_ones() != 1 {
        return 0;
    }
    let within = (x.cmpgt(leaf.aabb.min) & x.cmplt(leaf.aabb.max)).bitmask();
    if within | axes != 0b111 {
        return 0;
    }
    let axis = axes.trailing_zeros();
    // Moving down the axis, it comes in through the upper face.
    let upper = v[axis as usize] < 0.0;
    let clearance = view.nodes()[leaf.node as usize].clearance(2 * axis + upper as u32);
    if clearance == 0 {
        return 0;
    }
    SIDE_CAGED | SIDE_SLAB | side_exit(axis, upper)
}

/// Contact where the surface is: in a one-sided surface leaf a particle moving against the
/// normal collides on the leaf's plane (its stored normal and offset), not at the face it
/// entered by. `true` when it collides now: it was on or behind the plane already, or its path
/// meets the plane within the leaf and the time left, and it has moved there. `false` when the
/// path leaves the leaf or the step ends first: it travels on, on its side of the plane. A leaf
/// stops early only where its triangles lie within half a `dmax` leaf of that plane, and a
/// `dmax` leaf is one leaf across, so particles rest, and hit, within about a leaf of the true
/// surface however coarse the leaf, and pass it by at most that before they collide (at the
/// entry face of a coarse leaf over a flat floor they rested up to 8 `dmax` leaves above it).
/// Solid (two-sided) leaves collide at their faces (`true`): they are `dmax` leaves, and a
/// particle must not move about in one; `enter_surface_leaf` sends it into the leaf's slab by
/// the face instead where the face has clearance.
#[inline(always)]
fn reach_plane<O: MarchObserver>(st: &mut MarchState, leaf: &LeafInfo, obs: &mut O) -> bool {
    if leaf.two_sided {
        return true;
    }
    let centre = (leaf.aabb.min + leaf.aabb.max) * 0.5;
    let above = leaf.normal.dot(st.x - centre) - leaf.plane_offset;
    let t = -above / leaf.normal.dot(st.v);
    if !(t > 0.0) {
        return true;
    }
    let hit = st.x + st.v * t;
    let in_leaf = (hit.cmpge(leaf.aabb.min) & hit.cmple(leaf.aabb.max)).bitmask() == 0b111;
    if !(t < st.remaining) || !in_leaf {
        return false;
    }
    obs.piece(st.x, hit);
    st.x = hit;
    st.remaining -= t;
    true
}

/// The normal a surface leaf collides with: for a solid (two-sided) leaf, that of the faces the
/// particle is entering through, found from the box, so a particle resting on one at the
/// start of a step counts; otherwise, and for a particle strictly inside a solid leaf (a step
/// that starts there), the leaf's normal, flipped for the back side. Inside a solid leaf that
/// an open sheet's rim passes through, a particle free to move would go round the rim to the
/// other side and back through the sheet within the leaf, and leave it on its own side, with
/// nothing to stop it (found by a campaign of starts near a sheet's and a dome's rims); held
/// to its side of the leaf's plane, it cannot.
#[inline(always)]
fn collision_normal(st: &MarchState, leaf: &LeafInfo) -> Vec3 {
    let inside = (st.x.cmpgt(leaf.aabb.min) & st.x.cmplt(leaf.aabb.max)).all();
    if leaf.two_sided && !inside {
        face_normal(entry_faces(&leaf.aabb, st.x, st.v), st.v)
    } else if st.side == SIDE_BACK {
        -leaf.normal
    } else {
        leaf.normal
    }
}

/// A collision with normal `n` in `leaf`: the response, and the pinch rule when it is caught
/// (at the point of the last collision, or against a surface facing the last one within the
/// leaf's diagonal of it) and the response still points into the last surface.
#[inline(always)]
fn collide<O: MarchObserver>(
    st: &mut MarchState,
    leaf: &LeafInfo,
    n: Vec3,
    params: &StepParams,
    obs: &mut O,
) {
    let before = st.v;
    st.v = respond(st.v, n, params.restitution, params.friction);
    // Caught: at the point of the last collision, or against a surface facing the last one
    // within this leaf's diagonal of it (contact is on the leaves' planes, so two facing
    // surfaces a gap apart are hit at two points).
    let (gap, diagonal) = (st.x - st.hit_x, leaf.aabb.max - leaf.aabb.min);
    let facing = n.dot(st.hit_n) < 0.0 && gap.dot(gap) <= diagonal.dot(diagonal);
    if st.collisions > 0 && (st.x == st.hit_x || facing) && st.v.dot(st.hit_n) < 0.0 {
        // Pinched; pinched again at the same point (rounding left the velocity a hair into a
        // surface), it stops there.
        obs.branch(if st.pinched {
            MarchBranch::PinchStop
        } else {
            MarchBranch::Pinch
        });
        st.v = if st.pinched {
            Vec3::ZERO
        } else {
            pinch(st.v, n, st.hit_n)
        };
        st.pinched = true;
    } else {
        st.pinched = false;
    }
    (st.hit_x, st.hit_n) = (st.x, n);
    st.collisions += 1;
    st.last_collided = leaf.node;
    if obs.hit(st.x, n, before, st.v, st.remaining, leaf.node) {
        // Every loop of the march ends when the time is up; the particle stays at the hit.
        st.remaining = 0.0;
    }
}

/// A caged particle's step, before the march: in its cage ([`SIDE_CAGED`]: the solid leaf it
/// started in) it moves freely, bounces off every face that is not one of its exits as off a
/// wall (`collide`, with the pinch rule), and leaves through an exit out of the shell, into the
/// empty leaf beyond, whose label the march then stamps. `Some(cage)` when the step ended in
/// the cage (its time used up, or the leaf bound hit: back where it started); `None` when the
/// march goes on: from the exit point, or, for a particle not strictly inside a solid leaf
/// (moved by hand, or stepped against another proxy), from where it is, caged no more.
///
/// Its exits are the faces it could reach from where it started without crossing the surface
/// (the host decides, from the mesh). The cage is where one side bit cannot say which of the
/// surfaces in a leaf a particle is behind (two parts crossing, a fold, a rim), and a particle
/// free to leave it anywhere left it beyond the surface it had not been stamped for (found by
/// the starts campaign on open models whose parts pass through each other: the teapot's spout,
/// Suzanne's eyes, the ogre). A prologue out of line, not a turn of the march's loop, so the
/// march pays nothing for it but one test.
#[inline(never)]
fn walk_in_cage<O: MarchObserver>(
    view: &ProxyView<'_>,
    mut state: MarchState,
    params: &StepParams,
    obs: &mut O,
) -> (MarchState, Option<LeafInfo>) {
    let st = &mut state;
    let cage = 'walk: {
        let found = if view.root_contains(st.x, st.v) {
            Some(view.locate_inside(st.x, st.v))
        } else {
            None
        };
        let Some(cage) = found.filter(|l| {
            let inside = (st.x.cmpgt(l.aabb.min) & st.x.cmplt(l.aabb.max)).all();
            l.kind == LeafKind::Surface && l.two_sided && inside
        }) else {
            obs.branch(MarchBranch::CageLost);
            st.exits = 0;
            break 'walk None;
        };
        st.in_shell = true;
        st.shell_entry = st.x;
        // The particle moves now: a hint is for its first leaf only.
        st.hinted = None;
        if st.exits & SIDE_SLAB != 0 {
            return walk_in_slab(view, state, cage, false, params, obs);
        }
        let budget = view.max_leaves_per_step();
        while st.remaining > 0.0 {
            if st.visited >= budget {
                stop_at_leaf_bound(st, obs);
                break 'walk Some(cage);
            }
            st.visited += 1;
            let Some(exit) = move_in_box(st, &cage.aabb, obs) else {
                break 'walk Some(cage);
            };
            let axis = exit.axes.trailing_zeros().min(2);
            let upper = st.v[axis as usize] > 0.0;
            if exit.axes.count_ones() == 1 && st.exits & side_exit(axis, upper) != 0 {
                // On the exit face, and strictly inside it: on an edge of the cage (a velocity
                // component of +0 after sliding along a wall, or an exit point rounded onto a
                // bound), the tie rule would find the leaf across the edge, not the face.
                let mut x = strictly_inside(st.x, &cage.aabb);
                x[axis as usize] = st.x[axis as usize];
                // An exit leads into an empty leaf (the host made it one); a stale cage (a
                // particle file written against another proxy) may name a face that does not,
                // and that face is a wall.
                if view
                    .locate_next(&cage, x, st.v)
                    .is_some_and(|l| l.kind == LeafKind::Empty)
                {
                    // Out by an exit, and out of the shell: the leaf beyond stamps it.
                    obs.branch(MarchBranch::CageExit);
                    obs.piece(st.x, x);
                    st.x = x;
                    st.exits = 0;
                    st.in_shell = false;
                    st.cross_axes = exit.axes;
                    st.cross_signs = st.v;
                    st.last_leaf = Some(cage);
                    break 'walk None;
                }
            }
            obs.branch(MarchBranch::CageWall);
            collide(st, &cage, face_normal(exit.axes, st.v), params, obs);
        }
        Some(cage)
    };
    (state, cage)
}

/// A caged particle's move in its cage's box `b` (the leaf, or a slab of it): to the end of
/// the step if that is strictly inside `b`, or on `b`'s boundary before the exit (`None`: the
/// step ends there); otherwise to where it leaves `b` (`Some`, with the time left reduced).
#[inline(always)]
fn move_in_box<O: MarchObserver>(
    st: &mut MarchState,
    b: &Aabb,
    obs: &mut O,
) -> Option<BoxCrossing> {
    let end = st.x + st.v * st.remaining;
    if (end.cmpgt(b.min) & end.cmplt(b.max)).all() {
        obs.piece(st.x, end);
        st.x = end;
        return None;
    }
    let exit = exit_box(b, st.x, st.v);
    if exit.t >= st.remaining {
        obs.branch(MarchBranch::EndOnFace);
        let end = (st.x + st.v * st.remaining).clamp(b.min, b.max);
        obs.piece(st.x, end);
        st.x = end;
        return None;
    }
    obs.piece(st.x, exit.point);
    st.x = exit.point;
    st.remaining -= exit.t;
    Some(exit)
}

/// A particle in the slab of a solid leaf ([`SIDE_SLAB`]): the part of the leaf within its
/// clearance of the face the particle came in by, which holds no triangle. It moves freely in
/// the slab and collides at its inner side, as it would have at the face, nearer the surface:
/// particles rest there, not on a face up to a leaf above it. It leaves through the face; at
/// a side of the slab it is put back onto the face (straight across the slab, crossing
/// nothing) and goes on from there, as if it had slid along the face outside the leaf: into
/// the leaf beyond the face, where the march goes on, with the shell rule. `entered`: it came
/// in through the face in this step (`slab_entry`); otherwise the step started in the slab
/// (`walk_in_cage`), and a particle not strictly inside it loses its slab bits. `Some(slab)`
/// when the step ended in the slab (the slab as the leaf's box); `None` when the march goes
/// on. Out of line.
#[inline(never)]
fn walk_in_slab<O: MarchObserver>(
    view: &ProxyView<'_>,
    mut state: MarchState,
    leaf: LeafInfo,
    entered: bool,
    params: &StepParams,
    obs: &mut O,
) -> (MarchState, Option<LeafInfo>) {
    let st = &mut state;
    let slab = 'walk: {
        let face = ((st.exits & SIDE_EXITS_MASK) >> SIDE_EXITS_SHIFT)
            .trailing_zeros()
            .min(5);
        let (axis, upper) = ((face >> 1) as usize, face & 1 != 0);
        let clearance = view.nodes()[leaf.node as usize].clearance(face);
        let edge = leaf.aabb.max[axis] - leaf.aabb.min[axis];
        let depth = edge * (clearance as f32 * (1.0 / CLEARANCE_STEPS as f32));
        let mut slab = leaf;
        let plane = if upper {
            slab.aabb.min[axis] = leaf.aabb.max[axis] - depth;
            leaf.aabb.max[axis]
        } else {
            slab.aabb.max[axis] = leaf.aabb.min[axis] + depth;
            leaf.aabb.min[axis]
        };
        if !entered {
            let inside = (st.x.cmpgt(slab.aabb.min) & st.x.cmplt(slab.aabb.max)).all();
            if clearance == 0 || !inside {
                obs.branch(MarchBranch::CageLost);
                st.exits = 0;
                break 'walk None;
            }
        }
        let budget = view.max_leaves_per_step();
        while st.remaining > 0.0 {
            if st.visited >= budget {
                if entered {
                    // The march stops at the bound, where the particle entered the shell.
                    st.exits = 0;
                    break 'walk None;
                }
                stop_at_leaf_bound(st, obs);
                break 'walk Some(slab);
            }
            st.visited += 1;
            let Some(exit) = move_in_box(st, &slab.aabb, obs) else {
                break 'walk Some(slab);
            };
            let through_face = exit.axes & (1 << axis) != 0 && (st.v[axis] > 0.0) == upper;
            let sides = exit.axes & !(1 << axis);
            if through_face || sides != 0 {
                let mut x = st.x;
                if through_face {
                    // Strictly inside the face: never out by an edge of the leaf.
                    obs.branch(MarchBranch::CageExit);
                    x = strictly_inside(x, &slab.aabb);
                    x[axis] = plane;
                } else {
                    obs.branch(MarchBranch::SlabSide);
                    x[axis] = plane;
                }
                obs.piece(st.x, x);
                st.x = x;
                st.exits = 0;
                // Where the shell rule and the leaf bound put it back, if they stop it later in
                // this step: a point on its side outside the leaf (a step that started in the
                // slab had its start there, strictly inside a solid leaf, where it would be free
                // once out of its slab).
                st.shell_entry = x;
                // Out across the face: the leaf beyond it at this point (at a side of the slab,
                // on the leaf's edge, the leaf across that edge, as the velocity leads).
                let mut out = st.v;
                out[axis] = if upper { 1.0 } else { -1.0 };
                st.cross_axes = 1 << axis;
                st.cross_signs = out;
                st.last_collided = NO_LEAF;
                st.last_leaf = None;
                st.hinted = if view.root_contains(x, out) {
                    Some(view.locate_inside(x, out))
                } else {
                    None
                };
                break 'walk None;
            }
            obs.branch(MarchBranch::CageWall);
            collide(st, &slab, face_normal(exit.axes, st.v), params, obs);
        }
        Some(slab)
    };
    (state, slab)
}

/// The next float from `x` up (`up`) or down, never a subnormal (a GPU may flush those to
/// zero): from zero, the smallest normal float; from that, towards zero, zero.
#[inline(always)]
fn next_float(x: f32, up: bool) -> f32 {
    if x == 0.0 {
        return if up {
            f32::MIN_POSITIVE
        } else {
            -f32::MIN_POSITIVE
        };
    }
    if x.abs() == f32::MIN_POSITIVE && (x > 0.0) != up {
        return 0.0;
    }
    let bits = x.to_bits();
    f32::from_bits(if (x > 0.0) == up { bits + 1 } else { bits - 1 })
}

/// `x` moved strictly inside the box `b` where it lies on a face: the next float inward.
/// Out of line: only a caged particle needs it.
#[inline(never)]
fn strictly_inside(x: Vec3, b: &Aabb) -> Vec3 {
    let mut y = x;
    for a in 0..3 {
        if !(x[a] > b.min[a]) {
            y[a] = next_float(b.min[a], true);
        } else if !(x[a] < b.max[a]) {
            y[a] = next_float(b.max[a], false);
        }
    }
    y
}

/// Through the leaf: the step ends in it (`true`, leaving it in `hint`), or the particle moves
/// to where it leaves it (`false`, the march goes on from the exit point).
#[inline(always)]
fn travel_through_leaf<O: MarchObserver>(
    st: &mut MarchState,
    leaf: &LeafInfo,
    hint: &mut LeafHint,
    obs: &mut O,
) -> bool {
    // Most steps end in the leaf they start in: an end point strictly inside the box settles
    // it without the exit time (the segment stays in the convex box).
    let end = st.x + st.v * st.remaining;
    // One test of a mask, not six short-circuit branches.
    if (end.cmpgt(leaf.aabb.min) & end.cmplt(leaf.aabb.max)).bitmask() == 0b111 {
        obs.piece(st.x, end);
        st.x = end;
        *hint = LeafHint::of(leaf);
        return true;
    }
    let exit = exit_box(&leaf.aabb, st.x, st.v);
    if exit.t >= st.remaining {
        obs.branch(MarchBranch::EndOnFace);
        let end = (st.x + st.v * st.remaining).clamp(leaf.aabb.min, leaf.aabb.max);
        obs.piece(st.x, end);
        st.x = end;
        *hint = LeafHint::of(leaf);
        return true;
    }
    obs.piece(st.x, exit.point);
    st.x = exit.point;
    st.remaining -= exit.t;
    st.cross_axes = exit.axes;
    st.cross_signs = st.v;
    st.last_collided = NO_LEAF;
    false
}

/// [`finish_march`] for a particle whose step ended in its cage, out of line: the common
/// march carries none of it.
#[inline(never)]
fn finish_caged<O: MarchObserver>(
    p: &mut Particle,
    st: MarchState,
    cage: Option<LeafInfo>,
    obs: &mut O,
) -> StepOutcome {
    finish_march(p, &st, cage, obs)
}

/// The particle as the march leaves it: position, velocity and side, the collision count and
/// the step's status flags; or flagged invalid when the march made it non-finite.
#[inline(always)]
fn finish_march<O: MarchObserver>(
    p: &mut Particle,
    st: &MarchState,
    cage: Option<LeafInfo>,
    obs: &mut O,
) -> StepOutcome {
    obs.finished(st.visited);
    if !st.x.is_finite() || !st.v.is_finite() {
        obs.branch(MarchBranch::InvalidEnd);
        p.flags |= FLAG_INVALID;
        return StepOutcome::Invalid;
    }
    let mut x = st.x;
    if let Some(cage) = cage {
        // Still caged: strictly inside the cage, so that the next step finds it there.
        let inside = strictly_inside(x, &cage.aabb);
        if inside != x {
            obs.branch(MarchBranch::CageNudge);
            obs.piece(x, inside);
            x = inside;
        }
    }
    p.position = x.to_array();
    p.velocity = st.v.to_array();
    p.side = st.side | if cage.is_some() { st.exits } else { 0 };
    let count = (p.collisions() + st.collisions).min(MAX_COLLISIONS);
    let mut status = p.flags & FLAG_STATUS_MASK & !FLAG_STEP_STATUS;
    match st.outcome {
        StepOutcome::Blocked => status |= FLAG_BLOCKED,
        StepOutcome::BoundHit => status |= FLAG_BOUND_HIT,
        _ => {}
    }
    p.flags = status | count << COLLISION_SHIFT;
    st.outcome
}

/// The step itself, for every public entry point above: leaf by leaf, each found from the
/// last, until the time is used up, a rule stops the particle, or the leaf bound is hit.
#[inline(always)]
pub(crate) fn march<O: MarchObserver>(
    view: &ProxyView<'_>,
    p: &mut Particle,
    params: &StepParams,
    hint: &mut LeafHint,
    obs: &mut O,
) -> StepOutcome {
    march_after(view, p, params, hint, obs, NO_LEAF)
}

/// [`march`] for a particle that has just collided in surface leaf `collided` (a record, or
/// [`NO_LEAF`]) and has not left it: it does not collide there again before it crosses a
/// face, as within one march. The scene step goes on from a contact with it.
#[inline(always)]
pub(crate) fn march_after<O: MarchObserver>(
    view: &ProxyView<'_>,
    p: &mut Particle,
    params: &StepParams,
    hint: &mut LeafHint,
    obs: &mut O,
    collided: u32,
) -> StepOutcome {
    let hinted = hint.leaf(view, Vec3::from_array(p.position));
    march_hinted(view, p, params, hint, obs, collided, hinted)
}

/// [`march_after`] with the hint already decoded: `hinted` is `hint.leaf` at the particle's
/// position (`None` for none).
#[inline(always)]
fn march_hinted<O: MarchObserver>(
    view: &ProxyView<'_>,
    p: &mut Particle,
    params: &StepParams,
    hint: &mut LeafHint,
    obs: &mut O,
    collided: u32,
    hinted: Option<LeafInfo>,
) -> StepOutcome {
    *hint = LeafHint::NONE;
    if !Vec3::from_array(p.position).is_finite() || !Vec3::from_array(p.velocity).is_finite() {
        obs.branch(MarchBranch::InvalidStart);
        obs.finished(0);
        p.flags |= FLAG_INVALID;
        return StepOutcome::Invalid;
    }
    let mut st = start_march(p, params, hinted);
    st.last_collided = collided;
    if st.exits != 0 {
        // By value, in and out: a march state behind a pointer that escapes into a call out
        // of line lives in memory for the whole march (LLVM keeps it in registers only while
        // no pointer to it escapes), and the march ran 20 % slower for it.
        let cage;
        (st, cage) = walk_in_cage(view, st, params, obs);
        if cage.is_some() {
            return finish_caged(p, st, cage, obs);
        }
    }
    let budget = view.max_leaves_per_step();
    while st.remaining > 0.0 {
        if st.visited >= budget {
            stop_at_leaf_bound(&mut st, obs);
            break;
        }
        st.visited += 1;
        let Some(next) = find_next_leaf(view, &mut st, obs) else {
            if enter_root(view, &mut st, obs) {
                continue;
            }
            break;
        };
        let leaf = slide_off_solid_face(view, &mut st, next, obs);
        st.last_leaf = Some(leaf);
        match leaf.kind {
            LeafKind::Empty => {
                let blocked = enter_empty_leaf(&mut st, &leaf, params, obs);
                if blocked {
                    continue;
                }
            }
            LeafKind::Surface => {
                let collided = enter_surface_leaf(view, &mut st, &leaf, params, obs);
                if collided {
                    if st.exits != 0 {
                        let slab;
                        (st, slab) = walk_in_slab(view, st, leaf, true, params, obs);
                        if slab.is_some() {
                            return finish_caged(p, st, slab, obs);
                        }
                    }
                    continue;
                }
            }
        }
        let ended = travel_through_leaf(&mut st, &leaf, hint, obs);
        if ended {
            break;
        }
    }
    finish_march(p, &st, None, obs)
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
