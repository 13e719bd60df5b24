//! Merge and tone-map once: a frame's float tiles become one image, written as the camera's
//! outputs (`tessera::output`): `.exr` plus the tone-mapped `.png` for HDR image names, the
//! clamped `.png` plus the float frame as `.exr` for LDR ones. The photographic operator needs
//! the whole image (log average, burn-out percentile), so it runs here and nowhere per tile.
//!
//! [`merge_frame`] is the farm's entry point, called when a frame's last tile is accepted (and at
//! startup for frames a crash left unmerged, and by [`retry_when_space_returns`] for frames that
//! found the disk full); the rest is CPU and file work that it runs on `spawn_blocking`.

use std::collections::{HashMap, HashSet};
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use tessera::camera::Camera;
use tessera::image::{Image, TileRect};
use tessera::output::{self, OutputFile, OutputKind};
use tessera::protocol::{JobState, Rect, ServerEvent, decode_tile, tile_bytes, tile_planes};
use tessera::render::AuxImages;
use tessera::tonemap::params::{Operator, Photographic};
use tessera::tonemap::tonemap_with;

use crate::db::{FrameRow, JobRow, MergeTiming};
use crate::state::AppState;

/// Assembles `tiles` into a `width` x `height` image; missing tiles stay black.
pub fn assemble(width: u32, height: u32, tiles: &[(Rect, Vec<u8>)]) -> Result<Image> {
    Ok(assemble_with_aux(width, height, tiles, false)?.0)
}

/// [`assemble`], and with `aux` the denoising features the tiles carry (every tile must).
pub fn assemble_with_aux(
    width: u32,
    height: u32,
    tiles: &[(Rect, Vec<u8>)],
    aux: bool,
) -> Result<(Image, Option<AuxImages>)> {
    let mut img = Image::new(width, height);
    let mut features =
        aux.then(|| AuxImages { albedo: Image::new(width, height), normal: Image::new(width, height) });
    for (r, bytes) in tiles {
        if r.x0 + r.width > width || r.y0 + r.height > height {
            bail!("tile {r:?} lies outside the {width}x{height} frame");
        }
        let n = (r.width * r.height) as usize;
        let (colour, planes) = tile_planes(bytes, n)
            .with_context(|| format!("tile {r:?} holds {} bytes, not {}", bytes.len(), tile_bytes(n, aux)))?;
        let decode =
            |b: &[u8]| decode_tile(b, n).with_context(|| format!("tile {r:?}: a plane of the wrong size"));
        let rect = TileRect::from(*r);
        if (r.x0, r.y0, r.width, r.height) == (0, 0, width, height) {
            // A frame rendered as one tile (a sequence's small frames): its pixels are the image.
            img.pixels = decode(colour)?;
        } else {
            img.put_tile(rect, &decode(colour)?);
        }
        if let Some(f) = features.as_mut() {
            let (albedo, normal) = planes.with_context(|| format!("tile {r:?} has no denoising features"))?;
            f.albedo.put_tile(rect, &decode(albedo)?);
            f.normal.put_tile(rect, &decode(normal)?);
        }
    }
    Ok((img, features))
}

/// Writes `img` denoised (OIDN's RT filter, high quality, with the features) as the camera's
/// `<stem>_denoised` files in `dir` (`output::denoised_plan`). Returns their names, the
/// denoiser's seconds and a sentence for the job's log.
pub fn write_denoised(
    dir: &Path,
    cam: &Camera,
    img: &Image,
    aux: &AuxImages,
) -> Result<(Vec<String>, f64, String)> {
    let oidn = tessera_denoise::oidn().map_err(|e| anyhow::anyhow!("{e}"))?;
    let (clean, seconds) = oidn
        .denoise(img, Some(aux), tessera_denoise::Quality::High)
        .map_err(|e| anyhow::anyhow!("denoising failed: {e}"))?;
    let files = output::denoised_plan(cam);
    output::write(dir, &clean, &files).map_err(anyhow::Error::new)?;
    let names: Vec<String> = files.into_iter().map(|f| f.name).collect();
    let what = format!(
        "denoised with Intel Open Image Denoise {} (RT filter, high quality, albedo and normal): {}",
        oidn.version(),
        names.join(", ")
    );
    Ok((names, seconds, what))
}

