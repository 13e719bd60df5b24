//! The file store: every file of every job kept once, named by the SHA-256 of its bytes
//! (`files/<first two hex digits>/<sha256>` in the data directory).
//!
//! Clients ask which files the server lacks and upload only those; a job names its files by
//! path and hash (`job_files` rows, and a [`tessera::protocol::Manifest`] that is itself a file
//! here), and workers fetch each by hash. A file is written to a temporary name, checked
//! against its hash and renamed, so a stored file is always complete and right: an upload
//! ([`FileStore::put_stream`]) is streamed to a temporary file in `files/` while it is hashed,
//! and a temporary file a killed server left is removed at the next start
//! ([`FileStore::remove_temporaries`]).
//!
//! A file no job names any more, and not touched for [`GRACE`] (an upload waiting for the job
//! that names it), is removed by the housekeeping ([`collect_garbage`]), like the tar bundles
//! (`blobs/HASH.tar`) of older jobs once no job names them.

use std::path::{Path, PathBuf};
use std::sync::{Arc, RwLock};
use std::time::{Duration, SystemTime};

use anyhow::{Context, Result};
use sha2::{Digest, Sha256};
use tessera::atomic_write::{unique_temp_name, write_atomic};

use crate::bundle::{BlobStore, sha256_hex};
use crate::db::Store;

/// How long a file that no job names is kept after it was last uploaded or asked about: the
/// time a client has between uploading a job's files and submitting the job.
pub const GRACE: Duration = Duration::from_secs(3600);

/// Whether `s` is a SHA-256 as the store names files: 64 lowercase hex digits.
pub fn is_sha256(s: &str) -> bool {
    s.len() == 64 && s.bytes().all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

#[derive(Clone, Debug)]
pub struct FileStore {
    pub dir: PathBuf,
    /// Held (read) by whoever stores a job naming files of the store, from its check that the
    /// files are there to the commit of its rows; held (write) by [`collect_garbage`] while it
    /// decides and removes, so that no file is removed under a job being stored.
    pub gate: Arc<RwLock<()>>,
}

/// How an upload ended well.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stored {
    /// The file is new: stored now.
    New,
    /// The store had it already (the body was checked and dropped).
    Had,
}

/// Why an upload was not stored. Nothing of it is left either way.
#[derive(Debug)]
pub enum PutError {
    /// The body's SHA-256 is not the one it was uploaded under.
    WrongHash { expected: String, actual: String },
    /// The body is longer than the cap (`limit` bytes).
    TooLarge { limit: u64 },
    /// The body could not be read to its end (the connection was cut, a pause too long).
    Body(String),
    /// Writing it failed (a full disk among others: [`crate::storage::out_of_space`]).
    Io(anyhow::Error),
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
        FileStore { dir: data_dir.join("files"), gate: Arc::default() }
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

    /// Marks the file `sha256` as just used (its modification time becomes now), so that it is
    /// kept for another [`GRACE`] even if no job names it yet. Returns whether it is stored.
    pub fn touch(&self, sha256: &str) -> bool {
        let Some(path) = self.path(sha256) else { return false };
        match std::fs::File::open(&path) {
            Ok(f) => {
                let _ = f.set_modified(SystemTime::now());
                true
            }
            Err(_) => false,
        }
    }

