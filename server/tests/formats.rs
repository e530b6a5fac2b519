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
    assert!(v.values() == r.values(), "{what}: voxels differ");
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
    assert!(matches!(e.kind, VolumeErrorKind::OutOfMemory { .. }), "{e}");
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

fn write_tiff_pages(p: &Path, pages: &[(u32, u32, Vec<u16>)]) {
    use tiff::encoder::{colortype::Gray16, TiffEncoder};
    let mut enc = TiffEncoder::new(std::io::BufWriter::new(std::fs::File::create(p).unwrap())).unwrap();
    for (w, h, data) in pages {
        enc.write_image::<Gray16>(*w, *h, data).unwrap();
    }
}

/// The ramp's slice `z` as 16-bit pixels (offset to unsigned).
fn ramp_slice_u16(z: usize) -> Vec<u16> {
    let n = (DIMS[0] * DIMS[1]) as usize;
    ramp()[z * n..(z + 1) * n].iter().map(|&x| (x as i32 + 1000) as u16).collect()
}

fn reference_u16() -> Volume {
    Volume::from_values("r", DIMS, SPACING, ramp().iter().map(|&x| x as f32 + 1000.0).collect()).unwrap()
}

#[test]
fn tiff_stacks_load_as_the_same_volume() {
    let dir = temp_dir("tiff");
    let r = reference_u16();
    let opts = LoadOptions { spacing: Some(SPACING), ..LoadOptions::default() };
    // One multi-page file.
    let p = dir.join("stack.tif");
    let pages: Vec<_> = (0..3).map(|z| (DIMS[0], DIMS[1], ramp_slice_u16(z))).collect();
    write_tiff_pages(&p, &pages);
    let v = load_volume(&p, &opts).unwrap();
    assert_same(&v, &r, "multi-page TIFF");
    assert_eq!((v.source().format.as_str(), v.source().voxel_type), ("TIFF", Some(VoxelType::U16)));
    assert_eq!(load(&p).spacing(), Vec3::ONE, "spacing 1 unless the options say otherwise");

    // A folder of slices, named so that plain string order would be wrong (10 before 9).
    let slices = dir.join("slices");
    std::fs::create_dir_all(&slices).unwrap();
    for (z, num) in [(0, 8), (1, 9), (2, 10)] {
        write_tiff_pages(&slices.join(format!("img{num}.tif")), &[(DIMS[0], DIMS[1], ramp_slice_u16(z))]);
    }
    std::fs::write(slices.join("notes.txt"), "not a slice").unwrap();
    let v = load_volume(&slices, &opts).unwrap();
    assert_same(&v, &r, "TIFF folder");
    assert_eq!(v.source().files, 3);

    // 8-bit pages.
    let p8 = dir.join("bytes.tiff");
    {
        use tiff::encoder::{colortype::Gray8, TiffEncoder};
        let mut enc = TiffEncoder::new(std::fs::File::create(&p8).unwrap()).unwrap();
        for z in 0..2u8 {
            enc.write_image::<Gray8>(3, 2, &[z, 1, 2, 3, 4, 250]).unwrap();
        }
    }
    let v = load(&p8);
    assert_eq!(v.dims(), [3, 2, 2]);
    assert_eq!(v.value_range(), (0.0, 250.0));
}

#[test]
fn broken_tiff_stacks_are_clear_errors() {
    let dir = temp_dir("tiff-errors");
    // An odd-sized slice in a folder: the error names that file and both sizes.
    let odd = dir.join("odd");
    std::fs::create_dir_all(&odd).unwrap();
    for k in 1..=5u32 {
        let (w, h) = if k == 4 { (7, 4) } else { (7, 5) };
        write_tiff_pages(&odd.join(format!("s_{k:03}.tif")), &[(w, h, vec![k as u16; (w * h) as usize])]);
    }
    let e = load_volume(&odd, &LoadOptions::default()).unwrap_err();
    assert!(e.to_string().contains("slice 4 (s_004.tif) is 7×4, the others 7×5"), "{e}");
    assert_eq!(e.path.as_deref().and_then(|p| p.file_name()), Some("s_004.tif".as_ref()), "{e}");

    // A missing slice: the numbering jumps.
    std::fs::remove_file(odd.join("s_004.tif")).unwrap();
    let e = load_volume(&odd, &LoadOptions::default()).unwrap_err();
    assert!(e.to_string().contains("5 follows 3") && e.to_string().contains("missing"), "{e}");
    assert_eq!(e.path.as_deref(), Some(odd.as_path()));

    // Odd page in a multi-page file.
    let p = dir.join("pages.tif");
    write_tiff_pages(&p, &[(4, 4, vec![0; 16]), (4, 4, vec![0; 16]), (4, 3, vec![0; 12])]);
    let e = load_err(&p);
    assert!(e.to_string().contains("page 3 is 4×3, the others 4×4"), "{e}");

    // A truncated file.
    let p2 = dir.join("cut.tif");
    write_tiff_pages(&p2, &[(64, 64, vec![7; 4096])]);
    let b = std::fs::read(&p2).unwrap();
    std::fs::write(&p2, &b[..b.len() / 3]).unwrap();
    load_err(&p2);

    // More voxels than the limit: refused before decoding.
    let p3 = dir.join("three.tif");
    write_tiff_pages(&p3, &[(4, 4, vec![0; 16]), (4, 4, vec![0; 16]), (4, 4, vec![0; 16])]);
    let e = load_volume(&p3, &LoadOptions { max_voxels: 40, ..LoadOptions::default() }).unwrap_err();
    assert!(matches!(e.kind, VolumeErrorKind::TooLarge { voxels: 48, limit: 40 }), "{e}");
}

