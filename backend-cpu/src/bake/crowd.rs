//! Crowded surface leaves: where two sheets of the surface come within a `dmax` leaf of a
//! surface leaf (two parts through or beside each other, a fold, a surface through itself),
//! the leaf is solid.
//!
//! A particle's side is one bit, right for the surface it was last stamped by (or, at its
//! start, the one it is nearest). Between two sheets it can be in front of one and behind the
//! other, and where their surface leaves meet with no empty leaf between to stamp it again, a
//! one-sided leaf of the second sheet read that bit against its own normal and let the
//! particle through (found by the starts campaign: the teapot's spout through its body,
//! Suzanne's eyes in her head, the ogre's overlapping parts, 0.1–5 % of the particles started
//! near them). A solid leaf holds a particle from every side, whatever its bit.
//!
//! A **sheet** is a set of triangles joined by manifold edges (vertices welded by position
//! across the scene; an edge joins the two triangles that use it, once in each direction, and
//! no others): near a leaf, the triangles that meet its box grown by one `dmax` leaf on every
//! side. One sheet that does not cross itself has one front and one back there (an orientable
//! patch; its rims are solid already); two sheets, or one that crosses itself, do not. Parts
//! that share an edge without joining there (two sheets through one line, fins welded to a
//! plate) are two sheets.

use std::collections::HashMap;

use glam::{DVec3, UVec3};
use octoproxy_core::MAX_DEPTH;
use rayon::prelude::*;

use super::flat::{Flat, Kind};
use super::{geom, DirectedEdge, Grid, Tri, REUSE_TRIANGLES};

/// A leaf's key across the bake's passes: its depth and cell. A leaf's triangles are those
/// that meet its box, whatever the tree around it, so what is found for a leaf in one pass
/// holds in the next, where most leaves are the same.
type LeafKey = (u32, [u32; 3]);

/// What the crowding test keeps across a bake's passes: the scene's manifold edges, and per
/// leaf whether it crosses itself and whether more than one sheet meets its grown box. The
/// triangles that meet the grown box are gathered from the surface leaves around it, through
/// their own boxes (a rounded test), so the sheets are reused only where those leaves are the
/// very same (their keys, in the order met).
pub(crate) struct Crowding {
    joins: Vec<[u32; 3]>,
    crosses: HashMap<LeafKey, bool>,
    sheets: HashMap<LeafKey, (Vec<LeafKey>, bool)>,
}

impl Crowding {
    pub(crate) fn new(tris: &[Tri]) -> Self {
        Crowding {
            joins: manifold_edges(tris),
            crosses: HashMap::new(),
            sheets: HashMap::new(),
        }
    }

    /// Forgets what was found about leaves (keeps the manifold edges).
    pub(crate) fn forget(&mut self) {
        self.crosses.clear();
        self.sheets.clear();
    }

