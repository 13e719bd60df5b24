//! A job changed after its submission: paused, resumed, requeued (its unfinished frames, or
//! frames chosen, rendered again) and its priority set. Each answers the job's JSON; each
//! change is an event in the job's log and a `job` event of the status stream.

use axum::Json;
use axum::extract::{Path, State};
use axum::http::StatusCode;
use serde_json::{Map, Value};
use tessera::protocol::*;

use super::jobs::job_info;
use super::{ApiResult, AppError, AppState, off_thread};
use crate::db::{Control, Requeued};

/// Longest JSON body of these requests.
const MAX_BODY: usize = 16 << 10;

/// The job's JSON after a change.
fn answer(state: &AppState, id: u64) -> ApiResult<Json<JobInfo>> {
    Ok(Json(job_info(state, id)?.ok_or_else(|| anyhow::anyhow!("job {id} vanished"))?))
}

fn no_such_job(id: u64) -> AppError {
    AppError::not_found(format!("there is no job {id}"))
}

/// The body as a JSON object of only the fields `allowed` (an empty body: no fields), or a 400
/// naming what is wrong and what `route` takes (`example`). The body is read only up to
/// [`MAX_BODY`]: a larger one is refused without being held in memory.
async fn object(
    body: axum::body::Body,
    allowed: &[&str],
    route: &str,
    example: &str,
) -> ApiResult<Map<String, Value>> {
    use futures_util::StreamExt;
    let too_large = || {
        AppError::bad_request(format!(
            "{route} takes a JSON object of at most {} KiB such as {example}",
            MAX_BODY >> 10
        ))
    };
    let mut kept = Vec::new();
    let mut stream = body.into_data_stream();
    while let Some(chunk) = stream.next().await {
        let chunk =
            chunk.map_err(|e| AppError::bad_request(format!("{route}: the body was cut off: {e}")))?;
        if kept.len() + chunk.len() > MAX_BODY {
            // Read on and drop, within the bounds oversized uploads get, so that a client that
            // writes its whole body before reading the answer sees the message, not a broken
            // pipe; past them the connection closes.
            let deadline =
                tokio::time::Instant::now() + std::time::Duration::from_secs(super::OVERSIZED_DRAIN_SECONDS);
            let mut read = (kept.len() + chunk.len()) as u64;
            while read < super::OVERSIZED_DRAIN_BYTES {
                match tokio::time::timeout_at(deadline, stream.next()).await {
                    Ok(Some(Ok(c))) => read += c.len() as u64,
                    _ => break,
                }
            }
            return Err(too_large());
        }
        kept.extend_from_slice(&chunk);
    }
    let body: &[u8] = &kept;
    if body.iter().all(u8::is_ascii_whitespace) {
        return Ok(Map::new());
    }
    let value: Value = serde_json::from_slice(body).map_err(|e| {
        AppError::bad_request(format!(
            "{route} takes a JSON object such as {example}; the body is not JSON: {e}"
        ))
    })?;
    let Value::Object(map) = value else {
        return Err(AppError::bad_request(format!(
            "{route} takes a JSON object such as {example}, found {value}"
        )));
    };
    let unknown: Vec<String> =
        map.keys().filter(|k| !allowed.contains(&k.as_str())).map(|k| format!("\"{k}\"")).collect();
    if !unknown.is_empty() {
        return Err(AppError::bad_request(format!(
            "unknown field(s) {}; {route} takes only {}",
            unknown.join(", "),
            allowed.join(", ")
        )));
    }
    Ok(map)
}

#[utoipa::path(post, path = "/api/v1/jobs/{id}/pause", tag = "jobs", security((), ("api_token" = [])), params(("id" = u64, Path, description = "The job's id")),
    responses(
        (status = 200, description = "Paused: no more of its tiles are leased; the leases already out finish and their results are kept. `resume` goes on", body = JobInfo),
        (status = 400, description = "A path parameter does not parse", body = ApiError), (status = 401, description = "The server needs an API token", body = ApiError), (status = 404, description = "No such job", body = ApiError),
        (status = 409, description = "The job is paused already, or has ended (the message names its state)", body = ApiError)))]
