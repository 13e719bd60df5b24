//! A new job in the store: its row, its frames (each with its scene file), the files it names
//! (`job_files`) and its units of work, written in steps while the job is `inserting`.

use super::*;

/// A new job's rows.
#[derive(Default)]
pub struct NewJob {
    pub name: String,
    pub priority: i64,
    pub tile_size: u32,
    pub samples: Option<u32>,
    pub bundle: String,
    pub scene_path: String,
    pub frames: Vec<NewFrame>,
    /// The scene's warnings, one `warning` event each in the job's log.
    pub warnings: Vec<String>,
    /// Render the scene without its unsupported elements (`allow_unsupported=true`).
    pub allow_unsupported: bool,
    /// Tiles carry the denoiser's features, and each merged frame is also written denoised
    /// (`denoise=true`).
    pub denoise: bool,
    /// Samples per pass as the job asked (`pass_samples`); `None`: the default.
    pub pass_samples: Option<u32>,
    /// Stop a tile once its noise is at most this (`noise_target`).
    pub noise_target: Option<f64>,
    /// SHA-256 of the job's [`tessera::protocol::Manifest`] (in the file store), for a job whose
    /// files are there (`bundle` is then ""); `None`: a tar bundle.
    pub manifest: Option<String>,
    /// The manifest's files, one `job_files` row each (what keeps them in the file store).
    pub files: Vec<tessera::protocol::JobFile>,
    /// Scene files the job renders (more than one: a sequence, leased frame by frame).
    pub scenes: u32,
    /// The options as asked (`None`: the default): `video`, `fps`, `keep_float`.
    pub video: Option<tessera::protocol::VideoKind>,
    pub fps: Option<u32>,
    pub keep_float: Option<bool>,
    /// Where to POST the job's end (checked by the submission).
    pub notify_url: Option<String>,
    /// Every frame rendered at this scale (`scale`; the frames' sizes are already scaled).
    pub scale: Option<f64>,
    /// Tags a worker must all have to lease its tiles (checked by the submission).
    pub worker_tags: Vec<String>,
}

#[derive(Default)]
pub struct NewFrame {
    pub camera: u32,
    pub image_name: String,
    pub width: u32,
    pub height: u32,
    pub tiles: Vec<Rect>,
    /// Samples per pixel (the job's `samples` or the camera's `NumSamples`).
    pub samples: u32,
    /// Samples per pass, whole blocks; at least `samples` renders every tile in one piece.
    pub pass_samples: u32,
    /// The frame's scene file (a path of the job's manifest); `None`: the job's `scene_path`.
    pub scene_path: Option<String>,
}

impl NewFrame {
    /// The passes of each tile.
    pub fn passes(&self) -> u32 {
        tessera::passes::pass_count(self.samples, self.pass_samples)
    }
}

/// The first event of a job's log: what was accepted.
fn accepted_message(job: &NewJob) -> String {
    let tiles: usize = job.frames.iter().map(|f| f.tiles.len()).sum();
    let passes = job.frames.iter().map(NewFrame::passes).max().unwrap_or(1);
    let in_passes = match (passes, job.frames.first()) {
        (1, _) | (_, None) => String::new(),
        (_, Some(f)) => format!(
            ", {passes} pass(es) of {} samples{}",
            f.pass_samples,
            job.noise_target.map(|t| format!(", noise target {t}")).unwrap_or_default()
        ),
    };
    let scene = match job.scenes {
        0 | 1 => format!("scene {}", job.scene_path),
        n => format!(
            "{n} scene files from {} to {}",
            job.scene_path,
            job.frames.last().and_then(|f| f.scene_path.as_deref()).unwrap_or(&job.scene_path)
        ),
    };
    let scale = match (job.scale, job.frames.first()) {
        (Some(s), Some(f)) => format!(", at scale {s} ({}x{})", f.width, f.height),
        _ => String::new(),
    };
    format!(
        "accepted: {} frame(s), {tiles} tile(s) of {} px{in_passes}{scale}, {scene}",
        job.frames.len(),
        job.tile_size,
    )
}

