//! The job rules through the router, in process: requests go to [`app`] with `oneshot` (no
//! socket, no child process) over a real SQLite store in a temporary directory. The end-to-end
//! tests in `server/tests/` check the same rules against the real binaries.

use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::body::Body;
use axum::http::{HeaderMap, Method, Request, StatusCode, header};
use serde_json::{Value, json};
use tessera::protocol::{CHECKSUM_HEADER, checksum, encode_tile};
use tessera_testkit::TempDir;
use tower::ServiceExt;

use super::{AppState, Settings, app};
use crate::bundle::{BlobStore, Limits};
use crate::db::Store;
use crate::scheduler::Timing;
use tessera_testkit::tiny_scene;

const TOKEN: &str = "wtok";

/// A server without a socket: the router over a store in a directory of its own.
struct Farm {
    app: Router,
    state: AppState,
    /// The secret each worker registered through [`Farm::post`] was given, sent with its later
    /// requests as a real worker sends it.
    secrets: std::sync::Mutex<std::collections::HashMap<u64, String>>,
    _dir: TempDir,
}

impl Farm {
    /// Leases live `lease_seconds` without a heartbeat.
    fn new(lease_seconds: f64) -> Farm {
        let dir = TempDir::new("unit-api");
        let store = Arc::new(Store::open(&dir.path().join("tessera.db")).unwrap());
        let blobs = BlobStore::new(dir.path()).unwrap();
        let settings = Settings {
            data_dir: dir.path().to_path_buf(),
            tile_size: 32,
            api_token: None,
            worker_token: TOKEN.into(),
            max_upload_bytes: 16 << 20,
            bundle_limits: Limits::default(),
            max_job_tiles: 100_000,
            max_job_frames: 4096,
            max_job_samples: 1 << 40,
            access: Default::default(),
            max_job_units: 1_000_000,
            max_workers: 4096,
            local_worker_token: "local".into(),
            notify_allow: Vec::new(),
            forget_workers_after: 86_400.0,
            retention: Default::default(),
        };
        let timing =
            Timing { lease_seconds, heartbeat_seconds: 1.0, max_wait_seconds: 20.0, max_tile_seconds: 60.0 };
        let state = AppState::new(store, blobs, settings, timing);
        Farm { app: app(state.clone()), state, secrets: Default::default(), _dir: dir }
    }

    /// The status, headers and body (JSON, else a JSON string) of a request.
    async fn send(&self, req: Request<Body>) -> (StatusCode, HeaderMap, Value) {
        let resp = self.app.clone().oneshot(req).await.unwrap();
        let (parts, body) = resp.into_parts();
        let bytes = axum::body::to_bytes(body, usize::MAX).await.unwrap();
        let text = String::from_utf8_lossy(&bytes).into_owned();
        (parts.status, parts.headers, serde_json::from_str(&text).unwrap_or(Value::String(text)))
    }

    /// A worker-protocol POST (with the secret of the `worker_id` it names, once registered).
    async fn post(&self, path: &str, body: Value) -> (StatusCode, Value) {
        let secret = body["worker_id"].as_u64().map(|w| self.secret(w)).unwrap_or_default();
        let req = Request::builder()
            .method(Method::POST)
            .uri(path)
            .header(header::AUTHORIZATION, format!("Bearer {TOKEN}"))
            .header(tessera::protocol::WORKER_SECRET_HEADER, secret)
            .header(header::CONTENT_TYPE, "application/json")
            .body(Body::from(body.to_string()))
            .unwrap();
        let (status, _, v) = self.send(req).await;
        if path == "/api/v1/worker/register" && status == StatusCode::OK {
            let secret = v["worker_secret"].as_str().unwrap().to_string();
            self.secrets.lock().unwrap().insert(v["worker_id"].as_u64().unwrap(), secret);
        }
        (status, v)
    }

    /// Worker `w`'s secret ("" for a worker not registered through [`Farm::post`]).
    fn secret(&self, w: u64) -> String {
        self.secrets.lock().unwrap().get(&w).cloned().unwrap_or_default()
    }

    async fn get(&self, path: &str) -> (StatusCode, Value) {
        let (status, _, v) = self.send(Request::get(path).body(Body::empty()).unwrap()).await;
        (status, v)
    }

