//! The encoding of the flat tree into words: node records breadth first, then the lookup
//! table (core/FORMAT.md).

use glam::Vec3;
use octoproxy_core::format::{
    encode_normal, header, NodeRecord, FORMAT_VERSION, HEADER_WORDS, MAGIC, NODE_WORDS,
};
use octoproxy_core::lut_target;
use rayon::prelude::*;

use super::flat::{Flat, Kind, EMPTY};
use super::label::Labels;
use super::{BuildParams, BuildReport, Grid};

/// Encodes the tree breadth first, then the lookup table; fills the report's sizes.
pub(crate) fn encode(
    tree: &Flat,
    labels: &Labels,
    crowded: &[bool],
    grid: &Grid,
    params: &BuildParams,
    report: &mut BuildReport,
) -> Vec<u32> {
    // Breadth-first order of the nodes that get a record.
    let mut order: Vec<u32> = vec![0];
    let mut first_child: Vec<u32> = Vec::new();
    let mut i = 0;
    while i < order.len() {
        let id = order[i];
        if let Kind::Internal { children } = &tree.nodes[id as usize].kind {
            first_child.push(order.len() as u32);
            order.extend(children.iter().copied().filter(|&c| c != EMPTY));
        } else {
            first_child.push(0);
        }
        i += 1;
    }
    let mut tree_depth = 0;
    let mut records: Vec<NodeRecord> = Vec::with_capacity(order.len());
    for (k, &id) in order.iter().enumerate() {
        let node = &tree.nodes[id as usize];
        match &node.kind {
            Kind::Internal { children } => {
                tree_depth = tree_depth.max(node.depth + 1);
                let mut child_mask = 0u8;
                let mut internal_mask = 0u8;
                let mut label_bits = 0u16;
                for (o, &c) in children.iter().enumerate() {
                    if c == EMPTY {
                        label_bits |= (labels.get(id * 8 + o as u32).bits() as u16) << (2 * o);
                    } else {
                        child_mask |= 1 << o;
                        if matches!(tree.nodes[c as usize].kind, Kind::Internal { .. }) {
                            internal_mask |= 1 << o;
                        }
                    }
                }
                records.push(NodeRecord::internal(
                    first_child[k],
                    child_mask,
                    internal_mask,
                    label_bits,
                ));
            }
            Kind::Surface(s) => {
                tree_depth = tree_depth.max(node.depth);
                let two_sided = s.two_sided || labels.conflicted(id) || crowded[id as usize];
                report.surface_leaves += 1;
                report.two_sided_leaves += two_sided as usize;
                report.coarse_solid_leaves += (two_sided && node.depth < params.dmax) as usize;
                let n = Vec3::new(s.normal.x as f32, s.normal.y as f32, s.normal.z as f32);
                records.push(if two_sided {
                    NodeRecord::solid(encode_normal(n), s.clearance)
                } else {
                    NodeRecord::surface(encode_normal(n), s.plane_offset as f32)
                });
            }
        }
    }
    let lut_depth = params.lut_depth.min(tree_depth);
    let lut: Vec<u32> = if lut_depth == 0 {
        Vec::new()
    } else {
        let n = 1u32 << lut_depth;
        (0..n * n * n)
            .into_par_iter()
            .map(|e| lut_target(&records, [e % n, (e / n) % n, e / (n * n)], lut_depth))
            .collect()
    };
    let node_words = records.len() * NODE_WORDS;
    let total = HEADER_WORDS + node_words + lut.len();
    let mut words = vec![0u32; HEADER_WORDS];
    words[header::MAGIC] = MAGIC;
    words[header::VERSION] = FORMAT_VERSION;
    words[header::HEADER_WORDS] = HEADER_WORDS as u32;
    words[header::TOTAL_WORDS] = total as u32;
    words[header::NODE_COUNT] = records.len() as u32;
    words[header::NODES_OFFSET] = HEADER_WORDS as u32;
    words[header::LUT_DEPTH] = lut_depth;
    words[header::LUT_OFFSET] = (HEADER_WORDS + node_words) as u32;
    words[header::TREE_DEPTH] = tree_depth;
    words[header::DMIN] = params.dmin;
    words[header::DMAX] = params.dmax;
    words[header::EPSILON] = params.epsilon.to_bits();
    for a in 0..3 {
        words[header::ROOT_MIN + a] = grid.root_min[a].to_bits();
    }
    words[header::ROOT_SIZE] = grid.root_size.to_bits();
    words.reserve(total - HEADER_WORDS);
    words.extend_from_slice(bytemuck::cast_slice(&records));
    words.extend_from_slice(&lut);
    octoproxy_core::format::seal(&mut words);
    report.nodes = records.len();
    report.tree_depth = tree_depth;
    report.lut_depth = lut_depth;
    report.node_bytes = node_words * 4;
    report.lut_bytes = lut.len() * 4;
    report.total_bytes = total * 4;
    report.labelled_leaves = labels.labelled;
    report.conflicting_labels = labels.conflicts;
    words
}