    /// Per flat node: whether it is a crowded surface leaf. `boxes`: each triangle's
    /// [`outward_box`], a cheap first test of whether it can meet a grown box, before the
    /// exact one reads the triangle. `embedded`: the surface crosses itself nowhere (an
    /// offset surface: [`super::Regions::OneBand`]), so no leaf's triangles are tested for
    /// crossing each other.
    pub(crate) fn crowded(
        &mut self,
        tree: &Flat,
        tris: &[Tri],
        boxes: &[[f32; 6]],
        grid: &Grid,
        dmax: u32,
        embedded: bool,
    ) -> Vec<bool> {
        let key = |leaf: u32| {
            let n = &tree.nodes[leaf as usize];
            (n.depth, n.cell.to_array())
        };
        // Leaves of at least `REUSE_TRIANGLES` keep what was found about them for the next pass.
        let heavy = |leaf: u32| match &tree.nodes[leaf as usize].kind {
            Kind::Surface(s) => s.tris.len() >= REUSE_TRIANGLES,
            Kind::Internal { .. } => false,
        };
        let crosses = &self.crosses;
        let found: Vec<(u32, bool)> = tree
            .surface
            .par_iter()
            .map(|&leaf| {
                let known = heavy(leaf).then(|| crosses.get(&key(leaf))).flatten();
                let c = match (known, &tree.nodes[leaf as usize].kind) {
                    (Some(&c), _) => c,
                    (None, Kind::Surface(s)) => !embedded && crosses_itself(&s.tris, tris),
                    (None, Kind::Internal { .. }) => false,
                };
                (leaf, c)
            })
            .collect();
        let mut crossing = vec![false; tree.nodes.len()];
        for (leaf, c) in found {
            crossing[leaf as usize] = c;
            if heavy(leaf) {
                self.crosses.insert(key(leaf), c);
            }
        }
        let grow = UVec3::splat(1 << (MAX_DEPTH - dmax));
        let end = UVec3::splat(1 << MAX_DEPTH);
        let (joins, known) = (&self.joins, &self.sheets);
        // `Some(sheets > 1)` where it was asked, `None` where a crossing leaf nearby decides.
        let flags: Vec<(u32, Option<bool>, Vec<LeafKey>)> = tree
            .surface
            .par_iter()
            .map_init(
                || (Marks::new(), Vec::new()),
                |(marks, near), &leaf| {
                    let (lo, hi) = tree.nodes[leaf as usize].range();
                    let (qlo, qhi) = (lo.saturating_sub(grow), (hi + grow).min(end));
                    // The surface leaves that touch the grown box, found once for both uses.
                    near.clear();
                    tree.for_each_touching_surface(qlo, qhi, |n| near.push(n));
                    let near_crossing = near.iter().any(|&n| crossing[n as usize]);
                    let around: Vec<LeafKey> = if heavy(leaf) {
                        near.iter().map(|&n| key(n)).collect()
                    } else {
                        Vec::new()
                    };
                    if near_crossing {
                        return (leaf, None, around);
                    }
                    let was = heavy(leaf).then(|| known.get(&key(leaf))).flatten();
                    if let Some((_, many)) = was.filter(|(keys, _)| *keys == around) {
                        return (leaf, Some(*many), around);
                    }
                    let (wlo, whi) = (grid.point(qlo), grid.point(qhi));
                    let far = BoxFilter::new(wlo, whi);
                    marks.clear();
                    for &n in near.iter() {
                        let node = &tree.nodes[n as usize];
                        let Kind::Surface(s) = &node.kind else {
                            continue;
                        };
                        // A leaf inside the grown box brings all its triangles (each meets
                        // it); one across its boundary, those that meet the box; one beside
                        // it, none. Each triangle once (a triangle is in every leaf it meets).
                        let (nlo, nhi) = node.range();
                        if nlo.cmpge(qlo).all() && nhi.cmple(qhi).all() {
                            for &t in &s.tris {
                                marks.add(t);
                            }
                        } else if nlo.cmplt(qhi).all() && nhi.cmpgt(qlo).all() {
                            for &t in &s.tris {
                                if !far.misses(&boxes[t as usize])
                                    && !marks.has(t)
                                    && geom::triangle_overlaps_box(&tris[t as usize].v(), wlo, whi)
                                {
                                    marks.add(t);
                                }
                            }
                        }
                    }
                    (leaf, Some(sheets(marks, joins) > 1), around)
                },
            )
            .collect();
        let mut out = vec![false; tree.nodes.len()];
        for (leaf, many, around) in flags {
            out[leaf as usize] = many.unwrap_or(true);
            if let Some(many) = many.filter(|_| heavy(leaf)) {
                self.sheets.insert(key(leaf), (around, many));
            }
        }
        out
    }
}

/// No neighbour across an edge.
const NONE: u32 = u32::MAX;

