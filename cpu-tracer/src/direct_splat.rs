//! Exact sphere splatting in the samples' own order, without binning ([`DirectSplat`]): the
//! same image as first-hit tracing — core's ray–sphere test for every covered pixel's own
//! primary ray and core's tie rule — like [`crate::TileSplat`], but with no tiles, no bins and
//! no second read of the spheres. **Not the default and not in the renderer registry**: on the
//! MRI benchmark frame it is measured 1.2–1.4× slower than the tiled splatter at 1024² and
//! level with it at 512² (`docs/perf.md`, "Measured and not built"); it stays for measurements
//! (`examples/splat_timing.rs` names it `splat-direct`, the bench times it) and as the tested
//! record of that route.
//!
//! The server compacts a frame's samples in its camera's scanline order, and the LBVH orders a
//! built scene in Morton order: either way consecutive spheres land near each other on the new
//! image, so a whole-image key plane is touched a band of rows at a time (at 1024² from the
//! benchmark frame about 40 rows: the depth variation of one source row). The spheres are taken
//! in the scene's order:
//!
//! 1. **Bound**, eight at a time in f32 lanes: the pixels whose *centres* lie between the
//!    tangents from the eye (the tiled splatter's bound, [`crate::tile_splat`]). A sphere whose
//!    rectangle holds no pixel centre costs only this.
//! 2. **Pack**: every pixel of the rectangle, as 4×2 windows, goes into a stream of
//!    (sphere, pixel) pairs: the window's pixel centres are left-packed by the mask of pixels
//!    inside the rectangle (one `vpermps` with a 256-entry table), and the sphere's centre
//!    relative to the eye and squared radius are written beside them. The common case, a
//!    rectangle of at most 4×2 pixels (or 4×4 when more than a quarter of a subsample's small
//!    rectangles are three or four rows tall, as at 1024² from a 1024² frame), is one or two
//!    windows with no branch on its size.
//! 3. **Test**, eight pairs at a time, every lane a useful pixel: the lanes' unit ray
//!    directions (`RayBasis::dir`'s operations) and the packet tracer's ray–sphere operations
//!    (the same `t` bit for bit), then per hit lane a 64-bit key `(t bits << 32) | id` kept if
//!    smaller than the pixel's (core's tie rule: equal `t`, the smaller index). An unbuilt
//!    scene's ties go to a cold path with the order the LBVH build would give, as in
//!    [`crate::TileSplat`].
//!
//! Packing makes the lanes full: at 512² from the benchmark frame a sphere covers about two
//! pixel centres, and a 4×2 block per sphere tests eight lanes for two. (Per-frame direction
//! planes read by the windows, and 4×2 blocks tested in place against whole-image depth and id
//! planes, were measured first and were slower: the planes' band of rows does not stay in L2.)
//!
//! **Threads, no merge.** The image is cut into one band of rows per thread, each holding about
//! as many spheres (quantiles of the rectangles' centre rows of a subsample). Thread `k` takes
//! the `k`-th contiguous share of the spheres, bounds them and draws what falls in its own band;
//! a sphere that reaches into another band is handed to that band's thread (its index and
//! rectangle), which draws it, clipped to its rows, in a second pass after all first passes.
//! Every (sphere, pixel) pair is tested once, by the pixel's owner, and the kept key is a
//! minimum, so the image does not depend on the thread count or on the order (tested). In the
//! server's scanline order the shares and the bands nearly coincide and few spheres are handed
//! over (about 1 %); in Morton order about as many as the share holds (the second pass then
//! draws them), still with no whole-image merge.
//!
//! Memory: 8 bytes per pixel (the keys; rows are cleared as the spheres first reach them), a stream of a few hundred pairs per
//! thread and 12 bytes per handed-over sphere. No occlusion culling: spheres large on screen
//! are the tracer's (the cost model's) case.

