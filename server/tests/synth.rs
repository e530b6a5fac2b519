//! Synthetic volumes (`volwarp_server::synth`, `volwarp-server synth`): deterministic bytes,
//! slices made alone equal to the file's, loadable by path, the content the module promises.

mod common;

use std::path::PathBuf;
use std::process::Command;
use volwarp_server::synth::{synth_fill, synth_slice, synth_value, write_synth, SynthError, SynthType};
use volwarp_server::volume::{load_volume, LoadOptions};
use volwarp_server::Dataset;

const BIN: &str = env!("CARGO_BIN_EXE_volwarp-server");

fn write(dims: [u32; 3], ty: SynthType, dir: &str) -> (PathBuf, Vec<u8>) {
    let path = write_synth(dims, ty, &common::temp_dir(dir)).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    assert_eq!(bytes.len(), dims.iter().product::<u32>() as usize * ty.size());
    (path, bytes)
}

fn values(bytes: &[u8], ty: SynthType) -> Vec<u16> {
    match ty {
        SynthType::U8 => bytes.iter().map(|&b| u16::from(b)).collect(),
        SynthType::U16 => bytes.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect(),
    }
}

#[test]
fn two_writes_give_identical_bytes() {
    for ty in [SynthType::U8, SynthType::U16] {
        let (a, x) = write([24, 20, 16], ty, "synth-det-a");
        let (b, y) = write([24, 20, 16], ty, "synth-det-b");
        assert_ne!(a, b);
        assert_eq!(a.file_name(), b.file_name());
        assert!(x == y, "{ty:?}: two writes differ");
        assert!(x.iter().any(|&v| v != 0));
    }
}

#[test]
fn a_slice_made_alone_equals_its_bytes_in_the_file() {
    for (dims, ty) in [([40, 36, 32], SynthType::U8), ([33, 17, 9], SynthType::U16)] {
        let (_, file) = write(dims, ty, "synth-slice");
        let slice = (dims[0] * dims[1]) as usize * ty.size();
        let mut buf = vec![0u8; slice];
        for k in 0..dims[2] {
            synth_slice(dims, ty, k, &mut buf);
            let at = k as usize * slice;
            assert!(buf == file[at..at + slice], "{dims:?} {ty:?}: slice {k}");
        }
        // Any range, from any voxel, and single voxels.
        let mut part = vec![0u8; 1001 * ty.size()];
        synth_fill(dims, ty, 777, &mut part);
        assert!(part == file[777 * ty.size()..1778 * ty.size()]);
        let v = values(&file, ty);
        let (nx, ny) = (dims[0] as usize, dims[1] as usize);
        for (i, j, k) in [(0, 0, 0), (5, 7, 3), (dims[0] - 1, dims[1] - 1, dims[2] - 1), (20, 8, 4)] {
            let at = i as usize + nx * (j as usize + ny * k as usize);
            assert_eq!(synth_value(i, j, k, dims, ty), v[at], "{dims:?} {ty:?} ({i}, {j}, {k})");
        }
    }
}

#[test]
fn the_file_loads_by_path_with_default_options() {
    let (path, _) = write([48, 40, 32], SynthType::U16, "synth-load");
    assert_eq!(path.file_name().unwrap(), "synth_48x40x32_uint16.raw");
    let v = load_volume(&path, &LoadOptions::default()).unwrap();
    assert_eq!(v.dims(), [48, 40, 32]);
    assert_eq!(v.name, "synth");
    let ds = Dataset::load(&path, None).unwrap();
    assert_eq!(ds.tf.name, "synth");
    assert!(ds.tf.table().iter().any(|e| e[3] > 0.5), "the preset shows surfaces");
}

#[test]
fn odd_dims_work() {
    for ty in [SynthType::U8, SynthType::U16] {
        for dims in [[1, 2, 33], [1, 1, 1], [3, 1, 2], [65, 3, 1]] {
            let (path, bytes) = write(dims, ty, "synth-odd");
            assert_eq!(load_volume(&path, &LoadOptions::default()).unwrap().dims(), dims);
            let v = values(&bytes, ty);
            for (n, &x) in v.iter().enumerate() {
                let n = n as u32;
                let (i, j, k) = (n % dims[0], n / dims[0] % dims[1], n / (dims[0] * dims[1]));
                assert_eq!(synth_value(i, j, k, dims, ty), x, "{dims:?}");
            }
        }
    }
    // One voxel: the centre of the field.
    assert!(synth_value(0, 0, 0, [1, 1, 1], SynthType::U8) > 0);
}

