//! Side views at rest in the session simulator: the client holds the first frame's side views
//! at time 0, asks for a resting view's side views once its frame has arrived (one after the
//! other), and a flick from rest warps the nearer side view until the move's first frame comes.

mod common;

use volwarp_core::method::Method;
use volwarp_eval::session::model::NetworkModel;
use volwarp_eval::session::paths::CameraPath;
use volwarp_eval::session::simulate_all;
use volwarp_server::dataset::Dataset;

/// The default method without side views.
const WITHOUT: &str = "splat-layers+predict+frames=4+adapt+layers=4+coarse=2";

#[test]
fn a_flick_from_rest_warps_the_side_view_and_the_rest_after_it_asks_for_both() {
    // The flick (180°/s for 0.5 s, then rest) at 128², a 500 ms server at 100 Mbit/s: no frame
    // of the move can come before 0.6 s, so at 0.167 s (30° turned) the client shows what it
    // held at the start.
    let net = NetworkModel { server_ms: 500.0, latency_ms: 50.0, mbps: 100.0 };
    let ds = vec![Dataset::default_bundled()];
    let mut o = common::session_opts(&["flick"], &format!("volwarp,{WITHOUT}"), net);
    o.cfg.size = 128;
    o.cfg.duration_s = 3.0;
    o.cfg.score_every = 1;
    o.server_ms = Some(500.0);
    let run = simulate_all(&ds, &o).unwrap().remove(0);
    let frames = &run.result.frames; // the default's (the first method)
    let policy = Method::DEFAULT.request();
    let c0 = frames[0].view;
    let start: Vec<_> = frames.iter().filter(|f| f.held_at_start()).map(|f| f.view).collect();
    let mut want = vec![c0];
    want.extend(policy.side_views(&c0).unwrap());
    assert_eq!(start, want, "the first frame and its side views at the start");
    // Where the flick rests: its rest frame arrives, then each side view, asked for after the
    // frame before it arrived, each rendered at full resolution.
    let rest = CameraPath::parse("flick").unwrap().camera(&c0, 3.0);
    let sides = policy.side_views(&rest).unwrap();
    let at = |v| frames.iter().position(|f| f.view == v).unwrap_or_else(|| panic!("no frame for {v:?}: {frames:?}"));
    let (r, a, b) = (at(rest), at(sides[0]), at(sides[1]));
    assert!(r < a && a < b, "{frames:?}");
    assert!(frames[a].request_ms >= frames[r].arrive_ms && frames[b].request_ms >= frames[a].arrive_ms, "{frames:?}");
    assert!([a, b].iter().all(|&i| frames[i].divisor == 1 && frames[i].view.width == 128), "{frames:?}");
    // Tick 5 (0.167 s, 30° turned): the default shows the side view held at the start (seq 1),
    // and scores better than the same method warping the rest frame.
    let row = |m: &str| run.result.rows.iter().find(|r| r.method == m && r.tick == 5).unwrap();
    let (with, without) = (row("volwarp"), row(WITHOUT));
    assert_eq!((with.frame_seq, without.frame_seq), (1, 0), "{with:?} {without:?}");
    assert!(with.metrics.flip < 0.5 * without.metrics.flip, "{with:?} {without:?}");
}
