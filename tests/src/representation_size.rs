//! Representation size (TODO).
use crate::ErrorBox;
use std::path::Path;
use volwarp_core::Heuristic;
use volwarp_server::dataset::Dataset;
/// Runs it.
pub fn run(_ds: &Dataset, _h: Heuristic, _size: u32, _out: &Path) -> Result<(), ErrorBox> {
    Err("todo".into())
}
