//! How a path leaves a surface, one path at a time ([`scatter`]): a BRDF bounce's direction
//! and weight, a mirror's or conductor's choice between its mirror lobe and its BRDF, a
//! dielectric's choice between reflection and refraction, the glossy perturbation of a mirror
//! direction. The tracer's paths (`trace_path`) and the path lanes' specular vertices both
//! take them from here, so the two compute the same bits.

use glam::DVec3;

use super::direct::BounceDensity;
use crate::material::{Material, MaterialKind, Refraction, fresnel_conductor, refract};
use crate::math::{orthonormal_pair, reflect, sincos_turns};
use crate::sampler::Sampler;
use crate::scene::DielectricSides;

/// Where a path arrives at a surface.
pub(super) struct Arrival {
    /// The point, and the shading normal on the side the path arrives from.
    pub x: DVec3,
    pub n: DVec3,
    /// The shading normal as given (a mirror's reflected ray starts on its side, §6.8).
    pub shading_normal: DVec3,
    /// The path's direction, and whether it arrives on the geometry's front side.
    pub d: DVec3,
    pub front: bool,
    /// Whether the path is inside a dielectric.
    pub inside: bool,
}

/// Where a path goes from a vertex ([`scatter`]).
pub(super) struct Scattered {
    pub origin: DVec3,
    pub dir: DVec3,
    /// What the throughput is multiplied by (`None`: nothing, as at glass).
    pub weight: Option<DVec3>,
    /// For a BRDF bounce: the BRDF value (the course roulette's factor) and the direction's
    /// density times the chance of the BRDF lobe (what multiple importance sampling weighs).
    /// `None` for a specular direction.
    pub brdf: Option<(DVec3, f64)>,
    /// For a refraction: the medium entered (`Some(absorption)`) or left (`None`).
    pub refracted: Option<Option<DVec3>>,
}

impl Scattered {
    /// Whether the direction is specular (mirror lobe, reflection or refraction at glass).
    pub fn specular(&self) -> bool {
        self.brdf.is_none()
    }

    /// Whether the path leaves a dielectric here.
    pub fn leaves(&self) -> bool {
        matches!(self.refracted, Some(None))
    }
}

/// Where a path arriving `at` a surface of material `mat` goes on, drawing from `rng`: a BRDF
/// bounce at diffuse and glossy materials (uniform or, with `importance`, cosine-distributed);
/// at mirrors and conductors the mirror lobe or the BRDF, chosen by [`mirror_choice`]; at
/// dielectrics reflection or refraction, chosen by the Fresnel reflectance, entering by the
/// `sides` rule. New rays start `eps` off the surface. `None` ends the path (nothing is
/// reflected that way). Its callers bounce diffuse and glossy vertices themselves (the
/// tracer's paths with [`brdf_bounce`], to the same bits: an out-of-line call returning this
/// record cost them 3-4 %; the path lanes side by side) and call it for the others.
pub(super) fn scatter(
    mat: &Material,
    at: &Arrival,
    sides: DielectricSides,
    importance: bool,
    eps: f64,
    rng: &mut Sampler,
) -> Option<Scattered> {
    let (x, n, d) = (at.x, at.n, at.d);
    match mat.kind {
        MaterialKind::Dielectric => {
            let eta = mat.refraction_index;
            let entering = match sides {
                DielectricSides::FaceSide => at.front,
                DielectricSides::Flag => !at.inside,
            };
            let (n1, n2) = if entering { (1.0, eta) } else { (eta, 1.0) };
            let reflected = glossy(reflect(d, n), mat.roughness, rng);
            let xi = rng.next_1d();
            Some(match refract(d, n, n1, n2) {
                Refraction::Split { fr, dir } if xi >= fr => Scattered {
                    origin: x - eps * n,
                    dir: glossy(dir, mat.roughness, rng),
                    weight: None,
                    brdf: None,
                    refracted: Some(entering.then_some(mat.absorption)),
                },
                _ => Scattered {
                    origin: x + eps * n,
                    dir: reflected,
                    weight: None,
                    brdf: None,
                    refracted: None,
                },
            })
        }
        MaterialKind::Mirror | MaterialKind::Conductor => {
            let (weight, p_spec) = mirror_choice(mat, d, n);
            let w_spec = weight.max_element();
            let xi = rng.next_1d();
            if xi < p_spec {
                if w_spec <= 0.0 {
                    return None;
                }
                Some(Scattered {
                    origin: x + eps * at.shading_normal,
                    dir: glossy(reflect(d, n), mat.roughness, rng),
                    weight: Some(weight / p_spec),
                    brdf: None,
                    refracted: None,
                })
            } else {
                brdf_scattered(mat, at, 1.0 - p_spec, importance, eps, rng)
            }
        }
        // (Dividing by a chance of 1 and multiplying by it are exact: the same bits as the
        // callers' own diffuse bounces.)
        MaterialKind::Plain => brdf_scattered(mat, at, 1.0, importance, eps, rng),
    }
}

