//! The wire types of the farm: the job API (`/api/v1/jobs...`) and the worker protocol
//! (`/api/v1/worker/...`), serialised as JSON, plus the binary tile format.
//!
//! Only these types derive `Serialize`/`Deserialize`; the tracer's own types never travel.
//! With the `openapi` feature (the server's) they also derive utoipa's `ToSchema`, so the
//! server's OpenAPI description (`/api/v1/openapi.json`) is made from these very types and their
//! doc comments; the worker builds without it.
//!
//! Worker protocol, in order:
//! 1. `POST /api/v1/worker/register` [`RegisterRequest`] → [`RegisterResponse`].
//! 2. `POST /api/v1/worker/lease` [`LeaseRequest`] (a long poll: the server answers as soon as
//!    a tile is free, or after `wait_seconds` with 204 No Content) → [`Lease`].
//! 3. `GET /api/v1/worker/bundles/{sha256}`: the job's files as a tar archive, fetched once per
//!    job and cached by the worker (content-addressed, so it never changes).
//! 4. While rendering, `POST /api/v1/worker/heartbeat` [`HeartbeatRequest`] every
//!    `heartbeat_seconds` renews the deadlines of the worker's leases (from a thread of its own
//!    that rendering cannot starve) → [`HeartbeatResponse`] lists leases the server revoked.
//!    Beside it, `POST /api/v1/worker/watch` [`WatchRequest`] is a long poll that answers as
//!    soon as one of the listed leases is revoked (its job cancelled), so a tile in progress
//!    stops within a moment of a cancel, not a heartbeat later → [`HeartbeatResponse`].
//! 5. `PUT /api/v1/worker/leases/{lease}/result`: the tile as [`encode_tile`] bytes with the
//!    header [`CHECKSUM_HEADER`] = [`checksum`] of the body. Accepted once; a lease that expired
//!    or was revoked gets 409 Conflict and the worker drops the tile. Or
//!    `POST /api/v1/worker/leases/{lease}/fail` [`FailRequest`] when the tile cannot be rendered.
//! 6. `POST /api/v1/worker/leases/{lease}/release` [`ReleaseRequest`]: a worker that is stopping
//!    gives back a lease it has not started (204; 409 when it is not that worker's live lease),
//!    so the tile goes back to the queue at once instead of waiting for the lease to expire.
//!
//! Every worker request carries `Authorization: Bearer <worker token>`, and every request after
//! registration also [`WORKER_SECRET_HEADER`] with the secret the registration answered: the
//! worker token lets a machine join the farm, the secret proves which registered worker is
//! calling, so one worker cannot report, fail or give back another's leases.
//!
//! Limits every worker keeps (the server refuses what goes past them): a name of at most
//! [`MAX_WORKER_NAME`] bytes, 1 to [`MAX_WORKER_THREADS`] threads, at most threads + 2 live
//! leases, at most [`MAX_LISTED_LEASES`] leases listed in a heartbeat or watch, JSON bodies of at
//! most [`MAX_WORKER_JSON_BYTES`], failure messages of at most [`MAX_ERROR_BYTES`] (longer ones are
//! cut), and tile pixels that are finite numbers ([`check_tile_values`]).

use serde::{Deserialize, Serialize};

/// Header carrying a registered worker's secret (from [`RegisterResponse::worker_secret`]) on
/// each of its requests after registration.
pub const WORKER_SECRET_HEADER: &str = "x-tessera-worker-secret";

/// Longest worker name, in bytes.
pub const MAX_WORKER_NAME: usize = 128;

/// Most render threads a worker may declare (it may hold that many leases plus two).
pub const MAX_WORKER_THREADS: u32 = 1024;

/// Most leases one heartbeat or watch may list: a worker holds at most its threads plus two.
pub const MAX_LISTED_LEASES: usize = MAX_WORKER_THREADS as usize + 2;

/// Largest JSON body of a worker request (register, lease, heartbeat, watch, fail, release).
pub const MAX_WORKER_JSON_BYTES: usize = 64 << 10;

/// Longest failure message the server keeps from a worker, in bytes; the rest is cut.
pub const MAX_ERROR_BYTES: usize = 4 << 10;

/// `text` cut to at most `max` bytes on a character boundary, with a note of how much was cut.
pub fn truncate_message(text: &str, max: usize) -> String {
    if text.len() <= max {
        return text.to_string();
    }
    let mut end = max.saturating_sub(48);
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    format!("{}... ({} more bytes cut)", &text[..end], text.len() - end)
}

/// Header carrying the checksum of a tile upload.
pub const CHECKSUM_HEADER: &str = "x-tessera-checksum";

/// Optional header of a tile upload: the seconds the worker spent rendering the tile, as it
/// measured them (a decimal number). The job log's `tile_done` events and `/metrics` show it.
pub const RENDER_SECONDS_HEADER: &str = "x-tessera-render-seconds";

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct RegisterRequest {
    /// A name for logs and the status page (host name and process id by default).
    pub name: String,
    /// Render threads the worker uses.
    pub threads: u32,
    /// What the worker offers (`tessera-worker work --tags gpu,big`): it leases only tiles of
    /// jobs whose `worker_tags` it all has ([`check_tags`]: at most [`MAX_TAGS`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub tags: Vec<String>,
    /// The worker protocol the worker speaks ([`WORKER_PROTOCOL`]); 0 (absent): a worker from
    /// before versions were sent, or a hand-written client, which the server takes.
    #[serde(default)]
    pub protocol: u32,
}

/// The version of the worker protocol (leases, results, passes, manifests, the scale of a
/// frame): raised whenever a lease or a result gains something that a worker or server of the
/// version before would ignore or misread, so that the two refuse each other rather than render
/// a wrong image. A worker sends it when it registers, and the server answers with its own.
pub const WORKER_PROTOCOL: u32 = 1;

