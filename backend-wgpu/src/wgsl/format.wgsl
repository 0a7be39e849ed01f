// The proxy buffer as core/src/format.rs encodes it: the header words and the two-word node
// records, read straight from the bytes the CPU validated. Mirrors `NodeRecord`'s accessors,
// `decode_normal` and `grid_plane` operation for operation. The constants (LEAF_BIT, OCT_MAX,
// ...) come from Rust: `shader::constants_wgsl` writes them in front of this file.

// The whole proxy, exactly as core encodes it: header, node records, lookup table. A scene's
// proxies lie one after another in it; `header.base` is the word where the one in use starts.
@group(0) @binding(0) var<storage, read> proxy: array<u32>;

// One node record (core's `NodeRecord`): two words whose meaning depends on LEAF_BIT.
struct NodeRecord {
    a: u32,
    b: u32,
}

// The header fields a step reads, decoded once per proxy used (core's `Header` plus
// `ProxyView::cell_unit` and `uses_lut`), and where the proxy starts in the buffer.
struct Header {
    base: u32,
    root_min: vec3<f32>,
    root_size: f32,
    cell_unit: f32,
    lut_depth: u32,
    tree_depth: u32,
    dmax: u32,
    lut_offset: u32,
    use_lut: bool,
}

var<private> header: Header;

// The proxy that starts at word `base` of the buffer is the one the step reads from now on.
fn load_header(base: u32, use_lut: bool) {
    header.base = base;
    header.root_min = vec3<f32>(
        bitcast<f32>(proxy[base + HEADER_ROOT_MIN]),
        bitcast<f32>(proxy[base + HEADER_ROOT_MIN + 1u]),
        bitcast<f32>(proxy[base + HEADER_ROOT_MIN + 2u]),
    );
    header.root_size = bitcast<f32>(proxy[base + HEADER_ROOT_SIZE]);
    // A power-of-two scale: exact, as on the CPU.
    header.cell_unit = header.root_size * INV_GRID_CELLS;
    header.lut_depth = proxy[base + HEADER_LUT_DEPTH];
    header.tree_depth = proxy[base + HEADER_TREE_DEPTH];
    header.dmax = proxy[base + HEADER_DMAX];
    header.lut_offset = proxy[base + HEADER_LUT_OFFSET];
    header.use_lut = use_lut && header.lut_depth > 0u;
}

fn node_record(index: u32) -> NodeRecord {
    let w = header.base + HEADER_WORDS + NODE_WORDS * index;
    return NodeRecord(proxy[w], proxy[w + 1u]);
}

fn is_leaf(r: NodeRecord) -> bool {
    return (r.a & LEAF_BIT) != 0u;
}

fn first_child(r: NodeRecord) -> u32 {
    return r.a & ~LEAF_BIT;
}

fn child_mask(r: NodeRecord) -> u32 {
    return (r.b >> CHILD_MASK_SHIFT) & 0xffu;
}

fn label_bits(r: NodeRecord, octant: u32) -> u32 {
    return (r.b >> (LABEL_SHIFT + 2u * octant)) & 3u;
}

fn child_index(r: NodeRecord, octant: u32) -> u32 {
    let below = child_mask(r) & ((1u << octant) - 1u);
    return first_child(r) + countOneBits(below);
}

fn is_two_sided(r: NodeRecord) -> bool {
    return (r.a & TWO_SIDED_BIT) != 0u;
}

fn plane_offset(r: NodeRecord) -> f32 {
    if is_two_sided(r) {
        return 0.0;
    }
    return bitcast<f32>(r.b);
}

fn clearance(r: NodeRecord, face: u32) -> u32 {
    return (r.b >> (CLEARANCE_BITS * face)) & CLEARANCE_MAX;
}

fn normal(r: NodeRecord) -> vec3<f32> {
    return decode_normal(r.a & OCT_MASK);
}

fn sign_nonneg(x: f32) -> f32 {
    if x >= 0.0 {
        return 1.0;
    }
    return -1.0;
}

// The scalar dot product in glam's order, x then y then z.
fn dot3(a: vec3<f32>, b: vec3<f32>) -> f32 {
    return a.x * b.x + a.y * b.y + a.z * b.z;
}

fn decode_normal(bits: u32) -> vec3<f32> {
    let component_mask = (1u << OCT_BITS) - 1u;
    let u = (f32(bits & component_mask) - f32(OCT_MAX)) * INV_OCT_MAX;
    let v = (f32((bits >> OCT_BITS) & component_mask) - f32(OCT_MAX)) * INV_OCT_MAX;
    let z = 1.0 - abs(u) - abs(v);
    var x = u;
    var y = v;
    if z < 0.0 {
        x = (1.0 - abs(v)) * sign_nonneg(u);
        y = (1.0 - abs(u)) * sign_nonneg(v);
    }
    let n = vec3<f32>(x, y, z);
    return n * (1.0 / sqrt(dot3(n, n)));
}

fn grid_plane(root_min: f32, cell_unit: f32, i: u32) -> f32 {
    return root_min + f32(i) * cell_unit;
}

// Bit tests, not comparisons: they hold whatever a driver assumes about NaN and infinity.
fn is_finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

fn is_finite3(v: vec3<f32>) -> bool {
    return is_finite(v.x) && is_finite(v.y) && is_finite(v.z);
}

fn infinity() -> f32 {
    return bitcast<f32>(0x7f800000u);
}
