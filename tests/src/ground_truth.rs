//! Exact ground truth for a triangle mesh, through a bounding-volume hierarchy: the
//! generalized winding number (inside/outside, robust to small holes and self-overlap), the
//! unsigned distance to the surface, and how many triangles a segment crosses.
//!
//! All geometry is kept in `f64`. The winding number follows Barill et al. 2018, "Fast
//! winding numbers for soups and clouds": near the query point triangles are summed exactly
//! (Van Oosterom–Strackee solid angle), far away a whole subtree contributes through its
//! dipole (area-weighted normal at the area-weighted centroid) plus the second-order term of
//! the same expansion. Segment crossings use exact orientation predicates (a floating-point
//! filter with an exact expansion-arithmetic fallback), so adjacent triangles agree about a
//! segment passing through their shared edge.

use glam::DVec3;

/// Triangles per leaf at most.
const LEAF_SIZE: usize = 4;

/// A node is treated as far when the query point is farther from its centroid than `BETA`
/// times the radius of the ball (around that centroid) holding all of its triangles.
const BETA: f64 = 2.0;

/// Depth of the fixed traversal stacks; median splits keep trees far shallower.
const STACK: usize = 96;

/// One node of the hierarchy.
#[derive(Clone, Copy, Debug)]
struct Node {
    /// Bounding box, slightly inflated so culling is conservative under rounding.
    lo: DVec3,
    hi: DVec3,
    /// Leaf: index of the first triangle; internal: index of the left child.
    start: u32,
    /// Leaf: number of triangles (positive); internal: 0.
    count: u32,
    /// Internal: index of the right child.
    right: u32,
}

/// The far-field expansion of one node.
#[derive(Clone, Copy, Debug)]
struct Far {
    /// Area-weighted centroid.
    c: DVec3,
    /// Sum of the area vectors (area times unit normal).
    n: DVec3,
    /// Second-order moment: the sum over triangles of `area_vector ⊗ (centroid - c)`, rows
    /// indexed by the normal component.
    m: [DVec3; 3],
    /// `(BETA * radius)²`: farther than this (squared) from `c` the expansion is used.
    far2: f64,
}

/// A triangle mesh prepared for exact queries. It is `Send + Sync`: query it from many
/// threads at once.
pub struct GroundTruth {
    /// Triangles in the leaves' order.
    tris: Vec<[DVec3; 3]>,
    /// The hierarchy; node 0 is the root (empty when there are no triangles).
    nodes: Vec<Node>,
    /// The far-field data, parallel to `nodes`.
    far: Vec<Far>,
}

fn to_d(p: [f32; 3]) -> DVec3 {
    DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}

impl GroundTruth {
    /// Prepares the mesh. Triangles with an out-of-range index, a non-finite vertex, or zero
    /// area are left out; nothing here panics on the input.
    pub fn new(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Self {
        let mut tris: Vec<[DVec3; 3]> = triangles
            .iter()
            .filter_map(|t| {
                let v = t.map(|i| positions.get(i as usize).map(|p| to_d(*p)));
                let v = [v[0]?, v[1]?, v[2]?];
                let finite = v.iter().all(|p| p.is_finite());
                (finite && (v[1] - v[0]).cross(v[2] - v[0]).length_squared() > 0.0).then_some(v)
            })
            .collect();
        let mut gt = GroundTruth { tris: Vec::new(), nodes: Vec::new(), far: Vec::new() };
        if tris.is_empty() {
            return gt;
        }
        // Sort by centroid through an index array, so each split moves only 8-byte items.
        let centroids: Vec<DVec3> = tris.iter().map(|t| (t[0] + t[1] + t[2]) / 3.0).collect();
        let mut order: Vec<u32> = (0..tris.len() as u32).collect();
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for t in &tris {
            lo = lo.min(t[0].min(t[1]).min(t[2]));
            hi = hi.max(t[0].max(t[1]).max(t[2]));
        }
        let scale = lo.abs().max(hi.abs()).max_element().max(f64::MIN_POSITIVE);
        let mut b = Builder {
            tris: &tris,
            centroids: &centroids,
            order: &mut order,
            nodes: Vec::with_capacity(2 * tris.len() / LEAF_SIZE + 2),
            far: Vec::with_capacity(2 * tris.len() / LEAF_SIZE + 2),
            pad: scale * 1e-12 + 1e-300,
        };
        b.build(0, tris.len());
        gt.nodes = b.nodes;
        gt.far = b.far;
        tris = order.iter().map(|&i| tris[i as usize]).collect();
        gt.tris = tris;
        gt
    }

    /// Triangles kept (after leaving out degenerate and invalid ones).
    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }

