//! `tessera-worker work`: pulls tiles from a `tessera-server` and renders them
//! (the worker side of `tessera::protocol`).
//!
//! These threads share the work:
//! - the **fetcher** long-polls for the next lease and hands it over through a channel of one,
//!   so while tiles render the next one is already here and the cores never wait on the
//!   network;
//! - the **heartbeat** thread renews every lease the worker holds (rendering or prefetched)
//!   every `heartbeat_seconds`; it only does HTTP, so rendering cannot starve it, and gives a
//!   heartbeat up after a third of the lease, so one that hangs leaves time for the next;
//!   leases the server revoked are remembered and their tiles dropped;
//! - the **watcher** holds a long poll (`/api/v1/worker/watch`) on the leases being rendered,
//!   which the server answers the moment one is revoked (its job cancelled or failed); it, or
//!   the heartbeat, raises that tile's stop flag, and the renderer, which looks at the flag
//!   every few samples, gives up within a moment instead of finishing a tile nobody wants;
//! - a **render slot** per thread (`--threads`, default every core) takes a lease, fetches its
//!   job's files once (its bundle, or each file of its manifest: `jobfiles`) and builds the
//!   scene once per (bundle or manifest, scene file), cached and shared by the slots (the build
//!   runs on a rayon pool of as many threads), and renders the whole tile on
//!   its own thread with the same `render_tile_until` as `tessera-worker render`, which also
//!   gives each thread whole tiles (same bits). A tile that is still rendering after the
//!   lease's `max_render_seconds` (the server's `--max-tile-seconds`) is stopped and reported
//!   failed with a message naming that limit;
//! - the **uploader** sends each finished tile while the slots render the next ones;
//! - and, for a local worker of `tessera-server` (`--exit-with-parent`), a **parent-watch**
//!   thread that ends the process when its parent is gone.
//!
//! **Stopping.** SIGTERM or Ctrl-C (SIGINT) sets a flag: the worker takes no new lease, finishes
//! and uploads the tiles it is rendering, gives back (`.../release`) the lease it fetched ahead and
//! exits with status 0, so its tiles go back to the queue at once instead of after the lease
//! expires. A second signal exits at once (status 1); the server then requeues the tile when its
//! lease expires, as after a crash.

use std::collections::{HashMap, HashSet};
use std::io::Read;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, sync_channel};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use tessera::bundle::{BundleSceneError, load_bundle_scene_cached, read_tar};
use tessera::image::TileRect;
use tessera::passes::{BLOCK, SampleRange, encode_pass_tile};
use tessera::protocol::*;
use tessera::render::{
    AuxTile, RenderSettings, Stop, Stopped, render_tile_sums_until, render_tile_until,
    render_tile_with_aux_until, samples_per_pixel,
};
use tessera::scene::Scene;
use tessera::scene::load::LoadOptions;

/// What `work` was told.
pub struct WorkOptions {
    pub server: String,
    pub token: String,
    pub name: String,
    pub threads: Option<usize>,
    /// What the worker offers (`--tags`, checked): it is given only jobs asking for these.
    pub tags: Vec<String>,
    /// Stop after this many tiles (tests and benchmarks); `None`: run until killed.
    pub max_tiles: Option<u64>,
    /// Job files on disk by SHA-256 (`--cache-dir`, `--cache-mb`).
    pub files: Arc<crate::filecache::FileCache>,
    /// Meshes and images kept across frames and jobs (`--mesh-cache-mb`).
    pub meshes: Arc<tessera::scene::cache::MeshCache>,
}

/// The leases this worker holds and those the server took back.
struct Leases {
    held: HashSet<u64>,
    revoked: HashSet<u64>,
    /// The lease each render slot is rendering.
    rendering: Vec<Option<u64>>,
    /// Raised to stop the tile of a slot; a new one for every tile.
    cancel: Vec<Arc<AtomicBool>>,
}

impl Leases {
    fn new(slots: usize) -> Leases {
        Leases {
            held: HashSet::new(),
            revoked: HashSet::new(),
            rendering: vec![None; slots],
            cancel: (0..slots).map(|_| Arc::new(AtomicBool::new(false))).collect(),
        }
    }

    /// The server took `lease` back: forget it, and stop it if it is being rendered.
    fn revoke(&mut self, lease: u64) {
        self.held.remove(&lease);
        self.revoked.insert(lease);
        for (r, c) in self.rendering.iter().zip(&self.cancel) {
            if *r == Some(lease) {
                c.store(true, Ordering::SeqCst);
            }
        }
    }

    /// Whether the worker may ask for one more lease: it holds at most one per render slot, the
    /// one fetched ahead and one finished tile uploading (leases count until the server has
    /// their results), the most the server grants (threads + 2).
    fn may_lease(&self) -> bool {
        self.held.len() < self.rendering.len() + 2
    }

    /// The oldest lease being rendered: what the status page shows the worker doing.
    fn shown(&self) -> Option<u64> {
        self.rendering.iter().flatten().min().copied()
    }
}