#[test]
fn vti_in_every_encoding_loads_the_same() {
    use volwarp_server::volume::vti::{write, WriteFormat};
    let dir = temp_dir("vti");
    let r = reference();
    let bytes = le(&ramp());
    for (name, fmt, h64) in [
        ("ascii.vti", WriteFormat::Ascii, false),
        ("b64.vti", WriteFormat::Binary { zlib: false }, false),
        ("b64z.vti", WriteFormat::Binary { zlib: true }, false),
        ("b64z64.vti", WriteFormat::Binary { zlib: true }, true),
        ("app.vti", WriteFormat::AppendedRaw { zlib: false }, true),
        ("appz.vti", WriteFormat::AppendedRaw { zlib: true }, false),
    ] {
        let p = dir.join(name);
        write(&p, &bytes, VoxelType::I16, DIMS, SPACING, fmt, h64).unwrap();
        let v = load(&p);
        assert_same(&v, &r, name);
        assert_eq!(v.source().format, "VTK image data");
    }

    // Appended base64 data, two arrays (the PointData's Scalars one is read), a flipped
    // Direction, hand-written as VTK does: header and data base64-encoded separately.
    use base64::Engine;
    let b64 = |b: &[u8]| base64::engine::general_purpose::STANDARD.encode(b);
    let other = b64(&4u32.to_le_bytes()) + &b64(&[9, 9, 9, 9]);
    let [nx, ny, nz] = DIMS.map(|d| d as usize);
    let mut yflip = Vec::new();
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                yflip.push(at(&ramp(), x, ny - 1 - y, z));
            }
        }
    }
    let yb = le(&yflip);
    let mine = b64(&(yb.len() as u32).to_le_bytes()) + &b64(&yb);
    let xml = format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"ImageData\" version=\"1.0\" byte_order=\"LittleEndian\">\n\
<ImageData WholeExtent=\"2 8 0 4 10 12\" Origin=\"5 5 5\" Spacing=\"0.5 1 2\" Direction=\"1 0 0 0 -1 0 0 0 1\">\n\
<Piece Extent=\"2 8 0 4 10 12\"><PointData Scalars=\"density\">\n\
<DataArray type=\"UInt8\" Name=\"mask\" format=\"appended\" offset=\"0\"/>\n\
<DataArray type=\"Int16\" Name=\"density\" format=\"appended\" offset=\"{}\"/>\n\
</PointData></Piece></ImageData>\n<AppendedData encoding=\"base64\">\n _{other}{mine}\n</AppendedData>\n</VTKFile>\n",
        other.len()
    );
    let p = dir.join("hand.vti");
    std::fs::write(&p, xml).unwrap();
    let v = load(&p);
    assert_same(&v, &r, "appended base64 with a y-flipping Direction");
    assert!(v.source().orientation.contains("-j"), "{}", v.source().orientation);
}

#[test]
fn broken_vti_files_are_clear_errors() {
    use volwarp_server::volume::vti::{write, WriteFormat};
    let dir = temp_dir("vti-errors");
    let bytes = le(&ramp());
    let p = dir.join("z.vti");
    write(&p, &bytes, VoxelType::I16, DIMS, SPACING, WriteFormat::AppendedRaw { zlib: true }, false).unwrap();
    let full = std::fs::read(&p).unwrap();
    // Cut inside the compressed blocks.
    let at = full.windows(1).position(|w| w == b"_").unwrap() + 60;
    let t = dir.join("cut.vti");
    std::fs::write(&t, &full[..at]).unwrap();
    load_err(&t);
    // A block-size header that claims more than the extent.
    let mut lie = full.clone();
    let us = lie.iter().position(|&c| c == b'_').unwrap() + 1;
    lie[us..us + 4].copy_from_slice(&1000u32.to_le_bytes());
    let t = dir.join("lie.vti");
    std::fs::write(&t, &lie).unwrap();
    load_err(&t);
    // An extent that overflows: refused before any allocation.
    let text = String::from_utf8_lossy(&full)
        .replace("WholeExtent=\"0 6 0 4 0 2\"", "WholeExtent=\"0 4294967295 0 4294967295 0 4294967295\"");
    let t = dir.join("huge.vti");
    std::fs::write(&t, text.as_bytes()).unwrap();
    let e = load_err(&t);
    assert!(matches!(e.kind, VolumeErrorKind::BadGeometry(_) | VolumeErrorKind::Malformed { .. }), "{e}");
    // Ascii with too few values.
    let t = dir.join("few.vti");
    write(&t, &bytes[..bytes.len() - 2], VoxelType::I16, DIMS, SPACING, WriteFormat::Ascii, false).unwrap();
    let e = load_err(&t);
    assert!(e.to_string().contains("104 values"), "{e}");
}

/// One DICOM file, built in memory with dicom-object.
struct Slice<'a> {
    series: &'a str,
    position: Option<[f64; 3]>,
    iop: [f64; 6],
    /// PixelSpacing: between rows, between columns.
    ps: [f64; 2],
    rows: u16,
    cols: u16,
    frames: usize,
    pixels: Vec<u16>,
    signed: bool,
    rescale: Option<(f64, f64)>,
    between: Option<f64>,
    syntax: &'a str,
}

const EXPLICIT_LE: &str = "1.2.840.10008.1.2.1";
const IMPLICIT_LE: &str = "1.2.840.10008.1.2";

