//! The real `volwarp-server` as a child process: what the one-command demo and `--bench
//! --prerender` talk to when no `--connect` is given. The thin client never links the server's
//! ray marcher; it starts the server program on a free loopback port, reads the address it
//! prints (`listening on ADDR`) and connects over TCP exactly as it would to a remote one.
//!
//! The program is looked up as `$VOLWARP_SERVER`, then beside the client's own executable (and
//! one folder up, for test binaries in `target/*/deps`), then on `PATH`.

use crate::error::ClientError;
use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

/// The server program's file name.
pub const SERVER_PROGRAM: &str = if cfg!(windows) { "volwarp-server.exe" } else { "volwarp-server" };

/// How to start the child server.
#[derive(Clone, Debug, Default)]
pub struct ServerSpawn {
    /// Delay before each frame (slows the server down to show latency hiding).
    pub frame_delay: Option<Duration>,
    /// Marcher threads (0: all cores).
    pub threads: usize,
    /// Extra arguments (e.g. `--volume FILE`).
    pub extra_args: Vec<String>,
    /// How long to wait for the server to listen.
    pub startup_timeout: Duration,
}

/// A `volwarp-server` child process listening on loopback; killed when dropped.
pub struct ServerProcess {
    /// Dropping `child` (its stdin pipe with it) or this process ending stops the server.
    child: Child,
    addr: SocketAddr,
}

/// Where the server program is, or an error that says how to get it.
pub fn find_server_program() -> Result<PathBuf, ClientError> {
    if let Some(p) = std::env::var_os("VOLWARP_SERVER") {
        let p = PathBuf::from(p);
        return if p.is_file() {
            Ok(p)
        } else {
            Err(ClientError::Io(format!("$VOLWARP_SERVER = {} is not a file", p.display())))
        };
    }
    let mut candidates = Vec::new();
    if let Some(dir) = std::env::current_exe().ok().and_then(|e| e.parent().map(PathBuf::from)) {
        candidates.push(dir.join(SERVER_PROGRAM));
        if let Some(up) = dir.parent() {
            candidates.push(up.join(SERVER_PROGRAM));
        }
    }
    if let Some(path) = std::env::var_os("PATH") {
        candidates.extend(std::env::split_paths(&path).map(|d| d.join(SERVER_PROGRAM)));
    }
    candidates.into_iter().find(|p| p.is_file()).ok_or_else(|| {
        ClientError::Io(format!(
            "no --connect given and no `{SERVER_PROGRAM}` program found (beside this client, on PATH or in \
             $VOLWARP_SERVER): build it with `cargo build --release -p volwarp-server`, or pass --connect ADDR"
        ))
    })
}

impl ServerProcess {
    /// Starts the server on `127.0.0.1:0` and waits until it says where it listens.
    pub fn spawn(opts: &ServerSpawn) -> Result<ServerProcess, ClientError> {
        let program = find_server_program()?;
        let mut cmd = Command::new(&program);
        cmd.args(["--listen", "127.0.0.1:0", "--max-clients", "2", "--exit-on-stdin-eof", "--threads"])
            .arg(opts.threads.to_string())
            .arg("--frame-delay-ms")
            .arg(opts.frame_delay.map_or(0, |d| d.as_millis() as u64).to_string())
            .args(&opts.extra_args)
            // The server exits when this pipe closes: with the client, however it ends.
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit());
        let mut child = cmd.spawn().map_err(|e| ClientError::Io(format!("cannot start {}: {e}", program.display())))?;
        let stdout = child.stdout.take().expect("stdout is piped");
        let (tx, rx) = mpsc::channel();
        // Read lines until the address, then keep draining (and showing) the rest.
        std::thread::Builder::new()
            .name("volwarp-server-stdout".into())
            .spawn(move || {
                let mut tx = Some(tx);
                for line in BufReader::new(stdout).lines() {
                    let Ok(line) = line else { break };
                    match (tx.as_ref(), line.strip_prefix("listening on ")) {
                        (Some(t), Some(a)) => {
                            let _ = t.send(a.trim().parse::<SocketAddr>().map_err(|e| format!("`{a}`: {e}")));
                            tx = None;
                        }
                        _ => println!("server: {line}"),
                    }
                }
            })
            .map_err(|e| ClientError::Io(format!("cannot start a thread: {e}")))?;
        let timeout = if opts.startup_timeout.is_zero() { Duration::from_secs(30) } else { opts.startup_timeout };
        let addr = match rx.recv_timeout(timeout) {
            Ok(Ok(addr)) => addr,
            Ok(Err(e)) => return Err(kill_with(child, format!("the server printed a bad address {e}"))),
            Err(_) => {
                let status = child.try_wait().ok().flatten();
                let why = match status {
                    Some(s) => format!("the server exited ({s}) before listening"),
                    None => format!("the server did not listen within {} s", timeout.as_secs()),
                };
                return Err(kill_with(child, why));
            }
        };
        log::info!("started {} (pid {}) on {addr}", program.display(), child.id());
        Ok(ServerProcess { child, addr })
    }

    /// The address it listens on.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }
}

fn kill_with(mut child: Child, why: String) -> ClientError {
    let _ = child.kill();
    let _ = child.wait();
    ClientError::Io(why)
}

impl Drop for ServerProcess {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
