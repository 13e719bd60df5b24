//! The HTTP API: the job API for people (curl, the web page) and the worker protocol
//! (`tessera::protocol`), both JSON under `/api/v1`, plus `/healthz` and `/metrics`.
//!
//! [`app`] builds the router from an [`AppState`]; handlers do database work under a short
//! mutex and push CPU work (scene validation, merging, tone mapping, PNG encoding) to
//! `spawn_blocking`. Every error is an [`AppError`] answered as `{"error", "problems"}` JSON with
//! a fitting status; internal details go to the log, not to the client.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use axum::body::Bytes;
use axum::extract::{DefaultBodyLimit, Multipart, Path, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post, put};
use axum::{Json, Router};
use tessera::assets::MemResolver;
use tessera::camera::Camera;
use tessera::protocol::*;
use tessera::scene::build::build_scene;
use tessera::scene::load::parse_scene;
use tokio::sync::Notify;

use crate::bundle::{self, BlobStore, BundleError, Files, Unpacker};
use crate::db::{FailOutcome, ResultOutcome, Store};
use crate::merge;

/// Settings the handlers need.
#[derive(Clone, Debug)]
pub struct Settings {
    pub data_dir: PathBuf,
    pub tile_size: u32,
    /// `None`: the job API is open (loopback only; `main` enforces that).
    pub api_token: Option<String>,
    pub worker_token: String,
    pub lease_seconds: f64,
    pub heartbeat_seconds: f64,
    /// Longest a lease request is held open.
    pub max_wait_seconds: f64,
    pub max_upload_bytes: usize,
    /// Caps on what an upload unpacks to.
    pub bundle_limits: bundle::Limits,
    /// Most tiles one job may be cut into.
    pub max_job_tiles: u64,
    /// Longest one tile may render (sent with every lease).
    pub max_tile_seconds: f64,
    /// Most samples (pixels x samples per pixel over all frames) one job may ask for.
    pub max_job_samples: u64,
}

/// Counters that are not in the database.
#[derive(Default)]
pub struct Counters {
    pub lease_expiries: AtomicU64,
    pub results_refused: AtomicU64,
}

#[derive(Clone)]
pub struct AppState {
    pub store: Arc<Store>,
    pub blobs: BlobStore,
    pub settings: Arc<Settings>,
    /// Woken when tiles become available (a job submitted, a lease expired, a tile failed).
    pub work: Arc<Notify>,
    pub counters: Arc<Counters>,
    /// Built cameras per job (parsed once from the bundle), for merging and previews.
    pub cameras: Arc<std::sync::Mutex<HashMap<u64, Arc<Vec<Camera>>>>>,
    /// Pushed to the status page (server-sent events); nobody listening is fine.
    pub events: tokio::sync::broadcast::Sender<ServerEvent>,
    /// Set when the server begins to shut down: no more leases, and long polls answer at once
    /// with 503 (so stopping workers are not held up by a poll that could only bring a lease to
    /// give back).
    pub shutting_down: Arc<std::sync::atomic::AtomicBool>,
    /// Uploads being unpacked and validated at once (each holds its files in memory).
    pub unpacking: Arc<tokio::sync::Semaphore>,
}

impl AppState {
    pub fn emit(&self, e: ServerEvent) {
        let _ = self.events.send(e);
    }

    /// Where the output files of a job's frame are written: `outputs/JOB/FRAME/`.
    pub fn frame_dir(&self, job: u64, frame: u32) -> PathBuf {
        self.settings.data_dir.join("outputs").join(job.to_string()).join(frame.to_string())
    }
}

// ---------------------------------------------------------------------------------------------
// Errors
// ---------------------------------------------------------------------------------------------

#[derive(Debug)]
pub struct AppError {
    pub status: StatusCode,
    pub body: ApiError,
}

impl AppError {
    pub fn new(status: StatusCode, message: impl Into<String>) -> Self {
        AppError { status, body: ApiError { error: message.into(), problems: Vec::new() } }
    }
    fn bad_request(message: impl Into<String>) -> Self {
        Self::new(StatusCode::BAD_REQUEST, message)
    }
    fn not_found(message: impl Into<String>) -> Self {
        Self::new(StatusCode::NOT_FOUND, message)
    }
}

impl From<anyhow::Error> for AppError {
    fn from(e: anyhow::Error) -> Self {
        tracing::error!("internal error: {e:#}");
        AppError::new(StatusCode::INTERNAL_SERVER_ERROR, "internal error; see the server log")
    }
}

impl IntoResponse for AppError {
    fn into_response(self) -> Response {
        (self.status, Json(self.body)).into_response()
    }
}

type ApiResult<T> = Result<T, AppError>;

// ---------------------------------------------------------------------------------------------
// Router
// ---------------------------------------------------------------------------------------------

pub fn app(state: AppState) -> Router {
    let jobs = Router::new()
        .route("/api/v1/jobs", post(submit_job).get(list_jobs))
        .route("/api/v1/jobs/{id}", get(show_job))
        .route("/api/v1/jobs/{id}/cancel", post(cancel_job))
        .route("/api/v1/jobs/{id}/frames/{frame}/preview.png", get(frame_preview))
        .route("/api/v1/jobs/{id}/frames/{frame}/files/{name}", get(frame_file))
        .route("/api/v1/jobs/{id}/frames/{frame}/tonemap.png", get(frame_tonemap))
        .route("/api/v1/workers", get(list_workers))
        .route("/api/v1/events", get(events))
        .route_layer(axum::middleware::from_fn_with_state(state.clone(), require_api_token));
    let workers = Router::new()
        .route("/api/v1/worker/register", post(register))
        .route("/api/v1/worker/lease", post(lease))
        .route("/api/v1/worker/heartbeat", post(heartbeat))
        .route("/api/v1/worker/watch", post(watch))
        .route("/api/v1/worker/leases/{lease}/result", put(result))
        .route("/api/v1/worker/leases/{lease}/fail", post(fail))
        .route("/api/v1/worker/leases/{lease}/release", post(release))
        .route("/api/v1/worker/bundles/{hash}", get(get_bundle))
        .route_layer(axum::middleware::from_fn_with_state(state.clone(), require_worker_token));
    let limit = state.settings.max_upload_bytes;
    Router::new()
        .route("/healthz", get(|| async { "ok\n" }))
        .route("/", get(|| async { crate::web::page("index.html") }))
        .route("/static/{name}", get(|Path(name): Path<String>| async move { crate::web::page(&name) }))
        .route("/metrics", get(metrics))
        .merge(jobs)
        .merge(workers)
        .fallback(|| async {
            AppError::not_found("no such endpoint; the API lives under /api/v1 (see the README)")
        })
        .layer(DefaultBodyLimit::max(limit))
        .layer(axum::middleware::map_response(no_store))
        .with_state(state)
}

