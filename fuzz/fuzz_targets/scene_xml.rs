//! The XML front end and the scene builder on arbitrary text: any input gives records or a
//! `SceneError`, never a panic, a hang or an allocation out of proportion to the input.
#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../probes/scene.rs"]
mod probe;

fuzz_target!(|data: &[u8]| probe::scene(data, false));
