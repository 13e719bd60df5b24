//! The HTTP API's shape over real HTTP against the real binary: its OpenAPI description checked
//! by an independent validator (Python's `openapi-spec-validator`), the one JSON error shape of
//! every refusal, and a job's log as a real worker process renders it.
//!
//! The validator: `pip install openapi-spec-validator`. `.ci/run` installs it and sets
//! `TESSERA_REQUIRE_OPENAPI_VALIDATOR=1`, so CI cannot skip that check; elsewhere it is skipped,
//! saying why, when the package is missing.

mod support;

use std::process::Command;

use serde_json::{Value, json};
use support::*;
use tessera::protocol::{ApiError, JobLog};

/// Runs the validator on `spec`: `Some(passed, output)`, or `None` when it is not installed.
fn validate(spec: &Value, dir: &TempDir, name: &str) -> Option<(bool, String)> {
    let file = dir.join(name);
    std::fs::write(&file, serde_json::to_vec_pretty(spec).unwrap()).unwrap();
    let out = Command::new("python3").args(["-m", "openapi_spec_validator"]).arg(&file).output().ok()?;
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    if text.contains("No module named openapi_spec_validator") {
        return None;
    }
    Some((out.status.success(), text))
}

#[test]
fn the_openapi_description_is_valid_and_describes_the_log() {
    let _s = serial();
    let server = Server::start_temp("api-openapi", &["--local-workers", "0"]);
    let resp = ureq::get(&format!("{}/api/v1/openapi.json", server.url)).call().unwrap();
    assert_eq!(resp.content_type(), "application/json");
    let spec: Value = resp.into_json().unwrap();
    assert!(spec["openapi"].as_str().unwrap().starts_with("3."), "{}", spec["openapi"]);
    // What the other engineers build against is in it: the log endpoint with its `after` query
    // and the JobLog schema, the error schema.
    let log = &spec["paths"]["/api/v1/jobs/{id}/log"]["get"];
    let params: Vec<&str> =
        log["parameters"].as_array().unwrap().iter().map(|p| p["name"].as_str().unwrap()).collect();
    assert_eq!(params, ["id", "after"], "{log}");
    assert_eq!(
        log["responses"]["200"]["content"]["application/json"]["schema"]["$ref"],
        "#/components/schemas/JobLog"
    );
    let event = &spec["components"]["schemas"]["JobEvent"];
    let mut required: Vec<&str> =
        event["required"].as_array().unwrap().iter().map(|v| v.as_str().unwrap()).collect();
    required.sort();
    assert_eq!(required, ["at", "kind", "message", "seq"], "{event}");
    assert!(spec["components"]["schemas"]["ApiError"]["properties"]["problems"].is_object());

    let dir = TempDir::new("api-openapi-files");
    let required = std::env::var_os("TESSERA_REQUIRE_OPENAPI_VALIDATOR").is_some();
    let Some((ok, output)) = validate(&spec, &dir, "openapi.json") else {
        assert!(
            !required,
            "TESSERA_REQUIRE_OPENAPI_VALIDATOR is set but python3 -m openapi_spec_validator is not installed"
        );
        eprintln!("skipping the OpenAPI validation: pip install openapi-spec-validator");
        return;
    };
    assert!(ok, "openapi-spec-validator refuses the description:\n{output}");
    // The validator does judge: the same description with a broken reference is refused.
    let mut broken = spec.clone();
    broken["paths"]["/api/v1/jobs/{id}/log"]["get"]["responses"]["200"]["content"]["application/json"]["schema"]
        ["$ref"] = json!("#/components/schemas/NoSuchSchema");
    let (ok, output) = validate(&broken, &dir, "broken.json").unwrap();
    assert!(!ok, "the validator accepted a dangling $ref:\n{output}");
}

/// A request that must be refused with the JSON error: (method, path, body or none, status).
fn refused(server: &Server, method: &str, path: &str, body: Option<(&str, &[u8])>, status: u16) {
    let req =
        ureq::request(method, &format!("{}{path}", server.url)).set("Authorization", "Bearer wrong-or-none");
    let res = match body {
        Some((ct, bytes)) => req.set("Content-Type", ct).send_bytes(bytes),
        None => req.call(),
    };
    let Err(ureq::Error::Status(code, resp)) = res else {
        panic!("{method} {path} was not refused: {res:?}")
    };
    assert_eq!(code, status, "{method} {path}");
    assert_eq!(resp.content_type(), "application/json", "{method} {path}");
    let text = resp.into_string().unwrap();
    let e: ApiError = serde_json::from_str(&text).unwrap_or_else(|e| panic!("{method} {path}: {e}: {text}"));
    assert!(!e.error.is_empty(), "{method} {path}: {text}");
}

#[test]
fn refusals_over_http_are_json_errors() {
    let _s = serial();
    let server = Server::start_temp("api-errors", &["--local-workers", "0"]);
    refused(&server, "GET", "/api/v1/jobs/abc", None, 400);
    refused(&server, "GET", "/api/v1/jobs/1/frames/0/tonemap.png?key=x", None, 400);
    refused(&server, "GET", "/api/v1/jobs/1/log?after=-3", None, 400);
    refused(&server, "GET", "/api/v1/jobs/1/log", None, 404);
    refused(&server, "GET", "/api/v1/no/such/route", None, 404);
    refused(&server, "DELETE", "/api/v1/jobs", None, 405);
    refused(&server, "POST", "/api/v1/jobs", Some(("text/plain", b"scene")), 400);
    // The worker protocol checks its token first: a wrong one is a JSON 401 too.
    refused(&server, "POST", "/api/v1/worker/register", Some(("application/json", b"{")), 401);
}

#[test]
fn a_jobs_log_follows_a_real_worker_through_the_job() {
    let _s = serial();
    let server = Server::start_temp(
        "api-log",
        &["--local-workers", "1", "--local-worker-threads", "1", "--tile-size", "8"],
    );
    let scene = tessera_testkit::tiny_scene(16, 8);
    // Two tiles of 8 (without a tile_size a frame this small would be one tile).
    let (code, job) =
        submit(&server.url, None, &[("scene", Some("tiny.xml"), &scene), ("tile_size", None, b"8")]);
    assert_eq!(code, 201, "{job}");
    let id = job["id"].as_u64().unwrap();
    wait_job(&server, id, 120, |j| j["state"] == "done");
    let log: JobLog =
        serde_json::from_value(get_json(&server.url, &format!("/api/v1/jobs/{id}/log"))).unwrap();
    assert_eq!(log.job, id);
    let kinds: Vec<&str> = log.events.iter().map(|e| e.kind.as_str()).collect();
    assert_eq!(kinds, ["accepted", "tile_done", "tile_done", "frame_merged", "job_done"], "{log:?}");
    for tile in &log.events[1..3] {
        assert_eq!(tile.worker.as_deref(), Some("local-1"), "{tile:?}");
        let s = tile.seconds.expect("the worker's render time");
        assert!(s > 0.0 && s < 60.0, "{tile:?}");
        assert_eq!(tile.frame, Some(0));
    }
    let mut tiles: Vec<u32> = log.events[1..3].iter().map(|e| e.tile.unwrap()).collect();
    tiles.sort();
    assert_eq!(tiles, [0, 1]);
    assert!(log.events[3].seconds.is_some());
    // ?after= gives the rest only.
    let rest: JobLog =
        serde_json::from_value(get_json(&server.url, &format!("/api/v1/jobs/{id}/log?after=3"))).unwrap();
    assert_eq!(rest.events, log.events[3..]);
}
