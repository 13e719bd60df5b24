//! Cheap requests that used to cost the server dearly, against the real server over real
//! sockets: each test reproduces one and checks the bounded outcome with its figure (rows and
//! bytes of the job store on disk, the latency of another client during the attack).

mod support;

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use support::*;

const API: &str = "APITOK";
const WORKER: &str = "WTOK";

/// The most another client may wait for a lease or a job view while an attack runs (the
/// slowest of its requests). The attacks used to hold the store for seconds; with the store
/// let go between steps the slowest request stays well below this bound, which leaves room for
/// a loaded 2-core machine without letting such a stall through.
const OTHERS_WAIT_AT_MOST: f64 = 0.5;

fn args(extra: &[&str]) -> Vec<String> {
    let mut args: Vec<String> =
        ["--api-token", API, "--worker-token", WORKER, "--local-workers", "0"].map(String::from).to_vec();
    args.extend(extra.iter().map(|s| s.to_string()));
    args
}

/// A server on `data` (kept by the caller: the tests read its database).
fn start_on(data: &Path, extra: &[&str]) -> Server {
    let args = args(extra);
    Server::start(data, &args.iter().map(String::as_str).collect::<Vec<_>>())
}

fn post(url: &str, path: &str, body: Value) -> (u16, Value) {
    worker_post(url, WORKER, path, body)
}

fn register(url: &str, name: &str, threads: u32) -> u64 {
    let (code, v) = post(url, "/api/v1/worker/register", json!({"name": name, "threads": threads}));
    assert_eq!(code, 200, "{v}");
    v["worker_id"].as_u64().unwrap()
}

fn get_api(url: &str, path: &str) -> (u16, Value) {
    call(ureq::get(&format!("{url}{path}")).set("Authorization", &format!("Bearer {API}")), None)
}

fn submit_scene(url: &str, scene: &[u8], fields: &[(&str, &str)]) -> (u16, Value) {
    let mut parts: Vec<(&str, Option<&str>, &[u8])> = vec![("scene", Some("tiny.xml"), scene)];
    parts.extend(fields.iter().map(|(k, v)| (*k, None, v.as_bytes())));
    submit(url, Some(API), &parts)
}

/// The submission: 316 x 316 pixels in one-pixel tiles, with `samples` in passes of 16.
fn submit_big(url: &str, samples: &str) -> (u16, Value) {
    let scene = tessera_testkit::tiny_scene(316, 316);
    submit_scene(url, &scene, &[("tile_size", "1"), ("samples", samples), ("pass_samples", "16")])
}

/// A job of `w` x `h` pixels in one-pixel tiles, one pass each.
fn submit_small(url: &str, w: u32, h: u32) -> u64 {
    let scene = tessera_testkit::tiny_scene(w, h);
    let (code, v) = submit_scene(url, &scene, &[("tile_size", "1"), ("samples", "1")]);
    assert_eq!(code, 201, "{v}");
    v["id"].as_u64().unwrap()
}

/// What the job store holds on disk: its tile rows, the bytes of its files (database and
/// write-ahead log), its pages and free pages.
#[derive(Debug, Clone, Copy)]
struct Disk {
    tiles: i64,
    bytes: u64,
    /// Of which the write-ahead log.
    log_bytes: u64,
    pages: i64,
    free_pages: i64,
}

fn disk(data: &Path) -> Disk {
    let db = data.join("tessera.db");
    let bytes = ["", "-wal"]
        .iter()
        .map(|s| std::fs::metadata(format!("{}{s}", db.display())).map_or(0, |m| m.len()))
        .sum();
    let log_bytes = std::fs::metadata(format!("{}-wal", db.display())).map_or(0, |m| m.len());
    let conn = rusqlite::Connection::open(&db).unwrap();
    conn.busy_timeout(Duration::from_secs(10)).unwrap();
    let tiles = conn.query_row("SELECT count(*) FROM tiles", [], |r| r.get(0)).unwrap();
    let pages = conn.query_row("PRAGMA page_count", [], |r| r.get(0)).unwrap();
    let free_pages = conn.query_row("PRAGMA freelist_count", [], |r| r.get(0)).unwrap();
    Disk { tiles, bytes, log_bytes, pages, free_pages }
}