    /// Submits the tiny scene at `w` x `h` pixels in tiles of `tile`; returns the job id.
    async fn submit(&self, w: u32, h: u32, tile: u32, priority: i64) -> u64 {
        let scene = tiny_scene(w, h);
        let (content_type, body) = multipart(&[
            ("scene", Some("tiny.xml"), &scene),
            ("tile_size", None, tile.to_string().as_bytes()),
            ("priority", None, priority.to_string().as_bytes()),
        ]);
        let req = Request::post("/api/v1/jobs")
            .header(header::CONTENT_TYPE, content_type)
            .body(Body::from(body))
            .unwrap();
        let (status, _, v) = self.send(req).await;
        assert_eq!(status, StatusCode::CREATED, "{v}");
        v["id"].as_u64().unwrap()
    }

    async fn job(&self, id: u64) -> Value {
        let (status, v) = self.get(&format!("/api/v1/jobs/{id}")).await;
        assert_eq!(status, StatusCode::OK, "{v}");
        v
    }

    async fn cancel(&self, id: u64) -> (StatusCode, Value) {
        let (status, _, v) =
            self.send(Request::post(format!("/api/v1/jobs/{id}/cancel")).body(Body::empty()).unwrap()).await;
        (status, v)
    }

    /// Registers a worker of 16 threads (tests lease several tiles before rendering any).
    async fn register(&self, name: &str) -> u64 {
        let (status, v) = self.post("/api/v1/worker/register", json!({"name": name, "threads": 16})).await;
        assert_eq!(status, StatusCode::OK, "{v}");
        v["worker_id"].as_u64().unwrap()
    }

    /// A lease request waiting up to `wait` seconds: the lease, or None (204).
    async fn lease_within(&self, worker: u64, wait: f64) -> Option<Value> {
        let (status, v) =
            self.post("/api/v1/worker/lease", json!({"worker_id": worker, "wait_seconds": wait})).await;
        match status {
            StatusCode::OK => Some(v),
            StatusCode::NO_CONTENT => None,
            _ => panic!("lease: {status} {v}"),
        }
    }

    /// A lease without waiting, or None.
    async fn lease(&self, worker: u64) -> Option<Value> {
        self.lease_within(worker, 0.0).await
    }

    /// Sends the tile of `lease` (right size, right checksum unless `sum` says otherwise).
    async fn upload(&self, worker: u64, lease: &Value, sum: Option<&str>) -> (StatusCode, Value) {
        let r = &lease["rect"];
        let n = (r["width"].as_u64().unwrap() * r["height"].as_u64().unwrap()) as usize;
        let body = encode_tile(&vec![[1.0, 2.0, 3.0]; n]);
        let sum = sum.map_or_else(|| checksum(&body), str::to_string);
        let req = Request::put(format!("/api/v1/worker/leases/{}/result", lease["lease_id"]))
            .header(header::AUTHORIZATION, format!("Bearer {TOKEN}"))
            .header(tessera::protocol::WORKER_SECRET_HEADER, self.secret(worker))
            .header("x-tessera-worker", worker.to_string())
            .header(CHECKSUM_HEADER, sum)
            .body(Body::from(body))
            .unwrap();
        let (status, _, v) = self.send(req).await;
        (status, v)
    }

    async fn fail(&self, worker: u64, lease: &Value, error: &str, fatal: bool) -> StatusCode {
        let (status, v) = self
            .post(
                &format!("/api/v1/worker/leases/{}/fail", lease["lease_id"]),
                json!({"worker_id": worker, "error": error, "fatal": fatal}),
            )
            .await;
        assert!(status == StatusCode::NO_CONTENT || status == StatusCode::CONFLICT, "fail: {status} {v}");
        status
    }

    async fn heartbeat(&self, worker: u64, lease: &Value) -> Value {
        let (status, v) = self
            .post(
                "/api/v1/worker/heartbeat",
                json!({"worker_id": worker, "leases": [lease["lease_id"]], "rendering": lease["lease_id"]}),
            )
            .await;
        assert_eq!(status, StatusCode::OK, "{v}");
        v["revoked"].clone()
    }

    async fn metric(&self, name: &str) -> String {
        let (status, _, v) = self.send(Request::get("/metrics").body(Body::empty()).unwrap()).await;
        assert_eq!(status, StatusCode::OK);
        let text = v.as_str().unwrap().to_string();
        text.lines()
            .find_map(|l| l.strip_prefix(name).and_then(|v| v.strip_prefix(' ')).map(str::to_string))
            .unwrap_or_else(|| panic!("no {name} in\n{text}"))
    }
}

