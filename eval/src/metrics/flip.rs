//! LDR-ꟻLIP (Andersson, Nilsson, Akenine-Möller, Oskarsson, Åström, Fairchild: "FLIP: A
//! Difference Evaluator for Alternating Images", HPG 2020), as NVIDIA's reference
//! implementation computes it (the `flip-evaluator` Python package, version 1.7, which wraps the
//! C++ `FLIP.h`).
//!
//! Pipeline, per image pair (sRGB 8-bit in, error map in 0..=1 out):
//! 1. sRGB → linear RGB → XYZ (D65) → YCxCz (a linearized CIELab).
//! 2. **Color pipeline.** Each YCxCz channel is filtered with the contrast sensitivity
//!    functions of the paper (sums of Gaussians in visual degrees at [`DEFAULT_PPD`] pixels per
//!    degree), applied separably with clamp-to-edge borders; the blue–yellow channel's sum of
//!    two Gaussians is split into two separable filters. The filtered colors go back to linear
//!    RGB, are clamped to 0..=1, converted to CIELab, Hunt-adjusted (`a, b *= 0.01 · L`), and
//!    compared with the HyAB distance raised to `q_c = 0.7`; that is remapped so that
//!    `p_c · c_max` maps to `p_t = 0.95` (`c_max` is the green–blue distance).
//! 3. **Feature pipeline.** The normalized achromatic channel `(Y + 16) / 116` is filtered with
//!    the first and second derivatives of a Gaussian of σ = ½ · 0.082° (edges and points); the
//!    feature difference is `(max(|Δedge|, |Δpoint|) / √2)^0.5`.
//! 4. `FLIP = color^(1 − feature)` per pixel; the mean over all pixels is the score.
//!
//! All arithmetic is `f32` like the reference, in the same order, so the mean agrees with
//! `flip_evaluator.evaluate(ref, test, "LDR")` to about 1e-6 (tested against committed
//! fixtures in `eval/fixtures/`). The mean itself is accumulated in `f64`.

// The constants are written as in the reference, digit for digit, so they can be compared.
#![allow(clippy::excessive_precision)]

use super::psnr::same_shape;
use rayon::prelude::*;
use volwarp_core::Image;

/// Pixels per degree of the reference's default viewing setup: a 0.7 m wide 3840-pixel
/// monitor seen from 0.7 m.
pub const DEFAULT_PPD: f32 = 0.7 * (3840.0 / 0.7) * (PI / 180.0);

const PI: f32 = std::f32::consts::PI;
const QC: f32 = 0.7;
const PC: f32 = 0.4;
const PT: f32 = 0.95;
const GW: f32 = 0.082;
const QF: f32 = 0.5;

const ILLUMINANT: [f32; 3] = [0.950428545, 1.000000000, 1.088900371];
const INV_ILLUMINANT: [f32; 3] = [1.052156925, 1.000000000, 0.918357670];

// Contrast sensitivity parameters (a1, b1, a2, b2) of the Y, Cx and Cz channels.
const A1: [f32; 3] = [1.0, 1.0, 34.1];
const B1: [f32; 3] = [0.0047, 0.0053, 0.04];
const A2: [f32; 3] = [0.0, 0.0, 13.5];
const B2: [f32; 3] = [1.0e-5, 1.0e-5, 0.025];

type C3 = [f32; 3];

#[inline]
fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

#[inline]
fn linear_rgb_to_xyz(c: C3) -> C3 {
    let a11 = 10135552.0f32 / 24577794.0;
    let a12 = 8788810.0f32 / 24577794.0;
    let a13 = 4435075.0f32 / 24577794.0;
    let a21 = 2613072.0f32 / 12288897.0;
    let a22 = 8788810.0f32 / 12288897.0;
    let a23 = 887015.0f32 / 12288897.0;
    let a31 = 1425312.0f32 / 73733382.0;
    let a32 = 8788810.0f32 / 73733382.0;
    let a33 = 70074185.0f32 / 73733382.0;
    [a11 * c[0] + a12 * c[1] + a13 * c[2], a21 * c[0] + a22 * c[1] + a23 * c[2], a31 * c[0] + a32 * c[1] + a33 * c[2]]
}

#[inline]
fn xyz_to_linear_rgb(c: C3) -> C3 {
    [
        3.241003275 * c[0] + -1.537398934 * c[1] + -0.498615861 * c[2],
        -0.969224334 * c[0] + 1.875930071 * c[1] + 0.041554224 * c[2],
        0.055639423 * c[0] + -0.204011202 * c[1] + 1.057148933 * c[2],
    ]
}

