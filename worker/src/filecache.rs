//! The farm worker's on-disk cache of job files, by SHA-256.
//!
//! A farm job names its files by SHA-256 and size (its manifest); a worker downloads each
//! distinct file once and keeps it here for the frames and jobs that follow: an orbit of 360
//! frames around one statue downloads the statue once, and so does the next job of the same
//! statue, even after the worker restarts.
//!
//! Layout: `DIR/<first 2 hex digits>/<sha256>`, one file each, and `DIR/tmp/` for downloads
//! under way. A download goes to a temporary file while its bytes are counted and hashed;
//! only a file of the announced size and hash is renamed into place, so an interrupted or
//! corrupt download leaves nothing behind (and `tmp/` is emptied when the cache is opened).
//! The cache is bounded (`--cache-mb`): past the bound the least recently used files are
//! removed. A use touches the file's modification time, so the order survives a restart:
//! opening the cache scans `DIR` and orders what it finds by that time. Concurrent requests
//! for one file download it once; the others wait for that download. Several worker processes
//! may share a directory: a file another one removed is simply downloaded again.

use std::collections::{HashMap, HashSet};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::SystemTime;

use anyhow::{Context, Result, anyhow, bail};
use sha2::{Digest, Sha256};

/// `--cache-mb`'s default: 2 GiB.
pub const DEFAULT_CACHE_MB: u64 = 2048;

/// The default cache directory: `$XDG_CACHE_HOME/tessera/files`, else
/// `$HOME/.cache/tessera/files`; `None` when neither is set.
pub fn default_dir() -> Option<PathBuf> {
    let var = |name: &str| std::env::var_os(name).filter(|v| !v.is_empty()).map(PathBuf::from);
    var("XDG_CACHE_HOME")
        .map(|x| x.join("tessera/files"))
        .or_else(|| var("HOME").map(|h| h.join(".cache/tessera/files")))
}

/// Whether `s` is a SHA-256 as files are named: 64 lowercase hex digits.
pub fn is_sha256(s: &str) -> bool {
    s.len() == 64 && s.bytes().all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

/// What the cache did since it was opened, and what it holds now.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FileCacheStats {
    /// Requests served from the directory.
    pub hits: u64,
    /// Downloads that completed and verified.
    pub fetches: u64,
    /// Files removed to stay within the bound.
    pub evictions: u64,
    pub files: u64,
    pub bytes: u64,
}

struct Known {
    size: u64,
    /// The use count when it was last used (larger = more recent).
    used: u64,
}

#[derive(Default)]
struct State {
    files: HashMap<String, Known>,
    bytes: u64,
    clock: u64,
    /// Files being downloaded now (their requests wait for that download).
    fetching: HashSet<String>,
    stats: FileCacheStats,
}

/// Job files on disk by SHA-256 (see the module's documentation).
pub struct FileCache {
    dir: PathBuf,
    limit: u64,
    state: Mutex<State>,
    fetched: Condvar,
    /// Numbers temporary files apart within this process.
    temp_counter: AtomicU64,
}

impl std::fmt::Debug for FileCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "FileCache({}, limit {} bytes)", self.dir.display(), self.limit)
    }
}

/// A writer that keeps the bytes, writes them to a file, hashes and counts them, and refuses
/// more than `expected`.
struct Verifying<'a> {
    file: std::io::BufWriter<std::fs::File>,
    hasher: Sha256,
    bytes: Vec<u8>,
    expected: u64,
    sha: &'a str,
}

impl Write for Verifying<'_> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        if self.bytes.len() as u64 + buf.len() as u64 > self.expected {
            return Err(std::io::Error::other(format!(
                "file {} is longer than its announced {} bytes",
                self.sha, self.expected
            )));
        }
        self.file.write_all(buf)?;
        self.hasher.update(buf);
        self.bytes.extend_from_slice(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush()
    }
}

fn lock(m: &Mutex<State>) -> std::sync::MutexGuard<'_, State> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Removes the file at `path`, if any; a file already gone is fine.
fn remove(path: &Path) {
    let _ = std::fs::remove_file(path);
}

