//! Following a job until it ends (a progress bar per frame on a terminal, a line per change
//! otherwise) and downloading its outputs.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Result, bail};
use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};
use tessera::protocol::{FrameInfo, JobInfo, JobState, OutputInfo};

use crate::api::{Api, CallError, is_transient};

/// How often the job is looked at while it runs.
const POLL: Duration = Duration::from_millis(400);
/// How long the server may be unreachable (a restart) before following gives up.
const RETRY_FOR: Duration = Duration::from_secs(120);
/// Without a terminal, a progress line at most this often.
const TEXT_PROGRESS_EVERY: Duration = Duration::from_secs(10);

/// Whether progress bars can be drawn (stderr is a terminal and not `--quiet`).
pub fn bars_wanted(quiet: bool) -> bool {
    !quiet && std::io::stderr().is_terminal()
}

/// `f` retried while the server is unreachable (it may be restarting), for up to
/// [`RETRY_FOR`]; other errors at once.
pub fn with_retries<T>(quiet: bool, mut f: impl FnMut() -> Result<T, CallError>) -> Result<T> {
    let start = Instant::now();
    let mut said = false;
    loop {
        match f() {
            Ok(v) => return Ok(v),
            Err(e) if is_transient(&e) && start.elapsed() < RETRY_FOR => {
                if !said && !quiet {
                    eprintln!("{e}\n  retrying for up to {} s", RETRY_FOR.as_secs());
                    said = true;
                }
                std::thread::sleep(Duration::from_secs(1));
            }
            Err(e) => return Err(e.into()),
        }
    }
}

/// Most frames a job may have and still be followed frame by frame (a bar or a line each); a
/// sequence, or a job with more frames, is followed by its frame counts.
const FRAMES_SHOWN: usize = 16;

/// Whether `job` is shown by its frame counts rather than frame by frame.
pub fn by_counts(job: &JobInfo) -> bool {
    job.scenes > 1 || job.frames.len() > FRAMES_SHOWN
}

/// "120/360 frames done, 2 rendering, 238 queued".
pub fn counts_line(job: &JobInfo) -> String {
    let c = &job.frame_counts;
    format!(
        "{}/{} frames done, {} rendering, {} queued",
        c.done,
        c.done + c.rendering + c.queued,
        c.rendering,
        c.queued
    )
}

/// Whether the job's video is still to come (waiting for frames or being encoded).
pub fn video_pending(job: &JobInfo) -> bool {
    job.video.as_ref().is_some_and(|v| matches!(v.state.as_str(), "waiting" | "encoding"))
}

/// Longest a finished job's video is waited for.
const VIDEO_WAIT: Duration = Duration::from_secs(1800);

fn frame_label(f: &FrameInfo) -> String {
    format!("frame {} {} ({}x{})", f.index, f.image_name, f.width, f.height)
}

/// A frame's progress as (done, to do): pixel-samples, or tiles from a server that does not
/// count samples.
pub fn frame_work(f: &FrameInfo) -> (u64, u64) {
    if f.samples_total > 0 {
        (f.samples_done, f.samples_total)
    } else {
        (u64::from(f.tiles_done), u64::from(f.tiles_total))
    }
}

/// A job's progress as (done, to do), like [`frame_work`].
pub fn job_work(job: &JobInfo) -> (u64, u64) {
    if job.samples_total > 0 {
        (job.samples_done, job.samples_total)
    } else {
        (
            job.frames.iter().map(|f| u64::from(f.tiles_done)).sum(),
            job.frames.iter().map(|f| u64::from(f.tiles_total)).sum(),
        )
    }
}

/// Whole percent of `done` over `total`, rounded down (0 of nothing).
pub fn percent(done: u64, total: u64) -> u64 {
    if total == 0 { 0 } else { (u128::from(done.min(total)) * 100 / u128::from(total)) as u64 }
}

/// "pass 6 of 16, 96 spp" for a frame in passes, "96 spp" otherwise; "" from a server that
/// does not count samples.
pub fn pass_note(f: &FrameInfo) -> String {
    let spp = if f.samples_total > 0 { format!("{} spp", f.spp) } else { String::new() };
    if f.passes_total > 1 && f.pass > 0 {
        let pass = format!("pass {} of {}", f.pass, f.passes_total);
        if spp.is_empty() { pass } else { format!("{pass}, {spp}") }
    } else {
        spp
    }
}