use crate::depth_buffer::EMPTY;
use crate::lanes::{self, ray_dirs, Lanes};
use crate::sphere_splat::View;
use crate::threads::Threads;
use crate::tile_splat::{bound_group, sorted_before, tight_bound, Rect, Ties, ViewF32, NO_RECT};
use crate::{begin_frame_unbuilt_ok as begin_frame, shade, NO_HIT};
use rayon::prelude::*;
use volwarp_core::renderer::Image;
#[cfg(doc)]
use volwarp_core::renderer::Renderer;
use volwarp_core::sample::Dequantizer;
#[cfg(doc)]
use volwarp_core::RendererKind;
use volwarp_core::{Camera, RayBasis, Scene, BACKGROUND};

/// Spheres bounded by one call of the bound kernel.
const CHUNK: usize = 32;

/// Spheres of the subsample that places the bands and picks one or two windows.
const BAND_SAMPLE: usize = 4096;

/// Pairs a stream holds before it is tested (plus eight of slack for the last window).
const CAP: usize = 256;

/// The exact sphere splatter in the samples' order (see the module docs).
#[derive(Debug)]
pub struct DirectSplat {
    threads: Threads,
    bands: Vec<Band>,
    /// `handed[src][dst]`: spheres thread `src` bounded that reach into band `dst`.
    handed: Vec<Vec<Vec<(u32, Rect)>>>,
    /// Force one window (`Some(false)`) or two (`Some(true)`) for the common case; `None`:
    /// chosen per frame.
    force_two: Option<bool>,
    /// Whether the last frame took two windows.
    last_two: bool,
}

/// One thread's rows of the image, its key plane (row stride: the image width) and its stream
/// of pairs.
#[derive(Debug)]
struct Band {
    /// First image row.
    y0: usize,
    /// Rows (at least one).
    rows: usize,
    /// Per pixel, the key `(t bits << 32) | id` of the nearest hit so far, [`EMPTY`] where none.
    keys: Vec<u64>,
    /// Rows whose keys are cleared and directions computed this frame ([`ensure_rows`]).
    ready: usize,
    stream: Box<Stream>,
}

impl Default for Band {
    fn default() -> Self {
        Band { y0: 0, rows: 1, keys: Vec::new(), ready: 0, stream: Box::new(Stream::default()) }
    }
}

impl Band {
    fn plane(&self, stride: usize) -> usize {
        self.rows * stride
    }
}

/// (sphere, pixel) pairs waiting for their test, in planes: the pixel's centre (`f[0..2]`:
/// column and image row + 0.5), the sphere's centre less the eye (`f[2..5]`) and squared radius (`f[5]`), the
/// pixel's index in the band's planes and the sphere's index.
#[derive(Debug)]
struct Stream {
    n: usize,
    f: [[f32; CAP + 8]; 6],
    pix: [u32; CAP + 8],
    id: [u32; CAP + 8],
}

impl Default for Stream {
    fn default() -> Self {
        Stream { n: 0, f: [[0.0; CAP + 8]; 6], pix: [0; CAP + 8], id: [0; CAP + 8] }
    }
}

/// What every band's passes read.
struct Ctx<'a> {
    view: &'a View,
    vf: &'a ViewF32,
    scene: &'a Scene,
    stride: usize,
    /// Whether the common case is two 4×2 windows (rectangles up to 4×4) instead of one (up to
    /// 4×2): chosen per frame from the subsample's rectangle heights.
    two: bool,
    /// `(first row, rows)` of every band.
    bands: &'a [(usize, usize)],
}

impl DirectSplat {
    /// A splatter on `threads` threads (0: one per core).
    pub fn new(threads: usize) -> Self {
        DirectSplat {
            threads: Threads::new(threads),
            bands: Vec::new(),
            handed: Vec::new(),
            force_two: None,
            last_two: false,
        }
    }

    /// The same splatter always taking one 4×2 window (`false`) or two (`true`) for a small
    /// rectangle instead of choosing per frame (for tests and measurements: the image is the
    /// same).
    pub fn with_windows(mut self, two: bool) -> Self {
        self.force_two = Some(two);
        self
    }

    /// Whether the last frame's common case was two windows.
    pub fn last_two_windows(&self) -> bool {
        self.last_two
    }

    /// The number of threads it draws with.
    pub fn threads(&self) -> usize {
        self.threads.count()
    }

