//! What users would pick instead of octoproxy, behind one interface, for the benchmarks
//! (`cargo xtask bench`) and their tests: a triangle-list octree with exact segment tests
//! (the paper's own baseline), parry3d's `TriMesh` ray casts, and a signed-distance grid.
//!
//! Every method steps a particle exactly as core's `step_particle` integrates it
//! (semi-implicit Euler: `v += g dt`, then move along `v` for `dt`), colliding with the mesh
//! on the way and responding with core's [`octoproxy_core::respond`] (same restitution and
//! friction), so that only the collision structure differs.

use octoproxy_core::{Particle, StepParams};

/// A collision method that steps particles against one scene.
pub trait Method: Send + Sync {
    /// The name used in benchmark output (`triangle-octree`, `parry3d`, `sdf-grid`).
    fn name(&self) -> &'static str;

    /// Bytes of the collision structure (not counting the input mesh unless the method
    /// needs to keep it).
    fn memory_bytes(&self) -> usize;

    /// Advances one particle by `params.dt`. Never panics, whatever the particle holds.
    fn step(&self, p: &mut Particle, params: &StepParams) {
        self.step_traced(p, params, &mut |_, _| {});
    }

    /// [`Method::step`], calling `trace(from, to)` for every straight piece of the particle's
    /// path in the step, in order (a move that is put rather than travelled, as the signed
    /// distance grid's push out, is a piece too): what the bench's penetration check follows.
    fn step_traced(&self, p: &mut Particle, params: &StepParams, trace: &mut dyn FnMut(Vec3, Vec3));
}

pub mod parry;
pub mod sdf_grid;
pub mod triangle_octree;

use glam::{DVec3, Vec3};
use octoproxy_core::{
    respond, COLLISION_SHIFT, FLAG_BOUND_HIT, FLAG_INVALID, FLAG_STATUS_MASK, FLAG_STEP_STATUS,
    MAX_COLLISIONS,
};

/// Bounces one step may have in the ray-casting methods; at the next hit the particle stops
/// where it is (and gets [`FLAG_BOUND_HIT`]).
pub const MAX_BOUNCES: u32 = 16;

/// A hit of a cast: the fraction `t` in `[0, 1]` of the displacement at which it hits, and
/// the (not necessarily unit, not necessarily oriented) normal of the surface there.
pub(crate) type Hit = Option<(f64, DVec3)>;

/// Vertices and triangles with the ones a method cannot use left out: indices past the
/// vertex list, non-finite vertices, and triangles of zero area (in `f64`). Returns the kept
/// triangles and how many were dropped.
pub(crate) fn valid_triangles(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
) -> (Vec<[u32; 3]>, usize) {
    let kept: Vec<[u32; 3]> = triangles
        .iter()
        .filter(|t| {
            t.iter().all(|&i| {
                positions
                    .get(i as usize)
                    .is_some_and(|p| p.iter().all(|c| c.is_finite()))
            }) && {
                let v = t.map(|i| DVec3::from_array(positions[i as usize].map(f64::from)));
                let n = (v[1] - v[0]).cross(v[2] - v[0]);
                n.length_squared() > 0.0 && n.is_finite()
            }
        })
        .copied()
        .collect();
    let dropped = triangles.len() - kept.len();
    (kept, dropped)
}

/// The distance a ray-casting method keeps a particle off the surface it hit: a millionth of
/// the scene's diagonal, and at least 4 `f32` ulps of its largest coordinate, so the rounded
/// position stays on the particle's side.
pub(crate) fn standoff(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> f64 {
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for t in triangles {
        for &i in t {
            let p = DVec3::from_array(positions[i as usize].map(f64::from));
            lo = lo.min(p);
            hi = hi.max(p);
        }
    }
    if !lo.is_finite() || !hi.is_finite() {
        return 1e-6;
    }
    let diag = (hi - lo).length();
    let mag = lo.abs().max(hi.abs()).max_element();
    (diag * 1e-6)
        .max(mag * 4.0 * f64::from(f32::EPSILON))
        .max(f64::from(f32::MIN_POSITIVE))
}

/// Writes the end of a step into `p` the way core's `step_particle` does: position,
/// velocity, the saturating collision count, and the step status bits (only
/// [`FLAG_BOUND_HIT`] here). `x` and `v` must be finite, or the particle is marked invalid and
/// left as it was.
pub(crate) fn finish(
    p: &mut octoproxy_core::Particle,
    x: Vec3,
    v: Vec3,
    collisions: u32,
    bound_hit: bool,
) {
    if !x.is_finite() || !v.is_finite() {
        p.flags |= FLAG_INVALID;
        return;
    }
    p.position = x.to_array();
    p.velocity = v.to_array();
    let count = (p.collisions().saturating_add(collisions)).min(MAX_COLLISIONS);
    let mut status = p.flags & FLAG_STATUS_MASK & !FLAG_STEP_STATUS;
    if bound_hit {
        status |= FLAG_BOUND_HIT;
    }
    p.flags = status | count << COLLISION_SHIFT;
}

/// The step of the ray-casting methods: integrate as core does (`v += g dt`), then cast the
/// displacement `v * remaining` from the particle with `cast(x, d)`; at the nearest hit, turn
/// the normal against the velocity (so both sides collide), put the particle back along its
/// path until it is `standoff` off the surface (never behind where the piece started, so it
/// stays on its side), respond with core's `respond`, and go on with the time left. After
/// [`MAX_BOUNCES`] bounces the next hit stops the particle where it is.
pub(crate) fn step_by_casting(
    p: &mut octoproxy_core::Particle,
    params: &octoproxy_core::StepParams,
    standoff: f64,
    cast: impl Fn(DVec3, DVec3) -> Hit,
    trace: &mut dyn FnMut(Vec3, Vec3),
) {
    let x0 = Vec3::from_array(p.position);
    let v0 = Vec3::from_array(p.velocity);
    if !x0.is_finite() || !v0.is_finite() {
        p.flags |= FLAG_INVALID;
        return;
    }
    let mut v = v0 + Vec3::from_array(params.gravity) * params.dt;
    let mut x = x0;
    let mut remaining = params.dt;
    let mut collisions = 0u32;
    let mut bound_hit = false;
    if !v.is_finite() {
        p.flags |= FLAG_INVALID;
        return;
    }
    for bounce in 0..=MAX_BOUNCES {
        if remaining.is_nan() || remaining <= 0.0 {
            break;
        }
        let d = (v * remaining).as_dvec3();
        let len = d.length();
        if !len.is_finite() || len <= 0.0 {
            break;
        }
        let xd = x.as_dvec3();
        let Some((t, n)) = cast(xd, d) else {
            let end = (xd + d).as_vec3();
            trace(x, end);
            x = end;
            break;
        };
        if bounce == MAX_BOUNCES {
            bound_hit = true;
            break;
        }
        let dir = d / len;
        let mut n = n.normalize_or_zero();
        if n == DVec3::ZERO || !n.is_finite() {
            n = -dir;
        }
        if n.dot(d) > 0.0 {
            n = -n;
        }
        // Back along the path until `standoff` off the plane (or at most 100 standoffs along
        // the path for a grazing hit).
        let cos = (-n.dot(dir)).max(0.01);
        let t_back = (t.clamp(0.0, 1.0) - standoff / cos / len).max(0.0);
        let back = (xd + d * t_back).as_vec3();
        trace(x, back);
        x = back;
        remaining *= (1.0 - t_back) as f32;
        v = respond(v, n.as_vec3(), params.restitution, params.friction);
        collisions += 1;
    }
    finish(p, x, v, collisions, bound_hit);
}
