//! The game-engine way: a regular grid of `f32` signed distances over the mesh's bounding box
//! (grown by two cells each side), as fine as a memory budget allows, sampled trilinearly.
//!
//! Building: every sample within three cells of the surface takes its exact distance to the
//! mesh from the tests crate's [`GroundTruth`] (in parallel
//! with rayon); the samples beyond get a chamfer distance transform from those (up to about 10 %
//! long at most, and only far from the surface, where no collision looks). For a closed mesh
//! the sign is inside/outside: the exact winding number, taken once per group of samples that
//! no surface separates (see `signs`). For an open mesh the grid keeps the unsigned distance
//! minus half a cell, a shell one cell thick around the surface.
//!
//! Stepping, with no substeps: integrate as core does (`v += g dt`, `x += v dt`), sample the
//! distance at the end point; below zero, take the normalized gradient (central differences,
//! one cell each way) as the normal, push the particle out along it to distance zero and
//! respond with core's `respond`. Where the gradient vanishes (deep inside a thick part, or
//! on a ridge of the distance field) the particle goes back to where the step started and its
//! velocity is answered against its own direction. Only the end point is looked at, so a
//! particle that moves more than the shell's thickness in a step can pass through: that leak
//! is what this baseline is measured for. Outside the grid there is no collision.

use glam::Vec3;
use octoproxy_core::{respond, Particle, StepParams, FLAG_INVALID};
use rayon::prelude::*;

use super::Method;
use octoproxy_cpu::ground_truth::GroundTruth;

/// Cells of margin around the mesh's bounding box on every side.
const MARGIN_CELLS: f64 = 2.0;

/// Cells around the surface within which the grid's distances are exact.
const BAND_CELLS: f64 = 3.0;

/// Whether each sample is inside (closed meshes). Two samples next to each other, one of them
/// farther than a cell from the surface, are on the same side: the edge between them cannot
/// cross it. So the samples are grouped (union-find over such edges) and the exact
/// winding number is taken once per group.
fn signs(
    gt: &GroundTruth,
    dist: &[f64],
    n: [usize; 3],
    h: f64,
    point: &(impl Fn(usize) -> [f32; 3] + Sync),
) -> Vec<bool> {
    let total = dist.len();
    let mut parent: Vec<u32> = (0..total as u32).collect();
    fn find(parent: &mut [u32], mut i: u32) -> u32 {
        while parent[i as usize] != i {
            let up = parent[parent[i as usize] as usize];
            parent[i as usize] = up;
            i = up;
        }
        i
    }
    // A little more than a cell: the samples are rounded to `f32`.
    let far = h * 1.01;
    let strides = [1, n[0], n[0] * n[1]];
    for idx in 0..total {
        let ijk = [idx % n[0], (idx / n[0]) % n[1], idx / (n[0] * n[1])];
        for a in 0..3 {
            if ijk[a] + 1 < n[a] {
                let other = idx + strides[a];
                if dist[idx] > far || dist[other] > far {
                    let (ra, rb) = (
                        find(&mut parent, idx as u32),
                        find(&mut parent, other as u32),
                    );
                    if ra != rb {
                        parent[ra.max(rb) as usize] = ra.min(rb);
                    }
                }
            }
        }
    }
    let roots: Vec<u32> = (0..total as u32).map(|i| find(&mut parent, i)).collect();
    let mut reps: Vec<u32> = roots.clone();
    reps.sort_unstable();
    reps.dedup();
    let inside: Vec<bool> = reps
        .par_iter()
        .map(|&r| gt.is_inside(point(r as usize)))
        .collect();
    roots
        .iter()
        .map(|r| inside[reps.binary_search(r).unwrap_or(0)])
        .collect()
}