/// "1 min 34 s", "12 s", "2 h 5 min".
pub fn duration_text(d: Duration) -> String {
    let s = d.as_secs();
    match s {
        0..60 => format!("{s} s"),
        60..3600 => format!("{} min {} s", s / 60, s % 60),
        _ => format!("{} h {} min", s / 3600, s % 3600 / 60),
    }
}

/// The time left at the rate of samples since work began: `done` of `total` after `elapsed`.
/// "ETA 1 min 4 s"; "ETA at most ..." when `total` is an upper bound (a noise target);
/// "ETA unknown" before anything is done.
pub fn eta_text(done: u64, total: u64, elapsed: Duration, bound: bool) -> String {
    if done >= total && total > 0 {
        return "ETA 0 s".into();
    }
    if done == 0 || elapsed.is_zero() {
        return "ETA unknown".into();
    }
    let left = elapsed.as_secs_f64() * (total - done) as f64 / done as f64;
    let left = Duration::from_secs_f64(left.min(1e9));
    format!("ETA {}{}", if bound { "at most " } else { "" }, duration_text(left))
}

/// The rate of a job's work measured while following it: from the first look that saw it
/// under way, so that the time it queued does not count.
#[derive(Default)]
pub struct Rate {
    first: Option<(Instant, u64)>,
}

impl Rate {
    /// [`eta_text`] for `done` of `total` now.
    pub fn eta(&mut self, done: u64, total: u64, bound: bool) -> String {
        let (at, from) = *self.first.get_or_insert((Instant::now(), done));
        if done < from {
            // Work done again (a requeue): measure from here.
            self.first = Some((Instant::now(), done));
            return "ETA unknown".into();
        }
        eta_text(done - from, total.saturating_sub(from), at.elapsed(), bound)
    }
}

