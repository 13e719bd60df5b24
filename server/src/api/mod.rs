//! The HTTP API's frame: the router, the state every handler shares, and the one error type.
//!
//! Two APIs under `/api/v1`, both JSON: the job API for people (curl, the status page) and the
//! worker protocol (`tessera::protocol`), plus `/healthz`, `/metrics` and the page itself. The
//! handlers live by concern in the submodules; the scheduling rules they call are in
//! [`crate::scheduler`], the store in [`crate::db`]. Handlers do their database work (a short
//! transaction under the store's mutex) and their CPU work (scene validation, merging, tone
//! mapping, PNG encoding) on `spawn_blocking` ([`off_thread`]), never on the async threads. Every error is an [`AppError`] answered as `{"error", "problems"}` JSON with
//! a fitting status; internal details go to the log, not to the client.

mod auth;
pub mod browser;
mod files;
mod jobctl;
mod jobs;
pub(crate) use jobs::job_info;
mod jobspec;
mod metrics;
mod openapi;
mod status;
mod submit;
#[cfg(test)]
mod tests;
mod video;
mod worker;

use axum::extract::{DefaultBodyLimit, Path};
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::{Json, Router};
use tessera::protocol::*;
use utoipa::OpenApi;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use crate::state::{AppState, Settings};

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
        if crate::storage::out_of_space(&e) {
            // A full disk: the request's transaction rolled back and its files went (written
            // under temporary names), so nothing of it was stored.
            tracing::error!("refused a request, the disk is full: {e:#}");
            return AppError::new(StatusCode::INSUFFICIENT_STORAGE, crate::storage::OUT_OF_SPACE);
        }
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

/// Waits for a turn under one of the semaphores that bound what holds memory at once
/// (unpacking, previews); only a closed semaphore (the server stopping) refuses.
async fn turn(gate: &std::sync::Arc<tokio::sync::Semaphore>) -> ApiResult<tokio::sync::OwnedSemaphorePermit> {
    gate.clone()
        .acquire_owned()
        .await
        .map_err(|_| AppError::new(StatusCode::SERVICE_UNAVAILABLE, "the server is stopping"))
}

/// Runs a handler's store and file work on the blocking pool. The store is one SQLite
/// connection behind a mutex: work under it must never hold one of the few async threads that
/// accept connections and answer every other request (`/healthz` included), whatever another
/// client sends.
async fn off_thread<T: Send + 'static>(f: impl FnOnce() -> ApiResult<T> + Send + 'static) -> ApiResult<T> {
    tokio::task::spawn_blocking(f)
        .await
        .map_err(|e| anyhow::anyhow!("a handler's blocking task failed: {e}"))?
}

/// Bytes a streamed file is read in (and about what one download holds in memory, beside the
/// connection's write buffer).
const FILE_CHUNK: usize = 64 << 10;

/// A file opened to be answered as it is read: its body is streamed in [`FILE_CHUNK`] pieces
/// as the client takes them, never held whole in memory, with its length. The open file is
/// read to its end even if the name is replaced meanwhile (outputs are replaced by renames).
pub(crate) struct FileBody {
    file: tokio::fs::File,
    len: u64,
}

impl FileBody {
    pub(crate) async fn open(path: &std::path::Path) -> std::io::Result<FileBody> {
        let file = tokio::fs::File::open(path).await?;
        let meta = file.metadata().await?;
        if !meta.is_file() {
            return Err(std::io::Error::other("not a file"));
        }
        Ok(FileBody { file, len: meta.len() })
    }

    /// The file's length in bytes.
    pub(crate) fn len(&self) -> u64 {
        self.len
    }

    /// Only bytes `start..start + len` of the file (a `Range` request's): the answer's body and
    /// `Content-Length` are those.
    pub(crate) async fn range(mut self, start: u64, len: u64) -> std::io::Result<FileBody> {
        use tokio::io::AsyncSeekExt;
        self.file.seek(std::io::SeekFrom::Start(start)).await?;
        self.len = len.min(self.len.saturating_sub(start));
        Ok(self)
    }

