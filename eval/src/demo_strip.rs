//! The README demo's side-by-side strip: for a few display frames of a recorded
//! client session (`volwarp-client --record`), the truth (the server's marcher for the camera
//! shown), the stale frame (the newest frame as rendered, unwarped, cropped to the display where
//! it has a guard band: what a send-image system shows, except that volwarp asked for a
//! predicted camera, so this column flatters the send-image system) and
//! what volwarp's default drawing showed: for layered frames (the client's default)
//! the layered splatter with hole filling and warp-grown footprints, for one-sample frames the
//! hole-filling sphere splatter with warp-sized radii. The stale frame of a layered frame is its
//! segments composited at the frame's own camera.
//!
//! The rows are display frames whose camera differs from the newest frame's (where warping has
//! work to do), spread evenly over the recording. Each row is scored with ꟻLIP against the truth
//! and the scores go to a CSV file beside the PNG.

use crate::{ErrorBox, Metrics};
use std::path::Path;
use volwarp_core::record::{read_entry, read_magic, Entry};
use volwarp_core::renderer::Renderer;
use volwarp_core::wire::{Frame, Limits};
use volwarp_core::{Camera, Image, RendererKind};
use volwarp_cpu_tracer::layer_splat::LayerOptions;
use volwarp_cpu_tracer::stale_image::nearest;
use volwarp_cpu_tracer::LayerSplat;
use volwarp_server::Marcher;

use crate::session::paths::MAX_RECORDED_VIEWPORT;

/// One row of the strip: the display frame's time and the scores of stale and volwarp.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StripRow {
    /// Seconds since the recording started.
    pub t_s: f64,
    /// Sequence number of the newest frame held then.
    pub frame_seq: u64,
    /// ꟻLIP of the stale frame against the truth.
    pub stale_flip: f64,
    /// ꟻLIP of volwarp's default drawing against the truth.
    pub volwarp_flip: f64,
}

/// A display frame of a record: its time in seconds, its camera, the index of the newest frame.
type Shown = (f64, Camera, usize);

/// The display frames of a record with the newest frame held at each, in order.
fn displayed(record: &Path) -> Result<(Vec<Frame>, Vec<Shown>), ErrorBox> {
    let bytes = std::fs::read(record).map_err(|e| format!("{}: {e}", record.display()))?;
    let mut r: &[u8] = &bytes;
    let bad = |e: volwarp_core::record::RecordError| format!("{}: {e}", record.display());
    read_magic(&mut r).map_err(bad)?;
    let limits = Limits::for_frames(MAX_RECORDED_VIEWPORT);
    let (mut frames, mut shown) = (Vec::new(), Vec::new());
    while let Some(e) = read_entry(&mut r, &limits).map_err(bad)? {
        match e {
            Entry::Frame { frame, .. } => frames.push(frame),
            Entry::Camera { t_us, request } => {
                request
                    .camera
                    .validate(MAX_RECORDED_VIEWPORT)
                    .map_err(|e| format!("{}: camera: {e}", record.display()))?;
                if let Some(i) = frames.len().checked_sub(1) {
                    shown.push((t_us as f64 * 1e-6, request.camera, i));
                }
            }
        }
    }
    Ok((frames, shown))
}

/// The frame as rendered, unwarped, at the display's size: where the client asked for a guard
/// band (the frame is larger than the display), its centre crop; else resized to the display.
/// `stale` is the stale renderer, or for a layered frame the layered splatter without fill
/// (which, drawn for the frame's own camera, composites the frame as rendered).
fn stale_view(stale: &mut dyn Renderer, layered: bool, scene: &volwarp_core::Scene, display: &Camera, out: &mut Image) {
    let fc = scene.header.camera;
    let guard = fc.width > display.width && fc.height > display.height;
    if !guard && !layered {
        stale.render(scene, display, out);
        return;
    }
    let mut full = Image::new(0, 0);
    stale.render(scene, &fc, &mut full);
    out.reset_for(display);
    if full.pixels.is_empty() {
        return; // an unusable frame camera: the background
    }
    if !guard {
        // The layered frame as rendered, resized to the display as the stale renderer resizes.
        let (dw, dh) = (display.width, display.height);
        for y in 0..dh {
            let sy = nearest(y, dh, full.height);
            for x in 0..dw {
                out.pixels[(y * dw + x) as usize] = full.pixels[sy * full.width as usize + nearest(x, dw, full.width)];
            }
        }
        return;
    }
    let (x0, y0) = ((fc.width - display.width) / 2, (fc.height - display.height) / 2);
    let w = display.width as usize;
    for y in 0..display.height {
        let src = ((y + y0) * fc.width + x0) as usize;
        out.pixels[y as usize * w..(y as usize + 1) * w].copy_from_slice(&full.pixels[src..src + w]);
    }
}

