//! `cargo run --release -p volwarp-server --example composite_timing -- [N] [SIZE] [PARTS]`:
//! the MRI benchmark view split into PARTS parts (in one process), each marched once; then the
//! first band of rows (what rank 0 owns) merged N times: alone, with the positions of its frame
//! samples (direction, radius, quantized position: the position step of `Assembler::push`,
//! written out here to time it apart; the one-process marcher runs the same scalar code per
//! segment), and with the whole assembly (`FrameGeometry::assembler`: those and the colors
//! packed by core's `pack_colors`); the median wall ms of each is printed, with the share of the
//! band's non-empty pixels that one part alone saw. `RAYON_NUM_THREADS=1` times one core.

use std::sync::Arc;
use std::time::Instant;
use volwarp_core::sample::Quantizer;
use volwarp_core::wire::CameraRequest;
use volwarp_core::Heuristic;
use volwarp_server::distributed::composite::{self, BandView};
use volwarp_server::distributed::decomposition::{part_of, Decomposition};
use volwarp_server::distributed::partial::{PartMarcher, Seg};
use volwarp_server::distributed::{FrameGeometry, FramePart};
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
    let mut merge_ms = Vec::new();
    let mut pos_ms = Vec::new();
    let mut asm_ms = Vec::new();
    let mut segs = 0;
    let mut samples = 0;
    for _ in 0..n {
        let t = Instant::now();
        let runs = composite::merge_views_with(&views, pixels, k, ert, |_, s: &[Seg], acc: &mut usize| *acc += s.len())
            .unwrap();
        segs = runs.iter().sum::<usize>();
        merge_ms.push(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        let runs = composite::merge_views_with(&views, pixels, k, ert, |i, s: &[Seg], out: &mut Vec<u64>| {
            let d = basis.dir(i as u32 % size, i as u32 / size);
            out.extend(s.iter().map(|s| q.pack(o + d * s.t, radius.at(d, s.t))));
        })
        .unwrap();
        std::hint::black_box(runs);
        pos_ms.push(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        let a = geo.assembler(&req, layers);
        let runs =
            composite::merge_views_with(&views, pixels, k, ert, |i, s, out: &mut FramePart| a.push(i as u32, s, out))
                .unwrap();
        let bytes = FramePart::join_to_bytes(&runs);
        samples = FramePart::check(&bytes, true).expect("the assembled band's bytes");
        asm_ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    println!(
        "{size}², {parts} parts, band 0 ({pixels} pixels, {segs} merged segments, {samples} samples): \
         {:.1} % of the seen pixels seen by one part alone; merge {:.1} ms, merge + positions {:.1} ms, \
         merge + assembly {:.1} ms (medians of {n})",
        100.0 * one as f64 / any.max(1) as f64,
        median(merge_ms),
        median(pos_ms),
        median(asm_ms)
    );
}
