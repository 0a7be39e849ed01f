//! Baking: triangles in memory → encoded proxy words.
//!
//! 1. **Gather** every mesh of the scene into one triangle soup, rejecting bad indices and
//!    non-finite coordinates, skipping (and counting) zero-area triangles, and marking the
//!    triangles of closed components (every edge shared by exactly two triangles, once in
//!    each direction).
//! 2. **Root cube**: the scene box, padded so that no surface leaf touches the root boundary
//!    (particles coming from outside always meet a labelled empty leaf first), its size
//!    rounded up to [`ROOT_SIZE_MANTISSA_BITS`] mantissa bits so that cell planes are exact.
//! 3. **Subdivide** with an exact triangle–box test until a node is empty, reaches `dmax`, or
//!    is deeper than `dmin` with normal variance below `epsilon` (equations (1)–(2) of the
//!    paper, divided by the node's total triangle area so that `epsilon` means the same for a
//!    mesh and its subdivision) and its triangles, clipped to it, no thicker across their mean
//!    normal than [`MAX_EARLY_LEAF_THICKNESS`] `dmax` leaves (a curved patch in a coarse leaf
//!    would let particles through it) and spanning the node (a patch that ends inside a
//!    coarse leaf leaves part of it on no definite side of the surface). A node touching the
//!    root boundary always subdivides, and so does a node holding a rim edge or triangles of
//!    more than one connected component (its leaf may be solid, so it is kept to `dmax`
//!    size). A leaf that stopped early next to a surface leaf of another component is
//!    refined to `dmax` in a further pass of [`bake`].
//! 4. **Normals**: the area-weighted normal of the triangles clipped to each surface leaf. If
//!    they cancel (coherence below [`TWO_SIDED_COHERENCE`]), or the leaf holds a rim (an edge
//!    of a hole, or a non-manifold edge), the leaf is two-sided: solid from every side.
//! 5. **Label** every empty leaf that touches a surface leaf (faces, edges and corners, any
//!    size) by the view-visible method: segments from points on the surface leaf's triangles
//!    to the shared boundary; the hit nearest the boundary votes front or back. Votes from
//!    closed components outrank votes from open ones; within a rank the majority wins and a
//!    tie goes to back. See the private `label` module.
//! 6. **Encode** breadth first, then fill the lookup table.

mod crowd;
mod encode;
mod flat;
pub mod geom;
mod label;
pub mod offset;

use std::collections::HashSet;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use crate::ground_truth::GroundTruth;
use glam::{DVec3, UVec3, Vec3};
use octoproxy_core::format::{header, quantize_root_size, ROOT_SIZE_MANTISSA_BITS};
use octoproxy_core::{ulp, MAX_DEPTH, MAX_LUT_DEPTH};
use rayon::prelude::*;

/// Below this ratio of |Σ a n| to Σ a, a surface leaf's triangles face opposite ways and the
/// leaf is two-sided (a knife edge sharper than about 35°, or both faces of a thin wall).
pub const TWO_SIDED_COHERENCE: f64 = 0.3;

/// A surface leaf stops before `dmax` only if its triangles, clipped to it, lie between two
/// planes across its mean normal at most this many `dmax`-leaf sizes apart. A leaf holds one
/// normal, and a particle that does not move against it passes through the leaf: across a
/// curved patch in a coarse leaf it would cross the real surface, as deep as the patch is
/// thick. Normal variance alone (`epsilon`) lets a leaf of any size hold a curved patch.
pub const MAX_EARLY_LEAF_THICKNESS: f64 = 0.5;

const PROGRESS_DEPTH: u32 = 3;

/// Nodes above this depth subdivide their children in parallel, however few triangles they
/// hold (below it, only nodes with many triangles do).
const PARALLEL_DEPTH: u32 = 3;

/// Surface leaves with at least this many triangles keep what a pass found about them for
/// the next (their normal, votes and crowding): below it, finding it again costs less than
/// keeping it.
pub(crate) const REUSE_TRIANGLES: usize = 8;

/// Most subdivide–label passes a bake makes (see [`bake`]).
const MAX_PASSES: u32 = 8;

/// Default cap on the number of tree nodes a bake may create.
pub const DEFAULT_MAX_NODES: u64 = 1 << 26;

/// Build parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BuildParams {
    /// Depth below which nodes always subdivide.
    pub dmin: u32,
    /// Maximum depth.
    pub dmax: u32,
    /// Normal-variance tolerance (area-normalised; see the module documentation).
    pub epsilon: f32,
    /// Depth of the lookup table (clamped to the tree depth; 0 for none).
    pub lut_depth: u32,
    /// Give up with [`BuildError::TooManyNodes`] past this many nodes.
    pub max_nodes: u64,
}

impl Default for BuildParams {
    fn default() -> Self {
        Self {
            dmin: 4,
            dmax: 8,
            epsilon: 0.01,
            lut_depth: 5,
            max_nodes: DEFAULT_MAX_NODES,
        }
    }
}

impl BuildParams {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), BuildError> {
        if self.dmax < 2 || self.dmax > MAX_DEPTH {
            return Err(BuildError::BadParam(format!(
                "dmax must be in 2..={MAX_DEPTH}, got {}",
                self.dmax
            )));
        }
        if self.dmin > self.dmax {
            return Err(BuildError::BadParam(format!(
                "dmin ({}) must not exceed dmax ({})",
                self.dmin, self.dmax
            )));
        }
        if !(self.epsilon >= 0.0) || !self.epsilon.is_finite() {
            return Err(BuildError::BadParam(format!(
                "epsilon must be a finite number >= 0, got {}",
                self.epsilon
            )));
        }
        if self.lut_depth > MAX_LUT_DEPTH {
            return Err(BuildError::BadParam(format!(
                "lut-depth must be in 0..={MAX_LUT_DEPTH}, got {}",
                self.lut_depth
            )));
        }
        Ok(())
    }
}

