//! The build's context: the records, the resolver and the cache every step reads, its
//! messages, and the transformations (§10) that place objects, cameras and lights.

use std::collections::HashMap;

use glam::{DAffine3, DMat3, DMat4, DVec3};

use crate::assets::AssetResolver;
use crate::error::{Loc, SceneError, Warning};
use crate::math::{Transform, v3};
use crate::scene::cache::MeshCache;
use crate::scene::records::*;
use crate::scene::tree::json_words;

/// The exponent that linearises `degamma="true"` materials and texture maps (§6.6): the `Gamma`
/// of the first camera's first `<Tonemap>` when it is a number, else 2.2 (also for `sRGB`, whose
/// curve 2.2 approximates).
pub(super) fn degamma_exponent(rec: &SceneRecords) -> f64 {
    rec.cameras
        .iter()
        .find_map(|c| c.tonemaps.first())
        .and_then(|t| match t.params.gamma {
            crate::tonemap::params::Gamma::Power(g) => Some(g),
            crate::tonemap::params::Gamma::Srgb => None,
        })
        .unwrap_or(2.2)
}

/// The warning about `n` of an object's `total` triangles that lie beyond
/// [`MAX_COORDINATE`](crate::geometry::mesh::MAX_COORDINATE) and are left out of the picture:
/// in the mesh's own coordinates, or `carried` there by the object's transformations.
pub(super) fn unplaced_message(n: usize, total: usize, carried: bool) -> String {
    let limit = crate::geometry::mesh::MAX_COORDINATE;
    let (which, what) = if carried {
        ("its transformations carry", "scale them (or the whole scene) down")
    } else {
        ("its vertex data puts", "scale the vertex data down")
    };
    let (count, left) = if total == 1 {
        ("its triangle".to_string(), "it is left out and will not be seen")
    } else {
        (format!("{n} of its {total} triangles"), "they are left out and will not be seen")
    };
    format!(
        "{which} {count} beyond ±{limit:e}, farther from the origin than the single-precision ray \
         tests can place: {left}; {what}"
    )
}

pub(super) struct Ctx<'a> {
    pub(super) rec: &'a SceneRecords,
    pub(super) resolver: &'a dyn AssetResolver,
    /// Meshes and images kept across builds ([`build_scene_cached`]).
    pub(super) cache: Option<&'a MeshCache>,
}

