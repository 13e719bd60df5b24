//! Scenes: parse into plain records first, then build the render scene.

pub mod records;
pub mod xml;
