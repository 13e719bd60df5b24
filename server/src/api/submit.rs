//! Job submission: `POST /api/v1/jobs` as a multipart upload (spooled to disk under the caps
//! and unpacked) or as JSON naming files the server has ([`JobRequest`]); either becomes a
//! [`jobspec::Submission`] that `jobspec` validates (parse and build each scene, check the
//! tile, frame and sample limits) and stores as a queued job. The limit checks are here.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;

use axum::Json;
use axum::extract::{FromRequest, Multipart, Request, State};
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use tessera::bundle::BundleFiles;
use tessera::camera::Camera;
use tessera::protocol::*;

use super::jobspec::{self, Submission};
use super::{ApiResult, AppError, AppState, Settings};
use crate::bundle::{self, BundleError, Unpacker};

/// The multipart form of a submission, for the OpenAPI description only (the handler reads the
/// fields as they stream in, see [`read_fields`]). Files are named by their path relative to the
/// job's top folder (the part's file name). A sequence (one job whose frames are several scene
/// files' cameras, in order) is several `scene` fields, in frame order, or a `scenes` field.
#[derive(utoipa::ToSchema)]
#[allow(dead_code)]
pub(super) struct SubmitForm {
    /// The scene file (.xml or .json); several `scene` fields make a sequence, rendered in the
    /// order of the fields.
    #[schema(value_type = Option<Vec<String>>)]
    scene: Option<Vec<Vec<u8>>>,
    /// Its assets (PLY models, textures), one part each; also accepted as `file`, `assets`, `files`.
    #[schema(value_type = Option<Vec<String>>)]
    asset: Option<Vec<Vec<u8>>>,
    /// Or everything in one .tar, .tar.gz or .zip archive.
    #[schema(value_type = Option<String>, format = Binary)]
    bundle: Option<Vec<u8>>,
    /// The job's name (default: the scene file's name).
    name: Option<String>,
    /// Higher runs first (default 0).
    priority: Option<i64>,
    /// Tile edge in pixels, 1 to 4096 (default: the server's --tile-size).
    tile_size: Option<u32>,
    /// Samples per pixel instead of each camera's NumSamples.
    samples: Option<u32>,
    /// Which cameras to render, 1-based, e.g. "1,3" (default: all); each once, at most 1,024.
    cameras: Option<String>,
    /// Which file of a bundle is the scene, when it holds several.
    scene_path: Option<String>,
    /// Or the scene files of a sequence among the uploaded files (a bundle's paths), in frame
    /// order, separated by newlines or commas.
    scenes: Option<String>,
    /// Whether to keep a PNG-named frame's float image (`.exr`, losslessly compressed) beside
    /// it: by default "true" for a job of one scene file, "false" for a sequence.
    keep_float: Option<bool>,
    /// "true": also write each frame denoised (`<stem>_denoised.exr` and its PNG) with Intel
    /// Open Image Denoise on the server; 422 when the server has no OIDN.
    denoise: Option<bool>,
    /// Samples per pass (rounded up to whole blocks of 16; default: a sixteenth of the samples,
    /// at least 256 unless the job has a noise target).
    /// Each tile's passes are leased on their own, so a frame keeps tiles x passes workers busy,
    /// and the frame is published after every pass all its tiles have finished.
    pass_samples: Option<u32>,
    /// Stop sampling a tile once its estimated relative noise is at most this, in (0, 1]
    /// (e.g. 0.02); the samples become a cap. Default: every tile takes every sample.
    noise_target: Option<f64>,
    /// The video made of the frames once all are merged: `mp4` (H.264; 422 when the server has
    /// no ffmpeg), `gif` or `none`. Default: `mp4` for a sequence of scene files (a GIF when the
    /// server has no ffmpeg), `none` for one scene. 422 when the frames differ in size.
    video: Option<String>,
    /// Frames a second of the video, 1 to 120 (default 30).
    fps: Option<u32>,
    /// Where to POST the job's end (`{"event", "job"}`), under a prefix the server allows
    /// (`--notify-allow`; 422 otherwise).
    notify_url: Option<String>,
    /// Render every frame at this scale, a number in (0, 1]: each side of the image times
    /// `scale`, rounded to the nearest pixel (halves up), at least 1 (e.g. 0.25: an 800x450
    /// camera renders at 200x113). The image plane stays: the same picture, coarser.
    scale: Option<f64>,
    /// Tags a worker must all have to render the job, separated by commas (or several fields),
    /// e.g. "gpu,big"; each 1 to 32 letters, digits, '-', '_' or '.', at most 16 (422 otherwise).
    /// Default: any worker.
    worker_tags: Option<String>,
}

