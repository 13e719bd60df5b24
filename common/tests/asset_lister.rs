//! `SceneRecords::asset_paths` (the files a scene names, listed from its records alone) against
//! what a full load reads: for every scene of the course corpus, the scene is built through a
//! `RecordingResolver` around `FsResolver`, and the paths the build asked for (each once, in
//! order) are exactly the listed ones; `FsResolver::locate` finds each where the build read it.
//! A scene that fails to load (the corpus has scenes whose assets are missing everywhere) has
//! read a part of the list, and its error names a listed path that `locate` does not find.
//!
//! The build runs on a one-thread rayon pool, so the order of its parallel reads (images, PLY
//! files) is the sequential one.

use std::path::{Path, PathBuf};

use tessera::assets::{FsResolver, RecordingResolver};
use tessera::scene::build::build_scene;
use tessera::scene::load::parse_scene;
use tessera_testkit::scene_files;

/// What happened to one scene.
enum Outcome {
    Loaded,
    FailedOnMissing,
    NotParsed,
}

fn check(scene: &Path) -> Outcome {
    let Ok(text) = std::fs::read_to_string(scene) else { return Outcome::NotParsed };
    let Ok(records) = parse_scene(&text, scene) else { return Outcome::NotParsed };
    let listed: Vec<String> = records.asset_paths().into_iter().map(|a| a.path).collect();
    let fs = FsResolver::for_scene(scene);
    let recorder = RecordingResolver::new(fs.clone());
    let built = build_scene(&records, &recorder);
    let mut read: Vec<String> = Vec::new();
    for s in recorder.served() {
        assert_eq!(fs.locate(&s.requested), Some(s.found_at.clone()), "{}: {}", scene.display(), s.requested);
        if !read.contains(&s.requested) {
            read.push(s.requested);
        }
    }
    match built {
        Ok(_) => {
            assert_eq!(listed, read, "{}: listed vs read by the build", scene.display());
            Outcome::Loaded
        }
        Err(e) => {
            let e = e.to_string();
            for r in &read {
                assert!(listed.contains(r), "{}: read {r}, not listed in {listed:?}", scene.display());
            }
            assert!(
                e.contains("cannot read"),
                "{}: fails for another reason than a missing file: {e}",
                scene.display()
            );
            let missing: Vec<&String> = listed.iter().filter(|p| fs.locate(p).is_none()).collect();
            assert!(
                missing.iter().any(|p| e.contains(p.as_str())),
                "{}: the error names no listed path that cannot be found ({missing:?}): {e}",
                scene.display()
            );
            Outcome::FailedOnMissing
        }
    }
}

#[test]
fn listed_assets_are_exactly_what_a_full_load_reads_for_the_whole_corpus() {
    let corpus = tessera_testkit::shared_scenes();
    if !tessera_testkit::corpus_has(&corpus.join("xml")) {
        return;
    }
    let mut scenes: Vec<PathBuf> = Vec::new();
    for dir in ["xml", "json"] {
        scenes.extend(scene_files(&corpus.join(dir)));
    }
    // A sequence's frames name the same files: its first, middle and last frames are loaded
    // in full, and every frame's list is located.
    for seq in scene_files(&corpus.join("sequences")).chunk_by(|a, b| a.parent() == b.parent()) {
        for s in seq {
            let text = std::fs::read_to_string(s).unwrap();
            let records = parse_scene(&text, s).unwrap_or_else(|e| panic!("{e}"));
            let fs = FsResolver::for_scene(s);
            for a in records.asset_paths() {
                assert!(fs.locate(&a.path).is_some(), "{}: {} not found", s.display(), a.path);
            }
        }
        scenes.extend([&seq[0], &seq[seq.len() / 2], &seq[seq.len() - 1]].map(|p| p.to_path_buf()));
    }
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let (mut loaded, mut failed, mut unparsed) = (0, 0, 0);
    pool.install(|| {
        for s in &scenes {
            match check(s) {
                Outcome::Loaded => loaded += 1,
                Outcome::FailedOnMissing => failed += 1,
                Outcome::NotParsed => unparsed += 1,
            }
        }
    });
    eprintln!("{loaded} scenes loaded, {failed} refused for a missing file, {unparsed} not parsed");
    assert!(loaded >= 130, "{loaded} scenes loaded of {}", scenes.len());
}