/// Why a bake failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BuildError {
    /// A parameter is out of range.
    #[error("{0}")]
    BadParam(String),
    /// A triangle refers to a vertex that does not exist.
    #[error("mesh {mesh}: triangle {triangle} uses vertex {index}, but the mesh has {vertices} vertices")]
    IndexOutOfRange {
        /// Which mesh of the scene.
        mesh: usize,
        /// Which triangle.
        triangle: usize,
        /// The bad index.
        index: u32,
        /// Number of vertices.
        vertices: usize,
    },
    /// A vertex coordinate is NaN or infinite.
    #[error("mesh {mesh}: vertex {vertex} has a NaN or infinite coordinate")]
    NonFinite {
        /// Which mesh of the scene.
        mesh: usize,
        /// Which vertex.
        vertex: usize,
    },
    /// No triangle with a positive area.
    #[error("the scene has no triangle with a positive area ({degenerate} degenerate triangles skipped)")]
    Empty {
        /// Triangles skipped for zero area.
        degenerate: usize,
    },
    /// No child of the root cube keeps any triangle: the exact overlap tests disagree at the
    /// scene's magnitudes (coordinates near the limits of `f32`).
    #[error("no triangle fits a cell of the octree (coordinates too extreme for exact overlap tests); scale the scene down")]
    Unsplittable,
    /// The scene is too large for `f32`: its root cube would reach beyond `f32::MAX`.
    #[error("the scene is too large for f32: its extent of {extent:.3e} needs a root cube beyond f32's range (about 3.4e38); scale it down")]
    TooLarge {
        /// Largest side of the scene's box.
        extent: f64,
    },
    /// The scene is too small for `f32` at `dmax`: its leaves would fall below the normal range.
    #[error("the scene is too small for f32 at dmax {dmax}: its extent of {extent:.3e} gives cells below f32's normal range; scale it up or lower dmax")]
    TooSmall {
        /// Largest side of the scene's box.
        extent: f64,
        /// dmax asked for.
        dmax: u32,
    },
    /// The scene is too far from the origin for its size: cells would collapse in `f32`.
    #[error("the scene is too small for its distance from the origin at dmax {dmax} (cells of {cell} at coordinates up to {magnitude}); move it nearer the origin or lower dmax")]
    Resolution {
        /// dmax asked for.
        dmax: u32,
        /// Leaf size at dmax.
        cell: f32,
        /// Largest coordinate magnitude.
        magnitude: f32,
    },
    /// The tree would be too large.
    #[error("the proxy would need more than {max_nodes} nodes; lower dmax or raise epsilon")]
    TooManyNodes {
        /// The cap.
        max_nodes: u64,
    },
}

/// Receives progress while baking (all methods may be called from several threads).
pub trait BuildProgress: Sync {
    /// A stage starts, with `total` units of work.
    fn begin(&self, _stage: &'static str, _total: u64) {}
    /// `n` more units of the current stage are done.
    fn advance(&self, _n: u64) {}
}

impl BuildProgress for () {}

/// What a bake produced, for reports.
#[derive(Clone, Debug, Default)]
pub struct BuildReport {
    /// Triangles given.
    pub triangles_in: usize,
    /// Zero-area triangles skipped.
    pub degenerate_skipped: usize,
    /// Triangles belonging to closed components.
    pub closed_triangles: usize,
    /// Node records.
    pub nodes: usize,
    /// Surface leaves.
    pub surface_leaves: usize,
    /// Of those, two-sided.
    pub two_sided_leaves: usize,
    /// Of those, larger than `dmax` leaves. The bake's last pass refines every surface leaf
    /// to `dmax` when the others leave such a leaf (see [`bake`]), so this is zero unless
    /// rounding at extreme magnitudes kept a node from splitting. A particle caged in one
    /// moves about in it farther than a `dmax` diagonal from the surface, so the guarantee
    /// does not cover particles that start inside one.
    pub coarse_solid_leaves: usize,
    /// Empty leaves given a label.
    pub labelled_leaves: usize,
    /// Labelled leaves whose votes disagreed.
    pub conflicting_labels: usize,
    /// Depth of the deepest leaf.
    pub tree_depth: u32,
    /// Subdivide–label passes made (more than one when conflicts forced refinement; the
    /// last of `MAX_PASSES + 1` refines every surface leaf to `dmax`).
    pub passes: u32,
    /// Lookup-table depth used.
    pub lut_depth: u32,
    /// Bytes of the node array.
    pub node_bytes: usize,
    /// Bytes of the lookup table.
    pub lut_bytes: usize,
    /// Bytes of the whole buffer.
    pub total_bytes: usize,
    /// Root cube minimum corner.
    pub root_min: [f32; 3],
    /// Root cube edge length.
    pub root_size: f32,
    /// The particle radius baked for (`0`: the mesh itself; see [`bake_with_radius`]).
    pub radius: f32,
    /// Triangles of the offset surface baked in the mesh's place (0 without a radius).
    pub offset_triangles: usize,
    /// The grid spacing that surface was extracted at (0 without a radius): every point of
    /// it is at least `radius - spacing * √3` from the mesh.
    pub offset_spacing: f64,
    /// Wall time per stage.
    pub timings: Vec<(&'static str, Duration)>,
}

/// One mesh of a scene, borrowed.
#[derive(Clone, Copy, Debug)]
pub struct MeshRef<'a> {
    /// Vertex positions.
    pub positions: &'a [[f32; 3]],
    /// Triangles as vertex indices.
    pub triangles: &'a [[u32; 3]],
}

/// A triangle of the scene, in f64.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Tri {
    /// Its vertices: the mesh's own `f32` positions, which every test reads in `f64`
    /// ([`Tri::v`], exact), stored at half the size (the bake reads them in every phase).
    pub p: [Vec3; 3],
    /// Unit normal.
    pub n: DVec3,
    pub area: f64,
    pub closed: bool,
    /// Its rim edges, bit `k` for the edge from `v[k]` to `v[(k + 1) % 3]`: edges not shared
    /// by exactly two triangles in opposite directions (the rim of a hole, a non-manifold
    /// edge, or one between triangles wound opposite ways).
    pub rim: u8,
    /// Connected component (triangles joined by shared edges), unique across the scene.
    pub component: u32,
    /// Its vertices, welded by position across the scene: equal ids are equal positions.
    pub vid: [u32; 3],
}

impl Tri {
    /// Its vertices in `f64`: the mesh's positions, exactly.
    #[inline(always)]
    pub fn v(&self) -> [DVec3; 3] {
        self.p.map(|p| p.as_dvec3())
    }

