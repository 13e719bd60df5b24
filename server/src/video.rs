//! A job's video: once its last frame is merged, its frames' pictures (each frame's first PNG
//! output, in frame order) become one video in the server's folder of the job,
//! `frames/JOB/video.mp4` or `frames/JOB/video.gif`, served at `/api/v1/jobs/ID/video.mp4`
//! (`.gif`).
//!
//! - MP4 (H.264, yuv420p, `+faststart`) is made by the `ffmpeg` program, found as
//!   `$TESSERA_FFMPEG` or on `PATH` when it is needed (Debian's `ffmpeg` package); the frames are
//!   piped to it as raw RGB, odd sizes padded to even, its stderr kept for the failure's message,
//!   and it is stopped past a time limit ([`time_limit`]).
//! - GIF is made here with the `image` crate (looping, one delay per frame from `fps`).
//!
//! What a job makes ([`plan`]): what it asked for (`video`, `fps`), else an MP4 for a job of
//! several scene files (a sequence) and none otherwise; a GIF instead of the default MP4 when the
//! server has no ffmpeg (the job's `video.message` says so). Frames of different sizes make no
//! video ([`first_size_mismatch`]). The file is written under a temporary name and renamed, so
//! it is whole or absent; what became of it is in the store (`db/video.rs`) with a `video_done`
//! or `video_failed` event in the job's log. The frames stay done whatever happens to the video.
//! A server stopped while a video was due makes it when it starts again ([`resume`]).

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use tessera::protocol::{JobState, ServerEvent, VideoInfo, VideoKind};

use crate::db::{FrameRow, JobRow};
use crate::state::AppState;

/// Frames a second when a job gives none (the course's videos are at 30).
pub const DEFAULT_FPS: u32 = 30;

/// The environment variable that names the `ffmpeg` program (else it is looked up on `PATH`).
pub const FFMPEG_ENV: &str = "TESSERA_FFMPEG";

/// How hard the GIF encoder works on each frame's palette (1: best, 30: fastest; see the `gif`
/// crate's `Frame::from_rgba_speed`).
const GIF_SPEED: i32 = 10;

/// Bytes of ffmpeg's stderr kept for a failure's message (its end).
const STDERR_TAIL: usize = 2048;

/// Where job `job`'s video of `kind` is kept: `frames/JOB/video.mp4` (or `.gif`).
pub fn video_path(data_dir: &Path, job: u64, kind: VideoKind) -> PathBuf {
    data_dir.join(crate::storage::FRAMES_DIR).join(job.to_string()).join(file_name(kind))
}

/// `video.mp4` or `video.gif`.
pub fn file_name(kind: VideoKind) -> String {
    format!("video.{}", kind.as_str())
}

/// The `ffmpeg` program: `$TESSERA_FFMPEG` when set, else `ffmpeg` on `PATH`; the error says
/// how to get one (it names no path of the server).
pub fn find_ffmpeg() -> Result<PathBuf, String> {
    let executable = |p: &Path| {
        use std::os::unix::fs::PermissionsExt;
        std::fs::metadata(p).is_ok_and(|m| m.is_file() && m.permissions().mode() & 0o111 != 0)
    };
    if let Some(set) = std::env::var_os(FFMPEG_ENV).filter(|v| !v.is_empty()) {
        let p = PathBuf::from(set);
        return if executable(&p) {
            Ok(p)
        } else {
            Err(format!(
                "this server's {FFMPEG_ENV} does not name an executable ffmpeg program; an operator can install \
                 Debian's ffmpeg package (apt-get install ffmpeg) and set {FFMPEG_ENV} to it or unset it"
            ))
        };
    }
    let path = std::env::var_os("PATH").unwrap_or_default();
    std::env::split_paths(&path).map(|d| d.join("ffmpeg")).find(|p| executable(p)).ok_or_else(|| {
        format!(
            "this server has no ffmpeg program (none on its PATH, and {FFMPEG_ENV} is not set); an operator can \
             install Debian's ffmpeg package (apt-get install ffmpeg) or set {FFMPEG_ENV}"
        )
    })
}

/// [`find_ffmpeg`], looked up again at most every few seconds (job views ask for it).
fn ffmpeg_cached() -> Result<PathBuf, String> {
    type Found = Option<(Instant, Result<PathBuf, String>)>;
    static FOUND: Mutex<Found> = Mutex::new(None);
    let mut found = FOUND.lock().unwrap_or_else(|e| e.into_inner());
    match &*found {
        Some((at, r)) if at.elapsed() < Duration::from_secs(5) => r.clone(),
        _ => {
            let r = find_ffmpeg();
            *found = Some((Instant::now(), r.clone()));
            r
        }
    }
}

