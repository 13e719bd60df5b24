//! Sequences end to end: several scene files submitted once are one job, whose frames are
//! leased in order, rendered by real workers fetching the job's files by SHA-256, and equal to
//! what `tessera-worker render` writes for each scene. The real binaries over loopback, on
//! tiny hand-written scenes sharing one PLY.

mod support;

use std::path::Path;
use std::process::{Command, Stdio};

use serde_json::{Value, json};
use support::*;

/// A small mesh every frame shares: a tetrahedron.
const PLY: &str = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n\
element face 4\nproperty list uchar int vertex_indices\nend_header\n\
-1 -1 -1\n1 -1 -1\n0 1 -1\n0 -0.3 0.6\n3 0 1 2\n3 0 1 3\n3 1 2 3\n3 2 0 3\n";

/// Frame `k` of a sequence: the camera moves along x, `size` pixels square at `spp` samples.
/// Its image is `image` (default `frame_KKK.png`) and its mesh `mesh` (relative to the scene).
fn scene(k: usize, size: u32, spp: u32, image: Option<&str>, mesh: &str) -> String {
    let x = -1.0 + 0.05 * k as f64;
    let image = image.map_or_else(|| format!("frame_{k:03}.png"), str::to_string);
    format!(
        r#"<Scene>
  <MaxRecursionDepth>2</MaxRecursionDepth>
  <BackgroundColor>10 20 30</BackgroundColor>
  <Cameras><Camera id="1"><Position>{x} 0 4</Position><Gaze>{gx} 0 -1</Gaze><Up>0 1 0</Up>
    <NearPlane>-1 1 -1 1</NearPlane><NearDistance>2</NearDistance><ImageResolution>{size} {size}</ImageResolution>
    <NumSamples>{spp}</NumSamples><ImageName>{image}</ImageName></Camera></Cameras>
  <Lights><AmbientLight>20 20 20</AmbientLight>
    <PointLight id="1"><Position>2 3 4</Position><Intensity>4000 4000 4000</Intensity></PointLight></Lights>
  <Materials><Material id="1"><AmbientReflectance>0.2 0.2 0.2</AmbientReflectance>
    <DiffuseReflectance>0.8 0.5 0.3</DiffuseReflectance><SpecularReflectance>0 0 0</SpecularReflectance></Material></Materials>
  <Objects><Mesh id="1"><Material>1</Material><Faces plyFile="{mesh}"/></Mesh></Objects>
</Scene>
"#,
        gx = -0.1 * x,
    )
}

/// A sequence of `n` frames on disk (`seq/frame_KKK.xml` naming `../ply/shape.ply`), its files
/// as multipart parts (path, bytes) in frame order, the PLY last.
fn sequence(dir: &Path, n: usize, size: u32, spp: u32) -> Vec<(String, Vec<u8>)> {
    std::fs::create_dir_all(dir.join("seq")).unwrap();
    std::fs::create_dir_all(dir.join("ply")).unwrap();
    std::fs::write(dir.join("ply/shape.ply"), PLY).unwrap();
    let mut files = Vec::new();
    for k in 0..n {
        let path = format!("seq/frame_{k:03}.xml");
        let text = scene(k, size, spp, None, "../ply/shape.ply");
        std::fs::write(dir.join(&path), &text).unwrap();
        files.push((path, text.into_bytes()));
    }
    files.push(("ply/shape.ply".into(), PLY.as_bytes().to_vec()));
    files
}

/// Submits `files` as one multipart job: each `.xml` a `scene` field (in order), the rest
/// `asset`s, with `extra` text fields.
fn submit_sequence(server: &Server, files: &[(String, Vec<u8>)], extra: &[(&str, &str)]) -> (u16, Value) {
    let mut parts: Vec<(&str, Option<&str>, &[u8])> = files
        .iter()
        .map(|(p, b)| (if p.ends_with(".xml") { "scene" } else { "asset" }, Some(p.as_str()), b.as_slice()))
        .collect();
    parts.extend(extra.iter().map(|(k, v)| (*k, None, v.as_bytes())));
    submit(&server.url, None, &parts)
}

