//! The visual state: a crop renders as the volume cut in memory, a preset as its JSON file,
//! window/level and opacity scale change the image as they should, crop and clip cut the
//! empty-space traversal without changing the image, bad values get clear errors.

use std::path::Path;
use std::sync::Arc;
use volwarp_core::{Camera, Image, Vec3};
use volwarp_server::marcher::Cut;
use volwarp_server::visual::{VisualState, PRESETS};
use volwarp_server::{Dataset, MarchOptions, Marcher, TransferFunction, Volume};

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(name)
}

/// The share of pixels equal and the largest channel difference of two images.
fn compare(a: &Image, b: &Image) -> (f64, u8) {
    assert_eq!((a.width, a.height), (b.width, b.height));
    let mut same = 0;
    let mut max = 0u8;
    for (p, q) in a.pixels.iter().zip(&b.pixels) {
        same += usize::from(p == q);
        for (x, y) in p.to_le_bytes().into_iter().zip(q.to_le_bytes()) {
            max = max.max(x.abs_diff(y));
        }
    }
    (same as f64 / a.pixels.len() as f64, max)
}

/// The CT head's normalized values with the global minimum and maximum forced into the crop
/// (so the full and the cut volume normalize alike), the full volume and the cut one.
fn head_and_cut(i0: [u32; 3], i1: [u32; 3]) -> (Volume, Volume) {
    let ds = Dataset::load(data("data/ct_head_quarter.nhdr"), None).unwrap();
    let v = &ds.volume;
    let [nx, ny, nz] = v.dims();
    let idx = |x: u32, y: u32, z: u32| (x + nx * (y + ny * z)) as usize;
    let mut values = Vec::with_capacity((nx * ny * nz) as usize);
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                values.push(v.voxel(x, y, z));
            }
        }
    }
    values[idx(i0[0], i0[1], i0[2])] = 0.0;
    values[idx(i1[0], i1[1], i1[2])] = 1.0;
    let full = Volume::from_values("ct_head", [nx, ny, nz], v.spacing(), values.clone()).unwrap();
    let d = [i1[0] - i0[0] + 1, i1[1] - i0[1] + 1, i1[2] - i0[2] + 1];
    let mut cut = Vec::new();
    for z in i0[2]..=i1[2] {
        for y in i0[1]..=i1[1] {
            for x in i0[0]..=i1[0] {
                cut.push(values[idx(x, y, z)]);
            }
        }
    }
    let cut = Volume::from_values("ct_head", d, v.spacing(), cut).unwrap();
    (full, cut)
}

#[test]
fn a_crop_renders_as_the_volume_cut_in_memory() {
    let (i0, i1) = ([9, 14, 20], [50, 63, 70]);
    let (full, cut) = head_and_cut(i0, i1);
    let sp = full.spacing();
    let lo = Vec3::new(i0[0] as f32, i0[1] as f32, i0[2] as f32) * sp;
    let hi = (Vec3::new(i1[0] as f32, i1[1] as f32, i1[2] as f32) + 1.0) * sp;
    let tf = TransferFunction::preset("ct_head");
    for shading in [None, Some(volwarp_server::marcher::Shading::DEFAULT)] {
        let opts = MarchOptions { shading, ..MarchOptions::default() };
        let cropped = Marcher::with_options(Arc::new(full.clone()), &tf, opts).with_cut(Cut::new(lo, hi, None));
        let reference = Marcher::with_options(Arc::new(cut.clone()), &tf, opts);
        let base = cropped.default_camera(96, 80);
        for (yaw, pitch) in [(0.0, 0.0), (35.0, 20.0), (-120.0, -30.0), (90.0, 60.0)] {
            let cam = base.orbit(yaw, pitch);
            // The same rays, the cut volume's box moved to the crop's place.
            let moved = Camera { eye: cam.eye - lo, target: cam.target - lo, ..cam };
            let a = cropped.render_image(&cam);
            let b = reference.render_image(&moved);
            let (same, max) = compare(&a, &b);
            let lit = a.pixels.iter().filter(|&&p| p != a.pixels[0]).count();
            assert!(lit > 500, "{yaw},{pitch}: the crop shows nothing");
            assert!(same >= 0.999 && max <= 2, "{shading:?} {yaw},{pitch}: {same:.4} equal, max channel {max}");
            eprintln!("{shading:?} {yaw},{pitch}: crop against the cut volume: {same:.4} equal, max channel {max}");
            // And differs from the uncropped volume.
            let whole = Marcher::with_options(Arc::new(full.clone()), &tf, opts).render_image(&cam);
            assert!(compare(&a, &whole).0 < 0.99, "{yaw},{pitch}: the crop changed little");
        }
    }
}

