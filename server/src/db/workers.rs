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

/// Tags as the store keeps them: comma-joined (checked tags hold no comma), `NULL` for none.
pub(crate) fn tags_to_text(tags: &[String]) -> Option<String> {
    (!tags.is_empty()).then(|| tags.join(","))
}

/// [`tags_to_text`] read back.
pub(crate) fn tags_from_text(text: Option<String>) -> Vec<String> {
    text.map(|t| t.split(',').filter(|s| !s.is_empty()).map(str::to_string).collect()).unwrap_or_default()
}

/// A worker about to be registered.
#[derive(Clone, Copy, Debug)]
pub struct NewWorker<'a> {
    pub name: &'a str,
    pub threads: u32,
    /// SHA-256 (hex) of the secret it was given.
    pub secret_hash: &'a str,
    /// What it declared (checked and sorted).
    pub tags: &'a [String],
}

/// A worker that can take new work now: seen within the lost limit and active.
#[derive(Clone, Debug, PartialEq)]
pub struct ServingWorker {
    pub tags: Vec<String>,
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
        self.workers_seen_since(f64::NEG_INFINITY)
    }

    /// The workers seen since `since` (the list leaves out those silent for longer than
    /// `--forget-workers-after`, whether or not their rows are gone yet).
    pub fn workers_seen_since(&self, since: f64) -> Result<Vec<WorkerRow>> {
        let conn = self.conn();
        let mut stmt = conn.prepare_cached(
            "SELECT w.id, w.name, w.threads, w.registered_at, w.last_seen, w.tiles_done, w.failures, w.rendering, t.job_id, t.frame, t.tile, w.mode, w.tags
             FROM workers w LEFT JOIN tiles t ON t.lease_id = w.rendering WHERE w.last_seen >= ?1 ORDER BY w.id",
        )?;
        let rows = stmt
            .query_map([since], |r| {
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
                    tags: tags_from_text(r.get(12)?),
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
        self.register_new_worker(&NewWorker { name, threads, secret_hash, tags: &[] }, max_live, live_since)
    }

    /// [`Store::register_worker_within`] with the worker's tags.
    pub fn register_new_worker(
        &self,
        w: &NewWorker<'_>,
        max_live: Option<u64>,
        live_since: f64,
    ) -> Result<Registered> {
        let NewWorker { name, threads, secret_hash, tags } = *w;
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
            "INSERT INTO workers(name, threads, registered_at, last_seen, secret_hash, tags) VALUES (?1, ?2, ?3, ?3, ?4, ?5)",
            params![name, threads, t, secret_hash, tags_to_text(tags)],
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

    /// Registers one of the server's own local workers: the row of its earlier lives (the local
    /// worker of that name before the server or the worker restarted) when there is one, else a
    /// new row marked local. A row taken over keeps its id, name, history and mode, gets the new
    /// secret, threads and tags, and first has its live leases expired exactly as the expiry
    /// sweep would expire them (the process that held them is dead): each counts a failure
    /// against its tile, a `lease_expired` event, and may fail its job. Returns the id and
    /// what expired, for the scheduler's counters and wake-ups.
    pub fn register_local_worker(&self, w: &NewWorker<'_>) -> Result<(u64, Expired)> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        let t = now();
        let earlier: Option<i64> = tx
            .query_row_cached("SELECT max(id) FROM workers WHERE name = ?1 AND local = 1", [w.name], |r| {
                r.get(0)
            })
            .optional()?
            .flatten();
        let (id, expired) = match earlier {
            Some(id) => {
                let held: Vec<(i64, i64, i64, i64, i64)> = {
                    let mut stmt = tx.prepare_cached(
                        "SELECT job_id, frame, tile, worker_id, pass FROM tiles WHERE state = 'leased' AND worker_id = ?1",
                    )?;
                    stmt.query_map([id], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?)))?
                        .collect::<rusqlite::Result<_>>()?
                };
                let expired = super::leases::expire_held(&tx, held, t)?;
                tx.execute_cached(
                    "UPDATE workers SET threads = ?2, last_seen = ?3, secret_hash = ?4, tags = ?5, rendering = NULL WHERE id = ?1",
                    params![id, w.threads, t, w.secret_hash, tags_to_text(w.tags)],
                )?;
                (id as u64, expired)
            }
            None => {
                tx.execute_cached(
                    "INSERT INTO workers(name, threads, registered_at, last_seen, secret_hash, tags, local) VALUES (?1, ?2, ?3, ?3, ?4, ?5, 1)",
                    params![w.name, w.threads, t, w.secret_hash, tags_to_text(w.tags)],
                )?;
                (tx.last_insert_rowid() as u64, Expired { leases: 0, failed_jobs: Vec::new() })
            }
        };
        tx.commit()?;
        Ok((id, expired))
    }

    /// The workers that can take new work now (seen since `live_since`, active), with their
    /// tags: what a job that waits is told it lacks.
    pub fn serving_workers(&self, live_since: f64) -> Result<(usize, Vec<ServingWorker>)> {
        let conn = self.conn();
        let mut stmt = conn.prepare_cached("SELECT mode, tags FROM workers WHERE last_seen >= ?1")?;
        let rows: Vec<(String, Option<String>)> =
            stmt.query_map([live_since], |r| Ok((r.get(0)?, r.get(1)?)))?.collect::<rusqlite::Result<_>>()?;
        let live = rows.len();
        let serving = rows
            .into_iter()
            .filter(|(mode, _)| WorkerMode::parse(mode) == Some(WorkerMode::Active))
            .map(|(_, tags)| ServingWorker { tags: tags_from_text(tags) })
            .collect();
        Ok((live, serving))
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::store;

    /// A job of `tiles` one-pixel tiles asking for `tags`.
    fn job(s: &Store, tiles: u32, tags: &[&str]) -> u64 {
        s.insert_job(&NewJob {
            name: "j".into(),
            tile_size: 1,
            bundle: "0".repeat(64),
            scene_path: "scene.xml".into(),
            frames: vec![NewFrame {
                image_name: "j.png".into(),
                width: tiles,
                height: 1,
                tiles: (0..tiles).map(|x| Rect { x0: x, y0: 0, width: 1, height: 1 }).collect(),
                samples: 1,
                pass_samples: 16,
                ..Default::default()
            }],
            worker_tags: tags.iter().map(|t| t.to_string()).collect(),
            ..Default::default()
        })
        .unwrap()
    }

    fn new_worker<'a>(name: &'a str, tags: &'a [String]) -> NewWorker<'a> {
        NewWorker { name, threads: 4, secret_hash: "h", tags }
    }

    /// A local worker that registers again takes over its row, but only after the leases of its
    /// earlier (dead) process expired as the sweep expires them: a failure of the tile each,
    /// the `lease_expired` event, and the failure rule's verdict.
    #[test]
    fn a_local_worker_registering_again_expires_its_leases_then_reuses_its_row() {
        let (_d, s) = store("local-again");
        let j = job(&s, 2, &[]);
        let remote = s.register_new_worker(&new_worker("local-1", &[]), Some(10), 0.0).unwrap();
        let (id, none) = s.register_local_worker(&new_worker("local-1", &[])).unwrap();
        assert_eq!(none.leases, 0);
        assert!(
            matches!(remote, Registered::Id(r) if r != id),
            "a remote worker's row is never a local one's"
        );
        let held = s.lease(id, 60.0).unwrap().granted().unwrap();
        s.set_worker_mode(id, WorkerMode::Draining).unwrap();
        let gpu = vec!["gpu".to_string()];
        let (again, expired) = s.register_local_worker(&new_worker("local-1", &gpu)).unwrap();
        assert_eq!(again, id, "the same row");
        assert_eq!(expired.leases, 1);
        let row = s.workers().unwrap().into_iter().find(|w| w.id == id).unwrap();
        assert_eq!((row.failures, row.rendering, row.mode, row.tags), (1, None, WorkerMode::Draining, gpu));
        assert_eq!(s.worker_secret_hash(id).unwrap(), Some(Some("h".into())));
        let log = s.job_log(j, 0).unwrap().unwrap();
        let last = log.last().unwrap();
        assert_eq!(
            (last.kind.as_str(), last.tile, last.worker_id),
            ("lease_expired", Some(held.tile), Some(id))
        );
        assert_eq!(s.recent_failures(j).unwrap().len(), 1);
        // The tile is queued again: another worker gets it.
        let other = s.register_worker("other", 1, "").unwrap();
        assert_eq!(s.lease(other, 60.0).unwrap().granted().unwrap().tile, held.tile);
        assert_eq!(
            s.workers().unwrap().iter().filter(|w| w.name == "local-1").count(),
            2,
            "one local, one remote"
        );
    }

    /// Five deaths of the same local worker on a tile fail its job, as five crashes of any
    /// worker do.
    #[test]
    fn a_tile_that_kills_the_same_local_worker_five_times_fails_its_job() {
        let (_d, s) = store("local-crashes");
        let j = job(&s, 1, &[]);
        for k in 1..=5 {
            let (id, _) = s.register_local_worker(&new_worker("local-1", &[])).unwrap();
            assert!(!s.job(j).unwrap().unwrap().state.is_final(), "ended after {k} deaths");
            // Past the 30 s a failed worker is kept off the tile.
            s.conn().execute("UPDATE tile_failures SET at = at - 60", []).unwrap();
            s.lease(id, 60.0).unwrap().granted().expect("the tile again");
        }
        let (_, expired) = s.register_local_worker(&new_worker("local-1", &[])).unwrap();
        assert_eq!(expired.failed_jobs.len(), 1);
        assert!(
            expired.failed_jobs[0].1.contains("crashed its workers: 5 time(s), on 1 worker(s)"),
            "{expired:?}"
        );
        assert_eq!(s.job(j).unwrap().unwrap().state, JobState::Failed);
    }

    /// A worker leases only from jobs whose tags it all has; jobs without tags go to anyone.
    #[test]
    fn a_worker_leases_only_jobs_whose_tags_it_has() {
        let (_d, s) = store("tags");
        let gpu_big = job(&s, 1, &["big", "gpu"]);
        let gpu = job(&s, 1, &["gpu"]);
        let any = job(&s, 1, &[]);
        let (plain, only_gpu, both) =
            (vec![], vec!["gpu".to_string()], vec!["big".to_string(), "gpu".to_string()]);
        let register =
            |tags: &[String]| match s.register_new_worker(&new_worker("w", tags), None, 0.0).unwrap() {
                Registered::Id(id) => id,
                Registered::Full { .. } => unreachable!(),
            };
        let (p, g, b) = (register(&plain), register(&only_gpu), register(&both));
        let job_of = |w| s.lease(w, 60.0).unwrap().granted().map(|l| l.job_id);
        assert_eq!(job_of(p), Some(any), "an untagged worker takes only the untagged job");
        assert_eq!(job_of(p), None);
        assert_eq!(job_of(g), Some(gpu));
        assert_eq!(job_of(g), None, "gpu alone is not gpu and big");
        assert_eq!(job_of(b), Some(gpu_big));
        let listed = s.workers().unwrap().into_iter().find(|w| w.id == b).unwrap();
        assert_eq!(listed.tags, both);
        assert_eq!(s.job(gpu_big).unwrap().unwrap().worker_tags, both);
        let (live, serving) = s.serving_workers(0.0).unwrap();
        assert_eq!((live, serving.len()), (3, 3));
        s.set_worker_mode(g, WorkerMode::Disabled).unwrap();
        assert_eq!(s.serving_workers(0.0).unwrap().1.len(), 2);
        assert_eq!(s.serving_workers(now() + 1.0).unwrap(), (0, vec![]), "all silent since");
    }
}
