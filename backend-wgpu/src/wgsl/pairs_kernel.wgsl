// The pass's entry points, one stage of a substep each; `backend-wgpu/src/pairs.rs` records
// them in this order, one dispatch after another (each dispatch sees what the last wrote):
//
//   pair_reset_kernel    the table's ranges to [0, 0], the largest speed and the valid count to 0
//   pair_speed_kernel    per chunk: the largest speed after gravity, and the fast particles
//                        (in the probe before a step, `pair_reset_kernel` and this alone with
//                        a zero substep: also the most particles in one column)
//   pair_step_kernel     one invocation: the substep's cell from the largest speed
//   pair_key_kernel      per chunk: each particle's (hash, index)
//   pair_sort_*_kernel   a bitonic sort of the keys: blocks sorted in workgroup memory, the
//                        passes over longer distances one dispatch each
//   pair_rank_kernel     each particle's place in the sorted order, the ranges, the valid count
//   pair_gather_kernel   per chunk: the bodies in sorted order
//   pair_start_kernel    per chunk: the velocities and supports in sorted order (`pair_start`;
//                        in a scene `pair_start_given_kernel`, the supports found by the scene
//                        module's `scene_support_kernel`)
//   pair_iterate_kernel  one Jacobi iteration (ping-pong between two velocity buffers)
//   pair_scatter_kernel  per chunk: the valid particles' velocities back
//
// then the plain step kernel (kernel.wgsl) marches every chunk with no gravity over the
// substep. One invocation does one particle's part of one stage: no loop of stages runs
// inside a kernel (see `STEPS_PER_SUBMIT`). Invocations past the count do nothing; a
// dispatch may be folded into two dimensions, as the step's.

// Per-chunk settings (the Rust twin is `ChunkParams`): the particles in the chunk and the
// index of its first particle.
struct ChunkParams {
    count: u32,
    first: u32,
    _pad1: u32,
    _pad2: u32,
}

// The pass's sizes (the Rust twin is `PairPassParams`): the particles, and the table's size,
// which is also the padded length of the keys.
struct PairPassParams {
    count: u32,
    table: u32,
    _pad0: u32,
    _pad1: u32,
}

