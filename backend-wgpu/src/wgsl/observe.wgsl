// The scene kernel's march observer, as core's `HitObserver` (less its host-only trace): the
// last collision in the world, whether the march stops at its first (a probe), and every
// collision to the event buffer when the march is the particle's path. The step reports each
// collision response to `observe_hit`.

// core's `HitObserver`, its GPU part.
struct HitObserver {
    stop: bool,
    emit: bool,
    count: u32,
    last: Hit,
    remaining: f32,
    leaf: u32,
    at: HitFrame,
}

var<private> observer: HitObserver;
// The particle being stepped, by its index in upload order (for its events).
var<private> event_particle: u32;

// What the scene steps report, kept until the host takes it: particle-steps crushed and with
// sides lost, the events stored and lost (64-bit counts as low and high words), and the events.
struct SceneOut {
    crushed_lo: atomic<u32>,
    crushed_hi: atomic<u32>,
    sides_lost_lo: atomic<u32>,
    sides_lost_hi: atomic<u32>,
    stored: atomic<u32>,
    lost_lo: atomic<u32>,
    lost_hi: atomic<u32>,
    _pad: u32,
    events: array<HitEvent>,
}

@group(0) @binding(7) var<storage, read_write> scene_out: SceneOut;

// Each adds one to a count kept as two words (WGSL passes no storage pointers).
fn count_crushed() {
    if atomicAdd(&scene_out.crushed_lo, 1u) == 0xffffffffu {
        atomicAdd(&scene_out.crushed_hi, 1u);
    }
}

fn count_sides_lost() {
    if atomicAdd(&scene_out.sides_lost_lo, 1u) == 0xffffffffu {
        atomicAdd(&scene_out.sides_lost_hi, 1u);
    }
}

fn count_lost_event() {
    if atomicAdd(&scene_out.lost_lo, 1u) == 0xffffffffu {
        atomicAdd(&scene_out.lost_hi, 1u);
    }
}

// core's `HitObserver::new`.
fn observe(stop: bool, emit: bool, at: HitFrame) {
    observer.stop = stop;
    observer.emit = emit;
    observer.count = 0u;
    observer.last = no_hit();
    observer.remaining = 0.0;
    observer.leaf = NO_LEAF;
    observer.at = at;
}

// One event, stored while there is room, else counted as lost. The stored count never passes
// the capacity for long (an add past it is taken back), so it cannot wrap.
fn push_event(hit: Hit) {
    if scene_params.event_capacity == 0u {
        return;
    }
    let k = atomicAdd(&scene_out.stored, 1u);
    if k < scene_params.event_capacity {
        let whole = hit_in_whole_step(hit, scene_params.substep, scene_params.substeps);
        scene_out.events[k] = HitEvent(scene_params.step, event_particle, whole);
    } else {
        atomicSub(&scene_out.stored, 1u);
        count_lost_event();
    }
}

fn observe_hit(x: vec3<f32>, n: vec3<f32>, before: vec3<f32>, after: vec3<f32>, remaining: f32, leaf: u32) -> bool {
    observer.count += 1u;
    observer.last = hit_frame_hit(observer.at, x, n, before, remaining);
    observer.remaining = remaining;
    observer.leaf = leaf;
    if observer.emit {
        push_event(observer.last);
    }
    return observer.stop;
}
