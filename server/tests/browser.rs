//! The status page in a real browser: headless Chromium driven over WebDriver (chromedriver),
//! against a real server with a real worker process.
//!
//! Needs `chromium` and `chromedriver` (Debian: `chromium`, `chromium-driver`; `.ci/run` installs
//! them and sets `TESSERA_REQUIRE_BROWSER=1`, so CI cannot skip these tests). Without them, and
//! without that variable, the tests print why and pass without checking anything.

mod support;

use std::time::Duration;

use serde_json::json;
use support::browser::*;
use support::*;

/// The sum of the preview canvas's pixel bytes (0 for a blank canvas).
const CANVAS_SUM: &str = "(() => { const c = document.querySelector('.frame canvas'); if (!c) return 0; \
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; let s = 0, lit = 0; \
    for (let i = 0; i < d.length; i += 4) { const v = d[i] + d[i+1] + d[i+2]; s += v; if (v > 30) lit++; } \
    return lit > 1000 ? s : 0; })()";

#[test]
fn the_page_follows_a_render_live_and_retonemaps_it() {
    let _s = serial();
    let Some(browser) = Browser::start() else { return };
    let server = Server::start_temp(
        "farm-browser",
        &["--local-workers", "1", "--local-worker-threads", "2", "--tile-size", "32"],
    );
    browser.goto(&server.url);
    assert_eq!(browser.exec("return document.title;"), json!("Tessera render farm"));
    browser.wait("the live connection", 20, "document.querySelector('#live').textContent === 'live'");
    browser.wait(
        "the local worker in the table",
        20,
        "document.querySelector('#workers tbody').innerText.includes('local-1')",
    );

    // Submit the environment demo (an HDR scene) from the page: scene and asset picked as files.
    // chromedriver wants canonical paths.
    let scene = repo().join("scenes/environment.xml").canonicalize().unwrap();
    let sky = repo().join("scenes/textures/sky.hdr").canonicalize().unwrap();
    browser.type_into("#files", &format!("{}\n{}", scene.display(), sky.display()));
    browser.type_into("#samples", "64");
    browser.click("#submit-button");
    browser.wait("the job to be accepted", 60, "!document.querySelector('#submit-ok').hidden");

    // While it renders, the preview fills in from tile events.
    browser.wait(
        "a drawn preview",
        60,
        "document.querySelector('.frame') && Number(document.querySelector('.frame').dataset.drawn) >= 1",
    );
    browser.wait(
        "a preview half done",
        120,
        "Number(document.querySelector('.frame').dataset.percent) >= 45",
    );
    // Let the throttled preview catch up before the picture.
    std::thread::sleep(Duration::from_millis(900));
    let pct = browser.exec("return document.querySelector('.frame').dataset.percent;");
    let shot = browser.screenshot();
    assert!(shot.starts_with(b"\x89PNG"));
    let target = repo().join("target");
    let _ = std::fs::create_dir_all(&target);
    std::fs::write(target.join("browser-during-render.png"), &shot).unwrap();
    if std::env::var_os("TESSERA_UPDATE_SCREENSHOT").is_some() {
        std::fs::write(repo().join("docs/screenshot.png"), &shot).unwrap();
    }
    eprintln!("screenshot at {pct}% written to target/browser-during-render.png");

    // Progress reaches 100 % in the page, with the output links.
    browser.wait("100 %", 180, "document.querySelector('.frame').dataset.percent === '100' && document.querySelectorAll('.frame .links a').length === 2");
    browser.wait("the job state done", 30, "document.querySelector('.job .state').textContent === 'done'");
    let links = browser
        .exec("return [...document.querySelectorAll('.frame .links a')].map(a => a.textContent).join(',');");
    assert_eq!(links, json!("environment.exr,environment.png"));
    // The canvas shows the picture.
    let before = browser.wait("a non-blank canvas", 30, CANVAS_SUM);

    // Re-tone-mapping: a brighter key redraws the canvas from the stored EXR.
    browser.wait("the tone sliders", 30, "!document.querySelector('.tone').hidden");
    browser.exec("const s = document.querySelector('input.tone-key'); s.value = '0.9'; s.dispatchEvent(new Event('input')); return 1;");
    // Other draws (the final PNG, a trailing preview) may land in between: wait for the picture
    // itself to get brighter.
    let threshold = before.as_f64().unwrap() * 1.2;
    let after =
        browser.wait("the re-tone-mapped, brighter picture", 30, &format!("{CANVAS_SUM} > {threshold}"));
    assert!(after.as_bool() == Some(true), "{after}");
    let src = browser.exec("return document.querySelector('.tone a.retoned').getAttribute('href');");
    assert!(src.as_str().unwrap().contains("tonemap.png?key=0.9"), "{src}");
    // The workers table shows the work done.
    let table = browser.exec("return document.querySelector('#workers tbody').innerText;");
    assert!(table.as_str().unwrap().contains("local-1"), "{table}");
}

