//! Acknowledged work is never lost, against the real server over real sockets: a disk that fills
//! during a merge (the merge waits and finishes once space returns), submissions and tile
//! uploads on a full disk (507, nothing stored, no server path), a kill -9 during a merge (its
//! temporary files are removed at the next start), output names equal to the server's own file
//! names (`pass.png`, `pass.exr`, `pass.hdr`), and a lost job store beside earlier outputs (a
//! refusal to start, the outputs untouched).
//!
//! The full-disk test runs the server in a mount namespace of its own with a small tmpfs on its
//! data directory (`unshare(CLONE_NEWNS)` and `mount(2)` in the child before it starts: root on
//! Linux); the test reaches that directory through `/proc/PID/root`. Where that cannot be done
//! it skips with the reason, unless `TESSERA_REQUIRE_SMALL_FS=1` (`.ci/run`, after a probe),
//! which makes that a failure.

mod support;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use support::small_fs::*;
use support::*;
use tessera::protocol::{checksum, encode_tile};

const WORKER: &str = "WTOK";

/// A server with no local worker (the tests play the worker) and leases that outlive the test.
const ARGS: [&str; 8] =
    ["--worker-token", WORKER, "--local-workers", "0", "--lease-seconds", "900", "--heartbeat-seconds", "5"];

fn register(url: &str, threads: u32) -> u64 {
    let (code, v) =
        worker_post(url, WORKER, "/api/v1/worker/register", json!({"name": "scripted", "threads": threads}));
    assert_eq!(code, 200, "{v}");
    v["worker_id"].as_u64().unwrap()
}

fn lease(url: &str, worker: u64) -> Value {
    let (code, v) =
        worker_post(url, WORKER, "/api/v1/worker/lease", json!({"worker_id": worker, "wait_seconds": 0.0}));
    assert_eq!(code, 200, "{v}");
    assert!(v["lease_id"].is_u64(), "no tile to lease: {v}");
    v
}

/// A tile upload as a worker sends it.
fn upload(url: &str, worker: u64, lease: &Value) -> (u16, Value) {
    let body = tile_pixels(lease);
    let req = ureq::put(&format!("{url}/api/v1/worker/leases/{}/result", lease["lease_id"]))
        .set("Authorization", &format!("Bearer {WORKER}"))
        .set("x-tessera-worker", &worker.to_string())
        .set("x-tessera-worker-secret", &worker_secret(url, worker).unwrap_or_default())
        .set("x-tessera-checksum", &checksum(&body));
    call(req, Some(("application/octet-stream".into(), body)))
}

/// The pixels the scripted worker sends for a lease's tile: noise in [0, 1) drawn from the
/// tile's place, so that two runs send the same bytes whatever order the tiles are leased in,
/// and the outputs (PNG and EXR) do not compress below their pixels' size.
fn tile_pixels(lease: &Value) -> Vec<u8> {
    let r = &lease["rect"];
    let field = |k: &str| r[k].as_u64().unwrap();
    let (x0, y0) = (field("x0"), field("y0"));
    let n = (field("width") * field("height")) as usize;
    let mut state = (x0 << 32 | y0) ^ 0x9e37_79b9_7f4a_7c15;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    let px: Vec<[f32; 3]> = (0..n).map(|_| [next(), next(), next()]).collect();
    encode_tile(&px)
}

fn submit_tiny(url: &str, w: u32, h: u32, tile: u32) -> (u16, Value) {
    let scene = tessera_testkit::tiny_scene(w, h);
    submit(
        url,
        None,
        &[("scene", Some("tiny.xml"), &scene), ("tile_size", None, tile.to_string().as_bytes())],
    )
}

fn job(server: &Server, id: u64) -> Value {
    get_json(&server.url, &format!("/api/v1/jobs/{id}"))
}

fn events(server: &Server, id: u64) -> Vec<Value> {
    get_json(&server.url, &format!("/api/v1/jobs/{id}/log"))["events"].as_array().unwrap().clone()
}

fn kinds(events: &[Value], kind: &str) -> usize {
    events.iter().filter(|e| e["kind"] == kind).count()
}

