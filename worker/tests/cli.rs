//! End-to-end tests of the `tessera-worker` binary: real scene files in, PNG files and messages
//! out. Every test writes only into its own directory under the system temp dir.

mod support;
use support::*;

use std::path::{Path, PathBuf};

fn repo_scene(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes").join(name)
}

use tessera_testkit::rgb8::Rgb8;
use tessera_testkit::{TempDir, shared_scenes};

fn pngs_in(dir: &Path) -> Vec<PathBuf> {
    match std::fs::read_dir(dir) {
        Ok(rd) => rd
            .filter_map(|e| e.ok())
            .map(|e| e.path())
            .filter(|p| p.extension().is_some_and(|x| x == "png"))
            .collect(),
        Err(_) => Vec::new(),
    }
}

/// A tiny valid scene (one triangle, one camera of 16x16) with `objects` inside <Objects> and
/// `extra` after it, inside <Scene>. The camera starts on line 3, <Objects> children on line 9.
fn small_scene(objects: &str, extra: &str) -> String {
    format!(
        r#"<Scene>
  <Cameras>
    <Camera id="1"><Position>0 0 5</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up><NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>16 16</ImageResolution><ImageName>small.png</ImageName></Camera>
  </Cameras>
  <Lights><AmbientLight>25 25 25</AmbientLight><PointLight id="1"><Position>0 5 5</Position><Intensity>1000 1000 1000</Intensity></PointLight></Lights>
  <Materials><Material id="1"><AmbientReflectance>1 1 1</AmbientReflectance><DiffuseReflectance>1 1 1</DiffuseReflectance><SpecularReflectance>0 0 0</SpecularReflectance></Material></Materials>
  <VertexData>-1 -1 0  1 -1 0  0 1 0</VertexData>
  <Objects>
    {objects}
  </Objects>
  {extra}
</Scene>
"#
    )
}

const TRIANGLE: &str = r#"<Mesh id="1"><Material>1</Material><Faces>1 2 3</Faces></Mesh>"#;

// ---------------------------------------------------------------------------------------------
// Successful renders
// ---------------------------------------------------------------------------------------------

#[test]
fn renders_the_repository_scenes() {
    // (scene file, output image, width, height)
    let cases = [
        ("cornell_box.xml", "cornell_box.png", 512, 512),
        ("tori.xml", "tori.png", 640, 400),
        ("spotlights.xml", "spotlights.png", 480, 300),
        // HDR: environment.exr and its tone-mapped environment.png.
        ("environment.xml", "environment.png", 480, 270),
    ];
    for (scene, image, w, h) in cases {
        let tmp = TempDir::new("cli-render");
        let out = tmp.path().join("out");
        let r = run(&[
            "render".as_ref(),
            repo_scene(scene).as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
            "--quiet".as_ref(),
        ]);
        assert_eq!(r.code, Some(0), "{scene}: {}", r.describe());
        assert!(!r.stderr.contains("panicked"), "{scene}: {}", r.describe());

        let png = out.join(image);
        let img = Rgb8::read_png(&png)
            .unwrap_or_else(|e| panic!("{scene}: cannot read {}: {e}\n{}", png.display(), r.describe()));
        assert_eq!((img.width, img.height), (w, h), "{scene}: image size");
        assert_eq!(img.data.len(), (w * h * 3) as usize);
        let bright = img.data.iter().filter(|&&v| v > 50).count();
        assert!(
            bright > (w * h) as usize / 100,
            "{scene}: the image is (nearly) blank: {bright} channel values above 50"
        );
        let distinct: std::collections::HashSet<&[u8]> = img.data.chunks_exact(3).collect();
        assert!(distinct.len() > 16, "{scene}: only {} distinct colours", distinct.len());

        let summary = r.stdout.lines().find(|l| l.contains("Mrays/s"));
        let summary = summary
            .unwrap_or_else(|| panic!("{scene}: no summary line with Mrays/s on stdout\n{}", r.describe()));
        assert!(
            summary.contains(image) && summary.contains(&format!("{w}x{h}")),
            "{scene}: summary line {summary:?}"
        );
        assert_eq!(pngs_in(&out).len(), 1, "{scene}: exactly one image expected in the output dir");
    }
}

