//! The course's environment-light scenes with their missing maps substituted.
//!
//! The HW5 environment maps (`pisa_latlong.exr`, `grace-new.exr`, ...) and the head's albedo
//! texture are missing from every public copy of the course files (../shared/scenes/README.md).
//! To render those scenes anyway, [`load_substituted`] parses the original scene file, points
//! every missing `.exr` image at a CC0 map from `../shared/scenes/hdri/`, drops texture maps
//! whose (LDR) image is missing together with the objects' references to them, and builds the
//! result with assets resolved next to the original file. Nothing is written to disk.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use tessera::assets::FsResolver;
use tessera::scene::Scene;
use tessera::scene::build::build_scene;
use tessera::scene::records::{SceneRecords, TextureSource};
use tessera::scene::xml::parse_xml;

/// The course scenes lit by an environment map that is missing, with the substitute map each
/// is rendered with here (`sky` and `sunrise` have a small, bright sun).
pub const ENV_SCENES: &[(&str, &str)] = &[
    ("sphere_env_light", "sky"),
    ("mirror_sphere_env", "studio"),
    ("glass_sphere_env", "studio"),
    ("head_env_light", "sunrise"),
    // The 2021 version: 900 samples per pixel (the speed comparison of issue #5).
    ("head_env_light_2021", "sunrise"),
    ("audi-tt-pisa", "park"),
];

/// `../shared/scenes/hdri/<name>.exr`.
pub fn hdri(name: &str) -> PathBuf {
    crate::shared_scenes().join("hdri").join(format!("{name}.exr"))
}

/// What [`substitute`] changed, for reports.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Substitutions {
    /// (image path as written, substitute path).
    pub maps: Vec<(String, PathBuf)>,
    /// Texture map ids dropped because their image is missing.
    pub dropped_maps: Vec<String>,
}

/// Rewrites `rec` (parsed from a file in `dir`) so that missing `.exr` images become `map` and
/// texture maps with other missing images are dropped.
pub fn substitute(rec: &mut SceneRecords, dir: &Path, map: &Path) -> Substitutions {
    let mut subs = Substitutions::default();
    let mut missing_ldr = Vec::new();
    for img in &mut rec.images {
        if dir.join(&img.path).exists() {
            continue;
        }
        if img.path.to_ascii_lowercase().ends_with(".exr") {
            subs.maps.push((img.path.clone(), map.to_path_buf()));
            img.path = map.to_string_lossy().into_owned();
        } else {
            missing_ldr.push(img.id.clone());
        }
    }
    rec.texture_maps.retain(|m| match &m.source {
        TextureSource::Image { image, .. } if missing_ldr.contains(image) => {
            subs.dropped_maps.push(m.id.clone());
            false
        }
        _ => true,
    });
    let dropped = subs.dropped_maps.clone();
    let keep = |ids: &mut Vec<String>| ids.retain(|t| !dropped.contains(t));
    rec.meshes.iter_mut().for_each(|m| keep(&mut m.textures));
    rec.triangles.iter_mut().for_each(|m| keep(&mut m.textures));
    rec.spheres.iter_mut().for_each(|m| keep(&mut m.textures));
    subs
}

/// Loads course scene `scene` (under ../shared/scenes/xml) with its missing environment map
/// replaced by `hdri/<map>.exr`; `edit` may change the records further (resolution, samples).
pub fn load_substituted(
    scene: &str,
    map: &str,
    edit: impl FnOnce(&mut SceneRecords),
) -> Result<(Scene, Substitutions)> {
    let path = crate::shared_scenes().join("xml").join(format!("{scene}.xml"));
    let text = std::fs::read_to_string(&path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut rec = parse_xml(&text, &path).map_err(|e| anyhow::anyhow!("{e}"))?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let subs = substitute(&mut rec, dir, &hdri(map));
    edit(&mut rec);
    let scene = build_scene(&rec, &FsResolver::for_scene(&path)).map_err(|e| anyhow::anyhow!("{e}"))?;
    Ok((scene, subs))
}
