//! Exact-enough f64 geometry for baking: triangle–box overlap by separating axes, clipping a
//! triangle to a box, segment–box and segment–triangle intersection.

use glam::DVec3;

/// Whether the segment `a`–`b` may touch the closed box `[min, max]`: `true` whenever it does,
/// and perhaps when it passes within a few rounding errors of it (the box is grown by a
/// millionth of its size, far more than the slab test's rounding, so no touch is missed).
pub fn segment_may_touch_box(a: DVec3, b: DVec3, min: DVec3, max: DVec3) -> bool {
    let pad =
        (max - min).max_element() * 1e-6 + (min.abs().max(max.abs()).max_element() * f64::EPSILON);
    let (min, max) = (min - DVec3::splat(pad), max + DVec3::splat(pad));
    let d = b - a;
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for k in 0..3 {
        if d[k] == 0.0 {
            if a[k] < min[k] || a[k] > max[k] {
                return false;
            }
            continue;
        }
        let (u, w) = ((min[k] - a[k]) / d[k], (max[k] - a[k]) / d[k]);
        t0 = t0.max(u.min(w));
        t1 = t1.min(u.max(w));
    }
    t0 <= t1
}

/// Whether the triangle `v` overlaps the closed box `[min, max]` (touching counts), by the
/// separating axis theorem over the 13 axes of Akenine-Möller's test.
pub fn triangle_overlaps_box(v: &[DVec3; 3], min: DVec3, max: DVec3) -> bool {
    let c = (min + max) * 0.5;
    let h = (max - min) * 0.5;
    let v0 = v[0] - c;
    let v1 = v[1] - c;
    let v2 = v[2] - c;
    // Every vertex inside the box by a margin far above the rounding of the tests below (a
    // billionth of the coordinates' size; they round at about 1e-16 of it): each of them
    // passes, so the triangle overlaps. Most triangles of a fine mesh lie inside the boxes
    // they are tested against.
    let margin = 1e-9 * (c.abs().max_element() + h.max_element());
    let inner = h - DVec3::splat(margin);
    if inner.cmpgt(DVec3::ZERO).all()
        && v0.abs().cmplt(inner).all()
        && v1.abs().cmplt(inner).all()
        && v2.abs().cmplt(inner).all()
    {
        return true;
    }
    // The three box face normals.
    for a in 0..3 {
        let lo = v0[a].min(v1[a]).min(v2[a]);
        let hi = v0[a].max(v1[a]).max(v2[a]);
        if lo > h[a] || hi < -h[a] {
            return false;
        }
    }
    let e = [v1 - v0, v2 - v1, v0 - v2];
    // The triangle normal.
    let n = e[0].cross(e[1]);
    let r = h.x * n.x.abs() + h.y * n.y.abs() + h.z * n.z.abs();
    let s = n.dot(v0);
    if s > r || s < -r {
        return false;
    }
    // The nine cross products of box axes and triangle edges.
    let axes = [DVec3::X, DVec3::Y, DVec3::Z];
    for ax in axes {
        for ed in e {
            let a = ax.cross(ed);
            if a == DVec3::ZERO {
                continue;
            }
            let p0 = a.dot(v0);
            let p1 = a.dot(v1);
            let p2 = a.dot(v2);
            let r = h.x * a.x.abs() + h.y * a.y.abs() + h.z * a.z.abs();
            let lo = p0.min(p1).min(p2);
            let hi = p0.max(p1).max(p2);
            if lo > r || hi < -r {
                return false;
            }
        }
    }
    true
}

/// A convex polygon of at most 9 vertices (a triangle clipped by 6 planes).
#[derive(Clone, Copy)]
pub struct Poly {
    pts: [DVec3; 12],
    len: usize,
}

impl Poly {
    /// Whether nothing is left.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub(crate) fn points(&self) -> &[DVec3] {
        &self.pts[..self.len]
    }

    /// Area and area centroid (the centroid is the mean of the vertices when the area is 0).
    pub fn area_centroid(&self) -> (f64, DVec3) {
        let p = self.points();
        if p.is_empty() {
            return (0.0, DVec3::ZERO);
        }
        let mut area = 0.0;
        let mut c = DVec3::ZERO;
        for i in 1..p.len().saturating_sub(1) {
            let a = (p[i] - p[0]).cross(p[i + 1] - p[0]).length() * 0.5;
            area += a;
            c += (p[0] + p[i] + p[i + 1]) * (a / 3.0);
        }
        if area > 0.0 {
            (area, c / area)
        } else {
            (0.0, p.iter().copied().sum::<DVec3>() / p.len() as f64)
        }
    }
}