/// Options of a submission (multipart text fields, or a [`JobRequest`]'s).
#[derive(Default)]
pub(super) struct SubmitOptions {
    pub name: Option<String>,
    pub priority: i64,
    pub tile_size: Option<u32>,
    pub samples: Option<u32>,
    pub cameras: Option<Vec<u32>>,
    pub scene_path: Option<String>,
    /// Render the scene without the elements Tessera does not implement instead of refusing it.
    pub allow_unsupported: bool,
    /// Also write each frame denoised.
    pub denoise: bool,
    pub pass_samples: Option<u32>,
    pub noise_target: Option<f64>,
    pub video: Option<VideoKind>,
    pub fps: Option<u32>,
    pub keep_float: Option<bool>,
    /// The `scenes` field: a sequence's scene files among the uploaded files.
    pub scenes: Option<Vec<String>>,
    /// Where to POST the job's end (checked against `--notify-allow`).
    pub notify_url: Option<String>,
    /// Tags a worker must all have (as given; checked with the rest of the job).
    pub worker_tags: Vec<String>,
    /// Render every frame at this scale, in (0, 1].
    pub scale: Option<f64>,
}

/// A job's `scale` as it may be ([`tessera::camera::check_scale`]), or a 400 naming the field.
pub(super) fn check_scale(scale: f64) -> ApiResult<f64> {
    tessera::camera::check_scale(scale).map_err(|e| AppError::bad_request(format!("scale {e}")))
}

pub(super) fn problem_from(e: &tessera::SceneError) -> Problem {
    Problem {
        file: Some(e.file.display().to_string()),
        line: e.loc.line,
        element: e.loc.element.clone(),
        message: e.message.clone(),
    }
}

/// An upload's files on disk while its request is read: the multipart body is streamed into
/// `<data>/uploads/<unique>/`, never held in memory, and the folder goes when the request ends.
struct Spool {
    dir: PathBuf,
    /// (field kind, file name given, spooled file)
    parts: Vec<(SpoolKind, String, PathBuf)>,
}

#[derive(Clone, Copy, PartialEq)]
enum SpoolKind {
    File,
    Archive,
}

impl Spool {
    fn new(data_dir: &std::path::Path) -> anyhow::Result<Spool> {
        let dir = tessera::atomic_write::unique_temp_name(&data_dir.join("uploads").join("upload"));
        std::fs::create_dir_all(&dir).map_err(|e| anyhow::anyhow!("cannot create {}: {e}", dir.display()))?;
        Ok(Spool { dir, parts: Vec::new() })
    }
}

