//! The minifb window: input to camera, the display loop at display rate, the status title.
//!
//! A window needs a display: on Unix without `DISPLAY` or `WAYLAND_DISPLAY`, or when the window
//! cannot be created, the client stops with [`ClientError::NoDisplay`], which tells the user to
//! run `--headless` instead (no silent fallback: a user asking for a window learns why there
//! is none).

use crate::controls::{Controls, HeldKeys};
use crate::display::{to_0rgb, Display, RateMeter};
use crate::error::ClientError;
use crate::network::View;
use crate::options::Options;
use crate::visual::VisualControls;
use minifb::{Key, KeyRepeat, MouseButton, MouseMode, Window, WindowOptions};
use std::time::{Duration, Instant};
use volwarp_core::renderer::Image;
use volwarp_core::{Camera, Heuristic};

/// How often the title is refreshed.
pub(crate) const TITLE_EVERY: Duration = Duration::from_millis(250);

/// Checks there is a display to open a window on (Unix: `DISPLAY` or `WAYLAND_DISPLAY`).
pub fn check_display() -> Result<(), ClientError> {
    if cfg!(all(unix, not(target_os = "macos"))) {
        let set = |k: &str| std::env::var_os(k).is_some_and(|v| !v.is_empty());
        if !set("DISPLAY") && !set("WAYLAND_DISPLAY") {
            return Err(ClientError::NoDisplay("DISPLAY and WAYLAND_DISPLAY are not set".into()));
        }
    }
    Ok(())
}

/// A window showing RGBA8 images.
pub struct Screen {
    /// The minifb window.
    pub window: Window,
    buf: Vec<u32>,
}

impl Screen {
    /// Opens a resizable window of `width × height`, limited to `fps` updates per second
    /// (0: unlimited).
    pub fn open(title: &str, width: u32, height: u32, fps: u32) -> Result<Screen, ClientError> {
        check_display()?;
        let opts = WindowOptions { resize: true, ..WindowOptions::default() };
        let mut window = Window::new(title, width as usize, height as usize, opts)
            .map_err(|e| ClientError::NoDisplay(format!("cannot open a window ({e})")))?;
        window.set_target_fps(fps as usize);
        Ok(Screen { window, buf: Vec::new() })
    }

    /// Shows `image`.
    pub fn present(&mut self, image: &Image) -> Result<(), ClientError> {
        if image.width == 0 || image.height == 0 {
            self.window.update();
            return Ok(());
        }
        to_0rgb(image, &mut self.buf);
        self.window
            .update_with_buffer(&self.buf, image.width as usize, image.height as usize)
            .map_err(|e| ClientError::Io(format!("cannot update the window: {e}")))
    }

    /// The inner size, at least 1×1.
    pub fn size(&self) -> (u32, u32) {
        let (w, h) = self.window.get_size();
        ((w as u32).clamp(1, 4096), (h as u32).clamp(1, 4096))
    }

    /// Whether the user asked to quit (window closed, Esc or Q).
    pub fn quit(&self) -> bool {
        !self.window.is_open() || self.window.is_key_down(Key::Escape) || self.window.is_key_down(Key::Q)
    }

    /// Number key 0–9 pressed this frame, if any (0: the default renderer, as 1).
    pub fn renderer_key(&self) -> Option<u8> {
        let w = &self.window;
        if w.is_key_pressed(Key::Key0, KeyRepeat::No) || w.is_key_pressed(Key::NumPad0, KeyRepeat::No) {
            return Some(0);
        }
        const KEYS: [(Key, Key); 9] = [
            (Key::Key1, Key::NumPad1),
            (Key::Key2, Key::NumPad2),
            (Key::Key3, Key::NumPad3),
            (Key::Key4, Key::NumPad4),
            (Key::Key5, Key::NumPad5),
            (Key::Key6, Key::NumPad6),
            (Key::Key7, Key::NumPad7),
            (Key::Key8, Key::NumPad8),
            (Key::Key9, Key::NumPad9),
        ];
        KEYS.iter()
            .position(|(a, b)| w.is_key_pressed(*a, KeyRepeat::No) || w.is_key_pressed(*b, KeyRepeat::No))
            .map(|i| i as u8 + 1)
    }
}

/// The next (or previous) heuristic.
pub fn cycle_heuristic(h: Heuristic, back: bool) -> Heuristic {
    let n = Heuristic::ALL.len();
    let i = h.code() as usize;
    Heuristic::ALL[if back { (i + n - 1) % n } else { (i + 1) % n }]
}

/// The window title: display FPS, server FPS, frame age, samples, renderer, heuristic.
pub fn title(
    display_fps: f64,
    server_fps: f64,
    age_ms: Option<f64>,
    samples: usize,
    renderer: &str,
    h: Heuristic,
) -> String {
    let age = age_ms.map_or("-".to_string(), |a| format!("{a:.0} ms"));
    format!(
        "volwarp | display {display_fps:.0} FPS | server {server_fps:.1} FPS | frame age {age} | {samples} samples | {renderer} | {h}"
    )
}

