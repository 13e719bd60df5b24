//! `tessera-worker render` on 2025 JSON scenes (scene-format.md §14): the front end is chosen by
//! content, whatever the extension; Planes render; each `Tonemap` writes its own PNG with its
//! operator; a broken file fails with file, line and JSON path.

mod support;

use support::run;
use tessera::hdr_io::read_exr;
use tessera::tonemap::params::{Operator, Photographic};
use tessera::tonemap::tonemap_with;

use tessera_testkit::rgb8::Rgb8;
use tessera_testkit::{TempDir, shared_scenes};

/// A small version of the 2025 simple.json: a triangle, a sphere and a plane under a point light.
const TINY: &str = r#"{"Scene": {
  "BackgroundColor": "0 0 0", "MaxRecursionDepth": "1",
  "Cameras": {"Camera": {"_id": "1", "Position": "0 0 0", "Gaze": "0 0 -1", "Up": "0 1 0",
      "NearPlane": "-1 1 -1 1", "NearDistance": "1", "ImageResolution": "16 16", "ImageName": "tiny.png"}},
  "Lights": {"AmbientLight": "25 25 25",
      "PointLight": {"_id": "1", "Position": "0 2 0", "Intensity": "1000 1000 1000"}},
  "Materials": {"Material": {"_id": "1", "AmbientReflectance": "1 1 1", "DiffuseReflectance": "1 1 1",
      "SpecularReflectance": "0 0 0", "PhongExponent": "1"}},
  "VertexData": {"_data": "-0.5 0.5 -2 -0.5 -0.5 -2 0.5 -0.5 -2 0 0 -3 0 -1 0", "_type": "xyz"},
  "Objects": {
      "Triangle": {"_id": "1", "Material": "1", "Indices": "1 2 3"},
      "Sphere": {"_id": "1", "Material": "1", "Center": "4", "Radius": "0.3"},
      "Plane": {"_id": "1", "Material": "1", "Point": "5", "Normal": "0 1 0"}}}}"#;

#[test]
fn a_json_scene_renders_whatever_its_extension() {
    let dir = TempDir::new("json-tiny");
    let scene = dir.join("tiny.scene");
    std::fs::write(&scene, TINY).unwrap();
    let out = dir.join("out");
    let r =
        run(&["render".as_ref(), scene.as_os_str(), "--quiet".as_ref(), "--out".as_ref(), out.as_os_str()]);
    assert_eq!(r.code, Some(0), "{}", r.describe());
    let png = Rgb8::read_png(&out.join("tiny.png")).unwrap();
    assert_eq!((png.width, png.height), (16, 16));
    // The plane (y = -1) fills the bottom rows: lit, not background.
    let bottom = &png.data[(15 * 16 + 8) * 3..(15 * 16 + 8) * 3 + 3];
    assert!(bottom.iter().all(|&c| c > 0), "{bottom:?}");
    // The top rows see only the black background.
    assert_eq!(&png.data[..3], &[0, 0, 0]);

    // Broken: a mesh without Faces names the file, the line and the JSON path.
    let broken = TINY.replace(
        r#""Triangle": {"_id": "1", "Material": "1", "Indices": "1 2 3"}"#,
        r#""Mesh": {"_id": "1", "Material": "1"}"#,
    );
    let bad = dir.join("bad.json");
    std::fs::write(&bad, broken).unwrap();
    let r = run(&["render".as_ref(), bad.as_os_str(), "--quiet".as_ref(), "--out".as_ref(), out.as_os_str()]);
    assert_ne!(r.code, Some(0), "{}", r.describe());
    assert!(
        r.stderr.contains("bad.json:11: <Scene.Objects.Mesh.Faces>: missing \"Faces\""),
        "{}",
        r.describe()
    );
    // Truncated: malformed JSON with line and column.
    std::fs::write(&bad, &TINY[..200]).unwrap();
    let r = run(&["render".as_ref(), bad.as_os_str(), "--quiet".as_ref(), "--out".as_ref(), out.as_os_str()]);
    assert_ne!(r.code, Some(0), "{}", r.describe());
    assert!(r.stderr.contains("malformed JSON") && r.stderr.contains("column"), "{}", r.describe());
}

/// The 2025 cube_point_hdr.json has three Tonemaps (Photographic, ACES, Filmic) with
/// Extensions: one PNG each, each the EXR through its own operator.
#[test]
fn each_tonemap_of_a_json_scene_writes_its_png() {
    let scene = shared_scenes().join("json/hw5/cube_point_hdr.json");
    if !tessera_testkit::corpus_has(&scene) {
        return;
    }
    let out = TempDir::new("json-hdr");
    let r =
        run(&["render".as_ref(), scene.as_os_str(), "--quiet".as_ref(), "--out".as_ref(), out.as_os_str()]);
    assert_eq!(r.code, Some(0), "{}", r.describe());
    let exr = read_exr(&out.join("cube_point_hdr.exr")).unwrap();
    let params = Photographic::default(); // the scene's "0.18 1", saturation 1, gamma 2.2
    for (ext, op) in [
        ("_phot.png", Operator::Photographic),
        ("_aces.png", Operator::Aces),
        ("_film.png", Operator::Filmic),
    ] {
        let png = Rgb8::read_png(&out.join(format!("cube_point_hdr{ext}"))).unwrap();
        assert_eq!(png.data, tonemap_with(&exr, op, &params).0, "{ext}");
    }
    assert!(!out.join("cube_point_hdr.png").exists());
}
