//! Front/back labels of the empty leaves that touch the surface: the view-visible method of
//! the paper's section 3.2, applied to every (surface leaf, touching empty leaf) pair.
//!
//! For a pair, `Pe` is the centre of the boundary the two closed boxes share (a face, an
//! edge or a corner: every kind of contact is labelled, whatever the two leaves' sizes, so
//! that a particle leaving the shell always lands in a labelled leaf). Segments run from
//! `Pe` to up to [`SAMPLES`] points `Pb` on the surface leaf's triangles (the nearest ones);
//! the triangle hit nearest `Pe` votes front when its normal faces `Pe`, back otherwise.
//! The whole segment lies in the surface leaf's box, and every triangle that touches that
//! box is in its list, so the nearest hit is exact.
//!
//! **Conflicts.** Two surfaces can see one empty leaf from different sides (thin gaps, holes,
//! overlapping parts). Votes of triangles from closed components outrank votes from open
//! ones: a leaf is labelled by the closed votes if it has any, else by the open ones. Within
//! a rank the majority wins and a tie is labelled back. Where votes disagree at all, one side
//! bit cannot be right for every surface there (self-intersections, overlapping parts, thin
//! gaps between opposite faces), so every surface leaf that touches such an empty leaf is made
//! two-sided: solid from every side, whatever the particle's side.
//!
//! **Votes against the leaf's normal.** A label is the side of the surface that decided it,
//! but a step reads it against the surface leaf's one normal. Where the deciding surface faces
//! against that normal (a leaf holding surfaces that face both ways, the other way in the
//! majority: the wall of a hollow ball where it passes a face of an overlapping box), the
//! label means the other side of the leaf's plane, and a particle it stamps would pass through
//! the surface it faces. Such a surface leaf is made two-sided too.

use std::collections::HashMap;

use glam::{DVec3, UVec3};
use octoproxy_core::Label;
use rayon::prelude::*;

use super::flat::{Flat, Kind, Surface};
use super::{geom, BuildProgress, Grid, Tri, REUSE_TRIANGLES};
use crate::ground_truth::GroundTruth;

/// Segments cast per (surface leaf, empty leaf) pair.
pub(crate) const SAMPLES: usize = 3;

pub(crate) struct Labels {
    /// Label per `parent * 8 + octant`, as label bits.
    bits: Vec<u8>,
    /// Per flat node: a surface leaf next to an empty leaf whose votes disagree.
    conflicted: Vec<bool>,
    pub labelled: usize,
    pub conflicts: usize,
}

impl Labels {
    /// Whether surface leaf `node` touches an empty leaf whose votes disagree: one side bit
    /// cannot be right for every surface there, so the leaf must be solid from every side.
    pub fn conflicted(&self, node: u32) -> bool {
        self.conflicted.get(node as usize).copied().unwrap_or(false)
    }

    pub fn get(&self, empty_id: u32) -> Label {
        match self.bits.get(empty_id as usize) {
            Some(1) => Label::Front,
            Some(2) => Label::Back,
            _ => Label::None,
        }
    }
}

/// One vote of a surface leaf for an empty leaf (`parent * 8 + octant`), in 8 bytes: a bake
/// of a few hundred thousand surface leaves holds millions of them at once.
#[derive(Clone, Copy)]
struct Vote {
    empty: u32,
    /// [`Vote::FRONT`], [`Vote::CLOSED`] and [`Vote::AGAINST`].
    bits: u8,
}

impl Vote {
    /// The triangle hit nearest the empty leaf faces it.
    const FRONT: u8 = 1;
    /// That triangle is in a closed component.
    const CLOSED: u8 = 2;
    /// The surface that decided the vote faces against the surface leaf's normal.
    const AGAINST: u8 = 4;

    fn new(empty: u32, (front, closed, against): (bool, bool, bool)) -> Self {
        let flag = |on: bool, bit: u8| if on { bit } else { 0 };
        Self {
            empty,
            bits: flag(front, Self::FRONT)
                | flag(closed, Self::CLOSED)
                | flag(against, Self::AGAINST),
        }
    }

