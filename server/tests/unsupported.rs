//! A farm upload of a scene with elements Tessera does not implement and that change the picture
//! (issue #17 item 5) is answered 422 with one problem per element (file, line, element) unless
//! it is submitted with `allow_unsupported=true`; then the job renders on a worker, which builds
//! the scene with the lease's `allow_unsupported`, exactly like `tessera-worker render
//! --allow-unsupported`.

mod support;

use support::*;
use tessera_testkit::TempDir;

/// A sphere, a mesh, a triangle and two tone-mapping operators no course material names
/// (lines 4 and 5).
const SCENE: &str = r#"<Scene>
<Cameras><Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
<NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>24 16</ImageResolution>
<ImageName>u.png</ImageName><Tonemap><TMO>Durand</TMO></Tonemap>
<Tonemap><TMO>Drago</TMO></Tonemap></Camera></Cameras>
<Lights><PointLight id="1"><Position>0 2 0</Position><Intensity>100 100 100</Intensity></PointLight></Lights>
<Materials><Material id="1"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
<VertexData>0 0 -3 1 0 -3 0 1 -3</VertexData>
<Objects><Mesh id="2"><Material>1</Material><Faces>1 2 3</Faces></Mesh>
<Sphere id="1"><Material>1</Material><Center>1</Center><Radius>1</Radius></Sphere>
<Triangle id="3"><Material>1</Material><Indices>1 2 3</Indices></Triangle>
</Objects>
</Scene>
"#;

#[test]
fn unsupported_elements_are_a_422_unless_allowed_and_then_the_job_renders() {
    let _s = serial();
    let data = TempDir::new("farm-unsupported");
    let server = Server::start(&data, &["--local-workers", "1", "--local-worker-threads", "1"]);
    let scene = ("scene", Some("u.xml"), SCENE.as_bytes());

    let (code, body) = submit(&server.url, None, &[scene]);
    assert_eq!(code, 422, "{body}");
    assert!(body["error"].as_str().unwrap().contains("allow_unsupported=true"), "{body}");
    let problems = body["problems"].as_array().unwrap();
    let at: Vec<(u64, &str)> =
        problems.iter().map(|p| (p["line"].as_u64().unwrap(), p["element"].as_str().unwrap())).collect();
    let tmo = "Camera id=\"1\"> / <Tonemap> / <TMO";
    assert_eq!(at, [(4, tmo), (5, tmo)], "{body}");
    assert!(problems.iter().all(|p| p["file"] == "u.xml"), "{body}");
    let (code, body) = submit(&server.url, None, &[scene, ("allow_unsupported", None, b"maybe")]);
    assert_eq!(code, 400, "{body}");

    let (code, job) = submit(&server.url, None, &[scene, ("allow_unsupported", None, b"true")]);
    assert_eq!(code, 201, "{job}");
    let warnings = job["warnings"].to_string();
    assert!(warnings.contains("u.xml:4") && warnings.contains("u.xml:5"), "{job}");
    let id = job["id"].as_u64().unwrap();
    let job = wait_job(&server, id, 120, |j| j["state"] == "done");

    // The same image as the CLI's with --allow-unsupported.
    let dir = TempDir::new("farm-unsupported-cli");
    std::fs::write(dir.join("u.xml"), SCENE).unwrap();
    assert_job_outputs_equal_cli(&server, &job, &cli_render(&dir.join("u.xml"), &["--allow-unsupported"]));
}
