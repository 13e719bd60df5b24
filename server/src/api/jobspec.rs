//! A job as both forms of `POST /api/v1/jobs` describe it (multipart, or a JSON
//! [`JobRequest`] naming files the server already has): its scene files in frame order and every
//! file by path. Here it is checked (paths, the caps, the store), every scene parsed and built,
//! the frames listed (scene by scene, each scene's cameras), and the job stored with its
//! manifest.

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;

use axum::Json;
use axum::http::StatusCode;
use tessera::bundle::{BundleFiles, BundleSceneError, load_bundle_scene_cached};
use tessera::camera::Camera;
use tessera::protocol::*;
use tessera::scene::Scene;
use tessera::scene::cache::MeshCache;
use tessera::scene::load::LoadOptions;

use super::jobs::job_info;
use super::submit::{self, SubmitOptions};
use super::{ApiResult, AppError, AppState, off_thread};
use crate::bundle::{BundleError, Limits, Unpacker};

/// A job about to be validated: its scene files (normalised paths of `files`) in frame order
/// and every file's bytes, with their SHA-256s.
pub(super) struct Submission {
    pub scenes: Vec<String>,
    pub files: BundleFiles,
    /// SHA-256 and size of each file, by path (sorted: the manifest's order).
    pub digests: BTreeMap<String, (String, u64)>,
    /// Whether the files are in the file store already (a JSON submission) or still to be put
    /// there once the job is valid (a multipart upload).
    pub stored: bool,
    pub opts: SubmitOptions,
}

/// The 413 of a job over one of the bundle limits (the same as an upload over them).
fn over_limits(e: BundleError) -> AppError {
    AppError::new(StatusCode::PAYLOAD_TOO_LARGE, e.to_string())
}

/// Checks a [`JobRequest`]'s files (paths, duplicates, the caps) and that the server has each
/// of them, then reads them. A file the store lacks is a 409 listing every missing one.
pub(super) fn request_submission(state: &AppState, req: JobRequest) -> ApiResult<Submission> {
    let limits: Limits = state.settings.bundle_limits;
    let checker = Unpacker::new(limits);
    if req.files.len() > limits.max_files {
        return Err(over_limits(checker.too_many_files_error()));
    }
    let mut digests = BTreeMap::new();
    let mut total = 0u64;
    for f in &req.files {
        let path = tessera::assets::normalize_bundle_path(&f.path).ok_or_else(|| {
            AppError::bad_request(format!(
                "files: the path \"{}\" is absolute or leaves the job's top folder; give paths relative to it, \
                 '/'-separated",
                f.path
            ))
        })?;
        if !crate::files::is_sha256(&f.sha256) {
            return Err(AppError::bad_request(format!(
                "files: {path}: sha256 must be the file's SHA-256 in 64 lowercase hex digits, found \"{}\"",
                f.sha256
            )));
        }
        if f.size > limits.max_file_bytes {
            return Err(over_limits(checker.file_too_large_error(&path)));
        }
        total = total.saturating_add(f.size);
        if total > limits.max_unpacked_bytes {
            return Err(AppError::new(
                StatusCode::PAYLOAD_TOO_LARGE,
                format!(
                    "the job's files add up to more than this server accepts for one job ({} MiB); start the server \
                     with a larger --max-unpacked-mb, or submit fewer files",
                    limits.max_unpacked_bytes >> 20
                ),
            ));
        }
        if digests.insert(path.clone(), (f.sha256.clone(), f.size)).is_some() {
            return Err(AppError::bad_request(format!("files: the path {path} is given twice")));
        }
    }
    let scenes = scene_list(&req.scenes, &digests)?;
    let missing: Vec<(&String, &(String, u64))> =
        digests.iter().filter(|(_, (sha, size))| !state.files.has(sha, *size)).collect();
    if !missing.is_empty() {
        let listed: Vec<String> =
            missing.iter().take(20).map(|(p, (sha, size))| format!("{p} ({sha}, {size} bytes)")).collect();
        let more =
            if missing.len() > 20 { format!(" and {} more", missing.len() - 20) } else { String::new() };
        return Err(AppError {
            status: StatusCode::CONFLICT,
            body: ApiError {
                error: format!(
                    "the server does not have {} of the job's files: {}{more}; upload them first with \
                     PUT /api/v1/files/{{sha256}} (POST /api/v1/files/missing lists what it lacks), then submit again",
                    missing.len(),
                    listed.join(", ")
                ),
                problems: missing
                    .iter()
                    .map(|(p, (sha, _))| Problem {
                        file: Some((*p).clone()),
                        line: None,
                        element: None,
                        message: format!("missing: {sha}"),
                    })
                    .collect(),
            },
        });
    }
    let mut files = BundleFiles::new();
    for (path, (sha, _)) in &digests {
        let bytes =
            state.files.read(sha).map_err(|e| anyhow::anyhow!("cannot read stored file {sha}: {e}"))?;
        files.insert(path.clone(), Arc::new(bytes));
    }
    let opts = SubmitOptions {
        name: req.name,
        priority: req.priority.unwrap_or(0),
        tile_size: req
            .tile_size
            .map(|t| submit::bounded("tile_size", i64::from(t), 4096, "pixels"))
            .transpose()?,
        samples: req.samples.map(|s| submit::bounded("samples", i64::from(s), 1_000_000, "")).transpose()?,
        cameras: req
            .cameras
            .map(|c| submit::camera_selection(c, state.settings.max_job_frames))
            .transpose()?,
        scene_path: None,
        allow_unsupported: req.allow_unsupported,
        denoise: req.denoise,
        pass_samples: req
            .pass_samples
            .map(|s| submit::bounded("pass_samples", i64::from(s), 1_000_000, ""))
            .transpose()?,
        noise_target: req
            .noise_target
            .map(|t| {
                tessera::passes::check_noise_target(t)
                    .map_err(|e| AppError::bad_request(format!("noise_target: {e}")))
            })
            .transpose()?,
        video: req.video,
        fps: req.fps.map(check_fps).transpose()?,
        keep_float: req.keep_float,
        scenes: None,
        notify_url: req.notify_url,
        scale: req.scale.map(submit::check_scale).transpose()?,
        worker_tags: req.worker_tags,
    };
    Ok(Submission { scenes, files, digests, stored: true, opts })
}

