//! Every float intrinsic the step uses, in one place, routed through `libm` so results do
//! not change when some other crate turns on glam's `std` feature. WGSL mirrors these.

/// Square root.
#[inline]
pub(crate) fn sqrt(x: f32) -> f32 {
    libm::sqrtf(x)
}

/// Largest integer not above `x`.
#[inline]
pub(crate) fn floor(x: f32) -> f32 {
    libm::floorf(x)
}

/// Absolute value.
#[inline]
pub(crate) fn abs(x: f32) -> f32 {
    libm::fabsf(x)
}
