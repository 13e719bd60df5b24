//! Jobs' files in the store: which files of the file store (`crate::files`) and which tar
//! bundles a job still names, and a finished job deleted with every row it has.

use std::collections::HashSet;

use super::*;

/// The highest id of a deleted job, in a one-row table: a new job never takes the id of a
/// deleted one (whose folders are gone, so `storage::highest_job_folder` no longer sees it).
const FILES_SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS deleted_jobs(
    id INTEGER PRIMARY KEY CHECK (id = 1),
    highest INTEGER NOT NULL
);
";

/// Creates the table of deleted job ids; returns the highest id deleted (0 if none).
pub(super) fn create(conn: &Connection) -> Result<u64> {
    conn.execute_batch(FILES_SCHEMA)?;
    let highest: Option<i64> =
        conn.query_row("SELECT highest FROM deleted_jobs WHERE id = 1", [], |r| r.get(0)).optional()?;
    Ok(highest.unwrap_or(0).max(0) as u64)
}

/// What [`Store::delete_job`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Deleted {
    /// There is no such job.
    NoSuchJob,
    /// The job is queued or running: it must be cancelled first.
    NotFinal(JobState),
    /// The job and its rows (this many, over every table) are gone.
    Gone { rows: usize },
}

/// The members of `keys` that `sql` (with one `?N` per key, `{}` standing for them) finds.
fn present(conn: &Connection, sql: &str, keys: &[&str]) -> Result<HashSet<String>> {
    let mut found = HashSet::new();
    for chunk in keys.chunks(500) {
        let marks = (1..=chunk.len()).map(|i| format!("?{i}")).collect::<Vec<_>>().join(", ");
        let mut stmt = conn.prepare(&sql.replace("{}", &marks))?;
        let rows = stmt.query_map(rusqlite::params_from_iter(chunk.iter()), |r| r.get::<_, String>(0))?;
        for r in rows {
            found.insert(r?);
        }
    }
    Ok(found)
}

impl Store {
    /// Which of the file store's files `shas` a job names: a `job_files` row of any job, or a
    /// job's `manifest`.
    pub fn referenced_files(&self, shas: &[&str]) -> Result<HashSet<String>> {
        let conn = self.conn();
        let mut named = present(&conn, "SELECT DISTINCT sha256 FROM job_files WHERE sha256 IN ({})", shas)?;
        named.extend(present(&conn, "SELECT DISTINCT manifest FROM jobs WHERE manifest IN ({})", shas)?);
        Ok(named)
    }

    /// Which of the tar bundles `hashes` a job names (`jobs.bundle`).
    pub fn referenced_bundles(&self, hashes: &[&str]) -> Result<HashSet<String>> {
        present(&self.conn(), "SELECT DISTINCT bundle FROM jobs WHERE bundle IN ({})", hashes)
    }

