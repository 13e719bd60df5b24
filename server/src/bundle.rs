//! Job bundles: the scene file and its assets as one content-addressed tar archive.
//!
//! Uploads arrive as separate multipart files or as one `.tar`, `.tar.gz` or `.zip` archive;
//! either way they become a map from normalised relative paths to bytes ([`Files`]), checked for
//! paths that would leave the bundle. [`canonical_tar`] writes that map as a tar with sorted
//! entries and fixed metadata, so the same files always give the same bytes, and the SHA-256 of
//! those bytes names the bundle (`blobs/<hash>.tar` in the data directory). Workers fetch a
//! bundle once per hash and cache the scene built from it.

use std::collections::{BTreeMap, HashMap};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result};
use sha2::{Digest, Sha256};
use tessera::assets::normalize_bundle_path;

/// Files of a bundle by normalised path.
pub type Files = BTreeMap<String, Vec<u8>>;

/// Why an upload is not a usable bundle (a 400 for the client).
#[derive(Debug)]
pub enum BundleError {
    /// A path that is absolute or climbs out of the bundle (`../`).
    UnsafePath(String),
    /// Not a tar, tar.gz or zip archive, or a damaged one.
    Archive(String),
    /// The same path twice.
    Duplicate(String),
}

impl std::error::Error for BundleError {}

impl std::fmt::Display for BundleError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            BundleError::UnsafePath(p) => write!(
                f,
                "the path \"{p}\" leaves the bundle (absolute, or with ../ above its top); name files by their path relative to the scene's folder"
            ),
            BundleError::Archive(m) => write!(f, "{m}"),
            BundleError::Duplicate(p) => write!(f, "the file \"{p}\" is given twice"),
        }
    }
}

/// Adds one uploaded file under `path`.
pub fn add_file(files: &mut Files, path: &str, bytes: Vec<u8>) -> Result<(), BundleError> {
    let norm = normalize_bundle_path(path).ok_or_else(|| BundleError::UnsafePath(path.to_string()))?;
    if files.insert(norm.clone(), bytes).is_some() {
        return Err(BundleError::Duplicate(norm));
    }
    Ok(())
}

/// Unpacks an archive (recognised by content: gzip, zip or tar) into `files`.
pub fn add_archive(files: &mut Files, bytes: &[u8]) -> Result<(), BundleError> {
    if bytes.starts_with(&[0x1f, 0x8b]) {
        let mut tar = Vec::new();
        flate2::read::GzDecoder::new(bytes)
            .read_to_end(&mut tar)
            .map_err(|e| BundleError::Archive(format!("the .tar.gz bundle cannot be decompressed: {e}")))?;
        return add_tar(files, &tar);
    }
    if bytes.starts_with(b"PK") {
        let mut zip = zip::ZipArchive::new(std::io::Cursor::new(bytes))
            .map_err(|e| BundleError::Archive(format!("the .zip bundle cannot be read: {e}")))?;
        for i in 0..zip.len() {
            let mut entry = zip
                .by_index(i)
                .map_err(|e| BundleError::Archive(format!("the .zip bundle is damaged: {e}")))?;
            if entry.is_dir() {
                continue;
            }
            let name = entry.name().to_string();
            let mut data = Vec::new();
            entry.read_to_end(&mut data).map_err(|e| {
                BundleError::Archive(format!("cannot unpack {name} from the .zip bundle: {e}"))
            })?;
            add_file(files, &name, data)?;
        }
        return Ok(());
    }
    if bytes.len() >= 262 && &bytes[257..262] == b"ustar" || bytes.len() >= 512 && looks_like_v7_tar(bytes) {
        return add_tar(files, bytes);
    }
    Err(BundleError::Archive(
        "the bundle is not a .tar, .tar.gz or .zip archive; upload the scene and its assets as separate files, or pack them with tar or zip".into(),
    ))
}

/// An old-style tar without the ustar magic: the header checksum matches.
fn looks_like_v7_tar(bytes: &[u8]) -> bool {
    let header = &bytes[..512];
    let stored =
        std::str::from_utf8(&header[148..156]).ok().map(|s| s.trim_matches(|c: char| c == '\0' || c == ' '));
    let Some(stored) = stored.and_then(|s| u32::from_str_radix(s, 8).ok()) else { return false };
    let sum: u32 = header
        .iter()
        .enumerate()
        .map(|(i, b)| if (148..156).contains(&i) { 32 } else { u32::from(*b) })
        .sum();
    sum == stored
}

