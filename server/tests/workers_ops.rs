//! Managing workers day to day, against the real server: a drained worker finishes what it
//! holds and takes nothing new, a disabled one gives its tiles back at once, an enabled one
//! works again; a restarted server's local worker keeps its one row; the client drives it all.

mod support;

use std::process::Command;
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use support::*;

const TOKEN: &str = "wtok";

fn post(url: &str, path: &str, body: Value) -> (u16, Value) {
    worker_post(url, TOKEN, path, body)
}

fn register(url: &str, name: &str) -> u64 {
    let (code, v) = post(url, "/api/v1/worker/register", json!({"name": name, "threads": 4}));
    assert_eq!(code, 200, "{v}");
    v["worker_id"].as_u64().unwrap()
}

/// A lease within `wait` seconds, or None (204).
fn lease(url: &str, worker: u64, wait: f64) -> Option<Value> {
    let (code, v) = post(url, "/api/v1/worker/lease", json!({"worker_id": worker, "wait_seconds": wait}));
    match code {
        200 => Some(v),
        204 => None,
        _ => panic!("lease: {code} {v}"),
    }
}

fn operator(url: &str, path: &str) -> (u16, Value) {
    call(ureq::post(&format!("{url}{path}")), Some(("text/plain".into(), Vec::new())))
}

fn worker_json(url: &str, id: u64) -> Value {
    get_json(url, "/api/v1/workers")["workers"]
        .as_array()
        .unwrap()
        .iter()
        .find(|w| w["id"] == id)
        .unwrap()
        .clone()
}

#[test]
fn drained_and_disabled_workers_take_no_new_tile() {
    let _serial = serial();
    let server = Server::start_temp("workers-modes", &["--local-workers", "0", "--worker-token", TOKEN]);
    let url = &server.url;
    // 16 tiles of 8 px.
    let job = submit_environment_with(&server, "1", "8", &[]);
    let a = register(url, "a");
    // b may hold every tile of the job (threads + 2 leases).
    let b = {
        let (code, v) = post(url, "/api/v1/worker/register", json!({"name": "b", "threads": 16}));
        assert_eq!(code, 200, "{v}");
        v["worker_id"].as_u64().unwrap()
    };
    let held = lease(url, a, 0.0).expect("a tile for a");

    // Draining: a keeps its tile (a heartbeat renews it) but gets no new one, however long it asks.
    let (code, w) = operator(url, &format!("/api/v1/workers/{a}/drain"));
    assert_eq!((code, w["mode"].as_str()), (200, Some("draining")), "{w}");
    assert!(lease(url, a, 1.0).is_none(), "a draining worker was given a tile");
    let (code, hb) =
        post(url, "/api/v1/worker/heartbeat", json!({"worker_id": a, "leases": [held["lease_id"]]}));
    assert_eq!(code, 200);
    assert_eq!(hb["revoked"], json!([]), "draining keeps the tiles a worker holds");
    assert!(lease(url, b, 0.0).is_some(), "the others still work");

    // Disabling: the tile a holds goes back to the queue at once, its heartbeat says so.
    let (code, w) = operator(url, &format!("/api/v1/workers/{a}/disable"));
    assert_eq!((code, w["mode"].as_str()), (200, Some("disabled")), "{w}");
    let (_, hb) =
        post(url, "/api/v1/worker/heartbeat", json!({"worker_id": a, "leases": [held["lease_id"]]}));
    assert_eq!(hb["revoked"], json!([held["lease_id"]]), "{hb}");
    let (tile, frame) = (held["tile"].clone(), held["camera"].clone());
    let mut retaken = None;
    while let Some(l) = lease(url, b, 0.0) {
        if l["tile"] == tile && l["camera"] == frame {
            retaken = Some(l);
            break;
        }
    }
    let retaken = retaken.expect("the disabled worker's tile was not queued again");
    assert!(lease(url, a, 0.5).is_none());

    // Enabling: a poll a is waiting in when it is enabled gets the next free tile.
    let waiting = {
        let url = url.clone();
        std::thread::spawn(move || lease(&url, a, 15.0))
    };
    std::thread::sleep(Duration::from_millis(300));
    let (code, _) =
        post(url, &format!("/api/v1/worker/leases/{}/release", retaken["lease_id"]), json!({"worker_id": b}));
    assert_eq!(code, 204, "b gives its tile back");
    std::thread::sleep(Duration::from_millis(300));
    let (code, w) = operator(url, &format!("/api/v1/workers/{a}/enable"));
    assert_eq!((code, w["mode"].as_str()), (200, Some("active")));
    let started = Instant::now();
    let got = waiting.join().unwrap().expect("the enabled worker's waiting poll got no tile");
    assert!(started.elapsed() < Duration::from_secs(5), "the poll was not woken by the enabling");
    assert_eq!(got["job_id"].as_u64(), Some(job));
    assert_eq!(worker_json(url, a)["mode"], "active");

    // Unknown workers are a clear 404.
    let (code, e) = operator(url, "/api/v1/workers/999/drain");
    assert_eq!(code, 404);
    assert!(e["error"].as_str().unwrap().contains("no worker 999"), "{e}");
}

#[test]
fn the_client_lists_drains_and_enables_workers() {
    let _serial = serial();
    let server = Server::start_temp("workers-client", &["--local-workers", "0", "--worker-token", TOKEN]);
    let id = register(&server.url, "render-box-7");
    let client = |args: &[&str]| {
        let out = Command::new(client_bin())
            .args(args)
            .env("TESSERA_SERVER", &server.url)
            .env_remove("TESSERA_TOKEN")
            .output()
            .expect("run tessera");
        assert!(out.status.success(), "tessera {args:?}: {}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let listed = client(&["workers"]);
    assert!(listed.contains("render-box-7") && listed.contains("active"), "{listed}");
    let said = client(&["worker", "drain", &id.to_string()]);
    assert!(said.contains("draining"), "{said}");
    assert!(client(&["workers"]).contains("draining"));
    let said = client(&["worker", "enable", &id.to_string()]);
    assert!(said.contains("active"), "{said}");
    let json: Value = serde_json::from_str(&client(&["workers", "--json"])).unwrap();
    assert_eq!(json["workers"][0]["mode"], "active");
}