/// The float frame the farm keeps beside a camera's LDR image (`<stem>.exr`, so the frame can be
/// re-tone-mapped later), unless the image name already writes one (`.exr`, `.hdr`) or the
/// job's `keep_float` is false.
/// Whether a job keeps each PNG frame's float image beside it: as it asked, else a job of one
/// scene does (its frames may be re-tone-mapped or fetched with `--float-exr`) and a sequence
/// does not (its product is the PNGs and the video; an 800x800 float frame is 3.4 MB even
/// compressed, and compressing it costs the server more CPU than the worker's render of a
/// course frame).
pub fn keeps_float(asked: Option<bool>, scenes: u32) -> bool {
    asked.unwrap_or(scenes <= 1)
}

pub fn kept_float(files: &[OutputFile], keep_float: bool) -> Option<String> {
    if !keep_float || files.iter().any(|f| matches!(f.kind, OutputKind::Exr | OutputKind::Hdr)) {
        return None;
    }
    let stem = Path::new(&files.first()?.name)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let exr = format!("{stem}.exr");
    (!files.iter().any(|f| f.name == exr)).then_some(exr)
}

/// Writes the frame's outputs into `dir` (created): what `tessera-worker render` writes (the
/// same bytes), plus the kept float frame ([`kept_float`]), ZIP-compressed (lossless; most
/// of a course frame's bytes, so it is the smaller kind of file even if slower to write).
/// `output::write` puts each file in place atomically (a synced temporary file of its own,
/// renamed), so a crash never leaves half a file under the final name, and two merges of one
/// frame (a restart's recovery and a late trigger) never write into each other's files.
/// Returns the file names, and the seconds spent on the tone-mapped PNGs (tone mapping and
/// encoding; `None` when there are none) and on the rest. The files are written one
/// `output::write` call each, only so that they can be timed apart.
pub fn write_outputs(
    dir: &Path,
    cam: &Camera,
    img: &Image,
    keep_float: bool,
) -> Result<(Vec<String>, f64, Option<f64>)> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let (files, _) = output::plan(cam);
    let (mut plain, mut tonemapped) = (0.0, None::<f64>);
    for f in &files {
        let started = Instant::now();
        output::write(dir, img, std::slice::from_ref(f)).map_err(anyhow::Error::new)?;
        let took = started.elapsed().as_secs_f64();
        match f.kind {
            OutputKind::Tonemapped(..) => *tonemapped.get_or_insert(0.0) += took,
            _ => plain += took,
        }
    }
    let extra = kept_float(&files, keep_float);
    let mut names: Vec<String> = files.into_iter().map(|f| f.name).collect();
    if let Some(exr) = extra {
        let started = Instant::now();
        tessera::hdr_io::write_exr_zip(&dir.join(&exr), img).map_err(anyhow::Error::new)?;
        plain += started.elapsed().as_secs_f64();
        names.push(exr);
    }
    Ok((names, plain, tonemapped))
}

/// The output PNG the page shows for a camera's finished frame: its first tone-mapped PNG, else
/// its plain PNG (what [`final_png`] makes, byte for byte).
pub fn display_png(cam: &Camera) -> Option<String> {
    let (files, _) = output::plan(cam);
    files
        .iter()
        .find(|f| matches!(f.kind, OutputKind::Tonemapped(..)))
        .or_else(|| files.iter().find(|f| matches!(f.kind, OutputKind::LdrPng)))
        .map(|f| f.name.clone())
}

