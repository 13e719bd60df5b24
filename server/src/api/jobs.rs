//! The job API's views and controls: jobs listed, shown and cancelled, and each frame's output
//! files, live preview and re-tone-mapped picture.

use axum::Json;
use axum::extract::{Path, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use tessera::camera::Camera;
use tessera::protocol::*;

use super::{ApiResult, AppError, AppState, off_thread};
use crate::merge;

fn tone_params(p: &tessera::tonemap::params::Photographic) -> ToneParams {
    ToneParams { key: p.key, burn: p.burn_percent, saturation: p.saturation, gamma: p.gamma.to_string() }
}

/// The parameters a camera's HDR output is tone-mapped with, if it is HDR.
fn camera_tonemap(cam: &Camera) -> Option<tessera::tonemap::params::Photographic> {
    merge::display_tonemap(cam).map(|(_, p)| p)
}

/// Jobs of more frames than this are listed (`GET /api/v1/jobs`) without their frames: their
/// `frame_counts` summarise them, and the job's own `GET` lists every one.
pub const LISTED_FRAMES: usize = 32;

pub(crate) fn job_info(state: &AppState, id: u64) -> anyhow::Result<Option<JobInfo>> {
    job_info_with(state, id, usize::MAX)
}

/// [`job_info`], its `frames` left out when there are more than `max_frames`.
fn job_info_with(state: &AppState, id: u64, max_frames: usize) -> anyhow::Result<Option<JobInfo>> {
    let Some(job) = state.store.job(id)? else { return Ok(None) };
    let frames = state.store.frames(id)?;
    let started = if job.state.is_final() { Default::default() } else { state.store.frames_leased(id)? };
    let mut frame_counts = FrameCounts::default();
    for f in &frames {
        if f.outputs.is_some() {
            frame_counts.done += 1;
        } else if f.tiles_done > 0 || f.passes_published > 0 || started.contains(&f.index) {
            frame_counts.rendering += 1;
        } else {
            frame_counts.queued += 1;
        }
    }
    let listed = if frames.len() > max_frames { &frames[..0] } else { &frames[..] };
    // Progress by samples, from each frame's counters (no scan of its tiles).
    let bound = |f: &crate::db::FrameRow| {
        job.noise_target.is_some() && f.outputs.is_none() && f.samples_done < f.samples_total()
    };
    let spp = |f: &crate::db::FrameRow| {
        let pixels = (u64::from(f.width) * u64::from(f.height)).max(1);
        u32::try_from(f.samples_done / pixels).unwrap_or(u32::MAX)
    };
    let sequence = job.scenes > 1;
    let cameras = state.frame_cameras(&job).ok();
    let url = format!("/api/v1/jobs/{id}");
    let mut error = job.error.clone();
    if error.is_none() && !job.state.is_final() {
        // Tile failures that have not failed the job yet are worth seeing too.
        let recent = state.store.recent_failures(id)?;
        if !recent.is_empty() {
            error = Some(format!("retrying after tile failures: {}", recent.join("; ")));
        }
    }
    Ok(Some(JobInfo {
        id,
        name: job.name.clone(),
        state: job.state,
        priority: job.priority,
        tile_size: job.tile_size,
        samples: job.samples,
        denoise: job.denoise,
        submitted_at: job.submitted_at,
        started_at: job.started_at,
        finished_at: job.finished_at,
        frames: listed
            .iter()
            .map(|f| FrameInfo {
                index: f.index,
                camera: f.camera,
                image_name: f.image_name.clone(),
                width: f.width,
                height: f.height,
                tiles_total: f.tiles_total,
                tiles_done: f.tiles_done,
                outputs: f
                    .outputs
                    .iter()
                    .flatten()
                    .map(|n| OutputInfo {
                        name: n.clone(),
                        url: format!("{url}/frames/{}/files/{n}", f.index),
                    })
                    .collect(),
                preview_url: format!("{url}/frames/{}/preview.png", f.index),
                samples: f.samples,
                passes_total: f.passes_total,
                passes_done: f.passes_published,
                // Listed once written: the store counts a pass as published in the transaction
                // of its last tile, and `merge::publish_pass` writes the files just after (the
                // PNG last).
                pass_outputs: if f.outputs.is_none()
                    && f.passes_published > 0
                    && state.server_frame_dir(id, f.index).join(crate::merge::PASS_FILES[1]).exists()
                {
                    crate::merge::PASS_FILES
                        .iter()
                        .map(|n| OutputInfo {
                            name: n.to_string(),
                            url: format!("{url}/frames/{}/files/{n}", f.index),
                        })
                        .collect()
                } else {
                    Vec::new()
                },
                tonemap: cameras
                    .as_ref()
                    .and_then(|c| c.get(f.index as usize))
                    .and_then(camera_tonemap)
                    .map(|p| tone_params(&p)),
                tonemap_url: float_output(f.outputs.as_deref())
                    .map(|_| format!("{url}/frames/{}/tonemap.png", f.index)),
                scene: if sequence { f.scene_path.clone() } else { None },
                samples_done: f.samples_done,
                samples_total: f.samples_total(),
                samples_total_is_bound: bound(f),
                spp: spp(f),
                pass: if f.outputs.is_some() {
                    f.passes_total
                } else {
                    (f.passes_published + 1).min(f.passes_total.max(1))
                },
                pass_denoised_url: (job.denoise
                    && f.outputs.is_none()
                    && f.passes_published > 0
                    && state.server_frame_dir(id, f.index).join(crate::storage::PASS_DENOISED_FILE).exists())
                .then(|| format!("{url}/frames/{}/files/{}", f.index, crate::storage::PASS_DENOISED_FILE)),
            })
            .collect(),
        frame_counts,
        scenes: job.scenes,
        video: crate::video::info(state, &job, &frames)?,
        samples_done: frames.iter().fold(0u64, |a, f| a.saturating_add(f.samples_done)),
        samples_total: frames.iter().fold(0u64, |a, f| a.saturating_add(f.samples_total())),
        samples_total_is_bound: frames.iter().any(bound),
        error,
        warnings: Vec::new(),
        url,
        // Said only while nothing moves: a job with a tile on a worker is being served.
        waiting_for: if matches!(job.state, JobState::Queued | JobState::Running) && started.is_empty() {
            state.scheduler.waiting_for(&job.worker_tags)?
        } else {
            None
        },
        worker_tags: job.worker_tags,
    }))
}

#[utoipa::path(get, path = "/api/v1/jobs", tag = "jobs", security((), ("api_token" = [])),
    responses((status = 200, description = "Every job, newest first. A job of more than 32 frames (a sequence) is listed with `frames` empty: its `frame_counts` say how many are done, rendering and queued, and `GET /api/v1/jobs/{id}` lists every frame", body = JobList), (status = 401, description = "The server needs an API token", body = ApiError)))]
