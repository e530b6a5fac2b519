//! The volume formats beyond raw and NRRD: one volume written in every format loads to the same
//! voxels and spacing; orientations, scaling and compression; clear errors naming the file.
//! Every test file is written here (hand-built headers or the formats' own encoders).

use std::path::{Path, PathBuf};
use volwarp_core::Vec3;
use volwarp_server::volume::{load_volume, nifti, nrrd, LoadOptions, Volume, VolumeError, VolumeErrorKind, VoxelType};

const DIMS: [u32; 3] = [7, 5, 3];
const SPACING: Vec3 = Vec3::new(0.5, 1.0, 2.0);

fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("volwarp-formats-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The 7×5×3 i16 ramp every format stores, LPS order, x fastest.
fn ramp() -> Vec<i16> {
    let mut v = Vec::new();
    for z in 0..DIMS[2] as i16 {
        for y in 0..DIMS[1] as i16 {
            for x in 0..DIMS[0] as i16 {
                v.push(x * 3 + y * 29 + z * 211 - 300);
            }
        }
    }
    v
}

fn at(v: &[i16], x: usize, y: usize, z: usize) -> i16 {
    v[(z * DIMS[1] as usize + y) * DIMS[0] as usize + x]
}

fn le(v: &[i16]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// The reference: the ramp as a volume.
fn reference() -> Volume {
    Volume::from_values("ramp", DIMS, SPACING, ramp().iter().map(|&x| x as f32).collect()).unwrap()
}

fn assert_same(v: &Volume, r: &Volume, what: &str) {
    assert_eq!(v.dims(), r.dims(), "{what}: dims");
    assert_eq!(v.spacing(), r.spacing(), "{what}: spacing");
    assert_eq!(v.value_range(), r.value_range(), "{what}: value range");
    assert!(v.data() == r.data(), "{what}: voxels differ");
}

fn load(p: &Path) -> Volume {
    load_volume(p, &LoadOptions::default()).unwrap_or_else(|e| panic!("{e}"))
}

fn load_err(p: &Path) -> VolumeError {
    let e = load_volume(p, &LoadOptions::default()).err().unwrap_or_else(|| panic!("{} loaded", p.display()));
    assert_eq!(e.path.as_deref().and_then(|q| q.file_name()), p.file_name(), "error names the file: {e}");
    e
}

/// The LPS-ordered ramp as a NIfTI file: RAS sform diag(-0.5, -1, 2) is LPS diag(0.5, 1, 2).
fn nifti_lps(p: &Path, version: u8, gzip: bool) {
    let o = nifti::WriteOptions {
        version,
        pixdim: SPACING.to_array(),
        scale: (0.0, 0.0),
        sform: Some([[-0.5, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 2.0, 0.0]]),
        gzip,
    };
    nifti::write(p, &le(&ramp()), VoxelType::I16, DIMS, &o).unwrap();
}

#[test]
fn one_volume_in_every_format_loads_the_same() {
    let dir = temp_dir("same");
    let r = reference();
    let bytes = le(&ramp());

    let raw = dir.join("ramp_7x5x3_int16.raw");
    std::fs::write(&raw, &bytes).unwrap();
    let v = load_volume(&raw, &LoadOptions { spacing: Some(SPACING), ..LoadOptions::default() }).unwrap();
    assert_same(&v, &r, "raw");
    assert_eq!(v.source().format, "raw");

    let nrrd_p = dir.join("ramp.nrrd");
    nrrd::write(&nrrd_p, &bytes, VoxelType::I16, DIMS, SPACING, true, None).unwrap();
    assert_same(&load(&nrrd_p), &r, "NRRD");

    for (name, version, gzip) in
        [("a.nii", 1, false), ("b.nii.gz", 1, true), ("c.nii", 2, false), ("d.nii.gz", 2, true)]
    {
        let p = dir.join(name);
        nifti_lps(&p, version, gzip);
        let v = load(&p);
        assert_same(&v, &r, name);
        assert_eq!(v.source().format, format!("NIfTI-{version}"));
        assert_eq!(v.source().voxel_type, Some(VoxelType::I16));
        // Recognized by content too.
        let q = dir.join(format!("{name}.bin"));
        std::fs::copy(&p, &q).unwrap();
        assert_same(&load(&q), &r, "NIfTI without its extension");
    }
}

#[test]
fn nifti_orientations_reorder_into_lps() {
    let dir = temp_dir("nifti-orient");
    let r = reference();
    let v = ramp();
    let [nx, ny, nz] = DIMS.map(|d| d as usize);
    // RAS order with a RAS identity-like sform: LPS x and y run against the file's i and j.
    let mut ras = Vec::new();
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                ras.push(at(&v, nx - 1 - x, ny - 1 - y, z));
            }
        }
    }
    let p = dir.join("ras.nii");
    let o = nifti::WriteOptions {
        version: 1,
        pixdim: SPACING.to_array(),
        scale: (0.0, 0.0),
        sform: Some([[0.5, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 2.0, 0.0]]),
        gzip: false,
    };
    nifti::write(&p, &le(&ras), VoxelType::I16, DIMS, &o).unwrap();
    let got = load(&p);
    assert_same(&got, &r, "RAS sform");
    assert!(got.source().orientation.contains("-i, -j, +k"), "{}", got.source().orientation);

    // Permuted axes: file i along +S (2 mm), j along +L (0.5 mm), k along -P (1 mm).
    let mut perm = Vec::new();
    for k in 0..ny {
        for j in 0..nx {
            for i in 0..nz {
                perm.push(at(&v, j, ny - 1 - k, i));
            }
        }
    }
    let p = dir.join("perm.nii.gz");
    let o = nifti::WriteOptions {
        version: 2,
        pixdim: [2.0, 0.5, 1.0],
        scale: (0.0, 0.0),
        sform: Some([[0.0, -0.5, 0.0, 10.0], [0.0, 0.0, 1.0, -3.0], [2.0, 0.0, 0.0, 7.0]]),
        gzip: true,
    };
    nifti::write(&p, &le(&perm), VoxelType::I16, [DIMS[2], DIMS[0], DIMS[1]], &o).unwrap();
    assert_same(&load(&p), &r, "permuted sform");

    // Oblique: refused with a clear message.
    let p = dir.join("oblique.nii");
    let o =
        nifti::WriteOptions { sform: Some([[0.4, 0.3, 0.0, 0.0], [-0.3, 0.4, 0.0, 0.0], [0.0, 0.0, 2.0, 0.0]]), ..o };
    nifti::write(&p, &le(&v), VoxelType::I16, DIMS, &nifti::WriteOptions { gzip: false, ..o }).unwrap();
    let e = load_err(&p);
    assert!(matches!(e.kind, VolumeErrorKind::Unsupported(_)) && e.to_string().contains("oblique"), "{e}");
}

