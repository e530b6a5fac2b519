//! The window/level drag during an orbit (`wl-drag`): frames rendered with the visual state of
//! the request they serve, the truth of each tick in that tick's state, determinism, and the
//! cost of an edit scored like a camera move.

mod common;

use volwarp_eval::session::model::NetworkModel;
use volwarp_eval::session::paths::{CameraPath, WL_DRAG_S, WL_DRAG_START_S, WL_FROM, WL_TO};
use volwarp_eval::session::report::{session_table, Run};
use volwarp_eval::session::simulate::{Looks, TruthCache};
use volwarp_eval::session::simulate_all;
use volwarp_server::dataset::Dataset;
use volwarp_server::Marcher;

fn head() -> Vec<Dataset> {
    vec![Dataset::default_bundled()]
}

fn flips<'a>(runs: &'a [Run], method: &'a str) -> impl Iterator<Item = (f64, f64)> + 'a {
    runs.iter().flat_map(|r| &r.result.rows).filter(move |r| r.method == method).map(|r| (r.time_s, r.metrics.flip))
}

#[test]
fn each_tick_has_the_state_the_user_set_and_the_states_look_different() {
    let ds = &head()[0];
    let marcher = Marcher::from_dataset(ds).with_transfer_function(&ds.tf, Default::default());
    let path = CameraPath::parse("wl-drag").unwrap();
    let hz = 30.0;
    let ticks = ((WL_DRAG_START_S + WL_DRAG_S + 0.5) * hz) as usize;
    let looks = Looks::of(&marcher, &path, ticks, hz).unwrap();
    // One state before the drag, one per tick of the drag.
    assert_eq!(looks.state_at(0), 0);
    assert_eq!(looks.window_level(0), WL_FROM);
    assert_eq!(looks.state_at((WL_DRAG_START_S * hz) as usize - 1), 0);
    assert_eq!(looks.len(), 1 + (WL_DRAG_S * hz) as usize);
    assert_eq!(looks.window_level(looks.state_at(ticks - 1)), WL_TO);
    let mid = looks.state_at(((WL_DRAG_START_S + 0.5 * WL_DRAG_S) * hz) as usize);
    assert!(mid > 0 && mid < looks.len() - 1);
    // A path that edits nothing has the one state.
    assert_eq!(Looks::of(&marcher, &CameraPath::parse("orbit").unwrap(), ticks, hz).unwrap().len(), 1);
    // The end state shows another image than the start state at the same camera, and the
    // truth cache keeps them apart.
    let cam = marcher.default_camera(common::SIZE, common::SIZE);
    let mut truths = TruthCache::default();
    let a = truths.get_in(&looks, 0, &cam).clone();
    let b = truths.get_in(&looks, looks.state_at(ticks - 1), &cam).clone();
    assert_ne!(a.pixels, b.pixels, "window/level changed nothing");
    assert_eq!(truths.rendered, 2);
    assert_eq!(truths.get(&marcher, &cam).pixels, a.pixels, "state 0 is the dataset's own marcher");
    assert_eq!(truths.rendered, 2);
}

#[test]
fn an_instant_server_shows_every_tick_in_its_own_state() {
    let mut o = common::session_opts(
        &["wl-drag"],
        "stale,volwarp",
        NetworkModel { server_ms: 0.0, latency_ms: 0.0, mbps: f64::INFINITY },
    );
    o.cfg.duration_s = WL_DRAG_START_S + WL_DRAG_S + 0.3;
    let runs = simulate_all(&head(), &o).unwrap();
    let frames = &runs[0].result.frames;
    assert!(frames.windows(2).all(|w| w[0].state <= w[1].state), "states only move forward");
    assert!(frames.last().unwrap().state > 0, "the drag's states were rendered");
    for row in &runs[0].result.rows {
        // Each tick's frame was rendered for its camera and its state: the truth (the layered
        // frames up to their 8-bit segment colors).
        let tolerance = if row.method == "volwarp" { 0.01 } else { 0.0 };
        assert!(row.metrics.flip <= tolerance, "{} tick {}: {}", row.method, row.tick, row.metrics.flip);
    }
}

#[test]
fn a_slow_server_makes_the_edit_cost_like_a_move_and_runs_are_deterministic() {
    let net = NetworkModel { server_ms: 300.0, latency_ms: 50.0, mbps: 100.0 };
    let mut o = common::session_opts(&["wl-drag", "orbit"], "stale,volwarp", net);
    o.cfg.size = 48;
    o.cfg.duration_s = WL_DRAG_START_S + WL_DRAG_S + 1.0;
    let runs = simulate_all(&head(), &o).unwrap();
    let again = simulate_all(&head(), &o).unwrap();
    assert_eq!(session_table(&runs).to_csv(), session_table(&again).to_csv());
    let (drag, orbit) = (&runs[..1], &runs[1..]);
    assert_eq!(drag[0].key.scenario, "wl-drag");
    // Before the drag both scenarios are the same session.
    let before = |r: &[Run], m: &str| -> Vec<f64> {
        flips(r, m).filter(|(t, _)| *t < WL_DRAG_START_S).map(|(_, f)| f).collect()
    };
    assert_eq!(before(drag, "volwarp"), before(orbit, "volwarp"));
    // During the drag the frames shown are of an older state than the truth's: every method
    // scores worse than on the plain orbit, and the warp still beats the stale frame.
    let during = |r: &[Run], m: &str| -> f64 {
        let v: Vec<f64> = flips(r, m)
            .filter(|(t, _)| *t > WL_DRAG_START_S + 0.2 && *t <= WL_DRAG_START_S + WL_DRAG_S)
            .map(|(_, f)| f)
            .collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    for m in ["stale", "volwarp"] {
        assert!(during(drag, m) > during(orbit, m), "{m}: {} vs {}", during(drag, m), during(orbit, m));
    }
    assert!(during(drag, "volwarp") < during(drag, "stale"));
    // After the drag the frames of the final state (the last one made: one state per tick of
    // the drag at 30 Hz) arrive.
    let last = drag[0].result.frames.last().unwrap();
    assert_eq!(last.state, (WL_DRAG_S * 30.0) as usize);
}
