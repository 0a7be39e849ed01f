// The scene step, as core/src/scene.rs: a particle marched in each instance's frame, from its
// start in the start pose to its end in the end pose; alone near one static instance, the
// whole step there; otherwise in rounds. Read the Rust module for the rules; this file
// mirrors it function for function (a Rust closure is a function here, a walk of the broad
// phase is a loop over `broad_walk_next`), with the same order of floating-point operations.

// core's `SceneSides`, `SceneHint` and `SceneSlots`.
struct SceneSides {
    hint: vec2<u32>,
    hint_instance: u32,
    slots: array<u32, SIDE_SLOTS>,
    _pad: u32,
}

struct SceneHint {
    hint: vec2<u32>,
    hint_instance: u32,
    first_slot: u32,
}

struct SceneSlots {
    slots: array<u32, 7>,
    _pad: u32,
}

fn scene_sides_join(h: SceneHint, s: SceneSlots) -> SceneSides {
    var all: SceneSides;
    all.hint = h.hint;
    all.hint_instance = h.hint_instance;
    all.slots[0] = h.first_slot;
    for (var k = 1u; k < SIDE_SLOTS; k++) {
        all.slots[k] = s.slots[k - 1u];
    }
    all._pad = 0u;
    return all;
}

fn scene_sides_split(all: SceneSides, h: ptr<function, SceneHint>, s: ptr<function, SceneSlots>) {
    (*h).hint = all.hint;
    (*h).hint_instance = all.hint_instance;
    (*h).first_slot = all.slots[0];
    for (var k = 1u; k < SIDE_SLOTS; k++) {
        (*s).slots[k - 1u] = all.slots[k];
    }
    (*s)._pad = 0u;
}

// A Rust `Option<u32>`.
struct U32Option {
    value: u32,
    some: bool,
}

fn commit(slots: ptr<function, array<u32, SIDE_SLOTS>>, instance: u32, side: u32, required: bool) -> bool {
    let word = (instance << SLOT_INSTANCE_SHIFT) | select(0u, SLOT_REQUIRED, required) | (side & SLOT_SIDE_MASK);
    var free = SIDE_SLOTS;
    var optional = SIDE_SLOTS;
    for (var k = 0u; k < SIDE_SLOTS; k++) {
        let s = (*slots)[k];
        if s == EMPTY_SLOT {
            if free == SIDE_SLOTS {
                free = k;
            }
        } else if (s >> SLOT_INSTANCE_SHIFT) == instance {
            (*slots)[k] = word;
            return true;
        } else if (s & SLOT_REQUIRED) == 0u {
            optional = k;
        }
    }
    if free != SIDE_SLOTS {
        (*slots)[free] = word;
        return true;
    }
    if optional != SIDE_SLOTS && required {
        (*slots)[optional] = word;
        return true;
    }
    // No room for a side that may be derived again: dropping it loses nothing.
    return !required;
}

fn optional_slots(slots: array<u32, SIDE_SLOTS>) -> array<u32, SIDE_SLOTS> {
    var out = slots;
    for (var k = 0u; k < SIDE_SLOTS; k++) {
        if out[k] != EMPTY_SLOT {
            out[k] = out[k] & ~SLOT_REQUIRED;
        }
    }
    return out;
}

fn slot_side(slots: array<u32, SIDE_SLOTS>, instance: u32) -> U32Option {
    for (var k = 0u; k < SIDE_SLOTS; k++) {
        let s = slots[k];
        if s != EMPTY_SLOT && (s >> SLOT_INSTANCE_SHIFT) == instance {
            return U32Option(s & SLOT_SIDE_MASK, true);
        }
    }
    return U32Option(0u, false);
}

// core's `kept_side`: the kept side, unless the instance was just shown (INSTANCE_SHOWN).
fn kept_side(inst: Instance, slots: array<u32, SIDE_SLOTS>, c: u32) -> U32Option {
    if (inst.flags & INSTANCE_SHOWN) != 0u {
        return U32Option(0u, false);
    }
    return slot_side(slots, c);
}

fn first_side(slots: array<u32, SIDE_SLOTS>, otherwise: u32) -> u32 {
    for (var k = 0u; k < SIDE_SLOTS; k++) {
        if slots[k] != EMPTY_SLOT {
            return slots[k] & SLOT_SIDE_MASK;
        }
    }
    return otherwise;
}

