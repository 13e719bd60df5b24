//! Where scene assets (PLY models, texture and environment images) come from.
//!
//! `common` never decides on its own where bytes live: the CLI reads the file system next to the
//! scene ([`FsResolver`]); the server's validation and the farm worker read an uploaded bundle
//! ([`MemResolver`]). Both implement [`AssetResolver`].

use std::io;
use std::path::{Component, Path, PathBuf};

/// Finds the bytes of an asset named by a scene.
pub trait AssetResolver: Sync {
    /// Reads the asset `rel` (as written in the scene, relative to the scene file's directory).
    /// Returns the bytes and the path it was found at (for error messages).
    fn read(&self, rel: &str) -> io::Result<(Vec<u8>, PathBuf)>;

    /// The path to show in messages for an asset that could not be found.
    fn display_path(&self, rel: &str) -> PathBuf;

    /// The SHA-256 of the asset `rel`'s bytes, when the resolver knows it without reading them
    /// (a farm worker's files are named by it). `None` (the default): unknown, and a build
    /// with a [`crate::scene::cache::MeshCache`] reads the bytes and hashes them. It must be
    /// the hash of exactly what [`AssetResolver::read`] would return: the cache serves what it
    /// built from those bytes without reading them.
    fn content_id(&self, _rel: &str) -> Option<[u8; 32]> {
        None
    }

    /// The file of this machine's file system that [`AssetResolver::read`] would read `rel`
    /// from, when assets are such files (`None`, the default: they are not). A
    /// [`crate::scene::cache::MeshCache`] remembers the SHA-256 of such a file with its
    /// `stat` identity, and does not read an unchanged file again to find its cached mesh or
    /// image.
    fn local_file(&self, _rel: &str) -> Option<PathBuf> {
        None
    }
}

/// Resolves assets on the file system relative to the scene file's directory.
///
/// Following scene-format.md §1.3, when the path does not exist as written it tries, in order:
/// relative to the current directory, then with leading components stripped one at a time (so the
/// student copies that rewrote paths to `assets/ply/...` still load).
#[derive(Clone, Debug)]
pub struct FsResolver {
    pub base_dir: PathBuf,
}

impl FsResolver {
    /// A resolver for the scene file at `scene_path`.
    pub fn for_scene(scene_path: &Path) -> Self {
        let base_dir = scene_path.parent().map(Path::to_path_buf).unwrap_or_default();
        FsResolver { base_dir }
    }

    fn candidates(&self, rel: &str) -> Vec<PathBuf> {
        let rel_norm = rel.replace('\\', "/");
        let rel_path = Path::new(&rel_norm);
        let mut out = vec![self.base_dir.join(rel_path)];
        if rel_path.is_relative() {
            out.push(rel_path.to_path_buf());
        }
        let parts: Vec<Component> = rel_path.components().collect();
        for skip in 1..parts.len() {
            let tail: PathBuf = parts[skip..].iter().collect();
            out.push(self.base_dir.join(tail));
        }
        out
    }

    /// Where [`AssetResolver::read`] would read `rel` from: the first of the same candidates,
    /// in the same order, that is a file; `None` when none is. Reads nothing (a client lists a
    /// scene's files this way without loading them).
    pub fn locate(&self, rel: &str) -> Option<PathBuf> {
        self.candidates(rel).into_iter().find(|c| std::fs::metadata(c).is_ok_and(|m| m.is_file()))
    }
}

impl AssetResolver for FsResolver {
    fn read(&self, rel: &str) -> io::Result<(Vec<u8>, PathBuf)> {
        let mut first_err = None;
        for cand in self.candidates(rel) {
            match std::fs::read(&cand) {
                Ok(bytes) => return Ok((bytes, cand)),
                Err(e) => {
                    if first_err.is_none() {
                        first_err = Some(e);
                    }
                }
            }
        }
        Err(first_err.unwrap_or_else(|| io::Error::new(io::ErrorKind::NotFound, "no candidate path")))
    }

    fn display_path(&self, rel: &str) -> PathBuf {
        self.base_dir.join(rel)
    }

    fn local_file(&self, rel: &str) -> Option<PathBuf> {
        self.locate(rel)
    }
}

/// Resolves assets inside an in-memory bundle (an uploaded job): `files` maps normalised
/// relative paths (`ply/head.ply`, `/`-separated, no `.` or `..`) to bytes, and `base` is the
/// scene file's directory inside the bundle ("" for the top). Paths that would leave the bundle
/// are not found. Like [`FsResolver`], a path that is not found as written is retried with its
/// leading components stripped one at a time.
#[derive(Clone, Debug, Default)]
pub struct MemResolver {
    pub files: std::collections::HashMap<String, std::sync::Arc<Vec<u8>>>,
    pub base: String,
}

/// `path` with `.` and `..` resolved and `\` read as `/`; `None` if it is absolute or leaves the
/// top directory.
pub fn normalize_bundle_path(path: &str) -> Option<String> {
    let unified = path.replace('\\', "/");
    if unified.starts_with('/') || unified.contains(':') {
        return None;
    }
    let mut parts: Vec<&str> = Vec::new();
    for part in unified.split('/') {
        match part {
            "" | "." => {}
            ".." => {
                parts.pop()?;
            }
            p => parts.push(p),
        }
    }
    if parts.is_empty() { None } else { Some(parts.join("/")) }
}

