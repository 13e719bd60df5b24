//! Job submission: the multipart upload spooled to disk under the caps, unpacked, validated
//! (parse and build the scene, check the tile and sample limits) and stored as a queued job.

use std::path::PathBuf;
use std::sync::Arc;

use axum::Json;
use axum::extract::{Multipart, State};
use axum::http::StatusCode;
use tessera::bundle::{BundleFiles, BundleSceneError, load_bundle_scene};
use tessera::camera::Camera;
use tessera::protocol::*;
use tessera::scene::load::LoadOptions;

use super::jobs::job_info;
use super::{ApiResult, AppError, AppState, Settings, off_thread};
use crate::bundle::{self, BundleError, Files, Unpacker};

/// The multipart form of a submission, for the OpenAPI description only (the handler reads the
/// fields as they stream in, see [`read_fields`]). Files are named by their path relative to the
/// scene file (the part's file name).
#[derive(utoipa::ToSchema)]
#[allow(dead_code)]
pub(super) struct SubmitForm {
    /// The scene file (.xml or .json).
    #[schema(value_type = Option<String>, format = Binary)]
    scene: Option<Vec<u8>>,
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
}

/// Options of a submission (multipart text fields).
#[derive(Default)]
struct SubmitOptions {
    name: Option<String>,
    priority: i64,
    tile_size: Option<u32>,
    samples: Option<u32>,
    cameras: Option<Vec<u32>>,
    scene_path: Option<String>,
    /// Render the scene without the elements Tessera does not implement instead of refusing it.
    allow_unsupported: bool,
    /// Also write each frame denoised.
    denoise: bool,
    pass_samples: Option<u32>,
    noise_target: Option<f64>,
    /// The video of the frames (`mp4`, `gif`, `none`; default: `video.rs`'s rule).
    video: Option<VideoKind>,
    /// Its frames a second.
    fps: Option<u32>,
}

fn problem_from(e: &tessera::SceneError) -> Problem {
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
    scene_field: &mut Option<String>,
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
                    *scene_field = tessera::assets::normalize_bundle_path(&f);
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
            "cameras" => opts.cameras = Some(camera_list(&text())?),
            "video" => {
                opts.video = Some(VideoKind::parse(&text()).ok_or_else(|| {
                    AppError::bad_request(format!("video must be mp4, gif or none, found \"{}\"", text()))
                })?)
            }
            "fps" => opts.fps = Some(bounded("fps", number("fps")?, 120, "frames a second")?),
            "scene_path" => opts.scene_path = Some(text()),
            field @ ("allow_unsupported" | "denoise") => {
                let yes = match text().as_str() {
                    "true" | "1" => true,
                    "false" | "0" => false,
                    other => {
                        return Err(AppError::bad_request(format!(
                            "{field} must be true or false, found \"{other}\""
                        )));
                    }
                };
                if field == "denoise" {
                    opts.denoise = yes;
                } else {
                    opts.allow_unsupported = yes;
                }
            }
            other => {
                return Err(AppError::bad_request(format!(
                    "unknown field \"{other}\"; send scene, asset (one per file, named by its relative path), bundle, name, priority, tile_size, samples, pass_samples, noise_target, cameras, scene_path, allow_unsupported, denoise, video or fps"
                )));
            }
        }
    }
    Ok(())
}

#[utoipa::path(post, path = "/api/v1/jobs", tag = "jobs", security((), ("api_token" = [])),
    request_body(content = SubmitForm, content_type = "multipart/form-data"),
    responses(
        (status = 201, description = "Accepted and queued (with the scene's warnings)", body = JobInfo),
        (status = 400, description = "Not valid multipart, a bad field, or a scene that does not parse or build (`problems` says where)", body = ApiError),
        (status = 401, description = "The server needs an API token", body = ApiError),
        (status = 413, description = "Over the upload or unpacking limits", body = ApiError),
        (status = 422, description = "Over the tile, unit, frame or sample limits, an empty `cameras`, denoise=true on a server without Intel Open Image Denoise, video=mp4 on a server without ffmpeg, or a video of frames of different sizes", body = ApiError),
        (status = 507, description = "The server's disk is full: nothing was stored; submit again once space is freed", body = ApiError)))]
