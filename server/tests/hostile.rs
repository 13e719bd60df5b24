//! Clients and workers that mean harm, against the real server over real sockets: each test is
//! one way a holder of the worker token, an idle socket or a large request used to stall, bloat
//! or take over the farm, and checks that it no longer does (and that nobody else waits).

mod support;

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use support::*;
use tessera::protocol::{checksum, encode_tile};

const API: &str = "APITOK";
const WORKER: &str = "WTOK";

fn start(tag: &str, extra: &[&str]) -> Server {
    let mut args = vec!["--api-token", API, "--worker-token", WORKER, "--local-workers", "0"];
    args.extend_from_slice(extra);
    Server::start_temp(&format!("hostile-{tag}"), &args)
}

fn post(url: &str, path: &str, body: Value) -> (u16, Value) {
    worker_post(url, WORKER, path, body)
}

fn register(url: &str, name: &str, threads: u32) -> u64 {
    let (code, v) = post(url, "/api/v1/worker/register", json!({"name": name, "threads": threads}));
    assert_eq!(code, 200, "{v}");
    v["worker_id"].as_u64().unwrap()
}

fn lease(url: &str, worker: u64) -> (u16, Value) {
    post(url, "/api/v1/worker/lease", json!({"worker_id": worker, "wait_seconds": 0.0}))
}

fn submit_tiny(url: &str, w: u32, h: u32, tile: u32) -> u64 {
    let scene = tessera_testkit::tiny_scene(w, h);
    let (code, v) = submit(
        url,
        Some(API),
        &[("scene", Some("tiny.xml"), &scene), ("tile_size", None, tile.to_string().as_bytes())],
    );
    assert_eq!(code, 201, "{v}");
    v["id"].as_u64().unwrap()
}

fn get_api(url: &str, path: &str) -> (u16, Value) {
    call(ureq::get(&format!("{url}{path}")).set("Authorization", &format!("Bearer {API}")), None)
}

/// A tile upload as a worker sends it, with the secret of `secret_of` (usually the worker
/// itself) and `worker` as the id it claims.
fn upload_as(url: &str, worker: u64, secret_of: u64, lease: u64, body: &[u8]) -> (u16, Value) {
    let req = ureq::put(&format!("{url}/api/v1/worker/leases/{lease}/result"))
        .set("Authorization", &format!("Bearer {WORKER}"))
        .set("x-tessera-worker", &worker.to_string())
        .set("x-tessera-worker-secret", &worker_secret(url, secret_of).unwrap_or_default())
        .set("x-tessera-checksum", &checksum(body));
    call(req, Some(("application/octet-stream".into(), body.to_vec())))
}

fn addr(url: &str) -> SocketAddr {
    url.trim_start_matches("http://").parse().unwrap()
}

/// Seconds a GET takes, with the API token.
fn timed_get(url: &str, path: &str) -> f64 {
    let t = Instant::now();
    let (code, v) = get_api(url, path);
    assert_eq!(code, 200, "GET {path}: {v}");
    t.elapsed().as_secs_f64()
}

