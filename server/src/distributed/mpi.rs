//! The MPI front end (feature `mpi`): `mpiexec -n N volwarp-server serve|render|dump …`.
//!
//! Every rank reads its part of the volume ([`super::decomposition`]); rank 0 keeps the
//! one-process front end (the TCP server with its wire format, or the `render` / `dump` file)
//! and for each frame broadcasts the request; every rank marches its part
//! ([`super::partial`]), sends each band of image rows to the band's owner (rank `b` owns band
//! `b`: one all-to-all, direct-send), merges what it received ([`super::composite`]) and
//! assembles its band's share of the frame (packed samples, colors, segment indices, as the
//! one-process server makes them: [`super::FrameGeometry::frame_part`]); the shares are
//! gathered to rank 0, which joins and encodes the frame (`render` gathers the merged bands
//! instead, for the image).
//!
//! **Faults.** MPI calls run on rank 0's main thread only, with errors returned rather than
//! fatal; a watchdog thread times every frame. A frame not done within the rank timeout (a
//! rank hangs), or whose bands do not arrive whole (a rank failed: a rank whose march panics
//! still takes part in the exchange, sending bands that do not decode), makes rank 0 send every
//! client, waiting for a frame or idle, an `INTERNAL` error, print it and end every rank with
//! `MPI_Abort` (status 3) — never a silent hang. A rank that dies (killed, aborted) makes
//! MPICH's `mpiexec` kill every rank, rank 0 too, even with `-disable-auto-cleanup` (MPICH
//! 4.0): the clients' connections close and `mpiexec` fails. A bad launch — files that differ
//! between ranks, more ranks than the volume has bricks, a part refused for memory — is
//! reported by rank 0 (and the rank concerned) before any frame, and every rank exits non-zero.

use super::composite::{self, Band, BandView};
use super::decomposition::{self, Decomposition};
use super::partial::{keep_for_next_frame, PartMarcher, Seg};
use super::{FrameGeometry, FramePart, FrameSlots};
use crate::marcher::{FrameStats, MarchOptions, Marcher};
use crate::server::{FrameSource, Server, ServerConfig};
use crate::transfer_function::TransferFunction;
use crate::volume::LoadOptions;
use mpi::collective::SystemOperation;
use mpi::datatype::{Partition, PartitionMut};
use mpi::point_to_point::Source as _;
use mpi::request::{Request, Scope};
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use std::path::PathBuf;
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use volwarp_core::compact_frame::Encoding;
use volwarp_core::wire::{CameraRequest, Frame};
use volwarp_core::{Camera, Heuristic, Image, Vec3};

/// Whether this process was started by an MPI launcher (`mpiexec` sets `PMI_RANK`; Open MPI
/// sets `OMPI_COMM_WORLD_SIZE`).
pub fn launched_by_mpiexec() -> bool {
    ["PMI_RANK", "PMI_SIZE", "OMPI_COMM_WORLD_SIZE"].iter().any(|v| std::env::var_os(v).is_some())
}

/// What every rank loads and marches.
#[derive(Clone, Debug)]
pub struct Launch {
    /// The volume file (each rank reads its part of it).
    pub volume: PathBuf,
    /// Loader options (`--max-memory` applies to each rank's part).
    pub load: LoadOptions,
    /// Transfer function file (else the preset for the volume's name and dims).
    pub tf: Option<PathBuf>,
    /// March options.
    pub opts: MarchOptions,
    /// How long a frame may take before rank 0 gives up on the other ranks.
    pub rank_timeout: Duration,
}

/// What a `dump` does with its frame: the frame, its message bytes, their encoding and the
/// frame's stats.
pub type WriteFrame = Box<dyn FnOnce(&Frame, Vec<u8>, Encoding, &FrameStats) -> Result<(), String> + Send>;

/// A frame request to rank 0's MPI thread and where its frame goes.
type FrameJob = (CameraRequest, u32, mpsc::Sender<Result<(Frame, FrameStats), String>>);

/// What rank 0 gathers of a frame, in image order: the merged bands (for an image) or the
/// frame's samples, each band's assembled by its owner (for a frame to send).
enum Collected {
    Bands(Vec<Band>),
    Frame(Frame),
}

/// What rank 0 gathers of a frame and every rank's stats.
type Gathered = (Collected, Vec<RankStats>);

/// What rank 0 does with the ranks.
pub enum Job {
    /// Serve clients over TCP (the one-process server's front end).
    Serve(ServerConfig, Box<dyn FnOnce(std::net::SocketAddr) + Send>),
    /// Render the composited image for a camera (given the default camera of the volume box).
    Render(
        Box<dyn FnOnce(Camera) -> Result<Camera, String> + Send>,
        Box<dyn FnOnce(Image) -> Result<(), String> + Send>,
    ),
    /// Render one frame for a request (given the default camera), with `layers` segments per
    /// pixel, as many times as the second count says (the last is kept: the earlier ones time
    /// the steady state), encoded in `Encoding`, and hand its bytes over.
    Dump(Box<dyn FnOnce(Camera) -> Result<CameraRequest, String> + Send>, u32, u32, Encoding, WriteFrame),
}