#[test]
fn a_bad_upload_shows_its_error_on_the_page() {
    let _s = serial();
    let Some(browser) = Browser::start() else { return };
    let server = Server::start_temp("farm-browser-bad", &["--local-workers", "0"]);
    let dir = TempDir::new("farm-browser-bad-scene");
    let bad = dir.canonicalize().unwrap().join("broken.xml");
    std::fs::write(
        &bad,
        "<Scene>\n<Cameras>\n<Camera id=\"1\"><Position>0 zero 0</Position></Camera>\n</Cameras>\n</Scene>\n",
    )
    .unwrap();
    browser.goto(&server.url);
    browser.type_into("#files", &bad.display().to_string());
    browser.click("#submit-button");
    let text = browser.submit_error();
    assert!(
        text.contains("expected 3 numbers") && text.contains("line 3") && text.contains("broken.xml"),
        "{text}"
    );
    // No job was created.
    assert_eq!(browser.exec("return document.querySelectorAll('.job').length;"), json!(0));
}

/// The page's "Denoise" box sends `denoise=true`: a server without the denoiser answers it with
/// its 422, which the page shows (and no job is made).
#[test]
fn the_denoise_box_asks_the_server_to_denoise() {
    let _s = serial();
    let Some(browser) = Browser::start() else { return };
    let data = TempDir::new("farm-browser-denoise");
    let server = Server::start_with(&data, &["--local-workers", "0"], |cmd| {
        cmd.env("TESSERA_OIDN_LIB", "/nonexistent/oidn");
    });
    let dir = TempDir::new("farm-browser-denoise-scene");
    let scene = dir.canonicalize().unwrap().join("tiny.xml");
    std::fs::write(&scene, tessera_testkit::tiny_scene(8, 8)).unwrap();
    browser.goto(&server.url);
    browser.type_into("#files", &scene.display().to_string());
    browser.click("#denoise");
    browser.click("#submit-button");
    let text = browser.submit_error();
    assert!(text.contains("this server cannot denoise") && text.contains("pip install pyoidn"), "{text}");
    assert_eq!(browser.exec("return document.querySelectorAll('.job').length;"), json!(0));
}

