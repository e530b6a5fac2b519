//! `volwarp-compare FILE [--renderer spheres-gpu|splat-gpu|splat-layers-gpu] [--out DIR]
//! [--width W --height H] [--adapter NAME] [--keep-frames K] [--adapt BOOL]`: replays a record
//! file through a GPU renderer and its CPU twin (the packet tracer, the exact splatter, the
//! layered splatter with the older frames kept, as the client draws them) and reports, per
//! frame and camera, the share of identical pixels, the largest channel difference and each
//! side's time; writes `CPU | GPU | difference` PNGs.
//!
//! Exit status: 0 when every image reaches 99.9 % identical pixels (the layered splatter:
//! 99.9 % within one 8-bit step, the tests' target), 3 when one does not, 1 on errors
//! (unreadable file, no GPU).
#![forbid(unsafe_code)]

use clap::Parser;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;
use volwarp_core::image_diff::{channel_diff, TARGET_IDENTICAL};
use volwarp_core::record::{read_entry, read_magic, Entry};
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::wire::{Frame, Limits};
use volwarp_core::{Camera, RendererKind, Scene};
use volwarp_cpu_tracer::layer_splat::LayerOptions;
use volwarp_cpu_tracer::route::unbuilt_scene;
use volwarp_cpu_tracer::{LayerSplat, PacketTracer, SphereSplat};
use volwarp_eval::metrics::diff::save_comparison;
use volwarp_gpu_tracer::{GpuError, GpuLayerSplat, GpuSplat, GpuTracer};

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
    /// The GPU renderer compared with its CPU twin: `spheres-gpu` (the packet tracer),
    /// `splat-gpu` (the exact splatter) or `splat-layers-gpu` (the layered splatter, the
    /// client's default, with the older frames kept).
    #[arg(long, default_value = "spheres-gpu", value_parser = parse_gpu_kind)]
    renderer: RendererKind,
    /// `splat-layers-gpu`: the frames kept for multi-frame filling (the newest and up to K − 1
    /// older ones, as the client's `--keep-frames`).
    #[arg(long, value_name = "K", default_value_t = 4)]
    keep_frames: usize,
    /// The splatters: warp-sized footprints, as the client's `--adapt` (default on).
    #[arg(long, value_name = "BOOL", default_value_t = true, action = clap::ArgAction::Set)]
    adapt: bool,
}

fn parse_gpu_kind(s: &str) -> Result<RendererKind, String> {
    match RendererKind::from_name(s) {
        Some(k @ (RendererKind::SpheresGpu | RendererKind::SplatGpu | RendererKind::SplatLayersGpu)) => Ok(k),
        _ => Err(format!("{s:?}: one of spheres-gpu, splat-gpu, splat-layers-gpu")),
    }
}

/// A GPU renderer and its CPU twin.
enum Pair {
    Spheres(Box<(PacketTracer, GpuTracer)>),
    Splat(Box<(SphereSplat, GpuSplat)>),
    Layers(Box<(LayerSplat, GpuLayerSplat)>),
}

impl Pair {
    fn open(args: &Args) -> Result<Pair, GpuError> {
        let a = args.adapter.as_deref();
        Ok(match args.renderer {
            RendererKind::SplatGpu => Pair::Splat(Box::new((SphereSplat::new(0), GpuSplat::with_adapter(a)?))),
            RendererKind::SplatLayersGpu => {
                let mut cpu = LayerSplat::with_options(0, LayerOptions::DEFAULT);
                let ctx = volwarp_gpu_tracer::GpuContext::with_adapter(a)?;
                let mut gpu = GpuLayerSplat::with_context(ctx, LayerOptions::DEFAULT)?;
                cpu.set_adaptive_radius(args.adapt);
                gpu.set_adaptive_radius(args.adapt);
                Pair::Layers(Box::new((cpu, gpu)))
            }
            _ => Pair::Spheres(Box::new((PacketTracer::new(0), GpuTracer::with_adapter(a)?))),
        })
    }

    fn names(&self) -> (&'static str, &'static str) {
        match self {
            Pair::Spheres(p) => (p.0.name(), p.1.name()),
            Pair::Splat(p) => (p.0.name(), p.1.name()),
            Pair::Layers(p) => (p.0.name(), p.1.name()),
        }
    }

    fn adapter(&self) -> String {
        match self {
            Pair::Spheres(p) => p.1.context().describe_driver(),
            Pair::Splat(p) => p.1.context().describe_driver(),
            Pair::Layers(p) => p.1.context().describe_driver(),
        }
    }