/// The operator of a camera's first tone-mapped PNG, if its image name is HDR.
pub fn display_tonemap(cam: &Camera) -> Option<(Operator, Photographic)> {
    output::plan(cam).0.iter().find_map(|f| match &f.kind {
        OutputKind::Tonemapped(op, p) => Some((*op, *p)),
        _ => None,
    })
}

/// Longest side of a preview, in pixels: larger frames are previewed box-filtered by a whole
/// factor, so a preview costs a bounded amount of memory whatever the frame's size.
pub const PREVIEW_MAX_SIDE: u32 = 1024;

/// The whole factor a `width` x `height` frame is shrunk by for its preview, and the preview's
/// size.
pub fn preview_size(width: u32, height: u32) -> (u32, u32, u32) {
    let scale = width.max(height).div_ceil(PREVIEW_MAX_SIDE).max(1);
    (scale, width.div_ceil(scale), height.div_ceil(scale))
}

/// A frame's preview being filled tile by tile: each preview pixel the average of the frame
/// pixels of its `scale` x `scale` box that have arrived.
pub struct PreviewCanvas {
    width: u32,
    height: u32,
    scale: u32,
    pw: u32,
    ph: u32,
    sums: Vec<[f32; 3]>,
    counts: Vec<u32>,
}

impl PreviewCanvas {
    pub fn new(width: u32, height: u32) -> PreviewCanvas {
        let (scale, pw, ph) = preview_size(width, height);
        let n = (pw * ph) as usize;
        PreviewCanvas { width, height, scale, pw, ph, sums: vec![[0.0; 3]; n], counts: vec![0; n] }
    }

    /// Adds a tile's pixels (the wire format) at its rectangle.
    pub fn add(&mut self, r: Rect, bytes: &[u8]) -> Result<()> {
        if r.x0.checked_add(r.width).is_none_or(|x| x > self.width)
            || r.y0.checked_add(r.height).is_none_or(|y| y > self.height)
        {
            bail!("tile {r:?} lies outside the {}x{} frame", self.width, self.height);
        }
        let n = (r.width * r.height) as usize;
        let px = tile_planes(bytes, n).and_then(|(colour, _)| decode_tile(colour, n)).with_context(|| {
            format!("tile {r:?} holds {} bytes, not {} (or three times that)", bytes.len(), n * 12)
        })?;
        for y in 0..r.height {
            let row = ((r.y0 + y) / self.scale * self.pw) as usize;
            for x in 0..r.width {
                let at = row + ((r.x0 + x) / self.scale) as usize;
                let p = px[(y * r.width + x) as usize];
                let s = &mut self.sums[at];
                for c in 0..3 {
                    s[c] += p[c];
                }
                self.counts[at] += 1;
            }
        }
        Ok(())
    }

    /// The preview as a PNG: HDR frames through the camera's operator with its statistics
    /// taken over the arrived pixels only (the black of missing tiles would otherwise drag the
    /// log average down and wash the picture out), LDR frames clamped.
    pub fn png(&self, cam: &Camera) -> Result<Vec<u8>> {
        let arrived: Vec<usize> = (0..self.counts.len()).filter(|&i| self.counts[i] > 0).collect();
        let mean = |i: usize| {
            let n = self.counts[i] as f32;
            let s = self.sums[i];
            [s[0] / n, s[1] / n, s[2] / n]
        };
        let mut rgb = vec![0u8; (self.pw * self.ph * 3) as usize];
        let Some((operator, params)) = display_tonemap(cam) else {
            let mut img = Image::new(self.pw, self.ph);
            for &i in &arrived {
                img.pixels[i] = mean(i);
            }
            return encode_png(self.pw, self.ph, &img.to_ldr());
        };
        if !arrived.is_empty() {
            // The arrived pixels as one strip, tone-mapped together, then put back in place.
            let strip = Image {
                width: arrived.len() as u32,
                height: 1,
                pixels: arrived.iter().map(|&i| mean(i)).collect(),
            };
            let (mapped, _) = tonemap_with(&strip, operator, &params);
            for (k, &i) in arrived.iter().enumerate() {
                rgb[i * 3..i * 3 + 3].copy_from_slice(&mapped[k * 3..k * 3 + 3]);
            }
        }
        encode_png(self.pw, self.ph, &rgb)
    }
}

