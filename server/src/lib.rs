//! `tessera-server`: the farm's HTTP server.
//!
//! - [`api`]: the routes (job API, worker protocol, health, metrics) over an [`api::AppState`].
//! - [`db`]: the SQLite job store, the single source of truth (jobs, frames, tiles with their
//!   pixels, leases, workers); a restart loses nothing that was acknowledged.
//! - [`bundle`]: uploads into content-addressed tar bundles.
//! - [`merge`]: tiles into frames, frames into `.exr` and tone-mapped `.png` files, once.
//! - [`serve`]: binds, starts the background tasks (lease expiry, merges left over from a crash)
//!   and the local worker processes, and shuts down on Ctrl-C or SIGTERM.

pub mod api;
pub mod bundle;
pub mod db;
pub mod merge;
pub mod scheduler;
pub mod web;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use tokio::process::Command;

/// Uploads unpacked and validated at the same time. Each holds at most `--max-unpacked-mb` of
/// files plus the canonical tar of them and the decoded scene; the rest wait their turn.
pub const UNPACKING_AT_ONCE: usize = 2;

/// Everything `tessera-server` can be told (flags and environment).
#[derive(Clone, Debug)]
pub struct Config {
    pub bind: SocketAddr,
    pub data_dir: PathBuf,
    pub local_workers: usize,
    /// Threads per local worker (`None`: every core).
    pub local_worker_threads: Option<usize>,
    pub worker_bin: Option<PathBuf>,
    pub tile_size: u32,
    pub api_token: Option<String>,
    pub worker_token: Option<String>,
    pub insecure: bool,
    pub lease_seconds: f64,
    pub heartbeat_seconds: f64,
    pub max_upload_mb: usize,
    /// Caps on what one upload unpacks to (total, per file, file count).
    pub max_unpacked_mb: u64,
    pub max_file_mb: u64,
    pub max_bundle_files: usize,
    /// Most tiles one job may be cut into.
    pub max_job_tiles: u64,
    /// Longest one tile may render before its worker gives up and fails it.
    pub max_tile_seconds: f64,
    /// Most samples (pixels x samples per pixel, over every frame) one job may ask for.
    pub max_job_samples: u64,
}

