//! The element tree both front ends build, and its walk into scene records.
//!
//! The tree is `Node`s; the walk, `parse_tree`, holds every element rule, default, warning
//! and error of the scene format, shared by the XML ([`super::xml`]) and JSON ([`super::json`])
//! front ends.
//!
//! `parse_tree` walks a `<Scene>` tree and fills [`SceneRecords`]. Because it looks children
//! up by name, the order of elements inside `<Scene>` (and anywhere else) does not matter. The
//! 2019 legacy rules for materials (scene-format.md §6.1, §6.9) and the 2019 `<Texture>` /
//! `<BackgroundTexture>` elements (translated into 2020 texture maps, §11.11) apply to XML trees
//! only. The `Dialect` of a tree changes how messages name elements (`json_words`) and one
//! default ([`DEFAULT_MAX_RECURSION_DEPTH`]), nothing else.
//!
//! Nothing is resolved here: ids stay strings, PLY files are not opened. Elements we do not know
//! become warnings, elements of the format that are not implemented yet become "not supported
//! yet" warnings marked [`Warning::unsupported`] when leaving them out changes the picture (the
//! loaders refuse those unless allowed), and everything a user can get wrong is a [`SceneError`]
//! naming the file, the line and the element. No input makes this module panic.

use std::path::Path;

use super::records::{
    AreaLightRec, BinaryFileRec, BrdfKind, BrdfRec, CameraRec, DecalMode, DirectionalLightRec, EnvLightRec,
    EnvMapping, EnvSampler, FacesRec, Handedness, ImageRec, InstanceRec, Interpolation, LensRec,
    MAX_RECURSION_DEPTH_LIMIT, MaterialKind, MaterialRec, MeshRec, NoiseConversion, PathParams, PlaneRec,
    PointLightRec, Projection, Renderer, Roulette, SceneRecords, ShadingMode, SphereRec, SpotLightRec,
    TextureMapRec, TextureSource, TonemapRec, TransformOp, TransformRec, TransformRef, TriangleRec, Vec3,
};
use crate::error::{Loc, SceneError, Warning};
use crate::tonemap::params::{Operator, Photographic};

type Result<T> = std::result::Result<T, SceneError>;

/// `MaxRecursionDepth` of a JSON scene that does not give one. The course parser's default is
/// 0 (§3) and the 2022 references follow it, but the 2025 references do not: bunny_with_plane
/// (mirror floor and wall, no MaxRecursionDepth) is 17.6 dB (PSNR after the 4x4 box) from its
/// reference with 0 and 52.3 dB with any depth from 2 up (1: 52.0 dB). 6 is what 30 of the 34
/// shipped JSON scenes that give a depth give.
pub const DEFAULT_MAX_RECURSION_DEPTH: u32 = 6;

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
        parser.out.max_recursion_depth = DEFAULT_MAX_RECURSION_DEPTH;
    }
    parser.scene(root)?;
    // Report in file order (the walk visits blocks, not lines); the sort is stable.
    parser.out.warnings.sort_by_key(|w| w.loc.line);
    Ok(parser.out)
}

