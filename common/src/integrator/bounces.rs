//! How a path leaves a surface, one path at a time: a BRDF bounce's direction and weight, the
//! glossy perturbation of a mirror direction, and a mirror's or conductor's choice between its
//! mirror lobe and its BRDF. The tracer's paths (`trace_path`) and the path lanes' specular
//! vertices both take them from here, so the two compute the same bits.

use glam::DVec3;

use super::direct::BounceDensity;
use crate::material::{Material, MaterialKind, fresnel_conductor};
use crate::math::{orthonormal_pair, sincos_turns};
use crate::sampler::Sampler;

/// A mirror's or conductor's mirror-lobe weight for a ray of direction `d` arriving at normal
/// `n`, and the probability with which a path takes that lobe rather than the material's BRDF:
/// each by its largest channel (the chosen one's weight is then divided by its probability).
pub(super) fn mirror_choice(mat: &Material, d: DVec3, n: DVec3) -> (DVec3, f64) {
    let weight = if mat.kind == MaterialKind::Conductor {
        mat.mirror * fresnel_conductor(-d.dot(n), mat.refraction_index, mat.absorption_index)
    } else {
        mat.mirror
    };
    let w_spec = weight.max_element();
    let w_brdf = (mat.diffuse + mat.specular).max_element();
    (weight, if w_brdf > 0.0 { w_spec / (w_spec + w_brdf) } else { 1.0 })
}

/// One bounce direction at a diffuse or glossy vertex: uniform in the hemisphere of `n`
/// (pdf 1/2π) or cosine-distributed (pdf cos θ/π), the throughput factor
/// `f(wi, wo)·cos θ / pdf` and the BRDF value `f(wi, wo)`. `None` when the material
/// reflects nothing that way.
pub(super) fn brdf_bounce(
    n: DVec3,
    wo: DVec3,
    mat: &Material,
    importance: bool,
    rng: &mut Sampler,
) -> Option<(DVec3, DVec3, DVec3)> {
    let (u1, u2) = rng.next_2d();
    let (t, b) = orthonormal_pair(n);
    let (cos_t, pdf_over_cos) = if importance {
        let c = (1.0 - u1).sqrt();
        (c, 1.0 / std::f64::consts::PI)
    } else {
        (u1, 0.0)
    };
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    let (sp, cp) = sincos_turns(u2);
    let wi = (sin_t * cp) * t + (sin_t * sp) * b + cos_t * n;
    if cos_t <= 0.0 {
        return None;
    }
    let pdf = if importance { cos_t * pdf_over_cos } else { 1.0 / std::f64::consts::TAU };
    let f_cos = mat.reflectance(n, wi, wo);
    let f = f_cos / pdf;
    (f != DVec3::ZERO && f.is_finite()).then_some((wi, f, f_cos / cos_t))
}

/// The solid-angle density of a BRDF bounce towards `wi` at normal `n` (see [`BounceDensity`]).
pub(super) fn density(cosine: bool, n: DVec3, wi: DVec3) -> f64 {
    BounceDensity { cosine, chance: 1.0 }.pdf(n, wi)
}

/// Glossy perturbation of a reflection direction (§6.7); identity for roughness 0.
pub(super) fn glossy(r: DVec3, roughness: f64, rng: &mut Sampler) -> DVec3 {
    if roughness <= 0.0 {
        return r;
    }
    let (u, v) = orthonormal_pair(r);
    let (a, b) = rng.next_2d();
    let (a, b) = (a - 0.5, b - 0.5);
    (r + roughness * (a * u + b * v)).normalize()
}
