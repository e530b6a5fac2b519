//! Sort-last compositing of the ranks' segments: direct-send by bands of image rows, the merge
//! by depth, the fuse down to the client's K, and the frame rank 0 encodes.
//!
//! **The rule.** Per pixel, the segments of every part are merged by depth (a k-way merge of
//! the parts' front-to-back lists; equal depths keep the parts' order; lists that lie apart in
//! depth, as disjoint parts' do, are concatenated, which is the same), which is their
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

/// The first row of each of `n` bands of rows and the end of the last (`n + 1` values), cut so
/// the bands carry about equal work: `load[y]` is row `y`'s work (its segments over every part
/// plus a share per pixel), the same on every rank (all-reduced), so every rank cuts alike.
/// Contiguous, in order, covering every row once; a band may be empty. The band owners then
/// finish their merges together, so none waits long for another in the gather.
pub fn balanced_bands(load: &[u64], n: usize) -> Vec<u32> {
    let total: u128 = load.iter().map(|&l| u128::from(l)).sum();
    let mut out = Vec::with_capacity(n + 1);
    out.push(0u32);
    let (mut y, mut acc) = (0usize, 0u128);
    for b in 1..n {
        // The first row at which the bands before it reach b/n of the work.
        let want = total * b as u128 / n as u128;
        while y < load.len() && acc + u128::from(load[y]) <= want {
            acc += u128::from(load[y]);
            y += 1;
        }
        out.push(y as u32);
    }
    out.push(load.len() as u32);
    out
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
    segs.truncate(kept(segs, ert));
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

/// How many of `segs` (front to back) early termination at `ert` keeps: those before the
/// accumulated opacity (`A += (1 − A)·α` from an empty pixel) reaches `ert`.
#[inline]
fn kept(segs: &[Seg], ert: f32) -> usize {
    let mut a = 0.0f32;
    for (i, s) in segs.iter().enumerate() {
        if a >= ert {
            return i;
        }
        a += (1.0 - a) * s.c[3];
    }
    segs.len()
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
///
/// Parts are disjoint convex boxes, so a pixel's non-empty lists occupy disjoint depth ranges:
/// ordered by their first depth, each sorted and each ending strictly before the next begins,
/// their depth merge is their concatenation in that order (no depth ties across lists, and a
/// stable merge keeps each list's own order). That is checked per pixel (a compare per
/// segment); lists that overlap or are out of order (bytes from a failed rank) take the k-way
/// merge, so the result is [`merge_reference`]'s either way.
pub fn merge(lists: &[&[Seg]], k: usize, ert: f32, out: &mut Vec<Seg>) {
    out.clear();
    // The non-empty lists, in order of their first depth (insertion sort: a pixel has few).
    let mut ne: [&[Seg]; 8] = [&[]; 8];
    let mut n = 0;
    for l in lists.iter().filter(|l| !l.is_empty()) {
        if n == ne.len() {
            // More parts over one pixel than the fast path holds: the k-way merge.
            merge_lists(lists, out);
            reduce(out, k, ert);
            return;
        }
        let mut j = n;
        while j > 0 && ne[j - 1][0].t > l[0].t {
            ne[j] = ne[j - 1];
            j -= 1;
        }
        ne[j] = l;
        n += 1;
    }
    match n {
        0 => {}
        // One part saw the pixel: its list as it is (most pixels).
        1 => out.extend_from_slice(ne[0]),
        _ => {
            let sorted = |l: &[Seg]| l.windows(2).all(|w| w[0].t <= w[1].t);
            let apart = ne[..n].windows(2).all(|w| w[0][w[0].len() - 1].t < w[1][0].t);
            if apart && ne[..n].iter().all(|l| sorted(l)) {
                for l in &ne[..n] {
                    out.extend_from_slice(l);
                }
            } else {
                merge_lists(lists, out);
            }
        }
    }
    reduce(out, k, ert);
}

/// The bytes the count bytes of a band of `pixels` pixels take between ranks: padded to a
/// multiple of 4, so the segments after them lie 4-byte aligned in an aligned buffer and are
/// read in place.
pub fn counts_len(pixels: usize) -> usize {
    pixels.next_multiple_of(4)
}

/// The bytes [`encode_band_into`] writes for pixels `rows` of `pf`.
pub fn band_len(pf: &PartFrame, rows: std::ops::Range<u32>) -> usize {
    let w = pf.width as usize;
    let (p0, p1) = (rows.start as usize * w, rows.end as usize * w);
    counts_len(p1 - p0) + SEG_BYTES * pf.count[p0..p1].iter().map(|&c| c as usize).sum::<usize>()
}

/// Writes a band of a [`PartFrame`] into `out` (of [`band_len`] bytes) as a rank sends it to its
/// band's owner: a segment count per pixel (zeros up to [`counts_len`]), then the segments (`t`
/// and RGBA as `f32` in memory order, [`SEG_BYTES`] each).
pub fn encode_band_into(pf: &PartFrame, rows: std::ops::Range<u32>, out: &mut [u8]) {
    use rayon::prelude::*;
    let w = pf.width as usize;
    let (p0, p1) = (rows.start as usize * w, rows.end as usize * w);
    let cl = counts_len(p1 - p0);
    let (counts, mut body) = out.split_at_mut(cl);
    counts[..p1 - p0].copy_from_slice(&pf.count[p0..p1]);
    counts[p1 - p0..].fill(0);
    // In parallel over blocks of pixels, each block's bytes where its segments start.
    const BLOCK: usize = 16384;
    let mut blocks = Vec::with_capacity((p1 - p0).div_ceil(BLOCK));
    for b0 in (p0..p1).step_by(BLOCK) {
        let b1 = (b0 + BLOCK).min(p1);
        let n: usize = pf.count[b0..b1].iter().map(|&c| c as usize).sum();
        let (c, r) = body.split_at_mut(n * SEG_BYTES);
        blocks.push((b0..b1, c));
        body = r;
    }
    blocks.into_par_iter().for_each(|(px, out)| {
        let mut at = 0;
        for i in px {
            let b: &[u8] = bytemuck::cast_slice(pf.pixel(i));
            out[at..at + b.len()].copy_from_slice(b);
            at += b.len();
        }
    });
}

/// A band of per-pixel segment lists, borrowed: as received from another rank (the lists one
/// after another) or as this rank marched it (pixel `i`'s list at slot `i·k` of a
/// [`PartFrame`]).
#[derive(Clone, Copy, Debug)]
pub struct BandView<'a> {
    /// Segments per pixel.
    pub count: &'a [u8],
    /// The segments.
    pub segs: &'a [Seg],
    /// Slots per pixel where the lists are at fixed strides (a [`PartFrame`]), else `None`.
    pub stride: Option<usize>,
}

impl<'a> BandView<'a> {
    /// The band of pixels `rows` of a rank's own [`PartFrame`], in place.
    pub fn of_part(pf: &'a PartFrame, rows: std::ops::Range<u32>) -> BandView<'a> {
        let w = pf.width as usize;
        let (p0, p1) = (rows.start as usize * w, rows.end as usize * w);
        BandView { count: &pf.count[p0..p1], segs: &pf.segs[p0 * pf.k..p1 * pf.k], stride: Some(pf.k) }
    }

    /// A band of [`Band`]'s lists.
    pub fn of_band(b: &'a Band) -> BandView<'a> {
        BandView { count: &b.count, segs: &b.segs, stride: None }
    }

    /// The band [`encode_band_into`] wrote, read in place: an error for bytes that are not one
    /// (a count above `k`, a length that does not match the counts, nonzero padding, a
    /// segment with a non-finite value: bytes from a failed rank) or that are not 4-byte
    /// aligned.
    pub fn parse(bytes: &'a [u8], pixels: usize, k: usize) -> Result<BandView<'a>, String> {
        let cl = counts_len(pixels);
        let (count, pad) = match (bytes.get(..pixels), bytes.get(pixels..cl)) {
            (Some(c), Some(p)) => (c, p),
            _ => return Err(format!("a band of {pixels} pixels needs {cl} count bytes")),
        };
        if pad.iter().any(|&b| b != 0) {
            return Err("a band with nonzero padding after its counts".into());
        }
        if let Some(c) = count.iter().find(|&&c| c as usize > k) {
            return Err(format!("a pixel with {c} segments (at most {k})"));
        }
        let n: usize = count.iter().map(|&c| c as usize).sum();
        let body = &bytes[cl..];
        if body.len() != n * SEG_BYTES {
            return Err(format!("a band of {n} segments holds {} bytes, not {}", body.len(), n * SEG_BYTES));
        }
        let segs: &[Seg] =
            bytemuck::try_cast_slice(body).map_err(|e| format!("a band's segments cannot be read in place: {e}"))?;
        if !all_finite(segs) {
            return Err("a segment with a non-finite value".into());
        }
        Ok(BandView { count, segs, stride: None })
    }

    /// Where the list of pixel `i` starts in `segs` for each `i = r·run` (one per run of `run`
    /// pixels), and the end of the last.
    fn run_starts(&self, run: usize) -> Vec<usize> {
        use rayon::prelude::*;
        let runs = self.count.len().div_ceil(run);
        match self.stride {
            Some(k) => (0..=runs).map(|r| (r * run).min(self.count.len()) * k).collect(),
            None => {
                let sums: Vec<usize> =
                    self.count.par_chunks(run.max(1)).map(|c| c.iter().map(|&c| c as usize).sum()).collect();
                std::iter::once(0)
                    .chain(sums.iter().scan(0usize, |at, &s| {
                        *at += s;
                        Some(*at)
                    }))
                    .collect()
            }
        }
    }
}

/// A band of a [`PartFrame`] as the bytes a rank sends its band's owner
/// ([`encode_band_into`]).
pub fn encode_band(pf: &PartFrame, rows: std::ops::Range<u32>) -> Vec<u8> {
    let mut out = vec![0u8; band_len(pf, rows.clone())];
    encode_band_into(pf, rows, &mut out);
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

/// Whether every value of `segs` is finite: one pass over their bits in parallel blocks, with
/// no early exit (the compiler vectorizes it).
fn all_finite(segs: &[Seg]) -> bool {
    use rayon::prelude::*;
    let bits: &[u32] = bytemuck::cast_slice(segs);
    let exp = 0x7F80_0000;
    bits.par_chunks(1 << 16).all(|c| c.iter().fold(true, |ok, &b| ok & (b & exp != exp)))
}

/// Decodes a band of `pixels` pixels with at most `k` segments each (bytes at any alignment,
/// copied); an error for bytes that are not one.
pub fn decode_band(bytes: &[u8], pixels: usize, k: usize) -> Result<Band, String> {
    let cl = counts_len(pixels);
    let Some(count) = bytes.get(..pixels) else {
        return Err(format!("a band of {pixels} pixels needs {cl} count bytes"));
    };
    // The checks of `BandView::parse` on an aligned copy.
    let mut aligned = vec![0u32; bytes.len().div_ceil(4)];
    bytemuck::cast_slice_mut::<u32, u8>(&mut aligned)[..bytes.len()].copy_from_slice(bytes);
    let view = BandView::parse(&bytemuck::cast_slice::<u32, u8>(&aligned)[..bytes.len()], pixels, k)?;
    let segs = view.segs.to_vec();
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
    let views: Vec<BandView> = bands.iter().map(BandView::of_band).collect();
    let runs: Vec<(Vec<u8>, Vec<Seg>)> =
        merge_views_with(&views, pixels, k, ert, |_, merged, (count, segs): &mut (Vec<u8>, Vec<Seg>)| {
            count.push(merged.len() as u8);
            segs.extend_from_slice(merged);
        })
        .expect("decoded bands hold the segments their counts need");
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
    let views: Vec<BandView> = bands.iter().map(BandView::of_band).collect();
    merge_views_with(&views, pixels, k, ert, f).expect("decoded bands hold the segments their counts need")
}

/// [`merge_bands_with`] of bands read in place ([`BandView`]), each of `pixels` pixels (whose
/// values [`BandView::parse`] checked where they came from another rank).
pub fn merge_views_with<A: Default + Send>(
    bands: &[BandView],
    pixels: usize,
    k: usize,
    ert: f32,
    f: impl Fn(usize, &[Seg], &mut A) + Sync,
) -> Result<Vec<A>, String> {
    use rayon::prelude::*;
    const RUN: usize = 4096;
    if let Some(b) = bands.iter().find(|b| b.count.len() != pixels) {
        return Err(format!("a band of {} pixels, not {pixels}", b.count.len()));
    }
    let starts: Vec<Vec<usize>> = bands.iter().map(|b| b.run_starts(RUN)).collect();
    if let Some(b) = bands.iter().zip(&starts).find(|(b, s)| s.last().is_some_and(|&e| e > b.segs.len())) {
        return Err(format!("a band of {} segments whose counts need more", b.0.segs.len()));
    }
    Ok((0..pixels.div_ceil(RUN))
        .into_par_iter()
        .map(|r| {
            let mut acc = A::default();
            let mut buf = Vec::with_capacity(k.max(1) * bands.len());
            let mut lists: Vec<&[Seg]> = vec![&[]; bands.len()];
            let mut at: Vec<usize> = starts.iter().map(|s| s[r]).collect();
            for i in r * RUN..((r + 1) * RUN).min(pixels) {
                let (mut seen, mut only): (usize, &[Seg]) = (0, &[]);
                for ((l, b), at) in lists.iter_mut().zip(bands).zip(at.iter_mut()) {
                    let c = b.count[i] as usize;
                    *l = &b.segs[*at..*at + c];
                    *at += b.stride.unwrap_or(c);
                    if c > 0 {
                        seen += 1;
                        only = l;
                    }
                }
                match seen {
                    // What `merge` gives a pixel no part saw, and a pixel one part alone saw with
                    // at most K segments (its list up to early termination), without its copy.
                    0 => f(i, &[], &mut acc),
                    1 if only.len() <= k => f(i, &only[..kept(only, ert)], &mut acc),
                    _ => {
                        merge(&lists, k, ert, &mut buf);
                        f(i, &buf, &mut acc);
                    }
                }
            }
            acc
        })
        .collect())
}

/// The bytes of a merged band (the same coding as [`encode_band`]).
pub fn encode_merged(b: &Band) -> Vec<u8> {
    let cl = counts_len(b.count.len());
    let mut out = Vec::with_capacity(cl + b.segs.len() * SEG_BYTES);
    out.extend_from_slice(&b.count);
    out.resize(cl, 0);
    out.extend_from_slice(bytemuck::cast_slice(&b.segs));
    out
}
