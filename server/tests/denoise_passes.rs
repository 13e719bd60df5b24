//! Denoised previews on the farm: the real server and worker processes, the real Intel Open
//! Image Denoise library. Each published pass of a job with `denoise` is denoised too, and a
//! server started without the library finds it once installed, without a restart.

mod support;

use std::process::Command;
use std::time::{Duration, Instant};

use support::*;
use tessera_testkit::{denoiser_found, small_path_traced_box};

/// The mean absolute difference between horizontally adjacent pixels (all channels, 0-255):
/// the high-frequency energy of a picture, which per-pixel noise makes large.
fn roughness(png: &[u8]) -> f64 {
    let img = image::load_from_memory(png).expect("a PNG").to_rgb8();
    let (w, h) = img.dimensions();
    let mut sum = 0.0;
    for y in 0..h {
        for x in 1..w {
            let (a, b) = (img.get_pixel(x - 1, y), img.get_pixel(x, y));
            sum += (0..3).map(|c| (f64::from(a[c]) - f64::from(b[c])).abs()).sum::<f64>();
        }
    }
    sum / f64::from(3 * (w - 1) * h)
}

fn mean(png: &[u8]) -> f64 {
    let img = image::load_from_memory(png).expect("a PNG").to_rgb8();
    img.as_raw().iter().map(|&v| f64::from(v)).sum::<f64>() / img.as_raw().len() as f64
}