/// The value behind `m`, even if a thread panicked while holding it (the lease book's sets,
/// the scene cache and the lease channel stay consistent: none is left half-changed).
fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

pub(crate) struct Client {
    base: String,
    pub(crate) token: String,
    /// The secret registration answered (empty before registration): sent on every later call.
    secret: String,
    pub(crate) agent: ureq::Agent,
}

impl Client {
    pub(crate) fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base)
    }

    // ureq's error type is large; these calls are a few per tile, not a hot path.
    #[allow(clippy::result_large_err)]
    fn post_json<T: serde::Serialize>(&self, path: &str, body: &T) -> Result<ureq::Response, ureq::Error> {
        self.post_json_within(path, body, None)
    }

    /// [`Client::post_json`] with a limit of its own on the whole request, instead of the agent's.
    #[allow(clippy::result_large_err)]
    fn post_json_within<T: serde::Serialize>(
        &self,
        path: &str,
        body: &T,
        timeout: Option<Duration>,
    ) -> Result<ureq::Response, ureq::Error> {
        let mut req = self.agent.post(&self.url(path));
        if let Some(t) = timeout {
            req = req.timeout(t);
        }
        req.set("Authorization", &format!("Bearer {}", self.token))
            .set(WORKER_SECRET_HEADER, &self.secret)
            .send_json(serde_json::to_value(body).expect("protocol types serialise"))
    }
}

/// Exits this process when its parent ends (it is re-parented), checked twice a second: local
/// workers must not outlive a server that was killed.
pub fn exit_with_parent() {
    #[cfg(unix)]
    {
        let parent = std::os::unix::process::parent_id();
        let _ = std::thread::Builder::new().name("parent-watch".into()).spawn(move || {
            loop {
                std::thread::sleep(Duration::from_millis(500));
                if std::os::unix::process::parent_id() != parent {
                    say!("the server that started this worker is gone; exiting");
                    std::process::exit(0);
                }
            }
        });
    }
}

/// Sleeps for `d`, or less once `stop` is set: a back-off must not hold up a stopping worker.
fn pause(stop: &AtomicBool, d: Duration) {
    let end = Instant::now() + d;
    while !stop.load(Ordering::SeqCst) {
        let left = end.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return;
        }
        std::thread::sleep(left.min(Duration::from_millis(20)));
    }
}

/// Why a request failed, for messages: the server's JSON error when there is one.
pub(crate) fn describe(e: ureq::Error) -> String {
    match e {
        ureq::Error::Status(code, resp) => {
            let body = resp.into_string().unwrap_or_default();
            match serde_json::from_str::<ApiError>(&body) {
                Ok(api) => format!("HTTP {code}: {}", api.error),
                Err(_) => format!("HTTP {code}: {}", body.trim()),
            }
        }
        ureq::Error::Transport(t) if t.url().is_some_and(|u| u.scheme() == "https") => {
            format!("cannot reach the server: {t}; {}", tessera::protocol::HTTPS_HINT)
        }
        ureq::Error::Transport(t) => format!("cannot reach the server: {t}"),
    }
}

/// The flag SIGTERM and SIGINT set; a second signal while it is set exits at once (status 1).
fn stop_flag() -> Result<Arc<AtomicBool>> {
    let stop = Arc::new(AtomicBool::new(false));
    #[cfg(unix)]
    for sig in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
        // The conditional exit first: it sees the flag as the previous signal left it.
        signal_hook::flag::register_conditional_shutdown(sig, 1, stop.clone())
            .context("cannot install the signal handlers")?;
        signal_hook::flag::register(sig, stop.clone()).context("cannot install the signal handlers")?;
    }
    Ok(stop)
}

/// The heartbeat period the server's register answer asks for, if it is one a worker can keep
/// ([`tessera::protocol::HEARTBEAT_SECONDS`]; a Tessera server checks its own against it).
fn heartbeat_interval(seconds: f64) -> Result<Duration> {
    if !tessera::protocol::HEARTBEAT_SECONDS.contains(&seconds) {
        bail!(
            "the server's register answer asks for a heartbeat every {seconds} s (heartbeat_seconds); \
             a worker keeps periods from 1 ms to 1e9 s: check the server's --heartbeat-seconds, \
             and that --server names a Tessera server"
        );
    }
    Ok(Duration::from_secs_f64(seconds))
}

/// How long one heartbeat may take: a third of the lease (`lease_seconds` of the register
/// answer), so that one that hangs (a connection gone half-open, a stalled server) is given up
/// while the lease still has time for the next ones; 1 s to 120 s (the other requests' limit),
/// 10 s if the server named no lease that makes sense.
fn heartbeat_timeout(lease_seconds: f64) -> Duration {
    let third = lease_seconds / 3.0;
    if third > 0.0 { Duration::from_secs_f64(third.clamp(1.0, 120.0)) } else { Duration::from_secs(10) }
}