/// The name of a merged frame's preview, among the server's own files of the frame
/// ([`AppState::server_frame_dir`]), never beside its outputs.
pub use crate::storage::PREVIEW_FILE;

/// A finished frame's preview: the whole image box-filtered to the preview's size
/// ([`shrink_for_preview`]), then tone mapped as the camera's final picture.
pub fn final_preview_png(cam: &Camera, img: &Image) -> Result<Vec<u8>> {
    match shrink_for_preview(img) {
        Some(small) => final_png(cam, &small),
        None => final_png(cam, img),
    }
}

/// `img` shrunk by the preview's whole factor (each pixel the mean of its box; boxes cut by the
/// frame's edge average the pixels they hold), or `None` when it is small enough already.
pub fn shrink_for_preview(img: &Image) -> Option<Image> {
    let (scale, pw, ph) = preview_size(img.width, img.height);
    if scale == 1 {
        return None;
    }
    let mut small = Image::new(pw, ph);
    let mut counts = vec![0u32; (pw * ph) as usize];
    for y in 0..img.height {
        for x in 0..img.width {
            let at = (y / scale * pw + x / scale) as usize;
            let p = img.pixels[(y * img.width + x) as usize];
            for (s, v) in small.pixels[at].iter_mut().zip(p) {
                *s += v;
            }
            counts[at] += 1;
        }
    }
    for (p, n) in small.pixels.iter_mut().zip(counts) {
        for c in p.iter_mut() {
            *c /= n.max(1) as f32;
        }
    }
    Some(small)
}

/// A finished frame's picture for the page: the camera's tone mapping of the whole image.
pub fn final_png(cam: &Camera, img: &Image) -> Result<Vec<u8>> {
    let rgb = match display_tonemap(cam) {
        Some((operator, params)) => tonemap_with(img, operator, &params).0,
        None => img.to_ldr(),
    };
    encode_png(img.width, img.height, &rgb)
}

/// 8-bit RGB bytes as a PNG file in memory (the same encoding as the written PNGs).
pub fn encode_png(width: u32, height: u32, rgb: &[u8]) -> Result<Vec<u8>> {
    tessera::hdr_io::encode_png_rgb8(width, height, rgb)
        .map_err(|m| anyhow::anyhow!("cannot encode the PNG: {m}"))
}

/// A job, all its frames and where among them frame `frame` is; an error if either is gone.
fn look_up_frame(st: &AppState, job_id: u64, frame: u32) -> Result<(JobRow, Vec<FrameRow>, usize)> {
    let job = st.store.job(job_id)?.ok_or_else(|| anyhow::anyhow!("job {job_id} vanished"))?;
    let frames = st.store.frames(job_id)?;
    let at = frames
        .iter()
        .position(|f| f.index == frame)
        .ok_or_else(|| anyhow::anyhow!("frame {frame} vanished"))?;
    Ok((job, frames, at))
}

/// The camera frame `f` renders.
fn frame_camera(st: &AppState, job: &JobRow, f: &FrameRow) -> Result<Camera> {
    let cam = st.frame_cameras(job)?.get(f.index as usize).cloned();
    cam.ok_or_else(|| anyhow::anyhow!("the camera of frame {} is missing", f.index))
}

/// Frame `f`'s stored tiles as one image, with the denoising features when the job asked for
/// them.
fn assemble_frame(st: &AppState, job: &JobRow, f: &FrameRow) -> Result<(Image, Option<AuxImages>)> {
    let tiles = st.store.frame_tiles(job.id, f.index)?;
    assemble_with_aux(f.width, f.height, &tiles, job.denoise)
}

