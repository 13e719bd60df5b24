//! Uploads bounded after decompression (issue #16 item 4), with the real server: archives that
//! unpack to far more than they weigh, too many files, and files over the size cap are refused
//! with a 413 that names the cap and its flag, while the server's peak memory stays small and
//! the farm goes on rendering.

mod support;

use std::io::Write;

use support::*;

const SCENE: &str = r#"<Scene>
    <Cameras><Camera id="1"><Position>0 0 5</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
        <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance>
        <ImageResolution>8 8</ImageResolution><ImageName>ok.png</ImageName></Camera></Cameras>
    <Lights><PointLight id="1"><Position>0 0 5</Position><Intensity>100 100 100</Intensity></PointLight></Lights>
    <Materials><Material id="1"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
    <VertexData>0 0 0</VertexData>
    <Objects><Sphere id="1"><Material>1</Material><Center>1</Center><Radius>1</Radius></Sphere></Objects>
</Scene>"#;

/// The server's peak resident memory so far, in MiB (VmHWM).
fn peak_rss_mib(server: &Server) -> f64 {
    let status = std::fs::read_to_string(format!("/proc/{}/status", server.child.id())).unwrap();
    let line = status.lines().find(|l| l.starts_with("VmHWM:")).unwrap();
    let kib: f64 = line.split_whitespace().nth(1).unwrap().parse().unwrap();
    kib / 1024.0
}

/// `zeros` bytes of zeros written in 1 MiB pieces to `w`.
fn write_zeros(w: &mut impl Write, zeros: u64) {
    let block = vec![0u8; 1 << 20];
    let mut left = zeros;
    while left > 0 {
        let n = left.min(block.len() as u64) as usize;
        w.write_all(&block[..n]).unwrap();
        left -= n as u64;
    }
}

/// The issue's bomb: a zip of about 1 MB holding the scene and 1 GiB of zeros.
fn zip_bomb() -> Vec<u8> {
    let mut zip = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated)
        .large_file(true);
    zip.start_file("scene.xml", opts).unwrap();
    zip.write_all(SCENE.as_bytes()).unwrap();
    zip.start_file("zeros.bin", opts).unwrap();
    write_zeros(&mut zip, 1 << 30);
    zip.finish().unwrap().into_inner()
}

/// A .tar.gz of the scene and eight files of 128 MiB of zeros: each under the single-file cap,
/// together far over the total.
fn tar_gz_bomb() -> Vec<u8> {
    let gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    let mut tar = tar::Builder::new(gz);
    let mut header = tar::Header::new_gnu();
    header.set_size(SCENE.len() as u64);
    header.set_mode(0o644);
    tar.append_data(&mut header, "scene.xml", SCENE.as_bytes()).unwrap();
    for k in 0..8 {
        let mut header = tar::Header::new_gnu();
        header.set_size(128 << 20);
        header.set_mode(0o644);
        let zeros = std::io::Read::take(std::io::repeat(0), 128 << 20);
        tar.append_data(&mut header, format!("zeros{k}.bin"), zeros).unwrap();
    }
    tar.into_inner().unwrap().finish().unwrap()
}

fn submit_bundle(server: &Server, name: &str, bytes: &[u8]) -> (u16, serde_json::Value) {
    submit(&server.url, None, &[("bundle", Some(name), bytes), ("samples", None, b"1")])
}

fn assert_refused(answer: &(u16, serde_json::Value), flag: &str, server: &Server) {
    let (code, body) = answer;
    assert_eq!(*code, 413, "{body}\n{}", server.log());
    let error = body["error"].as_str().unwrap_or_default();
    assert!(error.contains(flag), "the error does not name {flag}: {error}");
}

fn uploads_left(data: &std::path::Path) -> usize {
    std::fs::read_dir(data.join("uploads")).map(|d| d.count()).unwrap_or(0)
}

