//! The worker protocol over HTTP: register, lease, heartbeat, watch, result, fail, release and
//! bundle download; each checks its request, leaves the rules to [`crate::scheduler`] and answers
//! with the status the protocol promises.

use axum::Json;
use axum::extract::{Path, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use tessera::protocol::*;

use super::{ApiResult, AppError, AppState, off_thread};
use crate::db::{FailOutcome, ResultBody, ResultOutcome};
use crate::merge::merge_frame;
use crate::scheduler::LeaseWait;

#[utoipa::path(post, path = "/api/v1/worker/register", tag = "worker", security(("worker_token" = [])), request_body = RegisterRequest,
    responses((status = 200, description = "The worker's id and the farm's clock", body = RegisterResponse), (status = 400, description = "The body is not JSON", body = ApiError), (status = 415, description = "The body is not sent as application/json", body = ApiError), (status = 422, description = "The JSON does not have the request's shape", body = ApiError), (status = 401, description = "Missing or wrong worker token", body = ApiError),
        (status = 429, description = "Too many registrations with the worker token: ask again after `Retry-After` seconds", body = ApiError),
        (status = 503, description = "As many workers as the server takes (`--max-workers`) are live: ask again after `Retry-After` seconds", body = ApiError)))]
pub(super) async fn register(
    State(state): State<AppState>,
    headers: HeaderMap,
    Json(req): Json<RegisterRequest>,
) -> ApiResult<Response> {
    check_name(&req.name)?;
    if !(1..=MAX_WORKER_THREADS).contains(&req.threads) {
        return Err(AppError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            format!("threads must be from 1 to {MAX_WORKER_THREADS}, found {}", req.threads),
        ));
    }
    let tags = check_tags(&req.tags).map_err(|e| {
        AppError::new(StatusCode::UNPROCESSABLE_ENTITY, format!("tags: {e} (tessera-worker work --tags)"))
    })?;
    // A worker of another protocol would misread leases (or write results this server
    // misreads): refused, saying so. One that sends none (older, or hand-written) is taken.
    if req.protocol != 0
        && let Some(why) =
            tessera::protocol::protocol_mismatch(req.protocol, tessera::protocol::WORKER_PROTOCOL)
    {
        return Err(AppError::new(StatusCode::UNPROCESSABLE_ENTITY, format!("protocol: {why}")));
    }
    // The server's own local workers are not counted: one restarted always gets back in.
    let local = super::auth::is_local_worker(&state, &headers);
    if !local && let Err(wait) = state.registrations.take() {
        use crate::registrations::{REGISTRATION_BURST, REGISTRATIONS_PER_SECOND};
        let seconds = wait.as_secs_f64().ceil().max(1.0) as u64;
        return Ok(with_retry_after(
            AppError::new(
                StatusCode::TOO_MANY_REQUESTS,
                format!(
                    "too many worker registrations: this server registers at most {REGISTRATIONS_PER_SECOND} workers a \
                     second ({REGISTRATION_BURST} at once) with the worker token; ask again in {seconds} s (a worker \
                     registers once, when it starts)"
                ),
            ),
            seconds,
        ));
    }
    let secret = crate::random_token();
    let hash = crate::bundle::sha256_hex(secret.as_bytes());
    let timing = *state.scheduler.timing();
    let lost_after = crate::scheduler::lost_after(timing.heartbeat_seconds);
    let max_live = (!local).then_some(state.settings.max_workers);
    let registered = {
        let (state, name) = (state.clone(), req.name.clone());
        let live_since = crate::db::now() - lost_after;
        off_thread(move || {
            let w =
                crate::db::NewWorker { name: &name, threads: req.threads, secret_hash: &hash, tags: &tags };
            if local {
                // The same row as this worker's earlier lives (this server's earlier runs, or
                // before the server restarted it), its dead process's leases expired first.
                return Ok(crate::db::Registered::Id(state.scheduler.register_local_worker(&w)?));
            }
            Ok(state.store.register_new_worker(&w, max_live, live_since)?)
        })
        .await?
    };
    let id = match registered {
        crate::db::Registered::Id(id) => id,
        crate::db::Registered::Full { live } => {
            let seconds = lost_after.ceil() as u64;
            return Ok(with_retry_after(
                AppError::new(
                    StatusCode::SERVICE_UNAVAILABLE,
                    format!(
                        "this farm has {live} live workers, the most it takes (--max-workers, TESSERA_MAX_WORKERS); \
                         ask again when one has stopped (a worker silent for {lost_after} s no longer counts), or \
                         start the server with a larger --max-workers"
                    ),
                ),
                seconds,
            ));
        }
    };
    tracing::info!(worker = id, name = %req.name, threads = req.threads, "worker registered");
    state.emit(ServerEvent::Workers);
    Ok(Json(RegisterResponse {
        worker_id: id,
        worker_secret: secret,
        heartbeat_seconds: timing.heartbeat_seconds,
        lease_seconds: timing.lease_seconds,
        protocol: tessera::protocol::WORKER_PROTOCOL,
    })
    .into_response())
}

