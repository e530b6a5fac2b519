//! Timing of the sphere routes (tiled splatter, packet tracer, the earlier splatter, the
//! automatic choice) on the MRI benchmark frame, 10° off, over viewports, radius models and
//! zooms, with the quantities the route cost model uses:
//! `cargo run --release -p volwarp-cpu-tracer --example splat_timing [threads] [frame cache dir]`;
//! one renderer alone (for profiles and A/B runs):
//! `… splat_timing threads dir renderer [viewport] [footprint|voxel] [dolly]`, where the renderer
//! `splat-tiles-nocull` is the tiled splatter without occlusion culling.
//!
//! One thread: on-CPU time of the calling thread (robust on a busy machine); more threads:
//! wall time. Medians of 7. The marched frames are cached in the given folder (default: the
//! system's temporary folder) so repeated runs skip the march.

use std::time::Instant;
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::wire::{self, Frame, Limits, Message};
use volwarp_core::Scene;
use volwarp_cpu_tracer::{route, AutoSpheres, PacketTracer, SphereSplat, TileSplat};

#[path = "../benches/support/frames.rs"]
mod frames;

/// Nanoseconds this thread has run (Linux `/proc/thread-self/schedstat`), if available.
fn cpu_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat").ok()?.split_whitespace().next()?.parse().ok()
}

/// The MRI frame with radius model `model`, from the cache or marched (and cached).
fn frame(model: volwarp_server::RadiusModel, dir: &str) -> Option<Frame> {
    let path = format!("{dir}/volwarp-mri-1024-{model}.frame");
    if let Ok(bytes) = std::fs::read(&path) {
        if let Ok(Message::Frame(f)) = wire::read_message(&mut &bytes[..], &Limits::default()) {
            return Some(f);
        }
    }
    let f = frames::mri_frame_with(1024, model)?.0;
    let _ = std::fs::write(&path, wire::encode_to_vec(&Message::Frame(f.clone())));
    Some(f)
}

/// `splat-direct`: the splatter in the samples' order (`splat-direct-one`, `-two`: one or two
/// 4×2 windows for small rectangles instead of the per-frame choice), with feature
/// `direct-splat`.
#[cfg(feature = "direct-splat")]
mod direct {
    use super::*;
    use volwarp_cpu_tracer::DirectSplat;

    /// [`DirectSplat`] behind the `Renderer` interface for the timing loop (it is not in the
    /// registry; the kind reported is never read here).
    pub struct Direct(DirectSplat);

    impl Renderer for Direct {
        fn kind(&self) -> volwarp_core::RendererKind {
            volwarp_core::RendererKind::SplatTiles
        }
        fn render(&mut self, scene: &Scene, camera: &volwarp_core::Camera, out: &mut Image) {
            self.0.render(scene, camera, out)
        }
    }

    pub fn make(what: &str, threads: usize) -> Option<Direct> {
        what.starts_with("splat-direct").then(|| {
            Direct(match what {
                "splat-direct-one" => DirectSplat::new(threads).with_windows(false),
                "splat-direct-two" => DirectSplat::new(threads).with_windows(true),
                _ => DirectSplat::new(threads),
            })
        })
    }

    pub fn report(d: &Direct) {
        println!(
            "bands {:?}, spheres handed over {}, two windows {}",
            d.0.band_rows(),
            d.0.handed_over(),
            d.0.last_two_windows()
        );
    }
}

/// Without feature `direct-splat` there is no `splat-direct`.
#[cfg(not(feature = "direct-splat"))]
mod direct {
    use super::*;

    pub enum Direct {}

    impl Renderer for Direct {
        fn kind(&self) -> volwarp_core::RendererKind {
            match *self {}
        }
        fn render(&mut self, _: &Scene, _: &volwarp_core::Camera, _: &mut Image) {
            match *self {}
        }
    }

    pub fn make(what: &str, _threads: usize) -> Option<Direct> {
        if what.starts_with("splat-direct") {
            eprintln!("{what}: build with `--features direct-splat`");
            std::process::exit(2);
        }
        None
    }

