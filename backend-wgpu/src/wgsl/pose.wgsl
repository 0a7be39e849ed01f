// Scenes, as core/src/scene.rs: poses, instances, the broad phase, hit records, and where a
// scene's tables are. Only the scene kernel has this file. The host writes the tables into one
// word buffer (`scene`) each step, as core's bytes: the word offset of every proxy in the
// proxy buffer, then the instances (20 words each), then the broad phase (8 words a node);
// `scene_params` says where each part starts.

// core's `Pose`: 32 bytes.
struct Pose {
    translation: vec3<f32>,
    scale: f32,
    rotation: vec4<f32>,
}

// core's `Instance`: 80 bytes.
struct Instance {
    start: Pose,
    end: Pose,
    proxy: u32,
    flags: u32,
    leaf: u32,
    half_turn: f32,
}

// core's `BroadNode`: 32 bytes.
struct BroadNode {
    min: vec3<f32>,
    index: u32,
    max: vec3<f32>,
    kind: u32,
}

// core's `Hit`: 36 bytes, scalar fields (a vec3 would align to 16).
struct Hit {
    instance: i32,
    position: array<f32, 3>,
    normal: array<f32, 3>,
    t: f32,
    speed: f32,
}

// core's `HitEvent`: 44 bytes.
struct HitEvent {
    step: u32,
    particle: u32,
    hit: Hit,
}

// Where the scene's tables are in `scene` (the Rust twin is `SceneParams`), and what the step
// records.
struct SceneParams {
    instances_at: u32,
    nodes_at: u32,
    node_count: u32,
    plain: u32,
    hits: u32,
    event_capacity: u32,
    step: u32,
    use_lut: u32,
    substep: u32,
    substeps: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(5) var<storage, read> scene: array<u32>;
@group(0) @binding(6) var<uniform> scene_params: SceneParams;

// The proxy whose header is loaded (`use_proxy`), or NO_INSTANCE for none yet.
var<private> loaded_proxy: u32 = NO_INSTANCE;

// Proxy `k` of the scene is the one the step reads from now on.
fn use_proxy(k: u32) {
    if loaded_proxy != k {
        load_header(scene[k], scene_params.use_lut != 0u);
        loaded_proxy = k;
    }
}

fn load_pose(w: u32) -> Pose {
    return Pose(
        vec3<f32>(bitcast<f32>(scene[w]), bitcast<f32>(scene[w + 1u]), bitcast<f32>(scene[w + 2u])),
        bitcast<f32>(scene[w + 3u]),
        vec4<f32>(bitcast<f32>(scene[w + 4u]), bitcast<f32>(scene[w + 5u]), bitcast<f32>(scene[w + 6u]), bitcast<f32>(scene[w + 7u])),
    );
}

fn load_instance(c: u32) -> Instance {
    let w = scene_params.instances_at + INSTANCE_WORDS * c;
    return Instance(load_pose(w), load_pose(w + 8u), scene[w + 16u], scene[w + 17u], scene[w + 18u], bitcast<f32>(scene[w + 19u]));
}

// The instances in the tables: they run from `instances_at` to `nodes_at`.
fn instance_count() -> u32 {
    return (scene_params.nodes_at - scene_params.instances_at) / INSTANCE_WORDS;
}

fn load_broad_node(i: u32) -> BroadNode {
    let w = scene_params.nodes_at + BROAD_NODE_WORDS * i;
    return BroadNode(
        vec3<f32>(bitcast<f32>(scene[w]), bitcast<f32>(scene[w + 1u]), bitcast<f32>(scene[w + 2u])),
        scene[w + 3u],
        vec3<f32>(bitcast<f32>(scene[w + 4u]), bitcast<f32>(scene[w + 5u]), bitcast<f32>(scene[w + 6u])),
        scene[w + 7u],
    );
}

// glam's scalar `max` and `min` (`f32::max` may give either zero for -0 and 0).
fn max_of(a: f32, b: f32) -> f32 {
    return select(b, a, a > b);
}

fn min_of(a: f32, b: f32) -> f32 {
    return select(b, a, a < b);
}

// core's `plus_zero`: every zero +0.0, in bits (a comparison and a select NIR might fold).
fn plus_zero(v: vec3<f32>) -> vec3<f32> {
    let keep = select(vec3<u32>(0xffffffffu), vec3<u32>(0x7fffffffu), v == vec3<f32>(0.0));
    return bitcast<vec3<f32>>(bitcast<vec3<u32>>(v) & keep);
}

// glam's `Vec3::max` and `max_element`.
fn vmax(a: vec3<f32>, b: vec3<f32>) -> vec3<f32> {
    return select(b, a, a > b);
}

fn vmin(a: vec3<f32>, b: vec3<f32>) -> vec3<f32> {
    return select(b, a, a < b);
}

fn max_element(v: vec3<f32>) -> f32 {
    return max_of(max_of(v.x, v.y), v.z);
}

fn length3(v: vec3<f32>) -> f32 {
    return sqrt(dot3(v, v));
}

// core's `wide_length`: |v| without the overflow of its squares for a finite v.
fn wide_length3(v: vec3<f32>) -> f32 {
    let l = length3(v);
    if is_finite(l) {
        return l;
    }
    let m = max_element(abs(v));
    if !(m > 0.0 && is_finite(m)) {
        return l;
    }
    return m * length3(v / m);
}

// core's `ulp`: the gap from |x| to the next float up.
fn ulp(x: f32) -> f32 {
    let a = abs(x);
    if !is_finite(a) {
        return infinity();
    }
    return bitcast<f32>(bitcast<u32>(a) + 1u) - a;
}

// core's `rotate`: the rotation matrix, each entry a sum or difference of two products,
// applied as three dot products (shapes NIR does not reassociate).
fn rotate(q: vec4<f32>, v: vec3<f32>) -> vec3<f32> {
    let x = q.x;
    let y = q.y;
    let z = q.z;
    let w = q.w;
    if x == 0.0 && y == 0.0 && z == 0.0 {
        return v;
    }
    let r0 = vec3<f32>(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w));
    let r1 = vec3<f32>(2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w));
    let r2 = vec3<f32>(2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y));
    return vec3<f32>(dot3(r0, v), dot3(r1, v), dot3(r2, v));
}

