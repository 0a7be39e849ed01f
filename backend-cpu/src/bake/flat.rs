//! The flat tree: the subdivided octree as a list of leaves and inner nodes with their
//! cells, each surface leaf's clipped normal and triangle list, and the neighbour traversal
//! (`Flat::for_each_touching_leaf`) that labelling and refinement query.

use std::collections::HashMap;

use glam::{DVec3, UVec3};
use octoproxy_core::format::{NodeRecord, CLEARANCE_MAX, CLEARANCE_STEPS};
use octoproxy_core::MAX_DEPTH;
use rayon::prelude::*;

use super::geom;
use super::{Grid, Node, Tri, REUSE_TRIANGLES, TWO_SIDED_COHERENCE};

/// No child: the octant is an empty leaf.
pub(crate) const EMPTY: u32 = u32::MAX;

pub(crate) struct Surface {
    pub tris: Vec<u32>,
    /// Unit representative normal (+z when the triangles cancel exactly).
    pub normal: DVec3,
    pub two_sided: bool,
    /// Offset of the mean plane from the leaf centre along `normal`.
    pub plane_offset: f64,
    /// Each face's clearance (`2 * axis + upper`), as a solid leaf stores it
    /// (`NodeRecord::clearance`): the slab of the leaf within that many 32nds of its edge
    /// from the face holds no point of its triangles.
    pub clearance: [u32; 6],
    /// Points on the leaf's triangles inside its box, with their triangle: the start points
    /// of labelling segments.
    pub anchors: Vec<(DVec3, u32)>,
}

pub(crate) enum Kind {
    Internal { children: [u32; 8] },
    Surface(Box<Surface>),
}

pub(crate) struct FlatNode {
    pub depth: u32,
    pub cell: UVec3,
    pub kind: Kind,
}

impl FlatNode {
    /// The closed box in finest-grid plane indices.
    pub fn range(&self) -> (UVec3, UVec3) {
        let s = MAX_DEPTH - self.depth;
        (self.cell << s, (self.cell + 1) << s)
    }
}

pub(crate) struct Flat {
    pub nodes: Vec<FlatNode>,
    /// Indices of the surface leaves.
    pub surface: Vec<u32>,
}

impl Flat {
    /// Flattens the pointer tree and computes each surface leaf's normal and anchors.
    /// A surface leaf of `last` (the bake's last pass) at the same depth and cell holds the
    /// same triangles, so its normal and anchors are taken from there (for leaves of at least
    /// [`REUSE_TRIANGLES`]).
    pub fn new(root: Node, tris: &[Tri], grid: &Grid, last: Option<&Flat>) -> Flat {
        let mut flat = Flat {
            nodes: Vec::new(),
            surface: Vec::new(),
        };
        flat.push(root, UVec3::ZERO, 0);
        let known: HashMap<(u32, [u32; 3]), &Surface> = last
            .map(|last| {
                last.surface
                    .iter()
                    .filter_map(|&i| {
                        let n = &last.nodes[i as usize];
                        match &n.kind {
                            Kind::Surface(s) if s.tris.len() >= REUSE_TRIANGLES => {
                                Some(((n.depth, n.cell.to_array()), &**s))
                            }
                            _ => None,
                        }
                    })
                    .collect()
            })
            .unwrap_or_default();
        flat.nodes.par_iter_mut().for_each(|n| {
            if let Kind::Surface(s) = &mut n.kind {
                let heavy = s.tris.len() >= REUSE_TRIANGLES;
                if let Some(was) = heavy
                    .then(|| known.get(&(n.depth, n.cell.to_array())))
                    .flatten()
                {
                    s.normal = was.normal;
                    s.two_sided = was.two_sided;
                    s.plane_offset = was.plane_offset;
                    s.clearance = was.clearance;
                    s.anchors.clone_from(&was.anchors);
                    return;
                }
                let (lo, hi) = grid.cell_box(n.cell, n.depth);
                let bound = NodeRecord::plane_offset_bound(grid.root_size, n.depth) as f64;
                finish_surface(s, tris, lo, hi, bound);
            }
        });
        flat
    }

    /// The pointer tree of node `id` ([`EMPTY`]: an empty leaf), as [`Flat::new`] took it.
    pub fn node(&self, id: u32) -> Node {
        if id == EMPTY {
            return Node::Empty;
        }
        match &self.nodes[id as usize].kind {
            Kind::Surface(s) => Node::Surface {
                tris: s.tris.clone(),
            },
            Kind::Internal { children } => Node::Internal {
                children: Box::new(children.map(|c| self.node(c))),
            },
        }
    }

