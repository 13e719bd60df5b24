//! Sending a packed job by content: ask the server which files it lacks
//! (`POST /api/v1/files/missing`), upload only those (`PUT /api/v1/files/{sha256}`, streamed from
//! disk), then submit the job as JSON (`POST /api/v1/jobs`, a [`JobRequest`] naming every file
//! by path and SHA-256). A file the server already has, from this job's other frames or from
//! another job, is not sent again.

use std::collections::HashMap;
use std::io::Read;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use tessera::protocol::{JobInfo, JobRequest, MissingFilesRequest};

use crate::api::{Api, CallError};
use crate::pack::Packed;

/// Without a terminal, a progress line at most this often while uploading.
const TEXT_PROGRESS_EVERY: Duration = Duration::from_secs(10);

/// What was sent.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Sent {
    /// Distinct files uploaded, and their bytes.
    pub files: usize,
    pub bytes: u64,
    /// Distinct files of the job, and their bytes.
    pub total_files: usize,
    pub total_bytes: u64,
    /// Seconds spent asking and uploading, and waiting for the server to accept the job.
    pub upload_seconds: f64,
    pub submit_seconds: f64,
}

impl std::fmt::Display for Sent {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "uploaded {} of {} files, {} bytes (the server had the other {} files, {} bytes)",
            self.files,
            self.total_files,
            self.bytes,
            self.total_files - self.files,
            self.total_bytes - self.bytes
        )
    }
}

/// How the server took the job.
pub enum Submitted {
    Job(Box<JobInfo>, Sent),
    /// The server has no content-addressed files (404/405 on `files/missing`): it is older.
    OldServer,
}

/// Whether a failed call means the server does not know the route.
fn unknown_route(e: &CallError) -> bool {
    matches!(e, CallError::Status { code: 404 | 405, .. })
}

/// Uploads what the server lacks of `packed`; `bars`: a progress bar on stderr; `text`: lines.
fn upload_missing(api: &Api, packed: &Packed, bars: bool, text: bool, sent: &mut Sent) -> Result<bool> {
    let asked = MissingFilesRequest { files: packed.digests() };
    let missing = match api.missing_files(&asked) {
        Ok(m) => m.missing,
        Err(e) if unknown_route(&e) => return Ok(false),
        Err(e) => return Err(e.into()),
    };
    let by_sha: HashMap<&str, usize> =
        packed.distinct.iter().enumerate().map(|(i, d)| (d.sha256.as_str(), i)).collect();
    let mut todo = Vec::new();
    for sha in &missing {
        let Some(&i) = by_sha.get(sha.as_str()) else {
            bail!("the server asked for a file this job does not have ({sha}); is it a tessera-server?");
        };
        if !todo.contains(&i) {
            todo.push(i);
        }
    }
    let total: u64 = todo.iter().map(|&i| packed.distinct[i].size).sum();
    let bar = bars.then(|| {
        let bar = ProgressBar::new(total);
        bar.set_style(
            ProgressStyle::with_template("uploading [{bar:30}] {bytes}/{total_bytes}, {bytes_per_sec} {msg}")
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> "),
        );
        bar
    });
    let mut done = 0u64;
    let mut last_line = Instant::now();
    for (n, &i) in todo.iter().enumerate() {
        let d = &packed.distinct[i];
        let file =
            std::fs::File::open(&d.source).with_context(|| format!("cannot read {}", d.source.display()))?;
        let what = format!("uploading {}", d.source.display());
        let body = file.take(d.size);
        let result = match &bar {
            Some(bar) => {
                bar.set_message(format!("file {} of {}", n + 1, todo.len()));
                api.put_file(&what, &d.sha256, d.size, bar.wrap_read(body))
            }
            None => api.put_file(&what, &d.sha256, d.size, body),
        };
        if let Err(e) = result {
            if let Some(bar) = &bar {
                bar.abandon();
            }
            if let CallError::Status { code: 400, .. } = e {
                bail!("{e}\n  did {} change since it was read? submit again", d.source.display());
            }
            return Err(e.into());
        }
        done += d.size;
        sent.files += 1;
        sent.bytes += d.size;
        if text && (last_line.elapsed() >= TEXT_PROGRESS_EVERY || n + 1 == todo.len()) && total >= 16 << 20 {
            last_line = Instant::now();
            eprintln!("uploading: {done} of {total} bytes sent ({} of {} files)", n + 1, todo.len());
        }
    }
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    Ok(true)
}

/// Uploads what the server lacks and submits `request` (its `scenes` and `files` are set here).
pub fn submit(
    api: &Api,
    packed: &Packed,
    mut request: JobRequest,
    bars: bool,
    text: bool,
) -> Result<Submitted> {
    request.scenes = packed.scenes.iter().map(|s| s.path.clone()).collect();
    request.files = packed.job_files();
    let mut sent =
        Sent { total_files: packed.distinct.len(), total_bytes: packed.total_bytes(), ..Sent::default() };
    let started = Instant::now();
    if !upload_missing(api, packed, bars, text, &mut sent)? {
        return Ok(Submitted::OldServer);
    }
    sent.upload_seconds = started.elapsed().as_secs_f64();
    let started = Instant::now();
    let answer = api.submit_json(&request);
    sent.submit_seconds = started.elapsed().as_secs_f64();
    match answer {
        Ok(job) => Ok(Submitted::Job(Box::new(job), sent)),
        // A file went from the store between the upload and the submission (an unreferenced
        // upload is removed after a grace period): send what it lacks again, once.
        Err(CallError::Status { code: 409, .. }) => {
            upload_missing(api, packed, bars, text, &mut sent)?;
            Ok(Submitted::Job(Box::new(api.submit_json(&request)?), sent))
        }
        Err(e) => Err(e.into()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_summary_says_what_was_sent_and_what_the_server_had() {
        let sent = Sent { files: 3, bytes: 1200, total_files: 4, total_bytes: 2_000_000, ..Sent::default() };
        assert_eq!(
            sent.to_string(),
            "uploaded 3 of 4 files, 1200 bytes (the server had the other 1 files, 1998800 bytes)"
        );
    }
}
