//! Shared helpers for Tessera's end-to-end tests and the conformance runner.
//!
//! The course's scene corpus lives outside the repository in `../shared/scenes` (never copied
//! in); [`shared_scenes`] finds it.

pub mod anchors;
pub mod conformance;
pub mod envmaps;
pub mod perf_guard;

pub use tessera_testkit::{anchor_python, corpus_has, missing, repo_root, shared_bench, shared_scenes};

/// The scene files (`.xml`, `.json`) under `dir` and its subfolders, sorted; none when `dir`
/// cannot be read.
pub fn scene_files(dir: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    let mut dirs = vec![dir.to_path_buf()];
    while let Some(d) = dirs.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else { continue };
        for path in entries.flatten().map(|e| e.path()) {
            if path.is_dir() {
                dirs.push(path);
            } else if path.extension().is_some_and(|e| e == "xml" || e == "json") {
                out.push(path);
            }
        }
    }
    out.sort();
    out
}