/// Answers change from one moment to the next: browsers must not reuse them.
async fn no_store(mut resp: Response) -> Response {
    resp.headers_mut().entry(header::CACHE_CONTROL).or_insert(HeaderValue::from_static("no-store"));
    resp
}

fn bearer(headers: &HeaderMap) -> Option<&str> {
    headers.get(header::AUTHORIZATION)?.to_str().ok()?.strip_prefix("Bearer ").map(str::trim)
}

/// Constant-time comparison, so a token cannot be guessed byte by byte from response times.
fn same_token(a: &str, b: &str) -> bool {
    a.len() == b.len() && a.bytes().zip(b.bytes()).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

async fn require_api_token(
    State(state): State<AppState>,
    req: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    if let Some(token) = &state.settings.api_token {
        // EventSource and <img> cannot send headers: the page may pass ?access_token= instead.
        let from_query = req
            .uri()
            .query()
            .and_then(|q| q.split('&').find_map(|kv| kv.strip_prefix("access_token=")).map(str::to_string));
        let given = bearer(req.headers()).map(str::to_string).or(from_query);
        match given.as_deref() {
            Some(t) if same_token(t, token) => {}
            Some(_) => return AppError::new(StatusCode::UNAUTHORIZED, "wrong API token").into_response(),
            None => {
                return AppError::new(
                    StatusCode::UNAUTHORIZED,
                    "this server needs an API token: send the header \"Authorization: Bearer <token>\"",
                )
                .into_response();
            }
        }
    }
    next.run(req).await
}

async fn require_worker_token(
    State(state): State<AppState>,
    req: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    match bearer(req.headers()) {
        Some(t) if same_token(t, &state.settings.worker_token) => next.run(req).await,
        _ => AppError::new(StatusCode::UNAUTHORIZED, "missing or wrong worker token").into_response(),
    }
}

// ---------------------------------------------------------------------------------------------
// Jobs
// ---------------------------------------------------------------------------------------------

/// Options of a submission (multipart text fields).
#[derive(Default)]
struct SubmitOptions {
    name: Option<String>,
    priority: i64,
    tile_size: Option<u32>,
    samples: Option<u32>,
    cameras: Option<Vec<u32>>,
    scene_path: Option<String>,
}

fn problem_from(e: &tessera::SceneError) -> Problem {
    Problem {
        file: Some(e.file.display().to_string()),
        line: e.loc.line,
        element: e.loc.element.clone(),
        message: e.message.clone(),
    }
}

/// An upload's files on disk while its request is read: the multipart body is streamed into
/// `<data>/uploads/<unique>/`, never held in memory, and the folder goes when the request ends.
struct Spool {
    dir: PathBuf,
    /// (field kind, file name given, spooled file)
    parts: Vec<(SpoolKind, String, PathBuf)>,
}

#[derive(Clone, Copy, PartialEq)]
enum SpoolKind {
    File,
    Archive,
}

impl Spool {
    fn new(data_dir: &std::path::Path) -> anyhow::Result<Spool> {
        let dir = crate::bundle::unique_temp_name(&data_dir.join("uploads").join("upload"));
        std::fs::create_dir_all(&dir).map_err(|e| anyhow::anyhow!("cannot create {}: {e}", dir.display()))?;
        Ok(Spool { dir, parts: Vec::new() })
    }
}

impl Drop for Spool {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// The longest a text field (name, priority, cameras, ...) may be.
const MAX_TEXT_FIELD: usize = 64 << 10;

/// Reads the multipart fields of a submission: files are streamed into `spool` under the
/// caps, the options into `opts`.
async fn read_fields(
    state: &AppState,
    multipart: &mut Multipart,
    spool: &mut Spool,
    opts: &mut SubmitOptions,
    scene_field: &mut Option<String>,
) -> ApiResult<()> {
    use tokio::io::AsyncWriteExt;
    let limits = state.settings.bundle_limits;
    let too_big = |e: &axum::extract::multipart::MultipartError| e.status() == StatusCode::PAYLOAD_TOO_LARGE;
    let too_large = |e: BundleError| AppError::new(StatusCode::PAYLOAD_TOO_LARGE, e.to_string());
    loop {
        let mut field = match multipart.next_field().await {
            Ok(Some(f)) => f,
            Ok(None) => break,
            Err(e) if too_big(&e) => return Err(upload_too_large(state)),
            Err(e) => {
                return Err(AppError::bad_request(format!(
                    "the upload is not valid multipart/form-data: {e}"
                )));
            }
        };
        let name = field.name().unwrap_or("").to_string();
        let file_name = field.file_name().map(str::to_string);
        let kind = match name.as_str() {
            "scene" | "asset" | "file" | "assets" | "files" => Some(SpoolKind::File),
            "bundle" => Some(SpoolKind::Archive),
            _ => None,
        };
        let read_error = |e: axum::extract::multipart::MultipartError| {
            if too_big(&e) {
                upload_too_large(state)
            } else {
                AppError::bad_request(format!("cannot read the field \"{name}\": {e}"))
            }
        };
        if let Some(kind) = kind {
            let path = match (name.as_str(), file_name) {
                ("scene", f) => {
                    let f = f.unwrap_or_else(|| "scene.xml".into());
                    *scene_field = tessera::assets::normalize_bundle_path(&f);
                    f
                }
                ("bundle", f) => f.unwrap_or_else(|| "bundle".into()),
                (_, Some(f)) => f,
                (_, None) => {
                    return Err(AppError::bad_request(format!(
                        "the field \"{name}\" needs a file name: its path relative to the scene file"
                    )));
                }
            };
            if kind == SpoolKind::File && tessera::assets::normalize_bundle_path(&path).is_none() {
                return Err(AppError::bad_request(BundleError::UnsafePath(path).to_string()));
            }
            if spool.parts.len() >= limits.max_files {
                return Err(too_large(Unpacker::new(limits).too_many_files_error()));
            }
            let file = spool.dir.join(format!("part{}", spool.parts.len()));
            let mut out = tokio::fs::File::create(&file)
                .await
                .map_err(|e| anyhow::anyhow!("cannot create {}: {e}", file.display()))?;
            let mut size = 0u64;
            while let Some(chunk) = field.chunk().await.map_err(read_error)? {
                size += chunk.len() as u64;
                if kind == SpoolKind::File && size > limits.max_file_bytes {
                    return Err(too_large(Unpacker::new(limits).file_too_large_error(&path)));
                }
                out.write_all(&chunk)
                    .await
                    .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", file.display()))?;
            }
            out.flush().await.map_err(|e| anyhow::anyhow!("cannot write {}: {e}", file.display()))?;
            spool.parts.push((kind, path, file));
            continue;
        }
        let mut data = Vec::new();
        while let Some(chunk) = field.chunk().await.map_err(read_error)? {
            data.extend_from_slice(&chunk);
            if data.len() > MAX_TEXT_FIELD {
                return Err(AppError::bad_request(format!(
                    "the field \"{name}\" is longer than {} KiB; send files as scene, asset or bundle fields",
                    MAX_TEXT_FIELD >> 10
                )));
            }
        }
        let text = || String::from_utf8_lossy(&data).trim().to_string();
        let number = |what: &str| -> ApiResult<i64> {
            text().parse::<i64>().map_err(|_| {
                AppError::bad_request(format!("{what} must be an integer, found \"{}\"", text()))
            })
        };
        match name.as_str() {
            "name" => opts.name = Some(text()),
            "priority" => opts.priority = number("priority")?,
            "tile_size" => opts.tile_size = Some(bounded("tile_size", number("tile_size")?, 4096, "pixels")?),
            "samples" => opts.samples = Some(bounded("samples", number("samples")?, 1_000_000, "")?),
            "cameras" => {
                let mut list = Vec::new();
                for part in text().split([',', ' ']).filter(|p| !p.is_empty()) {
                    let k: u32 = part.parse().ok().filter(|k| *k >= 1).ok_or_else(|| {
                        AppError::bad_request(format!(
                            "cameras must list camera numbers from 1, e.g. \"1,3\"; found \"{part}\""
                        ))
                    })?;
                    list.push(k);
                }
                opts.cameras = Some(list);
            }
            "scene_path" => opts.scene_path = Some(text()),
            other => {
                return Err(AppError::bad_request(format!(
                    "unknown field \"{other}\"; send scene, asset (one per file, named by its relative path), bundle, name, priority, tile_size, samples, cameras or scene_path"
                )));
            }
        }
    }
    Ok(())
}

async fn submit_job(
    State(state): State<AppState>,
    mut multipart: Multipart,
) -> ApiResult<(StatusCode, Json<JobInfo>)> {
    let limits = state.settings.bundle_limits;
    let mut spool = Spool::new(&state.settings.data_dir)?;
    let mut opts = SubmitOptions::default();
    let mut scene_field: Option<String> = None;
    if let Err(refusal) = read_fields(&state, &mut multipart, &mut spool, &mut opts, &mut scene_field).await {
        // Read the rest of the body (bounded by --max-upload-mb, discarded) so that a client
        // still sending gets the answer instead of a broken connection.
        while let Ok(Some(mut field)) = multipart.next_field().await {
            while let Ok(Some(_)) = field.chunk().await {}
        }
        return Err(refusal);
    }
    let too_large = |e: BundleError| AppError::new(StatusCode::PAYLOAD_TOO_LARGE, e.to_string());
    if spool.parts.is_empty() {
        return Err(AppError::bad_request(
            "the upload holds no files; send the scene as the \"scene\" field (and its assets as \"asset\" fields) or a \"bundle\" archive",
        ));
    }

    // Unpacking and validation hold the files in memory: a few uploads at a time, so the
    // server's memory stays bounded however many arrive at once.
    let _permit = state
        .unpacking
        .clone()
        .acquire_owned()
        .await
        .map_err(|_| AppError::new(StatusCode::SERVICE_UNAVAILABLE, "the server is stopping"))?;
    let tile_size = opts.tile_size.unwrap_or(state.settings.tile_size);
    let wanted = opts.scene_path.clone().or(scene_field);
    let cameras_wanted = opts.cameras.clone();
    let max_tiles = state.settings.max_job_tiles;
    let (scene_path, tar, cameras, frames, warnings) = tokio::task::spawn_blocking(move || {
        let mut unpacker = Unpacker::new(limits);
        for (kind, path, file) in &spool.parts {
            let opened = std::fs::File::open(file)
                .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", file.display()))?;
            let added = match kind {
                SpoolKind::File => unpacker.add_reader(path, opened),
                SpoolKind::Archive => unpacker.add_archive(opened),
            };
            added.map_err(|e| match e {
                e @ BundleError::TooLarge(_) => too_large(e),
                e => AppError::bad_request(e.to_string()),
            })?;
        }
        drop(spool);
        let files = unpacker.files;
        let scene_path = bundle::find_scene(&files, wanted.as_deref()).map_err(AppError::bad_request)?;
        let (tar, cameras, frames, warnings) =
            validate(files, &scene_path, cameras_wanted, tile_size, max_tiles)?;
        Ok::<_, AppError>((scene_path, tar, cameras, frames, warnings))
    })
    .await
    .map_err(|e| anyhow::anyhow!("validation task: {e}"))??;
    check_sample_budget(&state.settings, &cameras, &frames, opts.samples)?;
    let hash = state.blobs.put(&tar)?;
    let name = opts.name.unwrap_or_else(|| scene_path.rsplit('/').next().unwrap_or(&scene_path).to_string());
    let job = crate::db::NewJob {
        name,
        priority: opts.priority,
        tile_size,
        samples: opts.samples,
        bundle: hash,
        scene_path,
        frames,
    };
    let id = state.store.insert_job(&job)?;
    state.cameras.lock().unwrap_or_else(|e| e.into_inner()).insert(id, Arc::new(cameras));
    state.work.notify_waiters();
    state.emit(ServerEvent::Job { job: id, state: JobState::Queued });
    tracing::info!(job = id, name = %job.name, "job accepted");
    let mut info = job_info(&state, id)?.ok_or_else(|| anyhow::anyhow!("job {id} vanished"))?;
    info.warnings = warnings;
    Ok((StatusCode::CREATED, Json(info)))
}

/// Refuses a job asking for more samples than the server's `--max-job-samples`: one that would
/// keep the farm busy for days is a 422 that says the limit and how to get under it.
fn check_sample_budget(
    settings: &Settings,
    cameras: &[Camera],
    frames: &[crate::db::NewFrame],
    samples: Option<u32>,
) -> ApiResult<()> {
    let mut total: u64 = 0;
    for f in frames {
        let spp = samples.unwrap_or(cameras[f.camera as usize].num_samples).max(1);
        let n = u64::from(f.width) * u64::from(f.height) * u64::from(spp);
        total = total.saturating_add(n);
    }
    if total > settings.max_job_samples {
        return Err(AppError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            format!(
                "the job asks for {total} samples (pixels x samples per pixel over its frames), more than this \
                 server's limit of {}: lower NumSamples or ImageResolution, submit with samples=N, or start the \
                 server with a larger --max-job-samples (TESSERA_MAX_JOB_SAMPLES)",
                settings.max_job_samples
            ),
        ));
    }
    Ok(())
}

/// Tiles of frames of `sizes` cut at `tile_size`.
fn tile_count(sizes: &[(u32, u32)], tile_size: u32) -> u64 {
    sizes.iter().map(|&(w, h)| u64::from(w.div_ceil(tile_size)) * u64::from(h.div_ceil(tile_size))).sum()
}

/// Refuses a job that would be cut into more than `max_tiles` tiles (a queue of hundreds of
/// thousands of one-pixel tiles costs the farm more in bookkeeping than in rendering), naming
/// the smallest tile size that fits.
fn check_tile_count(sizes: &[(u32, u32)], tile_size: u32, max_tiles: u64) -> ApiResult<()> {
    let n = tile_count(sizes, tile_size);
    if n <= max_tiles {
        return Ok(());
    }
    let fits = (tile_size..=4096).find(|&t| tile_count(sizes, t) <= max_tiles);
    let advice = match fits {
        Some(t) => format!("submit with tile_size={t} or more"),
        None => "render fewer cameras per job".to_string(),
    };
    Err(AppError::new(
        StatusCode::UNPROCESSABLE_ENTITY,
        format!(
            "the job would be cut into {n} tiles of {tile_size} pixels, more than this server's limit of \
             {max_tiles} tiles per job (--max-job-tiles, TESSERA_MAX_JOB_TILES); {advice}"
        ),
    ))
}

/// An upload field that must be an integer between 1 and `max` (`unit` for the message).
fn bounded(what: &str, value: i64, max: i64, unit: &str) -> ApiResult<u32> {
    if (1..=max).contains(&value) {
        Ok(value as u32)
    } else {
        let unit = if unit.is_empty() { String::new() } else { format!(" {unit}") };
        Err(AppError::bad_request(format!("{what} must be between 1 and {max}{unit}, found {value}")))
    }
}

fn upload_too_large(state: &AppState) -> AppError {
    AppError::new(
        StatusCode::PAYLOAD_TOO_LARGE,
        format!(
            "the upload is larger than this server accepts ({} MiB); start the server with a larger --max-upload-mb",
            state.settings.max_upload_bytes >> 20
        ),
    )
}

/// What a valid upload becomes: the canonical bundle, the scene's cameras, the frames to render
/// and the scene's warnings.
type Validated = (Vec<u8>, Vec<Camera>, Vec<crate::db::NewFrame>, Vec<String>);

/// Parses and builds the scene from the uploaded files.
fn validate(
    files: Files,
    scene_path: &str,
    cameras_wanted: Option<Vec<u32>>,
    tile_size: u32,
    max_tiles: u64,
) -> ApiResult<Validated> {
    let tar = bundle::canonical_tar(&files);
    let text = std::str::from_utf8(&files[scene_path]).map_err(|e| {
        AppError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            format!(
                "{scene_path}: the scene file is not UTF-8 text (byte {}); save it as UTF-8",
                e.valid_up_to()
            ),
        )
    })?;
    let invalid = |e: tessera::SceneError| AppError {
        status: StatusCode::UNPROCESSABLE_ENTITY,
        body: ApiError {
            error: format!("the scene cannot be rendered: {e}"),
            problems: vec![problem_from(&e)],
        },
    };
    let records = parse_scene(text, std::path::Path::new(scene_path)).map_err(invalid)?;
    let shared: HashMap<String, Arc<Vec<u8>>> = files.into_iter().map(|(k, v)| (k, Arc::new(v))).collect();
    let resolver = MemResolver::for_scene(shared, scene_path);
    let scene = build_scene(&records, &resolver).map_err(invalid)?;
    if scene.cameras.is_empty() {
        return Err(AppError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            format!("{scene_path}: the scene has no camera; add one under <Cameras>"),
        ));
    }
    let selected: Vec<u32> = match cameras_wanted {
        None => (0..scene.cameras.len() as u32).collect(),
        Some(list) => {
            let n = scene.cameras.len() as u32;
            if let Some(bad) = list.iter().find(|k| **k > n) {
                return Err(AppError::bad_request(format!(
                    "camera {bad} does not exist: the scene has {n} camera(s), numbered from 1"
                )));
            }
            list.into_iter().map(|k| k - 1).collect()
        }
    };
    let sizes: Vec<(u32, u32)> = selected
        .iter()
        .map(|&c| (scene.cameras[c as usize].width, scene.cameras[c as usize].height))
        .collect();
    check_tile_count(&sizes, tile_size, max_tiles)?;
    let frames = selected
        .iter()
        .map(|&c| {
            let cam = &scene.cameras[c as usize];
            crate::db::NewFrame {
                camera: c,
                image_name: cam.image_name.clone(),
                width: cam.width,
                height: cam.height,
                tiles: tessera::render::tiles(cam.width, cam.height, tile_size)
                    .into_iter()
                    .map(Rect::from)
                    .collect(),
            }
        })
        .collect();
    let warnings = scene.warnings.iter().map(ToString::to_string).collect();
    Ok((tar, scene.cameras, frames, warnings))
}