#[test]
fn crop_and_clip_skipping_changes_no_image() {
    let ds = Dataset::load(data("data/mri_colin27.nrrd"), None).unwrap();
    let state = VisualState {
        crop: [0.1, 0.2, 0.05, 0.8, 0.7, 0.9],
        clip: Some([0.5, 0.5, 0.5, 0.3, 1.0, -0.2]),
        shade: true,
        ..VisualState::default()
    };
    let skip = Marcher::from_dataset(&ds).with_visual(&ds.tf, &state).unwrap();
    let plain =
        Marcher::with_options(ds.volume.clone(), &ds.tf, MarchOptions { skip_empty: false, ..MarchOptions::default() })
            .with_visual(&ds.tf, &state)
            .unwrap();
    assert!(skip.occupancy().fraction_occupied() < Marcher::from_dataset(&ds).occupancy().fraction_occupied());
    for (yaw, pitch) in [(0.0, 0.0), (60.0, 10.0), (200.0, -40.0)] {
        let cam = skip.default_camera(64, 64).orbit(yaw, pitch);
        assert!(skip.render_image(&cam).pixels == plain.render_image(&cam).pixels, "{yaw},{pitch}");
    }
    // The clip plane removes what lies on its back side.
    let unclipped =
        Marcher::from_dataset(&ds).with_visual(&ds.tf, &VisualState { clip: None, ..state.clone() }).unwrap();
    let cam = skip.default_camera(64, 64);
    assert_ne!(skip.render_image(&cam).pixels, unclipped.render_image(&cam).pixels);
}

#[test]
fn a_preset_renders_as_its_json_file() {
    let ds = Dataset::load(data("data/mri_colin27.nrrd"), None).unwrap();
    for (name, _, _) in PRESETS {
        let file = data(&format!("data/presets/{name}.json"));
        let from_file = TransferFunction::load(&file, ds.volume.value_range()).unwrap();
        for shade in [false, true] {
            let state = VisualState { preset: Some(name.to_string()), shade, ..VisualState::default() };
            let a = Marcher::from_dataset(&ds).with_visual(&ds.tf, &state).unwrap();
            let b = Marcher::new(ds.volume.clone(), &from_file)
                .with_visual(&from_file, &VisualState { shade, ..VisualState::default() })
                .unwrap();
            let cam = a.default_camera(48, 48).orbit(20.0, 10.0);
            let img = a.render_image(&cam);
            assert!(img.pixels == b.render_image(&cam).pixels, "{name} shade {shade}");
            assert!(img.pixels.iter().any(|&p| p != img.pixels[0]), "{name}: an empty image");
        }
    }
}

#[test]
fn window_level_and_opacity_scale_change_the_image_as_they_should() {
    let ds = Dataset::load(data("data/ct_head_quarter.nhdr"), None).unwrap();
    let m = Marcher::from_dataset(&ds);
    let cam = m.default_camera(48, 48);
    let render = |s: VisualState| m.with_visual(&ds.tf, &s).unwrap().render_image(&cam);
    let base = render(VisualState::default());
    assert!(base.pixels == m.render_image(&cam).pixels, "the default state changes the image");
    let coverage = |img: &Image| img.pixels.iter().filter(|&&p| p != img.pixels[0]).count();
    // Fading: fewer opaque pixels; a narrower window around a higher level hides soft tissue.
    let faded = render(VisualState { opacity_scale: 0.2, ..VisualState::default() });
    assert_ne!(faded.pixels, base.pixels);
    let bone = render(VisualState { window: 0.5, level: 0.6, ..VisualState::default() });
    assert!(coverage(&bone) < coverage(&base), "{} vs {}", coverage(&bone), coverage(&base));
    let zero = render(VisualState { opacity_scale: 0.0, ..VisualState::default() });
    assert_eq!(coverage(&zero), 0);
}

