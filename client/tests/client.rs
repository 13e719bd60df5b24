//! `tessera` against the real farm: a real `tessera-server` (its SQLite file in a temporary
//! data directory) and real `tessera-worker work` processes over real HTTP.

mod support;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use serde_json::Value;
use support::*;

const MINUTE: Duration = Duration::from_secs(60);

/// The files a scene names (`plyFile="..."`, `"_plyFile": "..."`, `<Image ...>path</Image>`),
/// read from its text here, independently of the client's packing.
fn named_files(scene_text: &str) -> Vec<String> {
    let mut out = Vec::new();
    for key in ["plyFile=\"", "\"_plyFile\": \""] {
        let mut rest = scene_text;
        while let Some(i) = rest.find(key) {
            rest = &rest[i + key.len()..];
            let end = rest.find('"').unwrap();
            out.push(rest[..end].to_string());
        }
    }
    let mut rest = scene_text;
    while let Some(i) = rest.find("<Image id=") {
        rest = &rest[i..];
        let open = rest.find('>').unwrap();
        let close = rest.find("</Image>").unwrap();
        out.push(rest[open + 1..close].trim().to_string());
        rest = &rest[close..];
    }
    out.sort();
    out.dedup();
    out
}

/// The paths inside a stored bundle.
fn bundle_paths(tar: &Path) -> Vec<String> {
    let files = tessera::bundle::read_tar(&std::fs::read(tar).unwrap()).unwrap();
    let mut paths: Vec<String> = files.into_keys().collect();
    paths.sort();
    paths
}

/// `tessera submit SCENE --wait --out DIR` leaves exactly the files `tessera-worker render SCENE
/// --out DIR` writes, byte for byte, for a course scene with PLY models and JPEG textures in
/// subfolders (XML) and one with PLY models in a subfolder (2025 JSON); the server got exactly
/// the files each scene names.
#[test]
fn client_submit_wait_gives_the_clis_files_byte_for_byte() {
    let scenes = tessera_testkit::shared_scenes();
    let cases = [scenes.join("xml/VeachAjar.xml"), scenes.join("json/hw5/cube_point.json")];
    if !cases.iter().all(|c| tessera_testkit::corpus_has(c)) {
        return;
    }
    let _serial = serial();
    let server = Server::start("client-e2e", &[]);
    let _workers = [Worker::start(&server.url, "w1"), Worker::start(&server.url, "w2")];
    let home = TempDir::new("client-e2e-home");
    for (i, scene) in cases.iter().enumerate() {
        let cli = TempDir::new("client-e2e-cli");
        let t = Instant::now();
        cli_render(scene, &cli, &["--samples", "1"]);
        let cli_secs = t.elapsed().as_secs_f64();

        let farm = TempDir::new("client-e2e-farm");
        let t = Instant::now();
        let out = run(
            client(&home)
                .env("TESSERA_SERVER", &server.url)
                .arg("submit")
                .arg(scene)
                .args(["--wait", "--samples", "1", "--tile-size", "64", "--out"])
                .arg(farm.path()),
            Duration::from_secs(300),
        );
        let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
        assert!(out.status.success(), "{stdout}\n{stderr}\n{}", server.log());
        eprintln!(
            "{}: tessera-worker render {cli_secs:.1} s, tessera submit --wait {:.1} s",
            scene.display(),
            t.elapsed().as_secs_f64()
        );

        let (want, got) = (files_under(&cli), files_under(&farm));
        let names = |v: &[(String, Vec<u8>)]| v.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>();
        assert!(!want.is_empty());
        assert_eq!(names(&got), names(&want), "the same files");
        for ((name, a), (_, b)) in want.iter().zip(&got) {
            assert!(a == b, "{name} differs from the CLI's ({} vs {} bytes)", b.len(), a.len());
        }
        // The client said what it wrote (stdout) and followed the job to its end (stderr).
        for (name, _) in &got {
            assert!(stdout.contains(&farm.join(name).display().to_string()), "{stdout}");
        }
        let id = i as u64 + 1;
        assert!(stdout.contains(&format!("submitted job {id} ")), "{stdout}");
        assert!(stderr.contains(&format!("job {id} (")) && stderr.contains("): done in"), "{stderr}");
        let job = server.get_json(&format!("/api/v1/jobs/{id}"), None);
        assert_eq!(job["state"], "done", "{job}");
        assert_eq!(job["samples"], 1, "{job}");
        assert_eq!(job["tile_size"], 64, "{job}");

        // Exactly the scene and the files it names: in a stored bundle at the paths it names
        // them by (a server that takes bundles only), or in the server's file store by hash.
        let scene_name = scene.file_name().unwrap().to_string_lossy().into_owned();
        let mut expected = named_files(&std::fs::read_to_string(scene).unwrap());
        assert!(expected.len() >= 2, "{expected:?}");
        expected.push(scene_name);
        expected.sort();
        let blobs = server.blobs();
        if blobs.is_empty() {
            let summary =
                stderr.lines().find(|l| l.starts_with("uploaded ")).unwrap_or_else(|| panic!("{stderr}"));
            assert!(summary.contains(&format!(" of {} files,", expected.len())), "{summary}");
            for p in &expected {
                let sha = sha256_hex(&scene.parent().unwrap().join(p));
                let at = server.data.join("files").join(&sha[..2]).join(&sha);
                assert!(at.is_file(), "{p} is not in the file store");
            }
        } else {
            assert_eq!(blobs.len(), i + 1, "one bundle per job");
            let stored: Vec<Vec<String>> = blobs.iter().map(|b| bundle_paths(b)).collect();
            assert!(stored.contains(&expected), "stored bundles {stored:?}, expected {expected:?}");
        }
    }
}

