//! Point queries: which leaf holds a point, entered through the lookup table.
//!
//! A point that lies exactly on a cell plane belongs to the cell its direction of travel
//! enters: the upper cell when the direction's component is `>= 0`, the lower one otherwise.
//! Every plane coordinate comes from [`grid_plane`](crate::format::grid_plane), so the box a query returns and the
//! planes the next query compares against are the very same floats.

use glam::{UVec3, Vec3, Vec3A};

use crate::format::{Label, NodeRecord, LUT_DEPTH_SHIFT, LUT_INDEX_MASK, MAX_DEPTH};
use crate::view::ProxyView;

/// An axis-aligned box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Minimum corner.
    pub min: Vec3,
    /// Maximum corner.
    pub max: Vec3,
}

/// What a leaf holds. The discriminants are the codes WGSL's `LEAF_EMPTY` and `LEAF_SURFACE`
/// take (generated from these).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LeafKind {
    /// No triangle touches the leaf.
    Empty = 0,
    /// Triangles touch the leaf; it keeps one representative normal.
    Surface = 1,
}

/// A record index that names no record: the `node` of a leaf known only by its cell (a
/// hinted leaf), and a march's last collided leaf when there is none.
pub const NO_LEAF: u32 = u32::MAX;

/// The leaf that holds a point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LeafInfo {
    /// The leaf's box.
    pub aabb: Aabb,
    /// Empty or surface.
    pub kind: LeafKind,
    /// Surface leaves: the representative normal (zero for empty leaves).
    pub normal: Vec3,
    /// Surface leaves: whether the leaf is two-sided (solid from every side).
    pub two_sided: bool,
    /// Surface leaves: offset of the surface's mean plane from the leaf's centre along
    /// `normal` (see `NodeRecord::plane_offset`); 0 for empty leaves.
    pub plane_offset: f32,
    /// Empty leaves: the front/back label ([`Label::None`] for surface leaves).
    pub label: Label,
    /// Surface leaves: the index of the leaf's record. Empty leaves have no record: the
    /// index of their parent's record.
    pub node: u32,
    /// Depth of the leaf.
    pub depth: u32,
    /// Integer coordinates of the leaf among the `2^depth` cells per axis.
    pub cell: UVec3,
}

impl LeafInfo {
    /// A key that identifies the leaf: surface leaves by record, empty ones by parent and octant.
    pub fn key(&self) -> u32 {
        match self.kind {
            LeafKind::Surface => self.node,
            LeafKind::Empty => {
                let o = (self.cell.x & 1) | (self.cell.y & 1) << 1 | (self.cell.z & 1) << 2;
                0x8000_0000 | self.node << 3 | o
            }
        }
    }
}

/// Whether `p`, travelling along `dir`, is on the upper side of `plane` (ties as the module
/// says). Non-short-circuit `|` and `&`: which side a point is on is a coin toss for the
/// branch predictor, so the descent computes it instead of branching on it.
#[inline]
fn upper(p: f32, plane: f32, dir: f32) -> bool {
    (p > plane) | ((p == plane) & (dir >= 0.0))
}

