//! What the server's parts share while it runs: its settings, the store, the blobs, the
//! scheduler, the cache of jobs' cameras and the event channel. The HTTP handlers (`api`) and the
//! merging of finished frames (`merge`) both work on an [`AppState`]; neither depends on the
//! other for it.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;

use tessera::camera::Camera;
use tessera::protocol::ServerEvent;

use crate::bundle::{self, BlobStore};
use crate::db::Store;
use crate::scheduler::{Scheduler, Timing};

/// Settings the handlers need (the scheduler's are its [`Timing`]).
#[derive(Clone, Debug)]
pub struct Settings {
    pub data_dir: PathBuf,
    pub tile_size: u32,
    /// `None`: the job API is open (loopback only; `main` enforces that).
    pub api_token: Option<String>,
    pub worker_token: String,
    pub max_upload_bytes: usize,
    /// Caps on what an upload unpacks to.
    pub bundle_limits: bundle::Limits,
    /// Most tiles one job may be cut into.
    pub max_job_tiles: u64,
    /// Most frames one job may render (`--max-job-frames`).
    pub max_job_frames: usize,
    /// Most samples (pixels x samples per pixel over all frames) one job may ask for.
    pub max_job_samples: u64,
    /// Who besides the farm's own pages and addresses may reach it, and whether `/metrics` is
    /// public.
    pub access: Access,
    /// Most units of work (tiles x passes over all frames) one job may be.
    pub max_job_units: u64,
    /// Most live registered workers (the local workers register past it).
    pub max_workers: u64,
    /// The token of the server's own local workers, which the registration limits let through.
    pub local_worker_token: String,
    /// URL prefixes a job's own `notify_url` must start with (`--notify-allow`).
    pub notify_allow: Vec<String>,
    /// Seconds of silence after which a worker is forgotten (`--forget-workers-after`, never
    /// less than it takes to count as lost): it leaves the workers list at once, its row when
    /// housekeeping next runs.
    pub forget_workers_after: f64,
    /// Which finished jobs the housekeeping removes (`--keep-finished-days`, `--disk-budget-mb`).
    pub retention: Retention,
}

/// Which finished jobs the housekeeping removes (`None`: that rule is off); made by
/// `retention::policy`, applied by `retention::apply`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Retention {
    /// Finished jobs that ended longer ago than this, in seconds, are removed.
    pub keep_finished_seconds: Option<f64>,
    /// The oldest finished jobs are removed while the jobs' outputs take more bytes than this.
    pub disk_budget_bytes: Option<u64>,
}

impl Retention {
    pub fn is_off(&self) -> bool {
        self.keep_finished_seconds.is_none() && self.disk_budget_bytes.is_none()
    }
}

/// What browsers and scrapers may reach (`--allowed-origin`, `--allowed-host`,
/// `--public-metrics`); the checks are in `api::browser`.
#[derive(Clone, Debug, Default)]
pub struct Access {
    /// Origins (`scheme://host[:port]`, as `api::browser::normalize_origin` writes them) besides
    /// the farm's own whose pages may send it state-changing requests.
    pub allowed_origins: Vec<String>,
    /// Host names answered besides IP literals and `localhost` (lowercase, no trailing dot).
    pub allowed_hosts: Vec<String>,
    /// `--allowed-host '*'`: every `Host` is answered.
    pub any_host: bool,
    /// `/metrics` without the API token.
    pub public_metrics: bool,
}

/// Videos encoded at the same time (`video::make_video`), and the jobs whose video is being
/// made, so that a second trigger of a job's last frame does not encode it twice.
#[derive(Clone)]
pub struct Videos {
    pub gate: Arc<tokio::sync::Semaphore>,
    pub busy: Arc<std::sync::Mutex<std::collections::HashSet<u64>>>,
}

impl Default for Videos {
    fn default() -> Self {
        Videos { gate: Arc::new(tokio::sync::Semaphore::new(1)), busy: Arc::default() }
    }
}

/// Everything a handler or a merge works on; cloning it shares the same store, scheduler,
/// cache and channel.
#[derive(Clone)]
pub struct AppState {
    pub store: Arc<Store>,
    pub blobs: BlobStore,
    /// Every job file once, by SHA-256 (`files.rs`).
    pub files: crate::files::FileStore,
    pub settings: Arc<Settings>,
    /// Leasing, failures, expiry and revocation: the scheduling rules.
    pub scheduler: Scheduler,
    /// Each frame's camera per job ([`AppState::frame_cameras`]), for merging and previews.
    pub cameras: Arc<std::sync::Mutex<HashMap<u64, Arc<Vec<Camera>>>>>,
    /// Pushed to the status page (server-sent events); nobody listening is fine.
    pub events: tokio::sync::broadcast::Sender<ServerEvent>,
    /// Uploads being unpacked and validated at once (each holds its files in memory).
    pub unpacking: Arc<tokio::sync::Semaphore>,
    /// Previews and re-tone-mappings made at once (each holds a picture in memory).
    pub previews: Arc<tokio::sync::Semaphore>,
    /// Frames merged at once (each holds its whole float frame in memory).
    pub merging: Arc<tokio::sync::Semaphore>,
    /// Frames whose merge found the disk full, tried again until it has room
    /// (`merge::retry_when_space_returns`); `true` once the job's log says so.
    pub waiting_for_space: Arc<std::sync::Mutex<HashMap<(u64, u32), bool>>>,
    /// Registrations with the worker token (a rate; the local workers' are not counted).
    pub registrations: Arc<crate::registrations::TokenBucket>,
    /// Videos being made (one at a time; `video.rs`).
    pub videos: Videos,
}