fn conjugate(q: vec4<f32>) -> vec4<f32> {
    return vec4<f32>(-q.x, -q.y, -q.z, q.w);
}

fn sin_poly(x: f32) -> f32 {
    let x2 = x * x;
    var p = SIN_POLY_C11;
    p = p * -x2 + SIN_POLY_C9;
    p = p * x2 - SIN_POLY_C7;
    p = p * x2 + SIN_POLY_C5;
    p = p * x2 - SIN_POLY_C3;
    p = p * x2 + 1.0;
    return x * p;
}

// core's `Pose::to_world` and the rest of its transforms.
fn pose_to_world(p: Pose, l: vec3<f32>) -> vec3<f32> {
    return p.translation + rotate(p.rotation, l * p.scale);
}

fn pose_to_local(p: Pose, x: vec3<f32>) -> vec3<f32> {
    return rotate(conjugate(p.rotation), x - p.translation) / p.scale;
}

fn pose_vector_to_world(p: Pose, l: vec3<f32>) -> vec3<f32> {
    return rotate(p.rotation, l * p.scale);
}

fn pose_vector_to_local(p: Pose, x: vec3<f32>) -> vec3<f32> {
    return rotate(conjugate(p.rotation), x) / p.scale;
}

fn pose_normal_to_world(p: Pose, n: vec3<f32>) -> vec3<f32> {
    return rotate(p.rotation, n);
}

// core's `pose_words` compared: the same bits.
fn same_pose(a: Pose, b: Pose) -> bool {
    return all(bitcast<vec3<u32>>(a.translation) == bitcast<vec3<u32>>(b.translation))
        && bitcast<u32>(a.scale) == bitcast<u32>(b.scale)
        && all(bitcast<vec4<u32>>(a.rotation) == bitcast<vec4<u32>>(b.rotation));
}

