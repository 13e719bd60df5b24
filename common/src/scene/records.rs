//! Plain scene records: what a scene file *says*, before anything is built from it.
//!
//! The XML and 2025 JSON front ends produce exactly these types; everything after parsing (id
//! resolution, PLY and image loading, BVH building) reads only these. They carry no XML
//! and no render structures, and each record keeps the [`Loc`] of the element it came from so
//! that the build step can report errors precisely.
//!
//! Defaults follow scene-format.md §16.1 and are applied by the front end, so a record always
//! holds the value that will be rendered.

use std::path::PathBuf;

use crate::error::{Loc, Warning};

pub type Vec3 = [f64; 3];

/// The deepest `MaxRecursionDepth` traced; a scene asking for more is capped, with a warning.
/// The course's scenes ask for at most 6; the cap keeps a hostile value (a million) from
/// overflowing a render thread's stack, as secondary rays recurse.
pub const MAX_RECURSION_DEPTH_LIMIT: u32 = 64;

/// A whole scene file.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneRecords {
    /// The scene file this came from; asset paths are relative to its directory.
    pub source: PathBuf,
    /// Written in the 2025 JSON dialect: messages about it use JSON words (`"Material"` with
    /// `"_id"`, not `<Material id>`).
    pub json: bool,
    pub background_color: Vec3,
    pub shadow_ray_epsilon: f64,
    pub intersection_test_epsilon: f64,
    /// Where the scene gives `ShadowRayEpsilon` and `IntersectionTestEpsilon` (`None`: the
    /// default), for the build's warnings about values no scene means (see `build::epsilons`).
    pub epsilon_locs: [Option<Loc>; 2],
    /// At most [`MAX_RECURSION_DEPTH_LIMIT`].
    pub max_recursion_depth: u32,
    pub cameras: Vec<CameraRec>,
    pub ambient_light: Vec3,
    pub point_lights: Vec<PointLightRec>,
    pub area_lights: Vec<AreaLightRec>,
    pub directional_lights: Vec<DirectionalLightRec>,
    pub spot_lights: Vec<SpotLightRec>,
    /// `SphericalDirectionalLight`s (HW5 environment lights).
    pub env_lights: Vec<EnvLightRec>,
    pub materials: Vec<MaterialRec>,
    /// `<BRDFs>` entries (HW6, §7), selected by a material's `BRDF` attribute.
    pub brdfs: Vec<BrdfRec>,
    /// Global vertex list; vertex id `k` (1-based) is `vertices[k - 1]`.
    pub vertices: Vec<Vec3>,
    /// Global texture coordinates (`TexCoordData`), parallel to `vertices`: id `k` is
    /// `tex_coords[k - 1]`.
    pub tex_coords: Vec<[f64; 2]>,
    /// 2019 `<VertexData binaryFile>` and `<TexCoordData binaryFile>` (§8.2, §8.4): the values
    /// come from these files, read when the scene is built, in place of `vertices` and
    /// `tex_coords`.
    pub vertex_file: Option<BinaryFileRec>,
    pub tex_coord_file: Option<BinaryFileRec>,
    /// 2019 `<ZeroBasedIndexing>true`: the vertex ids of faces (inline and binary) and of
    /// `Triangle` `Indices` count from 0; the build turns them 1-based.
    pub zero_based_indexing: bool,
    /// `Textures/Images/Image`: image files by id (HW4).
    pub images: Vec<ImageRec>,
    /// `Textures/TextureMap` (and 2019 `<Texture>` elements, translated).
    pub texture_maps: Vec<TextureMapRec>,
    pub transformations: Vec<TransformRec>,
    pub meshes: Vec<MeshRec>,
    pub triangles: Vec<TriangleRec>,
    pub spheres: Vec<SphereRec>,
    pub instances: Vec<InstanceRec>,
    /// `Plane`s (2025 JSON dialect, §9.8).
    pub planes: Vec<PlaneRec>,
    /// Unknown or not-yet-supported elements, reported but not fatal.
    pub warnings: Vec<Warning>,
}