    /// The generalized winding number at `p`: the signed solid angle the surface subtends,
    /// over 4π. About 1 inside a closed, outward-facing mesh, about 0 outside; for open or
    /// leaky meshes it degrades gracefully. Near triangles are summed exactly, far subtrees
    /// through their second-order dipole expansion (error well under 1e-3).
    pub fn winding_number(&self, p: [f32; 3]) -> f64 {
        let p = to_d(p);
        if self.nodes.is_empty() {
            return 0.0;
        }
        let mut sum = 0.0;
        let mut stack = [0u32; STACK];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let i = stack[top] as usize;
            let f = &self.far[i];
            let r = f.c - p;
            let d2 = r.length_squared();
            if d2 > f.far2 {
                sum += far_solid_angle(f, r, d2);
                continue;
            }
            let n = &self.nodes[i];
            if n.count > 0 {
                for t in &self.tris[n.start as usize..(n.start + n.count) as usize] {
                    sum += solid_angle(t, p);
                }
            } else if top + 2 <= STACK {
                stack[top] = n.start;
                stack[top + 1] = n.right;
                top += 2;
            } else {
                // Unreachable for trees built here; stay exact rather than overflow.
                sum += self.exact_subtree(i, p);
            }
        }
        sum / (4.0 * core::f64::consts::PI)
    }

    /// The winding number summed exactly over every triangle (no far-field approximation).
    /// Linear in the triangle count: meant for checking [`GroundTruth::winding_number`].
    pub fn winding_number_exact(&self, p: [f32; 3]) -> f64 {
        let p = to_d(p);
        self.tris.iter().map(|t| solid_angle(t, p)).sum::<f64>() / (4.0 * core::f64::consts::PI)
    }

    fn exact_subtree(&self, i: usize, p: DVec3) -> f64 {
        let n = &self.nodes[i];
        if n.count > 0 {
            self.tris[n.start as usize..(n.start + n.count) as usize].iter().map(|t| solid_angle(t, p)).sum()
        } else {
            self.exact_subtree(n.start as usize, p) + self.exact_subtree(n.right as usize, p)
        }
    }

    /// Whether `p` is inside: `winding_number(p) >= 0.5`.
    pub fn is_inside(&self, p: [f32; 3]) -> bool {
        self.winding_number(p) >= 0.5
    }

    /// Unsigned distance from `p` to the closest point of the surface (infinite for a mesh
    /// with no triangles).
    pub fn distance(&self, p: [f32; 3]) -> f64 {
        let p = to_d(p);
        if self.nodes.is_empty() {
            return f64::INFINITY;
        }
        let box_d2 = |n: &Node| (p.clamp(n.lo, n.hi) - p).length_squared();
        let mut best = f64::INFINITY;
        // Each entry carries its box's squared distance, so a popped node is skipped cheaply.
        let mut stack = [(0u32, 0.0f64); STACK];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let (i, d) = stack[top];
            if d >= best {
                continue;
            }
            let n = &self.nodes[i as usize];
            if n.count > 0 {
                for t in &self.tris[n.start as usize..(n.start + n.count) as usize] {
                    best = best.min((closest_point(p, t) - p).length_squared());
                }
            } else {
                let dl = box_d2(&self.nodes[n.start as usize]);
                let dr = box_d2(&self.nodes[n.right as usize]);
                // The nearer child goes on top, to be visited first.
                let (near, far) = if dl <= dr { ((n.start, dl), (n.right, dr)) } else { ((n.right, dr), (n.start, dl)) };
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
        }
        best.sqrt()
    }

    fn distance2_subtree(&self, i: usize, p: DVec3) -> f64 {
        let n = &self.nodes[i];
        if n.count > 0 {
            self.tris[n.start as usize..(n.start + n.count) as usize]
                .iter()
                .map(|t| (closest_point(p, t) - p).length_squared())
                .fold(f64::INFINITY, f64::min)
        } else {
            self.distance2_subtree(n.start as usize, p).min(self.distance2_subtree(n.right as usize, p))
        }
    }

    /// Number of triangles the closed segment `a → b` crosses or touches (a segment through
    /// a shared edge or vertex counts once for every triangle there). A segment lying in a
    /// triangle's plane does not count for it. The tests are exact; `a == b` gives 0.
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
            if seg_hi.cmplt(n.lo).any() || seg_lo.cmpgt(n.hi).any() || !segment_box(a, inv, n.lo, n.hi) {
                continue;
            }
            if n.count > 0 {
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

    fn crossings_subtree(&self, i: usize, a: DVec3, b: DVec3) -> u32 {
        let n = &self.nodes[i];
        if n.count > 0 {
            self.tris[n.start as usize..(n.start + n.count) as usize]
                .iter()
                .map(|t| segment_hits_triangle(a, b, t) as u32)
                .sum()
        } else {
            self.crossings_subtree(n.start as usize, a, b) + self.crossings_subtree(n.right as usize, a, b)
        }
    }
}

