//! `tessera-server`: the farm's HTTP server.
//!
//! - [`api`]: the routes (job API, worker protocol, health, metrics) over a [`state::AppState`].
//! - [`state`]: what the handlers and the merges share (settings, store, blobs, scheduler,
//!   cached cameras, events).
//! - [`scheduler`]: the scheduling rules (priority, long polls and their wake-ups, failures and
//!   bans, lease expiry, revocation, lost workers) between the handlers and the store.
//! - [`failures`]: the failure rules the store applies in its transactions (re-exported by
//!   `scheduler`).
//! - [`db`]: the SQLite job store, the single source of truth (jobs, frames, tiles with their
//!   pixels, leases, workers); a restart loses nothing that was acknowledged.
//! - [`bundle`]: uploads into content-addressed tar bundles (jobs stored before the file store).
//! - [`files`]: the file store, every job file once by SHA-256.
//! - [`merge`]: tiles into frames, frames into `.exr` and tone-mapped `.png` files, once.
//! - [`video`]: a job's frames into one MP4 (ffmpeg) or GIF once they are all merged.
//! - [`web`]: the status page.
//! - [`serve`]: binds, starts the background tasks (lease expiry, merges left over from a crash)
//!   and the local worker processes (`local_workers`), and stops when its shutdown stream says
//!   so (the binary's: Ctrl-C or SIGTERM).

pub mod api;
pub mod bundle;
pub mod connections;
pub mod db;
pub mod failures;
pub mod files;
pub mod housekeeping;
mod local_workers;
pub mod merge;
pub mod notify;
pub mod registrations;
pub mod retention;
pub mod scheduler;
pub mod state;
pub mod storage;
pub mod video;
pub mod web;

#[cfg(test)]
mod testutil;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use futures_util::{Stream, StreamExt};

pub use local_workers::LOCAL_WORKER_GRACE;

/// Uploads unpacked and validated at the same time. Each holds at most `--max-unpacked-mb` of
/// files plus the canonical tar of them and the decoded scene; the rest wait their turn.
pub const UNPACKING_AT_ONCE: usize = 2;

/// Previews (at most [`merge::PREVIEW_MAX_SIDE`] pixels a side, plus one tile's pixels being
/// read) and re-tone-mappings of a stored frame made at the same time; the rest wait their turn.
pub const PREVIEWS_AT_ONCE: usize = 2;

/// Frames merged at the same time: a merge holds its whole float frame.
pub const MERGES_AT_ONCE: usize = 1;

/// The longest `--forget-workers-after`: 100 years, in seconds.
pub const MAX_FORGET_WORKERS_AFTER: f64 = 100.0 * 365.0 * 86_400.0;

