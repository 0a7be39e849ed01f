//! The encoded proxy: one flat buffer of little-endian 32-bit words, read unchanged by every
//! backend. `core/FORMAT.md` documents every word and bit; the constants here are the source
//! of truth for both that document and the WGSL mirror.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use crate::math;

/// First word of every proxy: the bytes `OCTP` read as a little-endian `u32`.
pub const MAGIC: u32 = u32::from_le_bytes(*b"OCTP");
/// Bumped whenever the meaning of any word or bit changes.
pub const FORMAT_VERSION: u32 = 5;
/// Words in the header, before the node array.
pub const HEADER_WORDS: usize = 18;
/// Deepest tree the format supports. Cell bounds are computed on a `2^MAX_DEPTH` grid.
pub const MAX_DEPTH: u32 = 16;
/// Deepest lookup table the format supports (`8^MAX_LUT_DEPTH` entries).
pub const MAX_LUT_DEPTH: u32 = 8;
/// Words per node record.
pub const NODE_WORDS: usize = 2;
/// Mantissa bits the root size may use, so that `i * cell_unit` is exact for every grid
/// index `i <= 2^MAX_DEPTH` (17 bits): `24 - 17 = 7`.
pub const ROOT_SIZE_MANTISSA_BITS: u32 = 24 - (MAX_DEPTH + 1);

/// Header word indices.
pub mod header {
    /// [`super::MAGIC`].
    pub const MAGIC: usize = 0;
    /// [`super::FORMAT_VERSION`].
    pub const VERSION: usize = 1;
    /// Words in the header ([`super::HEADER_WORDS`]).
    pub const HEADER_WORDS: usize = 2;
    /// Total words in the buffer.
    pub const TOTAL_WORDS: usize = 3;
    /// Number of node records.
    pub const NODE_COUNT: usize = 4;
    /// Word offset of the node array.
    pub const NODES_OFFSET: usize = 5;
    /// Depth of the lookup table.
    pub const LUT_DEPTH: usize = 6;
    /// Word offset of the lookup table.
    pub const LUT_OFFSET: usize = 7;
    /// Depth of the deepest leaf.
    pub const TREE_DEPTH: usize = 8;
    /// `dmin` the proxy was built with (informational).
    pub const DMIN: usize = 9;
    /// `dmax` the proxy was built with.
    pub const DMAX: usize = 10;
    /// `epsilon` the proxy was built with, as `f32` bits (informational).
    pub const EPSILON: usize = 11;
    /// Root cube minimum corner x, as `f32` bits (then y, z).
    pub const ROOT_MIN: usize = 12;
    /// Root cube edge length, as `f32` bits.
    pub const ROOT_SIZE: usize = 15;
    /// [`super::checksum`] of the whole buffer, this word read as zero.
    pub const CHECKSUM: usize = 16;
    /// The particle radius the proxy was baked for, as `f32` bits: `0` for points (the
    /// proxy's surface is the mesh), else its surface is the mesh's offset surface at this
    /// distance, and particles of this radius step against it.
    pub const RADIUS: usize = 17;
}

/// FNV-1a over the little-endian bytes of every word, [`header::CHECKSUM`] read as zero.
/// Each step is a bijection of the running hash, so any change of one byte (every bit flip)
/// changes the result.
pub fn checksum(words: &[u32]) -> u32 {
    let mut h = 0x811c_9dc5u32;
    for (i, &w) in words.iter().enumerate() {
        let w = if i == header::CHECKSUM { 0 } else { w };
        for b in w.to_le_bytes() {
            h = (h ^ b as u32).wrapping_mul(0x0100_0193);
        }
    }
    h
}

/// Writes [`checksum`] into the header of `words` (the last step of encoding a proxy).
pub fn seal(words: &mut [u32]) {
    if words.len() > header::CHECKSUM {
        words[header::CHECKSUM] = checksum(words);
    }
}