#[test]
fn a_jobs_log_shows_its_tiles_as_a_worker_renders_them() {
    let _s = serial();
    let Some(browser) = Browser::start() else { return };
    let server = Server::start_temp(
        "farm-browser-log",
        &["--local-workers", "1", "--local-worker-threads", "1", "--tile-size", "8"],
    );
    browser.goto(&server.url);
    browser.wait("the live connection", 20, "document.querySelector('#live').textContent === 'live'");
    // Submitted over the API, not the page: the page learns of it from the event stream.
    let scene = tessera_testkit::tiny_scene(16, 8);
    let (code, job) =
        submit(&server.url, None, &[("scene", Some("tiny.xml"), &scene), ("tile_size", None, b"8")]);
    assert_eq!(code, 201, "{job}");
    let id = job["id"].as_u64().unwrap();
    let lines = format!("document.querySelectorAll('.job[data-job-id=\"{id}\"] .log-lines li')");
    browser.wait(
        "the accepted line",
        30,
        &format!("{lines}.length >= 1 && {lines}[0].innerText.includes('accepted')"),
    );
    // The tiles' lines arrive as the worker renders them, with its name and render time, and
    // the job's end after them.
    let tile_line = browser.wait(
        "a tile_done line",
        60,
        &format!("[...{lines}].map(l => l.innerText).find(t => t.includes('tile_done'))"),
    );
    let tile_line = tile_line.as_str().unwrap();
    assert!(tile_line.contains("on local-1") && tile_line.contains(" s"), "{tile_line}");
    browser.wait(
        "the job_done line",
        60,
        &format!("[...{lines}].some(l => l.innerText.includes('job_done'))"),
    );
    // Each event once, in order, though the page asked for the log many times.
    let seqs = browser.exec(&format!("return [...{lines}].map(l => Number(l.dataset.seq));"));
    let n = seqs.as_array().unwrap().len() as u64;
    assert_eq!(seqs, json!((1..=n).collect::<Vec<u64>>()));
    let served = get_json(&server.url, &format!("/api/v1/jobs/{id}/log"));
    assert_eq!(served["events"].as_array().unwrap().len() as u64, n, "{served}");
}

/// A frame in passes refines on the page: the form sends pass samples and a noise target, the
/// frame says which pass every tile has reached and links the latest pass's files.
#[test]
fn the_page_shows_a_frame_refining_pass_by_pass() {
    let _s = serial();
    let Some(browser) = Browser::start() else { return };
    let dir = TempDir::new("farm-browser-passes");
    let Some(scene) = tessera_testkit::small_path_traced_box(dir.path()) else { return };
    let server = Server::start_temp(
        "farm-browser-passes-data",
        &["--local-workers", "1", "--local-worker-threads", "1", "--tile-size", "48"],
    );
    browser.goto(&server.url);
    browser.wait("the live connection", 20, "document.querySelector('#live').textContent === 'live'");
    browser.type_into("#files", &scene.canonicalize().unwrap().display().to_string());
    browser.type_into("#samples", "320");
    browser.type_into("#pass-samples", "32");
    browser.type_into("#noise-target", "0.001");
    browser.click("#submit-button");
    browser.wait("the job to be accepted", 60, "!document.querySelector('#submit-ok').hidden");
    // The first camera's frame: after its first pass it says so and links pass.exr and pass.png.
    let frame = "document.querySelector('.frame')";
    browser.wait("a published pass", 120, &format!("{frame} && Number({frame}.dataset.passes) >= 1"));
    let text = browser.wait(
        "the pass's files",
        30,
        &format!("{frame}.querySelector('.links').innerText.includes('pass.exr (after pass')"),
    );
    assert_eq!(text, json!(true));
    let progress = browser.exec(&format!("return {frame}.querySelector('.progress-text').textContent;"));
    assert!(progress.as_str().unwrap().starts_with("pass "), "{progress}");
    let job = get_json(&server.url, "/api/v1/jobs")["jobs"][0].clone();
    assert_eq!(job["frames"][0]["passes_total"], 10, "{job}");
    cancel(&server, job["id"].as_u64().unwrap());
}