/// What a job's frames become.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    pub kind: VideoKind,
    pub fps: u32,
    /// Why it is not the kind the job would have had (a GIF: the server has no ffmpeg).
    pub message: Option<String>,
}

/// The video a job makes: `asked` (`None`: the default, an MP4 for a job of more than one scene
/// file, none otherwise) at `fps` (default [`DEFAULT_FPS`]); `Ok(None)` for no video. An MP4
/// needs ffmpeg (`ffmpeg`): asked for and missing, the error says so; by default and missing, a
/// GIF instead with a message saying why.
pub fn plan(
    asked: Option<VideoKind>,
    fps: Option<u32>,
    scenes: u32,
    ffmpeg: impl FnOnce() -> Result<PathBuf, String>,
) -> Result<Option<Plan>, String> {
    let fps = fps.unwrap_or(DEFAULT_FPS);
    let plan = |kind, message| Ok(Some(Plan { kind, fps, message }));
    match asked {
        Some(VideoKind::None) => Ok(None),
        Some(VideoKind::Gif) => plan(VideoKind::Gif, None),
        Some(VideoKind::Mp4) => match ffmpeg() {
            Ok(_) => plan(VideoKind::Mp4, None),
            Err(e) => {
                Err(format!("video=mp4: {e}; or submit with video=gif (made without ffmpeg) or video=none"))
            }
        },
        None if scenes > 1 => match ffmpeg() {
            Ok(_) => plan(VideoKind::Mp4, None),
            Err(e) => plan(VideoKind::Gif, Some(format!("a GIF instead of an MP4: {e}"))),
        },
        None => Ok(None),
    }
}

/// The first frame whose size differs from frame 0's, as a sentence naming both (with their
/// scene files when `scenes` has them), or `None` when every frame has one size.
pub fn first_size_mismatch(sizes: &[(u32, u32, u32)], scenes: &[String]) -> Option<String> {
    let (i0, w0, h0) = *sizes.first()?;
    let (i, w, h) = *sizes.iter().find(|&&(_, w, h)| (w, h) != (w0, h0))?;
    let name = |k: u32| match scenes.get(k as usize) {
        Some(s) if scenes.iter().any(|o| o != s) => format!("frame {k} ({s})"),
        _ => format!("frame {k}"),
    };
    Some(format!("{} is {w}x{h} while {} is {w0}x{h0}: a video needs frames of one size", name(i), name(i0)))
}

/// The check of a submission that asks for a video (`asked`): an MP4 needs ffmpeg, and any
/// video frames of one size (`sizes`: index, width, height; `scenes`: each frame's scene file,
/// or empty). The error is the 422's message.
pub fn check_submission(
    asked: Option<VideoKind>,
    sizes: &[(u32, u32, u32)],
    scenes: &[String],
) -> Result<(), String> {
    let Some(kind @ (VideoKind::Mp4 | VideoKind::Gif)) = asked else { return Ok(()) };
    plan(asked, None, 1, find_ffmpeg)?;
    match first_size_mismatch(sizes, scenes) {
        None => Ok(()),
        Some(m) => {
            Err(format!("video={}: {m}; render frames of one size, or submit with video=none", kind.as_str()))
        }
    }
}

/// The longest an encoding may take: two minutes, plus a second per frame and megapixel.
pub fn time_limit(frames: usize, width: u32, height: u32) -> Duration {
    let megapixels = f64::from(width) * f64::from(height) / 1e6;
    Duration::from_secs_f64(120.0 + frames as f64 * megapixels.max(0.01))
}

/// What [`encode`] made.
#[derive(Debug)]
pub struct Encoded {
    pub frames: usize,
    pub width: u32,
    pub height: u32,
    pub bytes: u64,
}

