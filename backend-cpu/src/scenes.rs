//! Procedural test scenes. Closed ones are watertight (vertices shared, every edge used by
//! exactly two triangles) and consistently oriented with outward normals (counter-clockwise
//! seen from outside); open ones say which way they face.
//!
//! [`Mesh`] is the mesh type of `octoproxy-cpu` (the same two public fields, `positions` and
//! `triangles`), so that scenes, loaded meshes and the baker's `MeshRef::from` all take one
//! type; [`MeshExt`] adds the checks.

use std::collections::HashMap;
use std::f32::consts::{PI, TAU};

pub use crate::io::Mesh;

/// Checks on a [`Mesh`].
pub trait MeshExt {
    /// Whether every undirected edge is used by exactly two triangles (and no triangle
    /// repeats a vertex or indexes past the vertex list).
    fn is_closed(&self) -> bool;
    /// Whether every directed edge is used at most once and, when its reverse is used, by a
    /// neighbour: neighbours agree about orientation. A closed mesh for which this holds has
    /// every edge once in each direction.
    fn is_consistently_oriented(&self) -> bool;
    /// The signed volume (positive for a closed mesh whose normals face out).
    fn signed_volume(&self) -> f64;
}

impl MeshExt for Mesh {
    fn is_closed(&self) -> bool {
        let mut uses: HashMap<(u32, u32), u32> = HashMap::with_capacity(self.triangles.len() * 2);
        for t in &self.triangles {
            if t.iter().any(|&i| i as usize >= self.positions.len())
                || t[0] == t[1]
                || t[1] == t[2]
                || t[2] == t[0]
            {
                return false;
            }
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *uses.entry((a.min(b), a.max(b))).or_insert(0) += 1;
            }
        }
        uses.values().all(|&n| n == 2)
    }

    fn is_consistently_oriented(&self) -> bool {
        let mut uses: HashMap<(u32, u32), u32> = HashMap::with_capacity(self.triangles.len() * 3);
        for t in &self.triangles {
            for k in 0..3 {
                *uses.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
            }
        }
        uses.values().all(|&n| n == 1)
    }

    fn signed_volume(&self) -> f64 {
        let p = |i: u32| {
            self.positions
                .get(i as usize)
                .map_or(glam::DVec3::ZERO, |v| {
                    glam::DVec3::from_array(v.map(f64::from))
                })
        };
        self.triangles
            .iter()
            .map(|t| p(t[0]).dot(p(t[1]).cross(p(t[2]))) / 6.0)
            .sum()
    }
}

/// Whether every undirected edge of `mesh` is used by exactly two triangles (the same as
/// [`MeshExt::is_closed`], for callers without the trait in scope).
pub fn is_closed(mesh: &Mesh) -> bool {
    mesh.is_closed()
}

/// Appends quad `a b c d` (counter-clockwise seen from the side it faces) as two triangles.
fn quad(t: &mut Vec<[u32; 3]>, a: u32, b: u32, c: u32, d: u32) {
    t.push([a, b, c]);
    t.push([a, c, d]);
}

/// A closed axis-aligned box from `min` to `max`: 8 vertices, 12 triangles.
pub fn cube(min: [f32; 3], max: [f32; 3]) -> Mesh {
    let mut positions = Vec::with_capacity(8);
    for i in 0..8 {
        positions.push([
            if i & 1 == 0 { min[0] } else { max[0] },
            if i & 2 == 0 { min[1] } else { max[1] },
            if i & 4 == 0 { min[2] } else { max[2] },
        ]);
    }
    let mut triangles = Vec::with_capacity(12);
    // Faces -z, +z, -y, +y, -x, +x, each counter-clockwise seen from outside.
    for q in [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ] {
        quad(&mut triangles, q[0], q[1], q[2], q[3]);
    }
    Mesh {
        positions,
        triangles,
    }
}

/// A closed box centred at `center` with edge lengths `size`; meant to be thin in one axis.
pub fn slab(center: [f32; 3], size: [f32; 3]) -> Mesh {
    let h = size.map(|s| s * 0.5);
    cube(
        [center[0] - h[0], center[1] - h[1], center[2] - h[2]],
        [center[0] + h[0], center[1] + h[1], center[2] + h[2]],
    )
}

