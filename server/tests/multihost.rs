//! The farm across machines, simulated with Linux network namespaces: a server host
//! (10.77.0.1) and two worker hosts (10.77.0.2, 10.77.0.3), each a namespace with a veth link to
//! a bridge in a fourth (hub) namespace. The server binds its host's address with tokens, the
//! workers reach it over the bridge, the test talks to it with `curl` run inside the server's
//! namespace. Mid-job one worker host's link goes down: the job still completes through the
//! other worker, byte for byte what `tessera-worker render` writes.
//!
//! Needs root and `ip` (iproute2) and `curl`; without them it skips with the reason, unless
//! `TESSERA_REQUIRE_NETNS=1` (CI), which makes that a failure.

mod support;

use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;
use support::*;

const API: &str = "atok";
const WORKER: &str = "wtok";
/// Samples and tile size make a tile take tens of milliseconds, far longer than a lease round
/// trip over the bridge, so a worker always holds the lease of the tile it renders (its fetcher
/// has the next one before the current one is done). With millisecond tiles the renderer waits on
/// the network, and a cut that falls while its lease request is on the wire leaves the server
/// holding nothing of that host's: no lease expires, and the test would be about nothing.
const SAMPLES: &str = "64";
const TILE_SIZE: &str = "32";

fn required() -> bool {
    std::env::var_os("TESSERA_REQUIRE_NETNS").is_some_and(|v| v != "0" && !v.is_empty())
}

fn skip(reason: &str) {
    assert!(!required(), "TESSERA_REQUIRE_NETNS is set but {reason}");
    eprintln!("skipped: {reason}");
}

fn ip(args: &[&str]) -> Output {
    Command::new("ip").args(args).stdin(Stdio::null()).output().expect("run ip")
}

fn ip_ok(args: &[&str]) {
    let out = ip(args);
    assert!(out.status.success(), "ip {}: {}", args.join(" "), String::from_utf8_lossy(&out.stderr));
}

/// Namespaces that are deleted when this is dropped (on failure too), with any veth end still
/// in this namespace (`{tag}{s,a,b}{0,1}`).
struct Namespaces(Vec<String>, String);

impl Drop for Namespaces {
    fn drop(&mut self) {
        for ns in &self.0 {
            let _ = ip(&["netns", "del", ns]);
        }
        for h in ["s0", "a0", "b0", "s1", "a1", "b1"] {
            let name = format!("{}{h}", self.1);
            if Path::new(&format!("/sys/class/net/{name}")).exists() {
                let _ = ip(&["link", "del", &name]);
            }
        }
    }
}

/// A process that is killed when dropped.
struct Proc(Child);

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

struct Farm {
    server_ns: String,
    url: String,
    log: std::path::PathBuf,
}

impl Farm {
    /// `curl` inside the server's namespace; (HTTP status, body).
    fn curl(&self, args: &[&str]) -> (u16, Vec<u8>) {
        let out = Command::new("ip")
            .args([
                "netns",
                "exec",
                &self.server_ns,
                "curl",
                "-sS",
                "-H",
                &format!("Authorization: Bearer {API}"),
            ])
            .args(["-w", "\n%{http_code}"])
            .args(args)
            .output()
            .expect("run curl");
        assert!(out.status.success(), "curl {args:?}: {}", String::from_utf8_lossy(&out.stderr));
        let body = out.stdout;
        let nl = body.iter().rposition(|&b| b == b'\n').unwrap();
        let code = std::str::from_utf8(&body[nl + 1..]).unwrap().trim().parse().unwrap();
        (code, body[..nl].to_vec())
    }

    fn get_json(&self, path: &str) -> Value {
        let (code, body) = self.curl(&[&format!("{}{path}", self.url)]);
        assert_eq!(code, 200, "GET {path}: {}", String::from_utf8_lossy(&body));
        serde_json::from_slice(&body).unwrap()
    }

    fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }
}

