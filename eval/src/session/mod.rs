//! The session simulator: what a user sees while dragging the camera as the server
//! renders at its own pace and frames cross a network.
//!
//! A session is a dataset, a camera path over time ([`paths`]), a server, network and client
//! model ([`model`]), and the methods the client may show ([`methods`]). The simulated clock
//! ([`simulate`]) decides which frame each method holds at each display tick; the truth (the
//! server's marcher for the camera of that tick) scores it. [`report`] writes the CSV files,
//! the summary and the charts.
//!
//! | module | concept |
//! |---|---|
//! | [`paths`] | steady orbit, stop-and-go, dolly, look-around, recorded paths |
//! | [`model`] | server policy, network, client draw times, the calibration file |
//! | [`methods`] | the methods compared (one registry entry each) |
//! | [`peers`] | what users would pick instead: JPEG images, downscaled while moving |
//! | [`simulate`] | the simulated clock and event loop, truth cache |
//! | [`report`] | `session.csv`, summaries, charts, worst-tick strips |

pub mod methods;
pub mod model;
pub mod paths;
pub mod peers;
pub mod report;
pub mod simulate;

use crate::ErrorBox;
use model::{server_policy, Calibration, ClientModel, NetworkModel};
use paths::CameraPath;
use report::{Run, RunKey};
use simulate::{run_session, SessionConfig, TruthCache};
use std::path::Path;
use std::time::Instant;
use volwarp_core::wire::CameraRequest;
use volwarp_core::{Heuristic, Image};
use volwarp_server::dataset::Dataset;
use volwarp_server::Marcher;

/// What to sweep besides the base setting.
#[derive(Clone, Debug, PartialEq)]
pub enum Sweep {
    /// One setting.
    None,
    /// Server ms per frame.
    Server(Vec<f64>),
    /// Bandwidths (Mbit/s) at each viewport side.
    Bandwidth(Vec<f64>, Vec<u32>),
}

/// Options of [`run`].
pub struct SessionOptions {
    /// The base setting (size, duration, network, client, scoring).
    pub cfg: SessionConfig,
    /// Server ms given on the command line (else the calibration's figure for the dataset and
    /// size, else the base setting's).
    pub server_ms: Option<f64>,
    /// Measured draw and server times.
    pub calibration: Calibration,
    /// The scenarios.
    pub scenarios: Vec<CameraPath>,
    /// Method list (`all` or names).
    pub methods: String,
    /// Threads per CPU renderer (0: all cores).
    pub threads: usize,
    /// Server policy name.
    pub policy: String,
    /// The sweep.
    pub sweep: Sweep,
    /// The server's march options (its sphere radius model: `session --radius`).
    pub march: volwarp_server::MarchOptions,
}

/// Runs every session (datasets × scenarios × sweep settings) and writes the files into `out`.
pub fn run(datasets: &[Dataset], opts: &SessionOptions, out: &Path) -> Result<Vec<Run>, ErrorBox> {
    let runs = simulate_all(datasets, opts)?;
    let sweep = match opts.sweep {
        Sweep::None => None,
        Sweep::Server(_) => Some("server"),
        Sweep::Bandwidth(..) => Some("bandwidth"),
    };
    report::write_all(&runs, out, sweep)?;
    log::info!("wrote {}", out.join("session.csv").display());
    Ok(runs)
}

/// The settings of a sweep: `(size, server ms or None for the default, mbps)`.
fn settings(opts: &SessionOptions) -> Vec<(u32, Option<f64>, f64)> {
    let c = &opts.cfg;
    match &opts.sweep {
        Sweep::None => vec![(c.size, opts.server_ms, c.net.mbps)],
        Sweep::Server(v) => v.iter().map(|&s| (c.size, Some(s), c.net.mbps)).collect(),
        Sweep::Bandwidth(b, sizes) => {
            sizes.iter().flat_map(|&sz| b.iter().map(move |&m| (sz, opts.server_ms, m))).collect()
        }
    }
}