    fn front(self) -> bool {
        self.bits & Self::FRONT != 0
    }

    fn closed(self) -> bool {
        self.bits & Self::CLOSED != 0
    }

    fn against(self) -> bool {
        self.bits & Self::AGAINST != 0
    }
}

/// A surface leaf's votes across the bake's passes (leaves of at least [`REUSE_TRIANGLES`]),
/// by its depth and cell: per touching
/// empty leaf (its closed box in plane indices), each segment's `(front, closed, against)`.
/// They depend on the two leaves alone (a leaf's triangles are those that meet its box), so
/// a pair met again in the next pass votes as before.
#[derive(Default)]
pub(crate) struct VoteCache(HashMap<LeafKey, Vec<PairVotes>>);

/// A leaf's depth and cell.
type LeafKey = (u32, [u32; 3]);

/// A surface leaf's pairs' votes, for [`VoteCache`].
type LeafPairs = Option<(LeafKey, Vec<PairVotes>)>;

/// The votes of one (surface leaf, empty leaf) pair.
#[derive(Clone, Copy)]
struct PairVotes {
    empty: (UVec3, UVec3),
    votes: [(bool, bool, bool); SAMPLES],
    len: u8,
}

impl PairVotes {
    /// The order of a leaf's pairs in the cache: by the empty leaf's box.
    fn order(&self) -> ([u32; 3], [u32; 3]) {
        (self.empty.0.to_array(), self.empty.1.to_array())
    }
}

pub(crate) fn label(
    tree: &Flat,
    tris: &[Tri],
    grid: &Grid,
    matter: Option<&GroundTruth>,
    cache: &mut VoteCache,
    progress: &dyn BuildProgress,
) -> Labels {
    progress.begin("label", tree.surface.len() as u64);
    let known = &cache.0;
    let found: Vec<(Vec<Vote>, LeafPairs)> = tree
        .surface
        .par_iter()
        .map(|&leaf| {
            let v = leaf_votes(tree, leaf, tris, grid, known);
            progress.advance(1);
            v
        })
        .collect();
    // Each surface leaf's votes stay in its own list (`tree.surface`'s order): the counts,
    // the centres and the conflicts below do not depend on the order of the votes.
    let mut next = HashMap::new();
    let mut lists = Vec::with_capacity(found.len());
    for (v, pairs) in found {
        lists.push(v);
        next.extend(pairs);
    }
    let votes = || {
        tree.surface
            .iter()
            .zip(&lists)
            .flat_map(|(&s, l)| l.iter().map(move |&v| (s, v)))
    };
    cache.0 = next;
    // counts: closed front, closed back, open front, open back.
    let mut counts = vec![[0u32; 4]; tree.nodes.len() * 8];
    for (_, v) in votes() {
        let k = (!v.closed() as usize) * 2 + (!v.front() as usize);
        counts[v.empty as usize][k] += 1;
    }
    // Inside other parts: an empty leaf that a closed surface sees from its front, but that
    // lies inside the closed parts taken together, is in matter (a leaf inside a plate beside
    // a fin through it), and its label is back. Empty leaves hold no triangles, so the winding
    // number at the centre holds for the whole leaf.
    let mut in_matter = vec![false; counts.len()];
    if let Some(gt) = matter {
        let mut empties: Vec<u32> = votes()
            .filter(|(_, v)| v.closed() && v.front())
            .map(|(_, v)| v.empty)
            .collect();
        empties.sort_unstable();
        empties.dedup();
        let inside: Vec<u32> = empties
            .par_iter()
            .filter(|&&e| gt.is_inside(empty_centre(tree, grid, e).as_vec3().to_array()))
            .copied()
            .collect();
        for e in inside {
            in_matter[e as usize] = true;
        }
    }
    let mut labelled = 0;
    let mut conflicts = 0;
    let disagree = |c: &[u32; 4]| (c[0] + c[2] > 0) && (c[1] + c[3] > 0);
    let mut conflicted = vec![false; tree.nodes.len()];
    for (surface, v) in votes() {
        if v.against() || in_matter[v.empty as usize] || disagree(&counts[v.empty as usize]) {
            conflicted[surface as usize] = true;
        }
    }
    let bits = counts
        .iter()
        .zip(&in_matter)
        .map(|(c, &in_matter)| {
            if in_matter {
                labelled += 1;
                conflicts += 1;
                return Label::Back.bits() as u8;
            }
            let (front, back) = if c[0] + c[1] > 0 {
                (c[0], c[1])
            } else {
                (c[2], c[3])
            };
            if front + back == 0 {
                return 0u8;
            }
            labelled += 1;
            if disagree(c) {
                conflicts += 1;
            }
            if front > back {
                Label::Front.bits() as u8
            } else {
                Label::Back.bits() as u8
            }
        })
        .collect();
    Labels {
        bits,
        conflicted,
        labelled,
        conflicts,
    }
}

