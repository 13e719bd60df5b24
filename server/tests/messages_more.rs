//! The messages a farm user meets, with the real binaries: a misspelt element or key is named
//! with the one meant, before anything is uploaded and once for a whole sequence; a `--server`
//! pasted with the API's path, or given as https://, is understood or explained; and a job's
//! `scale` renders the picture of `tessera-worker render --scale`, bit for bit.

mod support;

use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use sha2::{Digest, Sha256};
use support::*;

/// A one-sphere scene lit by `lights` (the text inside `<Lights>`), `w` x `h` pixels, writing
/// `image`. The `<Lights>` block starts on line 4.
fn scene(image: &str, lights: &str, w: u32, h: u32) -> String {
    format!(
        "<Scene>\n<Cameras><Camera id=\"1\"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>\n\
         <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>{w} {h}</ImageResolution><ImageName>{image}</ImageName></Camera></Cameras>\n\
         <Lights>\n{lights}\n</Lights>\n\
         <Materials><Material id=\"1\"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>\n\
         <VertexData>0 0 -5</VertexData>\n\
         <Objects><Sphere id=\"1\"><Material>1</Material><Center>1</Center><Radius>1</Radius></Sphere></Objects>\n</Scene>\n"
    )
}

const MISSPELT_LIGHT: &str =
    "<PointLigth id=\"1\"><Position>0 0 0</Position><Intensity>10 10 10</Intensity></PointLigth>";
const MISSPELT_POSITION: &str =
    "<PointLight id=\"1\"><Positon>0 0 0</Positon><Intensity>10 10 10</Intensity></PointLight>";

/// The client `tessera ARGS` against `server`, with no setting of this machine.
fn client(server: &str, args: &[&str]) -> Output {
    let mut cmd = Command::new(client_bin());
    cmd.args(args).env("TESSERA_SERVER", server).env_remove("TESSERA_TOKEN").env_remove("TESSERA_CONFIG");
    cmd.env("XDG_CONFIG_HOME", "/nonexistent").stdin(Stdio::null());
    run(&mut cmd, Duration::from_secs(120))
}

