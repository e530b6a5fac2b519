//! `volwarp-server`: serve a volume to volwarp clients, render ground-truth images, dump frames.
//!
//! ```text
//! volwarp-server                                   # serve the bundled CT head on 127.0.0.1:7878
//! volwarp-server --volume head.nrrd --tf tf.json --listen 0.0.0.0:7878 --token-file ~/.volwarp-token
//! volwarp-server --listen 0.0.0.0:7878 --token-file T --tls-cert cert.pem --tls-key key.pem   # over TLS
//! volwarp-server render --volume FILE [--tf FILE] [--orbit 30,10] [--size 1024x1024] --out img.png
//! volwarp-server dump [--orbit 30,10] [--heuristic threshold] [--encoding compact|raw12] --out frame.vwf
//! volwarp-server render --preset ct-bone --window-level 0.8,0.45 --crop 0,0,0,1,0.5,1 --out cut.png
//! volwarp-server info scan.nii.gz                  # what a volume file holds, without rendering
//! volwarp-server synth --dims 1024,1024,1024 --type u8 --out /tmp/big   # a synthetic volume
//! ```

use clap::{Args, Parser, Subcommand};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};
use volwarp_core::compact_frame::Encoding;
use volwarp_core::wire::CameraRequest;
use volwarp_core::{Camera, Heuristic};
use volwarp_server::volume::{parse_dims, LoadOptions, VoxelType};
use volwarp_server::{
    default_camera, Dataset, MarchKernel, MarchOptions, Marcher, RadiusModel, Server, ServerConfig, TlsIdentity,
};

#[derive(Parser, Debug)]
#[command(
    name = "volwarp-server",
    version,
    about = "volwarp server: ray-marches a volume and sends compacted object-space samples to clients"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Option<Cmd>,
    #[command(flatten)]
    data: DataArgs,
    #[command(flatten)]
    net: NetArgs,
}

#[derive(Subcommand, Debug)]
enum Cmd {
    /// Serve clients (the default).
    Serve,
    /// Render a ground-truth image to a PNG file.
    Render {
        #[command(flatten)]
        cam: CameraArgs,
        /// Output PNG file.
        #[arg(long)]
        out: PathBuf,
        /// Render level of detail N (0: the volume itself; N: downsampled 2^N times per axis,
        /// what a moving camera gets under `--frame-budget-ms`).
        #[arg(long, default_value_t = 0)]
        level: u8,
    },
    /// Write one Frame (wire format, header included) to a file; prints its sample count and
    /// bytes.
    Dump {
        #[command(flatten)]
        cam: CameraArgs,
        /// Output file.
        #[arg(long)]
        out: PathBuf,
        /// Wire encoding: `raw12` (message type 3, 12 bytes per sample) or `compact` (type 6).
        #[arg(long, default_value = "raw12", value_parser = parse_encoding)]
        encoding: Encoding,
        /// Render the frame this many times (1–100), logging each, and write the last: the
        /// first frame of a process pays for touching its buffers' memory, later ones are what
        /// a serving server takes per frame.
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=100))]
        frames: u32,
    },
    /// Print what a volume file (or folder of slices) holds: format, dims, voxel type,
    /// spacing, value range, the orientation applied, bytes. Nothing is rendered.
    Info {
        /// The volume: any file or folder `--volume` takes.
        path: PathBuf,
    },
    /// Write a synthetic volume of any size (`--dims X,Y,Z`, `--type u8|u16`, default u8) into
    /// a folder as `synth_XxYxZ_uint8.raw` (or `_uint16`), which `--volume` then opens by path;
    /// prints the path and the time taken.
    Synth {
        /// Output folder (must exist).
        #[arg(long)]
        out: PathBuf,
    },
}

