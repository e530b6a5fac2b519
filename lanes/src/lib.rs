//! # volwarp-lanes
//!
//! The one place that decides which SIMD lanes volwarp's kernels run on, for every crate that
//! has such kernels: the server's packet marcher, the CPU tracer's splatters and core's compact
//! frame codec.
//!
//! - **Detection once.** [`detected`] asks the CPU once (`is_x86_feature_detected!`, feature
//!   `std`; without it, what the build targets) and keeps the answer.
//! - **One override.** [`lane_kind`] is the detected level clamped by the environment
//!   variable `VOLWARP_LANES` (`portable`, `avx2` or `avx512`; read once, feature `std`;
//!   `VOLWARP_PORTABLE_SIMD`, set to anything, is the older spelling of `portable`) and by
//!   [`limit_lanes`], the programmatic limit that tests and benchmarks use. Every kind computes
//!   the same values, so the override only changes the speed.
//! - **Proof tokens.** [`Avx2Token`] and [`Avx512Token`] are zero-sized values that can only
//!   be obtained where the CPU has the features (as `pulp`'s and `safe_arch`'s tokens): a
//!   function holding one may call the code compiled for them. [`level`] hands out the token
//!   of the level [`lane_kind`] picks.
//! - **Base lane types.** [`Avx2`] and [`Avx512`] (x86-64, module [`x86`]): the registers
//!   and the operations every kernel shares, with one set of operator impls; a value exists
//!   only where the CPU has the features (the safe constructors take a token). The server's
//!   marcher lanes and the CPU tracer's lanes implement their traits on them.
//! - **One dispatch macro.** [`dispatch!`] defines a function that runs a kernel generic over
//!   its lanes on the level [`level`] picks: the kernel's instances compiled with
//!   `#[target_feature]`, or the portable one.
//!
//! The crate is `#![no_std]` so that core (no_std) can use it for its codec; it is a crate of
//! its own rather than a module of core because the lane levels are not part of core's
//! vocabulary and the server and the tracer need them without core's features.
#![no_std]
#![deny(missing_docs)]
#![deny(unsafe_op_in_unsafe_fn)]

#[cfg(feature = "std")]
extern crate std;

use core::ops::{Add, BitAnd, BitOr, Div, Mul, Sub};
use core::sync::atomic::{AtomicU8, Ordering};

#[cfg(target_arch = "x86_64")]
pub mod x86;
#[cfg(target_arch = "x86_64")]
pub use x86::{Avx2, Avx2I, Avx512, Avx512I};

/// Defines [`Ops`] as the operators `$op` and its blanket impl.
macro_rules! ops_trait {
    ($($op:ident),*) => {
        /// The operators every lane type has (`+ − × ÷`, and `& |` on masks): the common
        /// supertrait of the kernels' lane traits (implemented for every type that has them).
        pub trait Ops: Copy $(+ $op<Output = Self>)* {}
        impl<T: Copy $(+ $op<Output = T>)*> Ops for T {}
    };
}
ops_trait!(Add, Sub, Mul, Div, BitAnd, BitOr);

/// A level of SIMD lanes, narrowest first (the order [`limit_lanes`] clamps by).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum LaneKind {
    /// The build's baseline vectors (SSE2 on x86-64, NEON on aarch64), e.g. `wide`'s lanes.
    Portable = 0,
    /// AVX2 (256-bit registers), x86-64 only.
    Avx2 = 1,
    /// AVX-512 F and DQ (512-bit registers and mask registers), x86-64 only; every such CPU
    /// also has AVX2.
    Avx512 = 2,
}

impl LaneKind {
    /// The name `VOLWARP_LANES` gives this kind: `portable`, `avx2` or `avx512`.
    pub fn name(self) -> &'static str {
        match self {
            LaneKind::Portable => "portable",
            LaneKind::Avx2 => "avx2",
            LaneKind::Avx512 => "avx512",
        }
    }

    fn from_u8(v: u8) -> LaneKind {
        match v {
            0 => LaneKind::Portable,
            1 => LaneKind::Avx2,
            _ => LaneKind::Avx512,
        }
    }
}