/// Writes `out` (PNG: one row per chosen display frame, truth | stale | volwarp) and
/// `out` with the extension `csv` (the scores), for `rows` display frames of `record`;
/// `marcher` renders the truth. Returns the rows.
pub fn write_strip(marcher: &Marcher, record: &Path, rows: usize, out: &Path) -> Result<Vec<StripRow>, ErrorBox> {
    let (frames, shown) = displayed(record)?;
    // Display frames that warp: the camera is not the newest frame's own.
    let warping: Vec<&Shown> =
        shown.iter().filter(|(_, c, i)| *c != frames[*i].header.camera && frames[*i].header.camera.width > 0).collect();
    if warping.is_empty() {
        return Err(
            format!("{}: no display frame warps a received frame (did the camera move?)", record.display()).into()
        );
    }
    let n = rows.clamp(1, warping.len());
    let picks: Vec<&Shown> = (0..n).map(|k| warping[(2 * k + 1) * warping.len() / (2 * n)]).collect();
    let mut stale = volwarp_cpu_tracer::create(RendererKind::Stale, 0).ok_or("no stale renderer")?;
    let mut volwarp = volwarp_cpu_tracer::create(RendererKind::SplatFill, 0).ok_or("no splat-fill renderer")?;
    volwarp.set_adaptive_radius(true);
    let no_fill = LayerOptions { fill: false, ..LayerOptions::DEFAULT };
    let mut stale_layers = LayerSplat::with_options(0, no_fill);
    let mut layers = LayerSplat::new(0);
    layers.set_adaptive_radius(true);
    let mut images: Vec<[Image; 3]> = Vec::new();
    let mut out_rows = Vec::new();
    for &&(t, camera, fi) in &picks {
        let frame = &frames[fi];
        let scene = volwarp_cpu_tracer::build_scene(frame);
        let truth = marcher.render_image(&camera);
        let (mut a, mut b) = (Image::new(0, 0), Image::new(0, 0));
        if frame.segments.is_empty() {
            stale_view(stale.as_mut(), false, &scene, &camera, &mut a);
            volwarp.render(&scene, &camera, &mut b);
        } else {
            stale_view(&mut stale_layers, true, &scene, &camera, &mut a);
            layers.render(&scene, &camera, &mut b);
        }
        let flip = |img: &Image| Metrics::of(&truth, img).map_or(1.0, |m| m.flip);
        out_rows.push(StripRow { t_s: t, frame_seq: frame.header.seq, stale_flip: flip(&a), volwarp_flip: flip(&b) });
        images.push([truth, a, b]);
    }
    let grid: Vec<Vec<&Image>> = images.iter().map(|r| r.iter().collect()).collect();
    crate::image_io::strip(&grid, 4, u32::MAX).save_png(out).map_err(|e| format!("{}: {e:?}", out.display()))?;
    let mut csv = String::from("t_s,frame_seq,stale_flip,volwarp_flip\n");
    for r in &out_rows {
        csv.push_str(&format!("{:.3},{},{:.4},{:.4}\n", r.t_s, r.frame_seq, r.stale_flip, r.volwarp_flip));
    }
    let csv_path = out.with_extension("csv");
    std::fs::write(&csv_path, csv).map_err(|e| format!("{}: {e}", csv_path.display()))?;
    Ok(out_rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use volwarp_core::wire::CameraRequest;
    use volwarp_core::Heuristic;
    use volwarp_server::dataset::Dataset;

    #[test]
    fn the_stale_view_of_a_layered_frame_fits_any_display() {
        let m = Marcher::from_dataset(&Dataset::marschner_lobb(24));
        let fc = m.default_camera(40, 30);
        let req = CameraRequest { seq: 1, camera: fc, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
        let scene = volwarp_cpu_tracer::route::unbuilt_scene(&m.render_frame_layers(&req, 4).0);
        let mut r = LayerSplat::with_options(1, LayerOptions { fill: false, ..LayerOptions::DEFAULT });
        let (mut own, mut out) = (Image::new(0, 0), Image::new(0, 0));
        r.render(&scene, &fc, &mut own);
        assert!(own.pixels.iter().any(|&p| p != volwarp_core::BACKGROUND));
        // The display the frame was rendered for: the frame itself.
        stale_view(&mut r, true, &scene, &fc, &mut out);
        assert!(out == own);
        // Another size (larger, or larger along one axis only): resized, nearest pixel.
        let with = |w: u32, h: u32| Camera { width: w, height: h, ..fc };
        for (w, h) in [(80, 60), (50, 20), (20, 50)] {
            stale_view(&mut r, true, &scene, &with(w, h), &mut out);
            assert_eq!((out.width, out.height), (w, h));
        }
        stale_view(&mut r, true, &scene, &with(80, 60), &mut out);
        for (y, x) in [(0, 0), (7, 13), (29, 39)] {
            assert_eq!(out.pixels[2 * y * 80 + 2 * x], own.pixels[y * 40 + x]);
        }
        // A guard band (the frame larger than the display both ways): its centre crop.
        stale_view(&mut r, true, &scene, &with(20, 10), &mut out);
        assert_eq!(out.pixels[0], own.pixels[10 * 40 + 10]);
        assert_eq!(out.pixels[9 * 20 + 19], own.pixels[19 * 40 + 29]);
    }
}
