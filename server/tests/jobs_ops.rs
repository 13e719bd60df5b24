//! Managing jobs after their submission, against the real server: a paused job leases nothing
//! while others do and finishes once resumed; a cancelled job requeued finishes; a frame
//! rendered again has the bytes of its first render; a new priority orders the next lease; the
//! retention policy removes the oldest finished job's files; the client drives it all.

mod support;

use std::process::Command;
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use support::*;
use tessera::protocol::{checksum, encode_tile};

const TOKEN: &str = "wtok";
const ARGS: [&str; 4] = ["--local-workers", "0", "--worker-token", TOKEN];

fn register(url: &str) -> u64 {
    let (code, v) =
        worker_post(url, TOKEN, "/api/v1/worker/register", json!({"name": "scripted", "threads": 16}));
    assert_eq!(code, 200, "{v}");
    v["worker_id"].as_u64().unwrap()
}

/// A lease within `wait` seconds, or None (204).
fn lease(url: &str, worker: u64, wait: f64) -> Option<Value> {
    let (code, v) =
        worker_post(url, TOKEN, "/api/v1/worker/lease", json!({"worker_id": worker, "wait_seconds": wait}));
    match code {
        200 => Some(v),
        204 => None,
        _ => panic!("lease: {code} {v}"),
    }
}

/// Noise drawn from the tile's place (outputs that do not compress below their pixels' size).
fn tile_pixels(lease: &Value) -> Vec<u8> {
    let r = &lease["rect"];
    let field = |k: &str| r[k].as_u64().unwrap();
    let n = (field("width") * field("height")) as usize;
    let mut state = (field("x0") << 32 | field("y0")) ^ 0x9e37_79b9_7f4a_7c15;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    encode_tile(&(0..n).map(|_| [next(), next(), next()]).collect::<Vec<_>>())
}

/// A tile upload as a worker sends it: the status.
fn upload(url: &str, worker: u64, lease: &Value) -> u16 {
    let body = tile_pixels(lease);
    let req = ureq::put(&format!("{url}/api/v1/worker/leases/{}/result", lease["lease_id"]))
        .set("Authorization", &format!("Bearer {TOKEN}"))
        .set("x-tessera-worker", &worker.to_string())
        .set("x-tessera-worker-secret", &worker_secret(url, worker).unwrap_or_default())
        .set("x-tessera-checksum", &checksum(&body));
    call(req, Some(("application/octet-stream".into(), body))).0
}

/// Submits the tiny scene at `w` x `h` in tiles of `tile` with `extra` fields; its id.
fn submit_tiny(url: &str, w: u32, h: u32, tile: u32, extra: &[(&str, &str)]) -> u64 {
    let scene = tessera_testkit::tiny_scene(w, h);
    let tile = tile.to_string();
    let mut parts: Vec<(&str, Option<&str>, &[u8])> =
        vec![("scene", Some("tiny.xml"), &scene), ("tile_size", None, tile.as_bytes())];
    parts.extend(extra.iter().map(|(k, v)| (*k, None, v.as_bytes())));
    let (code, v) = submit(url, None, &parts);
    assert_eq!(code, 201, "{v}");
    v["id"].as_u64().unwrap()
}

/// A job-changing request with a JSON (or raw) body: status and answer.
fn send(url: &str, method: &str, path: &str, body: &str) -> (u16, Value) {
    call(
        ureq::request(method, &format!("{url}{path}")),
        Some(("application/json".into(), body.as_bytes().to_vec())),
    )
}

fn kinds(url: &str, id: u64) -> Vec<String> {
    get_json(url, &format!("/api/v1/jobs/{id}/log"))["events"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["kind"].as_str().unwrap().to_string())
        .collect()
}

fn state(url: &str, id: u64) -> String {
    get_json(url, &format!("/api/v1/jobs/{id}"))["state"].as_str().unwrap().to_string()
}

