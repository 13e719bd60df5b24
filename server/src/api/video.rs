//! A job's video (`video.rs` makes it): `GET /api/v1/jobs/ID/video.mp4` and `.gif`, streamed
//! from the server's folder of the job.

use axum::extract::{Path, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use tessera::protocol::*;

use super::{ApiResult, AppError, AppState, off_thread};

/// The first byte range of a `Range: bytes=...` header for a file of `len` bytes, as (start,
/// length); `None` when there is none or it is not of that form (the whole file is answered),
/// `Some(Err(()))` when it lies past the end (416).
fn byte_range(headers: &HeaderMap, len: u64) -> Option<Result<(u64, u64), ()>> {
    let spec = headers.get(header::RANGE)?.to_str().ok()?.trim().strip_prefix("bytes=")?;
    let first = spec.split(',').next()?.trim();
    let (a, b) = first.split_once('-')?;
    let (start, end) = match (a.trim(), b.trim()) {
        ("", "") => return None,
        // The last `n` bytes.
        ("", n) => {
            let n: u64 = n.parse().ok()?;
            (len.saturating_sub(n), len.saturating_sub(1))
        }
        (a, "") => (a.parse().ok()?, len.saturating_sub(1)),
        (a, b) => (a.parse().ok()?, b.parse::<u64>().ok()?.min(len.saturating_sub(1))),
    };
    if start >= len || end < start {
        return Some(Err(()));
    }
    Some(Ok((start, end - start + 1)))
}

/// The video of `kind` of job `id`, or a 404 (409 while it is being made) saying what there is.
/// A `Range` request (players seek) gets those bytes (206).
async fn video_file(state: AppState, id: u64, kind: VideoKind, headers: HeaderMap) -> ApiResult<Response> {
    let st = state.clone();
    let path = off_thread(move || {
        let Some(job) = st.store.job(id)? else {
            return Err(AppError::not_found(format!("there is no job {id}")));
        };
        let name = crate::video::file_name(kind);
        let frames = st.store.frames(id)?;
        let Some(video) = crate::video::info(&st, &job, &frames)? else {
            return Err(AppError::not_found(format!(
                "job {id} makes no video (submit with video=mp4 or video=gif)"
            )));
        };
        if video.kind != kind {
            return Err(AppError::not_found(format!(
                "job {id} has no {name}: its video is {}",
                crate::video::file_name(video.kind)
            )));
        }
        match video.state.as_str() {
            "done" => Ok(crate::video::video_path(&st.settings.data_dir, id, kind)),
            "failed" => Err(AppError::not_found(format!(
                "job {id} has no {name}: {}",
                video.message.unwrap_or_else(|| "its encoding failed".into())
            ))),
            s => Err(AppError::new(
                StatusCode::CONFLICT,
                format!(
                    "job {id}'s {name} is not made yet ({s}); ask again once the job's video.state is done"
                ),
            )),
        }
    })
    .await?;
    let file = super::FileBody::open(&path)
        .await
        .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", path.display()))?;
    let mime = match kind {
        VideoKind::Gif => "image/gif",
        _ => "video/mp4",
    };
    let len = file.len();
    let mut answer = vec![
        (header::CONTENT_TYPE, HeaderValue::from_static(mime)),
        (header::ACCEPT_RANGES, HeaderValue::from_static("bytes")),
    ];
    match byte_range(&headers, len) {
        None => Ok(file.into_response_with(&answer)),
        Some(Err(())) => {
            let mut refusal = AppError::new(
                StatusCode::RANGE_NOT_SATISFIABLE,
                format!("the range asked for lies past the end of the video ({len} bytes)"),
            )
            .into_response();
            if let Ok(v) = HeaderValue::from_str(&format!("bytes */{len}")) {
                refusal.headers_mut().insert(header::CONTENT_RANGE, v);
            }
            Ok(refusal)
        }
        Some(Ok((start, n))) => {
            let part = file
                .range(start, n)
                .await
                .map_err(|e| anyhow::anyhow!("cannot seek {}: {e}", path.display()))?;
            if let Ok(v) = HeaderValue::from_str(&format!("bytes {start}-{}/{len}", start + n - 1)) {
                answer.push((header::CONTENT_RANGE, v));
            }
            let mut resp = part.into_response_with(&answer);
            *resp.status_mut() = StatusCode::PARTIAL_CONTENT;
            Ok(resp)
        }
    }
}

#[utoipa::path(get, path = "/api/v1/jobs/{id}/video.mp4", tag = "jobs", security((), ("api_token" = [])),
    params(("id" = u64, Path, description = "The job's id")),
    responses(
        (status = 200, description = "The job's video, H.264 in MP4 (yuv420p, +faststart), once the job's `video.state` is done", content_type = "video/mp4", body = super::openapi::Binary),
        (status = 206, description = "The bytes a `Range: bytes=A-B` header asked for (players seek)", content_type = "video/mp4", body = super::openapi::Binary),
        (status = 416, description = "The range lies past the end of the file", body = ApiError),
        (status = 400, description = "A path parameter does not parse", body = ApiError), (status = 401, description = "The server needs an API token", body = ApiError),
        (status = 404, description = "No such job, the job makes no MP4, or its video failed (the message says why)", body = ApiError),
        (status = 409, description = "The video is not made yet (the job's frames are rendering or it is encoding)", body = ApiError)))]
pub(super) async fn video_mp4(
    State(state): State<AppState>,
    Path(id): Path<u64>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    video_file(state, id, VideoKind::Mp4, headers).await
}

#[utoipa::path(get, path = "/api/v1/jobs/{id}/video.gif", tag = "jobs", security((), ("api_token" = [])),
    params(("id" = u64, Path, description = "The job's id")),
    responses(
        (status = 200, description = "The job's video as an animated GIF (looping), once the job's `video.state` is done", content_type = "image/gif", body = super::openapi::Binary),
        (status = 206, description = "The bytes a `Range: bytes=A-B` header asked for", content_type = "image/gif", body = super::openapi::Binary),
        (status = 416, description = "The range lies past the end of the file", body = ApiError),
        (status = 400, description = "A path parameter does not parse", body = ApiError), (status = 401, description = "The server needs an API token", body = ApiError),
        (status = 404, description = "No such job, the job makes no GIF, or its video failed (the message says why)", body = ApiError),
        (status = 409, description = "The video is not made yet (the job's frames are rendering or it is encoding)", body = ApiError)))]
pub(super) async fn video_gif(
    State(state): State<AppState>,
    Path(id): Path<u64>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    video_file(state, id, VideoKind::Gif, headers).await
}
