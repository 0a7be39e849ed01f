//! Exact ground truth for a triangle mesh, through a bounding-volume hierarchy: the
//! generalized winding number (inside/outside, meaningful for open and leaky meshes too),
//! the unsigned distance to the surface, and how many triangles a segment crosses.
//!
//! All geometry is kept in `f64`. The winding number is a sum of exact triangle solid angles
//! (Van Oosterom–Strackee), accelerated through the hierarchy in two ways:
//!
//! - **Caps** (Jacobson et al. 2013, "Robust inside-outside segmentation using generalized
//!   winding numbers"): a subtree's triangles together with a fan from a point of its hull
//!   over its boundary edges, reversed, form a closed surface inside that hull, whose winding
//!   number is 0 outside it. So seen from outside its bounds a subtree contributes exactly
//!   what the fan over its boundary does. Vertices are welded by position and the boundary is
//!   the net oriented edge chain, so this holds for any triangle soup; it pays where the
//!   boundary is shorter than the triangle list, as for patches of a manifold mesh, and a
//!   closed mesh contributes exactly 0 at once from outside its box.
//! - **Far field** (Barill et al. 2018, "Fast winding numbers for soups and clouds"): a large
//!   subtree without a short boundary (a soup), far from the query (beyond [`BETA`] times the
//!   radius of its ball), contributes through its dipole (the area-weighted normal at the
//!   area-weighted centroid) plus the second-order term of the same expansion. This is the
//!   only approximation; manifold meshes, open or closed, do not reach it.
//!
//! A first-order dipole alone, at 2 radii, is not enough for 1e-3: seen from the concave side
//! of a curved patch its relative error is several per cent, and inside a closed mesh every
//! patch is seen from that side, so the errors add up instead of cancelling (measured: 4e-2
//! on a 5k-triangle sphere).
//!
//! Every node is bounded by its box and by a slab across its mean normal; the slab bounds
//! curved patches much more tightly, for caps, distances and segments alike.
//!
//! Segment crossings use exact orientation predicates (a floating-point filter with an exact
//! expansion-arithmetic fallback) and a symbolic perturbation for the exact zeros: a segment
//! through an edge or vertex shared by several triangles is counted as if moved off it by an
//! infinitesimal translation, so the crossing count along a path has the parity of the path's
//! real passages through the surface.

use glam::DVec3;

/// Triangles per leaf at most.
const LEAF_SIZE: usize = 4;

/// A large node without a cap counts as far when the query point is farther from its
/// centroid than `BETA` times the radius of the ball (around that centroid) holding its
/// triangles.
pub const BETA: f64 = 6.0;

/// Nodes with fewer triangles than this never use the far field: summing them is cheap.
const FAR_MIN_TRIANGLES: u32 = 64;

/// Depth of the fixed traversal stacks; median splits keep trees far shallower.
const STACK: usize = 96;

/// One node of the hierarchy.
#[derive(Clone, Copy, Debug)]
struct Node {
    /// Bounding box, slightly inflated so culling is conservative under rounding.
    lo: DVec3,
    hi: DVec3,
    /// A second convex bound: the slab `smin <= axis · x <= smax` (inflated like the box)
    /// across the node's mean normal; `axis` is zero, and the slab everything, when the
    /// normals cancel.
    axis: DVec3,
    smin: f64,
    smax: f64,
    /// Leaf: index of the first triangle; internal: index of the left child.
    start: u32,
    /// Triangles in the subtree.
    count: u32,
    /// Internal: index of the right child; 0 for a leaf (the root is nobody's child).
    right: u32,
    /// The node's cap: loops `loops[cap_start..cap_end]` (none for a closed subtree).
    cap_start: u32,
    cap_end: u32,
    /// Whether the node has a cap; leaves and nodes whose boundary is longer than their
    /// triangle list have none.
    has_cap: bool,
}

/// The far-field expansion of one node.
#[derive(Clone, Copy, Debug)]
struct Far {
    /// Area-weighted centroid (also the apex of the cap's fan).
    c: DVec3,
    /// Sum of the area vectors (area times unit normal).
    n: DVec3,
    /// Second-order moment: the sum over triangles of `area_vector ⊗ (centroid - c)`, rows
    /// indexed by the normal component.
    m: [DVec3; 3],
    /// `(BETA * radius)²`: farther than this (squared) from `c` the expansion may be used.
    far2: f64,
}

/// A triangle mesh prepared for exact queries. It is `Send + Sync`: query it from many
/// threads at once.
pub struct GroundTruth {
    /// Triangles in the leaves' order.
    tris: Vec<[DVec3; 3]>,
    /// The hierarchy; node 0 is the root (none when there are no triangles).
    nodes: Vec<Node>,
    /// The far-field data, parallel to `nodes`.
    far: Vec<Far>,
    /// Boundary loops of the caps: ranges of `loop_verts`, each loop closed by repeating its
    /// first vertex at the end, oriented as in the node's triangles.
    loops: Vec<[u32; 2]>,
    loop_verts: Vec<DVec3>,
    /// The index, in the triangle list given to [`GroundTruth::new`], of each of `tris`.
    source: Vec<u32>,
}

/// One of the triangles nearest a point ([`GroundTruth::nearest_triangles`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NearTriangle {
    /// Its index in the triangle list given to [`GroundTruth::new`].
    pub triangle: u32,
    /// Its closest point to the query point.
    pub closest: DVec3,
    /// Its counter-clockwise unit normal.
    pub normal: DVec3,
    /// Its angle at the closest point: 2π inside it, π on an edge, its corner angle at a
    /// vertex: the weights of an angle-weighted pseudo-normal (Bærentzen and Aanæs 2005).
    pub angle: f64,
}

fn to_d(p: [f32; 3]) -> DVec3 {
    DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}

impl GroundTruth {
    /// Prepares the mesh. Triangles with an out-of-range index, a non-finite vertex, or zero
    /// area are left out; nothing here panics on the input.
    pub fn new(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Self {
        Self::built(positions, triangles, None)
    }

    /// [`Self::new`], building the halves of subtrees of at least `parallel` triangles in
    /// parallel; `None`: the root's halves only, enough for two threads. A subtree built apart
    /// is copied into its parent's arrays: splitting the top three levels took a 2M-triangle
    /// build on one thread from 11 to 13 s, and the root alone costs nothing measurable there.
    /// Tests compare builds.
    fn built(positions: &[[f32; 3]], triangles: &[[u32; 3]], parallel: Option<usize>) -> Self {
        let mut gt = GroundTruth {
            tris: Vec::new(),
            nodes: Vec::new(),
            far: Vec::new(),
            loops: Vec::new(),
            loop_verts: Vec::new(),
            source: Vec::new(),
        };
        // Weld: every vertex gets the id of the first vertex at the same position.
        let key = |i: u32| positions[i as usize].map(|x| if x == 0.0 { 0 } else { x.to_bits() });
        let mut by_pos: Vec<u32> = (0..positions.len() as u32).collect();
        by_pos.sort_unstable_by_key(|&i| (key(i), i));
        let mut canon = vec![0u32; positions.len()];
        for w in 0..by_pos.len() {
            let i = by_pos[w];
            let same = w > 0 && key(by_pos[w - 1]) == key(i);
            canon[i as usize] = if same {
                canon[by_pos[w - 1] as usize]
            } else {
                i
            };
        }
        let mut tris = Vec::with_capacity(triangles.len());
        let mut ids = Vec::with_capacity(triangles.len());
        let mut kept = Vec::with_capacity(triangles.len());
        for (ti, t) in triangles.iter().enumerate() {
            if t.iter().any(|&i| i as usize >= positions.len()) {
                continue;
            }
            let v = t.map(|i| to_d(positions[i as usize]));
            let finite = v.iter().all(|p| p.is_finite());
            if finite && (v[1] - v[0]).cross(v[2] - v[0]).length_squared() > 0.0 {
                tris.push(v);
                ids.push(t.map(|i| canon[i as usize]));
                kept.push(ti as u32);
            }
        }
        if tris.is_empty() {
            return gt;
        }
        let centroids: Vec<DVec3> = tris.iter().map(|t| (t[0] + t[1] + t[2]) / 3.0).collect();
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for t in &tris {
            lo = lo.min(t[0].min(t[1]).min(t[2]));
            hi = hi.max(t[0].max(t[1]).max(t[2]));
        }
        let scale = lo.abs().max(hi.abs()).max_element().max(f64::MIN_POSITIVE);
        // Sort through an index array, so each split moves only 4-byte items.
        let mut order: Vec<u32> = (0..tris.len() as u32).collect();
        let b = Builder {
            tris: &tris,
            ids: &ids,
            positions,
            centroids: &centroids,
            pad: scale * 1e-12 + 1e-300,
            parallel: parallel.unwrap_or(tris.len().max(PARALLEL_BUILD)),
        };
        let mut built = Built::with_room(tris.len());
        b.build(&mut built, &mut order, 0);
        gt.nodes = built.nodes;
        gt.far = built.far;
        gt.loops = built.loops;
        gt.loop_verts = built.loop_verts;
        gt.tris = order.iter().map(|&i| tris[i as usize]).collect();
        gt.source = order.iter().map(|&i| kept[i as usize]).collect();
        gt
    }

    /// Triangles kept (after leaving out degenerate and invalid ones).
    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }

    /// The generalized winding number at `p`: the signed solid angle the surface subtends,
    /// over 4π. 1 inside a closed, outward-facing mesh and 0 outside, up to rounding (about
    /// 1e-12); fractional near the holes of open meshes. Only large subtrees of triangle
    /// soups (no shared edges) use the far-field expansion, whose error is well under 1e-3.
    pub fn winding_number(&self, p: [f32; 3]) -> f64 {
        let p = to_d(p);
        if self.nodes.is_empty() {
            return 0.0;
        }
        // The sum of half solid angles.
        let mut half = 0.0;
        let mut stack = [0u32; STACK];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let i = stack[top] as usize;
            let n = &self.nodes[i];
            // Outside the box or the slab, hence outside the convex hull of the subtree and
            // of its cap's fan.
            let s = n.axis.dot(p);
            let outside = p.cmplt(n.lo).any() || p.cmpgt(n.hi).any() || s < n.smin || s > n.smax;
            if outside && n.has_cap {
                half += self.cap_half_angle(i, p);
                continue;
            }
            if n.right == 0 {
                for t in &self.tris[n.start as usize..(n.start + n.count) as usize] {
                    half += half_solid_angle(t, p);
                }
                continue;
            }
            if outside && n.count >= FAR_MIN_TRIANGLES {
                let f = &self.far[i];
                let r = f.c - p;
                let d2 = r.length_squared();
                if d2 > f.far2 {
                    half += 0.5 * far_solid_angle(f, r, d2);
                    continue;
                }
            }
            if top + 2 <= STACK {
                stack[top] = n.start;
                stack[top + 1] = n.right;
                top += 2;
            } else {
                // Unreachable for trees built here; stay exact rather than overflow.
                half += self.exact_subtree(i, p);
            }
        }
        half / (2.0 * core::f64::consts::PI)
    }

    /// Half the solid angle of node `i`'s cap (the fan from its centroid over its boundary).
    fn cap_half_angle(&self, i: usize, p: DVec3) -> f64 {
        let n = &self.nodes[i];
        let o = self.far[i].c - p;
        let lo = o.length();
        let mut half = 0.0;
        for l in &self.loops[n.cap_start as usize..n.cap_end as usize] {
            let verts = &self.loop_verts[l[0] as usize..l[1] as usize];
            let Some((first, rest)) = verts.split_first() else {
                continue;
            };
            let a0 = *first - p;
            let (mut a, mut la, mut ao) = (a0, a0.length(), a0.dot(o));
            // A pending cone, as (den, num): it is folded with the next one when both lie
            // within a quarter turn (positive den), so their sum stays within ±π and one
            // `atan2` of the complex product serves both.
            let mut pending: Option<(f64, f64)> = None;
            for v in rest {
                let b = *v - p;
                let (lb, bo) = (b.length(), b.dot(o));
                let num = a.dot(b.cross(o));
                let den = la * lb * lo + a.dot(b) * lo + ao * lb + bo * la;
                if den > 0.0 {
                    match pending.take() {
                        Some((d0, n0)) => half += (d0 * num + n0 * den).atan2(d0 * den - n0 * num),
                        None => pending = Some((den, num)),
                    }
                } else {
                    half += num.atan2(den);
                }
                (a, la, ao) = (b, lb, bo);
            }
            if let Some((d0, n0)) = pending {
                half += n0.atan2(d0);
            }
        }
        half
    }

    /// The winding number summed exactly over every triangle (no hierarchy at all). Linear
    /// in the triangle count: meant for checking [`GroundTruth::winding_number`].
    pub fn winding_number_exact(&self, p: [f32; 3]) -> f64 {
        let p = to_d(p);
        self.tris
            .iter()
            .map(|t| half_solid_angle(t, p))
            .sum::<f64>()
            / (2.0 * core::f64::consts::PI)
    }

    /// Half the solid angle of the subtree at `i`, triangle by triangle.
    fn exact_subtree(&self, i: usize, p: DVec3) -> f64 {
        let n = &self.nodes[i];
        if n.right == 0 {
            self.tris[n.start as usize..(n.start + n.count) as usize]
                .iter()
                .map(|t| half_solid_angle(t, p))
                .sum()
        } else {
            self.exact_subtree(n.start as usize, p) + self.exact_subtree(n.right as usize, p)
        }
    }

    /// Whether `p` is inside: `winding_number(p) >= 0.5`.
    pub fn is_inside(&self, p: [f32; 3]) -> bool {
        self.winding_number(p) >= 0.5
    }

    /// Unsigned distance from `p` to the closest point of the surface (infinite for a mesh
    /// with no triangles). Near the surface this takes microseconds; far from a finely
    /// tessellated curved surface, where many triangles are almost equally near, longer.
    pub fn distance(&self, p: [f32; 3]) -> f64 {
        self.distance_capped(p, f64::INFINITY)
    }

    /// `min(distance(p), cap)`, faster than [`GroundTruth::distance`] where the surface is
    /// farther than `cap`: for checks like "is `p` more than `cap` from the surface".
    pub fn distance_capped(&self, p: [f32; 3], cap: f64) -> f64 {
        let p = to_d(p);
        if self.nodes.is_empty() || cap.is_nan() || cap <= 0.0 {
            return cap;
        }
        // A lower bound on the squared distance to a node: to its box, or to its slab.
        let bound = |n: &Node| {
            let s = n.axis.dot(p);
            let slab = (n.smin - s).max(s - n.smax).max(0.0);
            (p.clamp(n.lo, n.hi) - p).length_squared().max(slab * slab)
        };
        let cap2 = cap * cap;
        let mut best = cap2;
        // Each entry carries its bound, so a popped node is skipped cheaply.
        let mut stack = [(0u32, 0.0f64); STACK];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let (i, d) = stack[top];
            if d >= best {
                continue;
            }
            let n = &self.nodes[i as usize];
            if n.right == 0 {
                for t in &self.tris[n.start as usize..(n.start + n.count) as usize] {
                    best = best.min((closest_point(p, t) - p).length_squared());
                }
                continue;
            }
            let dl = bound(&self.nodes[n.start as usize]);
            let dr = bound(&self.nodes[n.right as usize]);
            // The nearer child goes on top, to be visited first.
            let (near, far) = if dl <= dr {
                ((n.start, dl), (n.right, dr))
            } else {
                ((n.right, dr), (n.start, dl))
            };
            if top + 2 <= STACK {
                if far.1 < best {
                    stack[top] = far;
                    top += 1;
                }
                if near.1 < best {
                    stack[top] = near;
                    top += 1;
                }
            } else {
                best = best.min(self.distance2_subtree(i as usize, p));
            }
        }
        if best < cap2 {
            best.sqrt().min(cap)
        } else {
            cap
        }
    }

    /// The triangles nearest `p`: every triangle whose distance is the least distance (to
    /// within rounding: a relative 1e-9 of the distance and of `p`'s magnitude), with its
    /// closest point, normal and angle there, into `out` (cleared first). Returns the least
    /// distance; infinite, with `out` empty, for a mesh with no triangles. Several triangles
    /// come back where the nearest point is on an edge or a vertex, or where surfaces are
    /// equally near.
    pub fn nearest_triangles(&self, p: [f32; 3], out: &mut Vec<NearTriangle>) -> f64 {
        out.clear();
        let d = self.distance(p);
        if !d.is_finite() {
            return d;
        }
        let q = to_d(p);
        let tie = (d + q.abs().max_element()) * 1e-9;
        let reach2 = (d + tie) * (d + tie);
        let mut stack = [0u32; STACK];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let i = stack[top] as usize;
            let n = &self.nodes[i];
            let s = n.axis.dot(q);
            let slab = (n.smin - s).max(s - n.smax).max(0.0);
            if (q.clamp(n.lo, n.hi) - q).length_squared().max(slab * slab) > reach2 {
                continue;
            }
            if n.right == 0 || top + 2 > STACK {
                self.near_in_subtree(i, q, reach2, out);
            } else {
                stack[top] = n.start;
                stack[top + 1] = n.right;
                top += 2;
            }
        }
        d
    }

    /// [`GroundTruth::nearest_triangles`] within the subtree at `i`, triangle by triangle.
    fn near_in_subtree(&self, i: usize, q: DVec3, reach2: f64, out: &mut Vec<NearTriangle>) {
        let n = &self.nodes[i];
        if n.right != 0 {
            self.near_in_subtree(n.start as usize, q, reach2, out);
            self.near_in_subtree(n.right as usize, q, reach2, out);
            return;
        }
        for k in n.start as usize..(n.start + n.count) as usize {
            let t = &self.tris[k];
            let (closest, feature) = closest_feature(q, t);
            if (closest - q).length_squared() > reach2 {
                continue;
            }
            let angle = match feature {
                Feature::Face => 2.0 * std::f64::consts::PI,
                Feature::Edge => std::f64::consts::PI,
                Feature::Vertex(v) => {
                    let (a, b) = (t[(v + 1) % 3] - t[v], t[(v + 2) % 3] - t[v]);
                    a.angle_between(b)
                }
            };
            out.push(NearTriangle {
                triangle: self.source[k],
                closest,
                normal: (t[1] - t[0]).cross(t[2] - t[0]).normalize(),
                angle,
            });
        }
    }

    /// Squared distance to the subtree at `i`, triangle by triangle.
    fn distance2_subtree(&self, i: usize, p: DVec3) -> f64 {
        let n = &self.nodes[i];
        if n.right == 0 {
            self.tris[n.start as usize..(n.start + n.count) as usize]
                .iter()
                .map(|t| (closest_point(p, t) - p).length_squared())
                .fold(f64::INFINITY, f64::min)
        } else {
            self.distance2_subtree(n.start as usize, p)
                .min(self.distance2_subtree(n.right as usize, p))
        }
    }

    /// Number of triangles the segment `a → b` crosses, exactly, as if translated by an
    /// infinitesimal `δ = ε x̂ + ε² ŷ + ε³ ẑ` (see `segment_hits_triangle`): a segment through
    /// a shared edge or vertex counts once where it passes from one side of the surface to the
    /// other, and an even number of times where it only touches it; an end point on a triangle
    /// counts on the side `δ` moves it to, the same for the pieces before and after it. The
    /// sum over the pieces of a path has the parity of the path's passages through the
    /// surface. `a == b` gives 0.
    pub fn segment_crossings(&self, a: [f32; 3], b: [f32; 3]) -> u32 {
        let a = to_d(a);
        let b = to_d(b);
        if a == b || self.nodes.is_empty() || !a.is_finite() || !b.is_finite() {
            return 0;
        }
        let inv = DVec3::ONE / (b - a);
        let seg_lo = a.min(b);
        let seg_hi = a.max(b);
        let mut hits = 0;
        let mut stack = [0u32; STACK];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let i = stack[top] as usize;
            let n = &self.nodes[i];
            let (sa, sb) = (n.axis.dot(a), n.axis.dot(b));
            if seg_hi.cmplt(n.lo).any()
                || seg_lo.cmpgt(n.hi).any()
                || sa.max(sb) < n.smin
                || sa.min(sb) > n.smax
                || !segment_box(a, inv, n.lo, n.hi)
            {
                continue;
            }
            if n.right == 0 {
                for t in &self.tris[n.start as usize..(n.start + n.count) as usize] {
                    hits += segment_hits_triangle(a, b, t) as u32;
                }
            } else if top + 2 <= STACK {
                stack[top] = n.start;
                stack[top + 1] = n.right;
                top += 2;
            } else {
                hits += self.crossings_subtree(i, a, b);
            }
        }
        hits
    }

    /// Crossings with the subtree at `i`, triangle by triangle.
    fn crossings_subtree(&self, i: usize, a: DVec3, b: DVec3) -> u32 {
        let n = &self.nodes[i];
        if n.right == 0 {
            self.tris[n.start as usize..(n.start + n.count) as usize]
                .iter()
                .map(|t| segment_hits_triangle(a, b, t) as u32)
                .sum()
        } else {
            self.crossings_subtree(n.start as usize, a, b)
                + self.crossings_subtree(n.right as usize, a, b)
        }
    }
}