/// Internal-node `b` word: bits 0..8, which children have a record (are not empty).
pub const CHILD_MASK_SHIFT: u32 = 0;
/// Internal-node `b` word: bits 8..16, which children are internal nodes.
pub const INTERNAL_MASK_SHIFT: u32 = 8;
/// Internal-node `b` word: bits 16..32, two label bits per child (child `i` at `16 + 2i`).
pub const LABEL_SHIFT: u32 = 16;
/// Record `a` word: set for a surface (non-empty) leaf, clear for an internal node.
pub const LEAF_BIT: u32 = 1 << 31;
/// Surface-leaf `a` word: the triangles in the leaf face opposite ways, so the averaged normal
/// means nothing; the step treats the leaf as solid from every side.
pub const TWO_SIDED_BIT: u32 = 1 << 30;
/// Solid-leaf `b` word: bits of each face's clearance; face `k = 2 * axis + upper` at bits
/// `CLEARANCE_BITS * k ..`, the top two bits zero.
pub const CLEARANCE_BITS: u32 = 5;
/// The largest clearance.
pub const CLEARANCE_MAX: u32 = (1 << CLEARANCE_BITS) - 1;
/// A clearance counts steps of the leaf's edge divided by this: the slab of the leaf within
/// `clearance / CLEARANCE_STEPS` of its edge from the face holds no point of any triangle.
pub const CLEARANCE_STEPS: u32 = 32;
/// Surface-leaf `a` word: bits of each octahedral normal component.
pub const OCT_BITS: u32 = 15;
/// Largest magnitude of a centred octahedral component.
pub const OCT_MAX: u32 = (1 << (OCT_BITS - 1)) - 1;
/// Lookup-table entry: bits 0..27 hold a node index.
pub const LUT_INDEX_MASK: u32 = (1 << 27) - 1;
/// Lookup-table entry: bits 27..32 hold that node's depth.
pub const LUT_DEPTH_SHIFT: u32 = 27;

/// The front/back label of an empty leaf.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Label {
    /// Not next to the surface: crossing it does not change a particle's side.
    None = 0,
    /// In front of the surface (the side its normals point to).
    Front = 1,
    /// Behind the surface.
    Back = 2,
}

impl Label {
    /// The two label bits of this label.
    pub const fn bits(self) -> u32 {
        self as u32
    }

    /// Decodes two label bits; `3` is not a label.
    #[inline]
    pub const fn from_bits(bits: u32) -> Option<Label> {
        // A table, not a `match`: a `match` compiles to a jump table, and which label a leaf
        // has is a coin toss for the predictor of that indirect jump (a tenth of the
        // mispredictions of a two-leaf step).
        const LABELS: [Option<Label>; 4] = [
            Some(Label::None),
            Some(Label::Front),
            Some(Label::Back),
            None,
        ];
        if bits < 4 {
            LABELS[bits as usize]
        } else {
            None
        }
    }
}

/// One node record: two words whose meaning depends on [`LEAF_BIT`].
///
/// Internal node: `a` is the index of its first child record (children with a record are
/// stored contiguously in octant order), `b` holds the child, internal and label masks.
/// Surface leaf: `a` holds [`LEAF_BIT`], [`TWO_SIDED_BIT`] and the octahedral normal; `b` is
/// the plane offset as `f32` bits (see [`NodeRecord::plane_offset`]) for a one-sided leaf, and
/// the six faces' clearances for a solid (two-sided) one (see [`NodeRecord::clearance`]).
// Layout reason: two `u32`, no padding, 4-byte aligned, so a `&[u32]` casts to `&[NodeRecord]`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct NodeRecord {
    /// First word.
    pub a: u32,
    /// Second word.
    pub b: u32,
}

const _: () = assert!(core::mem::size_of::<NodeRecord>() == NODE_WORDS * 4);

