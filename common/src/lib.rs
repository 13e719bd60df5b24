//! Tessera's tracer core.
//!
//! Pure computation: scene bytes and an [`assets::AssetResolver`] in, linear float images out.
//! No network, no async runtime, no database: the worker and the server bring those.
//!
//! Pipeline: a front end ([`scene::xml`] or [`scene::json`], both building a [`scene::tree`]
//! that [`scene::elements`] walks)
//! parses a file into [`scene::records`] (plain data with source locations), [`scene::build`]
//! turns records into a render-ready [`scene::Scene`] (meshes, BVHs, instances, materials,
//! lights), [`scene::load`] does both for scene text or a file, [`bundle`] for a farm job's tar
//! bundle, and [`render`] traces tiles of it with [`integrator`].
//!
//! The modules are layered one way, each importing only lower layers (docs/ARCHITECTURE.md,
//! "Layers"; checked by `tests/layers.rs`).

pub mod assets;
pub mod atomic_write;
pub mod bundle;
pub mod camera;
pub mod error;
pub mod geometry;
pub mod hdr_io;
pub mod image;
pub mod integrator;
pub mod lights;
pub mod material;
pub mod math;
pub mod output;
pub mod passes;
pub mod ply;
pub mod protocol;
pub mod render;
pub mod sampler;
pub mod scene;
pub mod texture;
pub mod tonemap;

pub use error::{Loc, SceneError, Warning};