#[test]
fn output_does_not_depend_on_threads_or_tile_size() {
    let tmp = TempDir::new("cli-threads");
    let mut images = Vec::new();
    for (threads, tile) in [("1", "16"), ("2", "64")] {
        let out = tmp.path().join(format!("out-{threads}-{tile}"));
        let r = run(&[
            "render".as_ref(),
            repo_scene("tori.xml").as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
            "--threads".as_ref(),
            threads.as_ref(),
            "--tile-size".as_ref(),
            tile.as_ref(),
            "--camera".as_ref(),
            "1".as_ref(),
        ]);
        assert_eq!(r.code, Some(0), "{}", r.describe());
        images.push(Rgb8::read_png(&out.join("tori.png")).expect("read tori.png"));
    }
    assert!(
        images[0] == images[1],
        "tori.png differs between --threads 1 --tile-size 16 and --threads 2 --tile-size 64"
    );
}

#[test]
fn unknown_element_warns_and_still_renders() {
    let tmp = TempDir::new("cli-unknown");
    let scene = tmp.write("unknown.xml", small_scene(TRIANGLE, "<Frobnicate>1 2 3</Frobnicate>"));
    let out = tmp.path().join("out");
    let r = run(&["render".as_ref(), scene.as_os_str(), "--out".as_ref(), out.as_os_str(), "-q".as_ref()]);
    assert_eq!(r.code, Some(0), "{}", r.describe());
    let warning = r.stderr.lines().find(|l| l.contains("warning"));
    let warning = warning.unwrap_or_else(|| panic!("no warning on stderr\n{}", r.describe()));
    assert!(
        warning.contains("Frobnicate") && warning.contains("unknown.xml:11"),
        "warning should name the element and where it is: {warning}"
    );
    let img = Rgb8::read_png(&out.join("small.png")).expect("the scene still renders");
    assert_eq!((img.width, img.height), (16, 16));
    assert!(r.stdout.contains("Mrays/s"), "{}", r.describe());
}

/// A camera inside a closed mirror (then glass) sphere with a hostile MaxRecursionDepth: the
/// depth is capped with a warning that says so, and the render finishes instead of overflowing a
/// render thread's stack (a mirror) or splitting rays for ever (glass, 2^depth rays a sample).
#[test]
fn hostile_recursion_depth_is_capped_with_a_warning() {
    let tmp = TempDir::new("cli-depth");
    for (kind, material) in [
        (
            "mirror",
            r#"<Material id="1" type="mirror"><AmbientReflectance>0 0 0</AmbientReflectance><DiffuseReflectance>0.1 0.1 0.1</DiffuseReflectance><SpecularReflectance>0 0 0</SpecularReflectance><MirrorReflectance>1 1 1</MirrorReflectance></Material>"#,
        ),
        (
            "glass",
            r#"<Material id="1" type="dielectric"><AmbientReflectance>0 0 0</AmbientReflectance><DiffuseReflectance>0 0 0</DiffuseReflectance><SpecularReflectance>0 0 0</SpecularReflectance><AbsorptionCoefficient>0 0 0</AbsorptionCoefficient><RefractionIndex>1.5</RefractionIndex></Material>"#,
        ),
    ] {
        let scene = format!(
            r#"<Scene>
  <MaxRecursionDepth>1000000</MaxRecursionDepth>
  <Cameras>
    <Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up><NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>4 4</ImageResolution><ImageName>{kind}.png</ImageName></Camera>
  </Cameras>
  <Lights><AmbientLight>25 25 25</AmbientLight><PointLight id="1"><Position>0 0.5 0</Position><Intensity>10 10 10</Intensity></PointLight></Lights>
  <Materials>{material}</Materials>
  <VertexData>0 0 0  0 0 0.3</VertexData>
  <Objects>
    <Sphere id="1"><Material>1</Material><Center>1</Center><Radius>2</Radius></Sphere>
    <Sphere id="2"><Material>1</Material><Center>2</Center><Radius>1.5</Radius></Sphere>
  </Objects>
</Scene>
"#
        );
        let file = tmp.write(&format!("{kind}.xml"), &scene);
        let out = tmp.path().join(kind);
        let r = run(&["render".as_ref(), file.as_os_str(), "--out".as_ref(), out.as_os_str(), "-q".as_ref()]);
        assert_eq!(r.code, Some(0), "{kind}: {}", r.describe());
        let warning = r.stderr.lines().find(|l| l.contains("MaxRecursionDepth"));
        let warning =
            warning.unwrap_or_else(|| panic!("{kind}: no warning about the depth\n{}", r.describe()));
        assert!(
            warning.contains("1000000")
                && warning.contains("capped to 64")
                && warning.contains(&format!("{kind}.xml:2")),
            "{kind}: the warning should give the value, the cap and the line: {warning}"
        );
        let img = Rgb8::read_png(&out.join(format!("{kind}.png"))).expect("the scene renders");
        assert_eq!((img.width, img.height), (4, 4));
    }
}