/// Why a worker speaking `worker` and a server speaking `server` cannot work together (`None`:
/// they can). 0 is a side from before versions were exchanged.
pub fn protocol_mismatch(worker: u32, server: u32) -> Option<String> {
    (worker != server).then(|| {
        let name = |v: u32| {
            if v == 0 {
                "an older one, from before versions were exchanged".to_string()
            } else {
                v.to_string()
            }
        };
        format!(
            "the worker speaks worker protocol {} and the server {}: run the same Tessera version on both \
             (tessera-worker --version, tessera-server --version)",
            name(worker),
            name(server)
        )
    })
}

/// The heartbeat periods, in seconds, a server may ask for and a worker keeps: a shorter one
/// would flood the server (a zero `Duration` does not sleep), a longer one does not fit a
/// `Duration` (`Duration::from_secs_f64` panics beyond).
pub const HEARTBEAT_SECONDS: std::ops::RangeInclusive<f64> = 1e-3..=1e9;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct RegisterResponse {
    pub worker_id: u64,
    /// The worker's secret: send it as [`WORKER_SECRET_HEADER`] on every later request. The
    /// server keeps only its hash.
    pub worker_secret: String,
    /// How often to send heartbeats (within [`HEARTBEAT_SECONDS`]).
    pub heartbeat_seconds: f64,
    /// How long a lease lives without a heartbeat.
    pub lease_seconds: f64,
    /// The worker protocol the server speaks ([`WORKER_PROTOCOL`]; 0: a server from before
    /// versions were sent). A worker of another version stops ([`protocol_mismatch`]).
    #[serde(default)]
    pub protocol: u32,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct LeaseRequest {
    pub worker_id: u64,
    /// How long the server may hold the request open waiting for work (it caps this).
    pub wait_seconds: f64,
}

/// A pixel rectangle of a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct Rect {
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
}

/// One tile to render, owned by one worker until its deadline.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct Lease {
    pub lease_id: u64,
    pub job_id: u64,
    /// Index of the camera in the scene file (0-based).
    pub camera: u32,
    pub tile: u32,
    pub rect: Rect,
    /// SHA-256 (hex) of the job's bundle: fetch it once, cache the built scene by it.
    pub bundle: String,
    /// The scene file's path inside the bundle.
    pub scene_path: String,
    /// Samples per pixel instead of the camera's NumSamples (the job's option).
    pub samples: Option<u32>,
    /// Seconds until the lease expires unless a heartbeat renews it.
    pub lease_seconds: f64,
    /// Longest the tile may render (the server's `--max-tile-seconds`); past it the worker
    /// stops and reports the tile failed. Absent from older servers: no limit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_render_seconds: Option<f64>,
    /// The job was submitted with `allow_unsupported=true`: build its scene without the elements
    /// Tessera does not implement instead of refusing it. Absent: false.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub allow_unsupported: bool,
    /// Send the tile's denoising features too ([`encode_tile_with_aux`]): the job is denoised.
    #[serde(default)]
    pub aux: bool,
    /// Render only these samples of each pixel and send their block sums
    /// ([`crate::passes::encode_pass_tile`]) instead of finished pixels. Absent: the whole tile.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pass: Option<PassLease>,
    /// Under a noise target, the pixels of the tile this pass renders: bit `i % 8` of byte
    /// `i / 8` is pixel `i`, row by row ([`crate::passes::encode_mask`]), as lowercase hex; the
    /// others' sums are sent as zero. Absent: every pixel. (A worker that ignores it renders
    /// every pixel, and the server adds only the masked ones: the same image.)
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pass_mask: Option<String>,
    /// Render the frame at this scale, in (0, 1] ([`crate::camera::Camera::scaled`]): the
    /// rect is a tile of the scaled frame. Absent: the camera's own resolution.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<f64>,
    /// SHA-256 of the job's [`Manifest`] (itself a file of the server's file store). When
    /// present, `bundle` is empty, `scene_path` is this frame's scene file (a path of the
    /// manifest), and every file the scene names is the manifest's file of that path, fetched
    /// by `GET /api/v1/worker/files/{sha256}` once and kept in the worker's file cache. Absent:
    /// a job stored before sequences, whose files are the tar `bundle`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub manifest: Option<String>,
}

// ---- Content-addressed files: a job's files are sent and stored once, by SHA-256 ----

/// What names a file in the farm: the SHA-256 of its bytes (64 lowercase hex digits) and its
/// size in bytes.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct FileDigest {
    pub sha256: String,
    pub size: u64,
}

/// `POST /api/v1/files/missing`: which of these files the server does not have yet.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct MissingFilesRequest {
    pub files: Vec<FileDigest>,
}

/// The answer to [`MissingFilesRequest`]: the SHA-256s to upload (each once, in the order
/// asked) with `PUT /api/v1/files/{sha256}`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct MissingFilesResponse {
    pub missing: Vec<String>,
}

/// One file of a job: its path relative to the job's top folder (normalised: `/`-separated,
/// no `.`, `..` or leading `/`) and the file it is.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct JobFile {
    pub path: String,
    pub sha256: String,
    pub size: u64,
}

/// A job's files as the server stores them and workers fetch them: canonical JSON
/// (`serde_json::to_vec` of this, files sorted by path, each path once), kept in the file store
/// under its own SHA-256, which [`Lease::manifest`] names.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct Manifest {
    pub files: Vec<JobFile>,
}

/// What a job's frames become once they are merged.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "lowercase")]
pub enum VideoKind {
    /// H.264 in MP4 (yuv420p, `+faststart`), made by the `ffmpeg` program.
    Mp4,
    /// An animated GIF, made by the server itself.
    Gif,
    /// No video.
    None,
}