/// Per-rank timings and bytes of one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RankStats {
    /// Marching the part, µs.
    pub march_us: u64,
    /// Waiting for the slowest rank's march (the all-reduce of the rows' work), µs.
    pub wait_us: u64,
    /// The bands' all-to-all, µs.
    pub exchange_us: u64,
    /// Decoding and merging the received bands and, for a frame, assembling the band's
    /// samples, µs.
    pub merge_us: u64,
    /// The gather to rank 0, µs.
    pub gather_us: u64,
    /// Of `merge_us`, reading the received bands (their counts checked, in place), µs.
    pub decode_us: u64,
    /// Writing the bands to send, µs.
    pub encode_us: u64,
    /// Bytes sent to other ranks (bands and the merged band).
    pub bytes_sent: u64,
}

/// A failure injected into one rank for the fault tests, from the environment variable
/// `VOLWARP_MPI_FAULT=RANK:FRAME:abort|panic|hang` (rank `RANK` ≥ 1 aborts the process, panics
/// or hangs after marching its `FRAME`-th frame, counted from 1): what a crashed, failing or
/// stuck node does mid-frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Fault {
    frame: u64,
    what: FaultKind,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum FaultKind {
    Abort,
    Panic,
    Hang,
}

impl Fault {
    fn from_env(rank: usize) -> Option<Fault> {
        let v = std::env::var("VOLWARP_MPI_FAULT").ok()?;
        let mut it = v.split(':');
        let (r, f, what) = (it.next()?.parse::<usize>().ok()?, it.next()?.parse().ok()?, it.next()?);
        let what = match what {
            "abort" => FaultKind::Abort,
            "panic" => FaultKind::Panic,
            "hang" => FaultKind::Hang,
            _ => return None,
        };
        (r == rank && rank != 0).then_some(Fault { frame: f, what })
    }

    fn strike(self, rank: usize) {
        eprintln!("volwarp-server (rank {rank}): VOLWARP_MPI_FAULT: {:?} mid-frame", self.what);
        match self.what {
            FaultKind::Abort => std::process::abort(),
            FaultKind::Panic => panic!("VOLWARP_MPI_FAULT: a failure injected mid-frame"),
            FaultKind::Hang => loop {
                std::thread::sleep(Duration::from_secs(3600));
            },
        }
    }
}

/// What a rank whose march failed sends for every band: no band decodes from it (a count
/// above any K, or bytes too many for a band of no pixels; 4 of them, as every band's bytes
/// are a multiple of 4 to lie aligned in the receive buffer).
const FAILED_BAND: [u8; 4] = [0xff; 4];

/// Waits for `req`, yielding the core between tests instead of MPICH's busy poll: the ranks
/// share the cores (a rank waiting for a slower one's march or merge would otherwise take a
/// core from it), and a test drives MPI's progress as a wait would. Every rank takes part in
/// such a collective by its nonblocking form (a blocking collective does not match one).
fn wait_yielding<'a, D: ?Sized, S: Scope<'a>>(mut req: Request<'a, D, S>) {
    loop {
        match req.test() {
            Ok(_) => return,
            Err(r) => req = r,
        }
        std::thread::yield_now();
    }
}

/// Waits for `req` that may take long (the next frame's command): as [`wait_yielding`] for a
/// millisecond, then testing every 100 µs asleep, so an idle rank takes no core.
fn wait_idle<'a, D: ?Sized, S: Scope<'a>>(mut req: Request<'a, D, S>) {
    let t = Instant::now();
    loop {
        match req.test() {
            Ok(_) => return,
            Err(r) => req = r,
        }
        if t.elapsed() < Duration::from_millis(1) {
            std::thread::yield_now();
        } else {
            std::thread::sleep(Duration::from_micros(100));
        }
    }
}

const CMD_LEN: usize = 72;
const CMD_QUIT: u8 = 0;
const CMD_FRAME: u8 = 1;

fn encode_cmd(req: &CameraRequest, layers: u32, assemble: bool) -> [u8; CMD_LEN] {
    let mut b = [0u8; CMD_LEN];
    b[0] = CMD_FRAME;
    b[1] = layers.min(255) as u8;
    b[2] = req.heuristic.code();
    b[3] = u8::from(assemble);
    b[64..72].copy_from_slice(&req.seq.to_le_bytes());
    let c = &req.camera;
    let f = [c.eye.x, c.eye.y, c.eye.z, c.target.x, c.target.y, c.target.z, c.up.x, c.up.y, c.up.z, c.fov_y_deg];
    for (i, v) in f.iter().enumerate() {
        b[8 + 4 * i..12 + 4 * i].copy_from_slice(&v.to_le_bytes());
    }
    b[48..52].copy_from_slice(&c.width.to_le_bytes());
    b[52..56].copy_from_slice(&c.height.to_le_bytes());
    b[56..60].copy_from_slice(&req.radius_scale.to_le_bytes());
    b
}

fn decode_cmd(b: &[u8; CMD_LEN]) -> Option<(CameraRequest, u32, bool)> {
    if b[0] != CMD_FRAME {
        return None;
    }
    let f = |i: usize| f32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
    let u = |i: usize| u32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
    let camera = Camera {
        eye: Vec3::new(f(8), f(12), f(16)),
        target: Vec3::new(f(20), f(24), f(28)),
        up: Vec3::new(f(32), f(36), f(40)),
        fov_y_deg: f(44),
        width: u(48),
        height: u(52),
    };
    let req = CameraRequest {
        seq: u64::from_le_bytes([b[64], b[65], b[66], b[67], b[68], b[69], b[70], b[71]]),
        camera,
        heuristic: Heuristic::from_code(b[2]).unwrap_or(Heuristic::Threshold),
        radius_scale: f(56),
        layers: 0,
    };
    Some((req, u32::from(b[1]), b[3] != 0))
}