    /// Of the last frame: the spheres handed from one band's thread to another's.
    pub fn handed_over(&self) -> usize {
        self.handed.iter().flatten().map(Vec::len).sum()
    }

    /// The first row of every band of the last frame, and the image height last.
    pub fn band_rows(&self) -> Vec<usize> {
        let mut v: Vec<usize> = self.bands.iter().map(|b| b.y0).collect();
        v.extend(self.bands.last().map(|b| b.y0 + b.rows));
        v
    }

    /// Splats `camera`'s viewport into `ids` (row-major, resized): the first-hit sample index
    /// per pixel, [`NO_HIT`] where none. `false` if the camera or scene is unusable.
    pub fn splat_ids(&mut self, scene: &Scene, camera: &Camera, ids: &mut Vec<u32>) -> bool {
        let mut img = Image { width: 0, height: 0, pixels: std::mem::take(ids) };
        let ok = begin_frame(scene, camera, &mut img);
        *ids = img.pixels;
        ids.fill(NO_HIT);
        if ok {
            self.draw(scene, camera, ids, |_, id| id);
        }
        ok
    }

    /// Draws the scene, writing `out_of(colors, id)` for every pixel of `out` (`width ×
    /// height` long; `id` the pixel's first-hit sample, [`NO_HIT`] where none).
    fn draw(&mut self, scene: &Scene, camera: &Camera, out: &mut [u32], out_of: impl Fn(&[u32], u32) -> u32 + Sync) {
        let view = View::new(camera);
        let vf = ViewF32::new(&view);
        let (w, h) = (camera.width as usize, camera.height as usize);
        let (rows, two) = band_rows(scene, &view, self.threads.count().min(h).max(1));
        let two = self.force_two.unwrap_or(two);
        self.last_two = two;
        let nb = rows.len();
        let bands: Vec<(usize, usize)> = rows.iter().map(|&(a, b)| (a, b - a)).collect();
        self.bands.resize_with(nb, Band::default);
        for (b, &(y0, r)) in self.bands.iter_mut().zip(&bands) {
            (b.y0, b.rows) = (y0, r);
        }
        self.handed.resize_with(nb, Vec::new);
        for h in &mut self.handed {
            h.resize_with(nb, Vec::new);
            h.iter_mut().for_each(Vec::clear);
        }
        let ctx = Ctx { view: &view, vf: &vf, scene, stride: w, two, bands: &bands };
        let n = scene.samples.len();
        let share = |k: usize| (n * k / nb, n * (k + 1) / nb);
        let colors = &scene.colors[..];
        let write = |b: &Band, out: &mut [u32]| {
            for (y, row) in out.chunks_mut(w).enumerate() {
                for (p, &k) in row.iter_mut().zip(&b.keys[y * ctx.stride..y * ctx.stride + w]) {
                    *p = out_of(colors, if k == EMPTY { NO_HIT } else { k as u32 });
                }
            }
        };
        if nb == 1 {
            let (lo, hi) = share(0);
            first_pass(&ctx, &mut self.bands[0], 0, lo, hi, &mut self.handed[0]);
            write(&self.bands[0], out);
            return;
        }
        let ctx = &ctx;
        let (bufs, handed) = (&mut self.bands, &mut self.handed);
        self.threads.install(|| {
            bufs.par_iter_mut().zip(handed.par_iter_mut()).enumerate().for_each(|(k, (b, hd))| {
                let (lo, hi) = share(k);
                first_pass(ctx, b, k, lo, hi, hd)
            })
        });
        let mut outs = Vec::with_capacity(nb);
        let mut rest = out;
        for &(_, r) in &bands {
            let (a, b) = rest.split_at_mut(r * w);
            outs.push(a);
            rest = b;
        }
        let handed = &self.handed;
        self.threads.install(|| {
            self.bands.par_iter_mut().zip(outs.into_par_iter()).enumerate().for_each(|(k, (b, o))| {
                second_pass(ctx, b, k, handed);
                write(b, o);
            })
        });
    }
}

