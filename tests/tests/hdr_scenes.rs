//! HW5 course scenes: HDR output, the degamma rule, environment lights with substituted maps,
//! and the agreement of the environment estimators.

use tessera::image::Image;
use tessera::render::{RenderSettings, render_camera};
use tessera::scene::load::load_scene_file;
use tessera::scene::records::{EnvSampler, SceneRecords};
use tessera_tests::envmaps::{ENV_SCENES, load_substituted};
use tessera_tests::shared_scenes;

fn render(scene: &tessera::scene::Scene, settings: &RenderSettings) -> Image {
    render_camera(scene, 0, 32, settings, &|_, _| {}).0
}

/// cube_point_hdr is cube_point with a degamma'd cube and HDR output: the floor (plain
/// material) renders to the same linear values, the cube's reflectances become k^2.2.
#[test]
fn cube_point_hdr_differs_from_cube_point_only_by_degamma() {
    let xml = shared_scenes().join("xml");
    let ldr = load_scene_file(&xml.join("cube_point.xml")).unwrap();
    let hdr = load_scene_file(&xml.join("cube_point_hdr.xml")).unwrap();
    assert_eq!(hdr.cameras[0].image_name, "cube_point_hdr.exr");
    let a = render(&ldr, &RenderSettings::default());
    let b = render(&hdr, &RenderSettings::default());
    let mut same = 0;
    for (p, q) in a.pixels.iter().zip(&b.pixels) {
        if p == q {
            same += 1;
        } else {
            // A cube pixel: every channel of 0.651 0.389 0.389 is darker once linearised.
            assert!((0..3).all(|c| q[c] < p[c]), "{p:?} vs {q:?}");
        }
    }
    let share = same as f64 / a.pixels.len() as f64;
    assert!(share > 0.6 && share < 0.95, "floor share {share}");
    // Degamma with the camera's Gamma 2.2: 0.651 -> 0.389, as scene-format.md §6.6 works out.
    let m = &hdr.materials[1];
    assert!((m.diffuse.x - 0.651f64.powf(2.2)).abs() < 1e-12 && (m.diffuse.x - 0.389).abs() < 1e-3);
}

#[test]
fn a_missing_environment_map_is_an_error_naming_the_file() {
    let path = shared_scenes().join("xml/sphere_env_light.xml");
    let err = match load_scene_file(&path) {
        Ok(_) => panic!("sphere_env_light has no map here and must not load"),
        Err(e) => e.to_string(),
    };
    assert!(
        err.contains("sphere_env_light.xml:")
            && err.contains("textures/pisa_latlong.exr")
            && err.contains("environment light"),
        "{err}"
    );
}

/// Shrinks every camera to `width` pixels wide (same aspect and field of view).
fn shrink(rec: &mut SceneRecords, width: u32) {
    for c in &mut rec.cameras {
        c.height = (c.height * width / c.width).max(1);
        c.width = width;
    }
}

#[test]
fn every_substituted_environment_scene_renders() {
    for &(scene, map) in ENV_SCENES {
        let (s, subs) =
            load_substituted(scene, map, |r| shrink(r, 40)).unwrap_or_else(|e| panic!("{scene}: {e:#}"));
        assert!(!subs.maps.is_empty(), "{scene}: nothing substituted");
        assert!(s.env_light.is_some(), "{scene}");
        let img = render(&s, &RenderSettings { samples: Some(2), ..RenderSettings::default() });
        assert!(img.pixels.iter().all(|p| p.iter().all(|c| c.is_finite() && *c >= 0.0)), "{scene}");
        // Something is lit and the background shows the map.
        assert!(img.pixels.iter().any(|p| p[0] > 0.0), "{scene}");
    }
}

/// The three environment estimators converge to the same image (the course's uniform one,
/// cosine, and importance sampling by the map mixed with the cosine lobe) on sphere_env_light
/// lit by the sunrise map (a small bright sun). Background pixels are
/// bit-identical (same camera rays, same lookups); on the sphere the mean radiance must agree
/// within noise.
#[test]
fn environment_estimators_converge_to_the_same_image() {
    let (scene, _) = load_substituted("sphere_env_light", "sunrise", |r| shrink(r, 100)).unwrap();
    let run = |sampler, spp| {
        render(
            &scene,
            &RenderSettings { samples: Some(spp), env_sampling: Some(sampler), ..RenderSettings::default() },
        )
    };
    let uniform = run(EnvSampler::Uniform, 1024);
    let cosine = run(EnvSampler::Cosine, 1024);
    let importance = run(EnvSampler::Importance, 256);
    // The sphere: where two estimators at the same samples per pixel (so the same camera rays)
    // differ at all.
    let mask: Vec<bool> = uniform.pixels.iter().zip(&cosine.pixels).map(|(a, b)| a != b).collect();
    let n = mask.iter().filter(|m| **m).count();
    assert!(n > 200 && n < 1000, "sphere pixels: {n}");
    for (i, p) in uniform.pixels.iter().enumerate() {
        if !mask[i] {
            assert_eq!(*p, cosine.pixels[i], "background pixel {i} differs");
        }
    }
    // The sphere's mean per channel, without its 1 % lowest and 1 % highest pixels. The
    // sunrise map's sun has a core of six texels at 15,008 in blue (and about 0 in red and
    // green): one cosine or uniform sample in 280,000 that lands there makes a single pixel's
    // blue 40 times its neighbours' and moves the plain mean by 15 %, so whether the test
    // passed depended on whether one sample did. A wrong pdf moves every pixel and still
    // shows.
    let mean = |img: &Image| -> [f64; 3] {
        std::array::from_fn(|c| {
            let mut v: Vec<f64> =
                img.pixels.iter().zip(&mask).filter(|(_, m)| **m).map(|(p, _)| f64::from(p[c])).collect();
            v.sort_by(f64::total_cmp);
            let cut = n.div_ceil(100);
            let kept = &v[cut..n - cut];
            kept.iter().sum::<f64>() / kept.len() as f64
        })
    };
    let (u, c, i) = (mean(&uniform), mean(&cosine), mean(&importance));
    for ch in 0..3 {
        let rel_u = u[ch] / i[ch] - 1.0;
        let rel_c = c[ch] / i[ch] - 1.0;
        assert!(
            rel_u.abs() < TOLERANCE && rel_c.abs() < TOLERANCE,
            "channel {ch}: uniform {u:?}, cosine {c:?}, importance {i:?}"
        );
    }
}

/// Relative tolerance of the sphere means above. Measured over 6 seeds with the Sobol sampler,
/// the relative standard deviation of the sphere's mean is at most 0.35 % per channel (uniform
/// and cosine at 1024 spp, importance at 256), so 2 % is about 4 standard deviations of a
/// difference; a wrong pdf (a missing sin θ, a missing mixture weight) is off by far more. With
/// the 1 % trimmed at both ends (2026-11-27): the three agree within 0.8 %; importance
/// sampling without the sin θ of its pdf is 1.7-4.1 % off (green and blue fail), with the
/// map's mixture weight 1 instead of ½ 20-24 % off (both tried: the test fails).
/// The park map is not used: a few isolated blue-only texels (up to 11800) make its blue
/// channel heavy-tailed for the uniform and cosine estimators (one seed in six put the cosine
/// mean 13 % high through a single pixel).
const TOLERANCE: f64 = 0.02;
