//! The 2025 JSON front end and the scene builder on arbitrary text.
#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../probes/scene.rs"]
mod probe;

fuzz_target!(|data: &[u8]| probe::scene(data, true));
