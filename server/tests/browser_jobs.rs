//! The status page's job controls in a real browser: headless Chromium driven over WebDriver
//! (chromedriver), against a real server that needs an API token (which the page sends, as it
//! does for its other calls). A queued job is paused, reprioritised and resumed from the page,
//! cancelled, requeued, and deleted with the page's confirmation.
//!
//! Needs `chromium` and `chromedriver` (Debian: `chromium`, `chromium-driver`); with
//! `TESSERA_REQUIRE_BROWSER=1` (as CI sets it) their absence fails the test, otherwise it says
//! why and checks nothing.

mod support;

use std::time::{Duration, Instant};

use serde_json::{Value, json};
use support::browser::*;
use support::*;

const API: &str = "page-secret";

/// The job's JSON over the API (with the token), and its status.
fn job(url: &str, id: u64) -> (u16, Value) {
    call(ureq::get(&format!("{url}/api/v1/jobs/{id}")).set("Authorization", &format!("Bearer {API}")), None)
}

#[test]
fn the_page_pauses_reprioritises_resumes_requeues_and_deletes_a_job() {
    let _s = serial();
    let Some(browser) = Browser::start_keeping_prompts() else { return };
    let server = Server::start_temp(
        "browser-jobs",
        &["--local-workers", "0", "--worker-token", "wtok", "--api-token", API],
    );
    let url = &server.url;
    let scene = tessera_testkit::tiny_scene(16, 8);
    let (code, v) = submit(url, Some(API), &[("scene", Some("tiny.xml"), &scene), ("tile_size", None, b"8")]);
    assert_eq!(code, 201, "{v}");
    let id = v["id"].as_u64().unwrap();

    // The page keeps its token where the token field puts it.
    browser.goto(url);
    browser.exec(&format!("localStorage.setItem('tessera-token', '{API}');"));
    browser.goto(url);
    let node = format!(".job[data-job-id=\"{id}\"]");
    let shown = |css: &str| {
        format!("document.querySelector('{node} {css}') && !document.querySelector('{node} {css}').hidden")
    };
    let state_is = |s: &str| {
        format!(
            "document.querySelector('{node} .state') && document.querySelector('{node} .state').textContent === '{s}'"
        )
    };
    browser.wait(
        "the queued job with its Pause button",
        30,
        &format!("{} && {}", state_is("queued"), shown(".pause")),
    );
    assert_eq!(
        browser.exec(&format!("return {};", shown(".delete"))),
        json!(false),
        "delete shows for a queued job"
    );

    // Pause: the page shows the state change, and the server has it.
    browser.click(&format!("{node} .pause"));
    browser.wait("the paused state", 20, &format!("{} && {}", state_is("paused"), shown(".resume")));
    assert_eq!(job(url, id).1["state"], "paused");
    assert_eq!(browser.exec(&format!("return {};", shown(".pause"))), json!(false));

    // A new priority typed into the job's field (Enter sends it).
    let field = browser.find(&format!("{node} input.priority"));
    browser.cmd("POST", &format!("/element/{field}/clear"), Some(json!({})));
    browser.cmd("POST", &format!("/element/{field}/value"), Some(json!({"text": "7\u{E007}"})));
    let deadline = Instant::now() + Duration::from_secs(20);
    while job(url, id).1["priority"] != 7 {
        assert!(
            Instant::now() < deadline,
            "the page's priority never reached the server: {}",
            job(url, id).1
        );
        std::thread::sleep(Duration::from_millis(100));
    }

    browser.click(&format!("{node} .resume"));
    browser.wait("the queued state again", 20, &state_is("queued"));
    browser.click(&format!("{node} .cancel"));
    browser.wait("the cancelled state", 20, &format!("{} && {}", state_is("canceled"), shown(".requeue")));
    browser.click(&format!("{node} .requeue"));
    browser.wait("the requeued job", 20, &state_is("queued"));
    browser.click(&format!("{node} .cancel"));
    browser.wait(
        "the cancelled job's Delete button",
        20,
        &format!("{} && {}", state_is("canceled"), shown(".delete")),
    );

    // Delete asks first; dismissed, nothing happens; accepted, the job is gone.
    browser.click(&format!("{node} .delete"));
    let text = browser.cmd("GET", "/alert/text", None);
    assert!(text.as_str().unwrap().contains(&format!("Delete job #{id}")), "{text}");
    browser.cmd("POST", "/alert/dismiss", Some(json!({})));
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(job(url, id).0, 200, "a dismissed confirm deleted the job");
    browser.click(&format!("{node} .delete"));
    browser.cmd("POST", "/alert/accept", Some(json!({})));
    browser.wait("the job gone from the page", 20, &format!("!document.querySelector('{node}')"));
    assert_eq!(job(url, id).0, 404);
    let log = server.log();
    assert!(log.contains("deleted a finished job"), "{log}");
}
