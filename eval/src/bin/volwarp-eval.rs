//! `volwarp-eval`: accuracy against speed.
//!
//! ```text
//! volwarp-eval quality  --volume FILE [--tf FILE] [--heuristic H|all] --out DIR
//! volwarp-eval quality  --all [--data-dir ../shared/data] --out DIR
//! volwarp-eval table1   [--volume ../shared/data/mri_colin27_181x217x181_uint8.raw] --out DIR [--results docs/results.md]
//! volwarp-eval bits     [--volume FILE] --out DIR
//! volwarp-eval radius   [--volume FILE | --all] --out DIR
//! volwarp-eval uncertainty [--volume FILE | --all] [--variants footprint,uncertainty:gain=0.05:max=2] --out DIR
//! volwarp-eval failures [--volume FILE] --out DIR
//! volwarp-eval session  [--volume FILE | --all] [--scenarios orbit,stop-and-go,dolly,look-around] --out DIR
//! volwarp-eval strip --record FILE [--volume FILE] --out strip.png
//! volwarp-eval session-calibrate [--volume FILE | --all] [--size 512] --out FILE
//! volwarp-eval replot   --dir DIR
//! volwarp-eval fixtures --out eval/fixtures
//! ```
//! Without `--volume`, the bundled dataset (`data/ct_head_quarter.nhdr`) is used.
#![forbid(unsafe_code)]

use clap::{Args, Parser, Subcommand};
use std::path::{Path, PathBuf};
use std::time::Instant;
use volwarp_core::Heuristic;
use volwarp_eval::roster::{roster, RosterOptions};
use volwarp_eval::{report, ErrorBox};
use volwarp_server::dataset::{data_dir, Dataset};
use volwarp_server::Marcher;

#[derive(Parser)]
#[command(name = "volwarp-eval", version, about = "volwarp evaluation: accuracy (PSNR, SSIM, FLIP) against speed")]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Args, Clone)]
struct Common {
    /// Volume file (raw `name_XxYxZ_type.raw` or NRRD); default: the bundled dataset.
    #[arg(long)]
    volume: Option<PathBuf>,
    /// Transfer function file (ParaView JSON or text); default: the volume's preset.
    #[arg(long)]
    tf: Option<PathBuf>,
    /// Output folder (CSV, charts, strips).
    #[arg(long, default_value = "out/eval")]
    out: PathBuf,
    /// Threads per CPU renderer (0: all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Leave the GPU tracer out.
    #[arg(long)]
    no_gpu: bool,
}

/// Which datasets: `--volume` (or the bundled one), or with `--all` every volume of a folder.
#[derive(Args, Clone)]
struct Selection {
    /// Every dataset of `--data-dir`.
    #[arg(long)]
    all: bool,
    /// Folder of the shared volumes (for `--all`).
    #[arg(long, default_value = "../shared/data")]
    data_dir: PathBuf,
}

impl Selection {
    fn datasets(&self, common: &Common) -> Result<Vec<Dataset>, ErrorBox> {
        if self.all {
            report::shared_datasets(&self.data_dir)
        } else {
            Ok(vec![load(common.volume.as_deref(), common.tf.as_deref())?])
        }
    }
}