fn write_dicom(p: &Path, s: &Slice, uid: u32) {
    use dicom_core::{DataElement, PrimitiveValue, VR};
    use dicom_dictionary_std::tags;
    use dicom_object::{FileMetaTableBuilder, InMemDicomObject};
    let ds = |v: &[f64]| PrimitiveValue::from(v.iter().map(|x| x.to_string()).collect::<Vec<_>>().join("\\"));
    let mut o = InMemDicomObject::new_empty();
    o.put(DataElement::new(tags::SOP_CLASS_UID, VR::UI, PrimitiveValue::from("1.2.840.10008.5.1.4.1.1.2")));
    o.put(DataElement::new(tags::SOP_INSTANCE_UID, VR::UI, PrimitiveValue::from(format!("2.25.77.{uid}"))));
    o.put(DataElement::new(tags::SERIES_INSTANCE_UID, VR::UI, PrimitiveValue::from(s.series)));
    o.put(DataElement::new(tags::MODALITY, VR::CS, PrimitiveValue::from("CT")));
    if let Some(pos) = s.position {
        o.put(DataElement::new(tags::IMAGE_POSITION_PATIENT, VR::DS, ds(&pos)));
    }
    o.put(DataElement::new(tags::IMAGE_ORIENTATION_PATIENT, VR::DS, ds(&s.iop)));
    o.put(DataElement::new(tags::PIXEL_SPACING, VR::DS, ds(&s.ps)));
    if let Some(b) = s.between {
        o.put(DataElement::new(tags::SPACING_BETWEEN_SLICES, VR::DS, ds(&[b])));
    }
    o.put(DataElement::new(tags::SLICE_THICKNESS, VR::DS, ds(&[9.0])));
    o.put(DataElement::new(tags::SAMPLES_PER_PIXEL, VR::US, PrimitiveValue::from(1u16)));
    o.put(DataElement::new(tags::PHOTOMETRIC_INTERPRETATION, VR::CS, PrimitiveValue::from("MONOCHROME2")));
    if s.frames > 1 {
        o.put(DataElement::new(tags::NUMBER_OF_FRAMES, VR::IS, PrimitiveValue::from(s.frames.to_string())));
    }
    o.put(DataElement::new(tags::ROWS, VR::US, PrimitiveValue::from(s.rows)));
    o.put(DataElement::new(tags::COLUMNS, VR::US, PrimitiveValue::from(s.cols)));
    o.put(DataElement::new(tags::BITS_ALLOCATED, VR::US, PrimitiveValue::from(16u16)));
    o.put(DataElement::new(tags::BITS_STORED, VR::US, PrimitiveValue::from(16u16)));
    o.put(DataElement::new(tags::HIGH_BIT, VR::US, PrimitiveValue::from(15u16)));
    o.put(DataElement::new(tags::PIXEL_REPRESENTATION, VR::US, PrimitiveValue::from(s.signed as u16)));
    if let Some((slope, inter)) = s.rescale {
        o.put(DataElement::new(tags::RESCALE_SLOPE, VR::DS, ds(&[slope])));
        o.put(DataElement::new(tags::RESCALE_INTERCEPT, VR::DS, ds(&[inter])));
    }
    o.put(DataElement::new(tags::PIXEL_DATA, VR::OW, PrimitiveValue::U16(s.pixels.iter().copied().collect())));
    let f = o.with_meta(FileMetaTableBuilder::new().transfer_syntax(s.syntax)).unwrap();
    f.write_to_file(p).unwrap();
}

fn axial(series: &str, z: f64, pixels: Vec<u16>) -> Slice<'_> {
    Slice {
        series,
        position: Some([-10.0, 20.0, z]),
        iop: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0],
        ps: [1.0, 0.5],
        rows: DIMS[1] as u16,
        cols: DIMS[0] as u16,
        frames: 1,
        pixels,
        signed: true,
        rescale: None,
        between: None,
        syntax: EXPLICIT_LE,
    }
}

fn slice_i16(z: usize) -> Vec<u16> {
    let n = (DIMS[0] * DIMS[1]) as usize;
    ramp()[z * n..(z + 1) * n].iter().map(|&x| x as u16).collect()
}

#[test]
fn dicom_series_load_as_the_same_volume() {
    let dir = temp_dir("dicom");
    let r = reference();
    // Shuffled names; slices 2 mm apart; one file in implicit VR; a smaller second series.
    let series = dir.join("series");
    std::fs::create_dir_all(&series).unwrap();
    for (name, k) in [("IM_b", 2usize), ("IM_c", 0), ("IM_a.dcm", 1)] {
        let mut s = axial("1.2.3.4", 5.0 + 2.0 * k as f64, slice_i16(k));
        if k == 1 {
            s.syntax = IMPLICIT_LE;
        }
        write_dicom(&series.join(name), &s, k as u32);
    }
    for k in 0..2 {
        write_dicom(&series.join(format!("scout{k}")), &axial("1.2.3.5", k as f64, slice_i16(0)), 10 + k);
    }
    std::fs::write(series.join("README.txt"), "not DICOM").unwrap();
    // A DICOMDIR-like object without an image: skipped.
    {
        use dicom_core::{DataElement, PrimitiveValue, VR};
        use dicom_dictionary_std::tags;
        let o = dicom_object::InMemDicomObject::from_element_iter([
            DataElement::new(tags::SOP_CLASS_UID, VR::UI, PrimitiveValue::from("1.2.840.10008.1.3.10")),
            DataElement::new(tags::SOP_INSTANCE_UID, VR::UI, PrimitiveValue::from("2.25.5")),
        ]);
        let f = o.with_meta(dicom_object::FileMetaTableBuilder::new().transfer_syntax(EXPLICIT_LE)).unwrap();
        f.write_to_file(series.join("DICOMDIR")).unwrap();
    }
    let v = load(&series);
    assert_same(&v, &r, "DICOM folder");
    assert_eq!((v.source().format.as_str(), v.source().files), ("DICOM", 3));

    // Unsigned pixels with a rescale intercept; coronal slices (rows run down the patient).
    let coronal = dir.join("coronal");
    std::fs::create_dir_all(&coronal).unwrap();
    let [nx, ny, nz] = DIMS.map(|d| d as usize);
    for k in 0..ny {
        let mut px = Vec::new();
        for j in 0..nz {
            for i in 0..nx {
                px.push((at(&ramp(), i, k, nz - 1 - j) as i32 + 1024) as u16);
            }
        }
        let s = Slice {
            iop: [1.0, 0.0, 0.0, 0.0, 0.0, -1.0],
            ps: [2.0, 0.5],
            rows: nz as u16,
            cols: nx as u16,
            position: Some([0.0, 3.0 + k as f64, 50.0]),
            signed: false,
            rescale: Some((1.0, -1024.0)),
            ..axial("9.9", 0.0, px)
        };
        write_dicom(&coronal.join(format!("{}.dcm", 100 - k)), &s, 20 + k as u32);
    }
    let v = load(&coronal);
    assert_same(&v, &r, "coronal DICOM with rescale");
    assert!(v.source().orientation.contains("+i, +k, -j"), "{}", v.source().orientation);

    // A multi-frame file (SpacingBetweenSlices, no per-frame positions).
    let mf = dir.join("multi.dcm");
    let all: Vec<u16> = ramp().iter().map(|&x| x as u16).collect();
    write_dicom(&mf, &Slice { frames: 3, between: Some(2.0), position: None, ..axial("7.7", 0.0, all) }, 30);
    assert_same(&load(&mf), &r, "multi-frame DICOM");
}

