//! The single-warp measurement of layered samples: for every dataset of a folder, the
//! C0 frame (default framing, 512², heuristic `threshold`) is rendered with one sample per pixel
//! and with K segments per pixel (`--layers 2,4,8`), warped along the orbit to 0–30° and scored
//! (PSNR, ꟻLIP, SSIM) against the marcher's truth:
//!
//! * `stale`, `points1`, `points2`, `points3`, `splat` on the one-sample frame (as today),
//! * `splat-layers K=k` on each layered frame (`K=1`: the one-sample frame composited with its
//!   opacities),
//!
//! then prints samples and bytes per frame (raw12 and compact, the server's C zstd), and with
//! `--time` the server's march time per frame (all cores) and the client draw time at 512² on
//! one thread of `splat` on the one-sample frame and `splat-layers` on each layered one (medians
//! of `--runs`, default 9), at 10°.
//!
//! ```sh
//! cargo run --release -p volwarp-eval --example layers -- ../shared/data --layers 2,4,8 --time
//! ```
//!
//! Footprint options of the layered renderer: `--own`, `--no-fill`, `--no-cracks`, `--grow`, `--grow-alpha`,
//! `--max-own`, `--watertight T` (0: off), `--water-ratio R`, `--opacity-limit F`; `--png DIR` writes each layered
//! image, the truth and the ꟻLIP map; `--angles A,B,…` warps to other angles, `--only NAME`
//! takes the datasets whose name contains NAME.

use std::path::Path;
use std::time::Instant;
use volwarp_core::compact_frame::Encoding;
use volwarp_core::renderer::Renderer;
use volwarp_core::wire::{CameraRequest, Frame};
use volwarp_core::{Heuristic, Image, RendererKind, Scene};
use volwarp_cpu_tracer::{build_scene, create};
use volwarp_eval::camera_paths::orbit;
use volwarp_eval::example_args::{arg, datasets_or_exit, layer_options};
use volwarp_eval::{median, Metrics};
use volwarp_server::Marcher;

/// The default warps, degrees along the orbit (`--angles A,B,…` sets others).
const ANGLES: [f32; 6] = [0.0, 2.5, 5.0, 10.0, 20.0, 30.0];