/// `tessera-worker render` of every scene of `dir/seq` (one process each), into one folder.
fn cli_render_all(dir: &Path, n: usize) -> TempDir {
    let out = TempDir::new("seq-cli");
    for k in 0..n {
        let status = Command::new(worker_bin())
            .arg("render")
            .arg(dir.join(format!("seq/frame_{k:03}.xml")))
            .args(["--quiet", "--out"])
            .arg(out.path())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .unwrap();
        assert!(status.success(), "tessera-worker render of frame {k} failed");
    }
    out
}

/// The frames of the job's `frame_merged` events, in the log's order.
fn merged_order(server: &Server, id: u64) -> Vec<u64> {
    let log = get_json(&server.url, &format!("/api/v1/jobs/{id}/log"));
    log["events"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["kind"] == "frame_merged")
        .map(|e| e["frame"].as_u64().unwrap())
        .collect()
}

/// The mean seconds between two frames merged, and the mean of the frames' render seconds as
/// the worker measured them (`tile_done`).
fn frame_costs(server: &Server, id: u64) -> (f64, f64) {
    let log = get_json(&server.url, &format!("/api/v1/jobs/{id}/log"));
    let events = log["events"].as_array().unwrap();
    let at = |kind: &str| -> Vec<f64> {
        events.iter().filter(|e| e["kind"] == kind).map(|e| e["at"].as_f64().unwrap()).collect()
    };
    let merged = at("frame_merged");
    let renders: Vec<f64> =
        events.iter().filter(|e| e["kind"] == "tile_done").filter_map(|e| e["seconds"].as_f64()).collect();
    let span = merged.last().unwrap() - merged.first().unwrap();
    (span / (merged.len() - 1) as f64, renders.iter().sum::<f64>() / renders.len() as f64)
}

/// Files in the server's file store (`DATA/files/xx/<sha256>`).
fn stored_files(data: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    let Ok(folders) = std::fs::read_dir(data.join("files")) else { return out };
    for d in folders {
        let d = d.unwrap().path();
        if d.is_dir() {
            for f in std::fs::read_dir(&d).unwrap() {
                let f = f.unwrap().path();
                if f.file_name().unwrap().len() == 64 {
                    out.push(f);
                }
            }
        }
    }
    out
}