/// `fps` as a job may ask: 1 to 120 frames a second.
pub(super) fn check_fps(fps: u32) -> ApiResult<u32> {
    if (1..=120).contains(&fps) {
        Ok(fps)
    } else {
        Err(AppError::bad_request(format!("fps must be between 1 and 120 frames a second, found {fps}")))
    }
}

/// The scene files `listed` (paths, in frame order), normalised, each one of the job's files.
pub(super) fn scene_list<T>(listed: &[String], files: &BTreeMap<String, T>) -> ApiResult<Vec<String>> {
    if listed.is_empty() {
        return Err(AppError::bad_request(
            "scenes lists no scene file; name the scene files to render, in frame order",
        ));
    }
    listed
        .iter()
        .map(|s| {
            let path = tessera::assets::normalize_bundle_path(s).ok_or_else(|| {
                AppError::bad_request(format!(
                    "scenes: the path \"{s}\" is absolute or leaves the job's top folder"
                ))
            })?;
            if files.contains_key(&path) {
                Ok(path)
            } else {
                Err(AppError::bad_request(format!(
                    "scenes: {path} is not one of the job's files; add it to the files (or fix the path)"
                )))
            }
        })
        .collect()
}

/// Parses and builds the scene `scene_path` of `files` as a worker will (the same
/// [`LoadOptions`]): the one place a submission builds a scene. `meshes` is the submission's
/// own cache, shared by its scenes: a sequence's PLY files are parsed and their BVHs built once,
/// not once a frame.
pub(super) fn validate_scene(
    files: &BundleFiles,
    scene_path: &str,
    load: LoadOptions,
    meshes: &MeshCache,
) -> Result<Scene, BundleSceneError> {
    load_bundle_scene_cached(files.clone(), scene_path, load, Some(meshes))
}

/// The memory a submission's mesh cache may hold (it lives while the submission is validated;
/// at most `UNPACKING_AT_ONCE` submissions are).
pub const VALIDATION_MESH_CACHE_BYTES: u64 = 1 << 30;

/// Scenes a submission builds at once, at most (fewer on a machine of fewer cores).
pub const SCENES_AT_ONCE: usize = 4;

/// What validation keeps of a built scene: its cameras and its warnings.
struct Loaded {
    cameras: Vec<Camera>,
    warnings: Vec<String>,
}

