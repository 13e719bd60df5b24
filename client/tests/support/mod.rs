//! The client's end-to-end tests run the real programs: a `tessera-server` with its SQLite
//! file in a temporary data directory, `tessera-worker work` processes, and the `tessera`
//! client, over real HTTP on loopback. Every wait has a deadline; the client never sees the
//! developer's own config file or TESSERA_* variables.

#![allow(dead_code)]

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::Duration;

use serde_json::Value;
pub use tessera_testkit::TempDir;
// For the tests that include this module, whichever of them each one uses.
#[allow(unused_imports)]
pub use tessera_testkit::{first_line, signal, start_server, wait_timeout};

/// How long one test may run before its test binary is stopped (a hang fails with a name).
const HANG_LIMIT: Duration = Duration::from_secs(600);

/// Takes the lock that runs these tests one at a time, and starts the hang watchdog.
pub fn serial() -> tessera_testkit::Serial {
    tessera_testkit::serial(HANG_LIMIT)
}

pub fn client_bin() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_tessera"))
}

/// `tessera-server` or `tessera-worker`, built beside the client: cargo builds only this
/// package's binaries for its tests, so `cargo build` runs once per test binary (a no-op when
/// they are up to date).
pub fn farm_bin(name: &str) -> PathBuf {
    static BUILT: std::sync::Once = std::sync::Once::new();
    BUILT.call_once(|| {
        let release = client_bin().components().any(|c| c.as_os_str() == "release");
        let mut cmd = Command::new(env!("CARGO"));
        cmd.args(["build", "-p", "tessera-server", "-p", "tessera-worker"]);
        if release {
            cmd.arg("--release");
        }
        let status = cmd.status().expect("run cargo build -p tessera-server -p tessera-worker");
        assert!(status.success(), "cannot build tessera-server and tessera-worker");
    });
    client_bin().with_file_name(name)
}

pub fn repo() -> PathBuf {
    tessera_testkit::repo_root()
}

/// The worker token the test servers are started with.
pub const WORKER_TOKEN: &str = "client-test-worker-token";

pub struct Server {
    pub child: Child,
    pub url: String,
    pub data: TempDir,
    pub log: PathBuf,
}

impl Server {
    /// A server on a free loopback port with a data directory of its own and no local workers.
    pub fn start(tag: &str, args: &[&str]) -> Server {
        let data = TempDir::new(tag);
        let log = data.with_extension("log");
        let mut cmd = Command::new(farm_bin("tessera-server"));
        cmd.arg("--data-dir")
            .arg(data.path())
            .args(["--bind", "127.0.0.1:0", "--local-workers", "0", "--worker-token", WORKER_TOKEN])
            .args(args);
        let (child, url) = start_server(cmd, &log);
        Server { child, url, data, log }
    }

    pub fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// `GET path` as JSON (with `token` when given); panics unless 200.
    pub fn get_json(&self, path: &str, token: Option<&str>) -> Value {
        let mut req = ureq::get(&format!("{}{path}", self.url));
        if let Some(t) = token {
            req = req.set("Authorization", &format!("Bearer {t}"));
        }
        let text = req.call().unwrap_or_else(|e| panic!("GET {path}: {e}")).into_string().unwrap();
        serde_json::from_str(&text).unwrap()
    }

    /// The bundles the server stored (`DATA/blobs/*.tar`).
    pub fn blobs(&self) -> Vec<PathBuf> {
        let mut out: Vec<PathBuf> = std::fs::read_dir(self.data.join("blobs"))
            .map(|d| {
                d.flatten().map(|e| e.path()).filter(|p| p.extension().is_some_and(|e| e == "tar")).collect()
            })
            .unwrap_or_default();
        out.sort();
        out
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        signal(&self.child, libc::SIGTERM);
        if wait_timeout(&mut self.child, Duration::from_secs(10)).is_none() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
        let _ = std::fs::remove_file(&self.log);
    }
}

/// A `tessera-worker work` process (one render thread), killed on drop.
pub struct Worker(pub Child);

impl Worker {
    pub fn start(url: &str, name: &str) -> Worker {
        let child = Command::new(farm_bin("tessera-worker"))
            .args(["work", "--server", url, "--token", WORKER_TOKEN, "--name", name, "--threads", "1"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start tessera-worker work");
        Worker(child)
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// The `tessera` client as a command whose environment holds no TESSERA_* variable and whose
/// config directory is `config_home` (so no real user's config file is read).
pub fn client(config_home: &Path) -> Command {
    let mut cmd = Command::new(client_bin());
    for (k, _) in std::env::vars_os() {
        if k.to_string_lossy().starts_with("TESSERA_") {
            cmd.env_remove(&k);
        }
    }
    cmd.env("XDG_CONFIG_HOME", config_home).env("HOME", config_home);
    cmd.stdin(Stdio::null());
    cmd
}

/// Runs `cmd` to its end within `limit` (killed and a panic after it), capturing its output.
pub fn run(cmd: &mut Command, limit: Duration) -> Output {
    let mut child = cmd.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("start tessera");
    let out = child.stdout.take().unwrap();
    let err = child.stderr.take().unwrap();
    let read = |mut r: Box<dyn Read + Send>| {
        std::thread::spawn(move || {
            let mut v = Vec::new();
            let _ = r.read_to_end(&mut v);
            v
        })
    };
    let (out, err) = (read(Box::new(out)), read(Box::new(err)));
    let status = wait_timeout(&mut child, limit).unwrap_or_else(|| {
        let _ = child.kill();
        let _ = child.wait();
        panic!("{cmd:?} still running after {} s", limit.as_secs())
    });
    Output { status, stdout: out.join().unwrap(), stderr: err.join().unwrap() }
}

pub fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// Every file under `dir` (relative paths, sorted) with its bytes.
pub fn files_under(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(dir).unwrap().to_string_lossy().into_owned();
                out.push((rel, std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

/// What `tessera-worker render SCENE --out DIR` writes, with `extra` options.
pub fn cli_render(scene: &Path, out: &Path, extra: &[&str]) {
    let output = run(
        Command::new(farm_bin("tessera-worker"))
            .arg("render")
            .arg(scene)
            .arg("--out")
            .arg(out)
            .arg("--quiet")
            .args(extra),
        Duration::from_secs(300),
    );
    assert!(output.status.success(), "tessera-worker render {}: {}", scene.display(), text(&output.stderr));
}
