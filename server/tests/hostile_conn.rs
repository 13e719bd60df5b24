//! Connections, downloads and decoders under attack, against the real server over real sockets:
//! request bodies that never come, kept-alive connections left open up to the caps, parallel
//! slow downloads of large outputs, pass results of out-of-range sums, and re-tone-mapping of
//! frames that have no `.exr`. Each test reproduces one way through and checks the bounded or
//! clear outcome.

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
    Server::start_temp(&format!("hostile-conn-{tag}"), &args)
}

fn post(url: &str, path: &str, body: Value) -> (u16, Value) {
    worker_post(url, WORKER, path, body)
}

fn register(url: &str, name: &str) -> u64 {
    let (code, v) = post(url, "/api/v1/worker/register", json!({"name": name, "threads": 1}));
    assert_eq!(code, 200, "{v}");
    v["worker_id"].as_u64().unwrap()
}

fn lease(url: &str, worker: u64) -> Value {
    let (code, l) = post(url, "/api/v1/worker/lease", json!({"worker_id": worker, "wait_seconds": 5.0}));
    assert_eq!(code, 200, "{l}");
    l
}

/// A one-sphere scene of `w` x `h` pixels whose camera writes `image`.
fn scene(w: u32, h: u32, image: &str) -> Vec<u8> {
    String::from_utf8(tessera_testkit::tiny_scene(w, h)).unwrap().replace("tiny.png", image).into_bytes()
}

/// Submits `scene` with the API token and `fields`; the job's id.
fn submit_scene(url: &str, scene: &[u8], fields: &[(&str, &str)]) -> u64 {
    let mut parts: Vec<(&str, Option<&str>, &[u8])> = vec![("scene", Some("scene.xml"), scene)];
    parts.extend(fields.iter().map(|(k, v)| (*k, None, v.as_bytes())));
    let (code, v) = submit(url, Some(API), &parts);
    assert_eq!(code, 201, "{v}");
    v["id"].as_u64().unwrap()
}

fn get_api(url: &str, path: &str) -> (u16, Value) {
    call(ureq::get(&format!("{url}{path}")).set("Authorization", &format!("Bearer {API}")), None)
}

fn upload(url: &str, worker: u64, lease: u64, body: &[u8]) -> (u16, Value) {
    let req = ureq::put(&format!("{url}/api/v1/worker/leases/{lease}/result"))
        .set("Authorization", &format!("Bearer {WORKER}"))
        .set("x-tessera-worker", &worker.to_string())
        .set("x-tessera-worker-secret", &worker_secret(url, worker).unwrap_or_default())
        .set("x-tessera-checksum", &checksum(body));
    call(req, Some(("application/octet-stream".into(), body.to_vec())))
}

fn addr(url: &str) -> SocketAddr {
    url.trim_start_matches("http://").parse().unwrap()
}

/// A connection to `target` from the loopback address `from`.
fn connect_from(from: &str, target: SocketAddr) -> TcpStream {
    let sock = socket2::Socket::new(socket2::Domain::IPV4, socket2::Type::STREAM, None).unwrap();
    sock.bind(&format!("{from}:0").parse::<SocketAddr>().unwrap().into()).unwrap();
    sock.connect_timeout(&target.into(), Duration::from_secs(2)).unwrap();
    let s: TcpStream = sock.into();
    s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
    s
}

/// Reads one answer (head and `Content-Length` body) from `s`; `None` if the connection
/// closes (or says nothing for the read timeout) first.
fn read_answer(s: &mut TcpStream) -> Option<String> {
    let mut got = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        if let Some(end) = got.windows(4).position(|w| w == b"\r\n\r\n") {
            let head = String::from_utf8_lossy(&got[..end]).to_ascii_lowercase();
            let len: usize = head
                .lines()
                .find_map(|l| l.strip_prefix("content-length:"))
                .and_then(|v| v.trim().parse().ok())
                .unwrap_or(0);
            if got.len() >= end + 4 + len {
                return Some(String::from_utf8_lossy(&got[..end + 4 + len]).into_owned());
            }
        }
        match s.read(&mut buf) {
            Ok(0) | Err(_) => return None,
            Ok(n) => got.extend_from_slice(&buf[..n]),
        }
    }
}

