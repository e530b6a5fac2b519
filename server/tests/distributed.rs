//! The volume split across parts (what MPI ranks do, run here in one process): the
//! decomposition, the parts' samples against the whole volume's, the composited frame
//! against the one-process marcher's, and the merge against a concatenate-and-sort reference.

use proptest::prelude::*;
use std::path::PathBuf;
use std::sync::Arc;
use volwarp_core::wire::CameraRequest;
use volwarp_core::{Heuristic, Vec3};
use volwarp_server::distributed::composite::{self, merge, merge_reference, Band, BandView};
use volwarp_server::distributed::decomposition::{combine_ranges, part_of, read_part, Decomposition};
use volwarp_server::distributed::partial::{PartMarcher, Seg};
use volwarp_server::distributed::{image, render_in_process, FrameGeometry};
use volwarp_server::volume::LoadOptions;
use volwarp_server::{Dataset, MarchKernel, MarchOptions, Marcher, Volume};

fn data(file: &str) -> PathBuf {
    volwarp_server::dataset::data_dir().expect("the bundled data/ folder").join(file)
}

/// The parts of a file as [`read_part`] reads them, normalized over their combined range.
fn parts_of_file(path: &PathBuf, n: usize) -> (Arc<Decomposition>, Vec<Volume>) {
    let whole = volwarp_server::load_volume(path, &LoadOptions::default()).unwrap();
    let dec = Arc::new(Decomposition::new(whole.dims(), n).unwrap());
    let parts: Vec<_> = (0..n).map(|p| read_part(path, &LoadOptions::default(), &dec, p).unwrap()).collect();
    let range = combine_ranges(parts.iter().map(|p| p.range));
    (dec, parts.into_iter().map(|p| p.into_volume(range).unwrap()).collect())
}

fn parts_in_memory(whole: &Volume, n: usize) -> (Arc<Decomposition>, Vec<Volume>) {
    let dec = Arc::new(Decomposition::new(whole.dims(), n).unwrap());
    let vols = (0..n)
        .map(|p| {
            let d = part_of(whole, &dec, p);
            let r = d.range;
            d.into_volume(r).unwrap()
        })
        .collect();
    (dec, vols)
}

#[test]
fn parts_partition_the_volume_and_split_at_bricks() {
    for dims in [[64, 64, 93], [181, 217, 181], [33, 7, 300], [1024, 1024, 1024]] {
        let bricks: usize = dims.iter().map(|&d: &u32| d.div_ceil(32) as usize).product();
        for n in 1..=9usize.min(bricks) {
            let d = Decomposition::new(dims, n).unwrap();
            assert_eq!(d.parts.len(), n);
            let total: u64 = d.parts.iter().map(|p| p.owned_voxels()).sum();
            assert_eq!(total, dims.iter().map(|&x| u64::from(x)).product::<u64>(), "{dims:?} {n}");
            for (i, a) in d.parts.iter().enumerate() {
                for b in &d.parts[i + 1..] {
                    let overlap = (0..3).all(|k| a.lo[k] < b.hi[k] && b.lo[k] < a.hi[k]);
                    assert!(!overlap, "{a:?} {b:?}");
                }
                for k in 0..3 {
                    // Interior faces at brick boundaries where the part is longer than a brick.
                    for f in [a.lo[k], a.hi[k]] {
                        if f != 0 && f != dims[k] && dims[k] >= 64 {
                            assert_eq!(f % 32, 0, "{dims:?} n={n} {a:?}");
                        }
                    }
                    assert_eq!(a.held_lo[k], a.lo[k].saturating_sub(1));
                    assert_eq!(a.held_hi[k], (a.hi[k] + 1).min(dims[k]));
                }
            }
        }
    }
    assert!(Decomposition::new([40, 40, 40], 9).unwrap_err().contains("at most 8 ranks"));
    assert!(Decomposition::new([40, 40, 40], 0).is_err());
}