/// Every output of a finished job, by frame and name, as downloaded.
fn downloads(server: &Server, job: &Value) -> BTreeMap<(usize, String), Vec<u8>> {
    let id = job["id"].as_u64().unwrap();
    let mut files = BTreeMap::new();
    for (k, frame) in job["frames"].as_array().unwrap().iter().enumerate() {
        for o in frame["outputs"].as_array().unwrap() {
            let name = o["name"].as_str().unwrap().to_string();
            let bytes = get_bytes(&server.url, &format!("/api/v1/jobs/{id}/frames/{k}/files/{name}"));
            files.insert((k, name), bytes);
        }
    }
    files
}

/// What a farm without trouble makes of the tiny scene at `w` x `h` in tiles of `tile` with the
/// scripted worker's pixels: its outputs as downloaded.
fn normal_run(w: u32, h: u32, tile: u32) -> BTreeMap<(usize, String), Vec<u8>> {
    let server = Server::start_temp("durable-normal", &ARGS);
    let (code, v) = submit_tiny(&server.url, w, h, tile);
    assert_eq!(code, 201, "{v}");
    let id = v["id"].as_u64().unwrap();
    let worker = register(&server.url, 1);
    let tiles = u64::from(w.div_ceil(tile) * h.div_ceil(tile));
    for _ in 0..tiles {
        let l = lease(&server.url, worker);
        assert_eq!(upload(&server.url, worker, &l).0, 204);
    }
    let done = wait_job(&server, id, 120, |j| j["state"] == "done");
    downloads(&server, &done)
}

/// Names of the writers' temporary files (`.NAME.PID-N-NANOS.tmp`, and the old `.pass.exr.tmp`)
/// under `dir`, at any depth.
fn temporaries(dir: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let Ok(entries) = std::fs::read_dir(dir) else { return found };
    for e in entries.flatten() {
        let path = e.path();
        if path.is_dir() {
            found.extend(temporaries(&path));
        } else if e.file_name().to_string_lossy().starts_with('.')
            && e.file_name().to_string_lossy().ends_with(".tmp")
        {
            found.push(path);
        }
    }
    found
}

