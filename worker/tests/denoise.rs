//! `tessera-worker render --denoise` end to end: the real binary, the real Intel Open Image
//! Denoise library (found as a user's machine would find it), real EXR files.

mod support;
use support::*;

use std::path::Path;

use tessera::hdr_io::read_float_image;
use tessera::image::Image;
use tessera_testkit::{TempDir, denoiser_found, small_path_traced_box};

/// The path-traced camera with next-event estimation and importance sampling.
const CAMERA: &str = "3";
const STEM: &str = "glass_next_importance";

/// Relative mean squared error of `img` against `reference`: the mean over pixels and channels
/// of (x − r)² / (r² + 0.01), so dark and bright regions weigh alike.
fn rel_mse(img: &Image, reference: &Image) -> f64 {
    assert_eq!((img.width, img.height), (reference.width, reference.height));
    let mut sum = 0.0;
    for (p, r) in img.pixels.iter().zip(&reference.pixels) {
        for c in 0..3 {
            let (x, r) = (f64::from(p[c]), f64::from(r[c]));
            sum += (x - r) * (x - r) / (r * r + 0.01);
        }
    }
    sum / (img.pixels.len() * 3) as f64
}

fn render(scene: &Path, out: &Path, extra: &[&str]) -> Run {
    let mut args = vec!["render".to_string(), scene.display().to_string(), "--quiet".into(), "--out".into()];
    args.push(out.display().to_string());
    args.extend(["--camera", CAMERA].map(String::from));
    args.extend(extra.iter().map(|s| s.to_string()));
    let r = run(&args);
    assert_eq!(r.code, Some(0), "{}", r.describe());
    r
}

#[test]
fn a_denoised_frame_is_written_beside_the_raw_one_and_is_closer_to_a_converged_render() {
    if !denoiser_found(tessera_denoise::oidn().map(|_| ())) {
        return;
    }
    let dir = TempDir::new("denoise-cli");
    let Some(scene) = small_path_traced_box(dir.path()) else { return };
    let (noisy, plain, reference) =
        (dir.path().join("noisy"), dir.path().join("plain"), dir.path().join("ref"));
    let r = render(&scene, &noisy, &["--samples", "8", "--denoise"]);
    assert!(
        r.stdout.contains("denoised in") && r.stdout.contains("Intel Open Image Denoise 2."),
        "{}",
        r.describe()
    );
    let mut names: Vec<String> =
        std::fs::read_dir(&noisy).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    names.sort();
    let expected = [STEM, "_denoised"].concat();
    assert_eq!(
        names,
        [format!("{STEM}.exr"), format!("{STEM}.png"), format!("{expected}.exr"), format!("{expected}.png")]
    );
    // The course's outputs are what a render without --denoise writes, to the bit: the features
    // draw no random numbers.
    render(&scene, &plain, &["--samples", "8"]);
    for ext in ["exr", "png"] {
        let name = format!("{STEM}.{ext}");
        assert!(
            std::fs::read(noisy.join(&name)).unwrap() == std::fs::read(plain.join(&name)).unwrap(),
            "{name} changed with --denoise"
        );
    }
    render(&scene, &reference, &["--samples", "256"]);
    let truth = read_float_image(&reference.join(format!("{STEM}.exr"))).unwrap();
    let raw = read_float_image(&noisy.join(format!("{STEM}.exr"))).unwrap();
    let clean = read_float_image(&noisy.join(format!("{expected}.exr"))).unwrap();
    let (before, after) = (rel_mse(&raw, &truth), rel_mse(&clean, &truth));
    eprintln!("relative MSE against 256 spp: raw 8 spp {before:.4}, denoised {after:.4}");
    assert!(after * 4.0 < before, "the denoised frame is not much closer: raw {before}, denoised {after}");
    // The denoised PNG is a real picture of the box, not black: its mean is near the raw one's.
    let mean = |img: &Image| img.pixels.iter().map(|p| f64::from(p[0] + p[1] + p[2])).sum::<f64>();
    let ratio = mean(&clean) / mean(&raw);
    assert!((0.8..1.2).contains(&ratio), "denoised / raw brightness {ratio}");
}

#[test]
fn a_missing_denoiser_is_an_error_that_says_how_to_install_it_and_nothing_is_rendered() {
    let dir = TempDir::new("denoise-missing");
    let scene = dir.write("s.xml", tessera_testkit::tiny_scene(8, 8));
    let out = dir.path().join("out");
    let r = support::run_with_env(
        &["render", scene.to_str().unwrap(), "--denoise", "--out", out.to_str().unwrap()],
        &[("TESSERA_OIDN_LIB", "/nonexistent/oidn/lib")],
    );
    assert_eq!(r.code, Some(1), "{}", r.describe());
    assert!(
        r.stderr.contains(
            "--denoise: Intel Open Image Denoise was not found: TESSERA_OIDN_LIB is /nonexistent/oidn/lib"
        ) && r.stderr.contains("python3 -m pip install pyoidn"),
        "{}",
        r.describe()
    );
    assert!(!out.exists(), "nothing is written, not even the output folder");
}
