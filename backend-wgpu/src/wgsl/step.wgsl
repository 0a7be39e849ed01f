// The step, as core/src/step.rs: one particle marched leaf by leaf along x(t) -> x(t + dt).
// Read the Rust module for the rules; this file mirrors it function for function, with the
// same names, the same order of floating-point operations, and no tracing.

// core's `Particle`: 32 bytes, vec3 members at offsets 0 and 16.
struct Particle {
    position: vec3<f32>,
    side: u32,
    velocity: vec3<f32>,
    flags: u32,
}

// core's `StepParams`: 32 bytes.
struct StepParams {
    gravity: vec3<f32>,
    dt: f32,
    restitution: f32,
    friction: f32,
    _pad: vec2<u32>,
}

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

// Where a ray crosses a box face: time, point (exactly on the faces in `axes`), and whether
// it does at all (enter_box only).
struct BoxCrossing {
    t: f32,
    p: vec3<f32>,
    axes: u32,
    hit: bool,
}

fn exit_box(b: Aabb, x: vec3<f32>, v: vec3<f32>) -> BoxCrossing {
    let inf = infinity();
    var t = inf;
    var ts = vec3<f32>(inf);
    for (var a = 0u; a < 3u; a++) {
        var ta = inf;
        if v[a] > 0.0 {
            ta = (b.max[a] - x[a]) / v[a];
        } else if v[a] < 0.0 {
            ta = (b.min[a] - x[a]) / v[a];
        }
        if ta > 0.0 {
            ts[a] = ta;
        } else {
            ts[a] = 0.0;
        }
        if ts[a] < t {
            t = ts[a];
        }
    }
    var axes = 0u;
    var p = x;
    for (var a = 0u; a < 3u; a++) {
        if ts[a] == t && is_finite(t) {
            axes |= 1u << a;
            if v[a] > 0.0 {
                p[a] = b.max[a];
            } else {
                p[a] = b.min[a];
            }
        } else {
            p[a] = clamp(x[a] + v[a] * t, b.min[a], b.max[a]);
        }
    }
    return BoxCrossing(t, p, axes, true);
}

fn enter_box(b: Aabb, x: vec3<f32>, v: vec3<f32>, limit: f32) -> BoxCrossing {
    let miss = BoxCrossing(0.0, x, 0u, false);
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
    return BoxCrossing(near, p, axes, true);
}

// core's `LeafHint`, as `vec2<u32>(xy, z_depth_label)`: the empty leaf a particle ended its
// last step in, or zero.
fn hint_of(leaf: LeafInfo) -> vec2<u32> {
    if leaf.kind != LEAF_EMPTY {
        return vec2<u32>(0u);
    }
    return vec2<u32>(
        leaf.cell.x | (leaf.cell.y << HINT_Y_SHIFT),
        leaf.cell.z | (leaf.depth << HINT_DEPTH_SHIFT) | (leaf.label << HINT_LABEL_SHIFT) | HINT_VALID,
    );
}

struct HintedLeaf {
    leaf: LeafInfo,
    hit: bool,
}

// core's `LeafHint::leaf`: the hinted leaf, if the hint is well formed and `x` lies strictly
// inside its box.
fn hint_leaf(hint: vec2<u32>, x: vec3<f32>) -> HintedLeaf {
    var out: HintedLeaf;
    out.hit = false;
    let w = hint.y;
    let depth = (w >> HINT_DEPTH_SHIFT) & HINT_DEPTH_MASK;
    // Depth 0 would be the root, which is never a leaf.
    if (w & HINT_VALID) == 0u || depth == 0u || depth > MAX_DEPTH {
        return out;
    }
    let cell = vec3<u32>(hint.x & HINT_CELL_MASK, hint.x >> HINT_Y_SHIFT, w & HINT_CELL_MASK);
    if ((cell.x | cell.y | cell.z) >> depth) != 0u {
        return out;
    }
    let label = (w >> HINT_LABEL_SHIFT) & 3u;
    if label > LABEL_BACK {
        return out;
    }
    let leaf = empty_leaf(cell, depth, NO_LEAF, label);
    if !(all(x > leaf.aabb.min) && all(x < leaf.aabb.max)) {
        return out;
    }
    out.leaf = leaf;
    out.hit = true;
    return out;
}

