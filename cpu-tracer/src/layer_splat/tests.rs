use super::*;
use crate::lanes;
use crate::layered::*;
use crate::sphere_splat::View;
use crate::threads::Threads;
use volwarp_core::renderer::{Image, Renderer};
use volwarp_core::sample::Dequantizer;
use volwarp_core::{Camera, Vec3, BACKGROUND};

#[test]
fn the_row_test_is_the_pixel_test() {
    // Quadrilaterals around random points, pixel centres on and near their edges (exact
    // zeros of an edge function included), and non-finite coefficients.
    let mut x = 0x9E37_79B9u32;
    let mut rnd = move || {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        (x >> 8) as f32 / (1 << 24) as f32
    };
    let mut tested = [0usize; 2];
    for i in 0..20_000 {
        let (cx, cy) = (rnd() * 64.0, rnd() * 64.0);
        let q: [(f32, f32); 4] = core::array::from_fn(|k| {
            let a = (k as f32 + rnd() * 0.8) * core::f32::consts::FRAC_PI_2;
            let r = 0.5 + rnd() * 3.0;
            (cx + r * a.cos(), cy + r * a.sin())
        });
        let mut quad = Quad { edges: coefficient_major(edges_of(q)), ..Quad::NONE };
        if i % 97 == 0 {
            quad.edges[(i / 97) % 3][i % 4] = [f32::NAN, f32::INFINITY, -f32::INFINITY][i % 3];
        }
        for _ in 0..16 {
            let (px, py) = ((cx + rnd() * 8.0 - 4.0).floor() + 0.5, (cy + rnd() * 8.0 - 4.0).floor() + 0.5);
            let want = quad.covers(px, py);
            assert_eq!(quad.row(py).covers(px), want, "{quad:?} at ({px}, {py})");
            tested[want as usize] += 1;
        }
        // A corner itself: every edge through it is zero there.
        let (px, py) = q[0];
        assert_eq!(quad.row(py).covers(px), quad.covers(px, py));
    }
    assert!(tested[0] > 10_000 && tested[1] > 10_000, "{tested:?}");
}

/// Warp-grown footprints grow by the display's pixels: a frame on the half-resolution grid of
/// adaptive resolution grows half as many of its own pixels per degree, a full-resolution one
/// (with or without a guard band) as many.
#[test]
fn footprints_grow_by_the_displays_pixels() {
    use crate::layered::source_pixel_scale;
    let fc = crate::synthetic::depth_image_frame(64, 1.0, 7).header.camera;
    let cam = fc.orbit(10.0, 0.0);
    let coarse = fc.with_viewport(fc.width / 2, fc.height / 2);
    assert!((source_pixel_scale(&coarse, &cam) - 2.0).abs() < 1e-5);
    assert_eq!(source_pixel_scale(&fc, &cam), 1.0);
    // A guard band: more pixels over a wider field of view, at the same pitch.
    let half = (fc.fov_y_deg.to_radians() * 0.5).tan() * 1.25;
    let guard = Camera { fov_y_deg: (2.0 * half.atan()).to_degrees(), height: fc.height * 5 / 4, ..fc };
    assert!((source_pixel_scale(&guard, &cam) - 1.0).abs() < 1e-5);
    // A finer frame grows in its own pixels, and nothing yields NaN.
    assert_eq!(source_pixel_scale(&fc.with_viewport(fc.width * 2, fc.height * 2), &cam), 1.0);
    assert_eq!(source_pixel_scale(&Camera { fov_y_deg: f32::NAN, ..fc }, &cam), 1.0);
    let o = LayerOptions::DEFAULT;
    let deg = volwarp_core::warp_radius::warp_angle_deg(&fc, &cam);
    assert!((deg - 10.0).abs() < 0.5, "{deg}");
    assert!((o.grown(&fc, &cam) - o.own_at(deg)).abs() < 1e-6);
    assert!((o.grown(&coarse, &cam) - o.own_at(deg / 2.0)).abs() < 1e-4);
    assert!(o.grown(&coarse, &cam) < o.grown(&fc, &cam));
    assert_eq!(o.grown(&fc, &fc), o.own, "the frame's own camera: its own pixels");
    // Up to `grow_from_deg` footprints keep their own size, then grow `grow_per_degree` a degree.
    assert!(o.grow_from_deg > 0.0 && o.grow_from_deg < deg);
    assert_eq!(o.own_at(o.grow_from_deg), o.own);
    assert_eq!(o.own_at(o.grow_from_deg * 0.5), o.own);
    assert!((o.own_at(o.grow_from_deg + 2.0) - (o.own + 2.0 * o.grow_per_degree)).abs() < 1e-6);
    assert_eq!(o.own_at(f32::NAN), o.own);
    let from_zero = LayerOptions { grow_from_deg: f32::NAN, ..o };
    assert!((from_zero.own_at(2.0) - (o.own + 2.0 * o.grow_per_degree)).abs() < 1e-6);
}

