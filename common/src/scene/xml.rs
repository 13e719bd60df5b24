//! XML front end: the 2020/21 CENG795 dialect (homeworks 1-4), plus the 2019 legacy rules for
//! materials (scene-format.md §6.1, §6.9) and the 2019 `<Texture>` / `<BackgroundTexture>`
//! elements, translated into 2020 texture maps (§11.11).
//!
//! Parsing happens in two steps:
//!
//! 1. [`read_tree`] turns the text into a small element tree ([`Node`]) with line numbers, using
//!    `quick-xml`. Everything about well-formedness is decided here.
//! 2. [`Parser`] walks the tree and fills [`SceneRecords`]. Because it looks children up by
//!    name, the order of elements inside `<Scene>` (and anywhere else) does not matter.
//!
//! Nothing is resolved here: ids stay strings, PLY files are not opened. Elements we do not know
//! become warnings, elements of the format that are not implemented yet become "not supported
//! yet" warnings, and everything a user can get wrong is a [`SceneError`] naming the file, the
//! line and the element. No input makes this module panic.

use std::borrow::Cow;
use std::path::Path;

use quick_xml::errors::{Error as XmlError, IllFormedError, SyntaxError};
use quick_xml::escape::resolve_predefined_entity;
use quick_xml::events::{BytesStart, Event};
use quick_xml::{Reader, XmlVersion};

use super::records::{
    AreaLightRec, CameraRec, DecalMode, DirectionalLightRec, EnvLightRec, EnvMapping, EnvSampler, FacesRec,
    Handedness, ImageRec, InstanceRec, Interpolation, LensRec, MAX_RECURSION_DEPTH_LIMIT, MaterialKind,
    MaterialRec, MeshRec, NoiseConversion, PlaneRec, PointLightRec, Projection, SceneRecords, ShadingMode,
    SphereRec, SpotLightRec, TextureMapRec, TextureSource, TonemapRec, TransformOp, TransformRec,
    TransformRef, TriangleRec, Vec3,
};
use crate::error::{Loc, SceneError, Warning};
use crate::tonemap::params::{Operator, Photographic};

type Result<T> = std::result::Result<T, SceneError>;

/// Parses a scene file of the XML dialect into plain records.
///
/// `source` is only used to name the file in errors and warnings and is stored in
/// [`SceneRecords::source`]; nothing is read from disk. Unknown elements and elements that are
/// not supported yet end up in [`SceneRecords::warnings`], in file order.
///
/// # Errors
///
/// A [`SceneError`] with line and element for malformed XML, a root other than `<Scene>`,
/// malformed numbers, missing required children or attributes, and invalid attribute values.
pub fn parse_xml(text: &str, source: &Path) -> Result<SceneRecords> {
    let root = read_tree(text, source)?;
    if root.name != "Scene" {
        return Err(SceneError::new(
            source,
            root.loc(),
            format!("the root element must be <Scene>, found <{}>; is this a scene file?", root.name),
        ));
    }
    parse_tree(&root, source, Dialect::Xml)
}

/// Which front end built the [`Node`] tree: only changes how messages name elements.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Dialect {
    Xml,
    /// The 2025 JSON encoding (scene-format.md §14): node labels are JSON paths, and messages
    /// say `"Faces"` / `"_id"` where the XML ones say `<Faces>` / `attribute id`.
    Json,
}

/// Step 2 for both front ends: walks a `<Scene>` tree into records.
pub(super) fn parse_tree(root: &Node, source: &Path, dialect: Dialect) -> Result<SceneRecords> {
    let mut parser = Parser {
        file: source,
        // The 2019 rules never apply to JSON files: they are 2025 scenes, and the 2025
        // references render an untyped MirrorReflectance as no mirror (rt_raven: 51.6 dB this
        // way, 17.2 dB with the 2019 rule).
        legacy: dialect == Dialect::Xml && is_legacy_2019(root),
        legacy_bumps: Vec::new(),
        dialect,
        out: SceneRecords::new(source),
    };
    if dialect == Dialect::Json {
        parser.out.json = true;
        // Measured: the 2025 references trace mirrors in scenes without MaxRecursionDepth.
        parser.out.max_recursion_depth = super::json::DEFAULT_MAX_RECURSION_DEPTH;
    }
    parser.scene(root)?;
    // Report in file order (the walk visits blocks, not lines); the sort is stable.
    parser.out.warnings.sort_by_key(|w| w.loc.line);
    Ok(parser.out)
}

// ---------------------------------------------------------------------------------------------
// Step 1: text -> element tree
// ---------------------------------------------------------------------------------------------

/// Deeper nesting than this is certainly not a scene file; refusing it keeps the recursive
/// walks (and dropping the tree) far away from stack overflows on hostile input.
const MAX_DEPTH: usize = 64;

/// One XML element with what the walk needs: name, attributes, text and where it was written.
#[derive(Debug)]
pub(super) struct Node {
    pub(super) name: String,
    /// How errors name this element: `Sphere id="2"`, or for an element inside a record its
    /// path from the record, `Camera id="1"> / <Position` (displayed by [`SceneError`] as
    /// `<Camera id="1"> / <Position>`).
    pub(super) label: String,
    /// Nesting depth: `<Scene>` is 1, `<Cameras>` 2, `<Camera>` 3, `<Position>` 4.
    pub(super) depth: usize,
    /// Line of the start tag.
    pub(super) line: u32,
    /// Line on which the element's text starts (after the start tag's `>`).
    pub(super) content_line: u32,
    pub(super) attrs: Vec<(String, String)>,
    /// The element's own character data, concatenated. Comments inside it are replaced by a
    /// space plus their newlines, so tokens keep their line numbers and a comment separates
    /// numbers (`1 2<!-- note -->3` reads as three numbers).
    pub(super) text: String,
    pub(super) children: Vec<Node>,
}

impl Node {
    fn loc(&self) -> Loc {
        Loc::new(self.line, self.label.clone())
    }

    fn attr(&self, key: &str) -> Option<&str> {
        self.attrs.iter().find(|(k, _)| k == key).map(|(_, v)| v.as_str())
    }

    /// The first child with this name (later duplicates are reported by [`Parser::check`]).
    fn child(&self, name: &str) -> Option<&Node> {
        self.children.iter().find(|c| c.name == name)
    }

    fn children_named<'a>(&'a self, name: &'a str) -> impl Iterator<Item = &'a Node> + 'a {
        self.children.iter().filter(move |c| c.name == name)
    }
}

/// Turns byte offsets into 1-based line numbers. Offsets mostly grow, so it counts forwards
/// from the last answer and only restarts from the top when asked about an earlier offset.
struct Lines<'a> {
    bytes: &'a [u8],
    offset: usize,
    line: u32,
}

impl<'a> Lines<'a> {
    fn new(text: &'a str) -> Self {
        Lines { bytes: text.as_bytes(), offset: 0, line: 1 }
    }

    fn line_at(&mut self, offset: u64) -> u32 {
        let offset = usize::try_from(offset).unwrap_or(usize::MAX).min(self.bytes.len());
        if offset < self.offset {
            self.offset = 0;
            self.line = 1;
        }
        let newlines = newline_count(&self.bytes[self.offset..offset]);
        self.line = self.line.saturating_add(u32::try_from(newlines).unwrap_or(u32::MAX));
        self.offset = offset;
        self.line
    }
}

fn newline_count(bytes: &[u8]) -> usize {
    bytes.iter().filter(|&&b| b == b'\n').count()
}

/// Reads the whole document into a tree and returns its root element.
fn read_tree(text: &str, file: &Path) -> Result<Node> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut reader = Reader::from_str(text);
    let mut lines = Lines::new(text);
    let mut stack: Vec<Node> = Vec::new();
    let mut root: Option<Node> = None;
    let file_err = |line: u32, message: String| SceneError::new(file, line_loc(line), message);

    loop {
        // Text is not trimmed, so the next event starts exactly here: for tags, at the `<`.
        let start = reader.buffer_position();
        let event = match reader.read_event() {
            Ok(event) => event,
            Err(e) => {
                let line = lines.line_at(reader.error_position());
                return Err(file_err(line, format!("malformed XML: {e}. Hint: {}", xml_hint(&e))));
            }
        };
        match event {
            Event::Start(tag) => {
                let line = lines.line_at(start);
                let content_line = lines.line_at(reader.buffer_position());
                let node = new_node(&tag, stack.last(), line, content_line, file)?;
                if stack.len() >= MAX_DEPTH {
                    return Err(SceneError::new(
                        file,
                        node.loc(),
                        format!(
                            "elements are nested more than {MAX_DEPTH} levels deep; this is not a scene file"
                        ),
                    ));
                }
                stack.push(node);
            }
            Event::Empty(tag) => {
                let line = lines.line_at(start);
                let node = new_node(&tag, stack.last(), line, line, file)?;
                attach(node, &mut stack, &mut root, file)?;
            }
            Event::End(_) => {
                // quick-xml has already checked that the name matches the open element.
                if let Some(node) = stack.pop() {
                    attach(node, &mut stack, &mut root, file)?;
                }
            }
            Event::Text(t) => push_text(&mut stack, &t, lines.line_at(start), file)?,
            Event::CData(t) => push_text(&mut stack, &t, lines.line_at(start), file)?,
            Event::GeneralRef(r) => {
                let line = lines.line_at(start);
                let resolved = match r.resolve_char_ref() {
                    Ok(Some(c)) => Cow::Owned(c.to_string()),
                    Ok(None) => match resolve_predefined_entity(&r) {
                        Some(s) => Cow::Borrowed(s),
                        None => {
                            return Err(file_err(
                                line,
                                format!("unknown entity &{};. Hint: write a literal & as &amp;", &*r),
                            ));
                        }
                    },
                    Err(e) => return Err(file_err(line, format!("bad character reference &{};: {e}", &*r))),
                };
                push_text(&mut stack, &resolved, line, file)?;
            }
            Event::Comment(c) => {
                if let Some(top) = stack.last_mut() {
                    top.text.push(' ');
                    top.text.extend(std::iter::repeat_n('\n', newline_count(c.as_bytes())));
                }
            }
            Event::Decl(_) | Event::PI(_) | Event::DocType(_) => {}
            Event::Eof => break,
        }
    }

    if let Some(open) = stack.last() {
        return Err(SceneError::new(
            file,
            open.loc(),
            format!("<{}> is never closed: the file ends first (is it truncated?)", open.name),
        ));
    }
    root.ok_or_else(|| {
        SceneError::file(file, "no XML element found: the file is empty or is not an XML scene")
    })
}

fn line_loc(line: u32) -> Loc {
    Loc { line: Some(line), element: None }
}

/// A short, practical hint for each kind of XML error.
fn xml_hint(e: &XmlError) -> &'static str {
    match e {
        XmlError::Syntax(
            SyntaxError::UnclosedTag
            | SyntaxError::UnclosedComment
            | SyntaxError::UnclosedCData
            | SyntaxError::UnclosedPI
            | SyntaxError::UnclosedXmlDecl
            | SyntaxError::UnclosedDoctype
            | SyntaxError::UnclosedSingleQuotedAttributeValue
            | SyntaxError::UnclosedDoubleQuotedAttributeValue,
        ) => {
            "the file ends inside a tag, comment or quoted value; is it truncated, or is a `>`, `-->` or quote missing?"
        }
        XmlError::IllFormed(IllFormedError::MismatchedEndTag { .. }) => {
            "every <Element> must be closed by its own </Element>, innermost first"
        }
        XmlError::IllFormed(IllFormedError::UnmatchedEndTag(_)) => {
            "this closing tag has no opening tag; is an opening tag misspelt or missing?"
        }
        XmlError::IllFormed(IllFormedError::UnclosedReference) | XmlError::Escape(_) => {
            "write a literal & as &amp; and < as &lt;"
        }
        XmlError::InvalidAttr(_) => r#"attributes are written name="value", with the value quoted"#,
        _ => {
            "check that the file is well-formed XML: tags closed and properly nested, attribute values quoted"
        }
    }
}

fn new_node(
    tag: &BytesStart,
    parent: Option<&Node>,
    line: u32,
    content_line: u32,
    file: &Path,
) -> Result<Node> {
    let name = tag.name().as_ref().to_string();
    let mut attrs = Vec::new();
    for attr in tag.attributes() {
        let attr = attr.map_err(|e| {
            SceneError::new(
                file,
                Loc::new(line, name.clone()),
                format!("malformed attribute: {e}. Hint: attributes are written name=\"value\""),
            )
        })?;
        let value = attr.normalized_value(XmlVersion::Implicit1_0).map_err(|e| {
            SceneError::new(file, Loc::new(line, name.clone()), format!("malformed attribute value: {e}"))
        })?;
        attrs.push((attr.key.as_ref().to_string(), value.into_owned()));
    }
    let own = match attrs.iter().find(|(k, _)| k == "id") {
        Some((_, id)) => format!(r#"{name} id="{id}""#),
        None => name.clone(),
    };
    let depth = parent.map_or(1, |p| p.depth + 1);
    // Records (Camera, Material, Sphere, ...) sit at depth 3; inside them, name the path from
    // the record so that `<Position>` says which camera it belongs to.
    let label = match parent {
        Some(p) if p.depth >= 3 => format!("{}> / <{own}", p.label),
        _ => own,
    };
    Ok(Node { name, label, depth, line, content_line, attrs, text: String::new(), children: Vec::new() })
}

fn attach(node: Node, stack: &mut [Node], root: &mut Option<Node>, file: &Path) -> Result<()> {
    if let Some(parent) = stack.last_mut() {
        parent.children.push(node);
    } else if root.is_none() {
        *root = Some(node);
    } else {
        return Err(SceneError::new(
            file,
            node.loc(),
            format!("a second top-level element <{}>; a scene file has exactly one <Scene>", node.name),
        ));
    }
    Ok(())
}

fn push_text(stack: &mut [Node], text: &str, line: u32, file: &Path) -> Result<()> {
    match stack.last_mut() {
        Some(top) => top.text.push_str(text),
        None if text.trim().is_empty() => {}
        None => {
            return Err(SceneError::new(
                file,
                line_loc(line),
                format!("text \"{}\" outside of any element; is this an XML scene file?", excerpt(text)),
            ));
        }
    }
    Ok(())
}

/// The 2019 dialect has no `type` on materials and no `TextureMap`s (scene-format.md §1.2, §6.1).
fn is_legacy_2019(root: &Node) -> bool {
    fn has_texture_map(node: &Node) -> bool {
        node.name == "TextureMap" || node.children.iter().any(has_texture_map)
    }
    let typed_material = root
        .children_named("Materials")
        .flat_map(|ms| ms.children_named("Material"))
        .any(|m| m.attr("type").is_some());
    !typed_material && !has_texture_map(root)
}

/// Up to about 60 characters of `text`, whitespace runs collapsed, for quoting in messages.
fn excerpt(text: &str) -> String {
    const MAX: usize = 60;
    let mut out = String::new();
    for token in text.split_ascii_whitespace() {
        if !out.is_empty() {
            out.push(' ');
        }
        if out.len() + token.len() > MAX {
            out.extend(token.chars().take(MAX.saturating_sub(out.len())));
            out.push_str("...");
            break;
        }
        out.push_str(token);
    }
    out
}

/// `text` quoted for a message (see [`excerpt`]), or `nothing` when it is blank.
fn quoted(text: &str) -> String {
    match excerpt(text) {
        e if e.is_empty() => "nothing".to_string(),
        e => format!("\"{e}\""),
    }
}

/// Whitespace-separated tokens of `text` with the 0-based line (relative to the text start)
/// each one is on. Any ASCII whitespace separates (spaces, tabs, LF, CRLF).
fn tokens(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.split_inclusive('\n')
        .enumerate()
        .flat_map(|(i, line)| line.split_ascii_whitespace().map(move |t| (i, t)))
}

// ---------------------------------------------------------------------------------------------
// Numbers
// ---------------------------------------------------------------------------------------------

/// A value that appears as a whitespace-separated token in element text.
trait Token: Copy + Default {
    /// "a number", "an integer"...
    const ONE: &'static str;
    /// "numbers", "integers"...
    const MANY: &'static str;
    fn parse(token: &str) -> Option<Self>;
}

impl Token for f64 {
    const ONE: &'static str = "a number";
    const MANY: &'static str = "numbers";
    fn parse(token: &str) -> Option<Self> {
        // Rust also accepts "inf" and "NaN"; no scene means those.
        token.parse::<f64>().ok().filter(|x| x.is_finite())
    }
}

impl Token for i64 {
    const ONE: &'static str = "an integer";
    const MANY: &'static str = "integers";
    fn parse(token: &str) -> Option<Self> {
        token.parse().ok()
    }
}

impl Token for u32 {
    const ONE: &'static str = "a non-negative integer";
    const MANY: &'static str = "non-negative integers";
    fn parse(token: &str) -> Option<Self> {
        token.parse().ok()
    }
}

fn expected<T: Token>(n: usize) -> String {
    if n == 1 { T::ONE.to_string() } else { format!("{n} {}", T::MANY) }
}

// ---------------------------------------------------------------------------------------------
// Step 2: tree -> records
// ---------------------------------------------------------------------------------------------

/// What an element may contain, for the unknown / not-supported-yet warnings.
struct Schema {
    /// Children read by the parser, at most one of each (later copies are warned about).
    single: &'static [&'static str],
    /// Children read by the parser that may repeat (list entries and containers).
    many: &'static [&'static str],
    /// Children that belong to the format but are not implemented yet.
    unsupported: &'static [&'static str],
    attrs: &'static [&'static str],
    unsupported_attrs: &'static [&'static str],
    /// Children that belong to a sibling variant (another kind of texture) and mean nothing
    /// here; warned about with `inapplicable_why` ("does not apply to ...").
    inapplicable: &'static [&'static str],
    inapplicable_why: &'static str,
}

impl Schema {
    const EMPTY: Schema = Schema {
        single: &[],
        many: &[],
        unsupported: &[],
        attrs: &[],
        unsupported_attrs: &[],
        inapplicable: &[],
        inapplicable_why: "",
    };
}

const SCENE: Schema = Schema {
    // BackgroundTexture, BackfaceCulling and ZeroBasedIndexing are 2019 elements.
    single: &[
        "BackgroundColor",
        "ShadowRayEpsilon",
        "IntersectionTestEpsilon",
        "MaxRecursionDepth",
        "VertexData",
        "TexCoordData",
        "BackgroundTexture",
    ],
    many: &["Cameras", "Lights", "Materials", "Transformations", "Objects", "Textures"],
    unsupported: &["BRDFs", "BackfaceCulling", "ZeroBasedIndexing"],
    ..Schema::EMPTY
};
const CAMERAS: Schema = Schema { many: &["Camera"], ..Schema::EMPTY };
const CAMERA: Schema = Schema {
    single: &[
        "Position",
        "Gaze",
        "GazePoint",
        "Up",
        "NearPlane",
        "FovY",
        "NearDistance",
        "ImageResolution",
        "ImageName",
        "NumSamples",
        "FocusDistance",
        "ApertureSize",
        "Transformations",
    ],
    many: &["Tonemap"],
    unsupported: &["Renderer", "RendererParams", "ClampSamples"],
    attrs: &["id", "type", "handedness"],
    ..Schema::EMPTY
};
const LIGHTS: Schema = Schema {
    single: &["AmbientLight"],
    many: &["PointLight", "AreaLight", "DirectionalLight", "SpotLight", "SphericalDirectionalLight"],
    ..Schema::EMPTY
};
// Cameras and lights take `Transformations` in 2025 scenes (§10.4).
const DIRECTIONAL_LIGHT: Schema =
    Schema { single: &["Direction", "Radiance", "Transformations"], attrs: &["id"], ..Schema::EMPTY };
