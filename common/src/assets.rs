//! Where scene assets (PLY files, later images) come from.
//!
//! `common` never decides on its own where bytes live: the CLI reads the file system next to the
//! scene, the farm worker reads an uploaded bundle. Both implement [`AssetResolver`].

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strips_leading_components_when_path_was_rewritten() {
        let dir = std::env::temp_dir().join(format!("tessera-assets-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("ply")).unwrap();
        std::fs::write(dir.join("ply/x.ply"), b"abc").unwrap();
        let r = FsResolver { base_dir: dir.clone() };
        assert_eq!(r.read("ply/x.ply").unwrap().0, b"abc");
        assert_eq!(r.read("assets/ply/x.ply").unwrap().0, b"abc");
        assert!(r.read("ply/missing.ply").is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
