//! The ZAL12 representative-depth heuristics, as small state machines.
//!
//! The marcher feeds every classified sample along a ray, front to back, with
//! [`DepthPicker::feed`]: the ray parameter `t`, the sample's own opacity `src_a` (after
//! opacity correction) and the accumulated opacity `dst_a` **after** compositing that sample.
//! [`DepthPicker::finish`] then gives the representative depth, or `None` for an empty ray.
//!
//! Two heuristics need the whole ray before they can decide ([`Heuristic::needs_first_pass`]):
//! the marcher runs the ray once into a [`FirstPassAccumulator`], then again into a
//! [`DepthPicker`] built with that [`FirstPass`].
//!
//! **When nothing qualifies.** A ray whose final accumulated opacity is at most
//! [`EMPTY_ALPHA`] is *empty*: `finish` returns `None` and the sample gets radius 0. A ray that
//! is not empty but never meets its heuristic's criterion (possible for `Threshold`,
//! `RelThreshold` never, `EnExMean` when all opacities are equal) is placed at the ray's exit
//! from the volume box (`t_exit`), as the seed paper's code does. `Entrance`, `Exit`,
//! `Midpoint`, `Peak` and `Gradient` always qualify on a non-empty ray.

/// Accumulated opacity the `Threshold` heuristic waits for.
pub const THRESHOLD: f32 = 0.8;

/// Final accumulated opacity at or below which a ray counts as empty.
pub const EMPTY_ALPHA: f32 = 1e-8;

/// Which representative depth a pixel gets.
#[repr(u8)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Heuristic {
    /// First sample with `src_a > 0`.
    Entrance = 0,
    /// Last sample with `src_a > 0` (before early termination, if the marcher stops early).
    Exit = 1,
    /// `(entrance + exit) / 2` (the published code's `(exit - entrance) / 2` was a bug).
    Midpoint = 2,
    /// First sample where `dst_a > 0.8` (the seed paper's choice).
    Threshold = 3,
    /// Sample with the largest `src_a` (the first of equal maxima).
    Peak = 4,
    /// Sample with the largest step `dst_a - previous dst_a` (the first of equal maxima).
    Gradient = 5,
    /// Two passes: first sample where `dst_a > 0.8 × final dst_a`.
    RelThreshold = 6,
    /// Two passes: first sample whose `src_a` exceeds the mean of the entrance and exit `src_a`.
    EnExMean = 7,
}

impl Heuristic {
    /// All heuristics, in wire-code order.
    pub const ALL: [Heuristic; 8] = [
        Heuristic::Entrance,
        Heuristic::Exit,
        Heuristic::Midpoint,
        Heuristic::Threshold,
        Heuristic::Peak,
        Heuristic::Gradient,
        Heuristic::RelThreshold,
        Heuristic::EnExMean,
    ];

    /// The wire code.
    pub fn code(self) -> u8 {
        self as u8
    }

    /// The heuristic with this wire code.
    pub fn from_code(code: u8) -> Option<Heuristic> {
        Heuristic::ALL.get(code as usize).copied()
    }

    /// The short kebab-case name used on command lines and in CSV files.
    pub fn name(self) -> &'static str {
        match self {
            Heuristic::Entrance => "entrance",
            Heuristic::Exit => "exit",
            Heuristic::Midpoint => "midpoint",
            Heuristic::Threshold => "threshold",
            Heuristic::Peak => "peak",
            Heuristic::Gradient => "gradient",
            Heuristic::RelThreshold => "rel-threshold",
            Heuristic::EnExMean => "en-ex-mean",
        }
    }

    /// Parses [`Heuristic::name`].
    pub fn from_name(name: &str) -> Option<Heuristic> {
        Heuristic::ALL.iter().copied().find(|h| h.name() == name)
    }

    /// Whether the marcher must run a first pass (into a [`FirstPassAccumulator`]).
    pub fn needs_first_pass(self) -> bool {
        matches!(self, Heuristic::RelThreshold | Heuristic::EnExMean)
    }
}

