//! The version-4 visual messages: each round-trips byte for byte, the largest fit the server's
//! request limit, and malformed ones are refused after their whole payload was read (the next
//! message still decodes).

use volwarp_core::wire::{
    self, edit_field, encode_to_vec, preset_name, read_message, Limits, Message, TfPoints, VisualEdit, VisualState,
    VisualWireError, WireError, MAX_PRESETS, MAX_TF_POINTS, VISUAL_EDIT_FIXED_LEN, VISUAL_EDIT_MAX_LEN,
};

fn full_edit() -> VisualEdit {
    let mut tf = TfPoints::default();
    for i in 0..MAX_TF_POINTS {
        let x = i as f32 / (MAX_TF_POINTS - 1) as f32;
        tf.color.push([x, 1.0 - x, 0.5, x]).unwrap();
        tf.opacity.push([x, x * x]).unwrap();
    }
    VisualEdit {
        id: 7,
        shade: Some(true),
        preset: Some(preset_name("a-name-of-exactly-thirty-two-byt").unwrap()),
        window_level: Some([0.4, 0.6]),
        opacity_scale: Some(2.0),
        crop: Some([0.0, 0.1, 0.2, 0.9, 1.0, 0.8]),
        clip: Some(Some([0.5, 0.5, 0.5, 0.0, 0.0, 1.0])),
        transfer_function: Some(tf),
    }
}

fn roundtrip(m: &Message, limits: &Limits) {
    let bytes = encode_to_vec(m);
    let back = read_message(&mut &bytes[..], limits).unwrap();
    assert_eq!(&back, m);
    assert_eq!(encode_to_vec(&back), bytes);
}

#[test]
fn every_edit_round_trips() {
    let limits = Limits::for_requests(4096);
    let full = full_edit();
    assert_eq!(full.encoded_len(), VISUAL_EDIT_MAX_LEN);
    roundtrip(&Message::VisualEdit(full.clone()), &limits);
    // Each field alone, and none.
    roundtrip(&Message::VisualEdit(VisualEdit { id: 1, ..VisualEdit::default() }), &limits);
    let one = [
        VisualEdit { shade: Some(false), ..VisualEdit::default() },
        VisualEdit { preset: full.preset.clone(), ..VisualEdit::default() },
        VisualEdit { window_level: full.window_level, ..VisualEdit::default() },
        VisualEdit { opacity_scale: Some(0.0), ..VisualEdit::default() },
        VisualEdit { crop: full.crop, ..VisualEdit::default() },
        VisualEdit { clip: Some(None), ..VisualEdit::default() },
        VisualEdit { clip: full.clip, ..VisualEdit::default() },
        VisualEdit { transfer_function: Some(TfPoints::default()), ..VisualEdit::default() },
        VisualEdit { transfer_function: full.transfer_function.clone(), ..VisualEdit::default() },
    ];
    for e in one {
        assert_eq!(e.fields().count_ones(), 1, "{e:?}");
        roundtrip(&Message::VisualEdit(e), &limits);
    }
    assert_eq!(full_edit().fields(), edit_field::ALL);
}

#[test]
fn every_state_round_trips() {
    let mut s = VisualState {
        id: 3,
        shade: true,
        preset: preset_name("ct-bone").unwrap(),
        custom: false,
        window_level: [1.0, 0.5],
        opacity_scale: 1.0,
        crop: [0.0, 0.0, 0.0, 1.0, 1.0, 0.5],
        clip: Some([0.5, 0.5, 0.5, 1.0, 0.0, 0.0]),
        presets: Default::default(),
    };
    for i in 0..MAX_PRESETS {
        s.presets.push(preset_name(&format!("{i:0>32}")).unwrap()).unwrap();
    }
    let mut longest = s.clone();
    longest.preset = preset_name(&"p".repeat(32)).unwrap();
    let bytes = encode_to_vec(&Message::VisualState(longest));
    assert_eq!(bytes.len() - wire::HEADER_LEN, wire::VISUAL_STATE_MAX_LEN);
    roundtrip(&Message::VisualState(s.clone()), &Limits::default());
    roundtrip(&Message::VisualState(VisualState::default()), &Limits::default());
    s.clip = None;
    s.custom = true;
    s.preset.clear();
    roundtrip(&Message::VisualState(s), &Limits::default());
}

/// A byte of the payload (after the 12-byte header) overwritten.
fn with(bytes: &[u8], at: usize, v: &[u8]) -> Vec<u8> {
    let mut b = bytes.to_vec();
    b[wire::HEADER_LEN + at..wire::HEADER_LEN + at + v.len()].copy_from_slice(v);
    b
}

#[test]
fn malformed_edits_are_refused_and_the_stream_goes_on() {
    let limits = Limits::for_requests(4096);
    let edit = VisualEdit { id: 2, window_level: Some([0.5, 0.5]), ..VisualEdit::default() };
    let good = encode_to_vec(&Message::VisualEdit(edit.clone()));
    let bye = encode_to_vec(&Message::Bye);
    let cases: [(Vec<u8>, WireError); 4] = [
        (with(&good, 8, &f32::NAN.to_le_bytes()), WireError::BadVisual(VisualWireError::NonFinite)),
        (with(&good, 4, &0x80u16.to_le_bytes()), WireError::BadVisual(VisualWireError::UnknownField(0x80))),
        (with(&good, 6, &[2]), WireError::BadVisual(VisualWireError::BadFlag)),
        // Points without the transfer-function bit.
        (
            {
                let mut e = encode_to_vec(&Message::VisualEdit(VisualEdit {
                    transfer_function: Some(TfPoints {
                        color: Default::default(),
                        opacity: [[0.0, 1.0]].into_iter().collect(),
                    }),
                    ..edit.clone()
                }));
                let f = u16::from_le_bytes([e[16], e[17]]) & !edit_field::TRANSFER_FUNCTION;
                e[16..18].copy_from_slice(&f.to_le_bytes());
                e
            },
            WireError::BadVisual(VisualWireError::BadPoints),
        ),
    ];
    for (bad, want) in cases {
        let mut stream = bad.clone();
        stream.extend_from_slice(&bye);
        let mut r = &stream[..];
        assert_eq!(read_message(&mut r, &limits), Err(want));
        assert_eq!(read_message(&mut r, &limits), Ok(Message::Bye), "the stream is at the next message");
    }
    // A NaN in a field the edit does not set is not looked at.
    let unused = with(&good, 16, &f32::NAN.to_le_bytes());
    assert_eq!(read_message(&mut &unused[..], &limits), Ok(Message::VisualEdit(edit)));
    // Lengths that do not add up, and over the limit, before anything is read.
    let short = {
        let mut b = good[..wire::HEADER_LEN + VISUAL_EDIT_FIXED_LEN].to_vec();
        b[wire::HEADER_LEN + 69] = 1; // one color point promised, none sent
        b
    };
    assert!(matches!(read_message(&mut &short[..], &limits), Err(WireError::BadLength { .. })));
    let mut huge = good.clone();
    huge[8..12].copy_from_slice(&(VISUAL_EDIT_MAX_LEN as u32 + 1).to_le_bytes());
    assert!(matches!(
        read_message(&mut &huge[..], &limits),
        Err(WireError::TooLarge { .. } | WireError::BadLength { .. })
    ));
}