impl MemResolver {
    /// A resolver for the scene at `scene_path` (a normalised bundle path).
    pub fn for_scene(
        files: std::collections::HashMap<String, std::sync::Arc<Vec<u8>>>,
        scene_path: &str,
    ) -> Self {
        MemResolver { files, base: scene_dir(scene_path) }
    }

    fn candidates(&self, rel: &str) -> Vec<String> {
        bundle_candidates(&self.base, rel)
    }
}

/// The directory of the scene at `scene_path` (a normalised bundle path): "" for the top.
pub fn scene_dir(scene_path: &str) -> String {
    match scene_path.rfind('/') {
        Some(i) => scene_path[..i].to_string(),
        None => String::new(),
    }
}

/// Where a [`MemResolver`] for a scene whose directory in the bundle is `base` looks for `rel`,
/// in order (normalised bundle paths). Every resolver over a job's files by path (the farm
/// worker's over a job's manifest too) looks in these places, so all find the same file.
pub fn bundle_candidates(base: &str, rel: &str) -> Vec<String> {
    let joined = if base.is_empty() { rel.to_string() } else { format!("{base}/{rel}") };
    let mut out: Vec<String> = normalize_bundle_path(&joined).into_iter().collect();
    out.extend(normalize_bundle_path(rel));
    let parts: Vec<&str> = rel.split(['/', '\\']).filter(|p| !p.is_empty()).collect();
    for skip in 1..parts.len() {
        let tail = parts[skip..].join("/");
        let joined = if base.is_empty() { tail } else { format!("{base}/{tail}") };
        out.extend(normalize_bundle_path(&joined));
    }
    out
}

/// Where to pack the asset a scene names `rel` in a bundle whose scene file lies in the
/// directory `base` ("" for the top): the first place a [`MemResolver`] looks for it, so the
/// farm reads exactly that file. `None` when no place inside the bundle is looked at (a path
/// that is nothing but `..`s and `/`s).
pub fn bundle_path_for(base: &str, rel: &str) -> Option<String> {
    bundle_candidates(base, rel).into_iter().next()
}

/// One asset a [`RecordingResolver`] served: the path as the scene wrote it, where it was
/// found and its bytes.
#[derive(Clone, Debug, PartialEq)]
pub struct ServedAsset {
    pub requested: String,
    pub found_at: PathBuf,
    pub bytes: std::sync::Arc<Vec<u8>>,
}

/// Wraps a resolver and records every asset it serves, in the order of the requests: loading a
/// scene through it lists exactly the files the renderer reads (the client packs those into a
/// job's bundle, and nothing else). Failed requests are not recorded: they fail the load with
/// an error that names the file and the element. It does not pass on the inner resolver's
/// [`AssetResolver::content_id`], so that a build with a cache still reads (and lists) every asset.
#[derive(Debug)]
pub struct RecordingResolver<R> {
    pub inner: R,
    served: std::sync::Mutex<Vec<ServedAsset>>,
}

impl<R: AssetResolver> RecordingResolver<R> {
    pub fn new(inner: R) -> Self {
        RecordingResolver { inner, served: std::sync::Mutex::new(Vec::new()) }
    }

    /// Every asset served so far, in the order of the requests (an asset asked for twice is
    /// listed twice).
    pub fn served(&self) -> Vec<ServedAsset> {
        self.served.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }
}

impl<R: AssetResolver> AssetResolver for RecordingResolver<R> {
    fn read(&self, rel: &str) -> io::Result<(Vec<u8>, PathBuf)> {
        let (bytes, found_at) = self.inner.read(rel)?;
        let served = ServedAsset {
            requested: rel.to_string(),
            found_at: found_at.clone(),
            bytes: std::sync::Arc::new(bytes.clone()),
        };
        self.served.lock().unwrap_or_else(|e| e.into_inner()).push(served);
        Ok((bytes, found_at))
    }

    fn display_path(&self, rel: &str) -> PathBuf {
        self.inner.display_path(rel)
    }
}

impl AssetResolver for MemResolver {
    fn read(&self, rel: &str) -> io::Result<(Vec<u8>, PathBuf)> {
        for cand in self.candidates(rel) {
            if let Some(bytes) = self.files.get(&cand) {
                return Ok((bytes.as_ref().clone(), PathBuf::from(cand)));
            }
        }
        Err(io::Error::new(io::ErrorKind::NotFound, "not in the uploaded files"))
    }

