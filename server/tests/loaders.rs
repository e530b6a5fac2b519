//! Volume and transfer-function loaders: round trips and clear errors.

mod common;

use volwarp_core::Vec3;
use volwarp_server::nrrd;
use volwarp_server::volume::{load_volume, LoadOptions, MemoryLimit, VolumeErrorKind, VoxelType};
use volwarp_server::{Dataset, TransferFunction};

fn ramp_i16(n: usize) -> (Vec<i16>, Vec<u8>) {
    let v: Vec<i16> = (0..n).map(|i| (i as i16 * 37) % 1000 - 200).collect();
    let b = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    (v, b)
}

fn expect_normalized(vol: &volwarp_server::Volume, raw: &[f32]) {
    let (lo, hi) = vol.value_range();
    assert_eq!(lo, raw.iter().cloned().fold(f32::INFINITY, f32::min));
    assert_eq!(hi, raw.iter().cloned().fold(f32::NEG_INFINITY, f32::max));
    for (a, &b) in vol.values().iter().zip(raw) {
        assert!((a - (b - lo) / (hi - lo)).abs() < 1e-6);
    }
}

#[test]
fn raw_round_trip_with_dims_from_the_name() {
    let dir = common::temp_dir("raw");
    let (v, b) = ramp_i16(5 * 4 * 3);
    let p = dir.join("thing_5x4x3_int16.raw");
    std::fs::write(&p, &b).unwrap();
    let vol = load_volume(&p, &LoadOptions::default()).unwrap();
    assert_eq!(vol.name, "thing");
    assert_eq!(vol.dims(), [5, 4, 3]);
    assert_eq!(vol.spacing(), Vec3::ONE);
    expect_normalized(&vol, &v.iter().map(|&x| x as f32).collect::<Vec<_>>());

    // Dims, type and spacing from options for a file without them in its name.
    let q = dir.join("plain.dat");
    let f: Vec<f32> = (0..24).map(|i| i as f32 * 0.5).collect();
    std::fs::write(&q, f.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>()).unwrap();
    let opts = LoadOptions {
        dims: Some([2, 3, 4]),
        voxel_type: Some(VoxelType::F32),
        spacing: Some(Vec3::new(1.0, 2.0, 0.5)),
        ..LoadOptions::default()
    };
    let vol = load_volume(&q, &opts).unwrap();
    assert_eq!(vol.extent(), Vec3::new(2.0, 6.0, 2.0));
    expect_normalized(&vol, &f);
}

