//! The job store: one SQLite database in WAL mode (`tessera.db` in the data directory).
//!
//! SQLite is the single source of truth for jobs, frames, tiles (with their rendered pixels;
//! a large tile's are a file of its own that its row names: `results.rs`),
//! leases and workers, so a server killed at any instant restarts with everything it had
//! accepted: a tile result is acknowledged only after its transaction commits. Leases do not
//! survive a restart (their workers may be gone): [`Store::open`] puts every leased tile back in
//! the queue, and a late result for such a lease is refused like any expired one.
//!
//! All access goes through one `std::sync::Mutex<Connection>`; every method is a short
//! transaction that never crosses an `.await`.

use std::path::Path;
use std::sync::Mutex;

use anyhow::{Context, Result};
use rusqlite::{Connection, OptionalExtension, params};
use tessera::protocol::{JobEvent, JobState, Lease, Rect};

use crate::failures::{self, TileFailures};

mod control;
mod counters;
mod files;
mod jobs;
mod leases;
mod notify;
mod passes;
mod results;
mod schema;
mod upkeep;
mod video;
mod workers;

pub use control::{Control, Requeued};
pub use files::Deleted;
pub use jobs::{NewFrame, NewJob};
pub use notify::{DueNotification, Notified};
pub use passes::ResultShape;
pub use results::{FILE_RESULT_BYTES, RESULT_GRACE, RESULTS_DIR, ResultBody};
pub use video::VideoRow;
pub use workers::{NewWorker, ServingWorker};

/// Most events a job's log keeps: a job of a million tiles must not write a million rows of
/// log. The event after the last one kept says the log
/// is full (`log_truncated`); the job's end (done, failed, cancelled) is still recorded, so a
/// log holds at most this many events plus three (with the job's video, [`JOB_EVENT_KINDS_VIDEO`]).
pub const MAX_JOB_EVENTS: i64 = 10_000;

/// Rows written or deleted per transaction when a job's tiles are stored or purged: the store's
/// lock is let go between two such steps, so that leases, results and views of other clients
/// wait for one step at most (a few milliseconds), never for the whole job.
pub const ROWS_PER_STEP: usize = 2048;

/// Steps of [`ROWS_PER_STEP`] rows between two checkpoints of a long insertion or purge (a
/// few MiB of log).
pub const CHECKPOINT_STEPS: usize = 8;

/// How often the server copies the write-ahead log into the database file
/// ([`Store::checkpoint`]).
pub const CHECKPOINT_EVERY: std::time::Duration = std::time::Duration::from_millis(250);

/// Why a job left half stored by a stop of the server failed.
pub const INTERRUPTED_INSERT: &str =
    "the server stopped while it was storing this job, before the job was queued; submit it again";

/// The kinds that end a job: recorded whatever the length of its log.
pub const JOB_EVENT_KINDS_FINAL: [&str; 3] = ["job_done", "job_failed", "job_cancelled"];

/// What became of a job's video, after its end: recorded whatever the length of its log too.
pub const JOB_EVENT_KINDS_VIDEO: [&str; 2] = ["video_done", "video_failed"];

/// One entry of a job's log to record ([`log_event`]).
struct Event<'a> {
    kind: &'static str,
    frame: Option<i64>,
    tile: Option<i64>,
    /// The worker's id; the log keeps the id and shows the worker's name when read.
    worker: Option<i64>,
    seconds: Option<f64>,
    message: &'a str,
}

impl<'a> Event<'a> {
    fn new(kind: &'static str, message: &'a str) -> Event<'a> {
        Event { kind, frame: None, tile: None, worker: None, seconds: None, message }
    }
    fn tile(self, frame: i64, tile: i64) -> Self {
        Event { frame: Some(frame), tile: Some(tile), ..self }
    }
    fn worker(self, worker: i64) -> Self {
        Event { worker: Some(worker), ..self }
    }
}

/// Appends `e` to the log of `job` inside the caller's transaction, so an event is recorded
/// exactly when what it tells of is. Past [`MAX_JOB_EVENTS`] only the job's end is kept (and
/// once, a `log_truncated` event saying so).
fn log_event(tx: &Connection, job: i64, e: Event<'_>) -> Result<()> {
    let last: i64 = tx
        .prepare_cached("SELECT coalesce(max(seq), 0) FROM job_events WHERE job_id = ?1")?
        .query_row([job], |r| r.get(0))?;
    // The worker's name is kept with the event: the log still names a worker after its row is
    // forgotten (`Store::forget_workers`).
    let mut insert = tx.prepare_cached(
        "INSERT INTO job_events(job_id, seq, at, kind, frame, tile, worker_id, seconds, message, worker)
         VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, (SELECT name FROM workers WHERE id = ?7))",
    )?;
    let kept = JOB_EVENT_KINDS_FINAL.contains(&e.kind) || JOB_EVENT_KINDS_VIDEO.contains(&e.kind);
    if last >= MAX_JOB_EVENTS && !kept {
        if last == MAX_JOB_EVENTS {
            let message = format!(
                "the log is full ({MAX_JOB_EVENTS} events): later tile and frame events of this job are not \
                 recorded; its end still is"
            );
            insert.execute(params![
                job,
                last + 1,
                now(),
                "log_truncated",
                None::<i64>,
                None::<i64>,
                None::<i64>,
                None::<f64>,
                message
            ])?;
        }
        return Ok(());
    }
    insert.execute(params![job, last + 1, now(), e.kind, e.frame, e.tile, e.worker, e.seconds, e.message])?;
    Ok(())
}

/// What [`Store::expire_leases`] did.
#[derive(Debug, Default)]
pub struct Expired {
    /// Leases that expired.
    pub leases: usize,
    /// Jobs failed because a tile kept crashing its workers: (job, message).
    pub failed_jobs: Vec<(u64, String)>,
}

/// Records a failure of `tile` on `worker` inside `tx`: the tile goes back to the queue, or its
/// job fails, as the failure rule ([`failures::tile_verdict`]) says. A lease expiry is such a
/// failure too (the worker crashed).
fn record_failure(
    tx: &rusqlite::Transaction<'_>,
    (job, frame, tile, pass): (i64, i64, i64, i64),
    worker: i64,
    failure: Failure<'_>,
    t: f64,
) -> Result<FailOutcome> {
    let (kind, error, fatal) = match failure {
        Failure::Reported { error, fatal } => ("tile_failed", error, fatal),
        Failure::LeaseExpired { error } => ("lease_expired", error, false),
    };
    log_event(tx, job, Event::new(kind, error).tile(frame, tile).worker(worker))?;
    tx.execute_cached(
        "INSERT INTO tile_failures(job_id, frame, tile, worker_id, error, at) VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
        params![job, frame, tile, worker, error, t],
    )?;
    tx.execute_cached(
        "UPDATE workers SET failures = failures + 1, rendering = NULL WHERE id = ?1",
        [worker],
    )?;
    tx.execute_cached(
        "UPDATE tiles SET state = 'queued', lease_id = NULL, worker_id = NULL, deadline = NULL WHERE job_id = ?1 AND frame = ?2 AND tile = ?3 AND pass = ?4",
        params![job, frame, tile, pass],
    )?;
    let failures = tx.query_row_cached(
        "SELECT count(DISTINCT worker_id), count(*), sum(error LIKE '% stopped answering while rendering this tile %')
         FROM tile_failures WHERE job_id = ?1 AND frame = ?2 AND tile = ?3",
        params![job, frame, tile],
        |r| {
            Ok(TileFailures {
                workers: r.get(0)?,
                total: r.get(1)?,
                crashes: r.get::<_, Option<i64>>(2)?.unwrap_or(0),
            })
        },
    )?;
    let Some(message) = failures::tile_verdict(frame, tile, failures, error, fatal) else {
        return Ok(FailOutcome::Requeued);
    };
    let ended = tx.execute_cached(
        "UPDATE jobs SET state = 'failed', error = ?2, finished_at = ?3 WHERE id = ?1 AND state IN ('queued', 'running', 'paused')",
        params![job, message, t],
    )?;
    if ended > 0 {
        log_event(tx, job, Event::new("job_failed", &message))?;
    }
    revoke_leases(tx, job)?;
    Ok(FailOutcome::JobFailed { job: job as u64, message })
}

