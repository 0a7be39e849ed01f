//! [`ProxyView`]: the only way from words to traversal. `ProxyView::new` checks everything a
//! traversal relies on, so code that takes a `&ProxyView` never indexes out of bounds and
//! never loops.

use core::fmt;

use glam::Vec3;

use crate::query::Aabb;

use crate::format::{
    self, header, Label, NodeRecord, FORMAT_VERSION, HEADER_WORDS, LUT_INDEX_MASK, MAGIC,
    MAX_DEPTH, MAX_LUT_DEPTH, NODE_WORDS,
};

/// Why a buffer is not a valid proxy. Every variant carries numbers, never text.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum FormatError {
    /// A byte slice is not 4-byte aligned or its length is not a multiple of 4.
    Misaligned {
        /// Length of the byte slice.
        len: usize,
    },
    /// The buffer ends before the data its header describes.
    Truncated {
        /// Words the header asks for.
        needed_words: usize,
        /// Words present.
        have_words: usize,
    },
    /// The buffer is longer than its header says.
    TrailingWords {
        /// Words the header describes.
        expected_words: usize,
        /// Words present.
        have_words: usize,
    },
    /// The first word is not [`MAGIC`].
    BadMagic {
        /// The word found.
        found: u32,
    },
    /// The format version is not [`FORMAT_VERSION`].
    UnsupportedVersion {
        /// The version found.
        found: u32,
    },
    /// A header field is out of its range.
    BadHeader {
        /// Index of the offending header word.
        word: usize,
        /// Its value.
        value: u32,
    },
    /// The root box is not finite, its size is not positive or has too many mantissa bits,
    /// or its cells at the tree depth are too small to tell apart in `f32`.
    BadRootBox,
    /// The root record is a leaf (the root is always an internal node).
    RootIsLeaf,
    /// A node record is malformed (reserved bits set, masks disagree, invalid label).
    BadNode {
        /// Index of the record.
        node: u32,
    },
    /// A node's children are not where breadth-first order puts them, or lie past the end.
    ChildOutOfRange {
        /// Index of the parent record.
        node: u32,
        /// Its first-child index.
        child: u32,
    },
    /// A record is nobody's child.
    Orphan {
        /// Index of the record.
        node: u32,
    },
    /// An internal node sits at or below [`MAX_DEPTH`], or deeper than the header says.
    TooDeep {
        /// Index of the record.
        node: u32,
    },
    /// The checksum word does not match the buffer (a bit flipped in transit or on disk).
    BadChecksum {
        /// The checksum of the buffer.
        expected: u32,
        /// The checksum word found.
        found: u32,
    },
    /// A lookup-table entry does not point where descending from the root leads.
    BadLookupEntry {
        /// Index of the entry.
        entry: u32,
        /// Its value.
        value: u32,
    },
}

impl fmt::Display for FormatError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            FormatError::Misaligned { len } => {
                write!(f, "proxy bytes are not 4-byte aligned words (length {len})")
            }
            FormatError::Truncated { needed_words, have_words } => write!(
                f,
                "proxy is truncated: needs {needed_words} words, has {have_words}"
            ),
            FormatError::TrailingWords { expected_words, have_words } => write!(
                f,
                "proxy has trailing data: header describes {expected_words} words, buffer has {have_words}"
            ),
            FormatError::BadMagic { found } => {
                write!(f, "not an octoproxy proxy (magic {found:#010x}, expected {MAGIC:#010x})")
            }
            FormatError::UnsupportedVersion { found } => write!(
                f,
                "proxy format version {found} is not supported (this build reads version {FORMAT_VERSION})"
            ),
            FormatError::BadHeader { word, value } => {
                write!(f, "proxy header word {word} has an invalid value {value}")
            }
            FormatError::BadRootBox => write!(f, "proxy root box is invalid"),
            FormatError::RootIsLeaf => write!(f, "proxy root is a leaf"),
            FormatError::BadNode { node } => write!(f, "proxy node {node} is malformed"),
            FormatError::ChildOutOfRange { node, child } => write!(
                f,
                "proxy node {node} points to children at {child}, which is out of order or out of range"
            ),
            FormatError::Orphan { node } => write!(f, "proxy node {node} has no parent"),
            FormatError::TooDeep { node } => write!(f, "proxy node {node} is deeper than allowed"),
            FormatError::BadChecksum { expected, found } => write!(
                f,
                "proxy checksum is {found:#010x}, the data's is {expected:#010x}: the file is corrupt"
            ),
            FormatError::BadLookupEntry { entry, value } => write!(
                f,
                "proxy lookup-table entry {entry} ({value:#010x}) does not match the tree"
            ),
        }
    }
}

