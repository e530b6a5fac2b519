//! Adaptive resolution: a frame on a coarser pixel grid warped at display resolution has no
//! holes, and the session simulator charges a coarse frame the server time measured at its
//! resolution and the bytes of its own encoding.

mod common;

use volwarp_core::method::coarse_viewport;
use volwarp_core::wire::CameraRequest;
use volwarp_core::{Heuristic, Image, BACKGROUND};
use volwarp_eval::session::methods::{make_methods, HeldFrame};
use volwarp_eval::session::model::NetworkModel;
use volwarp_eval::session::peers::scaled_name;
use volwarp_eval::session::simulate::FrameEvent;
use volwarp_eval::session::simulate_all;
use volwarp_eval::Metrics;
use volwarp_server::dataset::Dataset;
use volwarp_server::Marcher;

fn layered(marcher: &Marcher, camera: volwarp_core::Camera) -> HeldFrame {
    let req = CameraRequest { seq: 1, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
    HeldFrame::new(marcher.render_frame_layers(&req, 4).0)
}

#[test]
fn a_coarse_frame_warped_at_display_resolution_has_no_holes_at_its_own_camera() {
    let ds = Dataset::default_bundled();
    let marcher = Marcher::from_dataset(&ds);
    for divisor in [2u32, 4] {
        let cam = marcher.default_camera(128, 128).orbit(20.0, 10.0);
        let (w, h) = coarse_viewport(cam.width, cam.height, divisor);
        let coarse_cam = cam.with_viewport(w, h);
        let coarse = layered(&marcher, coarse_cam);
        let full = layered(&marcher, cam);
        // The default method (the window client's), drawing each frame at the display camera.
        let mut method = make_methods("volwarp", 1).unwrap().pop().unwrap();
        let (mut warped, mut exact) = (Image::new(0, 0), Image::new(0, 0));
        method.draw(&[&coarse], &cam, &mut warped);
        method.draw(&[&full], &cam, &mut exact);
        assert_eq!((warped.width, warped.height), (128, 128));
        // Every display pixel whose coarse source pixel saw the volume is covered.
        let coarse_image = marcher.render_image(&coarse_cam);
        let holes = (0..128 * 128usize)
            .filter(|&i| {
                let (x, y) = (i as u32 % 128 / divisor, i as u32 / 128 / divisor);
                let src = coarse_image.pixels[(y.min(h - 1) * w + x.min(w - 1)) as usize];
                // The source pixel is clearly covered (not a faint fringe).
                let covered = src != BACKGROUND && src.to_le_bytes()[3] > 64;
                covered && warped.pixels[i] == BACKGROUND
            })
            .count();
        assert_eq!(holes, 0, "1/{divisor}: display pixels left empty under covered coarse pixels");
        // Against the full-resolution frame shown at the same camera: the error of a coarser
        // grid, no more than the coarse image upscaled shows.
        let truth = marcher.render_image(&cam);
        let mut up = Image::new(0, 0);
        coarse_image.resize_into(128, 128, &mut up);
        let f_warp = Metrics::of(&exact, &warped).unwrap().flip;
        let f_up = Metrics::of(&truth, &up).unwrap().flip;
        let f_truth = Metrics::of(&truth, &warped).unwrap().flip;
        assert!(f_warp < 0.15, "1/{divisor}: FLIP {f_warp} against the full frame");
        assert!(f_truth <= 1.25 * f_up + 0.01, "1/{divisor}: FLIP {f_truth} against upscaled {f_up}");
    }
}

#[test]
fn coarse_frames_cost_the_measured_server_time_at_their_resolution() {
    // A flick (90 °/s for 0.5 s, then rest) at 256², a 500 ms server on a 1 Mbit/s link.
    let net = NetworkModel { server_ms: 500.0, latency_ms: 20.0, mbps: 1.0 };
    let ds = vec![Dataset::default_bundled()];
    let run = |half_ms: f64| {
        let mut o = common::session_opts(&["flick:90"], "volwarp-adaptive,volwarp", net);
        o.cfg.size = 256;
        o.cfg.duration_s = 3.0;
        o.cfg.score_every = 3;
        // The measured ratio from a calibration file.
        o.calibration.ms.insert(("server".into(), ds[0].name.clone(), 256), 500.0);
        o.calibration.ms.insert(("server".into(), scaled_name(&ds[0].name, 2), 256), half_ms);
        o.calibration.ms.insert(("server".into(), scaled_name(&ds[0].name, 4), 256), 50.0);
        o.server_ms = Some(500.0);
        simulate_all(&ds, &o).unwrap()
    };
    let link = |f: &FrameEvent| f.bytes as f64 * 8.0 / 1e3;
    let mut firsts = Vec::new();
    for half_ms in [125.0, 250.0] {
        let runs = run(half_ms);
        let frames = &runs[0].result.frames; // volwarp-adaptive's (the first method)
        let coarse: Vec<_> = frames.iter().filter(|f| !f.held_at_start()).filter(|f| f.camera.width == 128).collect();
        let full: Vec<_> = frames.iter().filter(|f| !f.held_at_start()).filter(|f| f.camera.width == 256).collect();
        let at_start = frames.iter().filter(|f| f.held_at_start()).count();
        assert_eq!(at_start, 3, "the first frame and its two side views: {frames:?}");
        assert_eq!(coarse.len() + full.len(), frames.len() - at_start, "{frames:?}");
        assert!(!coarse.is_empty() && !full.is_empty(), "{frames:?}");
        for f in &coarse {
            assert!(f.request_ms < 0.5e3 + 20.0, "coarse only while moving: {f:?}");
            assert_eq!(f.view.height, 128);
            assert!((f.arrive_ms - f.start_ms - half_ms - link(f) - 20.0).abs() < 1e-6, "{f:?}");
        }
        for f in &full {
            assert!(f.request_ms > 0.5e3, "full resolution at rest: {f:?}");
            assert!((f.arrive_ms - f.start_ms - 500.0 - link(f) - 20.0).abs() < 1e-6, "{f:?}");
        }
        let mean = |v: &[&FrameEvent]| v.iter().map(|f| f.bytes as f64).sum::<f64>() / v.len() as f64;
        assert!(mean(&coarse) < 0.5 * mean(&full), "the encoder's bytes at a quarter of the pixels");
        firsts.push(coarse[0].arrive_ms);
        // The default (adaptive too) is served on its own stream.
        let rows: Vec<_> = runs[0].result.rows.iter().filter(|r| r.method == "volwarp-adaptive").collect();
        assert!(!rows.is_empty() && rows.iter().all(|r| r.metrics.flip.is_finite()));
    }
    assert!(firsts[0] < firsts[1], "the measured ratio sets the coarse frame's time: {firsts:?}");
}

/// The frames of the default method's stop-and-go at 256² (128² while moving) over `net` for
/// `duration_s`, served by a server finishing every render and write, and by the default one;
/// the server's half-resolution frames take 250 ms.
fn stop_and_go_frames(net: NetworkModel, duration_s: f64) -> (Vec<FrameEvent>, Vec<FrameEvent>) {
    let ds = vec![Dataset::default_bundled()];
    let spec = volwarp_eval::session::methods::default_method();
    let run = |methods: &str| {
        let mut o = common::session_opts(&["stop-and-go"], methods, net);
        o.cfg.size = 256;
        o.cfg.duration_s = duration_s;
        o.cfg.score_every = 9;
        o.calibration.ms.insert(("server".into(), ds[0].name.clone(), 256), 500.0);
        o.calibration.ms.insert(("server".into(), scaled_name(&ds[0].name, 2), 256), 250.0);
        o.calibration.ms.insert(("server".into(), scaled_name(&ds[0].name, 4), 256), 125.0);
        o.server_ms = Some(500.0);
        simulate_all(&ds, &o).unwrap().remove(0).result.frames
    };
    (run(&format!("{spec}+no-preempt")), run(&spec))
}

#[test]
fn a_preempting_server_drops_the_render_a_turn_makes_stale() {
    // Stop-and-go (1.5 s moving, then 1 s at rest) at 256² (half resolution while moving:
    // 128²), a 500 ms server whose half-resolution frames take 250 ms, on a 5 Mbit/s link.
    let net = NetworkModel { server_ms: 500.0, latency_ms: 20.0, mbps: 5.0 };
    // The default method (with its adaptive resolution), without and with preemption.
    let (plain, preempt) = stop_and_go_frames(net, 3.0);
    let moving = |f: &FrameEvent| f.camera.width < 256;
    let rest = |frames: &[FrameEvent]| {
        frames
            .iter()
            .filter(|f| !f.held_at_start())
            .find(|f| !moving(f))
            .cloned()
            .unwrap_or_else(|| panic!("no rest frame: {frames:?}"))
    };
    // The plain server finishes the half-resolution render in flight when the view comes to
    // rest; the preempting one drops it and starts the resting view's at once.
    let (a, b) = (rest(&plain), rest(&preempt));
    assert_eq!(a.request_ms, b.request_ms, "the same rest request: {a:?} {b:?}");
    assert!(b.start_ms < a.start_ms, "preempted: {b:?}, finished first: {a:?}");
    assert_eq!(b.start_ms, b.request_ms + net.latency_ms, "rendered as it arrived: {b:?}");
    // The rest frame arrives that much earlier, and the ticks at rest show it sooner.
    assert!(b.arrive_ms < a.arrive_ms, "{b:?} {a:?}");
}

#[test]
fn a_preempting_server_drops_the_frame_a_turn_makes_stale_on_the_link() {
    // Stop-and-go at 256² on a 2 Mbit/s link: the full-resolution rest frame (about 150 KB,
    // 0.6 s) is still being written when the move back begins at 2.5 s.
    let net = NetworkModel { server_ms: 500.0, latency_ms: 20.0, mbps: 2.0 };
    let (plain, dropping) = stop_and_go_frames(net, 3.6);
    let turn = 2500.0 + net.latency_ms;
    // The server writing every frame whole: the rest frame is on the link as the move begins.
    let rest = plain.iter().filter(|f| !f.held_at_start()).find(|f| f.camera.width == 256).expect("a rest frame");
    let link_ms = rest.bytes as f64 * 8.0 / (net.mbps * 1e3);
    assert!(rest.arrive_ms - net.latency_ms - link_ms < turn && turn < rest.arrive_ms, "{rest:?}");
    // The dropping one stops writing it, and the move's first frame comes sooner.
    assert!(dropping.iter().all(|f| f.request_ms != rest.request_ms), "the rest frame was dropped: {dropping:?}");
    let first_back =
        |frames: &[FrameEvent]| frames.iter().find(|f| f.request_ms >= 2500.0).cloned().expect("a frame of the move");
    let (a, b) = (first_back(&plain), first_back(&dropping));
    assert!(b.arrive_ms + 100.0 < a.arrive_ms, "dropping: {b:?}, writing whole: {a:?}");
}

#[test]
fn a_view_that_flips_between_moving_and_still_still_gets_every_other_render() {
    // At 256² (coarse 128² while moving) the view moves for two ticks and holds for two, over
    // 3 s, against a 500 ms server: every render in flight sees a request for the other
    // viewport. The server drops one, never two in a row, so frames keep coming.
    let marcher = Marcher::from_dataset(&Dataset::default_bundled());
    let home = marcher.default_camera(256, 256);
    let cams: Vec<_> = (0..91).map(|t| home.orbit((t / 4 * 2 + (t % 4).min(2)) as f32 * 2.0, 0.0)).collect();
    assert!(cams[1] != cams[0] && cams[3] == cams[2] && cams[5] != cams[4], "moves two ticks, holds two");
    let looks = volwarp_eval::session::simulate::Looks::fixed(&marcher, cams.len());
    let mut o = common::session_opts(&[], "volwarp", NetworkModel { server_ms: 500.0, latency_ms: 20.0, mbps: 100.0 });
    o.cfg.size = 256;
    let serve = |spec: &str| {
        let request = volwarp_eval::session::methods::MethodSpec::parse(spec).unwrap().request;
        let mut policy = volwarp_eval::session::model::LastReceived;
        volwarp_eval::session::simulate::serve(&looks, &cams, &o.cfg, &mut policy, request)
    };
    let spec = volwarp_eval::session::methods::default_method();
    let (finished, dropping) = (serve(&format!("{spec}+no-preempt")), serve(&spec));
    // The first frame comes before any request; then at least one render in two completes.
    let served = |v: &[(FrameEvent, _)]| v.iter().filter(|(f, _)| !f.held_at_start()).count();
    let (finished_n, dropping_n) = (served(&finished), served(&dropping));
    assert!(finished_n >= 3, "{finished_n}");
    assert!(2 * dropping_n >= finished_n, "{dropping_n} frames against {finished_n}");
    let starts: Vec<f64> = dropping.iter().filter(|(f, _)| !f.held_at_start()).map(|(f, _)| f.start_ms).collect();
    assert!(starts.windows(2).all(|w| w[1] - w[0] < 3.0 * 500.0), "no gap of three renders: {starts:?}");
}

#[test]
fn a_fast_flick_asks_for_the_coarser_grid() {
    // The default method's flick (180°/s for 0.5 s, then rest) at 512², a 500 ms server: the
    // view would turn far more than `FAST_WARP_DEG` before a half-resolution frame could come,
    // so while it turns its requests ask for the quarter grid (128²), and at rest for the full
    // resolution; on the 30°/s orbit (about 10° in that time) for the half grid (256²).
    let net = NetworkModel { server_ms: 500.0, latency_ms: 50.0, mbps: 100.0 };
    let ds = vec![Dataset::default_bundled()];
    let widths = |scenario: &str| {
        let mut o = common::session_opts(&[scenario], "volwarp", net);
        o.cfg.size = 512;
        o.cfg.duration_s = 1.5;
        o.cfg.score_every = 1000;
        o.server_ms = Some(500.0);
        let frames = simulate_all(&ds, &o).unwrap().remove(0).result.frames;
        // Each frame names the grid it was rendered on: the display's width over the divisor.
        assert_eq!(frames[0].divisor, 1);
        assert!(frames.iter().all(|f| f.view.width * f.divisor == 512), "{frames:?}");
        frames
            .iter()
            .filter(|f| !f.held_at_start())
            .map(|f| (f.view.width, f.request_ms, f.render_ms))
            .collect::<Vec<_>>()
    };
    let flick = widths("flick");
    let turning = flick.iter().take_while(|f| f.1 < 500.0).count();
    assert!(turning >= 3 && flick[..turning].iter().all(|f| f.0 == 128), "{flick:?}");
    // Each rendered in the quarter grid's share of the 500 ms.
    assert!(flick[..turning].iter().all(|f| f.2 < 0.2 * 500.0), "{flick:?}");
    assert!(flick[turning..].iter().all(|f| f.0 == 512) && turning < flick.len(), "{flick:?}");
    let orbit = widths("orbit");
    assert!(orbit.len() >= 3 && orbit.iter().all(|f| f.0 == 256), "{orbit:?}");
}