/// A closed UV sphere around the y axis: `segments` around (at least 3), `rings` from pole
/// to pole (at least 2), one shared vertex at each pole.
pub fn uv_sphere(center: [f32; 3], radius: f32, segments: u32, rings: u32) -> Mesh {
    let (segments, rings) = (segments.max(3), rings.max(2));
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
    let mut triangles = Vec::with_capacity(2 * segments as usize * (rings as usize - 1));
    for s in 0..segments {
        triangles.push([0, idx(1, s + 1), idx(1, s)]);
        triangles.push([south, idx(rings - 1, s), idx(rings - 1, s + 1)]);
    }
    for r in 1..rings - 1 {
        for s in 0..segments {
            quad(
                &mut triangles,
                idx(r, s),
                idx(r, s + 1),
                idx(r + 1, s + 1),
                idx(r + 1, s),
            );
        }
    }
    Mesh {
        positions,
        triangles,
    }
}

/// A closed torus around the y axis: tube centre line of radius `major`, tube radius
/// `minor`, `seg_major` segments around the axis and `seg_minor` around the tube (each at
/// least 3).
pub fn torus(center: [f32; 3], major: f32, minor: f32, seg_major: u32, seg_minor: u32) -> Mesh {
    let (seg_major, seg_minor) = (seg_major.max(3), seg_minor.max(3));
    let mut positions = Vec::with_capacity((seg_major * seg_minor) as usize);
    for i in 0..seg_major {
        let u = TAU * i as f32 / seg_major as f32;
        for j in 0..seg_minor {
            let v = TAU * j as f32 / seg_minor as f32;
            let r = major + minor * v.cos();
            positions.push([
                center[0] + r * u.cos(),
                center[1] + minor * v.sin(),
                center[2] + r * u.sin(),
            ]);
        }
    }
    let idx = |i: u32, j: u32| (i % seg_major) * seg_minor + (j % seg_minor);
    let mut triangles = Vec::with_capacity(2 * (seg_major * seg_minor) as usize);
    for i in 0..seg_major {
        for j in 0..seg_minor {
            quad(
                &mut triangles,
                idx(i, j),
                idx(i, j + 1),
                idx(i + 1, j + 1),
                idx(i + 1, j),
            );
        }
    }
    Mesh {
        positions,
        triangles,
    }
}

/// A closed prism: the polygon `outline` (in xy, counter-clockwise) extruded along z from
/// `-depth / 2` to `depth / 2`. The caps are fans from the average of the outline's points, so
/// the outline must be star-shaped around that point (convex outlines and stars are).
pub fn prism(outline: &[[f32; 2]], depth: f32) -> Mesh {
    let n = outline.len() as u32;
    let c = outline.iter().fold([0.0, 0.0], |a, p| {
        [a[0] + p[0] / n as f32, a[1] + p[1] / n as f32]
    });
    let mut positions = Vec::with_capacity(2 * n as usize + 2);
    for z in [-depth * 0.5, depth * 0.5] {
        positions.extend(outline.iter().map(|p| [p[0], p[1], z]));
        positions.push([c[0], c[1], z]);
    }
    // Bottom ring, its centre, top ring, its centre.
    let (b, bc, t, tc) = (0, n, n + 1, 2 * n + 1);
    let mut triangles = Vec::with_capacity(4 * n as usize);
    for i in 0..n {
        let j = (i + 1) % n;
        triangles.push([bc, b + j, b + i]);
        triangles.push([tc, t + i, t + j]);
        quad(&mut triangles, b + i, b + j, t + j, t + i);
    }
    Mesh {
        positions,
        triangles,
    }
}

/// A closed wedge: a triangular prism (along z, `depth` deep) whose cross-section has a
/// sharp apex of `apex_angle_deg` degrees at `(length, 0)`, its back face on `x = 0`. The
/// apex runs along z as a knife edge.
pub fn wedge(apex_angle_deg: f32, length: f32, depth: f32) -> Mesh {
    let half = (apex_angle_deg.to_radians() * 0.5).tan() * length;
    prism(&[[0.0, -half], [length, 0.0], [0.0, half]], depth)
}

/// A closed, non-convex star prism: `points` tips (at least 2) at radius `r_outer`, notches
/// at `r_inner`, extruded along z to `height` (centred on the origin).
pub fn star_prism(points: u32, r_outer: f32, r_inner: f32, height: f32) -> Mesh {
    let points = points.max(2);
    let outline: Vec<[f32; 2]> = (0..2 * points)
        .map(|i| {
            let a = PI * i as f32 / points as f32;
            let r = if i % 2 == 0 { r_outer } else { r_inner };
            [r * a.cos(), r * a.sin()]
        })
        .collect();
    prism(&outline, height)
}