impl Drop for Spool {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// The longest a text field (name, priority, cameras, ...) may be.
const MAX_TEXT_FIELD: usize = 64 << 10;

/// Reads the multipart fields of a submission: files are streamed into `spool` under the
/// caps, the options into `opts`.
async fn read_fields(
    state: &AppState,
    multipart: &mut Multipart,
    spool: &mut Spool,
    opts: &mut SubmitOptions,
    scene_fields: &mut Vec<String>,
) -> ApiResult<()> {
    use tokio::io::AsyncWriteExt;
    let limits = state.settings.bundle_limits;
    let too_big = |e: &axum::extract::multipart::MultipartError| e.status() == StatusCode::PAYLOAD_TOO_LARGE;
    let too_large = |e: BundleError| AppError::new(StatusCode::PAYLOAD_TOO_LARGE, e.to_string());
    loop {
        let mut field = match multipart.next_field().await {
            Ok(Some(f)) => f,
            Ok(None) => break,
            Err(e) if too_big(&e) => return Err(upload_too_large(state.settings.max_upload_bytes)),
            Err(e) => {
                return Err(AppError::bad_request(format!(
                    "the upload is not valid multipart/form-data: {e}"
                )));
            }
        };
        let name = field.name().unwrap_or("").to_string();
        let file_name = field.file_name().map(str::to_string);
        let kind = match name.as_str() {
            "scene" | "asset" | "file" | "assets" | "files" => Some(SpoolKind::File),
            "bundle" => Some(SpoolKind::Archive),
            _ => None,
        };
        let read_error = |e: axum::extract::multipart::MultipartError| {
            if too_big(&e) {
                upload_too_large(state.settings.max_upload_bytes)
            } else {
                AppError::bad_request(format!("cannot read the field \"{name}\": {e}"))
            }
        };
        if let Some(kind) = kind {
            let path = match (name.as_str(), file_name) {
                ("scene", f) => {
                    let f = f.unwrap_or_else(|| "scene.xml".into());
                    scene_fields.extend(tessera::assets::normalize_bundle_path(&f));
                    f
                }
                ("bundle", f) => f.unwrap_or_else(|| "bundle".into()),
                (_, Some(f)) => f,
                (_, None) => {
                    return Err(AppError::bad_request(format!(
                        "the field \"{name}\" needs a file name: its path relative to the scene file"
                    )));
                }
            };
            if kind == SpoolKind::File && tessera::assets::normalize_bundle_path(&path).is_none() {
                return Err(AppError::bad_request(BundleError::UnsafePath(path).to_string()));
            }
            if spool.parts.len() >= limits.max_files {
                return Err(too_large(Unpacker::new(limits).too_many_files_error()));
            }
            let file = spool.dir.join(format!("part{}", spool.parts.len()));
            let mut out = tokio::fs::File::create(&file)
                .await
                .map_err(|e| anyhow::anyhow!("cannot create {}: {e}", file.display()))?;
            let mut size = 0u64;
            while let Some(chunk) = field.chunk().await.map_err(read_error)? {
                size += chunk.len() as u64;
                if kind == SpoolKind::File && size > limits.max_file_bytes {
                    return Err(too_large(Unpacker::new(limits).file_too_large_error(&path)));
                }
                out.write_all(&chunk)
                    .await
                    .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", file.display()))?;
            }
            out.flush().await.map_err(|e| anyhow::anyhow!("cannot write {}: {e}", file.display()))?;
            spool.parts.push((kind, path, file));
            continue;
        }
        let mut data = Vec::new();
        while let Some(chunk) = field.chunk().await.map_err(read_error)? {
            data.extend_from_slice(&chunk);
            if data.len() > MAX_TEXT_FIELD {
                return Err(AppError::bad_request(format!(
                    "the field \"{name}\" is longer than {} KiB; send files as scene, asset or bundle fields",
                    MAX_TEXT_FIELD >> 10
                )));
            }
        }
        let text = || String::from_utf8_lossy(&data).trim().to_string();
        let number = |what: &str| -> ApiResult<i64> {
            text().parse::<i64>().map_err(|_| {
                AppError::bad_request(format!("{what} must be an integer, found \"{}\"", text()))
            })
        };
        match name.as_str() {
            "name" => opts.name = Some(text()),
            "priority" => opts.priority = number("priority")?,
            "tile_size" => opts.tile_size = Some(bounded("tile_size", number("tile_size")?, 4096, "pixels")?),
            "samples" => opts.samples = Some(bounded("samples", number("samples")?, 1_000_000, "")?),
            "pass_samples" => {
                opts.pass_samples = Some(bounded("pass_samples", number("pass_samples")?, 1_000_000, "")?)
            }
            "noise_target" => {
                let t = text();
                let v: f64 = t.trim().parse().map_err(|_| {
                    AppError::bad_request(format!(
                        "noise_target must be a number in (0, 1], e.g. 0.02; found \"{t}\""
                    ))
                })?;
                opts.noise_target = Some(
                    tessera::passes::check_noise_target(v)
                        .map_err(|e| AppError::bad_request(format!("noise_target: {e}")))?,
                );
            }
            "cameras" => opts.cameras = Some(camera_list(&text(), state.settings.max_job_frames)?),
            "scale" => {
                let t = text();
                let v: f64 = t.parse().map_err(|_| {
                    AppError::bad_request(format!(
                        "scale must be a number in (0, 1], e.g. 0.25; found \"{t}\""
                    ))
                })?;
                opts.scale = Some(check_scale(v)?);
            }
            "scene_path" => opts.scene_path = Some(text()),
            "scenes" => {
                let list: Vec<String> = text()
                    .split(['\n', ','])
                    .map(str::trim)
                    .filter(|p| !p.is_empty())
                    .map(str::to_string)
                    .collect();
                if list.len() > state.settings.max_job_frames {
                    return Err(too_many_frames(list.len(), state.settings.max_job_frames));
                }
                opts.scenes = Some(list);
            }
            "notify_url" => opts.notify_url = Some(text()),
            "worker_tags" => {
                if opts.worker_tags.len() >= MAX_TAGS {
                    return Err(AppError::new(
                        StatusCode::UNPROCESSABLE_ENTITY,
                        format!("worker_tags: more than {MAX_TAGS} tags; give at most {MAX_TAGS}"),
                    ));
                }
                opts.worker_tags.push(text())
            }
            "video" => {
                opts.video = Some(VideoKind::parse(&text()).ok_or_else(|| {
                    AppError::bad_request(format!("video must be mp4, gif or none, found \"{}\"", text()))
                })?)
            }
            "fps" => {
                opts.fps = Some(jobspec::check_fps(bounded("fps", number("fps")?, 120, "frames a second")?)?)
            }
            field @ ("allow_unsupported" | "denoise" | "keep_float") => {
                let yes = match text().as_str() {
                    "true" | "1" => true,
                    "false" | "0" => false,
                    other => {
                        return Err(AppError::bad_request(format!(
                            "{field} must be true or false, found \"{other}\""
                        )));
                    }
                };
                match field {
                    "denoise" => opts.denoise = yes,
                    "keep_float" => opts.keep_float = Some(yes),
                    _ => opts.allow_unsupported = yes,
                }
            }
            other => {
                return Err(AppError::bad_request(format!(
                    "unknown field \"{other}\"; send scene, asset (one per file, named by its relative path), bundle, name, priority, tile_size, samples, pass_samples, noise_target, cameras, scene_path, scenes, allow_unsupported, denoise, video, fps, keep_float, notify_url, scale or worker_tags"
                )));
            }
        }
    }
    Ok(())
}

#[utoipa::path(post, path = "/api/v1/jobs", tag = "jobs", security((), ("api_token" = [])),
    request_body(content(
        (SubmitForm = "multipart/form-data"),
        (JobRequest = "application/json")),
        description = "The job: a multipart upload of its files and options, or (`Content-Type: application/json`) a `JobRequest` naming files already uploaded with `PUT /api/v1/files/{sha256}`. Several scene files (several `scene` fields, a `scenes` field, or the request's `scenes`) make one job whose frames are their cameras in that order."),
    responses(
        (status = 201, description = "Accepted and queued (with the scene's warnings)", body = JobInfo),
        (status = 400, description = "Not valid multipart or JSON, a bad field or path, a path given twice, or a scene that does not parse or build (`problems` says where)", body = ApiError),
        (status = 401, description = "The server needs an API token", body = ApiError),
        (status = 409, description = "JSON: the server lacks some of the files (`problems` lists each path with its SHA-256); upload them first", body = ApiError),
        (status = 413, description = "Over the upload or unpacking limits (file count, bytes of one file or of all)", body = ApiError),
        (status = 422, description = "A scene that cannot be rendered (for a sequence the message names the frame and scene file, e.g. a file it names that is not among the job's), two frames writing the same image name, over the tile, unit, frame (--max-job-frames) or sample limits, an empty `cameras`, or denoise=true on a server without Intel Open Image Denoise", body = ApiError),
        (status = 507, description = "The server's disk is full: nothing was stored; submit again once space is freed", body = ApiError)))]