/// The votes of surface leaf `leaf` with every empty leaf it touches, and its pairs' votes
/// for the next pass (`known`: the last pass's).
fn leaf_votes(
    tree: &Flat,
    leaf: u32,
    tris: &[Tri],
    grid: &Grid,
    known: &HashMap<LeafKey, Vec<PairVotes>>,
) -> (Vec<Vote>, LeafPairs) {
    let node = &tree.nodes[leaf as usize];
    let Kind::Surface(surface) = &node.kind else {
        return (Vec::new(), None);
    };
    let key = (node.depth, node.cell.to_array());
    let heavy = surface.tris.len() >= REUSE_TRIANGLES;
    let was = heavy.then(|| known.get(&key)).flatten();
    let (lo, hi) = node.range();
    let mut out = Vec::new();
    let mut pairs = Vec::new();
    // The leaf's triangles' boxes, found once for all its pairs' segments.
    let mut boxes = None;
    tree.for_each_touching_empty(lo, hi, |empty, elo, ehi| {
        let found = was.and_then(|w| {
            let at = (elo.to_array(), ehi.to_array());
            w.binary_search_by(|p| p.order().cmp(&at))
                .ok()
                .map(|i| w[i])
        });
        let pair = found.unwrap_or_else(|| {
            let boxes = boxes.get_or_insert_with(|| boxes_of(&surface.tris, tris));
            pair_votes(surface, boxes, (lo, hi), (elo, ehi), tris, grid)
        });
        out.extend(
            pair.votes[..pair.len as usize]
                .iter()
                .map(|&vote| Vote::new(empty, vote)),
        );
        if heavy {
            pairs.push(pair);
        }
    });
    // Sorted by the empty leaf's box, for the next pass's search.
    pairs.sort_unstable_by_key(PairVotes::order);
    (out, heavy.then_some((key, pairs)))
}

/// The centre of the empty leaf `empty` (`parent * 8 + octant`): the midpoints of its grid
/// planes, as [`Flat::for_each_touching_empty`] gives them.
fn empty_centre(tree: &Flat, grid: &Grid, empty: u32) -> DVec3 {
    let parent = &tree.nodes[(empty / 8) as usize];
    let o = empty % 8;
    let cell = parent.cell * 2 + UVec3::new(o & 1, (o >> 1) & 1, (o >> 2) & 1);
    let (lo, hi) = grid.cell_box(cell, parent.depth + 1);
    (lo + hi) * 0.5
}

/// The boxes of the triangles `list`, in its order.
fn boxes_of(list: &[u32], tris: &[Tri]) -> Vec<(DVec3, DVec3)> {
    list.iter()
        .map(|&t| {
            let v = tris[t as usize].v();
            (v[0].min(v[1]).min(v[2]), v[0].max(v[1]).max(v[2]))
        })
        .collect()
}