/// A disk that fills between a frame's last acknowledged tile and its merge: the job goes on
/// (not failed, its error empty), its log says why once however often the merge is tried, and
/// once the filler is deleted the frame merges by itself into the outputs a normal run makes.
/// Meanwhile, on the full disk, a submission and a tile upload are 507s that say so, name no
/// server path and store nothing; the same upload is taken once space is back.
#[test]
fn a_merge_that_finds_the_disk_full_waits_for_space_and_loses_nothing() {
    let _s = serial();
    if let Err(why) = small_fs_works() {
        return skip(&why);
    }
    let data = TempDir::new("durable-full");
    let server = Server::start_with(&data, &ARGS, |cmd| on_small_fs(cmd, &data, 16));
    let root = as_server_sees(&server, &data);
    let total = free_bytes(&root);
    assert!(total < 17 << 20, "the data directory is not on the small filesystem: {total} bytes free");

    // Job A: 384 x 384 in four tiles of 192 (432 KiB of pixels each); job B: one such tile.
    let (code, a) = submit_tiny(&server.url, 384, 384, 192);
    assert_eq!(code, 201, "{a}");
    let (code, b) = submit_tiny(&server.url, 192, 192, 192);
    assert_eq!(code, 201, "{b}");
    let (a, b) = (a["id"].as_u64().unwrap(), b["id"].as_u64().unwrap());
    let worker = register(&server.url, 4);
    let leases: Vec<Value> = (0..5).map(|_| lease(&server.url, worker)).collect();
    assert!(leases[..4].iter().all(|l| l["job_id"] == a) && leases[4]["job_id"] == b);
    for l in &leases[..3] {
        assert_eq!(upload(&server.url, worker, l).0, 204);
    }

    // Room for the last tile (432 KiB in the store) but not for the outputs (a 432 KiB PNG, a
    // 1.7 MiB EXR): the merge finds the disk full after the tile is acknowledged.
    let filler = root.join("filler");
    fill(&filler, 800 << 10);
    let (code, v) = upload(&server.url, worker, &leases[3]);
    assert_eq!(code, 204, "the last tile must be acknowledged: {v}\n{}", server.log());
    let deadline = Instant::now() + Duration::from_secs(60);
    while kinds(&events(&server, a), "merge_waiting_for_space") == 0 {
        assert!(Instant::now() < deadline, "no merge_waiting_for_space event\n{}", server.log());
        std::thread::sleep(Duration::from_millis(100));
    }
    // Retried (every 2 s, then 4, ...) and told once.
    std::thread::sleep(Duration::from_secs(7));
    let log = events(&server, a);
    let told: Vec<&Value> = log.iter().filter(|e| e["kind"] == "merge_waiting_for_space").collect();
    assert_eq!(told.len(), 1, "{log:?}");
    let message = told[0]["message"].as_str().unwrap();
    assert!(message.contains("disk is full") && message.contains("frees space"), "{message}");
    let waiting = job(&server, a);
    assert_eq!((waiting["state"].as_str(), &waiting["error"]), (Some("running"), &Value::Null), "{waiting}");
    assert!(waiting["frames"][0]["outputs"].as_array().unwrap().is_empty(), "{waiting}");
    let retries = server.log().matches("the disk is still full").count();
    assert!(retries >= 1, "the merge was not tried again\n{}", server.log());
    eprintln!("merge tried {} time(s) while the disk was full, told once in the job's log", retries + 1);

    // The disk full to the last byte: a submission and a tile upload are refused whole.
    fill(&filler, 0);
    let data_path = data.path().to_str().unwrap().to_string();
    let (code, v) = submit_tiny(&server.url, 64, 64, 32);
    assert_eq!(code, 507, "{v}");
    let said = v.to_string();
    assert!(said.contains("disk is full") && said.contains("nothing was stored"), "{said}");
    assert!(!said.contains(&data_path) && !said.contains("/proc") && !said.contains("/tmp"), "{said}");
    let (code, v) = upload(&server.url, worker, &leases[4]);
    assert_eq!(code, 507, "{v}");
    let said = v.to_string();
    assert!(said.contains("disk is full") && !said.contains(&data_path), "{said}");
    assert_eq!(job(&server, b)["frames"][0]["tiles_done"], 0);
    let jobs = get_json(&server.url, "/api/v1/jobs");
    assert_eq!(jobs["jobs"].as_array().map(Vec::len), Some(2), "a job was stored: {jobs}");

    // Space returns: the frame merges by itself, the refused tile is taken when sent again.
    std::fs::remove_file(&filler).unwrap();
    let freed = Instant::now();
    let done = wait_job(&server, a, 60, |j| j["state"] == "done");
    eprintln!("job merged {:.1} s after the filler was deleted", freed.elapsed().as_secs_f64());
    let log = events(&server, a);
    assert_eq!(kinds(&log, "merge_waiting_for_space"), 1, "{log:?}");
    assert_eq!(kinds(&log, "frame_merged"), 1, "{log:?}");
    for e in &log {
        let m = e["message"].as_str().unwrap_or_default();
        assert!(!m.contains(&data_path) && !m.contains("/proc/"), "a path in the job's log: {m}");
    }
    assert_eq!(upload(&server.url, worker, &leases[4]).0, 204);
    wait_job(&server, b, 60, |j| j["state"] == "done");
    assert_eq!(downloads(&server, &done), normal_run(384, 384, 192), "outputs differ from a normal run's");
    let left = temporaries(&root);
    assert!(left.is_empty(), "temporary files left: {left:?}");
}

