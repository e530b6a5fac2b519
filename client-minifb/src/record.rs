//! `--record FILE`: saves the received stream for offline replay, in core's record format
//! ([`volwarp_core::record`], `docs/record-format.md`): every Frame exactly as its bytes came
//! off the socket, and every displayed camera, each with its time since the recording started.
//!
//! In a camera entry written by this client the CameraRequest's `seq` is the sequence number
//! of the **frame shown** with that camera (0 while none was shown), and its heuristic and
//! radius scale are the ones the client was asking for; [`crate::replay`] uses `seq` to draw
//! each camera with exactly the frame that was on screen.
//!
//! A writer thread does the file I/O, so neither the network thread nor the display loop waits
//! on the disk: frames go through a bounded channel (the network thread waits if the disk falls
//! far behind), cameras are dropped (and counted) rather than stall the display.

use crate::error::ClientError;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Instant;
use volwarp_core::record::{self, EntryKind};
use volwarp_core::wire::{self, CameraRequest, VecWriter};

/// Entries that may wait for the disk.
const QUEUE: usize = 64;

enum Item {
    Frame { t_us: u64, bytes: Vec<u8> },
    Camera { t_us: u64, request: CameraRequest },
}

/// Where the network thread and the display loop hand entries to the writer thread.
#[derive(Clone)]
pub struct RecordSink {
    tx: SyncSender<Item>,
    start: Instant,
    dropped: Arc<AtomicU64>,
}

/// A recording in progress.
pub struct Recorder {
    sink: RecordSink,
    path: PathBuf,
    thread: JoinHandle<Result<u64, String>>,
}

impl RecordSink {
    fn now_us(&self) -> u64 {
        self.start.elapsed().as_micros().min(u64::MAX as u128) as u64
    }

    /// Records a received Frame: its exact bytes, header included. Waits if the writer is far
    /// behind.
    pub fn frame(&self, bytes: Vec<u8>) {
        let _ = self.tx.send(Item::Frame { t_us: self.now_us(), bytes });
    }

    /// Records a displayed camera (never waits: dropped and counted if the writer is behind).
    pub fn camera(&self, request: CameraRequest) {
        if let Err(TrySendError::Full(_)) = self.tx.try_send(Item::Camera { t_us: self.now_us(), request }) {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

fn write_loop(rx: Receiver<Item>, mut out: BufWriter<File>) -> Result<u64, String> {
    let mut n = 0u64;
    for item in rx {
        let mut prefix = Vec::with_capacity(80);
        match &item {
            Item::Frame { t_us, .. } => {
                let _ = record::write_entry_prefix(&mut VecWriter(&mut prefix), EntryKind::Frame, *t_us);
            }
            Item::Camera { t_us, request } => {
                let _ = record::write_entry_prefix(&mut VecWriter(&mut prefix), EntryKind::Camera, *t_us);
                let _ = wire::write_camera_request(&mut VecWriter(&mut prefix), request);
            }
        }
        out.write_all(&prefix).map_err(|e| e.to_string())?;
        if let Item::Frame { bytes, .. } = &item {
            out.write_all(bytes).map_err(|e| e.to_string())?;
        }
        n += 1;
    }
    out.flush().map_err(|e| e.to_string())?;
    out.into_inner().map_err(|e| e.error().to_string())?.sync_all().map_err(|e| e.to_string())?;
    Ok(n)
}

impl Recorder {
    /// Creates `path` and writes the magic bytes.
    pub fn create(path: &Path) -> Result<Recorder, ClientError> {
        let err = |e: std::io::Error| ClientError::Io(format!("cannot write the record file {}: {e}", path.display()));
        let mut out = BufWriter::with_capacity(1 << 20, File::create(path).map_err(err)?);
        out.write_all(&record::RECORD_MAGIC).map_err(err)?;
        let (tx, rx) = sync_channel(QUEUE);
        let thread = std::thread::Builder::new()
            .name("volwarp-record".into())
            .spawn(move || write_loop(rx, out))
            .map_err(|e| ClientError::Io(format!("cannot start the record thread: {e}")))?;
        let sink = RecordSink { tx, start: Instant::now(), dropped: Arc::new(AtomicU64::new(0)) };
        log::info!("recording to {}", path.display());
        Ok(Recorder { sink, path: path.to_path_buf(), thread })
    }

    /// A sink to hand entries to.
    pub fn sink(&self) -> RecordSink {
        self.sink.clone()
    }

    /// Ends the recording once every other sink is dropped: flushes and closes the file.
    /// Returns the number of entries written.
    pub fn finish(self) -> Result<u64, ClientError> {
        let dropped = self.sink.dropped.load(Ordering::Relaxed);
        drop(self.sink);
        let n = match self.thread.join() {
            Ok(r) => r.map_err(|e| ClientError::Io(format!("writing the record file {}: {e}", self.path.display())))?,
            Err(_) => return Err(ClientError::Io("the record thread failed".into())),
        };
        if dropped > 0 {
            log::warn!("record: {dropped} displayed cameras dropped (the disk was too slow)");
        }
        log::info!("recorded {n} entries to {}", self.path.display());
        Ok(n)
    }
}
