//! Sharing one marcher pool between clients.
//!
//! Every client's frame runs on the same rayon pool, its row bands shared out to every thread.
//! **Large frames take turns, first come first served** (a ticket [`Gate`]): one large frame
//! marches at a time, in the order the requests came, so each waits at most for the frames
//! asked for before it, and as a client asks for its next frame only after it got the last one,
//! every busy client gets the same share. (Entering the pool all at once, as the first version
//! did, let a worker waiting inside one frame's parallel split take up another frame's job, so
//! the frame it was in ended only after that one: with four clients asking for equal MRI frames
//! at 512², the fastest got 2.1× the frames of the slowest, `docs/perf.md`.) **Small frames**
//! (at most [`SMALL_FRAME`] pixels) skip the line and run beside a large one: a 48² frame never
//! waits for a 512² one (a lock around every frame was tried first and made a small frame miss
//! a 1.5 s idle timeout on a loaded test machine).
//!
//! A request identical to one being rendered or just rendered (same camera, viewport,
//! heuristic, radius scale and level of detail; any sequence number) is answered with a copy of
//! that render instead of a second one.
//!
//! **Levels of detail.** A queue may hold marchers of ever coarser copies of the volume
//! ([`crate::volume::pyramid`]) and a frame-time budget ([`LevelPolicy`]): while a client's
//! camera moves, its frames come from the finest level whose predicted time fits the budget;
//! when the camera rests, from the volume itself. The prediction is the last measured time per
//! pixel of that level, or of the nearest measured one scaled by [`LEVEL_RATIO`] per level (a
//! level has half the samples per ray of the one before, but the per-pixel work does not
//! shrink, so a level measures 0.5–0.8 of the one before: 0.7 errs towards the coarser level,
//! and the next frame's measurement corrects it both ways).

use crate::marcher::{FrameStats, Marcher};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::Duration;
use volwarp_core::wire::{CameraRequest, Frame};

/// What makes two requests render the same frame (everything but the sequence number).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Key([u32; 17]);

impl Key {
    fn of(req: &CameraRequest, layers: u32, level: u8, generation: u32) -> Key {
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
            level as u32,
            generation,
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
    /// Renders stopped part-way ([`RenderQueue::render_view_until`]) and not published.
    pub stopped: u64,
}

/// Frames of at most this many pixels do not take a turn at the [`Gate`] (128², a thumbnail or
/// a test's frame; the client's views are 512² and up).
pub const SMALL_FRAME: u64 = 128 * 128;

/// First come, first served by ticket: [`Gate::enter`] waits until every earlier ticket has
/// left (its [`Turn`] dropped, also when the render panics).
#[derive(Default)]
pub struct Gate {
    /// (next ticket to hand out, ticket being served).
    tickets: Mutex<(u64, u64)>,
    turn: Condvar,
}

/// A ticket's turn at the [`Gate`]: the next ticket is served once it is dropped.
pub struct Turn<'a>(&'a Gate);

impl Gate {
    /// A ticket: the place in line, in the order of the calls.
    pub fn ticket(&self) -> u64 {
        let mut t = self.lock();
        t.0 += 1;
        t.0 - 1
    }

    /// Waits until `ticket` is served.
    pub fn enter(&self, ticket: u64) -> Turn<'_> {
        let mut t = self.lock();
        while t.1 != ticket {
            t = self.turn.wait(t).unwrap_or_else(|e| e.into_inner());
        }
        Turn(self)
    }

    fn lock(&self) -> MutexGuard<'_, (u64, u64)> {
        self.tickets.lock().unwrap_or_else(|e| e.into_inner())
    }
}

impl Drop for Turn<'_> {
    fn drop(&mut self) {
        self.0.lock().1 += 1;
        self.0.turn.notify_all();
    }
}

/// The predicted time of a level against the next finer one (see the module docs).
pub const LEVEL_RATIO: f64 = 0.7;

/// How a queue picks the level of detail of a frame (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LevelPolicy {
    /// The frame time to keep within while the camera moves (`None`: always the volume itself).
    pub budget: Option<Duration>,
}