pub(super) async fn list_jobs(State(state): State<AppState>) -> ApiResult<Json<JobList>> {
    off_thread(move || {
        let ids: Vec<u64> = state.store.jobs()?.iter().map(|j| j.id).collect();
        let mut jobs = Vec::new();
        for id in ids {
            jobs.extend(job_info_with(&state, id, LISTED_FRAMES)?);
        }
        Ok(Json(JobList { jobs }))
    })
    .await
}

#[utoipa::path(get, path = "/api/v1/jobs/{id}", tag = "jobs", security((), ("api_token" = [])), params(("id" = u64, Path, description = "The job's id")),
    responses((status = 200, description = "The job", body = JobInfo), (status = 400, description = "A path parameter or query does not parse", body = ApiError), (status = 401, description = "The server needs an API token", body = ApiError), (status = 404, description = "No such job", body = ApiError)))]
pub(super) async fn show_job(State(state): State<AppState>, Path(id): Path<u64>) -> ApiResult<Json<JobInfo>> {
    off_thread(move || {
        job_info(&state, id)?.map(Json).ok_or_else(|| AppError::not_found(format!("there is no job {id}")))
    })
    .await
}

#[utoipa::path(post, path = "/api/v1/jobs/{id}/cancel", tag = "jobs", security((), ("api_token" = [])), params(("id" = u64, Path, description = "The job's id")),
    responses(
        (status = 200, description = "Cancelled: its leases are revoked, no more tiles are handed out", body = JobInfo),
        (status = 400, description = "A path parameter or query does not parse", body = ApiError), (status = 401, description = "The server needs an API token", body = ApiError), (status = 404, description = "No such job", body = ApiError),
        (status = 409, description = "The job has already ended", body = ApiError)))]
