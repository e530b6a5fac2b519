//! Putting the client together: in-process server or `--connect`, connection, network thread,
//! renderers, recorder, and one of the window / headless / bench loops.

use crate::connection::connect;
use crate::controls::home_camera;
use crate::display::Display;
use crate::error::ClientError;
use crate::local_server::LocalServer;
use crate::network::{NetConfig, Network};
use crate::options::Options;
use crate::record::Recorder;
use crate::renderers::Renderers;
use std::time::Duration;

/// Runs the client as the command line says.
pub fn run(opts: &Options) -> Result<(), ClientError> {
    opts.validate()?;
    if let Some(path) = &opts.replay {
        return crate::replay::run(opts, path);
    }
    let windowed = !opts.headless && !opts.bench;
    if windowed {
        // Fail before starting anything when there is no display at all.
        crate::window::check_display()?;
    }
    let local = match &opts.connect {
        Some(_) => None,
        None => {
            let delay = (opts.server_delay_ms > 0).then(|| Duration::from_millis(opts.server_delay_ms));
            Some(LocalServer::start(delay, opts.server_threads)?)
        }
    };
    let addr = match (&opts.connect, &local) {
        (Some(a), _) => a.clone(),
        (None, Some(l)) => l.addr().to_string(),
        (None, None) => unreachable!("an in-process server was started"),
    };
    let result = run_connected(opts, &addr);
    if let Some(l) = local {
        l.shutdown();
    }
    result
}

fn run_connected(opts: &Options, addr: &str) -> Result<(), ClientError> {
    let timeout = Duration::from_secs(opts.timeout_s.max(1));
    let renderers = Renderers::new(&opts.renderer, opts.tracer_threads()).map_err(ClientError::Renderer)?;
    let conn = connect(addr, opts.token.as_deref(), timeout)?;
    let home = home_camera(&conn.bounds, opts.size.0, opts.size.1);
    let recorder = opts.record.as_deref().map(Recorder::create).transpose()?;
    let cfg = NetConfig { latency: Duration::from_millis(opts.latency_ms), build_threads: opts.build_threads, timeout };
    let net = Network::start(conn, cfg, recorder.as_ref().map(Recorder::sink))?;
    let mut display = Display::new(net, renderers, recorder.as_ref().map(Recorder::sink));
    let result = if opts.bench {
        crate::bench::run(opts, &mut display, home).map(|_| ())
    } else if opts.headless {
        crate::headless::run(opts, &mut display, home)
    } else {
        crate::window::run_live(opts, &mut display, home)
    };
    display.shutdown();
    let recorded = recorder.map(Recorder::finish).transpose();
    result?;
    recorded.map(|_| ())
}