#[test]
fn a_pass_preview_is_denoised_and_the_finished_frame_serves_its_denoised_png_under_that_name() {
    let _s = serial();
    if !denoiser_found(tessera_denoise::oidn().map(|_| ())) {
        return;
    }
    let dir = TempDir::new("denoise-passes");
    let Some(scene) = small_path_traced_box(dir.path()) else { return };
    let server =
        Server::start_temp("denoise-passes-data", &["--local-workers", "1", "--local-worker-threads", "1"]);
    // 96 x 96 in four tiles, passes of 16 samples: the early passes are very noisy.
    let job = submit_box(
        &server,
        &scene,
        &[("samples", b"96"), ("pass_samples", b"16"), ("tile_size", b"48"), ("denoise", b"true")],
    );
    let id = job["id"].as_u64().unwrap();
    // A pass's raw and denoised pictures, of the same pass (a later pass may land between two
    // downloads: then again).
    let deadline = Instant::now() + Duration::from_secs(120);
    let (raw, denoised, pass) = loop {
        assert!(Instant::now() < deadline, "no denoised pass came\n{}", server.log());
        let job = get_json(&server.url, &format!("/api/v1/jobs/{id}"));
        let f = &job["frames"][0];
        assert_ne!(job["state"], "done", "the job ended before a denoised pass was seen: {job}");
        let (Some(url), Some(raw_url)) =
            (f["pass_denoised_url"].as_str(), f["pass_outputs"].as_array().and_then(|o| o.get(1)))
        else {
            std::thread::sleep(Duration::from_millis(20));
            continue;
        };
        assert!(url.ends_with("/frames/0/files/pass_denoised.png"), "{job}");
        let denoised = get_bytes(&server.url, url);
        let raw = get_bytes(&server.url, raw_url["url"].as_str().unwrap());
        let again = get_json(&server.url, &format!("/api/v1/jobs/{id}"));
        if again["frames"][0]["passes_done"] == f["passes_done"] && again["state"] != "done" {
            break (raw, denoised, f["passes_done"].as_u64().unwrap());
        }
    };
    assert!(pass < 6, "pass {pass}");
    assert_ne!(raw, denoised, "the denoised pass is the raw one");
    let (r, d) = (roughness(&raw), roughness(&denoised));
    eprintln!("pass {pass}: roughness {r:.2} raw, {d:.2} denoised");
    assert!(d < 0.6 * r, "the denoised pass {pass} is not smoother: {d:.2} against {r:.2} raw");
    // The same picture, only cleaner: its brightness stays close.
    let (mr, md) = (mean(&raw), mean(&denoised));
    assert!((mr - md).abs() < 0.2 * mr.max(1.0), "mean {md:.1} denoised against {mr:.1} raw");
    let job = wait_job(&server, id, 300, |j| j["state"] == "done");
    // The log says each published pass was denoised.
    let log = get_json(&server.url, &format!("/api/v1/jobs/{id}/log"));
    let passes: Vec<&str> = log["events"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["kind"] == "frame_pass")
        .map(|e| e["message"].as_str().unwrap())
        .collect();
    assert!(
        !passes.is_empty() && passes.iter().all(|m| m.contains("pass_denoised.png (denoised in")),
        "{passes:?}"
    );
    // Once finished, the name serves the frame's own denoised PNG, and the JSON lists no pass
    // picture any more.
    assert!(job["frames"][0]["pass_denoised_url"].is_null(), "{job}");
    let output = job["frames"][0]["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .find(|o| o["name"].as_str().unwrap().ends_with("_denoised.png"))
        .unwrap_or_else(|| panic!("no denoised PNG: {job}"));
    assert_eq!(
        get_bytes(&server.url, &format!("/api/v1/jobs/{id}/frames/0/files/pass_denoised.png")),
        get_bytes(&server.url, output["url"].as_str().unwrap())
    );
}

#[test]
fn a_denoiser_installed_while_the_server_runs_is_found_without_a_restart() {
    let _s = serial();
    let Ok(oidn) = tessera_denoise::oidn() else {
        assert!(denoiser_found(tessera_denoise::oidn().map(|_| ())));
        return;
    };
    let lib_dir = oidn.path().parent().map(|d| d.to_path_buf()).unwrap_or_default();
    if !lib_dir.is_absolute() {
        // Found by the dynamic linker's search: there is no folder of it to link to.
        eprintln!("skipping: the denoiser was found by the system's library search, not in a folder");
        return;
    }
    let dir = TempDir::new("denoise-later");
    // Where the server is told the library is: nothing there yet.
    let later = dir.path().join("oidn");
    let data = TempDir::new("denoise-later-data");
    let server = Server::start_with(
        &data,
        &["--local-workers", "1", "--local-worker-threads", "1"],
        |cmd: &mut Command| {
            cmd.env("TESSERA_OIDN_LIB", &later);
        },
    );
    let scene = tessera_testkit::tiny_scene(16, 16);
    let parts: [(&str, Option<&str>, &[u8]); 2] =
        [("scene", Some("s.xml"), &scene), ("denoise", None, b"true")];
    let (code, body) = submit(&server.url, None, &parts);
    assert_eq!(code, 422, "{body}");
    let error = body["error"].as_str().unwrap();
    assert!(error.contains("pip install pyoidn") && error.contains("without a restart"), "{error}");
    assert!(!error.contains(&dir.path().display().to_string()), "a server path in {error}");
    // Installed now (the library's folder appears where the server looks); the same server
    // takes the next denoised job within a few seconds.
    std::os::unix::fs::symlink(&lib_dir, &later).unwrap();
    let installed = Instant::now();
    let id = loop {
        let (code, body) = submit(&server.url, None, &parts);
        if code == 201 {
            break body["id"].as_u64().unwrap();
        }
        assert_eq!(code, 422, "{body}");
        assert!(installed.elapsed() < Duration::from_secs(15), "still refused: {body}\n{}", server.log());
        std::thread::sleep(Duration::from_millis(250));
    };
    eprintln!("accepted {:.2} s after the library appeared", installed.elapsed().as_secs_f64());
    let job = wait_job(&server, id, 120, |j| j["state"] == "done");
    let names: Vec<&str> =
        job["frames"][0]["outputs"].as_array().unwrap().iter().map(|o| o["name"].as_str().unwrap()).collect();
    assert!(names.contains(&"tiny_denoised.png"), "{names:?}");
}
