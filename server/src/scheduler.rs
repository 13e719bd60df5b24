//! The scheduling rules: which tile a worker gets and when, what a failure or a silent worker
//! does to a tile and its job, when a lease is taken back, when a worker is lost.
//!
//! The rules the store ([`crate::db`]) applies inside one transaction are in
//! [`crate::failures`] (the failure limits, `tile_verdict`; the per-worker ban), so that the
//! store imports them and not this module; priority order is the store's lease query. The rest
//! come first here, as constants and pure functions (lost workers). [`Scheduler`] does
//! everything around the store: the long poll for a lease waits on one [`Notify`] woken by
//! whatever can free a tile (a submission, a failed or released tile, an expired lease,
//! shutdown), the watch long poll follows the event channel for revocations (a job cancelled or
//! failed), and the lease-expiry task sweeps dead leases twice a second. The HTTP handlers
//! (`api::worker`) only translate requests and outcomes.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use anyhow::Result;
use tessera::protocol::{JobState, Lease, ServerEvent};
use tokio::sync::{Notify, broadcast};

use crate::db::{FailOutcome, Leased, ResultOutcome, Store, WorkerRow};

// ---------------------------------------------------------------------------------------------
// The rules
// ---------------------------------------------------------------------------------------------

/// How often the lease-expiry task looks for leases past their deadline.
pub const EXPIRY_SWEEP: Duration = Duration::from_millis(500);
/// Most leases one watch request follows.
const MAX_WATCHED_LEASES: usize = 64;

/// Runs store work on the blocking pool, so that the async threads keep answering while a
/// transaction waits for the store's mutex or the disk.
async fn blocking<T: Send + 'static>(f: impl FnOnce() -> Result<T> + Send + 'static) -> Result<T> {
    tokio::task::spawn_blocking(f).await.map_err(|e| anyhow::anyhow!("a store task failed: {e}"))?
}

/// What a registered worker is doing, as the workers list and `/metrics` show it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum WorkerState {
    Idle,
    Rendering,
    /// Silent for longer than [`lost_after`].
    Lost,
}

impl WorkerState {
    pub const ALL: [WorkerState; 3] = [WorkerState::Idle, WorkerState::Rendering, WorkerState::Lost];

    pub fn as_str(self) -> &'static str {
        match self {
            WorkerState::Idle => "idle",
            WorkerState::Rendering => "rendering",
            WorkerState::Lost => "lost",
        }
    }
}

/// Seconds of silence after which a worker counts as lost: three missed heartbeats and two
/// seconds of slack.
pub fn lost_after(heartbeat_seconds: f64) -> f64 {
    3.0 * heartbeat_seconds + 2.0
}

/// The worker-lost rule: a worker not seen for [`lost_after`] is lost, else it is rendering
/// while it holds a tile, else idle.
pub fn worker_state(w: &WorkerRow, now: f64, heartbeat_seconds: f64) -> WorkerState {
    if now - w.last_seen > lost_after(heartbeat_seconds) {
        WorkerState::Lost
    } else if w.rendering.is_some() {
        WorkerState::Rendering
    } else {
        WorkerState::Idle
    }
}

/// Why a job that asks for `job_tags` cannot get a tile now, given the `live` workers (seen
/// within the lost limit) and the tags of those of them that take new work (`serving`: active,
/// neither draining nor disabled); `None` when one of them can take it. A sentence that says
/// what to do.
pub fn waiting_for(job_tags: &[String], live: usize, serving: &[crate::db::ServingWorker]) -> Option<String> {
    let start = "tessera-worker work --server URL --token TOKEN";
    let token = "(on the server's machine `tessera-server worker-token` prints the token)";
    if live == 0 {
        let with =
            if job_tags.is_empty() { String::new() } else { format!(" --tags {}", job_tags.join(",")) };
        return Some(format!("no worker is connected to this farm; start one with: {start}{with} {token}"));
    }
    if serving.is_empty() {
        return Some(format!(
            "every connected worker ({live}) is draining or disabled; enable one with `tessera worker enable ID` \
             (`tessera workers` lists them), or start another with: {start}"
        ));
    }
    if serving.iter().any(|w| job_tags.iter().all(|t| w.tags.contains(t))) {
        return None;
    }
    Some(format!(
        "no active worker has the tag(s) {} this job asks for (worker_tags); start one with: {start} --tags {} {token}",
        job_tags.join(", "),
        job_tags.join(",")
    ))
}