#[test]
fn the_order_is_front_to_back_along_every_ray() {
    let dims = [100, 80, 60];
    let d = Decomposition::new(dims, 7).unwrap();
    let mut seed = 7u64;
    let mut rnd = move || {
        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (seed >> 40) as f32 / (1u64 << 24) as f32
    };
    for _ in 0..50 {
        let eye = Vec3::new(rnd() * 300.0 - 100.0, rnd() * 240.0 - 80.0, rnd() * 180.0 - 60.0);
        let order = d.order(eye);
        let rank_of: Vec<usize> = (0..7).map(|p| order.iter().position(|&q| q == p).unwrap()).collect();
        for _ in 0..50 {
            let target = Vec3::new(rnd() * 100.0, rnd() * 80.0, rnd() * 60.0);
            let dir = (target - eye).normalize();
            let mut last = 0;
            for s in 0..2000 {
                let u = eye + dir * (s as f32 * 0.25);
                let g = u - 0.5;
                if (0..3).any(|a| u[a] < 0.0 || u[a] >= dims[a] as f32) {
                    continue;
                }
                let p = (0..7).find(|&p| d.owns(p, g)).expect("every inside point has a part");
                assert_eq!((0..7).filter(|&q| d.owns(q, g)).count(), 1);
                assert!(rank_of[p] >= last, "eye {eye} dir {dir}");
                last = rank_of[p];
            }
        }
    }
}

/// Every part's samples inside its owned box equal the whole volume's, bit for bit.
fn assert_parts_sample_like_whole(whole: &Volume, dec: &Decomposition, parts: &[Volume]) {
    let mut seed = 11u64;
    let mut rnd = move || {
        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (seed >> 40) as f32 / (1u64 << 24) as f32
    };
    for (p, (part, vol)) in dec.parts.iter().zip(parts).enumerate() {
        let off = Vec3::new(part.held_lo[0] as f32, part.held_lo[1] as f32, part.held_lo[2] as f32);
        for i in 0..4000 {
            // Random points of the owned box, and its faces and corners.
            let g = Vec3::from(std::array::from_fn::<f32, 3, _>(|a| {
                let (lo, hi) = (part.lo[a] as f32 - 0.5, part.hi[a] as f32 - 0.5);
                match i % 4 {
                    0 => lo,
                    1 => hi.next_down(),
                    _ => lo + (hi - lo) * rnd(),
                }
            }));
            if !dec.owns(p, g) {
                continue;
            }
            assert_eq!(
                vol.sample_grid(g - off).to_bits(),
                whole.sample_grid(g).to_bits(),
                "{} part {p} of {} at {g}: normalization {:?} {:?}, types {} {}",
                whole.name,
                parts.len(),
                vol.normalization(),
                whole.normalization(),
                vol.voxels().type_name(),
                whole.voxels().type_name()
            );
        }
    }
    assert_eq!(parts[0].value_range(), whole.value_range());
}

#[test]
fn parts_read_by_byte_ranges_sample_like_the_whole_volume() {
    // Raw u8, NRRD header with detached int16 raw data, and gzip NRRD (loaded whole).
    for file in ["neghip_64x64x64_uint8.raw", "ct_head_quarter.nhdr", "mri_colin27.nrrd"] {
        let path = data(file);
        let whole = volwarp_server::load_volume(&path, &LoadOptions::default()).unwrap();
        for n in [2, 3, 4] {
            let (dec, parts) = parts_of_file(&path, n);
            assert_parts_sample_like_whole(&whole, &dec, &parts);
        }
    }
    // Floats, from memory.
    let whole = Volume::marschner_lobb(41);
    let (dec, parts) = parts_in_memory(&whole, 3);
    assert_parts_sample_like_whole(&whole, &dec, &parts);
}

#[test]
fn a_part_refused_for_memory_fits_when_split() {
    let path = data("neghip_64x64x64_uint8.raw");
    let dec = Decomposition::new([64, 64, 64], 4).unwrap();
    let limit = LoadOptions { memory: volwarp_server::volume::MemoryLimit::Bytes(200_000), ..Default::default() };
    let whole = Decomposition::new([64, 64, 64], 1).unwrap();
    let e = read_part(&path, &limit, &whole, 0).unwrap_err();
    assert!(e.to_string().contains("--max-memory"), "{e}");
    for p in 0..4 {
        read_part(&path, &limit, &dec, p).unwrap();
    }
    // A file that does not match the decomposition is an error, not a wrong part.
    let other = Decomposition::new([64, 64, 32], 2).unwrap();
    assert!(read_part(&path, &LoadOptions::default(), &other, 0).is_err());
}