fn run(cmd: &mut Command, limit: Duration) -> Output {
    let mut child = cmd.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("start the program");
    let out = child.stdout.take().unwrap();
    let err = child.stderr.take().unwrap();
    let (out, err) = (
        std::thread::spawn(move || drain_for(out, limit)),
        std::thread::spawn(move || drain_for(err, limit)),
    );
    let status = wait_timeout(&mut child, limit).unwrap_or_else(|| {
        let _ = child.kill();
        panic!("{cmd:?} did not finish within {limit:?}")
    });
    Output { status, stdout: out.join().unwrap().into_bytes(), stderr: err.join().unwrap().into_bytes() }
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn jobs(server: &Server) -> usize {
    get_json(&server.url, "/api/v1/jobs")["jobs"].as_array().unwrap().len()
}

/// `<PointLigth>` in each of three scene files: the client shows the warning, with file, line,
/// element and the name meant, once, before it uploads anything, counting the other frames;
/// the server's own copies of it are not printed again. `tessera-worker render` says the same.
#[test]
fn a_misspelt_element_is_warned_about_once_before_upload() {
    let _serial = serial();
    let server = Server::start_temp("messages-warn", &["--local-workers", "0"]);
    let dir = TempDir::new("messages-warn-scenes");
    let files: Vec<String> = (0..3)
        .map(|k| {
            let name = format!("frame_{k}.xml");
            dir.write(&name, scene(&format!("frame_{k}.png"), MISSPELT_LIGHT, 8, 8));
            dir.join(&name).display().to_string()
        })
        .collect();
    let mut args = vec!["submit"];
    args.extend(files.iter().map(String::as_str));
    let o = client(&server.url, &args);
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    let first = err.lines().next().unwrap_or("");
    assert!(
        first.contains("frame_0.xml:5: <PointLigth id=\"1\">: unknown element <PointLigth>; did you mean <PointLight>? It is ignored")
            && first.ends_with("(and in 2 more frames)"),
        "the first thing said is the warning, once for the three frames:\n{err}"
    );
    assert_eq!(err.matches("PointLigth>;").count(), 1, "{err}");
    assert_eq!(jobs(&server), 1);

    // One scene: said once too (the server's copy is not printed again).
    let o = client(&server.url, &["submit", &files[1]]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(stderr(&o).matches("PointLigth>;").count(), 1, "{}", stderr(&o));
    assert!(!stderr(&o).contains("more frame"), "{}", stderr(&o));
    assert_eq!(jobs(&server), 2);

    // --dry-run shows it too, before listing the files, and uploads nothing.
    let o = client(&server.url, &["submit", &files[0], "--dry-run"]);
    assert!(o.status.success() && stderr(&o).contains("did you mean <PointLight>?"), "{}", stderr(&o));
    assert_eq!(jobs(&server), 2);

    // The CLI says it when it meets it, and at the end how many more scene files repeated it.
    let out = TempDir::new("messages-warn-cli");
    let o = run(
        Command::new(worker_bin()).arg("render").args(&files).args(["--quiet", "--out"]).arg(out.path()),
        Duration::from_secs(120),
    );
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    let said: Vec<&str> = err.lines().filter(|l| l.contains("PointLigth>;")).collect();
    assert_eq!(said.len(), 2, "{err}");
    assert!(
        said[0].contains(
            "frame_0.xml:5: <PointLigth id=\"1\">: unknown element <PointLigth>; did you mean <PointLight>?"
        ),
        "{err}"
    );
    assert!(said[1].ends_with("(and in 2 more scene files)"), "{err}");
}

/// `<Positon>` where `<Position>` is required: the error is about `<Positon>`, with the name
/// meant, in XML and in JSON, from the client (nothing uploaded) and from the CLI.
#[test]
fn a_misspelt_required_element_says_which_was_meant() {
    let _serial = serial();
    let server = Server::start_temp("messages-positon", &["--local-workers", "0"]);
    let dir = TempDir::new("messages-positon-scenes");
    let xml = dir.write("light.xml", scene("light.png", MISSPELT_POSITION, 8, 8));
    let json = dir.write(
        "light.json",
        r#"{"Scene": {
  "Cameras": {"Camera": {"_id": "1", "Position": "0 0 0", "Gaze": "0 0 -1", "Up": "0 1 0",
    "NearPlane": "-1 1 -1 1", "NearDistance": "1", "ImageResolution": "8 8", "ImageName": "j.png"}},
  "Lights": {"PointLight": {"_id": "1",
    "Positon": "0 0 0", "Intensity": "10 10 10"}},
  "Materials": {"Material": {"_id": "1", "DiffuseReflectance": "1 1 1"}},
  "VertexData": {"_data": "0 0 -5"},
  "Objects": {"Sphere": {"_id": "1", "Material": "1", "Center": "1", "Radius": "1"}}
}}"#,
    );
    let cases = [
        (
            &xml,
            "light.xml:5: <PointLight id=\"1\"> / <Positon>: unknown element <Positon>; did you mean <Position>?",
        ),
        (
            &json,
            "light.json:5: <Scene.Lights.PointLight.Positon>: unknown key \"Positon\"; did you mean \"Position\"?",
        ),
    ];
    for (file, want) in cases {
        let file = file.display().to_string();
        let o = client(&server.url, &["submit", &file]);
        assert!(!o.status.success() && stderr(&o).contains(want), "{file}: {}", stderr(&o));
        let out = TempDir::new("messages-positon-cli");
        let o = run(
            Command::new(worker_bin()).args(["render", &file, "--quiet", "--out"]).arg(out.path()),
            Duration::from_secs(60),
        );
        assert!(!o.status.success() && stderr(&o).contains(want), "{file}: {}", stderr(&o));
    }
    assert_eq!(jobs(&server), 0, "nothing was submitted");
}

