//! The client's decode of LayeredCompactFrames, its layers on several threads
//! (`connection::decode_layered_parallel`) against core's one-thread decoder, on the frames of
//! a record file (the client's `--record`), each encoded as the compact form:
//!
//! ```sh
//! cargo run --release -p volwarp-client --example layered_decode -- FILE.vwrec [RUNS]   # default 15
//! ```
//!
//! Prints per frame its samples, layers and compact bytes, and the median wall milliseconds of
//! both decoders (alternated, the same bytes), then the medians over all frames.

use std::time::Instant;
use volwarp_client::connection::decode_layered_parallel;
use volwarp_core::compact_frame::{encode_frame, EncodeOptions, Encoding};
use volwarp_core::record::{read_entry, read_magic, Entry};
use volwarp_core::segments::decode_layered_payload;
use volwarp_core::wire::{Limits, HEADER_LEN};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let Some(path) = args.get(1) else {
        eprintln!("usage: layered_decode FILE.vwrec [RUNS]");
        std::process::exit(2);
    };
    let runs: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(15).max(1);
    let file = std::fs::File::open(path).unwrap_or_else(|e| panic!("{path}: {e}"));
    let mut r = embedded_io_adapters::std::FromStd::new(std::io::BufReader::new(file));
    read_magic(&mut r).unwrap_or_else(|e| panic!("{path}: {e}"));
    let limits = Limits::default();
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!("{threads} threads available");
    println!("frame   samples  layers     bytes   one thread ms   threads ms");
    let (mut all_one, mut all_par) = (Vec::new(), Vec::new());
    let mut i = 0;
    while let Ok(Some(entry)) = read_entry(&mut r, &limits) {
        let Entry::Frame { frame, .. } = entry else { continue };
        if frame.layers() < 2 {
            continue;
        }
        let (msg, enc) = encode_frame(&frame, Encoding::Compact, &EncodeOptions::default());
        if enc != Encoding::Compact {
            continue;
        }
        let payload = &msg[HEADER_LEN..];
        let want = decode_layered_payload(payload, &limits).expect("decode");
        let (mut one, mut par) = (Vec::new(), Vec::new());
        for _ in 0..runs {
            let t = Instant::now();
            std::hint::black_box(decode_layered_payload(payload, &limits).expect("decode"));
            one.push(t.elapsed().as_secs_f64() * 1e3);
            let t = Instant::now();
            let got = std::hint::black_box(decode_layered_parallel(payload, &limits).expect("decode"));
            par.push(t.elapsed().as_secs_f64() * 1e3);
            assert!(got == want, "frame {i}: the threads' frame differs");
        }
        let (a, b) = (median(one), median(par));
        println!("{i:5} {:9} {:7} {:9}   {a:13.2}   {b:10.2}", frame.samples.len(), frame.layers(), msg.len());
        all_one.push(a);
        all_par.push(b);
        i += 1;
    }
    if all_one.is_empty() {
        println!("no layered frames in {path}");
        return;
    }
    let (a, b) = (median(all_one), median(all_par));
    println!("median over {i} frames: one thread {a:.2} ms, {threads} threads {b:.2} ms ({:.2}×)", a / b);
}