#[derive(Args, Debug)]
struct DataArgs {
    /// Volume: a file (.raw named name_XxYxZ_type.raw, .nrrd, .nhdr, .nii, .nii.gz, .vti,
    /// .tif, .dcm) or a folder of DICOM or TIFF slices (recognized by content), or
    /// `marschner-lobb[:N]`. Default: the bundled CT head in data/.
    #[arg(long, global = true)]
    volume: Option<String>,
    /// Transfer function (.json from ParaView, or the text format of docs/server.md). Default:
    /// the preset for the volume.
    #[arg(long, global = true)]
    tf: Option<PathBuf>,
    /// Dimensions XxYxZ of a raw file whose name does not carry them; for `synth`, those of the
    /// volume to write (X,Y,Z or XxYxZ).
    #[arg(long, global = true)]
    dims: Option<String>,
    /// Voxel type of a raw file (uint8, uint16, int16, float32, ...); for `synth`, u8 or u16.
    #[arg(long = "type", global = true)]
    voxel_type: Option<String>,
    /// Voxel spacing X,Y,Z (overrides the file).
    #[arg(long, global = true)]
    spacing: Option<String>,
    /// The memory a volume may take: `auto` (what the system has available), a size such as
    /// `20G` or `512M`, or `none` (load whatever it needs). A volume that needs more is
    /// refused before anything is allocated.
    #[arg(long, global = true, default_value = "auto", value_parser = volwarp_server::volume::MemoryLimit::parse)]
    max_memory: volwarp_server::volume::MemoryLimit,
    /// Ray-marching step in voxels.
    #[arg(long, global = true, default_value_t = 0.5)]
    step: f32,
    /// Depth heuristic for `dump` (entrance, exit, midpoint, threshold, peak, gradient,
    /// rel-threshold, en-ex-mean).
    #[arg(long, global = true, default_value = "threshold")]
    heuristic: String,
    /// Sphere radius model: `footprint` (a pixel diagonal at the sample's depth),
    /// `voxel` (half a voxel diagonal, the seed paper's) or `uncertainty` (the footprint grown
    /// where the ray's color is spread along it).
    #[arg(long, global = true, default_value = "footprint")]
    radius: RadiusModel,
    /// Sphere radius as a multiple of the model's (for `dump`; clients send their own).
    #[arg(long, global = true, default_value_t = 1.0)]
    radius_scale: f32,
    /// Marching kernel: `packet` (16 to 64 rays at once in SIMD lanes) or `scalar` (one ray at a
    /// time, the reference); both give the same image.
    #[arg(long, global = true, default_value = "packet", value_parser = ["packet", "scalar"])]
    kernel: String,
    /// Skip bricks the transfer function makes invisible (`--skip-empty false` turns it off).
    #[arg(long, global = true, default_value_t = true, action = clap::ArgAction::Set)]
    skip_empty: bool,
    /// Accumulated opacity at which a ray stops (1 or more: never).
    #[arg(long, global = true, default_value_t = 0.99)]
    early_termination: f32,
    /// Layered samples, 1–16 segments per pixel: for `dump`, the frame's count
    /// (default 1: one sample per pixel at the heuristic's depth); when serving, the most a
    /// client may ask for in its Hello (default 16).
    #[arg(long, global = true, value_parser = clap::value_parser!(u8).range(1..=16))]
    layers: Option<u8>,
    #[command(flatten)]
    visual: VisualArgs,
    /// Under `mpiexec` (a build with the feature `mpi`): seconds a frame may take on the
    /// ranks before rank 0 reports a failed rank to its clients and exits with status 3.
    #[arg(long, global = true, default_value_t = 120.0)]
    rank_timeout: f64,
}