/// Registers, retrying while the server is not up yet; fails at once on a bad token. `None`
/// when told to stop before the server answered.
fn register(
    client: &Client,
    name: &str,
    threads: u32,
    tags: &[String],
    stop: &AtomicBool,
) -> Result<Option<RegisterResponse>> {
    let mut delay = Duration::from_millis(200);
    let started = Instant::now();
    loop {
        if stop.load(Ordering::SeqCst) {
            return Ok(None);
        }
        match client.post_json(
            "/api/v1/worker/register",
            &RegisterRequest {
                name: name.into(),
                threads,
                tags: tags.to_vec(),
                protocol: tessera::protocol::WORKER_PROTOCOL,
            },
        ) {
            Ok(resp) => {
                let reg: RegisterResponse =
                    resp.into_json().context("the server's register answer is not valid JSON")?;
                // A server of another version would send leases this worker misreads.
                if let Some(why) =
                    tessera::protocol::protocol_mismatch(tessera::protocol::WORKER_PROTOCOL, reg.protocol)
                {
                    bail!("cannot work for the server at {}: {why}", client.base);
                }
                return Ok(Some(reg));
            }
            Err(ureq::Error::Status(401, _)) => {
                bail!(
                    "the server refused the worker token; pass the farm's worker token with --token or TESSERA_WORKER_TOKEN \
                     (on the server's machine `tessera-server worker-token` prints it)"
                )
            }
            Err(ureq::Error::Status(code @ (400 | 413 | 422), r)) => {
                bail!(
                    "the server refused to register this worker: {}",
                    describe(ureq::Error::Status(code, r))
                )
            }
            // TLS with a server that does not speak it: waiting does not help.
            Err(ureq::Error::Transport(t))
                if client.base.starts_with("https://") && t.to_string().contains("tls") =>
            {
                bail!("cannot reach the server at {}: {t}; {}", client.base, tessera::protocol::HTTPS_HINT)
            }
            Err(e) => {
                if started.elapsed() > Duration::from_secs(5) {
                    say!("waiting for the server at {}: {}", client.base, describe(e));
                }
                pause(stop, delay);
                delay = (delay * 2).min(Duration::from_secs(5));
            }
        }
    }
}