/// `e` as an answer that says when to ask again.
fn with_retry_after(e: AppError, seconds: u64) -> Response {
    let mut response = e.into_response();
    response.headers_mut().insert(header::RETRY_AFTER, HeaderValue::from(seconds));
    response
}

/// A worker's name as the page and the logs show it: at most [`MAX_WORKER_NAME`] bytes, not
/// empty, no control characters.
fn check_name(name: &str) -> ApiResult<()> {
    let problem = if name.trim().is_empty() {
        "is empty"
    } else if name.len() > MAX_WORKER_NAME {
        "is too long"
    } else if name.chars().any(char::is_control) {
        "holds control characters"
    } else {
        return Ok(());
    };
    Err(AppError::new(
        StatusCode::UNPROCESSABLE_ENTITY,
        format!(
            "the worker's name {problem}: give a name of 1 to {MAX_WORKER_NAME} bytes without control characters (--name)"
        ),
    ))
}

/// Checks that the caller is registered worker `id`. The middleware has checked the worker
/// token; this checks the secret the worker got at registration ([`WORKER_SECRET_HEADER`]), so
/// a holder of the worker token cannot act as another worker. An unknown worker is a 404
/// (register again), a missing or wrong secret a 401.
fn authenticate(state: &AppState, headers: &HeaderMap, id: u64) -> ApiResult<()> {
    let given = headers.get(WORKER_SECRET_HEADER).and_then(|v| v.to_str().ok());
    let Some(stored) = state.store.worker_secret_hash(id)? else {
        return Err(AppError::new(StatusCode::NOT_FOUND, format!("unknown worker {id}; register again")));
    };
    match (given, stored) {
        (Some(secret), Some(hash))
            if super::auth::same_token(&crate::bundle::sha256_hex(secret.as_bytes()), &hash) =>
        {
            Ok(())
        }
        (None, _) => Err(AppError::new(
            StatusCode::UNAUTHORIZED,
            format!(
                "missing header {WORKER_SECRET_HEADER}: send the worker_secret that registration answered"
            ),
        )),
        _ => Err(AppError::new(
            StatusCode::UNAUTHORIZED,
            format!(
                "wrong {WORKER_SECRET_HEADER} for worker {id}: a worker may only act for itself; register again"
            ),
        )),
    }
}

/// [`authenticate`] on the blocking pool (it reads the store).
async fn authenticated(state: &AppState, headers: &HeaderMap, id: u64) -> ApiResult<()> {
    let (state, headers) = (state.clone(), headers.clone());
    off_thread(move || authenticate(&state, &headers, id)).await
}

/// Refuses a list of more leases than any worker may hold.
fn check_listed(leases: &[u64]) -> ApiResult<()> {
    if leases.len() > MAX_LISTED_LEASES {
        return Err(AppError::bad_request(format!(
            "the request lists {} leases; a worker holds at most {MAX_LISTED_LEASES} (its threads + 2)",
            leases.len()
        )));
    }
    Ok(())
}