/// What [`record_failure`] records: a failure the worker reported, or a lease that expired.
enum Failure<'a> {
    Reported { error: &'a str, fatal: bool },
    LeaseExpired { error: &'a str },
}

/// Takes back the live leases of a job that has ended: heartbeats and watches report them
/// revoked, results for them are refused. Its queued tiles stay as they are (an index seek
/// touches only the leased ones): leasing looks at live jobs only, so they are never handed
/// out, and cancelling a job of a million tiles costs as little as one of ten.
fn revoke_leases(tx: &rusqlite::Transaction<'_>, job: i64) -> Result<()> {
    tx.execute_cached(
        "UPDATE tiles SET state = 'canceled', lease_id = NULL, worker_id = NULL, deadline = NULL WHERE job_id = ?1 AND state = 'leased'",
        [job],
    )?;
    Ok(())
}

/// What [`Store::register_worker_within`] did.
#[derive(Debug, PartialEq)]
pub enum Registered {
    Id(u64),
    /// As many workers as allowed are live.
    Full {
        live: u64,
    },
}

/// Prepared statements the connection keeps: more than the store runs after it opens.
const STATEMENT_CACHE: usize = 96;

/// `execute` and `query_row` through the connection's statement cache: the store's statements
/// are a fixed set, so each is parsed once per connection instead of once per call.
trait Cached {
    fn execute_cached<P: rusqlite::Params>(&self, sql: &str, params: P) -> rusqlite::Result<usize>;
    fn query_row_cached<T, P: rusqlite::Params, F: FnOnce(&rusqlite::Row<'_>) -> rusqlite::Result<T>>(
        &self,
        sql: &str,
        params: P,
        f: F,
    ) -> rusqlite::Result<T>;
}

impl Cached for Connection {
    fn execute_cached<P: rusqlite::Params>(&self, sql: &str, params: P) -> rusqlite::Result<usize> {
        self.prepare_cached(sql)?.execute(params)
    }

    fn query_row_cached<T, P: rusqlite::Params, F: FnOnce(&rusqlite::Row<'_>) -> rusqlite::Result<T>>(
        &self,
        sql: &str,
        params: P,
        f: F,
    ) -> rusqlite::Result<T> {
        self.prepare_cached(sql)?.query_row(params, f)
    }
}

pub struct Store {
    conn: Mutex<Connection>,
    next_lease: Mutex<u64>,
    /// The least id the next job may take ([`Store::keep_job_ids_above`]); grows past every id
    /// handed out, so an id is never taken twice while the server runs.
    min_job_id: std::sync::atomic::AtomicU64,
    /// A second connection that only copies the write-ahead log into the database file
    /// ([`Store::checkpoint`]), so that no request waits for that behind the store's lock.
    checkpointer: Mutex<Connection>,
    /// Jobs whose frames are being queued again in steps (`control.rs`): not purged nor deleted
    /// meanwhile.
    requeueing: Mutex<std::collections::HashSet<u64>>,
    /// The folder of large tile results, beside the database (`results.rs`).
    results_dir: std::path::PathBuf,
    /// Seconds a worker is kept off a tile it failed (the bits of an `f64`;
    /// [`failures::RETRY_FAILED_AFTER`] unless [`Store::set_retry_failed_after`]).
    retry_failed_after: std::sync::atomic::AtomicU64,
}

#[derive(Clone, Debug)]
pub struct JobRow {
    pub id: u64,
    pub name: String,
    pub state: JobState,
    pub priority: i64,
    pub tile_size: u32,
    pub samples: Option<u32>,
    pub bundle: String,
    pub scene_path: String,
    pub submitted_at: f64,
    pub started_at: Option<f64>,
    pub finished_at: Option<f64>,
    pub error: Option<String>,
    pub denoise: bool,
    pub pass_samples: Option<u32>,
    pub noise_target: Option<f64>,
    /// SHA-256 of the job's manifest (its files in the file store); `None`: a tar `bundle`.
    pub manifest: Option<String>,
    /// Scene files the job renders (more than one: a sequence).
    pub scenes: u32,
    /// The options as asked; `None`: the default.
    pub video: Option<tessera::protocol::VideoKind>,
    pub fps: Option<u32>,
    pub keep_float: Option<bool>,
    /// Every frame rendered at this scale (`None`: the cameras' resolution).
    pub scale: Option<f64>,
    /// Tags a worker must all have to lease the job's tiles (none: any worker).
    pub worker_tags: Vec<String>,
}

/// A frame in passes at one moment ([`Store::pass_snapshot`]).
#[derive(Debug, Clone, Copy)]
pub struct PassSnapshot {
    /// Passes every tile has finished.
    pub passes: u32,
    /// The fewest samples any tile's pixels have.
    pub least: i64,
    /// Tiles that need no more passes (the noise target stopped them, or their last is in).
    pub finished: i64,
    pub tiles: i64,
    /// Every tile is in: the frame's merge is due, and supersedes any pass picture.
    pub complete: bool,
}

#[derive(Clone, Debug)]
pub struct FrameRow {
    pub job_id: u64,
    pub index: u32,
    pub camera: u32,
    pub image_name: String,
    pub width: u32,
    pub height: u32,
    pub tiles_total: u32,
    pub tiles_done: u32,
    /// Output file names once merged.
    pub outputs: Option<Vec<String>>,
    /// Samples per pixel, passes per tile, and the passes every tile has finished whose frame
    /// was published (`pass.exr`, `pass.png`).
    pub samples: u32,
    pub passes_total: u32,
    pub passes_published: u32,
    /// The frame's scene file; `None`: the job's `scene_path` (jobs from before sequences).
    pub scene_path: Option<String>,
    /// Pixel-samples in the frame's film (each tile's pixels times the samples added into it),
    /// and those that tiles stopped by the noise target will never take: counters kept with
    /// the tiles' results, so that progress costs no scan of the tiles.
    pub samples_done: u64,
    pub samples_skipped: u64,
}

impl FrameRow {
    /// Pixel-samples the frame takes at most: every pixel at `samples`, less those skipped.
    pub fn samples_total(&self) -> u64 {
        let all = u64::from(self.width) * u64::from(self.height) * u64::from(self.samples.max(1));
        all.saturating_sub(self.samples_skipped).max(self.samples_done)
    }
}

#[derive(Clone, Debug)]
pub struct WorkerRow {
    pub id: u64,
    pub name: String,
    pub threads: u32,
    pub registered_at: f64,
    pub last_seen: f64,
    pub tiles_done: u64,
    pub failures: u64,
    pub rendering: Option<u64>,
    /// The tile of `rendering`: (job, frame, tile).
    pub current_tile: Option<(u64, u32, u32)>,
    /// Whether it takes new work: `active`, `draining` or `disabled` ([`WorkerMode`]).
    pub mode: WorkerMode,
    /// The tags it declared at its registration.
    pub tags: Vec<String>,
}

/// Whether a worker takes new work.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WorkerMode {
    /// Takes leases.
    Active,
    /// Finishes the leases it holds, takes no new one.
    Draining,
    /// Takes no lease; the leases it held were queued again when it was disabled.
    Disabled,
}

impl WorkerMode {
    pub fn as_str(self) -> &'static str {
        match self {
            WorkerMode::Active => "active",
            WorkerMode::Draining => "draining",
            WorkerMode::Disabled => "disabled",
        }
    }

    pub fn parse(s: &str) -> Option<WorkerMode> {
        Some(match s {
            "active" => WorkerMode::Active,
            "draining" => WorkerMode::Draining,
            "disabled" => WorkerMode::Disabled,
            _ => return None,
        })
    }
}

/// What happened to a submitted result.
#[derive(Debug, PartialEq)]
pub enum ResultOutcome {
    /// Stored; `frame_complete` when it was the frame's last tile.
    Accepted {
        job_id: u64,
        frame: u32,
        tile: u32,
        rect: Rect,
        tiles_done: u32,
        tiles_total: u32,
        frame_complete: bool,
        /// Every tile of the frame has now finished this many passes (and the frame is not
        /// complete): publish the frame as it stands.
        pass_published: Option<u32>,
    },
    /// No such live lease (expired, revoked, already submitted, job not running).
    Conflict,
    /// The pixel count does not match the lease's rectangle.
    WrongSize { expected: usize },
}

/// What a lease request got from the store.
#[derive(Debug, PartialEq)]
pub enum Leased {
    Granted(Lease),
    /// Nothing is queued that this worker may take.
    NoWork,
    /// The worker holds as many live leases as it may ([`max_live_leases`]).
    Full {
        held: u32,
        allowed: u32,
    },
}

impl Leased {
    /// The lease, if one was granted.
    pub fn granted(self) -> Option<Lease> {
        match self {
            Leased::Granted(l) => Some(l),
            _ => None,
        }
    }
}

/// Most live leases a worker of `threads` render threads may hold: one per thread, the one it
/// fetches ahead, and one whose finished tile is on its way (a lease lives until its result is
/// committed; without that one the next lease would wait for each upload, and a render slot
/// would idle through every short tile). A worker that asks for more is refused, so one
/// registration cannot take a farm's queue for itself.
pub fn max_live_leases(threads: u32) -> u32 {
    threads.saturating_add(2)
}

/// What a tile failure did.
#[derive(Debug, PartialEq)]
pub enum FailOutcome {
    Requeued,
    JobFailed { job: u64, message: String },
    Conflict,
}

/// How long a frame's merge took, for its log: assembling the tiles and writing the files
/// that need no tone mapping, and tone mapping (with its PNG) where the frame has one.
#[derive(Clone, Debug, Default)]
pub struct MergeTiming {
    pub merge_seconds: f64,
    pub tonemap_seconds: Option<f64>,
    /// The denoiser's run (OIDN's filters) and a description of it, for denoised jobs.
    pub denoise: Option<(f64, String)>,
}

/// What /metrics reads from the store.
pub struct StoreMetrics {
    pub jobs_by_state: Vec<(String, i64)>,
    pub tiles_done: i64,
    pub render_seconds_sum: f64,
    pub render_seconds_count: i64,
}

pub fn now() -> f64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs_f64()).unwrap_or(0.0)
}

/// The tile rectangle in columns `at`..`at + 4` (x0, y0, w, h) of a row.
fn rect_at(r: &rusqlite::Row, at: usize) -> rusqlite::Result<Rect> {
    Ok(Rect {
        x0: r.get::<_, i64>(at)? as u32,
        y0: r.get::<_, i64>(at + 1)? as u32,
        width: r.get::<_, i64>(at + 2)? as u32,
        height: r.get::<_, i64>(at + 3)? as u32,
    })
}

/// A unit's pass as a lease names it (columns pass, first_sample, end_sample, passes_total from
/// `at`); `None` for a tile rendered whole.
fn unit_pass(r: &rusqlite::Row, at: usize) -> rusqlite::Result<Option<tessera::protocol::PassLease>> {
    let index: i64 = r.get(at)?;
    let range = r.get::<_, Option<i64>>(at + 1)?.zip(r.get::<_, Option<i64>>(at + 2)?);
    let count: i64 = r.get(at + 3)?;
    Ok(range.map(|(start, end)| tessera::protocol::PassLease {
        index: index as u32,
        count: count as u32,
        start: start as u32,
        end: end as u32,
    }))
}

fn job_from_row(r: &rusqlite::Row) -> rusqlite::Result<JobRow> {
    let state: String = r.get(2)?;
    Ok(JobRow {
        id: r.get::<_, i64>(0)? as u64,
        name: r.get(1)?,
        state: JobState::parse(&state).unwrap_or(JobState::Failed),
        priority: r.get(3)?,
        tile_size: r.get::<_, i64>(4)? as u32,
        samples: r.get::<_, Option<i64>>(5)?.map(|s| s as u32),
        bundle: r.get(6)?,
        scene_path: r.get(7)?,
        submitted_at: r.get(8)?,
        started_at: r.get(9)?,
        finished_at: r.get(10)?,
        error: r.get(11)?,
        denoise: r.get(12)?,
        pass_samples: r.get::<_, Option<i64>>(13)?.map(|s| s as u32),
        noise_target: r.get(14)?,
        manifest: r.get(15)?,
        scenes: r.get::<_, i64>(16)?.clamp(1, i64::from(u32::MAX)) as u32,
        video: r.get::<_, Option<String>>(17)?.as_deref().and_then(tessera::protocol::VideoKind::parse),
        fps: r.get::<_, Option<i64>>(18)?.map(|f| f as u32),
        keep_float: r.get(19)?,
        scale: r.get(20)?,
        worker_tags: workers::tags_from_text(r.get(21)?),
    })
}

const JOB_COLUMNS: &str = "id, name, state, priority, tile_size, samples, bundle, scene_path, submitted_at, started_at, finished_at, error, denoise, pass_samples, noise_target, manifest, scenes, video, fps, keep_float, scale, worker_tags";

