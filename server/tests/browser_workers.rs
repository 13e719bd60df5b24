//! The workers list and the "no worker" notice in a real browser (headless Chromium over
//! WebDriver, as `browser.rs`), against a real server and a real worker process: a job nobody
//! can serve says why on the page; the worker's Drain and Enable buttons change its mode.

mod support;

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use support::*;

const TOKEN: &str = "wtok";

const ELEMENT: &str = "element-6066-11e4-a52e-4f735466cecf";

fn find_program(names: &[&str]) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    for dir in std::env::split_paths(&path) {
        for n in names {
            let p = dir.join(n);
            if p.is_file() {
                return Some(p);
            }
        }
    }
    None
}

struct Browser {
    driver: Child,
    base: String,
    session: String,
}

impl Browser {
    /// A headless Chromium session, or `None` when the browser is not installed here.
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
            eprintln!(
                "skipping the browser test: chromium and chromedriver are not installed (apt-get install chromium chromium-driver)"
            );
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

    fn goto(&self, url: &str) {
        self.cmd("POST", "/url", Some(json!({"url": url})));
    }

    fn find(&self, css: &str) -> String {
        let v = self.cmd("POST", "/element", Some(json!({"using": "css selector", "value": css})));
        v[ELEMENT].as_str().unwrap().to_string()
    }

    fn click(&self, css: &str) {
        let e = self.find(css);
        self.cmd("POST", &format!("/element/{e}/click"), Some(json!({})));
    }

    fn exec(&self, script: &str) -> Value {
        self.cmd("POST", "/execute/sync", Some(json!({"script": script, "args": []})))
    }

    /// Waits until `script` (a JS expression) is truthy.
    fn wait(&self, what: &str, secs: u64, script: &str) -> Value {
        let deadline = Instant::now() + Duration::from_secs(secs);
        loop {
            let v = self.exec(&format!("return ({script});"));
            if !(v.is_null() || v == json!(false) || v == json!(0) || v == json!("")) {
                return v;
            }
            if Instant::now() > deadline {
                let page = self.exec("return document.body.innerText;");
                panic!("timed out waiting for {what}; the page says:\n{}", page.as_str().unwrap_or(""));
            }
            std::thread::sleep(Duration::from_millis(100));
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

#[test]
fn the_page_says_why_a_job_waits_and_drains_a_worker() {
    let _s = serial();
    let Some(browser) = Browser::start() else { return };
    let server = Server::start_temp("workers-browser", &["--local-workers", "0", "--worker-token", TOKEN]);
    browser.goto(&server.url);
    browser.wait("the live connection", 20, "document.querySelector('#live').textContent === 'live'");
    let job = submit_environment_with(&server, "1", "64", &[("worker_tags", "gpu")]);
    let notice = format!("document.querySelector('.job[data-job-id=\"{job}\"] .waiting-for')");
    let text = browser.wait(
        "the job's no-worker notice",
        20,
        &format!("{notice} && !{notice}.hidden && {notice}.innerText"),
    );
    assert!(text.as_str().unwrap().contains("no worker is connected"), "{text}");
    // A worker without the tag: the notice says which tag is missing.
    let _worker = Worker::start(&server.url, TOKEN, "plain-box");
    let row = "document.querySelector('#workers tbody tr[data-worker-id]')";
    browser.wait("the worker in the table", 30, &format!("{row} && {row}.innerText.includes('plain-box')"));
    let text = browser.wait(
        "the notice naming the tag",
        20,
        &format!("{notice}.innerText.includes('no active worker has the tag(s) gpu') && {notice}.innerText"),
    );
    assert!(text.as_str().unwrap().contains("--tags gpu"), "{text}");
    // Drain it from the page: the list and the API say draining, and so does the notice.
    browser.click("#workers tbody tr[data-worker-id] button.worker-drain");
    browser.wait("the row shows draining", 20, &format!("{row}.dataset.mode === 'draining'"));
    let shown = browser.exec(&format!("return {row}.innerText;"));
    assert!(shown.as_str().unwrap().contains("draining"), "{shown}");
    let listed = get_json(&server.url, "/api/v1/workers");
    assert_eq!(listed["workers"][0]["mode"], "draining", "{listed}");
    browser.wait(
        "the notice saying every worker is draining",
        20,
        &format!("{notice}.innerText.includes('every connected worker (1) is draining or disabled')"),
    );
    // Enable it again.
    browser.click("#workers tbody tr[data-worker-id] button.worker-enable");
    browser.wait("the row shows active", 20, &format!("{row}.dataset.mode === 'active'"));
    assert_eq!(get_json(&server.url, "/api/v1/workers")["workers"][0]["mode"], "active");
    let buttons = browser
        .exec(&format!("return [...{row}.querySelectorAll('button')].map(b => b.textContent).join(',');"));
    assert_eq!(buttons, json!("Drain,Disable"));
}
