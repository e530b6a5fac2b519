//! Sharing one marcher pool between clients.
//!
//! Every client's frame runs on the same rayon pool: a request becomes one job in the pool's
//! first-in-first-out injector queue, behind the jobs already waiting, and its row bands are
//! shared out to whichever threads are free; a client asks for its next frame only after it
//! got the last one, so it queues behind every other waiting client and none can starve
//! another (each waits at most for the frames queued before it). A small frame is not held
//! up behind a large one: both run at once. (A first-come-first-served lock around whole
//! frames was tried first: a 48² frame then waited for a 512² one and missed a 1.5 s idle
//! timeout on the loaded test machine.)
//!
//! A request identical to one being rendered or just rendered (same camera, viewport,
//! heuristic and radius scale; any sequence number) is answered with a copy of that render
//! instead of a second one.

use crate::marcher::{FrameStats, Marcher};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use volwarp_core::wire::{CameraRequest, Frame};

/// What makes two requests render the same frame (everything but the sequence number).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Key([u32; 15]);

impl Key {
    fn of(req: &CameraRequest, layers: u32) -> Key {
        let c = &req.camera;
        Key([
            c.eye.x.to_bits(),
            c.eye.y.to_bits(),
            c.eye.z.to_bits(),
            c.target.x.to_bits(),
            c.target.y.to_bits(),
            c.target.z.to_bits(),
            c.up.x.to_bits(),
            c.up.y.to_bits(),
            c.up.z.to_bits(),
            c.fov_y_deg.to_bits(),
            c.width,
            c.height,
            req.heuristic.code() as u32,
            req.radius_scale.to_bits(),
            layers.max(1),
        ])
    }
}

#[derive(Default)]
struct State {
    /// Keys being rendered.
    in_flight: Vec<Key>,
    /// The last frame rendered, for requests identical to it.
    last: Option<(Key, Arc<Frame>)>,
}

/// Counts of the renders done and avoided.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RenderCounts {
    /// Frames marched.
    pub rendered: u64,
    /// Requests answered with a copy of an identical request's frame.
    pub shared: u64,
}

/// The shared render queue in front of one marcher and its thread pool.
pub struct RenderQueue {
    marcher: Arc<Marcher>,
    pool: rayon::ThreadPool,
    state: Mutex<State>,
    /// Signalled when a render ends.
    done: Condvar,
    rendered: AtomicU64,
    shared: AtomicU64,
}

/// Ends a key's flight when dropped (also when the render panics), waking its waiters.
struct Flight<'a>(&'a RenderQueue, Key);

impl Drop for Flight<'_> {
    fn drop(&mut self) {
        let mut s = self.0.lock();
        s.in_flight.retain(|k| *k != self.1);
        self.0.done.notify_all();
    }
}

impl RenderQueue {
    /// A queue rendering with `marcher` on `pool`.
    pub fn new(marcher: Arc<Marcher>, pool: rayon::ThreadPool) -> RenderQueue {
        RenderQueue {
            marcher,
            pool,
            state: Mutex::new(State::default()),
            done: Condvar::new(),
            rendered: AtomicU64::new(0),
            shared: AtomicU64::new(0),
        }
    }

    /// The marcher.
    pub fn marcher(&self) -> &Arc<Marcher> {
        &self.marcher
    }

    /// Renders `req` into `frame` (its vectors reused) on the shared pool, or copies the frame
    /// of an identical request rendered meanwhile; the header is `req`'s (its `seq`).
    /// The stats are the render's (zero times for a copy).
    pub fn render(&self, req: &CameraRequest, frame: &mut Frame) -> FrameStats {
        self.render_layers(req, 1, frame)
    }

    /// [`RenderQueue::render`] of a layered frame with at most `layers` segments per pixel
    /// ([`Marcher::render_frame_layers_into`]; 1 is [`RenderQueue::render`]).
    pub fn render_layers(&self, req: &CameraRequest, layers: u32, frame: &mut Frame) -> FrameStats {
        let key = Key::of(req, layers);
        let mut s = self.lock();
        loop {
            if let Some((k, f)) = &s.last {
                if *k == key {
                    let f = f.clone();
                    drop(s);
                    self.shared.fetch_add(1, Ordering::Relaxed);
                    frame.header = f.header;
                    frame.header.seq = req.seq;
                    frame.samples.clear();
                    frame.samples.extend_from_slice(&f.samples);
                    frame.colors.clear();
                    frame.colors.extend_from_slice(&f.colors);
                    frame.segments.clear();
                    frame.segments.extend_from_slice(&f.segments);
                    return FrameStats {
                        samples: f.samples.len(),
                        pixels: f.header.camera.width as usize * f.header.camera.height as usize,
                        ..FrameStats::default()
                    };
                }
            }
            if !s.in_flight.contains(&key) {
                break;
            }
            // An identical request is queued or rendering: wait for its frame.
            s = self.done.wait(s).unwrap_or_else(|e| e.into_inner());
        }
        s.in_flight.push(key);
        drop(s);
        let flight = Flight(self, key);
        let stats = self.pool.install(|| self.marcher.render_frame_layers_into(req, layers, frame));
        self.rendered.fetch_add(1, Ordering::Relaxed);
        // Keep a copy for identical requests (published before the flight ends), reusing the
        // previous copy's memory when no client holds it any more.
        let mut old = self.lock().last.take().map(|(_, f)| f);
        let copy = match old.as_mut().and_then(Arc::get_mut) {
            Some(f) => {
                f.header = frame.header;
                f.samples.clear();
                f.samples.extend_from_slice(&frame.samples);
                f.colors.clear();
                f.colors.extend_from_slice(&frame.colors);
                f.segments.clear();
                f.segments.extend_from_slice(&frame.segments);
                old.take().unwrap_or_else(|| Arc::new(frame.clone()))
            }
            None => Arc::new(frame.clone()),
        };
        self.lock().last = Some((key, copy));
        drop(flight);
        stats
    }

    /// Frames rendered and requests answered with a copy so far.
    pub fn counts(&self) -> RenderCounts {
        RenderCounts { rendered: self.rendered.load(Ordering::Relaxed), shared: self.shared.load(Ordering::Relaxed) }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }
}