pub(super) async fn pause_job(
    State(state): State<AppState>,
    Path(id): Path<u64>,
) -> ApiResult<Json<JobInfo>> {
    off_thread(move || match state.store.pause_job(id)? {
        Control::NoSuchJob => Err(no_such_job(id)),
        Control::Refused(JobState::Paused) => Err(AppError::new(
            StatusCode::CONFLICT,
            format!("job {id} is paused already; resume it with tessera resume {id}"),
        )),
        Control::Refused(s) => Err(AppError::new(
            StatusCode::CONFLICT,
            format!(
                "job {id} has already ended ({}); only a queued or running job can be paused",
                s.as_str()
            ),
        )),
        Control::Changed(out) => {
            tracing::info!(job = id, leases_out = out, "job paused");
            state.scheduler.job_changed(id, JobState::Paused);
            answer(&state, id)
        }
    })
    .await
}

#[utoipa::path(post, path = "/api/v1/jobs/{id}/resume", tag = "jobs", security((), ("api_token" = [])), params(("id" = u64, Path, description = "The job's id")),
    responses(
        (status = 200, description = "Resumed: queued again, or running when some of its work is done", body = JobInfo),
        (status = 400, description = "A path parameter does not parse", body = ApiError), (status = 401, description = "The server needs an API token", body = ApiError), (status = 404, description = "No such job", body = ApiError),
        (status = 409, description = "The job is not paused (the message names its state)", body = ApiError)))]
pub(super) async fn resume_job(
    State(state): State<AppState>,
    Path(id): Path<u64>,
) -> ApiResult<Json<JobInfo>> {
    off_thread(move || match state.store.resume_job(id)? {
        Control::NoSuchJob => Err(no_such_job(id)),
        Control::Refused(s) => Err(AppError::new(
            StatusCode::CONFLICT,
            format!("job {id} is {}, not paused; only a paused job can be resumed", s.as_str()),
        )),
        Control::Changed(now) => {
            tracing::info!(job = id, state = now.as_str(), "job resumed");
            state.scheduler.job_changed(id, now);
            answer(&state, id)
        }
    })
    .await
}

/// Renders frames of a finished job again, without submitting it again.
#[utoipa::path(post, path = "/api/v1/jobs/{id}/requeue", tag = "jobs", security((), ("api_token" = [])), params(("id" = u64, Path, description = "The job's id")),
    request_body(content = Option<RequeueRequest>, description = "Optional. Without `frames`: every unfinished frame of a failed or cancelled job renders again, with fresh retry counts. With `frames` (0-based indexes and ranges, e.g. \"0-9,12\"; any finished job, a done one too): those frames render again from the start, their outputs replaced when done (a sequence's video is made again)", content_type = "application/json"),
    responses(
        (status = 200, description = "Requeued: the job is queued; its log tells which frames render again", body = JobInfo),
        (status = 400, description = "The body or its frame list does not parse, names an unknown field, or names a frame past the job's last", body = ApiError),
        (status = 401, description = "The server needs an API token", body = ApiError), (status = 404, description = "No such job", body = ApiError),
        (status = 409, description = "The job is queued, running or paused (only a finished job is requeued), or it is done and no frames were named", body = ApiError)))]
