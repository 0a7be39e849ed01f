// The step, as core/src/step.rs: one particle marched leaf by leaf along x(t) -> x(t + dt).
// Read the Rust module for the rules; this file mirrors it function for function, with the
// same names (a Rust method `LeafHint::of` is `leaf_hint_of` here), the same order of
// floating-point operations. Of Rust's march observer only the collisions are reported here,
// to `observe_hit`: nothing in the plain kernel (observe_none.wgsl), the scene step's hit
// records and events in the scene kernel (observe.wgsl). A Rust `Option<T>` is a
// `TOption { value, some }`; the twins are listed, and checked, in backend-wgpu/tests/wgsl.rs.

fn respond(v: vec3<f32>, n: vec3<f32>, restitution: f32, friction: f32) -> vec3<f32> {
    let vn = dot3(v, n);
    if vn >= 0.0 {
        return v;
    }
    let v_n = n * vn;
    let v_t = v - v_n;
    let t_len = sqrt(dot3(v_t, v_t));
    let impulse = friction * (1.0 + restitution) * -vn;
    var keep = 0.0;
    if t_len > impulse {
        keep = 1.0 - impulse / t_len;
    }
    return v_t * keep - v_n * restitution;
}

fn pinch(v: vec3<f32>, n: vec3<f32>, m: vec3<f32>) -> vec3<f32> {
    let c = vec3<f32>(n.y * m.z - m.y * n.z, n.z * m.x - m.z * n.x, n.x * m.y - m.x * n.y);
    let cc = dot3(c, c);
    if cc > PINCH_PARALLEL {
        return c * (dot3(v, c) / cc);
    }
    return v - n * dot3(v, n);
}

fn face_normal(axes: u32, signs: vec3<f32>) -> vec3<f32> {
    var n = vec3<f32>(0.0);
    for (var a = 0u; a < 3u; a++) {
        if (axes & (1u << a)) != 0u {
            if signs[a] >= 0.0 {
                n[a] = -1.0;
            } else {
                n[a] = 1.0;
            }
        }
    }
    let l2 = dot3(n, n);
    if l2 > 0.0 {
        return n * (1.0 / sqrt(l2));
    }
    return n;
}

fn entry_faces(b: Aabb, x: vec3<f32>, v: vec3<f32>) -> u32 {
    var axes = 0u;
    for (var a = 0u; a < 3u; a++) {
        if (x[a] == b.min[a] && v[a] > 0.0) || (x[a] == b.max[a] && v[a] < 0.0) {
            axes |= 1u << a;
        }
    }
    return axes;
}

// core's `BoxCrossing`: where a ray crosses a box's boundary, after time `t`, at `point`
// (exactly on the faces of the axes in `axes`).
struct BoxCrossing {
    t: f32,
    point: vec3<f32>,
    axes: u32,
}

// A Rust `Option<BoxCrossing>`.
struct BoxCrossingOption {
    value: BoxCrossing,
    some: bool,
}

// Selects, as core's: per axis `(far - x) / v`, clamped below at 0, and infinity for `v == 0`
// (the quotient by zero is computed and thrown away).
fn exit_box(b: Aabb, x: vec3<f32>, v: vec3<f32>) -> BoxCrossing {
    let inf = infinity();
    var ts = vec3<f32>(inf);
    var far = vec3<f32>(0.0);
    for (var a = 0u; a < 3u; a++) {
        far[a] = select(b.min[a], b.max[a], v[a] > 0.0);
        let ta = (far[a] - x[a]) / v[a];
        ts[a] = select(select(0.0, ta, ta > 0.0), inf, v[a] == 0.0);
    }
    var t = inf;
    for (var a = 0u; a < 3u; a++) {
        t = select(t, ts[a], ts[a] < t);
    }
    let finite = is_finite(t);
    var axes = 0u;
    var p = x;
    for (var a = 0u; a < 3u; a++) {
        let on_face = ts[a] == t && finite;
        axes |= select(0u, 1u, on_face) << a;
        let along = clamp(x[a] + v[a] * t, b.min[a], b.max[a]);
        p[a] = select(along, far[a], on_face);
    }
    return BoxCrossing(t, p, axes);
}

fn enter_box(b: Aabb, x: vec3<f32>, v: vec3<f32>, limit: f32) -> BoxCrossingOption {
    var miss: BoxCrossingOption;
    miss.some = false;
    let inf = infinity();
    var near = -inf;
    var far = inf;
    var axes = 0u;
    for (var a = 0u; a < 3u; a++) {
        if v[a] == 0.0 {
            // Half-open on the upper side, as the tie rule of point location.
            if !(x[a] >= b.min[a] && x[a] < b.max[a]) {
                return miss;
            }
            continue;
        }
        let t1 = (b.min[a] - x[a]) / v[a];
        let t2 = (b.max[a] - x[a]) / v[a];
        var lo = t2;
        var hi = t1;
        if v[a] > 0.0 {
            lo = t1;
            hi = t2;
        }
        if lo > near {
            near = lo;
            axes = 1u << a;
        } else if lo == near {
            axes |= 1u << a;
        }
        if hi < far {
            far = hi;
        }
    }
    if !(near >= 0.0 && near <= far && far > 0.0 && near < limit) {
        return miss;
    }
    var p = x;
    for (var a = 0u; a < 3u; a++) {
        if (axes & (1u << a)) != 0u {
            if v[a] > 0.0 {
                p[a] = b.min[a];
            } else {
                p[a] = b.max[a];
            }
        } else {
            p[a] = clamp(x[a] + v[a] * near, b.min[a], b.max[a]);
        }
    }
    return BoxCrossingOption(BoxCrossing(near, p, axes), true);
}

