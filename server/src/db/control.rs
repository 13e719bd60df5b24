//! A job changed after its submission: paused and resumed, its priority changed, requeued
//! (its unfinished frames, or frames chosen, rendered again), and the finished jobs the
//! retention policy looks at. Each change is one transaction with its event in the job's log.

use std::collections::BTreeSet;
use std::ops::RangeInclusive;

use super::*;

/// What a change of a job's state found.
#[derive(Clone, Debug, PartialEq)]
pub enum Control<T> {
    /// There is no such job.
    NoSuchJob,
    /// The job is in a state the change does not apply to.
    Refused(JobState),
    /// Done; what it did.
    Changed(T),
}

/// What [`Store::requeue_job`] did or why it did not.
#[derive(Clone, Debug, PartialEq)]
pub enum Requeued {
    /// Every frame of the job is finished and no frame was named: nothing to render again.
    NothingUnfinished,
    /// A frame asked for is past the job's last (`frames` frames: indexes `0..frames`).
    NoSuchFrame { asked: u32, frames: u32 },
    /// These frames render again (their units of work, tiles x passes, queued afresh).
    Queued { frames: Vec<u32>, units: u64 },
    /// Another requeue of the job is under way.
    Busy,
}

/// Why a requeue does nothing (what [`Store::requeue_job`] answers).
type Refusal = Control<Requeued>;

/// A frame a requeue renders again, cut as at its submission.
struct FramePlan {
    frame: u32,
    width: u32,
    height: u32,
    /// The tiles' edge.
    edge: u32,
    samples: u32,
    /// Samples per pass (whole blocks), and the passes.
    pass: u32,
    passes: u32,
    /// Under a noise target a tile's later passes wait for the verdict on the one before.
    waiting: bool,
}

/// A job's state in `tx`, `None` when there is no such job (or it is still being stored).
fn job_state(tx: &Connection, id: i64) -> Result<Option<JobState>> {
    let state: Option<String> = tx
        .query_row_cached("SELECT state FROM jobs WHERE id = ?1 AND state != 'inserting'", [id], |r| r.get(0))
        .optional()?;
    state.map(|s| JobState::parse(&s).ok_or_else(|| anyhow::anyhow!("job {id} has state {s}"))).transpose()
}

impl Store {
    /// Pauses a queued or running job: it leases nothing more (the lease query looks at queued
    /// and running jobs only); its leases out finish and their results are kept.
    pub fn pause_job(&self, job: u64) -> Result<Control<u64>> {
        let Ok(id) = i64::try_from(job) else { return Ok(Control::NoSuchJob) };
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        match job_state(&tx, id)? {
            None => return Ok(Control::NoSuchJob),
            Some(JobState::Queued | JobState::Running) => {}
            Some(s) => return Ok(Control::Refused(s)),
        }
        tx.execute_cached("UPDATE jobs SET state = 'paused' WHERE id = ?1", [id])?;
        let out: i64 = tx.query_row_cached(
            "SELECT count(*) FROM tiles WHERE job_id = ?1 AND state = 'leased'",
            [id],
            |r| r.get(0),
        )?;
        let message = format!("paused: no more tiles are leased; {out} lease(s) out finish and are kept");
        log_event(&tx, id, Event::new("job_paused", &message))?;
        tx.commit()?;
        Ok(Control::Changed(out as u64))
    }

    /// Resumes a paused job: queued again, or running when some of its work is done or out.
    /// Returns its new state.
    pub fn resume_job(&self, job: u64) -> Result<Control<JobState>> {
        let Ok(id) = i64::try_from(job) else { return Ok(Control::NoSuchJob) };
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        match job_state(&tx, id)? {
            None => return Ok(Control::NoSuchJob),
            Some(JobState::Paused) => {}
            Some(s) => return Ok(Control::Refused(s)),
        }
        let started: bool = tx.query_row_cached(
            "SELECT EXISTS (SELECT 1 FROM frames WHERE job_id = ?1 AND (tiles_done > 0 OR passes_published > 0 OR outputs IS NOT NULL))
                 OR EXISTS (SELECT 1 FROM tiles WHERE job_id = ?1 AND state IN ('leased', 'done'))",
            [id],
            |r| r.get(0),
        )?;
        let state = if started { JobState::Running } else { JobState::Queued };
        tx.execute_cached("UPDATE jobs SET state = ?2 WHERE id = ?1", params![id, state.as_str()])?;
        log_event(&tx, id, Event::new("job_resumed", &format!("resumed: {}", state.as_str())))?;
        tx.commit()?;
        Ok(Control::Changed(state))
    }

