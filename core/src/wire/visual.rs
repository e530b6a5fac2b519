//! The live visual state on the wire (version 4): the client's [`VisualEdit`] (type 8) and the
//! server's [`VisualState`] (type 9), documented byte by byte in `docs/wire-format.md`.
//!
//! The codec checks the structure (lengths, flags, UTF-8 names, counts within their bounds) and
//! refuses every non-finite float ([`WireError::BadVisual`]), always after reading the whole
//! payload, so a receiver can refuse the edit and keep reading the stream. What a value means
//! (ranges, sorted points, a known preset, a crop box inside the volume) is the server's to
//! check: it answers a bad edit with an Error of code [`super::error_code::BAD_EDIT`] and keeps
//! the connection.

use super::*;

/// Most control points of each kind (color, opacity) in a transfer-function edit.
pub const MAX_TF_POINTS: usize = 64;
/// Longest preset name, in bytes of UTF-8.
pub const MAX_PRESET_NAME: usize = 32;
/// Most preset names a [`VisualState`] lists.
pub const MAX_PRESETS: usize = 16;
/// Bytes of a VisualEdit before its preset name and points.
pub const VISUAL_EDIT_FIXED_LEN: usize = 72;
/// Largest VisualEdit payload: the fixed part, a longest name, the most points.
pub const VISUAL_EDIT_MAX_LEN: usize = VISUAL_EDIT_FIXED_LEN + MAX_PRESET_NAME + MAX_TF_POINTS * (16 + 8);
/// Bytes of a VisualState before its preset names.
pub const VISUAL_STATE_FIXED_LEN: usize = 68;
/// Largest VisualState payload: the fixed part, its preset's name and the most names listed.
pub const VISUAL_STATE_MAX_LEN: usize = VISUAL_STATE_FIXED_LEN + MAX_PRESET_NAME + MAX_PRESETS * (1 + MAX_PRESET_NAME);

/// A preset's name.
pub type PresetName = heapless::String<MAX_PRESET_NAME>;
/// The preset names a [`VisualState`] lists.
pub type PresetNames = heapless::Vec<PresetName, MAX_PRESETS>;

/// `s` as a preset name; `None` if it is over [`MAX_PRESET_NAME`] bytes.
pub fn preset_name(s: &str) -> Option<PresetName> {
    let mut n = PresetName::new();
    n.push_str(s).ok()?;
    Some(n)
}

/// Field bits of a VisualEdit (byte 4–5).
pub mod edit_field {
    /// Gradient shading on or off.
    pub const SHADE: u16 = 1;
    /// A bundled preset by name.
    pub const PRESET: u16 = 2;
    /// Window and level.
    pub const WINDOW_LEVEL: u16 = 4;
    /// Global opacity scale.
    pub const OPACITY_SCALE: u16 = 8;
    /// Crop box.
    pub const CROP: u16 = 16;
    /// Clip plane (set or removed).
    pub const CLIP: u16 = 32;
    /// A piecewise transfer function (color and opacity points).
    pub const TRANSFER_FUNCTION: u16 = 64;
    /// Every bit a receiver knows.
    pub const ALL: u16 = 127;
}

/// What is wrong with a visual message's structure.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VisualWireError {
    /// A float field the message uses is NaN or infinite.
    NonFinite,
    /// A field bit the receiver does not know.
    UnknownField(u16),
    /// A flag byte other than 0 or 1.
    BadFlag,
    /// The preset name is empty where one is needed, present where none is, over
    /// [`MAX_PRESET_NAME`] bytes or not UTF-8.
    BadName,
    /// Point counts over [`MAX_TF_POINTS`], or points without the transfer-function bit.
    BadPoints,
    /// More than [`MAX_PRESETS`] names.
    TooManyPresets,
}

impl core::fmt::Display for VisualWireError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            VisualWireError::NonFinite => f.write_str("visual edit holds a NaN or infinite number"),
            VisualWireError::UnknownField(b) => write!(f, "visual edit sets unknown field bits {b:#x}"),
            VisualWireError::BadFlag => f.write_str("visual message flag byte is neither 0 nor 1"),
            VisualWireError::BadName => {
                write!(f, "preset name is empty, misplaced, over {MAX_PRESET_NAME} bytes or not UTF-8")
            }
            VisualWireError::BadPoints => {
                write!(f, "transfer-function points: over {MAX_TF_POINTS} of a kind, or sent without the field bit")
            }
            VisualWireError::TooManyPresets => write!(f, "more than {MAX_PRESETS} preset names"),
        }
    }
}

