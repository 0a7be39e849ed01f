//! Exact starting sides, from the mesh itself: which side of the surface a particle that has
//! none starts on, for particles anywhere (far from the surface, inside the shell of surface
//! leaves, in the creases of overlapping parts).
//!
//! The proxy alone can only guess near the surface ([`octoproxy_core::initial_side`] takes
//! the side of a surface leaf's mean plane, an approximation within a leaf of the surface);
//! a particle given the wrong side there is on the wrong side of the shell rule, and can
//! cross. With the mesh at hand, [`Sides`] decides exactly.
//!
//! # The rule
//!
//! 1. **The nearest surface.** A particle is on the side of the surface it is nearest: in
//!    front where that surface's normal (counter-clockwise) points, behind otherwise. Where
//!    the nearest point is on an edge or a corner, or several surfaces are equally near, every
//!    triangle at that distance is asked, and they decide when they agree.
//! 2. **Edges, corners and ties: the winding number.** Where they do not agree (near a sharp
//!    edge or corner, where the point is in front of one face and behind the next; where two
//!    parts meet), a closed part among them decides by its own generalized winding number:
//!    inside an outward-wound part is behind, outside it in front; for an inward-wound part
//!    (a room seen from inside: its normals point into it) the other way round. The nearest
//!    such part decides. Open parts alone decide by the angle-weighted pseudo-normal of the
//!    triangles there (Bærentzen and Aanæs 2005), which is the same answer for a manifold
//!    patch.
//! 3. **Inside other parts.** A particle in front of the surface it is nearest, but inside
//!    the closed parts of the scene taken together (their winding number, summed over every
//!    closed part, is at least ½: kitbashed parts, a peg in its hole, a fin through a plate),
//!    is behind: it is in matter, whichever face is nearest. Summed, nested shells cancel,
//!    so the cavity of a hollow ball is in front, and its wall behind.
//!
//! A point exactly on the surface is behind where the closed parts' winding number is at
//! least ½ (as the penetration harness counts it), in front otherwise. A scene with no
//! triangles puts everything in front.
//!
//! Particle files that carry a `side` keep it (it is the user's word); [`Sides::assign`]
//! counts those that contradict the mesh.

use glam::DVec3;
use glam::Vec3;
use octoproxy_core::{
    side_exit, Aabb, LeafKind, Particle, ProxyView, SIDE_BACK, SIDE_CAGED, SIDE_FRONT, SIDE_MASK,
};
use rayon::prelude::*;

use crate::bake::{edge_classes, MeshRef};
use crate::ground_truth::{GroundTruth, NearTriangle};

/// Which part of [the rule](self) decided a particle's side.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SideRule {
    /// The nearest surface (1).
    Nearest,
    /// A closed part's winding number at an edge, a corner or a tie (2).
    Winding,
    /// The pseudo-normal of open parts at an edge, a corner or a tie (2).
    PseudoNormal,
    /// Inside the closed parts taken together (3).
    InsideClosedParts,
    /// No triangles at all: front.
    NoSurface,
}

/// A particle's side and how it was decided.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SideVerdict {
    /// [`SIDE_FRONT`] or [`SIDE_BACK`].
    pub side: u32,
    /// The part of the rule that decided it.
    pub rule: SideRule,
    /// The distance to the nearest surface.
    pub distance: f64,
}

/// What [`Sides::assign`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SideCounts {
    /// Particles given a side from the mesh.
    pub assigned: usize,
    /// Particles that kept a side of their own.
    pub kept: usize,
    /// Of those, particles whose side contradicts the mesh.
    pub contradicting: usize,
    /// Particles behind the surface (after assigning).
    pub behind: usize,
    /// Particles with a non-finite position (left as they are; the step flags them).
    pub non_finite: usize,
}

/// What [`Sides::cages`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CageCounts {
    /// Particles that start strictly inside a solid leaf, now caged there.
    pub caged: usize,
    /// Of those, particles that can reach no face of their cage into an empty leaf without
    /// crossing the surface: they stay in it.
    pub without_exit: usize,
    /// Particles that kept the cage their file gave them.
    pub kept: usize,
}

/// Points per side of the grid of points on a face of a cage that [`Sides::cage`] tries to
/// reach: `CAGE_SAMPLES²` segments per face at most.
pub const CAGE_SAMPLES: usize = 4;

/// One connected part of the scene (triangles joined by shared edges).
struct Part {
    /// Every edge is used exactly once in each direction.
    closed: bool,
    /// Closed, with a negative signed volume: its normals point into it.
    inward: bool,
    /// Its own ground truth, for a closed part (an index into `Sides::truths`).
    truth: Option<usize>,
}

/// A scene's triangles prepared for exact starting sides. `Send + Sync`: ask it from many
/// threads at once.
pub struct Sides {
    /// Ground truths: every triangle, each closed part, all closed parts together; one where
    /// two of them hold the same triangles.
    truths: Vec<GroundTruth>,
    /// Per triangle of the scene (all meshes, in order): its part.
    part_of: Vec<u32>,
    parts: Vec<Part>,
    /// All closed triangles together (an index into `truths`).
    matter: Option<usize>,
    closed_parts: usize,
    /// The scene's rims for the parity of crossings: edges used by an odd number of
    /// triangles (a hole's rim, a sheet's edge, a non-manifold edge of three).
    rims: Rims,
}

