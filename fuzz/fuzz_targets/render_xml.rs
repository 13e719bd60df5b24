//! The tracer on arbitrary XML scenes: every scene the builder accepts renders a few pixels of
//! each camera (the middle 3x3 of the frame, 2 samples, every environment sampler) without a
//! panic or a hang: degenerate meshes, transformations and materials, lights at or inside
//! surfaces, cameras looking along nothing. Starts best from the `scene_xml` corpus.
#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../probes/scene.rs"]
mod probe;

fuzz_target!(|data: &[u8]| probe::render(data, false));