/// Clips a triangle to the closed box `[min, max]`.
pub fn clip_triangle(v: &[DVec3; 3], min: DVec3, max: DVec3) -> Poly {
    let mut poly = Poly {
        pts: [DVec3::ZERO; 12],
        len: 3,
    };
    poly.pts[..3].copy_from_slice(v);
    // Most triangles of a fine mesh lie wholly inside the box: nothing to clip.
    if v.iter().all(|p| p.cmpge(min).all() && p.cmple(max).all()) {
        return poly;
    }
    for a in 0..3 {
        poly = clip_plane(&poly, a, min[a], 1.0);
        poly = clip_plane(&poly, a, max[a], -1.0);
        if poly.len == 0 {
            break;
        }
    }
    poly
}

/// The section of the closed box `[min, max]` by the plane `n · x = d`: a square in the plane,
/// larger than the box's section wherever it is, clipped to the box.
fn section_polygon(n: DVec3, d: f64, min: DVec3, max: DVec3) -> Poly {
    let mid = (min + max) * 0.5;
    let center = mid - n * (n.dot(mid) - d);
    let (u, w) = n.any_orthonormal_pair();
    let h = (max - min).length() + (center - mid).length();
    let mut poly = Poly {
        pts: [DVec3::ZERO; 12],
        len: 4,
    };
    poly.pts[..4].copy_from_slice(&[
        center - (u + w) * h,
        center + (u - w) * h,
        center + (u + w) * h,
        center - (u - w) * h,
    ]);
    for a in 0..3 {
        poly = clip_plane(&poly, a, min[a], 1.0);
        poly = clip_plane(&poly, a, max[a], -1.0);
    }
    poly
}

/// Whether every point of the section of the closed box `[min, max]` by the plane `n · x = d`
/// (`n` a unit vector) lies within `reach` of the patch `polys` projected on that plane,
/// checked at the centres of a grid of `spacing` over the section: a patch that spans the box
/// up to a rim of `reach`. Each polygon is binned into the grid cells its projection, grown by
/// `reach`, overlaps, so a sample tests only the polygons near it.
pub fn patch_covers_section(
    polys: &[&Poly],
    n: DVec3,
    d: f64,
    min: DVec3,
    max: DVec3,
    spacing: f64,
    reach: f64,
) -> bool {
    let (u, w) = n.any_orthonormal_pair();
    let origin = n * d;
    let flat = |q: DVec3| [u.dot(q - origin), w.dot(q - origin)];
    let section = section_polygon(n, d, min, max);
    let outline: Vec<[f64; 2]> = section.points().iter().map(|&q| flat(q)).collect();
    if outline.len() < 3 {
        return true;
    }
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for q in &outline {
        for k in 0..2 {
            lo[k] = lo[k].min(q[k]);
            hi[k] = hi[k].max(q[k]);
        }
    }
    let cells = [0, 1].map(|k| (((hi[k] - lo[k]) / spacing).ceil() as usize).clamp(1, 4096));
    let cell_of =
        |x: f64, k: usize| (((x - lo[k]) / spacing).floor().max(0.0) as usize).min(cells[k] - 1);
    let shapes: Vec<Vec<[f64; 2]>> = polys
        .iter()
        .map(|p| p.points().iter().map(|&q| flat(q)).collect())
        .collect();
    let mut bins: Vec<Vec<u32>> = vec![Vec::new(); cells[0] * cells[1]];
    for (i, shape) in shapes.iter().enumerate() {
        if shape.is_empty() {
            continue;
        }
        let (mut a, mut b) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for q in shape {
            for k in 0..2 {
                a[k] = a[k].min(q[k] - reach);
                b[k] = b[k].max(q[k] + reach);
            }
        }
        if b[0] < lo[0] || b[1] < lo[1] || a[0] > hi[0] || a[1] > hi[1] {
            continue;
        }
        for y in cell_of(a[1], 1)..=cell_of(b[1], 1) {
            for x in cell_of(a[0], 0)..=cell_of(b[0], 0) {
                bins[y * cells[0] + x].push(i as u32);
            }
        }
    }
    let inside_outline = |p: [f64; 2]| convex_distance(&outline, p) == 0.0;
    for y in 0..cells[1] {
        for x in 0..cells[0] {
            let p = [
                lo[0] + (x as f64 + 0.5) * spacing,
                lo[1] + (y as f64 + 0.5) * spacing,
            ];
            if !inside_outline(p) {
                continue;
            }
            let near = bins[y * cells[0] + x]
                .iter()
                .any(|&i| convex_distance(&shapes[i as usize], p) <= reach);
            if !near {
                return false;
            }
        }
    }
    true
}

