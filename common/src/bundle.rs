//! Job bundles: a scene file and its assets as one tar archive, and the one path from a
//! bundle's bytes to a scene.
//!
//! A bundle is a tar of regular files named by normalised relative paths (`scene.xml`,
//! `ply/head.ply`). [`for_each_tar_file`] is the one tar reader: [`read_tar`] reads a whole
//! bundle with it, and the server's upload unpacker reads uploaded tars with it under its caps.
//! [`load_bundle_scene`] parses and builds the scene at a path of the bundle with its assets from
//! the bundle ([`MemResolver`]); the server validates uploads with it and the worker renders with
//! it. [`bundle_cameras`] is the same path stopped after the cameras (the server's camera lookup:
//! merging and previews need no meshes). Bytes in, scene out: nothing here touches the file
//! system.

use std::collections::HashMap;
use std::io::Read;
use std::path::Path;
use std::sync::Arc;

use crate::assets::{AssetResolver, MemResolver, normalize_bundle_path};
use crate::camera::Camera;
use crate::error::SceneError;
use crate::scene::Scene;
use crate::scene::build::{build_cameras, build_scene, build_scene_cached};
use crate::scene::cache::MeshCache;
use crate::scene::load::{LoadOptions, parse_scene};
use crate::scene::records::SceneRecords;

/// A bundle's files by normalised path, shared (what a [`MemResolver`] reads).
pub type BundleFiles = HashMap<String, Arc<Vec<u8>>>;

/// Why a tar archive cannot be read; the message says what is wrong.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct TarError(pub String);

/// Reads the regular files of the tar archive `source` in order: for each one, `file` gets its
/// path as stored (not normalised), its size as its header claims and a reader of its bytes.
/// Directories and pax extension headers are skipped; any other entry (a link, a device) is an
/// error, as is a damaged archive. `what` names the archive in messages (`tar`, `.tar.gz`).
pub fn for_each_tar_file<E: From<TarError>>(
    source: impl Read,
    what: &str,
    mut file: impl FnMut(&str, u64, &mut dyn Read) -> Result<(), E>,
) -> Result<(), E> {
    let mut archive = tar::Archive::new(source);
    let entries =
        archive.entries().map_err(|e| TarError(format!("the {what} bundle cannot be read: {e}")))?;
    for entry in entries {
        let mut entry = entry.map_err(|e| TarError(format!("the {what} bundle is damaged: {e}")))?;
        let kind = entry.header().entry_type();
        if kind.is_dir() || kind.is_pax_global_extensions() || kind.is_pax_local_extensions() {
            continue;
        }
        let path = entry.path_bytes().into_owned();
        let path = String::from_utf8_lossy(&path).into_owned();
        if !kind.is_file() {
            return Err(TarError(format!(
                "the {what} bundle holds \"{path}\", which is not a regular file (links are not accepted)"
            ))
            .into());
        }
        let size = entry.size();
        file(&path, size, &mut entry)?;
    }
    Ok(())
}

/// The files of a bundle's tar: every path normalised ([`normalize_bundle_path`]); a path that
/// leaves the bundle, a path given twice or an entry that is not a regular file is an error.
pub fn read_tar(bytes: &[u8]) -> Result<BundleFiles, TarError> {
    let mut files = BundleFiles::new();
    for_each_tar_file(bytes, "tar", |path, _, data| {
        let norm = normalize_bundle_path(path)
            .ok_or_else(|| TarError(format!("the path \"{path}\" leaves the bundle")))?;
        if files.contains_key(&norm) {
            return Err(TarError(format!("the file \"{norm}\" is given twice")));
        }
        let mut bytes = Vec::new();
        data.read_to_end(&mut bytes).map_err(|e| TarError(format!("cannot unpack {path}: {e}")))?;
        files.insert(norm, Arc::new(bytes));
        Ok(())
    })?;
    Ok(files)
}

/// Why a bundle's scene cannot be loaded.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum BundleSceneError {
    /// The scene file is not in the bundle, or is not UTF-8 text: nothing was parsed. The error
    /// names the file.
    #[error("{0}")]
    Unreadable(SceneError),
    /// The scene text cannot be parsed or built: file, line and element.
    #[error("{0}")]
    Invalid(SceneError),
    /// The scene uses elements that change the picture but are not implemented, and they were
    /// not allowed ([`LoadOptions::allow_unsupported`]): every one of them, in file order, each
    /// with its file, line and element. Never empty.
    #[error("{}", .0.iter().map(ToString::to_string).collect::<Vec<_>>().join("\n"))]
    Unsupported(Vec<SceneError>),
}

