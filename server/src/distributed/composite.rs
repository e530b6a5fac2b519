//! Sort-last compositing of the ranks' segments: direct-send by bands of image rows, the merge
//! by depth, the fuse down to the client's K, and the frame rank 0 encodes.
//!
//! **The rule.** Per pixel, the segments of every part are merged by depth (a k-way merge of
//! the parts' front-to-back lists; equal depths keep the parts' order), which is their
//! visibility order: parts are disjoint convex boxes, so along a ray their samples, and the
//! segments over them, do not interleave. Front to back, once the accumulated opacity
//! (`A += (1 − A)·α`) reaches the early-termination threshold the segments behind are dropped
//! (what the one-process marcher's early termination drops). While more than K remain, the
//! adjacent pair with the smallest depth gap (the first of equal gaps) is fused: premultiplied
//! `c = c₁ + (1 − α₁)·c₂`, `α = α₁ + (1 − α₁)·α₂`, and the depth their opacity-weighted mean
//! `(α₁·t₁ + (1 − α₁)·α₂·t₂) / α` (the segmenter's rule for one segment, in real arithmetic).
//! For K = 1 frames (one sample per pixel at a heuristic's depth) the parts' segments are
//! composited into one whose depth is the **nearest** part's pick: the one-process depth bit
//! for bit for Entrance, and for Threshold where the nearest visible part crosses on its own
//! (the heuristics served across ranks: [`super::one_sample_heuristic`]).
//!
//! With one part the merged frame is the one-process frame bit for bit. With several, a
//! part's segmenter sees only its own accumulated opacity, so cuts, colors (float order) and
//! the tail after early termination differ from the one-process frame by rounding and by the
//! cuts at part faces: the composited image stays within a few 8-bit levels of it (tested).

use super::partial::{PartFrame, Seg, SEG_BYTES};

/// The rows of band `b` of `n` bands of an image `height` rows high (contiguous, the first
/// bands one row longer where `height` is not a multiple).
pub fn band_rows(height: u32, n: usize, b: usize) -> std::ops::Range<u32> {
    let (n, b, h) = (n as u64, b as u64, u64::from(height));
    let start = h * b / n;
    let end = h * (b + 1) / n;
    start as u32..end as u32
}

/// Fuses two adjacent segments, front one first (see the module docs).
#[inline]
pub fn fuse(a: Seg, b: Seg) -> Seg {
    let keep = 1.0 - a.c[3];
    let c = [0, 1, 2, 3].map(|i| a.c[i] + keep * b.c[i]);
    let (wa, wb) = (a.c[3], keep * b.c[3]);
    let w = wa + wb;
    let t = if w > 0.0 { ((wa * a.t + wb * b.t) / w).clamp(a.t.min(b.t), a.t.max(b.t)) } else { a.t };
    Seg { t, c }
}

/// Applies early termination at `ert` and fuses `segs` (front to back) down to `k` segments.
/// `k` = 1 composites them all at the nearest segment's depth (the heuristic rule).
pub fn reduce(segs: &mut Vec<Seg>, k: usize, ert: f32) {
    let mut a = 0.0f32;
    for (i, s) in segs.iter().enumerate() {
        if a >= ert {
            segs.truncate(i);
            break;
        }
        a += (1.0 - a) * s.c[3];
    }
    if k <= 1 {
        if let Some(&first) = segs.first() {
            let mut all = segs.iter().skip(1).fold(first, |acc, &s| fuse(acc, s));
            all.t = first.t;
            segs.clear();
            segs.push(all);
        }
        return;
    }
    while segs.len() > k {
        let mut best = 0;
        for i in 1..segs.len() - 1 {
            if segs[i + 1].t - segs[i].t < segs[best + 1].t - segs[best].t {
                best = i;
            }
        }
        segs[best] = fuse(segs[best], segs[best + 1]);
        segs.remove(best + 1);
    }
}

/// Merges front-to-back lists by depth (k-way; equal depths keep the lists' order) into `out`.
pub fn merge_lists(lists: &[&[Seg]], out: &mut Vec<Seg>) {
    out.clear();
    let mut heads = vec![0usize; lists.len()];
    loop {
        let mut pick: Option<usize> = None;
        for (l, list) in lists.iter().enumerate() {
            if let Some(s) = list.get(heads[l]) {
                if pick.is_none_or(|p| s.t < lists[p][heads[p]].t) {
                    pick = Some(l);
                }
            }
        }
        let Some(l) = pick else { break };
        out.push(lists[l][heads[l]]);
        heads[l] += 1;
    }
}

/// The reference merge: the lists concatenated and stably sorted by depth, then reduced.
pub fn merge_reference(lists: &[&[Seg]], k: usize, ert: f32) -> Vec<Seg> {
    let mut all: Vec<Seg> = lists.iter().flat_map(|l| l.iter().copied()).collect();
    all.sort_by(|a, b| a.t.total_cmp(&b.t));
    reduce(&mut all, k, ert);
    all
}

/// Merges pixel lists and reduces them to `k` (the fast path of [`merge_reference`]).
pub fn merge(lists: &[&[Seg]], k: usize, ert: f32, out: &mut Vec<Seg>) {
    let mut nonempty = lists.iter().filter(|l| !l.is_empty());
    match (nonempty.next(), nonempty.next()) {
        (None, _) => out.clear(),
        // One part saw the pixel: its list as it is (most pixels).
        (Some(l), None) => {
            out.clear();
            out.extend_from_slice(l);
        }
        _ => merge_lists(lists, out),
    }
    reduce(out, k, ert);
}