/// A directed edge between welded vertex ids `(lo, hi)` with its net multiplicity: positive
/// for `lo → hi`, negative for `hi → lo`.
type Edge = (u32, u32, i32);

/// Adds up the multiplicities of equal edges and drops those that cancel.
fn net_edges(mut edges: Vec<Edge>) -> Vec<Edge> {
    edges.sort_unstable_by_key(|e| (e.0, e.1));
    let mut out: Vec<Edge> = Vec::with_capacity(edges.len());
    for e in edges {
        match out.last_mut() {
            Some(last) if (last.0, last.1) == (e.0, e.1) => last.2 += e.2,
            _ => out.push(e),
        }
        if out.last().is_some_and(|l| l.2 == 0) {
            out.pop();
        }
    }
    out
}

/// Splits a boundary (a cycle: at every vertex as many edges in as out) into closed loops of
/// vertex ids, each listing its first vertex again at the end.
fn boundary_loops(edges: &[Edge]) -> Vec<Vec<u32>> {
    // Directed edges, one per unit of multiplicity, sorted by tail.
    let mut directed: Vec<(u32, u32)> = Vec::new();
    for &(a, b, k) in edges {
        let e = if k > 0 { (a, b) } else { (b, a) };
        directed.extend(core::iter::repeat_n(e, k.unsigned_abs() as usize));
    }
    directed.sort_unstable();
    let mut used = vec![false; directed.len()];
    // The first unused out-edge of a vertex: binary search, then a short scan.
    let next_out = |v: u32, used: &[bool]| {
        let first = directed.partition_point(|e| e.0 < v);
        (first..directed.len())
            .take_while(|&j| directed[j].0 == v)
            .find(|&j| !used[j])
    };
    let mut loops = Vec::new();
    for s in 0..directed.len() {
        if used[s] {
            continue;
        }
        used[s] = true;
        let start = directed[s].0;
        let mut l = vec![start, directed[s].1];
        let mut v = directed[s].1;
        while v != start {
            // A cycle never strands the walk: every vertex entered has an unused way out.
            let Some(j) = next_out(v, &used) else { break };
            used[j] = true;
            v = directed[j].1;
            l.push(v);
        }
        loops.push(l);
    }
    loops
}

/// The fewest triangles whose subtree builds its two halves in parallel.
const PARALLEL_BUILD: usize = 1 << 14;

/// What a build makes: the nodes in depth-first order (a node, its left subtree, its right
/// subtree), their expansions, and the caps' loops in the order their nodes finish.
#[derive(Default)]
struct Built {
    nodes: Vec<Node>,
    far: Vec<Far>,
    loops: Vec<[u32; 2]>,
    loop_verts: Vec<DVec3>,
}

impl Built {
    /// Room for the nodes of `triangles` triangles.
    fn with_room(triangles: usize) -> Self {
        Built {
            nodes: Vec::with_capacity(2 * triangles / LEAF_SIZE + 2),
            far: Vec::with_capacity(2 * triangles / LEAF_SIZE + 2),
            ..Built::default()
        }
    }

    /// Appends `sub`, built apart, as the serial build would have pushed it here: its node,
    /// loop and loop-vertex indices moved by what is here already (a leaf's `start` is a
    /// triangle's place, the same either way, and a leaf has no cap). Returns the index of
    /// its root.
    fn append(&mut self, sub: Built) -> u32 {
        let (nodes, loops, verts) = (
            self.nodes.len() as u32,
            self.loops.len() as u32,
            self.loop_verts.len() as u32,
        );
        self.nodes.extend(sub.nodes.into_iter().map(|n| {
            if n.right == 0 {
                n
            } else {
                Node {
                    start: n.start + nodes,
                    right: n.right + nodes,
                    cap_start: n.cap_start + loops,
                    cap_end: n.cap_end + loops,
                    ..n
                }
            }
        }));
        self.far.extend(sub.far);
        self.loops
            .extend(sub.loops.into_iter().map(|[a, b]| [a + verts, b + verts]));
        self.loop_verts.extend(sub.loop_verts);
        nodes
    }
}