/// Merges a complete frame off the executor. A full disk (or quota) leaves the job going and
/// the frame waiting for space ([`wait_for_space`]); any other failure fails the job with the
/// reason.
pub async fn merge_frame(state: AppState, job_id: u64, frame: u32) {
    // A merge holds its whole frame in memory: one at a time.
    let Ok(_permit) = state.merging.clone().acquire_owned().await else { return };
    let st = state.clone();
    let outcome = tokio::task::spawn_blocking(move || -> anyhow::Result<bool> {
        let (job, frames, at) = look_up_frame(&st, job_id, frame)?;
        let f = &frames[at];
        if f.outputs.is_some() {
            // Merged already (a second trigger of one frame): the outputs stand.
            return Ok(frames.iter().all(|f| f.outputs.is_some()));
        }
        let cam = frame_camera(&st, &job, f)?;
        let started = Instant::now();
        let (img, aux) = assemble_frame(&st, &job, f)?;
        let assembled = started.elapsed().as_secs_f64();
        let dir = st.frame_dir(job_id, frame);
        let (mut names, written, tonemap_seconds) =
            write_outputs(&dir, &cam, &img, keeps_float(job.keep_float, job.scenes))?;
        // The denoised frame goes beside the course's outputs, from the merged frame (never
        // tile by tile: the filter would leave seams).
        let denoise = match &aux {
            Some(aux) => {
                let (more, seconds, what) = write_denoised(&dir, &cam, &img, aux)?;
                names.extend(more);
                Some((seconds, what))
            }
            None => None,
        };
        // The page's picture of the finished frame, made once here: a preview request then
        // reads a small file instead of the whole float frame.
        let own = st.server_frame_dir(job_id, frame);
        std::fs::create_dir_all(&own).with_context(|| format!("cannot create {}", own.display()))?;
        // A frame small enough to be previewed whole has that picture among its outputs
        // already: copied, not tone-mapped and encoded a second time.
        let preview = match display_png(&cam) {
            Some(name) if preview_size(img.width, img.height).0 == 1 => std::fs::read(dir.join(&name))
                .with_context(|| format!("cannot read the frame's {name} for its preview"))?,
            _ => final_preview_png(&cam, &img)?,
        };
        tessera::atomic_write::write_atomic(&own.join(PREVIEW_FILE), &preview)
            .context("cannot write the frame's preview")?;
        if job.noise_target.is_some() {
            let name = tessera::output::samples_map_name(&cam);
            let counts = st.store.tile_samples(job_id, frame)?;
            let tiles: Vec<_> =
                counts.iter().map(|(r, n)| (tessera::image::TileRect::from(*r), n.as_slice())).collect();
            let rgb = tessera::output::samples_map(f.width, f.height, &tiles, f.samples);
            tessera::hdr_io::write_png_rgb8(&dir.join(&name), f.width, f.height, &rgb)
                .map_err(anyhow::Error::new)?;
            names.push(name);
        }
        let timing = MergeTiming { merge_seconds: assembled + written, tonemap_seconds, denoise };
        let done = st.store.frame_merged(job_id, frame, &names, timing)?;
        // The last pass's files are superseded by the outputs, which their names now serve
        // (`api::jobs::frame_file`). Removed only once the outputs are recorded, so that a
        // download of them never finds neither; from the server's own folder of the frame,
        // never from the outputs' (where an output may have the same name).
        for name in PASS_FILES.iter().chain([&PASS_DENOISED_FILE]) {
            let _ = std::fs::remove_file(own.join(name));
        }
        Ok(done)
    })
    .await;
    match outcome {
        Ok(Ok(done)) => {
            tracing::info!(job = job_id, frame, done, "frame merged");
            waiting_for_space(&state).remove(&(job_id, frame));
            state.emit(ServerEvent::Frame { job: job_id, frame });
            if done {
                state.emit(ServerEvent::Job { job: job_id, state: JobState::Done });
                // The job's video, if it makes one, from its merged frames.
                tokio::spawn(crate::video::make_video(state.clone(), job_id));
            }
        }
        Ok(Err(e)) if crate::storage::out_of_space(&e) => wait_for_space(&state, job_id, frame, &e).await,
        Ok(Err(e)) => {
            tracing::error!(job = job_id, frame, "merge failed: {e:#}");
            waiting_for_space(&state).remove(&(job_id, frame));
            // The job's error is shown to its clients: paths into the data directory become
            // file names (the log above has them whole).
            let error = crate::storage::without_paths(
                &format!("merging frame {frame} failed: {e:#}; the server's log has the details"),
                &state.settings.data_dir,
            );
            let store = state.store.clone();
            let _ = tokio::task::spawn_blocking(move || store.fail_job(job_id, &error)).await;
            state.emit(ServerEvent::Job { job: job_id, state: JobState::Failed });
        }
        Err(e) => tracing::error!(job = job_id, frame, "merge task panicked: {e}"),
    }
}

