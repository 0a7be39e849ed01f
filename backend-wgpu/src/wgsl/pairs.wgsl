// The particle-particle pass, as core/src/pairs.rs (read its module documentation for the
// rules): the same functions under the same names, the same order of floating-point
// operations (glam's `Vec3::dot` is `dot3`, x then y then z; `f32::clamp` is the builtin,
// which differs from it only on NaN: `pair_cell` spells out Rust's NaN). A Rust `Option<T>`
// is a `TOption { value, some }`. The pass's buffers hold every particle, whatever chunk it
// lies in; `pairs_kernel.wgsl` runs the pass over them, a kernel per stage, and
// `backend-wgpu/src/pairs.rs` records the dispatches.

// core's `PairStep`: 80 bytes. The host writes every field but `cell` and `inv_cell`, which
// `pair_step_kernel` computes from the substep's largest speed without a read-back.
struct PairStep {
    gravity_h: vec3<f32>,
    h: f32,
    up: vec3<f32>,
    inv_h: f32,
    radius: f32,
    diameter: f32,
    inv_diameter: f32,
    cell: f32,
    inv_cell: f32,
    mask: u32,
    restitution: f32,
    friction: f32,
    relaxation: f32,
    half_stacking: f32,
    max_candidates: u32,
    scene_friction: f32,
}

// core's `PairBody`: 32 bytes.
struct PairBody {
    position: vec3<f32>,
    index: u32,
    cell: vec3<i32>,
    hash: u32,
}

// The substep's constants and what the pass counts (the Rust twin is
// `octoproxy_wgpu::PairState`): the largest speed's bits (speeds are >= 0, so the order of
// the bits is the order of the values), the valid particles (the sorted keys before the first
// `PAIR_HASH_NONE`), the report's counts as low and high words, and a zero read at run time
// (see `pair_velocity`).
struct PairState {
    step: PairStep,
    v_max: atomic<u32>,
    valid: u32,
    fast_lo: atomic<u32>,
    fast_hi: atomic<u32>,
    capped_lo: atomic<u32>,
    capped_hi: atomic<u32>,
    zero: f32,
    relaxation: f32,
    // The probe's most particles in one column (`pair_column_key`), and the two unit
    // vectors across gravity the host writes for it (`xyz`).
    deepest: atomic<u32>,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
    across0: vec4<f32>,
    across1: vec4<f32>,
}

@group(0) @binding(3) var<storage, read_write> pair_state: PairState;
// `(hash, index)` per particle, sorted in place; padded to the table's size with
// `(u32::MAX, u32::MAX)`, which sorts after every particle's key.
@group(0) @binding(4) var<storage, read_write> pair_keys: array<vec2<u32>>;
// The particles in sorted order.
@group(0) @binding(6) var<storage, read_write> pair_bodies: array<PairBody>;
// The last iteration's velocities (in sorted order), and the next iteration's.
@group(0) @binding(7) var<storage, read> pair_vel: array<vec4<f32>>;
@group(0) @binding(8) var<storage, read_write> pair_vel_next: array<vec4<f32>>;
// Each hash's `[start, end)` in the sorted order; `[0, 0]` when empty.
@group(0) @binding(9) var<storage, read_write> pair_ranges: array<vec2<u32>>;
// Each grain's support (`pair_support`), in sorted order.
@group(0) @binding(12) var<storage, read_write> pair_supports: array<vec4<f32>>;
// The velocities entering the iterations (in sorted order), for each pair's target.
@group(0) @binding(14) var<storage, read> pair_vel_start: array<vec4<f32>>;

// Rust's `Option<(Vec3, f32)>` of `pair_prepare`.
struct PreparedOption {
    v: vec3<f32>,
    speed: f32,
    some: bool,
}

// Rust's `Option<PairChange>` of `pair_impulse`, with the pair's share (`PairGeometry::share`).
struct PairImpulse {
    normal: vec3<f32>,
    friction: vec3<f32>,
    share: f32,
    some: bool,
}