pub(super) async fn submit_job(
    State(state): State<AppState>,
    mut multipart: Multipart,
) -> ApiResult<(StatusCode, Json<JobInfo>)> {
    let limits = state.settings.bundle_limits;
    let mut spool = Spool::new(&state.settings.data_dir)?;
    let mut opts = SubmitOptions::default();
    let mut scene_field: Option<String> = None;
    if let Err(refusal) = read_fields(&state, &mut multipart, &mut spool, &mut opts, &mut scene_field).await {
        // Read the rest of the body (bounded by --max-upload-mb, discarded) so that a client
        // still sending gets the answer instead of a broken connection.
        while let Ok(Some(mut field)) = multipart.next_field().await {
            while let Ok(Some(_)) = field.chunk().await {}
        }
        return Err(refusal);
    }
    if opts.denoise {
        // Refused before anything is unpacked: the server denoises the merged frames, so it needs
        // the library itself (workers only send features).
        let found = tokio::task::spawn_blocking(|| tessera_denoise::oidn().map(|_| ()))
            .await
            .map_err(|e| anyhow::anyhow!("denoiser lookup task: {e}"))?;
        if let Err(e) = found {
            return Err(AppError::new(
                StatusCode::UNPROCESSABLE_ENTITY,
                format!("denoise=true: this server cannot denoise: {e}; or submit without denoise"),
            ));
        }
    }
    let too_large = |e: BundleError| AppError::new(StatusCode::PAYLOAD_TOO_LARGE, e.to_string());
    if spool.parts.is_empty() {
        return Err(AppError::bad_request(
            "the upload holds no files; send the scene as the \"scene\" field (and its assets as \"asset\" fields) or a \"bundle\" archive",
        ));
    }

    // Unpacking and validation hold the files in memory: a few uploads at a time, so the
    // server's memory stays bounded however many arrive at once.
    let _permit = super::turn(&state.unpacking).await?;
    let tile_size = opts.tile_size.unwrap_or(state.settings.tile_size);
    let wanted = opts.scene_path.clone().or(scene_field);
    let cameras_wanted = opts.cameras.clone();
    let max_tiles = state.settings.max_job_tiles;
    let load = LoadOptions { allow_unsupported: opts.allow_unsupported };
    let (scene_path, tar, cameras, frames, warnings) = tokio::task::spawn_blocking(move || {
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
        let scene_path = bundle::find_scene(&files, wanted.as_deref()).map_err(AppError::bad_request)?;
        let (tar, cameras, frames, warnings) =
            validate(files, &scene_path, load, cameras_wanted, tile_size, max_tiles)?;
        Ok::<_, AppError>((scene_path, tar, cameras, frames, warnings))
    })
    .await
    .map_err(|e| anyhow::anyhow!("validation task: {e}"))??;
    check_sample_budget(&state.settings, &cameras, &frames, opts.samples)?;
    let mut frames = frames;
    plan_passes(
        &mut frames,
        &cameras,
        opts.samples,
        opts.pass_samples,
        opts.noise_target.is_some(),
        (tile_size, state.settings.max_job_units),
    )?;
    if opts.denoise {
        check_denoise_size(&frames)?;
    }
    let sizes: Vec<(u32, u32, u32)> =
        frames.iter().enumerate().map(|(k, f)| (k as u32, f.width, f.height)).collect();
    let (video, fps) = (opts.video, opts.fps);
    tokio::task::spawn_blocking(move || crate::video::check_submission(video, &sizes, &[]))
        .await
        .map_err(|e| anyhow::anyhow!("video check task: {e}"))?
        .map_err(|m| AppError::new(StatusCode::UNPROCESSABLE_ENTITY, m))?;
    let name = opts.name.unwrap_or_else(|| scene_path.rsplit('/').next().unwrap_or(&scene_path).to_string());
    off_thread(move || {
        let hash = state.blobs.put(&tar)?;
        let job = crate::db::NewJob {
            name,
            priority: opts.priority,
            tile_size,
            samples: opts.samples,
            bundle: hash,
            scene_path,
            frames,
            warnings: warnings.clone(),
            allow_unsupported: opts.allow_unsupported,
            denoise: opts.denoise,
            pass_samples: opts.pass_samples,
            noise_target: opts.noise_target,
        };
        let id = state.store.insert_job(&job)?;
        state.store.set_video_options(id, video, fps)?;
        state.cameras.lock().unwrap_or_else(|e| e.into_inner()).insert(id, Arc::new(cameras));
        state.scheduler.job_submitted(id);
        tracing::info!(job = id, name = %job.name, "job accepted");
        let mut info = job_info(&state, id)?.ok_or_else(|| anyhow::anyhow!("job {id} vanished"))?;
        info.warnings = warnings;
        Ok((StatusCode::CREATED, Json(info)))
    })
    .await
}