    /// Sets the priority of a job that has not ended (the next lease goes by it); returns the
    /// priority it had.
    pub fn set_priority(&self, job: u64, priority: i64) -> Result<Control<i64>> {
        let Ok(id) = i64::try_from(job) else { return Ok(Control::NoSuchJob) };
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        match job_state(&tx, id)? {
            None => return Ok(Control::NoSuchJob),
            Some(s) if s.is_final() => return Ok(Control::Refused(s)),
            Some(_) => {}
        }
        let old: i64 = tx.query_row_cached("SELECT priority FROM jobs WHERE id = ?1", [id], |r| r.get(0))?;
        tx.execute_cached("UPDATE jobs SET priority = ?2 WHERE id = ?1", params![id, priority])?;
        log_event(
            &tx,
            id,
            Event::new("priority_changed", &format!("priority changed from {old} to {priority}")),
        )?;
        tx.commit()?;
        Ok(Control::Changed(old))
    }

    /// Renders frames of a finished job again: `frames` (0-based ranges; any finished job, a
    /// done one too), else every frame of a failed or cancelled job without outputs. Each such
    /// frame's units of work are queued afresh (the tiles and passes it was cut into at
    /// submission), its progress and outputs cleared (the files stay until the new ones replace
    /// them), and the job's tile failures forgotten (fresh retry counts); the job is queued,
    /// its end announced again and its video (a sequence's) made again once it is done.
    ///
    /// The frames' tile rows are deleted and written again [`ROWS_PER_STEP`] to a transaction,
    /// the store's lock let go between two, while the job stays as it was (a finished job leases
    /// nothing; the housekeeping does not purge it nor a `DELETE` delete it meanwhile); the last
    /// step clears the frames and queues the job. A stop half-way leaves the finished job as it
    /// was, with rows the housekeeping purges or a requeue writes again.
    pub fn requeue_job(&self, job: u64, frames: Option<&[RangeInclusive<u32>]>) -> Result<Control<Requeued>> {
        let Ok(id) = i64::try_from(job) else { return Ok(Control::NoSuchJob) };
        let (state, plan) = match self.requeue_plan(id, frames)? {
            Ok(p) => p,
            Err(refusal) => return Ok(refusal),
        };
        if !self.requeueing.lock().unwrap_or_else(|e| e.into_inner()).insert(job) {
            return Ok(Control::Changed(Requeued::Busy));
        }
        let result = self.requeue_in_steps(id, state, &plan);
        self.requeueing.lock().unwrap_or_else(|e| e.into_inner()).remove(&job);
        result
    }

    pub(super) fn is_requeueing(&self, job: u64) -> bool {
        self.requeueing.lock().unwrap_or_else(|e| e.into_inner()).contains(&job)
    }