/// Follows job `id` until it ends and returns it as it ended. `bars`: progress bars on stderr;
/// otherwise (unless `quiet`) a line on stderr per change of state, per finished frame, and on
/// progress at most every 10 s.
pub fn follow(api: &Api, id: u64, bars: bool, quiet: bool) -> Result<JobInfo> {
    let multi = MultiProgress::with_draw_target(if bars {
        ProgressDrawTarget::stderr()
    } else {
        ProgressDrawTarget::hidden()
    });
    // Progress by samples (pixel-samples: large numbers, so a percentage); the pass, the
    // samples per pixel and the ETA are in the message.
    let style = ProgressStyle::with_template("{prefix} [{bar:30}] {percent:>3}%, {elapsed} elapsed, {msg}")
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> ");
    let mut frame_bars: Vec<ProgressBar> = Vec::new();
    let mut last_state: Option<JobState> = None;
    let mut frames_reported: Vec<bool> = Vec::new();
    let mut passes_reported: Vec<u32> = Vec::new();
    let mut last_error: Option<String> = None;
    let mut last_waiting: Option<String> = None;
    let mut last_text = Instant::now();
    let text = !bars && !quiet;
    let mut counts_bar: Option<ProgressBar> = None;
    let mut video_since: Option<Instant> = None;
    let mut rate = Rate::default();
    let mut frame_rates: Vec<Rate> = Vec::new();
    loop {
        let job = with_retries(quiet, || api.job(id))?;
        // The job's progress, and its ETA from the rate of samples since it has been running.
        let (work_done, work_total) = job_work(&job);
        let eta = if job.state == JobState::Running {
            rate.eta(work_done, work_total, job.samples_total_is_bound)
        } else {
            rate = Rate::default();
            "ETA unknown".to_string()
        };
        if by_counts(&job) {
            let c = &job.frame_counts;
            let bar = counts_bar.get_or_insert_with(|| {
                let bar = multi.add(ProgressBar::new(0));
                bar.set_style(
                    ProgressStyle::with_template(
                        "{prefix} [{bar:30}] {pos}/{len} frames, {elapsed} elapsed, {msg}",
                    )
                    .unwrap_or_else(|_| ProgressStyle::default_bar())
                    .progress_chars("=> "),
                );
                bar.set_prefix(format!("job {id}"));
                bar
            });
            bar.set_length(u64::from(c.done + c.rendering + c.queued));
            bar.set_position(u64::from(c.done));
            bar.set_message(format!(
                "{} rendering, {} queued, {}% of samples, {eta}",
                c.rendering,
                c.queued,
                percent(work_done, work_total)
            ));
        } else if frame_bars.is_empty() {
            for f in &job.frames {
                let bar = multi.add(ProgressBar::new(frame_work(f).1));
                bar.set_style(style.clone());
                bar.set_prefix(frame_label(f));
                frame_bars.push(bar);
            }
            frames_reported = vec![false; job.frames.len()];
            passes_reported = vec![0; job.frames.len()];
            frame_rates = job.frames.iter().map(|_| Rate::default()).collect();
        }
        // The end has a line of its own below.
        if last_state != Some(job.state) && text && !job.state.is_final() {
            if job.state == JobState::Paused {
                eprintln!("job {id} ({}): paused; it renders again after: tessera resume {id}", job.name);
            } else {
                eprintln!("job {id} ({}): {}", job.name, job.state.as_str());
            }
        }
        last_state = Some(job.state);
        if job.error != last_error {
            if let Some(e) = &job.error
                && !job.state.is_final()
            {
                let _ = multi.println(format!("job {id}: {e}"));
                if text {
                    eprintln!("job {id}: {e}");
                }
            }
            last_error = job.error.clone();
        }
        // Why nothing moves (no worker able to take the job), once each time it changes.
        if job.waiting_for != last_waiting {
            if let Some(w) = &job.waiting_for
                && !quiet
            {
                let _ = multi.println(format!("job {id} waits: {w}"));
                if text {
                    eprintln!("job {id} waits: {w}");
                }
            }
            last_waiting = job.waiting_for.clone();
        }
        let frames: &[FrameInfo] = if counts_bar.is_some() { &[] } else { &job.frames };
        for (i, f) in frames.iter().enumerate() {
            let Some(bar) = frame_bars.get(i) else { continue };
            let (done, total) = frame_work(f);
            bar.set_length(total);
            bar.set_position(done);
            if f.outputs.is_empty() {
                let eta = match frame_rates.get_mut(i) {
                    Some(r) if job.state == JobState::Running && done > 0 => {
                        r.eta(done, total, f.samples_total_is_bound)
                    }
                    _ => "ETA unknown".to_string(),
                };
                let note = pass_note(f);
                bar.set_message(if note.is_empty() { eta } else { format!("{note}, {eta}") });
            }
            if let Some(seen) = passes_reported.get_mut(i)
                && f.passes_total > 1
                && f.passes_done > *seen
                && f.outputs.is_empty()
            {
                *seen = f.passes_done;
                // The pass's files are listed a moment after the pass counts (once written).
                let files = match f.pass_denoised_url.as_ref().or(f.pass_outputs.last().map(|o| &o.url)) {
                    Some(url) => format!("; preview {url}"),
                    None => String::new(),
                };
                let spp = if f.samples_total > 0 { format!(", {} spp", f.spp) } else { String::new() };
                if text {
                    eprintln!(
                        "job {id}: {} pass {} of {} done{spp}{files}",
                        frame_label(f),
                        f.passes_done,
                        f.passes_total
                    );
                }
            }
            let Some(reported) = frames_reported.get_mut(i) else { continue };
            if !f.outputs.is_empty() && !*reported {
                *reported = true;
                bar.finish_with_message("merged");
                if text {
                    let names: Vec<&str> = f.outputs.iter().map(|o| o.name.as_str()).collect();
                    eprintln!("job {id}: {} done: {}", frame_label(f), names.join(", "));
                }
            }
        }
        // A done job's video comes a moment after its frames: wait for it (bounded).
        if job.state == JobState::Done && video_pending(&job) {
            let since = *video_since.get_or_insert_with(|| {
                if text {
                    eprintln!("job {id} ({}): frames done; waiting for the video", job.name);
                }
                Instant::now()
            });
            if let Some(bar) = &counts_bar {
                bar.set_message("encoding the video");
            }
            if since.elapsed() < VIDEO_WAIT {
                std::thread::sleep(POLL);
                continue;
            }
        }
        if job.state.is_final() {
            if let Some(bar) = &counts_bar {
                if job.state == JobState::Done {
                    bar.finish_with_message("done");
                } else {
                    bar.abandon_with_message(job.state.as_str().to_string());
                }
            }
            for bar in &frame_bars {
                if !bar.is_finished() {
                    bar.abandon_with_message(job.state.as_str().to_string());
                }
            }
            if text || bars {
                let secs = match (job.started_at, job.finished_at) {
                    (Some(s), Some(e)) => format!(" in {:.1} s", e - s),
                    _ => String::new(),
                };
                eprintln!("job {id} ({}): {}{secs}", job.name, job.state.as_str());
            }
            return Ok(job);
        }
        if text && last_text.elapsed() >= TEXT_PROGRESS_EVERY {
            last_text = Instant::now();
            let (done, total) = (work_done, work_total);
            let what = if job.samples_total > 0 { "samples" } else { "tiles" };
            if counts_bar.is_some() {
                eprintln!("job {id}: {}; {}% of {what}, {eta}", counts_line(&job), percent(done, total));
            } else {
                // Frames in passes finish their tiles late: say how far the passes are.
                let notes: Vec<String> = job
                    .frames
                    .iter()
                    .filter(|f| f.outputs.is_empty())
                    .map(|f| (f, pass_note(f)))
                    .filter(|(_, n)| !n.is_empty())
                    .map(|(f, n)| format!("{}: {n}", frame_label(f)))
                    .collect();
                let notes = if notes.is_empty() { String::new() } else { format!(" ({})", notes.join("; ")) };
                eprintln!("job {id}: {}% of {what} done, {eta}{notes}", percent(done, total));
            }
        }
        std::thread::sleep(POLL);
    }
}