impl FileCache {
    /// Opens (creating it if needed) the cache in `dir`, bounded to `limit_bytes`: removes
    /// downloads a previous run left half done, finds the files already there (ordered by
    /// their last use) and removes the least recently used past the bound.
    pub fn open(dir: &Path, limit_bytes: u64) -> Result<FileCache> {
        let tmp = dir.join("tmp");
        std::fs::create_dir_all(&tmp)
            .with_context(|| format!("cannot create the file cache directory {}", dir.display()))?;
        if let Ok(entries) = std::fs::read_dir(&tmp) {
            for e in entries.flatten() {
                remove(&e.path());
            }
        }
        let mut found: Vec<(SystemTime, String, u64)> = Vec::new();
        let entries = std::fs::read_dir(dir)
            .with_context(|| format!("cannot read the file cache {}", dir.display()))?;
        for prefix in entries.flatten() {
            let name = prefix.file_name().to_string_lossy().into_owned();
            if name.len() != 2 || !prefix.path().is_dir() {
                continue;
            }
            let Ok(files) = std::fs::read_dir(prefix.path()) else { continue };
            for f in files.flatten() {
                let sha = f.file_name().to_string_lossy().into_owned();
                let Ok(meta) = f.metadata() else { continue };
                if is_sha256(&sha) && sha.starts_with(&name) && meta.is_file() {
                    found.push((meta.modified().unwrap_or(SystemTime::UNIX_EPOCH), sha, meta.len()));
                }
            }
        }
        found.sort();
        let mut state = State::default();
        for (_, sha, size) in found {
            state.clock += 1;
            state.bytes += size;
            state.files.insert(sha, Known { size, used: state.clock });
        }
        let cache = FileCache {
            dir: dir.to_path_buf(),
            limit: limit_bytes,
            state: Mutex::new(state),
            fetched: Condvar::new(),
            temp_counter: AtomicU64::new(0),
        };
        {
            let mut state = lock(&cache.state);
            cache.evict(&mut state, None);
        }
        Ok(cache)
    }

    /// The directory it keeps its files in.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The bound it was opened with, in bytes.
    pub fn limit_bytes(&self) -> u64 {
        self.limit
    }

    /// What it did and holds.
    pub fn stats(&self) -> FileCacheStats {
        let state = lock(&self.state);
        FileCacheStats { files: state.files.len() as u64, bytes: state.bytes, ..state.stats }
    }

    /// Where the file `sha` is kept.
    pub fn path(&self, sha: &str) -> PathBuf {
        self.dir.join(&sha[..2]).join(sha)
    }

    /// Removes least recently used files until the cache is within its bound, never `keep`.
    fn evict(&self, state: &mut State, keep: Option<&str>) {
        while state.bytes > self.limit {
            let oldest = state
                .files
                .iter()
                .filter(|(sha, _)| Some(sha.as_str()) != keep)
                .min_by_key(|(_, k)| k.used)
                .map(|(sha, _)| sha.clone());
            let Some(sha) = oldest else { break };
            if let Some(k) = state.files.remove(&sha) {
                state.bytes -= k.size;
                state.stats.evictions += 1;
                remove(&self.path(&sha));
            }
        }
    }

