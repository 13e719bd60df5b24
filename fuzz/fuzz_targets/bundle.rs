//! The server's reading of uploaded archives (tar, tar.gz, zip) into bundle files.
#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../probes/inputs.rs"]
mod probe;

fuzz_target!(|data: &[u8]| probe::bundle(data));
