//! Procedural test scenes. Closed ones are watertight and consistently oriented with
//! outward normals (counter-clockwise seen from outside); open ones say which way they face.

use std::f32::consts::{PI, TAU};

pub use octoproxy_cpu::mesh::Mesh;

/// Appends quad `a b c d` (counter-clockwise seen from the side it faces) as two triangles.
fn quad(t: &mut Vec<[u32; 3]>, a: u32, b: u32, c: u32, d: u32) {
    t.push([a, b, c]);
    t.push([a, c, d]);
}

/// A closed axis-aligned box.
pub fn cube(min: [f32; 3], max: [f32; 3]) -> Mesh {
    let mut positions = Vec::new();
    for i in 0..8 {
        positions.push([
            if i & 1 == 0 { min[0] } else { max[0] },
            if i & 2 == 0 { min[1] } else { max[1] },
            if i & 4 == 0 { min[2] } else { max[2] },
        ]);
    }
    let mut triangles = Vec::new();
    for q in [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]] {
        quad(&mut triangles, q[0], q[1], q[2], q[3]);
    }
    Mesh { positions, triangles }
}

/// A closed box centred at `center` with edge lengths `size` (thin in one axis: a slab).
pub fn slab(center: [f32; 3], size: [f32; 3]) -> Mesh {
    let h = size.map(|s| s * 0.5);
    cube([center[0] - h[0], center[1] - h[1], center[2] - h[2]], [center[0] + h[0], center[1] + h[1], center[2] + h[2]])
}

/// A closed UV sphere with shared poles.
pub fn uv_sphere(center: [f32; 3], radius: f32, segments: u32, rings: u32) -> Mesh {
    let mut positions = vec![[center[0], center[1] + radius, center[2]]];
    for r in 1..rings {
        let phi = PI * r as f32 / rings as f32;
        for s in 0..segments {
            let th = TAU * s as f32 / segments as f32;
            positions.push([
                center[0] + radius * phi.sin() * th.cos(),
                center[1] + radius * phi.cos(),
                center[2] + radius * phi.sin() * th.sin(),
            ]);
        }
    }
    positions.push([center[0], center[1] - radius, center[2]]);
    let south = positions.len() as u32 - 1;
    let idx = |r: u32, s: u32| 1 + (r - 1) * segments + (s % segments);
    let mut triangles = Vec::new();
    for s in 0..segments {
        triangles.push([0, idx(1, s + 1), idx(1, s)]);
        triangles.push([south, idx(rings - 1, s), idx(rings - 1, s + 1)]);
    }
    for r in 1..rings - 1 {
        for s in 0..segments {
            quad(&mut triangles, idx(r, s), idx(r, s + 1), idx(r + 1, s + 1), idx(r + 1, s));
        }
    }
    Mesh { positions, triangles }
}

/// A closed torus around the y axis.
pub fn torus(center: [f32; 3], major: f32, minor: f32, seg_major: u32, seg_minor: u32) -> Mesh {
    let mut positions = Vec::new();
    for i in 0..seg_major {
        let u = TAU * i as f32 / seg_major as f32;
        for j in 0..seg_minor {
            let v = TAU * j as f32 / seg_minor as f32;
            let r = major + minor * v.cos();
            positions.push([center[0] + r * u.cos(), center[1] + minor * v.sin(), center[2] + r * u.sin()]);
        }
    }
    let idx = |i: u32, j: u32| (i % seg_major) * seg_minor + (j % seg_minor);
    let mut triangles = Vec::new();
    for i in 0..seg_major {
        for j in 0..seg_minor {
            quad(&mut triangles, idx(i, j), idx(i, j + 1), idx(i + 1, j + 1), idx(i + 1, j));
        }
    }
    Mesh { positions, triangles }
}