/// The frames waiting for disk space, locked.
fn waiting_for_space(state: &AppState) -> std::sync::MutexGuard<'_, HashMap<(u64, u32), bool>> {
    state.waiting_for_space.lock().unwrap_or_else(|e| e.into_inner())
}

/// A merge that found the disk full: the job goes on (every tile is kept in the store), the
/// frame joins those [`retry_when_space_returns`] merges again, and the job's log says why,
/// once per episode (a `merge_waiting_for_space` event; tried again at the next attempt if the
/// full disk refused the event itself).
async fn wait_for_space(state: &AppState, job_id: u64, frame: u32, e: &anyhow::Error) {
    let told = *waiting_for_space(state).entry((job_id, frame)).or_insert(false);
    if told {
        tracing::info!(job = job_id, frame, "the disk is still full; the merge waits: {e:#}");
        return;
    }
    tracing::warn!(job = job_id, frame, "the disk is full; the merge waits for space: {e:#}");
    let message = format!(
        "frame {frame} is complete, but the server's disk is full: its merge waits (every tile is kept) and is \
         tried again every few seconds until an operator frees space"
    );
    let store = state.store.clone();
    let logged = tokio::task::spawn_blocking(move || {
        store.log_frame_event(job_id, frame, "merge_waiting_for_space", &message)
    })
    .await;
    if matches!(logged, Ok(Ok(())))
        && let Some(told) = waiting_for_space(state).get_mut(&(job_id, frame))
    {
        *told = true;
    }
}

/// The first wait before frames that found the disk full are merged again, and the longest:
/// the wait doubles while the disk stays full, and starts again from the first once they merge.
pub const SPACE_RETRY_FIRST: Duration = Duration::from_secs(2);
pub const SPACE_RETRY_MAX: Duration = Duration::from_secs(16);

/// Merges the frames that found the disk full again, on a backoff from [`SPACE_RETRY_FIRST`] to
/// [`SPACE_RETRY_MAX`], for as long as the server runs: once an operator frees space, the
/// frames are merged and their jobs finish without anybody resubmitting them. A frame whose job
/// has ended meanwhile (cancelled) is dropped.
pub fn retry_when_space_returns(state: AppState) {
    tokio::spawn(async move {
        let mut wait = SPACE_RETRY_FIRST;
        loop {
            tokio::time::sleep(wait).await;
            let waiting: Vec<(u64, u32)> = waiting_for_space(&state).keys().copied().collect();
            if waiting.is_empty() {
                wait = SPACE_RETRY_FIRST;
                continue;
            }
            let store = state.store.clone();
            let Ok(Ok(awaiting)) = tokio::task::spawn_blocking(move || store.frames_awaiting_merge()).await
            else {
                wait = (wait * 2).min(SPACE_RETRY_MAX);
                continue;
            };
            let live: HashSet<(u64, u32)> = awaiting.iter().map(|f| (f.job_id, f.index)).collect();
            waiting_for_space(&state).retain(|k, _| live.contains(k));
            for (job, frame) in waiting.into_iter().filter(|k| live.contains(k)) {
                merge_frame(state.clone(), job, frame).await;
            }
            let still = !waiting_for_space(&state).is_empty();
            wait = if still { (wait * 2).min(SPACE_RETRY_MAX) } else { SPACE_RETRY_FIRST };
        }
    });
}