/// Row 1: one heartbeat listing 30 million lease ids (57 MiB of JSON) used to hold the store for
/// 14 s while `/healthz` and the job API waited 12 s. Now worker bodies are small: it is a 413,
/// the server's memory does not grow by the body, and nobody else waits a second.
#[test]
fn a_giant_heartbeat_is_refused_and_stalls_nobody() {
    let _s = serial();
    let server = start("heartbeat", &[]);
    let job = submit_tiny(&server.url, 64, 64, 32);
    let w = register(&server.url, "w", 1);
    let before = server.memory_kib("VmHWM");
    let mut body = String::with_capacity(60 << 20);
    body.push_str(&format!("{{\"worker_id\":{w},\"rendering\":null,\"leases\":["));
    for i in 0..30_000_000u64 {
        if i > 0 {
            body.push(',');
        }
        body.push_str(&(i % 10).to_string());
    }
    body.push_str("]}");
    assert!(body.len() > 50 << 20);
    let url = server.url.clone();
    let secret = worker_secret(&url, w).unwrap();
    let attack = std::thread::spawn(move || {
        let t = Instant::now();
        let r = ureq::post(&format!("{url}/api/v1/worker/heartbeat"))
            .set("Authorization", &format!("Bearer {WORKER}"))
            .set("x-tessera-worker-secret", &secret)
            .set("Content-Type", "application/json")
            .send_bytes(body.as_bytes());
        let code = match r {
            Ok(r) => r.status(),
            Err(ureq::Error::Status(c, _)) => c,
            Err(e) => panic!("the giant heartbeat got no answer: {e}"),
        };
        (code, t.elapsed().as_secs_f64())
    });
    let mut worst: f64 = 0.0;
    while !attack.is_finished() {
        worst = worst.max(timed_get(&server.url, "/healthz"));
        worst = worst.max(timed_get(&server.url, &format!("/api/v1/jobs/{job}")));
    }
    let (code, took) = attack.join().unwrap();
    assert_eq!(code, 413, "a 57 MiB heartbeat is refused for its size");
    assert!(worst < 1.0, "another client waited {worst:.2} s during the heartbeat ({took:.2} s)");
    let grown = server.memory_kib("VmHWM").saturating_sub(before);
    eprintln!(
        "giant heartbeat: {code} after {took:.2} s; slowest other request {worst:.3} s; peak memory +{grown} KiB"
    );
    assert!(grown < 32 << 10, "the server's peak memory grew by {grown} KiB for a refused body");

    // A heartbeat under the body limit that lists more leases than any worker holds is refused
    // too, by count.
    let many: Vec<u64> = (1..=1100).collect();
    let (code, v) = post(
        &server.url,
        "/api/v1/worker/heartbeat",
        json!({"worker_id": w, "leases": many, "rendering": null}),
    );
    assert_eq!(code, 400, "{v}");
    assert!(v["error"].as_str().unwrap().contains("at most 1026"), "{v}");
    // A worker's own heartbeat still works.
    let (code, v) = post(
        &server.url,
        "/api/v1/worker/heartbeat",
        json!({"worker_id": w, "leases": [], "rendering": null}),
    );
    assert_eq!(code, 200, "{v}");
}

/// Row 2: the preview of a 16384 x 16384 frame used to cost 786 MiB (five at once 3.3 GiB).
/// Previews are now at most 1024 pixels a side and made two at a time.
#[test]
fn previews_of_huge_frames_stay_small() {
    let _s = serial();
    let server = start("preview", &[]);
    let scene = tessera_testkit::tiny_scene(16384, 16384);
    let (code, v) = submit(
        &server.url,
        Some(API),
        &[("scene", Some("huge.xml"), &scene), ("tile_size", None, b"4096"), ("samples", None, b"1")],
    );
    assert_eq!(code, 201, "{v}");
    let id = v["id"].as_u64().unwrap();
    let before = server.memory_kib("VmHWM");
    let fetch = |url: String| {
        std::thread::spawn(move || {
            let resp = ureq::get(&format!("{url}/api/v1/jobs/{id}/frames/0/preview.png"))
                .set("Authorization", &format!("Bearer {API}"))
                .call()
                .unwrap();
            let mut png = Vec::new();
            resp.into_reader().read_to_end(&mut png).unwrap();
            png
        })
    };
    let all: Vec<_> = (0..5).map(|_| fetch(server.url.clone())).collect();
    for png in all {
        let png = png.join().unwrap();
        assert!(png.starts_with(b"\x89PNG"));
        let width = u32::from_be_bytes(png[16..20].try_into().unwrap());
        let height = u32::from_be_bytes(png[20..24].try_into().unwrap());
        assert_eq!((width, height), (1024, 1024), "a 16384 px frame is previewed at 1/16");
    }
    let grown = server.memory_kib("VmHWM").saturating_sub(before);
    eprintln!("five previews of a 16384 px frame: peak memory +{grown} KiB");
    assert!(grown < 128 << 10, "five previews of a 16384 px frame grew the server's peak by {grown} KiB");
}

