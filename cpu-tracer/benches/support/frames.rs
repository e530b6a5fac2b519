//! Real frames for the benchmark (none until the server library is a dependency).

use volwarp_core::wire::Frame;

/// A server render of the MRI at `res`², with a description; `None` when unavailable.
pub fn mri_frame(_res: u32) -> Option<(Frame, String)> {
    None
}