fn side_of(label: u32) -> u32 {
    if label == LABEL_BACK {
        return SIDE_BACK;
    }
    return SIDE_FRONT;
}

// core's `LeafHint` is `vec2<u32>(xy, z_depth_label)`: the empty or one-sided surface leaf a
// particle ended its last step in, or zero.

// core's `LeafHint::of`: the hint for `leaf`; for a one-sided surface leaf no deeper than
// HINT_MAX_SURFACE_DEPTH its record, depth and cell; none for other surface leaves.
fn leaf_hint_of(leaf: LeafInfo) -> vec2<u32> {
    if leaf.kind == LEAF_SURFACE {
        if leaf.two_sided || leaf.depth > HINT_MAX_SURFACE_DEPTH {
            return vec2<u32>(0u);
        }
        let b = HINT_SURFACE_CELL_BITS;
        return vec2<u32>(
            leaf.node | (leaf.depth << HINT_RECORD_DEPTH_SHIFT),
            leaf.cell.x | (leaf.cell.y << b) | (leaf.cell.z << (2u * b)) | HINT_SURFACE | HINT_VALID,
        );
    }
    return vec2<u32>(
        leaf.cell.x | (leaf.cell.y << HINT_Y_SHIFT),
        leaf.cell.z | (leaf.depth << HINT_DEPTH_SHIFT) | (leaf.label << HINT_LABEL_SHIFT) | HINT_VALID,
    );
}

// core's `LeafHint::leaf`: the hinted leaf, if the hint is well formed and `x` lies strictly
// inside its box.
fn leaf_hint_leaf(hint: vec2<u32>, x: vec3<f32>) -> LeafOption {
    var none: LeafOption;
    none.some = false;
    let w = hint.y;
    if (w & HINT_VALID) == 0u {
        return none;
    }
    var leaf: LeafInfo;
    if (w & HINT_SURFACE) != 0u {
        let depth = hint.x >> HINT_RECORD_DEPTH_SHIFT;
        let node = hint.x & HINT_RECORD_MASK;
        let b = HINT_SURFACE_CELL_BITS;
        let mask = (1u << b) - 1u;
        let cell = vec3<u32>(w & mask, (w >> b) & mask, (w >> (2u * b)) & mask);
        if depth == 0u || depth > HINT_MAX_SURFACE_DEPTH || ((cell.x | cell.y | cell.z) >> depth) != 0u {
            return none;
        }
        // Rust's `nodes().get(node)`: the records lie between the header and the table.
        if node >= (header.lut_offset - HEADER_WORDS) / NODE_WORDS {
            return none;
        }
        let rec = node_record(node);
        if !is_leaf(rec) || is_two_sided(rec) {
            return none;
        }
        leaf = surface_leaf(cell, depth, node, rec);
    } else {
        let depth = (w >> HINT_DEPTH_SHIFT) & HINT_DEPTH_MASK;
        // Depth 0 would be the root, which is never a leaf.
        if depth == 0u || depth > MAX_DEPTH {
            return none;
        }
        let cell = vec3<u32>(hint.x & HINT_CELL_MASK, hint.x >> HINT_Y_SHIFT, w & HINT_CELL_MASK);
        if ((cell.x | cell.y | cell.z) >> depth) != 0u {
            return none;
        }
        let label = (w >> HINT_LABEL_SHIFT) & 3u;
        if label > LABEL_BACK {
            return none;
        }
        leaf = empty_leaf(cell, depth, NO_LEAF, label);
    }
    if !(all(x > leaf.aabb.min) && all(x < leaf.aabb.max)) {
        return none;
    }
    return LeafOption(leaf, true);
}

// core's `max_leaves_per_step`, from the same constants.
fn max_leaves_per_step(tree_depth: u32) -> u32 {
    return (LEAF_BOUND_PER_CELL << tree_depth) + LEAF_BOUND_EXTRA;
}

// core's `Particle::collisions`.
fn collisions(p: Particle) -> u32 {
    return p.flags >> COLLISION_SHIFT;
}

