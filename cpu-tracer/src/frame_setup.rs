//! What every CPU renderer does before it draws: validate the camera and the scene (core's
//! [`Scene::check`]), size and clear the output, and draw the background (with one warning)
//! for anything unusable; and the color a sample-id pixel shows.

use crate::{MAX_VIEWPORT, NO_HIT};
use std::sync::atomic::{AtomicBool, Ordering};
use volwarp_core::renderer::Image;
use volwarp_core::sample::over_background;
use volwarp_core::{Camera, Scene, BACKGROUND};

static WARNED_CAMERA: AtomicBool = AtomicBool::new(false);
static WARNED_SCENE: AtomicBool = AtomicBool::new(false);

fn warn_once(flag: &AtomicBool, msg: &str) {
    if !flag.swap(true, Ordering::Relaxed) {
        log::warn!("{msg} (drawing the background; warned once)");
    }
}

/// The common body of the tracers' `trace_ids`: sizes `ids` to the camera's viewport, fills it
/// with [`NO_HIT`] and, if camera and scene are usable, lets `draw` write the first-hit ids.
pub(crate) fn trace_ids_with(
    scene: &Scene,
    camera: &Camera,
    ids: &mut Vec<u32>,
    draw: impl FnOnce(&mut [u32]),
) -> bool {
    let mut img = Image { width: 0, height: 0, pixels: std::mem::take(ids) };
    let ok = begin_frame(scene, camera, &mut img);
    *ids = img.pixels;
    ids.fill(NO_HIT);
    if ok {
        draw(ids);
    }
    ok
}

/// Prepares `out` for drawing `scene` from `camera`: resizes and clears it. Returns `false`
/// (after drawing the background, or an empty image for an unusable viewport) if the camera
/// does not validate or the scene is inconsistent.
pub(crate) fn begin_frame(scene: &Scene, camera: &Camera, out: &mut Image) -> bool {
    if let Err(e) = camera.validate(MAX_VIEWPORT) {
        warn_once(&WARNED_CAMERA, &format!("unusable camera: {e}"));
        out.reset_for_unusable(camera, MAX_VIEWPORT);
        return false;
    }
    out.reset_for(camera);
    if let Err(e) = scene.check() {
        warn_once(&WARNED_SCENE, &format!("unusable scene: {e}"));
        return false;
    }
    true
}

/// [`begin_frame`] for a renderer that also draws unbuilt scenes (no nodes: samples and
/// colors of a frame in arrival order, [`crate::route::unbuilt_scene`]).
pub(crate) fn begin_frame_unbuilt_ok(scene: &Scene, camera: &Camera, out: &mut Image) -> bool {
    if !scene.nodes.is_empty() || scene.samples.len() < 2 {
        return begin_frame(scene, camera, out);
    }
    if let Err(e) = camera.validate(MAX_VIEWPORT) {
        warn_once(&WARNED_CAMERA, &format!("unusable camera: {e}"));
        out.reset_for_unusable(camera, MAX_VIEWPORT);
        return false;
    }
    out.reset_for(camera);
    let ok = unbuilt_ok(scene);
    if !ok {
        warn_once(&WARNED_SCENE, "unusable unbuilt scene");
    }
    ok
}

/// [`begin_frame_unbuilt_ok`] for a renderer that writes every pixel of a usable frame: the
/// same checks, but a usable frame's image is only sized ([`Image::size_for`]), not cleared.
pub(crate) fn begin_frame_overwritten(scene: &Scene, camera: &Camera, out: &mut Image) -> bool {
    let usable = camera.validate(MAX_VIEWPORT).is_ok()
        && if scene.nodes.is_empty() && scene.samples.len() >= 2 { unbuilt_ok(scene) } else { scene.check().is_ok() };
    if !usable {
        // Clears, draws the background and warns once, as every renderer does.
        return begin_frame_unbuilt_ok(scene, camera, out);
    }
    out.size_for(camera);
    true
}

/// Whether a scene keeps the scene's rules but the node count (an unbuilt scene has none).
pub(crate) fn unbuilt_ok(scene: &Scene) -> bool {
    let d = &scene.deq;
    scene.colors.len() == scene.samples.len()
        && scene.samples.len() < Scene::MAX_SAMPLES
        && d.min.is_finite()
        && d.step.is_finite()
        && d.radius_unit.is_finite()
}

/// The color a renderer shows for a sample-id pixel.
#[inline(always)]
pub(crate) fn shade(colors: &[u32], prim: u32) -> u32 {
    match colors.get(prim as usize) {
        Some(&c) => over_background(c, BACKGROUND),
        None => BACKGROUND,
    }
}