pub(super) async fn submit_job(State(state): State<AppState>, request: Request) -> ApiResult<Response> {
    let json = request
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.trim_start().to_ascii_lowercase().starts_with("application/json"));
    if json {
        let Json(req) = match Json::<JobRequest>::from_request(request, &state).await {
            Ok(req) => req,
            Err(rejection) => {
                // A body that is not a `JobRequest` (a field missing, unknown or of the wrong
                // type) is a bad request like a bad multipart field.
                let status = match rejection.status() {
                    StatusCode::PAYLOAD_TOO_LARGE => StatusCode::PAYLOAD_TOO_LARGE,
                    _ => StatusCode::BAD_REQUEST,
                };
                return Err(AppError::new(status, format!("the job request: {}", rejection.body_text())));
            }
        };
        let _permit = super::turn(&state.unpacking).await?;
        let st = state.clone();
        let sub = super::off_thread(move || jobspec::request_submission(&st, req)).await?;
        return Ok(jobspec::accept(state, sub).await?.into_response());
    }
    let multipart = match Multipart::from_request(request, &state).await {
        Ok(m) => m,
        Err(rejection) => return Ok(rejection.into_response()),
    };
    Ok(submit_multipart(state, multipart).await?.into_response())
}

/// What a client asking for denoising is told when the server has no denoiser: how to install
/// one, and that it takes effect without a restart (where the server looked, paths of the
/// server's machine, goes to its log only).
pub const NO_DENOISER: &str = "denoise=true: this server cannot denoise: Intel Open Image Denoise 2 is \
     not installed where it looks (its log says where). Install it on the server with `python3 -m pip \
     install pyoidn` (or point TESSERA_OIDN_LIB at the library): the server looks again at the next \
     request that needs it, within a few seconds, without a restart. Or submit without denoise";