impl Ctx<'_> {
    /// An error about the scene, in the words of its dialect.
    pub(super) fn err(&self, loc: &Loc, msg: impl Into<String>) -> SceneError {
        let msg = msg.into();
        let msg = if self.rec.json { json_words(&msg) } else { msg };
        SceneError::new(&self.rec.source, loc.clone(), msg)
    }

    /// The one way every step reports a warning about the scene: at `loc` of the scene file.
    /// ([`build_scene`] puts them all in the words of the scene's dialect at the end.)
    pub(super) fn warn(&self, warnings: &mut Vec<Warning>, loc: &Loc, message: impl Into<String>) {
        warnings.push(Warning::new(&self.rec.source, loc.clone(), message));
    }

    pub(super) fn material(&self, ids: &HashMap<&str, u32>, id: &str, loc: &Loc) -> Result<u32, SceneError> {
        ids.get(id).copied().ok_or_else(|| {
            self.err(loc, format!("material \"{id}\" is not defined; add <Material id=\"{id}\"> under <Materials> or use an existing id"))
        })
    }

    pub(super) fn vertex(&self, id: i64, loc: &Loc, what: &str) -> Result<u32, SceneError> {
        let n = self.rec.vertices.len();
        if id >= 1 && (id as u64) <= n as u64 {
            Ok((id - 1) as u32)
        } else {
            Err(self.err(
                loc,
                format!("{what} refers to vertex {id}, but <VertexData> has {n} vertices (ids start at 1)"),
            ))
        }
    }

    pub(super) fn transform(
        &self,
        table: &HashMap<(char, &str), TransformOp>,
        refs: &[TransformRef],
        loc: &Loc,
    ) -> Result<DAffine3, SceneError> {
        let mut m = DAffine3::IDENTITY;
        for r in refs {
            let op = table.get(&(r.letter, r.id.as_str())).ok_or_else(|| {
                let kind = match r.letter {
                    't' => "Translation",
                    's' => "Scaling",
                    'r' => "Rotation",
                    _ => "Composite",
                };
                self.err(loc, format!("transformation \"{}{}\" is not defined; add <{kind} id=\"{}\"> under <Transformations>", r.letter, r.id, r.id))
            })?;
            // Tokens apply left to right: M = Xn ··· X2 · X1.
            m = op_matrix(op) * m;
        }
        Ok(m)
    }

    pub(super) fn make_transform(&self, m: DAffine3, loc: &Loc) -> Result<Option<Transform>, SceneError> {
        if m == DAffine3::IDENTITY {
            return Ok(None);
        }
        Transform::new(m).map(Some).ok_or_else(|| {
            self.err(loc, "the transformation is singular (a zero scale?); the object would be flat: use non-zero Scaling factors")
        })
    }

    /// Where a camera's or light's `Transformations` put it (§10.4): the same composite matrix
    /// as an object's, `None` when there are none, so untransformed scenes keep their exact
    /// numbers. A singular matrix is refused: it would squash a viewing or lighting direction
    /// to nothing or, for an area light, leave its normal undefined.
    pub(super) fn placement(
        &self,
        table: &HashMap<(char, &str), TransformOp>,
        refs: &[TransformRef],
        loc: &Loc,
    ) -> Result<Option<Transform>, SceneError> {
        if refs.is_empty() {
            return Ok(None);
        }
        let m = self.transform(table, refs, loc)?;
        Transform::new(m).map(Some).ok_or_else(|| {
            self.err(loc, "the transformation is singular (a zero scale?); it would flatten the directions of this camera or light: use non-zero Scaling factors")
        })
    }
}

/// A position (camera or light Position) under an optional placement: moved as a point (w = 1).
pub(super) fn placed_point(placement: Option<&Transform>, p: Vec3) -> DVec3 {
    placement.map_or(v3(p), |t| t.to_world.transform_point3(v3(p)))
}

/// A direction (Gaze, Up, light Direction) under an optional placement: only the linear part
/// acts (w = 0). Its length is not kept; every user normalises it.
pub(super) fn placed_vector(placement: Option<&Transform>, d: Vec3) -> DVec3 {
    placement.map_or(v3(d), |t| t.to_world.transform_vector3(v3(d)))
}

/// An area light's normal under an optional placement: by the inverse transpose, like a
/// surface normal (§10.3), so that it stays perpendicular to the square's plane under
/// non-uniform scaling.
pub(super) fn placed_normal(placement: Option<&Transform>, n: Vec3) -> DVec3 {
    placement.map_or(v3(n), |t| t.normal_to_world(v3(n)))
}

/// The matrix of one transformation element (§10.1).
pub fn op_matrix(op: &TransformOp) -> DAffine3 {
    match *op {
        TransformOp::Translation(t) => DAffine3::from_translation(v3(t)),
        TransformOp::Scaling(s) => DAffine3::from_scale(v3(s)),
        TransformOp::Rotation { degrees, axis } => {
            let a = v3(axis);
            if a.length_squared() == 0.0 {
                DAffine3::IDENTITY
            } else {
                DAffine3::from_axis_angle(a.normalize(), degrees.to_radians())
            }
        }
        TransformOp::Composite(m) => {
            // Row-major in the file; glam reads column-major.
            let mat = DMat4::from_cols_array(&m).transpose();
            DAffine3 { matrix3: DMat3::from_mat4(mat), translation: mat.w_axis.truncate() }
        }
    }
}
