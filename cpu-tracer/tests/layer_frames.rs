//! Older frames for layered frames (the multi-frame filling in `splat-layers`): an older
//! frame fills only pixels the newest frame leaves uncovered, only with what the newest frame
//! did not see (the newest frame's samples again, from other cameras, add nothing), and fills a
//! disocclusion and a 180° turn.

use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::{Camera, Scene, Vec3, BACKGROUND};
use volwarp_cpu_tracer::layer_splat::{LayerOptions, LayerSplat};
use volwarp_cpu_tracer::route::unbuilt_scene;
use volwarp_cpu_tracer::synthetic::{depth_image_frame, frame_from_points, Point};

/// A square grid of `n`² opaque points on the plane `z = z0` over `[-e, e]²`, one color,
/// keeping those `keep` accepts.
fn plane(n: u32, e: f32, z0: f32, rgba: [f32; 4], keep: impl Fn(f32, f32) -> bool) -> Vec<Point> {
    let step = 2.0 * e / n as f32;
    let mut pts = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let (x, y) = (-e + (i as f32 + 0.5) * step, -e + (j as f32 + 0.5) * step);
            if keep(x, y) {
                pts.push(Point { center: Vec3::new(x, y, z0), radius: 0.75 * step, color: rgba });
            }
        }
    }
    pts
}

/// Compares images without printing them.
fn same(a: &Image, b: &Image) -> bool {
    a.width == b.width && a.height == b.height && a.pixels == b.pixels
}

fn draw(r: &mut LayerSplat, scenes: &[&Scene], cam: &Camera) -> Image {
    let mut img = Image::new(1, 1);
    r.render_set(scenes, cam, &mut img);
    img
}

/// Checks that every pixel the newest frame covers (`alone`) keeps its color with the older
/// frames (`both`) and that every pixel they fill has the older frame's color (`older_color`);
/// returns the counts of both.
fn compare(alone: &Image, both: &Image, older_color: impl Fn(u32) -> bool) -> (usize, usize) {
    assert_eq!((both.width, both.height), (alone.width, alone.height));
    let (mut kept, mut filled) = (0, 0);
    for (&a, &b) in alone.pixels.iter().zip(&both.pixels) {
        if a != BACKGROUND {
            assert_eq!(b, a, "a pixel the newest frame covers keeps its color");
            kept += 1;
        } else if b != BACKGROUND {
            assert!(older_color(b), "filled with the older frame's color: {b:08x}");
            filled += 1;
        }
    }
    (kept, filled)
}

/// Without the stale fill, so what the older frames add is all that differs.
fn unfilled() -> LayerSplat {
    LayerSplat::with_options(1, LayerOptions { fill: false, ..LayerOptions::DEFAULT })
}

/// The newest frame saw an opaque occluder in front of a wall and so misses the wall behind it;
/// an older frame from another side saw the wall there.
fn disocclusion() -> (Scene, Scene, Camera) {
    let cam0 = Camera::look_at(Vec3::new(0.0, 0.0, 4.0), Vec3::ZERO, Vec3::Y, 40.0, 64, 64);
    let red = [1.0, 0.2, 0.2, 1.0];
    let mut newest = plane(40, 0.4, 0.5, red, |_, _| true);
    // The wall behind the occluder was never sampled.
    newest.extend(plane(60, 1.0, -0.5, [0.2, 0.2, 1.0, 1.0], |x, y| x.abs() > 0.55 || y.abs() > 0.55));
    let older = plane(60, 1.0, -0.45, [0.2, 1.0, 0.2, 1.0], |_, _| true);
    let newest = unbuilt_scene(&frame_from_points(&newest, cam0));
    let older = unbuilt_scene(&frame_from_points(&older, cam0.orbit(30.0, 0.0)));
    (newest, older, cam0.orbit(-25.0, 0.0))
}

#[test]
fn an_older_frame_fills_a_disocclusion_and_never_overrides_the_newest() {
    let (newest, older, cam) = disocclusion();
    let mut r = unfilled();
    r.set_adaptive_radius(true);
    let alone = draw(&mut r, &[&newest], &cam);
    let mut r2 = unfilled();
    r2.set_adaptive_radius(true);
    let both = draw(&mut r2, &[&newest, &older], &cam);
    // Filled from the older frame: its green wall.
    let (kept, filled) = compare(&alone, &both, |p| (p >> 8 & 0xff) > (p & 0xff));
    assert!(kept > 1000, "{kept} pixels covered by the newest frame");
    assert!(filled > 50, "{filled} pixels of the disocclusion filled from the older frame");
}