impl VideoKind {
    pub fn as_str(self) -> &'static str {
        match self {
            VideoKind::Mp4 => "mp4",
            VideoKind::Gif => "gif",
            VideoKind::None => "none",
        }
    }

    pub fn parse(s: &str) -> Option<VideoKind> {
        Some(match s {
            "mp4" => VideoKind::Mp4,
            "gif" => VideoKind::Gif,
            "none" => VideoKind::None,
            _ => return None,
        })
    }
}

/// `POST /api/v1/jobs` with `Content-Type: application/json`: a job (one scene, or a sequence
/// of scenes, one after another) whose files the server already has (ask with
/// [`MissingFilesRequest`], upload what it lacks, then submit this). Every option is the
/// multipart form's field of the same name.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct JobRequest {
    /// The scene files, paths of `files`, in frame order: each scene's cameras (all, or those
    /// `cameras` names) are frames of the job in this order.
    pub scenes: Vec<String>,
    /// Every file the scenes use, the scenes included.
    pub files: Vec<JobFile>,
    #[serde(default)]
    pub name: Option<String>,
    #[serde(default)]
    pub priority: Option<i64>,
    #[serde(default)]
    pub tile_size: Option<u32>,
    #[serde(default)]
    pub samples: Option<u32>,
    /// Cameras of each scene to render, 1-based (default: all).
    #[serde(default)]
    pub cameras: Option<Vec<u32>>,
    #[serde(default)]
    pub pass_samples: Option<u32>,
    #[serde(default)]
    pub noise_target: Option<f64>,
    #[serde(default)]
    pub allow_unsupported: bool,
    #[serde(default)]
    pub denoise: bool,
    /// The video made of the frames once all are merged (default: `mp4` for a sequence of
    /// more than one scene file, `none` otherwise; a GIF instead when the server has no
    /// `ffmpeg` and the video was not asked for).
    #[serde(default)]
    pub video: Option<VideoKind>,
    /// Frames a second of the video (default 30).
    #[serde(default)]
    pub fps: Option<u32>,
    /// Keep each frame's float image (`.exr`, losslessly compressed) beside a PNG frame
    /// (default: true for a job of one scene file, false for a sequence); false keeps only the
    /// PNG.
    #[serde(default)]
    pub keep_float: Option<bool>,
    /// Where to POST the job's end (under a prefix the server allows with `--notify-allow`).
    #[serde(default)]
    pub notify_url: Option<String>,
    /// Render every frame at this scale, in (0, 1]: each side of the image times `scale`,
    /// rounded to the nearest pixel (halves up), at least 1; the image plane stays, so the
    /// picture is the same, coarser (e.g. 0.25: an 800x450 camera renders at 200x113).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<f64>,
    /// Tags a worker must all have to render this job ([`check_tags`]; default none: any
    /// worker).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub worker_tags: Vec<String>,
}

/// One pass of a tile: samples `start..end` of every pixel (whole blocks of
/// [`crate::passes::BLOCK`] samples from `start`), pass `index` of `count`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct PassLease {
    pub index: u32,
    pub count: u32,
    pub start: u32,
    pub end: u32,
}

/// A long poll for revocations of the leases a worker is rendering.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct WatchRequest {
    pub worker_id: u64,
    pub leases: Vec<u64>,
    /// Longest the server holds the request (it may answer sooner, with nothing revoked).
    pub wait_seconds: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct HeartbeatRequest {
    pub worker_id: u64,
    /// The leases the worker holds (rendering or prefetched).
    pub leases: Vec<u64>,
    /// What the worker is doing, for the status page.
    pub rendering: Option<u64>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct HeartbeatResponse {
    /// Leases the worker no longer owns (expired, cancelled job): drop their work.
    pub revoked: Vec<u64>,
}

/// Gives a lease back unrendered (the worker is stopping).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct ReleaseRequest {
    pub worker_id: u64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct FailRequest {
    pub worker_id: u64,
    pub error: String,
    /// The failure is the job's, not this worker's: its tile went over the farm's longest render
    /// of one tile. The server fails the job at once rather than spend that time again on other
    /// workers. Absent from older workers: false.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub fatal: bool,
}

/// A problem with a submitted scene or bundle, as precise as the parser knows it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct Problem {
    pub file: Option<String>,
    pub line: Option<u32>,
    pub element: Option<String>,
    pub message: String,
}

/// Every error response of the API: `{"error": ..., "problems": [...]}`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct ApiError {
    pub error: String,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub problems: Vec<Problem>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "lowercase")]
pub enum JobState {
    Queued,
    Running,
    /// Paused (`POST /api/v1/jobs/{id}/pause`): leases nothing; the leases already out finish
    /// and their results are kept. `resume` makes it queued or running again.
    Paused,
    Done,
    Failed,
    Canceled,
}

impl JobState {
    pub fn as_str(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Paused => "paused",
            JobState::Done => "done",
            JobState::Failed => "failed",
            JobState::Canceled => "canceled",
        }
    }

    pub fn parse(s: &str) -> Option<JobState> {
        Some(match s {
            "queued" => JobState::Queued,
            "running" => JobState::Running,
            "paused" => JobState::Paused,
            "done" => JobState::Done,
            "failed" => JobState::Failed,
            "canceled" => JobState::Canceled,
            _ => return None,
        })
    }

    /// Finished one way or another: no more tiles will be handed out.
    pub fn is_final(self) -> bool {
        matches!(self, JobState::Done | JobState::Failed | JobState::Canceled)
    }
}