pub fn work(opts: WorkOptions) -> Result<()> {
    let (base, note) =
        tessera::protocol::server_base_url(&opts.server).map_err(|e| anyhow!("--server: {e}"))?;
    if let Some(note) = note {
        say!("{note}");
    }
    // The server's name is looked up on a thread of its own and its last addresses kept
    // (crate::resolve): a name server that stops answering for a while must not stall the
    // heartbeats, as glibc's lookup on the calling thread did (5 s a try, no timeout of ureq's).
    let connect = Duration::from_secs(10);
    let agent = ureq::AgentBuilder::new()
        .resolver(crate::resolve::CachingResolver::new(connect))
        .timeout_connect(connect)
        .timeout(Duration::from_secs(120))
        .build();
    let client = Client { base, token: opts.token.clone(), secret: String::new(), agent };
    let mut pool = rayon::ThreadPoolBuilder::new();
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    match opts.threads {
        Some(n) if n > MAX_WORKER_THREADS as usize => {
            bail!(
                "--threads {n} is more than a farm worker may use ({MAX_WORKER_THREADS}); run several workers instead"
            )
        }
        Some(n) => pool = pool.num_threads(n),
        // A machine of more cores than one worker may declare runs that many threads.
        None => pool = pool.num_threads(cores.min(MAX_WORKER_THREADS as usize)),
    }
    let pool = pool.build().context("cannot start the render threads")?;
    let stop = stop_flag()?;
    let Some(reg) = register(&client, &opts.name, pool.current_num_threads() as u32, &opts.tags, &stop)?
    else {
        say!("stopped before the server answered");
        return Ok(());
    };
    let worker_id = reg.worker_id;
    let client = Arc::new(Client { secret: reg.worker_secret.clone(), ..client });
    let heartbeat_every = heartbeat_interval(reg.heartbeat_seconds)?;
    let heartbeat_limit = heartbeat_timeout(reg.lease_seconds);
    say!(
        "worker {} ({}, {} threads{}) registered with {}",
        worker_id,
        opts.name,
        pool.current_num_threads(),
        if opts.tags.is_empty() { String::new() } else { format!(", tags {}", opts.tags.join(",")) },
        client.base
    );
    let kept = opts.files.stats();
    say!(
        "file cache {}: {} file(s), {} of {} MiB; mesh cache {} MiB",
        opts.files.dir().display(),
        kept.files,
        kept.bytes >> 20,
        opts.files.limit_bytes() >> 20,
        opts.meshes.limit_bytes() >> 20
    );
    // A render slot per thread, each rendering a whole tile, as `tessera-worker render` renders
    // its tiles. Every core on one tile instead (its rows in parallel; one tile, or two at once)
    // left the farm at 1.09 of the CLI's CPU and 1.13-1.17 of its wall time (farmbench medians
    // of six runs, two threads); a tile per thread, 1.05 and 1.03.
    let slot_count = pool.current_num_threads();
    let leases = Arc::new(Mutex::new(Leases::new(slot_count)));

    // Heartbeats.
    {
        let (client, leases) = (client.clone(), leases.clone());
        std::thread::Builder::new().name("heartbeat".into()).spawn(move || {
            loop {
                std::thread::sleep(heartbeat_every);
                let (held, rendering) = {
                    let l = lock(&leases);
                    (l.held.iter().copied().collect::<Vec<_>>(), l.shown())
                };
                match client.post_json_within(
                    "/api/v1/worker/heartbeat",
                    &HeartbeatRequest { worker_id, leases: held, rendering },
                    Some(heartbeat_limit),
                ) {
                    Ok(resp) => {
                        if let Ok(hb) = resp.into_json::<HeartbeatResponse>() {
                            let mut l = lock(&leases);
                            for r in hb.revoked {
                                l.revoke(r);
                            }
                        }
                    }
                    Err(e) => say!("heartbeat: {}", describe(e)),
                }
            }
        })?;
    }

    // The watcher: a long poll on the leases being rendered.
    {
        let (client, leases, stop) = (client.clone(), leases.clone(), stop.clone());
        std::thread::Builder::new()
            .name("watcher".into())
            .spawn(move || watch_rendering(&client, worker_id, &leases, &stop))?;
    }

    // The fetcher: one lease ahead.
    let (tx, rx): (SyncSender<Lease>, Receiver<Lease>) = sync_channel(0);
    {
        let (client, leases, stop) = (client.clone(), leases.clone(), stop.clone());
        std::thread::Builder::new()
            .name("fetcher".into())
            .spawn(move || fetch_leases(&client, worker_id, &leases, &tx, &stop))?;
    }

    // Uploads run beside the rendering, so the cores start the next tile at once; the lease
    // stays held (and heartbeated) until its upload is answered.
    let (up_tx, up_rx) = sync_channel::<(u64, Vec<u8>, f64)>(2);
    let uploader = {
        let (client, leases) = (client.clone(), leases.clone());
        std::thread::Builder::new().name("uploader".into()).spawn(move || {
            for (id, px, seconds) in up_rx {
                upload(&client, worker_id, id, &px, seconds);
                lock(&leases).held.remove(&id);
            }
        })?
    };

    let scenes: Mutex<HashMap<SceneKey, Arc<Scene>>> = Mutex::new(HashMap::new());
    // Tiles taken so far, for `max_tiles`.
    let taken = std::sync::atomic::AtomicU64::new(0);
    let rx = Mutex::new(rx);
    let slots = Slots {
        client: &client,
        worker_id,
        leases: &leases,
        stop: &stop,
        pool: &pool,
        scenes: &scenes,
        caches: Caches { files: &opts.files, meshes: &opts.meshes },
        taken: &taken,
        max_tiles: opts.max_tiles,
        rx: &rx,
        announced: AtomicBool::new(false),
    };
    let ended: Vec<Result<()>> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..slot_count)
            .map(|slot| {
                let (slots, up_tx) = (&slots, up_tx.clone());
                std::thread::Builder::new().name(format!("slot-{slot}")).spawn_scoped(scope, move || {
                    // However a slot ends (stopped, an error, a panic), the others stop too:
                    // the worker is ending, and they are joined below.
                    let _ending = StopOnDrop(slots.stop);
                    slots.run(slot, up_tx)
                })
            })
            .collect();
        if handles.iter().any(|h| h.is_err()) {
            // A slot could not start: the others end too, and the error is returned.
            stop.store(true, Ordering::SeqCst);
        }
        handles
            .into_iter()
            .map(|h| match h {
                Ok(h) => {
                    h.join().unwrap_or_else(|_| Err(anyhow!("a render slot panicked (a bug in Tessera)")))
                }
                Err(e) => Err(anyhow!("cannot start a render slot: {e}")),
            })
            .collect()
    });
    let rx = rx.into_inner().unwrap_or_else(|e| e.into_inner());
    stop.store(true, Ordering::SeqCst);
    // Finish the uploads in flight, then give back what was fetched ahead.
    drop(up_tx);
    let _ = uploader.join();
    give_back(&client, worker_id, &leases, &rx);
    ended.into_iter().collect()
}

/// Raises the stop flag when dropped (also while unwinding).
struct StopOnDrop<'a>(&'a AtomicBool);

impl Drop for StopOnDrop<'_> {
    fn drop(&mut self) {
        self.0.store(true, Ordering::SeqCst);
    }
}

/// The worker's caches: job files on disk by SHA-256, and built meshes, images and world trees
/// in memory by content, shared by every frame and job this worker renders.
#[derive(Clone, Copy)]
pub struct Caches<'a> {
    pub files: &'a crate::filecache::FileCache,
    pub meshes: &'a tessera::scene::cache::MeshCache,
}

