// Entry points: one invocation per particle and one step per dispatch; the host records one
// dispatch per step, with no read-back in between. Particles beyond `chunk.count` (the last workgroup's tail) do nothing. The
// dispatch may be folded into two dimensions when a chunk needs more than 65,535 workgroups.

// Per-call settings shared by every chunk (the Rust twin is `RunParams`).
struct RunParams {
    use_lut: u32,
    // The plain step's invocations per workgroup and the widest row of workgroups, for the
    // split step's `args_kernel`.
    workgroup_size: u32,
    fold_width: u32,
    _pad2: u32,
}

// Per-chunk settings (the Rust twin is `ChunkParams`): the particles in the chunk and the
// index of its first particle.
struct ChunkParams {
    count: u32,
    first: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(1) var<storage, read_write> particles: array<Particle>;
@group(0) @binding(2) var<uniform> params: StepParams;
@group(0) @binding(3) var<uniform> run: RunParams;
@group(0) @binding(4) var<uniform> chunk: ChunkParams;
// Each particle's `LeafHint` (core), kept between steps; zeroed when the proxy or the
// particles are replaced.
@group(0) @binding(5) var<storage, read_write> hints: array<vec2<u32>>;

fn particle_index(wg: vec3<u32>, groups: vec3<u32>, local: u32) -> u32 {
    return (wg.y * groups.x + wg.x) * WORKGROUP_SIZE + local;
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn step_kernel(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(wg, groups, local);
    if i >= chunk.count {
        return;
    }
    load_header(0u, run.use_lut != 0u);
    var p = particles[i];
    var hint = hints[i];
    step_particle_hinted(&p, params, &hint);
    particles[i] = p;
    hints[i] = hint;
}

// The split step (`WgpuBackend::set_split_step`): three dispatches per chunk that step each
// particle exactly as `step_kernel` does. `settle_kernel` steps the particles that settle in
// their hinted leaf (most of them, at a few loads each) and queues the others;
// `args_kernel` turns the queue's length into workgroups for `march_kernel`, dispatched
// indirectly, which steps the queued ones. Its workgroups hold only particles that march,
// so lanes that settle do not idle beside lanes that march, as they do in `step_kernel`'s.
// Which slot a particle takes in the queue varies from run to run; what it steps to does not.
struct Queue {
    count: atomic<u32>,
    // The length `args_kernel` found (and reset `count` from) for `march_kernel`.
    n: u32,
    _pad0: u32,
    _pad1: u32,
}

// Indirect dispatch arguments: workgroups in x, y and z.
struct DispatchArgs {
    x: u32,
    y: u32,
    z: u32,
    _pad: u32,
}

@group(0) @binding(6) var<storage, read_write> queued: array<u32>;
@group(0) @binding(7) var<storage, read_write> queue: Queue;
// Bound only for `args_kernel` (the buffer is `march_kernel`'s indirect argument).
@group(0) @binding(8) var<storage, read_write> march_args: DispatchArgs;

// The workgroup's queued particles, counted in workgroup memory, and where they go in the
// queue: one global atomic per workgroup, not one per queued particle.
var<workgroup> queued_here: atomic<u32>;
var<workgroup> queued_base: u32;

@compute @workgroup_size(WORKGROUP_SIZE)
fn settle_kernel(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(wg, groups, local);
    if local == 0u {
        atomicStore(&queued_here, 0u);
    }
    workgroupBarrier();
    var slot = 0xffffffffu;
    if i < chunk.count {
        load_header(0u, run.use_lut != 0u);
        var p = particles[i];
        // `step_particle_hinted`'s first settle: it leaves the hint as it is.
        if settle_in_hinted_leaf(&p, params, hints[i]) {
            particles[i] = p;
        } else {
            slot = atomicAdd(&queued_here, 1u);
        }
    }
    workgroupBarrier();
    if local == 0u {
        queued_base = atomicAdd(&queue.count, atomicLoad(&queued_here));
    }
    let base = workgroupUniformLoad(&queued_base);
    if slot != 0xffffffffu {
        queued[base + slot] = i;
    }
}

@compute @workgroup_size(1)
fn args_kernel() {
    let n = atomicLoad(&queue.count);
    atomicStore(&queue.count, 0u);
    queue.n = n;
    let size = max(run.workgroup_size, 1u);
    let groups = n / size + select(0u, 1u, n % size != 0u);
    let fold = max(run.fold_width, 1u);
    if groups <= fold {
        march_args = DispatchArgs(groups, 1u, 1u, 0u);
    } else {
        march_args = DispatchArgs(fold, groups / fold + select(0u, 1u, groups % fold != 0u), 1u, 0u);
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn march_kernel(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let j = particle_index(wg, groups, local);
    if j >= queue.n {
        return;
    }
    load_header(0u, run.use_lut != 0u);
    let i = queued[j];
    var p = particles[i];
    var hint = hints[i];
    step_particle_hinted(&p, params, &hint);
    particles[i] = p;
    hints[i] = hint;
}

// The floor: the same particles, integrated with no collision at all (semi-implicit Euler,
// as the step integrates). What a step costs beyond memory traffic is measured against it.
@compute @workgroup_size(WORKGROUP_SIZE)
fn integrate_kernel(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(wg, groups, local);
    if i >= chunk.count {
        return;
    }
    var p = particles[i];
    let v = p.velocity + params.gravity * params.dt;
    p.velocity = v;
    p.position = p.position + v * params.dt;
    particles[i] = p;
}