/// Row 3: a chunked tile upload of 300 MiB for a lease of 480 000 bytes used to be read whole
/// before its size was checked. Now the body is refused once it passes the tile's size.
#[test]
fn a_tile_body_longer_than_its_tile_is_cut_off() {
    let _s = serial();
    let server = start("chunked", &[]);
    let job = submit_tiny(&server.url, 200, 200, 200);
    let w = register(&server.url, "w", 1);
    let (code, l) = lease(&server.url, w);
    assert_eq!(code, 200, "{l}");
    let lease_id = l["lease_id"].as_u64().unwrap();
    let before = server.memory_kib("VmHWM");
    let mut s = TcpStream::connect(addr(&server.url)).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    let head = format!(
        "PUT /api/v1/worker/leases/{lease_id}/result HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {WORKER}\r\n\
         x-tessera-worker: {w}\r\nx-tessera-worker-secret: {}\r\nx-tessera-checksum: 0000000000000000\r\n\
         Content-Type: application/octet-stream\r\nTransfer-Encoding: chunked\r\n\r\n",
        worker_secret(&server.url, w).unwrap()
    );
    s.write_all(head.as_bytes()).unwrap();
    let chunk = vec![0u8; 1 << 20];
    let mut sent = 0usize;
    let started = Instant::now();
    while sent < 300 << 20 && started.elapsed() < Duration::from_secs(60) {
        let framed = [format!("{:x}\r\n", chunk.len()).as_bytes(), &chunk, b"\r\n"].concat();
        if s.write_all(&framed).is_err() {
            break; // the server closed the connection: refused
        }
        sent += chunk.len();
    }
    assert!(sent < 300 << 20, "the server read all 300 MiB of a 480 000-byte tile");
    let mut answer = Vec::new();
    let _ = s.read_to_end(&mut answer);
    let answer = String::from_utf8_lossy(&answer);
    assert!(answer.is_empty() || answer.starts_with("HTTP/1.1 413"), "{answer}");
    let grown = server.memory_kib("VmHWM").saturating_sub(before);
    eprintln!("chunked upload: cut off after {} MiB sent; peak memory +{grown} KiB", sent >> 20);
    assert!(grown < 32 << 10, "the cut-off upload grew the server's peak memory by {grown} KiB");
    // Nothing was stored, and the lease's holder still uploads the right tile.
    assert_eq!(get_api(&server.url, &format!("/api/v1/jobs/{job}")).1["frames"][0]["tiles_done"], 0);
    let body = encode_tile(&vec![[0.5, 0.5, 0.5]; 200 * 200]);
    assert_eq!(upload_as(&server.url, w, w, lease_id, &body).0, 204);
}

/// Raises this process's soft limit on open files to `n` (its hard limit allowing).
fn allow_open_files(n: u64) {
    let mut lim = libc::rlimit { rlim_cur: 0, rlim_max: 0 };
    // SAFETY: getrlimit and setrlimit only read and write the struct passed.
    unsafe {
        assert_eq!(libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim), 0);
        if lim.rlim_cur < n {
            lim.rlim_cur = n.min(lim.rlim_max);
            assert_eq!(libc::setrlimit(libc::RLIMIT_NOFILE, &lim), 0);
        }
    }
}

