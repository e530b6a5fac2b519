//! Connecting to a server: address resolution, TCP with timeouts, the TLS handshake where asked
//! (`--tls`), the Hello exchange and a 1×1 probe frame whose header tells the client the
//! volume's bounds (so it can frame the volume before it has seen anything).

use crate::error::ClientError;
use std::io::{self, Read, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::sync::Arc;
use std::time::{Duration, Instant};
use volwarp_core::sample::Bounds;
use volwarp_core::wire::{self, error_code, CameraRequest, Hello, Limits, Message, WireError, HEADER_LEN};
use volwarp_core::{Camera, Heuristic, Vec3};
use volwarp_tls::rustls::ClientConfig;
use volwarp_tls::{TlsError, TlsLink, TlsReader, TlsWriter};

/// A connection's TLS state: the rustls connection shared by the reader and writer halves,
/// and the reading half (it may hold ciphertext already read).
pub struct TlsSession {
    /// The shared TLS state.
    pub link: TlsLink,
    /// The reading half over the socket.
    pub reader: TlsReader<TcpStream>,
}

impl std::fmt::Debug for TlsSession {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("TlsSession")
    }
}

/// An open, greeted connection.
#[derive(Debug)]
pub struct Connection {
    /// The socket (with TLS: carrying its records; read and write through [`Connection::tls`]).
    pub stream: TcpStream,
    /// The TLS session, where the connection has one.
    pub tls: Option<TlsSession>,
    /// The server's address.
    pub addr: SocketAddr,
    /// The server's Hello.
    pub hello: Hello,
    /// The volume's bounds, from the probe frame.
    pub bounds: Bounds,
    /// What this client accepts from the server.
    pub limits: Limits,
    /// The server's visual state and presets, where it applies live edits (`CAP_VISUAL`).
    pub visual: Option<wire::VisualState>,
}

impl Connection {
    /// Sends Bye (through TLS where the connection has it; best effort).
    pub fn bye(&mut self) {
        match &self.tls {
            Some(t) => {
                let Ok(raw) = self.stream.try_clone() else { return };
                let mut w = t.link.writer(raw);
                send_bye(&mut w);
                w.close();
            }
            None => send_bye(&mut self.stream),
        }
    }
}

/// Resolves `addr` (`host:port`) to its first socket address.
pub fn resolve(addr: &str) -> Result<SocketAddr, ClientError> {
    let mut it = addr.to_socket_addrs().map_err(|e| ClientError::BadAddress(format!("`{addr}`: {e}")))?;
    it.next().ok_or_else(|| ClientError::BadAddress(format!("`{addr}` resolves to no address")))
}

fn io_err(what: &str, e: &io::Error) -> ClientError {
    match e.kind() {
        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut => {
            ClientError::Gone(format!("no answer from the server while {what} (timed out)"))
        }
        io::ErrorKind::UnexpectedEof => ClientError::Gone(format!("the server closed the connection while {what}")),
        _ => ClientError::Gone(format!("{what}: {e}")),
    }
}

/// Maps a decoding error to a client error.
pub fn wire_err(e: WireError) -> ClientError {
    match e {
        WireError::UnsupportedVersion(v) => ClientError::Version(format!(
            "the server speaks protocol version {v}, this client speaks {}",
            wire::VERSION
        )),
        WireError::Closed | WireError::UnexpectedEof => ClientError::Gone("the server closed the connection".into()),
        e => ClientError::Protocol(e.to_string()),
    }
}

/// A reader whose read timeouts read as [`io::ErrorKind::TimedOut`]: a socket's read timeout
/// is `WouldBlock` on Unix, which core's wire reads (through embedded-io, whose error kinds
/// have no `WouldBlock`) would see as `Other`.
struct Timeouts<'a, R: ?Sized>(&'a mut R);

