//! `tessera submit a_*.json` as one job: a sequence of scene files sent by content, against a
//! real `tessera-server` and `tessera-worker work` over loopback HTTP. The frames are the CLI's
//! bytes, the PLY every frame shares is uploaded and stored once (the client's summary counts
//! the bytes it PUT, the server's file store holds one copy), a second sequence with the same
//! PLY uploads none of it, and a frame naming a missing PLY is refused before any upload.
//!
//! A stand-in server (answering scripted JSON, recording the requests) checks what needs an
//! older server or a long job: the multipart fallback, the sequence refused by a server without
//! content-addressed files, and `status` of a long sequence by its frame counts.

mod support;

use std::io::{BufRead, BufReader, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use serde_json::{Value, json};
use support::*;

const MINUTE: Duration = Duration::from_secs(60);

/// A PLY grid of `n` x `n` quads (2 n^2 triangles) in front of the camera, ASCII.
fn grid_ply(n: usize) -> String {
    let mut s = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        (n + 1) * (n + 1),
        2 * n * n
    );
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as f64 / n as f64 * 2.0 - 1.0, j as f64 / n as f64 * 2.0 - 1.0);
            s.push_str(&format!("{x:.5} {y:.5} {:.5}\n", -3.0 - 0.2 * (x * 3.0).sin() * (y * 2.0).cos()));
        }
    }
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i;
            s.push_str(&format!("3 {a} {} {}\n3 {a} {} {}\n", a + 1, a + n + 2, a + n + 2, a + n + 1));
        }
    }
    s
}

/// Frame `k` of a little orbit: a 16x16 camera looking at a mesh from `ply` (as the scene
/// names it), writing `name_k.png`.
fn frame_xml(k: usize, name: &str, ply: &str) -> String {
    let a = k as f64 * 0.05;
    format!(
        r#"<Scene>
<Cameras><Camera id="1"><Position>{:.4} 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
<NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>16 16</ImageResolution>
<ImageName>{name}_{k:03}.png</ImageName></Camera></Cameras>
<Lights><AmbientLight>40 40 40</AmbientLight><PointLight id="1"><Position>0 2 0</Position><Intensity>900 900 900</Intensity></PointLight></Lights>
<Materials><Material id="1"><AmbientReflectance>1 1 1</AmbientReflectance><DiffuseReflectance>0.8 0.6 0.4</DiffuseReflectance></Material></Materials>
<Objects><Mesh id="1"><Material>1</Material><Faces plyFile="{ply}"/></Mesh></Objects>
</Scene>"#,
        a.sin() * 0.5
    )
}

/// `count` frames in `dir/input/NAME_KKK.xml` naming `../ply/shared.ply` (written too).
fn sequence(dir: &Path, name: &str, count: usize, ply: &str) -> Vec<PathBuf> {
    std::fs::create_dir_all(dir.join("input")).unwrap();
    std::fs::create_dir_all(dir.join("ply")).unwrap();
    std::fs::write(dir.join("ply/shared.ply"), ply).unwrap();
    (0..count)
        .map(|k| {
            let p = dir.join(format!("input/{name}_{k:03}.xml"));
            std::fs::write(&p, frame_xml(k, name, "../ply/shared.ply")).unwrap();
            p
        })
        .collect()
}

/// The client's summary "uploaded N of M files, X bytes": (N, M, X).
fn uploaded(stderr: &str) -> (usize, usize, u64) {
    let line =
        stderr.lines().find(|l| l.starts_with("uploaded ")).unwrap_or_else(|| panic!("no summary: {stderr}"));
    let w: Vec<&str> = line.split_whitespace().collect();
    (w[1].parse().unwrap(), w[3].parse().unwrap(), w[5].parse().unwrap())
}

/// Every regular file of the server's file store (`DATA/files/<2 hex>/<sha256>`), by name.
fn stored(data: &Path) -> Vec<(String, u64)> {
    let mut out = Vec::new();
    let Ok(dirs) = std::fs::read_dir(data.join("files")) else { return out };
    for d in dirs.flatten() {
        let Ok(files) = std::fs::read_dir(d.path()) else { continue };
        for f in files.flatten() {
            let m = f.metadata().unwrap();
            if m.is_file() {
                out.push((f.file_name().to_string_lossy().into_owned(), m.len()));
            }
        }
    }
    out.sort();
    out
}