/// Long poll: a lease as soon as a tile is free, or 204 after the wait.
#[utoipa::path(post, path = "/api/v1/worker/lease", tag = "worker", security(("worker_token" = [], "worker_secret" = [])), request_body = LeaseRequest,
    responses(
        (status = 200, description = "A tile to render", body = Lease),
        (status = 204, description = "Nothing became free within the wait"),
        (status = 400, description = "The body is not JSON", body = ApiError), (status = 415, description = "The body is not sent as application/json", body = ApiError), (status = 422, description = "The JSON does not have the request's shape", body = ApiError), (status = 401, description = "Missing or wrong worker token or worker secret", body = ApiError), (status = 404, description = "Unknown worker: register again", body = ApiError),
        (status = 503, description = "The server is shutting down (with Retry-After)", body = ApiError)))]
pub(super) async fn lease(
    State(state): State<AppState>,
    headers: HeaderMap,
    Json(req): Json<LeaseRequest>,
) -> ApiResult<Response> {
    authenticated(&state, &headers, req.worker_id).await?;
    Ok(match state.scheduler.lease(req.worker_id, req.wait_seconds).await? {
        LeaseWait::Granted(lease) => Json(lease).into_response(),
        LeaseWait::Full { held, allowed } => AppError::new(
            StatusCode::TOO_MANY_REQUESTS,
            format!(
                "worker {} holds {held} live leases, the most a worker of its threads may (threads + 2 = {allowed}); \
                 render, report or release one first",
                req.worker_id
            ),
        )
        .into_response(),
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

#[utoipa::path(post, path = "/api/v1/worker/heartbeat", tag = "worker", security(("worker_token" = [], "worker_secret" = [])), request_body = HeartbeatRequest,
    responses((status = 200, description = "The leases renewed; those no longer the worker's", body = HeartbeatResponse), (status = 400, description = "The body is not JSON", body = ApiError), (status = 415, description = "The body is not sent as application/json", body = ApiError), (status = 422, description = "The JSON does not have the request's shape", body = ApiError), (status = 401, description = "Missing or wrong worker token or worker secret", body = ApiError), (status = 404, description = "Unknown worker: register again", body = ApiError)))]
pub(super) async fn heartbeat(
    State(state): State<AppState>,
    headers: HeaderMap,
    Json(req): Json<HeartbeatRequest>,
) -> ApiResult<Json<HeartbeatResponse>> {
    check_listed(&req.leases)?;
    off_thread(move || {
        authenticate(&state, &headers, req.worker_id)?;
        let revoked = state.scheduler.heartbeat(req.worker_id, &req.leases, req.rendering)?;
        Ok(Json(HeartbeatResponse { revoked }))
    })
    .await
}

/// Long poll: answers as soon as one of the worker's listed leases is no longer its own (its
/// job was cancelled or failed), else after the wait with nothing revoked.
#[utoipa::path(post, path = "/api/v1/worker/watch", tag = "worker", security(("worker_token" = [], "worker_secret" = [])), request_body = WatchRequest,
    responses((status = 200, description = "Leases revoked (as soon as one is), or none after the wait", body = HeartbeatResponse), (status = 400, description = "The body is not JSON", body = ApiError), (status = 415, description = "The body is not sent as application/json", body = ApiError), (status = 422, description = "The JSON does not have the request's shape", body = ApiError), (status = 401, description = "Missing or wrong worker token or worker secret", body = ApiError), (status = 404, description = "Unknown worker: register again", body = ApiError)))]
pub(super) async fn watch(
    State(state): State<AppState>,
    headers: HeaderMap,
    Json(req): Json<WatchRequest>,
) -> ApiResult<Json<HeartbeatResponse>> {
    check_listed(&req.leases)?;
    authenticated(&state, &headers, req.worker_id).await?;
    let revoked = state.scheduler.watch(req.worker_id, req.leases, req.wait_seconds).await?;
    Ok(Json(HeartbeatResponse { revoked }))
}