impl core::error::Error for FormatError {}

/// The header fields of a validated proxy.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Header {
    /// Number of node records.
    pub node_count: u32,
    /// Depth of the lookup table (0: no table).
    pub lut_depth: u32,
    /// Depth of the deepest leaf.
    pub tree_depth: u32,
    /// `dmin` used to build the proxy.
    pub dmin: u32,
    /// `dmax` used to build the proxy.
    pub dmax: u32,
    /// `epsilon` used to build the proxy.
    pub epsilon: f32,
    /// Minimum corner of the root cube.
    pub root_min: Vec3,
    /// Edge length of the root cube.
    pub root_size: f32,
    /// The particle radius the proxy was baked for (`0` for points).
    pub radius: f32,
}

/// A validated, zero-copy view of an encoded proxy.
#[derive(Clone, Copy, Debug)]
pub struct ProxyView<'a> {
    words: &'a [u32],
    nodes: &'a [NodeRecord],
    lut: &'a [u32],
    header: Header,
    cell_unit: f32,
    /// `header.root_min` as an array: indexed by axis in the hottest loops.
    root_min: [f32; 3],
    /// The root cube's planes (`plane(a, 0)` and `plane(a, 2^MAX_DEPTH)`), computed once:
    /// every step that leaves a leaf tests them.
    pub(crate) root: Aabb,
    use_lut: bool,
}

fn word(words: &[u32], i: usize) -> Result<u32, FormatError> {
    words.get(i).copied().ok_or(FormatError::Truncated {
        needed_words: HEADER_WORDS,
        have_words: words.len(),
    })
}

impl<'a> ProxyView<'a> {
    /// Validates `words` and returns a view of them.
    pub fn new(words: &'a [u32]) -> Result<Self, FormatError> {
        let magic = word(words, header::MAGIC)?;
        if magic != MAGIC {
            return Err(FormatError::BadMagic { found: magic });
        }
        let version = word(words, header::VERSION)?;
        if version != FORMAT_VERSION {
            return Err(FormatError::UnsupportedVersion { found: version });
        }
        if words.len() < HEADER_WORDS {
            return Err(FormatError::Truncated {
                needed_words: HEADER_WORDS,
                have_words: words.len(),
            });
        }
        let h = |i: usize| words[i];
        let bad = |i: usize| FormatError::BadHeader {
            word: i,
            value: words[i],
        };
        if h(header::HEADER_WORDS) as usize != HEADER_WORDS {
            return Err(bad(header::HEADER_WORDS));
        }
        let node_count = h(header::NODE_COUNT);
        if node_count == 0 || node_count > LUT_INDEX_MASK {
            return Err(bad(header::NODE_COUNT));
        }
        let lut_depth = h(header::LUT_DEPTH);
        let tree_depth = h(header::TREE_DEPTH);
        let dmin = h(header::DMIN);
        let dmax = h(header::DMAX);
        if tree_depth == 0 || tree_depth > MAX_DEPTH {
            return Err(bad(header::TREE_DEPTH));
        }
        if dmax > MAX_DEPTH || dmax < tree_depth {
            return Err(bad(header::DMAX));
        }
        if dmin > dmax {
            return Err(bad(header::DMIN));
        }
        if lut_depth > MAX_LUT_DEPTH || lut_depth > tree_depth {
            return Err(bad(header::LUT_DEPTH));
        }
        let node_words = node_count as usize * NODE_WORDS;
        let lut_len = 1usize << (3 * lut_depth);
        let lut_len = if lut_depth == 0 { 0 } else { lut_len };
        let nodes_offset = h(header::NODES_OFFSET) as usize;
        if nodes_offset != HEADER_WORDS {
            return Err(bad(header::NODES_OFFSET));
        }
        let lut_offset = h(header::LUT_OFFSET) as usize;
        if lut_offset != nodes_offset + node_words {
            return Err(bad(header::LUT_OFFSET));
        }
        let total = lut_offset + lut_len;
        if h(header::TOTAL_WORDS) as usize != total {
            return Err(bad(header::TOTAL_WORDS));
        }
        if words.len() < total {
            return Err(FormatError::Truncated {
                needed_words: total,
                have_words: words.len(),
            });
        }
        if words.len() > total {
            return Err(FormatError::TrailingWords {
                expected_words: total,
                have_words: words.len(),
            });
        }
        let epsilon = f32::from_bits(h(header::EPSILON));
        if !(epsilon >= 0.0) || !epsilon.is_finite() {
            return Err(bad(header::EPSILON));
        }
        let root_min = Vec3::new(
            f32::from_bits(h(header::ROOT_MIN)),
            f32::from_bits(h(header::ROOT_MIN + 1)),
            f32::from_bits(h(header::ROOT_MIN + 2)),
        );
        let root_size = f32::from_bits(h(header::ROOT_SIZE));
        let radius = f32::from_bits(h(header::RADIUS));
        if !(radius >= 0.0) || !radius.is_finite() || radius.to_bits() == (-0.0f32).to_bits() {
            return Err(bad(header::RADIUS));
        }
        if !root_box_is_valid(root_min, root_size, tree_depth) {
            return Err(FormatError::BadRootBox);
        }
        let nodes: &[NodeRecord] = bytemuck::cast_slice(&words[nodes_offset..lut_offset]);
        let lut = &words[lut_offset..total];
        let header = Header {
            node_count,
            lut_depth,
            tree_depth,
            dmin,
            dmax,
            epsilon,
            root_min,
            root_size,
            radius,
        };
        validate_nodes(nodes, tree_depth, root_size)?;
        let cell_unit = root_size * (1.0 / (1u32 << MAX_DEPTH) as f32);
        // The root cube's planes, by the one formula every other plane comes from.
        let root_plane = |i: u32| {
            Vec3::from_array(core::array::from_fn(|a| {
                format::grid_plane(root_min[a], cell_unit, i)
            }))
        };
        let view = ProxyView {
            words,
            nodes,
            lut,
            header,
            cell_unit,
            root_min: root_min.to_array(),
            root: Aabb {
                min: root_plane(0),
                max: root_plane(1 << MAX_DEPTH),
            },
            use_lut: lut_depth > 0,
        };
        view.validate_lut()?;
        // Last, so that structural damage keeps its specific error; what is left (normals,
        // offsets, labels, root box, informational fields) is caught here.
        let expected = format::checksum(words);
        if h(header::CHECKSUM) != expected {
            return Err(FormatError::BadChecksum {
                expected,
                found: h(header::CHECKSUM),
            });
        }
        Ok(view)
    }

