//! Real frames: the server's render of the MRI of `../shared/data`, framed like the server's
//! benchmark (default camera orbited 20°/10°, dolly 0.66: ≈ 620k samples at 1024²,
//! threshold heuristic, the paper's radius).

use std::path::Path;
use volwarp_core::wire::{CameraRequest, Frame};
use volwarp_core::Heuristic;
use volwarp_server::{Dataset, Marcher};

/// Where the MRI lies beside the checkout.
pub const MRI: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/mri_colin27_181x217x181_uint8.raw");

/// A server render of the MRI at `res`², with a description; `None` (and a notice) when the
/// shared data is absent.
pub fn mri_frame(res: u32) -> Option<(Frame, String)> {
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
    let m = Marcher::from_dataset(&ds);
    let camera = m.default_camera(res, res).orbit(20.0, 10.0).dolly(0.66);
    let req = CameraRequest { seq: 0, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0 };
    let (frame, _) = m.render_frame(&req);
    let what = format!(
        "server render of the MRI at {res}² (threshold heuristic, radius scale 1), {} samples",
        frame.samples.len()
    );
    Some((frame, what))
}
