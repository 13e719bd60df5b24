//! `tessera-server`: the render farm's server. See the crate docs (`lib.rs`) and the README.

use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use tessera_server::{Config, serve};

#[derive(Parser)]
#[command(
    name = "tessera-server",
    version,
    about = "Tessera's render farm server: takes CENG795 scenes over HTTP, cuts every frame into tiles, hands them to workers, merges and tone-maps the results",
    after_help = "With no options it listens on 127.0.0.1:8080, keeps its state in ./tessera-data and starts one local worker that uses every core: a working farm.\n\nExamples:\n  tessera-server\n  curl -F scene=@scene.xml -F asset=@ply/bunny.ply\\;filename=ply/bunny.ply http://127.0.0.1:8080/api/v1/jobs\n  tessera-server --bind 0.0.0.0:8080 --api-token SECRET --worker-token WSECRET --local-workers 0\n  tessera-worker work --server http://farm:8080 --token WSECRET\n  tessera-server worker-token    (the farm's worker token, to join another machine)"
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    /// Address and port to listen on. Anything other than loopback needs --api-token (or
    /// --insecure).
    #[arg(long, default_value = "127.0.0.1:8080", env = "TESSERA_BIND", value_name = "ADDR:PORT")]
    bind: SocketAddr,
    /// Directory for the job database (tessera.db), uploaded bundles and rendered outputs.
    #[arg(long, default_value = "tessera-data", env = "TESSERA_DATA_DIR", value_name = "DIR")]
    data_dir: PathBuf,
    /// Worker processes to start on this machine (0: only remote workers).
    #[arg(long, default_value_t = 1, env = "TESSERA_LOCAL_WORKERS", value_name = "N")]
    local_workers: usize,
    /// Render threads of each local worker (default: every core).
    #[arg(long, env = "TESSERA_LOCAL_WORKER_THREADS", value_name = "N")]
    local_worker_threads: Option<usize>,
    /// The tessera-worker binary for local workers (default: the one next to this binary).
    #[arg(long, env = "TESSERA_WORKER_BIN", value_name = "PATH")]
    worker_bin: Option<PathBuf>,
    /// Default tile edge in pixels (a job may choose its own).
    #[arg(long, default_value_t = 32, env = "TESSERA_TILE_SIZE", value_name = "PX")]
    tile_size: u32,
    /// Token the job API requires ("Authorization: Bearer TOKEN"). Without one the API is open,
    /// which is allowed on loopback addresses only.
    #[arg(long, env = "TESSERA_API_TOKEN", value_name = "TOKEN", hide_env_values = true)]
    api_token: Option<String>,
    /// Token workers must present. Default: a random one, given to the local workers.
    #[arg(long, env = "TESSERA_WORKER_TOKEN", value_name = "TOKEN", hide_env_values = true)]
    worker_token: Option<String>,
    /// Allow a non-loopback --bind without tokens (only on a network you trust).
    #[arg(long)]
    insecure: bool,
    /// Seconds a lease lives without a heartbeat before its tile goes back to the queue (longer
    /// than --heartbeat-seconds, at most 1e9).
    #[arg(long, default_value_t = 30.0, env = "TESSERA_LEASE_SECONDS", value_name = "S")]
    lease_seconds: f64,
    /// How often workers send heartbeats, in seconds (0.001 to 1e9).
    #[arg(long, default_value_t = 5.0, env = "TESSERA_HEARTBEAT_SECONDS", value_name = "S")]
    heartbeat_seconds: f64,
    /// Seconds a worker is kept off a tile it failed or crashed on (and off a job it failed
    /// three tiles of), from its latest failure there, so that another worker takes the tile
    /// first (0 to 1e9).
    #[arg(long, default_value_t = 30.0, env = "TESSERA_RETRY_FAILED_AFTER_SECONDS", value_name = "S")]
    retry_failed_after_seconds: f64,
    /// Largest accepted upload in MiB.
    #[arg(long, default_value_t = 1024, env = "TESSERA_MAX_UPLOAD_MB", value_name = "MIB")]
    max_upload_mb: usize,
    /// Most bytes one upload may unpack to, in MiB: its files, and whatever its archives
    /// decompress to (a zip bomb stops here, with a 413 that names this flag).
    #[arg(long, default_value_t = 256, env = "TESSERA_MAX_UNPACKED_MB", value_name = "MIB")]
    max_unpacked_mb: u64,
    /// Largest single file of an upload, unpacked, in MiB; also the largest upload to the file
    /// store (PUT /api/v1/files/SHA256), whatever --max-upload-mb.
    #[arg(long, default_value_t = 256, env = "TESSERA_MAX_FILE_MB", value_name = "MIB")]
    max_file_mb: u64,
    /// Most files one upload may hold (loose or inside archives).
    #[arg(long, default_value_t = 10_000, env = "TESSERA_MAX_BUNDLE_FILES", value_name = "N")]
    max_bundle_files: usize,
    /// Most tiles one job may be cut into (a 4K frame in 16-pixel tiles is 32 400); a job over
    /// it is refused with 422, naming the smallest tile_size that fits.
    #[arg(long, default_value_t = 100_000, env = "TESSERA_MAX_JOB_TILES", value_name = "N")]
    max_job_tiles: u64,
    /// Most frames one job may render: the cameras of its scene files (a 360-frame sequence is
    /// 360). Larger jobs are refused with 422; submit them as several jobs.
    #[arg(long, default_value_t = 4096, env = "TESSERA_MAX_JOB_FRAMES", value_name = "N")]
    max_job_frames: usize,
    /// Longest one tile may render (on one thread of a worker); past it the worker stops and
    /// the tile fails (a job whose tiles keep failing fails). Raise it, or submit with a larger tile count (smaller
    /// --tile-size) or fewer samples.
    #[arg(long, default_value_t = 1800.0, env = "TESSERA_MAX_TILE_SECONDS", value_name = "S")]
    max_tile_seconds: f64,
    /// Most samples one job may ask for: pixels x samples per pixel, summed over its frames
    /// (VeachAjar_hw6's 1280x720 at 2500 spp is 2.3e9). Larger jobs are refused with 422.
    #[arg(long, default_value_t = 100_000_000_000, env = "TESSERA_MAX_JOB_SAMPLES", value_name = "N")]
    max_job_samples: u64,
    /// Most units of work one job may be: tiles x passes, summed over its frames, each a row of
    /// the job store (a 4K frame in 16-pixel tiles in 16 passes is 518 400). Larger jobs are
    /// refused with 422, naming the smallest tile_size and pass_samples that fit.
    #[arg(long, default_value_t = 1_000_000, env = "TESSERA_MAX_JOB_UNITS", value_name = "N")]
    max_job_units: u64,
    /// Most live (not lost) registered workers; past it a registration is refused with 503
    /// (the server's own local workers still register).
    #[arg(long, default_value_t = 4096, env = "TESSERA_MAX_WORKERS", value_name = "N")]
    max_workers: u64,
    /// How long a worker may be silent before it is forgotten: it leaves the workers list and
    /// the page at once, and its row goes once it holds no lease (the job logs keep its name;
    /// if it comes back it registers again). Seconds, or a number with s, m, h or d (90s, 30m,
    /// 12h, 2d); never sooner than it counts as lost (three heartbeats and two seconds).
    #[arg(
        long,
        default_value = "1d",
        env = "TESSERA_FORGET_WORKERS_AFTER",
        value_name = "DURATION",
        value_parser = tessera_server::parse_duration
    )]
    forget_workers_after: f64,
    /// --forget-workers-after in hours (its older form).
    #[arg(
        long,
        hide = true,
        env = "TESSERA_FORGET_WORKERS_AFTER_HOURS",
        value_name = "H",
        conflicts_with = "forget_workers_after"
    )]
    forget_workers_after_hours: Option<f64>,
    /// Most connections open at once; more are closed as they arrive. Default: the process's
    /// open-file limit (raised to its hard limit at start) less 128 kept for the server's files.
    #[arg(long, env = "TESSERA_MAX_CONNECTIONS", value_name = "N")]
    max_connections: Option<usize>,
    /// Most connections open at once from one client address (a worker uses up to four, a
    /// browser six).
    #[arg(long, default_value_t = 256, env = "TESSERA_MAX_CONNECTIONS_PER_IP", value_name = "N")]
    max_connections_per_ip: usize,
    /// Seconds a client has to send a request's head; a kept-alive connection idle this long is
    /// closed too (0.1 to 3600).
    #[arg(long, default_value_t = 20.0, env = "TESSERA_HEADER_TIMEOUT_SECONDS", value_name = "S")]
    header_timeout_seconds: f64,
    /// An origin (scheme://host[:port]) besides the farm's own whose web pages may submit,
    /// cancel and otherwise change jobs; repeat it or separate origins with commas. Other
    /// sites' pages are refused (403).
    #[arg(
        long = "allowed-origin",
        env = "TESSERA_ALLOWED_ORIGINS",
        value_delimiter = ',',
        value_name = "ORIGIN"
    )]
    allowed_origins: Vec<String>,
    /// A host name clients reach the server by, besides IP addresses and localhost; repeat it or
    /// separate names with commas; * answers any. Other names are refused (421: DNS rebinding),
    /// except for requests that carry the API or worker token.
    #[arg(long = "allowed-host", env = "TESSERA_ALLOWED_HOSTS", value_delimiter = ',', value_name = "NAME")]
    allowed_hosts: Vec<String>,
    /// Answer /metrics without the API token (for a scraper that cannot send one).
    #[arg(long, env = "TESSERA_PUBLIC_METRICS")]
    public_metrics: bool,
    /// Longest pause in a request's body, in seconds, while the server waits for it (measured
    /// between the body's bytes, not over the whole body: a slow upload that keeps sending is
    /// never cut); past it the request is answered 408 and its connection closed (0.1 to 3600).
    #[arg(long, default_value_t = 60.0, env = "TESSERA_BODY_TIMEOUT_SECONDS", value_name = "S")]
    body_timeout_seconds: f64,
    /// POST a JSON document to this URL whenever a job ends (done, failed or cancelled):
    /// `{"event": "job_done"|"job_failed"|"job_cancelled", "job": <the job's JSON>}`, tried 4
    /// times with a 10 s timeout, never holding up the server.
    #[arg(long, env = "TESSERA_NOTIFY_URL", value_name = "URL")]
    notify_url: Option<String>,
    /// A URL prefix under which a job's own notify_url may point (repeat it or separate with
    /// commas); without one, jobs may not ask to be announced anywhere.
    #[arg(long = "notify-allow", env = "TESSERA_NOTIFY_ALLOW", value_delimiter = ',', value_name = "PREFIX")]
    notify_allow: Vec<String>,
    /// Remove finished jobs (done, failed, cancelled) with their outputs this many days after
    /// they ended (fractions allowed, e.g. 0.5). Default: finished jobs are kept for ever.
    #[arg(long, env = "TESSERA_KEEP_FINISHED_DAYS", value_name = "D", allow_negative_numbers = true)]
    keep_finished_days: Option<f64>,
    /// Remove the oldest finished jobs with their outputs while the jobs' outputs (the data
    /// directory's outputs/ and frames/) take more than this many MiB; the job that finished
    /// last always stays. Default: no budget.
    #[arg(long, env = "TESSERA_DISK_BUDGET_MB", value_name = "M")]
    disk_budget_mb: Option<u64>,
}