#[test]
fn a_paused_job_leases_nothing_keeps_what_was_out_and_finishes_once_resumed() {
    let _serial = serial();
    let server = Server::start_temp("jobs-pause", &ARGS);
    let url = &server.url;
    // Four tiles each; the paused one would go first by priority.
    let a = submit_tiny(url, 64, 64, 32, &[("priority", "5")]);
    let b = submit_tiny(url, 64, 64, 32, &[]);
    let w = register(url);
    let held = lease(url, w, 0.0).expect("a tile");
    assert_eq!(held["job_id"], a);

    let (code, v) = send(url, "POST", &format!("/api/v1/jobs/{a}/pause"), "");
    assert_eq!((code, v["state"].as_str()), (200, Some("paused")), "{v}");
    // Every tile the worker asks for is the other job's, and then there is nothing.
    let mut others = Vec::new();
    for _ in 0..4 {
        let l = lease(url, w, 0.0).expect("a tile of the other job");
        assert_eq!(l["job_id"], b, "a paused job's tile was leased: {l}");
        others.push(l);
    }
    assert!(lease(url, w, 1.0).is_none(), "a paused job's tile was leased");
    // The lease that was out when it paused finishes, and its result is kept.
    assert_eq!(upload(url, w, &held), 204);
    let job = get_json(url, &format!("/api/v1/jobs/{a}"));
    assert_eq!((job["state"].as_str(), tiles_done(&job)), (Some("paused"), 1), "{job}");
    for l in &others {
        assert_eq!(upload(url, w, l), 204);
    }
    wait_job(&server, b, 60, |j| j["state"] == "done");

    // Pausing twice, or a finished job, or no job: refused, naming why.
    let (code, v) = send(url, "POST", &format!("/api/v1/jobs/{a}/pause"), "");
    assert_eq!(code, 409, "{v}");
    assert!(v["error"].as_str().unwrap().contains("paused already"), "{v}");
    let (code, v) = send(url, "POST", &format!("/api/v1/jobs/{b}/pause"), "");
    assert_eq!(code, 409, "{v}");
    assert!(v["error"].as_str().unwrap().contains("(done)"), "{v}");
    let (code, v) = send(url, "POST", &format!("/api/v1/jobs/{b}/resume"), "");
    assert!(code == 409 && v["error"].as_str().unwrap().contains("is done, not paused"), "{code} {v}");
    assert_eq!(send(url, "POST", "/api/v1/jobs/999/pause", "").0, 404);

    // Resumed: running (a tile of it is done), and it finishes.
    let (code, v) = send(url, "POST", &format!("/api/v1/jobs/{a}/resume"), "");
    assert_eq!((code, v["state"].as_str()), (200, Some("running")), "{v}");
    for _ in 0..3 {
        let l = lease(url, w, 5.0).expect("a tile of the resumed job");
        assert_eq!(l["job_id"], a);
        assert_eq!(upload(url, w, &l), 204);
    }
    wait_job(&server, a, 60, |j| j["state"] == "done");
    let k = kinds(url, a);
    let at = |kind: &str| k.iter().position(|x| x == kind).unwrap_or_else(|| panic!("no {kind} in {k:?}"));
    assert!(at("job_paused") < at("job_resumed") && at("job_resumed") < at("job_done"), "{k:?}");
}

