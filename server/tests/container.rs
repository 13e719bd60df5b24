//! The container image, built and run for real: `deploy/build-image.sh` builds it as a user
//! would (a Debian base made with mmdebstrap, the release binaries built here, nothing pulled from
//! a registry), then a farm runs in it: a server container and two worker containers on a podman
//! network with tokens, the server's port published on 127.0.0.1 only. The real client submits a
//! scene from the host; mid-job one worker container is stopped (`podman stop`: SIGTERM, the
//! image's STOPSIGNAL), the job still finishes on the other, and the files the client downloads
//! are byte for byte what `tessera-worker render` writes on the host with the same binary. The
//! image's health check turns healthy, the server runs as the image's non-root user on the `/data`
//! volume.
//!
//! Needs podman and mmdebstrap (`apt-get install podman mmdebstrap runc`) and a podman that can
//! run a container here; without them it skips with the reason, unless
//! `TESSERA_REQUIRE_CONTAINER=1` (CI), which makes that a failure. The image, containers, network
//! and volume it makes are removed however it ends; the base image and its mmdebstrap tarball
//! stay cached (see the script).

mod support;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;
use support::*;

const API: &str = "container-api-token";
const WORKER: &str = "container-worker-token";
/// The job takes about half a minute on two one-thread workers (in 32-pixel tiles: 135 of
/// them), so a worker container can be stopped well inside it.
const SAMPLES: &str = "512";
const TILE_SIZE: &str = "32";
/// The whole test, image build (with a release build when none is up to date) included: a hang
/// stops the test binary, naming it, instead of holding CI up.
const HANG_LIMIT: Duration = Duration::from_secs(1800);

fn required() -> bool {
    std::env::var_os("TESSERA_REQUIRE_CONTAINER").is_some_and(|v| v != "0" && !v.is_empty())
}

fn skip(reason: &str) {
    assert!(!required(), "TESSERA_REQUIRE_CONTAINER is set but {reason}");
    eprintln!("skipped: {reason}");
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).trim().to_string()
}

/// `podman` with the settings `deploy/build-image.sh --check` found this host needs.
struct Podman {
    conf: Option<String>,
}

impl Podman {
    fn cmd(&self) -> Command {
        let mut cmd = Command::new("podman");
        if let Some(conf) = &self.conf {
            cmd.env("CONTAINERS_CONF", conf);
        }
        cmd.stdin(Stdio::null());
        cmd
    }

    fn run(&self, args: &[&str]) -> Output {
        self.cmd().args(args).output().expect("run podman")
    }

    /// Runs podman, which must succeed; its standard output, trimmed.
    fn ok(&self, args: &[&str]) -> String {
        let out = self.run(args);
        assert!(out.status.success(), "podman {}: {}", args.join(" "), text(&out.stderr));
        text(&out.stdout)
    }

    fn logs(&self, container: &str) -> String {
        let out = self.run(&["logs", container]);
        format!("--- {container} ---\n{}{}", text(&out.stdout), text(&out.stderr))
    }
}

/// Everything the test makes in podman, removed when dropped (on failure too).
struct Made {
    podman: Podman,
    image: String,
    network: String,
    volume: String,
    containers: Vec<String>,
}

impl Made {
    fn logs(&self) -> String {
        self.containers.iter().map(|c| self.podman.logs(c)).collect::<Vec<_>>().join("\n")
    }
}

impl Drop for Made {
    fn drop(&mut self) {
        for c in &self.containers {
            let _ = self.podman.run(&["rm", "--force", "--volumes", "--time", "0", c]);
        }
        let _ = self.podman.run(&["network", "rm", "--force", &self.network]);
        let _ = self.podman.run(&["volume", "rm", "--force", &self.volume]);
        let _ = self.podman.run(&["rmi", "--force", &self.image]);
    }
}

/// The client, killed when dropped.
struct Client(Child);

