//! Nothing: the tests under `tests/` run volwarp-core's own tests against its no_std + alloc
//! build (see `Cargo.toml`).
#![no_std]
