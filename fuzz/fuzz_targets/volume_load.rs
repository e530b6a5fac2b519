//! Fuzz target `volume_load`: see `volwarp_fuzz::volume_checks::volume_load`.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    volwarp_fuzz::volume_checks::volume_load(data);
});
