//! End-to-end tests of `tessera-worker tonemap`: the real binary on the course's official HDR
//! outputs (compared with the official tone-mapped PNGs) and on bad input. Every test writes only
//! into its own directory under the system temp dir.

mod support;
use support::*;

use std::path::PathBuf;

use tessera::hdr_io::{read_hdr, write_hdr};
use tessera::image::Image;
use tessera::tonemap::params::Photographic;
use tessera::tonemap::tonemap;
use tessera_testkit::TempDir;
use tessera_testkit::rgb8::Rgb8;

fn reference_dir() -> PathBuf {
    tessera_testkit::shared_scenes().join("reference")
}

/// The official `NAME.exr` and `NAME.png`, or `None` (with a message) when the corpus is absent.
fn official(name: &str) -> Option<(PathBuf, PathBuf)> {
    let dir = reference_dir();
    let (exr, png) = (dir.join(format!("{name}.exr")), dir.join(format!("{name}.png")));
    (tessera_testkit::corpus_has(&exr) && tessera_testkit::corpus_has(&png)).then_some((exr, png))
}

/// Largest per-channel difference and mean absolute difference.
fn difference(a: &Rgb8, b: &Rgb8) -> (u8, f64) {
    assert_eq!((a.width, a.height), (b.width, b.height), "image sizes differ");
    let max = a.data.iter().zip(&b.data).map(|(x, y)| x.abs_diff(*y)).max().unwrap_or(0);
    let sum: u64 = a.data.iter().zip(&b.data).map(|(x, y)| u64::from(x.abs_diff(*y))).sum();
    (max, sum as f64 / a.data.len().max(1) as f64)
}

/// Runs `tonemap` on the official EXR with `args` and checks the PNG against the official one.
fn check_reference(name: &str, args: &[&str]) {
    let Some((exr, png)) = official(name) else { return };
    let dir = TempDir::new(&format!("tonemap-cli-{name}"));
    let out = dir.path().join(format!("{name}.png"));
    let mut argv: Vec<std::ffi::OsString> = vec!["tonemap".into(), exr.clone().into()];
    argv.extend(args.iter().map(Into::into));
    argv.extend(["-o".into(), out.clone().into()]);
    let r = run(&argv);
    assert_eq!(r.code, Some(0), "{}", r.describe());
    // One summary line naming the output, with the statistics.
    assert_eq!(r.stdout.lines().count(), 1, "{}", r.describe());
    for needle in [out.to_str().unwrap(), "log-average luminance", "non-finite pixel(s)"] {
        assert!(r.stdout.contains(needle), "missing {needle:?}: {}", r.describe());
    }
    let ours = Rgb8::read_png(&out).expect("output PNG");
    let theirs = Rgb8::read_png(&png).expect("official PNG");
    let (max, mean) = difference(&ours, &theirs);
    println!("{name} {args:?}: max difference {max}, mean {mean:.4}");
    assert!(max <= 1, "{name}: off by up to {max} code values (mean {mean:.4})");
}

#[test]
fn tonemap_reproduces_official_pngs() {
    // Scene parameters (from the scene files): head_env_light 0.18 1 (the defaults, given
    // explicitly here), sphere_point_hdr_texture 0.01 2, VeachAjar_hw6's path camera 0.20 0.
    check_reference(
        "head_env_light",
        &["--key", "0.18", "--burn", "1", "--saturation", "1", "--gamma", "2.2"],
    );
    check_reference("sphere_point_hdr_texture", &["--key", "0.01", "--burn", "2"]);
    check_reference("VeachAjar_hw6__VeachAjar_path", &["--key", "0.2", "--burn", "0"]);
}