// Rust's `(PairVelocity, [f32; 4])` of `pair_start`.
struct PairStart {
    v: vec4<f32>,
    support: vec4<f32>,
}

// Rust's `(PairVelocity, bool)` of `pair_velocity`.
struct PairVelocityOut {
    v: vec4<f32>,
    capped: bool,
}

fn pair_cell_edge(diameter: f32, radius: f32, v_max: f32, h: f32) -> f32 {
    var d = v_max * h;
    if !(d < radius) {
        d = radius;
    }
    return (diameter + 2.0 * d) * PAIR_CELL_MARGIN;
}

fn pair_is_fast(speed: f32, s: PairStep) -> bool {
    return speed * s.h > s.radius;
}

fn pair_prepare(p: Particle, s: PairStep) -> PreparedOption {
    let x = p.position;
    let v = p.velocity + s.gravity_h;
    if !is_finite3(x) || !is_finite3(v) {
        return PreparedOption(vec3<f32>(0.0), 0.0, false);
    }
    return PreparedOption(v, sqrt(dot3(v, v)), true);
}

// A position's part along a unit vector (Rust's `pair_height`), summed in this order.
fn pair_height(x: vec3<f32>, a: vec3<f32>) -> f32 {
    return x.x * a.x + x.y * a.y + x.z * a.z;
}

// The key of a position's column: its two coordinates across gravity, clamped as
// `pair_cell`'s, 15 and 16 bits of them with the top bit set (never 0, an empty slot).
fn pair_column_key(x: vec3<f32>, a0: vec3<f32>, a1: vec3<f32>, inv_diameter: f32) -> u32 {
    let f = floor(vec2<f32>(pair_height(x, a0) * inv_diameter, pair_height(x, a1) * inv_diameter));
    let c = bitcast<vec2<u32>>(vec2<i32>(clamp(f, vec2<f32>(-PAIR_CELL_LIMIT), vec2<f32>(PAIR_CELL_LIMIT))));
    return 0x80000000u | ((c.x & 0x7fffu) << 16u) | (c.y & 0xffffu);
}

// The mix of a region's combined coordinates in `pair_hash`: where its run starts.
fn region_mix(x: u32) -> u32 {
    var h = x;
    h ^= h >> 16u;
    h = h * 0x7feb352du;
    h ^= h >> 15u;
    h = h * 0x846ca68bu;
    return h ^ (h >> 16u);
}

// Where a column's key starts its search in a table of `mask + 1` entries: `pair_hash`'s
// mix of a region.
fn pair_column_slot(key: u32, mask: u32) -> u32 {
    return region_mix(key) & mask;
}

fn pair_cell(x: vec3<f32>, s: PairStep) -> vec3<i32> {
    let f = floor(x * s.inv_cell);
    let c = vec3<i32>(clamp(f, vec3<f32>(-PAIR_CELL_LIMIT), vec3<f32>(PAIR_CELL_LIMIT)));
    // Rust's `as i32` takes a NaN (kept by `f32::clamp`) to 0.
    let nan = (bitcast<vec3<u32>>(f) & vec3<u32>(0x7fffffffu)) > vec3<u32>(0x7f800000u);
    return select(c, vec3<i32>(0), nan);
}

// `load_header` must have run.
fn pair_start(p: Particle, hint: vec2<u32>, s: PairStep) -> PairStart {
    return pair_start_with(p, pair_support(p, hint), s);
}

// The restitution of the support's response is zero, read at run time (see `pair_velocity`).
fn pair_start_with(p: Particle, support: vec4<f32>, s: PairStep) -> PairStart {
    var v = vec3<f32>(0.0);
    let prepared = pair_prepare(p, s);
    if prepared.some {
        v = prepared.v;
    }
    if support.w != 0.0 {
        v = respond(v, support.xyz, pair_state.zero, s.scene_friction);
    }
    return PairStart(vec4<f32>(v, 0.0), support);
}

