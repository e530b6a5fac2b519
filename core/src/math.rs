//! Scalar math that must give bit-identical results in every tracer.

/// Correctly rounded square root (IEEE 754), the same on every target.
#[inline(always)]
pub(crate) fn sqrt(x: f32) -> f32 {
    #[cfg(feature = "std")]
    {
        x.sqrt()
    }
    #[cfg(not(feature = "std"))]
    {
        libm::sqrtf(x)
    }
}

/// Tangent, used only for camera set-up.
#[inline]
pub(crate) fn tan(x: f32) -> f32 {
    libm::tanf(x)
}