#[derive(Subcommand)]
enum Cmd {
    /// Warp a frame along orbit and dolly paths with every renderer; score against the truth.
    Quality {
        #[command(flatten)]
        common: Common,
        #[command(flatten)]
        sel: Selection,
        /// A heuristic name, or `all`.
        #[arg(long, default_value = "threshold")]
        heuristic: String,
        /// Viewport side of the accuracy comparison.
        #[arg(long, default_value_t = 512)]
        size: u32,
        /// Renders per timing (median reported); 0: no timing.
        #[arg(long, default_value_t = 3)]
        runs: usize,
        /// Time every heuristic, not only the first.
        #[arg(long)]
        time_all_heuristics: bool,
        /// Largest viewport side at which the GPU tracer is timed.
        #[arg(long, default_value_t = 512)]
        gpu_max_time_size: u32,
    },
    /// The paper's Table 1: samples, compaction and LBVH ms, FPS per view per tracer.
    Table1 {
        #[command(flatten)]
        common: Common,
        /// Viewport side.
        #[arg(long, default_value_t = 1024)]
        size: u32,
        /// Depth heuristic of the frame (the paper's Figure 3 uses gradient).
        #[arg(long, default_value = "gradient")]
        heuristic: String,
        /// Timed renders per view and tracer.
        #[arg(long, default_value_t = 5)]
        runs: usize,
        /// Markdown file whose `table1` section (between marker comments) is replaced.
        #[arg(long)]
        results: Option<PathBuf>,
    },
    /// Error against representation size: position bits, radius bits, samples kept.
    Bits {
        #[command(flatten)]
        common: Common,
        /// Viewport side.
        #[arg(long, default_value_t = 512)]
        size: u32,
        /// Depth heuristic of the frame.
        #[arg(long, default_value = "threshold")]
        heuristic: String,
    },
    /// Accuracy against tracing speed for the sphere radius models (voxel, footprint).
    Radius {
        #[command(flatten)]
        common: Common,
        #[command(flatten)]
        sel: Selection,
        /// Viewport side.
        #[arg(long, default_value_t = 512)]
        size: u32,
        /// Depth heuristic of the frames.
        #[arg(long, default_value = "threshold")]
        heuristic: String,
        /// Timed renders per variant (median reported); 0: no timing.
        #[arg(long, default_value_t = 5)]
        runs: usize,
    },
    /// Samples sized by what is known: single warps of frames of each radius
    /// model, drawn with `splat` and the default drawing (`volwarp`), against the stale frame.
    Uncertainty {
        #[command(flatten)]
        common: Common,
        #[command(flatten)]
        sel: Selection,
        /// Viewport side.
        #[arg(long, default_value_t = 512)]
        size: u32,
        /// Depth heuristic of the frames.
        #[arg(long, default_value = "threshold")]
        heuristic: String,
        /// Radius variants, comma-separated: `footprint`, `voxel`, `uncertainty`, or
        /// `uncertainty:gain=G:max=M:opacity=O:measure=sigma|span`.
        #[arg(long, default_value = "footprint,uncertainty")]
        variants: String,
    },
    /// Drive every renderer through the failure cases; CSV and pictures.
    Failures {
        #[command(flatten)]
        common: Common,
        /// Viewport side.
        #[arg(long, default_value_t = 256)]
        size: u32,
        /// Depth heuristic of the frames.
        #[arg(long, default_value = "threshold")]
        heuristic: String,
    },
    /// Simulate sessions (camera path, server, network, client) and score what each method
    /// shows at every display tick against the truth.
    Session {
        #[command(flatten)]
        common: Common,
        #[command(flatten)]
        sel: Selection,
        #[command(flatten)]
        s: Box<SessionArgs>,
    },
    /// Measure the server's frame time per dataset and each method's draw time on this machine
    /// and write them as a calibration file for `session --calibration`.
    SessionCalibrate {
        /// Volume file; default: the bundled dataset.
        #[arg(long)]
        volume: Option<PathBuf>,
        #[command(flatten)]
        sel: Selection,
        /// Viewport side.
        #[arg(long, default_value_t = 512)]
        size: u32,
        /// Timed runs (median).
        #[arg(long, default_value_t = 5)]
        runs: usize,
        /// Threads per CPU renderer (0: all cores).
        #[arg(long, default_value_t = 0)]
        threads: usize,
        /// Methods to time, as `session --methods` takes them (`all`, or specs).
        #[arg(long, default_value = "all")]
        methods: String,
        /// The calibration file to write.
        #[arg(long)]
        out: PathBuf,
    },
    /// Truth | stale | volwarp side by side for a few display frames of a recorded client
    /// session (`volwarp-client --record`), with their ꟻLIP in a CSV beside the PNG.
    Strip {
        /// The record file.
        #[arg(long)]
        record: PathBuf,
        /// The volume the server served (the truth is its marcher's render); default: the
        /// bundled dataset.
        #[arg(long)]
        volume: Option<PathBuf>,
        /// Rows (display frames).
        #[arg(long, default_value_t = 4)]
        rows: usize,
        /// The PNG to write (the CSV goes beside it).
        #[arg(long)]
        out: PathBuf,
    },
    /// Redraw a session run's summaries and speed-vs-accuracy chart from its session.csv
    /// (with --calibration: with those draw times).
    SessionReplot {
        /// The session.csv.
        #[arg(long)]
        csv: PathBuf,
        /// Calibration file (`session-calibrate`) whose draw times replace the CSV's.
        #[arg(long)]
        calibration: Option<PathBuf>,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
    },
    /// Redraw the charts of a quality run from its quality.csv.
    Replot {
        /// The folder of the run (with quality.csv).
        #[arg(long)]
        dir: PathBuf,
    },
    /// Write the small image pairs the metric tests compare with the reference implementations.
    Fixtures {
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
    },
}