#[inline]
fn xyz_to_ycxcz(c: C3) -> C3 {
    let (x, y, z) = (c[0] * INV_ILLUMINANT[0], c[1] * INV_ILLUMINANT[1], c[2] * INV_ILLUMINANT[2]);
    [116.0 * y - 16.0, 500.0 * (x - y), 200.0 * (y - z)]
}

#[inline]
fn ycxcz_to_xyz(c: C3) -> C3 {
    let y = (c[0] + 16.0) / 116.0;
    let cx = c[1] / 500.0;
    let cz = c[2] / 200.0;
    [(y + cx) * ILLUMINANT[0], y * ILLUMINANT[1], (y - cz) * ILLUMINANT[2]]
}

#[inline]
fn xyz_to_cielab(c: C3) -> C3 {
    let delta = 6.0f32 / 29.0;
    let delta_square = delta * delta;
    let delta_cube = delta * delta_square;
    let factor = 1.0 / (3.0 * delta_square);
    let term = 4.0f32 / 29.0;
    let f = |v: f32| if v > delta_cube { v.powf(1.0 / 3.0) } else { factor * v + term };
    let (x, y, z) = (f(c[0] * INV_ILLUMINANT[0]), f(c[1] * INV_ILLUMINANT[1]), f(c[2] * INV_ILLUMINANT[2]));
    [116.0 * y - 16.0, 500.0 * (x - y), 200.0 * (y - z)]
}

#[inline]
fn hunt(l: f32, c: f32) -> f32 {
    0.01 * l * c
}

#[inline]
fn hyab(a: C3, b: C3) -> f32 {
    (a[0] - b[0]).abs() + ((a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2])).sqrt()
}

fn hunt_lab(rgb: C3) -> C3 {
    let lab = xyz_to_cielab(linear_rgb_to_xyz(rgb));
    [lab[0], hunt(lab[0], lab[1]), hunt(lab[0], lab[2])]
}

/// The largest color distance: between pure green and pure blue, after `q_c`.
fn max_distance() -> f32 {
    hyab(hunt_lab([0.0, 1.0, 0.0]), hunt_lab([0.0, 0.0, 1.0])).powf(QC)
}

#[inline]
fn gaussian_ab(x2: f32, a: f32, b: f32) -> f32 {
    let pi_sq = PI * PI;
    a * (PI / b).sqrt() * (-pi_sq * x2 / b).exp()
}

#[inline]
fn gaussian_sqrt(x2: f32, a: f32, b: f32) -> f32 {
    let pi_sq = PI * PI;
    (a * (PI / b).sqrt()).sqrt() * (-pi_sq * x2 / b).exp()
}

fn spatial_radius(ppd: f32) -> usize {
    let pi_sq = PI * PI;
    let max_b = B1.iter().chain(B2.iter()).fold(0.0f32, |m, &b| m.max(b));
    (3.0 * (max_b / (2.0 * pi_sq)).sqrt() * ppd).ceil() as usize
}

/// The separable spatial filters: `(Y, Cx)` taps and the two `Cz` taps.
fn spatial_filters(ppd: f32) -> (Vec<[f32; 2]>, Vec<[f32; 2]>) {
    let r = spatial_radius(ppd) as i32;
    let dx = 1.0 / ppd;
    let mut ycx = Vec::new();
    let mut cz = Vec::new();
    let (mut s_ycx, mut s_cz) = ([0.0f32; 2], [0.0f32; 2]);
    for i in -r..=r {
        let x = i as f32 * dx;
        let x2 = x * x;
        let a = [gaussian_ab(x2, A1[0], B1[0]), gaussian_ab(x2, A1[1], B1[1])];
        let b = [gaussian_sqrt(x2, A1[2], B1[2]), gaussian_sqrt(x2, A2[2], B2[2])];
        s_ycx[0] += a[0];
        s_ycx[1] += a[1];
        s_cz[0] += b[0];
        s_cz[1] += b[1];
        ycx.push(a);
        cz.push(b);
    }
    let n_ycx = [1.0 / s_ycx[0], 1.0 / s_ycx[1]];
    let n_cz = 1.0 / (s_cz[0] * s_cz[0] + s_cz[1] * s_cz[1]).sqrt();
    for v in &mut ycx {
        *v = [v[0] * n_ycx[0], v[1] * n_ycx[1]];
    }
    for v in &mut cz {
        *v = [v[0] * n_cz, v[1] * n_cz];
    }
    (ycx, cz)
}

