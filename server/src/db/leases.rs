//! Leasing in the store: a tile handed to a worker, kept alive by heartbeats, given back,
//! expired, failed, or answered with its pixels (a pass's sums go on in `passes`).

use super::*;

/// The first queued unit of job `?1` not kept from worker `?2` by a failure since `?3`, by
/// pass, then frame, then tile (one scene's frames; `tiles_queue_by_pass`).
const NEXT_UNIT_BY_PASS: &str = "SELECT t.frame, t.tile, t.x0, t.y0, t.w, t.h, f.camera, t.pass, t.first_sample, t.end_sample, f.passes_total, f.scene_path, t.mask
     FROM tiles t JOIN frames f ON f.job_id = t.job_id AND f.idx = t.frame
     WHERE t.job_id = ?1 AND t.state = 'queued'
       AND NOT EXISTS (SELECT 1 FROM tile_failures x WHERE x.job_id = t.job_id AND x.frame = t.frame AND x.tile = t.tile AND x.worker_id = ?2 AND x.at > ?3)
     ORDER BY t.pass, t.frame, t.tile LIMIT 1";

/// [`NEXT_UNIT_BY_PASS`] by frame, then pass, then tile (a sequence; `tiles_queue_by_frame`).
const NEXT_UNIT_BY_FRAME: &str = "SELECT t.frame, t.tile, t.x0, t.y0, t.w, t.h, f.camera, t.pass, t.first_sample, t.end_sample, f.passes_total, f.scene_path, t.mask
     FROM tiles t JOIN frames f ON f.job_id = t.job_id AND f.idx = t.frame
     WHERE t.job_id = ?1 AND t.state = 'queued'
       AND NOT EXISTS (SELECT 1 FROM tile_failures x WHERE x.job_id = t.job_id AND x.frame = t.frame AND x.tile = t.tile AND x.worker_id = ?2 AND x.at > ?3)
     ORDER BY t.frame, t.pass, t.tile LIMIT 1";

/// A job a lease may come from: id, bundle, scene file, samples, allow_unsupported, denoise,
/// manifest and scale, scene files and the tags it asks of its workers.
type LiveJob =
    (i64, String, String, Option<i64>, bool, bool, (Option<String>, Option<f64>), i64, Option<String>);

/// Expires the leases `held` ((job, frame, tile, worker, pass) of live leases) inside `tx`:
/// the worker stopped answering while it held each tile, which counts against the tile like a
/// reported failure ([`record_failure`]): the tile goes back to the queue, or fails its job.
/// The expiry sweep and a local worker registering again (its earlier process is dead) both
/// come here, so that either way the same failures, events and verdicts are recorded.
pub(super) fn expire_held(
    tx: &rusqlite::Transaction<'_>,
    held: Vec<(i64, i64, i64, i64, i64)>,
    t: f64,
) -> Result<Expired> {
    let mut out = Expired { leases: held.len(), failed_jobs: Vec::new() };
    for (job, frame, tile, worker, pass) in held {
        let error = format!(
            "worker {worker} stopped answering while rendering this tile (it crashed, was killed or lost \
             its connection) and its lease expired"
        );
        tx.execute_cached(
            "UPDATE workers SET rendering = NULL WHERE id = ?1 AND rendering IS NOT NULL",
            [worker],
        )?;
        if let FailOutcome::JobFailed { job, message } =
            record_failure(tx, (job, frame, tile, pass), worker, Failure::LeaseExpired { error: &error }, t)?
        {
            out.failed_jobs.push((job, message));
        }
    }
    Ok(out)
}