fn marchers(ds: &Dataset, dec: &Arc<Decomposition>, parts: Vec<Volume>, opts: MarchOptions) -> Vec<PartMarcher> {
    parts
        .into_iter()
        .enumerate()
        .map(|(p, v)| PartMarcher::new(Arc::new(v), dec.clone(), p, &ds.tf, opts).unwrap())
        .collect()
}

fn request(m: &Marcher, size: u32, yaw: f32, heuristic: Heuristic) -> CameraRequest {
    CameraRequest {
        seq: 3,
        camera: m.default_camera(size, size).orbit(yaw, 20.0),
        heuristic,
        radius_scale: 1.0,
        layers: 0,
    }
}

#[test]
fn one_part_gives_the_one_process_frame_bit_for_bit() {
    let ds = Dataset::load(data("ct_head_quarter.nhdr"), None).unwrap();
    let opts = MarchOptions::default();
    let m = Marcher::with_options(ds.volume.clone(), &ds.tf, opts);
    let (dec, parts) = parts_of_file(&data("ct_head_quarter.nhdr"), 1);
    let pm = marchers(&ds, &dec, parts, opts);
    let geo = FrameGeometry { dims: ds.volume.dims(), spacing: ds.volume.spacing(), opts };
    for (layers, heuristic) in
        [(4, Heuristic::Threshold), (1, Heuristic::Threshold), (1, Heuristic::Entrance), (2, Heuristic::Peak)]
    {
        let req = request(&m, 48, 30.0, heuristic);
        let (want, _) = m.render_frame_layers(&req, layers);
        let bands = render_in_process(&pm, &req, layers, 3);
        let got = geo.frame(&req, layers, &bands, want.header.render_us);
        assert_eq!(got.samples, want.samples, "K={layers} {heuristic}");
        assert_eq!(got.colors, want.colors, "K={layers} {heuristic}");
        assert_eq!(got.segments, want.segments);
        assert_eq!(got.header, want.header);
        let enc = |e| geo.encode(&req, &got, e, true).0;
        let want_enc = |e| volwarp_server::encoding::encode_frame_for(&m, &req, &want, e, true).0;
        for e in [volwarp_core::compact_frame::Encoding::Compact, volwarp_core::compact_frame::Encoding::Raw12] {
            assert_eq!(enc(e), want_enc(e));
        }
    }
}

/// A part frame's segment slots as bits (equal bit for bit, not as floats).
fn frame_bits(f: &volwarp_server::distributed::partial::PartFrame) -> (Vec<u8>, Vec<u32>) {
    let bits = f
        .segs
        .iter()
        .flat_map(|s| [s.t.to_bits(), s.c[0].to_bits(), s.c[1].to_bits(), s.c[2].to_bits(), s.c[3].to_bits()]);
    (f.count.clone(), bits.collect())
}

#[test]
fn packet_parts_equal_scalar_parts_bit_for_bit() {
    use volwarp_server::{lane_kind, limit_lanes, LaneKind};
    for file in ["ct_head_quarter.nhdr", "mri_colin27.nrrd"] {
        let ds = Dataset::load(data(file), None).unwrap();
        let m = Marcher::new(ds.volume.clone(), &ds.tf);
        for (n, opts) in [
            (1, MarchOptions::default()),
            (3, MarchOptions::default()),
            (4, MarchOptions { skip_empty: false, early_termination: 1.0, ..MarchOptions::default() }),
            (2, MarchOptions { step_voxels: 0.7, ..MarchOptions::default() }),
        ] {
            let (dec, parts) = parts_of_file(&data(file), n);
            let packet = marchers(&ds, &dec, parts, MarchOptions { kernel: MarchKernel::Packet, ..opts });
            let (_, parts) = parts_of_file(&data(file), n);
            let scalar = marchers(&ds, &dec, parts, MarchOptions { kernel: MarchKernel::Scalar, ..opts });
            for (layers, heuristic, yaw) in [
                (4, Heuristic::Threshold, 30.0),
                (2, Heuristic::Peak, 160.0),
                (1, Heuristic::Threshold, 70.0),
                (1, Heuristic::RelThreshold, 250.0),
                (1, Heuristic::Midpoint, 10.0),
            ] {
                // 37 pixels: packets cut by the image's edge.
                let cam = request(&m, 37, yaw, heuristic).camera;
                for (p, (fast, slow)) in packet.iter().zip(&scalar).enumerate() {
                    let want = frame_bits(&slow.march(&cam, layers, heuristic));
                    assert!(want.0.iter().any(|&c| c > 0) || n > 2, "{file}: part {p} of {n} saw nothing");
                    for kind in [LaneKind::Avx512, LaneKind::Avx2, LaneKind::Portable] {
                        limit_lanes(kind);
                        if lane_kind() != kind {
                            continue;
                        }
                        let got = frame_bits(&fast.march(&cam, layers, heuristic));
                        assert!(got == want, "{file} n={n} part {p} K={layers} {heuristic} {kind:?} {opts:?}");
                    }
                    limit_lanes(LaneKind::Avx512);
                }
            }
        }
    }
}

