//! A dataset: a volume with its transfer function, and the bundled default.

use crate::transfer_function::{TfError, TransferFunction};
use crate::volume::{load_volume, LoadOptions, Volume, VolumeError};
use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The bundled default volume, relative to the `data/` folder.
pub const DEFAULT_VOLUME: &str = "ct_head_quarter.nhdr";

/// A volume and the transfer function it is shown with.
#[derive(Clone, Debug)]
pub struct Dataset {
    /// A short name (the volume's).
    pub name: String,
    /// The volume (shared with marchers).
    pub volume: Arc<Volume>,
    /// The transfer function.
    pub tf: TransferFunction,
}

/// A dataset that could not be loaded.
#[derive(Debug)]
pub enum DatasetError {
    /// The volume.
    Volume(VolumeError),
    /// The transfer function.
    TransferFunction(TfError),
}

impl fmt::Display for DatasetError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DatasetError::Volume(e) => write!(f, "volume {e}"),
            DatasetError::TransferFunction(e) => write!(f, "transfer function {e}"),
        }
    }
}

impl std::error::Error for DatasetError {}

impl Dataset {
    /// A dataset from a volume and a transfer function.
    pub fn new(volume: Volume, tf: TransferFunction) -> Dataset {
        Dataset { name: volume.name.clone(), volume: Arc::new(volume), tf }
    }

    /// A volume with its preset transfer function ([`TransferFunction::preset_for`] of its name
    /// and dims).
    pub fn with_preset(volume: Volume) -> Dataset {
        let tf = TransferFunction::preset_for(&volume.name, volume.dims());
        Dataset::new(volume, tf)
    }

    /// Loads a volume (raw or NRRD) and a transfer function file, or the preset for the
    /// volume's name and dims ([`TransferFunction::preset_for`]) when `tf` is `None`.
    pub fn load(path: impl AsRef<Path>, tf: Option<&Path>) -> Result<Dataset, DatasetError> {
        Dataset::load_with(path, &LoadOptions::default(), tf)
    }

    /// [`Dataset::load`] with loader options.
    pub fn load_with(path: impl AsRef<Path>, opts: &LoadOptions, tf: Option<&Path>) -> Result<Dataset, DatasetError> {
        let volume = load_volume(path, opts).map_err(DatasetError::Volume)?;
        let tf = match tf {
            Some(p) => TransferFunction::load(p, volume.value_range()).map_err(DatasetError::TransferFunction)?,
            None => TransferFunction::preset_for(&volume.name, volume.dims()),
        };
        Ok(Dataset::new(volume, tf))
    }

    /// The procedural Marschner–Lobb volume (`n³`) with its preset.
    pub fn marschner_lobb(n: u32) -> Dataset {
        Dataset::with_preset(Volume::marschner_lobb(n))
    }

    /// The bundled default ([`DEFAULT_VOLUME`] in [`data_dir`]); if it cannot be found or
    /// loaded, the Marschner–Lobb volume (64³), with a log line saying so.
    pub fn default_bundled() -> Dataset {
        match data_dir() {
            Some(dir) => match Dataset::load(dir.join(DEFAULT_VOLUME), None) {
                Ok(d) => return d,
                Err(e) => log::warn!("bundled dataset unusable ({e}); using the procedural Marschner-Lobb volume"),
            },
            None => log::warn!("no data/ folder found; using the procedural Marschner-Lobb volume"),
        }
        Dataset::marschner_lobb(64)
    }
}

/// The bundled `data/` folder: `$VOLWARP_DATA` if set, else `data/` of the source checkout
/// (next to this crate), else a `data/` folder beside the executable or one of its ancestors.
pub fn data_dir() -> Option<PathBuf> {
    let is_data = |p: &Path| p.join(DEFAULT_VOLUME).is_file();
    if let Some(p) = std::env::var_os("VOLWARP_DATA").map(PathBuf::from) {
        if is_data(&p) {
            return Some(p);
        }
    }
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join("data");
    if is_data(&src) {
        return Some(src);
    }
    let exe = std::env::current_exe().ok()?;
    exe.ancestors().skip(1).map(|a| a.join("data")).find(|p| is_data(p))
}
