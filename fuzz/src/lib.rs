//! Fuzz targets of volwarp (see `docs/fuzzing.md`). The properties live in [`checks`], which
//! the stable proptest mirrors in `core/tests/fuzz_mirror.rs` include unchanged; this crate adds
//! the structured-message generator for `arbitrary`; `volume_checks` (feature `volume`) holds the
//! properties of the server's volume header parsers.
#![deny(missing_docs)]

pub mod checks;
#[cfg(feature = "volume")]
pub mod volume_checks;

use arbitrary::{Result, Unstructured};
use volwarp_core::camera::Camera;
use volwarp_core::heuristics::Heuristic;
use volwarp_core::sample::Bounds;
use volwarp_core::wire::{
    ErrorMsg, Frame, FrameHeader, Hello, Message, PresetName, TfPoints, VisualEdit, VisualState, MAX_PRESETS,
    MAX_PRESET_NAME, MAX_TF_POINTS, MAX_TOKEN,
};
use volwarp_core::Vec3;

/// Any bit pattern, or a small exact value (so that valid messages are common).
fn float(u: &mut Unstructured) -> Result<f32> {
    Ok(if u.arbitrary::<bool>()? { f32::from_bits(u.arbitrary()?) } else { u.int_in_range(-64i32..=64)? as f32 * 0.25 })
}

fn vec3(u: &mut Unstructured) -> Result<Vec3> {
    Ok(Vec3::new(float(u)?, float(u)?, float(u)?))
}

fn dim(u: &mut Unstructured) -> Result<u32> {
    Ok(if u.ratio(1, 8)? { u.arbitrary()? } else { u.int_in_range(0..=80)? })
}

fn camera(u: &mut Unstructured) -> Result<Camera> {
    let fov = if u.arbitrary::<bool>()? { float(u)? } else { u.int_in_range(1..=179)? as f32 };
    Ok(Camera { eye: vec3(u)?, target: vec3(u)?, up: vec3(u)?, fov_y_deg: fov, width: dim(u)?, height: dim(u)? })
}

fn heuristic(u: &mut Unstructured) -> Result<Heuristic> {
    Ok(*u.choose(&Heuristic::ALL)?)
}

/// A structured message from fuzz input: every field arbitrary, floats biased towards values
/// that validate. Frames have up to 300 samples with one color each.
pub fn arb_message(u: &mut Unstructured) -> Result<Message> {
    Ok(match u.int_in_range(0u8..=6)? {
        0 => {
            let n = u.int_in_range(0..=MAX_TOKEN)?;
            let token = u.bytes(n)?;
            let h = Hello { version: u.arbitrary()?, capabilities: u.arbitrary()?, token: Default::default(), layers: 1 };
            Message::Hello(h.with_token(token).map_err(|_| arbitrary::Error::IncorrectFormat)?)
        }
        1 => checks::camera_request(u.arbitrary()?, camera(u)?, heuristic(u)?, float(u)?, u.int_in_range(0u8..=20)?),
        2 => {
            let n = u.int_in_range(0..=300usize)?;
            let mut samples = Vec::with_capacity(n);
            let mut colors = Vec::with_capacity(n);
            for _ in 0..n {
                samples.push(u.arbitrary()?);
                colors.push(u.arbitrary()?);
            }
            let header = FrameHeader {
                seq: u.arbitrary()?,
                camera: camera(u)?,
                heuristic: heuristic(u)?,
                bounds: Bounds::new(vec3(u)?, vec3(u)?),
                radius_unit: float(u)?,
                render_us: u.arbitrary()?,
                level: 0,
                count: n as u32,
            };
            Message::Frame(Frame { header, samples, colors, segments: Vec::new() })
        }
        3 => {
            let code = u.arbitrary()?;
            let text: &str = u.arbitrary()?;
            Message::Error(ErrorMsg::new(code, text))
        }
        5 => Message::VisualEdit(arb_visual_edit(u)?),
        6 => Message::VisualState(arb_visual_state(u)?),
        _ => Message::Bye,
    })
}

fn floats<const N: usize>(u: &mut Unstructured) -> Result<[f32; N]> {
    let mut a = [0.0; N];
    for x in &mut a {
        *x = float(u)?;
    }
    Ok(a)
}

fn preset_name(u: &mut Unstructured) -> Result<PresetName> {
    let mut s: &str = u.arbitrary()?;
    let mut end = s.len().min(MAX_PRESET_NAME);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    s = &s[..end];
    let mut n = PresetName::new();
    let _ = n.push_str(s);
    Ok(n)
}

fn opt<T>(u: &mut Unstructured, f: impl FnOnce(&mut Unstructured) -> Result<T>) -> Result<Option<T>> {
    Ok(if u.arbitrary::<bool>()? { Some(f(u)?) } else { None })
}

/// A structured VisualEdit: any subset of fields, up to the most points of each kind.
pub fn arb_visual_edit(u: &mut Unstructured) -> Result<VisualEdit> {
    Ok(VisualEdit {
        id: u.arbitrary()?,
        shade: opt(u, |u| u.arbitrary())?,
        preset: opt(u, preset_name)?,
        window_level: opt(u, floats::<2>)?,
        opacity_scale: opt(u, float)?,
        crop: opt(u, floats::<6>)?,
        clip: opt(u, |u| opt(u, floats::<6>))?,
        transfer_function: opt(u, |u| {
            let mut t = TfPoints::default();
            for _ in 0..u.int_in_range(0..=MAX_TF_POINTS)? {
                let _ = t.color.push(floats::<4>(u)?);
            }
            for _ in 0..u.int_in_range(0..=MAX_TF_POINTS)? {
                let _ = t.opacity.push(floats::<2>(u)?);
            }
            Ok(t)
        })?,
    })
}

/// A structured VisualState: any fields, up to the most preset names.
pub fn arb_visual_state(u: &mut Unstructured) -> Result<VisualState> {
    let mut presets: volwarp_core::wire::PresetNames = Default::default();
    for _ in 0..u.int_in_range(0..=MAX_PRESETS)? {
        let _ = presets.push(preset_name(u)?);
    }
    Ok(VisualState {
        id: u.arbitrary()?,
        shade: u.arbitrary()?,
        preset: preset_name(u)?,
        custom: u.arbitrary()?,
        window_level: floats::<2>(u)?,
        opacity_scale: float(u)?,
        crop: floats::<6>(u)?,
        clip: opt(u, floats::<6>)?,
        presets,
    })
}