// ---------------------------------------------------------------------------------------------
// The scheduler
// ---------------------------------------------------------------------------------------------

/// The farm's clock settings.
#[derive(Clone, Copy, Debug)]
pub struct Timing {
    /// A lease lives this long without a heartbeat.
    pub lease_seconds: f64,
    /// How often workers send heartbeats (told at registration).
    pub heartbeat_seconds: f64,
    /// Longest a long poll (lease, watch) is held open.
    pub max_wait_seconds: f64,
    /// Longest one tile may render (sent with every lease).
    pub max_tile_seconds: f64,
}

/// Counters that are not in the database.
#[derive(Default, Debug)]
pub struct Counters {
    pub lease_expiries: AtomicU64,
    pub results_refused: AtomicU64,
}

/// What a lease request got.
#[derive(Debug)]
pub enum LeaseWait {
    Granted(Lease),
    /// Nothing became free within the wait.
    NoWork,
    /// The server is stopping: no more leases.
    ShuttingDown,
    /// The worker already holds as many live leases as its threads allow (plus two).
    Full {
        held: u32,
        allowed: u32,
    },
}

/// The scheduling side of the farm: the store's leasing, failure and expiry operations with the
/// wake-ups, events and counters that go with them. Cheap to clone (shared parts).
#[derive(Clone)]
pub struct Scheduler {
    store: Arc<Store>,
    timing: Timing,
    /// Woken when tiles may have become available (a job submitted, a tile failed or given
    /// back, a lease expired) and at shutdown.
    work: Arc<Notify>,
    events: broadcast::Sender<ServerEvent>,
    /// Set when the server begins to shut down: no more leases, and long polls answer at once
    /// (so stopping workers are not held up by a poll that could only bring a lease to give
    /// back).
    shutting_down: Arc<AtomicBool>,
    counters: Arc<Counters>,
}

impl Scheduler {
    pub fn new(store: Arc<Store>, timing: Timing, events: broadcast::Sender<ServerEvent>) -> Scheduler {
        Scheduler {
            store,
            timing,
            work: Arc::new(Notify::new()),
            events,
            shutting_down: Arc::default(),
            counters: Arc::default(),
        }
    }

    pub fn timing(&self) -> &Timing {
        &self.timing
    }

    pub fn counters(&self) -> &Counters {
        &self.counters
    }

    fn emit(&self, e: ServerEvent) {
        let _ = self.events.send(e);
    }

    /// Wakes every waiting lease request to look again.
    fn wake(&self) {
        self.work.notify_waiters();
    }

    /// A job was stored: its tiles are free.
    pub fn job_submitted(&self, job: u64) {
        self.wake();
        self.emit(ServerEvent::Job { job, state: JobState::Queued });
    }

    /// Cancels a job that has not ended, revoking its leases (watches of them answer at once);
    /// false when it had ended or does not exist.
    pub fn cancel(&self, job: u64) -> Result<bool> {
        if !self.store.cancel_job(job)? {
            return Ok(false);
        }
        tracing::info!(job, "job canceled");
        self.emit(ServerEvent::Job { job, state: JobState::Canceled });
        Ok(true)
    }

    /// A job's state or priority changed (paused, resumed, requeued, its priority set): the page
    /// hears of it, and the lease polls look again (a resumed or requeued job's tiles are free,
    /// a new priority orders the next lease).
    pub fn job_changed(&self, job: u64, state: JobState) {
        self.wake();
        self.emit(ServerEvent::Job { job, state });
    }

