//! Replays the fuzzing corpus and every crash the fuzzers found (fuzz/corpus/<target>/ and
//! fuzz/regressions/<target>/) through the same entry points as the fuzz targets in
//! fuzz/fuzz_targets/, on the stable toolchain: what once crashed must now give an error or a
//! result, on every CI run.

use std::path::{Path, PathBuf};

use tessera::assets::MemResolver;
use tessera::scene::build::build_scene;

fn inputs(target: &str) -> Vec<(PathBuf, Vec<u8>)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz");
    let mut out = Vec::new();
    for dir in ["corpus", "regressions"] {
        let Ok(entries) = std::fs::read_dir(root.join(dir).join(target)) else { continue };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_file() {
                let bytes = std::fs::read(&p).unwrap();
                out.push((p, bytes));
            }
        }
    }
    out.sort();
    out
}

/// Runs `f` on every input of `target`, naming the file of the first that panics.
fn replay(target: &str, min: usize, f: impl Fn(&[u8])) {
    let all = inputs(target);
    assert!(all.len() >= min, "fuzz/corpus/{target} holds {} inputs, expected at least {min}", all.len());
    for (path, bytes) in &all {
        if std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| f(bytes))).is_err() {
            panic!("{} panics", path.display());
        }
    }
}

fn scene(text_bytes: &[u8], name: &str, json: bool) {
    let Ok(text) = std::str::from_utf8(text_bytes) else { return };
    let path = Path::new(name);
    let parsed = if json {
        tessera::scene::json::parse_json(text, path)
    } else {
        tessera::scene::xml::parse_xml(text, path)
    };
    if let Ok(records) = parsed {
        let _ = build_scene(&records, &MemResolver::for_scene(Default::default(), name));
    }
}

/// The `render_xml` fuzz target's entry point, the same file.
#[path = "../../fuzz/probes/render_xml.rs"]
mod render_probe;

/// The renderer's fuzzer starts from the scene corpus: both corpora and its crashes render.
#[test]
fn render_xml_inputs() {
    replay("scene_xml", 1, render_probe::render_xml);
    replay("render_xml", 1, render_probe::render_xml);
}

#[test]
fn scene_xml_inputs() {
    replay("scene_xml", 1, |b| scene(b, "fuzz.xml", false));
}

#[test]
fn scene_json_inputs() {
    replay("scene_json", 1, |b| scene(b, "fuzz.json", true));
}

#[test]
fn ply_inputs() {
    replay("ply", 1, |b| {
        let _ = tessera::ply::parse_ply(b);
    });
}

#[test]
fn texture_image_inputs() {
    replay("texture_image", 1, |b| {
        if let Ok(img) = tessera::texture::image::TextureImage::decode(b) {
            let _ = img.bilinear(0.37, 0.81);
            let _ = img.nearest(0.99, 0.0);
        }
    });
}

#[test]
fn bundle_inputs() {
    replay("bundle", 1, |b| {
        let mut files = Default::default();
        if tessera_server::bundle::add_archive(&mut files, b).is_ok() {
            let _ = tessera_server::bundle::find_scene(&files, None);
        }
    });
}

#[test]
fn tile_upload_inputs() {
    replay("tile_upload", 1, |data| {
        if data.len() < 2 {
            return;
        }
        let pixels = usize::from(u16::from_le_bytes([data[0], data[1]]));
        let body = &data[2..];
        if let Some(px) = tessera::protocol::decode_tile(body, pixels) {
            assert_eq!(px.len(), pixels);
            assert_eq!(tessera::protocol::encode_tile(&px), body);
        }
    });
}
