//! `core/tests/properties.rs` against the no_std + alloc build of volwarp-core (ruzstd, libm).

#[path = "../../tests/properties.rs"]
mod properties;