#[test]
fn a_sequence_submitted_once_is_one_job_rendered_in_order_like_the_cli() {
    let _s = serial();
    let dir = TempDir::new("seq-scenes");
    let n = 40;
    let files = sequence(&dir, n, 16, 4);
    let data = TempDir::new("seq-data");
    let server = Server::start(&data, &["--local-workers", "1", "--local-worker-threads", "1"]);
    let (code, job) = submit_sequence(&server, &files, &[]);
    assert_eq!(code, 201, "{job}\n{}", server.log());
    let id = job["id"].as_u64().unwrap();
    assert_eq!(job["scenes"], n as u64, "{job}");
    assert_eq!(job["frames"].as_array().unwrap().len(), n);
    // Small frames are one tile each (no tile_size asked).
    assert!(job["frames"].as_array().unwrap().iter().all(|f| f["tiles_total"] == 1), "{job}");
    let job = wait_job(&server, id, 120, |j| j["state"] == "done");
    assert_eq!(job["frame_counts"], json!({"done": n, "rendering": 0, "queued": 0}), "{job}");
    for (k, f) in job["frames"].as_array().unwrap().iter().enumerate() {
        assert_eq!(f["scene"], format!("seq/frame_{k:03}.xml"), "{f}");
        let names: Vec<&str> =
            f["outputs"].as_array().unwrap().iter().map(|o| o["name"].as_str().unwrap()).collect();
        // A sequence keeps no float frame beside its PNGs unless asked (keep_float=true).
        assert_eq!(names, [format!("frame_{k:03}.png")], "{f}");
    }
    // One local worker of one thread: the frames were merged in frame order.
    assert_eq!(merged_order(&server, id), (0..n as u64).collect::<Vec<_>>());
    // What a frame costs the farm besides its pixels (lease, scene, upload, merge), from the
    // log: the time from one frame merged to the next, less the next one's render.
    let (per_frame, render) = frame_costs(&server, id);
    eprintln!(
        "{n} frames of 16 x 16 at 4 spp: one every {:.1} ms, of which {:.1} ms rendering (worker's measure)",
        per_frame * 1e3,
        render * 1e3
    );
    // The worker built the shared PLY mesh once: every later frame took it from its cache.
    let log = server.log();
    let built: Vec<&str> = log.lines().filter(|l| l.contains(&format!("job {id}: seq/frame_"))).collect();
    assert_eq!(built.len(), n, "one build a frame:\n{log}");
    let from_cache = built.iter().filter(|l| l.contains("(1 mesh(es) from the cache")).count();
    assert_eq!(
        from_cache,
        n - 1,
        "every frame after the first takes its mesh from the cache:\n{}",
        built.join("\n")
    );
    // Every frame is the CLI's, to the byte.
    let cli = cli_render_all(&dir, n);
    assert_job_outputs_equal_cli(&server, &job, &cli);
    // Each distinct file stored once: the 40 scenes, the shared PLY and the manifest.
    assert_eq!(stored_files(&data).len(), n + 2, "{:?}", stored_files(&data));
    // The job list summarises a job of more than 32 frames; its own GET lists them all.
    let list = get_json(&server.url, "/api/v1/jobs");
    assert_eq!(list["jobs"][0]["frames"], json!([]), "{}", list["jobs"][0]);
    assert_eq!(list["jobs"][0]["frame_counts"]["done"], n as u64);
}