/// The footprints of a synthetic surface (plus random samples, some behind the eye, some
/// degenerate) for `frame_camera`, set up for `camera` by the scalar reference and by the
/// lanes kernel on both lane types: the same quads bit for bit.
#[test]
fn lanes_match_the_scalar_footprints() {
    use crate::synthetic::{depth_image_frame, SplitMix64};
    let frame = depth_image_frame(96, 1.0, 7);
    let fc = frame.header.camera;
    let deq = Dequantizer::new(frame.header.bounds, frame.header.radius_unit);
    let mut samples = frame.samples.clone();
    let mut rng = SplitMix64(3);
    samples.extend((0..300).map(|_| rng.next_u64()));
    let colors: Vec<u32> = (0..samples.len()).map(|_| rng.next_u64() as u32).collect();
    let same = |a: &Quad, b: &Quad| {
        a.key == b.key
            && a.x == b.x
            && a.y == b.y
            && (a.x[0] > a.x[1]
                || a.edges.iter().flatten().zip(b.edges.iter().flatten()).all(|(p, q)| p.to_bits() == q.to_bits()))
    };
    let mut drawn = 0;
    for (deg, grown, size) in
        [(0.0, 0.5, (96, 96)), (10.0, 1.3, (96, 96)), (35.0, 2.0, (131, 77)), (170.0, 0.5, (96, 96))]
    {
        let mut camera = fc.orbit(deg, deg * 0.3);
        (camera.width, camera.height) = size;
        let mut setup = Setup::new(&camera, &fc, &deq, 0.5, grown, 230);
        // Without shared corners, and with some (each sample's own depth, a little off per
        // corner, some corners and samples not shared), at two area ratios.
        let none: Vec<[f32; 4]> = Vec::new();
        let some: Vec<[f32; 4]> = samples
            .iter()
            .enumerate()
            .map(|(i, &smp)| {
                let z = (deq.center(smp) - setup.src_eye).dot(setup.src_w);
                core::array::from_fn(|k| match (i + k) % 5 {
                    0 => f32::NAN,
                    j => z * (1.0 + 0.01 * j as f32 - 0.02),
                })
            })
            .map(|c| if rng.next_u64().is_multiple_of(4) { [f32::NAN; 4] } else { c })
            .collect();
        for (shared, ratio, limit) in [(&none, 1.0, 4.0), (&some, 1.0, 1.0), (&some, 0.0, 4.0), (&some, 1.5, 4.0)] {
            setup.water_ratio = ratio;
            setup.opacity_limit = limit;
            let (reference, colored): (Vec<Quad>, Vec<u32>) =
                samples.iter().enumerate().map(|(i, &smp)| setup.quad(smp, &colors, i, shared.get(i).copied())).unzip();
            drawn += reference.iter().filter(|q| q.x[0] <= q.x[1]).count();
            let mut portable = vec![Quad::NONE; samples.len()];
            let mut portable_colors = vec![0u32; samples.len()];
            footprint_lanes::<wide::f32x8>(&setup, &samples, &colors, shared, 0, &mut portable, &mut portable_colors);
            assert!(reference.iter().zip(&portable).all(|(a, b)| same(a, b)), "portable lanes differ at {deg}°");
            assert!(colored == portable_colors, "portable lanes draw other colors at {deg}°");
            #[cfg(target_arch = "x86_64")]
            if lanes::use_avx2() {
                let mut avx = vec![Quad::NONE; samples.len()];
                let mut avx_colors = vec![0u32; samples.len()];
                // SAFETY: the CPU has AVX2 (`use_avx2`).
                unsafe { footprints_avx2_for_tests(&setup, &samples, &colors, shared, 0, &mut avx, &mut avx_colors) };
                assert!(reference.iter().zip(&avx).all(|(a, b)| same(a, b)), "AVX2 lanes differ at {deg}°");
                assert!(colored == avx_colors, "AVX2 lanes draw other colors at {deg}°");
            }
            // Colors change only on shared corners, and only with a limit above 1.
            let recolored = colored.iter().zip(&colors).filter(|(a, b)| a != b).count();
            if shared.is_empty() || limit <= 1.0 || deg == 0.0 {
                assert_eq!(recolored, 0, "colors changed without shared corners at {deg}°");
            } else if ratio <= 1.0 && deg < 90.0 {
                // (With a ratio of 1.5 the slab's corners are taken only where they cover far
                // more than the plane, which these corners, each within 2 % of the sample's
                // depth, seldom do.)
                assert!(recolored > 0, "no color scaled at {deg}° (area ratio {ratio})");
            }
            if shared.is_empty() {
                continue;
            }
            // The shared corners change footprints (else this compares nothing new).
            let plain: Vec<Quad> =
                samples.iter().enumerate().map(|(i, &smp)| setup.quad(smp, &colors, i, None).0).collect();
            let changed = plain.iter().zip(&reference).filter(|(a, b)| !same(a, b)).count();
            assert!(ratio > 1.0 || changed > samples.len() / 10, "{changed} footprints changed at {deg}°");
        }
    }
    assert!(drawn > 6 * frame.samples.len(), "too few footprints drawn: {drawn}");
}