#[test]
fn loader_errors_name_the_file_and_the_problem() {
    let dir = common::temp_dir("errors");
    let missing = dir.join("nope_4x4x4_uint8.raw");
    let e = load_volume(&missing, &LoadOptions::default()).unwrap_err();
    assert!(matches!(e.kind, VolumeErrorKind::Io(_)));
    assert!(e.to_string().contains("nope_4x4x4_uint8.raw"), "{e}");

    let short = dir.join("short_4x4x4_uint16.raw");
    std::fs::write(&short, [0u8; 100]).unwrap();
    let e = load_volume(&short, &LoadOptions::default()).unwrap_err();
    assert!(matches!(e.kind, VolumeErrorKind::SizeMismatch { expected: 128, actual: 100 }), "{e}");
    assert!(e.to_string().contains("short_4x4x4_uint16.raw") && e.to_string().contains("128"), "{e}");

    let noname = dir.join("volume.raw");
    std::fs::write(&noname, [0u8; 8]).unwrap();
    let e = load_volume(&noname, &LoadOptions::default()).unwrap_err();
    assert!(matches!(e.kind, VolumeErrorKind::BadName(_)), "{e}");

    let badtype = dir.join("v_2x2x2_complex64.raw");
    std::fs::write(&badtype, [0u8; 8]).unwrap();
    let e = load_volume(&badtype, &LoadOptions::default()).unwrap_err();
    assert!(matches!(e.kind, VolumeErrorKind::UnknownType(_)), "{e}");

    // 64 GiB of voxels (70.2 GiB of bricks, 0.5 GiB for a slab of slices, 1.9 GiB of empty-space
    // grids) against a 16 GiB limit: refused before anything is
    // read or allocated, saying what it needs, what there is and how to force it; forced, the
    // load goes on to find the file too short (still before allocating).
    let big = dir.join("big_4096x4096x4096_uint8.raw");
    std::fs::write(&big, [0u8; 8]).unwrap();
    let limited = LoadOptions { memory: MemoryLimit::Bytes(16 << 30), ..LoadOptions::default() };
    let e = load_volume(&big, &limited).unwrap_err();
    let VolumeErrorKind::OutOfMemory { needed, available } = e.kind else { panic!("{e}") };
    assert_eq!(available, Some(16 << 30));
    assert!((72 << 30..73 << 30).contains(&needed), "{needed}");
    let msg = load_volume(&big, &limited).unwrap_err().to_string();
    assert!(
        msg.contains("needs 72.") && msg.contains("16.00 GiB available") && msg.contains("--max-memory none"),
        "{msg}"
    );
    let forced = LoadOptions { memory: MemoryLimit::Unlimited, ..LoadOptions::default() };
    let e = load_volume(&big, &forced).unwrap_err();
    assert!(matches!(e.kind, VolumeErrorKind::SizeMismatch { actual: 8, .. }), "{e}");
    let e = load_volume(&big, &LoadOptions { max_voxels: 1 << 28, ..forced }).unwrap_err();
    assert!(matches!(e.kind, VolumeErrorKind::TooLarge { .. }), "{e}");

    let hdr = dir.join("bad.nrrd");
    std::fs::write(&hdr, b"NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2\nencoding: raw\n\n\0\0\0\0").unwrap();
    let e = load_volume(&hdr, &LoadOptions::default()).unwrap_err();
    assert!(e.to_string().contains("bad.nrrd"), "{e}");

    let trunc = dir.join("trunc.nrrd");
    std::fs::write(&trunc, b"NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n\n\0\0\0").unwrap();
    let e = load_volume(&trunc, &LoadOptions::default()).unwrap_err();
    assert!(matches!(e.kind, VolumeErrorKind::SizeMismatch { expected: 8, actual: 3 }), "{e}");

    let badgz = dir.join("badgz.nrrd");
    std::fs::write(&badgz, b"NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: gzip\n\nnot gzip at all")
        .unwrap();
    let e = load_volume(&badgz, &LoadOptions::default()).unwrap_err();
    assert!(matches!(e.kind, VolumeErrorKind::Decompress(_)), "{e}");

    let e = Dataset::load(dir.join("thing_1x1x1_uint8.raw"), None).unwrap_err();
    assert!(e.to_string().contains("thing_1x1x1_uint8.raw"), "{e}");
}