/// The frame after its latest pass (`pass.exr`, and `pass.png` tone-mapped on the whole frame
/// like the final one), among the server's own files of the frame
/// ([`AppState::server_frame_dir`]) until the frame is merged: never in the outputs' folder,
/// where a camera's `ImageName` may be `pass.png` too.
pub use crate::storage::PASS_FILES;

/// Publishes a frame whose every tile has finished another pass: the tiles as they stand merged,
/// written as [`PASS_FILES`] and logged with the samples reached. Skipped once the frame is
/// merged (its outputs supersede it).
pub async fn publish_pass(state: AppState, job_id: u64, frame: u32) {
    let Ok(_permit) = state.merging.clone().acquire_owned().await else { return };
    let st = state.clone();
    let outcome = tokio::task::spawn_blocking(move || -> anyhow::Result<bool> {
        let (job, frames, at) = look_up_frame(&st, job_id, frame)?;
        let f = &frames[at];
        if f.outputs.is_some() || job.state.is_final() {
            return Ok(false);
        }
        // Read before the tiles are (which only gain samples after it), so that the pass
        // named is one the picture has. A frame whose every tile is in is left to its merge:
        // a pass picture of it would be the finished frame under the name of a pass.
        let at = st.store.pass_snapshot(job_id, frame)?;
        if at.complete {
            return Ok(false);
        }
        let cam = frame_camera(&st, &job, f)?;
        let started = Instant::now();
        let (img, aux) = assemble_frame(&st, &job, f)?;
        // Each written atomically (a temporary file of its own, renamed), the PNG last: the
        // job lists the pass files once it is there.
        let dir = st.server_frame_dir(job_id, frame);
        std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
        tessera::hdr_io::write_exr(&dir.join(PASS_FILES[0]), &img).map_err(anyhow::Error::new)?;
        tessera::atomic_write::write_atomic(&dir.join(PASS_FILES[1]), &final_png(&cam, &img)?)
            .context("cannot write the pass's PNG")?;
        // A denoised job's pass is denoised too (here, off the executor and the lease path,
        // like the merges): a failure leaves the raw pass, and is logged with it.
        let denoised = aux.map(|aux| denoise_pass(&dir, &cam, &img, &aux));
        st.store.frame_passed(
            job_id,
            frame,
            &at,
            f.passes_total,
            started.elapsed().as_secs_f64(),
            denoised.as_ref(),
        )?;
        Ok(true)
    })
    .await;
    match outcome {
        Ok(Ok(true)) => state.emit(ServerEvent::Frame { job: job_id, frame }),
        Ok(Ok(false)) => {}
        Ok(Err(e)) => tracing::warn!(job = job_id, frame, "publishing a pass failed: {e:#}"),
        Err(e) => tracing::error!(job = job_id, frame, "pass task panicked: {e}"),
    }
}

/// Writes the frame after a pass denoised ([`PASS_DENOISED_FILE`]): OIDN's RT filter at its
/// fast quality (a preview, replaced by the next pass), with the features of the tiles, tone
/// mapped like the pass's PNG. Returns the denoiser's seconds, or why there is no denoised
/// pass (a sentence for the job's log).
pub fn denoise_pass(dir: &Path, cam: &Camera, img: &Image, aux: &AuxImages) -> Result<f64, String> {
    let written = (|| {
        let oidn = tessera_denoise::oidn().map_err(|e| {
            // Where it was looked for is the server's business: its log has it.
            tracing::warn!("a pass is not denoised: {e}");
            "Intel Open Image Denoise is not available (the server's log says why)".to_string()
        })?;
        let (clean, seconds) = oidn.denoise(img, Some(aux), tessera_denoise::Quality::Fast)?;
        let png = final_png(cam, &clean).map_err(|e| format!("{e:#}"))?;
        tessera::atomic_write::write_atomic(&dir.join(PASS_DENOISED_FILE), &png)
            .map_err(|e| format!("cannot write {PASS_DENOISED_FILE}: {e}"))?;
        Ok(seconds)
    })();
    if written.is_err() {
        // An earlier pass's denoised picture must not pass for this one's.
        let _ = std::fs::remove_file(dir.join(PASS_DENOISED_FILE));
    }
    written
}