/// `--server` as a user may paste it: the API's URL works (with a note), https:// to this
/// plain-HTTP server says what to give instead; the same for the worker.
#[test]
fn a_pasted_api_url_or_https_gets_a_clear_answer() {
    let _serial = serial();
    let server =
        Server::start_temp("messages-server-url", &["--local-workers", "0", "--worker-token", "WTOKEN"]);
    for pasted in [format!("{}/api/v1", server.url), format!("{}/api/v1/jobs/", server.url)] {
        let o = client(&pasted, &["status"]);
        assert!(o.status.success(), "{pasted}: {}", stderr(&o));
        assert!(
            stderr(&o).contains(&format!("note: using the server {}", server.url)),
            "{pasted}: {}",
            stderr(&o)
        );
    }
    let https = server.url.replace("http://", "https://");
    let o = client(&https, &["status"]);
    let err = stderr(&o);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("serves plain HTTP") && err.contains("reverse proxy"), "{err}");
    let o = client(&server.url.replace("http://", "ftp://"), &["status"]);
    assert!(!o.status.success() && stderr(&o).contains("--server") && stderr(&o).contains("http://"));

    // The worker: the API's URL registers; https:// explains itself while it waits.
    let mut worker = Command::new(worker_bin())
        .args([
            "work",
            "--server",
            &format!("{}/api/v1/", server.url),
            "--token",
            "WTOKEN",
            "--name",
            "pasted",
        ])
        .args(["--threads", "1"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let workers = get_json(&server.url, "/api/v1/workers");
        let listed = workers["workers"].as_array().unwrap().iter().any(|w| w["name"] == "pasted");
        if listed {
            break;
        }
        assert!(Instant::now() < deadline, "the worker given the API's URL did not register: {workers}");
        std::thread::sleep(Duration::from_millis(100));
    }
    let _ = worker.kill();
    let _ = worker.wait();
    let o = run(
        Command::new(worker_bin()).args(["work", "--server", &https, "--token", "WTOKEN", "--name", "tls"]),
        Duration::from_secs(30),
    );
    let said = stderr(&o);
    assert!(!o.status.success(), "{said}");
    assert!(said.contains("serves plain HTTP") && said.contains("reverse proxy"), "{said}");
}

/// Width and height of a PNG.
fn png_size(png: &[u8]) -> (u32, u32) {
    let be = |k: usize| u32::from_be_bytes(png[k..k + 4].try_into().unwrap());
    (be(16), be(20))
}

