//! The GPU layered splatter (`splat-layers-gpu`) against the CPU's `LayerSplat`:
//! real layered frames of the server's marcher (K = 4; the bundled CT head and neghip, the
//! MRI from `../shared/data`, see `volwarp_server::testdata`) at the frame's own camera and warped, fill and
//! adaptive growth on and off, and edge cases (0 and 1 samples, odd viewports, a viewport larger
//! than the frame, garbage samples). Target: every pixel identical on a software rasterizer
//! (lavapipe in CI); on a hardware GPU ≥ 99.9 % of pixels within one 8-bit step per channel
//! (`required_identical_share`). Needs a GPU adapter (lavapipe in CI); `VOLWARP_SKIP_GPU=1` skips explicitly.

use std::path::Path;
use volwarp_core::image_diff::{channel_diff, TARGET_IDENTICAL};
use volwarp_core::renderer::{Image, Renderer, BACKGROUND};
use volwarp_core::wire::{CameraRequest, Frame};
use volwarp_core::{Camera, Heuristic, RendererKind, Scene};
use volwarp_cpu_tracer::layer_splat::LayerOptions;
use volwarp_cpu_tracer::route::unbuilt_scene;
use volwarp_cpu_tracer::LayerSplat;
use volwarp_gpu_tracer::adapter::required_identical_share;
use volwarp_gpu_tracer::{GpuContext, GpuLayerSplat, WgScanKind};
use volwarp_server::{Dataset, Marcher};

fn gpu(opts: LayerOptions) -> Option<GpuLayerSplat> {
    if std::env::var("VOLWARP_SKIP_GPU").is_ok_and(|v| v == "1") {
        eprintln!("VOLWARP_SKIP_GPU=1: GPU test skipped");
        return None;
    }
    let _ = env_logger::builder().is_test(true).try_init();
    let ctx = GpuContext::new().unwrap_or_else(|e| panic!("{e} (set VOLWARP_SKIP_GPU=1 to skip the GPU tests)"));
    EXACT.get_or_init(|| required_identical_share(&ctx.info) == 1.0);
    Some(GpuLayerSplat::with_context(ctx, opts).unwrap())
}

/// Whether the adapter must draw every pixel exactly as the CPU does (a software rasterizer,
/// lavapipe in CI: `required_identical_share`); elsewhere pixels agree within one 8-bit step
/// (a hardware driver may reassociate the blend), on `TARGET_IDENTICAL` of them.
static EXACT: std::sync::OnceLock<bool> = std::sync::OnceLock::new();

/// Whether two pixels agree on this adapter (see [`EXACT`]).
fn alike(p: u32, q: u32) -> bool {
    if *EXACT.get().expect("a GPU was opened") {
        p == q
    } else {
        channel_diff(p, q) <= 1
    }
}

/// The share of agreeing pixels the comparisons need (see [`EXACT`]).
fn need() -> f64 {
    if *EXACT.get().expect("a GPU was opened") {
        1.0
    } else {
        TARGET_IDENTICAL
    }
}

/// Share of pixels that agree (see [`EXACT`]).
fn agreeing(a: &Image, b: &Image) -> f64 {
    assert_eq!((a.width, a.height), (b.width, b.height));
    let ok = a.pixels.iter().zip(&b.pixels).filter(|(&p, &q)| alike(p, q)).count();
    ok as f64 / a.pixels.len().max(1) as f64
}

/// Share of pixels whose channels all differ by at most one 8-bit step.
fn within_one(a: &Image, b: &Image) -> f64 {
    assert_eq!((a.width, a.height), (b.width, b.height));
    let ok = a.pixels.iter().zip(&b.pixels).filter(|(&p, &q)| channel_diff(p, q) <= 1).count();
    ok as f64 / a.pixels.len().max(1) as f64
}

