//! `volwarp-compare FILE [--out DIR] [--width W --height H] [--adapter NAME]`: replays a record file through the
//! CPU and the GPU tracer and reports, per frame and camera, the share of identical pixels, the
//! largest channel difference and each tracer's time; writes `CPU | GPU | difference` PNGs.
//!
//! Exit status: 0 when every image reaches 99.9 % identical pixels, 3 when one does not, 1 on
//! errors (unreadable file, no GPU).

use clap::Parser;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;
use volwarp_core::image_diff::TARGET_IDENTICAL;
use volwarp_core::record::{read_entry, read_magic, Entry};
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::wire::{Frame, Limits};
use volwarp_core::{Camera, Scene};
use volwarp_cpu_tracer::PacketTracer;
use volwarp_eval::metrics::diff::save_comparison;
use volwarp_gpu_tracer::GpuTracer;

/// Replays a recorded volwarp stream through the CPU and GPU tracers and compares the images.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    /// Record file (written by the client's --record).
    file: PathBuf,
    /// Directory for the side-by-side PNGs (CPU | GPU | difference); none written without it.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Render width (default: each camera's own).
    #[arg(long)]
    width: Option<u32>,
    /// Render height (default: each camera's own).
    #[arg(long)]
    height: Option<u32>,
    /// Most displayed cameras compared per frame (evenly spread over those recorded).
    #[arg(long, default_value_t = 3)]
    cameras_per_frame: usize,
    /// Build the GPU side's tree on the CPU too (default: the GPU builds it).
    #[arg(long)]
    cpu_build: bool,
    /// The GPU adapter whose name contains NAME (case-insensitive; default: the best there is).
    #[arg(long, value_name = "NAME")]
    adapter: Option<String>,
}

struct Job {
    frame: Frame,
    cameras: Vec<Camera>,
}

fn read_jobs(args: &Args) -> Result<Vec<Job>, String> {
    let file = std::fs::File::open(&args.file).map_err(|e| format!("{}: {e}", args.file.display()))?;
    let mut r = embedded_io_adapters::std::FromStd::new(std::io::BufReader::new(file));
    read_magic(&mut r).map_err(|e| format!("{}: {e}", args.file.display()))?;
    let limits = Limits::default();
    let mut jobs: Vec<Job> = Vec::new();
    loop {
        match read_entry(&mut r, &limits) {
            Ok(None) => break,
            Ok(Some(Entry::Frame { frame, .. })) => jobs.push(Job { frame, cameras: Vec::new() }),
            Ok(Some(Entry::Camera { request, .. })) => {
                if let Some(j) = jobs.last_mut() {
                    j.cameras.push(request.camera);
                }
            }
            Err(e) => {
                // A truncated tail (the client was killed mid-write) still leaves the frames before.
                log::warn!("{}: stopping at a bad entry: {e}", args.file.display());
                break;
            }
        }
    }
    Ok(jobs)
}

/// Up to `k` cameras evenly spread over `all`; the frame's own camera orbited 10° if none.
fn pick_cameras(frame: &Frame, all: &[Camera], k: usize, args: &Args) -> Vec<Camera> {
    let mut picked: Vec<Camera> = if all.is_empty() {
        vec![frame.header.camera.orbit(10.0, 0.0)]
    } else {
        let k = k.clamp(1, all.len());
        (0..k).map(|i| all[i * all.len() / k]).collect()
    };
    for c in &mut picked {
        *c = c.with_viewport(args.width.unwrap_or(c.width), args.height.unwrap_or(c.height));
    }
    picked
}

fn run(args: &Args) -> Result<bool, String> {
    let jobs = read_jobs(args)?;
    if jobs.is_empty() {
        return Err(format!("{}: no frames recorded", args.file.display()));
    }
    let mut gpu = GpuTracer::with_adapter(args.adapter.as_deref()).map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.context().describe_driver());
    let mut cpu = PacketTracer::new(0);
    println!("CPU tracer: {}", cpu.name());
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    }
    println!(
        "frame camera   samples   size       identical   max diff   cpu ms   gpu ms   cpu build ms   gpu build ms"
    );
    let mut all_ok = true;
    let mut worst = 1.0f64;
    let (mut cpu_img, mut gpu_img) = (Image::new(1, 1), Image::new(1, 1));
    for (fi, job) in jobs.iter().enumerate() {
        let t = Instant::now();
        let scene = Scene::build(&job.frame);
        let cpu_build_ms = t.elapsed().as_secs_f64() * 1e3;
        let (gpu_scene, gpu_build_ms) = if args.cpu_build {
            (None, f64::NAN)
        } else {
            match gpu.build_scene(&job.frame) {
                Ok(s) => (Some(s), gpu.last_build_timing().build.as_secs_f64() * 1e3),
                Err(e) => {
                    log::warn!("frame {fi}: GPU build failed ({e}); using the CPU-built tree");
                    (None, f64::NAN)
                }
            }
        };
        if let Some(s) = &gpu_scene {
            let mut seen = vec![0u8; 2 * s.samples.len()];
            if let Err(e) = s.lbvh().check(&mut seen) {
                println!("frame {fi}: GPU-built tree is INVALID: {e:?}");
                all_ok = false;
            }
        }
        let gscene = gpu_scene.as_ref().unwrap_or(&scene);
        for (ci, cam) in pick_cameras(&job.frame, &job.cameras, args.cameras_per_frame, args).iter().enumerate() {
            let t = Instant::now();
            cpu.render(&scene, cam, &mut cpu_img);
            let cpu_ms = t.elapsed().as_secs_f64() * 1e3;
            let t = Instant::now();
            gpu.try_render(gscene, cam, &mut gpu_img).map_err(|e| format!("frame {fi}: {e}"))?;
            let gpu_ms = t.elapsed().as_secs_f64() * 1e3;
            let d = cpu_img.diff(&gpu_img).ok_or("image sizes differ")?;
            let ok = d.meets_target();
            all_ok &= ok;
            worst = worst.min(d.identical_share());
            println!(
                "{fi:5} {ci:6} {:9}   {:>4}x{:<4}  {:8.4} %  {:8}   {cpu_ms:6.1}   {gpu_ms:6.1}   {cpu_build_ms:12.1}   {gpu_build_ms:12.1}{}",
                job.frame.samples.len(),
                cam.width,
                cam.height,
                100.0 * d.identical_share(),
                d.max_channel_diff,
                if ok { "" } else { "   BELOW TARGET" }
            );
            if let Some(dir) = &args.out {
                let path = dir.join(format!("frame{fi:04}_cam{ci:02}.png"));
                match save_comparison(&cpu_img, &gpu_img, &path) {
                    Some(Ok(())) => {}
                    Some(Err(e)) => return Err(format!("{}: {e}", path.display())),
                    None => return Err("image sizes differ".into()),
                }
            }
        }
    }
    println!(
        "worst identical share {:.4} % (target {:.1} %): {}",
        100.0 * worst,
        100.0 * TARGET_IDENTICAL,
        if all_ok { "ok" } else { "BELOW TARGET" }
    );
    Ok(all_ok)
}

fn main() -> ExitCode {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("info")).init();
    let args = Args::parse();
    match run(&args) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(3),
        Err(e) => {
            eprintln!("volwarp-compare: {e}");
            ExitCode::FAILURE
        }
    }
}
