//! A job's video (issue #71 item 5), with the real binaries: a job of 24 frames (24 cameras of a
//! tiny scene) makes an MP4 that ffprobe reads as 24 H.264 yuv420p frames at 24 fps, padded to
//! even sides, whose first frame is the job's first PNG (PSNR after a 4x4 box); `video=gif`
//! makes a looping GIF of 24 frames without ffmpeg; `video=mp4` on a server without ffmpeg and
//! a video of frames of different sizes are 422s that say what to do; an ffmpeg that fails
//! leaves the frames done with a `video_failed` event saying why; a server killed while
//! encoding makes the video when it starts again.
//!
//! The MP4 tests need Debian's `ffmpeg` (ffmpeg and ffprobe on PATH): without them they say so
//! and pass, unless `TESSERA_REQUIRE_FFMPEG=1` (set by `.ci/run`), where they fail.

mod support;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use serde_json::Value;
use support::*;

/// Frames of the test jobs: 24 cameras circling a sphere.
const FRAMES: usize = 24;

/// A scene of `n` cameras of `width` x `height` circling a sphere (so that the frames differ),
/// the last one `last` pixels wide instead when given.
fn circling_scene(n: usize, (width, height): (u32, u32), last: Option<u32>) -> Vec<u8> {
    let mut cams = String::new();
    for k in 0..n {
        let a = k as f64 / n as f64 * std::f64::consts::TAU;
        let (x, z) = (5.0 * a.sin(), 5.0 * a.cos());
        let w = if k + 1 == n { last.unwrap_or(width) } else { width };
        let half = f64::from(w) / f64::from(height);
        cams.push_str(&format!(
            "<Camera id=\"{id}\"><Position>{x:.4} 0.5 {z:.4}</Position><Gaze>{gx:.4} -0.1 {gz:.4}</Gaze><Up>0 1 0</Up>\
             <NearPlane>-{half:.4} {half:.4} -1 1</NearPlane><NearDistance>1.5</NearDistance>\
             <ImageResolution>{w} {height}</ImageResolution><ImageName>f{k:02}.png</ImageName></Camera>\n",
            id = k + 1,
            gx = -x,
            gz = -z,
        ));
    }
    format!(
        r#"<Scene>
    <BackgroundColor>20 40 90</BackgroundColor>
    <Cameras>{cams}</Cameras>
    <Lights>
        <AmbientLight>30 30 30</AmbientLight>
        <PointLight id="1"><Position>3 4 4</Position><Intensity>900 900 900</Intensity></PointLight>
    </Lights>
    <Materials>
        <Material id="1"><DiffuseReflectance>0.9 0.4 0.2</DiffuseReflectance></Material>
        <Material id="2"><DiffuseReflectance>0.2 0.8 0.3</DiffuseReflectance></Material>
    </Materials>
    <VertexData>0 0 0
        1.2 0.3 0</VertexData>
    <Objects>
        <Sphere id="1"><Material>1</Material><Center>1</Center><Radius>1</Radius></Sphere>
        <Sphere id="2"><Material>2</Material><Center>2</Center><Radius>0.4</Radius></Sphere>
    </Objects>
</Scene>
"#
    )
    .into_bytes()
}

/// Whether ffmpeg and ffprobe are on PATH; without them the MP4 tests pass saying so, unless
/// `TESSERA_REQUIRE_FFMPEG=1`.
fn have_ffmpeg(test: &str) -> bool {
    let runs = |p: &str| Command::new(p).arg("-version").output().is_ok_and(|o| o.status.success());
    if runs("ffmpeg") && runs("ffprobe") {
        return true;
    }
    assert!(
        std::env::var("TESSERA_REQUIRE_FFMPEG").map_or(true, |v| v.is_empty() || v == "0"),
        "TESSERA_REQUIRE_FFMPEG is set but ffmpeg/ffprobe are not on PATH (apt-get install ffmpeg)"
    );
    eprintln!("\n*** SKIPPED {test}: no ffmpeg/ffprobe on PATH (apt-get install ffmpeg) ***\n");
    false
}

