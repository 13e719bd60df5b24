//! The status page's messages in a real browser (headless Chromium over WebDriver, as in
//! browser.rs; skipped without chromium and chromedriver unless TESSERA_REQUIRE_BROWSER is set):
//! a farm with an API token says on the page that it needs the token and where to enter it,
//! instead of "No jobs yet." while jobs are queued.

mod support;

use serde_json::json;
use support::browser::*;
use support::*;

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
