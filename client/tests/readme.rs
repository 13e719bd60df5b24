//! The README's commands, run as a newcomer would run them: every `sh` block's command line
//! (the farm started in the background, the client, curl) in a fresh folder, with the
//! `./target/release/` binaries replaced by the ones under test and the farm's address by a
//! free port; and every flag of every synopsis (`text` blocks) checked against the binary's
//! `--help`. The two `cargo` commands are the ones that build and run this very test: they are
//! not run again from here.

mod support;

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;

use support::*;

/// The fenced code blocks of `markdown` with their language tag.
fn code_blocks(markdown: &str) -> Vec<(String, Vec<String>)> {
    let mut blocks = Vec::new();
    let mut current: Option<(String, Vec<String>)> = None;
    for line in markdown.lines() {
        let fence = line.trim_start().strip_prefix("```");
        match (fence, current.take()) {
            (Some(lang), None) => current = Some((lang.trim().to_string(), Vec::new())),
            (Some(_), Some(block)) => blocks.push(block),
            (None, Some((lang, mut lines))) => {
                lines.push(line.to_string());
                current = Some((lang, lines));
            }
            (None, None) => {}
        }
    }
    blocks
}

/// Command lines of a shell block: continuations joined, comments and blank lines dropped.
fn command_lines(block: &[String]) -> Vec<String> {
    let mut out = Vec::new();
    let mut pending = String::new();
    for line in block {
        let line = line.trim();
        if let Some(head) = line.strip_suffix('\\') {
            pending.push_str(head);
            pending.push(' ');
            continue;
        }
        pending.push_str(line);
        let command = std::mem::take(&mut pending);
        if !command.is_empty() && !command.starts_with('#') {
            out.push(command);
        }
    }
    out
}

fn readme() -> String {
    std::fs::read_to_string(repo().join("README.md")).expect("read README.md")
}

