//! The status page's messages in a real browser (headless Chromium over WebDriver, as in
//! browser.rs; skipped without chromium and chromedriver unless TESSERA_REQUIRE_BROWSER is set):
//! a farm with an API token says on the page that it needs the token and where to enter it,
//! instead of "No jobs yet." while jobs are queued.

mod support;

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use support::*;

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

    fn type_into(&self, css: &str, text: &str) {
        let e = self.find(css);
        self.cmd("POST", &format!("/element/{e}/value"), Some(json!({"text": text})));
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

const API: &str = "PAGETOKEN";

#[test]
fn a_token_protected_page_asks_for_its_token_and_then_lists_the_jobs() {
    let _s = serial();
    let Some(browser) = Browser::start() else { return };
    // No worker: the job stays queued.
    let server = Server::start_temp("browser-messages-token", &["--local-workers", "0", "--api-token", API]);
    let scene = tessera_testkit::tiny_scene(8, 8);
    let (code, job) = submit(&server.url, Some(API), &[("scene", Some("tiny.xml"), &scene)]);
    assert_eq!(code, 201, "{job}");
    browser.goto(&server.url);
    let said = browser.wait(
        "the jobs list to ask for the token",
        30,
        "document.querySelector('#jobs .token-needed')?.innerText",
    );
    let said = said.as_str().unwrap();
    assert!(said.contains("needs its API token") && said.contains("API token box"), "{said}");
    assert!(!browser.exec("return document.body.innerText;").as_str().unwrap().contains("No jobs yet"));
    assert_eq!(browser.exec("return document.querySelector('#token-box').hidden;"), json!(false));
    // A wrong token is said to be refused.
    browser.type_into("#token", "wrong");
    browser.exec("document.querySelector('#token').dispatchEvent(new Event('change'));");
    let said = browser.wait(
        "the page to say the token was refused",
        30,
        "(document.querySelector('#jobs .token-needed')?.innerText || '').includes('refused') && document.querySelector('#jobs .token-needed').innerText",
    );
    assert!(said.as_str().unwrap().contains("--api-token"), "{said}");
    // The right one shows the queued job.
    browser.exec(
        "const t = document.querySelector('#token'); t.value = ''; t.dispatchEvent(new Event('change'));",
    );
    browser.type_into("#token", API);
    browser.exec("document.querySelector('#token').dispatchEvent(new Event('change'));");
    let id = job["id"].as_u64().unwrap();
    browser.wait(
        "the queued job to show",
        30,
        &format!("document.querySelector('.job[data-job-id=\"{id}\"] .state')?.textContent === 'queued'"),
    );
    assert_eq!(browser.exec("return document.querySelectorAll('#jobs .token-needed').length;"), json!(0));
}