/// A multipart/form-data body: (field, file name or None, bytes).
fn multipart(parts: &[(&str, Option<&str>, &[u8])]) -> (String, Vec<u8>) {
    let boundary = "tessera-unit-boundary";
    let mut body = Vec::new();
    for (name, file, data) in parts {
        body.extend_from_slice(format!("--{boundary}\r\n").as_bytes());
        let disposition = match file {
            Some(f) => format!("Content-Disposition: form-data; name=\"{name}\"; filename=\"{f}\"\r\n\r\n"),
            None => format!("Content-Disposition: form-data; name=\"{name}\"\r\n\r\n"),
        };
        body.extend_from_slice(disposition.as_bytes());
        body.extend_from_slice(data);
        body.extend_from_slice(b"\r\n");
    }
    body.extend_from_slice(format!("--{boundary}--\r\n").as_bytes());
    (format!("multipart/form-data; boundary={boundary}"), body)
}

/// Long enough for the farm's leases not to expire during a test.
const LONG: f64 = 60.0;

/// Waits (a bounded while) until `task` is parked in its long poll.
async fn is_waiting<T>(task: &tokio::task::JoinHandle<T>) -> bool {
    tokio::time::sleep(Duration::from_millis(100)).await;
    !task.is_finished()
}

#[tokio::test]
async fn leases_go_to_the_highest_priority_then_the_oldest_job() {
    let farm = Farm::new(LONG);
    let low = farm.submit(2, 2, 64, 0).await;
    let low2 = farm.submit(2, 2, 64, 0).await;
    let high = farm.submit(2, 2, 64, 5).await;
    let w = farm.register("w").await;
    let mut order = Vec::new();
    while let Some(l) = farm.lease(w).await {
        order.push(l["job_id"].as_u64().unwrap());
    }
    assert_eq!(order, [high, low, low2]);
}

#[tokio::test]
async fn a_tile_failing_on_three_workers_fails_its_job() {
    let farm = Farm::new(LONG);
    let job = farm.submit(4, 4, 64, 0).await; // one tile
    for k in 0..3 {
        let w = farm.register(&format!("bad-{k}")).await;
        let l = farm.lease(w).await.expect("the failed tile is offered to the next worker");
        assert_eq!(
            farm.fail(w, &l, &format!("out of memory on bad-{k}"), false).await,
            StatusCode::NO_CONTENT
        );
        // The same worker is never given the tile it failed again.
        assert!(farm.lease(w).await.is_none());
        let state = farm.job(job).await["state"].clone();
        assert_eq!(state, if k < 2 { "running" } else { "failed" }, "after {} failure(s)", k + 1);
    }
    let j = farm.job(job).await;
    let err = j["error"].as_str().unwrap();
    assert!(err.contains("3 worker(s)") && err.contains("out of memory on bad-2"), "{err}");
    assert!(farm.lease(farm.register("fresh").await).await.is_none(), "a failed job's tile was handed out");
}

#[tokio::test]
async fn a_fatal_failure_fails_the_job_at_once() {
    let farm = Farm::new(LONG);
    let job = farm.submit(8, 8, 4, 0).await; // four tiles
    let w = farm.register("w").await;
    let l = farm.lease(w).await.unwrap();
    let second = farm.lease(w).await.unwrap();
    assert_eq!(farm.fail(w, &l, "the tile took longer than 60 s", true).await, StatusCode::NO_CONTENT);
    let j = farm.job(job).await;
    assert_eq!(j["state"], "failed", "{j}");
    assert!(j["error"].as_str().unwrap().contains("longer than 60 s"), "{j}");
    // Its other live lease is revoked with it.
    assert_eq!(farm.heartbeat(w, &second).await, json!([second["lease_id"]]));
    assert!(farm.lease(farm.register("other").await).await.is_none());
}

#[tokio::test]
async fn a_worker_failing_three_tiles_of_a_job_is_kept_off_that_job_only() {
    let farm = Farm::new(LONG);
    let job = farm.submit(8, 8, 2, 5).await; // 16 tiles
    let w = farm.register("flaky").await;
    for _ in 0..3 {
        let l = farm.lease(w).await.unwrap();
        assert_eq!(l["job_id"], job);
        assert_eq!(farm.fail(w, &l, "boom", false).await, StatusCode::NO_CONTENT);
    }
    assert!(farm.lease(w).await.is_none(), "a worker with 3 failures in the job got another of its tiles");
    // Other jobs still get it, and the job goes on with other workers.
    let other = farm.submit(2, 2, 64, 0).await;
    assert_eq!(farm.lease(w).await.unwrap()["job_id"], other);
    let good = farm.register("good").await;
    assert_eq!(farm.lease(good).await.unwrap()["job_id"], job);
    let j = farm.job(job).await;
    assert_eq!(j["state"], "running");
    assert!(j["error"].as_str().unwrap_or("").contains("boom"), "recent failures are shown: {j}");
}