/// Fills the samples at `band` or beyond with a chamfer distance transform (weights 1, √2,
/// √3 over the 26 neighbours, two sweeps) from the samples nearer than `band`, whose distances
/// are exact; it overestimates the Euclidean distance, by up to about 10 %.
fn chamfer(dist: &mut [f64], n: [usize; 3], h: f64, band: f64) {
    for d in dist.iter_mut() {
        if *d >= band {
            *d = f64::INFINITY;
        }
    }
    let w = |di: isize, dj: isize, dk: isize| h * ((di * di + dj * dj + dk * dk) as f64).sqrt();
    // The 13 neighbours before a sample in scan order, and their weights.
    let mut before = Vec::new();
    for dk in -1isize..=0 {
        for dj in -1isize..=1 {
            for di in -1isize..=1 {
                if (dk, dj, di) < (0, 0, 0) {
                    before.push((di, dj, dk, w(di, dj, dk)));
                }
            }
        }
    }
    let (nx, ny, nz) = (n[0] as isize, n[1] as isize, n[2] as isize);
    let at = |i: isize, j: isize, k: isize| (i + nx * (j + ny * k)) as usize;
    for pass in 0..2 {
        let s: isize = if pass == 0 { 1 } else { -1 };
        for k0 in 0..nz {
            let k = if pass == 0 { k0 } else { nz - 1 - k0 };
            for j0 in 0..ny {
                let j = if pass == 0 { j0 } else { ny - 1 - j0 };
                for i0 in 0..nx {
                    let i = if pass == 0 { i0 } else { nx - 1 - i0 };
                    let mut best = dist[at(i, j, k)];
                    for &(di, dj, dk, wt) in &before {
                        let (a, b, c) = (i + s * di, j + s * dj, k + s * dk);
                        if a >= 0 && a < nx && b >= 0 && b < ny && c >= 0 && c < nz {
                            best = best.min(dist[at(a, b, c)] + wt);
                        }
                    }
                    dist[at(i, j, k)] = best;
                }
            }
        }
    }
    // A mesh with no triangles leaves everything infinite: call it far.
    for d in dist.iter_mut() {
        if !d.is_finite() {
            *d = 1e30;
        }
    }
}

/// A signed-distance grid.
pub struct SdfGrid {
    origin: Vec3,
    cell: f32,
    inv_cell: f32,
    dims: [u32; 3],
    data: Vec<f32>,
    closed: bool,
}

/// Samples along each axis for cell size `h` over extents `ext`.
fn dims_for(ext: [f64; 3], h: f64) -> [u64; 3] {
    ext.map(|e| {
        ((e / h).ceil().max(0.0) as u64)
            .saturating_add(2 * MARGIN_CELLS as u64 + 1)
            .max(2)
    })
}

fn count(d: [u64; 3]) -> u64 {
    d[0].saturating_mul(d[1]).saturating_mul(d[2])
}

impl SdfGrid {
    /// Builds the grid over `positions`/`triangles` with as many samples as fit in
    /// `memory_budget_bytes` (4 bytes each; at least 5 per axis, for the margins, whatever the
    /// budget). `closed` picks the sign: inside/outside for a closed mesh, a one-cell shell
    /// around the surface otherwise. Bad triangles (indices past the vertex list, non-finite
    /// vertices, zero area) are ignored.
    pub fn new(
        positions: &[[f32; 3]],
        triangles: &[[u32; 3]],
        memory_budget_bytes: usize,
        closed: bool,
    ) -> Self {
        let (triangles, _) = super::valid_triangles(positions, triangles);
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for t in &triangles {
            for &i in t {
                for k in 0..3 {
                    let c = f64::from(positions[i as usize][k]);
                    lo[k] = lo[k].min(c);
                    hi[k] = hi[k].max(c);
                }
            }
        }
        if triangles.is_empty() {
            lo = [0.0; 3];
            hi = [1.0; 3];
        }
        let ext = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
        let samples =
            ((memory_budget_bytes.saturating_sub(std::mem::size_of::<Self>())) / 4) as u64;
        // The smallest cell size whose grid fits: the count falls as the cell grows.
        let diag = (ext[0] * ext[0] + ext[1] * ext[1] + ext[2] * ext[2])
            .sqrt()
            .max(1e-30);
        let (mut small, mut big) = (diag * 1e-7, diag * 2.0);
        for _ in 0..200 {
            let mid = (small * big).sqrt();
            if count(dims_for(ext, mid)) <= samples {
                big = mid;
            } else {
                small = mid;
            }
            if big / small < 1.0 + 1e-12 {
                break;
            }
        }
        let h = big;
        let d = dims_for(ext, h);
        let dims = d.map(|n| n.min(u64::from(u32::MAX)) as u32);
        let origin = [
            lo[0] - MARGIN_CELLS * h,
            lo[1] - MARGIN_CELLS * h,
            lo[2] - MARGIN_CELLS * h,
        ];
        let gt = GroundTruth::new(positions, &triangles);
        let n = [dims[0] as usize, dims[1] as usize, dims[2] as usize];
        let total = n[0] * n[1] * n[2];
        let point = |idx: usize| {
            let (i, j, k) = (idx % n[0], (idx / n[0]) % n[1], idx / (n[0] * n[1]));
            [
                (origin[0] + i as f64 * h) as f32,
                (origin[1] + j as f64 * h) as f32,
                (origin[2] + k as f64 * h) as f32,
            ]
        };
        // Exact distances in a band of BAND_CELLS cells around the surface.
        let band = BAND_CELLS * h;
        let mut dist: Vec<f64> = (0..total)
            .into_par_iter()
            .map(|idx| gt.distance_capped(point(idx), band))
            .collect();
        let sign = if closed {
            Some(signs(&gt, &dist, n, h, &point))
        } else {
            None
        };
        // Beyond the band, a chamfer distance transform from it.
        chamfer(&mut dist, n, h, band);
        let half = h * 0.5;
        let data: Vec<f32> = match sign {
            Some(sign) => dist
                .iter()
                .zip(&sign)
                .map(|(&d, &inside)| if inside { -d as f32 } else { d as f32 })
                .collect(),
            None => dist.iter().map(|&d| (d - half) as f32).collect(),
        };
        SdfGrid {
            origin: Vec3::new(origin[0] as f32, origin[1] as f32, origin[2] as f32),
            cell: h as f32,
            inv_cell: (1.0 / h) as f32,
            dims,
            data,
            closed,
        }
    }

