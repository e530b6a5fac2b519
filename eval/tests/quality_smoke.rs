//! The quality sweep end to end on the bundled dataset at 64² (no timing): every renderer is
//! scored at every angle, the GPU tracer (where present) agrees with the CPU tracer, the CSV has
//! exactly the documented columns and the charts are drawn.

use volwarp_eval::quality::{evaluate, QualityOptions, QUALITY_COLUMNS};
use volwarp_eval::roster::{roster, RosterOptions};
use volwarp_server::{Dataset, Marcher};

#[test]
fn quality_sweep_writes_every_row_and_chart() {
    let ds = Dataset::default_bundled();
    let opts = QualityOptions { size: 64, runs: 0, angles: vec![0.0, 10.0], dolly: vec![0.85], ..Default::default() };
    let mut r = roster(RosterOptions { threads: 2, gpu: true });
    let res = evaluate(
        &ds.name,
        &Marcher::from_dataset(&ds),
        &[volwarp_core::Heuristic::Threshold],
        &mut r,
        &opts,
        &mut |_| {},
    );
    assert_eq!(res.rows.len(), 2 * r.len());
    assert_eq!(res.dolly_rows.len(), r.len());
    let get = |name: &str, a: f32| res.rows.iter().find(|x| x.renderer == name && x.angle_deg == a).map(|x| x.metrics);
    // Unwarped, the stale image and 1-pixel points reproduce the frame exactly.
    assert_eq!(get("stale", 0.0).unwrap().flip, 0.0);
    assert_eq!(get("points1", 0.0).unwrap().flip, 0.0);
    // Exact splatting and tracing draw the same spheres; so does the GPU tracer where present.
    let sp = get("spheres-cpu", 10.0).unwrap();
    assert!((get("splat", 10.0).unwrap().flip - sp.flip).abs() < 1e-3);
    if let Some(g) = get("spheres-gpu", 10.0) {
        assert!((g.flip - sp.flip).abs() < 1e-3, "GPU {g:?} vs CPU {sp:?}");
    }
    // Moving the camera costs accuracy.
    assert!(get("stale", 10.0).unwrap().flip > 0.0);
    assert_eq!(res.strip.truth.len(), 2);
    let dir = std::env::temp_dir().join(format!("volwarp-quality-{}", std::process::id()));
    let res_rows = res.rows.clone();
    volwarp_eval::report::write_quality_for_test(&[(ds.name.clone(), res)], &dir).unwrap();
    let csv = std::fs::read_to_string(dir.join("quality.csv")).unwrap();
    assert_eq!(csv.lines().next().unwrap(), QUALITY_COLUMNS.join(","));
    assert_eq!(csv.lines().count(), 1 + 2 * r.len());
    let parsed = volwarp_eval::report::parse_quality_csv(&csv).unwrap();
    assert_eq!(parsed.len(), 2 * r.len());
    assert!(parsed
        .iter()
        .zip(&res_rows)
        .all(|(a, b)| a.renderer == b.renderer && (a.metrics.flip - b.metrics.flip).abs() < 1e-4));
    volwarp_eval::report::replot(&dir).unwrap();
    for f in ["error_vs_angle.png", "speed_vs_accuracy.png", "heuristics.png", "strip.png", "dolly.csv"] {
        assert!(dir.join(f).is_file(), "{f} missing");
    }
    std::fs::remove_dir_all(&dir).ok();
}