#[test]
fn broken_dicom_series_are_clear_errors() {
    let dir = temp_dir("dicom-errors");
    // A missing slice: gaps 2, 4.
    let gap = dir.join("gap");
    std::fs::create_dir_all(&gap).unwrap();
    for (k, z) in [0.0, 2.0, 6.0].iter().enumerate() {
        write_dicom(&gap.join(format!("s{k}")), &axial("1", *z, slice_i16(k)), k as u32);
    }
    let e = load_volume(&gap, &LoadOptions::default()).unwrap_err();
    assert!(e.to_string().contains("inconsistent slice gaps") && e.to_string().contains("s1 and s2"), "{e}");
    assert_eq!(e.path.as_deref(), Some(gap.as_path()));

    // A compressed transfer syntax.
    let jpeg = dir.join("jpeg.dcm");
    write_dicom(&jpeg, &Slice { syntax: "1.2.840.10008.1.2.4.50", ..axial("2", 0.0, slice_i16(0)) }, 5);
    let e = load_err(&jpeg);
    assert!(e.to_string().contains("transfer syntax 1.2.840.10008.1.2.4.50 (JPEG baseline)"), "{e}");

    // Real encapsulated pixel data (fragments) in a compressed syntax: the syntax is named.
    {
        use dicom_core::header::Header as _;
        use dicom_core::value::PixelFragmentSequence;
        use dicom_core::{DataElement, VR};
        use dicom_dictionary_std::tags;
        let mut o = dicom_object::InMemDicomObject::new_empty();
        let plain = dir.join("plain.dcm");
        write_dicom(&plain, &axial("2", 0.0, slice_i16(0)), 11);
        for e in dicom_object::open_file(&plain).unwrap().into_inner() {
            if e.tag() != tags::PIXEL_DATA {
                o.put(e);
            }
        }
        let frags = PixelFragmentSequence::new(Vec::<u32>::new(), vec![vec![0xFFu8, 0xD8, 0xFF, 0xD9, 1, 2, 3, 4]]);
        o.put(DataElement::new(tags::PIXEL_DATA, VR::OB, frags));
        let p = dir.join("encapsulated.dcm");
        let syntax = "1.2.840.10008.1.2.4.90";
        let f = o.with_meta(dicom_object::FileMetaTableBuilder::new().transfer_syntax(syntax)).unwrap();
        f.write_to_file(&p).unwrap();
        let e = load_err(&p);
        assert!(e.to_string().contains("transfer syntax 1.2.840.10008.1.2.4.90 (JPEG 2000)"), "{e}");
    }

    // Oblique slices.
    let ob = dir.join("oblique.dcm");
    write_dicom(&ob, &Slice { iop: [0.8, 0.6, 0.0, -0.6, 0.8, 0.0], ..axial("3", 0.0, slice_i16(0)) }, 6);
    let e = load_err(&ob);
    assert!(e.to_string().contains("oblique"), "{e}");

    // Pixel data shorter than rows × columns × frames.
    let short = dir.join("short.dcm");
    write_dicom(&short, &Slice { frames: 3, between: Some(1.0), ..axial("4", 0.0, slice_i16(0)) }, 7);
    let e = load_err(&short);
    assert!(matches!(e.kind, VolumeErrorKind::SizeMismatch { .. }), "{e}");

    // A truncated file, and a 600-byte file whose pixel data claims 4 GiB: refused before the
    // DICOM parser allocates what the length says.
    let ok = dir.join("ok.dcm");
    write_dicom(&ok, &axial("6", 0.0, slice_i16(0)), 9);
    let b = std::fs::read(&ok).unwrap();
    let cut = dir.join("cut.dcm");
    std::fs::write(&cut, &b[..b.len() - 10]).unwrap();
    let e = load_err(&cut);
    assert!(e.to_string().contains("truncated"), "{e}");
    let px = b.windows(4).rposition(|w| w == [0xE0, 0x7F, 0x10, 0x00]).unwrap();
    let mut lie = b.clone();
    lie[px + 8..px + 12].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
    let lie_p = dir.join("lie.dcm");
    std::fs::write(&lie_p, &lie).unwrap();
    let t = std::time::Instant::now();
    let e = load_err(&lie_p);
    assert!(e.to_string().contains("claims 4294967280 bytes"), "{e}");
    assert!(t.elapsed().as_secs_f64() < 1.0);

    // Rows × columns × frames past the memory there is: refused before the pixels are read.
    let huge = dir.join("huge.dcm");
    write_dicom(&huge, &Slice { rows: 65535, cols: 65535, frames: 9999, ..axial("5", 0.0, vec![0; 4]) }, 8);
    let e = load_err(&huge);
    assert!(matches!(e.kind, VolumeErrorKind::OutOfMemory { .. }), "{e}");
}