/// The visual state (`volwarp_server::visual`): what a client can change live, a script can
/// render.
#[derive(Args, Debug)]
struct VisualArgs {
    /// Gradient shading (ambient, diffuse, Blinn–Phong specular; light fixed to the volume):
    /// true or false. Default: on with the ct-bone, ct-soft-tissue and mr-default presets, off
    /// otherwise.
    #[arg(long, global = true, value_name = "BOOL", action = clap::ArgAction::Set)]
    shade: Option<bool>,
    /// A bundled transfer-function preset instead of --tf or the volume's own: grey, ct-bone,
    /// ct-soft-tissue, mr-default, cool-warm (data/presets/NAME.json).
    #[arg(long, global = true, value_name = "NAME", conflicts_with = "tf")]
    preset: Option<String>,
    /// Window and level as fractions of the value range: the transfer function spans
    /// LEVEL ± WINDOW/2 (default 1,0.5: as it is).
    #[arg(long, global = true, value_name = "W,L", allow_hyphen_values = true)]
    window_level: Option<String>,
    /// Every opacity of the transfer function times S (0..=100).
    #[arg(long, global = true, value_name = "S", default_value_t = 1.0, allow_hyphen_values = true)]
    opacity_scale: f32,
    /// Crop box in fractions of the volume box (0,0,0,1,1,1 is the whole volume).
    #[arg(long, global = true, value_name = "X0,Y0,Z0,X1,Y1,Z1")]
    crop: Option<String>,
    /// Clip plane: a point in fractions of the volume box and a normal; the side the normal
    /// points to is kept.
    #[arg(long, global = true, value_name = "PX,PY,PZ,NX,NY,NZ", allow_hyphen_values = true)]
    clip: Option<String>,
}

/// The visual state of the command line, checked.
fn visual_state(a: &VisualArgs) -> Result<volwarp_server::visual::VisualState, String> {
    use volwarp_server::visual::{parse_numbers, VisualState};
    let mut vs =
        VisualState { opacity_scale: a.opacity_scale, ..VisualState::default() }.with_preset(a.preset.clone(), a.shade);
    let e = |e: volwarp_server::visual::VisualError| e.to_string();
    if let Some(s) = &a.window_level {
        [vs.window, vs.level] = parse_numbers::<2>(s, "--window-level").map_err(e)?;
    }
    if let Some(s) = &a.crop {
        vs.crop = parse_numbers::<6>(s, "--crop").map_err(e)?;
    }
    if let Some(s) = &a.clip {
        vs.clip = Some(parse_numbers::<6>(s, "--clip").map_err(e)?);
    }
    vs.validate().map_err(|e| {
        let flag = match e.0.split_whitespace().next() {
            Some("window") | Some("level") => "--window-level",
            Some("opacity") => "--opacity-scale",
            Some("crop") => "--crop",
            Some("clip") => "--clip",
            _ => "--preset",
        };
        format!("{flag}: {e}")
    })?;
    Ok(vs)
}