#[test]
fn decompression_bombs_are_refused_and_the_server_stays_small() {
    let _s = serial();
    let data = TempDir::new("farm-upload-bombs");
    let server = Server::start(&data, &["--local-workers", "1", "--local-worker-threads", "1"]);

    let zip = zip_bomb();
    assert!(zip.len() < 4 << 20, "the zip bomb is {} bytes", zip.len());
    let answer = submit_bundle(&server, "bomb.zip", &zip);
    assert_refused(&answer, "--max-file-mb", &server);
    assert!(answer.1["error"].as_str().unwrap().contains("zeros.bin"), "{}", answer.1);

    let tgz = tar_gz_bomb();
    assert!(tgz.len() < 8 << 20, "the tar.gz bomb is {} bytes", tgz.len());
    let answer = submit_bundle(&server, "bomb.tar.gz", &tgz);
    assert_refused(&answer, "--max-unpacked-mb", &server);

    // Before the caps, unpacking the zip took the server to 2.1 GB.
    let peak = peak_rss_mib(&server);
    eprintln!("server peak RSS after both bombs: {peak:.0} MiB");
    assert!(peak < 400.0, "the server's peak RSS reached {peak:.0} MiB");
    assert_eq!(uploads_left(&data), 0, "spooled uploads were left behind");

    // The farm goes on serving.
    let (code, job) = submit(&server.url, None, &[("scene", Some("scene.xml"), SCENE.as_bytes())]);
    assert_eq!(code, 201, "{job}");
    wait_job(&server, job["id"].as_u64().unwrap(), 60, |j| j["state"] == "done");
}

#[test]
fn too_many_files_and_too_large_files_are_refused_with_the_cap_named() {
    let _s = serial();
    let data = TempDir::new("farm-upload-caps");
    let server = Server::start(
        &data,
        &["--local-workers", "0", "--max-bundle-files", "20", "--max-file-mb", "1", "--max-unpacked-mb", "3"],
    );

    // 30 files in a tar.
    let mut tar = tar::Builder::new(Vec::new());
    for k in 0..30 {
        let body: &[u8] = if k == 0 { SCENE.as_bytes() } else { b"x" };
        let mut header = tar::Header::new_gnu();
        header.set_size(body.len() as u64);
        header.set_mode(0o644);
        let name = if k == 0 { "scene.xml".to_string() } else { format!("extra/{k}.txt") };
        tar.append_data(&mut header, name, body).unwrap();
    }
    let answer = submit_bundle(&server, "many.tar", &tar.into_inner().unwrap());
    assert_refused(&answer, "--max-bundle-files", &server);

    // 30 loose files.
    let extras: Vec<(String, Vec<u8>)> = (1..30).map(|k| (format!("extra/{k}.txt"), b"x".to_vec())).collect();
    let mut parts: Vec<(&str, Option<&str>, &[u8])> = vec![("scene", Some("scene.xml"), SCENE.as_bytes())];
    parts.extend(extras.iter().map(|(n, b)| ("asset", Some(n.as_str()), b.as_slice())));
    assert_refused(&submit(&server.url, None, &parts), "--max-bundle-files", &server);

    // A loose asset of 2 MiB against a 1 MiB cap: refused while it streams in.
    let big = vec![7u8; 2 << 20];
    let answer = submit(
        &server.url,
        None,
        &[("scene", Some("scene.xml"), SCENE.as_bytes()), ("asset", Some("big.bin"), &big)],
    );
    assert_refused(&answer, "--max-file-mb", &server);
    assert!(answer.1["error"].as_str().unwrap().contains("big.bin"), "{}", answer.1);

    // Four loose files of 0.9 MiB: each under the file cap, together over the 3 MiB total.
    let piece = vec![1u8; 900 << 10];
    let answer = submit(
        &server.url,
        None,
        &[
            ("scene", Some("scene.xml"), SCENE.as_bytes()),
            ("asset", Some("a.bin"), &piece),
            ("asset", Some("b.bin"), &piece),
            ("asset", Some("c.bin"), &piece),
            ("asset", Some("d.bin"), &piece),
        ],
    );
    assert_refused(&answer, "--max-unpacked-mb", &server);

    // A text field cannot carry a file's worth of bytes.
    let long_name = vec![b'n'; 100 << 10];
    let (code, body) = submit(
        &server.url,
        None,
        &[("scene", Some("scene.xml"), SCENE.as_bytes()), ("name", None, &long_name)],
    );
    assert_eq!(code, 400, "{body}");
    assert!(body["error"].as_str().unwrap().contains("\"name\" is longer than 64 KiB"), "{body}");

    // Under every cap the same server accepts the scene with a small asset.
    let (code, job) = submit(
        &server.url,
        None,
        &[("scene", Some("scene.xml"), SCENE.as_bytes()), ("asset", Some("a.bin"), &piece)],
    );
    assert_eq!(code, 201, "{job}");
    assert_eq!(uploads_left(&data), 0, "spooled uploads were left behind");
}
