//! Job-end notifications: when a job ends (done, failed or cancelled) the server POSTs a JSON
//! document to the operator's `--notify-url` and to the job's own `notify_url` (accepted only
//! under a prefix the operator allows with `--notify-allow`: a farm must not POST wherever a
//! client points it).
//!
//! Deliveries run on threads of their own, never on the server's runtime: a receiver that is
//! slow or down costs a thread for at most [`ATTEMPTS`] tries of [`TIMEOUT`] each, never a
//! request. The store records each job's outcome (`jobs.notified`) with an event in its log
//! (`notified` or `notify_failed`), so every job end is announced once; a server killed in the
//! middle of a delivery announces that job again after its restart (at least once).
//!
//! The document: `{"event": "job_done" | "job_failed" | "job_cancelled", "job": JobInfo}`, the
//! job as `GET /api/v1/jobs/ID` shows it (its URLs relative to the server), sent with
//! `Content-Type: application/json` and `User-Agent: tessera-server`. Any 2xx answer is a
//! delivery; redirects are not followed.

use std::collections::HashSet;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tessera::protocol::JobState;

use crate::db::Notified;
use crate::state::AppState;

/// Tries per receiver, with pauses of 1, 4 and 16 s between them.
pub const ATTEMPTS: u32 = 4;

/// Longest wait for a receiver's answer (connecting included).
pub const TIMEOUT: Duration = Duration::from_secs(10);

/// Deliveries under way at once; more ended jobs wait their turn.
const AT_ONCE: usize = 8;

/// Longest notification URL accepted.
pub const MAX_URL_BYTES: usize = 2048;

/// Whether `url` can be a notification receiver: `http://` or `https://` with a host, no
/// spaces or control characters, at most [`MAX_URL_BYTES`].
pub fn check_url(url: &str) -> Result<(), String> {
    let rest = url.strip_prefix("http://").or_else(|| url.strip_prefix("https://"));
    let host = rest.map(|r| r.split(['/', '?', '#']).next().unwrap_or(""));
    if url.len() > MAX_URL_BYTES {
        return Err(format!("is longer than {MAX_URL_BYTES} bytes"));
    }
    if url.chars().any(|c| c.is_whitespace() || c.is_control()) {
        return Err("holds a space or a control character".into());
    }
    match host {
        Some(h) if !h.is_empty() && !h.contains('@') => Ok(()),
        Some(_) => Err("needs a host after the scheme, without user information (user@)".into()),
        None => Err("must start with http:// or https://".into()),
    }
}

/// Whether a job may ask for `url`: it starts with one of `allow`, the prefix ending at a
/// boundary of the URL (`https://hooks.example/ci` allows `https://hooks.example/ci/7` and
/// `https://hooks.example/ci?x`, not `https://hooks.example/cia` or a longer host name).
pub fn allowed(url: &str, allow: &[String]) -> bool {
    check_url(url).is_ok()
        && allow.iter().any(|p| {
            url.strip_prefix(p.as_str())
                .is_some_and(|rest| rest.is_empty() || p.ends_with('/') || rest.starts_with(['/', '?', '#']))
        })
}

/// The event name of a job's end.
fn event_of(state: JobState) -> &'static str {
    match state {
        JobState::Done => "job_done",
        JobState::Failed => "job_failed",
        _ => "job_cancelled",
    }
}

/// How the document's `job` is made: the API's view of a job (`api::job_info`, handed in by
/// `serve`, so that this module does not import the API that imports it).
pub type JobView = fn(&AppState, u64) -> anyhow::Result<Option<tessera::protocol::JobInfo>>;

/// Starts the thread that finds ended jobs to announce (once a second) and hands each to a
/// delivery thread of its own.
pub fn spawn(state: AppState, operator_url: Option<String>, job_view: JobView) {
    let in_flight: Arc<Mutex<HashSet<u64>>> = Arc::default();
    let spawned = std::thread::Builder::new().name("notify".into()).spawn(move || {
        loop {
            match state.store.due_notifications(64) {
                Ok(due) => {
                    for d in due {
                        let mut busy = in_flight.lock().unwrap_or_else(|e| e.into_inner());
                        if busy.len() >= AT_ONCE || busy.contains(&d.job) {
                            continue;
                        }
                        busy.insert(d.job);
                        let (state, in_flight, operator_url) =
                            (state.clone(), in_flight.clone(), operator_url.clone());
                        let started =
                            std::thread::Builder::new().name("notify-job".into()).spawn(move || {
                                let outcome = deliver(
                                    &state,
                                    job_view,
                                    d.job,
                                    d.state,
                                    operator_url.as_deref(),
                                    d.url.as_deref(),
                                );
                                if let Err(e) = state.store.notification_sent(d.job, outcome) {
                                    tracing::warn!(
                                        job = d.job,
                                        "cannot record the job's notification: {e:#}"
                                    );
                                }
                                in_flight.lock().unwrap_or_else(|e| e.into_inner()).remove(&d.job);
                            });
                        if started.is_err() {
                            busy.remove(&d.job);
                        }
                    }
                }
                Err(e) => tracing::warn!("cannot read the jobs to announce: {e:#}"),
            }
            std::thread::sleep(Duration::from_secs(1));
        }
    });
    if let Err(e) = spawned {
        tracing::error!("cannot start the notification thread: {e}; job ends will not be announced");
    }
}