const SPOT_LIGHT: Schema = Schema {
    single: &["Position", "Direction", "Intensity", "CoverageAngle", "FalloffAngle", "Transformations"],
    attrs: &["id"],
    ..Schema::EMPTY
};
/// `EnvMapName` is the 2019 form of `ImageId`; `Sampler` and `type` are 2025 additions (Tessera
/// also reads `Sampler importance`).
const ENV_LIGHT: Schema =
    Schema { single: &["ImageId", "EnvMapName", "Sampler"], attrs: &["id", "type"], ..Schema::EMPTY };
const TONEMAP: Schema =
    Schema { single: &["TMO", "TMOOptions", "Saturation", "Gamma", "Extension"], ..Schema::EMPTY };
const ENV_MAPPINGS: &[(&str, EnvMapping)] = &[("latlong", EnvMapping::LatLong), ("probe", EnvMapping::Probe)];
const ENV_SAMPLERS: &[(&str, EnvSampler)] = &[
    ("uniform", EnvSampler::Uniform),
    ("cosine", EnvSampler::Cosine),
    ("importance", EnvSampler::Importance),
];
const POINT_LIGHT: Schema =
    Schema { single: &["Position", "Intensity", "Transformations"], attrs: &["id"], ..Schema::EMPTY };
const AREA_LIGHT: Schema = Schema {
    single: &["Position", "Normal", "Size", "Radiance", "Transformations"],
    attrs: &["id"],
    ..Schema::EMPTY
};
const MATERIALS: Schema = Schema { many: &["Material"], ..Schema::EMPTY };
const MATERIAL: Schema = Schema {
    single: &[
        "AmbientReflectance",
        "DiffuseReflectance",
        "SpecularReflectance",
        "MirrorReflectance",
        "PhongExponent",
        "RefractionIndex",
        "AbsorptionIndex",
        "AbsorptionCoefficient",
        "Roughness",
        "Transparency",
    ],
    attrs: &["id", "type", "degamma"],
    unsupported_attrs: &["BRDF"],
    ..Schema::EMPTY
};
const TRANSFORMATIONS: Schema =
    Schema { many: &["Translation", "Scaling", "Rotation", "Composite"], ..Schema::EMPTY };
const TRANSFORMATION: Schema = Schema { attrs: &["id"], ..Schema::EMPTY };
const OBJECTS: Schema = Schema {
    // Plane only exists in the 2025 JSON dialect so far (§9.8); XML files may use it too.
    many: &["Mesh", "Triangle", "Sphere", "MeshInstance", "Plane"],
    unsupported: &["LightMesh", "LightSphere"],
    ..Schema::EMPTY
};
// `Texture` is the 2019 spelling of an object's `Textures`. Both are read (and their repeats
// checked) by `Parser::object_textures`.
const MESH: Schema = Schema {
    single: &["Material", "Faces", "Transformations", "MotionBlur"],
    many: &["Textures", "Texture"],
    attrs: &["id", "shadingMode"],
    ..Schema::EMPTY
};
const TRIANGLE: Schema = Schema {
    single: &["Material", "Indices", "Transformations"],
    many: &["Textures", "Texture"],
    unsupported: &["MotionBlur"],
    attrs: &["id"],
    ..Schema::EMPTY
};
const SPHERE: Schema = Schema {
    single: &["Material", "Center", "Radius", "Transformations", "MotionBlur"],
    many: &["Textures", "Texture"],
    attrs: &["id"],
    ..Schema::EMPTY
};
const PLANE: Schema = Schema {
    single: &["Material", "Point", "Normal", "Transformations", "MotionBlur"],
    many: &["Textures", "Texture"],
    attrs: &["id"],
    ..Schema::EMPTY
};
const MESH_INSTANCE: Schema = Schema {
    single: &["Material", "Transformations", "MotionBlur"],
    unsupported: &["Textures", "Texture"],
    attrs: &["id", "baseMeshId", "resetTransform", "shadingMode"],
    ..Schema::EMPTY
};
// Also used for `TexCoordData`.
// `type` is the 2025 JSON `_type` (`xyz`, `uv`), checked by `Parser::data_type`.
const VERTEX_DATA_ATTRS: &[&str] = &["type"];
const VERTEX_DATA_UNSUPPORTED_ATTRS: &[&str] = &["binaryFile"];
// `binaryFile` is known here but handled by `Parser::mesh` (the mesh is skipped).
const FACES_ATTRS: &[&str] = &["vertexOffset", "textureOffset", "plyFile", "binaryFile", "type"];
const FACES_UNSUPPORTED_ATTRS: &[&str] = &[];

// --- textures (HW4, scene-format.md §11) ---

const TEXTURES: Schema = Schema { many: &["Images", "TextureMap", "Texture"], ..Schema::EMPTY };
const IMAGES: Schema = Schema { many: &["Image"], ..Schema::EMPTY };
const IMAGE: Schema = Schema { attrs: &["id"], ..Schema::EMPTY };
const TEXTURE_MAP_ATTRS: &[&str] = &["id", "type", "degamma"];
const IMAGE_MAP: Schema = Schema {
    single: &["DecalMode", "ImageId", "Interpolation", "Normalizer", "BumpFactor"],
    attrs: TEXTURE_MAP_ATTRS,
    inapplicable: &[
        "NoiseConversion",
        "NoiseScale",
        "NumOctaves",
        "BlackColor",
        "WhiteColor",
        "Scale",
        "Offset",
    ],
    inapplicable_why: "does not apply to image texture maps",
    ..Schema::EMPTY
};
const PERLIN_MAP: Schema = Schema {
    single: &["DecalMode", "NoiseConversion", "NoiseScale", "BumpFactor"],
    // 2025 scenes: fractal sum of octaves.
    unsupported: &["NumOctaves"],
    attrs: TEXTURE_MAP_ATTRS,
    inapplicable: &["ImageId", "Interpolation", "Normalizer", "BlackColor", "WhiteColor", "Scale", "Offset"],
    inapplicable_why: "does not apply to perlin texture maps",
    ..Schema::EMPTY
};
const CHECKERBOARD_MAP: Schema = Schema {
    single: &["DecalMode", "BlackColor", "WhiteColor", "Scale", "Offset", "BumpFactor"],
    attrs: TEXTURE_MAP_ATTRS,
    inapplicable: &["ImageId", "Interpolation", "Normalizer", "NoiseConversion", "NoiseScale", "NumOctaves"],
    inapplicable_why: "does not apply to checkerboard texture maps",
    ..Schema::EMPTY
};
/// 2019 `<Texture>` (§11.11); which children apply depends on `ImageName`.
const LEGACY_TEXTURE_ATTRS: &[&str] = &["id", "bumpmap", "bumpmapMultiplier", "degamma"];
const LEGACY_IMAGE_TEXTURE: Schema = Schema {
    single: &["ImageName", "DecalMode", "Interpolation", "Normalizer", "Appearance"],
    attrs: LEGACY_TEXTURE_ATTRS,
    inapplicable: &["ScalingFactor", "Offset", "BlackColor", "WhiteColor", "Dimension3"],
    inapplicable_why: "does not apply to image textures",
    ..Schema::EMPTY
};
const LEGACY_PERLIN_TEXTURE: Schema = Schema {
    single: &["ImageName", "DecalMode", "Normalizer", "Appearance", "ScalingFactor"],
    attrs: LEGACY_TEXTURE_ATTRS,
    inapplicable: &["Interpolation", "Offset", "BlackColor", "WhiteColor", "Dimension3"],
    inapplicable_why: "does not apply to perlin textures",
    ..Schema::EMPTY
};
// `Dimension3` is accepted and ignored: the 2020 checkerboard is always 3-D.
const LEGACY_CHECKERBOARD_TEXTURE: Schema = Schema {
    single: &[
        "ImageName",
        "DecalMode",
        "Normalizer",
        "ScalingFactor",
        "Offset",
        "BlackColor",
        "WhiteColor",
        "Dimension3",
    ],
    attrs: LEGACY_TEXTURE_ATTRS,
    inapplicable: &["Interpolation", "Appearance"],
    inapplicable_why: "does not apply to checkerboard textures",
    ..Schema::EMPTY
};

const DECAL_MODES: &[(&str, DecalMode)] = &[
    ("replace_kd", DecalMode::ReplaceKd),
    ("blend_kd", DecalMode::BlendKd),
    ("replace_ks", DecalMode::ReplaceKs),
    ("replace_all", DecalMode::ReplaceAll),
    ("replace_normal", DecalMode::ReplaceNormal),
    ("bump_normal", DecalMode::BumpNormal),
    ("replace_background", DecalMode::ReplaceBackground),
];
/// 2019 files: the 2020 names plus the short spellings of the 2019 assignment text.
static LEGACY_DECAL_MODES: std::sync::LazyLock<Vec<(&str, DecalMode)>> = std::sync::LazyLock::new(|| {
    let mut modes = DECAL_MODES.to_vec();
    modes.extend([("replace", DecalMode::ReplaceKd), ("blend", DecalMode::BlendKd)]);
    modes
});
const INTERPOLATIONS: &[(&str, Interpolation)] = &[
    ("nearest", Interpolation::Nearest),
    ("bilinear", Interpolation::Bilinear),
    ("trilinear", Interpolation::Trilinear),
];
const NOISE_CONVERSIONS: &[(&str, NoiseConversion)] =
    &[("linear", NoiseConversion::Linear), ("absval", NoiseConversion::AbsVal)];
/// 2019 `<Appearance>` of perlin textures.
const LEGACY_PERLIN_APPEARANCES: &[(&str, NoiseConversion)] =
    &[("patch", NoiseConversion::Linear), ("vein", NoiseConversion::AbsVal)];
/// 2019 `<Appearance>` of image textures: is it `clamp`?
const LEGACY_IMAGE_APPEARANCES: &[(&str, bool)] = &[("repeat", false), ("clamp", true)];

/// Image and texture-map id of a 2019 `<BackgroundTexture>`.
const BACKGROUND_TEXTURE_ID: &str = "2019:background";
/// Prefix of the image ids made for 2019 `<EnvMapName>` paths (followed by the light's number).
const ENV_MAP_IMAGE_ID: &str = "2019:envmap";

#[derive(Clone, Copy)]
enum MapKind {
    Image,
    Perlin,
    Checkerboard,
}

/// "a", "a or b", "a, b or c".
fn one_of<T>(options: &[(&str, T)]) -> String {
    let names: Vec<&str> = options.iter().map(|(name, _)| *name).collect();
    match names.split_last() {
        None => String::new(),
        Some((last, [])) => (*last).to_string(),
        Some((last, rest)) => format!("{} or {last}", rest.join(", ")),
    }
}

struct Parser<'a> {
    file: &'a Path,
    /// 2019 dialect: untyped MirrorReflectance / Transparency make mirrors / dielectrics.
    legacy: bool,
    /// 2019 `<Texture bumpmap="true">` ids with the id of the extra bump map made for each,
    /// so that an object's `<Texture>k</Texture>` can refer to both maps.
    legacy_bumps: Vec<(String, String)>,
    dialect: Dialect,
    out: SceneRecords,
}