/// Builds the hierarchy over `order` (indices into `tris`), depth first; large subtrees build
/// their halves in parallel, into the very arrays the serial build makes.
struct Builder<'a> {
    tris: &'a [[DVec3; 3]],
    /// Welded vertex ids of each triangle.
    ids: &'a [[u32; 3]],
    positions: &'a [[f32; 3]],
    centroids: &'a [DVec3],
    /// How much every bound is inflated.
    pad: f64,
    /// Subtrees of at least this many triangles build their halves in parallel.
    parallel: usize,
}

impl Builder<'_> {
    /// Builds the subtree over `order`, the part of the whole order from `base`, into `out`;
    /// returns its index there and its boundary.
    fn build(&self, out: &mut Built, order: &mut [u32], base: usize) -> (u32, Vec<Edge>) {
        let id = out.nodes.len() as u32;
        let (start, end) = (base, base + order.len());
        let items = &*order;
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        let (mut clo, mut chi) = (lo, hi);
        let (mut n, mut weighted, mut area) = (DVec3::ZERO, DVec3::ZERO, 0.0);
        for &k in items {
            let t = &self.tris[k as usize];
            lo = lo.min(t[0].min(t[1]).min(t[2]));
            hi = hi.max(t[0].max(t[1]).max(t[2]));
            let c = self.centroids[k as usize];
            clo = clo.min(c);
            chi = chi.max(c);
            let av = 0.5 * (t[1] - t[0]).cross(t[2] - t[0]);
            let a = av.length();
            n += av;
            weighted += a * c;
            area += a;
        }
        // The fan's apex must lie in the box; rounding must not move it out.
        let c = (weighted / area).clamp(lo, hi);
        let (mut m, mut r2) = ([DVec3::ZERO; 3], 0.0f64);
        for &k in items {
            let t = &self.tris[k as usize];
            let av = 0.5 * (t[1] - t[0]).cross(t[2] - t[0]);
            let d = self.centroids[k as usize] - c;
            m[0] += av.x * d;
            m[1] += av.y * d;
            m[2] += av.z * d;
            for v in t {
                r2 = r2.max((*v - c).length_squared());
            }
        }
        // The slab across the mean normal (none when the normals cancel). The apex, a convex
        // combination of points of the triangles, lies in it up to rounding, which the
        // padding covers.
        let (mut axis, mut smin, mut smax) = (DVec3::ZERO, f64::NEG_INFINITY, f64::INFINITY);
        if n.length() > 1e-9 * area {
            axis = n.normalize();
            (smin, smax) = (f64::INFINITY, f64::NEG_INFINITY);
            for &k in items {
                for v in &self.tris[k as usize] {
                    smin = smin.min(axis.dot(*v));
                    smax = smax.max(axis.dot(*v));
                }
            }
            (smin, smax) = (smin - self.pad, smax + self.pad);
        }
        let pad = DVec3::splat(self.pad);
        let count = (end - start) as u32;
        let (lo, hi) = (lo - pad, hi + pad);
        let node = Node {
            lo,
            hi,
            axis,
            smin,
            smax,
            start: start as u32,
            count,
            right: 0,
            cap_start: 0,
            cap_end: 0,
            has_cap: false,
        };
        out.nodes.push(node);
        out.far.push(Far {
            c,
            n,
            m,
            far2: BETA * BETA * r2,
        });
        if end - start <= LEAF_SIZE {
            let mut edges = Vec::with_capacity(3 * (end - start));
            for &k in order.iter() {
                let t = self.ids[k as usize];
                for j in 0..3 {
                    let (a, b) = (t[j], t[(j + 1) % 3]);
                    edges.push(if a < b { (a, b, 1) } else { (b, a, -1) });
                }
            }
            return (id, net_edges(edges));
        }
        // Median split along the widest axis of the centroids.
        let split = (chi - clo).max_position();
        let mid = order.len() / 2;
        let cent = self.centroids;
        order.select_nth_unstable_by(mid, |&x, &y| {
            cent[x as usize][split].total_cmp(&cent[y as usize][split])
        });
        let total = order.len();
        let (first, second) = order.split_at_mut(mid);
        let (left, mut edges, right, right_edges) = if total >= self.parallel {
            let ((lb, le), (rb, re)) = rayon::join(
                || {
                    let mut b = Built::with_room(first.len());
                    let (_, e) = self.build(&mut b, first, base);
                    (b, e)
                },
                || {
                    let mut b = Built::with_room(second.len());
                    let (_, e) = self.build(&mut b, second, base + mid);
                    (b, e)
                },
            );
            let left = out.append(lb);
            let right = out.append(rb);
            (left, le, right, re)
        } else {
            let (left, le) = self.build(out, first, base);
            let (right, re) = self.build(out, second, base + mid);
            (left, le, right, re)
        };
        edges.extend(right_edges);
        let edges = net_edges(edges);
        let cap_edges: u64 = edges.iter().map(|e| e.2.unsigned_abs() as u64).sum();
        let cap_start = out.loops.len() as u32;
        let has_cap = cap_edges <= count as u64;
        if has_cap {
            for l in boundary_loops(&edges) {
                let first = out.loop_verts.len() as u32;
                out.loop_verts
                    .extend(l.iter().map(|&v| to_d(self.positions[v as usize])));
                out.loops.push([first, out.loop_verts.len() as u32]);
            }
        }
        let cap_end = out.loops.len() as u32;
        out.nodes[id as usize] = Node {
            start: left,
            right,
            cap_start,
            cap_end,
            has_cap,
            ..node
        };
        (id, edges)
    }
}

/// Solid angle of a node seen from `p`, through its expansion; `r = c - p`, `d2 = |r|²`.
fn far_solid_angle(f: &Far, r: DVec3, d2: f64) -> f64 {
    let d = d2.sqrt();
    let inv3 = 1.0 / (d2 * d);
    let inv5 = inv3 / d2;
    // First order: the dipole. Second order: the Jacobian of r/|r|³ contracted with `m`.
    let mr = DVec3::new(f.m[0].dot(r), f.m[1].dot(r), f.m[2].dot(r));
    let trace = f.m[0].x + f.m[1].y + f.m[2].z;
    f.n.dot(r) * inv3 + trace * inv3 - 3.0 * r.dot(mr) * inv5
}

/// Half the signed solid angle of triangle `t` seen from `p` (Van Oosterom–Strackee),
/// positive when `p` is behind it (on the side its counter-clockwise normal points away from).
fn half_solid_angle(t: &[DVec3; 3], p: DVec3) -> f64 {
    let a = t[0] - p;
    let b = t[1] - p;
    let c = t[2] - p;
    let (la, lb, lc) = (a.length(), b.length(), c.length());
    let num = a.dot(b.cross(c));
    let den = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
    num.atan2(den)
}

/// Whether the segment from `a` (with `inv = 1 / (b - a)`) meets the box `[lo, hi]`.
/// Boxes are padded at build time, so rounding here cannot lose a touching triangle.
fn segment_box(a: DVec3, inv: DVec3, lo: DVec3, hi: DVec3) -> bool {
    let mut t0: f64 = 0.0;
    let mut t1: f64 = 1.0;
    for k in 0..3 {
        let (mut ta, mut tb) = ((lo[k] - a[k]) * inv[k], (hi[k] - a[k]) * inv[k]);
        if ta.is_nan() || tb.is_nan() {
            // Parallel to the slab and on one of its planes: the earlier cull kept it.
            continue;
        }
        if ta > tb {
            core::mem::swap(&mut ta, &mut tb);
        }
        t0 = t0.max(ta);
        t1 = t1.min(tb);
    }
    t0 <= t1
}