#[test]
fn lanes_project_like_the_scalar_reference() {
    use crate::synthetic::{depth_image_frame, SplitMix64};
    let frame = depth_image_frame(64, 1.0, 5);
    let deq = Dequantizer::new(frame.header.bounds, frame.header.radius_unit);
    let mut samples = frame.samples.clone();
    let mut rng = SplitMix64(11);
    samples.extend((0..301).map(|_| rng.next_u64()));
    let mut inside = 0;
    for (deg, size) in [(0.0, (64, 64)), (25.0, (97, 53)), (180.0, (64, 64))] {
        let mut camera = frame.header.camera.orbit(deg, deg * 0.2);
        (camera.width, camera.height) = size;
        let p = Proj::new(&View::new(&camera));
        let (w, h) = (size.0 as usize, size.1 as usize);
        let reference: Vec<(u32, Option<u32>)> = samples
            .iter()
            .map(|&smp| match pixel(&p, w, h, deq.center(smp)) {
                Some((i, z)) => (i as u32, Some(z.to_bits())),
                None => (NO_PIXEL, None),
            })
            .collect();
        inside += reference.iter().filter(|r| r.0 != NO_PIXEL).count();
        let check = |idx: &[u32], zs: &[f32], what: &str| {
            for (k, (&i, &z)) in idx.iter().zip(zs).enumerate() {
                assert_eq!(i, reference[k].0, "{what} at {deg}°, sample {k}");
                if let Some(bits) = reference[k].1 {
                    assert_eq!(z.to_bits(), bits, "{what} depth at {deg}°, sample {k}");
                }
            }
        };
        let (mut idx, mut zs) = (vec![0; samples.len()], vec![0.0; samples.len()]);
        let mut d2 = vec![0.0; samples.len()];
        project_lanes::<wide::f32x8>(&p, (w, h), &deq, &samples, &mut idx, &mut zs, &mut d2);
        check(&idx, &zs, "portable lanes");
        for (k, &smp) in samples.iter().enumerate() {
            let n = deq.center(smp) - p.eye;
            assert_eq!(d2[k].to_bits(), (n.x * n.x + n.y * n.y + n.z * n.z).to_bits(), "distance of {k}");
        }
        let mut d2_dispatched = vec![0.0; samples.len()];
        project(&p, (w, h), &deq, &samples, &mut idx, &mut zs, &mut d2_dispatched);
        check(&idx, &zs, "dispatched lanes");
        assert!(d2.iter().zip(&d2_dispatched).all(|(a, b)| a.to_bits() == b.to_bits()));
    }
    assert!(inside > frame.samples.len(), "too few samples in view: {inside}");
}