/// A job's `scale`: checked (a clear 400 naming the field), each side rounded to the nearest
/// pixel (800 x 450 at 0.25 is 200 x 113), and `tessera submit --scale 0.25` of a course scene
/// gives the bytes of `tessera-worker render --scale 0.25`.
#[test]
fn a_scaled_job_renders_the_clis_scaled_bytes() {
    let _serial = serial();
    let server =
        Server::start_temp("messages-scale", &["--local-workers", "1", "--local-worker-threads", "2"]);
    let wide = scene("wide.png", "", 800, 450);
    for bad in ["0", "-0.5", "1.5", "NaN", "inf", "quarter", ""] {
        let (code, answer) = submit(
            &server.url,
            None,
            &[("scene", Some("wide.xml"), wide.as_bytes()), ("scale", None, bad.as_bytes())],
        );
        let error = answer["error"].as_str().unwrap_or_default();
        assert_eq!(code, 400, "scale {bad:?}: {answer}");
        assert!(error.starts_with("scale ") && error.contains("(0, 1]"), "scale {bad:?}: {error}");
    }
    let (code, job) = submit(
        &server.url,
        None,
        &[("scene", Some("wide.xml"), wide.as_bytes()), ("scale", None, b"0.25"), ("samples", None, b"1")],
    );
    assert_eq!(code, 201, "{job}");
    let frame = &job["frames"][0];
    assert_eq!((frame["width"].as_u64(), frame["height"].as_u64()), (Some(200), Some(113)), "{job}");
    let id = job["id"].as_u64().unwrap();
    let done = wait_job(&server, id, 60, |j| j["state"] == "done");
    let png = get_bytes(&server.url, &format!("/api/v1/jobs/{id}/frames/0/files/wide.png"));
    assert_eq!(png_size(&png), (200, 113));
    let log = get_json(&server.url, &format!("/api/v1/jobs/{id}/log"));
    assert!(log.to_string().contains("at scale 0.25 (200x113)"), "{log}\n{done}");

    // The JSON submission (what the client sends) takes the same field, checked the same way.
    let sha: String = Sha256::digest(wide.as_bytes()).iter().map(|b| format!("{b:02x}")).collect();
    let put = call(
        ureq::put(&format!("{}/api/v1/files/{sha}", server.url)),
        Some(("application/octet-stream".into(), wide.clone().into_bytes())),
    );
    assert!(put.0 == 200 || put.0 == 201, "{put:?}");
    let json_submit = |scale: Value| {
        let body = json!({"scenes": ["wide.xml"], "files": [{"path": "wide.xml", "sha256": sha, "size": wide.len()}],
            "samples": 1, "scale": scale});
        call(
            ureq::post(&format!("{}/api/v1/jobs", server.url)),
            Some(("application/json".into(), body.to_string().into_bytes())),
        )
    };
    for bad in [json!(0), json!(-1), json!(2), json!(1e308)] {
        let (code, answer) = json_submit(bad.clone());
        assert_eq!(code, 400, "scale {bad}: {answer}");
        assert!(answer["error"].as_str().unwrap_or_default().starts_with("scale "), "scale {bad}: {answer}");
    }
    let (code, job) = json_submit(json!(0.25));
    assert_eq!(code, 201, "{job}");
    assert_eq!(
        (job["frames"][0]["width"].as_u64(), job["frames"][0]["height"].as_u64()),
        (Some(200), Some(113))
    );

    // The client and the CLI flags refuse what the field refuses.
    let o = client(&server.url, &["submit", "x.xml", "--scale", "0"]);
    assert!(
        !o.status.success() && stderr(&o).contains("--scale") && stderr(&o).contains("(0, 1]"),
        "{}",
        stderr(&o)
    );
    let o =
        run(Command::new(worker_bin()).args(["render", "x.xml", "--scale", "2"]), Duration::from_secs(30));
    assert!(
        !o.status.success() && stderr(&o).contains("--scale") && stderr(&o).contains("(0, 1]"),
        "{}",
        stderr(&o)
    );

    // A course scene, on the farm through the client (a JSON submission) and on the CLI.
    let course = tessera_testkit::shared_scenes().join("xml/simple.xml");
    if !tessera_testkit::corpus_has(&course) {
        return;
    }
    let farm = TempDir::new("messages-scale-farm");
    let course_arg = course.display().to_string();
    let farm_arg = farm.path().display().to_string();
    let o = client(&server.url, &["submit", &course_arg, "--scale", "0.25", "--wait", "--out", &farm_arg]);
    assert!(o.status.success(), "{}", stderr(&o));
    let cli = cli_render(&course, &["--scale", "0.25"]);
    let mut compared = 0;
    for entry in std::fs::read_dir(cli.path()).unwrap() {
        let name = entry.unwrap().file_name();
        let mine = std::fs::read(cli.join(&name)).unwrap();
        let theirs = std::fs::read(farm.join(&name)).unwrap_or_else(|e| panic!("{name:?}: {e}"));
        assert!(mine == theirs, "{name:?}: the farm's bytes differ from tessera-worker render --scale 0.25");
        if Path::new(&name).extension().is_some_and(|e| e == "png") {
            assert_eq!(png_size(&theirs), (200, 200), "{name:?}: simple.xml is 800 x 800");
        }
        compared += 1;
    }
    assert!(compared > 0);
}

/// A scaled job that a restart of the server interrupts before any worker took it renders at
/// its scale afterwards: the scale is stored with the job, and the merge reads it back.
#[test]
fn a_scaled_job_keeps_its_scale_across_a_restart() {
    let _serial = serial();
    let data = TempDir::new("messages-scale-restart");
    let wide = scene("wide.png", "", 800, 450);
    let id = {
        let server = Server::start(&data, &["--local-workers", "0"]);
        let (code, job) = submit(
            &server.url,
            None,
            &[
                ("scene", Some("wide.xml"), wide.as_bytes()),
                ("scale", None, b"0.05"),
                ("samples", None, b"1"),
            ],
        );
        assert_eq!(code, 201, "{job}");
        job["id"].as_u64().unwrap()
    };
    let server = Server::start(&data, &["--local-workers", "1", "--local-worker-threads", "1"]);
    let job = wait_job(&server, id, 60, |j| j["state"] == "done");
    let frame = &job["frames"][0];
    assert_eq!((frame["width"].as_u64(), frame["height"].as_u64()), (Some(40), Some(23)), "{job}");
    let png = get_bytes(&server.url, &format!("/api/v1/jobs/{id}/frames/0/files/wide.png"));
    assert_eq!(png_size(&png), (40, 23));
    let cli_dir = TempDir::new("messages-scale-restart-cli");
    let scene_file = cli_dir.write("wide.xml", &wide);
    let cli = cli_render(&scene_file, &["--scale", "0.05", "--samples", "1"]);
    assert!(
        png == std::fs::read(cli.join("wide.png")).unwrap(),
        "the farm's wide.png differs from the CLI's"
    );
}