/// Whether the segment `a b`, translated by the infinitesimal `δ = ε x̂ + ε² ŷ + ε³ ẑ`,
/// crosses the triangle `v` (exact). Every orientation that is exactly zero (an end point in
/// the triangle's plane, the segment's line meeting an edge's line) takes the sign of its
/// first nonzero term in `ε` instead. All pieces of a path are translated alike, so the
/// translated path is still a path, and it is in general position: it passes through no edge
/// or vertex and ends on no triangle. A segment through an edge shared by two triangles
/// crosses exactly one of them when it passes from one side of the surface to the other, and
/// none or both when it only touches a ridge, whatever the triangles' orientations; a segment
/// in a triangle's plane crosses it nowhere.
fn segment_hits_triangle(a: DVec3, b: DVec3, v: &[DVec3; 3]) -> bool {
    // `orient(v0, v1, v2, a + δ) = orient(v0, v1, v2, a) + n · δ`, `n = (v1 - v0) × (v2 - v0)`.
    let plane_tie = || first_nonzero(|axis| exact::cross_sign(v[0], v[1], v[0], v[2], axis));
    let mut sa = orient(v[0], v[1], v[2], a);
    let mut sb = orient(v[0], v[1], v[2], b);
    if sa == 0 || sb == 0 {
        let tie = plane_tie();
        sa = if sa == 0 { tie } else { sa };
        sb = if sb == 0 { tie } else { sb };
    }
    if sa == sb {
        return false;
    }
    // `orient(a + δ, b + δ, u, w) = orient(a, b, u, w) - δ · ((w - u) × (b - a))`.
    let edge = |u: DVec3, w: DVec3| match orient(a, b, u, w) {
        0 => first_nonzero(|axis| -exact::cross_sign(u, w, a, b, axis)),
        o => o,
    };
    let (e0, e1, e2) = (edge(v[0], v[1]), edge(v[1], v[2]), edge(v[2], v[0]));
    // Every sign is nonzero unless the triangle is degenerate (the constructor drops those)
    // or the segment is parallel to its plane (then `sa == sb` above): keep both closed
    // tests anyway.
    (e0 >= 0 && e1 >= 0 && e2 >= 0) || (e0 <= 0 && e1 <= 0 && e2 <= 0)
}

/// The first nonzero of `f(0)`, `f(1)`, `f(2)`: the sign of the leading term of
/// `c · δ` for `c = (f(0), f(1), f(2))` in signs, with `δ` as in [`segment_hits_triangle`].
fn first_nonzero(f: impl Fn(usize) -> i32) -> i32 {
    (0..3).map(f).find(|&s| s != 0).unwrap_or(0)
}

/// Exact sign of `(q - p) × (r - p) · (s - p)`: positive when `s` is on the side of plane
/// `p q r` that its counter-clockwise normal points to. Inputs must be `f32` values (so every
/// product stays far from overflow and underflow in `f64`).
fn orient(p: DVec3, q: DVec3, r: DVec3, s: DVec3) -> i32 {
    // Shewchuk's orient3d(a, b, c, d) = det[a - d, b - d, c - d] with a = q, b = r, c = s,
    // d = p, and his stage-A error bound.
    let (a, b, c, d) = (q, r, s, p);
    let (adx, ady, adz) = (a.x - d.x, a.y - d.y, a.z - d.z);
    let (bdx, bdy, bdz) = (b.x - d.x, b.y - d.y, b.z - d.z);
    let (cdx, cdy, cdz) = (c.x - d.x, c.y - d.y, c.z - d.z);
    let (bdxcdy, cdxbdy) = (bdx * cdy, cdx * bdy);
    let (cdxady, adxcdy) = (cdx * ady, adx * cdy);
    let (adxbdy, bdxady) = (adx * bdy, bdx * ady);
    let det = adz * (bdxcdy - cdxbdy) + bdz * (cdxady - adxcdy) + cdz * (adxbdy - bdxady);
    let permanent = (bdxcdy.abs() + cdxbdy.abs()) * adz.abs()
        + (cdxady.abs() + adxcdy.abs()) * bdz.abs()
        + (adxbdy.abs() + bdxady.abs()) * cdz.abs();
    const EPS: f64 = f64::EPSILON * 0.5;
    let bound = (7.0 + 56.0 * EPS) * EPS * permanent;
    if det > bound {
        return 1;
    }
    if -det > bound {
        return -1;
    }
    exact::orient3d_sign(a, b, c, d)
}

/// Exact arithmetic on floating-point expansions (Shewchuk 1997), for the rare orientation
/// tests the filter cannot decide. Speed does not matter here; clarity does.
mod exact {
    use glam::DVec3;

    /// `a + b` as `(sum, error)`, exactly.
    fn two_sum(a: f64, b: f64) -> (f64, f64) {
        let s = a + b;
        let bv = s - a;
        let av = s - bv;
        (s, (a - av) + (b - bv))
    }

    /// Dekker's split of `a` into two 26-bit halves.
    fn split(a: f64) -> (f64, f64) {
        let c = 134_217_729.0 * a;
        let big = c - a;
        let hi = c - big;
        (hi, a - hi)
    }

    /// `a * b` as `(product, error)`, exactly.
    fn two_product(a: f64, b: f64) -> (f64, f64) {
        let x = a * b;
        let (ah, al) = split(a);
        let (bh, bl) = split(b);
        let err = x - ah * bh - al * bh - ah * bl;
        (x, al * bl - err)
    }

    /// `e += b` in place (Grow-Expansion with zero elimination). Expansions are
    /// nonoverlapping, smallest component first, and hold no zeros.
    fn grow(e: &mut Vec<f64>, b: f64) {
        let mut q = b;
        let mut kept = 0;
        for i in 0..e.len() {
            let (s, h) = two_sum(q, e[i]);
            if h != 0.0 {
                e[kept] = h;
                kept += 1;
            }
            q = s;
        }
        e.truncate(kept);
        if q != 0.0 {
            e.push(q);
        }
    }

    /// `e + f`.
    fn sum(e: &[f64], f: &[f64]) -> Vec<f64> {
        let mut out = e.to_vec();
        for &x in f {
            grow(&mut out, x);
        }
        out
    }

    /// `e * b` (Scale-Expansion with zero elimination).
    fn scale(e: &[f64], b: f64) -> Vec<f64> {
        let mut out = Vec::with_capacity(2 * e.len());
        let Some((&first, rest)) = e.split_first() else {
            return out;
        };
        let (mut q, h) = two_product(first, b);
        out.push(h);
        for &x in rest {
            let (t1, t0) = two_product(x, b);
            let (s, h) = two_sum(q, t0);
            out.push(h);
            let (s2, h2) = two_sum(t1, s);
            out.push(h2);
            q = s2;
        }
        out.push(q);
        out.retain(|x| *x != 0.0);
        out
    }

    /// `e * f`.
    fn mul(e: &[f64], f: &[f64]) -> Vec<f64> {
        let mut out = Vec::new();
        for &x in f {
            for c in scale(e, x) {
                grow(&mut out, c);
            }
        }
        out
    }

    fn neg(e: &[f64]) -> Vec<f64> {
        e.iter().map(|x| -x).collect()
    }

    /// `a - b` as an expansion.
    fn diff(a: f64, b: f64) -> Vec<f64> {
        let (s, e) = two_sum(a, -b);
        [e, s].into_iter().filter(|x| *x != 0.0).collect()
    }

    /// Sign of a nonoverlapping expansion: that of its largest nonzero component.
    fn sign(e: &[f64]) -> i32 {
        match e.iter().rev().find(|x| **x != 0.0) {
            Some(x) if *x > 0.0 => 1,
            Some(_) => -1,
            None => 0,
        }
    }

    /// Exact sign of component `axis` of `(p1 - p0) × (q1 - q0)`.
    pub(super) fn cross_sign(p0: DVec3, p1: DVec3, q0: DVec3, q1: DVec3, axis: usize) -> i32 {
        let (i, j) = ((axis + 1) % 3, (axis + 2) % 3);
        let (pi, pj) = (diff(p1[i], p0[i]), diff(p1[j], p0[j]));
        let (qi, qj) = (diff(q1[i], q0[i]), diff(q1[j], q0[j]));
        sign(&sum(&mul(&pi, &qj), &neg(&mul(&pj, &qi))))
    }

    /// Exact sign of `det[a - d, b - d, c - d]`.
    pub(super) fn orient3d_sign(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> i32 {
        let (adx, ady, adz) = (diff(a.x, d.x), diff(a.y, d.y), diff(a.z, d.z));
        let (bdx, bdy, bdz) = (diff(b.x, d.x), diff(b.y, d.y), diff(b.z, d.z));
        let (cdx, cdy, cdz) = (diff(c.x, d.x), diff(c.y, d.y), diff(c.z, d.z));
        let minor = |p: &[f64], q: &[f64], r: &[f64], s: &[f64]| sum(&mul(p, q), &neg(&mul(r, s)));
        let t1 = mul(&adz, &minor(&bdx, &cdy, &cdx, &bdy));
        let t2 = mul(&bdz, &minor(&cdx, &ady, &adx, &cdy));
        let t3 = mul(&cdz, &minor(&adx, &bdy, &bdx, &ady));
        sign(&sum(&sum(&t1, &t2), &t3))
    }
}

/// Closest point of a triangle to `p` (Ericson, Real-Time Collision Detection, 5.1.5).
fn closest_point(p: DVec3, t: &[DVec3; 3]) -> DVec3 {
    closest_feature(p, t).0
}

/// Where on a triangle its closest point to a point lies.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Feature {
    /// At vertex `k`.
    Vertex(usize),
    /// On an edge, between its end points.
    Edge,
    /// Inside the triangle.
    Face,
}

