//! Layered samples end to end: the server's layered frames drawn by `splat-layers`
//! against the marcher's truth at the frame's own camera, order independence, K = 1 against
//! today's images, the transparent extreme and a session with layered frames.

use std::path::Path;
use std::sync::Arc;
use volwarp_core::renderer::Renderer;
use volwarp_core::wire::{CameraRequest, Frame};
use volwarp_core::{Heuristic, Image, RendererKind, Vec3, BACKGROUND};
use volwarp_cpu_tracer::route::unbuilt_scene;
use volwarp_cpu_tracer::{build_scene, create, LayerSplat};
use volwarp_eval::camera_paths::orbit;
use volwarp_eval::Metrics;
use volwarp_server::dataset::Dataset;
use volwarp_server::transfer_function::TransferFunction;
use volwarp_server::{Marcher, Volume};

const SIZE: u32 = 96;

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(name)
}

/// The bundled datasets and the shared ones (see `volwarp_server::testdata`).
fn datasets() -> Vec<Dataset> {
    let mut out = vec![
        Dataset::load(data("data/ct_head_quarter.nhdr"), None).unwrap(),
        Dataset::load(data("data/neghip_64x64x64_uint8.raw"), None).unwrap(),
    ];
    for f in ["iron_protein_68x68x68_uint8.raw", "tooth_103x94x161_uint8.raw", "mri_colin27_181x217x181_uint8.raw"] {
        out.extend(volwarp_server::testdata::shared_dataset(f));
    }
    out
}

fn request(m: &Marcher, yaw: f32) -> CameraRequest {
    CameraRequest {
        seq: 1,
        camera: orbit(&m.default_camera(SIZE, SIZE), yaw),
        heuristic: Heuristic::Threshold,
        radius_scale: 1.0,
        layers: 0,
    }
}

fn draw(r: &mut dyn Renderer, f: &Frame, cam: &volwarp_core::Camera) -> Image {
    let mut img = Image::new(0, 0);
    r.render(&unbuilt_scene(f), cam, &mut img);
    img
}

#[test]
fn at_the_frames_own_camera_the_composite_is_the_servers_render() {
    let mut r = LayerSplat::new(1);
    for ds in datasets() {
        let m = Marcher::from_dataset(&ds);
        let req = request(&m, 12.0);
        let truth = m.render_image(&req.camera);
        for k in [2, 4, 8] {
            // Pixel for pixel: each pixel takes exactly its own segments there, and their 8-bit
            // colors composite to the server's pixel (core's `segments::pack_colors`).
            let (f, _) = m.render_frame_layers(&req, k);
            let img = draw(&mut r, &f, &req.camera);
            let off = img.pixels.iter().zip(&truth.pixels).filter(|(a, b)| a != b).count();
            assert_eq!(off, 0, "{} K={k}: {off} pixels differ from the server's render", ds.name);
        }
        // A warp 10° away still beats the stale frame (the point of layers).
        let (f, _) = m.render_frame_layers(&req, 4);
        let cam = orbit(&req.camera, 10.0);
        let truth = m.render_image(&cam);
        let warped = Metrics::of(&truth, &draw(&mut r, &f, &cam)).unwrap();
        let stale = Metrics::of(&truth, &draw(create(RendererKind::Stale, 1).unwrap().as_mut(), &f, &cam)).unwrap();
        assert!(warped.psnr > stale.psnr, "{}: {:.1} dB warped, {:.1} dB stale", ds.name, warped.psnr, stale.psnr);
    }
}

#[test]
fn the_layered_tracer_composites_the_servers_render_too() {
    // `spheres-layers`: multi-hit traversal of the built scene's LBVH, the same compositing.
    let mut r = create(RendererKind::SpheresLayers, 2).unwrap();
    let mut any_hits = false;
    for ds in datasets() {
        let m = Marcher::from_dataset(&ds);
        let req = request(&m, 12.0);
        let truth = m.render_image(&req.camera);
        let (f, _) = m.render_frame_layers(&req, 4);
        let scene = build_scene(&f);
        let mut img = Image::new(0, 0);
        r.render(&scene, &req.camera, &mut img);
        let q = Metrics::of(&truth, &img).unwrap();
        assert!(q.psnr >= 40.0, "{}: {:.1} dB", ds.name, q.psnr);
        assert!(q.flip <= 0.005, "{}: ꟻLIP {:.4}", ds.name, q.flip);
        any_hits |= img.pixels.iter().any(|&p| p != BACKGROUND);
        // 10° away it beats the stale frame, as the splatter does.
        let cam = orbit(&req.camera, 10.0);
        let truth = m.render_image(&cam);
        r.render(&scene, &cam, &mut img);
        let warped = Metrics::of(&truth, &img).unwrap();
        let stale = Metrics::of(&truth, &draw(create(RendererKind::Stale, 1).unwrap().as_mut(), &f, &cam)).unwrap();
        assert!(warped.psnr > stale.psnr, "{}: {:.1} dB traced, {:.1} dB stale", ds.name, warped.psnr, stale.psnr);
        // The one-sample frame (K = 1) drawn the same way is its own image at its camera.
        let one = m.render_frame(&req).0;
        r.render(&build_scene(&one), &req.camera, &mut img);
        let own = draw(create(RendererKind::Stale, 1).unwrap().as_mut(), &one, &req.camera);
        let q1 = Metrics::of(&own, &img).unwrap();
        assert!(q1.psnr >= 40.0, "{} K=1: {:.1} dB", ds.name, q1.psnr);
    }
    assert!(any_hits);
}

