//! Web pages that mean harm, against the real server over real sockets: a page the user visits
//! sends the farm cross-site requests (a multipart submission, a `text/plain` cancel: CORS
//! "simple" requests that no preflight stops), points a name of its own at it (DNS rebinding)
//! or frames it. Each test sends what the browser would send (`Origin`, `Sec-Fetch-Site`,
//! `Host`) byte for byte, and checks the refusal and that nothing changed. Also: `/metrics`
//! behind the API token, and cheap beside a job of a hundred thousand tiles.

mod support;

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use support::*;
use tessera::protocol::{CHECKSUM_HEADER, RENDER_SECONDS_HEADER, checksum, encode_tile};

const API: &str = "APITOK";
const WORKER: &str = "WTOK";

/// The answer to a raw request: status, headers (lowercase names), body.
struct Answer {
    status: u16,
    headers: Vec<(String, String)>,
    body: Vec<u8>,
}

impl Answer {
    fn header(&self, name: &str) -> Option<&str> {
        self.headers.iter().find(|(k, _)| k == name).map(|(_, v)| v.as_str())
    }
    fn json(&self) -> Value {
        serde_json::from_slice(&self.body).unwrap_or_else(|_| Value::String(self.text()))
    }
    fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }
    /// The `error` of a JSON refusal.
    fn error(&self) -> String {
        self.json()["error"].as_str().unwrap_or_else(|| panic!("no error in {}", self.text())).to_string()
    }
}

/// A request written byte for byte as a browser would (its `Host` included, which is the
/// point of DNS rebinding: the page's name, the farm's address), over a fresh connection that
/// closes after the answer. `host` `None`: the server's own address.
fn raw(
    url: &str,
    method: &str,
    path: &str,
    host: Option<&str>,
    headers: &[(&str, &str)],
    body: &[u8],
) -> Answer {
    let addr = url.trim_start_matches("http://");
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
    let mut head =
        format!("{method} {path} HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n", host.unwrap_or(addr));
    for (k, v) in headers {
        head += &format!("{k}: {v}\r\n");
    }
    head += &format!("Content-Length: {}\r\n\r\n", body.len());
    s.write_all(head.as_bytes()).unwrap();
    s.write_all(body).unwrap();
    let mut out = Vec::new();
    s.read_to_end(&mut out).unwrap();
    let end = out.windows(4).position(|w| w == b"\r\n\r\n").expect("an answer head");
    let head = String::from_utf8_lossy(&out[..end]).into_owned();
    let mut lines = head.lines();
    let status = lines.next().unwrap().split(' ').nth(1).unwrap().parse().unwrap();
    let headers: Vec<(String, String)> = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
        .collect();
    let mut body = out[end + 4..].to_vec();
    if headers.iter().any(|(k, v)| k == "transfer-encoding" && v.contains("chunked")) {
        body = dechunk(&body);
    }
    Answer { status, headers, body }
}

fn dechunk(mut b: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    loop {
        let nl = b.windows(2).position(|w| w == b"\r\n").unwrap();
        let size = usize::from_str_radix(std::str::from_utf8(&b[..nl]).unwrap().trim(), 16).unwrap();
        if size == 0 {
            return out;
        }
        out.extend_from_slice(&b[nl + 2..nl + 2 + size]);
        b = &b[nl + 2 + size + 2..];
    }
}

/// The tiny scene as the multipart body a page's `<form enctype="multipart/form-data">` posts.
fn tiny_form() -> (String, Vec<u8>) {
    multipart(&[("scene", Some("tiny.xml"), &tessera_testkit::tiny_scene(8, 8))])
}

/// A submission from a browser with `headers` (`Origin`, `Sec-Fetch-Site`).
fn submit_as(url: &str, host: Option<&str>, headers: &[(&str, &str)]) -> Answer {
    let (ct, body) = tiny_form();
    let mut all = vec![("Content-Type", ct.as_str())];
    all.extend_from_slice(headers);
    raw(url, "POST", "/api/v1/jobs", host, &all, &body)
}

