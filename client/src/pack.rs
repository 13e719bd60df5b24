//! A scene file and exactly the files it uses, as one bundle for the farm.
//!
//! There is no second scene parser here: the scene is loaded with the library's own parser and
//! builder (as `tessera-worker render` loads it), through a [`RecordingResolver`] around the
//! CLI's [`FsResolver`] (the corpus' path fallbacks included), so the files packed are exactly
//! the ones the renderer reads, and a missing or broken asset is the library's `SceneError`
//! (file, line, element) before anything goes on the network.
//!
//! Each file is packed where the server's resolver ([`tessera::assets::MemResolver`]) looks for
//! the path as the scene writes it first ([`bundle_path_for`]), so the farm reads the same bytes
//! the CLI read, even when the CLI found them through a fallback. A scene that climbs out of its
//! folder (`../models/x.ply`) is put in as many folders as it climbs, named as on disk.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Component, Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use tessera::assets::{FsResolver, RecordingResolver, bundle_path_for};
use tessera::camera::Camera;
use tessera::scene::build::build_scene;
use tessera::scene::load::parse_scene;

/// One file of a bundle and where it came from.
#[derive(Clone, Debug, PartialEq)]
pub struct Packed {
    pub bytes: Arc<Vec<u8>>,
    /// The file on disk.
    pub source: PathBuf,
    /// How the scene names it (`None` for the scene file itself).
    pub requested: Option<String>,
}

/// A scene packed for submission.
#[derive(Debug)]
pub struct Bundle {
    /// The scene file's path inside the bundle.
    pub scene_path: String,
    /// Every file by its path inside the bundle (the scene file too).
    pub files: BTreeMap<String, Packed>,
    /// The scene's cameras as the library builds them.
    pub cameras: Vec<Camera>,
    /// The parser's and builder's warnings.
    pub warnings: Vec<String>,
}

impl Bundle {
    /// Bytes of every file, unpacked.
    pub fn total_bytes(&self) -> u64 {
        self.files.values().map(|f| f.bytes.len() as u64).sum()
    }

    /// The bundle as a gzip-compressed tar: entries sorted, mode 0644, mtime 0 (the same files
    /// give the same bytes).
    pub fn tar_gz(&self) -> Result<Vec<u8>> {
        let gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        let mut builder = tar::Builder::new(gz);
        for (path, f) in &self.files {
            let mut header = tar::Header::new_gnu();
            header.set_size(f.bytes.len() as u64);
            header.set_mode(0o644);
            header.set_mtime(0);
            header.set_entry_type(tar::EntryType::Regular);
            builder
                .append_data(&mut header, path, f.bytes.as_slice())
                .with_context(|| format!("cannot pack {path}"))?;
        }
        let mut gz = builder.into_inner().context("cannot finish the bundle")?;
        gz.flush().context("cannot finish the bundle")?;
        gz.finish().context("cannot finish the bundle")
    }
}

/// How many folders above its own the scene's path `rel` climbs (`../../x` climbs 2,
/// `a/../../x` climbs 1).
fn climb(rel: &str) -> usize {
    let unified = rel.replace('\\', "/");
    if unified.starts_with('/') {
        return 0;
    }
    let mut depth: isize = 0;
    let mut lowest: isize = 0;
    for part in unified.split('/') {
        match part {
            "" | "." => {}
            ".." => {
                depth -= 1;
                lowest = lowest.min(depth);
            }
            _ => depth += 1,
        }
    }
    (-lowest) as usize
}

/// The folder (inside the bundle) to put the scene file in so that its paths can climb
/// `levels` folders: the last `levels` folder names above it on disk, or `up1`, `up2`, ... where
/// the disk has fewer.
fn scene_base(scene: &Path, levels: usize) -> String {
    if levels == 0 {
        return String::new();
    }
    let dir = scene.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let dir = std::fs::canonicalize(dir).unwrap_or_else(|_| dir.to_path_buf());
    let names: Vec<String> = dir
        .components()
        .filter_map(|c| match c {
            Component::Normal(n) => Some(n.to_string_lossy().into_owned()),
            _ => None,
        })
        .collect();
    let mut base: Vec<String> = names.iter().rev().take(levels).rev().cloned().collect();
    for i in base.len()..levels {
        base.insert(0, format!("up{}", i + 1));
    }
    base.join("/")
}

