//! The cases where warping breaks down ("where methods fail"): a transfer function
//! that makes everything transparent (a frame with no samples), one that makes everything
//! opaque, a thin isosurface, a camera inside the volume, a 180° turn (looking at the back of
//! the samples), extreme zoom in and out, and heavy disocclusion. Each case is a transfer
//! function for the frame and the truth, the frame's camera and the camera it is warped to.
//! [`run_case`] drives every renderer through it and scores the result; the integration test
//! `tests/failure_modes.rs` and `volwarp-eval failures` both use it.

use crate::camera_paths::orbit;
use crate::quality::frame_for;
use crate::roster::{Entry, SceneSet};
use crate::{is_defined, Metrics};
use volwarp_core::{Camera, Heuristic, Image};
use volwarp_server::{MarchOptions, Marcher, TransferFunction};

/// How the transfer function of a case is made.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TfKind {
    /// The dataset's own.
    Dataset,
    /// Opacity 0 everywhere.
    Transparent,
    /// Opacity 1 everywhere (air included: the volume box is a solid block).
    Opaque,
    /// Opacity 1 only in a narrow band (±1 % of the range) around 40 % of the value range.
    ThinIso,
}

/// One failure case.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Case {
    /// Short name (CSV and file names).
    pub name: &'static str,
    /// What it stresses.
    pub what: &'static str,
    /// The transfer function.
    pub tf: TfKind,
    /// Dolly factor of the frame's camera C0 relative to the default framing.
    pub c0_dolly: f32,
    /// Yaw, pitch (degrees) and dolly factor of the camera the frame is warped to, relative to
    /// C0.
    pub yaw: f32,
    /// See `yaw`.
    pub pitch: f32,
    /// See `yaw`.
    pub dolly: f32,
}

/// The baseline (an ordinary 10° orbit) and every failure case.
pub const CASES: [Case; 9] = [
    Case {
        name: "baseline-10deg",
        what: "an ordinary 10° orbit",
        tf: TfKind::Dataset,
        c0_dolly: 1.0,
        yaw: 10.0,
        pitch: 0.0,
        dolly: 1.0,
    },
    Case {
        name: "transparent",
        what: "no sample at all",
        tf: TfKind::Transparent,
        c0_dolly: 1.0,
        yaw: 10.0,
        pitch: 0.0,
        dolly: 1.0,
    },
    Case {
        name: "opaque",
        what: "a solid block: only its front faces are sampled",
        tf: TfKind::Opaque,
        c0_dolly: 1.0,
        yaw: 20.0,
        pitch: 0.0,
        dolly: 1.0,
    },
    Case {
        name: "thin-iso",
        what: "a thin, fully opaque isosurface",
        tf: TfKind::ThinIso,
        c0_dolly: 1.0,
        yaw: 10.0,
        pitch: 0.0,
        dolly: 1.0,
    },
    Case {
        name: "inside",
        what: "the camera inside the volume",
        tf: TfKind::Dataset,
        c0_dolly: 0.12,
        yaw: 10.0,
        pitch: 0.0,
        dolly: 1.0,
    },
    Case {
        name: "turn-180",
        what: "looking at the back of the samples",
        tf: TfKind::Dataset,
        c0_dolly: 1.0,
        yaw: 180.0,
        pitch: 0.0,
        dolly: 1.0,
    },
    Case {
        name: "zoom-in",
        what: "dolly to 0.3× the distance",
        tf: TfKind::Dataset,
        c0_dolly: 1.0,
        yaw: 0.0,
        pitch: 0.0,
        dolly: 0.3,
    },
    Case {
        name: "zoom-out",
        what: "dolly to 20× the distance",
        tf: TfKind::Dataset,
        c0_dolly: 1.0,
        yaw: 0.0,
        pitch: 0.0,
        dolly: 20.0,
    },
    Case {
        name: "disocclusion",
        what: "60° yaw and 45° pitch: most of what shows was hidden",
        tf: TfKind::Dataset,
        c0_dolly: 1.0,
        yaw: 60.0,
        pitch: 45.0,
        dolly: 1.0,
    },
];

impl Case {
    /// The frame's camera for a viewport of `size`².
    pub fn c0(&self, marcher: &Marcher, size: u32) -> Camera {
        marcher.default_camera(size, size).dolly(self.c0_dolly)
    }

    /// The camera the frame is warped to.
    pub fn target(&self, c0: &Camera) -> Camera {
        let c = if self.pitch != 0.0 { c0.orbit(self.yaw, self.pitch) } else { orbit(c0, self.yaw) };
        if self.dolly != 1.0 {
            c.dolly(self.dolly)
        } else {
            c
        }
    }

    /// The case's marcher (same volume, the case's transfer function).
    pub fn marcher(&self, base: &Marcher) -> Marcher {
        let tf = match self.tf {
            TfKind::Dataset => return base.clone(),
            TfKind::Transparent => TransferFunction::from_points("transparent", &[], &[(0.0, 0.0), (1.0, 0.0)]),
            TfKind::Opaque => TransferFunction::from_points(
                "opaque",
                &[(0.0, [0.2, 0.3, 0.8]), (1.0, [1.0, 0.9, 0.6])],
                &[(0.0, 1.0), (1.0, 1.0)],
            ),
            TfKind::ThinIso => TransferFunction::from_points(
                "thin-iso",
                &[(0.0, [0.9, 0.8, 0.7]), (1.0, [0.9, 0.8, 0.7])],
                &[(0.0, 0.0), (0.39, 0.0), (0.40, 1.0), (0.41, 0.0), (1.0, 0.0)],
            ),
        };
        base.with_transfer_function(&tf, MarchOptions::default())
    }
}

/// One renderer's result in one case.
#[derive(Clone, Debug)]
pub struct Outcome {
    /// Renderer name.
    pub renderer: String,
    /// Right size and every pixel opaque.
    pub defined: bool,
    /// Scores against the truth (finite for a defined image).
    pub metrics: Metrics,
    /// The image.
    pub image: Image,
}

/// Everything one case produced.
#[derive(Clone, Debug)]
pub struct CaseResult {
    /// The case.
    pub case: Case,
    /// Samples in the frame.
    pub samples: usize,
    /// The truth at the target camera.
    pub truth: Image,
    /// One per renderer.
    pub outcomes: Vec<Outcome>,
}

/// Runs one case at `size`² with `heuristic` through every renderer of `roster`.
pub fn run_case(case: &Case, base: &Marcher, heuristic: Heuristic, size: u32, roster: &mut [Entry]) -> CaseResult {
    let marcher = case.marcher(base);
    let c0 = case.c0(&marcher, size);
    let target = case.target(&c0);
    let frame = frame_for(&marcher, &c0, heuristic);
    let scenes = SceneSet::build(&frame);
    let truth = marcher.render_image(&target);
    let outcomes = roster
        .iter_mut()
        .map(|e| {
            let mut image = Image::new(0, 0);
            e.renderer.render(scenes.get(e.radius_scale), &target, &mut image);
            let defined = is_defined(&image, size, size);
            let metrics = Metrics::of(&truth, &image).unwrap_or(Metrics { psnr: 0.0, ssim: 0.0, flip: 1.0 });
            Outcome { renderer: e.name.clone(), defined, metrics, image }
        })
        .collect();
    CaseResult { case: *case, samples: frame.samples.len(), truth, outcomes }
}
