//! Particle emitters for trying octoproxy out without a particle file: uniformly in a box, or
//! just in front of a scene's surface. Deterministic for a given seed.

use glam::{DVec3, Vec3};
use octoproxy_core::{Particle, ProxyView, SIDE_FRONT};

use crate::bake::offset::OffsetSurface;
use crate::bake::MeshRef;
use crate::sides::{in_solid_leaf, Sides};

/// A small, fast, seedable generator (xorshift64*), so emission needs no dependency.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A generator for `seed` (any value, zero included).
    pub fn new(seed: u64) -> Self {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0xD1B5_4A32_D192_ED03 | 1)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Uniform in `[0, 1)`.
    pub fn f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }

    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.f32()
    }

    /// A uniformly random unit vector.
    pub fn unit_vector(&mut self) -> Vec3 {
        loop {
            let v = Vec3::new(
                self.range(-1.0, 1.0),
                self.range(-1.0, 1.0),
                self.range(-1.0, 1.0),
            );
            let l = v.length_squared();
            if l > 1e-4 && l <= 1.0 {
                return v / l.sqrt();
            }
        }
    }
}

/// An emitter asked for more particles than memory holds: the allocation failed, and nothing
/// was emitted (an error where `Vec::with_capacity` would abort the process).
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{particles} particles ({bytes} bytes) could not be allocated")]
pub struct EmitError {
    /// Particles asked for.
    pub particles: usize,
    /// The bytes they need (saturated).
    pub bytes: u64,
}

/// An empty list with room for `n` particles, or [`EmitError`] where memory has none.
pub fn reserve_particles(n: usize) -> Result<Vec<Particle>, EmitError> {
    let mut out = Vec::new();
    out.try_reserve_exact(n).map_err(|_| EmitError {
        particles: n,
        bytes: (n as u64).saturating_mul(core::mem::size_of::<Particle>() as u64),
    })?;
    Ok(out)
}

/// `n` particles uniformly in the box `[min, max]`, each moving in a random direction at
/// `speed`. [`EmitError`] when `n` particles do not fit in memory.
pub fn emit_box(
    n: usize,
    min: Vec3,
    max: Vec3,
    speed: f32,
    seed: u64,
) -> Result<Vec<Particle>, EmitError> {
    let mut rng = Rng::new(seed);
    let mut out = reserve_particles(n)?;
    out.extend((0..n).map(|_| {
        let p = Vec3::new(
            rng.range(min.x, max.x),
            rng.range(min.y, max.y),
            rng.range(min.z, max.z),
        );
        Particle::new(p.to_array(), (rng.unit_vector() * speed).to_array())
    }));
    Ok(out)
}

/// Uniform random points on the surface of meshes: triangles picked by area, points uniform
/// in them. Triangles with a bad index, a non-finite vertex or no area are left out.
pub struct SurfaceSampler {
    /// Each triangle's vertices and unit normal.
    tris: Vec<([DVec3; 3], DVec3)>,
    /// The running sum of their areas.
    cumulative: Vec<f64>,
}

