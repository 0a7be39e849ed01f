//! The offset surface of a particle radius: the boundary of the band of points closer than
//! `R` to the scene's triangles, as a closed triangle mesh that the ordinary bake takes.
//!
//! A particle of radius `R` touches the scene where its centre meets that surface, so a
//! proxy of it ([`super::bake_with_radius`]) makes the march, unchanged, collide centres at
//! the radius. The band is closed whatever the scene is (a sheet becomes a slab of thickness
//! `2R` with rounded rims), parts thinner than `2R` fill it and vanish into it, and every
//! point outside it is in front of it: its normals point away from the scene, so both sides
//! of an open sheet and the inside of a thick solid are all front.
//!
//! **Extraction.** The exact unsigned distance `d` (a BVH over the triangles, the same one
//! the ground truth uses) is sampled on a grid of spacing `h`, at most one `dmax` leaf of the
//! proxy that will be baked ([`spacing`]), and only near the offset surface: a block of the grid is
//! skipped whole when the distance at its centre is farther from `R` than the block's half
//! diagonal (`d` is 1-Lipschitz). Each cell is cut into six tetrahedra around its main
//! diagonal (the Kuhn triangulation, which matches across faces, so the surface has no
//! cracks) and each tetrahedron with corners on both sides of `d = R` gives one or two
//! triangles on the linear interpolation's zero set, facing away from the band. A corner with
//! `d >= R` is outside, and corner values are kept a thousandth of `h` from zero, so no two
//! cuts meet: the surface is closed (checked after welding; an error where `f32` cannot keep
//! its vertices apart).
//!
//! **Resolution.** The radius must exceed the cell diagonal `h√3`: then every tetrahedron
//! holding a point of the scene has every corner nearer than `R`, so the scene lies strictly
//! inside the band and no path reaches it without crossing the surface. A smaller radius is
//! an error (it would mean less than a leaf anyway).
//!
//! **Accuracy.** A point of the surface lies in a tetrahedron with a corner at `d >= R`, at
//! most the cell diagonal `h√3` from it, so its distance to the scene is at least `R - h√3`;
//! any point outside the band is at least that far too (a point nearer than `R - h√3` has
//! every corner of its tetrahedron inside), and a point at `R + h√3` or farther is outside.
//! With `h` at most a leaf, `h√3` is at most a `dmax` leaf's diagonal: a centre that never
//! crosses the surface stays at least `R` less a leaf diagonal from every triangle.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use glam::DVec3;
use rayon::prelude::*;

use super::{BuildError, BuildProgress, MeshRef};
use crate::ground_truth::GroundTruth;
use octoproxy_core::{Particle, ProxyView};

use crate::sides::{assign_each, cage_each, in_solid_leaf, CageCounts, SideCounts, Sides};

/// Largest radius, in multiples of the scene's extent, that [`offset_mesh`] accepts.
pub const MAX_RADIUS_PER_EXTENT: f64 = 1000.0;

/// Most triangles an offset surface may have before the bake gives up (a radius bake at a
/// `dmax` finer than the scene needs).
pub const MAX_OFFSET_TRIANGLES: usize = 1 << 27;

/// Blocks of the grid at most this many cells wide are searched by one thread each.
const SERIAL_BLOCK: u32 = 16;

/// The offset surface at distance `radius` from every triangle of `meshes`.
#[derive(Clone, Debug, Default)]
pub struct OffsetMesh {
    /// Vertex positions.
    pub positions: Vec<[f32; 3]>,
    /// Triangles, counter-clockwise seen from outside the band.
    pub triangles: Vec<[u32; 3]>,
    /// The grid spacing `h` the surface was extracted at: every point of the surface, and
    /// every point outside the band, is at least `radius - h√3` from the scene.
    pub spacing: f64,
}

/// The grid the offset surface is extracted on: cell `(i, j, k)` spans `lo + h * (i, j, k)
/// ..= lo + h * (i + 1, j + 1, k + 1)`. The bake and the host (starting sides, the emitter)
/// build the same one from the same meshes, radius and `dmax`.
#[derive(Clone, Debug)]
pub struct OffsetGrid {
    lo: DVec3,
    h: f64,
    /// Cells per axis.
    cells: [u32; 3],
    radius: f64,
    dmax: u32,
}