/// A merge that fails for another reason than space (here the frame's output folder cannot be
/// made: a file stands in its place) still fails its job at once, and neither the job's error
/// nor its log shows a server path: the file names stay, the folders go to the server's log.
#[test]
fn a_merge_failing_for_another_reason_fails_its_job_without_showing_a_path() {
    let _s = serial();
    let data = TempDir::new("durable-fails");
    let server = Server::start(&data, &ARGS);
    let (code, v) = submit_tiny(&server.url, 32, 32, 32);
    assert_eq!(code, 201, "{v}");
    let id = v["id"].as_u64().unwrap();
    std::fs::create_dir_all(data.join(format!("outputs/{id}"))).unwrap();
    std::fs::write(data.join(format!("outputs/{id}/0")), b"in the way").unwrap();
    let worker = register(&server.url, 1);
    assert_eq!(upload(&server.url, worker, &lease(&server.url, worker)).0, 204);
    let deadline = Instant::now() + Duration::from_secs(60);
    let failed = loop {
        let j = job(&server, id);
        if j["state"] == "failed" {
            break j;
        }
        assert!(Instant::now() < deadline && j["state"] == "running", "{j}\n{}", server.log());
        std::thread::sleep(Duration::from_millis(50));
    };
    let error = failed["error"].as_str().unwrap();
    eprintln!("the job's error: {error}");
    let data_path = data.path().to_str().unwrap();
    assert!(error.starts_with("merging frame 0 failed: "), "{error}");
    assert!(!error.contains(data_path) && !error.contains("/outputs/"), "a path in the job's error: {error}");
    let log = events(&server, id);
    assert_eq!(kinds(&log, "merge_waiting_for_space"), 0, "{log:?}");
    let told: Vec<&str> =
        log.iter().filter(|e| e["kind"] == "job_failed").filter_map(|e| e["message"].as_str()).collect();
    assert_eq!(told, [error], "{log:?}");
    // The server's log has the whole path.
    assert!(server.log().contains(&format!("{data_path}/outputs/{id}/0")), "{}", server.log());
}

// ---------------------------------------------------------------------------------------------
// kill -9 during a merge.
// ---------------------------------------------------------------------------------------------