// Wrapping multiplies and adds, as Rust's `wrapping_mul` and `wrapping_add`; `>>` on `i32` is
// arithmetic, as Rust's: the region of 8x8x8 blocks hashed to where its run starts, the
// block's place in it in Morton order times 64, plus the cell's place in its block of 4x4x4.
fn pair_hash(c: vec3<i32>, mask: u32) -> u32 {
    let b = c >> vec3<u32>(2u);
    let r = b >> vec3<u32>(3u);
    let h = region_mix((bitcast<u32>(r.x) * 0x8da6b343u) ^ (bitcast<u32>(r.y) * 0xd8163841u)
        ^ (bitcast<u32>(r.z) * 0xcb1ab31fu));
    let bb = bitcast<vec3<u32>>(b);
    var block = 0u;
    for (var i = 0u; i < 3u; i++) {
        for (var a = 0u; a < 3u; a++) {
            block |= ((bb[a] >> i) & 1u) << (3u * i + a);
        }
    }
    let l = bitcast<vec3<u32>>(c & vec3<i32>(3));
    let local = l.x | (l.y << 2u) | (l.z << 4u);
    return (h + ((block << 6u) | local)) & mask;
}

// Whether sorted position `k` is the first and the last entry of its bucket in `pair_keys`,
// which holds `len` keys (the padding's hash is `PAIR_HASH_NONE`, as every invalid
// particle's, so it ends a bucket as the array's end does).
fn pair_range_marks(k: u32, len: u32) -> vec2<bool> {
    let h = pair_keys[k].x;
    if h == PAIR_HASH_NONE {
        return vec2<bool>(false, false);
    }
    let first = k == 0u || pair_keys[k - 1u].x != h;
    let last = k + 1u == len || pair_keys[k + 1u].x != h;
    return vec2<bool>(first, last);
}

fn pair_target(gap: f32, approach: f32, beta: f32, s: PairStep) -> f32 {
    var closing = beta * gap * s.inv_h;
    if gap >= 0.0 {
        closing = gap * s.inv_h;
    }
    var target_vn = s.restitution * approach + (1.0 - s.restitution) * -closing;
    if gap < 0.0 && target_vn < -closing {
        target_vn = -closing;
    }
    return target_vn;
}

// How far a push along `dir` moves a grain on `support` along it (Rust's `pair_free`).
fn pair_free(support: vec4<f32>, dir: vec3<f32>, friction: f32) -> f32 {
    if support.w == 0.0 {
        return 1.0;
    }
    let into = -dot3(dir, support.xyz);
    if !(into > 0.0) {
        return 1.0;
    }
    if support.w == PAIR_WEDGED {
        return 0.0;
    }
    let across2 = 1.0 - into * into;
    var across = 0.0;
    if across2 > 0.0 {
        across = sqrt(across2);
    }
    let kept = across - friction * into;
    if kept > 0.0 {
        return across * kept;
    }
    return 0.0;
}

fn pair_impulse(me: PairBody, v: vec3<f32>, v0: vec3<f32>, sup_me: vec4<f32>, other: PairBody, w: vec3<f32>, w0: vec3<f32>, sup_other: vec4<f32>, s: PairStep) -> PairImpulse {
    let x = me.position - other.position;
    let d2 = dot3(x, x);
    var dist = 0.0;
    var n = vec3<f32>(0.0, select(-1.0, 1.0, me.index > other.index), 0.0);
    if d2 > 0.0 {
        dist = sqrt(d2);
        n = x * (1.0 / dist);
    }
    let height = clamp(dot3(x, s.up) * s.inv_diameter, -1.0, 1.0);
    // A grain on the scene leaves the part of a push into its support to the other grain.
    let even = 0.5 + height * s.half_stacking;
    let mine = even * pair_free(sup_me, n, s.scene_friction);
    let theirs = (0.5 - height * s.half_stacking) * pair_free(sup_other, -n, s.scene_friction);
    var share = even;
    if mine + theirs > 0.0 {
        share = mine / (mine + theirs);
    }
    let none = PairImpulse(vec3<f32>(0.0), vec3<f32>(0.0), share, false);
    let gap = dist - s.diameter;
    let vn0 = dot3(v0 - w0, n);
    var approach = 0.0;
    if vn0 < 0.0 {
        approach = -vn0;
    }
    let target_vn = pair_target(gap, approach, s.relaxation, s);
    let vr = v - w;
    let vn = dot3(vr, n);
    if gap + vn * s.h >= 0.0 {
        return none;
    }
    let jn = target_vn - vn;
    let pushes = jn > 0.0;
    let pulls = gap < 0.0 && jn < 0.0;
    if !(pushes || pulls) {
        return none;
    }
    let vt = vr - n * vn;
    let t2 = dot3(vt, vt);
    var friction = vec3<f32>(0.0);
    if t2 > 0.0 && pushes {
        let tl = sqrt(t2);
        let limit = s.friction * jn;
        var keep = 1.0;
        if !(tl <= limit) {
            keep = limit / tl;
        }
        friction = vt * -keep;
    }
    return PairImpulse(n * (jn * share), friction * share, share, true);
}