    /// The children of node `id`, if it is an internal node.
    pub fn children(&self, id: u32) -> Option<&[u32; 8]> {
        match self.nodes.get(id as usize).map(|n| &n.kind) {
            Some(Kind::Internal { children }) => Some(children),
            _ => None,
        }
    }

    fn push(&mut self, node: Node, cell: UVec3, depth: u32) -> u32 {
        let id = self.nodes.len() as u32;
        match node {
            Node::Empty => EMPTY,
            Node::Surface { tris } => {
                self.nodes.push(FlatNode {
                    depth,
                    cell,
                    kind: Kind::Surface(Box::new(Surface {
                        tris,
                        ..empty_surface()
                    })),
                });
                self.surface.push(id);
                id
            }
            Node::Internal { children } => {
                self.nodes.push(FlatNode {
                    depth,
                    cell,
                    kind: Kind::Internal {
                        children: [EMPTY; 8],
                    },
                });
                let mut ids = [EMPTY; 8];
                for (o, child) in children.into_iter().enumerate() {
                    let o = o as u32;
                    let c = cell * 2 + UVec3::new(o & 1, (o >> 1) & 1, (o >> 2) & 1);
                    ids[o as usize] = self.push(child, c, depth + 1);
                }
                self.nodes[id as usize].kind = Kind::Internal { children: ids };
                id
            }
        }
    }

    /// Calls `f(node)` for every surface leaf whose closed box meets the closed region
    /// `qlo..qhi` (finest-grid plane indices): the leaves inside it and those touching it.
    pub fn for_each_touching_surface(&self, qlo: UVec3, qhi: UVec3, mut f: impl FnMut(u32)) {
        self.for_each_touching_leaf(qlo, qhi, |_, child, _, _| {
            if child != EMPTY {
                f(child);
            }
        });
    }

    /// Calls `f(empty_id, lo, hi)` for every empty leaf whose closed box touches the closed
    /// box `[qlo, qhi]` (finest-grid plane indices). `empty_id` is `parent * 8 + octant`.
    pub fn for_each_touching_empty(
        &self,
        qlo: UVec3,
        qhi: UVec3,
        mut f: impl FnMut(u32, UVec3, UVec3),
    ) {
        self.for_each_touching_leaf(qlo, qhi, |slot, child, lo, hi| {
            if child == EMPTY {
                f(slot, lo, hi);
            }
        });
    }

    /// Calls `f(parent * 8 + octant, child, lo, hi)` for every leaf, empty (`child` is
    /// [`EMPTY`]) or surface, whose closed box `lo..hi` meets the closed box `[qlo, qhi]`
    /// (finest-grid plane indices).
    fn for_each_touching_leaf(
        &self,
        qlo: UVec3,
        qhi: UVec3,
        mut f: impl FnMut(u32, u32, UVec3, UVec3),
    ) {
        let mut stack = [0u32; 8 * (MAX_DEPTH as usize + 1)];
        let mut top = 1;
        stack[0] = 0;
        while top > 0 {
            top -= 1;
            let id = stack[top];
            let node = &self.nodes[id as usize];
            let Kind::Internal { children } = &node.kind else {
                continue;
            };
            let s = MAX_DEPTH - node.depth - 1;
            for (o, &child) in children.iter().enumerate() {
                let o = o as u32;
                let c = node.cell * 2 + UVec3::new(o & 1, (o >> 1) & 1, (o >> 2) & 1);
                let (lo, hi) = (c << s, (c + 1) << s);
                if !(lo.cmple(qhi).all() && qlo.cmple(hi).all()) {
                    continue;
                }
                if child != EMPTY
                    && matches!(self.nodes[child as usize].kind, Kind::Internal { .. })
                {
                    if top < stack.len() {
                        stack[top] = child;
                        top += 1;
                    }
                } else {
                    f(id * 8 + o, child, lo, hi);
                }
            }
        }
    }
}