#[test]
fn every_synopsis_flag_is_one_the_binary_takes() {
    let mut checked = 0;
    for (lang, block) in code_blocks(&readme()) {
        if lang != "text" {
            continue;
        }
        // A synopsis line starts with the program; the following indented lines continue it.
        let mut synopses: Vec<String> = Vec::new();
        for line in &block {
            if line.starts_with("tessera") {
                synopses.push(line.clone());
            } else if let Some(last) = synopses.last_mut() {
                last.push(' ');
                last.push_str(line.trim());
            }
        }
        for synopsis in synopses {
            let mut words = synopsis.split_whitespace();
            let program = words.next().unwrap();
            let bin = if program == "tessera" { client_bin() } else { farm_bin(program) };
            let rest: Vec<&str> = words.collect();
            // The subcommand, if the second word is one (not an operand like SCENE or a flag).
            let sub = rest.first().filter(|w| w.chars().all(|c| c.is_ascii_lowercase() || c == '-'));
            let mut cmd = Command::new(&bin);
            cmd.args(sub).arg("--help");
            let help = cmd.output().unwrap_or_else(|e| panic!("{bin:?} --help: {e}"));
            assert!(help.status.success(), "{synopsis}: --help failed");
            let help = String::from_utf8_lossy(&help.stdout);
            for flag in
                rest.iter().flat_map(|w| w.split(['[', ']', '|', '.'])).filter(|w| w.starts_with("--"))
            {
                let flag = flag.split('=').next().unwrap();
                assert!(
                    help.contains(flag),
                    "README: `{synopsis}` names {flag}, which `{program} {}--help` does not list",
                    sub.map(|s| format!("{s} ")).unwrap_or_default()
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 40, "only {checked} flags found in the README's synopses");
}

#[test]
fn the_readmes_commands_work_as_written() {
    let _serial = serial();
    let work = TempDir::new("readme");
    // The README runs from the repository's root: its scenes are where it says.
    std::os::unix::fs::symlink(repo().join("scenes"), work.join("scenes")).unwrap();
    let bins = client_bin().parent().unwrap().to_path_buf();
    farm_bin("tessera-server");
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let address = format!("127.0.0.1:{port}");
    let config_home = work.join("config");
    std::fs::create_dir_all(&config_home).unwrap();

    let rewrite = |line: &str| -> String {
        line.replace("./target/release/", &format!("{}/", bins.display())).replace("127.0.0.1:8080", &address)
    };
    // A shell as a newcomer's: no TESSERA_* settings of this machine, a config folder of its
    // own; the farm on the free port (the client and the server read these variables too).
    let shell = |line: &str| -> Command {
        let mut sh = Command::new("sh");
        sh.arg("-c").arg(line).current_dir(work.path()).stdin(Stdio::null());
        for (k, _) in std::env::vars_os() {
            if k.to_string_lossy().starts_with("TESSERA_") {
                sh.env_remove(&k);
            }
        }
        sh.env("XDG_CONFIG_HOME", &config_home).env("HOME", &config_home);
        sh.env("TESSERA_BIND", &address)
            .env("TESSERA_SERVER", format!("http://{address}"))
            .env("TESSERA_DATA_DIR", work.join("tessera-data"))
            .env("TESSERA_LOCAL_WORKER_THREADS", "2");
        sh
    };

    let mut server: Option<std::process::Child> = None;
    let mut ran = Vec::new();
    let blocks = code_blocks(&readme());
    for (lang, block) in &blocks {
        if lang != "sh" {
            continue;
        }
        for line in command_lines(block) {
            if line == "cargo test --workspace" {
                continue; // what runs this test
            }
            // The farm: built by `cargo build --release` in the README, by cargo test here.
            let line = line.strip_prefix("cargo build --release && ").unwrap_or(&line).to_string();
            let line = rewrite(&line);
            if line.ends_with("/tessera-server") {
                let log = work.join("server.log");
                // `exec`: the shell becomes the server, so the signal that stops it below
                // reaches the server itself (and its local worker with it).
                let mut cmd = shell(&format!("exec {line}"));
                cmd.stdout(Stdio::piped()).stderr(std::fs::File::create(&log).unwrap());
                let mut child = cmd.spawn().expect("start the README's server");
                let first =
                    tessera_testkit::first_line(child.stdout.take().unwrap(), Duration::from_secs(30));
                assert!(
                    first.as_deref().is_some_and(|l| l.contains(&address)),
                    "the README's server did not start on {address}: {first:?}\n{}",
                    std::fs::read_to_string(&log).unwrap_or_default()
                );
                server = Some(child);
                ran.push(line);
                continue;
            }
            assert!(server.is_some(), "the README runs `{line}` before it starts the farm");
            let out = run(&mut shell(&line), Duration::from_secs(300));
            assert!(
                out.status.success(),
                "README command `{line}` failed ({:?}):\n{}\n{}",
                out.status,
                text(&out.stdout),
                text(&out.stderr)
            );
            ran.push(line);
        }
    }
    if let Some(mut s) = server {
        signal(&s, libc::SIGTERM);
        if wait_timeout(&mut s, Duration::from_secs(15)).is_none() {
            let _ = s.kill();
        }
    }
    assert!(ran.len() >= 5, "too few README commands ran: {ran:?}");

    // What the README says they leave: the client's PNG has the CLI's bytes, and curl's
    // download of it too.
    let png =
        std::fs::read(work.join("out/tori.png")).expect("the README's first render writes out/tori.png");
    let cli = TempDir::new("readme-cli");
    cli_render(&repo().join("scenes/tori.xml"), cli.path(), &[]);
    assert_eq!(
        png,
        std::fs::read(cli.join("tori.png")).unwrap(),
        "the client's tori.png differs from the CLI's"
    );
    // The animation: 24 frames with the CLI's bytes, and their video.
    let orbit = work.join("orbit");
    for k in 0..24 {
        assert!(
            orbit.join(format!("orbit_{k:02}.png")).is_file(),
            "the README's animation left no frame {k}"
        );
    }
    let cli = TempDir::new("readme-cli-orbit");
    cli_render(&repo().join("scenes/orbit/orbit_05.xml"), cli.path(), &[]);
    assert_eq!(
        std::fs::read(orbit.join("orbit_05.png")).unwrap(),
        std::fs::read(cli.join("orbit_05.png")).unwrap()
    );
    assert!(
        orbit.join("video.mp4").is_file() || orbit.join("video.gif").is_file(),
        "the README's animation left no video"
    );
    let curl_png: PathBuf = work.join("tori.png");
    assert_eq!(std::fs::read(&curl_png).expect("curl -O wrote tori.png"), png);
}
