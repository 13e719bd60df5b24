//! Job bundles: the scene file and its assets as one content-addressed tar archive.
//!
//! Uploads arrive as separate multipart files or as one `.tar`, `.tar.gz` or `.zip` archive;
//! either way they become a map from normalised relative paths to bytes ([`Files`]), checked for
//! paths that would leave the bundle. [`canonical_tar`] writes that map as a tar with sorted
//! entries and fixed metadata, so the same files always give the same bytes, and the SHA-256 of
//! those bytes names the bundle (`blobs/<hash>.tar` in the data directory). Tars are read by
//! common's reader (`tessera::bundle`), which also turns a bundle into a scene, for the server's
//! validation and camera lookup as for the workers, which fetch a bundle once per hash and cache
//! the scene built from it. Blobs are written with [`write_atomic`].

use std::collections::BTreeMap;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use sha2::{Digest, Sha256};
use tessera::assets::normalize_bundle_path;
use tessera::atomic_write::write_atomic;
use tessera::bundle::{TarError, for_each_tar_file};

/// Files of a bundle by normalised path.
pub type Files = BTreeMap<String, Vec<u8>>;

/// Caps on what an upload may unpack to, checked while reading (an archive is never unpacked
/// further than the cap, whatever its headers claim).
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    /// Total bytes of every file of the bundle, unpacked.
    pub max_unpacked_bytes: u64,
    /// Number of files.
    pub max_files: usize,
    /// Bytes of any one file, unpacked.
    pub max_file_bytes: u64,
}

impl Default for Limits {
    /// 256 MiB in all, in at most 10 000 files: every course scene with its assets is under
    /// 20 MiB.
    fn default() -> Self {
        Limits { max_unpacked_bytes: 256 << 20, max_files: 10_000, max_file_bytes: 256 << 20 }
    }
}

/// Why an upload is not a usable bundle (a 400 for the client, a 413 for [`BundleError::TooLarge`]).
#[derive(Debug)]
pub enum BundleError {
    /// A path that is absolute or climbs out of the bundle (`../`).
    UnsafePath(String),
    /// Not a tar, tar.gz or zip archive, or a damaged one.
    Archive(String),
    /// The same path twice.
    Duplicate(String),
    /// A file name holding a control character (a NUL byte, a line break, ...).
    BadName(String),
    /// Over one of the [`Limits`]; the message names the cap and the flag that raises it.
    TooLarge(String),
}

impl std::error::Error for BundleError {}

impl From<TarError> for BundleError {
    fn from(e: TarError) -> Self {
        BundleError::Archive(e.0)
    }
}

impl std::fmt::Display for BundleError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            BundleError::UnsafePath(p) => write!(
                f,
                "the path \"{p}\" leaves the bundle (absolute, or with ../ above its top); name files by their path relative to the scene's folder"
            ),
            BundleError::Archive(m) | BundleError::TooLarge(m) => write!(f, "{m}"),
            BundleError::Duplicate(p) => write!(f, "the file \"{p}\" is given twice"),
            BundleError::BadName(p) => write!(
                f,
                "the file name {p:?} holds a control character (a NUL byte, a line break or a tab); \
                 rename the file without them and pack it again"
            ),
        }
    }
}

fn mib(bytes: u64) -> String {
    let m = bytes as f64 / f64::from(1 << 20);
    if m >= 10.0 { format!("{m:.0} MiB") } else { format!("{m:.2} MiB") }
}

/// Collects a bundle's files under [`Limits`]: every file is read through a cap of what is
/// left, so an upload can never make it hold more than `max_unpacked_bytes`.
pub struct Unpacker {
    pub files: Files,
    limits: Limits,
    total: u64,
}

impl Unpacker {
    pub fn new(limits: Limits) -> Unpacker {
        Unpacker { files: Files::new(), limits, total: 0 }
    }

    /// Bytes unpacked so far.
    pub fn total_bytes(&self) -> u64 {
        self.total
    }

    pub fn too_many_files_error(&self) -> BundleError {
        BundleError::TooLarge(format!(
            "the bundle holds more than {} files, the most this server accepts (--max-bundle-files, \
             TESSERA_MAX_BUNDLE_FILES); leave out files the scene does not use, or ask the farm's operator to raise the limit",
            self.limits.max_files
        ))
    }

