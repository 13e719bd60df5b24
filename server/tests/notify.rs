//! Job-end notifications against the real server: a receiver (a plain HTTP listener in this
//! test) gets exactly one POST per job end, a failing receiver is tried again, and a receiver
//! that never answers holds up nothing else.

mod support;

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde_json::Value;
use support::*;

/// What the receiver does with a request.
#[derive(Clone, Copy)]
enum Answer {
    /// 204 No Content.
    Ok,
    /// 500, `n` times, then 204.
    FailFirst(usize),
    /// Reads the request and never answers.
    Silent,
}

/// An HTTP receiver on a free port: every request's path and JSON body, in arrival order.
struct Receiver {
    url: String,
    got: Arc<Mutex<Vec<(String, Value)>>>,
}

impl Receiver {
    fn start(answer: Answer) -> Receiver {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let url = format!("http://{}", listener.local_addr().unwrap());
        let got: Arc<Mutex<Vec<(String, Value)>>> = Arc::default();
        let seen = got.clone();
        std::thread::spawn(move || {
            let mut held = Vec::new();
            for stream in listener.incoming().flatten() {
                let Some((path, body)) = read_request(&stream) else { continue };
                let n = {
                    let mut seen = seen.lock().unwrap();
                    seen.push((path, body));
                    seen.len()
                };
                let status = match answer {
                    Answer::Ok => "204 No Content",
                    Answer::FailFirst(k) if n <= k => "500 Internal Server Error",
                    Answer::FailFirst(_) => "204 No Content",
                    Answer::Silent => {
                        held.push(stream);
                        continue;
                    }
                };
                let _ = (&stream).write_all(
                    format!("HTTP/1.1 {status}\r\nContent-Length: 0\r\nConnection: close\r\n\r\n").as_bytes(),
                );
            }
        });
        Receiver { url, got }
    }

    fn events(&self) -> Vec<(String, Value)> {
        self.got.lock().unwrap().clone()
    }
}

fn read_request(stream: &TcpStream) -> Option<(String, Value)> {
    stream.set_read_timeout(Some(Duration::from_secs(10))).ok()?;
    let mut reader = BufReader::new(stream);
    let mut line = String::new();
    reader.read_line(&mut line).ok()?;
    let path = line.split_whitespace().nth(1)?.to_string();
    let mut length = 0usize;
    loop {
        let mut header = String::new();
        reader.read_line(&mut header).ok()?;
        if header.trim().is_empty() {
            break;
        }
        if let Some((k, v)) = header.split_once(':')
            && k.eq_ignore_ascii_case("content-length")
        {
            length = v.trim().parse().ok()?;
        }
    }
    let mut body = vec![0; length];
    reader.read_exact(&mut body).ok()?;
    Some((path, serde_json::from_slice(&body).unwrap_or(Value::Null)))
}

fn wait_for(what: &str, server: &Server, limit: Duration, mut done: impl FnMut() -> bool) {
    let deadline = Instant::now() + limit;
    while !done() {
        assert!(Instant::now() < deadline, "{what}\n{}", server.log());
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn log_kinds(server: &Server, id: u64) -> Vec<String> {
    get_json(&server.url, &format!("/api/v1/jobs/{id}/log"))["events"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["kind"].as_str().unwrap().to_string())
        .collect()
}

#[test]
fn every_job_end_is_posted_once() {
    let _serial = serial();
    let receiver = Receiver::start(Answer::Ok);
    let hook = format!("{}/hooks/farm", receiver.url);
    let server = Server::start_temp("notify-once", &["--local-workers", "1", "--notify-url", &hook]);
    let done = submit_environment(&server, "1", "64");
    wait_job(&server, done, 120, |j| j["state"] == "done");
    // A second job, cancelled while it waits behind nothing: its end is announced too.
    let cancelled = submit_environment_with(&server, "4096", "8", &[]);
    let (code, _) = cancel(&server, cancelled);
    assert_eq!(code, 200);
    wait_for("two notifications", &server, Duration::from_secs(30), || receiver.events().len() >= 2);
    // Nothing more comes: one POST per end, not one per poll of the notifier.
    std::thread::sleep(Duration::from_secs(3));
    let events = receiver.events();
    assert_eq!(events.len(), 2, "{events:?}");
    let by_job =
        |id: u64| events.iter().find(|(_, b)| b["job"]["id"] == id).unwrap_or_else(|| panic!("{events:?}"));
    let (path, body) = by_job(done);
    assert_eq!(path, "/hooks/farm");
    assert_eq!(body["event"], "job_done");
    assert_eq!(body["job"]["state"], "done");
    assert!(body["job"]["frames"][0]["outputs"].as_array().is_some_and(|o| !o.is_empty()), "{body}");
    let (_, body) = by_job(cancelled);
    assert_eq!(body["event"], "job_cancelled");
    // The log says it was announced.
    wait_for("the notified event", &server, Duration::from_secs(10), || {
        log_kinds(&server, done).contains(&"notified".to_string())
    });
}

#[test]
fn a_failing_receiver_is_tried_again_and_a_silent_one_holds_up_nothing() {
    let _serial = serial();
    let flaky = Receiver::start(Answer::FailFirst(2));
    let server = Server::start_temp("notify-retry", &["--local-workers", "1", "--notify-url", &flaky.url]);
    let id = submit_environment(&server, "1", "64");
    wait_job(&server, id, 120, |j| j["state"] == "done");
    // Two 500s, then a 204 after the pauses of 1 and 4 s.
    wait_for("the third try", &server, Duration::from_secs(30), || flaky.events().len() >= 3);
    wait_for("the notified event", &server, Duration::from_secs(10), || {
        log_kinds(&server, id).contains(&"notified".to_string())
    });
    assert_eq!(flaky.events().len(), 3);
    drop(server);

    let silent = Receiver::start(Answer::Silent);
    let server = Server::start_temp("notify-silent", &["--local-workers", "1", "--notify-url", &silent.url]);
    let first = submit_environment(&server, "1", "64");
    wait_job(&server, first, 120, |j| j["state"] == "done");
    wait_for("the POST to arrive", &server, Duration::from_secs(10), || !silent.events().is_empty());
    // While that delivery waits for an answer, the farm goes on: another job renders and
    // requests are answered at once.
    let started = Instant::now();
    let second = submit_environment(&server, "1", "64");
    wait_job(&server, second, 120, |j| j["state"] == "done");
    let t = Instant::now();
    get_json(&server.url, "/api/v1/jobs");
    assert!(t.elapsed() < Duration::from_secs(2), "a job list took {:?}", t.elapsed());
    assert!(
        !log_kinds(&server, first).iter().any(|k| k == "notified" || k == "notify_failed"),
        "the silent receiver's delivery is still waiting ({:?} after the second job started)",
        started.elapsed()
    );
}