impl SceneRecords {
    /// An empty scene with the format's defaults (§16.1).
    pub fn new(source: impl Into<PathBuf>) -> Self {
        SceneRecords {
            source: source.into(),
            json: false,
            background_color: [0.0; 3],
            shadow_ray_epsilon: 1e-3,
            intersection_test_epsilon: 1e-6,
            epsilon_locs: [None, None],
            max_recursion_depth: 0,
            cameras: Vec::new(),
            ambient_light: [0.0; 3],
            point_lights: Vec::new(),
            area_lights: Vec::new(),
            directional_lights: Vec::new(),
            spot_lights: Vec::new(),
            env_lights: Vec::new(),
            materials: Vec::new(),
            brdfs: Vec::new(),
            vertices: Vec::new(),
            tex_coords: Vec::new(),
            vertex_file: None,
            tex_coord_file: None,
            zero_based_indexing: false,
            images: Vec::new(),
            texture_maps: Vec::new(),
            transformations: Vec::new(),
            meshes: Vec::new(),
            triangles: Vec::new(),
            spheres: Vec::new(),
            instances: Vec::new(),
            planes: Vec::new(),
            warnings: Vec::new(),
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Handedness {
    Right,
    Left,
}

/// How the image plane is given.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Projection {
    /// Plain camera: `NearPlane` l r b t.
    NearPlane { left: f64, right: f64, bottom: f64, top: f64 },
    /// `type="lookAt"`: full vertical field of view in degrees, symmetric frustum.
    FovY(f64),
}

#[derive(Clone, Debug, PartialEq)]
pub struct CameraRec {
    pub id: String,
    pub loc: Loc,
    pub position: Vec3,
    /// Viewing direction (for lookAt cameras with GazePoint: `GazePoint - Position`). Not normalised.
    pub gaze: Vec3,
    pub up: Vec3,
    /// `Transformations` (2025, §10.4), applied by the build step to Position (and so GazePoint)
    /// as a point and to Gaze and Up as directions. Empty for the 2020/21 course scenes.
    pub transforms: Vec<TransformRef>,
    pub projection: Projection,
    pub near_distance: f64,
    pub width: u32,
    pub height: u32,
    pub image_name: String,
    pub handedness: Handedness,
    /// `NumSamples`, default 1.
    pub num_samples: u32,
    /// 2019 `ClampSamples`: each sample's radiance is clamped to at most this, per channel,
    /// before the pixel's samples are averaged (`None`: not clamped).
    pub clamp_samples: Option<f64>,
    /// Thin-lens depth of field: `FocusDistance` and `ApertureSize` (side of the square lens).
    /// Both present and the aperture positive, or the camera is a pinhole.
    pub lens: Option<LensRec>,
    /// `<Tonemap>` blocks (HW5): how an HDR `ImageName` (`.exr`, `.hdr`) is also written as PNG.
    /// Empty: the photographic defaults of §12.2.
    pub tonemaps: Vec<TonemapRec>,
    /// `<Renderer>` and `<RendererParams>` (§13.1): classic ray tracing unless `PathTracing`.
    pub renderer: Renderer,
}

/// How a camera's pixels are computed (§13.1).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Renderer {
    /// The course's recursive ray tracer (§6, §16.2): direct lighting plus specular recursion.
    #[default]
    Classic,
    /// Monte Carlo path tracing (§13.2) with the camera's `RendererParams`.
    Path(PathParams),
}

/// The switches of `<RendererParams>` (§13.1).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PathParams {
    /// `NextEventEstimation`: diffuse and glossy vertices sample the lights.
    pub next_event: bool,
    /// `ImportanceSampling`: bounce directions from the cosine lobe instead of uniformly.
    pub importance: bool,
    /// `RussianRoulette` or `UnbiasedRussianRoulette`: paths end at random instead of at the
    /// depth limit.
    pub roulette: Roulette,
    /// `SampleOneLight` (Tessera's own flag, not in the course format): next-event estimation
    /// samples one light a vertex, chosen by its power ([`crate::lights::choice::LightChoice`]), and
    /// divides its light by the choice's probability, instead of sampling every light. The
    /// same image in expectation for a fraction of the shadow rays in scenes of several lights;
    /// more noise per sample where the lights' shares of a point's light differ from their
    /// shares of the power.
    pub one_light: bool,
    /// `MultipleImportanceSampling` (Tessera's own flag, not in the course format): with
    /// next-event estimation, an object light's light reaches a diffuse or glossy vertex both
    /// through its sampled point and through the bounce ray that hits it, each weighted by the
    /// power heuristic of the two strategies' densities (Veach 1997), instead of through the
    /// sampled point alone. The same image in expectation; less noise where a bounce finds a
    /// light more easily than a sampled point does (large lights near a surface).
    pub mis: bool,
}