fn sha256_hex(path: &Path) -> String {
    use sha2::Digest;
    format!("{:x}", sha2::Sha256::digest(std::fs::read(path).unwrap()))
}

/// 24 frames submitted once are one job whose frames are the CLI's bytes, followed by its frame
/// counts, with a video; the shared PLY is uploaded and stored once, and a second sequence
/// with the same PLY (elsewhere on disk) uploads none of it.
#[test]
fn a_sequence_is_one_job_and_its_shared_ply_is_sent_once() {
    let _serial = serial();
    let server = Server::start("client-seq", &[]);
    let _worker = Worker::start(&server.url, "w1");
    let home = TempDir::new("client-seq-home");
    let dir = TempDir::new("client-seq");
    let ply = grid_ply(40);
    let scenes = sequence(&dir.join("orbit"), "orbit", 24, &ply);
    let ply_path = dir.join("orbit/ply/shared.ply");
    let ply_size = ply.len() as u64;
    let scene_bytes: u64 = scenes.iter().map(|s| std::fs::metadata(s).unwrap().len()).sum();

    let farm = dir.join("farm");
    let out = run(
        client(&home)
            .env("TESSERA_SERVER", &server.url)
            .arg("submit")
            .args(&scenes)
            .args(["--verbose", "--fps", "12", "--wait", "--out"])
            .arg(&farm),
        Duration::from_secs(300),
    );
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(out.status.success(), "{stdout}\n{stderr}\n{}", server.log());
    eprintln!("{stderr}");
    assert_eq!(uploaded(&stderr), (25, 25, scene_bytes + ply_size), "{stderr}");
    assert!(stdout.contains("submitted job 1 ") && stdout.contains(": 24 frame(s)"), "{stdout}");
    // Followed by its counts, not a line a frame.
    assert!(!stderr.contains("frame 3 "), "{stderr}");

    // One job of 24 frames in the order given, each from its scene file.
    let job = server.get_json("/api/v1/jobs/1", None);
    assert_eq!(job["state"], "done", "{job}");
    assert_eq!(job["scenes"], 24, "{job}");
    assert_eq!(job["frame_counts"], json!({"done": 24, "rendering": 0, "queued": 0}), "{job}");
    let frames = job["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 24);
    for (k, f) in frames.iter().enumerate() {
        assert_eq!(f["image_name"], format!("orbit_{k:03}.png"), "{f}");
        assert_eq!(f["scene"], format!("input/orbit_{k:03}.xml"), "{f}");
    }
    assert_eq!(server.get_json("/api/v1/jobs", None)["jobs"].as_array().unwrap().len(), 1);

    // The PLY is stored once.
    let store = stored(&server.data);
    let sha = sha256_hex(&ply_path);
    assert_eq!(store.iter().filter(|(n, _)| *n == sha).count(), 1, "{store:?}");
    assert_eq!(store.iter().filter(|(_, size)| *size == ply_size).count(), 1, "{store:?}");

    // Every frame is the CLI's bytes; the video came down beside them.
    let cli = dir.join("cli");
    for s in &scenes {
        cli_render(s, &cli, &[]);
    }
    let want = files_under(&cli);
    let mut got = files_under(&farm);
    let video = job["video"].clone();
    let video_name = video["url"]
        .as_str()
        .unwrap_or_else(|| panic!("no video: {job}"))
        .rsplit('/')
        .next()
        .unwrap()
        .to_string();
    let at = got
        .iter()
        .position(|(n, _)| *n == video_name)
        .unwrap_or_else(|| panic!("{video_name} not downloaded"));
    let (_, video_bytes) = got.remove(at);
    assert_eq!(got.len(), 24);
    assert_eq!(got, want, "the frames are the CLI's files");
    assert_eq!(video["fps"], 12, "{video}");
    if video["kind"] == "mp4" {
        let path = farm.join(&video_name);
        let probe = std::process::Command::new("ffprobe")
            .args([
                "-v",
                "error",
                "-count_frames",
                "-select_streams",
                "v:0",
                "-show_entries",
                "stream=nb_read_frames,r_frame_rate",
                "-of",
                "csv=p=0",
            ])
            .arg(&path)
            .output();
        if let Ok(p) = probe {
            let line = text(&p.stdout);
            assert!(line.contains("12/1") && line.contains("24"), "ffprobe: {line}");
        }
    } else {
        assert!(video_bytes.starts_with(b"GIF8"), "{video}");
    }

    // status shows the counts, in a few lines.
    let out = run(client(&home).env("TESSERA_SERVER", &server.url).args(["status", "1"]), MINUTE);
    let shown = text(&out.stdout);
    assert!(
        shown.contains("frames: 24/24 frames done, 0 rendering, 0 queued (of 24 scene file(s))"),
        "{shown}"
    );
    assert!(shown.lines().count() < 10, "{shown}");

    // Another sequence naming a copy of the same PLY elsewhere: only its scenes are sent.
    let other = sequence(&dir.join("other"), "other", 3, &ply);
    let other_bytes: u64 = other.iter().map(|s| std::fs::metadata(s).unwrap().len()).sum();
    let out = run(
        client(&home).env("TESSERA_SERVER", &server.url).arg("submit").args(&other).args(["--video", "none"]),
        MINUTE,
    );
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert_eq!(uploaded(&stderr), (3, 4, other_bytes), "{stderr}");
    let store = stored(&server.data);
    assert_eq!(store.iter().filter(|(n, _)| *n == sha).count(), 1, "{store:?}");
}

/// A frame naming a PLY that is not there refuses the whole sequence before anything is sent:
/// the message names the frame, its scene file and the path; the server has no job and no file.
#[test]
fn a_missing_ply_in_one_frame_is_refused_before_any_upload() {
    let _serial = serial();
    let server = Server::start("client-seq-missing", &[]);
    let home = TempDir::new("client-seq-missing-home");
    let dir = TempDir::new("client-seq-missing");
    let scenes = sequence(&dir, "f", 24, &grid_ply(4));
    std::fs::write(&scenes[7], frame_xml(7, "f", "../ply/absent.ply")).unwrap();
    let out = run(client(&home).env("TESSERA_SERVER", &server.url).arg("submit").args(&scenes), MINUTE);
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.starts_with(&format!("error: frame 7 ({}): ", scenes[7].display())), "{stderr}");
    assert!(stderr.contains("f_007.xml:7: <Mesh id=\"1\"> / <Faces>: cannot find the PLY file"), "{stderr}");
    assert!(stderr.contains("ply/absent.ply") && stderr.contains("nothing was uploaded"), "{stderr}");
    assert!(out.stdout.is_empty());
    assert_eq!(server.get_json("/api/v1/jobs", None)["jobs"], json!([]));
    assert_eq!(stored(&server.data), vec![], "nothing stored");
}

