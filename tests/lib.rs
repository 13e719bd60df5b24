//! Shared helpers for Tessera's end-to-end tests and the conformance runner.
//!
//! The course's scene corpus lives outside the repository in `../shared/scenes` (never copied
//! in); [`shared_scenes`] finds it.

pub mod anchors;
pub mod conformance;
pub mod envmaps;
pub mod perf_guard;

pub use tessera_testkit::{
    anchor_python, corpus_has, missing, repo_root, scene_files, shared_bench, shared_scenes,
};