fn pair_weight(share: f32) -> f32 {
    let w = 2.0 * share;
    if w < 1.0 {
        return w;
    }
    return 1.0;
}

// One Jacobi iteration for the particle at sorted position `k`: the 27 cells around its own,
// z then y then x from -1 to 1, each bucket in sorted order, the entries of that very cell
// closer than the cell edge (Rust's `pair_candidates`, inlined), velocities from `pair_vel`,
// then its support's response (Rust's `PairSum`). Rust's `respond(.., 0.0, ..)` takes a restitution of zero: here it
// is read at run time (`pair_state.zero`), for a constant one may let the compiler fold
// `v_n * 0.0` to +0 (NIR's inexact `a * 0.0 -> 0.0`), where IEEE gives -0 for a negative
// `v_n`, and then `v_t * keep - v_n * 0.0` its sign of zero.
fn pair_velocity(k: u32, s: PairStep) -> PairVelocityOut {
    let me = pair_bodies[k];
    let v = pair_vel[k].xyz;
    let v0 = pair_vel_start[k].xyz;
    let support = pair_supports[k];
    var sum = vec3<f32>(0.0);
    var friction = vec3<f32>(0.0);
    var weight = 0.0;
    var holds = 0u;
    var visited = 0u;
    var capped = false;
    let reach = s.cell * s.cell;
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            for (var dx = -1; dx <= 1; dx++) {
                let c = me.cell + vec3<i32>(dx, dy, dz);
                let r = pair_ranges[pair_hash(c, s.mask)];
                for (var m = r.x; m < r.y; m++) {
                    if visited == s.max_candidates {
                        capped = true;
                        break;
                    }
                    visited += 1u;
                    let o = pair_bodies[m];
                    if m == k || any(o.cell != c) {
                        continue;
                    }
                    let d = me.position - o.position;
                    if dot3(d, d) >= reach {
                        continue;
                    }
                    let w = pair_vel[m].xyz;
                    let dv = pair_impulse(me, v, v0, support, o, w, pair_vel_start[m].xyz, pair_supports[m], s);
                    if dv.some {
                        sum += dv.normal;
                        friction += dv.friction;
                        let wt = pair_weight(dv.share);
                        weight += wt;
                        holds += select(0u, 1u, wt > 0.0);
                    }
                }
                if capped {
                    break;
                }
            }
            if capped {
                break;
            }
        }
        if capped {
            break;
        }
    }
    // Friction holds a grain held by two or more contacts, or by one and the scene.
    if holds >= 2u || (holds == 1u && support.w != 0.0) {
        sum = sum + friction;
    }
    var out = v;
    if weight > 0.0 {
        out = v + sum * (1.0 / weight);
    }
    if support.w != 0.0 {
        out = respond(out, support.xyz, pair_state.zero, s.scene_friction);
    }
    return PairVelocityOut(vec4<f32>(out, 0.0), capped);
}
