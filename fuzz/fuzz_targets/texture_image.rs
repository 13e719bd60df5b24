//! The texture decoders (PNG, JPEG, OpenEXR, Radiance HDR, chosen by content) on arbitrary
//! bytes, and a lookup in whatever decodes.
#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../probes/inputs.rs"]
mod probe;

fuzz_target!(|data: &[u8]| probe::texture_image(data));