/// Makes `out` (written under a temporary name and renamed: whole or absent) of `kind` at `fps`
/// from the pictures `pngs`, in order; `ffmpeg` for an MP4.
pub fn encode(
    kind: VideoKind,
    pngs: &[PathBuf],
    fps: u32,
    out: &Path,
    ffmpeg: Option<&Path>,
) -> Result<Encoded> {
    let first = pngs.first().ok_or_else(|| anyhow!("the job has no frame"))?;
    let (width, height) = image::image_dimensions(first)
        .with_context(|| format!("cannot read frame 0's picture {}", first.display()))?;
    let temp = tessera::atomic_write::unique_temp_name(out);
    let made = match kind {
        VideoKind::Mp4 => {
            let ffmpeg = ffmpeg.ok_or_else(|| anyhow!("no ffmpeg"))?;
            encode_mp4(ffmpeg, pngs, (width, height), fps, &temp, time_limit(pngs.len(), width, height))
        }
        VideoKind::Gif => encode_gif(pngs, (width, height), fps, &temp),
        VideoKind::None => Err(anyhow!("no video asked for")),
    }
    .and_then(|()| {
        std::fs::File::open(&temp)
            .and_then(|f| f.sync_all())
            .with_context(|| format!("cannot sync {}", temp.display()))?;
        std::fs::rename(&temp, out).with_context(|| format!("cannot move {} into place", out.display()))
    });
    if let Err(e) = made {
        let _ = std::fs::remove_file(&temp);
        return Err(e);
    }
    let bytes = std::fs::metadata(out)?.len();
    Ok(Encoded { frames: pngs.len(), width, height, bytes })
}

/// A frame's picture as 8-bit RGB of `size`, or an error naming the frame.
fn rgb_frame(k: usize, png: &Path, size: (u32, u32)) -> Result<image::RgbImage> {
    let img = image::ImageReader::open(png)
        .and_then(|r| r.with_guessed_format())
        .map_err(anyhow::Error::new)
        .and_then(|r| r.decode().map_err(anyhow::Error::new))
        .with_context(|| format!("cannot read frame {k}'s picture {}", png.display()))?;
    if (img.width(), img.height()) != size {
        bail!(
            "frame {k} is {}x{} while frame 0 is {}x{}: a video needs frames of one size",
            img.width(),
            img.height(),
            size.0,
            size.1
        );
    }
    Ok(img.into_rgb8())
}

fn encode_mp4(
    ffmpeg: &Path,
    pngs: &[PathBuf],
    size: (u32, u32),
    fps: u32,
    out: &Path,
    limit: Duration,
) -> Result<()> {
    let mut child = Command::new(ffmpeg)
        .args(["-hide_banner", "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24"])
        .args(["-s", &format!("{}x{}", size.0, size.1), "-framerate", &fps.to_string(), "-i", "pipe:0"])
        .args(["-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-c:v", "libx264", "-preset", "medium", "-crf", "18"])
        .args(["-pix_fmt", "yuv420p", "-r", &fps.to_string(), "-movflags", "+faststart", "-f", "mp4"])
        .arg(out)
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| anyhow!("cannot start ffmpeg: {e}"))?;
    let mut stderr = child.stderr.take().expect("piped");
    let tail = std::thread::spawn(move || {
        let mut all = Vec::new();
        let mut buf = [0u8; 4096];
        while let Ok(n) = stderr.read(&mut buf) {
            if n == 0 {
                break;
            }
            all.extend_from_slice(&buf[..n]);
            if all.len() > 4 * STDERR_TAIL {
                all.drain(..all.len() - STDERR_TAIL);
            }
        }
        String::from_utf8_lossy(&all[all.len().saturating_sub(STDERR_TAIL)..]).trim().to_string()
    });
    let mut stdin = child.stdin.take().expect("piped");
    let frames = pngs.to_vec();
    let writer = std::thread::spawn(move || -> Result<()> {
        for (k, png) in frames.iter().enumerate() {
            let rgb = rgb_frame(k, png, size)?;
            if stdin.write_all(rgb.as_raw()).is_err() {
                // ffmpeg stopped reading: its status and stderr say why.
                return Ok(());
            }
        }
        Ok(())
    });
    let deadline = Instant::now() + limit;
    // A frame that cannot be read ends the writer, which closes ffmpeg's input: ffmpeg then
    // finishes, and the writer's error is the answer.
    let status = loop {
        if let Some(status) = child.try_wait()? {
            break status;
        }
        if Instant::now() >= deadline {
            let _ = child.kill();
            let _ = child.wait();
            bail!("ffmpeg took longer than {:.0} s and was stopped", limit.as_secs_f64());
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let written = writer.join().map_err(|_| anyhow!("the frame writer panicked"))?;
    let stderr = tail.join().unwrap_or_default();
    written?;
    if !status.success() {
        let said =
            if stderr.is_empty() { "it said nothing".to_string() } else { format!("it said: {stderr}") };
        bail!("ffmpeg failed ({status}); {said}");
    }
    Ok(())
}

/// Writes into `inner`, keeping the first error (the GIF encoder's last writes happen when it
/// is dropped, where errors are otherwise lost).
struct Checked<W: Write> {
    inner: W,
    error: Arc<Mutex<Option<std::io::Error>>>,
}

impl<W: Write> Write for Checked<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.inner.write(buf).inspect_err(|e| self.keep(e))
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush().inspect_err(|e| self.keep(e))
    }
}