impl NodeRecord {
    /// An internal node record.
    pub const fn internal(
        first_child: u32,
        child_mask: u8,
        internal_mask: u8,
        labels: u16,
    ) -> Self {
        Self {
            a: first_child & !LEAF_BIT,
            b: (child_mask as u32) << CHILD_MASK_SHIFT
                | (internal_mask as u32) << INTERNAL_MASK_SHIFT
                | (labels as u32) << LABEL_SHIFT,
        }
    }

    /// A one-sided surface leaf record with the given (encoded) normal and plane offset.
    pub fn surface(normal_bits: u32, plane_offset: f32) -> Self {
        Self {
            a: LEAF_BIT | (normal_bits & oct_mask()),
            b: plane_offset.to_bits(),
        }
    }

    /// A solid (two-sided) surface leaf record with the given (encoded) normal and the
    /// clearances of its faces (`clearance[2 * axis + upper]`, each at most
    /// [`CLEARANCE_MAX`]; larger values are cut to it).
    pub fn solid(normal_bits: u32, clearance: [u32; 6]) -> Self {
        let mut b = 0;
        for (k, c) in clearance.iter().enumerate() {
            b |= (*c).min(CLEARANCE_MAX) << (CLEARANCE_BITS * k as u32);
        }
        Self {
            a: LEAF_BIT | TWO_SIDED_BIT | (normal_bits & oct_mask()),
            b,
        }
    }

    /// One-sided surface leaf: the offset `d` of the surface's mean plane `n · (x - c) = d`,
    /// with `n` the normal and `c` the leaf's centre: where a particle colliding in the leaf
    /// makes contact, and which side of it a particle that starts inside the leaf is on. Zero
    /// for a solid leaf, whose `b` word holds clearances.
    #[inline]
    pub fn plane_offset(self) -> f32 {
        if self.is_two_sided() {
            0.0
        } else {
            f32::from_bits(self.b)
        }
    }

    /// Solid leaf: the clearance of face `face` (`2 * axis + upper`), in steps of the leaf's
    /// edge divided by [`CLEARANCE_STEPS`]: no point of any triangle lies in the closed slab
    /// of the leaf within that distance of the face. A particle that enters the leaf through
    /// that face alone moves in the slab and collides at its inner side, nearer the surface
    /// than the face.
    #[inline]
    pub const fn clearance(self, face: u32) -> u32 {
        (self.b >> (CLEARANCE_BITS * face)) & CLEARANCE_MAX
    }

    /// The largest `|plane_offset|` a valid proxy holds for a surface leaf at `depth` in a
    /// root cube of `root_size`: a hair over half the diagonal of the leaf's nominal cube (the
    /// mean plane passes through the leaf). The validator checks it; the baker stays inside it.
    #[inline]
    pub fn plane_offset_bound(root_size: f32, depth: u32) -> f32 {
        root_size / (1u32 << depth.min(MAX_DEPTH)) as f32 * 0.8661
    }

    /// Whether this is a surface leaf.
    #[inline]
    pub const fn is_leaf(self) -> bool {
        self.a & LEAF_BIT != 0
    }

    /// Internal node: index of the first child record.
    #[inline]
    pub const fn first_child(self) -> u32 {
        self.a & !LEAF_BIT
    }

    /// Internal node: children that have a record.
    #[inline]
    pub const fn child_mask(self) -> u32 {
        (self.b >> CHILD_MASK_SHIFT) & 0xff
    }

    /// Internal node: children that are internal nodes.
    #[inline]
    pub const fn internal_mask(self) -> u32 {
        (self.b >> INTERNAL_MASK_SHIFT) & 0xff
    }

    /// Internal node: the two label bits of empty child `octant`.
    #[inline]
    pub const fn label_bits(self, octant: u32) -> u32 {
        (self.b >> (LABEL_SHIFT + 2 * octant)) & 3
    }

    /// Internal node: index of the record of child `octant`, which must be in `child_mask`.
    #[inline]
    pub const fn child_index(self, octant: u32) -> u32 {
        let below = self.child_mask() & ((1 << octant) - 1);
        self.first_child() + below.count_ones()
    }

