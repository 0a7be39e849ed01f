//! The particle record every backend steps, and the step parameters.

use bytemuck::{Pod, Zeroable};

/// Side value: the particle is in front of the surface (the side the normals point to).
pub const SIDE_FRONT: u32 = 0;
/// Side value: the particle is behind the surface.
pub const SIDE_BACK: u32 = 1;

/// Flag: the particle's position or velocity was NaN or infinite; it is left unchanged.
pub const FLAG_INVALID: u32 = 1 << 0;
/// Flag: the last step hit `max_leaves_per_step` and left the particle at its last safe point.
pub const FLAG_BOUND_HIT: u32 = 1 << 1;
/// Flag: the last step tried to leave the surface shell on the other side and was stopped.
pub const FLAG_BLOCKED: u32 = 1 << 2;
/// Mask of the status bits that each step recomputes.
pub const FLAG_STEP_STATUS: u32 = FLAG_BOUND_HIT | FLAG_BLOCKED;
/// Bits of `flags` that hold the status flags; the collision count sits above them.
pub const FLAG_STATUS_MASK: u32 = 0xff;
/// Shift of the saturating 24-bit collision counter inside `flags`.
pub const COLLISION_SHIFT: u32 = 8;
/// Largest collision count `flags` can hold.
pub const MAX_COLLISIONS: u32 = (1 << (32 - COLLISION_SHIFT)) - 1;

/// One particle, exactly as the GPU sees it: 32 bytes, `vec3` + scalar twice.
// Layout reason: `position, side, velocity, flags` is 32 bytes with no padding both in
// `#[repr(C)]` Rust and in WGSL, where a `vec3<f32>` has 16-byte alignment.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Particle {
    /// World-space position.
    pub position: [f32; 3],
    /// [`SIDE_FRONT`] or [`SIDE_BACK`]: the label of the last labelled empty leaf it crossed.
    pub side: u32,
    /// Velocity in units per second.
    pub velocity: [f32; 3],
    /// Status bits (low 8, `FLAG_*`) and the collision count (high 24, saturating).
    pub flags: u32,
}

const _: () = assert!(core::mem::size_of::<Particle>() == 32);

impl Particle {
    /// A particle at rest state with the given position and velocity, in front, no flags.
    pub const fn new(position: [f32; 3], velocity: [f32; 3]) -> Self {
        Self {
            position,
            side: SIDE_FRONT,
            velocity,
            flags: 0,
        }
    }

    /// Number of collisions this particle has had (saturates at [`MAX_COLLISIONS`]).
    pub const fn collisions(&self) -> u32 {
        self.flags >> COLLISION_SHIFT
    }
}
