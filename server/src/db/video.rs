//! A job's video in the store: the options the job was submitted with (`jobs.video`,
//! `jobs.fps`), and what became of its video (`job_videos`, one row from the moment its
//! encoding starts: `encoding`, then `done` or `failed`), with the `video_done` /
//! `video_failed` events of the job's log written in the same transaction.

use tessera::protocol::VideoKind;

use super::*;

/// What became of jobs' videos: a row from the moment encoding starts.
const VIDEOS_SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS job_videos(
    job_id INTEGER PRIMARY KEY,
    kind TEXT NOT NULL,
    fps INTEGER NOT NULL,
    state TEXT NOT NULL,
    message TEXT,
    seconds REAL,
    bytes INTEGER
);
";

pub(super) fn create_videos_table(conn: &Connection) -> Result<()> {
    conn.execute_batch(VIDEOS_SCHEMA)?;
    Ok(())
}

/// A job's video as recorded once its encoding started.
#[derive(Clone, Debug, PartialEq)]
pub struct VideoRow {
    pub kind: VideoKind,
    pub fps: u32,
    /// `encoding`, `done` or `failed`.
    pub state: String,
    /// Why it failed, or why it is not the kind asked for.
    pub message: Option<String>,
    pub seconds: Option<f64>,
    pub bytes: Option<u64>,
}

impl Store {
    /// The video options job `job` was submitted with: (`video`, `fps`), `None` where the job
    /// gave none (or the job does not exist).
    pub fn video_options(&self, job: u64) -> Result<(Option<VideoKind>, Option<u32>)> {
        let conn = self.conn();
        let row: Option<(Option<String>, Option<i64>)> = conn
            .query_row_cached("SELECT video, fps FROM jobs WHERE id = ?1", [job as i64], |r| {
                Ok((r.get(0)?, r.get(1)?))
            })
            .optional()?;
        let (video, fps) = row.unwrap_or_default();
        Ok((video.as_deref().and_then(VideoKind::parse), fps.map(|f| f as u32)))
    }

    /// Records the video options of a job just stored.
    pub fn set_video_options(&self, job: u64, video: Option<VideoKind>, fps: Option<u32>) -> Result<()> {
        self.conn().execute_cached(
            "UPDATE jobs SET video = ?2, fps = ?3 WHERE id = ?1",
            params![job as i64, video.map(VideoKind::as_str), fps],
        )?;
        Ok(())
    }

    /// The scene files job `job`'s frames come from (1 for a job of one scene).
    pub fn scene_count(&self, job: u64) -> Result<u32> {
        let n: i64 = self.conn().query_row_cached(
            "SELECT count(DISTINCT coalesce(f.scene_path, j.scene_path)) FROM frames f JOIN jobs j ON j.id = f.job_id
             WHERE f.job_id = ?1",
            [job as i64],
            |r| r.get(0),
        )?;
        Ok(n.max(1) as u32)
    }

    /// Each frame's scene file (its own, or the job's), in frame order.
    pub fn frame_scenes(&self, job: u64) -> Result<Vec<String>> {
        let conn = self.conn();
        let mut stmt = conn.prepare_cached(
            "SELECT coalesce(f.scene_path, j.scene_path) FROM frames f JOIN jobs j ON j.id = f.job_id
             WHERE f.job_id = ?1 ORDER BY f.idx",
        )?;
        let rows = stmt.query_map([job as i64], |r| r.get(0))?.collect::<rusqlite::Result<Vec<String>>>()?;
        Ok(rows)
    }

    /// What became of job `job`'s video, once its encoding started.
    pub fn video(&self, job: u64) -> Result<Option<VideoRow>> {
        let conn = self.conn();
        Ok(conn
            .query_row_cached(
                "SELECT kind, fps, state, message, seconds, bytes FROM job_videos WHERE job_id = ?1",
                [job as i64],
                |r| {
                    let kind: String = r.get(0)?;
                    Ok(VideoRow {
                        kind: VideoKind::parse(&kind).unwrap_or(VideoKind::None),
                        fps: r.get::<_, i64>(1)? as u32,
                        state: r.get(2)?,
                        message: r.get(3)?,
                        seconds: r.get(4)?,
                        bytes: r.get::<_, Option<i64>>(5)?.map(|b| b as u64),
                    })
                },
            )
            .optional()?)
    }

    /// Marks job `job`'s video as being encoded (again, after a restart cut it off).
    pub fn video_encoding(&self, job: u64, kind: VideoKind, fps: u32, message: Option<&str>) -> Result<()> {
        self.conn().execute_cached(
            "INSERT INTO job_videos(job_id, kind, fps, state, message) VALUES (?1, ?2, ?3, 'encoding', ?4)
             ON CONFLICT(job_id) DO UPDATE SET kind = ?2, fps = ?3, state = 'encoding', message = ?4, seconds = NULL, bytes = NULL",
            params![job as i64, kind.as_str(), fps, message],
        )?;
        Ok(())
    }