fn identity_pose() -> Pose {
    return Pose(vec3<f32>(0.0), 1.0, vec4<f32>(0.0, 0.0, 0.0, 1.0));
}

// core's `Instance::is_active`: live, and not hidden by a scale of 0 at either end.
fn instance_is_active(inst: Instance) -> bool {
    return (inst.flags & INSTANCE_LIVE) != 0u && inst.start.scale > 0.0 && inst.end.scale > 0.0;
}

fn instance_is_static(inst: Instance) -> bool {
    return same_pose(inst.start, inst.end);
}

fn instance_pose_at(inst: Instance, u: f32) -> Pose {
    if u <= 0.0 {
        return inst.start;
    }
    if u >= 1.0 {
        return inst.end;
    }
    let a = inst.start;
    let b = inst.end;
    let translation = a.translation + (b.translation - a.translation) * u;
    let scale = a.scale + (b.scale - a.scale) * u;
    let qa = a.rotation;
    var qb = b.rotation;
    let d = qa.x * qb.x + qa.y * qb.y + qa.z * qb.z + qa.w * qb.w;
    if d < 0.0 {
        qb = -qb;
    }
    let phi = inst.half_turn;
    var wa: f32;
    var wb: f32;
    if phi < SLERP_LINEAR_BELOW {
        wa = 1.0 - u;
        wb = u;
    } else {
        let s = sin_poly(phi);
        wa = sin_poly((1.0 - u) * phi) / s;
        wb = sin_poly(u * phi) / s;
    }
    let q = qa * wa + qb * wb;
    let len = sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w);
    return Pose(translation, scale, q / len);
}

// core's `HitFrame`: where a march's collisions are in the world (instance `c`'s frame over a
// chord from fraction `ua` to `ub` of the step, `h` seconds long, of a step of `dt`; at `pose`
// for a static instance, else at `inst`'s pose at each collision's moment).
struct HitFrame {
    c: u32,
    pose: Pose,
    moving: bool,
    inst: Instance,
    ua: f32,
    ub: f32,
    h: f32,
    dt: f32,
}

fn hit_frame_whole_step(c: u32, pose: Pose, dt: f32) -> HitFrame {
    var f: HitFrame;
    f.c = c;
    f.pose = pose;
    f.moving = false;
    f.ua = 0.0;
    f.ub = 1.0;
    f.h = dt;
    f.dt = dt;
    return f;
}

fn hit_frame_hit(f: HitFrame, x: vec3<f32>, n: vec3<f32>, before: vec3<f32>, remaining: f32) -> Hit {
    let u = min_of(f.ua + (f.h - remaining) / f.dt, f.ub);
    var pose = f.pose;
    if f.moving {
        pose = instance_pose_at(f.inst, u);
    }
    let w = pose_to_world(pose, x);
    let m = pose_normal_to_world(pose, n);
    return Hit(i32(f.c), array<f32, 3>(w.x, w.y, w.z), array<f32, 3>(m.x, m.y, m.z), u, max_of(-dot3(before, n) * pose.scale, 0.0));
}

// core's `Hit::in_whole_step`: a hit of substep `substep` of `substeps`, its `t` a fraction of
// the whole step.
fn hit_in_whole_step(h: Hit, substep: u32, substeps: u32) -> Hit {
    if substeps <= 1u || h.instance < 0 {
        return h;
    }
    var out = h;
    out.t = (f32(substep) + h.t) / f32(substeps);
    return out;
}

fn no_hit() -> Hit {
    return Hit(-1, array<f32, 3>(0.0, 0.0, 0.0), array<f32, 3>(0.0, 0.0, 0.0), 0.0, 0.0);
}

fn hit_position(h: Hit) -> vec3<f32> {
    return vec3<f32>(h.position[0], h.position[1], h.position[2]);
}

fn hit_normal(h: Hit) -> vec3<f32> {
    return vec3<f32>(h.normal[0], h.normal[1], h.normal[2]);
}
