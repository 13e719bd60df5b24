//! The running totals `/metrics` reports: one row kept up in the transactions that change
//! them, so that a call never scans the tiles.

use super::*;

/// The running totals `/metrics` reports, one row kept up in the transactions that change them
/// (a call reads one row instead of scanning every tile).
const COUNTERS_SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS counters(
    id INTEGER PRIMARY KEY CHECK (id = 1),
    tiles_done INTEGER NOT NULL,
    render_seconds_sum REAL NOT NULL,
    render_seconds_count INTEGER NOT NULL
);
";

/// Creates the counters' row; a database from before it gets the totals its tiles hold, counted
/// once.
pub(super) fn seed_counters(conn: &Connection) -> Result<()> {
    conn.execute_batch(COUNTERS_SCHEMA)?;
    let seeded: bool = conn.query_row("SELECT EXISTS (SELECT 1 FROM counters)", [], |r| r.get(0))?;
    if !seeded {
        conn.execute(
            "INSERT INTO counters(id, tiles_done, render_seconds_sum, render_seconds_count)
             SELECT 1, count(CASE WHEN state = 'done' THEN 1 END), coalesce(sum(render_seconds), 0.0), count(render_seconds)
             FROM tiles",
            [],
        )?;
    }
    Ok(())
}

impl Store {
    /// Counts for /metrics: the jobs by state (from the `jobs_by_state` index) and the running
    /// totals of the counters' row, never a scan of the tiles.
    pub fn metrics(&self) -> Result<StoreMetrics> {
        let conn = self.conn();
        let mut stmt = conn.prepare_cached("SELECT state, count(*) FROM jobs GROUP BY state")?;
        let states =
            stmt.query_map([], |r| Ok((r.get(0)?, r.get(1)?)))?.collect::<rusqlite::Result<Vec<_>>>()?;
        let (done, sum, count): (i64, f64, i64) = conn.query_row_cached(
            "SELECT tiles_done, render_seconds_sum, render_seconds_count FROM counters WHERE id = 1",
            [],
            |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)),
        )?;
        Ok(StoreMetrics {
            jobs_by_state: states,
            tiles_done: done,
            render_seconds_sum: sum,
            render_seconds_count: count,
        })
    }
}