// ---------------------------------------------------------------------------------------------
// The element tree
// ---------------------------------------------------------------------------------------------

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
    pub(super) fn loc(&self) -> Loc {
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
pub(super) fn excerpt(text: &str) -> String {
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

/// An element or attribute of the format that is not implemented, with what the picture lacks
/// without it ("without it, ..."): [`Parser::check`] reports it as [`Warning::unsupported`].
type Unsupported = (&'static str, &'static str);

/// What an element may contain, for the unknown / not-supported-yet warnings.
struct Schema {
    /// Children read by the parser, at most one of each (later copies are warned about).
    single: &'static [&'static str],
    /// Children read by the parser that may repeat (list entries and containers).
    many: &'static [&'static str],
    /// Children that belong to the format but are not implemented yet; each changes the
    /// picture (elements that would not are read and warned about where they are read).
    unsupported: &'static [Unsupported],
    attrs: &'static [&'static str],
    unsupported_attrs: &'static [Unsupported],
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
    // BackgroundTexture, BackfaceCulling and ZeroBasedIndexing are 2019 elements, the last two
    // read by `Parser::legacy_hints`.
    single: &[
        "BackgroundColor",
        "ShadowRayEpsilon",
        "IntersectionTestEpsilon",
        "MaxRecursionDepth",
        "VertexData",
        "TexCoordData",
        "BackgroundTexture",
        "BackfaceCulling",
        "ZeroBasedIndexing",
    ],
    many: &["Cameras", "Lights", "Materials", "Transformations", "Objects", "Textures", "BRDFs"],
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
        "Renderer",
        "RendererParams",
        // 2019 path tracing (§4.1: commented out in sponza_path.xml).
        "ClampSamples",
    ],
    many: &["Tonemap"],
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
    attrs: &["id", "type", "degamma", "BRDF"],
    ..Schema::EMPTY
};
const BRDFS: Schema = Schema {
    many: &["OriginalPhong", "ModifiedPhong", "OriginalBlinnPhong", "ModifiedBlinnPhong", "TorranceSparrow"],
    ..Schema::EMPTY
};
const BRDF_KINDS: &[(&str, BrdfKind)] = &[
    ("OriginalPhong", BrdfKind::OriginalPhong),
    ("ModifiedPhong", BrdfKind::ModifiedPhong),
    ("OriginalBlinnPhong", BrdfKind::OriginalBlinnPhong),
    ("ModifiedBlinnPhong", BrdfKind::ModifiedBlinnPhong),
    ("TorranceSparrow", BrdfKind::TorranceSparrow),
];
const BRDF_PLAIN: Schema = Schema { single: &["Exponent"], attrs: &["id"], ..Schema::EMPTY };
const BRDF_MODIFIED: Schema = Schema { single: &["Exponent"], attrs: &["id", "normalized"], ..Schema::EMPTY };
const BRDF_TORRANCE_SPARROW: Schema =
    Schema { single: &["Exponent", "RefractiveIndex"], attrs: &["id", "kdfresnel"], ..Schema::EMPTY };
/// The words of `<RendererParams>` (§13.1).
const RENDERER_PARAMS: &[&str] =
    &["NextEventEstimation", "ImportanceSampling", "RussianRoulette", "UnbiasedRussianRoulette"];
const TRANSFORMATIONS: Schema =
    Schema { many: &["Translation", "Scaling", "Rotation", "Composite"], ..Schema::EMPTY };
