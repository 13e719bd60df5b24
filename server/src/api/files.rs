//! The file store over HTTP (job API): which files the server lacks, and an upload of one
//! file by its SHA-256. A client asks first and uploads only what is missing; the job that
//! names the files comes after (`POST /api/v1/jobs` as a `JobRequest`).

use axum::Json;
use axum::extract::{Path, State};
use axum::http::{HeaderMap, StatusCode, header};
use tessera::protocol::*;

use super::{ApiResult, AppError, AppState, off_thread};
use crate::files::{PutError, Stored, is_sha256};

/// Bytes of JSON one entry of a [`MissingFilesRequest`] takes at most (a SHA-256, a size and
/// the punctuation, with room to spare): the request's body limit is this times the entries
/// allowed.
const MISSING_ENTRY_BYTES: usize = 256;

/// The body limit of `POST /api/v1/files/missing`: `--max-bundle-files` entries.
pub(super) fn missing_body_limit(state: &AppState) -> usize {
    state.settings.bundle_limits.max_files.saturating_mul(MISSING_ENTRY_BYTES).saturating_add(64 << 10)
}

/// The 413 of a file over `--max-file-mb` (`limit` bytes).
pub(super) fn file_too_large(limit: u64) -> AppError {
    AppError::new(
        StatusCode::PAYLOAD_TOO_LARGE,
        format!(
            "the file is larger than {} MiB, the largest single file this server accepts (--max-file-mb, \
             TESSERA_MAX_FILE_MB); nothing was stored; shrink the file, or ask the farm's operator to raise the limit",
            limit >> 20
        ),
    )
}

/// Which of the files the server lacks: each SHA-256 it does not hold with that size, once, in
/// the order asked. Every file it does hold is kept for another hour from now even if no job
/// names it yet (the time to submit the job that does).
#[utoipa::path(post, path = "/api/v1/files/missing", tag = "jobs", security((), ("api_token" = [])),
    request_body(content = MissingFilesRequest, content_type = "application/json"),
    responses(
        (status = 200, description = "The SHA-256s to upload with PUT /api/v1/files/{sha256}", body = MissingFilesResponse),
        (status = 400, description = "Not a MissingFilesRequest, a `sha256` that is not 64 lowercase hex digits, or more entries than --max-bundle-files", body = ApiError),
        (status = 401, description = "The server needs an API token", body = ApiError),
        (status = 413, description = "A body over the request's limit", body = ApiError)))]
pub(super) async fn missing_files(
    State(state): State<AppState>,
    Json(req): Json<MissingFilesRequest>,
) -> ApiResult<Json<MissingFilesResponse>> {
    let max = state.settings.bundle_limits.max_files;
    if req.files.len() > max {
        return Err(AppError::bad_request(format!(
            "files: {} entries, more than the {max} a job may have (--max-bundle-files, TESSERA_MAX_BUNDLE_FILES); ask in several requests",
            req.files.len()
        )));
    }
    if let Some((i, bad)) = req.files.iter().enumerate().find(|(_, f)| !is_sha256(&f.sha256)) {
        return Err(AppError::bad_request(format!(
            "files[{i}].sha256: \"{}\" is not a SHA-256 (64 lowercase hex digits)",
            bad.sha256.chars().take(80).collect::<String>()
        )));
    }
    off_thread(move || {
        let (mut seen, mut listed) = (std::collections::HashSet::new(), std::collections::HashSet::new());
        let mut missing = Vec::new();
        for f in &req.files {
            if !seen.insert((f.sha256.as_str(), f.size)) {
                continue;
            }
            if state.files.has(&f.sha256, f.size) {
                state.files.touch(&f.sha256);
            } else if listed.insert(f.sha256.as_str()) {
                missing.push(f.sha256.clone());
            }
        }
        Ok(Json(MissingFilesResponse { missing }))
    })
    .await
}

