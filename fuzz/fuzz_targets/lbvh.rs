//! Fuzz target `lbvh`: see `volwarp_fuzz::checks::lbvh`.
#![no_main]

use libfuzzer_sys::fuzz_target;
use volwarp_fuzz::checks;

#[global_allocator]
static ALLOC: checks::CountingAlloc = checks::CountingAlloc;

fuzz_target!(|data: &[u8]| {
    checks::lbvh(data);
});
