//! Helpers shared by the integration tests.
#![allow(dead_code)]

use embedded_io_adapters::std::FromStd;
use std::net::{SocketAddr, TcpStream};
use std::path::PathBuf;
use std::time::Duration;
use volwarp_core::wire::{self, Hello, Limits, Message, WireError};

/// A fresh temporary folder for one test.
pub fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("volwarp-server-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A test client speaking the wire protocol.
pub struct Client {
    pub stream: TcpStream,
}

impl Client {
    pub fn connect(addr: SocketAddr) -> Client {
        let stream = TcpStream::connect(addr).unwrap();
        stream.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
        Client { stream }
    }

    pub fn send(&mut self, m: &Message) {
        wire::write_message(&mut FromStd::new(&mut self.stream), m).unwrap();
    }

    pub fn send_raw(&mut self, bytes: &[u8]) {
        use std::io::Write;
        let _ = self.stream.write_all(bytes);
    }

    pub fn recv(&mut self) -> Result<Message, WireError> {
        wire::read_message(&mut FromStd::new(&mut self.stream), &Limits::for_frames(4096))
    }

    /// Connects and completes the Hello exchange.
    pub fn hello(addr: SocketAddr, token: Option<&[u8]>) -> Client {
        let mut c = Client::connect(addr);
        let mut h = Hello::new(0);
        if let Some(t) = token {
            h = h.with_token(t).unwrap();
        }
        c.send(&Message::Hello(h));
        match c.recv() {
            Ok(Message::Hello(h)) => assert_eq!(h.version, wire::VERSION),
            other => panic!("expected Hello, got {other:?}"),
        }
        c
    }
}

/// Tests that depend on the lane kind hold this while they run (the limit is process-wide, so a
/// test that limits the lanes would change the kind another test runs on).
static LANES: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Runs `f` with each lane kind this CPU has (widest first), holding the lane lock, then lifts
/// the limit; prints the kinds this CPU lacks. The portable kind runs everywhere.
pub fn for_each_lane_kind(mut f: impl FnMut(volwarp_server::LaneKind)) {
    use volwarp_server::{lane_kind, limit_lanes, LaneKind};
    let _guard = LANES.lock().unwrap_or_else(|e| e.into_inner());
    let mut ran = Vec::new();
    for kind in [LaneKind::Avx512, LaneKind::Avx2, LaneKind::Portable] {
        limit_lanes(kind);
        if lane_kind() != kind {
            eprintln!("this CPU lacks {kind:?} lanes: not tested here");
            continue;
        }
        f(kind);
        ran.push(kind);
    }
    limit_lanes(LaneKind::Avx512);
    assert!(ran.contains(&LaneKind::Portable), "the portable lanes did not run: {ran:?}");
}

/// Holds the lane lock with the lanes at the widest kind this CPU has, for a test that needs
/// one known kind (the guard keeps other tests from limiting the lanes meanwhile).
pub fn widest_lanes() -> std::sync::MutexGuard<'static, ()> {
    let guard = LANES.lock().unwrap_or_else(|e| e.into_inner());
    volwarp_server::limit_lanes(volwarp_server::LaneKind::Avx512);
    guard
}

/// Every dataset the marcher tests run on: the bundled ones (`data/`), the shared ones (see
/// `volwarp_server::testdata`: missing ones fail unless `VOLWARP_NO_SHARED_DATA=1`) and a
/// procedural one.
pub fn datasets() -> Vec<volwarp_server::Dataset> {
    use volwarp_server::Dataset;
    let data = |name: &str| std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(name);
    let mut out = vec![
        Dataset::load(data("data/ct_head_quarter.nhdr"), None).unwrap(),
        Dataset::load(data("data/neghip_64x64x64_uint8.raw"), None).unwrap(),
        Dataset::marschner_lobb(41),
    ];
    for f in [
        "iron_protein_68x68x68_uint8.raw",
        "tooth_103x94x161_uint8.raw",
        "mri_colin27_181x217x181_uint8.raw",
        "ct_head_quarter_64x64x93_int16.raw",
    ] {
        out.extend(volwarp_server::testdata::shared_dataset(f));
    }
    out
}