/// Sends `GET /healthz` on `s` and reads its answer.
fn healthz_on(s: &mut TcpStream) -> Option<String> {
    s.write_all(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n").ok()?;
    read_answer(s)
}

/// Seconds a `GET /healthz` from `from` takes to be answered 200 on a new connection; panics
/// if the connection is closed unanswered.
fn fresh_healthz(from: &str, target: SocketAddr) -> f64 {
    let t = Instant::now();
    let mut s = connect_from(from, target);
    let answer = healthz_on(&mut s).unwrap_or_default();
    assert!(answer.starts_with("HTTP/1.1 200"), "a new client from {from} was refused: {answer:?}");
    t.elapsed().as_secs_f64()
}

/// Opens `n` connections from `from` that each finish a request and stay open, idle.
fn idle_kept_alive(from: &str, target: SocketAddr, n: usize) -> Vec<TcpStream> {
    (0..n)
        .map(|i| {
            let mut s = connect_from(from, target);
            let answer = healthz_on(&mut s).unwrap_or_default();
            assert!(answer.starts_with("HTTP/1.1 200"), "connection {i} was not answered: {answer:?}");
            s
        })
        .collect()
}

/// How many of `conns` the server has closed (a read that ends at once).
fn closed(conns: &mut [TcpStream]) -> usize {
    conns
        .iter_mut()
        .map(|s| {
            s.set_read_timeout(Some(Duration::from_millis(20))).unwrap();
            let mut b = [0u8; 16];
            matches!(s.read(&mut b), Ok(0))
        })
        .filter(|&gone| gone)
        .count()
}

/// Row "connection cap": 256 idle connections from 127.0.0.1 (the per-address cap), kept
/// alive after a request or silent since they opened, used to lock every other local client
/// (the local worker too) out for the header timeout (20 s), and the total cap did the same for
/// every address. Now the connection idle the longest makes room: a new client is answered at
/// once, and a busy connection is never the one closed.
#[test]
fn idle_kept_alive_connections_make_room_for_new_clients() {
    let _s = serial();
    // The per-address cap (the default, 256).
    let server = start("idle-per-ip", &[]);
    let target = addr(&server.url);
    let mut idle = idle_kept_alive("127.0.0.1", target, 256);
    let mut worst: f64 = 0.0;
    for _ in 0..5 {
        worst = worst.max(fresh_healthz("127.0.0.1", target));
    }
    eprintln!("behind 256 idle kept-alive connections of its own address: a new client waited {worst:.3} s");
    assert!(worst < 1.0, "a new client from 127.0.0.1 waited {worst:.2} s behind 256 idle connections");
    // The oldest idle ones made room; the others are still open (and still answer).
    let gone = closed(&mut idle);
    assert!((1..=10).contains(&gone), "{gone} idle connections were closed for 5 new clients");
    let last = idle.last_mut().unwrap();
    last.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    assert!(healthz_on(last).is_some_and(|a| a.starts_with("HTTP/1.1 200")));
    assert!(server.log().contains("closing idle connections"), "{}", server.log());
    drop(idle);

    // Connections that never send a byte are idle too: 256 of them from 127.0.0.1 (opened
    // after the ones above were dropped) make room for a new client at once, long before the
    // header timeout (20 s) would close them.
    let silent: Vec<TcpStream> = (0..256).map(|_| connect_from("127.0.0.1", target)).collect();
    std::thread::sleep(Duration::from_millis(300));
    let took = fresh_healthz("127.0.0.1", target);
    eprintln!("behind 256 silent connections of its own address: a new client waited {took:.3} s");
    assert!(took < 1.0, "a new client from 127.0.0.1 waited {took:.2} s behind 256 silent connections");
    drop(silent);
    drop(server);

    // The total cap: 64 idle connections from 127.0.0.2 fill it; 127.0.0.1 still gets in.
    let server = start("idle-total", &["--max-connections", "64"]);
    let target = addr(&server.url);
    let _idle = idle_kept_alive("127.0.0.2", target, 64);
    let took = fresh_healthz("127.0.0.1", target);
    eprintln!("behind 64 idle connections at the total cap: a new client waited {took:.3} s");
    assert!(took < 1.0, "a new client waited {took:.2} s at the total cap");
    // With the cap full of requests in progress (bodies still coming), nobody is closed to
    // make room: a newcomer is refused, the requests go on.
    let busy: Vec<TcpStream> = (0..64)
        .map(|_| {
            let mut s = connect_from("127.0.0.3", target);
            s.write_all(submission_head(100_000).as_bytes()).unwrap();
            s
        })
        .collect();
    std::thread::sleep(Duration::from_millis(500));
    let mut late = connect_from("127.0.0.1", target);
    late.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    assert_eq!(healthz_on(&mut late), None, "a connection over a cap of busy connections is closed");
    drop(busy);
}

/// The head of a submission whose multipart body of `len` bytes is still to come.
fn submission_head(len: usize) -> String {
    format!(
        "POST /api/v1/jobs HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {API}\r\n\
         Content-Type: multipart/form-data; boundary=b0undary\r\nContent-Length: {len}\r\n\r\n"
    )
}

/// Row "body timeout": a request whose head is complete but whose body never comes (or stops
/// half way) used to be held open for ever: 16 of them held the per-address cap. Now each is
/// answered 408 (naming --body-timeout-seconds) and closed after the body timeout, nothing is
/// stored, and the address gets in again; a body that keeps coming slowly is never cut.
#[test]
fn request_bodies_that_stop_are_timed_out() {
    let _s = serial();
    let server = start("body", &["--max-connections-per-ip", "16", "--body-timeout-seconds", "2"]);
    let target = addr(&server.url);
    // A worker's lease (from another address), for a tile upload that stalls.
    let job = submit_scene(&server.url, &scene(8, 8, "t.png"), &[("tile_size", "8")]);
    let w = register(&server.url, "w");
    let l = lease(&server.url, w);
    let lease_id = l["lease_id"].as_u64().unwrap();
    let tile = encode_tile(&vec![[0.25, 0.5, 0.75]; 64]);

    // 16 stalled requests from 127.0.0.2: submissions with no body or half a body, and a tile
    // upload with half its tile.
    let started = Instant::now();
    let mut stalled: Vec<TcpStream> = (0..16)
        .map(|i| {
            let mut s = connect_from("127.0.0.2", target);
            if i == 15 {
                let head = format!(
                    "PUT /api/v1/worker/leases/{lease_id}/result HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {WORKER}\r\n\
                     x-tessera-worker: {w}\r\nx-tessera-worker-secret: {}\r\nx-tessera-checksum: {}\r\n\
                     Content-Type: application/octet-stream\r\nContent-Length: {}\r\n\r\n",
                    worker_secret(&server.url, w).unwrap(),
                    checksum(&tile),
                    tile.len()
                );
                s.write_all(head.as_bytes()).unwrap();
                s.write_all(&tile[..tile.len() / 2]).unwrap();
            } else {
                s.write_all(submission_head(100_000).as_bytes()).unwrap();
                if i % 2 == 1 {
                    s.write_all(b"--b0undary\r\nContent-Disposition: form-data; name=\"scene\"; filename=\"a.xml\"\r\n\r\n<Scene>").unwrap();
                }
            }
            s
        })
        .collect();
    // The address is at its cap: a 17th connection from it is closed unanswered.
    std::thread::sleep(Duration::from_millis(200));
    let mut over = connect_from("127.0.0.2", target);
    over.set_read_timeout(Some(Duration::from_secs(1))).unwrap();
    assert_eq!(healthz_on(&mut over), None, "the 17th connection of 127.0.0.2 got in while 16 were open");
    // Other addresses are served meanwhile.
    let took = fresh_healthz("127.0.0.1", target);
    assert!(took < 1.0, "another client waited {took:.2} s behind the stalled requests");

    // Each stalled request is answered 408 once its body has been silent for 2 s, and closed.
    let mut latest: f64 = 0.0;
    for (i, s) in stalled.iter_mut().enumerate() {
        let answer = read_answer(s).unwrap_or_else(|| panic!("stalled request {i} got no answer"));
        latest = latest.max(started.elapsed().as_secs_f64());
        assert!(answer.starts_with("HTTP/1.1 408"), "request {i}: {answer}");
        assert!(answer.contains("--body-timeout-seconds"), "request {i}: {answer}");
        assert!(!answer.contains("/tmp") && !answer.contains("tessera-data"), "{answer}");
        let mut rest = Vec::new();
        s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        assert!(matches!(s.read_to_end(&mut rest), Ok(0)), "request {i}: the connection stays open");
    }
    eprintln!("16 stalled requests answered 408 and closed within {latest:.2} s (body timeout 2 s)");
    assert!(latest < 6.0, "the stalled requests were held {latest:.1} s with a body timeout of 2 s");
    // The address gets in again, at once.
    let took = fresh_healthz("127.0.0.2", target);
    assert!(took < 1.0, "127.0.0.2 waited {took:.2} s after its stalled requests were closed");
    // Nothing of them was stored: one job (the test's own), no tile, no upload spooled.
    let (_, jobs) = get_api(&server.url, "/api/v1/jobs");
    assert_eq!(jobs["jobs"].as_array().unwrap().len(), 1, "{jobs}");
    let (_, j) = get_api(&server.url, &format!("/api/v1/jobs/{job}"));
    assert_eq!(j["frames"][0]["tiles_done"], 0, "{j}");

    // A body that keeps coming, a few bytes every half second for longer than the timeout,
    // is not cut: the tile is stored.
    let mut s = connect_from("127.0.0.1", target);
    let head = format!(
        "PUT /api/v1/worker/leases/{lease_id}/result HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {WORKER}\r\n\
         x-tessera-worker: {w}\r\nx-tessera-worker-secret: {}\r\nx-tessera-checksum: {}\r\n\
         Content-Type: application/octet-stream\r\nContent-Length: {}\r\n\r\n",
        worker_secret(&server.url, w).unwrap(),
        checksum(&tile),
        tile.len()
    );
    s.write_all(head.as_bytes()).unwrap();
    let slow = Instant::now();
    for chunk in tile.chunks(tile.len() / 8 + 1) {
        std::thread::sleep(Duration::from_millis(500));
        s.write_all(chunk).unwrap();
    }
    let answer = read_answer(&mut s).unwrap_or_default();
    eprintln!(
        "a tile sent over {:.1} s in pieces: {}",
        slow.elapsed().as_secs_f64(),
        answer.lines().next().unwrap_or("")
    );
    assert!(slow.elapsed() > Duration::from_secs(3));
    assert!(answer.starts_with("HTTP/1.1 204"), "{answer}");
    let j = wait_for(&server.url, job, |j| j["frames"][0]["tiles_done"] == 1);
    assert_eq!(j["frames"][0]["tiles_done"], 1);
}

/// Polls job `id` (with the API token) until `until` holds, for at most a minute.
fn wait_for(url: &str, id: u64, until: impl Fn(&Value) -> bool) -> Value {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let (code, j) = get_api(url, &format!("/api/v1/jobs/{id}"));
        assert_eq!(code, 200, "{j}");
        if until(&j) {
            return j;
        }
        assert!(Instant::now() < deadline, "timed out waiting for job {id}: {j}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// xorshift64: pseudo-random bits for incompressible test data.
fn noise(n: usize, mut state: u64) -> impl Iterator<Item = u64> {
    (0..n).map(move |_| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    })
}

/// Reads `path` (with `auth`) slowly, 256 KiB every 20 ms; the bytes read.
fn slow_download(url: String, path: String, auth: String) -> std::thread::JoinHandle<usize> {
    std::thread::spawn(move || {
        let resp = ureq::get(&format!("{url}{path}")).set("Authorization", &auth).call().unwrap();
        let mut reader = resp.into_reader();
        let mut total = 0;
        loop {
            let mut piece = Vec::with_capacity(256 << 10);
            match (&mut reader).take(256 << 10).read_to_end(&mut piece) {
                Ok(0) => return total,
                Ok(n) => total += n,
                Err(e) => panic!("download of {path} broke after {total} bytes: {e}"),
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    })
}

/// Peak growth of the server's resident memory (KiB) while eight slow downloads of `path`
/// (of `each` bytes) run at once.
fn peak_growth_of_eight(server: &Server, path: &str, auth: &str, each: usize) -> u64 {
    let before = server.memory_kib("VmRSS");
    let downloads: Vec<_> =
        (0..8).map(|_| slow_download(server.url.clone(), path.to_string(), auth.to_string())).collect();
    let mut peak = before;
    while downloads.iter().any(|d| !d.is_finished()) {
        peak = peak.max(server.memory_kib("VmRSS"));
        std::thread::sleep(Duration::from_millis(20));
    }
    for d in downloads {
        assert_eq!(d.join().unwrap(), each, "a download was cut short");
    }
    peak.saturating_sub(before)
}

/// Row "downloads": a download used to read the whole file into memory: one 48 MiB EXR was
/// +48 MiB of server memory, eight at once +384 MiB. Now files (outputs and the workers'
/// job files) are streamed: eight slow parallel downloads of a 48 MiB EXR, and of a 24 MiB
/// job file, grow the server's memory by a small fraction of one file.
#[test]
fn downloads_are_streamed_from_their_files() {
    let _s = serial();
    let server = start("downloads", &[]);
    // A 2048 x 2048 frame of incompressible floats: its EXR is 48 MiB. The job's bundle holds
    // 24 MiB of random bytes beside the scene.
    let side = 2048u32;
    let ballast: Vec<u8> = noise(3 << 20, 7).flat_map(u64::to_le_bytes).collect();
    let (code, v) = submit(
        &server.url,
        Some(API),
        &[
            ("scene", Some("scene.xml"), &scene(side, side, "big.exr")),
            ("asset", Some("ballast.bin"), &ballast),
            ("tile_size", None, side.to_string().as_bytes()),
            ("samples", None, b"1"),
        ],
    );
    assert_eq!(code, 201, "{v}");
    let job = v["id"].as_u64().unwrap();
    drop(ballast);
    let w = register(&server.url, "w");
    let l = lease(&server.url, w);
    let pixels: Vec<[f32; 3]> = noise((side * side) as usize, 11)
        .map(|r| {
            let f = |k: u32| ((r >> k) & 0xffff) as f32 / 65536.0 + 0.001;
            [f(0), f(16), f(32)]
        })
        .collect();
    let body = encode_tile(&pixels);
    drop(pixels);
    let (code, v) = upload(&server.url, w, l["lease_id"].as_u64().unwrap(), &body);
    assert_eq!(code, 204, "{v}");
    drop(body);
    let j = wait_for(&server.url, job, |j| j["state"] == "done");
    let exr_url = j["frames"][0]["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .find(|o| o["name"] == "big.exr")
        .unwrap_or_else(|| panic!("no big.exr: {j}"))["url"]
        .as_str()
        .unwrap()
        .to_string();
    let exr_len = get_api_len(&server.url, &exr_url);
    assert!(exr_len > 40 << 20, "the EXR is {exr_len} bytes");
    // Let the merge's memory settle before measuring.
    std::thread::sleep(Duration::from_millis(500));
    let grown = peak_growth_of_eight(&server, &exr_url, &format!("Bearer {API}"), exr_len);
    eprintln!(
        "eight slow downloads of a {} MiB EXR at once: server memory +{grown} KiB at the peak",
        exr_len >> 20
    );
    assert!(grown < 48 << 10, "eight downloads of a {exr_len}-byte EXR grew the server by {grown} KiB");

    // The workers' download of the job's files (its largest, the ballast), the same way.
    let wauth = format!("Bearer {WORKER}");
    let worker_get = |path: &str| {
        let r = ureq::get(&format!("{}{path}", server.url)).set("Authorization", &wauth).call().unwrap();
        let mut all = Vec::new();
        r.into_reader().read_to_end(&mut all).unwrap();
        all
    };
    let manifest: serde_json::Value = serde_json::from_slice(&worker_get(&format!(
        "/api/v1/worker/files/{}",
        l["manifest"].as_str().unwrap()
    )))
    .unwrap();
    let largest =
        manifest["files"].as_array().unwrap().iter().max_by_key(|f| f["size"].as_u64()).unwrap().clone();
    let file = format!("/api/v1/worker/files/{}", largest["sha256"].as_str().unwrap());
    let file_len = worker_get(&file).len();
    assert!(file_len >= 24 << 20, "the job's largest file is {file_len} bytes");
    let grown = peak_growth_of_eight(&server, &file, &wauth, file_len);
    eprintln!(
        "eight slow downloads of a {} MiB job file at once: server memory +{grown} KiB at the peak",
        file_len >> 20
    );
    assert!(grown < 48 << 10, "eight downloads of a {file_len}-byte job file grew the server by {grown} KiB");
}

/// The length of a download with the API token, read whole.
fn get_api_len(url: &str, path: &str) -> usize {
    let r = ureq::get(&format!("{url}{path}")).set("Authorization", &format!("Bearer {API}")).call().unwrap();
    assert!(r.header("content-length").is_some(), "a file is answered with its length");
    let mut all = Vec::new();
    r.into_reader().read_to_end(&mut all).unwrap();
    all.len()
}

/// Row "pass sums": a pass result whose sums were i128::MIN was accepted (204): `abs()`
/// overflowed in the range check. Now every such sum (in any channel) is a 400 naming the
/// pixel and channel, nothing is stored, and the real pass is still taken.
#[test]
fn pass_sums_of_i128_min_are_refused() {
    let _s = serial();
    let server = start("pass-sums", &[]);
    let job = submit_scene(
        &server.url,
        &scene(8, 8, "p.png"),
        &[("tile_size", "8"), ("samples", "32"), ("pass_samples", "16")],
    );
    let w = register(&server.url, "w");
    let l = lease(&server.url, w);
    assert!(l["pass"].is_object(), "the job is leased in passes: {l}");
    let lease_id = l["lease_id"].as_u64().unwrap();
    let sums = |at: usize, v: i128| {
        let mut body = Vec::with_capacity(64 * 64);
        for px in 0..64usize {
            for c in 0..4usize {
                let value = if px * 4 + c == at { v } else { 1 << 40 };
                body.extend_from_slice(&value.to_le_bytes());
            }
        }
        body
    };
    for (at, value) in [(0, i128::MIN), (4 * 63 + 3, i128::MIN), (4 * 5 + 1, i128::MAX), (2, -(1i128 << 120))]
    {
        let (code, v) = upload(&server.url, w, lease_id, &sums(at, value));
        assert_eq!(code, 400, "sum {value} at {at} was taken: {v}");
        let msg = v["error"].as_str().unwrap();
        assert!(msg.contains(&format!("pixel {}", at / 4)) && msg.contains("channel"), "{msg}");
        assert!(msg.contains("nothing was stored"), "{msg}");
    }
    let (_, j) = get_api(&server.url, &format!("/api/v1/jobs/{job}"));
    assert_eq!(j["frames"][0]["passes_done"], 0, "{j}");
    // The sums of a real pass (16 samples of radiance 1 each) are taken.
    let (code, v) = upload(&server.url, w, lease_id, &sums(usize::MAX, 0));
    assert_eq!(code, 204, "{v}");
}

/// Row "re-tone-mapping": an HDR frame named x.hdr was offered re-tone-mapping sliders, but
/// its tone map answered 404 (it has no .exr). Now the .hdr is re-tone-mapped, and the job
/// says where (`tonemap_url`) only once the frame has a float output.
#[test]
fn hdr_frames_are_re_tone_mapped() {
    let _s = serial();
    let server = start("tonemap-hdr", &[]);
    let job = submit_scene(&server.url, &scene(16, 16, "x.hdr"), &[("tile_size", "16")]);
    let (_, j) = get_api(&server.url, &format!("/api/v1/jobs/{job}"));
    assert!(j["frames"][0]["tonemap_url"].is_null(), "offered before the frame is merged: {j}");
    let w = register(&server.url, "w");
    let l = lease(&server.url, w);
    let pixels: Vec<[f32; 3]> = (0..256).map(|i| [i as f32 / 64.0, 0.5, 2.0]).collect();
    let (code, v) = upload(&server.url, w, l["lease_id"].as_u64().unwrap(), &encode_tile(&pixels));
    assert_eq!(code, 204, "{v}");
    let j = wait_for(&server.url, job, |j| j["state"] == "done");
    let frame = &j["frames"][0];
    let names: Vec<&str> =
        frame["outputs"].as_array().unwrap().iter().map(|o| o["name"].as_str().unwrap()).collect();
    assert!(names.contains(&"x.hdr") && !names.iter().any(|n| n.ends_with(".exr")), "{names:?}");
    assert!(frame["tonemap"].is_object(), "{frame}");
    let url = frame["tonemap_url"].as_str().unwrap_or_else(|| panic!("no tonemap_url: {frame}"));
    let png = |q: &str| {
        let r = ureq::get(&format!("{}{url}?{q}", server.url))
            .set("Authorization", &format!("Bearer {API}"))
            .call()
            .unwrap_or_else(|e| panic!("tone map {q}: {e}"));
        let mut out = Vec::new();
        r.into_reader().read_to_end(&mut out).unwrap();
        out
    };
    let dim = png("key=0.05");
    let bright = png("key=0.9");
    assert!(dim.starts_with(b"\x89PNG") && bright.starts_with(b"\x89PNG"));
    assert_ne!(dim, bright, "the key changes the picture");
    // Out-of-range parameters are still a 400.
    let (code, _) = get_api(&server.url, &format!("{url}?key=-1"));
    assert_eq!(code, 400);
    // The page offers the sliders by tonemap_url.
    let app = String::from_utf8(get_bytes(&server.url, "/static/app.js")).unwrap();
    assert!(app.contains("f.tonemap_url"), "the page does not use tonemap_url");
}
