//! A queue of hundreds of thousands of tiles (issue #16 item 5), with the real binaries: the
//! default server refuses a job cut into more tiles than `--max-job-tiles` with a 422 that
//! names the limit and a tile size that fits; a server whose operator raised the limit takes
//! an 800x800 frame in one-pixel tiles (640 000 of them), and a high-priority job submitted
//! behind it is leased before the big job's next tile and renders to the end, while listing
//! and cancelling stay quick.
//!
//! The times printed here are figures for the notes, not assertions: a slow machine is not a
//! failure. What is asserted is the order of events: the small job overtakes the big one.

mod support;

use std::io::BufRead;
use std::time::Instant;

use support::*;

/// An 800x800 frame of one diffuse sphere under a point light.
fn big_scene() -> Vec<u8> {
    br#"<Scene>
    <BackgroundColor>10 10 10</BackgroundColor>
    <Cameras>
        <Camera id="1">
            <Position>0 0 5</Position>
            <Gaze>0 0 -1</Gaze>
            <Up>0 1 0</Up>
            <NearPlane>-1 1 -1 1</NearPlane>
            <NearDistance>1</NearDistance>
            <ImageResolution>800 800</ImageResolution>
            <ImageName>big.png</ImageName>
        </Camera>
    </Cameras>
    <Lights>
        <AmbientLight>20 20 20</AmbientLight>
        <PointLight id="1"><Position>2 2 4</Position><Intensity>200 200 200</Intensity></PointLight>
    </Lights>
    <Materials>
        <Material id="1"><DiffuseReflectance>0.8 0.5 0.3</DiffuseReflectance></Material>
    </Materials>
    <VertexData>0 0 0</VertexData>
    <Objects>
        <Sphere id="1"><Material>1</Material><Center>1</Center><Radius>1</Radius></Sphere>
    </Objects>
</Scene>
"#
    .to_vec()
}

fn submit_big(server: &Server, tile_size: &str) -> (u16, serde_json::Value) {
    let scene = big_scene();
    submit(
        &server.url,
        None,
        &[
            ("scene", Some("big.xml"), &scene),
            ("tile_size", None, tile_size.as_bytes()),
            ("samples", None, b"1"),
        ],
    )
}

#[test]
fn a_job_of_more_tiles_than_the_limit_is_refused_with_a_tile_size_that_fits() {
    let _s = serial();
    let server = Server::start_temp("farm-queue-refused", &["--local-workers", "0"]);
    let (code, body) = submit_big(&server, "1");
    assert_eq!(code, 422, "{body}");
    let msg = body["error"].as_str().unwrap_or_default();
    assert!(msg.contains("640000 tiles"), "{msg}");
    assert!(msg.contains("--max-job-tiles") && msg.contains("TESSERA_MAX_JOB_TILES"), "{msg}");
    // 800/2 = 400 per side is 160 000 tiles, over 100 000; 800/3 rounds up to 267 per side.
    assert!(msg.contains("tile_size=3"), "{msg}");
    // Nothing was stored.
    assert_eq!(get_json(&server.url, "/api/v1/jobs")["jobs"].as_array().unwrap().len(), 0);
    // The advice works.
    let (code, body) = submit_big(&server, "3");
    assert_eq!(code, 201, "{body}");
}