/// Whether `name` is the float frame the farm keeps beside an LDR image (`<stem>.exr` for an
/// `ImageName` that is not `.exr` or `.hdr`): a file `tessera-worker render` does not write.
pub fn is_farm_extra(frame: &FrameInfo, name: &str) -> bool {
    let image = Path::new(&frame.image_name);
    let ext = image.extension().map(|e| e.to_string_lossy().to_ascii_lowercase());
    if matches!(ext.as_deref(), Some("exr" | "hdr")) {
        return false;
    }
    let stem = image.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    name == format!("{stem}.exr")
}

/// The outputs of `frame` to download: what `tessera-worker render` writes, and with `float`
/// the farm's float `.exr` of LDR frames too.
pub fn wanted_outputs(frame: &FrameInfo, float: bool) -> Vec<&OutputInfo> {
    frame.outputs.iter().filter(|o| float || !is_farm_extra(frame, &o.name)).collect()
}

/// Downloads the outputs of every finished frame of `job` into `out` (created), each file
/// written atomically. Frames not finished are an error after the others are downloaded.
pub fn download(api: &Api, job: &JobInfo, out: &Path, float: bool, quiet: bool) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(out)
        .map_err(|e| anyhow::anyhow!("cannot create the output directory {}: {e}", out.display()))?;
    let mut written = Vec::new();
    let mut unfinished = Vec::new();
    for f in &job.frames {
        if f.outputs.is_empty() {
            unfinished.push(format!("{} ({}/{} tiles)", frame_label(f), f.tiles_done, f.tiles_total));
            continue;
        }
        for o in wanted_outputs(f, float) {
            // A file name, never a path: the server's names must not write elsewhere.
            if Path::new(&o.name).file_name().map(|n| n.to_string_lossy() != o.name.as_str()).unwrap_or(true)
            {
                bail!(
                    "job {}: the server lists an output named {:?}, which is not a plain file name",
                    job.id,
                    o.name
                );
            }
            let what = format!("downloading {} of job {}", o.name, job.id);
            let url = format!("/api/v1/jobs/{}/frames/{}/files/{}", job.id, f.index, percent_encode(&o.name));
            let bytes = with_retries(quiet, || api.download(&what, &url))?;
            let path = out.join(&o.name);
            tessera::atomic_write::write_atomic(&path, &bytes)
                .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
            if !quiet {
                println!("{}", path.display());
            }
            written.push(path);
        }
    }
    if let Some(v) = &job.video {
        match (&v.url, v.state.as_str()) {
            (Some(url), "done") => {
                let name = url.rsplit('/').next().unwrap_or_default().to_string();
                if name.is_empty() || Path::new(&name).file_name().is_none_or(|n| n.to_string_lossy() != name)
                {
                    bail!(
                        "job {}: the server lists a video at {url:?}, which has no plain file name",
                        job.id
                    );
                }
                let what = format!("downloading the video of job {}", job.id);
                let bytes = with_retries(quiet, || api.download(&what, url))?;
                let path = out.join(&name);
                tessera::atomic_write::write_atomic(&path, &bytes)
                    .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
                if !quiet {
                    println!("{}", path.display());
                }
                written.push(path);
            }
            (_, "failed") => eprintln!(
                "job {}: no video: {}",
                job.id,
                v.message.as_deref().unwrap_or("its encoding failed (see tessera logs)")
            ),
            (_, state) if job.state == JobState::Done => {
                eprintln!("job {}: the video is not ready yet ({state}); fetch it again in a moment", job.id)
            }
            _ => {}
        }
    }
    if !unfinished.is_empty() {
        let n = unfinished.len();
        unfinished.truncate(5);
        if n > 5 {
            unfinished.push(format!("and {} more", n - 5));
        }
        // Waiting helps only a job that is still rendering: an ended one's missing frames never
        // come.
        let advice = match job.state {
            JobState::Queued | JobState::Running => {
                format!("wait for them with: tessera fetch {} --wait --out {}", job.id, out.display())
            }
            JobState::Paused => format!(
                "the job is paused; resume it (tessera resume {}) and wait for them with: tessera fetch {} --wait --out {}",
                job.id,
                job.id,
                out.display()
            ),
            JobState::Canceled => {
                "the job was cancelled before they were rendered; submit it again to render them".to_string()
            }
            JobState::Failed => format!(
                "the job failed before they were rendered ({}); see tessera logs {}",
                job.error.as_deref().unwrap_or("no reason given"),
                job.id
            ),
            JobState::Done => "the server lists them as done without outputs; see tessera logs".to_string(),
        };
        bail!(
            "job {} ({}) has frames without outputs: {}; {advice}",
            job.id,
            job.state.as_str(),
            unfinished.join(", "),
        );
    }
    Ok(written)
}