    /// Validates little-endian bytes. They must be 4-byte aligned (as `Vec<u32>` storage or
    /// a GPU mapping is); copy into a `Vec<u32>` first otherwise.
    pub fn from_bytes(bytes: &'a [u8]) -> Result<Self, FormatError> {
        let words: &[u32] = bytemuck::try_cast_slice(bytes)
            .map_err(|_| FormatError::Misaligned { len: bytes.len() })?;
        Self::new(words)
    }

    /// The same proxy, traversed from the root instead of through the lookup table (for
    /// measuring what the table buys; results are identical).
    pub fn without_lut(mut self) -> Self {
        self.use_lut = false;
        self
    }

    /// The whole buffer, exactly as validated (what backends upload).
    pub fn words(&self) -> &'a [u32] {
        self.words
    }

    /// The node records.
    pub fn nodes(&self) -> &'a [NodeRecord] {
        self.nodes
    }

    /// The lookup table.
    pub fn lut(&self) -> &'a [u32] {
        self.lut
    }

    /// The header fields.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// Edge length of a cell of the `2^MAX_DEPTH` grid.
    pub fn cell_unit(&self) -> f32 {
        self.cell_unit
    }

    /// Coordinate of grid plane `i` (on the `2^MAX_DEPTH` grid) along `axis` (0, 1 or 2).
    #[inline]
    pub fn plane(&self, axis: usize, i: u32) -> f32 {
        format::grid_plane(self.root_min[axis], self.cell_unit, i)
    }

    /// Whether queries enter through the lookup table.
    pub fn uses_lut(&self) -> bool {
        self.use_lut
    }

    /// Edge length of a leaf at depth `dmax`.
    pub fn finest_leaf_size(&self) -> f32 {
        self.header.root_size / (1u32 << self.header.dmax) as f32
    }

    /// Bytes of the node array.
    pub fn node_bytes(&self) -> usize {
        self.nodes.len() * NODE_WORDS * 4
    }

    /// Bytes of the lookup table.
    pub fn lut_bytes(&self) -> usize {
        self.lut.len() * 4
    }

    /// Maximum number of leaves a single step visits (see [`crate::max_leaves_per_step`]).
    pub fn max_leaves_per_step(&self) -> u32 {
        crate::step::max_leaves_per_step(self.header.tree_depth)
    }

    /// Checks every entry of the lookup table against a descent from the root, so that
    /// entering through the table and from the root always find the same leaf.
    fn validate_lut(&self) -> Result<(), FormatError> {
        let d = self.header.lut_depth;
        if d == 0 {
            return Ok(());
        }
        let n = 1u32 << d;
        for (entry, &value) in self.lut.iter().enumerate() {
            let e = entry as u32;
            let cell = [e % n, (e / n) % n, e / (n * n)];
            let expected = lut_target(self.nodes, cell, d);
            if value != expected {
                return Err(FormatError::BadLookupEntry { entry: e, value });
            }
        }
        Ok(())
    }
}

