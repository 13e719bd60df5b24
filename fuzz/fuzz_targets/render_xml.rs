//! The tracer on arbitrary XML scenes: every scene the builder accepts renders a few pixels of
//! each camera (the middle 3x3 of the frame, 2 samples, every environment sampler) without a
//! panic or a hang: degenerate meshes, transformations and materials, lights at or inside
//! surfaces, cameras looking along nothing. Starts best from the `scene_xml` corpus.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera::image::TileRect;
use tessera::render::{RenderSettings, render_tile};
use tessera::scene::records::EnvSampler;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let path = std::path::Path::new("fuzz.xml");
    let Ok(records) = tessera::scene::xml::parse_xml(text, path) else { return };
    let resolver = tessera::assets::MemResolver::for_scene(Default::default(), "fuzz.xml");
    let Ok(scene) = tessera::scene::build::build_scene(&records, &resolver) else { return };
    for (k, cam) in scene.cameras.iter().enumerate().take(2) {
        let (w, h) = (cam.width.min(3), cam.height.min(3));
        let rect = TileRect { x0: (cam.width - w) / 2, y0: (cam.height - h) / 2, width: w, height: h };
        for env in [EnvSampler::Uniform, EnvSampler::Cosine, EnvSampler::Importance] {
            let settings = RenderSettings { samples: Some(2), env_sampling: Some(env), ..Default::default() };
            let _ = render_tile(&scene, k, rect, &settings);
        }
    }
});
