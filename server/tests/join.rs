//! A second machine joins the default farm: the server says how (once, at start), keeps its
//! worker token in a 0600 file that survives restarts, `tessera-server worker-token` prints it,
//! and a worker with the wrong token is told where to find the right one.

mod support;

use std::os::unix::fs::PermissionsExt;
use std::process::Command;
use std::time::{Duration, Instant};

use serde_json::json;
use support::*;

fn worker_token_of(data: &std::path::Path) -> (bool, String, String) {
    let out = Command::new(server_bin())
        .args(["worker-token", "--data-dir"])
        .arg(data)
        .env_remove("TESSERA_DATA_DIR")
        .output()
        .expect("run tessera-server worker-token");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).trim().to_string(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn the_default_farm_says_how_to_join_and_keeps_its_token() {
    let _serial = serial();
    let data = TempDir::new("join");
    // Before the first start there is no farm: a clear error, not an empty line.
    let (ok, _, err) = worker_token_of(&data);
    assert!(!ok && err.contains("start tessera-server"), "{err}");

    let token = {
        let server = Server::start(&data, &["--local-workers", "0"]);
        let file = data.join("worker-token");
        let kept = std::fs::read_to_string(&file).unwrap().trim().to_string();
        assert!(kept.len() >= 32, "a random token of at least 128 bits: {kept:?}");
        let mode = std::fs::metadata(&file).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o600, "the token file is the owner's only");
        // The log says, once, what to run on another machine, with this token.
        let deadline = Instant::now() + Duration::from_secs(10);
        while !server.log().contains("tessera-worker work --server") {
            assert!(Instant::now() < deadline, "no join advice in the log:\n{}", server.log());
            std::thread::sleep(Duration::from_millis(20));
        }
        let log = server.log();
        assert_eq!(log.matches("tessera-worker work --server").count(), 1, "{log}");
        assert!(log.contains(&format!("--token {kept}")), "{log}");
        assert!(log.contains("tessera-server worker-token"), "{log}");
        // It says that a loopback farm is reachable from this machine only.
        assert!(log.contains("loopback only"), "{log}");

        // The printed command works: a real worker registers with it.
        let (ok, printed, err) = worker_token_of(&data);
        assert!(ok, "{err}");
        assert_eq!(printed, kept);
        let _worker = Worker::start(&server.url, &printed, "second-machine");
        let deadline = Instant::now() + Duration::from_secs(30);
        while !get_json(&server.url, "/api/v1/workers")["workers"]
            .as_array()
            .unwrap()
            .iter()
            .any(|w| w["name"] == "second-machine")
        {
            assert!(Instant::now() < deadline, "the worker never registered:\n{}", server.log());
            std::thread::sleep(Duration::from_millis(50));
        }

        // A wrong token is refused, and the refusal says where the right one is.
        let (code, body) = worker_post(
            &server.url,
            "not-the-token",
            "/api/v1/worker/register",
            json!({"name": "stranger", "threads": 1}),
        );
        assert_eq!(code, 401);
        let message = body["error"].as_str().unwrap_or_default();
        assert!(
            message.contains("tessera-server worker-token") && message.contains("worker-token"),
            "{body}"
        );
        kept
    };

    // A restart keeps the token: the machine that joined keeps working.
    let server = Server::start(&data, &["--local-workers", "0"]);
    let (code, body) =
        worker_post(&server.url, &token, "/api/v1/worker/register", json!({"name": "again", "threads": 1}));
    assert_eq!(code, 200, "{body}");
    drop(server);

    // An operator's own --worker-token replaces the kept one (and is what the command prints).
    let server = Server::start(&data, &["--local-workers", "0", "--worker-token", "chosen-by-the-operator"]);
    assert_eq!(worker_token_of(&data).1, "chosen-by-the-operator");
    let (code, _) =
        worker_post(&server.url, &token, "/api/v1/worker/register", json!({"name": "old", "threads": 1}));
    assert_eq!(code, 401, "the old token no longer joins");
}