/// A lane kind name that is none of `portable`, `avx2`, `avx512`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct UnknownLaneKind;

impl core::fmt::Display for UnknownLaneKind {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("unknown lane kind (portable, avx2 or avx512)")
    }
}

impl core::str::FromStr for LaneKind {
    type Err = UnknownLaneKind;
    /// `portable`, `avx2` or `avx512`, in any case.
    fn from_str(s: &str) -> Result<LaneKind, UnknownLaneKind> {
        [LaneKind::Portable, LaneKind::Avx2, LaneKind::Avx512]
            .into_iter()
            .find(|k| k.name().eq_ignore_ascii_case(s))
            .ok_or(UnknownLaneKind)
    }
}

/// A level kept in an atomic: 0 not decided yet, else 1 + the kind.
fn cached(state: &AtomicU8, decide: impl FnOnce() -> LaneKind) -> LaneKind {
    match state.load(Ordering::Relaxed) {
        0 => {
            let kind = decide();
            state.store(kind as u8 + 1, Ordering::Relaxed);
            kind
        }
        v => LaneKind::from_u8(v - 1),
    }
}

/// The widest lanes this CPU has, asked once (with `std`; without it, the widest the build
/// targets). Overrides do not change it: the tokens' `detected` constructors use it.
pub fn detected() -> LaneKind {
    static DETECTED: AtomicU8 = AtomicU8::new(0);
    cached(&DETECTED, detect)
}

#[cfg(all(feature = "std", target_arch = "x86_64"))]
fn detect() -> LaneKind {
    if std::is_x86_feature_detected!("avx512f")
        && std::is_x86_feature_detected!("avx512dq")
        && std::is_x86_feature_detected!("avx2")
    {
        LaneKind::Avx512
    } else if std::is_x86_feature_detected!("avx2") {
        LaneKind::Avx2
    } else {
        LaneKind::Portable
    }
}

#[cfg(not(all(feature = "std", target_arch = "x86_64")))]
fn detect() -> LaneKind {
    if cfg!(all(target_arch = "x86_64", target_feature = "avx512f", target_feature = "avx512dq")) {
        LaneKind::Avx512
    } else if cfg!(all(target_arch = "x86_64", target_feature = "avx2")) {
        LaneKind::Avx2
    } else {
        LaneKind::Portable
    }
}

/// The limit the environment sets, read once (feature `std`): `VOLWARP_LANES` (`portable`,
/// `avx2` or `avx512`; an unknown value sets none), else `portable` where
/// `VOLWARP_PORTABLE_SIMD` is set; `None` where neither is (or without `std`).
pub fn env_limit() -> Option<LaneKind> {
    // 0: not read yet, 1: no limit, 2 + kind: that limit.
    static ENV: AtomicU8 = AtomicU8::new(0);
    match ENV.load(Ordering::Relaxed) {
        0 => {
            let limit = read_env();
            ENV.store(limit.map_or(1, |k| k as u8 + 2), Ordering::Relaxed);
            limit
        }
        1 => None,
        v => Some(LaneKind::from_u8(v - 2)),
    }
}

#[cfg(feature = "std")]
fn read_env() -> Option<LaneKind> {
    match std::env::var("VOLWARP_LANES") {
        Ok(v) => v.parse().ok(),
        Err(_) => std::env::var_os("VOLWARP_PORTABLE_SIMD").map(|_| LaneKind::Portable),
    }
}

#[cfg(not(feature = "std"))]
fn read_env() -> Option<LaneKind> {
    None
}

static LIMIT: AtomicU8 = AtomicU8::new(LaneKind::Avx512 as u8);

/// Limits every kernel to lanes no wider than `kind` (process-wide, from now on; every kind
/// computes the same values). Tests run each kind the CPU has this way; `limit_lanes(Avx512)`
/// lifts the limit.
pub fn limit_lanes(kind: LaneKind) {
    LIMIT.store(kind as u8, Ordering::Relaxed);
}

