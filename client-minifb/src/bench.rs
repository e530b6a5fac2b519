//! `--bench`: the display rate while frames keep arriving. Runs the display loop headless and
//! unpaced for `--seconds`, orbiting continuously (30°/s, so every display frame is a new
//! camera and the writer keeps sending), converting every image to the window's pixel format,
//! and reports the frame rate over all display frames and over those during which the network
//! thread was decoding or building a frame's LBVH. Slow the server down with
//! `--server-delay-ms` (or `--latency-ms`) to see latency hiding at work. With `--out DIR` every
//! display frame is also written to `DIR/bench.csv`.

use crate::display::{to_0rgb, Display};
use crate::error::ClientError;
use crate::network::View;
use crate::options::Options;
use std::fmt;
use std::fmt::Write as _;
use std::time::{Duration, Instant};
use volwarp_core::Camera;

/// Orbit speed of the bench camera.
pub const DEG_PER_SECOND: f32 = 30.0;

/// CPU time the calling thread has run, in ns (Linux: `/proc/thread-self/schedstat`), so a
/// loaded machine's scheduling can be told apart from the display loop's own cost.
pub fn thread_cpu_ns() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    s.split_whitespace().next()?.parse().ok()
}

/// Median and minimum of a set of per-frame rates.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FpsStats {
    /// Display frames measured.
    pub frames: usize,
    /// Median frames per second (1000 / median frame time).
    pub median: f64,
    /// Lowest frames per second (1000 / longest frame time).
    pub min: f64,
    /// 1st percentile of frames per second.
    pub p1: f64,
}

impl FpsStats {
    /// The statistics of frame times in ms.
    pub fn of(ms: &[f64]) -> FpsStats {
        if ms.is_empty() {
            return FpsStats::default();
        }
        let mut v: Vec<f64> = ms.iter().copied().filter(|m| m.is_finite()).collect();
        v.sort_by(f64::total_cmp);
        let fps = |m: f64| if m > 0.0 { 1000.0 / m } else { f64::INFINITY };
        let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
        FpsStats { frames: v.len(), median: fps(at(0.5)), min: fps(v[v.len() - 1]), p1: fps(at(0.99)) }
    }
}

impl fmt::Display for FpsStats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{:6} frames, median {:7.1} FPS, 1st percentile {:7.1} FPS, minimum {:7.1} FPS",
            self.frames, self.median, self.p1, self.min
        )
    }
}

/// The outcome of a bench run.
#[derive(Clone, Debug, Default)]
pub struct BenchSummary {
    /// Over all display frames.
    pub all: FpsStats,
    /// Over display frames that overlapped a decode or LBVH build.
    pub during_build: FpsStats,
    /// Over the other display frames.
    pub idle: FpsStats,
    /// Over all display frames, from the display thread's CPU time per frame (what the rate
    /// would be with a core to itself; `None` where the OS does not tell).
    pub all_cpu: Option<FpsStats>,
    /// The same for display frames that overlapped a decode or LBVH build.
    pub during_build_cpu: Option<FpsStats>,
    /// Frames received from the server.
    pub server_frames: u64,
    /// Seconds measured.
    pub seconds: f64,
    /// Median LBVH build time in ms.
    pub build_ms_median: f64,
    /// Median samples per shown scene.
    pub samples_median: usize,
    /// Median age of the shown frame in ms.
    pub age_ms_median: f64,
}

impl fmt::Display for BenchSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "all display frames:      {}", self.all)?;
        writeln!(f, "during decode/LBVH build: {}", self.during_build)?;
        writeln!(f, "other frames:            {}", self.idle)?;
        if let (Some(a), Some(b)) = (&self.all_cpu, &self.during_build_cpu) {
            writeln!(f, "from display-thread CPU time per frame (the loop's own cost, without preemption):")?;
            writeln!(f, "all display frames:      {a}")?;
            writeln!(f, "during decode/LBVH build: {b}")?;
        }
        writeln!(
            f,
            "server frames: {} in {:.1} s ({:.2}/s); LBVH build median {:.1} ms; samples median {}; frame age median {:.0} ms",
            self.server_frames,
            self.seconds,
            self.server_frames as f64 / self.seconds.max(1e-9),
            self.build_ms_median,
            self.samples_median,
            self.age_ms_median
        )
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    volwarp_core::stats::median(&mut v).unwrap_or(f64::NAN)
}