/// The cameras of a job, parsed from its bundle once and cached.
pub fn job_cameras(state: &AppState, job: &crate::db::JobRow) -> anyhow::Result<Arc<Vec<Camera>>> {
    if let Some(c) = state.cameras.lock().unwrap_or_else(|e| e.into_inner()).get(&job.id) {
        return Ok(c.clone());
    }
    let tar = state
        .blobs
        .get(&job.bundle)
        .ok_or_else(|| anyhow::anyhow!("bundle {} of job {} is missing", job.bundle, job.id))?;
    let files = bundle::read_tar(&tar)?;
    let text = files
        .get(&job.scene_path)
        .ok_or_else(|| anyhow::anyhow!("scene {} missing from its bundle", job.scene_path))?;
    let records = parse_scene(&String::from_utf8_lossy(text), std::path::Path::new(&job.scene_path))
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let cameras =
        Arc::new(tessera::scene::build::build_cameras(&records).map_err(|e| anyhow::anyhow!("{e}"))?);
    state.cameras.lock().unwrap_or_else(|e| e.into_inner()).insert(job.id, cameras.clone());
    Ok(cameras)
}

fn tone_params(p: &tessera::tonemap::params::Photographic) -> ToneParams {
    ToneParams { key: p.key, burn: p.burn_percent, saturation: p.saturation, gamma: p.gamma.to_string() }
}