impl Store {
    /// Hands the next tile to `worker`: highest job priority first, then submission order, then
    /// pass, frame and tile order (a sequence's: frame, pass and tile); not a tile of a job the worker has failed
    /// [`failures::WORKER_FAILURES_PER_JOB`] tiles of, nor a tile it failed, until
    /// [`failures::RETRY_FAILED_AFTER`] (or `--retry-failed-after-seconds`) has passed since its
    /// latest failure there.
    ///
    /// A worker holds at most its threads plus two (the lease it fetches ahead, a tile uploading) live leases
    /// ([`max_live_leases`]): past that it gets [`Leased::Full`], whatever is queued.
    pub fn lease(&self, worker: u64, lease_seconds: f64) -> Result<Leased> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        let w = worker as i64;
        let (threads, worker_tags): (i64, Option<String>) =
            tx.query_row_cached("SELECT threads, tags FROM workers WHERE id = ?1", [w], |r| {
                Ok((r.get(0)?, r.get(1)?))
            })?;
        let worker_tags = workers::tags_from_text(worker_tags);
        let held: i64 = tx.query_row_cached(
            "SELECT count(*) FROM tiles WHERE state = 'leased' AND worker_id = ?1",
            [w],
            |r| r.get(0),
        )?;
        let allowed = max_live_leases(threads.clamp(0, i64::from(u32::MAX)) as u32);
        if held >= i64::from(allowed) {
            return Ok(Leased::Full { held: held as u32, allowed });
        }
        // Failures since this moment keep the worker off their tile (and job).
        let recent = now() - self.retry_failed_after();
        // Two indexed steps instead of one join sorted over every queued tile: the live jobs in
        // priority order (a short list), then the first queued tile of each (an index seek on
        // `tiles_queue`), so a lease costs the same behind a million queued tiles as behind ten.
        let jobs: Vec<LiveJob> = {
            let mut stmt = tx.prepare_cached(
                "SELECT j.id, j.bundle, j.scene_path, j.samples, j.allow_unsupported, j.denoise, j.manifest, j.scenes, j.scale, j.worker_tags FROM jobs j
                 WHERE j.state IN ('queued', 'running')
                   AND NOT (SELECT count(*) >= ?2 AND max(x.at) > ?3
                            FROM tile_failures x WHERE x.job_id = j.id AND x.worker_id = ?1)
                 ORDER BY j.priority DESC, j.id",
            )?;
            stmt.query_map(params![w, failures::WORKER_FAILURES_PER_JOB, recent], |r| {
                Ok((
                    r.get(0)?,
                    r.get(1)?,
                    r.get(2)?,
                    r.get(3)?,
                    r.get(4)?,
                    r.get(5)?,
                    (r.get(6)?, r.get(8)?),
                    r.get(7)?,
                    r.get(9)?,
                ))
            })?
            .collect::<rusqlite::Result<_>>()?
        };
        let mut candidate = None;
        for (job, bundle, scene_path, samples, allow_unsupported, aux, (manifest, scale), scenes, tags) in
            jobs
        {
            // A job that asks for tags goes only to a worker that has them all (few jobs ask:
            // the live jobs are a short list, filtered here rather than in the query).
            if !workers::tags_from_text(tags).iter().all(|t| worker_tags.contains(t)) {
                continue;
            }
            // A sequence (frames of several scene files) goes frame by frame, each frame's
            // passes in order, so that its beginning is watchable first; one scene's frames go
            // pass by pass over all of them, so that every frame shows a first pass early. Each
            // order has its index (`tiles_queue_by_frame`, `tiles_queue_by_pass`): the first
            // queued unit is a seek, whatever the job's length.
            let sql = if scenes > 1 { NEXT_UNIT_BY_FRAME } else { NEXT_UNIT_BY_PASS };
            let tile = tx
                .prepare_cached(sql)?
                .query_row(params![job, w, recent], |r| {
                    Ok((
                        r.get::<_, i64>(0)?,
                        r.get::<_, i64>(1)?,
                        rect_at(r, 2)?,
                        r.get::<_, i64>(6)?,
                        unit_pass(r, 7)?,
                        r.get::<_, Option<String>>(11)?,
                        r.get::<_, Option<Vec<u8>>>(12)?,
                    ))
                })
                .optional()?;
            if let Some((frame, tile, rect, camera, pass, frame_scene, mask)) = tile {
                candidate = Some((
                    job,
                    frame,
                    tile,
                    rect,
                    bundle,
                    (frame_scene.unwrap_or(scene_path), manifest, scale),
                    samples,
                    camera,
                    allow_unsupported,
                    aux,
                    (pass, mask),
                ));
                break;
            }
        }
        let Some((
            job,
            frame,
            tile,
            rect,
            bundle,
            (scene_path, manifest, scale),
            samples,
            camera,
            allow_unsupported,
            aux,
            (pass, mask),
        )) = candidate
        else {
            tx.execute_cached("UPDATE workers SET last_seen = ?2 WHERE id = ?1", params![w, now()])?;
            tx.commit()?;
            return Ok(Leased::NoWork);
        };
        let lease_id = {
            let mut next = self.next_lease.lock().unwrap_or_else(|e| e.into_inner());
            let id = *next;
            *next += 1;
            id
        };
        let t = now();
        tx.execute_cached(
            "UPDATE tiles SET state = 'leased', lease_id = ?4, worker_id = ?5, deadline = ?6 WHERE job_id = ?1 AND frame = ?2 AND tile = ?3 AND pass = ?7",
            params![job, frame, tile, lease_id as i64, w, t + lease_seconds, pass.map_or(0, |p| p.index)],
        )?;
        let failures: i64 = tx
            .prepare_cached(
                "SELECT count(*) FROM tile_failures WHERE job_id = ?1 AND frame = ?2 AND tile = ?3",
            )?
            .query_row(params![job, frame, tile], |r| r.get(0))?;
        if failures > 0 {
            let message = format!("tile {tile} of frame {frame} tried again after {failures} failure(s)");
            log_event(&tx, job, Event::new("tile_retried", &message).tile(frame, tile).worker(w))?;
        }
        tx.execute_cached(
            "UPDATE jobs SET state = 'running', started_at = ?2 WHERE id = ?1 AND state = 'queued'",
            params![job, t],
        )?;
        // Shown as the worker's current tile until a heartbeat says which one it renders.
        tx.execute_cached(
            "UPDATE workers SET last_seen = ?2, rendering = coalesce(rendering, ?3) WHERE id = ?1",
            params![w, t, lease_id as i64],
        )?;
        tx.commit()?;
        Ok(Leased::Granted(Lease {
            lease_id,
            job_id: job as u64,
            camera: camera as u32,
            tile: tile as u32,
            rect,
            bundle,
            scene_path,
            samples: samples.map(|s| s as u32),
            lease_seconds,
            max_render_seconds: None,
            allow_unsupported,
            // Features come with a tile's first samples.
            aux: aux && pass.is_none_or(|p| p.index == 0),
            pass,
            pass_mask: mask.map(|m| tessera::passes::mask_to_hex(&m)),
            scale,
            manifest,
        }))
    }

    /// Renews the worker's live leases; returns those it listed that it no longer owns.
    pub fn heartbeat(
        &self,
        worker: u64,
        leases: &[u64],
        rendering: Option<u64>,
        lease_seconds: f64,
    ) -> Result<Vec<u64>> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        let t = now();
        let mut revoked = Vec::new();
        for &l in leases {
            let n = tx.execute_cached(
                "UPDATE tiles SET deadline = ?3 WHERE lease_id = ?1 AND worker_id = ?2 AND state = 'leased'",
                params![l as i64, worker as i64, t + lease_seconds],
            )?;
            if n == 0 {
                revoked.push(l);
            }
        }
        let rendering = rendering.filter(|r| !revoked.contains(r));
        tx.execute_cached(
            "UPDATE workers SET last_seen = ?2, rendering = ?3 WHERE id = ?1",
            params![worker as i64, t, rendering.map(|r| r as i64)],
        )?;
        tx.commit()?;
        Ok(revoked)
    }

    /// Of `leases`, those `worker` no longer owns (expired, revoked, cancelled, done). Reads only.
    pub fn revoked_among(&self, worker: u64, leases: &[u64]) -> Result<Vec<u64>> {
        let conn = self.conn();
        let mut live = conn.prepare_cached(
            "SELECT COUNT(*) FROM tiles WHERE lease_id = ?1 AND worker_id = ?2 AND state = 'leased'",
        )?;
        let mut revoked = Vec::new();
        for &l in leases {
            let n: i64 = live.query_row(params![l as i64, worker as i64], |r| r.get(0))?;
            if n == 0 {
                revoked.push(l);
            }
        }
        Ok(revoked)
    }

    /// Handles leases whose deadline passed: the worker stopped answering while it held the
    /// tile (it crashed, was killed, or lost the network), which counts against the tile like a
    /// reported failure. Each tile goes back to the queue, or fails its job once the tile has
    /// crashed or failed on too many workers (see [`Store::fail_tile`]).
    pub fn expire_leases(&self) -> Result<Expired> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        let t = now();
        let expired: Vec<(i64, i64, i64, i64, i64)> = {
            let mut stmt = tx.prepare_cached(
                "SELECT job_id, frame, tile, worker_id, pass FROM tiles WHERE state = 'leased' AND deadline < ?1",
            )?;
            stmt.query_map([t], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?)))?
                .collect::<rusqlite::Result<_>>()?
        };
        let out = expire_held(&tx, expired, t)?;
        tx.commit()?;
        Ok(out)
    }

    /// Puts the tile of a live lease held by `worker` back in the queue (the worker is stopping
    /// and never started it); false when it is not that worker's live lease.
    pub fn release_lease(&self, lease: u64, worker: u64) -> Result<bool> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        let n = tx.execute_cached(
            "UPDATE tiles SET state = 'queued', lease_id = NULL, worker_id = NULL, deadline = NULL
             WHERE lease_id = ?1 AND worker_id = ?2 AND state = 'leased' AND deadline >= ?3",
            params![lease as i64, worker as i64, now()],
        )?;
        if n > 0 {
            tx.execute_cached(
                "UPDATE workers SET rendering = NULL, last_seen = ?3 WHERE id = ?1 AND rendering = ?2",
                params![worker as i64, lease as i64, now()],
            )?;
        }
        tx.commit()?;
        Ok(n > 0)
    }

    /// What the result of a live lease of `worker` must hold ([`ResultShape`]: finished
    /// pixels or a pass's sums, with or without features), or `None` when it is not such a
    /// lease: the result route reads no more than its bytes of a body.
    pub fn result_size(&self, lease: u64, worker: u64) -> Result<Option<ResultShape>> {
        let conn = self.conn();
        let (lease, worker) = (i64::try_from(lease).unwrap_or(-1), i64::try_from(worker).unwrap_or(-1));
        Ok(conn
            .query_row_cached(
                "SELECT t.w * t.h, t.first_sample, t.end_sample, t.pass, j.denoise
                 FROM tiles t JOIN jobs j ON j.id = t.job_id
                 WHERE t.lease_id = ?1 AND t.worker_id = ?2 AND t.state = 'leased'",
                params![lease, worker],
                |r| {
                    let pass = r.get::<_, Option<i64>>(1)?.zip(r.get::<_, Option<i64>>(2)?);
                    let index: i64 = r.get(3)?;
                    Ok(ResultShape {
                        pixels: r.get::<_, i64>(0)? as usize,
                        // The blocks of its samples (the last may be short): the passes'
                        // counts add up to the pixel's, so their sums to at most 2^126.
                        blocks: pass
                            .map(|(a, b)| ((b - a).max(0) as u32).div_ceil(tessera::passes::BLOCK).max(1)),
                        aux: r.get::<_, bool>(4)? && index == 0,
                    })
                },
            )
            .optional()?)
    }

    /// Stores a tile's pixels (or a pass's sums) for a live lease held by `worker`, once. A
    /// pass is added into its tile as soon as the passes before it are (in the same
    /// transaction: a finished pass survives any crash after its answer).
    pub fn submit_result(
        &self,
        lease: u64,
        worker: u64,
        pixels: &[u8],
        render_seconds: Option<f64>,
    ) -> Result<ResultOutcome> {
        self.submit_result_as(lease, worker, ResultBody::Bytes(pixels), render_seconds)
    }

    /// [`Store::submit_result`] of a result kept in its row or written as a result file
    /// (`results.rs`) already.
    pub fn submit_result_as(
        &self,
        lease: u64,
        worker: u64,
        pixels: ResultBody<'_>,
        render_seconds: Option<f64>,
    ) -> Result<ResultOutcome> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        let row = tx
            .query_row_cached(
                "SELECT t.job_id, t.frame, t.tile, t.pass, t.deadline, j.denoise, t.x0, t.y0, t.w, t.h, t.first_sample IS NOT NULL
                 FROM tiles t JOIN jobs j ON j.id = t.job_id
                 WHERE t.lease_id = ?1 AND t.worker_id = ?2 AND t.state = 'leased' AND j.state IN ('queued', 'running', 'paused')",
                params![lease as i64, worker as i64],
                |r| {
                    Ok((
                        (r.get::<_, i64>(0)?, r.get::<_, i64>(1)?, r.get::<_, i64>(2)?, r.get::<_, i64>(3)?),
                        rect_at(r, 6)?,
                        r.get::<_, f64>(4)?,
                        r.get::<_, bool>(5)?,
                        r.get::<_, bool>(10)?,
                    ))
                },
            )
            .optional()?;
        let Some(((job, frame, tile, pass), rect, deadline, denoise, in_passes)) = row else {
            return Ok(ResultOutcome::Conflict);
        };
        if deadline < now() {
            // Expired but not swept yet: the tile may already be someone else's.
            return Ok(ResultOutcome::Conflict);
        }
        let px = (rect.width * rect.height) as usize;
        let expected = if in_passes {
            tessera::passes::pass_tile_bytes(px, denoise && pass == 0)
        } else {
            tessera::protocol::tile_bytes(px, denoise)
        };
        if pixels.size() != expected {
            return Ok(ResultOutcome::WrongSize { expected });
        }
        let (bytes, file) = match pixels {
            // A pass's sums are added into its tile at once (`passes::absorb`): always a row's.
            ResultBody::File { name, .. } if !in_passes => (None, Some(name)),
            ResultBody::File { .. } => anyhow::bail!("a pass's result must be stored in its row"),
            ResultBody::Bytes(b) => (Some(b), None),
        };
        tx.execute_cached(
            "UPDATE tiles SET state = 'done', pixels = ?2, pixels_file = ?4, deadline = NULL, render_seconds = ?3 WHERE lease_id = ?1",
            params![lease as i64, bytes, render_seconds, file],
        )?;
        tx.execute_cached(
            "UPDATE counters SET tiles_done = tiles_done + 1, render_seconds_sum = render_seconds_sum + coalesce(?1, 0.0),
             render_seconds_count = render_seconds_count + (?1 IS NOT NULL) WHERE id = 1",
            [render_seconds],
        )?;
        tx.execute_cached(
            "UPDATE workers SET tiles_done = tiles_done + 1, last_seen = ?2, rendering = NULL WHERE id = ?1",
            params![worker as i64, now()],
        )?;
        let mut published = None;
        // A pass is not logged on its own: a frame in passes is tiles x passes results, which
        // would fill the bounded log before the tiles' `tile_done` events (samples, noise).
        if !in_passes {
            let message = match render_seconds {
                Some(s) => format!("tile {tile} of frame {frame} rendered in {s:.3} s"),
                None => format!("tile {tile} of frame {frame} rendered"),
            };
            log_event(
                &tx,
                job,
                Event {
                    seconds: render_seconds,
                    ..Event::new("tile_done", &message).tile(frame, tile).worker(worker as i64)
                },
            )?;
        }
        if in_passes {
            published = passes::absorb(&tx, job, frame, tile, rect)?;
        } else {
            // A tile rendered whole brings all the frame's samples for its pixels.
            tx.execute_cached(
                "UPDATE frames SET tiles_done = tiles_done + 1, samples_done = samples_done + ?3 * max(samples, 1)
                 WHERE job_id = ?1 AND idx = ?2",
                params![job, frame, px as i64],
            )?;
        }
        let (done, total): (i64, i64) = tx.query_row_cached(
            "SELECT tiles_done, tiles_total FROM frames WHERE job_id = ?1 AND idx = ?2",
            params![job, frame],
            |r| Ok((r.get(0)?, r.get(1)?)),
        )?;
        tx.commit()?;
        Ok(ResultOutcome::Accepted {
            job_id: job as u64,
            frame: frame as u32,
            tile: tile as u32,
            rect,
            tiles_done: done as u32,
            tiles_total: total as u32,
            frame_complete: done == total,
            pass_published: published.filter(|_| done < total),
        })
    }

    /// Records that `worker` could not render the tile of `lease`: the tile goes back to the
    /// queue, or fails its job ([`failures::tile_verdict`]: too many workers or attempts, or at
    /// once when the failure is `fatal`, the tile having gone over the farm's render time limit
    /// that another worker would spend again).
    pub fn fail_tile(&self, lease: u64, worker: u64, error: &str, fatal: bool) -> Result<FailOutcome> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        let row = tx
            .query_row_cached(
                "SELECT job_id, frame, tile, pass FROM tiles WHERE lease_id = ?1 AND worker_id = ?2 AND state = 'leased'",
                params![lease as i64, worker as i64],
                |r| Ok((r.get::<_, i64>(0)?, r.get::<_, i64>(1)?, r.get::<_, i64>(2)?, r.get::<_, i64>(3)?)),
            )
            .optional()?;
        let Some((job, frame, tile, pass)) = row else { return Ok(FailOutcome::Conflict) };
        let outcome = record_failure(
            &tx,
            (job, frame, tile, pass),
            worker as i64,
            Failure::Reported { error, fatal },
            now(),
        )?;
        tx.commit()?;
        Ok(outcome)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The next unit of a job, in either order, is an index seek on the queue's index of that
    /// order, never a sort of the job's queued units (a 360-frame sequence leases as cheaply as a
    /// frame).
    #[test]
    fn each_lease_order_is_an_index_seek() {
        let (_dir, s) = crate::testutil::store("lease-plan");
        let conn = s.conn();
        for (sql, index) in
            [(NEXT_UNIT_BY_FRAME, "tiles_queue_by_frame"), (NEXT_UNIT_BY_PASS, "tiles_queue_by_pass")]
        {
            let mut stmt = conn.prepare(&format!("EXPLAIN QUERY PLAN {sql}")).unwrap();
            let plan: Vec<String> = stmt
                .query_map(params![1, 1, 0.0], |r| r.get::<_, String>(3))
                .unwrap()
                .collect::<rusqlite::Result<_>>()
                .unwrap();
            let plan = plan.join("\n");
            assert!(plan.contains(&format!("USING INDEX {index} (job_id=? AND state=?)")), "{plan}");
            assert!(!plan.contains("TEMP B-TREE"), "the units are sorted: {plan}");
        }
    }
}
