//! `core/tests/compact_frame.rs` against the no_std + alloc build of volwarp-core: the compact
//! codec with ruzstd's encoder and decoder and libm's math, as a no_std client runs it.

#[path = "../../tests/compact_frame.rs"]
mod compact_frame;

/// The build under test really is the alloc-only one (no `std` feature).
#[test]
fn core_is_built_without_std() {
    assert!(!volwarp_core::BUILT_WITH_STD, "volwarp-core was built with std: features were unified");
}