/// `[start, end)` rows of `bands` bands (at most `height`; at least one row each) holding about
/// as many spheres — quantiles of the centre rows of a subsample's rectangles (equal rows when
/// none is in view) — and whether the common case should be two 4×2 windows: more than a
/// quarter of the subsample's rectangles of width ≤ 4 and height ≤ 4 are 3 or 4 rows tall.
fn band_rows(scene: &Scene, view: &View, bands: usize) -> (Vec<(usize, usize)>, bool) {
    let h = view.height as usize;
    let n = scene.samples.len();
    let mut ys = Vec::new();
    let (mut small, mut tall) = (0usize, 0usize);
    if n > 0 {
        let step = (n / BAND_SAMPLE).max(1);
        for &s in scene.samples.iter().step_by(step) {
            if let Some((x0, x1, y0, y1)) = tight_bound(view, scene.deq.center(s), scene.deq.radius(s)) {
                ys.push((y0 + y1) / 2);
                if x1 - x0 < 4 && y1 - y0 < 4 {
                    small += 1;
                    tall += (y1 - y0 >= 2) as usize;
                }
            }
        }
        ys.sort_unstable();
    }
    let mut cuts = vec![0usize];
    for k in 1..bands {
        let y = if ys.is_empty() { h * k / bands } else { ys[ys.len() * k / bands] as usize };
        // At least one row per band, in order.
        let y = y.max(cuts[k - 1] + 1).min(h - (bands - k));
        cuts.push(y);
    }
    cuts.push(h);
    (cuts.windows(2).map(|c| (c[0], c[1])).collect(), 4 * tall > small)
}

/// For every 8-bit mask, the lanes whose bit is set, in order (then zeros): the `vpermps`
/// indices that left-pack them.
const PACK: [[u32; 8]; 256] = {
    let mut t = [[0u32; 8]; 256];
    let mut m = 0;
    while m < 256 {
        let (mut l, mut k) = (0, 0);
        while l < 8 {
            if m >> l & 1 == 1 {
                t[m][k] = l as u32;
                k += 1;
            }
            l += 1;
        }
        m += 1;
    }
    t
};

/// Lanes of a 4×2 window (lane `l` is pixel `(l % 4, l / 4)`) whose column is below `w`
/// (index `w`, at most 4).
const WBITS: [u32; 5] = [0, 0x11, 0x33, 0x77, 0xff];
/// Lanes whose row is below `h` (index `h`, at most 2).
const HBITS: [u32; 3] = [0, 0x0f, 0xff];

/// The per-frame constants of the kernels.
struct Kernel<'a, L> {
    basis: &'a RayBasis,
    /// Pixel-centre offsets of a window's lanes: `l % 4 + 0.5`, `l / 4 + 0.5`.
    lane4c: L,
    row2c: L,
    samples: &'a [u64],
    deq: &'a Dequantizer,
    ties: Ties<'a>,
    o: [f32; 3],
    stride: usize,
    /// Offsets of a window's pixels in a plane: `l % 4 + (l / 4)·stride`.
    offsets: [u32; 8],
}

impl<'a, L: Lanes> Kernel<'a, L> {
    fn new(ctx: &Ctx<'a>) -> Self {
        let b = &ctx.view.basis;
        let samples = &ctx.scene.samples[..];
        let s = ctx.stride as u32;
        Kernel {
            basis: b,
            lane4c: L::new([0.5, 1.5, 2.5, 3.5, 0.5, 1.5, 2.5, 3.5]),
            row2c: L::new([0.5, 0.5, 0.5, 0.5, 1.5, 1.5, 1.5, 1.5]),
            samples,
            deq: &ctx.scene.deq,
            ties: if ctx.scene.nodes.is_empty() { Ties::Sorted(samples) } else { Ties::Index },
            o: [b.eye[0], b.eye[1], b.eye[2]],
            stride: ctx.stride,
            offsets: [0, 1, 2, 3, s, s + 1, s + 2, s + 3],
        }
    }