impl<W: Write> Checked<W> {
    fn keep(&self, e: &std::io::Error) {
        let mut slot = self.error.lock().unwrap_or_else(|p| p.into_inner());
        if slot.is_none() {
            *slot = Some(std::io::Error::new(e.kind(), e.to_string()));
        }
    }
}

fn encode_gif(pngs: &[PathBuf], size: (u32, u32), fps: u32, out: &Path) -> Result<()> {
    use image::codecs::gif::{GifEncoder, Repeat};
    if size.0 > u32::from(u16::MAX) || size.1 > u32::from(u16::MAX) {
        bail!("a GIF is at most 65535 pixels a side; the frames are {}x{}", size.0, size.1);
    }
    let file = std::fs::File::create(out).with_context(|| format!("cannot create {}", out.display()))?;
    let error = Arc::new(Mutex::new(None));
    let checked = Checked { inner: &file, error: error.clone() };
    {
        let mut gif =
            GifEncoder::new_with_speed(std::io::BufWriter::with_capacity(1 << 20, checked), GIF_SPEED);
        gif.set_repeat(Repeat::Infinite)?;
        for (k, png) in pngs.iter().enumerate() {
            let rgba = image::DynamicImage::ImageRgb8(rgb_frame(k, png, size)?).into_rgba8();
            let delay = image::Delay::from_numer_denom_ms(1000, fps);
            gif.encode_frame(image::Frame::from_parts(rgba, 0, 0, delay))
                .with_context(|| format!("cannot encode frame {k} into the GIF"))?;
        }
    }
    if let Some(e) = error.lock().unwrap_or_else(|p| p.into_inner()).take() {
        return Err(anyhow::Error::new(e).context(format!("cannot write {}", out.display())));
    }
    Ok(())
}

/// Each frame's picture, the first PNG among its outputs, in frame order; an error names the
/// first frame that has none.
fn frame_pictures(state: &AppState, job: u64, frames: &[FrameRow]) -> Result<Vec<PathBuf>> {
    frames
        .iter()
        .map(|f| {
            let outputs = f.outputs.as_deref().ok_or_else(|| anyhow!("frame {} is not merged", f.index))?;
            let png = outputs
                .iter()
                .find(|o| o.to_ascii_lowercase().ends_with(".png"))
                .ok_or_else(|| anyhow!("frame {} has no PNG output to make a video of", f.index))?;
            Ok(state.frame_dir(job, f.index).join(png))
        })
        .collect()
}

/// The plan of job `job` as it stands (its options, its scene files, ffmpeg looked up now).
fn job_plan(state: &AppState, job: u64) -> Result<Result<Option<Plan>, String>> {
    let (asked, fps) = state.store.video_options(job)?;
    let scenes = if asked.is_none() { state.store.scene_count(job)? } else { 1 };
    Ok(plan(asked, fps, scenes, ffmpeg_cached))
}

/// Makes job `job`'s video if it is done and makes one that is not made yet: off the async
/// runtime, one video at a time. Logs `video_done` or `video_failed`; the frames stay done.
pub async fn make_video(state: AppState, job: u64) {
    {
        let mut busy = state.videos.busy.lock().unwrap_or_else(|e| e.into_inner());
        if !busy.insert(job) {
            return;
        }
    }
    let permit = state.videos.gate.clone().acquire_owned().await;
    let st = state.clone();
    let made = tokio::task::spawn_blocking(move || make_video_now(&st, job)).await;
    drop(permit);
    state.videos.busy.lock().unwrap_or_else(|e| e.into_inner()).remove(&job);
    match made {
        Ok(Ok(true)) => state.emit(ServerEvent::Job { job, state: JobState::Done }),
        Ok(Ok(false)) => {}
        Ok(Err(e)) => tracing::error!(job, "recording the video failed: {e:#}"),
        Err(e) => tracing::error!(job, "video task panicked: {e}"),
    }
}

