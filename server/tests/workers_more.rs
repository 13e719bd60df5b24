//! Workers over time, against the real binaries: a restarted server's local worker is the same
//! row; a job nobody can serve says so (the job's JSON, the client) and renders once a worker
//! comes; workers declare tags and jobs ask for them; silent workers leave the list after
//! `--forget-workers-after`.

mod support;

use std::io::Read;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use support::*;

const TOKEN: &str = "wtok";

fn workers(url: &str) -> Vec<Value> {
    get_json(url, "/api/v1/workers")["workers"].as_array().unwrap().clone()
}

fn register(url: &str, name: &str, tags: &[&str]) -> (u16, Value) {
    worker_post(url, TOKEN, "/api/v1/worker/register", json!({"name": name, "threads": 2, "tags": tags}))
}

/// Polls `f` every 50 ms until it gives `Some`, for at most `secs` seconds.
fn within<T>(secs: u64, what: &str, server: &Server, mut f: impl FnMut() -> Option<T>) -> T {
    let deadline = Instant::now() + Duration::from_secs(secs);
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(Instant::now() < deadline, "{what} within {secs} s\n{}", server.log());
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A worker process with tags, its stderr kept.
fn tagged_worker(url: &str, name: &str, tags: &str) -> Worker {
    let child = Command::new(worker_bin())
        .args(["work", "--server", url, "--token", TOKEN, "--name", name, "--threads", "1", "--tags", tags])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start tessera-worker work");
    Worker(child)
}

#[test]
fn a_restarted_servers_local_worker_is_the_same_row() {
    let _serial = serial();
    let data = TempDir::new("workers-local-row");
    let local_rows =
        |url: &str| -> Vec<Value> { workers(url).into_iter().filter(|w| w["name"] == "local-1").collect() };
    let start = || {
        let server = Server::start(&data, &["--local-workers", "1", "--local-worker-threads", "1"]);
        within(60, "local-1 registered", &server, || {
            local_rows(&server.url).iter().any(|w| w["state"] != "lost").then_some(())
        });
        server
    };
    let first_id = {
        let server = start();
        let job = submit_environment(&server, "1", "64");
        wait_job(&server, job, 120, |j| j["state"] == "done");
        local_rows(&server.url)[0]["id"].as_u64().unwrap()
    };
    for restart in 1..=2 {
        let server = start();
        let rows = local_rows(&server.url);
        assert_eq!(rows.len(), 1, "restart {restart}: a ghost local-1 beside the live one: {rows:?}");
        assert_eq!(rows[0]["id"].as_u64(), Some(first_id), "restart {restart}: the same row");
        assert!(rows[0]["tiles_done"].as_u64().unwrap() >= 1, "its history is kept: {rows:?}");
        // And it works: a job renders on it.
        let job = submit_environment(&server, "1", "64");
        wait_job(&server, job, 120, |j| j["state"] == "done");
        assert_eq!(workers(&server.url).len(), 1, "one worker in all");
    }
}

/// A farm with no worker: within seconds the job's JSON and the client following it say so,
/// once; a worker that comes renders it and the notice goes.
#[test]
fn a_job_nobody_can_serve_says_so_until_a_worker_comes() {
    let _serial = serial();
    let server = Server::start_temp("workers-nobody", &["--local-workers", "0", "--worker-token", TOKEN]);
    let out = TempDir::new("workers-nobody-out");
    let started = Instant::now();
    let mut client = Command::new(client_bin())
        .arg("--server")
        .arg(&server.url)
        .arg("submit")
        .arg(repo().join("scenes/environment.xml"))
        .args(["--samples", "1", "--tile-size", "64", "--wait", "--out"])
        .arg(out.path())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = client.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    let reader = std::thread::spawn(move || {
        let mut all = String::new();
        let mut lines = std::io::BufReader::new(stderr);
        let mut line = String::new();
        while std::io::BufRead::read_line(&mut lines, &mut line).unwrap_or(0) > 0 {
            let _ = tx.send(line.clone());
            all.push_str(&line);
            line.clear();
        }
        all
    });
    // The client says it within seconds.
    let said = within(20, "the client's notice", &server, || {
        rx.try_iter().find(|l| l.contains("waits: no worker is connected"))
    });
    let waited = started.elapsed();
    assert!(said.contains("tessera-worker work --server URL --token TOKEN"), "{said}");
    let jobs = get_json(&server.url, "/api/v1/jobs");
    let job = &jobs["jobs"][0];
    let id = job["id"].as_u64().unwrap();
    assert_eq!(job["state"], "queued");
    let why = job["waiting_for"].as_str().unwrap_or_else(|| panic!("no waiting_for: {job}"));
    assert!(why.starts_with("no worker is connected"), "{why}");
    assert!(!why.contains(&server.url) && !why.contains('/'), "no path or address in it: {why}");
    // The client's status says it too.
    let status = Command::new(client_bin())
        .args(["--server", &server.url, "status", &id.to_string()])
        .output()
        .unwrap();
    let status = String::from_utf8_lossy(&status.stdout);
    assert!(status.contains("waiting: no worker is connected"), "{status}");
    let list = Command::new(client_bin()).args(["--server", &server.url, "status"]).output().unwrap();
    let list = String::from_utf8_lossy(&list.stdout);
    assert!(list.contains(&format!("job {id} waits: no worker is connected")), "{list}");
    // A few more polls of the client, then a worker comes.
    std::thread::sleep(Duration::from_secs(2));
    let _worker = Worker::start(&server.url, TOKEN, "late");
    let code = within(120, "the client to finish", &server, || client.try_wait().unwrap());
    let mut stdout = String::new();
    client.stdout.take().unwrap().read_to_string(&mut stdout).unwrap();
    let stderr = reader.join().unwrap();
    assert!(code.success(), "{stderr}\n{stdout}");
    assert_eq!(
        stderr.matches("waits: no worker is connected").count(),
        1,
        "said once, not every poll:\n{stderr}"
    );
    assert!(out.path().join("environment.png").exists(), "{stdout}");
    let done = get_json(&server.url, &format!("/api/v1/jobs/{id}"));
    assert_eq!(done["state"], "done");
    assert!(done.get("waiting_for").is_none(), "{done}");
    eprintln!("the client said why the job waited {:.1} s after it started", waited.as_secs_f64());
}

/// Workers declare tags, jobs ask for them: a job is leased only to a worker that has all its
/// tags; until one is connected the job says which tags are missing. Bad tags are refused with
/// the field or flag named.
#[test]
fn jobs_with_worker_tags_go_only_to_workers_with_those_tags() {
    let _serial = serial();
    let server = Server::start_temp(
        "workers-tags",
        &["--local-workers", "0", "--worker-token", TOKEN, "--heartbeat-seconds", "0.5"],
    );
    let url = &server.url;
    let _gpu = tagged_worker(url, "gpu-box", "GPU");
    within(30, "gpu-box registered", &server, || {
        workers(url).iter().find(|w| w["name"] == "gpu-box").map(|w| assert_eq!(w["tags"], json!(["gpu"])))
    });
    let listed = Command::new(client_bin()).args(["--server", url, "workers"]).output().unwrap();
    let listed = String::from_utf8_lossy(&listed.stdout);
    assert!(listed.lines().any(|l| l.contains("gpu-box") && l.contains(" gpu ")), "{listed}");
    let big = submit_environment_with(&server, "1", "64", &[("worker_tags", "gpu"), ("worker_tags", "big")]);
    let gpu = submit_environment_with(&server, "1", "64", &[("worker_tags", "gpu")]);
    let any = submit_environment_with(&server, "1", "64", &[]);
    wait_job(&server, gpu, 120, |j| j["state"] == "done");
    wait_job(&server, any, 120, |j| j["state"] == "done");
    let waiting = get_json(url, &format!("/api/v1/jobs/{big}"));
    assert_eq!((waiting["state"].as_str(), tiles_done(&waiting)), (Some("queued"), 0), "{waiting}");
    assert_eq!(waiting["worker_tags"], json!(["big", "gpu"]));
    let why = waiting["waiting_for"].as_str().unwrap_or_else(|| panic!("{waiting}"));
    assert!(
        why.contains("no active worker has the tag(s) big, gpu") && why.contains("--tags big,gpu"),
        "{why}"
    );
    // A worker with both tags takes it.
    let _both = tagged_worker(url, "big-gpu-box", "gpu,big");
    let done = wait_job(&server, big, 120, |j| j["state"] == "done");
    assert!(done.get("waiting_for").is_none(), "{done}");
    let log = get_json(url, &format!("/api/v1/jobs/{big}/log"));
    let names: Vec<&str> =
        log["events"].as_array().unwrap().iter().filter_map(|e| e["worker"].as_str()).collect();
    assert!(!names.is_empty() && names.iter().all(|n| *n == "big-gpu-box"), "{names:?}");

    // Bad tags: the submission, the registration, the worker and the client name what is wrong.
    let scene = std::fs::read(repo().join("scenes/environment.xml")).unwrap();
    for (tags, says) in [("g pu", "holds ' '"), (&"x".repeat(33)[..], "longer than 32 bytes")] {
        let (code, e) = submit(
            url,
            None,
            &[("scene", Some("environment.xml"), &scene), ("worker_tags", None, tags.as_bytes())],
        );
        assert_eq!(code, 422, "{e}");
        assert!(
            e["error"].as_str().unwrap().starts_with("worker_tags: ") && e.to_string().contains(says),
            "{e}"
        );
        let (code, e) = register(url, "bad", &[tags]);
        assert_eq!(code, 422, "{e}");
        assert!(e["error"].as_str().unwrap().starts_with("tags: ") && e.to_string().contains(says), "{e}");
    }
    let many: Vec<String> = (0..17).map(|k| format!("t{k}")).collect();
    let mut parts: Vec<(&str, Option<&str>, &[u8])> = vec![("scene", Some("environment.xml"), &scene)];
    parts.extend(many.iter().map(|t| ("worker_tags", None, t.as_bytes())));
    let (code, e) = submit(url, None, &parts);
    assert_eq!(code, 422, "{e}");
    assert!(e["error"].as_str().unwrap().contains("worker_tags: more than 16 tags"), "{e}");
    let run = Command::new(worker_bin())
        .args(["work", "--server", url, "--token", TOKEN, "--tags", "gpu;rm"])
        .output()
        .unwrap();
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("--tags: the tag \"gpu;rm\" holds ';'"), "{err}");
    let run = Command::new(client_bin())
        .args(["--server", url, "submit"])
        .arg(repo().join("scenes/environment.xml"))
        .args(["--worker-tag", "ok", "--worker-tag", "not ok"])
        .output()
        .unwrap();
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("--worker-tag: the tag \"not ok\" holds ' '"), "{err}");
    assert_eq!(get_json(url, "/api/v1/jobs")["jobs"].as_array().unwrap().len(), 3, "nothing more was stored");
    // The client's tags go in its JSON submission, lowercased; it says why the job waits.
    let run = Command::new(client_bin())
        .args(["--server", url, "submit"])
        .arg(repo().join("scenes/environment.xml"))
        .args(["--samples", "1", "--worker-tag", "CUDA"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{err}");
    assert!(err.contains("waits: no active worker has the tag(s) cuda"), "{err}");
    let jobs = get_json(url, "/api/v1/jobs");
    assert_eq!(jobs["jobs"][0]["worker_tags"], json!(["cuda"]), "{jobs}");
}

/// A worker silent for longer than `--forget-workers-after` leaves the list (its name stays in
/// the job logs); a bad duration stops the server with a message naming the flag.
#[test]
fn silent_workers_leave_the_list_after_forget_workers_after() {
    let _serial = serial();
    let server = Server::start_temp(
        "workers-forget",
        &[
            "--local-workers",
            "0",
            "--worker-token",
            TOKEN,
            "--heartbeat-seconds",
            "0.5",
            "--forget-workers-after",
            "4s",
        ],
    );
    let url = &server.url;
    let (code, v) = register(url, "short-lived", &[]);
    assert_eq!(code, 200, "{v}");
    let short = v["worker_id"].as_u64().unwrap();
    // It fails a tile of a job before it falls silent: the job's log names it.
    let job = submit_environment(&server, "1", "64");
    let (code, lease) =
        worker_post(url, TOKEN, "/api/v1/worker/lease", json!({"worker_id": short, "wait_seconds": 5.0}));
    assert_eq!(code, 200, "{lease}");
    let fail = format!("/api/v1/worker/leases/{}/fail", lease["lease_id"]);
    let (code, v) =
        worker_post(url, TOKEN, &fail, json!({"worker_id": short, "error": "out of luck", "fatal": false}));
    assert_eq!(code, 204, "{v}");
    let (code, v) = register(url, "keeps-going", &[]);
    assert_eq!(code, 200, "{v}");
    let alive = v["worker_id"].as_u64().unwrap();
    assert_eq!(workers(url).len(), 2);
    let started = Instant::now();
    // One keeps sending heartbeats; the other is silent.
    let gone = within(20, "the silent worker forgotten", &server, || {
        let (code, v) =
            worker_post(url, TOKEN, "/api/v1/worker/heartbeat", json!({"worker_id": alive, "leases": []}));
        assert_eq!(code, 200, "{v}");
        let names: Vec<String> =
            workers(url).iter().map(|w| w["name"].as_str().unwrap().to_string()).collect();
        (names == ["keeps-going"]).then_some(started.elapsed())
    });
    assert!(gone >= Duration::from_secs(3), "forgotten after {gone:?}, before 4 s of silence");
    let log = get_json(url, &format!("/api/v1/jobs/{job}/log"));
    let failed = log["events"].as_array().unwrap().iter().find(|e| e["kind"] == "tile_failed").cloned();
    assert_eq!(failed.map(|e| e["worker"].clone()), Some(json!("short-lived")), "{log}");
    eprintln!("a worker silent for 4 s left the list after {:.1} s", gone.as_secs_f64());

    for (bad, says) in [
        ("1w", "the unit must be s, m, h or d"),
        ("0", "more than 0"),
        ("soon", "the unit must be"),
        ("1.5.3h", "is not a duration"),
    ] {
        let data = TempDir::new("workers-forget-bad");
        let run = Command::new(server_bin())
            .arg("--data-dir")
            .arg(data.path())
            .args(["--bind", "127.0.0.1:0", "--local-workers", "0", "--forget-workers-after", bad])
            .output()
            .unwrap();
        assert!(!run.status.success(), "{bad} was taken");
        let err = String::from_utf8_lossy(&run.stderr);
        assert!(err.contains("--forget-workers-after") && err.contains(says), "{bad}: {err}");
    }
}
