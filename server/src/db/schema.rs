//! The store's tables: the schema a new database gets, and what an older one gains when it
//! opens.

use super::*;

/// The tables of a new database.
pub(super) const SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS jobs(
    id INTEGER PRIMARY KEY,
    name TEXT NOT NULL,
    state TEXT NOT NULL,
    priority INTEGER NOT NULL,
    tile_size INTEGER NOT NULL,
    samples INTEGER,
    bundle TEXT NOT NULL,
    scene_path TEXT NOT NULL,
    submitted_at REAL NOT NULL,
    started_at REAL,
    finished_at REAL,
    error TEXT,
    allow_unsupported INTEGER NOT NULL DEFAULT 0,
    denoise INTEGER NOT NULL DEFAULT 0,
    pass_samples INTEGER,
    noise_target REAL,
    manifest TEXT,
    notify_url TEXT,
    notified INTEGER NOT NULL DEFAULT 0,
    scenes INTEGER NOT NULL DEFAULT 1,
    video TEXT,
    fps INTEGER,
    keep_float INTEGER,
    scale REAL,
    worker_tags TEXT
);
CREATE TABLE IF NOT EXISTS frames(
    job_id INTEGER NOT NULL,
    idx INTEGER NOT NULL,
    camera INTEGER NOT NULL,
    image_name TEXT NOT NULL,
    width INTEGER NOT NULL,
    height INTEGER NOT NULL,
    tiles_total INTEGER NOT NULL,
    tiles_done INTEGER NOT NULL DEFAULT 0,
    outputs TEXT,
    samples INTEGER NOT NULL DEFAULT 1,
    passes_total INTEGER NOT NULL DEFAULT 1,
    passes_published INTEGER NOT NULL DEFAULT 0,
    scene_path TEXT,
    samples_done INTEGER NOT NULL DEFAULT 0,
    samples_skipped INTEGER NOT NULL DEFAULT 0,
    PRIMARY KEY(job_id, idx)
);
CREATE TABLE IF NOT EXISTS tiles(
    job_id INTEGER NOT NULL,
    frame INTEGER NOT NULL,
    tile INTEGER NOT NULL,
    x0 INTEGER NOT NULL, y0 INTEGER NOT NULL, w INTEGER NOT NULL, h INTEGER NOT NULL,
    state TEXT NOT NULL,
    lease_id INTEGER,
    worker_id INTEGER,
    deadline REAL,
    pixels BLOB,
    -- A large result's file in results/ instead of `pixels` (db/results.rs).
    pixels_file TEXT,
    render_seconds REAL,
    pass INTEGER NOT NULL DEFAULT 0,
    first_sample INTEGER,
    end_sample INTEGER,
    sums BLOB,
    passes_done INTEGER NOT NULL DEFAULT 0,
    samples_done INTEGER NOT NULL DEFAULT 0,
    error REAL,
    finished INTEGER NOT NULL DEFAULT 0,
    -- Under a per-pixel noise target: the pixels this unit renders (NULL: every pixel), and on
    -- the tile's first unit each pixel's samples so far (NULL: `samples_done` for every pixel).
    mask BLOB,
    pixel_samples BLOB,
    PRIMARY KEY(job_id, frame, tile, pass)
);
CREATE INDEX IF NOT EXISTS tiles_by_state ON tiles(state, job_id);
CREATE INDEX IF NOT EXISTS jobs_by_state ON jobs(state, priority, id);
CREATE UNIQUE INDEX IF NOT EXISTS tiles_by_lease ON tiles(lease_id) WHERE lease_id IS NOT NULL;
CREATE TABLE IF NOT EXISTS tile_failures(
    job_id INTEGER NOT NULL,
    frame INTEGER NOT NULL,
    tile INTEGER NOT NULL,
    worker_id INTEGER NOT NULL,
    error TEXT NOT NULL,
    at REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS tile_failures_by_tile ON tile_failures(job_id, frame, tile);
CREATE INDEX IF NOT EXISTS tile_failures_by_worker ON tile_failures(job_id, worker_id);
CREATE TABLE IF NOT EXISTS workers(
    id INTEGER PRIMARY KEY,
    name TEXT NOT NULL,
    threads INTEGER NOT NULL,
    registered_at REAL NOT NULL,
    last_seen REAL NOT NULL,
    tiles_done INTEGER NOT NULL DEFAULT 0,
    failures INTEGER NOT NULL DEFAULT 0,
    rendering INTEGER,
    secret_hash TEXT,
    mode TEXT NOT NULL DEFAULT 'active',
    tags TEXT,
    local INTEGER NOT NULL DEFAULT 0
);
CREATE TABLE IF NOT EXISTS job_files(
    job_id INTEGER NOT NULL,
    path TEXT NOT NULL,
    sha256 TEXT NOT NULL,
    size INTEGER NOT NULL,
    PRIMARY KEY(job_id, path)
) WITHOUT ROWID;
CREATE INDEX IF NOT EXISTS job_files_by_sha ON job_files(sha256);
CREATE TABLE IF NOT EXISTS job_events(
    job_id INTEGER NOT NULL,
    seq INTEGER NOT NULL,
    at REAL NOT NULL,
    kind TEXT NOT NULL,
    frame INTEGER,
    tile INTEGER,
    worker TEXT,
    seconds REAL,
    message TEXT NOT NULL,
    worker_id INTEGER,
    PRIMARY KEY(job_id, seq)
) WITHOUT ROWID;
";

/// Adds what later versions added to the tables of an older database (CREATE TABLE IF NOT
/// EXISTS leaves an existing table as it is).
pub(super) fn migrate(conn: &Connection) -> Result<()> {
    let has_column = |table: &str, column: &str| -> Result<bool> {
        let n: i64 = conn.query_row(
            "SELECT count(*) FROM pragma_table_info(?1) WHERE name = ?2",
            params![table, column],
            |r| r.get(0),
        )?;
        Ok(n > 0)
    };
    if !has_column("workers", "secret_hash")? {
        // Workers registered before secrets existed have none: every call of theirs is refused
        // until they register again (a worker does when the server refuses it).
        conn.execute("ALTER TABLE workers ADD COLUMN secret_hash TEXT", [])?;
    }
    if !has_column("job_events", "worker_id")? {
        // Older events kept the worker's name itself (in `worker`); they still show it.
        conn.execute("ALTER TABLE job_events ADD COLUMN worker_id INTEGER", [])?;
    }
    if !has_column("jobs", "allow_unsupported")? {
        // Jobs accepted before the column existed were accepted with their unsupported elements
        // (older servers only warned about them): they keep rendering that way.
        conn.execute("ALTER TABLE jobs ADD COLUMN allow_unsupported INTEGER NOT NULL DEFAULT 1", [])?;
    }
    if !has_column("jobs", "denoise")? {
        // Jobs from before denoising existed did not ask for it.
        conn.execute("ALTER TABLE jobs ADD COLUMN denoise INTEGER NOT NULL DEFAULT 0", [])?;
    }
    if !has_column("jobs", "pass_samples")? {
        // Jobs from before passes render each tile whole: one pass (NULL), no noise target.
        conn.execute_batch(
            "ALTER TABLE jobs ADD COLUMN pass_samples INTEGER;
             ALTER TABLE jobs ADD COLUMN noise_target REAL;
             ALTER TABLE frames ADD COLUMN samples INTEGER NOT NULL DEFAULT 1;
             ALTER TABLE frames ADD COLUMN passes_total INTEGER NOT NULL DEFAULT 1;
             ALTER TABLE frames ADD COLUMN passes_published INTEGER NOT NULL DEFAULT 0;",
        )?;
    }
    if !has_column("tiles", "pass")? {
        // A tile row becomes a unit of work (tile, pass): the key gains the pass, which SQLite
        // cannot add to a table's key in place. Every existing row is its tile's only pass.
        conn.execute_batch(
            "BEGIN;
             ALTER TABLE tiles RENAME TO tiles_before_passes;
             DROP INDEX IF EXISTS tiles_by_state;
             DROP INDEX IF EXISTS tiles_queue;
             DROP INDEX IF EXISTS tiles_by_lease;",
        )?;
        conn.execute_batch(SCHEMA)?;
        conn.execute_batch(
            "INSERT INTO tiles(job_id, frame, tile, x0, y0, w, h, state, lease_id, worker_id, deadline, pixels, render_seconds)
               SELECT job_id, frame, tile, x0, y0, w, h, state, lease_id, worker_id, deadline, pixels, render_seconds
               FROM tiles_before_passes;
             DROP TABLE tiles_before_passes;
             COMMIT;",
        )?;
    }
    if !has_column("jobs", "manifest")? {
        // Jobs from before the file store keep their tar bundle (`manifest` NULL) and one
        // scene file for all their frames (`scene_path` NULL: the job's).
        conn.execute_batch(
            "ALTER TABLE jobs ADD COLUMN manifest TEXT;
             ALTER TABLE frames ADD COLUMN scene_path TEXT;",
        )?;
    }
    if !has_column("workers", "mode")? {
        // Every worker registered before drain and disable existed takes work.
        conn.execute("ALTER TABLE workers ADD COLUMN mode TEXT NOT NULL DEFAULT 'active'", [])?;
    }
    if !has_column("jobs", "notified")? {
        // Jobs that ended before notifications existed are not announced now.
        conn.execute_batch(
            "ALTER TABLE jobs ADD COLUMN notify_url TEXT;
             ALTER TABLE jobs ADD COLUMN notified INTEGER NOT NULL DEFAULT 0;
             UPDATE jobs SET notified = 1 WHERE state IN ('done', 'failed', 'canceled');",
        )?;
    }
    if !has_column("jobs", "video")? {
        // Jobs from before videos: the defaults (`video`, `fps` NULL), float frames kept.
        conn.execute_batch(
            "ALTER TABLE jobs ADD COLUMN video TEXT;
             ALTER TABLE jobs ADD COLUMN fps INTEGER;
             ALTER TABLE jobs ADD COLUMN keep_float INTEGER;",
        )?;
    }
    if !has_column("jobs", "scenes")? {
        // Jobs from before sequences render one scene file.
        conn.execute_batch("ALTER TABLE jobs ADD COLUMN scenes INTEGER NOT NULL DEFAULT 1;")?;
    }
    if conn.pragma_query_value(None, "user_version", |r| r.get::<_, i64>(0))? < 1 {
        // Events name their worker themselves since workers can be forgotten: older events get
        // the name of theirs while it is still known.
        conn.execute_batch(
            "UPDATE job_events SET worker = (SELECT name FROM workers w WHERE w.id = job_events.worker_id)
               WHERE worker IS NULL AND worker_id IS NOT NULL;
             PRAGMA user_version = 1;",
        )?;
    }
    if !has_column("frames", "samples_done")? {
        // Progress by samples: the counters of frames from before them, counted once from
        // their tiles (a tile rendered whole has all its samples once done; a merged frame
        // whose tiles are purged has all it took).
        conn.execute_batch(
            "ALTER TABLE frames ADD COLUMN samples_done INTEGER NOT NULL DEFAULT 0;
             ALTER TABLE frames ADD COLUMN samples_skipped INTEGER NOT NULL DEFAULT 0;
             UPDATE frames SET
               samples_skipped = coalesce((SELECT sum(t.w * t.h * max(frames.samples - t.samples_done, 0)) FROM tiles t
                 WHERE t.job_id = frames.job_id AND t.frame = frames.idx AND t.pass = 0
                   AND t.first_sample IS NOT NULL AND t.finished), 0),
               samples_done = coalesce((SELECT sum(t.w * t.h * CASE WHEN t.first_sample IS NOT NULL THEN t.samples_done
                                                     WHEN t.state = 'done' THEN frames.samples ELSE 0 END) FROM tiles t
                 WHERE t.job_id = frames.job_id AND t.frame = frames.idx AND t.pass = 0), 0);
             UPDATE frames SET samples_done = max(width * height * samples - samples_skipped, 0)
               WHERE outputs IS NOT NULL;",
        )?;
    }
    conn.execute_batch(
        "CREATE INDEX IF NOT EXISTS tiles_by_state ON tiles(state, job_id);
         CREATE INDEX IF NOT EXISTS tiles_queue_by_pass ON tiles(job_id, state, pass, frame, tile);
         CREATE INDEX IF NOT EXISTS tiles_queue_by_frame ON tiles(job_id, state, frame, pass, tile);
         CREATE UNIQUE INDEX IF NOT EXISTS tiles_by_lease ON tiles(lease_id) WHERE lease_id IS NOT NULL;",
    )?;
    if !has_column("jobs", "scale")? {
        // Jobs from before `scale` render at their cameras' resolution (NULL).
        conn.execute("ALTER TABLE jobs ADD COLUMN scale REAL", [])?;
    }
    if !has_column("workers", "tags")? {
        // Workers from before tags declared none, and none of them was known as one of the
        // server's own local workers (a local worker's first start after this gets a row it
        // keeps from then on).
        conn.execute_batch(
            "ALTER TABLE workers ADD COLUMN tags TEXT;
             ALTER TABLE workers ADD COLUMN local INTEGER NOT NULL DEFAULT 0;",
        )?;
    }
    if !has_column("jobs", "worker_tags")? {
        // Jobs from before tags ask for none: any worker renders them.
        conn.execute("ALTER TABLE jobs ADD COLUMN worker_tags TEXT", [])?;
    }
    if !has_column("tiles", "mask")? {
        // Per-pixel noise targets: a pass row's `mask`, the pixels it renders (NULL: every
        // one), and the row of pass 0's `pixel_samples`, each pixel's samples so far (NULL:
        // `samples_done` for every pixel). Tiles stored before them have NULL in both, which
        // means what they meant: whole tiles.
        conn.execute_batch(
            "ALTER TABLE tiles ADD COLUMN mask BLOB;
             ALTER TABLE tiles ADD COLUMN pixel_samples BLOB;",
        )?;
    }
    if !has_column("tiles", "pixels_file")? {
        // Results from before result files are all in their rows (`pixels`).
        conn.execute("ALTER TABLE tiles ADD COLUMN pixels_file TEXT", [])?;
    }
    Ok(())
}