/// Per triangle, its neighbour across each edge (from vertex `k`) where that edge is manifold
/// across the whole scene: used by exactly two triangles, once in each direction; [`NONE`]
/// elsewhere.
fn manifold_edges(tris: &[Tri]) -> Vec<[u32; 3]> {
    let edges = DirectedEdge::sorted(tris.len(), |t| Some(tris[t].vid));
    let mut joins = vec![[NONE; 3]; tris.len()];
    for group in edges.chunk_by(|x, y| x.key == y.key) {
        if let [a, b] = group {
            if a.forward() != b.forward() {
                joins[a.triangle() as usize][a.edge() as usize] = b.triangle();
                joins[b.triangle() as usize][b.edge() as usize] = a.triangle();
            }
        }
    }
    joins
}

/// How many sheets (sets joined by manifold edges, `joins`) the triangles gathered in `marks`
/// make.
fn sheets(marks: &Marks, joins: &[[u32; 3]]) -> usize {
    let set = &marks.list;
    let mut parent: Vec<u32> = (0..set.len() as u32).collect();
    fn find(p: &mut [u32], mut x: u32) -> u32 {
        while p[x as usize] != x {
            p[x as usize] = p[p[x as usize] as usize];
            x = p[x as usize];
        }
        x
    }
    let mut roots = set.len();
    for (i, &t) in set.iter().enumerate() {
        for &n in &joins[t as usize] {
            // Each joined pair once: from its smaller triangle.
            if n == NONE || n < t {
                continue;
            }
            if let Some(j) = marks.place(n) {
                let (a, b) = (find(&mut parent, i as u32), find(&mut parent, j));
                if a != b {
                    parent[a as usize] = b;
                    roots -= 1;
                }
            }
        }
    }
    roots
}

/// The triangles gathered for one grown box, in the order added, each once, with an
/// open-addressing table (linear probing) from a triangle to its place in that list, so that
/// membership is one probe or a few instead of a sort and a binary search. A new number per
/// gathering empties the table at once; it doubles when half full.
struct Marks {
    current: u32,
    /// Per slot: the gathering that filled it (`current` when filled now).
    stamp: Vec<u32>,
    keys: Vec<u32>,
    place: Vec<u32>,
    /// The triangles added since the last [`Marks::clear`], in order.
    list: Vec<u32>,
}

impl Marks {
    fn new() -> Self {
        Self::with_slots(1024, Vec::new())
    }

    /// A table of `slots` (a power of two) holding `list`.
    fn with_slots(slots: usize, list: Vec<u32>) -> Self {
        let mut m = Marks {
            current: 1,
            stamp: vec![0; slots],
            keys: vec![0; slots],
            place: vec![0; slots],
            list,
        };
        for k in 0..m.list.len() {
            let t = m.list[k];
            m.fill(m.slot(t), t, k as u32);
        }
        m
    }

    /// Empties it for the next gathering.
    fn clear(&mut self) {
        if self.current == u32::MAX {
            self.stamp.fill(0);
            self.current = 0;
        }
        self.current += 1;
        self.list.clear();
    }

    /// The slot of `t`, or the empty slot where it would go.
    #[inline]
    fn slot(&self, t: u32) -> usize {
        let mask = self.keys.len() - 1;
        let mut i = (t.wrapping_mul(0x9e37_79b1) >> 8) as usize & mask;
        while self.stamp[i] == self.current && self.keys[i] != t {
            i = (i + 1) & mask;
        }
        i
    }

    #[inline]
    fn fill(&mut self, i: usize, t: u32, place: u32) {
        self.stamp[i] = self.current;
        self.keys[i] = t;
        self.place[i] = place;
    }

    #[inline]
    fn has(&self, t: u32) -> bool {
        self.place(t).is_some()
    }

    /// Adds `t` unless it is there.
    #[inline]
    fn add(&mut self, t: u32) {
        let i = self.slot(t);
        if self.stamp[i] == self.current {
            return;
        }
        self.fill(i, t, self.list.len() as u32);
        self.list.push(t);
        if 2 * self.list.len() > self.keys.len() {
            let list = core::mem::take(&mut self.list);
            *self = Self::with_slots(2 * self.keys.len(), list);
        }
    }

    /// The place of `t` in [`Marks::list`], if it was added.
    #[inline]
    fn place(&self, t: u32) -> Option<u32> {
        let i = self.slot(t);
        (self.stamp[i] == self.current).then(|| self.place[i])
    }
}