/// A band of a [`PartFrame`] as the bytes a rank sends its band's owner: a segment count per
/// pixel, then the segments (`t` and RGBA as `f32` in memory order, [`SEG_BYTES`] each).
pub fn encode_band(pf: &PartFrame, rows: std::ops::Range<u32>) -> Vec<u8> {
    let w = pf.width as usize;
    let (p0, p1) = (rows.start as usize * w, rows.end as usize * w);
    let n: usize = pf.count[p0..p1].iter().map(|&c| c as usize).sum();
    let mut out = Vec::with_capacity(p1 - p0 + n * SEG_BYTES);
    out.extend_from_slice(&pf.count[p0..p1]);
    for i in p0..p1 {
        out.extend_from_slice(bytemuck::cast_slice(pf.pixel(i)));
    }
    out
}

/// Per-pixel segment lists of a band (what [`encode_band`] wrote).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Band {
    /// Segments per pixel.
    pub count: Vec<u8>,
    /// Where each pixel's segments start in `segs`.
    pub start: Vec<u32>,
    /// The segments, pixel after pixel.
    pub segs: Vec<Seg>,
}

impl Band {
    /// Pixel `i`'s segments.
    pub fn pixel(&self, i: usize) -> &[Seg] {
        let s = self.start[i] as usize;
        &self.segs[s..s + self.count[i] as usize]
    }
}

/// Decodes a band of `pixels` pixels with at most `k` segments each; an error for bytes that
/// are not one.
pub fn decode_band(bytes: &[u8], pixels: usize, k: usize) -> Result<Band, String> {
    let count = bytes.get(..pixels).ok_or_else(|| format!("a band of {pixels} pixels needs {pixels} count bytes"))?;
    if let Some(c) = count.iter().find(|&&c| c as usize > k) {
        return Err(format!("a pixel with {c} segments (at most {k})"));
    }
    let n: usize = count.iter().map(|&c| c as usize).sum();
    let body = &bytes[pixels..];
    if body.len() != n * SEG_BYTES {
        return Err(format!("a band of {n} segments holds {} bytes, not {}", body.len(), n * SEG_BYTES));
    }
    let segs: Vec<Seg> = bytemuck::pod_collect_to_vec(body);
    if segs.iter().any(|s| !s.t.is_finite() || s.c.iter().any(|v| !v.is_finite())) {
        return Err("a segment with a non-finite value".into());
    }
    let mut start = Vec::with_capacity(pixels);
    let mut at = 0u32;
    for &c in count {
        start.push(at);
        at += u32::from(c);
    }
    Ok(Band { count: count.to_vec(), start, segs })
}

/// Merges the bands every part sent for one band of the image into `k` segments per pixel
/// (the band's owner's work, in parallel over runs of pixels), as a [`Band`].
pub fn merge_bands(bands: &[Band], pixels: usize, k: usize, ert: f32) -> Band {
    let runs: Vec<(Vec<u8>, Vec<Seg>)> =
        merge_bands_with(bands, pixels, k, ert, |_, merged, (count, segs): &mut (Vec<u8>, Vec<Seg>)| {
            count.push(merged.len() as u8);
            segs.extend_from_slice(merged);
        });
    let mut out = Band { count: Vec::with_capacity(pixels), start: Vec::with_capacity(pixels), segs: Vec::new() };
    let mut at = 0u32;
    for (count, segs) in runs {
        for &c in &count {
            out.start.push(at);
            at += u32::from(c);
        }
        out.count.extend_from_slice(&count);
        out.segs.extend_from_slice(&segs);
    }
    out
}

/// [`merge_bands`] handing each pixel's merged segments to `f(pixel, segments, acc)` in runs of
/// pixels in parallel, instead of collecting them (a band owner assembles its frame samples
/// this way, without a merged band in between): the runs' accumulators, in pixel order.
pub fn merge_bands_with<A: Default + Send>(
    bands: &[Band],
    pixels: usize,
    k: usize,
    ert: f32,
    f: impl Fn(usize, &[Seg], &mut A) + Sync,
) -> Vec<A> {
    use rayon::prelude::*;
    const RUN: usize = 4096;
    (0..pixels.div_ceil(RUN))
        .into_par_iter()
        .map(|r| {
            let mut acc = A::default();
            let mut buf = Vec::new();
            let mut lists: Vec<&[Seg]> = Vec::with_capacity(bands.len());
            for i in r * RUN..((r + 1) * RUN).min(pixels) {
                lists.clear();
                lists.extend(bands.iter().map(|b| b.pixel(i)));
                merge(&lists, k, ert, &mut buf);
                f(i, &buf, &mut acc);
            }
            acc
        })
        .collect()
}

/// The bytes of a merged band (the same coding as [`encode_band`]).
pub fn encode_merged(b: &Band) -> Vec<u8> {
    let mut out = Vec::with_capacity(b.count.len() + b.segs.len() * SEG_BYTES);
    out.extend_from_slice(&b.count);
    out.extend_from_slice(bytemuck::cast_slice(&b.segs));
    out
}