#[derive(Args, Debug)]
struct NetArgs {
    /// Address to listen on (port 0 picks a free port).
    #[arg(long, default_value = "127.0.0.1:7878")]
    listen: SocketAddr,
    /// Access token clients must send (required on non-loopback addresses; also $VOLWARP_TOKEN).
    #[arg(long, conflicts_with = "token_file")]
    token: Option<String>,
    /// Read the access token from FILE (surrounding whitespace trimmed), so it does not show in
    /// `ps` output.
    #[arg(long, value_name = "FILE")]
    token_file: Option<PathBuf>,
    /// Wrong tokens accepted per second from one address (IPv6: one /64), in bursts of as
    /// many; then its connections get Error RATE_LIMITED before the handshake (0: no limit).
    #[arg(long, value_name = "N", default_value_t = 10)]
    max_auth_failures: u32,
    /// Serve over TLS with this PEM certificate chain (leaf first; needs --tls-key). Clients
    /// connect with `volwarp-client --tls [--ca FILE]`. Default: plain TCP.
    #[arg(long, value_name = "FILE", requires = "tls_key")]
    tls_cert: Option<PathBuf>,
    /// The PEM private key of --tls-cert (PKCS#8, PKCS#1 or SEC1).
    #[arg(long, value_name = "FILE", requires = "tls_cert")]
    tls_key: Option<PathBuf>,
    /// Marcher threads (0 = one per core).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Most clients at once.
    #[arg(long, default_value_t = 8)]
    max_clients: usize,
    /// Largest client message payload in bytes (1640: the largest VisualEdit, a transfer
    /// function of 64 color and 64 opacity points).
    #[arg(long, default_value_t = volwarp_core::wire::VISUAL_EDIT_MAX_LEN as u32)]
    max_message: u32,
    /// Seconds a client has for the Hello exchange.
    #[arg(long, default_value_t = 5.0)]
    handshake_timeout: f64,
    /// Seconds a client may stay silent.
    #[arg(long, default_value_t = 600.0)]
    idle_timeout: f64,
    /// Seconds a frame may take to send.
    #[arg(long, default_value_t = 30.0)]
    send_timeout: f64,
    /// Largest viewport width or height.
    #[arg(long, default_value_t = 4096)]
    max_viewport: u32,
    /// Artificial delay before each frame, in milliseconds (latency demos).
    #[arg(long, default_value_t = 0)]
    frame_delay_ms: u64,
    /// Exit when standard input reaches its end: a parent that started this server as a child
    /// (the client's demo) takes it down with it, even if the parent is killed.
    #[arg(long)]
    exit_on_stdin_eof: bool,
    /// Never send CompactFrames, even to clients that ask (every frame 12 bytes per sample).
    #[arg(long)]
    no_compact: bool,
    /// Frame-time budget in milliseconds while a client's camera moves: builds the levels of
    /// detail at start (about +14 % memory) and marches the finest one predicted to fit; a
    /// resting camera always gets the volume itself. Default: no budget, no levels.
    #[arg(long)]
    frame_budget_ms: Option<f64>,
}

#[derive(Args, Debug)]
struct CameraArgs {
    /// Orbit YAW,PITCH in degrees relative to the default camera (which frames the volume from
    /// its +y side with +z up).
    #[arg(long, default_value = "0,0", allow_hyphen_values = true)]
    orbit: String,
    /// Distance factor relative to the default camera (< 1 moves closer).
    #[arg(long, default_value_t = 1.0)]
    zoom: f32,
    /// Vertical field of view in degrees.
    #[arg(long, default_value_t = 30.0)]
    fov: f32,
    /// Viewport WxH.
    #[arg(long, default_value = "1024x1024")]
    size: String,
}

fn secs(s: f64, what: &str) -> Result<Duration, String> {
    Duration::try_from_secs_f64(s).map_err(|_| format!("--{what} must be a non-negative number of seconds"))
}

fn camera(ds: &Dataset, a: &CameraArgs) -> Result<Camera, String> {
    camera_from(default_camera(&ds.volume, 1, 1), a)
}

/// The camera of `--orbit`, `--zoom`, `--fov` and `--size` from the volume's default camera.
fn camera_from(default: Camera, a: &CameraArgs) -> Result<Camera, String> {
    let (w, h) = a
        .size
        .split_once(['x', 'X'])
        .and_then(|(w, h)| Some((w.trim().parse::<u32>().ok()?, h.trim().parse::<u32>().ok()?)))
        .ok_or_else(|| format!("--size {:?} is not WxH", a.size))?;
    let (yaw, pitch) = a
        .orbit
        .split_once(',')
        .and_then(|(y, p)| Some((y.trim().parse::<f32>().ok()?, p.trim().parse::<f32>().ok()?)))
        .ok_or_else(|| format!("--orbit {:?} is not YAW,PITCH", a.orbit))?;
    let cam = Camera { fov_y_deg: a.fov, width: w, height: h, ..default }.orbit(yaw, pitch).dolly(a.zoom);
    cam.validate(16384).map_err(|e| format!("camera: {e}"))?;
    Ok(cam)
}