#[test]
fn a_json_job_names_stored_files_and_one_the_server_lacks_is_a_409() {
    let _s = serial();
    let dir = TempDir::new("seq-json");
    let n = 3;
    let files = sequence(&dir, n, 12, 2);
    let data = TempDir::new("seq-json-data");
    let server = Server::start(&data, &["--local-workers", "1", "--local-worker-threads", "1"]);
    // A first job (multipart) puts the files in the store, asking for the float frames too.
    let (code, first) = submit_sequence(&server, &files, &[("keep_float", "true"), ("video", "none")]);
    assert_eq!(code, 201, "{first}");
    let first_id = first["id"].as_u64().unwrap();
    let first = wait_job(&server, first_id, 60, |j| j["state"] == "done");
    assert_eq!(first["frames"][0]["outputs"].as_array().unwrap().len(), 2, "keep_float=true: {first}");
    // The kept float frame is an OpenEXR file (ZIP-compressed; the PNG is the CLI's).
    let exr = get_bytes(&server.url, &format!("/api/v1/jobs/{first_id}/frames/1/files/frame_001.exr"));
    assert!(exr.starts_with(&[0x76, 0x2f, 0x31, 0x01]), "not an OpenEXR file");
    let digest = |b: &[u8]| {
        use sha2::Digest;
        sha2::Sha256::digest(b).iter().map(|x| format!("{x:02x}")).collect::<String>()
    };
    let mut listed: Vec<Value> =
        files.iter().map(|(p, b)| json!({"path": p, "sha256": digest(b), "size": b.len()})).collect();
    let scenes: Vec<&str> =
        files.iter().filter(|(p, _)| p.ends_with(".xml")).map(|(p, _)| p.as_str()).collect();
    let post = |body: &Value| {
        call(
            ureq::post(&format!("{}/api/v1/jobs", server.url)),
            Some(("application/json".into(), body.to_string().into_bytes())),
        )
    };
    // A file the server never got: 409 naming it, nothing queued.
    let extra = b"not uploaded".to_vec();
    listed.push(json!({"path": "ply/extra.ply", "sha256": digest(&extra), "size": extra.len()}));
    let (code, e) = post(&json!({"scenes": scenes, "files": listed}));
    assert_eq!(code, 409, "{e}");
    let text = e["error"].as_str().unwrap();
    assert!(
        text.contains("ply/extra.ply")
            && text.contains(&digest(&extra))
            && text.contains("PUT /api/v1/files/"),
        "{e}"
    );
    assert_eq!(e["problems"][0]["file"], "ply/extra.ply", "{e}");
    listed.pop();
    // Bad requests: a path twice, a bad hash, a scene not among the files, an unknown field.
    let mut twice = listed.clone();
    twice.push(listed[0].clone());
    let (code, e) = post(&json!({"scenes": scenes, "files": twice}));
    assert!(code == 400 && e["error"].as_str().unwrap().contains("given twice"), "{code} {e}");
    let (code, e) = post(&json!({"scenes": ["seq/none.xml"], "files": listed}));
    assert!(code == 400 && e["error"].as_str().unwrap().contains("seq/none.xml"), "{code} {e}");
    let (code, e) = post(&json!({"scenes": scenes, "files": listed, "fps": 0}));
    assert!(code == 400 && e["error"].as_str().unwrap().contains("fps"), "{code} {e}");
    let (code, e) = post(&json!({"scenes": scenes, "files": listed, "colour": 1}));
    assert!(code == 400 && e["error"].as_str().unwrap().contains("colour"), "{code} {e}");
    let jobs = get_json(&server.url, "/api/v1/jobs")["jobs"].as_array().unwrap().len();
    assert_eq!(jobs, 1, "a refused request stored a job");
    // Every file stored: a second job of the same files is accepted and renders the same bytes.
    let (code, second) =
        post(&json!({"scenes": scenes, "files": listed, "name": "again", "fps": 24, "video": "gif"}));
    assert_eq!(code, 201, "{second}");
    let id = second["id"].as_u64().unwrap();
    let second = wait_job(&server, id, 60, |j| j["state"] == "done");
    for k in 0..n {
        let name = format!("frame_{k:03}.png");
        let a = get_bytes(&server.url, &format!("/api/v1/jobs/{first_id}/frames/{k}/files/{name}"));
        let b = get_bytes(&server.url, &format!("/api/v1/jobs/{id}/frames/{k}/files/{name}"));
        assert!(a == b, "frame {k} differs between the two jobs");
    }
    // The second job did not ask for the float frames: a sequence keeps only its PNGs by default.
    assert_eq!(second["frames"][0]["outputs"].as_array().unwrap().len(), 1, "{second}");
    // Both jobs share the stored files: 3 scenes, the PLY, one manifest.
    assert_eq!(stored_files(&data).len(), n + 2);
}