    /// Streams an upload into the store under `sha256`: the body is written to a temporary
    /// file in the store while it is hashed, checked against `sha256` and `max_bytes`, synced
    /// and renamed into place. On any error (a wrong hash, too many bytes, a body cut off, a
    /// full disk) the temporary file is removed: nothing of the upload is left. A file the
    /// store has already is hashed and checked the same way but not written again (it is
    /// touched instead, [`FileStore::touch`]), unless `declared` (the body's length, when the
    /// request says it) differs from the stored copy's: that copy is then replaced.
    pub async fn put_stream<S, B, E>(
        &self,
        sha256: &str,
        mut body: S,
        declared: Option<u64>,
        max_bytes: u64,
    ) -> Result<Stored, PutError>
    where
        S: futures_util::Stream<Item = Result<B, E>> + Unpin,
        B: AsRef<[u8]>,
        E: std::fmt::Display,
    {
        use futures_util::StreamExt;
        use tokio::io::AsyncWriteExt;
        let path = self
            .path(sha256)
            .ok_or_else(|| PutError::WrongHash { expected: sha256.to_string(), actual: String::new() })?;
        // Touched first: a file the store has is then never collected during its upload.
        let stored_len = std::fs::metadata(&path).ok().filter(|m| m.is_file()).map(|m| m.len());
        let had = stored_len.is_some_and(|n| declared.is_none_or(|d| d == n)) && self.touch(sha256);
        let io = |what: &str, p: &Path, e: std::io::Error| {
            PutError::Io(anyhow::Error::new(e).context(format!("{what} {}", p.display())))
        };
        // Removed on every way out but the rename (a dropped future included: a client gone).
        let mut temp = None;
        let mut out = None;
        if !had {
            std::fs::create_dir_all(&self.dir).map_err(|e| io("cannot create", &self.dir, e))?;
            let t = TempFile(unique_temp_name(&self.dir.join(sha256)));
            out = Some(tokio::fs::File::create(&t.0).await.map_err(|e| io("cannot create", &t.0, e))?);
            temp = Some(t);
        }
        let mut hasher = Sha256::new();
        let mut size = 0u64;
        while let Some(chunk) = body.next().await {
            let chunk = chunk.map_err(|e| PutError::Body(e.to_string()))?;
            let chunk = chunk.as_ref();
            size += chunk.len() as u64;
            if size > max_bytes {
                return Err(PutError::TooLarge { limit: max_bytes });
            }
            hasher.update(chunk);
            if let (Some(out), Some(t)) = (out.as_mut(), temp.as_ref()) {
                out.write_all(chunk).await.map_err(|e| io("cannot write", &t.0, e))?;
            }
        }
        let actual: String = hasher.finalize().iter().map(|b| format!("{b:02x}")).collect();
        if actual != sha256 {
            return Err(PutError::WrongHash { expected: sha256.to_string(), actual });
        }
        let (Some(mut out), Some(temp)) = (out, temp) else { return Ok(Stored::Had) };
        out.flush().await.map_err(|e| io("cannot write", &temp.0, e))?;
        out.sync_all().await.map_err(|e| io("cannot write", &temp.0, e))?;
        drop(out);
        let parent = path.parent().expect("a folder of the store");
        tokio::fs::create_dir_all(parent).await.map_err(|e| io("cannot create", parent, e))?;
        // Another upload of the same file may have won meanwhile: equal bytes, replaced at once.
        tokio::fs::rename(&temp.0, &path).await.map_err(|e| io("cannot move into place", &path, e))?;
        std::mem::forget(temp);
        Ok(Stored::New)
    }

    /// Removes the temporary files a killed server left in the store (uploads and writes cut
    /// off: [`crate::storage::is_temp_name`]). Called at start, before anything writes.
    pub fn remove_temporaries(&self) -> usize {
        let mut removed = 0;
        let Ok(entries) = std::fs::read_dir(&self.dir) else { return 0 };
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if crate::storage::is_temp_name(&name) {
                removed += usize::from(std::fs::remove_file(e.path()).is_ok());
            } else if e.file_type().is_ok_and(|t| t.is_dir()) {
                for f in std::fs::read_dir(e.path()).into_iter().flatten().flatten() {
                    if crate::storage::is_temp_name(&f.file_name().to_string_lossy()) {
                        removed += usize::from(std::fs::remove_file(f.path()).is_ok());
                    }
                }
            }
        }
        removed
    }

    /// Every stored file: its SHA-256, path, size and modification time.
    fn stored(&self) -> Vec<(String, PathBuf, u64, SystemTime)> {
        let mut out = Vec::new();
        for dir in std::fs::read_dir(&self.dir).into_iter().flatten().flatten() {
            let prefix = dir.file_name().to_string_lossy().into_owned();
            if prefix.len() != 2 || !dir.file_type().is_ok_and(|t| t.is_dir()) {
                continue;
            }
            for f in std::fs::read_dir(dir.path()).into_iter().flatten().flatten() {
                let name = f.file_name().to_string_lossy().into_owned();
                if !is_sha256(&name) || !name.starts_with(&prefix) {
                    continue;
                }
                if let Some(m) = file_metadata(&f) {
                    out.push((name, f.path(), m.len(), m.modified().unwrap_or(SystemTime::now())));
                }
            }
        }
        out
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

/// A temporary file removed when dropped (unless forgotten once renamed).
struct TempFile(PathBuf);

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// The metadata of a regular file (not a folder, not a link's target).
fn file_metadata(e: &std::fs::DirEntry) -> Option<std::fs::Metadata> {
    e.metadata().ok().filter(|m| m.is_file())
}

/// What one pass of [`collect_garbage`] removed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Collected {
    pub files: usize,
    pub file_bytes: u64,
    pub bundles: usize,
    pub bundle_bytes: u64,
}