    /// Records job `job`'s video as written (`bytes` long, in `seconds`), with a `video_done`
    /// event in its log.
    pub fn video_done(&self, job: u64, seconds: f64, bytes: u64, event: &str) -> Result<()> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        tx.execute_cached(
            "UPDATE job_videos SET state = 'done', seconds = ?2, bytes = ?3 WHERE job_id = ?1",
            params![job as i64, seconds, bytes as i64],
        )?;
        log_event(&tx, job as i64, Event { seconds: Some(seconds), ..Event::new("video_done", event) })?;
        tx.commit()?;
        Ok(())
    }

    /// Records that job `job`'s video could not be made, and why (`video_failed` in its log).
    /// Its frames stay done.
    pub fn video_failed(&self, job: u64, seconds: Option<f64>, message: &str) -> Result<()> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        tx.execute_cached(
            "UPDATE job_videos SET state = 'failed', message = ?2, seconds = ?3 WHERE job_id = ?1",
            params![job as i64, message, seconds],
        )?;
        log_event(&tx, job as i64, Event { seconds, ..Event::new("video_failed", message) })?;
        tx.commit()?;
        Ok(())
    }

    /// Jobs done whose video may be due and is not made: none recorded, or one whose encoding a
    /// stop cut off. (Whether each makes a video at all is the caller's rule.)
    pub fn videos_due(&self) -> Result<Vec<u64>> {
        let conn = self.conn();
        let mut stmt = conn.prepare_cached(
            "SELECT j.id FROM jobs j LEFT JOIN job_videos v ON v.job_id = j.id
             WHERE j.state = 'done' AND (v.state IS NULL OR v.state = 'encoding')
               AND (j.video IS NULL OR j.video != 'none')
             ORDER BY j.id",
        )?;
        let rows = stmt.query_map([], |r| r.get::<_, i64>(0))?.collect::<rusqlite::Result<Vec<_>>>()?;
        Ok(rows.into_iter().map(|id| id as u64).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{frame, job_of, store};

    fn job(s: &Store) -> u64 {
        let frames = vec![frame("a.png", 2, 2), frame("a.png", 2, 2)];
        s.insert_job(&NewJob {
            name: "v".into(),
            tile_size: 2,
            scene_path: "a.json".into(),
            ..job_of(frames)
        })
        .unwrap()
    }

    /// Options round-trip; the video's row goes from encoding to done or failed with its event,
    /// and a job is due until its video is done or failed.
    #[test]
    fn a_jobs_video_is_recorded_with_its_event() {
        let (_dir, s) = store("db-video");
        let id = job(&s);
        assert_eq!(s.video_options(id).unwrap(), (None, None));
        s.set_video_options(id, Some(VideoKind::Gif), Some(12)).unwrap();
        assert_eq!(s.video_options(id).unwrap(), (Some(VideoKind::Gif), Some(12)));
        assert_eq!(s.scene_count(id).unwrap(), 1);
        assert_eq!(s.frame_scenes(id).unwrap(), ["a.json", "a.json"]);
        assert!(s.videos_due().unwrap().is_empty(), "a queued job's video is not due");
        s.conn().execute("UPDATE jobs SET state = 'done' WHERE id = ?1", [id as i64]).unwrap();
        assert_eq!(s.videos_due().unwrap(), [id]);
        s.video_encoding(id, VideoKind::Gif, 12, None).unwrap();
        assert_eq!(s.videos_due().unwrap(), [id], "cut off while encoding: still due");
        s.video_done(id, 1.5, 1234, "video.gif written").unwrap();
        let v = s.video(id).unwrap().unwrap();
        assert_eq!((v.kind, v.fps, v.state.as_str(), v.bytes), (VideoKind::Gif, 12, "done", Some(1234)));
        assert!(s.videos_due().unwrap().is_empty());
        s.video_encoding(id, VideoKind::Mp4, 12, Some("again")).unwrap();
        s.video_failed(id, None, "ffmpeg exited with status 1").unwrap();
        let v = s.video(id).unwrap().unwrap();
        assert_eq!((v.state.as_str(), v.message.as_deref()), ("failed", Some("ffmpeg exited with status 1")));
        let log = s.job_log(id, 0).unwrap().unwrap();
        let kinds: Vec<&str> = log.iter().map(|e| e.kind.as_str()).collect();
        assert!(kinds.ends_with(&["video_done", "video_failed"]), "{kinds:?}");
        assert_eq!(log.iter().find(|e| e.kind == "video_done").unwrap().seconds, Some(1.5));
        // A full log still records what became of the video.
        s.conn()
            .execute(
                "INSERT INTO job_events(job_id, seq, at, kind, message) VALUES (?1, ?2, 0, 'tile_done', 'x')",
                params![id as i64, MAX_JOB_EVENTS + 1],
            )
            .unwrap();
        s.video_failed(id, None, "again").unwrap();
        let last = s.job_log(id, 0).unwrap().unwrap().pop().unwrap();
        assert_eq!((last.kind.as_str(), last.message.as_str()), ("video_failed", "again"));
        s.set_video_options(id, Some(VideoKind::None), None).unwrap();
        s.conn().execute("DELETE FROM job_videos", []).unwrap();
        assert!(s.videos_due().unwrap().is_empty(), "video=none is never due");
    }
}
