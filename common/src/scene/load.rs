//! Loading a scene: text or a file, through the front end its content picks, to a [`Scene`].
//!
//! [`parse_scene`] picks the front end ([`detect_format`]); [`load_scene_str`] and
//! [`load_scene_file`] parse and then [`build_scene`], and refuse a scene with elements that
//! change the picture but are not implemented ([`Warning::unsupported`]) unless
//! [`LoadOptions::allow_unsupported`] (the `_with` forms take the options).

use std::path::Path;

use super::Scene;
use super::build::{build_scene, build_scene_cached};
use super::cache::MeshCache;
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
    load_scene_str_cached(text, source, resolver, options, None)
}

/// [`load_scene_str_with`] with meshes and images kept in `cache` across builds (the same
/// scene, bit for bit; [`super::cache`]).
pub fn load_scene_str_cached(
    text: &str,
    source: &Path,
    resolver: &dyn AssetResolver,
    options: LoadOptions,
    cache: Option<&MeshCache>,
) -> Result<Scene, SceneError> {
    let refuse = |errors: Vec<SceneError>| join_errors(errors).expect("check errs with some");
    let rec = parse_scene(text, source)?;
    options.check(&rec.warnings).map_err(refuse)?;
    let scene = match cache {
        Some(cache) => build_scene_cached(&rec, resolver, cache)?,
        None => build_scene(&rec, resolver)?,
    };
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

#[cfg(test)]
mod tests {
    use std::collections::HashMap;

    use super::*;
    use crate::assets::MemResolver;

    fn camera(id: u32, extra: &str) -> String {
        format!(
            "<Cameras><Camera id=\"{id}\"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>\
             <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>4 3</ImageResolution>\
             <ImageName>c{id}.png</ImageName>{extra}</Camera></Cameras>"
        )
    }

    /// A one-sphere scene with `extra` from line 2 (each extra block on a line of its own).
    fn scene(extra: &str) -> String {
        format!(
            "<Scene>\n{extra}\n{}\n<Materials><Material id=\"1\"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>\n\
             <VertexData>0 0 -2 1 0 -2 0 1 -2</VertexData>\n\
             <Objects><Sphere id=\"4\"><Material>1</Material><Center>1</Center><Radius>0.5</Radius></Sphere></Objects>\n</Scene>\n",
            camera(1, "")
        )
    }

    fn load(text: &str, options: LoadOptions) -> Result<Scene, SceneError> {
        let no_assets = MemResolver { files: HashMap::new(), base: String::new() };
        load_scene_str_with(text, Path::new("s.xml"), &no_assets, options)
    }

    const TEXTURE_MAPS: &str = "<Textures><TextureMap id=\"c1\" type=\"checkerboard\"><DecalMode>replace_kd</DecalMode></TextureMap>\
        <TextureMap id=\"c2\" type=\"checkerboard\"><DecalMode>replace_ks</DecalMode></TextureMap>\
        <TextureMap id=\"c3\" type=\"checkerboard\"><DecalMode>blend_kd</DecalMode></TextureMap></Textures>";

    /// (extra scene text, the element the error names, whether the scene builds without assets
    /// once allowed).
    fn unsupported_cases() -> Vec<(String, &'static str, bool)> {
        vec![(camera(3, "<Tonemap><TMO>Drago</TMO></Tonemap>"), "Camera id=\"3\"> / <Tonemap> / <TMO", true)]
    }

    #[test]
    fn each_unsupported_element_is_an_error_naming_its_line_and_element() {
        for (extra, element, _) in unsupported_cases() {
            let text = scene(&extra);
            let Err(e) = load(&text, LoadOptions::STRICT) else { panic!("loaded strictly:\n{text}") };
            let line =
                2 + extra.lines().take_while(|l| !l.contains(element.rsplit('<').next().unwrap())).count();
            assert_eq!(e.loc.element.as_deref(), Some(element), "{e}");
            assert_eq!(e.loc.line, Some(line as u32), "{e}");
            assert!(e.message.contains("not supported") || e.message.contains("too many"), "{e}");
            assert!(e.message.contains("--allow-unsupported"), "{e}");
            // The default of load_scene_str is strict too.
            let no_assets = MemResolver { files: HashMap::new(), base: String::new() };
            assert_eq!(load_scene_str(&text, Path::new("s.xml"), &no_assets).err(), Some(e));
        }
    }

    #[test]
    fn epsilons_no_scene_means_are_warnings_naming_their_line() {
        // The sphere of `scene` spans a box of diagonal about 1.73: a tenth of it is 0.173.
        let cases: &[(&str, Option<&str>)] = &[
            ("<ShadowRayEpsilon>-0.01</ShadowRayEpsilon>", Some("ShadowRayEpsilon -0.01 is negative")),
            (
                "<IntersectionTestEpsilon>-1e-6</IntersectionTestEpsilon>",
                Some("IntersectionTestEpsilon -1e-6 is negative"),
            ),
            (
                "<ShadowRayEpsilon>2e54</ShadowRayEpsilon>",
                Some("ShadowRayEpsilon 2e54 is more than a tenth of the scene's size (its objects span 1.7"),
            ),
            (
                "<IntersectionTestEpsilon>0.2</IntersectionTestEpsilon>",
                Some("is more than a tenth of the scene's size"),
            ),
            ("<ShadowRayEpsilon>0.1</ShadowRayEpsilon>", None),
            ("<ShadowRayEpsilon>0</ShadowRayEpsilon>", None),
            ("<IntersectionTestEpsilon>1e-9</IntersectionTestEpsilon>", None),
        ];
        for (extra, expected) in cases {
            let scene = load(&scene(extra), LoadOptions::STRICT).unwrap_or_else(|e| panic!("{extra}: {e}"));
            let found: Vec<&Warning> =
                scene.warnings.iter().filter(|w| w.message.contains("Epsilon")).collect();
            match expected {
                None => assert!(found.is_empty(), "{extra}: {found:?}"),
                Some(text) => {
                    assert_eq!(found.len(), 1, "{extra}: {:?}", scene.warnings);
                    let w = found[0];
                    assert!(w.message.contains(text), "{extra}: {w}");
                    assert!(w.message.contains("(the default)"), "{extra}: {w}");
                    assert_eq!(w.loc.line, Some(2), "{extra}: {w}");
                    let element = extra[1..].split('>').next().unwrap();
                    assert_eq!(w.loc.element.as_deref(), Some(element), "{extra}: {w}");
                }
            }
        }
    }

    #[test]
    fn allowed_unsupported_elements_are_warnings() {
        for (extra, element, builds) in unsupported_cases() {
            let text = scene(&extra);
            let records = parse_scene(&text, Path::new("s.xml")).unwrap();
            let w: Vec<&Warning> = records.warnings.iter().filter(|w| w.unsupported).collect();
            assert_eq!(w.len(), 1, "{:?}", records.warnings);
            assert_eq!(w[0].loc.element.as_deref(), Some(element));
            if builds {
                let scene = load(&text, LoadOptions::ALLOW_UNSUPPORTED).unwrap_or_else(|e| panic!("{e}"));
                let w: Vec<&Warning> = scene.warnings.iter().filter(|w| w.unsupported).collect();
                assert_eq!(w.len(), 1, "{:?}", scene.warnings);
                assert_eq!(w[0].loc.element.as_deref(), Some(element));
                assert!(w[0].to_string().starts_with("warning: s.xml:"), "{}", w[0]);
            }
        }
    }

    #[test]
    fn several_unsupported_elements_are_all_named() {
        let drago = |id: u32| camera(id, &format!("<Tonemap><TMO>Drago{id}</TMO></Tonemap>"));
        let text = scene(&format!("{}\n{}\n{}", drago(2), drago(3), drago(4)));
        let records = parse_scene(&text, Path::new("s.xml")).unwrap();
        let errors = LoadOptions::STRICT.check(&records.warnings).unwrap_err();
        let lines: Vec<Option<u32>> = errors.iter().map(|e| e.loc.line).collect();
        assert_eq!(lines, [Some(2), Some(3), Some(4)]);
        let Err(e) = load(&text, LoadOptions::STRICT) else { panic!("loaded") };
        let shown = e.to_string();
        assert_eq!(shown.lines().count(), 3, "{shown}");
        assert!(shown.starts_with("s.xml:2: <Camera id=\"2\"> / <Tonemap> / <TMO>: "), "{shown}");
        assert!(shown.contains("\ns.xml:3: <Camera id=\"3\"> / <Tonemap> / <TMO>: "), "{shown}");
        assert!(shown.contains("\ns.xml:4: <Camera id=\"4\"> / <Tonemap> / <TMO>: "), "{shown}");
        assert_eq!(LoadOptions::ALLOW_UNSUPPORTED.check(&records.warnings), Ok(()));
    }

    #[test]
    fn what_does_not_change_the_picture_stays_a_warning_or_is_accepted() {
        for (extra, warned) in [
            // An optimisation hint: not culling is the correct image.
            ("<BackfaceCulling>true</BackfaceCulling>", true),
            ("<BackfaceCulling>false</BackfaceCulling>", false),
            ("<ZeroBasedIndexing>false</ZeroBasedIndexing>", false),
            ("<ZeroBasedIndexing>true</ZeroBasedIndexing>", false),
            (
                "<Textures><TextureMap id=\"p\" type=\"perlin\"><DecalMode>replace_kd</DecalMode><NumOctaves>1</NumOctaves></TextureMap></Textures>",
                false,
            ),
            (
                "<Textures><Texture id=\"8\"><ImageName>checkerboard</ImageName><Dimension3>true</Dimension3></Texture></Textures>",
                false,
            ),
            (
                "<Textures><TextureMap id=\"p\" type=\"perlin\"><DecalMode>replace_kd</DecalMode><NumOctaves>3</NumOctaves></TextureMap></Textures>",
                false,
            ),
            (
                "<Textures><Texture id=\"8\"><ImageName>checkerboard</ImageName><Dimension3>false</Dimension3></Texture></Textures>",
                false,
            ),
            ("<Foo>1</Foo>", true),
        ] {
            let scene = load(&scene(extra), LoadOptions::STRICT).unwrap_or_else(|e| panic!("{extra}: {e}"));
            assert!(scene.warnings.iter().all(|w| !w.unsupported), "{:?}", scene.warnings);
            assert_eq!(!scene.warnings.is_empty(), warned, "{extra}: {:?}", scene.warnings);
        }
        // Three colour maps on one object (applied in order).
        let three = format!(
            "{TEXTURE_MAPS}\n<Objects><Sphere id=\"5\"><Material>1</Material><Center>2</Center><Radius>1</Radius>\
             <Textures>c1 c2 c3</Textures></Sphere></Objects>"
        );
        let scene = load(&scene(&three), LoadOptions::STRICT).unwrap_or_else(|e| panic!("{e}"));
        assert!(scene.warnings.is_empty(), "{:?}", scene.warnings);
    }
}
