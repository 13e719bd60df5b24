//! The decoder of a pass's result uploaded by a worker: the first byte chooses the pixel count
//! the lease expects, the next four the blocks of samples of the pass, the rest is the body.
#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../probes/inputs.rs"]
mod probe;

fuzz_target!(|data: &[u8]| probe::pass_upload(data));