/// One request to the stand-in server.
#[derive(Clone, Debug)]
struct Seen {
    method: String,
    path: String,
    content_type: String,
    body: Vec<u8>,
}

/// A stand-in HTTP server on loopback: `answer` gives (status, JSON body) for each request,
/// every request is recorded. It serves until the test process ends.
fn stand_in(answer: impl Fn(&Seen) -> (u16, String) + Send + 'static) -> (String, Arc<Mutex<Vec<Seen>>>) {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("http://{}", listener.local_addr().unwrap());
    let seen = Arc::new(Mutex::new(Vec::new()));
    let log = seen.clone();
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            let Ok(mut stream) = stream else { continue };
            stream.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
            let mut reader = BufReader::new(stream.try_clone().unwrap());
            let mut line = String::new();
            if reader.read_line(&mut line).is_err() {
                continue;
            }
            let mut parts = line.split_whitespace();
            let (method, path) =
                (parts.next().unwrap_or("").to_string(), parts.next().unwrap_or("").to_string());
            let (mut length, mut content_type) = (0usize, String::new());
            loop {
                let mut h = String::new();
                reader.read_line(&mut h).unwrap();
                if h.trim().is_empty() {
                    break;
                }
                let (k, v) = h.split_once(':').unwrap_or((&h, ""));
                match k.trim().to_ascii_lowercase().as_str() {
                    "content-length" => length = v.trim().parse().unwrap_or(0),
                    "content-type" => content_type = v.trim().to_string(),
                    _ => {}
                }
            }
            let mut body = vec![0; length];
            reader.read_exact(&mut body).unwrap();
            let req = Seen { method, path, content_type, body };
            let (status, reply) = answer(&req);
            log.lock().unwrap().push(req);
            let _ = write!(
                stream,
                "HTTP/1.1 {status} X\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{reply}",
                reply.len()
            );
        }
    });
    (url, seen)
}