#[utoipa::path(put, path = "/api/v1/worker/leases/{lease}/result", tag = "worker", security(("worker_token" = [], "worker_secret" = [])),
    params(
        ("lease" = u64, Path, description = "The lease's id"),
        ("x-tessera-worker" = u64, Header, description = "The worker's id"),
        ("x-tessera-checksum" = String, Header, description = "CRC-32 (IEEE, as zlib computes it) of the body, 8 hex digits"),
        ("x-tessera-render-seconds" = Option<f64>, Header, description = "Seconds the worker spent rendering the tile (shown in the job's log)")),
    request_body(content = super::openapi::Binary, content_type = "application/octet-stream", description = "The tile: width x height RGB triples of little-endian f32, row-major; for a lease with `aux` (a denoised job), then the albedo and the normal the same way. For a lease with `pass`: each pixel's block sums instead of the colour (four little-endian i128: R, G, B in units of 2^-40, and the odd blocks' luminance), then the features when `aux` is set"),
    responses(
        (status = 204, description = "Stored (committed before this answer)"),
        (status = 400, description = "A missing header, a checksum that does not match, the wrong size, a value that is not a finite number, or a pass's sum larger than its samples can add up to", body = ApiError),
        (status = 401, description = "Missing or wrong worker token or worker secret", body = ApiError),
        (status = 409, description = "The lease is not the worker's any more: drop the tile", body = ApiError),
        (status = 413, description = "The body goes past the tile's size (width x height x 12 bytes)", body = ApiError),
        (status = 507, description = "The server's disk is full: nothing was stored; send the tile again later", body = ApiError)))]