impl core::fmt::Display for Heuristic {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.name())
    }
}

/// What the two-pass heuristics learn from the first pass.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FirstPass {
    /// Final accumulated opacity of the ray.
    pub final_alpha: f32,
    /// `src_a` of the entrance sample (0 if none).
    pub entrance_alpha: f32,
    /// `src_a` of the exit sample (0 if none).
    pub exit_alpha: f32,
}

/// Collects a [`FirstPass`] from one march of the ray.
#[derive(Clone, Copy, Debug, Default)]
pub struct FirstPassAccumulator {
    pass: FirstPass,
    seen: bool,
}

impl FirstPassAccumulator {
    /// An empty accumulator.
    pub fn new() -> Self {
        Self::default()
    }

    /// Feeds one classified sample (see the module docs).
    #[inline]
    pub fn feed(&mut self, src_a: f32, dst_a: f32) {
        if src_a > 0.0 {
            if !self.seen {
                self.pass.entrance_alpha = src_a;
                self.seen = true;
            }
            self.pass.exit_alpha = src_a;
        }
        self.pass.final_alpha = dst_a;
    }

    /// The result.
    pub fn finish(&self) -> FirstPass {
        self.pass
    }
}

/// The per-ray state machine of one heuristic.
#[derive(Clone, Copy, Debug)]
pub struct DepthPicker {
    heuristic: Heuristic,
    /// Criterion value for the threshold-like heuristics.
    target: f32,
    entrance: Option<f32>,
    exit: Option<f32>,
    chosen: Option<f32>,
    best: f32,
    prev_dst: f32,
    final_dst: f32,
}

impl DepthPicker {
    /// A picker for a one-pass heuristic, or a two-pass one with the first pass's result
    /// (`first` is ignored by one-pass heuristics; a two-pass heuristic without it behaves as if
    /// the first pass saw nothing and falls back to the volume exit).
    pub fn new(heuristic: Heuristic, first: Option<FirstPass>) -> Self {
        let target = match heuristic {
            Heuristic::Threshold => THRESHOLD,
            Heuristic::RelThreshold => first.map_or(f32::INFINITY, |f| THRESHOLD * f.final_alpha),
            Heuristic::EnExMean => first.map_or(f32::INFINITY, |f| 0.5 * (f.entrance_alpha + f.exit_alpha)),
            _ => 0.0,
        };
        DepthPicker {
            heuristic,
            target,
            entrance: None,
            exit: None,
            chosen: None,
            best: -1.0,
            prev_dst: 0.0,
            final_dst: 0.0,
        }
    }

    /// The heuristic this picker runs.
    pub fn heuristic(&self) -> Heuristic {
        self.heuristic
    }

    /// Whether the criterion is decided, so the marcher may stop early for depth purposes
    /// (it still has to composite the color to the end or to early termination).
    pub fn decided(&self) -> bool {
        match self.heuristic {
            Heuristic::Entrance | Heuristic::Threshold | Heuristic::RelThreshold | Heuristic::EnExMean => {
                self.chosen.is_some()
            }
            _ => false,
        }
    }

    /// For [`Heuristic::Threshold`] and [`Heuristic::RelThreshold`], the target of their
    /// criterion: [`DepthPicker::feed`] picks the first sample with `dst_a > target`. A marcher
    /// that feeds many rays at once in SIMD lanes can apply that one comparison lane-wise and
    /// hand the outcome back with [`DepthPicker::with_outcome`]; `None` for the others.
    pub fn threshold_target(&self) -> Option<f32> {
        matches!(self.heuristic, Heuristic::Threshold | Heuristic::RelThreshold).then_some(self.target)
    }

    /// This picker (of a heuristic with a [`DepthPicker::threshold_target`]) as if it had been
    /// fed a ray's samples whose first with `dst_a > target` lay at `chosen` and whose last left
    /// the accumulated opacity at `final_dst` (0 if none was fed): what
    /// [`DepthPicker::finish`] needs of a threshold-like heuristic.
    pub fn with_outcome(mut self, chosen: Option<f32>, final_dst: f32) -> Self {
        self.chosen = chosen;
        self.final_dst = final_dst;
        self
    }