fn frame_from_row(r: &rusqlite::Row) -> rusqlite::Result<FrameRow> {
    let outputs: Option<String> = r.get(8)?;
    Ok(FrameRow {
        job_id: r.get::<_, i64>(0)? as u64,
        index: r.get::<_, i64>(1)? as u32,
        camera: r.get::<_, i64>(2)? as u32,
        image_name: r.get(3)?,
        width: r.get::<_, i64>(4)? as u32,
        height: r.get::<_, i64>(5)? as u32,
        tiles_total: r.get::<_, i64>(6)? as u32,
        tiles_done: r.get::<_, i64>(7)? as u32,
        outputs: outputs.and_then(|o| serde_json::from_str(&o).ok()),
        samples: r.get::<_, i64>(9)? as u32,
        passes_total: r.get::<_, i64>(10)? as u32,
        passes_published: r.get::<_, i64>(11)? as u32,
        scene_path: r.get(12)?,
        samples_done: r.get::<_, i64>(13)?.max(0) as u64,
        samples_skipped: r.get::<_, i64>(14)?.max(0) as u64,
    })
}

const FRAME_COLUMNS: &str = "job_id, idx, camera, image_name, width, height, tiles_total, tiles_done, outputs, samples, passes_total, passes_published, scene_path, samples_done, samples_skipped";

/// The pause between two steps of writing or purging a job's rows: the lock is free during it,
/// so that another request waiting for the store gets it first.
const STEP_PAUSE: std::time::Duration = std::time::Duration::from_millis(1);

impl Store {
    /// Opens (creating if needed) the database at `path`, and returns every tile that was
    /// leased when the server stopped to the queue.
    pub fn open(path: &Path) -> Result<Store> {
        let conn = Connection::open(path)
            .with_context(|| format!("cannot open the job store {}", path.display()))?;
        // A new database gives the pages of deleted rows back to the file system in steps
        // ([`Store::release_free_pages`]); an older one reuses them for new rows. (Only an empty
        // database can change this; on any other it does nothing.)
        conn.pragma_update(None, "auto_vacuum", "INCREMENTAL")?;
        conn.pragma_update(None, "journal_mode", "WAL")?;
        conn.pragma_update(None, "synchronous", "NORMAL")?;
        conn.busy_timeout(std::time::Duration::from_secs(5))?;
        // Every statement is prepared once and kept: parsing them again on each request cost
        // about a fifth of the server's CPU under a polling client (perf, farmbench).
        conn.set_prepared_statement_cache_capacity(STATEMENT_CACHE);
        conn.execute_batch(schema::SCHEMA).context("cannot create the job store's tables")?;
        schema::migrate(&conn).context("cannot bring the job store's tables up to date")?;
        counters::seed_counters(&conn).context("cannot create the job store's counters")?;
        let highest_deleted = files::create(&conn).context("cannot create the job store's tables")?;
        video::create_videos_table(&conn).context("cannot create the job store's table of videos")?;
        conn.execute(
            "UPDATE tiles SET state = 'queued', lease_id = NULL, worker_id = NULL, deadline = NULL WHERE state = 'leased'",
            [],
        )?;
        conn.execute("UPDATE workers SET rendering = NULL", [])?;
        // A job whose rows were still being written when the server stopped was never
        // acknowledged nor leased: it fails, saying so, and its rows are purged like any failed
        // job's (`Store::purge_job_rows`).
        conn.execute(
            "UPDATE jobs SET state = 'failed', finished_at = ?1, error = ?2 WHERE state = 'inserting'",
            params![now(), INTERRUPTED_INSERT],
        )?;
        let max_lease: Option<i64> = conn.query_row("SELECT max(lease_id) FROM tiles", [], |r| r.get(0))?;
        // Lease ids never repeat, across restarts too: start past every id still recorded, and
        // past the clock (ids handed out before a crash were never recorded if their tile was
        // requeued above, so a stale worker could otherwise hold a reused id).
        let clock = (now() * 1000.0) as u64 * 1000;
        let next = (max_lease.unwrap_or(0) as u64 + 1).max(clock);
        // Checkpoints run on their own connection, outside the store's lock (`checkpoint`),
        // instead of inside whichever transaction fills the log past 1,000 pages: a job's
        // insertion used to make a lease that committed then wait for 4 MiB to be copied and
        // synced.
        conn.pragma_update(None, "wal_autocheckpoint", 0)?;
        // A log that grew (during a large insertion) is cut back when it starts over.
        conn.pragma_update(None, "journal_size_limit", 8i64 << 20)?;
        let checkpointer = Connection::open(path)
            .with_context(|| format!("cannot open the job store {}", path.display()))?;
        checkpointer.busy_timeout(std::time::Duration::from_secs(5))?;
        Ok(Store {
            conn: Mutex::new(conn),
            next_lease: Mutex::new(next),
            // A deleted job's id is never handed out again.
            min_job_id: std::sync::atomic::AtomicU64::new(highest_deleted.saturating_add(1)),
            checkpointer: Mutex::new(checkpointer),
            requeueing: Mutex::default(),
            results_dir: path.parent().unwrap_or(Path::new("")).join(results::RESULTS_DIR),
            retry_failed_after: std::sync::atomic::AtomicU64::new(failures::RETRY_FAILED_AFTER.to_bits()),
        })
    }

    /// New jobs get ids above `id` (the largest job folder in the data directory), whatever
    /// the store holds: a job never takes the folder of one it does not know.
    pub fn keep_job_ids_above(&self, id: u64) {
        self.min_job_id.fetch_max(id.saturating_add(1), std::sync::atomic::Ordering::SeqCst);
    }

    /// Keeps a worker off a tile it failed (and off a job it failed [`failures::WORKER_FAILURES_PER_JOB`]
    /// tiles of) for `seconds` after its latest failure there (`--retry-failed-after-seconds`).
    pub fn set_retry_failed_after(&self, seconds: f64) {
        self.retry_failed_after.store(seconds.to_bits(), std::sync::atomic::Ordering::Relaxed);
    }

    fn retry_failed_after(&self) -> f64 {
        f64::from_bits(self.retry_failed_after.load(std::sync::atomic::Ordering::Relaxed))
    }

