//! The file store over HTTP with the real server (issue #71 item 2): a client asks which files
//! the server lacks and uploads only those; each file is stored once, checked against its
//! SHA-256 and the size cap; an upload that is wrong, too large or cut off leaves nothing;
//! finished jobs are deleted with their rows and folders; and the files and bundles no job
//! names are removed once past their grace.

mod support;

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime};

use serde_json::{Value, json};
use sha2::{Digest, Sha256};
use support::*;

const API: &str = "APITOK";
const WORKER: &str = "WTOK";

fn sha256(bytes: &[u8]) -> String {
    Sha256::digest(bytes).iter().map(|b| format!("{b:02x}")).collect()
}

/// A server with an API token and no local worker, on `data`.
fn start(data: &Path, extra: &[&str]) -> Server {
    let mut args = vec!["--api-token", API, "--worker-token", WORKER, "--local-workers", "0"];
    args.extend_from_slice(extra);
    Server::start(data, &args)
}

fn authed(req: ureq::Request) -> ureq::Request {
    req.set("Authorization", &format!("Bearer {API}"))
}

/// `POST /api/v1/files/missing` of (sha256, size) pairs.
fn missing(url: &str, files: &[(&str, u64)]) -> (u16, Value) {
    let body =
        json!({"files": files.iter().map(|(s, n)| json!({"sha256": s, "size": n})).collect::<Vec<_>>()});
    call(
        authed(ureq::post(&format!("{url}/api/v1/files/missing"))),
        Some(("application/json".into(), body.to_string().into_bytes())),
    )
}

/// `PUT /api/v1/files/SHA` with `bytes`.
fn put(url: &str, sha: &str, bytes: &[u8]) -> (u16, Value) {
    call(
        authed(ureq::put(&format!("{url}/api/v1/files/{sha}"))),
        Some(("application/octet-stream".into(), bytes.to_vec())),
    )
}

/// Every file under `dir` (recursively): its path relative to `dir`.
fn files_under(dir: &Path) -> Vec<String> {
    fn walk(dir: &Path, top: &Path, out: &mut Vec<String>) {
        for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
            let p = e.path();
            if p.is_dir() {
                walk(&p, top, out);
            } else {
                out.push(p.strip_prefix(top).unwrap().display().to_string());
            }
        }
    }
    let mut out = Vec::new();
    walk(dir, dir, &mut out);
    out.sort();
    out
}

/// Bytes of the files under `dir`, but SQLite's write-ahead log and its index (which keep their
/// size until the log starts over).
fn bytes_under(dir: &Path) -> u64 {
    files_under(dir)
        .iter()
        .filter(|p| !p.ends_with("-wal") && !p.ends_with("-shm"))
        .map(|p| std::fs::metadata(dir.join(p)).map_or(0, |m| m.len()))
        .sum()
}

/// Sets the modification time of `path` two hours back: past the store's one-hour grace.
fn age(path: &Path) {
    let two_hours_ago = SystemTime::now() - Duration::from_secs(7200);
    std::fs::File::open(path).unwrap().set_modified(two_hours_ago).unwrap();
}

fn stored_path(data: &Path, sha: &str) -> PathBuf {
    data.join("files").join(&sha[..2]).join(sha)
}

