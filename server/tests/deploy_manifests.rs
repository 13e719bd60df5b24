//! The deployment files in `deploy/` agree with the binaries: every `--flag` they name exists in
//! `tessera-server --help`, `tessera-worker work --help` or (pgo-build.sh's training renders)
//! `tessera-worker render --help`, every `TESSERA_*` variable is one the
//! programs read, every port is the one the server binds, every health-check path is answered by
//! the real server, and every command line in them actually starts a server (or a worker that
//! registers with it).
//!
//! With `kubernetes-validate` on PATH (`pip install kubernetes-validate`) the Kubernetes
//! manifests are also validated against the Kubernetes schemas; `TESSERA_REQUIRE_K8S_VALIDATE=1`
//! makes its absence a failure (CI).

mod support;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use support::*;

/// The one port of the farm in every deployment file.
const PORT: u16 = 8080;

/// Flags in deploy/ that belong to other programs (cargo, useradd, curl, Containerfile
/// instructions, compose and kubectl in comments).
const FOREIGN_FLAGS: &[&str] = &[
    "--release",
    "--locked",
    "--no-install-recommends",
    "--system",
    "--gid",
    "--uid",
    "--home-dir",
    "--shell",
    "--from",
    "--interval",
    "--timeout",
    "--start-period",
    "--from-literal",
    "--scale",
    "--build",
    "--env-file",
    "--now",
    "--target-dir",
    "--config",
    "--print",
    "--bin",
    // podman build and podman's own options in build-image.sh and the Containerfiles' comments.
    "--format",
    "--build-arg",
    "--pull",
    "--network",
    "--rm",
    "--change",
    // mmdebstrap's, in build-image.sh.
    "--variant",
    "--include",
    "--hook-dir",
    "--dpkgopt",
    // build-image.sh's own.
    "--tag",
    "--suite",
    "--no-cargo",
    "--refresh-base",
    "--check",
];

fn deploy_dir() -> PathBuf {
    repo().join("deploy")
}

/// Every file under deploy/, as (path relative to deploy/, text).
fn deploy_files() -> Vec<(String, String)> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() { walk(&p, out) } else { out.push(p) }
        }
    }
    let mut paths = Vec::new();
    walk(&deploy_dir(), &mut paths);
    paths.sort();
    paths
        .into_iter()
        .filter(|p| p.file_name().is_some_and(|n| n != "tessera.env")) // a local copy with secrets
        .map(|p| {
            let rel = p.strip_prefix(deploy_dir()).unwrap().to_string_lossy().into_owned();
            (rel, std::fs::read_to_string(&p).unwrap())
        })
        .collect()
}

fn help(bin: &Path, args: &[&str]) -> String {
    let out = Command::new(bin).args(args).output().unwrap();
    assert!(out.status.success(), "{} {args:?} failed", bin.display());
    String::from_utf8(out.stdout).unwrap()
}

/// `--long-flag` tokens of a text.
fn flags_in(text: &str) -> BTreeSet<String> {
    let b = text.as_bytes();
    let mut out = BTreeSet::new();
    let mut i = 0;
    while i + 2 < b.len() {
        let starts = b[i] == b'-'
            && b[i + 1] == b'-'
            && b[i + 2].is_ascii_lowercase()
            && (i == 0 || !(b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'-'));
        if starts {
            let mut j = i + 2;
            while j < b.len() && (b[j].is_ascii_lowercase() || b[j].is_ascii_digit() || b[j] == b'-') {
                j += 1;
            }
            out.insert(text[i..j].to_string());
            i = j;
        } else {
            i += 1;
        }
    }
    out
}

