//! Exact ground truth for a triangle mesh, through a bounding-volume hierarchy: how many
//! triangles a segment crosses, the distance to the surface, and inside/outside of closed
//! meshes by the parity of crossings along three rays (majority vote, so a ray grazing an
//! edge cannot decide alone).

use glam::DVec3;

#[derive(Clone, Copy)]
struct Node {
    lo: DVec3,
    hi: DVec3,
    /// Leaf: first triangle and count; internal: left child index and 0 (right is next).
    start: u32,
    count: u32,
    right: u32,
}

/// A mesh prepared for exact queries.
pub struct GroundTruth {
    tris: Vec<[DVec3; 3]>,
    nodes: Vec<Node>,
    lo: DVec3,
    hi: DVec3,
}

fn tri_box(t: &[DVec3; 3]) -> (DVec3, DVec3) {
    (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]))
}

impl GroundTruth {
    /// Prepares the mesh (zero-area and out-of-range triangles are left out).
    pub fn new(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Self {
        let mut tris: Vec<[DVec3; 3]> = triangles
            .iter()
            .filter_map(|t| {
                let v = t.map(|i| positions.get(i as usize).map(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)));
                let v = [v[0]?, v[1]?, v[2]?];
                ((v[1] - v[0]).cross(v[2] - v[0]).length() > 0.0).then_some(v)
            })
            .collect();
        let mut nodes = Vec::with_capacity(2 * tris.len() / 4 + 1);
        let n = tris.len();
        if n > 0 {
            build(&mut tris, 0, n, &mut nodes);
        }
        let (lo, hi) = nodes.first().map(|r| (r.lo, r.hi)).unwrap_or((DVec3::ZERO, DVec3::ZERO));
        GroundTruth { tris, nodes, lo, hi }
    }

    /// Triangles kept.
    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }

    /// Number of triangles the closed segment `a → b` touches.
    pub fn segment_crossings(&self, a: [f32; 3], b: [f32; 3]) -> u32 {
        let a = DVec3::from_array(a.map(f64::from));
        let b = DVec3::from_array(b.map(f64::from));
        if a == b {
            return 0;
        }
        self.count_hits(a, b)
    }

    fn count_hits(&self, a: DVec3, b: DVec3) -> u32 {
        if self.nodes.is_empty() {
            return 0;
        }
        let d = b - a;
        let inv = DVec3::ONE / d;
        let mut hits = 0;
        let mut stack = vec![0u32];
        while let Some(i) = stack.pop() {
            let n = &self.nodes[i as usize];
            if !segment_box(a, inv, n.lo, n.hi) {
                continue;
            }
            if n.count > 0 {
                for t in &self.tris[n.start as usize..(n.start + n.count) as usize] {
                    if segment_hits_triangle(a, b, t) {
                        hits += 1;
                    }
                }
            } else {
                stack.push(n.start);
                stack.push(n.right);
            }
        }
        hits
    }

    /// Whether `p` is inside a closed mesh: odd crossings along at least two of three rays.
    pub fn is_inside(&self, p: [f32; 3]) -> bool {
        let p = DVec3::from_array(p.map(f64::from));
        if !(p.cmpge(self.lo).all() && p.cmple(self.hi).all()) {
            return false;
        }
        let reach = (self.hi - self.lo).length() * 2.0 + 1.0;
        let dirs = [
            DVec3::new(0.5773, 0.6123, 0.5402).normalize(),
            DVec3::new(-0.7071, 0.3011, 0.6397).normalize(),
            DVec3::new(0.2113, -0.8902, 0.4037).normalize(),
        ];
        let odd = dirs.iter().filter(|d| self.count_hits(p, p + **d * reach) % 2 == 1).count();
        odd >= 2
    }

    /// Distance from `p` to the surface.
    pub fn distance(&self, p: [f32; 3]) -> f64 {
        let p = DVec3::from_array(p.map(f64::from));
        if self.nodes.is_empty() {
            return f64::INFINITY;
        }
        let mut best = f64::INFINITY;
        let mut stack = vec![0u32];
        while let Some(i) = stack.pop() {
            let n = &self.nodes[i as usize];
            let d = (p.clamp(n.lo, n.hi) - p).length_squared();
            if d >= best {
                continue;
            }
            if n.count > 0 {
                for t in &self.tris[n.start as usize..(n.start + n.count) as usize] {
                    best = best.min((closest_point(p, t) - p).length_squared());
                }
            } else {
                let (l, r) = (&self.nodes[n.start as usize], &self.nodes[n.right as usize]);
                let dl = (p.clamp(l.lo, l.hi) - p).length_squared();
                let dr = (p.clamp(r.lo, r.hi) - p).length_squared();
                if dl < dr {
                    stack.push(n.right);
                    stack.push(n.start);
                } else {
                    stack.push(n.start);
                    stack.push(n.right);
                }
            }
        }
        best.sqrt()
    }
}