/// The jobs the farm holds (as a client without a browser's headers sees them).
fn job_count(url: &str, token: Option<&str>) -> usize {
    let mut req = ureq::get(&format!("{url}/api/v1/jobs"));
    if let Some(t) = token {
        req = req.set("Authorization", &format!("Bearer {t}"));
    }
    let (code, v) = call(req, None);
    assert_eq!(code, 200, "{v}");
    v["jobs"].as_array().unwrap().len()
}

fn own_host(server: &Server) -> String {
    server.url.trim_start_matches("http://").to_string()
}

/// A page at evil.example (and a sandboxed frame or local file: `Origin: null`) posts a scene
/// in a multipart form to the token-less farm on 127.0.0.1. It used to queue a job (201): any
/// site could spend the machine. Now: 403 naming `--allowed-origin`, and no job.
#[test]
fn a_cross_site_multipart_submission_is_refused() {
    let _s = serial();
    let server = Server::start_temp("browser-submit", &["--local-workers", "0"]);
    for origin in ["https://evil.example", "null"] {
        let a = submit_as(&server.url, None, &[("Origin", origin), ("Sec-Fetch-Site", "cross-site")]);
        assert_eq!(a.status, 403, "Origin: {origin}: {}", a.text());
        let e = a.error();
        assert!(e.contains("--allowed-origin") && e.contains("refused"), "{e}");
        // Without the Sec-Fetch-Site an older browser leaves out, the Origin alone is refused.
        let a = submit_as(&server.url, None, &[("Origin", origin)]);
        assert_eq!(a.status, 403, "Origin: {origin}: {}", a.text());
    }
    assert_eq!(job_count(&server.url, None), 0, "a refused submission queued a job");
}

/// A page's `fetch(.., {method: "POST", mode: "no-cors", body: "x"})` (a `text/plain` body)
/// to `/api/v1/jobs/1/cancel` used to cancel the job (200). Now: 403, and the job still queued.
#[test]
fn a_foreign_text_plain_cancel_is_refused() {
    let _s = serial();
    let server = Server::start_temp("browser-cancel", &["--local-workers", "0"]);
    let a = submit_as(&server.url, None, &[]);
    assert_eq!(a.status, 201, "{}", a.text());
    let id = a.json()["id"].as_u64().unwrap();
    let path = format!("/api/v1/jobs/{id}/cancel");
    for headers in [
        vec![("Origin", "https://evil.example"), ("Sec-Fetch-Site", "cross-site")],
        vec![("Origin", "http://127.0.0.1.evil.example")],
        vec![("Origin", "null")],
    ] {
        let mut all = vec![("Content-Type", "text/plain;charset=UTF-8")];
        all.extend(headers.iter().copied());
        let a = raw(&server.url, "POST", &path, None, &all, b"x");
        assert_eq!(a.status, 403, "{headers:?}: {}", a.text());
        assert!(a.error().contains("--allowed-origin"), "{}", a.text());
    }
    let job = get_json(&server.url, &format!("/api/v1/jobs/{id}"));
    assert_eq!(job["state"], "queued", "a refused cancel cancelled the job: {job}");
    // The client's cancel (no browser headers) still works.
    assert_eq!(cancel(&server, id).0, 200);
}

