//! volwarp evaluation and integration tests (in progress).
//!
//! Nothing here yet: this crate is a placeholder member of the workspace.
