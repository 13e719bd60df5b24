//! The local worker processes: `tessera-worker work` children of the server over real HTTP,
//! restarted with a doubling back-off while they keep dying young, stopped with SIGTERM and a
//! grace period (SIGKILL after it, or at once when hurried).

use std::future::Future;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use tokio::process::Command;
use tokio::sync::watch;

use crate::Config;

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

/// The supervised local workers of a server.
pub(crate) struct LocalWorkers {
    stopping: watch::Sender<Stopping>,
    supervisors: Vec<tokio::task::JoinHandle<()>>,
}

impl LocalWorkers {
    /// Starts `config.local_workers` workers (maybe none) against the server listening at
    /// `addr`, each with the worker token `token`.
    pub(crate) fn start(config: &Config, addr: SocketAddr, token: &str) -> Result<LocalWorkers> {
        let (stopping, stopping_rx) = watch::channel(Stopping::No);
        let mut supervisors = Vec::new();
        if config.local_workers > 0 {
            let bin = worker_binary(config)?;
            let url = format!(
                "http://{}",
                if addr.ip().is_unspecified() {
                    SocketAddr::from(([127, 0, 0, 1], addr.port()))
                } else {
                    addr
                }
            );
            for k in 0..config.local_workers {
                let local = LocalWorker {
                    k: k + 1,
                    bin: bin.clone(),
                    url: url.clone(),
                    token: token.to_string(),
                    threads: config.local_worker_threads,
                    cache_dir: config.data_dir.join("worker-cache"),
                };
                supervisors.push(tokio::spawn(supervise_worker(local, stopping_rx.clone())));
            }
        }
        Ok(LocalWorkers { stopping, supervisors })
    }

    /// SIGTERM to each worker: it finishes and uploads its tile, gives back the one it fetched
    /// ahead, and exits.
    pub(crate) fn stop_gracefully(&self) {
        let _ = self.stopping.send(Stopping::Gracefully);
    }

    /// Waits until every worker has exited (each is killed [`LOCAL_WORKER_GRACE`] after its
    /// SIGTERM); when `hurry` resolves first, the rest are killed at once.
    pub(crate) async fn stopped(self, hurry: impl Future<Output = ()>) {
        let all_stopped = futures_util::future::join_all(self.supervisors);
        tokio::pin!(all_stopped);
        tokio::select! {
            _ = &mut all_stopped => {}
            _ = hurry => {
                tracing::warn!("second signal: stopping the local workers now");
                let _ = self.stopping.send(Stopping::Now);
                all_stopped.await;
            }
        }
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
    /// The job files' cache on disk, shared by the local workers (`DATA/worker-cache`).
    cache_dir: std::path::PathBuf,
    bin: PathBuf,
    url: String,
    token: String,
    threads: Option<usize>,
}

/// Keeps a local worker running until the server stops, then stops it: SIGTERM and a grace
/// period, SIGKILL after that or on [`Stopping::Now`].
async fn supervise_worker(w: LocalWorker, mut stopping: watch::Receiver<Stopping>) {
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
            .arg("--cache-dir")
            .arg(&w.cache_dir)
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

async fn stop_worker(k: usize, child: &mut tokio::process::Child, stopping: &mut watch::Receiver<Stopping>) {
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