impl LevelPolicy {
    /// The level for a frame of `pixels` pixels: 0 unless `moving` under a budget, else the
    /// finest level predicted to fit it (the coarsest if none is), from `cost`, each level's
    /// last measured nanoseconds per pixel (`None`: not measured yet).
    pub fn pick(&self, moving: bool, pixels: u64, cost: &[Option<f64>]) -> u8 {
        let Some(budget) = self.budget.filter(|_| moving && cost.len() > 1) else {
            return 0;
        };
        let budget_ns = budget.as_nanos() as f64;
        for l in 0..cost.len() {
            // The nearest measured level, scaled by LEVEL_RATIO per level between them.
            let predicted = (0..cost.len())
                .filter_map(|m| cost[m].map(|c| (m, c)))
                .min_by_key(|&(m, _)| m.abs_diff(l))
                .map(|(m, c)| c * pixels as f64 * LEVEL_RATIO.powi(l as i32 - m as i32));
            match predicted {
                Some(t) if t <= budget_ns => return l as u8,
                None => return 0,
                _ => {}
            }
        }
        (cost.len() - 1) as u8
    }
}

/// The shared render queue in front of one marcher (or one per level of detail) and its
/// thread pool.
pub struct RenderQueue {
    /// The marchers, level 0 (the volume itself) first.
    levels: Vec<Arc<Marcher>>,
    policy: LevelPolicy,
    /// Per level, the last measured render nanoseconds per pixel.
    cost: Mutex<Vec<Option<f64>>>,
    pool: rayon::ThreadPool,
    state: Mutex<State>,
    /// Large frames' turns.
    gate: Gate,
    /// Signalled when a render ends.
    done: Condvar,
    rendered: AtomicU64,
    shared: AtomicU64,
    stopped: AtomicU64,
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
        RenderQueue::with_levels(vec![marcher], LevelPolicy::default(), pool)
    }

    /// A queue rendering with the marchers of `levels` (level 0, the volume itself, first; at
    /// least one) as `policy` picks, on `pool`.
    pub fn with_levels(levels: Vec<Arc<Marcher>>, policy: LevelPolicy, pool: rayon::ThreadPool) -> RenderQueue {
        assert!(!levels.is_empty(), "a render queue needs a marcher");
        RenderQueue {
            cost: Mutex::new(vec![None; levels.len()]),
            levels,
            policy,
            pool,
            state: Mutex::new(State::default()),
            gate: Gate::default(),
            done: Condvar::new(),
            rendered: AtomicU64::new(0),
            shared: AtomicU64::new(0),
            stopped: AtomicU64::new(0),
        }
    }

    /// The marcher of the volume itself (level 0).
    pub fn marcher(&self) -> &Arc<Marcher> {
        &self.levels[0]
    }

    /// The marchers, one per level of detail.
    pub fn levels(&self) -> &[Arc<Marcher>] {
        &self.levels
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
        self.render_view(req, layers, false, frame)
    }

    /// [`RenderQueue::render_layers`] for a camera that is `moving` (it differs from the
    /// client's last request): under a [`LevelPolicy`] budget, from a coarser level of detail.
    pub fn render_view(&self, req: &CameraRequest, layers: u32, moving: bool, frame: &mut Frame) -> FrameStats {
        self.render_view_until(&self.levels, 0, req, layers, moving, frame, &crate::marcher::NEVER).unwrap_or_default()
    }

    /// [`RenderQueue::render_view`] with other marchers of the same volume and levels (a
    /// client's own visual state, [`Marcher::with_visual_tf`]), `generation` naming them: only
    /// requests of the same generation share a frame (0: the queue's own marchers). It gives up
    /// once `stop` is set, while it waits for its turn or marches
    /// ([`Marcher::render_frame_layers_until`]): `None`, `frame` holds nothing to send, and
    /// nothing is published for identical requests (one waiting for this render renders itself).
    #[allow(clippy::too_many_arguments)]
    pub fn render_view_until(
        &self,
        levels: &[Arc<Marcher>],
        generation: u32,
        req: &CameraRequest,
        layers: u32,
        moving: bool,
        frame: &mut Frame,
        stop: &AtomicBool,
    ) -> Option<FrameStats> {
        let levels = if levels.is_empty() { &self.levels[..] } else { levels };
        let pixels = req.camera.width as u64 * req.camera.height as u64;
        let level = {
            let cost = self.cost.lock().unwrap_or_else(|e| e.into_inner());
            self.policy.pick(moving, pixels, &cost)
        };
        let marcher = &levels[usize::from(level).min(levels.len() - 1)];
        let key = Key::of(req, layers, level, generation);
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
                    return Some(FrameStats {
                        samples: f.samples.len(),
                        pixels: f.header.camera.width as usize * f.header.camera.height as usize,
                        ..FrameStats::default()
                    });
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
        let turn = (pixels > SMALL_FRAME).then(|| self.gate.enter(self.gate.ticket()));
        let stats = self.pool.install(|| marcher.render_frame_layers_until(req, layers, frame, stop));
        drop(turn);
        let Some(stats) = stats else {
            self.stopped.fetch_add(1, Ordering::Relaxed);
            return None;
        };
        if levels.len() > 1 {
            let ns = (stats.march_us + stats.compact_us) as f64 * 1e3 / pixels.max(1) as f64;
            self.cost.lock().unwrap_or_else(|e| e.into_inner())[usize::from(level)] = Some(ns);
        }
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
        Some(stats)
    }

    /// Frames rendered, requests answered with a copy and renders stopped so far.
    pub fn counts(&self) -> RenderCounts {
        RenderCounts {
            rendered: self.rendered.load(Ordering::Relaxed),
            shared: self.shared.load(Ordering::Relaxed),
            stopped: self.stopped.load(Ordering::Relaxed),
        }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_policy_picks_the_finest_level_within_the_budget_while_moving() {
        let p = LevelPolicy { budget: Some(Duration::from_millis(50)) };
        let px = 1_000_000;
        // 100 ns per pixel at level 0: 100 ms; level 2 predicted at 49 ms.
        let cost = [Some(100.0), None, None, None];
        assert_eq!(p.pick(true, px, &cost), 2);
        assert_eq!(p.pick(false, px, &cost), 0, "a resting camera gets the volume itself");
        // Measured levels win over predictions (level 1 at 40 ms; a measured coarse level
        // predicts the finer ones: 30 / 0.7 = 43 ms fits); nothing fits: the coarsest.
        assert_eq!(p.pick(true, px, &[Some(100.0), Some(40.0), None, None]), 1);
        assert_eq!(p.pick(true, px, &[Some(900.0), None, None, Some(30.0)]), 2);
        assert_eq!(p.pick(true, px, &[Some(9e3), None, None, Some(900.0)]), 3);
        // Nothing measured yet: the volume itself (measured then); no budget: always 0.
        assert_eq!(p.pick(true, px, &[None, None]), 0);
        assert_eq!(LevelPolicy::default().pick(true, px, &cost), 0);
        assert_eq!(p.pick(true, px, &[Some(9e3)]), 0, "one level only");
    }

    /// A stopped render gives no frame and publishes none: an identical request afterwards
    /// is marched, not copied, and its frame is the one-process render.
    #[test]
    fn a_stopped_render_is_not_published() {
        let marcher = Arc::new(Marcher::from_dataset(&crate::Dataset::default_bundled()));
        let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
        let queue = RenderQueue::new(marcher.clone(), pool);
        let req = CameraRequest {
            seq: 1,
            camera: marcher.default_camera(200, 150),
            heuristic: volwarp_core::Heuristic::Threshold,
            radius_scale: 1.0,
            layers: 0,
        };
        let mut frame = marcher.empty_frame();
        let stop = AtomicBool::new(true);
        for layers in [1, 4] {
            assert_eq!(queue.render_view_until(&[], 0, &req, layers, false, &mut frame, &stop), None);
        }
        assert_eq!(queue.counts(), RenderCounts { rendered: 0, shared: 0, stopped: 2 });
        let stats = queue.render_view_until(&[], 0, &req, 4, false, &mut frame, &AtomicBool::new(false));
        assert!(stats.is_some_and(|s| s.samples > 0));
        assert_eq!(queue.counts(), RenderCounts { rendered: 1, shared: 0, stopped: 2 });
        let (one, _) = marcher.render_frame_layers(&req, 4);
        assert_eq!((frame.samples, frame.colors, frame.segments), (one.samples, one.colors, one.segments));
    }

    /// Tickets are served in the order they were handed out, whatever order their holders
    /// arrive at the gate in.
    #[test]
    fn the_gate_serves_tickets_in_order() {
        let gate = Arc::new(Gate::default());
        let order = Arc::new(Mutex::new(Vec::new()));
        let tickets: Vec<u64> = (0..6).map(|_| gate.ticket()).collect();
        let threads: Vec<_> = tickets
            .iter()
            .rev()
            .map(|&t| {
                let (gate, order) = (gate.clone(), order.clone());
                std::thread::spawn(move || {
                    let _turn = gate.enter(t);
                    order.lock().unwrap().push(t);
                })
            })
            .collect();
        for t in threads {
            t.join().unwrap();
        }
        assert_eq!(*order.lock().unwrap(), tickets);
    }

    /// A holder that panics still hands the turn on.
    #[test]
    fn a_panicking_turn_hands_on() {
        let gate = Arc::new(Gate::default());
        let (a, b) = (gate.ticket(), gate.ticket());
        let g = gate.clone();
        let r = std::thread::spawn(move || {
            let _turn = g.enter(a);
            panic!("render failed");
        })
        .join();
        assert!(r.is_err());
        drop(gate.enter(b));
    }
}