pub(super) async fn result(
    State(state): State<AppState>,
    Path(lease): Path<u64>,
    headers: HeaderMap,
    body: axum::body::Body,
) -> ApiResult<StatusCode> {
    let worker: u64 = headers
        .get("x-tessera-worker")
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse().ok())
        .ok_or_else(|| AppError::bad_request("missing header x-tessera-worker (the worker id)"))?;
    let declared = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<u64>().ok());
    if let Err(refused) = authenticated(&state, &headers, worker).await {
        // As for a lease that is gone (below): a worker that writes before it reads gets the
        // 401 or 404, not a connection reset over its unread body.
        drain(body, declared.unwrap_or(0).min(MAX_TILE_BYTES), DRAIN_SECONDS).await;
        return Err(refused);
    }
    let sum = headers
        .get(CHECKSUM_HEADER)
        .and_then(|v| v.to_str().ok())
        .ok_or_else(|| AppError::bad_request(format!("missing header {CHECKSUM_HEADER}")))?
        .to_string();
    // The lease says how many bytes its tile has: the body is read up to that and no further.
    let expected = {
        let state = state.clone();
        off_thread(move || Ok(state.store.result_size(lease, worker)?)).await?
    };
    let Some(shape) = expected else {
        // Read what a worker that writes before it reads is still sending (a tile's worth at
        // most, for a while), so that it gets the 409 rather than a broken pipe.
        drain(body, declared.unwrap_or(0).min(MAX_TILE_BYTES), DRAIN_SECONDS).await;
        state.scheduler.counters().results_refused.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        return Err(lease_gone(lease));
    };
    let expected = shape.bytes();
    let wrong_size = |got: String| {
        AppError::bad_request(format!(
            "the tile holds {got} bytes; its lease needs {expected} (width x height x 3 little-endian f32, three times that for a denoised job; 64 bytes a pixel for a pass's sums)"
        ))
    };
    if let Some(n) = declared.filter(|&n| n != expected as u64) {
        return Err(wrong_size(n.to_string()));
    }
    let body = read_at_most(body, expected).await.map_err(|e| match e {
        BodyError::TooLong => AppError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!(
                "the tile's body goes past the {expected} bytes its lease needs (width x height x 3 little-endian f32, three times that for a denoised job; 64 bytes a pixel for a pass's sums); nothing was stored"
            ),
        ),
        BodyError::Broken(e) => AppError::bad_request(format!("the tile's body could not be read: {e}")),
    })?;
    if body.len() != expected {
        return Err(wrong_size(body.len().to_string()));
    }
    if sum != checksum(&body) {
        return Err(AppError::bad_request(
            "the tile's checksum (CRC-32 of the body, 8 hex digits) does not match its bytes; send it again (a worker of another Tessera version computes another: run the same version as the server)",
        ));
    }
    // Finished pixels (and features) must be finite numbers; a pass's sums must be within what
    // its blocks of samples can reach.
    let floats = match shape.blocks {
        None => &body[..],
        Some(blocks) => {
            use tessera::passes::{PassResultError, decode_pass_result};
            match decode_pass_result(&body, shape.pixels, blocks) {
                Ok((_, features)) => features,
                Err(PassResultError::WrongSize { .. }) => return Err(wrong_size(body.len().to_string())),
                Err(e @ PassResultError::OutOfRange { .. }) => {
                    return Err(AppError::bad_request(format!("{e}; nothing was stored")));
                }
            }
        }
    };
    if floats.len() % 12 != 0 {
        return Err(wrong_size(body.len().to_string()));
    }
    if let Some((i, c, v)) = first_not_finite(floats) {
        return Err(AppError::bad_request(format!(
            "the tile's pixel {i} (row-major), channel {c}, is {v}: tile values must be finite numbers; nothing was stored"
        )));
    }
    let render_seconds = headers
        .get(RENDER_SECONDS_HEADER)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<f64>().ok())
        .filter(|s| s.is_finite() && *s >= 0.0);
    // A large tile's pixels (a whole frame) go to a file of their own before its row commits
    // (`db::results`); a pass's sums always to the row, which adds them up at once.
    let as_file = shape.blocks.is_none() && body.len() >= crate::db::FILE_RESULT_BYTES;
    // The result is stored, and what its storing starts (the frame's merge, a pass's picture) is
    // started, in one blocking task: that runs to its end even when the worker hangs up meanwhile
    // (a killed worker; the server then drops this handler), so a frame is never left stored
    // whole and unmerged.
    let runtime = tokio::runtime::Handle::current();
    let outcome = {
        let state = state.clone();
        off_thread(move || {
            let outcome = if as_file {
                let name = state.store.write_result_file(lease, &body)?;
                let file = ResultBody::File { name: &name, len: body.len() };
                let outcome = state.scheduler.result(lease, worker, file, render_seconds);
                // Not taken (the lease is gone, or the store failed): its row does not name it.
                if !matches!(outcome, Ok(ResultOutcome::Accepted { .. })) {
                    state.store.remove_result_files(std::slice::from_ref(&name));
                }
                outcome?
            } else {
                state.scheduler.result(lease, worker, ResultBody::Bytes(&body), render_seconds)?
            };
            if let ResultOutcome::Accepted { job_id, frame, frame_complete, pass_published, .. } = outcome {
                if frame_complete {
                    runtime.spawn(merge_frame(state, job_id, frame));
                } else if pass_published.is_some() {
                    runtime.spawn(crate::merge::publish_pass(state, job_id, frame));
                }
            }
            Ok(outcome)
        })
        .await?
    };
    match outcome {
        ResultOutcome::Accepted { .. } => Ok(StatusCode::NO_CONTENT),
        ResultOutcome::Conflict => Err(lease_gone(lease)),
        ResultOutcome::WrongSize { expected } => Err(AppError::bad_request(format!(
            "the tile's lease needs {expected} bytes (width x height x 3 little-endian f32, three times that for a denoised job; 64 bytes a pixel for a pass's sums)"
        ))),
    }
}