#[tokio::test]
async fn a_result_is_accepted_once_from_the_lease_holder_with_the_right_bytes() {
    let farm = Farm::new(LONG);
    let job = farm.submit(8, 8, 4, 0).await; // four tiles
    let w = farm.register("w").await;
    let l = farm.lease(w).await.unwrap();
    // A damaged tile is refused and the lease stays live; so is a tile sent by another worker.
    let (status, v) = farm.upload(w, &l, Some("0000000000000000")).await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{v}");
    assert!(v["error"].as_str().unwrap().contains("checksum"), "{v}");
    let other = farm.register("other").await;
    assert_eq!(farm.upload(other, &l, None).await.0, StatusCode::CONFLICT);
    // Accepted once; the same lease again is a conflict.
    assert_eq!(farm.upload(w, &l, None).await.0, StatusCode::NO_CONTENT);
    let (status, v) = farm.upload(w, &l, None).await;
    assert_eq!(status, StatusCode::CONFLICT, "{v}");
    assert_eq!(farm.job(job).await["frames"][0]["tiles_done"], 1);
    assert_eq!(farm.metric("tessera_results_refused_total").await, "2");
    assert_eq!(farm.metric("tessera_tiles_done_total").await, "1");
}

#[tokio::test]
async fn an_expired_lease_is_a_failure_its_result_a_409_and_its_tile_queued_again() {
    let farm = Farm::new(0.05);
    let job = farm.submit(8, 8, 4, 0).await;
    let w = farm.register("silent").await;
    let l = farm.lease(w).await.unwrap();
    tokio::time::sleep(Duration::from_millis(120)).await;
    // Past its deadline the result is refused even before the expiry task has swept it.
    let (status, v) = farm.upload(w, &l, None).await;
    assert_eq!(status, StatusCode::CONFLICT, "{v}");
    assert_eq!(farm.state.scheduler.expire_leases().unwrap(), 1);
    assert_eq!(farm.heartbeat(w, &l).await, json!([l["lease_id"]]));
    // The expiry counts against the tile: its worker is not given it again, another is.
    let j = farm.job(job).await;
    assert_eq!(j["state"], "running");
    assert!(j["error"].as_str().unwrap().contains("stopped answering"), "{j}");
    let next = farm.lease(w).await.unwrap();
    assert_ne!(next["tile"], l["tile"]);
    let other = farm.register("other").await;
    let again = farm.lease(other).await.unwrap();
    assert_eq!((&again["job_id"], &again["tile"]), (&l["job_id"], &l["tile"]));
    assert_eq!(farm.metric("tessera_lease_expiries_total").await, "1");
    assert_eq!(farm.metric("tessera_results_refused_total").await, "1");
}

#[tokio::test]
async fn cancel_revokes_the_leases_and_answers_watches_at_once() {
    let farm = Farm::new(LONG);
    let job = farm.submit(8, 8, 4, 0).await;
    let w = farm.register("w").await;
    let l = farm.lease(w).await.unwrap();
    let watch = {
        let farm_app = farm.app.clone();
        let body = json!({"worker_id": w, "leases": [l["lease_id"]], "wait_seconds": 15.0});
        let secret = farm.secret(w);
        tokio::spawn(async move {
            let req = Request::post("/api/v1/worker/watch")
                .header(header::AUTHORIZATION, format!("Bearer {TOKEN}"))
                .header(tessera::protocol::WORKER_SECRET_HEADER, secret)
                .header(header::CONTENT_TYPE, "application/json")
                .body(Body::from(body.to_string()))
                .unwrap();
            let resp = farm_app.oneshot(req).await.unwrap();
            let bytes = axum::body::to_bytes(resp.into_body(), usize::MAX).await.unwrap();
            serde_json::from_slice::<Value>(&bytes).unwrap()
        })
    };
    assert!(is_waiting(&watch).await, "the watch answered before anything was revoked");
    let (status, v) = farm.cancel(job).await;
    assert_eq!(status, StatusCode::OK, "{v}");
    assert_eq!(v["state"], "canceled");
    let answer = tokio::time::timeout(Duration::from_secs(5), watch).await.expect("the watch hangs").unwrap();
    assert_eq!(answer["revoked"], json!([l["lease_id"]]));
    assert_eq!(farm.heartbeat(w, &l).await, json!([l["lease_id"]]));
    assert_eq!(farm.upload(w, &l, None).await.0, StatusCode::CONFLICT);
    assert!(farm.lease(w).await.is_none(), "a cancelled job's tile was handed out");
    assert_eq!(farm.cancel(job).await.0, StatusCode::CONFLICT);
}