/// What the render slots share.
struct Slots<'a> {
    client: &'a Client,
    worker_id: u64,
    leases: &'a Mutex<Leases>,
    stop: &'a AtomicBool,
    pool: &'a rayon::ThreadPool,
    scenes: &'a Mutex<HashMap<SceneKey, Arc<Scene>>>,
    caches: Caches<'a>,
    taken: &'a std::sync::atomic::AtomicU64,
    max_tiles: Option<u64>,
    rx: &'a Mutex<Receiver<Lease>>,
    /// Whether "stopping" was said.
    announced: AtomicBool,
}

impl Slots<'_> {
    /// Says once, from the first slot that sees the flag, that the worker is stopping.
    fn stopping(&self) {
        if !self.announced.swap(true, Ordering::SeqCst) {
            say!("stopping: no new tiles");
        }
    }

    /// Render slot `slot`: takes the next lease, renders it on this thread, hands the tile to
    /// the uploader (or reports its failure); until the worker stops or has taken `max_tiles`.
    fn run(&self, slot: usize, up_tx: SyncSender<(u64, Vec<u8>, f64)>) -> Result<()> {
        let (client, worker_id, leases, stop) = (self.client, self.worker_id, self.leases, self.stop);
        loop {
            if stop.load(Ordering::SeqCst) {
                self.stopping();
                return Ok(());
            }
            let next = {
                // One slot waits on the channel at a time; the others wait for it here, and look
                // at the flag again once they get their turn.
                let rx = lock(self.rx);
                if stop.load(Ordering::SeqCst) {
                    self.stopping();
                    return Ok(());
                }
                rx.recv_timeout(Duration::from_millis(200))
            };
            let lease = match next {
                Ok(lease) => lease,
                Err(RecvTimeoutError::Timeout) => continue,
                Err(RecvTimeoutError::Disconnected) => return Ok(()),
            };
            let over = self.max_tiles.is_some_and(|m| self.taken.fetch_add(1, Ordering::SeqCst) >= m);
            if stop.load(Ordering::SeqCst) || over {
                // The signal (or the last tile wanted) came while this lease was on its way: it
                // was never started.
                release(client, worker_id, leases, lease.lease_id);
                stop.store(true, Ordering::SeqCst);
                return Ok(());
            }
            let id = lease.lease_id;
            let cancel = {
                let mut l = lock(leases);
                l.rendering[slot] = Some(id);
                l.cancel[slot] = Arc::new(AtomicBool::new(false));
                // Revoked while it waited in the channel: start it only to drop it at once.
                if l.revoked.contains(&id) {
                    l.cancel[slot].store(true, Ordering::SeqCst);
                }
                l.cancel[slot].clone()
            };
            let started = Instant::now();
            let rendered = if cancel.load(Ordering::SeqCst) {
                Ok(None)
            } else {
                lease_scene(client, self.scenes, self.caches, self.pool, &lease)
                    .and_then(|scene| render_lease(&scene, &lease, &cancel))
            };
            let seconds = started.elapsed().as_secs_f64();
            let revoked = {
                let mut l = lock(leases);
                l.rendering[slot] = None;
                l.revoked.remove(&id)
            };
            if revoked {
                say!("lease {id} was revoked while rendering; dropping the tile");
                lock(leases).held.remove(&id);
                continue;
            }
            match rendered {
                // Only a revocation raises the flag, and that was handled above.
                Ok(None) => {
                    lock(leases).held.remove(&id);
                }
                Ok(Some(px)) => {
                    if up_tx.send((id, px, seconds)).is_err() {
                        bail!("the upload thread ended");
                    }
                }
                Err(e) => {
                    say!("tile {} of job {} failed: {e:#}", lease.tile, lease.job_id);
                    let fatal = e.downcast_ref::<OutOfTime>().is_some();
                    let req = FailRequest { worker_id, error: format!("{e:#}"), fatal };
                    if let Err(e) = client.post_json(&format!("/api/v1/worker/leases/{id}/fail"), &req) {
                        say!("reporting the failure: {}", describe(e));
                    }
                    lock(leases).held.remove(&id);
                }
            }
            if self.max_tiles.is_some_and(|m| self.taken.load(Ordering::SeqCst) >= m) {
                stop.store(true, Ordering::SeqCst);
                return Ok(());
            }
        }
    }
}

/// How long a stopping worker waits for a long poll in flight to come back (a lease it brings
/// is given back too); after that the worker exits and such a lease expires on the server.
const STOP_WAIT: Duration = Duration::from_secs(3);

/// Gives back the lease the fetcher holds (and one its poll in flight may still bring).
fn give_back(client: &Client, worker_id: u64, leases: &Mutex<Leases>, rx: &Receiver<Lease>) {
    let deadline = Instant::now() + STOP_WAIT;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match rx.recv_timeout(left) {
            Ok(lease) => {
                release(client, worker_id, leases, lease.lease_id);
            }
            // The fetcher saw the flag and ended, or is still in a long poll: done either way.
            Err(_) => return,
        }
    }
}