pub(super) async fn cancel_job(
    State(state): State<AppState>,
    Path(id): Path<u64>,
) -> ApiResult<Json<JobInfo>> {
    off_thread(move || {
        let Some(job) = state.store.job(id)? else {
            return Err(AppError::not_found(format!("there is no job {id}")));
        };
        if !state.scheduler.cancel(id)? {
            return Err(AppError::new(
                StatusCode::CONFLICT,
                format!("job {id} has already ended ({})", job.state.as_str()),
            ));
        }
        Ok(Json(job_info(&state, id)?.ok_or_else(|| anyhow::anyhow!("job {id} vanished"))?))
    })
    .await
}

/// The job's event log, or the part of it after `?after=SEQ`.
#[utoipa::path(get, path = "/api/v1/jobs/{id}/log", tag = "jobs", security((), ("api_token" = [])), params(("id" = u64, Path, description = "The job's id"), LogQuery),
    responses(
        (status = 200, description = "The job's events, oldest first (only those after `after`)", body = JobLog),
        (status = 400, description = "A path parameter or query does not parse", body = ApiError), (status = 401, description = "The server needs an API token", body = ApiError), (status = 404, description = "No such job", body = ApiError)))]
pub(super) async fn job_log(
    State(state): State<AppState>,
    Path(id): Path<u64>,
    axum::extract::Query(q): axum::extract::Query<LogQuery>,
) -> ApiResult<Json<JobLog>> {
    off_thread(move || {
        let events = state
            .store
            .job_log(id, q.after.unwrap_or(0))?
            .ok_or_else(|| AppError::not_found(format!("there is no job {id}")))?;
        Ok(Json(JobLog { job: id, events }))
    })
    .await
}

/// Frame `frame` of job `id`, or a 404 naming what is missing.
fn find_frame(state: &AppState, id: u64, frame: u32) -> ApiResult<crate::db::FrameRow> {
    state
        .store
        .frames(id)?
        .into_iter()
        .find(|f| f.index == frame)
        .ok_or_else(|| AppError::not_found(format!("job {id} has no frame {frame}")))
}

/// The output of a finished frame that its pass file `pass` (`pass.exr` or `pass.png`) stands
/// for: the image of the same kind under the camera's `image_name` stem, if the frame has one
/// (a `.png` frame has no EXR, for one).
fn final_of_pass(image_name: &str, pass: &str, outputs: &[String]) -> Option<String> {
    let stem = std::path::Path::new(image_name).file_stem()?.to_str()?;
    let ext = std::path::Path::new(pass).extension()?.to_str()?;
    let wanted = if pass == crate::storage::PASS_DENOISED_FILE {
        format!("{stem}_denoised.{ext}")
    } else {
        format!("{stem}.{ext}")
    };
    outputs.iter().find(|o| o.eq_ignore_ascii_case(&wanted)).cloned()
}

/// Job `id` and its frame `frame`, or a 404 naming the first that is missing.
fn job_and_frame(
    state: &AppState,
    id: u64,
    frame: u32,
) -> ApiResult<(crate::db::JobRow, crate::db::FrameRow)> {
    let job = state.store.job(id)?.ok_or_else(|| AppError::not_found(format!("there is no job {id}")))?;
    Ok((job, find_frame(state, id, frame)?))
}

#[utoipa::path(get, path = "/api/v1/jobs/{id}/frames/{frame}/files/{name}", tag = "jobs", security((), ("api_token" = [])),
    params(("id" = u64, Path, description = "The job's id"), ("frame" = u32, Path, description = "The frame's index in the job (0-based)"), ("name" = String, Path, description = "An output file's name, as the frame's `outputs` list it, or `pass.exr` / `pass.png`: the frame after its latest pass (once the frame is finished, its own EXR / PNG), or `pass_denoised.png` for a job with denoise: that pass denoised (once finished, the frame's denoised PNG)")),
    responses(
        (status = 200, description = "The file (PNG, OpenEXR or Radiance HDR)", content_type = "application/octet-stream", body = super::openapi::Binary),
        (status = 400, description = "A path parameter or query does not parse", body = ApiError), (status = 401, description = "The server needs an API token", body = ApiError),
        (status = 404, description = "No such job, frame or file", body = ApiError),
        (status = 409, description = "The frame is not finished", body = ApiError)))]