// Advances one particle by params.dt; returns the outcome (STEP_DONE, STEP_BLOCKED,
// STEP_BOUND_HIT or STEP_INVALID). `load_header` must have run. Starts from the leaf in
// `hint` when the particle is still strictly inside it, and leaves in `hint` the empty leaf
// the step ended in: the two settles, then the march.
fn step_particle_hinted(p: ptr<function, Particle>, params: StepParams, hint: ptr<function, vec2<u32>>) -> u32 {
    if settle_in_hinted_leaf(p, params, *hint) {
        return STEP_DONE;
    }
    // A particle outside the root has no hint; one moving away from the root stays outside.
    if all(*hint == vec2<u32>(0u)) && settle_leaving_root(p, params) {
        return STEP_DONE;
    }
    // Decoded once, for both: settle_on_plane and the march's first leaf.
    let hinted = leaf_hint_leaf(*hint, (*p).position);
    if settle_on_plane(p, params, hinted) {
        return STEP_DONE;
    }
    return march_hinted(p, params, hint, NO_LEAF, hinted);
}

// core's `settle_on_plane`: a particle in its hinted one-sided surface leaf that collides
// with the leaf's plane at most once and ends strictly inside the leaf, settled as the march
// would settle it; the hint stays.
fn settle_on_plane(p: ptr<function, Particle>, params: StepParams, hinted: LeafOption) -> bool {
    // A surface hint names only one-sided surface leaves.
    if !hinted.some || hinted.value.kind != LEAF_SURFACE || hinted.value.two_sided {
        return false;
    }
    if ((*p).side & ~SIDE_MASK) != 0u {
        return false;
    }
    let x0 = (*p).position;
    let leaf = hinted.value;
    let v = (*p).velocity + params.gravity * params.dt;
    if !(params.dt > 0.0) || !is_finite3(v) {
        return false;
    }
    var n = leaf.normal;
    if (*p).side == SIDE_BACK {
        n = -leaf.normal;
    }
    var x = x0;
    var vel = v;
    var remaining = params.dt;
    var collided = 0u;
    if dot3(v, n) < 0.0 {
        let centre = (leaf.aabb.min + leaf.aabb.max) * 0.5;
        let above = dot3(leaf.normal, x - centre) - leaf.plane_offset;
        let t = -above / dot3(leaf.normal, v);
        var reached = true;
        if t > 0.0 {
            let hit = x + v * t;
            let in_leaf = all(hit >= leaf.aabb.min) && all(hit <= leaf.aabb.max);
            if !(t < remaining) || !in_leaf {
                reached = false;
            } else {
                x = hit;
                remaining -= t;
            }
        }
        if reached {
            vel = respond(v, n, params.restitution, params.friction);
            collided = 1u;
            if !(all(x > leaf.aabb.min) && all(x < leaf.aabb.max)) || !(remaining > 0.0) {
                return false;
            }
        }
    }
    let end = x + vel * remaining;
    if !(all(end > leaf.aabb.min) && all(end < leaf.aabb.max)) {
        return false;
    }
    if collided == 1u {
        // The march's observer would not stop here: the collision leaves the particle
        // strictly inside the leaf with time left, where the march goes on.
        _ = observe_hit(x, n, v, vel, remaining, leaf.node);
    }
    (*p).position = end;
    (*p).velocity = vel;
    let count = min(collisions(*p) + collided, MAX_COLLISIONS);
    let status = (*p).flags & FLAG_STATUS_MASK & ~FLAG_STEP_STATUS;
    (*p).flags = status | (count << COLLISION_SHIFT);
    return true;
}

// core's `settle_leaving_root`: a particle outside the root cube whose path stays beyond one
// of its faces (not moving back toward it, or both ends beyond it by a margin), moved to its
// end point as the march would.
fn settle_leaving_root(p: ptr<function, Particle>, params: StepParams) -> bool {
    let x0 = (*p).position;
    let v = (*p).velocity + params.gravity * params.dt;
    let end = x0 + v * params.dt;
    let root = root_aabb();
    let zero = vec3<f32>(0.0);
    let leaving = ((x0 < root.min) & (v <= zero)) | ((x0 > root.max) & (v >= zero));
    let valid = is_finite3(x0) & is_finite3(v) & is_finite3(end) & (params.dt > 0.0);
    if !valid {
        return false;
    }
    let margin = (abs(x0) + abs(end) + abs(root.min) + abs(root.max)) * (1.0 / 4096.0);
    let beyond = ((x0 < root.min) & (end < root.min - margin)) | ((x0 > root.max) & (end > root.max + margin));
    if !any(leaving | beyond) {
        return false;
    }
    (*p).position = end;
    (*p).velocity = v;
    (*p).side = (*p).side & SIDE_MASK;
    (*p).flags &= ~FLAG_STEP_STATUS;
    return true;
}