    /// A file whose size is known before reading it (a header's claim, checked again on reading).
    fn check_claim(&self, path: &str, size: u64) -> Result<(), BundleError> {
        if size > self.limits.max_file_bytes {
            return Err(self.file_too_large_error(path));
        }
        if size > self.limits.max_unpacked_bytes - self.total {
            return Err(self.total_too_large());
        }
        Ok(())
    }

    pub fn file_too_large_error(&self, path: &str) -> BundleError {
        BundleError::TooLarge(format!(
            "\"{path}\" is larger than {}, the largest single file this server accepts (--max-file-mb, \
             TESSERA_MAX_FILE_MB); shrink the file, or ask the farm's operator to raise the limit",
            mib(self.limits.max_file_bytes)
        ))
    }

    fn total_too_large(&self) -> BundleError {
        BundleError::TooLarge(format!(
            "the bundle unpacks to more than {}, the most this server accepts (--max-unpacked-mb, \
             TESSERA_MAX_UNPACKED_MB); an archive that unpacks to far more than its size may be a \
             decompression bomb; send only the files the scene uses, or ask the farm's operator to raise the limit",
            mib(self.limits.max_unpacked_bytes)
        ))
    }

    /// Adds one file under `path`, read from `data` through the caps.
    pub fn add_reader(&mut self, path: &str, data: impl Read) -> Result<(), BundleError> {
        let norm = checked_path(path)?;
        if self.files.contains_key(&norm) {
            return Err(BundleError::Duplicate(norm));
        }
        if self.files.len() >= self.limits.max_files {
            return Err(self.too_many_files_error());
        }
        let room = self.limits.max_file_bytes.min(self.limits.max_unpacked_bytes - self.total);
        let mut bytes = Vec::new();
        data.take(room.saturating_add(1))
            .read_to_end(&mut bytes)
            .map_err(|e| BundleError::Archive(format!("cannot unpack {path}: {e}")))?;
        if bytes.len() as u64 > room {
            return Err(if bytes.len() as u64 > self.limits.max_file_bytes {
                self.file_too_large_error(path)
            } else {
                self.total_too_large()
            });
        }
        self.total += bytes.len() as u64;
        self.files.insert(norm, bytes);
        Ok(())
    }

    /// Unpacks an archive (recognised by content: gzip, zip or tar), streaming from `source`.
    pub fn add_archive<R: Read + Seek>(&mut self, mut source: R) -> Result<(), BundleError> {
        let damaged = |e: std::io::Error| BundleError::Archive(format!("the bundle cannot be read: {e}"));
        let mut head = Vec::with_capacity(512);
        (&mut source).take(512).read_to_end(&mut head).map_err(damaged)?;
        source.seek(SeekFrom::Start(0)).map_err(damaged)?;
        if head.starts_with(&[0x1f, 0x8b]) {
            let gz = flate2::read::GzDecoder::new(std::io::BufReader::new(source));
            return self.add_tar(gz, ".tar.gz");
        }
        if head.starts_with(b"PK") {
            return self.add_zip(source);
        }
        if head.len() >= 262 && &head[257..262] == b"ustar" || head.len() == 512 && looks_like_v7_tar(&head) {
            return self.add_tar(std::io::BufReader::new(source), "tar");
        }
        Err(BundleError::Archive(
            "the bundle is not a .tar, .tar.gz or .zip archive; upload the scene and its assets as separate files, or pack them with tar or zip".into(),
        ))
    }

    fn add_zip<R: Read + Seek>(&mut self, source: R) -> Result<(), BundleError> {
        let mut zip = zip::ZipArchive::new(source)
            .map_err(|e| BundleError::Archive(format!("the .zip bundle cannot be read: {e}")))?;
        // The central directory gives the count up front: refuse before unpacking anything.
        if zip.len() > self.limits.max_files.saturating_sub(self.files.len()) {
            return Err(self.too_many_files_error());
        }
        for i in 0..zip.len() {
            let entry = zip
                .by_index(i)
                .map_err(|e| BundleError::Archive(format!("the .zip bundle is damaged: {e}")))?;
            if entry.is_dir() {
                continue;
            }
            let name = entry.name().to_string();
            self.check_claim(&name, entry.size())?;
            self.add_reader(&name, entry).map_err(|e| match e {
                BundleError::Archive(m) => BundleError::Archive(format!("{m} (in the .zip bundle)")),
                other => other,
            })?;
        }
        Ok(())
    }