/// A frame (one camera) of a job.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct FrameInfo {
    pub index: u32,
    pub camera: u32,
    pub image_name: String,
    pub width: u32,
    pub height: u32,
    pub tiles_total: u32,
    pub tiles_done: u32,
    /// Output files once the frame is merged, with their download URLs.
    pub outputs: Vec<OutputInfo>,
    /// A PNG of the tiles that have arrived (black elsewhere).
    pub preview_url: String,
    /// The camera's photographic operator for HDR frames (the defaults of a re-tone-map).
    pub tonemap: Option<ToneParams>,
    /// Where the finished frame is re-tone-mapped (`tonemap.png`, with [`ToneQuery`]'s
    /// parameters): set once the frame has a float output (`.exr` or `.hdr`) to tone-map, `None`
    /// while it renders or when it has none.
    #[serde(default)]
    pub tonemap_url: Option<String>,
    /// Samples per pixel (the cap, under a noise target).
    #[serde(default)]
    pub samples: u32,
    /// Passes each tile is cut into (1: tiles render whole).
    #[serde(default)]
    pub passes_total: u32,
    /// Passes every tile has finished (a tile stopped by the noise target counts as finished).
    #[serde(default)]
    pub passes_done: u32,
    /// The frame after its latest finished pass (`pass.exr`, `pass.png`), once written (a moment
    /// after `passes_done` counts the pass), until the frame is merged.
    #[serde(default)]
    pub pass_outputs: Vec<OutputInfo>,
    /// The scene file this frame comes from (a path of the job's files), for a job of several
    /// scene files (a sequence); `None` for a job of one scene.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scene: Option<String>,
    /// Progress by samples: pixel-samples in the frame's film so far (each pixel's samples,
    /// summed), counted pass by pass as the server adds them; it never decreases.
    #[serde(default)]
    pub samples_done: u64,
    /// Pixel-samples the frame takes: its pixels times `samples`, less what tiles stopped by
    /// the noise target leave out; equal to `samples_done` once the frame is finished.
    #[serde(default)]
    pub samples_total: u64,
    /// `samples_total` is an upper bound (a noise target may stop tiles sooner): it can only
    /// shrink. False once the frame is finished, and without a noise target.
    #[serde(default)]
    pub samples_total_is_bound: bool,
    /// Samples per pixel reached, on average over the frame (`samples_done` / pixels, rounded
    /// down).
    #[serde(default)]
    pub spp: u32,
    /// The pass under way (from 1): one past `passes_done` while the frame renders,
    /// `passes_total` once every pass is done.
    #[serde(default)]
    pub pass: u32,
    /// The denoised picture of the frame after its latest pass (`pass_denoised.png`), for a
    /// job with `denoise`, once written; `None` otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pass_denoised_url: Option<String>,
}

/// How many of a job's frames are in each state.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct FrameCounts {
    /// Merged: their outputs are written.
    pub done: u32,
    /// Some of their work is leased or finished, not all of it merged.
    pub rendering: u32,
    /// Nothing of theirs started.
    pub queued: u32,
}

/// A job's video (see [`VideoKind`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct VideoInfo {
    /// What is made: `mp4` or `gif`.
    pub kind: VideoKind,
    pub fps: u32,
    /// `waiting` (for the last frame), `encoding`, `done` or `failed`.
    pub state: String,
    /// The video's download URL, once done.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub url: Option<String>,
    /// Why there is no video, or why it is not the kind asked for (a GIF because the server
    /// has no ffmpeg, ...).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub message: Option<String>,
}

/// Photographic operator parameters as the API shows them (`gamma`: a number or "sRGB").
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct ToneParams {
    pub key: f64,
    pub burn: f64,
    pub saturation: f64,
    pub gamma: String,
}

/// What the server pushes to the status page (`GET /api/v1/events`, server-sent events; the
/// event name is the variant, the data this JSON).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum ServerEvent {
    /// A job was submitted or changed state.
    Job { job: u64, state: JobState },
    /// A tile was accepted.
    Tile { job: u64, frame: u32, tile: u32, rect: Rect, tiles_done: u32, tiles_total: u32 },
    /// A frame's outputs were written.
    Frame { job: u64, frame: u32 },
    /// A worker registered, took a tile or finished one.
    Workers,
}