/// A frame in pixel order is grouped by the parallel path exactly as the counting sort
/// groups it, with samples outside the view (last, as the projection sorts them) or not.
#[test]
fn pixel_order_groups_like_the_counting_sort() {
    use crate::synthetic::{frame_from_points, Point};
    let frame = two_slab_frame();
    // A small frame in pixel order whose last two samples lie behind the eye.
    let camera = Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y, 40.0, 8, 8);
    let basis = camera.ray_basis();
    let mut pts: Vec<Point> = (0..64)
        .map(|i| Point {
            center: camera.eye + basis.dir(i % 8, i / 8) * 2.0,
            radius: 0.01,
            color: [0.2, 0.2, 0.2, 0.5],
        })
        .collect();
    pts.extend((0..2).map(|k| Point {
        center: camera.eye + Vec3::new(0.0, 0.0, 1.0 + k as f32),
        radius: 0.01,
        color: [0.1; 4],
    }));
    let away = frame_from_points(&pts, camera);
    for (f, n) in [(&frame, 1), (&frame, 3), (&away, 2)] {
        let threads = Threads::new(n);
        let scene = crate::route::unbuilt_scene(f);
        let mut own = OwnPass::default();
        own.project(&scene, &threads);
        assert!(own.at.windows(2).all(|p| p[0] >> 32 <= p[1] >> 32), "the frame is in pixel order");
        assert!(own.group(&threads));
        let (start, grouped) = (own.start.clone(), own.grouped.clone());
        own.group_any_order();
        assert_eq!(own.start, start);
        assert_eq!(own.grouped, grouped);
        // The frame behind the eye keeps its 64 samples in view, not the two behind.
        let in_view = if n == 2 { 64 } else { f.samples.len() };
        assert_eq!(grouped.len(), in_view);
    }
}

/// A layer of two semi-transparent slabs on a tilted, gently curved surface, one segment
/// per slab on every pixel's ray of a 96² camera.
fn two_slab_frame() -> volwarp_core::wire::Frame {
    use crate::synthetic::{frame_from_points, Point};
    let camera = Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y, 40.0, 96, 96);
    let basis = camera.ray_basis();
    let eye = camera.eye;
    let mut pts = Vec::new();
    for y in 0..96 {
        for x in 0..96 {
            let d = basis.dir(x, y);
            // The surface z = 0.5·x + 0.1·y² (tilted about 27° to the view, curved).
            let (mut t, mut hit) = (0.0, None);
            for _ in 0..40 {
                let p = eye + d * t;
                let f = p.z - (0.5 * p.x + 0.1 * p.y * p.y);
                if f.abs() < 1e-6 {
                    hit = Some(t);
                    break;
                }
                t += f / (-d.z + 0.5 * d.x + 0.2 * p.y * d.y);
            }
            let Some(t) = hit else { continue };
            for (k, dt) in [0.0f32, 0.02].into_iter().enumerate() {
                let a = 0.4;
                let c = if k == 0 { [0.35, 0.2, 0.1, a] } else { [0.1, 0.3, 0.35, a] };
                pts.push(Point { center: eye + d * (t + dt), radius: 0.01, color: c });
            }
        }
    }
    frame_from_points(&pts, camera)
}

