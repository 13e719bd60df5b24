//! Merge and tone-map once: a frame's float tiles become one image, written as the camera's
//! outputs (`tessera::output`): `.exr` plus the tone-mapped `.png` for HDR image names, the
//! clamped `.png` plus the float frame as `.exr` for LDR ones. The photographic operator needs
//! the whole image (log average, burn-out percentile), so it runs here and nowhere per tile.
//!
//! [`merge_frame`] is the farm's entry point, called when a frame's last tile is accepted (and at
//! startup for frames a crash left unmerged); the rest is CPU and file work that it runs on
//! `spawn_blocking`.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use tessera::camera::Camera;
use tessera::image::{Image, TileRect};
use tessera::output::{self, OutputFile, OutputKind};
use tessera::protocol::{JobState, Rect, ServerEvent, decode_tile};
use tessera::tonemap::params::{Operator, Photographic};
use tessera::tonemap::tonemap_with;

use crate::db::MergeTiming;
use crate::state::AppState;

/// Assembles `tiles` into a `width` x `height` image; missing tiles stay black.
pub fn assemble(width: u32, height: u32, tiles: &[(Rect, Vec<u8>)]) -> Result<Image> {
    let mut img = Image::new(width, height);
    for (r, bytes) in tiles {
        if r.x0 + r.width > width || r.y0 + r.height > height {
            bail!("tile {r:?} lies outside the {width}x{height} frame");
        }
        let px = decode_tile(bytes, (r.width * r.height) as usize).with_context(|| {
            format!("tile {r:?} holds {} bytes, not {}", bytes.len(), r.width * r.height * 12)
        })?;
        img.put_tile(TileRect::from(*r), &px);
    }
    Ok(img)
}

/// The files the farm writes for a camera: what `tessera-worker render` writes, plus the float
/// frame as `<stem>.exr` when the image name is LDR (so it can be re-tone-mapped later).
pub fn farm_outputs(cam: &Camera) -> Vec<OutputFile> {
    let (mut files, _) = output::plan(cam);
    if !files.iter().any(|f| matches!(f.kind, OutputKind::Exr | OutputKind::Hdr)) {
        let stem = Path::new(&files[0].name)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let exr = format!("{stem}.exr");
        if !files.iter().any(|f| f.name == exr) {
            files.push(OutputFile { name: exr, kind: OutputKind::Exr });
        }
    }
    files
}

/// Writes the frame's outputs into `dir` (created). `output::write` puts each file in place
/// atomically (a synced temporary file of its own, renamed), so a crash never leaves half a file
/// under the final name, and two merges of one frame (a restart's recovery and a late trigger)
/// never write into each other's files. Returns the file names, and the seconds spent on the
/// tone-mapped PNGs (tone mapping and encoding; `None` when there are none) and on the rest.
/// The files are written one `output::write` call each, only so that they can be timed apart.
pub fn write_outputs(dir: &Path, cam: &Camera, img: &Image) -> Result<(Vec<String>, f64, Option<f64>)> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let files = farm_outputs(cam);
    let (mut plain, mut tonemapped) = (0.0, None::<f64>);
    for f in &files {
        let started = Instant::now();
        output::write(dir, img, std::slice::from_ref(f)).map_err(|e| anyhow::anyhow!("{e}"))?;
        let took = started.elapsed().as_secs_f64();
        match f.kind {
            OutputKind::Tonemapped(..) => *tonemapped.get_or_insert(0.0) += took,
            _ => plain += took,
        }
    }
    Ok((files.into_iter().map(|f| f.name).collect(), plain, tonemapped))
}

/// The operator of a camera's first tone-mapped PNG, if its image name is HDR.
pub fn display_tonemap(cam: &Camera) -> Option<(Operator, Photographic)> {
    farm_outputs(cam).iter().find_map(|f| match &f.kind {
        OutputKind::Tonemapped(op, p) => Some((*op, *p)),
        _ => None,
    })
}

/// A PNG of what has arrived so far, for the status page: HDR frames through the camera's
/// operator with its statistics taken over the arrived tiles only (the black of missing tiles
/// would otherwise drag the log average down and wash the picture out), LDR frames clamped.
pub fn preview_png(cam: &Camera, width: u32, height: u32, tiles: &[(Rect, Vec<u8>)]) -> Result<Vec<u8>> {
    let img = assemble(width, height, tiles)?;
    let Some((operator, params)) = display_tonemap(cam) else {
        return encode_png(width, height, &img.to_ldr());
    };
    // The arrived pixels as one strip, tone-mapped together, then put back in place.
    let mut strip = Vec::new();
    for (r, _) in tiles {
        for y in r.y0..r.y0 + r.height {
            let row = (y * width + r.x0) as usize;
            strip.extend_from_slice(&img.pixels[row..row + r.width as usize]);
        }
    }
    let mut rgb = vec![0u8; (width * height * 3) as usize];
    if !strip.is_empty() {
        let n = strip.len() as u32;
        let (mapped, _) = tonemap_with(&Image { width: n, height: 1, pixels: strip }, operator, &params);
        let mut k = 0usize;
        for (r, _) in tiles {
            for y in r.y0..r.y0 + r.height {
                let at = ((y * width + r.x0) * 3) as usize;
                let len = (r.width * 3) as usize;
                rgb[at..at + len].copy_from_slice(&mapped[k..k + len]);
                k += len;
            }
        }
    }
    encode_png(width, height, &rgb)
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

/// Merges a complete frame off the executor; a failure fails the job with the reason.
pub async fn merge_frame(state: AppState, job_id: u64, frame: u32) {
    let st = state.clone();
    let outcome = tokio::task::spawn_blocking(move || -> anyhow::Result<bool> {
        let job = st.store.job(job_id)?.ok_or_else(|| anyhow::anyhow!("job {job_id} vanished"))?;
        let frames = st.store.frames(job_id)?;
        let f = frames
            .iter()
            .find(|f| f.index == frame)
            .ok_or_else(|| anyhow::anyhow!("frame {frame} vanished"))?;
        if f.outputs.is_some() {
            // Merged already (a second trigger of one frame): the outputs stand.
            return Ok(frames.iter().all(|f| f.outputs.is_some()));
        }
        let cameras = st.job_cameras(&job)?;
        let cam =
            cameras.get(f.camera as usize).ok_or_else(|| anyhow::anyhow!("camera {} missing", f.camera))?;
        let started = Instant::now();
        let tiles = st.store.frame_tiles(job_id, frame)?;
        let img = assemble(f.width, f.height, &tiles)?;
        let assembled = started.elapsed().as_secs_f64();
        let (names, written, tonemap_seconds) = write_outputs(&st.frame_dir(job_id, frame), cam, &img)?;
        let timing = MergeTiming { merge_seconds: assembled + written, tonemap_seconds };
        st.store.frame_merged(job_id, frame, &names, timing)
    })
    .await;
    match outcome {
        Ok(Ok(done)) => {
            tracing::info!(job = job_id, frame, done, "frame merged");
            state.emit(ServerEvent::Frame { job: job_id, frame });
            if done {
                state.emit(ServerEvent::Job { job: job_id, state: JobState::Done });
            }
        }
        Ok(Err(e)) => {
            tracing::error!(job = job_id, frame, "merge failed: {e:#}");
            let _ = state.store.fail_job(job_id, &format!("merging frame {frame} failed: {e:#}"));
            state.emit(ServerEvent::Job { job: job_id, state: JobState::Failed });
        }
        Err(e) => tracing::error!(job = job_id, frame, "merge task panicked: {e}"),
    }
}
