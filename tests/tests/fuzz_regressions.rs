//! Replays the fuzzing corpus and every crash the fuzzers found (fuzz/corpus/<target>/ and
//! fuzz/regressions/<target>/) through the same entry points as the fuzz targets in
//! fuzz/fuzz_targets/, on the stable toolchain: what once crashed must now give an error or a
//! result, on every CI run.

use std::path::{Path, PathBuf};

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

// The fuzz targets' entry points: the files the targets include.
#[path = "../../fuzz/probes/inputs.rs"]
mod inputs_probe;
#[path = "../../fuzz/probes/scene.rs"]
mod scene_probe;

/// The renderer's fuzzers start from the scene corpora: both corpora of a dialect and its
/// crashes render.
#[test]
fn render_xml_inputs() {
    replay("scene_xml", 1, |b| scene_probe::render(b, false));
    replay("render_xml", 1, |b| scene_probe::render(b, false));
}

#[test]
fn render_json_inputs() {
    replay("scene_json", 1, |b| scene_probe::render(b, true));
    replay("render_json", 1, |b| scene_probe::render(b, true));
}

#[test]
fn scene_xml_inputs() {
    replay("scene_xml", 1, |b| scene_probe::scene(b, false));
}

#[test]
fn scene_json_inputs() {
    replay("scene_json", 1, |b| scene_probe::scene(b, true));
}

#[test]
fn ply_inputs() {
    replay("ply", 1, inputs_probe::ply);
}

#[test]
fn texture_image_inputs() {
    replay("texture_image", 1, inputs_probe::texture_image);
}

#[test]
fn bundle_inputs() {
    replay("bundle", 1, inputs_probe::bundle);
}

#[test]
fn tile_upload_inputs() {
    replay("tile_upload", 1, inputs_probe::tile_upload);
}

#[test]
fn pass_upload_inputs() {
    replay("pass_upload", 4, inputs_probe::pass_upload);
}