fn rows_of(data: &Path, sql: &str) -> i64 {
    let conn = rusqlite::Connection::open(data.join("tessera.db")).unwrap();
    conn.busy_timeout(Duration::from_secs(10)).unwrap();
    conn.query_row(sql, [], |r| r.get(0)).unwrap()
}

/// Seconds a call takes, and its status.
fn timed(f: impl FnOnce() -> (u16, Value)) -> (f64, u16) {
    let t = Instant::now();
    let (code, _) = f();
    (t.elapsed().as_secs_f64(), code)
}

/// The worst latencies of another client (a lease of worker `w`, a view of job `job`) while
/// `busy` holds.
fn other_clients_while(url: &str, w: u64, job: u64, busy: impl Fn() -> bool) -> (f64, f64, usize) {
    let (mut lease, mut view, mut calls) = (0f64, 0f64, 0);
    while busy() {
        let (t, code) =
            timed(|| post(url, "/api/v1/worker/lease", json!({"worker_id": w, "wait_seconds": 0.0})));
        assert!([200, 204, 429].contains(&code), "lease: {code}");
        lease = lease.max(t);
        let (t, code) = timed(|| get_api(url, &format!("/api/v1/jobs/{job}")));
        assert_eq!(code, 200);
        view = view.max(t);
        calls += 1;
        std::thread::sleep(Duration::from_millis(5));
    }
    (lease, view, calls)
}

