//! Our PSNR, SSIM and FLIP against the reference implementations (scikit-image and NVIDIA's
//! `flip-evaluator` 1.7) on the committed 64² image pairs in `eval/fixtures/` (truth and a
//! warped render each; `eval/fixtures/reference.py` made `reference.csv`).

use std::path::Path;
use volwarp_eval::metrics::{flip, psnr, ssim};

#[test]
fn metrics_match_the_reference_implementations() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures");
    let text = std::fs::read_to_string(dir.join("reference.csv")).unwrap();
    let mut n = 0;
    for line in text.lines().skip(1).filter(|l| !l.is_empty()) {
        let f: Vec<&str> = line.split(',').collect();
        let (name, flip_ref, psnr_ref, ssim_ref) =
            (f[0], f[1].parse::<f64>().unwrap(), f[2].parse::<f64>().unwrap(), f[3].parse::<f64>().unwrap());
        let a = volwarp_core::Image::load_png(&dir.join(format!("{name}_ref.png")), 1 << 20).unwrap();
        let b = volwarp_core::Image::load_png(&dir.join(format!("{name}_test.png")), 1 << 20).unwrap();
        let ours = flip::flip(&a, &b).unwrap();
        assert!((ours - flip_ref).abs() < 1e-5, "{name}: FLIP {ours} vs reference {flip_ref}");
        let p = psnr::psnr(&a, &b).unwrap();
        assert!((p - psnr_ref).abs() < 1e-4, "{name}: PSNR {p} vs reference {psnr_ref}");
        let s = ssim::ssim(&a, &b).unwrap();
        assert!((s - ssim_ref).abs() < 1e-5, "{name}: SSIM {s} vs reference {ssim_ref}");
        println!("{name}: FLIP {ours:.7} (ref {flip_ref:.7})  PSNR {p:.4} (ref {psnr_ref:.4})  SSIM {s:.6} (ref {ssim_ref:.6})");
        n += 1;
    }
    assert!(n >= 4, "fixtures missing");
}