/// A duration as `--forget-workers-after` takes it: a number of seconds, or a number with a unit
/// `s`, `m`, `h` or `d` (`90`, `90s`, `30m`, `1.5h`, `2d`). The error says what is accepted.
pub fn parse_duration(text: &str) -> std::result::Result<f64, String> {
    let t = text.trim();
    let number = t.trim_end_matches(|c: char| c.is_ascii_alphabetic());
    let unit = match &t[number.len()..] {
        "" => "s",
        unit => unit,
    };
    let scale = match unit.to_ascii_lowercase().as_str() {
        "s" | "sec" | "secs" | "second" | "seconds" => 1.0,
        "m" | "min" | "mins" | "minute" | "minutes" => 60.0,
        "h" | "hour" | "hours" => 3600.0,
        "d" | "day" | "days" => 86_400.0,
        _ => return Err(format!("\"{text}\": the unit must be s, m, h or d (e.g. 90s, 30m, 1h, 2d)")),
    };
    let n: f64 = number.trim().parse().map_err(|_| {
        format!("\"{text}\" is not a duration: write a number of seconds or one with a unit (e.g. 90s, 30m, 1h, 2d)")
    })?;
    let seconds = n * scale;
    if !(seconds.is_finite() && seconds > 0.0 && seconds <= MAX_FORGET_WORKERS_AFTER) {
        return Err(format!("\"{text}\" must be more than 0 and at most 100 years (e.g. 90s, 30m, 1h, 2d)"));
    }
    Ok(seconds)
}

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
    /// How long a worker is kept off a tile it failed (`failures::RETRY_FAILED_AFTER` by default).
    pub retry_failed_after_seconds: f64,
    pub max_upload_mb: usize,
    /// Caps on what one upload unpacks to (total, per file, file count).
    pub max_unpacked_mb: u64,
    pub max_file_mb: u64,
    pub max_bundle_files: usize,
    /// Most tiles one job may be cut into.
    pub max_job_tiles: u64,
    /// Most frames (cameras of its scene files) one job may render.
    pub max_job_frames: usize,
    /// Longest one tile may render before its worker gives up and fails it.
    pub max_tile_seconds: f64,
    /// Most samples (pixels x samples per pixel, over every frame) one job may ask for.
    pub max_job_samples: u64,
    /// Most units of work (tiles x passes over every frame: rows of the store) of one job.
    pub max_job_units: u64,
    /// Most live (not lost) registered workers.
    pub max_workers: u64,
    /// Seconds after which a silent worker is forgotten: it leaves the workers list, and its
    /// row goes once it holds no live lease (`--forget-workers-after`).
    pub forget_workers_after: f64,
    /// Most connections open at once (`None`: the descriptor limit less a reserve).
    pub max_connections: Option<usize>,
    /// Most connections open at once from one client address.
    pub max_connections_per_ip: usize,
    /// Seconds a client has to send a request head; a kept-alive connection idle this long is
    /// closed.
    pub header_timeout_seconds: f64,
    /// Origins besides the farm's own whose pages may send it state-changing requests.
    pub allowed_origins: Vec<String>,
    /// Host names answered besides IP literals and `localhost` (`*`: any).
    pub allowed_hosts: Vec<String>,
    /// `/metrics` without the API token.
    pub public_metrics: bool,
    /// Longest pause, in seconds, in a request body the server is waiting for: past it the
    /// request is answered 408 and its connection closed.
    pub body_timeout_seconds: f64,
    /// Where every job's end is POSTed (`notify.rs`).
    pub notify_url: Option<String>,
    /// URL prefixes a job's own `notify_url` must start with (none: jobs may not ask).
    pub notify_allow: Vec<String>,
    /// Finished jobs are removed this many days after they ended (`None`: kept for ever).
    pub keep_finished_days: Option<f64>,
    /// The oldest finished jobs are removed while the jobs' outputs take more MiB than this.
    pub disk_budget_mb: Option<u64>,
}

