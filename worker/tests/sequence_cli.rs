//! `tessera-worker render` of several scene files in one process (an animation, a file a
//! frame): the same bytes as rendering each file alone, and the meshes they share built once.

mod support;
use support::*;

use std::path::{Path, PathBuf};

use tessera_testkit::{TempDir, shared_scenes};

/// The first `n` frames of the course's orbit around the two statues (one 1.9 MB PLY).
fn orbit_frames(n: usize) -> Vec<PathBuf> {
    let dir = shared_scenes().join("sequences/camera_around_david");
    (0..n).map(|k| dir.join(format!("davids_camera_{k:03}.json"))).collect()
}

fn render_into(scenes: &[PathBuf], out: &Path, extra: &[&str]) -> Run {
    let mut args: Vec<std::ffi::OsString> = vec!["render".into()];
    args.extend(scenes.iter().map(|s| s.clone().into_os_string()));
    for a in ["--samples", "1", "--quiet", "--out"] {
        args.push(a.into());
    }
    args.push(out.as_os_str().to_owned());
    args.extend(extra.iter().map(Into::into));
    run(&args)
}

/// The `--timings-json` lines of a run, in order.
fn timings(r: &Run) -> Vec<serde_json::Value> {
    r.stdout
        .lines()
        .filter(|l| l.starts_with('{'))
        .map(|l| serde_json::from_str(l).expect("a JSON line"))
        .collect()
}

#[test]
fn frames_rendered_together_are_the_bytes_of_each_alone_and_share_their_meshes() {
    let frames = orbit_frames(3);
    let tmp = TempDir::new("sequence-cli");
    let together = tmp.path().join("together");
    let r = render_into(&frames, &together, &["--timings", "--timings-json"]);
    assert_eq!(r.code, Some(0), "{}", r.describe());
    let t = timings(&r);
    assert_eq!(t.len(), 3, "{}", r.describe());
    for (k, (line, frame)) in t.iter().zip(&frames).enumerate() {
        assert_eq!(line["scene"], frame.display().to_string());
        assert_eq!(line["meshes"], 2, "{line}");
        // The statue is parsed and its BVH built for the first frame only; the camera alone
        // moves, so the world-space tree of the two statues is the first frame's too.
        assert_eq!(line["meshes_cached"], if k == 0 { 0 } else { 2 }, "{line}");
        assert_eq!(line["top_level_cached"], k > 0, "{line}");
        for key in ["parse_seconds", "build_seconds", "mesh_seconds", "top_level_seconds", "render_seconds"] {
            assert!(line[key].as_f64().is_some_and(|s| s >= 0.0), "{key}: {line}");
        }
    }
    let mesh = |k: usize| t[k]["mesh_seconds"].as_f64().unwrap();
    // (The smaller of two, so that one descheduled thread on a busy machine cannot fail it.)
    assert!(mesh(1).min(mesh(2)) < mesh(0) / 4.0, "cached mesh builds cost little: {t:?}");
    // The human form: one line a frame.
    let lines: Vec<&str> = r.stdout.lines().filter(|l| l.starts_with("timings: ")).collect();
    assert_eq!(lines.len(), 3, "{}", r.describe());
    assert!(lines[1].contains("2 of 2 from the cache"), "{}", lines[1]);

    for (k, frame) in frames.iter().enumerate() {
        let alone = tmp.path().join(format!("alone{k}"));
        let r = render_into(std::slice::from_ref(frame), &alone, &[]);
        assert_eq!(r.code, Some(0), "{}", r.describe());
        let name = format!("davids_camera_{k:03}.png");
        let a = std::fs::read(together.join(&name)).expect("rendered together");
        let b = std::fs::read(alone.join(&name)).expect("rendered alone");
        assert!(a == b, "{name}: rendered together and alone differ");
    }
}

#[test]
fn a_missing_scene_file_stops_with_its_name_after_the_frames_before_it() {
    let mut frames = orbit_frames(1);
    frames.push(shared_scenes().join("sequences/camera_around_david/no_such_frame.json"));
    let tmp = TempDir::new("sequence-cli-missing");
    let r = render_into(&frames, tmp.path(), &[]);
    assert_eq!(r.code, Some(1), "{}", r.describe());
    assert!(r.stderr.contains("no_such_frame.json: cannot read the scene file"), "{}", r.describe());
    assert!(tmp.path().join("davids_camera_000.png").is_file(), "the frame before it is written");
}