/// [`make_video`]'s work; `Ok(true)` when a video was made or failed (the job changed).
fn make_video_now(state: &AppState, job: u64) -> Result<bool> {
    let Some(row) = state.store.job(job)? else { return Ok(false) };
    if row.state != JobState::Done {
        return Ok(false);
    }
    if let Some(v) = state.store.video(job)?
        && v.state != "encoding"
    {
        return Ok(false);
    }
    let (kind, fps, message) = match job_plan(state, job)? {
        Ok(None) => return Ok(false),
        Ok(Some(p)) => (p.kind, p.fps, p.message),
        Err(refusal) => {
            let (_, fps) = state.store.video_options(job)?;
            state.store.video_encoding(job, VideoKind::Mp4, fps.unwrap_or(DEFAULT_FPS), None)?;
            state.store.video_failed(job, None, &refusal)?;
            return Ok(true);
        }
    };
    state.store.video_encoding(job, kind, fps, message.as_deref())?;
    state.emit(ServerEvent::Job { job, state: JobState::Done });
    let started = Instant::now();
    let out = video_path(&state.settings.data_dir, job, kind);
    let result = (|| -> Result<Encoded> {
        let frames = state.store.frames(job)?;
        let sizes: Vec<(u32, u32, u32)> = frames.iter().map(|f| (f.index, f.width, f.height)).collect();
        if let Some(m) = first_size_mismatch(&sizes, &state.store.frame_scenes(job)?) {
            bail!("{m}");
        }
        let pngs = frame_pictures(state, job, &frames)?;
        let ffmpeg = match kind {
            VideoKind::Mp4 => Some(find_ffmpeg().map_err(|e| anyhow!("{e}"))?),
            _ => None,
        };
        let dir = out.parent().expect("frames/JOB");
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        encode(kind, &pngs, fps, &out, ffmpeg.as_deref())
    })();
    let seconds = started.elapsed().as_secs_f64();
    match result {
        Ok(e) => {
            let what = format!(
                "{} written: {} frames of {}x{} at {fps} fps, {} bytes",
                file_name(kind),
                e.frames,
                e.width,
                e.height,
                e.bytes
            );
            tracing::info!(job, seconds, "{what}");
            state.store.video_done(job, seconds, e.bytes, &what)?;
        }
        Err(e) => {
            tracing::warn!(job, "the video failed: {e:#}");
            let message = crate::storage::without_paths(
                &format!("no {}: {e:#}; the frames are done", file_name(kind)),
                &state.settings.data_dir,
            );
            state.store.video_failed(job, Some(seconds), &message)?;
        }
    }
    Ok(true)
}

/// At start: removes the temporary files of encodings a stop cut off (in `frames/JOB/`), and
/// makes the videos that were due.
pub fn resume(state: &AppState) -> Result<()> {
    if let Ok(jobs) = std::fs::read_dir(state.settings.data_dir.join(crate::storage::FRAMES_DIR)) {
        for dir in jobs.flatten() {
            let Ok(files) = std::fs::read_dir(dir.path()) else { continue };
            for f in files.flatten() {
                let name = f.file_name();
                let name = name.to_string_lossy();
                if name.starts_with(".video.") && crate::storage::is_temp_name(&name) {
                    let _ = std::fs::remove_file(f.path());
                }
            }
        }
    }
    for job in state.store.videos_due()? {
        tokio::spawn(make_video(state.clone(), job));
    }
    Ok(())
}