    /// The bytes of the file whose SHA-256 is `sha` (64 lowercase hex digits) and whose size
    /// is `size`: from the cache, or else written by `fetch` (a download) into a temporary
    /// file, checked against `size` and `sha`, and kept. A download of other bytes is an error
    /// and leaves nothing behind. When another thread is fetching the same file, this waits
    /// for it instead of downloading it again. A file larger than the whole bound is returned
    /// but not kept.
    pub fn get_or_fetch(
        &self,
        sha: &str,
        size: u64,
        fetch: impl FnOnce(&mut dyn Write) -> Result<()>,
    ) -> Result<Arc<Vec<u8>>> {
        if !is_sha256(sha) {
            bail!("{sha:?} is not a SHA-256 (64 lowercase hex digits)");
        }
        let mut state = lock(&self.state);
        loop {
            if state.files.contains_key(sha) {
                drop(state);
                if let Some(bytes) = self.read_kept(sha, size) {
                    return Ok(bytes);
                }
                state = lock(&self.state);
                continue;
            }
            if !state.fetching.contains(sha) {
                break;
            }
            state = self.fetched.wait(state).unwrap_or_else(|e| e.into_inner());
        }
        state.fetching.insert(sha.to_string());
        drop(state);
        let fetched = self.download(sha, size, fetch);
        let mut state = lock(&self.state);
        state.fetching.remove(sha);
        if fetched.is_ok() {
            state.stats.fetches += 1;
            if size <= self.limit {
                state.clock += 1;
                let used = state.clock;
                if state.files.insert(sha.to_string(), Known { size, used }).is_none() {
                    state.bytes += size;
                }
                self.evict(&mut state, Some(sha));
            } else {
                remove(&self.path(sha));
            }
        }
        self.fetched.notify_all();
        fetched
    }

    /// The kept file `sha`, read and checked, touched as used; `None` (and the file forgotten
    /// and removed) when it is gone or not what its name says (then it is downloaded again).
    fn read_kept(&self, sha: &str, size: u64) -> Option<Arc<Vec<u8>>> {
        let path = self.path(sha);
        let good =
            std::fs::read(&path).ok().filter(|b| b.len() as u64 == size && hex(&Sha256::digest(b)) == sha);
        let mut state = lock(&self.state);
        match good {
            Some(bytes) => {
                state.clock += 1;
                let now = state.clock;
                if let Some(k) = state.files.get_mut(sha) {
                    k.used = now;
                }
                state.stats.hits += 1;
                drop(state);
                // The order of use survives a restart (see `open`).
                if let Ok(f) = std::fs::File::options().write(true).open(&path) {
                    let _ = f.set_modified(SystemTime::now());
                }
                Some(Arc::new(bytes))
            }
            None => {
                if let Some(k) = state.files.remove(sha) {
                    state.bytes -= k.size;
                    remove(&path);
                }
                None
            }
        }
    }

    /// Runs `fetch` into a temporary file, checks what it wrote and renames it into place.
    fn download(
        &self,
        sha: &str,
        size: u64,
        fetch: impl FnOnce(&mut dyn Write) -> Result<()>,
    ) -> Result<Arc<Vec<u8>>> {
        let n = self.temp_counter.fetch_add(1, Ordering::Relaxed);
        let temp = self.dir.join("tmp").join(format!("{sha}.{}.{n}", std::process::id()));
        let written = (|| -> Result<Vec<u8>> {
            let file = std::fs::File::create(&temp)
                .with_context(|| format!("cannot write into the file cache {}", self.dir.display()))?;
            let mut out = Verifying {
                file: std::io::BufWriter::new(file),
                hasher: Sha256::new(),
                bytes: Vec::with_capacity(size.min(1 << 30) as usize),
                expected: size,
                sha,
            };
            fetch(&mut out).with_context(|| format!("downloading file {sha}"))?;
            out.flush().with_context(|| format!("writing file {sha} into the file cache"))?;
            if out.bytes.len() as u64 != size {
                bail!("file {sha}: the download is {} bytes, not the announced {size}", out.bytes.len());
            }
            let actual = hex(&out.hasher.finalize());
            if actual != sha {
                bail!("file {sha}: the download's SHA-256 is {actual}; it is corrupt or not that file");
            }
            let file = out.file.into_inner().map_err(|e| anyhow!("writing file {sha}: {}", e.error()))?;
            file.sync_all().with_context(|| format!("writing file {sha} into the file cache"))?;
            Ok(out.bytes)
        })();
        let bytes = match written {
            Ok(b) => b,
            Err(e) => {
                remove(&temp);
                return Err(e);
            }
        };
        let path = self.path(sha);
        let placed = std::fs::create_dir_all(path.parent().unwrap_or(&self.dir))
            .and_then(|()| std::fs::rename(&temp, &path));
        if let Err(e) = placed {
            remove(&temp);
            return Err(anyhow!("cannot keep file {sha} in the file cache {}: {e}", self.dir.display()));
        }
        Ok(Arc::new(bytes))
    }
}