    /// The answer: `headers`, the file's `Content-Length` and its bytes.
    pub(crate) fn into_response_with(self, headers: &[(header::HeaderName, HeaderValue)]) -> Response {
        use tokio::io::AsyncReadExt;
        let stream = futures_util::stream::unfold(Some((self.file, self.len)), |state| async move {
            let (mut file, left) = state?;
            if left == 0 {
                return None;
            }
            let mut buf = vec![0u8; FILE_CHUNK.min(usize::try_from(left).unwrap_or(FILE_CHUNK))];
            match file.read(&mut buf).await {
                Ok(0) => None,
                Ok(n) => {
                    buf.truncate(n);
                    Some((Ok(axum::body::Bytes::from(buf)), Some((file, left - n as u64))))
                }
                // The answer is cut short (the client sees its length unmet): said once.
                Err(e) => Some((Err(e), None)),
            }
        });
        let mut resp = axum::body::Body::from_stream(stream).into_response();
        let h = resp.headers_mut();
        for (name, value) in headers {
            h.insert(name.clone(), value.clone());
        }
        h.insert(header::CONTENT_LENGTH, HeaderValue::from(self.len));
        resp
    }
}

// ---------------------------------------------------------------------------------------------
// Router
// ---------------------------------------------------------------------------------------------

/// The server's routes, each with its OpenAPI operation: `routes!` takes a route's path and
/// method from the handler's `#[utoipa::path]`, so the router and the description are made from
/// the same attribute and cannot list different paths.
fn routes(state: &AppState) -> OpenApiRouter<AppState> {
    let job_api = OpenApiRouter::new()
        .routes(routes!(submit::submit_job, jobs::list_jobs))
        .routes(routes!(jobs::show_job))
        .routes(routes!(jobs::cancel_job))
        .routes(routes!(jobs::delete_job))
        // Jobs changed after submission (`jobctl.rs`).
        .routes(routes!(jobctl::patch_job))
        .routes(routes!(jobctl::pause_job))
        .routes(routes!(jobctl::resume_job))
        .routes(routes!(jobctl::requeue_job))
        .routes(routes!(jobs::job_log))
        .routes(routes!(jobs::frame_preview))
        .routes(routes!(jobs::frame_file))
        .routes(routes!(jobs::frame_tonemap))
        .routes(routes!(video::video_mp4))
        .routes(routes!(video::video_gif))
        .routes(routes!(status::list_workers))
        .routes(routes!(status::drain_worker))
        .routes(routes!(status::disable_worker))
        .routes(routes!(status::enable_worker))
        .routes(routes!(status::events))
        .route_layer(axum::middleware::from_fn_with_state(state.clone(), auth::require_api_token));
    // The file store: a small JSON question, and uploads streamed to disk under the file cap
    // (read by the handler itself, so no body limit of the router applies to them).
    let files_api = OpenApiRouter::new()
        .routes(routes!(files::missing_files))
        .route_layer(DefaultBodyLimit::max(files::missing_body_limit(state)))
        .routes(routes!(files::put_file))
        .route_layer(axum::middleware::from_fn_with_state(state.clone(), auth::require_api_token));
    let worker_api = OpenApiRouter::new()
        .routes(routes!(worker::register))
        .routes(routes!(worker::lease))
        .routes(routes!(worker::heartbeat))
        .routes(routes!(worker::watch))
        .routes(routes!(worker::result))
        .routes(routes!(worker::fail))
        .routes(routes!(worker::release))
        .routes(routes!(worker::get_bundle))
        .routes(routes!(worker::get_file))
        // Worker requests are small JSON (the tile upload reads its body itself, up to the
        // tile's size): a body past this is refused before it is parsed.
        .route_layer(DefaultBodyLimit::max(MAX_WORKER_JSON_BYTES))
        .route_layer(axum::middleware::from_fn_with_state(state.clone(), auth::require_worker_token));
    // `/metrics` counts jobs and workers: behind the API token like the job API, unless
    // `--public-metrics`.
    let mut metrics = OpenApiRouter::new().routes(routes!(metrics::metrics));
    if !state.settings.access.public_metrics {
        metrics =
            metrics.route_layer(axum::middleware::from_fn_with_state(state.clone(), auth::require_api_token));
    }
    OpenApiRouter::with_openapi(openapi::ApiDoc::openapi())
        .routes(routes!(healthz))
        .routes(routes!(index))
        .routes(routes!(static_file))
        .merge(metrics)
        .routes(routes!(openapi::openapi_json))
        .merge(job_api)
        .merge(files_api)
        .merge(worker_api)
}