/// Each pixel's segments (the slots its count covers), as bits.
fn pixel_bits(f: &volwarp_server::distributed::partial::PartFrame) -> Vec<Vec<u32>> {
    (0..f.count.len())
        .map(|i| {
            f.pixel(i)
                .iter()
                .flat_map(|s| [s.t.to_bits(), s.c[0].to_bits(), s.c[1].to_bits(), s.c[2].to_bits(), s.c[3].to_bits()])
                .collect()
        })
        .collect()
}

#[test]
fn a_part_reusing_its_last_frames_buffers_marches_as_a_fresh_one() {
    let ds = Dataset::load(data("mri_colin27.nrrd"), None).unwrap();
    let m = Marcher::new(ds.volume.clone(), &ds.tf);
    let (dec, parts) = parts_of_file(&data("mri_colin27.nrrd"), 2);
    let reused = marchers(&ds, &dec, parts, MarchOptions::default());
    // Larger frames first, then smaller and fewer segments: the kept slots hold old segments.
    for (size, layers, yaw) in [(48, 4, 30.0), (48, 4, 120.0), (33, 2, 200.0), (40, 3, 75.0), (20, 1, 10.0)] {
        let cam = request(&m, size, yaw, Heuristic::Threshold).camera;
        for p in &reused {
            let fresh = p.clone().march(&cam, layers, Heuristic::Threshold);
            let got = p.march(&cam, layers, Heuristic::Threshold);
            assert_eq!(got.count, fresh.count, "part {} size {size} K={layers}", p.part());
            assert!(got.count.iter().any(|&c| c > 0), "part {} saw nothing", p.part());
            assert!(pixel_bits(&got) == pixel_bits(&fresh), "part {} size {size} K={layers}", p.part());
            p.recycle(got);
        }
    }
}

#[test]
fn band_owners_assemble_the_frame_rank_0_would() {
    use volwarp_server::distributed::{FramePart, FrameSlots};
    let ds = Dataset::load(data("ct_head_quarter.nhdr"), None).unwrap();
    let opts = MarchOptions::default();
    let m = Marcher::with_options(ds.volume.clone(), &ds.tf, opts);
    let (dec, parts) = parts_of_file(&data("ct_head_quarter.nhdr"), 3);
    let pm = marchers(&ds, &dec, parts, opts);
    let geo = FrameGeometry { dims: ds.volume.dims(), spacing: ds.volume.spacing(), opts };
    for (layers, heuristic) in [(4, Heuristic::Threshold), (1, Heuristic::Entrance)] {
        let req = request(&m, 50, 20.0, heuristic);
        let bands = render_in_process(&pm, &req, layers, 3);
        let want = geo.frame(&req, layers, &bands, 7);
        // Each band's owner assembles its pixels in runs; rank 0 fills them into the frame in
        // place (its own band copied, the others' received: here copied too).
        let mut first = 0u32;
        let owners: Vec<Vec<FramePart>> = bands
            .iter()
            .map(|b| {
                let n = b.count.len();
                let runs: Vec<_> = (0..n.div_ceil(300))
                    .map(|r| geo.frame_part(&req, layers, b, first, r * 300..((r + 1) * 300).min(n)))
                    .collect();
                first += n as u32;
                runs
            })
            .collect();
        let counts: Vec<usize> = owners.iter().map(|r| r.iter().map(|p| p.samples.len()).sum()).collect();
        let mut got = geo.frame_of_count(&req, layers, counts.iter().sum(), 7);
        let slots = FrameSlots::split(&mut got, &counts).expect("counts that add up");
        for (mut slot, (b, runs)) in slots.into_iter().zip(owners.iter().enumerate()) {
            // A sender's runs joined into one fill the same slot.
            let runs = if b == 1 { vec![FramePart::join(runs)] } else { runs.clone() };
            assert!(slot.fill(&runs), "K={layers} band {b}");
        }
        assert_eq!(got, want, "K={layers}");
        // Counts that do not add up, and runs that do not fit their slot, are refused.
        let mut f = geo.frame_of_count(&req, layers, counts.iter().sum(), 7);
        let mut short = counts.clone();
        short[0] -= 1;
        assert!(FrameSlots::split(&mut f, &short).is_none());
        let mut slots = FrameSlots::split(&mut f, &counts).unwrap();
        assert!(!slots[0].fill(&owners[1]), "K={layers}: band 1's runs in band 0's slot");
        assert!(!slots[0].fill(&[]));
    }
}

