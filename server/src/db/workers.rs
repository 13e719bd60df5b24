//! Workers in the store: registration (bounded by a cap on live workers), the secrets that
//! authenticate them, the list the API shows, and forgetting those long gone.

use super::*;

/// Deletes up to `limit` rows of workers not seen since `before` and holding no live lease,
/// oldest first. The worker of the highest id stays: ids are never handed out again (a new row
/// takes the highest id + 1), so an id in a log or a tile failure always means one worker.
fn forget(tx: &rusqlite::Transaction<'_>, before: f64, limit: i64) -> Result<usize> {
    Ok(tx.execute_cached(
        "DELETE FROM workers WHERE id IN (
           SELECT w.id FROM workers w
           WHERE w.last_seen < ?1 AND w.id < (SELECT max(id) FROM workers)
             AND NOT EXISTS (SELECT 1 FROM tiles t WHERE t.state = 'leased' AND t.worker_id = w.id)
           ORDER BY w.last_seen LIMIT ?2)",
        params![before, limit],
    )?)
}

impl Store {
    /// Registers a worker; `secret_hash` is the SHA-256 (hex) of the secret it was given, which
    /// every later call of that worker must present ([`Store::worker_secret_hash`]).
    pub fn register_worker(&self, name: &str, threads: u32, secret_hash: &str) -> Result<u64> {
        let conn = self.conn();
        let t = now();
        conn.execute_cached(
            "INSERT INTO workers(name, threads, registered_at, last_seen, secret_hash) VALUES (?1, ?2, ?3, ?3, ?4)",
            params![name, threads, t, secret_hash],
        )?;
        Ok(conn.last_insert_rowid() as u64)
    }

    /// The hash of a worker's secret: `None` when there is no such worker, `Some(None)` for a
    /// worker registered before secrets existed (it must register again).
    pub fn worker_secret_hash(&self, id: u64) -> Result<Option<Option<String>>> {
        let conn = self.conn();
        let id = i64::try_from(id).unwrap_or(-1);
        Ok(conn
            .query_row_cached("SELECT secret_hash FROM workers WHERE id = ?1", [id], |r| r.get(0))
            .optional()?)
    }

    pub fn workers(&self) -> Result<Vec<WorkerRow>> {
        let conn = self.conn();
        let mut stmt = conn.prepare_cached(
            "SELECT w.id, w.name, w.threads, w.registered_at, w.last_seen, w.tiles_done, w.failures, w.rendering, t.job_id, t.frame, t.tile, w.mode
             FROM workers w LEFT JOIN tiles t ON t.lease_id = w.rendering ORDER BY w.id",
        )?;
        let rows = stmt
            .query_map([], |r| {
                let job: Option<i64> = r.get(8)?;
                Ok(WorkerRow {
                    id: r.get::<_, i64>(0)? as u64,
                    name: r.get(1)?,
                    threads: r.get::<_, i64>(2)? as u32,
                    registered_at: r.get(3)?,
                    last_seen: r.get(4)?,
                    tiles_done: r.get::<_, i64>(5)? as u64,
                    failures: r.get::<_, i64>(6)? as u64,
                    rendering: r.get::<_, Option<i64>>(7)?.map(|x| x as u64),
                    current_tile: match job {
                        Some(j) => Some((j as u64, r.get::<_, i64>(9)? as u32, r.get::<_, i64>(10)? as u32)),
                        None => None,
                    },
                    mode: WorkerMode::parse(&r.get::<_, String>(11)?).unwrap_or(WorkerMode::Active),
                })
            })?
            .collect::<rusqlite::Result<Vec<_>>>()?;
        Ok(rows)
    }

    /// Registers a worker unless `max_live` workers are live already (seen since `live_since`):
    /// then [`Registered::Full`]. Past `max_live` rows, lost workers (not seen since
    /// `live_since`) without a live lease are forgotten, oldest first, so that the table holds
    /// about `max_live` rows whatever registers. `max_live: None` (the server's own local
    /// workers) registers whatever the count.
    pub fn register_worker_within(
        &self,
        name: &str,
        threads: u32,
        secret_hash: &str,
        max_live: Option<u64>,
        live_since: f64,
    ) -> Result<Registered> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        if let Some(max) = max_live {
            let live: i64 = tx.query_row_cached(
                "SELECT count(*) FROM workers WHERE last_seen >= ?1",
                [live_since],
                |r| r.get(0),
            )?;
            if live as u64 >= max {
                return Ok(Registered::Full { live: live as u64 });
            }
        }
        let t = now();
        tx.execute_cached(
            "INSERT INTO workers(name, threads, registered_at, last_seen, secret_hash) VALUES (?1, ?2, ?3, ?3, ?4)",
            params![name, threads, t, secret_hash],
        )?;
        let id = tx.last_insert_rowid() as u64;
        if let Some(max) = max_live {
            let rows: i64 = tx.query_row_cached("SELECT count(*) FROM workers", [], |r| r.get(0))?;
            let over = rows - i64::try_from(max).unwrap_or(i64::MAX);
            if over > 0 {
                forget(&tx, live_since, over)?;
            }
        }
        tx.commit()?;
        Ok(Registered::Id(id))
    }

    /// Sets whether worker `id` takes new work; `None` when there is no such worker. Disabling
    /// also queues again every tile it holds (its next heartbeat learns they are no longer its
    /// own, and it stops rendering them); draining leaves them to finish.
    pub fn set_worker_mode(&self, id: u64, mode: WorkerMode) -> Result<Option<usize>> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        let id = i64::try_from(id).unwrap_or(-1);
        if tx.execute("UPDATE workers SET mode = ?2 WHERE id = ?1", params![id, mode.as_str()])? == 0 {
            return Ok(None);
        }
        let mut requeued = 0;
        if mode == WorkerMode::Disabled {
            requeued = tx.execute(
                "UPDATE tiles SET state = 'queued', lease_id = NULL, worker_id = NULL, deadline = NULL
                 WHERE worker_id = ?1 AND state = 'leased'",
                [id],
            )?;
            tx.execute("UPDATE workers SET rendering = NULL WHERE id = ?1", [id])?;
        }
        tx.commit()?;
        Ok(Some(requeued))
    }

    /// Whether worker `id` takes new work (an unknown worker: active, as registration decides).
    pub fn worker_mode(&self, id: u64) -> Result<WorkerMode> {
        let conn = self.conn();
        let mode: Option<String> = conn
            .query_row_cached(
                "SELECT mode FROM workers WHERE id = ?1",
                [i64::try_from(id).unwrap_or(-1)],
                |r| r.get(0),
            )
            .optional()?;
        Ok(mode.and_then(|m| WorkerMode::parse(&m)).unwrap_or(WorkerMode::Active))
    }

    /// Forgets workers not seen since `before` that hold no live lease: their rows go (a worker
    /// that comes back gets a 404 and registers again); the job logs keep their names. Returns
    /// how many went.
    pub fn forget_workers(&self, before: f64) -> Result<usize> {
        let mut total = 0;
        loop {
            let mut conn = self.conn();
            let tx = conn.transaction()?;
            let n = forget(&tx, before, ROWS_PER_STEP as i64)?;
            tx.commit()?;
            drop(conn);
            total += n;
            if n < ROWS_PER_STEP {
                return Ok(total);
            }
            std::thread::sleep(STEP_PAUSE);
        }
    }
}