/// A random token from the operating system's generator (for local workers when none is set).
pub(crate) fn random_token() -> String {
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

/// The file in the data directory that holds the farm's worker token (mode 0600).
pub fn worker_token_file(data_dir: &std::path::Path) -> PathBuf {
    data_dir.join("worker-token")
}

/// The worker token this server uses, kept in [`worker_token_file`] so that it can be shown
/// again (`tessera-server worker-token`) and survives restarts (a second machine that joined
/// keeps working): `given` (`--worker-token`) if set, else the file's, else a new random one.
pub fn keep_worker_token(data_dir: &std::path::Path, given: Option<&str>) -> Result<String> {
    let file = worker_token_file(data_dir);
    let kept = std::fs::read_to_string(&file).ok().map(|t| t.trim().to_string()).filter(|t| !t.is_empty());
    let token = match (given, kept.as_deref()) {
        (Some(t), _) => t.to_string(),
        (None, Some(k)) => return Ok(k.to_string()),
        (None, None) => random_token(),
    };
    if kept.as_deref() != Some(token.as_str()) {
        write_private(&file, format!("{token}\n").as_bytes())
            .with_context(|| format!("cannot keep the worker token in {}", file.display()))?;
    }
    Ok(token)
}

/// Writes `bytes` to `path` readable by its owner only (0600 from the start: the bytes are
/// never readable by others, not even for a moment), replacing it atomically.
fn write_private(path: &std::path::Path, bytes: &[u8]) -> std::io::Result<()> {
    use std::io::Write;
    let temp = tessera::atomic_write::unique_temp_name(path);
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create_new(true);
    #[cfg(unix)]
    std::os::unix::fs::OpenOptionsExt::mode(&mut options, 0o600);
    let written = (|| {
        let mut f = options.open(&temp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&temp, path)
    })();
    if written.is_err() {
        let _ = std::fs::remove_file(&temp);
    }
    written
}

/// The line the server logs once at start: how another machine joins this farm.
fn join_advice(bind: SocketAddr, addr: SocketAddr, token: &str, data_dir: &std::path::Path) -> String {
    let file = worker_token_file(data_dir);
    let kept = format!(
        "the token is kept in {} (mode 0600); `tessera-server worker-token --data-dir {}` prints it again",
        file.display(),
        data_dir.display()
    );
    let port = addr.port();
    if bind.ip().is_loopback() {
        format!(
            "this farm listens on loopback only, so only this machine's workers can join; to add another \
             machine, start the server with --bind 0.0.0.0:{port} and an --api-token, then run there: \
             tessera-worker work --server http://THIS-MACHINE:{port} --token {token} ({kept})"
        )
    } else {
        let host =
            if addr.ip().is_unspecified() { "THIS-MACHINE".to_string() } else { addr.ip().to_string() };
        format!(
            "to add a machine to this farm, run there: tessera-worker work --server http://{host}:{port} --token {token} ({kept})"
        )
    }
}

/// Checks the configuration before anything starts.
pub fn check_config(config: &Config) -> Result<()> {
    if let Some(url) = &config.notify_url {
        notify::check_url(url).map_err(|e| anyhow::anyhow!("--notify-url {url:?} {e}"))?;
    }
    for prefix in &config.notify_allow {
        notify::check_url(prefix).map_err(|e| {
            anyhow::anyhow!(
                "--notify-allow {prefix:?} {e}; give a URL prefix such as https://hooks.example/tessera/"
            )
        })?;
    }
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
    if config.max_job_frames == 0 || config.max_job_frames > 1 << 20 {
        bail!("--max-job-frames must be from 1 to 1048576 frames a job, found {}", config.max_job_frames);
    }
    if config.tile_size == 0 || config.tile_size > 4096 {
        bail!("--tile-size must be between 1 and 4096 pixels, found {}", config.tile_size);
    }
    // The periods workers keep; a NaN fails both tests.
    let periods = tessera::protocol::HEARTBEAT_SECONDS;
    let heartbeat_ok = periods.contains(&config.heartbeat_seconds);
    let lease_ok = config.lease_seconds > config.heartbeat_seconds && config.lease_seconds <= *periods.end();
    if !heartbeat_ok || !lease_ok {
        bail!(
            "--heartbeat-seconds ({}) must be from 0.001 to 1e9 and shorter than --lease-seconds ({}, at most 1e9)",
            config.heartbeat_seconds,
            config.lease_seconds
        );
    }
    if !(0.0..=1e9).contains(&config.retry_failed_after_seconds) {
        bail!(
            "--retry-failed-after-seconds must be from 0 to 1e9 seconds, found {}",
            config.retry_failed_after_seconds
        );
    }
    if !(config.max_tile_seconds > 0.0 && config.max_tile_seconds.is_finite()) {
        bail!("--max-tile-seconds must be a positive number of seconds, found {}", config.max_tile_seconds);
    }
    if config.max_job_samples == 0 {
        bail!("--max-job-samples must be at least 1");
    }
    if config.max_job_units == 0 {
        bail!("--max-job-units must be at least 1");
    }
    if config.max_workers == 0 {
        bail!("--max-workers must be at least 1");
    }
    let forget = config.forget_workers_after;
    if !(forget > 0.0 && forget <= MAX_FORGET_WORKERS_AFTER) {
        bail!(
            "--forget-workers-after must be a positive duration of at most 100 years (e.g. 90s, 30m, 1h, 2d), found {forget} s"
        );
    }
    if config.max_connections == Some(0) || config.max_connections_per_ip == 0 {
        bail!("--max-connections and --max-connections-per-ip must be at least 1");
    }
    if !(config.header_timeout_seconds >= 0.1 && config.header_timeout_seconds <= 3600.0) {
        bail!("--header-timeout-seconds must be from 0.1 to 3600, found {}", config.header_timeout_seconds);
    }
    access(config)?;
    retention::policy(config.keep_finished_days, config.disk_budget_mb).map_err(anyhow::Error::msg)?;
    if !(config.body_timeout_seconds >= 0.1 && config.body_timeout_seconds <= 3600.0) {
        bail!(
            "--body-timeout-seconds must be from 0.1 to 3600 (the longest pause in a request body), found {}",
            config.body_timeout_seconds
        );
    }
    Ok(())
}

/// `--allowed-origin`, `--allowed-host` and `--public-metrics` as the server checks them.
fn access(config: &Config) -> Result<state::Access> {
    let mut access = state::Access { public_metrics: config.public_metrics, ..Default::default() };
    for o in config.allowed_origins.iter().filter(|o| !o.trim().is_empty()) {
        if o.trim() == "*" || o.trim().eq_ignore_ascii_case("null") {
            bail!(
                "--allowed-origin {o}: name each site whose pages may change the farm (e.g. https://ui.example); \
                 {o} would let any page do so"
            );
        }
        let origin =
            api::browser::normalize_origin(o).map_err(|e| anyhow::anyhow!("--allowed-origin: {e}"))?;
        access.allowed_origins.push(origin);
    }
    for h in config.allowed_hosts.iter().filter(|h| !h.trim().is_empty()) {
        let host =
            api::browser::normalize_allowed_host(h).map_err(|e| anyhow::anyhow!("--allowed-host: {e}"))?;
        if host == "*" {
            access.any_host = true;
        } else {
            access.allowed_hosts.push(host);
        }
    }
    Ok(access)
}

/// Runs the server until `shutdown` asks it to stop. `on_listening` gets the bound address (port
/// 0 picks a free one).
///
/// The first item of `shutdown` stops the server gracefully: the local workers get SIGTERM and
/// up to [`LOCAL_WORKER_GRACE`] to finish their tiles while the server still takes their results,
/// long polls answer 503 at once, then open requests get 3 s. A second item kills the local
/// workers at once. The binary passes Ctrl-C and SIGTERM; a test can pass
/// `futures_util::stream::once(..)` of anything. A stream that ends asks for nothing more.
pub async fn serve(
    config: Config,
    on_listening: impl FnOnce(SocketAddr),
    shutdown: impl Stream<Item = ()> + Send + 'static,
) -> Result<()> {
    check_config(&config)?;
    std::fs::create_dir_all(&config.data_dir)
        .with_context(|| format!("cannot create the data directory {}", config.data_dir.display()))?;
    // A lost job store beside earlier jobs' files is a refusal, never an empty farm.
    let store = Arc::new(storage::open_store(&config.data_dir)?);
    store.set_retry_failed_after(config.retry_failed_after_seconds);
    let blobs = bundle::BlobStore::new(&config.data_dir)?;
    // Uploads spooled by requests that were cut off by a crash, and the temporary files of
    // merges and passes a kill cut off.
    let _ = std::fs::remove_dir_all(config.data_dir.join("uploads"));
    let swept = storage::sweep(&config.data_dir, &store)?;
    if swept != storage::Swept::default() {
        tracing::info!(
            "removed {} temporary file(s) of writes cut off by a stop, and {} pass file(s) of older versions",
            swept.temporaries,
            swept.old_pass_files
        );
    }
    // Result files whose rows never committed (or let go of them just before a stop).
    let unnamed = store.sweep_results(std::time::Duration::ZERO)?;
    if unnamed > 0 {
        tracing::info!("removed {unnamed} tile result file(s) that no tile names any more");
    }
    // Uploads to the file store that a stop cut off.
    let cut = files::FileStore::new(&config.data_dir)?.remove_temporaries();
    if cut > 0 {
        tracing::info!("removed {cut} temporary file(s) of uploads to the file store cut off by a stop");
    }
    let worker_token = keep_worker_token(&config.data_dir, config.worker_token.as_deref())?;
    let settings = state::Settings {
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
        max_job_frames: config.max_job_frames,
        notify_allow: config.notify_allow.clone(),
        access: access(&config)?,
        max_job_units: config.max_job_units,
        max_workers: config.max_workers,
        local_worker_token: random_token(),
        forget_workers_after: config
            .forget_workers_after
            .max(scheduler::lost_after(config.heartbeat_seconds)),
        retention: retention::policy(config.keep_finished_days, config.disk_budget_mb)
            .map_err(anyhow::Error::msg)?,
    };
    let timing = scheduler::Timing {
        lease_seconds: config.lease_seconds,
        heartbeat_seconds: config.heartbeat_seconds,
        max_wait_seconds: 20.0,
        max_tile_seconds: config.max_tile_seconds,
    };
    let state = state::AppState::new(store.clone(), blobs, settings, timing);

    let listener = tokio::net::TcpListener::bind(config.bind)
        .await
        .with_context(|| format!("cannot listen on {}", config.bind))?;
    let addr = listener.local_addr()?;
    let descriptors = connections::raise_descriptor_limit();
    let limits = connections::ConnectionLimits {
        max_total: connections::max_connections(descriptors, config.max_connections),
        max_per_ip: config.max_connections_per_ip,
        header_timeout: Duration::from_secs_f64(config.header_timeout_seconds),
        body_timeout: Duration::from_secs_f64(config.body_timeout_seconds),
    };
    tracing::info!(
        "listening on http://{addr}, data in {}; at most {} connections ({} per client address; {descriptors} descriptors)",
        config.data_dir.display(),
        limits.max_total,
        limits.max_per_ip
    );
    on_listening(addr);
    tracing::info!("{}", join_advice(config.bind, addr, &worker_token, &config.data_dir));

    // Frames whose last tile arrived just before a crash, or whose merge found the disk full.
    for f in store.frames_awaiting_merge()? {
        tracing::info!(job = f.job_id, frame = f.index, "merging a frame left from before the restart");
        tokio::spawn(merge::merge_frame(state.clone(), f.job_id, f.index));
    }
    // Videos due when the server stopped (their frames all merged, the video not made).
    video::resume(&state)?;
    // Merges that find the disk full wait for space, and are tried again until it returns.
    merge::retry_when_space_returns(state.clone());

    // Lease expiry: tiles of silent workers go back to the queue.
    state.scheduler.spawn_expiry();

    // Local workers: real processes over real HTTP, restarted if they die, stopped gracefully.
    // They hold a token of their own, which the registration limits do not count.
    let local = local_workers::LocalWorkers::start(&config, addr, &state.settings.local_worker_token)?;

    // Rows of ended jobs purged, stale workers forgotten.
    // Never sooner than a worker counts as lost.
    housekeeping::spawn(state.clone(), state.settings.forget_workers_after);
    housekeeping::spawn_checkpoints(store.clone());
    // Job ends announced to the operator's and the jobs' receivers.
    notify::spawn(state.clone(), config.notify_url.clone(), api::job_info);

    let (stop_tx, mut stop_rx) = tokio::sync::watch::channel(false);
    let app = api::app(state.clone());
    let shutdown = async move {
        let mut shutdown = std::pin::pin!(shutdown);
        if shutdown.next().await.is_none() {
            return std::future::pending().await;
        }
        tracing::info!("shutting down");
        // Stop the local workers first, while the server still takes their last results and
        // the leases they give back; a second request stops them at once. Then end the long
        // polls, which can no longer bring anything but a lease to give back.
        local.stop_gracefully();
        state.scheduler.begin_shutdown();
        local
            .stopped(async {
                if shutdown.next().await.is_none() {
                    std::future::pending::<()>().await;
                }
            })
            .await;
        let _ = stop_tx.send(true);
    };
    let server = connections::serve(listener, app, limits, shutdown);
    // In-flight requests (long polls of remote workers) get a few seconds to finish.
    let server = std::pin::pin!(server);
    tokio::select! {
        () = server => {}
        _ = async {
            let _ = stop_rx.wait_for(|s| *s).await;
            tokio::time::sleep(Duration::from_secs(3)).await;
        } => tracing::info!("stopped with requests still open"),
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(dir: &tessera_testkit::TempDir) -> Config {
        Config {
            bind: "127.0.0.1:0".parse().unwrap(),
            data_dir: dir.path().join("data"),
            local_workers: 0,
            local_worker_threads: None,
            worker_bin: None,
            tile_size: 32,
            api_token: None,
            worker_token: Some("wtok".into()),
            insecure: false,
            lease_seconds: 30.0,
            heartbeat_seconds: 5.0,
            retry_failed_after_seconds: 30.0,
            max_upload_mb: 16,
            max_unpacked_mb: 16,
            max_file_mb: 16,
            max_bundle_files: 100,
            max_job_tiles: 1000,
            max_job_frames: 4096,
            max_tile_seconds: 60.0,
            max_job_samples: 1 << 30,
            max_job_units: 1_000_000,
            max_workers: 4096,
            forget_workers_after: 86_400.0,
            max_connections: None,
            max_connections_per_ip: 256,
            header_timeout_seconds: 20.0,
            allowed_origins: Vec::new(),
            allowed_hosts: Vec::new(),
            public_metrics: false,
            body_timeout_seconds: 60.0,
            notify_url: None,
            notify_allow: Vec::new(),
            keep_finished_days: None,
            disk_budget_mb: None,
        }
    }

    /// Allowed origins and hosts are checked, and a bad one is named with its flag.
    #[test]
    fn allowed_origins_and_hosts_are_checked() {
        let dir = tessera_testkit::TempDir::new("unit-access");
        let with = |origins: &[&str], hosts: &[&str]| {
            check_config(&Config {
                allowed_origins: origins.iter().map(|s| s.to_string()).collect(),
                allowed_hosts: hosts.iter().map(|s| s.to_string()).collect(),
                ..config(&dir)
            })
        };
        assert!(with(&["https://ui.example", "http://127.0.0.1:3000"], &["farm.example", "*"]).is_ok());
        for bad in ["*", "null", "ui.example", "https://ui.example/path"] {
            let e = with(&[bad], &[]).unwrap_err().to_string();
            assert!(e.contains("--allowed-origin"), "{bad}: {e}");
        }
        for bad in ["farm.example:8080", "https://farm.example", "a b"] {
            let e = with(&[], &[bad]).unwrap_err().to_string();
            assert!(e.contains("--allowed-host"), "{bad}: {e}");
        }
    }

    /// Heartbeat and lease periods a worker can keep, and nothing else: a NaN, a period too
    /// short to sleep, one too long for a `Duration`, a lease not longer than the heartbeat.
    #[test]
    fn heartbeat_and_lease_periods_are_checked() {
        let dir = tessera_testkit::TempDir::new("unit-periods");
        let with = |heartbeat: f64, lease: f64| {
            check_config(&Config { heartbeat_seconds: heartbeat, lease_seconds: lease, ..config(&dir) })
        };
        for (heartbeat, lease) in [(5.0, 30.0), (0.001, 0.002), (100_000.0, 300_000.0), (1.0, 1e9)] {
            assert!(with(heartbeat, lease).is_ok(), "{heartbeat} {lease}");
        }
        for (heartbeat, lease) in [
            (0.0, 30.0),
            (-1.0, 30.0),
            (1e-4, 30.0),
            (f64::NAN, 30.0),
            (5.0, f64::NAN),
            (5.0, f64::INFINITY),
            (5.0, 5.0),
            (30.0, 5.0),
            (2e9, 3e9),
        ] {
            let e = with(heartbeat, lease).unwrap_err().to_string();
            assert!(
                e.contains("--heartbeat-seconds") && e.contains("--lease-seconds"),
                "{heartbeat} {lease}: {e}"
            );
        }
    }

    /// Connection limits of at least one, and a header timeout a client can meet.
    #[test]
    fn connection_limits_are_checked() {
        let dir = tessera_testkit::TempDir::new("unit-connections");
        assert!(check_config(&config(&dir)).is_ok());
        for bad in [
            Config { max_connections: Some(0), ..config(&dir) },
            Config { max_connections_per_ip: 0, ..config(&dir) },
        ] {
            let e = check_config(&bad).unwrap_err().to_string();
            assert!(e.contains("--max-connections"), "{e}");
        }
        for t in [0.0, 0.05, 3601.0, f64::NAN, f64::INFINITY] {
            let e =
                check_config(&Config { header_timeout_seconds: t, ..config(&dir) }).unwrap_err().to_string();
            assert!(e.contains("--header-timeout-seconds"), "{t}: {e}");
            let e =
                check_config(&Config { body_timeout_seconds: t, ..config(&dir) }).unwrap_err().to_string();
            assert!(e.contains("--body-timeout-seconds"), "{t}: {e}");
        }
    }

    /// The store's limits: at least one unit, one worker, and a positive time to forget.
    #[test]
    fn store_limits_are_checked() {
        let dir = tessera_testkit::TempDir::new("unit-store-limits");
        for (bad, flag) in [
            (Config { max_job_units: 0, ..config(&dir) }, "--max-job-units"),
            (Config { notify_url: Some("ftp://x/".into()), ..config(&dir) }, "--notify-url"),
            (Config { notify_allow: vec!["hooks.example".into()], ..config(&dir) }, "--notify-allow"),
            (Config { max_job_frames: 0, ..config(&dir) }, "--max-job-frames"),
            (Config { max_job_frames: (1 << 20) + 1, ..config(&dir) }, "--max-job-frames"),
            (Config { max_workers: 0, ..config(&dir) }, "--max-workers"),
            (Config { forget_workers_after: 0.0, ..config(&dir) }, "--forget-workers-after"),
            (Config { forget_workers_after: f64::NAN, ..config(&dir) }, "--forget-workers-after"),
            (Config { forget_workers_after: 1e10, ..config(&dir) }, "--forget-workers-after"),
            (Config { retry_failed_after_seconds: -1.0, ..config(&dir) }, "--retry-failed-after-seconds"),
            (Config { retry_failed_after_seconds: f64::NAN, ..config(&dir) }, "--retry-failed-after-seconds"),
            (Config { retry_failed_after_seconds: 1e10, ..config(&dir) }, "--retry-failed-after-seconds"),
        ] {
            let e = check_config(&bad).unwrap_err().to_string();
            assert!(e.contains(flag), "{e}");
        }
        assert!(check_config(&Config { forget_workers_after: 3.6, ..config(&dir) }).is_ok());
    }

    #[test]
    fn durations_are_seconds_or_a_number_with_a_unit() {
        for (text, seconds) in [
            ("90", 90.0),
            ("90s", 90.0),
            ("30m", 1800.0),
            ("1.5h", 5400.0),
            (" 2d ", 172_800.0),
            ("2 days", 172_800.0),
        ] {
            assert_eq!(parse_duration(text), Ok(seconds), "{text}");
        }
        for (bad, says) in [
            ("", "is not a duration"),
            ("h", "is not a duration"),
            ("1w", "the unit must be s, m, h or d"),
            ("0", "more than 0"),
            ("-5m", "more than 0"),
            ("1e300d", "at most 100 years"),
            ("NaN", "the unit must be"),
        ] {
            let e = parse_duration(bad).unwrap_err();
            assert!(e.contains(says), "{bad}: {e}");
        }
    }

    #[tokio::test]
    async fn serve_answers_until_its_shutdown_stream_says_stop() {
        let dir = tessera_testkit::TempDir::new("unit-serve");
        let config = config(&dir);
        let (listening_tx, listening_rx) = tokio::sync::oneshot::channel();
        let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
        let stop = futures_util::stream::once(async move {
            let _ = stop_rx.await;
        });
        let server = tokio::spawn(serve(
            config,
            move |addr| {
                let _ = listening_tx.send(addr);
            },
            stop,
        ));
        let addr = tokio::time::timeout(Duration::from_secs(10), listening_rx).await.unwrap().unwrap();
        let health = tokio::task::spawn_blocking(move || {
            ureq::get(&format!("http://{addr}/healthz")).call().unwrap().into_string().unwrap()
        })
        .await
        .unwrap();
        assert_eq!(health, "ok\n");
        stop_tx.send(()).unwrap();
        let stopped = tokio::time::timeout(Duration::from_secs(10), server).await;
        stopped.expect("serve did not stop").unwrap().unwrap();
    }
}
