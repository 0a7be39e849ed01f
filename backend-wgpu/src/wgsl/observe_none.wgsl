// The plain kernel's march observer: nothing. The step reports each collision response to
// `observe_hit`, which in this module records nothing and never stops the march (core's
// `Unobserved`); the scene kernel's observe.wgsl records hits and events.
fn observe_hit(x: vec3<f32>, n: vec3<f32>, before: vec3<f32>, after: vec3<f32>, remaining: f32, leaf: u32) -> bool {
    return false;
}