/// Refuses a job asking for more samples than the server's `--max-job-samples`: one that would
/// keep the farm busy for days is a 422 that says the limit and how to get under it.
fn check_sample_budget(
    settings: &Settings,
    cameras: &[Camera],
    frames: &[crate::db::NewFrame],
    samples: Option<u32>,
) -> ApiResult<()> {
    let mut total: u64 = 0;
    for f in frames {
        let spp = samples.unwrap_or(cameras[f.camera as usize].num_samples).max(1);
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
fn check_denoise_size(frames: &[crate::db::NewFrame]) -> ApiResult<()> {
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

/// Most frames (selected cameras) one job may render: each is a row, a line of the job's JSON
/// and a merge.
pub const MAX_JOB_FRAMES: usize = 1024;

/// The cameras a submission's `cameras` field names ("1,3", "1 3"), each once, in the order
/// first named; an empty list is refused (it would make a job of no frames, queued for ever).
fn camera_list(text: &str) -> ApiResult<Vec<u32>> {
    let mut list = Vec::new();
    for part in text.split([',', ' ']).map(str::trim).filter(|p| !p.is_empty()) {
        let k: u32 = part.parse().ok().filter(|k| *k >= 1).ok_or_else(|| {
            AppError::bad_request(format!(
                "cameras must list camera numbers from 1, e.g. \"1,3\"; found \"{part}\""
            ))
        })?;
        if !list.contains(&k) {
            if list.len() == MAX_JOB_FRAMES {
                return Err(too_many_frames(MAX_JOB_FRAMES + 1));
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

/// The 422 of a job of more than [`MAX_JOB_FRAMES`] frames (`n`: at least how many).
fn too_many_frames(n: usize) -> AppError {
    AppError::new(
        StatusCode::UNPROCESSABLE_ENTITY,
        format!(
            "the job would render {n} or more frames (cameras), more than the {MAX_JOB_FRAMES} one job may; \
             name at most {MAX_JOB_FRAMES} cameras with cameras=, e.g. cameras=1,2,3, and submit the rest as other jobs"
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
fn plan_passes(
    frames: &mut [crate::db::NewFrame],
    cameras: &[Camera],
    samples: Option<u32>,
    pass_samples: Option<u32>,
    noise_target: bool,
    (tile_size, max_units): (u32, u64),
) -> ApiResult<()> {
    let mut units = 0u64;
    for f in frames.iter_mut() {
        f.samples = samples.unwrap_or(cameras[f.camera as usize].num_samples).max(1);
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

/// Tiles of frames of `sizes` cut at `tile_size`.
fn tile_count(sizes: &[(u32, u32)], tile_size: u32) -> u64 {
    sizes.iter().map(|&(w, h)| u64::from(w.div_ceil(tile_size)) * u64::from(h.div_ceil(tile_size))).sum()
}

/// Refuses a job that would be cut into more than `max_tiles` tiles (a queue of hundreds of
/// thousands of one-pixel tiles costs the farm more in bookkeeping than in rendering), naming
/// the smallest tile size that fits.
fn check_tile_count(sizes: &[(u32, u32)], tile_size: u32, max_tiles: u64) -> ApiResult<()> {
    let n = tile_count(sizes, tile_size);
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
fn bounded(what: &str, value: i64, max: i64, unit: &str) -> ApiResult<u32> {
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

/// What a valid upload becomes: the canonical bundle, the scene's cameras, the frames to render
/// and the scene's warnings.
type Validated = (Vec<u8>, Vec<Camera>, Vec<crate::db::NewFrame>, Vec<String>);

/// Parses and builds the scene from the uploaded files.
fn validate(
    files: Files,
    scene_path: &str,
    load: LoadOptions,
    cameras_wanted: Option<Vec<u32>>,
    tile_size: u32,
    max_tiles: u64,
) -> ApiResult<Validated> {
    let tar = bundle::canonical_tar(&files).map_err(|e| AppError::bad_request(e.to_string()))?;
    let shared: BundleFiles = files.into_iter().map(|(k, v)| (k, Arc::new(v))).collect();
    let scene = load_bundle_scene(shared, scene_path, load).map_err(|e| match e {
        // The scene file is not text: said as it is ("<file>: the scene file is not UTF-8 text ...").
        BundleSceneError::Unreadable(e) => AppError::new(StatusCode::UNPROCESSABLE_ENTITY, e.to_string()),
        BundleSceneError::Invalid(e) => AppError {
            status: StatusCode::UNPROCESSABLE_ENTITY,
            body: ApiError {
                error: format!("the scene cannot be rendered: {e}"),
                problems: vec![problem_from(&e)],
            },
        },
        // One problem per element.
        BundleSceneError::Unsupported(errors) => AppError {
            status: StatusCode::UNPROCESSABLE_ENTITY,
            body: ApiError {
                error: format!(
                    "{scene_path}: the scene uses {} element(s) that change the picture but are not supported; \
                     remove them, or submit with allow_unsupported=true to render without them",
                    errors.len()
                ),
                problems: errors.iter().map(problem_from).collect(),
            },
        },
    })?;
    if scene.cameras.is_empty() {
        return Err(AppError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            format!("{scene_path}: the scene has no camera; add one under <Cameras>"),
        ));
    }
    let selected: Vec<u32> = match cameras_wanted {
        None => (0..scene.cameras.len() as u32).collect(),
        Some(list) => {
            let n = scene.cameras.len() as u32;
            if let Some(bad) = list.iter().find(|k| **k > n) {
                return Err(AppError::bad_request(format!(
                    "camera {bad} does not exist: the scene has {n} camera(s), numbered from 1"
                )));
            }
            list.into_iter().map(|k| k - 1).collect()
        }
    };
    if selected.len() > MAX_JOB_FRAMES {
        return Err(too_many_frames(selected.len()));
    }
    let sizes: Vec<(u32, u32)> = selected
        .iter()
        .map(|&c| (scene.cameras[c as usize].width, scene.cameras[c as usize].height))
        .collect();
    check_tile_count(&sizes, tile_size, max_tiles)?;
    let frames = selected
        .iter()
        .map(|&c| {
            let cam = &scene.cameras[c as usize];
            crate::db::NewFrame {
                camera: c,
                image_name: cam.image_name.clone(),
                width: cam.width,
                height: cam.height,
                tiles: tessera::render::tiles(cam.width, cam.height, tile_size)
                    .into_iter()
                    .map(Rect::from)
                    .collect(),
                // Set by `plan_passes` once the job's options are known.
                samples: cam.num_samples.max(1),
                pass_samples: tessera::passes::round_to_blocks(cam.num_samples),
            }
        })
        .collect();
    let warnings = scene.warnings.iter().map(ToString::to_string).collect();
    Ok((tar, scene.cameras, frames, warnings))
}
