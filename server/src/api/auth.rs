//! Who may call what: the bearer-token middleware of the job API and of the worker protocol.

use axum::extract::State;
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};

use super::{AppError, AppState};

pub(super) fn bearer(headers: &HeaderMap) -> Option<&str> {
    headers.get(header::AUTHORIZATION)?.to_str().ok()?.strip_prefix("Bearer ").map(str::trim)
}

/// Constant-time comparison, so a token cannot be guessed byte by byte from response times.
pub(super) fn same_token(a: &str, b: &str) -> bool {
    a.len() == b.len() && a.bytes().zip(b.bytes()).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

pub(super) async fn require_api_token(
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

/// Whether a request comes from one of the server's own local workers (their token).
pub(super) fn is_local_worker(state: &AppState, headers: &HeaderMap) -> bool {
    bearer(headers).is_some_and(|t| same_token(t, &state.settings.local_worker_token))
}

/// The worker token, or the local workers' own.
pub(super) async fn require_worker_token(
    State(state): State<AppState>,
    req: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    match bearer(req.headers()) {
        Some(t)
            if same_token(t, &state.settings.worker_token)
                || same_token(t, &state.settings.local_worker_token) =>
        {
            next.run(req).await
        }
        _ => AppError::new(
            StatusCode::UNAUTHORIZED,
            "missing or wrong worker token: give the farm's worker token (--token or TESSERA_WORKER_TOKEN); \
             on the server's machine `tessera-server worker-token` prints it (it is kept in the file \
             worker-token of the server's data directory)",
        )
        .into_response(),
    }
}
