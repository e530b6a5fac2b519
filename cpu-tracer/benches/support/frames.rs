//! Real frames: the server's render of the MRI of `../shared/data`, framed like the server's
//! benchmark (default camera orbited 20°/10°, dolly 0.66: ≈ 620k samples at 1024²,
//! threshold heuristic), with the server's default radius model (a pixel diagonal at
//! the sample's depth) or
//! another one (the paper's half voxel diagonal).

use std::path::Path;
use volwarp_core::wire::{CameraRequest, Frame};
use volwarp_core::Heuristic;
use volwarp_server::{Dataset, MarchOptions, Marcher, RadiusModel};

/// Where the MRI lies beside the checkout.
pub const MRI: &str = volwarp_server::testdata::MRI_PATH;

/// A server render of the MRI at `res`² with the default radius model, with a description;
/// `None` (and a notice) when the shared data is absent.
#[allow(dead_code)]
pub fn mri_frame(res: u32) -> Option<(Frame, String)> {
    mri_frame_with(res, RadiusModel::default())
}

/// [`mri_frame`] with the radius model `model`.
pub fn mri_frame_with(res: u32, model: RadiusModel) -> Option<(Frame, String)> {
    if !Path::new(MRI).exists() {
        eprintln!("notice: {MRI} not found; using a synthetic frame");
        return None;
    }
    let ds = match Dataset::load(MRI, None) {
        Ok(ds) => ds,
        Err(e) => {
            eprintln!("notice: cannot load the MRI ({e}); using a synthetic frame");
            return None;
        }
    };
    let m = Marcher::from_dataset(&ds)
        .with_transfer_function(&ds.tf, MarchOptions { radius: model, ..MarchOptions::default() });
    let camera = m.default_camera(res, res).orbit(20.0, 10.0).dolly(0.66);
    let req = CameraRequest { seq: 0, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
    let (frame, _) = m.render_frame(&req);
    let what = format!(
        "server render of the MRI at {res}² (threshold heuristic, {model} radius), {} samples",
        frame.samples.len()
    );
    Some((frame, what))
}