fn sha256_hex(path: &Path) -> String {
    use sha2::Digest;
    format!("{:x}", sha2::Sha256::digest(std::fs::read(path).unwrap()))
}

/// `tessera submit --denoise --wait` brings down the denoised files too, the CLI's bytes.
#[test]
fn client_submit_denoise_downloads_the_clis_denoised_files() {
    if !tessera_testkit::denoiser_found(tessera_denoise::oidn().map(|_| ())) {
        return;
    }
    let dir = TempDir::new("client-denoise");
    let Some(scene) = tessera_testkit::small_path_traced_box(dir.path()) else { return };
    let _serial = serial();
    let server = Server::start("client-denoise", &[]);
    let _worker = Worker::start(&server.url, "w1");
    let (cli, farm, home) = (dir.path().join("cli"), dir.path().join("farm"), dir.path().join("home"));
    let args = ["--camera", "3", "--samples", "8", "--denoise"];
    cli_render(&scene, &cli, &args);
    let out = run(
        client(&home)
            .env("TESSERA_SERVER", &server.url)
            .arg("submit")
            .arg(&scene)
            .args(["--cameras", "3", "--samples", "8", "--denoise", "--wait", "--out"])
            .arg(&farm),
        Duration::from_secs(300),
    );
    assert!(out.status.success(), "{}\n{}\n{}", text(&out.stdout), text(&out.stderr), server.log());
    let (want, got) = (files_under(&cli), files_under(&farm));
    let names = |v: &[(String, Vec<u8>)]| v.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>();
    assert_eq!(names(&got), names(&want), "the same files");
    assert!(names(&got).contains(&"glass_next_importance_denoised.exr".to_string()), "{:?}", names(&got));
    for ((name, a), (_, b)) in want.iter().zip(&got) {
        assert!(a == b, "{name} differs from the CLI's");
    }
}