    /// Surface leaf: whether it is two-sided.
    #[inline]
    pub const fn is_two_sided(self) -> bool {
        self.a & TWO_SIDED_BIT != 0
    }

    /// Surface leaf: the representative normal (unit length, or zero for a two-sided leaf
    /// whose triangles cancel).
    #[inline]
    pub fn normal(self) -> Vec3 {
        decode_normal(self.a & oct_mask())
    }
}

const fn oct_mask() -> u32 {
    (1 << (2 * OCT_BITS)) - 1
}

/// Encodes a direction as two 15-bit octahedral components (`u` low, `v` high).
/// A zero or non-finite vector encodes as `+z`.
pub fn encode_normal(n: Vec3) -> u32 {
    let l1 = math::abs(n.x) + math::abs(n.y) + math::abs(n.z);
    if !(l1 > 0.0) || !l1.is_finite() {
        return encode_components(0.0, 0.0);
    }
    let p = n / l1;
    let (u, v) = if p.z >= 0.0 {
        (p.x, p.y)
    } else {
        (
            (1.0 - math::abs(p.y)) * sign(p.x),
            (1.0 - math::abs(p.x)) * sign(p.y),
        )
    };
    encode_components(u, v)
}

fn encode_components(u: f32, v: f32) -> u32 {
    let q = |c: f32| -> u32 {
        let c = c.clamp(-1.0, 1.0) * OCT_MAX as f32;
        // Round half away from zero, then centre on OCT_MAX.
        let r = if c >= 0.0 {
            math::floor(c + 0.5)
        } else {
            -math::floor(-c + 0.5)
        };
        (r as i32 + OCT_MAX as i32) as u32
    };
    q(u) | q(v) << OCT_BITS
}

/// Decodes [`encode_normal`]'s bits to a unit vector. WGSL's `decode_normal` mirrors this
/// operation for operation. Always inlined: the march decodes one per surface leaf it finds.
#[inline(always)]
pub fn decode_normal(bits: u32) -> Vec3 {
    let comp = |q: u32| -> f32 { (q as f32 - OCT_MAX as f32) * (1.0 / OCT_MAX as f32) };
    let u = comp(bits & ((1 << OCT_BITS) - 1));
    let v = comp((bits >> OCT_BITS) & ((1 << OCT_BITS) - 1));
    let z = 1.0 - math::abs(u) - math::abs(v);
    let (x, y) = if z >= 0.0 {
        (u, v)
    } else {
        (
            (1.0 - math::abs(v)) * sign(u),
            (1.0 - math::abs(u)) * sign(v),
        )
    };
    let n = Vec3::new(x, y, z);
    n * (1.0 / math::sqrt(n.dot(n)))
}

#[inline]
fn sign(x: f32) -> f32 {
    if x >= 0.0 {
        1.0
    } else {
        -1.0
    }
}

/// Packs a lookup-table entry.
pub const fn lut_entry(node: u32, depth: u32) -> u32 {
    (node & LUT_INDEX_MASK) | depth << LUT_DEPTH_SHIFT
}

/// The one formula for the coordinate of grid plane `i` (on the `2^MAX_DEPTH` grid) along
/// an axis. `i * cell_unit` is exact (see [`ROOT_SIZE_MANTISSA_BITS`]), so a fused
/// multiply-add gives the same result as a multiply then an add: one rounding, everywhere.
#[inline]
pub fn grid_plane(root_min: f32, cell_unit: f32, i: u32) -> f32 {
    root_min + i as f32 * cell_unit
}

/// Rounds a root size up to a value with at most [`ROOT_SIZE_MANTISSA_BITS`] mantissa bits.
pub fn quantize_root_size(size: f32) -> f32 {
    let drop = 23 - (ROOT_SIZE_MANTISSA_BITS - 1);
    let bits = size.to_bits();
    let mask = (1u32 << drop) - 1;
    if bits & mask == 0 {
        size
    } else {
        f32::from_bits((bits | mask) + 1)
    }
}
