//! `cargo run --release -p volwarp-server --example composite_timing -- [N] [SIZE] [PARTS]`:
//! the MRI benchmark view split into PARTS parts (in one process), each marched once; then the
//! first band of rows (what rank 0 owns) merged N times alone and with the whole assembly of its
//! frame samples (`FrameGeometry::assembler`, as the band owner does it); and over the band's
//! merged lists, collected once, the assembly's two lane kernels against their one-at-a-time
//! references, asserted equal: the colors packed by core's `pack_colors` one ray at a time and
//! by `PackLanes` eight at a time, the positions quantized by `Quantizer::pack` one sample at a
//! time and by `Quantizer::pack8` eight at a time (the rays' directions and radii computed
//! alike in both). The median wall ms of each is printed, with the share of the band's
//! non-empty pixels that one part alone saw. `RAYON_NUM_THREADS=1` times one core.

use std::sync::Arc;
use std::time::Instant;
use volwarp_core::sample::Quantizer;
use volwarp_core::segments::{composite, pack_colors, PackLanes, Segment, MAX_LAYERS};
use volwarp_core::wire::CameraRequest;
use volwarp_core::Heuristic;
use volwarp_server::distributed::composite::{self, BandView};
use volwarp_server::distributed::decomposition::{part_of, Decomposition};
use volwarp_server::distributed::partial::{PartMarcher, Seg};
use volwarp_server::distributed::{FrameGeometry, FramePart, PartBuilder};
use volwarp_server::{Dataset, MarchOptions, Marcher};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(7);
    let size: u32 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1024);
    let parts: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(2);
    let layers = 4u32;
    let ds = Dataset::load(volwarp_server::testdata::MRI_PATH, None).expect("loading the volume");
    let opts = MarchOptions::default();
    let m = Marcher::with_options(ds.volume.clone(), &ds.tf, opts);
    let dec = Arc::new(Decomposition::new(ds.volume.dims(), parts).unwrap());
    let pm: Vec<PartMarcher> = (0..parts)
        .map(|p| {
            let d = part_of(&ds.volume, &dec, p);
            let r = d.range;
            PartMarcher::new(Arc::new(d.into_volume(r).unwrap()), dec.clone(), p, &ds.tf, opts).unwrap()
        })
        .collect();
    let camera = m.default_camera(size, size).orbit(20.0, 10.0).dolly(0.68);
    let req = CameraRequest { seq: 1, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
    let frames: Vec<_> = pm.iter().map(|p| p.march(&camera, layers, req.heuristic)).collect();
    let geo = FrameGeometry { dims: ds.volume.dims(), spacing: ds.volume.spacing(), opts: m.options() };
    let rows = composite::band_rows(size, parts, 0);
    let pixels = (rows.end - rows.start) as usize * size as usize;
    let views: Vec<BandView> = frames.iter().map(|f| BandView::of_part(f, rows.clone())).collect();
    let k = layers as usize;
    let ert = opts.early_termination;
    // The pixels one part alone saw, of those any part saw.
    let (mut one, mut any) = (0usize, 0usize);
    for i in 0..pixels {
        let seen = views.iter().filter(|v| v.count[i] > 0).count();
        one += usize::from(seen == 1);
        any += usize::from(seen > 0);
    }
    let radius = geo.frame_radius(&req);
    let q = Quantizer::new(geo.bounds(), radius.unit());
    let basis = camera.ray_basis();
    let o = basis.origin();
    let ms = |t: Instant| t.elapsed().as_secs_f64() * 1e3;
    let (mut merge_ms, mut asm_ms) = (Vec::new(), Vec::new());
    let (mut segs, mut samples) = (0, 0);
    for _ in 0..n {
        let t = Instant::now();
        let runs = composite::merge_views_with(&views, pixels, k, ert, |_, s: &[Seg], acc: &mut usize| *acc += s.len())
            .unwrap();
        segs = runs.iter().sum::<usize>();
        merge_ms.push(ms(t));
        let t = Instant::now();
        let a = geo.assembler(&req, layers);
        let runs =
            composite::merge_views_with(&views, pixels, k, ert, |i, s, out: &mut PartBuilder| a.push(i as u32, s, out))
                .unwrap();
        let runs: Vec<FramePart> = runs.into_iter().map(|b| a.finish(b)).collect();
        samples = FramePart::join(&runs).samples.len();
        asm_ms.push(ms(t));
    }
    // The band's merged lists, collected once: (pixel, first segment, count).
    let mut flat: Vec<Seg> = Vec::new();
    let lists: Vec<(u32, usize, usize)> =
        composite::merge_views_with(&views, pixels, k, ert, |i, s: &[Seg], acc: &mut Vec<(u32, Vec<Seg>)>| {
            if !s.is_empty() {
                acc.push((i as u32, s.to_vec()));
            }
        })
        .unwrap()
        .into_iter()
        .flatten()
        .map(|(i, s)| {
            flat.extend_from_slice(&s);
            (i, flat.len() - s.len(), s.len())
        })
        .collect();
    let (mut one_ms, mut lanes_ms, mut pack_ms, mut pack8_ms) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for _ in 0..n {
        let t = Instant::now();
        let mut one_at_a_time = vec![0u32; flat.len()];
        for &(_, at, len) in &lists {
            let s = &flat[at..at + len];
            let mut list = [Segment::default(); MAX_LAYERS];
            for (l, s) in list.iter_mut().zip(s) {
                *l = Segment { t: s.t, color: s.c };
            }
            pack_colors(&list[..len.min(MAX_LAYERS)], composite(s.iter().map(|s| s.c)), &mut one_at_a_time[at..]);
        }
        one_ms.push(ms(t));
        let t = Instant::now();
        let mut in_lanes = vec![0u32; flat.len()];
        let mut batch = PackLanes::new();
        for &(_, at, len) in &lists {
            let s = &flat[at..at + len];
            batch.push(s.iter().map(|s| s.c), composite(s.iter().map(|s| s.c)), at, &mut in_lanes);
        }
        batch.flush(&mut in_lanes);
        lanes_ms.push(ms(t));
        assert_eq!(one_at_a_time, in_lanes, "the colors packed in lanes");
        // Positions: each sample's point and radius, then quantized.
        let point = |i: u32, s: &Seg| {
            let d = basis.dir(i % size, i / size);
            (o + d * s.t, radius.at(d, s.t))
        };
        let t = Instant::now();
        let mut one_at_a_time = Vec::with_capacity(flat.len());
        for &(i, at, len) in &lists {
            for s in &flat[at..at + len] {
                let (p, r) = point(i, s);
                one_at_a_time.push(q.pack(p, r));
            }
        }
        pack_ms.push(ms(t));
        let t = Instant::now();
        let mut eight = Vec::with_capacity(flat.len() + 8);
        let (mut p8, mut r8, mut queued) = ([[0f32; 8]; 3], [0f32; 8], 0);
        for &(i, at, len) in &lists {
            for s in &flat[at..at + len] {
                let (p, r) = point(i, s);
                for (a, v) in p.to_array().into_iter().enumerate() {
                    p8[a][queued] = v;
                }
                r8[queued] = r;
                queued += 1;
                if queued == 8 {
                    eight.extend_from_slice(&q.pack8(&p8, &r8));
                    queued = 0;
                }
            }
        }
        eight.extend_from_slice(&q.pack8(&p8, &r8)[..queued]);
        pack8_ms.push(ms(t));
        assert_eq!(one_at_a_time, eight, "the positions quantized eight at a time");
    }
    println!(
        "{size}², {parts} parts, band 0 ({pixels} pixels, {} with segments, {segs} merged segments, {samples} \
         samples): {:.1} % of the seen pixels seen by one part alone; merge {:.1} ms, merge + assembly {:.1} ms; \
         colors: pack_colors {:.1} ms, PackLanes {:.1} ms; positions: pack {:.1} ms, pack8 {:.1} ms (medians of {n})",
        lists.len(),
        100.0 * one as f64 / any.max(1) as f64,
        median(merge_ms),
        median(asm_ms),
        median(one_ms),
        median(lanes_ms),
        median(pack_ms),
        median(pack8_ms),
    );
}