#[tokio::test]
async fn a_waiting_lease_request_wakes_when_a_job_is_submitted() {
    let farm = Arc::new(Farm::new(LONG));
    let w = farm.register("w").await;
    let waiting = {
        let farm = farm.clone();
        tokio::spawn(async move { farm.lease_within(w, 15.0).await })
    };
    assert!(is_waiting(&waiting).await, "the lease request answered with nothing to lease");
    let job = farm.submit(2, 2, 64, 0).await;
    // Woken well before its 15 s wait ends.
    let lease = tokio::time::timeout(Duration::from_secs(5), waiting).await.expect("not woken").unwrap();
    assert_eq!(lease.expect("woken without a lease")["job_id"], job);
}

#[tokio::test]
async fn a_waiting_lease_request_wakes_when_a_tile_is_given_back_or_fails() {
    let farm = Arc::new(Farm::new(LONG));
    farm.submit(2, 2, 64, 0).await; // one tile
    let mut holder = farm.register("a").await;
    let mut lease = farm.lease(holder).await.unwrap();
    for (name, how) in [("b", "release"), ("c", "fail")] {
        let next = farm.register(name).await;
        let waiting = {
            let farm = farm.clone();
            tokio::spawn(async move { farm.lease_within(next, 15.0).await })
        };
        assert!(is_waiting(&waiting).await, "a lease came while the only tile was leased");
        if how == "release" {
            let path = format!("/api/v1/worker/leases/{}/release", lease["lease_id"]);
            let (status, v) = farm.post(&path, json!({"worker_id": holder})).await;
            assert_eq!(status, StatusCode::NO_CONTENT, "{v}");
            assert_eq!(farm.post(&path, json!({"worker_id": holder})).await.0, StatusCode::CONFLICT);
        } else {
            assert_eq!(farm.fail(holder, &lease, "boom", false).await, StatusCode::NO_CONTENT);
        }
        // Woken well before its 15 s wait ends.
        let got = tokio::time::timeout(Duration::from_secs(5), waiting)
            .await
            .unwrap_or_else(|_| panic!("not woken by the {how}"))
            .unwrap()
            .expect("woken without a lease");
        assert_eq!(got["tile"], lease["tile"]);
        (holder, lease) = (next, got);
    }
}

#[tokio::test]
async fn lease_requests_answer_503_once_the_server_stops() {
    let farm = Arc::new(Farm::new(LONG));
    let w = farm.register("w").await;
    let waiting = {
        let farm = farm.clone();
        tokio::spawn(async move {
            farm.post("/api/v1/worker/lease", json!({"worker_id": w, "wait_seconds": 15.0})).await
        })
    };
    assert!(is_waiting(&waiting).await);
    farm.state.scheduler.begin_shutdown();
    let (status, v) =
        tokio::time::timeout(Duration::from_secs(5), waiting).await.expect("not woken").unwrap();
    assert_eq!(status, StatusCode::SERVICE_UNAVAILABLE, "{v}");
    farm.submit(2, 2, 64, 0).await;
    let (status, _) = farm.post("/api/v1/worker/lease", json!({"worker_id": w, "wait_seconds": 0.0})).await;
    assert_eq!(status, StatusCode::SERVICE_UNAVAILABLE, "a stopping server handed out a lease");
}

#[tokio::test]
async fn each_api_needs_its_token() {
    let farm = Farm::new(LONG);
    let req = Request::post("/api/v1/worker/register")
        .header(header::CONTENT_TYPE, "application/json")
        .body(Body::from(json!({"name": "x", "threads": 1}).to_string()))
        .unwrap();
    assert_eq!(farm.send(req).await.0, StatusCode::UNAUTHORIZED);
    let req = Request::post("/api/v1/worker/register")
        .header(header::AUTHORIZATION, "Bearer wrong")
        .header(header::CONTENT_TYPE, "application/json")
        .body(Body::from(json!({"name": "x", "threads": 1}).to_string()))
        .unwrap();
    assert_eq!(farm.send(req).await.0, StatusCode::UNAUTHORIZED);
    let (status, v) = farm.post("/api/v1/worker/lease", json!({"worker_id": 999, "wait_seconds": 0.0})).await;
    assert_eq!(status, StatusCode::NOT_FOUND, "{v}");
}