// ---------------------------------------------------------------------------------------------
// Help
// ---------------------------------------------------------------------------------------------

#[test]
fn help_texts() {
    // (arguments, what the text must mention)
    let cases: [(&[&str], &[&str]); 4] = [
        (&["--help"], &["render", "Usage"]),
        (&["help", "render"], &["--out", "--threads", "--camera", "--tile-size"]),
        (&["render", "--help"], &["--out", "--threads", "--camera", "--tile-size", "--quiet"]),
        (&["render", "-h"], &["--out", "--threads", "--camera"]),
    ];
    for (args, needles) in cases {
        let r = run(args);
        assert_eq!(r.code, Some(0), "{args:?}: {}", r.describe());
        for n in needles {
            assert!(r.stdout.contains(n), "{args:?}: help does not mention {n}\n{}", r.describe());
        }
    }
}

#[test]
fn usage_errors_exit_non_zero_without_panicking() {
    // (arguments, what stderr must mention)
    let cases: [(&[&str], &[&str]); 3] = [
        (&[], &["Usage"]),
        (&["render"], &["SCENE"]),
        (&["render", "x.xml", "--frobnicate"], &["--frobnicate"]),
    ];
    for (args, needles) in cases {
        let r = run(args);
        assert!(r.code.is_some_and(|c| c != 0), "{args:?}: {}", r.describe());
        assert!(!r.stderr.contains("panicked"), "{args:?}: {}", r.describe());
        for n in needles {
            assert!(r.stderr.contains(n), "{args:?}: stderr does not mention {n}\n{}", r.describe());
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Errors: non-zero exit, a message on stderr naming the problem, no panic, no image
// ---------------------------------------------------------------------------------------------

/// An ASCII PLY triangle whose face names vertex 5 of 3.
const PLY_BAD_INDEX: &str = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
element face 1\nproperty list uchar int vertex_indices\nend_header\n-1 -1 0\n1 -1 0\n0 1 0\n3 0 1 5\n";
/// An ASCII PLY that ends after 2 of its 3 vertices.
const PLY_TRUNCATED: &str = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
element face 1\nproperty list uchar int vertex_indices\nend_header\n-1 -1 0\n1 -1 0\n";

struct ErrorCase {
    name: &'static str,
    /// The scene text written to `<name>.xml` in the temp dir; `None` to pass a nonexistent path.
    scene: Option<String>,
    /// Other files written next to the scene: (name, contents).
    files: &'static [(&'static str, &'static str)],
    extra_args: &'static [&'static str],
    /// Every one of these must appear in stderr.
    expect: &'static [&'static str],
}

fn error_cases() -> Vec<ErrorCase> {
    vec![
        ErrorCase {
            name: "missing_ply",
            scene: Some(small_scene(
                r#"<Mesh id="1"><Material>1</Material><Faces plyFile="nope/missing.ply"/></Mesh>"#,
                "",
            )),
            files: &[],
            extra_args: &[],
            expect: &["missing.ply", "missing_ply.xml:9", "Mesh"],
        },
        ErrorCase {
            name: "ply_face_index_out_of_range",
            scene: Some(small_scene(
                r#"<Mesh id="1"><Material>1</Material><Faces plyFile="bad_index.ply"/></Mesh>"#,
                "",
            )),
            files: &[("bad_index.ply", PLY_BAD_INDEX)],
            extra_args: &[],
            expect: &["bad_index.ply", "vertex 5", "3 vertices", "ply_face_index_out_of_range.xml"],
        },
        ErrorCase {
            name: "ply_truncated",
            scene: Some(small_scene(
                r#"<Mesh id="1"><Material>1</Material><Faces plyFile="truncated.ply"/></Mesh>"#,
                "",
            )),
            files: &[("truncated.ply", PLY_TRUNCATED)],
            extra_args: &[],
            expect: &["truncated.ply", "ply_truncated.xml"],
        },
        ErrorCase {
            name: "malformed_unterminated_tag",
            scene: Some(small_scene(r#"<Mesh id="1"><Material>1</Material><Faces>1 2 3</Faces></Mesh"#, "")),
            files: &[],
            extra_args: &[],
            expect: &["malformed_unterminated_tag.xml:9"],
        },
        ErrorCase {
            name: "malformed_mismatched_close",
            scene: Some(small_scene(
                r#"<Sphere id="1"><Material>1</Material><Center>1</Center><Radius>1</Radiuss></Sphere>"#,
                "",
            )),
            files: &[],
            extra_args: &[],
            expect: &["malformed_mismatched_close.xml:9", "Radius"],
        },
        ErrorCase {
            name: "undefined_material_mesh",
            scene: Some(small_scene(
                r#"<Mesh id="7"><Material>42</Material><Faces>1 2 3</Faces></Mesh>"#,
                "",
            )),
            files: &[],
            extra_args: &[],
            expect: &["undefined_material_mesh.xml:9", r#"Mesh id="7""#, "42"],
        },
        ErrorCase {
            name: "undefined_material_sphere",
            scene: Some(small_scene(
                r#"<Sphere id="4"><Material>42</Material><Center>1</Center><Radius>1</Radius></Sphere>"#,
                "",
            )),
            files: &[],
            extra_args: &[],
            expect: &["undefined_material_sphere.xml:9", r#"Sphere id="4""#, "42"],
        },
        ErrorCase {
            name: "vertex_index_out_of_range",
            scene: Some(small_scene(
                r#"<Mesh id="1"><Material>1</Material><Faces>1 2 3  1 2 17</Faces></Mesh>"#,
                "",
            )),
            files: &[],
            extra_args: &[],
            expect: &["vertex_index_out_of_range.xml:9", "Faces", "17", "3 vertices"],
        },
        ErrorCase {
            name: "vertex_index_zero",
            scene: Some(small_scene(r#"<Mesh id="1"><Material>1</Material><Faces>0 1 2</Faces></Mesh>"#, "")),
            files: &[],
            extra_args: &[],
            expect: &["vertex_index_zero.xml:9", "Faces", "vertex 0"],
        },
        ErrorCase {
            name: "sphere_center_out_of_range",
            scene: Some(small_scene(
                r#"<Sphere id="2"><Material>1</Material><Center>9</Center><Radius>1</Radius></Sphere>"#,
                "",
            )),
            files: &[],
            extra_args: &[],
            expect: &["sphere_center_out_of_range.xml", r#"Sphere id="2""#, "9"],
        },
        ErrorCase {
            name: "negative_radius",
            scene: Some(small_scene(
                r#"<Sphere id="3"><Material>1</Material><Center>1</Center><Radius>-1</Radius></Sphere>"#,
                "",
            )),
            files: &[],
            extra_args: &[],
            expect: &["negative_radius.xml:9", r#"Sphere id="3""#, "Radius"],
        },
        ErrorCase {
            name: "non_number_position",
            scene: Some(
                small_scene(TRIANGLE, "")
                    .replace("<Position>0 0 5</Position>", "<Position>0 abc 5</Position>"),
            ),
            files: &[],
            extra_args: &[],
            expect: &["non_number_position.xml:3", "Position", "abc"],
        },
        ErrorCase {
            name: "non_number_vertex_data",
            scene: Some(small_scene(TRIANGLE, "").replace("1 -1 0  0 1 0", "1 -1 0  0 one 0")),
            files: &[],
            extra_args: &[],
            expect: &["non_number_vertex_data.xml:7", "VertexData", "one"],
        },
        ErrorCase {
            name: "root_is_not_scene",
            scene: Some("<Sceen>\n</Sceen>\n".to_string()),
            files: &[],
            extra_args: &[],
            expect: &["root_is_not_scene.xml:1", "Sceen"],
        },
        ErrorCase {
            name: "empty_file",
            scene: Some(String::new()),
            files: &[],
            extra_args: &[],
            expect: &["empty_file.xml"],
        },
        ErrorCase {
            name: "nonexistent_scene",
            scene: None,
            files: &[],
            extra_args: &[],
            expect: &["nonexistent_scene.xml"],
        },
        ErrorCase {
            name: "camera_out_of_range",
            scene: Some(small_scene(TRIANGLE, "")),
            files: &[],
            extra_args: &["--camera", "5"],
            expect: &["--camera 5", "1 camera"],
        },
        ErrorCase {
            name: "camera_zero",
            scene: Some(small_scene(TRIANGLE, "")),
            files: &[],
            extra_args: &["--camera", "0"],
            expect: &["--camera 0"],
        },
        ErrorCase {
            name: "zero_threads",
            scene: Some(small_scene(TRIANGLE, "")),
            files: &[],
            extra_args: &["--threads", "0"],
            expect: &["--threads"],
        },
        ErrorCase {
            name: "zero_tile_size",
            scene: Some(small_scene(TRIANGLE, "")),
            files: &[],
            extra_args: &["--tile-size", "0"],
            expect: &["--tile-size"],
        },
    ]
}

#[test]
fn errors_are_reported_without_panicking() {
    let mut failures = Vec::new();
    for case in error_cases() {
        let tmp = TempDir::new(&format!("cli-{}", case.name));
        let file = format!("{}.xml", case.name);
        let scene = match &case.scene {
            Some(text) => tmp.write(&file, text),
            None => tmp.path().join(&file),
        };
        for (name, text) in case.files {
            tmp.write(name, text);
        }
        let out = tmp.path().join("out");
        let mut args = vec![
            "render".into(),
            scene.into_os_string(),
            "--out".into(),
            out.clone().into_os_string(),
            "--quiet".into(),
        ];
        args.extend(case.extra_args.iter().map(Into::into));
        let r = run(&args);

        let mut problems = Vec::new();
        if r.code == Some(0) || r.code.is_none() {
            problems.push(format!("expected a non-zero exit code, got {:?}", r.code));
        }
        if r.stderr.contains("panicked") {
            problems.push("stderr shows a panic".to_string());
        }
        if !r.stderr.contains("error") {
            problems.push("stderr has no error message".to_string());
        }
        for n in case.expect {
            if !r.stderr.contains(n) {
                problems.push(format!("stderr does not mention {n:?}"));
            }
        }
        if !pngs_in(&out).is_empty() {
            problems.push("an image was written despite the error".to_string());
        }
        if !problems.is_empty() {
            failures.push(format!("{}: {}\n{}", case.name, problems.join("; "), r.describe()));
        }
    }
    assert!(failures.is_empty(), "{} error case(s) failed:\n\n{}", failures.len(), failures.join("\n\n"));
}

#[test]
fn course_scene_with_a_missing_ply_names_it() {
    let scene = shared_scenes().join("xml/trex_smooth.xml");
    if !tessera_testkit::corpus_has(&scene) {
        return;
    }
    let missing = shared_scenes().join("xml/trex_smooth_ply/mesh_3.ply");
    if missing.exists() {
        eprintln!(
            "skipping: {} exists now, so trex_smooth is no longer a missing-asset scene",
            missing.display()
        );
        return;
    }
    let tmp = TempDir::new("cli-trex");
    let out = tmp.path().join("out");
    let r = run(&["render".as_ref(), scene.as_os_str(), "--out".as_ref(), out.as_os_str(), "-q".as_ref()]);
    assert!(r.code.is_some_and(|c| c != 0), "{}", r.describe());
    assert!(!r.stderr.contains("panicked"), "{}", r.describe());
    assert!(r.stderr.contains("mesh_3.ply") && r.stderr.contains("trex_smooth.xml"), "{}", r.describe());
    assert!(pngs_in(&out).is_empty(), "no image may be written");
}

/// Every repository scene renders to the same bytes (EXR and PNG) whether its camera rays walk
/// the world tree in pairs of packets, sixteen lanes at a time (what an AVX-512 host does), or
/// one packet at a time (`TESSERA_SIMD=avx2`, what every host can do). On a host without
/// AVX-512 both runs take the eight-lane walk.
#[test]
fn the_sixteen_lane_walk_changes_no_byte() {
    let tmp = TempDir::new("cli-simd");
    let scenes: Vec<PathBuf> = std::fs::read_dir(repo_scene(""))
        .expect("read scenes/")
        .map(|e| e.expect("scenes/ entry").path())
        .filter(|p| p.extension().is_some_and(|x| x == "xml"))
        .collect();
    assert!(scenes.len() >= 8, "the repository's scenes: {scenes:?}");
    let mut outputs = Vec::new();
    for simd in ["", "avx2"] {
        let out = tmp.path().join(format!("out-{simd}"));
        let mut args = vec!["render".into(), "--quiet".into(), "--out".into(), out.clone().into_os_string()];
        args.extend(scenes.iter().map(|s| s.clone().into_os_string()));
        let r = run_with_env(&args, &[("TESSERA_SIMD", simd)]);
        assert_eq!(r.code, Some(0), "TESSERA_SIMD={simd}: {}", r.describe());
        let mut files: Vec<(String, Vec<u8>)> = std::fs::read_dir(&out)
            .expect("read the output")
            .map(|e| {
                let p = e.expect("output entry").path();
                (
                    p.file_name().unwrap().to_string_lossy().into_owned(),
                    std::fs::read(&p).expect("read an output"),
                )
            })
            .collect();
        files.sort();
        outputs.push(files);
    }
    let names = |o: &[(String, Vec<u8>)]| o.iter().map(|f| f.0.clone()).collect::<Vec<_>>();
    assert_eq!(names(&outputs[0]), names(&outputs[1]), "the same files");
    assert!(outputs[0].iter().filter(|f| f.0.ends_with(".exr")).count() >= 6, "{:?}", names(&outputs[0]));
    for (a, b) in outputs[0].iter().zip(&outputs[1]) {
        assert!(a.1 == b.1, "{} differs between the two walks", a.0);
    }
}

/// A value of `TESSERA_SIMD` other than `avx2` is a warning that names the variable and its one
/// value, and the render goes on as if it were unset; `avx2` and unset print nothing of it.
#[test]
fn an_unknown_simd_value_is_named_and_ignored() {
    let tmp = TempDir::new("cli-simd-value");
    let scene = tmp.write("small.xml", small_scene(TRIANGLE, ""));
    let mut images = Vec::new();
    for (simd, warned) in [("", false), ("avx2", false), ("avx512", true)] {
        let out = tmp.path().join(format!("out-{simd}"));
        let args =
            ["render".as_ref(), "--quiet".as_ref(), "--out".as_ref(), out.as_os_str(), scene.as_os_str()];
        let r = run_with_env(&args, &[("TESSERA_SIMD", simd)]);
        assert_eq!(r.code, Some(0), "TESSERA_SIMD={simd}: {}", r.describe());
        assert_eq!(r.stderr.contains("TESSERA_SIMD"), warned, "TESSERA_SIMD={simd}: {}", r.describe());
        if warned {
            assert!(
                r.stderr.contains("warning: TESSERA_SIMD=avx512 ") && r.stderr.contains("'avx2'"),
                "{}",
                r.describe()
            );
        }
        images.push(std::fs::read(out.join("small.png")).expect("the image"));
    }
    assert!(images.iter().all(|i| *i == images[0]), "the same image whatever the value");
}
