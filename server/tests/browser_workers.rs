//! The workers list and the "no worker" notice in a real browser (headless Chromium over
//! WebDriver, as `browser.rs`), against a real server and a real worker process: a job nobody
//! can serve says why on the page; the worker's Drain and Enable buttons change its mode.

mod support;

use serde_json::json;
use support::browser::*;
use support::*;

const TOKEN: &str = "wtok";

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