/// The largest channel difference and the share of identical pixels of two images.
fn diff(a: &volwarp_core::Image, b: &volwarp_core::Image) -> (u32, f64) {
    let mut worst = 0;
    let mut same = 0;
    for (&x, &y) in a.pixels.iter().zip(&b.pixels) {
        let d = (0..4).map(|i| ((x >> (8 * i)) & 255).abs_diff((y >> (8 * i)) & 255)).max().unwrap_or(0);
        worst = worst.max(d);
        same += usize::from(x == y);
    }
    (worst, same as f64 / a.pixels.len() as f64)
}

#[test]
fn split_frames_composite_to_the_one_process_image() {
    for file in ["ct_head_quarter.nhdr", "neghip_64x64x64_uint8.raw", "mri_colin27.nrrd"] {
        let ds = Dataset::load(data(file), None).unwrap();
        let opts = MarchOptions { kernel: MarchKernel::Packet, ..MarchOptions::default() };
        let m = Marcher::with_options(ds.volume.clone(), &ds.tf, opts);
        for n in [2, 3, 4] {
            let (dec, parts) = parts_of_file(&data(file), n);
            let pm = marchers(&ds, &dec, parts, opts);
            for yaw in [0.0, 70.0] {
                let req = request(&m, 64, yaw, Heuristic::Threshold);
                let want = m.render_image(&req.camera);
                let bands = render_in_process(&pm, &req, 4, n);
                let (worst, same) = diff(&image(64, 64, &bands), &want);
                assert!(worst <= 3 && same > 0.6, "{file} n={n} yaw={yaw}: worst {worst}, identical {same}");
                // The frame holds at most K segments per pixel, front to back.
                for b in &bands {
                    for p in 0..b.count.len() {
                        let s = b.pixel(p);
                        assert!(s.len() <= 4 && s.windows(2).all(|w| w[0].t < w[1].t));
                    }
                }
            }
        }
    }
}

#[test]
fn the_entrance_depth_is_the_one_process_depth() {
    let ds = Dataset::load(data("ct_head_quarter.nhdr"), None).unwrap();
    let opts = MarchOptions::default();
    let m = Marcher::with_options(ds.volume.clone(), &ds.tf, opts);
    let (dec, parts) = parts_of_file(&data("ct_head_quarter.nhdr"), 4);
    let pm = marchers(&ds, &dec, parts, opts);
    let req = request(&m, 64, 40.0, Heuristic::Entrance);
    let want = m.march(&req.camera, Heuristic::Entrance);
    let bands = render_in_process(&pm, &req, 1, 2);
    let mut i = 0;
    let (mut equal, mut n) = (0, 0);
    for b in &bands {
        for p in 0..b.count.len() {
            if let (Some(s), true) = (b.pixel(p).first(), want.t[i].is_finite()) {
                n += 1;
                equal += usize::from(s.t.to_bits() == want.t[i].to_bits());
            }
            i += 1;
        }
    }
    assert!(n > 500);
    assert_eq!(equal, n, "the nearest part's first visible sample is the ray's");
}

