//! Live visual edits over the wire (VisualEdit / VisualState, version 4): a crop box sent by a
//! client renders as the same state given at start, a preset by name as its JSON file, an edit
//! alone brings a frame, bad edits get a clear non-closing Error while the connection and the
//! other clients keep being served, and one client's edit does not change another's frames.

mod common;

use common::Client;
use std::path::Path;
use volwarp_core::wire::{
    self, error_code, CameraRequest, Frame, Hello, Message, TfPoints, VisualEdit, VISUAL_EDIT_FIXED_LEN,
};
use volwarp_core::Heuristic;
use volwarp_server::visual::{preset_names, VisualState};
use volwarp_server::{Dataset, Marcher, Server, ServerConfig, TransferFunction};

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(name)
}

fn config() -> ServerConfig {
    ServerConfig { listen: "127.0.0.1:0".parse().unwrap(), threads: 2, ..ServerConfig::default() }
}

/// A server on `ds` started with `start` as `volwarp-server --preset … --crop …` starts one.
fn serve(ds: &Dataset, start: &VisualState) -> volwarp_server::ServerHandle {
    let marcher = Marcher::from_dataset(ds).with_visual(&ds.tf, start).unwrap();
    let tf = start.transfer_function(&ds.tf, ds.volume.value_range()).unwrap();
    Server::with_transfer_function(config(), marcher, &tf).unwrap().with_visual(ds.tf.clone(), start.clone()).spawn()
}

/// Connects asking for live edits and 12-byte frames; returns the client and the start state.
fn live_client(addr: std::net::SocketAddr) -> (Client, wire::VisualState) {
    let mut c = Client::connect(addr);
    c.send(&Message::Hello(Hello::new(wire::CAP_VISUAL)));
    match c.recv() {
        Ok(Message::Hello(h)) => assert!(h.capabilities & wire::CAP_VISUAL != 0, "the server applies edits"),
        other => panic!("expected Hello, got {other:?}"),
    }
    match c.recv() {
        Ok(Message::VisualState(s)) => (c, s),
        other => panic!("expected the start VisualState, got {other:?}"),
    }
}

fn request(seq: u64, m: &Marcher) -> CameraRequest {
    let camera = m.default_camera(64, 56).orbit(30.0, 15.0);
    CameraRequest { seq, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 }
}

fn frame(c: &mut Client) -> Frame {
    match c.recv() {
        Ok(Message::Frame(f)) => f,
        other => panic!("expected a Frame, got {other:?}"),
    }
}

fn same_frame(a: &Frame, b: &Frame) -> bool {
    a.samples == b.samples && a.colors == b.colors && a.segments == b.segments
}

#[test]
fn a_crop_edit_renders_as_the_same_state_given_at_start() {
    let ds = Dataset::load(data("data/ct_head_quarter.nhdr"), None).unwrap();
    let live = serve(&ds, &VisualState::default());
    let cropped = VisualState { crop: [0.1, 0.2, 0.0, 0.9, 0.6, 0.8], ..VisualState::default() };
    let at_start = serve(&ds, &cropped);
    let m = Marcher::from_dataset(&ds);

    let (mut a, start) = live_client(live.local_addr());
    assert_eq!(start.id, 0);
    assert_eq!(start.crop, [0.0, 0.0, 0.0, 1.0, 1.0, 1.0]);
    let names: Vec<&str> = start.presets.iter().map(|n| n.as_str()).collect();
    assert_eq!(names, preset_names().collect::<Vec<_>>(), "the server lists its presets");
    a.send(&Message::CameraRequest(request(1, &m)));
    let whole = frame(&mut a);
    // The edit alone brings a frame: the last camera again, after the new state's VisualState.
    a.send(&Message::VisualEdit(VisualEdit { id: 5, crop: Some(cropped.crop), ..VisualEdit::default() }));
    match a.recv() {
        Ok(Message::VisualState(s)) => {
            assert_eq!((s.id, s.crop), (5, cropped.crop));
        }
        other => panic!("expected VisualState 5, got {other:?}"),
    }
    let cut = frame(&mut a);
    assert!(!same_frame(&whole, &cut), "the crop changed nothing");

    let (mut b, s) = live_client(at_start.local_addr());
    assert_eq!(s.crop, cropped.crop);
    b.send(&Message::CameraRequest(request(1, &m)));
    assert!(same_frame(&cut, &frame(&mut b)), "a crop edit renders unlike the same crop given at start");
    // And as the marcher given the state directly (itself tested against the volume cut in
    // memory in tests/visual.rs).
    let direct = m.with_visual(&ds.tf, &cropped).unwrap().render_frame_layers(&request(1, &m), 1).0;
    assert!(same_frame(&cut, &direct));
    // Back to the start state: the server's own marchers again.
    a.send(&Message::VisualEdit(VisualEdit { id: 6, crop: Some(start.crop), ..VisualEdit::default() }));
    assert!(matches!(a.recv(), Ok(Message::VisualState(s)) if s.id == 6));
    assert!(same_frame(&whole, &frame(&mut a)));
}

