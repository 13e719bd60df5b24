//! The worker protocol's rules, checked against the real server over HTTP with hand-driven
//! workers (the test plays the worker, so it can be late, wrong or failing on purpose).

mod support;

use serde_json::{Value, json};
use support::*;
use tessera::protocol::{checksum, encode_tile};

const TOKEN: &str = "wtok";

fn post(url: &str, path: &str, body: Value) -> (u16, Value) {
    worker_post(url, TOKEN, path, body)
}

/// Registers a worker of 16 threads: tests lease several tiles before rendering any, within
/// its limit of threads + 2 live leases.
fn register(url: &str, name: &str) -> u64 {
    let (code, v) = post(url, "/api/v1/worker/register", json!({"name": name, "threads": 16}));
    assert_eq!(code, 200, "{v}");
    v["worker_id"].as_u64().unwrap()
}

/// A lease without waiting, or None (204).
fn lease(url: &str, worker: u64) -> Option<Value> {
    let (code, v) = post(url, "/api/v1/worker/lease", json!({"worker_id": worker, "wait_seconds": 0.0}));
    match code {
        200 => Some(v),
        204 => None,
        _ => panic!("lease: {code} {v}"),
    }
}

fn upload(url: &str, worker: u64, lease: &Value, pixels: &[[f32; 3]], sum: Option<&str>) -> (u16, Value) {
    let body = encode_tile(pixels);
    let sum = sum.map(str::to_string).unwrap_or_else(|| checksum(&body));
    let id = lease["lease_id"].as_u64().unwrap();
    let req = ureq::put(&format!("{url}/api/v1/worker/leases/{id}/result"))
        .set("Authorization", &format!("Bearer {TOKEN}"))
        .set("x-tessera-worker", &worker.to_string())
        .set("x-tessera-worker-secret", &worker_secret(url, worker).unwrap_or_default())
        .set("x-tessera-checksum", &sum);
    call(req, Some(("application/octet-stream".into(), body)))
}

fn pixels_for(lease: &Value) -> Vec<[f32; 3]> {
    let r = &lease["rect"];
    vec![[1.0, 2.0, 3.0]; (r["width"].as_u64().unwrap() * r["height"].as_u64().unwrap()) as usize]
}

fn submit_tiny(url: &str, w: u32, h: u32, tile: u32, priority: i64) -> u64 {
    let scene = tessera_testkit::tiny_scene(w, h);
    let (code, v) = submit(
        url,
        None,
        &[
            ("scene", Some("tiny.xml"), &scene),
            ("tile_size", None, tile.to_string().as_bytes()),
            ("priority", None, priority.to_string().as_bytes()),
        ],
    );
    assert_eq!(code, 201, "{v}");
    v["id"].as_u64().unwrap()
}

fn start() -> Server {
    Server::start_temp(
        &format!("farm-proto-{}", std::thread::current().name().unwrap_or("t").replace("::", "-")),
        &[
            "--local-workers",
            "0",
            "--worker-token",
            TOKEN,
            "--lease-seconds",
            "1",
            "--heartbeat-seconds",
            "0.3",
        ],
    )
}

#[test]
fn results_are_accepted_once_checked_and_refused_after_expiry() {
    let _s = serial();
    let server = start();
    let url = &server.url;
    let job = submit_tiny(url, 8, 8, 4, 0); // 4 tiles
    let w = register(url, "fake");

    // Accepted once; the same lease again is a conflict.
    let l1 = lease(url, w).unwrap();
    assert_eq!(l1["job_id"], job);
    let (code, v) = upload(url, w, &l1, &pixels_for(&l1), None);
    assert_eq!(code, 204, "{v}");
    let (code, v) = upload(url, w, &l1, &pixels_for(&l1), None);
    assert_eq!(code, 409, "{v}");

    // A damaged tile (checksum mismatch) and a wrong size are refused, the lease stays live.
    let l2 = lease(url, w).unwrap();
    let (code, v) = upload(url, w, &l2, &pixels_for(&l2), Some("0000000000000000"));
    assert_eq!(code, 400, "{v}");
    assert!(v["error"].as_str().unwrap().contains("checksum"), "{v}");
    let (code, v) = upload(url, w, &l2, &[[0.0; 3]], None);
    assert_eq!(code, 400, "{v}");
    // Another worker cannot deliver it.
    let other = register(url, "other");
    let (code, _) = upload(url, other, &l2, &pixels_for(&l2), None);
    assert_eq!(code, 409);

    // Without heartbeats the lease expires (1 s), the tile is handed out again, and the late
    // result is refused.
    std::thread::sleep(std::time::Duration::from_millis(2500));
    let (code, v) = upload(url, w, &l2, &pixels_for(&l2), None);
    assert_eq!(code, 409, "{v}");
    let again = lease(url, other).unwrap();
    assert_eq!((again["tile"].clone(), again["job_id"].clone()), (l2["tile"].clone(), l2["job_id"].clone()));
    // A heartbeat tells the first worker its lease is gone; the second keeps its own.
    let (code, hb) = post(
        url,
        "/api/v1/worker/heartbeat",
        json!({"worker_id": w, "leases": [l2["lease_id"]], "rendering": l2["lease_id"]}),
    );
    assert_eq!(code, 200);
    assert_eq!(hb["revoked"], json!([l2["lease_id"]]));
    let (_, hb) = post(
        url,
        "/api/v1/worker/heartbeat",
        json!({"worker_id": other, "leases": [again["lease_id"]], "rendering": null}),
    );
    assert_eq!(hb["revoked"], json!([]));
    let metrics = String::from_utf8(get_bytes(url, "/metrics")).unwrap();
    assert!(metrics.contains("tessera_lease_expiries_total 1"), "{metrics}");
    assert!(metrics.contains("tessera_results_refused_total 3"), "{metrics}");
}

