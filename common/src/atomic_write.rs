//! Writing a file in place without ever showing half of it: [`write_atomic`].
//!
//! Every file Tessera writes (a camera's outputs, the CLI's tone-mapped PNG, the server's bundle
//! blobs and merged frames) goes through it: the bytes go to a temporary file of the writer's
//! own beside the target ([`unique_temp_name`]), are synced, and the temporary file is renamed
//! over the target, which replaces it atomically. Readers see the old file or the new one; a
//! crash leaves at most a temporary file (`.<name>.<pid>-<n>-<nanos>.tmp`), never a truncated
//! file under the final name; any number of concurrent writers of one file each rename their
//! own complete copy.

use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// The step of [`write_atomic`] that failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WriteStep {
    /// Creating the temporary file (e.g. the folder does not exist or is read-only).
    Create,
    /// Writing or syncing the bytes.
    Write,
    /// Renaming the temporary file over the target.
    Rename,
}

impl WriteStep {
    /// "cannot create", "cannot write" or "cannot move into place".
    pub fn action(self) -> &'static str {
        match self {
            WriteStep::Create => "cannot create",
            WriteStep::Write => "cannot write",
            WriteStep::Rename => "cannot move into place",
        }
    }
}

/// Why [`write_atomic`] failed: the file, the step and the operating system's reason.
#[derive(Debug, thiserror::Error)]
#[error("{}: {}: {error}", path.display(), step.action())]
pub struct WriteError {
    /// The file that was to be written (not the temporary one).
    pub path: PathBuf,
    pub step: WriteStep,
    /// The operating system's reason (shown in the message, so not also a `source()`).
    pub error: io::Error,
}

/// A name beside `path` that no other writer in this or any other process uses: the process
/// id, a per-process counter and the clock. Concurrent writers of one file each get their own.
/// The name starts with `.` and ends with `.tmp`.
pub fn unique_temp_name(path: &Path) -> PathBuf {
    // The counter only keeps names apart; it never reaches anything rendered.
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos())
        .unwrap_or(0);
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.{}-{n}-{nanos}.tmp", std::process::id()))
}

/// Writes `bytes` to `path` through a synced temporary file of its own and a rename (which
/// replaces an existing file atomically), so readers see the old or the new file, never half
/// of one, and concurrent writers never trip over each other's temporary files. On failure
/// the temporary file is removed.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), WriteError> {
    let tmp = unique_temp_name(path);
    let fail = |step| move |error| WriteError { path: path.to_path_buf(), step, error };
    let write = || -> Result<(), WriteError> {
        let mut f = std::fs::File::create(&tmp).map_err(fail(WriteStep::Create))?;
        f.write_all(bytes).map_err(fail(WriteStep::Write))?;
        f.sync_all().map_err(fail(WriteStep::Write))?;
        drop(f);
        std::fs::rename(&tmp, path).map_err(fail(WriteStep::Rename))
    };
    let result = write();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replaces_the_file_and_leaves_no_temporary_file() {
        let dir = tessera_testkit::TempDir::new("atomic-write");
        let path = dir.join("a.bin");
        write_atomic(&path, b"first").unwrap();
        write_atomic(&path, b"second").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"second");
        let names: Vec<_> = std::fs::read_dir(&*dir).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names, ["a.bin"]);
    }

    #[test]
    fn a_missing_folder_is_an_error_naming_the_file_and_the_step() {
        let dir = tessera_testkit::TempDir::new("atomic-write-missing");
        let path = dir.join("no/such/out.png");
        let e = write_atomic(&path, b"x").unwrap_err();
        assert_eq!((e.path.as_path(), e.step), (path.as_path(), WriteStep::Create));
        let msg = e.to_string();
        assert!(msg.contains("out.png: cannot create: "), "{msg}");
    }

    #[test]
    fn temporary_names_differ_and_stay_beside_the_file() {
        let a = unique_temp_name(Path::new("/d/x.tar"));
        let b = unique_temp_name(Path::new("/d/x.tar"));
        assert_ne!(a, b);
        assert_eq!(a.parent(), Some(Path::new("/d")));
        let name = a.file_name().unwrap().to_string_lossy().into_owned();
        assert!(name.starts_with(".x.tar.") && name.ends_with(".tmp"), "{name}");
    }
}