/// The lookup-table entry for `cell` at `depth`: the deepest record on the way down from the
/// root, no deeper than `depth`, with its depth. Used by the builder and by validation.
pub fn lut_target(nodes: &[NodeRecord], cell: [u32; 3], depth: u32) -> u32 {
    let mut index = 0u32;
    let mut d = 0u32;
    while d < depth {
        let Some(rec) = nodes.get(index as usize).copied() else {
            break;
        };
        if rec.is_leaf() {
            break;
        }
        let shift = depth - d - 1;
        let octant = ((cell[0] >> shift) & 1)
            | ((cell[1] >> shift) & 1) << 1
            | ((cell[2] >> shift) & 1) << 2;
        if rec.child_mask() & (1 << octant) == 0 {
            break;
        }
        index = rec.child_index(octant);
        d += 1;
    }
    format::lut_entry(index, d)
}

fn root_box_is_valid(root_min: Vec3, root_size: f32, tree_depth: u32) -> bool {
    if !root_min.is_finite() || !root_size.is_finite() || !(root_size > 0.0) {
        return false;
    }
    if format::quantize_root_size(root_size) != root_size || !root_size.is_normal() {
        return false;
    }
    let unit = root_size * (1.0 / (1u32 << MAX_DEPTH) as f32);
    if !unit.is_normal() {
        return false;
    }
    let max = root_min + Vec3::splat(root_size);
    if !max.is_finite() {
        return false;
    }
    // Cells at the tree depth must stay several ulps wide so that every plane is distinct.
    let cell = root_size / (1u32 << tree_depth) as f32;
    let mag = root_min.abs().max(max.abs()).max_element();
    cell >= 4.0 * ulp(mag)
}

/// `|v|` without the overflow of its squares: `v.length()` where that is finite (the same
/// bits), else, for a finite `v`, `m·|v/m|` with `m` its largest magnitude, finite up to about
/// `1.9e38`. A particle at `1e20` per second has a reach, where `v.length()` is infinite
/// (its squares pass `f32::MAX` from about `1.8e19`) and would have made it invalid. WGSL's
/// `wide_length3` is the same operations.
#[inline]
pub fn wide_length(v: Vec3) -> f32 {
    let l = v.length();
    if l.is_finite() {
        return l;
    }
    let m = v.abs().max_element();
    if !(m > 0.0 && m.is_finite()) {
        return l;
    }
    m * (v / m).length()
}

/// Distance from `x` to the next larger `f32`.
pub fn ulp(x: f32) -> f32 {
    let x = x.abs();
    if !x.is_finite() {
        return f32::INFINITY;
    }
    f32::from_bits(x.to_bits() + 1) - x
}