/// `s` as one URL path segment: every byte but the unreserved ones (RFC 3986) percent-encoded.
fn percent_encode(s: &str) -> String {
    let mut out = String::new();
    for b in s.bytes() {
        if b.is_ascii_alphanumeric() || b"-._~".contains(&b) {
            out.push(b as char);
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

/// Unix seconds as `YYYY-MM-DD HH:MM:SS` (UTC).
pub fn utc(secs: f64) -> String {
    let secs = secs.max(0.0) as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Howard Hinnant's civil_from_days.
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!("{y:04}-{m:02}-{d:02} {:02}:{:02}:{:02}", rem / 3600, rem % 3600 / 60, rem % 60)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(image_name: &str, outputs: &[&str]) -> FrameInfo {
        FrameInfo {
            index: 0,
            camera: 0,
            image_name: image_name.into(),
            width: 1,
            height: 1,
            tiles_total: 1,
            tiles_done: 1,
            outputs: outputs
                .iter()
                .map(|n| OutputInfo { name: n.to_string(), url: format!("/x/{n}") })
                .collect(),
            preview_url: String::new(),
            tonemap: None,
            tonemap_url: None,
            samples: 1,
            passes_total: 1,
            passes_done: 0,
            pass_outputs: Vec::new(),
            scene: None,
            samples_done: 0,
            samples_total: 0,
            samples_total_is_bound: false,
            spp: 0,
            pass: 0,
            pass_denoised_url: None,
        }
    }

    #[test]
    fn the_cli_files_leave_out_only_the_farms_float_frame() {
        let names = |f: &FrameInfo, float| {
            wanted_outputs(f, float).iter().map(|o| o.name.clone()).collect::<Vec<_>>()
        };
        let ldr = frame("out/a.png", &["a.png", "a.exr"]);
        assert_eq!(names(&ldr, false), ["a.png"]);
        assert_eq!(names(&ldr, true), ["a.png", "a.exr"]);
        let hdr = frame("a.exr", &["a.exr", "a.png", "a_aces.png"]);
        assert_eq!(names(&hdr, false), ["a.exr", "a.png", "a_aces.png"]);
        let rgbe = frame("a.HDR", &["a.HDR", "a.png"]);
        assert_eq!(names(&rgbe, false), ["a.HDR", "a.png"]);
        let odd = frame("a.ppm", &["a.png", "a.exr"]);
        assert_eq!(names(&odd, false), ["a.png"]);
    }

    #[test]
    fn sequences_and_long_jobs_are_shown_by_their_counts() {
        let job = |frames: usize, scenes: u32| JobInfo {
            id: 1,
            name: "a".into(),
            state: JobState::Running,
            priority: 0,
            tile_size: 64,
            samples: None,
            denoise: false,
            submitted_at: 0.0,
            started_at: None,
            finished_at: None,
            frames: (0..frames).map(|_| frame("a.png", &[])).collect(),
            frame_counts: tessera::protocol::FrameCounts { done: 5, rendering: 2, queued: 9 },
            scenes,
            video: None,
            samples_done: 0,
            samples_total: 0,
            samples_total_is_bound: false,
            error: None,
            warnings: Vec::new(),
            url: String::new(),
            worker_tags: Vec::new(),
            waiting_for: None,
        };
        assert!(!by_counts(&job(3, 1)));
        assert!(!by_counts(&job(16, 0)), "an older server's job: no scene count");
        assert!(by_counts(&job(2, 2)));
        assert!(by_counts(&job(17, 1)));
        assert!(by_counts(&job(0, 360)), "a long job listed without its frames");
        assert_eq!(counts_line(&job(0, 16)), "5/16 frames done, 2 rendering, 9 queued");
    }

    #[test]
    fn progress_counts_samples_and_says_the_pass_and_the_samples_per_pixel() {
        let mut f = frame("a.png", &[]);
        assert_eq!(frame_work(&f), (1, 1), "an older server: tiles");
        assert_eq!(pass_note(&f), "");
        (f.samples_done, f.samples_total, f.spp, f.pass, f.passes_total) = (6 * 16, 16 * 16, 96, 7, 16);
        assert_eq!(frame_work(&f), (96, 256));
        assert_eq!(percent(96, 256), 37);
        assert_eq!(percent(5, 0), 0);
        assert_eq!(pass_note(&f), "pass 7 of 16, 96 spp");
        f.passes_total = 1;
        assert_eq!(pass_note(&f), "96 spp");
        let secs = Duration::from_secs;
        assert_eq!(eta_text(0, 100, secs(5), false), "ETA unknown");
        assert_eq!(eta_text(25, 100, secs(10), false), "ETA 30 s");
        assert_eq!(eta_text(50, 100, secs(94), true), "ETA at most 1 min 34 s");
        assert_eq!(eta_text(100, 100, secs(94), false), "ETA 0 s");
        assert_eq!(duration_text(secs(7530)), "2 h 5 min");
    }

    #[test]
    fn file_names_are_one_path_segment() {
        assert_eq!(percent_encode("a b/c%.png"), "a%20b%2Fc%25.png");
        assert_eq!(percent_encode("VeachAjar_1-2~x.exr"), "VeachAjar_1-2~x.exr");
        assert_eq!(percent_encode("ü"), "%C3%BC");
    }

    #[test]
    fn utc_dates() {
        assert_eq!(utc(0.0), "1970-01-01 00:00:00");
        assert_eq!(utc(951_782_400.0), "2000-02-29 00:00:00");
        assert_eq!(utc(1_795_000_000.5), "2026-11-18 11:06:40");
    }
}