#[test]
fn tonemap_takes_its_defaults_from_a_scene() {
    // sphere_point_hdr_texture's <Tonemap> says 0.01 2: with --scene alone the official PNG comes out.
    let scene = reference_dir().join("../xml/sphere_point_hdr_texture.xml");
    let s = scene.to_str().unwrap();
    check_reference("sphere_point_hdr_texture", &["--scene", s]);
    // An explicit option still wins over the scene's.
    let Some((exr, _)) = official("sphere_point_hdr_texture") else { return };
    let dir = TempDir::new("tonemap-cli-scene");
    let out = dir.path().join("o.png");
    let r = run(&[
        OsArg::from("tonemap"),
        exr.clone().into(),
        "--scene".into(),
        s.into(),
        "--key".into(),
        "0.5".into(),
        "-o".into(),
        out.into(),
    ]);
    assert_eq!(r.code, Some(0), "{}", r.describe());
    assert!(r.stdout.contains("key 0.5") && r.stdout.contains("burn 2%"), "{}", r.describe());
    // A camera number the scene does not have, and a scene that cannot be read.
    let r = run(&[
        OsArg::from("tonemap"),
        exr.clone().into(),
        "--scene".into(),
        s.into(),
        "--camera".into(),
        "3".into(),
        "-o".into(),
        dir.path().join("p.png").into(),
    ]);
    assert_eq!(r.code, Some(1), "{}", r.describe());
    assert!(r.stderr.contains("--camera 3") && r.stderr.contains("1 camera(s)"), "{}", r.describe());
    let r = run(&[
        OsArg::from("tonemap"),
        exr.into(),
        "--scene".into(),
        "nope.xml".into(),
        "-o".into(),
        dir.path().join("q.png").into(),
    ]);
    assert_eq!(r.code, Some(1), "{}", r.describe());
    assert!(r.stderr.contains("nope.xml: cannot read the scene file"), "{}", r.describe());
}

#[test]
fn each_operator_re_tone_maps_to_the_png_the_render_wrote() {
    // The 2025 cube_point_hdr camera lists three Tonemaps (Photographic, ACES, Filmic), each
    // with its own PNG. Re-tone-mapping the rendered EXR with --scene and --operator must give
    // each of those PNGs back byte for byte, and the three must differ.
    let scene = reference_dir().join("../json/hw5/cube_point_hdr.json");
    if !tessera_testkit::corpus_has(&scene) {
        return;
    }
    let dir = TempDir::new("tonemap-cli-operators");
    let r = run(&[
        OsArg::from("render"),
        scene.clone().into(),
        "--quiet".into(),
        "--out".into(),
        dir.path().into(),
    ]);
    assert_eq!(r.code, Some(0), "{}", r.describe());
    let exr = dir.path().join("cube_point_hdr.exr");
    let mut rendered = Vec::new();
    for (operator, suffix, shown) in
        [("photographic", "_phot", "Photographic"), ("aces", "_aces", "ACES"), ("filmic", "_film", "Filmic")]
    {
        let out = dir.path().join(format!("again_{operator}.png"));
        let r = run(&[
            OsArg::from("tonemap"),
            exr.clone().into(),
            "--scene".into(),
            scene.clone().into(),
            "--operator".into(),
            operator.into(),
            "-o".into(),
            out.clone().into(),
        ]);
        assert_eq!(r.code, Some(0), "{}", r.describe());
        assert!(r.stdout.contains(&format!(", {shown}, key 0.18")), "{}", r.describe());
        let from_render = std::fs::read(dir.path().join(format!("cube_point_hdr{suffix}.png"))).unwrap();
        assert!(std::fs::read(&out).unwrap() == from_render, "{operator}: differs from the render's PNG");
        rendered.push(from_render);
    }
    assert!(rendered[0] != rendered[1] && rendered[1] != rendered[2] && rendered[0] != rendered[2]);
    // An operator that does not exist is refused with the choices.
    let r = run(&[
        OsArg::from("tonemap"),
        exr.into(),
        "--operator".into(),
        "drago".into(),
        "-o".into(),
        dir.path().join("x.png").into(),
    ]);
    assert_eq!(r.code, Some(2), "{}", r.describe());
    assert!(r.stderr.contains("expected Photographic, Filmic or ACES"), "{}", r.describe());
}

