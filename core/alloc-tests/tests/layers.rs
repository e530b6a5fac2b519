//! `core/tests/layers.rs` against the no_std + alloc build of volwarp-core (ruzstd, libm).

#[path = "../../tests/layers.rs"]
mod layers;