#[test]
fn the_threshold_depth_is_the_one_process_depth_where_the_nearest_part_crosses() {
    let ds = Dataset::load(data("mri_colin27.nrrd"), None).unwrap();
    let opts = MarchOptions::default();
    let m = Marcher::with_options(ds.volume.clone(), &ds.tf, opts);
    let (dec, parts) = parts_of_file(&data("mri_colin27.nrrd"), 4);
    let pm = marchers(&ds, &dec, parts, opts);
    let req = request(&m, 64, 40.0, Heuristic::Threshold);
    let want = m.march(&req.camera, Heuristic::Threshold);
    let frames: Vec<_> = pm.iter().map(|p| p.march(&req.camera, 1, Heuristic::Threshold)).collect();
    let order = dec.order(req.camera.eye / ds.volume.spacing());
    let bands = render_in_process(&pm, &req, 1, 3);
    let merged: Vec<Option<Seg>> =
        bands.iter().flat_map(|b| (0..b.count.len()).map(|p| b.pixel(p).first().copied())).collect();
    let (mut crossed, mut other) = (0, 0);
    for (i, got) in merged.iter().enumerate() {
        // The nearest part with a visible sample, and whether its own samples cross.
        let Some(&near) = order.iter().find(|&&p| frames[p].count[i] > 0) else {
            assert!(got.is_none() && !want.t[i].is_finite(), "pixel {i}: no part saw it");
            continue;
        };
        let got = got.expect("a part saw the pixel");
        if frames[near].pixel(i)[0].c[3] > volwarp_core::heuristics::THRESHOLD {
            crossed += 1;
            assert_eq!(got.t.to_bits(), want.t[i].to_bits(), "pixel {i}: the nearest part's crossing is the ray's");
        } else {
            // The ray crosses over several parts: where it leaves the nearest part, in front of
            // the ray's crossing.
            other += 1;
            assert!(got.t <= want.t[i], "pixel {i}: {} behind {}", got.t, want.t[i]);
        }
    }
    eprintln!("threshold: {crossed} pixels crossed in the nearest part, {other} over several parts");
    assert!(crossed > 1000 && other > 0, "crossed {crossed}, over several parts {other}");
}

/// The bytes of a band in a 4-byte aligned buffer (as a rank receives them), and their length.
fn aligned(bytes: &[u8]) -> Vec<u32> {
    let mut out = vec![0u32; bytes.len().div_ceil(4)];
    bytemuck::cast_slice_mut::<u32, u8>(&mut out)[..bytes.len()].copy_from_slice(bytes);
    out
}