    /// What the stream holds of sphere `i`: its centre less the eye and its squared radius,
    /// as `sphere_hits` computes them.
    #[inline(always)]
    fn sphere(&self, i: u32) -> [f32; 4] {
        let s = self.samples.get(i as usize).copied().unwrap_or(0);
        let (c, r) = (self.deq.center(s), self.deq.radius(s));
        [c.x - self.o[0], c.y - self.o[1], c.z - self.o[2], r * r]
    }
}

/// Sizes `band`'s key plane for the frame; its rows are cleared when first needed
/// ([`ensure_rows`]).
fn prepare(ctx: &Ctx, band: &mut Band) {
    let plane = band.plane(ctx.stride);
    band.keys.resize(plane, EMPTY);
    band.stream.n = 0;
    band.ready = 0;
}

/// Rows made ready at a time by [`ensure_rows`].
const READY_STEP: usize = 8;

/// Makes `band`'s rows up to `y` (band rows, inclusive) ready: their keys cleared. Done a few
/// rows at a time as the spheres first reach them, so in the server's scanline order a row's
/// keys are still in cache when its spheres are drawn.
#[inline(always)]
fn ensure_rows(ctx: &Ctx, band: &mut Band, y: usize) {
    if y >= band.ready && band.ready < band.rows {
        make_ready(ctx, band, (y + READY_STEP).min(band.rows));
    }
}

/// [`ensure_rows`]'s work: rows `band.ready..end`.
#[inline(never)]
fn make_ready(ctx: &Ctx, band: &mut Band, end: usize) {
    let stride = ctx.stride;
    if let Some(k) = band.keys.get_mut(band.ready * stride..end * stride) {
        k.fill(EMPTY);
    }
    band.ready = end;
}

/// Pass 1 of band `k`: its planes, then the spheres `lo..hi` bounded [`CHUNK`] at a time, each
/// drawn in this band where it reaches it and handed to every other band it reaches.
#[inline(always)]
fn first_pass_lanes<L: Lanes>(
    ctx: &Ctx,
    band: &mut Band,
    k: usize,
    lo: usize,
    hi: usize,
    handed: &mut [Vec<(u32, Rect)>],
) {
    prepare(ctx, band);
    let kern = Kernel::<L>::new(ctx);
    let (by0, by1) = (band.y0, band.y0 + band.rows - 1);
    let (two, stride) = (ctx.two, ctx.stride);
    let hmax = if two { 4 } else { 2 };
    let mut rects = [NO_RECT; CHUNK];
    let samples = &ctx.scene.samples[..];
    let mut i = lo;
    while i < hi {
        let n = CHUNK.min(hi - i);
        let rects = &mut rects[..n];
        bound_group::<L>(ctx.view, ctx.vf, &ctx.scene.deq, &samples[i..i + n], rects, &mut []);
        for (j, &r) in rects.iter().enumerate() {
            let id = (i + j) as u32;
            let (ry0, ry1) = (r.y0 as usize, r.y1 as usize);
            // The common case without a branch on the sphere's size: a rectangle (or none:
            // `w = h = 0`) of one or two 4×2 windows inside this band.
            let (w, h) = (r.x1 as i32 - r.x0 as i32 + 1, ry1 as i32 - ry0 as i32 + 1);
            if ry0 >= by0 && ry1 <= by1 && w <= 4 && h <= hmax {
                ensure_rows(ctx, band, ry0 - by0 + hmax as usize);
                let sph = kern.sphere(id);
                let (wb, x0) = (WBITS[w.clamp(0, 4) as usize], r.x0 as usize);
                let at = (ry0 - by0) * stride + x0;
                emit::<L>(&kern, band, at, x0, ry0, wb & HBITS[h.clamp(0, 2) as usize], &sph, id);
                if two {
                    let hb = HBITS[(h - 2).clamp(0, 2) as usize];
                    emit::<L>(&kern, band, at + 2 * stride, x0, ry0 + 2, wb & hb, &sph, id);
                }
                continue;
            }
            if r.is_empty() {
                continue;
            }
            if ry1 >= by0 && ry0 <= by1 {
                ensure_rows(ctx, band, ry1.min(by1) - by0);
                windows::<L>(&kern, band, r, id);
            }
            if ry0 < by0 || ry1 > by1 {
                hand_over(ctx.bands, k, r, id, handed);
            }
        }
        i += n;
    }
    ensure_rows(ctx, band, band.rows - 1);
    flush::<L>(&kern, band, true);
}

