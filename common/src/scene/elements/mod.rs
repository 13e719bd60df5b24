//! The walk of a `<Scene>` tree into scene records: scene-level values, and dispatch to the
//! element rules of each family.
//!
//! `parse_tree` walks a `<Scene>` tree and fills [`SceneRecords`]; it is shared by the XML
//! ([`super::xml`]) and JSON ([`super::json`]) front ends. Each family of elements has its rules
//! (schemas, defaults, warnings and errors) in a file of its own: [`camera`] (cameras and their
//! renderer), [`tonemap`] (a camera's `<Tonemap>`), [`lights`], [`materials`] (materials and
//! BRDFs), [`textures`] (images, texture maps, 2019 textures) and [`geometry`] (vertex data,
//! transformations, objects). Each adds methods to the shared [`Parser`] of [`super::tree`],
//! which also holds what they all read values with.
//!
//! Because the walk looks children up by name, the order of elements inside `<Scene>` (and
//! anywhere else) does not matter. The 2019 legacy rules for materials (scene-format.md §6.1,
//! §6.9) and the 2019 `<Texture>` / `<BackgroundTexture>` elements (translated into 2020 texture
//! maps, §11.11) apply to XML trees only. The `Dialect` of a tree changes how messages name
//! elements (`json_words`) and one default ([`DEFAULT_MAX_RECURSION_DEPTH`]), nothing else.
//!
//! Nothing is resolved here: ids stay strings, PLY files are not opened. Elements we do not know
//! become warnings, elements of the format that are not implemented yet become "not supported
//! yet" warnings marked [`Warning::unsupported`] when leaving them out changes the picture (the
//! loaders refuse those unless allowed), and everything a user can get wrong is a [`SceneError`]
//! naming the file, the line and the element. No input makes this module panic.
//!
//! [`Warning::unsupported`]: crate::error::Warning::unsupported
//! [`SceneError`]: crate::error::SceneError

mod camera;
mod geometry;
mod lights;
mod materials;
mod textures;
mod tonemap;

use std::path::Path;

use super::records::{MAX_RECURSION_DEPTH_LIMIT, SceneRecords};
use super::tree::{BOOLEANS, DEFAULT_MAX_RECURSION_DEPTH, Dialect, Node, Parser, Result, Schema};

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

impl Parser<'_> {
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
                "Cameras" => self.cameras(block)?,
                "Lights" => self.lights(block)?,
                "Materials" => self.materials(block)?,
                "Transformations" => self.transformations(block)?,
                "Objects" => self.objects(block)?,
                "BRDFs" => self.brdfs(block)?,
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
}