impl<R: Read + ?Sized> Read for Timeouts<'_, R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.0.read(buf).map_err(|e| match e.kind() {
            io::ErrorKind::WouldBlock => io::Error::new(io::ErrorKind::TimedOut, e),
            _ => e,
        })
    }
}

/// Maps an error of reading a frame's part while `what` to a client error: the server falling
/// silent or closing inside a frame says so, as between messages.
fn part_err(what: &str, e: WireError) -> ClientError {
    match e {
        WireError::Io(k) if io::ErrorKind::from(k) == io::ErrorKind::TimedOut => {
            ClientError::Gone(format!("no answer from the server inside a frame while {what} (timed out)"))
        }
        WireError::Closed | WireError::UnexpectedEof => closed_inside_a_frame(what),
        e => wire_err(e),
    }
}

/// The server closed the connection between a frame's parts or inside one, while `what`.
fn closed_inside_a_frame(what: &str) -> ClientError {
    ClientError::Gone(format!("the server closed the connection inside a frame while {what}"))
}

/// Reads one whole message; returns its exact bytes (header included) and the decoded message.
/// A clean close before the first byte is [`ClientError::Gone`]; allocates only what `limits`
/// allows.
pub fn read_message_bytes(
    stream: &mut impl Read,
    limits: &Limits,
    what: &str,
) -> Result<(Vec<u8>, Message), ClientError> {
    read_message_bytes_marked(stream, limits, what, || ())
}

/// [`read_message_bytes`], calling `mark` once the first header has arrived and keeping what it
/// returns (e.g. a "decoding" guard) alive until the message is read and decoded. A frame sent
/// in parts (wire version 6) is reassembled (core's `wire::take_part`): its bytes are the whole
/// frame message's, as if it had come whole, and a frame the server dropped part-way is skipped.
pub fn read_message_bytes_marked<G>(
    stream: &mut impl Read,
    limits: &Limits,
    what: &str,
    mark: impl FnOnce() -> G,
) -> Result<(Vec<u8>, Message), ClientError> {
    let mut mark = Some(mark);
    let mut _guard = None;
    let mut parts = wire::Assembly::new();
    let (bytes, h) = loop {
        let mut head = [0u8; HEADER_LEN];
        let mut got = 0;
        while got < HEADER_LEN {
            match stream.read(&mut head[got..]) {
                Ok(0) if parts.is_empty() => {
                    return Err(ClientError::Gone(format!("the server closed the connection while {what}")))
                }
                Ok(0) => return Err(closed_inside_a_frame(what)),
                Ok(n) => got += n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(io_err(what, &e)),
            }
            if got >= 4 && head[..4] != wire::MAGIC {
                return Err(wire_err(WireError::BadMagic([head[0], head[1], head[2], head[3]])));
            }
        }
        let h = wire::parse_header(&head, limits).map_err(wire_err)?;
        if let Some(m) = mark.take() {
            _guard = Some(m());
        }
        let mut r = embedded_io_adapters::std::FromStd::new(Timeouts(&mut *stream));
        if let Some(whole) = wire::take_part(&mut r, &h, limits, &mut parts).map_err(|e| part_err(what, e))? {
            break whole;
        }
        if matches!(h.ty, wire::MsgType::FramePart | wire::MsgType::FrameDropped) {
            continue;
        }
        let mut bytes = Vec::new();
        bytes
            .try_reserve_exact(HEADER_LEN + h.len as usize)
            .map_err(|_| ClientError::Protocol("out of memory".into()))?;
        bytes.extend_from_slice(&head);
        bytes.resize(HEADER_LEN + h.len as usize, 0);
        stream.read_exact(&mut bytes[HEADER_LEN..]).map_err(|e| io_err(what, &e))?;
        break (bytes, h);
    };
    let msg = if h.ty == wire::MsgType::LayeredCompactFrame {
        Message::Frame(decode_layered_parallel(&bytes[HEADER_LEN..], limits).map_err(wire_err)?)
    } else {
        wire::decode_message(&bytes, &h, limits).map_err(wire_err)?
    };
    Ok((bytes, msg))
}

