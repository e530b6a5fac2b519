//! Fuzz target `compact_decode`: see `volwarp_fuzz::checks::compact_decode`.
#![no_main]

use libfuzzer_sys::fuzz_target;
use volwarp_fuzz::checks;

#[global_allocator]
static ALLOC: checks::CountingAlloc = checks::CountingAlloc;

fuzz_target!(|data: &[u8]| {
    checks::compact_decode(data);
});