pub(super) async fn requeue_job(
    State(state): State<AppState>,
    Path(id): Path<u64>,
    body: axum::body::Body,
) -> ApiResult<Json<JobInfo>> {
    const ROUTE: &str = "POST /api/v1/jobs/{id}/requeue";
    let map = object(body, &["frames"], ROUTE, r#"{"frames": "0-9,12"}"#).await?;
    let frames = match map.get("frames") {
        None | Some(Value::Null) => None,
        Some(Value::String(s)) => Some(s.clone()),
        Some(Value::Number(n)) if n.is_u64() => Some(n.to_string()),
        Some(other) => {
            return Err(AppError::bad_request(format!(
                "frames must be a string of 0-based frame indexes and ranges such as \"0-9,12\", found {other}"
            )));
        }
    };
    let ranges = frames
        .as_deref()
        .map(parse_frame_list)
        .transpose()
        .map_err(|e| AppError::bad_request(format!("frames: {e}")))?;
    off_thread(move || match state.store.requeue_job(id, ranges.as_deref())? {
        Control::NoSuchJob => Err(no_such_job(id)),
        Control::Refused(s) => Err(AppError::new(
            StatusCode::CONFLICT,
            format!(
                "job {id} is {}; only a finished job (done, failed or cancelled) can be requeued: wait for it to end, \
                 or cancel it first (tessera cancel {id})",
                s.as_str()
            ),
        )),
        Control::Changed(Requeued::NothingUnfinished) => Err(AppError::new(
            StatusCode::CONFLICT,
            format!(
                "job {id} has no unfinished frame; name the frames to render again, e.g. {{\"frames\": \"0-2\"}} \
                 (tessera requeue {id} --frames 0-2)"
            ),
        )),
        Control::Changed(Requeued::Busy) => Err(AppError::new(
            StatusCode::CONFLICT,
            format!("job {id} is being requeued already; see its state in a moment (tessera status {id})"),
        )),
        Control::Changed(Requeued::NoSuchFrame { asked, frames }) => Err(AppError::bad_request(format!(
            "frames: job {id} has {frames} frame(s), numbered 0 to {} (0-based, as frames[].index); there is no frame {asked}",
            frames.saturating_sub(1)
        ))),
        Control::Changed(Requeued::Queued { frames, units }) => {
            tracing::info!(job = id, frames = %tessera::protocol::frame_ranges(&frames), units, "job requeued");
            // A frame's pass files from before are not this render's.
            for &f in &frames {
                for name in crate::merge::PASS_FILES {
                    let _ = std::fs::remove_file(state.server_frame_dir(id, f).join(name));
                }
            }
            state.scheduler.job_changed(id, JobState::Queued);
            answer(&state, id)
        }
    })
    .await
}

/// Changes a job after its submission; only its priority for now.
#[utoipa::path(patch, path = "/api/v1/jobs/{id}", tag = "jobs", security((), ("api_token" = [])), params(("id" = u64, Path, description = "The job's id")),
    request_body(content = JobPatch, description = "The fields to change: only `priority` (an integer, higher first) for now", content_type = "application/json"),
    responses(
        (status = 200, description = "Changed: the next lease goes by the new priority", body = JobInfo),
        (status = 400, description = "The body is not JSON, names an unknown field, or its priority is not a 64-bit integer", body = ApiError),
        (status = 401, description = "The server needs an API token", body = ApiError), (status = 404, description = "No such job", body = ApiError),
        (status = 409, description = "The job has ended (the message names its state)", body = ApiError)))]
pub(super) async fn patch_job(
    State(state): State<AppState>,
    Path(id): Path<u64>,
    body: axum::body::Body,
) -> ApiResult<Json<JobInfo>> {
    const ROUTE: &str = "PATCH /api/v1/jobs/{id}";
    let map = object(body, &["priority"], ROUTE, r#"{"priority": 10}"#).await?;
    let priority = match map.get("priority") {
        None => {
            return Err(AppError::bad_request(format!(
                r#"{ROUTE} needs the field to change, e.g. {{"priority": 10}}"#
            )));
        }
        Some(Value::Number(n)) if n.is_i64() => n.as_i64().unwrap_or_default(),
        Some(other) => {
            return Err(AppError::bad_request(format!(
                "priority must be an integer from {} to {}, found {other}",
                i64::MIN,
                i64::MAX
            )));
        }
    };
    off_thread(move || match state.store.set_priority(id, priority)? {
        Control::NoSuchJob => Err(no_such_job(id)),
        Control::Refused(s) => Err(AppError::new(
            StatusCode::CONFLICT,
            format!("job {id} has ended ({}); its priority no longer orders anything", s.as_str()),
        )),
        Control::Changed(old) => {
            tracing::info!(job = id, old, priority, "job priority changed");
            let now = state.store.job(id)?.map_or(JobState::Queued, |j| j.state);
            state.scheduler.job_changed(id, now);
            answer(&state, id)
        }
    })
    .await
}