/// The clearance of the face of the leaf `lo..hi` (one axis; its upper face if `upper`) in
/// steps of the edge divided by `CLEARANCE_STEPS`, for a least distance `near` from the face
/// to the leaf's triangles: the largest whole step strictly below it (less a twentieth of a
/// step), then lowered until the slab's inner plane as the step computes it in `f32` (its
/// rounding grows with the coordinates: at 2e5 from the origin half an ulp is an eighth of a
/// 6 cm leaf) lies strictly inside the leaf and strictly short of `near`; 0 for a triangle on
/// the face, at most `CLEARANCE_MAX`.
pub(crate) fn clearance_steps(near: f64, lo: f64, hi: f64, upper: bool) -> u32 {
    let steps = near / (hi - lo) * f64::from(CLEARANCE_STEPS) - 0.05;
    let mut c = if steps >= 1.0 {
        (steps.ceil() - 1.0).min(f64::from(CLEARANCE_MAX)) as u32
    } else {
        0
    };
    // The leaf's planes are `f32` grid planes: the step's `slab` box, exactly.
    let (lo32, hi32) = (lo as f32, hi as f32);
    let edge = hi32 - lo32;
    while c > 0 {
        let depth = edge * (c as f32 * (1.0 / CLEARANCE_STEPS as f32));
        let reach = if upper {
            hi - f64::from(hi32 - depth)
        } else {
            f64::from(lo32 + depth) - lo
        };
        if reach <= 0.0 {
            return 0;
        }
        if reach < near {
            return c;
        }
        c -= 1;
    }
    0
}

fn empty_surface() -> Surface {
    Surface {
        tris: Vec::new(),
        normal: DVec3::Z,
        two_sided: false,
        plane_offset: 0.0,
        clearance: [0; 6],
        anchors: Vec::new(),
    }
}

/// Fills in a surface leaf with the box `lo..hi`; `bound` is the validator's bound on its
/// plane offset ([`NodeRecord::plane_offset_bound`]).
fn finish_surface(s: &mut Surface, tris: &[Tri], lo: DVec3, hi: DVec3, bound: f64) {
    let mut clipped_sum = DVec3::ZERO;
    let mut clipped_area = 0.0;
    let mut full_sum = DVec3::ZERO;
    let mut full_area = 0.0;
    let mut rim = false;
    // Σ area · centroid of the clipped pieces, for the mean plane.
    let mut moment = DVec3::ZERO;
    // The least distance from each face to a point of a triangle in the box.
    let mut near = [f64::INFINITY; 6];
    for &t in &s.tris {
        let tri = &tris[t as usize];
        rim |= tri.rim_touches(lo, hi);
        let v = tri.v();
        let poly = geom::clip_triangle(&v, lo, hi);
        // Where clipping leaves nothing of a triangle that touches the box (numerically, at
        // an edge or a corner), the part of its bounding box in the leaf stands in for it.
        let (pmin, pmax) = if poly.is_empty() {
            let (a, b) = (v[0].min(v[1]).min(v[2]), v[0].max(v[1]).max(v[2]));
            (a.clamp(lo, hi), b.clamp(lo, hi))
        } else {
            poly.points()
                .iter()
                .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(a, b), p| {
                    (a.min(*p), b.max(*p))
                })
        };
        for a in 0..3 {
            near[2 * a] = near[2 * a].min(pmin[a] - lo[a]);
            near[2 * a + 1] = near[2 * a + 1].min(hi[a] - pmax[a]);
        }
        let (area, centroid) = poly.area_centroid();
        if !poly.is_empty() {
            s.anchors.push((centroid, t));
        }
        clipped_sum += tri.n * area;
        moment += centroid * area;
        clipped_area += area;
        full_sum += tri.n * tri.area;
        full_area += tri.area;
    }
    let (sum, area) = if clipped_area > 0.0 {
        (clipped_sum, clipped_area)
    } else {
        (full_sum, full_area)
    };
    let len = sum.length();
    // A leaf holding a rim cannot tell its sides apart by labels (they meet around the rim),
    // so it is solid from every side, as is a leaf whose normals cancel.
    s.two_sided = rim || !(len > TWO_SIDED_COHERENCE * area);
    s.normal = if len > 0.0 { sum / len } else { DVec3::Z };
    let center = (lo + hi) * 0.5;
    let half_diagonal = (hi - lo).length() * 0.5;
    let d = if clipped_area > 0.0 {
        s.normal.dot(moment / clipped_area - center)
    } else {
        0.0
    };
    // Rounded to f32 inside the bound the validator checks. Far from the origin a box of
    // rounded grid planes can be wider than the nominal cube that bound is made from, so
    // both limit it.
    let limit = half_diagonal.min(bound) * 0.99;
    s.plane_offset = d.clamp(-limit, limit);
    for (k, c) in s.clearance.iter_mut().enumerate() {
        *c = clearance_steps(near[k], lo[k / 2], hi[k / 2], k % 2 == 1);
    }
    if s.anchors.is_empty() {
        // Numerically, no triangle reached inside: anchor at each centroid, clamped in.
        for &t in &s.tris {
            let v = tris[t as usize].v();
            let c = (v[0] + v[1] + v[2]) / 3.0;
            s.anchors.push((c.clamp(lo, hi), t));
        }
    }
}
