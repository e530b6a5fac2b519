//! `cargo run --release -p volwarp-server --example load_timing -- FILE [RUNS]`: how fast a
//! volume file becomes bricks and empty-space grids, against reading the file (`cat FILE >
//! /dev/null`) on a warm page cache, and what it costs in memory. Prints, medians of RUNS
//! (default 3) after one warm-up read:
//!
//! - `read`: the file read into a 1 MiB buffer and dropped (what `cat > /dev/null` does);
//! - `bricks`: `load_volume` (the streaming loaders for raw and NRRD);
//! - `grids`: `MinMaxGrid::new` (the empty-space grid);
//! - the floor of any load into new memory: writing one byte per 4 KiB page of as many fresh
//!   bytes as the bricks take (the kernel zeroes each page on its first touch);
//! - the resident memory the volume and its grids add (`VmRSS`), against the file's voxel
//!   bytes.
//!
//! `RAYON_NUM_THREADS` picks the threads.

use std::io::Read;
use std::time::Instant;
use volwarp_server::empty_space::MinMaxGrid;
use volwarp_server::volume::{load_volume, LoadOptions};

/// `VmRSS` of this process in bytes.
fn rss() -> u64 {
    let s = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    s.lines()
        .find(|l| l.starts_with("VmRSS:"))
        .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
        .unwrap_or(0)
        * 1024
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn read_file(path: &str) -> u64 {
    let mut f = std::fs::File::open(path).expect("opening the file");
    let mut buf = vec![0u8; 1 << 20];
    let mut n = 0u64;
    loop {
        match f.read(&mut buf) {
            Ok(0) => return n,
            Ok(k) => n += k as u64,
            Err(e) => panic!("reading {path}: {e}"),
        }
    }
}

fn main() {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    let args: Vec<String> = std::env::args().collect();
    let Some(path) = args.get(1).cloned() else {
        eprintln!("usage: load_timing FILE [RUNS]");
        std::process::exit(2);
    };
    let runs: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(3);
    let bytes = read_file(&path); // warm-up: the page cache
    let mut read = Vec::new();
    for _ in 0..runs {
        let t = Instant::now();
        read_file(&path);
        read.push(t.elapsed().as_secs_f64());
    }
    let (mut load, mut grid, mut mem, mut vol_bytes, mut grid_bytes) = (Vec::new(), Vec::new(), 0, 0, 0);
    let mut info = String::new();
    for _ in 0..runs {
        let before = rss();
        let t = Instant::now();
        let v = load_volume(&path, &LoadOptions::default()).expect("loading the volume");
        load.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        let g = MinMaxGrid::new(&v);
        grid.push(t.elapsed().as_secs_f64());
        mem = rss().saturating_sub(before);
        vol_bytes = v.memory_bytes();
        grid_bytes = std::mem::size_of_val(g.ranges()) as u64;
        let d = v.dims();
        info = format!("{}x{}x{} {} ({} file bytes)", d[0], d[1], d[2], v.voxels().type_name(), v.source().data_bytes);
        drop(g);
        drop(v);
    }
    // The floor of any load into new memory: touching as many fresh bytes as the bricks take
    // (the kernel zeroes each page on its first write), in parallel on the threads.
    let mut touch = Vec::new();
    for _ in 0..runs {
        use rayon::prelude::*;
        let t = Instant::now();
        let mut fresh = vec![0u8; vol_bytes as usize];
        fresh.par_chunks_mut(1 << 21).for_each(|c| c.iter_mut().step_by(4096).for_each(|b| *b = 1));
        touch.push(t.elapsed().as_secs_f64());
        std::hint::black_box(&fresh);
    }
    let (r, l, g) = (median(read), median(load), median(grid));
    let touch = median(touch);
    let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
    let data = bytes as f64;
    println!("{path}: {info}, threads {}", rayon::current_num_threads());
    println!("read (cat > /dev/null)  {:8.3} s  {:6.2} GB/s", r, data / r / 1e9);
    println!("first touch of as many new bytes as the bricks {:8.3} s  {:5.2}x read", touch, touch / r);
    println!("bricks (load_volume)    {:8.3} s  {:6.2} GB/s  {:5.2}x read", l, data / l / 1e9, l / r);
    println!("grids (MinMaxGrid)      {:8.3} s", g);
    println!("bricks + grids          {:8.3} s  {:5.2}x read", l + g, (l + g) / r);
    println!(
        "memory: bricks {:.3} GiB ({:.3}x the file), grid ranges {:.3} GiB, resident growth {:.3} GiB ({:.3}x the file)",
        gib(vol_bytes),
        vol_bytes as f64 / data,
        gib(grid_bytes),
        gib(mem),
        mem as f64 / data
    );
}