/// The warp levers that are on, for the title: camera prediction, the guard band,
/// warp-sized radii (only where the current renderer can), the frames kept (only where the
/// current renderer uses older frames), watertight slabs (only with a layered renderer), or
/// `no levers`.
pub fn levers(predict: bool, guard: f32, adaptive_radius: bool, frames: usize, watertight: f32) -> String {
    let mut on = Vec::new();
    if predict {
        on.push("predict".to_string());
    }
    if guard > 0.0 {
        on.push(format!("guard {guard}"));
    }
    if adaptive_radius {
        on.push("adapt".to_string());
    }
    if frames > 1 {
        on.push(format!("{frames} frames"));
    }
    if watertight > 0.0 {
        on.push(format!("watertight {watertight}"));
    }
    if on.is_empty() {
        "no levers".into()
    } else {
        on.join(" + ")
    }
}

/// Runs the live window until it is closed (or `--frames` display frames).
pub fn run_live(opts: &Options, display: &mut Display, home: Camera) -> Result<(), ClientError> {
    let fps = opts.fps.unwrap_or(60);
    let mut screen = Screen::open("volwarp", home.width, home.height, fps)?;
    log::info!("window open ({}x{}); --help lists the controls", home.width, home.height);
    let mut controls = Controls::new(home);
    let mut heuristic = opts.heuristic;
    let mut radius_scale = opts.radius_scale;
    let mut meter = RateMeter::default();
    let mut last = Instant::now();
    let mut last_title = last - TITLE_EVERY;
    let mut mouse_prev: Option<(f32, f32)> = None;
    let mut shown_first = false;
    let mut frames = 0u64;
    // The visual-state controls, once the server said it applies edits; the last edit's id and
    // when it was made (until its first frame is shown).
    let mut visual: Option<VisualControls> = None;
    let mut edit_at: Option<(u32, Instant)> = None;
    let mut shots = 0u32;
    let limit = opts.frames.filter(|n| *n > 0).map(u64::from);
    while !screen.quit() && limit.is_none_or(|n| frames < n) {
        let now = Instant::now();
        let dt = now.duration_since(last).as_secs_f32();
        last = now;
        let w = &screen.window;
        // Input.
        match screen.renderer_key() {
            Some(0) => {
                let _ = display.renderers.select(volwarp_core::RendererKind::DEFAULT);
            }
            Some(k) => {
                let _ = display.renderers.select_key(k);
            }
            None => {}
        }
        if w.is_key_pressed(Key::H, KeyRepeat::No) {
            let back = w.is_key_down(Key::LeftShift) || w.is_key_down(Key::RightShift);
            heuristic = cycle_heuristic(heuristic, back);
            log::info!("heuristic: {heuristic}");
        }
        if w.is_key_pressed(Key::LeftBracket, KeyRepeat::Yes) {
            radius_scale = (radius_scale / 1.25).max(0.05);
            log::info!("radius scale: {radius_scale:.2}");
        }
        if w.is_key_pressed(Key::RightBracket, KeyRepeat::Yes) {
            radius_scale = (radius_scale * 1.25).min(16.0);
            log::info!("radius scale: {radius_scale:.2}");
        }
        if w.is_key_pressed(Key::R, KeyRepeat::No) {
            controls.reset();
        }
        if visual.is_none() {
            visual = display.network().visual_state().map(|s| VisualControls::new(&s));
        }
        let shift = w.is_key_down(Key::LeftShift) || w.is_key_down(Key::RightShift);
        let ctrl = w.is_key_down(Key::LeftCtrl) || w.is_key_down(Key::RightCtrl);
        let mut edit = None;
        if let Some(v) = &mut visual {
            if w.is_key_pressed(Key::P, KeyRepeat::No) {
                edit = v.cycle_preset(shift);
            }
            if w.is_key_pressed(Key::O, KeyRepeat::Yes) {
                edit = Some(v.step_opacity(!shift));
            }
            if w.is_key_pressed(Key::C, KeyRepeat::No) {
                edit = Some(v.toggle_crop());
            }
            if w.is_key_pressed(Key::F, KeyRepeat::No) {
                v.cycle_face(shift);
            }
            if w.is_key_pressed(Key::PageUp, KeyRepeat::Yes) {
                edit = Some(v.move_face(1.0));
            }
            if w.is_key_pressed(Key::PageDown, KeyRepeat::Yes) {
                edit = Some(v.move_face(-1.0));
            }
            if w.is_key_pressed(Key::L, KeyRepeat::No) {
                let shown = display.network().visual_state().is_some_and(|s| s.shade);
                edit = Some(v.toggle_shade(shown));
            }
        }
        if w.is_key_pressed(Key::F12, KeyRepeat::No) {
            shots += 1;
            let path = std::path::PathBuf::from(format!("volwarp-shot-{shots}.png"));
            match display.image.save_png(&path) {
                Ok(()) => log::info!("screenshot saved to {}", path.display()),
                Err(e) => log::warn!("cannot save the screenshot {}: {e}", path.display()),
            }
        }
        let mouse = w.get_mouse_pos(MouseMode::Pass);
        if let (Some((x, y)), Some((px, py))) = (mouse, mouse_prev) {
            let (dx, dy) = (x - px, y - py);
            if w.get_mouse_down(MouseButton::Left) && ctrl {
                if let Some(v) = &mut visual {
                    edit = v.window_level_drag(dx, dy, controls.camera.height).or(edit);
                }
            } else if w.get_mouse_down(MouseButton::Left) {
                controls.orbit_pixels(dx, dy);
            } else if w.get_mouse_down(MouseButton::Right) {
                controls.pan_pixels(dx, dy);
            }
        }
        mouse_prev = mouse;
        if let Some((_, sy)) = w.get_scroll_wheel() {
            if sy != 0.0 {
                controls.zoom(sy.signum());
            }
        }
        let held = HeldKeys {
            left: w.is_key_down(Key::Left),
            right: w.is_key_down(Key::Right),
            up: w.is_key_down(Key::Up),
            down: w.is_key_down(Key::Down),
            w: w.is_key_down(Key::W),
            a: w.is_key_down(Key::A),
            s: w.is_key_down(Key::S),
            d: w.is_key_down(Key::D),
            zoom_in: w.is_key_down(Key::Equal) || w.is_key_down(Key::NumPadPlus),
            zoom_out: w.is_key_down(Key::Minus) || w.is_key_down(Key::NumPadMinus),
        };
        controls.keys(dt, &held);
        let (sw, sh) = screen.size();
        if (sw, sh) != (controls.camera.width, controls.camera.height) {
            controls.resize(sw, sh);
        }
        if let Some(e) = edit {
            log::info!("visual edit {}: {}", e.id, visual.as_ref().map_or(String::new(), |v| v.label(e.id)));
            edit_at = Some((e.id, Instant::now()));
            display.network().send_edit(e);
        }
        if let Some(text) = display.network().take_refusal() {
            log::warn!("the server refused the edit: {text}");
        }
        // Draw.
        let view = View { camera: controls.camera, heuristic, radius_scale };
        let report = display.frame(&view);
        if let Some((id, t)) = edit_at.filter(|(id, _)| *id == report.state) {
            log::info!("visual state {id} shown {:.1} ms after the edit", t.elapsed().as_secs_f64() * 1e3);
            edit_at = None;
        }
        screen.present(&display.image)?;
        frames += 1;
        meter.add(1, Instant::now());
        if report.frame_seq != 0 && !shown_first {
            shown_first = true;
            log::info!("window: showing frame {} ({} samples)", report.frame_seq, report.samples);
        }
        display.check()?;
        if last_title.elapsed() >= TITLE_EVERY {
            last_title = Instant::now();
            let server_fps = display.server_fps();
            let t = title(
                meter.rate(last_title),
                server_fps,
                report.age_ms,
                report.samples,
                display.renderers.name(),
                heuristic,
            );
            let (frames_used, watertight) = (display.frames_used(), display.renderers.watertight());
            let l = levers(opts.predict, opts.guard, display.renderers.adaptive_radius(), frames_used, watertight);
            let mut title = match display.network().state().label() {
                Some(link) => format!("{} | {l}", t.replacen("volwarp | ", &format!("volwarp | {link} | "), 1)),
                None => format!("{t} | {l}"),
            };
            if let Some(v) = &visual {
                title = format!("{title} | {}", v.label(report.state));
            }
            screen.window.set_title(&title);
        }
    }
    log::info!("window closed after {frames} display frames");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn heuristics_cycle_both_ways_and_title_has_every_figure() {
        let mut h = Heuristic::Entrance;
        for _ in 0..Heuristic::ALL.len() {
            h = cycle_heuristic(h, false);
        }
        assert_eq!(h, Heuristic::Entrance);
        assert_eq!(cycle_heuristic(Heuristic::Entrance, true), Heuristic::EnExMean);
        let t = title(59.6, 1.5, Some(812.4), 123456, "splat", Heuristic::Gradient);
        for part in ["60 FPS", "1.5 FPS", "812 ms", "123456 samples", "splat", "gradient"] {
            assert!(t.contains(part), "{t}");
        }
        assert_eq!(levers(true, 0.1, true, 1, 0.0), "predict + guard 0.1 + adapt");
        assert_eq!(levers(true, 0.0, true, 4, 1.5), "predict + adapt + 4 frames + watertight 1.5");
        assert_eq!(levers(false, 0.0, false, 1, 0.0), "no levers");
    }
}