    /// The long poll for a lease: the next tile by priority as soon as one is free for
    /// `worker`, waiting at most `wait_seconds` (capped by [`Timing::max_wait_seconds`]).
    pub async fn lease(&self, worker: u64, wait_seconds: f64) -> Result<LeaseWait> {
        let wait = wait_seconds.clamp(0.0, self.timing.max_wait_seconds);
        let deadline = tokio::time::Instant::now() + Duration::from_secs_f64(wait);
        loop {
            // Register interest before looking, so a notification between the look and the
            // wait is not lost.
            let notified = self.work.notified();
            if self.is_shutting_down() {
                return Ok(LeaseWait::ShuttingDown);
            }
            let (store, lease_seconds) = (self.store.clone(), self.timing.lease_seconds);
            let leased = blocking(move || {
                // A draining or disabled worker takes nothing new; its poll waits like an idle one.
                if store.worker_mode(worker)? != crate::db::WorkerMode::Active {
                    return Ok(Leased::NoWork);
                }
                store.lease(worker, lease_seconds)
            });
            match leased.await? {
                Leased::Granted(mut lease) => {
                    lease.max_render_seconds = Some(self.timing.max_tile_seconds);
                    self.emit(ServerEvent::Job { job: lease.job_id, state: JobState::Running });
                    self.emit(ServerEvent::Workers);
                    return Ok(LeaseWait::Granted(lease));
                }
                Leased::Full { held, allowed } => return Ok(LeaseWait::Full { held, allowed }),
                Leased::NoWork => {}
            }
            if tokio::time::timeout_at(deadline, notified).await.is_err() {
                return Ok(LeaseWait::NoWork);
            }
        }
    }

    /// Sets whether `worker` takes new work; `None` when there is no such worker, else how many
    /// of its tiles went back to the queue (disabling). Wakes the lease polls: a worker made
    /// active again gets work at once, and tiles a disabled one held go to others.
    pub fn set_worker_mode(&self, worker: u64, mode: crate::db::WorkerMode) -> Result<Option<usize>> {
        let changed = self.store.set_worker_mode(worker, mode)?;
        if changed.is_some() {
            tracing::info!(worker, mode = mode.as_str(), "worker mode changed");
            self.emit(ServerEvent::Workers);
            self.wake();
        }
        Ok(changed)
    }

    /// Renews `worker`'s live leases among `leases`; returns those it no longer owns.
    pub fn heartbeat(&self, worker: u64, leases: &[u64], rendering: Option<u64>) -> Result<Vec<u64>> {
        self.store.heartbeat(worker, leases, rendering, self.timing.lease_seconds)
    }

    /// The long poll on leases being rendered: answers as soon as one of `leases` (the first
    /// [`MAX_WATCHED_LEASES`]) is no longer `worker`'s (its job was cancelled or failed), else
    /// after the wait with nothing revoked. Reads only; heartbeats still renew the leases.
    pub async fn watch(&self, worker: u64, leases: Vec<u64>, wait_seconds: f64) -> Result<Vec<u64>> {
        let wait = wait_seconds.clamp(0.0, self.timing.max_wait_seconds);
        let deadline = tokio::time::Instant::now() + Duration::from_secs_f64(wait);
        let leases: Vec<u64> = leases.into_iter().take(MAX_WATCHED_LEASES).collect();
        // Subscribe before looking, so a cancel between the look and the wait is not lost.
        let mut events = self.events.subscribe();
        let leases = Arc::new(leases);
        loop {
            let (store, listed) = (self.store.clone(), leases.clone());
            let revoked = blocking(move || store.revoked_among(worker, &listed)).await?;
            if !revoked.is_empty() || self.is_shutting_down() {
                return Ok(revoked);
            }
            loop {
                match tokio::time::timeout_at(deadline, events.recv()).await {
                    Err(_) => return Ok(Vec::new()),
                    Ok(Ok(ServerEvent::Job { state: JobState::Canceled | JobState::Failed, .. })) => break,
                    // Missed events: look again.
                    Ok(Err(broadcast::error::RecvError::Lagged(_))) => break,
                    Ok(Err(broadcast::error::RecvError::Closed)) => return Ok(Vec::new()),
                    Ok(Ok(_)) => {}
                }
            }
        }
    }

