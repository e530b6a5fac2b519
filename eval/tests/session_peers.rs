//! The image-sending peers (`send-image`, `downscale`) and the scenarios users produce (flick,
//! zoom, the bundled recorded drag): real JPEG bytes decoded and scored, a reduced image's
//! server time from the measured ratio, determinism of the new scenarios, and the default never
//! worse than the stale frame per tick on a steady orbit, exact once a flick rests.

mod common;

use common::SIZE;
use volwarp_eval::session::model::NetworkModel;
use volwarp_eval::session::peers::{decode_jpeg, encode_jpeg, scaled_name};
use volwarp_eval::session::report::{session_table, Run};
use volwarp_eval::session::{calibrate, simulate_all, SessionOptions};
use volwarp_eval::Metrics;
use volwarp_server::dataset::Dataset;
use volwarp_server::Marcher;

fn opts(scenarios: &[&str], methods: &str, net: NetworkModel) -> SessionOptions {
    common::session_opts(scenarios, methods, net)
}

fn head() -> Vec<Dataset> {
    vec![Dataset::default_bundled()]
}

fn rows<'a>(runs: &'a [Run], method: &'a str) -> impl Iterator<Item = &'a volwarp_eval::session::simulate::TickRow> {
    runs.iter().flat_map(|r| &r.result.rows).filter(move |r| r.method == method)
}

#[test]
fn send_image_shows_the_decoded_jpeg_of_the_truth_and_is_charged_its_bytes() {
    // An instant server and link: every tick shows the JPEG of that tick's truth.
    let o = opts(&["orbit"], "send-image", NetworkModel { server_ms: 0.0, latency_ms: 0.0, mbps: f64::INFINITY });
    let runs = simulate_all(&head(), &o).unwrap();
    let m = Marcher::from_dataset(&head()[0]);
    let c0 = m.default_camera(SIZE, SIZE);
    let truth = m.render_image(&c0);
    let jpeg = encode_jpeg(&truth, 90).unwrap();
    assert_eq!(runs[0].result.frames[0].bytes, jpeg.len() as u64, "the first image's bytes are its JPEG's");
    let decoded = decode_jpeg(&jpeg).unwrap();
    let expected = Metrics::of(&truth, &decoded).unwrap().flip;
    let tick0 = rows(&runs, "send-image").next().unwrap();
    assert_eq!(tick0.metrics.flip, expected, "tick 0 scores the decoded JPEG");
    // JPEG is lossy: not the truth, but close at quality 90.
    assert!(tick0.metrics.flip > 0.0 && tick0.metrics.flip < 0.1, "{}", tick0.metrics.flip);
    for r in rows(&runs, "send-image") {
        assert!(r.metrics.flip > 0.0 && r.metrics.flip < 0.15, "tick {}: {}", r.tick, r.metrics.flip);
        assert_eq!(r.frame_age_ms, 0.0, "instant: a fresh image every tick");
    }
}