fn bytes(m: &Marcher, req: &CameraRequest, f: &Frame) -> (usize, usize) {
    let raw = volwarp_server::encoding::encode_frame(m, req, f, Encoding::Raw12).0.len();
    let (b, got) = volwarp_server::encoding::encode_frame(m, req, f, Encoding::Compact);
    assert_eq!(got, Encoding::Compact, "the compact form holds the frame");
    (raw, b.len())
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let layers: Vec<u32> =
        arg(&args, "--layers").unwrap_or("2,4,8").split(',').map(|s| s.parse().expect("a layer count")).collect();
    let runs: usize = arg(&args, "--runs").map_or(9, |s| s.parse().expect("a run count"));
    let size: u32 = arg(&args, "--size").map_or(512, |s| s.parse().expect("a size"));
    let time = args.iter().any(|a| a == "--time");
    let lopts = layer_options(&args).expect("footprint options");
    let adapt = lopts.grow_per_degree > 0.0;
    let angles: Vec<f32> = arg(&args, "--angles")
        .map_or(ANGLES.to_vec(), |v| v.split(',').map(|a| a.parse().expect("an angle in degrees")).collect());
    let datasets = datasets_or_exit(&args);
    let h = Heuristic::Threshold;
    let base =
        [RendererKind::Stale, RendererKind::Points1, RendererKind::Points2, RendererKind::Points3, RendererKind::Splat];
    let mut names: Vec<String> = base.iter().map(|k| k.name().to_string()).collect();
    names.push("splat-layers K=1".into());
    names.extend(layers.iter().map(|k| format!("splat-layers K={k}")));
    println!("dataset,method,angle,psnr,flip,ssim");
    let mut sums = vec![vec![(0.0f64, 0.0f64); angles.len()]; names.len()];
    let mut budget = Vec::new();
    let mut times = Vec::new();
    for ds in &datasets {
        let m = Marcher::from_dataset(ds);
        let c0 = m.default_camera(size, size);
        let req = CameraRequest { seq: 1, camera: c0, heuristic: h, radius_scale: 1.0, layers: 0 };
        let one = m.render_frame(&req).0;
        let mut frames = vec![(1u32, one.clone())];
        frames.extend(layers.iter().map(|&k| (k, m.render_frame_layers(&req, k).0)));
        for (k, f) in &frames {
            let (raw, compact) = bytes(&m, &req, f);
            // The server's march and compaction (all cores), median of `runs`, with `--time`.
            let march = if time {
                let mut ms: Vec<f64> = (0..runs)
                    .map(|_| {
                        let t = Instant::now();
                        std::hint::black_box(m.render_frame_layers(&req, *k));
                        t.elapsed().as_secs_f64() * 1e3
                    })
                    .collect();
                format!(" {:.1} |", median(&mut ms).unwrap_or(0.0))
            } else {
                String::new()
            };
            budget.push(format!(
                "| {} | {k} | {} | {:.2} | {raw} | {compact} | {:.2} |{march}",
                ds.name,
                f.samples.len(),
                f.samples.len() as f64 / one.samples.len().max(1) as f64,
                compact as f64 / f.samples.len().max(1) as f64
            ));
        }
        let scene_one = build_scene(&one);
        let scenes: Vec<Scene> = frames.iter().map(|(_, f)| volwarp_cpu_tracer::route::unbuilt_scene(f)).collect();
        let mut plain: Vec<Box<dyn Renderer + Send>> = base.iter().map(|&k| create(k, 0).unwrap()).collect();
        let mut layered = volwarp_cpu_tracer::LayerSplat::with_options(0, lopts);
        layered.set_adaptive_radius(adapt);
        for (ai, &a) in angles.iter().enumerate() {
            let cam = orbit(&c0, a);
            let truth = m.render_image(&cam);
            let mut img = Image::new(0, 0);
            let mut scores = Vec::new();
            for r in plain.iter_mut() {
                r.render(&scene_one, &cam, &mut img);
                scores.push(Metrics::of(&truth, &img).map_or((0.0, 1.0, 0.0), |m| (m.psnr, m.flip, m.ssim)));
            }
            for (s, (k, _)) in scenes.iter().zip(&frames) {
                layered.render(s, &cam, &mut img);
                scores.push(Metrics::of(&truth, &img).map_or((0.0, 1.0, 0.0), |m| (m.psnr, m.flip, m.ssim)));
                // `--png DIR`: the layered image and the truth, for looking at.
                if let Some(dir) = arg(&args, "--png") {
                    let _ = std::fs::create_dir_all(dir);
                    let _ = img.save_png(&Path::new(dir).join(format!("{}_k{k}_{a}.png", ds.name)));
                    let _ = truth.save_png(&Path::new(dir).join(format!("{}_truth_{a}.png", ds.name)));
                    if let Some(map) =
                        volwarp_eval::metrics::flip::flip_map(&truth, &img, volwarp_eval::metrics::flip::DEFAULT_PPD)
                    {
                        let mut fm = Image::new(img.width, img.height);
                        for (p, &v) in fm.pixels.iter_mut().zip(&map) {
                            let g = (v.clamp(0.0, 1.0) * 255.0) as u32;
                            *p = 0xff00_0000 | g << 16 | g << 8 | g;
                        }
                        let _ = fm.save_png(&Path::new(dir).join(format!("{}_k{k}_{a}_flip.png", ds.name)));
                    }
                }
            }
            for (i, (p, f, ss)) in scores.iter().enumerate() {
                println!("{},{},{a},{p:.2},{f:.4},{ss:.4}", ds.name, names[i]);
                sums[i][ai].0 += p / datasets.len() as f64;
                sums[i][ai].1 += f / datasets.len() as f64;
            }
        }
        if time {
            let cam = orbit(&c0, 10.0);
            let t = |r: &mut dyn Renderer, s: &Scene| {
                let mut img = Image::new(0, 0);
                r.render(s, &cam, &mut img);
                let mut ms: Vec<f64> = (0..runs)
                    .map(|_| {
                        let t = Instant::now();
                        r.render(s, &cam, &mut img);
                        t.elapsed().as_secs_f64() * 1e3
                    })
                    .collect();
                median(&mut ms).unwrap_or(0.0)
            };
            let mut splat = create(RendererKind::Splat, 1).unwrap();
            let mut lay = volwarp_cpu_tracer::LayerSplat::with_options(1, lopts);
            lay.set_adaptive_radius(adapt);
            let base_ms = t(splat.as_mut(), &scene_one);
            let mut row = format!("| {} | {base_ms:.1} |", ds.name);
            for s in &scenes {
                let ms = t(&mut lay, s);
                row += &format!(" {ms:.1} ({:.2}×) |", ms / base_ms);
            }
            times.push(row);
        }
    }
    println!("\nmean over {} datasets, PSNR dB / ꟻLIP", datasets.len());
    println!("| method | {} |", angles.iter().map(|a| format!("{a}°")).collect::<Vec<_>>().join(" | "));
    println!("|---|{}", "---|".repeat(angles.len()));
    for (i, n) in names.iter().enumerate() {
        println!(
            "| {n} | {} |",
            sums[i].iter().map(|(p, f)| format!("{p:.1} / {f:.4}")).collect::<Vec<_>>().join(" | ")
        );
    }
    let march = if time { " server march ms |" } else { "" };
    println!("\n| dataset | K | samples | × K=1 | raw12 bytes | compact bytes | compact B/sample |{march}");
    println!("|---|---|---|---|---|---|---|{}", if time { "---|" } else { "" });
    for r in &budget {
        println!("{r}");
    }
    if time {
        let ks: Vec<String> =
            std::iter::once(1).chain(layers.iter().copied()).map(|k| format!("splat-layers K={k} ms")).collect();
        println!("\n| dataset | splat ms | {} |", ks.join(" | "));
        println!("|---|---|{}", "---|".repeat(ks.len()));
        for r in &times {
            println!("{r}");
        }
    }
}
