//! The datasets beside the project in development and CI (`../shared/data`), for tests and
//! benchmarks that compare on real volumes besides the bundled ones in `data/`.
//!
//! A test that needs one of them asks [`shared_data`]: where the file is missing the test
//! **fails** with a message saying so, unless `VOLWARP_NO_SHARED_DATA=1` says that this is a
//! bare clone without `../shared/` (then the test says what it leaves out and passes). CI always
//! has `../shared/`, so what CI is meant to check is never skipped silently.

use crate::Dataset;
use std::path::PathBuf;

/// The folder of the shared datasets.
pub const SHARED_DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data");

/// The MRI head of the shared datasets (the project's main benchmark volume).
pub const MRI: &str = "mri_colin27_181x217x181_uint8.raw";

/// [`MRI`]'s path in [`SHARED_DATA`], for benchmarks and examples that fall back to other data
/// where it is missing.
pub const MRI_PATH: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/mri_colin27_181x217x181_uint8.raw");

/// Whether `VOLWARP_NO_SHARED_DATA=1` allows tests to leave out the shared datasets.
pub fn shared_data_optional() -> bool {
    std::env::var("VOLWARP_NO_SHARED_DATA").is_ok_and(|v| v == "1")
}

/// The path of `file` in [`SHARED_DATA`]; `None` only where it is missing and
/// `VOLWARP_NO_SHARED_DATA=1` (saying so on stderr).
///
/// # Panics
/// Where the file is missing and the switch is not set: a test that needs it must not pass
/// without it.
pub fn shared_data(file: &str) -> Option<PathBuf> {
    let path = PathBuf::from(SHARED_DATA).join(file);
    if path.is_file() {
        return Some(path);
    }
    if shared_data_optional() {
        eprintln!("VOLWARP_NO_SHARED_DATA=1: {} is missing, so what needs it is not checked", path.display());
        return None;
    }
    panic!(
        "{} is missing: this test needs the shared datasets beside the project (set VOLWARP_NO_SHARED_DATA=1 \
         in a bare clone to leave them out explicitly)",
        path.display()
    );
}

/// [`shared_data`] loaded as a dataset with its preset transfer function.
///
/// # Panics
/// Where the file is missing (unless the switch is set), and always where it is present but
/// does not load.
pub fn shared_dataset(file: &str) -> Option<Dataset> {
    let path = shared_data(file)?;
    Some(Dataset::load(&path, None).unwrap_or_else(|e| panic!("{} does not load: {e}", path.display())))
}