    fn conn(&self) -> std::sync::MutexGuard<'_, Connection> {
        // A panic while holding the lock leaves SQLite consistent (transactions roll back).
        self.conn.lock().unwrap_or_else(|e| e.into_inner())
    }

    pub fn job(&self, id: u64) -> Result<Option<JobRow>> {
        let conn = self.conn();
        Ok(conn
            .query_row_cached(
                &format!("SELECT {JOB_COLUMNS} FROM jobs WHERE id = ?1 AND state != 'inserting'"),
                [id as i64],
                job_from_row,
            )
            .optional()?)
    }

    pub fn jobs(&self) -> Result<Vec<JobRow>> {
        let conn = self.conn();
        let mut stmt = conn.prepare_cached(&format!(
            "SELECT {JOB_COLUMNS} FROM jobs WHERE state != 'inserting' ORDER BY id DESC"
        ))?;
        let rows = stmt.query_map([], job_from_row)?.collect::<rusqlite::Result<Vec<_>>>()?;
        Ok(rows)
    }

    pub fn frames(&self, job: u64) -> Result<Vec<FrameRow>> {
        let conn = self.conn();
        let mut stmt = conn
            .prepare_cached(&format!("SELECT {FRAME_COLUMNS} FROM frames WHERE job_id = ?1 ORDER BY idx"))?;
        let rows = stmt.query_map([job as i64], frame_from_row)?.collect::<rusqlite::Result<Vec<_>>>()?;
        Ok(rows)
    }

    /// Frames of live jobs whose every tile has arrived but whose outputs were never written
    /// (the server stopped in between, or the disk was full): merged again at startup, and
    /// while the disk is full, again until it has room.
    pub fn frames_awaiting_merge(&self) -> Result<Vec<FrameRow>> {
        let conn = self.conn();
        let mut stmt = conn.prepare_cached(&format!(
            "SELECT {FRAME_COLUMNS} FROM frames f WHERE tiles_done = tiles_total AND outputs IS NULL AND (SELECT state FROM jobs WHERE id = f.job_id) IN ('queued', 'running', 'paused')"
        ))?;
        let rows = stmt.query_map([], frame_from_row)?.collect::<rusqlite::Result<Vec<_>>>()?;
        Ok(rows)
    }

    /// The rectangles of a frame's rendered tiles, by tile index, without their pixels: a
    /// preview reads the pixels one tile at a time ([`Store::tile_pixels`]), each under a short
    /// lock, instead of every tile of a large frame at once.
    pub fn done_tile_rects(&self, job: u64, frame: u32) -> Result<Vec<(u32, Rect)>> {
        let conn = self.conn();
        let mut stmt = conn.prepare_cached(
            "SELECT tile, x0, y0, w, h FROM tiles WHERE job_id = ?1 AND frame = ?2 AND pass = 0 AND state = 'done' AND (pixels IS NOT NULL OR pixels_file IS NOT NULL) ORDER BY tile",
        )?;
        let rows = stmt
            .query_map(params![job as i64, frame], |r| Ok((r.get::<_, i64>(0)? as u32, rect_at(r, 1)?)))?
            .collect::<rusqlite::Result<Vec<_>>>()?;
        Ok(rows)
    }

    /// One rendered tile's pixels (`None` once the finished job dropped them).
    pub fn tile_pixels(&self, job: u64, frame: u32, tile: u32) -> Result<Option<Vec<u8>>> {
        let row = self
            .conn()
            .query_row_cached(
                "SELECT pixels, pixels_file FROM tiles WHERE job_id = ?1 AND frame = ?2 AND tile = ?3 AND pass = 0 AND state = 'done' AND (pixels IS NOT NULL OR pixels_file IS NOT NULL)",
                params![job as i64, frame, tile],
                |r| Ok((r.get(0)?, r.get(1)?)),
            )
            .optional()?;
        // A result file is read outside the store's lock.
        row.map(|(bytes, file)| self.read_result(bytes, file)).transpose()
    }

    /// The rendered tiles of a frame: (rect, pixels bytes).
    pub fn frame_tiles(&self, job: u64, frame: u32) -> Result<Vec<(Rect, Vec<u8>)>> {
        type Row = (Rect, Option<Vec<u8>>, Option<String>);
        let rows: Vec<Row> = {
            let conn = self.conn();
            let mut stmt = conn.prepare_cached(
                "SELECT x0, y0, w, h, pixels, pixels_file FROM tiles WHERE job_id = ?1 AND frame = ?2 AND pass = 0 AND state = 'done' AND (pixels IS NOT NULL OR pixels_file IS NOT NULL)",
            )?;
            stmt.query_map(params![job as i64, frame], |r| {
                Ok::<Row, _>((rect_at(r, 0)?, r.get(4)?, r.get(5)?))
            })?
            .collect::<rusqlite::Result<Vec<_>>>()?
        };
        // Result files are read outside the store's lock.
        rows.into_iter().map(|(rect, bytes, file)| Ok((rect, self.read_result(bytes, file)?))).collect()
    }

    /// Records a merged frame's outputs (and in the job's log, how long merging and tone
    /// mapping took); when it was the job's last frame the job is done. Returns whether the job
    /// is now done.
    pub fn frame_merged(
        &self,
        job: u64,
        frame: u32,
        outputs: &[String],
        timing: MergeTiming,
    ) -> Result<bool> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        tx.execute_cached(
            "UPDATE frames SET outputs = ?3 WHERE job_id = ?1 AND idx = ?2",
            params![job as i64, frame, serde_json::to_string(outputs)?],
        )?;
        // The frame's pixels live on in its outputs, which previews and re-tone-mapping read
        // from now on (a merge writes the preview too): keep the database small.
        // Its result files go once this commits.
        let files: Vec<String> = {
            let mut stmt = tx.prepare_cached(
                "SELECT pixels_file FROM tiles WHERE job_id = ?1 AND frame = ?2 AND pixels_file IS NOT NULL",
            )?;
            stmt.query_map(params![job as i64, frame], |r| r.get(0))?.collect::<rusqlite::Result<_>>()?
        };
        tx.execute_cached(
            "UPDATE tiles SET pixels = NULL, sums = NULL, pixels_file = NULL WHERE job_id = ?1 AND frame = ?2
               AND (pixels IS NOT NULL OR sums IS NOT NULL OR pixels_file IS NOT NULL)",
            params![job as i64, frame],
        )?;
        let merged = format!("frame {frame} merged and written: {}", outputs.join(", "));
        let f = Some(i64::from(frame));
        log_event(
            &tx,
            job as i64,
            Event { frame: f, seconds: Some(timing.merge_seconds), ..Event::new("frame_merged", &merged) },
        )?;
        if let Some(seconds) = timing.tonemap_seconds {
            let tonemapped = format!("frame {frame} tone-mapped to PNG");
            log_event(
                &tx,
                job as i64,
                Event { frame: f, seconds: Some(seconds), ..Event::new("frame_tonemapped", &tonemapped) },
            )?;
        }
        if let Some((seconds, what)) = &timing.denoise {
            log_event(
                &tx,
                job as i64,
                Event { frame: f, seconds: Some(*seconds), ..Event::new("frame_denoised", what) },
            )?;
        }
        let left: i64 = tx.query_row_cached(
            "SELECT count(*) FROM frames WHERE job_id = ?1 AND outputs IS NULL",
            [job as i64],
            |r| r.get(0),
        )?;
        let done = left == 0;
        if done {
            let ended = tx.execute_cached(
                "UPDATE jobs SET state = 'done', finished_at = ?2 WHERE id = ?1 AND state IN ('queued', 'running', 'paused')",
                params![job as i64, now()],
            )?;
            if ended > 0 {
                log_event(&tx, job as i64, Event::new("job_done", "done: every frame is merged"))?;
            }
        }
        tx.commit()?;
        self.remove_result_files(&files);
        Ok(done)
    }

    /// Each tile's rectangle and samples per pixel (a tile rendered whole has them all).
    pub fn tile_samples(&self, job: u64, frame: u32) -> Result<Vec<(Rect, Vec<u32>)>> {
        let conn = self.conn();
        let mut stmt = conn.prepare_cached(
            "SELECT t.x0, t.y0, t.w, t.h, CASE WHEN t.first_sample IS NULL THEN f.samples ELSE t.samples_done END,
                    t.pixel_samples
             FROM tiles t JOIN frames f ON f.job_id = t.job_id AND f.idx = t.frame
             WHERE t.job_id = ?1 AND t.frame = ?2 AND t.pass = 0 ORDER BY t.tile",
        )?;
        let rows = stmt
            .query_map(params![job as i64, frame], |r| {
                let rect = rect_at(r, 0)?;
                let pixels = (rect.width * rect.height) as usize;
                // Each pixel's samples when they differ, else the tile's.
                let counts = r
                    .get::<_, Option<Vec<u8>>>(5)?
                    .and_then(|b| tessera::passes::decode_counts(&b, pixels))
                    .unwrap_or_else(|| vec![r.get::<_, i64>(4).map_or(0, |n| n as u32)]);
                Ok((rect, counts))
            })?
            .collect::<rusqlite::Result<Vec<_>>>()?;
        Ok(rows)
    }

    /// Where a frame in passes stands, read at one moment (under one lock, so a pass absorbed
    /// meanwhile cannot make the count of passes and the samples disagree): a pass's picture is
    /// published as of this, and tiles only gain samples after it.
    pub fn pass_snapshot(&self, job: u64, frame: u32) -> Result<PassSnapshot> {
        let conn = self.conn();
        let (passes, complete): (i64, bool) = conn.query_row_cached(
            "SELECT passes_published, tiles_done >= tiles_total FROM frames WHERE job_id = ?1 AND idx = ?2",
            params![job as i64, frame],
            |r| Ok((r.get(0)?, r.get(1)?)),
        )?;
        let (least, finished, tiles): (Option<i64>, i64, i64) = conn.query_row_cached(
            "SELECT min(samples_done), sum(finished), count(*) FROM tiles WHERE job_id = ?1 AND frame = ?2 AND pass = 0",
            params![job as i64, frame],
            |r| Ok((r.get(0)?, r.get::<_, Option<i64>>(1)?.unwrap_or(0), r.get(2)?)),
        )?;
        Ok(PassSnapshot { passes: passes as u32, least: least.unwrap_or(0), finished, tiles, complete })
    }

    /// Logs that a frame was published as it stood at `at` (after `at.passes` of its
    /// `passes_total` passes, with the fewest samples per pixel any of its tiles had).
    pub fn frame_passed(
        &self,
        job: u64,
        frame: u32,
        at: &PassSnapshot,
        passes_total: u32,
        seconds: f64,
        denoised: Option<&Result<f64, String>>,
    ) -> Result<()> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        let PassSnapshot { passes, least, finished, tiles, .. } = *at;
        let message = format!(
            "frame {frame} after pass {passes} of {passes_total}: at least {least} samples per pixel, {finished} of {tiles} tiles finished; pass.exr and pass.png written{}",
            match denoised {
                None => String::new(),
                Some(Ok(s)) => format!(", and pass_denoised.png (denoised in {s:.3} s)"),
                Some(Err(e)) => format!("; not denoised: {e}"),
            }
        );
        let e = Event {
            frame: Some(i64::from(frame)),
            seconds: Some(seconds),
            ..Event::new("frame_pass", &message)
        };
        log_event(&tx, job as i64, e)?;
        tx.commit()?;
        Ok(())
    }

    /// Logs `message` as an event of `kind` about frame `frame` of `job`.
    pub fn log_frame_event(&self, job: u64, frame: u32, kind: &'static str, message: &str) -> Result<()> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        log_event(&tx, job as i64, Event { frame: Some(i64::from(frame)), ..Event::new(kind, message) })?;
        tx.commit()?;
        Ok(())
    }

    pub fn fail_job(&self, job: u64, error: &str) -> Result<()> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        let ended = tx.execute_cached(
            "UPDATE jobs SET state = 'failed', error = ?2, finished_at = ?3 WHERE id = ?1 AND state IN ('queued', 'running', 'paused')",
            params![job as i64, error, now()],
        )?;
        if ended > 0 {
            log_event(&tx, job as i64, Event::new("job_failed", error))?;
        }
        tx.commit()?;
        Ok(())
    }

    /// Cancels a job that has not finished; returns false if it had (or does not exist).
    pub fn cancel_job(&self, job: u64) -> Result<bool> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        let n = tx.execute_cached(
            "UPDATE jobs SET state = 'canceled', finished_at = ?2 WHERE id = ?1 AND state IN ('queued', 'running', 'paused')",
            params![job as i64, now()],
        )?;
        if n > 0 {
            log_event(&tx, job as i64, Event::new("job_cancelled", "cancelled"))?;
            revoke_leases(&tx, job as i64)?;
        }
        tx.commit()?;
        Ok(n > 0)
    }

    /// The log of `job` after event `after` (0: from the start), oldest first; `None` when
    /// there is no such job.
    pub fn job_log(&self, job: u64, after: u64) -> Result<Option<Vec<JobEvent>>> {
        let conn = self.conn();
        let exists: i64 = conn.query_row_cached(
            "SELECT count(*) FROM jobs WHERE id = ?1 AND state != 'inserting'",
            [job as i64],
            |r| r.get(0),
        )?;
        if exists == 0 {
            return Ok(None);
        }
        let mut stmt = conn.prepare_cached(
            "SELECT e.seq, e.at, e.kind, e.frame, e.tile,
                    coalesce(e.worker, (SELECT w.name FROM workers w WHERE w.id = e.worker_id)),
                    e.seconds, e.message, e.worker_id
             FROM job_events e WHERE e.job_id = ?1 AND e.seq > ?2 ORDER BY e.seq",
        )?;
        let after = i64::try_from(after).unwrap_or(i64::MAX);
        let events = stmt
            .query_map(params![job as i64, after], |r| {
                Ok(JobEvent {
                    seq: r.get::<_, i64>(0)? as u64,
                    at: r.get(1)?,
                    kind: r.get(2)?,
                    frame: r.get::<_, Option<i64>>(3)?.map(|f| f as u32),
                    tile: r.get::<_, Option<i64>>(4)?.map(|t| t as u32),
                    worker: r.get(5)?,
                    worker_id: r.get::<_, Option<i64>>(8)?.map(|w| w as u64),
                    seconds: r.get(6)?,
                    message: r.get(7)?,
                })
            })?
            .collect::<rusqlite::Result<Vec<_>>>()?;
        Ok(Some(events))
    }

    /// The most recent failure messages of a job's tiles (for the job view).
    pub fn recent_failures(&self, job: u64) -> Result<Vec<String>> {
        let conn = self.conn();
        let mut stmt = conn.prepare_cached(
            "SELECT frame, tile, worker_id, error FROM tile_failures WHERE job_id = ?1 ORDER BY at DESC LIMIT 10",
        )?;
        let rows = stmt
            .query_map([job as i64], |r| {
                Ok(format!(
                    "frame {} tile {} on worker {}: {}",
                    r.get::<_, i64>(0)?,
                    r.get::<_, i64>(1)?,
                    r.get::<_, i64>(2)?,
                    r.get::<_, String>(3)?
                ))
            })?
            .collect::<rusqlite::Result<Vec<_>>>()?;
        Ok(rows)
    }
}

