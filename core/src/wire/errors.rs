//! The payload codecs' errors, carried by [`super::WireError`] (the codecs themselves, above
//! the framing, re-export them: `compact_frame::CompactError`, `segments::LayerError`).

/// Why a compact frame could not be decoded. Carried by [`WireError::Compact`](super::WireError::Compact).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CompactError {
    /// The depth origin or step is NaN, infinite, not positive, or the largest depth code
    /// decodes to a non-finite depth.
    BadDepth,
    /// The radius model's constant or slope is NaN or infinite.
    BadRadiusModel,
    /// Unknown entropy coder code.
    BadCoder(u8),
    /// The stated decompressed length is not `⌈w·h/8⌉ + 8·count`.
    BadRawLength {
        /// Stated.
        stated: u32,
        /// What the header's dimensions and count give.
        expected: u64,
    },
    /// The entropy-coded body is corrupt (zstd refused it, it decompresses to another length,
    /// or a stored body has the wrong length).
    Corrupt,
    /// The coverage mask has another number of set bits than the sample count, or bits set
    /// past the last pixel.
    MaskCount {
        /// Set bits of the mask (within the viewport).
        mask: u32,
        /// The header's sample count.
        count: u32,
    },
    /// A radius residual outside the 10-bit code range.
    BadRadiusResidual,
    /// Unknown color coding code (byte 113).
    BadColorCoding(u8),
}

impl core::fmt::Display for CompactError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            CompactError::BadDepth => f.write_str("compact frame: bad depth origin or step"),
            CompactError::BadRadiusModel => f.write_str("compact frame: bad radius model"),
            CompactError::BadCoder(c) => write!(f, "compact frame: unknown entropy coder {c}"),
            CompactError::BadRawLength { stated, expected } => {
                write!(f, "compact frame: body length {stated}, expected {expected}")
            }
            CompactError::Corrupt => f.write_str("compact frame: corrupt compressed body"),
            CompactError::MaskCount { mask, count } => {
                write!(f, "compact frame: coverage mask has {mask} pixels, header says {count} samples")
            }
            CompactError::BadRadiusResidual => f.write_str("compact frame: radius residual out of range"),
            CompactError::BadColorCoding(c) => write!(f, "compact frame: unknown color coding {c}"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for CompactError {}

/// Why a layered frame's segments were refused (`WireError::Layers`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LayerError {
    /// The frame has more segments per pixel than the receiver negotiated (or than
    /// [`crate::wire::MAX_LAYERS`]).
    TooManyLayers {
        /// The frame's layer count.
        layers: u8,
        /// The receiver's maximum.
        limit: u8,
    },
    /// Sample `index`'s segment index is not 0 (a new pixel) or the previous one + 1, or is not
    /// below the frame's layer count.
    BadIndex {
        /// The sample.
        index: usize,
    },
    /// Sample `index` is not strictly behind the previous segment of its pixel (depths unsorted
    /// or overlapping), or not on the same pixel's ray.
    Unsorted {
        /// The sample.
        index: usize,
    },
    /// Sample `index`'s premultiplied color has a channel above its opacity (an opacity-
    /// normalised color above 1).
    Opacity {
        /// The sample.
        index: usize,
    },
    /// The segment plane's length differs from the sample count, or a layer's part of a
    /// LayeredCompactFrame disagrees with the frame (header, nesting of the layers' masks).
    Inconsistent,
    /// A layered frame where only a one-sample-per-pixel frame can be read (the allocation-free
    /// `wire::read_frame_header`).
    Layered,
}

impl core::fmt::Display for LayerError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            LayerError::TooManyLayers { layers, limit } => {
                write!(f, "layered frame with {layers} segments per pixel, over the negotiated {limit}")
            }
            LayerError::BadIndex { index } => write!(f, "layered frame: bad segment index at sample {index}"),
            LayerError::Unsorted { index } => {
                write!(f, "layered frame: sample {index} is not behind its pixel's previous segment")
            }
            LayerError::Opacity { index } => write!(f, "layered frame: sample {index} has color above its opacity"),
            LayerError::Inconsistent => f.write_str("layered frame: segment data inconsistent with the frame"),
            LayerError::Layered => f.write_str("layered frame where a one-sample-per-pixel frame was expected"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for LayerError {}