impl BundleSceneError {
    /// The error, or the first unsupported element.
    pub fn scene_error(&self) -> &SceneError {
        match self {
            BundleSceneError::Unreadable(e) | BundleSceneError::Invalid(e) => e,
            BundleSceneError::Unsupported(errors) => &errors[0],
        }
    }
}

/// The scene file `scene_path` of `files`, parsed.
fn parse_bundle_scene(files: &BundleFiles, scene_path: &str) -> Result<SceneRecords, BundleSceneError> {
    let bytes = files.get(scene_path).ok_or_else(|| {
        BundleSceneError::Unreadable(SceneError::file(scene_path, "the bundle has no such file".to_string()))
    })?;
    parse_scene_bytes(bytes, scene_path)
}

/// The scene file `scene_path` whose bytes are `bytes`, parsed.
pub fn parse_scene_bytes(bytes: &[u8], scene_path: &str) -> Result<SceneRecords, BundleSceneError> {
    let unreadable = |message: String| BundleSceneError::Unreadable(SceneError::file(scene_path, message));
    let text = std::str::from_utf8(bytes).map_err(|e| {
        unreadable(format!("the scene file is not UTF-8 text (byte {}); save it as UTF-8", e.valid_up_to()))
    })?;
    parse_scene(text, Path::new(scene_path)).map_err(BundleSceneError::Invalid)
}

/// Parses and builds the scene at `scene_path` (a normalised path of the bundle), with its
/// assets from `files`: the farm's one way from a bundle to a [`Scene`] (its warnings in
/// [`Scene::warnings`]). Unsupported elements are refused as in [`crate::scene::load`] unless
/// `options` allow them: those the parser finds before any asset is read.
pub fn load_bundle_scene(
    files: BundleFiles,
    scene_path: &str,
    options: LoadOptions,
) -> Result<Scene, BundleSceneError> {
    load_bundle_scene_cached(files, scene_path, options, None)
}

/// [`load_bundle_scene`] with meshes and images kept in `cache` across builds (the same scene,
/// bit for bit; [`crate::scene::cache`]).
pub fn load_bundle_scene_cached(
    files: BundleFiles,
    scene_path: &str,
    options: LoadOptions,
    cache: Option<&MeshCache>,
) -> Result<Scene, BundleSceneError> {
    let records = parse_bundle_scene(&files, scene_path)?;
    let resolver = MemResolver::for_scene(files, scene_path);
    build_checked(&records, &resolver, options, cache)
}

/// Parses and builds the scene file `scene_path` (a normalised job path) whose bytes are
/// `bytes`, with its assets from `resolver` (which resolves paths as a [`MemResolver`] for that
/// scene would): [`load_bundle_scene`] for a job whose files are not one in-memory bundle (a
/// worker's manifest of files fetched as needed), with meshes and images kept in `cache`
/// across builds when given.
pub fn load_scene_bytes(
    bytes: &[u8],
    scene_path: &str,
    resolver: &dyn AssetResolver,
    options: LoadOptions,
    cache: Option<&MeshCache>,
) -> Result<Scene, BundleSceneError> {
    let records = parse_scene_bytes(bytes, scene_path)?;
    build_checked(&records, resolver, options, cache)
}

/// Builds parsed `records`, refusing unsupported elements unless `options` allow them (those the
/// parser found before any asset is read, then those the build found).
fn build_checked(
    records: &SceneRecords,
    resolver: &dyn AssetResolver,
    options: LoadOptions,
    cache: Option<&MeshCache>,
) -> Result<Scene, BundleSceneError> {
    options.check(&records.warnings).map_err(BundleSceneError::Unsupported)?;
    let scene = match cache {
        Some(cache) => build_scene_cached(records, resolver, cache),
        None => build_scene(records, resolver),
    }
    .map_err(BundleSceneError::Invalid)?;
    options.check(&scene.warnings).map_err(BundleSceneError::Unsupported)?;
    Ok(scene)
}