/// Drawn 12° around the frame's camera, the slabs' footprints cover every pixel inside
/// the layer once per slab with shared corners; without, neighbouring footprints of one
/// slab overlap (a pixel takes it twice) and part (it misses it).
#[test]
fn shared_corners_make_each_slab_watertight() {
    let frame = two_slab_frame();
    let scene = crate::route::unbuilt_scene(&frame);
    let cam = frame.header.camera.orbit(12.0, 4.0);
    let mut out = Image::new(0, 0);
    let mut counts = Vec::new();
    for tol in [0.0, 3.0] {
        let opts = LayerOptions { fill: false, watertight: tol, water_ratio: 0.0, ..LayerOptions::DEFAULT };
        let mut r = LayerSplat::with_options(1, opts);
        r.render(&scene, &cam, &mut out);
        // Pixels inside the layer: between the first and last covered pixel of their row
        // and of their column, two pixels in.
        let (w, h) = (96usize, 96usize);
        let c = |x: usize, y: usize| r.count[y * w + x];
        let span = |v: Vec<u8>| {
            let first = v.iter().position(|&n| n > 0).unwrap_or(v.len());
            let last = v.iter().rposition(|&n| n > 0).unwrap_or(0);
            (first + 2, last.saturating_sub(2))
        };
        let mut hist = [0usize; 4];
        for y in 0..h {
            let (x0, x1) = span((0..w).map(|x| c(x, y)).collect());
            for x in x0..=x1.min(w - 1) {
                let (y0, y1) = span((0..h).map(|yy| c(x, yy)).collect());
                if (y0..=y1).contains(&y) {
                    hist[(c(x, y) as usize).min(3)] += 1;
                }
            }
        }
        counts.push(hist);
    }
    // The same frame with its samples in reverse order (each pixel's segments back to
    // front): the corners are found by sorting and moved to the samples' ids, and the
    // image is the same.
    let mut reversed = frame.clone();
    reversed.samples.reverse();
    reversed.colors.reverse();
    let opts = LayerOptions { fill: false, watertight: 3.0, water_ratio: 0.0, ..LayerOptions::DEFAULT };
    let (mut a, mut b) = (Image::new(0, 0), Image::new(0, 0));
    LayerSplat::with_options(1, opts).render(&scene, &cam, &mut a);
    LayerSplat::with_options(1, opts).render(&crate::route::unbuilt_scene(&reversed), &cam, &mut b);
    let same = a.pixels.iter().zip(&b.pixels).filter(|(p, q)| p == q).count();
    assert!(same * 1000 >= a.pixels.len() * 999, "{same} of {} pixels equal in reverse order", a.pixels.len());
    let (plain, tight) = (counts[0], counts[1]);
    let inside: usize = tight.iter().sum();
    assert!(inside > 3000, "the layer covers too little: {tight:?}");
    // Watertight: each pixel inside takes both slabs, once each.
    assert!(tight[2] * 1000 >= inside * 998, "shared corners: {tight:?} (count 0, 1, 2, 3+)");
    // Plain footprints: overlaps and gaps.
    assert!(plain[1] + plain[3] > inside / 50, "plain footprints: {plain:?}");
}