#[test]
fn info_prints_what_was_read() {
    let dir = temp_dir("info");
    let p = dir.join("scan.nii.gz");
    let o = nifti::WriteOptions {
        version: 1,
        pixdim: SPACING.to_array(),
        scale: (0.0, 0.0),
        sform: Some([[0.5, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 2.0, 0.0]]),
        gzip: true,
    };
    nifti::write(&p, &le(&ramp()), VoxelType::I16, DIMS, &o).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_volwarp-server"))
        .arg("info")
        .arg(&p)
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}{}", String::from_utf8_lossy(&out.stderr));
    for want in [
        "format       NIfTI-1",
        "dims         7 x 5 x 3 (105 voxels)",
        "voxel type   int16",
        "spacing      0.5, 1, 2",
        "value range  -300 .. 256",
        "orientation  file axes (-i, -j, +k) as LPS (x, y, z) (sform, RAS to LPS)",
        "data         210 bytes in 1 file",
    ] {
        assert!(text.contains(want), "{want:?} missing from:\n{text}");
    }
    // A broken file: a non-zero exit and the file named.
    std::fs::write(dir.join("bad.nii"), b"short").unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_volwarp-server"))
        .arg("info")
        .arg(dir.join("bad.nii"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("bad.nii"));
}

#[test]
fn nifti_qform_pairs_and_4d_files() {
    let dir = temp_dir("nifti-more");
    let r = reference();
    let v = ramp();
    let [nx, ny, nz] = DIMS.map(|d| d as usize);
    let set = |b: &mut Vec<u8>, at: usize, bytes: &[u8]| b[at..at + bytes.len()].copy_from_slice(bytes);
    let plain =
        nifti::WriteOptions { version: 1, pixdim: SPACING.to_array(), scale: (0.0, 0.0), sform: None, gzip: false };

    // qform: a 180° rotation about z (quaternion d = 1) maps RAS onto LPS; qfac -1 flips k.
    let mut zflip = Vec::new();
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                zflip.push(at(&v, x, y, nz - 1 - z));
            }
        }
    }
    let p = dir.join("qform.nii");
    nifti::write(&p, &le(&zflip), VoxelType::I16, DIMS, &plain).unwrap();
    let mut b = std::fs::read(&p).unwrap();
    set(&mut b, 252, &1i16.to_le_bytes()); // qform_code
    set(&mut b, 264, &1f32.to_le_bytes()); // quatern_d
    set(&mut b, 76, &(-1f32).to_le_bytes()); // pixdim[0] = qfac
    std::fs::write(&p, &b).unwrap();
    let got = load(&p);
    assert_same(&got, &r, "qform with qfac -1");
    assert!(got.source().orientation.contains("(+i, +j, -k)") && got.source().orientation.contains("qform"));

    // A .hdr/.img pair (magic ni1, data at offset 0 of the .img).
    let p = dir.join("pair.nii");
    nifti::write(&p, &le(&v), VoxelType::I16, DIMS, &plain).unwrap();
    let b = std::fs::read(&p).unwrap();
    let mut hdr = b[..348].to_vec();
    set(&mut hdr, 344, b"ni1\0");
    set(&mut hdr, 108, &0f32.to_le_bytes());
    std::fs::write(dir.join("pair.hdr"), &hdr).unwrap();
    std::fs::write(dir.join("pair.img"), &b[352..]).unwrap();
    let got = load(&dir.join("pair.hdr"));
    assert_same(&got, &r, ".hdr/.img pair");
    assert_eq!(got.source().files, 2);
    std::fs::remove_file(dir.join("pair.img")).unwrap();
    let e = load_err(&dir.join("pair.hdr"));
    assert!(e.to_string().contains("pair.img"), "{e}");

    // 4-D: two volumes, the first is read.
    let p = dir.join("series.nii");
    let two: Vec<i16> = v.iter().copied().chain(v.iter().map(|x| x / 2)).collect();
    nifti::write(&p, &le(&two), VoxelType::I16, DIMS, &plain).unwrap();
    let mut b = std::fs::read(&p).unwrap();
    set(&mut b, 40, &4i16.to_le_bytes());
    set(&mut b, 48, &2i16.to_le_bytes());
    std::fs::write(&p, &b).unwrap();
    assert_same(&load(&p), &r, "first volume of a 4-D file");

    // Big-endian: every field and voxel byte-swapped.
    let p = dir.join("big.nii");
    let mut b = vec![0u8; 352];
    set(&mut b, 0, &348i32.to_be_bytes());
    for (i, d) in [3i16, 7, 5, 3, 1, 1, 1, 1].iter().enumerate() {
        set(&mut b, 40 + 2 * i, &d.to_be_bytes());
    }
    set(&mut b, 70, &4i16.to_be_bytes());
    set(&mut b, 72, &16i16.to_be_bytes());
    for (i, d) in [1f32, 0.5, 1.0, 2.0].iter().enumerate() {
        set(&mut b, 76 + 4 * i, &d.to_be_bytes());
    }
    set(&mut b, 108, &352f32.to_be_bytes());
    set(&mut b, 344, b"n+1\0");
    b.extend(v.iter().flat_map(|x| x.to_be_bytes()));
    std::fs::write(&p, &b).unwrap();
    assert_same(&load(&p), &r, "big-endian NIfTI-1");
}