/// `bytes` as lowercase hex.
fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicUsize;

    fn sha_of(bytes: &[u8]) -> String {
        hex(&Sha256::digest(bytes))
    }

    /// A fetch that writes `bytes` and counts its calls in `calls`.
    fn serve<'a>(bytes: &'a [u8], calls: &'a AtomicUsize) -> impl FnOnce(&mut dyn Write) -> Result<()> + 'a {
        move |w: &mut dyn Write| {
            calls.fetch_add(1, Ordering::SeqCst);
            w.write_all(bytes)?;
            Ok(())
        }
    }

    fn files_in(dir: &Path) -> Vec<PathBuf> {
        let mut out = Vec::new();
        for d in std::fs::read_dir(dir).unwrap().flatten() {
            if d.path().is_dir() {
                out.extend(std::fs::read_dir(d.path()).unwrap().flatten().map(|f| f.path()));
            }
        }
        out
    }

    #[test]
    fn a_file_is_fetched_once_kept_on_disk_and_found_again_after_a_restart() {
        let dir = tessera_testkit::TempDir::new("filecache");
        let calls = AtomicUsize::new(0);
        let data = b"ply\nformat ascii 1.0\n".repeat(10);
        let sha = sha_of(&data);
        let cache = FileCache::open(dir.path(), 1 << 20).unwrap();
        for _ in 0..3 {
            let got = cache.get_or_fetch(&sha, data.len() as u64, serve(&data, &calls)).unwrap();
            assert_eq!(got.as_slice(), data.as_slice());
        }
        assert_eq!(calls.load(Ordering::SeqCst), 1);
        assert_eq!(std::fs::read(cache.path(&sha)).unwrap(), data);
        let s = cache.stats();
        assert_eq!((s.fetches, s.hits, s.files, s.bytes), (1, 2, 1, data.len() as u64));
        drop(cache);
        let again = FileCache::open(dir.path(), 1 << 20).unwrap();
        assert_eq!(again.stats().files, 1);
        again.get_or_fetch(&sha, data.len() as u64, serve(&data, &calls)).unwrap();
        assert_eq!(calls.load(Ordering::SeqCst), 1, "found on disk, not fetched");
        // A file damaged on disk is not served: it is fetched again.
        std::fs::write(again.path(&sha), b"damaged").unwrap();
        let got = again.get_or_fetch(&sha, data.len() as u64, serve(&data, &calls)).unwrap();
        assert_eq!(got.as_slice(), data.as_slice());
        assert_eq!(calls.load(Ordering::SeqCst), 2);
    }

    #[test]
    fn the_least_recently_used_files_go_past_the_bound_also_at_start() {
        let dir = tessera_testkit::TempDir::new("filecache-lru");
        let calls = AtomicUsize::new(0);
        let blobs: Vec<Vec<u8>> = (0..4u8).map(|k| vec![k; 400]).collect();
        let shas: Vec<String> = blobs.iter().map(|b| sha_of(b)).collect();
        // Room for two of them.
        let cache = FileCache::open(dir.path(), 1000).unwrap();
        let get = |k: usize| cache.get_or_fetch(&shas[k], 400, serve(&blobs[k], &calls)).unwrap();
        get(0);
        get(1);
        get(0); // 1 is now the least recently used
        get(2);
        assert!(cache.path(&shas[0]).is_file() && cache.path(&shas[2]).is_file());
        assert!(!cache.path(&shas[1]).exists(), "evicted from disk too");
        let s = cache.stats();
        assert_eq!((s.files, s.bytes, s.evictions), (2, 800, 1));
        // A file over the whole bound is served, not kept.
        let big = vec![9u8; 2000];
        let got = cache.get_or_fetch(&sha_of(&big), 2000, serve(&big, &calls)).unwrap();
        assert_eq!(got.len(), 2000);
        assert!(!cache.path(&sha_of(&big)).exists());
        assert_eq!(files_in(dir.path()).len(), 2, "{:?}", files_in(dir.path()));
        drop(cache);
        // Opened again with a smaller bound: the older of the two goes.
        std::thread::sleep(std::time::Duration::from_millis(20));
        let f =
            std::fs::File::options().write(true).open(dir.path().join(&shas[0][..2]).join(&shas[0])).unwrap();
        f.set_modified(SystemTime::now()).unwrap();
        let small = FileCache::open(dir.path(), 500).unwrap();
        assert_eq!(small.stats().files, 1);
        assert!(small.path(&shas[0]).is_file() && !small.path(&shas[2]).exists());
    }

    #[test]
    fn a_corrupt_short_long_or_failed_download_is_refused_and_leaves_nothing() {
        let dir = tessera_testkit::TempDir::new("filecache-corrupt");
        let calls = AtomicUsize::new(0);
        let cache = FileCache::open(dir.path(), 1 << 20).unwrap();
        let good = b"the right bytes".to_vec();
        let sha = sha_of(&good);
        let n = good.len() as u64;
        let e = cache.get_or_fetch(&sha, n, serve(b"the wrong bytes", &calls)).unwrap_err();
        assert!(format!("{e:#}").contains("corrupt"), "{e:#}");
        let e = cache.get_or_fetch(&sha, n, serve(b"the right", &calls)).unwrap_err();
        assert!(format!("{e:#}").contains("not the announced"), "{e:#}");
        let e = cache.get_or_fetch(&sha, n, serve(b"the right bytes and more", &calls)).unwrap_err();
        assert!(format!("{e:#}").contains("longer than"), "{e:#}");
        let e = cache
            .get_or_fetch(&sha, n, |w: &mut dyn Write| {
                w.write_all(b"the ri")?;
                Err(anyhow!("connection reset"))
            })
            .unwrap_err();
        assert!(format!("{e:#}").contains("connection reset"), "{e:#}");
        assert!(files_in(dir.path()).is_empty(), "{:?}", files_in(dir.path()));
        assert_eq!(std::fs::read_dir(dir.path().join("tmp")).unwrap().count(), 0);
        assert_eq!(cache.stats().files, 0);
        let e = cache.get_or_fetch("../etc/passwd", 1, serve(b"x", &calls)).unwrap_err();
        assert!(e.to_string().contains("not a SHA-256"), "{e}");
        // The right bytes then are kept.
        cache.get_or_fetch(&sha, n, serve(&good, &calls)).unwrap();
        assert_eq!(cache.stats().files, 1);
        // A half download left by a killed process is removed at start.
        std::fs::write(dir.path().join("tmp").join(format!("{sha}.1.0")), b"half").unwrap();
        drop(cache);
        FileCache::open(dir.path(), 1 << 20).unwrap();
        assert_eq!(std::fs::read_dir(dir.path().join("tmp")).unwrap().count(), 0);
    }

    #[test]
    fn concurrent_requests_for_one_file_fetch_it_once() {
        let dir = tessera_testkit::TempDir::new("filecache-concurrent");
        let cache = FileCache::open(dir.path(), 1 << 20).unwrap();
        let data: Vec<u8> = (0..100_000u32).map(|k| (k % 251) as u8).collect();
        let sha = sha_of(&data);
        let calls = AtomicUsize::new(0);
        std::thread::scope(|s| {
            let handles: Vec<_> = (0..8)
                .map(|_| {
                    s.spawn(|| {
                        cache.get_or_fetch(&sha, data.len() as u64, |w: &mut dyn Write| {
                            calls.fetch_add(1, Ordering::SeqCst);
                            // Slow enough that the others ask while it runs.
                            for chunk in data.chunks(10_000) {
                                std::thread::sleep(std::time::Duration::from_millis(5));
                                w.write_all(chunk)?;
                            }
                            Ok(())
                        })
                    })
                })
                .collect();
            for h in handles {
                assert_eq!(h.join().unwrap().unwrap().as_slice(), data.as_slice());
            }
        });
        assert_eq!(calls.load(Ordering::SeqCst), 1);
        assert_eq!(cache.stats().hits, 7);
    }
}
