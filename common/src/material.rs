//! Materials and the Fresnel terms of the course's shading model (scene-format.md §6).

use glam::DVec3;

pub use crate::scene::records::MaterialKind;

/// A material ready for shading; reflectances already linearised when `degamma` was set.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    pub kind: MaterialKind,
    pub ambient: DVec3,
    pub diffuse: DVec3,
    pub specular: DVec3,
    pub mirror: DVec3,
    pub phong_exponent: f64,
    /// `phong_exponent` when it is a whole number in [0, 4096] (evaluated with `powi`).
    pub phong_exponent_int: Option<i32>,
    pub refraction_index: f64,
    pub absorption_index: f64,
    pub absorption: DVec3,
    pub roughness: f64,
}

/// Unpolarised Fresnel reflectance of a conductor with complex index `eta + i·kappa`, for the
/// cosine `c` of the incidence angle (§6.4).
pub fn fresnel_conductor(c: f64, eta: f64, kappa: f64) -> f64 {
    let c = c.clamp(0.0, 1.0);
    let nk = eta * eta + kappa * kappa;
    let c2 = c * c;
    let rs = (nk - 2.0 * eta * c + c2) / (nk + 2.0 * eta * c + c2);
    let rp = (nk * c2 - 2.0 * eta * c + 1.0) / (nk * c2 + 2.0 * eta * c + 1.0);
    0.5 * (rs + rp)
}

/// Refraction through an interface from index `n1` into `n2`.
pub enum Refraction {
    /// Total internal reflection: everything is reflected.
    Total,
    /// Fresnel reflectance `fr` (transmittance is `1 - fr`) and the unit refracted direction.
    Split { fr: f64, dir: DVec3 },
}

/// Exact dielectric Fresnel and Snell's law. `d` is the unit incoming direction, `n` the unit
/// normal facing the incoming ray (`d·n < 0`).
pub fn refract(d: DVec3, n: DVec3, n1: f64, n2: f64) -> Refraction {
    let ci = (-d.dot(n)).clamp(0.0, 1.0);
    let ratio = n1 / n2;
    let ct2 = 1.0 - ratio * ratio * (1.0 - ci * ci);
    if ct2 < 0.0 {
        return Refraction::Total;
    }
    let ct = ct2.sqrt();
    let dir = (ratio * d + (ratio * ci - ct) * n).normalize();
    let r_par = (n2 * ci - n1 * ct) / (n2 * ci + n1 * ct);
    let r_perp = (n1 * ci - n2 * ct) / (n1 * ci + n2 * ct);
    Refraction::Split { fr: 0.5 * (r_par * r_par + r_perp * r_perp), dir }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dielectric_fresnel_at_normal_incidence_matches_closed_form() {
        // ((n1-n2)/(n1+n2))^2 = (0.5/2.5)^2 = 0.04 for glass 1.5.
        match refract(DVec3::NEG_Z, DVec3::Z, 1.0, 1.5) {
            Refraction::Split { fr, dir } => {
                assert!((fr - 0.04).abs() < 1e-12);
                assert!((dir - DVec3::NEG_Z).length() < 1e-12);
            }
            Refraction::Total => panic!("no TIR at normal incidence"),
        }
    }

    #[test]
    fn total_internal_reflection_beyond_critical_angle() {
        // Critical angle of 1.5 -> 1 is 41.8°; 60° from the normal must reflect totally.
        let d = DVec3::new(60f64.to_radians().sin(), 0.0, -60f64.to_radians().cos());
        assert!(matches!(refract(d, DVec3::Z, 1.5, 1.0), Refraction::Total));
        let d = DVec3::new(30f64.to_radians().sin(), 0.0, -30f64.to_radians().cos());
        assert!(matches!(refract(d, DVec3::Z, 1.5, 1.0), Refraction::Split { .. }));
    }

    #[test]
    fn snell_law_holds() {
        let th = 40f64.to_radians();
        let d = DVec3::new(th.sin(), 0.0, -th.cos());
        let Refraction::Split { dir, .. } = refract(d, DVec3::Z, 1.0, 1.33) else { panic!() };
        assert!((th.sin() - 1.33 * dir.x).abs() < 1e-12);
    }

    #[test]
    fn conductor_fresnel_limits() {
        // Normal incidence: ((n-1)^2 + k^2) / ((n+1)^2 + k^2).
        let (n, k) = (0.37, 2.82);
        let expect = ((n - 1.0f64).powi(2) + k * k) / ((n + 1.0f64).powi(2) + k * k);
        assert!((fresnel_conductor(1.0, n, k) - expect).abs() < 1e-12);
        // Grazing incidence reflects everything.
        assert!((fresnel_conductor(0.0, n, k) - 1.0).abs() < 1e-12);
    }
}