fn prefix(counts: &[i32]) -> Vec<i32> {
    counts
        .iter()
        .scan(0i32, |acc, &c| {
            let d = *acc;
            *acc += c;
            Some(d)
        })
        .collect()
}

/// A rank's exchange buffers, kept from frame to frame: allocated anew, a 1024² frame's 10–20 MB
/// of bands cost a page fault per 4 KiB every frame.
#[derive(Default)]
struct Buffers {
    send: Vec<u32>,
    recv: Vec<u32>,
}

/// One frame on every rank (collective): march, direct-send by bands, merge, (with `assemble`)
/// each band's samples assembled by its owner, gather. Rank 0 gets the merged bands or the
/// frame, and every rank's stats.
fn frame_collective(
    world: &SimpleCommunicator,
    part: &PartMarcher,
    bufs: &mut Buffers,
    geometry: &FrameGeometry,
    (req, layers, assemble): (&CameraRequest, u32, bool),
    fault: Option<Fault>,
) -> Option<Result<Gathered, String>> {
    let size = world.size() as usize;
    let rank = world.rank() as usize;
    let cam = &req.camera;
    let k = layers.clamp(1, volwarp_core::segments::MAX_LAYERS as u32) as usize;
    let ert = part.options().early_termination;
    let mut st = RankStats::default();
    let t0 = Instant::now();
    // A march that fails (a panic) still takes part in the collectives, sending bands that do
    // not decode: the others go on, rank 0 fails the frame and ends the job.
    let marched = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let pf = part.march(cam, layers, req.heuristic);
        if let Some(f) = fault {
            f.strike(rank);
        }
        pf
    }));
    let t_marched = Instant::now();
    st.march_us = (t_marched - t0).as_micros() as u64;
    // The image's rows cut into bands of about equal work (every rank's segments per row,
    // all-reduced; the all-reduce is where the ranks wait for the slowest march).
    let w = cam.width as u64;
    let mine: Vec<u64> = match &marched {
        Ok(pf) => pf.count.chunks(cam.width.max(1) as usize).map(|r| r.iter().map(|&c| u64::from(c)).sum()).collect(),
        Err(_) => vec![0; cam.height as usize],
    };
    let mut load = vec![0u64; mine.len()];
    mpi::request::scope(|scope| {
        wait_yielding(world.immediate_all_reduce_into(scope, &mine[..], &mut load[..], SystemOperation::sum()))
    });
    // A pixel costs about a quarter of a segment's merge and assembly.
    let load: Vec<u64> = load.iter().map(|&s| s + w / 4).collect();
    let bounds = composite::balanced_bands(&load, size);
    let rows_of = |b: usize| bounds[b]..bounds[b + 1];
    let t1 = Instant::now();
    st.wait_us = (t1 - t_marched).as_micros() as u64;
    // Direct-send: band b to rank b, each band written in place into one 4-byte aligned send
    // buffer (in parallel); a rank's own band is not sent, it is read from its march.
    let mut scounts = vec![0i32; size];
    let send: Vec<u32> = match &marched {
        Ok(pf) => {
            let lens: Vec<usize> =
                (0..size).map(|b| if b == rank { 0 } else { composite::band_len(pf, rows_of(b)) }).collect();
            let mut send = std::mem::take(&mut bufs.send);
            send.clear();
            send.resize(lens.iter().sum::<usize>() / 4, 0);
            let mut rest = bytemuck::cast_slice_mut::<u32, u8>(&mut send);
            for (b, &l) in lens.iter().enumerate() {
                let (c, r) = rest.split_at_mut(l);
                if b != rank {
                    composite::encode_band_into(pf, rows_of(b), c);
                }
                rest = r;
            }
            for (c, l) in scounts.iter_mut().zip(&lens) {
                *c = *l as i32;
            }
            send
        }
        Err(_) => {
            eprintln!("volwarp-server (rank {rank}): the march of this rank's part failed; the frame is failed");
            for (b, c) in scounts.iter_mut().enumerate() {
                *c = if b == rank { 0 } else { FAILED_BAND.len() as i32 };
            }
            vec![u32::from_ne_bytes(FAILED_BAND); size - 1]
        }
    };
    st.bytes_sent += scounts.iter().map(|&c| c as u64).sum::<u64>();
    let t_sent = Instant::now();
    st.encode_us = (t_sent - t1).as_micros() as u64;
    let mut rcounts = vec![0i32; size];
    world.all_to_all_into(&scounts[..], &mut rcounts[..]);
    let (sdispl, rdispl) = (prefix(&scounts), prefix(&rcounts));
    let recv_len: usize = rcounts.iter().map(|&c| c as usize).sum();
    let mut recv = std::mem::take(&mut bufs.recv);
    recv.clear();
    recv.resize(recv_len.div_ceil(4), 0);
    {
        let send = bytemuck::cast_slice::<u32, u8>(&send);
        let recv = &mut bytemuck::cast_slice_mut::<u32, u8>(&mut recv)[..recv_len];
        let sp = Partition::new(send, &scounts[..], &sdispl[..]);
        let mut rp = PartitionMut::new(recv, &rcounts[..], &rdispl[..]);
        mpi::request::scope(|scope| wait_yielding(world.immediate_all_to_all_varcount_into(scope, &sp, &mut rp)));
    }
    keep_for_next_frame(&mut bufs.send, send);
    let t2 = Instant::now();
    st.exchange_us = (t2 - t_sent).as_micros() as u64;
    let rows = rows_of(rank);
    let pixels = (rows.end - rows.start) as usize * cam.width as usize;
    // The received bands read in place, this rank's own from its march. A band that does not
    // parse (a failed rank's): rank 0 fails the frame.
    let received = &bytemuck::cast_slice::<u32, u8>(&recv)[..recv_len];
    let mut broken = false;
    let views: Vec<BandView> = (0..size)
        .filter_map(|r| {
            if r == rank {
                return marched.as_ref().ok().map(|pf| BandView::of_part(pf, rows.clone()));
            }
            let (a, n) = (rdispl[r] as usize, rcounts[r] as usize);
            match BandView::parse(&received[a..a + n], pixels, k) {
                Ok(v) => Some(v),
                Err(e) => {
                    log::error!("rank {rank}: the band from rank {r} is broken ({e}); left out");
                    broken = true;
                    None
                }
            }
        })
        .collect();
    broken |= marched.is_err();
    st.decode_us = t2.elapsed().as_micros() as u64;
    // What this band owner hands rank 0: its band's frame samples, assembled in runs (a
    // frame), or its merged band's bytes (an image). `None`: a band was broken.
    let merged: Option<Merged> = if broken {
        None
    } else if assemble {
        // Merged and assembled pixel by pixel: no merged band in between.
        let first = rows.start * cam.width;
        let a = geometry.assembler(req, layers);
        composite::merge_views_with(&views, pixels, k, ert, |i, segs, out: &mut super::PartBuilder| {
            a.push(first + i as u32, segs, out)
        })
        .map(|runs| Merged::Runs(runs.into_iter().map(|b| a.finish(b)).collect()))
        .ok()
    } else {
        composite::merge_views_with(&views, pixels, k, ert, |_, merged, (count, segs): &mut (Vec<u8>, Vec<Seg>)| {
            count.push(merged.len() as u8);
            segs.extend_from_slice(merged);
        })
        .map(|runs| {
            let count: Vec<u8> = runs.iter().flat_map(|r| r.0.iter().copied()).collect();
            let segs: Vec<Seg> = runs.iter().flat_map(|r| r.1.iter().copied()).collect();
            Merged::Bytes(composite::encode_merged(&Band { count, start: Vec::new(), segs }))
        })
        .ok()
    };
    drop(views);
    keep_for_next_frame(&mut bufs.recv, recv);
    if let Ok(pf) = marched {
        part.recycle(pf);
    }
    let t3 = Instant::now();
    st.merge_us = (t3 - t2).as_micros() as u64;
    // The most samples band b may hold (its pixels times K).
    let most = |b: usize| (rows_of(b).len() * cam.width as usize * k) as u64;
    let root = world.process_at_rank(0);
    let out = if assemble {
        let runs = merged.map(|m| match m {
            Merged::Runs(r) => r,
            Merged::Bytes(_) => unreachable!("a frame's band owners assemble runs"),
        });
        if rank == 0 {
            Some(gather_frame_root(world, geometry, (req, layers), runs, &(0..size).map(most).collect::<Vec<_>>()))
        } else {
            st.bytes_sent += send_frame_part(world, runs, most(rank), layers > 1);
            None
        }
    } else {
        let merged = match merged {
            Some(Merged::Bytes(b)) => b,
            _ => FAILED_BAND.to_vec(),
        };
        let len = merged.len() as i32;
        if rank == 0 {
            let mut lens = vec![0i32; size];
            // Rank 0 waits here for the slowest band owner's merge: yielding the core to it.
            mpi::request::scope(|scope| wait_yielding(root.immediate_gather_into_root(scope, &len, &mut lens[..])));
            // Rank 0's own band stays where it is (it sends itself nothing).
            lens[0] = 0;
            let displs = prefix(&lens);
            let mut all = vec![0u8; lens.iter().map(|&c| c as usize).sum()];
            {
                let mut rp = PartitionMut::new(&mut all[..], &lens[..], &displs[..]);
                mpi::request::scope(|scope| {
                    wait_yielding(root.immediate_gather_varcount_into_root(scope, &merged[..0], &mut rp))
                });
            }
            let band =
                |b: usize| if b == 0 { &merged[..] } else { &all[displs[b] as usize..(displs[b] + lens[b]) as usize] };
            Some(
                (0..size)
                    .map(|b| {
                        let pixels = rows_of(b).len() * cam.width as usize;
                        composite::decode_band(band(b), pixels, k)
                            .map_err(|why| format!("rank {b} sent no valid band ({why}): a rank failed"))
                    })
                    .collect::<Result<Vec<Band>, String>>()
                    .map(Collected::Bands),
            )
        } else {
            st.bytes_sent += merged.len() as u64;
            mpi::request::scope(|scope| {
                wait_yielding(root.immediate_gather_into(scope, &len));
                wait_yielding(root.immediate_gather_varcount_into(scope, &merged[..]));
            });
            None
        }
    };
    st.gather_us = t3.elapsed().as_micros() as u64;
    let mine =
        [st.march_us, st.wait_us, st.exchange_us, st.merge_us, st.gather_us, st.bytes_sent, st.decode_us, st.encode_us];
    if rank == 0 {
        let mut all = vec![0u64; 8 * size];
        root.gather_into_root(&mine[..], &mut all[..]);
        let stats = all
            .chunks_exact(8)
            .map(|s| RankStats {
                march_us: s[0],
                wait_us: s[1],
                exchange_us: s[2],
                merge_us: s[3],
                gather_us: s[4],
                bytes_sent: s[5],
                decode_us: s[6],
                encode_us: s[7],
            })
            .collect();
        out.map(|o| o.map(|o| (o, stats)))
    } else {
        root.gather_into(&mine[..]);
        None
    }
}