impl Store {
    /// Stores a new job and queues it; returns its id.
    ///
    /// A job may be a million rows (tiles x passes): they are written [`ROWS_PER_STEP`] to a
    /// transaction, the store's lock let go between two, while the job is `inserting`, a state
    /// that no lease, listing or view sees. The last step queues it. A job left `inserting` by a
    /// stop of the server fails when the store opens again ([`INTERRUPTED_INSERT`]); one whose
    /// rows cannot be written fails at once; either way its rows are purged.
    pub fn insert_job(&self, job: &NewJob) -> Result<u64> {
        let id = {
            let mut conn = self.conn();
            let tx = conn.transaction()?;
            // Past every id the store holds and every job folder the data directory holds.
            let next: i64 =
                tx.query_row_cached("SELECT coalesce(max(id), 0) + 1 FROM jobs", [], |r| r.get(0))?;
            let floor = self.min_job_id.load(std::sync::atomic::Ordering::SeqCst);
            let id = next.max(i64::try_from(floor).unwrap_or(i64::MAX));
            tx.execute_cached(
                "INSERT INTO jobs(id, name, state, priority, tile_size, samples, bundle, scene_path, submitted_at, allow_unsupported, denoise, pass_samples, noise_target, manifest, scenes, video, fps, keep_float, notify_url, worker_tags) VALUES (?12, ?1, 'inserting', ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?13, ?14, ?15, ?16, ?17, ?18, ?19)",
                params![
                    job.name,
                    job.priority,
                    job.tile_size,
                    job.samples,
                    job.bundle,
                    job.scene_path,
                    now(),
                    job.allow_unsupported,
                    job.denoise,
                    job.pass_samples,
                    job.noise_target,
                    id,
                    job.manifest,
                    job.scenes.max(1),
                    job.video.map(|v| v.as_str()),
                    job.fps,
                    job.keep_float,
                    job.notify_url,
                    super::workers::tags_to_text(&job.worker_tags),
                ],
            )?;
            if job.scale.is_some() {
                tx.execute_cached("UPDATE jobs SET scale = ?2 WHERE id = ?1", params![id, job.scale])?;
            }
            for (i, f) in job.frames.iter().enumerate() {
                tx.execute_cached(
                    "INSERT INTO frames(job_id, idx, camera, image_name, width, height, tiles_total, samples, passes_total, scene_path) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10)",
                    params![id, i as i64, f.camera, f.image_name, f.width, f.height, f.tiles.len() as i64, f.samples, f.passes(), f.scene_path],
                )?;
            }
            // The files the job names, in the transaction that makes the job: from here on the
            // file store keeps them for it.
            for file in &job.files {
                tx.execute_cached(
                    "INSERT INTO job_files(job_id, path, sha256, size) VALUES (?1, ?2, ?3, ?4)",
                    params![id, file.path, file.sha256, file.size as i64],
                )?;
            }
            log_event(&tx, id, Event::new("accepted", &accepted_message(job)))?;
            tx.commit()?;
            self.keep_job_ids_above(id as u64);
            id
        };
        if let Err(e) = self.insert_job_rows(id, job) {
            let _ = self.conn().execute(
                "UPDATE jobs SET state = 'failed', finished_at = ?2, error = ?3 WHERE id = ?1 AND state = 'inserting'",
                params![id, now(), "the server could not store this job's tiles; submit it again"],
            );
            return Err(e);
        }
        let queued = self
            .conn()
            .execute("UPDATE jobs SET state = 'queued' WHERE id = ?1 AND state = 'inserting'", [id])?;
        anyhow::ensure!(queued == 1, "job {id} left its inserting state while it was being stored");
        Ok(id as u64)
    }

    /// The warnings and tile rows of job `id` (still `inserting`), a step at a time.
    fn insert_job_rows(&self, id: i64, job: &NewJob) -> Result<()> {
        for warnings in job.warnings.chunks(256) {
            let mut conn = self.conn();
            let tx = conn.transaction()?;
            for w in warnings {
                log_event(&tx, id, Event::new("warning", w))?;
            }
            tx.commit()?;
        }
        // One row per tile and pass. A tile of one pass renders whole (no sample range); a
        // tile of several renders pass by pass. Under a noise target a tile's pass waits until
        // the one before it was added up and found too noisy.
        let mut units = job.frames.iter().enumerate().flat_map(|(i, f)| {
            let passes = f.passes();
            (0..passes)
                .flat_map(move |k| f.tiles.iter().enumerate().map(move |(t, r)| (i, f, t, r, k, passes)))
        });
        const ROWS: usize = 128;
        let insert = |n: usize| {
            let row = "(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)";
            format!(
                "INSERT INTO tiles(job_id, frame, tile, x0, y0, w, h, pass, first_sample, end_sample, state) VALUES {}",
                vec![row; n].join(", ")
            )
        };
        for steps in 1.. {
            let step: Vec<_> = units.by_ref().take(ROWS_PER_STEP).collect();
            if step.is_empty() {
                break;
            }
            {
                let mut conn = self.conn();
                let tx = conn.transaction()?;
                for chunk in step.chunks(ROWS) {
                    let mut stmt = tx.prepare_cached(&insert(chunk.len()))?;
                    let mut values: Vec<rusqlite::types::Value> = Vec::with_capacity(chunk.len() * 11);
                    for &(i, f, t, r, k, passes) in chunk {
                        let range =
                            (passes > 1).then(|| tessera::passes::pass_range(f.samples, f.pass_samples, k));
                        let state = if k > 0 && job.noise_target.is_some() { "waiting" } else { "queued" };
                        use rusqlite::types::Value::{Integer, Null, Text};
                        values.extend([
                            Integer(id),
                            Integer(i as i64),
                            Integer(t as i64),
                            Integer(i64::from(r.x0)),
                            Integer(i64::from(r.y0)),
                            Integer(i64::from(r.width)),
                            Integer(i64::from(r.height)),
                            Integer(i64::from(k)),
                            range.map_or(Null, |r| Integer(i64::from(r.start))),
                            range.map_or(Null, |r| Integer(i64::from(r.end))),
                            Text(state.into()),
                        ]);
                    }
                    stmt.execute(rusqlite::params_from_iter(values))?;
                }
                tx.commit()?;
            }
            // The lock is free: let whoever waits for it (a lease, a view) take it before the
            // next step does. Every few steps the log is copied into the database file (outside
            // the lock), so that it starts over instead of growing by the whole job.
            if steps % CHECKPOINT_STEPS == 0 {
                self.checkpoint_to_start_over()?;
            }
            std::thread::sleep(STEP_PAUSE);
        }
        Ok(())
    }