/// Whether a file last modified at `modified` is past the grace at `now`.
fn past_grace(modified: SystemTime, now: SystemTime, grace: Duration) -> bool {
    now.duration_since(modified).is_ok_and(|age| age > grace)
}

/// Removes the files of the store that no job names (no `job_files` row, no `jobs.manifest`)
/// and that nobody uploaded or asked about for `grace`, and the tar bundles (`blobs/HASH.tar`)
/// that no job names and that are older than `grace`. Decided and removed under the store's
/// gate ([`FileStore::gate`]), in batches, each file's age looked at again just before it goes.
pub fn collect_garbage(
    files: &FileStore,
    blobs: &BlobStore,
    store: &Store,
    grace: Duration,
) -> Result<Collected> {
    let mut done = Collected::default();
    let now = SystemTime::now();
    let old: Vec<_> = files.stored().into_iter().filter(|(_, _, _, t)| past_grace(*t, now, grace)).collect();
    for batch in old.chunks(500) {
        let _gate = files.gate.write().unwrap_or_else(|e| e.into_inner());
        let shas: Vec<&str> = batch.iter().map(|(s, ..)| s.as_str()).collect();
        let named = store.referenced_files(&shas)?;
        for (sha, path, size, _) in batch {
            let still_old = std::fs::metadata(path)
                .and_then(|m| m.modified())
                .is_ok_and(|t| past_grace(t, SystemTime::now(), grace));
            if named.contains(sha) || !still_old {
                continue;
            }
            if std::fs::remove_file(path).is_ok() {
                done.files += 1;
                done.file_bytes += size;
                // The folder of its first two hex digits goes once empty (fails otherwise).
                if let Some(parent) = path.parent() {
                    let _ = std::fs::remove_dir(parent);
                }
            }
        }
    }
    let mut tars = Vec::new();
    for e in std::fs::read_dir(&blobs.dir).into_iter().flatten().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(hash) = name.strip_suffix(".tar").filter(|h| is_sha256(h)) else { continue };
        if let Some(m) = file_metadata(&e).filter(|m| past_grace(m.modified().unwrap_or(now), now, grace)) {
            tars.push((hash.to_string(), e.path(), m.len()));
        }
    }
    for batch in tars.chunks(500) {
        let _gate = files.gate.write().unwrap_or_else(|e| e.into_inner());
        let hashes: Vec<&str> = batch.iter().map(|(h, ..)| h.as_str()).collect();
        let named = store.referenced_bundles(&hashes)?;
        for (hash, path, size) in batch {
            if !named.contains(hash) && std::fs::remove_file(path).is_ok() {
                done.bundles += 1;
                done.bundle_bytes += size;
            }
        }
    }
    Ok(done)
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

    fn chunks(parts: &[&[u8]]) -> impl futures_util::Stream<Item = Result<Vec<u8>, String>> + Unpin {
        futures_util::stream::iter(parts.iter().map(|p| Ok(p.to_vec())).collect::<Vec<_>>())
    }

    /// Every name in the store's folders (files and temporaries).
    fn names(store: &FileStore) -> Vec<String> {
        let mut out = Vec::new();
        for e in std::fs::read_dir(&store.dir).unwrap().flatten() {
            if e.file_type().unwrap().is_dir() {
                out.extend(
                    std::fs::read_dir(e.path())
                        .unwrap()
                        .flatten()
                        .map(|f| f.file_name().to_string_lossy().into_owned()),
                );
            } else {
                out.push(e.file_name().to_string_lossy().into_owned());
            }
        }
        out
    }

    #[tokio::test]
    async fn an_upload_is_stored_once_checked_and_nothing_is_left_of_a_bad_one() {
        let dir = tessera_testkit::TempDir::new("unit-files-stream");
        let store = FileStore::new(dir.path()).unwrap();
        let sha = sha256_hex(b"hello world");
        assert_eq!(
            store.put_stream(&sha, chunks(&[b"hello ", b"world"]), None, 11).await.unwrap(),
            Stored::New
        );
        assert_eq!(store.read(&sha).unwrap(), b"hello world");
        assert_eq!(store.put_stream(&sha, chunks(&[b"hello world"]), None, 100).await.unwrap(), Stored::Had);
        assert_eq!(names(&store), std::slice::from_ref(&sha));
        // A wrong hash, a body over the cap, a body cut off: nothing stored, nothing left.
        let other = sha256_hex(b"other");
        match store.put_stream(&other, chunks(&[b"not other"]), None, 100).await {
            Err(PutError::WrongHash { expected, actual }) => {
                assert_eq!((expected, actual), (other.clone(), sha256_hex(b"not other")))
            }
            r => panic!("{r:?}"),
        }
        assert!(matches!(
            store.put_stream(&other, chunks(&[b"oth", b"er"]), None, 4).await,
            Err(PutError::TooLarge { limit: 4 })
        ));
        let cut = futures_util::stream::iter(vec![Ok(b"oth".to_vec()), Err("connection reset".to_string())]);
        assert!(matches!(store.put_stream(&other, cut, None, 100).await, Err(PutError::Body(_))));
        // An upload whose future is dropped half-way (its client went): its temporary goes too.
        let pending = futures_util::StreamExt::chain(
            futures_util::stream::iter(vec![Ok::<_, String>(b"oth".to_vec())]),
            futures_util::stream::pending(),
        );
        let put = store.put_stream(&other, Box::pin(pending), None, 100);
        assert!(tokio::time::timeout(Duration::from_millis(50), put).await.is_err());
        // A wrong hash for a file the store has is refused too, and the file stays.
        assert!(matches!(
            store.put_stream(&sha, chunks(&[b"hello"]), None, 100).await,
            Err(PutError::WrongHash { .. })
        ));
        assert_eq!(names(&store), std::slice::from_ref(&sha));
        assert_eq!(store.read(&sha).unwrap(), b"hello world");
        // A stored copy that is not the file (cut by a crash of the machine): replaced when the
        // upload declares its length.
        std::fs::write(store.path(&sha).unwrap(), b"hello").unwrap();
        assert_eq!(
            store.put_stream(&sha, chunks(&[b"hello world"]), Some(11), 100).await.unwrap(),
            Stored::New
        );
        assert_eq!(store.read(&sha).unwrap(), b"hello world");
        // What a killed server left is swept at start.
        std::fs::write(store.dir.join(".x.1-2-3.tmp"), b"half").unwrap();
        std::fs::write(store.dir.join(&sha[..2]).join(".y.4-5-6.tmp"), b"half").unwrap();
        assert_eq!(store.remove_temporaries(), 2);
        assert_eq!(names(&store), [sha]);
    }

    /// Files no job names go once past the grace (their age looked at when they go, so a file
    /// asked about meanwhile stays); named files and young files stay; bundles likewise.
    #[test]
    fn garbage_is_what_no_job_names_past_the_grace() {
        let (dir, db) = crate::testutil::store("files-gc");
        let files = FileStore::new(dir.path()).unwrap();
        let blobs = BlobStore::new(dir.path()).unwrap();
        let old = SystemTime::now() - Duration::from_secs(7200);
        let age = |p: &Path| std::fs::File::open(p).unwrap().set_modified(old).unwrap();
        let (named, loose, young, touched) = (
            files.put(b"named").unwrap(),
            files.put(b"loose").unwrap(),
            files.put(b"young").unwrap(),
            files.put(b"touched").unwrap(),
        );
        for s in [&named, &loose, &touched] {
            age(&files.path(s).unwrap());
        }
        assert!(files.touch(&touched));
        let (bundle_named, bundle_loose) = (blobs.put(b"tar 1").unwrap(), blobs.put(b"tar 2").unwrap());
        age(&blobs.path(&bundle_named));
        age(&blobs.path(&bundle_loose));
        let job = crate::db::NewJob {
            bundle: bundle_named.clone(),
            scene_path: "s.json".into(),
            ..crate::testutil::job_of(Vec::new())
        };
        db.insert_job(&job).unwrap();
        let id = db.jobs().unwrap()[0].id;
        db.set_job_files_for_test(id, &named);
        let c = collect_garbage(&files, &blobs, &db, GRACE).unwrap();
        assert_eq!(c, Collected { files: 1, file_bytes: 5, bundles: 1, bundle_bytes: 5 });
        assert!(files.path(&loose).is_some_and(|p| !p.exists()));
        for s in [&named, &young, &touched] {
            assert!(files.has(s, std::fs::metadata(files.path(s).unwrap()).unwrap().len()), "{s}");
        }
        assert!(blobs.path(&bundle_named).exists() && !blobs.path(&bundle_loose).exists());
    }
}