// core's `settle_in_hinted_leaf`: the particle stays strictly inside its hinted empty leaf for
// the whole step; the checks folded into one value, the label's side computed.
fn settle_in_hinted_leaf(p: ptr<function, Particle>, params: StepParams, hint: vec2<u32>) -> bool {
    let w = hint.y;
    let depth = (w >> HINT_DEPTH_SHIFT) & HINT_DEPTH_MASK;
    let label_bits = (w >> HINT_LABEL_SHIFT) & 3u;
    let cell = vec3<u32>(hint.x & HINT_CELL_MASK, hint.x >> HINT_Y_SHIFT, w & HINT_CELL_MASK);
    // `leaf_hint_leaf`'s shape checks; `depth - 1 < MAX_DEPTH` is `1 <= depth <= MAX_DEPTH`.
    let shape_ok = ((w & (HINT_VALID | HINT_SURFACE)) == HINT_VALID) & (depth - 1u < MAX_DEPTH) & (((cell.x | cell.y | cell.z) >> depth) == 0u) & (label_bits != 3u);
    if !shape_ok {
        return false;
    }
    let b = cell_aabb(cell, depth);
    let x0 = (*p).position;
    let v = (*p).velocity + params.gravity * params.dt;
    let end = x0 + v * params.dt;
    // (`dt > 0` as the march's loop condition: unvalidated parameters take the march.)
    let settled = all((x0 > b.min) & (x0 < b.max) & (end > b.min) & (end < b.max)) & is_finite3(v) & (params.dt > 0.0);
    if !settled {
        return false;
    }
    (*p).position = end;
    (*p).velocity = v;
    // An unlabelled leaf keeps the side (normalised: no cage); a labelled one stamps it: label
    // bits 1 (front) and 2 (back) are sides 0 and 1.
    let kept = (*p).side & SIDE_MASK;
    (*p).side = select(label_bits - 1u, kept, label_bits == 0u);
    (*p).flags &= ~FLAG_STEP_STATUS;
    return true;
}

// core's `start_beside_shell`: a step that starts on a face between a surface leaf and an
// empty leaf labelled with the other side starts in the surface leaf, so that the shell rule
// decides whether it may come out there.
fn start_beside_shell(leaf: LeafInfo, x: vec3<f32>, v: vec3<f32>, side: u32) -> LeafInfo {
    if leaf.kind != LEAF_EMPTY || leaf.label == LABEL_NONE || side_of(leaf.label) == side {
        return leaf;
    }
    for (var a = 0u; a < 3u; a++) {
        let below = x[a] == leaf.aabb.min[a];
        if !below && x[a] != leaf.aabb.max[a] {
            continue;
        }
        var dir = v;
        dir[a] = select(1.0, -1.0, below);
        if root_contains(x, dir) {
            let across = locate_inside(x, dir);
            if across.kind == LEAF_SURFACE {
                return across;
            }
        }
    }
    return leaf;
}

// core's `MarchState`: the march between two leaves, field for field.
struct MarchState {
    x: vec3<f32>,
    v: vec3<f32>,
    side: u32,
    remaining: f32,
    collisions: u32,
    in_shell: bool,
    shell_entry: vec3<f32>,
    last_collided: u32,
    hit_x: vec3<f32>,
    hit_n: vec3<f32>,
    pinched: bool,
    cross_axes: u32,
    cross_signs: vec3<f32>,
    last_leaf: LeafOption,
    hinted: LeafOption,
    exits: u32,
    visited: u32,
    outcome: u32,
    blocked_once: bool,
}

// core's `NextLeaf`: the leaf the march goes through next, and whether it is the shell beside
// the point the step starts on.
struct NextLeaf {
    leaf: LeafInfo,
    beside_shell: bool,
}

// A Rust `Option<NextLeaf>`.
struct NextLeafOption {
    value: NextLeaf,
    some: bool,
}

fn start_march(p: Particle, params: StepParams, hinted: LeafOption) -> MarchState {
    let x0 = p.position;
    let v0 = p.velocity;
    var st: MarchState;
    st.x = x0;
    st.v = v0 + params.gravity * params.dt;
    st.side = p.side & SIDE_MASK;
    st.remaining = params.dt;
    st.collisions = 0u;
    st.in_shell = false;
    st.shell_entry = x0;
    st.last_collided = NO_LEAF;
    st.hit_x = x0;
    st.hit_n = vec3<f32>(0.0);
    st.pinched = false;
    st.cross_axes = 0u;
    st.cross_signs = vec3<f32>(0.0);
    st.last_leaf.some = false;
    st.hinted = hinted;
    st.exits = select(0u, p.side & SIDE_CAGE_MASK, (p.side & SIDE_CAGED) != 0u);
    st.visited = 0u;
    st.outcome = STEP_DONE;
    st.blocked_once = false;
    return st;
}

fn stop_at_leaf_bound(st: ptr<function, MarchState>) {
    (*st).outcome = STEP_BOUND_HIT;
    if (*st).in_shell {
        (*st).x = (*st).shell_entry;
    }
}

