//! A job's video (`video.rs` makes it): `GET /api/v1/jobs/ID/video.mp4` and `.gif`, streamed
//! from the server's folder of the job.

use axum::extract::{Path, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::Response;
use tessera::protocol::*;

use super::{ApiResult, AppError, AppState, off_thread};

/// The video of `kind` of job `id`, or a 404 (409 while it is being made) saying what there is.
async fn video_file(state: AppState, id: u64, kind: VideoKind) -> ApiResult<Response> {
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
    Ok(file.into_response_with(&[(header::CONTENT_TYPE, HeaderValue::from_static(mime))]))
}

#[utoipa::path(get, path = "/api/v1/jobs/{id}/video.mp4", tag = "jobs", security((), ("api_token" = [])),
    params(("id" = u64, Path, description = "The job's id")),
    responses(
        (status = 200, description = "The job's video, H.264 in MP4 (yuv420p, +faststart), once the job's `video.state` is done", content_type = "video/mp4", body = super::openapi::Binary),
        (status = 400, description = "A path parameter does not parse", body = ApiError), (status = 401, description = "The server needs an API token", body = ApiError),
        (status = 404, description = "No such job, the job makes no MP4, or its video failed (the message says why)", body = ApiError),
        (status = 409, description = "The video is not made yet (the job's frames are rendering or it is encoding)", body = ApiError)))]
pub(super) async fn video_mp4(State(state): State<AppState>, Path(id): Path<u64>) -> ApiResult<Response> {
    video_file(state, id, VideoKind::Mp4).await
}

#[utoipa::path(get, path = "/api/v1/jobs/{id}/video.gif", tag = "jobs", security((), ("api_token" = [])),
    params(("id" = u64, Path, description = "The job's id")),
    responses(
        (status = 200, description = "The job's video as an animated GIF (looping), once the job's `video.state` is done", content_type = "image/gif", body = super::openapi::Binary),
        (status = 400, description = "A path parameter does not parse", body = ApiError), (status = 401, description = "The server needs an API token", body = ApiError),
        (status = 404, description = "No such job, the job makes no GIF, or its video failed (the message says why)", body = ApiError),
        (status = 409, description = "The video is not made yet (the job's frames are rendering or it is encoding)", body = ApiError)))]
pub(super) async fn video_gif(State(state): State<AppState>, Path(id): Path<u64>) -> ApiResult<Response> {
    video_file(state, id, VideoKind::Gif).await
}