fn load(d: &DataArgs) -> Result<Dataset, String> {
    let Some(v) = &d.volume else {
        return Ok(Dataset::default_bundled());
    };
    if let Some(rest) = v.strip_prefix("marschner-lobb") {
        let n =
            rest.strip_prefix(':').map_or(Ok(64), |s| s.parse::<u32>()).map_err(|_| "marschner-lobb:N".to_string())?;
        let mut ds = Dataset::marschner_lobb(n);
        if let Some(tf) = &d.tf {
            ds.tf = volwarp_server::TransferFunction::load(tf, ds.volume.value_range()).map_err(|e| e.to_string())?;
        }
        return Ok(ds);
    }
    let opts = load_options(d)?;
    Dataset::load_with(v, &opts, d.tf.as_deref()).map_err(|e| e.to_string())
}

/// The loader options of `--dims`, `--type`, `--spacing` and `--max-memory`.
fn load_options(d: &DataArgs) -> Result<LoadOptions, String> {
    let mut opts = LoadOptions { memory: d.max_memory, ..LoadOptions::default() };
    if let Some(s) = &d.dims {
        opts.dims = Some(parse_dims(s).ok_or_else(|| format!("--dims {s:?} is not XxYxZ"))?);
    }
    if let Some(t) = &d.voxel_type {
        opts.voxel_type = Some(VoxelType::parse(t).ok_or_else(|| format!("--type {t:?} is not a voxel type"))?);
    }
    if let Some(s) = &d.spacing {
        let v: Vec<f32> = s.split(',').filter_map(|x| x.trim().parse().ok()).collect();
        if v.len() != 3 || v.iter().any(|x| !(x.is_finite() && *x > 0.0)) {
            return Err(format!("--spacing {s:?} is not three positive numbers X,Y,Z"));
        }
        opts.spacing = Some(volwarp_core::Vec3::new(v[0], v[1], v[2]));
    }
    Ok(opts)
}

/// `info PATH`: what the loader read.
fn info(path: &std::path::Path, d: &DataArgs) -> Result<(), String> {
    let v = volwarp_server::load_volume(path, &load_options(d)?).map_err(|e| e.to_string())?;
    let src = v.source();
    let [nx, ny, nz] = v.dims();
    let (s, e) = (v.spacing(), v.extent());
    let (lo, hi) = v.value_range();
    println!("file         {}", path.display());
    println!("format       {}", src.format);
    println!("dims         {nx} x {ny} x {nz} ({} voxels)", nx as u64 * ny as u64 * nz as u64);
    println!("voxel type   {}", src.voxel_type.map_or("?", |t| t.name()));
    println!("spacing      {}, {}, {}", s.x, s.y, s.z);
    println!("extent       {}, {}, {}", e.x, e.y, e.z);
    println!("value range  {lo} .. {hi}");
    println!("orientation  {}", src.orientation);
    println!("data         {} bytes in {} file{}", src.data_bytes, src.files, if src.files == 1 { "" } else { "s" });
    let bricks = v.voxels().layout().bricks();
    println!(
        "in memory    {} bytes: {} bricks of {}^3 voxels as {}",
        v.memory_bytes(),
        bricks.iter().map(|&b| u64::from(b)).product::<u64>(),
        volwarp_server::volume::bricks::BRICK_EDGE,
        v.voxels().type_name()
    );
    Ok(())
}

/// `synth --dims X,Y,Z --type u8|u16 --out DIR`: writes the volume, prints its path and time.
fn synth(d: &DataArgs, out: &std::path::Path) -> Result<(), String> {
    use volwarp_server::synth::{write_synth, SynthType};
    let s = d.dims.as_deref().ok_or("synth needs --dims X,Y,Z")?;
    let v: Vec<u32> = s.split([',', 'x', 'X']).filter_map(|x| x.trim().parse().ok()).collect();
    let dims: [u32; 3] = v
        .try_into()
        .ok()
        .filter(|d: &[u32; 3]| !d.contains(&0))
        .ok_or_else(|| format!("--dims {s:?} is not three positive integers X,Y,Z"))?;
    let t = d.voxel_type.as_deref().unwrap_or("u8");
    let ty = SynthType::parse(t).ok_or_else(|| format!("--type {t:?}: synth writes u8 or u16"))?;
    let t0 = Instant::now();
    let path = write_synth(dims, ty, out).map_err(|e| e.to_string())?;
    println!("wrote {} in {:.2} s", path.display(), t0.elapsed().as_secs_f64());
    Ok(())
}

