//! `tessera pause`, `resume`, `requeue` and `priority`: a job changed after its submission.
//! Frames are numbered from 0, as the job's JSON (`frames[].index`) and `tessera status`
//! number them.

use anyhow::{Result, anyhow};
use serde_json::json;
use tessera::protocol::{JobInfo, JobState};

use crate::api::Api;

pub fn pause(api: &Api, id: u64) -> Result<()> {
    let job =
        api.change_job(&format!("pausing job {id}"), "POST", &format!("/api/v1/jobs/{id}/pause"), None)?;
    println!(
        "job {id} ({}) paused: no more of its tiles are handed out; tiles being rendered finish and are kept. \
         Resume it with: tessera resume {id}",
        job.name
    );
    Ok(())
}

pub fn resume(api: &Api, id: u64) -> Result<()> {
    let job =
        api.change_job(&format!("resuming job {id}"), "POST", &format!("/api/v1/jobs/{id}/resume"), None)?;
    println!("job {id} ({}) resumed: {}", job.name, job.state.as_str());
    Ok(())
}

/// Checks `--frames` before anything is sent: the same syntax the server reads.
pub fn check_frames(text: &str) -> Result<String, String> {
    tessera::protocol::parse_frame_list(text).map(|_| text.to_string())
}

pub fn requeue(api: &Api, id: u64, frames: Option<&str>) -> Result<()> {
    let body = frames.map(|f| json!({ "frames": f }));
    let job = api.change_job(
        &format!("requeueing job {id}"),
        "POST",
        &format!("/api/v1/jobs/{id}/requeue"),
        body.as_ref(),
    )?;
    println!("job {id} ({}) requeued: {}", job.name, what_renders(&job));
    println!("follow it with: tessera fetch {id} --wait --out DIR (or tessera logs {id} --follow)");
    Ok(())
}

/// The frames of a requeued job that render again (those without outputs), when listed.
fn what_renders(job: &JobInfo) -> String {
    if job.frames.is_empty() {
        let c = &job.frame_counts;
        return format!("{} frame(s) render again, {} kept", c.queued + c.rendering, c.done);
    }
    let again: Vec<u32> = job.frames.iter().filter(|f| f.outputs.is_empty()).map(|f| f.index).collect();
    let kept = job.frames.len() - again.len();
    format!(
        "frame(s) {} render again (numbered from 0), {kept} kept",
        tessera::protocol::frame_ranges(&again)
    )
}

pub fn priority(api: &Api, id: u64, priority: i64) -> Result<()> {
    let job = api.change_job(
        &format!("changing the priority of job {id}"),
        "PATCH",
        &format!("/api/v1/jobs/{id}"),
        Some(&json!({ "priority": priority })),
    )?;
    if job.priority != priority {
        return Err(anyhow!("job {id}: the server kept priority {} instead of {priority}", job.priority));
    }
    let when = if job.state == JobState::Paused { " once resumed" } else { "" };
    println!("job {id} ({}): priority {priority}; its next tiles are handed out by it{when}", job.name);
    Ok(())
}