#[test]
fn nifti_negative_pixdim_flips_and_slope_scales() {
    let dir = temp_dir("nifti-scale");
    let v = ramp();
    let [nx, ny, nz] = DIMS.map(|d| d as usize);
    let mut flipped = Vec::new();
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                flipped.push(at(&v, nx - 1 - x, y, z));
            }
        }
    }
    let p = dir.join("scaled.nii");
    let o = nifti::WriteOptions { version: 1, pixdim: [-0.5, 1.0, 2.0], scale: (2.0, -10.0), sform: None, gzip: false };
    nifti::write(&p, &le(&flipped), VoxelType::I16, DIMS, &o).unwrap();
    let got = load(&p);
    let want = Volume::from_values("w", DIMS, SPACING, v.iter().map(|&x| x as f32 * 2.0 - 10.0).collect()).unwrap();
    assert_same(&got, &want, "negative pixdim with slope 2, intercept -10");
    assert_eq!(got.value_range(), (-610.0, 2.0 * (6.0 * 3.0 + 4.0 * 29.0 + 2.0 * 211.0 - 300.0) - 10.0));

    // Slope 0 means none.
    let p = dir.join("unscaled.nii");
    let o = nifti::WriteOptions { pixdim: SPACING.to_array(), scale: (0.0, 55.0), ..o };
    nifti::write(&p, &le(&v), VoxelType::I16, DIMS, &o).unwrap();
    assert_same(&load(&p), &reference(), "slope 0");
}

#[test]
fn broken_nifti_files_are_clear_errors() {
    let dir = temp_dir("nifti-errors");
    let p = dir.join("full.nii");
    nifti_lps(&p, 1, false);
    let bytes = std::fs::read(&p).unwrap();

    let t = dir.join("truncated.nii");
    std::fs::write(&t, &bytes[..bytes.len() - 7]).unwrap();
    let e = load_err(&t);
    assert!(matches!(e.kind, VolumeErrorKind::SizeMismatch { expected: 210, actual: 203 }), "{e}");

    let t = dir.join("header_only.nii");
    std::fs::write(&t, &bytes[..200]).unwrap();
    let e = load_err(&t);
    assert!(matches!(e.kind, VolumeErrorKind::Malformed { .. }) && e.to_string().contains("fewer than"), "{e}");

    // Gzip cut short.
    let g = dir.join("full.nii.gz");
    nifti_lps(&g, 2, true);
    let gz = std::fs::read(&g).unwrap();
    let t = dir.join("truncated.nii.gz");
    std::fs::write(&t, &gz[..gz.len() - 40]).unwrap();
    load_err(&t);

    // Dims whose product overflows: refused before any allocation.
    let mut h = bytes[..352].to_vec();
    for i in 1..4 {
        h[40 + 2 * i..42 + 2 * i].copy_from_slice(&32_767i16.to_le_bytes());
    }
    let t = dir.join("huge.nii");
    std::fs::write(&t, &h).unwrap();
    let e = load_err(&t);
    assert!(matches!(e.kind, VolumeErrorKind::TooLarge { .. }), "{e}");
    let big = dir.join("huge2.nii");
    let o = nifti::WriteOptions { version: 2, pixdim: [1.0; 3], scale: (0.0, 0.0), sform: None, gzip: false };
    nifti::write(&big, &[], VoxelType::F64, [1, 1, 1], &o).unwrap();
    let mut b = std::fs::read(&big).unwrap();
    for i in 1..4 {
        b[16 + 8 * i..24 + 8 * i].copy_from_slice(&(1i64 << 31).to_le_bytes());
    }
    std::fs::write(&big, &b).unwrap();
    let e = load_err(&big);
    assert!(matches!(e.kind, VolumeErrorKind::BadGeometry(_) | VolumeErrorKind::TooLarge { .. }), "{e}");
    b[24..32].copy_from_slice(&(1i64 << 40).to_le_bytes());
    std::fs::write(&big, &b).unwrap();
    load_err(&big);
}