impl Sides {
    /// Prepares `meshes` (the meshes of a scene, as given to [`crate::bake()`]). Triangles
    /// with an out-of-range index, a non-finite vertex or no area are left out; nothing here
    /// panics on the input.
    pub fn new(meshes: &[MeshRef<'_>]) -> Self {
        let mut positions: Vec<[f32; 3]> = Vec::new();
        let mut triangles: Vec<[u32; 3]> = Vec::new();
        let mut part_of: Vec<u32> = Vec::new();
        let mut parts: Vec<Part> = Vec::new();
        // Per part: its triangles (indices into `triangles`) and signed volume.
        let mut members: Vec<Vec<u32>> = Vec::new();
        let mut volume: Vec<f64> = Vec::new();
        for m in meshes {
            let (closed, _, component) = edge_classes(m);
            let base = positions.len() as u32;
            positions.extend_from_slice(m.positions);
            let mut local: std::collections::HashMap<u32, u32> = Default::default();
            let centre = mean_position(m.positions);
            for (ti, t) in m.triangles.iter().enumerate() {
                let valid = t.iter().all(|&i| (i as usize) < m.positions.len());
                let k = *local.entry(component[ti]).or_insert_with(|| {
                    parts.push(Part {
                        closed: closed[ti],
                        inward: false,
                        truth: None,
                    });
                    members.push(Vec::new());
                    volume.push(0.0);
                    parts.len() as u32 - 1
                });
                // An invalid triangle becomes an out-of-range one: the ground truths skip it.
                let g = if valid {
                    t.map(|i| base + i)
                } else {
                    [u32::MAX; 3]
                };
                if valid {
                    let v = t.map(|i| DVec3::from_array(m.positions[i as usize].map(f64::from)));
                    let (a, b, c) = (v[0] - centre, v[1] - centre, v[2] - centre);
                    volume[k as usize] += a.dot(b.cross(c)) / 6.0;
                }
                members[k as usize].push(triangles.len() as u32);
                triangles.push(g);
                part_of.push(k);
            }
        }
        let mut truths = vec![GroundTruth::new(&positions, &triangles)];
        let closed_parts = parts.iter().filter(|p| p.closed).count();
        let only_part = parts.len() == 1;
        let mut matter = None;
        for (k, part) in parts.iter_mut().enumerate() {
            if !part.closed {
                continue;
            }
            part.inward = volume[k] < 0.0;
            if only_part {
                part.truth = Some(0);
                matter = Some(0);
                continue;
            }
            let tris: Vec<[u32; 3]> = members[k].iter().map(|&t| triangles[t as usize]).collect();
            truths.push(GroundTruth::new(&positions, &tris));
            part.truth = Some(truths.len() - 1);
            if closed_parts == 1 {
                matter = part.truth;
            }
        }
        if closed_parts > 1 && closed_parts == parts.len() {
            // Every part closed: the closed triangles are all of them, in the same order.
            matter = Some(0);
        } else if closed_parts > 1 {
            let tris: Vec<[u32; 3]> = triangles
                .iter()
                .zip(&part_of)
                .filter(|(_, &k)| parts[k as usize].closed)
                .map(|(t, _)| *t)
                .collect();
            truths.push(GroundTruth::new(&positions, &tris));
            matter = Some(truths.len() - 1);
        }
        let rims = Rims::new(&positions, &triangles);
        Sides {
            truths,
            part_of,
            parts,
            matter,
            closed_parts,
            rims,
        }
    }

    /// The side of a particle at `p` by [the rule](self).
    pub fn side(&self, p: [f32; 3]) -> u32 {
        self.verdict(p).side
    }

    /// The side of a particle at `p`, how it was decided, and how far the surface is.
    pub fn verdict(&self, p: [f32; 3]) -> SideVerdict {
        NEAR.with(|near| {
            let mut near = near.borrow_mut();
            self.verdict_with(p, &mut near)
        })
    }

    fn verdict_with(&self, p: [f32; 3], near: &mut Vec<NearTriangle>) -> SideVerdict {
        let distance = self.truths[0].nearest_triangles(p, near);
        let verdict = |side, rule| SideVerdict {
            side,
            rule,
            distance,
        };
        if near.is_empty() {
            return verdict(SIDE_FRONT, SideRule::NoSurface);
        }
        let q = DVec3::from_array(p.map(f64::from));
        let eps = (distance + q.abs().max_element()) * 1e-12;
        // 1. The nearest surface, where every triangle at that distance agrees.
        let (mut front, mut back) = (false, false);
        for t in near.iter() {
            let s = (q - t.closest).dot(t.normal);
            front |= s > eps;
            back |= s < -eps;
        }
        let (side, rule) = if front != back {
            (if back { SIDE_BACK } else { SIDE_FRONT }, SideRule::Nearest)
        } else if let Some(side) = self.by_nearest_closed_part(p, near) {
            // 2. A closed part there decides by its winding number.
            (side, SideRule::Winding)
        } else {
            // 2. Open parts only: the angle-weighted pseudo-normal (in the plane of every
            // nearest triangle and off them, beyond an open sheet's rim: front).
            let n: DVec3 = near.iter().map(|t| t.normal * t.angle).sum();
            let s = (q - near[0].closest).dot(n);
            let side = if s < -eps || (s <= eps && distance == 0.0 && self.in_matter(p)) {
                SIDE_BACK
            } else {
                SIDE_FRONT
            };
            (side, SideRule::PseudoNormal)
        };
        // 3. In front of the nearest surface, but inside the closed parts taken together.
        let nearest_closed_alone = self.closed_parts == 1
            && near
                .iter()
                .all(|t| self.part(t.triangle).is_some_and(|k| k.closed));
        if side == SIDE_FRONT && !nearest_closed_alone && self.in_matter(p) {
            return verdict(SIDE_BACK, SideRule::InsideClosedParts);
        }
        verdict(side, rule)
    }

    fn part(&self, triangle: u32) -> Option<&Part> {
        let k = *self.part_of.get(triangle as usize)?;
        self.parts.get(k as usize)
    }

    /// The side by the winding number of the closed part of the nearest triangles (the first
    /// of them in a closed part); `None` when none is closed.
    fn by_nearest_closed_part(&self, p: [f32; 3], near: &[NearTriangle]) -> Option<u32> {
        let part = near
            .iter()
            .filter_map(|t| self.part(t.triangle))
            .find(|k| k.closed)?;
        let w = self.truths[part.truth?].winding_number(p);
        // Behind: inside an outward part, or outside an inward one (w is -1 inside it).
        let behind = if part.inward { w > -0.5 } else { w >= 0.5 };
        Some(if behind { SIDE_BACK } else { SIDE_FRONT })
    }

    /// Whether `p` is inside the closed parts taken together (their summed winding number is
    /// at least ½).
    fn in_matter(&self, p: [f32; 3]) -> bool {
        self.matter
            .is_some_and(|m| self.truths[m].winding_number(p) >= 0.5)
    }

    /// The generalized winding number of the whole scene at `p`, open parts included: about 1
    /// inside what a nearly closed open mesh encloses (a scan with holes, parts of an open
    /// model through each other), fractional near the holes.
    pub fn winding_number(&self, p: [f32; 3]) -> f64 {
        self.truths[0].winding_number(p)
    }

    /// How many triangles of the scene the segment `a → b` crosses
    /// ([`GroundTruth::segment_crossings`]).
    pub fn crossings(&self, a: [f32; 3], b: [f32; 3]) -> u32 {
        self.truths[0].segment_crossings(a, b)
    }

    /// The cage bits of a particle at `p` in `view`'s proxy ([`SIDE_CAGED`] and its exits), or
    /// 0 when it does not start strictly inside a solid (two-sided) leaf. There one side bit
    /// cannot say which of the surfaces in the leaf it is behind (parts crossing, a fold, a
    /// rim), so the step holds it in the leaf, and lets it out only through the faces it can
    /// reach from `p` without crossing the surface: a face into a single empty leaf (no
    /// triangle touches it) that a straight segment from `p` reaches, on a grid of
    /// [`CAGE_SAMPLES`]² points of the face, crossing no triangle (exactly,
    /// [`GroundTruth::segment_crossings`]). An empty leaf holds no surface, so all of it is
    /// where that segment ends: on the particle's side of every surface in the cage.
    ///
    /// A particle exactly on the surface is on neither side of it: a segment from there
    /// crosses nothing whichever way it leaves. It is on its `side` (bit 0), so the segments
    /// start a hair from it on that side (`origin_on_side`); where no such point is sure, it
    /// has no exit.
    pub fn cage(&self, view: &ProxyView<'_>, p: [f32; 3], side: u32) -> u32 {
        let x = Vec3::from_array(p);
        if !x.is_finite() {
            return 0;
        }
        let Some(leaf) = view.locate_leaf(x) else {
            return 0;
        };
        let b = leaf.aabb;
        let inside = x.cmpgt(b.min).all() && x.cmplt(b.max).all();
        if leaf.kind != LeafKind::Surface || !leaf.two_sided || !inside {
            return 0;
        }
        let mut bits = SIDE_CAGED;
        // Round a rim, a path may cross the surface once and come back to where a straight
        // segment reaches without crossing: no exit is sure there.
        if self.rims.touch(b.min.as_dvec3(), b.max.as_dvec3()) {
            return bits;
        }
        let Some(from) = self.origin_on_side(p, side & SIDE_MASK, &b) else {
            return bits;
        };
        for axis in 0..3 {
            let (u, w) = ((axis + 1) % 3, (axis + 2) % 3);
            for upper in [false, true] {
                let mut centre = (b.min + b.max) * 0.5;
                centre[axis] = if upper { b.max[axis] } else { b.min[axis] };
                let mut dir = Vec3::ZERO;
                dir[axis] = if upper { 1.0 } else { -1.0 };
                let across = view
                    .locate_leaf_toward(centre, dir)
                    .filter(|n| n.kind == LeafKind::Empty);
                let Some(n) = across else {
                    continue;
                };
                let holds_face = [u, w]
                    .iter()
                    .all(|&a| n.aabb.min[a] <= b.min[a] && n.aabb.max[a] >= b.max[a]);
                if !holds_face {
                    continue;
                }
                let reachable = (0..CAGE_SAMPLES * CAGE_SAMPLES).any(|k| {
                    let f = |i: usize| (i as f32 + 0.5) / CAGE_SAMPLES as f32;
                    let mut q = centre;
                    q[u] = b.min[u] + (b.max[u] - b.min[u]) * f(k % CAGE_SAMPLES);
                    q[w] = b.min[w] + (b.max[w] - b.min[w]) * f(k / CAGE_SAMPLES);
                    self.truths[0].segment_crossings(from, q.to_array()) == 0
                });
                if reachable {
                    bits |= side_exit(axis as u32, upper);
                }
            }
        }
        bits
    }

    /// Where a cage's segments start for a particle at `p` on `side` in the cage `b`: `p`
    /// itself when it is off the surface by more than a hair (a thousandth of the cage's
    /// size). On it (exactly on a triangle, where a segment from `p` crosses that triangle or
    /// not depending only on which way it leaves; its distance in `f64` may round to a
    /// little more than zero) or within a hair of it, the point a hair from the nearest
    /// point of the surface along the angle-weighted pseudo-normal of the triangles there
    /// (Bærentzen and Aanæs 2005), forward for the front and backward for the back, if that
    /// point is strictly inside the cage, more than half a hair from the surface, and on
    /// `side` by [the rule](self); `None` otherwise.
    fn origin_on_side(&self, p: [f32; 3], side: u32, b: &Aabb) -> Option<[f32; 3]> {
        let hair = (b.max - b.min).min_element() as f64 * 1e-3;
        let mut near = Vec::new();
        let distance = self.truths[0].nearest_triangles(p, &mut near);
        if distance > hair || near.is_empty() {
            return Some(p);
        }
        let n: DVec3 = near.iter().map(|t| t.normal * t.angle).sum();
        let n = if side == SIDE_BACK { -n } else { n }.normalize_or_zero();
        let q = (near[0].closest + n * hair).as_vec3();
        let inside = q.cmpgt(b.min).all() && q.cmplt(b.max).all();
        let verdict = self.verdict_with(q.to_array(), &mut near);
        let sure = n != DVec3::ZERO && inside && verdict.distance > 0.5 * hair;
        (sure && verdict.side == side).then_some(q.to_array())
    }

    /// Cages every particle of `particles` that starts strictly inside a solid leaf of
    /// `view`'s proxy ([`Sides::cage`]), in parallel, keeping its side; with `keep_given`, a
    /// particle already caged (a frame written mid-run) keeps its cage. Cage bits belong to the
    /// proxy they were made with: make them again for another.
    pub fn cages(
        &self,
        view: &ProxyView<'_>,
        particles: &mut [Particle],
        keep_given: bool,
    ) -> CageCounts {
        cage_each(particles, keep_given, |p| {
            self.cage(view, p.position, p.side)
        })
    }

    /// Gives every particle of `particles` its side by [the rule](self), in parallel; or, with
    /// `keep_given`, leaves each its own and counts those that contradict the mesh.
    pub fn assign(&self, particles: &mut [Particle], keep_given: bool) -> SideCounts {
        assign_each(particles, keep_given, |p, near| {
            self.verdict_with(p, near).side
        })
    }
}

/// Gives every particle of `particles` with a finite position the side `side` says, in
/// parallel (its scratch list is per thread); or, with `keep_given`, leaves each its own and
/// counts those that contradict it.
pub(crate) fn assign_each(
    particles: &mut [Particle],
    keep_given: bool,
    side: impl Fn([f32; 3], &mut Vec<NearTriangle>) -> u32 + Sync,
) -> SideCounts {
    particles
        .par_iter_mut()
        .map_init(Vec::new, |near, p| {
            let mut c = SideCounts::default();
            if !p.position.iter().all(|x| x.is_finite()) {
                c.non_finite = 1;
                return c;
            }
            let side = side(p.position, near);
            if keep_given {
                c.kept = 1;
                c.contradicting = (p.side & SIDE_MASK != side) as usize;
            } else {
                c.assigned = 1;
                p.side = side;
            }
            c.behind = (p.side & SIDE_MASK == SIDE_BACK) as usize;
            c
        })
        .reduce(SideCounts::default, |a, b| SideCounts {
            assigned: a.assigned + b.assigned,
            kept: a.kept + b.kept,
            contradicting: a.contradicting + b.contradicting,
            behind: a.behind + b.behind,
            non_finite: a.non_finite + b.non_finite,
        })
}

/// Segments (a scene's rim edges) in a bounding-volume hierarchy, for "does any touch this
/// box".
struct Rims {
    /// Segments, in the hierarchy's leaf order.
    segments: Vec<[DVec3; 2]>,
    /// Nodes: box, then the first segment and count for a leaf (`count > 0`), or the right
    /// child for an inner node (its left child follows it).
    nodes: Vec<(DVec3, DVec3, u32, u32)>,
}

impl Rims {
    /// The edges of `triangles` used by an odd number of them, vertices welded by position
    /// (triangles with an out-of-range index are left out).
    fn new(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Rims {
        let key = |i: u32| positions[i as usize].map(|x| if x == 0.0 { 0 } else { x.to_bits() });
        let mut edges: Vec<([u32; 3], [u32; 3])> = Vec::new();
        for t in triangles {
            if t.iter().any(|&i| i as usize >= positions.len()) {
                continue;
            }
            for k in 0..3 {
                let (a, b) = (key(t[k]), key(t[(k + 1) % 3]));
                if a != b {
                    edges.push(if a < b { (a, b) } else { (b, a) });
                }
            }
        }
        edges.par_sort_unstable();
        let mut segments = Vec::new();
        let mut i = 0;
        while i < edges.len() {
            let j = i + edges[i..].iter().take_while(|e| **e == edges[i]).count();
            if (j - i) % 2 == 1 {
                let p = |k: [u32; 3]| DVec3::from_array(k.map(|b| f32::from_bits(b) as f64));
                segments.push([p(edges[i].0), p(edges[i].1)]);
            }
            i = j;
        }
        let mut rims = Rims {
            segments,
            nodes: Vec::new(),
        };
        let n = rims.segments.len();
        if n > 0 {
            rims.build(0, n);
        }
        rims
    }

    fn build(&mut self, start: usize, end: usize) -> usize {
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for s in &self.segments[start..end] {
            lo = lo.min(s[0]).min(s[1]);
            hi = hi.max(s[0]).max(s[1]);
        }
        let id = self.nodes.len();
        if end - start <= 4 {
            self.nodes
                .push((lo, hi, start as u32, (end - start) as u32));
            return id;
        }
        self.nodes.push((lo, hi, 0, 0));
        let axis = (hi - lo).max_position();
        let mid = (start + end) / 2;
        self.segments[start..end].select_nth_unstable_by(mid - start, |a, b| {
            (a[0][axis] + a[1][axis]).total_cmp(&(b[0][axis] + b[1][axis]))
        });
        self.build(start, mid);
        let right = self.build(mid, end);
        self.nodes[id].2 = right as u32;
        id
    }

    /// Whether a segment touches the closed box `lo..hi` (or may, within rounding).
    fn touch(&self, lo: DVec3, hi: DVec3) -> bool {
        let mut stack = vec![0usize];
        while let Some(id) = stack.pop() {
            let Some(&(nlo, nhi, first, count)) = self.nodes.get(id) else {
                continue;
            };
            if nlo.cmpgt(hi).any() || nhi.cmplt(lo).any() {
                continue;
            }
            if count > 0 {
                let range = first as usize..(first + count) as usize;
                if self.segments[range]
                    .iter()
                    .any(|s| crate::bake::geom::segment_may_touch_box(s[0], s[1], lo, hi))
                {
                    return true;
                }
            } else {
                stack.push(id + 1);
                stack.push(first as usize);
            }
        }
        false
    }
}

thread_local! {
    static NEAR: std::cell::RefCell<Vec<NearTriangle>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// The mean of the finite positions (the origin of a part's signed volume, which keeps its
/// sum from cancelling far from the coordinate origin).
fn mean_position(positions: &[[f32; 3]]) -> DVec3 {
    let (mut sum, mut n) = (DVec3::ZERO, 0.0);
    for p in positions {
        let p = DVec3::from_array(p.map(f64::from));
        if p.is_finite() {
            sum += p;
            n += 1.0;
        }
    }
    if n > 0.0 {
        sum / n
    } else {
        DVec3::ZERO
    }
}

/// How many of `particles` start in a surface leaf of `view` (inside the shell), where a
/// side from the proxy alone is the mean plane's, an approximation within a leaf of the
/// surface.
pub fn count_in_shell(view: &ProxyView<'_>, particles: &[Particle]) -> usize {
    particles
        .par_iter()
        .filter(|p| {
            glam::Vec3::from_array(p.position).is_finite()
                && view
                    .locate_leaf(glam::Vec3::from_array(p.position))
                    .is_some_and(|l| l.kind == LeafKind::Surface)
        })
        .count()
}

/// What [`starting_sides`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StartCounts {
    /// The sides ([`Sides::assign`]).
    pub sides: SideCounts,
    /// The cages ([`Sides::cages`]).
    pub cages: CageCounts,
}

/// How many of `particles` start strictly inside a solid (two-sided) leaf of `view`, where
/// only the mesh can cage them ([`Sides::cage`]).
pub fn count_in_solid(view: &ProxyView<'_>, particles: &[Particle]) -> usize {
    particles
        .par_iter()
        .filter(|p| in_solid_leaf(view, p.position))
        .count()
}

/// Starting sides and cages against one proxy's surface, in the proxy's own frame, for
/// [`crate::starting_scene_sides`]: [`Sides`] (from a scene's meshes) or, for a proxy baked for
/// a radius, its [`crate::bake::offset::OffsetSurface`] (from the band, without the offset
/// surface's own ground truths unless a particle starts in a solid leaf).
pub trait StartSides: Sync {
    /// The side of a particle at `p`.
    fn side(&self, p: [f32; 3]) -> u32;
    /// The cage bits of a particle at `p` on `side` in `view`'s proxy.
    fn cage(&self, view: &ProxyView<'_>, p: [f32; 3], side: u32) -> u32;
}

impl StartSides for Sides {
    fn side(&self, p: [f32; 3]) -> u32 {
        Sides::side(self, p)
    }
    fn cage(&self, view: &ProxyView<'_>, p: [f32; 3], side: u32) -> u32 {
        Sides::cage(self, view, p, side)
    }
}

impl StartSides for crate::bake::offset::OffsetSurface {
    fn side(&self, p: [f32; 3]) -> u32 {
        crate::bake::offset::OffsetSurface::side(self, p)
    }
    fn cage(&self, view: &ProxyView<'_>, p: [f32; 3], side: u32) -> u32 {
        crate::bake::offset::OffsetSurface::cage(self, view, p, side)
    }
}

/// Gives every particle of `particles` the cage bits `cage` makes for it, in parallel,
/// keeping its side; with `keep_given`, a particle already caged keeps its cage.
pub(crate) fn cage_each(
    particles: &mut [Particle],
    keep_given: bool,
    cage: impl Fn(&Particle) -> u32 + Sync,
) -> CageCounts {
    particles
        .par_iter_mut()
        .map(|p| {
            let mut c = CageCounts::default();
            if keep_given && p.is_caged() {
                c.kept = 1;
                return c;
            }
            let bits = cage(p);
            p.side = (p.side & SIDE_MASK) | bits;
            if bits != 0 {
                c.caged = 1;
                c.without_exit = (bits == SIDE_CAGED) as usize;
            }
            c
        })
        .reduce(CageCounts::default, |a, b| CageCounts {
            caged: a.caged + b.caged,
            without_exit: a.without_exit + b.without_exit,
            kept: a.kept + b.kept,
        })
}

/// Whether `p` is strictly inside a solid (two-sided) surface leaf of `view`, where a
/// particle starts caged ([`Sides::cage`]).
pub fn in_solid_leaf(view: &ProxyView<'_>, p: [f32; 3]) -> bool {
    let x = Vec3::from_array(p);
    x.is_finite()
        && view.locate_leaf(x).is_some_and(|l| {
            l.kind == LeafKind::Surface
                && l.two_sided
                && x.cmpgt(l.aabb.min).all()
                && x.cmplt(l.aabb.max).all()
        })
}

/// Gives every particle its starting side from `meshes` by [the rule](self), and cages those
/// that start strictly inside a solid leaf of `view`'s proxy ([`Sides::cage`]): the function
/// beside [`crate::bake()`] for particles of your own. Build a [`Sides`] once instead to ask
/// it again, or to keep the sides particles carry and count those that contradict the mesh.
pub fn starting_sides(
    meshes: &[MeshRef<'_>],
    view: &ProxyView<'_>,
    particles: &mut [Particle],
) -> StartCounts {
    let sides = Sides::new(meshes);
    StartCounts {
        sides: sides.assign(particles, false),
        cages: sides.cages(view, particles, false),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::emit::Rng;
    use crate::io::Mesh;
    use crate::scenes::{self, MeshExt};
    use glam::Vec3;

    fn sides_of(meshes: &[Mesh]) -> Sides {
        let refs: Vec<MeshRef<'_>> = meshes.iter().map(MeshRef::from).collect();
        Sides::new(&refs)
    }

    fn flipped(m: &Mesh) -> Mesh {
        let mut m = m.clone();
        for t in &mut m.triangles {
            t.swap(1, 2);
        }
        m
    }

    /// Random points within `reach` of the vertices and edge midpoints of `meshes` (where
    /// edges, corners and the creases of overlapping parts are), and some farther out.
    fn points_near(meshes: &[Mesh], reach: f32, n: usize, seed: u64) -> Vec<[f32; 3]> {
        let mut anchors = Vec::new();
        for m in meshes {
            for t in &m.triangles {
                let v = t.map(|i| Vec3::from_array(m.positions[i as usize]));
                anchors.extend([v[0], (v[0] + v[1]) * 0.5, (v[0] + v[1] + v[2]) / 3.0]);
            }
        }
        let mut rng = Rng::new(seed);
        (0..n)
            .map(|i| {
                let a = anchors[(rng.next_u64() % anchors.len() as u64) as usize];
                let r = if i % 10 == 0 { 20.0 * reach } else { reach };
                (a + rng.unit_vector() * rng.range(0.0, r)).to_array()
            })
            .collect()
    }

    /// Outward-wound closed parts, overlapping or not: behind exactly where inside them.
    fn agrees_with_winding(meshes: &[Mesh], reach: f32) {
        let sides = sides_of(meshes);
        let all = scenes::merge(meshes);
        let gt = GroundTruth::new(&all.positions, &all.triangles);
        let mut wrong = Vec::new();
        for p in points_near(meshes, reach, 4000, 7) {
            let w = gt.winding_number(p);
            if (w - 0.5).abs() < 1e-6 {
                continue; // on the surface
            }
            let v = sides.verdict(p);
            if (v.side == SIDE_BACK) != (w >= 0.5) {
                wrong.push((p, w, v));
            }
        }
        assert!(
            wrong.is_empty(),
            "{} wrong, e.g. {:?}",
            wrong.len(),
            &wrong[..wrong.len().min(3)]
        );
    }

    #[test]
    fn closed_parts_are_behind_exactly_where_their_winding_number_says_inside() {
        agrees_with_winding(&[scenes::cube([0.0; 3], [1.0; 3])], 0.05);
        agrees_with_winding(&[scenes::uv_sphere([0.0; 3], 1.0, 24, 12)], 0.05);
        agrees_with_winding(&[scenes::star_prism(7, 1.5, 0.4, 1.0)], 0.05);
        agrees_with_winding(&[scenes::wedge(8.0, 2.0, 1.0)], 0.02);
        agrees_with_winding(&[scenes::torus([0.0; 3], 1.0, 0.3, 24, 12)], 0.05);
    }

    #[test]
    fn overlapping_parts_are_behind_inside_any_of_them() {
        let plate = scenes::slab([0.0; 3], [2.0, 0.2, 2.0]);
        let fins: Vec<Mesh> = (0..4)
            .map(|i| scenes::slab([i as f32 * 0.4 - 0.6, 0.2, 0.0], [0.02, 0.8, 1.5]))
            .collect();
        let mut parts = vec![plate];
        parts.extend(fins);
        agrees_with_winding(&parts, 0.05);
        let boxes = [
            scenes::cube([0.0; 3], [1.0; 3]),
            scenes::cube([0.5, 0.3, 0.2], [1.5, 0.7, 0.8]),
        ];
        agrees_with_winding(&boxes, 0.05);
        // A peg in a hole that fits it, touching face to face.
        let peg = scenes::cube([0.4, 0.0, 0.4], [0.6, 1.5, 0.6]);
        let ring: Vec<Mesh> = [
            ([0.0, 0.0, 0.0], [0.4, 0.5, 1.0]),
            ([0.6, 0.0, 0.0], [1.0, 0.5, 1.0]),
            ([0.4, 0.0, 0.0], [0.6, 0.5, 0.4]),
            ([0.4, 0.0, 0.6], [0.6, 0.5, 1.0]),
        ]
        .iter()
        .map(|&(a, b)| scenes::cube(a, b))
        .collect();
        let mut parts = vec![peg];
        parts.extend(ring);
        agrees_with_winding(&parts, 0.05);
    }

    #[test]
    fn a_point_in_front_of_a_fin_inside_the_plate_is_behind() {
        let parts = [
            scenes::slab([0.0; 3], [2.0, 0.2, 2.0]),
            scenes::slab([0.0, 0.3, 0.0], [0.02, 0.8, 1.5]),
        ];
        let sides = sides_of(&parts);
        // Inside the plate, a hair in front of the fin's face: the fin's face is nearest.
        let v = sides.verdict([0.015, -0.05, 0.0]);
        assert_eq!((v.side, v.rule), (SIDE_BACK, SideRule::InsideClosedParts));
        // Above the plate, in front of the fin.
        assert_eq!(sides.side([0.015, 0.15, 0.0]), SIDE_FRONT);
    }

    #[test]
    fn nested_shells_flipped_windings_and_rooms() {
        // A hollow ball: the cavity is in front of the inner wall, the wall behind.
        let shells = sides_of(&[scenes::nested_shells(1.0, 0.05)]);
        assert_eq!(shells.side([0.0, 0.0, 0.0]), SIDE_FRONT);
        assert_eq!(shells.side([0.0, 0.94, 0.0]), SIDE_FRONT);
        assert_eq!(shells.side([0.0, 0.975, 0.0]), SIDE_BACK);
        assert_eq!(shells.side([0.0, 1.01, 0.0]), SIDE_FRONT);
        // A room seen from inside (a cube wound inward) with a box in it: in front inside the
        // room, behind outside it and inside the box; at its corners too.
        let room = flipped(&scenes::cube([0.0; 3], [4.0; 3]));
        let sides = sides_of(&[room.clone(), scenes::cube([1.0; 3], [2.0; 3])]);
        for (p, side) in [
            ([0.01, 0.01, 0.01], SIDE_FRONT),
            ([-0.01, -0.01, -0.01], SIDE_BACK),
            ([-0.01, 0.5, 0.5], SIDE_BACK),
            ([3.99, 0.5, 0.01], SIDE_FRONT),
            ([0.99, 0.99, 0.99], SIDE_FRONT),
            ([1.01, 1.01, 1.01], SIDE_BACK),
            ([1.5, 1.5, 1.5], SIDE_BACK),
            ([9.0, 9.0, 9.0], SIDE_BACK),
        ] {
            assert_eq!(sides.side(p), side, "{p:?}");
        }
        // A flipped sphere alone: behind outside, in front inside.
        let s = sides_of(&[flipped(&scenes::uv_sphere([0.0; 3], 1.0, 24, 12))]);
        assert_eq!(s.side([0.0, 0.0, 0.0]), SIDE_FRONT);
        assert_eq!(s.side([0.0, 0.0, 1.2]), SIDE_BACK);
        assert!(room.is_closed());
    }

    #[test]
    fn open_sheets_by_their_normal_and_pseudo_normal() {
        let sheet = scenes::flat_sheet([0.0; 3], 2.0, 4); // normal +y
        let sides = sides_of(&[sheet]);
        assert_eq!(sides.side([0.3, 0.01, 0.2]), SIDE_FRONT);
        assert_eq!(sides.side([0.3, -0.01, 0.2]), SIDE_BACK);
        // Over a vertex shared by several triangles.
        assert_eq!(sides.side([0.0, -1e-3, 0.0]), SIDE_BACK);
        // In its plane beyond its rim.
        let v = sides.verdict([1.5, 0.0, 0.0]);
        assert_eq!((v.side, v.rule), (SIDE_FRONT, SideRule::PseudoNormal));
        let none = sides_of(&[]);
        assert_eq!(none.verdict([0.0; 3]).rule, SideRule::NoSurface);
    }

    #[test]
    fn assign_gives_sides_or_counts_contradictions() {
        let m = scenes::cube([0.0; 3], [1.0; 3]);
        let refs = [MeshRef::from(&m)];
        let mut ps = vec![
            Particle::new([0.5, 0.5, 0.5], [0.0; 3]),
            Particle::new([0.5, 1.001, 0.5], [0.0; 3]),
            Particle::new([f32::NAN, 0.0, 0.0], [0.0; 3]),
        ];
        let (words, _) = crate::bake(&refs, &crate::BuildParams::default(), &()).unwrap();
        let view = ProxyView::new(&words).unwrap();
        let c = starting_sides(&refs, &view, &mut ps);
        assert_eq!(
            (c.sides.assigned, c.sides.behind, c.sides.non_finite),
            (2, 1, 1)
        );
        assert_eq!((ps[0].side, ps[1].side), (SIDE_BACK, SIDE_FRONT));
        ps[0].side = SIDE_FRONT;
        let c = Sides::new(&refs).assign(&mut ps, true);
        assert_eq!((c.kept, c.contradicting), (2, 1));
        assert_eq!(ps[0].side, SIDE_FRONT, "a given side is kept");
    }

    /// Two open sheets crossing along the z axis (an X seen along z), 60° apart.
    fn crossing_sheets() -> Vec<Mesh> {
        let a = scenes::flat_sheet([0.0; 3], 2.0, 4);
        let b = scenes::rotated(&a, 60.0, 0.0);
        vec![a, b]
    }

    #[test]
    fn particles_caged_where_sheets_cross_leave_only_without_crossing_them() {
        use crate::harness::run_check;
        use octoproxy_core::{StepParams, SIDE_EXITS_MASK};
        let parts = crossing_sheets();
        let refs: Vec<MeshRef<'_>> = parts.iter().map(MeshRef::from).collect();
        let params = crate::BuildParams {
            dmax: 6,
            ..crate::BuildParams::default()
        };
        let (words, _) = crate::bake(&refs, &params, &()).unwrap();
        let view = ProxyView::new(&words).unwrap();
        let sides = Sides::new(&refs);
        let all = scenes::merge(&parts);
        let gt = GroundTruth::new(&all.positions, &all.triangles);
        let leaf = view.finest_leaf_size();
        // Within a leaf of the crossing line, away from the sheets' rims.
        let mut rng = Rng::new(11);
        let mut ps = Vec::new();
        for _ in 0..100_000 {
            if ps.len() == 600 {
                break;
            }
            let x = [
                rng.range(-leaf, leaf),
                rng.range(-leaf, leaf),
                rng.range(-0.6, 0.6),
            ];
            let bits = sides.cage(&view, x, sides.side(x));
            if bits == 0 {
                continue;
            }
            let v = rng.unit_vector() * leaf * rng.range(1.0, 40.0) * 60.0;
            let mut p = Particle::new(x, v.to_array());
            p.side = sides.side(x) | bits;
            ps.push(p);
        }
        assert_eq!(
            ps.len(),
            600,
            "too few particles in solid leaves by the crossing"
        );
        let with_exits = ps.iter().filter(|p| p.side & SIDE_EXITS_MASK != 0).count();
        assert!(
            with_exits > 300,
            "only {with_exits} of 600 cages have an exit"
        );
        for params in [
            StepParams {
                gravity: [0.0; 3],
                restitution: 1.0,
                friction: 0.0,
                ..StepParams::default()
            },
            StepParams::default(),
        ] {
            let mut run = ps.clone();
            let r = run_check(&view, &gt, &mut run, 60, &params, false);
            assert_eq!(r.penetrations, 0, "{:?}", r.examples);
            let left = run.iter().filter(|p| !p.is_caged()).count();
            assert!(left > 200, "only {left} of 600 left their cages");
        }
        // Counted as `cages` counts them.
        let mut again: Vec<Particle> = ps
            .iter()
            .map(|p| Particle::new(p.position, [0.0; 3]))
            .collect();
        let c = sides.cages(&view, &mut again, false);
        assert_eq!((c.caged, c.kept), (600, 0));
        assert_eq!(c.without_exit, 600 - with_exits);
        assert!(again
            .iter()
            .zip(&ps)
            .all(|(a, b)| a.side & !SIDE_MASK == b.side & !SIDE_MASK));
    }

    #[test]
    fn a_particle_exactly_on_the_surface_leaves_its_cage_only_to_its_own_side() {
        // A peg through a plate: solid leaves where their faces meet. Points exactly on the
        // axis-aligned faces (a segment from there crosses nothing whichever way it goes),
        // given either side: every exit leads to a leaf on that side, and both sides have
        // some. Found by the penetration campaign: a particle on a box's face, in front of
        // it, left its cage into the box.
        let plate = scenes::cube([-0.5, -0.1, -0.5], [0.5, 0.1, 0.5]);
        let peg = scenes::cube([-0.13, -0.6, -0.13], [0.13, 0.6, 0.13]);
        let refs = [MeshRef::from(&plate), MeshRef::from(&peg)];
        let params = crate::BuildParams {
            dmax: 5,
            ..crate::BuildParams::default()
        };
        let (words, _) = crate::bake(&refs, &params, &()).unwrap();
        let view = ProxyView::new(&words).unwrap();
        let sides = Sides::new(&refs);
        let mut rng = Rng::new(3);
        let mut with_exits = [0; 2];
        for k in 0..4000 {
            // On the plate's top face, or on the peg's face at x = 0.13.
            let x = if k % 2 == 0 {
                [rng.range(-0.5, 0.5), 0.1, rng.range(-0.5, 0.5)]
            } else {
                [0.13, rng.range(-0.6, 0.6), rng.range(-0.13, 0.13)]
            };
            for side in [SIDE_FRONT, SIDE_BACK] {
                let bits = sides.cage(&view, x, side);
                for axis in 0..3u32 {
                    for upper in [false, true] {
                        if bits & side_exit(axis, upper) == 0 {
                            continue;
                        }
                        let cage = view.locate_leaf(Vec3::from_array(x)).unwrap();
                        let mut dir = Vec3::ZERO;
                        dir[axis as usize] = if upper { 1.0 } else { -1.0 };
                        let mut face = (cage.aabb.min + cage.aabb.max) * 0.5;
                        face[axis as usize] = if upper {
                            cage.aabb.max[axis as usize]
                        } else {
                            cage.aabb.min[axis as usize]
                        };
                        let across = view.locate_leaf_toward(face, dir).unwrap();
                        let centre = (across.aabb.min + across.aabb.max) * 0.5;
                        assert_eq!(
                            sides.side(centre.to_array()),
                            side,
                            "{x:?} on side {side} leaves its cage {:?} by axis {axis} upper {upper} into {:?}",
                            cage.aabb,
                            across.aabb
                        );
                        with_exits[side as usize] += 1;
                    }
                }
            }
        }
        assert!(
            with_exits.iter().all(|&n| n > 20),
            "too few exits to check: {with_exits:?}"
        );
    }

    #[test]
    fn a_cage_a_rim_passes_through_has_no_exit() {
        // Round a sheet's rim a path can cross the sheet and come back to where a straight
        // segment reaches without crossing: no face of the cage is a sure exit.
        let sheet = scenes::flat_sheet([0.0; 3], 2.0, 4);
        let refs = [MeshRef::from(&sheet)];
        let (words, _) = crate::bake(&refs, &crate::BuildParams::default(), &()).unwrap();
        let view = ProxyView::new(&words).unwrap();
        let sides = Sides::new(&refs);
        let leaf = view.finest_leaf_size();
        let mut found = 0;
        let mut rng = Rng::new(5);
        for _ in 0..2000 {
            let x = [
                1.0 + rng.range(-leaf, leaf),
                rng.range(-leaf, leaf),
                rng.range(-0.9, 0.9),
            ];
            let bits = sides.cage(&view, x, sides.side(x));
            if bits != 0 {
                found += 1;
                assert_eq!(bits, SIDE_CAGED, "at {x:?}");
            }
        }
        assert!(
            found > 100,
            "only {found} particles in the rim's solid leaves"
        );
        // Not in a solid leaf: no cage; nor at a non-finite position.
        assert_eq!(sides.cage(&view, [0.3, 0.5, 0.3], SIDE_FRONT), 0);
        assert_eq!(sides.cage(&view, [f32::NAN, 0.0, 0.0], SIDE_FRONT), 0);
    }
}