/// One bad request of the error-shape table: what is sent and the status it must get.
struct Bad {
    method: Method,
    uri: &'static str,
    /// Send the worker token.
    worker: bool,
    content_type: Option<&'static str>,
    body: Vec<u8>,
    status: StatusCode,
    /// A word the message must hold (it says what was wrong).
    says: &'static str,
}

fn bad(method: Method, uri: &'static str, status: StatusCode, says: &'static str) -> Bad {
    Bad { method, uri, worker: false, content_type: None, body: Vec::new(), status, says }
}

fn bad_worker(
    uri: &'static str,
    content_type: Option<&'static str>,
    body: &[u8],
    status: StatusCode,
    says: &'static str,
) -> Bad {
    Bad { method: Method::POST, uri, worker: true, content_type, body: body.to_vec(), status, says }
}

#[tokio::test]
async fn every_error_is_the_documented_json_error() {
    let farm = Farm::new(LONG);
    let job = farm.submit(8, 8, 4, 0).await;
    assert_eq!(job, 1, "the table's URIs name job 1");
    let json = Some("application/json");
    let over_limit = vec![b' '; (16 << 20) + 1];
    let table = vec![
        // Path parameters that do not parse.
        bad(Method::GET, "/api/v1/jobs/abc", StatusCode::BAD_REQUEST, "abc"),
        bad(Method::GET, "/api/v1/jobs/-1", StatusCode::BAD_REQUEST, "-1"),
        bad(
            Method::GET,
            "/api/v1/jobs/99999999999999999999999",
            StatusCode::BAD_REQUEST,
            "99999999999999999999999",
        ),
        bad(Method::GET, "/api/v1/jobs/1/frames/x/preview.png", StatusCode::BAD_REQUEST, "x"),
        bad(Method::GET, "/api/v1/jobs/abc/log", StatusCode::BAD_REQUEST, "abc"),
        bad(Method::POST, "/api/v1/jobs/abc/cancel", StatusCode::BAD_REQUEST, "abc"),
        // Query strings.
        bad(Method::GET, "/api/v1/jobs/1/frames/0/tonemap.png?key=x", StatusCode::BAD_REQUEST, "key"),
        bad(Method::GET, "/api/v1/jobs/1/frames/0/tonemap.png?burn=1e999x", StatusCode::BAD_REQUEST, "burn"),
        bad(Method::GET, "/api/v1/jobs/1/log?after=soon", StatusCode::BAD_REQUEST, "after"),
        // The handlers' own refusals (already JSON; they stay so).
        bad(Method::GET, "/api/v1/jobs/7", StatusCode::NOT_FOUND, "no job 7"),
        bad(Method::GET, "/api/v1/jobs/7/log", StatusCode::NOT_FOUND, "no job 7"),
        bad(Method::GET, "/api/v1/jobs/1/frames/0/tonemap.png?key=2", StatusCode::CONFLICT, "not finished"),
        // Unknown routes and wrong methods.
        bad(Method::GET, "/api/v1/nothing", StatusCode::NOT_FOUND, "no such endpoint"),
        bad(Method::GET, "/static/nothing.js", StatusCode::NOT_FOUND, "no such file"),
        bad(Method::DELETE, "/api/v1/jobs", StatusCode::METHOD_NOT_ALLOWED, "GET"),
        bad(Method::PUT, "/healthz", StatusCode::METHOD_NOT_ALLOWED, "GET"),
        bad(Method::GET, "/api/v1/jobs/1/cancel", StatusCode::METHOD_NOT_ALLOWED, "POST"),
        Bad {
            worker: true,
            ..bad(Method::GET, "/api/v1/worker/lease", StatusCode::METHOD_NOT_ALLOWED, "POST")
        },
        // Submissions that are not multipart.
        bad(Method::POST, "/api/v1/jobs", StatusCode::BAD_REQUEST, "boundary"),
        // Worker bodies: no content type, not JSON, the wrong shape, too large.
        bad_worker(
            "/api/v1/worker/register",
            None,
            br#"{"name": "w", "threads": 1}"#,
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "application/json",
        ),
        bad_worker("/api/v1/worker/register", json, b"{", StatusCode::BAD_REQUEST, "EOF"),
        bad_worker(
            "/api/v1/worker/register",
            json,
            br#"{"name": "w"}"#,
            StatusCode::UNPROCESSABLE_ENTITY,
            "threads",
        ),
        bad_worker(
            "/api/v1/worker/register",
            json,
            br#"{"name": "w", "threads": -1}"#,
            StatusCode::UNPROCESSABLE_ENTITY,
            "threads",
        ),
        bad_worker(
            "/api/v1/worker/lease",
            json,
            br#"{"worker_id": "one", "wait_seconds": 0}"#,
            StatusCode::UNPROCESSABLE_ENTITY,
            "worker_id",
        ),
        bad_worker(
            "/api/v1/worker/leases/abc/fail",
            json,
            br#"{"worker_id": 1, "error": "x"}"#,
            StatusCode::BAD_REQUEST,
            "abc",
        ),
        bad_worker(
            "/api/v1/worker/leases/5/release",
            json,
            b"[]",
            StatusCode::UNPROCESSABLE_ENTITY,
            "ReleaseRequest",
        ),
        bad_worker("/api/v1/worker/heartbeat", json, &over_limit, StatusCode::PAYLOAD_TOO_LARGE, "limit"),
        Bad {
            method: Method::PUT,
            uri: "/api/v1/worker/leases/abc/result",
            worker: true,
            content_type: None,
            body: vec![0; 12],
            status: StatusCode::BAD_REQUEST,
            says: "abc",
        },
        Bad {
            method: Method::GET,
            uri: "/api/v1/worker/bundles/abc",
            worker: false,
            content_type: None,
            body: Vec::new(),
            status: StatusCode::UNAUTHORIZED,
            says: "token",
        },
    ];
    for case in table {
        let mut req = Request::builder().method(case.method.clone()).uri(case.uri);
        if case.worker {
            req = req.header(header::AUTHORIZATION, format!("Bearer {TOKEN}"));
        }
        if let Some(t) = case.content_type {
            req = req.header(header::CONTENT_TYPE, t);
        }
        let (status, headers, v) = farm.send(req.body(Body::from(case.body)).unwrap()).await;
        let what = format!("{} {}", case.method, case.uri);
        assert_eq!(status, case.status, "{what}: {v}");
        assert_eq!(headers[header::CONTENT_TYPE], "application/json", "{what}");
        let e: tessera::protocol::ApiError = serde_json::from_value(v.clone())
            .unwrap_or_else(|err| panic!("{what}: not an ApiError ({err}): {v}"));
        assert!(e.error.contains(case.says), "{what}: the message does not say {:?}: {}", case.says, e.error);
        if status == StatusCode::METHOD_NOT_ALLOWED {
            assert!(headers.contains_key(header::ALLOW), "{what}: a 405 keeps its Allow header");
        }
    }
}

