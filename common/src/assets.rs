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
        let base = match scene_path.rfind('/') {
            Some(i) => scene_path[..i].to_string(),
            None => String::new(),
        };
        MemResolver { files, base }
    }

    fn candidates(&self, rel: &str) -> Vec<String> {
        let joined = if self.base.is_empty() { rel.to_string() } else { format!("{}/{rel}", self.base) };
        let mut out: Vec<String> = normalize_bundle_path(&joined).into_iter().collect();
        out.extend(normalize_bundle_path(rel));
        let parts: Vec<&str> = rel.split(['/', '\\']).filter(|p| !p.is_empty()).collect();
        for skip in 1..parts.len() {
            let tail = parts[skip..].join("/");
            let joined = if self.base.is_empty() { tail } else { format!("{}/{tail}", self.base) };
            out.extend(normalize_bundle_path(&joined));
        }
        out
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
}
