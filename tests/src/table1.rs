//! The paper's Table 1 (TODO).
use crate::ErrorBox;
use std::path::Path;
use volwarp_core::Heuristic;
use volwarp_server::dataset::Dataset;
/// Runs it.
#[allow(clippy::too_many_arguments)]
pub fn run(
    _ds: &Dataset,
    _h: Heuristic,
    _size: u32,
    _runs: usize,
    _threads: usize,
    _gpu: bool,
    _out: &Path,
    _results: Option<&Path>,
) -> Result<(), ErrorBox> {
    Err("todo".into())
}