/// What a valid job's scenes make: each frame's camera (by frame index), the frames and the
/// scenes' warnings.
pub(super) type Frames = (Vec<Camera>, Vec<crate::db::NewFrame>, Vec<String>);

/// Frames of at most this many samples (pixels x samples per pixel) are one tile each when the
/// job names no `tile_size`: a small frame costs one lease, one upload and one merge of one
/// tile, instead of dozens of each (a course frame of 800 x 800 at up to 26 spp).
pub const WHOLE_FRAME_SAMPLES: u64 = 1 << 24;

/// The caps a job's frames are held to while its scenes are read.
pub(super) struct FrameLimits {
    pub tile_size: u32,
    /// The job named its `tile_size` (otherwise small frames are whole: [`WHOLE_FRAME_SAMPLES`]).
    pub tile_size_given: bool,
    /// The job's `samples` (instead of each camera's).
    pub samples: Option<u32>,
    pub max_tiles: u64,
    pub max_frames: usize,
    /// The job's `scale`: each frame's camera at this scale.
    pub scale: Option<f64>,
}

/// Builds every scene of `scenes` (in order) and lists the job's frames: each scene's
/// cameras, all or the 1-based `cameras_wanted`. Errors name the scene, and for a sequence the
/// frame it starts at.
pub(super) fn validate_frames(
    files: &BundleFiles,
    scenes: &[String],
    load: LoadOptions,
    cameras_wanted: Option<&[u32]>,
    limits: &FrameLimits,
) -> ApiResult<Frames> {
    if scenes.len() > limits.max_frames {
        return Err(submit::too_many_frames(scenes.len(), limits.max_frames));
    }
    let sequence = scenes.len() > 1;
    let (mut cameras, mut frames, mut warnings) = (Vec::new(), Vec::new(), Vec::new());
    // Which frame writes each output name first.
    let mut names: HashMap<String, (usize, String)> = HashMap::new();
    // A few scenes are built at once (each on a thread of a pool of the submission's own, its
    // meshes in memory until its cameras and warnings are taken), a batch at a time in frame
    // order, so that the first refusal is the first frame's and nothing after its batch is
    // built.
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).clamp(1, SCENES_AT_ONCE);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(|k| format!("validate-{k}"))
        .build()
        .map_err(|e| anyhow::anyhow!("cannot start the validation threads: {e}"))?;
    let meshes = MeshCache::new(VALIDATION_MESH_CACHE_BYTES);
    let loaded = scenes.chunks(threads * 2).flat_map(|batch| {
        let built: Vec<_> = pool.install(|| {
            use rayon::prelude::*;
            batch
                .par_iter()
                .map(|path| {
                    validate_scene(files, path, load, &meshes).map(|scene| Loaded {
                        warnings: scene.warnings.iter().map(ToString::to_string).collect(),
                        cameras: scene.cameras,
                    })
                })
                .collect()
        });
        batch.iter().zip(built)
    });
    for (scene_path, built) in loaded {
        let first = frames.len();
        let at = |message: String| {
            if sequence { format!("frame {first} ({scene_path}): {message}") } else { message }
        };
        let scene: Loaded = built.map_err(|e| scene_refusal(e, scene_path, &at))?;
        if scene.cameras.is_empty() {
            return Err(AppError::new(
                StatusCode::UNPROCESSABLE_ENTITY,
                at(format!("{scene_path}: the scene has no camera; add one under <Cameras>")),
            ));
        }
        let n = scene.cameras.len() as u32;
        let selected: Vec<u32> = match cameras_wanted {
            None => (0..n).collect(),
            Some(list) => {
                if let Some(bad) = list.iter().find(|k| **k > n) {
                    return Err(AppError::bad_request(at(format!(
                        "camera {bad} does not exist: {scene_path} has {n} camera(s), numbered from 1"
                    ))));
                }
                list.iter().map(|k| k - 1).collect()
            }
        };
        if frames.len() + selected.len() > limits.max_frames {
            return Err(submit::too_many_frames(frames.len() + selected.len(), limits.max_frames));
        }
        for c in selected {
            let cam = &match limits.scale {
                Some(s) => scene.cameras[c as usize].scaled(s),
                None => scene.cameras[c as usize].clone(),
            };
            let index = frames.len();
            let name = tessera::output::plan(cam).0[0].name.clone();
            if let Some((other, other_scene)) = names.get(&name) {
                return Err(AppError::new(
                    StatusCode::UNPROCESSABLE_ENTITY,
                    format!(
                        "frames {other} ({other_scene}) and {index} ({scene_path}, camera {}) both write {name}; \
                         give each camera its own ImageName",
                        c + 1
                    ),
                ));
            }
            names.insert(name, (index, scene_path.clone()));
            frames.push(crate::db::NewFrame {
                camera: c,
                image_name: cam.image_name.clone(),
                width: cam.width,
                height: cam.height,
                tiles: Vec::new(),
                // Set by `plan_passes` once the job's options are known.
                samples: cam.num_samples.max(1),
                pass_samples: tessera::passes::round_to_blocks(cam.num_samples),
                scene_path: Some(scene_path.clone()),
            });
            cameras.push(cam.clone());
        }
        warnings.extend(scene.warnings.into_iter().map(at));
    }
    let mut sizes: Vec<(u32, u32, u32)> = Vec::with_capacity(frames.len());
    for (f, cam) in frames.iter_mut().zip(&cameras) {
        let spp = limits.samples.unwrap_or(cam.num_samples).max(1);
        let whole = !limits.tile_size_given
            && u64::from(f.width) * u64::from(f.height) * u64::from(spp) <= WHOLE_FRAME_SAMPLES;
        let edge = if whole { f.width.max(f.height).max(1) } else { limits.tile_size };
        sizes.push((f.width, f.height, edge));
        f.tiles = tessera::render::tiles(f.width, f.height, edge).into_iter().map(Rect::from).collect();
    }
    submit::check_tile_count(&sizes, limits.tile_size, limits.max_tiles)?;
    Ok((cameras, frames, warnings))
}