/// [`detected`] clamped by [`env_limit`], worked out once.
fn ceiling() -> LaneKind {
    static CEILING: AtomicU8 = AtomicU8::new(0);
    cached(&CEILING, || match env_limit() {
        Some(env) => detected().min(env),
        None => detected(),
    })
}

/// The lanes the kernels use now: [`detected`], clamped by [`env_limit`] and [`limit_lanes`].
#[inline]
pub fn lane_kind() -> LaneKind {
    ceiling().min(LaneKind::from_u8(LIMIT.load(Ordering::Relaxed)))
}

/// [`lane_kind`] with the proof of its features: what [`dispatch!`] matches on.
#[derive(Clone, Copy, Debug)]
pub enum Level {
    /// The portable lanes.
    Portable,
    /// AVX2.
    #[cfg(target_arch = "x86_64")]
    Avx2(Avx2Token),
    /// AVX-512 F and DQ (and AVX2).
    #[cfg(target_arch = "x86_64")]
    Avx512(Avx512Token),
}

/// The level the kernels use now ([`lane_kind`]) and its token.
pub fn level() -> Level {
    match lane_kind() {
        #[cfg(target_arch = "x86_64")]
        LaneKind::Avx512 => Level::Avx512(Avx512Token(())),
        #[cfg(target_arch = "x86_64")]
        LaneKind::Avx2 => Level::Avx2(Avx2Token(())),
        _ => Level::Portable,
    }
}