/// A server with one local worker of one thread, `ffmpeg` as its TESSERA_FFMPEG (unset: PATH).
fn server(data: &Path, ffmpeg: Option<&Path>) -> Server {
    Server::start_with(
        data,
        &["--local-workers", "1", "--local-worker-threads", "1", "--tile-size", "64"],
        |c| {
            c.env_remove("TESSERA_FFMPEG");
            if let Some(f) = ffmpeg {
                c.env("TESSERA_FFMPEG", f);
            }
        },
    )
}

/// Submits the circling scene with `options`; (status, answer).
fn submit_scene(server: &Server, scene: &[u8], options: &[(&str, &str)]) -> (u16, Value) {
    let mut parts: Vec<(&str, Option<&str>, &[u8])> =
        vec![("scene", Some("circle.xml"), scene), ("samples", None, b"1")];
    for (k, v) in options {
        parts.push((k, None, v.as_bytes()));
    }
    submit(&server.url, None, &parts)
}

/// Waits until the job's video is done or failed; the job.
fn wait_video(server: &Server, id: u64) -> Value {
    wait_job(server, id, 120, |j| {
        j["state"] == "done" && matches!(j["video"]["state"].as_str(), Some("done" | "failed"))
    })
}

fn events(server: &Server, id: u64) -> Vec<Value> {
    get_json(&server.url, &format!("/api/v1/jobs/{id}/log"))["events"].as_array().unwrap().clone()
}

/// (status, Content-Type, body) of a GET.
fn get_raw(url: &str) -> (u16, String, Vec<u8>) {
    use std::io::Read;
    let r = match ureq::get(url).call() {
        Ok(r) => r,
        Err(ureq::Error::Status(_, r)) => r,
        Err(e) => panic!("GET {url}: {e}"),
    };
    let (status, ct) = (r.status(), r.content_type().to_string());
    let mut body = Vec::new();
    r.into_reader().read_to_end(&mut body).unwrap();
    (status, ct, body)
}

/// ffprobe's answer about the video stream of `file`, counting its frames.
fn ffprobe(file: &Path) -> Value {
    let out = Command::new("ffprobe")
        .args(["-v", "error", "-select_streams", "v:0", "-count_frames", "-show_entries"])
        .arg("stream=codec_name,pix_fmt,width,height,r_frame_rate,avg_frame_rate,nb_read_frames")
        .args(["-of", "json"])
        .arg(file)
        .output()
        .expect("run ffprobe");
    assert!(out.status.success(), "ffprobe: {}", String::from_utf8_lossy(&out.stderr));
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    v["streams"][0].clone()
}

/// 4x4 box averages of an RGB image's first `w` x `h` pixels, as floats.
fn box4(img: &image::RgbImage, w: u32, h: u32) -> Vec<f64> {
    let mut out = Vec::new();
    for by in 0..h / 4 {
        for bx in 0..w / 4 {
            for c in 0..3 {
                let mut s = 0.0;
                for y in 0..4 {
                    for x in 0..4 {
                        s += f64::from(img.get_pixel(bx * 4 + x, by * 4 + y)[c]);
                    }
                }
                out.push(s / 16.0);
            }
        }
    }
    out
}