/// The access token: `--token`, else `--token-file` (trimmed), else `$VOLWARP_TOKEN`.
fn token(n: &NetArgs) -> Result<Option<String>, String> {
    if let Some(t) = &n.token {
        return Ok(Some(t.clone()));
    }
    if let Some(path) = &n.token_file {
        let text = std::fs::read_to_string(path).map_err(|e| format!("--token-file {}: {e}", path.display()))?;
        let t = text.trim();
        if t.is_empty() {
            return Err(format!("--token-file {}: the file holds no token", path.display()));
        }
        return Ok(Some(t.to_string()));
    }
    Ok(std::env::var("VOLWARP_TOKEN").ok().filter(|t| !t.is_empty()))
}

/// The server settings of the command line.
fn server_config(n: &NetArgs, layers: Option<u8>) -> Result<ServerConfig, String> {
    let token = token(n)?;
    Ok(ServerConfig {
        listen: n.listen,
        threads: n.threads,
        max_clients: n.max_clients,
        max_message: n.max_message,
        handshake_timeout: secs(n.handshake_timeout, "handshake-timeout")?,
        idle_timeout: secs(n.idle_timeout, "idle-timeout")?,
        send_timeout: secs(n.send_timeout, "send-timeout")?,
        max_viewport: n.max_viewport,
        token,
        max_auth_failures: n.max_auth_failures,
        tls: tls(n)?,
        frame_delay: (n.frame_delay_ms > 0).then(|| Duration::from_millis(n.frame_delay_ms)),
        compact: !n.no_compact,
        layers: layers.unwrap_or(volwarp_core::segments::MAX_LAYERS as u8),
        frame_budget: match n.frame_budget_ms {
            Some(ms) => Some(secs(ms / 1e3, "frame-budget-ms")?),
            None => None,
        },
    })
}

/// The TLS identity of `--tls-cert` and `--tls-key`, if given.
fn tls(n: &NetArgs) -> Result<Option<TlsIdentity>, String> {
    match (&n.tls_cert, &n.tls_key) {
        (Some(cert), Some(key)) => {
            TlsIdentity::from_pem_files(cert, key).map(Some).map_err(|e| format!("--tls-cert/--tls-key: {e}"))
        }
        _ => Ok(None),
    }
}