/// The settings of `volwarp-eval session`.
#[derive(Args, Clone)]
struct SessionArgs {
    /// Scenarios, comma-separated: orbit, stop-and-go, dolly, look-around, flick (180°/s for
    /// 0.5 s, then rest), zoom (into detail, then rest), wl-drag (a window/level drag from 1 to 2 s during an orbit) (each with an optional :DEG_PER_S), or
    /// record:FILE (a `volwarp-client --record` file).
    #[arg(long, default_value = "orbit,stop-and-go,dolly,look-around")]
    scenarios: String,
    /// Methods, comma-separated, or `all`: each a renderer with the client's options,
    /// `RENDERER[+predict][+guard=G][+frames=K][+adapt][+pp=L][+layers=K][+coarse=N][+no-preempt]`
    /// (`+no-preempt`: the server finishes every render and write, where by default, as the
    /// real server, it drops one when a request for another viewport arrives) (e.g.
    /// `splat-fill+predict+guard=0.1+frames=2`), or `volwarp` (the window client's default
    /// method), `volwarp-adaptive` / `volwarp-adaptive=4` (it on a 1/2 or 1/4 pixel grid per
    /// axis while the camera moves, full at rest), or an image-sending peer:
    /// `send-image` (JPEG q90), `downscale` / `downscale=4` (1/2 or 1/4 resolution at JPEG q50
    /// while moving, full at rest).
    #[arg(long, default_value = "all")]
    methods: String,
    /// Viewport side.
    #[arg(long, default_value_t = 512)]
    size: u32,
    /// Session length, seconds.
    #[arg(long, default_value_t = 6.0)]
    duration: f64,
    /// Server ms per frame (default 500, or the calibration file's figure for the dataset).
    #[arg(long)]
    server_ms: Option<f64>,
    /// One-way network latency, ms.
    #[arg(long, default_value_t = 50.0)]
    latency_ms: f64,
    /// Bandwidth, Mbit/s (`inf`: no transfer time).
    #[arg(long, default_value_t = 100.0)]
    mbps: f64,
    /// Display rate, Hz.
    #[arg(long, default_value_t = 30.0)]
    display_hz: f64,
    /// Score every n-th display tick (3: 10 Hz scoring of a 30 Hz display).
    #[arg(long, default_value_t = 3)]
    score_every: usize,
    /// Depth heuristic of the frames.
    #[arg(long, default_value = "threshold")]
    heuristic: String,
    /// What the server renders for.
    #[arg(long, default_value = "last-received")]
    policy: String,
    /// Calibration file (`session-calibrate`): draw ms per method, server ms per dataset.
    #[arg(long)]
    calibration: Option<PathBuf>,
    /// Sweep the server ms per frame over these values (comma-separated).
    #[arg(long, value_delimiter = ',')]
    sweep_server_ms: Vec<f64>,
    /// Sweep the bandwidth (Mbit/s) over these values, at each of `--sweep-sizes`.
    #[arg(long, value_delimiter = ',')]
    sweep_mbps: Vec<f64>,
    /// Viewport sides of the bandwidth sweep (default: `--size`).
    #[arg(long, value_delimiter = ',')]
    sweep_sizes: Vec<u32>,
    /// Warp even where the camera equals the frame's (by default the frame itself is shown).
    #[arg(long)]
    always_warp: bool,
    /// The frames' wire encoding, charged on the link: compact (the server's default) or raw12.
    #[arg(long, default_value = "compact")]
    encoding: String,
    /// Segments per pixel of the server's frames (layered samples, 1–16; method
    /// `splat-layers` composites them; 1: one sample per pixel).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=16))]
    layers: u32,
    /// The server's sphere radius model: `footprint`, `voxel`, `uncertainty` or
    /// `uncertainty:gain=G:max=M:opacity=O:measure=sigma|span`.
    #[arg(long, default_value = "footprint")]
    radius: String,
}