/// A transfer function as ParaView writes one: piecewise-linear color points `(x, r, g, b)` and
/// opacity points `(x, a)`, `x` in fractions of the volume's value range.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct TfPoints {
    /// Color points `[x, r, g, b]`.
    pub color: heapless::Vec<[f32; 4], MAX_TF_POINTS>,
    /// Opacity points `[x, a]`.
    pub opacity: heapless::Vec<[f32; 2], MAX_TF_POINTS>,
}

/// Client to server: change these parts of the visual state (`None`: keep). The server applies
/// it to the next frame and announces the result with a [`VisualState`] of the same `id`.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct VisualEdit {
    /// The id the state after this edit gets (chosen by the client; frames rendered with it
    /// follow the server's VisualState of this id).
    pub id: u32,
    /// Gradient shading.
    pub shade: Option<bool>,
    /// A bundled preset by name (replaces a custom transfer function).
    pub preset: Option<PresetName>,
    /// Window and level, fractions of the value range.
    pub window_level: Option<[f32; 2]>,
    /// Every opacity times this.
    pub opacity_scale: Option<f32>,
    /// Crop box `[x0, y0, z0, x1, y1, z1]`, fractions of the volume box.
    pub crop: Option<[f32; 6]>,
    /// Clip plane `[px, py, pz, nx, ny, nz]` (`Some(None)`: remove the plane).
    pub clip: Option<Option<[f32; 6]>>,
    /// A custom transfer function (replaces the preset).
    pub transfer_function: Option<TfPoints>,
}

/// Server to client: the visual state the frames after this message are rendered with, and the
/// presets the server has. Sent after the server's Hello to a client that announced
/// [`CAP_VISUAL`] (id 0: the state given at start), then after every edit it applied.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct VisualState {
    /// The id of the edit that made this state (0: the server's start state).
    pub id: u32,
    /// Gradient shading.
    pub shade: bool,
    /// The preset shown (empty: the function given at start, or a custom one).
    pub preset: PresetName,
    /// A custom transfer function (sent by a client) is shown.
    pub custom: bool,
    /// Window and level, fractions of the value range.
    pub window_level: [f32; 2],
    /// Opacity scale.
    pub opacity_scale: f32,
    /// Crop box, fractions of the volume box.
    pub crop: [f32; 6],
    /// Clip plane, if any.
    pub clip: Option<[f32; 6]>,
    /// The bundled presets' names.
    pub presets: PresetNames,
}

/// Capability bit (version 4): in a client's Hello, "I send VisualEdits and read VisualStates";
/// in the server's answer, "I apply them" (a VisualState with the start state follows the Hello).
pub const CAP_VISUAL: u32 = 8;

fn put_f32s<const N: usize>(o: &mut Out<N>, v: &[f32]) {
    for x in v {
        o.put(&x.to_le_bytes());
    }
}

fn f32s<const K: usize>(c: &mut Cur) -> [f32; K] {
    core::array::from_fn(|_| c.f32())
}

fn finite(v: &[f32]) -> Result<(), WireError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(WireError::BadVisual(VisualWireError::NonFinite))
    }
}

fn name(b: &[u8]) -> Result<PresetName, WireError> {
    let s = core::str::from_utf8(b).map_err(|_| WireError::BadVisual(VisualWireError::BadName))?;
    let mut n = PresetName::new();
    n.push_str(s).map_err(|_| WireError::BadVisual(VisualWireError::BadName))?;
    Ok(n)
}

impl VisualEdit {
    /// The field bits this edit sets ([`edit_field`]).
    pub fn fields(&self) -> u16 {
        let mut b = 0;
        let mut set = |on: bool, bit: u16| {
            if on {
                b |= bit;
            }
        };
        set(self.shade.is_some(), edit_field::SHADE);
        set(self.preset.is_some(), edit_field::PRESET);
        set(self.window_level.is_some(), edit_field::WINDOW_LEVEL);
        set(self.opacity_scale.is_some(), edit_field::OPACITY_SCALE);
        set(self.crop.is_some(), edit_field::CROP);
        set(self.clip.is_some(), edit_field::CLIP);
        set(self.transfer_function.is_some(), edit_field::TRANSFER_FUNCTION);
        b
    }

