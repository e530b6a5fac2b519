//! volwarp server: volumes, ray marcher, frames over TCP (in progress).
//!
//! Nothing here yet: this crate is a placeholder member of the workspace.