fn session_options(s: SessionArgs, threads: usize) -> Result<volwarp_eval::session::SessionOptions, ErrorBox> {
    use volwarp_eval::session::{model, paths, simulate::SessionConfig, SessionOptions, Sweep};
    let calibration = match &s.calibration {
        Some(p) => model::Calibration::load(p)?,
        None => model::Calibration::default(),
    };
    let sweep = match (s.sweep_server_ms.is_empty(), s.sweep_mbps.is_empty()) {
        (true, true) => Sweep::None,
        (false, true) => Sweep::Server(s.sweep_server_ms),
        (true, false) => {
            let sizes = if s.sweep_sizes.is_empty() { vec![s.size] } else { s.sweep_sizes };
            Sweep::Bandwidth(s.sweep_mbps, sizes)
        }
        (false, false) => return Err("sweep one of --sweep-server-ms and --sweep-mbps at a time".into()),
    };
    let (radius, uncertainty) = volwarp_server::radius::parse_spec(&s.radius)?;
    Ok(SessionOptions {
        march: volwarp_server::MarchOptions { radius, uncertainty, ..Default::default() },
        cfg: SessionConfig {
            size: s.size,
            duration_s: s.duration,
            net: model::NetworkModel { server_ms: 500.0, latency_ms: s.latency_ms, mbps: s.mbps },
            client: model::ClientModel { display_hz: s.display_hz, draw_ms: Default::default() },
            score_every: s.score_every,
            heuristic: heuristic(&s.heuristic)?,
            exact_when_still: !s.always_warp,
            encoding: volwarp_core::compact_frame::Encoding::from_name(&s.encoding)
                .ok_or_else(|| format!("unknown encoding {:?}; compact or raw12", s.encoding))?,
            layers: s.layers,
            resolution_cost: volwarp_eval::session::peers::ResolutionCost::MEASURED_512,
        },
        server_ms: s.server_ms,
        calibration,
        scenarios: paths::parse_list(&s.scenarios)?,
        methods: s.methods,
        threads,
        policy: s.policy,
        sweep,
    })
}

fn load(volume: Option<&Path>, tf: Option<&Path>) -> Result<Dataset, ErrorBox> {
    Ok(match volume {
        Some(v) => Dataset::load(v, tf)?,
        None => {
            let dir = data_dir().ok_or("the bundled data/ folder was not found (set VOLWARP_DATA)")?;
            Dataset::load(dir.join(volwarp_server::dataset::DEFAULT_VOLUME), tf)?
        }
    })
}

fn heuristic(name: &str) -> Result<Heuristic, ErrorBox> {
    Heuristic::from_name(name).ok_or_else(|| {
        let names: Vec<&str> = Heuristic::ALL.iter().map(|h| h.name()).collect();
        format!("unknown heuristic {name:?}; one of {}", names.join(", ")).into()
    })
}

