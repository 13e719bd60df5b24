//! The farm's overhead: the same scene rendered by `tessera-worker render` and through
//! `tessera-server` with one local worker, comparing wall time and the CPU seconds of every
//! process involved.
//!
//! ```text
//! cargo build --release && cargo run --release -p tessera-tests --bin farmbench -- [SCENE] [--samples N] [--tile-size PX]
//! ```
//! Default scene: `scenes/environment.xml` at 200 samples per pixel. Assets are uploaded from
//! the scene's folder (every file the scene's directory holds, up to 64 MiB).
//!
//! Farm wall time runs from the submission request to the job's `done` state (upload,
//! validation, bundle fetch and scene build on the worker, rendering, merge, tone mapping),
//! which is awaited on the server's event stream (`/api/v1/events`, as the status page
//! follows jobs) rather than by polling; the server is already running, as a farm is. CPU seconds are read from /proc for the
//! server and its worker (Linux only).

use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};

fn clock_ticks() -> f64 {
    Command::new("getconf")
        .arg("CLK_TCK")
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or(100.0)
}

/// (utime + stime) of a process, and (cutime + cstime) of its waited-for children, in seconds.
fn cpu_of(pid: u32) -> Result<(f64, f64)> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .with_context(|| format!("cannot read /proc/{pid}/stat"))?;
    // Fields after the command name (which may contain spaces) start at index 2 (state).
    let rest = &stat[stat.rfind(')').context("odd /proc stat")? + 2..];
    let f: Vec<f64> = rest.split_whitespace().map(|x| x.parse().unwrap_or(0.0)).collect();
    let t = clock_ticks();
    // utime, stime, cutime, cstime are fields 14-17 (1-based) = indices 11-14 here.
    Ok(((f[11] + f[12]) / t, (f[13] + f[14]) / t))
}

/// Children of `pid` (by scanning /proc).
fn children(pid: u32) -> Vec<u32> {
    let mut out = Vec::new();
    if let Ok(entries) = std::fs::read_dir("/proc") {
        for e in entries.flatten() {
            let Ok(p) = e.file_name().to_string_lossy().parse::<u32>() else { continue };
            if let Ok(stat) = std::fs::read_to_string(format!("/proc/{p}/stat"))
                && let Some(i) = stat.rfind(')')
                && stat[i + 2..].split_whitespace().nth(1).and_then(|x| x.parse::<u32>().ok()) == Some(pid)
            {
                out.push(p);
            }
        }
    }
    out
}