/// A triangle's box in `f32`, each bound rounded outward (the `f64` box lies inside it).
pub(crate) fn outward_box(v: &[DVec3; 3]) -> [f32; 6] {
    let (lo, hi) = bounds(v);
    let down = |x: f64| {
        let f = x as f32;
        if f as f64 > x {
            f.next_down()
        } else {
            f
        }
    };
    let up = |x: f64| {
        let f = x as f32;
        if (f as f64) < x {
            f.next_up()
        } else {
            f
        }
    };
    [
        down(lo.x),
        down(lo.y),
        down(lo.z),
        up(hi.x),
        up(hi.y),
        up(hi.z),
    ]
}

/// The first test of whether a triangle can meet the box `[lo, hi]`: its outward `f32` box
/// ([`outward_box`]) beyond the box grown by a millionth of the sizes involved on some axis.
/// [`geom::triangle_overlaps_box`] separates such a triangle on that axis too (its rounding is
/// about 10⁻¹⁶ of those sizes), so the set gathered is the same.
struct BoxFilter {
    lo: [f64; 3],
    hi: [f64; 3],
}

impl BoxFilter {
    fn new(lo: DVec3, hi: DVec3) -> Self {
        let margin =
            1e-6 * (lo.abs().max_element() + hi.abs().max_element() + (hi - lo).max_element());
        BoxFilter {
            lo: (lo - DVec3::splat(margin)).to_array(),
            hi: (hi + DVec3::splat(margin)).to_array(),
        }
    }

    #[inline]
    fn misses(&self, b: &[f32; 6]) -> bool {
        (0..3).any(|a| (b[a] as f64) > self.hi[a] || (b[a + 3] as f64) < self.lo[a])
    }
}

/// Whether two of the triangles `list` cross or touch each other away from a shared vertex:
/// an edge of one meets the other. Pairs sharing an edge are not tested (neighbours in a mesh
/// touch there), nor are coplanar pairs (the segment test misses them). Pairs sharing one
/// vertex (a fan folded through itself, as sculpted and decimated meshes have) cross exactly
/// when the edge of one opposite that vertex meets the other: their intersection is a segment
/// from the vertex, and it ends on one of those edges.
fn crosses_itself(list: &[u32], tris: &[Tri]) -> bool {
    // Sweep along x over the triangles' boxes: only pairs whose boxes overlap are tested.
    // Each triangle's box, found once (not once per pair).
    let mut boxes: Vec<(DVec3, DVec3, u32)> = list
        .iter()
        .map(|&t| {
            let (lo, hi) = bounds(&tris[t as usize].v());
            (lo, hi, t)
        })
        .collect();
    boxes.sort_unstable_by(|a, b| a.0.x.total_cmp(&b.0.x));
    for (i, &(alo, ahi, a)) in boxes.iter().enumerate() {
        let ta = &tris[a as usize];
        for &(blo, bhi, b) in &boxes[i + 1..] {
            if blo.x > ahi.x {
                break;
            }
            if alo.cmpgt(bhi).any() || blo.cmpgt(ahi).any() {
                continue;
            }
            let tb = &tris[b as usize];
            let shared = ta.vid.iter().filter(|v| tb.vid.contains(v)).count();
            if shared >= 2 || (shared == 1 && fan_apart(ta, tb)) {
                continue;
            }
            if edges_meet(ta, tb, shared) {
                return true;
            }
        }
    }
    false
}

/// Whether an edge of either of two triangles that share `shared` (0 or 1) vertices meets the
/// other: with a shared vertex, only the edge opposite it. Edge k runs from vertex k to vertex
/// k + 1.
fn edges_meet(a: &Tri, b: &Tri, shared: usize) -> bool {
    let meets = |p: &Tri, q: &Tri| {
        let (pv, qv) = (p.v(), q.v());
        (0..3).any(|k| {
            let (i, j) = (k, (k + 1) % 3);
            let away = shared == 0 || !(q.vid.contains(&p.vid[i]) || q.vid.contains(&p.vid[j]));
            away && !apart(pv[i], pv[j], q) && geom::segment_triangle(pv[i], pv[j], &qv).is_some()
        })
    };
    meets(a, b) || meets(b, a)
}

