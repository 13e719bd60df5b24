//! Frames in passes on the farm: real `tessera-server` and `tessera-worker` processes over HTTP,
//! a real SQLite file. A tile's passes are leased on their own; the server adds each pass's
//! fixed-point sums into its tile, publishes the frame after every pass all its tiles have
//! finished, and (under a noise target) stops tiles whose noise is low enough. The final files
//! are compared byte for byte with `tessera-worker render`'s.

mod support;

use std::time::{Duration, Instant};

use support::*;
use tessera_testkit::small_path_traced_box;

const SHORT_LEASES: [&str; 8] =
    ["--local-workers", "0", "--worker-token", "wtok", "--lease-seconds", "2", "--heartbeat-seconds", "0.5"];

fn events(server: &Server, id: u64, kind: &str) -> Vec<serde_json::Value> {
    let log = get_json(&server.url, &format!("/api/v1/jobs/{id}/log"));
    log["events"].as_array().unwrap().iter().filter(|e| e["kind"] == kind).cloned().collect()
}

#[test]
fn a_frame_in_passes_with_a_worker_killed_mid_pass_is_the_clis_bytes_and_is_published_after_each_pass() {
    let _s = serial();
    let dir = TempDir::new("passes-farm");
    let Some(scene) = small_path_traced_box(dir.path()) else { return };
    let data = TempDir::new("passes-farm-data");
    let server = Server::start(&data, &SHORT_LEASES);
    // Worker a renders alone until it is killed, then b joins: with two workers from the
    // start, the whole job (0.19 s in one CI run) could end before the test saw worker a
    // holding a lease.
    let mut a = Worker::start(&server.url, "wtok", "a");
    // 9 tiles of 32 px, 128 samples in passes of 32: 36 units of work.
    let id = submit_box(
        &server,
        &scene,
        &[("tile_size", b"32"), ("samples", b"128"), ("pass_samples", b"32")],
    )["id"]
        .as_u64()
        .unwrap();
    let job = get_json(&server.url, &format!("/api/v1/jobs/{id}"));
    assert_eq!(
        (job["frames"][0]["passes_total"].as_u64(), job["frames"][0]["samples"].as_u64()),
        (Some(4), Some(128))
    );
    // The frame after its first pass is published while later passes still render: its EXR
    // and PNG download.
    // (`pass_outputs` lists them once written, just after the pass is counted.)
    let job = wait_job(&server, id, 120, |j| {
        j["state"] == "done" || j["frames"][0]["pass_outputs"].as_array().is_some_and(|a| !a.is_empty())
    });
    if job["state"] != "done" {
        let urls: Vec<&str> = job["frames"][0]["pass_outputs"]
            .as_array()
            .unwrap()
            .iter()
            .map(|o| o["url"].as_str().unwrap())
            .collect();
        assert_eq!(urls.len(), 2, "{job}");
        let exr = get_bytes(&server.url, urls[0]);
        assert_eq!(&exr[..4], &[0x76, 0x2f, 0x31, 0x01], "pass.exr is an OpenEXR file");
        let png = get_bytes(&server.url, urls[1]);
        assert_eq!(&png[1..4], b"PNG");
    }
    // Kill worker a while it renders a pass: its lease expires and the pass is rendered again.
    wait_until_rendering(&server, "a");
    a.kill9();
    let _b = Worker::start(&server.url, "wtok", "b");
    let job = wait_job(&server, id, 300, |j| j["state"] == "done");
    let cli = cli_render(&scene, &["--camera", "3", "--samples", "128"]);
    assert_job_outputs_equal_cli(&server, &job, cli.path());
    // Every pass was published before the end (the log says so), and the last pass's files
    // gave way to the outputs.
    let published = events(&server, id, "frame_pass");
    assert!(!published.is_empty() && published.len() <= 3, "{published:?}");
    // Publishing coalesces: a busy server publishes the pass that is complete when it gets to
    // it, so the passes named are increasing, each with its samples, but may skip one.
    let passes: Vec<u32> = published
        .iter()
        .map(|e| {
            let m = e["message"].as_str().unwrap();
            let k: u32 = m
                .split("after pass ")
                .nth(1)
                .and_then(|r| r.split(' ').next())
                .and_then(|k| k.parse().ok())
                .unwrap_or_else(|| panic!("no pass in {m:?}"));
            assert!(
                m.contains(&format!("after pass {k} of 4: at least {} samples per pixel", 32 * k)),
                "{m}"
            );
            k
        })
        .collect();
    assert!(passes.windows(2).all(|w| w[0] < w[1]) && passes[passes.len() - 1] <= 3, "{passes:?}");
    // The log has each tile once, when its last pass is in, not each pass.
    assert_eq!(events(&server, id, "tile_done").len(), 9);
    assert!(events(&server, id, "pass_done").is_empty());
    assert!(job["frames"][0]["pass_outputs"].as_array().unwrap().is_empty());
    // The pass names still answer, with the finished frame's own files: a client that follows
    // the passes is not left with an error when the last one lands.
    let base = format!("/api/v1/jobs/{id}/frames/0/files");
    let image = job["frames"][0]["image_name"].as_str().unwrap();
    let stem = image.rsplit_once('.').unwrap().0;
    for ext in ["exr", "png"] {
        let output = job["frames"][0]["outputs"]
            .as_array()
            .unwrap()
            .iter()
            .map(|o| o["url"].as_str().unwrap())
            .find(|u| u.ends_with(&format!("/{stem}.{ext}")))
            .unwrap_or_else(|| panic!("no .{ext} output: {job}"));
        assert_eq!(
            get_bytes(&server.url, &format!("{base}/pass.{ext}")),
            get_bytes(&server.url, output),
            "pass.{ext} after the end"
        );
    }
}