#[test]
fn a_high_priority_job_overtakes_640000_queued_tiles() {
    let _s = serial();
    let server = Server::start_temp(
        "farm-queue-big",
        &["--local-workers", "1", "--local-worker-threads", "1", "--max-job-tiles", "1000000"],
    );
    let t0 = Instant::now();
    let (code, body) = submit_big(&server, "1");
    let took_submit = t0.elapsed();
    assert_eq!(code, 201, "{body}\n{}", server.log());
    let big = body["id"].as_u64().unwrap();
    assert_eq!(body["frames"][0]["tiles_total"].as_u64(), Some(640_000), "{body}");
    eprintln!("submitting 640000 tiles took {:.2} s", took_submit.as_secs_f64());
    let running = wait_job(&server, big, 60, |j| tiles_done(j) > 0);
    assert_eq!(running["state"], "running", "{running}");

    // The order in which tiles come back, from the server's event stream.
    let tiles = std::sync::Arc::new(std::sync::Mutex::new(Vec::<u64>::new()));
    {
        let tiles = tiles.clone();
        let resp = ureq::get(&format!("{}/api/v1/events", server.url)).call().unwrap();
        std::thread::spawn(move || {
            for line in std::io::BufReader::new(resp.into_reader()).lines() {
                let Ok(line) = line else { return };
                let Some(data) = line.strip_prefix("data:") else { continue };
                let Ok(ev) = serde_json::from_str::<serde_json::Value>(data.trim()) else { continue };
                if ev["type"] == "tile" {
                    tiles.lock().unwrap().push(ev["job"].as_u64().unwrap());
                }
            }
        });
    }

    // A small job of higher priority, submitted behind the queue.
    let scene = std::fs::read(repo().join("scenes/environment.xml")).unwrap();
    let sky = std::fs::read(repo().join("scenes/textures/sky.hdr")).unwrap();
    let t1 = Instant::now();
    let (code, body) = submit(
        &server.url,
        None,
        &[
            ("scene", Some("environment.xml"), &scene),
            ("asset", Some("textures/sky.hdr"), &sky),
            ("samples", None, b"1"),
            ("tile_size", None, b"64"),
            ("priority", None, b"10"),
        ],
    );
    assert_eq!(code, 201, "{body}");
    let small = body["id"].as_u64().unwrap();
    let started = wait_job(&server, small, 60, |j| j["state"] != "queued");
    let took_start = t1.elapsed();
    eprintln!(
        "the priority-10 job started {:.3} s after its submission ({})",
        took_start.as_secs_f64(),
        started["state"]
    );
    let done = wait_job(&server, small, 120, |j| j["state"] == "done");
    eprintln!("the priority-10 job finished {:.2} s after its submission", t1.elapsed().as_secs_f64());
    assert_eq!(tiles_done(&done), 40, "{done}");
    // Once the small job's first tile came back, the big job got at most the tiles the worker
    // already held until the small job's last one: it was not served meanwhile.
    let order: Vec<u64> = tiles.lock().unwrap().clone();
    let first = order.iter().position(|&j| j == small).expect("tile events of the small job");
    let last = order.iter().rposition(|&j| j == small).unwrap();
    let big_between = order[first..=last].iter().filter(|&&j| j == big).count();
    eprintln!(
        "tile events: {} before the small job's first, {big_between} of the big job among its 40",
        first
    );
    assert!(big_between <= 2, "the big job kept being served: {:?}", &order[first..=last]);
    assert_eq!(order[first..=last].iter().filter(|&&j| j == small).count(), 40);

    // Listing stays quick with the queue in place.
    let t2 = Instant::now();
    let list = get_json(&server.url, "/api/v1/jobs");
    eprintln!("listing jobs took {:.3} s", t2.elapsed().as_secs_f64());
    assert_eq!(list["jobs"].as_array().unwrap().len(), 2, "{list}");
    let t2 = Instant::now();
    let metrics = get_bytes(&server.url, "/metrics");
    eprintln!("/metrics took {:.3} s", t2.elapsed().as_secs_f64());
    assert!(String::from_utf8_lossy(&metrics).contains("tessera_jobs"));

    // Cancelling the big job revokes it at once.
    let t3 = Instant::now();
    let (code, body) = cancel(&server, big);
    eprintln!("cancelling the 640000-tile job took {:.3} s", t3.elapsed().as_secs_f64());
    assert_eq!(code, 200, "{body}");
    let j = get_json(&server.url, &format!("/api/v1/jobs/{big}"));
    assert_eq!(j["state"], "canceled", "{j}");
}