pub(super) async fn frame_file(
    State(state): State<AppState>,
    Path((id, frame, name)): Path<(u64, u32, String)>,
) -> ApiResult<Response> {
    let look_up = || {
        let state = state.clone();
        off_thread(move || find_frame(&state, id, frame))
    };
    let mut f = look_up().await?;
    let pass_file =
        crate::merge::PASS_FILES.contains(&name.as_str()) || name == crate::storage::PASS_DENOISED_FILE;
    if pass_file && f.outputs.is_none() {
        let path = state.server_frame_dir(id, frame).join(&name);
        if let Ok(file) = super::FileBody::open(&path).await {
            let mime = if name.ends_with(".png") { "image/png" } else { "application/octet-stream" };
            return Ok(file.into_response_with(&[(header::CONTENT_TYPE, HeaderValue::from_static(mime))]));
        }
        // No pass yet, or the frame finished (and its pass files went) since it was looked up.
        f = look_up().await?;
        if f.outputs.is_none() {
            let message = if name == crate::storage::PASS_DENOISED_FILE {
                format!(
                    "frame {frame} of job {id} has no denoised pass yet (after pass {} of {}): one is written after each pass of a job submitted with denoise=true",
                    f.passes_published, f.passes_total
                )
            } else if f.passes_published == 0 {
                format!(
                    "frame {frame} of job {id} has finished no pass yet (0 of {} passes); see preview.png meanwhile",
                    f.passes_total
                )
            } else {
                format!(
                    "frame {frame} of job {id} after pass {} of {} is being written; ask again in a moment (the job lists it in pass_outputs once written)",
                    f.passes_published, f.passes_total
                )
            };
            return Err(AppError::new(StatusCode::CONFLICT, message));
        }
    }
    // Once the frame is finished, the frame after its latest pass is the frame itself: the
    // pass names serve its image (so a client that follows a frame's passes is never left
    // with an error at the end).
    let name = match &f.outputs {
        Some(outputs) if pass_file => final_of_pass(&f.image_name, &name, outputs).unwrap_or(name),
        _ => name,
    };
    let Some(outputs) = &f.outputs else {
        return Err(AppError::new(
            StatusCode::CONFLICT,
            format!(
                "frame {frame} of job {id} is not finished ({} of {} tiles); see preview.png meanwhile",
                f.tiles_done, f.tiles_total
            ),
        ));
    };
    if !outputs.contains(&name) {
        return Err(AppError::not_found(format!(
            "frame {frame} of job {id} has no file {name}; it has {}",
            outputs.join(", ")
        )));
    }
    // Streamed from the file as the client reads it: a download holds a chunk of it in memory,
    // not the whole frame.
    let path = state.frame_dir(id, frame).join(&name);
    let file = super::FileBody::open(&path)
        .await
        .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", path.display()))?;
    let mime =
        if name.to_ascii_lowercase().ends_with(".png") { "image/png" } else { "application/octet-stream" };
    Ok(file.into_response_with(&[
        (header::CONTENT_TYPE, HeaderValue::from_static(mime)),
        (
            header::CONTENT_DISPOSITION,
            HeaderValue::from_str(&format!("attachment; filename=\"{name}\""))
                .unwrap_or(HeaderValue::from_static("attachment")),
        ),
    ]))
}

#[utoipa::path(get, path = "/api/v1/jobs/{id}/frames/{frame}/preview.png", tag = "jobs", security((), ("api_token" = [])),
    params(("id" = u64, Path, description = "The job's id"), ("frame" = u32, Path, description = "The frame's index in the job (0-based)")),
    responses(
        (status = 200, description = "The tiles that have arrived, tone-mapped over themselves (black elsewhere); the final picture once merged", content_type = "image/png", body = super::openapi::Binary),
        (status = 400, description = "A path parameter or query does not parse", body = ApiError), (status = 401, description = "The server needs an API token", body = ApiError),
        (status = 404, description = "No such job or frame", body = ApiError)))]