#[test]
fn scenes_that_write_the_same_image_name_are_warned_about() {
    let tmp = TempDir::new("sequence-cli-same-name");
    let scene = r#"<Scene><Cameras><Camera id="1"><Position>0 0 5</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
        <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>8 8</ImageResolution>
        <ImageName>same.png</ImageName></Camera></Cameras>
        <Lights><AmbientLight>25 25 25</AmbientLight></Lights>
        <Materials><Material id="1"><AmbientReflectance>1 1 1</AmbientReflectance></Material></Materials>
        <VertexData>-1 -1 0 1 -1 0 0 1 0</VertexData>
        <Objects><Mesh id="1"><Material>1</Material><Faces>1 2 3</Faces></Mesh></Objects></Scene>"#;
    let (a, b) = (tmp.path().join("a.xml"), tmp.path().join("b.xml"));
    std::fs::write(&a, scene).unwrap();
    std::fs::write(&b, scene).unwrap();
    let out = tmp.path().join("out");
    let r = render_into(&[a.clone(), b.clone()], &out, &[]);
    assert_eq!(r.code, Some(0), "{}", r.describe());
    assert!(
        r.stderr.contains("replaces the one") && r.stderr.contains("a.xml") && r.stderr.contains("b.xml"),
        "{}",
        r.describe()
    );
    // The same file twice is no conflict.
    let r = render_into(&[a.clone(), a], &tmp.path().join("again"), &[]);
    assert_eq!(r.code, Some(0), "{}", r.describe());
    assert!(!r.stderr.contains("replaces"), "{}", r.describe());
}

#[test]
fn a_mesh_cache_bound_of_zero_keeps_nothing_and_a_bad_one_is_refused() {
    let frames = orbit_frames(2);
    let tmp = TempDir::new("sequence-cli-no-cache");
    let r = render_into(&frames, tmp.path(), &["--timings-json", "--mesh-cache-mb", "0"]);
    assert_eq!(r.code, Some(0), "{}", r.describe());
    let t = timings(&r);
    assert_eq!(t.len(), 2, "{}", r.describe());
    assert!(t.iter().all(|l| l["meshes_cached"] == 0 && l["top_level_cached"] == false), "{t:?}");
    let r = render_into(&frames[..1], tmp.path(), &["--mesh-cache-mb", "lots"]);
    assert_eq!(r.code, Some(2), "{}", r.describe());
    assert!(r.stderr.contains("--mesh-cache-mb"), "{}", r.describe());
}

#[test]
fn work_refuses_a_cache_dir_it_cannot_use_and_falls_back_from_an_unusable_default() {
    let tmp = TempDir::new("sequence-cli-cache-dir");
    // A file where the cache directory should be.
    let file = tmp.path().join("not_a_dir");
    std::fs::write(&file, b"x").unwrap();
    let server = ["work", "--server", "http://127.0.0.1:9", "--token", "t"];
    let mut args: Vec<std::ffi::OsString> = server.iter().map(Into::into).collect();
    args.extend(["--cache-dir".into(), file.into_os_string()]);
    let r = run(&args);
    assert_eq!(r.code, Some(1), "{}", r.describe());
    assert!(r.stderr.contains("--cache-dir") && r.stderr.contains("not_a_dir"), "{}", r.describe());
    // No default place without HOME or XDG_CACHE_HOME: a warning, and a cache under the
    // temporary directory for this run. (The worker then waits for the server, which is not
    // there: it is stopped once its first line is read.)
    let mut child = std::process::Command::new(BIN)
        .args(server)
        .envs([("HOME", ""), ("XDG_CACHE_HOME", ""), ("TMPDIR", tmp.path().to_str().unwrap())])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = String::new();
    std::io::BufRead::read_line(&mut std::io::BufReader::new(child.stderr.take().unwrap()), &mut first)
        .unwrap();
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(first.contains("warning: no default file cache") && first.contains("--cache-dir"), "{first}");
    let made = std::fs::read_dir(tmp.path()).unwrap().flatten();
    assert!(
        made.into_iter().any(|e| e.file_name() == "tessera-worker-files"),
        "the run's cache is under TMPDIR"
    );
    let r = run(&[&server[..], &["--cache-mb", "lots"]].concat());
    assert_eq!(r.code, Some(2), "{}", r.describe());
    assert!(r.stderr.contains("--cache-mb"), "{}", r.describe());
}
