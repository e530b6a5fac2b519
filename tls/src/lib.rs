//! volwarp's optional TLS link: rustls (ring provider) between `volwarp-server --tls-cert
//! --tls-key` and `volwarp-client --tls [--ca FILE]`.
//!
//! The wire protocol is unchanged: the same messages travel inside a TLS 1.3 (or 1.2) stream.
//! Each side of a volwarp connection runs a reader and a writer on two threads, and rustls has
//! one state machine per connection, so a [`TlsLink`] is shared (behind a mutex that is held
//! only while bytes are encrypted or decrypted, never during socket I/O) by a [`TlsReader`]
//! and a [`TlsWriter`], each over its own handle of the socket (`TcpStream::try_clone`).
//! The reader waits for ciphertext without the lock, so a blocked read never stalls a write;
//! the writer encrypts under the lock and writes the records after releasing it. Only the
//! writer writes records (anything the reader's processing queues, such as a key update
//! answer, goes out with the next write), so records are never interleaved.
//!
//! Socket timeouts and deadlines stay the caller's: the halves pass the socket's
//! `WouldBlock`/`TimedOut` errors through and keep their partial state, so a read can be
//! tried again.
//!
//! Certificate verification is always on: against the given CA (or pinned self-signed)
//! certificates with `--ca`, else against the Mozilla roots (`webpki-roots`). A refused
//! certificate is a [`TlsError`] naming the reason, permanent for the client.

use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer, ServerName};
use std::io::{self, Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

pub use rustls;

/// The crypto provider of every config built here (ring).
pub fn provider() -> Arc<rustls::crypto::CryptoProvider> {
    Arc::new(rustls::crypto::ring::default_provider())
}

/// Reads every certificate of a PEM file.
pub fn load_certs(path: &Path) -> Result<Vec<CertificateDer<'static>>, String> {
    let certs = CertificateDer::pem_file_iter(path)
        .map_err(|e| format!("{}: {e}", path.display()))?
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| format!("{}: {e}", path.display()))?;
    if certs.is_empty() {
        return Err(format!("{}: no PEM certificate (-----BEGIN CERTIFICATE-----) in the file", path.display()));
    }
    Ok(certs)
}

/// Reads the first private key (PKCS#8, PKCS#1 or SEC1) of a PEM file.
pub fn load_key(path: &Path) -> Result<PrivateKeyDer<'static>, String> {
    PrivateKeyDer::from_pem_file(path).map_err(|e| format!("{}: no usable PEM private key: {e}", path.display()))
}

/// The server's TLS settings: its certificate chain (leaf first) and private key.
pub fn server_config(cert: &Path, key: &Path) -> Result<Arc<rustls::ServerConfig>, String> {
    let certs = load_certs(cert)?;
    let key_der = load_key(key)?;
    let cfg = rustls::ServerConfig::builder_with_provider(provider())
        .with_safe_default_protocol_versions()
        .map_err(|e| e.to_string())?
        .with_no_client_auth()
        .with_single_cert(certs, key_der)
        .map_err(|e| format!("{} and {}: {e}", cert.display(), key.display()))?;
    Ok(Arc::new(cfg))
}

/// The client's TLS settings: certificates verified against the CA or pinned certificates of
/// `ca` (a PEM file; a self-signed server certificate may be pinned this way), or against the
/// Mozilla roots without it.
pub fn client_config(ca: Option<&Path>) -> Result<Arc<rustls::ClientConfig>, String> {
    let mut roots = rustls::RootCertStore::empty();
    match ca {
        Some(path) => {
            for c in load_certs(path)? {
                roots.add(c).map_err(|e| format!("{}: not a usable CA certificate: {e}", path.display()))?;
            }
        }
        None => roots.extend(webpki_roots::TLS_SERVER_ROOTS.iter().cloned()),
    }
    let cfg = rustls::ClientConfig::builder_with_provider(provider())
        .with_safe_default_protocol_versions()
        .map_err(|e| e.to_string())?
        .with_root_certificates(roots)
        .with_no_client_auth();
    Ok(Arc::new(cfg))
}

