//! The paper's own baseline (its figure 7): a general octree whose leaves keep the indices of
//! the triangles that overlap them, stepped with exact segment–triangle tests.
//!
//! Building: the root is the mesh's bounding cube (slightly grown); a node is split into eight
//! while it overlaps more than `max_leaf_triangles` triangles and is shallower than
//! `max_depth`. Overlap is the exact separating-axis test of `octoproxy_cpu::bake::geom`
//! against the node's box grown by a hair, so a triangle touching a face is in both nodes.
//!
//! Stepping: the segment `x → x + v t` is walked through the tree front to back (children
//! sorted by where the segment enters them, nodes beyond the nearest hit so far skipped), every
//! triangle of the leaves it passes is tested with Möller–Trumbore in `f64`, and the nearest hit
//! is answered as `step_by_casting` in the parent module says.

use glam::{DVec3, Vec3};
use octoproxy_core::{Particle, StepParams};
use octoproxy_cpu::bake::geom::{self, triangle_overlaps_box};
use rayon::prelude::*;

use super::{Hit, Method};

/// Deepest tree this baseline builds, whatever is asked (bounds the traversal recursion).
pub const MAX_DEPTH: u32 = 16;

/// Nodes with more triangles than this build their children in parallel.
const PARALLEL_MIN: usize = 2048;

/// One node: eight children at `first_child..first_child + 8`, or a leaf (`first_child` 0)
/// with triangles `indices[start..start + count]`.
#[derive(Clone, Copy, Debug)]
struct Node {
    first_child: u32,
    start: u32,
    count: u32,
}

/// A node while building.
enum Tmp {
    Leaf(Vec<u32>),
    Inner(Box<[Tmp; 8]>),
}

/// A triangle-list octree with exact segment tests.
pub struct TriangleOctree {
    /// The kept triangles' corners, in input order (the leaves index it).
    tris: Vec<[[f32; 3]; 3]>,
    nodes: Vec<Node>,
    indices: Vec<u32>,
    root_min: DVec3,
    root_size: f64,
    standoff: f64,
    depth: u32,
    dropped: usize,
}

#[inline]
fn corners(t: &[[f32; 3]; 3]) -> [DVec3; 3] {
    t.map(|p| DVec3::from_array(p.map(f64::from)))
}

fn tri_of(positions: &[[f32; 3]], t: [u32; 3]) -> [DVec3; 3] {
    t.map(|i| DVec3::from_array(positions[i as usize].map(f64::from)))
}

/// Entry and exit parameters of the segment `a + t d` (`t` in `[0, limit]`) through the
/// closed box `[lo, hi]`, or `None` when it misses.
#[inline]
fn segment_box(a: DVec3, d: DVec3, inv: DVec3, lo: DVec3, hi: DVec3, limit: f64) -> Option<f64> {
    let mut near = 0.0f64;
    let mut far = limit;
    for k in 0..3 {
        if d[k] == 0.0 {
            if a[k] < lo[k] || a[k] > hi[k] {
                return None;
            }
        } else {
            let t1 = (lo[k] - a[k]) * inv[k];
            let t2 = (hi[k] - a[k]) * inv[k];
            let (t1, t2) = if t1 <= t2 { (t1, t2) } else { (t2, t1) };
            near = near.max(t1);
            far = far.min(t2);
            if near > far {
                return None;
            }
        }
    }
    Some(near)
}

