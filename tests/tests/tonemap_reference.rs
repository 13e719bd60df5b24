//! The photographic tone-mapping operator (`tessera::tonemap`, scene-format.md §12.3) against the
//! course's official outputs: every official `.exr` in `../shared/scenes/reference` that has a
//! `.png` twin is tone-mapped with the Tonemap parameters of its scene, and every channel of
//! every pixel must be within 1 code value of the official PNG.
//!
//! Parameters are read from the scene XML in `../shared/scenes/xml` by a tiny string search (no
//! XML parser): the `<Camera>` whose `<ImageName>` produced the reference (`scene.exr` → the
//! scene's camera with an `.exr` ImageName; `scene__name.exr` → the camera with ImageName
//! `name.exr`), then its `<Tonemap>`'s `TMOOptions` (key, burn), `Saturation` and `Gamma`.
//! Comments are stripped first. What was found (all `Photographic`):
//!
//! | references | key | burn | saturation | gamma |
//! |---|---|---|---|---|
//! | sphere_env_light, mirror_sphere_env, glass_sphere_env, head_env_light, head_env_light_2019, audi-tt-pisa, audi-tt-glacier, every cornellbox_jaroslav_* | 0.18 | 1 | 1.0 | 2.2 |
//! | sphere_point_hdr_texture | 0.01 | 2 | 1.0 | 2.2 |
//! | VeachAjar_2019 | 0.36 | 0 | 1.0 | 2.2 |
//! | VeachAjar_hw6__VeachAjar_path | 0.20 | 0 | 1.0 | 2.2 |
//!
//! Excluded from the assertion (still tone-mapped and printed): the four path-traced
//! cornellbox_jaroslav_path_glass cameras *without* next-event estimation — `glass` (max 24,
//! mean 6.85 code values off), `glass_importance` (max 26, mean 9.03), `glass_russian` (max 17,
//! mean 1.24), `glass_importance_russian` (max 14, mean 0.89). Ours are darker; fitting the
//! scale says their PNGs were made with a log average about 20–25 % lower than these EXRs give
//! (e.g. `glass`: Ȳ 0.0483 instead of 0.0620, which then matches within 1), so they do not
//! follow the operator with δ = 1e-6 — the other 12 jaroslav path-tracing cameras, including the
//! same scene with next-event estimation, do.

use std::path::{Path, PathBuf};

use rayon::prelude::*;
use tessera::hdr_io::{read_exr, write_exr};
use tessera::tonemap::params::{Gamma, Photographic};
use tessera::tonemap::tonemap;
use tessera_testkit::TempDir;
use tessera_testkit::rgb8::Rgb8;

/// References whose PNG does not follow the operator (module docs: how far off and why).
const EXCLUDED: &[&str] = &[
    "cornellbox_jaroslav_path_glass__glass",
    "cornellbox_jaroslav_path_glass__glass_importance",
    "cornellbox_jaroslav_path_glass__glass_importance_russian",
    "cornellbox_jaroslav_path_glass__glass_russian",
];

/// §12.3 names these as reproduced within 1 code value; the test insists they were checked.
const NAMED_IN_SPEC: &[&str] =
    &["sphere_env_light", "mirror_sphere_env", "glass_sphere_env", "head_env_light", "audi-tt-pisa"];

// ---------------------------------------------------------------------------------------------
// Reading the Tonemap parameters out of the scene XML with plain string search.

fn strip_comments(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(start) = rest.find("<!--") {
        out.push_str(&rest[..start]);
        rest = match rest[start..].find("-->") {
            Some(end) => &rest[start + end + 3..],
            None => "",
        };
    }
    out.push_str(rest);
    out
}

/// The trimmed text of the first `<name>...</name>` in `block`.
fn element<'a>(block: &'a str, name: &str) -> Option<&'a str> {
    let open = format!("<{name}>");
    let close = format!("</{name}>");
    let start = block.find(&open)? + open.len();
    let end = block[start..].find(&close)? + start;
    Some(block[start..end].trim())
}

