//! The PLY reader (ASCII and binary, both byte orders) on arbitrary bytes.
#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../probes/inputs.rs"]
mod probe;

fuzz_target!(|data: &[u8]| probe::ply(data));
