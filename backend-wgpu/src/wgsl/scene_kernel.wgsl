// The scene kernel's entry points: one invocation per particle and one scene step per
// dispatch, as kernel.wgsl's (`scene_kernel`); and each grain's support for the
// particle-particle pass in a scene (`scene_support_kernel`). Bindings 0 (proxy), 5 (scene), 6 (scene_params) and 7 (scene_out) are
// declared with what reads them.

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
@group(0) @binding(3) var<uniform> chunk: ChunkParams;
// Each particle's sides for the instances of the scene, in core's two parts.
@group(0) @binding(4) var<storage, read_write> scene_hints: array<SceneHint>;
@group(0) @binding(8) var<storage, read_write> scene_slots: array<SceneSlots>;
// Each particle's last collision in the step, written when asked for.
@group(0) @binding(9) var<storage, read_write> hits: array<Hit>;

fn particle_index(wg: vec3<u32>, groups: vec3<u32>, local: u32) -> u32 {
    return (wg.y * groups.x + wg.x) * WORKGROUP_SIZE + local;
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn scene_kernel(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(wg, groups, local);
    if i >= chunk.count {
        return;
    }
    event_particle = chunk.first + i;
    var p = particles[i];
    var hint = scene_hints[i];
    var hit = no_hit();
    let c = scene_params.plain;
    if c != NO_INSTANCE && (hint.first_slot >> SLOT_INSTANCE_SHIFT) == c && hint.hint_instance == c {
        // The plain step, which reads no other slot (the CPU backend's loop does the same).
        step_plain(c, &p, &hint, params, &hit);
    } else {
        var slots = scene_slots[i];
        step_particle_scene(&p, &hint, &slots, params, &hit);
        scene_slots[i] = slots;
    }
    particles[i] = p;
    scene_hints[i] = hint;
    // A step of several substeps keeps each particle's last hit of any of them.
    if scene_params.hits != 0u && (hit.instance >= 0 || scene_params.substep == 0u) {
        hits[i] = hit_in_whole_step(hit, scene_params.substep, scene_params.substeps);
    }
    if (p.flags & FLAG_CRUSHED) != 0u {
        count_crushed();
    }
    if (p.flags & FLAG_SIDES_LOST) != 0u {
        count_sides_lost();
    }
}

// Each grain's support on the scene for the particle-particle pass (core's
// `pair_support_scene`), by its index in upload order, for the pass's `pair_start_given_kernel`.
@group(0) @binding(10) var<storage, read_write> scene_supports: array<vec4<f32>>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn scene_support_kernel(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(wg, groups, local);
    if i >= chunk.count {
        return;
    }
    scene_supports[chunk.first + i] = pair_support_scene(particles[i], scene_hints[i], scene_slots[i]);
}
