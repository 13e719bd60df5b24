//! The status page's denoised previews in a real browser: headless Chromium driven over
//! WebDriver (chromedriver) against a real server and worker, with the real Intel Open Image
//! Denoise. A frame of a job with `denoise` shows its denoised picture first, while it renders
//! (after each pass) and once finished; a toggle switches to the raw picture and back.
//!
//! Needs `chromium` and `chromedriver` (`TESSERA_REQUIRE_BROWSER=1` makes their absence a
//! failure) and OIDN (`TESSERA_REQUIRE_OIDN=1` likewise).

mod support;

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use support::*;
use tessera_testkit::{denoiser_found, small_path_traced_box};

fn find_program(names: &[&str]) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path).flat_map(|d| names.iter().map(move |n| d.join(n))).find(|p| p.is_file())
}

/// A headless Chromium session over chromedriver (as in browser.rs).
struct Browser {
    driver: Child,
    base: String,
    session: String,
}

impl Browser {
    fn start() -> Option<Browser> {
        let required = std::env::var_os("TESSERA_REQUIRE_BROWSER").is_some();
        let (Some(driver), Some(chrome)) = (
            find_program(&["chromedriver"]),
            find_program(&["chromium", "chromium-browser", "google-chrome"]),
        ) else {
            assert!(
                !required,
                "TESSERA_REQUIRE_BROWSER is set but chromium or chromedriver is not installed"
            );
            eprintln!("skipping the browser test: chromium and chromedriver are not installed");
            return None;
        };
        let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let child = Command::new(driver)
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start chromedriver");
        let base = format!("http://127.0.0.1:{port}");
        let deadline = Instant::now() + Duration::from_secs(20);
        while ureq::get(&format!("{base}/status")).call().is_err() {
            assert!(Instant::now() < deadline, "chromedriver did not start");
            std::thread::sleep(Duration::from_millis(100));
        }
        let caps = json!({"capabilities": {"alwaysMatch": {"browserName": "chrome", "goog:chromeOptions": {
            "binary": chrome.to_string_lossy(),
            "args": ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--window-size=1280,1000"]
        }}}});
        let v: Value = ureq::post(&format!("{base}/session"))
            .send_json(caps)
            .expect("new WebDriver session")
            .into_json()
            .unwrap();
        let session = v["value"]["sessionId"].as_str().expect("session id").to_string();
        Some(Browser { driver: child, base, session })
    }

    fn cmd(&self, method: &str, path: &str, body: Option<Value>) -> Value {
        let url = format!("{}/session/{}{path}", self.base, self.session);
        let req = ureq::request(method, &url);
        let res = match body {
            Some(b) => req.send_json(b),
            None => req.call(),
        };
        match res {
            Ok(r) => r.into_json::<Value>().unwrap()["value"].clone(),
            Err(ureq::Error::Status(code, r)) => {
                panic!("WebDriver {method} {path}: {code} {}", r.into_string().unwrap_or_default())
            }
            Err(e) => panic!("WebDriver {method} {path}: {e}"),
        }
    }

    fn click(&self, css: &str) {
        let v = self.cmd("POST", "/element", Some(json!({"using": "css selector", "value": css})));
        let e = v["element-6066-11e4-a52e-4f735466cecf"].as_str().unwrap().to_string();
        self.cmd("POST", &format!("/element/{e}/click"), Some(json!({})));
    }

    fn exec(&self, script: &str) -> Value {
        self.cmd("POST", "/execute/sync", Some(json!({"script": script, "args": []})))
    }

    /// Waits until `script` (a JS expression) is truthy; its value.
    fn wait(&self, what: &str, secs: u64, script: &str) -> Value {
        let deadline = Instant::now() + Duration::from_secs(secs);
        loop {
            let v = self.exec(&format!("return ({script});"));
            if !(v.is_null() || v == json!(false) || v == json!(0) || v == json!("")) {
                return v;
            }
            assert!(
                Instant::now() < deadline,
                "timed out waiting for {what}; the page says:\n{}",
                self.exec("return document.body.innerText;").as_str().unwrap_or("")
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = ureq::delete(&format!("{}/session/{}", self.base, self.session)).call();
        let _ = self.driver.kill();
        let _ = self.driver.wait();
    }
}

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

fn submit_box(server: &Server, text: &[u8], samples: &str) -> u64 {
    let (code, job) = submit(
        &server.url,
        None,
        &[
            ("scene", Some("box.xml"), text),
            ("cameras", None, b"3"),
            ("samples", None, samples.as_bytes()),
            ("pass_samples", None, b"16"),
            ("tile_size", None, b"48"),
            ("denoise", None, b"true"),
        ],
    );
    assert_eq!(code, 201, "{job}");
    job["id"].as_u64().unwrap()
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
    let text = std::fs::read(&scene).unwrap();
    browser.cmd("POST", "/url", Some(json!({"url": server.url})));
    browser.wait("the live connection", 20, "document.querySelector('#live').textContent === 'live'");

    // While it renders (many passes of 16 samples): the denoised pass first.
    let long = submit_box(&server, &text, "4096");
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
    let short = submit_box(&server, &text, "64");
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