/// The name a client verifies the server's certificate for: the host part of `host:port`
/// (an IP address must be in the certificate as an IP address).
pub fn server_name(addr: &str) -> Result<ServerName<'static>, String> {
    let host = match addr.rsplit_once(':') {
        Some((h, _)) => h,
        None => addr,
    };
    let host = host.trim_start_matches('[').trim_end_matches(']');
    ServerName::try_from(host.to_string()).map_err(|e| format!("`{host}` is not a valid TLS server name: {e}"))
}

/// Whether `first` (the first byte a peer sent) starts a TLS record: handshake (22) or alert
/// (21). A volwarp message starts with `V`.
pub fn looks_like_tls(first: u8) -> bool {
    first == 22 || first == 21
}

/// Why a TLS handshake failed.
#[derive(Debug)]
pub enum TlsError {
    /// The socket failed or timed out (`io::ErrorKind::TimedOut`/`WouldBlock` for a timeout).
    Io(io::Error),
    /// The peer closed the connection during the handshake.
    Closed,
    /// The peer's certificate was refused (unknown issuer, wrong name, expired, ...).
    Certificate(rustls::CertificateError),
    /// The peer did not speak TLS: what it sent first (not a TLS record), for the caller to
    /// make sense of (a plain volwarp server's Error message, say).
    NotTls(Vec<u8>),
    /// Any other TLS failure (no common protocol version or cipher suite, a peer's alert, ...).
    Tls(rustls::Error),
}

impl std::fmt::Display for TlsError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TlsError::Io(e) => write!(f, "{e}"),
            TlsError::Closed => write!(f, "the peer closed the connection during the TLS handshake"),
            TlsError::Certificate(e) => write!(f, "certificate refused: {e:?}"),
            TlsError::NotTls(b) => {
                write!(f, "the peer does not speak TLS (it sent {} bytes that are no TLS record)", b.len())
            }
            TlsError::Tls(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for TlsError {}

impl From<rustls::Error> for TlsError {
    fn from(e: rustls::Error) -> Self {
        match e {
            rustls::Error::InvalidCertificate(c) => TlsError::Certificate(c),
            e => TlsError::Tls(e),
        }
    }
}

/// What a peer that does not speak TLS sent: `first` and whatever follows until it closes, up
/// to 4 KiB and at most one second (or `deadline`). A plain server's Error message may arrive
/// in more than one read; the caller wants it whole.
fn rest_of_plain_reply(sock: &TcpStream, first: &[u8], deadline: Option<Instant>) -> Vec<u8> {
    const MOST: usize = 4096;
    let mut sent = first[..first.len().min(MOST)].to_vec();
    let until = Instant::now() + std::time::Duration::from_secs(1);
    let until = deadline.map_or(until, |d| d.min(until));
    let mut buf = [0u8; 1024];
    while sent.len() < MOST {
        let left = until.saturating_duration_since(Instant::now());
        if left.is_zero() || sock.set_read_timeout(Some(left)).is_err() {
            break;
        }
        match (&mut &*sock).read(&mut buf) {
            Ok(0) => break,
            Ok(n) => sent.extend_from_slice(&buf[..n.min(MOST - sent.len())]),
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(_) => break,
        }
    }
    sent
}

/// One TLS connection's state, shared by its reader and writer halves.
#[derive(Clone)]
pub struct TlsLink(Arc<Mutex<rustls::Connection>>);

impl std::fmt::Debug for TlsLink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("TlsLink")
    }
}

