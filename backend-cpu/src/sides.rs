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
use octoproxy_core::{LeafKind, Particle, ProxyView, SIDE_BACK, SIDE_FRONT};
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
        if closed_parts > 1 {
            let tris: Vec<[u32; 3]> = triangles
                .iter()
                .zip(&part_of)
                .filter(|(_, &k)| parts[k as usize].closed)
                .map(|(t, _)| *t)
                .collect();
            truths.push(GroundTruth::new(&positions, &tris));
            matter = Some(truths.len() - 1);
        }
        Sides {
            truths,
            part_of,
            parts,
            matter,
            closed_parts,
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

    /// Gives every particle of `particles` its side by [the rule](self), in parallel; or, with
    /// `keep_given`, leaves each its own and counts those that contradict the mesh.
    pub fn assign(&self, particles: &mut [Particle], keep_given: bool) -> SideCounts {
        particles
            .par_iter_mut()
            .map_init(Vec::new, |near, p| {
                let mut c = SideCounts::default();
                if !p.position.iter().all(|x| x.is_finite()) {
                    c.non_finite = 1;
                    return c;
                }
                let side = self.verdict_with(p.position, near).side;
                if keep_given {
                    c.kept = 1;
                    let own = if p.side == SIDE_BACK {
                        SIDE_BACK
                    } else {
                        SIDE_FRONT
                    };
                    c.contradicting = (own != side) as usize;
                } else {
                    c.assigned = 1;
                    p.side = side;
                }
                c.behind = (p.side == SIDE_BACK) as usize;
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

/// Gives every particle its starting side from `meshes` by [the rule](self): the function
/// beside [`crate::bake()`] for particles of your own. Build a [`Sides`] once instead to ask
/// it again, or to keep the sides particles carry and count those that contradict the mesh.
pub fn starting_sides(meshes: &[MeshRef<'_>], particles: &mut [Particle]) -> SideCounts {
    Sides::new(meshes).assign(particles, false)
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
        let c = starting_sides(&refs, &mut ps);
        assert_eq!((c.assigned, c.behind, c.non_finite), (2, 1, 1));
        assert_eq!((ps[0].side, ps[1].side), (SIDE_BACK, SIDE_FRONT));
        ps[0].side = SIDE_FRONT;
        let c = Sides::new(&refs).assign(&mut ps, true);
        assert_eq!((c.kept, c.contradicting), (2, 1));
        assert_eq!(ps[0].side, SIDE_FRONT, "a given side is kept");
    }
}