/// The parameters a camera's HDR output is tone-mapped with, if it is HDR.
fn camera_tonemap(cam: &Camera) -> Option<tessera::tonemap::params::Photographic> {
    merge::display_tonemap(cam).map(|(_, p)| p)
}

fn job_info(state: &AppState, id: u64) -> anyhow::Result<Option<JobInfo>> {
    let Some(job) = state.store.job(id)? else { return Ok(None) };
    let frames = state.store.frames(id)?;
    let cameras = job_cameras(state, &job).ok();
    let url = format!("/api/v1/jobs/{id}");
    let mut error = job.error.clone();
    if error.is_none() && !job.state.is_final() {
        // Tile failures that have not failed the job yet are worth seeing too.
        let recent = state.store.recent_failures(id)?;
        if !recent.is_empty() {
            error = Some(format!("retrying after tile failures: {}", recent.join("; ")));
        }
    }
    Ok(Some(JobInfo {
        id,
        name: job.name.clone(),
        state: job.state,
        priority: job.priority,
        tile_size: job.tile_size,
        samples: job.samples,
        submitted_at: job.submitted_at,
        started_at: job.started_at,
        finished_at: job.finished_at,
        frames: frames
            .iter()
            .map(|f| FrameInfo {
                index: f.index,
                camera: f.camera,
                image_name: f.image_name.clone(),
                width: f.width,
                height: f.height,
                tiles_total: f.tiles_total,
                tiles_done: f.tiles_done,
                outputs: f
                    .outputs
                    .iter()
                    .flatten()
                    .map(|n| OutputInfo {
                        name: n.clone(),
                        url: format!("{url}/frames/{}/files/{n}", f.index),
                    })
                    .collect(),
                preview_url: format!("{url}/frames/{}/preview.png", f.index),
                tonemap: cameras
                    .as_ref()
                    .and_then(|c| c.get(f.camera as usize))
                    .and_then(camera_tonemap)
                    .map(|p| tone_params(&p)),
            })
            .collect(),
        error,
        warnings: Vec::new(),
        url,
    }))
}

