//! A link model for the loopback stream (`--bandwidth-mbps`): a token bucket on the client's
//! socket reads (frames) and writes (camera requests), so the window and `--bench` show what a
//! slow network does to frame age — and what the compact encoding saves there.
//!
//! The bucket fills at the link rate up to a burst of [`BURST`] bytes (or 2 ms of the rate,
//! whichever is larger); each read or write first waits until at least one byte's worth of
//! tokens is there, then moves at most the tokens on hand and spends what it moved. A frame of
//! `B` bytes therefore arrives no sooner than `(B − burst) / rate` after its first byte, as it
//! would over a link of that rate (propagation delay is `--latency-ms`'s job). The kernel's
//! socket buffers still fill at loopback speed; only what the client sees is throttled.

use std::io::{self, Read, Write};
use std::time::{Duration, Instant};

/// Smallest burst the bucket allows, in bytes.
pub const BURST: f64 = 16.0 * 1024.0;

/// A token bucket of `rate` bytes per second.
#[derive(Debug)]
pub struct TokenBucket {
    rate: f64,
    burst: f64,
    tokens: f64,
    last: Instant,
}

impl TokenBucket {
    /// A bucket for a link of `mbps` megabits per second (10⁶ bit/s), full at the start.
    /// `None` for a rate that is not a positive finite number.
    pub fn from_mbps(mbps: f64) -> Option<TokenBucket> {
        let rate = mbps * 1e6 / 8.0;
        (rate > 0.0 && rate.is_finite()).then(|| {
            let burst = BURST.max(rate * 0.002);
            TokenBucket { rate, burst, tokens: burst, last: Instant::now() }
        })
    }

    /// Bytes per second.
    pub fn rate(&self) -> f64 {
        self.rate
    }

    /// Burst size in bytes.
    pub fn burst(&self) -> f64 {
        self.burst
    }

    fn refill(&mut self) {
        let now = Instant::now();
        self.tokens = (self.tokens + (now - self.last).as_secs_f64() * self.rate).min(self.burst);
        self.last = now;
    }

    /// Waits until at least one byte may pass and returns how many may (at most `want`, ≥ 1
    /// when `want` ≥ 1).
    pub fn admit(&mut self, want: usize) -> usize {
        if want == 0 {
            return 0;
        }
        self.refill();
        if self.tokens < 1.0 {
            std::thread::sleep(Duration::from_secs_f64((1.0 - self.tokens) / self.rate));
            self.refill();
        }
        (self.tokens.max(1.0) as usize).min(want)
    }

    /// Spends the tokens of `n` bytes that passed.
    pub fn spend(&mut self, n: usize) {
        self.tokens -= n as f64;
    }
}

/// A stream whose reads and writes pass through token buckets (one per direction).
#[derive(Debug)]
pub struct Throttled<S> {
    inner: S,
    bucket: TokenBucket,
}

impl<S> Throttled<S> {
    /// `inner` throttled by `bucket`.
    pub fn new(inner: S, bucket: TokenBucket) -> Self {
        Throttled { inner, bucket }
    }

    /// The stream inside.
    pub fn get_mut(&mut self) -> &mut S {
        &mut self.inner
    }
}

impl<S: Read> Read for Throttled<S> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let k = self.bucket.admit(buf.len());
        let n = self.inner.read(&mut buf[..k])?;
        self.bucket.spend(n);
        Ok(n)
    }
}

impl<S: Write> Write for Throttled<S> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let k = self.bucket.admit(buf.len());
        let n = self.inner.write(&buf[..k])?;
        self.bucket.spend(n);
        Ok(n)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rates_parse_and_bad_rates_are_refused() {
        assert_eq!(TokenBucket::from_mbps(8.0).unwrap().rate(), 1e6);
        assert_eq!(TokenBucket::from_mbps(8.0).unwrap().burst(), BURST);
        assert_eq!(TokenBucket::from_mbps(1000.0).unwrap().burst(), 125e6 * 0.002);
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(TokenBucket::from_mbps(bad).is_none(), "{bad}");
        }
    }

    #[test]
    fn a_throttled_read_is_never_faster_than_the_link_and_loses_nothing() {
        // 300 kB at 16 Mbit/s (2 MB/s): at least (300 kB − burst) / rate ≈ 142 ms. Only the
        // lower bound is a property (a loaded machine can only be slower).
        let data: Vec<u8> = (0..300_000u32).map(|i| (i * 7 + i / 251) as u8).collect();
        let bucket = TokenBucket::from_mbps(16.0).unwrap();
        let min = Duration::from_secs_f64((data.len() as f64 - bucket.burst()) / bucket.rate());
        let mut r = Throttled::new(&data[..], bucket);
        let t = Instant::now();
        let mut got = Vec::new();
        r.read_to_end(&mut got).unwrap();
        assert!(t.elapsed() >= min.mul_f64(0.99), "{:?} < {min:?}", t.elapsed());
        assert_eq!(got, data);
    }

    #[test]
    fn a_throttled_write_is_never_faster_than_the_link() {
        let bucket = TokenBucket::from_mbps(8.0).unwrap();
        let min = Duration::from_secs_f64((100_000.0 - bucket.burst()) / bucket.rate());
        let mut w = Throttled::new(Vec::new(), bucket);
        let t = Instant::now();
        w.write_all(&[5u8; 100_000]).unwrap();
        assert!(t.elapsed() >= min.mul_f64(0.99));
        assert_eq!(w.get_mut().len(), 100_000);
    }
}