impl ServerEvent {
    pub fn name(&self) -> &'static str {
        match self {
            ServerEvent::Job { .. } => "job",
            ServerEvent::Tile { .. } => "tile",
            ServerEvent::Frame { .. } => "frame",
            ServerEvent::Workers => "workers",
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct OutputInfo {
    pub name: String,
    pub url: String,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct JobInfo {
    pub id: u64,
    pub name: String,
    pub state: JobState,
    pub priority: i64,
    pub tile_size: u32,
    pub samples: Option<u32>,
    /// Each frame is also written denoised (`<stem>_denoised.exr` and its PNG).
    #[serde(default)]
    pub denoise: bool,
    /// Unix seconds.
    pub submitted_at: f64,
    pub started_at: Option<f64>,
    pub finished_at: Option<f64>,
    /// Every frame, in order; left empty in the job list (`GET /api/v1/jobs`) for a job of more
    /// than 32 frames (`frame_counts` summarise them there).
    pub frames: Vec<FrameInfo>,
    /// Frames by state (always complete, also when `frames` is left out of a job list).
    #[serde(default)]
    pub frame_counts: FrameCounts,
    /// Scene files the job renders: 1, or the length of a sequence.
    #[serde(default)]
    pub scenes: u32,
    /// The job's video, when it makes one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub video: Option<VideoInfo>,
    /// Progress by samples over every frame (also when `frames` is left out of a job list):
    /// the sums of the frames' `samples_done` and `samples_total`; `samples_total_is_bound`
    /// when a frame's is.
    #[serde(default)]
    pub samples_done: u64,
    #[serde(default)]
    pub samples_total: u64,
    #[serde(default)]
    pub samples_total_is_bound: bool,
    pub error: Option<String>,
    /// What the scene's parser and builder warned about (unknown elements, a capped
    /// MaxRecursionDepth, ...): in the answer to a submission only.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
    pub url: String,
    /// Tags a worker must all have to render this job (none: any worker).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub worker_tags: Vec<String>,
    /// Why a job that has not ended makes no progress, as a sentence with what to do: no worker
    /// is connected, every one is draining or disabled, or none has the job's tags. Absent
    /// while a worker can take its tiles.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub waiting_for: Option<String>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct JobList {
    pub jobs: Vec<JobInfo>,
}

/// One entry of a job's event log (`GET /api/v1/jobs/ID/log`), oldest first.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct JobEvent {
    /// Position in the job's log, from 1: a client that has seen up to `seq` asks for more
    /// with `?after=seq`.
    pub seq: u64,
    /// Unix seconds.
    pub at: f64,
    /// What happened: `accepted`, `warning`, `tile_done`, `tile_failed`, `tile_retried`,
    /// `lease_expired`, `frame_merged`, `frame_tonemapped`, `frame_denoised`, `video_done` (the
    /// encoding's seconds), `video_failed` (why; the frames stay done), `job_done`, `job_failed`,
    /// `job_cancelled`, and `log_truncated`: the log is bounded (the server keeps a fixed number
    /// of events per job), this event says it is full, and only the job's end follows it.
    pub kind: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tile: Option<u32>,
    /// The worker's name, for tile events.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub worker: Option<String>,
    /// The worker's id, for tile events (the workers list has the rest of it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub worker_id: Option<u64>,
    /// Seconds the step took (a tile's render, a merge, a tone map), where it has a duration.
    /// A tile's is the worker's own measurement of its render, sent with the result
    /// ([`RENDER_SECONDS_HEADER`]; absent when the worker sent none), not the time between
    /// lease and result, which includes waiting in the worker's prefetch queue and the upload.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seconds: Option<f64>,
    /// A sentence for people: the warning's or the failure's text, or a summary.
    pub message: String,
}

/// `GET /api/v1/jobs/ID/log`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct JobLog {
    pub job: u64,
    pub events: Vec<JobEvent>,
}

// ---- Job controls after submission: requeue, priority (pause and resume take no body) ----

/// Body of `POST /api/v1/jobs/{id}/requeue` (optional; no body or `{}`: every unfinished frame
/// of a failed or cancelled job).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct RequeueRequest {
    /// Frames to render again, by their 0-based index (`frames[].index` of the job's JSON, as in
    /// its URLs): numbers and inclusive ranges separated by commas, e.g. `"0-9,12"`
    /// ([`parse_frame_list`]). Their outputs are replaced when they are done again.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames: Option<String>,
}

/// Body of `PATCH /api/v1/jobs/{id}`: the fields to change (only `priority` for now).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct JobPatch {
    /// The job's new priority (any 64-bit integer, as at submission; higher leases first).
    pub priority: i64,
}

/// Longest frame list [`parse_frame_list`] reads, in bytes.
pub const MAX_FRAME_LIST_BYTES: usize = 4096;

/// `frames` (0-based, sorted) as short ranges, the way a frame list is written back to the
/// user: `0-9, 12` (what [`parse_frame_list`] reads, with spaces).
pub fn frame_ranges(frames: &[u32]) -> String {
    let mut out: Vec<String> = Vec::new();
    let mut i = 0;
    while i < frames.len() {
        let mut j = i;
        while j + 1 < frames.len() && frames[j + 1] == frames[j] + 1 {
            j += 1;
        }
        out.push(if i == j { frames[i].to_string() } else { format!("{}-{}", frames[i], frames[j]) });
        i = j + 1;
    }
    out.join(", ")
}

/// Reads a frame list: 0-based frame indexes and inclusive ranges separated by commas
/// (`"0-9,12"`; spaces around the parts are allowed). Returns the ranges as written, not
/// expanded (a range of a billion frames costs nothing here: the server checks each against the
/// job's frames). The error says what is wrong and the syntax.
pub fn parse_frame_list(text: &str) -> Result<Vec<std::ops::RangeInclusive<u32>>, String> {
    const SYNTAX: &str = "frame indexes (0-based) and ranges separated by commas, e.g. 0-9,12";
    if text.len() > MAX_FRAME_LIST_BYTES {
        return Err(format!(
            "the frame list is longer than {MAX_FRAME_LIST_BYTES} bytes; write ranges instead: {SYNTAX}"
        ));
    }
    let number = |s: &str| -> Result<u32, String> {
        let s = s.trim();
        if s.is_empty() || !s.bytes().all(|b| b.is_ascii_digit()) {
            return Err(format!("\"{s}\" is not a frame index; write {SYNTAX}"));
        }
        s.parse::<u32>().map_err(|_| format!("frame {s} is too large; write {SYNTAX}"))
    };
    if text.trim().is_empty() {
        return Err(format!("the frame list is empty; write {SYNTAX}"));
    }
    let mut out = Vec::new();
    for part in text.split(',') {
        let range = match part.split_once('-') {
            Some((a, b)) => {
                let (a, b) = (number(a)?, number(b)?);
                if a > b {
                    return Err(format!("the range {a}-{b} runs backwards; write {b}-{a}"));
                }
                a..=b
            }
            None => {
                let n = number(part)?;
                n..=n
            }
        };
        out.push(range);
    }
    Ok(out)
}

/// Query of `GET /api/v1/jobs/ID/log`: only the events after `after` (a `seq`; default 0, the
/// whole log).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema, utoipa::IntoParams))]
#[cfg_attr(feature = "openapi", into_params(parameter_in = Query))]
pub struct LogQuery {
    pub after: Option<u64>,
}