/// Refused before anything is unpacked when a job asks for denoising: the server denoises the
/// merged frames and the passes' previews, so it needs the library itself (workers only send
/// features). The library is looked for again when this is asked a few seconds after a failed
/// lookup ([`tessera_denoise::RETRY_LOOKUP_AFTER`]).
pub(super) async fn check_denoiser() -> ApiResult<()> {
    let found = tokio::task::spawn_blocking(|| tessera_denoise::oidn().map(|_| ()))
        .await
        .map_err(|e| anyhow::anyhow!("denoiser lookup task: {e}"))?;
    found.map_err(|e| {
        tracing::warn!("a job asks for denoising, and {e}");
        AppError::new(StatusCode::UNPROCESSABLE_ENTITY, NO_DENOISER.to_string())
    })
}

/// A multipart submission: its files spooled, unpacked and hashed, its scene files found.
async fn submit_multipart(
    state: AppState,
    mut multipart: Multipart,
) -> ApiResult<(StatusCode, Json<JobInfo>)> {
    let limits = state.settings.bundle_limits;
    let mut spool = Spool::new(&state.settings.data_dir)?;
    let mut opts = SubmitOptions::default();
    let mut scene_fields: Vec<String> = Vec::new();
    if let Err(refusal) = read_fields(&state, &mut multipart, &mut spool, &mut opts, &mut scene_fields).await
    {
        // Read the rest of the body (bounded by --max-upload-mb, discarded) so that a client
        // still sending gets the answer instead of a broken connection.
        while let Ok(Some(mut field)) = multipart.next_field().await {
            while let Ok(Some(_)) = field.chunk().await {}
        }
        return Err(refusal);
    }
    if opts.denoise {
        check_denoiser().await?;
    }
    let too_large = |e: BundleError| AppError::new(StatusCode::PAYLOAD_TOO_LARGE, e.to_string());
    if spool.parts.is_empty() {
        return Err(AppError::bad_request(
            "the upload holds no files; send the scene as the \"scene\" field (and its assets as \"asset\" fields) or a \"bundle\" archive",
        ));
    }
    if opts.scene_path.is_some() && scene_fields.len() > 1 {
        return Err(AppError::bad_request(
            "give either scene_path (one scene of a bundle) or several scene fields (a sequence), not both",
        ));
    }
    if opts.scenes.is_some() && opts.scene_path.is_some() {
        return Err(AppError::bad_request(
            "give either scene_path (one scene of a bundle) or scenes (a sequence), not both",
        ));
    }

    // Unpacking and validation hold the files in memory: a few uploads at a time, so the
    // server's memory stays bounded however many arrive at once.
    let _permit = super::turn(&state.unpacking).await?;
    let listed = opts.scenes.take();
    let wanted = opts.scene_path.clone().or_else(|| scene_fields.first().cloned());
    let sub = tokio::task::spawn_blocking(move || {
        let mut unpacker = Unpacker::new(limits);
        for (kind, path, file) in &spool.parts {
            let opened = std::fs::File::open(file)
                .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", file.display()))?;
            let added = match kind {
                SpoolKind::File => unpacker.add_reader(path, opened),
                SpoolKind::Archive => unpacker.add_archive(opened),
            };
            added.map_err(|e| match e {
                e @ BundleError::TooLarge(_) => too_large(e),
                e => AppError::bad_request(e.to_string()),
            })?;
        }
        drop(spool);
        let files = unpacker.files;
        let scenes = match listed {
            Some(list) => jobspec::scene_list(&list, &files)?,
            None if scene_fields.len() > 1 => scene_fields,
            None => vec![bundle::find_scene(&files, wanted.as_deref()).map_err(AppError::bad_request)?],
        };
        let digests: BTreeMap<String, (String, u64)> = files
            .iter()
            .map(|(path, bytes)| (path.clone(), (bundle::sha256_hex(bytes), bytes.len() as u64)))
            .collect();
        let files: BundleFiles = files.into_iter().map(|(k, v)| (k, Arc::new(v))).collect();
        Ok::<_, AppError>(Submission { scenes, files, digests, stored: false, opts })
    })
    .await
    .map_err(|e| anyhow::anyhow!("unpacking task: {e}"))??;
    jobspec::accept(state, sub).await
}