/// The shared corners as the definition states them, one segment and corner at a time:
/// the four pixels around the corner in row-then-column order, each joining with its
/// `j`-th segment where that lies within the tolerance of the segment's own depth.
fn corners_reference(own: &OwnPass, tol: f32) -> Vec<[f32; 4]> {
    let (proj, w, h) = own.proj.unwrap();
    let per_px = tol * 0.5 / proj.px_y;
    // Each pixel's depths front to back.
    let depths = |i: usize| -> Vec<f32> {
        let mut keys = own.grouped[own.start[i] as usize..own.start[i + 1] as usize].to_vec();
        keys.sort_unstable();
        keys.iter().map(|&k| f32::from_bits(own.at[k as u32 as usize] as u32)).collect()
    };
    let mut out = vec![[f32::NAN; 4]; own.at.len()];
    for y in 0..h {
        for x in 0..w {
            let mut keys = own.grouped[own.start[y * w + x] as usize..own.start[y * w + x + 1] as usize].to_vec();
            keys.sort_unstable();
            for (j, &key) in keys.iter().enumerate() {
                let z = f32::from_bits(own.at[key as u32 as usize] as u32);
                for (k, (sx, sy)) in [(-1i64, -1i64), (1, -1), (1, 1), (-1, 1)].into_iter().enumerate() {
                    let (cx, cy) = (x as i64 + (sx > 0) as i64, y as i64 + (sy < 0) as i64);
                    let (mut sum, mut count) = (0.0f32, 0.0f32);
                    for (px, py) in [(cx - 1, cy - 1), (cx, cy - 1), (cx - 1, cy), (cx, cy)] {
                        if px < 0 || py < 0 || px >= w as i64 || py >= h as i64 {
                            continue;
                        }
                        let d = depths(py as usize * w + px as usize);
                        let own_pixel = (px, py) == (x as i64, y as i64);
                        if let Some(&v) = d.get(j) {
                            if own_pixel || (v - z).abs() <= per_px * (v + z) {
                                sum += v;
                                count += 1.0;
                            }
                        }
                    }
                    out[key as u32 as usize][k] = corner(sum, count);
                }
            }
        }
    }
    out
}

/// The row stencil (on both lane types, on one thread and in parallel over bands of rows)
/// finds exactly the corners of the plain definition, on a frame in the server's order and
/// on the same frame shuffled.
#[test]
fn shared_corners_match_the_plain_definition() {
    let frame = two_slab_frame();
    let mut shuffled = frame.clone();
    let mut rng = crate::synthetic::SplitMix64(5);
    for i in (1..shuffled.samples.len()).rev() {
        let j = (rng.next_u64() % (i as u64 + 1)) as usize;
        shuffled.samples.swap(i, j);
        shuffled.colors.swap(i, j);
    }
    for (f, threads) in [(&frame, 1), (&shuffled, 1), (&frame, 2), (&shuffled, 3)] {
        let threads = Threads::new(threads);
        let scene = crate::route::unbuilt_scene(f);
        for tol in [1.5, 6.0] {
            let mut own = OwnPass::default();
            own.project(&scene, &threads);
            assert!(own.group(&threads));
            own.share_corners(tol, &threads);
            let reference = corners_reference(&own, tol);
            let same = |a: &[[f32; 4]], b: &[[f32; 4]]| {
                a.len() == b.len()
                    && a.iter().flatten().zip(b.iter().flatten()).all(|(p, q)| p.to_bits() == q.to_bits())
            };
            assert!(same(&own.shared, &reference), "tolerance {tol}");
            let shared = own.shared.iter().flatten().filter(|z| z.is_finite()).count();
            assert!(shared > own.shared.len(), "too few shared corners: {shared}");
            // The portable instance of the stencil, row band by row band (a frame in the
            // server's order: the corners are written by id).
            if core::ptr::eq(f, &frame) {
                let (proj, w, h) = own.proj.unwrap();
                let mut portable = vec![[f32::NAN; 4]; own.at.len()];
                band_corners_lanes::<wide::f32x8>(
                    &own.start,
                    Depths::Packed(&own.at),
                    (w, h),
                    tol * 0.5 / proj.px_y,
                    0..h,
                    &mut portable,
                    0,
                );
                assert!(same(&portable, &reference), "portable, tolerance {tol}");
            }
        }
    }
}