pub(super) async fn frame_preview(
    State(state): State<AppState>,
    Path((id, frame)): Path<(u64, u32)>,
) -> ApiResult<Response> {
    // Previews hold a picture each: a few at a time, the rest wait their turn.
    let _permit = super::turn(&state.previews).await?;
    let png = off_thread(move || {
        let (job, f) = job_and_frame(&state, id, frame)?;
        if f.outputs.is_some() {
            // A finished frame: the preview its merge wrote (older versions kept it beside the
            // outputs as `.preview.png`, unless an output has that name), or (frames merged
            // before there was one) made from the stored float frame.
            const OLD_PREVIEW: &str = ".preview.png";
            let outputs = f.outputs.as_deref().unwrap_or_default();
            let old = (!outputs.iter().any(|o| o == OLD_PREVIEW))
                .then(|| state.frame_dir(id, frame).join(OLD_PREVIEW));
            let new = state.server_frame_dir(id, frame).join(merge::PREVIEW_FILE);
            for path in std::iter::once(new).chain(old) {
                if let Ok(png) = std::fs::read(path) {
                    return Ok(png);
                }
            }
            if let Some(path) = stored_float(&state, &f) {
                let cam = job_camera(&state, &job, f.index)?;
                let img = tessera::hdr_io::read_float_image(&path).map_err(|e| anyhow::anyhow!("{e}"))?;
                return Ok(merge::final_preview_png(&cam, &img)?);
            }
        }
        let cam = job_camera(&state, &job, f.index)?;
        // The arrived tiles one at a time, each shrunk into the preview as it is read.
        let mut canvas = merge::PreviewCanvas::new(f.width, f.height);
        for (tile, rect) in state.store.done_tile_rects(id, frame)? {
            if let Some(bytes) = state.store.tile_pixels(id, frame, tile)? {
                canvas.add(rect, &bytes)?;
            }
        }
        Ok(canvas.png(&cam)?)
    })
    .await?;
    Ok(([(header::CONTENT_TYPE, HeaderValue::from_static("image/png"))], png).into_response())
}

/// The camera of a job's frame `frame`.
fn job_camera(state: &AppState, job: &crate::db::JobRow, frame: u32) -> ApiResult<Camera> {
    let cameras = state.frame_cameras(job)?;
    Ok(cameras
        .get(frame as usize)
        .cloned()
        .ok_or_else(|| anyhow::anyhow!("the camera of frame {frame} is missing"))?)
}

/// The float image among a merged frame's outputs: its first `.exr`, else its `.hdr` (an HDR
/// image name writes no `.exr`); what re-tone-mapping reads.
fn float_output(outputs: Option<&[String]>) -> Option<&String> {
    let outputs = outputs?;
    let with = |ext: &str| outputs.iter().find(|n| n.to_ascii_lowercase().ends_with(ext));
    with(".exr").or_else(|| with(".hdr"))
}

/// Where a merged frame's float image ([`float_output`]) is stored, if it has one.
fn stored_float(state: &AppState, f: &crate::db::FrameRow) -> Option<std::path::PathBuf> {
    let name = float_output(f.outputs.as_deref())?;
    Some(state.frame_dir(f.job_id, f.index).join(name))
}

/// A finished frame's float image (its `.exr`, else its `.hdr`) tone-mapped again with other
/// parameters, without rendering:
/// `GET /api/v1/jobs/ID/frames/F/tonemap.png?key=0.3&burn=2&saturation=1&gamma=2.2`.
#[utoipa::path(get, path = "/api/v1/jobs/{id}/frames/{frame}/tonemap.png", tag = "jobs", security((), ("api_token" = [])),
    params(("id" = u64, Path, description = "The job's id"), ("frame" = u32, Path, description = "The frame's index in the job (0-based)"), ToneQuery),
    responses(
        (status = 200, description = "The stored float frame tone-mapped with these parameters", content_type = "image/png", body = super::openapi::Binary),
        (status = 400, description = "A path parameter or query does not parse, or a parameter is out of range", body = ApiError),
        (status = 401, description = "The server needs an API token", body = ApiError),
        (status = 404, description = "No such job or frame, or the frame has no float output (.exr or .hdr; the frame's `tonemap_url` is then null)", body = ApiError),
        (status = 409, description = "The frame is not finished", body = ApiError)))]