/// Missing, uploaded, no longer missing: each distinct file stored once, whatever the number of
/// times it is asked about or uploaded.
#[test]
fn missing_then_uploaded_then_stored_once() {
    let _serial = serial();
    let dir = TempDir::new("files-once");
    let data = dir.join("data");
    let server = start(&data, &[]);
    let ply: Vec<u8> = (0..(1u32 << 20)).map(|i| (i * 7 % 251) as u8).collect();
    let scene = br#"{"Scene": {}}"#.to_vec();
    let (a, b) = (sha256(&ply), sha256(&scene));
    let asked =
        [(a.as_str(), ply.len() as u64), (b.as_str(), scene.len() as u64), (a.as_str(), ply.len() as u64)];
    let (code, v) = missing(&server.url, &asked);
    assert_eq!(code, 200, "{v}");
    assert_eq!(v["missing"], json!([a, b]), "each once, in the order asked");
    let t = Instant::now();
    let (code, v) = put(&server.url, &a, &ply);
    eprintln!("a 1 MiB upload took {:.3} s", t.elapsed().as_secs_f64());
    assert_eq!(code, 201, "{v}");
    assert_eq!(v, json!({"sha256": a, "size": ply.len()}));
    // The same file again: checked, not written again.
    let (code, v) = put(&server.url, &a, &ply);
    assert_eq!(code, 200, "{v}");
    let (code, v) = missing(&server.url, &asked);
    assert_eq!((code, v["missing"].clone()), (200, json!([b])));
    assert_eq!(put(&server.url, &b, &scene).0, 201);
    let (code, v) = missing(&server.url, &asked);
    assert_eq!((code, v["missing"].clone()), (200, json!([])));
    // The same SHA-256 with another size is another file: missing.
    let (_, v) = missing(&server.url, &[(a.as_str(), 5)]);
    assert_eq!(v["missing"], json!([a]));
    let on_disk = files_under(&data.join("files"));
    assert_eq!(on_disk.len(), 2, "{on_disk:?}");
    assert_eq!(std::fs::read(stored_path(&data, &a)).unwrap(), ply);
    // Bad names: a clear 400 naming the field.
    let (code, v) = missing(&server.url, &[("ABC", 1)]);
    assert_eq!(code, 400, "{v}");
    assert!(v["error"].as_str().unwrap().contains("files[0].sha256"), "{v}");
    let (code, v) = put(&server.url, "..%2F..%2Fetc", b"x");
    assert_eq!(code, 400, "{v}");
    assert!(v["error"].as_str().unwrap().contains("not a SHA-256"), "{v}");
    // The routes are in the OpenAPI description.
    let spec = get_bytes(&server.url, "/api/v1/openapi.json");
    let spec: Value = serde_json::from_slice(&spec).unwrap();
    assert!(spec["paths"]["/api/v1/files/missing"]["post"].is_object());
    assert!(spec["paths"]["/api/v1/files/{sha256}"]["put"].is_object());
    assert!(spec["paths"]["/api/v1/jobs/{id}"]["delete"].is_object());
}