    /// Bytes of this edit's payload.
    pub fn encoded_len(&self) -> usize {
        let p = self.preset.as_ref().map_or(0, |s| s.len());
        let (c, o) = self.transfer_function.as_ref().map_or((0, 0), |t| (t.color.len(), t.opacity.len()));
        VISUAL_EDIT_FIXED_LEN + p + 16 * c + 8 * o
    }
}

/// Writes a VisualEdit (type 8).
pub fn write_visual_edit<W: Write>(w: &mut W, e: &VisualEdit) -> Result<(), WireError> {
    let mut o = Out::<VISUAL_EDIT_MAX_LEN>::new();
    o.put(&e.id.to_le_bytes());
    o.put(&e.fields().to_le_bytes());
    o.put(&[u8::from(e.shade == Some(true)), u8::from(matches!(e.clip, Some(Some(_))))]);
    put_f32s(&mut o, &e.window_level.unwrap_or([0.0; 2]));
    put_f32s(&mut o, &[e.opacity_scale.unwrap_or(0.0)]);
    put_f32s(&mut o, &e.crop.unwrap_or([0.0; 6]));
    put_f32s(&mut o, &e.clip.flatten().unwrap_or([0.0; 6]));
    let tf = e.transfer_function.as_ref();
    let name = e.preset.as_ref().map_or(&b""[..], |s| s.as_bytes());
    o.put(&[name.len() as u8, tf.map_or(0, |t| t.color.len() as u8), tf.map_or(0, |t| t.opacity.len() as u8), 0]);
    o.put(name);
    if let Some(t) = tf {
        for p in &t.color {
            put_f32s(&mut o, p);
        }
        for p in &t.opacity {
            put_f32s(&mut o, p);
        }
    }
    write_header(w, MsgType::VisualEdit, o.p as u32)?;
    w.write_all(o.bytes()).map_err(io)
}

/// Reads a VisualEdit payload (after its header). The whole payload is read before any check,
/// so after a [`WireError::BadVisual`] the stream is at the next message.
pub fn read_visual_edit<R: Read>(r: &mut R, h: &Header) -> Result<VisualEdit, WireError> {
    let len = h.len as usize;
    if h.ty != MsgType::VisualEdit || !(VISUAL_EDIT_FIXED_LEN..=VISUAL_EDIT_MAX_LEN).contains(&len) {
        return Err(WireError::BadLength { ty: h.ty, len: h.len });
    }
    let b: [u8; VISUAL_EDIT_MAX_LEN] = read_fixed(r, len)?;
    let mut c = Cur::new(&b[..len]);
    let id = c.u32();
    let fields = c.u16();
    let (shade, has_clip) = (c.u8(), c.u8());
    let window_level: [f32; 2] = f32s(&mut c);
    let opacity = c.f32();
    let crop: [f32; 6] = f32s(&mut c);
    let clip: [f32; 6] = f32s(&mut c);
    let (p, nc, no) = (c.u8() as usize, c.u8() as usize, c.u8() as usize);
    let _reserved = c.u8();
    if VISUAL_EDIT_FIXED_LEN + p + 16 * nc + 8 * no != len {
        return Err(WireError::BadLength { ty: h.ty, len: h.len });
    }
    let bad = |e| Err(WireError::BadVisual(e));
    if fields & !edit_field::ALL != 0 {
        return bad(VisualWireError::UnknownField(fields & !edit_field::ALL));
    }
    if shade > 1 || has_clip > 1 {
        return bad(VisualWireError::BadFlag);
    }
    let on = |bit: u16| fields & bit != 0;
    if (p > 0) != on(edit_field::PRESET) || p > MAX_PRESET_NAME {
        return bad(VisualWireError::BadName);
    }
    if nc > MAX_TF_POINTS || no > MAX_TF_POINTS || (!on(edit_field::TRANSFER_FUNCTION) && nc + no > 0) {
        return bad(VisualWireError::BadPoints);
    }
    let mut e = VisualEdit { id, ..VisualEdit::default() };
    if on(edit_field::SHADE) {
        e.shade = Some(shade == 1);
    }
    if on(edit_field::WINDOW_LEVEL) {
        finite(&window_level)?;
        e.window_level = Some(window_level);
    }
    if on(edit_field::OPACITY_SCALE) {
        finite(&[opacity])?;
        e.opacity_scale = Some(opacity);
    }
    if on(edit_field::CROP) {
        finite(&crop)?;
        e.crop = Some(crop);
    }
    if on(edit_field::CLIP) {
        if has_clip == 1 {
            finite(&clip)?;
        }
        e.clip = Some((has_clip == 1).then_some(clip));
    }
    let rest = &b[VISUAL_EDIT_FIXED_LEN..len];
    if on(edit_field::PRESET) {
        e.preset = Some(name(&rest[..p])?);
    }
    if on(edit_field::TRANSFER_FUNCTION) {
        let mut c = Cur::new(&rest[p..]);
        let mut t = TfPoints::default();
        for _ in 0..nc {
            let q: [f32; 4] = f32s(&mut c);
            finite(&q)?;
            let _ = t.color.push(q);
        }
        for _ in 0..no {
            let q: [f32; 2] = f32s(&mut c);
            finite(&q)?;
            let _ = t.opacity.push(q);
        }
        e.transfer_function = Some(t);
    }
    Ok(e)
}