    /// Feeds one classified sample: its ray parameter `t`, its own opacity `src_a` and the
    /// accumulated opacity `dst_a` after compositing it.
    #[inline]
    pub fn feed(&mut self, t: f32, src_a: f32, dst_a: f32) {
        if src_a > 0.0 {
            if self.entrance.is_none() {
                self.entrance = Some(t);
            }
            self.exit = Some(t);
        }
        match self.heuristic {
            Heuristic::Threshold | Heuristic::RelThreshold => {
                if self.chosen.is_none() && dst_a > self.target {
                    self.chosen = Some(t);
                }
            }
            Heuristic::EnExMean => {
                if self.chosen.is_none() && src_a > self.target {
                    self.chosen = Some(t);
                }
            }
            Heuristic::Peak => {
                if src_a > 0.0 && src_a > self.best {
                    self.best = src_a;
                    self.chosen = Some(t);
                }
            }
            Heuristic::Gradient => {
                let step = dst_a - self.prev_dst;
                if src_a > 0.0 && step > self.best {
                    self.best = step;
                    self.chosen = Some(t);
                }
            }
            Heuristic::Entrance | Heuristic::Exit | Heuristic::Midpoint => {}
        }
        self.prev_dst = dst_a;
        self.final_dst = dst_a;
    }