/// Query of `GET /api/v1/jobs/ID/frames/F/tonemap.png`: any parameter left out takes the
/// camera's value (`gamma`: a number or "sRGB").
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema, utoipa::IntoParams))]
#[cfg_attr(feature = "openapi", into_params(parameter_in = Query))]
pub struct ToneQuery {
    pub key: Option<f64>,
    pub burn: Option<f64>,
    pub saturation: Option<f64>,
    pub gamma: Option<String>,
}

/// The tile a worker is rendering, as the workers list shows it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct WorkerTile {
    pub job: u64,
    pub frame: u32,
    pub tile: u32,
}

/// One registered worker in `GET /api/v1/workers`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct WorkerInfo {
    pub id: u64,
    pub name: String,
    pub threads: u32,
    /// `idle`, `rendering` or `lost` (silent for longer than three heartbeats).
    pub state: String,
    pub current_tile: Option<WorkerTile>,
    /// Unix seconds.
    pub last_heartbeat: f64,
    /// Units rendered: whole tiles, and each pass of a tile rendered in passes.
    pub tiles_done: u64,
    pub failures: u64,
    /// Whether it takes new work: `active`, `draining` (finishes what it holds, takes nothing
    /// new) or `disabled` (takes nothing; what it held went back to the queue).
    #[serde(default = "active_mode")]
    pub mode: String,
    /// The tags it declared (`tessera-worker work --tags`).
    #[serde(default)]
    pub tags: Vec<String>,
}

fn active_mode() -> String {
    "active".into()
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct WorkerList {
    pub workers: Vec<WorkerInfo>,
}

// ---------------------------------------------------------------------------------------------
// Worker tags: what a worker offers (`--tags gpu,big`) and what a job asks for (`worker_tags`)
// ---------------------------------------------------------------------------------------------

/// Most tags a worker may declare, or a job ask for.
pub const MAX_TAGS: usize = 16;
/// Longest tag, in bytes.
pub const MAX_TAG_BYTES: usize = 32;

/// Tags as the farm keeps them: each split further at commas, trimmed, lowercased, empty ones
/// dropped, duplicates once, sorted. A tag is 1 to [`MAX_TAG_BYTES`] ASCII letters, digits,
/// `-`, `_` or `.`; at most [`MAX_TAGS`] of them. The error says which tag is wrong and why
/// (the caller names the field or flag).
pub fn check_tags<S: AsRef<str>>(tags: &[S]) -> Result<Vec<String>, String> {
    let mut out: Vec<String> = Vec::new();
    for tag in tags.iter().flat_map(|t| t.as_ref().split(',')) {
        let tag = tag.trim();
        if tag.is_empty() {
            continue;
        }
        if tag.len() > MAX_TAG_BYTES {
            let shown: String = tag.chars().take(40).collect();
            return Err(format!("the tag \"{shown}\" is longer than {MAX_TAG_BYTES} bytes"));
        }
        if let Some(c) = tag.chars().find(|c| !(c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))) {
            return Err(format!(
                "the tag \"{}\" holds {c:?}: a tag is made of letters, digits, '-', '_' and '.' (separate tags with commas)",
                tag.escape_debug()
            ));
        }
        let tag = tag.to_ascii_lowercase();
        if !out.contains(&tag) {
            out.push(tag);
        }
        if out.len() > MAX_TAGS {
            return Err(format!("more than {MAX_TAGS} tags; give at most {MAX_TAGS}"));
        }
    }
    out.sort();
    Ok(out)
}

/// A tile's pixels on the wire: width·height RGB triples of little-endian `f32`, row-major.
pub fn encode_tile(px: &[[f32; 3]]) -> Vec<u8> {
    let mut out = Vec::with_capacity(px.len() * 12);
    for p in px {
        for c in p {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    out
}

/// The size of a tile of `pixels` pixels on the wire: its colour, and with `aux` its albedo and
/// normal after it ([`encode_tile_with_aux`]).
pub fn tile_bytes(pixels: usize, aux: bool) -> usize {
    pixels * 12 * if aux { 3 } else { 1 }
}

/// A tile with its denoising features on the wire: the colour as [`encode_tile`] writes it,
/// then the albedo, then the normal, each the same way (three planes of RGB triples).
pub fn encode_tile_with_aux(px: &[[f32; 3]], albedo: &[[f32; 3]], normal: &[[f32; 3]]) -> Vec<u8> {
    let mut out = encode_tile(px);
    out.extend_from_slice(&encode_tile(albedo));
    out.extend_from_slice(&encode_tile(normal));
    out
}

/// A tile's colour plane and, when present, its albedo and normal planes.
pub type TilePlanes<'a> = (&'a [u8], Option<(&'a [u8], &'a [u8])>);

/// A tile's planes as stored (colour, then albedo and normal when the job is denoised): the
/// colour's bytes and, when present, the features', split at `pixels` pixels each. `None` unless
/// the bytes hold one or three whole planes.
pub fn tile_planes(bytes: &[u8], pixels: usize) -> Option<TilePlanes<'_>> {
    let plane = pixels.checked_mul(12)?;
    if bytes.len() == plane {
        Some((bytes, None))
    } else if Some(bytes.len()) == plane.checked_mul(3) {
        let (colour, rest) = bytes.split_at(plane);
        Some((colour, Some(rest.split_at(plane))))
    } else {
        None
    }
}

/// The inverse of [`encode_tile`]; `None` unless `bytes` holds exactly `pixels` pixels.
pub fn decode_tile(bytes: &[u8], pixels: usize) -> Option<Vec<[f32; 3]>> {
    if bytes.len() != pixels.checked_mul(12)? {
        return None;
    }
    Some(
        bytes
            .chunks_exact(12)
            .map(|b| {
                let f = |i: usize| f32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
                [f(0), f(4), f(8)]
            })
            .collect(),
    )
}

