//! The decoder of tiles uploaded by workers: the first two bytes choose the pixel count the
//! lease expects, the rest is the body.
#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../probes/inputs.rs"]
mod probe;

fuzz_target!(|data: &[u8]| probe::tile_upload(data));