fn run(cli: Cli) -> Result<(), ErrorBox> {
    match cli.cmd {
        Cmd::Quality { common, sel, heuristic: h, size, runs, time_all_heuristics, gpu_max_time_size } => {
            // With `all`, threshold (the seed paper's choice) comes first: it is the primary
            // heuristic of the charts and the one that is timed.
            let heuristics = if h == "all" {
                let mut v = vec![Heuristic::Threshold];
                v.extend(Heuristic::ALL.iter().copied().filter(|&x| x != Heuristic::Threshold));
                v
            } else {
                vec![heuristic(&h)?]
            };
            let datasets = sel.datasets(&common)?;
            let opts = volwarp_eval::quality::QualityOptions {
                size,
                runs,
                time_all_heuristics,
                gpu_max_time_size,
                ..Default::default()
            };
            let mut r = roster(RosterOptions { threads: common.threads, gpu: !common.no_gpu });
            report::quality(&datasets, &heuristics, &mut r, &opts, &common.out)
        }
        Cmd::Table1 { common, size, heuristic: h, runs, results } => {
            let volume = common.volume.clone().unwrap_or_else(|| PathBuf::from(report::MRI));
            let ds = Dataset::load(&volume, common.tf.as_deref())?;
            let gpu = !common.no_gpu;
            volwarp_eval::table1::run(
                &ds,
                heuristic(&h)?,
                size,
                runs,
                common.threads,
                gpu,
                &common.out,
                results.as_deref(),
            )
        }
        Cmd::Bits { common, size, heuristic: h } => {
            let ds = load(common.volume.as_deref(), common.tf.as_deref())?;
            volwarp_eval::representation_size::run(&ds, heuristic(&h)?, size, &common.out)
        }
        Cmd::Radius { common, sel, size, heuristic: h, runs } => {
            volwarp_eval::radius_model::run(&sel.datasets(&common)?, heuristic(&h)?, size, runs, &common.out)
        }
        Cmd::Uncertainty { common, sel, size, heuristic: h, variants } => {
            let variants = volwarp_eval::uncertainty_radius::parse_variants(&variants)?;
            let datasets = sel.datasets(&common)?;
            volwarp_eval::uncertainty_radius::run(
                &datasets,
                heuristic(&h)?,
                size,
                &variants,
                common.threads,
                &common.out,
            )
        }
        Cmd::Failures { common, size, heuristic: h } => {
            let ds = load(common.volume.as_deref(), common.tf.as_deref())?;
            let mut r = roster(RosterOptions { threads: common.threads, gpu: !common.no_gpu });
            report::failures(&Marcher::from_dataset(&ds), &ds.name, heuristic(&h)?, size, &mut r, &common.out)
        }
        Cmd::Session { common, sel, s } => {
            let opts = session_options(*s, common.threads)?;
            let datasets = sel.datasets(&common)?;
            volwarp_eval::session::run(&datasets, &opts, &common.out).map(|_| ())
        }
        Cmd::SessionCalibrate { volume, sel, size, runs, threads, methods, out } => {
            let datasets =
                if sel.all { report::shared_datasets(&sel.data_dir)? } else { vec![load(volume.as_deref(), None)?] };
            let cal = volwarp_eval::session::calibrate(&datasets, size, runs, threads, &methods)?;
            std::fs::write(&out, cal.to_csv()).map_err(|e| format!("{}: {e}", out.display()))?;
            log::info!("wrote {}", out.display());
            Ok(())
        }
        Cmd::Strip { record, volume, rows, out } => {
            let ds = load(volume.as_deref(), None)?;
            let rows = volwarp_eval::demo_strip::write_strip(&Marcher::from_dataset(&ds), &record, rows, &out)?;
            for r in &rows {
                log::info!(
                    "t {:.2} s, frame {}: FLIP stale {:.4}, volwarp {:.4}",
                    r.t_s,
                    r.frame_seq,
                    r.stale_flip,
                    r.volwarp_flip
                );
            }
            log::info!("wrote {}", out.display());
            Ok(())
        }
        Cmd::SessionReplot { csv, calibration, out } => {
            let cal = calibration.as_deref().map(volwarp_eval::session::model::Calibration::load).transpose()?;
            volwarp_eval::session::report::replot(&csv, cal.as_ref(), &out)
        }
        Cmd::Fixtures { out } => report::fixtures(&out),
        Cmd::Replot { dir } => report::replot(&dir),
    }
}

fn main() {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("info")).init();
    let t = Instant::now();
    if let Err(e) = run(Cli::parse()) {
        log::error!("{e}");
        std::process::exit(1);
    }
    log::info!("done in {:.1} s", t.elapsed().as_secs_f64());
}