// One dispatch of the bitonic sort (the Rust twin is `PairSortParams`): the stage `k` (the
// size of the runs it merges), the compare distance `j` of a pass over all the keys, the
// compare-exchanges of such a pass (half the keys), the keys a workgroup sorts in its own
// memory (`PAIR_SORT_BLOCK`, or all of them when fewer), and the last stage it runs.
struct PairSortParams {
    k: u32,
    j: u32,
    threads: u32,
    block: u32,
    k_last: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(1) var<storage, read_write> particles: array<Particle>;
@group(0) @binding(2) var<uniform> chunk: ChunkParams;
// Each particle's place in the sorted order, by its index in upload order.
@group(0) @binding(5) var<storage, read_write> pair_rank: array<u32>;
@group(0) @binding(10) var<uniform> pair_pass: PairPassParams;
@group(0) @binding(11) var<uniform> pair_sort: PairSortParams;
// The chunk's particles' leaf hints, as the march left them (kernel.wgsl's `hints`).
@group(0) @binding(13) var<storage, read> pair_hints: array<vec2<u32>>;

fn particle_index(wg: vec3<u32>, groups: vec3<u32>, local: u32) -> u32 {
    return (wg.y * groups.x + wg.x) * WORKGROUP_SIZE + local;
}

// Each adds one to a count kept as two words (WGSL passes no storage pointers).
fn count_fast() {
    if atomicAdd(&pair_state.fast_lo, 1u) == 0xffffffffu {
        atomicAdd(&pair_state.fast_hi, 1u);
    }
}

fn count_capped() {
    if atomicAdd(&pair_state.capped_lo, 1u) == 0xffffffffu {
        atomicAdd(&pair_state.capped_hi, 1u);
    }
}

// Over the table's size.
@compute @workgroup_size(WORKGROUP_SIZE)
fn pair_reset_kernel(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let t = particle_index(wg, groups, local);
    if t == 0u {
        atomicStore(&pair_state.v_max, 0u);
        atomicStore(&pair_state.deepest, 0u);
        pair_state.valid = 0u;
    }
    if t < pair_pass.table {
        pair_ranges[t] = vec2<u32>(0u);
    }
}

// The probe's columns (`PairProbe`): a key and a count per entry, twice the table's size,
// zeroed by the host before the probe.
@group(0) @binding(16) var<storage, read_write> pair_columns: array<atomic<u32>>;

// Per chunk. A particle left out of the pass takes no part in the largest speed. In the
// probe before a step (a zero substep), each particle also counts in its column: the first
// entry from its key's slot on that is empty or holds the key (a compare-exchange that fails
// spuriously is tried again on the same entry, so a column never takes two), and the most in
// one column is kept.
@compute @workgroup_size(WORKGROUP_SIZE)
fn pair_speed_kernel(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(wg, groups, local);
    if i >= chunk.count {
        return;
    }
    let s = pair_state.step;
    let prepared = pair_prepare(particles[i], s);
    if !prepared.some {
        return;
    }
    atomicMax(&pair_state.v_max, bitcast<u32>(prepared.speed));
    // (A probe for the speed alone leaves the diameter's inverse 0: no columns.)
    if s.h == 0.0 && s.inv_diameter != 0.0 {
        let key = pair_column_key(
            particles[i].position,
            pair_state.across0.xyz,
            pair_state.across1.xyz,
            s.inv_diameter,
        );
        let size = 2u * pair_pass.table;
        var slot = pair_column_slot(key, size - 1u);
        // At most half the entries are taken: an empty one or the column's own is found.
        for (var tries = 0u; tries < 4u * size; tries++) {
            let r = atomicCompareExchangeWeak(&pair_columns[2u * slot], 0u, key);
            if r.exchanged || r.old_value == key {
                let count = atomicAdd(&pair_columns[2u * slot + 1u], 1u) + 1u;
                atomicMax(&pair_state.deepest, count);
                break;
            }
            if r.old_value != 0u {
                slot = (slot + 1u) & (size - 1u);
            }
        }
    }
    if pair_is_fast(prepared.speed, s) {
        count_fast();
    }
}

// One invocation: what `PairStep::new` computes from the largest speed.
@compute @workgroup_size(1)
fn pair_step_kernel() {
    let s = pair_state.step;
    let v_max = bitcast<f32>(atomicLoad(&pair_state.v_max));
    let cell = pair_cell_edge(s.diameter, s.radius, v_max, s.h);
    pair_state.step.cell = cell;
    pair_state.step.inv_cell = 1.0 / cell;
    pair_state.step.relaxation = pair_state.relaxation;
}

// One invocation, after the march: the debiasing iterations' constants (Rust's
// `PairStep::unbiased`), until the next substep's `pair_step_kernel` restores the relaxation.
@compute @workgroup_size(1)
fn pair_unbias_kernel() {
    pair_state.step.relaxation = 0.0;
}

// Per chunk.
@compute @workgroup_size(WORKGROUP_SIZE)
fn pair_key_kernel(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(wg, groups, local);
    if i >= chunk.count {
        return;
    }
    let s = pair_state.step;
    let p = particles[i];
    var hash = PAIR_HASH_NONE;
    if pair_prepare(p, s).some {
        hash = pair_hash(pair_cell(p.position, s), s.mask);
    }
    let index = chunk.first + i;
    pair_keys[index] = vec2<u32>(hash, index);
}

// The order of core's `[hash, index]` keys.
fn key_less(a: vec2<u32>, b: vec2<u32>) -> bool {
    return a.x < b.x || (a.x == b.x && a.y < b.y);
}

// The compare-exchange of positions `i` (bit `j` clear) and `i + j` in stage `k`: ascending
// where bit `k` of `i` is clear, descending where it is set.
fn sort_swaps(a: vec2<u32>, b: vec2<u32>, i: u32, k: u32) -> bool {
    let ascending = (i & k) == 0u;
    return select(key_less(a, b), key_less(b, a), ascending);
}

// One pass over all the keys at a distance `j` of a block or more: one compare-exchange per
// invocation.
@compute @workgroup_size(WORKGROUP_SIZE)
fn pair_sort_pass_kernel(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let t = particle_index(wg, groups, local);
    if t >= pair_sort.threads {
        return;
    }
    let j = pair_sort.j;
    let i = ((t & ~(j - 1u)) << 1u) | (t & (j - 1u));
    let l = i | j;
    let a = pair_keys[i];
    let b = pair_keys[l];
    if sort_swaps(a, b, i, pair_sort.k) {
        pair_keys[i] = b;
        pair_keys[l] = a;
    }
}

var<workgroup> sort_block: array<vec2<u32>, PAIR_SORT_BLOCK>;

// A block of keys in workgroup memory, each invocation two of them: stages `k` to `k_last`,
// each at distances from `k / 2` (or half the block, the passes above it done before) down
// to 1. The loops' bounds are uniform: every invocation reaches every barrier.
@compute @workgroup_size(PAIR_SORT_THREADS)
fn pair_sort_block_kernel(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
) {
    let size = pair_sort.block;
    let half = size / 2u;
    let base = (wg.y * groups.x + wg.x) * size;
    // A folded dispatch's last row may hold workgroups past the keys (the same for the whole
    // workgroup, so every barrier is still reached by all or none).
    if base >= 2u * pair_sort.threads {
        return;
    }
    if t < half {
        sort_block[t] = pair_keys[base + t];
        sort_block[t + half] = pair_keys[base + t + half];
    }
    workgroupBarrier();
    var k = pair_sort.k;
    loop {
        var j = min(k / 2u, half);
        loop {
            if j == 0u {
                break;
            }
            if t < half {
                let i = ((t & ~(j - 1u)) << 1u) | (t & (j - 1u));
                let l = i | j;
                let a = sort_block[i];
                let b = sort_block[l];
                if sort_swaps(a, b, base + i, k) {
                    sort_block[i] = b;
                    sort_block[l] = a;
                }
            }
            workgroupBarrier();
            j = j / 2u;
        }
        if k >= pair_sort.k_last {
            break;
        }
        k = k * 2u;
    }
    if t < half {
        pair_keys[base + t] = sort_block[t];
        pair_keys[base + t + half] = sort_block[t + half];
    }
}

// Over the particles, in sorted order: each particle's place, the buckets' ends (as
// `collide_pairs` marks them), and the count of valid particles.
@compute @workgroup_size(WORKGROUP_SIZE)
fn pair_rank_kernel(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let k = particle_index(wg, groups, local);
    if k >= pair_pass.count {
        return;
    }
    let key = pair_keys[k];
    pair_rank[key.y] = k;
    let marks = pair_range_marks(k, pair_pass.table);
    if marks.x {
        pair_ranges[key.x].x = k;
    }
    if marks.y {
        pair_ranges[key.x].y = k + 1u;
    }
    if key.x != PAIR_HASH_NONE && (k + 1u == pair_pass.table || pair_keys[k + 1u].x == PAIR_HASH_NONE) {
        pair_state.valid = k + 1u;
    }
}

// Per chunk: a valid particle's body, at its place in the sorted order.
@compute @workgroup_size(WORKGROUP_SIZE)
fn pair_gather_kernel(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(wg, groups, local);
    if i >= chunk.count {
        return;
    }
    let index = chunk.first + i;
    let k = pair_rank[index];
    if k >= pair_state.valid {
        return;
    }
    let s = pair_state.step;
    let p = particles[i];
    let cell = pair_cell(p.position, s);
    pair_bodies[k] = PairBody(p.position, index, cell, pair_hash(cell, s.mask));
}

// Per chunk: a valid grain's velocity entering the iterations and its support, at its place
// in the sorted order (`pair_vel_next` is bound to the velocities entering the iterations
// here: the first iteration reads them, and every iteration reads them as `pair_vel_start`).
@compute @workgroup_size(WORKGROUP_SIZE)
fn pair_start_kernel(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(wg, groups, local);
    if i >= chunk.count {
        return;
    }
    let k = pair_rank[chunk.first + i];
    if k >= pair_state.valid {
        return;
    }
    load_header(0u, false);
    let start = pair_start(particles[i], pair_hints[i], pair_state.step);
    pair_vel_next[k] = start.v;
    pair_supports[k] = start.support;
}

// Each grain's support, found by the scene module's `scene_support_kernel` in a scene, by its
// index in upload order.
@group(0) @binding(15) var<storage, read> pair_given_supports: array<vec4<f32>>;

// Per chunk, in a scene: as `pair_start_kernel`, with the supports given.
@compute @workgroup_size(WORKGROUP_SIZE)
fn pair_start_given_kernel(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(wg, groups, local);
    if i >= chunk.count {
        return;
    }
    let k = pair_rank[chunk.first + i];
    if k >= pair_state.valid {
        return;
    }
    let start = pair_start_with(particles[i], pair_given_supports[chunk.first + i], pair_state.step);
    pair_vel_next[k] = start.v;
    pair_supports[k] = start.support;
}

// Over the particles, in sorted order: one Jacobi iteration of each valid one.
@compute @workgroup_size(WORKGROUP_SIZE)
fn pair_iterate_kernel(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let k = particle_index(wg, groups, local);
    if k >= pair_state.valid {
        return;
    }
    let out = pair_velocity(k, pair_state.step);
    pair_vel_next[k] = out.v;
    if out.capped {
        count_capped();
    }
}

// Per chunk, after the march: each valid particle's velocity, at its place in the sorted
// order, for the debiasing iterations (`pair_vel_next` is the first one's input here).
@compute @workgroup_size(WORKGROUP_SIZE)
fn pair_regather_kernel(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(wg, groups, local);
    if i >= chunk.count {
        return;
    }
    let k = pair_rank[chunk.first + i];
    if k >= pair_state.valid {
        return;
    }
    pair_vel_next[k] = vec4<f32>(particles[i].velocity, 0.0);
}

// Per chunk: the last iteration's velocity of each valid particle (`pair_vel` is the last
// iteration's output here); a particle left out keeps its own, gravity not added.
@compute @workgroup_size(WORKGROUP_SIZE)
fn pair_scatter_kernel(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(wg, groups, local);
    if i >= chunk.count {
        return;
    }
    let k = pair_rank[chunk.first + i];
    if k >= pair_state.valid {
        return;
    }
    particles[i].velocity = pair_vel[k].xyz;
}