    /// Whether one of its rim edges touches the closed box `lo..hi` (or may: the test errs
    /// on the side of yes).
    pub fn rim_touches(&self, lo: DVec3, hi: DVec3) -> bool {
        if self.rim == 0 {
            return false;
        }
        let v = self.v();
        (0..3).any(|k| {
            self.rim & 1 << k != 0 && geom::segment_may_touch_box(v[k], v[(k + 1) % 3], lo, hi)
        })
    }
}

/// The grid: root cube and the exact `f32` planes every backend uses.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Grid {
    pub root_min: [f32; 3],
    pub root_size: f32,
    pub unit: f32,
}

impl Grid {
    /// Plane `i` of the finest grid along `axis`, as `f32` (same formula as core) in f64.
    pub fn plane(&self, axis: usize, i: u32) -> f64 {
        octoproxy_core::format::grid_plane(self.root_min[axis], self.unit, i) as f64
    }

    /// The point at finest-grid plane indices `i`.
    pub fn point(&self, i: UVec3) -> DVec3 {
        DVec3::new(self.plane(0, i.x), self.plane(1, i.y), self.plane(2, i.z))
    }

    /// The box of `cell` at `depth`.
    pub fn cell_box(&self, cell: UVec3, depth: u32) -> (DVec3, DVec3) {
        let s = MAX_DEPTH - depth;
        let lo = DVec3::new(
            self.plane(0, cell.x << s),
            self.plane(1, cell.y << s),
            self.plane(2, cell.z << s),
        );
        let hi = DVec3::new(
            self.plane(0, (cell.x + 1) << s),
            self.plane(1, (cell.y + 1) << s),
            self.plane(2, (cell.z + 1) << s),
        );
        (lo, hi)
    }
}

/// A node of the pointer tree, before encoding.
pub(crate) enum Node {
    Empty,
    Surface { tris: Vec<u32> },
    Internal { children: Box<[Node; 8]> },
}

impl Node {
    /// Internal nodes in the subtree: each made 8 nodes ([`BuildParams::max_nodes`]).
    fn internal_nodes(&self) -> u64 {
        match self {
            Node::Internal { children } => {
                1 + children.iter().map(Node::internal_nodes).sum::<u64>()
            }
            _ => 0,
        }
    }
}

