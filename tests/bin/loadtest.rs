//! `loadtest`: the real `tessera-server` under many workers, many submissions and a kill.
//!
//! ```text
//! cargo build --release && cargo run --release -p tessera-tests --bin loadtest -- [--workers N]
//!     [--jobs N] [--submitters N] [--tile-size PX] [--size PX] [--no-kill]
//! ```
//!
//! Starts the server (no local workers) on a fixed loopback port with a fresh data directory,
//! then runs N fake workers as threads that speak the real worker protocol over HTTP (register,
//! long-poll for a lease, upload a tile of the right size with its checksum) without rendering,
//! and submitter threads that post jobs (a small scene cut into many tiles) concurrently. When
//! about half of all tiles are acknowledged the server is killed with SIGKILL and started again
//! on the same data directory and port; workers and submitters ride out the gap by retrying.
//!
//! Prints tiles per second, the latency of lease requests that returned a tile (p50, p99, max),
//! answers by HTTP status and transport errors, and **lost acknowledged tiles**: tiles whose
//! upload was answered 204 and that the server later handed out again or does not count as
//! done. A farm that keeps what it acknowledged prints 0; the exit status is 1 otherwise.

use std::collections::{BTreeMap, HashMap};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use serde_json::{Value, json};
use tessera::protocol::{CHECKSUM_HEADER, checksum, encode_tile};

const WORKER_TOKEN: &str = "loadtest-worker-token";

struct Options {
    workers: usize,
    jobs: usize,
    submitters: usize,
    tile: u32,
    size: u32,
    kill: bool,
}

