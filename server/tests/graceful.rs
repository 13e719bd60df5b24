//! Stopping a worker gracefully: SIGTERM makes `tessera-worker work` finish and upload the tile it
//! renders, give back (`POST /api/v1/worker/leases/{lease}/release`) the lease it fetched ahead
//! and exit with status 0; the job completes through another worker without any lease expiring.

mod support;

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use support::*;

const TOKEN: &str = "wtok";
const SAMPLES: &str = "16";
/// Samples for the test whose signal must find the worker inside a tile: at 16 a tile of the
/// environment scene renders in about a millisecond, no longer than the lease and upload
/// round trips around it, so the signal often fell between two tiles; at 256 the render is
/// most of a tile's time.
const SIGTERM_SAMPLES: &str = "256";

fn post(url: &str, path: &str, body: Value) -> (u16, Value) {
    worker_post(url, TOKEN, path, body)
}

fn job(server: &Server, id: u64) -> Value {
    get_json(&server.url, &format!("/api/v1/jobs/{id}"))
}

fn wait_until(server: &Server, what: &str, secs: u64, mut f: impl FnMut() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(secs);
    while !f() {
        assert!(
            Instant::now() < deadline,
            "timed out waiting for {what}\n--- server log ---\n{}",
            server.log()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn release_gives_a_live_lease_back_to_the_queue_once() {
    let _s = serial();
    let data = TempDir::new("farm-release");
    let server = Server::start(&data, &["--local-workers", "0", "--worker-token", TOKEN]);
    submit_environment(&server, "1", "64");
    let (_, reg) = post(&server.url, "/api/v1/worker/register", json!({"name": "h", "threads": 1}));
    let w = reg["worker_id"].as_u64().unwrap();
    let lease = || {
        let (code, l) =
            post(&server.url, "/api/v1/worker/lease", json!({"worker_id": w, "wait_seconds": 0.0}));
        assert_eq!(code, 200, "{l}");
        l
    };
    let first = lease();
    let id = first["lease_id"].as_u64().unwrap();
    let release = |lease: u64, worker: u64| {
        post(&server.url, &format!("/api/v1/worker/leases/{lease}/release"), json!({"worker_id": worker})).0
    };
    // Another worker's lease, not a lease at all: 409, and the lease stays; no such worker: 404.
    let (_, other) = post(&server.url, "/api/v1/worker/register", json!({"name": "o", "threads": 1}));
    assert_eq!(release(id, other["worker_id"].as_u64().unwrap()), 409);
    assert_eq!(release(id + 1000, w), 409);
    assert_eq!(release(id, w + 1000), 404);
    // Without the worker token: refused.
    let (code, _) = call(
        ureq::post(&format!("{}/api/v1/worker/leases/{id}/release", server.url)),
        Some(("application/json".into(), json!({"worker_id": w}).to_string().into_bytes())),
    );
    assert_eq!(code, 401);
    assert_eq!(release(id, w), 204);
    assert_eq!(release(id, w), 409, "a lease is given back once");
    // The same tile is handed out again at once, under a new lease.
    let again = lease();
    assert_eq!(again["tile"], first["tile"], "{again} vs {first}");
    assert_ne!(again["lease_id"], first["lease_id"]);
    assert_eq!(metric(&server, "tessera_lease_expiries_total"), "0");
}

#[test]
fn a_worker_given_sigterm_mid_job_finishes_its_tile_gives_back_the_next_and_exits_0() {
    let _s = serial();
    let data = TempDir::new("farm-sigterm");
    // Leases live ten minutes: a tile that was not given back would hold the job up far longer
    // than this test waits.
    let server = Server::start(
        &data,
        &[
            "--local-workers",
            "0",
            "--worker-token",
            TOKEN,
            "--lease-seconds",
            "600",
            "--heartbeat-seconds",
            "0.5",
        ],
    );
    let id = submit_environment(&server, SAMPLES, "32");

    let log = data.join("worker-a.log");
    let mut a = Command::new(worker_bin())
        .args(["work", "--server", &server.url, "--token", TOKEN, "--name", "a", "--threads", "1"])
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log).unwrap())
        .spawn()
        .expect("start tessera-worker work");
    wait_until(&server, "worker a's first tiles", 120, || tiles_done(&job(&server, id)) >= 2);
    let total = job(&server, id)["frames"][0]["tiles_total"].as_u64().unwrap();
    signal(&a, libc::SIGTERM);
    let signalled = Instant::now();
    let exit = loop {
        if let Some(s) = a.try_wait().unwrap() {
            break s;
        }
        if signalled.elapsed() > Duration::from_secs(15) {
            let _ = a.kill();
            panic!(
                "the worker did not stop within 15 s of SIGTERM:\n{}",
                std::fs::read_to_string(&log).unwrap()
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let worker_log = std::fs::read_to_string(&log).unwrap();
    assert!(exit.success(), "worker exit {exit:?}:\n{worker_log}");
    // Whether the worker held a lease fetched ahead depends on where the signal found its
    // fetcher (just after handing one over, it holds none); when it held one it must have given
    // it back, which the probe below checks: no tile may still be leased to the stopped worker.
    let after = job(&server, id);
    assert!(
        tiles_done(&after) < total,
        "the job finished before the signal; the test proves nothing: {after}"
    );
    // Every tile not done is in the queue again: a hand-driven worker gets a lease on each (none
    // is still held by the stopped worker), then gives them all back.
    let (_, reg) = post(&server.url, "/api/v1/worker/register", json!({"name": "probe", "threads": 1024}));
    let probe = reg["worker_id"].as_u64().unwrap();
    let mut queued = Vec::new();
    loop {
        let (code, l) =
            post(&server.url, "/api/v1/worker/lease", json!({"worker_id": probe, "wait_seconds": 0.0}));
        if code != 200 {
            assert_eq!(code, 204, "{l}");
            break;
        }
        queued.push(l["lease_id"].as_u64().unwrap());
    }
    assert_eq!(
        queued.len() as u64,
        total - tiles_done(&job(&server, id)),
        "a tile is still leased to the stopped worker\n{worker_log}"
    );
    for l in queued {
        let (code, v) =
            post(&server.url, &format!("/api/v1/worker/leases/{l}/release"), json!({"worker_id": probe}));
        assert_eq!(code, 204, "{v}");
    }

    // Another worker finishes the job, long before any lease could expire.
    let _b = Worker::start(&server.url, TOKEN, "b");
    wait_until(&server, "the job to finish on worker b", 240, || job(&server, id)["state"] == "done");
    assert_eq!(metric(&server, "tessera_lease_expiries_total"), "0");
    assert_eq!(metric(&server, "tessera_results_refused_total"), "0");
    assert_eq!(metric(&server, "tessera_tiles_done_total"), total.to_string());

    // Byte for byte what the CLI renders.
    let (exr, png) = cli_render_environment(SAMPLES);
    for (name, cli) in [("environment.exr", exr), ("environment.png", png)] {
        let farm = get_bytes(&server.url, &format!("/api/v1/jobs/{id}/frames/0/files/{name}"));
        assert!(farm == cli, "the farm's {name} differs from the CLI's");
    }
}

#[test]
fn a_server_given_sigterm_lets_its_local_worker_finish_then_resumes_the_job_after_restart() {
    let _s = serial();
    let data = TempDir::new("farm-server-sigterm");
    let args = ["--local-workers", "1", "--local-worker-threads", "1", "--worker-token", TOKEN];
    let mut server = Server::start(&data, &args);
    let id = submit_environment(&server, SIGTERM_SAMPLES, "32");
    let total =
        wait_job(&server, id, 120, |j| tiles_done(j) >= 2)["frames"][0]["tiles_total"].as_u64().unwrap();
    // The worker renders without pause, so the signal finds it inside a tile.
    let at_signal = tiles_done(&job(&server, id));
    signal(&server.child, libc::SIGTERM);
    let limit = tessera_server::LOCAL_WORKER_GRACE + Duration::from_secs(10);
    let status = wait_timeout(&mut server.child, limit);
    let log = server.log();
    assert!(
        status.is_some_and(|s| s.success()),
        "the server did not exit 0 within {limit:?}: {status:?}\n{log}"
    );
    // The worker was told once (SIGTERM, not SIGKILL) and exited by itself with status 0, and
    // nothing was killed. (Whether it also had a lease fetched ahead to give back depends on
    // where the signal found it; the worker's own SIGTERM test above checks that part.)
    assert!(log.contains("local worker stopped worker=1 status=exit status: 0"), "{log}");
    assert!(!log.contains("killed"), "{log}");
    let pid: u32 = log
        .lines()
        .find(|l| l.contains("local worker started"))
        .and_then(|l| l.split("pid=").nth(1))
        .and_then(|rest| rest.split(|c: char| !c.is_ascii_digit()).next())
        .and_then(|p| p.parse().ok())
        .unwrap_or_else(|| panic!("no worker pid in the log:\n{log}"));
    assert!(!Path::new(&format!("/proc/{pid}")).exists(), "local worker {pid} outlived the server");

    // Restarted on the same data, the farm keeps every tile it took and finishes the job exactly
    // as the CLI renders it.
    drop(server);
    let server = Server::start(&data, &["--local-workers", "0", "--worker-token", TOKEN]);
    let resumed = tiles_done(&job(&server, id));
    assert!(resumed < total, "the job finished before the signal; the test proves nothing");
    assert!(
        resumed > at_signal,
        "the tile in progress at the signal was not kept ({resumed} tiles done, {at_signal} before the signal)"
    );
    let _w = Worker::start(&server.url, TOKEN, "after-restart");
    wait_job(&server, id, 240, |j| j["state"] == "done");
    let (exr, png) = cli_render_environment(SIGTERM_SAMPLES);
    for (name, cli) in [("environment.exr", exr), ("environment.png", png)] {
        let farm = get_bytes(&server.url, &format!("/api/v1/jobs/{id}/frames/0/files/{name}"));
        assert!(farm == cli, "the farm's {name} differs from the CLI's");
    }
}