impl ProxyView<'_> {
    /// The root cube.
    #[inline]
    pub fn root_aabb(&self) -> Aabb {
        self.root
    }

    /// The box of the cell `cell` at `depth`.
    #[inline]
    pub fn cell_aabb(&self, cell: UVec3, depth: u32) -> Aabb {
        let (min, max) = self.cell_box(cell, depth);
        Aabb {
            min: min.into(),
            max: max.into(),
        }
    }

    /// [`Self::cell_aabb`] as SIMD vectors, `(min, max)`: the planes `plane(a, cell[a] << s)`
    /// and `plane(a, (cell[a] + 1) << s)` with `s = MAX_DEPTH - depth`, the very same floats,
    /// in a few vector operations instead of a dozen scalar ones (the settled step computes
    /// one box per particle). A plane is `root_min + i * cell_unit` with an exact product
    /// ([`grid_plane`](crate::format::grid_plane)); here `i * cell_unit` is
    /// `cell * (cell_unit * 2^s)`, where scaling the normal `cell_unit` by a power of two is
    /// exact and the product is exact for the same reason, so the sum rounds the same.
    #[inline(always)]
    pub(crate) fn cell_box(&self, cell: UVec3, depth: u32) -> (Vec3A, Vec3A) {
        let size = Vec3A::splat(self.cell_unit() * (1u32 << (MAX_DEPTH - depth)) as f32);
        let c = Vec3A::new(cell.x as f32, cell.y as f32, cell.z as f32);
        let root_min = Vec3A::from(self.root.min);
        (root_min + c * size, root_min + (c + Vec3A::ONE) * size)
    }

    /// The box of every surface leaf (the shell's surface leaves), or `None` for a proxy
    /// with none. Walks every record once, depth first, with a fixed stack.
    pub fn surface_box(&self) -> Option<Aabb> {
        // (record, cell, depth): at most 8 pending children per level.
        let mut stack = [(0u32, UVec3::ZERO, 0u32); 8 * MAX_DEPTH as usize + 1];
        let mut top = 1usize;
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        while top > 0 {
            top -= 1;
            let (index, cell, depth) = stack[top];
            let rec = self.nodes()[index as usize];
            if rec.is_leaf() {
                let b = self.cell_aabb(cell, depth);
                lo = lo.min(b.min);
                hi = hi.max(b.max);
                continue;
            }
            for octant in 0..8 {
                if rec.child_mask() & (1 << octant) != 0 {
                    let child =
                        cell * 2 + UVec3::new(octant & 1, (octant >> 1) & 1, (octant >> 2) & 1);
                    stack[top] = (rec.child_index(octant), child, depth + 1);
                    top += 1;
                }
            }
        }
        (lo.cmple(hi).all()).then_some(Aabb { min: lo, max: hi })
    }

    /// Whether `p`, travelling along `dir`, is inside the root cube (ties as the module says).
    #[inline]
    pub fn root_contains(&self, p: Vec3, dir: Vec3) -> bool {
        let (lo, hi) = (self.root_aabb().min, self.root_aabb().max);
        (0..3).fold(true, |inside, a| {
            inside & upper(p[a], lo[a], dir[a]) & !upper(p[a], hi[a], dir[a])
        })
    }

    /// The leaf holding `p` (ties go to the upper cell), or `None` outside the root cube.
    pub fn locate_leaf(&self, p: Vec3) -> Option<LeafInfo> {
        self.locate_leaf_toward(p, Vec3::ZERO)
    }

    /// The leaf that a point at `p` travelling along `dir` is in: on a cell plane, the cell
    /// it enters. `None` outside the root cube or for a non-finite point.
    pub fn locate_leaf_toward(&self, p: Vec3, dir: Vec3) -> Option<LeafInfo> {
        if !p.is_finite() || !self.root_contains(p, dir) {
            return None;
        }
        Some(self.locate_inside(p, dir))
    }

    /// [`Self::locate_leaf_toward`] for a point `p` on the closed box of a leaf `from` that
    /// this proxy returned (a walker that moved from inside `from` to its boundary): the same
    /// answer, with `p`'s cell found from `from`'s in integers instead of estimated from `p`
    /// and settled on the planes. When `p` is not on `from`'s box, or that box is not the
    /// cell of this proxy's grid that `from.cell` and `from.depth` name, it is
    /// [`Self::locate_leaf_toward`] itself.
    pub fn locate_leaf_from(&self, from: &LeafInfo, p: Vec3, dir: Vec3) -> Option<LeafInfo> {
        let depth_ok = from.depth >= 1 && from.depth <= MAX_DEPTH;
        let on_box = depth_ok
            && (from.cell.x | from.cell.y | from.cell.z) >> from.depth == 0
            && from.aabb == self.cell_aabb(from.cell, from.depth)
            && p.is_finite()
            && from.aabb.min.cmple(p).all()
            && p.cmple(from.aabb.max).all();
        if on_box {
            self.locate_next(from, p, dir)
        } else {
            self.locate_leaf_toward(p, dir)
        }
    }

    /// [`Self::locate_leaf_toward`] for a point known to be inside the root cube.
    #[inline(always)]
    pub(crate) fn locate_inside(&self, p: Vec3, dir: Vec3) -> LeafInfo {
        if self.uses_lut() {
            let d = self.header().lut_depth;
            self.locate_in_cell(self.cell_at_depth(p, dir, d), d, p, dir)
        } else {
            self.descend(0, 0, UVec3::ZERO, (UVec3::ZERO, 0), p, dir)
        }
    }

    /// The leaf that `p`, travelling along `dir`, is in, for a point on the closed box of the
    /// leaf `from`: the exit point of the leaf a march just left, or the point where it
    /// collided in `from`. On each axis `p` is either strictly between `from`'s planes, in
    /// `from`'s cell, or on one of them, where the tie rule picks `from`'s cell or its
    /// neighbour by the sign of `dir`: the cell of `p` at `from`'s depth, found in integers,
    /// with no float estimate to settle. `None` when that cell is outside the root cube.
    #[inline(always)]
    pub(crate) fn locate_next(&self, from: &LeafInfo, p: Vec3, dir: Vec3) -> Option<LeafInfo> {
        let (lo, hi) = (from.aabb.min.to_array(), from.aabb.max.to_array());
        let (pa, da) = (p.to_array(), dir.to_array());
        let mut c = from.cell.to_array();
        for a in 0..3 {
            // `upper`'s tie rule, negated as written there (a NaN direction is not `>= 0`).
            let up = (pa[a] == hi[a]) & (da[a] >= 0.0);
            let down = (pa[a] == lo[a]) & !(da[a] >= 0.0);
            c[a] = c[a].wrapping_add(up as u32).wrapping_sub(down as u32);
        }
        // Below zero wraps to a huge value: one test for both sides of the root.
        if (c[0] | c[1] | c[2]) >> from.depth != 0 {
            return None;
        }
        Some(self.locate_in_cell(UVec3::from_array(c), from.depth, p, dir))
    }

    /// The leaf holding `p` (travelling along `dir`), given `p`'s cell at `depth`: entered
    /// through the lookup table when it is no deeper than `depth`, from the root otherwise.
    #[inline(always)]
    fn locate_in_cell(&self, cell: UVec3, depth: u32, p: Vec3, dir: Vec3) -> LeafInfo {
        let d = self.header().lut_depth;
        if self.uses_lut() && depth >= d {
            let c = cell >> (depth - d);
            let n = 1u32 << d;
            let entry = self.lut()[((c.z * n + c.y) * n + c.x) as usize];
            let (index, at) = (entry & LUT_INDEX_MASK, entry >> LUT_DEPTH_SHIFT);
            self.descend(index, at, cell >> (depth - at), (cell, depth), p, dir)
        } else {
            self.descend(0, 0, UVec3::ZERO, (cell, depth), p, dir)
        }
    }

    /// Descends from the record `index` of the cell `cell` at `depth` to the leaf holding `p`
    /// (travelling along `dir`). Down to the depth of `known`, `p`'s cell there, each octant is
    /// read from `known`'s bits; below it, from comparisons with the cell planes. The two
    /// agree: every plane is the same float wherever it is computed, and the tie rule puts a
    /// point on a plane on one side of it at every depth.
    #[inline(always)]
    fn descend(
        &self,
        mut index: u32,
        mut depth: u32,
        mut cell: UVec3,
        known: (UVec3, u32),
        p: Vec3,
        dir: Vec3,
    ) -> LeafInfo {
        let nodes = self.nodes();
        let (pa, da) = (p.to_array(), dir.to_array());
        let (known_cell, known_depth) = (known.0.to_array(), known.1);
        loop {
            let rec = nodes[index as usize];
            if rec.is_leaf() {
                return self.surface_leaf(cell, depth, index, rec);
            }
            if depth >= MAX_DEPTH {
                // A validated proxy has no internal node this deep; stay total anyway.
                return self.empty_leaf(cell, depth, index, Label::None);
            }
            let s = MAX_DEPTH - depth - 1;
            let mut octant = 0;
            let c = cell.to_array();
            if depth < known_depth {
                let k = known_depth - depth - 1;
                for (a, known) in known_cell.iter().enumerate() {
                    octant |= ((known >> k) & 1) << a;
                }
            } else {
                for a in 0..3 {
                    let mid = self.plane(a, (2 * c[a] + 1) << s);
                    if upper(pa[a], mid, da[a]) {
                        octant |= 1 << a;
                    }
                }
            }
            cell = cell * 2 + UVec3::new(octant & 1, (octant >> 1) & 1, (octant >> 2) & 1);
            depth += 1;
            if rec.child_mask() & (1 << octant) == 0 {
                let label = Label::from_bits(rec.label_bits(octant)).unwrap_or(Label::None);
                return self.empty_leaf(cell, depth, index, label);
            }
            index = rec.child_index(octant);
        }
    }

    /// The surface leaf `rec`, record `index`, of the cell `cell` at `depth`: what a descent
    /// that reaches it returns, and what a hint naming it ([`LeafHint`](crate::LeafHint))
    /// gives.
    #[inline(always)]
    pub(crate) fn surface_leaf(
        &self,
        cell: UVec3,
        depth: u32,
        index: u32,
        rec: NodeRecord,
    ) -> LeafInfo {
        LeafInfo {
            aabb: self.cell_aabb(cell, depth),
            kind: LeafKind::Surface,
            normal: rec.normal(),
            two_sided: rec.is_two_sided(),
            plane_offset: rec.plane_offset(),
            label: Label::None,
            node: index,
            depth,
            cell,
        }
    }

    #[inline]
    pub(crate) fn empty_leaf(
        &self,
        cell: UVec3,
        depth: u32,
        parent: u32,
        label: Label,
    ) -> LeafInfo {
        LeafInfo {
            aabb: self.cell_aabb(cell, depth),
            kind: LeafKind::Empty,
            normal: Vec3::ZERO,
            two_sided: false,
            plane_offset: 0.0,
            label,
            node: parent,
            depth,
            cell,
        }
    }

    /// Integer cell of `p` at `depth`, consistent with the plane comparisons of a descent.
    #[inline(always)]
    fn cell_at_depth(&self, p: Vec3, dir: Vec3, depth: u32) -> UVec3 {
        let n = 1u32 << depth;
        let s = MAX_DEPTH - depth;
        let root_min = self.header().root_min.to_array();
        let scale = n as f32 / self.header().root_size;
        // Arrays, not `Vec3` indexing: this is the hottest loop of a step.
        let (p, dir) = (p.to_array(), dir.to_array());
        let mut c = [0u32; 3];
        for a in 0..3 {
            // Truncation is the floor here: negative estimates clamp to 0 either way.
            let est = (p[a] - root_min[a]) * scale;
            let mut i = if est >= (n - 1) as f32 {
                n - 1
            } else if est > 0.0 {
                est as u32
            } else {
                0
            };
            // The estimate is off by at most one cell from rounding; settle it on the planes.
            for _ in 0..4 {
                if i > 0 && !upper(p[a], self.plane(a, i << s), dir[a]) {
                    i -= 1;
                } else if i + 1 < n && upper(p[a], self.plane(a, (i + 1) << s), dir[a]) {
                    i += 1;
                } else {
                    break;
                }
            }
            c[a] = i;
        }
        UVec3::from_array(c)
    }
}