// core's `pair_support_scene`: the support of the static instance the grain's scene hint
// holds, in its frame, the normal turned to the world.
fn pair_support_scene(p: Particle, hint: SceneHint, slots: SceneSlots) -> vec4<f32> {
    let c = hint.hint_instance;
    if c >= instance_count() {
        return vec4<f32>(0.0);
    }
    let inst = load_instance(c);
    if !instance_is_active(inst) || !instance_is_static(inst) {
        return vec4<f32>(0.0);
    }
    let side = kept_side(inst, scene_sides_join(hint, slots).slots, c);
    if !side.some {
        return vec4<f32>(0.0);
    }
    use_proxy(inst.proxy);
    var local = p;
    local.position = pose_to_local(inst.start, p.position);
    local.side = side.value;
    let sup = pair_support(local, hint.hint);
    if sup.w == 0.0 {
        return sup;
    }
    return vec4<f32>(pose_normal_to_world(inst.start, sup.xyz), sup.w);
}

// core's `BroadWalk`: a walk of the broad phase for the instances whose swept boxes meet a box.
struct BroadWalk {
    stack: array<u32, BROAD_STACK>,
    top: u32,
}

fn broad_walk_new() -> BroadWalk {
    var walk: BroadWalk;
    walk.top = select(0u, 1u, scene_params.node_count > 0u);
    walk.stack[0] = 0u;
    return walk;
}

// The next instance whose swept box meets `b`, or NO_INSTANCE when the walk is over.
fn broad_walk_next(walk: ptr<function, BroadWalk>, b: Aabb) -> u32 {
    while (*walk).top > 0u {
        (*walk).top -= 1u;
        let i = (*walk).stack[(*walk).top];
        let node = load_broad_node(i);
        if any(node.min > b.max) || any(node.max < b.min) {
            continue;
        }
        if node.kind == BROAD_LEAF {
            return node.index;
        }
        (*walk).stack[(*walk).top] = node.index;
        (*walk).stack[(*walk).top + 1u] = i + 1u;
        (*walk).top += 2u;
    }
    return NO_INSTANCE;
}

// core's `SceneView::count_candidates`: how many, and the first.
struct Candidates {
    count: u32,
    first: u32,
}

fn count_candidates(b: Aabb) -> Candidates {
    var out = Candidates(0u, 0u);
    var walk = broad_walk_new();
    loop {
        let c = broad_walk_next(&walk, b);
        if c == NO_INSTANCE {
            break;
        }
        if out.count == 0u {
            out.first = c;
        }
        out.count += 1u;
    }
    return out;
}

// core's `ProxyView::finest_leaf_size`, of the loaded proxy.
fn finest_leaf_size() -> f32 {
    return header.root_size / f32(1u << header.dmax);
}

fn local_radius(root: Aabb) -> f32 {
    return length3(vmax(abs(root.min), abs(root.max)));
}

// core's `initial_side` (the loaded proxy): in an empty leaf its label, in a surface leaf the
// side of its mean plane, front outside the root cube.
fn initial_side(position: vec3<f32>) -> u32 {
    let zero = vec3<f32>(0.0);
    if !is_finite3(position) || !root_contains(position, zero) {
        return SIDE_FRONT;
    }
    let leaf = locate_inside(position, zero);
    if leaf.kind == LEAF_SURFACE {
        let center = (leaf.aabb.min + leaf.aabb.max) * 0.5;
        if dot3(leaf.normal, position - center) >= leaf.plane_offset {
            return SIDE_FRONT;
        }
        return SIDE_BACK;
    }
    return side_of(leaf.label);
}