#[test]
fn dicom_enhanced_multiframe_uses_functional_groups() {
    use dicom_core::value::DataSetSequence;
    use dicom_core::{DataElement, PrimitiveValue, VR};
    use dicom_dictionary_std::tags;
    use dicom_object::{FileMetaTableBuilder, InMemDicomObject};
    let dir = temp_dir("dicom-enhanced");
    let ds = |v: &[f64]| PrimitiveValue::from(v.iter().map(|x| x.to_string()).collect::<Vec<_>>().join("\\"));
    let item = |elems: Vec<DataElement<InMemDicomObject>>| InMemDicomObject::from_element_iter(elems);
    let seq = |tag, items: Vec<InMemDicomObject>| DataElement::new(tag, VR::SQ, DataSetSequence::from(items));
    // Frames stored in the order z = 2, 0, 1; unsigned pixels with intercept -1024 in the shared
    // groups; orientation and pixel spacing only in the shared groups.
    let order = [2usize, 0, 1];
    let mut pixels = Vec::new();
    let mut per_frame = Vec::new();
    for &z in &order {
        pixels.extend(slice_i16(z).iter().map(|&x| (x as i16 as i32 + 1024) as u16));
        per_frame.push(item(vec![seq(
            tags::PLANE_POSITION_SEQUENCE,
            vec![item(vec![DataElement::new(
                tags::IMAGE_POSITION_PATIENT,
                VR::DS,
                ds(&[0.0, 0.0, 5.0 + 2.0 * z as f64]),
            )])],
        )]));
    }
    let shared = item(vec![
        seq(
            tags::PIXEL_MEASURES_SEQUENCE,
            vec![item(vec![DataElement::new(tags::PIXEL_SPACING, VR::DS, ds(&[1.0, 0.5]))])],
        ),
        seq(
            tags::PLANE_ORIENTATION_SEQUENCE,
            vec![item(vec![DataElement::new(
                tags::IMAGE_ORIENTATION_PATIENT,
                VR::DS,
                ds(&[1.0, 0.0, 0.0, 0.0, 1.0, 0.0]),
            )])],
        ),
        seq(
            tags::PIXEL_VALUE_TRANSFORMATION_SEQUENCE,
            vec![item(vec![
                DataElement::new(tags::RESCALE_INTERCEPT, VR::DS, ds(&[-1024.0])),
                DataElement::new(tags::RESCALE_SLOPE, VR::DS, ds(&[1.0])),
            ])],
        ),
    ]);
    let o = InMemDicomObject::from_element_iter([
        DataElement::new(tags::SOP_CLASS_UID, VR::UI, PrimitiveValue::from("1.2.840.10008.5.1.4.1.1.2.1")),
        DataElement::new(tags::SOP_INSTANCE_UID, VR::UI, PrimitiveValue::from("2.25.99")),
        DataElement::new(tags::SERIES_INSTANCE_UID, VR::UI, PrimitiveValue::from("2.25.98")),
        DataElement::new(tags::SAMPLES_PER_PIXEL, VR::US, PrimitiveValue::from(1u16)),
        DataElement::new(tags::NUMBER_OF_FRAMES, VR::IS, PrimitiveValue::from("3")),
        DataElement::new(tags::ROWS, VR::US, PrimitiveValue::from(DIMS[1] as u16)),
        DataElement::new(tags::COLUMNS, VR::US, PrimitiveValue::from(DIMS[0] as u16)),
        DataElement::new(tags::BITS_ALLOCATED, VR::US, PrimitiveValue::from(16u16)),
        DataElement::new(tags::BITS_STORED, VR::US, PrimitiveValue::from(12u16)),
        DataElement::new(tags::PIXEL_REPRESENTATION, VR::US, PrimitiveValue::from(0u16)),
        seq(tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE, vec![shared]),
        seq(tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE, per_frame),
        DataElement::new(tags::PIXEL_DATA, VR::OW, PrimitiveValue::U16(pixels.into())),
    ]);
    let p = dir.join("enhanced.dcm");
    o.with_meta(FileMetaTableBuilder::new().transfer_syntax(EXPLICIT_LE)).unwrap().write_to_file(&p).unwrap();
    assert_same(&load(&p), &reference(), "enhanced multi-frame DICOM");
}

