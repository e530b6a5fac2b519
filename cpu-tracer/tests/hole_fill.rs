//! Hole filling: the filled renderers never change a pixel the newest frame covers,
//! fill the ones it leaves empty (from older frames on a disocclusion and a 180° turn, from the
//! stale frame otherwise), and every CPU sphere renderer draws the same filled image.

use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::sample::over_background;
use volwarp_core::{Camera, RendererKind, Scene, Vec3, BACKGROUND};
use volwarp_cpu_tracer::hole_fill::MAX_FRAMES;
use volwarp_cpu_tracer::synthetic::{depth_image_frame, frame_from_points, Point, SplitMix64};
use volwarp_cpu_tracer::{FillOptions, HoleFill, PacketTracer, ScalarTracer, SphereSplat, StaleImage, NO_HIT};

fn ids(scene: &Scene, cam: &Camera) -> Vec<u32> {
    let mut v = Vec::new();
    assert!(PacketTracer::new(1).trace_ids(scene, cam, &mut v));
    v
}

fn render(r: &mut dyn Renderer, scene: &Scene, cam: &Camera) -> Image {
    let mut img = Image::new(1, 1);
    r.render(scene, cam, &mut img);
    img
}

/// A square grid of `n`² points on the plane `z = z0` over `[-e, e]²`, one color.
fn plane(n: u32, e: f32, z0: f32, rgb: [f32; 3], seed: u64) -> Vec<Point> {
    let mut rng = SplitMix64(seed);
    let step = 2.0 * e / n as f32;
    let mut pts = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let a = rng.range(0.8, 1.0);
            pts.push(Point {
                center: Vec3::new(-e + (i as f32 + 0.5) * step, -e + (j as f32 + 0.5) * step, z0),
                radius: 0.75 * step,
                color: [rgb[0] * a, rgb[1] * a, rgb[2] * a, a],
            });
        }
    }
    pts
}

fn fill(opts: FillOptions) -> HoleFill<PacketTracer> {
    HoleFill::new(PacketTracer::new(1), RendererKind::SpheresFill, opts, 1)
}

const STALE_ONLY: FillOptions = FillOptions { stale: true, enclosed_only: true, pull_push_levels: 0 };
const ALL_STAGES: FillOptions = FillOptions { stale: true, enclosed_only: true, pull_push_levels: 3 };
const FRAMES_ONLY: FillOptions = FillOptions { stale: false, enclosed_only: false, pull_push_levels: 0 };

#[test]
fn fill_keeps_covered_pixels_and_fills_holes_on_a_turn() {
    let frame = depth_image_frame(64, 0.5, 3);
    let scene = Scene::build(&frame);
    let cam = frame.header.camera.orbit(25.0, 10.0);
    let plain = render(&mut PacketTracer::new(1), &scene, &cam);
    let id = ids(&scene, &cam);
    for opts in [STALE_ONLY, ALL_STAGES, FillOptions { stale: false, enclosed_only: true, pull_push_levels: 2 }] {
        let filled = render(&mut fill(opts), &scene, &cam);
        assert_eq!((filled.width, filled.height), (plain.width, plain.height));
        let mut holes_filled = 0;
        for (i, &d) in id.iter().enumerate() {
            if d != NO_HIT {
                assert_eq!(filled.pixels[i], plain.pixels[i], "{opts:?}: covered pixel {i} changed");
            } else if filled.pixels[i] != BACKGROUND {
                holes_filled += 1;
            }
        }
        assert!(holes_filled > 20, "{opts:?}: only {holes_filled} holes filled");
    }
    // Enclosed only: nothing outside the covered pixels' row span is filled.
    let filled = render(&mut fill(STALE_ONLY), &scene, &cam);
    let w = cam.width as usize;
    for (y, row) in id.chunks(w).enumerate() {
        let Some(first) = row.iter().position(|&d| d != NO_HIT) else {
            assert!(filled.pixels[y * w..(y + 1) * w].iter().all(|&p| p == BACKGROUND));
            continue;
        };
        assert!(filled.pixels[y * w..y * w + first].iter().all(|&p| p == BACKGROUND), "row {y}");
    }
}

#[test]
fn stale_fill_at_the_frame_camera_is_the_stale_image() {
    let frame = depth_image_frame(48, 0.4, 5);
    let scene = Scene::build(&frame);
    let cam = frame.header.camera;
    let stale = render(&mut StaleImage::new(1), &scene, &cam);
    let everywhere = FillOptions { enclosed_only: false, ..STALE_ONLY };
    let filled = render(&mut fill(everywhere), &scene, &cam);
    let id = ids(&scene, &cam);
    let holes = id.iter().filter(|&&d| d == NO_HIT).count();
    assert!(holes > 100, "small spheres leave holes: {holes}");
    for (i, &d) in id.iter().enumerate() {
        if d == NO_HIT {
            assert_eq!(filled.pixels[i], stale.pixels[i], "hole {i} shows the stale frame");
        }
    }
}