fn add_tar(files: &mut Files, bytes: &[u8]) -> Result<(), BundleError> {
    let mut archive = tar::Archive::new(bytes);
    let entries =
        archive.entries().map_err(|e| BundleError::Archive(format!("the tar bundle cannot be read: {e}")))?;
    for entry in entries {
        let mut entry = entry.map_err(|e| BundleError::Archive(format!("the tar bundle is damaged: {e}")))?;
        let kind = entry.header().entry_type();
        if kind.is_dir() || kind.is_pax_global_extensions() || kind.is_pax_local_extensions() {
            continue;
        }
        let path = entry.path_bytes().into_owned();
        let path = String::from_utf8_lossy(&path).into_owned();
        if !kind.is_file() {
            return Err(BundleError::Archive(format!(
                "the tar bundle holds \"{path}\", which is not a regular file (links are not accepted)"
            )));
        }
        let mut data = Vec::new();
        entry
            .read_to_end(&mut data)
            .map_err(|e| BundleError::Archive(format!("cannot unpack {path} from the tar bundle: {e}")))?;
        add_file(files, &path, data)?;
    }
    Ok(())
}

/// The bundle as a tar with sorted entries, mode 0644 and mtime 0: same files, same bytes.
pub fn canonical_tar(files: &Files) -> Vec<u8> {
    let mut builder = tar::Builder::new(Vec::new());
    for (path, data) in files {
        let mut header = tar::Header::new_gnu();
        header.set_size(data.len() as u64);
        header.set_mode(0o644);
        header.set_mtime(0);
        header.set_entry_type(tar::EntryType::Regular);
        // `append_data` writes long names with GNU extension headers.
        builder
            .append_data(&mut header, path, data.as_slice())
            .expect("writing a tar into memory cannot fail");
    }
    builder.into_inner().expect("writing a tar into memory cannot fail")
}

/// Reads a tar written by [`canonical_tar`] back into shared buffers (for the resolver).
pub fn read_tar(bytes: &[u8]) -> Result<HashMap<String, Arc<Vec<u8>>>> {
    let mut files = Files::new();
    add_tar(&mut files, bytes).map_err(|e| anyhow::anyhow!("{e}"))?;
    Ok(files.into_iter().map(|(k, v)| (k, Arc::new(v))).collect())
}

pub fn sha256_hex(bytes: &[u8]) -> String {
    let digest = Sha256::digest(bytes);
    digest.iter().map(|b| format!("{b:02x}")).collect()
}

/// Content-addressed files under `<data>/blobs`.
#[derive(Clone, Debug)]
pub struct BlobStore {
    pub dir: PathBuf,
}

impl BlobStore {
    pub fn new(data_dir: &Path) -> Result<BlobStore> {
        let dir = data_dir.join("blobs");
        std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
        remove_stale_temp_files(&dir);
        Ok(BlobStore { dir })
    }

    pub fn path(&self, hash: &str) -> PathBuf {
        self.dir.join(format!("{hash}.tar"))
    }

    /// Stores `bytes` (if not stored yet) and returns their hash. Written to a temporary file
    /// of its own, synced and renamed, so a blob is either complete or absent. Any number of
    /// writers may put the same bytes at once: each renames its own complete copy over the same
    /// name (an atomic replace of equal content), so none fails because another won.
    pub fn put(&self, bytes: &[u8]) -> Result<String> {
        let hash = sha256_hex(bytes);
        let path = self.path(&hash);
        if !path.exists() {
            write_atomic(&path, bytes)?;
        }
        Ok(hash)
    }

    pub fn get(&self, hash: &str) -> Option<Vec<u8>> {
        if hash.len() != 64 || !hash.bytes().all(|b| b.is_ascii_hexdigit()) {
            return None;
        }
        std::fs::read(self.path(hash)).ok()
    }
}

/// A name beside `path` that no other writer in this or any other process uses: the process
/// id, a per-process counter and the clock. Concurrent writers of one file each get their own.
pub fn unique_temp_name(path: &Path) -> PathBuf {
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos())
        .unwrap_or(0);
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.{}-{n}-{nanos}.tmp", std::process::id()))
}

/// Removes temporary files a killed writer left in `dir`, once they are an hour old (a live
/// writer finishes long before; another server sharing the folder may be writing newer ones).
fn remove_stale_temp_files(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let old = e
            .metadata()
            .and_then(|m| m.modified())
            .ok()
            .and_then(|t| t.elapsed().ok())
            .is_some_and(|age| age > std::time::Duration::from_secs(3600));
        if name.starts_with('.') && name.ends_with(".tmp") && old {
            let _ = std::fs::remove_file(e.path());
        }
    }
}

/// Writes `bytes` to `path` through a synced temporary file of its own and a rename (which
/// replaces an existing file atomically), so readers see the old or the new file, never half
/// of one, and concurrent writers never trip over each other's temporary files.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    use std::io::Write;
    let tmp = unique_temp_name(path);
    let write = || -> Result<()> {
        let mut f =
            std::fs::File::create(&tmp).with_context(|| format!("cannot create {}", tmp.display()))?;
        f.write_all(bytes).with_context(|| format!("cannot write {}", tmp.display()))?;
        f.sync_all().with_context(|| format!("cannot sync {}", tmp.display()))?;
        drop(f);
        std::fs::rename(&tmp, path).with_context(|| format!("cannot move {} into place", path.display()))
    };
    let result = write();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// The scene file of a bundle: `wanted` if given, else the only `.xml` (or `.json`) file at the
