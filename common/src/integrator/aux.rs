//! What a denoiser reads beside the colour (Intel Open Image Denoise's `RT` filter): for each
//! camera sample, the albedo and the world-space normal of the first surface the ray meets that
//! is not a perfect mirror or perfect glass. Through those the ray goes on (a mirror's reflected
//! direction, glass's refracted one, or its reflection under total internal reflection), so a
//! denoiser sees the reflected or refracted scene's edges rather than a flat mirror.
//!
//! These are features, not light: no random numbers are drawn and no counter moves, so asking
//! for them changes no bit of the colour.

use glam::DVec3;

use super::Tracer;
use crate::geometry::SurfaceHit;
use crate::material::{MaterialKind, Refraction, refract};
use crate::math::{Ray, reflect};

/// One camera sample's features.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Aux {
    /// Reflectance in [0, 1] per channel: a material's diffuse plus specular colour after its
    /// texture maps; for an object light seen from its front, its radiance clamped to [0, 1];
    /// for a ray that leaves the scene, what it sees (environment or background) clamped.
    pub albedo: DVec3,
    /// The shading normal (after normal and bump maps) turned towards the ray; zero for a ray
    /// that leaves the scene.
    pub normal: DVec3,
}

/// How many perfect mirrors and glass surfaces a feature ray passes through before it takes
/// what it finds: a hall of mirrors must not cost without bound.
pub const AUX_CHAIN_LIMIT: u32 = 8;

fn clamp01(v: DVec3) -> DVec3 {
    // NaN (a degenerate texel) becomes 0, like the film's.
    let f = |x: f64| if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
    DVec3::new(f(v.x), f(v.y), f(v.z))
}

impl Tracer<'_> {
    /// The features of camera ray `ray`, whose first surface is `hit` (as
    /// [`Self::camera_hits`] found it).
    pub fn aux(&self, ray: &Ray, hit: Option<SurfaceHit>) -> Aux {
        let scene = self.scene;
        let eps = scene.shadow_ray_epsilon;
        let (mut ray, mut hit) = (*ray, hit);
        let mut travelled = 0.0;
        for depth in 0..=AUX_CHAIN_LIMIT {
            let Some(h) = hit else {
                let seen = match &scene.env_light {
                    Some(env) => env.radiance(ray.dir),
                    None => self.background,
                };
                return Aux { albedo: clamp01(seen), normal: DVec3::ZERO };
            };
            travelled += h.t;
            let mut slot = None;
            let s = match self.begin_shade(&ray, &h, self.spread * travelled, &mut slot) {
                Ok(s) => s,
                // A `replace_all` texel is the surface's colour as it is shown.
                Err(texel) => {
                    let n = if ray.dir.dot(h.shading_normal) < 0.0 {
                        h.shading_normal
                    } else {
                        -h.shading_normal
                    };
                    return Aux { albedo: clamp01(texel), normal: n };
                }
            };
            let n = s.facing();
            if s.emitted != DVec3::ZERO {
                return Aux { albedo: clamp01(s.emitted), normal: n };
            }
            let mat = s.mat;
            let smooth = mat.roughness == 0.0;
            let next = match mat.kind {
                MaterialKind::Dielectric if smooth => {
                    let (n1, n2) =
                        if s.entering { (1.0, mat.refraction_index) } else { (mat.refraction_index, 1.0) };
                    Some(match refract(ray.dir, n, n1, n2) {
                        Refraction::Total => ray.spawn(h.point + eps * n, reflect(ray.dir, n)),
                        Refraction::Split { dir, .. } => ray.spawn(h.point - eps * n, dir),
                    })
                }
                MaterialKind::Mirror | MaterialKind::Conductor
                    if smooth && mat.diffuse == DVec3::ZERO && mat.specular == DVec3::ZERO =>
                {
                    Some(ray.spawn(h.point + eps * s.shading_normal, reflect(ray.dir, n)))
                }
                _ => None,
            };
            match next {
                Some(r) if depth < AUX_CHAIN_LIMIT => {
                    ray = r;
                    hit = self.closest(&ray, depth + 1);
                }
                _ => {
                    let albedo = match mat.kind {
                        // Glass and mirrors that stop the chain (rough, or at its end) reflect
                        // what they see: white, or the mirror's colour.
                        MaterialKind::Dielectric => DVec3::ONE,
                        MaterialKind::Mirror | MaterialKind::Conductor => {
                            mat.diffuse + mat.specular + mat.mirror
                        }
                        MaterialKind::Plain => mat.diffuse + mat.specular,
                    };
                    return Aux { albedo: clamp01(albedo), normal: n };
                }
            }
        }
        unreachable!("the loop returns at its last step")
    }
}
