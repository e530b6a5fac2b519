//! Closing the cracks a warp opens between footprints, on the drawn image.
//!
//! Where the frame saw a surface nearly edge-on and the new camera sees it broadside (the side
//! of a head an orbit turns into view), each of the frame's rays stands for a long stretch of
//! the surface but its segments' footprints are one source pixel wide: they part, and the
//! background shows through in streaks one or two pixels wide, either uncovered (the fill's
//! lookup finds background there too) or under a thin, semi-transparent footprint of a deeper
//! slab; and where one semi-transparent slab's footprints part over deeper ones, the pixels
//! between show those alone, a thin dark speck. On the image (RGBA8, composited over the
//! background) a crack is a run of at most [`CRACK_RUN`] pixels along a row or a column whose
//! two bounding pixels are solid (at least [`CRACK_SOLID`] from the background) and alike
//! (their difference at most half their mean's distance from the background), every pixel of
//! the run nearer the background than [`CRACK_ALPHA`] of that mean's distance, or than
//! [`SPECK_ALPHA`] of it where the pixel is the mean's own color dimmed (within
//! [`SPECK_HUE`]). Each pixel of the run, read as the background plus a share α of the mean
//! (its projection on it), takes the missing `1 − α` of the mean over what it has: the
//! footprints parted there, so what covers the pixels either side covers it.
//!
//! Only the image is read, so the CPU and the GPU splatters run the same pass on what they
//! drew (the GPU one on the image it reads back). It never runs at the frame's own camera,
//! which is the server's image exactly. Work: one pass for each pixel's squared distance from
//! the background, then a pixel is looked at only where it is under three quarters of the
//! largest such distance within [`CRACK_RUN`] pixels along its row and column (which every
//! crack pixel is); 4 bytes per pixel, and 8 per pixel closed. Measured (`docs/results.md`,
//! "Closing cracks"; `docs/perf.md` for its time).

use super::options::LayerOptions;
use crate::threads::Threads;
use volwarp_core::{Camera, Image, BACKGROUND};

/// The longest run of pixels along a row or column closed as a crack.
pub const CRACK_RUN: usize = 2;

/// A crack's pixels lie nearer the background than this share of their bounding pixels'
/// mean's distance from it, whatever their color. Measured (single warps, five datasets, 512²;
/// `docs/results.md`).
pub const CRACK_ALPHA: f32 = 0.7;

/// Up to this share a crack's pixels may also lie where they are the mean's own color, only
/// dimmer ([`SPECK_HUE`]): one semi-transparent slab's footprints parted over deeper ones, so
/// the pixels between show those alone, a thin dark speck at a share of 0.78–0.85 of their
/// neighbours (hundreds of them at depth edges in the demo strip's frames). Measured
/// (`docs/results.md`, "Closing cracks").
pub const SPECK_ALPHA: f32 = 0.85;

/// A speck's color lies within this share of its distance from the background off the line
/// from the background to its bounding pixels' mean (the specks measured lie within 0.05; a
/// darker detail of another hue, a vessel drawn red on bone, stays).
pub const SPECK_HUE: f32 = 0.1;

/// How far (Euclidean, 8-bit RGB) from the background a pixel bounding a crack must be.
pub const CRACK_SOLID: i32 = 60;

/// Rows per task of the passes.
const CRACK_ROWS: usize = 32;

/// [`CRACK_ALPHA`]² and [`SPECK_ALPHA`]² in hundredths, and 1 − [`SPECK_HUE`]² in
/// ten-thousandths (the run test compares integers).
const ALPHA2_PERCENT: i64 = (CRACK_ALPHA * CRACK_ALPHA * 100.0 + 0.5) as i64;
const SPECK2_PERCENT: i64 = (SPECK_ALPHA * SPECK_ALPHA * 100.0 + 0.5) as i64;
const HUE_KEEP: i64 = ((1.0 - SPECK_HUE * SPECK_HUE) * 10_000.0 + 0.5) as i64;