/// A random token from the operating system's generator (for local workers when none is set).
fn random_token() -> String {
    use std::io::Read;
    let mut bytes = [0u8; 24];
    if let Ok(mut f) = std::fs::File::open("/dev/urandom") {
        let _ = f.read_exact(&mut bytes);
    }
    if bytes == [0u8; 24] {
        // No /dev/urandom: mix the clock and the process id (still unguessable enough for a
        // loopback-only default, and never used when the operator sets a token).
        let seed = format!("{:?}{}", std::time::SystemTime::now(), std::process::id());
        let h = bundle::sha256_hex(seed.as_bytes());
        return h[..48].to_string();
    }
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Checks the configuration before anything starts.
pub fn check_config(config: &Config) -> Result<()> {
    if !config.bind.ip().is_loopback() && config.api_token.is_none() && !config.insecure {
        bail!(
            "refusing to listen on {} without an API token: anyone who can reach it could run jobs on this machine. \
             Set --api-token (or TESSERA_API_TOKEN), or pass --insecure if this network is trusted",
            config.bind
        );
    }
    if !config.bind.ip().is_loopback()
        && config.worker_token.is_none()
        && config.local_workers == 0
        && !config.insecure
    {
        bail!(
            "listening on {} for remote workers needs --worker-token (or TESSERA_WORKER_TOKEN) so that they can authenticate",
            config.bind
        );
    }
    if config.max_unpacked_mb == 0 || config.max_file_mb == 0 || config.max_bundle_files == 0 {
        bail!("--max-unpacked-mb, --max-file-mb and --max-bundle-files must be at least 1");
    }
    if config.max_unpacked_mb > (1 << 20) || config.max_file_mb > (1 << 20) {
        bail!("--max-unpacked-mb and --max-file-mb must be at most 1048576 (1 TiB)");
    }
    if config.max_job_tiles == 0 {
        bail!("--max-job-tiles must be at least 1");
    }
    if config.tile_size == 0 || config.tile_size > 4096 {
        bail!("--tile-size must be between 1 and 4096 pixels, found {}", config.tile_size);
    }
    if config.lease_seconds <= 0.0
        || config.heartbeat_seconds <= 0.0
        || config.heartbeat_seconds >= config.lease_seconds
    {
        bail!(
            "--heartbeat-seconds ({}) must be positive and shorter than --lease-seconds ({})",
            config.heartbeat_seconds,
            config.lease_seconds
        );
    }
    if !(config.max_tile_seconds > 0.0 && config.max_tile_seconds.is_finite()) {
        bail!("--max-tile-seconds must be a positive number of seconds, found {}", config.max_tile_seconds);
    }
    if config.max_job_samples == 0 {
        bail!("--max-job-samples must be at least 1");
    }
    Ok(())
}

/// The `tessera-worker` binary the local workers run: `--worker-bin`, else next to this
/// executable.
fn worker_binary(config: &Config) -> Result<PathBuf> {
    if let Some(p) = &config.worker_bin {
        return Ok(p.clone());
    }
    let exe = std::env::current_exe().context("cannot find this executable's path")?;
    let name = if cfg!(windows) { "tessera-worker.exe" } else { "tessera-worker" };
    let candidate = exe.parent().map(|d| d.join(name)).unwrap_or_else(|| PathBuf::from(name));
    if candidate.exists() {
        Ok(candidate)
    } else {
        bail!(
            "cannot find {} for the local workers; build it (cargo build --release builds both binaries), pass --worker-bin, or start with --local-workers 0",
            candidate.display()
        )
    }
}

/// Runs the server until Ctrl-C or SIGTERM. `on_listening` gets the bound address (port 0
/// picks a free one).
pub async fn serve(config: Config, on_listening: impl FnOnce(SocketAddr)) -> Result<()> {
    check_config(&config)?;
    std::fs::create_dir_all(&config.data_dir)
        .with_context(|| format!("cannot create the data directory {}", config.data_dir.display()))?;
    let store = Arc::new(db::Store::open(&config.data_dir.join("tessera.db"))?);
    let blobs = bundle::BlobStore::new(&config.data_dir)?;
    // Uploads spooled by requests that were cut off by a crash.
    let _ = std::fs::remove_dir_all(config.data_dir.join("uploads"));
    let worker_token = config.worker_token.clone().unwrap_or_else(random_token);
    let settings = api::Settings {
        data_dir: config.data_dir.clone(),
        tile_size: config.tile_size,
        api_token: config.api_token.clone(),
        worker_token: worker_token.clone(),
        max_upload_bytes: config.max_upload_mb << 20,
        bundle_limits: bundle::Limits {
            max_unpacked_bytes: config.max_unpacked_mb << 20,
            max_files: config.max_bundle_files,
            max_file_bytes: config.max_file_mb << 20,
        },
        max_job_samples: config.max_job_samples,
        max_job_tiles: config.max_job_tiles,
    };
    let timing = scheduler::Timing {
        lease_seconds: config.lease_seconds,
        heartbeat_seconds: config.heartbeat_seconds,
        max_wait_seconds: 20.0,
        max_tile_seconds: config.max_tile_seconds,
    };
    let state = api::AppState::new(store.clone(), blobs, settings, timing);

    let listener = tokio::net::TcpListener::bind(config.bind)
        .await
        .with_context(|| format!("cannot listen on {}", config.bind))?;
    let addr = listener.local_addr()?;
    tracing::info!("listening on http://{addr}, data in {}", config.data_dir.display());
    on_listening(addr);

    // Frames whose last tile arrived just before a crash.
    for f in store.frames_awaiting_merge()? {
        tracing::info!(job = f.job_id, frame = f.index, "merging a frame left from before the restart");
        tokio::spawn(merge::merge_frame(state.clone(), f.job_id, f.index));
    }

    // Lease expiry: tiles of silent workers go back to the queue.
    state.scheduler.spawn_expiry();

    // Local workers: real processes over real HTTP, restarted if they die, stopped gracefully.
    let (stopping_tx, stopping_rx) = tokio::sync::watch::channel(Stopping::No);
    let mut supervisors = Vec::new();
    if config.local_workers > 0 {
        let bin = worker_binary(&config)?;
        let url = format!(
            "http://{}",
            if addr.ip().is_unspecified() { SocketAddr::from(([127, 0, 0, 1], addr.port())) } else { addr }
        );
        for k in 0..config.local_workers {
            let local = LocalWorker {
                k: k + 1,
                bin: bin.clone(),
                url: url.clone(),
                token: worker_token.clone(),
                threads: config.local_worker_threads,
            };
            supervisors.push(tokio::spawn(supervise_worker(local, stopping_rx.clone())));
        }
    }

    let (stop_tx, mut stop_rx) = tokio::sync::watch::channel(false);
    let app = api::app(state.clone());
    let shutdown = async move {
        let mut signals = Signals::new();
        signals.next().await;
        tracing::info!("shutting down");
        // Stop the local workers first, while the server still takes their last results and
        // the leases they give back; a second signal stops them at once. Then end the long
        // polls, which can no longer bring anything but a lease to give back.
        let _ = stopping_tx.send(Stopping::Gracefully);
        state.scheduler.begin_shutdown();
        let all_stopped = futures_util::future::join_all(supervisors);
        tokio::pin!(all_stopped);
        tokio::select! {
            _ = &mut all_stopped => {}
            _ = signals.next() => {
                tracing::warn!("second signal: stopping the local workers now");
                let _ = stopping_tx.send(Stopping::Now);
                all_stopped.await;
            }
        }
        let _ = stop_tx.send(true);
    };
    let server = axum::serve(listener, app).with_graceful_shutdown(shutdown);
    // In-flight requests (long polls of remote workers) get a few seconds to finish.
    let server = std::pin::pin!(server.into_future());
    tokio::select! {
        r = server => r?,
        _ = async {
            let _ = stop_rx.wait_for(|s| *s).await;
            tokio::time::sleep(Duration::from_secs(3)).await;
        } => tracing::info!("stopped with requests still open"),
    }
    Ok(())
}

/// How long a local worker may take to stop after SIGTERM (it finishes and uploads the tile it
/// is rendering, and gives back the one it fetched ahead) before it is killed.
pub const LOCAL_WORKER_GRACE: Duration = Duration::from_secs(10);

/// What the local workers' supervisors are told.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stopping {
    No,
    /// SIGTERM, then up to [`LOCAL_WORKER_GRACE`] to finish.
    Gracefully,
    /// SIGKILL.
    Now,
}

