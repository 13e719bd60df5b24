//! Large tile results as files of their own: a tile of at least [`FILE_RESULT_BYTES`] (a
//! sequence's whole-frame unit is 7.7 MB of floats at 800x800) is written to
//! `results/LEASE-PID-K.f32` in the data directory (atomically, synced) before its row, which
//! names the file (`tiles.pixels_file`), commits. Kept in the database, such a result was written
//! into the write-ahead log, copied into the database file by the next checkpoint, read back
//! page by page by the merge and its pages freed: several copies of every frame.
//!
//! A file is removed when its row lets go of it (the frame merged, the tile's rows purged or
//! queued again); a file no row names (a stop between the two) is removed by [`Store::sweep_results`]
//! at startup and, once older than a grace period, by the housekeeping's sweep.

use std::path::{Path, PathBuf};
use std::time::Duration;

use super::*;

/// The data directory's folder of result files.
pub const RESULTS_DIR: &str = "results";

/// Results of at least this many bytes are files; smaller ones (tiles of a large frame, a few
/// kB to a few hundred) stay rows, one commit each without a sync of their own.
pub const FILE_RESULT_BYTES: usize = 1 << 20;

/// How old a result file no row names must be before the housekeeping's sweep removes it: a
/// file is written just before its row commits.
pub const RESULT_GRACE: Duration = Duration::from_secs(600);

/// A tile's result as [`Store::submit_result`] takes it.
#[derive(Clone, Copy)]
pub enum ResultBody<'a> {
    /// The bytes, kept in the row.
    Bytes(&'a [u8]),
    /// Written already as this file of [`RESULTS_DIR`] ([`Store::write_result_file`]), of
    /// `len` bytes.
    File { name: &'a str, len: usize },
}

impl ResultBody<'_> {
    /// The result's size in bytes.
    pub fn size(&self) -> usize {
        match self {
            ResultBody::Bytes(b) => b.len(),
            ResultBody::File { len, .. } => *len,
        }
    }
}

/// A new name for a result file of lease `lease`: `LEASE-PID-K.f32`, a name of each upload's own,
/// so that an upload refused (a worker's retry of a result accepted meanwhile) removes its own
/// file and never the one the accepted result's row names.
pub fn result_file_name(lease: u64) -> String {
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let k = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    format!("{lease}-{}-{k}.f32", std::process::id())
}

/// The lease a result file's name is for (`None`: not such a name).
fn lease_of(name: &str) -> Option<i64> {
    let (lease, _) = name.strip_suffix(".f32")?.split_once('-')?;
    lease.parse::<u64>().ok().and_then(|l| i64::try_from(l).ok())
}

impl Store {
    /// Where result files are (`results/` beside the database).
    pub fn results_dir(&self) -> &Path {
        &self.results_dir
    }

    /// Writes the result of lease `lease` as its file (a synced temporary file renamed into
    /// place, so a stop never leaves half a result under its name); returns the name.
    pub fn write_result_file(&self, lease: u64, bytes: &[u8]) -> Result<String> {
        std::fs::create_dir_all(&self.results_dir)
            .with_context(|| format!("cannot create {}", self.results_dir.display()))?;
        let name = result_file_name(lease);
        tessera::atomic_write::write_atomic(&self.results_dir.join(&name), bytes)
            .context("cannot write the tile's result")?;
        Ok(name)
    }

    /// Removes result files whose rows let go of them (missing ones are no error).
    pub fn remove_result_files(&self, names: &[String]) {
        for name in names {
            let _ = std::fs::remove_file(self.results_dir.join(name));
        }
    }

    /// Reads the pixels of a row: its bytes, or its result file.
    pub(super) fn read_result(&self, bytes: Option<Vec<u8>>, file: Option<String>) -> Result<Vec<u8>> {
        match (bytes, file) {
            (Some(b), _) => Ok(b),
            (None, Some(name)) => {
                let path: PathBuf = self.results_dir.join(&name);
                std::fs::read(&path)
                    .with_context(|| format!("cannot read the tile result {}", path.display()))
            }
            (None, None) => anyhow::bail!("a tile's result has neither bytes nor a file"),
        }
    }