#[test]
fn downscale_sends_fewer_bytes_sooner_while_moving_and_full_resolution_at_rest() {
    // A 500 ms server, 1 Mbit/s: the downscaled images are cheaper on both.
    let net = NetworkModel { server_ms: 500.0, latency_ms: 20.0, mbps: 1.0 };
    let mut o = opts(&["flick:90"], "downscale,send-image,stale", net);
    o.cfg.size = 128;
    o.cfg.duration_s = 3.0;
    o.cfg.score_every = 1;
    // The measured ratio from a calibration file: 1/2 of the resolution costs 0.25 of the time.
    let ds = head();
    o.calibration.ms.insert(("server".into(), ds[0].name.clone(), 128), 500.0);
    o.calibration.ms.insert(("server".into(), scaled_name(&ds[0].name, 2), 128), 125.0);
    o.calibration.ms.insert(("server".into(), scaled_name(&ds[0].name, 4), 128), 50.0);
    o.server_ms = Some(500.0);
    let runs = simulate_all(&ds, &o).unwrap();
    let frames = &runs[0].result.frames; // downscale's images (the first method)
    let tick_ms = 1e3 / 30.0;
    let moving: Vec<_> = frames.iter().skip(1).filter(|f| f.request_ms < 0.5e3 + 0.5 * tick_ms).collect();
    let resting: Vec<_> = frames.iter().skip(1).filter(|f| f.request_ms > 0.5e3 + 0.5 * tick_ms).collect();
    assert!(!moving.is_empty() && !resting.is_empty(), "{frames:?}");
    for f in &moving {
        // arrive = start + server × ratio + bytes on the link + latency.
        let link = f.bytes as f64 * 8.0 / 1e3;
        assert!((f.arrive_ms - f.start_ms - 125.0 - link - 20.0).abs() < 1e-6, "{f:?}");
    }
    for f in &resting {
        let link = f.bytes as f64 * 8.0 / 1e3;
        assert!((f.arrive_ms - f.start_ms - 500.0 - link - 20.0).abs() < 1e-6, "{f:?}");
    }
    let mean = |v: &[&volwarp_eval::session::simulate::FrameEvent]| {
        v.iter().map(|f| f.bytes as f64).sum::<f64>() / v.len() as f64
    };
    assert!(mean(&moving) < 0.5 * mean(&resting), "quarter the pixels at quality 50: {frames:?}");
    // At rest the full-resolution image arrives: the last ticks show it at JPEG quality 90,
    // as send-image does.
    let last = |m: &str| rows(&runs, m).last().unwrap().metrics.flip;
    assert_eq!(last("downscale"), last("send-image"));
    // While the flick turns, the downscaled images are fresher than the full ones.
    let age = |m: &str| rows(&runs, m).filter(|r| r.time_s < 1.0).map(|r| r.frame_age_ms).sum::<f64>();
    assert!(age("downscale") < age("send-image"), "{} vs {}", age("downscale"), age("send-image"));
}

#[test]
fn the_new_scenarios_are_deterministic() {
    let net = NetworkModel { server_ms: 300.0, latency_ms: 50.0, mbps: 5.0 };
    let o = opts(&["flick", "zoom"], "volwarp,downscale=4,send-image,stale", net);
    let ds = vec![Dataset::marschner_lobb(24)];
    let a = session_table(&simulate_all(&ds, &o).unwrap()).to_csv();
    let b = session_table(&simulate_all(&ds, &o).unwrap()).to_csv();
    assert_eq!(a, b);
    // 2 scenarios × 31 scored ticks × 4 methods, plus the header.
    assert_eq!(a.lines().count(), 1 + 2 * 31 * 4);
    assert!(a.contains(",flick,") && a.contains(",zoom,") && a.contains(",downscale=4,"));
}

#[test]
fn calibration_measures_the_reduced_resolutions_server_time() {
    let ds = vec![Dataset::marschner_lobb(24)];
    let cal = calibrate(&ds, 32, 1, 1, "stale,send-image").unwrap();
    let name = &ds[0].name;
    for f in [2, 4] {
        let ms = cal.server_ms(&scaled_name(name, f), 32).unwrap();
        assert!(ms.is_finite() && ms >= 0.0, "{f}: {ms}");
    }
    let cost = cal.resolution_cost(name, 32).unwrap();
    assert!(cost.half.is_finite() && cost.quarter.is_finite());
    assert!(cal.ms.keys().all(|(k, n, _)| !(k == "client" && n == "send-image")), "peers draw no frame");
    assert!(simulate_all(&ds, &opts(&["orbit"], "downscale=3", NetworkModel::DEFAULT)).is_err());
}

#[test]
fn on_a_steady_orbit_the_default_is_never_worse_than_the_stale_frame() {
    // The bundled CT head at 128², a 500 ms server: at every scored tick the default shows no
    // more error than the stale frame.
    let mut o = opts(&["orbit"], "volwarp,stale", NetworkModel { server_ms: 500.0, latency_ms: 50.0, mbps: 100.0 });
    o.cfg.size = 128;
    o.cfg.duration_s = 3.0;
    o.cfg.score_every = 3;
    let runs = simulate_all(&head(), &o).unwrap();
    let stale: Vec<f64> = rows(&runs, "stale").map(|r| r.metrics.flip).collect();
    let volwarp: Vec<f64> = rows(&runs, "volwarp").map(|r| r.metrics.flip).collect();
    assert_eq!(stale.len(), volwarp.len());
    // Tick 0: the layered frame at its own camera is the server's image, pixel for pixel
    // (core's `segments::pack_colors`), as the stale frame is.
    assert_eq!(volwarp[0], 0.0, "tick 0");
    for (t, (v, s)) in volwarp.iter().zip(&stale).enumerate() {
        assert!(v <= s, "scored tick {t}: volwarp {v} > stale {s}");
    }
}