/// Ctrl-C and SIGTERM, as one stream.
struct Signals {
    #[cfg(unix)]
    term: tokio::signal::unix::Signal,
}

impl Signals {
    fn new() -> Signals {
        Signals {
            #[cfg(unix)]
            term: tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
                .expect("SIGTERM handler"),
        }
    }

    async fn next(&mut self) {
        #[cfg(unix)]
        tokio::select! { _ = tokio::signal::ctrl_c() => {}, _ = self.term.recv() => {} }
        #[cfg(not(unix))]
        let _ = tokio::signal::ctrl_c().await;
    }
}

/// A local worker that ran this long before exiting was not crash-looping.
const LOCAL_WORKER_STEADY: Duration = Duration::from_secs(60);

/// The wait before restarting a local worker after `crashes` short runs in a row: 1 s, then
/// doubling, at most 60 s.
fn restart_delay(crashes: u32) -> Duration {
    Duration::from_secs(1u64 << crashes.saturating_sub(1).min(6)).min(Duration::from_secs(60))
}

/// How to start local worker `k`.
struct LocalWorker {
    k: usize,
    bin: PathBuf,
    url: String,
    token: String,
    threads: Option<usize>,
}

/// Keeps a local worker running until the server stops, then stops it: SIGTERM and a grace
/// period, SIGKILL after that or on [`Stopping::Now`].
async fn supervise_worker(w: LocalWorker, mut stopping: tokio::sync::watch::Receiver<Stopping>) {
    let k = w.k;
    // Restarts that follow a short run back off: a worker that keeps crashing (a scene that
    // kills it, a broken binary) is restarted after 1, 2, 4, ... up to 60 s, not every second.
    let mut crashes_in_a_row = 0u32;
    loop {
        let started = tokio::time::Instant::now();
        let mut cmd = Command::new(&w.bin);
        cmd.arg("work")
            .arg("--server")
            .arg(&w.url)
            .arg("--name")
            .arg(format!("local-{k}"))
            .arg("--exit-with-parent");
        if let Some(t) = w.threads {
            cmd.arg("--threads").arg(t.to_string());
        }
        // A process group of its own: a Ctrl-C in the terminal reaches the server only, which
        // then stops its workers once and in order (a worker given two signals exits at once).
        #[cfg(unix)]
        cmd.process_group(0);
        cmd.env("TESSERA_WORKER_TOKEN", &w.token).kill_on_drop(true);
        let mut child = match cmd.spawn() {
            Ok(child) => child,
            Err(e) => {
                tracing::error!(worker = k, "cannot start {}: {e}", w.bin.display());
                tokio::select! {
                    _ = tokio::time::sleep(Duration::from_secs(1)) => continue,
                    _ = stopping.wait_for(|s| *s != Stopping::No) => return,
                }
            }
        };
        tracing::info!(worker = k, pid = child.id(), "local worker started");
        let stop = tokio::select! {
            status = child.wait() => {
                if let Err(e) = status {
                    tracing::error!(worker = k, "local worker: {e}");
                }
                false
            }
            _ = stopping.wait_for(|s| *s != Stopping::No) => true,
        };
        if stop {
            stop_worker(k, &mut child, &mut stopping).await;
            return;
        }
        let ran = started.elapsed();
        crashes_in_a_row = if ran < LOCAL_WORKER_STEADY { crashes_in_a_row + 1 } else { 1 };
        let delay = restart_delay(crashes_in_a_row);
        tracing::warn!(
            worker = k,
            "local worker exited after {:.1} s ({crashes_in_a_row} short run(s) in a row); restarting it in {} s",
            ran.as_secs_f64(),
            delay.as_secs()
        );
        tokio::select! {
            _ = tokio::time::sleep(delay) => {}
            _ = stopping.wait_for(|s| *s != Stopping::No) => return,
        }
    }
}