#[test]
fn a_farm_across_three_hosts_survives_a_worker_host_losing_its_link() {
    let _s = serial();
    if Command::new("ip").arg("-V").output().is_err() {
        return skip("`ip` (iproute2) is not installed");
    }
    if Command::new("curl").arg("--version").output().is_err() {
        return skip("`curl` is not installed");
    }
    let tag = format!("tsr{}", std::process::id());
    let [hub, srv, wa, wb] = ["h", "s", "a", "b"].map(|h| format!("{tag}{h}"));
    let out = ip(&["netns", "add", &hub]);
    if !out.status.success() {
        return skip(&format!(
            "cannot create network namespaces (root needed): {}",
            String::from_utf8_lossy(&out.stderr).trim()
        ));
    }
    let mut namespaces = Namespaces(vec![hub.clone()], tag.clone());
    for ns in [&srv, &wa, &wb] {
        ip_ok(&["netns", "add", ns]);
        namespaces.0.push(ns.clone());
    }
    ip_ok(&["-n", &hub, "link", "add", "br0", "type", "bridge"]);
    ip_ok(&["-n", &hub, "link", "set", "br0", "up"]);
    for (ns, host, addr) in
        [(&srv, "s", "10.77.0.1/24"), (&wa, "a", "10.77.0.2/24"), (&wb, "b", "10.77.0.3/24")]
    {
        // Created in this namespace under unique names, then moved to their hosts and the hub.
        let (near, far) = (format!("{tag}{host}0"), format!("{tag}{host}1"));
        ip_ok(&["link", "add", &near, "type", "veth", "peer", "name", &far]);
        ip_ok(&["link", "set", &near, "netns", ns]);
        ip_ok(&["link", "set", &far, "netns", &hub]);
        ip_ok(&["-n", ns, "link", "set", &near, "name", "eth0"]);
        ip_ok(&["-n", ns, "addr", "add", addr, "dev", "eth0"]);
        ip_ok(&["-n", ns, "link", "set", "eth0", "up"]);
        ip_ok(&["-n", ns, "link", "set", "lo", "up"]);
        ip_ok(&["-n", &hub, "link", "set", &far, "master", "br0"]);
        ip_ok(&["-n", &hub, "link", "set", &far, "up"]);
    }

    // The server on its host's address: tokens required off loopback; no local workers.
    let data = TempDir::new("farm-multihost");
    let log = data.with_extension(format!("log{}", std::process::id()));
    let mut server = Proc(
        Command::new("ip")
            .args(["netns", "exec", &srv])
            .arg(server_bin())
            .args(["--bind", "10.77.0.1:0", "--data-dir"])
            .arg(data.path())
            .args(["--local-workers", "0", "--api-token", API, "--worker-token", WORKER])
            .args(["--lease-seconds", "2", "--heartbeat-seconds", "0.5"])
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .expect("start tessera-server in its namespace"),
    );
    let line = first_line(server.0.stdout.take().unwrap(), Duration::from_secs(30)).unwrap_or_default();
    let url = line.trim().strip_prefix("listening on ").unwrap_or_else(|| {
        panic!("the server did not start: {line:?}\n{}", std::fs::read_to_string(&log).unwrap_or_default())
    });
    assert!(url.starts_with("http://10.77.0.1:"), "{url}");
    let farm = Farm { server_ns: srv.clone(), url: url.to_string(), log: log.clone() };
    let (code, body) = farm.curl(&[&format!("{url}/healthz")]);
    assert_eq!((code, body.as_slice()), (200, &b"ok\n"[..]));
    // Without the API token the job API refuses (the token is what guards a non-loopback farm).
    let out = Command::new("ip")
        .args(["netns", "exec", &srv, "curl", "-s", "-o", "/dev/null", "-w", "%{http_code}"])
        .arg(format!("{url}/api/v1/jobs"))
        .output()
        .unwrap();
    assert_eq!(String::from_utf8_lossy(&out.stdout), "401");

    // Two workers on the other hosts.
    let start_worker = |ns: &str, name: &str| {
        Proc(
            Command::new("ip")
                .args(["netns", "exec", ns])
                .arg(worker_bin())
                .args(["work", "--server", url, "--token", WORKER, "--name", name, "--threads", "1"])
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .expect("start a worker in its namespace"),
        )
    };
    let _a = start_worker(&wa, "host-a");
    let _b = start_worker(&wb, "host-b");

    // Submit over the server host's network.
    let scenes = repo().join("scenes");
    let (code, body) = farm.curl(&[
        "-F",
        &format!("scene=@{};filename=environment.xml", scenes.join("environment.xml").display()),
        "-F",
        &format!("asset=@{};filename=textures/sky.hdr", scenes.join("textures/sky.hdr").display()),
        "-F",
        &format!("samples={SAMPLES}"),
        "-F",
        &format!("tile_size={TILE_SIZE}"),
        &format!("{url}/api/v1/jobs"),
    ]);
    assert_eq!(code, 201, "{}\n{}", String::from_utf8_lossy(&body), farm.log());
    let id = serde_json::from_slice::<Value>(&body).unwrap()["id"].as_u64().unwrap();

    // Both hosts render; then host a loses its link mid-job.
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        let workers = farm.get_json("/api/v1/workers");
        let done: Vec<u64> = workers["workers"]
            .as_array()
            .unwrap()
            .iter()
            .map(|w| w["tiles_done"].as_u64().unwrap())
            .collect();
        if done.len() == 2 && done.iter().all(|&d| d >= 1) {
            break;
        }
        assert!(Instant::now() < deadline, "both workers never rendered: {workers}\n{}", farm.log());
        std::thread::sleep(Duration::from_millis(50));
    }
    let job = farm.get_json(&format!("/api/v1/jobs/{id}"));
    let total = job["frames"][0]["tiles_total"].as_u64().unwrap();
    assert!(
        job["frames"][0]["tiles_done"].as_u64().unwrap() + 10 < total,
        "the job is nearly done before the link goes down: {job}"
    );
    ip_ok(&["-n", &wa, "link", "set", "eth0", "down"]);
    // Let a request that was already in the server's hands before the cut finish.
    std::thread::sleep(Duration::from_millis(500));
    let cut = farm.get_json("/api/v1/workers");
    let a_at_cut = tiles_of(&cut, "host-a");

    let deadline = Instant::now() + Duration::from_secs(300);
    loop {
        let job = farm.get_json(&format!("/api/v1/jobs/{id}"));
        if job["state"] == "done" {
            break;
        }
        assert!(job["state"] == "running" || job["state"] == "queued", "{job}\n{}", farm.log());
        assert!(Instant::now() < deadline, "the job did not finish on host b: {job}\n{}", farm.log());
        std::thread::sleep(Duration::from_millis(200));
    }
    let workers = farm.get_json("/api/v1/workers");
    assert_eq!(tiles_of(&workers, "host-a"), a_at_cut, "host a rendered with its link down? {workers}");
    let (_, metrics) = farm.curl(&[&format!("{url}/metrics")]);
    let metrics = String::from_utf8(metrics).unwrap();
    let expiries: u64 = metrics
        .lines()
        .find_map(|l| l.strip_prefix("tessera_lease_expiries_total "))
        .unwrap()
        .parse()
        .unwrap();
    assert!(
        expiries >= 1,
        "host a's leases should have expired (host a at the cut: {:?}): {metrics}",
        cut["workers"].as_array().unwrap().iter().find(|w| w["name"] == "host-a")
    );

    // The outputs, fetched over the farm's network, equal the CLI's.
    let (exr, png) = cli_render_environment(SAMPLES);
    for (name, cli) in [("environment.exr", exr), ("environment.png", png)] {
        let (code, bytes) = farm.curl(&[&format!("{url}/api/v1/jobs/{id}/frames/0/files/{name}")]);
        assert_eq!(code, 200, "{name}");
        assert!(bytes == cli, "the farm's {name} differs from the CLI's");
    }
    drop(server);
    drop(data);
    drop(namespaces);
    assert!(!Path::new(&format!("/var/run/netns/{srv}")).exists(), "namespace {srv} left behind");
}

fn tiles_of(workers: &Value, name: &str) -> u64 {
    workers["workers"]
        .as_array()
        .unwrap()
        .iter()
        .find(|w| w["name"] == name)
        .unwrap_or_else(|| panic!("no worker {name}: {workers}"))["tiles_done"]
        .as_u64()
        .unwrap()
}