/// One file of the store, uploaded as the raw bytes of the body and stored under its SHA-256
/// once checked. A file no job names is removed an hour after its upload.
#[utoipa::path(put, path = "/api/v1/files/{sha256}", tag = "jobs", security((), ("api_token" = [])),
    params(("sha256" = String, Path, description = "The SHA-256 of the body, 64 lowercase hex digits")),
    request_body(content = super::openapi::Binary, content_type = "application/octet-stream",
        description = "The file's bytes (at most --max-file-mb MiB)"),
    responses(
        (status = 200, description = "The server had this file already (the body was checked and dropped)", body = FileDigest),
        (status = 201, description = "Stored", body = FileDigest),
        (status = 400, description = "`sha256` is not a SHA-256, the body's SHA-256 differs (the answer names both), or the body was cut off: nothing was stored", body = ApiError),
        (status = 401, description = "The server needs an API token", body = ApiError),
        (status = 408, description = "The body stopped arriving: nothing was stored", body = ApiError),
        (status = 413, description = "Over --max-file-mb: nothing was stored", body = ApiError),
        (status = 507, description = "The server's disk is full: nothing was stored; upload again once space is freed", body = ApiError)))]
pub(super) async fn put_file(
    State(state): State<AppState>,
    Path(sha256): Path<String>,
    headers: HeaderMap,
    body: axum::body::Body,
) -> ApiResult<(StatusCode, Json<FileDigest>)> {
    if !is_sha256(&sha256) {
        return Err(AppError::bad_request(format!(
            "the path's sha256 \"{}\" is not a SHA-256 (64 lowercase hex digits)",
            sha256.chars().take(80).collect::<String>()
        )));
    }
    let limit = state.settings.bundle_limits.max_file_bytes;
    let declared = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<u64>().ok());
    if declared.is_some_and(|n| n > limit) {
        return Err(file_too_large(limit));
    }
    let mut stream = body.into_data_stream();
    let stored = state.files.put_stream(&sha256, &mut stream, declared, limit).await;
    if matches!(stored, Err(PutError::TooLarge { .. } | PutError::Io(_))) {
        // Refused before the body's end: the rest is read and dropped first, so that a client
        // that writes its whole body before it reads the answer gets the answer.
        drain(&mut stream).await;
    }
    match stored {
        Ok(stored) => {
            let size =
                state.files.path(&sha256).and_then(|p| std::fs::metadata(p).ok()).map_or(0, |m| m.len());
            let status = if stored == Stored::New { StatusCode::CREATED } else { StatusCode::OK };
            if stored == Stored::New {
                tracing::debug!(sha256, size, "stored an uploaded file");
            }
            Ok((status, Json(FileDigest { sha256, size })))
        }
        Err(PutError::WrongHash { expected, actual }) => Err(AppError::bad_request(format!(
            "the body's SHA-256 is {actual}, not {expected} (the path's); nothing was stored; upload the file under its own SHA-256"
        ))),
        Err(PutError::TooLarge { limit }) => Err(file_too_large(limit)),
        Err(PutError::Body(e)) => Err(AppError::bad_request(format!(
            "the body could not be read to its end ({e}); nothing was stored; upload the file again"
        ))),
        Err(PutError::Io(e)) => Err(e.into()),
    }
}

/// Reads and drops what is left of a body, up to `OVERSIZED_DRAIN_BYTES` and
/// `OVERSIZED_DRAIN_SECONDS` (as `oversized_uploads` does for a body declared too large).
async fn drain(body: &mut axum::body::BodyDataStream) {
    use futures_util::StreamExt;
    let deadline =
        tokio::time::Instant::now() + std::time::Duration::from_secs(super::OVERSIZED_DRAIN_SECONDS);
    let mut read = 0u64;
    while read < super::OVERSIZED_DRAIN_BYTES {
        match tokio::time::timeout_at(deadline, body.next()).await {
            Ok(Some(Ok(chunk))) => read += chunk.len() as u64,
            _ => break,
        }
    }
}