/// A pixel's RGB less the background's.
#[inline]
fn rel(c: u32) -> [i32; 3] {
    let [r, g, b, _] = c.to_le_bytes();
    let [br, bg, bb, _] = BACKGROUND.to_le_bytes();
    [r as i32 - br as i32, g as i32 - bg as i32, b as i32 - bb as i32]
}

#[inline]
fn dot(a: [i32; 3], b: [i32; 3]) -> i32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// A pixel's squared distance from the background (an integer, exact in `f32`: at most 3·255²).
#[inline]
fn distance2(c: u32) -> f32 {
    let r = rel(c);
    dot(r, r) as f32
}

/// The sum of the two pixels bounding a crack at `a` and `b` (twice their mean), if they are
/// solid and alike.
#[inline]
fn bounds(a: u32, b: u32) -> Option<[i32; 3]> {
    let (a, b) = (rel(a), rel(b));
    let solid = CRACK_SOLID * CRACK_SOLID;
    if dot(a, a) < solid || dot(b, b) < solid {
        return None;
    }
    let s = [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    // |a − b| ≤ ½ |(a + b) / 2|.
    (16 * dot(d, d) <= dot(s, s)).then_some(s)
}

/// Whether pixel `c`, at squared distance `e` from the background, lies in a crack bounded by
/// pixels summing to `s`: nearer the background than [`CRACK_ALPHA`] of the mean `s / 2`'s
/// distance, or than [`SPECK_ALPHA`] of it and within [`SPECK_HUE`] of the line through the
/// mean.
#[inline]
fn low(c: u32, e: f32, s: [i32; 3]) -> bool {
    // e < α²·|s/2|²  ⇔  400·e < 100·α²·|s|² (integers).
    let (e, ss) = (e as i64, dot(s, s) as i64);
    if 400 * e < ALPHA2_PERCENT * ss {
        return true;
    }
    if 400 * e >= SPECK2_PERCENT * ss {
        return false;
    }
    // Off the line by at most h of its distance: |p|² − (p·s)²/|s|² ≤ h²·|p|²
    // ⇔ (1 − h²)·|p|²·|s|² ≤ (p·s)² (at most 2·10¹¹·10⁴: exact in i64), on the mean's side.
    let d = dot(rel(c), s) as i64;
    d > 0 && HUE_KEEP * e * ss <= 10_000 * d * d
}

/// The sum of the pixels bounding the crack pixel `(x, y)` of `px` (`w × h`, squared
/// distances from the background in `dist`) lies in, if it lies in one: rows first, then
/// columns, the shortest run first.
fn crack_at(px: &[u32], dist: &[f32], w: usize, h: usize, x: usize, y: usize) -> Option<[i32; 3]> {
    for along_row in [true, false] {
        let (pos, len) = if along_row { (x, w) } else { (y, h) };
        let index = |i: usize| if along_row { y * w + i } else { i * w + x };
        for run in 1..=CRACK_RUN {
            // The run starts `start` pixels before this one.
            for start in 0..run {
                if pos < start + 1 || pos + run - start >= len {
                    continue;
                }
                let (a, b) = (pos - start - 1, pos + run - start);
                let Some(s) = bounds(px[index(a)], px[index(b)]) else { continue };
                if (a + 1..b).all(|i| low(px[index(i)], dist[index(i)], s)) {
                    return Some(s);
                }
            }
        }
    }
    None
}

/// Pixel `c` with the share of the mean `s / 2` it lacks added over it.
fn closed(c: u32, s: [i32; 3]) -> u32 {
    let p = rel(c);
    let ss = dot(s, s) as f32;
    let alpha = (2.0 * dot(p, s) as f32 / ss).clamp(0.0, 1.0);
    let [br, bg, bb, _] = BACKGROUND.to_le_bytes();
    let ch = |i: usize, base: u8| {
        let v = base as f32 + p[i] as f32 + (1.0 - alpha) * 0.5 * s[i] as f32;
        v.round().clamp(0.0, 255.0) as u32
    };
    ch(0, br) | ch(1, bg) << 8 | ch(2, bb) << 16 | (c & 0xff00_0000)
}

/// What [`close_cracks`] keeps between calls: per pixel its squared distance from the
/// background, per band of rows the pixels it closes.
#[derive(Debug, Default)]
pub struct CrackScratch {
    dist: Vec<f32>,
    changes: Vec<Vec<(u32, u32)>>,
}

/// Closes the cracks of `image`, drawn for `camera` from a frame rendered for `frame`, where
/// `opts` closes them ([`LayerOptions::close_cracks`]) and the camera is not the frame's own
/// (whose image is the server's exactly): the step both layered splatters end with.
pub fn close_cracks_of(
    opts: &LayerOptions,
    frame: &Camera,
    camera: &Camera,
    image: &mut Image,
    scratch: &mut CrackScratch,
    threads: &Threads,
) {
    if opts.close_cracks && camera != frame {
        let (w, h) = (image.width as usize, image.height as usize);
        close_cracks(&mut image.pixels, w, h, scratch, threads);
    }
}

/// Closes the cracks of the `w × h` image `pixels` (see the module docs). Every band of rows
/// finds its cracks in the image as drawn and the closed pixels are written afterwards, so the
/// result does not depend on the order of the pixels. In parallel over bands of rows.
pub fn close_cracks(pixels: &mut [u32], w: usize, h: usize, scratch: &mut CrackScratch, threads: &Threads) {
    let n = w * h;
    if n == 0 || pixels.len() < n {
        return;
    }
    let CrackScratch { dist, changes } = scratch;
    dist.resize(n, 0.0);
    threads.for_each_chunk(&mut dist[..n], CRACK_ROWS * w, |band, dist| {
        let first = band * CRACK_ROWS * w;
        for (d, &p) in dist.iter_mut().zip(&pixels[first..]) {
            *d = distance2(p);
        }
    });
    let (px, dist) = (&pixels[..n], &dist[..n]);
    changes.resize_with(h.div_ceil(CRACK_ROWS), Vec::new);
    threads.for_each_chunk(changes, 1, |band, found| {
        let found = &mut found[0];
        found.clear();
        let mut look = Vec::new();
        for y in band * CRACK_ROWS..((band + 1) * CRACK_ROWS).min(h) {
            look_at(dist, w, h, y, &mut look);
            for x in (0..w).filter(|&x| look[x]) {
                if let Some(s) = crack_at(px, dist, w, h, x, y) {
                    let j = y * w + x;
                    found.push((j as u32, closed(px[j], s)));
                }
            }
        }
    });
    for &(j, c) in changes.iter().flatten() {
        pixels[j as usize] = c;
    }
}

/// Whether a pixel at squared distance `d` from the background can lie in a crack whose
/// bounding pixels are at most `far` from it (the farthest within [`CRACK_RUN`] along its row
/// and column): the mean of two bounding pixels is no farther from the background than the
/// farther of them, and a crack's pixels lie under [`SPECK_ALPHA`]² (0.7225) of it, so under
/// three quarters of `far` (`f32` products exact: `d`, `far` are integers under 2¹⁸, and
/// three quarters of one needs two more bits). The pixel's own distance in `far` fails the
/// second test alone, as it should.
#[inline]
fn may_crack(d: f32, far: f32) -> bool {
    far >= (CRACK_SOLID * CRACK_SOLID) as f32 && d < LOOK_SHARE * far
}

/// The share of the farthest neighbour's squared distance under which [`may_crack`] looks.
const LOOK_SHARE: f32 = 0.75;
const _: () = assert!(CRACK_ALPHA <= SPECK_ALPHA && SPECK_ALPHA * SPECK_ALPHA <= LOOK_SHARE);

/// Per pixel of row `y` whether it [`may_crack`] (into `look`): away from the image's edges
/// with `f32` maxima, which the compiler vectorizes on every x86-64 (`maxps`).
fn look_at(dist: &[f32], w: usize, h: usize, y: usize, look: &mut Vec<bool>) {
    const R: usize = CRACK_RUN;
    // The rows' and columns' neighbours below are written out for runs of two.
    const _: () = assert!(R == 2);
    look.clear();
    look.resize(w, false);
    let row = |yy: usize| &dist[yy * w..(yy + 1) * w];
    let edge = |x: usize| {
        let j = y * w + x;
        let mut far = 0.0f32;
        for k in 1..=R {
            if x >= k {
                far = far.max(dist[j - k]);
            }
            if x + k < w {
                far = far.max(dist[j + k]);
            }
            if y >= k {
                far = far.max(dist[j - k * w]);
            }
            if y + k < h {
                far = far.max(dist[j + k * w]);
            }
        }
        may_crack(dist[j], far)
    };
    if y < R || y + R >= h || w < 2 * R + 1 {
        for (x, l) in look.iter_mut().enumerate() {
            *l = edge(x);
        }
        return;
    }
    let m = w - 2 * R;
    let r = row(y);
    let (l2, l1, c, r1, r2) = (&r[0..m], &r[1..m + 1], &r[2..m + 2], &r[3..m + 3], &r[4..m + 4]);
    let (u2, u1, d1, d2) = (&row(y - 2)[R..m + R], &row(y - 1)[R..m + R], &row(y + 1)[R..m + R], &row(y + 2)[R..m + R]);
    // `maxps`: the distances are never NaN.
    let max = |a: f32, b: f32| if a > b { a } else { b };
    for (i, l) in look[R..R + m].iter_mut().enumerate() {
        let far = max(max(max(l2[i], l1[i]), max(r1[i], r2[i])), max(max(u2[i], u1[i]), max(d1[i], d2[i])));
        *l = may_crack(c[i], far);
    }
    for x in (0..R).chain(w - R..w) {
        look[x] = edge(x);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use volwarp_core::sample::pack_color;

    const SKIN: u32 = pack_color(230, 185, 155, 255);

    fn image(w: usize, h: usize, c: u32) -> Vec<u32> {
        vec![c; w * h]
    }

    fn run(px: &mut [u32], w: usize, h: usize) {
        close_cracks(px, w, h, &mut CrackScratch::default(), &Threads::new(2));
    }

    #[test]
    fn a_one_and_a_two_pixel_crack_in_a_surface_close() {
        let (w, h) = (9, 5);
        let mut px = image(w, h, SKIN);
        px[2 * w + 2] = BACKGROUND; // one pixel, uncovered
        px[2 * w + 5] = pack_color(60, 50, 50, 255); // a thin footprint over the background
        px[2 * w + 6] = BACKGROUND;
        run(&mut px, w, h);
        // The uncovered pixel takes the surface; the thin footprint keeps its own color under
        // the share of the surface it lacked (a few levels off the surface's).
        for (x, tol) in [(2, 0), (5, 4), (6, 0)] {
            let got = px[2 * w + x].to_le_bytes();
            let want = SKIN.to_le_bytes();
            for c in 0..3 {
                assert!((got[c] as i32 - want[c] as i32).abs() <= tol, "pixel {x}: {got:?} against {want:?}");
            }
        }
        assert!(px.iter().enumerate().all(|(i, &p)| p == SKIN || [2 * w + 2, 2 * w + 5, 2 * w + 6].contains(&i)));
    }

    /// `c`'s color `share` of the way from the background (premultiplied over it).
    fn dimmed(c: u32, share: f32) -> u32 {
        let (c, b) = (c.to_le_bytes(), BACKGROUND.to_le_bytes());
        let ch = |i: usize| (b[i] as f32 + share * (c[i] as f32 - b[i] as f32)).round() as u8;
        pack_color(ch(0), ch(1), ch(2), 255)
    }

    #[test]
    fn a_semi_transparent_slab_s_speck_closes_and_another_hue_stays() {
        let (w, h) = (7, 3);
        for (share, closes) in [(0.6, true), (0.8, true), (0.84, true), (0.88, false)] {
            let mut px = image(w, h, SKIN);
            px[w + 3] = dimmed(SKIN, share);
            let before = px.clone();
            run(&mut px, w, h);
            let got = px[w + 3].to_le_bytes();
            let near = (0..3).all(|c| (got[c] as i32 - SKIN.to_le_bytes()[c] as i32).abs() <= 2);
            assert_eq!(near, closes, "share {share}: {got:?}");
            assert!(px.iter().zip(&before).enumerate().all(|(i, (a, b))| a == b || i == w + 3));
        }
        // The same distance from the background in a redder hue (a vessel): not a speck.
        let vessel = pack_color(205, 120, 95, 255);
        let mut px = image(w, h, SKIN);
        px[w + 3] = vessel;
        let before = px.clone();
        run(&mut px, w, h);
        assert_eq!(px, before);
    }

    #[test]
    fn silhouettes_wide_gaps_and_dark_detail_stay() {
        let (w, h) = (12, 3);
        let mut px = image(w, h, BACKGROUND);
        // A surface ending at x = 4 (its silhouette against the background), and one from x = 8
        // after a gap of three pixels: no crack.
        for y in 0..h {
            for x in (0..=4).chain(8..w) {
                px[y * w + x] = SKIN;
            }
        }
        // Dark detail on the surface (a vessel): darker, but not the background showing
        // through.
        let vessel = pack_color(200, 140, 110, 255);
        px[w + 2] = vessel;
        let before = px.clone();
        run(&mut px, w, h);
        assert_eq!(px, before);
    }

    #[test]
    fn unlike_neighbours_leave_the_pixel_alone() {
        // A dark pixel between two surfaces of different colors: an edge, not a crack.
        let (w, h) = (3, 1);
        let mut px = vec![SKIN, BACKGROUND, pack_color(40, 120, 200, 255)];
        let before = px.clone();
        run(&mut px, w, h);
        assert_eq!(px, before);
    }

    /// Every pixel looked at, without the pass's pre-test.
    fn reference(px: &[u32], w: usize, h: usize) -> Vec<u32> {
        let dist: Vec<f32> = px.iter().map(|&p| distance2(p)).collect();
        (0..w * h).map(|j| crack_at(px, &dist, w, h, j % w, j / w).map_or(px[j], |s| closed(px[j], s))).collect()
    }

    #[test]
    fn the_pre_test_skips_no_crack() {
        let mut state = 99u32;
        let mut rnd = || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            state >> 8
        };
        for (w, h) in [(64, 48), (5, 70), (1, 9)] {
            // Surfaces of a few colors and brightnesses with holes, thin footprints and dark
            // detail, over the background.
            let colors =
                [SKIN, pack_color(120, 90, 70, 255), pack_color(40, 120, 200, 255), pack_color(70, 60, 60, 255)];
            let px: Vec<u32> = (0..w * h)
                .map(|_| match rnd() % 8 {
                    0 => BACKGROUND,
                    1 => pack_color((rnd() % 256) as u8, (rnd() % 256) as u8, (rnd() % 256) as u8, 255),
                    k => colors[k as usize % 4],
                })
                .collect();
            let mut got = px.clone();
            run(&mut got, w, h);
            assert_eq!(got, reference(&px, w, h), "{w}×{h}");
            if w * h > 1000 {
                assert!(got.iter().zip(&px).filter(|(a, b)| a != b).count() > 10, "cracks closed");
            }
        }
    }

    #[test]
    fn parallel_and_serial_agree_and_odd_sizes_are_safe() {
        let (w, h) = (37, 70);
        let mut state = 12345u32;
        let mut rnd = || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            state
        };
        let px: Vec<u32> = (0..w * h)
            .map(|_| if (rnd() >> 16) % 4 == 0 { BACKGROUND } else { SKIN ^ ((rnd() >> 8) & 0x000f_0f0f) })
            .collect();
        let (mut a, mut b) = (px.clone(), px.clone());
        close_cracks(&mut a, w, h, &mut CrackScratch::default(), &Threads::new(1));
        close_cracks(&mut b, w, h, &mut CrackScratch::default(), &Threads::new(3));
        assert_eq!(a, b);
        assert_ne!(a, px, "random holes in a surface are closed");
        for (w, h) in [(0, 0), (1, 1), (2, 1), (1, 3)] {
            let mut px = vec![BACKGROUND; w * h];
            run(&mut px, w, h);
        }
    }
}
