// Point queries, as core/src/query.rs: which leaf holds a point, entered through the lookup
// table. A point exactly on a cell plane belongs to the cell its direction of travel enters.

// core's `Aabb`.
struct Aabb {
    min: vec3<f32>,
    max: vec3<f32>,
}

// core's `LeafInfo`. `kind` is LEAF_EMPTY or LEAF_SURFACE, `label` is LABEL_NONE,
// LABEL_FRONT or LABEL_BACK.
struct LeafInfo {
    aabb: Aabb,
    kind: u32,
    normal: vec3<f32>,
    two_sided: bool,
    plane_offset: f32,
    label: u32,
    node: u32,
    depth: u32,
    cell: vec3<u32>,
}

fn upper(p: f32, plane_at: f32, dir: f32) -> bool {
    return p > plane_at || (p == plane_at && dir >= 0.0);
}

fn plane(axis: u32, i: u32) -> f32 {
    return grid_plane(header.root_min[axis], header.cell_unit, i);
}

fn root_aabb() -> Aabb {
    let n = 1u << MAX_DEPTH;
    return Aabb(
        vec3<f32>(plane(0u, 0u), plane(1u, 0u), plane(2u, 0u)),
        vec3<f32>(plane(0u, n), plane(1u, n), plane(2u, n)),
    );
}

fn cell_aabb(cell: vec3<u32>, depth: u32) -> Aabb {
    let s = MAX_DEPTH - depth;
    return Aabb(
        vec3<f32>(plane(0u, cell.x << s), plane(1u, cell.y << s), plane(2u, cell.z << s)),
        vec3<f32>(plane(0u, (cell.x + 1u) << s), plane(1u, (cell.y + 1u) << s), plane(2u, (cell.z + 1u) << s)),
    );
}

fn root_contains(p: vec3<f32>, dir: vec3<f32>) -> bool {
    let n = 1u << MAX_DEPTH;
    for (var a = 0u; a < 3u; a++) {
        if !(upper(p[a], plane(a, 0u), dir[a]) && !upper(p[a], plane(a, n), dir[a])) {
            return false;
        }
    }
    return true;
}

// core's `ProxyView::surface_leaf`: the surface leaf `rec`, record `index`, of the cell.
fn surface_leaf(cell: vec3<u32>, depth: u32, index: u32, rec: NodeRecord) -> LeafInfo {
    return LeafInfo(cell_aabb(cell, depth), LEAF_SURFACE, normal(rec), is_two_sided(rec), plane_offset(rec), LABEL_NONE, index, depth, cell);
}

fn empty_leaf(cell: vec3<u32>, depth: u32, parent: u32, label: u32) -> LeafInfo {
    return LeafInfo(cell_aabb(cell, depth), LEAF_EMPTY, vec3<f32>(0.0), false, 0.0, label, parent, depth, cell);
}

fn cell_at_depth(p: vec3<f32>, dir: vec3<f32>, depth: u32) -> vec3<u32> {
    let n = 1u << depth;
    let s = MAX_DEPTH - depth;
    let scale = f32(n) / header.root_size;
    var c = vec3<u32>(0u);
    for (var a = 0u; a < 3u; a++) {
        // Truncation is the floor here: negative estimates clamp to 0 either way.
        let est = (p[a] - header.root_min[a]) * scale;
        var i = 0u;
        if est >= f32(n - 1u) {
            i = n - 1u;
        } else if est > 0.0 {
            i = u32(est);
        }
        // The estimate is off by at most one cell from rounding; settle it on the planes.
        for (var k = 0u; k < 4u; k++) {
            if i > 0u && !upper(p[a], plane(a, i << s), dir[a]) {
                i -= 1u;
            } else if i + 1u < n && upper(p[a], plane(a, (i + 1u) << s), dir[a]) {
                i += 1u;
            } else {
                break;
            }
        }
        c[a] = i;
    }
    return c;
}

fn locate_inside(p: vec3<f32>, dir: vec3<f32>) -> LeafInfo {
    if header.use_lut {
        let d = header.lut_depth;
        return locate_in_cell(cell_at_depth(p, dir, d), d, p, dir);
    }
    return descend(0u, 0u, vec3<u32>(0u), vec3<u32>(0u), 0u, p, dir);
}

