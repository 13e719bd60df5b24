//! Scenes: parse into plain records first ([`records`], [`xml`]), then build the render scene
//! ([`build`]).

pub mod build;
pub mod json;
pub mod records;
pub mod xml;

use std::path::{Path, PathBuf};

use glam::DVec3;

use crate::assets::{AssetResolver, FsResolver};
use crate::camera::Camera;
use crate::error::{SceneError, Warning};
use crate::geometry::Accel;
use crate::material::Material;

pub use crate::lights::{AreaLight, DirectionalLight, EnvLight, PointLight, SpotLight};

/// Size and cost of a built scene, for logs and summaries.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneStats {
    /// Triangles over all instances (an instanced mesh counts once per instance).
    pub triangles: usize,
    pub instances: usize,
    /// Wall time of the build step (PLY loading, normals, BVHs).
    pub build_seconds: f64,
}

/// A render-ready scene. Immutable once built; shared by all render threads.
pub struct Scene {
    pub source: PathBuf,
    pub background: DVec3,
    pub shadow_ray_epsilon: f64,
    pub intersection_test_epsilon: f64,
    pub max_recursion_depth: u32,
    /// Camera rays pass through triangles seen from behind (2025 JSON scenes, §15 #23): the
    /// 2025 references cull them, e.g. the inward-facing front wall of the 2025
    /// cornellbox_boxes_dynamic, whose camera sits outside the box. Shadow and secondary rays
    /// never cull.
    pub cull_camera_back_faces: bool,
    pub ambient_light: DVec3,
    pub point_lights: Vec<PointLight>,
    pub area_lights: Vec<AreaLight>,
    pub directional_lights: Vec<DirectionalLight>,
    pub spot_lights: Vec<SpotLight>,
    /// The environment light (HW5), if any: lights the scene and is what rays that miss see.
    /// (A second `SphericalDirectionalLight` is warned about and ignored.)
    pub env_light: Option<EnvLight>,
    pub materials: Vec<Material>,
    pub cameras: Vec<Camera>,
    pub accel: Accel,
    /// Texture maps, indexed by [`crate::geometry::ObjectTextures`].
    pub textures: Vec<crate::texture::maps::TextureMap>,
    /// The `replace_background` map, if the scene has one (§11.8).
    pub background_texture: Option<u32>,
    /// Parser and builder warnings (unknown elements, skipped triangles, ...).
    pub warnings: Vec<Warning>,
    pub stats: SceneStats,
}

/// Which front end reads a scene text, chosen by content, not by file name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SceneFormat {
    /// First non-blank character `<`, or anything else (the XML parser explains what is wrong).
    Xml,
    /// First non-blank character `{` or `[`: the 2025 JSON dialect (scene-format.md §14).
    Json,
}

/// The front end for `text`: JSON if its first non-whitespace character (after a UTF-8 byte
/// order mark) is `{` or `[`, XML otherwise.
pub fn detect_format(text: &str) -> SceneFormat {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    match text.trim_start().as_bytes().first() {
        Some(b'{' | b'[') => SceneFormat::Json,
        _ => SceneFormat::Xml,
    }
}

/// Parses scene text named `source` (for messages) with the front end [`detect_format`] picks.
pub fn parse_scene(text: &str, source: &Path) -> Result<records::SceneRecords, SceneError> {
    match detect_format(text) {
        SceneFormat::Json => json::parse_json(text, source),
        SceneFormat::Xml => xml::parse_xml(text, source),
    }
}

/// Parses and builds a scene from text, with assets from `resolver`.
pub fn load_scene_str(text: &str, source: &Path, resolver: &dyn AssetResolver) -> Result<Scene, SceneError> {
    let rec = parse_scene(text, source)?;
    build::build_scene(&rec, resolver)
}

/// Reads, parses and builds the scene file at `path`; assets resolve relative to its directory.
pub fn load_scene_file(path: &Path) -> Result<Scene, SceneError> {
    let bytes = std::fs::read(path)
        .map_err(|e| SceneError::file(path, format!("cannot read the scene file: {e}")))?;
    let text = String::from_utf8(bytes).map_err(|e| {
        SceneError::file(
            path,
            format!(
                "the scene file is not UTF-8 text (byte {}); save it as UTF-8",
                e.utf8_error().valid_up_to()
            ),
        )
    })?;
    load_scene_str(&text, path, &FsResolver::for_scene(path))
}