/// A job of many frames is shown as a sequence (counts, one small cell a frame, the latest frame
/// large) and, once done, plays its video: here a GIF (`video=gif`, made without ffmpeg) in an
/// `<img>`, which loads under the page's Content-Security-Policy.
#[test]
fn a_sequence_shows_its_frames_compactly_and_plays_its_video() {
    let _s = serial();
    let Some(browser) = Browser::start() else { return };
    let server = Server::start_temp(
        "farm-browser-video",
        &["--local-workers", "1", "--local-worker-threads", "1", "--tile-size", "64"],
    );
    browser.goto(&server.url);
    browser.wait("the live connection", 20, "document.querySelector('#live').textContent === 'live'");
    // Twelve cameras sliding past a sphere under an ambient light.
    let cams: String = (0..12)
        .map(|k| {
            format!(
                "<Camera id=\"{}\"><Position>{:.2} 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>\
                 <NearPlane>-1 1 -0.75 0.75</NearPlane><NearDistance>1</NearDistance>\
                 <ImageResolution>32 24</ImageResolution><ImageName>f{k:02}.png</ImageName></Camera>",
                k + 1,
                f64::from(k) * 0.2 - 1.1
            )
        })
        .collect();
    let scene = format!(
        "<Scene><BackgroundColor>10 20 60</BackgroundColor><Cameras>{cams}</Cameras>\
         <Lights><AmbientLight>200 200 200</AmbientLight></Lights>\
         <Materials><Material id=\"1\"><AmbientReflectance>1 0.5 0.2</AmbientReflectance></Material></Materials>\
         <VertexData>0 0 -5</VertexData><Objects><Sphere id=\"1\"><Material>1</Material><Center>1</Center><Radius>1</Radius></Sphere></Objects></Scene>"
    );
    // Submitted from the page's form, with its video options.
    let dir = TempDir::new("farm-browser-video-scene");
    let file = dir.canonicalize().unwrap().join("slide.xml");
    std::fs::write(&file, &scene).unwrap();
    browser.type_into("#files", &file.display().to_string());
    browser.type_into("#samples", "1");
    browser.exec("document.querySelector('#video').value = 'gif'; return 1;");
    browser.type_into("#fps", "8");
    browser.click("#submit-button");
    browser.wait("the job to be accepted", 60, "!document.querySelector('#submit-ok').hidden");
    let job = get_json(&server.url, "/api/v1/jobs")["jobs"][0].clone();
    assert_eq!(
        (job["video"]["kind"].as_str(), job["video"]["fps"].as_u64()),
        (Some("gif"), Some(8)),
        "{job}"
    );
    let id = job["id"].as_u64().unwrap();
    let node = format!("document.querySelector('.job[data-job-id=\"{id}\"]')");
    // One cell a frame, not one block a frame.
    browser.wait(
        "the sequence's cells",
        60,
        &format!("{node} && {node}.querySelectorAll('.seq-cell').length === 12"),
    );
    assert_eq!(browser.exec(&format!("return {node}.querySelectorAll('.frame').length;")), json!(0));
    browser.wait(
        "every frame done",
        120,
        &format!("{node}.querySelectorAll('.seq-cell.done').length === 12"),
    );
    let counts = browser.wait(
        "the counts",
        30,
        &format!("{node}.querySelector('.seq-counts').textContent.includes('12 done') && {node}.querySelector('.seq-counts').textContent"),
    );
    assert!(counts.as_str().unwrap().starts_with("12 frames"), "{counts}");
    // The latest frame shown large, loaded.
    browser.wait(
        "the last frame large",
        30,
        &format!("{node}.querySelector('.seq-view').dataset.frame === '11' && {node}.querySelector('.seq-frame').naturalWidth === 32"),
    );
    // The video: a GIF in an <img>, loaded (its natural size is the frames').
    let player = format!("{node}.querySelector('.video img.player')");
    browser.wait(
        "the video player",
        60,
        &format!("{player} && {player}.complete && {player}.naturalWidth === 32"),
    );
    let line = browser.exec(&format!("return {node}.querySelector('.video-state').textContent;"));
    assert!(line.as_str().unwrap().contains("GIF, 8 fps): done"), "{line}");
    let href = browser.exec(&format!("return {node}.querySelector('.video-link').getAttribute('href');"));
    assert_eq!(href, json!(format!("/api/v1/jobs/{id}/video.gif")));
    // A click on a cell shows that frame.
    browser.exec(&format!("{node}.querySelectorAll('.seq-cell')[3].click(); return 1;"));
    browser.wait("frame 3 large", 30, &format!("{node}.querySelector('.seq-view').dataset.frame === '3'"));
}
