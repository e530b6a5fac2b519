//! volwarp thin client with a minifb window (in progress).
//!
//! Nothing here yet: this crate is a placeholder member of the workspace.