#[test]
fn bands_read_in_place_merge_as_decoded_bands() {
    // What a band owner merges: its own band read from its march (slots of K), the others'
    // bands read in place from the receive buffer, against the decoded-and-copied bands.
    let ds = Dataset::load(data("ct_head_quarter.nhdr"), None).unwrap();
    let opts = MarchOptions::default();
    let m = Marcher::with_options(ds.volume.clone(), &ds.tf, opts);
    let (dec, parts) = parts_of_file(&data("ct_head_quarter.nhdr"), 3);
    let pm = marchers(&ds, &dec, parts, opts);
    for layers in [4u32, 1] {
        let req = request(&m, 45, 40.0, Heuristic::Threshold);
        let cam = &req.camera;
        let frames: Vec<_> = pm.iter().map(|p| p.march(cam, layers, req.heuristic)).collect();
        let want = render_in_process(&pm, &req, layers, 3);
        let k = frames[0].k;
        for (owner, want) in want.iter().enumerate() {
            let rows = composite::band_rows(cam.height, 3, owner);
            let pixels = (rows.end - rows.start) as usize * cam.width as usize;
            let bytes: Vec<(Vec<u32>, usize)> = frames
                .iter()
                .map(|f| {
                    let b = composite::encode_band(f, rows.clone());
                    assert_eq!(b.len(), composite::band_len(f, rows.clone()));
                    (aligned(&b), b.len())
                })
                .collect();
            let views: Vec<BandView> = (0..3)
                .map(|p| {
                    if p == owner {
                        BandView::of_part(&frames[p], rows.clone())
                    } else {
                        let (b, n) = &bytes[p];
                        BandView::parse(&bytemuck::cast_slice::<u32, u8>(b)[..*n], pixels, k).unwrap()
                    }
                })
                .collect();
            let runs =
                composite::merge_views_with(&views, pixels, k, opts.early_termination, |_, s, acc: &mut Vec<Seg>| {
                    acc.push(Seg { t: s.len() as f32, c: [0.0; 4] });
                    acc.extend_from_slice(s);
                })
                .unwrap();
            let mut flat = Vec::new();
            for p in 0..pixels {
                flat.push(Seg { t: want.count[p] as f32, c: [0.0; 4] });
                flat.extend_from_slice(want.pixel(p));
            }
            assert_eq!(runs.concat(), flat, "K={layers} band {owner}");
            // A non-finite value in a received band fails its reading in place (and the decode).
            let other = (owner + 1) % 3;
            let (b, n) = &bytes[other];
            let segs_at = composite::counts_len(pixels);
            if *n > segs_at {
                let mut bad = b.clone();
                bytemuck::cast_slice_mut::<u32, u8>(&mut bad)[segs_at..segs_at + 4]
                    .copy_from_slice(&f32::NAN.to_ne_bytes());
                let bad_bytes = &bytemuck::cast_slice::<u32, u8>(&bad)[..*n];
                assert!(composite::decode_band(bad_bytes, pixels, k).is_err());
                assert!(BandView::parse(bad_bytes, pixels, k).is_err());
                // Bytes that do not lie aligned are refused, not read unaligned.
                let mut shifted = vec![0u8; n + 1];
                shifted[1..].copy_from_slice(&bytemuck::cast_slice::<u32, u8>(b)[..*n]);
                let shifted = &shifted[1..];
                if !(shifted.as_ptr() as usize).is_multiple_of(4) {
                    assert!(BandView::parse(shifted, pixels, k).is_err());
                }
                assert_eq!(
                    composite::decode_band(shifted, pixels, k).unwrap(),
                    composite::decode_band(&bytemuck::cast_slice::<u32, u8>(b)[..*n], pixels, k).unwrap()
                );
            }
        }
    }
}

fn segs() -> impl Strategy<Value = (Vec<Vec<Seg>>, usize, f32)> {
    // Up to 6 parts, each a front-to-back list inside its own depth interval; the parts in any
    // order.
    (1usize..7, 1usize..9, prop::bool::ANY).prop_flat_map(|(parts, k, ert)| {
        let list = prop::collection::vec((0.0f32..1.0, 0.0f32..1.0, 0.0f32..1.0), 0..6);
        (prop::collection::vec(list, parts), Just(parts), Just(k), Just(ert), any::<u64>()).prop_map(
            |(lists, parts, k, ert, shuffle)| {
                let mut out: Vec<Vec<Seg>> = lists
                    .into_iter()
                    .enumerate()
                    .map(|(p, l)| {
                        let mut ts: Vec<f32> = l.iter().map(|x| p as f32 * 10.0 + x.0 * 9.0).collect();
                        ts.sort_by(f32::total_cmp);
                        ts.dedup();
                        ts.iter()
                            .zip(&l)
                            .map(|(&t, &(_, a, g))| Seg { t, c: [a * g, a * (1.0 - g), a * 0.5, a] })
                            .collect()
                    })
                    .collect();
                let mut s = shuffle;
                for i in (1..parts).rev() {
                    out.swap(i, (s % (i as u64 + 1)) as usize);
                    s /= i as u64 + 1;
                }
                (out, k, if ert { 0.99 } else { 2.0 })
            },
        )
    })
}

