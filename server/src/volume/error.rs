//! The loaders' error type: the file (if known) and what is wrong with it.

use std::fmt;
use std::path::{Path, PathBuf};

/// What went wrong while loading a volume.
#[derive(Debug)]
pub enum VolumeErrorKind {
    /// The file could not be opened or read.
    Io(std::io::Error),
    /// The raw file name does not carry `_XxYxZ_type` and no options supplied them.
    BadName(String),
    /// The file holds a different number of bytes than the dims and type need.
    SizeMismatch {
        /// Bytes the header or name implies.
        expected: u64,
        /// Bytes found.
        actual: u64,
    },
    /// The voxel type is not one of [`VoxelType`](super::VoxelType).
    UnknownType(String),
    /// The NRRD header is malformed.
    BadHeader(String),
    /// A valid header asks for something this loader does not do (e.g. bzip2 encoding).
    Unsupported(String),
    /// More voxels than [`LoadOptions::max_voxels`](super::LoadOptions::max_voxels).
    TooLarge {
        /// Voxels the file declares.
        voxels: u64,
        /// The limit.
        limit: u64,
    },
    /// The volume needs more memory than the load may take
    /// ([`LoadOptions::memory`](super::LoadOptions::memory)).
    OutOfMemory {
        /// Bytes the volume needs (its bricks, the grids and any decoding buffer).
        needed: u64,
        /// Bytes available (`None`: an allocation failed).
        available: Option<u64>,
    },
    /// Gzip data that does not decompress.
    Decompress(String),
    /// A dimension or spacing is zero, negative or not finite.
    BadGeometry(String),
    /// A file of one of the other formats (NIfTI, TIFF, VTK image data, DICOM) that is not
    /// well formed, or a set of files that do not make one volume.
    Malformed {
        /// The format ("NIfTI", "TIFF", "VTK image data", "DICOM").
        format: &'static str,
        /// What is wrong.
        detail: String,
    },
}

/// A loader error: the file (if known) and what is wrong with it.
#[derive(Debug)]
pub struct VolumeError {
    /// The file the error is about.
    pub path: Option<PathBuf>,
    /// What is wrong.
    pub kind: VolumeErrorKind,
}

impl VolumeError {
    /// An error without a path (yet).
    pub fn new(kind: VolumeErrorKind) -> Self {
        VolumeError { path: None, kind }
    }

    /// A [`VolumeErrorKind::Malformed`] error.
    pub fn malformed(format: &'static str, detail: impl Into<String>) -> Self {
        VolumeError::new(VolumeErrorKind::Malformed { format, detail: detail.into() })
    }

    /// A [`VolumeErrorKind::Unsupported`] error.
    pub fn unsupported(what: impl Into<String>) -> Self {
        VolumeError::new(VolumeErrorKind::Unsupported(what.into()))
    }

    /// An I/O error about `path`.
    pub fn io(path: &Path, e: std::io::Error) -> Self {
        VolumeError::new(VolumeErrorKind::Io(e)).at(path)
    }

    /// The same error about `path` (keeps an existing path).
    pub fn at(mut self, path: &Path) -> Self {
        if self.path.is_none() {
            self.path = Some(path.to_path_buf());
        }
        self
    }
}

impl fmt::Display for VolumeErrorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            VolumeErrorKind::Io(e) => write!(f, "cannot read: {e}"),
            VolumeErrorKind::BadName(s) => write!(f, "{s}"),
            VolumeErrorKind::SizeMismatch { expected, actual } => {
                write!(f, "size mismatch: expected {expected} bytes of voxel data, found {actual}")
            }
            VolumeErrorKind::UnknownType(t) => write!(f, "unknown voxel type {t:?}"),
            VolumeErrorKind::BadHeader(s) => write!(f, "bad NRRD header: {s}"),
            VolumeErrorKind::Unsupported(s) => write!(f, "unsupported: {s}"),
            VolumeErrorKind::TooLarge { voxels, limit } => {
                write!(f, "{voxels} voxels is over the limit of {limit}")
            }
            VolumeErrorKind::OutOfMemory { needed, available } => {
                let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
                match available {
                    Some(a) => write!(
                        f,
                        "needs {:.2} GiB of memory, {:.2} GiB available (--max-memory SIZE or --max-memory none to load it anyway)",
                        gib(*needed),
                        gib(*a)
                    ),
                    None => write!(f, "could not allocate {:.2} GiB of memory", gib(*needed)),
                }
            }
            VolumeErrorKind::Decompress(s) => write!(f, "gzip data does not decompress: {s}"),
            VolumeErrorKind::BadGeometry(s) => write!(f, "{s}"),
            VolumeErrorKind::Malformed { format, detail } => write!(f, "bad {format} data: {detail}"),
        }
    }
}

impl fmt::Display for VolumeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.path {
            Some(p) => write!(f, "{}: {}", p.display(), self.kind),
            None => write!(f, "{}", self.kind),
        }
    }
}

impl std::error::Error for VolumeError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match &self.kind {
            VolumeErrorKind::Io(e) => Some(e),
            _ => None,
        }
    }
}