fn find_next_leaf(st: ptr<function, MarchState>) -> NextLeafOption {
    var leaf: LeafInfo;
    if (*st).hinted.some {
        leaf = (*st).hinted.value;
        (*st).hinted.some = false;
    } else {
        var next: LeafOption;
        next.some = false;
        if (*st).last_leaf.some {
            next = locate_next((*st).last_leaf.value, (*st).x, (*st).v);
        }
        if next.some {
            leaf = next.value;
        } else {
            if !root_contains((*st).x, (*st).v) {
                var none: NextLeafOption;
                none.some = false;
                return none;
            }
            leaf = locate_inside((*st).x, (*st).v);
            if (*st).visited == 1u {
                let start = start_beside_shell(leaf, (*st).x, (*st).v, (*st).side);
                return NextLeafOption(NextLeaf(start, start.kind != leaf.kind), true);
            }
        }
    }
    return NextLeafOption(NextLeaf(leaf, false), true);
}

fn enter_root(st: ptr<function, MarchState>) -> bool {
    let entry = enter_box(root_aabb(), (*st).x, (*st).v, (*st).remaining);
    if entry.some {
        (*st).x = entry.value.point;
        (*st).remaining -= entry.value.t;
        (*st).cross_axes = entry.value.axes;
        (*st).cross_signs = (*st).v;
        (*st).last_collided = NO_LEAF;
        (*st).last_leaf.some = false;
        return true;
    }
    (*st).x = (*st).x + (*st).v * (*st).remaining;
    return false;
}

fn slide_off_solid_face(st: ptr<function, MarchState>, next: NextLeaf) -> LeafInfo {
    let x = (*st).x;
    let v = (*st).v;
    var leaf = next.leaf;
    if leaf.two_sided && !next.beside_shell && entry_faces(leaf.aabb, x, v) == 0u {
        var dir = v;
        for (var a = 0u; a < 3u; a++) {
            if v[a] == 0.0 && x[a] == leaf.aabb.min[a] {
                dir[a] = -1.0;
            } else if v[a] == 0.0 && x[a] == leaf.aabb.max[a] {
                dir[a] = 1.0;
            }
        }
        if any(dir != v) {
            if !(*st).in_shell {
                (*st).in_shell = true;
                (*st).shell_entry = x;
            }
            leaf = locate_inside(x, dir);
        }
    }
    return leaf;
}

fn enter_empty_leaf(st: ptr<function, MarchState>, leaf: LeafInfo, params: StepParams) -> bool {
    let labelled = leaf.label != LABEL_NONE;
    let label_side = side_of(leaf.label);
    if labelled && (*st).in_shell && label_side != (*st).side {
        block_at_shell(st, params);
        return true;
    }
    (*st).side = select((*st).side, label_side, labelled);
    (*st).in_shell = false;
    return false;
}

fn block_at_shell(st: ptr<function, MarchState>, params: StepParams) {
    (*st).x = (*st).shell_entry;
    let n = face_normal((*st).cross_axes, (*st).cross_signs);
    let before = (*st).v;
    (*st).v = respond((*st).v, n, params.restitution, params.friction);
    (*st).collisions += 1u;
    (*st).outcome = STEP_BLOCKED;
    let stop = observe_hit((*st).x, n, before, (*st).v, (*st).remaining, NO_LEAF);
    if stop || (*st).blocked_once {
        (*st).remaining = 0.0;
    }
    (*st).blocked_once = true;
    (*st).last_leaf.some = false;
    (*st).hinted.some = false;
    (*st).last_collided = NO_LEAF;
}

fn enter_surface_leaf(st: ptr<function, MarchState>, leaf: LeafInfo, params: StepParams) -> bool {
    if !(*st).in_shell {
        (*st).in_shell = true;
        (*st).shell_entry = (*st).x;
    }
    if leaf.node == (*st).last_collided {
        return false;
    }
    let n = collision_normal(st, leaf);
    if !(dot3((*st).v, n) < 0.0) {
        return false;
    }
    if !reach_plane(st, leaf) {
        return false;
    }
    if leaf.two_sided {
        let slab = slab_entry(st, leaf);
        if slab != 0u {
            // Into the slab: the march walks it next (`walk_in_slab`).
            (*st).exits = slab;
            return true;
        }
    }
    collide(st, leaf, n, params);
    if all((*st).x > leaf.aabb.min) && all((*st).x < leaf.aabb.max) {
        (*st).hinted = LeafOption(leaf, true);
    }
    return true;
}

// core's `slab_entry`: the cage bits of the slab a particle entering a solid leaf through
// one face with clearance goes into, or 0 to collide at the face.
fn slab_entry(st: ptr<function, MarchState>, leaf: LeafInfo) -> u32 {
    let axes = entry_faces(leaf.aabb, (*st).x, (*st).v);
    if countOneBits(axes) != 1u {
        return 0u;
    }
    let within = ((*st).x > leaf.aabb.min) & ((*st).x < leaf.aabb.max);
    let mask = select(0u, 1u, within.x) | select(0u, 2u, within.y) | select(0u, 4u, within.z);
    if (mask | axes) != 7u {
        return 0u;
    }
    let axis = firstTrailingBit(axes);
    let upper = (*st).v[axis] < 0.0;
    let c = clearance(node_record(leaf.node), 2u * axis + select(0u, 1u, upper));
    if c == 0u {
        return 0u;
    }
    return SIDE_CAGED | SIDE_SLAB | side_exit(axis, upper);
}