/// Loads the scene at `scene` as the CLI does and packs it with every file it read.
pub fn pack(scene: &Path) -> Result<Bundle> {
    let bytes = std::fs::read(scene)
        .map_err(|e| anyhow::anyhow!("{}: cannot read the scene file: {e}", scene.display()))?;
    let text = std::str::from_utf8(&bytes).map_err(|e| {
        anyhow::anyhow!(
            "{}: the scene file is not UTF-8 text (byte {}); save it as UTF-8",
            scene.display(),
            e.valid_up_to()
        )
    })?;
    let records = parse_scene(text, scene)?;
    let resolver = RecordingResolver::new(FsResolver::for_scene(scene));
    let built = build_scene(&records, &resolver)?;
    let served = resolver.served();

    let levels = served.iter().map(|s| climb(&s.requested)).max().unwrap_or(0);
    let base = scene_base(scene, levels);
    let file_name = scene
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .ok_or_else(|| anyhow::anyhow!("{}: not a file name", scene.display()))?;
    let scene_path = if base.is_empty() { file_name } else { format!("{base}/{file_name}") };

    let mut files = BTreeMap::new();
    files.insert(
        scene_path.clone(),
        Packed { bytes: Arc::new(bytes.clone()), source: scene.to_path_buf(), requested: None },
    );
    for s in served {
        let Some(at) = bundle_path_for(&base, &s.requested) else {
            bail!(
                "{}: the asset path {:?} names no file inside a bundle; name the file by its path relative to the scene file",
                scene.display(),
                s.requested
            );
        };
        match files.get(&at) {
            Some(Packed { bytes, .. }) if *bytes == s.bytes => {}
            Some(other) => {
                let what = match &other.requested {
                    Some(r) => format!("the asset {r:?} ({})", other.source.display()),
                    None => "the scene file".to_string(),
                };
                bail!(
                    "{}: the asset {:?} ({}) and {what} would both be {at} in the bundle, with different contents; \
                     rename one of them",
                    scene.display(),
                    s.requested,
                    s.found_at.display()
                );
            }
            None => {
                files.insert(at, Packed { bytes: s.bytes, source: s.found_at, requested: Some(s.requested) });
            }
        }
    }
    Ok(Bundle {
        scene_path,
        files,
        cameras: built.cameras,
        warnings: built.warnings.iter().map(ToString::to_string).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_testkit::TempDir;

    #[test]
    fn climbing() {
        assert_eq!(climb("ply/x.ply"), 0);
        assert_eq!(climb("../ply/x.ply"), 1);
        assert_eq!(climb("..\\..\\x.ply"), 2);
        assert_eq!(climb("a/../../x.ply"), 1);
        assert_eq!(climb("a/b/../../x.ply"), 0);
        assert_eq!(climb("/abs/x.ply"), 0);
    }

    const PLY: &str = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 -2\n1 0 -2\n0 1 -2\n3 0 1 2\n";

    /// A scene in `dir/xml/` naming a PLY beside it, one a folder up, one through a rewritten
    /// path (found by the fallback) and an image, with a file it does not use next to them.
    fn scene_with_assets(dir: &Path) -> PathBuf {
        for d in ["xml/ply", "models", "xml/textures"] {
            std::fs::create_dir_all(dir.join(d)).unwrap();
        }
        std::fs::write(dir.join("xml/ply/a.ply"), PLY).unwrap();
        std::fs::write(dir.join("models/b.ply"), PLY.replace("-2", "-3")).unwrap();
        std::fs::write(dir.join("xml/ply/c.ply"), PLY.replace("-2", "-4")).unwrap();
        std::fs::write(dir.join("xml/ply/unused.ply"), PLY).unwrap();
        let mut png = Vec::new();
        let img = image_png_2x2();
        png.extend_from_slice(&img);
        std::fs::write(dir.join("xml/textures/t.png"), &png).unwrap();
        let scene = dir.join("xml/s.xml");
        std::fs::write(
            &scene,
            scene_xml(
                "s.png",
                r#"<Textures><Images><Image id="1">textures/t.png</Image></Images>
<TextureMap id="1" type="image"><ImageId>1</ImageId><DecalMode>replace_kd</DecalMode></TextureMap></Textures>
<Objects>
<Mesh id="1"><Material>1</Material><Textures>1</Textures><Faces plyFile="ply/a.ply"/></Mesh>
<Mesh id="2"><Material>1</Material><Faces plyFile="../models/b.ply"/></Mesh>
<Mesh id="3"><Material>1</Material><Faces plyFile="assets/ply/c.ply"/></Mesh>
<Mesh id="4"><Material>1</Material><Faces plyFile="ply/a.ply"/></Mesh>
</Objects>"#,
            ),
        )
        .unwrap();
        scene
    }

    /// A scene file of one 4x4 camera writing `image` and one white material, then `body` (its
    /// textures and objects).
    fn scene_xml(image: &str, body: &str) -> String {
        format!(
            r#"<Scene><Cameras><Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
<NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>4 4</ImageResolution>
<ImageName>{image}</ImageName></Camera></Cameras>
<Materials><Material id="1"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
{body}</Scene>"#
        )
    }

    /// A 2x2 PNG, encoded by the library.
    fn image_png_2x2() -> Vec<u8> {
        tessera::hdr_io::encode_png_rgb8(2, 2, &[255, 0, 0, 0, 255, 0, 0, 0, 255, 9, 9, 9]).unwrap()
    }

    #[test]
    fn packs_exactly_the_files_the_renderer_reads_where_the_farm_finds_them() {
        let dir = TempDir::new("client-pack");
        let scene = scene_with_assets(&dir);
        let bundle = pack(&scene).unwrap();
        // The scene climbs one folder: it goes into a folder named as on disk.
        assert_eq!(bundle.scene_path, "xml/s.xml");
        let paths: Vec<&str> = bundle.files.keys().map(String::as_str).collect();
        assert_eq!(
            paths,
            ["models/b.ply", "xml/assets/ply/c.ply", "xml/ply/a.ply", "xml/s.xml", "xml/textures/t.png"]
        );
        assert_eq!(bundle.files["xml/assets/ply/c.ply"].source, dir.join("xml/ply/c.ply"));
        assert_eq!(bundle.files["models/b.ply"].requested.as_deref(), Some("../models/b.ply"));
        for (path, f) in &bundle.files {
            assert_eq!(f.bytes.as_slice(), std::fs::read(&f.source).unwrap(), "{path}");
        }

        // The farm's own path from a bundle to a scene reads it back, with the same assets.
        let gz = bundle.tar_gz().unwrap();
        let mut raw = Vec::new();
        std::io::Read::read_to_end(&mut flate2::read::GzDecoder::new(gz.as_slice()), &mut raw).unwrap();
        let files = tessera::bundle::read_tar(&raw).unwrap();
        assert_eq!(files.len(), 5);
        let farm = tessera::bundle::load_bundle_scene(
            files.clone(),
            &bundle.scene_path,
            tessera::scene::load::LoadOptions::default(),
        )
        .unwrap();
        let cli = tessera::scene::load::load_scene_file(&scene).unwrap();
        assert_eq!(farm.stats.triangles, cli.stats.triangles);
        assert_eq!(farm.stats.triangles, 4);
        // The same bytes for the same files, and the same tar for the same scene.
        assert_eq!(bundle.tar_gz().unwrap(), pack(&scene).unwrap().tar_gz().unwrap());
    }

    #[test]
    fn a_missing_asset_names_the_file_and_the_element() {
        let dir = TempDir::new("client-pack-missing");
        let scene = scene_with_assets(&dir);
        std::fs::remove_file(dir.join("models/b.ply")).unwrap();
        let e = pack(&scene).unwrap_err().to_string();
        assert!(e.contains("s.xml:9: <Mesh id=\"2\"> / <Faces>"), "{e}");
        assert!(e.contains("models/b.ply"), "{e}");
        std::fs::remove_file(dir.join("xml/textures/t.png")).unwrap();
        std::fs::write(dir.join("models/b.ply"), PLY).unwrap();
        let e = pack(&scene).unwrap_err().to_string();
        assert!(e.contains("<Image id=\"1\">") && e.contains("textures/t.png"), "{e}");
    }

    #[cfg(unix)]
    #[test]
    fn two_assets_on_one_bundle_path_are_refused() {
        // "ply/../x.ply" is found as ply/../x.ply on disk = x.ply beside the scene, but a
        // scene in a folder whose "ply" is a link elsewhere could differ: here two spellings of
        // the same place with different bytes are simulated by a link.
        let dir = TempDir::new("client-pack-clash");
        std::fs::create_dir_all(dir.join("s")).unwrap();
        std::fs::create_dir_all(dir.join("elsewhere/deep")).unwrap();
        std::fs::write(dir.join("s/x.ply"), PLY).unwrap();
        std::fs::write(dir.join("elsewhere/x.ply"), PLY.replace("-2", "-5")).unwrap();
        std::os::unix::fs::symlink(dir.join("elsewhere/deep"), dir.join("s/ply")).unwrap();
        let scene = dir.join("s/a.xml");
        std::fs::write(
            &scene,
            scene_xml(
                "a.png",
                r#"<Objects><Mesh id="1"><Material>1</Material><Faces plyFile="x.ply"/></Mesh>
<Mesh id="2"><Material>1</Material><Faces plyFile="ply/../x.ply"/></Mesh></Objects>"#,
            ),
        )
        .unwrap();
        let e = pack(&scene).unwrap_err().to_string();
        assert!(e.contains("would both be x.ply in the bundle, with different contents"), "{e}");
    }
}
