//! Connecting to a server: address resolution, TCP with timeouts, the Hello exchange and a 1×1
//! probe frame whose header tells the client the volume's bounds (so it can frame the volume
//! before it has seen anything).

use crate::error::ClientError;
use std::io::{self, Read, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::time::Duration;
use volwarp_core::sample::Bounds;
use volwarp_core::wire::{self, error_code, CameraRequest, Hello, Limits, Message, WireError, HEADER_LEN};
use volwarp_core::{Camera, Heuristic, Vec3};

/// An open, greeted connection.
#[derive(Debug)]
pub struct Connection {
    /// The socket.
    pub stream: TcpStream,
    /// The server's address.
    pub addr: SocketAddr,
    /// The server's Hello.
    pub hello: Hello,
    /// The volume's bounds, from the probe frame.
    pub bounds: Bounds,
    /// What this client accepts from the server.
    pub limits: Limits,
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

/// [`read_message_bytes`], calling `mark` once the header has arrived and keeping what it
/// returns (e.g. a "decoding" guard) alive until the payload is read and decoded.
pub fn read_message_bytes_marked<G>(
    stream: &mut impl Read,
    limits: &Limits,
    what: &str,
    mark: impl FnOnce() -> G,
) -> Result<(Vec<u8>, Message), ClientError> {
    let mut head = [0u8; HEADER_LEN];
    let mut got = 0;
    while got < HEADER_LEN {
        match stream.read(&mut head[got..]) {
            Ok(0) => return Err(ClientError::Gone(format!("the server closed the connection while {what}"))),
            Ok(n) => got += n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return Err(io_err(what, &e)),
        }
        if got >= 4 && head[..4] != wire::MAGIC {
            return Err(wire_err(WireError::BadMagic([head[0], head[1], head[2], head[3]])));
        }
    }
    let h = wire::parse_header(&head, limits).map_err(wire_err)?;
    let _guard = mark();
    let mut bytes = Vec::new();
    bytes.try_reserve_exact(HEADER_LEN + h.len as usize).map_err(|_| ClientError::Protocol("out of memory".into()))?;
    bytes.extend_from_slice(&head);
    bytes.resize(HEADER_LEN + h.len as usize, 0);
    stream.read_exact(&mut bytes[HEADER_LEN..]).map_err(|e| io_err(what, &e))?;
    let mut payload: &[u8] = &bytes[HEADER_LEN..];
    let msg = wire::read_payload(&mut payload, &h, limits).map_err(wire_err)?;
    Ok((bytes, msg))
}

/// Encodes and sends a CameraRequest.
pub fn send_request(stream: &mut impl Write, req: &CameraRequest) -> io::Result<()> {
    let mut buf = Vec::with_capacity(HEADER_LEN + wire::CAMERA_REQUEST_LEN);
    let _ = wire::write_camera_request(&mut wire::VecWriter(&mut buf), req);
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

/// [`connect`] asking for layered frames of at most `layers` segments per pixel (issue 14; 1:
/// one sample per pixel). The server answers with the count it will render (at most this),
/// and the connection's limits refuse frames with more.
pub fn connect_layers(
    addr: &str,
    token: Option<&str>,
    timeout: Duration,
    layers: u8,
) -> Result<Connection, ClientError> {
    let sock = resolve(addr)?;
    let timeout = timeout.max(Duration::from_millis(10));
    let mut stream = TcpStream::connect_timeout(&sock, timeout)
        .map_err(|e| ClientError::Connect(format!("{addr} ({sock}): {e}")))?;
    let _ = stream.set_nodelay(true);
    stream.set_read_timeout(Some(timeout)).map_err(|e| ClientError::Connect(e.to_string()))?;
    stream.set_write_timeout(Some(timeout)).map_err(|e| ClientError::Connect(e.to_string()))?;
    let mut limits = Limits::default().with_layers(layers);

    // Ask for CompactFrames (about 3 bytes per sample instead of 12; the server decides).
    let mut hello =
        Hello::new(wire::CAP_COMPACT | if cfg!(feature = "gpu") { wire::CAP_GPU } else { 0 }).with_layers(layers);
    if let Some(t) = token {
        hello =
            hello.with_token(t.as_bytes()).map_err(|_| ClientError::Usage("--token is longer than 64 bytes".into()))?;
    }
    let mut buf = Vec::new();
    let _ = wire::write_hello(&mut wire::VecWriter(&mut buf), &hello);
    stream.write_all(&buf).map_err(|e| io_err("sending Hello", &e))?;
    let server_hello = match read_message_bytes(&mut stream, &limits, "waiting for the server's Hello")?.1 {
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
    let probe = CameraRequest { seq: 0, camera: probe_camera(), heuristic: Heuristic::Threshold, radius_scale: 1.0 };
    send_request(&mut stream, &probe).map_err(|e| io_err("sending the probe request", &e))?;
    let bounds = match read_message_bytes(&mut stream, &limits, "waiting for the probe frame")?.1 {
        Message::Frame(f) => f.header.bounds,
        Message::Error(e) => return Err(server_error(&e)),
        Message::Bye => return Err(ClientError::Gone("the server said goodbye".into())),
        _ => return Err(ClientError::Protocol("the server did not answer the probe with a Frame".into())),
    };
    log::info!("connected to {sock}; volume bounds {:?} .. {:?}", bounds.min(), bounds.max());
    Ok(Connection { stream, addr: sock, hello: server_hello, bounds, limits })
}
