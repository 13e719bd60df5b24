//! The worker protocol over HTTP: register, lease (long poll), heartbeat, watch (long poll),
//! result, fail, release and bundle download, each checking its request and answering with the
//! status the protocol promises.

use std::sync::atomic::Ordering;
use std::time::Duration;

use axum::Json;
use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use tessera::protocol::*;

use super::{ApiResult, AppError, AppState};
use crate::db::{FailOutcome, ResultOutcome};
use crate::merge::merge_frame;

pub(super) async fn register(
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
pub(super) async fn lease(
    State(state): State<AppState>,
    Json(req): Json<LeaseRequest>,
) -> ApiResult<Response> {
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

pub(super) async fn heartbeat(
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
pub(super) async fn watch(
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

pub(super) async fn fail(
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
pub(super) async fn release(
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
