//! The client's manners with the real farm: output cut off by its reader ends it quietly.

mod support;

use std::io::{BufRead, BufReader};
use std::os::unix::process::ExitStatusExt;
use std::process::{Command, Stdio};
use std::time::Duration;

use support::*;

/// `tessera logs ID --follow | head -1`: the client stops when its reader goes, without a
/// panic (it used to end with "failed printing to stdout: Broken pipe" and status 101).
#[test]
fn a_closed_pipe_ends_the_client_quietly() {
    let _serial = serial();
    let server = Server::start_temp("client-pipe", &["--local-workers", "1", "--local-worker-threads", "1"]);
    // Many small tiles: the log keeps growing while the client follows it.
    let id = submit_environment(&server, "64", "8");
    let mut child = Command::new(client_bin())
        .args(["logs", &id.to_string(), "--follow"])
        .env("TESSERA_SERVER", &server.url)
        .env_remove("TESSERA_TOKEN")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run tessera logs");
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let mut first = String::new();
    out.read_line(&mut first).unwrap();
    assert!(first.contains("accepted"), "{first}");
    drop(out);
    let status = wait_timeout(&mut child, Duration::from_secs(60)).unwrap_or_else(|| {
        let _ = child.kill();
        panic!("the client went on after its reader closed the pipe")
    });
    let mut err = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut err).unwrap();
    assert!(!err.contains("panicked") && !err.contains("Broken pipe"), "{err}");
    assert_eq!(status.signal(), Some(libc::SIGPIPE), "{status:?}: {err}");
}

/// `tessera fetch` of a cancelled job says its frames will not come, instead of advising
/// `--wait` (which would return at once with the same error).
#[test]
fn fetching_a_cancelled_job_says_why_nothing_comes() {
    let _serial = serial();
    let server = Server::start_temp("client-fetch-cancelled", &["--local-workers", "0"]);
    let id = submit_environment(&server, "64", "8");
    assert_eq!(cancel(&server, id).0, 200);
    let out = TempDir::new("client-fetch-cancelled-out");
    let run = Command::new(client_bin())
        .args(["fetch", &id.to_string(), "--out"])
        .arg(out.path())
        .env("TESSERA_SERVER", &server.url)
        .env_remove("TESSERA_TOKEN")
        .output()
        .expect("run tessera fetch");
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("cancelled") && err.contains("submit it again"), "{err}");
    assert!(!err.contains("--wait"), "{err}");
}

/// Ctrl-C while `--wait` follows a job stops the client (status 130) and says the job goes on
/// and how to follow it again.
#[test]
fn ctrl_c_while_waiting_says_the_job_goes_on() {
    let _serial = serial();
    // No worker: the job stays queued while the client follows it.
    let server = Server::start_temp("client-ctrl-c", &["--local-workers", "0"]);
    let id = submit_environment(&server, "1", "64");
    let out = TempDir::new("client-ctrl-c-out");
    let mut child = Command::new(client_bin())
        .args(["fetch", &id.to_string(), "--wait", "--out"])
        .arg(out.path())
        .env("TESSERA_SERVER", &server.url)
        .env_remove("TESSERA_TOKEN")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run tessera fetch --wait");
    // Let it start following.
    std::thread::sleep(Duration::from_millis(1500));
    signal(&child, libc::SIGINT);
    let status = wait_timeout(&mut child, Duration::from_secs(10)).expect("the client ignored Ctrl-C");
    let mut err = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut err).unwrap();
    assert_eq!(status.code(), Some(130), "{status:?}: {err}");
    assert!(
        err.contains("goes on rendering") && err.contains(&format!("tessera fetch {id} --wait")),
        "{err}"
    );
    // The job did go on: it is still queued, not cancelled.
    assert_eq!(get_json(&server.url, &format!("/api/v1/jobs/{id}"))["state"], "queued");
}