    /// Unpacks a tar (common's reader, `what` naming it in messages), every file through the caps.
    fn add_tar(&mut self, source: impl Read, what: &str) -> Result<(), BundleError> {
        for_each_tar_file(source, what, |path, size, data| {
            self.check_claim(path, size)?;
            self.add_reader(path, data)
        })
    }
}

/// Adds one uploaded file under `path` (no caps: the bytes are in memory already).
pub fn add_file(files: &mut Files, path: &str, bytes: Vec<u8>) -> Result<(), BundleError> {
    let norm = checked_path(path)?;
    if files.insert(norm.clone(), bytes).is_some() {
        return Err(BundleError::Duplicate(norm));
    }
    Ok(())
}

/// A member's path, normalised, or why it is refused: a control character anywhere in it (no
/// file system or tar header takes a NUL, and line breaks would forge log lines), or a path
/// that leaves the bundle.
fn checked_path(path: &str) -> Result<String, BundleError> {
    if path.chars().any(char::is_control) {
        return Err(BundleError::BadName(path.to_string()));
    }
    normalize_bundle_path(path).ok_or_else(|| BundleError::UnsafePath(path.to_string()))
}

/// Unpacks an archive held in memory into `files` under the default [`Limits`].
pub fn add_archive(files: &mut Files, bytes: &[u8]) -> Result<(), BundleError> {
    let mut unpacker = Unpacker::new(Limits::default());
    unpacker.files = std::mem::take(files);
    unpacker.total = unpacker.files.values().map(|v| v.len() as u64).sum();
    let result = unpacker.add_archive(std::io::Cursor::new(bytes));
    *files = unpacker.files;
    result
}

/// An old-style tar without the ustar magic: the header checksum matches.
fn looks_like_v7_tar(header: &[u8]) -> bool {
    let header = &header[..512];
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

/// The bundle as a tar with sorted entries, mode 0644 and mtime 0: same files, same bytes.
/// Fails, naming the file, only for a path no tar can hold (the unpacker refuses those first).
pub fn canonical_tar(files: &Files) -> Result<Vec<u8>, BundleError> {
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
            .map_err(|e| BundleError::Archive(format!("cannot pack the file {path:?}: {e}")))?;
    }
    builder.into_inner().map_err(|e| BundleError::Archive(format!("cannot pack the bundle: {e}")))
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
        } else if let Ok(f) = std::fs::File::open(&path) {
            // Used again: kept another grace by the collection of bundles no job names
            // (`files::collect_garbage`) while its job is being stored.
            let _ = f.set_modified(std::time::SystemTime::now());
        }
        Ok(hash)
    }

    pub fn get(&self, hash: &str) -> Option<Vec<u8>> {
        std::fs::read(self.stored_path(hash)?).ok()
    }

    /// Where blob `hash` is kept, if `hash` is a SHA-256 in hex (nothing else names a file);
    /// the file may not exist.
    pub fn stored_path(&self, hash: &str) -> Option<PathBuf> {
        (hash.len() == 64 && hash.bytes().all(|b| b.is_ascii_hexdigit())).then(|| self.path(hash))
    }
}

/// Removes temporary files a killed writer left in `dir` (`.<name>.<...>.tmp`, the names of
/// [`tessera::atomic_write::unique_temp_name`]), once they are an hour old (a live writer
/// finishes long before; another server sharing the folder may be writing newer ones).
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
        let (ta, tb) = (canonical_tar(&a).unwrap(), canonical_tar(&b).unwrap());
        assert_eq!(ta, tb);
        let back = tessera::bundle::read_tar(&ta).unwrap();
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
        let dir = tessera_testkit::TempDir::new("blobs-race");
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