/// CPU and GPU draw `scene` for `cam`; asserts the target and returns the covered pixels.
fn compare(cpu: &mut LayerSplat, gpu: &mut GpuLayerSplat, what: &str, scene: &Scene, cam: &Camera) -> usize {
    let (mut want, mut got) = (Image::new(1, 1), Image::new(1, 1));
    cpu.render(scene, cam, &mut want);
    gpu.try_render(scene, cam, &mut got).unwrap_or_else(|e| panic!("{what}: {e}"));
    let share = within_one(&want, &got);
    let identical = want.diff(&got).unwrap();
    let shown = want.pixels.iter().filter(|&&p| p != BACKGROUND).count();
    eprintln!(
        "{what}: {:.4} % within one step, {:.4} % identical, max diff {}, {shown} non-background pixels of {}",
        100.0 * share,
        100.0 * identical.identical_share(),
        identical.max_channel_diff,
        want.pixels.len()
    );
    let agree = agreeing(&want, &got);
    assert!(agree >= need(), "{what}: only {:.4} % of pixels agree", 100.0 * agree);
    shown
}

fn request(seq: u64, camera: Camera) -> CameraRequest {
    CameraRequest { seq, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 }
}

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(name)
}

/// A K = 4 layered frame of `ds` at `w × h`, 12° round from the default view.
fn layered_frame(ds: &Dataset, w: u32, h: u32) -> Frame {
    let m = Marcher::from_dataset(ds);
    let cam = m.default_camera(w, h).orbit(12.0, 5.0);
    m.render_frame_layers(&request(1, cam), 4).0
}

/// Every option pair, the frame's own camera and 10° off (orbit and a pan-like turn), the
/// scene built and unbuilt.
fn check_frame(name: &str, frame: &Frame) {
    let n = frame.samples.len();
    assert!(n > 2000, "{name}: only {n} samples");
    let fc = frame.header.camera;
    let cams = [("own camera", fc), ("10° orbit", fc.orbit(10.0, 0.0)), ("-7° 6° orbit", fc.orbit(-7.0, 6.0))];
    let built = Scene::build(frame);
    let unbuilt = unbuilt_scene(frame);
    for fill in [false, true] {
        let opts = LayerOptions { fill, ..LayerOptions::DEFAULT };
        let Some(mut g) = gpu(opts) else { return };
        for adaptive in [false, true] {
            let mut cpu = LayerSplat::with_options(1, opts);
            cpu.set_adaptive_radius(adaptive);
            assert!(g.set_adaptive_radius(adaptive));
            for (which, scene) in [("built", &built), ("unbuilt", &unbuilt)] {
                for (view, cam) in &cams {
                    let what = format!("{name} ({n} samples, {which}), {view}, fill {fill}, adaptive {adaptive}");
                    let shown = compare(&mut cpu, &mut g, &what, scene, cam);
                    let px = (cam.width * cam.height) as usize;
                    assert!(shown > px / 8, "{what}: the frame should fill much of the view ({shown} of {px})");
                }
            }
        }
        // One upload per switch of scene (2 option passes × built, unbuilt), not per camera.
        assert_eq!(g.scene_uploads(), 4, "a scene drawn again is not uploaded again");
    }
}

#[test]
fn gpu_layers_match_the_cpu_on_a_real_ct_head_frame() {
    let frame = layered_frame(&Dataset::default_bundled(), 96, 80);
    check_frame("ct head 96×80", &frame);
}

#[test]
fn gpu_layers_match_the_cpu_on_real_neghip_and_mri_frames() {
    let neghip = Dataset::load(data("data/neghip_64x64x64_uint8.raw"), None).unwrap();
    check_frame("neghip 80×96", &layered_frame(&neghip, 80, 96));
    if let Some(ds) = volwarp_server::testdata::shared_dataset(volwarp_server::testdata::MRI) {
        check_frame("mri 128×96", &layered_frame(&ds, 128, 96));
    }
}

#[test]
fn gpu_layers_match_the_cpu_on_odd_and_larger_viewports() {
    let frame = layered_frame(&Dataset::default_bundled(), 64, 48);
    let scene = unbuilt_scene(&frame);
    for fill in [false, true] {
        let opts = LayerOptions { fill, ..LayerOptions::DEFAULT };
        let Some(mut g) = gpu(opts) else { return };
        let mut cpu = LayerSplat::with_options(1, opts);
        let fc = frame.header.camera;
        for (w, h) in [(1, 1), (7, 13), (63, 47), (131, 97), (200, 150)] {
            for cam in [fc.with_viewport(w, h), fc.orbit(8.0, -3.0).with_viewport(w, h)] {
                compare(&mut cpu, &mut g, &format!("ct head 64×48 frame, {w}×{h} view, fill {fill}"), &scene, &cam);
            }
        }
    }
}

