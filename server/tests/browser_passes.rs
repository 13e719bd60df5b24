//! The status page's denoised previews in a real browser: headless Chromium driven over
//! WebDriver (chromedriver) against a real server and worker, with the real Intel Open Image
//! Denoise. A frame of a job with `denoise` shows its denoised picture first, while it renders
//! (after each pass) and once finished; a toggle switches to the raw picture and back.
//!
//! Needs `chromium` and `chromedriver` (`TESSERA_REQUIRE_BROWSER=1` makes their absence a
//! failure) and OIDN (`TESSERA_REQUIRE_OIDN=1` likewise).

mod support;

use serde_json::json;
use support::browser::*;
use support::*;
use tessera_testkit::{denoiser_found, small_path_traced_box};

/// The frame's node on the page.
fn frame(job: u64) -> String {
    format!(".job[data-job-id=\"{job}\"] .frame[data-frame=\"0\"]")
}

/// The mean absolute difference of horizontally adjacent pixels of the frame's canvas (0-255):
/// large for a noisy picture, small for a denoised one.
fn canvas_roughness(browser: &Browser, job: u64) -> f64 {
    let script = format!(
        "const c = document.querySelector('{} canvas'); const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; \
         let s = 0, n = 0; for (let y = 0; y < c.height; y++) for (let x = 1; x < c.width; x++) {{ \
         const i = 4 * (y * c.width + x); for (let k = 0; k < 3; k++) {{ s += Math.abs(d[i + k] - d[i - 4 + k]); n++; }} }} \
         return s / n;",
        frame(job).replace('"', "\\\"")
    );
    browser.exec(&script).as_f64().unwrap()
}

/// The box's camera 3, denoised, in passes of 16 samples.
fn box_in_passes(server: &Server, scene: &std::path::Path, samples: &[u8]) -> u64 {
    let options: [(&str, &[u8]); 4] =
        [("samples", samples), ("pass_samples", b"16"), ("tile_size", b"48"), ("denoise", b"true")];
    submit_box(server, scene, &options)["id"].as_u64().unwrap()
}

#[test]
fn the_denoised_toggle_switches_a_frame_between_its_denoised_and_raw_pictures() {
    let _s = serial();
    if !denoiser_found(tessera_denoise::oidn().map(|_| ())) {
        return;
    }
    let dir = TempDir::new("browser-passes");
    let Some(scene) = small_path_traced_box(dir.path()) else { return };
    let Some(browser) = Browser::start() else { return };
    let server =
        Server::start_temp("browser-passes-data", &["--local-workers", "1", "--local-worker-threads", "1"]);
    browser.cmd("POST", "/url", Some(json!({"url": server.url})));
    browser.wait("the live connection", 20, "document.querySelector('#live').textContent === 'live'");

    // While it renders (many passes of 16 samples): the denoised pass first.
    let long = box_in_passes(&server, &scene, b"4096");
    let node = frame(long);
    let q = |css: &str| format!("document.querySelector('{}')", css.replace('\'', "\\'"));
    browser.wait(
        "the denoised pass on the page",
        60,
        &format!(
            "({n}?.dataset.shown || '').endsWith('/pass_denoised.png') && {n}.dataset.view === 'denoised'",
            n = q(&node)
        ),
    );
    assert_eq!(
        browser.exec(&format!("return {}.textContent;", q(&format!("{node} .denoise-toggle")))),
        json!("Show raw")
    );
    let progress = browser.exec(&format!("return {}.textContent;", q(&format!("{node} .progress-text"))));
    assert!(
        progress.as_str().unwrap().contains(" of 256 · ") && progress.as_str().unwrap().contains(" spp"),
        "{progress}"
    );
    // The job's line: the rate of samples and the ETA they give.
    let times = browser.wait(
        "the rate of samples",
        30,
        &format!(
            "{}.textContent.includes('samples/s') && {0}.textContent",
            q(&format!(".job[data-job-id=\"{long}\"] .times"))
        ),
    );
    assert!(times.as_str().unwrap().contains(" · ETA "), "{times}");
    let denoised = canvas_roughness(&browser, long);
    browser.click(&format!("{node} .denoise-toggle"));
    browser.wait(
        "the raw preview",
        30,
        &format!(
            "{n}.dataset.view === 'raw' && ({n}.dataset.shown || '').endsWith('/preview.png')",
            n = q(&node)
        ),
    );
    let raw = canvas_roughness(&browser, long);
    eprintln!("the page's canvas: roughness {denoised:.2} denoised, {raw:.2} raw");
    assert!(
        raw > 1.5 * denoised,
        "the raw picture ({raw:.2}) is not rougher than the denoised one ({denoised:.2})"
    );
    assert_eq!(
        browser.exec(&format!("return {}.textContent;", q(&format!("{node} .denoise-toggle")))),
        json!("Show denoised")
    );
    browser.click(&format!("{node} .denoise-toggle"));
    browser.wait(
        "the denoised pass again",
        30,
        &format!(
            "{n}.dataset.view === 'denoised' && ({n}.dataset.shown || '').endsWith('/pass_denoised.png')",
            n = q(&node)
        ),
    );
    assert_eq!(cancel(&server, long).0, 200);

    // Finished: the denoised PNG first, the raw one a click away.
    let short = box_in_passes(&server, &scene, b"64");
    wait_job(&server, short, 120, |j| j["state"] == "done");
    let node = frame(short);
    browser.wait(
        "the finished frame's denoised PNG",
        30,
        &format!("({n}?.dataset.shown || '').endsWith('/glass_next_importance_denoised.png')", n = q(&node)),
    );
    browser.click(&format!("{node} .denoise-toggle"));
    browser.wait(
        "the finished frame's raw PNG",
        30,
        &format!("({n}.dataset.shown || '').endsWith('/glass_next_importance.png')", n = q(&node)),
    );
    let links = browser.exec(&format!("return {}.innerText;", q(&format!("{node} .links"))));
    assert!(
        links.as_str().unwrap().contains("glass_next_importance_denoised.png")
            && links.as_str().unwrap().contains("glass_next_importance.png"),
        "{links}"
    );
}
