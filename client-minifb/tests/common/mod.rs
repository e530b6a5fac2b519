//! Helpers shared by the client's integration tests: running the real binary with a time
//! limit, reading PNG frames, a scripted fake server.
#![allow(dead_code)]

use std::io::Read;
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};
use volwarp_core::wire::{self, Message, VecWriter};

/// The client binary built by cargo for these tests.
pub fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_volwarp-client")
}

/// The `volwarp-server` program the client starts when no `--connect` is given, beside the
/// client binary; built here (same profile and target dir) if this test run did not build it.
pub fn server_program() -> PathBuf {
    static PROGRAM: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    PROGRAM
        .get_or_init(|| {
            let client = Path::new(bin());
            let dir = client.parent().expect("the client binary is in a folder");
            let program = dir.join(format!("volwarp-server{}", std::env::consts::EXE_SUFFIX));
            if !program.is_file() {
                let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
                let mut cmd = Command::new(cargo);
                cmd.args(["build", "--quiet", "-p", "volwarp-server", "--bin", "volwarp-server"]);
                if dir.ends_with("release") {
                    cmd.arg("--release");
                }
                let ok = cmd.status().map(|s| s.success()).unwrap_or(false);
                assert!(ok && program.is_file(), "could not build {}", program.display());
            }
            program
        })
        .clone()
}

/// A fresh scratch folder under the target dir.
pub fn scratch(name: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("client-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Runs the client with `args`, killing it after `limit`; returns its output.
pub fn run(args: &[&str], limit: Duration) -> Output {
    let mut child = Command::new(bin())
        .args(args)
        .env("RUST_LOG", "info")
        .env("VOLWARP_SERVER", server_program())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("starting volwarp-client");
    let t0 = Instant::now();
    loop {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        if t0.elapsed() > limit {
            let _ = child.kill();
            let out = child.wait_with_output().unwrap();
            panic!(
                "volwarp-client {args:?} did not finish within {limit:?}\nstderr:\n{}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

/// The error line the client printed.
pub fn error_line(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr)
        .lines()
        .find(|l| l.starts_with("volwarp-client: error:"))
        .unwrap_or("")
        .to_string()
}

/// Decodes a PNG into RGBA8 pixels and its size.
pub fn load_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let img = image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())).to_rgba8();
    (img.width(), img.height(), img.into_raw())
}

/// Sorted PNG files in a folder.
pub fn pngs(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect();
    v.sort();
    v
}

/// Bytes of a message.
pub fn encode(m: &Message) -> Vec<u8> {
    let mut v = Vec::new();
    wire::write_message(&mut VecWriter(&mut v), m).unwrap();
    v
}

/// Reads one whole message from a socket (test side; small messages only).
pub fn read_msg(s: &mut TcpStream) -> Option<Message> {
    let mut head = [0u8; wire::HEADER_LEN];
    s.read_exact(&mut head).ok()?;
    let limits = wire::Limits::for_requests(4096);
    let h = wire::parse_header(&head, &limits).ok()?;
    let mut body = vec![0u8; h.len as usize];
    s.read_exact(&mut body).ok()?;
    wire::read_payload(&mut &body[..], &h, &limits).ok()
}

/// The server's side of a connection's start, as a fake server plays it: reads the client's
/// Hello, answers with `hello`, and answers the connection's probe request with an empty frame.
pub fn greet(s: &mut TcpStream, hello: volwarp_core::wire::Hello) {
    use std::io::Write;
    assert!(matches!(read_msg(s), Some(Message::Hello(_))));
    s.write_all(&encode(&Message::Hello(hello))).unwrap();
    assert!(matches!(read_msg(s), Some(Message::CameraRequest(_))));
    s.write_all(&encode(&empty_frame(0))).unwrap();
}

/// A one-connection fake server running `script` on the accepted socket; returns its address.
pub fn fake_server(script: impl FnOnce(TcpStream) + Send + 'static) -> String {
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = l.local_addr().unwrap().to_string();
    std::thread::spawn(move || {
        if let Ok((s, _)) = l.accept() {
            s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
            script(s);
        }
    });
    addr
}

/// A Frame with no samples for a 1×1 camera (what a fake server answers the client's probe with).
pub fn empty_frame(seq: u64) -> Message {
    use volwarp_core::sample::Bounds;
    use volwarp_core::wire::{Frame, FrameHeader};
    use volwarp_core::{Camera, Heuristic, Vec3};
    Message::Frame(Frame {
        header: FrameHeader {
            seq,
            camera: Camera::look_at(Vec3::new(0.0, 0.0, 1.0), Vec3::ZERO, Vec3::Y, 30.0, 1, 1),
            heuristic: Heuristic::Threshold,
            bounds: Bounds::new(Vec3::ZERO, Vec3::ONE),
            radius_unit: 0.01,
            render_us: 1,
            level: 0,
            count: 0,
        },
        samples: vec![],
        colors: vec![],
        segments: Vec::new(),
    })
}

/// The network settings of the tests: no added latency, one build thread, a 10 s timeout,
/// eager builds, no bandwidth limit, no extra requests.
pub fn net_config() -> volwarp_client::network::NetConfig {
    volwarp_client::network::NetConfig {
        latency: Duration::ZERO,
        build_threads: 1,
        timeout: Duration::from_secs(10),
        lazy_build: false,
        bandwidth_mbps: None,
        request: volwarp_core::method::RequestPolicy::NONE,
    }
}

/// Shows views (`view(home, i)`, as the display would) until a scene arrives that answers a
/// request sent after `after`, or `limit` passes; checks on the way that every scene is a
/// whole frame of the viewport with the volume in view, and that the network has not failed.
/// Returns when that scene arrived.
pub fn next_scene(
    net: &volwarp_client::network::Network,
    home: &volwarp_core::Camera,
    view: fn(&volwarp_core::Camera, u32) -> volwarp_client::network::View,
    after: Instant,
    limit: Duration,
) -> Option<Instant> {
    let t0 = Instant::now();
    let mut i = 0;
    while t0.elapsed() < limit {
        net.set_view(view(home, i));
        i += 1;
        if let Some(s) = net.take_scene() {
            let h = &s.scene.header;
            assert_eq!((h.camera.width, h.camera.height), (home.width, home.height), "a frame of the viewport");
            assert_eq!(s.scene.samples.len(), h.count as usize, "a torn frame: not every sample arrived");
            assert!(!s.scene.samples.is_empty(), "the volume is in view");
            let at = s.received_at;
            net.recycle(s.scene);
            if at > after {
                return Some(at);
            }
        }
        assert!(net.error().is_none(), "the network failed: {:?}", net.error());
        std::thread::sleep(Duration::from_millis(2));
    }
    None
}