/// The feature filter taps: Gaussian, first and second derivative.
fn feature_filter(ppd: f32) -> Vec<C3> {
    let sd = 0.5 * GW * ppd;
    let r = (3.0 * sd).ceil() as i32;
    let mut taps = Vec::new();
    let (mut g_sum, mut dg_neg, mut dg_pos, mut ddg_neg, mut ddg_pos) = (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
    for i in -r..=r {
        let x = i as f32;
        let g = (-(x * x) / (2.0 * sd * sd)).exp();
        g_sum += g;
        let dg = -x * g;
        if dg > 0.0 {
            dg_pos += dg;
        } else {
            dg_neg -= dg;
        }
        let ddg = (x * x / (sd * sd) - 1.0) * g;
        if ddg > 0.0 {
            ddg_pos += ddg;
        } else {
            ddg_neg -= ddg;
        }
        taps.push([g, dg, ddg]);
    }
    for t in &mut taps {
        *t = [
            t[0] / g_sum,
            t[1] / if t[1] > 0.0 { dg_pos } else { dg_neg },
            t[2] / if t[2] > 0.0 { ddg_pos } else { ddg_neg },
        ];
    }
    taps
}

/// The per-pixel LDR-ꟻLIP error map of `test` against `reference` (row-major, values in
/// 0..=1) at `ppd` pixels per degree; `None` if the sizes differ or the images are empty.
pub fn flip_map(reference: &Image, test: &Image, ppd: f32) -> Option<Vec<f32>> {
    if !same_shape(reference, test) || reference.pixels.is_empty() || !(ppd > 0.0 && ppd.is_finite()) {
        return None;
    }
    let (w, h) = (reference.width as usize, reference.height as usize);
    let to_ycxcz = |img: &Image| -> Vec<C3> {
        img.pixels
            .par_iter()
            .map(|&p| {
                let [r, g, b, _] = p.to_le_bytes();
                let lin = [r, g, b].map(|c| srgb_to_linear(c as f32 / 255.0));
                xyz_to_ycxcz(linear_rgb_to_xyz(lin))
            })
            .collect()
    };
    let (rf, ts) = (to_ycxcz(reference), to_ycxcz(test));
    let color = color_difference(&rf, &ts, w, h, ppd);
    Some(feature_and_final(&rf, &ts, &color, w, h, ppd))
}

/// Mean LDR-ꟻLIP error at [`DEFAULT_PPD`] (0 for identical images, at most 1).
pub fn flip(reference: &Image, test: &Image) -> Option<f64> {
    let map = flip_map(reference, test, DEFAULT_PPD)?;
    Some(map.iter().map(|&v| v as f64).sum::<f64>() / map.len() as f64)
}

#[inline]
fn clampi(v: isize, n: usize) -> usize {
    v.clamp(0, n as isize - 1) as usize
}

fn color_difference(rf: &[C3], ts: &[C3], w: usize, h: usize, ppd: f32) -> Vec<f32> {
    let (f_ycx, f_cz) = spatial_filters(ppd);
    let half = (f_ycx.len() / 2) as isize;
    // x pass: per pixel (Y, Cx, Cz1, Cz2) for both images.
    let mut inter = vec![[[0.0f32; 4]; 2]; w * h];
    inter.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let mut acc = [[0.0f32; 4]; 2];
            for i in -half..=half {
                let xx = clampi(x as isize + i, w);
                let (a, b) = (f_ycx[(i + half) as usize], f_cz[(i + half) as usize]);
                for (k, img) in [rf, ts].iter().enumerate() {
                    let c = img[y * w + xx];
                    acc[k][0] += a[0] * c[0];
                    acc[k][1] += a[1] * c[1];
                    acc[k][2] += b[0] * c[2];
                    acc[k][3] += b[1] * c[2];
                }
            }
            *o = acc;
        }
    });
    let cmax = max_distance();
    let pccmax = PC * cmax;
    let mut out = vec![0.0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let mut acc = [[0.0f32; 4]; 2];
            for i in -half..=half {
                let yy = clampi(y as isize + i, h);
                let (a, b) = (f_ycx[(i + half) as usize], f_cz[(i + half) as usize]);
                let v = &inter[yy * w + x];
                for k in 0..2 {
                    acc[k][0] += a[0] * v[k][0];
                    acc[k][1] += a[1] * v[k][1];
                    acc[k][2] += b[0] * v[k][2];
                    acc[k][3] += b[1] * v[k][3];
                }
            }
            let lab = |m: [f32; 4]| {
                let rgb = xyz_to_linear_rgb(ycxcz_to_xyz([m[0], m[1], m[2] + m[3]])).map(|c| c.clamp(0.0, 1.0));
                hunt_lab(rgb)
            };
            let mut d = hyab(lab(acc[0]), lab(acc[1])).powf(QC);
            if d < pccmax {
                d *= PT / pccmax;
            } else {
                d = PT + ((d - pccmax) / (cmax - pccmax)) * (1.0 - PT);
            }
            *o = d;
        }
    });
    out
}