/// The Tonemap of the camera that wrote `image` (its ImageName's file stem), or of the first
/// camera with an `.exr` ImageName when `image` is `None`. Errors say what is missing.
fn tonemap_params(xml: &Path, image: Option<&str>) -> Result<Photographic, String> {
    let text = std::fs::read_to_string(xml).map_err(|e| format!("{}: {e}", xml.display()))?;
    let text = strip_comments(&text);
    let mut rest = text.as_str();
    while let Some(start) = rest.find("<Camera") {
        let end = rest[start..].find("</Camera>").ok_or("unterminated <Camera>")? + start;
        let block = &rest[start..end];
        rest = &rest[end..];
        let name = element(block, "ImageName").ok_or("camera without <ImageName>")?;
        let wanted = match image {
            Some(img) => Path::new(name).file_stem().is_some_and(|s| s == img),
            None => name.ends_with(".exr"),
        };
        if !wanted {
            continue;
        }
        let tm = element(block, "Tonemap").ok_or_else(|| format!("camera {name}: no <Tonemap>"))?;
        let tmo = element(tm, "TMO").unwrap_or("Photographic");
        if tmo != "Photographic" {
            return Err(format!("camera {name}: TMO {tmo}"));
        }
        let options: Vec<f64> = element(tm, "TMOOptions")
            .unwrap_or("0.18 1")
            .split_whitespace()
            .map(|v| v.parse().map_err(|_| format!("camera {name}: TMOOptions number {v:?}")))
            .collect::<Result<_, _>>()?;
        let [key, burn_percent] = options[..] else {
            return Err(format!("camera {name}: TMOOptions needs 2 numbers, found {options:?}"));
        };
        let saturation = match element(tm, "Saturation") {
            Some(s) => s.parse().map_err(|_| format!("camera {name}: Saturation {s:?}"))?,
            None => 1.0,
        };
        let gamma: Gamma = match element(tm, "Gamma") {
            Some(g) => g.parse()?,
            None => Gamma::default(),
        };
        return Ok(Photographic { key, burn_percent, saturation, gamma });
    }
    Err(format!("{}: no camera writes {}", xml.display(), image.unwrap_or("an .exr")))
}

// ---------------------------------------------------------------------------------------------
// The corpus.

struct Reference {
    /// `scene` or `scene__image`.
    stem: String,
    exr: PathBuf,
    png: PathBuf,
    params: Photographic,
}

/// Every official `.exr` with a `.png` twin and a scene file, sorted; `None` (with a message)
/// when the corpus is absent.
fn references() -> Option<Vec<Reference>> {
    let root = tessera_tests::shared_scenes();
    let dir = root.join("reference");
    if !tessera_tests::corpus_has(&dir) {
        return None;
    }
    let entries = std::fs::read_dir(&dir).unwrap();
    let mut exrs: Vec<PathBuf> =
        entries.flatten().map(|e| e.path()).filter(|p| p.extension().is_some_and(|e| e == "exr")).collect();
    exrs.sort();
    let mut out = Vec::new();
    for exr in exrs {
        let png = exr.with_extension("png");
        let stem = exr.file_stem().and_then(|s| s.to_str()).unwrap_or_default().to_owned();
        if !png.exists() {
            println!("{stem}: no official .png twin; skipped");
            continue;
        }
        let (scene, image) = match stem.split_once("__") {
            Some((s, i)) => (s, Some(i)),
            None => (stem.as_str(), None),
        };
        let xml = root.join("xml").join(format!("{scene}.xml"));
        if !xml.exists() {
            println!("{stem}: scene file {} absent; skipped", xml.display());
            continue;
        }
        let params = tonemap_params(&xml, image).unwrap_or_else(|e| panic!("{stem}: {e}"));
        out.push(Reference { stem, exr, png, params });
    }
    Some(out)
}

/// (largest difference, mean absolute difference, channels off by more than 1) over all channels.
fn difference(ours: &[u8], official: &[u8]) -> (u8, f64, usize) {
    assert_eq!(ours.len(), official.len());
    let (mut max, mut sum, mut over) = (0u8, 0u64, 0usize);
    for (a, b) in ours.iter().zip(official) {
        let d = a.abs_diff(*b);
        max = max.max(d);
        sum += u64::from(d);
        over += usize::from(d > 1);
    }
    (max, sum as f64 / ours.len().max(1) as f64, over)
}