fn substeps(inst: Instance, v: vec3<f32>, u0: f32, u1: f32, dt: f32) -> u32 {
    let f = u1 - u0;
    let theta = 2.0 * inst.half_turn * f;
    let sigma = abs(inst.end.scale - inst.start.scale) * f;
    if theta == 0.0 && sigma == 0.0 {
        return 1u;
    }
    let d_t = (inst.end.translation - inst.start.translation) * f;
    let d = length3(v * (dt * f) - d_t);
    let s = min_of(inst.start.scale, inst.end.scale);
    let s_max = max_of(inst.start.scale, inst.end.scale);
    let y = s_max * local_radius(root_aabb()) + d;
    let c = ((2.0 * theta * d + theta * theta * y) / s
        + 2.0 * (theta * y + d) * sigma / (s * s)
        + 2.0 * y * sigma * sigma / (s * s * s))
        * 0.125;
    let m = SUBSTEP_MARGIN * finest_leaf_size();
    let n = sqrt(c / m);
    if !(n < f32(MAX_SUBSTEPS)) {
        return MAX_SUBSTEPS;
    }
    return min(u32(floor(n)) + 1u, MAX_SUBSTEPS);
}

// core's `must_keep` (the loaded proxy).
fn must_keep(lp: Particle, hint: vec2<u32>) -> bool {
    if (lp.side & SIDE_CAGE_MASK) != 0u {
        return true;
    }
    // In an empty leaf (the common case): its label is the side.
    if any(hint != vec2<u32>(0u)) && (hint.y & HINT_SURFACE) == 0u {
        return false;
    }
    let root = root_aabb();
    let l = lp.position;
    return all(l >= root.min) && all(l <= root.max);
}

fn derived_side(inst: Instance, x: vec3<f32>, u: f32) -> u32 {
    use_proxy(inst.proxy);
    return initial_side(pose_to_local(instance_pose_at(inst, u), x));
}

// core's `FrameHit` and `FrameMarch`, with their options.
struct FrameHit {
    hit: Hit,
    leaf: u32,
    blocked: bool,
}

struct FrameHitOption {
    value: FrameHit,
    some: bool,
}

// A Rust `Option<(f32, Vec3, Vec3)>`: where a march stopped, and how fast.
struct Moved {
    u: f32,
    x: vec3<f32>,
    v: vec3<f32>,
}

struct MovedOption {
    value: Moved,
    some: bool,
}

struct FrameMarch {
    side: u32,
    required: bool,
    moved: MovedOption,
    collisions: u32,
    hit: FrameHitOption,
    outcome: u32,
}

// core's `march_in_frame`; `stop` is its `AfterHit::Stop` (else `FinishChord`).
fn march_in_frame(c: u32, inst: Instance, x: vec3<f32>, v: vec3<f32>, u0: f32, u1: f32, side_in: u32, params: StepParams, stop: bool, collided_in: u32) -> FrameMarch {
    use_proxy(inst.proxy);
    let dt = params.dt;
    let fixed = instance_is_static(inst);
    var n = 1u;
    if !fixed {
        n = substeps(inst, v, u0, u1, dt);
    }
    var side = side_in;
    var collided = collided_in;
    var required = false;
    var outcome = STEP_DONE;
    // The chord's ends as offsets from `u0`, never as `(u0 + f) - u0` (NIR folds that to `f`).
    let span = u1 - u0;
    for (var k = 0u; k < n; k++) {
        let fa = span * (f32(k) / f32(n));
        let last = k + 1u == n;
        var fb = span;
        var ub = u1;
        if !last {
            fb = span * (f32(k + 1u) / f32(n));
            ub = u0 + fb;
        }
        let ua = u0 + fa;
        let h = (fb - fa) * dt;
        if !(h > 0.0) {
            continue;
        }
        let pa = instance_pose_at(inst, ua);
        let pb = instance_pose_at(inst, ub);
        let la = pose_to_local(pa, x + v * (fa * dt));
        var lv: vec3<f32>;
        if fixed {
            lv = pose_vector_to_local(pa, v);
        } else {
            lv = (pose_to_local(pb, x + v * (fb * dt)) - la) / h;
        }
        lv = plus_zero(lv);
        var lp = Particle(la, side, lv, 0u);
        observe(stop, !stop, HitFrame(c, pa, !fixed, inst, ua, ub, h, dt));
        var hint = vec2<u32>(0u);
        let local = StepParams(vec3<f32>(0.0), h, params.restitution, params.friction, params.radius, params._pad);
        outcome = march_after(&lp, local, &hint, collided);
        collided = NO_LEAF;
        side = lp.side;
        required = must_keep(lp, hint);
        if outcome == STEP_INVALID || outcome == STEP_BOUND_HIT {
            break;
        }
        if observer.count == 0u {
            continue;
        }
        // Where the march stopped: at the hit, or at the chord's end.
        var u_end = ub;
        var p_end = pb;
        if stop {
            u_end = min_of(ua + (h - observer.remaining) / dt, ub);
            p_end = instance_pose_at(inst, u_end);
        }
        let l_end = lp.position;
        // The collider's surface velocity there over this chord, added back (none for a
        // static one).
        var v_end = pose_vector_to_world(p_end, lp.velocity);
        if !fixed {
            v_end = (pose_to_world(pb, l_end) - pose_to_world(pa, l_end)) / h + v_end;
        }
        let hit = FrameHit(observer.last, observer.leaf, outcome == STEP_BLOCKED);
        return FrameMarch(side, true, MovedOption(Moved(u_end, pose_to_world(p_end, l_end), v_end), true), observer.count, FrameHitOption(hit, true), outcome);
    }
    var out: FrameMarch;
    out.side = side;
    out.required = required;
    out.moved.some = false;
    out.collisions = 0u;
    out.hit.some = false;
    out.outcome = outcome;
    return out;
}

