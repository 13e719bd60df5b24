//! The file store: every file of every job kept once, named by the SHA-256 of its bytes
//! (`files/<first two hex digits>/<sha256>` in the data directory).
//!
//! Clients ask which files the server lacks and upload only those; a job names its files by
//! path and hash (`job_files` rows, and a [`tessera::protocol::Manifest`] that is itself a file
//! here), and workers fetch each by hash. A file is written to a temporary name, checked
//! against its hash and renamed, so a stored file is always complete and right.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use tessera::atomic_write::write_atomic;

use crate::bundle::sha256_hex;

/// Whether `s` is a SHA-256 as the store names files: 64 lowercase hex digits.
pub fn is_sha256(s: &str) -> bool {
    s.len() == 64 && s.bytes().all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

#[derive(Clone, Debug)]
pub struct FileStore {
    pub dir: PathBuf,
}

impl FileStore {
    /// The store under `data_dir/files`, created if missing.
    pub fn new(data_dir: &Path) -> Result<FileStore> {
        let store = FileStore::at(data_dir);
        std::fs::create_dir_all(&store.dir)
            .with_context(|| format!("cannot create {}", store.dir.display()))?;
        Ok(store)
    }

    /// The store under `data_dir/files`, as it is (its folders are made as files arrive).
    pub fn at(data_dir: &Path) -> FileStore {
        FileStore { dir: data_dir.join("files") }
    }

    /// Where the file `sha256` is kept (it may not exist). `None` unless `sha256` is a
    /// SHA-256 in lowercase hex: nothing else names a file.
    pub fn path(&self, sha256: &str) -> Option<PathBuf> {
        is_sha256(sha256).then(|| self.dir.join(&sha256[..2]).join(sha256))
    }

    /// Whether the store holds the file `sha256` of `size` bytes.
    pub fn has(&self, sha256: &str, size: u64) -> bool {
        self.path(sha256)
            .and_then(|p| std::fs::metadata(p).ok())
            .is_some_and(|m| m.is_file() && m.len() == size)
    }

    /// The bytes of the file `sha256`.
    pub fn read(&self, sha256: &str) -> std::io::Result<Vec<u8>> {
        let path = self
            .path(sha256)
            .ok_or_else(|| std::io::Error::new(std::io::ErrorKind::NotFound, "not a SHA-256"))?;
        std::fs::read(path)
    }

    /// Stores `bytes` (if not stored yet) and returns their SHA-256. Written to a temporary
    /// file of its own, synced and renamed, so a file is either complete or absent.
    pub fn put(&self, bytes: &[u8]) -> Result<String> {
        let sha = sha256_hex(bytes);
        let path = self.path(&sha).expect("a SHA-256 in hex");
        if !self.has(&sha, bytes.len() as u64) {
            let parent = path.parent().expect("a folder of the store");
            std::fs::create_dir_all(parent).with_context(|| format!("cannot create {}", parent.display()))?;
            write_atomic(&path, bytes)?;
        }
        Ok(sha)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_is_stored_once_under_its_hash_and_read_back() {
        let dir = tessera_testkit::TempDir::new("unit-files");
        let store = FileStore::new(dir.path()).unwrap();
        let sha = store.put(b"ply\n").unwrap();
        assert_eq!(sha, sha256_hex(b"ply\n"));
        assert!(store.has(&sha, 4));
        assert!(!store.has(&sha, 5), "a size that differs is another file");
        assert_eq!(store.read(&sha).unwrap(), b"ply\n");
        assert_eq!(store.put(b"ply\n").unwrap(), sha);
        assert!(store.path("../../etc/passwd").is_none());
        assert!(store.path(&sha.to_uppercase()).is_none());
    }
}