#[test]
fn every_cpu_sphere_renderer_fills_the_same_image() {
    let frame = depth_image_frame(56, 1.0, 9);
    let older_frame = depth_image_frame(56, 1.0, 10);
    let scene = Scene::build(&frame);
    let older = Scene::build(&older_frame);
    for (yaw, pitch) in [(0.0, 0.0), (15.0, 5.0), (40.0, -20.0), (180.0, 0.0)] {
        let cam = frame.header.camera.orbit(yaw, pitch);
        for opts in [STALE_ONLY, ALL_STAGES, FRAMES_ONLY, FillOptions { enclosed_only: false, ..ALL_STAGES }] {
            let mut packet = fill(opts);
            let mut scalar = HoleFill::new(ScalarTracer::new(2), RendererKind::SpheresFill, opts, 2);
            let mut splat = HoleFill::new(SphereSplat::new(1), RendererKind::SplatFill, opts, 1);
            let mut out = [Image::new(1, 1), Image::new(1, 1), Image::new(1, 1)];
            packet.render_set(&[&scene, &older], &cam, &mut out[0]);
            scalar.render_set(&[&scene, &older], &cam, &mut out[1]);
            splat.render_set(&[&scene, &older], &cam, &mut out[2]);
            assert_eq!(out[0], out[1], "{yaw}°/{pitch}° {opts:?}: packet vs scalar");
            assert_eq!(out[0], out[2], "{yaw}°/{pitch}° {opts:?}: packet vs splat");
        }
    }
}

/// Checks a multi-frame fill: covered pixels of the newest frame keep its color, its holes that
/// an older frame hits take the older frame's color, and there are `min_filled` such holes.
fn check_set(newest: &Scene, older: &Scene, cam: &Camera, min_filled: usize) {
    let mut r = fill(FRAMES_ONLY);
    let mut out = Image::new(1, 1);
    r.render_set(&[newest, older], cam, &mut out);
    let (id_new, id_old) = (ids(newest, cam), ids(older, cam));
    let (mut kept, mut filled) = (0, 0);
    for i in 0..id_new.len() {
        if id_new[i] != NO_HIT {
            assert_eq!(out.pixels[i], over_background(newest.colors[id_new[i] as usize], BACKGROUND));
            if id_old[i] != NO_HIT {
                kept += 1;
            }
        } else if id_old[i] != NO_HIT {
            assert_eq!(out.pixels[i], over_background(older.colors[id_old[i] as usize], BACKGROUND));
            filled += 1;
        } else {
            assert_eq!(out.pixels[i], BACKGROUND);
        }
    }
    assert!(filled >= min_filled, "{filled} holes filled from the older frame");
    assert!(kept > 100, "{kept} pixels both frames cover keep the newest frame's color");
}

#[test]
fn older_frame_fills_a_disocclusion_without_overriding() {
    // The newest frame saw an occluder in front of the back wall and so misses the wall behind
    // it; the older frame, from another side, saw the wall (and is closer to the camera there).
    let cam0 = Camera::look_at(Vec3::new(0.0, 0.0, 4.0), Vec3::ZERO, Vec3::Y, 40.0, 64, 64);
    let mut newest_pts = plane(40, 0.4, 0.5, [1.0, 0.2, 0.2], 1);
    newest_pts.extend(plane(60, 1.0, -0.5, [0.2, 0.2, 1.0], 2).into_iter().filter(|p| {
        p.center.x.abs() > 0.55 || p.center.y.abs() > 0.55 // the wall behind the occluder was never sampled
    }));
    let older_pts = plane(60, 1.0, -0.45, [0.2, 1.0, 0.2], 3);
    let newest = Scene::build(&frame_from_points(&newest_pts, cam0));
    let older = Scene::build(&frame_from_points(&older_pts, cam0.orbit(30.0, 0.0)));
    check_set(&newest, &older, &cam0.orbit(-25.0, 0.0), 50);
}

#[test]
fn older_frame_fills_a_180_degree_turn() {
    // The newest frame is the front of a thin slab; the older one, from behind, saw its wider
    // back. Turned around, the newest frame's samples are seen from behind (mirrored) and the
    // older frame fills the rim around them, never drawing over them although it is closer.
    let front = Camera::look_at(Vec3::new(0.0, 0.0, 4.0), Vec3::ZERO, Vec3::Y, 40.0, 64, 64);
    let newest = Scene::build(&frame_from_points(&plane(40, 0.5, 0.1, [1.0, 0.5, 0.2], 4), front));
    let back = front.orbit(180.0, 0.0);
    let older = Scene::build(&frame_from_points(&plane(60, 1.0, -0.1, [0.2, 0.6, 1.0], 5), back));
    check_set(&newest, &older, &back.orbit(5.0, 0.0), 300);
}

#[test]
fn set_bounds_and_bad_scenes() {
    let frame = depth_image_frame(32, 1.0, 1);
    let scene = Scene::build(&frame);
    let cam = frame.header.camera.orbit(20.0, 0.0);
    let mut r = fill(ALL_STAGES);
    let mut one = Image::new(1, 1);
    r.render_set(&[&scene], &cam, &mut one);
    // An inconsistent older scene is skipped; frames past MAX_FRAMES are ignored.
    let mut bad = scene.clone();
    bad.colors.pop();
    let mut out = Image::new(1, 1);
    r.render_set(&[&scene, &bad], &cam, &mut out);
    assert_eq!(out, one);
    let empty = Scene::empty(&frame.header);
    let mut set: Vec<&Scene> = vec![&scene];
    set.extend(std::iter::repeat_n(&empty, MAX_FRAMES - 1));
    set.push(&scene);
    r.render_set(&set, &cam, &mut out);
    assert_eq!(out, one, "the frame past MAX_FRAMES is not used");
    // No scene: the background at the camera's viewport; an unusable camera: like every renderer.
    r.render_set(&[], &cam, &mut out);
    assert!(out.pixels.iter().all(|&p| p == BACKGROUND) && out.width == cam.width);
    let bad_cam = Camera { fov_y_deg: f32::NAN, ..cam };
    r.render_set(&[&scene], &bad_cam, &mut out);
    assert!(out.pixels.iter().all(|&p| p == BACKGROUND));
}