pub fn app(state: AppState) -> Router {
    // `Router::layer` puts a layer inside each route, around its handlers and its 405 answer
    // but under the code that adds the 405's `Allow` header: the layers that must see finished
    // answers wrap the whole router as one service instead.
    // Outermost: the `Host` and `Origin` checks, before a body is read, and the security
    // headers on every answer, refusals included.
    let limits = UploadLimits {
        upload: state.settings.max_upload_bytes,
        file: state.settings.bundle_limits.max_file_bytes,
    };
    Router::new()
        .fallback_service(routed(state.clone()))
        .layer(axum::middleware::from_fn_with_state(limits, oversized_uploads))
        .layer(axum::middleware::from_fn(json_errors))
        .layer(axum::middleware::map_response(no_store))
        .layer(axum::middleware::from_fn_with_state(state, browser::guard))
        .layer(axum::middleware::map_response(browser::security_headers))
}

/// The routes with their state, fallback and per-route layers: what [`app`] wraps.
pub(crate) fn routed(state: AppState) -> Router {
    let limit = state.settings.max_upload_bytes;
    let (router, spec) = routes(&state).split_for_parts();
    router
        .fallback(|| async {
            AppError::not_found("no such endpoint; the API lives under /api/v1 (see the README)")
        })
        .layer(axum::Extension(openapi::Spec::new(spec)))
        .layer(DefaultBodyLimit::max(limit))
        .with_state(state)
}

/// The description of the API as `app` serves it (for tests and tools).
pub fn openapi_description(state: &AppState) -> utoipa::openapi::OpenApi {
    routes(state).into_openapi()
}

#[utoipa::path(get, path = "/healthz", tag = "server",
    responses((status = 200, description = "The server is up", content_type = "text/plain", body = String)))]
async fn healthz() -> &'static str {
    "ok\n"
}

#[utoipa::path(get, path = "/", tag = "server",
    responses((status = 200, description = "The status page", content_type = "text/html", body = String)))]
async fn index() -> Response {
    crate::web::page("index.html")
}

#[utoipa::path(get, path = "/static/{name}", tag = "server",
    params(("name" = String, Path, description = "app.js or style.css")),
    responses(
        (status = 200, description = "The status page's script or style sheet", content_type = "text/plain", body = String),
        (status = 404, description = "No such file", body = ApiError)))]
async fn static_file(Path(name): Path<String>) -> Response {
    crate::web::page(&name)
}

/// Longest plain-text error body [`json_errors`] reads (axum's rejections are one line).
const MAX_PLAIN_ERROR: usize = 64 << 10;

/// One error shape everywhere: an error answer that is not JSON already is rewritten as the
/// documented [`ApiError`], keeping its status and headers (a 405's `Allow`). These come from
/// axum itself, before any handler runs: a path parameter that does not parse
/// (`/api/v1/jobs/abc`), a bad query string, a JSON body that is missing, malformed or of the
/// wrong shape, a body over `--max-upload-mb`, a method the route does not answer (405, empty
/// body), a multipart body without its boundary. Their text becomes `error`.
async fn json_errors(req: axum::extract::Request, next: axum::middleware::Next) -> Response {
    let method = req.method().clone();
    let path = req.uri().path().to_string();
    let resp = next.run(req).await;
    let status = resp.status();
    let is_json = resp
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/json"));
    if !(status.is_client_error() || status.is_server_error()) || is_json {
        return resp;
    }
    let (mut parts, body) = resp.into_parts();
    let text = match axum::body::to_bytes(body, MAX_PLAIN_ERROR).await {
        Ok(b) => String::from_utf8_lossy(&b).trim().to_string(),
        Err(_) => String::new(),
    };
    let error = if status == StatusCode::METHOD_NOT_ALLOWED {
        let allow = parts.headers.get(header::ALLOW).and_then(|v| v.to_str().ok()).unwrap_or("");
        format!("{path} does not answer {method}; it answers {allow}")
    } else if text.is_empty() {
        status.canonical_reason().unwrap_or("error").to_string()
    } else {
        text
    };
    parts.headers.remove(header::CONTENT_LENGTH);
    parts.headers.insert(header::CONTENT_TYPE, HeaderValue::from_static("application/json"));
    let body = serde_json::to_vec(&ApiError { error, problems: Vec::new() }).unwrap_or_default();
    Response::from_parts(parts, axum::body::Body::from(body))
}