/// Everything the threads count.
#[derive(Default)]
struct Tally {
    /// Answers by (request kind, status); transport errors as status 0.
    statuses: Mutex<BTreeMap<(&'static str, u16), u64>>,
    /// Seconds from a lease request to its answer, for answers that carried a tile.
    lease_latency: Mutex<Vec<f64>>,
    /// (job, camera, tile) -> how many times an upload of it was acknowledged.
    acked: Mutex<HashMap<(u64, u32, u32), u32>>,
    acked_total: AtomicU64,
    jobs: Mutex<Vec<u64>>,
}

impl Tally {
    fn status(&self, kind: &'static str, code: u16) {
        *self.statuses.lock().unwrap().entry((kind, code)).or_default() += 1;
    }
}

fn code_of(r: &Result<ureq::Response, ureq::Error>) -> u16 {
    match r {
        Ok(resp) => resp.status(),
        Err(ureq::Error::Status(code, _)) => *code,
        Err(ureq::Error::Transport(_)) => 0,
    }
}

fn free_port() -> Result<u16> {
    Ok(std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port())
}

fn start_server(bin: &Path, data: &Path, port: u16) -> Result<Child> {
    let mut child = Command::new(bin)
        .args([
            "--bind",
            &format!("127.0.0.1:{port}"),
            "--local-workers",
            "0",
            "--worker-token",
            WORKER_TOKEN,
        ])
        .arg("--data-dir")
        .arg(data)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .with_context(|| format!("cannot start {}", bin.display()))?;
    let mut line = String::new();
    BufReader::new(child.stdout.take().context("server stdout")?).read_line(&mut line)?;
    if !line.starts_with("listening on ") {
        let _ = child.kill();
        bail!("the server did not start: {line:?}");
    }
    Ok(child)
}

/// A small scene: one sphere, `size` x `size` pixels.
fn scene_xml(size: u32) -> String {
    format!(
        r#"<Scene><Cameras><Camera id="1"><Position>0 0 5</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
<NearPlane>-1 1 -1 1</NearPlane><NearDistance>2</NearDistance><ImageResolution>{size} {size}</ImageResolution>
<ImageName>load.png</ImageName></Camera></Cameras>
<Lights><AmbientLight>25 25 25</AmbientLight></Lights>
<Materials><Material id="1"><AmbientReflectance>1 1 1</AmbientReflectance></Material></Materials>
<VertexData>0 0 0</VertexData><Objects><Sphere id="1"><Material>1</Material><Center>1</Center><Radius>1</Radius></Sphere></Objects></Scene>"#
    )
}

fn multipart(parts: &[(&str, Option<&str>, &[u8])]) -> (String, Vec<u8>) {
    let boundary = "tessera-loadtest-4d1c";
    let mut body = Vec::new();
    for (name, file, data) in parts {
        body.extend_from_slice(
            format!("--{boundary}\r\nContent-Disposition: form-data; name=\"{name}\"").as_bytes(),
        );
        if let Some(f) = file {
            body.extend_from_slice(format!("; filename=\"{f}\"").as_bytes());
        }
        body.extend_from_slice(b"\r\n\r\n");
        body.extend_from_slice(data);
        body.extend_from_slice(b"\r\n");
    }
    body.extend_from_slice(format!("--{boundary}--\r\n").as_bytes());
    (format!("multipart/form-data; boundary={boundary}"), body)
}

fn submitter(url: &str, jobs: usize, opts: &Options, tally: &Tally, stop: &AtomicBool) {
    let scene = scene_xml(opts.size);
    let tile = opts.tile.to_string();
    for _ in 0..jobs {
        loop {
            if stop.load(Ordering::SeqCst) {
                return;
            }
            let (ctype, body) = multipart(&[
                ("scene", Some("load.xml"), scene.as_bytes()),
                ("samples", None, b"1"),
                ("tile_size", None, tile.as_bytes()),
            ]);
            let r = ureq::post(&format!("{url}/api/v1/jobs")).set("Content-Type", &ctype).send_bytes(&body);
            let code = code_of(&r);
            tally.status("submit", code);
            if code == 201 {
                let job: Value = r.unwrap().into_json().unwrap_or_default();
                if let Some(id) = job["id"].as_u64() {
                    tally.jobs.lock().unwrap().push(id);
                }
                break;
            }
            // The server is down (being restarted) or refused: try again shortly.
            std::thread::sleep(Duration::from_millis(100));
        }
    }
}

// ureq's own error, passed through unboxed: the callers only read its status code.
#[allow(clippy::result_large_err)]
fn post(url: &str, path: &str, secret: &str, body: Value) -> Result<ureq::Response, ureq::Error> {
    ureq::post(&format!("{url}{path}"))
        .timeout(Duration::from_secs(30))
        .set("Authorization", &format!("Bearer {WORKER_TOKEN}"))
        .set(tessera::protocol::WORKER_SECRET_HEADER, secret)
        .send_json(body)
}

fn worker(url: &str, n: usize, tally: &Tally, stop: &AtomicBool) {
    let name = format!("load-{n}");
    let (id, secret) = loop {
        if stop.load(Ordering::SeqCst) {
            return;
        }
        let r = post(url, "/api/v1/worker/register", "", json!({"name": name, "threads": 1}));
        tally.status("register", code_of(&r));
        match r {
            Ok(resp) => {
                let v = resp.into_json::<Value>().unwrap_or_default();
                break (
                    v["worker_id"].as_u64().unwrap_or(0),
                    v["worker_secret"].as_str().unwrap_or("").to_string(),
                );
            }
            Err(_) => std::thread::sleep(Duration::from_millis(100)),
        }
    };
    while !stop.load(Ordering::SeqCst) {
        let t0 = Instant::now();
        let r = post(url, "/api/v1/worker/lease", &secret, json!({"worker_id": id, "wait_seconds": 1.0}));
        let code = code_of(&r);
        tally.status("lease", code);
        if code != 200 {
            if code != 204 {
                std::thread::sleep(Duration::from_millis(100));
            }
            continue;
        }
        tally.lease_latency.lock().unwrap().push(t0.elapsed().as_secs_f64());
        let lease: Value = r.unwrap().into_json().unwrap_or_default();
        let (Some(lease_id), Some(job), Some(frame), Some(tile)) = (
            lease["lease_id"].as_u64(),
            lease["job_id"].as_u64(),
            lease["camera"].as_u64(),
            lease["tile"].as_u64(),
        ) else {
            tally.status("lease-parse", 0);
            continue;
        };
        let (w, h) =
            (lease["rect"]["width"].as_u64().unwrap_or(0), lease["rect"]["height"].as_u64().unwrap_or(0));
        let body = encode_tile(&vec![[0.25f32, 0.5, 0.75]; (w * h) as usize]);
        let sum = checksum(&body);
        // Retry while the server is down; a 409 means the lease died with it (or expired).
        loop {
            let r = ureq::put(&format!("{url}/api/v1/worker/leases/{lease_id}/result"))
                .timeout(Duration::from_secs(30))
                .set("Authorization", &format!("Bearer {WORKER_TOKEN}"))
                .set("x-tessera-worker", &id.to_string())
                .set(tessera::protocol::WORKER_SECRET_HEADER, &secret)
                .set(CHECKSUM_HEADER, &sum)
                .set("Content-Type", "application/octet-stream")
                .send_bytes(&body);
            let code = code_of(&r);
            tally.status("result", code);
            match code {
                200..=299 => {
                    *tally.acked.lock().unwrap().entry((job, frame as u32, tile as u32)).or_default() += 1;
                    tally.acked_total.fetch_add(1, Ordering::SeqCst);
                    break;
                }
                0 if !stop.load(Ordering::SeqCst) => std::thread::sleep(Duration::from_millis(100)),
                _ => break,
            }
        }
    }
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

fn main() -> Result<()> {
    let mut opts = Options { workers: 16, jobs: 40, submitters: 8, tile: 8, size: 64, kill: true };
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut num = |what: &str| -> Result<usize> {
            args.next()
                .with_context(|| format!("{what} needs a number"))?
                .parse::<usize>()
                .context(what.to_string())
        };
        match a.as_str() {
            "--workers" => opts.workers = num("--workers")?.max(1),
            "--jobs" => opts.jobs = num("--jobs")?.max(1),
            "--submitters" => opts.submitters = num("--submitters")?.max(1),
            "--tile-size" => opts.tile = num("--tile-size")?.max(1) as u32,
            "--size" => opts.size = num("--size")?.max(1) as u32,
            "--no-kill" => opts.kill = false,
            "-h" | "--help" => {
                println!(
                    "loadtest [--workers N] [--jobs N] [--submitters N] [--tile-size PX] [--size PX] [--no-kill]\n\
                     Fake workers (real protocol, no rendering) and concurrent submissions against a real\n\
                     tessera-server, killed with SIGKILL and restarted halfway unless --no-kill."
                );
                return Ok(());
            }
            other => bail!("unknown argument {other}; see --help"),
        }
    }
    let bin: PathBuf = std::env::current_exe()?.with_file_name("tessera-server");
    if !bin.exists() {
        bail!("build the server first: cargo build --release (looked for {})", bin.display());
    }
    let data = std::env::temp_dir().join(format!("tessera-loadtest-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&data);
    let port = free_port()?;
    let url = format!("http://127.0.0.1:{port}");
    let mut server = start_server(&bin, &data, port)?;

    let per_job = opts.size.div_ceil(opts.tile).pow(2) as u64;
    let total_tiles = per_job * opts.jobs as u64;
    println!(
        "{} workers, {} jobs of {}x{} px in {} px tiles ({} tiles each, {} in all), {} submitters, kill: {}",
        opts.workers,
        opts.jobs,
        opts.size,
        opts.size,
        opts.tile,
        per_job,
        total_tiles,
        opts.submitters,
        opts.kill
    );
    let tally = Arc::new(Tally::default());
    let stop = Arc::new(AtomicBool::new(false));
    let opts = Arc::new(opts);
    let started = Instant::now();
    let mut threads = Vec::new();
    for s in 0..opts.submitters {
        let n = opts.jobs / opts.submitters + usize::from(s < opts.jobs % opts.submitters);
        let (url, tally, stop, opts) = (url.clone(), tally.clone(), stop.clone(), opts.clone());
        threads.push(std::thread::spawn(move || submitter(&url, n, &opts, &tally, &stop)));
    }
    for w in 0..opts.workers {
        let (url, tally, stop) = (url.clone(), tally.clone(), stop.clone());
        threads.push(std::thread::spawn(move || worker(&url, w, &tally, &stop)));
    }

    let mut killed_at = None;
    let deadline = Instant::now() + Duration::from_secs(600);
    let mut last_check = Instant::now();
    loop {
        std::thread::sleep(Duration::from_millis(50));
        let acked = tally.acked_total.load(Ordering::SeqCst);
        if opts.kill && killed_at.is_none() && acked >= total_tiles / 2 {
            let _ = server.kill();
            let _ = server.wait();
            killed_at = Some(acked);
            std::thread::sleep(Duration::from_millis(300));
            server = start_server(&bin, &data, port)?;
            println!("killed the server (SIGKILL) after {acked} acknowledged tiles and started it again");
        }
        if last_check.elapsed() > Duration::from_millis(500) {
            last_check = Instant::now();
            let ids = tally.jobs.lock().unwrap().clone();
            if ids.len() == opts.jobs {
                let all_done = ids.iter().all(|id| {
                    ureq::get(&format!("{url}/api/v1/jobs/{id}"))
                        .call()
                        .ok()
                        .and_then(|r| r.into_json::<Value>().ok())
                        .is_some_and(|j| j["state"] == "done")
                });
                if all_done {
                    break;
                }
            }
        }
        if Instant::now() > deadline {
            stop.store(true, Ordering::SeqCst);
            let _ = server.kill();
            bail!("the jobs did not finish within 10 minutes");
        }
    }
    let wall = started.elapsed().as_secs_f64();
    stop.store(true, Ordering::SeqCst);
    for t in threads {
        let _ = t.join();
    }

    // Lost acknowledged tiles: acknowledged more than once (handed out again after a 204), or
    // short of the jobs' totals once every job reports done.
    let acked = tally.acked.lock().unwrap();
    let twice = acked.values().filter(|n| **n > 1).count() as u64;
    let ids = tally.jobs.lock().unwrap().clone();
    let mut done_tiles = 0u64;
    for id in &ids {
        let job: Value = ureq::get(&format!("{url}/api/v1/jobs/{id}")).call()?.into_json()?;
        for f in job["frames"].as_array().into_iter().flatten() {
            done_tiles += f["tiles_done"].as_u64().unwrap_or(0);
        }
    }
    let _ = server.kill();
    let _ = server.wait();
    let _ = std::fs::remove_dir_all(&data);

    let mut lat = tally.lease_latency.lock().unwrap().clone();
    lat.sort_by(f64::total_cmp);
    let acked_total = tally.acked_total.load(Ordering::SeqCst);
    println!("wall time            {wall:.2} s");
    println!("tiles acknowledged   {acked_total} ({:.0} tiles/s)", acked_total as f64 / wall);
    println!("tiles done (server)  {done_tiles} of {total_tiles}");
    println!(
        "lease latency        p50 {:.1} ms, p99 {:.1} ms, max {:.1} ms ({} leases)",
        percentile(&lat, 0.5) * 1e3,
        percentile(&lat, 0.99) * 1e3,
        lat.last().copied().unwrap_or(f64::NAN) * 1e3,
        lat.len()
    );
    println!("answers by status (0 = no connection):");
    for ((kind, code), n) in tally.statuses.lock().unwrap().iter() {
        println!("  {kind:<9} {code:>3}  {n}");
    }
    let short = total_tiles.saturating_sub(done_tiles);
    println!(
        "lost acknowledged tiles: {} ({twice} handed out again after a 204, {short} short of the jobs' totals)",
        twice + short
    );
    if twice + short > 0 {
        eprintln!("FAIL: the farm lost acknowledged work");
        std::process::exit(1);
    }
    Ok(())
}