    /// The representative depth, `None` for an empty ray; `t_exit` is where the ray leaves the
    /// volume box (the fallback, see the module docs).
    pub fn finish(&self, t_exit: f32) -> Option<f32> {
        if !(self.final_dst > EMPTY_ALPHA) {
            return None;
        }
        let t = match self.heuristic {
            Heuristic::Entrance => self.entrance,
            Heuristic::Exit => self.exit,
            Heuristic::Midpoint => match (self.entrance, self.exit) {
                (Some(a), Some(b)) => Some((a + b) * 0.5),
                _ => None,
            },
            _ => self.chosen,
        };
        Some(t.unwrap_or(t_exit))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Composites a profile of source opacities at t = 0, 1, 2, … and runs a heuristic.
    fn run(h: Heuristic, src: &[f32]) -> Option<f32> {
        let composite = |feed: &mut dyn FnMut(f32, f32, f32)| {
            let mut dst = 0.0f32;
            for (i, &a) in src.iter().enumerate() {
                dst += (1.0 - dst) * a;
                feed(i as f32, a, dst);
            }
        };
        let first = if h.needs_first_pass() {
            let mut acc = FirstPassAccumulator::new();
            composite(&mut |_, a, d| acc.feed(a, d));
            Some(acc.finish())
        } else {
            None
        };
        let mut p = DepthPicker::new(h, first);
        composite(&mut |t, a, d| p.feed(t, a, d));
        p.finish(100.0)
    }

    use Heuristic::*;

    #[test]
    fn empty_ray_gives_none_for_every_heuristic() {
        for h in Heuristic::ALL {
            assert_eq!(run(h, &[0.0; 10]), None, "{h}");
            assert_eq!(run(h, &[]), None, "{h}");
            assert_eq!(run(h, &[0.0, 1e-9, 0.0]), None, "{h}: faint below EMPTY_ALPHA");
        }
    }

    #[test]
    fn single_opaque_slab() {
        // Opaque at t = 3..=5: everything lands on the slab's front except exit/midpoint.
        let p = [0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0];
        assert_eq!(run(Entrance, &p), Some(3.0));
        assert_eq!(run(Exit, &p), Some(5.0));
        assert_eq!(run(Midpoint, &p), Some(4.0));
        assert_eq!(run(Threshold, &p), Some(3.0));
        assert_eq!(run(Peak, &p), Some(3.0));
        assert_eq!(run(Gradient, &p), Some(3.0));
        assert_eq!(run(RelThreshold, &p), Some(3.0));
        // entrance and exit alpha are 1: nothing exceeds the mean -> volume exit.
        assert_eq!(run(EnExMean, &p), Some(100.0));
    }

    #[test]
    fn ramp_profile_has_distinct_answers() {
        // src: 0.1 at t=1, 0.5 at t=3, 0.2 at t=5, 0.05 at t=7
        let p = [0.0, 0.1, 0.0, 0.5, 0.0, 0.2, 0.0, 0.05, 0.0];
        // dst after each: 0.1, 0.55, 0.64, 0.658
        assert_eq!(run(Entrance, &p), Some(1.0));
        assert_eq!(run(Exit, &p), Some(7.0));
        assert_eq!(run(Midpoint, &p), Some(4.0));
        assert_eq!(run(Threshold, &p), Some(100.0), "0.8 never reached -> volume exit");
        assert_eq!(run(Peak, &p), Some(3.0));
        assert_eq!(run(Gradient, &p), Some(3.0)); // steps 0.1, 0.45, 0.09, 0.018
                                                  // 0.8 * 0.658 = 0.5264: first dst above is 0.55 at t = 3.
        assert_eq!(run(RelThreshold, &p), Some(3.0));
        // mean(0.1, 0.05) = 0.075: first src above is 0.1 at t = 1.
        assert_eq!(run(EnExMean, &p), Some(1.0));
    }

    #[test]
    fn gradient_differs_from_peak_when_the_front_is_already_dense() {
        // src 0.6 then 0.9: the second has the larger src but a smaller dst step (0.36 < 0.6).
        let p = [0.6, 0.9];
        assert_eq!(run(Peak, &p), Some(1.0));
        assert_eq!(run(Gradient, &p), Some(0.0));
        assert_eq!(run(Threshold, &p), Some(1.0)); // dst 0.6, then 0.96
    }

    #[test]
    fn en_ex_mean_picks_first_above_mean() {
        let p = [0.2, 0.1, 0.7, 0.3, 0.4];
        // mean(0.2, 0.4) = 0.3: first above is 0.7 at t = 2 (0.3 does not exceed).
        assert_eq!(run(EnExMean, &p), Some(2.0));
    }

    #[test]
    fn names_and_codes_round_trip() {
        for h in Heuristic::ALL {
            assert_eq!(Heuristic::from_name(h.name()), Some(h));
            assert_eq!(Heuristic::from_code(h.code()), Some(h));
        }
        assert_eq!(Heuristic::from_code(8), None);
        assert_eq!(Heuristic::from_name("nope"), None);
    }

    #[test]
    fn threshold_outcome_equals_feeding() {
        // Profiles of source opacities; the outcome a lane-wise feeder finds (first dst_a above
        // the target, the final dst_a) must give the fed picker's depth.
        let profiles: [&[f32]; 5] = [&[], &[0.0, 0.0], &[0.1, 0.5, 0.9, 0.2], &[0.05; 12], &[0.0, 1.0]];
        for h in [Heuristic::Threshold, Heuristic::RelThreshold] {
            for src in profiles {
                let first = FirstPass { entrance_alpha: 0.3, exit_alpha: 0.4, final_alpha: 0.9 };
                let mut fed = DepthPicker::new(h, Some(first));
                let target = fed.threshold_target().expect("a threshold-like heuristic");
                let (mut dst, mut chosen) = (0.0f32, None);
                for (i, &a) in src.iter().enumerate() {
                    if a > 0.0 {
                        dst += (1.0 - dst) * a;
                        fed.feed(i as f32, a, dst);
                        if chosen.is_none() && dst > target {
                            chosen = Some(i as f32);
                        }
                    }
                }
                let lanes = DepthPicker::new(h, Some(first)).with_outcome(chosen, dst);
                assert_eq!(lanes.finish(99.0), fed.finish(99.0), "{h:?} {src:?}");
            }
        }
        assert_eq!(DepthPicker::new(Heuristic::Peak, None).threshold_target(), None);
    }
}