fn self_children_cpu() -> f64 {
    cpu_of(std::process::id()).map(|(_, c)| c).unwrap_or(0.0)
}

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let root = tessera_tests::repo_root();
    let mut scene = root.join("scenes/environment.xml");
    let mut samples = Some(200u32);
    let mut tile = 32u32;
    let mut repeat = 3usize;
    // Threads for the CLI and the local worker alike; None: every core.
    let mut threads: Option<usize> = None;
    while let Some(a) = args.next() {
        match a.as_str() {
            "--samples" => samples = Some(args.next().context("--samples N")?.parse()?),
            "--scene-samples" => samples = None,
            "--tile-size" => tile = args.next().context("--tile-size PX")?.parse()?,
            "--repeat" => repeat = args.next().context("--repeat N")?.parse::<usize>()?.max(1),
            "--threads" => threads = Some(args.next().context("--threads N")?.parse::<usize>()?.max(1)),
            "-h" | "--help" => {
                println!(
                    "farmbench [SCENE] [--samples N | --scene-samples] [--tile-size PX] [--repeat N] [--threads N]\n\
                     --threads 1 compares one core with one core: steadier on a small shared machine"
                );
                return Ok(());
            }
            other => scene = PathBuf::from(other),
        }
    }
    let bin_dir = std::env::current_exe()?.parent().map(Path::to_path_buf).unwrap_or_default();
    let (server_bin, worker_bin) = (bin_dir.join("tessera-server"), bin_dir.join("tessera-worker"));
    if !server_bin.exists() || !worker_bin.exists() {
        bail!("build the binaries first: cargo build --release (looked in {})", bin_dir.display());
    }
    let spp: Vec<String> = samples.map(|s| vec!["--samples".into(), s.to_string()]).unwrap_or_default();

    // 2. The farm: a server with one local worker, already up.
    let data = std::env::temp_dir().join(format!("farmbench-data-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&data);
    let mut server = Command::new(&server_bin)
        .args([
            "--bind",
            "127.0.0.1:0",
            "--local-workers",
            "1",
            "--tile-size",
            &tile.to_string(),
            "--data-dir",
        ])
        .arg(&data)
        .args(threads.map(|t| vec!["--local-worker-threads".to_string(), t.to_string()]).unwrap_or_default())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()?;
    let mut line = String::new();
    BufReader::new(server.stdout.take().context("server stdout")?).read_line(&mut line)?;
    let url = line.trim().strip_prefix("listening on ").context("unexpected server output")?.to_string();
    // Wait for the local worker to register.
    let deadline = Instant::now() + Duration::from_secs(20);
    let worker_pid = loop {
        let kids = children(server.id());
        let body = ureq::get(&format!("{url}/api/v1/workers"))
            .call()
            .ok()
            .and_then(|r| r.into_string().ok())
            .unwrap_or_default();
        if let (Some(&pid), true) = (kids.first(), body.contains("\"local-1\"")) {
            break pid;
        }
        if Instant::now() > deadline {
            bail!("the local worker did not start");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    // The upload: the scene and every file under its folder, as curl -F would send them.
    let dir = scene.parent().unwrap_or(Path::new("."));
    let mut parts: Vec<(String, Vec<u8>)> = vec![(
        format!("scene\"; filename=\"{}", scene.file_name().unwrap().to_string_lossy()),
        std::fs::read(&scene)?,
    )];
    let mut total = 0usize;
    for entry in walk(dir) {
        let rel = entry.strip_prefix(dir).unwrap().to_string_lossy().replace('\\', "/");
        if entry == scene || rel.ends_with(".xml") || rel.ends_with(".json") {
            continue;
        }
        let bytes = std::fs::read(&entry)?;
        total += bytes.len();
        if total > 64 << 20 {
            bail!("the scene's folder holds over 64 MiB; point farmbench at a smaller scene");
        }
        parts.push((format!("asset\"; filename=\"{rel}"), bytes));
    }
    if let Some(s) = samples {
        parts.push(("samples".into(), s.to_string().into_bytes()));
    }
    let boundary = "farmbench-boundary";
    let mut body = Vec::new();
    for (name, data) in &parts {
        body.extend_from_slice(
            format!("--{boundary}\r\nContent-Disposition: form-data; name=\"{name}\"\r\n\r\n").as_bytes(),
        );
        body.extend_from_slice(data);
        body.extend_from_slice(b"\r\n");
    }
    body.extend_from_slice(format!("--{boundary}--\r\n").as_bytes());

    let out = std::env::temp_dir().join(format!("farmbench-cli-{}", std::process::id()));
    // One CLI render: (wall, CPU of the process).
    let run_cli = || -> Result<(f64, f64)> {
        let cpu0 = self_children_cpu();
        let t = Instant::now();
        let status = Command::new(&worker_bin)
            .arg("render")
            .arg(&scene)
            .args(&spp)
            .args(["--quiet", "--tile-size", &tile.to_string(), "--out"])
            .arg(&out)
            .args(threads.map(|t| vec!["--threads".to_string(), t.to_string()]).unwrap_or_default())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()?;
        let wall = t.elapsed().as_secs_f64();
        if !status.success() {
            bail!("tessera-worker render failed on {}", scene.display());
        }
        Ok((wall, self_children_cpu() - cpu0))
    };
    // One job through the farm: (wall, CPU of server and worker, server CPU, worker CPU).
    let run_farm = || -> Result<(f64, f64, f64, f64)> {
        let (s0, _) = cpu_of(server.id())?;
        let (w0, _) = cpu_of(worker_pid)?;
        // The job's end is awaited on the server's event stream (as the status page follows
        // jobs), opened before the submission so no event can be missed: polling its state
        // every few milliseconds instead would load the server being measured.
        let stream = ureq::get(&format!("{url}/api/v1/events")).call().context("opening /api/v1/events")?;
        let mut events = BufReader::new(stream.into_reader());
        let t = Instant::now();
        let resp = ureq::post(&format!("{url}/api/v1/jobs"))
            .set("Content-Type", &format!("multipart/form-data; boundary={boundary}"))
            .send_bytes(&body);
        let job: serde_json::Value = match resp {
            Ok(r) => r.into_json()?,
            Err(ureq::Error::Status(code, r)) => {
                bail!("submission refused ({code}): {}", r.into_string().unwrap_or_default())
            }
            Err(e) => bail!("submission failed: {e}"),
        };
        let id = job["id"].as_u64().context("no job id")?;
        let state_of = || -> Result<String> {
            let mut text = String::new();
            ureq::get(&format!("{url}/api/v1/jobs/{id}")).call()?.into_reader().read_to_string(&mut text)?;
            let j: serde_json::Value = serde_json::from_str(&text)?;
            Ok(j["state"].as_str().unwrap_or_default().to_string())
        };
        let mut line = String::new();
        loop {
            line.clear();
            if events.read_line(&mut line)? == 0 {
                bail!("the server closed its event stream before job {id} ended");
            }
            // `event: resync` (this reader fell behind) means: look at the job itself.
            let state = if line.trim_end() == "event: resync" {
                state_of()?
            } else if let Some(data) = line.strip_prefix("data:") {
                let ev: serde_json::Value = serde_json::from_str(data.trim()).unwrap_or_default();
                if ev["type"] != "job" || ev["job"].as_u64() != Some(id) {
                    continue;
                }
                ev["state"].as_str().unwrap_or_default().to_string()
            } else {
                continue;
            };
            match state.as_str() {
                "done" => break,
                "failed" | "canceled" => bail!("job {id} ended {state}: {}", state_of().unwrap_or_default()),
                _ => {}
            }
        }
        let farm_wall = t.elapsed().as_secs_f64();
        let (s1, _) = cpu_of(server.id())?;
        let (w1, _) = cpu_of(worker_pid)?;
        let farm_cpu = (s1 - s0) + (w1 - w0);
        Ok((farm_wall, farm_cpu, s1 - s0, w1 - w0))
    };
    println!(
        "scene {} ({}), tile {tile} px, {}, {repeat} alternating runs each",
        scene.display(),
        samples.map_or("its own samples".to_string(), |s| format!("{s} spp")),
        threads.map_or("every core".to_string(), |t| format!("{t} thread(s) each"))
    );
    let (mut walls, mut cpus) = (Vec::new(), Vec::new());
    for k in 1..=repeat {
        // The order alternates (CLI first on odd runs, the farm first on even ones), so a
        // machine that speeds up or slows down within a pair favours neither side.
        let ((cw, cc), (fw, fc, sc, wc)) = if k % 2 == 1 {
            let cli = run_cli()?;
            (cli, run_farm()?)
        } else {
            let farm = run_farm()?;
            (run_cli()?, farm)
        };
        println!(
            "run {k} ({} first): CLI wall {cw:.2} s, CPU {cc:.2} s | farm wall {fw:.2} s, CPU {fc:.2} s (server {sc:.2}, worker {wc:.2}) | ratio wall {:.3}, CPU {:.3}",
            if k % 2 == 1 { "CLI" } else { "farm" },
            fw / cw,
            fc / cc
        );
        walls.push(fw / cw);
        cpus.push(fc / cc);
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    println!(
        "median ratio farm/CLI: wall {:.3}, CPU {:.3} (target <= 1.10; this machine's timings vary by about 10 % run to run)",
        median(&mut walls),
        median(&mut cpus)
    );
    // SIGTERM, so the server stops its local worker; kill(2) directly, since minimal machines
    // have no `kill` program.
    // SAFETY: kill(2) has no memory effects.
    unsafe {
        libc::kill(server.id() as libc::pid_t, libc::SIGTERM);
    }
    let _ = server.wait();
    let _ = std::fs::remove_dir_all(&data);
    let _ = std::fs::remove_dir_all(&out);
    Ok(())
}

fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                out.extend(walk(&p));
            } else {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}