/// A LayeredCompactFrame payload decoded as core's `segments::decode_layered_payload` does
/// (the same frame, the same checks), with its layers — independent CompactFrames — decoded on
/// up to as many threads as there are cores (layer `i` on thread `i mod threads`); core merges
/// them. A layer whose thread failed is an `Inconsistent` frame.
pub fn decode_layered_parallel(payload: &[u8], limits: &Limits) -> Result<wire::Frame, WireError> {
    use volwarp_core::segments::{decode_layered_part, decode_layered_payload_with, LayerError, LayerPart};
    decode_layered_payload_with(payload, limits, |parts| {
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).clamp(1, parts.len().max(1));
        let decode_every = |first: usize| -> Vec<(usize, Result<LayerPart, WireError>)> {
            (first..parts.len()).step_by(threads).map(|i| (i, decode_layered_part(parts[i], limits))).collect()
        };
        let mut out: Vec<Option<Result<LayerPart, WireError>>> = (0..parts.len()).map(|_| None).collect();
        std::thread::scope(|s| {
            let others: Vec<_> = (1..threads).map(|t| s.spawn(move || decode_every(t))).collect();
            let mine = decode_every(0);
            for (i, r) in mine.into_iter().chain(others.into_iter().filter_map(|h| h.join().ok()).flatten()) {
                out[i] = Some(r);
            }
        });
        out.into_iter().map(|r| r.unwrap_or(Err(WireError::Layers(LayerError::Inconsistent)))).collect()
    })
}

/// Encodes and sends a CameraRequest.
pub fn send_request(stream: &mut impl Write, req: &CameraRequest) -> io::Result<()> {
    let mut buf = Vec::with_capacity(HEADER_LEN + wire::CAMERA_REQUEST_LEN);
    let _ = wire::write_camera_request(&mut wire::VecWriter(&mut buf), req);
    stream.write_all(&buf)
}

/// Sends a visual edit.
pub fn send_edit(stream: &mut impl Write, e: &wire::VisualEdit) -> io::Result<()> {
    let mut buf = Vec::with_capacity(HEADER_LEN + e.encoded_len());
    let _ = wire::write_visual_edit(&mut wire::VecWriter(&mut buf), e);
    stream.write_all(&buf)
}

/// Sends Bye (best effort).
pub fn send_bye(stream: &mut impl Write) {
    let mut buf = Vec::new();
    let _ = wire::write_bye(&mut wire::VecWriter(&mut buf));
    let _ = stream.write_all(&buf);
}

/// The error a server's Error message means.
pub fn server_error(e: &wire::ErrorMsg) -> ClientError {
    if e.code == error_code::UNSUPPORTED_VERSION {
        ClientError::Version(format!("the server refused this client: {}", e.text))
    } else {
        ClientError::Server { code: e.code, text: e.text.to_string() }
    }
}

/// The probe camera: any valid 1×1 camera (the frame's header carries the volume bounds).
fn probe_camera() -> Camera {
    Camera::look_at(Vec3::new(0.0, 0.0, 1.0), Vec3::ZERO, Vec3::Y, 30.0, 1, 1)
}

/// Connects to `addr`, exchanges Hello and asks for the probe frame; `timeout` bounds each
/// step.
pub fn connect(addr: &str, token: Option<&str>, timeout: Duration) -> Result<Connection, ClientError> {
    connect_layers(addr, token, timeout, 1)
}

/// [`connect`] asking for layered frames of at most `layers` segments per pixel (1:
/// one sample per pixel). The server answers with the count it will render (at most this),
/// and the connection's limits refuse frames with more.
pub fn connect_layers(
    addr: &str,
    token: Option<&str>,
    timeout: Duration,
    layers: u8,
) -> Result<Connection, ClientError> {
    connect_secure(addr, token, timeout, layers, None)
}

