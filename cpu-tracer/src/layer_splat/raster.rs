//! The raster: footprints binned to bands of rows, each band's pixels taking the footprints
//! that cover them into short key lists, sorted and composited front to back.

use super::*;

impl LayerSplat {
    /// Composites `scene` for `camera` into `out` (already sized and cleared to the background)
    /// with footprints of half side [`LayerOptions::own`] source pixels, `grown` for samples at
    /// least [`LayerOptions::grow_min_alpha`] opaque; leaves `count` with each output pixel's
    /// number of segments.
    pub(super) fn draw(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        grown: f32,
        shared: &[[f32; 4]],
        out: &mut Image,
        only: Option<Holes>,
    ) {
        let own = self.opts.own;
        let (w, h) = (camera.width as usize, camera.height as usize);
        let deq = &scene.deq;
        let cap = LIST;
        self.count.clear();
        self.count.resize(w * h, 0);
        let mut setup = Setup::new(camera, &scene.header.camera, deq, own, grown, self.opts.grow_min_alpha);
        setup.water_ratio = self.opts.water_ratio;
        setup.opacity_limit = self.opts.opacity_limit;
        let colors = &scene.colors[..];
        // Each sample's color as drawn (its optical depth scaled with its footprint's area
        // where it takes its slab's shared corners, `drawn_color`).
        let mut drawn = core::mem::take(&mut self.drawn);
        drawn.resize(scene.samples.len(), 0);
        // 1. Every sample's footprint in the new image (in parallel over samples, eight at a
        // time in SIMD lanes). Every footprint is written (NONE where there is none): no
        // clearing pass.
        // The buffers only grow (an older frame's few samples between two newest frames must not
        // make the next draw rewrite them whole).
        let n = scene.samples.len();
        if self.quads.len() < n {
            self.quads.resize(n, Quad::NONE);
        }
        if self.bands.len() < n {
            self.bands.resize(n, NO_BANDS);
        }
        let samples = &scene.samples[..];
        self.threads.for_each_chunk_triple(
            &mut self.quads[..n],
            &mut self.bands[..n],
            &mut drawn[..n],
            QUAD_CHUNK,
            |chunk, quads, bands, drawn| {
                let first = chunk * QUAD_CHUNK;
                let sh = shared.get(first..(first + quads.len()).min(shared.len())).unwrap_or(&[]);
                footprints(&setup, &samples[first..first + quads.len()], colors, sh, first, quads, drawn);
                if let Some(holes) = only {
                    for q in quads.iter_mut().filter(|q| q.x[0] <= q.x[1] && !holes.near(q)) {
                        *q = Quad::NONE;
                    }
                }
                // The bands each footprint touches, for the binning below (4 bytes a sample to
                // read there instead of the 64-byte footprint).
                for (b, q) in bands.iter_mut().zip(quads.iter()) {
                    *b = if q.x[0] <= q.x[1] {
                        (q.y[0] as usize / RASTER_BAND) as u32 | ((q.y[1] as usize / RASTER_BAND) as u32) << 16
                    } else {
                        NO_BANDS
                    };
                }
            },
        );
        // 2. Each footprint to the row bands it touches: one task per thread, each over its
        // run of footprints into its own lists, so band `b`'s footprints are the tasks' lists
        // `b` one after the other (in the footprints' order).
        let bands = h.div_ceil(RASTER_BAND);
        let tasks = self.threads.count().max(1);
        self.bins.resize_with(tasks, Vec::new);
        let per_task = n.div_ceil(tasks).max(1);
        let footprint_bands = &self.bands[..n];
        self.threads.for_each_chunk(&mut self.bins, 1, |t, task| {
            let bins = &mut task[0];
            bins.resize_with(bands, Vec::new);
            bins.iter_mut().for_each(Vec::clear);
            let first = (t * per_task).min(n);
            for (id, &b) in footprint_bands[first..(first + per_task).min(n)].iter().enumerate() {
                for bin in &mut bins[(b & 0xffff) as usize..=(b >> 16) as usize] {
                    bin.push((first + id) as u32);
                }
            }
        });
        // 3. Per band of rows: its pixels take their footprints' keys, then the band is
        // composited while its lists are still in the cache (in parallel over bands: the lists
        // keep the nearest keys whatever the order, so the image does not depend on it). The
        // lists live in a band-sized buffer per thread, not one for the whole image.
        let (quads, bins) = (&self.quads[..], &self.bins[..]);
        let colors = &drawn[..];
        let band = |b: usize, px: &mut [u32], count: &mut [u8]| {
            // A band no footprint touches keeps its pixels (their counts are 0): an older
            // frame's few samples touch few bands.
            if bins.iter().all(|task| task[b].is_empty()) {
                return;
            }
            LISTS.with_borrow_mut(|keys| {
                if keys.len() < RASTER_BAND * w * cap {
                    keys.resize(RASTER_BAND * w * cap, u64::MAX);
                }
                let y_lo = b * RASTER_BAND;
                for list in bins.iter().map(|task| &task[b]) {
                    for (k, &id) in list.iter().enumerate() {
                        // The footprints are read in their order but scattered over ~60 MB:
                        // the one PREFETCH ahead is asked for now.
                        if let Some(&ahead) = list.get(k + PREFETCH) {
                            prefetch(&quads[ahead as usize]);
                        }
                        let q = &quads[id as usize];
                        let (ya, yb) = ((q.y[0] as usize).max(y_lo), (q.y[1] as usize).min(y_lo + RASTER_BAND - 1));
                        for y in ya..=yb {
                            let row = q.row(y as f32 + 0.5);
                            for x in q.x[0] as usize..=q.x[1] as usize {
                                let px = x as f32 + 0.5;
                                if row.covers(px) && only.is_none_or(|h| h.state[y * w + x] == UNFILLED) {
                                    let i = (y - y_lo) * w + x;
                                    insert(&mut keys[i * cap..(i + 1) * cap], &mut count[i], q.key);
                                }
                            }
                        }
                    }
                }
                for (i, &n) in count.iter().enumerate().filter(|(_, &n)| n > 1) {
                    sort_keys(&mut keys[i * cap..i * cap + n as usize]);
                }
                composite_run(keys, count, colors, px);
            })
        };
        let count = &mut self.count[..];
        self.threads.for_each_chunk_pair(&mut out.pixels, count, RASTER_BAND * w, band);
        self.drawn = drawn;
    }
}