/// A browser that says the request is cross-site (`Sec-Fetch-Site: cross-site` or
/// `same-site`: a page on another port or subdomain) without an `Origin` is refused too, on
/// the job API and the worker protocol alike.
#[test]
fn sec_fetch_site_cross_site_is_refused() {
    let _s = serial();
    let server = Server::start_temp(
        "browser-fetch-site",
        &["--local-workers", "0", "--worker-token", WORKER, "--api-token", API],
    );
    let bearer = format!("Bearer {API}");
    for site in ["cross-site", "same-site"] {
        let a = submit_as(&server.url, None, &[("Sec-Fetch-Site", site), ("Authorization", &bearer)]);
        assert_eq!(a.status, 403, "{site}: {}", a.text());
        let e = a.error();
        assert!(e.contains(site) && e.contains("--allowed-origin"), "{e}");
    }
    let wbearer = format!("Bearer {WORKER}");
    let a = raw(
        &server.url,
        "POST",
        "/api/v1/worker/register",
        None,
        &[
            ("Sec-Fetch-Site", "cross-site"),
            ("Authorization", &wbearer),
            ("Content-Type", "application/json"),
        ],
        json!({"name": "page", "threads": 1}).to_string().as_bytes(),
    );
    assert_eq!(a.status, 403, "{}", a.text());
    assert_eq!(job_count(&server.url, Some(API)), 0);
    assert!(get_json_token(&server.url, "/api/v1/workers")["workers"].as_array().unwrap().is_empty());
}

fn get_json_token(url: &str, path: &str) -> Value {
    let (code, v) =
        call(ureq::get(&format!("{url}{path}")).set("Authorization", &format!("Bearer {API}")), None);
    assert_eq!(code, 200, "{v}");
    v
}

/// The farm's own page (its origin: the address the browser reached it by) submits and
/// cancels as before, by IP address and by localhost; so do clients without browser headers.
#[test]
fn the_farms_own_origin_is_accepted() {
    let _s = serial();
    let server = Server::start_temp("browser-own", &["--local-workers", "0"]);
    let host = own_host(&server);
    let port = host.rsplit(':').next().unwrap().to_string();
    let local = format!("localhost:{port}");
    let mut ids = Vec::new();
    for (h, origin) in [(host.clone(), format!("http://{host}")), (local.clone(), format!("http://{local}"))]
    {
        let a = submit_as(&server.url, Some(&h), &[("Origin", &origin), ("Sec-Fetch-Site", "same-origin")]);
        assert_eq!(a.status, 201, "{origin}: {}", a.text());
        ids.push(a.json()["id"].as_u64().unwrap());
    }
    let a = raw(
        &server.url,
        "POST",
        &format!("/api/v1/jobs/{}/cancel", ids[0]),
        None,
        &[("Origin", &format!("http://{host}")), ("Sec-Fetch-Site", "same-origin")],
        b"",
    );
    assert_eq!(a.status, 200, "{}", a.text());
    // No Origin, no Sec-Fetch-Site (curl, the client, workers): accepted.
    let a = submit_as(&server.url, None, &[]);
    assert_eq!(a.status, 201, "{}", a.text());
    assert_eq!(job_count(&server.url, None), 3);
}