/// Hands the sphere `id` (rectangle `r`) to every band but `k` that it reaches.
#[inline(never)]
fn hand_over(bands: &[(usize, usize)], k: usize, r: Rect, id: u32, handed: &mut [Vec<(u32, Rect)>]) {
    let (ry0, ry1) = (r.y0 as usize, r.y1 as usize);
    for (d, (&(y0, rows), list)) in bands.iter().zip(handed.iter_mut()).enumerate() {
        if d != k && ry1 >= y0 && ry0 < y0 + rows {
            list.push((id, r));
        }
    }
}

/// Pass 2 of band `k`: the spheres the other bands' threads handed to it.
#[inline(always)]
fn second_pass_lanes<L: Lanes>(ctx: &Ctx, band: &mut Band, k: usize, handed: &[Vec<Vec<(u32, Rect)>>]) {
    let kern = Kernel::<L>::new(ctx);
    for from in handed {
        if let Some(list) = from.get(k) {
            for &(id, r) in list {
                windows::<L>(&kern, band, r, id);
            }
        }
    }
    flush::<L>(&kern, band, true);
}

lanes::dispatch! {
    /// [`first_pass_lanes`] on the best lanes this CPU has.
    fn first_pass / first_pass_avx2 => first_pass_lanes(
        ctx: &Ctx,
        band: &mut Band,
        k: usize,
        lo: usize,
        hi: usize,
        handed: &mut [Vec<(u32, Rect)>],
    )
}

lanes::dispatch! {
    /// [`second_pass_lanes`] on the best lanes this CPU has.
    fn second_pass / second_pass_avx2 => second_pass_lanes(
        ctx: &Ctx,
        band: &mut Band,
        k: usize,
        handed: &[Vec<Vec<(u32, Rect)>>],
    )
}

/// Writes the eight lanes `a` at `s[at..]` (the stream's planes have eight of slack).
#[inline(always)]
fn store<T: Copy>(s: &mut [T], at: usize, a: [T; 8]) {
    if let Some(r) = s.get_mut(at..).and_then(|r| r.first_chunk_mut::<8>()) {
        *r = a;
    }
}

/// Every pixel of the rectangle `r` (image rows, clipped to `band`'s) of sphere `i`, as 4×2
/// windows, into the stream.
#[inline(always)]
fn windows<L: Lanes>(k: &Kernel<L>, band: &mut Band, r: Rect, i: u32) {
    let y0 = (r.y0 as usize).max(band.y0) - band.y0;
    let y1 = (r.y1 as usize).min(band.y0 + band.rows - 1) - band.y0;
    let (x0, x1) = (r.x0 as usize, r.x1 as usize);
    let sph = k.sphere(i);
    for y in (y0..=y1).step_by(2) {
        let hb = HBITS[(y1 - y + 1).min(2)];
        for x in (x0..=x1).step_by(4) {
            emit::<L>(k, band, y * k.stride + x, x, band.y0 + y, WBITS[(x1 - x + 1).min(4)] & hb, &sph, i);
        }
    }
}

/// The pixels `bits` of the 4×2 window at `at` in `band`'s planes, for sphere `i` (`sph`:
/// [`Kernel::sphere`]), left-packed onto the stream; the stream is tested when nearly full.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn emit<L: Lanes>(k: &Kernel<L>, band: &mut Band, at: usize, px: usize, py: usize, bits: u32, sph: &[f32; 4], i: u32) {
    let perm = L::new_u(PACK[(bits & 0xff) as usize]);
    let st = &mut *band.stream;
    let n = st.n;
    store(&mut st.f[0], n, (L::splat(px as f32) + k.lane4c).permute(perm).to_array());
    store(&mut st.f[1], n, (L::splat(py as f32) + k.row2c).permute(perm).to_array());
    for (plane, &v) in st.f[2..].iter_mut().zip(sph) {
        store(plane, n, [v; 8]);
    }
    let pix = L::permute_u(L::new_u(core::array::from_fn(|l| at as u32 + k.offsets[l])), perm);
    store(&mut st.pix, n, L::u_to_array(pix));
    store(&mut st.id, n, [i; 8]);
    st.n = n + (bits & 0xff).count_ones() as usize;
    if st.n > CAP - 8 {
        flush::<L>(k, band, false);
    }
}

