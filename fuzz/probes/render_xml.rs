//! What the `render_xml` fuzz target does with an input, in one place: the target includes this
//! file, and so does the stable-toolchain replay test (tests/tests/fuzz_regressions.rs), by path,
//! so that the corpus is replayed through exactly what was fuzzed.

use tessera::image::TileRect;
use tessera::render::{RenderSettings, render_tile};
use tessera::scene::records::EnvSampler;

/// The middle 3x3 pixels of the first two cameras of a scene the builder accepts, 2 samples,
/// under each environment sampler.
pub fn render_xml(data: &[u8]) {
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
}