#[test]
fn a_tile_failing_on_three_workers_fails_the_job() {
    let _s = serial();
    let server = start();
    let url = &server.url;
    let job = submit_tiny(url, 4, 4, 64, 0); // one tile
    for k in 0..3 {
        let w = register(url, &format!("bad-{k}"));
        let l = lease(url, w).expect("the failed tile is offered to the next worker");
        let (code, v) = post(
            url,
            &format!("/api/v1/worker/leases/{}/fail", l["lease_id"]),
            json!({"worker_id": w, "error": format!("out of memory on bad-{k}")}),
        );
        assert_eq!(code, 204, "{v}");
        // The same worker is not given the tile it failed again.
        assert!(lease(url, w).is_none());
    }
    let j = get_json(url, &format!("/api/v1/jobs/{job}"));
    assert_eq!(j["state"], "failed", "{j}");
    let err = j["error"].as_str().unwrap();
    assert!(err.contains("3 worker(s)") && err.contains("out of memory on bad-2"), "{err}");
}

#[test]
fn a_worker_failing_three_tiles_of_a_job_is_kept_off_it() {
    let _s = serial();
    let server = start();
    let url = &server.url;
    let job = submit_tiny(url, 8, 8, 2, 0); // 16 tiles
    let w = register(url, "flaky");
    for _ in 0..3 {
        let l = lease(url, w).unwrap();
        let (code, _) = post(
            url,
            &format!("/api/v1/worker/leases/{}/fail", l["lease_id"]),
            json!({"worker_id": w, "error": "boom"}),
        );
        assert_eq!(code, 204);
    }
    assert!(lease(url, w).is_none(), "a worker with 3 failures in the job got another of its tiles");
    // The job goes on with other workers.
    let good = register(url, "good");
    let l = lease(url, good).unwrap();
    assert_eq!(l["job_id"], job);
    let j = get_json(url, &format!("/api/v1/jobs/{job}"));
    assert_eq!(j["state"], "running");
    assert!(j["error"].as_str().unwrap_or("").contains("boom"), "recent failures are shown: {j}");
}

#[test]
fn higher_priority_jobs_go_first_then_submission_order() {
    let _s = serial();
    let server = start();
    let url = &server.url;
    let low = submit_tiny(url, 2, 2, 64, 0);
    let low2 = submit_tiny(url, 2, 2, 64, 0);
    let high = submit_tiny(url, 2, 2, 64, 5);
    let w = register(url, "w");
    let order: Vec<u64> = (0..3).map(|_| lease(url, w).unwrap()["job_id"].as_u64().unwrap()).collect();
    assert_eq!(order, [high, low, low2]);
}

#[test]
fn unknown_workers_and_bad_bodies_are_refused() {
    let _s = serial();
    let server = start();
    let url = &server.url;
    let (code, v) = post(url, "/api/v1/worker/lease", json!({"worker_id": 999, "wait_seconds": 0.0}));
    assert_eq!(code, 404, "{v}");
    assert!(v["error"].as_str().unwrap().contains("register"), "{v}");
    let (code, _) = post(url, "/api/v1/worker/register", json!({"nom": "x"}));
    assert!((400..500).contains(&code));
    // A worker of another protocol version is told why, before it can misread a lease; the
    // server's own version is in every register answer, for the worker to check.
    let (code, v) = post(url, "/api/v1/worker/register", json!({"name": "w", "threads": 1, "protocol": 999}));
    assert_eq!(code, 422, "{v}");
    let e = v["error"].as_str().unwrap();
    assert!(e.contains("protocol 999") && e.contains("same Tessera version"), "{v}");
    let (code, v) = post(url, "/api/v1/worker/register", json!({"name": "w", "threads": 1}));
    assert_eq!((code, &v["protocol"]), (200, &json!(tessera::protocol::WORKER_PROTOCOL)), "{v}");
    let (code, v) = call(ureq::get(&format!("{url}/api/v1/nothing")), None);
    assert_eq!(code, 404, "{v}");
    let (code, _) = call(
        ureq::get(&format!("{url}/api/v1/worker/bundles/abc")).set("Authorization", "Bearer wtok"),
        None,
    );
    assert_eq!(code, 404);
}