/// A hollow ball centred on the origin: the outer sphere (radius `radius_outer`) facing out
/// and the inner one (radius `radius_outer - thickness`) facing into the cavity, as one mesh.
/// The solid is the shell between them; the cavity is outside.
pub fn nested_shells(radius_outer: f32, thickness: f32) -> Mesh {
    let outer = uv_sphere([0.0; 3], radius_outer, 48, 24);
    let mut inner = uv_sphere([0.0; 3], radius_outer - thickness, 40, 20);
    for t in &mut inner.triangles {
        t.swap(1, 2);
    }
    merge(&[outer, inner])
}

/// An open square sheet in the xz plane, `size` on a side, centred at `center`, split into
/// `subdivisions` × `subdivisions` quads (at least 1), facing +y.
pub fn flat_sheet(center: [f32; 3], size: f32, subdivisions: u32) -> Mesh {
    let n = subdivisions.max(1);
    let mut positions = Vec::with_capacity(((n + 1) * (n + 1)) as usize);
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
    let mut triangles = Vec::with_capacity(2 * (n * n) as usize);
    for i in 0..n {
        for j in 0..n {
            quad(
                &mut triangles,
                idx(i, j),
                idx(i, j + 1),
                idx(i + 1, j + 1),
                idx(i + 1, j),
            );
        }
    }
    Mesh {
        positions,
        triangles,
    }
}

/// An open dome: the upper half (y ≥ center.y) of a sphere, facing out, open at the bottom
/// (its rim is the equator). `segments` around (at least 3), `rings` from the pole to the
/// equator (at least 1).
pub fn hemisphere(center: [f32; 3], radius: f32, segments: u32, rings: u32) -> Mesh {
    let (segments, rings) = (segments.max(3), rings.max(1));
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
    let mut triangles = Vec::with_capacity((segments * (2 * rings - 1)) as usize);
    for s in 0..segments {
        triangles.push([0, idx(1, s + 1), idx(1, s)]);
    }
    for r in 1..rings {
        for s in 0..segments {
            quad(
                &mut triangles,
                idx(r, s),
                idx(r, s + 1),
                idx(r + 1, s + 1),
                idx(r + 1, s),
            );
        }
    }
    Mesh {
        positions,
        triangles,
    }
}

/// A closed cone along +x: its apex at `(length, 0, 0)`, its base a circle of `radius` on
/// `x = 0` (`segments` around, at least 3) closed by a fan from the origin. A thin one is a
/// needle: its tip is sharper than any leaf.
pub fn cone(length: f32, radius: f32, segments: u32) -> Mesh {
    let segments = segments.max(3);
    let mut positions = vec![[length, 0.0, 0.0], [0.0; 3]];
    for s in 0..segments {
        let th = TAU * s as f32 / segments as f32;
        positions.push([0.0, radius * th.cos(), radius * th.sin()]);
    }
    let mut triangles = Vec::with_capacity(2 * segments as usize);
    for s in 0..segments {
        let (a, b) = (2 + s, 2 + (s + 1) % segments);
        // The ring runs counter-clockwise seen from +x: the side faces the apex's way round,
        // the base faces -x.
        triangles.push([0, a, b]);
        triangles.push([1, b, a]);
    }
    Mesh {
        positions,
        triangles,
    }
}

/// An open V-groove: two unit wings meeting along the x axis at `angle_deg`, opening up
/// (+y), then turned by `tilt_deg` about z so that the crease slopes and particles slide
/// down it. Narrow ones squeeze a particle between two surfaces less than a leaf apart.
pub fn v_groove(angle_deg: f32, tilt_deg: f32) -> Mesh {
    let (s, c) = (0.5 * angle_deg).to_radians().sin_cos();
    let wings = Mesh {
        positions: vec![
            [-1.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, c, s],
            [-1.0, c, s],
            [1.0, c, -s],
            [-1.0, c, -s],
        ],
        triangles: vec![[0, 1, 2], [0, 2, 3], [0, 4, 1], [0, 5, 4]],
    };
    rotated(&wings, tilt_deg, 0.0)
}