impl Drop for Client {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Where the script's `cargo build --release` puts the binaries.
fn release_dir() -> PathBuf {
    match std::env::var_os("CARGO_TARGET_DIR") {
        Some(dir) if !dir.is_empty() => repo().join(dir).join("release"),
        _ => repo().join("target/release"),
    }
}

/// `deploy/build-image.sh` as a user runs it: without the variables cargo sets for a test
/// ([`without_test_env`]), which would make its `cargo build --release` rebuild every run.
fn build_image_sh() -> Command {
    let mut cmd = Command::new(repo().join("deploy/build-image.sh"));
    without_test_env(&mut cmd);
    cmd.stdin(Stdio::null());
    cmd
}

fn get(url: &str, path: &str) -> Value {
    let req = ureq::get(&format!("{url}{path}")).set("Authorization", &format!("Bearer {API}"));
    let (code, v) = call(req, None);
    assert_eq!(code, 200, "GET {path}: {v}");
    v
}

fn tiles_of(workers: &Value, name: &str) -> Option<u64> {
    workers["workers"].as_array()?.iter().find(|w| w["name"] == name)?["tiles_done"].as_u64()
}

#[test]
fn the_image_runs_a_farm_that_renders_like_the_cli_with_a_worker_container_stopped_mid_job() {
    let _s = tessera_testkit::serial(HANG_LIMIT);
    let began = Instant::now();
    if Command::new("podman").arg("--version").output().is_err() {
        return skip("podman is not installed (apt-get install podman mmdebstrap runc)");
    }
    // The base (made once, then cached) and a probe container: can podman run one here, and with
    // which settings?
    let t = Instant::now();
    let check = build_image_sh().arg("--check").output().expect("run build-image.sh");
    if !check.status.success() {
        return skip(&format!("podman cannot run a container here: {}", text(&check.stderr)));
    }
    let base_secs = t.elapsed().as_secs_f64();
    let conf = text(&check.stdout).strip_prefix("export CONTAINERS_CONF=").map(str::to_string);
    let podman = Podman { conf };

    let tag = format!("tessera-test-{}", std::process::id());
    let image = format!("localhost/{tag}:latest");
    let mut made = Made {
        podman,
        image: image.clone(),
        network: format!("{tag}-net"),
        volume: format!("{tag}-data"),
        containers: Vec::new(),
    };
    let podman = Podman { conf: made.podman.conf.clone() };

    // The image, as a user builds it: release binaries built here, copied onto the base.
    let t = Instant::now();
    let mut build = build_image_sh();
    build.args(["--tag", &image]);
    if let Some(conf) = &podman.conf {
        build.env("CONTAINERS_CONF", conf);
    }
    let out = build.output().expect("run build-image.sh");
    assert!(out.status.success(), "deploy/build-image.sh failed:\n{}", text(&out.stderr));
    let build_secs = t.elapsed().as_secs_f64();
    let size: u64 = podman.ok(&["image", "inspect", "--format", "{{.Size}}", &image]).parse().unwrap();
    assert_eq!(podman.ok(&["image", "inspect", "--format", "{{.Config.User}}", &image]), "10001:10001");
    let health = podman.ok(&["image", "inspect", "--format", "{{json .Config.Healthcheck}}", &image]);
    assert!(health.contains("http://127.0.0.1:8080/healthz"), "the image has no health check: {health}");
    let volumes = podman.ok(&["image", "inspect", "--format", "{{json .Config.Volumes}}", &image]);
    assert!(volumes.contains("\"/data\""), "the image declares no /data volume: {volumes}");

    podman.ok(&["network", "create", &made.network]);
    podman.ok(&["volume", "create", &made.volume]);

    // The server: the image's default command, tokens from the environment, its port on
    // 127.0.0.1 only, its state on the volume.
    let server = format!("{tag}-server");
    made.containers.push(server.clone());
    let t = Instant::now();
    podman.ok(&[
        "run",
        "--detach",
        "--name",
        &server,
        "--network",
        &made.network,
        "--publish",
        "127.0.0.1::8080",
        "--volume",
        &format!("{}:/data", made.volume),
        "--env",
        &format!("TESSERA_API_TOKEN={API}"),
        "--env",
        &format!("TESSERA_WORKER_TOKEN={WORKER}"),
        &image,
    ]);
    // Podman runs health checks from systemd timers; without systemd (CI's containers) nothing
    // runs them, so run the image's check by hand until it passes.
    let deadline = Instant::now() + Duration::from_secs(60);
    while !podman.run(&["healthcheck", "run", &server]).status.success() {
        assert!(Instant::now() < deadline, "the server never became healthy:\n{}", made.logs());
        std::thread::sleep(Duration::from_millis(100));
    }
    let healthy_secs = t.elapsed().as_secs_f64();
    assert_eq!(podman.ok(&["inspect", "--format", "{{.State.Health.Status}}", &server]), "healthy");
    // The farm runs as the image's user, not root, and keeps its database on the volume.
    assert_eq!(podman.ok(&["exec", &server, "id", "-u"]), "10001");
    let data = podman.ok(&["exec", &server, "ls", "/data"]);
    assert!(!data.is_empty(), "the server keeps nothing in /data");
    let port = podman.ok(&["port", &server, "8080/tcp"]);
    let host_port =
        port.strip_prefix("127.0.0.1:").unwrap_or_else(|| panic!("published beyond loopback: {port}"));
    let url = format!("http://127.0.0.1:{host_port}");
    // The job API wants the token.
    let (code, _) = call(ureq::get(&format!("{url}/api/v1/jobs")), None);
    assert_eq!(code, 401);

    // Two workers, one thread each, reaching the server by its container name.
    for name in ["worker-a", "worker-b"] {
        let container = format!("{tag}-{name}");
        made.containers.push(container.clone());
        podman.ok(&[
            "run",
            "--detach",
            "--name",
            &container,
            "--network",
            &made.network,
            "--env",
            &format!("TESSERA_WORKER_TOKEN={WORKER}"),
            &image,
            "tessera-worker",
            "work",
            "--server",
            &format!("http://{server}:8080"),
            "--name",
            name,
            "--threads",
            "1",
        ]);
    }
    let deadline = Instant::now() + Duration::from_secs(60);
    while get(&url, "/api/v1/workers")["workers"].as_array().map_or(0, Vec::len) < 2 {
        assert!(Instant::now() < deadline, "the workers never registered:\n{}", made.logs());
        std::thread::sleep(Duration::from_millis(100));
    }

    // The real client on the host submits the scene (with its texture), waits and downloads.
    let scene = repo().join("scenes/environment.xml");
    let farm_out = TempDir::new("container-farm-out");
    let client_log = farm_out.with_extension("log");
    let t = Instant::now();
    let mut client = Client(
        Command::new(release_dir().join("tessera"))
            .arg("submit")
            .arg(&scene)
            .args(["--server", &url, "--token", API, "--samples", SAMPLES, "--tile-size", TILE_SIZE])
            .arg("--out")
            .arg(farm_out.path())
            .env_remove("TESSERA_SERVER")
            .env_remove("TESSERA_TOKEN")
            .env_remove("TESSERA_CONFIG")
            .stdin(Stdio::null())
            .stdout(std::fs::File::create(&client_log).unwrap())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start the client"),
    );

    // Both workers render; then worker a's container is stopped while the job runs.
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        let workers = get(&url, "/api/v1/workers");
        if tiles_of(&workers, "worker-a").unwrap_or(0) >= 1
            && tiles_of(&workers, "worker-b").unwrap_or(0) >= 1
        {
            break;
        }
        assert!(client.0.try_wait().unwrap().is_none(), "the client ended early:\n{}", made.logs());
        assert!(Instant::now() < deadline, "both workers never rendered: {workers}\n{}", made.logs());
        std::thread::sleep(Duration::from_millis(100));
    }
    let jobs = get(&url, "/api/v1/jobs");
    let id = jobs["jobs"][0]["id"].as_u64().unwrap_or_else(|| panic!("no job: {jobs}"));
    let job = get(&url, &format!("/api/v1/jobs/{id}"));
    let total = job["frames"][0]["tiles_total"].as_u64().unwrap();
    assert!(tiles_done(&job) + 20 < total, "the job is nearly done before the stop: {job}");
    let worker_a = format!("{tag}-worker-a");
    // SIGTERM; the worker finishes and uploads its tile and gives the next one back.
    podman.ok(&["stop", "--time", "60", &worker_a]);
    let job = get(&url, &format!("/api/v1/jobs/{id}"));
    assert_ne!(job["state"], "done", "the job ended before worker a's container stopped: {job}");
    assert_eq!(
        podman.ok(&["inspect", "--format", "{{.State.ExitCode}}", &worker_a]),
        "0",
        "the worker did not stop cleanly on the container's stop signal:\n{}",
        podman.logs(&worker_a)
    );
    let a_at_stop = tiles_of(&get(&url, "/api/v1/workers"), "worker-a").unwrap();