/// PSNR in dB of `a` against `b` over their first `w` x `h` pixels after a 4x4 box.
fn psnr_box4(a: &image::RgbImage, b: &image::RgbImage, w: u32, h: u32) -> f64 {
    let (a, b) = (box4(a, w, h), box4(b, w, h));
    let mse = a.iter().zip(&b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>() / a.len() as f64;
    10.0 * (255.0 * 255.0 / mse.max(1e-12)).log10()
}

/// Frame `k` of `video` decoded by ffmpeg into a PNG in `dir`.
fn decode_frame(video: &Path, k: usize, dir: &Path) -> image::RgbImage {
    let png = dir.join(format!("decoded{k}.png"));
    let out = Command::new("ffmpeg")
        .args(["-v", "error", "-y", "-i"])
        .arg(video)
        .args(["-vf", &format!("select=eq(n\\,{k})"), "-frames:v", "1"])
        .arg(&png)
        .output()
        .expect("run ffmpeg");
    assert!(out.status.success(), "ffmpeg decode: {}", String::from_utf8_lossy(&out.stderr));
    image::open(&png).unwrap().into_rgb8()
}

/// The first PNG output of frame `k` of a finished job.
fn frame_png(server: &Server, job: &Value, k: usize) -> image::RgbImage {
    let f = &job["frames"][k];
    let url = f["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .find(|o| o["name"].as_str().unwrap().ends_with(".png"))
        .unwrap()["url"]
        .as_str()
        .unwrap()
        .to_string();
    image::load_from_memory(&get_bytes(&server.url, &url)).unwrap().into_rgb8()
}

/// An executable script in `dir`.
fn script(dir: &Path, name: &str, body: &str) -> PathBuf {
    use std::os::unix::fs::PermissionsExt;
    let p = dir.join(name);
    std::fs::write(&p, format!("#!/bin/sh\n{body}\n")).unwrap();
    std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).unwrap();
    p
}

#[test]
fn a_job_of_24_frames_makes_an_mp4_of_24_frames_at_its_fps() {
    let _serial = serial();
    if !have_ffmpeg("a_job_of_24_frames_makes_an_mp4_of_24_frames_at_its_fps") {
        return;
    }
    let dir = TempDir::new("video-mp4");
    let server = server(&dir.path().join("data"), None);
    // Odd sides: the video is padded to even ones.
    let scene = circling_scene(FRAMES, (33, 25), None);
    let started = Instant::now();
    let (code, job) = submit_scene(&server, &scene, &[("video", "mp4"), ("fps", "24")]);
    assert_eq!(code, 201, "{job}");
    let id = job["id"].as_u64().unwrap();
    assert_eq!(job["video"]["kind"], "mp4", "{job}");
    assert_eq!(job["video"]["fps"], 24);
    assert_eq!(job["video"]["state"], "waiting");
    let job = wait_video(&server, id);
    eprintln!("24 frames rendered and encoded in {:.2} s", started.elapsed().as_secs_f64());
    assert_eq!(job["video"]["state"], "done", "{job}");
    let url = job["video"]["url"].as_str().unwrap();
    assert_eq!(url, format!("/api/v1/jobs/{id}/video.mp4"));
    let (status, ct, body) = get_raw(&format!("{}{url}", server.url));
    assert_eq!((status, ct.as_str()), (200, "video/mp4"));
    let mp4 = dir.path().join("got.mp4");
    std::fs::write(&mp4, &body).unwrap();
    let s = ffprobe(&mp4);
    assert_eq!(s["codec_name"], "h264", "{s}");
    assert_eq!(s["pix_fmt"], "yuv420p", "{s}");
    assert_eq!((s["width"].as_u64(), s["height"].as_u64()), (Some(34), Some(26)), "{s}");
    assert_eq!(s["r_frame_rate"], "24/1", "{s}");
    assert_eq!(s["avg_frame_rate"], "24/1", "{s}");
    assert_eq!(s["nb_read_frames"], FRAMES.to_string(), "{s}");
    // `+faststart`: the index (moov) comes before the media data (mdat).
    let at = |tag: &[u8]| body.windows(4).position(|w| w == tag).unwrap();
    assert!(at(b"moov") < at(b"mdat"), "the MP4 is not +faststart");
    // Its frames are the job's pictures (lossy: compared after a 4x4 box).
    for k in [0, FRAMES - 1] {
        let (png, decoded) = (frame_png(&server, &job, k), decode_frame(&mp4, k, dir.path()));
        let db = psnr_box4(&decoded, &png, 32, 24);
        eprintln!("frame {k}: PSNR after a 4x4 box {db:.1} dB");
        assert!(db >= 35.0, "frame {k} of the MP4 is not the job's frame {k}: {db:.1} dB");
    }
    let done: Vec<Value> = events(&server, id).into_iter().filter(|e| e["kind"] == "video_done").collect();
    assert_eq!(done.len(), 1, "one video_done event");
    assert!(done[0]["seconds"].as_f64().unwrap() > 0.0);
    assert!(done[0]["message"].as_str().unwrap().contains("video.mp4 written: 24 frames"), "{}", done[0]);
    // Not a GIF, and asked for as one: a 404 that says what there is.
    let (status, _, body) = get_raw(&format!("{}/api/v1/jobs/{id}/video.gif", server.url));
    assert_eq!(status, 404);
    assert!(String::from_utf8_lossy(&body).contains("video.mp4"));
}

#[test]
fn video_gif_needs_no_ffmpeg_and_video_mp4_without_it_is_refused() {
    let _serial = serial();
    let dir = TempDir::new("video-gif");
    let missing = dir.path().join("no-such-ffmpeg");
    let server = server(&dir.path().join("data"), Some(&missing));
    let scene = circling_scene(FRAMES, (32, 24), None);

    // An MP4 needs ffmpeg: refused before anything is stored, saying how to get it.
    let (code, body) = submit_scene(&server, &scene, &[("video", "mp4")]);
    assert_eq!(code, 422, "{body}");
    let error = body["error"].as_str().unwrap();
    for needed in ["video=mp4", "TESSERA_FFMPEG", "ffmpeg package", "video=gif"] {
        assert!(error.contains(needed), "{needed} not in: {error}");
    }
    assert!(!error.contains(&*missing.to_string_lossy()), "a server path in: {error}");
    assert_eq!(get_json(&server.url, "/api/v1/jobs")["jobs"].as_array().unwrap().len(), 0);
    let (code, body) = submit_scene(&server, &scene, &[("video", "avi")]);
    assert_eq!(code, 400, "{body}");
    assert!(body["error"].as_str().unwrap().contains("mp4, gif or none"), "{body}");
    let (code, body) = submit_scene(&server, &scene, &[("video", "gif"), ("fps", "0")]);
    assert_eq!(code, 400, "{body}");
    assert!(body["error"].as_str().unwrap().contains("fps"), "{body}");

    // Frames of different sizes: no video, and the 422 names the first frame that differs.
    let uneven = circling_scene(3, (32, 24), Some(40));
    let (code, body) = submit_scene(&server, &uneven, &[("video", "gif")]);
    assert_eq!(code, 422, "{body}");
    assert!(body["error"].as_str().unwrap().contains("frame 2 is 40x24 while frame 0 is 32x24"), "{body}");
    // ... and without asking for a video, such a job renders.
    let (code, body) = submit_scene(&server, &uneven, &[]);
    assert_eq!(code, 201, "{body}");
    assert!(body["video"].is_null(), "one scene file makes no video by default: {body}");

    // A GIF, made by the server itself.
    let (code, job) = submit_scene(&server, &scene, &[("video", "gif"), ("fps", "10")]);
    assert_eq!(code, 201, "{job}");
    let id = job["id"].as_u64().unwrap();
    let job = wait_video(&server, id);
    assert_eq!(job["video"]["state"], "done", "{job}");
    assert_eq!(job["video"]["kind"], "gif");
    let (status, ct, body) = get_raw(&format!("{}/api/v1/jobs/{id}/video.gif", server.url));
    assert_eq!((status, ct.as_str()), (200, "image/gif"));
    // Players seek with byte ranges.
    let gif_url = format!("{}/api/v1/jobs/{id}/video.gif", server.url);
    let part = ureq::get(&gif_url).set("Range", "bytes=6-105").call().unwrap();
    assert_eq!(part.status(), 206);
    assert_eq!(part.header("Content-Range"), Some(format!("bytes 6-105/{}", body.len()).as_str()));
    let mut got = Vec::new();
    std::io::Read::read_to_end(&mut part.into_reader(), &mut got).unwrap();
    assert_eq!(got, body[6..106]);
    let tail = ureq::get(&gif_url).set("Range", "bytes=-10").call().unwrap();
    assert_eq!(
        tail.header("Content-Range"),
        Some(format!("bytes {}-{}/{}", body.len() - 10, body.len() - 1, body.len()).as_str())
    );
    let past = ureq::get(&gif_url).set("Range", &format!("bytes={}-", body.len())).call();
    assert!(matches!(past, Err(ureq::Error::Status(416, _))), "{past:?}");
    use image::AnimationDecoder;
    let frames = image::codecs::gif::GifDecoder::new(std::io::Cursor::new(&body))
        .unwrap()
        .into_frames()
        .collect_frames()
        .unwrap();
    assert_eq!(frames.len(), FRAMES);
    assert_eq!(frames[0].delay().numer_denom_ms(), (100, 1), "10 fps: 100 ms a frame");
    assert_eq!(frames[0].buffer().dimensions(), (32, 24));
    // Each GIF frame is its frame's picture, within the palette's error.
    for k in [0, FRAMES / 2] {
        let png = frame_png(&server, &job, k);
        let gif = image::DynamicImage::ImageRgba8(frames[k].buffer().clone()).into_rgb8();
        let db = psnr_box4(&gif, &png, 32, 24);
        assert!(db >= 30.0, "GIF frame {k}: {db:.1} dB");
    }
    assert!(events(&server, id).iter().any(|e| e["kind"] == "video_done"));
}

#[test]
fn a_failing_ffmpeg_leaves_the_frames_done_and_says_why() {
    let _serial = serial();
    let dir = TempDir::new("video-fail");
    let broken = script(
        dir.path(),
        "ffmpeg",
        "cat >/dev/null; echo 'simulated encoder failure: no libx264' >&2; exit 1",
    );
    let server = server(&dir.path().join("data"), Some(&broken));
    let (code, job) = submit_scene(&server, &circling_scene(FRAMES, (16, 12), None), &[("video", "mp4")]);
    assert_eq!(code, 201, "{job}");
    let id = job["id"].as_u64().unwrap();
    let job = wait_video(&server, id);
    assert_eq!(job["state"], "done", "the frames stay done: {job}");
    assert_eq!(job["video"]["state"], "failed", "{job}");
    let message = job["video"]["message"].as_str().unwrap();
    assert!(
        message.contains("simulated encoder failure") && message.contains("the frames are done"),
        "{message}"
    );
    assert!(job["frames"].as_array().unwrap().iter().all(|f| !f["outputs"].as_array().unwrap().is_empty()));
    let failed: Vec<Value> =
        events(&server, id).into_iter().filter(|e| e["kind"] == "video_failed").collect();
    assert_eq!(failed.len(), 1, "one video_failed event");
    assert!(failed[0]["message"].as_str().unwrap().contains("simulated encoder failure"));
    let data = dir.path().join("data").to_string_lossy().into_owned();
    assert!(!message.contains(&data), "a server path in: {message}");
    let (status, _, body) = get_raw(&format!("{}/api/v1/jobs/{id}/video.mp4", server.url));
    assert_eq!(status, 404);
    assert!(String::from_utf8_lossy(&body).contains("simulated encoder failure"));
    // No half file left behind.
    let job_dir = dir.path().join("data/frames").join(id.to_string());
    let left: Vec<String> = std::fs::read_dir(&job_dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains("video"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}

#[test]
fn a_server_killed_while_encoding_makes_the_video_when_it_starts_again() {
    let _serial = serial();
    if !have_ffmpeg("a_server_killed_while_encoding_makes_the_video_when_it_starts_again") {
        return;
    }
    let dir = TempDir::new("video-restart");
    let data = dir.path().join("data");
    // An ffmpeg that never finishes (it gives up after 20 s on its own once orphaned).
    let stuck = script(dir.path(), "ffmpeg", "sleep 20; exit 1");
    let mut first = server(&data, Some(&stuck));
    let (code, job) = submit_scene(&first, &circling_scene(FRAMES, (16, 12), None), &[("video", "mp4")]);
    assert_eq!(code, 201, "{job}");
    let id = job["id"].as_u64().unwrap();
    wait_job(&first, id, 60, |j| j["state"] == "done" && j["video"]["state"] == "encoding");
    std::thread::sleep(Duration::from_millis(300));
    first.kill9();
    drop(first);
    let second = server(&data, None);
    let job = wait_video(&second, id);
    assert_eq!(job["video"]["state"], "done", "{job}");
    let mp4 = dir.path().join("after.mp4");
    std::fs::write(&mp4, get_bytes(&second.url, &format!("/api/v1/jobs/{id}/video.mp4"))).unwrap();
    assert_eq!(ffprobe(&mp4)["nb_read_frames"], FRAMES.to_string());
}