/// Gives lease `lease` back to the server, and forgets it here.
fn release(client: &Client, worker_id: u64, leases: &Mutex<Leases>, lease: u64) {
    lock(leases).held.remove(&lease);
    match client.post_json(&format!("/api/v1/worker/leases/{lease}/release"), &ReleaseRequest { worker_id }) {
        Ok(_) => say!("gave back lease {lease}"),
        Err(e) => say!("giving back lease {lease}: {}", describe(e)),
    }
}

/// Long-polls for leases until told to stop, handing each to the renderer (blocking while it is
/// busy, so exactly one lease waits ahead). A lease that arrives after the stop is given back.
fn fetch_leases(
    client: &Client,
    worker_id: u64,
    leases: &Mutex<Leases>,
    tx: &SyncSender<Lease>,
    stop: &AtomicBool,
) {
    let mut delay = Duration::from_millis(200);
    loop {
        if stop.load(Ordering::SeqCst) {
            return;
        }
        if !lock(leases).may_lease() {
            // A finished tile still uploading holds its lease: wait for the upload's answer.
            std::thread::sleep(Duration::from_millis(5));
            continue;
        }
        match client.post_json("/api/v1/worker/lease", &LeaseRequest { worker_id, wait_seconds: 20.0 }) {
            Ok(resp) if resp.status() == 200 => {
                delay = Duration::from_millis(200);
                match resp.into_json::<Lease>() {
                    Ok(lease) => {
                        if stop.load(Ordering::SeqCst) {
                            release(client, worker_id, leases, lease.lease_id);
                            return;
                        }
                        lock(leases).held.insert(lease.lease_id);
                        if let Err(e) = tx.send(lease) {
                            // The renderer is gone (it stopped): nobody will render this one.
                            release(client, worker_id, leases, e.0.lease_id);
                            return;
                        }
                    }
                    Err(e) => say!("lease: the answer is not valid JSON: {e}"),
                }
            }
            Ok(_) => {} // 204: no work yet; ask again.
            Err(ureq::Error::Status(404, _)) => {
                // The server forgot this worker (a new data directory): nothing sensible to do
                // but stop; a supervisor restarts and registers again.
                say!("the server does not know worker {worker_id} any more; exiting");
                std::process::exit(3);
            }
            Err(ureq::Error::Status(401, r)) => {
                // The token changed, or the server no longer takes this worker's secret (it
                // registered with an older server): a restart registers again.
                say!(
                    "the server refuses worker {worker_id}: {}; exiting",
                    describe(ureq::Error::Status(401, r))
                );
                std::process::exit(3);
            }
            Err(_) if stop.load(Ordering::SeqCst) => return,
            Err(e) => {
                say!("lease: {}", describe(e));
                pause(stop, delay);
                delay = (delay * 2).min(Duration::from_secs(5));
            }
        }
    }
}

/// How long the watcher asks the server to hold a watch open.
const WATCH_SECONDS: f64 = 15.0;

/// Keeps a long poll open on the leases being rendered, and raises a tile's stop flag as soon
/// as the server says its lease was revoked. Idle (nothing rendering) it looks again every
/// 50 ms; after an error (an older server without the endpoint, a restart) it backs off up to
/// 30 s, and the heartbeat still revokes, only later.
///
/// A watch names the leases rendering when it was sent; a slot that starts a tile meanwhile
/// is not in it. The server answers a watch whenever a job is cancelled or fails if any lease
/// it names has ended, and one has: the slot's previous tile, whose lease was uploaded or
/// revoked. The next watch then names the new tile.
fn watch_rendering(client: &Client, worker_id: u64, leases: &Mutex<Leases>, stop: &AtomicBool) {
    let mut delay = Duration::from_secs(1);
    loop {
        let watched: Vec<u64> = lock(leases).rendering.iter().flatten().copied().collect();
        if watched.is_empty() {
            if stop.load(Ordering::SeqCst) {
                return;
            }
            std::thread::sleep(Duration::from_millis(50));
            continue;
        }
        let req = WatchRequest { worker_id, leases: watched.clone(), wait_seconds: WATCH_SECONDS };
        match client.post_json("/api/v1/worker/watch", &req) {
            Ok(resp) => {
                delay = Duration::from_secs(1);
                if let Ok(answer) = resp.into_json::<HeartbeatResponse>() {
                    let mut l = lock(leases);
                    // The server also lists leases that ended because their tiles were
                    // uploaded meanwhile; only those still rendering are stopped.
                    for id in answer.revoked {
                        if l.rendering.contains(&Some(id)) {
                            l.revoke(id);
                        }
                    }
                }
            }
            Err(e) => {
                if stop.load(Ordering::SeqCst) {
                    return;
                }
                say!("watching leases {watched:?}: {}", describe(e));
                std::thread::sleep(delay);
                delay = (delay * 2).min(Duration::from_secs(30));
            }
        }
    }
}

/// A built scene's key: the job's files (manifest or bundle), the scene file, and the bits of
/// the job's `scale` (its cameras are scaled; 0: none).
type SceneKey = (String, String, u64);

