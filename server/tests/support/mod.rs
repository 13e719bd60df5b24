//! What the farm's end-to-end tests share: starting the real binaries, HTTP calls, uploads.

#![allow(dead_code)]

pub mod browser;
pub mod small_fs;

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;
pub use tessera_testkit::TempDir;
// For the tests that include this module, whichever of them each one uses.
#[allow(unused_imports)]
pub use tessera_testkit::{first_line, signal, start_server, wait_timeout};

/// How long one farm test may run before the whole test binary is stopped: a hang (a child that
/// never exits, a pipe that never closes) must fail CI with the test's name, not eat its clock.
/// Generous, and never an assertion about speed: the slowest test takes about a minute here.
const HANG_LIMIT: Duration = Duration::from_secs(600);

/// Takes the lock that runs these tests one at a time, and starts the hang watchdog.
pub fn serial() -> tessera_testkit::Serial {
    tessera_testkit::serial(HANG_LIMIT)
}

/// What a pipe yields within `limit` (a reader thread; whatever arrived by then, lossily as text).
pub fn drain_for(mut pipe: impl Read + Send + 'static, limit: Duration) -> String {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut buf = [0u8; 4096];
        while let Ok(n) = pipe.read(&mut buf) {
            if n == 0 || tx.send(buf[..n].to_vec()).is_err() {
                break;
            }
        }
    });
    let deadline = Instant::now() + limit;
    let mut out = Vec::new();
    while let Ok(chunk) = rx.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
        out.extend(chunk);
    }
    String::from_utf8_lossy(&out).into_owned()
}

pub fn server_bin() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_tessera-server"))
}

/// `tessera-worker`, built next to the server binary. Cargo builds it for `cargo test
/// --workspace` but not for a test run of this package alone, where an older build would be
/// tested: so `cargo build` runs once per test binary here (a no-op when it is up to date).
pub fn worker_bin() -> PathBuf {
    static BUILT: std::sync::Once = std::sync::Once::new();
    let bin = server_bin().with_file_name("tessera-worker");
    BUILT.call_once(|| {
        let release = server_bin().components().any(|c| c.as_os_str() == "release");
        let mut cmd = Command::new(env!("CARGO"));
        cmd.args(["build", "-p", "tessera-worker"]);
        if release {
            cmd.arg("--release");
        }
        without_test_env(&mut cmd);
        let status = cmd.status().expect("run cargo build -p tessera-worker");
        assert!(status.success(), "cannot build tessera-worker");
    });
    bin
}

/// `tessera` (the client), built next to the server binary like [`worker_bin`].
pub fn client_bin() -> PathBuf {
    static BUILT: std::sync::Once = std::sync::Once::new();
    let bin = server_bin().with_file_name("tessera");
    BUILT.call_once(|| {
        let release = server_bin().components().any(|c| c.as_os_str() == "release");
        let mut cmd = Command::new(env!("CARGO"));
        cmd.args(["build", "-p", "tessera-client"]);
        if release {
            cmd.arg("--release");
        }
        without_test_env(&mut cmd);
        let status = cmd.status().expect("run cargo build -p tessera-client");
        assert!(status.success(), "cannot build tessera-client");
    });
    bin
}

pub use tessera_testkit::without_test_env;

pub fn repo() -> PathBuf {
    tessera_testkit::repo_root()
}

pub struct Server {
    pub child: Child,
    pub url: String,
    pub log: PathBuf,
    /// The data directory when the server owns it ([`Server::start_temp`]); removed after the
    /// server stops.
    data: Option<TempDir>,
}

impl Server {
    /// Starts `tessera-server` with `args` (plus a data dir and a free port unless given).
    pub fn start(data: &Path, args: &[&str]) -> Server {
        Server::start_with(data, args, |_| {})
    }

    /// [`Server::start`], with `configure` applied to the command first (limits, environment).
    pub fn start_with(data: &Path, args: &[&str], configure: impl FnOnce(&mut Command)) -> Server {
        let log = data.with_extension(format!("log{}", std::process::id()));
        let mut cmd = Command::new(server_bin());
        configure(&mut cmd);
        cmd.arg("--data-dir").arg(data).args(args);
        if !args.contains(&"--bind") {
            cmd.args(["--bind", "127.0.0.1:0"]);
        }
        cmd.arg("--worker-bin").arg(worker_bin());
        let (child, url) = start_server(cmd, &log);
        Server { child, url, log, data: None }
    }

