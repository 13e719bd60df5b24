//! `tessera-worker render` with HDR image names: the `.exr` (or `.hdr`) of the linear image and
//! the tone-mapped `.png` beside it, checked with our reader, the exr crate and, independently,
//! Python's OpenEXR bindings.

mod support;

use std::path::Path;
use std::process::Command;

use support::run;
use tessera::hdr_io::{read_exr, read_hdr};
use tessera::image::Image;
use tessera::render::{RenderSettings, render_camera};
use tessera::scene::load::load_scene_file;
use tessera::tonemap::tonemap;

use tessera_testkit::rgb8::Rgb8;
use tessera_testkit::{TempDir, shared_scenes};

/// The library's render of camera 0 of `scene`, for comparison with the files.
fn library_render(scene: &Path) -> Image {
    let s = load_scene_file(scene).unwrap();
    render_camera(&s, 0, 32, &RenderSettings::default(), &|_, _| {}).0
}

fn png_bytes(path: &Path) -> Vec<u8> {
    Rgb8::read_png(path).unwrap().data
}

#[test]
fn exr_image_name_writes_the_linear_exr_and_the_tone_mapped_png() {
    let scene = shared_scenes().join("xml/cube_point_hdr.xml");
    let out = TempDir::new("hdr-exr");
    let r =
        run(&["render".as_ref(), scene.as_os_str(), "--quiet".as_ref(), "--out".as_ref(), out.as_os_str()]);
    assert_eq!(r.code, Some(0), "{}", r.describe());
    let exr = out.join("cube_point_hdr.exr");
    let png = out.join("cube_point_hdr.png");
    assert!(
        r.stdout.contains("cube_point_hdr.exr + ") && r.stdout.contains("cube_point_hdr.png"),
        "{}",
        r.describe()
    );
    // The EXR holds exactly the rendered floats (0-255 scale, no clamping).
    let ours = library_render(&scene);
    let read = read_exr(&exr).unwrap();
    assert_eq!(read, ours);
    assert!(read.pixels.iter().any(|p| p[0] > 255.0), "an HDR scene has values above 255");
    // The PNG is the scene's Tonemap (photographic, key 0.18, burn 1 %) of that image.
    let hdr = load_scene_file(&scene).unwrap();
    let (expected, _) = tonemap(&ours, &hdr.cameras[0].tonemaps[0].params);
    assert_eq!(png_bytes(&png), expected);
}

#[test]
fn hdr_image_name_writes_radiance_rgbe_and_png() {
    let dir = TempDir::new("hdr-rgbe");
    let scene_text = std::fs::read_to_string(shared_scenes().join("xml/cube_point_hdr.xml"))
        .unwrap()
        .replace("cube_point_hdr.exr", "cube.hdr")
        .replace("<ImageResolution>800 800</ImageResolution>", "<ImageResolution>80 80</ImageResolution>")
        .replace("ply/", &format!("{}/", shared_scenes().join("xml/ply").display()));
    let scene = dir.join("cube.xml");
    std::fs::write(&scene, scene_text).unwrap();
    let r =
        run(&["render".as_ref(), scene.as_os_str(), "--quiet".as_ref(), "--out".as_ref(), dir.as_os_str()]);
    assert_eq!(r.code, Some(0), "{}", r.describe());
    let ours = library_render(&scene);
    let read = read_hdr(&dir.join("cube.hdr")).unwrap();
    assert_eq!((read.width, read.height), (80, 80));
    // RGBE keeps 8 bits of mantissa per channel relative to the pixel's largest channel.
    for (a, b) in read.pixels.iter().zip(&ours.pixels) {
        let m = b.iter().cloned().fold(0.0f32, f32::max);
        for c in 0..3 {
            assert!((a[c] - b[c]).abs() <= m / 128.0 + 1e-30, "{a:?} vs {b:?}");
        }
    }
    assert!(dir.join("cube.png").exists());
}