/// Checks breadth-first layout, masks, labels and depths in one pass with no allocation.
fn validate_nodes(
    nodes: &[NodeRecord],
    tree_depth: u32,
    root_size: f32,
) -> Result<(), FormatError> {
    let count = nodes.len() as u32;
    if nodes[0].is_leaf() {
        return Err(FormatError::RootIsLeaf);
    }
    // `next` is the first record not yet claimed as someone's child; records are claimed in
    // order, so every record but the root must be claimed before it is reached.
    let mut next = 1u32;
    let mut depth = 0u32;
    let mut level_end = 1u32;
    for (i, rec) in nodes.iter().enumerate() {
        let i = i as u32;
        if i > 0 && i >= next {
            return Err(FormatError::Orphan { node: i });
        }
        if i == level_end {
            depth += 1;
            level_end = next;
        }
        if rec.is_leaf() {
            // Every bit of a surface leaf's first word means something (leaf, two-sided, two
            // 15-bit normal components), and every pattern decodes to a unit normal.
            const _: () = assert!(
                format::LEAF_BIT | format::TWO_SIDED_BIT | ((1 << (2 * format::OCT_BITS)) - 1)
                    == u32::MAX
            );
            if depth == 0 || depth > tree_depth {
                return Err(FormatError::TooDeep { node: i });
            }
            if rec.is_two_sided() {
                // Six clearances; any values (a wrong one moves contact, not termination).
                if rec.b >> (6 * format::CLEARANCE_BITS) != 0 {
                    return Err(FormatError::BadNode { node: i });
                }
                continue;
            }
            // The mean plane passes through the leaf: |d| is at most half its diagonal.
            let d = rec.plane_offset();
            if !d.is_finite() || d.abs() > NodeRecord::plane_offset_bound(root_size, depth) {
                return Err(FormatError::BadNode { node: i });
            }
            continue;
        }
        if depth >= tree_depth {
            return Err(FormatError::TooDeep { node: i });
        }
        let child_mask = rec.child_mask();
        let internal_mask = rec.internal_mask();
        if child_mask == 0 || internal_mask & !child_mask != 0 {
            return Err(FormatError::BadNode { node: i });
        }
        for octant in 0..8 {
            let bits = rec.label_bits(octant);
            let has_child = child_mask & (1 << octant) != 0;
            if Label::from_bits(bits).is_none() || (has_child && bits != 0) {
                return Err(FormatError::BadNode { node: i });
            }
        }
        let first = rec.first_child();
        let n = child_mask.count_ones();
        if first != next || first.checked_add(n).is_none_or(|end| end > count) {
            return Err(FormatError::ChildOutOfRange {
                node: i,
                child: first,
            });
        }
        for octant in 0..8 {
            if child_mask & (1 << octant) != 0 {
                let child = nodes[rec.child_index(octant) as usize];
                let is_internal = internal_mask & (1 << octant) != 0;
                if child.is_leaf() == is_internal {
                    return Err(FormatError::BadNode { node: i });
                }
            }
        }
        next = first + n;
    }
    if next != count {
        return Err(FormatError::Orphan { node: next });
    }
    Ok(())
}

/// A validated proxy that owns its words: [`OwnedProxy::view`] is free, because the words
/// were validated once by [`OwnedProxy::new`] and cannot change afterwards.
#[cfg(feature = "alloc")]
#[derive(Clone, Debug)]
pub struct OwnedProxy {
    words: alloc::vec::Vec<u32>,
    header: Header,
    cell_unit: f32,
    root: Aabb,
    nodes: core::ops::Range<usize>,
    lut: core::ops::Range<usize>,
}

#[cfg(feature = "alloc")]
impl OwnedProxy {
    /// Validates `words` (as [`ProxyView::new`]) and keeps them.
    pub fn new(words: alloc::vec::Vec<u32>) -> Result<Self, FormatError> {
        let view = ProxyView::new(&words)?;
        let nodes_start = HEADER_WORDS;
        let nodes_end = nodes_start + view.nodes.len() * NODE_WORDS;
        let lut = nodes_end..nodes_end + view.lut.len();
        let (header, cell_unit, root) = (view.header, view.cell_unit, view.root);
        Ok(Self {
            words,
            header,
            cell_unit,
            root,
            nodes: nodes_start..nodes_end,
            lut,
        })
    }

    /// A view of the words, with no second validation.
    pub fn view(&self) -> ProxyView<'_> {
        ProxyView {
            words: &self.words,
            nodes: bytemuck::cast_slice(&self.words[self.nodes.clone()]),
            lut: &self.words[self.lut.clone()],
            header: self.header,
            cell_unit: self.cell_unit,
            root_min: self.header.root_min.to_array(),
            root: self.root,
            use_lut: self.header.lut_depth > 0,
        }
    }

    /// The words, exactly as validated.
    pub fn words(&self) -> &[u32] {
        &self.words
    }

    /// Gives the words back.
    pub fn into_words(self) -> alloc::vec::Vec<u32> {
        self.words
    }
}
