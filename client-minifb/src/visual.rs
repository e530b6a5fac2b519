//! The window's visual-state controls: window/level drags, presets, opacity, the crop box and
//! lighting, as [`VisualEdit`]s for the server (wire version 4). Pure functions of the input,
//! tested without a window.
//!
//! Every edit carries the whole state the user wants (preset, window/level, opacity, crop,
//! lighting where set), so edits are idempotent: the network sends the last one again after a
//! reconnect, and a lost or refused edit is repaired by the next.
//!
//! **Latency hiding.** A state change cannot be warped like a camera move. Until the first
//! frame rendered with the newest edit arrives, the window keeps warping the frames of the
//! state it has and says "updating" in its title ([`VisualControls::updating`]); the display
//! never draws frames of two states together (a new state drops the older frames kept for hole
//! filling, `Display::poll_scene`). Measured edit to first frame: `docs/perf.md`, "Live
//! visual edits".

use volwarp_core::wire::{preset_name, VisualEdit, VisualState};

/// Window change per pixel of horizontal drag (a factor: `exp(dx · this)`).
pub const WINDOW_PER_PIXEL: f32 = 0.01;
/// Level change per pixel of vertical drag, in fractions of the value range per window height
/// (drag up: higher level, as in medical viewers).
pub const LEVEL_PER_HEIGHT: f32 = 1.0;
/// Opacity scale factor per key press.
pub const OPACITY_STEP: f32 = 1.25;
/// Crop face move per key press, a fraction of the volume box.
pub const CROP_STEP: f32 = 0.02;
/// The crop box the crop key toggles on: the front half cut away (`y` ≥ 0.5 kept).
pub const DEFAULT_CROP: [f32; 6] = [0.0, 0.5, 0.0, 1.0, 1.0, 1.0];
const WHOLE: [f32; 6] = [0.0, 0.0, 0.0, 1.0, 1.0, 1.0];
/// The crop faces' names, in `crop` order.
pub const FACES: [&str; 6] = ["x min", "y min", "z min", "x max", "y max", "z max"];

/// What the user wants shown, and the edits sent for it.
#[derive(Clone, Debug, PartialEq)]
pub struct VisualControls {
    /// The server's presets.
    pub presets: Vec<String>,
    /// The preset chosen (`None`: the function the server started with).
    pub preset: Option<usize>,
    /// Lighting chosen (`None`: the preset's default).
    pub shade: Option<bool>,
    /// Window and level, fractions of the value range.
    pub window_level: [f32; 2],
    /// Opacity scale.
    pub opacity: f32,
    /// The crop box is on.
    pub crop_on: bool,
    /// The crop box (used while on).
    pub crop: [f32; 6],
    /// The face the crop keys move (index into [`FACES`]).
    pub face: usize,
    next_id: u32,
    /// The id of the last edit made (0: none).
    pub last_id: u32,
}

impl VisualControls {
    /// Controls starting from the server's state.
    pub fn new(server: &VisualState) -> VisualControls {
        let presets: Vec<String> = server.presets.iter().map(|n| n.to_string()).collect();
        let preset = presets.iter().position(|p| *p == server.preset.as_str());
        let crop_on = server.crop != WHOLE;
        VisualControls {
            presets,
            preset,
            shade: None,
            window_level: server.window_level,
            opacity: server.opacity_scale,
            crop_on,
            crop: if crop_on { server.crop } else { DEFAULT_CROP },
            face: 1,
            next_id: server.id.wrapping_add(1).max(1),
            last_id: 0,
        }
    }

    /// The edit of the whole wanted state, with a new id.
    pub fn edit(&mut self) -> VisualEdit {
        let id = self.next_id;
        self.next_id = self.next_id.wrapping_add(1).max(1);
        self.last_id = id;
        VisualEdit {
            id,
            shade: self.shade,
            preset: self.preset.and_then(|i| preset_name(&self.presets[i])),
            window_level: Some(self.window_level),
            opacity_scale: Some(self.opacity),
            crop: Some(if self.crop_on { self.crop } else { WHOLE }),
            clip: None,
            transfer_function: None,
        }
    }

    /// A window/level drag of `(dx, dy)` pixels in a view `height` pixels high: right widens
    /// the window, up raises the level.
    pub fn window_level_drag(&mut self, dx: f32, dy: f32, height: u32) -> Option<VisualEdit> {
        if !(dx.is_finite() && dy.is_finite()) || (dx == 0.0 && dy == 0.0) {
            return None;
        }
        let [w, l] = self.window_level;
        let w = (w * (dx * WINDOW_PER_PIXEL).exp()).clamp(0.01, 4.0);
        let l = (l - dy * LEVEL_PER_HEIGHT / height.max(1) as f32).clamp(-1.0, 2.0);
        self.window_level = [w, l];
        Some(self.edit())
    }

    /// The next (or previous) preset; after the last, the function the server started with.
    pub fn cycle_preset(&mut self, back: bool) -> Option<VisualEdit> {
        let n = self.presets.len();
        if n == 0 {
            return None;
        }
        // Positions 0..n are the presets, n the start function.
        let cur = self.preset.unwrap_or(n);
        let next = if back { (cur + n) % (n + 1) } else { (cur + 1) % (n + 1) };
        self.preset = (next < n).then_some(next);
        self.shade = None;
        self.window_level = [1.0, 0.5];
        Some(self.edit())
    }