impl OffsetGrid {
    /// Vertex `v`, as the `f32` point every query and every interpolation uses.
    fn vertex(&self, v: [u32; 3]) -> [f32; 3] {
        [0, 1, 2].map(|a| (self.lo[a] + self.h * v[a] as f64) as f32)
    }

    fn key(v: [u32; 3]) -> u64 {
        (v[0] as u64) | (v[1] as u64) << 21 | (v[2] as u64) << 42
    }

    fn unkey(k: u64) -> [u32; 3] {
        [k & 0x1f_ffff, (k >> 21) & 0x1f_ffff, k >> 42].map(|x| x as u32)
    }

    /// The grid spacing `h`.
    pub fn spacing(&self) -> f64 {
        self.h
    }

    /// The value whose zero set the surface is, at a grid vertex whose distance to the scene
    /// is `d`: `d - R`, kept at least [`SNAP`] `h` from zero on its own side, so that no
    /// corner lies on the surface (two cuts would meet there, and the triangles between
    /// them would collapse).
    fn value(&self, d: f64) -> f64 {
        let f = d - self.radius;
        let snap = SNAP * self.h;
        if f < 0.0 {
            f.min(-snap)
        } else {
            f.max(snap)
        }
    }

    /// The grid of the offset surface at `radius` from the triangles of `meshes` (checked by
    /// the bake's gather), for a proxy baked at `dmax`.
    pub fn new(meshes: &[MeshRef<'_>], radius: f32, dmax: u32) -> Result<Self, BuildError> {
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for m in meshes {
            for t in m.triangles {
                for &i in t {
                    if let Some(&p) = m.positions.get(i as usize) {
                        lo = lo.min(to_d(p));
                        hi = hi.max(to_d(p));
                    }
                }
            }
        }
        let r = radius as f64;
        let extent = (hi - lo).max_element();
        if !(r > 0.0) || !r.is_finite() {
            return Err(BuildError::BadParam(format!(
                "radius must be a finite number > 0 for an offset surface, got {radius}"
            )));
        }
        if !(extent > 0.0) || r > MAX_RADIUS_PER_EXTENT * extent {
            return Err(BuildError::BadParam(format!(
                "radius {radius} is more than {MAX_RADIUS_PER_EXTENT} times the scene's extent of {extent:.4e}: collide the scene against the particle instead"
            )));
        }
        let h = spacing(extent, r, dmax);
        if r <= h * 3f64.sqrt() {
            return Err(BuildError::BadParam(format!(
                "radius {radius} is not more than the offset grid's cell diagonal at dmax {dmax} ({:.4e}, about a dmax leaf's diagonal): the band would slip between the grid's points; raise dmax (or bake without a radius: a point proxy keeps centres to the surface itself)",
                h * 3f64.sqrt()
            )));
        }
        // Two cells of margin past the band on every side: the boundary vertices are outside.
        let lo = lo - DVec3::splat(r + 2.0 * h);
        let top = hi + DVec3::splat(r + 2.0 * h);
        if lo.abs().max(top.abs()).max_element() >= f32::MAX as f64 / 4.0 {
            // The surface's vertices, and the proxy's root cube around them, must be f32.
            return Err(BuildError::TooLarge {
                extent: (top - lo).max_element(),
            });
        }
        let span = top - lo;
        let cells = [0, 1, 2].map(|a| (span[a] / h).ceil() as u64 + 1);
        if cells.iter().any(|&c| c >= (1 << 21) - 1) {
            return Err(BuildError::BadParam(format!(
                "radius {radius} at dmax {dmax} needs a grid of {} x {} x {} cells (at most 2^21 - 2 per axis): lower dmax",
                cells[0], cells[1], cells[2]
            )));
        }
        Ok(OffsetGrid {
            lo,
            h,
            cells: cells.map(|c| c as u32),
            radius: r,
            dmax,
        })
    }

    /// Whether `p` is outside the band (in front of the offset surface), by at least
    /// `margin` of the interpolated distance, with `gt` the scene's ground truth: the linear
    /// interpolation over the tetrahedron of the Kuhn triangulation that holds `p` of the
    /// values at its corners, whose zero set the surface is. Exact but for the rounding of
    /// the surface's vertices to `f32`. Outside the grid, a point is outside the band.
    pub fn outside(&self, gt: &GroundTruth, p: [f32; 3], margin: f64) -> bool {
        let q = (to_d(p) - self.lo) / self.h;
        if !q.is_finite() || (0..3).any(|a| q[a] < 0.0 || q[a] >= self.cells[a] as f64) {
            return true;
        }
        let cell = [0, 1, 2].map(|a| q[a].floor() as u32);
        let frac = [0, 1, 2].map(|a| q[a] - cell[a] as f64);
        // The tetrahedron: from corner 0 along the axes in order of falling fraction.
        let mut axes = [0usize, 1, 2];
        axes.sort_by(|&a, &b| frac[b].total_cmp(&frac[a]));
        let cap = self.radius + 2.0 * self.h;
        let f = |v: [u32; 3]| self.value(gt.distance_capped(self.vertex(v), cap));
        let mut v = cell;
        let mut sum = (1.0 - frac[axes[0]]) * f(v);
        for k in 0..3 {
            v[axes[k]] += 1;
            let w = frac[axes[k]] - if k < 2 { frac[axes[k + 1]] } else { 0.0 };
            sum += w * f(v);
        }
        sum > margin
    }
}

/// Corner values are kept this many grid spacings from zero ([`OffsetGrid::value`]).
const SNAP: f64 = 1e-3;

fn to_d(p: [f32; 3]) -> DVec3 {
    DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}

/// The grid spacing for a proxy baked at `dmax` from the offset surface of a scene whose box
/// is `extent` wide: at most that proxy's `dmax` leaf. The offset surface's box is at least
/// `extent + 2R - 2h√3` wide, so its root cube, and so its leaf, is at least that wide over
/// `2^dmax`; this `h` solves `h = (extent + 2R - 2h√3) / 2^dmax`.
pub fn spacing(extent: f64, radius: f64, dmax: u32) -> f64 {
    let cells = (1u64 << dmax) as f64;
    (extent + 2.0 * radius) / (cells + 2.0 * 3f64.sqrt()) * (1.0 - 1e-9)
}

/// The offset surface at distance `radius` from the triangles of `meshes` (already checked
/// by the bake's gather: finite, in range), for a proxy baked at `dmax`.
pub fn offset_mesh(
    meshes: &[MeshRef<'_>],
    radius: f32,
    dmax: u32,
    progress: &dyn BuildProgress,
) -> Result<OffsetMesh, BuildError> {
    let grid = OffsetGrid::new(meshes, radius, dmax)?;
    let gt = scene_truth(meshes);
    extract(&grid, &gt, progress)
}

/// The surface on `grid`, with `gt` the scene's ground truth.
fn extract(
    grid: &OffsetGrid,
    gt: &GroundTruth,
    progress: &dyn BuildProgress,
) -> Result<OffsetMesh, BuildError> {
    let (radius, dmax) = (grid.radius, grid.dmax);
    let r = grid.radius;
    let h = grid.h;

    // 1. The cells the surface may pass through.
    let side = grid
        .cells
        .iter()
        .copied()
        .max()
        .unwrap_or(1)
        .next_power_of_two();
    progress.begin("offset: search", 1);
    let mut cells = Vec::new();
    search(grid, gt, [0; 3], side, &mut cells);
    progress.advance(1);
    cells.par_sort_unstable();

    // 2. The value at every corner of those cells, once per vertex.
    let mut keys: Vec<u64> = cells
        .par_iter()
        .flat_map_iter(|c| (0..8u32).map(move |k| OffsetGrid::key(corner(*c, k))))
        .collect();
    keys.par_sort_unstable();
    keys.dedup();
    progress.begin("offset: distance", keys.len() as u64);
    // Corners of a crossing cell are within h√3 of a corner inside the band: nearer than
    // R + 2h, so the cap never changes a value that is used.
    let cap = r + 2.0 * h;
    let values: Vec<f64> = keys
        .par_iter()
        .with_min_len(1024)
        .map(|&k| {
            let d = gt.distance_capped(grid.vertex(OffsetGrid::unkey(k)), cap);
            progress.advance(1);
            grid.value(d)
        })
        .collect();
    let value = |v: [u32; 3]| -> f64 {
        let k = OffsetGrid::key(v);
        keys.binary_search(&k)
            .map(|i| values[i])
            .unwrap_or_else(|_| grid.value(cap))
    };

    // 3. Triangles, cell by cell, then one vertex per distinct position (the cuts of one
    // grid edge have the same bits from every cell; no two edges share a cut).
    progress.begin("offset: triangles", cells.len() as u64);
    let soup: Vec<[[f32; 3]; 3]> = cells
        .par_iter()
        .with_min_len(256)
        .flat_map_iter(|&c| {
            let mut out = Vec::new();
            cell_triangles(grid, c, &value, &mut out);
            progress.advance(1);
            out
        })
        .collect();
    if soup.len() > MAX_OFFSET_TRIANGLES {
        return Err(BuildError::BadParam(format!(
            "the offset surface of radius {radius} at dmax {dmax} would have {} triangles (at most {MAX_OFFSET_TRIANGLES}): lower dmax",
            soup.len()
        )));
    }
    let mut ids: HashMap<u128, u32, BuildHasherDefault<WeldHasher>> =
        HashMap::with_capacity_and_hasher(soup.len() / 2 + 16, Default::default());
    let mut out = OffsetMesh {
        spacing: h,
        ..OffsetMesh::default()
    };
    for t in &soup {
        let tri = t.map(|p| {
            let [x, y, z] = p.map(|x| if x == 0.0 { 0 } else { x.to_bits() as u128 });
            let key = x | y << 32 | z << 64;
            let next = out.positions.len() as u32;
            *ids.entry(key).or_insert_with(|| {
                out.positions.push(p);
                next
            })
        });
        out.triangles.push(tri);
    }
    if !is_closed(&out.triangles) {
        return Err(BuildError::BadParam(format!(
            "the offset surface of radius {radius} at dmax {dmax} does not close at f32 precision (the scene is too small for its distance from the origin): move it nearer the origin or lower dmax"
        )));
    }
    Ok(out)
}

/// The hash of the offset surface's vertex weld: a position's three bits words, mixed by a
/// multiply and a shift (the standard library's SipHash, made to resist chosen keys, took 0.6 s
/// to weld fandisk's 2.3M offset triangles on one thread). Only the speed depends on it: the
/// weld numbers vertices in their order of first appearance whatever the hash.
#[derive(Default)]
struct WeldHasher(u64);

impl Hasher for WeldHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(b as u64);
        }
    }

    fn write_u64(&mut self, x: u64) {
        let h = (self.0 ^ x).wrapping_mul(0x9e37_79b9_7f4a_7c15);
        self.0 = h ^ h >> 29;
    }

    fn write_u128(&mut self, x: u128) {
        self.write_u64(x as u64);
        self.write_u64((x >> 64) as u64);
    }
}