/// A token type: proof of a lane kind's features, obtainable only where the CPU has them.
macro_rules! token {
    ($(#[$doc:meta])* $t:ident: $kind:ident, $features:literal) => {
        $(#[$doc])*
        #[cfg(target_arch = "x86_64")]
        #[derive(Clone, Copy, Debug)]
        pub struct $t(());

        #[cfg(target_arch = "x86_64")]
        impl $t {
            #[doc = concat!("The token where the kernels use ", $features, " now ([`lane_kind`], overrides applied).")]
            #[inline]
            pub fn new() -> Option<$t> {
                (lane_kind() >= LaneKind::$kind).then_some($t(()))
            }

            #[doc = concat!("The token where the CPU has ", $features, ", whatever the overrides (for tests that")]
            /// compare the instances with each other).
            #[inline]
            pub fn detected() -> Option<$t> {
                (detected() >= LaneKind::$kind).then_some($t(()))
            }

            /// The token without a check, for code that runs only where one was obtained before
            /// (a kernel's methods inside the instances [`dispatch!`] calls with a token).
            ///
            /// # Safety
            #[doc = concat!("The CPU must have ", $features, ".")]
            #[inline(always)]
            pub unsafe fn new_unchecked() -> $t {
                $t(())
            }
        }
    };
}

token!(
    /// Proof that the CPU has AVX2 (and so AVX, SSE4.2, …).
    Avx2Token: Avx2, "AVX2"
);
token!(
    /// Proof that the CPU has AVX-512 F and DQ, and AVX2.
    Avx512Token: Avx512, "AVX-512 F and DQ (and AVX2)"
);

#[cfg(target_arch = "x86_64")]
impl Avx512Token {
    /// Every CPU with AVX-512 F has AVX2.
    #[inline]
    pub fn avx2(self) -> Avx2Token {
        Avx2Token(())
    }
}

/// Defines `$name`, which runs the kernel `$kernel::<…>` on the lanes [`level`] picks, and
/// its instances compiled for wider lanes:
///
/// ```ignore
/// volwarp_lanes::dispatch! {
///     /// Docs of the dispatcher.
///     pub(crate) fn name / name_avx2 / name_avx512 => kernel(a: &[f32], b: u32) -> u64;
///     portable = [wide::f32x8], avx2 = [Avx2], avx512 = [Avx512]
/// }
/// ```
///
/// The bracketed lists are the kernel's generic arguments on each level (`kernel::<…>`). The
/// instance `$avx2` is the kernel compiled with AVX2, `$avx512` (optional: without it the
/// AVX-512 level takes the AVX2 instance) compiled with AVX2, AVX-512 F and DQ; both are
/// `unsafe fn`s whose caller guarantees those features (tests call them directly with a
/// token's `detected()`). All compute the same values where the kernel's lanes do.
#[macro_export]
macro_rules! dispatch {
    (
        $(#[$doc:meta])*
        $vis:vis fn $name:ident / $avx2:ident / $avx512:ident => $kernel:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)?;
        portable = [$($p:tt)*], avx2 = [$($a2:tt)*], avx512 = [$($a5:tt)*] $(,)?
    ) => {
        $(#[$doc])*
        #[allow(clippy::too_many_arguments)]
        $vis fn $name($($arg: $ty),*) $(-> $ret)? {
            match $crate::level() {
                // SAFETY: the token proves the CPU has AVX2, AVX-512 F and DQ.
                #[cfg(target_arch = "x86_64")]
                $crate::Level::Avx512(_) => unsafe { $avx512($($arg),*) },
                // SAFETY: the token proves the CPU has AVX2.
                #[cfg(target_arch = "x86_64")]
                $crate::Level::Avx2(_) => unsafe { $avx2($($arg),*) },
                _ => $kernel::<$($p)*>($($arg),*),
            }
        }
        $crate::dispatch!(@avx2 $avx2 $kernel [$($a2)*] ($($arg: $ty),*) $(-> $ret)?);

        /// The kernel compiled with AVX2, AVX-512 F and DQ, on its AVX-512 lanes.
        ///
        /// # Safety
        /// The CPU must support AVX2, AVX-512 F and DQ (an [`Avx512Token`]($crate::Avx512Token)
        /// proves it).
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2,avx512f,avx512dq")]
        #[allow(clippy::too_many_arguments)]
        unsafe fn $avx512($($arg: $ty),*) $(-> $ret)? {
            // The AVX-512 lanes' invariant holds: the caller guarantees the features.
            $kernel::<$($a5)*>($($arg),*)
        }
    };
    (
        $(#[$doc:meta])*
        $vis:vis fn $name:ident / $avx2:ident => $kernel:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)?;
        portable = [$($p:tt)*], avx2 = [$($a2:tt)*] $(,)?
    ) => {
        $(#[$doc])*
        #[allow(clippy::too_many_arguments)]
        $vis fn $name($($arg: $ty),*) $(-> $ret)? {
            #[cfg(target_arch = "x86_64")]
            if let Some(_token) = $crate::Avx2Token::new() {
                // SAFETY: the token proves the CPU has AVX2.
                return unsafe { $avx2($($arg),*) };
            }
            $kernel::<$($p)*>($($arg),*)
        }
        $crate::dispatch!(@avx2 $avx2 $kernel [$($a2)*] ($($arg: $ty),*) $(-> $ret)?);
    };
    (@avx2 $avx2:ident $kernel:ident [$($a2:tt)*] ($($arg:ident: $ty:ty),*) $(-> $ret:ty)?) => {
        /// The kernel compiled with AVX2, on its AVX2 lanes.
        ///
        /// # Safety
        /// The CPU must support AVX2 (an [`Avx2Token`]($crate::Avx2Token) proves it).
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2")]
        #[allow(clippy::too_many_arguments)]
        unsafe fn $avx2($($arg: $ty),*) $(-> $ret)? {
            // The AVX2 lanes' invariant holds: the caller guarantees AVX2.
            $kernel::<$($a2)*>($($arg),*)
        }
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for k in [LaneKind::Portable, LaneKind::Avx2, LaneKind::Avx512] {
            assert_eq!(k.name().parse::<LaneKind>(), Ok(k));
        }
        assert_eq!("AVX2".parse::<LaneKind>(), Ok(LaneKind::Avx2));
        assert_eq!("sse".parse::<LaneKind>(), Err(UnknownLaneKind));
    }

    #[test]
    fn the_limit_clamps() {
        let d = detected();
        for k in [LaneKind::Portable, LaneKind::Avx2, LaneKind::Avx512] {
            limit_lanes(k);
            assert!(lane_kind() <= k && lane_kind() <= d);
        }
        assert!(lane_kind() <= d);
    }
}
