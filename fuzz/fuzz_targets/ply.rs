//! The PLY reader (ASCII and binary, both byte orders) on arbitrary bytes.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = tessera::ply::parse_ply(data);
});