#[test]
fn a_noise_target_stops_easy_tiles_and_samples_hard_ones_exactly_like_the_cli() {
    let _s = serial();
    let dir = TempDir::new("passes-target");
    let Some(scene) = small_path_traced_box(dir.path()) else { return };
    let server =
        Server::start_temp("passes-target-data", &["--local-workers", "2", "--local-worker-threads", "1"]);
    let id = submit_box(&server, &scene, &[("noise_target", b"0.1"), ("tile_size", b"16")])["id"]
        .as_u64()
        .unwrap();
    let job = wait_job(&server, id, 300, |j| j["state"] == "done");
    let names: Vec<&str> =
        job["frames"][0]["outputs"].as_array().unwrap().iter().map(|o| o["name"].as_str().unwrap()).collect();
    assert!(names.contains(&"glass_next_importance_samples.png"), "{names:?}");
    let cli = cli_render(&scene, &["--camera", "3", "--tile-size", "16", "--noise-target", "0.1"]);
    assert!(cli.path().join("glass_next_importance_samples.png").exists());
    assert_job_outputs_equal_cli(&server, &job, cli.path());
    // The log has each tile's samples and noise. Pixels stop on their own (pooled over their
    // neighbours): in some tiles every pixel stopped at 64 of the 100 samples (an easy region),
    // others have pixels that stopped early beside pixels that took all 100 (a hard one, or
    // the edge of one), every one of them decided on its noise.
    let done = events(&server, id, "tile_done");
    assert_eq!(done.len(), 36, "{done:?}");
    let px = |e: &serde_json::Value| {
        let r = &e["message"].as_str().unwrap();
        let (_, rest) = r.split_once(": ").unwrap();
        let mean = rest.split_whitespace().next().unwrap().parse::<f64>().unwrap();
        // Uneven tiles say the samples of all their pixels; even ones, every pixel's.
        let total = rest
            .split_once("; ")
            .map(|(_, t)| t.split_whitespace().next().unwrap().parse::<u64>().unwrap())
            .unwrap_or((mean * 256.0) as u64);
        (mean, total)
    };
    let early = done.iter().filter(|e| px(e).0 < 100.0).count();
    let uneven = done.iter().filter(|e| e["message"].as_str().unwrap().contains("on average")).count();
    let full = done.iter().filter(|e| px(e).0 == 100.0).count();
    assert!(early >= 4 && uneven >= 4, "{early} tiles stopped early, {uneven} unevenly: {done:?}");
    assert!(full + uneven >= 4, "{full} tiles took every sample, {uneven} in part: {done:?}");
    assert!(done.iter().all(|e| e["message"].as_str().unwrap().contains(", noise 0.")), "{done:?}");
    // Progress counts the samples rendered, pixel by pixel: the frame's total is what its
    // pixels took, which is what the tiles say they took, and less than every sample.
    let f = &job["frames"][0];
    let taken: u64 = done.iter().map(|e| px(e).1).sum();
    assert_eq!(f["samples_done"].as_u64(), Some(taken), "{job}");
    assert_eq!(f["samples_total"].as_u64(), Some(taken), "{job}");
    assert!(taken < 96 * 96 * 100, "{job}");
}