/// A tiny scene in `dir` with a PLY model in `models/` and a PNG texture in `textures/`; its
/// mesh 2 names `mesh2`.
fn scene_with_assets(dir: &Path, mesh2: &str) -> PathBuf {
    std::fs::create_dir_all(dir.join("models")).unwrap();
    std::fs::create_dir_all(dir.join("textures")).unwrap();
    let ply = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
element face 1\nproperty list uchar int vertex_indices\nend_header\n-1 -1 -3\n1 -1 -3\n0 1 -3\n3 0 1 2\n";
    std::fs::write(dir.join("models/tri.ply"), ply).unwrap();
    let png =
        tessera::hdr_io::encode_png_rgb8(2, 2, &[250, 10, 10, 10, 250, 10, 10, 10, 250, 99, 99, 99]).unwrap();
    std::fs::write(dir.join("textures/check.png"), png).unwrap();
    let scene = dir.join("scene.xml");
    std::fs::write(
        &scene,
        format!(
            r#"<Scene>
<Cameras><Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
<NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>16 16</ImageResolution>
<ImageName>scene.png</ImageName></Camera></Cameras>
<Lights><AmbientLight>255 255 255</AmbientLight></Lights>
<Materials><Material id="1"><AmbientReflectance>1 1 1</AmbientReflectance><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
<Textures><Images><Image id="1">textures/check.png</Image></Images>
<TextureMap id="1" type="image"><ImageId>1</ImageId><DecalMode>replace_kd</DecalMode></TextureMap></Textures>
<VertexData>0 0 -4</VertexData>
<Objects>
<Sphere id="1"><Material>1</Material><Textures>1</Textures><Center>1</Center><Radius>0.5</Radius></Sphere>
<Mesh id="2"><Material>1</Material><Faces plyFile="{mesh2}"/></Mesh>
</Objects></Scene>"#
        ),
    )
    .unwrap();
    scene
}