async fn list_jobs(State(state): State<AppState>) -> ApiResult<Json<JobList>> {
    let ids: Vec<u64> = state.store.jobs()?.iter().map(|j| j.id).collect();
    let mut jobs = Vec::new();
    for id in ids {
        jobs.extend(job_info(&state, id)?);
    }
    Ok(Json(JobList { jobs }))
}

async fn show_job(State(state): State<AppState>, Path(id): Path<u64>) -> ApiResult<Json<JobInfo>> {
    job_info(&state, id)?.map(Json).ok_or_else(|| AppError::not_found(format!("there is no job {id}")))
}

async fn cancel_job(State(state): State<AppState>, Path(id): Path<u64>) -> ApiResult<Json<JobInfo>> {
    let Some(job) = state.store.job(id)? else {
        return Err(AppError::not_found(format!("there is no job {id}")));
    };
    if !state.store.cancel_job(id)? {
        return Err(AppError::new(
            StatusCode::CONFLICT,
            format!("job {id} has already ended ({})", job.state.as_str()),
        ));
    }
    tracing::info!(job = id, "job canceled");
    state.emit(ServerEvent::Job { job: id, state: JobState::Canceled });
    Ok(Json(job_info(&state, id)?.ok_or_else(|| anyhow::anyhow!("job {id} vanished"))?))
}

/// Frame `frame` of job `id`, or a 404 naming what is missing.
fn find_frame(state: &AppState, id: u64, frame: u32) -> ApiResult<crate::db::FrameRow> {
    state
        .store
        .frames(id)?
        .into_iter()
        .find(|f| f.index == frame)
        .ok_or_else(|| AppError::not_found(format!("job {id} has no frame {frame}")))
}

/// Job `id` and its frame `frame`, or a 404 naming the first that is missing.
fn job_and_frame(
    state: &AppState,
    id: u64,
    frame: u32,
) -> ApiResult<(crate::db::JobRow, crate::db::FrameRow)> {
    let job = state.store.job(id)?.ok_or_else(|| AppError::not_found(format!("there is no job {id}")))?;
    Ok((job, find_frame(state, id, frame)?))
}

async fn frame_file(
    State(state): State<AppState>,
    Path((id, frame, name)): Path<(u64, u32, String)>,
) -> ApiResult<Response> {
    let f = &find_frame(&state, id, frame)?;
    let Some(outputs) = &f.outputs else {
        return Err(AppError::new(
            StatusCode::CONFLICT,
            format!(
                "frame {frame} of job {id} is not finished ({} of {} tiles); see preview.png meanwhile",
                f.tiles_done, f.tiles_total
            ),
        ));
    };
    if !outputs.contains(&name) {
        return Err(AppError::not_found(format!(
            "frame {frame} of job {id} has no file {name}; it has {}",
            outputs.join(", ")
        )));
    }
    let path = state.frame_dir(id, frame).join(&name);
    let bytes =
        tokio::fs::read(&path).await.map_err(|e| anyhow::anyhow!("cannot read {}: {e}", path.display()))?;
    let mime =
        if name.to_ascii_lowercase().ends_with(".png") { "image/png" } else { "application/octet-stream" };
    Ok((
        [
            (header::CONTENT_TYPE, HeaderValue::from_static(mime)),
            (
                header::CONTENT_DISPOSITION,
                HeaderValue::from_str(&format!("attachment; filename=\"{name}\""))
                    .unwrap_or(HeaderValue::from_static("attachment")),
            ),
        ],
        bytes,
    )
        .into_response())
}

