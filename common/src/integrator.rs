//! The course's recursive ray tracer (scene-format.md §6, §16.2): ambient + Blinn-Phong from
//! point lights with shadow rays, then mirror, conductor and dielectric recursion bounded by
//! `MaxRecursionDepth`, with Beer's law inside dielectrics.

use glam::DVec3;

use crate::geometry::SurfaceHit;
use crate::material::{Material, MaterialKind, Refraction, fresnel_conductor, refract};
use crate::math::{Ray, orthonormal_pair, reflect};
use crate::sampler::SampleRng;
use crate::scene::Scene;

/// Rays traced, by kind, for throughput figures.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RayStats {
    pub primary: u64,
    pub shadow: u64,
    pub secondary: u64,
}

impl RayStats {
    pub fn total(&self) -> u64 {
        self.primary + self.shadow + self.secondary
    }

    pub fn add(&mut self, o: &RayStats) {
        self.primary += o.primary;
        self.shadow += o.shadow;
        self.secondary += o.secondary;
    }
}

/// Traces rays through one scene; one per render thread (it only holds counters).
pub struct Tracer<'a> {
    pub scene: &'a Scene,
    pub stats: RayStats,
}

impl<'a> Tracer<'a> {
    pub fn new(scene: &'a Scene) -> Self {
        Tracer { scene, stats: RayStats::default() }
    }

    /// Radiance along a camera ray.
    pub fn trace_primary(&mut self, ray: &Ray, rng: &mut SampleRng) -> DVec3 {
        self.stats.primary += 1;
        self.trace(ray, 0, None, rng)
    }

    /// Radiance arriving along `ray`. `medium` is the absorption coefficient of the dielectric
    /// the ray travels inside, if any (Beer's law applies over the segment's length).
    fn trace(&mut self, ray: &Ray, depth: u32, medium: Option<DVec3>, rng: &mut SampleRng) -> DVec3 {
        let scene = self.scene;
        let Some(hit) = scene.accel.intersect(ray, scene.intersection_test_epsilon, f64::INFINITY) else {
            return scene.background;
        };
        let l = self.shade(ray, &hit, depth, medium.is_some(), rng);
        match medium {
            Some(c) if c != DVec3::ZERO => l * (-c * hit.t).exp(),
            _ => l,
        }
    }

    fn shade(&mut self, ray: &Ray, hit: &SurfaceHit, depth: u32, inside: bool, rng: &mut SampleRng) -> DVec3 {
        let scene = self.scene;
        let mat = &scene.materials[hit.material as usize];
        let d = ray.dir;
        let entering = d.dot(hit.geo_normal) < 0.0;
        // Shading normal facing the incoming ray.
        let n = if entering { hit.shading_normal } else { -hit.shading_normal };
        let eps = scene.shadow_ray_epsilon;
        let can_recurse = depth < scene.max_recursion_depth;

        // Local shading; skipped for hits seen from inside a dielectric (§6.4, §15 #20).
        let mut l = if mat.kind == MaterialKind::Dielectric && inside {
            DVec3::ZERO
        } else {
            self.direct(hit.point, n, -d, mat)
        };

        match mat.kind {
            MaterialKind::Plain => {}
            MaterialKind::Mirror | MaterialKind::Conductor if can_recurse => {
                let weight = if mat.kind == MaterialKind::Conductor {
                    mat.mirror * fresnel_conductor(-d.dot(n), mat.refraction_index, mat.absorption_index)
                } else {
                    mat.mirror
                };
                if weight != DVec3::ZERO {
                    let r = glossy(reflect(d, n), mat.roughness, rng);
                    self.stats.secondary += 1;
                    l += weight * self.trace(&Ray::new(hit.point + eps * n, r), depth + 1, None, rng);
                }
            }
            MaterialKind::Dielectric if can_recurse => {
                let eta = mat.refraction_index;
                let (n1, n2) = if entering { (1.0, eta) } else { (eta, 1.0) };
                // The reflected ray stays on the incoming side; the refracted one crosses.
                let (refl_medium, refr_medium) =
                    if entering { (None, Some(mat.absorption)) } else { (Some(mat.absorption), None) };
                let reflected = Ray::new(hit.point + eps * n, reflect(d, n));
                match refract(d, n, n1, n2) {
                    Refraction::Total => {
                        self.stats.secondary += 1;
                        l += self.trace(&reflected, depth + 1, refl_medium, rng);
                    }
                    Refraction::Split { fr, dir } => {
                        self.stats.secondary += 2;
                        l += fr * self.trace(&reflected, depth + 1, refl_medium, rng);
                        l += (1.0 - fr)
                            * self.trace(&Ray::new(hit.point - eps * n, dir), depth + 1, refr_medium, rng);
                    }
                }
            }
            _ => {}
        }
        l
    }

    /// Ambient plus Blinn-Phong from every point light, with shadow rays (§6.2, §6.3).
    fn direct(&mut self, x: DVec3, n: DVec3, wo: DVec3, mat: &Material) -> DVec3 {
        let scene = self.scene;
        let mut l = mat.ambient * scene.ambient_light;
        if mat.diffuse == DVec3::ZERO && mat.specular == DVec3::ZERO {
            return l;
        }
        let origin = x + scene.shadow_ray_epsilon * n;
        for light in &scene.point_lights {
            let to_light = light.position - x;
            let dist2 = to_light.length_squared();
            let wi = to_light / dist2.sqrt();
            let cos = n.dot(wi);
            if cos <= 0.0 {
                continue;
            }
            self.stats.shadow += 1;
            let to_light_from_origin = light.position - origin;
            let shadow_len = to_light_from_origin.length();
            let shadow = Ray::new(origin, to_light_from_origin / shadow_len);
            if scene.accel.occluded(&shadow, scene.intersection_test_epsilon, shadow_len) {
                continue;
            }
            let e = light.intensity / dist2;
            let h = (wi + wo).normalize();
            let spec = n.dot(h).max(0.0).powf(mat.phong_exponent);
            l += (mat.diffuse * cos + mat.specular * spec) * e;
        }
        l
    }
}

/// Glossy perturbation of a reflection direction (§6.7); identity for roughness 0.
fn glossy(r: DVec3, roughness: f64, rng: &mut SampleRng) -> DVec3 {
    if roughness <= 0.0 {
        return r;
    }
    let (u, v) = orthonormal_pair(r);
    let a = rng.next_f64() - 0.5;
    let b = rng.next_f64() - 0.5;
    (r + roughness * (a * u + b * v)).normalize()
}