/// POSTs the end of `job` to every receiver, each tried up to [`ATTEMPTS`] times.
fn deliver(
    state: &AppState,
    job_view: JobView,
    job: u64,
    end: JobState,
    operator: Option<&str>,
    own: Option<&str>,
) -> Notified {
    let mut receivers: Vec<&str> = operator.into_iter().collect();
    if let Some(u) = own.filter(|u| !receivers.contains(u)) {
        receivers.push(u);
    }
    if receivers.is_empty() {
        return Notified::NoReceiver;
    }
    let info = match job_view(state, job) {
        Ok(Some(info)) => info,
        Ok(None) => return Notified::GaveUp("the job is gone".into()),
        Err(e) => return Notified::GaveUp(format!("cannot read the job: {e:#}")),
    };
    let body = serde_json::json!({ "event": event_of(end), "job": info }).to_string();
    let agent = ureq::AgentBuilder::new()
        .timeout_connect(TIMEOUT)
        .timeout(TIMEOUT)
        .redirects(0)
        .user_agent("tessera-server")
        .build();
    let mut failed = Vec::new();
    for url in &receivers {
        let mut last_error = String::new();
        let mut ok = false;
        for attempt in 0..ATTEMPTS {
            if attempt > 0 {
                std::thread::sleep(Duration::from_secs(4u64.pow(attempt - 1)));
            }
            match agent.post(url).set("Content-Type", "application/json").send_string(&body) {
                Ok(r) if (200..300).contains(&r.status()) => {
                    ok = true;
                    break;
                }
                Ok(r) => last_error = format!("answered HTTP {}", r.status()),
                Err(ureq::Error::Status(code, _)) => last_error = format!("answered HTTP {code}"),
                Err(ureq::Error::Transport(t)) => last_error = format!("cannot be reached: {t}"),
            }
        }
        if !ok {
            tracing::warn!(job, "the job's end notification to {url} failed {ATTEMPTS} times: {last_error}");
            failed.push(format!("{url} {last_error} ({ATTEMPTS} tries)"));
        }
    }
    if failed.is_empty() {
        Notified::Delivered(format!("{} POSTed to {}", event_of(end), receivers.join(" and ")))
    } else {
        Notified::GaveUp(format!("notification not delivered: {}", failed.join("; ")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_job_url_must_lie_under_an_allowed_prefix_at_a_boundary() {
        let allow = vec!["https://hooks.example/ci".to_string(), "http://10.0.0.5:9000/".to_string()];
        assert!(allowed("https://hooks.example/ci", &allow));
        assert!(allowed("https://hooks.example/ci/7", &allow));
        assert!(allowed("https://hooks.example/ci?job=7", &allow));
        assert!(allowed("http://10.0.0.5:9000/anything", &allow));
        assert!(!allowed("https://hooks.example/cia", &allow));
        assert!(!allowed("https://hooks.example.evil/ci", &allow));
        assert!(!allowed("http://169.254.169.254/latest/meta-data", &allow));
        assert!(!allowed("https://hooks.example/ci/ x", &allow), "spaces");
        assert!(!allowed("https://hooks.example/ci", &[]), "nothing is allowed by default");
    }

    #[test]
    fn receivers_are_http_urls_with_a_host() {
        assert!(check_url("http://127.0.0.1:8000/hook").is_ok());
        assert!(check_url("https://hooks.example").is_ok());
        assert!(check_url("ftp://x/").is_err());
        assert!(check_url("http:///path").is_err());
        assert!(check_url("http://user:pw@host/").is_err());
        assert!(check_url("http://host/\nX-Injected: 1").is_err());
        assert!(check_url(&format!("http://h/{}", "a".repeat(MAX_URL_BYTES))).is_err());
    }
}
