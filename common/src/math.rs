//! Small geometric helpers shared by the tracer: rays, affine transforms, orthonormal bases.
//!
//! Shading and hit points are computed in `f64` (the course scenes span scales from 0.1 to 1e3,
//! and the instructor recommends double precision against speckles); BVH traversal runs in `f32`
//! and every accepted closest hit is re-intersected in `f64`.

use glam::{DAffine3, DMat3, DVec3};

/// A ray in world or object space. `dir` is unit length in world space; in object space it is
/// the transformed (not renormalised) direction, so `t` is the same in both spaces.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub origin: DVec3,
    pub dir: DVec3,
    /// Time within the exposure, in [0, 1): where moving objects are (motion blur). Every ray
    /// spawned from a camera sample carries that sample's time.
    pub time: f64,
}

impl Ray {
    /// A ray at time 0.
    #[inline]
    pub fn new(origin: DVec3, dir: DVec3) -> Self {
        Ray { origin, dir, time: 0.0 }
    }

    /// A secondary ray (shadow, reflection, refraction) at the same time as `self`.
    #[inline]
    pub fn spawn(&self, origin: DVec3, dir: DVec3) -> Self {
        Ray { origin, dir, time: self.time }
    }

    #[inline]
    pub fn at(&self, t: f64) -> DVec3 {
        self.origin + self.dir * t
    }
}

/// An object-to-world transform with what intersection and shading need precomputed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transform {
    pub to_world: DAffine3,
    pub to_object: DAffine3,
    /// Inverse transpose of the linear part: maps object-space normals to world space.
    pub normal_matrix: DMat3,
}

/// The scale factor of a similarity (rotations, reflections and one uniform scale): `Some(s)`
/// when `m`'s columns are orthogonal and of one length `s` (to a relative 1e-9), else `None`.
/// A sphere under such a matrix is still a sphere, of radius `s·r`.
pub fn uniform_scale(m: &DMat3) -> Option<f64> {
    let g = m.transpose() * *m;
    let s2 = g.x_axis.x;
    let off = g.x_axis.y.abs() + g.x_axis.z.abs() + g.y_axis.z.abs();
    let uniform = s2 > 0.0
        && s2.is_finite()
        && (g.y_axis.y - s2).abs() <= 1e-9 * s2
        && (g.z_axis.z - s2).abs() <= 1e-9 * s2
        && off <= 1e-9 * s2;
    uniform.then(|| s2.sqrt())
}

impl Transform {
    /// `None` when the matrix is singular (a zero scale): the caller reports that as an error.
    pub fn new(to_world: DAffine3) -> Option<Self> {
        let det = to_world.matrix3.determinant();
        if !det.is_finite() || det.abs() < 1e-300 {
            return None;
        }
        let to_object = to_world.inverse();
        let normal_matrix = to_world.matrix3.inverse().transpose();
        Some(Transform { to_world, to_object, normal_matrix })
    }

    #[inline]
    pub fn ray_to_object(&self, ray: &Ray) -> Ray {
        Ray {
            origin: self.to_object.transform_point3(ray.origin),
            dir: self.to_object.transform_vector3(ray.dir),
            time: ray.time,
        }
    }

    #[inline]
    pub fn normal_to_world(&self, n: DVec3) -> DVec3 {
        (self.normal_matrix * n).normalize()
    }
}

/// Mirror direction of `d` about the unit normal `n`.
#[inline]
pub fn reflect(d: DVec3, n: DVec3) -> DVec3 {
    d - 2.0 * d.dot(n) * n
}

/// Two unit vectors orthogonal to the unit vector `n` and to each other, built the course's way
/// (scene-format.md §6.7): replace the smallest-magnitude component of `n` by 1, cross.
pub fn orthonormal_pair(n: DVec3) -> (DVec3, DVec3) {
    let a = n.abs();
    let mut r = n;
    if a.x <= a.y && a.x <= a.z {
        r.x = 1.0;
    } else if a.y <= a.z {
        r.y = 1.0;
    } else {
        r.z = 1.0;
    }
    let u = r.cross(n).normalize();
    let v = n.cross(u);
    (u, v)
}

/// Converts a `[f64; 3]` record value into a vector.
#[inline]
pub fn v3(a: [f64; 3]) -> DVec3 {
    DVec3::from_array(a)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orthonormal_pair_is_orthonormal() {
        for n in [
            DVec3::X,
            DVec3::Y,
            DVec3::Z,
            DVec3::new(1.0, 2.0, -3.0).normalize(),
            DVec3::new(-0.3, 0.0, 0.9).normalize(),
        ] {
            let (u, v) = orthonormal_pair(n);
            assert!((u.length() - 1.0).abs() < 1e-12 && (v.length() - 1.0).abs() < 1e-12);
            assert!(u.dot(n).abs() < 1e-12 && v.dot(n).abs() < 1e-12 && u.dot(v).abs() < 1e-12);
        }
    }

    #[test]
    fn uniform_scale_recognises_similarities_only() {
        let rot = DMat3::from_axis_angle(DVec3::new(1.0, 2.0, 3.0).normalize(), 0.7);
        assert!(
            (uniform_scale(&(rot * DMat3::from_diagonal(DVec3::splat(3.0)))).unwrap() - 3.0).abs() < 1e-12
        );
        assert!(
            (uniform_scale(&DMat3::from_diagonal(DVec3::new(-0.5, 0.5, 0.5))).unwrap() - 0.5).abs() < 1e-12
        );
        assert_eq!(uniform_scale(&(rot * DMat3::from_diagonal(DVec3::new(1.0, 1.0, 1.001)))), None);
        assert_eq!(
            uniform_scale(&DMat3::from_cols(DVec3::X, DVec3::new(0.1, 1.0, 0.0), DVec3::Z)),
            None,
            "shear"
        );
        assert_eq!(uniform_scale(&DMat3::ZERO), None);
    }

    #[test]
    fn normal_matrix_keeps_normals_perpendicular_under_nonuniform_scale() {
        let t = Transform::new(DAffine3::from_scale(DVec3::new(2.0, 0.5, -1.0))).unwrap();
        // A plane with normal (1,1,0)/√2 contains the tangent (1,-1,0).
        let n = DVec3::new(1.0, 1.0, 0.0).normalize();
        let tangent = t.to_world.transform_vector3(DVec3::new(1.0, -1.0, 0.0));
        assert!(t.normal_to_world(n).dot(tangent).abs() < 1e-12);
        assert!(Transform::new(DAffine3::from_scale(DVec3::new(1.0, 0.0, 1.0))).is_none());
    }
}