proptest! {
    #[test]
    fn the_merge_equals_concatenate_and_sort((lists, k, ert) in segs()) {
        let refs: Vec<&[Seg]> = lists.iter().map(|l| l.as_slice()).collect();
        let mut got = Vec::new();
        merge(&refs, k, ert, &mut got);
        let want = merge_reference(&refs, k, ert);
        prop_assert_eq!(&got, &want);
        prop_assert!(got.len() <= k);
        prop_assert!(got.windows(2).all(|w| w[0].t <= w[1].t));
        // Without early termination the fused segments composite to the segments' color.
        if ert > 1.0 {
            let comp = |s: &[Seg]| s.iter().fold([0.0f32; 4], |acc, x| {
                let keep = 1.0 - acc[3];
                [0, 1, 2, 3].map(|j| acc[j] + keep * x.c[j])
            });
            let mut all: Vec<Seg> = lists.concat();
            all.sort_by(|a, b| a.t.total_cmp(&b.t));
            let (a, b) = (comp(&got), comp(&all));
            for j in 0..4 {
                prop_assert!((a[j] - b[j]).abs() < 1e-5, "{:?} {:?}", a, b);
            }
        }
    }

    #[test]
    fn band_merges_equal_the_reference_pixel_by_pixel(pixels in prop::collection::vec(segs(), 1..24)) {
        // Bands of up to 6 parts over random pixels (no list, one part's, several; lists longer
        // than K too): every pixel's merged segments as merge_reference gives them.
        let (k, ert) = (pixels[0].1, pixels[0].2);
        let bands: Vec<Band> = (0..6)
            .map(|p| {
                let mut b = Band::default();
                for (lists, _, _) in &pixels {
                    let l = lists.get(p).map_or(&[][..], |l| l.as_slice());
                    b.start.push(b.segs.len() as u32);
                    b.count.push(l.len() as u8);
                    b.segs.extend_from_slice(l);
                }
                b
            })
            .collect();
        let got = composite::merge_bands_with(&bands, pixels.len(), k, ert, |i, s, acc: &mut Vec<(usize, Vec<Seg>)>| {
            acc.push((i, s.to_vec()))
        });
        let got: Vec<(usize, Vec<Seg>)> = got.into_iter().flatten().collect();
        prop_assert_eq!(got.len(), pixels.len());
        for (i, (lists, _, _)) in pixels.iter().enumerate() {
            let refs: Vec<&[Seg]> = lists.iter().map(|l| l.as_slice()).collect();
            prop_assert_eq!(got[i].0, i);
            prop_assert_eq!(&got[i].1, &merge_reference(&refs, k, ert));
        }
    }

    #[test]
    fn bands_decode_what_they_encode_and_refuse_garbage(bytes in prop::collection::vec(any::<u8>(), 0..200), pixels in 0usize..40) {
        // Never a panic, and a band that decodes holds at most K segments per pixel.
        if let Ok(b) = composite::decode_band(&bytes, pixels, 4) {
            prop_assert_eq!(b.count.len(), pixels);
            prop_assert!(b.count.iter().all(|&c| c <= 4));
            prop_assert_eq!(composite::encode_merged(&b), bytes);
        }
    }
}

#[test]
fn bands_cover_the_rows_once() {
    for h in [1u32, 7, 64, 1024] {
        for n in 1..=8 {
            let rows: Vec<_> = (0..n).flat_map(|b| composite::band_rows(h, n, b)).collect();
            assert_eq!(rows, (0..h).collect::<Vec<_>>());
        }
    }
    // Bands cut by work: contiguous, every row once, each band's work within one row's of an
    // even share.
    let mut seed = 11u64;
    for h in [0usize, 1, 5, 64, 1024] {
        for n in 1..=8 {
            let load: Vec<u64> = (0..h)
                .map(|_| {
                    seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    (seed >> 54) * u64::from(!seed.is_multiple_of(3))
                })
                .collect();
            let b = composite::balanced_bands(&load, n);
            assert_eq!(b.len(), n + 1);
            assert_eq!((b[0], b[n]), (0, h as u32));
            assert!(b.windows(2).all(|w| w[0] <= w[1]));
            let total: u64 = load.iter().sum();
            let max = load.iter().copied().max().unwrap_or(0);
            for j in 0..n {
                let work: u64 = load[b[j] as usize..b[j + 1] as usize].iter().sum();
                assert!(work <= total / n as u64 + 2 * max + 1, "h {h} n {n} band {j}: {work} of {total}");
            }
        }
    }
    let empty = Band::default();
    assert_eq!(composite::encode_merged(&empty), Vec::<u8>::new());
}