/// The votes of a surface leaf (`lo..hi`; `boxes`: its triangles' boxes) with an empty leaf
/// (`elo..ehi`) it touches: up to [`SAMPLES`] segments from the centre of their shared
/// boundary to the nearest anchors.
fn pair_votes(
    surface: &Surface,
    boxes: &[(DVec3, DVec3)],
    (lo, hi): (UVec3, UVec3),
    (elo, ehi): (UVec3, UVec3),
    tris: &[Tri],
    grid: &Grid,
) -> PairVotes {
    // The shared closed region, in plane indices, then its centre in world space.
    let slo = lo.max(elo);
    let shi = hi.min(ehi);
    let pe = DVec3::new(
        (grid.plane(0, slo.x) + grid.plane(0, shi.x)) * 0.5,
        (grid.plane(1, slo.y) + grid.plane(1, shi.y)) * 0.5,
        (grid.plane(2, slo.z) + grid.plane(2, shi.z)) * 0.5,
    );
    // The nearest anchors.
    let mut best: [(f64, usize); SAMPLES] = [(f64::INFINITY, usize::MAX); SAMPLES];
    for (i, (p, _)) in surface.anchors.iter().enumerate() {
        let d = (*p - pe).length_squared();
        if d < best[SAMPLES - 1].0 {
            best[SAMPLES - 1] = (d, i);
            best.sort_by(|a, b| a.0.total_cmp(&b.0));
        }
    }
    let mut out = PairVotes {
        empty: (elo, ehi),
        votes: [(false, false, false); SAMPLES],
        len: 0,
    };
    for &(_, i) in best.iter().filter(|b| b.1 != usize::MAX) {
        let (pb, own) = surface.anchors[i];
        if let Some((front, closed, n)) = view_visible(pe, pb, own, (&surface.tris, boxes), tris) {
            let against = !surface.two_sided && n.dot(surface.normal) < 0.0;
            out.votes[out.len as usize] = (front, closed, against);
            out.len += 1;
        }
    }
    out
}

/// The vote of one segment from `pe` to `pb` (a point on triangle `own`): the triangle hit
/// nearest `pe` faces `pe` (front) or not (back), whether it is closed, and its normal.
/// Hits within a hair of the nearest are summed, so a segment through an edge sees both
/// triangles. `None` when undecided. `list` comes with its triangles' boxes ([`boxes_of`]).
fn view_visible(
    pe: DVec3,
    pb: DVec3,
    own: u32,
    (list, boxes): (&[u32], &[(DVec3, DVec3)]),
    tris: &[Tri],
) -> Option<(bool, bool, DVec3)> {
    let dir = pb - pe;
    if dir.length_squared() == 0.0 {
        return None;
    }
    // One pass: the nearest hit, with the hits tied with it. `own` always counts, at the
    // latest at `Pb` itself (t = 1), so there is always a hit.
    const TIE: f64 = 1e-9;
    let mut best = f64::INFINITY;
    let mut n = DVec3::ZERO;
    let mut closed = false;
    // The segment's box: a triangle whose box misses it cannot be hit (a conservative
    // filter, so the votes are exactly those of testing every triangle).
    let (slo, shi) = (pe.min(pb), pe.max(pb));
    for (&t, (lo, hi)) in list.iter().zip(boxes) {
        if (lo.cmpgt(shi) | hi.cmplt(slo)).any() && t != own {
            continue;
        }
        let tri = &tris[t as usize];
        let Some(s) = geom::segment_triangle(pe, pb, &tri.v()).or((t == own).then_some(1.0)) else {
            continue;
        };
        if s < best - TIE {
            best = s;
            n = tri.n;
            closed = tri.closed;
        } else if s <= best + TIE {
            n += tri.n;
            closed |= tri.closed;
        }
    }
    // The segment runs from Pe to Pb: the surface faces Pe when its normal opposes `dir`.
    let facing = -n.dot(dir);
    if facing == 0.0 {
        return None;
    }
    Some((facing > 0.0, closed, n))
}
