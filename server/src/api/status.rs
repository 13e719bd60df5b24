//! What the status page follows besides the jobs: the workers list and the server-sent event
//! stream.

use axum::Json;
use axum::extract::{Path, State};
use axum::response::{IntoResponse, Response};

use tessera::protocol::{ApiError, ServerEvent, WorkerInfo, WorkerList, WorkerTile};

use super::{ApiResult, AppError, AppState, off_thread};
use crate::db::{WorkerMode, WorkerRow};

/// A worker's row as the API shows it.
fn worker_info(state: &AppState, w: WorkerRow, t: f64) -> WorkerInfo {
    WorkerInfo {
        state: state.scheduler.worker_state(&w, t).as_str().to_string(),
        id: w.id,
        name: w.name,
        threads: w.threads,
        current_tile: w.current_tile.map(|(job, frame, tile)| WorkerTile { job, frame, tile }),
        last_heartbeat: w.last_seen,
        tiles_done: w.tiles_done,
        failures: w.failures,
        mode: w.mode.as_str().to_string(),
        tags: w.tags,
    }
}

#[utoipa::path(get, path = "/api/v1/workers", tag = "status", security((), ("api_token" = [])),
    responses((status = 200, description = "Every registered worker, but those silent for longer than `--forget-workers-after` (forgotten: the job logs keep their names)", body = WorkerList), (status = 401, description = "The server needs an API token", body = ApiError)))]
pub(super) async fn list_workers(State(state): State<AppState>) -> ApiResult<Json<WorkerList>> {
    let rows = {
        let state = state.clone();
        let since = crate::db::now() - state.settings.forget_workers_after;
        off_thread(move || Ok(state.store.workers_seen_since(since)?)).await?
    };
    let t = crate::db::now();
    let workers: Vec<WorkerInfo> = rows.into_iter().map(|w| worker_info(&state, w, t)).collect();
    Ok(Json(WorkerList { workers }))
}

/// Sets a worker's mode and answers with the worker as it is then.
async fn set_mode(state: AppState, id: u64, mode: WorkerMode) -> ApiResult<Json<WorkerInfo>> {
    off_thread(move || {
        if state.scheduler.set_worker_mode(id, mode)?.is_none() {
            return Err(AppError::not_found(format!(
                "no worker {id}; GET /api/v1/workers lists them (a worker gone long enough is forgotten)"
            )));
        }
        let row = state.store.workers()?.into_iter().find(|w| w.id == id);
        let row = row.ok_or_else(|| AppError::not_found(format!("worker {id} was just forgotten")))?;
        Ok(Json(worker_info(&state, row, crate::db::now())))
    })
    .await
}

#[utoipa::path(post, path = "/api/v1/workers/{id}/drain", tag = "status", security((), ("api_token" = [])),
    params(("id" = u64, Path, description = "The worker's id")),
    responses((status = 200, description = "The worker finishes what it holds and takes no new work", body = WorkerInfo),
        (status = 404, description = "No such worker", body = ApiError), (status = 401, description = "The server needs an API token", body = ApiError)))]
pub(super) async fn drain_worker(
    State(state): State<AppState>,
    Path(id): Path<u64>,
) -> ApiResult<Json<WorkerInfo>> {
    set_mode(state, id, WorkerMode::Draining).await
}

#[utoipa::path(post, path = "/api/v1/workers/{id}/disable", tag = "status", security((), ("api_token" = [])),
    params(("id" = u64, Path, description = "The worker's id")),
    responses((status = 200, description = "The worker takes no work; the tiles it held are queued again (it stops rendering them at its next heartbeat)", body = WorkerInfo),
        (status = 404, description = "No such worker", body = ApiError), (status = 401, description = "The server needs an API token", body = ApiError)))]
pub(super) async fn disable_worker(
    State(state): State<AppState>,
    Path(id): Path<u64>,
) -> ApiResult<Json<WorkerInfo>> {
    set_mode(state, id, WorkerMode::Disabled).await
}

#[utoipa::path(post, path = "/api/v1/workers/{id}/enable", tag = "status", security((), ("api_token" = [])),
    params(("id" = u64, Path, description = "The worker's id")),
    responses((status = 200, description = "The worker takes work again", body = WorkerInfo),
        (status = 404, description = "No such worker", body = ApiError), (status = 401, description = "The server needs an API token", body = ApiError)))]
pub(super) async fn enable_worker(
    State(state): State<AppState>,
    Path(id): Path<u64>,
) -> ApiResult<Json<WorkerInfo>> {
    set_mode(state, id, WorkerMode::Active).await
}

/// Server-sent events for the status page: every [`tessera::protocol::ServerEvent`] as it happens.
/// The stream's events are named by `ServerEvent`'s `type` (plus `resync`: reload everything).
#[utoipa::path(get, path = "/api/v1/events", tag = "status", security((), ("api_token" = [])),
    responses(
        (status = 200, description = "Server-sent events, each one a ServerEvent as JSON", content_type = "text/event-stream", body = ServerEvent),
        (status = 401, description = "The server needs an API token", body = ApiError)))]
pub(super) async fn events(State(state): State<AppState>) -> Response {
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