#[test]
fn a_preset_by_name_renders_as_its_json_given_at_start() {
    let ds = Dataset::load(data("data/mri_colin27.nrrd"), None).unwrap();
    let server = serve(&ds, &VisualState::default());
    let m = Marcher::from_dataset(&ds);
    let (mut c, _) = live_client(server.local_addr());
    // A camera first; then each edit alone brings a frame of that camera in the new state (an
    // edit and a request sent together may bring two: the last camera's and the request's).
    c.send(&Message::CameraRequest(request(1, &m)));
    frame(&mut c);
    for (i, name) in preset_names().enumerate() {
        let id = 10 + i as u32;
        let edit = VisualEdit { id, preset: wire::preset_name(name), ..VisualEdit::default() };
        c.send(&Message::VisualEdit(edit));
        let state = match c.recv() {
            Ok(Message::VisualState(s)) => s,
            other => panic!("expected VisualState, got {other:?}"),
        };
        assert_eq!((state.id, state.preset.as_str()), (id, name));
        let got = frame(&mut c);
        // `--tf data/presets/NAME.json` with the preset's shading default.
        let file = TransferFunction::load(data(&format!("data/presets/{name}.json")), ds.volume.value_range()).unwrap();
        let shade = VisualState::default().with_preset(Some(name.into()), None).shade;
        assert_eq!(state.shade, shade);
        let reference = Marcher::new(ds.volume.clone(), &file)
            .with_visual(&file, &VisualState { shade, ..VisualState::default() })
            .unwrap();
        let want = reference.render_frame_layers(&request(1, &m), 1).0;
        assert!(same_frame(&got, &want), "preset {name} over the wire renders unlike its JSON file");
    }
}

/// A raw VisualEdit payload with one float overwritten.
fn raw_edit(edit: &VisualEdit, at: usize, v: f32) -> Vec<u8> {
    let mut b = wire::encode_to_vec(&Message::VisualEdit(edit.clone()));
    b[wire::HEADER_LEN + at..wire::HEADER_LEN + at + 4].copy_from_slice(&v.to_le_bytes());
    b
}

fn refused(c: &mut Client, want: &str) {
    match c.recv() {
        Ok(Message::Error(e)) => {
            assert_eq!(e.code, error_code::BAD_EDIT, "{e:?}");
            assert!(e.text.contains(want), "{:?} lacks {want:?}", e.text);
        }
        other => panic!("expected Error BAD_EDIT ({want}), got {other:?}"),
    }
}