/// Where an older frame may still draw: the fill state of every pixel and which tiles of
/// [`HOLE_TILE`]² pixels hold an unfilled one (footprints touching none are skipped whole).
#[derive(Clone, Copy)]
pub(super) struct Holes<'a> {
    pub(super) state: &'a [u64],
    pub(super) tiles: &'a [u8],
    pub(super) tiles_w: usize,
}

/// The side of [`Holes`]' tiles, pixels.
const HOLE_TILE: usize = 8;

impl Holes<'_> {
    /// Marks in `tiles` the tiles of a `w`-wide image holding an unfilled pixel.
    pub(super) fn mark(state: &[u64], w: usize, tiles: &mut Vec<u8>) -> usize {
        let tw = w.div_ceil(HOLE_TILE);
        let th = (state.len() / w.max(1)).div_ceil(HOLE_TILE);
        tiles.clear();
        tiles.resize(tw * th, 0);
        for (y, row) in state.chunks_exact(w.max(1)).enumerate() {
            for (x, _) in row.iter().enumerate().filter(|(_, &s)| s == UNFILLED) {
                tiles[(y / HOLE_TILE) * tw + x / HOLE_TILE] = 1;
            }
        }
        tw
    }

    /// Whether footprint `q`'s bounds touch a tile with an unfilled pixel.
    #[inline]
    fn near(&self, q: &Quad) -> bool {
        let (x0, x1) = (q.x[0] as usize / HOLE_TILE, q.x[1] as usize / HOLE_TILE);
        let (y0, y1) = (q.y[0] as usize / HOLE_TILE, q.y[1] as usize / HOLE_TILE);
        (y0..=y1)
            .any(|ty| self.tiles.get(ty * self.tiles_w + x0..=ty * self.tiles_w + x1).is_some_and(|r| r.contains(&1)))
    }
}

/// How many footprints ahead the rasterizer asks for a footprint's cache line.
const PREFETCH: usize = 24;

/// Asks the CPU to bring `q`'s cache line closer (a hint: no effect on any result).
#[inline(always)]
fn prefetch(q: &Quad) {
    crate::lanes::prefetch(core::slice::from_ref(q));
}

thread_local! {
    /// The per-pixel key lists of the band a thread is drawing (`RASTER_BAND` rows × `LIST`).
    static LISTS: core::cell::RefCell<Vec<u64>> = const { core::cell::RefCell::new(Vec::new()) };
}
