//! What the session simulator's integration tests share.

use volwarp_core::compact_frame::Encoding;
use volwarp_core::Heuristic;
use volwarp_eval::session::model::{Calibration, ClientModel, NetworkModel};
use volwarp_eval::session::paths::CameraPath;
use volwarp_eval::session::peers::ResolutionCost;
use volwarp_eval::session::simulate::SessionConfig;
use volwarp_eval::session::{SessionOptions, Sweep};

/// The viewport of the test sessions.
pub const SIZE: u32 = 32;

/// Two-second sessions at [`SIZE`]² of `scenarios` and `methods` over `net`, scored every
/// other tick, one thread.
pub fn session_opts(scenarios: &[&str], methods: &str, net: NetworkModel) -> SessionOptions {
    SessionOptions {
        march: volwarp_server::MarchOptions::default(),
        cfg: SessionConfig {
            size: SIZE,
            duration_s: 2.0,
            net,
            client: ClientModel { display_hz: 30.0, draw_ms: Default::default() },
            score_every: 2,
            heuristic: Heuristic::Threshold,
            exact_when_still: true,
            encoding: Encoding::Compact,
            layers: 1,
            resolution_cost: ResolutionCost::MEASURED_512,
        },
        server_ms: None,
        calibration: Calibration::default(),
        scenarios: scenarios.iter().map(|s| CameraPath::parse(s).unwrap()).collect(),
        methods: methods.into(),
        threads: 1,
        policy: "last-received".into(),
        sweep: Sweep::None,
    }
}