/// Most bytes of an upload declared too large that [`oversized_uploads`] reads past the limit
/// before answering, and how long it reads.
pub(super) const OVERSIZED_DRAIN_BYTES: u64 = 64 << 20;
pub(super) const OVERSIZED_DRAIN_SECONDS: u64 = 30;

/// The caps [`oversized_uploads`] checks declared lengths against.
#[derive(Clone, Copy)]
struct UploadLimits {
    /// `--max-upload-mb`, in bytes: any request of the job API.
    upload: usize,
    /// `--max-file-mb`, in bytes: an upload to the file store (`PUT /api/v1/files/...`).
    file: u64,
}

/// A request whose `Content-Length` is over `--max-upload-mb` (a worker's JSON request: over
/// [`MAX_WORKER_JSON_BYTES`]; an upload to the file store: over `--max-file-mb`) gets its 413 (with the message that names the limit) without
/// reaching a handler. Many clients (ureq, which the `tessera`
/// client uses, and simple scripts) write the whole body before they read the answer: if the
/// server answered and closed at once, they would see a broken pipe instead of the message. So
/// the rest of the body is read and dropped first, up to `OVERSIZED_DRAIN_BYTES` past the limit
/// and `OVERSIZED_DRAIN_SECONDS` (beyond that the connection closes and such a client does see
/// a broken pipe). A client that sent `Expect: 100-continue` (curl, for large bodies) has sent
/// nothing yet: it is answered at once and sends nothing.
async fn oversized_uploads(
    axum::extract::State(limits): axum::extract::State<UploadLimits>,
    req: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    let declared = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<u64>().ok());
    // A worker's JSON requests are small; its tile upload is checked against the tile's size
    // by its handler.
    let path = req.uri().path();
    let worker_json = path.starts_with("/api/v1/worker/") && !path.ends_with("/result");
    let file_upload = req.method() == axum::http::Method::PUT && path.starts_with("/api/v1/files/");
    let limit = if worker_json {
        MAX_WORKER_JSON_BYTES as u64
    } else if file_upload {
        limits.file
    } else {
        limits.upload as u64
    };
    let Some(declared) = declared.filter(|&n| n > limit) else {
        return next.run(req).await;
    };
    let expects_continue = req
        .headers()
        .get(header::EXPECT)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.eq_ignore_ascii_case("100-continue"));
    if !expects_continue {
        use futures_util::StreamExt;
        let budget = declared.min(limit.saturating_add(OVERSIZED_DRAIN_BYTES));
        let deadline = tokio::time::Instant::now() + std::time::Duration::from_secs(OVERSIZED_DRAIN_SECONDS);
        let mut body = req.into_body().into_data_stream();
        let mut read = 0u64;
        while read < budget {
            match tokio::time::timeout_at(deadline, body.next()).await {
                Ok(Some(Ok(chunk))) => read += chunk.len() as u64,
                _ => break,
            }
        }
    }
    if worker_json {
        return AppError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!(
                "a worker request's body may hold at most {} KiB of JSON; this one declares {declared} bytes",
                MAX_WORKER_JSON_BYTES >> 10
            ),
        )
        .into_response();
    }
    if file_upload {
        return files::file_too_large(limit).into_response();
    }
    submit::upload_too_large(limits.upload).into_response()
}

/// Answers change from one moment to the next: browsers must not reuse them.
async fn no_store(mut resp: Response) -> Response {
    resp.headers_mut().entry(header::CACHE_CONTROL).or_insert(HeaderValue::from_static("no-store"));
    resp
}
