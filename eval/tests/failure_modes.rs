//! Every renderer driven into the cases where warping breaks down (`volwarp_eval::failure_modes`):
//! each must finish without panicking, produce a defined image (the viewport's size, every
//! pixel opaque) and finite scores. The GPU tracer takes part where an adapter opens.

use volwarp_core::BACKGROUND;
use volwarp_eval::failure_modes::{run_case, CASES};
use volwarp_eval::roster::{roster, RosterOptions};
use volwarp_server::{Dataset, Marcher};

const SIZE: u32 = 64;

#[test]
fn every_renderer_survives_every_failure_case() {
    let ds = Dataset::default_bundled();
    let base = Marcher::from_dataset(&ds);
    let mut r = roster(RosterOptions { threads: 2, gpu: true });
    assert!(r.len() >= 8, "the roster lost renderers");
    let mut baseline_flip = f64::NAN;
    for case in &CASES {
        let res = run_case(case, &base, volwarp_core::Heuristic::Threshold, SIZE, &mut r);
        assert_eq!(res.outcomes.len(), r.len());
        for o in &res.outcomes {
            assert!(o.defined, "{}: {} gave an undefined image", case.name, o.renderer);
            let m = o.metrics;
            assert!(
                m.psnr.is_finite() && m.ssim.is_finite() && m.flip.is_finite(),
                "{}: {}: {m:?}",
                case.name,
                o.renderer
            );
            // The scores are those of the image shown: recomputed from it, and ꟻLIP 0 exactly
            // where it is the truth pixel for pixel.
            let again = volwarp_eval::Metrics::of(&res.truth, &o.image).expect("same size");
            assert_eq!(
                again.flip.to_bits(),
                m.flip.to_bits(),
                "{}: {}: the scores are not the image's",
                case.name,
                o.renderer
            );
            let exact = o.image.pixels == res.truth.pixels;
            assert_eq!(
                m.flip == 0.0,
                exact,
                "{}: {}: ꟻLIP {} for an image exact: {exact}",
                case.name,
                o.renderer,
                m.flip
            );
        }
        let spheres = res.outcomes.iter().find(|o| o.renderer == "spheres-cpu").unwrap();
        match case.name {
            "baseline-10deg" => {
                assert!(res.samples > 0);
                baseline_flip = spheres.metrics.flip;
            }
            "transparent" => {
                // No samples: every renderer and the truth show only the background.
                assert_eq!(res.samples, 0);
                assert!(res.truth.pixels.iter().all(|&p| p == BACKGROUND));
                for o in &res.outcomes {
                    assert!(o.image.pixels.iter().all(|&p| p == BACKGROUND), "{}", o.renderer);
                }
            }
            "opaque" => {
                // A solid block: every pixel near the image centre is covered in the truth.
                let c = res.truth.get(SIZE / 2, SIZE / 2);
                assert_ne!(c, BACKGROUND);
                assert!(res.samples > 0);
            }
            "turn-180" | "disocclusion" => {
                // Much worse than an ordinary 10° orbit.
                assert!(
                    spheres.metrics.flip > baseline_flip,
                    "{}: {} vs {baseline_flip}",
                    case.name,
                    spheres.metrics.flip
                );
            }
            _ => {}
        }
    }
}