/// A BRDF bounce from `at`, taken with probability `chance`: its throughput factor and density
/// carry the chance.
#[inline(always)]
fn brdf_scattered(
    mat: &Material,
    at: &Arrival,
    chance: f64,
    importance: bool,
    eps: f64,
    rng: &mut Sampler,
) -> Option<Scattered> {
    let (wi, f, brdf) = brdf_bounce(at.n, -at.d, mat, importance, rng)?;
    Some(Scattered {
        origin: at.x + eps * at.n,
        dir: wi,
        weight: Some(f / chance),
        brdf: Some((brdf, chance * density(importance, at.n, wi))),
        refracted: None,
    })
}

/// The chance that a path arriving along `d` at normal `n` (on its side) leaves by a BRDF
/// bounce: 1 at diffuse and glossy materials, 1 minus the mirror lobe's at mirrors and
/// conductors, none at dielectrics.
pub(super) fn brdf_chance(mat: &Material, d: DVec3, n: DVec3) -> f64 {
    match mat.kind {
        MaterialKind::Plain => 1.0,
        MaterialKind::Mirror | MaterialKind::Conductor => 1.0 - mirror_choice(mat, d, n).1,
        MaterialKind::Dielectric => 0.0,
    }
}

/// A mirror's or conductor's mirror-lobe weight for a ray of direction `d` arriving at normal
/// `n`, and the probability with which a path takes that lobe rather than the material's BRDF:
/// each by its largest channel (the chosen one's weight is then divided by its probability).
fn mirror_choice(mat: &Material, d: DVec3, n: DVec3) -> (DVec3, f64) {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// At a diffuse material `scatter` gives what the tracer's own diffuse bounce gives
    /// (`brdf_bounce` from the normal's side, the factor and density as they are), bit for bit.
    #[test]
    fn a_diffuse_scatter_is_the_plain_brdf_bounce() {
        let mat = Material {
            kind: MaterialKind::Plain,
            ambient: DVec3::ZERO,
            diffuse: DVec3::new(0.5, 0.3, 0.2),
            specular: DVec3::splat(0.2),
            mirror: DVec3::ZERO,
            phong_exponent: 12.0,
            phong_exponent_int: Some(12),
            refraction_index: 1.0,
            absorption_index: 0.0,
            absorption: DVec3::ZERO,
            roughness: 0.0,
            brdf: None,
        };
        let n = DVec3::new(0.2, -0.3, 0.9).normalize();
        let at = Arrival {
            x: DVec3::new(1.0, 2.0, 3.0),
            n,
            shading_normal: n,
            d: DVec3::new(0.1, 0.4, -1.0).normalize(),
            front: true,
            inside: false,
        };
        for (importance, sample) in [(false, 0), (true, 1), (true, 5)] {
            let rng = Sampler::new(11, 3, 4, sample);
            let (mut a, mut b) = (rng.clone(), rng);
            let got = scatter(&mat, &at, DielectricSides::Flag, importance, 1e-4, &mut a).unwrap();
            let (wi, f, brdf) = brdf_bounce(n, -at.d, &mat, importance, &mut b).unwrap();
            assert_eq!(got.dir, wi);
            assert_eq!(got.origin, at.x + 1e-4 * n);
            assert_eq!(
                got.weight.map(|w| w.to_array().map(f64::to_bits)),
                Some(f.to_array().map(f64::to_bits))
            );
            let (got_brdf, pdf) = got.brdf.unwrap();
            assert_eq!(got_brdf, brdf);
            assert_eq!(pdf.to_bits(), density(importance, n, wi).to_bits());
            assert!(!got.specular() && !got.leaves());
            assert_eq!(a.drawn(), b.drawn());
        }
    }
}