/// An open funnel: a cone with its apex at the origin, opening up (+y) to a rim at `y = 1`,
/// `half_angle_deg` from its axis, `segments` around (at least 3), facing inward. Particles
/// collect in its apex, where the surface closes in from every side.
pub fn funnel(half_angle_deg: f32, segments: u32) -> Mesh {
    let segments = segments.max(3);
    let r = half_angle_deg.to_radians().tan();
    let mut positions = vec![[0.0; 3]];
    for s in 0..segments {
        let th = TAU * s as f32 / segments as f32;
        positions.push([r * th.cos(), 1.0, r * th.sin()]);
    }
    let triangles = (0..segments)
        .map(|s| [0, 1 + (s + 1) % segments, 1 + s])
        .collect();
    Mesh {
        positions,
        triangles,
    }
}

/// `mesh` turned by `about_z_deg` about z, then by `about_x_deg` about x (through the origin).
pub fn rotated(mesh: &Mesh, about_z_deg: f32, about_x_deg: f32) -> Mesh {
    let (sz, cz) = about_z_deg.to_radians().sin_cos();
    let (sx, cx) = about_x_deg.to_radians().sin_cos();
    let positions = mesh
        .positions
        .iter()
        .map(|&[x, y, z]| {
            let (x, y) = (x * cz - y * sz, x * sz + y * cz);
            [x, y * cx - z * sx, y * sx + z * cx]
        })
        .collect();
    Mesh {
        positions,
        triangles: mesh.triangles.clone(),
    }
}

/// `mesh` scaled to `size` in its largest extent and moved to stand on the plane y = 0,
/// centred over the origin, with the height of its top; `None` for a mesh with no finite,
/// non-zero extent.
pub fn standing(mesh: &Mesh, size: f32) -> Option<(Mesh, f32)> {
    use glam::Vec3;
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for p in &mesh.positions {
        lo = lo.min(Vec3::from_array(*p));
        hi = hi.max(Vec3::from_array(*p));
    }
    let extent = (hi - lo).max_element();
    if !(extent.is_finite() && extent > 0.0) {
        return None;
    }
    let scale = size / extent;
    let base = Vec3::new((lo.x + hi.x) * 0.5, lo.y, (lo.z + hi.z) * 0.5);
    let positions: Vec<[f32; 3]> = mesh
        .positions
        .iter()
        .map(|p| ((Vec3::from_array(*p) - base) * scale).to_array())
        .collect();
    let top = positions.iter().map(|p| p[1]).fold(f32::MIN, f32::max);
    Some((
        Mesh {
            positions,
            triangles: mesh.triangles.clone(),
        },
        top,
    ))
}

/// Faces, edges and corners exactly on the octree's cell planes for a bake with `params`
/// (open, parts overlapping and touching): a closed cube over [-1, 1]³ that fixes the root
/// (so the planes are known before baking), boxes on the depth-3 and depth-6 grids (the second
/// on the first's +x face, overlapping part of it, face to face), a quad in a depth-4 cell
/// plane, and a staircase of three depth-5 cells. Triangles on a cell face belong to the
/// cells on both sides of it.
pub fn on_cell_planes(params: &crate::BuildParams) -> Mesh {
    use crate::{bake, MeshRef};
    use octoproxy_core::{ProxyView, MAX_DEPTH};
    let outer = cube([-1.0; 3], [1.0; 3]);
    let (words, _) = bake(&[MeshRef::from(&outer)], params, &()).expect("a cube bakes");
    let view = ProxyView::new(&words).expect("valid");
    let at = |d: u32, k: [u32; 3]| [0, 1, 2].map(|a| view.plane(a, k[a] << (MAX_DEPTH - d)));
    let a = cube(at(3, [2, 2, 3]), at(3, [4, 3, 5]));
    // Depth-3 plane 4 is depth-6 plane 32.
    let b = cube(at(6, [32, 16, 24]), at(6, [35, 20, 30]));
    let (q0, q1) = (at(4, [5, 11, 4]), at(4, [9, 11, 12]));
    let quad = Mesh {
        positions: vec![q0, [q1[0], q0[1], q0[2]], q1, [q0[0], q0[1], q1[2]]],
        triangles: vec![[0, 1, 2], [0, 2, 3]],
    };
    let mut stairs = Mesh::default();
    let (z0, z1) = (at(5, [0, 0, 18])[2], at(5, [0, 0, 26])[2]);
    for s in 0..3u32 {
        let ([xa, ya, _], [xb, yb, _]) = (at(5, [8 + s, 20 + s, 0]), at(5, [9 + s, 21 + s, 0]));
        let i = stairs.positions.len() as u32;
        stairs.positions.extend([
            [xa, ya, z0],
            [xa, yb, z0],
            [xa, yb, z1],
            [xa, ya, z1],
            [xb, yb, z0],
            [xb, yb, z1],
        ]);
        stairs.triangles.extend([
            [i, i + 1, i + 2],
            [i, i + 2, i + 3],
            [i + 1, i + 4, i + 5],
            [i + 1, i + 5, i + 2],
        ]);
    }
    let scene = merge(&[outer, a, b, quad, stairs]);
    let (words, _) = bake(&[MeshRef::from(&scene)], params, &()).expect("the scene bakes");
    let moved = ProxyView::new(&words).expect("valid");
    assert!(
        moved.root_aabb().min == view.root_aabb().min
            && moved.header().root_size == view.header().root_size,
        "the inner parts moved the root"
    );
    scene
}