/// Builds the hierarchy over `order` (indices into `tris`), depth first.
struct Builder<'a> {
    tris: &'a [[DVec3; 3]],
    centroids: &'a [DVec3],
    order: &'a mut [u32],
    nodes: Vec<Node>,
    far: Vec<Far>,
    /// How much every box is inflated.
    pad: f64,
}

impl Builder<'_> {
    fn build(&mut self, start: usize, end: usize) -> u32 {
        let id = self.nodes.len() as u32;
        let items = &self.order[start..end];
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
        let c = weighted / area;
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
        let pad = DVec3::splat(self.pad);
        self.nodes.push(Node { lo: lo - pad, hi: hi + pad, start: start as u32, count: (end - start) as u32, right: 0 });
        self.far.push(Far { c, n, m, far2: BETA * BETA * r2 });
        if end - start <= LEAF_SIZE {
            return id;
        }
        // Median split along the widest axis of the centroids.
        let axis = (chi - clo).max_position();
        let mid = (start + end) / 2;
        let cent = self.centroids;
        self.order[start..end]
            .select_nth_unstable_by(mid - start, |&x, &y| cent[x as usize][axis].total_cmp(&cent[y as usize][axis]));
        let left = self.build(start, mid);
        let right = self.build(mid, end);
        let node = &mut self.nodes[id as usize];
        node.start = left;
        node.count = 0;
        node.right = right;
        id
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

/// Signed solid angle of triangle `t` seen from `p` (Van Oosterom–Strackee), positive when
/// `p` is behind it (on the side its counter-clockwise normal points away from).
fn solid_angle(t: &[DVec3; 3], p: DVec3) -> f64 {
    let a = t[0] - p;
    let b = t[1] - p;
    let c = t[2] - p;
    let (la, lb, lc) = (a.length(), b.length(), c.length());
    let num = a.dot(b.cross(c));
    let den = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
    2.0 * num.atan2(den)
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

/// Whether the closed segment `a b` meets the closed triangle `v` (exact). A segment in the
/// triangle's plane does not count.
fn segment_hits_triangle(a: DVec3, b: DVec3, v: &[DVec3; 3]) -> bool {
    let sa = orient(v[0], v[1], v[2], a);
    let sb = orient(v[0], v[1], v[2], b);
    if sa == sb {
        // Both ends strictly on one side, or both in the plane.
        return false;
    }
    let e0 = orient(a, b, v[0], v[1]);
    let e1 = orient(a, b, v[1], v[2]);
    let e2 = orient(a, b, v[2], v[0]);
    (e0 >= 0 && e1 >= 0 && e2 >= 0) || (e0 <= 0 && e1 <= 0 && e2 <= 0)
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

    /// `e + b` (Grow-Expansion); expansions are nonoverlapping, smallest component first.
    fn grow(e: &[f64], b: f64) -> Vec<f64> {
        let mut out = Vec::with_capacity(e.len() + 1);
        let mut q = b;
        for &x in e {
            let (s, h) = two_sum(q, x);
            out.push(h);
            q = s;
        }
        out.push(q);
        out
    }

    /// `e + f`.
    fn sum(e: &[f64], f: &[f64]) -> Vec<f64> {
        let mut out = e.to_vec();
        for &x in f {
            out = grow(&out, x);
        }
        out
    }

    /// `e * b` (Scale-Expansion).
    fn scale(e: &[f64], b: f64) -> Vec<f64> {
        let mut out = Vec::with_capacity(2 * e.len());
        let Some((&first, rest)) = e.split_first() else { return out };
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
        out
    }

    /// `e * f`.
    fn mul(e: &[f64], f: &[f64]) -> Vec<f64> {
        let mut out = Vec::new();
        for &x in f {
            out = sum(&out, &scale(e, x));
        }
        out
    }

    fn neg(e: &[f64]) -> Vec<f64> {
        e.iter().map(|x| -x).collect()
    }

    /// `a - b` as a two-component expansion.
    fn diff(a: f64, b: f64) -> [f64; 2] {
        let (s, e) = two_sum(a, -b);
        [e, s]
    }

    /// Sign of a nonoverlapping expansion: that of its largest nonzero component.
    fn sign(e: &[f64]) -> i32 {
        match e.iter().rev().find(|x| **x != 0.0) {
            Some(x) if *x > 0.0 => 1,
            Some(_) => -1,
            None => 0,
        }
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
    let (a, b, c) = (t[0], t[1], t[2]);
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}