/// The denoised picture of the frame after its latest pass, beside [`PASS_FILES`].
pub use crate::storage::PASS_DENOISED_FILE;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn large_frames_are_previewed_shrunk_by_a_whole_factor() {
        assert_eq!(preview_size(800, 600), (1, 800, 600));
        assert_eq!(preview_size(1024, 1024), (1, 1024, 1024));
        assert_eq!(preview_size(16384, 16384), (16, 1024, 1024));
        assert_eq!(preview_size(3000, 10), (3, 1000, 4));
        let mut img = Image::new(3000, 10);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            let (x, y) = ((i % 3000) as f32, (i / 3000) as f32);
            *p = [x, y, 1.0];
        }
        assert!(shrink_for_preview(&Image::new(800, 600)).is_none());
        let small = shrink_for_preview(&img).unwrap();
        assert_eq!((small.width, small.height), (1000, 4));
        // Box (0, 0): x 0-2, y 0-2.
        assert_eq!(small.pixels[0], [1.0, 1.0, 1.0]);
        // The last row holds frame row 9 alone (the edge cuts its box).
        assert_eq!(small.pixels[3 * 1000 + 999], [2997.0 + 1.0, 9.0, 1.0]);
    }

    /// The merge copies the displayed output PNG as the preview of a frame small enough: that
    /// file must be what `final_png` makes, for a plain PNG and for a tone-mapped one.
    #[test]
    fn the_displayed_output_png_is_the_final_preview() {
        let dir = tessera_testkit::TempDir::new("unit-display-png");
        let mut img = Image::new(7, 5);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            *p = [i as f32 * 0.05, 0.3, 4.0 - i as f32 * 0.1];
        }
        for (name, shown) in [("a.png", "a.png"), ("b.exr", "b.png")] {
            let xml = String::from_utf8(tessera_testkit::tiny_scene(7, 5)).unwrap().replace("tiny.png", name);
            let rec = tessera::scene::xml::parse_xml(&xml, std::path::Path::new("t.xml")).unwrap();
            let cam = tessera::scene::build::build_cameras(&rec).unwrap().remove(0);
            assert_eq!(display_png(&cam).as_deref(), Some(shown));
            write_outputs(dir.path(), &cam, &img, false).unwrap();
            let written = std::fs::read(dir.join(shown)).unwrap();
            assert!(
                written == final_preview_png(&cam, &img).unwrap(),
                "{name}: the preview differs from {shown}"
            );
        }
    }

    #[test]
    fn a_preview_canvas_averages_the_arrived_pixels_of_each_box() {
        let mut canvas = PreviewCanvas::new(2048, 8); // scale 2: 1024 x 4
        let rect = Rect { x0: 0, y0: 0, width: 2, height: 1 };
        canvas.add(rect, &tessera::protocol::encode_tile(&[[1.0, 2.0, 3.0], [3.0, 4.0, 5.0]])).unwrap();
        assert_eq!((canvas.pw, canvas.ph, canvas.counts[0]), (1024, 4, 2));
        assert_eq!(canvas.sums[0], [4.0, 6.0, 8.0]);
        let outside = Rect { x0: 2047, y0: 0, width: 2, height: 1 };
        assert!(canvas.add(outside, &tessera::protocol::encode_tile(&[[0.0; 3]; 2])).is_err());
    }
}