fn reach_plane(st: ptr<function, MarchState>, leaf: LeafInfo) -> bool {
    if leaf.two_sided {
        return true;
    }
    let centre = (leaf.aabb.min + leaf.aabb.max) * 0.5;
    let above = dot3(leaf.normal, (*st).x - centre) - leaf.plane_offset;
    let t = -above / dot3(leaf.normal, (*st).v);
    if !(t > 0.0) {
        return true;
    }
    let hit = (*st).x + (*st).v * t;
    let in_leaf = all(hit >= leaf.aabb.min) && all(hit <= leaf.aabb.max);
    if !(t < (*st).remaining) || !in_leaf {
        return false;
    }
    (*st).x = hit;
    (*st).remaining -= t;
    return true;
}

fn collision_normal(st: ptr<function, MarchState>, leaf: LeafInfo) -> vec3<f32> {
    let x = (*st).x;
    let inside = all(x > leaf.aabb.min) && all(x < leaf.aabb.max);
    if leaf.two_sided && !inside {
        return face_normal(entry_faces(leaf.aabb, (*st).x, (*st).v), (*st).v);
    }
    if (*st).side == SIDE_BACK {
        return -leaf.normal;
    }
    return leaf.normal;
}

fn collide(st: ptr<function, MarchState>, leaf: LeafInfo, n: vec3<f32>, params: StepParams) {
    let before = (*st).v;
    (*st).v = respond((*st).v, n, params.restitution, params.friction);
    let gap = (*st).x - (*st).hit_x;
    let diagonal = leaf.aabb.max - leaf.aabb.min;
    let facing = dot3(n, (*st).hit_n) < 0.0 && dot3(gap, gap) <= dot3(diagonal, diagonal);
    if (*st).collisions > 0u && (all((*st).x == (*st).hit_x) || facing) && dot3((*st).v, (*st).hit_n) < 0.0 {
        // Pinched; pinched again at the same point, it stops there.
        if (*st).pinched {
            (*st).v = vec3<f32>(0.0);
        } else {
            (*st).v = pinch((*st).v, n, (*st).hit_n);
        }
        (*st).pinched = true;
    } else {
        (*st).pinched = false;
    }
    (*st).hit_x = (*st).x;
    (*st).hit_n = n;
    (*st).collisions += 1u;
    (*st).last_collided = leaf.node;
    if observe_hit((*st).x, n, before, (*st).v, (*st).remaining, leaf.node) {
        // Every loop of the march ends when the time is up; the particle stays at the hit.
        (*st).remaining = 0.0;
    }
}

// core's `walk_in_cage`: a caged particle's step before the march. In its cage it moves
// freely, bounces off every face that is not an exit, and leaves through an exit out of the
// shell. Some(cage) when the step ended in the cage; none when the march goes on (from the
// exit point, or, not strictly inside a solid leaf, from where it is, caged no more).
fn walk_in_cage(st: ptr<function, MarchState>, params: StepParams) -> LeafOption {
    var none: LeafOption;
    none.some = false;
    var found = false;
    var cage: LeafInfo;
    if root_contains((*st).x, (*st).v) {
        cage = locate_inside((*st).x, (*st).v);
        let inside = all((*st).x > cage.aabb.min) && all((*st).x < cage.aabb.max);
        found = cage.kind == LEAF_SURFACE && cage.two_sided && inside;
    }
    if !found {
        (*st).exits = 0u;
        return none;
    }
    (*st).in_shell = true;
    (*st).shell_entry = (*st).x;
    (*st).hinted.some = false;
    if ((*st).exits & SIDE_SLAB) != 0u {
        return walk_in_slab(st, cage, false, params);
    }
    let budget = max_leaves_per_step(header.tree_depth);
    while (*st).remaining > 0.0 {
        if (*st).visited >= budget {
            stop_at_leaf_bound(st);
            return LeafOption(cage, true);
        }
        (*st).visited += 1u;
        let moved = move_in_box(st, cage.aabb);
        if !moved.some {
            return LeafOption(cage, true);
        }
        let exit = moved.value;
        let axis = min(firstTrailingBit(exit.axes), 2u);
        let upper = (*st).v[axis] > 0.0;
        if countOneBits(exit.axes) == 1u && ((*st).exits & side_exit(axis, upper)) != 0u {
            // On the exit face, and strictly inside it: on an edge of the cage, the tie rule
            // would find the leaf across the edge, not the face.
            var x = strictly_inside((*st).x, cage.aabb);
            x[axis] = (*st).x[axis];
            // An exit leads into an empty leaf; a stale cage's face that does not is a wall.
            let beyond = locate_next(cage, x, (*st).v);
            if beyond.some && beyond.value.kind == LEAF_EMPTY {
                // Out by an exit, and out of the shell: the leaf beyond stamps it.
                (*st).x = x;
                (*st).exits = 0u;
                (*st).in_shell = false;
                (*st).cross_axes = exit.axes;
                (*st).cross_signs = (*st).v;
                (*st).last_leaf = LeafOption(cage, true);
                return none;
            }
        }
        collide(st, cage, face_normal(exit.axes, (*st).v), params);
    }
    return LeafOption(cage, true);
}

