// The records the kernels share with core: a particle (core/src/particle.rs) and the step's
// parameters (core/src/step.rs). The step, the scene step and the particle-particle pass all
// read them.

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
    radius: f32,
    _pad: u32,
}