impl AppState {
    /// The state of a server over `store` and `blobs`; its scheduler runs on `timing`.
    pub fn new(store: Arc<Store>, blobs: BlobStore, settings: Settings, timing: Timing) -> AppState {
        let events = tokio::sync::broadcast::channel(1024).0;
        AppState {
            scheduler: Scheduler::new(store.clone(), timing, events.clone()),
            store,
            blobs,
            files: crate::files::FileStore::at(&settings.data_dir),
            settings: Arc::new(settings),
            cameras: Arc::default(),
            events,
            unpacking: Arc::new(tokio::sync::Semaphore::new(crate::UNPACKING_AT_ONCE)),
            previews: Arc::new(tokio::sync::Semaphore::new(crate::PREVIEWS_AT_ONCE)),
            merging: Arc::new(tokio::sync::Semaphore::new(crate::MERGES_AT_ONCE)),
            waiting_for_space: Arc::default(),
            registrations: Arc::new(crate::registrations::TokenBucket::registrations()),
            videos: Videos::default(),
        }
    }

    pub fn emit(&self, e: ServerEvent) {
        let _ = self.events.send(e);
    }

    /// Where the output files of a job's frame are written: `outputs/JOB/FRAME/`. It holds the
    /// outputs only (any name can be an output: it comes from the scene's `ImageName`).
    pub fn frame_dir(&self, job: u64, frame: u32) -> PathBuf {
        self.settings.data_dir.join(crate::storage::OUTPUTS_DIR).join(job.to_string()).join(frame.to_string())
    }

    /// Where the server keeps its own files of a job's frame, apart from the outputs so that
    /// no output name can meet them: `frames/JOB/FRAME/` (the pass files, the preview).
    pub fn server_frame_dir(&self, job: u64, frame: u32) -> PathBuf {
        self.settings.data_dir.join(crate::storage::FRAMES_DIR).join(job.to_string()).join(frame.to_string())
    }

    /// The camera of each frame of a job, by frame index: the frame's camera in the frame's
    /// scene file (a sequence's frames come from several). Parsed from the job's files once
    /// (no asset is read, no geometry built) and cached.
    pub fn frame_cameras(&self, job: &crate::db::JobRow) -> anyhow::Result<Arc<Vec<Camera>>> {
        if let Some(c) = self.cameras.lock().unwrap_or_else(|e| e.into_inner()).get(&job.id) {
            return Ok(c.clone());
        }
        let frames = self.store.frames(job.id)?;
        let cameras = Arc::new(self.read_frame_cameras(job, &frames)?);
        self.cameras.lock().unwrap_or_else(|e| e.into_inner()).insert(job.id, cameras.clone());
        Ok(cameras)
    }

    fn read_frame_cameras(
        &self,
        job: &crate::db::JobRow,
        frames: &[crate::db::FrameRow],
    ) -> anyhow::Result<Vec<Camera>> {
        use anyhow::Context;
        // The cameras of each scene file, by path.
        let mut by_scene: HashMap<String, Vec<Camera>> = HashMap::new();
        match &job.manifest {
            None => {
                let tar = self
                    .blobs
                    .get(&job.bundle)
                    .ok_or_else(|| anyhow::anyhow!("bundle {} of job {} is missing", job.bundle, job.id))?;
                let files = tessera::bundle::read_tar(&tar)?;
                by_scene.insert(
                    job.scene_path.clone(),
                    tessera::bundle::bundle_cameras(&files, &job.scene_path)?,
                );
            }
            Some(sha) => {
                let manifest: tessera::protocol::Manifest = serde_json::from_slice(
                    &self
                        .files
                        .read(sha)
                        .with_context(|| format!("the manifest of job {} is missing", job.id))?,
                )
                .with_context(|| format!("the manifest of job {} does not parse", job.id))?;
                let shas: HashMap<&str, &str> =
                    manifest.files.iter().map(|f| (f.path.as_str(), f.sha256.as_str())).collect();
                for f in frames {
                    let scene = f.scene_path.as_deref().unwrap_or(&job.scene_path);
                    if by_scene.contains_key(scene) {
                        continue;
                    }
                    let sha = shas
                        .get(scene)
                        .ok_or_else(|| anyhow::anyhow!("job {}: {scene} is not in its manifest", job.id))?;
                    let bytes = self
                        .files
                        .read(sha)
                        .with_context(|| format!("job {}: {scene} is missing", job.id))?;
                    let files = tessera::bundle::BundleFiles::from([(scene.to_string(), Arc::new(bytes))]);
                    by_scene.insert(scene.to_string(), tessera::bundle::bundle_cameras(&files, scene)?);
                }
            }
        }
        frames
            .iter()
            .map(|f| {
                let scene = f.scene_path.as_deref().unwrap_or(&job.scene_path);
                by_scene
                    .get(scene)
                    .and_then(|c| c.get(f.camera as usize))
                    .map(|c| job.scale.map_or_else(|| c.clone(), |s| c.scaled(s)))
                    .ok_or_else(|| anyhow::anyhow!("job {}: {scene} has no camera {}", job.id, f.camera))
            })
            .collect()
    }
}