#[test]
fn bad_states_are_refused_by_the_marcher() {
    let ds = Dataset::load(data("data/neghip_64x64x64_uint8.raw"), None).unwrap();
    let m = Marcher::from_dataset(&ds);
    for (s, want) in [
        (VisualState { window: f32::NAN, ..VisualState::default() }, "window"),
        (VisualState { crop: [0.0, 0.0, 0.0, 1.0, 1.2, 1.0], ..VisualState::default() }, "crop box"),
        (VisualState { preset: Some("ct-bones".into()), ..VisualState::default() }, "unknown preset"),
        (VisualState { clip: Some([0.5, 0.5, 0.5, 0.0, 0.0, 0.0]), ..VisualState::default() }, "normal"),
    ] {
        let e = m.with_visual(&ds.tf, &s).unwrap_err().to_string();
        assert!(e.contains(want), "{e:?}");
    }
}

/// What the server makes for a live edit (`Marcher::with_visual` of the marcher showing the
/// state before: its tables and occupancy rebuilt, the distance sweeps of `empty_space`)
/// renders the frame of a marcher built from scratch for that state (its own min/max grid),
/// and of one that skips no empty space: window/level drags, an opacity fade and a crop, shaded and not.
#[test]
fn an_edits_rebuild_renders_the_full_builds_frame() {
    let ds = Dataset::load(data("data/mri_colin27.nrrd"), None).unwrap();
    let before = Marcher::from_dataset(&ds)
        .with_visual(&ds.tf, &VisualState { window: 0.9, level: 0.5, ..VisualState::default() })
        .unwrap();
    let plain_opts = MarchOptions { skip_empty: false, ..MarchOptions::default() };
    let states = [
        VisualState { window: 0.8, level: 0.45, ..VisualState::default() },
        VisualState { window: 0.3, level: 0.62, shade: true, ..VisualState::default() },
        VisualState { opacity_scale: 0.4, crop: [0.0, 0.3, 0.1, 1.0, 0.9, 1.0], ..VisualState::default() },
    ];
    for state in states {
        let edited = before.with_visual(&ds.tf, &state).unwrap();
        let tf = state.transfer_function(&ds.tf, ds.volume.value_range()).unwrap();
        // From scratch: a new min/max grid, the state's function, shading and cut.
        let shading = state.shade.then_some(volwarp_server::marcher::Shading::DEFAULT);
        let opts = MarchOptions { shading, ..MarchOptions::default() };
        let fresh = Marcher::with_options(ds.volume.clone(), &tf, opts).with_cut(state.cut(&ds.volume));
        let plain = Marcher::with_options(ds.volume.clone(), &tf, MarchOptions { shading, ..plain_opts })
            .with_cut(state.cut(&ds.volume));
        assert!(edited.occupancy().fraction_occupied() < 1.0, "{state:?}: nothing to skip");
        assert_eq!(edited.occupancy().distances(), fresh.occupancy().distances(), "{state:?}");
        for (yaw, pitch) in [(0.0, 0.0), (70.0, 15.0), (210.0, -35.0)] {
            let cam = edited.default_camera(64, 64).orbit(yaw, pitch);
            let img = edited.render_image(&cam);
            assert!(img.pixels.iter().any(|&p| p != img.pixels[0]), "{state:?}: an empty image");
            assert!(img.pixels == fresh.render_image(&cam).pixels, "{state:?} {yaw},{pitch}: against a fresh build");
            assert!(img.pixels == plain.render_image(&cam).pixels, "{state:?} {yaw},{pitch}: against no skipping");
        }
    }
}
