//! Fuzz target `volume_header`: see `volwarp_fuzz::volume_checks::volume_header`.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    volwarp_fuzz::volume_checks::volume_header(data);
});
