//! Bytes per sample of a frame in every encoding, and what the compact form costs in image
//! quality (the table in `docs/perf.md`):
//!
//! ```sh
//! cargo run --release -p volwarp-server --example bandwidth -- [SIZE ...]   # default 512 1024
//! ```
//!
//! For every dataset of `../shared/data` (preset transfer function, threshold heuristic, the
//! default camera) and every size: the sample count, then bytes per sample of the 12-byte
//! Frame, the compact form (the server's: the byte-run parse with C zstd's entropy stage; the
//! same planes through the C library's own level-1 parse; ruzstd's encoder, core's default),
//! general-purpose zstd (level 3) of the whole 12-byte message, and what an image-based
//! system would send: a PNG of the RGBA8 color image plus a 16-bit depth PNG (depth over the
//! frame's depth range, 0 where empty). Then the PSNR against the marcher's ground truth of
//! the frame traced (core's LBVH traversal, the reference every tracer matches) from the
//! 12-byte and from the decoded compact form at the frame's camera (0°) and 10° around.

use rayon::prelude::*;
use std::time::Instant;
use volwarp_core::compact_frame;
use volwarp_core::sample::over_background;
use volwarp_core::wire::{self, CameraRequest, Frame, Limits, Message, HEADER_LEN};
use volwarp_core::{Camera, Heuristic, Image, Scene, BACKGROUND};
use volwarp_server::encoding::{encode_compact, encode_options};
use volwarp_server::{Dataset, Marcher};

const DATA: &str = volwarp_server::testdata::SHARED_DATA;

/// What every renderer draws: the first hit sphere's color over the background.
fn trace(frame: &Frame, cam: &Camera) -> Image {
    let scene = Scene::build(frame);
    let lbvh = scene.lbvh();
    let basis = cam.ray_basis();
    let w = cam.width as usize;
    let mut img = Image::new(cam.width, cam.height);
    img.pixels.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, p) in row.iter_mut().enumerate() {
            *p = match lbvh.trace(&basis.ray(x as u32, y as u32)) {
                Some(h) => over_background(scene.colors[h.prim as usize], BACKGROUND),
                None => BACKGROUND,
            };
        }
    });
    img
}

fn psnr(a: &Image, b: &Image) -> f64 {
    let mut sum = 0u64;
    for (&p, &q) in a.pixels.iter().zip(&b.pixels) {
        let (p, q) = (p.to_le_bytes(), q.to_le_bytes());
        for c in 0..3 {
            let d = p[c] as i64 - q[c] as i64;
            sum += (d * d) as u64;
        }
    }
    let mse = sum as f64 / (a.pixels.len() * 3) as f64;
    if mse == 0.0 {
        100.0
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    }
}

fn png(bytes: &[u8], w: u32, h: u32, ty: image::ExtendedColorType) -> usize {
    let mut out = Vec::new();
    let enc = image::codecs::png::PngEncoder::new(&mut out);
    image::ImageEncoder::write_image(enc, bytes, w, h, ty).expect("png");
    out.len()
}

fn main() {
    let sizes: Vec<u32> = std::env::args().skip(1).filter_map(|s| s.parse().ok()).collect();
    let sizes = if sizes.is_empty() { vec![512, 1024] } else { sizes };
    let mut files: Vec<_> = std::fs::read_dir(DATA)
        .expect("../shared/data")
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "raw"))
        .collect();
    files.sort();
    println!(
        "| dataset | size | samples | raw12 | compact (server) | compact (zstd-1 parse) | compact (ruzstd enc.) | zstd-3 of raw12 | PNG color + 16-bit depth | encode ms | decode ms | PSNR 0° raw12 / compact (Δ) | PSNR 10° raw12 / compact (Δ) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for f in &files {
        let ds = Dataset::load(f, None).expect("dataset");
        let m = Marcher::from_dataset(&ds);
        let name = f.file_stem().unwrap().to_string_lossy().split('_').take(2).collect::<Vec<_>>().join("_");
        for &size in &sizes {
            let camera = m.default_camera(size, size);
            let req = CameraRequest { seq: 0, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
            let (frame, _) = m.render_frame(&req);
            let n = frame.samples.len().max(1) as f64;
            let raw = wire::encode_to_vec(&Message::Frame(frame.clone()));
            let opts = encode_options(&m, &req);
            let t = Instant::now();
            let compact = encode_compact(&frame, &opts, 1).expect("compact");
            let enc_ms = t.elapsed().as_secs_f64() * 1e3;
            let ruz = compact_frame::encode(&frame, &opts).expect("compact");
            // The same planes through the C library's own level-1 parse.
            let planes = compact_frame::build_planes(&frame, &opts).expect("planes");
            let lib1 =
                HEADER_LEN + compact_frame::COMPACT_FIXED_LEN + zstd::bulk::compress(&planes.body, 1).unwrap().len();
            let zraw = zstd::bulk::compress(&raw, 3).unwrap();
            // The image-based anchor: the color image and a 16-bit depth image.
            let pb = m.march(&camera, Heuristic::Threshold);
            let rgba: Vec<u8> = pb.color.iter().flat_map(|c| c.to_le_bytes()).collect();
            let (lo, hi) =
                pb.t.iter().filter(|t| t.is_finite()).fold((f32::MAX, f32::MIN), |(a, b), &t| (a.min(t), b.max(t)));
            let depth: Vec<u8> =
                pb.t.iter()
                    .flat_map(|&t| {
                        let d = if t.is_finite() { 1 + ((t - lo) / (hi - lo).max(1e-9) * 65534.0) as u16 } else { 0 };
                        d.to_be_bytes()
                    })
                    .collect();
            let img_bytes = png(&rgba, size, size, image::ExtendedColorType::Rgba8)
                + png(&depth, size, size, image::ExtendedColorType::L16);
            let t = Instant::now();
            let back = compact_frame::decode_payload(&compact[HEADER_LEN..], &Limits::default()).expect("decode");
            let dec_ms = t.elapsed().as_secs_f64() * 1e3;
            let mut cells = Vec::new();
            for angle in [0.0f32, 10.0] {
                let cam = camera.orbit(angle, 0.0);
                let truth = m.render_image(&cam);
                let (a, b) = (psnr(&truth, &trace(&frame, &cam)), psnr(&truth, &trace(&back, &cam)));
                cells.push(format!("{a:.2} / {b:.2} ({:+.3})", b - a));
            }
            println!(
                "| {name} | {size}² | {} | {:.2} | **{:.3}** | {:.3} | {:.3} | {:.3} | {:.3} | {enc_ms:.1} | {dec_ms:.1} | {} | {} |",
                frame.samples.len(),
                raw.len() as f64 / n,
                compact.len() as f64 / n,
                lib1 as f64 / n,
                ruz.len() as f64 / n,
                zraw.len() as f64 / n,
                img_bytes as f64 / n,
                cells[0],
                cells[1]
            );
        }
    }
}