/// A worker killed just after sending a result (its whole body out, its connection closed
/// before the answer, after a delay anywhere from none to a few milliseconds) never leaves a
/// frame stored and unmerged: each result is either taken whole (the frame merges) or not at all
/// (its lease expires and another worker renders the tile). An honest worker then finishes what
/// is left, and every job ends.
#[test]
fn results_whose_senders_hang_up_at_once_never_leave_a_frame_unmerged() {
    use std::io::Write;
    let _s = serial();
    // Leases of 10 s: none expires while the hang-ups are sent, however slow the machine, so
    // each lease below is the new job's only tile.
    let server = Server::start_temp(
        "farm-proto-hang-ups",
        &[
            "--local-workers",
            "0",
            "--worker-token",
            TOKEN,
            "--lease-seconds",
            "10",
            "--heartbeat-seconds",
            "1",
        ],
    );
    let url = &server.url;
    let addr = url.trim_start_matches("http://");
    // Hang-ups after no delay, then every 20 us up to 1 ms, then 10 % later each up to 20 ms:
    // the moment the handler stores the result is somewhere among them on any machine.
    let mut delays: Vec<u64> = (0..50).map(|k| k * 20).collect();
    while *delays.last().unwrap() < 20_000 {
        let next = delays.last().unwrap() * 11 / 10;
        delays.push(next);
    }
    let max_delay = std::time::Duration::from_micros(*delays.last().unwrap());
    // A hang-up before the result is stored leaves its lease live until it expires, and a worker
    // may hold at most threads + 2 = 18: a new worker takes over every 16 delays, so the cap
    // is never what refuses a lease however many hang-ups land early on a slow machine.
    let mut w = 0;
    let jobs: Vec<u64> = delays
        .iter()
        .enumerate()
        .map(|(k, &micros)| {
            if k % 16 == 0 {
                w = register(url, &format!("hangs-up-{}", k / 16));
            }
            let job = submit_tiny(url, 8, 8, 8, 0); // one tile
            let l = lease(url, w).unwrap();
            assert_eq!(l["job_id"], job);
            let body = encode_tile(&pixels_for(&l));
            let id = l["lease_id"].as_u64().unwrap();
            let mut conn = std::net::TcpStream::connect(addr).unwrap();
            let head = format!(
                "PUT /api/v1/worker/leases/{id}/result HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {TOKEN}\r\n\
                 x-tessera-worker: {w}\r\nx-tessera-worker-secret: {}\r\nx-tessera-checksum: {}\r\n\
                 Content-Type: application/octet-stream\r\nContent-Length: {}\r\n\r\n",
                worker_secret(url, w).unwrap_or_default(),
                checksum(&body),
                body.len()
            );
            conn.write_all(head.as_bytes()).unwrap();
            conn.write_all(&body).unwrap();
            std::thread::sleep(std::time::Duration::from_micros(micros));
            drop(conn);
            job
        })
        .collect();
    // The later hang-ups came after the answer was ready: those results were taken (so the
    // delays do reach past the window where a hang-up could cut the handler short).
    let taken =
        jobs.iter().filter(|j| get_json(url, &format!("/api/v1/jobs/{j}"))["state"] == "done").count();
    assert!(taken > 0, "no result was taken although some senders waited {max_delay:?}\n{}", server.log());
    // The hung-up leases expire (10 s); an honest worker renders whatever went back to the queue.
    let honest = register(url, "honest");
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    let mut left = jobs.clone();
    while !left.is_empty() {
        assert!(std::time::Instant::now() < deadline, "jobs never ended: {left:?}\n{}", server.log());
        while let Some(l) = lease(url, honest) {
            let (code, v) = upload(url, honest, &l, &pixels_for(&l), None);
            assert_eq!(code, 204, "{v}");
        }
        left.retain(|&j| get_json(url, &format!("/api/v1/jobs/{j}"))["state"] != "done");
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
}
