//! `RussianRoulette` follows the course renderer's rule (`tessera::scene::records::Roulette::Course`),
//! which its official images show and which is biased upwards: the reference roulette images of
//! cornellbox_jaroslav_path_diffuse are 1.3-1.5x brighter than the converged picture, so a
//! textbook (unbiased) roulette misses them by 13-22 % in every channel.
//!
//! Roulette images at 100 samples per pixel are dominated by rare, large pixel values (a path that
//! survives is divided by potentials of 0.05-0.26 per vertex), so their plain means and PSNR say
//! little: two of our own renders with different seeds differ by as much as we differ from the
//! reference. The mean of each channel below its 99th percentile is steady: two of our seeds agree
//! within 0.8 %, the course rule is within 1.2 % of the reference in every channel of these two
//! cameras, and the unbiased rule 13-22 % below it.

use tessera::hdr_io::read_exr;
use tessera::image::Image;
use tessera::render::{RenderSettings, render_camera};
use tessera::scene::load::load_scene_file;
use tessera_testkit::{corpus_has, shared_scenes};

/// Per channel, the mean of the pixels at or below that channel's 99th percentile.
fn trimmed_means(img: &Image) -> [f64; 3] {
    std::array::from_fn(|c| {
        let mut v: Vec<f64> = img.pixels.iter().map(|p| p[c] as f64).collect();
        v.sort_by(f64::total_cmp);
        let cut = v[(v.len() - 1) * 99 / 100];
        let kept = &v[..v.partition_point(|&x| x <= cut)];
        kept.iter().sum::<f64>() / kept.len() as f64
    })
}

/// Renders the camera of cornellbox_jaroslav_path_diffuse that writes `image` at the scene's
/// own sample count and compares its trimmed means with the official EXR's.
fn check(image: &str, tolerance: f64) {
    let scene_path = shared_scenes().join("xml/cornellbox_jaroslav_path_diffuse.xml");
    let reference = shared_scenes().join(format!("reference/cornellbox_jaroslav_path_diffuse__{image}"));
    if !corpus_has(&scene_path) || !corpus_has(&reference) {
        return;
    }
    let scene = load_scene_file(&scene_path).unwrap();
    let camera = scene
        .cameras
        .iter()
        .position(|c| c.image_name == image)
        .unwrap_or_else(|| panic!("no camera writes {image}"));
    let (ours, _) = render_camera(&scene, camera, 32, &RenderSettings::default(), &|_, _| {});
    let official = read_exr(&reference).unwrap();
    let (a, b) = (trimmed_means(&ours), trimmed_means(&official));
    for c in 0..3 {
        let ratio = a[c] / b[c];
        assert!(
            (ratio - 1.0).abs() < tolerance,
            "{image}: channel {c}: trimmed mean {:.4} vs the official {:.4} (ratio {ratio:.4}); ours {a:?}, official {b:?}",
            a[c],
            b[c]
        );
    }
}

#[test]
fn roulette_without_next_event_estimation_matches_the_official_image() {
    check("diffuse_importance_russian.exr", 0.03);
}

#[test]
fn roulette_with_next_event_estimation_matches_the_official_image() {
    check("diffuse_next_importance_russian.exr", 0.03);
}