    fn display_path(&self, rel: &str) -> PathBuf {
        let joined = if self.base.is_empty() { rel.to_string() } else { format!("{}/{rel}", self.base) };
        PathBuf::from(normalize_bundle_path(&joined).unwrap_or(joined))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strips_leading_components_when_path_was_rewritten() {
        let dir = tessera_testkit::TempDir::new("assets");
        std::fs::create_dir_all(dir.join("ply")).unwrap();
        std::fs::write(dir.join("ply/x.ply"), b"abc").unwrap();
        let r = FsResolver { base_dir: dir.to_path_buf() };
        assert_eq!(r.read("ply/x.ply").unwrap().0, b"abc");
        assert_eq!(r.read("assets/ply/x.ply").unwrap().0, b"abc");
        assert!(r.read("ply/missing.ply").is_err());
        // locate finds what read reads, where it reads it, and a folder is no file.
        for rel in ["ply/x.ply", "assets/ply/x.ply", "./ply/x.ply"] {
            assert_eq!(r.locate(rel), Some(r.read(rel).unwrap().1), "{rel}");
        }
        assert_eq!(r.locate("ply/x.ply"), Some(dir.join("ply/x.ply")));
        assert_eq!(r.locate("ply/missing.ply"), None);
        assert_eq!(r.locate("ply"), None);
    }

    #[test]
    fn bundle_paths_are_normalised_and_cannot_escape() {
        assert_eq!(normalize_bundle_path("a/./b/../c.ply").as_deref(), Some("a/c.ply"));
        assert_eq!(normalize_bundle_path("a\\b.ply").as_deref(), Some("a/b.ply"));
        for bad in ["../x", "a/../../x", "/etc/passwd", "C:/x", "", "."] {
            assert_eq!(normalize_bundle_path(bad), None, "{bad}");
        }
        let mut files = std::collections::HashMap::new();
        files.insert("scenes/ply/x.ply".to_string(), std::sync::Arc::new(b"abc".to_vec()));
        files.insert("top.txt".to_string(), std::sync::Arc::new(b"t".to_vec()));
        let r = MemResolver::for_scene(files, "scenes/a.xml");
        assert_eq!(r.read("ply/x.ply").unwrap().0, b"abc");
        assert_eq!(r.read("assets/ply/x.ply").unwrap().0, b"abc");
        assert_eq!(r.read("../top.txt").unwrap().0, b"t");
        // Nothing outside the bundle exists for it: a path climbing out is looked up inside it
        // (the leading-components fallback), never on disk.
        assert_eq!(r.read("../../top.txt").unwrap().1, PathBuf::from("top.txt"));
        assert!(r.read("../../etc/passwd").is_err());
        assert!(r.read("ply/missing.ply").is_err());
        assert_eq!(r.display_path("ply/missing.ply"), PathBuf::from("scenes/ply/missing.ply"));
    }

    #[test]
    fn bundle_path_for_is_where_the_bundle_resolver_looks_first() {
        assert_eq!(bundle_path_for("", "ply/x.ply").as_deref(), Some("ply/x.ply"));
        assert_eq!(bundle_path_for("xml", "../ply/x.ply").as_deref(), Some("ply/x.ply"));
        assert_eq!(bundle_path_for("a/b", "c\\d.png").as_deref(), Some("a/b/c/d.png"));
        // Climbing above the top: the first place looked at is the stripped path.
        assert_eq!(bundle_path_for("", "../ply/x.ply").as_deref(), Some("ply/x.ply"));
        // An absolute path is looked for below the scene's directory.
        assert_eq!(bundle_path_for("s", "/home/u/x.ply").as_deref(), Some("s/home/u/x.ply"));
        assert_eq!(bundle_path_for("", "/home/u/x.ply").as_deref(), Some("u/x.ply"));
        assert_eq!(bundle_path_for("", "../.."), None);
        // A file packed there is what the resolver finds, before any fallback.
        for (base, rel) in
            [("", "ply/x.ply"), ("xml", "../ply/x.ply"), ("s", "/home/u/x.ply"), ("", "/home/u/x.ply")]
        {
            let at = bundle_path_for(base, rel).unwrap();
            let mut files = std::collections::HashMap::new();
            files.insert(at.clone(), std::sync::Arc::new(b"right".to_vec()));
            files.insert("x.ply".to_string(), std::sync::Arc::new(b"wrong".to_vec()));
            let scene = if base.is_empty() { "a.xml".to_string() } else { format!("{base}/a.xml") };
            let r = MemResolver::for_scene(files, &scene);
            assert_eq!(r.read(rel).unwrap(), (b"right".to_vec(), PathBuf::from(at)), "{base} {rel}");
        }
    }

    #[test]
    fn recording_resolver_lists_what_it_served() {
        let dir = tessera_testkit::TempDir::new("assets-rec");
        std::fs::create_dir_all(dir.join("ply")).unwrap();
        std::fs::write(dir.join("ply/x.ply"), b"abc").unwrap();
        let r = RecordingResolver::new(FsResolver { base_dir: dir.to_path_buf() });
        assert_eq!(r.read("assets/ply/x.ply").unwrap().0, b"abc");
        assert!(r.read("ply/missing.ply").is_err());
        assert_eq!(r.display_path("ply/missing.ply"), dir.join("ply/missing.ply"));
        let served = r.served();
        assert_eq!(served.len(), 1);
        assert_eq!(served[0].requested, "assets/ply/x.ply");
        assert_eq!(served[0].found_at, dir.join("ply/x.ply"));
        assert_eq!(served[0].bytes.as_slice(), b"abc");
    }
}