#[test]
fn tonemap_defaults_are_the_course_defaults() {
    let Some((exr, _)) = official("sphere_env_light") else { return };
    let dir = TempDir::new("tonemap-cli-defaults");
    let (plain, explicit) = (dir.path().join("plain.png"), dir.path().join("explicit.png"));
    let r = run(&[OsArg::from("tonemap"), exr.clone().into(), "-o".into(), plain.clone().into()]);
    assert_eq!(r.code, Some(0), "{}", r.describe());
    assert!(r.stdout.contains("key 0.18") && r.stdout.contains("burn 1%") && r.stdout.contains("gamma 2.2"));
    let args = ["--key", "0.18", "--burn", "1", "--saturation", "1", "--gamma", "2.2"];
    let mut argv: Vec<OsArg> = vec!["tonemap".into(), exr.into(), "--out".into(), explicit.clone().into()];
    argv.extend(args.iter().map(Into::into));
    let r = run(&argv);
    assert_eq!(r.code, Some(0), "{}", r.describe());
    assert_eq!(Rgb8::read_png(&plain).unwrap(), Rgb8::read_png(&explicit).unwrap());
}

type OsArg = std::ffi::OsString;

#[test]
fn tonemap_reads_radiance_hdr_and_reports_non_finite_pixels() {
    let dir = TempDir::new("tonemap-cli-hdr");
    let pixels: Vec<[f32; 3]> =
        (0..8 * 6).map(|k| [k as f32 * 0.3, 1.0 + (k % 5) as f32, 0.25 * (k % 7) as f32]).collect();
    let input = dir.path().join("gradient.hdr");
    write_hdr(&input, &Image { width: 8, height: 6, pixels }).unwrap();
    let out = dir.path().join("gradient.png");
    let r = run(&[
        OsArg::from("tonemap"),
        input.clone().into(),
        "--gamma".into(),
        "srgb".into(),
        "-o".into(),
        out.clone().into(),
    ]);
    assert_eq!(r.code, Some(0), "{}", r.describe());
    assert!(r.stdout.contains("gamma sRGB") && r.stdout.contains("0 non-finite"), "{}", r.describe());
    // Exactly what the library gives for the same file.
    let params = Photographic { gamma: tessera::tonemap::params::Gamma::Srgb, ..Photographic::default() };
    let (expected, _) = tonemap(&read_hdr(&input).unwrap(), &params);
    assert_eq!(Rgb8::read_png(&out).unwrap().data, expected);

    // An EXR with NaN and infinite pixels: counted in the summary, warned about, still written.
    let Some((_, _)) = official("head_env_light") else { return };
    let mut img = tessera::hdr_io::read_exr(&reference_dir().join("head_env_light.exr")).unwrap();
    img.pixels[0] = [f32::NAN; 3];
    img.pixels[1] = [f32::INFINITY, 0.0, 1.0];
    let bad = dir.path().join("bad.exr");
    tessera::hdr_io::write_exr(&bad, &img).unwrap();
    let out = dir.path().join("bad.png");
    let r = run(&[OsArg::from("tonemap"), bad.into(), "-o".into(), out.clone().into()]);
    assert_eq!(r.code, Some(0), "{}", r.describe());
    assert!(r.stdout.contains("2 non-finite pixel(s)"), "{}", r.describe());
    assert!(r.stderr.contains("warning") && r.stderr.contains("bad.exr"), "{}", r.describe());
    let png = Rgb8::read_png(&out).unwrap();
    assert_eq!(&png.data[..6], [0, 0, 0, 255, 0, 0]);
}