/// Whether two triangles that share one vertex `V` clearly do not cross, as two triangles of
/// a fan around `V` that lies flat do not: seen along `d = n_p + n_q` (both triangles face
/// `d`, each by at least half), the two are wedges at `V`, and a line through `V` (along one
/// of their four sides, or through a gap between two) has one wedge on each side of it, one of
/// them away from it by a sine of 10⁻⁶. Then the projections meet only at `V`, and the edge of
/// one opposite `V`, which is at least a thousandth of the pair's longest edge from `V`
/// (neither is a needle seen from `V`), misses the other by far more than the rounding of
/// [`geom::segment_triangle`], which would miss too. `false` leaves the pair to that test: a
/// folded fan, a needle, triangles facing apart, or a wedge near another's side.
#[inline]
fn fan_apart(p: &Tri, q: &Tri) -> bool {
    let (Some(i), Some(j)) = (
        p.vid.iter().position(|v| q.vid.contains(v)),
        q.vid.iter().position(|v| p.vid.contains(v)),
    ) else {
        return false;
    };
    if p.n.dot(q.n) < -0.5 {
        return false;
    }
    let d = p.n + q.n;
    // The wedges' sides, from `V`, in each triangle's winding order: `orient(a, b) > 0`.
    let (pv, qv) = (p.v(), q.v());
    let vertex = pv[i];
    let (a, b) = (pv[(i + 1) % 3] - vertex, pv[(i + 2) % 3] - vertex);
    let (c, e) = (qv[(j + 1) % 3] - vertex, qv[(j + 2) % 3] - vertex);
    // Squared lengths: the tests below compare squares, with no square root until a line
    // through a gap is needed.
    let sides = [a, b, c, e];
    let len2 = sides.map(|x| x.length_squared());
    let longest2 = len2.into_iter().fold(
        (b - a).length_squared().max((e - c).length_squared()),
        f64::max,
    );
    // Twice each area is its height over the opposite edge times that edge (at most the
    // longest edge): heights of at least a thousandth of the longest.
    let stout = |area: f64| 2.0 * area >= 1e-3 * longest2;
    if !(stout(p.area) && stout(q.area)) {
        return false;
    }
    let m2 = 1e-12 * d.length_squared();
    // A line through `V` along `s` separates the wedges when one lies on one side of it (or
    // on it) and the other strictly on the other side, by a sine of more than 10⁻⁶ seen along
    // `d`. Lines along the four sides, then through the gaps between them.
    let separates = |s: DVec3| {
        let ls2 = s.length_squared();
        let o = sides.map(|x| s.cross(x).dot(d));
        // On side `sign` of the line (or on it); strictly on that side.
        let on = |k: usize, sign: f64| o[k] * sign >= 0.0;
        let beyond = |k: usize, sign: f64| o[k] * sign > 0.0 && o[k] * o[k] > m2 * ls2 * len2[k];
        [1.0, -1.0].iter().any(|&sign| {
            (on(0, -sign) && on(1, -sign) && beyond(2, sign) && beyond(3, sign))
                || (on(2, -sign) && on(3, -sign) && beyond(0, sign) && beyond(1, sign))
        })
    };
    if sides.into_iter().any(separates) {
        return true;
    }
    let unit = |k: usize| sides[k] / len2[k].sqrt();
    separates(unit(1) + unit(2)) || separates(unit(3) + unit(0))
}

