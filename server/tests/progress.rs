//! Honest progress on the farm: the real server, worker and client processes. A job's JSON
//! counts samples done over samples to do (pixel-samples), pass by pass; the client's `--wait`
//! says the pass and the samples per pixel reached; a sequence counts its frames.

mod support;

use std::io::Read;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;
use support::*;
use tessera_testkit::small_path_traced_box;

/// What one look at a running job showed.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Look {
    done: u64,
    total: u64,
    bound: bool,
    pass: u64,
    passes_done: u64,
    spp: u64,
}

fn look(job: &Value) -> Look {
    let f = &job["frames"][0];
    let n = |v: &Value| v.as_u64().unwrap_or_else(|| panic!("not a number: {v} in {job}"));
    let l = Look {
        done: n(&job["samples_done"]),
        total: n(&job["samples_total"]),
        bound: job["samples_total_is_bound"].as_bool().unwrap(),
        pass: n(&f["pass"]),
        passes_done: n(&f["passes_done"]),
        spp: n(&f["spp"]),
    };
    // One frame: the job's counts are the frame's.
    assert_eq!((l.done, l.total), (n(&f["samples_done"]), n(&f["samples_total"])), "{job}");
    l
}

/// Polls job `id` every few milliseconds until it is done; every look, in order.
fn watch(server: &Server, id: u64) -> Vec<Look> {
    let deadline = Instant::now() + Duration::from_secs(300);
    let mut looks = Vec::new();
    loop {
        let job = get_json(&server.url, &format!("/api/v1/jobs/{id}"));
        looks.push(look(&job));
        if job["state"] == "done" {
            return looks;
        }
        assert!(job["state"] == "queued" || job["state"] == "running", "{job}\n{}", server.log());
        assert!(Instant::now() < deadline, "job {id} never finished: {job}\n{}", server.log());
        std::thread::sleep(Duration::from_millis(15));
    }
}

/// Samples done never decrease and the total never grows; the pass never goes back.
fn assert_monotonic(looks: &[Look]) {
    for w in looks.windows(2) {
        assert!(w[1].done >= w[0].done, "samples done went back: {:?} -> {:?}", w[0], w[1]);
        assert!(w[1].total <= w[0].total, "the total grew: {:?} -> {:?}", w[0], w[1]);
        assert!(w[1].pass >= w[0].pass && w[1].passes_done >= w[0].passes_done, "{:?} -> {:?}", w[0], w[1]);
        assert!(w[0].done <= w[0].total, "{:?}", w[0]);
    }
}

fn job_id_of_first(server: &Server) -> u64 {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let list = get_json(&server.url, "/api/v1/jobs");
        if let Some(id) = list["jobs"].as_array().unwrap().first().and_then(|j| j["id"].as_u64()) {
            return id;
        }
        assert!(Instant::now() < deadline, "no job was submitted\n{}", server.log());
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
fn a_job_in_passes_counts_samples_pass_by_pass_and_the_client_says_the_pass_and_spp() {
    let _s = serial();
    let dir = TempDir::new("progress-passes");
    let Some(scene) = small_path_traced_box(dir.path()) else { return };
    let server =
        Server::start_temp("progress-passes-data", &["--local-workers", "1", "--local-worker-threads", "1"]);
    let out = TempDir::new("progress-passes-out");
    // 96 x 96 pixels in four tiles of 48, 128 samples in passes of 16: eight passes.
    let mut client = Command::new(client_bin())
        .arg("submit")
        .arg(&scene)
        .args([
            "--cameras",
            "3",
            "--samples",
            "128",
            "--pass-samples",
            "16",
            "--tile-size",
            "48",
            "--wait",
            "--out",
        ])
        .arg(out.path())
        .env("TESSERA_SERVER", &server.url)
        .env_remove("TESSERA_TOKEN")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run tessera submit --wait");
    let stderr = client.stderr.take().unwrap();
    let err_reader = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = { stderr }.read_to_string(&mut s);
        s
    });
    let id = job_id_of_first(&server);
    let looks = watch(&server, id);
    let status = wait_timeout(&mut client, Duration::from_secs(120)).expect("the client never ended");
    let err = err_reader.join().unwrap();
    assert!(status.success(), "{status:?}\n{err}");

    let full = 96 * 96 * 128;
    assert_monotonic(&looks);
    assert!(
        looks.iter().all(|l| l.total == full && !l.bound),
        "no noise target: the total is exact: {looks:?}"
    );
    let last = *looks.last().unwrap();
    assert_eq!((last.done, last.pass, last.passes_done, last.spp), (full, 8, 8, 128), "{looks:?}");
    // The passes were seen one after another, each with the samples per pixel it brings.
    let passes: std::collections::BTreeSet<u64> =
        looks.iter().filter(|l| l.done < full).map(|l| l.passes_done).collect();
    assert!(passes.len() >= 3, "too few passes seen while rendering: {passes:?}");
    for l in &looks {
        assert_eq!(l.spp, l.done / (96 * 96), "{l:?}");
        assert!(l.spp >= 16 * l.passes_done, "every tile has its passes: {l:?}");
        if l.done < full {
            assert_eq!(l.pass, l.passes_done + 1, "the pass under way follows the last done: {l:?}");
        }
    }
    // Part-way, the progress is part-way: a pass of 16 samples is an eighth of the work.
    assert!(looks.iter().any(|l| l.done > 0 && l.done < full / 2), "{looks:?}");

    // The client said each pass it saw, with the samples per pixel reached (on average: tiles
    // ahead of the last finished pass count theirs), and no empty parentheses.
    let said: Vec<&str> = err.lines().filter(|l| l.contains(" done, ") && l.contains(" pass ")).collect();
    assert!(!said.is_empty(), "no pass line:\n{err}");
    for line in &said {
        let rest = line.split(" pass ").nth(1).unwrap();
        let k: u64 = rest.split_whitespace().next().unwrap().parse().unwrap();
        assert!(rest.starts_with(&format!("{k} of 8 done, ")), "{line}\n{err}");
        let spp: u64 = rest.split(" done, ").nth(1).unwrap().split(" spp").next().unwrap().parse().unwrap();
        assert!((16 * k..=128).contains(&spp), "{line}\n{err}");
    }
    assert!(!err.contains("()") && !err.contains("ETA 0s"), "{err}");
    assert!(out.path().join("glass_next_importance.png").exists(), "{err}");
}

