//! What a Rust user reaches for today: parry3d's `TriMesh` (with its BVH), each particle's
//! step cast as a ray (`RayCast::cast_local_ray_and_get_normal`, not solid, so both sides of
//! every triangle are hit), the nearest hit answered as `step_by_casting` in the parent module says.
//!
//! parry works in `f32` (its `glamx` vectors); the ray's direction is the whole displacement
//! `v * t_remaining`, so its time of impact is the fraction of it, and the cast stops at 1.

use glam::{DVec3, Vec3};
use octoproxy_core::{Particle, StepParams};
use parry3d::math::Vector;
use parry3d::query::{Ray, RayCast};
use parry3d::shape::TriMesh;

use super::{Hit, Method};

/// A parry3d triangle mesh stepped with ray casts.
pub struct ParryTriMesh {
    mesh: TriMesh,
    standoff: f64,
    dropped: usize,
}

impl ParryTriMesh {
    /// Builds the `TriMesh` and its BVH. Triangles with an index past `positions`, a
    /// non-finite vertex or zero area are left out first (parry would keep them, and a
    /// non-finite vertex would poison its BVH); an error when none is left, or when parry
    /// refuses the mesh.
    pub fn new(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Result<Self, String> {
        let (triangles, dropped) = super::valid_triangles(positions, triangles);
        if triangles.is_empty() {
            return Err(format!("no usable triangle (of {dropped})"));
        }
        let standoff = super::standoff(positions, &triangles);
        let vertices: Vec<Vector> = positions
            .iter()
            .map(|p| Vector::new(p[0], p[1], p[2]))
            .collect();
        let mesh =
            TriMesh::new(vertices, triangles).map_err(|e| format!("parry3d TriMesh: {e}"))?;
        Ok(ParryTriMesh {
            mesh,
            standoff,
            dropped,
        })
    }

    /// Triangles left out when building (bad indices, non-finite vertices, zero area).
    pub fn dropped_triangles(&self) -> usize {
        self.dropped
    }

    /// The nearest hit of the segment `a → a + d`.
    fn cast(&self, a: DVec3, d: DVec3) -> Hit {
        let a = a.as_vec3();
        let d = d.as_vec3();
        let ray = Ray::new(Vector::new(a.x, a.y, a.z), Vector::new(d.x, d.y, d.z));
        let hit = self.mesh.cast_local_ray_and_get_normal(&ray, 1.0, false)?;
        let n = hit.normal;
        Some((
            f64::from(hit.time_of_impact),
            DVec3::new(n.x.into(), n.y.into(), n.z.into()),
        ))
    }
}

impl Method for ParryTriMesh {
    fn name(&self) -> &'static str {
        "parry3d"
    }

    /// parry's own accounting (`TriMesh::total_memory_size`): the struct, its vertices
    /// (12 bytes each) and indices (12 bytes per triangle), and its BVH (`Bvh::heap_memory_size`:
    /// wide nodes of two 32-byte children, the parent links and the leaf table). No topology,
    /// pseudo-normals or connected components are built.
    fn memory_bytes(&self) -> usize {
        self.mesh.total_memory_size()
    }

    fn step_traced(
        &self,
        p: &mut Particle,
        params: &StepParams,
        trace: &mut dyn FnMut(Vec3, Vec3),
    ) {
        super::step_by_casting(p, params, self.standoff, |a, d| self.cast(a, d), trace);
    }
}
