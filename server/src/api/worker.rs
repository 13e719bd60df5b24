//! The worker protocol over HTTP: register, lease, heartbeat, watch, result, fail, release and
//! bundle download; each checks its request, leaves the rules to [`crate::scheduler`] and answers
//! with the status the protocol promises.

use axum::Json;
use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use tessera::protocol::*;

use super::{ApiResult, AppError, AppState};
use crate::db::{FailOutcome, ResultOutcome};
use crate::merge::merge_frame;
use crate::scheduler::LeaseWait;

#[utoipa::path(post, path = "/api/v1/worker/register", tag = "worker", security(("worker_token" = [])), request_body = RegisterRequest,
    responses((status = 200, description = "The worker's id and the farm's clock", body = RegisterResponse), (status = 400, description = "The body is not JSON", body = ApiError), (status = 415, description = "The body is not sent as application/json", body = ApiError), (status = 422, description = "The JSON does not have the request's shape", body = ApiError), (status = 401, description = "Missing or wrong worker token", body = ApiError)))]
pub(super) async fn register(
    State(state): State<AppState>,
    Json(req): Json<RegisterRequest>,
) -> ApiResult<Json<RegisterResponse>> {
    let id = state.store.register_worker(&req.name, req.threads)?;
    tracing::info!(worker = id, name = %req.name, threads = req.threads, "worker registered");
    state.emit(ServerEvent::Workers);
    let timing = state.scheduler.timing();
    Ok(Json(RegisterResponse {
        worker_id: id,
        heartbeat_seconds: timing.heartbeat_seconds,
        lease_seconds: timing.lease_seconds,
    }))
}

fn known_worker(state: &AppState, id: u64) -> ApiResult<()> {
    if state.store.worker_exists(id)? {
        Ok(())
    } else {
        Err(AppError::new(StatusCode::NOT_FOUND, format!("unknown worker {id}; register again")))
    }
}

/// Long poll: a lease as soon as a tile is free, or 204 after the wait.
#[utoipa::path(post, path = "/api/v1/worker/lease", tag = "worker", security(("worker_token" = [])), request_body = LeaseRequest,
    responses(
        (status = 200, description = "A tile to render", body = Lease),
        (status = 204, description = "Nothing became free within the wait"),
        (status = 400, description = "The body is not JSON", body = ApiError), (status = 415, description = "The body is not sent as application/json", body = ApiError), (status = 422, description = "The JSON does not have the request's shape", body = ApiError), (status = 401, description = "Missing or wrong worker token", body = ApiError), (status = 404, description = "Unknown worker: register again", body = ApiError),
        (status = 503, description = "The server is shutting down (with Retry-After)", body = ApiError)))]
pub(super) async fn lease(
    State(state): State<AppState>,
    Json(req): Json<LeaseRequest>,
) -> ApiResult<Response> {
    known_worker(&state, req.worker_id)?;
    Ok(match state.scheduler.lease(req.worker_id, req.wait_seconds).await? {
        LeaseWait::Granted(lease) => Json(lease).into_response(),
        LeaseWait::NoWork => StatusCode::NO_CONTENT.into_response(),
        LeaseWait::ShuttingDown => {
            // An error, not "no work": workers back off on errors, while they ask again at once
            // after a 204, which would spin until the server is gone.
            let mut response = AppError::new(
                StatusCode::SERVICE_UNAVAILABLE,
                "the server is shutting down; ask again later",
            )
            .into_response();
            response.headers_mut().insert(header::RETRY_AFTER, HeaderValue::from_static("5"));
            response
        }
    })
}

#[utoipa::path(post, path = "/api/v1/worker/heartbeat", tag = "worker", security(("worker_token" = [])), request_body = HeartbeatRequest,
    responses((status = 200, description = "The leases renewed; those no longer the worker's", body = HeartbeatResponse), (status = 400, description = "The body is not JSON", body = ApiError), (status = 415, description = "The body is not sent as application/json", body = ApiError), (status = 422, description = "The JSON does not have the request's shape", body = ApiError), (status = 401, description = "Missing or wrong worker token", body = ApiError), (status = 404, description = "Unknown worker: register again", body = ApiError)))]
pub(super) async fn heartbeat(
    State(state): State<AppState>,
    Json(req): Json<HeartbeatRequest>,
) -> ApiResult<Json<HeartbeatResponse>> {
    known_worker(&state, req.worker_id)?;
    let revoked = state.scheduler.heartbeat(req.worker_id, &req.leases, req.rendering)?;
    Ok(Json(HeartbeatResponse { revoked }))
}

/// Long poll: answers as soon as one of the worker's listed leases is no longer its own (its
/// job was cancelled or failed), else after the wait with nothing revoked.
#[utoipa::path(post, path = "/api/v1/worker/watch", tag = "worker", security(("worker_token" = [])), request_body = WatchRequest,
    responses((status = 200, description = "Leases revoked (as soon as one is), or none after the wait", body = HeartbeatResponse), (status = 400, description = "The body is not JSON", body = ApiError), (status = 415, description = "The body is not sent as application/json", body = ApiError), (status = 422, description = "The JSON does not have the request's shape", body = ApiError), (status = 401, description = "Missing or wrong worker token", body = ApiError), (status = 404, description = "Unknown worker: register again", body = ApiError)))]
pub(super) async fn watch(
    State(state): State<AppState>,
    Json(req): Json<WatchRequest>,
) -> ApiResult<Json<HeartbeatResponse>> {
    known_worker(&state, req.worker_id)?;
    let revoked = state.scheduler.watch(req.worker_id, req.leases, req.wait_seconds).await?;
    Ok(Json(HeartbeatResponse { revoked }))
}

