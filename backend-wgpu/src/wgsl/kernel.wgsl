// Entry points: one invocation per particle and one step per dispatch; the host records one
// dispatch per step, with no read-back in between. Particles beyond `chunk.count` (the last workgroup's tail) do nothing. The
// dispatch may be folded into two dimensions when a chunk needs more than 65,535 workgroups.

// Per-call settings shared by every chunk (the Rust twin is `RunParams`).
struct RunParams {
    use_lut: u32,
    _pad0: u32,
    _pad1: u32,
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