#[test]
fn cancelling_a_job_in_passes_frees_every_worker_within_a_second() {
    let _s = serial();
    let dir = TempDir::new("passes-cancel");
    let Some(scene) = small_path_traced_box(dir.path()) else { return };
    // Heartbeats every 0.2 s: the worker list shows a worker idle as soon as it is.
    let server = Server::start_temp(
        "passes-cancel-data",
        &["--local-workers", "2", "--local-worker-threads", "1", "--heartbeat-seconds", "0.2"],
    );
    // Thousands of samples in passes of 16: far more work than the test waits for.
    let id =
        submit_box(&server, &scene, &[("tile_size", b"32"), ("samples", b"4000"), ("pass_samples", b"256")])
            ["id"]
            .as_u64()
            .unwrap();
    let busy = |server: &Server| {
        get_json(&server.url, "/api/v1/workers")["workers"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|w| w["state"] == "rendering")
            .count()
    };
    let deadline = Instant::now() + Duration::from_secs(60);
    while busy(&server) < 2 {
        assert!(Instant::now() < deadline, "the workers never both rendered\n{}", server.log());
        std::thread::sleep(Duration::from_millis(20));
    }
    let (code, job) = cancel(&server, id);
    assert_eq!(code, 200, "{job}");
    let cancelled = Instant::now();
    while busy(&server) > 0 {
        assert!(
            cancelled.elapsed() < Duration::from_millis(1200),
            "workers still rendering a second (and a heartbeat) after the cancel"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    // A higher-priority job's first pass goes before a running job's later passes.
    let low =
        submit_box(&server, &scene, &[("tile_size", b"32"), ("samples", b"4000"), ("pass_samples", b"256")])
            ["id"]
            .as_u64()
            .unwrap();
    wait_job(&server, low, 60, |j| j["state"] == "running");
    let high =
        submit_box(&server, &scene, &[("tile_size", b"32"), ("samples", b"16"), ("priority", b"5")])["id"]
            .as_u64()
            .unwrap();
    let job = wait_job(&server, high, 120, |j| j["state"] == "done");
    assert_eq!(job["state"], "done");
    let low_job = get_json(&server.url, &format!("/api/v1/jobs/{low}"));
    assert_ne!(low_job["state"], "done", "{low_job}");
    cancel(&server, low);
}

#[test]
fn finished_passes_survive_a_server_killed_mid_frame() {
    let _s = serial();
    let dir = TempDir::new("passes-kill-server");
    let Some(scene) = small_path_traced_box(dir.path()) else { return };
    let data = TempDir::new("passes-kill-server-data");
    let mut server = Server::start(&data, &SHORT_LEASES);
    let port = server.url.rsplit(':').next().unwrap().to_string();
    let _w = Worker::start(&server.url, "wtok", "w");
    let id = submit_box(
        &server,
        &scene,
        &[("tile_size", b"32"), ("samples", b"96"), ("pass_samples", b"16")],
    )["id"]
        .as_u64()
        .unwrap();
    let before = wait_job(&server, id, 120, |j| j["frames"][0]["passes_done"].as_u64() >= Some(1));
    let added_before = before["frames"][0]["passes_done"].as_u64();
    server.kill9();
    let bind = format!("127.0.0.1:{port}");
    let mut args = SHORT_LEASES.to_vec();
    args.extend(["--bind", &bind]);
    let server = Server::start(&data, &args);
    let after = get_json(&server.url, &format!("/api/v1/jobs/{id}"));
    assert!(
        after["frames"][0]["passes_done"].as_u64() >= before["frames"][0]["passes_done"].as_u64(),
        "published passes were lost: {before} -> {after}"
    );
    assert!(
        after["frames"][0]["passes_done"].as_u64() >= added_before,
        "finished passes were lost: {added_before:?} -> {after}"
    );
    let job = wait_job(&server, id, 300, |j| j["state"] == "done");
    let cli = cli_render(&scene, &["--camera", "3", "--samples", "96"]);
    assert_job_outputs_equal_cli(&server, &job, cli.path());
}