    /// Stores a tile's pixels for a live lease of `worker`, once: a second result, or one for a
    /// lease that expired or was revoked, is a [`ResultOutcome::Conflict`] (and counted).
    pub fn result(
        &self,
        lease: u64,
        worker: u64,
        pixels: crate::db::ResultBody<'_>,
        render_seconds: Option<f64>,
    ) -> Result<ResultOutcome> {
        let outcome = self.store.submit_result_as(lease, worker, pixels, render_seconds)?;
        match &outcome {
            ResultOutcome::Accepted { job_id, frame, tile, rect, tiles_done, tiles_total, .. } => {
                self.emit(ServerEvent::Tile {
                    job: *job_id,
                    frame: *frame,
                    tile: *tile,
                    rect: *rect,
                    tiles_done: *tiles_done,
                    tiles_total: *tiles_total,
                });
                self.emit(ServerEvent::Workers);
            }
            ResultOutcome::Conflict => {
                self.counters.results_refused.fetch_add(1, Ordering::Relaxed);
            }
            ResultOutcome::WrongSize { .. } => {}
        }
        Ok(outcome)
    }

    /// `worker` could not render the tile of `lease`: the failure rule
    /// ([`crate::failures::tile_verdict`]) queues it again, waking the lease requests, or fails
    /// its job.
    pub fn fail(&self, lease: u64, worker: u64, error: &str, fatal: bool) -> Result<FailOutcome> {
        let outcome = self.store.fail_tile(lease, worker, error, fatal)?;
        match &outcome {
            FailOutcome::Requeued => {
                tracing::warn!(lease, worker, error = %error, "tile failed; queued again");
                self.wake();
            }
            FailOutcome::JobFailed { job, message } => {
                tracing::error!(lease, job, "job failed: {message}");
                self.emit(ServerEvent::Job { job: *job, state: JobState::Failed });
            }
            FailOutcome::Conflict => {}
        }
        Ok(outcome)
    }

    /// A stopping worker gives back a live lease it has not started: the tile is queued again
    /// at once. False when it is not a live lease of `worker`.
    pub fn release(&self, lease: u64, worker: u64) -> Result<bool> {
        if !self.store.release_lease(lease, worker)? {
            return Ok(false);
        }
        tracing::info!(lease, worker, "lease given back; its tile is queued again");
        self.emit(ServerEvent::Workers);
        self.wake();
        Ok(true)
    }

    /// One sweep of the lease-expiry task: every lease past its deadline is a failure of its
    /// tile (its worker stopped answering), which goes back to the queue or fails its job.
    /// Returns how many leases expired.
    pub fn expire_leases(&self) -> Result<usize> {
        let e = self.store.expire_leases()?;
        Ok(self.expired(e))
    }

    /// What follows leases expired (by the sweep, or by a local worker registering again): the
    /// counter, a failed job's event, and the lease polls woken for the tiles queued again.
    fn expired(&self, e: crate::db::Expired) -> usize {
        if e.leases == 0 {
            return 0;
        }
        tracing::warn!(
            "{} lease(s) expired (their workers stopped answering); the tiles count a failure each and are queued again",
            e.leases
        );
        self.counters.lease_expiries.fetch_add(e.leases as u64, Ordering::Relaxed);
        for (job, message) in e.failed_jobs {
            tracing::error!(job, "job failed: {message}");
            self.emit(ServerEvent::Job { job, state: JobState::Failed });
        }
        self.wake();
        e.leases
    }

    /// Registers one of the server's own local workers on the row of its earlier lives
    /// ([`Store::register_local_worker`]): the leases its dead process held expire first, with
    /// the sweep's accounting.
    pub fn register_local_worker(&self, w: &crate::db::NewWorker<'_>) -> Result<u64> {
        let (id, expired) = self.store.register_local_worker(w)?;
        if expired.leases > 0 {
            tracing::info!(worker = id, name = w.name, "the local worker's earlier process held leases");
        }
        self.expired(expired);
        Ok(id)
    }