/// Reads an EXR with Python's OpenEXR bindings (the library other tools are built on) and
/// returns its size and pixels as the exact float32 values. `None` when Python or the module is
/// missing and `TESSERA_REQUIRE_OPENEXR` is unset (CI sets it: `.ci/run` installs the module).
fn python_read_exr(path: &Path) -> Option<Image> {
    const SCRIPT: &str = r#"
import sys, OpenEXR, numpy as np
f = OpenEXR.File(sys.argv[1])
ch = f.channels()
if "RGB" in ch:
    rgb = ch["RGB"].pixels
else:
    rgb = np.stack([ch["R"].pixels, ch["G"].pixels, ch["B"].pixels], axis=-1)
rgb = np.ascontiguousarray(rgb, dtype=np.float32)
h, w, _ = rgb.shape
sys.stdout.write(f"{w} {h}\n")
sys.stdout.write(rgb.view(np.uint32).ravel().tobytes().hex())
"#;
    let required = std::env::var_os("TESSERA_REQUIRE_OPENEXR").is_some();
    let out = Command::new("python3").arg("-c").arg(SCRIPT).arg(path).output();
    let out = match out {
        Ok(o) if o.status.success() => o,
        Ok(o) => {
            let why = String::from_utf8_lossy(&o.stderr).into_owned();
            assert!(!required, "python3 could not read {}: {why}", path.display());
            eprintln!(
                "skipping the independent EXR check: python3 OpenEXR is not available ({})",
                why.trim()
            );
            return None;
        }
        Err(e) => {
            assert!(!required, "cannot run python3: {e}");
            eprintln!("skipping the independent EXR check: cannot run python3 ({e})");
            return None;
        }
    };
    let text = String::from_utf8(out.stdout).unwrap();
    let (size, hex) = text.split_once('\n').unwrap();
    let mut dims = size.split(' ').map(|s| s.parse::<u32>().unwrap());
    let (width, height) = (dims.next().unwrap(), dims.next().unwrap());
    let bytes: Vec<u8> =
        (0..hex.len()).step_by(2).map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap()).collect();
    let floats: Vec<f32> =
        bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
    let pixels = floats.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    Some(Image { width, height, pixels })
}

#[test]
fn the_exr_opens_bit_exact_in_an_independent_reader() {
    let scene = shared_scenes().join("xml/cube_point_hdr.xml");
    let out = TempDir::new("hdr-python");
    let r =
        run(&["render".as_ref(), scene.as_os_str(), "--quiet".as_ref(), "--out".as_ref(), out.as_os_str()]);
    assert_eq!(r.code, Some(0), "{}", r.describe());
    let Some(theirs) = python_read_exr(&out.join("cube_point_hdr.exr")) else { return };
    let ours = library_render(&scene);
    assert_eq!((theirs.width, theirs.height), (800, 800));
    let differing = theirs.pixels.iter().zip(&ours.pixels).filter(|(a, b)| a != b).count();
    assert_eq!(differing, 0, "{differing} pixels read back differently by OpenEXR");
}

#[test]
fn env_sampling_option_is_documented_and_checked() {
    let r = run(&["render", "--help"]);
    assert!(r.stdout.contains("--env-sampling") && r.stdout.contains("importance"), "{}", r.describe());
    let r = run(&["render", "x.xml", "--env-sampling", "magic"]);
    assert_eq!(r.code, Some(2), "{}", r.describe());
    assert!(r.stderr.contains("magic") && r.stderr.contains("uniform"), "{}", r.describe());
}

#[test]
fn a_scene_whose_environment_map_is_missing_fails_naming_the_file() {
    let scene = shared_scenes().join("xml/mirror_sphere_env.xml");
    let r = run(&[
        "render".as_ref(),
        scene.as_os_str(),
        "--quiet".as_ref(),
        "--out".as_ref(),
        TempDir::new("hdr-missing").as_os_str(),
    ]);
    assert_eq!(r.code, Some(1), "{}", r.describe());
    assert!(
        r.stderr.contains("textures/grace-new.exr") && r.stderr.contains("environment light"),
        "{}",
        r.describe()
    );
    assert!(!r.stderr.contains("panicked"), "{}", r.describe());
}
