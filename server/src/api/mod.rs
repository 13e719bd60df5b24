//! The HTTP API's frame: the router, the state every handler shares, and the one error type.
//!
//! Two APIs under `/api/v1`, both JSON: the job API for people (curl, the status page) and the
//! worker protocol (`tessera::protocol`), plus `/healthz`, `/metrics` and the page itself. The
//! handlers live by concern in the submodules; the scheduling rules they call are in
//! [`crate::scheduler`], the store in [`crate::db`]. Handlers do database work under a short
//! mutex and push CPU work (scene validation, merging, tone mapping, PNG encoding) to
//! `spawn_blocking`. Every error is an [`AppError`] answered as `{"error", "problems"}` JSON with
//! a fitting status; internal details go to the log, not to the client.

mod auth;
mod jobs;
mod metrics;
mod status;
mod submit;
#[cfg(test)]
mod tests;
mod worker;

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;

use axum::extract::{DefaultBodyLimit, Path};
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post, put};
use axum::{Json, Router};
use tessera::camera::Camera;
use tessera::protocol::*;

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
    /// Most samples (pixels x samples per pixel over all frames) one job may ask for.
    pub max_job_samples: u64,
}

#[derive(Clone)]
pub struct AppState {
    pub store: Arc<Store>,
    pub blobs: BlobStore,
    pub settings: Arc<Settings>,
    /// Leasing, failures, expiry and revocation: the scheduling rules.
    pub scheduler: Scheduler,
    /// Built cameras per job (parsed once from the bundle), for merging and previews.
    pub cameras: Arc<std::sync::Mutex<HashMap<u64, Arc<Vec<Camera>>>>>,
    /// Pushed to the status page (server-sent events); nobody listening is fine.
    pub events: tokio::sync::broadcast::Sender<ServerEvent>,
    /// Uploads being unpacked and validated at once (each holds its files in memory).
    pub unpacking: Arc<tokio::sync::Semaphore>,
}

impl AppState {
    /// The state of a server over `store` and `blobs`; its scheduler runs on `timing`.
    pub fn new(store: Arc<Store>, blobs: BlobStore, settings: Settings, timing: Timing) -> AppState {
        let events = tokio::sync::broadcast::channel(1024).0;
        AppState {
            scheduler: Scheduler::new(store.clone(), timing, events.clone()),
            store,
            blobs,
            settings: Arc::new(settings),
            cameras: Arc::default(),
            events,
            unpacking: Arc::new(tokio::sync::Semaphore::new(crate::UNPACKING_AT_ONCE)),
        }
    }

    pub fn emit(&self, e: ServerEvent) {
        let _ = self.events.send(e);
    }

    /// Where the output files of a job's frame are written: `outputs/JOB/FRAME/`.
    pub fn frame_dir(&self, job: u64, frame: u32) -> PathBuf {
        self.settings.data_dir.join("outputs").join(job.to_string()).join(frame.to_string())
    }

    /// The cameras of a job, parsed from its bundle once and cached.
    pub fn job_cameras(&self, job: &crate::db::JobRow) -> anyhow::Result<Arc<Vec<Camera>>> {
        if let Some(c) = self.cameras.lock().unwrap_or_else(|e| e.into_inner()).get(&job.id) {
            return Ok(c.clone());
        }
        let tar = self
            .blobs
            .get(&job.bundle)
            .ok_or_else(|| anyhow::anyhow!("bundle {} of job {} is missing", job.bundle, job.id))?;
        let files = tessera::bundle::read_tar(&tar)?;
        let cameras = Arc::new(tessera::bundle::bundle_cameras(&files, &job.scene_path)?);
        self.cameras.lock().unwrap_or_else(|e| e.into_inner()).insert(job.id, cameras.clone());
        Ok(cameras)
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
    let job_api = Router::new()
        .route("/api/v1/jobs", post(submit::submit_job).get(jobs::list_jobs))
        .route("/api/v1/jobs/{id}", get(jobs::show_job))
        .route("/api/v1/jobs/{id}/cancel", post(jobs::cancel_job))
        .route("/api/v1/jobs/{id}/frames/{frame}/preview.png", get(jobs::frame_preview))
        .route("/api/v1/jobs/{id}/frames/{frame}/files/{name}", get(jobs::frame_file))
        .route("/api/v1/jobs/{id}/frames/{frame}/tonemap.png", get(jobs::frame_tonemap))
        .route("/api/v1/workers", get(status::list_workers))
        .route("/api/v1/events", get(status::events))
        .route_layer(axum::middleware::from_fn_with_state(state.clone(), auth::require_api_token));
    let worker_api = Router::new()
        .route("/api/v1/worker/register", post(worker::register))
        .route("/api/v1/worker/lease", post(worker::lease))
        .route("/api/v1/worker/heartbeat", post(worker::heartbeat))
        .route("/api/v1/worker/watch", post(worker::watch))
        .route("/api/v1/worker/leases/{lease}/result", put(worker::result))
        .route("/api/v1/worker/leases/{lease}/fail", post(worker::fail))
        .route("/api/v1/worker/leases/{lease}/release", post(worker::release))
        .route("/api/v1/worker/bundles/{hash}", get(worker::get_bundle))
        .route_layer(axum::middleware::from_fn_with_state(state.clone(), auth::require_worker_token));
    let limit = state.settings.max_upload_bytes;
    Router::new()
        .route("/healthz", get(|| async { "ok\n" }))
        .route("/", get(|| async { crate::web::page("index.html") }))
        .route("/static/{name}", get(|Path(name): Path<String>| async move { crate::web::page(&name) }))
        .route("/metrics", get(metrics::metrics))
        .merge(job_api)
        .merge(worker_api)
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
