//! The store's housekeeping, in the background and in small steps: the rows of cancelled and
//! failed jobs purged (at once when a job ends, and in a sweep at start and every
//! [`SWEEP`]), the free pages they leave given back to the file system, and workers not seen
//! for `--forget-workers-after` forgotten, and (at start and every sweep) the files and
//! tar bundles no job names removed once an hour old (`files::collect_garbage`), and finished
//! jobs removed as the retention policy says (`retention::apply`: at start, every sweep and
//! whenever a job ends).
//!
//! Every step is one short transaction ([`crate::db::ROWS_PER_STEP`] rows): other requests wait
//! for one step at most, never for a whole job of a million rows.

use std::collections::BTreeSet;
use std::time::Duration;

use tessera::protocol::{JobState, ServerEvent};
use tokio::sync::broadcast::error::RecvError;

use crate::db::{CHECKPOINT_STEPS, ROWS_PER_STEP};
use crate::state::AppState;

/// How often every ended job is looked at again (a purge cut short by a stop resumes at the
/// next start anyway) and stale workers are forgotten.
pub const SWEEP: Duration = Duration::from_secs(60);

/// Free pages given back to the file system per step (4 KiB each).
const PAGES_PER_STEP: u32 = 512;

/// Pause between two steps, during which the store is free for everyone else.
const PAUSE: Duration = Duration::from_millis(2);

async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> anyhow::Result<T> + Send + 'static,
) -> anyhow::Result<T> {
    tokio::task::spawn_blocking(f).await.map_err(|e| anyhow::anyhow!("a housekeeping task failed: {e}"))?
}

/// Starts the task that copies the job store's write-ahead log into its file every
/// [`crate::db::CHECKPOINT_EVERY`], on a connection of its own (the store's requests never wait
/// for it).
pub fn spawn_checkpoints(store: std::sync::Arc<crate::db::Store>) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(crate::db::CHECKPOINT_EVERY);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tick.tick().await;
            let store = store.clone();
            if let Err(e) = blocking(move || store.checkpoint()).await {
                tracing::error!("checkpoint of the job store: {e:#}");
            }
        }
    })
}

/// Removes the files of the file store and the tar bundles that no job names any more, once
/// unused for [`crate::files::GRACE`], with a log line saying what went.
async fn collect_garbage(state: &AppState) {
    let (files, blobs, store) = (state.files.clone(), state.blobs.clone(), state.store.clone());
    let grace = crate::files::GRACE;
    match blocking(move || crate::files::collect_garbage(&files, &blobs, &store, grace)).await {
        Ok(c) if c == crate::files::Collected::default() => {}
        Ok(c) => tracing::info!(
            "removed {} file(s) ({} bytes) and {} bundle(s) ({} bytes) that no job names, unused for {} s",
            c.files,
            c.file_bytes,
            c.bundles,
            c.bundle_bytes,
            grace.as_secs()
        ),
        Err(e) => tracing::error!("removing files that no job names: {e:#}"),
    }
}

/// Applies the retention policy (`--keep-finished-days`, `--disk-budget-mb`;
/// [`crate::retention::apply`], which logs each removal).
/// Removes the tile result files no row names any more (a job deleted or a frame queued again
/// while its file was being written), once older than [`crate::db::RESULT_GRACE`].
async fn sweep_results(state: &AppState) {
    let store = state.store.clone();
    match blocking(move || store.sweep_results(crate::db::RESULT_GRACE)).await {
        Ok(0) => {}
        Ok(n) => tracing::info!("removed {n} tile result file(s) that no tile names any more"),
        Err(e) => tracing::error!("removing tile result files no tile names: {e:#}"),
    }
}

async fn retain(state: &AppState) {
    if state.settings.retention.is_off() {
        return;
    }
    let st = state.clone();
    if let Err(e) = blocking(move || crate::retention::apply(&st, crate::db::now())).await {
        tracing::error!("removing finished jobs past the retention policy: {e:#}");
    }
}

/// Starts the housekeeping task. `forget_after`: seconds of silence after which a worker
/// without a live lease is forgotten.
pub fn spawn(state: AppState, forget_after: f64) -> tokio::task::JoinHandle<()> {
    // Subscribed before the task starts, so that no job ending after this returns is missed.
    let mut events = state.events.subscribe();
    tokio::spawn(async move {
        // A worker is forgotten at most a quarter of `forget_after` late.
        let mut sweep =
            tokio::time::interval(SWEEP.min(Duration::from_secs_f64((forget_after / 4.0).max(1.0))));
        let mut ended: BTreeSet<u64> = BTreeSet::new();
        loop {
            let mut full = false;
            tokio::select! {
                e = events.recv() => match e {
                    Ok(ServerEvent::Job { job, state: JobState::Canceled | JobState::Failed }) => {
                        ended.insert(job);
                        retain(&state).await;
                    }
                    // A job ended: the retention policy looks again.
                    Ok(ServerEvent::Job { state: JobState::Done, .. }) => {
                        retain(&state).await;
                        continue;
                    }
                    Ok(_) => continue,
                    Err(RecvError::Lagged(_)) => full = true,
                    Err(RecvError::Closed) => return,
                },
                _ = sweep.tick() => {
                    full = true;
                    let (store, before) = (state.store.clone(), crate::db::now() - forget_after);
                    match blocking(move || store.forget_workers(before)).await {
                        Ok(0) => {}
                        Ok(n) => {
                            tracing::info!("forgot {n} worker(s) not seen for {forget_after} s");
                            state.emit(ServerEvent::Workers);
                        }
                        Err(e) => tracing::error!("forgetting stale workers: {e:#}"),
                    }
                    collect_garbage(&state).await;
                    sweep_results(&state).await;
                    retain(&state).await;
                }
            }
            if full {
                let store = state.store.clone();
                match blocking(move || store.ended_jobs_with_rows()).await {
                    Ok(jobs) => ended.extend(jobs),
                    Err(e) => tracing::error!("looking for ended jobs' rows: {e:#}"),
                }
            }
            if ended.is_empty() {
                continue;
            }
            let (mut purged, mut steps) = (0, 0);
            while let Some(job) = ended.pop_first() {
                loop {
                    let store = state.store.clone();
                    match blocking(move || store.purge_job_rows(job, ROWS_PER_STEP)).await {
                        Ok(0) => break,
                        Ok(n) => {
                            purged += n;
                            steps += 1;
                            if steps % CHECKPOINT_STEPS == 0 {
                                // The log starts over instead of growing by the whole purge.
                                let store = state.store.clone();
                                let _ = blocking(move || store.checkpoint_to_start_over()).await;
                            }
                        }
                        Err(e) => {
                            tracing::error!(job, "purging the rows of an ended job: {e:#}");
                            break;
                        }
                    }
                    tokio::time::sleep(PAUSE).await;
                }
            }
            if purged == 0 {
                continue;
            }
            tracing::info!("purged {purged} row(s) of ended jobs");
            loop {
                let store = state.store.clone();
                match blocking(move || store.release_free_pages(PAGES_PER_STEP)).await {
                    Ok(0) => break,
                    Ok(_) => {
                        // Each step writes its pages to the log: it starts over after each.
                        let store = state.store.clone();
                        let _ = blocking(move || store.checkpoint_to_start_over()).await;
                        tokio::time::sleep(PAUSE).await;
                    }
                    Err(e) => {
                        tracing::error!("giving free pages back: {e:#}");
                        break;
                    }
                }
            }
            let store = state.store.clone();
            if let Err(e) = blocking(move || store.checkpoint_to_start_over()).await {
                tracing::error!("checkpoint: {e:#}");
            }
        }
    })
}
