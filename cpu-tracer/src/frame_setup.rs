//! What every CPU renderer does before it draws: validate the camera and the scene (core's
//! [`Scene::check`]), size and clear the output, and draw the background (with one warning)
//! for anything unusable; and the color a sample-id pixel shows.

use crate::{MAX_VIEWPORT, NO_HIT};
use std::sync::atomic::{AtomicBool, Ordering};
use volwarp_core::renderer::Image;
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
    start_frame(scene, camera, out, false, false)
}

/// [`begin_frame`] for a renderer that also draws unbuilt scenes (no nodes: samples and
/// colors of a frame in arrival order, [`crate::route::unbuilt_scene`]).
pub(crate) fn begin_frame_unbuilt_ok(scene: &Scene, camera: &Camera, out: &mut Image) -> bool {
    start_frame(scene, camera, out, true, false)
}

/// [`begin_frame_unbuilt_ok`] for a renderer that writes every pixel of a usable frame: the
/// same checks, but a usable frame's image is only sized ([`Image::size_for`]), not cleared.
pub(crate) fn begin_frame_overwritten(scene: &Scene, camera: &Camera, out: &mut Image) -> bool {
    start_frame(scene, camera, out, true, true)
}

/// The three above: the camera checked (an unusable one: [`Image::reset_for_unusable`]), the
/// scene checked by core's rules or, if `unbuilt` and it has no nodes and two samples or more,
/// by [`unbuilt_ok`]; the image cleared, or only sized where `overwritten` and both are
/// usable. Each kind of failure warns once.
fn start_frame(scene: &Scene, camera: &Camera, out: &mut Image, unbuilt: bool, overwritten: bool) -> bool {
    if let Err(e) = camera.validate(MAX_VIEWPORT) {
        warn_once(&WARNED_CAMERA, &format!("unusable camera: {e}"));
        out.reset_for_unusable(camera, MAX_VIEWPORT);
        return false;
    }
    let problem = if unbuilt && scene.nodes.is_empty() && scene.samples.len() >= 2 {
        (!unbuilt_ok(scene)).then(|| "unusable unbuilt scene".to_string())
    } else {
        scene.check().err().map(|e| format!("unusable scene: {e}"))
    };
    match problem {
        None if overwritten => out.size_for(camera),
        _ => out.reset_for(camera),
    }
    if let Some(p) = &problem {
        warn_once(&WARNED_SCENE, p);
    }
    problem.is_none()
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

/// The color a renderer shows for a sample-id pixel: the sample's premultiplied color over
/// [`BACKGROUND`] (core's `over_background`, by [`over_background_fast`]).
#[inline(always)]
pub(crate) fn shade(colors: &[u32], prim: u32) -> u32 {
    match colors.get(prim as usize) {
        Some(&c) => over_background_fast(c),
        None => BACKGROUND,
    }
}

/// Per alpha `a`, what core's `over_background(c, BACKGROUND)` adds to `c`'s channels: byte
/// `ch` is `((255 − a)·BACKGROUND[ch] + 127) / 255` for red, green and blue, and 255 for alpha
/// (which saturates the result's alpha to 255).
static BACKGROUND_TERMS: [u32; 256] = {
    let mut t = [0u32; 256];
    let mut a = 0;
    while a < 256 {
        let k = 255 - a as u32;
        let mut v = 0xFF00_0000u32;
        let mut ch = 0;
        while ch < 3 {
            let d = (BACKGROUND >> (8 * ch)) & 0xFF;
            v |= ((k * d + 127) / 255) << (8 * ch);
            ch += 1;
        }
        t[a] = v;
        a += 1;
    }
    t
};

/// `over_background(c, BACKGROUND)` exactly (tested for every alpha and channel value): the
/// per-alpha background term from a table, added to the four bytes with saturation in one
/// 32-bit word (the per-channel multiply and division by 255 depend only on the alpha).
#[inline(always)]
pub(crate) fn over_background_fast(c: u32) -> u32 {
    saturating_add_bytes(c, BACKGROUND_TERMS[(c >> 24) as usize])
}

/// The four bytes of `a` and `b` added, each saturating at 255 (SWAR: the low seven bits of
/// each byte are added without carries between bytes; bit 7 and its carry out are recovered
/// with exclusive-or and majority).
#[inline(always)]
fn saturating_add_bytes(a: u32, b: u32) -> u32 {
    const LOW: u32 = 0x7F7F_7F7F;
    const TOP: u32 = 0x8080_8080;
    let low = (a & LOW) + (b & LOW);
    let top = (a ^ b) & TOP;
    let sum = low ^ top;
    let carry = ((a & b) | (top & low)) & TOP;
    sum | ((carry >> 7) * 0xFF)
}

#[cfg(test)]
mod tests {
    use super::*;
    use volwarp_core::sample::over_background;

    #[test]
    fn the_fast_background_is_core_s_for_every_alpha_and_channel() {
        for a in 0..=255u32 {
            for v in 0..=255u32 {
                // Every channel value against every alpha, in each channel position, with the
                // other channels at the extremes.
                for c in [v | v << 8 | v << 16, v | 255 << 8, v << 8 | 255 << 16, v << 16 | 255, v ^ 0xFF_FF00] {
                    let c = c | a << 24;
                    assert_eq!(over_background_fast(c), over_background(c, BACKGROUND), "{c:#010x}");
                }
            }
        }
        let mut x = 0x1234_5678u32;
        for _ in 0..1_000_000 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            assert_eq!(over_background_fast(x), over_background(x, BACKGROUND), "{x:#010x}");
        }
    }

    #[test]
    fn bytes_add_with_saturation() {
        for a in 0..=255u32 {
            for b in 0..=255u32 {
                let want = (a + b).min(255);
                let got = saturating_add_bytes(a << 8 | b | a << 24, b << 8 | a | b << 24);
                assert_eq!(got, want << 8 | want | want << 24, "{a} + {b}");
            }
        }
    }
}
