//! `--headless`: a scripted camera path instead of a window. Waits for the first frame, then
//! orbits the home view by `--orbit` degrees over `--frames` display frames, writing each as
//! `frame_NNNNN.png` and one line per frame to `timings.csv`.

use crate::display::{Display, FrameReport};
use crate::error::ClientError;
use crate::network::View;
use crate::options::Options;
use std::fmt::Write as _;
use std::time::{Duration, Instant};
use volwarp_core::Camera;

/// The header of `timings.csv`.
pub const CSV_HEADER: &str =
    "frame,display_ms,frame_age_ms,samples,renderer,render_ms,frame_seq,new_frame,during_build";

/// The PNG file name of display frame `i`.
pub fn frame_file(i: usize) -> String {
    format!("frame_{i:05}.png")
}

/// One CSV line.
pub fn csv_line(csv: &mut String, i: usize, display_ms: f64, r: &FrameReport, renderer: &str) {
    let age = r.age_ms.map(|a| format!("{a:.2}")).unwrap_or_default();
    let _ = writeln!(
        csv,
        "{i},{display_ms:.3},{age},{},{renderer},{:.3},{},{},{}",
        r.samples,
        r.render_ms,
        r.frame_seq,
        u8::from(r.new_frame),
        u8::from(r.during_build)
    );
}

/// The camera of display frame `i` of `n` on the scripted orbit.
pub fn scripted_camera(home: &Camera, orbit_deg: f32, i: u32, n: u32) -> Camera {
    let f = if n > 1 { i as f32 / (n - 1) as f32 } else { 0.0 };
    home.orbit(orbit_deg * f, 0.0)
}

/// Runs the headless path.
pub fn run(opts: &Options, display: &mut Display, home: Camera) -> Result<(), ClientError> {
    let out = opts.out.as_deref().ok_or_else(|| ClientError::Usage("--headless needs --out DIR".into()))?;
    std::fs::create_dir_all(out).map_err(|e| ClientError::Io(format!("cannot create {}: {e}", out.display())))?;
    let n = opts.frames.unwrap_or(60);
    let pace = opts.fps.filter(|f| *f > 0).map(|f| Duration::from_secs_f64(1.0 / f as f64));
    log::info!("headless: waiting for the first frame");
    let first = View { camera: home, heuristic: opts.heuristic, radius_scale: opts.radius_scale };
    display.wait_first_scene(&first, Duration::from_secs(opts.timeout_s))?;
    let mut csv = String::from(CSV_HEADER);
    csv.push('\n');
    let t_start = Instant::now();
    for i in 0..n {
        let t0 = Instant::now();
        let view = View {
            camera: scripted_camera(&home, opts.orbit, i, n),
            heuristic: opts.heuristic,
            radius_scale: opts.radius_scale,
        };
        let report = display.frame(&view);
        let display_ms = t0.elapsed().as_secs_f64() * 1e3;
        display.check()?;
        display.image.save_png(&out.join(frame_file(i as usize))).map_err(|e| ClientError::Io(e.to_string()))?;
        csv_line(&mut csv, i as usize, display_ms, &report, display.renderers.name());
        if let Some(p) = pace {
            let next = t_start + p * (i + 1);
            std::thread::sleep(next.saturating_duration_since(Instant::now()));
        }
    }
    let path = out.join("timings.csv");
    std::fs::write(&path, csv).map_err(|e| ClientError::Io(format!("cannot write {}: {e}", path.display())))?;
    log::info!(
        "headless: {n} frames in {} ({} server frames received, {} built)",
        out.display(),
        display.network().frames_received(),
        display.network().scenes_built()
    );
    Ok(())
}