/// Runs the bench and prints its summary to stdout.
pub fn run(opts: &Options, display: &mut Display, home: Camera) -> Result<BenchSummary, ClientError> {
    log::info!("bench: waiting for the first frame");
    let first = View { camera: home, heuristic: opts.heuristic, radius_scale: opts.radius_scale };
    display.wait_first_scene(&first, Duration::from_secs(opts.timeout_s))?;
    let frames0 = display.network().frames_received();
    let mut buf = Vec::new();
    let (mut all, mut busy, mut idle, mut builds, mut samples, mut ages) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (mut cpu_all, mut cpu_busy) = (Vec::new(), Vec::new());
    let mut cpu_ok = thread_cpu_ns().is_some();
    let mut csv = String::from("frame,t_s,yaw_deg,display_ms,cpu_ms,render_ms,during_build,frame_seq,new_frame\n");
    let t_start = Instant::now();
    let dur = Duration::from_secs_f64(opts.seconds);
    while t_start.elapsed() < dur {
        let t0 = Instant::now();
        let c0 = thread_cpu_ns();
        let yaw = t_start.elapsed().as_secs_f32() * DEG_PER_SECOND;
        let view = View { camera: home.orbit(yaw, 0.0), heuristic: opts.heuristic, radius_scale: opts.radius_scale };
        let r = display.frame(&view);
        to_0rgb(&display.image, &mut buf);
        std::hint::black_box(&buf);
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        let cpu_ms = match (c0, thread_cpu_ns()) {
            (Some(a), Some(b)) => b.saturating_sub(a) as f64 / 1e6,
            _ => {
                cpu_ok = false;
                f64::NAN
            }
        };
        display.check()?;
        let _ = writeln!(
            csv,
            "{},{:.4},{yaw:.2},{ms:.3},{cpu_ms:.3},{:.3},{},{},{}",
            all.len(),
            t0.duration_since(t_start).as_secs_f64(),
            r.render_ms,
            u8::from(r.during_build),
            r.frame_seq,
            u8::from(r.new_frame)
        );
        all.push(ms);
        if r.during_build { &mut busy } else { &mut idle }.push(ms);
        cpu_all.push(cpu_ms);
        if r.during_build {
            cpu_busy.push(cpu_ms);
        }
        if let Some(b) = r.build_ms {
            builds.push(b);
            samples.push(r.samples as f64);
        }
        if let Some(a) = r.age_ms {
            ages.push(a);
        }
    }
    let seconds = t_start.elapsed().as_secs_f64();
    if let Some(dir) = &opts.out {
        let p = dir.join("bench.csv");
        std::fs::create_dir_all(dir)
            .and_then(|_| std::fs::write(&p, &csv))
            .map_err(|e| ClientError::Io(format!("cannot write {}: {e}", p.display())))?;
    }
    let s = BenchSummary {
        all: FpsStats::of(&all),
        during_build: FpsStats::of(&busy),
        idle: FpsStats::of(&idle),
        all_cpu: cpu_ok.then(|| FpsStats::of(&cpu_all)),
        during_build_cpu: cpu_ok.then(|| FpsStats::of(&cpu_busy)),
        server_frames: display.network().frames_received() - frames0,
        seconds,
        build_ms_median: median(builds),
        samples_median: median(samples) as usize,
        age_ms_median: median(ages),
    };
    println!(
        "volwarp-client bench: {}x{}, renderer {}, {} tracer thread(s), {} build thread(s), server delay {} ms, latency {} ms, link {}",
        home.width,
        home.height,
        display.renderers.name(),
        opts.tracer_threads(),
        opts.build_threads,
        opts.server_delay_ms,
        opts.latency_ms,
        if opts.bandwidth_mbps > 0.0 { format!("{} Mbit/s", opts.bandwidth_mbps) } else { "unthrottled".into() }
    );
    print!("{s}");
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fps_stats_use_median_and_longest_frame() {
        let s = FpsStats::of(&[10.0, 20.0, 40.0]);
        assert_eq!(s.frames, 3);
        assert!((s.median - 50.0).abs() < 1e-9);
        assert!((s.min - 25.0).abs() < 1e-9);
        assert_eq!(FpsStats::of(&[]), FpsStats::default());
    }
}