/// Bakes the meshes of one scene into proxy words.
pub fn bake(
    meshes: &[MeshRef<'_>],
    params: &BuildParams,
    progress: &dyn BuildProgress,
) -> Result<(Vec<u32>, BuildReport), BuildError> {
    bake_in_passes(meshes, params, progress, MAX_PASSES)
}

/// Bakes the meshes of one scene for particles of `radius`: the proxy of the offset surface
/// at that distance from every triangle ([`offset`]), `radius` in its header. Centres of
/// particles that start outside the band (surely so at `radius` plus a `dmax` leaf diagonal
/// from every triangle; [`offset::OffsetSurface::place`] moves the others out) then never
/// come nearer than `radius` less a leaf diagonal (the guarantee of the march, for the offset
/// surface). The radius must exceed about a leaf diagonal. A `radius` of 0 is [`bake`].
pub fn bake_with_radius(
    meshes: &[MeshRef<'_>],
    params: &BuildParams,
    radius: f32,
    progress: &dyn BuildProgress,
) -> Result<(Vec<u32>, BuildReport), BuildError> {
    bake_keeping_surface(meshes, params, radius, progress).map(|(words, report, _)| (words, report))
}

/// [`bake_with_radius`], returning the offset surface too (none for a radius of 0).
pub(crate) fn bake_keeping_surface(
    meshes: &[MeshRef<'_>],
    params: &BuildParams,
    radius: f32,
    progress: &dyn BuildProgress,
) -> Result<(Vec<u32>, BuildReport, Option<offset::OffsetSurface>), BuildError> {
    params.validate()?;
    if !(radius >= 0.0) || !radius.is_finite() {
        return Err(BuildError::BadParam(format!(
            "radius must be a finite number >= 0, got {radius}"
        )));
    }
    if radius == 0.0 {
        return bake(meshes, params, progress).map(|(words, report)| (words, report, None));
    }
    let t = Instant::now();
    let surface = offset::OffsetSurface::new(meshes, radius, params.dmax, progress)?;
    let (words, mut report) = bake_offset(&surface, params, progress)?;
    report.timings.insert(0, ("offset", t.elapsed()));
    let mut check = BuildReport::default();
    gather(meshes, &mut check)?;
    report.triangles_in = check.triangles_in;
    report.degenerate_skipped = check.degenerate_skipped;
    Ok((words, report, Some(surface)))
}

/// Bakes an offset surface built for `params.dmax` ([`offset::OffsetSurface`]), its radius
/// in the header: what [`bake_with_radius`] does once it has the surface. A host that also
/// places starting particles ([`offset::OffsetSurface::place`]) builds the surface once.
pub fn bake_offset(
    surface: &offset::OffsetSurface,
    params: &BuildParams,
    progress: &dyn BuildProgress,
) -> Result<(Vec<u32>, BuildReport), BuildError> {
    params.validate()?;
    if surface.dmax() != params.dmax {
        return Err(BuildError::BadParam(format!(
            "the offset surface was built for dmax {}, the bake asks for dmax {}: build it for the bake's dmax",
            surface.dmax(),
            params.dmax
        )));
    }
    // One region's boundary: no empty leaf it sees from its front is inside it, so the
    // winding number of `matter_of` is not asked (see `Regions::OneBand`).
    let (mut words, mut report) = bake_regions(
        &[surface.mesh_ref()],
        params,
        progress,
        MAX_PASSES,
        true,
        Regions::OneBand,
    )?;
    let radius = surface.radius();
    words[header::RADIUS] = radius.to_bits();
    octoproxy_core::format::seal(&mut words);
    report.radius = radius;
    report.offset_triangles = surface.mesh().triangles.len();
    report.offset_spacing = surface.mesh().spacing;
    Ok((words, report))
}

/// [`bake`] with at most `max_passes` subdivide–label passes before the last one, which
/// refines every surface leaf to `dmax` (tests take fewer, to reach that pass).
pub(crate) fn bake_in_passes(
    meshes: &[MeshRef<'_>],
    params: &BuildParams,
    progress: &dyn BuildProgress,
    max_passes: u32,
) -> Result<(Vec<u32>, BuildReport), BuildError> {
    bake_reusing(meshes, params, progress, max_passes, true)
}

/// [`bake_in_passes`]; `reuse` false finds everything again in every pass (tests check that
/// reusing what the last pass found changes no byte).
pub(crate) fn bake_reusing(
    meshes: &[MeshRef<'_>],
    params: &BuildParams,
    progress: &dyn BuildProgress,
    max_passes: u32,
    reuse: bool,
) -> Result<(Vec<u32>, BuildReport), BuildError> {
    bake_regions(meshes, params, progress, max_passes, reuse, Regions::Parts)
}

/// What the closed surfaces of a bake bound, for the label's "in matter" rule.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Regions {
    /// Closed parts that may overlap: an empty leaf that one of them sees from its front may
    /// still lie inside another (a leaf in a plate beside a fin through it), which the
    /// winding number of all of them together decides (`matter_of`).
    Parts,
    /// The closed, embedded boundary of one region, its normals pointing out of it: the
    /// offset surface of a radius ([`offset`]: the band's outer skin and the skins of the
    /// hollows inside it, none crossing another). A vote sees the surface it hits first
    /// along a segment from the empty leaf, so an empty leaf seen from a front is outside
    /// the region (winding number 0): the rule can never apply, and its winding numbers,
    /// most of such a bake's time (50 of 80 s for a tray at `dmax` 8), are skipped. No
    /// triangle of it crosses another either (each lies in one tetrahedron of the grid it was
    /// cut from, where the distance is linear), so no leaf is tested for crossing itself:
    /// a sixth of such a bake's time (2.8 of 19 s for fandisk at radius 0.05).
    /// `an_offset_bake_skips_only_what_cannot_apply` bakes both ways and compares bytes.
    OneBand,
}

/// [`bake_reusing`] for surfaces bounding `regions`.
pub(crate) fn bake_regions(
    meshes: &[MeshRef<'_>],
    params: &BuildParams,
    progress: &dyn BuildProgress,
    max_passes: u32,
    reuse: bool,
    regions: Regions,
) -> Result<(Vec<u32>, BuildReport), BuildError> {
    params.validate()?;
    let mut report = BuildReport::default();
    let t = Instant::now();
    let tris = gather(meshes, &mut report)?;
    report.timings.push(("gather", t.elapsed()));

    let grid = root_grid(&tris, params.dmax)?;
    let matter = match regions {
        Regions::Parts => matter_of(&tris),
        Regions::OneBand => None,
    };
    let embedded = regions == Regions::OneBand;
    report.root_min = grid.root_min;
    report.root_size = grid.root_size;

    // Subdivide, flatten, label; if a leaf larger than dmax came out solid (two-sided: its
    // normals cancel, or its labels conflict), force its region down to dmax and go again
    // (solid leaves must be small: a particle inside one is then never farther than a dmax
    // diagonal from the surface). The same for a leaf larger than dmax that touches a surface
    // leaf holding another part of the scene (see `touches_other_parts`). A few passes settle
    // it. Where they do not (unions of thin parts at coarse `dmin` needed more than 4: found
    // by the penetration fuzz target, a particle caged in a solid leaf 8 `dmax` leaves wide
    // went 3 leaves deep into a part), one last pass refines every surface leaf to dmax: no
    // leaf is then solid and coarse (`coarse_solid_leaves` counts what rounding at extreme
    // magnitudes still leaves), at the cost of a larger proxy for that scene.
    let mut force = Forced::default();
    let t = Instant::now();
    let boxes: Vec<[f32; 6]> = tris
        .par_iter()
        .map(|t| crowd::outward_box(&t.v()))
        .collect();
    let mut crowding = crowd::Crowding::new(&tris);
    report.timings.push(("edges and boxes", t.elapsed()));
    // The last pass's tree: a node that overlaps no forced cell comes out the same again.
    let mut last_flat: Option<flat::Flat> = None;
    let mut votes = label::VoteCache::default();
    let mut pass = 0;
    let (tree, labels, crowded) = loop {
        pass += 1;
        let t = Instant::now();
        let all: Vec<u32> = (0..tris.len() as u32).collect();
        progress.begin("subdivide", 1 << (3 * PROGRESS_DEPTH));
        let ctx = Subdiv {
            tris: &tris,
            boxes: &boxes,
            grid,
            params: *params,
            force: &force,
            nodes: AtomicU64::new(1),
            over: AtomicBool::new(false),
            progress,
        };
        let root = ctx.build(all, UVec3::ZERO, 0, last_flat.as_ref().map(|f| (f, 0)));
        if ctx.over.load(Ordering::Relaxed) {
            return Err(BuildError::TooManyNodes {
                max_nodes: params.max_nodes,
            });
        }
        if !matches!(root, Node::Internal { .. }) {
            return Err(BuildError::Unsplittable);
        }
        report.timings.push(("subdivide", t.elapsed()));

        let t = Instant::now();
        let tree = flat::Flat::new(root, &tris, &grid, last_flat.as_ref());
        report.timings.push(("normals", t.elapsed()));

        let t = Instant::now();
        let labels = label::label(&tree, &tris, &grid, matter.as_ref(), &mut votes, progress);
        report.timings.push(("label", t.elapsed()));

        let t = Instant::now();
        let crowded = crowding.crowded(&tree, &tris, &boxes, &grid, params.dmax, embedded);
        report.timings.push(("crowded", t.elapsed()));

        let big: Vec<(u32, UVec3)> = tree
            .surface
            .par_iter()
            .filter_map(|&i| {
                let n = &tree.nodes[i as usize];
                let solid = labels.conflicted(i)
                    || crowded[i as usize]
                    || matches!(&n.kind, flat::Kind::Surface(s) if s.two_sided);
                (n.depth < params.dmax && (solid || touches_other_parts(&tree, i, &tris)))
                    .then_some((n.depth, n.cell))
            })
            .collect();
        if big.is_empty() || force.everything {
            report.passes = pass;
            break (tree, labels, crowded);
        }
        if reuse {
            last_flat = Some(tree);
        } else {
            crowding.forget();
            votes = label::VoteCache::default();
        }
        if pass >= max_passes {
            force.everything = true;
            continue;
        }
        for (depth, cell) in big {
            force.add(depth, cell);
        }
    };

    let t = Instant::now();
    let words = encode::encode(&tree, &labels, &crowded, &grid, params, &mut report);
    report.timings.push(("encode", t.elapsed()));
    Ok((words, report))
}

/// The closed parts of the scene taken together, for the winding number that says whether an
/// empty leaf is inside them (in matter: see `label`); `None` with fewer than two closed
/// parts, where a closed surface is seen from its front only outside it.
fn matter_of(tris: &[Tri]) -> Option<GroundTruth> {
    let mut closed: Vec<u32> = tris
        .iter()
        .filter(|t| t.closed)
        .map(|t| t.component)
        .collect();
    closed.sort_unstable();
    closed.dedup();
    if closed.len() < 2 {
        return None;
    }
    let positions: Vec<[f32; 3]> = tris
        .iter()
        .filter(|t| t.closed)
        .flat_map(|t| t.v().map(|p| p.as_vec3().to_array()))
        .collect();
    let triangles: Vec<[u32; 3]> = (0..positions.len() as u32 / 3)
        .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
        .collect();
    Some(GroundTruth::new(&positions, &triangles))
}

/// Whether surface leaf `leaf` touches a surface leaf that holds triangles of a connected
/// component other than its own. A particle inside a leaf larger than `dmax` may be far from
/// its surface, and takes the side of its plane; it keeps that side if it moves straight into
/// a neighbouring surface leaf. Across one surface (a closed component, or one sheet) that side
/// still holds, but not across another part: between two parallel sheets, or a sheet and a
/// solid, a particle behind the one is in front of the other, and would pass through it.
fn touches_other_parts(tree: &flat::Flat, leaf: u32, tris: &[Tri]) -> bool {
    let node = &tree.nodes[leaf as usize];
    let flat::Kind::Surface(surface) = &node.kind else {
        return false;
    };
    let Some(&first) = surface.tris.first() else {
        return false;
    };
    let component = tris[first as usize].component;
    let (lo, hi) = node.range();
    let mut other = false;
    tree.for_each_touching_surface(lo, hi, |n| {
        if let flat::Kind::Surface(s) = &tree.nodes[n as usize].kind {
            other |= s
                .tris
                .iter()
                .any(|&t| tris[t as usize].component != component);
        }
    });
    other
}

fn gather(meshes: &[MeshRef<'_>], report: &mut BuildReport) -> Result<Vec<Tri>, BuildError> {
    for (mi, m) in meshes.iter().enumerate() {
        if let Some(vertex) = m
            .positions
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite()))
        {
            return Err(BuildError::NonFinite { mesh: mi, vertex });
        }
        let vertices = m.positions.len();
        let bad = m
            .triangles
            .par_iter()
            .position_first(|t| t.iter().any(|&i| i as usize >= vertices));
        if let Some(triangle) = bad {
            let t = m.triangles[triangle];
            let index = t
                .into_iter()
                .find(|&i| i as usize >= vertices)
                .unwrap_or(t[0]);
            return Err(BuildError::IndexOutOfRange {
                mesh: mi,
                triangle,
                index,
                vertices,
            });
        }
    }
    let vids = weld(meshes);
    let mut tris = Vec::new();
    for (m, vid) in meshes.iter().zip(&vids) {
        let (closed, rim, component) = edge_classes_welded(m, vid);
        let base = report.triangles_in as u32;
        report.triangles_in += m.triangles.len();
        let normal = |t: &[u32; 3]| {
            let v = t.map(|i| {
                let p = m.positions[i as usize];
                DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
            });
            let c = (v[1] - v[0]).cross(v[2] - v[0]);
            let len = c.length();
            (v, c, len, len > 0.0 && len.is_finite())
        };
        let make = |(ti, t): (usize, &[u32; 3])| {
            let (_, c, len, _) = normal(t);
            Tri {
                p: t.map(|i| Vec3::from_array(m.positions[i as usize])),
                n: c / len,
                area: len * 0.5,
                closed: closed[ti],
                rim: rim[ti],
                component: base + component[ti],
                vid: t.map(|i| vid[i as usize]),
            }
        };
        let degenerate = m.triangles.par_iter().filter(|t| !normal(t).3).count();
        // Without degenerate triangles, each goes straight to its place in `tris`: no list
        // of pieces to join, no second copy (at 6.4M triangles, 0.56 GB).
        let before = tris.len();
        if degenerate == 0 {
            tris.par_extend(m.triangles.par_iter().enumerate().map(make));
        } else {
            let made: Vec<Tri> = m
                .triangles
                .par_iter()
                .enumerate()
                .filter(|(_, t)| normal(t).3)
                .map(make)
                .collect();
            tris.extend(made);
        }
        report.degenerate_skipped += degenerate;
        report.closed_triangles += tris[before..].par_iter().filter(|t| t.closed).count();
    }
    if tris.is_empty() {
        return Err(BuildError::Empty {
            degenerate: report.degenerate_skipped,
        });
    }
    Ok(tris)
}

/// Vertex ids by position across every mesh of a scene, per mesh and vertex: equal ids are
/// equal positions (`-0.0` and `0.0` are one), numbered in the order of the positions' bits.
fn weld(meshes: &[MeshRef<'_>]) -> Vec<Vec<u32>> {
    let key = |p: &[f32; 3]| p.map(|x| if x == 0.0 { 0 } else { x.to_bits() });
    let mut all: Vec<([u32; 3], u32, u32)> = meshes
        .iter()
        .enumerate()
        .flat_map(|(mi, m)| {
            m.positions
                .iter()
                .enumerate()
                .map(move |(vi, p)| (key(p), mi as u32, vi as u32))
        })
        .collect();
    all.par_sort_unstable();
    let mut ids: Vec<Vec<u32>> = meshes.iter().map(|m| vec![0; m.positions.len()]).collect();
    let mut id = 0u32;
    for (i, &(k, mi, vi)) in all.iter().enumerate() {
        if i > 0 && all[i - 1].0 != k {
            id += 1;
        }
        ids[mi as usize][vi as usize] = id;
    }
    ids
}

/// Classifies triangles by their edges: those of closed components (components joined by
/// shared edges in which every edge is used exactly once in each direction), and their rim
/// edges (not used exactly once in each direction; bit `k` for the edge from vertex `k`).
/// Vertices are welded by position first (as [`weld`] does: `-0.0` is `0.0`), so seams of
/// duplicated vertices do not open a mesh. Components are numbered by one of their triangles.
pub(crate) fn edge_classes(m: &MeshRef<'_>) -> (Vec<bool>, Vec<u8>, Vec<u32>) {
    let vid = weld(&[*m]).pop().unwrap_or_default();
    edge_classes_welded(m, &vid)
}

/// [`edge_classes`] of a mesh whose vertices are welded already: `vid[i] == vid[j]` when
/// vertices `i` and `j` are at the same position ([`weld`]'s ids for this mesh).
fn edge_classes_welded(m: &MeshRef<'_>, vid: &[u32]) -> (Vec<bool>, Vec<u8>, Vec<u32>) {
    let n = m.triangles.len();
    let valid = |t: &[u32; 3]| t.iter().all(|&i| (i as usize) < m.positions.len());
    let edges = DirectedEdge::sorted(n, |t| {
        let t = &m.triangles[t];
        valid(t).then(|| t.map(|i| vid[i as usize]))
    });
    let mut parent: Vec<u32> = (0..n as u32).collect();
    fn find(p: &mut [u32], mut x: u32) -> u32 {
        while p[x as usize] != x {
            p[x as usize] = p[p[x as usize] as usize];
            x = p[x as usize];
        }
        x
    }
    let mut open = vec![0u8; n];
    for group in edges.chunk_by(|a, b| a.key == b.key) {
        let good = group.len() == 2 && group[0].forward() != group[1].forward();
        if !good {
            for e in group {
                open[e.triangle() as usize] |= 1 << e.edge();
            }
        }
        for e in &group[1..] {
            let (a, b) = (
                find(&mut parent, group[0].triangle()),
                find(&mut parent, e.triangle()),
            );
            if a != b {
                parent[a as usize] = b;
            }
        }
    }
    let mut comp_open = vec![false; n];
    for (t, &is_open) in open.iter().enumerate() {
        if is_open != 0 || !valid(&m.triangles[t]) {
            let r = find(&mut parent, t as u32);
            comp_open[r as usize] = true;
        }
    }
    let component: Vec<u32> = (0..n).map(|t| find(&mut parent, t as u32)).collect();
    let closed = component.iter().map(|&c| !comp_open[c as usize]).collect();
    (closed, open, component)
}

/// A triangle's edge from its vertex `k` to vertex `k + 1`, by welded vertex ids, with the
/// edge's undirected key (the smaller id above the larger).
#[derive(Clone, Copy)]
pub(crate) struct DirectedEdge {
    pub key: u64,
    /// `triangle << 3 | k << 1 | forward` (forward: from the smaller id to the larger).
    code: u64,
}

impl DirectedEdge {
    /// Every edge of `n` triangles, sorted by key (in no order within a key), where `ids(t)`
    /// gives triangle `t`'s welded vertex ids, `None` for a triangle left out. Edges between
    /// two equal ids are left out: they join nothing.
    pub fn sorted(n: usize, ids: impl Fn(usize) -> Option<[u32; 3]> + Sync) -> Vec<Self> {
        // A real key has the smaller id first, so is below `u64::MAX`: left-out edges take
        // that key, sort last and are cut off. Each edge is made in its place (an indexed
        // map), with no list of pieces to join: at 6.4M triangles there are 19M.
        const OUT: DirectedEdge = DirectedEdge {
            key: u64::MAX,
            code: 0,
        };
        let mut edges: Vec<Self> = (0..3 * n)
            .into_par_iter()
            .map(|e| {
                let (t, k) = (e / 3, e % 3);
                let Some(v) = ids(t) else { return OUT };
                let (a, b) = (v[k], v[(k + 1) % 3]);
                if a == b {
                    return OUT;
                }
                let (lo, hi) = (a.min(b), a.max(b));
                DirectedEdge {
                    key: (lo as u64) << 32 | hi as u64,
                    code: (t as u64) << 3 | (k as u64) << 1 | (a < b) as u64,
                }
            })
            .collect();
        edges.par_sort_unstable_by_key(|e| e.key);
        edges.truncate(edges.partition_point(|e| e.key != u64::MAX));
        edges
    }

    pub fn triangle(&self) -> u32 {
        (self.code >> 3) as u32
    }

    /// `k`: the edge goes from the triangle's vertex `k` to vertex `k + 1`.
    pub fn edge(&self) -> u32 {
        (self.code >> 1) as u32 & 3
    }

    /// Whether it goes from the smaller id to the larger.
    pub fn forward(&self) -> bool {
        self.code & 1 != 0
    }
}

/// The root cube: the scene box grown so that every triangle stays more than one `dmax`
/// leaf from the boundary, with an exact size.
fn root_grid(tris: &[Tri], dmax: u32) -> Result<Grid, BuildError> {
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for t in tris {
        for v in t.v() {
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    let extent = (hi - lo).max_element();
    let center = (lo + hi) * 0.5;
    let leaves = (1u64 << dmax) as f64;
    // 2.5 leaves of slack in all: 1.25 on each side, before rounding.
    let mut size = quantize_root_size((extent / (1.0 - 2.5 / leaves)) as f32 * (1.0 + 1e-6));
    let too_large = |size: f32| {
        !size.is_finite() || (0..3).any(|a| center[a].abs() + size as f64 >= f32::MAX as f64)
    };
    for _ in 0..64 {
        if too_large(size) {
            return Err(BuildError::TooLarge { extent });
        }
        let root_min = [0, 1, 2].map(|a| (center[a] - size as f64 * 0.5) as f32);
        let grid = Grid {
            root_min,
            root_size: size,
            unit: size * (1.0 / (1u32 << MAX_DEPTH) as f32),
        };
        let n = 1u32 << MAX_DEPTH;
        let leaf = size as f64 / leaves;
        let fits =
            (0..3).all(|a| lo[a] - grid.plane(a, 0) > leaf && grid.plane(a, n) - hi[a] > leaf);
        if fits {
            let magnitude = (0..3)
                .map(|a| grid.plane(a, 0).abs().max(grid.plane(a, n).abs()))
                .fold(0.0, f64::max) as f32;
            let cell = (size as f64 / leaves) as f32;
            if !grid.unit.is_normal() {
                return Err(BuildError::TooSmall { extent, dmax });
            }
            if !(cell >= 4.0 * ulp(magnitude)) {
                return Err(BuildError::Resolution {
                    dmax,
                    cell,
                    magnitude,
                });
            }
            return Ok(grid);
        }
        // Rounding ate the slack: the next representable size up.
        size = quantize_root_size(f32::from_bits(
            size.to_bits() + (1 << (23 - (ROOT_SIZE_MANTISSA_BITS - 1))),
        ));
    }
    Err(BuildError::Resolution {
        dmax,
        cell: size / leaves as f32,
        magnitude: extent as f32,
    })
}

/// Cells of the octree whose region must be subdivided to `dmax`. Two cells are nested or
/// disjoint, so a node overlaps a forced cell when it lies inside one (it or an ancestor is
/// forced) or holds one (it is an ancestor of a forced cell): a few hash lookups per node,
/// however many cells are forced (a linear scan over them made a bake of 160 triangles in
/// stacked sheets take 7 s).
pub(crate) struct Forced {
    /// The forced cells, as `(depth, cell)`.
    cells: HashSet<(u32, [u32; 3])>,
    /// Their strict ancestors.
    holders: HashSet<(u32, [u32; 3])>,
    /// The depth of the shallowest forced cell (`u32::MAX` when none).
    shallowest: u32,
    /// Every cell is forced: the bake's last pass.
    everything: bool,
}

impl Default for Forced {
    fn default() -> Self {
        Forced {
            cells: HashSet::new(),
            holders: HashSet::new(),
            shallowest: u32::MAX,
            everything: false,
        }
    }
}

impl Forced {
    pub(crate) fn add(&mut self, depth: u32, cell: UVec3) {
        self.shallowest = self.shallowest.min(depth);
        self.cells.insert((depth, cell.to_array()));
        for d in 0..depth {
            self.holders.insert((d, (cell >> (depth - d)).to_array()));
        }
    }

    /// Whether the cell `cell` at `depth` overlaps a forced cell.
    pub(crate) fn overlaps(&self, depth: u32, cell: UVec3) -> bool {
        self.everything
            || self.holders.contains(&(depth, cell.to_array()))
            || (self.shallowest..=depth)
                .any(|d| self.cells.contains(&(d, (cell >> (depth - d)).to_array())))
    }
}

struct Subdiv<'a> {
    tris: &'a [Tri],
    /// Each triangle's [`crowd::outward_box`].
    boxes: &'a [[f32; 6]],
    grid: Grid,
    params: BuildParams,
    /// Regions that must be subdivided to `dmax`.
    force: &'a Forced,
    nodes: AtomicU64,
    over: AtomicBool,
    progress: &'a dyn BuildProgress,
}

impl Subdiv<'_> {
    /// Builds the subtree of `cell` at `depth` from the triangles that overlap it.
    /// The node of `cell` at `depth` holding `list` (the triangles that meet it), given the
    /// last pass's node there, if any: a node that overlaps no forced cell is that node again
    /// (the last pass forced no more, and everything else that decides a node is the same).
    fn build(
        &self,
        list: Vec<u32>,
        cell: UVec3,
        depth: u32,
        last: Option<(&flat::Flat, u32)>,
    ) -> Node {
        if let Some((tree, id)) = last.filter(|_| !self.force.overlaps(depth, cell)) {
            let node = tree.node(id);
            // The nodes it made last time, counted as making them again counts them.
            let made = 8 * node.internal_nodes();
            if self.nodes.fetch_add(made, Ordering::Relaxed) + made > self.params.max_nodes {
                self.over.store(true, Ordering::Relaxed);
            }
            if depth <= PROGRESS_DEPTH {
                self.progress.advance(1 << (3 * (PROGRESS_DEPTH - depth)));
            }
            return node;
        }
        let node = self.build_inner(list, cell, depth, last);
        // Progress in units of depth-3 cells: 512 in all.
        if depth == PROGRESS_DEPTH
            || (depth < PROGRESS_DEPTH && !matches!(node, Node::Internal { .. }))
        {
            self.progress.advance(1 << (3 * (PROGRESS_DEPTH - depth)));
        }
        node
    }

    fn build_inner(
        &self,
        list: Vec<u32>,
        cell: UVec3,
        depth: u32,
        last: Option<(&flat::Flat, u32)>,
    ) -> Node {
        if list.is_empty() {
            return Node::Empty;
        }
        if self.over.load(Ordering::Relaxed) {
            return Node::Surface { tris: list };
        }
        let n = 1u32 << depth;
        let on_boundary = cell.min_element() == 0 || cell.max_element() == n - 1;
        // Leaves that may become solid (two-sided) must stay small, so no early stop for a
        // rim, nor where parts meet (their votes may conflict). Tested only where a node may
        // stop early: a rim edge costs a segment–box test.
        let rim_or_parts = || {
            let first = self.tris[list[0] as usize].component;
            let (lo, hi) = self.grid.cell_box(cell, depth);
            list.iter().any(|&t| {
                self.tris[t as usize].component != first
                    || self.tris[t as usize].rim_touches(lo, hi)
            })
        };
        let stop = depth >= self.params.dmax
            || (depth > self.params.dmin
                && !on_boundary
                && !self.force.overlaps(depth, cell)
                && !rim_or_parts()
                && self.variance(&list) < self.params.epsilon as f64
                && self.thickness(&list, cell, depth) <= self.flat_tolerance());
        if stop {
            return Node::Surface { tris: list };
        }
        if self.nodes.fetch_add(8, Ordering::Relaxed) + 8 > self.params.max_nodes {
            self.over.store(true, Ordering::Relaxed);
            return Node::Surface { tris: list };
        }
        let subs = self.split(&list, cell, depth);
        if subs.iter().all(Vec::is_empty) {
            // The parent's exact test kept triangles that no child's test keeps (rounding at
            // extreme magnitudes): the node stays a surface leaf rather than an internal node
            // with no children, which no valid proxy has, and gives back the 8 nodes it
            // counted (a reused subtree counts its internal nodes alone).
            self.nodes.fetch_sub(8, Ordering::Relaxed);
            return Node::Surface { tris: list };
        }
        drop(list);
        let last_children = last.and_then(|(tree, id)| tree.children(id).map(|c| (tree, c)));
        let child = |(o, sub): (u32, Vec<u32>)| -> Node {
            let c = cell * 2 + UVec3::new(o & 1, (o >> 1) & 1, (o >> 2) & 1);
            let last = last_children.map(|(tree, ids)| (tree, ids[o as usize]));
            self.build(sub, c, depth + 1, last)
        };
        // In parallel where there is much to do: many triangles, or (however few) the top of
        // the tree, where a few large triangles may still make a deep subtree in every child.
        let large = depth < PARALLEL_DEPTH || subs.iter().map(Vec::len).sum::<usize>() > 1024;
        let subs = (0u32..).zip(subs);
        let children: Vec<Node> = if large {
            subs.collect::<Vec<_>>()
                .into_par_iter()
                .map(child)
                .collect()
        } else {
            subs.map(child).collect()
        };
        let mut it = children.into_iter();
        Node::Internal {
            children: Box::new(std::array::from_fn(|_| it.next().unwrap_or(Node::Empty))),
        }
    }

    /// The triangles of `list` that overlap each child of `cell`, in `list` order. A
    /// triangle whose bounding box lies strictly on one side of every mid-plane overlaps
    /// exactly one child (it overlaps the parent, and the child is the parent's part on that
    /// side), so only triangles that straddle a mid-plane pay for the exact test, and only
    /// against the children their box touches.
    fn split(&self, list: &[u32], cell: UVec3, depth: u32) -> [Vec<u32>; 8] {
        let (mid, _) = self.grid.cell_box(cell * 2 + UVec3::ONE, depth + 1);
        let boxes: [(DVec3, DVec3); 8] = std::array::from_fn(|o| {
            let o = o as u32;
            self.grid.cell_box(
                cell * 2 + UVec3::new(o & 1, (o >> 1) & 1, (o >> 2) & 1),
                depth + 1,
            )
        });
        let mut subs: [Vec<u32>; 8] = Default::default();
        for &t in list {
            // Per axis: bit 0 = may touch the lower half, bit 1 = the upper half. First from
            // the box in `f32`, rounded outward: where it lies strictly on one side of a
            // mid-plane, the exact box does too. Most triangles of a fine mesh lie so on
            // every axis, and the triangle itself is not read.
            let b = &self.boxes[t as usize];
            let mut sides = [0u32; 3];
            for a in 0..3 {
                if (b[a + 3] as f64) < mid[a] {
                    sides[a] = 1;
                } else if (b[a] as f64) > mid[a] {
                    sides[a] = 2;
                }
            }
            let v = self.tris[t as usize].v();
            if sides.contains(&0) {
                let lo = v[0].min(v[1]).min(v[2]);
                let hi = v[0].max(v[1]).max(v[2]);
                sides =
                    [0, 1, 2].map(|a| (lo[a] <= mid[a]) as u32 | ((hi[a] >= mid[a]) as u32) << 1);
            }
            let straddles = sides.contains(&3);
            for o in 0..8u32 {
                let fits = (0..3).all(|a| sides[a] & (1 << ((o >> a) & 1)) != 0);
                if fits
                    && (!straddles
                        || geom::triangle_overlaps_box(
                            &v,
                            boxes[o as usize].0,
                            boxes[o as usize].1,
                        ))
                {
                    subs[o as usize].push(t);
                }
            }
        }
        subs
    }

    /// Largest thickness a surface leaf shallower than `dmax` may have (see
    /// [`MAX_EARLY_LEAF_THICKNESS`]).
    fn flat_tolerance(&self) -> f64 {
        MAX_EARLY_LEAF_THICKNESS * self.grid.root_size as f64 / (1u64 << self.params.dmax) as f64
    }

    /// How thick the triangles of `list` are inside the cell: clipped to its box, the distance
    /// between the two planes across their area-weighted mean normal that hold them (the
    /// normal the leaf would keep). Infinite when nothing of them is left inside, or when they
    /// do not span the cell: their area, projected on the mean plane, falls short of the
    /// cell's section by that plane by more than a strip of the flat tolerance along the
    /// section's rim. A patch that ends inside a coarse leaf (one that leaves it through a
    /// face it nearly lies in) leaves part of the leaf on no definite side of it: there the
    /// leaf's plane extends past the surface, and a particle that starts or turns there may
    /// take the wrong side and cross the surface in the next leaf.
    fn thickness(&self, list: &[u32], cell: UVec3, depth: u32) -> f64 {
        let (lo, hi) = self.grid.cell_box(cell, depth);
        let mut sum = DVec3::ZERO;
        let polys: Vec<(geom::Poly, f64)> = list
            .iter()
            .map(|&t| {
                let t = &self.tris[t as usize];
                let poly = geom::clip_triangle(&t.v(), lo, hi);
                let area = poly.area_centroid().0;
                sum += t.n * area;
                (poly, area)
            })
            .collect();
        let len = sum.length();
        if !(len > 0.0) {
            return f64::INFINITY;
        }
        let n = sum / len;
        let (low, high) = polys
            .iter()
            .flat_map(|(p, _)| p.points())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), q| {
                (lo.min(n.dot(*q)), hi.max(n.dot(*q)))
            });
        if !(low <= high) {
            return f64::INFINITY;
        }
        // The patch must span the cell: every point of the section within a `dmax` leaf of
        // it, sampled every half leaf. (An area test let a knife thinner than a leaf end
        // inside a coarse leaf: beyond its end, the section's uncovered quarter was a strip two
        // leaves wide, where a particle behind the plane was outside the knife, and went 2.3
        // leaves from it; found by the penetration fuzz target.)
        let tol = self.flat_tolerance();
        let clipped: Vec<&geom::Poly> = polys.iter().map(|(p, _)| p).collect();
        if !geom::patch_covers_section(&clipped, n, 0.5 * (low + high), lo, hi, tol, 2.0 * tol) {
            return f64::INFINITY;
        }
        high - low
    }

    /// Equations (1)–(2), divided by the total area: Σ aᵢ‖nᵢ − n̄‖² / Σ aᵢ with n̄ the
    /// normalised area-weighted mean. 0 for a flat patch, up to 4 for opposite faces.
    fn variance(&self, list: &[u32]) -> f64 {
        let mut sum = DVec3::ZERO;
        let mut area = 0.0;
        for &t in list {
            let t = &self.tris[t as usize];
            sum += t.n * t.area;
            area += t.area;
        }
        let len = sum.length();
        if !(len > 0.0) || !(area > 0.0) {
            return f64::INFINITY;
        }
        let avg = sum / len;
        list.iter()
            .map(|&t| {
                let t = &self.tris[t as usize];
                t.area * (t.n - avg).length_squared()
            })
            .sum::<f64>()
            / area
    }
}

#[cfg(test)]
mod tests;
