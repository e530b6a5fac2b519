//! The in-process server of the one-command demo: `volwarp-server`'s TCP server on the bundled
//! dataset, bound to a free loopback port; the client talks to it over real TCP exactly as it
//! would to a remote one.

use crate::error::ClientError;
use std::net::SocketAddr;
use std::time::Duration;
use volwarp_server::{Dataset, Server, ServerConfig, ServerHandle};

/// A server running on background threads of this process.
pub struct LocalServer {
    handle: ServerHandle,
}

impl LocalServer {
    /// Loads the bundled dataset and serves it on `127.0.0.1:0`; `frame_delay` slows every
    /// frame down, `threads` marcher threads (0: all cores).
    pub fn start(frame_delay: Option<Duration>, threads: usize) -> Result<LocalServer, ClientError> {
        let dataset = Dataset::default_bundled();
        log::info!("in-process server: dataset {}", dataset.name);
        let config = ServerConfig {
            listen: SocketAddr::from(([127, 0, 0, 1], 0)),
            threads,
            max_clients: 2,
            frame_delay,
            ..ServerConfig::default()
        };
        let server = Server::bind(config, dataset)
            .map_err(|e| ClientError::Io(format!("cannot start the in-process server: {e}")))?;
        Ok(LocalServer { handle: server.spawn() })
    }

    /// The address it listens on.
    pub fn addr(&self) -> SocketAddr {
        self.handle.local_addr()
    }

    /// Stops it and waits for its threads.
    pub fn shutdown(self) {
        self.handle.shutdown();
    }
}