#[test]
fn both_workgroup_scans_draw_the_cpu_image() {
    // The list scan in both forms (subgroup operations and the portable one) on a viewport of
    // 30 scan blocks, warped, with the fill: the same image as each other and as the CPU.
    if gpu(LayerOptions::DEFAULT).is_none() {
        return;
    }
    let frame = layered_frame(&Dataset::default_bundled(), 160, 120);
    let scene = unbuilt_scene(&frame);
    let cam = frame.header.camera.orbit(9.0, 4.0).with_viewport(400, 300);
    let mut cpu = LayerSplat::with_options(1, LayerOptions::DEFAULT);
    let mut images = Vec::new();
    for kind in WgScanKind::ALL {
        let mut ctx = GpuContext::new().unwrap();
        if let Err(e) = ctx.set_scan(kind) {
            let offered = ctx.adapter.features().contains(wgpu::Features::SUBGROUP);
            let disabled = std::env::var("VOLWARP_GPU_SUBGROUPS").is_ok_and(|v| v == "0");
            assert!(!offered || disabled, "the adapter offers subgroups but the {kind:?} scan is refused: {e}");
            eprintln!("{kind:?} scan not tested: {e}");
            continue;
        }
        let mut g = GpuLayerSplat::with_context(ctx, LayerOptions::DEFAULT).unwrap();
        compare(&mut cpu, &mut g, &format!("ct head, 400×300 view, {kind:?} scan"), &scene, &cam);
        let mut img = Image::new(1, 1);
        g.try_render(&scene, &cam, &mut img).unwrap();
        images.push(img);
    }
    if let [a, b] = &images[..] {
        assert!(a.pixels == b.pixels, "the two workgroup scans draw different images");
    }
    // Lavapipe offers subgroup operations: in CI both forms run, every time.
    let lavapipe = GpuContext::new().is_ok_and(|c| c.info.device_type == wgpu::DeviceType::Cpu);
    let disabled = std::env::var("VOLWARP_GPU_SUBGROUPS").is_ok_and(|v| v == "0");
    if lavapipe && !disabled {
        assert_eq!(images.len(), 2, "both workgroup scans must run on a software rasterizer");
    }
}

#[test]
fn zero_and_one_samples_and_garbage_draw_what_the_cpu_draws() {
    let Some(mut g) = gpu(LayerOptions::DEFAULT) else { return };
    let mut cpu = LayerSplat::new(1);
    let mut frame = layered_frame(&Dataset::default_bundled(), 48, 40);
    let fc = frame.header.camera;
    let cams = [fc, fc.orbit(10.0, 0.0), fc.with_viewport(33, 17)];
    // 0 samples: the background.
    let mut empty = frame.clone();
    empty.samples.clear();
    empty.colors.clear();
    for cam in &cams {
        compare(&mut cpu, &mut g, "0 samples", &unbuilt_scene(&empty), cam);
        let mut img = Image::new(1, 1);
        g.try_render(&unbuilt_scene(&empty), cam, &mut img).unwrap();
        assert!(img.pixels.iter().all(|&p| p == BACKGROUND));
    }
    // 1 sample (built: no nodes either way).
    let mut one = frame.clone();
    one.samples.truncate(1);
    one.colors.truncate(1);
    for cam in &cams {
        compare(&mut cpu, &mut g, "1 sample", &Scene::build(&one), cam);
    }
    // Garbage: random positions and colors (premultiplied or not, alpha anything).
    let mut x = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    for (s, c) in frame.samples.iter_mut().zip(frame.colors.iter_mut()) {
        if next() % 3 == 0 {
            *s = next();
            *c = next() as u32;
        }
    }
    for cam in &cams {
        compare(&mut cpu, &mut g, "garbage samples", &unbuilt_scene(&frame), cam);
    }
    // Older frames that are garbage, empty, inconsistent (a color short) or have an unusable
    // camera: drawn as the CPU draws them (or left out, as there), no error, no panic.
    let newest = unbuilt_scene(&layered_frame(&Dataset::default_bundled(), 48, 40));
    let garbage = unbuilt_scene(&frame);
    let mut short = garbage.clone();
    short.colors.pop();
    let mut bad_cam = garbage.clone();
    bad_cam.header.camera.fov_y_deg = f32::NAN;
    let empty = unbuilt_scene(&empty);
    let set = [&newest, &garbage, &empty, &short, &bad_cam];
    for cam in [fc.orbit(-12.0, 3.0), fc.orbit(170.0, 0.0)] {
        let (mut want, mut got) = (Image::new(1, 1), Image::new(1, 1));
        cpu.render_set(&set, &cam, &mut want);
        g.try_render_set(&set, &cam, &mut got).unwrap();
        let share = agreeing(&want, &got);
        assert!(share >= need(), "bad older frames: {:.4} % of pixels agree", 100.0 * share);
    }
}

