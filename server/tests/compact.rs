//! The compact encoding over loopback: a client that sets `CAP_COMPACT` gets
//! CompactFrames that decode to the 12-byte frame's colors and radius codes exactly and its
//! positions within the stated bound; a client that does not, or a server started with
//! `compact: false`, gets 12-byte Frames.

mod common;

use common::Client;
use std::io::Read;
use std::net::SocketAddr;
use std::sync::Arc;
use volwarp_core::compact_frame::{position_bound, read_params};
use volwarp_core::sample::{radius_code, Dequantizer};
use volwarp_core::wire::{self, CameraRequest, Hello, Limits, Message, MsgType, HEADER_LEN};
use volwarp_core::Heuristic;
use volwarp_server::{Dataset, Marcher, Server, ServerConfig, ServerHandle};

fn start(compact: bool) -> (ServerHandle, Arc<Marcher>) {
    let cfg =
        ServerConfig { listen: SocketAddr::from(([127, 0, 0, 1], 0)), threads: 2, compact, ..ServerConfig::default() };
    let marcher = Arc::new(Marcher::from_dataset(&Dataset::default_bundled()));
    let server = Server::with_marcher(cfg, marcher.clone()).unwrap();
    (server.spawn(), marcher)
}

/// Hello with `caps`; returns the client and the server's capabilities.
fn hello(addr: SocketAddr, caps: u32) -> (Client, u32) {
    let mut c = Client::connect(addr);
    c.send(&Message::Hello(Hello::new(caps)));
    match c.recv() {
        Ok(Message::Hello(h)) => (c, h.capabilities),
        other => panic!("expected Hello, got {other:?}"),
    }
}

/// The next message's raw bytes (header and payload).
fn recv_bytes(c: &mut Client) -> Vec<u8> {
    let mut h = [0u8; HEADER_LEN];
    c.stream.read_exact(&mut h).unwrap();
    let len = u32::from_le_bytes([h[8], h[9], h[10], h[11]]) as usize;
    let mut b = h.to_vec();
    b.resize(HEADER_LEN + len, 0);
    c.stream.read_exact(&mut b[HEADER_LEN..]).unwrap();
    b
}

#[test]
fn a_client_that_asks_gets_compact_frames_equal_to_the_12_byte_form() {
    let (server, m) = start(true);
    let (mut c, caps) = hello(server.local_addr(), wire::CAP_COMPACT);
    assert_ne!(caps & wire::CAP_COMPACT, 0, "the server agrees to send compact frames");
    let req = CameraRequest {
        seq: 3,
        camera: m.default_camera(192, 160).orbit(25.0, 10.0),
        heuristic: Heuristic::RelThreshold,
        radius_scale: 1.0,
        layers: 0,
    };
    c.send(&Message::CameraRequest(req));
    let bytes = recv_bytes(&mut c);
    assert_eq!(bytes[6], MsgType::CompactFrame as u8);
    let got = match wire::read_message(&mut &bytes[..], &Limits::default()).unwrap() {
        Message::Frame(f) => f,
        other => panic!("{other:?}"),
    };
    let (want, _) = m.render_frame(&req);
    assert!(want.samples.len() > 1000);
    assert!(bytes.len() * 3 < HEADER_LEN + 96 + 12 * want.samples.len(), "compact is under a third of 12 B/sample");
    let (_, params) = read_params(&bytes[HEADER_LEN..], &Limits::default()).unwrap();
    assert_eq!(got.header.seq, 3);
    assert_eq!(got.header.camera, want.header.camera);
    assert!(got.colors == want.colors);
    assert!(got.samples.iter().map(|&s| radius_code(s)).eq(want.samples.iter().map(|&s| radius_code(s))));
    let deq = Dequantizer::new(want.header.bounds, want.header.radius_unit);
    let bound = position_bound(&want.header, &params);
    for (&a, &b) in got.samples.iter().zip(&want.samples) {
        assert!((deq.center(a) - deq.center(b)).length() <= bound);
    }
    // With the server's exact radius model every radius residual is 0 or ±1 code.
    server.shutdown();
}

#[test]
fn clients_that_do_not_ask_and_servers_that_refuse_send_12_byte_frames() {
    for (compact_server, client_caps) in [(true, 0), (false, wire::CAP_COMPACT)] {
        let (server, m) = start(compact_server);
        let (mut c, caps) = hello(server.local_addr(), client_caps);
        assert_eq!(caps & wire::CAP_COMPACT, 0);
        let req = CameraRequest {
            seq: 1,
            camera: m.default_camera(32, 32),
            heuristic: Heuristic::Threshold,
            radius_scale: 1.0,
            layers: 0,
        };
        c.send(&Message::CameraRequest(req));
        let bytes = recv_bytes(&mut c);
        assert_eq!(bytes[6], MsgType::Frame as u8);
        server.shutdown();
    }
}

/// The color coding of each part of a LayeredCompactFrame message (byte 113 of each part).
fn part_color_codes(bytes: &[u8]) -> Vec<u8> {
    assert_eq!(bytes[6], MsgType::LayeredCompactFrame as u8);
    let mut at = HEADER_LEN + 96;
    let mut codes = Vec::new();
    while at < bytes.len() {
        let len = u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
        codes.push(bytes[at + 4 + 113]);
        at += 4 + len;
    }
    codes
}

#[test]
fn colors_are_coded_against_green_only_for_clients_that_read_it() {
    let (server, m) = start(true);
    let req = CameraRequest {
        seq: 2,
        camera: m.default_camera(160, 128).orbit(20.0, 10.0),
        heuristic: Heuristic::Threshold,
        radius_scale: 1.0,
        layers: 0,
    };
    let mut frames = Vec::new();
    for caps in [wire::CAP_COMPACT | wire::CAP_COLOR_GREEN, wire::CAP_COMPACT] {
        let mut c = Client::connect(server.local_addr());
        c.send(&Message::Hello(Hello::new(caps).with_layers(4)));
        let answer = match c.recv() {
            Ok(Message::Hello(h)) => h,
            other => panic!("expected Hello, got {other:?}"),
        };
        assert_eq!(answer.capabilities & wire::CAP_COLOR_GREEN, caps & wire::CAP_COLOR_GREEN);
        c.send(&Message::CameraRequest(req));
        let bytes = recv_bytes(&mut c);
        let codes = part_color_codes(&bytes);
        assert_eq!(codes.len(), 4, "four layers");
        if caps & wire::CAP_COLOR_GREEN != 0 {
            assert!(codes.iter().all(|&k| k <= 1));
            assert!(codes.contains(&1), "the CT head's layers are cheaper against green: {codes:?}");
        } else {
            assert!(codes.iter().all(|&k| k == 0), "a client that did not ask gets plain colors: {codes:?}");
        }
        match wire::read_message(&mut &bytes[..], &Limits::default()).unwrap() {
            Message::Frame(f) => frames.push((f, bytes.len())),
            other => panic!("{other:?}"),
        }
    }
    // The same frame either way (colors are lossless), in fewer bytes against green.
    assert!(frames[0].0 == frames[1].0, "the two codings decode to different frames");
    assert!(frames[0].1 < frames[1].1, "{} bytes against green, {} plain", frames[0].1, frames[1].1);
    server.shutdown();
}