// core's `step_particle_scene`: one particle's scene step. The kernel takes the plain step
// itself (`step_plain`) where the scene allows it, as the CPU backend's loop does.
fn step_particle_scene(p: ptr<function, Particle>, hint: ptr<function, SceneHint>, slots: ptr<function, SceneSlots>, params: StepParams, hit: ptr<function, Hit>) -> u32 {
    let c = scene_params.plain;
    if c != NO_INSTANCE && ((*hint).first_slot >> SLOT_INSTANCE_SHIFT) == c && (*hint).hint_instance == c {
        return step_plain(c, p, hint, params, hit);
    }
    var sides = scene_sides_join(*hint, *slots);
    let outcome = step_particle_scene_general(p, &sides, params, hit);
    scene_sides_split(sides, hint, slots);
    return outcome;
}

// core's `step_plain`: a one-proxy static scene at the identity, for a particle whose first
// slot and hint are its instance's.
fn step_plain(c: u32, p: ptr<function, Particle>, sides: ptr<function, SceneHint>, params: StepParams, hit: ptr<function, Hit>) -> u32 {
    let inst = load_instance(c);
    use_proxy(inst.proxy);
    (*p).side = (*sides).first_slot & SLOT_SIDE_MASK;
    observe(false, true, hit_frame_whole_step(c, identity_pose(), params.dt));
    // (A copy: naga cannot pass a pointer to a struct's member, gfx-rs/wgpu#4540.)
    var leaf_hint = (*sides).hint;
    let outcome = step_particle_hinted(p, params, &leaf_hint);
    (*sides).hint = leaf_hint;
    *hit = observer.last;
    if outcome == STEP_INVALID {
        return outcome;
    }
    let required = must_keep(*p, (*sides).hint);
    (*sides).first_slot = (c << SLOT_INSTANCE_SHIFT) | select(0u, SLOT_REQUIRED, required) | (*p).side;
    (*p).flags &= ~(FLAG_CRUSHED | FLAG_SIDES_LOST);
    return outcome;
}

fn step_particle_scene_general(p: ptr<function, Particle>, sides: ptr<function, SceneSides>, params: StepParams, hit: ptr<function, Hit>) -> u32 {
    *hit = no_hit();
    let x0 = (*p).position;
    let v0 = (*p).velocity;
    let dt = params.dt;
    let v = v0 + params.gravity * dt;
    let reach = wide_length3(v) * dt;
    if !is_finite3(x0) || !is_finite3(v0) || !is_finite(reach) || !(dt > 0.0) {
        (*p).flags |= FLAG_INVALID;
        return STEP_INVALID;
    }
    // Every point the particle can reach against static colliders: the ball of radius |v| dt.
    let pad = 4.0 * ulp(max_element(abs(x0)) + reach) + PATH_PAD;
    let ball = Aabb(x0 - (reach + pad), x0 + (reach + pad));
    let found = count_candidates(ball);
    let status_kept = (*p).flags & FLAG_STATUS_MASK & ~FLAG_SCENE_STATUS;
    if found.count == 0u {
        (*p).position = x0 + v * dt;
        (*p).velocity = v;
        (*p).side &= SIDE_MASK;
        (*p).flags = status_kept | ((*p).flags & ~FLAG_STATUS_MASK);
        (*sides).slots = optional_slots((*sides).slots);
        return STEP_DONE;
    }
    if found.count == 1u && instance_is_static(load_instance(found.first)) {
        return step_near_one_static(found.first, p, sides, params, hit);
    }
    return step_in_rounds(p, sides, params, hit);
}

