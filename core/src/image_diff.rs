//! How two images of the same size differ: the share of bit-identical pixels and the largest
//! channel difference. The fast-path-against-reference checks (GPU vs CPU, SIMD vs scalar) and
//! `volwarp-compare` all count with this one definition.

use crate::renderer::Image;

/// The identical-pixel share a renderer must reach against its reference (GPU vs CPU tracer).
pub const TARGET_IDENTICAL: f64 = 0.999;

/// How two images of the same size differ.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImageDiff {
    /// Pixels compared.
    pub pixels: u64,
    /// Pixels that are bit-identical.
    pub identical: u64,
    /// Largest absolute difference of one channel over all pixels (0..=255).
    pub max_channel_diff: u8,
}

impl ImageDiff {
    /// Share of identical pixels (1 for empty images).
    pub fn identical_share(&self) -> f64 {
        if self.pixels == 0 {
            1.0
        } else {
            self.identical as f64 / self.pixels as f64
        }
    }

    /// Whether the share reaches [`TARGET_IDENTICAL`].
    pub fn meets_target(&self) -> bool {
        self.identical_share() >= TARGET_IDENTICAL
    }
}

/// The largest absolute difference of one 8-bit channel of two packed RGBA8 pixels.
pub fn channel_diff(a: u32, b: u32) -> u8 {
    let (a, b) = (a.to_le_bytes(), b.to_le_bytes());
    let mut m = 0;
    for i in 0..4 {
        m = m.max(a[i].abs_diff(b[i]));
    }
    m
}

impl Image {
    /// Compares two images pixel by pixel; `None` when their sizes differ.
    pub fn diff(&self, other: &Image) -> Option<ImageDiff> {
        if self.width != other.width || self.height != other.height || self.pixels.len() != other.pixels.len() {
            return None;
        }
        let mut d = ImageDiff { pixels: self.pixels.len() as u64, identical: 0, max_channel_diff: 0 };
        for (&p, &q) in self.pixels.iter().zip(&other.pixels) {
            if p == q {
                d.identical += 1;
            } else {
                d.max_channel_diff = d.max_channel_diff.max(channel_diff(p, q));
            }
        }
        Some(d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use alloc::vec;

    fn img(w: u32, h: u32, v: u32) -> Image {
        Image { width: w, height: h, pixels: vec![v; (w * h) as usize] }
    }

    #[test]
    fn diff_counts_and_max() {
        let a = img(4, 2, 0xff10_2030);
        let mut b = a.clone();
        b.pixels[3] = 0xff10_2035;
        b.pixels[5] = 0xff00_2030;
        let d = a.diff(&b).unwrap();
        assert_eq!(d, ImageDiff { pixels: 8, identical: 6, max_channel_diff: 16 });
        assert_eq!(d.identical_share(), 0.75);
        assert!(!d.meets_target());
        assert!(a.diff(&img(2, 4, 0)).is_none());
        assert!(a.diff(&a).unwrap().meets_target());
    }
}