/// Dims whose product wraps a 64-bit voxel count (4194304³ = 2⁶⁶ wraps to 0) once passed the
/// voxel limit and the size check of an empty data file, and the allocation that followed
/// aborted the process. Each is a clear error now, whatever the limit.
#[test]
fn dims_that_overflow_a_voxel_count_are_refused_before_allocating() {
    let dir = common::temp_dir("overflow");
    let huge = "4194304 4194304 4194304";
    let nhdr = dir.join("wrap.nhdr");
    std::fs::write(dir.join("wrap.raw"), b"").unwrap();
    let header = format!("NRRD0004\ntype: uchar\ndimension: 3\nsizes: {huge}\nencoding: raw\ndata file: wrap.raw\n\n");
    std::fs::write(&nhdr, header).unwrap();
    let attached = dir.join("wrap.nrrd");
    std::fs::write(&attached, format!("NRRD0004\ntype: uchar\ndimension: 3\nsizes: {huge}\nencoding: raw\n\n"))
        .unwrap();
    let gz = dir.join("wrapgz.nrrd");
    std::fs::write(&gz, format!("NRRD0004\ntype: uchar\ndimension: 3\nsizes: {huge}\nencoding: gzip\n\n")).unwrap();
    let raw = dir.join("x_4194304x4194304x4194304_uint8.raw");
    std::fs::write(&raw, b"").unwrap();
    // 2²¹ cubed is 2⁶³ voxels (a count that fits) of 2 bytes: 2⁶⁴ bytes (a size that does not).
    let bytes = dir.join("y_2097152x2097152x2097152_uint16.raw");
    std::fs::write(&bytes, b"").unwrap();
    for limit in [1 << 28, u64::MAX] {
        let opts = LoadOptions { max_voxels: limit, memory: MemoryLimit::Unlimited, ..LoadOptions::default() };
        for p in [&nhdr, &attached, &gz, &raw, &bytes] {
            let e = load_volume(p, &opts).unwrap_err();
            let msg = e.to_string();
            assert!(msg.contains(p.file_name().unwrap().to_str().unwrap()), "{msg}");
            if limit == u64::MAX {
                assert!(matches!(e.kind, VolumeErrorKind::BadGeometry(_)), "{}: {msg}", p.display());
                assert!(msg.contains("2^64"), "{msg}");
            }
        }
        // Dims given as options overflow the same way.
        let forced = LoadOptions { dims: Some([1 << 22; 3]), voxel_type: Some(VoxelType::U8), ..opts.clone() };
        for p in [&nhdr, &raw] {
            assert!(load_volume(p, &forced).is_err(), "{}", p.display());
        }
    }
}