/// What a band owner hands rank 0 (see [`frame_collective`]).
enum Merged {
    /// Its band's frame samples, in runs of pixels.
    Runs(Vec<FramePart>),
    /// Its merged band's bytes ([`composite::encode_merged`]).
    Bytes(Vec<u8>),
}

/// The message tags of a band's frame samples sent to rank 0: samples, colors, segment indices.
const TAG_SAMPLES: i32 = 1;
const TAG_COLORS: i32 = 2;
const TAG_SEGMENTS: i32 = 3;

/// Rank 0's end of a frame's gather, straight into the frame it sends: every band owner's
/// sample count (−1: a band it received was broken) gathered, the frame allocated once, the
/// other owners' samples, colors and segment indices received in place while rank 0 copies its
/// own band's runs in (no bytes in between, no second copy). An error names a failed rank.
fn gather_frame_root(
    world: &SimpleCommunicator,
    geometry: &FrameGeometry,
    (req, layers): (&CameraRequest, u32),
    mine: Option<Vec<FramePart>>,
    most: &[u64],
) -> Result<Collected, String> {
    let size = world.size() as usize;
    let root = world.process_at_rank(0);
    let n_mine = mine.as_ref().map_or(-1, |runs| runs.iter().map(|p| p.samples.len() as i64).sum());
    let mut counts = vec![0i64; size];
    // Rank 0 waits here for the slowest band owner's merge: yielding the core to it.
    mpi::request::scope(|scope| wait_yielding(root.immediate_gather_into_root(scope, &n_mine, &mut counts[..])));
    // A band owner that sends nothing: one that received a broken band (or a count its band
    // cannot hold, which owners never send).
    let sent: Vec<bool> = counts.iter().zip(most).map(|(&c, &m)| c >= 0 && c as u64 <= m).collect();
    let counts: Vec<usize> = counts.iter().zip(&sent).map(|(&c, &ok)| if ok { c as usize } else { 0 }).collect();
    let mut frame = geometry.frame_of_count(req, layers, counts.iter().sum(), 0);
    let layered = layers > 1;
    let mut slots = FrameSlots::split(&mut frame, &counts).expect("the counts add up to the frame's samples");
    let mut own = slots.remove(0);
    mpi::request::scope(|scope| {
        let mut reqs = Vec::with_capacity(3 * size);
        for (b, slot) in (1..size).zip(slots).filter(|&(b, _)| sent[b]) {
            let p = world.process_at_rank(b as i32);
            reqs.push(p.immediate_receive_into_with_tag(scope, slot.samples, TAG_SAMPLES));
            reqs.push(p.immediate_receive_into_with_tag(scope, slot.colors, TAG_COLORS));
            if layered {
                reqs.push(p.immediate_receive_into_with_tag(scope, slot.segments, TAG_SEGMENTS));
            }
        }
        // Rank 0's own band copied in while the others' arrive.
        if let Some(runs) = &mine {
            let filled = own.fill(runs);
            debug_assert!(filled, "rank 0's count is its runs' samples");
        }
        for r in reqs {
            wait_yielding(r);
        }
    });
    match sent.iter().position(|&ok| !ok) {
        Some(0) => Err("a band rank 0 received was broken: a rank failed".into()),
        Some(b) => Err(format!("rank {b} sent no frame samples (a band it received was broken): a rank failed")),
        None => Ok(Collected::Frame(frame)),
    }
}