/// [`closest_point`], and the feature it lies on.
fn closest_feature(p: DVec3, t: &[DVec3; 3]) -> (DVec3, Feature) {
    let (a, b, c) = (t[0], t[1], t[2]);
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return (a, Feature::Vertex(0));
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return (b, Feature::Vertex(1));
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return (a + ab * (d1 / (d1 - d3)), Feature::Edge);
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return (c, Feature::Vertex(2));
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return (a + ac * (d2 / (d2 - d6)), Feature::Edge);
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return (
            b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))),
            Feature::Edge,
        );
    }
    let denom = 1.0 / (va + vb + vc);
    (a + ab * (vb * denom) + ac * (vc * denom), Feature::Face)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes;

    /// A small deterministic generator (a 64-bit LCG, top bits).
    struct Lcg(u64);

    impl Lcg {
        fn next(&mut self) -> u64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            self.0 >> 11
        }
        fn range(&mut self, lo: f32, hi: f32) -> f32 {
            lo + (hi - lo) * (self.next() as f64 / (1u64 << 53) as f64) as f32
        }
        fn point(&mut self, lo: f32, hi: f32) -> [f32; 3] {
            [self.range(lo, hi), self.range(lo, hi), self.range(lo, hi)]
        }
        fn int(&mut self, n: i64) -> i64 {
            (self.next() % (2 * n as u64 + 1)) as i64 - n
        }
    }

    fn gt(m: &scenes::Mesh) -> GroundTruth {
        GroundTruth::new(&m.positions, &m.triangles)
    }

    fn norm(p: [f32; 3]) -> f32 {
        (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()
    }

    #[test]
    fn a_parallel_build_makes_the_serial_arrays() {
        // Open and closed parts together (caps and loops at many nodes), built in parallel
        // from subtrees of 16 triangles up and serially: the same arrays, so the same answers.
        let mut m = scenes::torus([0.0; 3], 1.0, 0.3, 48, 24);
        let s = scenes::uv_sphere([0.5, 0.2, 0.1], 0.7, 40, 20);
        let base = m.positions.len() as u32;
        m.positions.extend(&s.positions);
        m.triangles.extend(
            s.triangles
                .iter()
                .take(s.triangles.len() - 37)
                .map(|t| t.map(|i| i + base)),
        );
        let serial = GroundTruth::built(&m.positions, &m.triangles, Some(usize::MAX));
        let parallel = GroundTruth::built(&m.positions, &m.triangles, Some(16));
        assert!(serial.loops.len() > 10, "{} loops", serial.loops.len());
        assert_eq!(
            format!("{:?}", serial.nodes),
            format!("{:?}", parallel.nodes)
        );
        assert_eq!(format!("{:?}", serial.far), format!("{:?}", parallel.far));
        assert_eq!(serial.loops, parallel.loops);
        assert_eq!(serial.loop_verts, parallel.loop_verts);
        assert_eq!(serial.tris, parallel.tris);
        assert_eq!(serial.source, parallel.source);
    }

    /// Each triangle on its own vertices, shrunk a little toward its centroid, so nothing
    /// welds and no subtree has a short boundary: a triangle soup.
    fn soup_of(m: &scenes::Mesh) -> scenes::Mesh {
        let mut soup = scenes::Mesh::default();
        for t in &m.triangles {
            let v = t.map(|i| glam::Vec3::from_array(m.positions[i as usize]));
            let c = (v[0] + v[1] + v[2]) / 3.0;
            let base = soup.positions.len() as u32;
            soup.positions
                .extend(v.iter().map(|p| (c + (*p - c) * 0.98).to_array()));
            soup.triangles.push([base, base + 1, base + 2]);
        }
        soup
    }

    #[test]
    fn is_send_and_sync() {
        fn check<T: Send + Sync>() {}
        check::<GroundTruth>();
    }

    #[test]
    fn orientation_is_exact_on_near_coplanar_points() {
        // Coordinates k / 1024 with |k| < 2^21 are exact in f32, and the determinant of their
        // integer numerators is exact in i128: compare signs, many of them zero or one unit off.
        let mut rng = Lcg(3);
        let mut zeros = 0;
        for i in 0..20_000 {
            let mut q = [[0i64; 3]; 4];
            for v in q.iter_mut().take(3) {
                *v = [rng.int(1 << 17), rng.int(1 << 17), rng.int(1 << 17)];
            }
            // The fourth point in the plane of the first three, then (half the time) nudged by
            // at most one unit.
            let (u, w) = (rng.int(3), rng.int(3));
            q[3] = core::array::from_fn(|k| {
                q[0][k] + u * (q[1][k] - q[0][k]) + w * (q[2][k] - q[0][k])
            });
            if i % 2 == 0 {
                q[3][rng.next() as usize % 3] += rng.int(1);
            }
            let d = |k: usize| {
                [q[k][0] - q[0][0], q[k][1] - q[0][1], q[k][2] - q[0][2]].map(|x| x as i128)
            };
            let (a, b, c) = (d(1), d(2), d(3));
            let det = a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                + a[2] * (b[0] * c[1] - b[1] * c[0]);
            let f = |k: usize| DVec3::from_array(q[k].map(|x| (x as f32 / 1024.0) as f64));
            let s = orient(f(0), f(1), f(2), f(3));
            assert_eq!(s, det.signum() as i32, "{q:?}");
            // The exact path alone agrees too (orient3d(q, r, s, p) is orient(p, q, r, s)).
            assert_eq!(exact::orient3d_sign(f(1), f(2), f(3), f(0)), s, "{q:?}");
            zeros += (det == 0) as u32;
        }
        assert!(
            zeros > 5000,
            "the test should exercise exactly coplanar cases ({zeros})"
        );
    }

    #[test]
    fn cube_winding_numbers() {
        let m = scenes::cube([-1.0; 3], [1.0; 3]);
        let g = gt(&m);
        assert_eq!(g.triangle_count(), 12);
        for p in [
            [0.0, 0.0, 0.0],
            [0.9, -0.9, 0.5],
            [-0.99, 0.3, 0.99],
            [0.5, 0.5, -0.2],
        ] {
            assert!(
                (g.winding_number(p) - 1.0).abs() < 1e-6,
                "{p:?}: {}",
                g.winding_number(p)
            );
            assert!((g.winding_number_exact(p) - 1.0).abs() < 1e-6);
            assert!(g.is_inside(p));
        }
        for p in [
            [1.01, 0.0, 0.0],
            [2.0, 2.0, 2.0],
            [0.0, -1.5, 0.3],
            [-1.2, 1.2, 0.0],
            [10.0, 3.0, -2.0],
        ] {
            assert!(
                g.winding_number(p).abs() < 1e-6,
                "{p:?}: {}",
                g.winding_number(p)
            );
            assert!(g.winding_number_exact(p).abs() < 1e-6);
            assert!(!g.is_inside(p));
        }
    }

    #[test]
    fn sphere_winding_numbers_match_radius() {
        let g = gt(&scenes::uv_sphere([0.0; 3], 1.0, 64, 32));
        let mut rng = Lcg(5);
        for _ in 0..3000 {
            let p = rng.point(-1.5, 1.5);
            let len = norm(p);
            // The polygonal sphere lies between radius 0.99 and 1.
            if !(0.99..=1.0).contains(&len) {
                let w = g.winding_number(p);
                let want = if len < 1.0 { 1.0 } else { 0.0 };
                assert!((w - want).abs() < 1e-6, "{p:?} (r {len}): {w}");
                assert_eq!(g.is_inside(p), len < 1.0, "{p:?}");
            }
        }
    }

    #[test]
    fn fast_winding_matches_brute_force_on_5k_sphere() {
        let m = scenes::uv_sphere([0.2, -0.1, 0.3], 1.0, 72, 36);
        let g = gt(&m);
        assert!(g.triangle_count() > 5000);
        let mut rng = Lcg(9);
        let mut worst: f64 = 0.0;
        for i in 0..2000 {
            // Half the points near the surface, where near and far parts mix most.
            let p = if i % 2 == 0 {
                rng.point(-1.5, 1.5)
            } else {
                let v = m.positions[rng.next() as usize % m.positions.len()];
                let s = rng.range(0.97, 1.03);
                [
                    0.2 + (v[0] - 0.2) * s,
                    -0.1 + (v[1] + 0.1) * s,
                    0.3 + (v[2] - 0.3) * s,
                ]
            };
            let (fast, slow) = (g.winding_number(p), g.winding_number_exact(p));
            worst = worst.max((fast - slow).abs());
        }
        for p in [[5.0, 0.0, 0.0], [3.0, 3.0, 3.0], [-20.0, 1.0, 2.0]] {
            let (fast, slow) = (g.winding_number(p), g.winding_number_exact(p));
            worst = worst.max((fast - slow).abs());
            assert!(slow.abs() < 1e-6, "{p:?}: exact {slow}");
        }
        // Without a far field on a manifold mesh, the two differ only by rounding.
        assert!(worst < 1e-9, "largest |fast - exact| {worst}");
    }

    #[test]
    fn far_field_of_a_soup_matches_brute_force() {
        let g = gt(&soup_of(&scenes::uv_sphere([0.0; 3], 1.0, 48, 24)));
        let mut rng = Lcg(21);
        let (mut worst_far, mut worst_near): (f64, f64) = (0.0, 0.0);
        for _ in 0..3000 {
            let p = rng.point(-4.0, 4.0);
            let (fast, slow) = (g.winding_number(p), g.winding_number_exact(p));
            if norm(p) > 2.0 {
                worst_far = worst_far.max((fast - slow).abs());
            } else {
                worst_near = worst_near.max((fast - slow).abs());
            }
        }
        assert!(
            worst_far < 1e-3 && worst_near < 1e-3,
            "far {worst_far}, near {worst_near}"
        );
        // Far away the expansion is used from the root down, and is far better than 1e-3.
        for p in [[30.0, 0.0, 0.0], [-20.0, 25.0, 3.0]] {
            let (fast, slow) = (g.winding_number(p), g.winding_number_exact(p));
            assert!(
                (fast - slow).abs() < 1e-5,
                "{p:?}: fast {fast}, exact {slow}"
            );
        }
        // The soup leaks a little (4 % of the area is gone) but still reads as inside.
        let w = g.winding_number([0.1, 0.2, 0.3]);
        assert!(w > 0.9 && w < 1.0, "{w}");
    }

    #[test]
    fn open_meshes_have_fractional_winding_numbers() {
        // Just above the middle of a large sheet facing +y: about -1/2 (it is seen from the
        // front); just below: about +1/2.
        let g = gt(&scenes::flat_sheet([0.0; 3], 100.0, 16));
        assert!((g.winding_number([0.0, 0.01, 0.0]) + 0.5).abs() < 1e-3);
        assert!((g.winding_number([0.0, -0.01, 0.0]) - 0.5).abs() < 1e-3);
        let dome = scenes::hemisphere([0.0; 3], 1.0, 48, 12);
        let g = gt(&dome);
        let mut rng = Lcg(23);
        for _ in 0..500 {
            let p = rng.point(-2.0, 2.0);
            assert!(
                (g.winding_number(p) - g.winding_number_exact(p)).abs() < 1e-9,
                "{p:?}"
            );
        }
    }

    #[test]
    fn nested_shell_cavity_is_outside() {
        let g = gt(&scenes::nested_shells(1.0, 0.2));
        assert!(g.winding_number([0.0; 3]).abs() < 1e-6);
        assert!((g.winding_number([0.0, 0.9, 0.0]) - 1.0).abs() < 1e-6);
        assert!(g.winding_number([0.0, 1.5, 0.0]).abs() < 1e-6);
    }

    #[test]
    fn cube_distances() {
        let g = gt(&scenes::cube([-1.0; 3], [1.0; 3]));
        let cases: [([f32; 3], f64); 7] = [
            ([0.5, 0.0, 0.0], 0.5),
            ([0.0, 0.0, 0.0], 1.0),
            ([3.0, 0.0, 0.0], 2.0),
            ([0.2, -1.25, 0.3], 0.25),
            ([2.0, 2.0, 0.0], 2f64.sqrt()),
            ([2.0, 2.0, 2.0], 3f64.sqrt()),
            ([1.0, 0.5, 0.25], 0.0),
        ];
        for (p, want) in cases {
            let d = g.distance(p);
            assert!((d - want).abs() < 1e-9, "{p:?}: {d}, want {want}");
        }
        assert_eq!(GroundTruth::new(&[], &[]).distance([0.0; 3]), f64::INFINITY);
        assert_eq!(g.distance_capped([3.0, 0.0, 0.0], 0.5), 0.5);
        assert!((g.distance_capped([3.0, 0.0, 0.0], 2.5) - 2.0).abs() < 1e-9);
        assert!((g.distance_capped([0.2, -1.25, 0.3], 1.0) - 0.25).abs() < 1e-9);
    }

    #[test]
    fn sphere_distances_match_brute_force() {
        let g = gt(&scenes::uv_sphere([0.0; 3], 1.0, 40, 20));
        let mut rng = Lcg(11);
        for _ in 0..500 {
            let p = rng.point(-2.0, 2.0);
            let q = to_d(p);
            let brute = g
                .tris
                .iter()
                .map(|t| (closest_point(q, t) - q).length())
                .fold(f64::INFINITY, f64::min);
            assert!((g.distance(p) - brute).abs() < 1e-12, "{p:?}");
            assert!(
                (g.distance_capped(p, 0.3) - brute.min(0.3)).abs() < 1e-12,
                "{p:?}"
            );
        }
    }

    #[test]
    fn cube_segment_crossings() {
        let g = gt(&scenes::cube([-1.0; 3], [1.0; 3]));
        assert_eq!(g.segment_crossings([-3.0, 0.1, 0.2], [3.0, 0.1, 0.2]), 2);
        assert_eq!(g.segment_crossings([0.0, 0.1, 0.2], [3.0, 0.1, 0.2]), 1);
        assert_eq!(g.segment_crossings([0.3, 3.0, -0.2], [0.1, 0.5, 0.4]), 1);
        assert_eq!(g.segment_crossings([2.0, 0.1, 0.2], [3.0, 0.1, 0.2]), 0);
        assert_eq!(g.segment_crossings([-3.0, 1.5, 0.2], [3.0, 1.5, 0.2]), 0);
        assert_eq!(g.segment_crossings([0.0, 0.1, 0.2], [0.5, 0.1, 0.2]), 0);
        assert_eq!(g.segment_crossings([0.0, 0.1, 0.2], [0.0, 0.1, 0.2]), 0);
        // Ending exactly on a face: the end point counts on the side the infinitesimal
        // translation (toward +x first) moves it to, outside the +x face and inside the -x
        // face; the piece that goes on from there counts the rest.
        assert_eq!(g.segment_crossings([3.0, 0.1, 0.2], [1.0, 0.1, 0.2]), 0);
        assert_eq!(g.segment_crossings([1.0, 0.1, 0.2], [0.0, 0.1, 0.2]), 1);
        assert_eq!(g.segment_crossings([-3.0, 0.1, 0.2], [-1.0, 0.1, 0.2]), 1);
        assert_eq!(g.segment_crossings([-1.0, 0.1, 0.2], [0.0, 0.1, 0.2]), 0);
        // Through the face centres, which lie on the quads' diagonals, each shared by two
        // triangles: once per face.
        assert_eq!(g.segment_crossings([-3.0, 0.0, 0.0], [3.0, 0.0, 0.0]), 2);
        // Through two opposite corners, where several triangles of three faces meet.
        assert_eq!(g.segment_crossings([-2.0, -2.0, -2.0], [2.0, 2.0, 2.0]), 2);
        // Along an edge of the cube from outside: it touches the surface only.
        assert_eq!(
            g.segment_crossings([1.0, 1.0, -3.0], [1.0, 1.0, 3.0]) % 2,
            0
        );
        // Lying in a face's plane does not count for that face.
        assert_eq!(g.segment_crossings([1.0, -0.5, -0.5], [1.0, 0.5, 0.5]), 0);
    }

    #[test]
    fn crossings_are_watertight_on_a_closed_sphere() {
        // Segments between points well inside and well outside cross an odd number of times
        // however they pass between triangles; inside to inside, an even number.
        let g = gt(&scenes::uv_sphere([0.0; 3], 1.0, 24, 12));
        let mut rng = Lcg(13);
        for _ in 0..5000 {
            let a = rng.point(-0.55, 0.55);
            let b = rng.point(-3.0, 3.0);
            if norm(b) > 1.05 {
                assert_eq!(g.segment_crossings(a, b) % 2, 1, "{a:?} {b:?}");
            } else if norm(b) < 0.95 {
                assert_eq!(g.segment_crossings(a, b) % 2, 0, "{a:?} {b:?}");
            }
        }
        // Through the poles, where 24 triangles share a vertex: once per pole.
        assert_eq!(g.segment_crossings([0.0, -2.0, 0.0], [0.0, 2.0, 0.0]), 2);
    }

    #[test]
    fn open_mesh_crossings_through_shared_edges_and_vertices() {
        // A 4x4 sheet in y = 0 over [-1, 1]²: vertices every 0.5, each quad split along a
        // diagonal. Straight through a vertex where six triangles meet, through an edge, and
        // through a diagonal's midpoint: once each.
        let sheet = gt(&scenes::flat_sheet([0.0; 3], 2.0, 4));
        assert_eq!(
            sheet.segment_crossings([0.0, -1.0, 0.0], [0.0, 1.0, 0.0]),
            1
        );
        assert_eq!(
            sheet.segment_crossings([0.5, 1.0, -0.5], [-0.5, -1.0, 0.5]),
            1
        );
        assert_eq!(
            sheet.segment_crossings([0.25, -1.0, 0.0], [0.25, 1.0, 0.0]),
            1
        );
        assert_eq!(
            sheet.segment_crossings([0.25, -1.0, 0.25], [0.25, 1.0, 0.25]),
            1
        );
        // Along the sheet, across its edges and vertices: never.
        assert_eq!(
            sheet.segment_crossings([-0.9, 0.0, -0.9], [0.9, 0.0, 0.7]),
            0
        );
        // A roof: two triangles meeting at the ridge x = 0, y = 1, sloping down to y = 0.
        let positions = [
            [0.0, 1.0, -1.0],
            [0.0, 1.0, 1.0],
            [1.0, 0.0, -1.0],
            [-1.0, 0.0, -1.0],
            [1.0, 0.0, 1.0],
            [-1.0, 0.0, 1.0],
        ];
        let roof = GroundTruth::new(&positions, &[[0, 1, 2], [2, 1, 4], [1, 0, 3], [1, 3, 5]]);
        // Grazing the ridge from above, it stays above: an even count.
        assert_eq!(
            roof.segment_crossings([-1.0, 1.5, 0.0], [1.0, 0.5, 0.0]) % 2,
            0
        );
        assert_eq!(
            roof.segment_crossings([-1.0, 2.0, 0.0], [1.0, 0.0, 0.0]) % 2,
            0
        );
        // Through the ridge from above to beneath: once.
        assert_eq!(roof.segment_crossings([0.0, 2.0, 0.0], [0.0, 0.5, 0.0]), 1);
        assert_eq!(
            roof.segment_crossings([-0.5, 2.0, 0.3], [0.5, 0.0, -0.3]),
            1
        );
    }

    /// `segment_hits_triangle` against an explicit translation by `(2^-16, 2^-32, 2^-48)`, on
    /// small lattice coordinates, where segments through edges, through vertices, along
    /// edges, ending on triangles and lying in their planes are common. Coordinates are
    /// multiples of 1/2 below 32 in size, so a nonzero orientation is at least 1/8 while the
    /// translation changes one by less than 1/16, each order of it outweighs the next, and the
    /// translated coordinates are exact: the explicit translation decides as the
    /// infinitesimal one does, and its orientations are never zero where they matter.
    #[test]
    fn perturbed_hits_match_an_explicit_translation() {
        let mut rng = Lcg(29);
        let lattice =
            |rng: &mut Lcg| DVec3::new(rng.int(8) as f64, rng.int(8) as f64, rng.int(8) as f64);
        let delta = DVec3::new(2f64.powi(-16), 2f64.powi(-32), 2f64.powi(-48));
        let mut degenerate = 0;
        let mut hits = 0;
        for _ in 0..20_000 {
            let v = [lattice(&mut rng), lattice(&mut rng), lattice(&mut rng)];
            if (v[1] - v[0]).cross(v[2] - v[0]) == DVec3::ZERO {
                continue;
            }
            // Segments through a vertex, through an edge's midpoint, or between lattice points.
            let a = lattice(&mut rng);
            let through = match rng.next() % 3 {
                0 => v[(rng.next() % 3) as usize],
                1 => (v[0] + v[1]) * 0.5,
                _ => lattice(&mut rng),
            };
            // Through it, or ending there.
            let b = if rng.next().is_multiple_of(4) {
                through
            } else {
                through + (through - a)
            };
            if a == b {
                continue;
            }
            let exact = [
                orient(v[0], v[1], v[2], a),
                orient(v[0], v[1], v[2], b),
                orient(a, b, v[0], v[1]),
                orient(a, b, v[1], v[2]),
                orient(a, b, v[2], v[0]),
            ];
            degenerate += exact.contains(&0) as u32;
            let (at, bt) = (a + delta, b + delta);
            let ends = [orient(v[0], v[1], v[2], at), orient(v[0], v[1], v[2], bt)];
            assert!(!ends.contains(&0), "{a} {b} {v:?}");
            let translated = ends[0] != ends[1] && {
                let edges = [
                    orient(at, bt, v[0], v[1]),
                    orient(at, bt, v[1], v[2]),
                    orient(at, bt, v[2], v[0]),
                ];
                // Crossing the plane, the segment is not parallel to any edge.
                assert!(!edges.contains(&0), "{a} {b} {v:?}");
                edges.iter().all(|&e| e > 0) || edges.iter().all(|&e| e < 0)
            };
            assert_eq!(segment_hits_triangle(a, b, &v), translated, "{a} {b} {v:?}");
            hits += translated as u32;
        }
        assert!(
            degenerate > 2000 && hits > 1000,
            "{degenerate} degenerate cases, {hits} hits"
        );
    }

    /// On a closed mesh whose vertices, edges and faces are all on a coarse lattice, the
    /// crossings along a random lattice path (through vertices and edges, along faces, ending
    /// on them) add up, at every end point off the surface, to the parity of inside versus
    /// where it started.
    #[test]
    fn path_crossings_have_the_parity_of_the_side_on_a_lattice_mesh() {
        let g = gt(&scenes::merge(&[
            scenes::cube([-2.0; 3], [2.0; 3]),
            scenes::cube([-1.0, -1.0, -1.0], [1.0, 3.0, 1.0]),
        ]));
        let inside = |p: [f32; 3]| g.winding_number(p).round() as i64 % 2 != 0;
        let mut rng = Lcg(31);
        let mut checked = 0;
        for _ in 0..300 {
            let mut p = [rng.int(4) as f32, rng.int(4) as f32, rng.int(4) as f32];
            while g.distance(p) == 0.0 {
                p[0] += 0.5;
            }
            let start = inside(p);
            let mut crossings = 0;
            for _ in 0..30 {
                let q = [rng.int(4) as f32, rng.int(4) as f32, rng.int(4) as f32];
                crossings += g.segment_crossings(p, q);
                p = q;
                if g.distance(p) > 0.0 {
                    assert_eq!(crossings % 2 == 1, inside(p) != start, "at {p:?}");
                    checked += 1;
                }
            }
        }
        assert!(checked > 3000, "{checked}");
    }

    #[test]
    fn invalid_input_is_skipped() {
        let positions = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [2.0, 0.0, 0.0],
            [f32::NAN, 0.0, 0.0],
        ];
        // Out of range, degenerate (collinear, repeated), non-finite, and one good triangle.
        let triangles = [
            [0, 1, 7],
            [0, 1, 3],
            [0, 0, 2],
            [0, 1, 4],
            [0, 1, 2],
            [u32::MAX, 0, 1],
        ];
        let g = GroundTruth::new(&positions, &triangles);
        assert_eq!(g.triangle_count(), 1);
        assert_eq!(g.segment_crossings([0.2, 0.2, -1.0], [0.2, 0.2, 1.0]), 1);
        assert!((g.distance([0.2, 0.2, 0.5]) - 0.5).abs() < 1e-12);
        let empty = GroundTruth::new(&positions, &[]);
        assert_eq!(empty.triangle_count(), 0);
        assert_eq!(empty.winding_number([0.0; 3]), 0.0);
        assert_eq!(empty.segment_crossings([0.0; 3], [1.0; 3]), 0);
    }
}