/// Whether the segment `a`–`b` lies clearly on one side of the plane of `q`: both ends
/// farther from it than a billionth of the sizes involved, the plane's crossing clearly
/// beyond the segment's ends, and `q` no needle (the sine of its angle above 10⁻⁶). Then [`geom::segment_triangle`] misses too (its
/// rounding is far smaller), and is not called: most pairs of neighbours in a fine mesh
/// are such.
#[inline]
fn apart(a: DVec3, b: DVec3, q: &Tri) -> bool {
    // A needle's normal is good only to about ε over the sine of its angle: leave it to the
    // exact test.
    let v = q.v();
    let (e1, e2) = (v[1] - v[0], v[2] - v[0]);
    let twice_area = 2.0 * q.area;
    if twice_area * twice_area < 1e-12 * e1.length_squared() * e2.length_squared() {
        return false;
    }
    let (da, db) = ((a - v[0]).dot(q.n), (b - v[0]).dot(q.n));
    if !(da * db > 0.0) {
        return false;
    }
    let near = da.abs().min(db.abs());
    let size2 = (a - v[0]).length_squared()
        + (b - v[0]).length_squared()
        + e1.length_squared()
        + e2.length_squared();
    near * near > 1e-18 * size2 && near > 1e-9 * (da - db).abs()
}