/// A frame that puts thousands of samples on one pixel: no panic, no buffer sized by them,
/// shared corners only for the nearest `LIST` of them, and an image without NaN colors.
#[test]
fn a_crowded_pixel_shares_only_its_nearest_slabs() {
    let mut frame = two_slab_frame();
    let (s0, c0) = (frame.samples[1000], frame.colors[1000]);
    let at = 1001;
    for _ in 0..5000 {
        frame.samples.insert(at, s0);
        frame.colors.insert(at, c0);
    }
    let scene = crate::route::unbuilt_scene(&frame);
    let threads = Threads::new(1);
    let mut own = OwnPass::default();
    own.project(&scene, &threads);
    assert!(own.group(&threads));
    own.share_corners(3.0, &threads);
    let (_, w, _) = own.proj.unwrap();
    let crowded = (0..own.start.len() - 1).max_by_key(|&i| own.start[i + 1] - own.start[i]).unwrap();
    let (a, e) = (own.start[crowded] as usize, own.start[crowded + 1] as usize);
    assert!(e - a > 5000, "{} samples on the crowded pixel {crowded} of a {w}-wide frame", e - a);
    let mut keys = own.grouped[a..e].to_vec();
    keys.sort_unstable();
    let far = keys[LIST..].iter().filter(|&&k| own.shared[k as u32 as usize].iter().any(|z| z.is_finite())).count();
    assert_eq!(far, 0, "segments past the nearest {LIST} share corners");
    let mut img = Image::new(0, 0);
    let cam = frame.header.camera.orbit(10.0, 0.0);
    LayerSplat::new(1).render(&scene, &cam, &mut img);
    assert!(img.pixels.iter().any(|&p| p != BACKGROUND));
}

/// The optical-depth scaling's own log2 and 2^y follow the standard ones closely enough for
/// 8-bit colors, and the drawn colors behave: unchanged at depth 1, more opaque for a slab
/// crossed along a longer path, less for a shorter one, premultiplied throughout, clamped to
/// the limit, and transparent or opaque samples untouched.
#[test]
fn drawn_colors_scale_the_optical_depth() {
    use crate::layered::{drawn_color, exp2_poly, log2_poly};
    for a8 in 1..=254u32 {
        let x = 1.0 - a8 as f32 / 255.0;
        assert!((log2_poly(x) - x.log2()).abs() < 2e-6, "log2 at {x}");
    }
    for k in 0..=4000 {
        let y = -40.0 + k as f32 * 0.01;
        let want = y.exp2();
        assert!((exp2_poly(y) - want).abs() <= 1e-6 * want, "2^{y}");
    }
    assert_eq!(exp2_poly(-200.0), 0.0);
    assert_eq!(exp2_poly(f32::NAN), 0.0);
    for a8 in [1u8, 30, 64, 128, 200, 254] {
        let c = u32::from_le_bytes([a8 / 2, a8 / 3, a8, a8]);
        assert_eq!(drawn_color(c, 1.0, 4.0), c);
        assert_eq!(drawn_color(c, 2.0, 1.0), c, "a limit of 1 scales nothing");
        assert_eq!(drawn_color(c, f32::NAN, 4.0), c);
        let (thick, thin) = (drawn_color(c, 2.0, 4.0).to_le_bytes(), drawn_color(c, 0.5, 4.0).to_le_bytes());
        // 1 − (1 − α)², and 1 − (1 − α)^½, to the nearest level.
        let a = a8 as f64 / 255.0;
        assert!((thick[3] as f64 - 255.0 * (1.0 - (1.0 - a).powi(2))).abs() <= 0.5 + 1e-3, "{a8}: {thick:?}");
        assert!((thin[3] as f64 - 255.0 * (1.0 - (1.0 - a).sqrt())).abs() <= 0.5 + 1e-3, "{a8}: {thin:?}");
        assert!(thick[3] >= a8 && thin[3] <= a8);
        for q in [thick, thin] {
            assert!(q[0] <= q[3] && q[1] <= q[3] && q[2] <= q[3], "{q:?} is not premultiplied");
        }
        assert_eq!(drawn_color(c, 100.0, 4.0), drawn_color(c, 4.0, 4.0), "clamped to the limit");
    }
    for c in [0u32, 0x00ff_ffff, 0xff10_2030] {
        assert_eq!(drawn_color(c, 3.0, 4.0), c, "transparent and opaque samples stay");
    }
}