/// Reads and writes a connection during the greeting: the socket, or TLS over it.
enum Greeting {
    Plain(TcpStream),
    Tls(TlsReader<TcpStream>, TlsWriter<TcpStream>),
}

impl Read for Greeting {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self {
            Greeting::Plain(s) => s.read(buf),
            Greeting::Tls(r, _) => r.read(buf),
        }
    }
}

impl Write for Greeting {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        match self {
            Greeting::Plain(s) => s.write(buf),
            Greeting::Tls(_, w) => w.write(buf),
        }
    }

    fn flush(&mut self) -> io::Result<()> {
        match self {
            Greeting::Plain(s) => s.flush(),
            Greeting::Tls(_, w) => w.flush(),
        }
    }
}

/// The client error of a failed TLS handshake with `addr`. Certificate refusals and a peer
/// that is no TLS server are permanent ([`ClientError::Tls`]); a plain Error message the
/// server sent before any handshake (busy, rate-limited) is that error.
fn tls_err(addr: &str, e: TlsError) -> ClientError {
    match e {
        // A self-signed certificate made without `basicConstraints CA:FALSE` is a CA
        // certificate, which webpki refuses as a server's (docs/security.md has the command).
        TlsError::Certificate(c) if format!("{c:?}").contains("CaUsedAsEndEntity") => ClientError::Tls(format!(
            "the certificate of {addr} is refused ({c:?}): it is a CA certificate, not a server's; make the \
             server's certificate with basicConstraints CA:FALSE (docs/security.md) and pin it with --ca"
        )),
        TlsError::Certificate(c) => ClientError::Tls(format!(
            "the certificate of {addr} is refused ({c:?}); pass --ca FILE with the CA that issued it, or the \
             server's own certificate to pin it"
        )),
        TlsError::NotTls(sent) => match wire::read_message(&mut &sent[..], &Limits::default()) {
            Ok(Message::Error(e)) => server_error(&e),
            _ => ClientError::Tls(format!("{addr} does not speak TLS (a plain server? connect without --tls)")),
        },
        TlsError::Io(e) => io_err("in the TLS handshake", &e),
        TlsError::Closed => ClientError::Gone(format!("{addr} closed the connection during the TLS handshake")),
        TlsError::Tls(e) => ClientError::Tls(format!("{addr}: {e}")),
    }
}