impl TlsLink {
    fn lock(&self) -> MutexGuard<'_, rustls::Connection> {
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Runs the handshake of `conn` on `sock`. With `deadline`, each socket read waits at most
    /// until it (a peer trickling bytes cannot stretch the handshake); without, the socket's
    /// own timeouts apply. On failure the alert rustls queued is sent (best effort).
    pub fn handshake(
        conn: impl Into<rustls::Connection>,
        sock: &TcpStream,
        deadline: Option<Instant>,
    ) -> Result<TlsLink, TlsError> {
        let mut conn: rustls::Connection = conn.into();
        let mut buf = vec![0u8; 16 * 1024];
        let mut first = true;
        while conn.is_handshaking() {
            while conn.wants_write() {
                conn.write_tls(&mut &*sock).map_err(TlsError::Io)?;
            }
            if !conn.is_handshaking() {
                break;
            }
            if let Some(d) = deadline {
                let left = d.saturating_duration_since(Instant::now());
                if left.is_zero() {
                    return Err(TlsError::Io(io::ErrorKind::TimedOut.into()));
                }
                let _ = sock.set_read_timeout(Some(left.max(std::time::Duration::from_millis(1))));
            }
            let n = match (&mut &*sock).read(&mut buf) {
                Ok(0) => return Err(TlsError::Closed),
                Ok(n) => n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(TlsError::Io(e)),
            };
            if std::mem::take(&mut first) && !looks_like_tls(buf[0]) {
                return Err(TlsError::NotTls(rest_of_plain_reply(sock, &buf[..n], deadline)));
            }
            let mut got = &buf[..n];
            while !got.is_empty() {
                conn.read_tls(&mut got).map_err(TlsError::Io)?;
                if let Err(e) = conn.process_new_packets() {
                    // Tell the peer why (the alert rustls queued), then give up.
                    while conn.wants_write() {
                        if conn.write_tls(&mut &*sock).is_err() {
                            break;
                        }
                    }
                    return Err(e.into());
                }
            }
        }
        // What the handshake's last flight queued (the server's session tickets, ...).
        while conn.wants_write() {
            conn.write_tls(&mut &*sock).map_err(TlsError::Io)?;
        }
        Ok(TlsLink(Arc::new(Mutex::new(conn))))
    }

    /// A client handshake with `server` (verified as `name`) on `sock`.
    pub fn connect(
        config: Arc<rustls::ClientConfig>,
        name: ServerName<'static>,
        sock: &TcpStream,
        deadline: Option<Instant>,
    ) -> Result<TlsLink, TlsError> {
        let conn = rustls::ClientConnection::new(config, name).map_err(TlsError::Tls)?;
        TlsLink::handshake(conn, sock, deadline)
    }

    /// A server handshake on `sock`.
    pub fn accept(
        config: Arc<rustls::ServerConfig>,
        sock: &TcpStream,
        deadline: Option<Instant>,
    ) -> Result<TlsLink, TlsError> {
        let conn = rustls::ServerConnection::new(config).map_err(TlsError::Tls)?;
        TlsLink::handshake(conn, sock, deadline)
    }

    /// The protocol version and cipher suite agreed on, for logs.
    pub fn describe(&self) -> String {
        let c = self.lock();
        let version = c.protocol_version().map_or("?".into(), |v| format!("{v:?}"));
        let suite = c.negotiated_cipher_suite().map_or("?".into(), |s| format!("{:?}", s.suite()));
        format!("{version} {suite}")
    }

    /// The reading half over `raw` (a handle of the socket).
    pub fn reader<R: Read>(&self, raw: R) -> TlsReader<R> {
        TlsReader { link: self.clone(), raw, buf: vec![0u8; 16 * 1024].into_boxed_slice(), start: 0, end: 0 }
    }

    /// The writing half over `raw` (a handle of the socket).
    pub fn writer<W: Write>(&self, raw: W) -> TlsWriter<W> {
        TlsWriter { link: self.clone(), raw, out: Vec::new() }
    }
}

/// The reading half of a [`TlsLink`]: plaintext out, ciphertext read from `R`.
pub struct TlsReader<R> {
    link: TlsLink,
    raw: R,
    /// Ciphertext read but not yet taken by rustls (`start..end`).
    buf: Box<[u8]>,
    start: usize,
    end: usize,
}

impl<R> TlsReader<R> {
    /// This half over another handle of the same socket, keeping the ciphertext it has read
    /// but not yet decrypted (a reader moving to another thread).
    pub fn with_raw<R2>(self, raw: R2) -> TlsReader<R2> {
        TlsReader { link: self.link, raw, buf: self.buf, start: self.start, end: self.end }
    }
}