/// The paths the router itself holds. axum has no API to list routes, but its `Debug` output
/// names each path (`RouteId(n): "/path"`); this reads them from there, so the list comes from
/// the router that serves, not from a copy. Should axum change that output, the checks below
/// fail (they demand the health check among the paths found), not pass over nothing.
fn router_paths(app: &Router) -> std::collections::BTreeSet<String> {
    let dump = format!("{app:?}");
    let mut paths = std::collections::BTreeSet::new();
    for (at, _) in dump.match_indices("RouteId(") {
        let rest = &dump[at + "RouteId(".len()..];
        let digits = rest.chars().take_while(char::is_ascii_digit).count();
        let Some(quoted) = rest[digits..].strip_prefix("): \"") else { continue };
        let path = &quoted[..quoted.find('"').unwrap()];
        if !path.contains("__private__") {
            paths.insert(path.to_string());
        }
    }
    paths
}

#[tokio::test]
async fn every_route_of_the_router_is_in_the_openapi_description_and_nothing_else() {
    let farm = Farm::new(LONG);
    // The routes as `app` holds them, under its outer layers.
    let paths = router_paths(&super::routed(farm.state.clone()));
    assert!(paths.contains("/healthz") && paths.contains("/api/v1/jobs/{id}/log"), "{paths:?}");
    // Each path's methods, as the router answers them: a method no route has gets a 405 whose
    // Allow header lists the path's methods.
    let probe = Method::from_bytes(b"PROBE").unwrap();
    let mut routed = std::collections::BTreeSet::new();
    for path in &paths {
        let uri: String = path
            .split('/')
            .map(|seg| if seg.starts_with('{') { "1" } else { seg })
            .collect::<Vec<_>>()
            .join("/");
        let req = Request::builder()
            .method(probe.clone())
            .uri(&uri)
            .header(header::AUTHORIZATION, format!("Bearer {TOKEN}"))
            .body(Body::empty())
            .unwrap();
        let (status, headers, v) = farm.send(req).await;
        assert_eq!(status, StatusCode::METHOD_NOT_ALLOWED, "PROBE {uri}: {v}");
        let allow = headers[header::ALLOW].to_str().unwrap();
        for m in allow.split(',').map(str::trim).filter(|m| *m != "HEAD") {
            routed.insert((path.clone(), m.to_string()));
        }
    }
    // What the server describes, as it serves it.
    let (status, headers, spec) =
        farm.send(Request::get("/api/v1/openapi.json").body(Body::empty()).unwrap()).await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(headers[header::CONTENT_TYPE], "application/json");
    let mut described = std::collections::BTreeSet::new();
    for (path, item) in spec["paths"].as_object().expect("paths") {
        for method in ["get", "put", "post", "delete", "patch", "options", "head", "trace"] {
            if item.get(method).is_some() {
                described.insert((path.clone(), method.to_ascii_uppercase()));
            }
        }
    }
    let undocumented: Vec<_> = routed.difference(&described).collect();
    let phantom: Vec<_> = described.difference(&routed).collect();
    assert!(undocumented.is_empty(), "routes missing from /api/v1/openapi.json: {undocumented:?}");
    assert!(phantom.is_empty(), "described but not routed: {phantom:?}");
    assert!(routed.len() >= 22, "only {} routes found: {routed:?}", routed.len());
    // The description served is the one the code makes.
    assert_eq!(spec, serde_json::to_value(super::openapi_description(&farm.state)).unwrap());
}