/// Refuses a job asking for more samples than the server's `--max-job-samples`: one that would
/// keep the farm busy for days is a 422 that says the limit and how to get under it.
pub(super) fn check_sample_budget(
    settings: &Settings,
    cameras: &[Camera],
    frames: &[crate::db::NewFrame],
    samples: Option<u32>,
) -> ApiResult<()> {
    let mut total: u64 = 0;
    for (f, cam) in frames.iter().zip(cameras) {
        let spp = samples.unwrap_or(cam.num_samples).max(1);
        let n = u64::from(f.width) * u64::from(f.height) * u64::from(spp);
        total = total.saturating_add(n);
    }
    if total > settings.max_job_samples {
        return Err(AppError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            format!(
                "the job asks for {total} samples (pixels x samples per pixel over its frames), more than this \
                 server's limit of {}: lower NumSamples or ImageResolution, submit with samples=N, or start the \
                 server with a larger --max-job-samples (TESSERA_MAX_JOB_SAMPLES)",
                settings.max_job_samples
            ),
        ));
    }
    Ok(())
}

/// The largest frame the server denoises, in pixels (4096 x 4096): a denoised merge holds the
/// frame's colour, albedo and normal and the denoiser's copies of them, about 84 bytes a pixel
/// (1.4 GB here) besides OIDN's own working memory, which it bounds by tiling.
pub const MAX_DENOISE_PIXELS: u64 = 4096 * 4096;

/// Refuses `denoise=true` for a job with a frame over [`MAX_DENOISE_PIXELS`].
pub(super) fn check_denoise_size(frames: &[crate::db::NewFrame]) -> ApiResult<()> {
    match frames.iter().find(|f| u64::from(f.width) * u64::from(f.height) > MAX_DENOISE_PIXELS) {
        None => Ok(()),
        Some(f) => Err(AppError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            format!(
                "denoise=true: {} is {}x{} pixels, and this server denoises frames of at most {MAX_DENOISE_PIXELS} pixels \
                 (4096 x 4096); submit without denoise and denoise the .exr on your machine (tessera-worker render \
                 --denoise), or render fewer pixels",
                f.image_name, f.width, f.height
            ),
        )),
    }
}

/// Most passes a tile may be cut into.
const MAX_PASSES: u32 = 256;

/// The cameras a submission's `cameras` field names ("1,3", "1 3"), each once, in the order
/// first named; an empty list is refused (it would make a job of no frames, queued for ever).
fn camera_list(text: &str, max_frames: usize) -> ApiResult<Vec<u32>> {
    let mut list = Vec::new();
    for part in text.split([',', ' ']).map(str::trim).filter(|p| !p.is_empty()) {
        let k: u32 = part.parse().ok().filter(|k| *k >= 1).ok_or_else(|| {
            AppError::bad_request(format!(
                "cameras must list camera numbers from 1, e.g. \"1,3\"; found \"{part}\""
            ))
        })?;
        list.push(k);
        if list.len() > max_frames {
            break;
        }
    }
    camera_selection(list, max_frames)
}