/// The first value of a tile's little-endian f32s that is not a finite number, as (pixel,
/// channel, value): read off the bytes, without decoding the tile (a whole frame is 7.7 MB).
fn first_not_finite(floats: &[u8]) -> Option<(usize, usize, f32)> {
    let word = |w: &[u8]| u32::from_le_bytes([w[0], w[1], w[2], w[3]]);
    // An exponent of all ones: an infinity or a NaN.
    let bad = |w: &[u8]| word(w) & 0x7f80_0000 == 0x7f80_0000;
    let k = floats.chunks_exact(4).position(bad)?;
    Some((k / 3, k % 3, f32::from_bits(word(&floats[k * 4..]))))
}

fn lease_gone(lease: u64) -> AppError {
    AppError::new(
        StatusCode::CONFLICT,
        format!("lease {lease} is not yours any more (expired, revoked or already done); drop the tile"),
    )
}

/// The largest tile body: a tile of the largest tile size (4096 x 4096 pixels).
const MAX_TILE_BYTES: u64 = 4096 * 4096 * 12;
/// How long a refused upload's rest is read before the connection is closed.
const DRAIN_SECONDS: u64 = 30;

enum BodyError {
    TooLong,
    Broken(String),
}

/// Reads a body of at most `max` bytes, stopping as soon as it goes past: a body that claims
/// nothing (chunked) or lies about its length costs no more memory than the tile it should be.
async fn read_at_most(body: axum::body::Body, max: usize) -> Result<Vec<u8>, BodyError> {
    use futures_util::StreamExt;
    let mut stream = body.into_data_stream();
    let mut out = Vec::with_capacity(max);
    while let Some(chunk) = stream.next().await {
        let chunk = chunk.map_err(|e| BodyError::Broken(e.to_string()))?;
        if out.len() + chunk.len() > max {
            return Err(BodyError::TooLong);
        }
        out.extend_from_slice(&chunk);
    }
    Ok(out)
}

/// Reads and drops up to `max` bytes of a body for at most `seconds`.
async fn drain(body: axum::body::Body, max: u64, seconds: u64) {
    use futures_util::StreamExt;
    let deadline = tokio::time::Instant::now() + std::time::Duration::from_secs(seconds);
    let mut stream = body.into_data_stream();
    let mut read = 0u64;
    while read < max {
        match tokio::time::timeout_at(deadline, stream.next()).await {
            Ok(Some(Ok(chunk))) => read += chunk.len() as u64,
            _ => break,
        }
    }
}

#[utoipa::path(post, path = "/api/v1/worker/leases/{lease}/fail", tag = "worker", security(("worker_token" = [], "worker_secret" = [])), params(("lease" = u64, Path, description = "The lease's id")), request_body = FailRequest,
    responses(
        (status = 204, description = "Recorded: the tile is queued again or its job failed"),
        (status = 400, description = "The body is not JSON", body = ApiError), (status = 415, description = "The body is not sent as application/json", body = ApiError), (status = 422, description = "The JSON does not have the request's shape", body = ApiError), (status = 401, description = "Missing or wrong worker token", body = ApiError),
        (status = 409, description = "The lease is not the worker's any more", body = ApiError)))]
pub(super) async fn fail(
    State(state): State<AppState>,
    Path(lease): Path<u64>,
    headers: HeaderMap,
    Json(req): Json<FailRequest>,
) -> ApiResult<StatusCode> {
    off_thread(move || {
        authenticate(&state, &headers, req.worker_id)?;
        // The message goes into the job's error and log: a few KiB say what went wrong.
        let error = truncate_message(&req.error, MAX_ERROR_BYTES);
        match state.scheduler.fail(lease, req.worker_id, &error, req.fatal)? {
            FailOutcome::Requeued | FailOutcome::JobFailed { .. } => Ok(StatusCode::NO_CONTENT),
            FailOutcome::Conflict => {
                Err(AppError::new(StatusCode::CONFLICT, format!("lease {lease} is not yours any more")))
            }
        }
    })
    .await
}