#[test]
fn the_margin_is_empty_and_the_inside_has_surfaces_and_interiors() {
    let n = 64u32;
    let (_, bytes) = write([n; 3], SynthType::U8, "synth-content");
    let in_margin = |i: u32| {
        let u = (i as f64 + 0.5) / n as f64;
        !(0.08..=0.92).contains(&u)
    };
    let (mut zeros, mut high, mut mid) = (0usize, 0usize, 0usize);
    for (at, &b) in bytes.iter().enumerate() {
        let at = at as u32;
        let (i, j, k) = (at % n, at / n % n, at / (n * n));
        if in_margin(i) || in_margin(j) || in_margin(k) {
            assert_eq!(b, 0, "margin voxel ({i}, {j}, {k})");
        }
        zeros += usize::from(b == 0);
        high += usize::from(b >= 230);
        mid += usize::from((64..=120).contains(&b));
    }
    let total = bytes.len();
    assert!(bytes.contains(&255), "surfaces reach full scale");
    assert!(zeros * 2 > total, "mostly empty: {zeros} of {total} zero");
    assert!(high * 200 > total, "surfaces: {high} of {total} voxels >= 230");
    assert!(mid * 20 > total, "interiors: {mid} of {total} voxels in 64..=120");
}

#[test]
fn u16_uses_a_range_wider_than_255() {
    let (_, bytes) = write([32, 32, 32], SynthType::U16, "synth-u16");
    let v = values(&bytes, SynthType::U16);
    let mut distinct = v.clone();
    distinct.sort_unstable();
    distinct.dedup();
    assert_eq!(*distinct.last().unwrap(), u16::MAX);
    assert!(distinct.len() > 1000, "{} distinct values", distinct.len());
    assert!(v.iter().any(|&x| x > 255 && x < 30_000));
}

#[test]
fn bad_requests_are_errors_not_panics() {
    let dir = common::temp_dir("synth-errors");
    let missing = dir.join("missing");
    let e = write_synth([4, 4, 4], SynthType::U8, &missing).unwrap_err();
    assert!(matches!(e, SynthError::OutDir { .. }) && e.to_string().contains("missing"), "{e}");
    let file = dir.join("a-file");
    std::fs::write(&file, b"x").unwrap();
    let e = write_synth([4, 4, 4], SynthType::U8, &file).unwrap_err();
    assert!(e.to_string().contains("not a folder"), "{e}");
    let e = write_synth([4, 0, 4], SynthType::U8, &dir).unwrap_err();
    assert!(matches!(e, SynthError::Dims(_)), "{e}");
    let e = write_synth([u32::MAX; 3], SynthType::U16, &dir).unwrap_err();
    assert!(e.to_string().contains("overflow"), "{e}");
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1, "nothing written");
}

#[test]
fn the_cli_writes_the_file_and_the_server_renders_it() {
    let dir = common::temp_dir("synth-cli");
    let out =
        Command::new(BIN).args(["synth", "--dims", "33,2,5", "--type", "u8", "--out"]).arg(&dir).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let path = dir.join("synth_33x2x5_uint8.raw");
    assert!(String::from_utf8_lossy(&out.stdout).contains(&*path.to_string_lossy()));
    assert_eq!(std::fs::read(&path).unwrap().len(), 33 * 2 * 5);

    let out = Command::new(BIN).args(["synth", "--dims", "24x24x24", "--type", "uint16", "--out"]).arg(&dir).output();
    assert!(out.unwrap().status.success());
    let vol = dir.join("synth_24x24x24_uint16.raw");
    let png = dir.join("s.png");
    let out = Command::new(BIN)
        .args(["render", "--size", "24x24", "--volume"])
        .arg(&vol)
        .arg("--out")
        .arg(&png)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(std::fs::read(&png).unwrap().starts_with(b"\x89PNG"));

    for args in [&["synth", "--dims", "4,4", "--out"][..], &["synth", "--dims", "4,4,4", "--type", "f32", "--out"]] {
        let out = Command::new(BIN).args(args).arg(&dir).output().unwrap();
        assert!(!out.status.success(), "{args:?}");
        assert!(String::from_utf8_lossy(&out.stderr).contains("volwarp-server: "), "{args:?}");
    }
    let out = Command::new(BIN).args(["synth", "--dims", "4,4,4", "--out"]).arg(dir.join("nope")).output().unwrap();
    assert!(String::from_utf8_lossy(&out.stderr).contains("nope"));
}