/// A scene naming a PLY file that does not exist is refused before anything is uploaded: the
/// message names the file, the line and the element, the exit status is 1, and the server has
/// no job (nor a bundle); without a server at all the message is the same.
#[test]
fn client_refuses_a_scene_with_a_missing_asset_before_uploading() {
    let _serial = serial();
    let server = Server::start("client-missing", &[]);
    let dir = TempDir::new("client-missing-scene");
    let scene = scene_with_assets(&dir, "models/absent.ply");
    let home = TempDir::new("client-missing-home");
    for url in [server.url.as_str(), "http://127.0.0.1:9"] {
        let out = run(client(&home).args(["--server", url, "submit"]).arg(&scene).arg("--wait"), MINUTE);
        let stderr = text(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{stderr}");
        assert!(stderr.starts_with("error: "), "{stderr}");
        assert!(
            stderr.contains("scene.xml:12: <Mesh id=\"2\">"),
            "names the file, line and element: {stderr}"
        );
        assert!(stderr.contains("models/absent.ply"), "names the missing file: {stderr}");
        assert!(!stderr.contains("cannot reach"), "no network before the scene is checked: {stderr}");
        assert!(out.stdout.is_empty());
    }
    // Other scenes that cannot be rendered are refused the same way, before any upload.
    let no_camera = dir.write("no_camera.xml", "<Scene><Objects></Objects></Scene>");
    let broken = dir.write("broken.xml", "<Scene>\n<Cameras>\n</Scene>\n");
    for (scene, says) in [
        (&no_camera, "no_camera.xml: the scene has no camera, so nothing to render; add one under <Cameras>"),
        (&broken, "broken.xml:3"),
    ] {
        let out = run(client(&home).args(["--server", &server.url, "submit"]).arg(scene), MINUTE);
        assert_eq!(out.status.code(), Some(1));
        assert!(text(&out.stderr).contains(says), "{}", text(&out.stderr));
    }
    let jobs = server.get_json("/api/v1/jobs", None);
    assert_eq!(jobs["jobs"], Value::Array(vec![]), "the server got no job");
    assert!(server.blobs().is_empty(), "the server stored no bundle");
    let store = server.data.join("files");
    assert!(!store.exists() || files_under(&store).is_empty(), "the server stored no file");

    // The same scene with the file in place goes through (the test above is about the file).
    let ok = scene_with_assets(&dir, "models/tri.ply");
    let out = run(client(&home).args(["--server", &server.url, "submit", "--quiet"]).arg(&ok), MINUTE);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(text(&out.stdout).trim(), "1");
    // --dry-run lists exactly the scene and its two assets, and submits nothing.
    let out =
        run(client(&home).args(["--server", "http://127.0.0.1:9", "submit", "--dry-run"]).arg(&ok), MINUTE);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let listed: Vec<String> =
        text(&out.stdout).lines().map(|l| l.split('\t').next().unwrap().to_string()).collect();
    assert_eq!(listed, ["models/tri.ply", "scene.xml", "textures/check.png"]);
    assert_eq!(server.get_json("/api/v1/jobs", None)["jobs"].as_array().unwrap().len(), 1);
}

/// `submit` without --wait, `status` (list and one job), `fetch --wait` following a job to
/// completion, `cancel`, and the errors of each for jobs that do not exist or have ended.
#[test]
fn client_follows_fetches_and_cancels_jobs() {
    let _serial = serial();
    let server = Server::start("client-follow", &[]);
    let home = TempDir::new("client-follow-home");
    let dir = TempDir::new("client-follow-scene");
    let scene = scene_with_assets(&dir, "models/tri.ply");
    let tessera = || {
        let mut c = client(&home);
        c.env("TESSERA_SERVER", &server.url);
        c
    };

    let out = run(tessera().args(["submit", "-q"]).arg(&scene), MINUTE);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let id: u64 = text(&out.stdout).trim().parse().unwrap();
    let out = run(tessera().arg("status"), MINUTE);
    let listing = text(&out.stdout);
    assert!(out.status.success());
    let row = listing
        .lines()
        .find(|l| l.trim_start().starts_with(&format!("{id} ")))
        .unwrap_or_else(|| panic!("{listing}"));
    assert!(row.contains("queued") && row.contains("0/1") && row.ends_with("scene.xml"), "{listing}");
    let out = run(tessera().args(["status", &id.to_string()]), MINUTE);
    let shown = text(&out.stdout);
    assert!(
        shown.contains("state: queued (0/1 tiles)")
            && shown.contains("frame 0: camera 1, scene.png (16x16), 0/1 tiles"),
        "{shown}"
    );

    // fetch --wait follows the queued job; a worker arrives later and renders it.
    let out_dir = TempDir::new("client-follow-out");
    let mut fetch = tessera();
    fetch.args(["fetch", &id.to_string(), "--wait", "--out"]).arg(out_dir.path());
    let fetcher = std::thread::spawn(move || run(&mut fetch, Duration::from_secs(120)));
    std::thread::sleep(Duration::from_millis(1500));
    assert!(!fetcher.is_finished(), "fetch --wait returned before the job ended");
    let worker = Worker::start(&server.url, "late");
    let out = fetcher.join().unwrap();
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "{stderr}\n{}", server.log());
    assert!(stderr.contains(&format!("job {id} (scene.xml): queued")), "{stderr}");
    assert!(stderr.contains("frame 0 scene.png (16x16) done: scene.png, scene.exr"), "{stderr}");
    assert!(stderr.contains(&format!("job {id} (scene.xml): done in")), "{stderr}");
    let cli = TempDir::new("client-follow-cli");
    cli_render(&scene, &cli, &[]);
    assert_eq!(files_under(&out_dir), files_under(&cli));
    // --float-exr adds the farm's float frame of the .png image.
    let out =
        run(tessera().args(["fetch", &id.to_string(), "--float-exr", "-o"]).arg(out_dir.path()), MINUTE);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let names: Vec<String> = files_under(&out_dir).into_iter().map(|(n, _)| n).collect();
    assert_eq!(names, ["scene.exr", "scene.png"]);

    // No worker: a job waits; cancelling it ends a follower with status 1.
    drop(worker);
    let out = run(tessera().args(["submit", "-q"]).arg(&scene), MINUTE);
    let id2: u64 = text(&out.stdout).trim().parse().unwrap();
    let mut wait = tessera();
    wait.args(["fetch", &id2.to_string(), "--wait", "--out"]).arg(out_dir.path());
    let waiter = std::thread::spawn(move || run(&mut wait, Duration::from_secs(120)));
    std::thread::sleep(Duration::from_millis(1000));
    let out = run(tessera().args(["cancel", &id2.to_string()]), MINUTE);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(text(&out.stdout).trim(), format!("job {id2} (scene.xml): canceled"));
    let out = waiter.join().unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(
        text(&out.stderr).contains(&format!("error: job {id2} (scene.xml) was cancelled")),
        "{}",
        text(&out.stderr)
    );
    // Cancelling it again, and jobs that do not exist.
    let out = run(tessera().args(["cancel", &id2.to_string()]), MINUTE);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        text(&out.stderr)
            .contains(&format!("the server answered 409: job {id2} has already ended (canceled)")),
        "{}",
        text(&out.stderr)
    );
    for args in [["status", "99"], ["cancel", "99"], ["fetch", "99"]] {
        let out = run(tessera().args(args), MINUTE);
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        assert!(text(&out.stderr).contains("404: there is no job 99"), "{args:?}: {}", text(&out.stderr));
    }
    // A fetch of an unfinished job says so.
    let out = run(tessera().args(["submit", "-q"]).arg(&scene), MINUTE);
    let id3 = text(&out.stdout).trim().to_string();
    let out = run(tessera().args(["fetch", &id3, "-o"]).arg(out_dir.path()), MINUTE);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        text(&out.stderr).contains("has frames without outputs: frame 0 scene.png (16x16) (0/1 tiles)"),
        "{}",
        text(&out.stderr)
    );
    // --json is the server's answer.
    let out = run(tessera().args(["status", &id3, "--json"]), MINUTE);
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["state"], "queued");
}