// core's `move_in_box`: a caged particle's move in its cage's box; no value when the step
// ends in the box.
fn move_in_box(st: ptr<function, MarchState>, b: Aabb) -> BoxCrossingOption {
    var none: BoxCrossingOption;
    none.some = false;
    let end = (*st).x + (*st).v * (*st).remaining;
    if all(end > b.min) && all(end < b.max) {
        (*st).x = end;
        return none;
    }
    let exit = exit_box(b, (*st).x, (*st).v);
    if exit.t >= (*st).remaining {
        (*st).x = clamp((*st).x + (*st).v * (*st).remaining, b.min, b.max);
        return none;
    }
    (*st).x = exit.point;
    (*st).remaining -= exit.t;
    return BoxCrossingOption(exit, true);
}

// core's `walk_in_slab`: a particle in the slab of a solid leaf moves in it, collides at its
// inner side, and leaves through the face it came in by, or is put back onto that face at a
// side of the slab.
fn walk_in_slab(st: ptr<function, MarchState>, leaf: LeafInfo, entered: bool, params: StepParams) -> LeafOption {
    var none: LeafOption;
    none.some = false;
    let face = min(firstTrailingBit(((*st).exits & SIDE_EXITS_MASK) >> SIDE_EXITS_SHIFT), 5u);
    let axis = face >> 1u;
    let upper = (face & 1u) != 0u;
    let c = clearance(node_record(leaf.node), face);
    let edge = leaf.aabb.max[axis] - leaf.aabb.min[axis];
    let depth = edge * (f32(c) * (1.0 / f32(CLEARANCE_STEPS)));
    var slab = leaf;
    var plane: f32;
    if upper {
        slab.aabb.min[axis] = leaf.aabb.max[axis] - depth;
        plane = leaf.aabb.max[axis];
    } else {
        slab.aabb.max[axis] = leaf.aabb.min[axis] + depth;
        plane = leaf.aabb.min[axis];
    }
    if !entered {
        let inside = all((*st).x > slab.aabb.min) && all((*st).x < slab.aabb.max);
        if c == 0u || !inside {
            (*st).exits = 0u;
            return none;
        }
    }
    let budget = max_leaves_per_step(header.tree_depth);
    while (*st).remaining > 0.0 {
        if (*st).visited >= budget {
            if entered {
                (*st).exits = 0u;
                return none;
            }
            stop_at_leaf_bound(st);
            return LeafOption(slab, true);
        }
        (*st).visited += 1u;
        let moved = move_in_box(st, slab.aabb);
        if !moved.some {
            return LeafOption(slab, true);
        }
        let exit = moved.value;
        let through_face = (exit.axes & (1u << axis)) != 0u && ((*st).v[axis] > 0.0) == upper;
        let sides = exit.axes & ~(1u << axis);
        if through_face || sides != 0u {
            var x = (*st).x;
            if through_face {
                x = strictly_inside(x, slab.aabb);
            }
            x[axis] = plane;
            (*st).x = x;
            (*st).exits = 0u;
            (*st).shell_entry = x;
            var out = (*st).v;
            out[axis] = select(-1.0, 1.0, upper);
            (*st).cross_axes = 1u << axis;
            (*st).cross_signs = out;
            (*st).last_collided = NO_LEAF;
            (*st).last_leaf.some = false;
            if root_contains(x, out) {
                (*st).hinted = LeafOption(locate_inside(x, out), true);
            } else {
                (*st).hinted.some = false;
            }
            return none;
        }
        collide(st, slab, face_normal(exit.axes, (*st).v), params);
    }
    return LeafOption(slab, true);
}

// particle.rs's `side_exit`: the exit bit of a cage's face across `axis` on its upper or
// lower side.
fn side_exit(axis: u32, upper: bool) -> u32 {
    return 1u << (SIDE_EXITS_SHIFT + 2u * axis + select(0u, 1u, upper));
}

// core's `next_float`: the next float up or down, never a subnormal.
fn next_float(x: f32, up: bool) -> f32 {
    if x == 0.0 {
        return select(-F32_MIN_POSITIVE, F32_MIN_POSITIVE, up);
    }
    if abs(x) == F32_MIN_POSITIVE && (x > 0.0) != up {
        return 0.0;
    }
    let bits = bitcast<u32>(x);
    return bitcast<f32>(select(bits - 1u, bits + 1u, (x > 0.0) == up));
}