    let status = wait_timeout(&mut client.0, Duration::from_secs(600));
    let job_secs = t.elapsed().as_secs_f64();
    let client_said = std::fs::read_to_string(&client_log).unwrap_or_default();
    assert!(
        status.is_some_and(|s| s.success()),
        "the client did not finish the job: {status:?}\n{client_said}\n{}",
        made.logs()
    );
    let job = get(&url, &format!("/api/v1/jobs/{id}"));
    assert_eq!(job["state"], "done", "{job}");
    let workers = get(&url, "/api/v1/workers");
    let b_tiles = tiles_of(&workers, "worker-b").unwrap();
    assert_eq!(
        tiles_of(&workers, "worker-a"),
        Some(a_at_stop),
        "worker a rendered after its stop: {workers}"
    );
    // Workers count units: a tile's passes each count once.
    let units = total * job["frames"][0]["passes_total"].as_u64().unwrap();
    assert_eq!(a_at_stop + b_tiles, units, "{workers}");
    // No worker went silent: worker a gave its leases back when it stopped, so none expired.
    // (A worker whose heartbeats stalled for a whole lease, as on lookups of the server's name
    // through a gateway whose MAC address changed, shows here first.)
    let server_log = podman.logs(&server);
    assert!(!server_log.contains("lease(s) expired"), "a lease expired during the job:\n{}", made.logs());

