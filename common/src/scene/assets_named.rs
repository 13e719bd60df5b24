//! The files a parsed scene names, listed without building it: what a client needs to send
//! with a scene, found by reading its records only (no PLY parsed, no image decoded).
//!
//! [`SceneRecords::asset_paths`] lists exactly the paths [`super::build::build_scene`] asks its
//! [`crate::assets::AssetResolver`] for, in the order the build's steps ask for them (2019
//! binary vertex, texture-coordinate and face files; the images of texture maps and environment
//! lights; PLY files), each path once: `tests/asset_lister.rs` checks it against a
//! [`crate::assets::RecordingResolver`] over a full load of every scene of the course corpus.

use std::collections::HashMap;

use super::records::{FacesRec, ImageRec, SceneRecords, TextureSource};
use crate::error::Loc;

/// What kind of file a scene names.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AssetKind {
    /// A 2019 `binaryFile` of vertices (`<VertexData binaryFile=...>`).
    BinaryVertices,
    /// A 2019 `binaryFile` of texture coordinates.
    BinaryTexCoords,
    /// A 2019 `binaryFile` of a mesh's faces.
    BinaryFaces,
    /// An image of a texture map or an environment light.
    Image,
    /// A mesh's `plyFile`.
    Ply,
}

impl AssetKind {
    /// A few words for messages.
    pub fn describe(self) -> &'static str {
        match self {
            AssetKind::BinaryVertices => "binary vertex file",
            AssetKind::BinaryTexCoords => "binary texture-coordinate file",
            AssetKind::BinaryFaces => "binary face file",
            AssetKind::Image => "image",
            AssetKind::Ply => "PLY file",
        }
    }
}

/// One file a scene names: the path as written (relative to the scene file's folder, resolved
/// like [`crate::assets::FsResolver`] does), what it is, and the element that names it first.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedAsset {
    pub path: String,
    pub kind: AssetKind,
    pub loc: Loc,
}

impl SceneRecords {
    /// Every asset path the scene's build reads, in the build's order, each once (see the
    /// module's documentation). An image is listed only when a texture map or an environment
    /// light uses it, as the build reads only those; an `ImageId` naming no `<Image>` lists
    /// nothing (the build refuses it with its own message).
    pub fn asset_paths(&self) -> Vec<NamedAsset> {
        let mut out: Vec<NamedAsset> = Vec::new();
        let mut add = |path: &str, kind: AssetKind, loc: &Loc| {
            if !out.iter().any(|a| a.path == path) {
                out.push(NamedAsset { path: path.to_string(), kind, loc: loc.clone() });
            }
        };
        // Step 0 (legacy_data): binary vertex and texture-coordinate files, then faces.
        if let Some(f) = &self.vertex_file {
            add(&f.path, AssetKind::BinaryVertices, &f.loc);
        }
        if let Some(f) = &self.tex_coord_file {
            add(&f.path, AssetKind::BinaryTexCoords, &f.loc);
        }
        for m in &self.meshes {
            if let FacesRec::Binary { path, .. } = &m.faces {
                add(path, AssetKind::BinaryFaces, &m.faces_loc);
            }
        }
        // Step 4 (textures): the images of texture maps, then of environment lights; an id
        // defined twice means its first definition.
        let mut images: HashMap<&str, &ImageRec> = HashMap::new();
        for img in &self.images {
            images.entry(img.id.as_str()).or_insert(img);
        }
        let map_images = self.texture_maps.iter().filter_map(|m| match &m.source {
            TextureSource::Image { image, .. } => Some(image.as_str()),
            _ => None,
        });
        let env_images = self.env_lights.iter().map(|l| l.image.as_str());
        for id in map_images.chain(env_images) {
            if let Some(img) = images.get(id) {
                add(&img.path, AssetKind::Image, &img.loc);
            }
        }
        // Step 5 (meshes): PLY files.
        for m in &self.meshes {
            if let FacesRec::Ply { path } = &m.faces {
                add(path, AssetKind::Ply, &m.faces_loc);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;
    use crate::scene::load::parse_scene;

    #[test]
    fn lists_each_named_file_once_in_build_order() {
        let xml = r#"<Scene>
<Cameras><Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
<NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>4 4</ImageResolution>
<ImageName>a.png</ImageName></Camera></Cameras>
<Materials><Material id="1"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
<Textures><Images><Image id="1">tex/used.png</Image><Image id="2">tex/unused.png</Image><Image id="1">tex/second.png</Image></Images>
<TextureMap id="1" type="image"><ImageId>1</ImageId><DecalMode>replace_kd</DecalMode></TextureMap>
<TextureMap id="2" type="image"><ImageId>9</ImageId><DecalMode>replace_kd</DecalMode></TextureMap></Textures>
<Objects>
<Mesh id="1"><Material>1</Material><Faces plyFile="ply/b.ply"/></Mesh>
<Mesh id="2"><Material>1</Material><Faces plyFile="ply/a.ply"/></Mesh>
<Mesh id="3"><Material>1</Material><Faces plyFile="ply/b.ply"/></Mesh>
</Objects></Scene>"#;
        let rec = parse_scene(xml, Path::new("s.xml")).unwrap();
        let assets = rec.asset_paths();
        let listed: Vec<(&str, AssetKind)> = assets.iter().map(|a| (a.path.as_str(), a.kind)).collect();
        assert_eq!(
            listed,
            [
                ("tex/used.png", AssetKind::Image),
                ("ply/b.ply", AssetKind::Ply),
                ("ply/a.ply", AssetKind::Ply)
            ]
        );
        assert_eq!(assets[1].loc.line, Some(10));
        assert_eq!(assets[1].loc.element.as_deref(), Some("Mesh id=\"1\"> / <Faces"));
    }
}