/// The refusal of a scene that does not load; `at` puts the frame before a sequence's messages.
fn scene_refusal(e: BundleSceneError, scene_path: &str, at: &dyn Fn(String) -> String) -> AppError {
    match e {
        // The scene file is not text: said as it is ("<file>: the scene file is not UTF-8 text ...").
        BundleSceneError::Unreadable(e) => AppError::new(StatusCode::UNPROCESSABLE_ENTITY, at(e.to_string())),
        BundleSceneError::Invalid(e) => AppError {
            status: StatusCode::UNPROCESSABLE_ENTITY,
            body: ApiError {
                error: at(format!("the scene cannot be rendered: {e}")),
                problems: vec![submit::problem_from(&e)],
            },
        },
        // One problem per element.
        BundleSceneError::Unsupported(errors) => AppError {
            status: StatusCode::UNPROCESSABLE_ENTITY,
            body: ApiError {
                error: at(format!(
                    "{scene_path}: the scene uses {} element(s) that change the picture but are not supported; \
                     remove them, or submit with allow_unsupported=true to render without them",
                    errors.len()
                )),
                problems: errors.iter().map(submit::problem_from).collect(),
            },
        },
    }
}

/// Validates a submission and stores it as a queued job: its files in the file store (a
/// multipart upload's), its manifest, its frames and units of work.
pub(super) async fn accept(state: AppState, sub: Submission) -> ApiResult<(StatusCode, Json<JobInfo>)> {
    let Submission { scenes, files, digests, stored, opts } = sub;
    if let Some(url) = &opts.notify_url
        && !crate::notify::allowed(url, &state.settings.notify_allow)
    {
        let allowed = &state.settings.notify_allow;
        return Err(AppError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            if allowed.is_empty() {
                "notify_url: this server lets no job choose where its end is POSTed (its operator allows URL \
                 prefixes with --notify-allow); submit without notify_url"
                    .to_string()
            } else {
                format!(
                    "notify_url must be an http(s) URL under one of the prefixes this server allows ({}); \
                     submit with such a URL or without notify_url",
                    allowed.join(", ")
                )
            },
        ));
    }
    let worker_tags = check_tags(&opts.worker_tags).map_err(|e| {
        AppError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            format!("worker_tags: {e}; name the tags a worker must have, e.g. worker_tags=gpu,big"),
        )
    })?;
    if opts.denoise {
        submit::check_denoiser().await?;
    }
    let tile_size = opts.tile_size.unwrap_or(state.settings.tile_size);
    let limits = FrameLimits {
        tile_size,
        tile_size_given: opts.tile_size.is_some(),
        samples: opts.samples,
        max_tiles: state.settings.max_job_tiles,
        max_frames: state.settings.max_job_frames,
        scale: opts.scale,
    };
    let load = LoadOptions { allow_unsupported: opts.allow_unsupported };
    let wanted = opts.cameras.clone();
    let (scenes, files, (cameras, mut frames, warnings)) = tokio::task::spawn_blocking(move || {
        let started = std::time::Instant::now();
        let frames = validate_frames(&files, &scenes, load, wanted.as_deref(), &limits)?;
        tracing::info!(
            scenes = scenes.len(),
            seconds = started.elapsed().as_secs_f64(),
            "submission validated"
        );
        Ok::<_, AppError>((scenes, files, frames))
    })
    .await
    .map_err(|e| anyhow::anyhow!("validation task: {e}"))??;
    submit::check_sample_budget(&state.settings, &cameras, &frames, opts.samples)?;
    submit::plan_passes(
        &mut frames,
        &cameras,
        opts.samples,
        opts.pass_samples,
        opts.noise_target.is_some(),
        (tile_size, state.settings.max_job_units),
    )?;
    if opts.denoise {
        submit::check_denoise_size(&frames)?;
    }
    // A video asked for needs ffmpeg (an MP4) and frames of one size.
    let sizes: Vec<(u32, u32, u32)> =
        frames.iter().enumerate().map(|(k, f)| (k as u32, f.width, f.height)).collect();
    let frame_scenes: Vec<String> =
        frames.iter().map(|f| f.scene_path.clone().unwrap_or_else(|| scenes[0].clone())).collect();
    let video = opts.video;
    tokio::task::spawn_blocking(move || crate::video::check_submission(video, &sizes, &frame_scenes))
        .await
        .map_err(|e| anyhow::anyhow!("video check task: {e}"))?
        .map_err(|m| AppError::new(StatusCode::UNPROCESSABLE_ENTITY, m))?;
    let scene_path = scenes[0].clone();
    let name = opts.name.unwrap_or_else(|| scene_path.rsplit('/').next().unwrap_or(&scene_path).to_string());
    off_thread(move || {
        // The file store's collection holds the gate to write while it removes files no job
        // names: from the check that the job's files are there to the job's rows, they stay.
        let _gate = state.files.gate.read().unwrap_or_else(|e| e.into_inner());
        if stored {
            let gone: Vec<&String> =
                digests.iter().filter(|(_, (sha, size))| !state.files.has(sha, *size)).map(|(p, _)| p).collect();
            if !gone.is_empty() {
                return Err(AppError::new(
                    StatusCode::CONFLICT,
                    format!(
                        "the server no longer has {} of the job's files ({}); upload them again with PUT /api/v1/files/{{sha256}} and submit again",
                        gone.len(),
                        gone.iter().take(5).map(|p| p.as_str()).collect::<Vec<_>>().join(", ")
                    ),
                ));
            }
        }
        if !stored {
            for bytes in files.values() {
                state.files.put(bytes)?;
            }
        }
        drop(files);
        let manifest = Manifest {
            files: digests
                .iter()
                .map(|(path, (sha, size))| JobFile { path: path.clone(), sha256: sha.clone(), size: *size })
                .collect(),
        };
        let manifest_sha = state.files.put(&serde_json::to_vec(&manifest).map_err(anyhow::Error::new)?)?;
        let job = crate::db::NewJob {
            name,
            priority: opts.priority,
            tile_size,
            samples: opts.samples,
            bundle: String::new(),
            scene_path,
            frames,
            warnings: warnings.clone(),
            allow_unsupported: opts.allow_unsupported,
            denoise: opts.denoise,
            pass_samples: opts.pass_samples,
            noise_target: opts.noise_target,
            manifest: Some(manifest_sha),
            files: manifest.files,
            scenes: scenes.len() as u32,
            video: opts.video,
            fps: opts.fps,
            keep_float: opts.keep_float,
            notify_url: opts.notify_url,
            scale: opts.scale,
            worker_tags,
        };
        let id = state.store.insert_job(&job)?;
        state.cameras.lock().unwrap_or_else(|e| e.into_inner()).insert(id, Arc::new(cameras));
        state.scheduler.job_submitted(id);
        tracing::info!(job = id, name = %job.name, frames = job.frames.len(), "job accepted");
        let mut info = job_info(&state, id)?.ok_or_else(|| anyhow::anyhow!("job {id} vanished"))?;
        info.warnings = warnings;
        Ok((StatusCode::CREATED, Json(info)))
    })
    .await
}
