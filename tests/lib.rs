//! Shared helpers for Tessera's end-to-end tests and the conformance runner.
//!
//! The course's scene corpus lives outside the repository in `../shared/scenes` (never copied
//! in); [`shared_scenes`] finds it.

pub mod conformance;
pub mod envmaps;

pub use tessera_testkit::{anchor_python, corpus_has, missing, repo_root, shared_bench, shared_scenes};