/// When a frame arrives, the set moves on by one: the older frames' residuals are then reduced
/// further by the new frame's sight only (the previous newest is reduced whole). A new frame that
/// also missed the wall must leave the disocclusion to the oldest frame, as a renderer that sees
/// the set for the first time draws it.
#[test]
fn a_set_moved_on_by_one_frame_draws_like_a_fresh_set() {
    let (newest, older, cam) = disocclusion();
    // The next frame: the newest frame's samples from a camera 4° further on (it saw the same).
    let mut next = newest.clone();
    next.header.camera = newest.header.camera.orbit(-4.0, 0.0);
    let next = Scene { samples: newest.samples.iter().rev().copied().collect(), ..next };
    let next = Scene { colors: newest.colors.iter().rev().copied().collect(), ..next };
    for fill in [false, true] {
        let opts = LayerOptions { fill, ..LayerOptions::DEFAULT };
        let mut r = LayerSplat::with_options(1, opts);
        r.set_adaptive_radius(true);
        let before = draw(&mut r, &[&newest, &older], &cam);
        let moved = draw(&mut r, &[&next, &newest, &older], &cam);
        let mut fresh = LayerSplat::with_options(1, opts);
        fresh.set_adaptive_radius(true);
        assert!(same(&moved, &draw(&mut fresh, &[&next, &newest, &older], &cam)), "fill {fill}");
        if !fill {
            let alone = draw(&mut fresh, &[&next], &cam);
            let (_, filled) = compare(&alone, &moved, |p| (p >> 8 & 0xff) > (p & 0xff));
            assert!(filled > 50, "{filled} pixels of the disocclusion filled from the oldest frame");
            let alone = draw(&mut fresh, &[&newest], &cam);
            let (_, filled_before) = compare(&alone, &before, |p| (p >> 8 & 0xff) > (p & 0xff));
            assert!(filled_before > 50);
        }
    }
}

#[test]
fn an_older_frame_fills_a_180_degree_turn() {
    // An opaque slab before a wide plate. The newest frame, zoomed in from the front, saw the
    // slab and the plate around it as far as its narrow view reached; the older one, from
    // behind, saw the whole plate. Turned around, the newest frame's footprints face away and
    // draw nothing, so the older frame is drawn whole: the plate, also where the newest frame
    // saw it (a residual alone would leave a ring open there).
    let front = Camera::look_at(Vec3::new(0.0, 0.0, 4.0), Vec3::ZERO, Vec3::Y, 12.0, 64, 64);
    let mut newest = plane(30, 0.3, 0.1, [1.0, 0.5, 0.2, 1.0], |_, _| true);
    newest.extend(plane(60, 1.0, -0.1, [0.2, 0.6, 1.0, 1.0], |x, y| {
        x.abs().max(y.abs()) > 0.3 && x.abs().max(y.abs()) < 0.4
    }));
    let back = Camera::look_at(Vec3::new(0.0, 0.0, -4.0), Vec3::ZERO, Vec3::Y, 40.0, 64, 64);
    let older = plane(60, 1.0, -0.1, [0.2, 0.6, 1.0, 1.0], |_, _| true);
    let newest = unbuilt_scene(&frame_from_points(&newest, front));
    let older = unbuilt_scene(&frame_from_points(&older, back));
    let cam = back.orbit(5.0, 0.0);
    let alone = draw(&mut unfilled(), &[&newest], &cam);
    let both = draw(&mut unfilled(), &[&newest, &older], &cam);
    // Filled from the older frame: its blue plate.
    let (kept, filled) = compare(&alone, &both, |p| (p >> 16 & 0xff) > (p & 0xff));
    assert_eq!(kept, 0, "seen from behind, the newest frame's footprints face away");
    // The whole plate, ring included (2042 pixels; the residual alone leaves about 290 open).
    assert!(filled > 1900, "{filled} pixels of the plate filled from the older frame");
}

#[test]
fn what_the_newest_frame_saw_is_not_drawn_again() {
    // The newest frame's samples again, as an older frame rendered from 10° and 20° away (so
    // with other footprints, which would cover pixels the newest frame's leave open): the
    // newest frame saw every one of them, so the image is the newest frame's alone, with and
    // without the stale fill.
    let frame = depth_image_frame(48, 1.0, 7);
    let newest = unbuilt_scene(&frame);
    let mut older = frame.clone();
    older.header.camera = frame.header.camera.orbit(-10.0, 0.0);
    let copy = unbuilt_scene(&older);
    older.header.camera = frame.header.camera.orbit(-20.0, 5.0);
    let copy2 = unbuilt_scene(&older);
    let cam = frame.header.camera.orbit(12.0, 4.0);
    for opts in [LayerOptions::DEFAULT, LayerOptions { fill: false, ..LayerOptions::DEFAULT }] {
        let mut r = LayerSplat::with_options(1, opts);
        r.set_adaptive_radius(true);
        let alone = draw(&mut r, &[&newest], &cam);
        let set = draw(&mut r, &[&newest, &copy, &copy2], &cam);
        assert!(same(&set, &alone), "fill {}", opts.fill);
    }
}

#[test]
fn one_frame_is_the_plain_render_and_bad_sets_draw_nothing_wrong() {
    let (newest, older, cam) = disocclusion();
    let mut r = LayerSplat::new(2);
    let mut plain = Image::new(1, 1);
    r.render(&newest, &cam, &mut plain);
    assert!(same(&draw(&mut r, &[&newest], &cam), &plain));
    // No scene: the background; an inconsistent older scene adds nothing; an empty one too.
    let none = draw(&mut r, &[], &cam);
    assert!(none.pixels.iter().all(|&p| p == BACKGROUND));
    let mut bad = older.clone();
    bad.colors.pop();
    let empty = Scene::empty(&older.header);
    assert!(same(&draw(&mut r, &[&newest, &bad, &empty], &cam), &plain));
    // Non-finite cameras neither panic nor leak NaN: the background.
    let bad_cam = Camera { fov_y_deg: f32::NAN, ..cam };
    let img = draw(&mut r, &[&newest, &older], &bad_cam);
    assert!(img.pixels.iter().all(|&p| p == BACKGROUND));
    assert!(r.keeps_frames());
}