    /// Edge length of a cell.
    pub fn cell_size(&self) -> f32 {
        self.cell
    }

    /// Samples along each axis.
    pub fn dims(&self) -> [u32; 3] {
        self.dims
    }

    /// Whether the grid is signed inside/outside (else it is a shell around an open mesh).
    pub fn is_closed(&self) -> bool {
        self.closed
    }

    #[inline]
    fn at(&self, i: usize, j: usize, k: usize) -> f32 {
        let (nx, ny) = (self.dims[0] as usize, self.dims[1] as usize);
        self.data[i + nx * (j + ny * k)]
    }

    /// The trilinear distance at `x`; `None` outside the grid (or for a non-finite `x`).
    pub fn sample(&self, x: Vec3) -> Option<f32> {
        let f = (x - self.origin) * self.inv_cell;
        let mut idx = [0usize; 3];
        let mut t = [0f32; 3];
        for a in 0..3 {
            let n = self.dims[a] as f32 - 1.0;
            if !(f[a] >= 0.0 && f[a] <= n) {
                return None;
            }
            let i = (f[a].floor()).min(n - 1.0).max(0.0);
            idx[a] = i as usize;
            t[a] = f[a] - i;
        }
        let [i, j, k] = idx;
        let lerp = |a: f32, b: f32, s: f32| a + (b - a) * s;
        let c00 = lerp(self.at(i, j, k), self.at(i + 1, j, k), t[0]);
        let c10 = lerp(self.at(i, j + 1, k), self.at(i + 1, j + 1, k), t[0]);
        let c01 = lerp(self.at(i, j, k + 1), self.at(i + 1, j, k + 1), t[0]);
        let c11 = lerp(self.at(i, j + 1, k + 1), self.at(i + 1, j + 1, k + 1), t[0]);
        Some(lerp(lerp(c00, c10, t[1]), lerp(c01, c11, t[1]), t[2]))
    }

    /// The gradient at `x` by central differences one cell each way (a side that leaves the
    /// grid uses `x` itself).
    fn gradient(&self, x: Vec3, at_x: f32) -> Vec3 {
        let mut g = Vec3::ZERO;
        for a in 0..3 {
            let mut e = Vec3::ZERO;
            e[a] = self.cell;
            let (hi, dh) = self.sample(x + e).map_or((at_x, 0.0), |s| (s, self.cell));
            let (lo, dl) = self.sample(x - e).map_or((at_x, 0.0), |s| (s, self.cell));
            if dh + dl > 0.0 {
                g[a] = (hi - lo) / (dh + dl);
            }
        }
        g
    }
}

impl Method for SdfGrid {
    fn name(&self) -> &'static str {
        "sdf-grid"
    }

    /// The samples (4 bytes each) and the struct.
    fn memory_bytes(&self) -> usize {
        std::mem::size_of::<Self>() + self.data.len() * 4
    }

    fn step_traced(
        &self,
        p: &mut Particle,
        params: &StepParams,
        trace: &mut dyn FnMut(Vec3, Vec3),
    ) {
        let x0 = Vec3::from_array(p.position);
        let v0 = Vec3::from_array(p.velocity);
        if !x0.is_finite() || !v0.is_finite() {
            p.flags |= FLAG_INVALID;
            return;
        }
        let mut v = v0 + Vec3::from_array(params.gravity) * params.dt;
        let mut x = x0 + v * params.dt;
        trace(x0, x);
        let moved = x;
        let mut collisions = 0;
        if let Some(phi) = self.sample(x) {
            if phi < 0.0 {
                let g = self.gradient(x, phi);
                let len = g.length();
                if len > 1e-6 && len.is_finite() {
                    let n = g / len;
                    x -= n * phi;
                    v = respond(v, n, params.restitution, params.friction);
                } else {
                    x = x0;
                    let n = -v.normalize_or_zero();
                    v = respond(v, n, params.restitution, params.friction);
                }
                collisions = 1;
                trace(moved, x);
            }
        }
        super::finish(p, x, v, collisions, false);
    }
}