/// A server killed with SIGKILL while it merges a large frame (the kill is sent as soon as a
/// temporary file of the merge shows in the frame's folder), plus temporary files planted under
/// the names the merge and the pass writer use: after a restart every temporary file is gone,
/// nothing else in the folders is touched, and the frame is merged into the outputs a normal
/// run makes.
#[test]
fn a_kill_during_a_merge_leaves_no_temporary_file_after_the_restart() {
    let _s = serial();
    let data = TempDir::new("durable-kill");
    let mut server = Server::start(&data, &ARGS);
    // 1024 x 1024 in 16 tiles of 256: a 12 MiB EXR and a 3 MiB PNG to write.
    let (code, v) = submit_tiny(&server.url, 1024, 1024, 256);
    assert_eq!(code, 201, "{v}");
    let id = v["id"].as_u64().unwrap();
    let worker = register(&server.url, 16);
    let leases: Vec<Value> = (0..16).map(|_| lease(&server.url, worker)).collect();
    for l in &leases[..15] {
        assert_eq!(upload(&server.url, worker, l).0, 204);
    }
    let outputs = data.join(format!("outputs/{id}/0"));
    let own = data.join(format!("frames/{id}/0"));
    std::fs::create_dir_all(&outputs).unwrap();
    std::fs::create_dir_all(&own).unwrap();
    let planted = [
        outputs.join(".tiny.exr.4242-7-123456789.tmp"),
        outputs.join(".tiny.png.4242-8-123456789.tmp"),
        outputs.join(".pass.exr.tmp"),
        own.join(".pass.png.4242-9-123456789.tmp"),
        own.join(".preview.png.4242-10-123456789.tmp"),
    ];
    for p in &planted {
        std::fs::write(p, vec![7u8; 1 << 20]).unwrap();
    }
    // Not a temporary file's name: stays.
    let keep = outputs.join("notes.tmp");
    std::fs::write(&keep, b"mine").unwrap();

    assert_eq!(upload(&server.url, worker, &leases[15]).0, 204);
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut caught = false;
    while Instant::now() < deadline {
        let fresh = temporaries(&data).into_iter().filter(|p| !planted.contains(p)).count();
        if fresh > 0 {
            caught = true;
            break;
        }
        if std::fs::read_dir(&outputs).unwrap().flatten().any(|e| e.file_name() == "tiny.exr") {
            break; // the merge wrote its EXR between two looks
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    server.kill9();
    let after_kill = temporaries(&data);
    eprintln!(
        "kill -9 {} the merge; {} temporary file(s) on disk after the kill ({} planted)",
        if caught { "landed during" } else { "came after the EXR of" },
        after_kill.len(),
        planted.len()
    );
    assert!(after_kill.len() >= planted.len(), "{after_kill:?}");

    let server = Server::start(&data, &ARGS);
    let left = temporaries(&data);
    assert!(left.is_empty(), "temporary files left after the restart: {left:?}\n{}", server.log());
    assert_eq!(std::fs::read(&keep).unwrap(), b"mine");
    let done = wait_job(&server, id, 120, |j| j["state"] == "done");
    assert_eq!(downloads(&server, &done), normal_run(1024, 1024, 256), "outputs differ from a normal run's");
    assert!(temporaries(&data).is_empty());
}

// ---------------------------------------------------------------------------------------------
// Output names equal to the server's own file names.
// ---------------------------------------------------------------------------------------------

/// Three cameras named like the server's pass files (pass.png, pass.exr, pass.hdr), rendered in
/// passes: once the job is done every output of every frame downloads, equal to what the CLI
/// writes for that camera, and the outputs' folders hold the outputs and nothing else.
#[test]
fn image_names_like_the_pass_files_keep_their_outputs() {
    let _s = serial();
    let camera = |id: u32, name: &str| {
        format!(
            r#"<Camera id="{id}"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
<NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>32 32</ImageResolution>
<ImageName>{name}</ImageName></Camera>"#
        )
    };
    let scene = format!(
        r#"<Scene><Cameras>{}{}{}</Cameras>
<Lights><AmbientLight>20 20 20</AmbientLight><PointLight id="1"><Position>0 2 -2</Position><Intensity>40 40 40</Intensity></PointLight></Lights>
<Materials><Material id="1"><AmbientReflectance>1 1 1</AmbientReflectance><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
<VertexData>0 0 -5</VertexData><Objects><Sphere id="1"><Material>1</Material><Center>1</Center><Radius>1</Radius></Sphere></Objects></Scene>"#,
        camera(1, "pass.png"),
        camera(2, "pass.exr"),
        camera(3, "pass.hdr")
    );
    let dir = TempDir::new("durable-names");
    let scene_file = dir.write("names.xml", &scene);
    let data = TempDir::new("durable-names-data");
    let server = Server::start(&data, &ARGS);
    let _worker = Worker::start(&server.url, WORKER, "w");
    let (code, v) = submit(
        &server.url,
        None,
        &[
            ("scene", Some("names.xml"), scene.as_bytes()),
            ("tile_size", None, b"16"),
            ("samples", None, b"32"),
            ("pass_samples", None, b"16"),
        ],
    );
    assert_eq!(code, 201, "{v}");
    let id = v["id"].as_u64().unwrap();
    assert_eq!(v["frames"][0]["passes_total"], 2, "{v}");
    let done = wait_job(&server, id, 180, |j| j["state"] == "done");
    let files = downloads(&server, &done);
    let names =
        |k: usize| -> Vec<&str> { files.keys().filter(|(f, _)| *f == k).map(|(_, n)| n.as_str()).collect() };
    assert_eq!(names(0), ["pass.exr", "pass.png"]);
    assert_eq!(names(1), ["pass.exr", "pass.png"]);
    assert_eq!(names(2), ["pass.hdr", "pass.png"]);
    for k in 0..3 {
        let cli = cli_render(&scene_file, &["--samples", "32", "--camera", &(k + 1).to_string()]);
        let mut compared = 0;
        for e in std::fs::read_dir(&*cli).unwrap() {
            let name = e.unwrap().file_name().into_string().unwrap();
            let farm = files.get(&(k, name.clone())).unwrap_or_else(|| panic!("frame {k} has no {name}"));
            assert!(
                *farm == std::fs::read(cli.join(&name)).unwrap(),
                "frame {k}: {name} differs from the CLI's"
            );
            compared += 1;
        }
        assert!(compared > 0);
        // The outputs' folder holds the outputs only; the server's own files are elsewhere.
        let mut on_disk: Vec<String> = std::fs::read_dir(data.join(format!("outputs/{id}/{k}")))
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        on_disk.sort();
        assert_eq!(on_disk, names(k), "frame {k}");
    }
    // A finished frame's pass names serve its own files.
    let png = get_bytes(&server.url, &format!("/api/v1/jobs/{id}/frames/2/files/pass.png"));
    assert_eq!(png, files[&(2, "pass.png".to_string())]);
}

// ---------------------------------------------------------------------------------------------
// A lost job store.
// ---------------------------------------------------------------------------------------------

/// Every file under `dir`, by path, with its bytes.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut files = BTreeMap::new();
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            files.extend(snapshot(&p));
        } else {
            files.insert(p.clone(), std::fs::read(&p).unwrap());
        }
    }
    files
}