    /// Starts `tessera-server` with `args` on a data directory of its own (`TempDir::new(tag)`),
    /// removed when the server is dropped.
    pub fn start_temp(tag: &str, args: &[&str]) -> Server {
        let data = TempDir::new(tag);
        let mut server = Server::start(&data, args);
        server.data = Some(data);
        server
    }

    /// A field of the server process's `/proc/PID/status` in KiB (`VmRSS`, `VmHWM`: the peak).
    pub fn memory_kib(&self, field: &str) -> u64 {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.child.id())).unwrap();
        status
            .lines()
            .find_map(|l| l.strip_prefix(field)?.strip_prefix(':'))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
            .unwrap_or_else(|| panic!("no {field} in /proc/PID/status"))
    }

    pub fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    pub fn kill9(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        // SIGTERM, so that the server stops its local workers.
        signal(&self.child, libc::SIGTERM);
        if wait_timeout(&mut self.child, Duration::from_secs(10)).is_some() {
            return;
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

pub struct Worker(pub Child);

impl Worker {
    pub fn start(url: &str, token: &str, name: &str) -> Worker {
        let child = Command::new(worker_bin())
            .args(["work", "--server", url, "--token", token, "--name", name, "--threads", "1"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start tessera-worker work");
        Worker(child)
    }

    pub fn kill9(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A multipart/form-data body: (field, file name or None, bytes).
pub fn multipart(parts: &[(&str, Option<&str>, &[u8])]) -> (String, Vec<u8>) {
    let boundary = "tessera-test-boundary-7f3a";
    let mut body = Vec::new();
    for (name, file, data) in parts {
        body.extend_from_slice(format!("--{boundary}\r\n").as_bytes());
        match file {
            Some(f) => body.extend_from_slice(
                format!("Content-Disposition: form-data; name=\"{name}\"; filename=\"{f}\"\r\nContent-Type: application/octet-stream\r\n\r\n").as_bytes(),
            ),
            None => body.extend_from_slice(format!("Content-Disposition: form-data; name=\"{name}\"\r\n\r\n").as_bytes()),
        }
        body.extend_from_slice(data);
        body.extend_from_slice(b"\r\n");
    }
    body.extend_from_slice(format!("--{boundary}--\r\n").as_bytes());
    (format!("multipart/form-data; boundary={boundary}"), body)
}

/// (status, JSON body) of a request; never panics on 4xx/5xx.
pub fn call(req: ureq::Request, body: Option<(String, Vec<u8>)>) -> (u16, Value) {
    let res = match body {
        Some((ct, bytes)) => req.set("Content-Type", &ct).send_bytes(&bytes),
        None => req.call(),
    };
    let (code, text) = match res {
        Ok(r) => (r.status(), r.into_string().unwrap_or_default()),
        Err(ureq::Error::Status(code, r)) => (code, r.into_string().unwrap_or_default()),
        Err(e) => panic!("request failed: {e}"),
    };
    (code, serde_json::from_str(&text).unwrap_or(Value::String(text)))
}

pub fn submit(url: &str, token: Option<&str>, parts: &[(&str, Option<&str>, &[u8])]) -> (u16, Value) {
    let mut req = ureq::post(&format!("{url}/api/v1/jobs"));
    if let Some(t) = token {
        req = req.set("Authorization", &format!("Bearer {t}"));
    }
    call(req, Some(multipart(parts)))
}

/// `POST /api/v1/jobs/ID/cancel`: the status and the answer.
pub fn cancel(server: &Server, id: u64) -> (u16, Value) {
    call(ureq::post(&format!("{}/api/v1/jobs/{id}/cancel", server.url)), Some(("text/plain".into(), vec![])))
}

pub fn get_json(url: &str, path: &str) -> Value {
    let (code, v) = call(ureq::get(&format!("{url}{path}")), None);
    assert_eq!(code, 200, "GET {path}: {v}");
    v
}

pub fn get_bytes(url: &str, path: &str) -> Vec<u8> {
    let r = ureq::get(&format!("{url}{path}")).call().unwrap_or_else(|e| match e {
        ureq::Error::Status(code, r) => panic!("GET {path}: {code}: {}", r.into_string().unwrap_or_default()),
        e => panic!("GET {path}: {e}"),
    });
    let mut out = Vec::new();
    r.into_reader().read_to_end(&mut out).unwrap();
    out
}

/// Polls the job until `until` holds for it, or panics with the server log after `secs` (or when
/// the job ends in a way `until` does not accept).
pub fn wait_job(server: &Server, id: u64, secs: u64, until: impl Fn(&Value) -> bool) -> Value {
    let deadline = Instant::now() + Duration::from_secs(secs);
    loop {
        let job = get_json(&server.url, &format!("/api/v1/jobs/{id}"));
        if until(&job) {
            return job;
        }
        assert!(
            !matches!(job["state"].as_str(), Some("failed") | Some("canceled")),
            "job ended unexpectedly: {job}\n{}",
            server.log()
        );
        if Instant::now() > deadline {
            panic!("timed out waiting for job {id}: {job}\n--- server log ---\n{}", server.log());
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Tiles done over all of a job's frames.
pub fn tiles_done(job: &Value) -> u64 {
    job["frames"].as_array().map_or(0, |f| f.iter().map(|f| f["tiles_done"].as_u64().unwrap_or(0)).sum())
}

/// Submits the demo environment scene (HDR output, an image asset) at `samples` spp in tiles of
/// `tile` pixels; returns the job id.
pub fn submit_environment(server: &Server, samples: &str, tile: &str) -> u64 {
    submit_environment_with(server, samples, tile, &[])
}

/// [`submit_environment`] with more fields (`pass_samples`, `priority`, ...).
pub fn submit_environment_with(server: &Server, samples: &str, tile: &str, extra: &[(&str, &str)]) -> u64 {
    let scene = std::fs::read(repo().join("scenes/environment.xml")).unwrap();
    let sky = std::fs::read(repo().join("scenes/textures/sky.hdr")).unwrap();
    let mut parts: Vec<(&str, Option<&str>, &[u8])> = vec![
        ("scene", Some("environment.xml"), &scene),
        ("asset", Some("textures/sky.hdr"), &sky),
        ("samples", None, samples.as_bytes()),
        ("tile_size", None, tile.as_bytes()),
    ];
    parts.extend(extra.iter().map(|(k, v)| (*k, None, v.as_bytes())));
    let (code, job) = submit(&server.url, None, &parts);
    assert_eq!(code, 201, "{job}\n{}", server.log());
    job["id"].as_u64().unwrap()
}

/// What `tessera-worker render` writes for the environment scene at `samples` spp: the bytes of
/// its `.exr` and `.png`.
pub fn cli_render_environment(samples: &str) -> (Vec<u8>, Vec<u8>) {
    let out = cli_render(&repo().join("scenes/environment.xml"), &["--samples", samples]);
    (std::fs::read(out.join("environment.exr")).unwrap(), std::fs::read(out.join("environment.png")).unwrap())
}

/// `tessera-worker render SCENE --quiet --out DIR` with `extra` options, which must succeed;
/// the directory of its outputs.
pub fn cli_render(scene: &Path, extra: &[&str]) -> TempDir {
    let out = TempDir::new("farm-cli");
    let status = Command::new(worker_bin())
        .arg("render")
        .arg(scene)
        .args(extra)
        .args(["--quiet", "--out"])
        .arg(out.path())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .unwrap();
    assert!(status.success(), "tessera-worker render {} {extra:?} failed", scene.display());
    out
}

/// Every file the CLI wrote into `cli_out` is an output of the finished job `job` (its JSON),
/// with the same bytes. (The farm may keep more: a float `.exr` beside a `.png` camera's image.)
pub fn assert_job_outputs_equal_cli(server: &Server, job: &Value, cli_out: &Path) {
    let id = job["id"].as_u64().unwrap();
    let mut farm_files = std::collections::HashMap::new();
    for (k, frame) in job["frames"].as_array().unwrap().iter().enumerate() {
        for o in frame["outputs"].as_array().unwrap() {
            farm_files.insert(o["name"].as_str().unwrap().to_string(), k);
        }
    }
    let mut compared = 0;
    for entry in std::fs::read_dir(cli_out).unwrap() {
        let name = entry.unwrap().file_name().into_string().unwrap();
        let k = farm_files.get(&name).unwrap_or_else(|| panic!("the farm has no {name}: {job}"));
        let farm = get_bytes(&server.url, &format!("/api/v1/jobs/{id}/frames/{k}/files/{name}"));
        assert!(
            farm == std::fs::read(cli_out.join(&name)).unwrap(),
            "frame {k}: the farm's {name} differs from the CLI's"
        );
        compared += 1;
    }
    assert!(compared > 0, "the CLI wrote nothing into {}", cli_out.display());
}

/// A worker-protocol POST with the worker token `token`.
/// A worker request as a worker sends it: the worker token, and after registration the
/// worker's secret. The secret each registration through here answers is remembered (by server
/// and worker id) and sent with every later request naming that `worker_id`, as a real worker
/// does; a test that plays a worker lying about its id sends the header itself.
pub fn worker_post(url: &str, token: &str, path: &str, body: Value) -> (u16, Value) {
    let mut req = ureq::post(&format!("{url}{path}")).set("Authorization", &format!("Bearer {token}"));
    if let Some(secret) = body["worker_id"].as_u64().and_then(|id| worker_secret(url, id)) {
        req = req.set("x-tessera-worker-secret", &secret);
    }
    let (code, v) = call(req, Some(("application/json".into(), body.to_string().into_bytes())));
    if let (true, Some(id), Some(secret)) = (
        path == "/api/v1/worker/register" && code == 200,
        v["worker_id"].as_u64(),
        v["worker_secret"].as_str(),
    ) {
        secrets().lock().unwrap().insert((url.to_string(), id), secret.to_string());
    }
    (code, v)
}

fn secrets() -> &'static std::sync::Mutex<std::collections::HashMap<(String, u64), String>> {
    static SECRETS: std::sync::OnceLock<std::sync::Mutex<std::collections::HashMap<(String, u64), String>>> =
        std::sync::OnceLock::new();
    SECRETS.get_or_init(Default::default)
}

/// The secret registration gave worker `id` of the server at `url` (through [`worker_post`]).
pub fn worker_secret(url: &str, id: u64) -> Option<String> {
    secrets().lock().unwrap().get(&(url.to_string(), id)).cloned()
}

/// The value of an unlabelled Prometheus metric, as text.
pub fn metric(server: &Server, name: &str) -> String {
    let metrics = String::from_utf8(get_bytes(&server.url, "/metrics")).unwrap();
    metrics
        .lines()
        .find_map(|l| l.strip_prefix(name).and_then(|v| v.strip_prefix(' ')).map(str::to_string))
        .unwrap_or_else(|| panic!("no {name} in\n{metrics}"))
}

/// Waits (up to a minute) until the worker named `name` is rendering a tile of its own: killing
/// it then leaves a lease to expire.
pub fn wait_until_rendering(server: &Server, name: &str) {
    let deadline = Instant::now() + Duration::from_secs(60);
    while !get_json(&server.url, "/api/v1/workers")["workers"]
        .as_array()
        .unwrap()
        .iter()
        .any(|w| w["name"] == name && w["state"] == "rendering" && !w["current_tile"].is_null())
    {
        assert!(Instant::now() < deadline, "worker {name} never rendered\n{}", server.log());
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Submits camera 3 (a path-traced view) of the scene file `scene` that
/// `tessera_testkit::small_path_traced_box` wrote, with the options `extra`; the accepted job's
/// JSON.
pub fn submit_box(server: &Server, scene: &std::path::Path, extra: &[(&str, &[u8])]) -> Value {
    let text = std::fs::read(scene).unwrap();
    let mut parts: Vec<(&str, Option<&str>, &[u8])> =
        vec![("scene", Some("box.xml"), &text), ("cameras", None, b"3")];
    parts.extend(extra.iter().map(|(k, v)| (*k, None, *v)));
    let (code, job) = submit(&server.url, None, &parts);
    assert_eq!(code, 201, "{job}\n{}", server.log());
    job
}