#[test]
fn a_cancelled_job_requeued_finishes_and_a_frame_rendered_again_has_the_same_bytes() {
    let _serial = serial();
    let server = Server::start_temp("jobs-requeue", &ARGS);
    let url = &server.url;
    let id = submit_environment(&server, "2", "64");
    assert_eq!(send(url, "POST", &format!("/api/v1/jobs/{id}/requeue"), "").0, 409, "a queued job");
    let (code, v) = cancel(&server, id);
    assert_eq!((code, v["state"].as_str()), (200, Some("canceled")), "{v}");

    // Hostile bodies: each a 400 naming the field and the syntax; nothing changes.
    for (body, says) in [
        (r#"{"frames": "0-4000000000"}"#, "there is no frame 4000000000"),
        (r#"{"frames": "1"}"#, "numbered 0 to 0"),
        (r#"{"frames": "abc"}"#, "0-9,12"),
        (r#"{"frames": "3-1"}"#, "runs backwards"),
        (r#"{"frames": ""}"#, "empty"),
        (r#"{"frames": -1}"#, "frames must be a string"),
        (r#"{"frames": "99999999999999999999"}"#, "too large"),
        (r#"{"frame": "0"}"#, "unknown field(s) \"frame\""),
        ("not json", "not JSON"),
        ("[1]", "JSON object"),
    ] {
        let (code, v) = send(url, "POST", &format!("/api/v1/jobs/{id}/requeue"), body);
        assert_eq!(code, 400, "{body}: {v}");
        let error = v["error"].as_str().unwrap();
        assert!(error.contains(says), "{body}: {error}");
        if body.contains("frames") && !body.contains("-1") {
            assert!(error.contains("frame"), "{body}: {error}");
        }
    }
    assert_eq!(state(url, id), "canceled");
    assert_eq!(send(url, "POST", "/api/v1/jobs/999/requeue", "").0, 404);

    // Requeued as it is (no body): queued again, and it finishes.
    let (code, v) = send(url, "POST", &format!("/api/v1/jobs/{id}/requeue"), "");
    assert_eq!((code, v["state"].as_str()), (200, Some("queued")), "{v}");
    let (code, v) = send(url, "POST", &format!("/api/v1/jobs/{id}/requeue"), "");
    assert!(code == 409 && v["error"].as_str().unwrap().contains("cancel it first"), "{code} {v}");
    let worker = Worker::start(url, TOKEN, "w1");
    let done = wait_job(&server, id, 120, |j| j["state"] == "done");
    let files = |job: &Value| -> Vec<(String, Vec<u8>)> {
        job["frames"][0]["outputs"]
            .as_array()
            .unwrap()
            .iter()
            .map(|o| {
                let name = o["name"].as_str().unwrap().to_string();
                let bytes = get_bytes(url, &format!("/api/v1/jobs/{id}/frames/0/files/{name}"));
                (name, bytes)
            })
            .collect()
    };
    let first = files(&done);
    assert!(first.len() >= 2, "{done}");

    // A done job without frames named has nothing to render again; frame 0 named renders again,
    // to the same bytes.
    let (code, v) = send(url, "POST", &format!("/api/v1/jobs/{id}/requeue"), "{}");
    assert!(code == 409 && v["error"].as_str().unwrap().contains("--frames 0-2"), "{code} {v}");
    let (code, v) = send(url, "POST", &format!("/api/v1/jobs/{id}/requeue"), r#"{"frames": "0"}"#);
    // The worker, polling, may have taken a tile already.
    assert!(code == 200 && (v["state"] == "queued" || v["state"] == "running"), "{code} {v}");
    assert_eq!(v["frames"][0]["outputs"], json!([]), "the frame renders again: {v}");
    let again = wait_job(&server, id, 120, |j| j["state"] == "done");
    // Progress starts again with the frame: done at the end, and counted once.
    assert_eq!(again["samples_done"], again["samples_total"], "{again}");
    assert_eq!(again["samples_total"], done["samples_total"], "{again}");
    let second = files(&again);
    assert_eq!(first.len(), second.len());
    for ((name, a), (name2, b)) in first.iter().zip(&second) {
        assert_eq!(name, name2);
        assert!(a == b, "{name}: the frame rendered again differs from its first render");
    }
    drop(worker);
    let k = kinds(url, id);
    assert_eq!(k.iter().filter(|x| *x == "job_requeued").count(), 2, "{k:?}");
    assert_eq!(k.iter().filter(|x| *x == "job_done").count(), 2, "{k:?}");
}

#[test]
fn a_sequences_frame_rendered_again_makes_its_video_again() {
    let _serial = serial();
    let server = Server::start_temp("jobs-requeue-video", &ARGS);
    let url = &server.url;
    let scene = |k: u32| {
        String::from_utf8(tessera_testkit::tiny_scene(16, 8))
            .unwrap()
            .replace("tiny.png", &format!("f{k}.png"))
    };
    let (a, b) = (scene(0), scene(1));
    let (code, v) = submit(
        url,
        None,
        &[
            ("scene", Some("f0.xml"), a.as_bytes()),
            ("scene", Some("f1.xml"), b.as_bytes()),
            ("video", None, b"gif"),
        ],
    );
    assert_eq!(code, 201, "{v}");
    let id = v["id"].as_u64().unwrap();
    let _worker = Worker::start(url, TOKEN, "w1");
    let video_done = |j: &Value| j["state"] == "done" && j["video"]["state"] == "done";
    let first = wait_job(&server, id, 120, video_done);
    let gif = get_bytes(url, first["video"]["url"].as_str().unwrap());
    let (code, v) = send(url, "POST", &format!("/api/v1/jobs/{id}/requeue"), r#"{"frames": "1-1"}"#);
    assert_eq!(code, 200, "{v}");
    assert_ne!(v["video"]["state"], "done", "the video is made again: {v}");
    assert!(!v["frames"][0]["outputs"].as_array().unwrap().is_empty(), "frame 0 keeps its files: {v}");
    let again = wait_job(&server, id, 120, video_done);
    assert!(get_bytes(url, again["video"]["url"].as_str().unwrap()) == gif, "the remade video differs");
    let k = kinds(url, id);
    assert_eq!(k.iter().filter(|x| *x == "video_done").count(), 2, "{k:?}");
}

#[test]
fn a_new_priority_orders_the_next_lease_and_bad_ones_are_refused() {
    let _serial = serial();
    let server = Server::start_temp("jobs-priority", &ARGS);
    let url = &server.url;
    let a = submit_tiny(url, 32, 32, 32, &[]);
    let b = submit_tiny(url, 32, 32, 32, &[]);
    for (body, says) in [
        (r#"{"priority": 1.5}"#, "priority must be an integer"),
        (r#"{"priority": "high"}"#, "priority must be an integer"),
        (r#"{"priority": 1e30}"#, "priority must be an integer"),
        (r#"{"priority": 99999999999999999999}"#, "priority must be an integer"),
        (r#"{"priority": 1, "name": "x", "tile_size": 8}"#, "unknown field(s) \"name\", \"tile_size\""),
        ("", "needs the field"),
        ("{", "not JSON"),
    ] {
        let (code, v) = send(url, "PATCH", &format!("/api/v1/jobs/{b}"), body);
        assert_eq!(code, 400, "{body}: {v}");
        assert!(v["error"].as_str().unwrap().contains(says), "{body}: {v}");
    }
    assert_eq!(send(url, "PATCH", "/api/v1/jobs/999", r#"{"priority": 1}"#).0, 404);
    // A body far past the change's 16 KiB (under the upload cap) is refused without being held:
    // the server's peak memory grows by a small part of it, and the client, which writes the
    // whole body first, reads the message.
    let before = server.memory_kib("VmHWM");
    let huge = format!(r#"{{"priority": 1, "pad": "{}"}}"#, "x".repeat(48 << 20));
    let (code, v) = send(url, "PATCH", &format!("/api/v1/jobs/{b}"), &huge);
    drop(huge);
    assert!(code == 400 && v["error"].as_str().unwrap().contains("at most 16 KiB"), "{code} {v}");
    let grown = server.memory_kib("VmHWM").saturating_sub(before);
    assert!(grown < 16 << 10, "a 48 MiB PATCH grew the server's peak memory by {grown} KiB");
    // By submission order a's tile goes first; b's new priority puts it ahead.
    let (code, v) = send(url, "PATCH", &format!("/api/v1/jobs/{b}"), r#"{"priority": 10}"#);
    assert_eq!((code, v["priority"].as_i64()), (200, Some(10)), "{v}");
    let w = register(url);
    assert_eq!(lease(url, w, 0.0).unwrap()["job_id"], b);
    assert_eq!(lease(url, w, 0.0).unwrap()["job_id"], a);
    let (code, v) =
        send(url, "PATCH", &format!("/api/v1/jobs/{a}"), &format!(r#"{{"priority": {}}}"#, i64::MIN));
    assert_eq!((code, v["priority"].as_i64()), (200, Some(i64::MIN)), "{v}");
    let log = get_json(url, &format!("/api/v1/jobs/{b}/log"));
    assert!(
        log["events"]
            .as_array()
            .unwrap()
            .iter()
            .any(|e| e["kind"] == "priority_changed"
                && e["message"].as_str().unwrap().contains("from 0 to 10")),
        "{log}"
    );
    assert_eq!(cancel(&server, a).0, 200);
    let (code, v) = send(url, "PATCH", &format!("/api/v1/jobs/{a}"), r#"{"priority": 1}"#);
    assert!(code == 409 && v["error"].as_str().unwrap().contains("(canceled)"), "{code} {v}");
}

/// Bytes of a job's folders in the data directory (outputs/ID and frames/ID).
fn job_bytes(data: &std::path::Path, id: u64) -> u64 {
    fn walk(p: &std::path::Path) -> u64 {
        std::fs::read_dir(p).map_or(0, |d| {
            d.flatten()
                .map(
                    |e| if e.path().is_dir() { walk(&e.path()) } else { e.metadata().map_or(0, |m| m.len()) },
                )
                .sum()
        })
    }
    ["outputs", "frames"].iter().map(|s| walk(&data.join(s).join(id.to_string()))).sum()
}

#[test]
fn retention_removes_the_oldest_finished_jobs_files_and_never_a_paused_job() {
    let _serial = serial();
    let data = tessera_testkit::TempDir::new("jobs-retention");
    let dir = data.join("data");
    // A wrong flag is refused at start, naming it.
    for (flag, value) in
        [("--keep-finished-days", "-1"), ("--keep-finished-days", "nan"), ("--disk-budget-mb", "0")]
    {
        let out = Command::new(server_bin())
            .args(["--data-dir"])
            .arg(&dir)
            .args(["--bind", "127.0.0.1:0", flag, value])
            .output()
            .unwrap();
        assert!(!out.status.success(), "{flag} {value} was accepted");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(flag) && err.contains("leave it out"), "{flag} {value}: {err}");
    }

    // Three finished jobs of noise (a few MiB each: their outputs do not compress), one paused.
    let ids: Vec<u64> = {
        let server = Server::start(&dir, &ARGS);
        let url = &server.url;
        let w = register(url);
        let mut ids = Vec::new();
        for _ in 0..3 {
            let id = submit_tiny(url, 512, 512, 128, &[]);
            while let Some(l) = lease(url, w, 0.0) {
                assert_eq!(upload(url, w, &l), 204);
            }
            wait_job(&server, id, 60, |j| j["state"] == "done");
            ids.push(id);
        }
        let paused = submit_tiny(url, 32, 32, 32, &[]);
        assert_eq!(send(url, "POST", &format!("/api/v1/jobs/{paused}/pause"), "").0, 200);
        ids.push(paused);
        ids
    };
    let sizes: Vec<u64> = ids.iter().map(|&id| job_bytes(&dir, id)).collect();
    assert!(sizes[..3].iter().all(|&s| s > 2 << 20), "{sizes:?}");
    // A budget that the three finished jobs exceed, and the last two fit.
    let budget_mb = (sizes[1] + sizes[2] + sizes[0] / 2) >> 20;
    eprintln!("the jobs' folders: {sizes:?} bytes; --disk-budget-mb {budget_mb}");
    assert!((budget_mb << 20) < sizes[0] + sizes[1] + sizes[2] && (budget_mb << 20) >= sizes[1] + sizes[2]);
    {
        let budget = budget_mb.to_string();
        let args: Vec<&str> = ARGS.iter().copied().chain(["--disk-budget-mb", budget.as_str()]).collect();
        let server = Server::start(&dir, &args);
        let url = &server.url;
        let deadline = Instant::now() + Duration::from_secs(30);
        // Its rows go first, then its folders, then the line that says so.
        let removal = format!("job={}", ids[0]);
        while call(ureq::get(&format!("{url}/api/v1/jobs/{}", ids[0])), None).0 != 404
            || job_bytes(&dir, ids[0]) > 0
            || !server
                .log()
                .lines()
                .any(|l| l.contains("removed the oldest finished job") && l.contains(&removal))
        {
            assert!(Instant::now() < deadline, "the oldest job was never removed\n{}", server.log());
            std::thread::sleep(Duration::from_millis(50));
        }
        assert!(!dir.join("outputs").join(ids[0].to_string()).exists());
        for &id in &ids[1..] {
            assert_eq!(call(ureq::get(&format!("{url}/api/v1/jobs/{id}")), None).0, 200, "job {id} stays");
            assert_eq!(job_bytes(&dir, id), sizes[ids.iter().position(|&x| x == id).unwrap()]);
        }
        let log = server.log();
        let line = log
            .lines()
            .find(|l| l.contains("removed the oldest finished job") && l.contains(&removal))
            .unwrap_or_else(|| panic!("no removal line in\n{log}"));
        assert!(line.contains(&format!("bytes={}", sizes[0])), "{line}");
        assert_eq!(state(url, ids[3]), "paused");
    }
    // Finished jobs older than a moment go; the paused one stays, whatever the rules.
    std::thread::sleep(Duration::from_millis(1200));
    let args: Vec<&str> =
        ARGS.iter().copied().chain(["--keep-finished-days", "0.00001", "--disk-budget-mb", "1"]).collect();
    let server = Server::start(&dir, &args);
    let url = &server.url;
    let deadline = Instant::now() + Duration::from_secs(30);
    while ids[1..3].iter().any(|&id| {
        call(ureq::get(&format!("{url}/api/v1/jobs/{id}")), None).0 != 404 || job_bytes(&dir, id) > 0
    }) || server.log().matches("past --keep-finished-days").count() < 2
    {
        assert!(Instant::now() < deadline, "finished jobs past their days stayed\n{}", server.log());
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(server.log().contains("past --keep-finished-days"), "{}", server.log());
    assert_eq!(state(url, ids[3]), "paused");
    assert_eq!((job_bytes(&dir, ids[1]), job_bytes(&dir, ids[2])), (0, 0));
}

/// `tessera ARGS` against `server`: (success, stdout, stderr).
fn tessera(server: &Server, args: &[&str]) -> (bool, String, String) {
    let out = Command::new(client_bin())
        .args(args)
        .env("TESSERA_SERVER", &server.url)
        .env_remove("TESSERA_TOKEN")
        .output()
        .expect("run tessera");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into(),
        String::from_utf8_lossy(&out.stderr).into(),
    )
}

#[test]
fn the_client_pauses_resumes_requeues_and_reprioritises_saying_what_it_did() {
    let _serial = serial();
    let server = Server::start_temp("jobs-client", &ARGS);
    let id = submit_tiny(&server.url, 32, 32, 16, &[]);
    let s = id.to_string();
    let (ok, out, err) = tessera(&server, &["pause", &s]);
    assert!(
        ok && out.contains(&format!("job {id} (tiny.xml) paused")) && out.contains("tessera resume"),
        "{out}{err}"
    );
    let (ok, out, err) = tessera(&server, &["priority", &s, "-3"]);
    assert!(ok && out.contains("priority -3") && out.contains("once resumed"), "{out}{err}");
    let (ok, out, err) = tessera(&server, &["resume", &s]);
    assert!(ok && out.contains(&format!("job {id} (tiny.xml) resumed: queued")), "{out}{err}");
    // A queued job is not requeued: the server's reason, and what to do.
    let (ok, _, err) = tessera(&server, &["requeue", &s]);
    assert!(!ok && err.contains("409") && err.contains("cancel it first"), "{err}");
    assert_eq!(cancel(&server, id).0, 200);
    // A bad frame list is refused before anything is sent; a frame past the last by the server.
    let (ok, _, err) = tessera(&server, &["requeue", &s, "--frames", "1-x"]);
    assert!(!ok && err.contains("--frames") && err.contains("0-9,12"), "{err}");
    let (ok, _, err) = tessera(&server, &["requeue", &s, "--frames", "5"]);
    assert!(!ok && err.contains("numbered 0 to 0") && err.contains("there is no frame 5"), "{err}");
    let (ok, out, err) = tessera(&server, &["requeue", &s, "--frames", "0"]);
    assert!(ok && out.contains("frame(s) 0 render again (numbered from 0)"), "{out}{err}");
    for cmd in ["pause", "resume", "requeue"] {
        let (ok, _, err) = tessera(&server, &[cmd, "999"]);
        assert!(!ok && err.contains("there is no job 999"), "{cmd}: {err}");
    }
    let (ok, _, err) = tessera(&server, &["priority", "999", "1"]);
    assert!(!ok && err.contains("there is no job 999"), "{err}");
    let (ok, _, err) = tessera(&server, &["priority", &s, "1.5"]);
    assert!(!ok && err.contains("1.5"), "{err}");
    let k = kinds(&server.url, id);
    for kind in ["job_paused", "priority_changed", "job_resumed", "job_cancelled", "job_requeued"] {
        assert!(k.contains(&kind.to_string()), "{kind} not in {k:?}");
    }
}