/// Whether every edge of `triangles` is used exactly once in each direction.
pub fn is_closed(triangles: &[[u32; 3]]) -> bool {
    let mut edges: Vec<(u64, bool)> = triangles
        .par_iter()
        .flat_map_iter(|t| {
            (0..3).map(move |k| {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                let (lo, hi) = (a.min(b) as u64, a.max(b) as u64);
                (lo << 32 | hi, a < b)
            })
        })
        .collect();
    edges.par_sort_unstable();
    edges.len().is_multiple_of(2)
        && edges
            .chunks_exact(2)
            .all(|w| w[0].0 == w[1].0 && w[0].1 != w[1].1 && w[0].0 >> 32 != (w[0].0 & 0xffff_ffff))
}

/// The ground truth of every triangle of `meshes`, one soup.
pub fn scene_truth(meshes: &[MeshRef<'_>]) -> GroundTruth {
    let mut positions: Vec<[f32; 3]> = Vec::new();
    let mut triangles: Vec<[u32; 3]> = Vec::new();
    for m in meshes {
        let base = positions.len() as u32;
        positions.extend_from_slice(m.positions);
        triangles.extend(m.triangles.iter().map(|t| t.map(|i| base + i)));
    }
    GroundTruth::new(&positions, &triangles)
}

/// Corner `k` (bit 0: +x, bit 1: +y, bit 2: +z) of cell `c`.
fn corner(c: [u32; 3], k: u32) -> [u32; 3] {
    [c[0] + (k & 1), c[1] + (k >> 1 & 1), c[2] + (k >> 2 & 1)]
}

/// Collects the cells of the block at `origin`, `size` cells wide, through which the surface
/// may pass: all but those of sub-blocks wholly inside or wholly outside the band.
fn search(
    grid: &OffsetGrid,
    gt: &GroundTruth,
    origin: [u32; 3],
    size: u32,
    out: &mut Vec<[u32; 3]>,
) {
    if (0..3).any(|a| origin[a] >= grid.cells[a]) {
        return;
    }
    // The block's corners as the f32 points queries use; the centre's distance bounds every
    // point of the block within the largest distance from the centre to a corner.
    let far = [0, 1, 2].map(|a| (origin[a] + size).min(grid.cells[a]));
    let a = to_d(grid.vertex(origin));
    let b = to_d(grid.vertex(far));
    let centre32 = ((a + b) * 0.5).as_vec3().to_array();
    let c = to_d(centre32);
    let reach = (0..8)
        .map(|k| {
            let p = DVec3::new(
                if k & 1 == 0 { a.x } else { b.x },
                if k & 2 == 0 { a.y } else { b.y },
                if k & 4 == 0 { a.z } else { b.z },
            );
            (p - c).length()
        })
        .fold(0.0f64, f64::max)
        * (1.0 + 1e-9);
    let r = grid.radius;
    let d = gt.distance_capped(centre32, r + reach * 2.0 + grid.h);
    if d - r > reach || r - d > reach {
        return;
    }
    if size == 1 {
        out.push(origin);
        return;
    }
    let half = size / 2;
    let children: Vec<[u32; 3]> = (0..8u32)
        .map(|k| [0, 1, 2].map(|ax| origin[ax] + half * (k >> ax & 1)))
        .collect();
    if size > SERIAL_BLOCK {
        let parts: Vec<Vec<[u32; 3]>> = children
            .par_iter()
            .map(|&o| {
                let mut v = Vec::new();
                search(grid, gt, o, half, &mut v);
                v
            })
            .collect();
        for p in parts {
            out.extend(p);
        }
    } else {
        for o in children {
            search(grid, gt, o, half, out);
        }
    }
}

/// The six tetrahedra of the Kuhn triangulation of a cell (corner indices as in [`corner`]):
/// from corner 0 to corner 7 along the axes in each order.
const TETS: [[u32; 4]; 6] = [
    [0, 1, 3, 7],
    [0, 1, 5, 7],
    [0, 2, 3, 7],
    [0, 2, 6, 7],
    [0, 4, 5, 7],
    [0, 4, 6, 7],
];

/// The triangles of cell `c` on the zero set of `value` (the distance less the radius,
/// never zero), each facing the side where it grows. Which way a triangle faces is decided on
/// the grid's integer corners, exactly: the cut points move along their edges with the
/// values, and a triangle of cuts on three distinct edges keeps its orientation wherever they
/// are (it degenerates only where two cuts meet at a corner, which no value allows).
fn cell_triangles(
    grid: &OffsetGrid,
    c: [u32; 3],
    value: &dyn Fn([u32; 3]) -> f64,
    out: &mut Vec<[[f32; 3]; 3]>,
) {
    let vs: [[u32; 3]; 8] = core::array::from_fn(|k| corner(c, k as u32));
    let f: [f64; 8] = vs.map(value);
    let inside = |k: u32| f[k as usize] < 0.0;
    if (0..8).all(inside) || !(0..8).any(inside) {
        return;
    }
    let p: [DVec3; 8] = vs.map(|v| to_d(grid.vertex(v)));
    // The point where the value is zero on the edge between corners a and b (one on each
    // side), computed from the two corners in the order of their grid keys, so that both
    // cells sharing the edge find the same bits.
    let cut = |(a, b): (u32, u32)| -> [f32; 3] {
        let (a, b) = if OffsetGrid::key(vs[a as usize]) < OffsetGrid::key(vs[b as usize]) {
            (a, b)
        } else {
            (b, a)
        };
        let (fa, fb) = (f[a as usize], f[b as usize]);
        let t = fa / (fa - fb);
        (p[a as usize] + (p[b as usize] - p[a as usize]) * t)
            .as_vec3()
            .to_array()
    };
    // A corner's offset in the cell, in integers.
    let off = |k: u32| [(k & 1) as i64, (k >> 1 & 1) as i64, (k >> 2 & 1) as i64];
    let add = |a: [i64; 3], b: [i64; 3]| [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
    let sub = |a: [i64; 3], b: [i64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let scale = |a: [i64; 3], s: i64| a.map(|x| x * s);
    for tet in TETS {
        let (ins, outs): (Vec<u32>, Vec<u32>) = tet.iter().partition(|&&k| inside(k));
        if ins.is_empty() || outs.is_empty() {
            continue;
        }
        // From the inside corners' centroid towards the outside ones' (scaled to integers).
        let sum = |s: &[u32]| s.iter().fold([0i64; 3], |acc, &k| add(acc, off(k)));
        let grow = sub(
            scale(sum(&outs), ins.len() as i64),
            scale(sum(&ins), outs.len() as i64),
        );
        let mut emit = |e: [(u32, u32); 3]| {
            // The triangle of the edges' midpoints (doubled), which faces as the cuts do.
            let [a, b, c] = e.map(|(i, o)| add(off(i), off(o)));
            let (u, v) = (sub(b, a), sub(c, a));
            let n = [
                u[1] * v[2] - u[2] * v[1],
                u[2] * v[0] - u[0] * v[2],
                u[0] * v[1] - u[1] * v[0],
            ];
            let t = e.map(cut);
            if n[0] * grow[0] + n[1] * grow[1] + n[2] * grow[2] < 0 {
                out.push([t[0], t[2], t[1]]);
            } else {
                out.push(t);
            }
        };
        match (ins.len(), outs.len()) {
            (1, 3) => emit([(ins[0], outs[0]), (ins[0], outs[1]), (ins[0], outs[2])]),
            (3, 1) => emit([(ins[0], outs[0]), (ins[1], outs[0]), (ins[2], outs[0])]),
            _ => {
                // A quad: its corners in order around it.
                let q = [
                    (ins[0], outs[0]),
                    (ins[0], outs[1]),
                    (ins[1], outs[1]),
                    (ins[1], outs[0]),
                ];
                emit([q[0], q[1], q[2]]);
                emit([q[0], q[2], q[3]]);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes;

    fn open_edges(m: &OffsetMesh) -> usize {
        let mr = MeshRef {
            positions: &m.positions,
            triangles: &m.triangles,
        };
        let (_, open, _) = super::super::edge_classes(&mr);
        open.iter().map(|b| b.count_ones() as usize).sum()
    }

    #[test]
    fn the_offset_surface_of_a_cube_is_closed() {
        let cube = scenes::cube([0.0; 3], [1.0; 3]);
        let mr = MeshRef {
            positions: &cube.positions,
            triangles: &cube.triangles,
        };
        let m = offset_mesh(&[mr], 0.1, 5, &()).unwrap();
        assert!(!m.triangles.is_empty());
        assert_eq!(open_edges(&m), 0, "{} triangles", m.triangles.len());
    }
}

/// What [`OffsetSurface::place`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PlaceCounts {
    /// Particles that started inside the band (nearer the scene than the offset surface) and
    /// were moved out of it.
    pub moved: usize,
    /// Particles inside the band that could not be moved out (wedged where bands of several
    /// surfaces meet); left where they were, behind the offset surface.
    pub stuck: usize,
}

/// Points tried on the way out of the band at each step of [`OffsetSurface::place`].
const PLACE_TRIES: u32 = 16;

/// Rounds of moving away from the nearest surface point in [`OffsetSurface::place`].
const PLACE_ROUNDS: u32 = 16;

/// The offset surface of a scene for one radius and `dmax`, with what the host needs beside
/// its proxy: the scene's ground truth and the grid, to say which points are outside the band
/// and to move starting particles out of it. The mesh is what [`super::bake_offset`] bakes.
pub struct OffsetSurface {
    grid: OffsetGrid,
    truth: GroundTruth,
    mesh: OffsetMesh,
    /// The mesh's own ground truths, for cages, built when first asked ([`Self::cage`]).
    mesh_sides: std::sync::OnceLock<Sides>,
}

impl OffsetSurface {
    /// The offset surface at `radius` from the triangles of `meshes`, for a proxy baked at
    /// `dmax`. The meshes are checked as the bake checks them.
    pub fn new(
        meshes: &[MeshRef<'_>],
        radius: f32,
        dmax: u32,
        progress: &dyn BuildProgress,
    ) -> Result<Self, BuildError> {
        let mut check = super::BuildReport::default();
        super::gather(meshes, &mut check)?;
        let grid = OffsetGrid::new(meshes, radius, dmax)?;
        let truth = scene_truth(meshes);
        let mesh = extract(&grid, &truth, progress)?;
        Ok(OffsetSurface {
            grid,
            truth,
            mesh,
            mesh_sides: std::sync::OnceLock::new(),
        })
    }

    /// The radius.
    pub fn radius(&self) -> f32 {
        self.grid.radius as f32
    }

    /// The `dmax` it was built for.
    pub fn dmax(&self) -> u32 {
        self.grid.dmax
    }

    /// The surface as a mesh.
    pub fn mesh(&self) -> &OffsetMesh {
        &self.mesh
    }

    /// The surface as a mesh to bake or to take sides from.
    pub fn mesh_ref(&self) -> MeshRef<'_> {
        MeshRef {
            positions: &self.mesh.positions,
            triangles: &self.mesh.triangles,
        }
    }

    /// The scene's ground truth (its own triangles, not the offset surface).
    pub fn truth(&self) -> &GroundTruth {
        &self.truth
    }

    /// The margin [`Self::outside`] is asked for by the host: a thousandth of the grid
    /// spacing, far above the rounding of the surface's vertices.
    pub fn margin(&self) -> f64 {
        1e-3 * self.grid.h
    }

    /// Whether `p` is outside the band, in front of the offset surface, by the host's margin
    /// ([`OffsetGrid::outside`]).
    pub fn outside(&self, p: [f32; 3]) -> bool {
        self.grid.outside(&self.truth, p, self.margin())
    }

    /// The farthest from the scene the offset surface comes: `radius + h√3`. Every point at
    /// least this far from every triangle is outside the band.
    pub fn reach(&self) -> f64 {
        self.grid.radius + self.grid.h * 3f64.sqrt()
    }

    /// Moves every particle that starts inside the band out of it: away from its nearest
    /// point of the scene (along that triangle's normal, on the particle's side, if it lies
    /// on the surface), to the first of a few points between the radius and
    /// [`Self::reach`] that is outside, repeated while another surface is nearer than the
    /// radius there. With the proxy baked from this surface (`view`), a moved particle is
    /// not put strictly inside one of its solid leaves, where it would start caged: it goes
    /// on, up to two leaf diagonals farther. Velocities are kept. Particles that cannot be
    /// moved out are counted and left; non-finite ones are left alone.
    pub fn place(&self, particles: &mut [Particle], view: Option<&ProxyView<'_>>) -> PlaceCounts {
        let results: Vec<(bool, bool)> = particles
            .par_iter_mut()
            .with_min_len(256)
            .map(|p| {
                if !p.position.iter().all(|c| c.is_finite()) || self.outside(p.position) {
                    return (false, false);
                }
                match self.way_out(p.position, p.side_only(), view) {
                    Some(q) => {
                        p.position = q;
                        (true, false)
                    }
                    None => (false, true),
                }
            })
            .collect();
        PlaceCounts {
            moved: results.iter().filter(|r| r.0).count(),
            stuck: results.iter().filter(|r| r.1).count(),
        }
    }

    /// Gives every particle its starting side against this surface, as
    /// [`crate::Sides::assign`] on [`Self::mesh_ref`] would, without the offset surface's
    /// own ground truths (building them for its millions of triangles took 40 s for the
    /// tests' tray at `dmax` 8): front outside the band, behind in it (on the surface
    /// included). The band is the interpolation the surface was cut from
    /// ([`OffsetGrid::outside`] with no margin), so this is its exact side but for the
    /// rounding of the surface's vertices to `f32`. With `keep_given`, each particle keeps
    /// its own side and those that contradict the band are counted. After [`Self::place`]
    /// every particle it moved, and every one it did not need to, is in front.
    pub fn assign_sides(&self, particles: &mut [Particle], keep_given: bool) -> SideCounts {
        assign_each(particles, keep_given, |p, _| self.side(p))
    }

    /// The side of a particle at `p` against this surface ([`Self::assign_sides`]).
    pub fn side(&self, p: [f32; 3]) -> u32 {
        if self.grid.outside(&self.truth, p, 0.0) {
            octoproxy_core::SIDE_FRONT
        } else {
            octoproxy_core::SIDE_BACK
        }
    }

    /// The cage bits of a particle at `p` on `side` in `view`, the proxy baked from this
    /// surface: [`crate::Sides::cage`] on [`Self::mesh_ref`], whose ground truths are built
    /// the first time a particle is strictly inside a solid leaf, and kept.
    pub fn cage(&self, view: &ProxyView<'_>, p: [f32; 3], side: u32) -> u32 {
        if !in_solid_leaf(view, p) {
            return 0;
        }
        self.mesh_sides
            .get_or_init(|| Sides::new(&[self.mesh_ref()]))
            .cage(view, p, side)
    }

    /// Cages the particles that start strictly inside a solid leaf of `view`, the proxy
    /// baked from this surface, as [`crate::Sides::cages`] on [`Self::mesh_ref`] does; the
    /// rest lose any cage bits (with `keep_given`, a particle already caged keeps its cage).
    /// The offset surface's ground truths, which a cage's segments need, are built only when
    /// some particle is in a solid leaf ([`Self::place`] puts none there).
    pub fn cages(
        &self,
        view: &ProxyView<'_>,
        particles: &mut [Particle],
        keep_given: bool,
    ) -> CageCounts {
        cage_each(particles, keep_given, |p| {
            self.cage(view, p.position, p.side)
        })
    }

    /// A point outside the band reached from `p` by moving away from the nearest surface
    /// (and not strictly inside a solid leaf of `view`).
    fn way_out(&self, p: [f32; 3], side: u32, view: Option<&ProxyView<'_>>) -> Option<[f32; 3]> {
        let extra = view.map_or(0.0, |v| 2.0 * 3f64.sqrt() * v.finest_leaf_size() as f64);
        let good = |q: [f32; 3]| self.outside(q) && view.is_none_or(|v| !in_solid_leaf(v, q));
        let mut near = Vec::new();
        let mut x = p;
        for _ in 0..PLACE_ROUNDS {
            let d = self.truth.nearest_triangles(x, &mut near);
            let first = near.first()?;
            let dir = if d > 0.0 {
                (to_d(x) - first.closest) / d
            } else if side == octoproxy_core::SIDE_BACK {
                -first.normal
            } else {
                first.normal
            };
            if !dir.is_finite() {
                return None;
            }
            let (from, to) = (self.grid.radius.max(d), self.reach() * (1.0 + 1e-6) + extra);
            let mut last = None;
            for k in 1..=PLACE_TRIES {
                let t = from + (to - from) * k as f64 / PLACE_TRIES as f64;
                let q = (first.closest + dir * t).as_vec3().to_array();
                if good(q) {
                    return Some(q);
                }
                last = Some(q);
            }
            // Still inside: another surface is near there; go on from the farthest point.
            x = last?;
        }
        None
    }
}