pub(super) async fn frame_tonemap(
    State(state): State<AppState>,
    Path((id, frame)): Path<(u64, u32)>,
    axum::extract::Query(q): axum::extract::Query<ToneQuery>,
) -> ApiResult<Response> {
    let _permit = super::turn(&state.previews).await?;
    let (job, f) = {
        let state = state.clone();
        off_thread(move || job_and_frame(&state, id, frame)).await?
    };
    if f.outputs.is_none() {
        return Err(AppError::new(
            StatusCode::CONFLICT,
            format!("frame {frame} of job {id} is not finished yet"),
        ));
    }
    let path = stored_float(&state, &f).ok_or_else(|| {
        AppError::not_found(format!(
            "frame {frame} of job {id} has no float image (.exr or .hdr) to tone-map; its outputs are {}",
            f.outputs.as_deref().unwrap_or_default().join(", ")
        ))
    })?;
    let cameras = {
        let state = state.clone();
        off_thread(move || Ok(state.frame_cameras(&job)?)).await?
    };
    let (operator, base) = cameras
        .get(f.index as usize)
        .and_then(merge::display_tonemap)
        .unwrap_or((tessera::tonemap::params::Operator::Photographic, Default::default()));
    let gamma = match q.gamma.as_deref() {
        Some(g) => g.parse().map_err(AppError::bad_request)?,
        None => base.gamma,
    };
    let params = tessera::tonemap::params::Photographic {
        key: q.key.unwrap_or(base.key),
        burn_percent: q.burn.unwrap_or(base.burn_percent),
        saturation: q.saturation.unwrap_or(base.saturation),
        gamma,
    };
    params.validate().map_err(AppError::bad_request)?;
    let png = tokio::task::spawn_blocking(move || -> anyhow::Result<Vec<u8>> {
        let img = tessera::hdr_io::read_float_image(&path)?;
        let (rgb, _) = tessera::tonemap::tonemap_with(&img, operator, &params);
        merge::encode_png(img.width, img.height, &rgb)
    })
    .await
    .map_err(|e| anyhow::anyhow!("tone-map task: {e}"))??;
    Ok(([(header::CONTENT_TYPE, HeaderValue::from_static("image/png"))], png).into_response())
}

/// Deletes a finished job (done, failed or cancelled): its rows, its frames' outputs and the
/// server's own files of them (`outputs/ID/`, `frames/ID/`, the video among them). Its files
/// in the file store, and its tar bundle, go with the housekeeping once no other job names
/// them. Its id is never given to another job.
#[utoipa::path(delete, path = "/api/v1/jobs/{id}", tag = "jobs", security((), ("api_token" = [])), params(("id" = u64, Path, description = "The job's id")),
    responses(
        (status = 204, description = "Deleted, with its outputs"),
        (status = 400, description = "A path parameter or query does not parse", body = ApiError), (status = 401, description = "The server needs an API token", body = ApiError), (status = 404, description = "No such job", body = ApiError),
        (status = 409, description = "The job is queued, running or paused: cancel it first", body = ApiError)))]
pub(super) async fn delete_job(State(state): State<AppState>, Path(id): Path<u64>) -> ApiResult<StatusCode> {
    off_thread(move || match crate::retention::remove_job(&state, id)? {
        crate::retention::Removed::NoSuchJob => Err(AppError::not_found(format!("there is no job {id}"))),
        crate::retention::Removed::NotFinal(s) => Err(AppError::new(
            StatusCode::CONFLICT,
            format!("job {id} is {}; cancel it first: tessera cancel {id}", s.as_str()),
        )),
        crate::retention::Removed::Gone { rows, bytes } => {
            tracing::info!(job = id, rows, bytes, "deleted a finished job with its outputs");
            Ok(StatusCode::NO_CONTENT)
        }
    })
    .await
}
