//! Every float intrinsic the step uses, in one place, routed through `libm` so results do
//! not change when some other crate turns on glam's `std` feature. WGSL mirrors these.

/// Square root.
#[inline]
pub(crate) fn sqrt(x: f32) -> f32 {
    libm::sqrtf(x)
}

/// Largest integer not above `x`: exactly `floorf`, zero's sign and NaN included, inline
/// (`libm::floorf` is a call of a dozen branches where the CPU has no rounding instruction
/// in its baseline, as x86-64's SSE2). From `2^23` up, and for non-finite values, a float is
/// its own floor; below, truncation toward zero, less one where that went up (a negative
/// non-integer).
#[inline(always)]
pub(crate) fn floor(x: f32) -> f32 {
    if !(abs(x) < 8_388_608.0) || x == 0.0 {
        return x;
    }
    let t = x as i32 as f32;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

/// Absolute value.
#[inline]
pub(crate) fn abs(x: f32) -> f32 {
    libm::fabsf(x)
}
