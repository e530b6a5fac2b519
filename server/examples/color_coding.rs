//! What coding the color residuals against green's (`ColorCoding::AgainstGreen`, sent to
//! clients that announce `CAP_COLOR_GREEN`) saves: for every dataset of `../shared/data`
//! (preset transfer function, threshold heuristic, the default camera turned 20°/10°), the
//! server's message bytes of the one-sample frame and the K = 4 layered frame, plain and against
//! green, with the median encode time of each (one thread's wall ms over `RUNS`):
//!
//! ```sh
//! cargo run --release -p volwarp-server --example color_coding -- [SIZE ...] [--runs N]   # default 512 1024, 7 runs
//! ```

use std::time::Instant;
use volwarp_core::compact_frame::Encoding;
use volwarp_core::wire::CameraRequest;
use volwarp_core::Heuristic;
use volwarp_server::encoding::encode_frame_for;
use volwarp_server::{Dataset, Marcher};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let runs = args.iter().position(|a| a == "--runs").and_then(|i| args.get(i + 1)).and_then(|s| s.parse().ok());
    let runs: usize = runs.unwrap_or(7).max(1);
    let mut sizes: Vec<u32> = args.iter().filter_map(|a| a.parse().ok()).filter(|&s| s >= 16).collect();
    if sizes.is_empty() {
        sizes = vec![512, 1024];
    }
    let dir = std::path::Path::new(volwarp_server::testdata::SHARED_DATA);
    let mut names: Vec<_> = std::fs::read_dir(dir)
        .map(|d| {
            d.filter_map(|e| e.ok()).map(|e| e.path()).filter(|p| p.extension().is_some_and(|x| x == "raw")).collect()
        })
        .unwrap_or_default();
    names.sort();
    if names.is_empty() {
        eprintln!("color_coding: no volumes in {}", dir.display());
        return;
    }
    println!("| dataset | size | K | samples | plain bytes | against green | saved | encode ms plain / green |");
    println!("|---|---|---|---|---|---|---|---|");
    for path in &names {
        let Ok(ds) = Dataset::load(path, None) else { continue };
        let m = Marcher::from_dataset(&ds);
        let name =
            path.file_stem().and_then(|s| s.to_str()).unwrap_or("?").split('_').take(2).collect::<Vec<_>>().join("_");
        for &size in &sizes {
            let camera = m.default_camera(size, size).orbit(20.0, 10.0);
            let req = CameraRequest { seq: 1, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
            for k in [1u32, 4] {
                let frame = if k > 1 { m.render_frame_layers(&req, k).0 } else { m.render_frame(&req).0 };
                let mut bytes = [0usize; 2];
                let mut ms = [0f64; 2];
                for (i, green) in [false, true].into_iter().enumerate() {
                    let mut t = Vec::new();
                    for _ in 0..runs {
                        let t0 = Instant::now();
                        let (b, enc) = encode_frame_for(&m, &req, &frame, Encoding::Compact, green);
                        t.push(t0.elapsed().as_secs_f64() * 1e3);
                        assert_eq!(enc, Encoding::Compact);
                        bytes[i] = b.len();
                    }
                    ms[i] = median(t);
                }
                println!(
                    "| {name} | {size}² | {k} | {} | {} | {} | {:.1} % | {:.2} / {:.2} |",
                    frame.samples.len(),
                    bytes[0],
                    bytes[1],
                    100.0 * (1.0 - bytes[1] as f64 / bytes[0] as f64),
                    ms[0],
                    ms[1]
                );
            }
        }
    }
}