/// Tests the stream's pairs eight at a time (all of them if `all`, else whole eights, the rest
/// kept for the next call): `sphere_hits`'s operations in lanes, then per lane the key kept if
/// smaller than the pixel's.
#[inline(always)]
fn flush<L: Lanes>(k: &Kernel<L>, band: &mut Band, all: bool) {
    let st = &mut *band.stream;
    let keys = &mut band.keys[..];
    let n = st.n;
    let full = if all { n.div_ceil(8) * 8 } else { n / 8 * 8 };
    let lane = L::new([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]);
    let zero = L::splat(0.0);
    let mut g = 0;
    while g < full {
        let ld =
            |a: usize| -> [f32; 8] { st.f[a].get(g..).and_then(|r| r.first_chunk::<8>()).copied().unwrap_or([0.0; 8]) };
        // `RayBasis::dir` of the lanes' pixel centres.
        let [dx, dy, dz] = ray_dirs(k.basis, L::new(ld(0)), L::new(ld(1)));
        let (ox, oy, oz, r2) = (L::new(ld(2)), L::new(ld(3)), L::new(ld(4)), L::new(ld(5)));
        // `sphere_hits`, operation by operation.
        let b = ox * dx + oy * dy + oz * dz;
        let fx = ox - b * dx;
        let fy = oy - b * dy;
        let fz = oz - b * dz;
        let disc = r2 - (fx * fx + fy * fy + fz * fz);
        let active = lane.simd_lt(L::splat((n - g) as f32));
        let ok = disc.simd_ge(zero) & active;
        let sq = disc.sqrt();
        let t0 = b - sq;
        let t1 = b + sq;
        let front = t0.simd_gt(zero);
        let t = front.select(t0, t1).to_array();
        let m = (ok & (front | t1.simd_gt(zero))).to_bitmask();
        let mut bits = m;
        while bits != 0 {
            let l = bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let (Some(&p), Some(&id)) = (st.pix.get(g + l), st.id.get(g + l)) else { continue };
            let key = ((t[l].to_bits() as u64) << 32) | id as u64;
            if let Some(slot) = keys.get_mut(p as usize) {
                let old = *slot;
                *slot = if key < old { key } else { old };
                if let Ties::Sorted(samples) = k.ties {
                    if (key ^ old) >> 32 == 0 && key != old {
                        *slot = sorted_tie(samples, key, old);
                    }
                }
            }
        }
        g += 8;
    }
    if all {
        st.n = 0;
    } else {
        let rest = n - full;
        for a in st.f.iter_mut() {
            a.copy_within(full..n, 0);
        }
        st.pix.copy_within(full..n, 0);
        st.id.copy_within(full..n, 0);
        st.n = rest;
    }
}

/// Of two keys at the same distance in an unbuilt scene, the one whose sample the LBVH build
/// orders first (so the image is the built scene's).
#[inline(never)]
#[cold]
fn sorted_tie(samples: &[u64], a: u64, b: u64) -> u64 {
    if sorted_before(samples, a as u32, b as u32) {
        a
    } else {
        b
    }
}

impl DirectSplat {
    /// Draws `scene` from `camera` into `out` (resized, background where nothing is hit), as a
    /// [`Renderer`] would. It is not one of the registry's renderers (it is not faster than the
    /// tiled splatter on the benchmark frame: `docs/perf.md`, "Measured and not built"), so it
    /// has no [`RendererKind`] and does not implement the trait.
    pub fn render(&mut self, scene: &Scene, camera: &Camera, out: &mut Image) {
        if begin_frame(scene, camera, out) {
            self.draw(
                scene,
                camera,
                &mut out.pixels,
                |colors, id| if id == NO_HIT { BACKGROUND } else { shade(colors, id) },
            );
        }
    }
}
