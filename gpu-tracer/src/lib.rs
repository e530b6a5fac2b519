//! wgpu compute tracer of volwarp scenes (in progress).
//!
//! Nothing here yet: this crate is a placeholder member of the workspace.