fn step_near_one_static(c: u32, p: ptr<function, Particle>, sides: ptr<function, SceneSides>, params: StepParams, hit: ptr<function, Hit>) -> u32 {
    let inst = load_instance(c);
    use_proxy(inst.proxy);
    let pose = inst.start;
    let identity = same_pose(pose, identity_pose());
    let x0 = (*p).position;
    var slots = optional_slots((*sides).slots);
    let kept_now = kept_side(inst, slots, c);
    var side = kept_now.value;
    if !kept_now.some {
        side = initial_side(pose_to_local(pose, x0));
    }
    var hint = vec2<u32>(0u);
    if (*sides).hint_instance == c {
        hint = (*sides).hint;
    }
    var lp = *p;
    lp.side = side;
    var local_params = params;
    if !identity {
        lp = Particle(pose_to_local(pose, x0), side, pose_vector_to_local(pose, (*p).velocity), (*p).flags);
        local_params.gravity = pose_vector_to_local(pose, params.gravity);
    }
    observe(false, true, hit_frame_whole_step(c, pose, params.dt));
    let outcome = step_particle_hinted(&lp, local_params, &hint);
    if outcome == STEP_INVALID {
        (*p).flags |= FLAG_INVALID;
        return outcome;
    }
    let required = must_keep(lp, hint);
    let kept = commit(&slots, c, lp.side, required);
    if identity {
        *p = lp;
    } else if observer.count == 0u && outcome == STEP_DONE {
        // No collision: the straight world path, not its round trip through the frame.
        let v = (*p).velocity + params.gravity * params.dt;
        (*p).position = x0 + v * params.dt;
        (*p).velocity = v;
        (*p).flags = lp.flags;
    } else {
        (*p).position = pose_to_world(pose, lp.position);
        (*p).velocity = pose_vector_to_world(pose, lp.velocity);
        (*p).flags = lp.flags;
    }
    *hit = observer.last;
    (*sides).slots = slots;
    (*sides).hint = hint;
    (*sides).hint_instance = c;
    (*p).side = first_side(slots, lp.side);
    (*p).flags &= ~(FLAG_CRUSHED | FLAG_SIDES_LOST);
    if !kept {
        (*p).flags |= FLAG_SIDES_LOST;
    }
    return outcome;
}

// core's `chord_per_length`: the most a turn from `a` to `b` (slerp's, the shorter way) moves
// a point per unit of its distance from the origin, from the quaternions' difference.
fn chord_per_length(a: vec4<f32>, b: vec4<f32>) -> f32 {
    let d = a.x * b.x + a.y * b.y + a.z * b.z + a.w * b.w;
    var sign = 1.0;
    if d < 0.0 {
        sign = -1.0;
    }
    let e = b * sign - a;
    let gap = sqrt(e.x * e.x + e.y * e.y + e.z * e.z + e.w * e.w);
    return min_of(2.0 * gap * (1.0 + 1e-6) + 4.0 * 1.1920929e-7, 2.0);
}

// core's `ride_is_clear`: riding with instance `c` for the rest of the step meets no other.
fn ride_is_clear(c: u32, x: vec3<f32>, u: f32) -> bool {
    let inst = load_instance(c);
    let l = pose_to_local(instance_pose_at(inst, u), x);
    let end = pose_to_world(inst.end, l);
    let r = length3(l);
    let turn = chord_per_length(inst.start.rotation, inst.end.rotation);
    let stray = r * max_of(inst.start.scale, inst.end.scale) * turn + r * abs(inst.end.scale - inst.start.scale);
    let pad = 4.0 * ulp(max_element(vmax(abs(x), abs(end)))) + PATH_PAD + stray;
    let found = count_candidates(Aabb(vmin(x, end) - pad, vmax(x, end) + pad));
    return found.count == 0u || (found.count == 1u && found.first == c);
}