/// The cameras of the scene at `scene_path` of `files`, as [`load_bundle_scene`] would build
/// them, without loading any asset or building any geometry.
pub fn bundle_cameras(files: &BundleFiles, scene_path: &str) -> Result<Vec<Camera>, BundleSceneError> {
    let records = parse_bundle_scene(files, scene_path)?;
    build_cameras(&records).map_err(BundleSceneError::Invalid)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tar of `(path, bytes)` entries, each path stored exactly as given (`./`, `..` and all).
    fn tar_of(entries: &[(&str, &[u8])]) -> Vec<u8> {
        let mut builder = tar::Builder::new(Vec::new());
        for (path, data) in entries {
            let mut header = tar::Header::new_gnu();
            header.as_gnu_mut().unwrap().name[..path.len()].copy_from_slice(path.as_bytes());
            header.set_size(data.len() as u64);
            header.set_mode(0o644);
            header.set_entry_type(tar::EntryType::Regular);
            header.set_cksum();
            builder.append(&header, *data).unwrap();
        }
        builder.into_inner().unwrap()
    }

    const SCENE: &str = r#"<Scene><Cameras><Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
<NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>4 3</ImageResolution>
<ImageName>t.png</ImageName></Camera></Cameras><Materials><Material id="1"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
<Objects><Mesh id="1"><Material>1</Material><Faces plyFile="ply/tri.ply"/></Mesh></Objects></Scene>"#;

    const PLY: &str = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\
0 0 -2\n1 0 -2\n0 1 -2\n3 0 1 2\n";

    #[test]
    fn a_bundle_loads_with_its_assets() {
        let tar = tar_of(&[("scenes/a.xml", SCENE.as_bytes()), ("./scenes/ply/tri.ply", PLY.as_bytes())]);
        let files = read_tar(&tar).unwrap();
        let mut names: Vec<_> = files.keys().cloned().collect();
        names.sort();
        assert_eq!(names, ["scenes/a.xml", "scenes/ply/tri.ply"]);
        let cameras = bundle_cameras(&files, "scenes/a.xml").unwrap();
        assert_eq!((cameras.len(), cameras[0].width, cameras[0].height), (1, 4, 3));
        let scene = load_bundle_scene(files, "scenes/a.xml", LoadOptions::STRICT).unwrap();
        assert_eq!(scene.cameras, cameras);
        assert_eq!(scene.stats.triangles, 1);
    }

    #[test]
    fn errors_name_the_file_and_say_whether_anything_was_parsed() {
        let mut files = BundleFiles::new();
        files.insert("s.xml".into(), Arc::new(SCENE.as_bytes().to_vec()));
        files.insert("bad.xml".into(), Arc::new(b"<Scene>\xff</Scene>".to_vec()));
        let Err(e) = load_bundle_scene(files.clone(), "s.xml", LoadOptions::STRICT) else {
            panic!("the PLY is missing")
        };
        assert!(matches!(e, BundleSceneError::Invalid(_)), "{e:?}");
        assert!(e.to_string().contains("ply/tri.ply"), "{e}");
        let e = bundle_cameras(&files, "bad.xml").unwrap_err();
        assert!(matches!(e, BundleSceneError::Unreadable(_)), "{e:?}");
        assert_eq!(e.to_string(), "bad.xml: the scene file is not UTF-8 text (byte 7); save it as UTF-8");
        let e = bundle_cameras(&files, "none.xml").unwrap_err();
        assert_eq!(e.scene_error().file, Path::new("none.xml"));
    }

    #[test]
    fn bad_tars_are_errors() {
        let twice = tar_of(&[("a.xml", b"1"), ("./a.xml", b"2")]);
        assert!(read_tar(&twice).unwrap_err().0.contains("twice"));
        let climbing = tar_of(&[("x/../../a.xml", b"1")]);
        assert!(read_tar(&climbing).unwrap_err().0.contains("leaves the bundle"));
        let mut builder = tar::Builder::new(Vec::new());
        let mut header = tar::Header::new_gnu();
        header.set_entry_type(tar::EntryType::Symlink);
        header.set_size(0);
        builder.append_link(&mut header, "link.xml", "/etc/passwd").unwrap();
        let link = builder.into_inner().unwrap();
        assert!(read_tar(&link).unwrap_err().0.contains("not a regular file"));
        let cut = tar_of(&[("a.xml", &[7u8; 1000])]);
        assert!(read_tar(&cut[..300]).unwrap_err().0.contains("damaged"));
    }
}
