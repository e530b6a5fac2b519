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