impl Parser<'_> {
    // --- reporting ---

    fn err(&self, node: &Node, message: impl Into<String>) -> SceneError {
        SceneError::new(self.file, node.loc(), self.say(message.into()))
    }

    fn warn(&mut self, node: &Node, message: impl Into<String>) {
        let message = self.say(message.into());
        self.out.warnings.push(Warning { file: self.file.to_path_buf(), loc: node.loc(), message });
    }

    /// A message in the words of the file's dialect (see [`super::json::json_words`]).
    fn say(&self, message: String) -> String {
        match self.dialect {
            Dialect::Xml => message,
            Dialect::Json => super::json::json_words(&message),
        }
    }

    /// Warns about every child or attribute of `node` that `schema` does not read, and about
    /// repeated single children. Children of the single children (which hold plain values)
    /// are warned about here too; list entries and containers are checked by their own parsers.
    fn check(&mut self, node: &Node, schema: &Schema) {
        self.check_attrs(node, schema.attrs, schema.unsupported_attrs);
        for (i, child) in node.children.iter().enumerate() {
            let name = child.name.as_str();
            if schema.single.contains(&name) {
                if node.children[..i].iter().any(|c| c.name == name) {
                    self.warn(child, format!("<{name}> is given more than once; only the first one is used"));
                }
                for grandchild in &child.children {
                    self.warn(grandchild, format!("unknown element <{}>; it is ignored", grandchild.name));
                }
            } else if schema.unsupported.contains(&name) {
                self.warn(child, format!("<{name}> is not supported yet; it is ignored"));
            } else if schema.inapplicable.contains(&name) {
                self.warn(child, format!("<{name}> {}; it is ignored", schema.inapplicable_why));
            } else if !schema.many.contains(&name) {
                self.warn(child, format!("unknown element <{name}>; it is ignored"));
            }
        }
    }

    fn check_attrs(&mut self, node: &Node, known: &[&str], unsupported: &[&str]) {
        for (key, _) in &node.attrs {
            if unsupported.contains(&key.as_str()) {
                self.warn(node, format!("attribute {key} is not supported yet; it is ignored"));
            } else if !known.contains(&key.as_str()) {
                self.warn(node, format!("unknown attribute {key}; it is ignored"));
            }
        }
    }

    // --- values ---

    fn required<'n>(&self, parent: &'n Node, name: &str) -> Result<&'n Node> {
        parent.child(name).ok_or_else(|| match self.dialect {
            Dialect::Xml => self.err(parent, format!("missing <{name}>")),
            // Name the JSON path of the missing key itself, e.g. `Scene.Objects.Mesh[3].Faces`.
            Dialect::Json => SceneError::new(
                self.file,
                Loc::new(parent.line, format!("{}.{name}", parent.label)),
                format!("missing \"{name}\"; add the key \"{name}\" to {}", parent.label),
            ),
        })
    }

    /// The first `N` tokens of `node`'s text; extra tokens are ignored (scene-format.md §2).
    fn numbers<T: Token, const N: usize>(&self, node: &Node) -> Result<[T; N]> {
        let mut out = [T::default(); N];
        let mut toks = node.text.split_ascii_whitespace();
        for slot in &mut out {
            *slot = toks.next().and_then(T::parse).ok_or_else(|| {
                self.err(node, format!("expected {}, found {}", expected::<T>(N), quoted(&node.text)))
            })?;
        }
        Ok(out)
    }

    fn number<T: Token>(&self, node: &Node) -> Result<T> {
        let [x] = self.numbers::<T, 1>(node)?;
        Ok(x)
    }

    fn required_numbers<T: Token, const N: usize>(&self, parent: &Node, name: &str) -> Result<[T; N]> {
        self.numbers(self.required(parent, name)?)
    }

    fn optional_numbers<T: Token, const N: usize>(
        &self,
        parent: &Node,
        name: &str,
    ) -> Result<Option<[T; N]>> {
        parent.child(name).map(|c| self.numbers(c)).transpose()
    }

    fn required_number<T: Token>(&self, parent: &Node, name: &str) -> Result<T> {
        self.number(self.required(parent, name)?)
    }

    fn optional_number<T: Token>(&self, parent: &Node, name: &str) -> Result<Option<T>> {
        parent.child(name).map(|c| self.number(c)).transpose()
    }

    /// All tokens of `node`'s text, whose count must be a multiple of `group` (`per` says what
    /// a group is, for the message). An error points at the line of the offending token.
    fn number_list<T: Token>(&self, node: &Node, group: usize, per: &str) -> Result<Vec<T>> {
        let mut out = Vec::new();
        for (line, token) in tokens(&node.text) {
            let value = T::parse(token).ok_or_else(|| {
                let line = node.content_line.saturating_add(u32::try_from(line).unwrap_or(u32::MAX));
                SceneError::new(
                    self.file,
                    Loc::new(line, node.label.clone()),
                    format!("expected {}, found \"{}\"", T::MANY, excerpt(token)),
                )
            })?;
            out.push(value);
        }
        if out.len() % group != 0 {
            return Err(self.err(
                node,
                format!("the number of values must be a multiple of {group} ({per}), found {}", out.len()),
            ));
        }
        Ok(out)
    }

    /// Trimmed text that must not be empty; `what` names it for the message.
    fn text<'n>(&self, node: &'n Node, what: &str) -> Result<&'n str> {
        match node.text.trim() {
            "" => Err(self.err(node, format!("expected {what}, found nothing"))),
            text => Ok(text),
        }
    }

    /// A reference to another element by id: one token.
    fn id_ref(&self, node: &Node, what: &str) -> Result<String> {
        let text = self.text(node, what)?;
        if text.split_ascii_whitespace().nth(1).is_some() {
            return Err(self.err(node, format!("expected {what}, found {}", quoted(text))));
        }
        Ok(text.to_string())
    }

    /// The `id` attribute; elements that others refer to (materials, transformations, meshes)
    /// must have one, for the rest it is only used in messages.
    fn id(&self, node: &Node, required: bool) -> Result<String> {
        match node.attr("id") {
            Some(id) => Ok(id.trim().to_string()),
            None if required => {
                Err(self.err(node, "missing attribute id (other elements refer to it by id)"))
            }
            None => Ok(String::new()),
        }
    }

    fn bool_attr(&self, node: &Node, key: &str) -> Result<Option<bool>> {
        match node.attr(key).map(str::trim) {
            None => Ok(None),
            Some("true") => Ok(Some(true)),
            Some("false") => Ok(Some(false)),
            Some(other) => {
                Err(self.err(node, format!("attribute {key} must be true or false, found \"{other}\"")))
            }
        }
    }

    /// An integer attribute such as `vertexOffset`.
    fn int_attr(&self, node: &Node, key: &str) -> Result<Option<i64>> {
        node.attr(key)
            .map(|v| {
                <i64 as Token>::parse(v.trim()).ok_or_else(|| {
                    self.err(node, format!("attribute {key} must be an integer, found \"{}\"", excerpt(v)))
                })
            })
            .transpose()
    }

    /// A number attribute such as `bumpmapMultiplier`.
    fn number_attr(&self, node: &Node, key: &str) -> Result<Option<f64>> {
        node.attr(key)
            .map(|v| {
                <f64 as Token>::parse(v.trim()).ok_or_else(|| {
                    self.err(node, format!("attribute {key} must be a number, found \"{}\"", excerpt(v)))
                })
            })
            .transpose()
    }

    /// The text of `node`, which must be one of the `options` (e.g. a DecalMode).
    fn keyword<T: Copy>(&self, node: &Node, options: &[(&str, T)]) -> Result<T> {
        let value = node.text.trim();
        match options.iter().find(|(name, _)| *name == value) {
            Some(&(_, v)) => Ok(v),
            None => Err(self.err(
                node,
                format!("{} must be {}, found {}", node.name, one_of(options), quoted(&node.text)),
            )),
        }
    }

    fn optional_keyword<T: Copy>(
        &self,
        parent: &Node,
        name: &str,
        options: &[(&str, T)],
    ) -> Result<Option<T>> {
        parent.child(name).map(|c| self.keyword(c, options)).transpose()
    }

    /// `<Normalizer>`, which divides texel values and so must be positive.
    fn normalizer(&self, parent: &Node) -> Result<Option<f64>> {
        let Some(n) = parent.child("Normalizer") else { return Ok(None) };
        match self.number::<f64>(n)? {
            v if v > 0.0 => Ok(Some(v)),
            v => Err(self.err(
                n,
                format!("Normalizer must be positive, found {v} (texel values are divided by it; 255 for 8-bit images)"),
            )),
        }
    }

    fn shading_attr(&self, node: &Node) -> Result<Option<ShadingMode>> {
        match node.attr("shadingMode").map(str::trim) {
            None => Ok(None),
            Some("smooth") => Ok(Some(ShadingMode::Smooth)),
            Some("flat") => Ok(Some(ShadingMode::Flat)),
            Some(other) => {
                Err(self
                    .err(node, format!("attribute shadingMode must be smooth or flat, found \"{other}\"")))
            }
        }
    }

    /// The first of two alternative children (e.g. `GazePoint` / `Gaze`), warning when both
    /// are given and the second is ignored.
    fn either<'n>(&mut self, parent: &'n Node, first: &str, second: &str) -> Option<&'n Node> {
        match (parent.child(first), parent.child(second)) {
            (Some(a), Some(b)) => {
                self.warn(b, format!("<{second}> is ignored because <{first}> is given"));
                Some(a)
            }
            (a, b) => a.or(b),
        }
    }

    // --- elements ---

    fn scene(&mut self, scene: &Node) -> Result<()> {
        self.check(scene, &SCENE);
        if let Some(c) = self.optional_numbers(scene, "BackgroundColor")? {
            self.out.background_color = c;
        }
        if let Some(e) = self.optional_number(scene, "ShadowRayEpsilon")? {
            self.out.shadow_ray_epsilon = e;
        }
        if let Some(e) = self.optional_number(scene, "IntersectionTestEpsilon")? {
            self.out.intersection_test_epsilon = e;
        }
        if let Some(d) = self.optional_number::<u32>(scene, "MaxRecursionDepth")? {
            self.out.max_recursion_depth = d.min(MAX_RECURSION_DEPTH_LIMIT);
            if d > MAX_RECURSION_DEPTH_LIMIT {
                let node = scene.child("MaxRecursionDepth").expect("just read");
                self.warn(
                    node,
                    format!(
                        "MaxRecursionDepth {d} is more than Tessera traces; it is capped to {MAX_RECURSION_DEPTH_LIMIT} \
                         (each bounce past a few dozen changes no pixel of an 8-bit or tone-mapped image)"
                    ),
                );
            }
        }
        if let Some(v) = scene.child("VertexData") {
            self.vertex_data(v)?;
        }
        if let Some(t) = scene.child("TexCoordData") {
            self.tex_coord_data(t)?;
        }
        // Textures before objects: a 2019 object's `<Texture>` needs to know which textures
        // also bump (see `legacy_bumps`).
        for block in scene.children_named("Textures") {
            self.textures(block)?;
        }
        if let Some(b) = scene.child("BackgroundTexture") {
            self.background_texture(b)?;
        }
        for block in &scene.children {
            match block.name.as_str() {
                "Cameras" => {
                    self.check(block, &CAMERAS);
                    for camera in block.children_named("Camera") {
                        let camera = self.camera(camera)?;
                        self.out.cameras.push(camera);
                    }
                }
                "Lights" => self.lights(block)?,
                "Materials" => {
                    self.check(block, &MATERIALS);
                    for material in block.children_named("Material") {
                        let material = self.material(material)?;
                        self.out.materials.push(material);
                    }
                }
                "Transformations" => {
                    self.check(block, &TRANSFORMATIONS);
                    for t in &block.children {
                        if let Some(t) = self.transformation(t)? {
                            self.out.transformations.push(t);
                        }
                    }
                }
                "Objects" => self.objects(block)?,
                _ => {}
            }
        }
        Ok(())
    }

    fn camera(&mut self, n: &Node) -> Result<CameraRec> {
        self.check(n, &CAMERA);
        let look_at = match n.attr("type").map(str::trim) {
            None => false,
            Some("lookAt") => true,
            Some(other) => {
                return Err(
                    self.err(n, format!("unknown camera type \"{other}\" (expected lookAt, or no type)"))
                );
            }
        };
        let handedness = match n.attr("handedness").map(str::trim) {
            None | Some("right") => Handedness::Right,
            Some("left") => Handedness::Left,
            Some(other) => {
                return Err(
                    self.err(n, format!("attribute handedness must be left or right, found \"{other}\""))
                );
            }
        };
        let position: Vec3 = self.required_numbers(n, "Position")?;

        // Each camera type has its own way of giving the view direction and the image plane;
        // the other way is accepted as a fallback.
        let (gaze_first, gaze_second) = if look_at { ("GazePoint", "Gaze") } else { ("Gaze", "GazePoint") };
        let gaze = match self.either(n, gaze_first, gaze_second) {
            Some(g) if g.name == "GazePoint" => {
                let [x, y, z]: Vec3 = self.numbers(g)?;
                [x - position[0], y - position[1], z - position[2]]
            }
            Some(g) => self.numbers(g)?,
            None => return Err(self.err(n, format!("missing <{gaze_first}> (or <{gaze_second}>)"))),
        };
        let (plane_first, plane_second) = if look_at { ("FovY", "NearPlane") } else { ("NearPlane", "FovY") };
        let projection = match self.either(n, plane_first, plane_second) {
            Some(p) if p.name == "FovY" => {
                let fov = self.number::<f64>(p)?;
                if !(fov > 0.0 && fov < 180.0) {
                    return Err(self.err(p, format!("FovY must be between 0 and 180 degrees, found {fov}")));
                }
                Projection::FovY(fov)
            }
            Some(p) => {
                let [left, right, bottom, top] = self.numbers(p)?;
                Projection::NearPlane { left, right, bottom, top }
            }
            None => return Err(self.err(n, format!("missing <{plane_first}> (or <{plane_second}>)"))),
        };

        let up = self.required_numbers(n, "Up")?;
        let near_distance = self.required_number(n, "NearDistance")?;
        let resolution = self.required(n, "ImageResolution")?;
        let [width, height] = self.numbers::<u32, 2>(resolution)?;
        if width == 0 || height == 0 {
            return Err(self.err(
                resolution,
                format!("the image must be at least 1 x 1 pixels, found {width} x {height}"),
            ));
        }
        let image_name = self.text(self.required(n, "ImageName")?, "an image file name")?.to_string();
        let num_samples = match n.child("NumSamples") {
            None => 1,
            Some(s) => match self.number::<u32>(s)? {
                0 => return Err(self.err(s, "NumSamples must be at least 1")),
                k => k,
            },
        };
        let focus: Option<f64> = self.optional_number(n, "FocusDistance")?;
        let aperture: Option<f64> = self.optional_number(n, "ApertureSize")?;
        let lens = match (focus, aperture) {
            (Some(focus_distance), Some(aperture_size)) if aperture_size > 0.0 => {
                // The parser rejects NaN, so this is the only way to be non-positive.
                if focus_distance <= 0.0 {
                    let node = n.child("FocusDistance").unwrap_or(n);
                    return Err(
                        self.err(node, format!("FocusDistance must be positive, found {focus_distance}"))
                    );
                }
                Some(LensRec { focus_distance, aperture_size })
            }
            (Some(_), None) | (None, Some(_)) => {
                self.warn(n, "depth of field needs both <FocusDistance> and <ApertureSize>; rendering as a pinhole camera");
                None
            }
            _ => None,
        };
        let mut tonemaps = Vec::new();
        for t in n.children_named("Tonemap") {
            tonemaps.push(self.tonemap(t)?);
        }
        Ok(CameraRec {
            id: self.id(n, false)?,
            loc: n.loc(),
            position,
            gaze,
            up,
            transforms: self.transform_refs(n)?,
            projection,
            near_distance,
            width,
            height,
            image_name,
            handedness,
            num_samples,
            lens,
            tonemaps,
        })
    }

    /// A camera's `<Tonemap>` (§12.2); absent children take the student-parser defaults.
    fn tonemap(&mut self, n: &Node) -> Result<TonemapRec> {
        self.check(n, &TONEMAP);
        let mut params = Photographic::default();
        let mut operator = Operator::Photographic;
        if let Some(t) = n.child("TMO") {
            match t.text.parse::<Operator>() {
                Ok(op) => operator = op,
                Err(_) => self.warn(
                    t,
                    format!(
                        "tone-mapping operator {} is not supported (Photographic, Filmic or ACES); the photographic operator is used",
                        quoted(t.text.trim())
                    ),
                ),
            }
        }
        if let Some(o) = n.child("TMOOptions") {
            let [key, burn] = self.numbers::<f64, 2>(o)?;
            params.key = key;
            params.burn_percent = burn;
        }
        if let Some(s) = self.optional_number::<f64>(n, "Saturation")? {
            params.saturation = s;
        }
        if let Some(g) = n.child("Gamma") {
            params.gamma = g.text.parse().map_err(|e: String| self.err(g, e))?;
        }
        if let Err(e) = params.validate() {
            return Err(
                self.err(n, format!("{e}; fix <TMOOptions> (key, burn percent), <Saturation> or <Gamma>"))
            );
        }
        let extension = match n.child("Extension") {
            Some(e) => Some(self.text(e, "a file name ending such as _phot.png")?.to_string()),
            None => None,
        };
        Ok(TonemapRec { loc: n.loc(), operator, params, extension })
    }

    fn lights(&mut self, lights: &Node) -> Result<()> {
        self.check(lights, &LIGHTS);
        if let Some(ambient) = self.optional_numbers(lights, "AmbientLight")? {
            self.out.ambient_light = ambient;
        }
        for n in lights.children_named("PointLight") {
            self.check(n, &POINT_LIGHT);
            let light = PointLightRec {
                id: self.id(n, false)?,
                loc: n.loc(),
                position: self.required_numbers(n, "Position")?,
                intensity: self.required_numbers(n, "Intensity")?,
                transforms: self.transform_refs(n)?,
            };
            self.out.point_lights.push(light);
        }
        for n in lights.children_named("AreaLight") {
            self.check(n, &AREA_LIGHT);
            let light = AreaLightRec {
                id: self.id(n, false)?,
                loc: n.loc(),
                position: self.required_numbers(n, "Position")?,
                normal: self.required_numbers(n, "Normal")?,
                size: self.required_number(n, "Size")?,
                radiance: self.required_numbers(n, "Radiance")?,
                transforms: self.transform_refs(n)?,
            };
            if light.normal == [0.0; 3] {
                return Err(self.err(n, "<Normal> is the zero vector; give the direction the light faces"));
            }
            if light.size <= 0.0 {
                return Err(self.err(n, format!("<Size> must be positive, found {}", light.size)));
            }
            self.out.area_lights.push(light);
        }
        for n in lights.children_named("DirectionalLight") {
            self.check(n, &DIRECTIONAL_LIGHT);
            let light = DirectionalLightRec {
                id: self.id(n, false)?,
                loc: n.loc(),
                direction: self.required_numbers(n, "Direction")?,
                radiance: self.required_numbers(n, "Radiance")?,
                transforms: self.transform_refs(n)?,
            };
            if light.direction == [0.0; 3] {
                return Err(
                    self.err(n, "<Direction> is the zero vector; give the direction the light travels in")
                );
            }
            self.out.directional_lights.push(light);
        }
        for n in lights.children_named("SpotLight") {
            self.check(n, &SPOT_LIGHT);
            let light = SpotLightRec {
                id: self.id(n, false)?,
                loc: n.loc(),
                position: self.required_numbers(n, "Position")?,
                direction: self.required_numbers(n, "Direction")?,
                intensity: self.required_numbers(n, "Intensity")?,
                coverage_angle: self.required_number(n, "CoverageAngle")?,
                falloff_angle: self.required_number(n, "FalloffAngle")?,
                transforms: self.transform_refs(n)?,
            };
            if light.direction == [0.0; 3] {
                return Err(
                    self.err(n, "<Direction> is the zero vector; give the axis the spot light points along")
                );
            }
            let (c, f) = (light.coverage_angle, light.falloff_angle);
            if !(c > 0.0 && c < 360.0) {
                return Err(self.err(
                    n,
                    format!("<CoverageAngle> must be between 0 and 360 degrees (the full apex angle of the cone), found {c}"),
                ));
            }
            if !(0.0..=c).contains(&f) {
                return Err(self.err(
                    n,
                    format!("<FalloffAngle> must be between 0 and <CoverageAngle> ({c}) degrees, found {f}: the full-power cone lies inside the covered cone"),
                ));
            }
            self.out.spot_lights.push(light);
        }
        for n in lights.children_named("SphericalDirectionalLight") {
            self.check(n, &ENV_LIGHT);
            let id = self.id(n, false)?;
            let image = match (n.child("ImageId"), n.child("EnvMapName")) {
                (Some(i), _) => self.id_ref(i, "an image id")?,
                (None, Some(legacy)) => {
                    // 2019: the map's path inline; give it an image record of its own.
                    let path = self.text(legacy, "an image file path")?.to_string();
                    let image_id = format!("{ENV_MAP_IMAGE_ID}{}", self.out.env_lights.len() + 1);
                    self.out.images.push(ImageRec { id: image_id.clone(), loc: legacy.loc(), path });
                    image_id
                }
                (None, None) => {
                    return Err(
                        self.err(n, "missing <ImageId>: name the <Image> that holds the environment map")
                    );
                }
            };
            let mapping = match n.attr("type").map(str::trim) {
                None => EnvMapping::LatLong,
                Some(t) => match ENV_MAPPINGS.iter().find(|(name, _)| *name == t) {
                    Some(&(_, m)) => m,
                    None => {
                        return Err(self.err(
                            n,
                            format!(
                                "attribute type must be {}, found \"{}\"",
                                one_of(ENV_MAPPINGS),
                                excerpt(t)
                            ),
                        ));
                    }
                },
            };
            let sampler = self.optional_keyword(n, "Sampler", ENV_SAMPLERS)?;
            self.out.env_lights.push(EnvLightRec { id, loc: n.loc(), image, mapping, sampler });
        }
        Ok(())
    }

    fn material(&mut self, n: &Node) -> Result<MaterialRec> {
        self.check(n, &MATERIAL);
        let mut m = MaterialRec::new(self.id(n, true)?, n.loc());
        m.kind = match n.attr("type").map(str::trim) {
            None => MaterialKind::Plain,
            Some("mirror") => MaterialKind::Mirror,
            Some("conductor") => MaterialKind::Conductor,
            Some("dielectric") => MaterialKind::Dielectric,
            Some(other) => {
                return Err(self.err(
                    n,
                    format!("unknown material type \"{other}\" (expected mirror, conductor or dielectric, or no type)"),
                ));
            }
        };
        m.degamma = self.bool_attr(n, "degamma")?.unwrap_or(false);

        let colours: [(&str, &mut Vec3); 5] = [
            ("AmbientReflectance", &mut m.ambient),
            ("DiffuseReflectance", &mut m.diffuse),
            ("SpecularReflectance", &mut m.specular),
            ("MirrorReflectance", &mut m.mirror),
            ("AbsorptionCoefficient", &mut m.absorption_coefficient),
        ];
        for (name, field) in colours {
            if let Some(v) = self.optional_numbers(n, name)? {
                *field = v;
            }
        }
        let scalars: [(&str, &mut f64); 4] = [
            ("PhongExponent", &mut m.phong_exponent),
            ("RefractionIndex", &mut m.refraction_index),
            ("AbsorptionIndex", &mut m.absorption_index),
            ("Roughness", &mut m.roughness),
        ];
        for (name, field) in scalars {
            if let Some(v) = self.optional_number(n, name)? {
                *field = v;
            }
        }

        let transparency: Option<Vec3> = self.optional_numbers(n, "Transparency")?;
        let nonzero = |v: &Vec3| v.iter().any(|&x| x != 0.0);
        if self.legacy {
            // 2019: no `type` attribute exists; a non-zero Transparency makes a dielectric
            // (§6.9) and a non-zero MirrorReflectance a mirror (§6.1).
            if transparency.as_ref().is_some_and(nonzero) {
                m.kind = MaterialKind::Dielectric;
            } else if nonzero(&m.mirror) {
                m.kind = MaterialKind::Mirror;
            }
        } else if let Some(t) = n.child("Transparency") {
            self.warn(t, "<Transparency> only has a meaning in 2019 scene files (materials without type); it is ignored");
        }
        // In 2020+ files an untyped MirrorReflectance is deliberately ignored (§6.1): kind stays Plain.
        Ok(m)
    }

    /// One child of `<Transformations>`; `None` for elements that are not transformations
    /// (already warned about by [`Parser::check`]).
    fn transformation(&mut self, n: &Node) -> Result<Option<TransformRec>> {
        let op = match n.name.as_str() {
            "Translation" => TransformOp::Translation(self.numbers(n)?),
            "Scaling" => TransformOp::Scaling(self.numbers(n)?),
            "Rotation" => {
                let [degrees, x, y, z] = self.numbers(n)?;
                TransformOp::Rotation { degrees, axis: [x, y, z] }
            }
            "Composite" => TransformOp::Composite(self.numbers(n)?),
            _ => return Ok(None),
        };
        self.check(n, &TRANSFORMATION);
        Ok(Some(TransformRec { id: self.id(n, true)?, loc: n.loc(), op }))
    }

    /// The 2025 `type` attribute of `VertexData` / `TexCoordData` / `Faces` (§14.2), which
    /// only has one value each: anything else would change how the numbers are read.
    fn data_type(&self, n: &Node, only: &str, meaning: &str) -> Result<()> {
        match n.attr("type").map(str::trim) {
            None => Ok(()),
            Some(t) if t == only => Ok(()),
            Some(other) => Err(self
                .err(n, format!("attribute type must be {only} ({meaning}), found \"{}\"", excerpt(other)))),
        }
    }

    fn vertex_data(&mut self, n: &Node) -> Result<()> {
        self.check_attrs(n, VERTEX_DATA_ATTRS, VERTEX_DATA_UNSUPPORTED_ATTRS);
        self.data_type(n, "xyz", "x y z per vertex")?;
        let values = self.number_list::<f64>(n, 3, "x y z per vertex")?;
        self.out.vertices = values.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        Ok(())
    }

    fn tex_coord_data(&mut self, n: &Node) -> Result<()> {
        self.check_attrs(n, VERTEX_DATA_ATTRS, VERTEX_DATA_UNSUPPORTED_ATTRS);
        self.data_type(n, "uv", "u v per texture coordinate")?;
        let values = self.number_list::<f64>(n, 2, "u v per texture coordinate")?;
        self.out.tex_coords = values.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
        Ok(())
    }

    /// A scene-level `<Textures>` block: 2020 `Images` and `TextureMap`s, 2019 `Texture`s.
    fn textures(&mut self, block: &Node) -> Result<()> {
        self.check(block, &TEXTURES);
        for child in &block.children {
            match child.name.as_str() {
                "Images" => {
                    self.check(child, &IMAGES);
                    for image in child.children_named("Image") {
                        self.check(image, &IMAGE);
                        let rec = ImageRec {
                            id: self.id(image, true)?,
                            loc: image.loc(),
                            path: self.text(image, "an image file path")?.to_string(),
                        };
                        self.out.images.push(rec);
                    }
                }
                "TextureMap" => {
                    let map = self.texture_map(child)?;
                    self.out.texture_maps.push(map);
                }
                "Texture" => self.legacy_texture(child)?,
                _ => {}
            }
        }
        Ok(())
    }

    /// The required `<DecalMode>` of a 2020 texture map.
    fn decal_mode(&self, n: &Node) -> Result<DecalMode> {
        match n.child("DecalMode") {
            Some(d) => self.keyword(d, DECAL_MODES),
            None => Err(self.err(
                n,
                format!("missing <DecalMode> (how the texture changes the surface: {})", one_of(DECAL_MODES)),
            )),
        }
    }

    /// A 2020 `<TextureMap>` (scene-format.md §11).
    fn texture_map(&mut self, n: &Node) -> Result<TextureMapRec> {
        const TYPES: &[(&str, MapKind)] = &[
            ("image", MapKind::Image),
            ("perlin", MapKind::Perlin),
            ("checkerboard", MapKind::Checkerboard),
        ];
        let kind = match n.attr("type").map(str::trim) {
            None => {
                return Err(self.err(n, format!("missing attribute type ({})", one_of(TYPES))));
            }
            Some(t) => match TYPES.iter().find(|(name, _)| *name == t) {
                Some(&(_, kind)) => kind,
                None => {
                    return Err(self.err(
                        n,
                        format!("attribute type must be {}, found \"{}\"", one_of(TYPES), excerpt(t)),
                    ));
                }
            },
        };
        self.check(
            n,
            match kind {
                MapKind::Image => &IMAGE_MAP,
                MapKind::Perlin => &PERLIN_MAP,
                MapKind::Checkerboard => &CHECKERBOARD_MAP,
            },
        );
        let id = self.id(n, true)?;
        let decal = self.decal_mode(n)?;
        let source = match kind {
            MapKind::Image => {
                let image = n.child("ImageId").ok_or_else(|| {
                    self.err(n, "missing <ImageId> (the id of an <Image> in <Textures> / <Images>)")
                })?;
                TextureSource::Image {
                    image: self.id_ref(image, "an image id")?,
                    interpolation: self
                        .optional_keyword(n, "Interpolation", INTERPOLATIONS)?
                        // Absent means nearest: measured against the references (sphere_nearest_bilinear,
                        // cube_waves, cube_cushion, sphere_normal match only this way).
                        .unwrap_or(Interpolation::Nearest),
                    normalizer: self.normalizer(n)?.unwrap_or(255.0),
                }
            }
            MapKind::Perlin => TextureSource::Perlin {
                conversion: self
                    .optional_keyword(n, "NoiseConversion", NOISE_CONVERSIONS)?
                    .unwrap_or(NoiseConversion::Linear),
                scale: self.optional_number(n, "NoiseScale")?.unwrap_or(1.0),
            },
            MapKind::Checkerboard => TextureSource::Checkerboard {
                black: self.optional_numbers(n, "BlackColor")?.unwrap_or([0.0; 3]),
                white: self.optional_numbers(n, "WhiteColor")?.unwrap_or([1.0; 3]),
                scale: self.optional_number(n, "Scale")?.unwrap_or(1.0),
                offset: self.optional_number(n, "Offset")?.unwrap_or(0.0),
            },
        };
        Ok(TextureMapRec {
            id,
            loc: n.loc(),
            source,
            decal,
            bump_factor: self.optional_number(n, "BumpFactor")?.unwrap_or(1.0),
            degamma: self.bool_attr(n, "degamma")?.unwrap_or(false),
        })
    }

    /// A 2019 `<Texture>` (scene-format.md §11.11), translated into one texture map, or two
    /// with `bumpmap="true"`: in 2019 such a texture colours the surface *and* bumps it, so a
    /// `bump_normal` map with id `<id>:bump` and `BumpFactor = bumpmapMultiplier` is added and
    /// remembered in `legacy_bumps`. An image file becomes an [`ImageRec`] with id `2019:<id>`.
    fn legacy_texture(&mut self, n: &Node) -> Result<()> {
        let id = self.id(n, true)?;
        let name_node = n.child("ImageName").ok_or_else(|| {
            self.err(n, "missing <ImageName> (an image file, or the word perlin or checkerboard)")
        })?;
        let name = self.text(name_node, "an image file, or the word perlin or checkerboard")?;
        let (kind, schema) = match name {
            "perlin" => (MapKind::Perlin, &LEGACY_PERLIN_TEXTURE),
            "checkerboard" => (MapKind::Checkerboard, &LEGACY_CHECKERBOARD_TEXTURE),
            _ => (MapKind::Image, &LEGACY_IMAGE_TEXTURE),
        };
        self.check(n, schema);
        let decal =
            self.optional_keyword(n, "DecalMode", &LEGACY_DECAL_MODES)?.unwrap_or(DecalMode::ReplaceKd);
        let bumpmap = self.bool_attr(n, "bumpmap")?.unwrap_or(false);
        // Read (and checked) even with bumpmap="false", where the 2019 files also write it.
        let multiplier = self.number_attr(n, "bumpmapMultiplier")?.unwrap_or(1.0);
        let degamma = self.bool_attr(n, "degamma")?.unwrap_or(false);
        let source = match kind {
            MapKind::Image => {
                if let Some(a) = n.child("Appearance")
                    && self.keyword(a, LEGACY_IMAGE_APPEARANCES)?
                {
                    self.warn(
                        a,
                        "<Appearance>clamp</Appearance> is not supported yet; the texture is repeated instead",
                    );
                }
                let image = format!("2019:{id}");
                let path = name.to_string();
                self.out.images.push(ImageRec { id: image.clone(), loc: n.loc(), path });
                TextureSource::Image {
                    image,
                    interpolation: self
                        .optional_keyword(n, "Interpolation", INTERPOLATIONS)?
                        // Absent means nearest: measured against the references (sphere_nearest_bilinear,
                        // cube_waves, cube_cushion, sphere_normal match only this way).
                        .unwrap_or(Interpolation::Nearest),
                    normalizer: self.normalizer(n)?.unwrap_or(255.0),
                }
            }
            MapKind::Perlin => {
                self.legacy_unused_normalizer(n, "perlin")?;
                TextureSource::Perlin {
                    conversion: self
                        .optional_keyword(n, "Appearance", LEGACY_PERLIN_APPEARANCES)?
                        .unwrap_or(NoiseConversion::Linear),
                    scale: self.optional_number(n, "ScalingFactor")?.unwrap_or(1.0),
                }
            }
            MapKind::Checkerboard => {
                self.legacy_unused_normalizer(n, "checkerboard")?;
                TextureSource::Checkerboard {
                    black: self.optional_numbers(n, "BlackColor")?.unwrap_or([0.0; 3]),
                    white: self.optional_numbers(n, "WhiteColor")?.unwrap_or([1.0; 3]),
                    scale: self.optional_number(n, "ScalingFactor")?.unwrap_or(1.0),
                    offset: self.optional_number(n, "Offset")?.unwrap_or(0.0),
                }
            }
        };
        let colour = TextureMapRec { id: id.clone(), loc: n.loc(), source, decal, bump_factor: 1.0, degamma };
        let bump = bumpmap.then(|| TextureMapRec {
            id: format!("{id}:bump"),
            decal: DecalMode::BumpNormal,
            bump_factor: multiplier,
            ..colour.clone()
        });
        self.out.texture_maps.push(colour);
        if let Some(bump) = bump {
            self.legacy_bumps.push((id, bump.id.clone()));
            self.out.texture_maps.push(bump);
        }
        Ok(())
    }

    /// The 2019 perlin and checkerboard textures write `<Normalizer>1</Normalizer>`; their
    /// values are used as they are, so anything else is warned about.
    fn legacy_unused_normalizer(&mut self, n: &Node, kind: &str) -> Result<()> {
        if let Some(norm) = n.child("Normalizer") {
            let v = self.number::<f64>(norm)?;
            if v != 1.0 {
                self.warn(
                    norm,
                    format!("<Normalizer> has no effect on {kind} textures (their values are used as they are); it is ignored"),
                );
            }
        }
        Ok(())
    }

    /// 2019 `<BackgroundTexture>path</BackgroundTexture>`: a `replace_background` image map
    /// whose texels are used raw (normalizer 1, scene-format.md §11.8).
    fn background_texture(&mut self, n: &Node) -> Result<()> {
        self.check_attrs(n, &[], &[]);
        let path = self.text(n, "an image file path")?.to_string();
        let id = BACKGROUND_TEXTURE_ID.to_string();
        self.out.images.push(ImageRec { id: id.clone(), loc: n.loc(), path });
        self.out.texture_maps.push(TextureMapRec {
            id: id.clone(),
            loc: n.loc(),
            source: TextureSource::Image {
                image: id,
                interpolation: Interpolation::Bilinear,
                normalizer: 1.0,
            },
            decal: DecalMode::ReplaceBackground,
            bump_factor: 1.0,
            degamma: false,
        });
        Ok(())
    }

    /// An object's texture-map ids: `<Textures>1 2</Textures>`, or the 2019 `<Texture>1</Texture>`.
    /// A reference to a 2019 `bumpmap="true"` texture also names the bump map made for it. A
    /// repeat with the same ids (the cube_* scenes) is accepted silently; one with other ids is
    /// warned about and the first is used.
    fn object_textures(&mut self, n: &Node) -> Result<Vec<String>> {
        let name = match (n.child("Textures"), n.child("Texture")) {
            (None, None) => return Ok(Vec::new()),
            (Some(_), Some(t)) => {
                self.warn(t, "<Texture> (the 2019 spelling) is ignored because <Textures> is given");
                "Textures"
            }
            (Some(_), None) => "Textures",
            (None, Some(_)) => "Texture",
        };
        let mut first: Option<&Node> = None;
        for list in n.children_named(name) {
            for grandchild in &list.children {
                self.warn(grandchild, format!("unknown element <{}>; it is ignored", grandchild.name));
            }
            match first {
                None => first = Some(list),
                Some(f) if f.text.split_ascii_whitespace().eq(list.text.split_ascii_whitespace()) => {}
                Some(f) => self.warn(
                    list,
                    format!(
                        "<{name}> is given more than once with different ids; only the first one ({}) is used",
                        quoted(&f.text)
                    ),
                ),
            }
        }
        let Some(list) = first else { return Ok(Vec::new()) };
        let mut ids = Vec::new();
        for id in list.text.split_ascii_whitespace() {
            ids.push(id.to_string());
            if let Some((_, bump)) = self.legacy_bumps.iter().find(|(t, _)| t == id) {
                ids.push(bump.clone());
            }
        }
        Ok(ids)
    }

    fn objects(&mut self, objects: &Node) -> Result<()> {
        self.check(objects, &OBJECTS);
        for n in &objects.children {
            match n.name.as_str() {
                "Mesh" => {
                    if let Some(mesh) = self.mesh(n)? {
                        self.out.meshes.push(mesh);
                    }
                }
                "Triangle" => {
                    let triangle = self.triangle(n)?;
                    self.out.triangles.push(triangle);
                }
                "Sphere" => {
                    let sphere = self.sphere(n)?;
                    self.out.spheres.push(sphere);
                }
                "MeshInstance" => {
                    let instance = self.instance(n)?;
                    self.out.instances.push(instance);
                }
                "Plane" => {
                    let plane = self.plane(n)?;
                    self.out.planes.push(plane);
                }
                _ => {}
            }
        }
        Ok(())
    }

    fn material_ref(&self, n: &Node) -> Result<String> {
        self.id_ref(self.required(n, "Material")?, "a material id")
    }

    /// The optional `<Transformations>` reference string, e.g. `t1 r2 s3 c1`, in written order.
    fn transform_refs(&self, n: &Node) -> Result<Vec<TransformRef>> {
        let Some(t) = n.child("Transformations") else { return Ok(Vec::new()) };
        t.text
            .split_ascii_whitespace()
            .map(|token| {
                let mut chars = token.chars();
                match (chars.next(), chars.as_str()) {
                    (Some(letter @ ('t' | 's' | 'r' | 'c')), id)
                        if !id.is_empty() && id.chars().all(|c| c.is_ascii_alphanumeric()) =>
                    {
                        Ok(TransformRef { letter, id: id.to_string() })
                    }
                    _ => Err(self.err(
                        t,
                        format!(
                            "bad transformation reference \"{}\": expected t, s, r or c followed by an id, e.g. \"t1\"",
                            excerpt(token)
                        ),
                    )),
                }
            })
            .collect()
    }

    /// `None` when the mesh cannot be read yet (2019 binary faces); a warning says so.
    fn mesh(&mut self, n: &Node) -> Result<Option<MeshRec>> {
        self.check(n, &MESH);
        let id = self.id(n, true)?;
        let faces = self.required(n, "Faces")?;
        self.check_attrs(faces, FACES_ATTRS, FACES_UNSUPPORTED_ATTRS);
        self.data_type(faces, "triangle", "three vertex ids per face")?;
        let faces_rec = if let Some(path) = faces.attr("plyFile") {
            match path.trim() {
                "" => return Err(self.err(faces, "attribute plyFile is empty; expected a PLY file path")),
                path => FacesRec::Ply { path: path.to_string() },
            }
        } else if faces.attr("binaryFile").is_some() {
            self.warn(
                faces,
                "<Faces binaryFile> (2019 binary faces) is not supported yet; the mesh is ignored",
            );
            return Ok(None);
        } else {
            FacesRec::Inline {
                indices: self.number_list(faces, 3, "three vertex ids per triangle")?,
                vertex_offset: self.int_attr(faces, "vertexOffset")?.unwrap_or(0),
                texture_offset: self.int_attr(faces, "textureOffset")?,
            }
        };
        Ok(Some(MeshRec {
            id,
            loc: n.loc(),
            material: self.material_ref(n)?,
            faces: faces_rec,
            faces_loc: faces.loc(),
            shading: self.shading_attr(n)?.unwrap_or(ShadingMode::Flat),
            transforms: self.transform_refs(n)?,
            motion_blur: self.optional_numbers(n, "MotionBlur")?,
            textures: self.object_textures(n)?,
        }))
    }

    fn triangle(&mut self, n: &Node) -> Result<TriangleRec> {
        self.check(n, &TRIANGLE);
        Ok(TriangleRec {
            id: self.id(n, false)?,
            loc: n.loc(),
            material: self.material_ref(n)?,
            indices: self.required_numbers(n, "Indices")?,
            transforms: self.transform_refs(n)?,
            textures: self.object_textures(n)?,
        })
    }

    fn sphere(&mut self, n: &Node) -> Result<SphereRec> {
        self.check(n, &SPHERE);
        Ok(SphereRec {
            id: self.id(n, false)?,
            loc: n.loc(),
            material: self.material_ref(n)?,
            center: self.required_number(n, "Center")?,
            radius: self.required_number(n, "Radius")?,
            transforms: self.transform_refs(n)?,
            motion_blur: self.optional_numbers(n, "MotionBlur")?,
            textures: self.object_textures(n)?,
        })
    }

    /// An infinite plane (2025, §9.8): `Point` is a vertex id, `Normal` a direction.
    fn plane(&mut self, n: &Node) -> Result<PlaneRec> {
        self.check(n, &PLANE);
        let normal: Vec3 = self.required_numbers(n, "Normal")?;
        if normal == [0.0; 3] {
            return Err(self.err(n, "<Normal> is the zero vector; give the direction the plane faces"));
        }
        Ok(PlaneRec {
            id: self.id(n, false)?,
            loc: n.loc(),
            material: self.material_ref(n)?,
            point: self.required_number(n, "Point")?,
            normal,
            transforms: self.transform_refs(n)?,
            motion_blur: self.optional_numbers(n, "MotionBlur")?,
            textures: self.object_textures(n)?,
        })
    }

    fn instance(&mut self, n: &Node) -> Result<InstanceRec> {
        self.check(n, &MESH_INSTANCE);
        let base_mesh = match n.attr("baseMeshId").map(str::trim) {
            None | Some("") => {
                return Err(self.err(n, "missing attribute baseMeshId (the id of the Mesh to reuse)"));
            }
            Some(id) => id.to_string(),
        };
        Ok(InstanceRec {
            id: self.id(n, false)?,
            loc: n.loc(),
            base_mesh,
            reset_transform: self.bool_attr(n, "resetTransform")?.unwrap_or(false),
            material: n.child("Material").map(|m| self.id_ref(m, "a material id")).transpose()?,
            transforms: self.transform_refs(n)?,
            shading: self.shading_attr(n)?,
            motion_blur: self.optional_numbers(n, "MotionBlur")?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FILE: &str = "scene.xml";

    fn parse(xml: &str) -> SceneRecords {
        match parse_xml(xml, Path::new(FILE)) {
            Ok(records) => records,
            Err(e) => panic!("unexpected error: {e}\nin:\n{xml}"),
        }
    }

    fn warnings(xml: &str) -> Vec<String> {
        parse(xml).warnings.iter().map(ToString::to_string).collect()
    }

    /// `<Scene>` on line 1, `body` from line 2.
    fn scene(body: &str) -> String {
        format!("<Scene>\n{body}\n</Scene>\n")
    }

    /// 1-based line of the first occurrence of `needle` in `text`.
    fn line_of(text: &str, needle: &str) -> u32 {
        let at = text.find(needle).unwrap_or_else(|| panic!("{needle:?} not in the test scene"));
        1 + text[..at].matches('\n').count() as u32
    }

    /// Checks that each input fails with exactly the expected message (as displayed).
    fn check_errors(cases: &[(&str, &str)]) {
        for (xml, expected) in cases {
            match parse_xml(xml, Path::new(FILE)) {
                Ok(_) => panic!("expected the error {expected:?}, but parsing succeeded:\n{xml}"),
                Err(e) => assert_eq!(e.to_string(), *expected, "input:\n{xml}"),
            }
        }
    }

    /// Checks that each input parses, with exactly the expected warnings (as displayed).
    fn check_warnings(cases: &[(&str, &[&str])]) {
        for (xml, expected) in cases {
            assert_eq!(warnings(xml), *expected, "input:\n{xml}");
        }
    }

    /// The first camera of a scene made of one camera element.
    fn camera(camera_xml: &str) -> CameraRec {
        let records = parse(&scene(&format!("<Cameras>\n{camera_xml}\n</Cameras>")));
        assert!(records.warnings.is_empty(), "{:?}", records.warnings);
        records.cameras[0].clone()
    }

    /// The records of a scene made of one `<Objects>` block (plus whatever `extra` holds).
    fn objects(objects_xml: &str, extra: &str) -> SceneRecords {
        parse(&scene(&format!("{extra}\n<Objects>\n{objects_xml}\n</Objects>")))
    }

    fn refs(list: &[(char, &str)]) -> Vec<TransformRef> {
        list.iter().map(|&(letter, id)| TransformRef { letter, id: id.to_string() }).collect()
    }

    /// A scene like the course's simple.xml, with its blocks deliberately out of the usual
    /// order, comments and odd whitespace.
    const SIMPLE: &str = "<?xml version=\"1.0\"?>
<Scene>
    <Objects>
        <Mesh id=\"1\">
            <Material>1</Material>
            <Faces>
                3 1 2
                1 3 4
            </Faces>
        </Mesh>
        <Triangle id=\"1\">
            <Material> 1 </Material>
            <Indices>1 2 3</Indices>
        </Triangle>
        <Sphere id=\"1\"> <!-- the ball -->
            <Material>1</Material>
            <Center>1</Center>
            <Radius>3.73896e-4</Radius>
        </Sphere>
    </Objects>
    <VertexData>
        -0.5 0.5 -2
        -0.5\t-0.5 -2\r
        0.5 -0.5 -2 0.5 0.5 -2
    </VertexData>
    <BackgroundColor>10 20 30</BackgroundColor>
    <ShadowRayEpsilon>1e-3</ShadowRayEpsilon>
    <IntersectionTestEpsilon>1e-5</IntersectionTestEpsilon>
    <Cameras>
        <Camera id=\"1\">
            <Position>0 0 0</Position>
            <Gaze>0 0 -1</Gaze>
            <Up>0 1 0</Up>
            <NearPlane>-1 1 -1 1</NearPlane>
            <NearDistance>1</NearDistance>
            <ImageResolution>800 600</ImageResolution>
            <ImageName>simple.png</ImageName>
        </Camera>
    </Cameras>
    <Lights>
        <AmbientLight>25 25 25</AmbientLight>
        <PointLight id=\"1\">
            <Position> 0 0 0  </Position>
            <Intensity>1000 1000 1e+05</Intensity>
        </PointLight>
    </Lights>
    <Materials>
        <Material id=\"1\"> <!-- For the light -->
            <AmbientReflectance>1 1 1</AmbientReflectance>
            <DiffuseReflectance>1 0.5 0.25</DiffuseReflectance>
            <SpecularReflectance>1 1 1</SpecularReflectance>
            <PhongExponent>10</PhongExponent>
        </Material>
    </Materials>
    <MaxRecursionDepth>6</MaxRecursionDepth>
</Scene>
";

    #[test]
    fn simple_scene_gives_the_expected_records() {
        let at = |needle: &str, element: &str| Loc::new(line_of(SIMPLE, needle), element);
        let mut expected = SceneRecords::new(FILE);
        expected.background_color = [10.0, 20.0, 30.0];
        expected.shadow_ray_epsilon = 1e-3;
        expected.intersection_test_epsilon = 1e-5;
        expected.max_recursion_depth = 6;
        expected.cameras.push(CameraRec {
            id: "1".into(),
            loc: at("<Camera id", r#"Camera id="1""#),
            position: [0.0, 0.0, 0.0],
            gaze: [0.0, 0.0, -1.0],
            up: [0.0, 1.0, 0.0],
            transforms: Vec::new(),
            projection: Projection::NearPlane { left: -1.0, right: 1.0, bottom: -1.0, top: 1.0 },
            near_distance: 1.0,
            width: 800,
            height: 600,
            image_name: "simple.png".into(),
            handedness: Handedness::Right,
            num_samples: 1,
            lens: None,
            tonemaps: Vec::new(),
        });
        expected.ambient_light = [25.0; 3];
        expected.point_lights.push(PointLightRec {
            id: "1".into(),
            loc: at("<PointLight", r#"PointLight id="1""#),
            position: [0.0; 3],
            intensity: [1000.0, 1000.0, 1e5],
            transforms: Vec::new(),
        });
        let mut material = MaterialRec::new("1", at("<Material id", r#"Material id="1""#));
        material.ambient = [1.0; 3];
        material.diffuse = [1.0, 0.5, 0.25];
        material.specular = [1.0; 3];
        material.phong_exponent = 10.0;
        expected.materials.push(material);
        expected.vertices = vec![[-0.5, 0.5, -2.0], [-0.5, -0.5, -2.0], [0.5, -0.5, -2.0], [0.5, 0.5, -2.0]];
        expected.meshes.push(MeshRec {
            id: "1".into(),
            loc: at("<Mesh", r#"Mesh id="1""#),
            material: "1".into(),
            faces: FacesRec::Inline {
                indices: vec![3, 1, 2, 1, 3, 4],
                vertex_offset: 0,
                texture_offset: None,
            },
            faces_loc: at("<Faces", r#"Mesh id="1"> / <Faces"#),
            shading: ShadingMode::Flat,
            transforms: vec![],
            motion_blur: None,
            textures: vec![],
        });
        expected.triangles.push(TriangleRec {
            id: "1".into(),
            loc: at("<Triangle", r#"Triangle id="1""#),
            material: "1".into(),
            indices: [1, 2, 3],
            transforms: vec![],
            textures: vec![],
        });
        expected.spheres.push(SphereRec {
            id: "1".into(),
            loc: at("<Sphere", r#"Sphere id="1""#),
            material: "1".into(),
            center: 1,
            radius: 3.73896e-4,
            transforms: vec![],
            motion_blur: None,
            textures: vec![],
        });
        assert_eq!(parse(SIMPLE), expected);
    }

    #[test]
    fn distribution_elements() {
        let rec = parse(
            r#"<Scene>
<Cameras><Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
  <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>4 4</ImageResolution>
  <ImageName>a.png</ImageName><NumSamples>9</NumSamples><FocusDistance>21</FocusDistance><ApertureSize>1.5</ApertureSize>
</Camera></Cameras>
<Lights><AreaLight id="1"><Position>0 9 0</Position><Normal>0 -2 0</Normal><Size>3</Size><Radiance>5 6 7</Radiance></AreaLight></Lights>
<VertexData>0 0 0</VertexData>
<Objects>
  <Mesh id="1"><Material>1</Material><Faces>1 1 1</Faces><MotionBlur>0 0 4</MotionBlur></Mesh>
  <MeshInstance id="2" baseMeshId="1"><MotionBlur>1 2 3</MotionBlur></MeshInstance>
  <Sphere id="1"><Material>1</Material><Center>1</Center><Radius>1</Radius><MotionBlur>3 0 0</MotionBlur></Sphere>
</Objects></Scene>"#,
        );
        assert!(rec.warnings.is_empty(), "{:?}", rec.warnings);
        let cam = &rec.cameras[0];
        assert_eq!(cam.num_samples, 9);
        assert_eq!(cam.lens, Some(LensRec { focus_distance: 21.0, aperture_size: 1.5 }));
        let l = &rec.area_lights[0];
        assert_eq!(
            (l.position, l.normal, l.size, l.radiance),
            ([0.0, 9.0, 0.0], [0.0, -2.0, 0.0], 3.0, [5.0, 6.0, 7.0])
        );
        assert_eq!(rec.meshes[0].motion_blur, Some([0.0, 0.0, 4.0]));
        assert_eq!(rec.instances[0].motion_blur, Some([1.0, 2.0, 3.0]));
        assert_eq!(rec.spheres[0].motion_blur, Some([3.0, 0.0, 0.0]));
        // Aperture 0 is a pinhole; a zero area-light normal or size is an error.
        let pinhole = parse(&SIMPLE.replace(
            "<ImageName>",
            "<FocusDistance>5</FocusDistance><ApertureSize>0</ApertureSize><ImageName>",
        ));
        assert_eq!(pinhole.cameras[0].lens, None);
    }

    #[test]
    fn hdr_lighting_elements() {
        let rec = parse(
            r#"<Scene>
<Cameras><Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
  <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>4 4</ImageResolution>
  <ImageName>a.exr</ImageName>
  <Tonemap><TMO>Photographic</TMO><TMOOptions>0.36 0</TMOOptions><Saturation>0.8</Saturation><Gamma>sRGB</Gamma></Tonemap>
  <Tonemap><Extension>_two.png</Extension></Tonemap>
  <Tonemap><TMO>ACES</TMO><Extension>_aces.png</Extension></Tonemap>
</Camera></Cameras>
<Textures><Images><Image id="7">textures/sky.exr</Image></Images></Textures>
<Lights>
  <DirectionalLight id="1"><Direction>1 -0.8 -1</Direction><Radiance>200 200 200</Radiance></DirectionalLight>
  <SpotLight id="2"><Position>1 2 3</Position><Direction>0 -1 0</Direction><Intensity>5 5 5</Intensity><CoverageAngle>10</CoverageAngle><FalloffAngle>8</FalloffAngle></SpotLight>
  <SphericalDirectionalLight id="3" type="probe"><ImageId>7</ImageId><Sampler>importance</Sampler></SphericalDirectionalLight>
</Lights>
</Scene>"#,
        );
        assert!(rec.warnings.is_empty(), "{:?}", rec.warnings);
        let t = &rec.cameras[0].tonemaps;
        assert_eq!(t.len(), 3);
        assert_eq!(
            t.iter().map(|t| t.operator).collect::<Vec<_>>(),
            [Operator::Photographic, Operator::Photographic, Operator::Aces]
        );
        assert_eq!(
            t[0].params,
            Photographic {
                key: 0.36,
                burn_percent: 0.0,
                saturation: 0.8,
                gamma: crate::tonemap::params::Gamma::Srgb
            }
        );
        assert_eq!(t[0].extension, None);
        assert_eq!((t[1].params, t[1].extension.as_deref()), (Photographic::default(), Some("_two.png")));
        let d = &rec.directional_lights[0];
        assert_eq!((d.direction, d.radiance), ([1.0, -0.8, -1.0], [200.0; 3]));
        let s = &rec.spot_lights[0];
        assert_eq!(
            (s.position, s.direction, s.intensity, s.coverage_angle, s.falloff_angle),
            ([1.0, 2.0, 3.0], [0.0, -1.0, 0.0], [5.0; 3], 10.0, 8.0)
        );
        let e = &rec.env_lights[0];
        assert_eq!(
            (e.id.as_str(), e.image.as_str(), e.mapping, e.sampler),
            ("3", "7", EnvMapping::Probe, Some(EnvSampler::Importance))
        );
        // Defaults: lat-long, the renderer's sampler. The 2019 EnvMapName gets an image record.
        let legacy = parse(&scene(
            "<Lights><SphericalDirectionalLight id=\"1\"><EnvMapName>maps/pisa.exr</EnvMapName></SphericalDirectionalLight></Lights>",
        ));
        let e = &legacy.env_lights[0];
        assert_eq!((e.mapping, e.sampler), (EnvMapping::LatLong, None));
        assert_eq!(legacy.images.len(), 1);
        assert_eq!(
            (legacy.images[0].id.as_str(), legacy.images[0].path.as_str()),
            (e.image.as_str(), "maps/pisa.exr")
        );
    }

    #[test]
    fn hdr_lighting_errors() {
        let lights = |body: &str| scene(&format!("<Lights>\n{body}\n</Lights>"));
        let spot = |cov: &str, fall: &str| {
            lights(&format!(
                "<SpotLight id=\"1\"><Position>0 0 0</Position><Direction>0 -1 0</Direction><Intensity>1 1 1</Intensity><CoverageAngle>{cov}</CoverageAngle><FalloffAngle>{fall}</FalloffAngle></SpotLight>"
            ))
        };
        let camera = |tonemap: &str| {
            scene(&format!(
                "<Cameras><Camera id=\"1\"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up><NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>4 4</ImageResolution><ImageName>a.exr</ImageName>\n<Tonemap>{tonemap}</Tonemap></Camera></Cameras>"
            ))
        };
        check_errors(&[
            (
                &lights(
                    "<DirectionalLight id=\"4\"><Direction>0 0 0</Direction><Radiance>1 1 1</Radiance></DirectionalLight>",
                ),
                r#"scene.xml:3: <DirectionalLight id="4">: <Direction> is the zero vector; give the direction the light travels in"#,
            ),
            (
                &lights("<DirectionalLight id=\"4\"><Direction>0 -1 0</Direction></DirectionalLight>"),
                r#"scene.xml:3: <DirectionalLight id="4">: missing <Radiance>"#,
            ),
            (
                &spot("0", "0"),
                r#"scene.xml:3: <SpotLight id="1">: <CoverageAngle> must be between 0 and 360 degrees (the full apex angle of the cone), found 0"#,
            ),
            (
                &spot("20", "30"),
                r#"scene.xml:3: <SpotLight id="1">: <FalloffAngle> must be between 0 and <CoverageAngle> (20) degrees, found 30: the full-power cone lies inside the covered cone"#,
            ),
            (
                &lights("<SphericalDirectionalLight id=\"5\"/>"),
                r#"scene.xml:3: <SphericalDirectionalLight id="5">: missing <ImageId>: name the <Image> that holds the environment map"#,
            ),
            (
                &lights(
                    "<SphericalDirectionalLight id=\"5\" type=\"cube\"><ImageId>1</ImageId></SphericalDirectionalLight>",
                ),
                r#"scene.xml:3: <SphericalDirectionalLight id="5">: attribute type must be latlong or probe, found "cube""#,
            ),
            (
                &lights(
                    "<SphericalDirectionalLight id=\"5\"><ImageId>1</ImageId><Sampler>stratified</Sampler></SphericalDirectionalLight>",
                ),
                r#"scene.xml:3: <SphericalDirectionalLight id="5"> / <Sampler>: Sampler must be uniform, cosine or importance, found "stratified""#,
            ),
            (
                &camera("<TMOOptions>0 1</TMOOptions>"),
                r#"scene.xml:3: <Camera id="1"> / <Tonemap>: key 0: must be a positive number (the scenes use 0.18); fix <TMOOptions> (key, burn percent), <Saturation> or <Gamma>"#,
            ),
            (
                &camera("<TMOOptions>0.18</TMOOptions>"),
                r#"scene.xml:3: <Camera id="1"> / <Tonemap> / <TMOOptions>: expected 2 numbers, found "0.18""#,
            ),
            (
                &camera("<Gamma>-2</Gamma>"),
                r#"scene.xml:3: <Camera id="1"> / <Tonemap> / <Gamma>: gamma "-2": expected a positive number (e.g. 2.2) or sRGB"#,
            ),
        ]);
    }

    #[test]
    fn look_at_cameras() {
        let with_gaze_point = camera(
            r#"<Camera id="2" type="lookAt" handedness="left">
                <Position>1 2 3</Position> <GazePoint>1 2 -7</GazePoint> <Up>0 1 0</Up>
                <FovY>45</FovY> <NearDistance>0.5</NearDistance>
                <ImageResolution>640 480</ImageResolution> <ImageName>a.exr</ImageName>
                <NumSamples>16</NumSamples>
            </Camera>"#,
        );
        assert_eq!(with_gaze_point.gaze, [0.0, 0.0, -10.0]);
        assert_eq!(with_gaze_point.projection, Projection::FovY(45.0));
        assert_eq!(with_gaze_point.handedness, Handedness::Left);
        assert_eq!(with_gaze_point.num_samples, 16);
        assert_eq!((with_gaze_point.width, with_gaze_point.height), (640, 480));
        assert_eq!(with_gaze_point.near_distance, 0.5);

        // All cornellbox_jaroslav scenes: lookAt with Gaze and no GazePoint.
        let with_gaze = camera(
            r#"<Camera id="1" type="lookAt" handedness="right">
                <Position>1 2 3</Position> <Gaze>0 0 -1</Gaze> <Up>0 1 0</Up>
                <FovY>39.3</FovY> <NearDistance>0.1</NearDistance>
                <ImageResolution>8 8</ImageResolution> <ImageName>b.png</ImageName>
            </Camera>"#,
        );
        assert_eq!(with_gaze.gaze, [0.0, 0.0, -1.0]);
        assert_eq!(with_gaze.projection, Projection::FovY(39.3));
        assert_eq!(with_gaze.handedness, Handedness::Right);
    }

    #[test]
    fn near_plane_extra_numbers_are_ignored() {
        // spheres.xml writes a fifth value.
        let c = camera(
            "<Camera id=\"1\"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
             <NearPlane> -1 1\t-0.5 0.5 10</NearPlane><NearDistance>1</NearDistance>
             <ImageResolution>2 1</ImageResolution><ImageName>s.png</ImageName></Camera>",
        );
        assert_eq!(c.projection, Projection::NearPlane { left: -1.0, right: 1.0, bottom: -0.5, top: 0.5 });
    }

    #[test]
    fn transformations_and_reference_strings() {
        let records = objects(
            r#"<Sphere id="1"><Material>1</Material><Center>1</Center><Radius>1</Radius>
                   <Transformations> t1 r2
                      s3 c1 </Transformations></Sphere>
               <Triangle id="1"><Material>1</Material><Indices>1 2 3</Indices>
                   <Transformations></Transformations></Triangle>"#,
            r#"<Transformations>
                   <Translation id="1">1 2 3</Translation>
                   <Scaling id="3">2 2 -1</Scaling>
                   <Rotation id="2">90 0 1 0</Rotation>
                   <Composite id="1">1 0 0 7.7898e-009
                       0 1 0 0 0 0 1 0 0 0 0 1</Composite>
                   <Translation id="1">4 5 6</Translation>
               </Transformations>"#,
        );
        let ops: Vec<(String, TransformOp)> =
            records.transformations.iter().map(|t| (t.id.clone(), t.op)).collect();
        let mut composite = [0.0; 16];
        for i in 0..4 {
            composite[i * 5] = 1.0;
        }
        composite[3] = 7.7898e-9;
        assert_eq!(
            ops,
            vec![
                ("1".into(), TransformOp::Translation([1.0, 2.0, 3.0])),
                ("3".into(), TransformOp::Scaling([2.0, 2.0, -1.0])),
                ("2".into(), TransformOp::Rotation { degrees: 90.0, axis: [0.0, 1.0, 0.0] }),
                ("1".into(), TransformOp::Composite(composite)),
                // Duplicate ids are kept; resolving them is the build step's business.
                ("1".into(), TransformOp::Translation([4.0, 5.0, 6.0])),
            ]
        );
        assert_eq!(records.spheres[0].transforms, refs(&[('t', "1"), ('r', "2"), ('s', "3"), ('c', "1")]));
        assert_eq!(records.triangles[0].transforms, vec![]);
    }

    /// Cameras and lights of 2025 scenes carry `Transformations` (§10.4): recorded like an
    /// object's, applied by the build step.
    #[test]
    fn cameras_and_lights_record_their_transformations() {
        let view = "<Up>0 1 0</Up><NearDistance>1</NearDistance><ImageResolution>4 4</ImageResolution>";
        let records = parse(&scene(&format!(
            r#"<Cameras>
<Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><NearPlane>-1 1 -1 1</NearPlane>{view}
    <ImageName>a.png</ImageName><Transformations>r1 t2</Transformations></Camera>
<Camera id="2" type="lookAt"><Position>1 2 3</Position><GazePoint>1 2 -7</GazePoint><FovY>45</FovY>{view}
    <ImageName>b.png</ImageName><Transformations> c1
    </Transformations></Camera>
<Camera id="3"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><NearPlane>-1 1 -1 1</NearPlane>{view}
    <ImageName>c.png</ImageName></Camera>
</Cameras>
<Lights>
<PointLight id="1"><Position>1 2 3</Position><Intensity>1 1 1</Intensity><Transformations>t1</Transformations></PointLight>
<AreaLight id="2"><Position>0 0 0</Position><Normal>0 1 0</Normal><Size>1</Size><Radiance>1 1 1</Radiance>
    <Transformations>s1 r1</Transformations></AreaLight>
<DirectionalLight id="3"><Direction>0 -1 0</Direction><Radiance>1 1 1</Radiance>
    <Transformations>r2</Transformations></DirectionalLight>
<SpotLight id="4"><Position>0 0 0</Position><Direction>0 -1 0</Direction><Intensity>1 1 1</Intensity>
    <CoverageAngle>30</CoverageAngle><FalloffAngle>20</FalloffAngle><Transformations>t3 r3</Transformations></SpotLight>
<PointLight id="5"><Position>0 0 0</Position><Intensity>1 1 1</Intensity></PointLight>
</Lights>"#
        )));
        assert!(records.warnings.is_empty(), "{:?}", records.warnings);
        assert_eq!(records.cameras[0].transforms, refs(&[('r', "1"), ('t', "2")]));
        assert_eq!(records.cameras[1].transforms, refs(&[('c', "1")]));
        assert_eq!(records.cameras[2].transforms, vec![]);
        assert_eq!(records.point_lights[0].transforms, refs(&[('t', "1")]));
        assert_eq!(records.area_lights[0].transforms, refs(&[('s', "1"), ('r', "1")]));
        assert_eq!(records.directional_lights[0].transforms, refs(&[('r', "2")]));
        assert_eq!(records.spot_lights[0].transforms, refs(&[('t', "3"), ('r', "3")]));
        assert_eq!(records.point_lights[1].transforms, vec![]);
        // Nothing is resolved while parsing: the vectors are as written.
        assert_eq!(
            (records.cameras[1].position, records.cameras[1].gaze),
            ([1.0, 2.0, 3.0], [0.0, 0.0, -10.0])
        );
        assert_eq!(records.point_lights[0].position, [1.0, 2.0, 3.0]);

        check_errors(&[
            (
                &scene(
                    "<Lights>\n<PointLight id=\"1\"><Position>0 0 0</Position><Intensity>1 1 1</Intensity>\n\
                     <Transformations>t1 q</Transformations></PointLight>\n</Lights>",
                ),
                r#"scene.xml:4: <PointLight id="1"> / <Transformations>: bad transformation reference "q": expected t, s, r or c followed by an id, e.g. "t1""#,
            ),
            (
                &scene(&format!(
                    "<Cameras>\n<Camera id=\"5\"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><NearPlane>-1 1 -1 1</NearPlane>{view}\n\
                     <ImageName>a.png</ImageName><Transformations>r1,t1</Transformations></Camera>\n</Cameras>"
                )),
                r#"scene.xml:4: <Camera id="5"> / <Transformations>: bad transformation reference "r1,t1": expected t, s, r or c followed by an id, e.g. "t1""#,
            ),
        ]);
    }

    #[test]
    fn mesh_instances() {
        let records = objects(
            r#"<Mesh id="1" shadingMode="smooth"><Material>1</Material><Faces plyFile="ply/dragon.ply"/>
                   <Transformations>s1</Transformations></Mesh>
               <MeshInstance id="1" baseMeshId="1" resetTransform="true">
                   <Material>2</Material><Transformations>t1 r1</Transformations></MeshInstance>
               <MeshInstance id="2" baseMeshId="1" shadingMode="smooth"/>
               <MeshInstance id="3" baseMeshId="1" resetTransform="false" shadingMode="flat"></MeshInstance>"#,
            "",
        );
        let summary: Vec<_> = records
            .instances
            .iter()
            .map(|i| {
                (
                    i.id.as_str(),
                    i.base_mesh.as_str(),
                    i.reset_transform,
                    i.material.clone(),
                    i.transforms.clone(),
                    i.shading,
                )
            })
            .collect();
        assert_eq!(
            summary,
            vec![
                ("1", "1", true, Some("2".to_string()), refs(&[('t', "1"), ('r', "1")]), None),
                ("2", "1", false, None, vec![], Some(ShadingMode::Smooth)),
                ("3", "1", false, None, vec![], Some(ShadingMode::Flat)),
            ]
        );
        assert!(records.warnings.is_empty(), "{:?}", records.warnings);
    }

    #[test]
    fn ply_faces_and_vertex_offsets() {
        let xml = scene(
            r#"<Objects>
<Mesh id="1" shadingMode="smooth"><Material>1</Material>
  <Faces plyFile=" ply/head.ply "/></Mesh>
<Mesh id="2"><Material>1</Material>
  <Faces vertexOffset="1">0 1 2
    0 2 3</Faces></Mesh>
<Mesh id="3" shadingMode="flat"><Material>1</Material><Faces vertexOffset="-2"></Faces></Mesh>
</Objects>"#,
        );
        let records = parse(&xml);
        let meshes: Vec<_> =
            records.meshes.iter().map(|m| (m.faces.clone(), m.shading, m.faces_loc.clone())).collect();
        assert_eq!(
            meshes,
            vec![
                (
                    FacesRec::Ply { path: "ply/head.ply".into() },
                    ShadingMode::Smooth,
                    Loc::new(4, r#"Mesh id="1"> / <Faces"#)
                ),
                (
                    FacesRec::Inline {
                        indices: vec![0, 1, 2, 0, 2, 3],
                        vertex_offset: 1,
                        texture_offset: None
                    },
                    ShadingMode::Flat,
                    Loc::new(6, r#"Mesh id="2"> / <Faces"#)
                ),
                (
                    FacesRec::Inline { indices: vec![], vertex_offset: -2, texture_offset: None },
                    ShadingMode::Flat,
                    Loc::new(8, r#"Mesh id="3"> / <Faces"#)
                ),
            ]
        );
    }

    #[test]
    fn materials() {
        let records = parse(&scene(
            r#"<Materials>
<Material id="1" type="conductor" degamma="true">
  <MirrorReflectance>1 0.86 0.57</MirrorReflectance><RefractionIndex>0.370</RefractionIndex>
  <AbsorptionIndex>2.820</AbsorptionIndex><Roughness>0.05</Roughness>
</Material>
<Material id="2" type="dielectric"><AbsorptionCoefficient>0.1 0 0.1</AbsorptionCoefficient>
  <RefractionIndex>1.5</RefractionIndex></Material>
<Material id="3" type="mirror"><MirrorReflectance>1 1 1</MirrorReflectance></Material>
<Material id="4"><MirrorReflectance>1 1 1</MirrorReflectance></Material>
</Materials>"#,
        ));
        let m = &records.materials;
        assert_eq!(m[0].kind, MaterialKind::Conductor);
        assert!(m[0].degamma);
        assert_eq!(
            (m[0].mirror, m[0].refraction_index, m[0].absorption_index),
            ([1.0, 0.86, 0.57], 0.37, 2.82)
        );
        assert_eq!(m[0].roughness, 0.05);
        assert_eq!(m[1].kind, MaterialKind::Dielectric);
        assert_eq!((m[1].absorption_coefficient, m[1].refraction_index), ([0.1, 0.0, 0.1], 1.5));
        assert_eq!(m[2].kind, MaterialKind::Mirror);
        // A 2020+ file (it has typed materials): untyped MirrorReflectance does not make a mirror.
        assert_eq!(m[3].kind, MaterialKind::Plain);
        assert!(!m[3].degamma);
        assert_eq!(m[3].phong_exponent, 1.0, "default from MaterialRec::new");
    }

    #[test]
    fn legacy_2019_material_rule() {
        let mirror = "<Material id=\"1\"><MirrorReflectance>0.5 0.5 0.5</MirrorReflectance></Material>";
        let zero_mirror = "<Material id=\"2\"><MirrorReflectance>0 0 0</MirrorReflectance></Material>";
        let glass = "<Material id=\"3\"><MirrorReflectance>0.1 0.1 0.1</MirrorReflectance>\
                     <Transparency>1 1 1</Transparency><RefractionIndex>1.5</RefractionIndex></Material>";
        let typed = "<Material id=\"4\" type=\"conductor\"></Material>";
        let texture_map = "<Textures><TextureMap id=\"1\" type=\"perlin\"><DecalMode>replace_kd</DecalMode>\
                           </TextureMap></Textures>";
        use MaterialKind::*;
        let cases: &[(&str, &str, &[MaterialKind])] = &[
            // 2019 file: no type attributes, no TextureMap.
            ("", "", &[Mirror, Plain, Dielectric]),
            // Any typed material makes it a 2020+ file.
            (typed, "", &[Plain, Plain, Plain, Conductor]),
            // So does a TextureMap.
            ("", texture_map, &[Plain, Plain, Plain]),
        ];
        for (extra_material, extra, kinds) in cases {
            let xml =
                scene(&format!("{extra}<Materials>{mirror}{zero_mirror}{glass}{extra_material}</Materials>"));
            let got: Vec<MaterialKind> = parse(&xml).materials.iter().map(|m| m.kind).collect();
            assert_eq!(got, *kinds, "input:\n{xml}");
        }
    }

    #[test]
    fn errors_name_file_line_and_element() {
        let cam =
            |inner: &str| scene(&format!("<Cameras>\n<Camera id=\"1\">\n{inner}\n</Camera>\n</Cameras>"));
        let complete_camera = |skip: &str| {
            let children = [
                "<Position>0 0 0</Position>",
                "<Gaze>0 0 -1</Gaze>",
                "<Up>0 1 0</Up>",
                "<NearPlane>-1 1 -1 1</NearPlane>",
                "<NearDistance>1</NearDistance>",
                "<ImageResolution>4 4</ImageResolution>",
                "<ImageName>x.png</ImageName>",
            ];
            cam(&children.iter().filter(|c| !c.starts_with(skip)).copied().collect::<Vec<_>>().join("\n"))
        };
        let sphere =
            |inner: &str| scene(&format!("<Objects>\n<Sphere id=\"2\">\n{inner}\n</Sphere>\n</Objects>"));
        let cases: &[(&str, &str)] = &[
            (
                &cam("<Position>0 zero 0</Position>"),
                r#"scene.xml:4: <Camera id="1"> / <Position>: expected 3 numbers, found "0 zero 0""#,
            ),
            (
                &scene("<BackgroundColor>1 2</BackgroundColor>"),
                r#"scene.xml:2: <BackgroundColor>: expected 3 numbers, found "1 2""#,
            ),
            (
                &scene("<BackgroundColor> <!-- none --> </BackgroundColor>"),
                "scene.xml:2: <BackgroundColor>: expected 3 numbers, found nothing",
            ),
            (
                &scene("<MaxRecursionDepth>-1</MaxRecursionDepth>"),
                r#"scene.xml:2: <MaxRecursionDepth>: expected a non-negative integer, found "-1""#,
            ),
            (
                &scene("<ShadowRayEpsilon>nan</ShadowRayEpsilon>"),
                r#"scene.xml:2: <ShadowRayEpsilon>: expected a number, found "nan""#,
            ),
            (
                &complete_camera("<ImageResolution"),
                r#"scene.xml:3: <Camera id="1">: missing <ImageResolution>"#,
            ),
            (
                &complete_camera("<NearPlane"),
                r#"scene.xml:3: <Camera id="1">: missing <NearPlane> (or <FovY>)"#,
            ),
            (&complete_camera("<Gaze"), r#"scene.xml:3: <Camera id="1">: missing <Gaze> (or <GazePoint>)"#),
            (
                &cam("<Position>0 0 0</Position><Up>0 1 0</Up><FovY>45</FovY>")
                    .replace("id=\"1\"", "id=\"1\" type=\"lookAt\""),
                r#"scene.xml:3: <Camera id="1">: missing <GazePoint> (or <Gaze>)"#,
            ),
            (
                &cam("").replace("id=\"1\"", "id=\"1\" type=\"ortho\""),
                r#"scene.xml:3: <Camera id="1">: unknown camera type "ortho" (expected lookAt, or no type)"#,
            ),
            (
                &complete_camera("<ImageResolution")
                    .replace("<ImageName>", "<ImageResolution>640 0</ImageResolution><ImageName>"),
                r#"scene.xml:9: <Camera id="1"> / <ImageResolution>: the image must be at least 1 x 1 pixels, found 640 x 0"#,
            ),
            (
                &scene("<Materials>\n<Material id=\"1\" type=\"glass\"/>\n</Materials>"),
                r#"scene.xml:3: <Material id="1">: unknown material type "glass" (expected mirror, conductor or dielectric, or no type)"#,
            ),
            (
                &scene("<Materials>\n<Material/>\n</Materials>"),
                "scene.xml:3: <Material>: missing attribute id (other elements refer to it by id)",
            ),
            (
                &sphere("<Material>1</Material><Center>1</Center>"),
                r#"scene.xml:3: <Sphere id="2">: missing <Radius>"#,
            ),
            (
                &sphere("<Center>1</Center><Radius>1</Radius>"),
                r#"scene.xml:3: <Sphere id="2">: missing <Material>"#,
            ),
            (
                &sphere("<Material></Material><Center>1</Center><Radius>1</Radius>"),
                r#"scene.xml:4: <Sphere id="2"> / <Material>: expected a material id, found nothing"#,
            ),
            (
                &sphere("<Material>1</Material><Center>1.5</Center><Radius>1</Radius>"),
                r#"scene.xml:4: <Sphere id="2"> / <Center>: expected an integer, found "1.5""#,
            ),
            (
                &sphere(
                    "<Material>1</Material><Center>1</Center><Radius>1</Radius>\n<Transformations>t1 x2</Transformations>",
                ),
                r#"scene.xml:5: <Sphere id="2"> / <Transformations>: bad transformation reference "x2": expected t, s, r or c followed by an id, e.g. "t1""#,
            ),
            (
                &sphere(
                    "<Material>1</Material><Center>1</Center><Radius>1</Radius>\n<Transformations>t</Transformations>",
                ),
                r#"scene.xml:5: <Sphere id="2"> / <Transformations>: bad transformation reference "t": expected t, s, r or c followed by an id, e.g. "t1""#,
            ),
            (
                &scene("<Objects>\n<Mesh id=\"7\">\n<Material>1</Material>\n</Mesh>\n</Objects>"),
                r#"scene.xml:3: <Mesh id="7">: missing <Faces>"#,
            ),
            (
                &scene(
                    "<Objects>\n<Mesh id=\"7\"><Material>1</Material>\n<Faces>1 2 3\n4 5 six\n</Faces></Mesh>\n</Objects>",
                ),
                r#"scene.xml:5: <Mesh id="7"> / <Faces>: expected integers, found "six""#,
            ),
            (
                &scene(
                    "<Objects>\n<Mesh id=\"7\"><Material>1</Material>\n<Faces>1 2 3 4</Faces></Mesh>\n</Objects>",
                ),
                r#"scene.xml:4: <Mesh id="7"> / <Faces>: the number of values must be a multiple of 3 (three vertex ids per triangle), found 4"#,
            ),
            (
                &scene(
                    "<Objects>\n<Mesh id=\"7\" shadingMode=\"phong\"><Material>1</Material><Faces>1 2 3</Faces></Mesh>\n</Objects>",
                ),
                r#"scene.xml:3: <Mesh id="7">: attribute shadingMode must be smooth or flat, found "phong""#,
            ),
            (
                &scene("<VertexData>\n1 2 3\n4 5 6 # 7\n</VertexData>"),
                r##"scene.xml:4: <VertexData>: expected numbers, found "#""##,
            ),
            (
                &scene("<VertexData>1 2 3 4</VertexData>"),
                "scene.xml:2: <VertexData>: the number of values must be a multiple of 3 (x y z per vertex), found 4",
            ),
            (
                &scene(
                    "<Objects>\n<MeshInstance id=\"1\" baseMeshId=\"1\" resetTransform=\"yes\"/>\n</Objects>",
                ),
                r#"scene.xml:3: <MeshInstance id="1">: attribute resetTransform must be true or false, found "yes""#,
            ),
            (
                &scene("<Objects>\n<MeshInstance id=\"1\"/>\n</Objects>"),
                r#"scene.xml:3: <MeshInstance id="1">: missing attribute baseMeshId (the id of the Mesh to reuse)"#,
            ),
            (
                &scene("<Transformations>\n<Rotation id=\"1\">90 0 1</Rotation>\n</Transformations>"),
                r#"scene.xml:3: <Rotation id="1">: expected 4 numbers, found "90 0 1""#,
            ),
            (
                "<Root>\n</Root>",
                "scene.xml:1: <Root>: the root element must be <Scene>, found <Root>; is this a scene file?",
            ),
            ("", "scene.xml: no XML element found: the file is empty or is not an XML scene"),
        ];
        check_errors(cases);
    }

    #[test]
    fn malformed_xml_errors_have_lines_and_hints() {
        let cases: &[(&str, &str)] = &[
            (
                "<Scene>\n<Cameras>\n<Camera id=\"1\">\n</Cameras>\n</Scene>",
                "scene.xml:4: malformed XML: ill-formed document: expected `</Camera>`, but `</Cameras>` was found. \
                 Hint: every <Element> must be closed by its own </Element>, innermost first",
            ),
            (
                "<Scene>\n<Cameras>\n<Camera id=\"1\">\n",
                r#"scene.xml:3: <Camera id="1">: <Camera> is never closed: the file ends first (is it truncated?)"#,
            ),
            (
                "<Scene>\n\n<Lights",
                "scene.xml:3: malformed XML: syntax error: tag not closed: `>` not found before end of input. Hint: the file ends inside a tag, comment or quoted value; is it truncated, or is a `>`, `-->` or quote missing?",
            ),
            (
                "<Scene>\n<Material id=1/>\n</Scene>",
                "scene.xml:2: <Material>: malformed attribute: position 12: attribute value must be enclosed in `\"` or `'`. Hint: attributes are written name=\"value\"",
            ),
            (
                "<Scene>\n<ImageName>a &b; c</ImageName>\n</Scene>",
                "scene.xml:2: unknown entity &b;. Hint: write a literal & as &amp;",
            ),
            (
                "<Scene>\n</Scene>\n<Scene/>",
                "scene.xml:3: <Scene>: a second top-level element <Scene>; a scene file has exactly one <Scene>",
            ),
            ("junk", "scene.xml:1: text \"junk\" outside of any element; is this an XML scene file?"),
        ];
        check_errors(cases);
    }

    #[test]
    fn entities_and_cdata_are_text() {
        let c = camera(
            "<Camera id=\"1\"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
             <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance>
             <ImageResolution>2&#32;1</ImageResolution><ImageName>a&amp;<![CDATA[b]]>.png</ImageName></Camera>",
        );
        assert_eq!((c.width, c.height, c.image_name.as_str()), (2, 1, "a&b.png"));
    }

    #[test]
    fn unknown_and_unsupported_elements_are_warnings() {
        let w = |line: u32, element: &str, message: &str| {
            format!("warning: scene.xml:{line}: <{element}>: {message}")
        };
        let sphere = "<Sphere id=\"1\"><Material>1</Material><Center>1</Center><Radius>1</Radius>";
        let cases: &[(&str, &[&str])] = &[
            (&scene("<Foo>1</Foo>"), &[&w(2, "Foo", "unknown element <Foo>; it is ignored")]),
            (
                &scene(&format!(
                    "<Objects>\n{sphere}\n<Radiuss>2</Radiuss><Textures>1</Textures>\n</Sphere>\n\
                     <MeshInstance id=\"2\" baseMeshId=\"1\"><Textures>1</Textures></MeshInstance>\n</Objects>"
                )),
                &[
                    &w(4, r#"Sphere id="1"> / <Radiuss"#, "unknown element <Radiuss>; it is ignored"),
                    &w(
                        6,
                        r#"MeshInstance id="2"> / <Textures"#,
                        "<Textures> is not supported yet; it is ignored",
                    ),
                ],
            ),
            (
                &scene(&format!("<Objects>\n{sphere}<Radius>2</Radius></Sphere>\n</Objects>")),
                &[&w(
                    3,
                    r#"Sphere id="1"> / <Radius"#,
                    "<Radius> is given more than once; only the first one is used",
                )],
            ),
            (
                &scene(
                    "<Lights>\n<SpotLight id=\"1\"><Position>0 0 0</Position><Direction>0 -1 0</Direction><Intensity>1 1 1</Intensity>\
                     <CoverageAngle>30</CoverageAngle><FalloffAngle>20</FalloffAngle><Exponent>2</Exponent></SpotLight>\n\
                     <SphericalDirectionalLight id=\"1\" scale=\"2\"><ImageId>1</ImageId></SphericalDirectionalLight>\n</Lights>",
                ),
                &[
                    &w(3, r#"SpotLight id="1"> / <Exponent"#, "unknown element <Exponent>; it is ignored"),
                    &w(4, r#"SphericalDirectionalLight id="1""#, "unknown attribute scale; it is ignored"),
                ],
            ),
            (
                &scene(
                    "<Materials>\n<Material id=\"1\" BRDF=\"2\" colour=\"red\"><Position>1</Position></Material>\n</Materials>",
                ),
                &[
                    &w(3, r#"Material id="1""#, "attribute BRDF is not supported yet; it is ignored"),
                    &w(3, r#"Material id="1""#, "unknown attribute colour; it is ignored"),
                    &w(3, r#"Material id="1"> / <Position"#, "unknown element <Position>; it is ignored"),
                ],
            ),
            (
                &scene(
                    "<VertexData binaryFile=\"geometry/vertices.bin\"/>\n<TexCoordData binaryFile=\"geometry/uvs.bin\"/>",
                ),
                &[
                    &w(2, "VertexData", "attribute binaryFile is not supported yet; it is ignored"),
                    &w(3, "TexCoordData", "attribute binaryFile is not supported yet; it is ignored"),
                ],
            ),
            (
                &scene(
                    "<Objects>\n<Mesh id=\"1\"><Material>1</Material><Faces binaryFile=\"0_face.bin\"/></Mesh>\n</Objects>",
                ),
                &[&w(
                    3,
                    r#"Mesh id="1"> / <Faces"#,
                    "<Faces binaryFile> (2019 binary faces) is not supported yet; the mesh is ignored",
                )],
            ),
            (
                &scene(
                    "<Materials>\n<Material id=\"1\" type=\"mirror\"><Transparency>1 1 1</Transparency></Material>\n</Materials>",
                ),
                &[&w(
                    3,
                    r#"Material id="1"> / <Transparency"#,
                    "<Transparency> only has a meaning in 2019 scene files (materials without type); it is ignored",
                )],
            ),
            (
                &scene(
                    "<Cameras>\n<Camera id=\"1\" type=\"lookAt\"><Position>0 0 0</Position><GazePoint>0 0 -1</GazePoint>\n<Gaze>0 0 1</Gaze>\
                        <Up>0 1 0</Up><FovY>45</FovY><NearDistance>1</NearDistance><ImageResolution>1 1</ImageResolution>\
                        <ImageName>a.exr</ImageName>\n<Tonemap><TMO>Drago</TMO></Tonemap></Camera>\n</Cameras>",
                ),
                &[
                    &w(4, r#"Camera id="1"> / <Gaze"#, "<Gaze> is ignored because <GazePoint> is given"),
                    &w(
                        5,
                        r#"Camera id="1"> / <Tonemap> / <TMO"#,
                        "tone-mapping operator \"Drago\" is not supported (Photographic, Filmic or ACES); the photographic operator is used",
                    ),
                ],
            ),
        ];
        check_warnings(cases);
        // The mesh with binary faces is skipped, not half-recorded.
        assert!(parse(cases[6].0).meshes.is_empty());
    }

    // ---------------------------------------------------------------------------------------
    // Textures (HW4)
    // ---------------------------------------------------------------------------------------

    /// `Loc` of the element whose start tag is the first occurrence of `needle` in `xml`.
    fn loc_of(xml: &str, needle: &str, element: &str) -> Loc {
        Loc::new(line_of(xml, needle), element)
    }

    fn map(id: &str, loc: Loc, source: TextureSource, decal: DecalMode) -> TextureMapRec {
        TextureMapRec { id: id.into(), loc, source, decal, bump_factor: 1.0, degamma: false }
    }

    fn image_source(image: &str, interpolation: Interpolation, normalizer: f64) -> TextureSource {
        TextureSource::Image { image: image.into(), interpolation, normalizer }
    }

    const TEXTURE_MAPS: &str = r#"<Scene>
<Textures>
  <Images>
    <Image id="1">textures/earth.jpg</Image>
    <Image id="hdr"> textures/grace new.exr </Image>
  </Images>
  <TextureMap id="1" type="image">
    <ImageId>1</ImageId>
    <DecalMode>replace_kd</DecalMode>
  </TextureMap>
  <TextureMap id="2" type="image" degamma="true">
    <ImageId> hdr </ImageId>
    <DecalMode>bump_normal</DecalMode>
    <Interpolation>nearest</Interpolation>
    <Normalizer>1</Normalizer>
    <BumpFactor>30</BumpFactor>
  </TextureMap>
  <TextureMap id="3" type="perlin">
    <DecalMode>replace_kd</DecalMode>
  </TextureMap>
  <TextureMap id="4" type="perlin" degamma="false">
    <DecalMode>bump_normal</DecalMode>
    <NoiseConversion>absval</NoiseConversion>
    <NoiseScale>0.5</NoiseScale>
    <BumpFactor>0.08</BumpFactor>
  </TextureMap>
  <TextureMap id="5" type="checkerboard">
    <DecalMode>blend_kd</DecalMode>
  </TextureMap>
  <TextureMap id="6" type="checkerboard">
    <DecalMode>replace_kd</DecalMode>
    <BlackColor>0.4 0.4 0.4</BlackColor>
    <WhiteColor>10 10 10</WhiteColor>
    <Scale>0.1</Scale>
    <Offset>79</Offset>
    <BumpFactor>2</BumpFactor>
  </TextureMap>
  <TextureMap id="7" type="image">
    <ImageId>1</ImageId>
    <DecalMode>replace_all</DecalMode>
    <Interpolation>trilinear</Interpolation>
  </TextureMap>
  <TextureMap id="8" type="perlin">
    <NoiseConversion>linear</NoiseConversion>
    <DecalMode>replace_kd</DecalMode>
  </TextureMap>
</Textures>
</Scene>
"#;

    #[test]
    fn texture_maps_of_each_type_with_defaults_and_every_child() {
        use DecalMode::*;
        use Interpolation::*;
        let xml = TEXTURE_MAPS;
        let records = parse(xml);
        assert!(records.warnings.is_empty(), "{:?}", records.warnings);
        assert_eq!(
            records.images,
            vec![
                ImageRec {
                    id: "1".into(),
                    loc: loc_of(xml, r#"<Image id="1""#, r#"Images> / <Image id="1""#),
                    path: "textures/earth.jpg".into(),
                },
                ImageRec {
                    id: "hdr".into(),
                    loc: loc_of(xml, r#"<Image id="hdr""#, r#"Images> / <Image id="hdr""#),
                    path: "textures/grace new.exr".into(),
                },
            ]
        );
        let at =
            |id: &str| loc_of(xml, &format!(r#"<TextureMap id="{id}""#), &format!(r#"TextureMap id="{id}""#));
        let expected = vec![
            // Defaults: nearest, Normalizer 255, BumpFactor 1, no degamma.
            map("1", at("1"), image_source("1", Nearest, 255.0), ReplaceKd),
            TextureMapRec {
                bump_factor: 30.0,
                degamma: true,
                ..map("2", at("2"), image_source("hdr", Nearest, 1.0), BumpNormal)
            },
            map(
                "3",
                at("3"),
                TextureSource::Perlin { conversion: NoiseConversion::Linear, scale: 1.0 },
                ReplaceKd,
            ),
            TextureMapRec {
                bump_factor: 0.08,
                ..map(
                    "4",
                    at("4"),
                    TextureSource::Perlin { conversion: NoiseConversion::AbsVal, scale: 0.5 },
                    BumpNormal,
                )
            },
            map(
                "5",
                at("5"),
                TextureSource::Checkerboard { black: [0.0; 3], white: [1.0; 3], scale: 1.0, offset: 0.0 },
                BlendKd,
            ),
            TextureMapRec {
                bump_factor: 2.0,
                ..map(
                    "6",
                    at("6"),
                    TextureSource::Checkerboard {
                        black: [0.4; 3],
                        white: [10.0; 3],
                        scale: 0.1,
                        offset: 79.0,
                    },
                    ReplaceKd,
                )
            },
            map("7", at("7"), image_source("1", Trilinear, 255.0), ReplaceAll),
            map(
                "8",
                at("8"),
                TextureSource::Perlin { conversion: NoiseConversion::Linear, scale: 1.0 },
                ReplaceKd,
            ),
        ];
        assert_eq!(records.texture_maps, expected);
    }

    #[test]
    fn every_decal_mode() {
        use DecalMode::*;
        let modes = [
            ("replace_kd", ReplaceKd),
            ("blend_kd", BlendKd),
            ("replace_ks", ReplaceKs),
            ("replace_all", ReplaceAll),
            ("replace_normal", ReplaceNormal),
            ("bump_normal", BumpNormal),
            ("replace_background", ReplaceBackground),
        ];
        for (name, mode) in modes {
            for map_type in ["image", "perlin", "checkerboard"] {
                let image = if map_type == "image" { "<ImageId>1</ImageId>" } else { "" };
                let xml = scene(&format!(
                    "<Textures><TextureMap id=\"1\" type=\"{map_type}\">{image}\
                     <DecalMode>\n {name}\n</DecalMode></TextureMap></Textures>"
                ));
                let records = parse(&xml);
                assert!(records.warnings.is_empty(), "{:?}", records.warnings);
                assert_eq!(records.texture_maps[0].decal, mode, "input:\n{xml}");
            }
        }
    }

    #[test]
    fn texture_errors_name_file_line_and_element() {
        let texture_map = |attrs: &str, children: &str| {
            scene(&format!(
                "<Textures>\n<TextureMap id=\"1\"{attrs}>\n{children}\n</TextureMap>\n</Textures>"
            ))
        };
        let image_map =
            |children: &str| texture_map(" type=\"image\"", &format!("<ImageId>1</ImageId>\n{children}"));
        let legacy = |attrs: &str, children: &str| {
            scene(&format!("<Textures>\n<Texture id=\"1\"{attrs}>\n{children}\n</Texture>\n</Textures>"))
        };
        let decals = "replace_kd, blend_kd, replace_ks, replace_all, replace_normal, bump_normal or replace_background";
        let cases: &[(&str, &str)] = &[
            (
                &image_map("<DecalMode>replace</DecalMode>"),
                &format!(
                    r#"scene.xml:5: <TextureMap id="1"> / <DecalMode>: DecalMode must be {decals}, found "replace""#
                ),
            ),
            (
                &image_map("<DecalMode></DecalMode>"),
                &format!(
                    r#"scene.xml:5: <TextureMap id="1"> / <DecalMode>: DecalMode must be {decals}, found nothing"#
                ),
            ),
            (
                &image_map("<Interpolation>bilinear</Interpolation>"),
                &format!(
                    r#"scene.xml:3: <TextureMap id="1">: missing <DecalMode> (how the texture changes the surface: {decals})"#
                ),
            ),
            (
                &texture_map(" type=\"noise\"", "<DecalMode>replace_kd</DecalMode>"),
                r#"scene.xml:3: <TextureMap id="1">: attribute type must be image, perlin or checkerboard, found "noise""#,
            ),
            (
                &texture_map("", "<DecalMode>replace_kd</DecalMode>"),
                r#"scene.xml:3: <TextureMap id="1">: missing attribute type (image, perlin or checkerboard)"#,
            ),
            (
                &scene(
                    "<Textures>\n<TextureMap type=\"perlin\"><DecalMode>replace_kd</DecalMode></TextureMap>\n</Textures>",
                ),
                "scene.xml:3: <TextureMap>: missing attribute id (other elements refer to it by id)",
            ),
            (
                &image_map("<DecalMode>replace_kd</DecalMode>\n<Interpolation>cubic</Interpolation>"),
                r#"scene.xml:6: <TextureMap id="1"> / <Interpolation>: Interpolation must be nearest, bilinear or trilinear, found "cubic""#,
            ),
            (
                &image_map("<DecalMode>replace_kd</DecalMode>\n<Normalizer>0</Normalizer>"),
                r#"scene.xml:6: <TextureMap id="1"> / <Normalizer>: Normalizer must be positive, found 0 (texel values are divided by it; 255 for 8-bit images)"#,
            ),
            (
                &image_map("<DecalMode>replace_kd</DecalMode>\n<BumpFactor>big</BumpFactor>"),
                r#"scene.xml:6: <TextureMap id="1"> / <BumpFactor>: expected a number, found "big""#,
            ),
            (
                &texture_map(" type=\"image\"", "<DecalMode>replace_kd</DecalMode>"),
                r#"scene.xml:3: <TextureMap id="1">: missing <ImageId> (the id of an <Image> in <Textures> / <Images>)"#,
            ),
            (
                &texture_map(" type=\"image\"", "<ImageId>1 2</ImageId><DecalMode>replace_kd</DecalMode>"),
                r#"scene.xml:4: <TextureMap id="1"> / <ImageId>: expected an image id, found "1 2""#,
            ),
            (
                &texture_map(
                    " type=\"perlin\"",
                    "<DecalMode>replace_kd</DecalMode>\n<NoiseConversion>abs</NoiseConversion>",
                ),
                r#"scene.xml:5: <TextureMap id="1"> / <NoiseConversion>: NoiseConversion must be linear or absval, found "abs""#,
            ),
            (
                &texture_map(
                    " type=\"checkerboard\"",
                    "<DecalMode>replace_kd</DecalMode>\n<BlackColor>0 0</BlackColor>",
                ),
                r#"scene.xml:5: <TextureMap id="1"> / <BlackColor>: expected 3 numbers, found "0 0""#,
            ),
            (
                &texture_map(" type=\"perlin\" degamma=\"yes\"", "<DecalMode>replace_kd</DecalMode>"),
                r#"scene.xml:3: <TextureMap id="1">: attribute degamma must be true or false, found "yes""#,
            ),
            (
                &scene("<Textures><Images>\n<Image>a.png</Image>\n</Images></Textures>"),
                "scene.xml:3: <Images> / <Image>: missing attribute id (other elements refer to it by id)",
            ),
            (
                &scene("<Textures><Images>\n<Image id=\"1\"> </Image>\n</Images></Textures>"),
                r#"scene.xml:3: <Images> / <Image id="1">: expected an image file path, found nothing"#,
            ),
            (
                &scene("<TexCoordData>\n0 0\n1 one\n</TexCoordData>"),
                r#"scene.xml:4: <TexCoordData>: expected numbers, found "one""#,
            ),
            (
                &scene("<TexCoordData>0 0 1</TexCoordData>"),
                "scene.xml:2: <TexCoordData>: the number of values must be a multiple of 2 (u v per texture coordinate), found 3",
            ),
            (
                &scene(
                    "<Objects>\n<Mesh id=\"1\"><Material>1</Material>\n<Faces vertexOffset=\"1\" textureOffset=\"1.5\">0 1 2</Faces></Mesh>\n</Objects>",
                ),
                r#"scene.xml:4: <Mesh id="1"> / <Faces>: attribute textureOffset must be an integer, found "1.5""#,
            ),
            (
                &scene("<BackgroundTexture>\n</BackgroundTexture>"),
                "scene.xml:2: <BackgroundTexture>: expected an image file path, found nothing",
            ),
            // 2019 <Texture>
            (
                &legacy("", "<Interpolation>bilinear</Interpolation>"),
                r#"scene.xml:3: <Texture id="1">: missing <ImageName> (an image file, or the word perlin or checkerboard)"#,
            ),
            (
                &scene("<Textures>\n<Texture><ImageName>perlin</ImageName></Texture>\n</Textures>"),
                "scene.xml:3: <Texture>: missing attribute id (other elements refer to it by id)",
            ),
            (
                &legacy("", "<ImageName>a.jpg</ImageName>\n<DecalMode>mix</DecalMode>"),
                &format!(
                    r#"scene.xml:5: <Texture id="1"> / <DecalMode>: DecalMode must be {}, replace or blend, found "mix""#,
                    decals.replace(" or ", ", ")
                ),
            ),
            (
                &legacy("", "<ImageName>a.jpg</ImageName>\n<Appearance>vein</Appearance>"),
                r#"scene.xml:5: <Texture id="1"> / <Appearance>: Appearance must be repeat or clamp, found "vein""#,
            ),
            (
                &legacy("", "<ImageName>perlin</ImageName>\n<Appearance>repeat</Appearance>"),
                r#"scene.xml:5: <Texture id="1"> / <Appearance>: Appearance must be patch or vein, found "repeat""#,
            ),
            (
                &legacy("", "<ImageName>perlin</ImageName>\n<Normalizer>one</Normalizer>"),
                r#"scene.xml:5: <Texture id="1"> / <Normalizer>: expected a number, found "one""#,
            ),
            (
                &legacy("", "<ImageName>checkerboard</ImageName>\n<ScalingFactor></ScalingFactor>"),
                r#"scene.xml:5: <Texture id="1"> / <ScalingFactor>: expected a number, found nothing"#,
            ),
            (
                &legacy(" bumpmap=\"yes\"", "<ImageName>a.jpg</ImageName>"),
                r#"scene.xml:3: <Texture id="1">: attribute bumpmap must be true or false, found "yes""#,
            ),
            (
                &legacy(" bumpmap=\"true\" bumpmapMultiplier=\"3x\"", "<ImageName>a.jpg</ImageName>"),
                r#"scene.xml:3: <Texture id="1">: attribute bumpmapMultiplier must be a number, found "3x""#,
            ),
        ];
        check_errors(cases);
    }

    #[test]
    fn tex_coords_and_texture_offset() {
        let records = parse(&scene(
            r#"<VertexData>0 0 0  1 0 0  0 1 0</VertexData>
<TexCoordData>
    0 0
    1 0.5  0.25
    1
</TexCoordData>
<Objects>
  <Mesh id="1"><Material>1</Material><Faces vertexOffset="1" textureOffset="2">0 1 2</Faces></Mesh>
  <Mesh id="2"><Material>1</Material><Faces textureOffset=" -1 ">1 2 3</Faces></Mesh>
  <Mesh id="3"><Material>1</Material><Faces>1 2 3</Faces></Mesh>
</Objects>"#,
        ));
        assert!(records.warnings.is_empty(), "{:?}", records.warnings);
        assert_eq!(records.tex_coords, vec![[0.0, 0.0], [1.0, 0.5], [0.25, 1.0]]);
        let faces: Vec<_> = records.meshes.iter().map(|m| m.faces.clone()).collect();
        assert_eq!(
            faces,
            vec![
                FacesRec::Inline { indices: vec![0, 1, 2], vertex_offset: 1, texture_offset: Some(2) },
                FacesRec::Inline { indices: vec![1, 2, 3], vertex_offset: 0, texture_offset: Some(-1) },
                FacesRec::Inline { indices: vec![1, 2, 3], vertex_offset: 0, texture_offset: None },
            ]
        );
        // Empty or absent (the PLY scenes: ton_Roosendaal_smooth, tower, windmill).
        for body in [
            "<TexCoordData></TexCoordData>",
            "<TexCoordData/>",
            "<TexCoordData> <!-- none --> </TexCoordData>",
            "",
        ] {
            let records = parse(&scene(body));
            assert!(records.warnings.is_empty(), "{:?}", records.warnings);
            assert!(records.tex_coords.is_empty());
        }
    }

    #[test]
    fn object_texture_lists() {
        let records = objects(
            r#"<Mesh id="1"><Material>1</Material><Textures>1 2</Textures><Faces>1 1 1</Faces></Mesh>
               <Mesh id="2"><Material>1</Material><Textures>1</Textures>
                   <Textures> 1 </Textures><Faces>1 1 1</Faces></Mesh>
               <Mesh id="3"><Material>1</Material><Faces>1 1 1</Faces><Textures></Textures></Mesh>
               <Triangle id="1"><Material>1</Material><Indices>1 1 1</Indices><Textures>
                   a  b
               </Textures></Triangle>
               <Sphere id="1"><Material>1</Material><Center>1</Center><Radius>1</Radius><Textures>3</Textures></Sphere>
               <Sphere id="2"><Material>1</Material><Center>1</Center><Radius>1</Radius></Sphere>"#,
            "",
        );
        // The repeated identical <Textures> of the cube_* scenes is accepted without a warning.
        assert!(records.warnings.is_empty(), "{:?}", records.warnings);
        let ids = |t: &[String]| t.join(",");
        let meshes: Vec<String> = records.meshes.iter().map(|m| ids(&m.textures)).collect();
        assert_eq!(meshes, ["1,2", "1", ""]);
        assert_eq!(ids(&records.triangles[0].textures), "a,b");
        let spheres: Vec<String> = records.spheres.iter().map(|s| ids(&s.textures)).collect();
        assert_eq!(spheres, ["3", ""]);
    }

    #[test]
    fn object_texture_list_warnings() {
        let w = |line: u32, element: &str, message: &str| {
            format!("warning: scene.xml:{line}: <{element}>: {message}")
        };
        let objs = |inner: &str| scene(&format!("<Objects>\n{inner}\n</Objects>"));
        let cases: &[(&str, &[&str], &[&str])] = &[
            (
                &objs(
                    "<Mesh id=\"1\"><Material>1</Material><Faces>1 1 1</Faces>\n<Textures>1 2</Textures>\n<Textures>1</Textures></Mesh>",
                ),
                &[&w(
                    5,
                    r#"Mesh id="1"> / <Textures"#,
                    r#"<Textures> is given more than once with different ids; only the first one ("1 2") is used"#,
                )],
                &["1", "2"],
            ),
            (
                &objs(
                    "<Sphere id=\"1\"><Material>1</Material><Center>1</Center><Radius>1</Radius>\n<Texture>1</Texture>\n<Textures>2</Textures></Sphere>",
                ),
                &[&w(
                    4,
                    r#"Sphere id="1"> / <Texture"#,
                    "<Texture> (the 2019 spelling) is ignored because <Textures> is given",
                )],
                &["2"],
            ),
            (
                &objs(
                    "<Triangle id=\"1\"><Material>1</Material><Indices>1 1 1</Indices>\n<Textures>1<Id>2</Id></Textures></Triangle>",
                ),
                &[&w(4, r#"Triangle id="1"> / <Textures> / <Id"#, "unknown element <Id>; it is ignored")],
                &["1"],
            ),
        ];
        for (xml, expected_warnings, expected_ids) in cases {
            let records = parse(xml);
            let got: Vec<String> = records.warnings.iter().map(ToString::to_string).collect();
            assert_eq!(got, *expected_warnings, "input:\n{xml}");
            let textures = (records.meshes.iter().map(|m| &m.textures))
                .chain(records.spheres.iter().map(|s| &s.textures))
                .chain(records.triangles.iter().map(|t| &t.textures))
                .next()
                .cloned()
                .unwrap_or_default();
            assert_eq!(textures, *expected_ids, "input:\n{xml}");
        }
    }

    /// The 2019 textures as the course scenes write them (bump_mapping_basic, spheres_perlin,
    /// perlin_types_bump, VeachAjar_2019, skybox), translated into 2020 records.
    const LEGACY_TEXTURES: &str = r#"<Scene>
<Textures>
    <Texture id="1">
        <ImageName>textures/earth.jpg</ImageName>
        <Interpolation>nearest</Interpolation>
        <DecalMode>blend_kd</DecalMode>
        <Normalizer>255</Normalizer>
        <Appearance>repeat</Appearance>
    </Texture>
    <Texture id="2" bumpmap="true" bumpmapMultiplier="30" degamma="true">
        <ImageName>textures/another_grid.jpg</ImageName>
        <Interpolation>bilinear</Interpolation>
        <DecalMode>replace_kd</DecalMode>
        <Normalizer>255</Normalizer>
    </Texture>
    <Texture id="3" bumpmap="true">
        <ImageName>perlin</ImageName>
        <ScalingFactor>3</ScalingFactor>
        <Appearance>vein</Appearance>
        <DecalMode>replace_kd</DecalMode>
        <Normalizer>1</Normalizer>
    </Texture>
    <Texture id="4">
        <ImageName>perlin</ImageName>
    </Texture>
    <Texture id="5" bumpmap="false" bumpmapMultiplier="30">
        <ImageName>checkerboard</ImageName>
        <BlackColor>0.4 0.4 0.4</BlackColor>
        <WhiteColor>10 10 10</WhiteColor>
        <ScalingFactor>0.1</ScalingFactor>
        <Offset>79</Offset>
        <DecalMode>blend</DecalMode>
        <Normalizer>1</Normalizer>
        <Dimension3>true</Dimension3>
    </Texture>
    <Texture id="6">
        <ImageName>checkerboard</ImageName>
        <DecalMode>replace</DecalMode>
    </Texture>
    <Texture id="7">
        <ImageName>textures/sky.jpg</ImageName>
        <DecalMode>replace_all</DecalMode>
        <Normalizer>1</Normalizer>
    </Texture>
    <Texture id="8">
        <ImageName>textures/plain.png</ImageName>
    </Texture>
</Textures>
<Objects>
    <Mesh id="1"><Material>1</Material><Texture>2</Texture><Faces>1 1 1</Faces></Mesh>
    <Sphere id="1"><Material>1</Material><Texture> 3 </Texture><Center>1</Center><Radius>1</Radius></Sphere>
    <Sphere id="2"><Material>1</Material><Texture>5</Texture><Center>1</Center><Radius>1</Radius></Sphere>
    <Sphere id="3"><Material>1</Material><Textures>2 1</Textures><Center>1</Center><Radius>1</Radius></Sphere>
    <Triangle id="1"><Material>1</Material><Texture>1</Texture><Texture>1</Texture><Indices>1 1 1</Indices></Triangle>
</Objects>
</Scene>
"#;

    #[test]
    fn legacy_2019_textures_become_texture_maps() {
        use DecalMode::*;
        use Interpolation::*;
        let xml = LEGACY_TEXTURES;
        let records = parse(xml);
        assert!(records.warnings.is_empty(), "{:?}", records.warnings);
        let at = |id: &str| loc_of(xml, &format!(r#"<Texture id="{id}""#), &format!(r#"Texture id="{id}""#));
        let image =
            |id: &str, path: &str| ImageRec { id: format!("2019:{id}"), loc: at(id), path: path.into() };
        assert_eq!(
            records.images,
            vec![
                image("1", "textures/earth.jpg"),
                image("2", "textures/another_grid.jpg"),
                image("7", "textures/sky.jpg"),
                image("8", "textures/plain.png"),
            ]
        );
        let vein = TextureSource::Perlin { conversion: NoiseConversion::AbsVal, scale: 3.0 };
        let grid = image_source("2019:2", Bilinear, 255.0);
        let expected = vec![
            map("1", at("1"), image_source("2019:1", Nearest, 255.0), BlendKd),
            // bumpmap="true": the colour map and a bump map over the same source.
            TextureMapRec { degamma: true, ..map("2", at("2"), grid.clone(), ReplaceKd) },
            TextureMapRec { bump_factor: 30.0, degamma: true, ..map("2:bump", at("2"), grid, BumpNormal) },
            map("3", at("3"), vein.clone(), ReplaceKd),
            map("3:bump", at("3"), vein, BumpNormal),
            // Defaults: patch (linear), ScalingFactor 1, DecalMode replace_kd.
            map(
                "4",
                at("4"),
                TextureSource::Perlin { conversion: NoiseConversion::Linear, scale: 1.0 },
                ReplaceKd,
            ),
            // bumpmap="false": the multiplier means nothing.
            map(
                "5",
                at("5"),
                TextureSource::Checkerboard { black: [0.4; 3], white: [10.0; 3], scale: 0.1, offset: 79.0 },
                BlendKd,
            ),
            map(
                "6",
                at("6"),
                TextureSource::Checkerboard { black: [0.0; 3], white: [1.0; 3], scale: 1.0, offset: 0.0 },
                ReplaceKd,
            ),
            map("7", at("7"), image_source("2019:7", Nearest, 1.0), ReplaceAll),
            map("8", at("8"), image_source("2019:8", Nearest, 255.0), ReplaceKd),
        ];
        assert_eq!(records.texture_maps, expected);
        // An object's <Texture>k</Texture> names both maps of a bumpmap texture.
        assert_eq!(records.meshes[0].textures, ["2", "2:bump"]);
        assert_eq!(records.spheres[0].textures, ["3", "3:bump"]);
        assert_eq!(records.spheres[1].textures, ["5"]);
        assert_eq!(records.spheres[2].textures, ["2", "2:bump", "1"]);
        assert_eq!(records.triangles[0].textures, ["1"]);
    }

    #[test]
    fn texture_warnings() {
        let w = |line: u32, element: &str, message: &str| {
            format!("warning: scene.xml:{line}: <{element}>: {message}")
        };
        let textures = |inner: &str| scene(&format!("<Textures>\n{inner}\n</Textures>"));
        let cases: &[(&str, &[&str])] = &[
            (
                &textures(
                    "<TextureMap id=\"1\" type=\"perlin\" bumpmap=\"true\"><DecalMode>replace_kd</DecalMode>\n\
                     <NumOctaves>4</NumOctaves>\n<Normalizer>1</Normalizer><Scale>2</Scale>\n<Foo/></TextureMap>",
                ),
                &[
                    &w(3, r#"TextureMap id="1""#, "unknown attribute bumpmap; it is ignored"),
                    &w(
                        4,
                        r#"TextureMap id="1"> / <NumOctaves"#,
                        "<NumOctaves> is not supported yet; it is ignored",
                    ),
                    &w(
                        5,
                        r#"TextureMap id="1"> / <Normalizer"#,
                        "<Normalizer> does not apply to perlin texture maps; it is ignored",
                    ),
                    &w(
                        5,
                        r#"TextureMap id="1"> / <Scale"#,
                        "<Scale> does not apply to perlin texture maps; it is ignored",
                    ),
                    &w(6, r#"TextureMap id="1"> / <Foo"#, "unknown element <Foo>; it is ignored"),
                ],
            ),
            (
                &textures(
                    "<TextureMap id=\"1\" type=\"checkerboard\"><DecalMode>replace_kd</DecalMode>\n<ImageId>1</ImageId></TextureMap>\n\
                     <TextureMap id=\"2\" type=\"image\"><ImageId>1</ImageId><DecalMode>replace_kd</DecalMode>\n\
                     <NoiseScale>2</NoiseScale><DecalMode>blend_kd</DecalMode></TextureMap>",
                ),
                &[
                    &w(
                        4,
                        r#"TextureMap id="1"> / <ImageId"#,
                        "<ImageId> does not apply to checkerboard texture maps; it is ignored",
                    ),
                    &w(
                        6,
                        r#"TextureMap id="2"> / <NoiseScale"#,
                        "<NoiseScale> does not apply to image texture maps; it is ignored",
                    ),
                    &w(
                        6,
                        r#"TextureMap id="2"> / <DecalMode"#,
                        "<DecalMode> is given more than once; only the first one is used",
                    ),
                ],
            ),
            (
                &textures(
                    "<Images><Image id=\"1\">a.png</Image>\n<Picture/></Images>\n<Texture id=\"1\">\n<ImageName>a.jpg</ImageName>\n\
                     <Appearance> clamp </Appearance>\n<ScalingFactor>2</ScalingFactor></Texture>\n<Texture id=\"2\">\
                     <ImageName>perlin</ImageName>\n<Normalizer>255</Normalizer><Interpolation>bilinear</Interpolation></Texture>\n\
                     <Texture id=\"3\"><ImageName>checkerboard</ImageName>\n<Appearance>patch</Appearance></Texture>\n<Other/>",
                ),
                &[
                    &w(4, "Images> / <Picture", "unknown element <Picture>; it is ignored"),
                    &w(
                        7,
                        r#"Texture id="1"> / <Appearance"#,
                        "<Appearance>clamp</Appearance> is not supported yet; the texture is repeated instead",
                    ),
                    &w(
                        8,
                        r#"Texture id="1"> / <ScalingFactor"#,
                        "<ScalingFactor> does not apply to image textures; it is ignored",
                    ),
                    &w(
                        10,
                        r#"Texture id="2"> / <Interpolation"#,
                        "<Interpolation> does not apply to perlin textures; it is ignored",
                    ),
                    &w(
                        10,
                        r#"Texture id="2"> / <Normalizer"#,
                        "<Normalizer> has no effect on perlin textures (their values are used as they are); it is ignored",
                    ),
                    &w(
                        12,
                        r#"Texture id="3"> / <Appearance"#,
                        "<Appearance> does not apply to checkerboard textures; it is ignored",
                    ),
                    &w(13, "Other", "unknown element <Other>; it is ignored"),
                ],
            ),
        ];
        check_warnings(cases);
    }

    #[test]
    fn background_texture_is_a_raw_replace_background_map() {
        let xml = scene("<BackgroundTexture> textures/galaxy.jpg </BackgroundTexture>");
        let records = parse(&xml);
        assert!(records.warnings.is_empty(), "{:?}", records.warnings);
        let loc = Loc::new(2, "BackgroundTexture");
        assert_eq!(
            records.images,
            vec![ImageRec {
                id: "2019:background".into(),
                loc: loc.clone(),
                path: "textures/galaxy.jpg".into()
            }]
        );
        assert_eq!(
            records.texture_maps,
            vec![map(
                "2019:background",
                loc,
                image_source("2019:background", Interpolation::Bilinear, 1.0),
                DecalMode::ReplaceBackground
            )]
        );
    }

    /// Truncated and garbage inputs must give errors, never panics.
    #[test]
    fn truncated_and_garbage_inputs_are_errors() {
        let end = SIMPLE.find("</Scene>").expect("SIMPLE ends with </Scene>") + "</Scene>".len();
        for (cut, _) in SIMPLE.char_indices().filter(|&(i, _)| i < end) {
            assert!(parse_xml(&SIMPLE[..cut], Path::new(FILE)).is_err(), "truncated at byte {cut} parsed");
        }
        let deep = "<Scene>".to_string() + &"<a>".repeat(100_000);
        let garbage = [
            "<",
            "<<>>",
            "</Scene>",
            "<Scene",
            "<Scene><!-- </Scene>",
            "<Scene><![CDATA[</Scene>",
            "<Scene><Cameras><Camera id=\"1\"><Position>1 2",
            "<Scene>&#0;</Scene>",
            "<Scene>&#xFFFFFFFF;</Scene>",
            "<Scene a='1' a='2'></Scene>",
            "<?xml version=\"1.0\"?>",
            "\u{0}\u{1}\u{2}",
            "\u{feff}",
            &deep,
        ];
        for input in garbage {
            assert!(parse_xml(input, Path::new(FILE)).is_err(), "{:?} parsed", excerpt(input));
        }
        // Random byte mutations of valid scenes: any result is fine, a panic is not.
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for valid in [SIMPLE, TEXTURE_MAPS, LEGACY_TEXTURES] {
            for _ in 0..2000 {
                let mut bytes = valid.as_bytes().to_vec();
                for _ in 0..3 {
                    let at = (next() % bytes.len() as u64) as usize;
                    bytes[at] = b"<>/=\"' 0x!-&;\n"[(next() % 14) as usize];
                }
                let _ = parse_xml(&String::from_utf8_lossy(&bytes), Path::new(FILE));
            }
        }
    }

    /// Every scene of the course set parses (2019 files may warn about legacy elements).
    #[test]
    fn all_course_scenes_parse() {
        let dir = tessera_testkit::shared_scenes().join("xml");
        if !tessera_testkit::corpus_has(&dir) {
            return;
        }
        let entries = std::fs::read_dir(&dir).unwrap();
        let mut paths: Vec<_> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "xml"))
            .collect();
        paths.sort();
        assert!(!paths.is_empty(), "no scenes in {}", dir.display());
        let mut failures = Vec::new();
        for path in &paths {
            let text = std::fs::read_to_string(path).expect("scene file is readable UTF-8");
            match parse_xml(&text, path) {
                Ok(records) => {
                    assert!(!records.cameras.is_empty(), "{}: no cameras", path.display());
                    let mut kinds: Vec<&str> = records.warnings.iter().map(|w| w.message.as_str()).collect();
                    kinds.sort();
                    kinds.dedup();
                    if !kinds.is_empty() {
                        println!(
                            "{}: {} warnings: {}",
                            path.display(),
                            records.warnings.len(),
                            kinds.join(" | ")
                        );
                    }
                }
                Err(e) => failures.push(e.to_string()),
            }
        }
        assert!(failures.is_empty(), "{} scenes failed:\n{}", failures.len(), failures.join("\n"));
    }
}