#[test]
fn after_a_flick_rests_the_default_shows_the_resting_frame_exactly() {
    // The bundled CT head at 64², a 300 ms server: the flick turns 90° in 0.5 s and rests. Once
    // the frame asked for at the first still tick has arrived, the default shows it as rendered
    // (the server's image), and over the session it shows less error than the stale frame.
    let mut o = opts(&["flick"], "volwarp,stale", NetworkModel { server_ms: 300.0, latency_ms: 50.0, mbps: 100.0 });
    o.cfg.size = 64;
    o.cfg.duration_s = 3.0;
    o.cfg.score_every = 3;
    let runs = simulate_all(&head(), &o).unwrap();
    let mean = |m: &str| rows(&runs, m).map(|r| r.metrics.flip).sum::<f64>() / rows(&runs, m).count() as f64;
    assert!(mean("volwarp") < mean("stale"), "{} vs {}", mean("volwarp"), mean("stale"));
    // The last second: the camera has rested for 1.5 s, the resting frame is on screen.
    let rest: Vec<_> = rows(&runs, "volwarp").filter(|r| r.time_s >= 2.0).collect();
    assert!(!rest.is_empty());
    for r in rest {
        assert_eq!(r.metrics.flip, 0.0, "tick {} at rest", r.tick);
    }
}

#[test]
fn the_view_at_rest_is_asked_for_one_sample_and_shown_exactly_once_it_arrived() {
    // Stop-and-go on the bundled CT head at 64², a 300 ms server, every tick scored: the camera
    // turns for 1.5 s and rests for 1 s. With `+rest=1` the default asks for the rest view with
    // one sample per pixel (core's `RequestPolicy::layers`): the server's own image, exact at its
    // camera, and fewer bytes than the layered frames.
    const REST1: &str = "splat-layers+predict+frames=4+adapt+layers=4+rest=1";
    let net = NetworkModel { server_ms: 300.0, latency_ms: 50.0, mbps: 100.0 };
    let mut o = opts(&["stop-and-go"], &format!("{REST1},stale"), net);
    o.cfg.size = 64;
    o.cfg.duration_s = 2.5;
    o.cfg.score_every = 1;
    let runs = simulate_all(&head(), &o).unwrap();
    let frames = &runs[0].result.frames; // the first method's stream
    let rest = frames.iter().find(|f| f.request_ms > 1500.0).expect("a frame asked for at rest");
    let moving = frames.iter().filter(|f| f.request_ms > 0.0 && f.request_ms < 1500.0).map(|f| f.bytes).min().unwrap();
    assert!(rest.bytes * 3 < moving * 2, "the one-sample frame {} B, the smallest layered {moving} B", rest.bytes);
    assert!(rest.arrive_ms < 2400.0, "it arrives while the camera rests: {} ms", rest.arrive_ms);
    let resting: Vec<_> = rows(&runs, REST1).filter(|r| r.time_s * 1e3 >= rest.arrive_ms && r.time_s < 2.5).collect();
    assert!(!resting.is_empty());
    for r in resting {
        assert_eq!(r.metrics.flip, 0.0, "tick {} at rest, after the exact frame arrived", r.tick);
    }
}

#[test]
fn the_bundled_recorded_drag_replays_deterministically() {
    let rec = format!("record:{}/../data/drag_ct_head.vwrec", env!("CARGO_MANIFEST_DIR"));
    let mut o = opts(&[rec.as_str()], "volwarp,stale", NetworkModel { server_ms: 300.0, latency_ms: 50.0, mbps: 50.0 });
    o.cfg.duration_s = 30.0;
    o.cfg.score_every = 15;
    let ds = vec![Dataset::marschner_lobb(24)];
    let a = session_table(&simulate_all(&ds, &o).unwrap()).to_csv();
    let b = session_table(&simulate_all(&ds, &o).unwrap()).to_csv();
    assert_eq!(a, b);
    // The recording is several seconds long and moves: more than a few scored ticks, and the
    // stale frame is not exact throughout.
    assert!(a.lines().count() > 1 + 2 * 8, "{}", a.lines().count());
    let runs = simulate_all(&ds, &o).unwrap();
    assert!(rows(&runs, "stale").any(|r| r.metrics.flip > 0.0), "the recorded drag never moved the camera");
}