    pub fn report(d: &Direct) {
        match *d {}
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let threads: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(1);
    let tmp = std::env::temp_dir();
    let dir = args.get(2).cloned().unwrap_or_else(|| tmp.to_string_lossy().into_owned());
    let mut img = Image::new(1, 1);
    let time = |r: &mut dyn Renderer, scene: &Scene, cam: &volwarp_core::Camera, img: &mut Image| {
        r.render(scene, cam, img);
        let mut v = Vec::new();
        for _ in 0..7 {
            let (c0, w0) = (cpu_ns(), Instant::now());
            r.render(scene, cam, img);
            let wall = w0.elapsed().as_secs_f64() * 1e3;
            v.push(match (threads, c0, cpu_ns()) {
                (1, Some(a), Some(b)) => (b - a) as f64 / 1e6,
                _ => wall,
            });
        }
        v.sort_by(f64::total_cmp);
        v[3]
    };
    if let Some(what) = args.get(3) {
        // Profiling: one renderer (`what`) at viewport `[4]` (default 1024²), radius model `[5]`
        // (`footprint` or `voxel`, default footprint), dolly `[6]` (default 1), 10° off, 30
        // times.
        let model = match args.get(5).map(String::as_str) {
            Some("voxel") => volwarp_server::RadiusModel::Voxel,
            _ => volwarp_server::RadiusModel::default(),
        };
        let dolly: f32 = args.get(6).and_then(|s| s.parse().ok()).unwrap_or(1.0);
        let f = frame(model, &dir).expect("the MRI frame");
        // `[7]` = `unbuilt`: the frame's samples in arrival order (the server's scanline order),
        // as a client draws them with `spheres`; default the built (Morton-ordered) scene.
        let scene = if args.get(7).map(String::as_str) == Some("unbuilt") {
            route::unbuilt_scene(&f)
        } else {
            Scene::build(&f)
        };
        let cam = f.header.camera.orbit(10.0, 0.0).dolly(dolly).with_viewport(1024, 1024);
        // `splat-tiles-nocull`: the tiled splatter without occlusion culling.
        let mut tiles = (what.starts_with("splat-tiles"))
            .then(|| TileSplat::new(threads).with_culling(what != "splat-tiles-nocull"));
        let mut direct = direct::make(what, threads);
        let mut other = match (&tiles, &direct) {
            (Some(_), _) | (_, Some(_)) => None,
            (None, None) => {
                let kind = volwarp_core::RendererKind::from_name(what).expect("a renderer name");
                Some(volwarp_cpu_tracer::create(kind, threads).expect("a CPU renderer"))
            }
        };
        let r: &mut dyn Renderer = match (&mut tiles, &mut direct, &mut other) {
            (Some(t), _, _) => t,
            (_, Some(d), _) => d,
            (_, _, Some(o)) => o.as_mut(),
            _ => return,
        };
        let res: u32 = args.get(4).and_then(|s| s.parse().ok()).unwrap_or(1024);
        let cam = cam.with_viewport(res, res);
        r.render(&scene, &cam, &mut img);
        let (t, c) = (Instant::now(), cpu_ns().unwrap_or(0));
        for _ in 0..30 {
            r.render(&scene, &cam, &mut img);
        }
        println!(
            "{what} {res}² ({} lanes): {:.1} ms per frame wall, {:.1} ms on this thread's CPU",
            volwarp_cpu_tracer::lane_kind(),
            t.elapsed().as_secs_f64() * 1e3 / 30.0,
            (cpu_ns().unwrap_or(0) - c) as f64 / 1e6 / 30.0
        );
        if let Some(d) = &direct {
            direct::report(d);
        }
        if let Some(t) = &tiles {
            let (pairs, culled) = t.culled();
            println!(
                "sphere-tile pairs {pairs}, culled whole {culled} ({:.1} %)",
                100.0 * culled as f64 / pairs.max(1) as f64
            );
        }
        return;
    }
    println!("threads {threads} ({})", if threads == 1 { "on-CPU ms" } else { "wall ms" });
    println!("| frame | view | viewport | spheres in view | covered px/pixel | splat-tiles | spheres-cpu | splat | spheres (route) |");
    println!("|---|---|---|---|---|---|---|---|---|");
    for model in [volwarp_server::RadiusModel::default(), volwarp_server::RadiusModel::Voxel] {
        let Some(f) = frame(model, &dir) else { return };
        let scene = Scene::build(&f);
        for (view, dolly) in [("10° off", 1.0f32), ("zoom 0.5", 0.5), ("zoom 0.25", 0.25)] {
            for res in [1024u32, 512] {
                let cam = f.header.camera.orbit(10.0, 0.0).dolly(dolly).with_viewport(res, res);
                let est = route::estimate(&scene, &cam);
                let mut ts = TileSplat::new(threads);
                let mut pt = PacketTracer::new(threads);
                let mut ss = SphereSplat::new(threads);
                let mut auto = AutoSpheres::new(threads);
                let a = time(&mut ts, &scene, &cam, &mut img);
                let b = time(&mut pt, &scene, &cam, &mut img);
                let c = if dolly == 1.0 { time(&mut ss, &scene, &cam, &mut img) } else { f64::NAN };
                let d = time(&mut auto, &scene, &cam, &mut img);
                println!(
                    "| {model} | {view} | {res}² | {:.0} | {:.2} | {a:.1} | {b:.1} | {c:.1} | {d:.1} ({:?}) |",
                    est.spheres,
                    est.coverage(),
                    auto.last_route()
                );
            }
        }
    }
}
