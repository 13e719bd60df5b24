//! What the status page follows besides the jobs: the workers list and the server-sent event
//! stream.

use axum::Json;
use axum::extract::State;
use axum::response::{IntoResponse, Response};

use tessera::protocol::{ApiError, ServerEvent, WorkerInfo, WorkerList, WorkerTile};

use super::{ApiResult, AppState, off_thread};

#[utoipa::path(get, path = "/api/v1/workers", tag = "status", security((), ("api_token" = [])),
    responses((status = 200, description = "Every registered worker", body = WorkerList), (status = 401, description = "The server needs an API token", body = ApiError)))]
pub(super) async fn list_workers(State(state): State<AppState>) -> ApiResult<Json<WorkerList>> {
    let rows = {
        let state = state.clone();
        off_thread(move || Ok(state.store.workers()?)).await?
    };
    let t = crate::db::now();
    let workers: Vec<WorkerInfo> = rows
        .into_iter()
        .map(|w| WorkerInfo {
            state: state.scheduler.worker_state(&w, t).as_str().to_string(),
            id: w.id,
            name: w.name,
            threads: w.threads,
            current_tile: w.current_tile.map(|(job, frame, tile)| WorkerTile { job, frame, tile }),
            last_heartbeat: w.last_seen,
            tiles_done: w.tiles_done,
            failures: w.failures,
        })
        .collect();
    Ok(Json(WorkerList { workers }))
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