/// shallowest depth.
pub fn find_scene(files: &Files, wanted: Option<&str>) -> Result<String, String> {
    if let Some(w) = wanted {
        let norm = normalize_bundle_path(w).ok_or_else(|| format!("scene path \"{w}\" leaves the bundle"))?;
        return if files.contains_key(&norm) {
            Ok(norm)
        } else {
            Err(format!("the bundle has no file \"{norm}\" (the scene_path field)"))
        };
    }
    let scenes: Vec<&String> = files
        .keys()
        .filter(|p| {
            let l = p.to_ascii_lowercase();
            l.ends_with(".xml") || l.ends_with(".json")
        })
        .collect();
    let depth = |p: &str| p.matches('/').count();
    let Some(min) = scenes.iter().map(|p| depth(p)).min() else {
        return Err(
            "the upload has no scene file (.xml or .json); add one as the \"scene\" field or inside the bundle".into(),
        );
    };
    let top: Vec<&&String> = scenes.iter().filter(|p| depth(p) == min).collect();
    match top.as_slice() {
        [one] => Ok((**one).clone()),
        many => Err(format!(
            "the bundle has several scene files ({}); say which with the scene_path field",
            many.iter().map(|s| s.as_str()).collect::<Vec<_>>().join(", ")
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn canonical_tar_is_deterministic_and_round_trips() {
        let mut a = Files::new();
        add_file(&mut a, "scene.xml", b"<Scene/>".to_vec()).unwrap();
        add_file(&mut a, "ply/x.ply", vec![1, 2, 3]).unwrap();
        let mut b = Files::new();
        add_file(&mut b, "./ply/../ply/x.ply", vec![1, 2, 3]).unwrap();
        add_file(&mut b, "scene.xml", b"<Scene/>".to_vec()).unwrap();
        let (ta, tb) = (canonical_tar(&a), canonical_tar(&b));
        assert_eq!(ta, tb);
        let back = read_tar(&ta).unwrap();
        assert_eq!(back.len(), 2);
        assert_eq!(back["ply/x.ply"].as_slice(), &[1, 2, 3]);
        // An uploaded tar is read like our own.
        let mut c = Files::new();
        add_archive(&mut c, &ta).unwrap();
        assert_eq!(c, a);
    }

    #[test]
    fn unsafe_paths_and_garbage_are_refused() {
        let mut f = Files::new();
        assert!(matches!(add_file(&mut f, "../x", vec![]), Err(BundleError::UnsafePath(_))));
        assert!(matches!(add_file(&mut f, "/etc/passwd", vec![]), Err(BundleError::UnsafePath(_))));
        assert!(matches!(add_archive(&mut f, b"hello world"), Err(BundleError::Archive(_))));
        add_file(&mut f, "a.xml", vec![]).unwrap();
        assert!(matches!(add_file(&mut f, "./a.xml", vec![]), Err(BundleError::Duplicate(_))));
    }

    /// Many threads storing the same bytes and different bytes at once: every put succeeds, each
    /// blob holds its bytes, and no temporary file is left behind.
    #[test]
    fn concurrent_puts_of_equal_and_different_bytes_all_succeed() {
        let dir = std::env::temp_dir().join(format!("tessera-blobs-race-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let store = BlobStore::new(&dir).unwrap();
        let threads: Vec<_> = (0..64)
            .map(|i| {
                let store = store.clone();
                std::thread::spawn(move || {
                    let bytes = if i % 4 == 0 { vec![i as u8; 100_000] } else { vec![7u8; 300_000] };
                    let hash = store.put(&bytes).unwrap();
                    assert_eq!(store.get(&hash).unwrap(), bytes);
                })
            })
            .collect();
        for t in threads {
            t.join().unwrap();
        }
        let names: Vec<String> = std::fs::read_dir(&store.dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names.len(), 17, "{names:?}");
        assert!(names.iter().all(|n| n.ends_with(".tar") && !n.starts_with('.')), "{names:?}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_scene_is_found() {
        let mut f = Files::new();
        add_file(&mut f, "scenes/a.xml", vec![]).unwrap();
        add_file(&mut f, "scenes/ply/b.xml", vec![]).unwrap();
        assert_eq!(find_scene(&f, None).unwrap(), "scenes/a.xml");
        add_file(&mut f, "scenes/c.xml", vec![]).unwrap();
        assert!(find_scene(&f, None).unwrap_err().contains("several"));
        assert_eq!(find_scene(&f, Some("scenes/c.xml")).unwrap(), "scenes/c.xml");
        assert!(find_scene(&Files::new(), None).is_err());
    }
}
