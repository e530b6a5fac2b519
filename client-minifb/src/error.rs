//! The client's errors: each is one line a user can act on, and maps to an exit code.

use std::fmt;

/// Why the client stopped.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ClientError {
    /// The command line is inconsistent (exit code 2).
    Usage(String),
    /// There is no display to open a window on (exit code 2).
    NoDisplay(String),
    /// The server address does not parse or resolve.
    BadAddress(String),
    /// The TCP connection could not be made.
    Connect(String),
    /// TLS failed for good: the server's certificate is refused, or the server does not speak
    /// TLS.
    Tls(String),
    /// The server speaks another protocol version.
    Version(String),
    /// The server sent an Error message.
    Server {
        /// The error code of the message.
        code: u16,
        /// Its text.
        text: String,
    },
    /// The server closed the connection or stopped answering.
    Gone(String),
    /// The server sent something this client does not understand.
    Protocol(String),
    /// A file could not be read or written.
    Io(String),
    /// A record file is unusable.
    Record(String),
    /// A renderer could not be set up.
    Renderer(String),
}

impl ClientError {
    /// The process exit code for this error.
    pub fn exit_code(&self) -> u8 {
        match self {
            ClientError::Usage(_) | ClientError::NoDisplay(_) => 2,
            _ => 1,
        }
    }
}

impl fmt::Display for ClientError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ClientError::Usage(s) => write!(f, "{s}"),
            ClientError::NoDisplay(s) => {
                write!(f, "no display: {s}; run with --headless --out DIR to render to PNG files")
            }
            ClientError::BadAddress(s) => write!(f, "bad server address: {s}"),
            ClientError::Connect(s) => write!(f, "cannot connect: {s}"),
            ClientError::Tls(s) => write!(f, "TLS: {s}"),
            ClientError::Version(s) => write!(f, "protocol version mismatch: {s}"),
            ClientError::Server { code, text } => write!(f, "server error {code}: {text}"),
            ClientError::Gone(s) => write!(f, "server gone: {s}"),
            ClientError::Protocol(s) => write!(f, "protocol error: {s}"),
            ClientError::Io(s) => write!(f, "{s}"),
            ClientError::Record(s) => write!(f, "record file: {s}"),
            ClientError::Renderer(s) => write!(f, "renderer: {s}"),
        }
    }
}

impl std::error::Error for ClientError {}