/// The scene of `lease`, built (on `pool`) if its bundle is new here. Called on a slot's own
/// thread, never on the pool: the cache's lock is held while a scene is built, so the other
/// slot, most likely rendering the same job, waits for it instead of building it again, and a
/// pool thread that steals work while it waits must never be one that wants the lock.
fn lease_scene(
    client: &Client,
    scenes: &Mutex<HashMap<SceneKey, Arc<Scene>>>,
    caches: Caches<'_>,
    pool: &rayon::ThreadPool,
    lease: &Lease,
) -> Result<Arc<Scene>> {
    // As the server validated the job: unsupported elements only if its submission allowed them.
    let options = LoadOptions { allow_unsupported: lease.allow_unsupported };
    // A job's files are its manifest's (or, stored before sequences, its bundle's).
    let key = (
        lease.manifest.clone().unwrap_or_else(|| lease.bundle.clone()),
        lease.scene_path.clone(),
        lease.scale.map_or(0, f64::to_bits),
    );
    let mut scenes = lock(scenes);
    Ok(match scenes.get(&key) {
        Some(s) => {
            // Built for another job of the same bundle, which may have allowed what this one does not.
            options.check(&s.warnings).map_err(BundleSceneError::Unsupported)?;
            s.clone()
        }
        None => {
            let started = Instant::now();
            let mut s = pool.install(|| match &lease.manifest {
                Some(manifest) => {
                    crate::jobfiles::manifest_scene(client, caches, manifest, &lease.scene_path, options)
                }
                None => fetch_bundle_scene(client, caches.meshes, &lease.bundle, &lease.scene_path, options),
            })?;
            // A line a scene built: what the caches saved (a sequence's frames after its first
            // build their meshes from the cache, or fetch nothing at all).
            let st = &s.stats;
            say!(
                "job {}: {} built in {:.3} s ({} mesh(es) from the cache, {:.3} s building meshes{})",
                lease.job_id,
                lease.scene_path,
                started.elapsed().as_secs_f64(),
                st.meshes_cached,
                st.mesh_seconds,
                if st.world_tree_cached { ", world tree from the cache" } else { "" }
            );
            // A job at a `scale` renders its cameras so (the server cut its tiles so).
            if let Some(scale) = lease.scale {
                let scale =
                    tessera::camera::check_scale(scale).map_err(|e| anyhow!("the lease's scale {e}"))?;
                s.cameras = s.cameras.iter().map(|c| c.scaled(scale)).collect();
            }
            let s = Arc::new(s);
            // Keep a few scenes; jobs rarely interleave more.
            if scenes.len() >= 4 {
                scenes.clear();
            }
            scenes.insert(key, s.clone());
            s
        }
    })
}

/// Renders the tile of `lease` on the calling thread (a render slot), as the bytes to upload
/// (with its denoising features when the lease asks for them). `None` when `cancel` was raised
/// (the lease was revoked) before the tile was done.
fn render_lease(scene: &Scene, lease: &Lease, cancel: &AtomicBool) -> Result<Option<Vec<u8>>> {
    let cam = scene
        .cameras
        .get(lease.camera as usize)
        .ok_or_else(|| anyhow!("the scene has no camera {}", lease.camera))?;
    let r = lease.rect;
    if r.width == 0 || r.height == 0 || r.x0 + r.width > cam.width || r.y0 + r.height > cam.height {
        bail!("tile {:?} lies outside the {}x{} frame", r, cam.width, cam.height);
    }
    let settings = RenderSettings { samples: lease.samples, ..RenderSettings::default() };
    let camera = lease.camera as usize;
    let limit = lease.max_render_seconds.filter(|s| s.is_finite() && *s > 0.0);
    let stop = Stop {
        flag: Some(cancel),
        deadline: limit.and_then(|s| Instant::now().checked_add(Duration::from_secs_f64(s.min(1e9)))),
    };
    // The whole tile on this thread; a panic is a bug, reported instead of ending the worker.
    let n = samples_per_pixel(scene, camera, &settings);
    if let Some(p) = lease.pass
        && (p.start % BLOCK != 0 || p.start >= p.end || p.end > n || (lease.aux && p.start != 0))
    {
        bail!("pass {p:?} is not a range of whole blocks of this frame's {n} samples");
    }
    let rendered = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let rect = TileRect::from(r);
        if let Some(p) = lease.pass {
            let range = SampleRange { start: p.start, end: p.end };
            let mut aux = lease.aux.then(AuxTile::default);
            render_tile_sums_until(scene, camera, rect, &settings, range, stop, aux.as_mut()).map(
                |(sums, _)| {
                    encode_pass_tile(&sums, aux.as_ref().map(|a| (a.albedo.as_slice(), a.normal.as_slice())))
                },
            )
        } else if lease.aux {
            render_tile_with_aux_until(scene, camera, rect, &settings, stop)
                .map(|(px, aux, _)| encode_tile_with_aux(&px, &aux.albedo, &aux.normal))
        } else {
            render_tile_until(scene, camera, rect, &settings, stop).map(|(px, _)| encode_tile(&px))
        }
    }))
    .map_err(|_| {
        anyhow!("the renderer panicked on this tile (a bug in Tessera; please report it with the scene)")
    })?;
    match rendered {
        Ok(px) => Ok(Some(px)),
        Err(Stopped::Cancelled) => Ok(None),
        Err(Stopped::OutOfTime) => Err(OutOfTime { seconds: limit.unwrap_or_default() }.into()),
    }
}

