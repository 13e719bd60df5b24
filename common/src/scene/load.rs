//! Loading a scene: text or a file, through the front end its content picks, to a [`Scene`].
//!
//! [`parse_scene`] picks the front end ([`detect_format`]); [`load_scene_str`] and
//! [`load_scene_file`] parse and then [`build_scene`].

use std::path::Path;

use super::Scene;
use super::build::build_scene;
use super::records::SceneRecords;
use super::{json, xml};
use crate::assets::{AssetResolver, FsResolver};
use crate::error::SceneError;

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
pub fn parse_scene(text: &str, source: &Path) -> Result<SceneRecords, SceneError> {
    match detect_format(text) {
        SceneFormat::Json => json::parse_json(text, source),
        SceneFormat::Xml => xml::parse_xml(text, source),
    }
}

/// Parses and builds a scene from text, with assets from `resolver`.
pub fn load_scene_str(text: &str, source: &Path, resolver: &dyn AssetResolver) -> Result<Scene, SceneError> {
    let rec = parse_scene(text, source)?;
    build_scene(&rec, resolver)
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