/// A job as a server lists it: `frames` frames of `scenes` scene files, with these counts.
fn job_json(id: u64, frames: usize, scenes: u32, counts: [u32; 3]) -> Value {
    let frame = |k: usize| {
        let (done, busy) = (k < counts[0] as usize, k < (counts[0] + counts[1]) as usize);
        json!({"index": k, "camera": 0, "image_name": format!("f_{k:03}.png"), "width": 16, "height": 16,
            "tiles_total": 4, "tiles_done": if done { 4 } else if busy { 2 } else { 0 },
            "outputs": if done { json!([{"name": format!("f_{k:03}.png"), "url": format!("/x/{k}")}]) } else { json!([]) },
            "preview_url": "", "tonemap": null, "scene": format!("input/f_{k:03}.xml")})
    };
    json!({"id": id, "name": "f_000.xml", "state": "running", "priority": 0, "tile_size": 64, "samples": null,
        "submitted_at": 1.0e9, "started_at": 1.0e9, "finished_at": null,
        "frames": (0..frames).map(frame).collect::<Vec<_>>(),
        "frame_counts": {"done": counts[0], "rendering": counts[1], "queued": counts[2]},
        "scenes": scenes, "video": {"kind": "mp4", "fps": 30, "state": "waiting"},
        "error": null, "url": format!("/api/v1/jobs/{id}")})
}

/// A server without content-addressed files (404 on `files/missing`, as servers before them
/// answer every unknown route): one scene goes as today's multipart bundle; a sequence is
/// refused with a message saying to upgrade the server, after that one question.
#[test]
fn an_older_server_gets_one_scene_as_a_bundle_and_refuses_a_sequence() {
    let (url, seen) = stand_in(|req| match (req.method.as_str(), req.path.as_str()) {
        ("POST", "/api/v1/jobs") => (200, job_json(1, 1, 0, [0, 0, 1]).to_string()),
        _ => {
            (404, r#"{"error":"no such endpoint; the API lives under /api/v1 (see the README)"}"#.to_string())
        }
    });
    let home = TempDir::new("client-seq-old-home");
    let dir = TempDir::new("client-seq-old");
    let scenes = sequence(&dir, "f", 3, &grid_ply(2));
    let out = run(client(&home).args(["--server", &url, "submit", "-q"]).arg(&scenes[0]), MINUTE);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(text(&out.stdout).trim(), "1");
    {
        let seen = seen.lock().unwrap();
        let asked: Vec<(&str, &str)> = seen.iter().map(|s| (s.method.as_str(), s.path.as_str())).collect();
        assert_eq!(asked, [("POST", "/api/v1/files/missing"), ("POST", "/api/v1/jobs")]);
        assert!(
            seen[1].content_type.starts_with("multipart/form-data; boundary="),
            "{:?}",
            seen[1].content_type
        );
        let body = String::from_utf8_lossy(&seen[1].body);
        assert!(body.contains("name=\"scene_path\"\r\n\r\ninput/f_000.xml\r\n"), "{body}");
        assert!(body.contains("filename=\"bundle.tar.gz\""), "{body}");
    }
    seen.lock().unwrap().clear();
    let out = run(client(&home).args(["--server", &url, "submit"]).args(&scenes), MINUTE);
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("does not take sequences") && stderr.contains("upgrade it"), "{stderr}");
    let seen = seen.lock().unwrap();
    assert_eq!(seen.len(), 1, "only the question: {seen:?}");
}