/// Checks a tile's pixels as the server takes them: every value a finite number. The tracer
/// never writes NaN or an infinity (it writes 0 for a NaN and the largest `f32` for an
/// overflow); negative values are legal (a scene may have lights of negative power, and the
/// CLI writes what the tracer computes). Returns the first bad value's pixel and channel.
pub fn check_tile_values(px: &[[f32; 3]]) -> Result<(), (usize, usize, f32)> {
    for (i, p) in px.iter().enumerate() {
        for (c, v) in p.iter().enumerate() {
            if !v.is_finite() {
                return Err((i, c, *v));
            }
        }
    }
    Ok(())
}

/// CRC-32 (IEEE 802.3, as zlib and PNG compute it) of `bytes` as 8 hex digits: detects a tile
/// damaged on the way. The table-free SIMD code of `crc32fast` runs at memory speed, which
/// matters for a whole 800x800 frame (7.7 MB) a second on both ends of the upload.
pub fn checksum(bytes: &[u8]) -> String {
    format!("{:08x}", crc32fast::hash(bytes))
}

// ---- The server's address as a user gives it (client and worker `--server`) ----

/// What a client or worker is told about `https://`: a Tessera server speaks plain HTTP.
pub const HTTPS_HINT: &str = "tessera-server itself serves plain HTTP: give http://HOST:PORT, or use https:// \
     only for a reverse proxy (nginx, Caddy, ...) that terminates TLS in front of it";

/// The farm's base URL from what a user gave (`--server`): `http://` added when there is no
/// scheme; a query, a `#` fragment, trailing `/`, and the API's path (`/api/v1` and what follows,
/// as copied from the OpenAPI description or a request) left out. With the base, a note when
/// more than a scheme or slashes was changed (to print, so that the user can fix the setting).
///
/// # Errors
///
/// A scheme other than `http` and `https`, or no host, with what to give instead.
pub fn server_base_url(given: &str) -> Result<(String, Option<String>), String> {
    let trimmed = given.trim();
    let with_scheme = if trimmed.contains("://") { trimmed.to_string() } else { format!("http://{trimmed}") };
    let (scheme, rest) = with_scheme.split_once("://").unwrap_or(("http", &with_scheme));
    let scheme = scheme.to_ascii_lowercase();
    if scheme != "http" && scheme != "https" {
        return Err(format!(
            "{trimmed:?} is not an http:// address; give the farm's address, e.g. http://farm.example:8080"
        ));
    }
    let rest = rest.split(['#', '?']).next().unwrap_or("");
    let (host, path) = rest.split_once('/').map_or((rest, ""), |(h, p)| (h, p));
    if host.is_empty() {
        return Err(format!(
            "{trimmed:?} names no host; give the farm's address, e.g. http://farm.example:8080"
        ));
    }
    let path = path.trim_end_matches('/');
    // `/api/v1...` anywhere in the path: what comes before it is the farm (a proxy may serve it
    // under a prefix).
    let (path, api) = match path.find("api/v1").filter(|&k| k == 0 || path[..k].ends_with('/')) {
        Some(k) if path[k + 6..].is_empty() || path[k + 6..].starts_with('/') => {
            (path[..k].trim_end_matches('/'), true)
        }
        _ => (path, false),
    };
    let base =
        if path.is_empty() { format!("{scheme}://{host}") } else { format!("{scheme}://{host}/{path}") };
    let changed = api || rest.len() != trimmed.split_once("://").map_or(trimmed, |(_, r)| r).len();
    let note = changed.then(|| {
        format!(
            "note: using the server {base} (from {trimmed:?}): --server takes the farm's address, the API's path /api/v1 is added by itself"
        )
    });
    Ok((base, note))
}

#[cfg(test)]
mod tests {

    #[test]
    fn workers_and_servers_of_other_protocols_refuse_each_other() {
        assert_eq!(protocol_mismatch(WORKER_PROTOCOL, WORKER_PROTOCOL), None);
        let older_server = protocol_mismatch(WORKER_PROTOCOL, 0).unwrap();
        assert!(
            older_server.contains("the server an older one") && older_server.contains("same Tessera version")
        );
        assert!(protocol_mismatch(WORKER_PROTOCOL + 1, WORKER_PROTOCOL).is_some());
    }

    use super::*;

    #[test]
    fn tiles_round_trip_bit_exact() {
        let px = vec![[1.0, -2.5, f32::INFINITY], [f32::MIN_POSITIVE, 0.0, 1e30]];
        let bytes = encode_tile(&px);
        assert_eq!(bytes.len(), 24);
        assert_eq!(decode_tile(&bytes, 2).unwrap(), px);
        assert_eq!(decode_tile(&bytes, 3), None);
        assert_eq!(decode_tile(&bytes[..23], 2), None);
        // NaN bits survive too.
        let nan = encode_tile(&[[f32::NAN; 3]]);
        assert!(decode_tile(&nan, 1).unwrap()[0][0].is_nan());
    }

    #[test]
    fn a_tile_with_features_splits_into_its_three_planes() {
        let (c, a, n) = ([[1.0, 2.0, 3.0]; 2], [[0.5; 3]; 2], [[0.0, 0.0, 1.0]; 2]);
        let bytes = encode_tile_with_aux(&c, &a, &n);
        assert_eq!(bytes.len(), tile_bytes(2, true));
        let (colour, aux) = tile_planes(&bytes, 2).unwrap();
        let (albedo, normal) = aux.unwrap();
        assert_eq!(decode_tile(colour, 2).unwrap(), c);
        assert_eq!(decode_tile(albedo, 2).unwrap(), a);
        assert_eq!(decode_tile(normal, 2).unwrap(), n);
        let plain = encode_tile(&c);
        assert_eq!(plain.len(), tile_bytes(2, false));
        assert_eq!(tile_planes(&plain, 2), Some((&plain[..], None)));
        assert_eq!(tile_planes(&bytes[..48], 2), None, "two planes are neither");
    }