impl TriangleOctree {
    /// Builds the tree. Triangles with an index past `positions`, a non-finite vertex or zero
    /// area are left out ([`TriangleOctree::dropped_triangles`]); `max_depth` is capped at
    /// [`MAX_DEPTH`] and `max_leaf_triangles` raised to 1.
    pub fn new(
        positions: &[[f32; 3]],
        triangles: &[[u32; 3]],
        max_depth: u32,
        max_leaf_triangles: usize,
    ) -> Self {
        let (triangles, dropped) = super::valid_triangles(positions, triangles);
        let standoff = super::standoff(positions, &triangles);
        let max_depth = max_depth.min(MAX_DEPTH);
        let max_leaf = max_leaf_triangles.max(1);
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for t in &triangles {
            for v in tri_of(positions, *t) {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
        if triangles.is_empty() {
            lo = DVec3::ZERO;
            hi = DVec3::ONE;
        }
        let size = (hi - lo).max_element().max(f64::MIN_POSITIVE) * (1.0 + 1e-6);
        let center = (lo + hi) * 0.5;
        let root_min = center - DVec3::splat(size * 0.5);
        let all: Vec<u32> = (0..triangles.len() as u32).collect();
        let builder = Builder {
            positions,
            triangles: &triangles,
            max_depth,
            max_leaf,
            pad: size * 1e-9,
        };
        let tmp = builder.build(all, root_min, size, 0);
        // Flatten breadth first, each node's eight children together.
        let mut nodes = vec![Node {
            first_child: 0,
            start: 0,
            count: 0,
        }];
        let mut indices = Vec::new();
        let mut queue = std::collections::VecDeque::from([(0usize, tmp)]);
        let mut depth_of = vec![0u32];
        let mut depth = 0;
        while let Some((at, t)) = queue.pop_front() {
            match t {
                Tmp::Leaf(list) => {
                    nodes[at] = Node {
                        first_child: 0,
                        start: indices.len() as u32,
                        count: list.len() as u32,
                    };
                    indices.extend_from_slice(&list);
                }
                Tmp::Inner(children) => {
                    let first = nodes.len();
                    nodes[at].first_child = first as u32;
                    let d = depth_of[at] + 1;
                    depth = depth.max(d);
                    for (k, c) in (*children).into_iter().enumerate() {
                        nodes.push(Node {
                            first_child: 0,
                            start: 0,
                            count: 0,
                        });
                        depth_of.push(d);
                        queue.push_back((first + k, c));
                    }
                }
            }
        }
        indices.shrink_to_fit();
        TriangleOctree {
            tris: triangles
                .iter()
                .map(|t| t.map(|i| positions[i as usize]))
                .collect(),
            nodes,
            indices,
            root_min,
            root_size: size,
            standoff,
            depth,
            dropped,
        }
    }

    /// Nodes in the tree.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Depth of the deepest leaf (the root is 0).
    pub fn depth(&self) -> u32 {
        self.depth
    }

    /// Triangles left out when building (bad indices, non-finite vertices, zero area).
    pub fn dropped_triangles(&self) -> usize {
        self.dropped
    }

    /// The nearest hit of the segment `a → a + d`: its parameter in `[0, 1]` and the
    /// triangle's geometric normal.
    pub(crate) fn cast(&self, a: DVec3, d: DVec3) -> Hit {
        let seg = Segment {
            a,
            d,
            inv: d.recip(),
        };
        let root_max = self.root_min + DVec3::splat(self.root_size);
        segment_box(a, d, seg.inv, self.root_min, root_max, 1.0)?;
        let mut best = (f64::INFINITY, u32::MAX);
        self.visit(&seg, 0, self.root_min, self.root_size, &mut best);
        if best.1 == u32::MAX {
            return None;
        }
        let v = corners(&self.tris[best.1 as usize]);
        Some((best.0, (v[1] - v[0]).cross(v[2] - v[0])))
    }

    /// Visits node `ni` (box `min`, `size`), which the segment reaches before `best.0`,
    /// nearest children first; `best` is the nearest hit so far and its triangle.
    fn visit(&self, seg: &Segment, ni: u32, min: DVec3, size: f64, best: &mut (f64, u32)) {
        let node = self.nodes[ni as usize];
        if node.first_child == 0 {
            let list = &self.indices[node.start as usize..(node.start + node.count) as usize];
            for &ti in list {
                let v = corners(&self.tris[ti as usize]);
                // The baker's Möller–Trumbore (edges count as hits).
                if let Some(t) = geom::segment_triangle(seg.a, seg.a + seg.d, &v) {
                    if t < best.0 {
                        *best = (t, ti);
                    }
                }
            }
            return;
        }
        let half = size * 0.5;
        // The halves of each axis the segment's box (up to the nearest hit) reaches: bit 0
        // the lower, bit 1 the upper.
        let reach = best.0.min(1.0);
        let end = seg.a + seg.d * reach;
        let (slo, shi) = (seg.a.min(end), seg.a.max(end));
        let mut halves = [0u32; 3];
        for k in 0..3 {
            let mid = min[k] + half;
            halves[k] = u32::from(slo[k] <= mid) | (u32::from(shi[k] >= mid) << 1);
        }
        let mut hits = [(0u32, 0.0f64); 8];
        let mut n = 0;
        for k in 0..8u32 {
            if halves[0] & (1 << (k & 1)) == 0
                || halves[1] & (1 << ((k >> 1) & 1)) == 0
                || halves[2] & (1 << ((k >> 2) & 1)) == 0
            {
                continue;
            }
            let cmin = child_min(min, half, k);
            if let Some(t) = segment_box(
                seg.a,
                seg.d,
                seg.inv,
                cmin,
                cmin + DVec3::splat(half),
                reach,
            ) {
                // Insertion sort, nearest first.
                let mut j = n;
                while j > 0 && hits[j - 1].1 > t {
                    hits[j] = hits[j - 1];
                    j -= 1;
                }
                hits[j] = (k, t);
                n += 1;
            }
        }
        for &(k, t) in &hits[..n] {
            if t > best.0 {
                break;
            }
            self.visit(
                seg,
                node.first_child + k,
                child_min(min, half, k),
                half,
                best,
            );
        }
    }
}

/// A segment `a + t d`, `t` in `[0, 1]`, and `1 / d`.
struct Segment {
    a: DVec3,
    d: DVec3,
    inv: DVec3,
}

/// Corner of child `k` (bit 0: upper x half, bit 1: y, bit 2: z) of the box at `min`.
#[inline]
fn child_min(min: DVec3, half: f64, k: u32) -> DVec3 {
    min + DVec3::new(
        if k & 1 != 0 { half } else { 0.0 },
        if k & 2 != 0 { half } else { 0.0 },
        if k & 4 != 0 { half } else { 0.0 },
    )
}

struct Builder<'a> {
    positions: &'a [[f32; 3]],
    triangles: &'a [[u32; 3]],
    max_depth: u32,
    max_leaf: usize,
    pad: f64,
}

impl Builder<'_> {
    fn build(&self, tris: Vec<u32>, min: DVec3, size: f64, depth: u32) -> Tmp {
        if tris.len() <= self.max_leaf || depth >= self.max_depth {
            return Tmp::Leaf(tris);
        }
        let half = size * 0.5;
        let child = |k: u32| {
            let cmin = child_min(min, half, k);
            let (lo, hi) = (
                cmin - DVec3::splat(self.pad),
                cmin + DVec3::splat(half + self.pad),
            );
            let list: Vec<u32> = tris
                .iter()
                .copied()
                .filter(|&t| {
                    triangle_overlaps_box(
                        &tri_of(self.positions, self.triangles[t as usize]),
                        lo,
                        hi,
                    )
                })
                .collect();
            self.build(list, cmin, half, depth + 1)
        };
        let children: Vec<Tmp> = if tris.len() >= PARALLEL_MIN {
            (0..8u32).into_par_iter().map(child).collect()
        } else {
            (0..8u32).map(child).collect()
        };
        let mut it = children.into_iter();
        Tmp::Inner(Box::new(std::array::from_fn(|_| {
            it.next().unwrap_or(Tmp::Leaf(Vec::new()))
        })))
    }
}

impl Method for TriangleOctree {
    fn name(&self) -> &'static str {
        "triangle-octree"
    }

    /// Nodes (12 bytes each), the leaves' index lists (4 bytes per entry), and the copy of
    /// the triangles it keeps (three `f32` corners each, 36 bytes).
    fn memory_bytes(&self) -> usize {
        std::mem::size_of::<Self>()
            + self.nodes.len() * std::mem::size_of::<Node>()
            + self.indices.len() * 4
            + self.tris.len() * std::mem::size_of::<[[f32; 3]; 3]>()
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
