//! The tracer on arbitrary 2025 JSON scenes, as `render_xml` on XML ones (the JSON front end
//! makes the same records, with its own planes and defaults). Starts best from the
//! `scene_json` corpus.
#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../probes/scene.rs"]
mod probe;

fuzz_target!(|data: &[u8]| probe::render(data, true));
