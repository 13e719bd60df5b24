//! Test-only helpers shared by the tests of every crate (a dev-dependency; it depends on no
//! Tessera crate, so `tessera-common`'s own unit tests can use it too).
//!
//! The course corpus (scenes, assets, official images) is read from `../shared/scenes` beside
//! the repository, or from `$TESSERA_SCENES`. A test that needs it and finds it missing skips,
//! saying so, unless `TESSERA_REQUIRE_SCENES` is set (`.ci/run` sets it): then it fails, so CI
//! can never pass by skipping the corpus tests.

use std::path::{Path, PathBuf};

/// The repository root.
pub fn repo_root() -> PathBuf {
    // This crate sits at tests/testkit.
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    here.parent().and_then(Path::parent).unwrap_or(here).to_path_buf()
}

/// The course corpus: `$TESSERA_SCENES`, or `../shared/scenes` beside the repository.
pub fn shared_scenes() -> PathBuf {
    match std::env::var_os("TESSERA_SCENES") {
        Some(p) if !p.is_empty() => PathBuf::from(p),
        _ => repo_root().join("../shared/scenes"),
    }
}

/// Whether `TESSERA_REQUIRE_SCENES` asks for the corpus (set, and neither empty nor `0`).
pub fn scenes_required() -> bool {
    std::env::var_os("TESSERA_REQUIRE_SCENES").is_some_and(|v| !v.is_empty() && v != "0")
}

/// Whether the corpus file or folder `path` is there. When it is not, the calling test should
/// skip: this prints why, or panics when `TESSERA_REQUIRE_SCENES` is set.
pub fn corpus_has(path: &Path) -> bool {
    if path.exists() {
        return true;
    }
    missing(&format!("{} is absent", path.display()));
    false
}

/// Reports a part of the corpus the calling test needs and did not find (see [`corpus_has`]).
pub fn missing(what: &str) {
    assert!(
        !scenes_required(),
        "TESSERA_REQUIRE_SCENES is set but {what}: put the course corpus in ../shared/scenes beside \
         the repository, or point TESSERA_SCENES at it (the corpus looked for: {})",
        shared_scenes().display()
    );
    eprintln!(
        "skipping: {what} (the course corpus is not checked out; TESSERA_REQUIRE_SCENES makes this a failure)"
    );
}
