//! Denoising on the farm: the real server and worker processes, the real Intel Open Image
//! Denoise library. The server denoises each merged frame once; its files are the CLI's bytes.

mod support;

use std::process::Command;

use support::*;
use tessera_testkit::{denoiser_found, small_path_traced_box};

#[test]
fn a_denoised_job_writes_the_clis_denoised_files_to_the_bit() {
    let _s = serial();
    if !denoiser_found(tessera_denoise::oidn().map(|_| ())) {
        return;
    }
    let dir = TempDir::new("denoise-farm");
    let Some(scene) = small_path_traced_box(dir.path()) else { return };
    let server =
        Server::start_temp("denoise-farm-data", &["--local-workers", "2", "--local-worker-threads", "1"]);
    // A frame too large to denoise on the server is refused, saying what to do.
    let huge = tessera_testkit::tiny_scene(4097, 4096);
    let (code, body) = submit(
        &server.url,
        None,
        &[("scene", Some("huge.xml"), &huge), ("tile_size", None, b"4096"), ("denoise", None, b"true")],
    );
    assert_eq!(code, 422, "{body}");
    let error = body["error"].as_str().unwrap();
    assert!(
        error.contains("tiny.png is 4097x4096 pixels") && error.contains("at most 16777216 pixels"),
        "{error}"
    );
    let job = submit_box(
        &server,
        &scene,
        &[("samples", b"40"), ("pass_samples", b"16"), ("tile_size", b"32"), ("denoise", b"true")],
    );
    assert_eq!(job["denoise"], true, "{job}");
    let id = job["id"].as_u64().unwrap();
    let job = wait_job(&server, id, 300, |j| j["state"] == "done");
    let names: Vec<&str> =
        job["frames"][0]["outputs"].as_array().unwrap().iter().map(|o| o["name"].as_str().unwrap()).collect();
    assert!(
        names.contains(&"glass_next_importance_denoised.exr")
            && names.contains(&"glass_next_importance_denoised.png"),
        "{names:?}"
    );
    // Tiles of 32 pixels in three passes (the features come with the first) from two workers,
    // merged, then denoised once: the CLI's files, every one.
    let cli = cli_render(&scene, &["--camera", "3", "--samples", "40", "--denoise"]);
    assert_eq!(std::fs::read_dir(cli.path()).unwrap().count(), 4);
    assert_job_outputs_equal_cli(&server, &job, cli.path());
    let log = get_json(&server.url, &format!("/api/v1/jobs/{id}/log"));
    let denoised: Vec<_> =
        log["events"].as_array().unwrap().iter().filter(|e| e["kind"] == "frame_denoised").collect();
    assert_eq!(denoised.len(), 1, "{log}");
    assert!(denoised[0]["seconds"].as_f64().is_some_and(|s| s > 0.0), "{log}");
    assert!(denoised[0]["message"].as_str().unwrap().contains("Intel Open Image Denoise 2."), "{log}");
}

#[test]
fn a_server_without_the_denoiser_refuses_denoised_jobs_and_takes_the_rest() {
    let _s = serial();
    let data = TempDir::new("denoise-missing");
    let server = Server::start_with(&data, &[], |cmd: &mut Command| {
        cmd.env("TESSERA_OIDN_LIB", "/nonexistent/oidn");
    });
    let scene = tessera_testkit::tiny_scene(8, 8);
    let (code, body) =
        submit(&server.url, None, &[("scene", Some("s.xml"), &scene), ("denoise", None, b"true")]);
    assert_eq!(code, 422, "{body}");
    let error = body["error"].as_str().unwrap();
    assert!(
        error.contains("denoise=true: this server cannot denoise")
            && error.contains("pip install pyoidn")
            && error.contains("without a restart"),
        "{error}"
    );
    // Where the server looked is its own business (its log has it), not the client's.
    assert!(!error.contains("/nonexistent"), "{error}");
    assert!(server.log().contains("TESSERA_OIDN_LIB is /nonexistent/oidn"), "{}", server.log());
    let (code, body) =
        submit(&server.url, None, &[("scene", Some("s.xml"), &scene), ("denoise", None, b"maybe")]);
    assert_eq!(code, 400, "{body}");
    assert!(body["error"].as_str().unwrap().contains("denoise must be true or false"), "{body}");
    let (code, body) = submit(&server.url, None, &[("scene", Some("s.xml"), &scene)]);
    assert_eq!(code, 201, "{body}");
    assert_eq!(body["denoise"], false);
}