/// `TESSERA_*` names in a text.
fn env_vars_in(text: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    for (i, _) in text.match_indices("TESSERA_") {
        let rest = &text[i..];
        let end = rest
            .find(|c: char| !(c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_'))
            .unwrap_or(rest.len());
        out.insert(rest[..end].to_string());
    }
    out
}

/// Every `"TESSERA_..."` string literal in the programs' sources (variables read with
/// `std::env`, like TESSERA_LOG).
fn env_vars_in_sources() -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    for dir in ["server/src", "worker/src"] {
        for e in std::fs::read_dir(repo().join(dir)).unwrap() {
            let text = std::fs::read_to_string(e.unwrap().path()).unwrap_or_default();
            for (i, _) in text.match_indices("\"TESSERA_") {
                out.extend(env_vars_in(&text[i + 1..]).into_iter().take(1));
            }
        }
    }
    out
}

/// The command lines in deploy/: Containerfile `CMD [...]`, YAML `command: [...]` (+ the
/// following `args: [...]`), systemd `ExecStart=`. (file, argv)
fn command_lines() -> Vec<(String, Vec<String>)> {
    let mut out = Vec::new();
    for (file, text) in deploy_files() {
        let mut pending: Option<Vec<String>> = None;
        for line in text.lines() {
            let t = line.trim_start().trim_start_matches("- ");
            let list = |rest: &str| -> Vec<String> {
                serde_json::from_str(rest.trim())
                    .unwrap_or_else(|e| panic!("{file}: {line:?} is not a flow list: {e}"))
            };
            if let Some(rest) = t.strip_prefix("CMD ").filter(|r| r.trim_start().starts_with('[')) {
                out.push((file.clone(), list(rest)));
            } else if let Some(rest) = t.strip_prefix("command:") {
                if let Some(p) = pending.take() {
                    out.push((file.clone(), p));
                }
                pending = Some(list(rest));
            } else if let Some(rest) = t.strip_prefix("args:") {
                let mut argv = pending.take().unwrap_or_else(|| panic!("{file}: args: without command:"));
                argv.extend(list(rest));
                out.push((file.clone(), argv));
            } else if let Some(rest) = t.strip_prefix("ExecStart=") {
                out.push((file.clone(), rest.split_whitespace().map(str::to_string).collect()));
            }
        }
        if let Some(p) = pending {
            out.push((file.clone(), p));
        }
    }
    out
}

fn program(argv: &[String]) -> &str {
    argv[0].rsplit('/').next().unwrap()
}

#[test]
fn every_flag_and_variable_in_deploy_exists_in_the_binaries() {
    let server_help = help(&server_bin(), &["--help"]);
    let worker_help = help(&worker_bin(), &["work", "--help"]);
    let server_flags = flags_in(&server_help);
    let worker_flags = flags_in(&worker_help);
    // pgo-build.sh renders scenes with `tessera-worker render`.
    let render_flags = flags_in(&help(&worker_bin(), &["render", "--help"]));
    assert!(server_flags.contains("--bind") && worker_flags.contains("--server"), "help output changed");
    assert!(render_flags.contains("--samples"), "help output changed");
    let mut known_vars = env_vars_in(&server_help);
    known_vars.extend(env_vars_in(&worker_help));
    known_vars.extend(env_vars_in_sources());
    assert!(known_vars.contains("TESSERA_LOG"), "{known_vars:?}");

    let files = deploy_files();
    assert!(files.len() >= 10, "deploy/ is incomplete: {:?}", files.iter().map(|f| &f.0).collect::<Vec<_>>());
    let mut problems = Vec::new();
    for (file, text) in &files {
        for flag in flags_in(text) {
            let ok = server_flags.contains(&flag)
                || worker_flags.contains(&flag)
                || render_flags.contains(&flag)
                || FOREIGN_FLAGS.contains(&flag.as_str());
            if !ok {
                problems.push(format!(
                    "{file}: {flag} is not a flag of tessera-server, tessera-worker work or tessera-worker render"
                ));
            }
        }
        for var in env_vars_in(text) {
            if !known_vars.contains(&var) {
                problems.push(format!("{file}: {var} is not read by tessera-server or tessera-worker"));
            }
        }
    }
    // Each command line's flags belong to its own program.
    let commands = command_lines();
    for (file, argv) in &commands {
        let (flags, what) = match program(argv) {
            "tessera-server" => (&server_flags, "tessera-server"),
            "tessera-worker" => {
                assert_eq!(argv.get(1).map(String::as_str), Some("work"), "{file}: {argv:?}");
                (&worker_flags, "tessera-worker work")
            }
            other => {
                problems
                    .push(format!("{file}: command {other} is neither tessera-server nor tessera-worker"));
                continue;
            }
        };
        for a in argv.iter().filter(|a| a.starts_with("--")) {
            let name = a.split('=').next().unwrap();
            if !flags.contains(name) {
                problems.push(format!("{file}: {name} is not a flag of {what}"));
            }
        }
    }
    for (file, program_name) in [
        ("Containerfile", "tessera-server"),
        ("Containerfile.prebuilt", "tessera-server"),
        ("compose.yaml", "tessera-server"),
        ("compose.yaml", "tessera-worker"),
        ("kubernetes/server.yaml", "tessera-server"),
        ("kubernetes/worker.yaml", "tessera-worker"),
        ("systemd/tessera-server.service", "tessera-server"),
        ("systemd/tessera-worker@.service", "tessera-worker"),
    ] {
        assert!(
            commands.iter().any(|(f, a)| f == file && program(a) == program_name),
            "{file} starts no {program_name}: {commands:?}"
        );
    }
    // The env files name both tokens, and the workers' server address.
    for file in ["tessera.env.example", "systemd/tessera.env.example"] {
        let text = &files.iter().find(|f| f.0 == file).unwrap_or_else(|| panic!("no deploy/{file}")).1;
        for var in ["TESSERA_API_TOKEN", "TESSERA_WORKER_TOKEN"] {
            assert!(text.lines().any(|l| l.starts_with(&format!("{var}="))), "{file} does not set {var}");
        }
    }
    assert!(problems.is_empty(), "deploy/ disagrees with the binaries:\n{}", problems.join("\n"));
}

/// Ports after a `host:` (`0.0.0.0:8080`, `http://server:8080/...`, `"127.0.0.1:8080:8080"`) and
/// in `EXPOSE`, `port:`, `containerPort:`, `targetPort:`.
fn ports_in(line: &str) -> Vec<u16> {
    let mut out = Vec::new();
    let t = line.trim_start().trim_start_matches("- ");
    if t.starts_with("USER ") {
        return out; // uid:gid
    }
    if let Some(rest) = t.strip_prefix("EXPOSE ") {
        out.extend(rest.split_whitespace().filter_map(|p| p.parse::<u16>().ok()));
    }
    for key in ["port:", "containerPort:", "targetPort:"] {
        if let Some(rest) = t.strip_prefix(key) {
            out.extend(rest.trim().parse::<u16>().ok());
        }
    }
    let b = line.as_bytes();
    for (i, _) in line.match_indices(':') {
        let digits: String = line[i + 1..].chars().take_while(|c| c.is_ascii_digit()).collect();
        let next = b.get(i + 1 + digits.len()).copied().unwrap_or(b' ');
        if digits.len() >= 2 && !(next.is_ascii_alphanumeric() || next == b'-' || next == b'.') {
            out.extend(digits.parse::<u16>().ok());
        }
    }
    out
}

#[test]
fn ports_and_health_paths_match_the_server() {
    let mut health_paths = BTreeSet::new();
    let mut problems = Vec::new();
    let mut seen_ports = 0;
    for (file, text) in deploy_files() {
        for line in text.lines() {
            for p in ports_in(line) {
                seen_ports += 1;
                if p != PORT {
                    problems.push(format!("{file}: port {p} in {:?} (the farm uses {PORT})", line.trim()));
                }
            }
            let t = line.trim_start();
            if let Some(p) = t.strip_prefix("path:") {
                health_paths.insert(p.trim().to_string());
            }
            if let Some(i) = line.find(&format!(":{PORT}/")) {
                let path: String =
                    line[i + 5..].chars().take_while(|c| !c.is_whitespace() && *c != '"').collect();
                health_paths.insert(path);
            }
        }
    }
    assert!(seen_ports >= 10, "the port scan found too little: {seen_ports}");
    assert!(problems.is_empty(), "{}", problems.join("\n"));
    assert_eq!(health_paths, BTreeSet::from(["/healthz".to_string()]), "health-check paths");
    // The Containerfile's default command binds the exposed port on every interface.
    let cmd = command_lines().into_iter().find(|(f, _)| f == "Containerfile").unwrap().1;
    let bind = cmd.iter().position(|a| a == "--bind").map(|i| cmd[i + 1].clone());
    assert_eq!(bind.as_deref(), Some(&*format!("0.0.0.0:{PORT}")), "{cmd:?}");
    // The real server answers those paths.
    let data = TempDir::new("farm-deploy-health");
    let server = Server::start(&data, &["--local-workers", "0"]);
    for p in &health_paths {
        assert_eq!(get_bytes(&server.url, p), b"ok\n", "{p}");
    }
}

/// Every command line in deploy/ starts: the servers listen (with the data directory and the
/// address swapped for a temporary one and a free loopback port), the workers register.
#[test]
fn every_command_line_in_deploy_runs() {
    let _s = serial();
    let commands = command_lines();
    assert!(commands.len() >= 7, "{commands:?}");
    let data = TempDir::new("farm-deploy-cmd-worker-target");
    let target = Server::start(&data, &["--local-workers", "0", "--worker-token", "wtok"]);
    for (n, (file, argv)) in commands.iter().enumerate() {
        let mut args: Vec<String> = argv[1..].to_vec();
        let set = |args: &mut Vec<String>, flag: &str, value: &str| {
            if let Some(i) = args.iter().position(|a| a == flag) {
                args[i + 1] = value.to_string();
            }
        };
        let name = args.iter().map(|a| a.replace("%H", "host").replace("%i", "1")).collect::<Vec<_>>();
        args = name;
        match program(argv) {
            "tessera-server" => {
                let dir = TempDir::new(&format!("farm-deploy-cmd-{n}"));
                set(&mut args, "--bind", "127.0.0.1:0");
                set(&mut args, "--data-dir", dir.to_str().unwrap());
                let mut child = Command::new(server_bin())
                    .args(&args)
                    .env("TESSERA_API_TOKEN", "atok")
                    .env("TESSERA_WORKER_TOKEN", "wtok")
                    .env("TESSERA_WORKER_BIN", worker_bin())
                    .stdout(Stdio::piped())
                    .stderr(Stdio::piped())
                    .spawn()
                    .unwrap();
                let line =
                    first_line(child.stdout.take().unwrap(), Duration::from_secs(30)).unwrap_or_default();
                let _ = child.kill();
                // Read what the server said on stderr, without waiting for end of file: local
                // workers it started may hold the pipe open for a moment after it is gone.
                let _ = wait_timeout(&mut child, Duration::from_secs(10));
                let stderr = drain_for(child.stderr.take().unwrap(), Duration::from_secs(2));
                assert!(
                    line.starts_with("listening on http://127.0.0.1:"),
                    "{file}: {argv:?} did not start: {line:?}\n{}",
                    stderr
                );
            }
            "tessera-worker" => {
                let before = get_json(&target.url, "/api/v1/workers")["workers"].as_array().unwrap().len();
                if args.iter().any(|a| a == "--server") {
                    set(&mut args, "--server", &target.url);
                }
                let mut child = Command::new(worker_bin())
                    .args(&args)
                    .env("TESSERA_SERVER", &target.url)
                    .env("TESSERA_WORKER_TOKEN", "wtok")
                    .stdout(Stdio::null())
                    .stderr(Stdio::null())
                    .spawn()
                    .unwrap();
                let deadline = Instant::now() + Duration::from_secs(20);
                let registered = loop {
                    let now = get_json(&target.url, "/api/v1/workers")["workers"].as_array().unwrap().len();
                    if now > before {
                        break true;
                    }
                    if Instant::now() > deadline || child.try_wait().unwrap().is_some() {
                        break false;
                    }
                    std::thread::sleep(Duration::from_millis(50));
                };
                signal(&child, libc::SIGTERM);
                let status = wait_timeout(&mut child, Duration::from_secs(40));
                if status.is_none() {
                    let _ = child.kill();
                    let _ = child.wait();
                }
                assert!(registered, "{file}: {argv:?} did not register with the server");
                assert!(
                    status.is_some_and(|s| s.success()),
                    "{file}: {argv:?} did not stop cleanly within 40 s of SIGTERM: {status:?}"
                );
            }
            other => panic!("{file}: unexpected program {other}"),
        }
    }
}

/// The two Containerfiles make the same image: the one that builds from source on a registry's
/// images and the one deploy/build-image.sh builds from host binaries share their runtime stage
/// (every instruction but the COPYs, whose sources differ) and the default base.
#[test]
fn both_containerfiles_share_the_runtime_stage() {
    let files = deploy_files();
    let text =
        |name: &str| &files.iter().find(|f| f.0 == name).unwrap_or_else(|| panic!("no deploy/{name}")).1;
    let runtime = |name: &str| -> Vec<String> {
        let t = text(name);
        let start =
            t.find("# ---- runtime stage").unwrap_or_else(|| panic!("{name}: no runtime stage marker"));
        t[start..]
            .lines()
            .skip(1)
            .filter(|l| !l.starts_with("COPY ") && !l.trim().is_empty())
            .map(str::to_string)
            .collect()
    };
    let (source, prebuilt) = (runtime("Containerfile"), runtime("Containerfile.prebuilt"));
    assert!(source.len() >= 10, "{source:?}");
    assert_eq!(source, prebuilt, "the runtime stages of Containerfile and Containerfile.prebuilt differ");
    for name in ["Containerfile", "Containerfile.prebuilt"] {
        let t = text(name);
        assert!(
            t.lines().any(|l| l == "ARG BASE=docker.io/library/debian:bookworm-slim"),
            "{name}: default BASE"
        );
        assert!(t.contains("COPY") && t.contains("image-setup.sh"), "{name} does not run image-setup.sh");
        for bin in ["tessera-server", "tessera-worker", "tessera "] {
            assert!(
                t.lines().any(|l| l.starts_with("COPY ") && l.contains(bin)),
                "{name} does not copy {bin}"
            );
        }
    }
}

#[test]
fn kubernetes_manifests_are_valid() {
    let required =
        std::env::var_os("TESSERA_REQUIRE_K8S_VALIDATE").is_some_and(|v| v != "0" && !v.is_empty());
    // The script pip installs, or the module where the script's directory is not on PATH.
    let candidates: [&[&str]; 2] = [&["kubernetes-validate"], &["python3", "-m", "kubernetes_validate"]];
    let Some(validator) = candidates.into_iter().find(|c| {
        Command::new(c[0])
            .args(&c[1..])
            .arg("--version")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    }) else {
        assert!(!required, "TESSERA_REQUIRE_K8S_VALIDATE is set but kubernetes-validate is not installed");
        eprintln!("skipped: kubernetes-validate is not installed (pip install kubernetes-validate)");
        return;
    };
    let dir = deploy_dir().join("kubernetes");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "yaml") && !p.ends_with("kustomization.yaml"))
        .collect();
    files.sort();
    assert!(files.len() >= 4, "{files:?}");
    let out = Command::new(validator[0]).args(&validator[1..]).arg("--strict").args(&files).output().unwrap();
    assert!(
        out.status.success(),
        "kubernetes-validate refused the manifests:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}