/// The load-speed bench: one N³ int16 volume (N from `VOLWARP_LOAD_N`, default 256) written in
/// every format, each loaded three times on a warm page cache, the median printed with its
/// ratio to raw (`VOLWARP_LOAD_N=512 cargo test --release -p volwarp-server --test formats --
/// --ignored --nocapture load_speed`); it checks nothing but that every format gives raw's voxels.
#[test]
#[ignore]
fn load_speed() {
    use volwarp_server::volume::vti::{write, WriteFormat};
    let dir = temp_dir("speed");
    let n: u32 = std::env::var("VOLWARP_LOAD_N").ok().and_then(|v| v.parse().ok()).unwrap_or(256);
    let dims = [n; 3];
    let vals: Vec<i16> = (0..n * n * n).map(|i| ((i % 4093) as i32 - 2000) as i16).collect();
    let bytes = le(&vals);
    let sp = Vec3::ONE;
    let raw = dir.join(format!("v_{n}x{n}x{n}_int16.raw"));
    std::fs::write(&raw, &bytes).unwrap();
    let nii = dir.join("v.nii");
    let lps = Some([[-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]);
    let o = nifti::WriteOptions { version: 1, pixdim: [1.0; 3], scale: (0.0, 0.0), sform: lps, gzip: false };
    nifti::write(&nii, &bytes, VoxelType::I16, dims, &o).unwrap();
    let niigz = dir.join("v.nii.gz");
    nifti::write(&niigz, &bytes, VoxelType::I16, dims, &nifti::WriteOptions { gzip: true, ..o.clone() }).unwrap();
    let ras = dir.join("ras.nii");
    nifti::write(
        &ras,
        &bytes,
        VoxelType::I16,
        dims,
        &nifti::WriteOptions { sform: None, pixdim: [-1.0, -1.0, 1.0], ..o },
    )
    .unwrap();
    let vti = dir.join("v.vti");
    write(&vti, &bytes, VoxelType::I16, dims, sp, WriteFormat::AppendedRaw { zlib: false }, true).unwrap();
    let vtiz = dir.join("z.vti");
    write(&vtiz, &bytes, VoxelType::I16, dims, sp, WriteFormat::AppendedRaw { zlib: true }, true).unwrap();
    let tif = dir.join("v.tif");
    let plane = (n * n) as usize;
    let pages: Vec<_> = (0..n as usize)
        .map(|z| (n, n, vals[z * plane..(z + 1) * plane].iter().map(|&x| (x as i32 + 2048) as u16).collect::<Vec<_>>()))
        .collect();
    write_tiff_pages(&tif, &pages);
    let dcm = dir.join("dicom");
    std::fs::create_dir_all(&dcm).unwrap();
    for z in 0..n as usize {
        let px: Vec<u16> = vals[z * plane..(z + 1) * plane].iter().map(|&x| x as u16).collect();
        let s = Slice {
            rows: n as u16,
            cols: n as u16,
            ps: [1.0, 1.0],
            position: Some([0.0, 0.0, z as f64]),
            ..axial("1", 0.0, px)
        };
        write_dicom(&dcm.join(format!("{z}.dcm")), &s, z as u32);
    }
    let opts = LoadOptions { max_voxels: u64::from(n).pow(3), ..LoadOptions::default() };
    let mut first: Option<Volume> = None;
    let mut raw_median: Option<f64> = None;
    for (what, p) in [
        ("raw", &raw),
        ("NIfTI", &nii),
        ("NIfTI gzip", &niigz),
        ("NIfTI, x and y flipped", &ras),
        (".vti appended raw", &vti),
        (".vti appended zlib", &vtiz),
        ("TIFF, one page a slice", &tif),
        ("DICOM, one file a slice", &dcm),
    ] {
        let mut ms = Vec::new();
        let mut v = None;
        for _ in 0..3 {
            drop(v.take());
            let t = std::time::Instant::now();
            v = Some(load_volume(p, &opts).unwrap());
            ms.push(t.elapsed().as_secs_f64() * 1e3);
        }
        let v = v.unwrap();
        ms.sort_by(f64::total_cmp);
        let raw_ms = *raw_median.get_or_insert(ms[1]);
        eprintln!("{what:24} {n}³: median {:7.1} ms ({:.2}× raw)", ms[1], ms[1] / raw_ms);
        if what == "raw" {
            first = Some(v);
        } else if !what.contains("flipped") {
            assert!(first.as_ref().is_some_and(|f| f.values() == v.values()), "{what}");
        }
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// DICOM series, TIFF stacks and `.vti` appended data stream into bricks of their own type:
/// a 64³ 16-bit volume loads within a memory limit that decoding it whole (4 bytes a voxel
/// kept, 8 while loading) would exceed, and gives raw's voxels; a `.vti` whose Direction
/// permutes the axes is decoded whole and refused under that limit.
#[test]
fn streamed_formats_load_within_their_stored_size() {
    use volwarp_server::volume::vti::{write, WriteFormat};
    use volwarp_server::volume::MemoryLimit;
    let dir = temp_dir("streamed");
    let n = 64u32;
    let plane = (n * n) as usize;
    let vals: Vec<i16> = (0..n * n * n).map(|i| ((i * 7919 % 4093) as i32 - 2000) as i16).collect();
    let bytes = le(&vals);
    let raw = dir.join(format!("v_{n}x{n}x{n}_int16.raw"));
    std::fs::write(&raw, &bytes).unwrap();
    let limited = LoadOptions { memory: MemoryLimit::Bytes(3 << 19), ..LoadOptions::default() };
    let r = load_volume(&raw, &limited).unwrap();

    let dcm = dir.join("dicom");
    std::fs::create_dir_all(&dcm).unwrap();
    for z in 0..n as usize {
        let px: Vec<u16> = vals[z * plane..(z + 1) * plane].iter().map(|&x| x as u16).collect();
        let s = Slice { rows: n as u16, cols: n as u16, ps: [1.0, 1.0], ..axial("1", z as f64, px) };
        // Shuffled file names: the order comes from the positions.
        write_dicom(&dcm.join(format!("{}.dcm", (z * 37) % 64)), &s, z as u32);
    }
    let tif = dir.join("v.tif");
    let pages: Vec<_> = (0..n as usize)
        .map(|z| (n, n, vals[z * plane..(z + 1) * plane].iter().map(|&x| (x as i32 + 2048) as u16).collect::<Vec<_>>()))
        .collect();
    write_tiff_pages(&tif, &pages);
    let vti = dir.join("v.vti");
    write(&vti, &bytes, VoxelType::I16, [n; 3], Vec3::ONE, WriteFormat::AppendedRaw { zlib: false }, false).unwrap();
    let vtiz = dir.join("z.vti");
    write(&vtiz, &bytes, VoxelType::I16, [n; 3], Vec3::ONE, WriteFormat::AppendedRaw { zlib: true }, true).unwrap();
    for p in [&dcm, &tif, &vti, &vtiz] {
        let v = load_volume(p, &limited).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        assert!(v.values() == r.values(), "{}: voxels differ from raw", p.display());
        assert_eq!(v.dims(), [n; 3]);
        assert!(v.memory_bytes() < 2 * bytes.len() as u64, "{}: {} bytes", p.display(), v.memory_bytes());
    }
    // The same appended data with a permuting Direction: decoded whole, over the limit.
    let text = std::fs::read(&vti).unwrap();
    let at = text.windows(9).position(|w| w == b"Spacing=\"").unwrap();
    let mut permuted = text[..at].to_vec();
    permuted.extend_from_slice(b"Direction=\"0 1 0 1 0 0 0 0 1\" ");
    permuted.extend_from_slice(&text[at..]);
    let pv = dir.join("permuted.vti");
    std::fs::write(&pv, &permuted).unwrap();
    let e = load_volume(&pv, &limited).expect_err("a permuted .vti is decoded whole");
    assert!(matches!(e.kind, VolumeErrorKind::OutOfMemory { .. }), "{e}");
    let v = load_volume(&pv, &LoadOptions::default()).unwrap();
    assert!(v.source().orientation.contains("(+j, +i, +k)"), "{}", v.source().orientation);
    std::fs::remove_dir_all(&dir).ok();
}

/// The pixel data is found where the data set has it, not inside a sequence item that holds
/// its own (an icon image), and behind elements larger than the first bytes read of a file;
/// 12 bits stored of 16 keep their low bits, sign-extended.
#[test]
fn dicom_pixel_data_behind_sequences_and_large_elements() {
    use dicom_core::value::DataSetSequence;
    use dicom_core::{DataElement, Length, PrimitiveValue, VR};
    use dicom_dictionary_std::tags;
    let dir = temp_dir("dicom-walk");
    let r = reference();
    for (k, case) in ["icon", "large", "bits"].iter().enumerate() {
        let series = dir.join(case);
        std::fs::create_dir_all(&series).unwrap();
        for z in 0..DIMS[2] as usize {
            let p = series.join(format!("{z}.dcm"));
            let mut px = slice_i16(z);
            if *case == "bits" {
                // Junk in the 4 bits above the 12 stored: the ramp fits in 12 signed bits.
                px.iter_mut().for_each(|v| *v = (*v & 0x0FFF) | 0x5000);
            }
            write_dicom(&p, &axial("5.5", 2.0 * z as f64, px), (100 * k + z) as u32);
            let mut o = dicom_object::open_file(&p).unwrap();
            match *case {
                "icon" => {
                    let icon = dicom_object::InMemDicomObject::from_element_iter([
                        DataElement::new(tags::ROWS, VR::US, PrimitiveValue::from(2u16)),
                        DataElement::new(tags::COLUMNS, VR::US, PrimitiveValue::from(2u16)),
                        DataElement::new(tags::PIXEL_DATA, VR::OB, PrimitiveValue::from(vec![9u8, 9, 9, 9])),
                    ]);
                    let seq = DataSetSequence::new(vec![icon], Length::UNDEFINED);
                    o.put(DataElement::new(tags::ICON_IMAGE_SEQUENCE, VR::SQ, seq));
                }
                "large" => {
                    let blob = vec![7u8; 100_000];
                    o.put(DataElement::new(dicom_core::Tag(0x0009, 0x1010), VR::OB, PrimitiveValue::from(blob)));
                }
                _ => {
                    o.put(DataElement::new(tags::BITS_STORED, VR::US, PrimitiveValue::from(12u16)));
                    o.put(DataElement::new(tags::HIGH_BIT, VR::US, PrimitiveValue::from(11u16)));
                }
            }
            o.write_to_file(&p).unwrap();
        }
        let v = load(&series);
        assert_same(&v, &r, case);
    }
}

/// The ramp written in every format that streams (raw, NRRD, NIfTI, `.vti` plain and zlib, a
/// signed 16-bit TIFF stack, a DICOM series) renders the identical image and the identical
/// layered frame (colors and depths bit for bit).
#[test]
fn one_volume_in_every_format_renders_the_same() {
    use std::sync::Arc;
    use volwarp_core::Camera;
    use volwarp_server::transfer_function::TransferFunction;
    use volwarp_server::volume::vti::{write, WriteFormat};
    use volwarp_server::Marcher;
    let dir = temp_dir("render");
    let bytes = le(&ramp());
    let raw = dir.join("ramp_7x5x3_int16.raw");
    std::fs::write(&raw, &bytes).unwrap();
    let nrrd_p = dir.join("ramp.nrrd");
    nrrd::write(&nrrd_p, &bytes, VoxelType::I16, DIMS, SPACING, true, None).unwrap();
    let nii = dir.join("ramp.nii.gz");
    nifti_lps(&nii, 1, true);
    let vti = dir.join("ramp.vti");
    write(&vti, &bytes, VoxelType::I16, DIMS, SPACING, WriteFormat::AppendedRaw { zlib: false }, false).unwrap();
    let vtiz = dir.join("rampz.vti");
    write(&vtiz, &bytes, VoxelType::I16, DIMS, SPACING, WriteFormat::AppendedRaw { zlib: true }, true).unwrap();
    let tif = dir.join("ramp.tif");
    {
        use tiff::encoder::{colortype::GrayI16, TiffEncoder};
        let mut enc = TiffEncoder::new(std::io::BufWriter::new(std::fs::File::create(&tif).unwrap())).unwrap();
        let plane = (DIMS[0] * DIMS[1]) as usize;
        for z in ramp().chunks(plane) {
            enc.write_image::<GrayI16>(DIMS[0], DIMS[1], z).unwrap();
        }
    }
    let dcm = dir.join("dicom");
    std::fs::create_dir_all(&dcm).unwrap();
    for z in 0..DIMS[2] as usize {
        write_dicom(&dcm.join(format!("{z}.dcm")), &axial("3.3", 2.0 * z as f64, slice_i16(z)), z as u32);
    }
    let with_spacing = LoadOptions { spacing: Some(SPACING), ..LoadOptions::default() };
    let tf = TransferFunction::from_points(
        "ramp",
        &[(0.0, [0.1, 0.2, 0.9]), (0.5, [0.9, 0.6, 0.1]), (1.0, [1.0, 1.0, 1.0])],
        &[(0.0, 0.0), (0.3, 0.4), (1.0, 0.9)],
    );
    let extent = Vec3::new(7.0 * 0.5, 5.0, 3.0 * 2.0);
    let cam = Camera::look_at(extent * 0.5 + Vec3::new(9.0, -6.0, 11.0), extent * 0.5, Vec3::Y, 40.0, 48, 40);
    let render = |p: &Path| {
        let v = load_volume(p, &with_spacing).unwrap_or_else(|e| panic!("{e}"));
        let m = Marcher::new(Arc::new(v), &tf);
        (m.render_image(&cam), m.march_layers(&cam, 4))
    };
    let (want_image, want_layers) = render(&raw);
    assert!(want_layers.count.iter().any(|&c| c > 1), "the view sees layered segments");
    for p in [&nrrd_p, &nii, &vti, &vtiz, &tif, &dcm] {
        let (image, layers) = render(p);
        assert!(image == want_image, "{}: the image differs from raw's", p.display());
        assert!(layers == want_layers, "{}: the layered frame differs from raw's", p.display());
    }
    std::fs::remove_dir_all(&dir).ok();
}