#[test]
fn under_a_noise_target_the_total_is_a_bound_that_only_shrinks_to_what_was_done() {
    let _s = serial();
    let dir = TempDir::new("progress-target");
    let Some(scene) = small_path_traced_box(dir.path()) else { return };
    let server =
        Server::start_temp("progress-target-data", &["--local-workers", "1", "--local-worker-threads", "1"]);
    let job = submit_box(&server, &scene, &[("tile_size", b"16"), ("noise_target", b"0.1")]);
    let id = job["id"].as_u64().unwrap();
    let first = look(&job);
    let cap = job["frames"][0]["samples"].as_u64().unwrap();
    let full = 96 * 96 * cap;
    assert_eq!((first.done, first.total, first.bound), (0, full, true), "{job}");
    let looks = watch(&server, id);
    assert_monotonic(&looks);
    let last = *looks.last().unwrap();
    // Tiles that stopped early took less than the cap: the bound came down to what was done.
    assert!(last.done == last.total && last.total < full && !last.bound, "{looks:?}");
    assert!(looks.iter().filter(|l| l.done < l.total).all(|l| l.bound), "{looks:?}");
    // The job list gives the same counts without listing tiles.
    let list = get_json(&server.url, "/api/v1/jobs");
    let listed = &list["jobs"][0];
    assert_eq!(
        (listed["samples_done"].as_u64(), listed["samples_total"].as_u64()),
        (Some(last.done), Some(last.total))
    );
}

/// A scene of a sequence: `size` pixels square, `spp` samples, the camera a little further
/// along x in each frame.
fn sequence_scene(k: usize, size: u32, spp: u32) -> Vec<u8> {
    let x = -0.5 + 0.1 * k as f64;
    format!(
        r#"<Scene><Cameras><Camera id="1"><Position>{x} 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
<NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>{size} {size}</ImageResolution>
<NumSamples>{spp}</NumSamples><ImageName>frame_{k:03}.png</ImageName></Camera></Cameras>
<Lights><AmbientLight>40 40 40</AmbientLight></Lights>
<Materials><Material id="1"><AmbientReflectance>1 1 1</AmbientReflectance><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
<VertexData>0 0 -5</VertexData><Objects><Sphere id="1"><Material>1</Material><Center>1</Center><Radius>1</Radius></Sphere></Objects></Scene>"#
    )
    .into_bytes()
}

#[test]
fn a_sequence_counts_its_frames_and_its_samples() {
    let _s = serial();
    let server =
        Server::start_temp("progress-seq-data", &["--local-workers", "1", "--local-worker-threads", "1"]);
    let scenes: Vec<(String, Vec<u8>)> =
        (0..4).map(|k| (format!("seq/frame_{k:03}.xml"), sequence_scene(k, 24, 4))).collect();
    let mut parts: Vec<(&str, Option<&str>, &[u8])> =
        scenes.iter().map(|(p, b)| ("scene", Some(p.as_str()), b.as_slice())).collect();
    parts.extend([("tile_size", None, b"8".as_slice()), ("video", None, b"none".as_slice())]);
    let (code, job) = submit(&server.url, None, &parts);
    assert_eq!(code, 201, "{job}");
    let id = job["id"].as_u64().unwrap();
    let full = 4 * 24 * 24 * 4;
    assert_eq!((job["samples_done"].as_u64(), job["samples_total"].as_u64()), (Some(0), Some(full)), "{job}");
    let deadline = Instant::now() + Duration::from_secs(120);
    let (mut frames_done, mut samples_done) = (0, 0);
    loop {
        let job = get_json(&server.url, &format!("/api/v1/jobs/{id}"));
        let fd = job["frame_counts"]["done"].as_u64().unwrap();
        let sd = job["samples_done"].as_u64().unwrap();
        assert!(fd >= frames_done && sd >= samples_done, "progress went back: {job}");
        assert_eq!(job["samples_total"].as_u64(), Some(full), "{job}");
        // Each merged frame brought all its samples.
        assert!(sd >= fd * 24 * 24 * 4, "{job}");
        (frames_done, samples_done) = (fd, sd);
        if job["state"] == "done" {
            break;
        }
        assert!(Instant::now() < deadline, "{job}\n{}", server.log());
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!((frames_done, samples_done), (4, full));
    // The client's status counts the frames, and says nothing is left.
    let run = Command::new(client_bin())
        .args(["status", &id.to_string()])
        .env("TESSERA_SERVER", &server.url)
        .env_remove("TESSERA_TOKEN")
        .output()
        .expect("run tessera status");
    let shown = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success() && shown.contains("frames: 4/4 frames done"), "{shown}");
}