#[test]
fn bad_edits_get_clear_errors_and_everyone_keeps_being_served() {
    let ds = Dataset::load(data("data/neghip_64x64x64_uint8.raw"), None).unwrap();
    let server = serve(&ds, &VisualState::default());
    let m = Marcher::from_dataset(&ds);
    let (mut bad, _) = live_client(server.local_addr());
    let (mut other, _) = live_client(server.local_addr());
    other.send(&Message::CameraRequest(request(1, &m)));
    let before = frame(&mut other);

    let wl = VisualEdit { id: 1, window_level: Some([0.5, 0.5]), ..VisualEdit::default() };
    let mut tf = TfPoints::default();
    tf.color.push([0.0, 1.0, 1.0, 1.0]).unwrap();
    tf.opacity.push([0.6, 0.0]).unwrap();
    tf.opacity.push([0.2, 1.0]).unwrap();
    let unsorted = VisualEdit { id: 2, transfer_function: Some(tf), ..VisualEdit::default() };
    let outside = VisualEdit { id: 3, crop: Some([0.0, 0.0, 0.0, 1.0, 1.5, 1.0]), ..VisualEdit::default() };
    let unknown = VisualEdit { id: 4, preset: wire::preset_name("ct-bones"), ..VisualEdit::default() };
    // 65 opacity points: one over the most a message may hold.
    let mut huge = wire::encode_to_vec(&Message::VisualEdit(VisualEdit {
        id: 5,
        transfer_function: Some(TfPoints::default()),
        ..VisualEdit::default()
    }));
    huge[wire::HEADER_LEN + 70] = 65;
    huge.extend(std::iter::repeat_n(0u8, 65 * 8));
    let len = (huge.len() - wire::HEADER_LEN) as u32;
    huge[8..12].copy_from_slice(&len.to_le_bytes());
    assert!(len as usize > VISUAL_EDIT_FIXED_LEN);

    bad.send_raw(&raw_edit(&wl, 8, f32::NAN));
    refused(&mut bad, "NaN");
    bad.send(&Message::VisualEdit(unsorted));
    refused(&mut bad, "not sorted");
    bad.send_raw(&huge);
    refused(&mut bad, "over 64");
    bad.send(&Message::VisualEdit(outside));
    refused(&mut bad, "crop box");
    bad.send(&Message::VisualEdit(unknown));
    refused(&mut bad, "unknown preset");
    bad.send(&Message::VisualEdit(VisualEdit { window_level: Some([0.0, 0.5]), ..wl.clone() }));
    refused(&mut bad, "window");
    // The connection still serves, in the state before the bad edits.
    bad.send(&Message::CameraRequest(request(2, &m)));
    assert!(same_frame(&before, &frame(&mut bad)));
    // A good edit after bad ones applies.
    bad.send(&Message::VisualEdit(wl));
    assert!(matches!(bad.recv(), Ok(Message::VisualState(s)) if s.id == 1 && s.window_level == [0.5, 0.5]));
    let edited = frame(&mut bad);
    assert!(!same_frame(&before, &edited));
    // The other client's frames are not changed by the first one's edit.
    other.send(&Message::CameraRequest(request(3, &m)));
    assert!(same_frame(&before, &frame(&mut other)));
    drop((bad, other));
    // A client that did not ask for edits gets none of the new messages, and one that sends an
    // edit anyway is still answered.
    let mut old = Client::hello(server.local_addr(), None);
    old.send(&Message::CameraRequest(request(4, &m)));
    assert!(same_frame(&before, &frame(&mut old)));
}

/// The occupancy's constant-time visibility test answers as the scan of the table does.
#[test]
fn the_visibility_test_agrees_with_the_table_scan() {
    for name in preset_names() {
        let tf = volwarp_server::visual::preset(name, (0.0, 255.0)).unwrap();
        for tf in [tf.clone(), tf.windowed(0.1, 0.7, 1.0), tf.windowed(0.5, 0.2, 0.0)] {
            let visible = tf.visibility();
            for i in 0..=80 {
                for j in 0..=80 {
                    let (lo, hi) = (i as f32 / 64.0 - 0.1, j as f32 / 64.0 - 0.1);
                    assert_eq!(visible(lo, hi), tf.max_opacity(lo, hi) > 0.0, "{name} {lo} {hi}");
                }
            }
        }
    }
}