/// Runs every session without writing files.
pub fn simulate_all(datasets: &[Dataset], opts: &SessionOptions) -> Result<Vec<Run>, ErrorBox> {
    // Check everything before the first long render.
    let mut methods = methods::make_methods(&opts.methods, opts.threads)?;
    let mut policy = server_policy(&opts.policy)?;
    for (size, sms, mbps) in settings(opts) {
        let net = NetworkModel { server_ms: sms.unwrap_or(opts.cfg.net.server_ms), mbps, ..opts.cfg.net };
        SessionConfig { size, net, ..opts.cfg.clone() }.check()?;
    }
    let mut runs = Vec::new();
    let total = datasets.len() * opts.scenarios.len() * settings(opts).len();
    let t0 = Instant::now();
    for ds in datasets {
        let marcher = Marcher::from_dataset(ds).with_transfer_function(&ds.tf, opts.march);
        let mut truths = TruthCache::default();
        for (size, sms, mbps) in settings(opts) {
            let server_ms =
                sms.or_else(|| opts.calibration.server_ms(&ds.name, size)).unwrap_or(opts.cfg.net.server_ms);
            let draw_ms =
                methods.iter().map(|m| (m.name().to_string(), opts.calibration.draw_ms(m.name(), size))).collect();
            let resolution_cost = opts.calibration.resolution_cost(&ds.name, size).unwrap_or(opts.cfg.resolution_cost);
            let cfg = SessionConfig {
                size,
                resolution_cost,
                net: NetworkModel { server_ms, mbps, ..opts.cfg.net },
                client: ClientModel { draw_ms, ..opts.cfg.client.clone() },
                ..opts.cfg.clone()
            };
            for sc in &opts.scenarios {
                let label = format!(
                    "[{}/{total}] {} {} {size}² server {server_ms} ms {mbps} Mbit/s",
                    runs.len() + 1,
                    ds.name,
                    sc.name
                );
                let mut progress = |done: usize, n: usize| {
                    if done == n || done.is_multiple_of(10) {
                        eprint!("\r{label}: tick {done}/{n} ({:.0} s)   ", t0.elapsed().as_secs_f64());
                    }
                };
                let result =
                    run_session(&marcher, sc, &cfg, policy.as_mut(), &mut methods, &mut truths, &mut progress)?;
                eprintln!();
                runs.push(Run {
                    key: RunKey {
                        dataset: ds.name.clone(),
                        scenario: sc.name.clone(),
                        policy: policy.name().into(),
                        size,
                        server_ms,
                        latency_ms: cfg.net.latency_ms,
                        mbps,
                    },
                    result,
                });
            }
        }
    }
    Ok(runs)
}