/// The job's video as its JSON shows it: what became of it once encoding started, else what it
/// will make (`waiting` while frames render, `encoding` once they are all merged); `None` when
/// it makes none (or ended without finishing its frames).
pub fn info(state: &AppState, job: &JobRow, frames: &[FrameRow]) -> Result<Option<VideoInfo>> {
    let url = |kind| format!("/api/v1/jobs/{}/{}", job.id, file_name(kind));
    if let Some(v) = state.store.video(job.id)? {
        return Ok(Some(VideoInfo {
            kind: v.kind,
            fps: v.fps,
            url: (v.state == "done").then(|| url(v.kind)),
            state: v.state,
            message: v.message,
        }));
    }
    if matches!(job.state, JobState::Failed | JobState::Canceled) {
        return Ok(None);
    }
    let plan = match job_plan(state, job.id)? {
        Ok(None) => return Ok(None),
        Ok(Some(p)) => p,
        Err(refusal) => {
            let (_, fps) = state.store.video_options(job.id)?;
            Plan { kind: VideoKind::Mp4, fps: fps.unwrap_or(DEFAULT_FPS), message: Some(refusal) }
        }
    };
    let sizes: Vec<(u32, u32, u32)> = frames.iter().map(|f| (f.index, f.width, f.height)).collect();
    let mismatch = first_size_mismatch(&sizes, &[])
        .map(|_| first_size_mismatch(&sizes, &state.store.frame_scenes(job.id).unwrap_or_default()))
        .unwrap_or_default();
    let message = match mismatch {
        Some(m) => Some(format!("no video will be made: {m}")),
        None => plan.message,
    };
    let state = if job.state == JobState::Done { "encoding" } else { "waiting" };
    Ok(Some(VideoInfo { kind: plan.kind, fps: plan.fps, state: state.into(), url: None, message }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_plan_follows_the_request_the_scenes_and_ffmpeg() {
        let have = || Ok(PathBuf::from("/usr/bin/ffmpeg"));
        let lack = || Err("no ffmpeg here".to_string());
        let p = |kind, message: Option<&str>| {
            Ok(Some(Plan { kind, fps: DEFAULT_FPS, message: message.map(str::to_string) }))
        };
        assert_eq!(plan(None, None, 1, have), Ok(None), "one scene: no video by default");
        assert_eq!(plan(None, None, 2, have), p(VideoKind::Mp4, None));
        let gif = plan(None, None, 360, lack).unwrap().unwrap();
        assert_eq!(gif.kind, VideoKind::Gif);
        assert!(gif.message.unwrap().contains("no ffmpeg here"));
        assert_eq!(plan(Some(VideoKind::Gif), Some(12), 1, lack).unwrap().unwrap().fps, 12);
        assert_eq!(plan(Some(VideoKind::None), None, 5, have), Ok(None));
        let refused = plan(Some(VideoKind::Mp4), None, 1, lack).unwrap_err();
        assert!(refused.contains("video=mp4") && refused.contains("video=gif"), "{refused}");
    }

    #[test]
    fn the_first_frame_of_another_size_is_named() {
        assert_eq!(first_size_mismatch(&[], &[]), None);
        assert_eq!(first_size_mismatch(&[(0, 4, 4), (1, 4, 4)], &[]), None);
        let m = first_size_mismatch(&[(0, 4, 4), (1, 4, 4), (2, 8, 4), (3, 2, 2)], &[]).unwrap();
        assert!(m.starts_with("frame 2 is 8x4 while frame 0 is 4x4"), "{m}");
        let scenes: Vec<String> = ["a/0.json", "a/1.json", "a/2.json"].map(String::from).into();
        let m = first_size_mismatch(&[(0, 4, 4), (1, 4, 4), (2, 8, 4)], &scenes).unwrap();
        assert!(m.starts_with("frame 2 (a/2.json) is 8x4 while frame 0 (a/0.json)"), "{m}");
    }

    /// A GIF of three frames decodes to three frames of the pictures' size, looping.
    #[test]
    fn a_gif_is_made_of_the_frames() {
        let dir = tessera_testkit::TempDir::new("unit-video-gif");
        let pngs: Vec<PathBuf> = (0..3u8)
            .map(|k| {
                let p = dir.path().join(format!("{k}.png"));
                image::RgbImage::from_pixel(5, 3, image::Rgb([k * 100, 20, 30])).save(&p).unwrap();
                p
            })
            .collect();
        let out = dir.path().join("video.gif");
        let e = encode(VideoKind::Gif, &pngs, 10, &out, None).unwrap();
        assert_eq!((e.frames, e.width, e.height), (3, 5, 3));
        use image::AnimationDecoder;
        let decoder =
            image::codecs::gif::GifDecoder::new(std::io::BufReader::new(std::fs::File::open(&out).unwrap()))
                .unwrap();
        let frames = decoder.into_frames().collect_frames().unwrap();
        assert_eq!(frames.len(), 3);
        assert_eq!(frames[2].buffer().get_pixel(1, 1).0[0], 200);
        assert_eq!(frames[0].delay().numer_denom_ms(), (100, 1));
        // Another size among the frames: no file.
        image::RgbImage::new(4, 3).save(&pngs[1]).unwrap();
        let e = encode(VideoKind::Gif, &pngs, 10, &dir.path().join("b.gif"), None).unwrap_err();
        assert!(format!("{e:#}").contains("frame 1 is 4x3 while frame 0 is 5x3"), "{e:#}");
        assert!(!dir.path().join("b.gif").exists());
        assert!(
            std::fs::read_dir(dir.path())
                .unwrap()
                .flatten()
                .all(|f| !f.file_name().to_string_lossy().ends_with(".tmp"))
        );
    }
}