/// `--allowed-origin` (and `TESSERA_ALLOWED_ORIGINS`, comma-separated) lets the named sites'
/// pages through, and nobody else.
#[test]
fn allowed_origin_lets_a_named_site_through() {
    let _s = serial();
    let data = TempDir::new("browser-allowed-origin");
    let server = Server::start_with(
        &data,
        &["--local-workers", "0", "--allowed-origin", "https://ui.example"],
        |cmd| {
            cmd.env("TESSERA_ALLOWED_ORIGINS", "http://tools.example:3000, https://other.example");
        },
    );
    let a =
        submit_as(&server.url, None, &[("Origin", "https://ui.example"), ("Sec-Fetch-Site", "cross-site")]);
    assert_eq!(a.status, 201, "{}", a.text());
    let a =
        submit_as(&server.url, None, &[("Origin", "https://evil.example"), ("Sec-Fetch-Site", "cross-site")]);
    assert_eq!(a.status, 403, "{}", a.text());
    assert_eq!(job_count(&server.url, None), 1);
    drop(server);

    // The environment's list, when no flag is given.
    let data = TempDir::new("browser-allowed-origin-env");
    let server = Server::start_with(&data, &["--local-workers", "0"], |cmd| {
        cmd.env("TESSERA_ALLOWED_ORIGINS", "http://tools.example:3000, https://other.example");
    });
    for origin in ["http://tools.example:3000", "https://other.example"] {
        let a = submit_as(&server.url, None, &[("Origin", origin), ("Sec-Fetch-Site", "cross-site")]);
        assert_eq!(a.status, 201, "{origin}: {}", a.text());
    }
    let a = submit_as(&server.url, None, &[("Origin", "http://tools.example:3001")]);
    assert_eq!(a.status, 403, "{}", a.text());

    // A bad origin stops the server at start, naming the flag.
    let out = std::process::Command::new(server_bin())
        .args(["--local-workers", "0", "--bind", "127.0.0.1:0", "--allowed-origin", "null"])
        .arg("--data-dir")
        .arg(data.path().join("never"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--allowed-origin"), "{err}");
}

/// A page at rebind.evil.example whose name now resolves to 127.0.0.1 reads and drives the
/// farm as its own origin (no Origin check can tell): it used to be answered on every route.
/// Now every route refuses that `Host` (421, naming `--allowed-host`): jobs, a job, its output
/// files, the workers, the events, the page, submission; and nothing was created or leaked.
#[test]
fn a_rebinding_host_is_refused_on_every_route() {
    let _s = serial();
    let server =
        Server::start_temp("browser-rebind", &["--local-workers", "1", "--local-worker-threads", "1"]);
    let scene = tessera_testkit::tiny_scene(8, 8);
    let (code, job) = submit(&server.url, None, &[("scene", Some("tiny.xml"), &scene)]);
    assert_eq!(code, 201, "{job}");
    let id = job["id"].as_u64().unwrap();
    let job = wait_job(&server, id, 120, |j| j["state"] == "done");
    let file = job["frames"][0]["outputs"][0]["name"].as_str().unwrap().to_string();
    let file_path = format!("/api/v1/jobs/{id}/frames/0/files/{file}");
    let port = own_host(&server).rsplit(':').next().unwrap().to_string();
    let evil = format!("rebind.evil.example:{port}");
    let reads = [
        "/api/v1/jobs".to_string(),
        format!("/api/v1/jobs/{id}"),
        format!("/api/v1/jobs/{id}/log"),
        file_path.clone(),
        format!("/api/v1/jobs/{id}/frames/0/preview.png"),
        "/api/v1/workers".to_string(),
        "/api/v1/events".to_string(),
        "/metrics".to_string(),
        "/".to_string(),
        "/static/app.js".to_string(),
    ];
    for path in &reads {
        let a = raw(&server.url, "GET", path, Some(&evil), &[], b"");
        assert_eq!(a.status, 421, "GET {path} as {evil}: {}", a.text());
        let e = a.error();
        assert!(e.contains("--allowed-host") && e.contains("rebind.evil.example"), "{e}");
        assert!(a.body.len() < 1024, "GET {path}: the refusal carries {} bytes", a.body.len());
    }
    // Submission and cancel, as the page's own origin (which is what a rebound page is).
    let origin = format!("http://{evil}");
    let a = submit_as(&server.url, Some(&evil), &[("Origin", &origin), ("Sec-Fetch-Site", "same-origin")]);
    assert_eq!(a.status, 421, "{}", a.text());
    let a = submit_as(&server.url, Some(&evil), &[]);
    assert_eq!(a.status, 421, "{}", a.text());
    let a = raw(
        &server.url,
        "POST",
        &format!("/api/v1/jobs/{id}/cancel"),
        Some(&evil),
        &[("Origin", &origin)],
        b"",
    );
    assert_eq!(a.status, 421, "{}", a.text());
    assert_eq!(job_count(&server.url, None), 1, "a refused submission queued a job");
    // The same requests by the farm's address, and by localhost, are answered.
    for host in [own_host(&server), format!("localhost:{port}")] {
        let a = raw(&server.url, "GET", &file_path, Some(&host), &[], b"");
        assert_eq!(a.status, 200, "{host}: {}", a.text());
        assert!(a.body.len() > 8, "{host}: an empty file");
    }
}

/// `--allowed-host` (and `TESSERA_ALLOWED_HOSTS`) names the hosts clients use; `*` answers any.
/// A request that carries the API or worker token is answered whatever its `Host` (a
/// rebinding page cannot know the token): workers and clients keep reaching a farm by a
/// service name they were not configured for.
#[test]
fn allowed_host_lets_a_named_host_through() {
    let _s = serial();
    let server = Server::start_temp(
        "browser-allowed-host",
        &["--local-workers", "0", "--allowed-host", "farm.example", "--allowed-host", "rebind.evil.example"],
    );
    for host in ["rebind.evil.example", "farm.example:8080", "FARM.EXAMPLE."] {
        let a = raw(&server.url, "GET", "/api/v1/jobs", Some(host), &[], b"");
        assert_eq!(a.status, 200, "{host}: {}", a.text());
        let a = submit_as(&server.url, Some(host), &[]);
        assert_eq!(a.status, 201, "{host}: {}", a.text());
    }
    let a = raw(&server.url, "GET", "/api/v1/jobs", Some("other.evil.example"), &[], b"");
    assert_eq!(a.status, 421, "{}", a.text());
    drop(server);

    let data = TempDir::new("browser-allowed-host-env");
    let server = Server::start_with(&data, &["--local-workers", "0"], |cmd| {
        cmd.env("TESSERA_ALLOWED_HOSTS", "*");
    });
    let a = raw(&server.url, "GET", "/api/v1/jobs", Some("anything.example"), &[], b"");
    assert_eq!(a.status, 200, "{}", a.text());
    drop(server);

    // Tokens: with the right one any Host is answered; without, or with a wrong one, not.
    let server = Server::start_temp(
        "browser-host-token",
        &["--local-workers", "0", "--api-token", API, "--worker-token", WORKER],
    );
    let host = Some("tessera-server:8080");
    let ok = |a: &Answer, what: &str| assert_eq!(a.status, 200, "{what}: {}", a.text());
    ok(
        &raw(&server.url, "GET", "/api/v1/jobs", host, &[("Authorization", &format!("Bearer {API}"))], b""),
        "api",
    );
    let register = json!({"name": "by-service-name", "threads": 1}).to_string();
    ok(
        &raw(
            &server.url,
            "POST",
            "/api/v1/worker/register",
            host,
            &[("Authorization", &format!("Bearer {WORKER}")), ("Content-Type", "application/json")],
            register.as_bytes(),
        ),
        "worker",
    );
    for auth in [vec![], vec![("Authorization", "Bearer wrong")]] {
        let a = raw(&server.url, "GET", "/api/v1/jobs", host, &auth, b"");
        assert_eq!(a.status, 421, "{auth:?}: {}", a.text());
    }
}

/// The page, its script and style sheet, and every other answer (refusals included) forbid
/// framing (`X-Frame-Options: DENY`, CSP `frame-ancestors 'none'`) and carry the page's
/// content policy.
#[test]
fn the_page_cannot_be_framed() {
    let _s = serial();
    let server = Server::start_temp("browser-frame", &["--local-workers", "0"]);
    for path in ["/", "/static/app.js", "/static/style.css", "/api/v1/jobs", "/healthz", "/no/such/thing"] {
        let a = raw(&server.url, "GET", path, None, &[], b"");
        assert_eq!(a.header("x-frame-options"), Some("DENY"), "{path}");
        let csp = a.header("content-security-policy").unwrap_or_else(|| panic!("{path}: no CSP"));
        for directive in ["frame-ancestors 'none'", "script-src 'self'", "default-src 'none'"] {
            assert!(csp.contains(directive), "{path}: {csp}");
        }
        assert_eq!(a.header("x-content-type-options"), Some("nosniff"), "{path}");
    }
    let a = raw(&server.url, "GET", "/", Some("rebind.evil.example"), &[], b"");
    assert_eq!((a.status, a.header("x-frame-options")), (421, Some("DENY")));
    let a = submit_as(&server.url, None, &[("Origin", "https://evil.example")]);
    assert_eq!((a.status, a.header("x-frame-options")), (403, Some("DENY")));
    // The page loads nothing inline that the policy would block.
    let page = String::from_utf8(get_bytes(&server.url, "/")).unwrap();
    let inline_handler = page.split(" on").skip(1).any(|rest| {
        let name: String = rest.chars().take_while(char::is_ascii_lowercase).collect();
        !name.is_empty() && rest[name.len()..].starts_with('=')
    });
    assert!(!page.contains("<script>") && !page.contains("style=") && !inline_handler, "{page}");
}

/// `/metrics` counts jobs and workers: a farm with an API token answers it only with the token
/// (401 without, naming the header), unless `--public-metrics` (or TESSERA_PUBLIC_METRICS).
#[test]
fn metrics_need_the_api_token_unless_public() {
    let _s = serial();
    let server = Server::start_temp("browser-metrics", &["--local-workers", "0", "--api-token", API]);
    let (code, v) = call(ureq::get(&format!("{}/metrics", server.url)), None);
    assert_eq!(code, 401, "{v}");
    assert!(v["error"].as_str().unwrap().contains("Authorization: Bearer"), "{v}");
    let (code, v) =
        call(ureq::get(&format!("{}/metrics", server.url)).set("Authorization", "Bearer nope"), None);
    assert_eq!(code, 401, "{v}");
    let (code, v) = call(
        ureq::get(&format!("{}/metrics", server.url)).set("Authorization", &format!("Bearer {API}")),
        None,
    );
    assert_eq!(code, 200, "{v}");
    assert!(v.as_str().unwrap().contains("tessera_tiles_done_total 0"), "{v}");
    drop(server);

    let server = Server::start_temp(
        "browser-metrics-public",
        &["--local-workers", "0", "--api-token", API, "--public-metrics"],
    );
    assert_eq!(metric(&server, "tessera_tiles_done_total"), "0");
    // The job API still wants the token.
    assert_eq!(call(ureq::get(&format!("{}/api/v1/jobs", server.url)), None).0, 401);
    drop(server);

    let data = TempDir::new("browser-metrics-env");
    let server = Server::start_with(&data, &["--local-workers", "0", "--api-token", API], |cmd| {
        cmd.env("TESSERA_PUBLIC_METRICS", "true");
    });
    assert_eq!(metric(&server, "tessera_lease_expiries_total"), "0");
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    v[v.len() / 2]
}

/// `/metrics` used to count every tile row on each call (0.16-0.27 s beside a big job) under
/// the store's lock: polled, it pushed a worker's lease from 1 ms to 0.4 s. Now it reads a row
/// of counters. A job of 99,856 tile rows (316 x 316 in 1-pixel tiles, under the default
/// `--max-job-tiles`); one thread polls `/metrics` without pause while a worker leases tiles
/// and returns them: `/metrics` and the lease each take under 5 ms (median; a scan of these
/// rows alone takes over 10 ms here), and the metrics count exactly the results returned and
/// their render seconds.
#[test]
fn metrics_stay_cheap_beside_a_large_job() {
    let _s = serial();
    let server = Server::start_temp(
        "browser-metrics-load",
        &["--local-workers", "0", "--worker-token", WORKER, "--public-metrics"],
    );
    let url = server.url.clone();
    let scene = tessera_testkit::tiny_scene(316, 316);
    let t = Instant::now();
    let (code, job) = submit(&url, None, &[("scene", Some("tiny.xml"), &scene), ("tile_size", None, b"1")]);
    assert_eq!(code, 201, "{job}");
    let id = job["id"].as_u64().unwrap();
    let tiles = get_json(&url, &format!("/api/v1/jobs/{id}"))["frames"][0]["tiles_total"].as_u64().unwrap();
    assert_eq!(tiles, 316 * 316);
    eprintln!("a job of {tiles} tile rows submitted in {:.2} s", t.elapsed().as_secs_f64());

    let (code, v) = worker_post(&url, WORKER, "/api/v1/worker/register", json!({"name": "w", "threads": 1}));
    assert_eq!(code, 200, "{v}");
    let worker = v["worker_id"].as_u64().unwrap();
    let secret = worker_secret(&url, worker).unwrap();
    let pixel = encode_tile(&[[0.25, 0.5, 0.75]]);
    // One tile: lease it (timed) and return it with 0.125 s of render time.
    let one_tile = || -> f64 {
        let t = Instant::now();
        let (code, lease) = worker_post(
            &url,
            WORKER,
            "/api/v1/worker/lease",
            json!({"worker_id": worker, "wait_seconds": 0.0}),
        );
        let took = t.elapsed().as_secs_f64();
        assert_eq!(code, 200, "{lease}");
        let req = ureq::put(&format!("{url}/api/v1/worker/leases/{}/result", lease["lease_id"]))
            .set("Authorization", &format!("Bearer {WORKER}"))
            .set("x-tessera-worker", &worker.to_string())
            .set("x-tessera-worker-secret", &secret)
            .set(CHECKSUM_HEADER, &checksum(&pixel))
            .set(RENDER_SECONDS_HEADER, "0.125");
        let (code, v) = call(req, Some(("application/octet-stream".into(), pixel.clone())));
        assert!(code == 204 || code == 200, "{code} {v}");
        took
    };
    const QUIET: usize = 50;
    const POLLED: usize = 300;
    let mut quiet: Vec<f64> = (0..QUIET).map(|_| one_tile()).collect();

    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let poller = {
        let (url, stop) = (url.clone(), stop.clone());
        std::thread::spawn(move || {
            let mut took = Vec::new();
            while !stop.load(std::sync::atomic::Ordering::Relaxed) && took.len() < 100_000 {
                let t = Instant::now();
                let body = get_bytes(&url, "/metrics");
                took.push(t.elapsed().as_secs_f64());
                assert!(String::from_utf8_lossy(&body).contains("tessera_tiles_done_total"));
            }
            took
        })
    };
    let mut polled: Vec<f64> = (0..POLLED).map(|_| one_tile()).collect();
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let mut scrapes = poller.join().unwrap();
    let (quiet_median, polled_median, scrape_median) =
        (median(&mut quiet), median(&mut polled), median(&mut scrapes));
    let polled_max = polled.last().copied().unwrap();
    eprintln!(
        "lease latency, median: {:.2} ms alone, {:.2} ms while /metrics is polled ({} scrapes, median {:.2} ms); slowest polled lease {:.1} ms",
        quiet_median * 1e3,
        polled_median * 1e3,
        scrapes.len(),
        scrape_median * 1e3,
        polled_max * 1e3
    );
    // A scan of the tile rows (what /metrics did) takes over 10 ms here, and a lease waits for
    // it; a read of the counters takes well under a millisecond.
    assert!(scrapes.len() >= 20, "/metrics answered only {} times", scrapes.len());
    assert!(scrape_median < 0.005, "/metrics took {:.1} ms (median)", scrape_median * 1e3);
    assert!(
        polled_median < 0.005,
        "a lease took {:.1} ms (median) while /metrics was polled",
        polled_median * 1e3
    );

    // The counters: exactly the results returned, their render seconds, the job running.
    let n = (QUIET + POLLED) as u64;
    assert_eq!(metric(&server, "tessera_tiles_done_total"), n.to_string());
    assert_eq!(metric(&server, "tessera_tile_render_seconds_count"), n.to_string());
    let sum: f64 = metric(&server, "tessera_tile_render_seconds_sum").parse().unwrap();
    assert!((sum - n as f64 * 0.125).abs() < 1e-6, "{sum}");
    let metrics = String::from_utf8(get_bytes(&url, "/metrics")).unwrap();
    assert!(metrics.contains("tessera_jobs{state=\"running\"} 1"), "{metrics}");
    assert!(metrics.contains("tessera_workers{state=\"idle\"} 1"), "{metrics}");
    assert_eq!(tiles_done(&get_json(&url, &format!("/api/v1/jobs/{id}"))), n);
}