async fn stop_worker(
    k: usize,
    child: &mut tokio::process::Child,
    stopping: &mut tokio::sync::watch::Receiver<Stopping>,
) {
    if *stopping.borrow() == Stopping::Gracefully {
        #[cfg(unix)]
        if let Some(pid) = child.id() {
            // SAFETY: kill(2) has no memory effects; `pid` is our own child, not yet reaped.
            unsafe {
                libc::kill(pid as libc::pid_t, libc::SIGTERM);
            }
        }
        tokio::select! {
            status = child.wait() => {
                match status {
                    Ok(status) => tracing::info!(worker = k, %status, "local worker stopped"),
                    Err(e) => tracing::error!(worker = k, "local worker: {e}"),
                }
                return;
            }
            _ = tokio::time::sleep(LOCAL_WORKER_GRACE) => {
                tracing::warn!(worker = k, "local worker still busy {} s after SIGTERM; killing it", LOCAL_WORKER_GRACE.as_secs());
            }
            _ = stopping.wait_for(|s| *s == Stopping::Now) => {}
        }
    }
    let _ = child.kill().await;
    tracing::warn!(worker = k, "local worker killed; its tiles are queued again");
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn restarts_back_off_doubling_up_to_a_minute() {
        let secs: Vec<u64> = (1..=9).map(|n| restart_delay(n).as_secs()).collect();
        assert_eq!(secs, [1, 2, 4, 8, 16, 32, 60, 60, 60]);
        assert_eq!(restart_delay(u32::MAX).as_secs(), 60);
    }
}
