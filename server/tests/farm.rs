//! End-to-end tests of the farm: the real `tessera-server` and `tessera-worker` binaries as
//! separate processes, talking HTTP on loopback, with a real SQLite file in a temp directory.
//! Results are compared byte for byte with what `tessera-worker render` writes.

mod support;

use std::process::Command;
use std::time::{Duration, Instant};

use support::*;

fn assert_outputs_equal_cli(server: &Server, id: u64, samples: &str) {
    let job = get_json(&server.url, &format!("/api/v1/jobs/{id}"));
    let names: Vec<&str> =
        job["frames"][0]["outputs"].as_array().unwrap().iter().map(|o| o["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["environment.exr", "environment.png"], "{job}");
    let exr = get_bytes(&server.url, &format!("/api/v1/jobs/{id}/frames/0/files/environment.exr"));
    let png = get_bytes(&server.url, &format!("/api/v1/jobs/{id}/frames/0/files/environment.png"));
    let (cli_exr, cli_png) = cli_render_environment(samples);
    assert!(
        exr == cli_exr,
        "the farm's EXR differs from the CLI's ({} vs {} bytes)",
        exr.len(),
        cli_exr.len()
    );
    assert!(png == cli_png, "the farm's PNG differs from the CLI's");
}

#[test]
fn a_job_renders_on_two_local_workers_exactly_like_the_cli() {
    let _s = serial();
    let data = TempDir::new("farm-two");
    let server = Server::start(&data, &["--local-workers", "2", "--local-worker-threads", "1"]);
    assert_eq!(get_bytes(&server.url, "/healthz"), b"ok\n");
    let id = submit_environment(&server, "4", "16");
    let job = wait_job(&server, id, 120, |j| j["state"] == "done");
    assert_eq!(job["frames"][0]["tiles_done"], job["frames"][0]["tiles_total"]);
    assert_outputs_equal_cli(&server, id, "4");
    // Both workers rendered part of the frame.
    let workers = get_json(&server.url, "/api/v1/workers");
    let done: Vec<u64> =
        workers["workers"].as_array().unwrap().iter().map(|w| w["tiles_done"].as_u64().unwrap()).collect();
    assert_eq!(done.len(), 2, "{workers}");
    assert!(done.iter().all(|&d| d > 0), "one worker did nothing: {workers}");
    assert_eq!(done.iter().sum::<u64>(), job["frames"][0]["tiles_total"].as_u64().unwrap());
    // The job list, the preview and the metrics.
    let list = get_json(&server.url, "/api/v1/jobs");
    assert_eq!(list["jobs"][0]["id"], id);
    let preview = get_bytes(&server.url, &format!("/api/v1/jobs/{id}/frames/0/preview.png"));
    assert!(preview.starts_with(b"\x89PNG"));
    let metrics = String::from_utf8(get_bytes(&server.url, "/metrics")).unwrap();
    assert!(metrics.contains("tessera_jobs{state=\"done\"} 1"), "{metrics}");
    assert!(metrics.contains(&format!("tessera_tiles_done_total {}", done.iter().sum::<u64>())), "{metrics}");
    assert!(metrics.contains("tessera_tile_render_seconds_count"), "{metrics}");
}

/// A worker of two threads renders a tile on each, two at once (as the CLI gives each thread
/// whole tiles), and the frame is still the CLI's to the bit. Tiles of a few milliseconds
/// each (8 spp, 64 pixels): two of the worker's tiles whose render intervals (as the log dates them: accepted
/// at `at`, rendered for `seconds` before) overlap by more than half the shorter one can only
/// have rendered side by side; one at a time, they would overlap by the jitter of the uploads.
#[test]
fn a_two_thread_worker_renders_a_tile_on_each_thread_exactly_like_the_cli() {
    let _s = serial();
    let data = TempDir::new("farm-slots");
    let server = Server::start(&data, &["--local-workers", "1", "--local-worker-threads", "2"]);
    let id = submit_environment(&server, "8", "64");
    let job = wait_job(&server, id, 120, |j| j["state"] == "done");
    assert_eq!(job["frames"][0]["tiles_done"], job["frames"][0]["tiles_total"]);
    assert_outputs_equal_cli(&server, id, "8");
    let log = get_json(&server.url, &format!("/api/v1/jobs/{id}/log"));
    let spans: Vec<(f64, f64)> = log["events"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["kind"] == "tile_done")
        .map(|e| {
            let (at, s) = (e["at"].as_f64().unwrap(), e["seconds"].as_f64().unwrap());
            (at - s, at)
        })
        .collect();
    assert_eq!(spans.len() as u64, job["frames"][0]["tiles_total"].as_u64().unwrap(), "{log}");
    let side_by_side = spans.iter().enumerate().any(|(i, a)| {
        spans[i + 1..].iter().any(|b| {
            let overlap = a.1.min(b.1) - a.0.max(b.0);
            overlap > 0.5 * (a.1 - a.0).min(b.1 - b.0)
        })
    });
    assert!(side_by_side, "no two tiles rendered at once: {spans:?}");
}

/// No local workers, worker token `wtok`, and leases that expire 2 s after the last heartbeat:
/// what the failure tests need to see a lost worker's tiles come back quickly.
const SHORT_LEASES: [&str; 8] =
    ["--local-workers", "0", "--worker-token", "wtok", "--lease-seconds", "2", "--heartbeat-seconds", "0.5"];

#[test]
fn a_worker_killed_mid_job_loses_nothing() {
    let _s = serial();
    let data = TempDir::new("farm-killworker");
    let server = Server::start(&data, &SHORT_LEASES);
    let mut a = Worker::start(&server.url, "wtok", "a");
    let _b = Worker::start(&server.url, "wtok", "b");
    let id = submit_environment(&server, "24", "32");
    wait_job(&server, id, 120, |j| tiles_done(j) >= 6);
    // Kill worker a while it holds a tile (it renders one and has fetched the next), so there
    // is a lease to expire.
    wait_until_rendering(&server, "a");
    a.kill9();
    wait_job(&server, id, 180, |j| j["state"] == "done");
    assert_outputs_equal_cli(&server, id, "24");
    let expiries: u64 = metric(&server, "tessera_lease_expiries_total").trim().parse().unwrap();
    assert!(expiries >= 1, "the killed worker's lease should have expired");
}

#[test]
fn a_server_killed_mid_job_resumes_after_restart() {
    let _s = serial();
    let data = TempDir::new("farm-killserver");
    let args = SHORT_LEASES;
    let mut server = Server::start(&data, &args);
    let port = server.url.rsplit(':').next().unwrap().to_string();
    let _w = Worker::start(&server.url, "wtok", "w");
    let id = submit_environment(&server, "24", "16");
    let before = wait_job(&server, id, 120, |j| tiles_done(j) >= 6);
    server.kill9();
    // Same data directory, same port: the worker carries on against the new process.
    let bind = format!("127.0.0.1:{port}");
    let mut args2 = args.to_vec();
    args2.extend(["--bind", &bind]);
    let server = Server::start(&data, &args2);
    let after = get_json(&server.url, &format!("/api/v1/jobs/{id}"));
    assert!(tiles_done(&after) >= tiles_done(&before), "tiles were lost: {before} -> {after}");
    wait_job(&server, id, 180, |j| j["state"] == "done");
    assert_outputs_equal_cli(&server, id, "24");
}

#[test]
fn canceling_a_job_stops_it_and_revokes_its_tiles() {
    let _s = serial();
    let data = TempDir::new("farm-cancel");
    let server = Server::start(&data, &["--local-workers", "1", "--local-worker-threads", "1"]);
    let id = submit_environment(&server, "64", "16");
    wait_job(&server, id, 60, |j| j["state"] == "running");
    let (code, job) = cancel(&server, id);
    assert_eq!(code, 200, "{job}");
    assert_eq!(job["state"], "canceled");
    let (code, again) = cancel(&server, id);
    assert_eq!(code, 409, "{again}");
    // No outputs appear, and the worker is free for the next job.
    let id2 = submit_environment(&server, "1", "64");
    wait_job(&server, id2, 60, |j| j["state"] == "done");
    let job = get_json(&server.url, &format!("/api/v1/jobs/{id}"));
    assert_eq!(job["state"], "canceled");
    assert!(job["frames"][0]["outputs"].as_array().unwrap().is_empty());
    let (code, _) =
        call(ureq::get(&format!("{}/api/v1/jobs/{id}/frames/0/files/environment.exr", server.url)), None);
    assert_eq!(code, 409);
}

/// A tar archive with one entry named `name` (written by hand: tar libraries refuse `..`).
fn raw_tar(name: &str, data: &[u8]) -> Vec<u8> {
    let mut h = [0u8; 512];
    h[..name.len()].copy_from_slice(name.as_bytes());
    h[100..107].copy_from_slice(b"0000644");
    h[108..115].copy_from_slice(b"0000000");
    h[116..123].copy_from_slice(b"0000000");
    h[124..135].copy_from_slice(format!("{:011o}", data.len()).as_bytes());
    h[136..147].copy_from_slice(b"00000000000");
    h[156] = b'0';
    h[257..263].copy_from_slice(b"ustar\0");
    h[263..265].copy_from_slice(b"00");
    h[148..156].copy_from_slice(b"        ");
    let sum: u32 = h.iter().map(|b| u32::from(*b)).sum();
    h[148..155].copy_from_slice(format!("{sum:06o}\0").as_bytes());
    let mut out = h.to_vec();
    out.extend_from_slice(data);
    out.resize(out.len().div_ceil(512) * 512 + 1024, 0);
    out
}

#[test]
fn bad_requests_get_clear_errors_and_the_server_keeps_serving() {
    let _s = serial();
    let data = TempDir::new("farm-bad");
    let server =
        Server::start(&data, &["--local-workers", "1", "--api-token", "sekret", "--max-upload-mb", "1"]);
    let tori = std::fs::read(repo().join("scenes/tori.xml")).unwrap();
    let torus = std::fs::read(repo().join("scenes/ply/torus.ply")).unwrap();
    let t = Some("sekret");

    // No token, a wrong token.
    let (code, v) = submit(&server.url, None, &[("scene", Some("tori.xml"), &tori)]);
    assert_eq!(code, 401, "{v}");
    assert!(v["error"].as_str().unwrap().contains("Authorization: Bearer"), "{v}");
    let (code, _) = submit(&server.url, Some("guess"), &[("scene", Some("tori.xml"), &tori)]);
    assert_eq!(code, 401);
    let (code, _) = call(ureq::get(&format!("{}/api/v1/jobs", server.url)), None);
    assert_eq!(code, 401);

    // A malformed scene: 422 with the file, line and element.
    let bad = b"<Scene>\n<Cameras>\n<Camera id=\"1\"><Position>0 zero 0</Position></Camera>\n</Cameras>\n</Scene>\n";
    let (code, v) = submit(&server.url, t, &[("scene", Some("bad.xml"), bad)]);
    assert_eq!(code, 422, "{v}");
    let p = &v["problems"][0];
    assert_eq!((p["file"].as_str(), p["line"].as_u64()), (Some("bad.xml"), Some(3)), "{v}");
    assert!(p["message"].as_str().unwrap().contains("expected 3 numbers"), "{v}");

    // A missing asset names the file.
    let (code, v) = submit(&server.url, t, &[("scene", Some("tori.xml"), &tori)]);
    assert_eq!(code, 422, "{v}");
    assert!(v["error"].as_str().unwrap().contains("ply/torus.ply"), "{v}");

    // Paths that leave the bundle, as a file name and inside a tar.
    let (code, v) = submit(
        &server.url,
        t,
        &[("scene", Some("tori.xml"), &tori), ("asset", Some("../ply/torus.ply"), &torus)],
    );
    assert_eq!(code, 400, "{v}");
    assert!(v["error"].as_str().unwrap().contains("../ply/torus.ply"), "{v}");
    let (code, v) =
        submit(&server.url, t, &[("bundle", Some("b.tar"), &raw_tar("../../etc/x.xml", b"<Scene/>"))]);
    assert_eq!(code, 400, "{v}");
    assert!(v["error"].as_str().unwrap().contains("leaves the bundle"), "{v}");
    let (code, v) = submit(&server.url, t, &[("bundle", Some("b.zip"), b"not an archive at all")]);
    assert_eq!(code, 400, "{v}");

    // Over the size limit.
    let big = vec![b' '; 2 << 20];
    let (code, v) =
        submit(&server.url, t, &[("scene", Some("tori.xml"), &tori), ("asset", Some("big.bin"), &big)]);
    assert_eq!(code, 413, "{v}");
    assert!(v["error"].as_str().unwrap().contains("--max-upload-mb"), "{v}");
    // The same with `Expect: 100-continue` (curl's way for large bodies): the answer comes
    // before any of the body is sent, so the client never sends it.
    {
        use std::io::{Read, Write};
        let addr = server.url.trim_start_matches("http://");
        let mut conn = std::net::TcpStream::connect(addr).expect("connect");
        conn.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        let head = format!(
            "POST /api/v1/jobs HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer sekret\r\n\
             Content-Type: multipart/form-data; boundary=x\r\nContent-Length: {}\r\n\
             Expect: 100-continue\r\n\r\n",
            3 << 20
        );
        conn.write_all(head.as_bytes()).unwrap();
        let mut answer = Vec::new();
        let mut buf = [0u8; 4096];
        while !String::from_utf8_lossy(&answer).contains("--max-upload-mb") {
            match conn.read(&mut buf) {
                Ok(0) | Err(_) => break,
                Ok(n) => answer.extend_from_slice(&buf[..n]),
            }
        }
        let answer = String::from_utf8_lossy(&answer);
        assert!(answer.starts_with("HTTP/1.1 413"), "no 100 Continue, a 413 at once: {answer}");
        assert!(answer.contains("--max-upload-mb"), "{answer}");
    }

    // Workers need their token too.
    let (code, _) = call(
        ureq::post(&format!("{}/api/v1/worker/register", server.url)),
        Some(("application/json".into(), br#"{"name":"x","threads":1}"#.to_vec())),
    );
    assert_eq!(code, 401);

    // Still serving: a good job (the scene and its asset inside a tar bundle) completes.
    let mut tar = tar::Builder::new(Vec::new());
    let mut add = |path: &str, data: &[u8]| {
        let mut h = tar::Header::new_gnu();
        h.set_size(data.len() as u64);
        h.set_mode(0o644);
        tar.append_data(&mut h, path, data).unwrap();
    };
    add("tori/tori.xml", &tori);
    add("tori/ply/torus.ply", &torus);
    let bundle = tar.into_inner().unwrap();
    let (code, v) =
        submit(&server.url, t, &[("bundle", Some("tori.tar"), &bundle), ("tile_size", None, b"64")]);
    assert_eq!(code, 201, "{v}");
    let id = v["id"].as_u64().unwrap();
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let (_, job) = call(
            ureq::get(&format!("{}/api/v1/jobs/{id}", server.url)).set("Authorization", "Bearer sekret"),
            None,
        );
        if job["state"] == "done" {
            break;
        }
        assert!(Instant::now() < deadline, "{job}\n{}", server.log());
        std::thread::sleep(Duration::from_millis(100));
    }
    assert_eq!(get_bytes(&server.url, "/healthz"), b"ok\n");
    assert!(!server.log().contains("panicked"), "{}", server.log());
}

/// A 2025 JSON scene goes through the farm like any other and gives the CLI's bytes.
#[test]
fn a_json_scene_renders_on_the_farm_like_on_the_cli() {
    let _s = serial();
    let scene_path = tessera_testkit::shared_scenes().join("json/hw1/spheres_with_plane.json");
    if !tessera_testkit::corpus_has(&scene_path) {
        return;
    }
    let scene = std::fs::read(&scene_path).unwrap();
    let data = TempDir::new("farm-json");
    let server = Server::start(&data, &["--local-workers", "1"]);
    let (code, job) = submit(&server.url, None, &[("scene", Some("spheres_with_plane.json"), &scene)]);
    assert_eq!(code, 201, "{job}");
    let id = job["id"].as_u64().unwrap();
    let job = wait_job(&server, id, 120, |j| j["state"] == "done");
    assert_job_outputs_equal_cli(&server, &job, &cli_render(&scene_path, &[]));
}

/// Homework 6 through the farm: object lights, BRDFs and path-traced cameras (every new random
/// dimension, `SampleOneLight`'s choice included) give the CLI's bytes for every output of every camera, with tiles spread over two
/// workers.
#[test]
fn a_path_traced_scene_renders_on_the_farm_like_on_the_cli() {
    let _s = serial();
    let scene_path = repo().join("scenes/path_traced.xml");
    let scene = std::fs::read(&scene_path).unwrap();
    let data = TempDir::new("farm-path");
    let server = Server::start(&data, &["--local-workers", "2", "--local-worker-threads", "1"]);
    let (code, job) =
        submit(&server.url, None, &[("scene", Some("path_traced.xml"), &scene), ("tile_size", None, b"16")]);
    assert_eq!(code, 201, "{job}");
    let id = job["id"].as_u64().unwrap();
    let job = wait_job(&server, id, 180, |j| j["state"] == "done");
    assert_eq!(job["frames"].as_array().unwrap().len(), 4, "{job}");
    assert_job_outputs_equal_cli(&server, &job, &cli_render(&scene_path, &[]));
}

#[test]
fn listening_beyond_loopback_needs_a_token() {
    let out = Command::new(server_bin())
        .args(["--bind", "0.0.0.0:0", "--local-workers", "0", "--data-dir"])
        .arg(TempDir::new("farm-open").path())
        .env_remove("TESSERA_API_TOKEN")
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--api-token") && err.contains("--insecure"), "{err}");
}

#[test]
fn help_lists_every_option() {
    let out = Command::new(server_bin()).arg("--help").output().unwrap();
    let help = String::from_utf8_lossy(&out.stdout);
    for flag in [
        "--bind",
        "--data-dir",
        "--local-workers",
        "--tile-size",
        "--api-token",
        "--worker-token",
        "--insecure",
        "--lease-seconds",
        "--max-upload-mb",
    ] {
        assert!(help.contains(flag), "{flag} missing from --help:\n{help}");
    }
}