/// The rules the store applies inside its transactions, on a real SQLite file: no HTTP, no
/// scene (a job here is rows with a made-up bundle).
#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{frame, job_of, row_of_pixels, store};

    /// Long enough for a lease not to expire during a test.
    const LONG: f64 = 60.0;
    /// A lease whose deadline has passed already.
    const EXPIRED: f64 = -1.0;

    /// A job of one frame cut into `tiles` one-pixel tiles.
    fn job(s: &Store, priority: i64, tiles: u32) -> u64 {
        s.insert_job(&NewJob { priority, ..job_of(vec![row_of_pixels("j.png", tiles, 1)]) }).unwrap()
    }

    /// Job ids stay above the floor the data directory's job folders set, and above every id
    /// handed out, even once the job holding the largest is gone from the store.
    #[test]
    fn new_jobs_take_ids_above_the_job_folders_and_never_one_handed_out() {
        let dir = tessera_testkit::TempDir::new("unit-job-ids");
        let s = Store::open(&dir.join("t.db")).unwrap();
        assert_eq!(job(&s, 0, 1), 1);
        s.keep_job_ids_above(7);
        assert_eq!(job(&s, 0, 1), 8);
        s.conn().execute("DELETE FROM jobs WHERE id = 8", []).unwrap();
        assert_eq!(job(&s, 0, 1), 9);
        s.keep_job_ids_above(3);
        assert_eq!(job(&s, 0, 1), 10);
    }

    /// A job of one 2-pixel tile of 48 samples in passes of 16 (`target`: its noise target).
    fn passes_job(s: &Store, target: Option<f64>) -> u64 {
        let frame = NewFrame { samples: 48, ..frame("p.exr", 2, 1) };
        let job = NewJob {
            name: "p".into(),
            tile_size: 2,
            samples: Some(48),
            pass_samples: Some(16),
            noise_target: target,
            ..job_of(vec![frame])
        };
        s.insert_job(&job).unwrap()
    }

    /// A pass's sums for two pixels: every sample of block `b` is `value(b)`.
    fn pass_sums(range: std::ops::Range<u32>, value: impl Fn(u32) -> f64) -> Vec<u8> {
        let mut px = [tessera::passes::PixelSum::default(); 2];
        for b in range.start / 16..range.end / 16 {
            for p in &mut px {
                p.add_block(b, glam::DVec3::splat(value(b) * 16.0));
            }
        }
        tessera::passes::encode_sums(&px)
    }

    #[test]
    fn passes_arriving_in_any_order_add_up_and_publish_the_frame_once_each_is_everywhere() {
        let (_d, s) = store("passes");
        let id = passes_job(&s, None);
        let w1 = s.register_worker("a", 8, "h").unwrap();
        let leases: Vec<Lease> = (0..3).map(|_| lease(&s, w1)).collect();
        let ranges: Vec<_> = leases.iter().map(|l| l.pass.expect("a pass")).collect();
        assert_eq!(
            ranges.iter().map(|p| (p.index, p.start, p.end)).collect::<Vec<_>>(),
            [(0, 0, 16), (1, 16, 32), (2, 32, 48)]
        );
        assert_eq!(s.result_size(leases[0].lease_id, w1).unwrap().map(|r| r.bytes()), Some(128));
        let value = |b: u32| f64::from(b + 1);
        let submit = |k: usize| {
            let p = ranges[k];
            s.submit_result(leases[k].lease_id, w1, &pass_sums(p.start..p.end, value), None).unwrap()
        };
        // The last pass first: kept aside, nothing published.
        assert!(matches!(
            submit(2),
            ResultOutcome::Accepted { pass_published: None, frame_complete: false, .. }
        ));
        assert!(s.frame_tiles(id, 0).unwrap().is_empty(), "no film before pass 0");
        // Progress counts the samples in the film (two pixels): none yet, of 96.
        let progress = || {
            let f = &s.frames(id).unwrap()[0];
            (f.samples_done, f.samples_total())
        };
        assert_eq!(progress(), (0, 96));
        // Pass 0: the tile has 16 samples, the frame is published after pass 1.
        assert!(matches!(submit(0), ResultOutcome::Accepted { pass_published: Some(1), .. }));
        let film = tessera::protocol::decode_tile(&s.frame_tiles(id, 0).unwrap()[0].1, 2).unwrap();
        assert_eq!(film, [[1.0; 3]; 2]);
        assert_eq!(progress(), (32, 96));
        // Its picture is published as after pass 1, of 16 samples, the frame not complete.
        let at = s.pass_snapshot(id, 0).unwrap();
        assert_eq!((at.passes, at.least, at.finished, at.tiles, at.complete), (1, 16, 0, 1, false));
        // Pass 1 brings pass 2 in with it: the frame is complete, averaged over 48 samples.
        assert!(matches!(submit(1), ResultOutcome::Accepted { frame_complete: true, .. }));
        let film = tessera::protocol::decode_tile(&s.frame_tiles(id, 0).unwrap()[0].1, 2).unwrap();
        assert_eq!(film, [[2.0; 3]; 2], "(1 + 2 + 3) / 3");
        assert_eq!(progress(), (96, 96));
        // A publication of pass 1 that runs only now finds the frame complete (its merge is
        // due): the finished frame is not shown as a pass.
        let at = s.pass_snapshot(id, 0).unwrap();
        assert_eq!((at.least, at.finished, at.complete), (48, 1, true));
    }

    #[test]
    fn under_a_noise_target_a_tiles_next_pass_waits_for_the_verdict_on_the_last() {
        let (_d, s) = store("passes-target");
        let id = passes_job(&s, Some(0.01));
        let w = s.register_worker("a", 8, "h").unwrap();
        let first = lease(&s, w);
        assert_eq!(first.pass.map(|p| p.index), Some(0));
        assert!(s.lease(w, 30.0).unwrap().granted().is_none(), "pass 1 waits for pass 0");
        let p = first.pass.unwrap();
        s.submit_result(first.lease_id, w, &pass_sums(p.start..p.end, |_| 1.0), None).unwrap();
        // Noise-free sums: after the minimum (48 samples here, the cap) the tile is done; before
        // it the next pass is queued.
        let second = lease(&s, w);
        assert_eq!(second.pass.map(|p| p.index), Some(1));
        let p = second.pass.unwrap();
        s.submit_result(second.lease_id, w, &pass_sums(p.start..p.end, |_| 1.0), None).unwrap();
        let third = lease(&s, w);
        let p = third.pass.unwrap();
        let done = s.submit_result(third.lease_id, w, &pass_sums(p.start..p.end, |_| 1.0), None).unwrap();
        assert!(matches!(done, ResultOutcome::Accepted { frame_complete: true, .. }), "{done:?}");
        assert_eq!(s.tile_samples(id, 0).unwrap(), [(Rect { x0: 0, y0: 0, width: 2, height: 1 }, vec![48])]);
    }

    #[test]
    fn a_database_from_before_passes_keeps_its_tiles_as_whole_tile_units() {
        let dir = tessera_testkit::TempDir::new("db-migrate-passes");
        let path = dir.path().join("tessera.db");
        {
            // The tables as they were before passes: no pass columns, tiles keyed by tile.
            let mut old = schema::SCHEMA.to_string();
            for gone in [
                "\n    samples_done INTEGER NOT NULL DEFAULT 0,\n    samples_skipped INTEGER NOT NULL DEFAULT 0,",
                ",\n    pass_samples INTEGER,\n    noise_target REAL",
                ",\n    samples INTEGER NOT NULL DEFAULT 1,\n    passes_total INTEGER NOT NULL DEFAULT 1,\n    passes_published INTEGER NOT NULL DEFAULT 0",
                "\n    pass INTEGER NOT NULL DEFAULT 0,\n    first_sample INTEGER,\n    end_sample INTEGER,\n    sums BLOB,\n    passes_done INTEGER NOT NULL DEFAULT 0,\n    samples_done INTEGER NOT NULL DEFAULT 0,\n    error REAL,\n    finished INTEGER NOT NULL DEFAULT 0,",
            ] {
                assert!(old.contains(gone), "the schema changed: {gone}");
                old = old.replace(gone, "");
            }
            let old = old
                .replace("PRIMARY KEY(job_id, frame, tile, pass)", "PRIMARY KEY(job_id, frame, tile)")
                + "CREATE INDEX IF NOT EXISTS tiles_queue ON tiles(job_id, state, frame, tile);";
            assert!(!old.contains("pass"), "{old}");
            let conn = Connection::open(&path).unwrap();
            conn.execute_batch(&old).unwrap();
            conn.execute_batch(
                "INSERT INTO jobs(name, state, priority, tile_size, bundle, scene_path, submitted_at) VALUES ('old', 'running', 0, 1, 'b', 's.xml', 0);
                 INSERT INTO frames(job_id, idx, camera, image_name, width, height, tiles_total, tiles_done) VALUES (1, 0, 0, 'o.png', 2, 1, 2, 1);
                 INSERT INTO tiles(job_id, frame, tile, x0, y0, w, h, state, pixels) VALUES (1, 0, 0, 0, 0, 1, 1, 'done', x'0000803f0000803f0000803f');
                 INSERT INTO tiles(job_id, frame, tile, x0, y0, w, h, state) VALUES (1, 0, 1, 1, 0, 1, 1, 'queued');",
            )
            .unwrap();
        }
        let s = Store::open(&path).unwrap();
        // The rendered tile is still there (and counted, once, into the metrics' counters, and
        // into the frame's samples); the queued one is leased whole and completes the frame.
        assert_eq!(s.frame_tiles(1, 0).unwrap().len(), 1);
        let progress = |s: &Store| {
            let f = &s.frames(1).unwrap()[0];
            (f.samples_done, f.samples_total())
        };
        assert_eq!(progress(&s), (1, 2));
        assert_eq!(s.metrics().unwrap().tiles_done, 1);
        let w = worker(&s);
        let l = lease(&s, w);
        assert_eq!((l.job_id, l.tile, l.pass), (1, 1, None));
        assert_eq!(s.result_size(l.lease_id, w).unwrap().map(|r| r.bytes()), Some(12));
        let done = s.submit_result(l.lease_id, w, &[0; 12], None).unwrap();
        assert!(matches!(done, ResultOutcome::Accepted { frame_complete: true, .. }), "{done:?}");
        assert_eq!(s.frames(1).unwrap()[0].passes_total, 1);
        assert_eq!(progress(&s), (2, 2));
        drop(s);
        assert_eq!(Store::open(&path).unwrap().metrics().unwrap().tiles_done, 2);
    }

    #[test]
    fn an_older_database_gains_allow_unsupported_and_its_jobs_keep_rendering_as_accepted() {
        let dir = tessera_testkit::TempDir::new("db-migrate");
        let path = dir.path().join("tessera.db");
        {
            // The jobs table before the column, with a job accepted then.
            let conn = Connection::open(&path).unwrap();
            let old = schema::SCHEMA
                .replace(",\n    allow_unsupported INTEGER NOT NULL DEFAULT 0", "")
                .replace(",\n    denoise INTEGER NOT NULL DEFAULT 0", "");
            assert!(!old.contains("denoise") && !old.contains("allow_unsupported"));
            conn.execute_batch(&old).unwrap();
            conn.execute(
                "INSERT INTO jobs(name, state, priority, tile_size, bundle, scene_path, submitted_at) VALUES ('old', 'queued', 0, 1, 'b', 's.xml', 0)",
                [],
            )
            .unwrap();
            conn.execute(
                "INSERT INTO frames(job_id, idx, camera, image_name, width, height, tiles_total) VALUES (1, 0, 0, 'o.png', 1, 1, 1)",
                [],
            )
            .unwrap();
            conn.execute(
                "INSERT INTO tiles(job_id, frame, tile, x0, y0, w, h, state) VALUES (1, 0, 0, 0, 0, 1, 1, 'queued')",
                [],
            )
            .unwrap();
        }
        let s = Store::open(&path).unwrap();
        let new = job(&s, -1, 1);
        let w = worker(&s);
        let old = lease(&s, w);
        assert_eq!((old.job_id, old.allow_unsupported, old.aux), (1, true, false), "not denoised");
        let fresh = lease(&s, w);
        assert_eq!((fresh.job_id, fresh.allow_unsupported), (new, false));
        drop(s);
        Store::open(&path).unwrap();
    }

    /// A worker of 16 threads: tests that lease tile after tile without rendering them stay
    /// under its lease limit.
    fn worker(s: &Store) -> u64 {
        s.register_worker("w", 16, "").unwrap()
    }

    fn lease(s: &Store, w: u64) -> Lease {
        s.lease(w, LONG).unwrap().granted().expect("a lease")
    }

    fn state(s: &Store, job: u64) -> JobState {
        s.job(job).unwrap().unwrap().state
    }

    const PIXEL: [u8; 12] = [0; 12];

    #[test]
    fn leases_go_by_priority_then_submission_then_frame_and_tile() {
        let (_d, s) = store("prio");
        let low = job(&s, 0, 2);
        let low2 = job(&s, 0, 1);
        let high = job(&s, 5, 1);
        let w = worker(&s);
        let order: Vec<(u64, u32)> = (0..4).map(|_| lease(&s, w)).map(|l| (l.job_id, l.tile)).collect();
        assert_eq!(order, [(high, 0), (low, 0), (low, 1), (low2, 0)]);
        assert!(s.lease(w, LONG).unwrap() == Leased::NoWork);
        // A job submitted later with a higher priority overtakes a running one.
        let running = job(&s, 0, 3);
        assert_eq!(lease(&s, w).job_id, running);
        let urgent = job(&s, 1, 1);
        assert_eq!(lease(&s, w).job_id, urgent);
        assert_eq!(state(&s, running), JobState::Running);
    }

    #[test]
    fn a_tile_failing_on_three_workers_fails_its_job() {
        let (_d, s) = store("three");
        let j = job(&s, 0, 2);
        for k in 0..3 {
            let w = worker(&s);
            let l = lease(&s, w);
            assert_eq!(l.tile, 0, "the failed tile goes to the next worker first");
            let out = s.fail_tile(l.lease_id, w, &format!("boom {k}"), false).unwrap();
            if k < 2 {
                assert_eq!(out, FailOutcome::Requeued);
                assert_eq!(state(&s, j), JobState::Running);
            } else {
                let FailOutcome::JobFailed { job, message } = out else { panic!("{out:?}") };
                assert_eq!(job, j);
                assert!(message.contains("3 worker(s), 3 time(s); last error: boom 2"), "{message}");
            }
        }
        assert_eq!(state(&s, j), JobState::Failed);
        assert!(s.lease(worker(&s), LONG).unwrap() == Leased::NoWork);
    }

    /// Moves every recorded failure `seconds` into the past (the retry window is wall time).
    fn age_failures(s: &Store, seconds: f64) {
        s.conn().execute("UPDATE tile_failures SET at = at - ?1", params![seconds]).unwrap();
    }

    #[test]
    fn a_farm_of_one_worker_retries_a_failed_tile_until_five_failures_fail_its_job() {
        // The only worker fails the only tile: it is kept off it for the retry window (nobody
        // else could take it), then gets it again, and the fifth failure fails the job instead
        // of leaving the tile queued for ever.
        let (_d, s) = store("five");
        let j = job(&s, 0, 1);
        let w = worker(&s);
        for k in 1..=5 {
            let l = lease(&s, w);
            assert_eq!((l.job_id, l.tile), (j, 0));
            let out = s.fail_tile(l.lease_id, w, &format!("boom {k}"), false).unwrap();
            if k < 5 {
                assert_eq!(out, FailOutcome::Requeued);
                assert!(s.lease(w, LONG).unwrap() == Leased::NoWork, "kept off the tile it just failed");
                age_failures(&s, failures::RETRY_FAILED_AFTER - 5.0);
                assert!(s.lease(w, LONG).unwrap() == Leased::NoWork, "still inside the retry window");
                age_failures(&s, 6.0);
            } else {
                let FailOutcome::JobFailed { message, .. } = out else { panic!("{out:?}") };
                assert!(message.contains("1 worker(s), 5 time(s); last error: boom 5"), "{message}");
            }
        }
        assert_eq!(state(&s, j), JobState::Failed);
    }

    #[test]
    fn the_retry_window_is_the_servers_setting() {
        // --retry-failed-after-seconds 10: a failure 9 s old keeps the worker off its tile, one
        // 11 s old no longer does.
        let (_d, s) = store("retry-window");
        s.set_retry_failed_after(10.0);
        let j = job(&s, 0, 1);
        let w = worker(&s);
        let l = lease(&s, w);
        assert_eq!(s.fail_tile(l.lease_id, w, "boom", false).unwrap(), FailOutcome::Requeued);
        age_failures(&s, 9.0);
        assert!(s.lease(w, LONG).unwrap() == Leased::NoWork, "inside the 10 s window");
        age_failures(&s, 2.0);
        let again = lease(&s, w);
        assert_eq!((again.job_id, again.tile), (j, 0));
    }

    #[test]
    fn a_fatal_failure_fails_the_job_at_once_and_revokes_its_leases() {
        let (_d, s) = store("fatal");
        let j = job(&s, 0, 3);
        let w = worker(&s);
        let (l, other) = (lease(&s, w), lease(&s, w));
        let out = s.fail_tile(l.lease_id, w, "over the render time limit", true).unwrap();
        let FailOutcome::JobFailed { message, .. } = out else { panic!("{out:?}") };
        assert!(
            message.contains("1 worker(s), 1 time(s); last error: over the render time limit"),
            "{message}"
        );
        assert_eq!(state(&s, j), JobState::Failed);
        assert_eq!(s.revoked_among(w, &[other.lease_id]).unwrap(), [other.lease_id]);
        assert!(s.lease(worker(&s), LONG).unwrap() == Leased::NoWork);
    }

    #[test]
    fn a_worker_failing_three_tiles_of_a_job_is_kept_off_that_job_only() {
        let (_d, s) = store("ban");
        let j = job(&s, 1, 8);
        let other = job(&s, 0, 1);
        let w = worker(&s);
        for t in 0..3 {
            let l = lease(&s, w);
            assert_eq!((l.job_id, l.tile), (j, t), "a worker is not given a tile it failed");
            assert_eq!(s.fail_tile(l.lease_id, w, "boom", false).unwrap(), FailOutcome::Requeued);
        }
        assert_eq!(lease(&s, w).job_id, other, "3 failed tiles keep the worker off the job");
        let good = worker(&s);
        assert_eq!((lease(&s, good).job_id, state(&s, j)), (j, JobState::Running));
        assert_eq!(s.workers().unwrap().iter().find(|x| x.id == w).unwrap().failures, 3);
        // For the retry window only: then it may take the job's tiles again, the ones it failed
        // included (a farm of one worker must not wait for ever).
        age_failures(&s, failures::RETRY_FAILED_AFTER + 1.0);
        let again = lease(&s, w);
        assert_eq!((again.job_id, again.tile), (j, 1), "back on the job (tile 0 is the good worker's)");
    }

    #[test]
    fn an_expired_lease_is_a_failure_and_three_fail_the_job_as_crashes() {
        let (_d, s) = store("expiry");
        let j = job(&s, 0, 1);
        for k in 0..3 {
            let w = worker(&s);
            let l = s.lease(w, EXPIRED).unwrap().granted().unwrap();
            let e = s.expire_leases().unwrap();
            assert_eq!(e.leases, 1);
            assert_eq!(s.submit_result(l.lease_id, w, &PIXEL, None).unwrap(), ResultOutcome::Conflict);
            assert_eq!(s.heartbeat(w, &[l.lease_id], Some(l.lease_id), LONG).unwrap(), [l.lease_id]);
            let row = s.workers().unwrap().into_iter().find(|x| x.id == w).unwrap();
            assert_eq!((row.failures, row.rendering), (1, None));
            if k < 2 {
                assert!(e.failed_jobs.is_empty());
                assert_eq!(state(&s, j), JobState::Running);
                assert!(s.recent_failures(j).unwrap()[0].contains("stopped answering"));
            } else {
                let [(job, message)] = &e.failed_jobs[..] else { panic!("{:?}", e.failed_jobs) };
                assert_eq!(*job, j);
                assert!(message.contains("crashed its workers: 3 time(s), on 3 worker(s)"), "{message}");
            }
        }
        assert_eq!(state(&s, j), JobState::Failed);
        assert_eq!(s.expire_leases().unwrap().leases, 0);
    }

    #[test]
    fn a_result_is_stored_once_for_a_live_lease_of_its_worker() {
        let (_d, s) = store("once");
        let j = job(&s, 0, 2);
        let (w, other) = (worker(&s), worker(&s));
        let l = lease(&s, w);
        assert_eq!(
            s.submit_result(l.lease_id, w, &[0; 24], None).unwrap(),
            ResultOutcome::WrongSize { expected: 12 }
        );
        assert_eq!(s.submit_result(l.lease_id, other, &PIXEL, None).unwrap(), ResultOutcome::Conflict);
        let ResultOutcome::Accepted { job_id, tiles_done, tiles_total, frame_complete, .. } =
            s.submit_result(l.lease_id, w, &PIXEL, Some(0.5)).unwrap()
        else {
            panic!("refused")
        };
        assert_eq!((job_id, tiles_done, tiles_total, frame_complete), (j, 1, 2, false));
        assert_eq!(s.submit_result(l.lease_id, w, &PIXEL, None).unwrap(), ResultOutcome::Conflict);
        // Past its deadline (not swept yet) a lease's result is refused too.
        let late = s.lease(w, EXPIRED).unwrap().granted().unwrap();
        assert_eq!(s.submit_result(late.lease_id, w, &PIXEL, None).unwrap(), ResultOutcome::Conflict);
        assert_eq!(s.frames(j).unwrap()[0].tiles_done, 1);
        // The metrics' counters count the one accepted result, refusals not.
        let m = s.metrics().unwrap();
        assert_eq!((m.tiles_done, m.render_seconds_sum, m.render_seconds_count), (1, 0.5, 1));
    }

    #[test]
    fn a_denoised_jobs_leases_ask_for_features_and_take_three_planes() {
        let (_d, s) = store("features");
        let plain = job(&s, 1, 1);
        let denoised = s
            .insert_job(&NewJob {
                name: "d".into(),
                priority: 0,
                tile_size: 1,
                samples: None,
                bundle: "0".repeat(64),
                scene_path: "scene.xml".into(),
                allow_unsupported: false,
                denoise: true,
                pass_samples: None,
                noise_target: None,
                frames: vec![NewFrame {
                    camera: 0,
                    image_name: "d.exr".into(),
                    width: 2,
                    height: 1,
                    tiles: vec![Rect { x0: 0, y0: 0, width: 2, height: 1 }],
                    samples: 1,
                    pass_samples: 16,
                    ..Default::default()
                }],
                warnings: Vec::new(),
                ..Default::default()
            })
            .unwrap();
        assert!(s.job(denoised).unwrap().unwrap().denoise && !s.job(plain).unwrap().unwrap().denoise);
        let w = worker(&s);
        let first = lease(&s, w);
        assert_eq!((first.job_id, first.aux), (plain, false));
        assert_eq!(s.result_size(first.lease_id, w).unwrap().map(|r| r.bytes()), Some(12));
        let l = lease(&s, w);
        assert_eq!((l.job_id, l.aux), (denoised, true));
        assert_eq!(
            s.result_size(l.lease_id, w).unwrap().map(|r| r.bytes()),
            Some(72),
            "2 pixels x 3 planes x 12 bytes"
        );
        assert_eq!(
            s.submit_result(l.lease_id, w, &[0; 24], None).unwrap(),
            ResultOutcome::WrongSize { expected: 72 },
            "the colour alone is refused"
        );
        assert!(matches!(
            s.submit_result(l.lease_id, w, &[0; 72], None).unwrap(),
            ResultOutcome::Accepted { .. }
        ));
    }

    #[test]
    fn cancel_revokes_the_live_leases_and_hands_out_no_more_tiles() {
        let (_d, s) = store("cancel");
        let j = job(&s, 0, 3);
        let w = worker(&s);
        let l = lease(&s, w);
        assert!(s.cancel_job(j).unwrap());
        assert_eq!(s.revoked_among(w, &[l.lease_id]).unwrap(), [l.lease_id]);
        assert_eq!(s.heartbeat(w, &[l.lease_id], Some(l.lease_id), LONG).unwrap(), [l.lease_id]);
        assert_eq!(s.submit_result(l.lease_id, w, &PIXEL, None).unwrap(), ResultOutcome::Conflict);
        assert_eq!(s.fail_tile(l.lease_id, w, "x", false).unwrap(), FailOutcome::Conflict);
        assert!(s.lease(w, LONG).unwrap() == Leased::NoWork);
        assert!(!s.cancel_job(j).unwrap(), "an ended job cannot be cancelled again");
    }

    #[test]
    fn a_released_lease_is_queued_again_once_without_a_failure() {
        let (_d, s) = store("release");
        let j = job(&s, 0, 1);
        let (w, other) = (worker(&s), worker(&s));
        let l = lease(&s, w);
        assert!(!s.release_lease(l.lease_id, other).unwrap(), "only its holder gives a lease back");
        assert!(s.release_lease(l.lease_id, w).unwrap());
        assert!(!s.release_lease(l.lease_id, w).unwrap());
        assert!(s.recent_failures(j).unwrap().is_empty());
        assert_eq!(lease(&s, w).tile, 0, "a released tile is no failure: its worker may take it again");
    }

    fn kinds(s: &Store, job: u64, after: u64) -> Vec<String> {
        s.job_log(job, after).unwrap().expect("a log").into_iter().map(|e| e.kind).collect()
    }

    #[test]
    fn a_jobs_log_tells_its_tiles_failures_retries_expiries_and_end_in_order() {
        let (_d, s) = store("log");
        let j = job(&s, 0, 2);
        let (a, b) = (s.register_worker("alpha", 1, "").unwrap(), s.register_worker("beta", 1, "").unwrap());
        let l = lease(&s, a);
        assert_eq!(s.fail_tile(l.lease_id, a, "out of memory", false).unwrap(), FailOutcome::Requeued);
        let again = lease(&s, b);
        assert_eq!(again.tile, 0);
        assert!(matches!(
            s.submit_result(again.lease_id, b, &PIXEL, Some(0.25)).unwrap(),
            ResultOutcome::Accepted { .. }
        ));
        let late = s.lease(a, EXPIRED).unwrap().granted().unwrap();
        assert_eq!(late.tile, 1);
        assert_eq!(s.expire_leases().unwrap().leases, 1);
        assert!(s.cancel_job(j).unwrap());
        let log = s.job_log(j, 0).unwrap().unwrap();
        let got: Vec<_> = log.iter().map(|e| (e.kind.as_str(), e.tile, e.worker.as_deref())).collect();
        assert_eq!(
            got,
            [
                ("accepted", None, None),
                ("tile_failed", Some(0), Some("alpha")),
                ("tile_retried", Some(0), Some("beta")),
                ("tile_done", Some(0), Some("beta")),
                ("lease_expired", Some(1), Some("alpha")),
                ("job_cancelled", None, None),
            ]
        );
        assert_eq!(log.iter().map(|e| e.seq).collect::<Vec<_>>(), [1, 2, 3, 4, 5, 6]);
        assert!(log.windows(2).all(|w| w[0].at <= w[1].at), "events out of time order");
        assert_eq!(log[1].message, "out of memory");
        assert_eq!(log[3].seconds, Some(0.25));
        assert!(log[4].message.contains("stopped answering"), "{}", log[4].message);
        // `after` returns only the newer events; past the end, none.
        assert_eq!(kinds(&s, j, 4), ["lease_expired", "job_cancelled"]);
        assert!(kinds(&s, j, 6).is_empty());
        assert!(kinds(&s, j, u64::MAX).is_empty());
        assert!(s.job_log(j + 1, 0).unwrap().is_none(), "an unknown job has no log");
    }

    #[test]
    fn a_failed_job_logs_the_failure_that_failed_it_once() {
        let (_d, s) = store("log-fail");
        let j = job(&s, 0, 2);
        let w = worker(&s);
        let (l, other) = (lease(&s, w), lease(&s, w));
        s.fail_tile(l.lease_id, w, "over the limit", true).unwrap();
        // Its other lease was revoked: no more events from it, and failing the job again
        // (a merge failure racing) records nothing.
        assert_eq!(s.fail_tile(other.lease_id, w, "late", false).unwrap(), FailOutcome::Conflict);
        s.fail_job(j, "merging failed").unwrap();
        assert_eq!(kinds(&s, j, 0), ["accepted", "tile_failed", "job_failed"]);
        let log = s.job_log(j, 0).unwrap().unwrap();
        assert!(log[2].message.contains("last error: over the limit"), "{}", log[2].message);
    }

    #[test]
    fn a_job_log_is_bounded_and_says_so_but_keeps_the_jobs_end() {
        let (_d, s) = store("log-cap");
        // A scene with more warnings than the log holds (a hostile job could as well have a
        // million tiles: each would be an event).
        let warnings: Vec<String> = (0..MAX_JOB_EVENTS + 50).map(|k| format!("warning {k}")).collect();
        let j = s
            .insert_job(&NewJob {
                name: "noisy".into(),
                priority: 0,
                tile_size: 1,
                samples: None,
                bundle: "0".repeat(64),
                scene_path: "scene.xml".into(),
                frames: vec![NewFrame {
                    camera: 0,
                    image_name: "n.png".into(),
                    width: 1,
                    height: 1,
                    tiles: vec![Rect { x0: 0, y0: 0, width: 1, height: 1 }],
                    samples: 1,
                    pass_samples: 16,
                    ..Default::default()
                }],
                warnings,
                allow_unsupported: false,
                denoise: false,
                pass_samples: None,
                noise_target: None,
                ..Default::default()
            })
            .unwrap();
        let w = worker(&s);
        let l = lease(&s, w);
        assert!(matches!(
            s.submit_result(l.lease_id, w, &PIXEL, Some(1.0)).unwrap(),
            ResultOutcome::Accepted { .. }
        ));
        assert!(s.frame_merged(j, 0, &["n.png".into()], MergeTiming::default()).unwrap());
        let log = s.job_log(j, 0).unwrap().unwrap();
        assert_eq!(log.len() as i64, MAX_JOB_EVENTS + 2);
        let last = &log[log.len() - 2..];
        assert_eq!((last[0].kind.as_str(), last[1].kind.as_str()), ("log_truncated", "job_done"));
        assert!(last[0].message.contains("full"), "{}", last[0].message);
        assert_eq!(log[log.len() - 3].message, format!("warning {}", MAX_JOB_EVENTS - 2));
        let rows: i64 = s.conn().query_row("SELECT count(*) FROM job_events", [], |r| r.get(0)).unwrap();
        assert_eq!(rows, MAX_JOB_EVENTS + 2, "the table grew past the cap");
    }

    #[test]
    fn a_database_from_before_the_log_opens_and_logs_from_then_on() {
        let (dir, s) = store("log-migrate");
        let j = job(&s, 0, 1);
        // What a database written by a server without job logs looks like: no job_events.
        s.conn().execute_batch("DROP TABLE job_events").unwrap();
        drop(s);
        let s = Store::open(&dir.path().join("tessera.db")).unwrap();
        assert_eq!(s.job_log(j, 0).unwrap().unwrap(), Vec::new(), "an old job has an empty log");
        assert_eq!(s.job(j).unwrap().unwrap().state, JobState::Queued, "its job survived");
        assert!(s.cancel_job(j).unwrap());
        assert_eq!(kinds(&s, j, 0), ["job_cancelled"]);
    }

    fn count(s: &Store, sql: &str) -> i64 {
        s.conn().query_row(sql, [], |r| r.get(0)).unwrap()
    }

    #[test]
    fn a_job_being_stored_is_invisible_and_one_cut_short_fails_and_is_purged() {
        let (dir, s) = store("inserting");
        let j = job(&s, 0, (ROWS_PER_STEP * 2 + 5) as u32);
        assert_eq!(count(&s, "SELECT count(*) FROM tiles"), (ROWS_PER_STEP * 2 + 5) as i64);
        assert_eq!(state(&s, j), JobState::Queued);
        // What a stop of the server between two steps leaves: the job not queued yet.
        s.conn().execute("UPDATE jobs SET state = 'inserting' WHERE id = ?1", [j as i64]).unwrap();
        assert!(s.job(j).unwrap().is_none() && s.jobs().unwrap().is_empty(), "an inserting job is seen");
        assert!(s.job_log(j, 0).unwrap().is_none());
        assert!(!s.cancel_job(j).unwrap());
        let w = worker(&s);
        assert!(s.lease(w, LONG).unwrap() == Leased::NoWork, "an inserting job's tile was leased");
        drop(s);
        let s = Store::open(&dir.path().join("tessera.db")).unwrap();
        let failed = s.job(j).unwrap().unwrap();
        assert_eq!(failed.state, JobState::Failed);
        assert_eq!(failed.error.as_deref(), Some(INTERRUPTED_INSERT));
        assert_eq!(s.ended_jobs_with_rows().unwrap(), [j]);
        while s.purge_job_rows(j, ROWS_PER_STEP).unwrap() > 0 {}
        assert_eq!(count(&s, "SELECT count(*) FROM tiles"), 0);
        assert!(s.ended_jobs_with_rows().unwrap().is_empty());
        assert_eq!(s.frames(j).unwrap()[0].tiles_total, (ROWS_PER_STEP * 2 + 5) as u32, "the frame stays");
    }

    #[test]
    fn ended_jobs_lose_their_tile_rows_but_keep_what_the_api_shows() {
        let (_d, s) = store("purge");
        let (cancelled, failed, live) = (job(&s, 0, 3), job(&s, 0, 2), job(&s, -1, 2));
        let w = worker(&s);
        let l = lease(&s, w);
        assert_eq!(l.job_id, cancelled);
        s.submit_result(l.lease_id, w, &PIXEL, None).unwrap();
        let l = lease(&s, w);
        s.fail_tile(l.lease_id, w, "boom", false).unwrap();
        assert!(s.cancel_job(cancelled).unwrap());
        s.fail_job(failed, "broken").unwrap();
        assert_eq!(s.ended_jobs_with_rows().unwrap(), [cancelled, failed]);
        assert_eq!(s.purge_job_rows(live, 100).unwrap(), 0, "a live job keeps its rows");
        for j in [cancelled, failed] {
            while s.purge_job_rows(j, 1).unwrap() > 0 {}
        }
        assert_eq!(count(&s, "SELECT count(*) FROM tiles"), 2, "only the live job's tiles are left");
        assert_eq!(count(&s, "SELECT count(*) FROM tile_failures"), 0);
        let frame = &s.frames(cancelled).unwrap()[0];
        assert_eq!((frame.tiles_done, frame.tiles_total), (1, 3), "tiles done per frame still answer");
        assert_eq!(kinds(&s, cancelled, 0), ["accepted", "tile_done", "tile_failed", "job_cancelled"]);
    }

    #[test]
    fn the_pages_of_purged_rows_go_back_to_the_file_system() {
        let (_d, s) = store("vacuum");
        let j = job(&s, 0, 50_000);
        let pages = || count(&s, "PRAGMA page_count");
        let full = pages();
        assert!(s.cancel_job(j).unwrap());
        while s.purge_job_rows(j, ROWS_PER_STEP).unwrap() > 0 {}
        assert!(count(&s, "PRAGMA freelist_count") > full / 2);
        let mut steps = 0;
        while s.release_free_pages(512).unwrap() > 0 {
            steps += 1;
            assert!(steps < 1000, "free pages are not given back");
        }
        s.checkpoint_to_start_over().unwrap();
        assert!(pages() < full / 10, "{full} pages, {} after the purge", pages());
    }

    #[test]
    fn a_failed_job_keeps_the_tiles_of_a_complete_frame_not_merged() {
        let (_d, s) = store("purge-complete");
        let j = job(&s, 0, 1);
        let w = worker(&s);
        let l = lease(&s, w);
        assert!(matches!(
            s.submit_result(l.lease_id, w, &PIXEL, None).unwrap(),
            ResultOutcome::Accepted { frame_complete: true, .. }
        ));
        s.fail_job(j, "merging frame 0 failed").unwrap();
        assert_eq!(s.purge_job_rows(j, 100).unwrap(), 0);
        assert_eq!(s.frame_tiles(j, 0).unwrap().len(), 1, "the frame's pixels are kept");
    }

    #[test]
    fn a_merged_frame_lets_go_of_its_pixels_before_the_job_is_done() {
        let (_d, s) = store("merged-pixels");
        let j = s
            .insert_job(&NewJob {
                frames: (0..2)
                    .map(|_| NewFrame {
                        camera: 0,
                        image_name: "m.png".into(),
                        width: 1,
                        height: 1,
                        tiles: vec![Rect { x0: 0, y0: 0, width: 1, height: 1 }],
                        samples: 1,
                        pass_samples: 16,
                        ..Default::default()
                    })
                    .collect(),
                ..two_frames()
            })
            .unwrap();
        let w = worker(&s);
        for _ in 0..2 {
            let l = lease(&s, w);
            s.submit_result(l.lease_id, w, &PIXEL, None).unwrap();
        }
        assert!(!s.frame_merged(j, 0, &["m.png".into()], MergeTiming::default()).unwrap());
        assert!(s.frame_tiles(j, 0).unwrap().is_empty(), "frame 0 kept its pixels after its merge");
        assert_eq!(s.frame_tiles(j, 1).unwrap().len(), 1, "frame 1 is not merged yet");
        assert!(s.frame_merged(j, 1, &["m.png".into()], MergeTiming::default()).unwrap());
        assert_eq!(count(&s, "SELECT count(*) FROM tiles WHERE pixels IS NOT NULL OR sums IS NOT NULL"), 0);
    }

    fn two_frames() -> NewJob {
        NewJob {
            name: "m".into(),
            priority: 0,
            tile_size: 1,
            samples: None,
            bundle: "0".repeat(64),
            scene_path: "scene.xml".into(),
            frames: Vec::new(),
            warnings: Vec::new(),
            allow_unsupported: false,
            denoise: false,
            pass_samples: None,
            noise_target: None,
            ..Default::default()
        }
    }

    #[test]
    fn registrations_stop_at_the_live_cap_and_lost_workers_are_forgotten_past_it() {
        let (_d, s) = store("workers-cap");
        let t = now();
        let register =
            |name: &str, max: Option<u64>| s.register_worker_within(name, 1, "h", max, t - 10.0).unwrap();
        for k in 0..3 {
            assert!(matches!(register(&format!("w{k}"), Some(3)), Registered::Id(_)));
        }
        assert_eq!(register("over", Some(3)), Registered::Full { live: 3 });
        assert!(matches!(register("local", None), Registered::Id(_)), "the local workers are not capped");
        // Three fall silent; one of them holds a lease (it may still upload).
        let j = job(&s, 0, 1);
        let holder = s.workers().unwrap()[0].id;
        lease(&s, holder);
        s.conn().execute("UPDATE workers SET last_seen = ?1 WHERE name != 'local'", [t - 100.0]).unwrap();
        let Registered::Id(new) = register("new", Some(3)) else { panic!("refused with one live worker") };
        let names: Vec<String> = s.workers().unwrap().into_iter().map(|w| w.name).collect();
        assert_eq!(names.len(), 3, "{names:?}");
        assert!(names.contains(&"w0".to_string()), "the lease holder was forgotten: {names:?}");
        let _ = j;
        // Forgetting by age keeps the highest id, so that no id is handed out twice.
        s.conn().execute("UPDATE workers SET last_seen = ?1", [t - 100.0]).unwrap();
        assert!(s.cancel_job(j).unwrap());
        assert_eq!(s.forget_workers(t).unwrap(), 2);
        assert_eq!(s.workers().unwrap().iter().map(|w| w.id).collect::<Vec<_>>(), [new]);
        let Registered::Id(next) = register("next", Some(3)) else { panic!() };
        assert!(next > new);
    }

    #[test]
    fn a_forgotten_workers_name_stays_in_the_job_log() {
        let (_d, s) = store("workers-log");
        let j = job(&s, 0, 2);
        let (a, _b) = (s.register_worker("alpha", 1, "").unwrap(), s.register_worker("beta", 1, "").unwrap());
        let l = lease(&s, a);
        s.fail_tile(l.lease_id, a, "boom", false).unwrap();
        assert_eq!(s.forget_workers(now() + 1.0).unwrap(), 1, "alpha goes, beta (the highest id) stays");
        let log = s.job_log(j, 0).unwrap().unwrap();
        assert_eq!(log[1].worker.as_deref(), Some("alpha"));
    }

    #[test]
    fn reopening_the_store_queues_leased_tiles_again_under_new_lease_ids() {
        let (dir, s) = store("reopen");
        let j = job(&s, 0, 1);
        let w = worker(&s);
        let l = lease(&s, w);
        drop(s);
        // Ids start past the clock in milliseconds: a restart takes longer than one.
        std::thread::sleep(std::time::Duration::from_millis(5));
        let s = Store::open(&dir.path().join("tessera.db")).unwrap();
        assert_eq!(s.submit_result(l.lease_id, w, &PIXEL, None).unwrap(), ResultOutcome::Conflict);
        let again = lease(&s, w);
        assert_eq!((again.job_id, again.tile), (j, 0));
        assert!(again.lease_id > l.lease_id, "lease ids repeat across a restart");
    }
}