/// `count` open sheets (as [`flat_sheet`], 2 on a side, facing +y) stacked `gap` apart,
/// centred on the origin: closer together than a leaf when `gap` is small, so that one leaf
/// holds several.
pub fn sheet_stack(count: u32, gap: f32) -> Mesh {
    let half = (count.max(1) - 1) as f32 * 0.5;
    let sheets: Vec<Mesh> = (0..count)
        .map(|i| flat_sheet([0.0, (i as f32 - half) * gap, 0.0], 2.0, 4))
        .collect();
    merge(&sheets)
}

/// `count` unconnected triangles at random in the cube [-1, 1]³, of sizes from 1 % to 40 %
/// of it, facing every way and passing through each other: no orientation, no inside, the
/// hardest case for labels. The same `seed` gives the same soup.
pub fn triangle_soup(count: u32, seed: u64) -> Mesh {
    let mut rng = crate::emit::Rng::new(seed);
    let mut positions = Vec::with_capacity(3 * count as usize);
    for _ in 0..count {
        let c = [
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
        ];
        let size = rng.range(0.01, 0.4);
        for _ in 0..3 {
            positions.push(c.map(|x| x + size * rng.range(-1.0, 1.0)));
        }
    }
    let triangles = (0..count).map(|i| [3 * i, 3 * i + 1, 3 * i + 2]).collect();
    Mesh {
        positions,
        triangles,
    }
}

/// One mesh holding all of `meshes` (vertices appended, indices shifted; nothing welded).
pub fn merge(meshes: &[Mesh]) -> Mesh {
    let mut out = Mesh::default();
    for m in meshes {
        let base = out.positions.len() as u32;
        out.positions.extend_from_slice(&m.positions);
        out.triangles
            .extend(m.triangles.iter().map(|t| t.map(|i| i + base)));
    }
    out
}

