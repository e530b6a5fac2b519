//! Fuzz target `roundtrip`: decode → encode → decode of the input's messages, then a
//! structured message built from the same input with `arbitrary` through encode → decode.
//! See `volwarp_fuzz::checks::roundtrip_bytes` and `roundtrip_message`.
#![no_main]

use arbitrary::Unstructured;
use libfuzzer_sys::fuzz_target;
use volwarp_fuzz::checks;

#[global_allocator]
static ALLOC: checks::CountingAlloc = checks::CountingAlloc;

fuzz_target!(|data: &[u8]| {
    checks::roundtrip_bytes(data);
    if let Ok(m) = volwarp_fuzz::arb_message(&mut Unstructured::new(data)) {
        checks::roundtrip_message(&m, &checks::LIMITS);
    }
});
