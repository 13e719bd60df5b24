//! The scene's placed objects as the geometry sees them: an [`Instance`] is a [`Shape`] (a mesh
//! by index, a sphere or an infinite plane) with its material, transform, motion and texture
//! maps, and carries rays into its object space.

use glam::DVec3;

use crate::math::{Ray, Transform};

/// What an instance is made of.
#[derive(Clone, Debug)]
pub enum Shape {
    /// Index into [`Accel::meshes`](super::Accel::meshes).
    Mesh { mesh: u32, smooth: bool },
    /// Object-space sphere (an ellipsoid once transformed).
    Sphere { center: DVec3, radius: f64 },
    /// Infinite object-space plane through `point` with unit `normal` (2025 scenes, §9.8).
    /// Unbounded, so it never enters the top-level BVH: [`Accel`](super::Accel) tests planes one by one.
    Plane { point: DVec3, normal: DVec3 },
}

/// One placed object of the scene.
#[derive(Clone, Debug)]
pub struct Instance {
    pub shape: Shape,
    pub material: u32,
    /// `None` means object space is world space (saves two matrix products per ray).
    pub transform: Option<Transform>,
    /// Motion blur: the object is translated by `time * motion` in world space after its
    /// transform (scene-format.md §10.5).
    pub motion: Option<DVec3>,
    /// Texture maps applied to this object (indices into the scene's texture maps).
    pub textures: ObjectTextures,
}

/// The texture maps of an object (§11.1): those that change its coefficients (wood_box pairs a
/// replace_kd map with a replace_ks map), applied in order — the first two here, any further
/// ones in the scene's `more_colour_maps` list `more_colour` — and the one that changes its
/// normal (the last such map the object names).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ObjectTextures {
    pub colour: [Option<u32>; 2],
    pub more_colour: Option<u32>,
    pub normal: Option<u32>,
}

impl Instance {
    /// Object space is world space at every time (no transform, no motion).
    #[inline]
    pub(super) fn is_world_space(&self) -> bool {
        self.transform.is_none() && self.motion.is_none()
    }

    /// A world-space point of this instance at `time`, in its object space: before its
    /// transformation and motion (for a MeshInstance, its base mesh's vertex space). Solid
    /// textures are evaluated there (scene-format.md §11.10).
    #[inline]
    pub fn object_point(&self, p: DVec3, time: f64) -> DVec3 {
        let p = match self.motion {
            Some(v) => p - time * v,
            None => p,
        };
        match &self.transform {
            Some(xf) => xf.to_object.transform_point3(p),
            None => p,
        }
    }

    /// [`Self::local_ray`] without a copy for an instance whose object space is world space:
    /// `ray` itself then, else the carried ray, kept in `slot`.
    #[inline(always)]
    pub(super) fn ray_here<'r>(&self, ray: &'r Ray, slot: &'r mut Option<Ray>) -> &'r Ray {
        if self.is_world_space() { ray } else { slot.insert(self.local_ray(ray)) }
    }

    /// The ray in this instance's object space at the ray's time.
    #[inline]
    pub(super) fn local_ray(&self, ray: &Ray) -> Ray {
        let moved;
        let r = match self.motion {
            Some(v) => {
                moved = Ray { origin: ray.origin - ray.time * v, ..*ray };
                &moved
            }
            None => ray,
        };
        match &self.transform {
            Some(xf) => xf.ray_to_object(r),
            None => *r,
        }
    }
}