/// How a path tracer's paths end (§13.2 step 5).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Roulette {
    /// After `MaxRecursionDepth` bounces.
    #[default]
    Off,
    /// `RussianRoulette`: the course renderer's roulette, which its official images show (their
    /// pixels are sums of exactly its quanta). At every vertex after the emission and the
    /// lights sampled there are gathered, the path's potential `q` is the largest channel of
    /// the product of the BRDF values `f` (without `cos θ / pdf`) of the vertices before it,
    /// capped at 1 (so 1 at the first vertex). With probability `1 − q` the path ends there
    /// keeping that vertex's light undivided; otherwise the throughput, that light included, is
    /// divided by `q`. It is biased upwards (the light of a vertex where a path ends counts
    /// `1 + (1 − q)` times on average): the course's roulette images are 1.3-1.5x brighter than
    /// the converged image.
    Course,
    /// `UnbiasedRussianRoulette` (Tessera's own flag, not in the course format): after each
    /// bounce the path survives with probability `q` = the throughput's largest channel capped
    /// at 1, and the throughput is divided by `q`. Same expectation as no roulette at an
    /// unlimited depth.
    Unbiased,
}

/// One `<Tonemap>` of a camera (§12.2).
#[derive(Clone, Debug, PartialEq)]
pub struct TonemapRec {
    pub loc: Loc,
    /// `<TMO>`: Photographic (default), or the 2025 Filmic / ACES.
    pub operator: crate::tonemap::params::Operator,
    /// `TMOOptions`, `Saturation`, `Gamma`: used by every operator.
    pub params: crate::tonemap::params::Photographic,
    /// [JSON 2025] the PNG's name suffix replacing `.exr` (e.g. `_phot.png`); `None`: `.png`.
    pub extension: Option<String>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LensRec {
    pub focus_distance: f64,
    pub aperture_size: f64,
}

#[derive(Clone, Debug, PartialEq)]
pub struct PointLightRec {
    pub id: String,
    pub loc: Loc,
    pub position: Vec3,
    pub intensity: Vec3,
    /// `Transformations` (2025, §10.4), applied by the build step to the position.
    pub transforms: Vec<TransformRef>,
}

/// A square emitter of side `size` centred at `position`, perpendicular to `normal` (HW3).
#[derive(Clone, Debug, PartialEq)]
pub struct AreaLightRec {
    pub id: String,
    pub loc: Loc,
    pub position: Vec3,
    pub normal: Vec3,
    pub size: f64,
    pub radiance: Vec3,
    /// `Transformations` (2025, §10.4), applied by the build step to the position as a point and
    /// to the normal as a normal; `size` stays as written.
    pub transforms: Vec<TransformRef>,
}

/// Light arriving from one direction everywhere (HW5, §5.4): no falloff, shadow rays to infinity.
#[derive(Clone, Debug, PartialEq)]
pub struct DirectionalLightRec {
    pub id: String,
    pub loc: Loc,
    /// The direction the light travels in (not normalised; never zero).
    pub direction: Vec3,
    pub radiance: Vec3,
    /// `Transformations` (2025, §10.4), applied by the build step to the direction.
    pub transforms: Vec<TransformRef>,
}

/// A point light limited to a cone with a smooth edge (HW5, §5.5).
#[derive(Clone, Debug, PartialEq)]
pub struct SpotLightRec {
    pub id: String,
    pub loc: Loc,
    pub position: Vec3,
    /// The cone's axis (not normalised; never zero).
    pub direction: Vec3,
    pub intensity: Vec3,
    /// Full apex angles in degrees (the cone is symmetric, so half of each is used):
    /// `0 <= falloff_angle <= coverage_angle`, `0 < coverage_angle < 360` (the parser checks).
    pub coverage_angle: f64,
    pub falloff_angle: f64,
    /// `Transformations` (2025, §10.4), applied by the build step to the position as a point and
    /// to the direction as a direction.
    pub transforms: Vec<TransformRef>,
}

/// How an environment map's image is laid out (§5.6).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum EnvMapping {
    /// Latitude-longitude (equirectangular) panorama, `v = 0` at +Y.
    #[default]
    LatLong,
    /// Debevec's angular light probe.
    Probe,
}