const TRANSFORMATION: Schema = Schema { attrs: &["id"], ..Schema::EMPTY };
const OBJECTS: Schema = Schema {
    // Plane only exists in the 2025 JSON dialect so far (§9.8); XML files may use it too.
    many: &["Mesh", "Triangle", "Sphere", "MeshInstance", "Plane", "LightMesh", "LightSphere"],
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
/// Object lights (§9.6, §9.7): a mesh or a sphere that also emits `Radiance`. They do not move
/// (no MotionBlur) and carry no textures.
const LIGHT_MESH: Schema = Schema {
    single: &["Material", "Faces", "Transformations", "Radiance"],
    unsupported: LIGHT_UNSUPPORTED,
    attrs: &["id", "shadingMode"],
    ..Schema::EMPTY
};
const LIGHT_SPHERE: Schema = Schema {
    single: &["Material", "Center", "Radius", "Transformations", "Radiance"],
    unsupported: LIGHT_UNSUPPORTED,
    attrs: &["id"],
    ..Schema::EMPTY
};
/// What other objects have and object lights do not (yet): each changes the picture.
const LIGHT_UNSUPPORTED: &[Unsupported] = &[
    ("MotionBlur", "without it, the light stands still"),
    ("Textures", "without them, the light's surface is untextured"),
    ("Texture", "without it, the light's surface is untextured"),
];
const TRIANGLE: Schema = Schema {
    single: &["Material", "Indices", "Transformations", "MotionBlur"],
    many: &["Textures", "Texture"],
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
    many: &["Textures", "Texture"],
    attrs: &["id", "baseMeshId", "resetTransform", "shadingMode"],
    ..Schema::EMPTY
};
// Also used for `TexCoordData`.
// `type` is the 2025 JSON `_type` (`xyz`, `uv`), checked by `Parser::data_type`; `binaryFile`
// (2019) names a file the values are read from at build time.
const VERTEX_DATA_ATTRS: &[&str] = &["type", "binaryFile"];
const FACES_ATTRS: &[&str] = &["vertexOffset", "textureOffset", "plyFile", "binaryFile", "type"];
const FACES_UNSUPPORTED_ATTRS: &[Unsupported] = &[];

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
    // `NumOctaves` (2025: a fractal sum of octaves) is read by `Parser::num_octaves`.
    single: &["DecalMode", "NoiseConversion", "NoiseScale", "BumpFactor", "NumOctaves"],
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
// `Dimension3` false: a 2-D checkerboard in the texture coordinates.
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
/// `true` / `false` element text (2019 `<Dimension3>`).
const BOOLEANS: &[(&str, bool)] = &[("true", true), ("false", false)];
/// Most octaves a perlin map's `<NumOctaves>` may ask for: octave 31 is already 2^-30 of the
/// first, far below any display's resolution.
const MAX_OCTAVES: u32 = 32;
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
        self.out.warnings.push(Warning::new(self.file, node.loc(), message));
    }

    /// Something of the format that is not implemented and whose absence changes the picture:
    /// `message` says what and, after "without it, ", what the picture lacks. The loaders refuse
    /// the scene unless unsupported elements are allowed ([`Warning::unsupported`]).
    fn unsupported(&mut self, node: &Node, message: impl Into<String>) {
        let message = self.say(message.into());
        self.out.warnings.push(Warning::unsupported(self.file, node.loc(), message));
    }

    /// A message in the words of the file's dialect (see [`json_words`]).
    fn say(&self, message: String) -> String {
        match self.dialect {
            Dialect::Xml => message,
            Dialect::Json => json_words(&message),
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
            } else if let Some((_, without)) = schema.unsupported.iter().find(|(n, _)| *n == name) {
                self.unsupported(child, format!("<{name}> is not supported yet; {without}"));
            } else if schema.inapplicable.contains(&name) {
                self.warn(child, format!("<{name}> {}; it is ignored", schema.inapplicable_why));
            } else if !schema.many.contains(&name) {
                self.warn(child, format!("unknown element <{name}>; it is ignored"));
            }
        }
    }

    fn check_attrs(&mut self, node: &Node, known: &[&str], unsupported: &[Unsupported]) {
        for (key, _) in &node.attrs {
            if let Some((_, without)) = unsupported.iter().find(|(k, _)| k == key) {
                self.unsupported(node, format!("attribute {key} is not supported yet; {without}"));
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
        self.legacy_hints(scene)?;
        if let Some(c) = self.optional_numbers(scene, "BackgroundColor")? {
            self.out.background_color = c;
        }
        if let Some(node) = scene.child("ShadowRayEpsilon") {
            self.out.shadow_ray_epsilon = self.number(node)?;
            self.out.epsilon_locs[0] = Some(node.loc());
        }
        if let Some(node) = scene.child("IntersectionTestEpsilon") {
            self.out.intersection_test_epsilon = self.number(node)?;
            self.out.epsilon_locs[1] = Some(node.loc());
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
                "BRDFs" => {
                    self.check(block, &BRDFS);
                    for b in &block.children {
                        if let Some(b) = self.brdf(b)? {
                            self.out.brdfs.push(b);
                        }
                    }
                }
                _ => {}
            }
        }
        Ok(())
    }

    /// The 2019 scene-level `<BackfaceCulling>` and `<ZeroBasedIndexing>` (§3). Culling is an
    /// optimisation hint that never changes the correct image, so not culling is only worth a
    /// warning (`false` is accepted without a word); `ZeroBasedIndexing` is recorded.
    fn legacy_hints(&mut self, scene: &Node) -> Result<()> {
        if let Some(b) = scene.child("BackfaceCulling")
            && b.text.trim() != "false"
        {
            self.warn(
                b,
                "<BackfaceCulling> is an optimisation hint that Tessera does not take: it never culls, \
                 which gives the correct image (§3); it is ignored",
            );
        }
        if let Some(z) = scene.child("ZeroBasedIndexing") {
            self.out.zero_based_indexing = self.keyword(z, BOOLEANS)?;
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
        let clamp_samples = match n.child("ClampSamples") {
            None => None,
            Some(c) => match self.number::<f64>(c)? {
                v if v > 0.0 => Some(v),
                v => {
                    return Err(self.err(
                        c,
                        format!("ClampSamples must be positive, found {v} (each sample's radiance is clamped to it)"),
                    ));
                }
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
        let renderer = self.renderer(n)?;
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
            clamp_samples,
            lens,
            tonemaps,
            renderer,
        })
    }

    /// A camera's `<Renderer>` and `<RendererParams>` (§13.1).
    fn renderer(&mut self, n: &Node) -> Result<Renderer> {
        let params = n.child("RendererParams");
        let path = match n.child("Renderer") {
            None => false,
            Some(r) => match r.text.trim() {
                "PathTracing" => true,
                // Some parsers accept the classic tracer's name explicitly.
                "" | "DirectLighting" | "RayTracing" => false,
                other => {
                    return Err(self.err(
                        r,
                        format!(
                            "unknown renderer \"{}\" (expected PathTracing, or DirectLighting for the classic ray tracer)",
                            excerpt(other)
                        ),
                    ));
                }
            },
        };
        if !path {
            if let Some(p) = params
                && !p.text.trim().is_empty()
            {
                self.warn(
                    p,
                    "<RendererParams> only applies to <Renderer>PathTracing</Renderer>; it is ignored",
                );
            }
            return Ok(Renderer::Classic);
        }
        let mut out = PathParams::default();
        for word in params.map(|p| p.text.split_ascii_whitespace()).into_iter().flatten() {
            match word {
                "NextEventEstimation" => out.next_event = true,
                "ImportanceSampling" => out.importance = true,
                "RussianRoulette" | "UnbiasedRussianRoulette" => {
                    let wanted =
                        if word == "RussianRoulette" { Roulette::Course } else { Roulette::Unbiased };
                    if out.roulette != Roulette::Off && out.roulette != wanted {
                        let p = params.expect("words come from it");
                        return Err(self.err(
                            p,
                            "RussianRoulette (the course's rule) and UnbiasedRussianRoulette exclude each other; keep one",
                        ));
                    }
                    out.roulette = wanted;
                }
                other => {
                    let p = params.expect("words come from it");
                    return Err(self.err(
                        p,
                        format!(
                            "unknown renderer parameter \"{}\" (expected any of {})",
                            excerpt(other),
                            RENDERER_PARAMS.join(", ")
                        ),
                    ));
                }
            }
        }
        Ok(Renderer::Path(out))
    }

    /// One entry of `<BRDFs>` (§7); `None` for elements that are not BRDFs (already warned
    /// about by the caller's check).
    fn brdf(&mut self, n: &Node) -> Result<Option<BrdfRec>> {
        let Some(&(_, kind)) = BRDF_KINDS.iter().find(|(name, _)| *name == n.name) else { return Ok(None) };
        let schema = match kind {
            BrdfKind::ModifiedPhong | BrdfKind::ModifiedBlinnPhong => &BRDF_MODIFIED,
            BrdfKind::TorranceSparrow => &BRDF_TORRANCE_SPARROW,
            BrdfKind::OriginalPhong | BrdfKind::OriginalBlinnPhong => &BRDF_PLAIN,
        };
        self.check(n, schema);
        let exponent: f64 = self.required_number(n, "Exponent")?;
        if !(0.0..=1e6).contains(&exponent) {
            let e = n.child("Exponent").unwrap_or(n);
            return Err(self.err(e, format!("Exponent must be between 0 and 1000000, found {exponent}")));
        }
        let refractive_index: Option<f64> = self.optional_number(n, "RefractiveIndex")?;
        if let Some(eta) = refractive_index
            && (eta.is_nan() || eta <= 0.0)
        {
            let e = n.child("RefractiveIndex").unwrap_or(n);
            return Err(self.err(e, format!("RefractiveIndex must be positive, found {eta}")));
        }
        Ok(Some(BrdfRec {
            id: self.id(n, true)?,
            loc: n.loc(),
            kind,
            exponent,
            normalized: self.bool_attr(n, "normalized")?.unwrap_or(false),
            kd_fresnel: self.bool_attr(n, "kdfresnel")?.unwrap_or(false),
            refractive_index,
        }))
    }

    /// A camera's `<Tonemap>` (§12.2); absent children take the student-parser defaults.
    fn tonemap(&mut self, n: &Node) -> Result<TonemapRec> {
        self.check(n, &TONEMAP);
        let mut params = Photographic::default();
        let mut operator = Operator::Photographic;
        if let Some(t) = n.child("TMO") {
            match t.text.parse::<Operator>() {
                Ok(op) => operator = op,
                Err(_) => self.unsupported(
                    t,
                    format!(
                        "tone-mapping operator {} is not supported (Photographic, Filmic or ACES); without it, \
                         the photographic operator is used",
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
        m.brdf = match n.attr("BRDF").map(str::trim) {
            None => None,
            Some("") => return Err(self.err(n, "attribute BRDF is empty; give the id of a <BRDFs> entry")),
            Some(id) => Some(id.to_string()),
        };

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
        self.check_attrs(n, VERTEX_DATA_ATTRS, &[]);
        self.data_type(n, "xyz", "x y z per vertex")?;
        if let Some(path) = self.binary_file(n)? {
            self.out.vertex_file = Some(path);
            return Ok(());
        }
        let values = self.number_list::<f64>(n, 3, "x y z per vertex")?;
        self.out.vertices = values.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        Ok(())
    }

    fn tex_coord_data(&mut self, n: &Node) -> Result<()> {
        self.check_attrs(n, VERTEX_DATA_ATTRS, &[]);
        self.data_type(n, "uv", "u v per texture coordinate")?;
        if let Some(path) = self.binary_file(n)? {
            self.out.tex_coord_file = Some(path);
            return Ok(());
        }
        let values = self.number_list::<f64>(n, 2, "u v per texture coordinate")?;
        self.out.tex_coords = values.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
        Ok(())
    }

    /// A 2019 `binaryFile="..."` attribute: `None` when absent; empty is an error.
    fn binary_file(&self, n: &Node) -> Result<Option<BinaryFileRec>> {
        match n.attr("binaryFile").map(str::trim) {
            None => Ok(None),
            Some("") => Err(self.err(n, "attribute binaryFile is empty; expected a file path")),
            Some(path) => Ok(Some(BinaryFileRec { path: path.to_string(), loc: n.loc() })),
        }
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
                    clamp: false,
                }
            }
            MapKind::Perlin => TextureSource::Perlin {
                conversion: self
                    .optional_keyword(n, "NoiseConversion", NOISE_CONVERSIONS)?
                    .unwrap_or(NoiseConversion::Linear),
                scale: self.optional_number(n, "NoiseScale")?.unwrap_or(1.0),
                octaves: self.num_octaves(n)?,
            },
            MapKind::Checkerboard => TextureSource::Checkerboard {
                black: self.optional_numbers(n, "BlackColor")?.unwrap_or([0.0; 3]),
                white: self.optional_numbers(n, "WhiteColor")?.unwrap_or([1.0; 3]),
                scale: self.optional_number(n, "Scale")?.unwrap_or(1.0),
                offset: self.optional_number(n, "Offset")?.unwrap_or(0.0),
                dimension3: true,
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

    /// A perlin map's `<NumOctaves>` (2025, §11.9: a fractal sum of octaves), 1 to
    /// [`MAX_OCTAVES`]; absent means 1.
    fn num_octaves(&mut self, n: &Node) -> Result<u32> {
        let Some(o) = n.child("NumOctaves") else { return Ok(1) };
        let v: u32 = self.number(o)?;
        if !(1..=MAX_OCTAVES).contains(&v) {
            return Err(self.err(
                o,
                format!("<NumOctaves> must be a whole number from 1 to {MAX_OCTAVES} (octaves of the noise), found {v}"),
            ));
        }
        Ok(v)
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
                let clamp =
                    self.optional_keyword(n, "Appearance", LEGACY_IMAGE_APPEARANCES)?.unwrap_or(false);
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
                    clamp,
                }
            }
            MapKind::Perlin => {
                self.legacy_unused_normalizer(n, "perlin")?;
                TextureSource::Perlin {
                    conversion: self
                        .optional_keyword(n, "Appearance", LEGACY_PERLIN_APPEARANCES)?
                        .unwrap_or(NoiseConversion::Linear),
                    scale: self.optional_number(n, "ScalingFactor")?.unwrap_or(1.0),
                    octaves: 1,
                }
            }
            MapKind::Checkerboard => {
                self.legacy_unused_normalizer(n, "checkerboard")?;
                TextureSource::Checkerboard {
                    black: self.optional_numbers(n, "BlackColor")?.unwrap_or([0.0; 3]),
                    white: self.optional_numbers(n, "WhiteColor")?.unwrap_or([1.0; 3]),
                    scale: self.optional_number(n, "ScalingFactor")?.unwrap_or(1.0),
                    offset: self.optional_number(n, "Offset")?.unwrap_or(0.0),
                    dimension3: self.optional_keyword(n, "Dimension3", BOOLEANS)?.unwrap_or(true),
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
                clamp: false,
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
                "Mesh" | "LightMesh" => {
                    let mesh = self.mesh(n)?;
                    self.out.meshes.push(mesh);
                }
                "Triangle" => {
                    let triangle = self.triangle(n)?;
                    self.out.triangles.push(triangle);
                }
                "Sphere" | "LightSphere" => {
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

    fn mesh(&mut self, n: &Node) -> Result<MeshRec> {
        let light = n.name == "LightMesh";
        self.check(n, if light { &LIGHT_MESH } else { &MESH });
        let id = self.id(n, true)?;
        let faces = self.required(n, "Faces")?;
        self.check_attrs(faces, FACES_ATTRS, FACES_UNSUPPORTED_ATTRS);
        self.data_type(faces, "triangle", "three vertex ids per face")?;
        let faces_rec = if let Some(path) = faces.attr("plyFile") {
            match path.trim() {
                "" => return Err(self.err(faces, "attribute plyFile is empty; expected a PLY file path")),
                path => FacesRec::Ply { path: path.to_string() },
            }
        } else if let Some(b) = self.binary_file(faces)? {
            FacesRec::Binary {
                path: b.path,
                vertex_offset: self.int_attr(faces, "vertexOffset")?.unwrap_or(0),
                texture_offset: self.int_attr(faces, "textureOffset")?,
            }
        } else {
            FacesRec::Inline {
                indices: self.number_list(faces, 3, "three vertex ids per triangle")?,
                vertex_offset: self.int_attr(faces, "vertexOffset")?.unwrap_or(0),
                texture_offset: self.int_attr(faces, "textureOffset")?,
            }
        };
        Ok(MeshRec {
            id,
            loc: n.loc(),
            material: self.material_ref(n)?,
            faces: faces_rec,
            faces_loc: faces.loc(),
            shading: self.shading_attr(n)?.unwrap_or(ShadingMode::Flat),
            transforms: self.transform_refs(n)?,
            motion_blur: if light { None } else { self.optional_numbers(n, "MotionBlur")? },
            textures: if light { Vec::new() } else { self.object_textures(n)? },
            radiance: if light { Some(self.radiance(n)?) } else { None },
        })
    }

    /// The `<Radiance>` of an object light: three non-negative numbers.
    fn radiance(&self, n: &Node) -> Result<Vec3> {
        let r = self.required(n, "Radiance")?;
        let v: Vec3 = self.numbers(r)?;
        if v.iter().any(|c| !(*c >= 0.0 && c.is_finite())) {
            return Err(self
                .err(r, format!("Radiance must be three non-negative numbers, found {}", quoted(&r.text))));
        }
        Ok(v)
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
            motion_blur: self.optional_numbers(n, "MotionBlur")?,
        })
    }

    fn sphere(&mut self, n: &Node) -> Result<SphereRec> {
        let light = n.name == "LightSphere";
        self.check(n, if light { &LIGHT_SPHERE } else { &SPHERE });
        Ok(SphereRec {
            id: self.id(n, false)?,
            loc: n.loc(),
            material: self.material_ref(n)?,
            center: self.required_number(n, "Center")?,
            radius: self.required_number(n, "Radius")?,
            transforms: self.transform_refs(n)?,
            motion_blur: if light { None } else { self.optional_numbers(n, "MotionBlur")? },
            textures: if light { Vec::new() } else { self.object_textures(n)? },
            radiance: if light { Some(self.radiance(n)?) } else { None },
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
            textures: self.object_textures(n)?,
        })
    }
}

// ---------------------------------------------------------------------------------------------
// Messages in JSON words
// ---------------------------------------------------------------------------------------------

/// ` key="value">` at the start of `s`: (key, value, what follows the `>`).
fn one_attribute(s: &str) -> Option<(&str, &str, &str)> {
    let s = s.strip_prefix(' ')?;
    let (key, s) = s.split_once("=\"")?;
    if key.is_empty() || !key.bytes().all(|b| b.is_ascii_alphanumeric()) {
        return None;
    }
    let (value, s) = s.split_once('"')?;
    let tail = s.strip_prefix('>')?;
    (!value.contains(['<', '>'])).then_some((key, value, tail))
}

/// Rewrites a message of the shared element rules in JSON words: `<Faces>` → `"Faces"`,
/// `attribute id` → `key "_id"`.
pub(super) fn json_words(message: &str) -> String {
    let mut out = String::with_capacity(message.len() + 8);
    let mut rest = message;
    while !rest.is_empty() {
        if let Some(after) = rest.strip_prefix('<') {
            let name_len = after.bytes().take_while(|b| b.is_ascii_alphanumeric()).count();
            if name_len > 0 && after.as_bytes().get(name_len) == Some(&b'>') {
                out.push('"');
                out.push_str(&after[..name_len]);
                out.push('"');
                rest = &after[name_len + 1..];
                continue;
            }
            // `<Name key="value">` (what to add, in build messages): `"Name" with "_key": "value"`.
            if let Some((key, value, tail)) = one_attribute(&after[name_len..]).filter(|_| name_len > 0) {
                out.push_str(&format!("\"{}\" with \"_{key}\": \"{value}\"", &after[..name_len]));
                rest = tail;
                continue;
            }
        }
        if let Some(after) = rest.strip_prefix("attribute ") {
            let name_len = after.bytes().take_while(|b| b.is_ascii_alphanumeric()).count();
            if name_len > 0 {
                out.push_str("key \"_");
                out.push_str(&after[..name_len]);
                out.push('"');
                rest = &after[name_len..];
                continue;
            }
        }
        let mut chars = rest.chars();
        if let Some(c) = chars.next() {
            out.push(c);
        }
        rest = chars.as_str();
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn words_are_translated_to_json() {
        assert_eq!(json_words("missing <Faces>"), "missing \"Faces\"");
        assert_eq!(
            json_words("attribute type must be latlong or probe"),
            "key \"_type\" must be latlong or probe"
        );
        assert_eq!(json_words("a < b and <x y>"), "a < b and <x y>");
        assert_eq!(json_words("ünïcode <Ä>"), "ünïcode <Ä>");
        assert_eq!(
            json_words(r#"add <Material id="7"> under <Materials> or use an existing id"#),
            r#"add "Material" with "_id": "7" under "Materials" or use an existing id"#
        );
        // Not one plain attribute: left as written.
        assert_eq!(
            json_words(r#"<A b="1" c="2">, <A b=1>, <A b="1""#),
            r#"<A b="1" c="2">, <A b=1>, <A b="1""#
        );
    }
}