fn run(cli: Cli) -> Result<(), String> {
    match &cli.cmd {
        Some(Cmd::Info { path }) => return info(path, &cli.data),
        Some(Cmd::Synth { out }) => return synth(&cli.data, out),
        None | Some(Cmd::Serve) => {
            // A bad token file or TLS file is reported before the volume is loaded.
            token(&cli.net)?;
            tls(&cli.net)?;
        }
        _ => {}
    }
    let visual = visual_state(&cli.data.visual)?;
    #[cfg(feature = "mpi")]
    if volwarp_server::distributed::mpi::launched_by_mpiexec() {
        if visual != volwarp_server::visual::VisualState::default() {
            return Err(
                "--preset, --shade, --window-level, --opacity-scale, --crop and --clip are not applied across \
                        MPI ranks yet: run them on one process, or give the transfer function with --tf"
                    .into(),
            );
        }
        return run_mpi(cli);
    }
    let ds = load(&cli.data)?;
    let heuristic = Heuristic::from_name(&cli.data.heuristic)
        .ok_or_else(|| format!("unknown heuristic {:?}", cli.data.heuristic))?;
    let kernel = if cli.data.kernel == "scalar" { MarchKernel::Scalar } else { MarchKernel::Packet };
    let opts = MarchOptions {
        step_voxels: cli.data.step,
        radius: cli.data.radius,
        uncertainty: volwarp_server::radius::UncertaintyParams::DEFAULT,
        kernel,
        skip_empty: cli.data.skip_empty,
        early_termination: cli.data.early_termination,
        shading: None,
    };
    let marcher = Marcher::with_options(ds.volume.clone(), &ds.tf, opts);
    let marcher = marcher.with_visual(&ds.tf, &visual).map_err(|e| e.to_string())?;
    // The transfer function shown (a preset, windowed, opacity-scaled): the levels' too.
    let tf = visual.transfer_function(&ds.tf, ds.volume.value_range()).map_err(|e| e.to_string())?;
    match cli.cmd.unwrap_or(Cmd::Serve) {
        Cmd::Serve => {
            let n = &cli.net;
            let config = server_config(&cli.net, cli.data.layers)?;
            let server = Server::with_transfer_function(config, marcher, &tf)
                .map_err(|e| e.to_string())?
                .with_visual(ds.tf.clone(), visual.clone());
            println!("listening on {}", server.local_addr());
            use std::io::Write;
            let _ = std::io::stdout().flush();
            if n.exit_on_stdin_eof {
                std::thread::spawn(|| {
                    let _ = std::io::copy(&mut std::io::stdin().lock(), &mut std::io::sink());
                    log::info!("standard input closed: the parent is gone, exiting");
                    std::process::exit(0);
                });
            }
            server.run();
            Ok(())
        }
        Cmd::Render { cam, out, level } => {
            let cam = camera(&ds, &cam)?;
            let levels;
            let marcher = if level > 0 {
                levels = marcher.levels(&tf).map_err(|e| e.to_string())?;
                let m = levels
                    .get(usize::from(level))
                    .ok_or_else(|| format!("--level {level}: the volume has {} levels", levels.len()))?;
                &**m
            } else {
                &marcher
            };
            let t = Instant::now();
            let img = marcher.render_image(&cam);
            log::info!("rendered {}x{} in {:.1} ms", cam.width, cam.height, t.elapsed().as_secs_f64() * 1e3);
            img.save_png(&out).map_err(|e| e.to_string())?;
            println!("wrote {}", out.display());
            Ok(())
        }
        Cmd::Dump { cam, out, encoding, frames } => {
            let cam = camera(&ds, &cam)?;
            let req = CameraRequest { seq: 0, camera: cam, heuristic, radius_scale: cli.data.radius_scale, layers: 0 };
            if !(req.radius_scale > 0.0 && req.radius_scale <= 16.0) {
                return Err("--radius-scale must be in (0, 16]".into());
            }
            let render = || {
                let (frame, stats) = marcher.render_frame_layers(&req, cli.data.layers.unwrap_or(1) as u32);
                log::info!(
                    "frame: {} samples, march {:.1} ms, compact {:.2} ms",
                    stats.samples,
                    stats.march_us as f64 / 1e3,
                    stats.compact_us as f64 / 1e3
                );
                (frame, stats)
            };
            let (mut frame, mut stats) = render();
            for _ in 1..frames {
                (frame, stats) = render();
            }
            let t = Instant::now();
            let (bytes, got) = volwarp_server::encoding::encode_frame(&marcher, &req, &frame, encoding);
            let encode_ms = t.elapsed().as_secs_f64() * 1e3;
            if got != encoding {
                log::warn!("the frame does not fit the compact form; wrote the 12-byte form");
            }
            write_dump(&out, &bytes, stats.samples, got, &format!(", encoded in {encode_ms:.1} ms"))
        }
        Cmd::Info { path } => info(&path, &cli.data),
        Cmd::Synth { out } => synth(&cli.data, &out),
    }
}