#[test]
fn nrrd_raw_gzip_and_detached_round_trips() {
    let dir = common::temp_dir("nrrd");
    let dims = [6, 5, 4];
    let (v, bytes) = ramp_i16(6 * 5 * 4);
    let raw: Vec<f32> = v.iter().map(|&x| x as f32).collect();
    let spacing = Vec3::new(3.2, 3.2, 1.5);
    for (name, gzip, detached) in [
        ("a.nrrd", false, None),
        ("b.nrrd", true, None),
        ("c.nhdr", false, Some("c.raw")),
        ("d.nhdr", true, Some("d.raw.gz")),
    ] {
        let p = dir.join(name);
        nrrd::write(&p, &bytes, VoxelType::I16, dims, spacing, gzip, detached).unwrap();
        let vol = load_volume(&p, &LoadOptions::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(vol.dims(), dims, "{name}");
        assert_eq!(vol.spacing(), spacing, "{name}");
        expect_normalized(&vol, &raw);
    }
    // A detached header whose data file is missing names that file.
    std::fs::remove_file(dir.join("c.raw")).unwrap();
    let e = load_volume(dir.join("c.nhdr"), &LoadOptions::default()).unwrap_err();
    assert!(e.to_string().contains("c.raw"), "{e}");
}

#[test]
fn bundled_data_loads_with_its_spacing_and_orientation() {
    let ds = Dataset::default_bundled();
    assert_eq!(ds.name, "ct_head_quarter");
    assert_eq!(ds.volume.dims(), [64, 64, 93]);
    assert_eq!(ds.volume.spacing(), Vec3::new(3.2, 3.2, 1.5));
    assert_eq!(ds.volume.value_range(), (0.0, 3926.0));
    // The header flips y and z: stored voxel (i, j, k) is at (i, 63 - j, 92 - k).
    let dir = volwarp_server::dataset::data_dir().unwrap();
    let raw = load_volume(dir.join("ct_head_quarter_64x64x93_int16.raw"), &LoadOptions::default()).unwrap();
    for (i, j, k) in [(0, 0, 0), (10, 20, 30), (63, 1, 92), (31, 40, 7)] {
        assert_eq!(raw.voxel(i, j, k), ds.volume.voxel(i, 63 - j, 92 - k));
    }
    let neghip = Dataset::load(dir.join("neghip_64x64x64_uint8.raw"), None).unwrap();
    assert_eq!(neghip.tf.name, "neghip");
}

#[test]
fn transfer_function_files() {
    let dir = common::temp_dir("tf");
    let j = dir.join("map.json");
    std::fs::write(&j, r#"[{"Name":"Cool","RGBPoints":[0,0,0,1, 100,1,0,0],"Points":[0,0,0.5,0, 100,0.5,0.5,0]}]"#)
        .unwrap();
    let tf = TransferFunction::load(&j, (0.0, 100.0)).unwrap();
    assert_eq!(tf.name, "Cool");
    assert_eq!(tf.lookup(1.0), [1.0, 0.0, 0.0, 0.5]);
    let t = dir.join("map.txt");
    std::fs::write(&t, "# x r g b a\n0 0 0 0 0\n50 1 1 1 1\n").unwrap();
    let tf = TransferFunction::load(&t, (0.0, 100.0)).unwrap();
    assert_eq!(tf.lookup(0.5), [1.0, 1.0, 1.0, 1.0]);
    let bad = dir.join("bad.txt");
    std::fs::write(&bad, "0 1 2\n").unwrap();
    let e = TransferFunction::load(&bad, (0.0, 1.0)).unwrap_err();
    assert!(e.to_string().contains("bad.txt") && e.to_string().contains("line 1"), "{e}");
    assert!(TransferFunction::load(dir.join("missing.json"), (0.0, 1.0)).is_err());
}

/// Raw and gzip NRRD data streamed into bricks across several 8 MiB slabs and brick slabs,
/// x and y mirrored by negative space directions while streaming, z by the whole-volume path:
/// every voxel where the header puts it. Truncated gzip data is a clear error.
#[test]
fn nrrd_streams_slabs_and_mirrors_into_bricks() {
    let dir = common::temp_dir("nrrd-stream");
    let dims = [320u32, 200, 70]; // 8.96 MB of 16-bit voxels: two read slabs, three brick slabs
    let n = dims.iter().product::<u32>() as usize;
    let v: Vec<u16> = (0..n).map(|i| (i.wrapping_mul(2_654_435_761) >> 7) as u16).collect();
    let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    let at = |x: u32, y: u32, z: u32| v[(x + dims[0] * (y + dims[1] * z)) as usize] as f32;
    let (lo, hi) = (*v.iter().min().unwrap() as f32, *v.iter().max().unwrap() as f32);
    let directions = ["(-1,0,0) (0,-1,0) (0,0,1)", "(1,0,0) (0,1,0) (0,0,-1)", "(1,0,0) (0,1,0) (0,0,1)"];
    for (d, flip) in directions.iter().zip([[true, true, false], [false, false, true], [false; 3]]) {
        for gzip in [false, true] {
            let data = if gzip {
                use std::io::Write;
                let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
                e.write_all(&bytes).unwrap();
                e.finish().unwrap()
            } else {
                bytes.clone()
            };
            let header = format!(
                "NRRD0004\ntype: uint16\ndimension: 3\nsizes: {} {} {}\nspace: left-posterior-superior\nspace directions: {d}\nendian: little\nencoding: {}\n\n",
                dims[0],
                dims[1],
                dims[2],
                if gzip { "gzip" } else { "raw" }
            );
            let p = dir.join(format!("v{}{}.nrrd", flip.iter().map(|&f| u8::from(f)).sum::<u8>(), gzip));
            let mut file = header.into_bytes();
            file.extend_from_slice(&data);
            std::fs::write(&p, &file).unwrap();
            let vol = load_volume(&p, &LoadOptions::default()).unwrap_or_else(|e| panic!("{d} {gzip}: {e}"));
            assert_eq!(vol.voxels().type_name(), "u16");
            assert_eq!(vol.value_range(), (lo, hi));
            for (x, y, z) in [(0, 0, 0), (319, 199, 69), (31, 32, 33), (32, 31, 64), (100, 150, 65), (5, 198, 1)] {
                let (sx, sy, sz) = (
                    if flip[0] { dims[0] - 1 - x } else { x },
                    if flip[1] { dims[1] - 1 - y } else { y },
                    if flip[2] { dims[2] - 1 - z } else { z },
                );
                // Stored as read (offset lo) or as codes (offset 0): the same normalized bits.
                let want = (at(sx, sy, sz) - lo) * code(hi - lo);
                assert_eq!(vol.voxel(x, y, z).to_bits(), want.to_bits(), "{d} {gzip} {x},{y},{z}");
            }
            if gzip {
                // The same gzip stream cut short: an error naming the file, no panic.
                let cut = dir.join("cut.nrrd");
                std::fs::write(&cut, &file[..file.len() - data.len() / 2]).unwrap();
                let e = load_volume(&cut, &LoadOptions::default()).unwrap_err();
                assert!(e.to_string().contains("cut.nrrd"), "{e}");
            }
        }
    }
}

/// The normalization scale of a code range (as the loaders compute it: the largest `f32` with
/// `range · scale ≤ 1`).
fn code(range: f32) -> f32 {
    let mut s = (1.0 / range as f64) as f32;
    while range * s > 1.0 {
        s = f32::from_bits(s.to_bits() - 1);
    }
    s
}

/// `space directions` that permute the axes reorder the volume into LPS with each world axis's
/// spacing; a right-anterior-superior `space` mirrors x and y; oblique directions are refused.
#[test]
fn nrrd_permuted_and_ras_directions_reorder_into_lps() {
    let dir = common::temp_dir("nrrd-perm");
    let dims = [4u32, 3, 5];
    let n = dims.iter().product::<u32>() as usize;
    let v: Vec<u8> = (0..n).map(|i| (i * 37 % 251) as u8).collect();
    let write = |name: &str, extra: &str| {
        let p = dir.join(name);
        let mut f = format!("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 4 3 5\n{extra}encoding: raw\n\n").into_bytes();
        f.extend_from_slice(&v);
        std::fs::write(&p, f).unwrap();
        load_volume(&p, &LoadOptions::default())
    };
    // File i runs along +y (spacing 2), j along +x (spacing 1), k along -z (spacing 1.5).
    let vol = write("perm.nrrd", "space directions: (0,2,0) (1,0,0) (0,0,-1.5)\n").unwrap();
    assert_eq!(vol.dims(), [3, 4, 5]);
    assert_eq!(vol.spacing(), Vec3::new(1.0, 2.0, 1.5));
    assert!(vol.source().orientation.contains("(+j, +i, -k)"), "{}", vol.source().orientation);
    let raw = write("plain.nrrd", "").unwrap();
    for (x, y, z) in [(0, 0, 0), (2, 3, 4), (1, 2, 0), (0, 3, 2)] {
        // World (x, y, z) is file (i = y, j = x, k = 4 - z).
        assert_eq!(vol.voxel(x, y, z), raw.voxel(y, x, 4 - z), "{x},{y},{z}");
    }
    // RAS: +i is +R, i.e. -x in LPS; +j is +A, -y.
    let ras = write("ras.nrrd", "space: right-anterior-superior\nspace directions: (1,0,0) (0,1,0) (0,0,1)\n").unwrap();
    assert_eq!(ras.dims(), dims);
    for (x, y, z) in [(0, 0, 0), (3, 2, 4), (1, 0, 2)] {
        assert_eq!(ras.voxel(x, y, z), raw.voxel(3 - x, 2 - y, z), "{x},{y},{z}");
    }
    // Oblique: a clear error naming the file.
    let e = write("oblique.nrrd", "space directions: (0.7,0.7,0) (-0.7,0.7,0) (0,0,1)\n").unwrap_err();
    assert!(e.to_string().contains("oblique") && e.to_string().contains("oblique.nrrd"), "{e}");
}