// core's `strictly_inside`: `x` moved strictly inside the box where it lies on a face.
fn strictly_inside(x: vec3<f32>, b: Aabb) -> vec3<f32> {
    var y = x;
    for (var a = 0u; a < 3u; a++) {
        if !(x[a] > b.min[a]) {
            y[a] = next_float(b.min[a], true);
        } else if !(x[a] < b.max[a]) {
            y[a] = next_float(b.max[a], false);
        }
    }
    return y;
}

fn travel_through_leaf(st: ptr<function, MarchState>, leaf: LeafInfo, hint: ptr<function, vec2<u32>>) -> bool {
    let end = (*st).x + (*st).v * (*st).remaining;
    if all(end > leaf.aabb.min) && all(end < leaf.aabb.max) {
        (*st).x = end;
        *hint = leaf_hint_of(leaf);
        return true;
    }
    let exit = exit_box(leaf.aabb, (*st).x, (*st).v);
    if exit.t >= (*st).remaining {
        (*st).x = clamp((*st).x + (*st).v * (*st).remaining, leaf.aabb.min, leaf.aabb.max);
        *hint = leaf_hint_of(leaf);
        return true;
    }
    (*st).x = exit.point;
    (*st).remaining -= exit.t;
    (*st).cross_axes = exit.axes;
    (*st).cross_signs = (*st).v;
    (*st).last_collided = NO_LEAF;
    return false;
}

fn finish_march(p: ptr<function, Particle>, st: ptr<function, MarchState>, cage: LeafOption) -> u32 {
    if !is_finite3((*st).x) || !is_finite3((*st).v) {
        (*p).flags |= FLAG_INVALID;
        return STEP_INVALID;
    }
    var x = (*st).x;
    if cage.some {
        // Still caged: strictly inside the cage, so that the next step finds it there.
        x = strictly_inside(x, cage.value.aabb);
    }
    (*p).position = x;
    (*p).velocity = (*st).v;
    (*p).side = (*st).side | select(0u, (*st).exits, cage.some);
    let count = min(collisions(*p) + (*st).collisions, MAX_COLLISIONS);
    var status = (*p).flags & FLAG_STATUS_MASK & ~FLAG_STEP_STATUS;
    if (*st).outcome == STEP_BLOCKED {
        status |= FLAG_BLOCKED;
    } else if (*st).outcome == STEP_BOUND_HIT {
        status |= FLAG_BOUND_HIT;
    }
    (*p).flags = status | (count << COLLISION_SHIFT);
    return (*st).outcome;
}

// core's `march_after`: the march of a particle that has just collided in surface leaf
// `collided` (or NO_LEAF) and has not left it; it does not collide there again before it
// crosses a face. The scene step goes on from a contact with it.
fn march_after(p: ptr<function, Particle>, params: StepParams, hint: ptr<function, vec2<u32>>, collided: u32) -> u32 {
    let hinted = leaf_hint_leaf(*hint, (*p).position);
    return march_hinted(p, params, hint, collided, hinted);
}

// core's `march_hinted`: `march_after` with the hint already decoded (`hinted`, the hint's
// leaf at the particle's position).
fn march_hinted(p: ptr<function, Particle>, params: StepParams, hint: ptr<function, vec2<u32>>, collided: u32, hinted: LeafOption) -> u32 {
    *hint = vec2<u32>(0u);
    if !is_finite3((*p).position) || !is_finite3((*p).velocity) {
        (*p).flags |= FLAG_INVALID;
        return STEP_INVALID;
    }
    var st = start_march(*p, params, hinted);
    st.last_collided = collided;
    if st.exits != 0u {
        let cage = walk_in_cage(&st, params);
        if cage.some {
            return finish_march(p, &st, cage);
        }
    }
    let budget = max_leaves_per_step(header.tree_depth);
    while st.remaining > 0.0 {
        if st.visited >= budget {
            stop_at_leaf_bound(&st);
            break;
        }
        st.visited += 1u;
        let next = find_next_leaf(&st);
        if !next.some {
            if enter_root(&st) {
                continue;
            }
            break;
        }
        let leaf = slide_off_solid_face(&st, next.value);
        st.last_leaf = LeafOption(leaf, true);
        if leaf.kind == LEAF_EMPTY {
            let blocked = enter_empty_leaf(&st, leaf, params);
            if blocked {
                continue;
            }
        } else {
            let collided = enter_surface_leaf(&st, leaf, params);
            if collided {
                if st.exits != 0u {
                    let slab = walk_in_slab(&st, leaf, true, params);
                    if slab.some {
                        return finish_march(p, &st, slab);
                    }
                }
                continue;
            }
        }
        let ended = travel_through_leaf(&st, leaf, hint);
        if ended {
            break;
        }
    }
    var none: LeafOption;
    none.some = false;
    return finish_march(p, &st, none);
}