fn side_of(label: u32) -> u32 {
    if label == LABEL_BACK {
        return SIDE_BACK;
    }
    return SIDE_FRONT;
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

fn max_leaves_per_step(tree_depth: u32) -> u32 {
    return (4u << tree_depth) + 64u;
}

fn collisions(p: Particle) -> u32 {
    return p.flags >> COLLISION_SHIFT;
}

// Advances one particle by params.dt; returns the outcome (STEP_DONE, STEP_BLOCKED,
// STEP_BOUND_HIT or STEP_INVALID). `load_header` must have run. Starts from the leaf in
// `hint` when the particle is still strictly inside it, and leaves in `hint` the empty leaf
// the step ended in (core's `step_particle_hinted`).
fn step_particle(p: ptr<function, Particle>, params: StepParams, hint: ptr<function, vec2<u32>>) -> u32 {
    let start_hint = *hint;
    *hint = vec2<u32>(0u);
    let x0 = (*p).position;
    let v0 = (*p).velocity;
    if !is_finite3(x0) || !is_finite3(v0) {
        (*p).flags |= FLAG_INVALID;
        return STEP_INVALID;
    }
    let e = params.restitution;
    let mu = params.friction;
    var v = v0 + params.gravity * params.dt;
    var x = x0;
    var side = SIDE_FRONT;
    if (*p).side == SIDE_BACK {
        side = SIDE_BACK;
    }
    // The common case, settled before the march is set up: the particle stays strictly inside
    // its hinted empty leaf for the whole step. This is what the march below does for it, in
    // the same operations (its first leaf, the label, the end-point test, the flags).
    var hinted = hint_leaf(start_hint, x0);
    if hinted.hit {
        let end = x0 + v * params.dt;
        let inside = all(end > hinted.leaf.aabb.min) && all(end < hinted.leaf.aabb.max);
        // (`dt > 0` as the loop's condition: unvalidated parameters take the loop.)
        if params.dt > 0.0 && inside && is_finite3(v) {
            (*p).position = end;
            (*p).velocity = v;
            if hinted.leaf.label != LABEL_NONE {
                (*p).side = side_of(hinted.leaf.label);
            } else {
                (*p).side = side;
            }
            (*p).flags &= ~FLAG_STEP_STATUS;
            *hint = start_hint;
            return STEP_DONE;
        }
    }
    // Core's `settle_leaving_root`: a particle with no hint, outside the root beyond one of
    // its faces and not moving back toward it, never enters the root this step.
    if all(start_hint == vec2<u32>(0u)) {
        let end = x0 + v * params.dt;
        let root = root_aabb();
        let zero = vec3<f32>(0.0);
        let leaving = ((x0 < root.min) & (v <= zero)) | ((x0 > root.max) & (v >= zero));
        if any(leaving) && is_finite3(v) && is_finite3(end) && params.dt > 0.0 {
            (*p).position = end;
            (*p).velocity = v;
            (*p).side = side;
            (*p).flags &= ~FLAG_STEP_STATUS;
            return STEP_DONE;
        }
    }
    var remaining = params.dt;
    var n_collisions = 0u;
    var in_shell = false;
    var shell_entry = x0;
    var last_collided = NO_LEAF;
    // Where the last collision was (when `n_collisions > 0`) and the normal it used, and
    // whether it pinched (`pinch`).
    var hit_x = x0;
    var hit_n = vec3<f32>(0.0);
    var pinched = false;
    // The face the particle last crossed (axes) and the signs of its velocity then.
    var cross_axes = 0u;
    var cross_signs = vec3<f32>(0.0);
    // The leaf the particle was last in, while it is on that leaf's closed box.
    var last_leaf = empty_leaf(vec3<u32>(0u), 0u, NO_LEAF, LABEL_NONE);
    var has_last_leaf = false;
    var outcome = STEP_DONE;
    let budget = max_leaves_per_step(header.tree_depth);
    var visited = 0u;
    while remaining > 0.0 {
        if visited >= budget {
            outcome = STEP_BOUND_HIT;
            if in_shell {
                x = shell_entry;
            }
            break;
        }
        visited += 1u;
        // Whether this leaf is the shell beside the point the step starts on.
        var beside_shell = false;
        // Only the first leaf of a step can come from the hint: the particle has not moved yet.
        // After it, the particle is on the closed box of the leaf it was last in, and the next
        // leaf is found from that leaf's cell.
        var next = NextLeaf(last_leaf, false);
        if has_last_leaf {
            next = locate_next(last_leaf, x, v);
        }
        var leaf: LeafInfo;
        if hinted.hit {
            leaf = hinted.leaf;
            hinted.hit = false;
        } else if next.hit {
            leaf = next.leaf;
        } else {
            if !root_contains(x, v) {
                let entry = enter_box(root_aabb(), x, v, remaining);
                if entry.hit {
                    x = entry.p;
                    remaining -= entry.t;
                    cross_axes = entry.axes;
                    cross_signs = v;
                    last_collided = NO_LEAF;
                    has_last_leaf = false;
                    continue;
                }
                x = x + v * remaining;
                break;
            }
            leaf = locate_inside(x, v);
            if visited == 1u {
                let start = start_beside_shell(leaf, x, v, side);
                beside_shell = start.kind != leaf.kind;
                leaf = start;
            }
        }
        if leaf.two_sided && !beside_shell && entry_faces(leaf.aabb, x, v) == 0u {
            // A particle sliding along a face of a solid leaf (no velocity across it), and not
            // entering through another, is not in the leaf: locate it on the face's outer side.
            var dir = v;
            for (var a = 0u; a < 3u; a++) {
                if v[a] == 0.0 && x[a] == leaf.aabb.min[a] {
                    dir[a] = -1.0;
                } else if v[a] == 0.0 && x[a] == leaf.aabb.max[a] {
                    dir[a] = 1.0;
                }
            }
            if any(dir != v) {
                leaf = locate_inside(x, dir);
            }
        }
        last_leaf = leaf;
        has_last_leaf = true;
        if leaf.kind == LEAF_EMPTY {
            if leaf.label != LABEL_NONE {
                let label_side = side_of(leaf.label);
                if in_shell && label_side != side {
                    x = shell_entry;
                    v = respond(v, face_normal(cross_axes, cross_signs), e, mu);
                    n_collisions += 1u;
                    outcome = STEP_BLOCKED;
                    break;
                }
                side = label_side;
            }
            in_shell = false;
        } else {
            if !in_shell {
                in_shell = true;
                shell_entry = x;
            }
            if leaf.node != last_collided {
                var n = leaf.normal;
                if leaf.two_sided {
                    // Solid from every side: the faces it is entering through, found from
                    // the box, so a particle resting on one at the start of a step counts.
                    n = face_normal(entry_faces(leaf.aabb, x, v), v);
                } else if side == SIDE_BACK {
                    n = -leaf.normal;
                }
                if dot3(v, n) < 0.0 {
                    v = respond(v, n, e, mu);
                    if n_collisions > 0u && all(x == hit_x) && dot3(v, hit_n) < 0.0 {
                        // Pinched; pinched again at the same point, it stops there.
                        if pinched {
                            v = vec3<f32>(0.0);
                        } else {
                            v = pinch(v, n, hit_n);
                        }
                        pinched = true;
                    } else {
                        pinched = false;
                    }
                    hit_x = x;
                    hit_n = n;
                    n_collisions += 1u;
                    last_collided = leaf.node;
                    continue;
                }
            }
        }
        // Most steps end in the leaf they start in: an end point strictly inside the box
        // settles it without the exit time (the segment stays in the convex box).
        let end = x + v * remaining;
        if all(end > leaf.aabb.min) && all(end < leaf.aabb.max) {
            x = end;
            *hint = hint_of(leaf);
            break;
        }
        let exit = exit_box(leaf.aabb, x, v);
        if exit.t >= remaining {
            x = clamp(x + v * remaining, leaf.aabb.min, leaf.aabb.max);
            *hint = hint_of(leaf);
            break;
        }
        x = exit.p;
        remaining -= exit.t;
        cross_axes = exit.axes;
        cross_signs = v;
        last_collided = NO_LEAF;
    }
    if !is_finite3(x) || !is_finite3(v) {
        (*p).flags |= FLAG_INVALID;
        return STEP_INVALID;
    }
    (*p).position = x;
    (*p).velocity = v;
    (*p).side = side;
    let count = min(collisions(*p) + n_collisions, MAX_COLLISIONS);
    var status = (*p).flags & FLAG_STATUS_MASK & ~FLAG_STEP_STATUS;
    if outcome == STEP_BLOCKED {
        status |= FLAG_BLOCKED;
    } else if outcome == STEP_BOUND_HIT {
        status |= FLAG_BOUND_HIT;
    }
    (*p).flags = status | (count << COLLISION_SHIFT);
    return outcome;
}
