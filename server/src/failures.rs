//! The failure rules the store applies inside its transactions, as constants and a pure
//! function: when a failed tile fails its job, and how long a worker is kept off a tile or a job
//! it failed. They import nothing of the server, so that the store ([`crate::db`]) and the
//! scheduler ([`crate::scheduler`], the rest of the rules) do not import each other in a
//! circle.

/// A tile that fails on this many different workers fails its job.
pub const TILE_FAILURE_WORKERS: i64 = 3;
/// ... or this many times in all (so that a farm with fewer workers still ends).
pub const TILE_FAILURE_TOTAL: i64 = 5;
/// A worker that fails this many tiles of a job is kept off that job (for
/// [`RETRY_FAILED_AFTER`]).
pub const WORKER_FAILURES_PER_JOB: i64 = 3;
/// How long a worker is kept off a tile it failed, and off a job whose tiles it failed
/// [`WORKER_FAILURES_PER_JOB`] times, counted from its latest failure there. Long enough for
/// another worker to take the tile on a farm that has one; finite, so that on a farm of one or
/// two workers the tile is tried again until [`TILE_FAILURE_TOTAL`] fails its job, instead of
/// staying queued for ever with nobody allowed to take it. The default of
/// `--retry-failed-after-seconds`.
pub const RETRY_FAILED_AFTER: f64 = 30.0;

/// A tile's failures so far, the latest included, as the store counts them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileFailures {
    /// Different workers it failed on.
    pub workers: i64,
    /// Failures in all.
    pub total: i64,
    /// Of those, leases that expired: the worker stopped answering while rendering the tile.
    pub crashes: i64,
}

/// The failure rule. After a failure of tile `tile` of frame `frame` (`error`, and `fatal` when
/// the tile went over the render time limit, which another worker would spend again): `None`
/// when the tile goes back to the queue, or the message its job fails with once the tile has
/// failed on [`TILE_FAILURE_WORKERS`] workers, [`TILE_FAILURE_TOTAL`] times, or fatally. A lease
/// expiry is such a failure too (the worker crashed), and a tile that only ever crashed its
/// workers says so.
pub fn tile_verdict(frame: i64, tile: i64, f: TileFailures, error: &str, fatal: bool) -> Option<String> {
    if !(fatal || f.workers >= TILE_FAILURE_WORKERS || f.total >= TILE_FAILURE_TOTAL) {
        return None;
    }
    let TileFailures { workers, total, crashes } = f;
    Some(if crashes == total {
        format!(
            "tile {tile} of frame {frame} crashed its workers: {total} time(s), on {workers} worker(s), the worker \
             rendering it stopped answering and its lease expired. The scene may make the renderer run out of \
             memory or crash; render it with `tessera-worker render` to see the error, or report it with the scene"
        )
    } else {
        format!(
            "tile {tile} of frame {frame} failed on {workers} worker(s), {total} time(s); last error: {error}"
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn failures(workers: i64, total: i64, crashes: i64) -> TileFailures {
        TileFailures { workers, total, crashes }
    }

    #[test]
    fn a_tile_fails_its_job_on_three_workers_five_failures_or_one_fatal() {
        let verdict = |f, fatal| tile_verdict(0, 7, f, "boom", fatal);
        assert_eq!(verdict(failures(1, 1, 0), false), None);
        assert_eq!(verdict(failures(2, 2, 0), false), None);
        assert_eq!(verdict(failures(2, 4, 0), false), None);
        let three = verdict(failures(3, 3, 0), false).expect("three workers");
        assert_eq!(three, "tile 7 of frame 0 failed on 3 worker(s), 3 time(s); last error: boom");
        assert!(verdict(failures(2, 5, 0), false).expect("five failures").contains("5 time(s)"));
        assert!(verdict(failures(1, 1, 0), true).expect("fatal").contains("last error: boom"));
    }

    #[test]
    fn a_tile_that_only_crashed_its_workers_says_so() {
        let crashed = tile_verdict(1, 2, failures(3, 3, 3), "stopped answering", false).unwrap();
        assert!(crashed.starts_with("tile 2 of frame 1 crashed its workers: 3 time(s), on 3 worker(s)"));
        // One reported error among the crashes: the message quotes it.
        let mixed = tile_verdict(1, 2, failures(3, 3, 2), "out of memory", false).unwrap();
        assert!(mixed.ends_with("last error: out of memory"), "{mixed}");
    }
}