#[utoipa::path(put, path = "/api/v1/worker/leases/{lease}/result", tag = "worker", security(("worker_token" = [])),
    params(
        ("lease" = u64, Path, description = "The lease's id"),
        ("x-tessera-worker" = u64, Header, description = "The worker's id"),
        ("x-tessera-checksum" = String, Header, description = "FNV-1a 64 of the body, 16 hex digits"),
        ("x-tessera-render-seconds" = Option<f64>, Header, description = "Seconds the worker spent rendering the tile (shown in the job's log)")),
    request_body(content = super::openapi::Binary, content_type = "application/octet-stream", description = "The tile: width x height RGB triples of little-endian f32, row-major"),
    responses(
        (status = 204, description = "Stored (committed before this answer)"),
        (status = 400, description = "A missing header, a checksum that does not match, or the wrong size", body = ApiError),
        (status = 401, description = "Missing or wrong worker token", body = ApiError),
        (status = 409, description = "The lease is not the worker's any more: drop the tile", body = ApiError),
        (status = 413, description = "The body is over the server's upload limit", body = ApiError)))]
pub(super) async fn result(
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
    let render_seconds = headers
        .get(RENDER_SECONDS_HEADER)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<f64>().ok())
        .filter(|s| s.is_finite() && *s >= 0.0);
    match state.scheduler.result(lease, worker, &body, render_seconds)? {
        ResultOutcome::Accepted { job_id, frame, frame_complete, .. } => {
            if frame_complete {
                let state = state.clone();
                tokio::spawn(async move { merge_frame(state, job_id, frame).await });
            }
            Ok(StatusCode::NO_CONTENT)
        }
        ResultOutcome::Conflict => Err(AppError::new(
            StatusCode::CONFLICT,
            format!("lease {lease} is not yours any more (expired, revoked or already done); drop the tile"),
        )),
        ResultOutcome::WrongSize { expected } => Err(AppError::bad_request(format!(
            "the tile holds {} bytes; its rectangle needs {expected} (width x height x 3 little-endian f32)",
            body.len()
        ))),
    }
}

#[utoipa::path(post, path = "/api/v1/worker/leases/{lease}/fail", tag = "worker", security(("worker_token" = [])), params(("lease" = u64, Path, description = "The lease's id")), request_body = FailRequest,
    responses(
        (status = 204, description = "Recorded: the tile is queued again or its job failed"),
        (status = 400, description = "The body is not JSON", body = ApiError), (status = 415, description = "The body is not sent as application/json", body = ApiError), (status = 422, description = "The JSON does not have the request's shape", body = ApiError), (status = 401, description = "Missing or wrong worker token", body = ApiError),
        (status = 409, description = "The lease is not the worker's any more", body = ApiError)))]
pub(super) async fn fail(
    State(state): State<AppState>,
    Path(lease): Path<u64>,
    Json(req): Json<FailRequest>,
) -> ApiResult<StatusCode> {
    match state.scheduler.fail(lease, req.worker_id, &req.error, req.fatal)? {
        FailOutcome::Requeued | FailOutcome::JobFailed { .. } => Ok(StatusCode::NO_CONTENT),
        FailOutcome::Conflict => {
            Err(AppError::new(StatusCode::CONFLICT, format!("lease {lease} is not yours any more")))
        }
    }
}

/// A stopping worker gives back a lease it has not started: the tile is queued again at once.
#[utoipa::path(post, path = "/api/v1/worker/leases/{lease}/release", tag = "worker", security(("worker_token" = [])), params(("lease" = u64, Path, description = "The lease's id")), request_body = ReleaseRequest,
    responses(
        (status = 204, description = "The tile is queued again"),
        (status = 400, description = "The body is not JSON", body = ApiError), (status = 415, description = "The body is not sent as application/json", body = ApiError), (status = 422, description = "The JSON does not have the request's shape", body = ApiError), (status = 401, description = "Missing or wrong worker token", body = ApiError),
        (status = 409, description = "Not a live lease of this worker", body = ApiError)))]
pub(super) async fn release(
    State(state): State<AppState>,
    Path(lease): Path<u64>,
    Json(req): Json<ReleaseRequest>,
) -> ApiResult<StatusCode> {
    if state.scheduler.release(lease, req.worker_id)? {
        Ok(StatusCode::NO_CONTENT)
    } else {
        Err(AppError::new(
            StatusCode::CONFLICT,
            format!("lease {lease} is not a live lease of worker {}", req.worker_id),
        ))
    }
}

#[utoipa::path(get, path = "/api/v1/worker/bundles/{hash}", tag = "worker", security(("worker_token" = [])),
    params(("hash" = String, Path, description = "SHA-256 of the bundle, as the lease names it")),
    responses(
        (status = 200, description = "The job's files as a tar archive", content_type = "application/x-tar", body = super::openapi::Binary),
        (status = 401, description = "Missing or wrong worker token", body = ApiError),
        (status = 404, description = "No such bundle", body = ApiError)))]
pub(super) async fn get_bundle(
    State(state): State<AppState>,
    Path(hash): Path<String>,
) -> ApiResult<Response> {
    let blobs = state.blobs.clone();
    let h = hash.clone();
    let bytes = tokio::task::spawn_blocking(move || blobs.get(&h))
        .await
        .map_err(|e| anyhow::anyhow!("bundle task: {e}"))?
        .ok_or_else(|| AppError::not_found(format!("no bundle {hash}")))?;
    Ok(([(header::CONTENT_TYPE, HeaderValue::from_static("application/x-tar"))], bytes).into_response())
}