#[test]
fn the_composite_does_not_depend_on_the_order_of_the_samples() {
    let ds = Dataset::load(data("data/ct_head_quarter.nhdr"), None).unwrap();
    let m = Marcher::from_dataset(&ds);
    let req = request(&m, 0.0);
    let (f, _) = m.render_frame_layers(&req, 4);
    let cam = orbit(&req.camera, 15.0);
    let mut r = LayerSplat::new(2);
    let a = draw(&mut r, &f, &cam);
    // The LBVH's Morton order, and a reversed order.
    let mut b = Image::new(0, 0);
    r.render(&build_scene(&Frame::new(f.header, f.samples.clone(), f.colors.clone())), &cam, &mut b);
    let rev = Frame::new(f.header, f.samples.iter().rev().copied().collect(), f.colors.iter().rev().copied().collect());
    let c = draw(&mut r, &rev, &cam);
    assert!(a == b && a == c, "the image depends on the order of the samples");
    assert!(a.pixels.iter().any(|&p| p != BACKGROUND));
}

#[test]
fn one_layer_frames_give_todays_images() {
    let ds = Dataset::load(data("data/neghip_64x64x64_uint8.raw"), None).unwrap();
    let m = Marcher::from_dataset(&ds);
    let req = request(&m, 0.0);
    let (today, _) = m.render_frame(&req);
    let (one, _) = m.render_frame_layers(&req, 1);
    let cam = orbit(&req.camera, 10.0);
    for kind in [RendererKind::Splat, RendererKind::Points2, RendererKind::Stale, RendererKind::SpheresCpu] {
        let mut r = create(kind, 1).unwrap();
        let (mut a, mut b) = (Image::new(0, 0), Image::new(0, 0));
        r.render(&build_scene(&today), &cam, &mut a);
        r.render(&build_scene(&one), &cam, &mut b);
        assert!(a == b, "{kind}");
    }
}

#[test]
fn a_transparent_volume_draws_the_background_and_zero_opacity_no_nan() {
    let vol = Arc::new(Volume::from_values("box", [16; 3], Vec3::ONE, vec![7.0; 16 * 16 * 16]).unwrap());
    let clear = TransferFunction::from_points("c", &[(0.0, [1.0, 0.5, 0.25])], &[(0.0, 0.0)]);
    let m = Marcher::new(vol, &clear);
    let req = request(&m, 0.0);
    let (f, _) = m.render_frame_layers(&req, 8);
    assert!(f.samples.is_empty());
    let img = draw(&mut LayerSplat::new(1), &f, &orbit(&req.camera, 5.0));
    assert!(img.pixels.iter().all(|&p| p == BACKGROUND));
    // Segments whose colors are all zero (opacity 0): the background, not NaN garbage.
    let ds = Dataset::load(data("data/neghip_64x64x64_uint8.raw"), None).unwrap();
    let m = Marcher::from_dataset(&ds);
    let (mut f, _) = m.render_frame_layers(&request(&m, 0.0), 4);
    assert!(!f.samples.is_empty());
    f.colors.iter_mut().for_each(|c| *c = 0);
    let img = draw(&mut LayerSplat::new(1), &f, &orbit(&f.header.camera, 5.0));
    assert!(img.pixels.iter().all(|&p| p == BACKGROUND));
}