/// A band owner's end of a frame's gather ([`gather_frame_root`]): its sample count, then its
/// samples, colors and (layered frames) segment indices, joined into one run. Returns the bytes
/// sent.
fn send_frame_part(world: &SimpleCommunicator, runs: Option<Vec<FramePart>>, most: u64, layered: bool) -> u64 {
    let root = world.process_at_rank(0);
    let part = runs.map(|r| FramePart::join(&r)).filter(|p| p.samples.len() as u64 <= most);
    let n = part.as_ref().map_or(-1, |p| p.samples.len() as i64);
    mpi::request::scope(|scope| {
        wait_yielding(root.immediate_gather_into(scope, &n));
        if let Some(p) = &part {
            let s = root.immediate_send_with_tag(scope, bytemuck::cast_slice::<u64, u8>(&p.samples), TAG_SAMPLES);
            let c = root.immediate_send_with_tag(scope, bytemuck::cast_slice::<u32, u8>(&p.colors), TAG_COLORS);
            let g = layered.then(|| root.immediate_send_with_tag(scope, &p.segments[..], TAG_SEGMENTS));
            wait_yielding(s);
            wait_yielding(c);
            if let Some(g) = g {
                wait_yielding(g);
            }
        }
    });
    part.map_or(8, |p| (8 + 12 * p.samples.len() + p.segments.len()) as u64)
}

/// The watchdog of rank 0: a frame in flight longer than the timeout is a failed rank.
struct Watchdog {
    started: Mutex<Option<Instant>>,
    failed: Mutex<Option<String>>,
    /// How many clients the server still has (set once it serves).
    clients: Mutex<Option<Box<dyn Fn() -> usize + Send>>>,
}

/// The longest rank 0 waits for its clients to be sent the error before it ends the job.
const TELL_CLIENTS: Duration = Duration::from_secs(3);

