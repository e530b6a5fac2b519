//! The window client and the session simulator run one method: with no options the client's
//! method and the simulator's `volwarp` method are core's `Method::DEFAULT`, and both ask
//! through core's one request policy.

use clap::Parser;
use volwarp_client::network::CADENCE;
use volwarp_client::options::Options;
use volwarp_core::method::{Method, ViewEvents};
use volwarp_eval::session::methods::MethodSpec;
use volwarp_eval::session::simulate::cadence;

#[test]
fn the_client_and_the_simulator_run_the_same_default_method() {
    let client = Options::parse_from(["volwarp-client"]).method();
    let simulator = MethodSpec::parse("volwarp").unwrap().method(volwarp_core::segments::DEFAULT_LAYERS as u8);
    assert_eq!(client, simulator);
    assert_eq!(client, Method::DEFAULT);
    assert_eq!(client.request(), simulator.request());
}

#[test]
fn the_two_cadences_differ_only_where_said() {
    let sim = cadence(1e3 / 60.0);
    assert_eq!(CADENCE.display_tick_s, sim.display_tick_s, "both take a 60 Hz tick off the horizon");
    let p = Method::DEFAULT.request();
    let moved = ViewEvents { moved: true, ..ViewEvents::default() };
    assert!(p.due(&CADENCE, moved) && p.due(&sim, moved));
    // The window client also asks when a frame arrives; both ask again at the first still
    // tick (where a predicted request overshot, the still view itself).
    assert!(CADENCE.on_frame_arrival && !sim.on_frame_arrival);
    assert!(CADENCE.on_first_still && sim.on_first_still);
}