/// Distance in the plane from `p` to the convex polygon `shape` (either orientation; a
/// segment or a point when it is degenerate): 0 inside it.
fn convex_distance(shape: &[[f64; 2]], p: [f64; 2]) -> f64 {
    let m = shape.len();
    let (mut pos, mut neg) = (false, false);
    let mut best = f64::INFINITY;
    for i in 0..m {
        let (a, b) = (shape[i], shape[(i + 1) % m]);
        let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
        let (px, py) = (p[0] - a[0], p[1] - a[1]);
        let cross = ex * py - ey * px;
        pos |= cross > 0.0;
        neg |= cross < 0.0;
        let len2 = ex * ex + ey * ey;
        let t = if len2 > 0.0 {
            ((px * ex + py * ey) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let (dx, dy) = (px - t * ex, py - t * ey);
        best = best.min((dx * dx + dy * dy).sqrt());
    }
    let degenerate = {
        // Zero area: the inside test means nothing; only the distance to the edges counts.
        let mut area = 0.0;
        for i in 0..m {
            let (a, b) = (shape[i], shape[(i + 1) % m]);
            area += a[0] * b[1] - a[1] * b[0];
        }
        area.abs() <= 1e-300
    };
    if m >= 3 && !degenerate && !(pos && neg) {
        0.0
    } else {
        best
    }
}

/// Keeps the part of `poly` where `sign * (p[axis] - value) >= 0`.
fn clip_plane(poly: &Poly, axis: usize, value: f64, sign: f64) -> Poly {
    let mut out = Poly {
        pts: [DVec3::ZERO; 12],
        len: 0,
    };
    let p = poly.points();
    let n = p.len();
    for i in 0..n {
        let a = p[i];
        let b = p[(i + 1) % n];
        let da = sign * (a[axis] - value);
        let db = sign * (b[axis] - value);
        if da >= 0.0 && out.len < out.pts.len() {
            out.pts[out.len] = a;
            out.len += 1;
        }
        if (da >= 0.0) != (db >= 0.0) && out.len < out.pts.len() {
            let t = da / (da - db);
            let mut q = a + (b - a) * t;
            q[axis] = value;
            out.pts[out.len] = q;
            out.len += 1;
        }
    }
    out
}

/// Parameter `t` in `[0, 1]` at which the segment `a + t (b - a)` meets the triangle
/// (edges included), by Möller–Trumbore; `None` when it misses or lies in its plane.
pub fn segment_triangle(a: DVec3, b: DVec3, v: &[DVec3; 3]) -> Option<f64> {
    let d = b - a;
    let e1 = v[1] - v[0];
    let e2 = v[2] - v[0];
    let p = d.cross(e2);
    let det = e1.dot(p);
    let scale = e1.length() * d.length() * e2.length();
    if det.abs() <= 1e-14 * scale || scale == 0.0 {
        return None;
    }
    let inv = 1.0 / det;
    let s = a - v[0];
    let u = s.dot(p) * inv;
    const TOL: f64 = 1e-12;
    if !(-TOL..=1.0 + TOL).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let w = d.dot(q) * inv;
    if w < -TOL || u + w > 1.0 + TOL {
        return None;
    }
    let t = e2.dot(q) * inv;
    (-TOL..=1.0 + TOL).contains(&t).then_some(t.clamp(0.0, 1.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> [DVec3; 3] {
        [DVec3::from(a), DVec3::from(b), DVec3::from(c)]
    }

    #[test]
    fn overlap_cases() {
        let (min, max) = (DVec3::ZERO, DVec3::ONE);
        // Inside.
        assert!(triangle_overlaps_box(
            &tri([0.2, 0.2, 0.5], [0.8, 0.2, 0.5], [0.5, 0.8, 0.5]),
            min,
            max
        ));
        // Far away.
        assert!(!triangle_overlaps_box(
            &tri([2.0, 2.0, 2.0], [3.0, 2.0, 2.0], [2.0, 3.0, 2.0]),
            min,
            max
        ));
        // Big triangle through the box with all vertices outside.
        assert!(triangle_overlaps_box(
            &tri([-5.0, -5.0, 0.5], [5.0, -5.0, 0.5], [0.0, 10.0, 0.5]),
            min,
            max
        ));
        // Touching a face exactly counts (closed box).
        assert!(triangle_overlaps_box(
            &tri([1.0, 0.2, 0.2], [1.0, 0.8, 0.2], [1.0, 0.5, 0.8]),
            min,
            max
        ));
        // Near a corner but separated only by an edge-cross-product axis.
        assert!(!triangle_overlaps_box(
            &tri([1.2, 0.0, -0.5], [1.2, 0.0, 1.5], [0.0, -1.2, 0.5]),
            min,
            max
        ));
        // Its plane misses the box although its projections on the box axes overlap it.
        assert!(!triangle_overlaps_box(
            &tri([-5.0, -5.0, 2.0], [5.0, -5.0, 2.0], [0.0, 10.0, 2.0]),
            min,
            max
        ));
        // The plane x + y + z = 0.5 cuts the box corner; x + y + z = 4 passes beyond it.
        assert!(triangle_overlaps_box(
            &tri([2.5, -1.0, -1.0], [-1.0, 2.5, -1.0], [-1.0, -1.0, 2.5]),
            min,
            max
        ));
        assert!(!triangle_overlaps_box(
            &tri([6.0, -1.0, -1.0], [-1.0, 6.0, -1.0], [-1.0, -1.0, 6.0]),
            min,
            max
        ));
    }

    #[test]
    fn overlap_agrees_with_sampling() {
        // Random triangles: whenever a sampled point of the triangle lies in the box, the
        // test must say they overlap (it may never miss a real overlap).
        let mut s = 0x1234_5678_9abc_def0u64;
        let mut r = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 * 3.0 - 1.0
        };
        let (min, max) = (DVec3::ZERO, DVec3::ONE);
        for _ in 0..2000 {
            let t = tri([r(), r(), r()], [r(), r(), r()], [r(), r(), r()]);
            let mut inside = false;
            for i in 0..=20 {
                for j in 0..=(20 - i) {
                    let (u, v) = (i as f64 / 20.0, j as f64 / 20.0);
                    let p = t[0] + (t[1] - t[0]) * u + (t[2] - t[0]) * v;
                    if p.cmpge(min).all() && p.cmple(max).all() {
                        inside = true;
                    }
                }
            }
            if inside {
                assert!(triangle_overlaps_box(&t, min, max));
            }
            // Clipping agrees: a triangle with no overlap clips to nothing of positive area.
            if !triangle_overlaps_box(&t, min, max) {
                assert_eq!(clip_triangle(&t, min, max).area_centroid().0, 0.0);
            }
        }
    }

    #[test]
    fn clip_area() {
        // A right triangle of area 2 clipped to the unit box leaves the unit square minus a
        // corner: x + y <= 2 inside [0,1]^2 is the whole square.
        let t = tri([0.0, 0.0, 0.5], [2.0, 0.0, 0.5], [0.0, 2.0, 0.5]);
        let (area, c) = clip_triangle(&t, DVec3::ZERO, DVec3::ONE).area_centroid();
        assert!((area - 1.0).abs() < 1e-12, "{area}");
        assert!((c - DVec3::new(0.5, 0.5, 0.5)).length() < 1e-12);
        let t = tri([0.0, 0.0, 0.5], [1.5, 0.0, 0.5], [0.0, 1.5, 0.5]);
        let (area, _) = clip_triangle(&t, DVec3::ZERO, DVec3::ONE).area_centroid();
        assert!((area - (1.0 - 0.125)).abs() < 1e-12, "{area}");
    }

    #[test]
    fn sections_of_a_box_by_planes() {
        let (min, max) = (DVec3::ZERO, DVec3::ONE);
        // Area and perimeter of the section.
        let section = |n: DVec3, d: f64| {
            let poly = section_polygon(n, d, min, max);
            let p = poly.points();
            let perimeter: f64 = (0..p.len())
                .map(|i| (p[(i + 1) % p.len()] - p[i]).length())
                .sum();
            (poly.area_centroid().0, perimeter)
        };
        let close = |got: (f64, f64), want: (f64, f64)| {
            (got.0 - want.0).abs() < 1e-12 && (got.1 - want.1).abs() < 1e-12
        };
        // Across an axis: the unit square.
        let s = section(DVec3::Y, 0.25);
        assert!(close(s, (1.0, 4.0)), "{s:?}");
        // On a face: still the whole face (the box is closed).
        let s = section(-DVec3::X, 0.0);
        assert!(close(s, (1.0, 4.0)), "{s:?}");
        // Through the centre across the main diagonal: a regular hexagon of side √2/2.
        let s = section(DVec3::ONE.normalize(), 1.5 / 3f64.sqrt());
        assert!(close(s, (0.75 * 3f64.sqrt(), 3.0 * 2f64.sqrt())), "{s:?}");
        // Past the box: nothing.
        assert_eq!(section(DVec3::Z, 1.5), (0.0, 0.0));
    }

    #[test]
    fn segments_against_a_box() {
        let (min, max) = (DVec3::ZERO, DVec3::ONE);
        let seg = |a: [f64; 3], b: [f64; 3]| {
            segment_may_touch_box(DVec3::from(a), DVec3::from(b), min, max)
        };
        assert!(seg([0.2, 0.3, 0.4], [0.6, 0.7, 0.8]), "inside");
        assert!(
            seg([-1.0, 0.5, 0.5], [2.0, 0.5, 0.5]),
            "through, both ends outside"
        );
        assert!(seg([1.0, 0.5, 0.5], [3.0, 0.5, 0.5]), "starting on a face");
        assert!(
            seg([-1.0, 0.0, 0.5], [1.0, 2.0, 0.5]),
            "touching an edge at (0, 1)"
        );
        assert!(
            !seg([-1.0, 0.1, 0.5], [1.0, 2.1, 0.5]),
            "passing the edge a tenth away"
        );
        assert!(
            !seg([1.5, -1.0, 0.5], [1.5, 2.0, 0.5]),
            "beside, parallel to a face"
        );
        assert!(
            !seg([2.0, 0.0, 0.0], [4.0, 1.0, 1.0]),
            "short of the box along its line"
        );
        // Against sampling: a segment with a sampled point in the box is never missed, and
        // one that the test passes gets within a millionth of the box.
        let mut rng = crate::emit::Rng::new(0x0ddb_a11c);
        let mut r = || f64::from(rng.range(-1.0, 2.0));
        let (mut touching, mut missing) = (0, 0);
        for _ in 0..4000 {
            let (a, b) = (DVec3::new(r(), r(), r()), DVec3::new(r(), r(), r()));
            let points = (0..=400).map(|i| a + (b - a) * (i as f64 / 400.0));
            let sampled = points
                .clone()
                .any(|p| p.cmpge(min).all() && p.cmple(max).all());
            let near = points
                .map(|p| (p - p.clamp(min, max)).length())
                .fold(f64::INFINITY, f64::min);
            let touches = segment_may_touch_box(a, b, min, max);
            assert!(!sampled || touches, "{a} {b}");
            assert!(
                !touches || near < 0.01,
                "{a} {b} passes {near} from the box"
            );
            touching += touches as u32;
            missing += !touches as u32;
        }
        assert!(touching > 500 && missing > 500, "{touching} {missing}");
    }

    #[test]
    fn segment_hits() {
        let t = tri([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        let hit =
            segment_triangle(DVec3::new(0.2, 0.2, 1.0), DVec3::new(0.2, 0.2, -1.0), &t).unwrap();
        assert!((hit - 0.5).abs() < 1e-12);
        assert!(
            segment_triangle(DVec3::new(2.0, 2.0, 1.0), DVec3::new(2.0, 2.0, -1.0), &t).is_none()
        );
        assert!(
            segment_triangle(DVec3::new(0.2, 0.2, 1.0), DVec3::new(0.2, 0.2, 0.5), &t).is_none()
        );
    }
}