/// [`connect_layers`] over TLS with `tls` (certificates verified for the host of `addr`), or
/// plain TCP with `None`.
pub fn connect_secure(
    addr: &str,
    token: Option<&str>,
    timeout: Duration,
    layers: u8,
    tls: Option<&Arc<ClientConfig>>,
) -> Result<Connection, ClientError> {
    let sock = resolve(addr)?;
    let timeout = timeout.max(Duration::from_millis(10));
    let stream = TcpStream::connect_timeout(&sock, timeout)
        .map_err(|e| ClientError::Connect(format!("{addr} ({sock}): {e}")))?;
    let _ = stream.set_nodelay(true);
    stream.set_read_timeout(Some(timeout)).map_err(|e| ClientError::Connect(e.to_string()))?;
    stream.set_write_timeout(Some(timeout)).map_err(|e| ClientError::Connect(e.to_string()))?;
    let clone = || stream.try_clone().map_err(|e| ClientError::Connect(format!("cannot share the socket: {e}")));
    let mut link = None;
    let mut io = match tls {
        Some(cfg) => {
            let name = volwarp_tls::server_name(addr).map_err(ClientError::Tls)?;
            let l = TlsLink::connect(cfg.clone(), name, &stream, Some(Instant::now() + timeout))
                .map_err(|e| tls_err(addr, e))?;
            // The handshake's deadline set a shorter read timeout: back to the full one.
            stream.set_read_timeout(Some(timeout)).map_err(|e| ClientError::Connect(e.to_string()))?;
            log::info!("TLS with {addr}: {}", l.describe());
            let halves = Greeting::Tls(l.reader(clone()?), l.writer(clone()?));
            link = Some(l);
            halves
        }
        None => Greeting::Plain(clone()?),
    };
    let mut limits = Limits::default().with_layers(layers);

    // Ask for CompactFrames (about 3 bytes per sample instead of 12; the server decides).
    let mut hello = Hello::new(
        wire::CAP_COMPACT
            | wire::CAP_COLOR_GREEN
            | wire::CAP_VISUAL
            | wire::CAP_PARTS
            | if cfg!(feature = "gpu") { wire::CAP_GPU } else { 0 },
    )
    .with_layers(layers);
    if let Some(t) = token {
        hello =
            hello.with_token(t.as_bytes()).map_err(|_| ClientError::Usage("--token is longer than 64 bytes".into()))?;
    }
    let mut buf = Vec::new();
    let _ = wire::write_hello(&mut wire::VecWriter(&mut buf), &hello);
    io.write_all(&buf).map_err(|e| io_err("sending Hello", &e))?;
    let server_hello = match read_message_bytes(&mut io, &limits, "waiting for the server's Hello")?.1 {
        Message::Hello(h) => h,
        Message::Error(e) => return Err(server_error(&e)),
        _ => return Err(ClientError::Protocol("the server did not answer Hello".into())),
    };
    if server_hello.version != wire::VERSION {
        return Err(ClientError::Version(format!(
            "the server speaks protocol version {}, this client speaks {}",
            server_hello.version,
            wire::VERSION
        )));
    }

    // The negotiated maximum: a frame with more segments per pixel is a typed error.
    limits = limits.with_layers(server_hello.layers.min(limits.max_layers));
    let probe =
        CameraRequest { seq: 0, camera: probe_camera(), heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
    send_request(&mut io, &probe).map_err(|e| io_err("sending the probe request", &e))?;
    // A server that applies live edits sends its visual state first.
    let mut visual = None;
    let bounds = loop {
        match read_message_bytes(&mut io, &limits, "waiting for the probe frame")?.1 {
            Message::Frame(f) => break f.header.bounds,
            Message::VisualState(v) if server_hello.capabilities & wire::CAP_VISUAL != 0 && visual.is_none() => {
                visual = Some(v)
            }
            Message::Error(e) => return Err(server_error(&e)),
            Message::Bye => return Err(ClientError::Gone("the server said goodbye".into())),
            _ => return Err(ClientError::Protocol("the server did not answer the probe with a Frame".into())),
        }
    };
    log::info!("connected to {sock}; volume bounds {:?} .. {:?}", bounds.min(), bounds.max());
    let tls = match (io, link) {
        (Greeting::Tls(reader, _), Some(link)) => Some(TlsSession { link, reader }),
        _ => None,
    };
    Ok(Connection { stream, tls, addr: sock, hello: server_hello, bounds, limits, visual })
}

#[cfg(test)]
mod tests {
    use super::*;
    use volwarp_core::compact_frame::{encode_frame, EncodeOptions, Encoding};
    use volwarp_core::sample::{pack_color, Quantizer};
    use volwarp_core::wire::{Frame, FrameHeader};

    /// A `w × w` layered frame, 0–4 segments per pixel on the pixel's ray.
    fn layered(w: u32) -> Frame {
        let camera = Camera::look_at(Vec3::new(0.5, 0.5, 3.0), Vec3::splat(0.5), Vec3::Y, 30.0, w, w);
        let bounds = Bounds::new(Vec3::new(-1.0, -1.0, -1.0), Vec3::new(2.0, 2.0, 2.0));
        let q = Quantizer::new(bounds, 0.001);
        let basis = camera.ray_basis();
        let (mut samples, mut colors, mut segments) = (Vec::new(), Vec::new(), Vec::new());
        for y in 0..w {
            for x in 0..w {
                let d = basis.dir(x, y);
                for j in 0..((x * 7 + y * 3) % 5) as u8 {
                    samples.push(q.pack(camera.eye + d * (2.0 + 0.3 * j as f32 + 0.01 * (x % 16) as f32), 0.004));
                    let a = 40 + 50 * j + (x % 16) as u8;
                    colors.push(pack_color(a / 2, a / 3, a, a));
                    segments.push(j);
                }
            }
        }
        let header = FrameHeader {
            seq: 1,
            camera,
            heuristic: Heuristic::Threshold,
            bounds,
            radius_unit: 0.001,
            render_us: 5,
            level: 0,
            count: samples.len() as u32,
        };
        Frame { header, samples, colors, segments }
    }

    /// A stream that gives `data`, then fails with `then` (`None`: ends).
    struct Stalls {
        data: Vec<u8>,
        at: usize,
        then: Option<io::ErrorKind>,
    }

    impl Read for Stalls {
        fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
            if self.at < self.data.len() {
                let n = buf.len().min(self.data.len() - self.at);
                buf[..n].copy_from_slice(&self.data[self.at..self.at + n]);
                self.at += n;
                return Ok(n);
            }
            match self.then {
                Some(k) => Err(io::Error::new(k, "stalled")),
                None => Ok(0),
            }
        }
    }

    #[test]
    fn a_stall_or_close_inside_a_frame_s_part_says_so() {
        // A FramePart's header announcing 1000 bytes, and 10 of them.
        let mut data = vec![0u8; HEADER_LEN];
        data[..4].copy_from_slice(&wire::MAGIC);
        data[4..6].copy_from_slice(&wire::VERSION.to_le_bytes());
        data[6] = wire::MsgType::FramePart as u8;
        data[8..12].copy_from_slice(&1000u32.to_le_bytes());
        data.extend_from_slice(&[0u8; 10]);
        let limits = Limits::default();
        // A socket's read timeout (`WouldBlock` on Unix, `TimedOut` elsewhere) is a timeout.
        for k in [io::ErrorKind::WouldBlock, io::ErrorKind::TimedOut] {
            let mut s = Stalls { data: data.clone(), at: 0, then: Some(k) };
            match read_message_bytes(&mut s, &limits, "waiting for a frame") {
                Err(ClientError::Gone(m)) => {
                    assert!(m.contains("timed out") && m.contains("inside a frame"), "{k:?}: {m}")
                }
                other => panic!("{k:?}: {other:?}"),
            }
        }
        let mut s = Stalls { data, at: 0, then: None };
        match read_message_bytes(&mut s, &limits, "waiting for a frame") {
            Err(ClientError::Gone(m)) => assert!(m.contains("closed the connection inside a frame"), "{m}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn layered_frames_decode_on_threads_as_in_one() {
        let (bytes, ty) = encode_frame(&layered(48), Encoding::Compact, &EncodeOptions::default());
        assert_eq!(ty, Encoding::Compact);
        assert_eq!(bytes[6], wire::MsgType::LayeredCompactFrame as u8);
        let limits = Limits::default();
        let serial = wire::read_message(&mut &bytes[..], &limits).unwrap();
        let (got_bytes, parallel) = read_message_bytes(&mut &bytes[..], &limits, "test").unwrap();
        assert_eq!(got_bytes, bytes);
        assert!(parallel == serial, "the threads' frame differs from core's");
        // Damaged messages: the same verdict as core's decoder, and no panic.
        for i in (12..bytes.len()).step_by(5) {
            let mut c = bytes.clone();
            c[i] ^= 0x3c;
            let want = wire::read_message(&mut &c[..], &limits);
            let got = decode_layered_parallel(&c[HEADER_LEN..], &limits);
            assert_eq!(want.is_ok(), got.is_ok(), "byte {i}");
        }
    }
}