#[test]
fn tonemap_errors_name_the_file_and_exit_non_zero() {
    let dir = TempDir::new("tonemap-cli-errors");
    let out = dir.path().join("out.png");

    let missing = dir.path().join("missing.exr");
    let r = run(&[OsArg::from("tonemap"), missing.into(), "-o".into(), out.clone().into()]);
    assert_eq!(r.code, Some(1), "{}", r.describe());
    assert!(r.stderr.contains("missing.exr") && r.stderr.contains("cannot read"), "{}", r.describe());

    // A PNG (even one named .exr) is not an HDR image.
    let png = dir.path().join("picture.exr");
    tessera::hdr_io::write_png_rgb8(&png, 2, 2, &[7; 12]).unwrap();
    let r = run(&[OsArg::from("tonemap"), png.into(), "-o".into(), out.clone().into()]);
    assert_eq!(r.code, Some(1), "{}", r.describe());
    assert!(
        r.stderr.contains("picture.exr")
            && r.stderr.contains("not an OpenEXR or Radiance HDR file")
            && r.stderr.contains("PNG"),
        "{}",
        r.describe()
    );

    // A truncated EXR.
    let cut = dir.path().join("cut.exr");
    let mut bytes = vec![0x76, 0x2f, 0x31, 0x01];
    bytes.extend_from_slice(&[2, 0, 0, 0, b'c', b'h']);
    std::fs::write(&cut, bytes).unwrap();
    let r = run(&[OsArg::from("tonemap"), cut.into(), "-o".into(), out.clone().into()]);
    assert_eq!(r.code, Some(1), "{}", r.describe());
    assert!(r.stderr.contains("cut.exr") && r.stderr.contains("OpenEXR"), "{}", r.describe());
    assert!(!out.exists(), "no output for a failed input");

    // An output that cannot be written.
    let Some((exr, _)) = official("head_env_light") else { return };
    let nowhere = dir.path().join("no/such/dir/out.png");
    let r = run(&[OsArg::from("tonemap"), exr.clone().into(), "-o".into(), nowhere.into()]);
    assert_eq!(r.code, Some(1), "{}", r.describe());
    assert!(r.stderr.contains("out.png") && r.stderr.contains("cannot write"), "{}", r.describe());

    // Parameters out of range: named, non-zero.
    for (flag, value, needle) in [
        ("--key", "-1", "key -1"),
        ("--key", "0", "key 0"),
        ("--burn", "150", "burn percentage 150"),
        ("--saturation", "-2", "saturation -2"),
    ] {
        let r = run(&[
            OsArg::from("tonemap"),
            exr.clone().into(),
            flag.into(),
            value.into(),
            "-o".into(),
            out.clone().into(),
        ]);
        assert_eq!(r.code, Some(1), "{flag} {value}: {}", r.describe());
        assert!(r.stderr.contains(needle), "{flag} {value}: {}", r.describe());
    }
    // Unparseable values and a missing -o are usage errors (clap: exit 2).
    for args in [
        vec!["--gamma", "abc", "-o", "x.png"],
        vec!["--gamma", "0", "-o", "x.png"],
        vec!["--key", "abc", "-o", "x.png"],
        vec![],
    ] {
        let mut argv: Vec<OsArg> = vec!["tonemap".into(), exr.clone().into()];
        argv.extend(args.iter().map(Into::into));
        let r = run(&argv);
        assert_eq!(r.code, Some(2), "{args:?}: {}", r.describe());
    }
    assert!(!out.exists());
}

#[test]
fn tonemap_help_explains_every_option() {
    let r = run(&["tonemap", "--help"]);
    assert_eq!(r.code, Some(0), "{}", r.describe());
    for needle in
        ["--key", "--burn", "--saturation", "--gamma", "--out", "srgb", "0.18", "photographic", "OpenEXR"]
    {
        assert!(r.stdout.contains(needle), "--help lacks {needle:?}:\n{}", r.stdout);
    }
    let r = run(&["--help"]);
    assert!(r.stdout.contains("tonemap"), "{}", r.stdout);
}