#[derive(clap::Subcommand)]
enum Command {
    /// Print this farm's worker token (what `tessera-worker work --token` needs to join), kept
    /// in the data directory's worker-token file since the server's first start.
    WorkerToken {
        /// The server's data directory.
        #[arg(long, default_value = "tessera-data", env = "TESSERA_DATA_DIR", value_name = "DIR")]
        data_dir: PathBuf,
    },
}

/// `tessera-server worker-token`: the kept token on stdout.
fn print_worker_token(data_dir: &std::path::Path) -> ExitCode {
    let file = tessera_server::worker_token_file(data_dir);
    match std::fs::read_to_string(&file) {
        Ok(t) if !t.trim().is_empty() => {
            println!("{}", t.trim());
            ExitCode::SUCCESS
        }
        Ok(_) | Err(_) if !data_dir.join("tessera.db").exists() => {
            eprintln!(
                "error: {} holds no farm yet: start tessera-server with --data-dir {} once (it makes the token), \
                 or give --data-dir the server's data directory",
                data_dir.display(),
                data_dir.display()
            );
            ExitCode::FAILURE
        }
        Ok(_) => {
            eprintln!("error: {} is empty: start the server once to make a new token", file.display());
            ExitCode::FAILURE
        }
        Err(e) => {
            eprintln!(
                "error: cannot read {}: {e}; run this as the user the server runs as, or start the server once to make it",
                file.display()
            );
            ExitCode::FAILURE
        }
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if let Some(Command::WorkerToken { data_dir }) = &cli.command {
        return print_worker_token(data_dir);
    }
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("TESSERA_LOG")
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let config = Config {
        bind: cli.bind,
        data_dir: cli.data_dir,
        local_workers: cli.local_workers,
        local_worker_threads: cli.local_worker_threads,
        worker_bin: cli.worker_bin,
        tile_size: cli.tile_size,
        api_token: cli.api_token.filter(|t| !t.is_empty()),
        worker_token: cli.worker_token.filter(|t| !t.is_empty()),
        insecure: cli.insecure,
        lease_seconds: cli.lease_seconds,
        heartbeat_seconds: cli.heartbeat_seconds,
        retry_failed_after_seconds: cli.retry_failed_after_seconds,
        max_upload_mb: cli.max_upload_mb,
        max_unpacked_mb: cli.max_unpacked_mb,
        max_file_mb: cli.max_file_mb,
        max_bundle_files: cli.max_bundle_files,
        max_job_tiles: cli.max_job_tiles,
        max_job_frames: cli.max_job_frames,
        max_tile_seconds: cli.max_tile_seconds,
        max_job_samples: cli.max_job_samples,
        max_job_units: cli.max_job_units,
        max_workers: cli.max_workers,
        forget_workers_after: cli.forget_workers_after_hours.map_or(cli.forget_workers_after, |h| h * 3600.0),
        max_connections: cli.max_connections,
        max_connections_per_ip: cli.max_connections_per_ip,
        header_timeout_seconds: cli.header_timeout_seconds,
        allowed_origins: cli.allowed_origins,
        allowed_hosts: cli.allowed_hosts,
        public_metrics: cli.public_metrics,
        body_timeout_seconds: cli.body_timeout_seconds,
        notify_url: cli.notify_url.filter(|u| !u.is_empty()),
        notify_allow: cli.notify_allow,
        keep_finished_days: cli.keep_finished_days,
        disk_budget_mb: cli.disk_budget_mb,
    };
    let runtime = match tokio::runtime::Builder::new_multi_thread().enable_all().build() {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: cannot start the async runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    let result = runtime.block_on(async {
        // Handlers first, so that a signal is never the default's (which would kill the server
        // without stopping its workers).
        let signals = shutdown_signals();
        serve(
            config,
            |addr| {
                // One machine-readable line on stdout, for scripts and tests that bind port 0.
                println!("listening on http://{addr}");
                let _ = std::io::stdout().flush();
            },
            signals,
        )
        .await
    });
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Ctrl-C and SIGTERM as one stream, for [`serve`]: the first stops the server gracefully, a
/// second stops its local workers at once. Call it inside the runtime.
fn shutdown_signals() -> impl futures_util::Stream<Item = ()> + Send + 'static {
    futures_util::stream::unfold(Signals::new(), |mut signals| async move {
        signals.next().await;
        Some(((), signals))
    })
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