/// A stopping worker gives back a lease it has not started: the tile is queued again at once.
#[utoipa::path(post, path = "/api/v1/worker/leases/{lease}/release", tag = "worker", security(("worker_token" = [], "worker_secret" = [])), params(("lease" = u64, Path, description = "The lease's id")), request_body = ReleaseRequest,
    responses(
        (status = 204, description = "The tile is queued again"),
        (status = 400, description = "The body is not JSON", body = ApiError), (status = 415, description = "The body is not sent as application/json", body = ApiError), (status = 422, description = "The JSON does not have the request's shape", body = ApiError), (status = 401, description = "Missing or wrong worker token", body = ApiError),
        (status = 409, description = "Not a live lease of this worker", body = ApiError)))]
pub(super) async fn release(
    State(state): State<AppState>,
    Path(lease): Path<u64>,
    headers: HeaderMap,
    Json(req): Json<ReleaseRequest>,
) -> ApiResult<StatusCode> {
    off_thread(move || {
        authenticate(&state, &headers, req.worker_id)?;
        if state.scheduler.release(lease, req.worker_id)? {
            Ok(StatusCode::NO_CONTENT)
        } else {
            Err(AppError::new(
                StatusCode::CONFLICT,
                format!("lease {lease} is not a live lease of worker {}", req.worker_id),
            ))
        }
    })
    .await
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
    // Streamed from its file as the worker reads it: a large bundle costs no more memory than
    // a small one, however many workers fetch it at once.
    let file = match state.blobs.stored_path(&hash) {
        Some(path) => super::FileBody::open(&path).await.ok(),
        None => None,
    };
    let file = file.ok_or_else(|| AppError::not_found(format!("no bundle {hash}")))?;
    Ok(file.into_response_with(&[(header::CONTENT_TYPE, HeaderValue::from_static("application/x-tar"))]))
}

#[utoipa::path(get, path = "/api/v1/worker/files/{sha256}", tag = "worker", security(("worker_token" = [])),
    params(("sha256" = String, Path, description = "SHA-256 of the file (64 lowercase hex digits): a job's manifest, as the lease names it, or a file the manifest lists")),
    responses(
        (status = 200, description = "The file's bytes", content_type = "application/octet-stream", body = super::openapi::Binary),
        (status = 401, description = "Missing or wrong worker token", body = ApiError),
        (status = 404, description = "The server has no such file", body = ApiError)))]
pub(super) async fn get_file(
    State(state): State<AppState>,
    Path(sha256): Path<String>,
) -> ApiResult<Response> {
    // Streamed from the file store as the worker reads it, like a bundle.
    let file = match state.files.path(&sha256) {
        Some(path) => super::FileBody::open(&path).await.ok(),
        None => None,
    };
    let file = file.ok_or_else(|| AppError::not_found(format!("no file {sha256}")))?;
    Ok(file
        .into_response_with(&[(header::CONTENT_TYPE, HeaderValue::from_static("application/octet-stream"))]))
}

#[cfg(test)]
mod tests {
    use super::first_not_finite;

    #[test]
    fn the_first_value_that_is_not_a_finite_number_is_found_in_the_bytes() {
        let px = [[0.0f32, 1.5, -2.0], [f32::MAX, f32::MIN_POSITIVE, 1e-45]];
        assert_eq!(first_not_finite(&tessera::protocol::encode_tile(&px)), None);
        for (bad, at) in [(f32::INFINITY, (1, 1)), (f32::NEG_INFINITY, (0, 2)), (f32::NAN, (1, 0))] {
            let mut p = px;
            p[at.0][at.1] = bad;
            let (i, c, v) = first_not_finite(&tessera::protocol::encode_tile(&p)).unwrap();
            assert_eq!((i, c), at);
            assert_eq!(v.to_bits(), bad.to_bits());
        }
    }
}
