//! Textures (HW4): decoded images ([`image`]) and texture maps with their decal modes ([`maps`]).
//! Images are decoded once per scene and shared by every map that names them.

pub mod image;
pub mod maps;
pub mod mip;