#[test]
fn hole_filling_fills_what_no_segment_covers_and_keeps_the_rest() {
    use volwarp_cpu_tracer::layer_splat::LayerOptions;
    let ds = Dataset::load(data("data/ct_head_quarter.nhdr"), None).unwrap();
    let m = Marcher::from_dataset(&ds);
    let req = request(&m, 0.0);
    let (f, _) = m.render_frame_layers(&req, 4);
    assert!(LayerSplat::new(1).options().fill, "the layered splatter fills by default");
    // The default footprints (the frame's own image grouped by source pixel) and wider ones
    // (the frame's own image drawn with them).
    for opts in [LayerOptions::DEFAULT, LayerOptions { own: 0.7, ..LayerOptions::DEFAULT }] {
        fills_only_holes(&f, &req.camera, opts);
    }
}

fn fills_only_holes(
    f: &Frame,
    frame_camera: &volwarp_core::Camera,
    opts: volwarp_cpu_tracer::layer_splat::LayerOptions,
) {
    use volwarp_cpu_tracer::layer_splat::LayerOptions;
    // The fill alone: the crack pass after it reads what the fill wrote (`layered::cracks` has
    // its own tests).
    let opts = LayerOptions { close_cracks: false, ..opts };
    let mut plain = LayerSplat::with_options(2, LayerOptions { fill: false, ..opts });
    let mut filled = LayerSplat::with_options(2, opts);
    // At the frame's own camera nothing is a hole.
    assert!(draw(&mut plain, f, frame_camera) == draw(&mut filled, f, frame_camera), "own {}", opts.own);
    let mut total = 0;
    for yaw in [40.0, 90.0, 180.0] {
        let cam = orbit(frame_camera, yaw);
        let (a, b) = (draw(&mut plain, f, &cam), draw(&mut filled, f, &cam));
        let mut changed = 0;
        for (&p, &q) in a.pixels.iter().zip(&b.pixels) {
            if p != q {
                // Only holes change, and they get the frame's color, not the background.
                assert_eq!(p, BACKGROUND, "{yaw}°: a covered pixel changed");
                assert_ne!(q, BACKGROUND);
                changed += 1;
            }
        }
        total += changed;
    }
    // Wider footprints leave fewer holes (39 pixels here; the default's watertight slabs 43).
    let least = if opts.own > 0.5 { 20 } else { 30 };
    assert!(total > least, "own {}: the turns opened holes and the fill filled {total} pixels", opts.own);
}

#[test]
fn one_and_several_threads_draw_the_same_layered_image() {
    let ds = Dataset::load(data("data/neghip_64x64x64_uint8.raw"), None).unwrap();
    let m = Marcher::from_dataset(&ds);
    let req = request(&m, 0.0);
    let (f, _) = m.render_frame_layers(&req, 4);
    let (mut one, mut two, mut three) = (LayerSplat::new(1), LayerSplat::new(2), LayerSplat::new(3));
    for r in [&mut one, &mut two, &mut three] {
        r.set_adaptive_radius(true);
    }
    for yaw in [0.0, 7.0, 25.0] {
        let cam = orbit(&req.camera, yaw);
        let a = draw(&mut one, &f, &cam);
        assert!(a == draw(&mut two, &f, &cam) && a == draw(&mut three, &f, &cam), "{yaw}°");
    }
    // An odd viewport (bands of rows that do not divide it).
    let mut cam = orbit(&req.camera, 9.0);
    (cam.width, cam.height) = (77, 45);
    assert!(draw(&mut one, &f, &cam) == draw(&mut two, &f, &cam));
}

/// The frame's own image (what the hole filling looks up and what the frame's own camera
/// shows) is made by grouping each pixel's segments, not by drawing footprints: it must be
/// what the footprints draw there, on every dataset, several K, odd viewports, 1 and 2 threads.
#[test]
fn the_frames_own_image_is_what_its_footprints_draw_there() {
    use volwarp_cpu_tracer::layer_splat::LayerOptions;
    for ds in datasets() {
        let m = Marcher::from_dataset(&ds);
        for (k, size, yaw) in [(4, (SIZE, SIZE), 0.0), (8, (131, 77), 33.0), (2, (64, 101), 200.0)] {
            let mut req = request(&m, yaw);
            (req.camera.width, req.camera.height) = size;
            let (f, _) = m.render_frame_layers(&req, k);
            assert!(!f.samples.is_empty());
            let footprints = draw(
                &mut LayerSplat::with_options(1, LayerOptions { fill: false, ..LayerOptions::DEFAULT }),
                &f,
                &req.camera,
            );
            for threads in [1, 2] {
                let own = draw(&mut LayerSplat::new(threads), &f, &req.camera);
                let differ = own.pixels.iter().zip(&footprints.pixels).filter(|(a, b)| a != b).count();
                assert_eq!(differ, 0, "{} K={k} {size:?} {threads} threads: {differ} pixels differ", ds.name);
            }
        }
    }
}