/// A closed prism whose cross-section (in xy) is the polygon `outline` (counter-clockwise),
/// extruded along z from `-depth/2` to `depth/2`. The outline must be star-shaped around its
/// first point's... centroid (caps are fans from the centroid).
pub fn prism(outline: &[[f32; 2]], depth: f32) -> Mesh {
    let n = outline.len() as u32;
    let c = outline.iter().fold([0.0, 0.0], |a, p| [a[0] + p[0] / n as f32, a[1] + p[1] / n as f32]);
    let mut positions = Vec::new();
    for z in [-depth * 0.5, depth * 0.5] {
        for p in outline {
            positions.push([p[0], p[1], z]);
        }
        positions.push([c[0], c[1], z]);
    }
    let (b, bc, t, tc) = (0, n, n + 1, 2 * n + 1);
    let mut triangles = Vec::new();
    for i in 0..n {
        let j = (i + 1) % n;
        triangles.push([bc, b + j, b + i]);
        triangles.push([tc, t + i, t + j]);
        quad(&mut triangles, b + i, b + j, t + j, t + i);
    }
    Mesh { positions, triangles }
}

/// A closed wedge: a triangular prism whose apex angle (degrees) makes a knife edge at +x.
pub fn wedge(apex_angle_deg: f32, length: f32, depth: f32) -> Mesh {
    let half = (apex_angle_deg.to_radians() * 0.5).tan() * length;
    prism(&[[0.0, -half], [length, 0.0], [0.0, half]], depth)
}

/// A closed, non-convex star prism.
pub fn star_prism(points: u32, r_outer: f32, r_inner: f32, height: f32) -> Mesh {
    let outline: Vec<[f32; 2]> = (0..2 * points)
        .map(|i| {
            let a = PI * i as f32 / points as f32;
            let r = if i % 2 == 0 { r_outer } else { r_inner };
            [r * a.cos(), r * a.sin()]
        })
        .collect();
    prism(&outline, height)
}

/// A hollow ball: the outer sphere facing out and the inner one facing into the cavity.
pub fn nested_shells(radius_outer: f32, thickness: f32) -> Mesh {
    let outer = uv_sphere([0.0; 3], radius_outer, 48, 24);
    let mut inner = uv_sphere([0.0; 3], radius_outer - thickness, 40, 20);
    for t in &mut inner.triangles {
        t.swap(1, 2);
    }
    merge(&[outer, inner])
}

/// An open square in the xz plane, facing +y.
pub fn flat_sheet(center: [f32; 3], size: f32, subdivisions: u32) -> Mesh {
    let n = subdivisions.max(1);
    let mut positions = Vec::new();
    for i in 0..=n {
        for j in 0..=n {
            positions.push([
                center[0] - size * 0.5 + size * i as f32 / n as f32,
                center[1],
                center[2] - size * 0.5 + size * j as f32 / n as f32,
            ]);
        }
    }
    let idx = |i: u32, j: u32| i * (n + 1) + j;
    let mut triangles = Vec::new();
    for i in 0..n {
        for j in 0..n {
            quad(&mut triangles, idx(i, j), idx(i, j + 1), idx(i + 1, j + 1), idx(i + 1, j));
        }
    }
    Mesh { positions, triangles }
}

/// An open dome: the upper half of a sphere, facing out, open at the bottom.
pub fn hemisphere(center: [f32; 3], radius: f32, segments: u32, rings: u32) -> Mesh {
    let mut positions = vec![[center[0], center[1] + radius, center[2]]];
    for r in 1..=rings {
        let phi = 0.5 * PI * r as f32 / rings as f32;
        for s in 0..segments {
            let th = TAU * s as f32 / segments as f32;
            positions.push([
                center[0] + radius * phi.sin() * th.cos(),
                center[1] + radius * phi.cos(),
                center[2] + radius * phi.sin() * th.sin(),
            ]);
        }
    }
    let idx = |r: u32, s: u32| 1 + (r - 1) * segments + (s % segments);
    let mut triangles = Vec::new();
    for s in 0..segments {
        triangles.push([0, idx(1, s + 1), idx(1, s)]);
    }
    for r in 1..rings {
        for s in 0..segments {
            quad(&mut triangles, idx(r, s), idx(r, s + 1), idx(r + 1, s + 1), idx(r + 1, s));
        }
    }
    Mesh { positions, triangles }
}