/// `mpiexec -n N volwarp-server serve|render|dump …`: the volume split across the ranks,
/// rank 0 the front end ([`volwarp_server::distributed`]).
#[cfg(feature = "mpi")]
fn run_mpi(cli: Cli) -> Result<(), String> {
    use volwarp_server::distributed::mpi::{run, Job, Launch};
    let volume = cli.data.volume.clone().ok_or("under mpiexec --volume names the file every rank reads")?;
    let heuristic = Heuristic::from_name(&cli.data.heuristic)
        .ok_or_else(|| format!("unknown heuristic {:?}", cli.data.heuristic))?;
    let launch = Launch {
        volume: PathBuf::from(volume),
        load: load_options(&cli.data)?,
        tf: cli.data.tf.clone(),
        opts: MarchOptions {
            step_voxels: cli.data.step,
            radius: cli.data.radius,
            uncertainty: volwarp_server::radius::UncertaintyParams::DEFAULT,
            kernel: if cli.data.kernel == "scalar" { MarchKernel::Scalar } else { MarchKernel::Packet },
            skip_empty: cli.data.skip_empty,
            early_termination: cli.data.early_termination,
            shading: None,
        },
        rank_timeout: secs(cli.data.rank_timeout, "rank-timeout")?,
    };
    let radius_scale = cli.data.radius_scale;
    let layers = cli.data.layers.unwrap_or(1) as u32;
    let job = match cli.cmd.as_ref().unwrap_or(&Cmd::Serve) {
        Cmd::Serve => {
            let config = server_config(&cli.net, cli.data.layers)?;
            Job::Serve(
                config,
                Box::new(|addr| {
                    use std::io::Write;
                    println!("listening on {addr}");
                    let _ = std::io::stdout().flush();
                }),
            )
        }
        Cmd::Render { cam, out, level } => {
            if *level > 0 {
                return Err("--level: levels of detail are not built across MPI ranks".into());
            }
            let (cam, out) = (clone_cam(cam), out.clone());
            Job::Render(
                Box::new(move |d| camera_from(d, &cam)),
                Box::new(move |img| {
                    img.save_png(&out).map_err(|e| e.to_string())?;
                    println!("wrote {}", out.display());
                    Ok(())
                }),
            )
        }
        Cmd::Dump { cam, out, encoding, frames } => {
            if !(radius_scale > 0.0 && radius_scale <= 16.0) {
                return Err("--radius-scale must be in (0, 16]".into());
            }
            let (cam, out) = (clone_cam(cam), out.clone());
            Job::Dump(
                Box::new(move |d| {
                    Ok(CameraRequest { seq: 0, camera: camera_from(d, &cam)?, heuristic, radius_scale, layers: 0 })
                }),
                layers,
                *frames,
                *encoding,
                Box::new(move |_, bytes, got, stats| write_dump(&out, &bytes, stats.samples, got, "")),
            )
        }
        Cmd::Info { .. } | Cmd::Synth { .. } => unreachable!("answered before any volume is loaded"),
    };
    run(launch, job)
}

#[cfg(feature = "mpi")]
fn clone_cam(c: &CameraArgs) -> CameraArgs {
    CameraArgs { orbit: c.orbit.clone(), zoom: c.zoom, fov: c.fov, size: c.size.clone() }
}

/// Writes a dumped frame's `bytes` to `out` and says what was written (`extra`: the end of
/// the line, e.g. the encode time).
fn write_dump(out: &Path, bytes: &[u8], samples: usize, got: Encoding, extra: &str) -> Result<(), String> {
    std::fs::write(out, bytes).map_err(|e| format!("{}: {e}", out.display()))?;
    println!(
        "wrote {} ({samples} samples, {} bytes, {:.3} bytes/sample, {}{extra})",
        out.display(),
        bytes.len(),
        bytes.len() as f64 / samples.max(1) as f64,
        got.name()
    );
    Ok(())
}

fn parse_encoding(s: &str) -> Result<Encoding, String> {
    Encoding::from_name(s).ok_or_else(|| format!("unknown encoding {s:?}; one of raw12, compact"))
}

fn main() -> ExitCode {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("info")).init();
    volwarp_server::limit_lanes_from_env();
    log::info!("packet marcher: {:?} lanes", volwarp_server::lane_kind());
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("volwarp-server: {e}");
            ExitCode::FAILURE
        }
    }
}