impl<R: Read> Read for TlsReader<R> {
    fn read(&mut self, out: &mut [u8]) -> io::Result<usize> {
        if out.is_empty() {
            return Ok(0);
        }
        loop {
            {
                let mut c = self.link.lock();
                // Hand rustls what was read; it may take less while its plaintext is unread.
                while self.start < self.end {
                    let mut pending = &self.buf[self.start..self.end];
                    let before = pending.len();
                    match c.read_tls(&mut pending) {
                        Ok(_) => {}
                        // Its buffer is full: read plaintext out first.
                        Err(e) if e.kind() == io::ErrorKind::Other => break,
                        Err(e) => return Err(e),
                    }
                    let took = before - pending.len();
                    self.start += took;
                    c.process_new_packets().map_err(|e| io::Error::new(io::ErrorKind::InvalidData, e))?;
                    if took == 0 {
                        break;
                    }
                }
                match c.reader().read(out) {
                    Ok(n) => return Ok(n),
                    Err(e) if e.kind() == io::ErrorKind::WouldBlock => {}
                    Err(e) => return Err(e),
                }
            }
            // Wait for more ciphertext without holding the lock.
            let n = loop {
                match self.raw.read(&mut self.buf) {
                    Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                    r => break r?,
                }
            };
            if n == 0 {
                // The end of the stream: rustls reports a close without close_notify as
                // UnexpectedEof on the next plaintext read, and a clean one as 0.
                let mut c = self.link.lock();
                let _ = c.read_tls(&mut &[][..]);
                c.process_new_packets().map_err(|e| io::Error::new(io::ErrorKind::InvalidData, e))?;
                return match c.reader().read(out) {
                    Err(e) if e.kind() == io::ErrorKind::WouldBlock => Err(io::ErrorKind::UnexpectedEof.into()),
                    r => r,
                };
            }
            self.start = 0;
            self.end = n;
        }
    }
}

/// The writing half of a [`TlsLink`]: plaintext in, records written to `W`.
pub struct TlsWriter<W> {
    link: TlsLink,
    raw: W,
    out: Vec<u8>,
}

impl<W: Write> TlsWriter<W> {
    /// Writes out every record rustls has queued.
    fn push(&mut self) -> io::Result<()> {
        self.out.clear();
        {
            let mut c = self.link.lock();
            while c.wants_write() {
                c.write_tls(&mut self.out)?;
            }
        }
        self.raw.write_all(&self.out)
    }

    /// Sends close_notify (the end of the TLS stream; best effort).
    pub fn close(&mut self) {
        self.link.lock().send_close_notify();
        let _ = self.push();
    }

    /// The socket handle under this half.
    pub fn get_ref(&self) -> &W {
        &self.raw
    }
}