#[test]
fn bad_sequences_are_refused_naming_the_frame_and_scene_and_nothing_is_stored() {
    let _s = serial();
    let dir = TempDir::new("seq-bad");
    let mut files = sequence(&dir, 6, 8, 1);
    let data = TempDir::new("seq-bad-data");
    let server =
        Server::start(&data, &["--local-workers", "0", "--max-job-frames", "5", "--worker-token", "wtok"]);
    // Six frames on a server of at most five a job.
    let (code, e) = submit_sequence(&server, &files, &[]);
    assert_eq!(code, 422, "{e}");
    assert!(e["error"].as_str().unwrap().contains("--max-job-frames"), "{e}");
    files.remove(5);
    // Frame 3 names a PLY the job does not have.
    files[3].1 = scene(3, 8, 1, None, "../ply/missing.ply").into_bytes();
    let (code, e) = submit_sequence(&server, &files, &[]);
    assert_eq!(code, 422, "{e}");
    let text = e["error"].as_str().unwrap();
    assert!(
        text.contains("frame 3 (seq/frame_003.xml)") && text.contains("ply/missing.ply"),
        "the error names the frame, its scene and the missing file: {e}"
    );
    // Frames 1 and 4 write the same image.
    files[3].1 = scene(3, 8, 1, None, "../ply/shape.ply").into_bytes();
    files[4].1 = scene(4, 8, 1, Some("frame_001.png"), "../ply/shape.ply").into_bytes();
    let (code, e) = submit_sequence(&server, &files, &[]);
    assert_eq!(code, 422, "{e}");
    let text = e["error"].as_str().unwrap();
    assert!(
        text.contains("frames 1 (seq/frame_001.xml) and 4 (seq/frame_004.xml")
            && text.contains("frame_001.png"),
        "{e}"
    );
    // A bad option.
    let (code, e) = submit_sequence(&server, &files, &[("video", "avi")]);
    assert!(code == 400 && e["error"].as_str().unwrap().contains("video"), "{code} {e}");
    // Nothing of any refusal was kept: no job, no file.
    assert_eq!(get_json(&server.url, "/api/v1/jobs")["jobs"], json!([]));
    assert!(stored_files(&data).is_empty(), "{:?}", stored_files(&data));
    // Fixed, it is accepted; a scenes field names the same sequence in another order.
    files[4].1 = scene(4, 8, 1, None, "../ply/shape.ply").into_bytes();
    let assets: Vec<(&str, Option<&str>, &[u8])> =
        files.iter().map(|(p, b)| ("asset", Some(p.as_str()), b.as_slice())).collect();
    let mut parts = assets.clone();
    parts.push(("scenes", None, b"seq/frame_004.xml\nseq/frame_000.xml, seq/frame_002.xml"));
    let (code, job) = submit(&server.url, None, &parts);
    assert_eq!(code, 201, "{job}");
    let scenes: Vec<&str> =
        job["frames"].as_array().unwrap().iter().map(|f| f["scene"].as_str().unwrap()).collect();
    assert_eq!(scenes, ["seq/frame_004.xml", "seq/frame_000.xml", "seq/frame_002.xml"]);
    assert_eq!(job["frame_counts"], json!({"done": 0, "rendering": 0, "queued": 3}));
    // Workers fetch the job's files by SHA-256 with the worker token, as stored.
    let fetch = |sha: &str, token: Option<&str>| {
        let mut req = ureq::get(&format!("{}/api/v1/worker/files/{sha}", server.url));
        if let Some(t) = token {
            req = req.set("Authorization", &format!("Bearer {t}"));
        }
        match req.call() {
            Ok(r) => {
                let mut body = Vec::new();
                std::io::Read::read_to_end(&mut r.into_reader(), &mut body).unwrap();
                (200, body)
            }
            Err(ureq::Error::Status(code, _)) => (code, Vec::new()),
            Err(e) => panic!("{e}"),
        }
    };
    let ply = {
        use sha2::Digest;
        sha2::Sha256::digest(PLY.as_bytes()).iter().map(|x| format!("{x:02x}")).collect::<String>()
    };
    assert_eq!(fetch(&ply, Some("wtok")), (200, PLY.as_bytes().to_vec()));
    assert_eq!(fetch(&ply, None).0, 401);
    assert_eq!(fetch(&"0".repeat(64), Some("wtok")).0, 404);
    assert_eq!(fetch("..%2F..%2Ftessera.db", Some("wtok")).0, 404);
}