/// The server and token come from flags, else TESSERA_SERVER / TESSERA_TOKEN, else the config
/// file; a missing or wrong token is a 401 with a hint.
#[test]
fn client_takes_server_and_token_from_flags_env_or_config() {
    let _serial = serial();
    let server = Server::start("client-token", &["--api-token", "right-token"]);
    let home = TempDir::new("client-token-home");

    let out = run(client(&home).args(["--server", &server.url, "status"]), MINUTE);
    assert_eq!(out.status.code(), Some(1));
    let e = text(&out.stderr);
    assert!(e.contains("the server answered 401") && e.contains("pass --token, set TESSERA_TOKEN"), "{e}");

    std::fs::create_dir_all(home.join("tessera")).unwrap();
    let config = home.join("tessera/client.toml");
    std::fs::write(&config, format!("# test farm\nserver = \"{}\"\ntoken = \"right-token\"\n", server.url))
        .unwrap();
    // Only its owner may read a file with a token (the client warns otherwise).
    std::fs::set_permissions(&config, std::os::unix::fs::PermissionsExt::from_mode(0o600)).unwrap();
    let out = run(client(&home).arg("status"), MINUTE);
    assert!(out.status.success(), "the config file alone: {}", text(&out.stderr));
    assert!(text(&out.stdout).contains("no jobs on"), "{}", text(&out.stdout));
    assert!(text(&out.stderr).is_empty(), "{}", text(&out.stderr));

    // The environment beats the file, a flag beats the environment.
    let out = run(client(&home).env("TESSERA_TOKEN", "wrong").arg("status"), MINUTE);
    assert_eq!(out.status.code(), Some(1), "TESSERA_TOKEN beats the file");
    let out =
        run(client(&home).env("TESSERA_TOKEN", "wrong").args(["--token", "right-token", "status"]), MINUTE);
    assert!(out.status.success(), "--token beats TESSERA_TOKEN: {}", text(&out.stderr));
    let out = run(client(&home).env("TESSERA_SERVER", "http://127.0.0.1:9").arg("status"), MINUTE);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        text(&out.stderr).contains("cannot reach the server at http://127.0.0.1:9"),
        "{}",
        text(&out.stderr)
    );
    let out = run(
        client(&home).env("TESSERA_SERVER", "http://127.0.0.1:9").args(["-s", &server.url, "status"]),
        MINUTE,
    );
    assert!(out.status.success(), "--server beats TESSERA_SERVER: {}", text(&out.stderr));

    // A broken config file is named with its line.
    std::fs::write(&config, "server = \"x\"\nsecret = \"y\"\n").unwrap();
    let out = run(client(&home).arg("status"), MINUTE);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        text(&out.stderr).contains(&format!("{}:2: unknown key \"secret\"", config.display())),
        "{}",
        text(&out.stderr)
    );
}