#[tokio::test]
async fn the_log_endpoint_serves_a_jobs_events_and_only_the_new_ones_after_seq() {
    let farm = Farm::new(LONG);
    let job = farm.submit(8, 4, 4, 0).await; // two tiles
    let w = farm.register("w-log").await;
    let l = farm.lease(w).await.unwrap();
    let body = encode_tile(&[[0.5, 0.5, 0.5]; 16]);
    let req = Request::put(format!("/api/v1/worker/leases/{}/result", l["lease_id"]))
        .header(header::AUTHORIZATION, format!("Bearer {TOKEN}"))
        .header(tessera::protocol::WORKER_SECRET_HEADER, farm.secret(w))
        .header("x-tessera-worker", w.to_string())
        .header(CHECKSUM_HEADER, checksum(&body))
        .header(tessera::protocol::RENDER_SECONDS_HEADER, "0.25")
        .body(Body::from(body))
        .unwrap();
    assert_eq!(farm.send(req).await.0, StatusCode::NO_CONTENT);
    let l2 = farm.lease(w).await.unwrap();
    // A nonsense render time is not recorded.
    let body = encode_tile(&[[0.5, 0.5, 0.5]; 16]);
    let req = Request::put(format!("/api/v1/worker/leases/{}/result", l2["lease_id"]))
        .header(header::AUTHORIZATION, format!("Bearer {TOKEN}"))
        .header(tessera::protocol::WORKER_SECRET_HEADER, farm.secret(w))
        .header("x-tessera-worker", w.to_string())
        .header(CHECKSUM_HEADER, checksum(&body))
        .header(tessera::protocol::RENDER_SECONDS_HEADER, "NaN")
        .body(Body::from(body))
        .unwrap();
    assert_eq!(farm.send(req).await.0, StatusCode::NO_CONTENT);
    // The merge runs in the background: wait (boundedly) for the job's end in its log.
    let mut log = Value::Null;
    for _ in 0..100 {
        let (status, v) = farm.get(&format!("/api/v1/jobs/{job}/log")).await;
        assert_eq!(status, StatusCode::OK, "{v}");
        log = v;
        if log["events"].as_array().unwrap().iter().any(|e| e["kind"] == "job_done") {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let log: tessera::protocol::JobLog = serde_json::from_value(log).unwrap();
    assert_eq!(log.job, job);
    let kinds: Vec<&str> = log.events.iter().map(|e| e.kind.as_str()).collect();
    assert_eq!(kinds, ["accepted", "tile_done", "tile_done", "frame_merged", "job_done"]);
    assert_eq!((log.events[1].tile, log.events[1].worker.as_deref()), (Some(0), Some("w-log")));
    assert_eq!(log.events[1].seconds, Some(0.25));
    assert_eq!(log.events[2].seconds, None);
    let (status, rest) = farm.get(&format!("/api/v1/jobs/{job}/log?after=2")).await;
    assert_eq!(status, StatusCode::OK);
    let rest: tessera::protocol::JobLog = serde_json::from_value(rest).unwrap();
    assert_eq!(rest.events, log.events[2..]);
}