/// A tile went over the lease's `max_render_seconds`.
#[derive(Debug)]
struct OutOfTime {
    seconds: f64,
}

impl std::fmt::Display for OutOfTime {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "the tile did not finish within {} s, this farm's longest render of one tile (the server's \
             --max-tile-seconds, TESSERA_MAX_TILE_SECONDS); submit with a smaller tile_size or fewer samples, \
             or ask the farm's operator to raise the limit",
            self.seconds
        )
    }
}

impl std::error::Error for OutOfTime {}

/// Fetches the bundle `bundle` and builds its scene `scene_path` (the server's validation built
/// it the same way).
fn fetch_bundle_scene(
    client: &Client,
    meshes: &tessera::scene::cache::MeshCache,
    bundle: &str,
    scene_path: &str,
    options: LoadOptions,
) -> Result<Scene> {
    let resp = client
        .agent
        .get(&client.url(&format!("/api/v1/worker/bundles/{bundle}")))
        .set("Authorization", &format!("Bearer {}", client.token))
        .call()
        .map_err(|e| anyhow!("fetching bundle {bundle}: {}", describe(e)))?;
    let mut tar = Vec::new();
    resp.into_reader().read_to_end(&mut tar).context("downloading the bundle")?;
    let files = read_tar(&tar).context("reading the bundle")?;
    Ok(load_bundle_scene_cached(files, scene_path, options, Some(meshes))?)
}

/// Uploads a tile, retrying transport errors; a 409 means the lease is gone: drop the tile.
fn upload(client: &Client, worker_id: u64, lease: u64, body: &[u8], seconds: f64) {
    let sum = checksum(body);
    let mut delay = Duration::from_millis(200);
    for _ in 0..8 {
        let res = client
            .agent
            .put(&client.url(&format!("/api/v1/worker/leases/{lease}/result")))
            .set("Authorization", &format!("Bearer {}", client.token))
            .set(WORKER_SECRET_HEADER, &client.secret)
            .set("x-tessera-worker", &worker_id.to_string())
            .set(CHECKSUM_HEADER, &sum)
            .set(RENDER_SECONDS_HEADER, &format!("{seconds:.6}"))
            .set("Content-Type", "application/octet-stream")
            .send_bytes(body);
        match res {
            Ok(_) => return,
            Err(ureq::Error::Status(409, _)) => {
                say!("lease {lease} expired or was revoked before the upload; the tile is dropped");
                return;
            }
            Err(ureq::Error::Status(code, r)) if code < 500 => {
                say!("the server refused tile of lease {lease}: {}", describe(ureq::Error::Status(code, r)));
                return;
            }
            Err(e) => {
                say!("uploading lease {lease}: {}; retrying", describe(e));
                std::thread::sleep(delay);
                delay = (delay * 2).min(Duration::from_secs(5));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_heartbeat_is_given_up_while_the_lease_has_time_for_the_next() {
        assert_eq!(heartbeat_timeout(30.0), Duration::from_secs(10));
        assert_eq!(heartbeat_timeout(0.5), Duration::from_secs(1));
        assert_eq!(heartbeat_timeout(86_400.0), Duration::from_secs(120));
        assert_eq!(heartbeat_timeout(f64::INFINITY), Duration::from_secs(120));
        for odd in [0.0, -1.0, f64::NAN] {
            assert_eq!(heartbeat_timeout(odd), Duration::from_secs(10), "{odd}");
        }
    }

    #[test]
    fn a_heartbeat_period_the_worker_cannot_keep_is_an_error_not_a_panic() {
        assert_eq!(heartbeat_interval(5.0).unwrap(), Duration::from_secs(5));
        assert_eq!(heartbeat_interval(0.001).unwrap(), Duration::from_millis(1));
        // A server with a lease of days may ask for a heartbeat every day or more.
        assert_eq!(heartbeat_interval(100_000.0).unwrap(), Duration::from_secs(100_000));
        assert_eq!(heartbeat_interval(1e9).unwrap(), Duration::from_secs(1_000_000_000));
        for bad in [0.0, -1.0, 1e-10, 0.000_999, 1.000_001e9, 1e300, f64::NAN, f64::INFINITY] {
            let e = heartbeat_interval(bad).unwrap_err().to_string();
            assert!(e.contains("heartbeat_seconds") && e.contains("--heartbeat-seconds"), "{bad}: {e}");
        }
    }
}