/// A sequence of `n` frames of `size` px at `spp` submitted (with `extra` fields) to a server
/// with one local worker of `threads` threads, the server killed with kill -9 once two frames
/// are done and started again on the same data and port: no frame finished before the kill is
/// lost, and the job ends with every frame the CLI's bytes. The data directory and the second
/// server, for more checks.
fn sequence_survives_the_server_killed(
    name: &str,
    (n, size, spp): (usize, u32, u32),
    threads: &str,
    extra: &[(&str, &str)],
) -> (TempDir, Server) {
    let dir = TempDir::new(name);
    let files = sequence(&dir, n, size, spp);
    let data = TempDir::new(&format!("{name}-data"));
    let args = ["--local-workers", "1", "--local-worker-threads", threads];
    let mut server = Server::start(&data, &args);
    let port = server.url.rsplit(':').next().unwrap().to_string();
    let (code, job) = submit_sequence(&server, &files, extra);
    assert_eq!(code, 201, "{job}");
    let id = job["id"].as_u64().unwrap();
    let before = wait_job(&server, id, 120, |j| j["frame_counts"]["done"].as_u64().unwrap() >= 2);
    server.kill9();
    let done_before: Vec<usize> = before["frames"]
        .as_array()
        .unwrap()
        .iter()
        .enumerate()
        .filter(|(_, f)| !f["outputs"].as_array().unwrap().is_empty())
        .map(|(k, _)| k)
        .collect();
    assert!(done_before.len() < n, "the job ended before the server was killed; make its frames slower");
    let bind = format!("127.0.0.1:{port}");
    let mut args2 = args.to_vec();
    args2.extend(["--bind", &bind]);
    let server = Server::start(&data, &args2);
    let after = get_json(&server.url, &format!("/api/v1/jobs/{id}"));
    for &k in &done_before {
        assert!(!after["frames"][k]["outputs"].as_array().unwrap().is_empty(), "frame {k} was lost: {after}");
    }
    let job = wait_job(&server, id, 180, |j| j["state"] == "done");
    let cli = cli_render_all(&dir, n);
    assert_job_outputs_equal_cli(&server, &job, &cli);
    (data, server)
}

#[test]
fn killing_the_server_mid_sequence_loses_no_finished_frame() {
    let _s = serial();
    sequence_survives_the_server_killed("seq-kill", (30, 40, 16), "1", &[]);
}

/// Frames of 300x300 send results of more than 1 MiB, which the server keeps as files in
/// `results/` until their frame is merged (server/src/db/results.rs): a server killed while
/// some are stored and not merged loses none, and leaves no file behind once the job is done.
#[test]
fn killing_the_server_while_results_are_files_loses_no_frame_and_leaves_no_file() {
    let _s = serial();
    let (data, server) =
        sequence_survives_the_server_killed("seq-kill-files", (16, 300, 1), "2", &[("video", "none")]);
    // Every result file went with the merge of its frame (or with the sweep of those a kill
    // left unnamed).
    let results = data.path().join("results");
    assert!(results.is_dir(), "no result was stored as a file: the test's frames are too small");
    let left: Vec<_> = std::fs::read_dir(&results).unwrap().map(|e| e.unwrap().path()).collect();
    assert!(left.is_empty(), "result files left after the job: {left:?}\n{}", server.log());
}

#[test]
fn killing_a_worker_mid_sequence_loses_no_finished_frame() {
    let _s = serial();
    let dir = TempDir::new("seq-kill-worker");
    let n = 30;
    let files = sequence(&dir, n, 40, 16);
    let server = Server::start_temp(
        "seq-kill-worker-data",
        &[
            "--local-workers",
            "0",
            "--worker-token",
            "wtok",
            "--lease-seconds",
            "2",
            "--heartbeat-seconds",
            "0.5",
        ],
    );
    let (code, job) = submit_sequence(&server, &files, &[]);
    assert_eq!(code, 201, "{job}");
    let id = job["id"].as_u64().unwrap();
    let mut first = Worker::start(&server.url, "wtok", "first");
    let before = wait_job(&server, id, 120, |j| j["frame_counts"]["done"].as_u64().unwrap() >= 3);
    first.kill9();
    let done_before: Vec<(usize, Value)> = before["frames"]
        .as_array()
        .unwrap()
        .iter()
        .enumerate()
        .filter(|(_, f)| !f["outputs"].as_array().unwrap().is_empty())
        .map(|(k, f)| (k, f["outputs"].clone()))
        .collect();
    assert!(done_before.len() < n, "the job ended before the worker was killed; make its frames slower");
    // Another worker takes over (the killed one's lease expires); the merged frames stay as they were.
    let _second = Worker::start(&server.url, "wtok", "second");
    let job = wait_job(&server, id, 180, |j| j["state"] == "done");
    for (k, outputs) in &done_before {
        assert_eq!(&job["frames"][*k]["outputs"], outputs, "frame {k} changed after the kill");
    }
    let cli = cli_render_all(&dir, n);
    assert_job_outputs_equal_cli(&server, &job, &cli);
}
