//! Edit to first frame of the new visual state, over loopback against the real server (the
//! table in `docs/perf.md`, "Live visual edits"):
//!
//! ```sh
//! cargo run --release -p volwarp-server --example edit_latency -- [RUNS]   # default 15
//! ```
//!
//! For the MRI and the CT head at 512² and 1024², one client speaking the wire as the window
//! client does (compact layered frames, 4 segments per pixel, `CAP_VISUAL`), the camera still:
//! - **camera → frame**: a CameraRequest for a camera turned by 0.5° (so no frame is reused) to
//!   its Frame received whole: one server frame time plus one network transfer, the target;
//! - **edit → frame**: a VisualEdit alone (window/level, alternating between two values) to the
//!   first Frame of the new state received whole (the server re-renders the last camera);
//! - **rebuild**: what the server rebuilds for such an edit (the transfer-function tables and
//!   the empty-space occupancy, `Marcher::with_visual_tf`), timed in process; and for a crop
//!   edit (the occupancy only, `Marcher::with_visual_cut`).
//!
//! Medians of RUNS each.

use embedded_io_adapters::std::FromStd;
use std::net::TcpStream;
use std::time::{Duration, Instant};
use volwarp_core::wire::{self, CameraRequest, Hello, Limits, Message, VisualEdit};
use volwarp_core::Heuristic;
use volwarp_server::visual::VisualState;
use volwarp_server::{Dataset, Marcher, Server, ServerConfig};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

struct Client {
    s: TcpStream,
}

impl Client {
    fn send(&mut self, m: &Message) {
        wire::write_message(&mut FromStd::new(&mut self.s), m).unwrap();
    }
    fn recv(&mut self) -> Message {
        wire::read_message(&mut FromStd::new(&mut self.s), &Limits::for_frames(4096)).unwrap()
    }
    /// Reads until a Frame; returns its server time (µs).
    fn frame(&mut self) -> u32 {
        loop {
            match self.recv() {
                Message::Frame(f) => return f.header.render_us,
                Message::VisualState(_) => {}
                other => panic!("unexpected {other:?}"),
            }
        }
    }
}

fn main() {
    let runs: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(15);
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    println!(
        "| volume | viewport | server frame (march + encode), ms | camera → frame, ms | edit → frame, ms | \
         edit − camera, ms | rebuild: tables + occupancy, ms | rebuild: crop (occupancy), ms |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for (name, file) in
        [("MRI 181×217×181", "data/mri_colin27.nrrd"), ("CT head 64×64×93", "data/ct_head_quarter.nhdr")]
    {
        let ds = Dataset::load(root.join(file), None).unwrap();
        let marcher = Marcher::from_dataset(&ds);
        // The rebuilds, in process.
        let states = [
            VisualState { window: 0.8, level: 0.45, ..VisualState::default() },
            VisualState { window: 0.9, level: 0.5, ..VisualState::default() },
        ];
        let tables: Vec<f64> = (0..runs)
            .map(|i| {
                let t = Instant::now();
                let s = &states[i % 2];
                let tf = s.transfer_function(&ds.tf, ds.volume.value_range()).unwrap();
                std::hint::black_box(marcher.with_visual_tf(&tf, s));
                ms(t)
            })
            .collect();
        let crops: Vec<f64> = (0..runs)
            .map(|i| {
                let s =
                    VisualState { crop: [0.0, 0.3 + 0.01 * (i % 5) as f32, 0.0, 1.0, 1.0, 1.0], ..states[0].clone() };
                let t = Instant::now();
                std::hint::black_box(marcher.with_visual_cut(&s));
                ms(t)
            })
            .collect();
        let config = ServerConfig { listen: "127.0.0.1:0".parse().unwrap(), ..ServerConfig::default() };
        let server = Server::bind(config, ds.clone()).unwrap().spawn();
        for size in [512u32, 1024] {
            let s = TcpStream::connect(server.local_addr()).unwrap();
            s.set_nodelay(true).unwrap();
            s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
            let mut c = Client { s };
            let caps = wire::CAP_COMPACT | wire::CAP_COLOR_GREEN | wire::CAP_VISUAL;
            c.send(&Message::Hello(Hello::new(caps).with_layers(4)));
            assert!(matches!(c.recv(), Message::Hello(_)));
            assert!(matches!(c.recv(), Message::VisualState(_)));
            let base = marcher.default_camera(size, size);
            let req = |seq: u64, deg: f32| CameraRequest {
                seq,
                camera: base.orbit(deg, 0.0),
                heuristic: Heuristic::Threshold,
                radius_scale: 1.0,
                layers: 0,
            };
            let mut seq = 0;
            let (mut server_us, mut camera, mut edit) = (Vec::new(), Vec::new(), Vec::new());
            // Warm up.
            for _ in 0..3 {
                seq += 1;
                c.send(&Message::CameraRequest(req(seq, seq as f32 * 0.5)));
                c.frame();
            }
            for i in 0..runs {
                seq += 1;
                let t = Instant::now();
                c.send(&Message::CameraRequest(req(seq, seq as f32 * 0.5)));
                server_us.push(c.frame() as f64 / 1e3);
                camera.push(ms(t));
                let s = &states[i % 2];
                let e =
                    VisualEdit { id: i as u32 + 1, window_level: Some([s.window, s.level]), ..VisualEdit::default() };
                let t = Instant::now();
                c.send(&Message::VisualEdit(e));
                loop {
                    match c.recv() {
                        Message::VisualState(v) => assert_eq!(v.id, i as u32 + 1),
                        Message::Frame(_) => break,
                        other => panic!("unexpected {other:?}"),
                    }
                }
                edit.push(ms(t));
            }
            c.send(&Message::Bye);
            let (cam, ed) = (median(camera), median(edit));
            println!(
                "| {name} | {size}² | {:.1} | {cam:.1} | {ed:.1} | {:+.1} | {:.2} | {:.2} |",
                median(server_us),
                ed - cam,
                median(tables.clone()),
                median(crops.clone()),
            );
        }
        server.shutdown();
    }
}