// step_in_rounds' closure `side_for`: the kept side, else the derived one.
fn side_for(slots: array<u32, SIDE_SLOTS>, c: u32, x: vec3<f32>, u: f32) -> u32 {
    let inst = load_instance(c);
    let kept = kept_side(inst, slots, c);
    if kept.some {
        return kept.value;
    }
    return derived_side(inst, x, u);
}

// step_in_rounds' closure `collided_in`: the surface leaf of the last collision when it was
// with static instance `c`.
fn collided_in(last: U32Option, last_leaf: u32, c: u32) -> u32 {
    if last.some && last.value == c && instance_is_static(load_instance(c)) {
        return last_leaf;
    }
    return NO_LEAF;
}

fn step_in_rounds(p: ptr<function, Particle>, sides: ptr<function, SceneSides>, params: StepParams, hit: ptr<function, Hit>) -> u32 {
    let dt = params.dt;
    var x = (*p).position;
    var v = (*p).velocity + params.gravity * dt;
    var u = 0.0;
    var slots = optional_slots((*sides).slots);
    var status = 0u;
    var collisions_made = 0u;
    var lost = false;
    // The instance and surface leaf of the last collision.
    var last = U32Option(0u, false);
    var last_leaf = NO_LEAF;
    // The last collision between static instances: point, normal, whether it pinched.
    var last_static = false;
    var static_x = vec3<f32>(0.0);
    var static_n = vec3<f32>(0.0);
    var static_pinched = false;
    var rounds = 0u;
    var contacts = 0u;
    var stalls = 0u;
    loop {
        if stalls == MAX_STALLS {
            stalls = 0u;
            if last.some && ride_is_clear(last.value, x, u) {
                contacts = MAX_CONTACTS;
            }
        }
        if rounds == MAX_ROUNDS || contacts == MAX_CONTACTS {
            // At its last contact, moving with what it touched: carried, or crushed where
            // another instance is on the way.
            let carried = rounds < MAX_ROUNDS && (!last.some || ride_is_clear(last.value, x, u));
            status |= select(FLAG_CRUSHED, FLAG_BOUND_HIT, carried);
            if last.some {
                let inst = load_instance(last.value);
                let end = pose_to_world(inst.end, pose_to_local(instance_pose_at(inst, u), x));
                let rest = (1.0 - u) * dt;
                if rest > 0.0 {
                    v = (end - x) / rest;
                } else {
                    v = vec3<f32>(0.0);
                }
                x = end;
            }
            break;
        }
        contacts += 1u;
        let rest = (1.0 - u) * dt;
        let end = x + v * rest;
        let pad = 4.0 * ulp(max_element(vmax(abs(x), abs(end)))) + PATH_PAD;
        let reach = wide_length3(v) * rest + pad;
        let ball = Aabb(x - reach, x + reach);
        let near = count_candidates(ball);
        var only = near.first;
        let one_static = near.count == 1u && instance_is_static(load_instance(only));
        let seg = Aabb(vmin(x, end) - pad, vmax(x, end) + pad);
        var count = 0u;
        if !one_static {
            let on_path = count_candidates(seg);
            count = on_path.count;
            only = on_path.first;
        }
        if near.count == 0u || (!one_static && count == 0u) {
            x = end;
            break;
        }
        if count > 1u {
            rounds += 1u;
        }
        // The round's outcome: how far it went, and the collision it ended with.
        var moved: MovedOption;
        moved.some = false;
        var round_hit: FrameHitOption;
        round_hit.some = false;
        var round_c = 0u;
        var round_collisions = 0u;
        var bound = false;
        var invalid = false;
        if one_static || count == 1u {
            let c = only;
            let inst = load_instance(c);
            let side = side_for(slots, c, x, u);
            let m = march_in_frame(c, inst, x, v, u, 1.0, side, params, !one_static, collided_in(last, last_leaf, c));
            invalid = m.outcome == STEP_INVALID;
            bound = m.outcome == STEP_BOUND_HIT;
            let kept = commit(&slots, c, m.side, m.required);
            lost = lost || !kept;
            moved = m.moved;
            if m.hit.some {
                round_hit = m.hit;
                round_c = c;
                round_collisions = m.collisions;
            }
        } else {
            // The earliest first collision, ties to the first in the broad phase's order.
            var best = U32Option(0u, false);
            var best_u = 0.0;
            var walk = broad_walk_new();
            loop {
                let c = broad_walk_next(&walk, seg);
                if c == NO_INSTANCE {
                    break;
                }
                let inst = load_instance(c);
                let side = side_for(slots, c, x, u);
                let m = march_in_frame(c, inst, x, v, u, 1.0, side, params, true, collided_in(last, last_leaf, c));
                invalid = invalid || m.outcome == STEP_INVALID;
                if m.hit.some {
                    if !best.some || m.hit.value.hit.t < best_u {
                        best = U32Option(c, true);
                        best_u = m.hit.value.hit.t;
                    }
                }
            }
            var until = 1.0;
            if best.some {
                until = best_u;
            }
            walk = broad_walk_new();
            loop {
                let c = broad_walk_next(&walk, seg);
                if c == NO_INSTANCE {
                    break;
                }
                let inst = load_instance(c);
                let side = side_for(slots, c, x, u);
                let is_best = best.some && best.value == c;
                let to = select(until, 1.0, is_best);
                let m = march_in_frame(c, inst, x, v, u, to, side, params, true, collided_in(last, last_leaf, c));
                invalid = invalid || m.outcome == STEP_INVALID;
                bound = bound || m.outcome == STEP_BOUND_HIT;
                if is_best {
                    moved = m.moved;
                    if m.hit.some {
                        round_hit = m.hit;
                        round_c = c;
                        round_collisions = m.collisions;
                    }
                }
                let kept = commit(&slots, c, m.side, m.required);
                lost = lost || !kept;
            }
        }
        if invalid {
            (*p).flags |= FLAG_INVALID;
            return STEP_INVALID;
        }
        if bound {
            // A march hit its leaf bound: the particle stays where this round started.
            status |= FLAG_BOUND_HIT;
            v = vec3<f32>(0.0);
            break;
        }
        if !(moved.some && round_hit.some) {
            x = end;
            break;
        }
        let h = round_hit.value;
        let c = round_c;
        collisions_made += round_collisions;
        if h.blocked {
            status |= FLAG_BLOCKED;
        }
        *hit = h.hit;
        // A march that finished its chord told every collision; a probe told none.
        if !one_static {
            push_event(h.hit);
        }
        stalls = select(0u, stalls + 1u, moved.value.u == u);
        x = moved.value.x;
        v = moved.value.v;
        u = moved.value.u;
        last = U32Option(c, true);
        last_leaf = h.leaf;
        // The pinch rule across static instances (a crease where two parts meet).
        let inst = load_instance(c);
        if instance_is_static(inst) && !h.blocked {
            use_proxy(inst.proxy);
            let reach_pinch = finest_leaf_size() * inst.start.scale * 2.0;
            let hx = hit_position(h.hit);
            let hn = hit_normal(h.hit);
            var pinched = false;
            if last_static {
                if length3(hx - static_x) <= reach_pinch && dot3(v, static_n) < 0.0 {
                    if static_pinched {
                        v = vec3<f32>(0.0);
                    } else {
                        v = pinch(v, hn, static_n);
                    }
                    pinched = true;
                }
            }
            last_static = true;
            static_x = hx;
            static_n = hn;
            static_pinched = pinched;
        } else {
            last_static = false;
        }
        if !(u < 1.0) {
            break;
        }
    }
    if !is_finite3(x) || !is_finite3(v) {
        (*p).flags |= FLAG_INVALID;
        return STEP_INVALID;
    }
    (*p).position = x;
    (*p).velocity = v;
    (*p).side = first_side(slots, (*p).side & SIDE_MASK);
    if lost {
        status |= FLAG_SIDES_LOST;
    }
    let count = min(collisions(*p) + collisions_made, MAX_COLLISIONS);
    (*p).flags = ((*p).flags & FLAG_STATUS_MASK & ~FLAG_SCENE_STATUS) | status | (count << COLLISION_SHIFT);
    (*sides).slots = slots;
    (*sides).hint = vec2<u32>(0u);
    (*sides).hint_instance = NO_INSTANCE;
    if (status & FLAG_CRUSHED) != 0u {
        return STEP_BOUND_HIT;
    } else if (status & FLAG_BLOCKED) != 0u {
        return STEP_BLOCKED;
    }
    return STEP_DONE;
}