/// Writes a VisualState (type 9).
pub fn write_visual_state<W: Write>(w: &mut W, s: &VisualState) -> Result<(), WireError> {
    let mut o = Out::<VISUAL_STATE_MAX_LEN>::new();
    o.put(&s.id.to_le_bytes());
    let flags = u8::from(s.clip.is_some()) | (u8::from(s.custom) << 1);
    o.put(&[u8::from(s.shade), flags, s.preset.len() as u8, s.presets.len() as u8]);
    put_f32s(&mut o, &s.window_level);
    put_f32s(&mut o, &[s.opacity_scale]);
    put_f32s(&mut o, &s.crop);
    put_f32s(&mut o, &s.clip.unwrap_or([0.0; 6]));
    o.put(s.preset.as_bytes());
    for n in &s.presets {
        o.put(&[n.len() as u8]);
        o.put(n.as_bytes());
    }
    write_header(w, MsgType::VisualState, o.p as u32)?;
    w.write_all(o.bytes()).map_err(io)
}

/// Reads a VisualState payload (after its header).
pub fn read_visual_state<R: Read>(r: &mut R, h: &Header) -> Result<VisualState, WireError> {
    let len = h.len as usize;
    if h.ty != MsgType::VisualState || !(VISUAL_STATE_FIXED_LEN..=VISUAL_STATE_MAX_LEN).contains(&len) {
        return Err(WireError::BadLength { ty: h.ty, len: h.len });
    }
    let b: [u8; VISUAL_STATE_MAX_LEN] = read_fixed(r, len)?;
    let mut c = Cur::new(&b[..len]);
    let id = c.u32();
    let (shade, flags, p, k) = (c.u8(), c.u8(), c.u8() as usize, c.u8() as usize);
    let window_level: [f32; 2] = f32s(&mut c);
    let opacity_scale = c.f32();
    let crop: [f32; 6] = f32s(&mut c);
    let clip: [f32; 6] = f32s(&mut c);
    let bad = |e| Err(WireError::BadVisual(e));
    if shade > 1 || flags > 3 {
        return bad(VisualWireError::BadFlag);
    }
    if p > MAX_PRESET_NAME || VISUAL_STATE_FIXED_LEN + p > len {
        return Err(WireError::BadLength { ty: h.ty, len: h.len });
    }
    if k > MAX_PRESETS {
        return bad(VisualWireError::TooManyPresets);
    }
    let preset = name(&b[VISUAL_STATE_FIXED_LEN..VISUAL_STATE_FIXED_LEN + p])?;
    let mut at = VISUAL_STATE_FIXED_LEN + p;
    let mut presets = PresetNames::new();
    for _ in 0..k {
        let Some(&n) = b[..len].get(at) else { return Err(WireError::BadLength { ty: h.ty, len: h.len }) };
        let (n, start) = (n as usize, at + 1);
        if n == 0 || n > MAX_PRESET_NAME {
            return bad(VisualWireError::BadName);
        }
        if start + n > len {
            return Err(WireError::BadLength { ty: h.ty, len: h.len });
        }
        let _ = presets.push(name(&b[start..start + n])?);
        at = start + n;
    }
    if at != len {
        return Err(WireError::BadLength { ty: h.ty, len: h.len });
    }
    finite(&window_level)?;
    finite(&[opacity_scale])?;
    finite(&crop)?;
    let clip = if flags & 1 != 0 {
        finite(&clip)?;
        Some(clip)
    } else {
        None
    };
    Ok(VisualState {
        id,
        shade: shade == 1,
        preset,
        custom: flags & 2 != 0,
        window_level,
        opacity_scale,
        crop,
        clip,
        presets,
    })
}