#[test]
fn an_unusable_camera_or_scene_is_a_typed_error_and_the_background() {
    let Some(mut g) = gpu(LayerOptions::DEFAULT) else { return };
    assert_eq!(g.kind(), RendererKind::SplatLayersGpu);
    assert_eq!(g.name(), "splat-layers-gpu");
    let frame = layered_frame(&Dataset::default_bundled(), 32, 32);
    let mut img = Image::new(1, 1);
    let mut bad = frame.header.camera;
    bad.fov_y_deg = f32::NAN;
    assert!(g.try_render(&unbuilt_scene(&frame), &bad, &mut img).is_err());
    let mut scene = unbuilt_scene(&frame);
    scene.colors.pop();
    assert!(g.try_render(&scene, &frame.header.camera, &mut img).is_err());
    assert!(img.pixels.iter().all(|&p| p == BACKGROUND));
    // And it still draws afterwards.
    let mut cpu = LayerSplat::new(1);
    let shown = compare(&mut cpu, &mut g, "after errors", &unbuilt_scene(&frame), &frame.header.camera.orbit(5.0, 0.0));
    assert!(shown > 100);
}

/// The pixels the fill changes are few at small warps, so the tests above could not see a
/// broken fill: here the warps are large and the comparison is on the filled pixels alone.
#[test]
fn the_fill_matches_the_cpu_on_the_pixels_it_fills() {
    let plain = LayerOptions { fill: false, ..LayerOptions::DEFAULT };
    let Some(mut g) = gpu(LayerOptions::DEFAULT) else { return };
    let frame = layered_frame(&Dataset::default_bundled(), 96, 80);
    let scene = unbuilt_scene(&frame);
    let fc = frame.header.camera;
    let mut filled_total = 0;
    for (what, cam) in [
        ("25° orbit", fc.orbit(25.0, 0.0)),
        ("40° orbit", fc.orbit(-40.0, 10.0)),
        ("zoomed 30° orbit", fc.orbit(30.0, -15.0).with_viewport(160, 140)),
    ] {
        for adaptive in [false, true] {
            let (mut off, mut on, mut got) = (Image::new(1, 1), Image::new(1, 1), Image::new(1, 1));
            let mut cpu_off = LayerSplat::with_options(1, plain);
            let mut cpu_on = LayerSplat::new(1);
            cpu_off.set_adaptive_radius(adaptive);
            cpu_on.set_adaptive_radius(adaptive);
            g.set_adaptive_radius(adaptive);
            cpu_off.render(&scene, &cam, &mut off);
            cpu_on.render(&scene, &cam, &mut on);
            g.try_render(&scene, &cam, &mut got).unwrap();
            let filled: Vec<usize> = (0..on.pixels.len()).filter(|&i| on.pixels[i] != off.pixels[i]).collect();
            let ok = filled.iter().filter(|&&i| alike(on.pixels[i], got.pixels[i])).count();
            eprintln!("{what}, adaptive {adaptive}: {} filled pixels, {ok} drawn alike", filled.len());
            assert!(ok as f64 >= need() * filled.len() as f64, "{what}: the fill differs");
            assert!(agreeing(&on, &got) >= need(), "{what}");
            filled_total += filled.len();
        }
    }
    // (Watertight slabs leave few holes at these turns: 84 at a tolerance of 5 source pixels.)
    assert!(filled_total > 50, "the views should open holes for the fill ({filled_total})");
}