    /// The GPU tracer, whose own LBVH build each frame's tree comes from (the splatters draw
    /// unbuilt or CPU-built scenes).
    fn gpu_tracer(&mut self) -> Option<&mut GpuTracer> {
        match self {
            Pair::Spheres(p) => Some(&mut p.1),
            _ => None,
        }
    }

    /// The CPU draw of `scenes` (newest first) for `cam`.
    fn cpu(&mut self, scenes: &[&Scene], cam: &Camera, out: &mut Image) {
        match self {
            Pair::Spheres(p) => p.0.render(scenes[0], cam, out),
            Pair::Splat(p) => p.0.render(scenes[0], cam, out),
            Pair::Layers(p) => p.0.render_set(scenes, cam, out),
        }
    }

    /// The GPU draw (the tracer's on `gpu_scene`, its own tree where it built one).
    fn gpu(&mut self, scenes: &[&Scene], gpu_scene: &Scene, cam: &Camera, out: &mut Image) -> Result<(), GpuError> {
        match self {
            Pair::Spheres(p) => p.1.try_render(gpu_scene, cam, out),
            Pair::Splat(p) => p.1.try_render(scenes[0], cam, out),
            Pair::Layers(p) => p.1.try_render_set(scenes, cam, out),
        }
    }
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
    let mut pair = Pair::open(args).map_err(|e| e.to_string())?;
    let layers = matches!(pair, Pair::Layers(_));
    println!("adapter: {}", pair.adapter());
    let (cpu_name, gpu_name) = pair.names();
    println!("CPU {cpu_name} against GPU {gpu_name}");
    if layers {
        println!("frames kept: {}; warp-sized footprints: {}", args.keep_frames.max(1), args.adapt);
    }
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    }
    println!(
        "frame camera   samples   size       identical   max diff   cpu ms   gpu ms   cpu build ms   gpu build ms"
    );
    let mut all_ok = true;
    let mut worst = 1.0f64;
    let (mut cpu_img, mut gpu_img) = (Image::new(1, 1), Image::new(1, 1));
    // The layered splatters draw the frames as the client does: unbuilt, the newest first
    // with the older ones kept.
    let unbuilt: Vec<Scene> = if layers { jobs.iter().map(|j| unbuilt_scene(&j.frame)).collect() } else { Vec::new() };
    for (fi, job) in jobs.iter().enumerate() {
        let t = Instant::now();
        let scene = if layers { unbuilt[fi].clone() } else { Scene::build(&job.frame) };
        let cpu_build_ms = if layers { f64::NAN } else { t.elapsed().as_secs_f64() * 1e3 };
        let (gpu_scene, gpu_build_ms) = match pair.gpu_tracer() {
            Some(gpu) if !args.cpu_build => match gpu.build_scene(&job.frame) {
                Ok(s) => (Some(s), gpu.last_build_timing().build.as_secs_f64() * 1e3),
                Err(e) => {
                    log::warn!("frame {fi}: GPU build failed ({e}); using the CPU-built tree");
                    (None, f64::NAN)
                }
            },
            _ => (None, f64::NAN),
        };
        let scenes: Vec<&Scene> =
            if layers { unbuilt[..=fi].iter().rev().take(args.keep_frames.max(1)).collect() } else { vec![&scene] };
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
            pair.cpu(&scenes, cam, &mut cpu_img);
            let cpu_ms = t.elapsed().as_secs_f64() * 1e3;
            let t = Instant::now();
            pair.gpu(&scenes, gscene, cam, &mut gpu_img).map_err(|e| format!("frame {fi}: {e}"))?;
            let gpu_ms = t.elapsed().as_secs_f64() * 1e3;
            let d = cpu_img.diff(&gpu_img).ok_or("image sizes differ")?;
            let within_one =
                cpu_img.pixels.iter().zip(&gpu_img.pixels).filter(|(&a, &b)| channel_diff(a, b) <= 1).count() as f64
                    / cpu_img.pixels.len().max(1) as f64;
            let ok = if layers { within_one >= TARGET_IDENTICAL } else { d.meets_target() };
            all_ok &= ok;
            worst = worst.min(if layers { within_one } else { d.identical_share() });
            println!(
                "{fi:5} {ci:6} {:9}   {:>4}x{:<4}  {:8.4} %  {:8}   {cpu_ms:6.1}   {gpu_ms:6.1}   {cpu_build_ms:12.1}   {gpu_build_ms:12.1}{}{}",
                job.frame.samples.len(),
                cam.width,
                cam.height,
                100.0 * d.identical_share(),
                d.max_channel_diff,
                if layers { format!("   {:.4} % within one step, {} frames", 100.0 * within_one, scenes.len()) } else { String::new() },
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
        "worst {} share {:.4} % (target {:.1} %): {}",
        if layers { "within-one-step" } else { "identical" },
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
