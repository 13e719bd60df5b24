//! Finished jobs removed with their files: one at a time (`DELETE /api/v1/jobs/{id}`,
//! [`remove_job`]), and by the retention policy ([`apply`], run by the housekeeping):
//! `--keep-finished-days` removes finished jobs (done, failed, cancelled) that ended longer ago
//! than that, `--disk-budget-mb` the oldest finished jobs while the jobs' outputs (`outputs/`
//! and `frames/` of the data directory) take more than the budget. The budget never removes
//! the job that finished last (its results have just arrived). A queued, running or paused job
//! is never removed. Each removal is a line of the server's log with the job's id and bytes.

use tessera::protocol::JobState;

use crate::state::AppState;
pub use crate::state::Retention;

/// Most days `--keep-finished-days` takes (a hundred years).
pub const MAX_KEEP_DAYS: f64 = 36_500.0;

/// The policy of `--keep-finished-days` and `--disk-budget-mb`, or the message naming the flag
/// that is wrong.
pub fn policy(keep_days: Option<f64>, budget_mb: Option<u64>) -> Result<Retention, String> {
    if let Some(d) = keep_days
        && !(d > 0.0 && d <= MAX_KEEP_DAYS)
    {
        return Err(format!(
            "--keep-finished-days must be a positive number of days (fractions allowed), at most {MAX_KEEP_DAYS}, found {d}; \
             leave it out to keep finished jobs for ever"
        ));
    }
    if let Some(mb) = budget_mb
        && !(1..=(u64::MAX >> 20)).contains(&mb)
    {
        return Err(format!(
            "--disk-budget-mb must be at least 1 (MiB of the jobs' outputs), found {mb}; leave it out for no budget"
        ));
    }
    Ok(Retention {
        keep_finished_seconds: keep_days.map(|d| d * 86_400.0),
        disk_budget_bytes: budget_mb.map(|mb| mb << 20),
    })
}

/// What [`remove_job`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Removed {
    NoSuchJob,
    /// The job is queued, running or paused: it must be cancelled first.
    NotFinal(JobState),
    /// The job went: this many rows of the store, this many bytes of its folders.
    Gone {
        rows: usize,
        bytes: u64,
    },
}

/// Deletes a finished job (done, failed or cancelled): its rows, its frames' outputs and the
/// server's own files of them (`outputs/ID/`, `frames/ID/`, the video among them). Its files
/// in the file store, and its tar bundle, go with the housekeeping once no other job names
/// them. Its id is never given to another job. Blocking: call it off the async threads.
pub fn remove_job(state: &AppState, id: u64) -> anyhow::Result<Removed> {
    let rows = match state.store.delete_job(id)? {
        crate::db::Deleted::NoSuchJob => return Ok(Removed::NoSuchJob),
        crate::db::Deleted::NotFinal(s) => return Ok(Removed::NotFinal(s)),
        crate::db::Deleted::Gone { rows } => rows,
    };
    state.cameras.lock().unwrap_or_else(|e| e.into_inner()).remove(&id);
    state.waiting_for_space.lock().unwrap_or_else(|e| e.into_inner()).retain(|(job, _), _| *job != id);
    let mut bytes = 0u64;
    for sub in [crate::storage::OUTPUTS_DIR, crate::storage::FRAMES_DIR] {
        let dir = state.settings.data_dir.join(sub).join(id.to_string());
        bytes += folder_bytes(&dir);
        match std::fs::remove_dir_all(&dir) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            // The rows are gone already: the folder is only logged (the id is never reused).
            Err(e) => tracing::error!(job = id, "cannot remove {}: {e}", dir.display()),
        }
    }
    // The pages of the deleted rows go back to the file system.
    while state.store.release_free_pages(512)? > 0 {
        state.store.checkpoint_to_start_over()?;
    }
    Ok(Removed::Gone { rows, bytes })
}

/// Bytes of the files under `dir` (0 if it is missing).
pub fn folder_bytes(dir: &std::path::Path) -> u64 {
    let Ok(entries) = std::fs::read_dir(dir) else { return 0 };
    entries
        .flatten()
        .map(|e| match e.file_type() {
            Ok(t) if t.is_dir() => folder_bytes(&e.path()),
            Ok(t) if t.is_file() => e.metadata().map_or(0, |m| m.len()),
            _ => 0,
        })
        .sum()
}

/// Bytes the jobs' outputs take: `outputs/` and `frames/` of the data directory.
pub fn outputs_bytes(data_dir: &std::path::Path) -> u64 {
    [crate::storage::OUTPUTS_DIR, crate::storage::FRAMES_DIR]
        .iter()
        .map(|s| folder_bytes(&data_dir.join(s)))
        .sum()
}

/// Applies the retention policy once: removes the finished jobs it says to, oldest first, each
/// logged. Returns the ids removed. Blocking: call it off the async threads.
pub fn apply(state: &AppState, now: f64) -> anyhow::Result<Vec<u64>> {
    let policy = state.settings.retention;
    let mut removed = Vec::new();
    if policy.is_off() {
        return Ok(removed);
    }
    let finished = state.store.finished_jobs_oldest_first()?;
    let mut left = finished.len();
    if let Some(keep) = policy.keep_finished_seconds {
        for &(id, at) in finished.iter().filter(|(_, at)| now - at > keep) {
            if let Removed::Gone { bytes, .. } = remove_job(state, id)? {
                tracing::info!(
                    job = id,
                    bytes,
                    "removed a finished job with its outputs: it ended {:.1} days ago, past --keep-finished-days",
                    (now - at) / 86_400.0
                );
                removed.push(id);
            }
            left -= 1;
        }
    }
    if let Some(budget) = policy.disk_budget_bytes {
        let mut used = outputs_bytes(&state.settings.data_dir);
        // The job that finished last stays, whatever the budget.
        let aged: Vec<u64> = removed.clone();
        for &(id, _) in finished.iter().filter(|(id, _)| !aged.contains(id)) {
            if used <= budget || left <= 1 {
                break;
            }
            if let Removed::Gone { bytes, .. } = remove_job(state, id)? {
                tracing::info!(
                    job = id,
                    bytes,
                    used,
                    budget,
                    "removed the oldest finished job with its outputs: the jobs' outputs took more than --disk-budget-mb"
                );
                used = used.saturating_sub(bytes);
                removed.push(id);
            }
            left -= 1;
        }
        if used > budget && !removed.is_empty() {
            tracing::warn!(
                used,
                budget,
                "the jobs' outputs take more than --disk-budget-mb; only queued, running or paused jobs and the \
                 last finished one are left"
            );
        }
    }
    Ok(removed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_policy_flags_are_checked_and_off_by_default() {
        assert!(policy(None, None).unwrap().is_off());
        let p = policy(Some(0.5), Some(3)).unwrap();
        assert_eq!(p.keep_finished_seconds, Some(43_200.0));
        assert_eq!(p.disk_budget_bytes, Some(3 << 20));
        for d in [0.0, -1.0, f64::NAN, f64::INFINITY, 1e9] {
            assert!(policy(Some(d), None).unwrap_err().contains("--keep-finished-days"), "{d}");
        }
        for mb in [0, u64::MAX] {
            assert!(policy(None, Some(mb)).unwrap_err().contains("--disk-budget-mb"), "{mb}");
        }
    }
}
