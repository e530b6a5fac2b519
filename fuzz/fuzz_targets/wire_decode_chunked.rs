//! Fuzz target `wire_decode_chunked`: see `volwarp_fuzz::checks::wire_decode_chunked`.
#![no_main]

use libfuzzer_sys::fuzz_target;
use volwarp_fuzz::checks;

#[global_allocator]
static ALLOC: checks::CountingAlloc = checks::CountingAlloc;

fuzz_target!(|data: &[u8]| {
    checks::wire_decode_chunked(data);
});