    // The CLI on the host, the same release binary as in the image: the same files, byte for byte.
    let cli_out = TempDir::new("container-cli-out");
    let status = Command::new(release_dir().join("tessera-worker"))
        .arg("render")
        .arg(&scene)
        .args(["--samples", SAMPLES, "--quiet", "--out"])
        .arg(cli_out.path())
        .stdin(Stdio::null())
        .status()
        .expect("run tessera-worker render");
    assert!(status.success(), "tessera-worker render failed");
    let names = |dir: &Path| {
        let mut v: Vec<String> =
            std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
        v.sort();
        v
    };
    let cli_files = names(cli_out.path());
    assert_eq!(names(farm_out.path()), cli_files, "the client downloaded other files than the CLI wrote");
    assert!(cli_files.iter().any(|n| n.ends_with(".exr")), "{cli_files:?}");
    for name in &cli_files {
        let farm = std::fs::read(farm_out.join(name)).unwrap();
        let cli = std::fs::read(cli_out.join(name)).unwrap();
        assert!(farm == cli, "the containerised farm's {name} differs from the CLI's");
    }

    eprintln!(
        "container farm: base check {base_secs:.1} s, image build {build_secs:.1} s, image {size} bytes \
         ({:.1} MB), server healthy {healthy_secs:.2} s after podman run, job {job_secs:.1} s \
         ({total} tiles: worker a {a_at_stop} before its stop, worker b {b_tiles}), test {:.1} s",
        size as f64 / 1e6,
        began.elapsed().as_secs_f64()
    );
    let containers = made.containers.clone();
    // The named volume and the workers' anonymous /data volumes.
    let mut volumes = Vec::new();
    for c in &containers {
        let names = podman.ok(&["inspect", "--format", "{{range .Mounts}}{{.Name}} {{end}}", c]);
        volumes.extend(names.split_whitespace().map(str::to_string));
    }
    assert!(volumes.contains(&made.volume), "{volumes:?}");
    drop(made);
    for c in containers {
        let out = podman.run(&["container", "exists", &c]);
        assert!(!out.status.success(), "container {c} left behind");
    }
    for v in volumes {
        assert!(!podman.run(&["volume", "exists", &v]).status.success(), "volume {v} left behind");
    }
    assert!(!podman.run(&["image", "exists", &image]).status.success(), "image {image} left behind");
}