async fn frame_preview(
    State(state): State<AppState>,
    Path((id, frame)): Path<(u64, u32)>,
) -> ApiResult<Response> {
    let (job, f) = job_and_frame(&state, id, frame)?;
    let cameras = job_cameras(&state, &job)?;
    let cam = cameras
        .get(f.camera as usize)
        .cloned()
        .ok_or_else(|| anyhow::anyhow!("camera {} missing", f.camera))?;
    let store = state.store.clone();
    let png = tokio::task::spawn_blocking(move || -> anyhow::Result<Vec<u8>> {
        let tiles = store.frame_tiles(id, frame)?;
        if tiles.is_empty() && f.outputs.is_some() {
            // A finished job drops its tiles: show the stored float frame.
            if let Some(path) = stored_exr(&state, &f) {
                let img = tessera::hdr_io::read_exr(&path)?;
                return merge::final_png(&cam, &img);
            }
        }
        merge::preview_png(&cam, f.width, f.height, &tiles)
    })
    .await
    .map_err(|e| anyhow::anyhow!("preview task: {e}"))??;
    Ok(([(header::CONTENT_TYPE, HeaderValue::from_static("image/png"))], png).into_response())
}

/// Where a merged frame's float image (`.exr` output) is stored, if it has one.
fn stored_exr(state: &AppState, f: &crate::db::FrameRow) -> Option<std::path::PathBuf> {
    let name = f.outputs.as_ref()?.iter().find(|n| n.to_ascii_lowercase().ends_with(".exr"))?;
    Some(state.frame_dir(f.job_id, f.index).join(name))
}

/// Query of `tonemap.png`: any parameter left out takes the camera's value.
#[derive(serde::Deserialize)]
struct ToneQuery {
    key: Option<f64>,
    burn: Option<f64>,
    saturation: Option<f64>,
    gamma: Option<String>,
}

/// A finished frame's float image tone-mapped again with other parameters, without rendering:
/// `GET /api/v1/jobs/ID/frames/F/tonemap.png?key=0.3&burn=2&saturation=1&gamma=2.2`.
async fn frame_tonemap(
    State(state): State<AppState>,
    Path((id, frame)): Path<(u64, u32)>,
    axum::extract::Query(q): axum::extract::Query<ToneQuery>,
) -> ApiResult<Response> {
    let (job, f) = job_and_frame(&state, id, frame)?;
    if f.outputs.is_none() {
        return Err(AppError::new(
            StatusCode::CONFLICT,
            format!("frame {frame} of job {id} is not finished yet"),
        ));
    }
    let path = stored_exr(&state, &f)
        .ok_or_else(|| AppError::not_found(format!("frame {frame} of job {id} has no .exr to tone-map")))?;
    let cameras = job_cameras(&state, &job)?;
    let (operator, base) = cameras
        .get(f.camera as usize)
        .and_then(merge::display_tonemap)
        .unwrap_or((tessera::tonemap::params::Operator::Photographic, Default::default()));
    let gamma = match q.gamma.as_deref() {
        Some(g) => g.parse().map_err(AppError::bad_request)?,
        None => base.gamma,
    };
    let params = tessera::tonemap::params::Photographic {
        key: q.key.unwrap_or(base.key),
        burn_percent: q.burn.unwrap_or(base.burn_percent),
        saturation: q.saturation.unwrap_or(base.saturation),
        gamma,
    };
    params.validate().map_err(AppError::bad_request)?;
    let png = tokio::task::spawn_blocking(move || -> anyhow::Result<Vec<u8>> {
        let img = tessera::hdr_io::read_exr(&path)?;
        let (rgb, _) = tessera::tonemap::tonemap_with(&img, operator, &params);
        merge::encode_png(img.width, img.height, &rgb)
    })
    .await
    .map_err(|e| anyhow::anyhow!("tone-map task: {e}"))??;
    Ok(([(header::CONTENT_TYPE, HeaderValue::from_static("image/png"))], png).into_response())
}

/// Server-sent events for the status page: every [`ServerEvent`] as it happens.
async fn events(State(state): State<AppState>) -> Response {
    use axum::response::sse::{Event, KeepAlive, Sse};
    let rx = state.events.subscribe();
    let stream = futures_util::stream::unfold(rx, |mut rx| async move {
        let ev = match rx.recv().await {
            Ok(e) => Event::default().event(e.name()).data(serde_json::to_string(&e).unwrap_or_default()),
            // A slow page missed some: tell it to reload everything.
            Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {
                Event::default().event("resync").data("{}")
            }
            Err(tokio::sync::broadcast::error::RecvError::Closed) => return None,
        };
        Some((Ok::<Event, std::convert::Infallible>(ev), rx))
    });
    Sse::new(stream).keep_alive(KeepAlive::default()).into_response()
}

// ---------------------------------------------------------------------------------------------
// Workers
// ---------------------------------------------------------------------------------------------

#[derive(serde::Serialize)]
struct WorkerInfo {
    id: u64,
    name: String,
    threads: u32,
    state: &'static str,
    current_tile: Option<CurrentTile>,
    last_heartbeat: f64,
    tiles_done: u64,
    failures: u64,
}

#[derive(serde::Serialize)]
struct CurrentTile {
    job: u64,
    frame: u32,
    tile: u32,
}

async fn list_workers(State(state): State<AppState>) -> ApiResult<Json<serde_json::Value>> {
    let lost_after = 3.0 * state.settings.heartbeat_seconds + 2.0;
    let t = crate::db::now();
    let workers: Vec<WorkerInfo> = state
        .store
        .workers()?
        .into_iter()
        .map(|w| WorkerInfo {
            id: w.id,
            name: w.name,
            threads: w.threads,
            state: if t - w.last_seen > lost_after {
                "lost"
            } else if w.rendering.is_some() {
                "rendering"
            } else {
                "idle"
            },
            current_tile: w.current_tile.map(|(job, frame, tile)| CurrentTile { job, frame, tile }),
            last_heartbeat: w.last_seen,
            tiles_done: w.tiles_done,
            failures: w.failures,
        })
        .collect();
    Ok(Json(serde_json::json!({ "workers": workers })))
}

async fn register(
    State(state): State<AppState>,
    Json(req): Json<RegisterRequest>,
) -> ApiResult<Json<RegisterResponse>> {
    let id = state.store.register_worker(&req.name, req.threads)?;
    tracing::info!(worker = id, name = %req.name, threads = req.threads, "worker registered");
    state.emit(ServerEvent::Workers);
    Ok(Json(RegisterResponse {
        worker_id: id,
        heartbeat_seconds: state.settings.heartbeat_seconds,
        lease_seconds: state.settings.lease_seconds,
    }))
}