/// The multi-frame filling on the GPU: `render_set` with older frames draws the CPU's
/// image (each older frame's residual into the pixels still empty, then the fill), through a
/// sequence of arrivals (the residuals are carried over when the set shifts by one frame),
/// with the fill on and off, adaptive sizing on and off, and a turn past 90° (older frames
/// drawn whole). The older frames must change the image, or the comparison says nothing.
#[test]
fn older_frames_fill_as_on_the_cpu() {
    if gpu(LayerOptions::DEFAULT).is_none() {
        return;
    }
    let ds = Dataset::default_bundled();
    let m = Marcher::from_dataset(&ds);
    let base = m.default_camera(96, 80);
    // Frames 8° apart along the orbit, oldest first: each arrival adds the next.
    let frames: Vec<Scene> = (0..5)
        .map(|i| {
            let cam = base.orbit(-24.0 + 8.0 * i as f32, 4.0);
            unbuilt_scene(&m.render_frame_layers(&request(i as u64 + 1, cam), 4).0)
        })
        .collect();
    for fill in [false, true] {
        for adaptive in [false, true] {
            let opts = LayerOptions { fill, ..LayerOptions::DEFAULT };
            let mut g = gpu(opts).unwrap();
            let mut cpu = LayerSplat::with_options(1, opts);
            assert!(g.keeps_frames() && cpu.keeps_frames());
            g.set_adaptive_radius(adaptive);
            cpu.set_adaptive_radius(adaptive);
            let mut changed = 0;
            // The client's pattern: after each arrival a few draws of the moving camera with
            // the newest frames kept (newest first, at most 4), then a turn past 90°.
            for newest in 1..frames.len() {
                let set: Vec<&Scene> = frames[..=newest].iter().rev().take(4).collect();
                let fc = set[0].header.camera;
                for (view, cam) in [("10° on", fc.orbit(10.0, 0.0)), ("25° back", fc.orbit(-25.0, -6.0))] {
                    let what = format!("fill {fill}, adaptive {adaptive}, {} frames, {view}", set.len());
                    let (mut want, mut got, mut alone) = (Image::new(1, 1), Image::new(1, 1), Image::new(1, 1));
                    cpu.render_set(&set, &cam, &mut want);
                    g.try_render_set(&set, &cam, &mut got).unwrap_or_else(|e| panic!("{what}: {e}"));
                    let share = agreeing(&want, &got);
                    eprintln!("{what}: {:.4} % of pixels agree", 100.0 * share);
                    assert!(share >= need(), "{what}: only {:.4} % of pixels agree", 100.0 * share);
                    let mut alone_cpu = LayerSplat::with_options(1, opts);
                    alone_cpu.set_adaptive_radius(adaptive);
                    alone_cpu.render(set[0], &cam, &mut alone);
                    // On the pixels the older frames changed alone, too (few at these warps).
                    let older_px: Vec<usize> =
                        (0..want.pixels.len()).filter(|&i| alone.pixels[i] != want.pixels[i]).collect();
                    let same = older_px.iter().filter(|&&i| alike(want.pixels[i], got.pixels[i])).count();
                    assert!(same as f64 >= need() * older_px.len() as f64, "{what}: the older frames' pixels differ");
                    changed += older_px.len();
                }
            }
            let set: Vec<&Scene> = frames.iter().rev().take(4).collect();
            let turned = set[0].header.camera.orbit(150.0, 0.0);
            let (mut want, mut got) = (Image::new(1, 1), Image::new(1, 1));
            cpu.render_set(&set, &turned, &mut want);
            g.try_render_set(&set, &turned, &mut got).unwrap();
            assert!(agreeing(&want, &got) >= need(), "fill {fill}, adaptive {adaptive}: 150° turn");
            eprintln!("fill {fill}, adaptive {adaptive}: the older frames changed {changed} pixels");
            assert!(changed > 50, "fill {fill}, adaptive {adaptive}: the older frames changed only {changed} pixels");
        }
    }
}