    /// Opacity up (or down) one step, within 0.01–100.
    pub fn step_opacity(&mut self, up: bool) -> VisualEdit {
        let f = if up { OPACITY_STEP } else { 1.0 / OPACITY_STEP };
        self.opacity = (self.opacity * f).clamp(0.01, 100.0);
        self.edit()
    }

    /// Crop box on or off.
    pub fn toggle_crop(&mut self) -> VisualEdit {
        self.crop_on = !self.crop_on;
        self.edit()
    }

    /// The next (or previous) face for the crop keys.
    pub fn cycle_face(&mut self, back: bool) {
        self.face = if back { (self.face + 5) % 6 } else { (self.face + 1) % 6 };
    }

    /// Moves the selected face by `steps` × [`CROP_STEP`] (positive: towards the box's max
    /// side), keeping at least one step between opposite faces; turns the crop on.
    pub fn move_face(&mut self, steps: f32) -> VisualEdit {
        let f = self.face;
        let (axis, is_max) = (f % 3, f >= 3);
        let v = self.crop[f] + steps * CROP_STEP;
        self.crop[f] = if is_max {
            v.clamp(self.crop[axis] + CROP_STEP, 1.0)
        } else {
            v.clamp(0.0, self.crop[axis + 3] - CROP_STEP)
        };
        self.crop_on = true;
        self.edit()
    }

    /// Lighting on or off.
    pub fn toggle_shade(&mut self, shown: bool) -> VisualEdit {
        self.shade = Some(!self.shade.unwrap_or(shown));
        self.edit()
    }

    /// Whether an edit is still waiting for its first frame (`shown`: the state id of the
    /// frame on screen).
    pub fn updating(&self, shown: u32) -> bool {
        self.last_id != 0 && shown != self.last_id
    }

    /// The title's part: preset, window/level, opacity, crop, and "updating…" while the frame
    /// of the newest edit has not arrived.
    pub fn label(&self, shown: u32) -> String {
        let tf = self.preset.map_or("start function", |i| self.presets[i].as_str());
        let [w, l] = self.window_level;
        let mut s = format!("{tf} | W {w:.2} L {l:.2}");
        if self.opacity != 1.0 {
            s.push_str(&format!(" | opacity {:.2}", self.opacity));
        }
        if self.crop_on {
            s.push_str(&format!(" | crop ({} face)", FACES[self.face]));
        }
        if self.updating(shown) {
            s.push_str(" | updating…");
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn server() -> VisualState {
        let mut s = VisualState { window_level: [1.0, 0.5], opacity_scale: 1.0, crop: WHOLE, ..VisualState::default() };
        for n in ["grey", "ct-bone", "mr-default"] {
            s.presets.push(preset_name(n).unwrap()).unwrap();
        }
        s
    }

    #[test]
    fn drags_and_keys_make_whole_state_edits_with_new_ids() {
        let mut c = VisualControls::new(&server());
        assert!(!c.updating(0));
        let e = c.window_level_drag(50.0, -24.0, 240).unwrap();
        assert_eq!(e.id, 1);
        let [w, l] = e.window_level.unwrap();
        assert!(w > 1.0 && (l - 0.6).abs() < 1e-6, "{w} {l}");
        assert_eq!((e.crop, e.opacity_scale, e.preset.clone()), (Some(WHOLE), Some(1.0), None));
        assert!(c.updating(0) && !c.updating(1));
        assert!(c.window_level_drag(0.0, 0.0, 240).is_none());
        assert!(c.window_level_drag(f32::NAN, 1.0, 240).is_none());
        // Presets cycle through the server's list and back to the start function.
        let names: Vec<Option<String>> =
            (0..4).map(|_| c.cycle_preset(false).unwrap().preset.map(|p| p.to_string())).collect();
        assert_eq!(names, [Some("grey".into()), Some("ct-bone".into()), Some("mr-default".into()), None]);
        assert_eq!(c.cycle_preset(true).unwrap().preset.unwrap().as_str(), "mr-default");
        assert_eq!(c.window_level, [1.0, 0.5], "a preset starts from its whole range");
        assert!(c.step_opacity(true).opacity_scale.unwrap() > 1.0);
        // The crop box: on, a face moved, never inverted.
        assert_eq!(c.toggle_crop().crop, Some(DEFAULT_CROP));
        c.face = 1;
        for _ in 0..100 {
            c.move_face(1.0);
        }
        let e = c.move_face(1.0);
        let crop = e.crop.unwrap();
        assert!(crop[1] < crop[4] && crop[4] <= 1.0, "{crop:?}");
        assert_eq!(c.toggle_crop().crop, Some(WHOLE));
        assert_eq!(c.toggle_shade(true).shade, Some(false));
        let last = c.last_id;
        assert!(c.label(0).contains("updating"));
        assert!(!c.label(last).contains("updating"));
        assert!(c.label(last).contains("mr-default | W 1.00 L 0.50"), "{}", c.label(last));
    }
}