impl Watchdog {
    fn spawn(timeout: Duration) -> Arc<Watchdog> {
        let w = Arc::new(Watchdog { started: Mutex::new(None), failed: Mutex::new(None), clients: Mutex::new(None) });
        let wd = w.clone();
        std::thread::Builder::new()
            .name("volwarp-mpi-watchdog".into())
            .spawn(move || loop {
                std::thread::sleep(Duration::from_millis(50));
                let late = wd.started.lock().unwrap_or_else(|e| e.into_inner()).is_some_and(|t| t.elapsed() > timeout);
                if late {
                    wd.fail(format!(
                        "the MPI ranks did not finish a frame within {:.1} s: a rank died or hangs",
                        timeout.as_secs_f64()
                    ));
                }
            })
            .expect("spawning the watchdog");
        w
    }

    /// Fails the job: every client (waiting for a frame or idle) is sent `msg` as an
    /// `INTERNAL` error, then every rank is ended with status 3 (`MPI_Abort`: the ranks still
    /// alive, stuck in a collective with a dead or hung one, would otherwise hang `mpiexec`).
    fn fail(&self, msg: String) -> ! {
        *self.failed.lock().unwrap_or_else(|e| e.into_inner()) = Some(msg.clone());
        eprintln!("volwarp-server (rank 0): {msg}");
        // The clients' threads send the error and end within the server's poll of its source.
        let t = Instant::now();
        let clients = self.clients.lock().unwrap_or_else(|e| e.into_inner()).take();
        let left = || clients.as_ref().map_or(0, |n| n());
        while left() > 0 && t.elapsed() < TELL_CLIENTS {
            std::thread::sleep(Duration::from_millis(20));
        }
        std::thread::sleep(Duration::from_millis(100));
        // SAFETY: MPI is initialized (the watchdog starts after it) and not finalized (rank 0
        // finalizes only after its job, and this call ends the process). MPI_Abort is the one
        // call MPI allows from any thread in a failure; MPICH's needs no lock at the funneled
        // threading level.
        unsafe {
            mpi::ffi::MPI_Abort(mpi::ffi::RSMPI_COMM_WORLD, 3);
        }
        std::process::exit(3);
    }

    fn failed(&self) -> Option<String> {
        self.failed.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    fn start(&self) {
        *self.started.lock().unwrap_or_else(|e| e.into_inner()) = Some(Instant::now());
    }

    fn done(&self) {
        *self.started.lock().unwrap_or_else(|e| e.into_inner()) = None;
    }
}

/// Rank 0's frames for the TCP server: requests go to the main thread (which alone calls
/// MPI), answers come back or the watchdog's error does.
struct Source {
    jobs: Mutex<mpsc::Sender<FrameJob>>,
    geometry: FrameGeometry,
    watchdog: Arc<Watchdog>,
}

impl FrameSource for Source {
    fn render(&self, req: &CameraRequest, layers: u32, frame: &mut Frame) -> Result<FrameStats, String> {
        if let Some(e) = self.watchdog.failed() {
            return Err(e);
        }
        let (tx, rx) = mpsc::channel();
        self.jobs
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .send((*req, layers, tx))
            .map_err(|_| "the MPI front end has stopped".to_string())?;
        loop {
            match rx.recv_timeout(Duration::from_millis(50)) {
                Ok(Ok((f, stats))) => {
                    *frame = f;
                    return Ok(stats);
                }
                Ok(Err(e)) => return Err(e),
                Err(mpsc::RecvTimeoutError::Timeout) => {
                    if let Some(e) = self.watchdog.failed() {
                        return Err(e);
                    }
                }
                Err(mpsc::RecvTimeoutError::Disconnected) => return Err("the MPI front end has stopped".into()),
            }
        }
    }

    fn encode(&self, req: &CameraRequest, frame: &Frame, encoding: Encoding, green: bool) -> (Vec<u8>, Encoding) {
        self.geometry.encode(req, frame, encoding, green)
    }

