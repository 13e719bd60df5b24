//! Shared helpers for Tessera's end-to-end tests and the conformance runner.
//!
//! The course's scene corpus lives outside the repository in `../shared/scenes` (never copied
//! in); [`shared_scenes`] finds it.

pub mod conformance;
pub mod envmaps;

use std::path::PathBuf;

/// The repository root (the workspace directory).
pub fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).parent().map(PathBuf::from).unwrap_or_default()
}

pub use tessera_testkit::{corpus_has, missing, shared_scenes};