// A Rust `Option<LeafInfo>`: `some` false is None (and `value` then means nothing).
struct LeafOption {
    value: LeafInfo,
    some: bool,
}

// core's `locate_leaf_toward`: the leaf of a point travelling along `dir`; none outside the
// root cube or for a non-finite point.
fn locate_leaf_toward(p: vec3<f32>, dir: vec3<f32>) -> LeafOption {
    if !is_finite3(p) || !root_contains(p, dir) {
        return LeafOption(LeafInfo(), false);
    }
    return LeafOption(locate_inside(p, dir), true);
}

// core's `locate_next`: the leaf of a point on the closed box of the leaf `last`, found from
// `last`'s cell in integers.
fn locate_next(last: LeafInfo, p: vec3<f32>, dir: vec3<f32>) -> LeafOption {
    var c = last.cell;
    for (var a = 0u; a < 3u; a++) {
        let up = p[a] == last.aabb.max[a] && dir[a] >= 0.0;
        let down = p[a] == last.aabb.min[a] && !(dir[a] >= 0.0);
        c[a] = c[a] + select(0u, 1u, up) - select(0u, 1u, down);
    }
    // Below zero wraps to a huge value: one test for both sides of the root.
    if ((c.x | c.y | c.z) >> last.depth) != 0u {
        return LeafOption(last, false);
    }
    return LeafOption(locate_in_cell(c, last.depth, p, dir), true);
}

// core's `locate_in_cell`.
fn locate_in_cell(cell: vec3<u32>, depth: u32, p: vec3<f32>, dir: vec3<f32>) -> LeafInfo {
    let d = header.lut_depth;
    if header.use_lut && depth >= d {
        let c = cell >> vec3<u32>(depth - d);
        let n = 1u << d;
        let entry = proxy[header.base + header.lut_offset + (c.z * n + c.y) * n + c.x];
        let at = entry >> LUT_DEPTH_SHIFT;
        return descend(entry & LUT_INDEX_MASK, at, cell >> vec3<u32>(depth - at), cell, depth, p, dir);
    }
    return descend(0u, 0u, vec3<u32>(0u), cell, depth, p, dir);
}

// core's `descend`: octants read from `known_cell`'s bits down to `known_depth`, from the
// cell planes below it.
fn descend(start: u32, start_depth: u32, start_cell: vec3<u32>, known_cell: vec3<u32>, known_depth: u32, p: vec3<f32>, dir: vec3<f32>) -> LeafInfo {
    var index = start;
    var depth = start_depth;
    var cell = start_cell;
    // A descent takes at most MAX_DEPTH + 1 records; the bound keeps the loop visibly finite.
    for (var guard = 0u; guard <= MAX_DEPTH; guard++) {
        let rec = node_record(index);
        if is_leaf(rec) {
            return surface_leaf(cell, depth, index, rec);
        }
        if depth >= MAX_DEPTH {
            // A validated proxy has no internal node this deep; stay total anyway.
            return empty_leaf(cell, depth, index, LABEL_NONE);
        }
        let s = MAX_DEPTH - depth - 1u;
        var octant = 0u;
        if depth < known_depth {
            let k = known_depth - depth - 1u;
            for (var a = 0u; a < 3u; a++) {
                octant |= ((known_cell[a] >> k) & 1u) << a;
            }
        } else {
            for (var a = 0u; a < 3u; a++) {
                let mid = plane(a, (2u * cell[a] + 1u) << s);
                if upper(p[a], mid, dir[a]) {
                    octant |= 1u << a;
                }
            }
        }
        cell = cell * 2u + vec3<u32>(octant & 1u, (octant >> 1u) & 1u, (octant >> 2u) & 1u);
        depth += 1u;
        if (child_mask(rec) & (1u << octant)) == 0u {
            var label = label_bits(rec, octant);
            if label > LABEL_BACK {
                label = LABEL_NONE;
            }
            return empty_leaf(cell, depth, index, label);
        }
        index = child_index(rec, octant);
    }
    return empty_leaf(cell, depth, index, LABEL_NONE);
}
