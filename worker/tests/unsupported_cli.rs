//! `tessera-worker render` refuses a scene with elements Tessera does not implement and that
//! change the picture (issue #17 item 5): a non-zero exit, every such element named with its
//! file and line on stderr, no image; with `--allow-unsupported` the same scene renders, the
//! elements reported as warnings.

mod support;

use support::run;
use tessera_testkit::TempDir;

/// One sphere and two tone-mapping operators no course material names (lines 4 and 7).
const SCENE: &str = r#"<Scene>
<Cameras><Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
<NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>8 8</ImageResolution>
<ImageName>u.exr</ImageName><Tonemap><TMO>Durand</TMO></Tonemap></Camera>
<Camera id="2"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
<NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>8 8</ImageResolution>
<ImageName>v.exr</ImageName><Tonemap><TMO>Drago</TMO></Tonemap></Camera></Cameras>
<Lights><PointLight id="1"><Position>0 2 0</Position><Intensity>100 100 100</Intensity></PointLight></Lights>
<Materials><Material id="1"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
<VertexData>0 0 -3 1 0 -3 0 1 -3</VertexData>
<Objects>
<Mesh id="2"><Material>1</Material><Faces>1 2 3</Faces></Mesh>
<Sphere id="1"><Material>1</Material><Center>1</Center><Radius>1</Radius></Sphere>
</Objects>
</Scene>
"#;

#[test]
fn unsupported_elements_fail_the_render_unless_allowed() {
    let dir = TempDir::new("unsupported-cli");
    let scene = dir.join("u.xml");
    std::fs::write(&scene, SCENE).unwrap();
    let out = dir.join("out");
    let args = |extra: &[&str]| {
        let mut a: Vec<std::ffi::OsString> =
            vec!["render".into(), scene.clone().into(), "--quiet".into(), "--out".into(), out.clone().into()];
        a.extend(extra.iter().map(Into::into));
        a
    };

    let r = run(&args(&[]));
    assert_ne!(r.code, Some(0), "{}", r.describe());
    assert!(r.stderr.contains("u.xml:4: <Camera id=\"1\"> / <Tonemap> / <TMO>: "), "{}", r.describe());
    assert!(r.stderr.contains("u.xml:7: <Camera id=\"2\"> / <Tonemap> / <TMO>: "), "{}", r.describe());
    assert!(r.stderr.contains("--allow-unsupported"), "{}", r.describe());
    assert!(r.stderr.contains("2 element(s) that change the picture are not supported"), "{}", r.describe());
    assert!(!out.join("u.png").exists(), "nothing is rendered");

    let r = run(&args(&["--allow-unsupported"]));
    assert_eq!(r.code, Some(0), "{}", r.describe());
    assert!(
        r.stderr.contains("warning: ") && r.stderr.contains("u.xml:4: <Camera id=\"1\"> / <Tonemap> / <TMO>"),
        "{}",
        r.describe()
    );
    assert!(out.join("u.png").exists(), "{}", r.describe());
}