/// A body whose hash differs, or over the cap (declared or streamed), is refused and leaves
/// nothing; without the API token nothing is answered but 401.
#[test]
fn wrong_hash_too_large_or_no_token_stores_nothing() {
    let _serial = serial();
    let dir = TempDir::new("files-refused");
    let data = dir.join("data");
    // The file cap, not the (smaller) cap of a submission's body, bounds an upload to the store.
    let server = start(&data, &["--max-file-mb", "2", "--max-upload-mb", "1"]);
    let body = b"the real bytes".to_vec();
    let claimed = sha256(b"other bytes");
    let (code, v) = put(&server.url, &claimed, &body);
    assert_eq!(code, 400, "{v}");
    let e = v["error"].as_str().unwrap();
    assert!(e.contains(&claimed) && e.contains(&sha256(&body)) && e.contains("nothing was stored"), "{e}");
    // Over the cap, declared in Content-Length.
    let big = vec![1u8; (2 << 20) + 1];
    let (code, v) = put(&server.url, &sha256(&big), &big);
    assert_eq!(code, 413, "{v}");
    assert!(v["error"].as_str().unwrap().contains("--max-file-mb"), "{v}");
    // Over the cap, streamed without a length (chunked): found while reading.
    let sha = sha256(&big);
    let resp = authed(ureq::put(&format!("{}/api/v1/files/{sha}", server.url)))
        .send(std::io::Cursor::new(big.clone()));
    match resp {
        Err(ureq::Error::Status(code, r)) => {
            let v: Value = serde_json::from_str(&r.into_string().unwrap()).unwrap();
            assert_eq!(code, 413, "{v}");
            assert!(v["error"].as_str().unwrap().contains("--max-file-mb"), "{v}");
        }
        other => panic!("a chunked upload over the cap: {other:?}"),
    }
    // Exactly at the cap is fine, though over --max-upload-mb.
    let at_cap = vec![2u8; 2 << 20];
    assert_eq!(put(&server.url, &sha256(&at_cap), &at_cap).0, 201);
    // No token, a wrong token: 401, nothing stored.
    for auth in [None, Some("Bearer nope")] {
        let mut req = ureq::put(&format!("{}/api/v1/files/{}", server.url, sha256(&body)));
        if let Some(a) = auth {
            req = req.set("Authorization", a);
        }
        let (code, v) = call(req, Some(("application/octet-stream".into(), body.clone())));
        assert_eq!(code, 401, "{v}");
        let mut req = ureq::post(&format!("{}/api/v1/files/missing", server.url));
        if let Some(a) = auth {
            req = req.set("Authorization", a);
        }
        let (code, v) = call(req, Some(("application/json".into(), br#"{"files": []}"#.to_vec())));
        assert_eq!(code, 401, "{v}");
    }
    assert_eq!(files_under(&data.join("files")), [format!("{}/{}", &sha256(&at_cap)[..2], sha256(&at_cap))]);
}

/// `PUT` head and half of the body over a raw connection.
fn half_upload(url: &str, sha: &str, body: &[u8]) -> TcpStream {
    let addr = url.trim_start_matches("http://");
    let mut s = TcpStream::connect(addr).unwrap();
    let head = format!(
        "PUT /api/v1/files/{sha} HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {API}\r\n\
         Content-Type: application/octet-stream\r\nContent-Length: {}\r\n\r\n",
        body.len()
    );
    s.write_all(head.as_bytes()).unwrap();
    s.write_all(&body[..body.len() / 2]).unwrap();
    s.flush().unwrap();
    s
}

/// Polls `dir` until `done` holds for its files, for at most ten seconds.
fn wait_for_files(dir: &Path, what: &str, done: impl Fn(&[String]) -> bool) -> Vec<String> {
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let files = files_under(dir);
        if done(&files) {
            return files;
        }
        assert!(Instant::now() < deadline, "{what}: {files:?}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// An upload cut half-way leaves no file and no temporary file: a client that closes its
/// connection, and a server killed mid-upload (its temporary is swept at the next start).
#[test]
fn an_upload_cut_half_way_leaves_nothing() {
    let _serial = serial();
    let dir = TempDir::new("files-cut");
    let data = dir.join("data");
    let mut server = start(&data, &[]);
    let body: Vec<u8> = (0..(4u32 << 20)).map(|i| (i % 253) as u8).collect();
    let sha = sha256(&body);
    let store = data.join("files");
    // The client goes away half-way.
    let conn = half_upload(&server.url, &sha, &body);
    let half = wait_for_files(&store, "the upload's temporary file never appeared", |f| {
        f.iter().any(|n| n.ends_with(".tmp"))
    });
    eprintln!("half-way, the store holds {half:?}");
    drop(conn);
    wait_for_files(&store, "a cut upload left files", |f| f.is_empty());
    assert_eq!(missing(&server.url, &[(&sha, body.len() as u64)]).1["missing"], json!([sha]));
    // The server is killed half-way: its temporary file stays until the next start.
    let _conn = half_upload(&server.url, &sha, &body);
    wait_for_files(&store, "the upload's temporary file never appeared", |f| {
        f.iter().any(|n| n.ends_with(".tmp"))
    });
    server.kill9();
    assert!(files_under(&store).iter().any(|n| n.ends_with(".tmp")));
    drop(server);
    let server = start(&data, &[]);
    assert_eq!(
        files_under(&store),
        Vec::<String>::new(),
        "the temporary of a killed upload is swept at start"
    );
    assert!(server.log().contains("temporary file(s) of uploads"), "{}", server.log());
    // And the whole file goes in afterwards.
    assert_eq!(put(&server.url, &sha, &body).0, 201);
    assert_eq!(files_under(&store).len(), 1);
}

fn job(url: &str, id: u64) -> (u16, Value) {
    call(authed(ureq::get(&format!("{url}/api/v1/jobs/{id}"))), None)
}

fn delete(url: &str, id: u64) -> (u16, Value) {
    call(authed(ureq::delete(&format!("{url}/api/v1/jobs/{id}"))), None)
}

/// Submits the tiny scene at `size` pixels a side (multipart: its files go into a tar bundle).
fn submit_tiny(url: &str, size: u32) -> u64 {
    let scene = tessera_testkit::tiny_scene(size, size);
    let (code, v) =
        submit(url, Some(API), &[("scene", Some("tiny.xml"), &scene), ("tile_size", None, b"64")]);
    assert_eq!(code, 201, "{v}");
    v["id"].as_u64().unwrap()
}

/// A queued or running job is not deleted (409, saying to cancel it); a finished one goes with
/// its rows and folders, and its id is not handed out again.
#[test]
fn a_finished_job_is_deleted_with_its_rows_and_folders() {
    let _serial = serial();
    let dir = TempDir::new("files-delete");
    let data = dir.join("data");
    let server = start(&data, &[]);
    let running = submit_tiny(&server.url, 16);
    let (code, v) = delete(&server.url, running);
    assert_eq!(code, 409, "{v}");
    assert!(
        v["error"].as_str().unwrap().contains(&format!("cancel it first: tessera cancel {running}")),
        "{v}"
    );
    // Running: a worker holds a lease of it.
    let (code, v) =
        worker_post(&server.url, WORKER, "/api/v1/worker/register", json!({"name": "w", "threads": 1}));
    assert_eq!(code, 200, "{v}");
    let w = v["worker_id"].as_u64().unwrap();
    let (code, v) = worker_post(
        &server.url,
        WORKER,
        "/api/v1/worker/lease",
        json!({"worker_id": w, "wait_seconds": 0.0}),
    );
    assert_eq!(code, 200, "{v}");
    assert_eq!(job(&server.url, running).1["state"], "running");
    let (code, v) = delete(&server.url, running);
    assert_eq!(code, 409, "{v}");
    assert!(v["error"].as_str().unwrap().contains("is running"), "{v}");
    let (code, _) = call(
        authed(ureq::post(&format!("{}/api/v1/jobs/{running}/cancel", server.url))),
        Some(("text/plain".into(), vec![])),
    );
    assert_eq!(code, 200);
    // A done job: rendered by a real worker.
    let done = submit_tiny(&server.url, 48);
    let _worker = Worker::start(&server.url, WORKER, "real");
    let deadline = Instant::now() + Duration::from_secs(60);
    while job(&server.url, done).1["state"] != "done" {
        assert!(Instant::now() < deadline, "job {done} never finished\n{}", server.log());
        std::thread::sleep(Duration::from_millis(50));
    }
    let folders = [data.join("outputs").join(done.to_string()), data.join("frames").join(done.to_string())];
    let folder_bytes: u64 = folders.iter().map(|f| bytes_under(f)).sum();
    assert!(folders[0].is_dir() && folder_bytes > 0, "{folders:?}");
    let before = bytes_under(&data);
    let (code, v) = delete(&server.url, done);
    assert_eq!(code, 204, "{v}");
    let after = bytes_under(&data);
    eprintln!(
        "deleting job {done}: its folders held {folder_bytes} bytes; the data directory went from {before} to {after} bytes (the job store's log aside)"
    );
    assert!(folders.iter().all(|f| !f.exists()), "{folders:?}");
    assert!(after + folder_bytes <= before + 4096, "{before} -> {after}, folders {folder_bytes}");
    let (code, v) = job(&server.url, done);
    assert_eq!(code, 404, "{v}");
    assert_eq!(delete(&server.url, done).0, 404);
    let (code, v) = call(authed(ureq::get(&format!("{}/api/v1/jobs/{done}/log", server.url))), None);
    assert_eq!(code, 404, "{v}");
    // The cancelled job goes too; another job keeps its own id above both.
    assert_eq!(delete(&server.url, running).0, 204);
    let (_, list) = call(authed(ureq::get(&format!("{}/api/v1/jobs", server.url))), None);
    assert_eq!(list["jobs"], json!([]));
    let next = submit_tiny(&server.url, 8);
    assert!(next > done, "job {next} after deleting job {done}");
}

/// Files and bundles no job names are removed once past the grace (at start and every sweep);
/// those a job names, and young ones, stay.
#[test]
fn files_no_job_names_are_collected_after_the_grace() {
    let _serial = serial();
    let dir = TempDir::new("files-gc");
    let data = dir.join("data");
    let server = start(&data, &[]);
    let (old, young) = (b"an upload whose job never came".to_vec(), b"an upload just made".to_vec());
    assert_eq!(put(&server.url, &sha256(&old), &old).0, 201);
    assert_eq!(put(&server.url, &sha256(&young), &young).0, 201);
    let kept_job = submit_tiny(&server.url, 8);
    let gone_job = submit_tiny(&server.url, 9);
    assert_eq!(
        call(
            authed(ureq::post(&format!("{}/api/v1/jobs/{gone_job}/cancel", server.url))),
            Some(("text/plain".into(), vec![]))
        )
        .0,
        200
    );
    assert_eq!(delete(&server.url, gone_job).0, 204);
    // Each job's files (its scene and its manifest) are in the store: the deleted job's scene
    // and manifest are named by no job now, the kept job's are.
    let stored_before = files_under(&data.join("files"));
    drop(server);
    // Everything but the young upload two hours old: only what no job names goes.
    let young_name = format!("{}/{}", &sha256(&young)[..2], sha256(&young));
    for f in stored_before.iter().filter(|f| **f != young_name) {
        age(&data.join("files").join(f));
    }
    let server = start(&data, &[]);
    let deadline = Instant::now() + Duration::from_secs(10);
    while !server.log().contains("that no job names") {
        assert!(Instant::now() < deadline, "no collection logged\n{}", server.log());
        std::thread::sleep(Duration::from_millis(20));
    }
    let line = server.log().lines().find(|l| l.contains("that no job names")).unwrap().to_string();
    eprintln!("{line}");
    // The old upload, the deleted job's scene and its manifest.
    assert!(line.contains("removed 3 file(s)"), "{line}");
    let left = files_under(&data.join("files"));
    assert_eq!(left.len(), stored_before.len() - 3, "{stored_before:?} -> {left:?}");
    assert!(left.contains(&format!("{}/{}", &sha256(&young)[..2], sha256(&young))), "{left:?}");
    assert!(!left.contains(&format!("{}/{}", &sha256(&old)[..2], sha256(&old))), "{left:?}");
    // What is left of the job's own files still renders it.
    let (code, v) = job(&server.url, kept_job);
    assert_eq!((code, v["state"].as_str()), (200, Some("queued")), "{v}");
    let _worker = Worker::start(&server.url, WORKER, "w");
    let deadline = Instant::now() + Duration::from_secs(60);
    while job(&server.url, kept_job).1["state"] != "done" {
        assert!(Instant::now() < deadline, "job {kept_job} never finished\n{}", server.log());
        std::thread::sleep(Duration::from_millis(50));
    }
    // Asking about a file keeps it another grace: an old file asked about stays.
    let young_path = stored_path(&data, &sha256(&young));
    age(&young_path);
    let (_, v) = missing(&server.url, &[(&sha256(&young), young.len() as u64)]);
    assert_eq!(v["missing"], json!([]));
    let modified = std::fs::metadata(&young_path).unwrap().modified().unwrap();
    assert!(modified.elapsed().unwrap() < Duration::from_secs(60), "not touched");
    let mut buf = Vec::new();
    let _ = std::fs::File::open(&young_path).unwrap().read_to_end(&mut buf);
    assert_eq!(buf, young);
}

/// An upload that finds the disk full is a 507 that says so, names no server path and leaves
/// nothing (its temporary file goes, so the space is back for the next upload). Needs a small
/// filesystem (`support::small_fs`: root on Linux); skips where there is none.
#[test]
fn an_upload_on_a_full_disk_is_a_507_and_leaves_nothing() {
    use support::small_fs::*;
    let _serial = serial();
    if let Err(why) = small_fs_works() {
        return skip(&why);
    }
    let data = TempDir::new("files-full");
    let args = ["--api-token", API, "--worker-token", WORKER, "--local-workers", "0"];
    let server = Server::start_with(&data, &args, |cmd| on_small_fs(cmd, &data, 4));
    let root = as_server_sees(&server, &data);
    assert!(free_bytes(&root) < 5 << 20, "the data directory is not on the small filesystem");
    let big: Vec<u8> = (0..(6u32 << 20)).map(|i| (i % 249) as u8).collect();
    let (code, v) = put(&server.url, &sha256(&big), &big);
    assert_eq!(code, 507, "{v}\n{}", server.log());
    let said = v["error"].as_str().unwrap();
    let data_path = data.display().to_string();
    assert!(said.contains("disk is full") && said.contains("nothing was stored"), "{said}");
    assert!(!said.contains(&data_path) && !said.contains("/files"), "{said}");
    assert_eq!(files_under(&root.join("files")), Vec::<String>::new());
    let small = vec![3u8; 1 << 20];
    let (code, v) = put(&server.url, &sha256(&small), &small);
    assert_eq!(code, 201, "space is back once the cut upload is gone: {v}");
    assert_eq!(files_under(&root.join("files")).len(), 1);
}

/// A large upload is streamed to disk, not held in memory: the server's peak memory grows by
/// far less than the file.
#[test]
fn a_large_upload_is_streamed_to_disk() {
    let _serial = serial();
    let dir = TempDir::new("files-large");
    let data = dir.join("data");
    let server = start(&data, &[]);
    let big: Vec<u8> = (0..(96u32 << 20)).map(|i| (i.wrapping_mul(2654435761) >> 24) as u8).collect();
    let sha = sha256(&big);
    // The server's own start (and a first small request) before the peak is read.
    assert_eq!(missing(&server.url, &[(&sha, big.len() as u64)]).1["missing"], json!([sha]));
    let before = server.memory_kib("VmHWM");
    let t = Instant::now();
    let (code, v) = put(&server.url, &sha, &big);
    let seconds = t.elapsed().as_secs_f64();
    assert_eq!(code, 201, "{v}");
    let grew = server.memory_kib("VmHWM").saturating_sub(before);
    eprintln!(
        "a 96 MiB upload took {seconds:.2} s ({:.0} MiB/s); the server's peak memory grew by {} KiB",
        96.0 / seconds,
        grew
    );
    assert!(grew < 24 << 10, "the server's peak memory grew by {grew} KiB for a 96 MiB upload");
    assert_eq!(std::fs::metadata(stored_path(&data, &sha)).unwrap().len(), big.len() as u64);
}

/// `tessera delete ID` deletes a finished job (and says what a running one needs).
#[test]
fn the_client_deletes_a_finished_job() {
    let _serial = serial();
    let dir = TempDir::new("files-client-delete");
    let server = start(&dir.join("data"), &[]);
    let id = submit_tiny(&server.url, 16);
    let client = |args: &[&str]| {
        std::process::Command::new(client_bin())
            .args(args)
            .env("TESSERA_SERVER", &server.url)
            .env("TESSERA_TOKEN", API)
            .output()
            .expect("run tessera")
    };
    let refused = client(&["delete", &id.to_string()]);
    assert!(!refused.status.success());
    let said = String::from_utf8_lossy(&refused.stderr);
    assert!(said.contains(&format!("tessera cancel {id}")), "{said}");
    assert!(client(&["cancel", &id.to_string()]).status.success());
    let deleted = client(&["delete", &id.to_string()]);
    assert!(deleted.status.success(), "{}", String::from_utf8_lossy(&deleted.stderr));
    assert!(String::from_utf8_lossy(&deleted.stdout).contains("deleted"));
    assert_eq!(job(&server.url, id).0, 404);
}
