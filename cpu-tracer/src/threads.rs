//! A renderer's own thread count: one thread runs on the caller's thread with no rayon at all
//! (thin clients), more run in a private rayon pool so the client's other threads (network,
//! LBVH build) do not compete with the global pool.

use rayon::prelude::*;

/// How many threads a renderer or builder uses, and its private pool.
#[derive(Debug)]
pub struct Threads {
    count: usize,
    pool: Option<rayon::ThreadPool>,
}

impl Threads {
    /// `count` threads; 0 means one per core. If the pool cannot be created, work runs on
    /// the caller's thread (logged).
    pub fn new(count: usize) -> Self {
        let count = if count == 0 { std::thread::available_parallelism().map_or(1, |n| n.get()) } else { count };
        if count <= 1 {
            return Threads { count: 1, pool: None };
        }
        match rayon::ThreadPoolBuilder::new().num_threads(count).thread_name(|i| format!("volwarp-cpu-{i}")).build() {
            Ok(pool) => Threads { count, pool: Some(pool) },
            Err(e) => {
                log::warn!("cannot start {count} render threads ({e}); rendering on one");
                Threads { count: 1, pool: None }
            }
        }
    }

    /// The number of threads.
    pub fn count(&self) -> usize {
        self.count
    }

    /// Calls `f(index, chunk)` for every `chunk_len`-long chunk of `data` (the last may be
    /// shorter), in parallel on the pool or serially on the caller's thread.
    pub fn for_each_chunk<T: Send, F>(&self, data: &mut [T], chunk_len: usize, f: F)
    where
        F: Fn(usize, &mut [T]) + Sync + Send,
    {
        let chunk_len = chunk_len.max(1);
        match &self.pool {
            Some(pool) => pool.install(|| data.par_chunks_mut(chunk_len).enumerate().for_each(|(i, c)| f(i, c))),
            None => data.chunks_mut(chunk_len).enumerate().for_each(|(i, c)| f(i, c)),
        }
    }

    /// Calls `f(index, a_chunk, b_chunk)` for the `chunk_len`-long chunks of `a` and `b`
    /// taken side by side (the same index ranges; `b` as long as `a`), in parallel on the pool
    /// or serially on the caller's thread.
    pub fn for_each_chunk_pair<T: Send, U: Send, F>(&self, a: &mut [T], b: &mut [U], chunk_len: usize, f: F)
    where
        F: Fn(usize, &mut [T], &mut [U]) + Sync + Send,
    {
        let chunk_len = chunk_len.max(1);
        match &self.pool {
            Some(pool) => pool.install(|| {
                a.par_chunks_mut(chunk_len)
                    .zip(b.par_chunks_mut(chunk_len))
                    .enumerate()
                    .for_each(|(i, (x, y))| f(i, x, y))
            }),
            None => a.chunks_mut(chunk_len).zip(b.chunks_mut(chunk_len)).enumerate().for_each(|(i, (x, y))| f(i, x, y)),
        }
    }

    /// [`Threads::for_each_chunk_pair`] for three slices taken side by side (`b` and `c` as
    /// long as `a`).
    pub fn for_each_chunk_triple<T: Send, U: Send, V: Send, F>(
        &self,
        a: &mut [T],
        b: &mut [U],
        c: &mut [V],
        chunk_len: usize,
        f: F,
    ) where
        F: Fn(usize, &mut [T], &mut [U], &mut [V]) + Sync + Send,
    {
        let chunk_len = chunk_len.max(1);
        match &self.pool {
            Some(pool) => pool.install(|| {
                a.par_chunks_mut(chunk_len)
                    .zip(b.par_chunks_mut(chunk_len))
                    .zip(c.par_chunks_mut(chunk_len))
                    .enumerate()
                    .for_each(|(i, ((x, y), z))| f(i, x, y, z))
            }),
            None => a
                .chunks_mut(chunk_len)
                .zip(b.chunks_mut(chunk_len))
                .zip(c.chunks_mut(chunk_len))
                .enumerate()
                .for_each(|(i, ((x, y), z))| f(i, x, y, z)),
        }
    }

    /// Calls `f(range)` for consecutive ranges of `0..n` at most `grain` long, in parallel on
    /// the pool or serially on the caller's thread.
    pub fn for_each_range<F>(&self, n: usize, grain: usize, f: F)
    where
        F: Fn(std::ops::Range<usize>) + Sync + Send,
    {
        let grain = grain.max(1);
        let chunks = n.div_ceil(grain);
        let range = |c: usize| c * grain..((c + 1) * grain).min(n);
        match &self.pool {
            Some(pool) => pool.install(|| (0..chunks).into_par_iter().for_each(|c| f(range(c)))),
            None => (0..chunks).for_each(|c| f(range(c))),
        }
    }

    /// Calls `f(index, part)` for the consecutive parts of `data` that end at `ends` (ascending,
    /// the last `data.len()`; a part may be empty), in parallel on the pool or serially on the
    /// caller's thread: chunks of uneven length, such as the samples of bands of pixel rows.
    pub fn for_each_part<T: Send, F>(&self, data: &mut [T], ends: &[usize], f: F)
    where
        F: Fn(usize, &mut [T]) + Sync + Send,
    {
        let mut parts = Vec::with_capacity(ends.len());
        let (mut rest, mut at) = (data, 0usize);
        for &end in ends {
            let (part, tail) = rest.split_at_mut(end.clamp(at, at + rest.len()) - at);
            at += part.len();
            parts.push(part);
            rest = tail;
        }
        match &self.pool {
            Some(pool) => pool.install(|| parts.into_par_iter().enumerate().for_each(|(i, c)| f(i, c))),
            None => parts.into_iter().enumerate().for_each(|(i, c)| f(i, c)),
        }
    }

    /// Runs `f` inside the pool (so rayon iterators in it use this pool), or on the caller's
    /// thread with a one-thread view.
    pub fn install<R: Send>(&self, f: impl FnOnce() -> R + Send) -> R {
        match &self.pool {
            Some(pool) => pool.install(f),
            None => f(),
        }
    }

    /// Whether work runs on the caller's thread only.
    pub fn is_serial(&self) -> bool {
        self.pool.is_none()
    }
}

impl Default for Threads {
    /// One thread per core.
    fn default() -> Self {
        Threads::new(0)
    }
}