async fn known_worker(state: &AppState, id: u64) -> ApiResult<()> {
    if state.store.worker_exists(id)? {
        Ok(())
    } else {
        Err(AppError::new(StatusCode::NOT_FOUND, format!("unknown worker {id}; register again")))
    }
}

/// Long poll: a lease as soon as a tile is free, or 204 after the wait.
async fn lease(State(state): State<AppState>, Json(req): Json<LeaseRequest>) -> ApiResult<Response> {
    known_worker(&state, req.worker_id).await?;
    let wait = req.wait_seconds.clamp(0.0, state.settings.max_wait_seconds);
    let deadline = tokio::time::Instant::now() + Duration::from_secs_f64(wait);
    loop {
        // Register interest before looking, so a notification between the look and the wait
        // is not lost.
        let notified = state.work.notified();
        if state.shutting_down.load(Ordering::SeqCst) {
            // An error, not "no work": workers back off on errors, while they ask again at once
            // after a 204, which would spin until the server is gone.
            let mut response = AppError::new(
                StatusCode::SERVICE_UNAVAILABLE,
                "the server is shutting down; ask again later",
            )
            .into_response();
            response
                .headers_mut()
                .insert(axum::http::header::RETRY_AFTER, axum::http::HeaderValue::from_static("5"));
            return Ok(response);
        }
        if let Some(mut lease) = state.store.lease(req.worker_id, state.settings.lease_seconds)? {
            lease.max_render_seconds = Some(state.settings.max_tile_seconds);
            state.emit(ServerEvent::Job { job: lease.job_id, state: JobState::Running });
            state.emit(ServerEvent::Workers);
            return Ok(Json(lease).into_response());
        }
        if tokio::time::timeout_at(deadline, notified).await.is_err() {
            return Ok(StatusCode::NO_CONTENT.into_response());
        }
    }
}

async fn heartbeat(
    State(state): State<AppState>,
    Json(req): Json<HeartbeatRequest>,
) -> ApiResult<Json<HeartbeatResponse>> {
    known_worker(&state, req.worker_id).await?;
    let revoked =
        state.store.heartbeat(req.worker_id, &req.leases, req.rendering, state.settings.lease_seconds)?;
    Ok(Json(HeartbeatResponse { revoked }))
}

/// Long poll: answers as soon as one of the worker's listed leases is no longer its own (its
/// job was cancelled or failed), else after the wait with nothing revoked. Reads only; the
/// heartbeat still renews the leases.
async fn watch(
    State(state): State<AppState>,
    Json(req): Json<WatchRequest>,
) -> ApiResult<Json<HeartbeatResponse>> {
    known_worker(&state, req.worker_id).await?;
    let wait = req.wait_seconds.clamp(0.0, state.settings.max_wait_seconds);
    let deadline = tokio::time::Instant::now() + Duration::from_secs_f64(wait);
    let leases: Vec<u64> = req.leases.into_iter().take(64).collect();
    // Subscribe before looking, so a cancel between the look and the wait is not lost.
    let mut events = state.events.subscribe();
    loop {
        let revoked = state.store.revoked_among(req.worker_id, &leases)?;
        if !revoked.is_empty() || state.shutting_down.load(Ordering::SeqCst) {
            return Ok(Json(HeartbeatResponse { revoked }));
        }
        loop {
            match tokio::time::timeout_at(deadline, events.recv()).await {
                Err(_) => return Ok(Json(HeartbeatResponse { revoked: Vec::new() })),
                Ok(Ok(ServerEvent::Job { state: JobState::Canceled | JobState::Failed, .. })) => break,
                // Missed events: look again.
                Ok(Err(tokio::sync::broadcast::error::RecvError::Lagged(_))) => break,
                Ok(Err(tokio::sync::broadcast::error::RecvError::Closed)) => {
                    return Ok(Json(HeartbeatResponse { revoked: Vec::new() }));
                }
                Ok(Ok(_)) => {}
            }
        }
    }
}

async fn result(
    State(state): State<AppState>,
    Path(lease): Path<u64>,
    headers: HeaderMap,
    body: Bytes,
) -> ApiResult<StatusCode> {
    let worker: u64 = headers
        .get("x-tessera-worker")
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse().ok())
        .ok_or_else(|| AppError::bad_request("missing header x-tessera-worker (the worker id)"))?;
    let sum = headers
        .get(CHECKSUM_HEADER)
        .and_then(|v| v.to_str().ok())
        .ok_or_else(|| AppError::bad_request(format!("missing header {CHECKSUM_HEADER}")))?;
    if sum != checksum(&body) {
        return Err(AppError::bad_request("the tile's checksum does not match its bytes; send it again"));
    }
    let render_seconds =
        headers.get("x-tessera-render-seconds").and_then(|v| v.to_str().ok()).and_then(|v| v.parse().ok());
    match state.store.submit_result(lease, worker, &body, render_seconds)? {
        ResultOutcome::Accepted { job_id, frame, tile, rect, tiles_done, tiles_total, frame_complete } => {
            state.emit(ServerEvent::Tile { job: job_id, frame, tile, rect, tiles_done, tiles_total });
            state.emit(ServerEvent::Workers);
            if frame_complete {
                let state = state.clone();
                tokio::spawn(async move { merge_frame(state, job_id, frame).await });
            }
            Ok(StatusCode::NO_CONTENT)
        }
        ResultOutcome::Conflict => {
            state.counters.results_refused.fetch_add(1, Ordering::Relaxed);
            Err(AppError::new(
                StatusCode::CONFLICT,
                format!(
                    "lease {lease} is not yours any more (expired, revoked or already done); drop the tile"
                ),
            ))
        }
        ResultOutcome::WrongSize { expected } => Err(AppError::bad_request(format!(
            "the tile holds {} bytes; its rectangle needs {expected} (width x height x 3 little-endian f32)",
            body.len()
        ))),
    }
}