    fn failed(&self) -> Option<String> {
        self.watchdog.failed()
    }
}

/// A failure every rank agrees on: `Err` on every rank where any rank's `result` is `Err`
/// (the failing ranks print their own message, rank 0 names them).
fn agree<T>(world: &SimpleCommunicator, what: &str, result: Result<T, String>) -> Result<T, String> {
    let rank = world.rank();
    let bad = i32::from(result.is_err());
    let mut all = vec![0i32; world.size() as usize];
    world.all_gather_into(&bad, &mut all[..]);
    if let Err(e) = &result {
        eprintln!("volwarp-server (rank {rank}): {what}: {e}");
    }
    let failed: Vec<usize> = all.iter().enumerate().filter(|(_, &b)| b != 0).map(|(r, _)| r).collect();
    match (result, failed.is_empty()) {
        (Ok(v), true) => Ok(v),
        (Err(e), _) => Err(e),
        (Ok(_), false) => Err(format!("{what} failed on rank(s) {failed:?}")),
    }
}

/// Runs `job` on `mpiexec`'s ranks (every rank calls this; rank 0 does the job, the others
/// serve frames until rank 0 is done). Returns the error to print; every rank of a failed
/// launch returns one.
pub fn run(launch: Launch, job: Job) -> Result<(), String> {
    let (universe, _) =
        mpi::initialize_with_threading(mpi::Threading::Funneled).ok_or("MPI is already initialized or cannot start")?;
    let world = universe.world();
    // A failed peer makes MPI calls return (their results then fail the frame's checks, or the
    // watchdog's timeout fires) instead of aborting rank 0 before it can tell its clients.
    // SAFETY: the communicator is valid for the universe's life; MPI_ERRORS_RETURN is a
    // predefined handler.
    unsafe {
        mpi::ffi::MPI_Comm_set_errhandler(world.as_raw(), mpi::ffi::RSMPI_ERRORS_RETURN);
    }
    let (rank, size) = (world.rank() as usize, world.size() as usize);
    // The same file on every rank: its dims, voxel spacing and size.
    let fingerprint = |path: &std::path::Path| -> Result<[u64; 5], String> {
        let dims = decomposition::volume_dims(path, &launch.load).map_err(|e| e.to_string())?;
        let len = std::fs::metadata(path).map_err(|e| format!("{}: {e}", path.display()))?.len();
        Ok([dims[0].into(), dims[1].into(), dims[2].into(), len, 0])
    };
    let fp = agree(&world, "opening the volume", fingerprint(&launch.volume))?;
    let mut all = vec![0u64; 5 * size];
    world.all_gather_into(&fp[..], &mut all[..]);
    if let Some(r) = (1..size).find(|&r| all[5 * r..5 * r + 5] != all[..5]) {
        return Err(format!(
            "rank {r} sees {} as {:?} (dims, bytes), rank 0 as {:?}: every rank must read the same file",
            launch.volume.display(),
            &all[5 * r..5 * r + 4],
            &all[..4]
        ));
    }
    let dims = [fp[0] as u32, fp[1] as u32, fp[2] as u32];
    let dec = Arc::new(agree(&world, "splitting the volume", Decomposition::new(dims, size))?);
    let t_load = Instant::now();
    let data = agree(
        &world,
        "reading this rank's part",
        decomposition::read_part(&launch.volume, &launch.load, &dec, rank).map_err(|e| e.to_string()),
    )?;
    let (mut lo, mut hi) = (0.0f32, 0.0f32);
    world.all_reduce_into(&data.range.0, &mut lo, SystemOperation::min());
    world.all_reduce_into(&data.range.1, &mut hi, SystemOperation::max());
    let name = data.name.clone();
    let spacing = data.spacing;
    let held = data.part.held_dims();
    let volume = agree(&world, "building this rank's part", data.into_volume((lo, hi)).map_err(|e| e.to_string()))?;
    let tf = match &launch.tf {
        Some(p) => TransferFunction::load(p, volume.value_range()).map_err(|e| e.to_string()),
        None => Ok(TransferFunction::preset_for(&name, dims)),
    };
    let tf = agree(&world, "loading the transfer function", tf)?;
    log::info!(
        "rank {rank}/{size} (pid {}): part {:?}..{:?} of {dims:?} ({held:?} held, {:.1} MiB) read in {:.2} s",
        std::process::id(),
        dec.parts[rank].lo,
        dec.parts[rank].hi,
        volume.memory_bytes() as f64 / (1u64 << 20) as f64,
        t_load.elapsed().as_secs_f64()
    );
    let volume = Arc::new(volume);
    let part = PartMarcher::new(volume.clone(), dec.clone(), rank, &tf, launch.opts)?;
    let geometry = FrameGeometry { dims, spacing, opts: part.options() };
    if rank != 0 {
        let root = world.process_at_rank(0);
        let fault = Fault::from_env(rank);
        let mut frames = 0u64;
        let mut bufs = Buffers::default();
        loop {
            let mut cmd = [0u8; CMD_LEN];
            mpi::request::scope(|scope| wait_idle(root.immediate_broadcast_into(scope, &mut cmd[..])));
            match decode_cmd(&cmd) {
                Some((req, layers, assemble)) => {
                    frames += 1;
                    let fault = fault.filter(|f| f.frame == frames);
                    frame_collective(&world, &part, &mut bufs, &geometry, (&req, layers, assemble), fault);
                }
                None => return Ok(()),
            }
        }
    }
    let watchdog = Watchdog::spawn(launch.rank_timeout);
    let root = world.process_at_rank(0);
    let bufs = std::cell::RefCell::new(Buffers::default());
    let frame = |req: &CameraRequest, layers: u32, assemble: bool| -> Result<(Collected, FrameStats), String> {
        if layers <= 1 {
            super::one_sample_heuristic(req.heuristic)?;
        }
        // MPI counts and displacements are 32-bit: the most bytes a frame's segments may take.
        let k = u64::from(layers.clamp(1, volwarp_core::segments::MAX_LAYERS as u32));
        let pixels = u64::from(req.camera.width) * u64::from(req.camera.height);
        if pixels * (1 + super::partial::SEG_BYTES as u64 * k) > i32::MAX as u64 {
            return Err(format!(
                "a {}x{} frame of {k} segments per pixel is too large for the exchange between MPI ranks \
                 (2 GiB of segments): ask for fewer pixels or segments",
                req.camera.width, req.camera.height
            ));
        }
        let t0 = Instant::now();
        watchdog.start();
        let mut cmd = encode_cmd(req, layers, assemble);
        // Nonblocking, as the other ranks wait for it (a blocking collective does not match a
        // nonblocking one).
        mpi::request::scope(|scope| wait_yielding(root.immediate_broadcast_into(scope, &mut cmd[..])));
        let (collected, stats) =
            match frame_collective(&world, &part, &mut bufs.borrow_mut(), &geometry, (req, layers, assemble), None) {
                Some(Ok(r)) => r,
                Some(Err(e)) => watchdog.fail(e),
                None => watchdog.fail("rank 0 got no frame".into()),
            };
        watchdog.done();
        let total = t0.elapsed().as_micros() as u64;
        let march = stats.iter().map(|s| s.march_us).max().unwrap_or(0);
        let march_min = stats.iter().map(|s| s.march_us).min().unwrap_or(0);
        let bytes_max = stats.iter().map(|s| s.bytes_sent).max().unwrap_or(0);
        let bytes_mean = stats.iter().map(|s| s.bytes_sent).sum::<u64>() / size.max(1) as u64;
        let slowest = |f: fn(&RankStats) -> u64| stats.iter().map(f).max().unwrap_or(0);
        let ms = |us: u64| us as f64 / 1e3;
        log::info!(
            "mpi frame {}x{} K={layers}: ranks={size} total_ms={:.1} march_max_ms={:.1} march_min_ms={:.1} \
             encode_ms={:.1} exchange_ms={:.1} merge_ms={:.1} decode_ms={:.1} gather_ms={:.1} \
             bytes_per_rank_max={bytes_max} bytes_per_rank_mean={bytes_mean}",
            req.camera.width,
            req.camera.height,
            ms(total),
            ms(march),
            ms(march_min),
            ms(slowest(|s| s.encode_us)),
            ms(slowest(|s| s.exchange_us)),
            ms(slowest(|s| s.merge_us)),
            ms(slowest(|s| s.decode_us)),
            ms(slowest(|s| s.gather_us)),
        );
        let samples = match &collected {
            Collected::Bands(bands) => bands.iter().map(|b| b.segs.len()).sum(),
            Collected::Frame(f) => f.samples.len(),
        };
        let fs = FrameStats {
            march_us: march,
            compact_us: total.saturating_sub(march),
            samples,
            pixels: (req.camera.width * req.camera.height) as usize,
        };
        Ok((collected, fs))
    };
    let default_camera = {
        let b = geometry.bounds();
        let f = Camera::framing(b.min(), b.max(), 0.0, 0.0, 30.0, 1, 1);
        let dist = (f.eye - f.target).length();
        Camera::look_at(f.target + Vec3::Y * dist, f.target, Vec3::Z, 30.0, 1, 1)
    };
    let result = match job {
        Job::Render(camera, write) => (|| {
            let cam = camera(default_camera)?;
            let req =
                CameraRequest { seq: 0, camera: cam, heuristic: Heuristic::Threshold, radius_scale: 1.0, layers: 0 };
            let Collected::Bands(bands) = frame(&req, volwarp_core::segments::DEFAULT_LAYERS as u32, false)?.0 else {
                return Err("rank 0 gathered no bands".into());
            };
            write(super::image(cam.width, cam.height, &bands))
        })(),
        Job::Dump(request, layers, frames, encoding, write) => (|| {
            let req = request(default_camera)?;
            // Earlier frames (`--frames`) only time the steady state; the last is written.
            for _ in 1..frames {
                frame(&req, layers, true)?;
            }
            let (Collected::Frame(mut f), stats) = frame(&req, layers, true)? else {
                return Err("rank 0 gathered no frame".into());
            };
            // The band owners assembled the frame's samples (their merge time), rank 0 joined
            // them (its gather time): what is left is the header.
            let t = Instant::now();
            f.header.render_us = (stats.march_us + stats.compact_us).min(u32::MAX as u64) as u32;
            let t_frame = t.elapsed();
            let (bytes, got) = geometry.encode(&req, &f, encoding, true);
            log::info!(
                "mpi frame assembly_ms={:.1} encode_ms={:.1}",
                t_frame.as_secs_f64() * 1e3,
                (t.elapsed() - t_frame).as_secs_f64() * 1e3
            );
            write(&f, bytes, got, &stats)
        })(),
        Job::Serve(config, ready) => (|| {
            let (tx, rx) = mpsc::channel::<FrameJob>();
            let source = Arc::new(Source { jobs: Mutex::new(tx), geometry, watchdog: watchdog.clone() });
            // The marcher only names the volume in the server's log.
            let marcher = Marcher::new(volume.clone(), &tf);
            let server =
                Server::with_marcher(config, Arc::new(marcher)).map_err(|e| e.to_string())?.with_source(source);
            ready(server.local_addr());
            let handle = Arc::new(server.spawn());
            let h = handle.clone();
            *watchdog.clients.lock().unwrap_or_else(|e| e.into_inner()) = Some(Box::new(move || h.active_clients()));
            for (req, layers, reply) in rx {
                let (f, stats) = match frame(&req, layers, true) {
                    Ok((Collected::Frame(f), stats)) => (f, stats),
                    Ok(_) => {
                        let _ = reply.send(Err("rank 0 gathered no frame".into()));
                        continue;
                    }
                    Err(e) => {
                        let _ = reply.send(Err(e));
                        continue;
                    }
                };
                let f = Frame {
                    header: volwarp_core::wire::FrameHeader {
                        render_us: (stats.march_us + stats.compact_us).min(u32::MAX as u64) as u32,
                        ..f.header
                    },
                    ..f
                };
                let _ = reply.send(Ok((f, stats)));
            }
            Ok(())
        })(),
    };
    let mut quit = [CMD_QUIT; CMD_LEN];
    mpi::request::scope(|scope| wait_yielding(root.immediate_broadcast_into(scope, &mut quit[..])));
    result
}
