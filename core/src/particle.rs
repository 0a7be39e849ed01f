//! The particle record every backend steps, and the step parameters.

use bytemuck::{Pod, Zeroable};

/// Side value: the particle is in front of the surface (the side the normals point to).
pub const SIDE_FRONT: u32 = 0;
/// Side value: the particle is behind the surface.
pub const SIDE_BACK: u32 = 1;
/// The bit of [`Particle::side`] that holds the side, [`SIDE_FRONT`] or [`SIDE_BACK`].
pub const SIDE_MASK: u32 = 1;
/// Set in [`Particle::side`] while the particle is **caged**: it started strictly inside a
/// solid (two-sided) surface leaf, where one side bit cannot say which of the surfaces in the
/// leaf it is behind, and it may leave that leaf only through the faces its exit bits name
/// ([`SIDE_EXITS_MASK`]); the others hold it like walls. The host sets it from the mesh
/// (`octoproxy_cpu::Sides::cages`); a step clears it when the particle leaves through an exit,
/// or when it is not strictly inside a solid leaf at the start of a step (a proxy of its own
/// is needed: reset it with the hints when the proxy changes).
pub const SIDE_CAGED: u32 = 1 << 7;
/// Shift of a caged particle's six exit bits in [`Particle::side`]: bit `SIDE_EXITS_SHIFT + 2
/// * axis + upper` lets it leave its cage through the face across `axis` (0 = x, 1 = y, 2 =
/// z) on the cage's upper (`upper` = 1) or lower side ([`side_exit`]).
pub const SIDE_EXITS_SHIFT: u32 = 1;
/// Mask of the six exit bits in [`Particle::side`], in place.
pub const SIDE_EXITS_MASK: u32 = 0x3f << SIDE_EXITS_SHIFT;
/// Set in [`Particle::side`], with [`SIDE_CAGED`] and one exit bit, while the particle is in
/// the **slab** of a solid leaf: it came in through the exit's face, where the leaf's
/// clearance says no triangle lies within some depth of it (`NodeRecord::clearance`), and it
/// moves in that slab, collides at its inner side (nearer the surface than the face), and
/// leaves through the face, or through a side of the slab back onto the face. The step sets
/// and clears it; a file of particles keeps it between runs with the same proxy.
pub const SIDE_SLAB: u32 = 1 << 8;
/// Mask of the cage in [`Particle::side`]: [`SIDE_CAGED`], the exit bits and [`SIDE_SLAB`].
pub const SIDE_CAGE_MASK: u32 = SIDE_CAGED | SIDE_EXITS_MASK | SIDE_SLAB;

/// The exit bit of [`Particle::side`] for a cage's face across `axis` (0 = x, 1 = y, 2 = z)
/// on its upper (`upper`) or lower side.
pub const fn side_exit(axis: u32, upper: bool) -> u32 {
    1 << (SIDE_EXITS_SHIFT + 2 * axis + upper as u32)
}

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
    /// Bit 0 ([`SIDE_MASK`]): [`SIDE_FRONT`] or [`SIDE_BACK`], the label of the last
    /// labelled empty leaf it crossed. Bits 1–8: zero, or the cage of a particle that started
    /// inside a solid leaf ([`SIDE_CAGED`], [`SIDE_EXITS_MASK`]) or is in a solid leaf's slab
    /// ([`SIDE_SLAB`]). A step ignores the bits above and leaves them zero.
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

    /// Its side, [`SIDE_FRONT`] or [`SIDE_BACK`], without the cage bits.
    pub const fn side_only(&self) -> u32 {
        self.side & SIDE_MASK
    }

    /// Whether it is caged in the solid leaf it started in ([`SIDE_CAGED`]).
    pub const fn is_caged(&self) -> bool {
        self.side & SIDE_CAGED != 0
    }
}