/// A job's `cameras` (1-based), each once in the order first named, at most `max_frames`; an
/// empty list is refused (it would make a job of no frames, queued for ever).
pub(super) fn camera_selection(wanted: Vec<u32>, max_frames: usize) -> ApiResult<Vec<u32>> {
    let mut list: Vec<u32> = Vec::new();
    for k in wanted {
        if k == 0 {
            return Err(AppError::bad_request(
                "cameras must list camera numbers from 1, e.g. [1, 3]; found 0",
            ));
        }
        if !list.contains(&k) {
            if list.len() == max_frames {
                return Err(too_many_frames(max_frames + 1, max_frames));
            }
            list.push(k);
        }
    }
    if list.is_empty() {
        return Err(AppError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            "cameras lists no camera; give ids like 1,3 or omit the field (every camera)",
        ));
    }
    Ok(list)
}

/// The 422 of a job of more than `max` frames (`n`: at least how many).
pub(super) fn too_many_frames(n: usize, max: usize) -> AppError {
    AppError::new(
        StatusCode::UNPROCESSABLE_ENTITY,
        format!(
            "the job would render {n} or more frames (cameras of its scene files), more than the {max} one job may \
             on this server (--max-job-frames, TESSERA_MAX_JOB_FRAMES); submit at most {max} frames (fewer scene \
             files, or fewer cameras with cameras=) per job and the rest as other jobs"
        ),
    )
}

/// Units of work (rows of the store: tiles x passes, over every frame) of frames of `sizes`
/// and samples per pixel `samples`, cut at `tile_size` into passes of `pass_samples` (`None`:
/// each frame's default).
fn unit_count(
    frames: &[crate::db::NewFrame],
    tile_size: u32,
    pass_samples: Option<u32>,
    noise_target: bool,
) -> u64 {
    frames
        .iter()
        .map(|f| {
            let tiles = u64::from(f.width.div_ceil(tile_size)) * u64::from(f.height.div_ceil(tile_size));
            let p = match pass_samples {
                Some(p) => tessera::passes::round_to_blocks(p),
                None => tessera::passes::default_farm_pass_samples(f.samples, noise_target),
            };
            tiles.saturating_mul(u64::from(tessera::passes::pass_count(f.samples, p)))
        })
        .fold(0u64, u64::saturating_add)
}

