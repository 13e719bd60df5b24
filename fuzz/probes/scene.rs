//! What the scene fuzz targets (`scene_xml`, `scene_json`) and the tracer's (`render_xml`,
//! `render_json`) do with an input, in one place: the targets include this file by path, and so
//! does the stable-toolchain replay test (tests/tests/fuzz_regressions.rs), so that the corpora
//! are replayed through exactly what was fuzzed.

use tessera::image::TileRect;
use tessera::render::{RenderSettings, render_tile};
use tessera::scene::Scene;
use tessera::scene::records::EnvSampler;

/// Parse, then build: any text gives a scene or a `SceneError` (`None`), never a panic, a hang
/// or an allocation out of proportion to the input. `json` picks the 2025 JSON front end, else
/// the XML one.
pub fn build(data: &[u8], json: bool) -> Option<Scene> {
    let text = std::str::from_utf8(data).ok()?;
    let name = if json { "fuzz.json" } else { "fuzz.xml" };
    let path = std::path::Path::new(name);
    let records = if json {
        tessera::scene::json::parse_json(text, path)
    } else {
        tessera::scene::xml::parse_xml(text, path)
    };
    let resolver = tessera::assets::MemResolver::for_scene(Default::default(), name);
    tessera::scene::build::build_scene(&records.ok()?, &resolver).ok()
}

/// The scene targets: [`build`].
#[allow(dead_code)]
pub fn scene(data: &[u8], json: bool) {
    let _ = build(data, json);
}

/// The tracer's targets: the middle 3x3 pixels of the first two cameras of a scene that
/// builds, 2 samples, under each environment sampler.
#[allow(dead_code)]
pub fn render(data: &[u8], json: bool) {
    let Some(scene) = build(data, json) else { return };
    for (k, cam) in scene.cameras.iter().enumerate().take(2) {
        let (w, h) = (cam.width.min(3), cam.height.min(3));
        let rect = TileRect { x0: (cam.width - w) / 2, y0: (cam.height - h) / 2, width: w, height: h };
        for env in [EnvSampler::Uniform, EnvSampler::Cosine, EnvSampler::Importance] {
            let settings = RenderSettings { samples: Some(2), env_sampling: Some(env), ..Default::default() };
            let _ = render_tile(&scene, k, rect, &settings);
        }
    }
}