impl SurfaceSampler {
    /// The triangles of `meshes` with an area.
    pub fn new(meshes: &[MeshRef<'_>]) -> Self {
        let mut tris = Vec::new();
        let mut cumulative = Vec::new();
        let mut total = 0.0f64;
        for m in meshes {
            for t in m.triangles {
                let Some(v) = t
                    .iter()
                    .map(|&i| m.positions.get(i as usize))
                    .collect::<Option<Vec<_>>>()
                else {
                    continue;
                };
                let v: [DVec3; 3] = [0, 1, 2].map(|k| DVec3::from_array(v[k].map(f64::from)));
                let c = (v[1] - v[0]).cross(v[2] - v[0]);
                let area = c.length() * 0.5;
                if area > 0.0 && area.is_finite() && v.iter().all(|p| p.is_finite()) {
                    total += area;
                    tris.push((v, c.normalize()));
                    cumulative.push(total);
                }
            }
        }
        SurfaceSampler { tris, cumulative }
    }

    /// Whether there is no area to sample.
    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    /// A random point of the surface and its triangle's normal. Panics if [`Self::is_empty`].
    pub fn sample(&self, rng: &mut Rng) -> (DVec3, DVec3) {
        let total = self.cumulative[self.cumulative.len() - 1];
        let r = rng.f32() as f64 * total;
        let i = self
            .cumulative
            .partition_point(|&c| c < r)
            .min(self.tris.len() - 1);
        let (v, normal) = self.tris[i];
        let (mut a, mut b) = (rng.f32() as f64, rng.f32() as f64);
        if a + b > 1.0 {
            a = 1.0 - a;
            b = 1.0 - b;
        }
        (v[0] + (v[1] - v[0]) * a + (v[2] - v[0]) * b, normal)
    }
}

/// Halvings of the offset tried at one surface point before another point is drawn.
const OFFSET_HALVINGS: u32 = 8;

/// Points drawn per particle at most before [`emit_surface`] gives up on the rest.
const DRAWS_PER_PARTICLE: usize = 64;

/// `n` particles on the surface of the meshes (triangles picked by area), each put `offset`
/// along its triangle's normal, in front of the face it was emitted from, moving at `speed` in
/// random directions, with side front.
///
/// Each is checked against the mesh ([`Sides`], exactly): it must be in front of its
/// surface by [the sides rule](crate::sides), so outside every closed part; outside what open
/// parts enclose too (the scene's generalized winding number there is below ½: not inside a
/// scan with holes, nor where the parts of an open model pass through each other); and the way
/// out from its face must cross no other surface. Where it is not (parts overlapping at the face,
/// a concave corner where the offset along one face lands behind the next, a sheet nearer
/// than the offset), the offset is halved, up to eight times, and then another point is drawn.
/// So every particle is within `offset` of its face; pass one `dmax` leaf for the command
/// line's emitter. Deterministic for a given seed. Fewer than `n` come back only where the
/// surface has no such points (after 64 draws per particle); none where it has no area.
/// [`EmitError`] when `n` particles do not fit in memory.
pub fn emit_surface(
    n: usize,
    meshes: &[MeshRef<'_>],
    offset: f32,
    speed: f32,
    seed: u64,
) -> Result<Vec<Particle>, EmitError> {
    emit_surface_where(n, meshes, 0.0, offset, speed, seed, |_| true)
}

/// The command line's emitter, [`emit_surface`] for the proxy `view`: one `dmax` leaf of
/// offset, and no particle strictly inside a solid leaf, where it would start caged
/// ([`Sides::cages`]: where parts cross, a surface folds or ends within a leaf, a particle
/// there may leave only through the faces it can reach without crossing, and some can reach
/// none). Where the surface is crowded, points are drawn again, so fewer particles start
/// near it (on the ogre, whose parts overlap, 8 % of the points one leaf in front of the
/// surface are in solid leaves at `dmax` 8).
///
/// For a proxy baked for a particle radius `R`, pass its offset surface (`radius`): each
/// particle is then put between `R` and `R` plus one leaf along its face's normal, at least
/// `R` from every triangle and outside the offset surface's band.
pub fn emit_surface_for(
    view: &ProxyView<'_>,
    n: usize,
    meshes: &[MeshRef<'_>],
    radius: Option<&OffsetSurface>,
    speed: f32,
    seed: u64,
) -> Result<Vec<Particle>, EmitError> {
    let base = radius.map_or(0.0, |s| s.radius() as f64);
    emit_surface_where(n, meshes, base, view.finest_leaf_size(), speed, seed, |p| {
        !in_solid_leaf(view, p)
            && radius.is_none_or(|s| s.outside(p) && s.truth().distance(p) >= s.radius() as f64)
    })
}

/// [`emit_surface`], keeping only the points `accept` takes.
fn emit_surface_where(
    n: usize,
    meshes: &[MeshRef<'_>],
    base: f64,
    offset: f32,
    speed: f32,
    seed: u64,
    accept: impl Fn([f32; 3]) -> bool,
) -> Result<Vec<Particle>, EmitError> {
    let mut out = reserve_particles(n)?;
    let surface = SurfaceSampler::new(meshes);
    if surface.is_empty() || !(offset > 0.0) || !offset.is_finite() {
        return Ok(Vec::new());
    }
    let sides = Sides::new(meshes);
    let mut rng = Rng::new(seed);
    for _ in 0..n.saturating_mul(DRAWS_PER_PARTICLE) {
        if out.len() == n {
            break;
        }
        let (on, normal) = surface.sample(&mut rng);
        let velocity = (rng.unit_vector() * speed).to_array();
        let mut d = offset as f64;
        for _ in 0..=OFFSET_HALVINGS {
            let p = (on + normal * (base + d)).as_vec3();
            let from = (on + normal * ((base + d) / 1024.0)).as_vec3();
            let clear = sides.crossings(from.to_array(), p.to_array()) == 0;
            let outside = sides.winding_number(p.to_array()) < 0.5;
            if clear && outside && accept(p.to_array()) && sides.side(p.to_array()) == SIDE_FRONT {
                let mut q = Particle::new(p.to_array(), velocity);
                q.side = SIDE_FRONT;
                out.push(q);
                break;
            }
            d *= 0.5;
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_emission_stays_in_the_box_and_is_deterministic() {
        let a = emit_box(1000, Vec3::splat(-1.0), Vec3::new(2.0, 3.0, 4.0), 2.0, 7).unwrap();
        let b = emit_box(1000, Vec3::splat(-1.0), Vec3::new(2.0, 3.0, 4.0), 2.0, 7).unwrap();
        assert_eq!(a, b);
        for p in &a {
            let x = Vec3::from_array(p.position);
            assert!(x.cmpge(Vec3::splat(-1.0)).all() && x.cmplt(Vec3::new(2.0, 3.0, 4.0)).all());
            assert!((Vec3::from_array(p.velocity).length() - 2.0).abs() < 1e-4);
        }
    }

    #[test]
    fn surface_emission_is_offset_along_the_normal() {
        let positions = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]];
        let triangles = [[0, 1, 2]]; // normal +y
        let p = emit_surface(
            100,
            &[MeshRef {
                positions: &positions,
                triangles: &triangles,
            }],
            0.25,
            0.0,
            3,
        )
        .unwrap();
        assert_eq!(p.len(), 100);
        for q in p {
            assert!((q.position[1] - 0.25).abs() < 1e-6, "{:?}", q.position);
        }
    }

    #[test]
    fn more_particles_than_memory_holds_is_an_error_not_an_abort() {
        // `usize::MAX / 2` particles: more bytes than any allocator gives.
        let n = usize::MAX / 2;
        let e = emit_box(n, Vec3::ZERO, Vec3::ONE, 0.0, 1).unwrap_err();
        assert_eq!(e.particles, n);
        assert_eq!(e.bytes, u64::MAX);
        let positions = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]];
        let triangles = [[0, 1, 2]];
        let mesh = [MeshRef {
            positions: &positions,
            triangles: &triangles,
        }];
        assert_eq!(
            emit_surface(n, &mesh, 0.25, 0.0, 3).unwrap_err().particles,
            n
        );
        assert!(e.to_string().contains("could not be allocated"), "{e}");
    }

    #[test]
    fn surface_emission_puts_none_inside_a_part_or_behind_a_surface() {
        use crate::ground_truth::GroundTruth;
        use crate::scenes;
        let plate = scenes::slab([0.0; 3], [2.0, 0.2, 2.0]);
        let mut fins_through_a_plate = vec![plate];
        fins_through_a_plate.extend(
            (0..4).map(|i| scenes::slab([i as f32 * 0.4 - 0.6, 0.2, 0.0], [0.01, 0.8, 1.5])),
        );
        let scenes_to_emit_on: Vec<Vec<crate::io::Mesh>> = vec![
            fins_through_a_plate,
            vec![
                scenes::cube([0.0; 3], [1.0; 3]),
                scenes::cube([0.5, 0.3, 0.2], [1.5, 0.7, 0.8]),
            ],
            vec![scenes::star_prism(7, 1.5, 0.4, 1.0)],
            vec![scenes::nested_shells(1.0, 0.02)],
            vec![scenes::v_groove(20.0, 0.0)],
        ];
        let offset = 0.03;
        for meshes in &scenes_to_emit_on {
            let refs: Vec<MeshRef<'_>> = meshes.iter().map(MeshRef::from).collect();
            let all = scenes::merge(meshes);
            let gt = GroundTruth::new(&all.positions, &all.triangles);
            let closed = scenes::is_closed(&all);
            let p = emit_surface(3000, &refs, offset, 1.0, 5).unwrap();
            assert_eq!(p.len(), 3000);
            let sides = Sides::new(&refs);
            for q in &p {
                assert_eq!(q.side, SIDE_FRONT);
                assert_eq!(sides.side(q.position), SIDE_FRONT, "{:?}", q.position);
                let d = gt.distance(q.position);
                assert!(
                    d <= offset as f64 * 1.0001 && d > 0.0,
                    "{d} at {:?}",
                    q.position
                );
                if closed {
                    assert!(!gt.is_inside(q.position), "inside at {:?}", q.position);
                }
            }
            // For a proxy: the same, and none where it would start caged.
            let params = crate::BuildParams {
                dmax: 6,
                ..crate::BuildParams::default()
            };
            let (words, _) = crate::bake(&refs, &params, &()).unwrap();
            let view = ProxyView::new(&words).unwrap();
            let p = emit_surface_for(&view, 2000, &refs, None, 1.0, 5).unwrap();
            assert_eq!(p.len(), 2000);
            let mut caged = p.clone();
            sides.cages(&view, &mut caged, false);
            for (q, c) in p.iter().zip(&caged) {
                assert!(!c.is_caged(), "caged at {:?}", q.position);
                assert_eq!(sides.side(q.position), SIDE_FRONT, "{:?}", q.position);
                assert!(gt.distance(q.position) <= view.finest_leaf_size() as f64 * 1.0001);
            }
        }
    }
}