/// Sets each frame's samples and pass size (the job's `pass_samples` in whole blocks, or the
/// default), and refuses pass sizes that would cut a tile into more than [`MAX_PASSES`] passes or
/// the job into more units of work than `--max-job-units` (`limits`: the job's tile size and
/// that limit), naming the smallest `tile_size` and the smallest `pass_samples` that fit.
pub(super) fn plan_passes(
    frames: &mut [crate::db::NewFrame],
    cameras: &[Camera],
    samples: Option<u32>,
    pass_samples: Option<u32>,
    noise_target: bool,
    (tile_size, max_units): (u32, u64),
) -> ApiResult<()> {
    let mut units = 0u64;
    for (f, cam) in frames.iter_mut().zip(cameras) {
        f.samples = samples.unwrap_or(cam.num_samples).max(1);
        f.pass_samples = match pass_samples {
            Some(p) => tessera::passes::round_to_blocks(p),
            None => tessera::passes::default_farm_pass_samples(f.samples, noise_target),
        };
        let passes = f.passes();
        if passes > MAX_PASSES {
            let least = tessera::passes::round_to_blocks(f.samples.div_ceil(MAX_PASSES));
            return Err(AppError::new(
                StatusCode::UNPROCESSABLE_ENTITY,
                format!(
                    "pass_samples={} cuts camera {}'s {} samples into {passes} passes, more than {MAX_PASSES}; \
                     submit with pass_samples={least} or more",
                    pass_samples.unwrap_or_default(),
                    f.camera + 1,
                    f.samples
                ),
            ));
        }
        units = units.saturating_add(f.tiles.len() as u64 * u64::from(passes));
    }
    if units <= max_units {
        return Ok(());
    }
    // What would fit, changing one option: a larger tile (the same passes), or larger passes
    // (the same tiles; fewer units the larger they are, down to one pass a tile).
    let mut advice = Vec::new();
    if let Some(t) =
        (tile_size + 1..=4096).find(|&t| unit_count(frames, t, pass_samples, noise_target) <= max_units)
    {
        advice.push(format!("tile_size={t} or more"));
    }
    let most = frames.iter().map(|f| f.samples).max().unwrap_or(1);
    let blocks = |p: u32| unit_count(frames, tile_size, Some(p * tessera::passes::BLOCK), noise_target);
    if blocks(most.div_ceil(tessera::passes::BLOCK)) <= max_units {
        // The fewest blocks a pass that fits: units only fall as passes grow.
        let (mut lo, mut hi) = (1u32, most.div_ceil(tessera::passes::BLOCK));
        while lo < hi {
            let mid = lo + (hi - lo) / 2;
            if blocks(mid) <= max_units { hi = mid } else { lo = mid + 1 }
        }
        advice.push(format!("pass_samples={} or more", lo * tessera::passes::BLOCK));
    }
    let advice = if advice.is_empty() {
        "render fewer cameras or fewer pixels per job".to_string()
    } else {
        format!("submit with {}", advice.join(", or with "))
    };
    Err(AppError::new(
        StatusCode::UNPROCESSABLE_ENTITY,
        format!(
            "the job would be {units} units of work (tiles x passes over its frames, one stored row each), more \
             than this server's limit of {max_units} (--max-job-units, TESSERA_MAX_JOB_UNITS); {advice}"
        ),
    ))
}

/// Tiles of frames of `sizes` (width, height, and the tile edge each is cut at: the job's, or
/// the frame's own when it is whole), cut at `tile_size` where that is larger.
fn tile_count(sizes: &[(u32, u32, u32)], tile_size: u32) -> u64 {
    sizes
        .iter()
        .map(|&(w, h, edge)| {
            let t = edge.max(tile_size);
            u64::from(w.div_ceil(t)) * u64::from(h.div_ceil(t))
        })
        .sum()
}

/// Refuses a job that would be cut into more than `max_tiles` tiles (a queue of hundreds of
/// thousands of one-pixel tiles costs the farm more in bookkeeping than in rendering), naming
/// the smallest tile size that fits. `sizes`: each frame's width, height and tile edge.
pub(super) fn check_tile_count(sizes: &[(u32, u32, u32)], tile_size: u32, max_tiles: u64) -> ApiResult<()> {
    let n = tile_count(sizes, 0);
    if n <= max_tiles {
        return Ok(());
    }
    let fits = (tile_size..=4096).find(|&t| tile_count(sizes, t) <= max_tiles);
    let advice = match fits {
        Some(t) => format!("submit with tile_size={t} or more"),
        None => "render fewer cameras per job".to_string(),
    };
    Err(AppError::new(
        StatusCode::UNPROCESSABLE_ENTITY,
        format!(
            "the job would be cut into {n} tiles of {tile_size} pixels, more than this server's limit of \
             {max_tiles} tiles per job (--max-job-tiles, TESSERA_MAX_JOB_TILES); {advice}"
        ),
    ))
}

/// An upload field that must be an integer between 1 and `max` (`unit` for the message).
pub(super) fn bounded(what: &str, value: i64, max: i64, unit: &str) -> ApiResult<u32> {
    if (1..=max).contains(&value) {
        Ok(value as u32)
    } else {
        let unit = if unit.is_empty() { String::new() } else { format!(" {unit}") };
        Err(AppError::bad_request(format!("{what} must be between 1 and {max}{unit}, found {value}")))
    }
}

/// The 413 of an upload over `--max-upload-mb` (`limit` bytes), found while reading it or, from
/// its `Content-Length`, before (`oversized_uploads`).
pub(super) fn upload_too_large(limit: usize) -> AppError {
    AppError::new(
        StatusCode::PAYLOAD_TOO_LARGE,
        format!(
            "the upload is larger than this server accepts ({} MiB); start the server with a larger --max-upload-mb",
            limit >> 20
        ),
    )
}