    /// The frames a requeue renders again, each as cut at submission; or why there is none.
    fn requeue_plan(
        &self,
        id: i64,
        frames: Option<&[RangeInclusive<u32>]>,
    ) -> Result<Result<(JobState, Vec<FramePlan>), Refusal>> {
        let conn = self.conn();
        let state = match job_state(&conn, id)? {
            None => return Ok(Err(Control::NoSuchJob)),
            Some(s) if !s.is_final() => return Ok(Err(Control::Refused(s))),
            Some(s) => s,
        };
        let (tile_size, pass_samples, noise_target): (i64, Option<i64>, Option<f64>) = conn
            .query_row_cached(
                "SELECT tile_size, pass_samples, noise_target FROM jobs WHERE id = ?1",
                [id],
                |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)),
            )?;
        let count: i64 =
            conn.query_row_cached("SELECT count(*) FROM frames WHERE job_id = ?1", [id], |r| r.get(0))?;
        let count = u32::try_from(count).unwrap_or(u32::MAX);
        let chosen: Vec<u32> = match frames {
            Some(ranges) => {
                if let Some(r) = ranges.iter().find(|r| *r.end() >= count) {
                    return Ok(Err(Control::Changed(Requeued::NoSuchFrame {
                        asked: *r.end(),
                        frames: count,
                    })));
                }
                let set: BTreeSet<u32> = ranges.iter().flat_map(|r| r.clone()).collect();
                set.into_iter().collect()
            }
            None => {
                let mut stmt = conn.prepare_cached(
                    "SELECT idx FROM frames WHERE job_id = ?1 AND outputs IS NULL ORDER BY idx",
                )?;
                let rows = stmt.query_map([id], |r| r.get::<_, i64>(0))?;
                rows.map(|r| r.map(|i| i as u32)).collect::<rusqlite::Result<_>>()?
            }
        };
        if chosen.is_empty() {
            return Ok(Err(Control::Changed(Requeued::NothingUnfinished)));
        }
        let mut plan = Vec::with_capacity(chosen.len());
        for frame in chosen {
            let (width, height, tiles_total, samples, passes_total): (u32, u32, i64, u32, u32) = conn.query_row_cached(
                "SELECT width, height, tiles_total, samples, passes_total FROM frames WHERE job_id = ?1 AND idx = ?2",
                params![id, frame],
                |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?)),
            )?;
            // The tiles as the submission cut them: a frame of one tile was rendered whole.
            let edge = if tiles_total == 1 { width.max(height) } else { tile_size.clamp(1, 4096) as u32 };
            let pass = match pass_samples {
                Some(p) => tessera::passes::round_to_blocks(p.clamp(1, i64::from(u32::MAX)) as u32),
                None => tessera::passes::default_farm_pass_samples(samples, noise_target.is_some()),
            };
            let passes = tessera::passes::pass_count(samples, pass);
            let tiles = tessera::render::tiles(width, height, edge).len() as i64;
            anyhow::ensure!(
                tiles == tiles_total && passes == passes_total,
                "frame {frame} of job {id} cannot be cut again as it was ({tiles_total} tiles of {passes_total} passes)"
            );
            plan.push(FramePlan {
                frame,
                width,
                height,
                edge,
                samples,
                pass,
                passes,
                waiting: noise_target.is_some(),
            });
        }
        Ok(Ok((state, plan)))
    }

    fn requeue_in_steps(&self, id: i64, state: JobState, plan: &[FramePlan]) -> Result<Control<Requeued>> {
        let mut units = 0u64;
        for f in plan {
            loop {
                // Each deleted row's result file, if it has one, goes too.
                let files: Vec<Option<String>> = self
                    .conn()
                    .prepare_cached(
                        "DELETE FROM tiles WHERE rowid IN (SELECT rowid FROM tiles WHERE job_id = ?1 AND frame = ?2 LIMIT ?3)
                         RETURNING pixels_file",
                    )?
                    .query_map(params![id, f.frame, ROWS_PER_STEP as i64], |r| r.get(0))?
                    .collect::<rusqlite::Result<_>>()?;
                let gone = files.len();
                self.remove_result_files(&files.into_iter().flatten().collect::<Vec<_>>());
                if gone < ROWS_PER_STEP {
                    break;
                }
                std::thread::sleep(STEP_PAUSE);
            }
            let rects = tessera::render::tiles(f.width, f.height, f.edge);
            let mut rows = (0..f.passes).flat_map(|k| rects.iter().enumerate().map(move |(t, r)| (k, t, r)));
            loop {
                let step: Vec<_> = rows.by_ref().take(ROWS_PER_STEP).collect();
                if step.is_empty() {
                    break;
                }
                let mut conn = self.conn();
                let tx = conn.transaction()?;
                {
                    let mut insert = tx.prepare_cached(
                        "INSERT INTO tiles(job_id, frame, tile, x0, y0, w, h, pass, first_sample, end_sample, state)
                         VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11)",
                    )?;
                    for (k, t, r) in &step {
                        let range =
                            (f.passes > 1).then(|| tessera::passes::pass_range(f.samples, f.pass, *k));
                        let unit_state = if *k > 0 && f.waiting { "waiting" } else { "queued" };
                        insert.execute(params![
                            id,
                            f.frame,
                            *t as i64,
                            r.x0,
                            r.y0,
                            r.width,
                            r.height,
                            k,
                            range.map(|r| r.start),
                            range.map(|r| r.end),
                            unit_state
                        ])?;
                    }
                }
                tx.commit()?;
                drop(conn);
                units += step.len() as u64;
                std::thread::sleep(STEP_PAUSE);
            }
        }
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        // Nothing changes a finished job's state but a requeue, which waits for this one.
        anyhow::ensure!(
            job_state(&tx, id)? == Some(state),
            "job {id} changed while its frames were being queued again"
        );
        for f in plan {
            tx.execute_cached(
                "UPDATE frames SET tiles_done = 0, passes_published = 0, samples_done = 0, samples_skipped = 0, outputs = NULL WHERE job_id = ?1 AND idx = ?2",
                params![id, f.frame],
            )?;
        }
        tx.execute_cached("DELETE FROM tile_failures WHERE job_id = ?1", [id])?;
        tx.execute_cached("DELETE FROM job_videos WHERE job_id = ?1", [id])?;
        tx.execute_cached(
            "UPDATE jobs SET state = 'queued', started_at = NULL, finished_at = NULL, error = NULL, notified = 0 WHERE id = ?1",
            [id],
        )?;
        let frames: Vec<u32> = plan.iter().map(|f| f.frame).collect();
        let message = format!(
            "requeued: frame(s) {} render again ({units} unit(s) of work); their outputs are replaced when done",
            tessera::protocol::frame_ranges(&frames)
        );
        log_event(&tx, id, Event::new("job_requeued", &message))?;
        tx.commit()?;
        Ok(Control::Changed(Requeued::Queued { frames, units }))
    }

    /// Finished jobs (done, failed, cancelled), the one that finished first first: what the
    /// retention policy removes, in that order. (id, finished_at)
    pub fn finished_jobs_oldest_first(&self) -> Result<Vec<(u64, f64)>> {
        let conn = self.conn();
        let mut stmt = conn.prepare_cached(
            "SELECT id, coalesce(finished_at, submitted_at) AS t FROM jobs
             WHERE state IN ('done', 'failed', 'canceled') ORDER BY t, id",
        )?;
        let rows = stmt
            .query_map([], |r| Ok((r.get::<_, i64>(0)? as u64, r.get::<_, f64>(1)?)))?
            .collect::<rusqlite::Result<_>>()?;
        Ok(rows)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{row_of_pixels, store};

    /// A job of two frames of two one-pixel tiles, in `passes` passes of 16 samples.
    fn job(s: &Store, passes: u32) -> u64 {
        let frame = |k: u32| row_of_pixels(&format!("f{k}.png"), 2, 16 * passes);
        s.insert_job(&NewJob {
            name: "j".into(),
            tile_size: 1,
            pass_samples: Some(16),
            scene_path: "s.xml".into(),
            frames: vec![frame(0), frame(1)],
            ..Default::default()
        })
        .unwrap()
    }

    fn units(s: &Store, job: u64) -> Vec<(i64, i64, i64, String, Option<i64>)> {
        let conn = s.conn();
        let mut stmt = conn
            .prepare("SELECT frame, tile, pass, state, first_sample FROM tiles WHERE job_id = ?1 ORDER BY frame, pass, tile")
            .unwrap();
        stmt.query_map([job as i64], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?)))
            .unwrap()
            .collect::<rusqlite::Result<_>>()
            .unwrap()
    }

    fn kinds(s: &Store, job: u64) -> Vec<String> {
        s.job_log(job, 0).unwrap().unwrap().into_iter().map(|e| e.kind).collect()
    }

    #[test]
    fn a_paused_job_leases_nothing_and_resumes_where_it_was() {
        let (_dir, s) = store("ctl-pause");
        let j = job(&s, 1);
        let w = s.register_worker("w", 4, "").unwrap();
        assert!(s.lease(w, 60.0).unwrap().granted().is_some());
        assert_eq!(s.pause_job(j).unwrap(), Control::Changed(1));
        assert_eq!(s.job(j).unwrap().unwrap().state, JobState::Paused);
        assert!(s.lease(w, 60.0).unwrap().granted().is_none(), "a paused job leases nothing");
        assert_eq!(s.pause_job(j).unwrap(), Control::Refused(JobState::Paused));
        assert_eq!(s.resume_job(j).unwrap(), Control::Changed(JobState::Running));
        assert!(s.lease(w, 60.0).unwrap().granted().is_some());
        assert_eq!(s.resume_job(j).unwrap(), Control::Refused(JobState::Running));
        assert_eq!(s.pause_job(999).unwrap(), Control::NoSuchJob);
        assert!(s.cancel_job(j).unwrap());
        assert_eq!(s.pause_job(j).unwrap(), Control::Refused(JobState::Canceled));
        assert_eq!(s.set_priority(j, 3).unwrap(), Control::Refused(JobState::Canceled));
        let k = kinds(&s, j);
        assert!(k.contains(&"job_paused".to_string()) && k.contains(&"job_resumed".to_string()), "{k:?}");
    }

    #[test]
    fn a_queued_job_paused_resumes_queued_and_priority_changes_are_logged() {
        let (_dir, s) = store("ctl-prio");
        let j = job(&s, 1);
        assert_eq!(s.pause_job(j).unwrap(), Control::Changed(0));
        assert_eq!(s.resume_job(j).unwrap(), Control::Changed(JobState::Queued));
        assert_eq!(s.set_priority(j, -7).unwrap(), Control::Changed(0));
        assert_eq!(s.job(j).unwrap().unwrap().priority, -7);
        let log = s.job_log(j, 0).unwrap().unwrap();
        assert!(log.iter().any(|e| e.kind == "priority_changed" && e.message.contains("from 0 to -7")));
    }

    #[test]
    fn requeue_cuts_the_frames_again_as_submitted_and_refuses_what_it_cannot() {
        let (_dir, s) = store("ctl-requeue");
        let j = job(&s, 2);
        let before = units(&s, j);
        assert_eq!(before.len(), 8);
        assert_eq!(s.requeue_job(j, None).unwrap(), Control::Refused(JobState::Queued));
        assert!(s.cancel_job(j).unwrap());
        // The housekeeping purges a cancelled job's tile rows; requeue makes them again.
        while s.purge_job_rows(j, 100).unwrap() > 0 {}
        assert!(units(&s, j).is_empty());
        let far = [0..=u32::MAX];
        assert_eq!(
            s.requeue_job(j, Some(&far)).unwrap(),
            Control::Changed(Requeued::NoSuchFrame { asked: u32::MAX, frames: 2 })
        );
        assert_eq!(
            s.requeue_job(j, None).unwrap(),
            Control::Changed(Requeued::Queued { frames: vec![0, 1], units: 8 })
        );
        assert_eq!(units(&s, j), before);
        let row = s.job(j).unwrap().unwrap();
        assert_eq!((row.state, row.finished_at), (JobState::Queued, None));
        assert!(kinds(&s, j).contains(&"job_requeued".to_string()));
        // A done job without frames named has nothing unfinished.
        s.conn().execute("UPDATE jobs SET state = 'done' WHERE id = ?1", [j as i64]).unwrap();
        s.conn().execute("UPDATE frames SET outputs = '[]' WHERE job_id = ?1", [j as i64]).unwrap();
        assert_eq!(s.requeue_job(j, None).unwrap(), Control::Changed(Requeued::NothingUnfinished));
        let one = [1..=1];
        assert_eq!(
            s.requeue_job(j, Some(&one)).unwrap(),
            Control::Changed(Requeued::Queued { frames: vec![1], units: 4 })
        );
        assert_eq!(s.frames(j).unwrap()[0].outputs, Some(vec![]), "frame 0 keeps its outputs");
        assert_eq!(s.frames(j).unwrap()[1].outputs, None);
    }

    #[test]
    fn a_paused_job_can_be_cancelled_and_fails_like_any_other() {
        let (_dir, s) = store("ctl-pause-end");
        let j = job(&s, 1);
        assert_eq!(s.pause_job(j).unwrap(), Control::Changed(0));
        assert!(s.cancel_job(j).unwrap(), "a paused job is cancelled");
        let k = job(&s, 1);
        assert_eq!(s.pause_job(k).unwrap(), Control::Changed(0));
        s.fail_job(k, "broken").unwrap();
        assert_eq!(s.job(k).unwrap().unwrap().state, JobState::Failed);
        assert_eq!(
            s.finished_jobs_oldest_first().unwrap().iter().map(|(id, _)| *id).collect::<Vec<_>>(),
            [j, k]
        );
    }
}