impl<W: Write> Write for TlsWriter<W> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let n = self.link.lock().writer().write(buf)?;
        self.push()?;
        Ok(n)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.push()?;
        self.raw.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::net::TcpListener;
    use std::time::Duration;

    struct Files {
        dir: std::path::PathBuf,
    }

    impl Files {
        fn new(tag: &str, names: &[&str]) -> (Files, Vec<u8>) {
            let dir = std::env::temp_dir().join(format!("volwarp-tls-{tag}-{}", std::process::id()));
            std::fs::create_dir_all(&dir).unwrap();
            let key = rcgen::KeyPair::generate().unwrap();
            let params =
                rcgen::CertificateParams::new(names.iter().map(|s| s.to_string()).collect::<Vec<_>>()).unwrap();
            let cert = params.self_signed(&key).unwrap();
            std::fs::write(dir.join("cert.pem"), cert.pem()).unwrap();
            std::fs::write(dir.join("key.pem"), key.serialize_pem()).unwrap();
            (Files { dir }, cert.der().to_vec())
        }
        fn cert(&self) -> std::path::PathBuf {
            self.dir.join("cert.pem")
        }
        fn key(&self) -> std::path::PathBuf {
            self.dir.join("key.pem")
        }
    }

    impl Drop for Files {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }

    /// An echo server on one TLS connection: the reader half on another thread than the
    /// writer half, as volwarp's server runs them.
    fn echo_server(
        cfg: Arc<rustls::ServerConfig>,
    ) -> (std::net::SocketAddr, std::thread::JoinHandle<Result<(), String>>) {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = l.local_addr().unwrap();
        let h = std::thread::spawn(move || {
            let (s, _) = l.accept().map_err(|e| e.to_string())?;
            let link =
                TlsLink::accept(cfg, &s, Some(Instant::now() + Duration::from_secs(10))).map_err(|e| e.to_string())?;
            let (tx, rx) = std::sync::mpsc::channel::<Vec<u8>>();
            let mut r = link.reader(s.try_clone().unwrap());
            let reader = std::thread::spawn(move || loop {
                let mut b = vec![0u8; 3000];
                match r.read(&mut b) {
                    Ok(0) | Err(_) => return,
                    Ok(n) => {
                        b.truncate(n);
                        if tx.send(b).is_err() {
                            return;
                        }
                    }
                }
            });
            let mut w = link.writer(s);
            for b in rx {
                w.write_all(&b).map_err(|e| e.to_string())?;
                w.flush().map_err(|e| e.to_string())?;
            }
            w.close();
            let _ = reader.join();
            Ok(())
        });
        (addr, h)
    }

    #[test]
    fn split_halves_carry_a_megabyte_both_ways_intact() {
        let (files, _) = Files::new("echo", &["localhost", "127.0.0.1"]);
        let (addr, server) = echo_server(server_config(&files.cert(), &files.key()).unwrap());
        let client = client_config(Some(&files.cert())).unwrap();
        let s = TcpStream::connect(addr).unwrap();
        let link = TlsLink::connect(client, server_name("localhost:1").unwrap(), &s, None).unwrap();
        let data: Vec<u8> = (0..1_000_003u32).map(|i| (i * 31 + i / 977) as u8).collect();
        let mut r = link.reader(s.try_clone().unwrap());
        let mut w = link.writer(s.try_clone().unwrap());
        let send = data.clone();
        let writer = std::thread::spawn(move || {
            for chunk in send.chunks(70_001) {
                w.write_all(chunk).unwrap();
            }
            w.flush().unwrap();
            w
        });
        let mut got = vec![0u8; data.len()];
        r.read_exact(&mut got).unwrap();
        assert!(got == data, "the echo differs");
        let mut w = writer.join().unwrap();
        w.close();
        let _ = s.shutdown(std::net::Shutdown::Write);
        let mut rest = Vec::new();
        assert_eq!(r.read_to_end(&mut rest).unwrap(), 0, "a clean close_notify reads as the end");
        server.join().unwrap().unwrap();
    }

    #[test]
    fn unknown_self_signed_and_wrong_name_certificates_are_refused() {
        let (files, _) = Files::new("refuse", &["localhost"]);
        let scfg = server_config(&files.cert(), &files.key()).unwrap();
        let (other, _) = Files::new("other", &["localhost"]);
        let cases = [
            ("an unknown self-signed certificate", client_config(None).unwrap(), "localhost:1"),
            ("another certificate pinned", client_config(Some(&other.cert())).unwrap(), "localhost:1"),
            ("a name the certificate lacks", client_config(Some(&files.cert())).unwrap(), "127.0.0.1:1"),
        ];
        for (what, ccfg, name) in cases {
            let (addr, server) = echo_server(scfg.clone());
            let s = TcpStream::connect(addr).unwrap();
            s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
            match TlsLink::connect(ccfg, server_name(name).unwrap(), &s, None) {
                Err(TlsError::Certificate(e)) => eprintln!("{what}: {e:?}"),
                other => panic!("{what}: expected a certificate error, got {other:?}"),
            }
            assert!(server.join().unwrap().is_err(), "{what}: the server saw the handshake fail");
        }
    }

    #[test]
    fn a_plain_peer_is_named_as_not_speaking_tls() {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = l.local_addr().unwrap();
        let t = std::thread::spawn(move || {
            let (mut s, _) = l.accept().unwrap();
            let _ = s.write_all(b"VWRP\x00\x01 not a TLS record at all");
            std::thread::sleep(Duration::from_millis(200));
        });
        let s = TcpStream::connect(addr).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        let err =
            TlsLink::connect(client_config(None).unwrap(), server_name("localhost:1").unwrap(), &s, None).unwrap_err();
        match err {
            TlsError::NotTls(sent) => assert!(sent.starts_with(b"VWRP"), "{sent:?}"),
            e => panic!("expected NotTls, got {e:?}"),
        }
        t.join().unwrap();
        assert!(looks_like_tls(22) && !looks_like_tls(b'V'));
    }

    #[test]
    fn bad_files_are_clear_errors() {
        let dir = std::env::temp_dir().join(format!("volwarp-tls-bad-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let junk = dir.join("junk.pem");
        std::fs::write(&junk, "hello").unwrap();
        assert!(load_certs(&junk).unwrap_err().contains("no PEM certificate"));
        assert!(load_key(&junk).unwrap_err().contains("no usable PEM private key"));
        assert!(load_certs(&dir.join("missing.pem")).is_err());
        assert!(server_name("[::1]:7878").is_ok() && server_name("bad name:1").is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