/// Waits up to `secs` for job `id` to be done.
fn wait_done(server: &Server, id: u64, secs: u64) -> Value {
    let deadline = Instant::now() + Duration::from_secs(secs);
    loop {
        let (code, job) = get_api(&server.url, &format!("/api/v1/jobs/{id}"));
        assert_eq!(code, 200, "{job}");
        if job["state"] == "done" {
            return job;
        }
        assert!(Instant::now() < deadline, "job {id} is not done: {job}\n{}", server.log());
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// The processes the server started (its local workers).
fn children(server: &Server) -> Vec<i32> {
    let tasks = std::fs::read_dir(format!("/proc/{}/task", server.child.id())).unwrap();
    tasks
        .flatten()
        .filter_map(|t| std::fs::read_to_string(t.path().join("children")).ok())
        .flat_map(|c| c.split_whitespace().filter_map(|p| p.parse().ok()).collect::<Vec<i32>>())
        .collect()
}

/// Waits up to `secs` for `until`.
fn wait_for(secs: u64, what: &str, server: &Server, until: impl Fn() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(secs);
    while !until() {
        assert!(Instant::now() < deadline, "timed out waiting for {what}\n{}", server.log());
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Row "a 2 KB submission of 1,597,696 units": refused for its rows, naming the flag and what
/// fits, before anything is stored.
#[test]
fn a_job_of_too_many_units_is_refused_naming_the_flag_and_what_fits() {
    let _s = serial();
    let data = TempDir::new("cost-units");
    let server = start_on(&data, &[]);
    let before = disk(&data);
    let t = Instant::now();
    let (code, v) = submit_big(&server.url, "256");
    let took = t.elapsed().as_secs_f64();
    assert_eq!(code, 422, "{v}");
    let error = v["error"].as_str().unwrap();
    for wanted in
        ["1597696 units", "1000000", "--max-job-units", "tile_size=2 or more", "pass_samples=32 or more"]
    {
        assert!(error.contains(wanted), "no {wanted:?} in: {error}");
    }
    let after = disk(&data);
    eprintln!("1,597,696 units: 422 in {took:.2} s; store {before:?} -> {after:?}");
    assert_eq!(after.tiles, 0);
    assert!(after.bytes < before.bytes + (1 << 20), "a refused job grew the store: {before:?} -> {after:?}");
    // What the answer advises fits.
    let (code, v) = submit_big(&server.url, "256");
    assert_eq!(code, 422, "{v}");
    let scene = tessera_testkit::tiny_scene(316, 316);
    let (code, v) =
        submit_scene(&server.url, &scene, &[("tile_size", "2"), ("samples", "256"), ("pass_samples", "16")]);
    assert_eq!(code, 201, "{v}");
    // The limit is the operator's to set.
    drop(server);
    let server = start_on(&data, &["--max-job-units", "100"]);
    let scene = tessera_testkit::tiny_scene(10, 11);
    let (code, v) = submit_scene(&server.url, &scene, &[("tile_size", "1"), ("samples", "1")]);
    assert_eq!(code, 422, "{v}");
    assert!(v["error"].as_str().unwrap().contains("110 units"), "{v}");
}

/// Row "writes 332 MiB of rows and stalls leases and job views for 3.7-6.3 s": the largest job
/// the default limit allows is stored a step at a time; another client's leases and views wait
/// for a step at most, and the job is never seen half stored.
#[test]
fn a_maximal_job_is_stored_in_steps_while_other_clients_carry_on() {
    let _s = serial();
    let data = TempDir::new("cost-insert");
    let server = start_on(&data, &[]);
    let small = submit_small(&server.url, 64, 64);
    let w = register(&server.url, "other", 1024);
    let url = server.url.clone();
    let t = Instant::now();
    // 99,856 tiles x 10 passes: 998,560 units, the most under the default 1,000,000.
    let big = std::thread::spawn(move || submit_big(&url, "160"));
    let mut half_seen = 0;
    let (mut lease, mut view, mut calls) = (0f64, 0f64, 0);
    while !big.is_finished() {
        let (t1, code) =
            timed(|| post(&server.url, "/api/v1/worker/lease", json!({"worker_id": w, "wait_seconds": 0.0})));
        assert!([200, 204, 429].contains(&code), "lease: {code}");
        lease = lease.max(t1);
        let (t2, list) = {
            let t = Instant::now();
            let (code, list) = get_api(&server.url, "/api/v1/jobs");
            assert_eq!(code, 200);
            (t.elapsed().as_secs_f64(), list)
        };
        view = view.max(t2);
        for j in list["jobs"].as_array().unwrap() {
            if j["id"] != small && j["state"] != "queued" {
                half_seen += 1;
            }
        }
        calls += 1;
        std::thread::sleep(Duration::from_millis(5));
    }
    let (code, v) = big.join().unwrap();
    let took = t.elapsed().as_secs_f64();
    assert_eq!(code, 201, "{v}");
    let after = disk(&data);
    eprintln!(
        "998,560 units stored in {took:.1} s: {} tile rows, {} MiB on disk ({} MiB of log); meanwhile {calls} leases and job lists, \
         slowest lease {lease:.3} s, slowest list {view:.3} s",
        after.tiles,
        after.bytes >> 20,
        after.log_bytes >> 20
    );
    assert!(after.log_bytes < 64 << 20, "the write-ahead log grew to {} MiB", after.log_bytes >> 20);
    assert_eq!(after.tiles, 998_560 + 64 * 64);
    assert!(calls >= 5, "the insertion was too quick to measure anything ({took:.2} s)");
    assert_eq!(half_seen, 0, "a job was listed before it was queued");
    assert!(lease < OTHERS_WAIT_AT_MOST, "a lease waited {lease:.3} s during the insertion");
    assert!(view < OTHERS_WAIT_AT_MOST, "the job list waited {view:.3} s during the insertion");
}

/// A server killed while it stores a job leaves no half job that is leased: at the next start
/// the job is failed, saying to submit it again, and its rows are purged.
#[test]
fn a_job_cut_short_by_a_kill_fails_at_start_and_is_never_leased() {
    let _s = serial();
    let data = TempDir::new("cost-insert-kill");
    let mut server = start_on(&data, &[]);
    let url = server.url.clone();
    let big = std::thread::spawn(move || {
        let scene = tessera_testkit::tiny_scene(316, 316);
        let mut parts: Vec<(&str, Option<&str>, &[u8])> = vec![("scene", Some("tiny.xml"), &scene)];
        parts.extend([
            ("tile_size", None, &b"1"[..]),
            ("samples", None, b"160"),
            ("pass_samples", None, b"16"),
        ]);
        let req = ureq::post(&format!("{url}/api/v1/jobs")).set("Authorization", &format!("Bearer {API}"));
        let (ct, body) = multipart(&parts);
        req.set("Content-Type", &ct).send_bytes(&body).is_ok()
    });
    wait_for(120, "the job's first rows", &server, || {
        rows_of(&data, "SELECT count(*) FROM jobs WHERE state = 'inserting'") == 1
            && rows_of(&data, "SELECT count(*) FROM tiles") > 0
    });
    server.kill9();
    assert!(!big.join().unwrap(), "the submission was answered although the server was killed");
    let cut = disk(&data);
    assert!(cut.tiles > 0 && cut.tiles < 998_560, "{cut:?}");
    let server = start_on(&data, &[]);
    let (code, list) = get_api(&server.url, "/api/v1/jobs");
    assert_eq!(code, 200);
    let job = &list["jobs"][0];
    assert_eq!(job["state"], "failed", "{list}");
    assert!(job["error"].as_str().unwrap().contains("submit it again"), "{job}");
    let w = register(&server.url, "w", 4);
    let (code, v) = post(&server.url, "/api/v1/worker/lease", json!({"worker_id": w, "wait_seconds": 0.0}));
    assert_eq!(code, 204, "a tile of the half job was leased: {v}");
    wait_for(120, "the half job's rows to be purged", &server, || disk(&data).tiles == 0);
    eprintln!("killed with {} of 998,560 rows written; at restart: failed, no lease, rows purged", cut.tiles);
}

/// Row "cancelled, the rows stay; the same again adds 170 MiB": a cancelled job's rows go,
/// a step at a time while others carry on, and their space is given back.
#[test]
fn cancelling_a_job_gives_its_rows_and_their_space_back() {
    let _s = serial();
    let data = TempDir::new("cost-cancel");
    let server = start_on(&data, &[]);
    let small = submit_small(&server.url, 8, 8);
    let w = register(&server.url, "other", 1024);
    let empty = disk(&data);
    // 99,856 tiles x 4 passes.
    let (code, v) = submit_big(&server.url, "64");
    assert_eq!(code, 201, "{v}");
    let id = v["id"].as_u64().unwrap();
    let stored = disk(&data);
    assert_eq!(stored.tiles, 399_424 + 64);
    let (code, v) = call(
        ureq::post(&format!("{}/api/v1/jobs/{id}/cancel", server.url))
            .set("Authorization", &format!("Bearer {API}")),
        Some(("text/plain".into(), Vec::new())),
    );
    assert_eq!(code, 200, "{v}");
    let t = Instant::now();
    let purging = || disk(&data).tiles > 64;
    let (lease, view, calls) = other_clients_while(&server.url, w, small, purging);
    let took = t.elapsed().as_secs_f64();
    // The file shrinks once the free pages are given back and checkpointed.
    wait_for(60, "the free pages to be given back", &server, || disk(&data).free_pages == 0);
    std::thread::sleep(Duration::from_millis(500));
    let purged = disk(&data);
    let (_, info) = get_api(&server.url, &format!("/api/v1/jobs/{id}"));
    assert_eq!(info["state"], "canceled");
    assert_eq!(info["frames"][0]["tiles_total"], 99_856, "what the job view shows stays");
    // The same submission again reuses the space.
    let (code, v) = submit_big(&server.url, "64");
    assert_eq!(code, 201, "{v}");
    let again = disk(&data);
    eprintln!(
        "cancel: empty {empty:?}; stored {stored:?}; purged in {took:.1} s (slowest lease {lease:.3} s, view \
         {view:.3} s over {calls} calls) {purged:?}; the same job again {again:?}"
    );
    assert_eq!(purged.tiles, 64, "the cancelled job's rows are gone");
    assert!(
        purged.pages < stored.pages / 4,
        "the database kept its pages: {} -> {} (free {})",
        stored.pages,
        purged.pages,
        purged.free_pages
    );
    assert!(
        again.bytes < stored.bytes + stored.bytes / 10,
        "the same job again grew the store: {} -> {} bytes",
        stored.bytes,
        again.bytes
    );
    assert!(lease < OTHERS_WAIT_AT_MOST, "a lease waited {lease:.3} s during the purge");
    assert!(view < OTHERS_WAIT_AT_MOST, "a job view waited {view:.3} s during the purge");
}

/// A failed job's tile rows go too, while its view still answers its tiles done per frame; a
/// done job keeps no pixels in the store, and its preview and tone map (read from its files)
/// still answer.
#[test]
fn failed_jobs_lose_their_rows_and_done_jobs_their_pixels() {
    let _s = serial();
    let data = TempDir::new("cost-failed");
    let server = start_on(&data, &[]);
    let failing = submit_small(&server.url, 16, 16);
    let w = register(&server.url, "w", 4);
    let lease = |w: u64| {
        let (code, l) =
            post(&server.url, "/api/v1/worker/lease", json!({"worker_id": w, "wait_seconds": 0.0}));
        assert_eq!(code, 200, "{l}");
        l["lease_id"].as_u64().unwrap()
    };
    let l = lease(w);
    let body = tessera::protocol::encode_tile(&[[0.5f32; 3]]);
    let req = ureq::put(&format!("{}/api/v1/worker/leases/{l}/result", server.url))
        .set("Authorization", &format!("Bearer {WORKER}"))
        .set("x-tessera-worker", &w.to_string())
        .set("x-tessera-worker-secret", &worker_secret(&server.url, w).unwrap())
        .set("x-tessera-checksum", &tessera::protocol::checksum(&body));
    assert_eq!(call(req, Some(("application/octet-stream".into(), body))).0, 204);
    let l = lease(w);
    let (code, v) = post(
        &server.url,
        &format!("/api/v1/worker/leases/{l}/fail"),
        json!({"worker_id": w, "error": "over the limit", "fatal": true}),
    );
    assert_eq!(code, 204, "{v}");
    wait_for(60, "the failed job's rows to be purged", &server, || {
        rows_of(&data, "SELECT count(*) FROM tiles") + rows_of(&data, "SELECT count(*) FROM tile_failures")
            == 0
    });
    let (_, info) = get_api(&server.url, &format!("/api/v1/jobs/{failing}"));
    assert_eq!(info["state"], "failed");
    assert_eq!(
        (info["frames"][0]["tiles_done"].as_u64(), info["frames"][0]["tiles_total"].as_u64()),
        (Some(1), Some(256))
    );

    // A job rendered by a real worker: no pixels stay in the store once its frame is merged.
    let done = submit_small(&server.url, 24, 24);
    let _worker = Worker::start(&server.url, WORKER, "renderer");
    let job = wait_done(&server, done, 120);
    assert_eq!(rows_of(&data, "SELECT count(*) FROM tiles WHERE pixels IS NOT NULL OR sums IS NOT NULL"), 0);
    let png = get_bytes(&server.url, &format!("/api/v1/jobs/{done}/frames/0/preview.png?access_token={API}"));
    assert!(png.starts_with(b"\x89PNG"));
    let (code, _) = get_api(&server.url, &format!("/api/v1/jobs/{done}/frames/0/tonemap.png"));
    assert_eq!(code, 200, "the tone map of a done frame reads its .exr");
    eprintln!(
        "failed job: rows purged, view answers 1 of 256 tiles; done job: {} outputs, no pixels kept",
        job["frames"][0]["outputs"]
    );
}

/// A flood of worker registrations with the worker token, from `threads` keep-alive clients,
/// for `seconds`: (accepted, refused with 429, other codes, a 429's Retry-After and message).
fn flood_registrations(
    url: &str,
    threads: usize,
    seconds: f64,
    stop: Arc<AtomicBool>,
) -> (u64, u64, u64, String, String) {
    let flooders: Vec<_> = (0..threads)
        .map(|k| {
            let (url, stop) = (url.to_string(), stop.clone());
            std::thread::spawn(move || {
                let agent = ureq::AgentBuilder::new().timeout(Duration::from_secs(10)).build();
                let body = json!({"name": format!("flood-{k}"), "threads": 1}).to_string();
                let (mut ok, mut refused, mut other) = (0u64, 0u64, 0u64);
                let (mut retry, mut message) = (String::new(), String::new());
                let end = Instant::now() + Duration::from_secs_f64(seconds);
                while Instant::now() < end && !stop.load(Ordering::Relaxed) {
                    let r = agent
                        .post(&format!("{url}/api/v1/worker/register"))
                        .set("Authorization", &format!("Bearer {WORKER}"))
                        .set("Content-Type", "application/json")
                        .send_string(&body);
                    match r {
                        Ok(_) => ok += 1,
                        Err(ureq::Error::Status(429, r)) => {
                            refused += 1;
                            if retry.is_empty() {
                                retry = r.header("retry-after").unwrap_or("none").to_string();
                                message = r.into_string().unwrap_or_default();
                            }
                        }
                        Err(_) => other += 1,
                    }
                }
                (ok, refused, other, retry, message)
            })
        })
        .collect();
    let mut out = (0, 0, 0, String::new(), String::new());
    for f in flooders {
        let (ok, refused, other, retry, message) = f.join().unwrap();
        out.0 += ok;
        out.1 += refused;
        out.2 += other;
        if out.3.is_empty() {
            out.3 = retry;
            out.4 = message;
        }
    }
    out
}

/// Row "100,000 worker registrations in 10 s, each accepted; the workers list becomes 13.5 MiB":
/// past a burst, registrations with the worker token are refused with 429 and Retry-After, the
/// workers list stays small, and other clients do not wait.
#[test]
fn a_flood_of_registrations_is_refused_and_the_workers_list_stays_small() {
    let _s = serial();
    let data = TempDir::new("cost-register");
    let server = start_on(&data, &[]);
    let small = submit_small(&server.url, 64, 64);
    let w = register(&server.url, "other", 1024);
    let stop = Arc::new(AtomicBool::new(false));
    let url = server.url.clone();
    let flood = {
        let stop = stop.clone();
        std::thread::spawn(move || flood_registrations(&url, 4, 10.0, stop))
    };
    let (lease, view, calls) = other_clients_while(&server.url, w, small, || !flood.is_finished());
    let (ok, refused, other, retry, message) = flood.join().unwrap();
    let list = get_bytes(&server.url, &format!("/api/v1/workers?access_token={API}"));
    let rows = rows_of(&data, "SELECT count(*) FROM workers");
    eprintln!(
        "registration flood: {} attempts in 10 s, {ok} accepted, {refused} refused (429, Retry-After {retry}), {other} \
         other; {rows} worker rows, workers list {} bytes; slowest lease {lease:.3} s, view {view:.3} s over {calls} calls",
        ok + refused + other,
        list.len()
    );
    assert_eq!(other, 0, "some registrations got neither 200 nor 429");
    assert!(refused > 10 * ok, "most registrations should be refused: {ok} accepted, {refused} refused");
    assert!(ok <= 256 + 16 * 11 + 1, "{ok} registrations accepted in 10 s");
    assert!(retry.parse::<u64>().is_ok_and(|s| (1..=60).contains(&s)), "Retry-After: {retry}");
    assert!(message.contains("too many worker registrations") && message.contains("a second"), "{message}");
    assert!(list.len() < 128 << 10, "the workers list is {} bytes", list.len());
    assert!(lease < OTHERS_WAIT_AT_MOST, "a lease waited {lease:.3} s during the flood");
    assert!(view < OTHERS_WAIT_AT_MOST, "a job view waited {view:.3} s during the flood");
    // The refused registrations left nothing behind.
    assert_eq!(rows as u64, ok + 1);
}

/// Live workers are capped (`--max-workers`, a 503 that names it); lost ones make room and are
/// forgotten past the cap and after `--forget-workers-after-hours`, their names kept in the job
/// logs.
#[test]
fn live_workers_are_capped_and_stale_ones_forgotten() {
    let _s = serial();
    let data = TempDir::new("cost-workers");
    let server = start_on(
        &data,
        &[
            "--max-workers",
            "20",
            "--heartbeat-seconds",
            "0.5",
            "--lease-seconds",
            "2",
            "--forget-workers-after-hours",
            "0.002",
        ],
    );
    let job = submit_small(&server.url, 4, 4);
    // A worker that fails a tile and falls silent: the log names it after it is forgotten.
    let failing = register(&server.url, "forget-me", 1);
    let (code, l) =
        post(&server.url, "/api/v1/worker/lease", json!({"worker_id": failing, "wait_seconds": 0.0}));
    assert_eq!(code, 200, "{l}");
    let (code, _) = post(
        &server.url,
        &format!("/api/v1/worker/leases/{}/fail", l["lease_id"]),
        json!({"worker_id": failing, "error": "out of memory", "fatal": false}),
    );
    assert_eq!(code, 204);
    for k in 1..20 {
        register(&server.url, &format!("w{k}"), 1);
    }
    let (code, v) =
        post(&server.url, "/api/v1/worker/register", json!({"name": "one-too-many", "threads": 1}));
    assert_eq!(code, 503, "{v}");
    let error = v["error"].as_str().unwrap();
    assert!(error.contains("--max-workers") && error.contains("20 live workers"), "{error}");
    // Once they are lost (3.5 s of silence here), there is room again, and the table stays
    // near the cap: lost workers are forgotten past it.
    std::thread::sleep(Duration::from_secs(4));
    for k in 0..20 {
        register(&server.url, &format!("new{k}"), 1);
    }
    let rows = rows_of(&data, "SELECT count(*) FROM workers");
    assert!(rows <= 21, "{rows} worker rows for a cap of 20");
    // After --forget-workers-after-hours (7.2 s here) the silent ones are forgotten; the
    // highest id is kept so that ids are never handed out twice.
    wait_for(30, "the silent workers to be forgotten", &server, || {
        rows_of(&data, "SELECT count(*) FROM workers") <= 1
    });
    let (_, log) = get_api(&server.url, &format!("/api/v1/jobs/{job}/log"));
    let failed = log["events"].as_array().unwrap().iter().find(|e| e["kind"] == "tile_failed").cloned();
    assert_eq!(failed.as_ref().map(|e| e["worker"].clone()), Some(json!("forget-me")), "{log}");
    let (code, v) =
        post(&server.url, "/api/v1/worker/lease", json!({"worker_id": failing, "wait_seconds": 0.0}));
    assert_eq!(code, 404, "a forgotten worker registers again: {v}");
    eprintln!("max-workers 20: the 21st got 503; {rows} rows after 20 more; silent ones forgotten");
}

/// The server's own local worker, restarted during a registration flood, gets back in and
/// renders: the flood's limit is the worker token's, not the local workers'.
#[test]
fn a_local_worker_restarted_during_a_flood_registers_and_renders() {
    let _s = serial();
    let data = TempDir::new("cost-local");
    let server = Server::start(
        &data,
        &[
            "--api-token",
            API,
            "--worker-token",
            WORKER,
            "--local-workers",
            "1",
            "--local-worker-threads",
            "1",
        ],
    );
    let stop = Arc::new(AtomicBool::new(false));
    let url = server.url.clone();
    let flood = {
        let stop = stop.clone();
        std::thread::spawn(move || flood_registrations(&url, 2, 60.0, stop))
    };
    // The bucket is empty once a registration is refused.
    wait_for(30, "a refused registration", &server, || {
        post(&server.url, "/api/v1/worker/register", json!({"name": "probe", "threads": 1})).0 == 429
    });
    let pids = children(&server);
    assert_eq!(pids.len(), 1, "the local worker: {pids:?}");
    unsafe { libc::kill(pids[0], libc::SIGKILL) };
    let job = submit_small(&server.url, 8, 8);
    let done = wait_done(&server, job, 120);
    stop.store(true, Ordering::Relaxed);
    let (ok, refused, _, _, _) = flood.join().unwrap();
    let locals = get_json(&server.url, &format!("/api/v1/workers?access_token={API}"))["workers"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|w| w["name"] == "local-1")
        .count();
    eprintln!(
        "flood of {} registrations ({refused} refused); the restarted local worker rendered job {job}",
        ok + refused
    );
    assert_eq!(done["state"], "done");
    // It registered again after its restart on its own row: no ghost beside it.
    assert_eq!(locals, 1, "the restarted local worker has one row");
}

/// Row "`cameras=` (empty), `,` and ` , ` make jobs of 0 frames; `cameras=1` 32,000 times makes
/// 32,000 frames and a 7.6 MiB job JSON": an empty list is a 422 naming the field, a camera
/// named many times is one frame, and a job has at most `--max-job-frames` frames (1,024 here).
#[test]
fn camera_lists_are_checked_and_deduplicated() {
    let _s = serial();
    let data = TempDir::new("cost-cameras");
    let server = start_on(&data, &["--max-job-frames", "1024"]);
    let scene = tessera_testkit::tiny_scene(4, 4);
    for empty in ["", ",", " , "] {
        let (code, v) = submit_scene(&server.url, &scene, &[("cameras", empty)]);
        assert_eq!(code, 422, "cameras={empty:?}: {v}");
        assert!(
            v["error"]
                .as_str()
                .unwrap()
                .contains("cameras lists no camera; give ids like 1,3 or omit the field"),
            "{v}"
        );
    }
    let many = "1,".repeat(32_000);
    let (code, v) = submit_scene(&server.url, &scene, &[("cameras", &many)]);
    assert_eq!(code, 201, "{v}");
    assert_eq!(v["frames"].as_array().unwrap().len(), 1);
    let id = v["id"].as_u64().unwrap();
    let (_, job) = get_api(&server.url, &format!("/api/v1/jobs/{id}"));
    let bytes = job.to_string().len();
    assert!(bytes < 4096, "the job's JSON is {bytes} bytes");
    // More frames than a job may have, named or in the scene.
    let ids: Vec<String> = (1..=1025).map(|k| k.to_string()).collect();
    let (code, v) = submit_scene(&server.url, &scene, &[("cameras", &ids.join(","))]);
    assert_eq!(code, 422, "{v}");
    assert!(v["error"].as_str().unwrap().contains("more than the 1024 one job may"), "{v}");
    assert!(v["error"].as_str().unwrap().contains("--max-job-frames"), "{v}");
    let text = String::from_utf8(scene.clone()).unwrap();
    let (head, rest) = text.split_once("<Camera id=\"1\">").unwrap();
    let (camera, tail) = rest.split_once("</Camera>").unwrap();
    let cameras: String = (1..=1025).map(|k| format!("<Camera id=\"{k}\">{camera}</Camera>")).collect();
    let crowded = format!("{head}{cameras}{tail}");
    let (code, v) = submit_scene(&server.url, crowded.as_bytes(), &[]);
    assert_eq!(code, 422, "{v}");
    assert!(v["error"].as_str().unwrap().contains("1025"), "{v}");
    eprintln!(
        "cameras: empty lists 422; 32,000 x camera 1: one frame, {bytes} bytes of job JSON; 1,025 frames 422"
    );
}