/// Each triangle into four, through its edge midpoints; a midpoint is shared by the two
/// triangles of its edge, so a closed mesh stays closed and keeps its orientation.
pub fn subdivide(mesh: &Mesh) -> Mesh {
    let mut positions = mesh.positions.clone();
    let mut mids: HashMap<(u32, u32), u32> = HashMap::new();
    let mut mid = |a: u32, b: u32, positions: &mut Vec<[f32; 3]>| -> u32 {
        *mids.entry((a.min(b), a.max(b))).or_insert_with(|| {
            let (p, q) = (positions[a as usize], positions[b as usize]);
            positions.push([
                (p[0] + q[0]) * 0.5,
                (p[1] + q[1]) * 0.5,
                (p[2] + q[2]) * 0.5,
            ]);
            positions.len() as u32 - 1
        })
    };
    let mut triangles = Vec::with_capacity(mesh.triangles.len() * 4);
    for &[a, b, c] in &mesh.triangles {
        let (ab, bc, ca) = (
            mid(a, b, &mut positions),
            mid(b, c, &mut positions),
            mid(c, a, &mut positions),
        );
        triangles.extend_from_slice(&[[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
    }
    Mesh {
        positions,
        triangles,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ground_truth::GroundTruth;
    use glam::Vec3;

    fn normal(m: &Mesh, t: &[u32; 3]) -> Vec3 {
        let p = t.map(|i| Vec3::from_array(m.positions[i as usize]));
        (p[1] - p[0]).cross(p[2] - p[0])
    }

    /// Closed, oriented, outward, non-degenerate, and inside/outside by winding number.
    fn check_closed(
        name: &str,
        m: &Mesh,
        inside: &[[f32; 3]],
        outside: &[[f32; 3]],
    ) -> GroundTruth {
        assert!(m.is_closed(), "{name} is not closed");
        assert!(is_closed(m));
        assert!(
            m.is_consistently_oriented(),
            "{name} is not consistently oriented"
        );
        assert!(
            m.signed_volume() > 0.0,
            "{name} faces in (volume {})",
            m.signed_volume()
        );
        assert!(
            m.triangles.iter().all(|t| normal(m, t).length() > 0.0),
            "{name} has a degenerate triangle"
        );
        let gt = GroundTruth::new(&m.positions, &m.triangles);
        assert_eq!(gt.triangle_count(), m.triangles.len());
        for p in inside {
            let w = gt.winding_number(*p);
            assert!(
                (w - 1.0).abs() < 1e-6,
                "{name}: {p:?} should be inside (winding number {w})"
            );
        }
        for p in outside
            .iter()
            .chain([[5.0, 5.0, 5.0], [-9.0, 0.1, 0.0]].iter())
        {
            let w = gt.winding_number(*p);
            assert!(
                w.abs() < 1e-6,
                "{name}: {p:?} should be outside (winding number {w})"
            );
        }
        gt
    }

    #[test]
    fn cube_and_slab() {
        let m = cube([-1.0, 0.0, 2.0], [1.0, 0.5, 3.0]);
        assert_eq!((m.positions.len(), m.triangles.len()), (8, 12));
        check_closed(
            "cube",
            &m,
            &[[0.0, 0.25, 2.5], [0.99, 0.49, 2.01]],
            &[[0.0, 0.25, 1.9], [1.01, 0.25, 2.5]],
        );
        assert!((m.signed_volume() - 1.0).abs() < 1e-6);
        let s = slab([0.0; 3], [2.0, 0.01, 2.0]);
        check_closed(
            "slab",
            &s,
            &[[0.3, 0.004, -0.7]],
            &[[0.3, 0.006, -0.7], [0.3, -0.006, -0.7]],
        );
        assert!((s.signed_volume() - 0.04).abs() < 1e-6);
    }

    #[test]
    fn spheres_and_tori() {
        let m = uv_sphere([1.0, 2.0, 3.0], 0.5, 32, 16);
        assert_eq!(m.positions.len(), 2 + 32 * 15);
        assert_eq!(m.triangles.len(), 2 * 32 * 15);
        check_closed(
            "sphere",
            &m,
            &[[1.0, 2.0, 3.0], [1.0, 2.45, 3.0]],
            &[[1.0, 2.55, 3.0], [0.0; 3]],
        );
        // The coarsest sphere, a triangular bipyramid, is still closed.
        check_closed(
            "low-poly sphere",
            &uv_sphere([0.0; 3], 1.0, 3, 2),
            &[[0.0, 0.1, 0.0]],
            &[[0.0, 1.1, 0.0]],
        );
        check_closed(
            "low-poly convex",
            &uv_sphere([0.0; 3], 1.0, 6, 3),
            &[[0.0; 3]],
            &[[1.01, 0.0, 0.0]],
        );
        let t = torus([0.0, 1.0, 0.0], 1.0, 0.3, 48, 24);
        assert_eq!(t.triangles.len(), 2 * 48 * 24);
        check_closed(
            "torus",
            &t,
            &[[1.0, 1.0, 0.0], [0.0, 1.2, -1.0]],
            &[[0.0, 1.0, 0.0], [1.0, 1.35, 0.0], [1.4, 1.0, 0.0]],
        );
        let expected = 2.0 * PI * PI * 1.0 * 0.3 * 0.3;
        assert!((t.signed_volume() as f32 - expected).abs() < 0.02 * expected);
    }

    #[test]
    fn prisms() {
        let w = wedge(20.0, 1.0, 1.0);
        check_closed(
            "wedge",
            &w,
            &[[0.3, 0.0, 0.0], [0.95, 0.0, 0.4]],
            &[[1.05, 0.0, 0.0], [0.5, 0.2, 0.0], [-0.01, 0.0, 0.0]],
        );
        // The cross-section is a triangle of base 2 tan(10°) and height 1.
        let area = (10f32).to_radians().tan();
        assert!((w.signed_volume() as f32 - area).abs() < 1e-5);
        // A knife: 8 degrees.
        check_closed(
            "knife wedge",
            &wedge(8.0, 1.5, 1.0),
            &[[1.4, 0.0, 0.0]],
            &[[1.4, 0.02, 0.0]],
        );
        let s = star_prism(5, 1.0, 0.4, 0.5);
        assert_eq!(s.triangles.len(), 4 * 10);
        // A tip is solid; the notch between two tips (at 36°, radius 0.6) is not.
        let notch = [0.6 * (PI / 5.0).cos(), 0.6 * (PI / 5.0).sin(), 0.0];
        check_closed(
            "star prism",
            &s,
            &[[0.0; 3], [0.9, 0.0, 0.2]],
            &[notch, [0.0, 0.0, 0.3]],
        );
        check_closed(
            "six-point star",
            &star_prism(6, 1.0, 0.35, 0.6),
            &[[0.0; 3]],
            &[[0.0, 0.0, 0.31]],
        );
    }

    #[test]
    fn nested_shells_are_hollow() {
        let m = nested_shells(1.0, 0.2);
        let gt = check_closed(
            "nested shells",
            &m,
            &[[0.0, 0.9, 0.0], [0.0, 0.0, -0.85]],
            &[[0.0; 3], [0.5, 0.0, 0.0]],
        );
        assert!(!gt.is_inside([0.0; 3]));
        // The shell's volume: the outer ball minus the inner one (both polygonal).
        let v = m.signed_volume() as f32;
        let want = 4.0 / 3.0 * PI * (1.0 - 0.8f32.powi(3));
        assert!((v - want).abs() < 0.03 * want, "{v} vs {want}");
    }

    #[test]
    fn open_scenes_face_the_right_way() {
        let s = flat_sheet([0.0, 1.0, 0.0], 2.0, 8);
        assert_eq!((s.positions.len(), s.triangles.len()), (81, 128));
        assert!(!s.is_closed());
        assert!(s.is_consistently_oriented());
        for t in &s.triangles {
            let n = normal(&s, t);
            assert!(n.y > 0.0 && n.x == 0.0 && n.z == 0.0, "{n}");
        }
        assert!(s
            .positions
            .iter()
            .all(|p| p[1] == 1.0 && p[0].abs() <= 1.0 && p[2].abs() <= 1.0));
        let h = hemisphere([0.0, -1.0, 0.0], 2.0, 32, 8);
        assert!(!h.is_closed());
        assert!(h.is_consistently_oriented());
        for t in &h.triangles {
            let p = t.map(|i| Vec3::from_array(h.positions[i as usize]));
            let c = (p[0] + p[1] + p[2]) / 3.0 - Vec3::new(0.0, -1.0, 0.0);
            assert!(normal(&h, t).dot(c) > 0.0);
        }
        assert!(h.positions.iter().all(|p| p[1] >= -1.0 - 1e-6));
        // The open edges are exactly the equator's.
        let mut uses: HashMap<(u32, u32), u32> = HashMap::new();
        for t in &h.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *uses.entry((a.min(b), a.max(b))).or_insert(0) += 1;
            }
        }
        let rim: Vec<_> = uses
            .iter()
            .filter(|(_, &n)| n == 1)
            .map(|(e, _)| *e)
            .collect();
        assert_eq!(rim.len(), 32);
        assert!(rim.iter().all(|&(a, b)| [a, b]
            .iter()
            .all(|&i| (h.positions[i as usize][1] + 1.0).abs() < 1e-5)));
    }

    #[test]
    fn cones_stacks_and_soups() {
        let c = cone(2.0, 0.1, 16);
        check_closed(
            "cone",
            &c,
            &[[0.5, 0.0, 0.0], [1.9, 0.0, 0.0]],
            &[[2.01, 0.0, 0.0], [1.0, 0.06, 0.0], [-0.01, 0.0, 0.0]],
        );
        // A regular 16-gon of circumradius 0.1 has area 8 · 0.1² · sin(π/8); the cone a third
        // of that times its length.
        let want = 8.0 * 0.01 * (PI / 8.0).sin() * 2.0 / 3.0;
        assert!((c.signed_volume() as f32 - want).abs() < 1e-4 * want);
        let s = sheet_stack(3, 0.01);
        assert_eq!(s.triangles.len(), 3 * 32);
        assert!(s.is_consistently_oriented() && !s.is_closed());
        let mut ys: Vec<f32> = s.positions.iter().map(|p| p[1]).collect();
        ys.dedup();
        assert_eq!(ys, [-0.01, 0.0, 0.01]);
        let a = triangle_soup(50, 3);
        assert_eq!((a.positions.len(), a.triangles.len()), (150, 50));
        assert_eq!(a.positions, triangle_soup(50, 3).positions);
        assert_ne!(a.positions, triangle_soup(50, 4).positions);
        assert!(a.positions.iter().flatten().all(|x| x.abs() < 1.4));
        assert!(a.triangles.iter().all(|t| normal(&a, t).length() > 0.0));
    }

    #[test]
    fn merge_and_subdivide() {
        let a = cube([-1.0; 3], [0.0; 3]);
        let b = uv_sphere([2.0, 0.0, 0.0], 0.5, 12, 6);
        let m = merge(&[a.clone(), b.clone()]);
        assert_eq!(m.positions.len(), a.positions.len() + b.positions.len());
        assert_eq!(m.triangles.len(), a.triangles.len() + b.triangles.len());
        assert_eq!(m.triangles[12], b.triangles[0].map(|i| i + 8));
        check_closed(
            "merged",
            &m,
            &[[-0.5; 3], [2.0, 0.0, 0.0]],
            &[[1.0, 0.0, 0.0]],
        );
        let s = uv_sphere([0.0; 3], 1.0, 16, 8);
        let d = subdivide(&s);
        assert_eq!(d.triangles.len(), 4 * s.triangles.len());
        // Euler: a closed triangle mesh has 3F/2 edges, one new vertex each.
        assert_eq!(
            d.positions.len(),
            s.positions.len() + 3 * s.triangles.len() / 2
        );
        check_closed("subdivided sphere", &d, &[[0.0; 3]], &[[0.0, 1.01, 0.0]]);
        assert!(
            (d.signed_volume() - s.signed_volume()).abs() < 1e-6,
            "midpoint subdivision keeps the shape"
        );
        check_closed(
            "subdivided torus",
            &subdivide(&torus([0.0; 3], 1.0, 0.3, 12, 8)),
            &[[0.0, 0.0, 1.0]],
            &[[0.0; 3]],
        );
        let sheet = subdivide(&flat_sheet([0.0; 3], 1.0, 2));
        assert_eq!(sheet.triangles.len(), 32);
        assert!(sheet.is_consistently_oriented() && !sheet.is_closed());
        assert!(merge(&[]).triangles.is_empty());
    }

    #[test]
    fn checks_catch_broken_meshes() {
        let mut m = cube([0.0; 3], [1.0; 3]);
        m.triangles.pop();
        assert!(!m.is_closed());
        let mut m = cube([0.0; 3], [1.0; 3]);
        m.triangles[3].swap(1, 2);
        assert!(m.is_closed() && !m.is_consistently_oriented());
        let mut m = cube([0.0; 3], [1.0; 3]);
        m.triangles[0] = [0, 0, 1];
        assert!(!m.is_closed());
        let mut m = cube([0.0; 3], [1.0; 3]);
        m.triangles[0][0] = 99;
        assert!(!m.is_closed());
        let mut m = cube([0.0; 3], [1.0; 3]);
        for t in &mut m.triangles {
            t.swap(1, 2);
        }
        assert!(m.is_closed() && m.is_consistently_oriented() && m.signed_volume() < 0.0);
    }

    #[test]
    fn a_standing_mesh_is_scaled_centred_and_on_the_floor() {
        let tall = cube([3.0, 1.0, -2.0], [5.0, 9.0, 0.0]);
        let (m, top) = standing(&tall, 2.0).unwrap();
        let ys: Vec<f32> = m.positions.iter().map(|p| p[1]).collect();
        let xs: Vec<f32> = m.positions.iter().map(|p| p[0]).collect();
        assert_eq!(ys.iter().copied().fold(f32::MAX, f32::min), 0.0);
        assert_eq!(top, 2.0);
        assert_eq!(xs.iter().copied().fold(f32::MAX, f32::min), -0.25);
        assert_eq!(xs.iter().copied().fold(f32::MIN, f32::max), 0.25);
        assert_eq!(m.triangles, tall.triangles);
        let point = Mesh {
            positions: vec![[1.0, 2.0, 3.0]; 3],
            triangles: vec![[0, 1, 2]],
        };
        assert!(standing(&point, 1.0).is_none());
        let mut bad = tall.clone();
        bad.positions[0][1] = f32::NAN;
        bad.positions[1][0] = f32::INFINITY;
        assert!(standing(&bad, 1.0).is_none());
    }
}