/// Row 4: 1 100 idle connections against a server limited to 1 024 open files used to leave it
/// unable to accept anything (`accept error: Too many open files`, `/healthz` timing out), and a
/// half-sent request head stayed open for over a minute. Now connections are capped below the
/// descriptor limit and per client address, and heads and idle connections time out.
#[test]
fn idle_connections_cannot_take_every_descriptor() {
    use std::os::unix::process::CommandExt;
    let _s = serial();
    allow_open_files(4096);
    let data = TempDir::new("hostile-idle");
    let server = Server::start_with(
        &data,
        &[
            "--api-token",
            API,
            "--worker-token",
            WORKER,
            "--local-workers",
            "0",
            "--header-timeout-seconds",
            "2",
        ],
        |cmd| {
            // SAFETY: setrlimit is async-signal-safe; nothing else runs between fork and exec.
            unsafe {
                cmd.pre_exec(|| {
                    let lim = libc::rlimit { rlim_cur: 1024, rlim_max: 1024 };
                    if libc::setrlimit(libc::RLIMIT_NOFILE, &lim) != 0 {
                        return Err(std::io::Error::last_os_error());
                    }
                    Ok(())
                });
            }
        },
    );
    let target = addr(&server.url);
    // 1 100 connections that say nothing, from another loopback address.
    let attacker: SocketAddr = "127.0.0.2:0".parse().unwrap();
    let mut idle = Vec::new();
    for _ in 0..1100 {
        let sock = socket2::Socket::new(socket2::Domain::IPV4, socket2::Type::STREAM, None).unwrap();
        sock.bind(&attacker.into()).unwrap();
        if sock.connect_timeout(&target.into(), Duration::from_secs(2)).is_ok() {
            idle.push(sock);
        }
    }
    // Meanwhile everyone else is served at once.
    for _ in 0..5 {
        let took = timed_get(&server.url, "/healthz");
        eprintln!("/healthz behind {} idle connections: {took:.4} s", idle.len());
        assert!(took < 1.0, "/healthz took {took:.2} s behind 1 100 idle connections");
    }
    let took = timed_get(&server.url, "/api/v1/jobs");
    assert!(took < 1.0, "the job list took {took:.2} s behind 1 100 idle connections");
    // A half-sent request head is closed after the header timeout (2 s here).
    let mut half = TcpStream::connect(target).unwrap();
    half.write_all(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n").unwrap();
    half.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let t = Instant::now();
    let mut buf = [0u8; 512];
    let n = half.read(&mut buf).unwrap_or(0);
    let waited = t.elapsed().as_secs_f64();
    eprintln!("a half-sent head was closed after {waited:.2} s");
    assert!(waited < 6.0, "a half-sent head stayed open {waited:.1} s");
    assert!(n == 0 || String::from_utf8_lossy(&buf[..n]).starts_with("HTTP/1.1 408"), "{:?}", &buf[..n]);
    // So is a kept-alive connection that sends nothing after its first request.
    let mut kept = TcpStream::connect(target).unwrap();
    kept.write_all(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n").unwrap();
    kept.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let n = kept.read(&mut buf).unwrap();
    assert!(String::from_utf8_lossy(&buf[..n]).starts_with("HTTP/1.1 200"));
    let t = Instant::now();
    let n = kept.read(&mut buf).unwrap_or(0);
    let waited = t.elapsed().as_secs_f64();
    eprintln!("an idle kept-alive connection was closed after {waited:.2} s");
    assert!(n == 0 && waited < 6.0, "an idle kept-alive connection stayed open {waited:.1} s ({n} bytes)");
    drop(idle);
    let log = server.log();
    assert!(!log.contains("Too many open files"), "{log}");
    // Past its address's cap, each of the attacker's new connections took the place of its own
    // oldest silent one: the attacker holds at most the cap, and says so in the log.
    assert!(
        log.contains("closing idle connections"),
        "the connections closed to make room are logged: {log}"
    );
}

/// Row 5: a worker of one thread used to get sixteen leases, and keep them with heartbeats. It
/// now holds at most its threads plus two (one fetched ahead, one uploading); the next worker
/// gets the rest.
#[test]
fn a_worker_holds_at_most_its_threads_plus_one_leases() {
    let _s = serial();
    let server = start("greedy", &[]);
    submit_tiny(&server.url, 64, 64, 16); // 16 tiles
    let greedy = register(&server.url, "greedy", 1);
    let codes: Vec<u16> = (0..16).map(|_| lease(&server.url, greedy).0).collect();
    assert_eq!(&codes[..3], [200, 200, 200]);
    assert!(codes[3..].iter().all(|&c| c == 429), "{codes:?}");
    let (_, v) = lease(&server.url, greedy);
    assert!(v["error"].as_str().unwrap().contains("threads + 2 = 3"), "{v}");
    let other = register(&server.url, "other", 1);
    assert_eq!(lease(&server.url, other).0, 200, "another worker gets work");
    // Threads are bounded at registration.
    let (code, v) = post(&server.url, "/api/v1/worker/register", json!({"name": "x", "threads": 1_000_000}));
    assert_eq!(code, 422, "{v}");
    let (code, v) = post(&server.url, "/api/v1/worker/register", json!({"name": "x", "threads": 0}));
    assert_eq!(code, 422, "{v}");
}

/// Row 6: anyone with the worker token could send `x-tessera-worker: 2` and worker 2's lease id
/// and report, fail or give back its tile. Every call now needs the calling worker's secret.
#[test]
fn a_worker_cannot_act_for_another() {
    let _s = serial();
    let server = start("impersonate", &[]);
    let job = submit_tiny(&server.url, 32, 32, 32);
    let victim = register(&server.url, "victim", 1);
    let mallory = register(&server.url, "mallory", 1);
    let (code, l) = lease(&server.url, victim);
    assert_eq!(code, 200, "{l}");
    let lease_id = l["lease_id"].as_u64().unwrap();
    let black = encode_tile(&vec![[0.0; 3]; 32 * 32]);
    // Claiming the victim's id with mallory's own secret, or with none.
    assert_eq!(upload_as(&server.url, victim, mallory, lease_id, &black).0, 401);
    let bare = ureq::put(&format!("{}/api/v1/worker/leases/{lease_id}/result", server.url))
        .set("Authorization", &format!("Bearer {WORKER}"))
        .set("x-tessera-worker", &victim.to_string())
        .set("x-tessera-checksum", &checksum(&black));
    let (code, v) = call(bare, Some(("application/octet-stream".into(), black.clone())));
    assert_eq!(code, 401, "{v}");
    assert!(v["error"].as_str().unwrap().contains("x-tessera-worker-secret"), "{v}");
    // Under its own id it is not mallory's lease.
    assert_eq!(upload_as(&server.url, mallory, mallory, lease_id, &black).0, 409);
    // Fail and release with the victim's id and mallory's secret.
    for path in [
        format!("/api/v1/worker/leases/{lease_id}/fail"),
        format!("/api/v1/worker/leases/{lease_id}/release"),
    ] {
        let r = ureq::post(&format!("{}{path}", server.url))
            .set("Authorization", &format!("Bearer {WORKER}"))
            .set("x-tessera-worker-secret", &worker_secret(&server.url, mallory).unwrap());
        let body = json!({"worker_id": victim, "error": "x", "fatal": true}).to_string().into_bytes();
        let (code, v) = call(r, Some(("application/json".into(), body)));
        assert_eq!(code, 401, "{path}: {v}");
    }
    // Heartbeats and leases in the victim's name too.
    for (path, body) in [
        ("/api/v1/worker/heartbeat", json!({"worker_id": victim, "leases": [lease_id], "rendering": null})),
        ("/api/v1/worker/lease", json!({"worker_id": victim, "wait_seconds": 0.0})),
        ("/api/v1/worker/watch", json!({"worker_id": victim, "leases": [lease_id], "wait_seconds": 0.0})),
    ] {
        let r = ureq::post(&format!("{}{path}", server.url))
            .set("Authorization", &format!("Bearer {WORKER}"))
            .set("x-tessera-worker-secret", &worker_secret(&server.url, mallory).unwrap());
        let (code, v) = call(r, Some(("application/json".into(), body.to_string().into_bytes())));
        assert_eq!(code, 401, "{path}: {v}");
    }
    // The real holder's result is the one stored.
    let white = encode_tile(&vec![[1.0; 3]; 32 * 32]);
    assert_eq!(upload_as(&server.url, victim, victim, lease_id, &white).0, 204);
    let log = get_api(&server.url, &format!("/api/v1/jobs/{job}/log")).1;
    let done: Vec<&Value> =
        log["events"].as_array().unwrap().iter().filter(|e| e["kind"] == "tile_done").collect();
    assert_eq!(done.len(), 1);
    assert_eq!((done[0]["worker"].as_str(), done[0]["worker_id"].as_u64()), (Some("victim"), Some(victim)));
}

/// Row 7: a 16 MiB failure message used to become the job's error (every job listing 16.8 MB,
/// the database +136 MB). Worker bodies are now at most 64 KiB, and a message is cut to 4 KiB.
#[test]
fn failure_messages_are_bounded() {
    let _s = serial();
    let server = start("fail", &[]);
    let job = submit_tiny(&server.url, 32, 32, 32);
    let w = register(&server.url, "w", 1);
    let (_, l) = lease(&server.url, w);
    let lease_id = l["lease_id"].as_u64().unwrap();
    let path = format!("/api/v1/worker/leases/{lease_id}/fail");
    let huge = "x".repeat(16 << 20);
    let (code, v) = post(&server.url, &path, json!({"worker_id": w, "error": huge, "fatal": true}));
    assert_eq!(code, 413, "{v}");
    let long = "é".repeat(30_000); // 60 000 bytes: under the body limit
    let (code, v) = post(&server.url, &path, json!({"worker_id": w, "error": long, "fatal": true}));
    assert_eq!(code, 204, "{v}");
    let (_, info) = get_api(&server.url, &format!("/api/v1/jobs/{job}"));
    assert_eq!(info["state"], "failed");
    let error = info["error"].as_str().unwrap();
    assert!(error.len() <= 4096 + 200, "the job's error is {} bytes", error.len());
    assert!(error.contains("bytes cut"), "{}", &error[error.len() - 60..]);
    let (_, list) = get_api(&server.url, "/api/v1/jobs");
    assert!(list.to_string().len() < 20_000, "the job list is {} bytes", list.to_string().len());
}

/// Row 8: a 4 MiB worker name used to be copied into every `tile_done` event. Names are now at
/// most 128 bytes, and events refer to the worker by id.
#[test]
fn worker_names_are_bounded() {
    let _s = serial();
    let server = start("names", &[]);
    let job = submit_tiny(&server.url, 64, 32, 32);
    let (code, v) =
        post(&server.url, "/api/v1/worker/register", json!({"name": "n".repeat(4 << 20), "threads": 1}));
    assert_eq!(code, 413, "{v}");
    let (code, v) =
        post(&server.url, "/api/v1/worker/register", json!({"name": "n".repeat(129), "threads": 1}));
    assert_eq!(code, 422, "{v}");
    assert!(v["error"].as_str().unwrap().contains("128 bytes"), "{v}");
    let (code, v) = post(&server.url, "/api/v1/worker/register", json!({"name": "a\nb", "threads": 1}));
    assert_eq!(code, 422, "{v}");
    let name = "n".repeat(128);
    let w = register(&server.url, &name, 1);
    for _ in 0..2 {
        let (_, l) = lease(&server.url, w);
        let body = encode_tile(&vec![[0.5; 3]; 32 * 32]);
        assert_eq!(upload_as(&server.url, w, w, l["lease_id"].as_u64().unwrap(), &body).0, 204);
    }
    let log = get_api(&server.url, &format!("/api/v1/jobs/{job}/log")).1;
    let done: Vec<&Value> =
        log["events"].as_array().unwrap().iter().filter(|e| e["kind"] == "tile_done").collect();
    assert_eq!(done.len(), 2);
    for e in done {
        assert_eq!((e["worker"].as_str(), e["worker_id"].as_u64()), (Some(name.as_str()), Some(w)));
    }
}

/// A tar whose one member is named by a pax header holding a NUL byte.
fn tar_with_nul_name() -> Vec<u8> {
    let mut b = tar::Builder::new(Vec::new());
    let record = |key: &str, value: &[u8]| {
        let body = [format!(" {key}=").as_bytes(), value, b"\n"].concat();
        // A record's length counts its own digits.
        let mut len = body.len() + 1;
        while format!("{len}").len() + body.len() != len {
            len += 1;
        }
        [format!("{len}").as_bytes(), &body].concat()
    };
    let pax = record("path", b"scene\0.xml");
    let mut h = tar::Header::new_ustar();
    h.set_entry_type(tar::EntryType::XHeader);
    h.set_size(pax.len() as u64);
    h.set_path("PaxHeader").unwrap();
    h.set_cksum();
    b.append(&h, pax.as_slice()).unwrap();
    let scene = tessera_testkit::tiny_scene(8, 8);
    let mut h = tar::Header::new_ustar();
    h.set_size(scene.len() as u64);
    h.set_path("scene.xml").unwrap();
    h.set_mode(0o644);
    h.set_cksum();
    b.append(&h, scene.as_slice()).unwrap();
    b.into_inner().unwrap()
}

/// A zip whose one member's name holds a NUL byte.
fn zip_with_nul_name() -> Vec<u8> {
    let mut z = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    z.start_file("scene\0.xml", zip::write::SimpleFileOptions::default()).unwrap();
    z.write_all(&tessera_testkit::tiny_scene(8, 8)).unwrap();
    z.finish().unwrap().into_inner()
}

/// Row 9: a bundle member whose name holds a NUL byte (a tar's pax path, a zip entry) used to
/// panic the server (a 500). It is a 400 naming the member.
#[test]
fn bundle_members_with_nul_bytes_are_refused_by_name() {
    let _s = serial();
    let server = start("nul", &[]);
    for (file, bundle) in [("b.tar", tar_with_nul_name()), ("b.zip", zip_with_nul_name())] {
        let (code, v) = submit(&server.url, Some(API), &[("bundle", Some(file), &bundle)]);
        assert_eq!(code, 400, "{file}: {v}");
        let error = v["error"].as_str().unwrap();
        assert!(error.contains(r#""scene\0.xml""#) && error.contains("control character"), "{file}: {error}");
    }
    assert!(!server.log().contains("panicked"), "{}", server.log());
    let took = timed_get(&server.url, "/healthz");
    assert!(took < 1.0, "/healthz took {took:.2} s after the refusals");
}

/// Row 10: a tile of NaN or infinite values with a correct checksum used to be stored (the frame
/// came out black or white). Non-finite values are refused; negative and large finite values
/// are legal (lights of negative power exist), and stored as they are.
#[test]
fn tiles_of_non_finite_values_are_refused() {
    let _s = serial();
    let server = start("nan", &[]);
    let job = submit_tiny(&server.url, 8, 4, 4); // two tiles of 16 pixels
    let w = register(&server.url, "w", 1);
    let (_, l) = lease(&server.url, w);
    let lease_id = l["lease_id"].as_u64().unwrap();
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let mut px = vec![[0.5f32; 3]; 16];
        px[7][1] = bad;
        let (code, v) = upload_as(&server.url, w, w, lease_id, &encode_tile(&px));
        assert_eq!(code, 400, "{bad}: {v}");
        assert!(v["error"].as_str().unwrap().contains("pixel 7 (row-major), channel 1"), "{v}");
    }
    let mut px = vec![[0.5f32; 3]; 16];
    px[0] = [-1.0, 1e38, 0.0];
    assert_eq!(upload_as(&server.url, w, w, lease_id, &encode_tile(&px)).0, 204);
    assert_eq!(get_api(&server.url, &format!("/api/v1/jobs/{job}")).1["frames"][0]["tiles_done"], 1);
}
