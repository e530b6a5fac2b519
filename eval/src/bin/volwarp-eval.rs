//! `volwarp-eval`: accuracy against speed (issue 7).
//!
//! ```text
//! volwarp-eval quality  --volume FILE [--tf FILE] [--heuristic H|all] --out DIR
//! volwarp-eval quality  --all [--data-dir ../shared/data] --out DIR
//! volwarp-eval table1   [--volume ../shared/data/mri_colin27_181x217x181_uint8.raw] --out DIR [--results docs/results.md]
//! volwarp-eval bits     [--volume FILE] --out DIR
//! volwarp-eval radius   [--volume FILE | --all] --out DIR
//! volwarp-eval failures [--volume FILE] --out DIR
//! volwarp-eval replot   --dir DIR
//! volwarp-eval fixtures --out eval/fixtures
//! ```
//! Without `--volume`, the bundled dataset (`data/ct_head_quarter.nhdr`) is used.

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
    /// Output folder.
    #[arg(long)]
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
        Cmd::Failures { common, size, heuristic: h } => {
            let ds = load(common.volume.as_deref(), common.tf.as_deref())?;
            let mut r = roster(RosterOptions { threads: common.threads, gpu: !common.no_gpu });
            report::failures(&Marcher::from_dataset(&ds), &ds.name, heuristic(&h)?, size, &mut r, &common.out)
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
