//! Putting the client together: a `volwarp-server` child process or `--connect`, connection, network thread,
//! renderers, recorder, and one of the window / headless / bench loops.

use crate::connection::connect_secure;
use crate::controls::home_camera;
use crate::display::Display;
use crate::error::ClientError;
use crate::feed_server::{FeedServer, PrerenderOptions};
use crate::network::{Backoff, NetConfig, Network, Redial};
use crate::options::Options;
use crate::record::Recorder;
use crate::renderers::Renderers;
use crate::server_process::{ServerProcess, ServerSpawn};
use std::time::Duration;

/// Runs the client as the command line says.
pub fn run(opts: &Options) -> Result<(), ClientError> {
    opts.validate()?;
    let with_token;
    let opts = match opts.access_token()? {
        Some(t) if opts.token.as_deref() != Some(t.as_str()) => {
            with_token = Options { token: Some(t), token_file: None, ..opts.clone() };
            &with_token
        }
        _ => opts,
    };
    crate::renderers::set_adapter(opts.adapter.clone());
    if let Some(path) = &opts.replay {
        return crate::replay::run(opts, path);
    }
    let windowed = !opts.headless && !opts.bench;
    if windowed {
        // Fail before starting anything when there is no display at all.
        crate::window::check_display()?;
    }
    if let Some(addr) = &opts.connect {
        // An external server may restart: connect again unless told not to.
        return run_connected(opts, addr, !opts.no_reconnect);
    }
    if opts.prerender {
        let interval = Duration::from_millis(if opts.server_delay_ms > 0 { opts.server_delay_ms } else { 500 });
        let step = crate::bench::DEG_PER_SECOND * interval.as_secs_f32();
        let count = ((360.0 / step).ceil() as usize).clamp(1, 64);
        log::info!("prerendering {count} frames of {}x{} ...", opts.size.0, opts.size.1);
        let pre = crate::feed_server::prerender(&PrerenderOptions {
            width: opts.size.0,
            height: opts.size.1,
            heuristic: opts.heuristic,
            radius_scale: opts.radius_scale,
            count,
            step_deg: step,
            server_threads: opts.server_threads,
            timeout: Duration::from_secs(opts.timeout_s.max(1)),
        })?;
        let feed = FeedServer::start(pre.frames, interval)?;
        return run_connected(opts, &feed.addr().to_string(), false);
    }
    let server = ServerProcess::spawn(&ServerSpawn {
        frame_delay: (opts.server_delay_ms > 0).then(|| Duration::from_millis(opts.server_delay_ms)),
        threads: opts.server_threads,
        extra_args: opts.server_args(),
        startup_timeout: Duration::from_secs(opts.timeout_s.max(1)),
    })?;
    // The child lives and dies with this client: no reconnecting to it.
    let result = run_connected(opts, &server.addr().to_string(), false);
    drop(server);
    result
}

fn run_connected(opts: &Options, addr: &str, reconnect: bool) -> Result<(), ClientError> {
    let timeout = Duration::from_secs(opts.timeout_s.max(1));
    crate::renderers::set_layer_options(opts.layer_options());
    let mut renderers = Renderers::new(opts.renderer, opts.tracer_threads()).map_err(ClientError::Renderer)?;
    renderers.set_adaptive_radius(opts.adapt);
    log::info!(
        "renderer {} with {}",
        opts.renderer,
        crate::window::levers(
            opts.predict,
            opts.guard,
            renderers.adaptive_radius(),
            if renderers.keeps_frames() { opts.keep_frames } else { 1 },
            renderers.watertight(),
        )
    );
    let tls = opts.tls_config()?;
    let conn = connect_secure(addr, opts.token.as_deref(), timeout, opts.layers(), tls.as_ref())?;
    let home = home_camera(&conn.bounds, opts.size.0, opts.size.1);
    let recorder = opts.record.as_deref().map(Recorder::create).transpose()?;
    let cfg = NetConfig {
        latency: Duration::from_millis(opts.latency_ms),
        build_threads: opts.build_threads,
        timeout,
        lazy_build: !opts.renderer.info().caps.needs_lbvh,
        bandwidth_mbps: (opts.bandwidth_mbps > 0.0).then_some(opts.bandwidth_mbps),
        request: opts.method().request(),
    };
    let sink = recorder.as_ref().map(Recorder::sink);
    let net = if reconnect {
        let redial = Redial {
            addr: addr.to_string(),
            token: opts.token.clone(),
            layers: opts.layers(),
            // Clients started together do not retry in lockstep.
            backoff: Backoff { seed: u64::from(std::process::id()), ..Backoff::default() },
            tls,
        };
        Network::start_reconnecting(conn, cfg, sink, redial)?
    } else {
        Network::start(conn, cfg, sink)?
    };
    let mut display = Display::new(net, renderers, recorder.as_ref().map(Recorder::sink));
    display.set_keep_frames(opts.keep_frames);
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