fn bounds(v: &[DVec3; 3]) -> (DVec3, DVec3) {
    (v[0].min(v[1]).min(v[2]), v[0].max(v[1]).max(v[2]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::{gather, BuildReport, MeshRef};

    fn sheets_of(set: &[u32], joins: &[[u32; 3]]) -> usize {
        let mut marks = Marks::new();
        for &t in set {
            marks.add(t);
        }
        sheets(&marks, joins)
    }

    fn tris(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Vec<Tri> {
        let mesh = MeshRef {
            positions,
            triangles,
        };
        gather(&[mesh], &mut BuildReport::default()).unwrap()
    }

    /// Two triangles around the origin, `[0, 1, 2]` and `[0, 3, 4]`, the second folded
    /// through the first; `[0, 4, 5]` folded up and away from it.
    const FOLDED_FAN: [[f32; 3]; 6] = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.3, 0.3, -0.5],
        [0.3, 0.3, 0.5],
        [0.6, 0.0, 0.5],
    ];

    #[test]
    fn triangles_crossing_each_other_are_found_and_neighbours_are_not() {
        let flat = [[-1.0, 0.0, -1.0], [1.0, 0.0, -1.0], [0.0, 0.0, 1.0]];
        // Through the first, sharing no vertex.
        let across = [[0.0, -1.0, 0.0], [0.0, 1.0, 0.0], [0.3, 0.0, -0.6]];
        let mut positions = flat.to_vec();
        positions.extend(across);
        let t = tris(&positions, &[[0, 2, 1], [3, 4, 5]]);
        assert!(crosses_itself(&[0, 1], &t));
        // Moved off it: apart.
        let lifted: Vec<[f32; 3]> = positions
            .iter()
            .enumerate()
            .map(|(i, p)| if i >= 3 { [p[0], p[1] + 2.5, p[2]] } else { *p })
            .collect();
        let t = tris(&lifted, &[[0, 2, 1], [3, 4, 5]]);
        assert!(!crosses_itself(&[0, 1], &t));
        // Sharing one vertex: a fan folded through itself crosses (the far edge of the second
        // goes through the first at (0.3, 0.3, 0)); folded up and away, it only touches there.
        let fan = FOLDED_FAN;
        let t = tris(&fan, &[[0, 1, 2], [0, 3, 4]]);
        assert!(crosses_itself(&[0, 1], &t));
        assert!(crosses_itself(&[1, 0], &t));
        let t = tris(&fan, &[[0, 1, 2], [0, 4, 5]]);
        assert!(!crosses_itself(&[0, 1], &t));
        // A quad's two triangles share an edge: neighbours, one sheet.
        let quad = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 0.0, 1.0],
            [0.0, 0.0, 1.0],
        ];
        let t = tris(&quad, &[[0, 2, 1], [0, 3, 2]]);
        assert!(!crosses_itself(&[0, 1], &t));
        let joins = manifold_edges(&t);
        assert_eq!(sheets_of(&[0, 1], &joins), 1);
        // Wound the same way across the shared edge: not joined there, two sheets.
        let t = tris(&quad, &[[0, 2, 1], [0, 2, 3]]);
        let joins = manifold_edges(&t);
        assert_eq!(sheets_of(&[0, 1], &joins), 2);
    }

    /// A grid of `w × w` quads (two triangles each), wound alike: one sheet.
    fn sheet(w: u32, y: f32) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        let mut positions = Vec::new();
        for j in 0..=w {
            for i in 0..=w {
                positions.push([i as f32, y, j as f32]);
            }
        }
        let at = |i: u32, j: u32| j * (w + 1) + i;
        let mut triangles = Vec::new();
        for j in 0..w {
            for i in 0..w {
                let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                triangles.push([a, c, b]);
                triangles.push([a, d, c]);
            }
        }
        (positions, triangles)
    }

    #[test]
    fn sheets_are_counted_in_sets_larger_than_the_marks_first_table() {
        // 2 × 30 × 30 = 1,800 triangles: the table (1,024 slots) doubles twice.
        let (mut positions, mut triangles) = sheet(30, 0.0);
        let (p2, t2) = sheet(30, 1.0);
        let base = positions.len() as u32;
        positions.extend(p2);
        triangles.extend(t2.iter().map(|t| t.map(|i| i + base)));
        let t = tris(&positions, &triangles);
        let joins = manifold_edges(&t);
        let one: Vec<u32> = (0..1800).collect();
        assert_eq!(sheets_of(&one, &joins), 1);
        // Out of order and with repeats: the marks keep each triangle once.
        let mut shuffled: Vec<u32> = (0..1800).rev().collect();
        shuffled.extend(0..100);
        assert_eq!(sheets_of(&shuffled, &joins), 1);
        let both: Vec<u32> = (0..3600).collect();
        assert_eq!(sheets_of(&both, &joins), 2);
        // A row of quads cut out of the middle of the first sheet splits it in two.
        let cut: Vec<u32> = (0..1800).filter(|&k| k / 60 != 15).collect();
        assert_eq!(sheets_of(&cut, &joins), 2);
        let mut marks = Marks::new();
        for &k in &shuffled {
            marks.add(k);
        }
        assert_eq!(marks.list.len(), 1800);
        for (place, &k) in marks.list.iter().enumerate() {
            assert_eq!(marks.place(k), Some(place as u32));
        }
        assert_eq!(marks.place(5000), None);
        marks.clear();
        assert!(!marks.has(0) && marks.place(1799).is_none());
    }

    #[test]
    fn the_box_filter_passes_every_triangle_the_exact_test_keeps() {
        let mut rng = crate::emit::Rng::new(3);
        let mut kept = 0;
        let mut filtered = 0;
        for round in 0..20_000 {
            // Boxes far from the origin too, where the f32 box rounds coarsely.
            let offset = if round % 2 == 0 { 0.0 } else { 1.0e5 };
            let c = DVec3::new(
                rng.range(-1.0, 1.0) as f64,
                rng.range(-1.0, 1.0) as f64,
                rng.range(-1.0, 1.0) as f64,
            ) + offset;
            let h = rng.range(0.01, 0.5) as f64;
            let (lo, hi) = (c - DVec3::splat(h), c + DVec3::splat(h));
            // A small triangle about a point near the box's faces, where the two tests could
            // disagree: inside, outside, or across them.
            let mut near = || rng.range(-1.3, 1.3) as f64;
            let at = c + DVec3::new(near(), near(), near()) * h;
            let mut jitter = || {
                DVec3::new(
                    rng.range(-0.1, 0.1) as f64,
                    rng.range(-0.1, 0.1) as f64,
                    rng.range(-0.1, 0.1) as f64,
                ) * h
            };
            let v = [at + jitter(), at + jitter(), at + jitter()];
            let exact = geom::triangle_overlaps_box(&v, lo, hi);
            let misses = BoxFilter::new(lo, hi).misses(&outward_box(&v));
            assert!(
                !(misses && exact),
                "filtered a triangle that meets the box: {v:?}"
            );
            kept += exact as u32;
            filtered += misses as u32;
        }
        // Both outcomes are exercised.
        assert!(
            kept > 1000 && filtered > 1000,
            "{kept} kept, {filtered} filtered"
        );
    }

    /// Whether the crossing test finds a pair sharing one vertex crossing, as
    /// `crosses_itself` asks it when `fan_apart` lets the pair through.
    fn fan_crosses(p: &Tri, q: &Tri) -> bool {
        edges_meet(p, q, 1)
    }

    #[test]
    fn a_fan_is_apart_only_where_the_exact_test_finds_no_crossing() {
        // A flat fan of six around the origin: every pair apart, none crossing.
        let mut positions = vec![[0.0f32; 3]];
        for k in 0..6 {
            let a = k as f32 * std::f32::consts::TAU / 6.0;
            positions.push([a.cos(), 0.1 * (3.0 * a).sin(), a.sin()]);
        }
        let triangles: Vec<[u32; 3]> = (0..6).map(|k| [0, 1 + (k + 1) % 6, 1 + k]).collect();
        let t = tris(&positions, &triangles);
        for a in 0..6 {
            for b in 0..6 {
                if (a as i32 - b as i32).rem_euclid(6) > 1
                    && (b as i32 - a as i32).rem_euclid(6) > 1
                {
                    assert!(fan_apart(&t[a], &t[b]), "{a} and {b}");
                    assert!(!fan_crosses(&t[a], &t[b]));
                }
            }
        }
        // The folded fan crosses, and is not apart.
        let t = tris(&FOLDED_FAN, &[[0, 1, 2], [0, 3, 4]]);
        assert!(fan_crosses(&t[0], &t[1]) && !fan_apart(&t[0], &t[1]));
        // Random pairs around one vertex, many nearly touching: apart never where the exact
        // test finds a crossing, and both outcomes exercised.
        let mut rng = crate::emit::Rng::new(11);
        let (mut apart, mut crossing) = (0, 0);
        for round in 0..20_000 {
            let offset = if round % 2 == 0 { 0.0 } else { 1.0e4 };
            let point = |rng: &mut crate::emit::Rng| {
                [
                    offset + rng.range(-1.0, 1.0),
                    rng.range(-0.3, 0.3),
                    rng.range(-1.0, 1.0),
                ]
            };
            let v = [offset, 0.0, 0.0];
            let mut positions = vec![v, point(&mut rng), point(&mut rng), point(&mut rng)];
            // Half the rounds: the third point on the first triangle's plane, near its far
            // edge, where the two nearly touch.
            if round % 4 < 2 {
                let (a, b) = (positions[1], positions[2]);
                let w = rng.range(-0.05, 1.05);
                let u = rng.range(-0.01, 0.01);
                positions[3] = std::array::from_fn(|k| {
                    v[k] + (a[k] - v[k]) * w + (b[k] - v[k]) * (1.0 - w) + u * (b[k] - a[k])
                });
            }
            positions.push(point(&mut rng));
            let t = [[0, 1, 2], [0, 3, 4]].map(|ids: [u32; 3]| {
                let v = ids.map(|i| DVec3::from(positions[i as usize].map(f64::from)));
                let c = (v[1] - v[0]).cross(v[2] - v[0]);
                Tri {
                    p: ids.map(|i| glam::Vec3::from_array(positions[i as usize])),
                    n: c / c.length(),
                    area: 0.5 * c.length(),
                    closed: false,
                    rim: 0,
                    component: 0,
                    vid: ids,
                }
            });
            if !(t[0].area > 0.0 && t[1].area > 0.0) {
                continue;
            }
            let (is_apart, crosses) = (fan_apart(&t[0], &t[1]), fan_crosses(&t[0], &t[1]));
            assert!(!(is_apart && crosses), "apart but crossing: {positions:?}");
            apart += is_apart as u32;
            crossing += crosses as u32;
        }
        assert!(
            apart > 2_000 && crossing > 2_000,
            "{apart} apart, {crossing} crossing"
        );
    }
}