/// One mesh holding all of `meshes`.
pub fn merge(meshes: &[Mesh]) -> Mesh {
    let mut out = Mesh::default();
    for m in meshes {
        let base = out.positions.len() as u32;
        out.positions.extend_from_slice(&m.positions);
        out.triangles.extend(m.triangles.iter().map(|t| t.map(|i| i + base)));
    }
    out
}

/// Each triangle into four, midpoints shared between neighbours (closed stays closed).
pub fn subdivide(mesh: &Mesh) -> Mesh {
    let mut positions = mesh.positions.clone();
    let mut mids = std::collections::HashMap::new();
    let mut mid = |a: u32, b: u32, positions: &mut Vec<[f32; 3]>| -> u32 {
        *mids.entry((a.min(b), a.max(b))).or_insert_with(|| {
            let (p, q) = (positions[a as usize], positions[b as usize]);
            positions.push([(p[0] + q[0]) * 0.5, (p[1] + q[1]) * 0.5, (p[2] + q[2]) * 0.5]);
            positions.len() as u32 - 1
        })
    };
    let mut triangles = Vec::with_capacity(mesh.triangles.len() * 4);
    for &[a, b, c] in &mesh.triangles {
        let (ab, bc, ca) = (mid(a, b, &mut positions), mid(b, c, &mut positions), mid(c, a, &mut positions));
        triangles.extend_from_slice(&[[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
    }
    Mesh { positions, triangles }
}

/// Whether every undirected edge is used exactly twice, once in each direction.
pub fn is_closed(mesh: &Mesh) -> bool {
    let mut edges = std::collections::HashMap::new();
    for t in &mesh.triangles {
        for k in 0..3 {
            *edges.entry((t[k], t[(k + 1) % 3])).or_insert(0u32) += 1;
        }
    }
    edges.iter().all(|(&(a, b), &n)| n == 1 && edges.get(&(b, a)) == Some(&1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ground_truth::GroundTruth;

    #[test]
    fn closed_scenes_are_watertight_and_face_out() {
        let cases: Vec<(Mesh, [f32; 3])> = vec![
            (cube([-1.0; 3], [1.0; 3]), [0.0; 3]),
            (uv_sphere([0.0; 3], 1.0, 32, 16), [0.0; 3]),
            (torus([0.0; 3], 1.0, 0.3, 48, 24), [1.0, 0.0, 0.0]),
            (wedge(20.0, 1.0, 1.0), [0.3, 0.0, 0.0]),
            (star_prism(5, 1.0, 0.4, 0.5), [0.0, 0.0, 0.0]),
            (nested_shells(1.0, 0.2), [0.0, 0.9, 0.0]),
            (subdivide(&uv_sphere([0.0; 3], 1.0, 16, 8)), [0.0; 3]),
        ];
        for (i, (m, inside)) in cases.iter().enumerate() {
            assert!(is_closed(m), "scene {i} is not closed");
            // Outward: the signed volume is positive.
            let vol: f64 = m
                .triangles
                .iter()
                .map(|t| {
                    let p = t.map(|k| glam::DVec3::from_array(m.positions[k as usize].map(f64::from)));
                    p[0].dot(p[1].cross(p[2])) / 6.0
                })
                .sum();
            assert!(vol > 0.0, "scene {i} faces in (volume {vol})");
            let gt = GroundTruth::new(&m.positions, &m.triangles);
            assert!(gt.is_inside(*inside), "scene {i}: {inside:?} should be inside");
            assert!(!gt.is_inside([5.0, 5.0, 5.0]));
        }
        // The cavity of the hollow ball is outside the solid.
        let m = nested_shells(1.0, 0.2);
        assert!(!GroundTruth::new(&m.positions, &m.triangles).is_inside([0.0; 3]));
    }
}