    /// The frames of job `job` some of whose units are leased now (the rest of a frame's
    /// progress is on its row: tiles done, passes published). An index seek
    /// (`tiles_queue_by_frame`) over the few live leases, whatever the job's length.
    pub fn frames_leased(&self, job: u64) -> Result<std::collections::HashSet<u32>> {
        let conn = self.conn();
        let mut stmt =
            conn.prepare_cached("SELECT DISTINCT frame FROM tiles WHERE job_id = ?1 AND state = 'leased'")?;
        let rows = stmt.query_map([job as i64], |r| r.get::<_, i64>(0))?;
        let mut out = std::collections::HashSet::new();
        for r in rows {
            out.insert(r? as u32);
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{row_of_pixels, store};

    /// A job of two frames of two one-pixel tiles in two passes each, from `scenes` scene files.
    fn two_by_two(s: &Store, scenes: u32) -> u64 {
        let frame = |k: u32| NewFrame {
            scene_path: Some(format!("s{}.xml", if scenes > 1 { k } else { 0 })),
            ..row_of_pixels(&format!("f{k}.png"), 2, 32)
        };
        s.insert_job(&NewJob {
            name: "j".into(),
            tile_size: 1,
            bundle: String::new(),
            scene_path: "s0.xml".into(),
            frames: vec![frame(0), frame(1)],
            manifest: Some("m".repeat(64)),
            files: vec![tessera::protocol::JobFile {
                path: "s0.xml".into(),
                sha256: "a".repeat(64),
                size: 3,
            }],
            scenes,
            ..Default::default()
        })
        .unwrap()
    }

    /// (pass, tile, scene file) of the units leased one after another.
    fn lease_order(s: &Store, n: usize) -> Vec<(u32, u32, String)> {
        let w = s.register_worker("w", 16, "").unwrap();
        (0..n)
            .map(|_| {
                let l = s.lease(w, 60.0).unwrap().granted().expect("a lease");
                assert_eq!(l.manifest.as_deref(), Some("m".repeat(64).as_str()));
                assert_eq!(l.bundle, "");
                (l.pass.map_or(0, |p| p.index), l.tile, l.scene_path)
            })
            .collect()
    }

    #[test]
    fn a_sequence_is_leased_frame_by_frame_and_one_scene_pass_by_pass() {
        let (_dir, s) = store("seq-order");
        let seq = two_by_two(&s, 2);
        let frames: Vec<Option<String>> = s.frames(seq).unwrap().into_iter().map(|f| f.scene_path).collect();
        assert_eq!(frames, [Some("s0.xml".to_string()), Some("s1.xml".to_string())]);
        let n: i64 = s
            .conn()
            .query_row("SELECT count(*) FROM job_files WHERE job_id = ?1", [seq as i64], |r| r.get(0))
            .unwrap();
        assert_eq!(n, 1, "the job's files are rows of job_files");
        let order = lease_order(&s, 8);
        // Frame 0's passes (each over its tiles) before any of frame 1's, each from its scene.
        let s0 = |p, t| (p, t, "s0.xml".to_string());
        let s1 = |p, t| (p, t, "s1.xml".to_string());
        assert_eq!(order, [s0(0, 0), s0(0, 1), s0(1, 0), s0(1, 1), s1(0, 0), s1(0, 1), s1(1, 0), s1(1, 1)]);
        // One scene file: every frame's first pass before any second pass.
        let (_dir, s) = store("seq-order-one");
        two_by_two(&s, 1);
        let passes: Vec<u32> = lease_order(&s, 8).into_iter().map(|(p, _, _)| p).collect();
        assert_eq!(passes, [0, 0, 0, 0, 1, 1, 1, 1]);
    }
}