async fn fail(
    State(state): State<AppState>,
    Path(lease): Path<u64>,
    Json(req): Json<FailRequest>,
) -> ApiResult<StatusCode> {
    match state.store.fail_tile(lease, req.worker_id, &req.error, req.fatal)? {
        FailOutcome::Requeued => {
            tracing::warn!(lease, worker = req.worker_id, error = %req.error, "tile failed; queued again");
            state.work.notify_waiters();
            Ok(StatusCode::NO_CONTENT)
        }
        FailOutcome::JobFailed { job, message } => {
            tracing::error!(lease, job, "job failed: {message}");
            state.emit(ServerEvent::Job { job, state: JobState::Failed });
            Ok(StatusCode::NO_CONTENT)
        }
        FailOutcome::Conflict => {
            Err(AppError::new(StatusCode::CONFLICT, format!("lease {lease} is not yours any more")))
        }
    }
}

/// A stopping worker gives back a lease it has not started: the tile is queued again at once.
async fn release(
    State(state): State<AppState>,
    Path(lease): Path<u64>,
    Json(req): Json<ReleaseRequest>,
) -> ApiResult<StatusCode> {
    if state.store.release_lease(lease, req.worker_id)? {
        tracing::info!(lease, worker = req.worker_id, "lease given back; its tile is queued again");
        state.emit(ServerEvent::Workers);
        state.work.notify_waiters();
        Ok(StatusCode::NO_CONTENT)
    } else {
        Err(AppError::new(
            StatusCode::CONFLICT,
            format!("lease {lease} is not a live lease of worker {}", req.worker_id),
        ))
    }
}

async fn get_bundle(State(state): State<AppState>, Path(hash): Path<String>) -> ApiResult<Response> {
    let blobs = state.blobs.clone();
    let h = hash.clone();
    let bytes = tokio::task::spawn_blocking(move || blobs.get(&h))
        .await
        .map_err(|e| anyhow::anyhow!("bundle task: {e}"))?
        .ok_or_else(|| AppError::not_found(format!("no bundle {hash}")))?;
    Ok(([(header::CONTENT_TYPE, HeaderValue::from_static("application/x-tar"))], bytes).into_response())
}

/// Merges a complete frame off the executor; a failure fails the job with the reason.
pub async fn merge_frame(state: AppState, job_id: u64, frame: u32) {
    let st = state.clone();
    let outcome = tokio::task::spawn_blocking(move || -> anyhow::Result<bool> {
        let job = st.store.job(job_id)?.ok_or_else(|| anyhow::anyhow!("job {job_id} vanished"))?;
        let frames = st.store.frames(job_id)?;
        let f = frames
            .iter()
            .find(|f| f.index == frame)
            .ok_or_else(|| anyhow::anyhow!("frame {frame} vanished"))?;
        if f.outputs.is_some() {
            // Merged already (a second trigger of one frame): the outputs stand.
            return Ok(frames.iter().all(|f| f.outputs.is_some()));
        }
        let cameras = job_cameras(&st, &job)?;
        let cam =
            cameras.get(f.camera as usize).ok_or_else(|| anyhow::anyhow!("camera {} missing", f.camera))?;
        let tiles = st.store.frame_tiles(job_id, frame)?;
        let img = merge::assemble(f.width, f.height, &tiles)?;
        let names = merge::write_outputs(&st.frame_dir(job_id, frame), cam, &img)?;
        st.store.frame_merged(job_id, frame, &names)
    })
    .await;
    match outcome {
        Ok(Ok(done)) => {
            tracing::info!(job = job_id, frame, done, "frame merged");
            state.emit(ServerEvent::Frame { job: job_id, frame });
            if done {
                state.emit(ServerEvent::Job { job: job_id, state: JobState::Done });
            }
        }
        Ok(Err(e)) => {
            tracing::error!(job = job_id, frame, "merge failed: {e:#}");
            let _ = state.store.fail_job(job_id, &format!("merging frame {frame} failed: {e:#}"));
            state.emit(ServerEvent::Job { job: job_id, state: JobState::Failed });
        }
        Err(e) => tracing::error!(job = job_id, frame, "merge task panicked: {e}"),
    }
}

// ---------------------------------------------------------------------------------------------
// Metrics
// ---------------------------------------------------------------------------------------------

async fn metrics(State(state): State<AppState>) -> ApiResult<Response> {
    let crate::db::StoreMetrics {
        jobs_by_state: states,
        tiles_done,
        render_seconds_sum: render_sum,
        render_seconds_count: render_count,
    } = state.store.metrics()?;
    let workers = state.store.workers()?;
    let lost_after = 3.0 * state.settings.heartbeat_seconds + 2.0;
    let t = crate::db::now();
    let mut by_state: HashMap<&str, i64> = HashMap::new();
    for w in &workers {
        let s = if t - w.last_seen > lost_after {
            "lost"
        } else if w.rendering.is_some() {
            "rendering"
        } else {
            "idle"
        };
        *by_state.entry(s).or_default() += 1;
    }
    let mut out = String::new();
    out += "# HELP tessera_jobs Jobs by state.\n# TYPE tessera_jobs gauge\n";
    for s in ["queued", "running", "done", "failed", "canceled"] {
        let n = states.iter().find(|(k, _)| k == s).map_or(0, |(_, n)| *n);
        out += &format!("tessera_jobs{{state=\"{s}\"}} {n}\n");
    }
    out += "# HELP tessera_tiles_done_total Tiles rendered and accepted.\n# TYPE tessera_tiles_done_total counter\n";
    out += &format!("tessera_tiles_done_total {tiles_done}\n");
    out += "# HELP tessera_lease_expiries_total Leases that expired and went back to the queue.\n# TYPE tessera_lease_expiries_total counter\n";
    out +=
        &format!("tessera_lease_expiries_total {}\n", state.counters.lease_expiries.load(Ordering::Relaxed));
    out += "# HELP tessera_results_refused_total Tile results refused (expired or revoked leases).\n# TYPE tessera_results_refused_total counter\n";
    out += &format!(
        "tessera_results_refused_total {}\n",
        state.counters.results_refused.load(Ordering::Relaxed)
    );
    out += "# HELP tessera_workers Registered workers by state.\n# TYPE tessera_workers gauge\n";
    for s in ["idle", "rendering", "lost"] {
        out += &format!("tessera_workers{{state=\"{s}\"}} {}\n", by_state.get(s).copied().unwrap_or(0));
    }
    out += "# HELP tessera_tile_render_seconds Time workers spent rendering tiles.\n# TYPE tessera_tile_render_seconds summary\n";
    out += &format!(
        "tessera_tile_render_seconds_sum {render_sum}\ntessera_tile_render_seconds_count {render_count}\n"
    );
    Ok(([(header::CONTENT_TYPE, HeaderValue::from_static("text/plain; version=0.0.4"))], out).into_response())
}