/// How the environment light picks its one direction per shading event.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EnvSampler {
    /// The course's estimator: uniform on the hemisphere around the normal, pdf 1/(2π).
    Uniform,
    /// Cosine-weighted on the hemisphere, pdf cos θ/π (a 2025 option).
    Cosine,
    /// By the map's luminance over the whole sphere (Tessera's option).
    Importance,
}

/// An environment light (`SphericalDirectionalLight`, HW5, §5.6).
#[derive(Clone, Debug, PartialEq)]
pub struct EnvLightRec {
    pub id: String,
    pub loc: Loc,
    /// The `<Image>` id holding the HDR map (2019 `EnvMapName` files get a generated image).
    pub image: String,
    pub mapping: EnvMapping,
    /// `None`: the renderer's default (uniform, unless the command line says otherwise).
    pub sampler: Option<EnvSampler>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MaterialKind {
    /// No `type`: Blinn-Phong only (untyped MirrorReflectance is ignored in 2020+ files).
    Plain,
    Mirror,
    Conductor,
    Dielectric,
}

#[derive(Clone, Debug, PartialEq)]
pub struct MaterialRec {
    pub id: String,
    pub loc: Loc,
    pub kind: MaterialKind,
    pub ambient: Vec3,
    pub diffuse: Vec3,
    pub specular: Vec3,
    pub mirror: Vec3,
    pub phong_exponent: f64,
    pub refraction_index: f64,
    pub absorption_index: f64,
    pub absorption_coefficient: Vec3,
    pub roughness: f64,
    /// `degamma="true"`: reflectances are display-referred (applied at build time).
    pub degamma: bool,
    /// The `BRDF` attribute: the id of a `<BRDFs>` entry (§7); `None` is the classic shading.
    pub brdf: Option<String>,
}

impl MaterialRec {
    /// A material with the format's defaults (§6.1).
    pub fn new(id: impl Into<String>, loc: Loc) -> Self {
        MaterialRec {
            id: id.into(),
            loc,
            kind: MaterialKind::Plain,
            ambient: [0.0; 3],
            diffuse: [0.0; 3],
            specular: [0.0; 3],
            mirror: [0.0; 3],
            phong_exponent: 1.0,
            refraction_index: 1.0,
            absorption_index: 0.0,
            absorption_coefficient: [0.0; 3],
            roughness: 0.0,
            degamma: false,
            brdf: None,
        }
    }
}

/// An image file named by `<Image id="k">path</Image>` (or by a 2019 `<Texture>`).
/// The reflectance models of `<BRDFs>` (§7).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BrdfKind {
    OriginalPhong,
    ModifiedPhong,
    OriginalBlinnPhong,
    ModifiedBlinnPhong,
    TorranceSparrow,
}