fn build(tris: &mut [[DVec3; 3]], start: usize, end: usize, nodes: &mut Vec<Node>) -> u32 {
    let id = nodes.len() as u32;
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for t in &tris[start..end] {
        let (a, b) = tri_box(t);
        lo = lo.min(a);
        hi = hi.max(b);
    }
    nodes.push(Node { lo, hi, start: start as u32, count: (end - start) as u32, right: 0 });
    if end - start <= 4 {
        return id;
    }
    let axis = (hi - lo).max_position();
    let mid = (start + end) / 2;
    let key = |t: &[DVec3; 3]| (t[0][axis] + t[1][axis] + t[2][axis]) / 3.0;
    tris[start..end].select_nth_unstable_by(mid - start, |a, b| key(a).total_cmp(&key(b)));
    let left = build(tris, start, mid, nodes);
    let right = build(tris, mid, end, nodes);
    nodes[id as usize] = Node { lo, hi, start: left, count: 0, right };
    id
}

fn segment_box(a: DVec3, inv: DVec3, lo: DVec3, hi: DVec3) -> bool {
    let mut t0: f64 = 0.0;
    let mut t1: f64 = 1.0;
    for k in 0..3 {
        let (mut ta, mut tb) = ((lo[k] - a[k]) * inv[k], (hi[k] - a[k]) * inv[k]);
        if ta.is_nan() || tb.is_nan() {
            // Parallel to the slab and on its boundary plane: inside iff within it.
            if a[k] < lo[k] || a[k] > hi[k] {
                return false;
            }
            continue;
        }
        if ta > tb {
            std::mem::swap(&mut ta, &mut tb);
        }
        t0 = t0.max(ta);
        t1 = t1.min(tb);
    }
    t0 <= t1 * (1.0 + 1e-12) + 1e-300
}

/// Exact-enough segment–triangle intersection (closed triangle, closed segment), f64.
fn segment_hits_triangle(a: DVec3, b: DVec3, v: &[DVec3; 3]) -> bool {
    // Signed volumes: the segment's ends on opposite sides of the plane, and the segment's
    // line on the same side of each edge.
    let vol = |p: DVec3, q: DVec3, r: DVec3, s: DVec3| (q - p).cross(r - p).dot(s - p);
    let sa = vol(v[0], v[1], v[2], a);
    let sb = vol(v[0], v[1], v[2], b);
    if (sa > 0.0 && sb > 0.0) || (sa < 0.0 && sb < 0.0) || (sa == 0.0 && sb == 0.0) {
        return false;
    }
    let e0 = vol(a, b, v[0], v[1]);
    let e1 = vol(a, b, v[1], v[2]);
    let e2 = vol(a, b, v[2], v[0]);
    (e0 >= 0.0 && e1 >= 0.0 && e2 >= 0.0) || (e0 <= 0.0 && e1 <= 0.0 && e2 <= 0.0)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes;

    #[test]
    fn cube_queries() {
        let m = scenes::cube([-1.0; 3], [1.0; 3]);
        let gt = GroundTruth::new(&m.positions, &m.triangles);
        assert!(gt.is_inside([0.1, 0.2, 0.3]));
        assert!(!gt.is_inside([1.5, 0.2, 0.3]));
        assert!((gt.distance([0.5, 0.0, 0.0]) - 0.5).abs() < 1e-9);
        assert!((gt.distance([3.0, 0.0, 0.0]) - 2.0).abs() < 1e-9);
        assert!((gt.distance([2.0, 2.0, 0.0]) - 2f64.sqrt()).abs() < 1e-9);
        assert_eq!(gt.segment_crossings([-3.0, 0.1, 0.2], [3.0, 0.1, 0.2]), 2);
        assert_eq!(gt.segment_crossings([0.0, 0.1, 0.2], [3.0, 0.1, 0.2]), 1);
        assert_eq!(gt.segment_crossings([2.0, 0.1, 0.2], [3.0, 0.1, 0.2]), 0);
    }

    #[test]
    fn sphere_inside_matches_radius() {
        let m = scenes::uv_sphere([0.0; 3], 1.0, 64, 32);
        let gt = GroundTruth::new(&m.positions, &m.triangles);
        let mut s = 5u64;
        for _ in 0..2000 {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let r = |k: u32| ((s >> k) & 0xffff) as f32 / 65535.0 * 3.0 - 1.5;
            let p = [r(0), r(16), r(32)];
            let len = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            if (len - 1.0).abs() > 0.01 {
                assert_eq!(gt.is_inside(p), len < 1.0, "{p:?}");
            }
        }
    }
}