fn feature_and_final(rf: &[C3], ts: &[C3], color: &[f32], w: usize, h: usize, ppd: f32) -> Vec<f32> {
    let f = feature_filter(ppd);
    let half = (f.len() / 2) as isize;
    let (one_over_116, sixteen_over_116) = (1.0f32 / 116.0, 16.0f32 / 116.0);
    // x pass: (dx, ddx, gaussian) for both images.
    let mut inter = vec![[[0.0f32; 3]; 2]; w * h];
    inter.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let mut acc = [[0.0f32; 3]; 2];
            for i in -half..=half {
                let xx = clampi(x as isize + i, w);
                let t = f[(i + half) as usize];
                for (k, img) in [rf, ts].iter().enumerate() {
                    let v = img[y * w + xx][0] * one_over_116 + sixteen_over_116;
                    acc[k][0] += t[1] * v;
                    acc[k][1] += t[2] * v;
                    acc[k][2] += t[0] * v;
                }
            }
            *o = acc;
        }
    });
    let norm = 1.0 / 2.0f32.sqrt();
    let mut out = vec![0.0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            // Per image: dx, ddx, dy, ddy.
            let mut acc = [[0.0f32; 4]; 2];
            for i in -half..=half {
                let yy = clampi(y as isize + i, h);
                let t = f[(i + half) as usize];
                let v = &inter[yy * w + x];
                for k in 0..2 {
                    acc[k][0] += t[0] * v[k][0];
                    acc[k][1] += t[0] * v[k][1];
                    acc[k][2] += t[1] * v[k][2];
                    acc[k][3] += t[2] * v[k][2];
                }
            }
            let edge = |m: [f32; 4]| (m[0] * m[0] + m[2] * m[2]).sqrt();
            let point = |m: [f32; 4]| (m[1] * m[1] + m[3] * m[3]).sqrt();
            let de = (edge(acc[0]) - edge(acc[1])).abs();
            let dp = (point(acc[0]) - point(acc[1])).abs();
            let feature = (norm * de.max(dp)).powf(QF);
            *o = color[y * w + x].powf(1.0 - feature);
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use volwarp_core::sample::pack_color;

    fn solid(w: u32, h: u32, c: u32) -> Image {
        Image { width: w, height: h, pixels: vec![c; (w * h) as usize] }
    }

    #[test]
    fn filter_sizes_match_the_reference_at_67_ppd() {
        assert!((DEFAULT_PPD - 67.0206).abs() < 1e-3);
        assert_eq!(spatial_radius(DEFAULT_PPD), 10);
        assert_eq!(feature_filter(DEFAULT_PPD).len(), 2 * 9 + 1);
        let (a, b) = spatial_filters(DEFAULT_PPD);
        let s: f32 = a.iter().map(|v| v[0]).sum();
        assert!((s - 1.0).abs() < 1e-5);
        assert_eq!(b.len(), 21);
    }

    #[test]
    fn identical_is_zero_and_black_white_is_large() {
        let a = solid(24, 24, pack_color(30, 140, 200, 255));
        assert_eq!(flip(&a, &a), Some(0.0));
        let b = solid(24, 24, pack_color(0, 0, 0, 255));
        let c = solid(24, 24, pack_color(255, 255, 255, 255));
        let e = flip(&b, &c).unwrap();
        assert!(e > 0.5 && e <= 1.0, "{e}");
        assert_eq!(flip(&b, &solid(24, 23, 0)), None);
    }
}
