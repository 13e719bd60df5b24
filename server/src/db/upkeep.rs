//! Keeping the store small: the rows of ended jobs purged a step at a time, their pages given
//! back to the file system, and the write-ahead log copied off the store's lock.

use super::*;

impl Store {
    /// Cancelled and failed jobs that still have rows to purge ([`Store::purge_job_rows`]).
    pub fn ended_jobs_with_rows(&self) -> Result<Vec<u64>> {
        let conn = self.conn();
        let mut stmt = conn.prepare_cached(
            "SELECT j.id FROM jobs j WHERE j.state IN ('canceled', 'failed')
               AND (EXISTS (SELECT 1 FROM tiles t WHERE t.job_id = j.id)
                    OR EXISTS (SELECT 1 FROM tile_failures x WHERE x.job_id = j.id))
             ORDER BY j.id",
        )?;
        let rows =
            stmt.query_map([], |r| Ok(r.get::<_, i64>(0)? as u64))?.collect::<rusqlite::Result<_>>()?;
        Ok(rows)
    }

    /// Deletes up to `limit` rows that job `job`, cancelled or failed, no longer needs: its tile
    /// rows (with their pixels and sums) and its tile failures. What the API shows of such a
    /// job (tiles done per frame, outputs, error, log) is in its frame, job and event rows,
    /// which stay. A failed job keeps the tiles of a frame that has every tile but was not
    /// merged: they are its pixels. Returns how many rows went (0: none left).
    pub fn purge_job_rows(&self, job: u64, limit: usize) -> Result<usize> {
        if self.is_requeueing(job) {
            return Ok(0);
        }
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        let state: Option<String> = tx
            .query_row_cached("SELECT state FROM jobs WHERE id = ?1", [job as i64], |r| r.get(0))
            .optional()?;
        let Some(state) = state.filter(|s| s == "canceled" || s == "failed") else { return Ok(0) };
        let limit = limit as i64;
        // Each deleted row's result file, if it has one: removed once this commits.
        let files: Vec<Option<String>> = tx
            .prepare_cached(
                "DELETE FROM tiles WHERE rowid IN (
                   SELECT rowid FROM tiles WHERE job_id = ?1 AND frame IN (
                     SELECT idx FROM frames WHERE job_id = ?1
                       AND (?3 = 'canceled' OR outputs IS NOT NULL OR tiles_done < tiles_total))
                   LIMIT ?2)
                 RETURNING pixels_file",
            )?
            .query_map(params![job as i64, limit, state], |r| r.get(0))?
            .collect::<rusqlite::Result<_>>()?;
        let tiles = files.len();
        let failures = tx.execute_cached(
            "DELETE FROM tile_failures WHERE rowid IN (SELECT rowid FROM tile_failures WHERE job_id = ?1 LIMIT ?2)",
            params![job as i64, limit - tiles as i64],
        )?;
        tx.commit()?;
        drop(conn);
        self.remove_result_files(&files.into_iter().flatten().collect::<Vec<_>>());
        Ok(tiles + failures)
    }

    /// Gives up to `pages` free pages (of deleted rows) back to the file system, on a database
    /// created with incremental auto-vacuum; returns the free pages left (0 on an older
    /// database, which reuses them for new rows instead).
    pub fn release_free_pages(&self, pages: u32) -> Result<u64> {
        let conn = self.conn();
        let mode: i64 = conn.pragma_query_value(None, "auto_vacuum", |r| r.get(0))?;
        if mode != 2 {
            return Ok(0);
        }
        // Each step of the statement frees one page.
        let mut stmt = conn.prepare(&format!("PRAGMA incremental_vacuum({pages})"))?;
        let mut rows = stmt.query([])?;
        while rows.next()?.is_some() {}
        drop(rows);
        drop(stmt);
        Ok(conn.pragma_query_value(None, "freelist_count", |r| r.get::<_, i64>(0))? as u64)
    }

    /// Copies what the write-ahead log holds into the database file (which shrinks then if
    /// pages were released), on a connection of its own: the store's lock stays free, and
    /// writers go on meanwhile. Returns the log's frames not copied yet. Run every
    /// [`CHECKPOINT_EVERY`] by the server (`housekeeping::spawn_checkpoints`).
    pub fn checkpoint(&self) -> Result<u64> {
        let conn = self.checkpointer.lock().unwrap_or_else(|e| e.into_inner());
        let (log, copied): (i64, i64) =
            conn.query_row("PRAGMA wal_checkpoint(PASSIVE)", [], |r| Ok((r.get(1)?, r.get(2)?)))?;
        Ok((log - copied).max(0) as u64)
    }

    /// Copies the whole write-ahead log into the database file so that the next transaction
    /// starts the log over: most of it outside the store's lock, then, under it, the little
    /// written meanwhile. A long insertion or purge calls this every [`CHECKPOINT_STEPS`]: a
    /// log that is never wholly copied (another request always writing after the copy) would
    /// otherwise grow by the whole job.
    pub fn checkpoint_to_start_over(&self) -> Result<()> {
        self.checkpoint()?;
        let _quiet = self.conn();
        self.checkpoint()?;
        Ok(())
    }
}