    /// Deletes job `id` if it is finished (done, failed or cancelled): its rows in `tiles`,
    /// `tile_failures`, `job_events`, `frames`, `job_files` and `jobs`. A job of a million tile
    /// rows is deleted [`ROWS_PER_STEP`] rows to a transaction, the store's lock let go between
    /// two; the job's own row goes last, so a stop half-way leaves a finished job with fewer rows,
    /// which deleting again finishes. Its id is never
    /// handed out again. Its folders on disk are the caller's (`api::jobs::delete_job`).
    pub fn delete_job(&self, id: u64) -> Result<Deleted> {
        let Ok(key) = i64::try_from(id) else { return Ok(Deleted::NoSuchJob) };
        {
            let mut conn = self.conn();
            let tx = conn.transaction()?;
            let state: Option<String> = tx
                .query_row_cached(
                    "SELECT state FROM jobs WHERE id = ?1 AND state != 'inserting'",
                    [key],
                    |r| r.get(0),
                )
                .optional()?;
            let Some(state) = state else { return Ok(Deleted::NoSuchJob) };
            let state =
                JobState::parse(&state).ok_or_else(|| anyhow::anyhow!("job {id} has state {state}"))?;
            if !state.is_final() {
                return Ok(Deleted::NotFinal(state));
            }
            if self.is_requeueing(id) {
                // Its frames are being queued again: it is about to be.
                return Ok(Deleted::NotFinal(JobState::Queued));
            }
            tx.execute_cached(
                "INSERT INTO deleted_jobs(id, highest) VALUES (1, ?1)
                 ON CONFLICT(id) DO UPDATE SET highest = max(highest, excluded.highest)",
                [key],
            )?;
            tx.commit()?;
        }
        self.keep_job_ids_above(id);
        let mut rows = 0;
        for table in ["tiles", "tile_failures", "job_events", "frames", "job_files"] {
            loop {
                let n = {
                    let conn = self.conn();
                    // `job_events` and `job_files` are WITHOUT ROWID: deleted by their key.
                    let sql = match table {
                        "job_events" => "DELETE FROM job_events WHERE job_id = ?1 AND seq IN (
                             SELECT seq FROM job_events WHERE job_id = ?1 LIMIT ?2)"
                            .to_string(),
                        "job_files" => "DELETE FROM job_files WHERE job_id = ?1 AND path IN (
                             SELECT path FROM job_files WHERE job_id = ?1 LIMIT ?2)"
                            .to_string(),
                        t => format!(
                            "DELETE FROM {t} WHERE rowid IN (SELECT rowid FROM {t} WHERE job_id = ?1 LIMIT ?2)"
                        ),
                    };
                    conn.execute_cached(&sql, params![key, ROWS_PER_STEP as i64])?
                };
                rows += n;
                if n < ROWS_PER_STEP {
                    break;
                }
                std::thread::sleep(STEP_PAUSE);
            }
        }
        rows += self.conn().execute_cached("DELETE FROM job_videos WHERE job_id = ?1", [key])?;
        rows += self.conn().execute_cached("DELETE FROM jobs WHERE id = ?1", [key])?;
        Ok(Deleted::Gone { rows })
    }

    /// Job `id` names the file `sha256` (a `job_files` row), for tests outside the store.
    #[cfg(test)]
    pub(crate) fn set_job_files_for_test(&self, id: u64, sha256: &str) {
        self.conn()
            .execute(
                "INSERT INTO job_files(job_id, path, sha256, size) VALUES (?1, 'f', ?2, 0)",
                params![id as i64, sha256],
            )
            .unwrap();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{job_of, row_of_pixels};

    /// A job of one frame of `tiles` one-pixel tiles, naming the bundle `bundle`.
    fn job(s: &Store, tiles: u32, bundle: &str) -> u64 {
        let frame = row_of_pixels("j.png", tiles, 1);
        let job = NewJob {
            bundle: bundle.into(),
            scene_path: "scene.json".into(),
            warnings: vec!["w".into()],
            ..job_of(vec![frame])
        };
        s.insert_job(&job).unwrap()
    }

    fn count(s: &Store, table: &str, id: u64) -> i64 {
        let column = if table == "jobs" { "id" } else { "job_id" };
        s.conn()
            .query_row(&format!("SELECT count(*) FROM {table} WHERE {column} = ?1"), [id as i64], |r| {
                r.get(0)
            })
            .unwrap()
    }

    /// A file is named while a job's `job_files` row or manifest names it; a bundle while a
    /// job's `bundle` does.
    #[test]
    fn files_and_bundles_are_named_by_jobs() {
        let (_dir, s) = crate::testutil::store("files-named");
        let (a, b, m, t) = ("a".repeat(64), "b".repeat(64), "c".repeat(64), "d".repeat(64));
        let id = job(&s, 1, &t);
        s.conn()
            .execute(
                "INSERT INTO job_files(job_id, path, sha256, size) VALUES (?1, 'x.ply', ?2, 3)",
                params![id as i64, a],
            )
            .unwrap();
        s.conn().execute("UPDATE jobs SET manifest = ?2 WHERE id = ?1", params![id as i64, m]).unwrap();
        let named = s.referenced_files(&[&a, &b, &m]).unwrap();
        assert_eq!(named, [a.clone(), m.clone()].into_iter().collect());
        assert_eq!(s.referenced_bundles(&[&t, &b]).unwrap(), [t.clone()].into_iter().collect());
        // Once the job is gone, nothing names them.
        assert!(s.cancel_job(id).unwrap());
        assert!(matches!(s.delete_job(id).unwrap(), Deleted::Gone { .. }));
        assert!(s.referenced_files(&[&a, &m]).unwrap().is_empty());
        assert!(s.referenced_bundles(&[&t]).unwrap().is_empty());
    }

    /// A queued job is refused; a finished one goes with every row of every table, its id
    /// never handed out again, across a restart too.
    #[test]
    fn only_a_finished_job_is_deleted_with_all_its_rows_and_its_id_stays_taken() {
        let dir = tessera_testkit::TempDir::new("unit-files-delete");
        let s = Store::open(&dir.join("t.db")).unwrap();
        let keep = job(&s, 3, "");
        let id = job(&s, ROWS_PER_STEP as u32 + 5, "");
        assert_eq!(s.delete_job(id).unwrap(), Deleted::NotFinal(JobState::Queued));
        assert_eq!(s.delete_job(999).unwrap(), Deleted::NoSuchJob);
        s.conn()
            .execute(
                "INSERT INTO job_files(job_id, path, sha256, size) VALUES (?1, 'x.ply', ?2, 3)",
                params![id as i64, "a".repeat(64)],
            )
            .unwrap();
        assert!(s.cancel_job(id).unwrap());
        let Deleted::Gone { rows } = s.delete_job(id).unwrap() else { panic!("not deleted") };
        assert!(rows > ROWS_PER_STEP + 5, "{rows}");
        for table in ["jobs", "frames", "tiles", "job_events", "job_files", "tile_failures"] {
            assert_eq!(count(&s, table, id), 0, "{table}");
        }
        assert!(s.job(id).unwrap().is_none());
        assert_eq!(count(&s, "tiles", keep), 3, "another job's rows stay");
        assert_eq!(s.delete_job(id).unwrap(), Deleted::NoSuchJob);
        // The job of the highest id went: a restarted store still never hands its id out.
        drop(s);
        let s = Store::open(&dir.join("t.db")).unwrap();
        assert_eq!(job(&s, 1, ""), id + 1, "a deleted job's id is never handed out again");
    }
}
