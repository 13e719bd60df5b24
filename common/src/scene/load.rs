//! Loading a scene: text or a file, through the front end its content picks, to a [`Scene`].
//!
//! [`parse_scene`] picks the front end ([`detect_format`]); [`load_scene_str`] and
//! [`load_scene_file`] parse and then [`build_scene`], and refuse a scene with elements that
//! change the picture but are not implemented ([`Warning::unsupported`]) unless
//! [`LoadOptions::allow_unsupported`] (the `_with` forms take the options).

use std::path::Path;

use super::Scene;
use super::build::build_scene;
use super::records::SceneRecords;
use super::{json, xml};
use crate::assets::{AssetResolver, FsResolver};
use crate::error::{SceneError, Warning, unsupported_errors};

/// How strictly a scene is loaded.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LoadOptions {
    /// Render a scene that uses elements Tessera does not implement and whose absence changes the
    /// picture (each one is then a warning). Off by default: such a scene is refused, naming
    /// every such element, so that no picture is silently wrong.
    pub allow_unsupported: bool,
}

impl LoadOptions {
    /// Unsupported elements are errors (the default).
    pub const STRICT: LoadOptions = LoadOptions { allow_unsupported: false };
    /// Unsupported elements are warnings, and the scene is rendered without them.
    pub const ALLOW_UNSUPPORTED: LoadOptions = LoadOptions { allow_unsupported: true };

    /// `Err` with every unsupported element among `warnings`, in order, unless they are
    /// allowed or there are none.
    pub fn check(&self, warnings: &[Warning]) -> Result<(), Vec<SceneError>> {
        if self.allow_unsupported {
            return Ok(());
        }
        let errors = unsupported_errors(warnings);
        if errors.is_empty() { Ok(()) } else { Err(errors) }
    }
}

/// Several errors as one, for callers that take a single [`SceneError`]: the first, its message
/// followed by the others, each on a line of its own in the same `file:line: <Element>: message`
/// form. `None` when there are none.
pub fn join_errors(mut errors: Vec<SceneError>) -> Option<SceneError> {
    if errors.is_empty() {
        return None;
    }
    let rest = errors.split_off(1);
    let mut first = errors.pop().expect("one is left");
    for e in rest {
        first.message.push_str(&format!("\n{e}"));
    }
    Some(first)
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
pub fn parse_scene(text: &str, source: &Path) -> Result<SceneRecords, SceneError> {
    match detect_format(text) {
        SceneFormat::Json => json::parse_json(text, source),
        SceneFormat::Xml => xml::parse_xml(text, source),
    }
}

/// Parses and builds a scene from text, with assets from `resolver`; unsupported elements are
/// errors ([`LoadOptions::STRICT`]).
pub fn load_scene_str(text: &str, source: &Path, resolver: &dyn AssetResolver) -> Result<Scene, SceneError> {
    load_scene_str_with(text, source, resolver, LoadOptions::STRICT)
}

/// [`load_scene_str`] with options. Unsupported elements the parser finds are refused before
/// any asset is read; those only the build finds (an object's texture too many), after it.
pub fn load_scene_str_with(
    text: &str,
    source: &Path,
    resolver: &dyn AssetResolver,
    options: LoadOptions,
) -> Result<Scene, SceneError> {
    let refuse = |errors: Vec<SceneError>| join_errors(errors).expect("check errs with some");
    let rec = parse_scene(text, source)?;
    options.check(&rec.warnings).map_err(refuse)?;
    let scene = build_scene(&rec, resolver)?;
    options.check(&scene.warnings).map_err(refuse)?;
    Ok(scene)
}

/// Reads, parses and builds the scene file at `path`; assets resolve relative to its directory.
/// Unsupported elements are errors ([`LoadOptions::STRICT`]).
pub fn load_scene_file(path: &Path) -> Result<Scene, SceneError> {
    load_scene_file_with(path, LoadOptions::STRICT)
}

/// [`load_scene_file`] with options.
pub fn load_scene_file_with(path: &Path, options: LoadOptions) -> Result<Scene, SceneError> {
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
    load_scene_str_with(&text, path, &FsResolver::for_scene(path), options)
}