/// Against a server with content-addressed files (a stand-in): the client asks for every
/// distinct file once, PUTs only what the server lacks with its bytes, and submits the job as
/// JSON naming every path with its hash, the scenes in the order given and the options.
#[test]
fn only_the_missing_files_are_put_and_the_job_is_json() {
    let dir = TempDir::new("client-seq-cas");
    let scenes = sequence(&dir, "f", 3, &grid_ply(3));
    let ply_sha = sha256_hex(&dir.join("ply/shared.ply"));
    let lacks = vec![sha256_hex(&scenes[1]), ply_sha.clone()];
    let answer_lacks = lacks.clone();
    let (url, seen) = stand_in(move |req| match (req.method.as_str(), req.path.as_str()) {
        ("POST", "/api/v1/files/missing") => (200, json!({"missing": answer_lacks}).to_string()),
        ("PUT", _) => (201, "{}".to_string()),
        ("POST", "/api/v1/jobs") => (200, job_json(5, 3, 3, [0, 0, 3]).to_string()),
        _ => (404, r#"{"error":"no such endpoint"}"#.to_string()),
    });
    let home = TempDir::new("client-seq-cas-home");
    let order = [scenes[2].clone(), scenes[0].clone(), scenes[1].clone()];
    let out = run(
        client(&home).args(["--server", &url, "submit"]).args(&order).args([
            "--fps",
            "24",
            "--video",
            "gif",
            "--no-keep-float",
            "--samples",
            "2",
        ]),
        MINUTE,
    );
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let seen = seen.lock().unwrap();
    let asked: Vec<(&str, &str)> = seen.iter().map(|s| (s.method.as_str(), s.path.as_str())).collect();
    let put = |sha: &str| format!("/api/v1/files/{sha}");
    assert_eq!(
        asked,
        [
            ("POST", "/api/v1/files/missing"),
            ("PUT", put(&lacks[0]).as_str()),
            ("PUT", put(&lacks[1]).as_str()),
            ("POST", "/api/v1/jobs")
        ]
    );
    let question: Value = serde_json::from_slice(&seen[0].body).unwrap();
    assert_eq!(
        question["files"].as_array().unwrap().len(),
        4,
        "three scenes and the PLY, each once: {question}"
    );
    assert_eq!(seen[1].body, std::fs::read(&scenes[1]).unwrap());
    assert_eq!(seen[2].body, std::fs::read(dir.join("ply/shared.ply")).unwrap());
    assert_eq!(seen[1].content_type, "application/octet-stream");
    assert_eq!(seen[3].content_type, "application/json");
    let job: Value = serde_json::from_slice(&seen[3].body).unwrap();
    assert_eq!(job["scenes"], json!(["input/f_002.xml", "input/f_000.xml", "input/f_001.xml"]), "{job}");
    let paths: Vec<&str> =
        job["files"].as_array().unwrap().iter().map(|f| f["path"].as_str().unwrap()).collect();
    assert_eq!(paths, ["input/f_000.xml", "input/f_001.xml", "input/f_002.xml", "ply/shared.ply"]);
    assert_eq!(job["files"][3]["sha256"], ply_sha.as_str());
    assert_eq!(
        (job["fps"].clone(), job["video"].clone(), job["keep_float"].clone()),
        (json!(24), json!("gif"), json!(false))
    );
    assert_eq!(job["samples"], 2);
    let ply_size = std::fs::metadata(dir.join("ply/shared.ply")).unwrap().len();
    let scene_size = std::fs::metadata(&scenes[1]).unwrap().len();
    assert_eq!(uploaded(&stderr), (2, 4, ply_size + scene_size), "{stderr}");
}

/// `status` of a long sequence is its frame counts, the frames under way and the video, in a
/// few lines, not a line a frame.
#[test]
fn status_of_a_sequence_is_its_frame_counts() {
    let (url, _seen) = stand_in(|req| match req.path.as_str() {
        "/api/v1/jobs/7" => (200, job_json(7, 360, 360, [100, 2, 258]).to_string()),
        "/api/v1/jobs" => (200, json!({"jobs": [job_json(7, 360, 360, [100, 2, 258])]}).to_string()),
        _ => (404, r#"{"error":"no such endpoint"}"#.to_string()),
    });
    let home = TempDir::new("client-seq-status-home");
    let out = run(client(&home).args(["--server", &url, "status", "7"]), MINUTE);
    let shown = text(&out.stdout);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(
        shown.contains("frames: 100/360 frames done, 2 rendering, 258 queued (of 360 scene file(s))"),
        "{shown}"
    );
    assert!(shown.contains("frame 100: f_100.png (16x16), 2/4 tiles, from input/f_100.xml"), "{shown}");
    assert!(shown.contains("frame 101: f_101.png"), "{shown}");
    assert!(!shown.contains("frame 99:") && !shown.contains("frame 102:"), "{shown}");
    assert!(shown.contains("video: mp4 at 30 fps, waiting"), "{shown}");
    assert!(shown.lines().count() <= 10, "{shown}");
    let out = run(client(&home).args(["--server", &url, "status"]), MINUTE);
    let listing = text(&out.stdout);
    assert!(listing.lines().nth(1).unwrap().contains("100/360"), "{listing}");
}