    #[test]
    fn long_messages_are_cut_on_a_character_boundary() {
        assert_eq!(truncate_message("short", 4096), "short");
        let long = "é".repeat(10_000); // 20 000 bytes
        let cut = truncate_message(&long, 4096);
        assert!(cut.len() <= 4096, "{}", cut.len());
        assert!(cut.starts_with("éé") && cut.ends_with("more bytes cut)"), "{cut}");
        let kept = cut.split("...").next().unwrap().len();
        assert!(cut.contains(&format!("({} more bytes cut)", 20_000 - kept)), "{cut}");
    }

    #[test]
    fn tile_values_must_be_finite_and_may_be_negative() {
        assert_eq!(check_tile_values(&[[0.0, -1.0, 1e38], [f32::MAX, f32::MIN, 0.5]]), Ok(()));
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            let got = check_tile_values(&[[0.0; 3], [0.0, 0.0, bad]]).unwrap_err();
            assert_eq!((got.0, got.1), (1, 2));
        }
    }

    #[test]
    fn tags_are_checked_lowercased_sorted_and_once() {
        assert_eq!(check_tags(&["GPU, big", "gpu", ""]).unwrap(), ["big", "gpu"]);
        assert_eq!(check_tags::<&str>(&[]).unwrap(), Vec::<String>::new());
        assert_eq!(check_tags(&["cuda-12.1_x"]).unwrap(), ["cuda-12.1_x"]);
        let e = check_tags(&["gp u"]).unwrap_err();
        assert!(e.contains("\"gp u\" holds ' '"), "{e}");
        let e = check_tags(&["a".repeat(33)]).unwrap_err();
        assert!(e.contains("longer than 32 bytes"), "{e}");
        let many: Vec<String> = (0..17).map(|k| format!("t{k}")).collect();
        assert!(check_tags(&many).unwrap_err().contains("more than 16 tags"));
        assert!(check_tags(&["t\u{7}"]).unwrap_err().contains("holds '\\u{7}'"));
    }

    #[test]
    fn checksum_is_crc32() {
        // The CRC-32 check value, and zlib's answers.
        assert_eq!(checksum(b"123456789"), "cbf43926");
        assert_eq!(checksum(b""), "00000000");
        assert_eq!(checksum(b"a"), "e8b7be43");
        assert_ne!(checksum(b"ab"), checksum(b"ba"));
    }

    #[test]
    fn frame_lists_print_as_ranges() {
        assert_eq!(frame_ranges(&[0, 1, 2, 5, 7, 8]), "0-2, 5, 7-8");
        assert_eq!(frame_ranges(&[3]), "3");
        assert_eq!(frame_ranges(&[]), "");
    }

    #[test]
    fn frame_lists_read_numbers_and_ranges_and_refuse_the_rest() {
        assert_eq!(parse_frame_list("0-9,12").unwrap(), vec![0..=9, 12..=12]);
        assert_eq!(parse_frame_list(" 3 , 5 - 6").unwrap(), vec![3..=3, 5..=6]);
        assert_eq!(parse_frame_list("0-4294967295").unwrap(), vec![0..=u32::MAX]);
        for bad in ["", "a", "1,,2", "-1", "1-", "9-2", "1.5", "99999999999", "1-2-3"] {
            let e = parse_frame_list(bad).unwrap_err();
            assert!(e.contains("0-9,12") || e.contains("9-2") || e.contains("2-9"), "{bad}: {e}");
        }
        assert!(parse_frame_list(&"1,".repeat(3000)).unwrap_err().contains("longer than"));
    }

    #[test]
    fn job_states_round_trip() {
        for s in [
            JobState::Queued,
            JobState::Running,
            JobState::Paused,
            JobState::Done,
            JobState::Failed,
            JobState::Canceled,
        ] {
            assert_eq!(JobState::parse(s.as_str()), Some(s));
            assert_eq!(serde_json::to_string(&s).unwrap(), format!("\"{}\"", s.as_str()));
        }
    }

    #[test]
    fn a_pasted_api_url_gives_the_farm_address() {
        let base = |s: &str| server_base_url(s).map(|(b, n)| (b, n.is_some()));
        assert_eq!(base("farm:8080"), Ok(("http://farm:8080".into(), false)));
        assert_eq!(base("http://farm:8080/"), Ok(("http://farm:8080".into(), false)));
        assert_eq!(base("https://farm.example"), Ok(("https://farm.example".into(), false)));
        assert_eq!(base("http://farm:8080/api/v1"), Ok(("http://farm:8080".into(), true)));
        assert_eq!(base("http://farm:8080/api/v1/jobs/3"), Ok(("http://farm:8080".into(), true)));
        assert_eq!(base("http://proxy/tessera/api/v1/"), Ok(("http://proxy/tessera".into(), true)));
        assert_eq!(base("http://proxy/tessera"), Ok(("http://proxy/tessera".into(), false)));
        assert_eq!(base("http://farm:8080/#/jobs/3"), Ok(("http://farm:8080".into(), true)));
        assert_eq!(base("http://farm/myapi/v1"), Ok(("http://farm/myapi/v1".into(), false)));
        assert!(server_base_url("ftp://farm").unwrap_err().contains("not an http:// address"));
        assert!(server_base_url("http:///api/v1").unwrap_err().contains("names no host"));
    }
}