/// Measures the server's frame time per dataset and each method's draw time at `size` on this
/// machine (medians of `runs`; the frame of the default camera drawn 10° away) and returns
/// them as a [`Calibration`] (`list`: the methods, as `session --methods` takes them; a
/// multi-frame method draws the frame and older ones 5°, 10°, … back along the orbit; a method
/// asking for layers draws layered frames of the default camera). This reads the wall clock; the simulation only reads its result.
pub fn calibrate(
    datasets: &[Dataset],
    size: u32,
    runs: usize,
    threads: usize,
    list: &str,
) -> Result<Calibration, ErrorBox> {
    let mut cal = Calibration::default();
    let mut draw: Vec<(String, Vec<f64>)> = Vec::new();
    for ds in datasets {
        let marcher = Marcher::from_dataset(ds);
        let c0 = marcher.default_camera(size, size);
        let mut frame = None;
        let server = median_ms(runs, || frame = Some(crate::quality::frame_for(&marcher, &c0, Heuristic::Threshold)));
        cal.ms.insert(("server".into(), ds.name.clone(), size), server);
        log::info!("{}: server {server:.1} ms per frame at {size}²", ds.name);
        // The marcher's image at 1/2 and 1/4 of the resolution against the full one (the
        // downscaling peers' and coarse frames' server time): the frame's time times the ratio.
        let image_ms = |side: u32| {
            let cam = marcher.default_camera(side.max(1), side.max(1));
            median_ms(runs, || {
                std::hint::black_box(marcher.render_image(&cam));
            })
        };
        // The same for a layered frame (K = 4, the default's coarse frames): logged beside the
        // image's ratio, which the simulator charges (a layered frame's is at most it).
        let layered_ms = |side: u32| {
            let camera = marcher.default_camera(side.max(1), side.max(1));
            let req = CameraRequest { seq: 1, camera, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
            median_ms(runs, || {
                std::hint::black_box(marcher.render_frame_layers(&req, 4));
            })
        };
        let (full, full_layered) = (image_ms(size), layered_ms(size));
        for f in [2u32, 4] {
            let ratio = if full > 0.0 { image_ms(size / f) / full } else { 1.0 };
            let layered = if full_layered > 0.0 { layered_ms(size / f) / full_layered } else { 1.0 };
            cal.ms.insert(("server".into(), peers::scaled_name(&ds.name, f), size), server * ratio);
            log::info!(
                "{}: server at 1/{f} of {size}²: {ratio:.3} of the full resolution's time (a layered frame: {layered:.3})",
                ds.name
            );
        }
        let held = methods::HeldFrame::new(frame.ok_or("no frame")?);
        // Methods that ask for layered frames draw one, K segments per pixel.
        let mut layered: Vec<(u32, methods::HeldFrame)> = Vec::new();
        let cam = c0.orbit(10.0, 0.0);
        for mut method in methods::make_methods(list, threads)? {
            if method.image_peer().is_some() {
                continue; // decoded and upscaled within a tick: the client model's default figure
            }
            let k = method.request().layers;
            if k > 1 && !layered.iter().any(|(n, _)| *n == k) {
                let req =
                    CameraRequest { seq: 1, camera: c0, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
                layered.push((k, methods::HeldFrame::new(marcher.render_frame_layers(&req, k).0)));
            }
            let held = layered.iter().find(|(n, _)| *n == k).map_or(&held, |(_, f)| f);
            // A method keeping several frames draws them all: older ones rendered 5°, 10°, …
            // back along the orbit (oldest first, as the simulator holds them).
            let older: Vec<methods::HeldFrame> = (1..method.frames_kept())
                .rev()
                .map(|i| {
                    let req = CameraRequest {
                        seq: 1,
                        camera: c0.orbit(-5.0 * i as f32, 0.0),
                        heuristic: Heuristic::Threshold,
                        radius_scale: 1.0,
                        layers: 0,
                    };
                    let f = if k > 1 { marcher.render_frame_layers(&req, k).0 } else { marcher.render_frame(&req).0 };
                    methods::HeldFrame::new(f)
                })
                .collect();
            let set: Vec<&methods::HeldFrame> = older.iter().chain(core::iter::once(held)).collect();
            let mut img = Image::new(0, 0);
            method.draw(&set, &cam, &mut img);
            let med = median_ms(runs, || method.draw(&set, &cam, &mut img));
            match draw.iter_mut().find(|(n, _)| n == method.name()) {
                Some((_, v)) => v.push(med),
                None => draw.push((method.name().into(), vec![med])),
            }
        }
    }
    for (name, mut v) in draw {
        let med = crate::median(&mut v).unwrap_or(0.0);
        log::info!("{name}: {med:.2} ms per draw at {size}² (median over datasets)");
        cal.ms.insert(("client".into(), name, size), med);
    }
    Ok(cal)
}

/// The median wall time of `runs` (at least one) calls of `f`, in ms.
fn median_ms(runs: usize, mut f: impl FnMut()) -> f64 {
    let mut t: Vec<f64> = (0..runs.max(1))
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    crate::median(&mut t).unwrap_or(0.0)
}