/// `tessera logs ID --follow` on the real server prints the job's events from its acceptance to
/// its end, in order, and `--after` only later ones.
#[test]
fn client_logs_follow_a_real_job() {
    let _serial = serial();
    let server = Server::start("client-logs", &[]);
    let home = TempDir::new("client-logs-home");
    let dir = TempDir::new("client-logs-scene");
    let scene = scene_with_assets(&dir, "models/tri.ply");
    let tessera = || {
        let mut c = client(&home);
        c.env("TESSERA_SERVER", &server.url);
        c
    };
    let out = run(tessera().args(["submit", "-q", "--tile-size", "8"]).arg(&scene), MINUTE);
    let id = text(&out.stdout).trim().to_string();
    let mut follow = tessera();
    follow.args(["logs", &id, "--follow"]);
    let follower = std::thread::spawn(move || run(&mut follow, Duration::from_secs(120)));
    let _worker = Worker::start(&server.url, "logger");
    let out = follower.join().unwrap();
    let log = text(&out.stdout);
    assert!(out.status.success(), "{}\n{log}", text(&out.stderr));
    let lines: Vec<&str> = log.lines().collect();
    let kinds: Vec<&str> = lines.iter().map(|l| l.split_whitespace().nth(3).unwrap()).collect();
    assert_eq!(kinds.first(), Some(&"accepted"), "{log}");
    assert_eq!(kinds.last(), Some(&"job_done"), "{log}");
    assert_eq!(kinds.iter().filter(|k| **k == "tile_done").count(), 4, "16x16 in tiles of 8: {log}");
    let seqs: Vec<u64> =
        lines.iter().map(|l| l.split_whitespace().next().unwrap().parse().unwrap()).collect();
    assert!(seqs.windows(2).all(|w| w[0] < w[1]), "{log}");
    let out = run(tessera().args(["logs", &id, "--after", &seqs[seqs.len() - 2].to_string()]), MINUTE);
    assert_eq!(text(&out.stdout).trim(), lines[lines.len() - 1].trim());
}

/// `logs --follow` asks for `?after=` the last event it printed and stops at the job's last
/// event: checked against a stand-in server that answers a scripted log and records the
/// requests (the real one is checked by `client_logs_follow_a_real_job`).
#[test]
fn client_logs_follow_polls_after_the_last_seq() {
    use std::io::{BufRead, BufReader, Write};
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("http://{}", listener.local_addr().unwrap());
    let event = |seq: u64, kind: &str| serde_json::json!({"seq": seq, "at": 1.0e9 + seq as f64, "kind": kind, "message": format!("event {seq}")});
    let answers = vec![
        (
            "/api/v1/jobs/5/log?after=0",
            serde_json::json!({"job": 5, "events": [event(1, "accepted"), event(2, "tile_done")]}),
        ),
        ("/api/v1/jobs/5/log?after=2", serde_json::json!({"job": 5, "events": []})),
        (
            "/api/v1/jobs/5",
            serde_json::json!({"id": 5, "name": "s.xml", "state": "running", "priority": 0, "tile_size": 8,
            "samples": null, "submitted_at": 1.0e9, "started_at": 1.0e9, "finished_at": null, "frames": [], "error": null, "url": "/api/v1/jobs/5"}),
        ),
        (
            "/api/v1/jobs/5/log?after=2",
            serde_json::json!({"job": 5, "events": [event(3, "frame_merged"), event(4, "job_done")]}),
        ),
    ];
    let server = std::thread::spawn(move || {
        let mut seen = Vec::new();
        for (expected, body) in answers {
            let (mut stream, _) = listener.accept().unwrap();
            let mut reader = BufReader::new(stream.try_clone().unwrap());
            let mut request_line = String::new();
            reader.read_line(&mut request_line).unwrap();
            loop {
                let mut h = String::new();
                reader.read_line(&mut h).unwrap();
                if h.trim().is_empty() {
                    break;
                }
            }
            let path = request_line.split_whitespace().nth(1).unwrap().to_string();
            let body = if path == expected {
                body.to_string()
            } else {
                format!("{{\"error\":\"expected {expected}\"}}")
            };
            let status = if path == expected { "200 OK" } else { "400 Bad Request" };
            write!(stream, "HTTP/1.1 {status}\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}", body.len()).unwrap();
            seen.push(path);
        }
        seen
    });
    let home = TempDir::new("client-logs-fake");
    let out = run(client(&home).args(["--server", &url, "logs", "5", "--follow"]), MINUTE);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let seen = server.join().unwrap();
    assert_eq!(seen.len(), 4, "{seen:?}");
    let stdout = text(&out.stdout);
    let kinds: Vec<&str> = stdout.lines().map(|l| l.split_whitespace().nth(3).unwrap()).collect();
    assert_eq!(kinds, ["accepted", "tile_done", "frame_merged", "job_done"], "{stdout}");
    assert!(stdout.lines().next().unwrap().ends_with("event 1"), "{stdout}");
}