    /// Starts the lease-expiry task: [`Scheduler::expire_leases`] every [`EXPIRY_SWEEP`].
    pub fn spawn_expiry(&self) -> tokio::task::JoinHandle<()> {
        let scheduler = self.clone();
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(EXPIRY_SWEEP);
            loop {
                tick.tick().await;
                let sweep = scheduler.clone();
                if let Err(e) = blocking(move || sweep.expire_leases()).await {
                    tracing::error!("lease expiry: {e:#}");
                }
            }
        })
    }

    /// The server begins to stop: no more leases, and waiting lease requests answer now.
    pub fn begin_shutdown(&self) {
        self.shutting_down.store(true, Ordering::SeqCst);
        self.wake();
    }

    pub fn is_shutting_down(&self) -> bool {
        self.shutting_down.load(Ordering::SeqCst)
    }

    /// [`waiting_for`] for a job asking for `job_tags`, with the workers as the store has them
    /// now.
    pub fn waiting_for(&self, job_tags: &[String]) -> Result<Option<String>> {
        let since = crate::db::now() - lost_after(self.timing.heartbeat_seconds);
        let (live, serving) = self.store.serving_workers(since)?;
        Ok(waiting_for(job_tags, live, &serving))
    }

    /// [`worker_state`] with this farm's heartbeat interval.
    pub fn worker_state(&self, w: &WorkerRow, now: f64) -> WorkerState {
        worker_state(w, now, self.timing.heartbeat_seconds)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_worker_silent_for_three_heartbeats_and_two_seconds_is_lost() {
        let w = |last_seen, rendering| WorkerRow {
            id: 1,
            name: "w".into(),
            threads: 1,
            registered_at: 0.0,
            last_seen,
            tiles_done: 0,
            failures: 0,
            rendering,
            current_tile: None,
            mode: crate::db::WorkerMode::Active,
            tags: Vec::new(),
        };
        // Heartbeats every 5 s: lost after 17 s of silence, whatever it was doing.
        assert_eq!(lost_after(5.0), 17.0);
        assert_eq!(worker_state(&w(100.0, None), 116.9, 5.0), WorkerState::Idle);
        assert_eq!(worker_state(&w(100.0, Some(4)), 116.9, 5.0), WorkerState::Rendering);
        assert_eq!(worker_state(&w(100.0, Some(4)), 117.1, 5.0), WorkerState::Lost);
        assert_eq!(worker_state(&w(100.0, None), 117.1, 5.0), WorkerState::Lost);
    }

    #[test]
    fn a_job_nobody_can_serve_says_why_and_what_to_do() {
        let w =
            |tags: &[&str]| crate::db::ServingWorker { tags: tags.iter().map(|t| t.to_string()).collect() };
        let gpu = vec!["gpu".to_string()];
        let none = waiting_for(&[], 0, &[]).unwrap();
        assert!(
            none.starts_with("no worker is connected") && none.contains("tessera-worker work --server URL"),
            "{none}"
        );
        assert!(waiting_for(&gpu, 0, &[]).unwrap().contains("--tags gpu"));
        let idle = waiting_for(&[], 2, &[]).unwrap();
        assert!(idle.contains("every connected worker (2) is draining or disabled"), "{idle}");
        assert_eq!(waiting_for(&[], 1, &[w(&[])]), None);
        assert_eq!(waiting_for(&gpu, 2, &[w(&[]), w(&["big", "gpu"])]), None);
        let tags = vec!["big".to_string(), "gpu".to_string()];
        let lacking = waiting_for(&tags, 2, &[w(&["gpu"]), w(&["big"])]).unwrap();
        assert!(
            lacking.contains("no active worker has the tag(s) big, gpu")
                && lacking.contains("--tags big,gpu"),
            "{lacking}"
        );
    }
}