/// Runs the server on `data` expecting it to refuse to start: its exit status and stderr.
fn refused_start(data: &Path) -> (std::process::ExitStatus, String, String) {
    let mut child = Command::new(server_bin())
        .arg("--data-dir")
        .arg(data)
        .args(["--bind", "127.0.0.1:0"])
        .args(ARGS)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let out = drain_for(child.stdout.take().unwrap(), Duration::from_secs(30));
    let err = drain_for(child.stderr.take().unwrap(), Duration::from_secs(5));
    let status = wait_timeout(&mut child, Duration::from_secs(30)).unwrap_or_else(|| {
        let _ = child.kill();
        panic!("the server started on a lost job store: {out}\n{err}")
    });
    (status, out, err)
}

/// A `tessera.db` truncated to zero bytes, or overwritten with something that is not a
/// database, beside the outputs of earlier jobs: the server exits non-zero with a message that
/// says what happened and what to do, and the outputs and the store stay as they were. A store
/// restored from before the jobs whose folders are there starts, and its next job takes a new
/// folder instead of job 1's.
#[test]
fn a_lost_job_store_beside_earlier_outputs_is_a_refusal_to_start() {
    let _s = serial();
    let data = TempDir::new("durable-lost-db");
    {
        let server = Server::start(&data, &ARGS);
        let (code, v) = submit_tiny(&server.url, 64, 64, 64);
        assert_eq!(code, 201, "{v}");
        let worker = register(&server.url, 1);
        assert_eq!(upload(&server.url, worker, &lease(&server.url, worker)).0, 204);
        wait_job(&server, 1, 60, |j| j["state"] == "done");
    }
    let outputs = snapshot(&data.join("outputs"));
    assert!(!outputs.is_empty());
    let db = data.join("tessera.db");

    std::fs::OpenOptions::new().write(true).truncate(true).open(&db).unwrap();
    let (status, out, err) = refused_start(&data);
    assert!(!status.success(), "{status}");
    assert!(!out.contains("listening"), "{out}");
    for says in ["is empty", "restore", "backup", "move the data directory", "empty farm"] {
        assert!(err.to_lowercase().contains(says), "the refusal does not say {says:?}: {err}");
    }
    assert_eq!(std::fs::metadata(&db).unwrap().len(), 0, "the empty store was written to");
    assert_eq!(snapshot(&data.join("outputs")), outputs);

    std::fs::write(&db, vec![b'x'; 8192]).unwrap();
    let (status, _, err) = refused_start(&data);
    assert!(!status.success(), "{status}");
    assert!(err.contains("cannot be read") && err.contains("backup"), "{err}");
    assert_eq!(snapshot(&data.join("outputs")), outputs);

    // A store from before job 1 (a fresh one) in its place: the farm starts, and the next job
    // is job 2, in a folder of its own.
    let fresh = TempDir::new("durable-fresh-db");
    drop(Server::start(&fresh, &ARGS));
    for suffix in ["", "-wal", "-shm"] {
        let name = format!("tessera.db{suffix}");
        let _ = std::fs::remove_file(data.join(&name));
        if fresh.join(&name).exists() {
            std::fs::copy(fresh.join(&name), data.join(&name)).unwrap();
        }
    }
    let server = Server::start(&data, &ARGS);
    let (code, v) = submit_tiny(&server.url, 64, 64, 64);
    assert_eq!(code, 201, "{v}");
    assert_eq!(v["id"], 2, "a new job took the id of an existing output folder: {v}");
    let worker = register(&server.url, 1);
    assert_eq!(upload(&server.url, worker, &lease(&server.url, worker)).0, 204);
    wait_job(&server, 2, 60, |j| j["state"] == "done");
    let now = snapshot(&data.join("outputs"));
    assert!(outputs.iter().all(|(p, b)| now.get(p) == Some(b)), "job 1's outputs changed");
}