    /// Removes the result files (and writers' temporaries) no tile row names; at startup
    /// (`grace` zero, nothing being written) and from the housekeeping (files older than
    /// `grace` only: one being uploaded is written before its row). Returns how many went.
    pub fn sweep_results(&self, grace: Duration) -> Result<usize> {
        let Ok(entries) = std::fs::read_dir(&self.results_dir) else { return Ok(0) };
        let mut removed = 0;
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let young = || {
                e.metadata().and_then(|m| m.modified()).is_ok_and(|t| t.elapsed().unwrap_or_default() < grace)
            };
            if grace > Duration::ZERO && young() {
                continue;
            }
            let named = match lease_of(&name) {
                Some(lease) => self
                    .conn()
                    .query_row_cached(
                        "SELECT 1 FROM tiles WHERE lease_id = ?1 AND pixels_file = ?2",
                        params![lease, name],
                        |_| Ok(()),
                    )
                    .optional()?
                    .is_some(),
                None => false,
            };
            if !named && std::fs::remove_file(e.path()).is_ok() {
                removed += 1;
            }
        }
        Ok(removed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{frame, job_of, store};

    /// A result file is named by its row until the frame is merged, then removed; one no row
    /// names (a stop between the file and its row) is swept, and a purge takes the files of
    /// the rows it deletes.
    #[test]
    fn a_result_file_lives_as_long_as_its_row_names_it() {
        let (_d, s) = store("result-files");
        let j = s.insert_job(&job_of(vec![frame("a.png", 2, 1), frame("b.png", 2, 1)])).unwrap();
        let w = s.register_worker("w", 4, "").unwrap();
        let lease = || s.lease(w, 60.0).unwrap().granted().expect("a lease").lease_id;
        let bytes: Vec<u8> = (0..24).collect();
        let (first, second) = (lease(), lease());
        let name = s.write_result_file(first, &bytes).unwrap();
        let body = ResultBody::File { name: &name, len: bytes.len() };
        assert!(matches!(s.submit_result_as(first, w, body, None).unwrap(), ResultOutcome::Accepted { .. }));
        assert_eq!(s.frame_tiles(j, 0).unwrap()[0].1, bytes);
        assert_eq!(s.tile_pixels(j, 0, 0).unwrap(), Some(bytes.clone()));
        // An unnamed file (its row never committed) is swept; a named one stays.
        let stray = s.write_result_file(second + 1000, b"x").unwrap();
        assert_eq!(s.sweep_results(RESULT_GRACE).unwrap(), 0, "a young file is left to its upload");
        assert_eq!(s.sweep_results(Duration::ZERO).unwrap(), 1);
        assert!(!s.results_dir().join(&stray).exists() && s.results_dir().join(&name).exists());
        // A wrong size is refused whatever holds the bytes.
        let short = ResultBody::File { name: "x.f32", len: 12 };
        assert!(matches!(
            s.submit_result_as(second, w, short, None).unwrap(),
            ResultOutcome::WrongSize { .. }
        ));
        s.frame_merged(j, 0, &["a.png".into()], Default::default()).unwrap();
        assert!(!s.results_dir().join(&name).exists(), "the merged frame's file stays");
        // A cancelled job's purge takes the files of its rows.
        let other = s.write_result_file(second, &bytes).unwrap();
        let body = ResultBody::File { name: &other, len: bytes.len() };
        assert!(matches!(s.submit_result_as(second, w, body, None).unwrap(), ResultOutcome::Accepted { .. }));
        s.cancel_job(j).unwrap();
        while s.purge_job_rows(j, 1).unwrap() > 0 {}
        assert!(!s.results_dir().join(&other).exists(), "a purged row's file stays");
    }
}