#[derive(Clone, Debug, PartialEq)]
pub struct BrdfRec {
    pub id: String,
    pub loc: Loc,
    pub kind: BrdfKind,
    /// `<Exponent>`: replaces the material's PhongExponent.
    pub exponent: f64,
    /// `normalized="true"` (Modified variants only).
    pub normalized: bool,
    /// `kdfresnel="true"` (TorranceSparrow only): the diffuse term is scaled by `1 − F`.
    pub kd_fresnel: bool,
    /// The 2019 `<RefractiveIndex>` of a TorranceSparrow BRDF (Schlick's Fresnel), if given.
    pub refractive_index: Option<f64>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct ImageRec {
    pub id: String,
    pub loc: Loc,
    /// As written in the scene, relative to the scene file's directory.
    pub path: String,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interpolation {
    Nearest,
    Bilinear,
    /// 2025 scenes; rendered as bilinear until mip-mapping exists.
    Trilinear,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NoiseConversion {
    /// `(n + 1) / 2`
    Linear,
    /// `|n|`
    AbsVal,
}

/// How a texture map changes the surface it is on (scene-format.md §11.6).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DecalMode {
    ReplaceKd,
    BlendKd,
    ReplaceKs,
    ReplaceAll,
    ReplaceNormal,
    BumpNormal,
    ReplaceBackground,
}

#[derive(Clone, Debug, PartialEq)]
pub enum TextureSource {
    /// `type="image"`: `ImageId`, `Interpolation` (default bilinear), `Normalizer` (default 255);
    /// `clamp`: the 2019 `<Appearance>clamp` (clamp-to-edge addressing instead of repeat).
    Image { image: String, interpolation: Interpolation, normalizer: f64, clamp: bool },
    /// `type="perlin"`: `NoiseConversion` (default linear), `NoiseScale` (default 1),
    /// `NumOctaves` (default 1; a fractal sum, see [`crate::texture::maps::fractal_noise`]).
    Perlin { conversion: NoiseConversion, scale: f64, octaves: u32 },
    /// `type="checkerboard"`: colours used as they are, `Scale`, `Offset`; `dimension3` false
    /// (2019 `<Dimension3>false`) makes it a 2-D checkerboard in the texture coordinates.
    Checkerboard { black: Vec3, white: Vec3, scale: f64, offset: f64, dimension3: bool },
}

#[derive(Clone, Debug, PartialEq)]
pub struct TextureMapRec {
    pub id: String,
    pub loc: Loc,
    pub source: TextureSource,
    pub decal: DecalMode,
    /// `BumpFactor`, default 1.
    pub bump_factor: f64,
    /// `degamma="true"`: texel values are linearised after normalisation.
    pub degamma: bool,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TransformOp {
    Translation(Vec3),
    Scaling(Vec3),
    /// Angle in degrees about an axis through the origin (right-hand rule).
    Rotation {
        degrees: f64,
        axis: Vec3,
    },
    /// 16 numbers, row-major.
    Composite([f64; 16]),
}

impl TransformOp {
    /// The letter used in reference strings (`t1 s2 r1 c1`).
    pub fn letter(&self) -> char {
        match self {
            TransformOp::Translation(_) => 't',
            TransformOp::Scaling(_) => 's',
            TransformOp::Rotation { .. } => 'r',
            TransformOp::Composite(_) => 'c',
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct TransformRec {
    pub id: String,
    pub loc: Loc,
    pub op: TransformOp,
}

/// A reference like `r1` inside a `Transformations` string: kind letter and id.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TransformRef {
    pub letter: char,
    pub id: String,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ShadingMode {
    Flat,
    Smooth,
}

/// Where a mesh's triangles come from.
#[derive(Clone, Debug, PartialEq)]
pub enum FacesRec {
    /// Inline triples of vertex ids as written; the real id is `index + vertex_offset` (1-based
    /// into [`SceneRecords::vertices`]). The texture-coordinate id is `index + texture_offset`,
    /// or the vertex id when `texture_offset` is absent (§8.4).
    Inline { indices: Vec<i64>, vertex_offset: i64, texture_offset: Option<i64> },
    /// `plyFile="..."`, as written in the scene (resolved against the scene's directory at build time).
    Ply { path: String },
    /// 2019 `binaryFile="..."` (§8.4): little-endian `int32 T`, then `T×3 int32` vertex ids,
    /// read at build time; they then count like inline ids, offsets included.
    Binary { path: String, vertex_offset: i64, texture_offset: Option<i64> },
}

/// A 2019 `binaryFile` of vertex or texture-coordinate data: little-endian `int32 N`, then
/// `N` records of 3 (vertices) or 2 (uv) `float32`.
#[derive(Clone, Debug, PartialEq)]
pub struct BinaryFileRec {
    pub path: String,
    pub loc: Loc,
}

#[derive(Clone, Debug, PartialEq)]
pub struct MeshRec {
    pub id: String,
    pub loc: Loc,
    pub material: String,
    pub faces: FacesRec,
    /// Location of the `<Faces>` element, for errors about indices or the PLY file.
    pub faces_loc: Loc,
    pub shading: ShadingMode,
    /// Applied left to right: the first reference is applied first.
    pub transforms: Vec<TransformRef>,
    /// `MotionBlur`: world-space translation over the exposure (time 0 to 1).
    pub motion_blur: Option<Vec3>,
    /// `Textures`: ids of texture maps, as written (at most one colour map and one normal map).
    pub textures: Vec<String>,
    /// `Some` for a `<LightMesh>` (§9.6): the radiance its front side emits.
    pub radiance: Option<Vec3>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct TriangleRec {
    pub id: String,
    pub loc: Loc,
    pub material: String,
    /// 1-based vertex ids.
    pub indices: [i64; 3],
    pub transforms: Vec<TransformRef>,
    pub textures: Vec<String>,
    /// `MotionBlur`: world-space translation over the exposure, as for meshes.
    pub motion_blur: Option<Vec3>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct SphereRec {
    pub id: String,
    pub loc: Loc,
    pub material: String,
    /// 1-based vertex id of the centre.
    pub center: i64,
    pub radius: f64,
    pub transforms: Vec<TransformRef>,
    /// `MotionBlur` (2019 dialect on spheres).
    pub motion_blur: Option<Vec3>,
    pub textures: Vec<String>,
    /// `Some` for a `<LightSphere>` (§9.7): the radiance its outside emits.
    pub radiance: Option<Vec3>,
}

/// An infinite plane `{x : (x − P)·N = 0}` (2025, §9.8).
#[derive(Clone, Debug, PartialEq)]
pub struct PlaneRec {
    pub id: String,
    pub loc: Loc,
    pub material: String,
    /// 1-based vertex id of a point on the plane.
    pub point: i64,
    /// The plane's normal (not normalised; never zero). Which side it points to only matters
    /// for dielectrics, as for the other shapes.
    pub normal: Vec3,
    pub transforms: Vec<TransformRef>,
    pub motion_blur: Option<Vec3>,
    pub textures: Vec<String>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct InstanceRec {
    pub id: String,
    pub loc: Loc,
    pub base_mesh: String,
    /// `resetTransform="true"`: only the instance's own transformations apply.
    pub reset_transform: bool,
    /// Overrides the base mesh's material when given.
    pub material: Option<String>,
    pub transforms: Vec<TransformRef>,
    /// `shadingMode` on the instance (repeats the base mesh's in the course files).
    pub shading: Option<ShadingMode>,
    /// The instance's own `MotionBlur`; it does not inherit its base's (§9.4).
    pub motion_blur: Option<Vec3>,
    /// `Textures` on the instance: they replace its base's (empty: the base's are kept).
    pub textures: Vec<String>,
}