#[test]
fn official_exrs_tone_map_to_their_official_pngs() {
    let Some(refs) = references() else { return };
    let results: Vec<(u8, f64, usize, String)> = refs
        .par_iter()
        .map(|r| {
            let img = read_exr(&r.exr).unwrap_or_else(|e| panic!("{e}"));
            let official = Rgb8::read_png(&r.png).unwrap_or_else(|e| panic!("{}: {e}", r.png.display()));
            assert_eq!((img.width, img.height), (official.width, official.height), "{}", r.stem);
            let (ours, stats) = tonemap(&img, &r.params);
            let (max, mean, over) = difference(&ours, &official.data);
            let p = &r.params;
            let line = format!(
                "{:<62} a={} b={} s={} γ={}  Ȳ={:.5} L_white={:.4} non-finite={}  max {max}, mean {mean:.4}, {over} channels > 1",
                r.stem, p.key, p.burn_percent, p.saturation, p.gamma, stats.log_average, stats.white, stats.non_finite
            );
            (max, mean, over, line)
        })
        .collect();
    let mut failures = Vec::new();
    for (r, (max, _, over, line)) in refs.iter().zip(&results) {
        let excluded = EXCLUDED.contains(&r.stem.as_str());
        println!("{}{line}", if excluded { "(excluded) " } else { "" });
        if !excluded && *max > 1 {
            failures.push(format!("{}: max difference {max}, {over} channels off by more than 1", r.stem));
        }
    }
    let checked: Vec<&str> = refs.iter().map(|r| r.stem.as_str()).collect();
    for name in NAMED_IN_SPEC {
        assert!(checked.contains(name), "{name}: official .exr/.png/.xml not found in the corpus");
    }
    assert!(failures.is_empty(), "tone-mapped references off by more than 1:\n{}", failures.join("\n"));
}

#[test]
fn scene_parameters_come_from_the_right_camera() {
    let xml = tessera_tests::shared_scenes().join("xml");
    if !tessera_tests::corpus_has(&xml) {
        return;
    }
    let get = |scene: &str, image: Option<&str>| {
        tonemap_params(&xml.join(format!("{scene}.xml")), image).unwrap_or_else(|e| panic!("{e}"))
    };
    let p = get("sphere_point_hdr_texture", None);
    assert_eq!((p.key, p.burn_percent, p.saturation, p.gamma), (0.01, 2.0, 1.0, Gamma::Power(2.2)));
    // The second camera (the first writes a PNG without a Tonemap).
    let p = get("VeachAjar_hw6", Some("VeachAjar_path"));
    assert_eq!((p.key, p.burn_percent), (0.2, 0.0));
    assert_eq!(get("VeachAjar_2019", None).key, 0.36);
    assert_eq!(get("cornellbox_jaroslav_path_glass", Some("glass_next_russian")), Photographic::default());
    assert!(tonemap_params(&xml.join("VeachAjar_hw6.xml"), Some("no_such_image")).is_err());
}

#[test]
fn official_exr_round_trips_through_write_exr() {
    let root = tessera_tests::shared_scenes().join("reference");
    let path = root.join("sphere_env_light.exr");
    if !tessera_tests::corpus_has(&path) {
        return;
    }
    let dir = TempDir::new("tonemap-ref");
    let img = read_exr(&path).unwrap();
    let copy = dir.join("copy.exr");
    write_exr(&copy, &img).unwrap();
    let back = read_exr(&copy).unwrap();
    assert_eq!((back.width, back.height), (img.width, img.height));
    assert!(
        img.pixels
            .iter()
            .flatten()
            .zip(back.pixels.iter().flatten())
            .all(|(a, b)| a.to_bits() == b.to_bits()),
        "write_exr/read_exr changed a value of {}",
        path.display()
    );
    let p = Photographic::default();
    assert_eq!(tonemap(&img, &p), tonemap(&back, &p));
}
