//! Materials and the Fresnel terms of the course's shading model (scene-format.md §6).

use glam::DVec3;

pub use crate::scene::records::{BrdfKind, MaterialKind};

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
    /// The BRDF the material selects (§7); `None` is the classic shading of §6.2. With one,
    /// `phong_exponent` holds the BRDF's `Exponent`.
    pub brdf: Option<Brdf>,
}

/// A reflectance model of `<BRDFs>` (§7), as a material uses it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Brdf {
    pub kind: BrdfKind,
    /// `normalized="true"` (Modified variants): energy-normalised lobes and `k_d/π`.
    pub normalized: bool,
    /// `kdfresnel="true"` (TorranceSparrow): the diffuse term is scaled by `1 − F`.
    pub kd_fresnel: bool,
    /// The 2019 `<RefractiveIndex>` of a TorranceSparrow BRDF, for Schlick's Fresnel.
    pub refractive_index: Option<f64>,
}

impl Material {
    /// This material's [`Matte`] form: its reflectance when it has no specular lobe (`k_s = 0`)
    /// and no Torrance-Sparrow BRDF; `None` otherwise.
    pub fn matte(&self) -> Option<Matte> {
        use BrdfKind::*;
        use std::f64::consts::PI;
        if self.specular != DVec3::ZERO {
            return None;
        }
        let zero = self.specular * 0.0;
        let (c, form) = match self.brdf {
            None => (self.diffuse, MatteForm::Plain),
            Some(b) => match (b.kind, b.normalized) {
                (OriginalPhong | OriginalBlinnPhong, _) => (self.diffuse, MatteForm::CheckedPlusZero),
                (ModifiedPhong | ModifiedBlinnPhong, true) => (self.diffuse / PI + zero, MatteForm::Checked),
                (ModifiedPhong | ModifiedBlinnPhong, false) => (self.diffuse + zero, MatteForm::Checked),
                (TorranceSparrow, _) => return None,
            },
        };
        Some(Matte { c, zero, form })
    }

    /// `cos^p` of an angle's cosine with the material's exponent (`powi` for whole exponents:
    /// several times cheaper than `powf`).
    #[inline]
    fn lobe(&self, c: f64) -> f64 {
        match self.phong_exponent_int {
            Some(k) => c.powi(k),
            None => c.powf(self.phong_exponent),
        }
    }

    /// Light reflected towards `wo` per unit of irradiance arriving from `wi` at normal
    /// incidence: `f(wi, wo)·cos θ_i`, for unit `n`, `wi`, `wo` (`wo` points back along the
    /// incoming ray). Without a BRDF this is the bracket of §6.2, diffuse cosine plus the
    /// Blinn-Phong lobe, bit for bit as the classic tracer has always computed it; with one it
    /// is §7's table. Every BRDF is zero where `wi` is below the surface.
    #[inline]
    pub fn reflectance(&self, n: DVec3, wi: DVec3, wo: DVec3) -> DVec3 {
        let Some(brdf) = &self.brdf else {
            // Most classic materials are matte: no half vector (a square root and a division)
            // for a lobe that would be multiplied by zero. The sum is the same value.
            if self.specular == DVec3::ZERO {
                return self.diffuse * n.dot(wi);
            }
            let h = (wi + wo).normalize();
            return self.diffuse * n.dot(wi) + self.specular * self.lobe(n.dot(h).max(0.0));
        };
        let cos_i = n.dot(wi);
        if cos_i.is_nan() || cos_i <= 0.0 {
            return DVec3::ZERO;
        }
        use std::f64::consts::PI;
        let p = self.phong_exponent;
        // α_r: between wo and wi mirrored about n. α_h: between n and the half vector.
        let cos_r = || (2.0 * cos_i * n - wi).dot(wo).max(0.0);
        let cos_h = || n.dot((wi + wo).normalize()).max(0.0);
        // The specular lobe times k_s; for a material without one (k_s = 0, the course's matte
        // BRDF materials) the lobe's power is skipped: the lobe is finite and at least 0, so
        // k_s times it is k_s times 0, the same signed zeros.
        let ks = self.specular;
        let spec = |lobe: &dyn Fn() -> f64| if ks == DVec3::ZERO { ks * 0.0 } else { ks * lobe() };
        match (brdf.kind, brdf.normalized) {
            // k_d + k_s cos^p α_r / cos θ_i, times cos θ_i.
            (BrdfKind::OriginalPhong, _) => self.diffuse * cos_i + spec(&|| self.lobe(cos_r())),
            (BrdfKind::ModifiedPhong, false) => (self.diffuse + spec(&|| self.lobe(cos_r()))) * cos_i,
            (BrdfKind::ModifiedPhong, true) => {
                (self.diffuse / PI + spec(&|| (p + 2.0) / (2.0 * PI) * self.lobe(cos_r()))) * cos_i
            }
            (BrdfKind::OriginalBlinnPhong, _) => self.diffuse * cos_i + spec(&|| self.lobe(cos_h())),
            (BrdfKind::ModifiedBlinnPhong, false) => (self.diffuse + spec(&|| self.lobe(cos_h()))) * cos_i,
            (BrdfKind::ModifiedBlinnPhong, true) => {
                (self.diffuse / PI + spec(&|| (p + 8.0) / (8.0 * PI) * self.lobe(cos_h()))) * cos_i
            }
            (BrdfKind::TorranceSparrow, _) => {
                let cos_o = n.dot(wo);
                let h = (wi + wo).normalize();
                let cos_beta = wo.dot(h);
                let f = self.torrance_sparrow_fresnel(brdf, cos_beta);
                let diffuse =
                    if brdf.kd_fresnel { self.diffuse * ((1.0 - f) / PI) } else { self.diffuse / PI };
                if !(cos_o > 0.0 && cos_beta > 0.0) {
                    return diffuse * cos_i;
                }
                let ch = n.dot(h).max(0.0);
                let d = (p + 2.0) / (2.0 * PI) * self.lobe(ch);
                let g = (2.0 * ch * cos_o / cos_beta).min(2.0 * ch * cos_i / cos_beta).min(1.0);
                // f·cos θ_i: the 1/cos θ_i of the microfacet term cancels.
                diffuse * cos_i + self.specular * (d * f * g / (4.0 * cos_o))
            }
        }
    }

    /// [`Self::reflectance`] of `N` lanes at once (`n[k]`, `wi[k]`, `wo[k]`) for a classic
    /// material (no BRDF) with a whole Phong exponent, the same bits lane by lane; `None` for
    /// other materials. Computed for every lane side by side, one component at a time, so the
    /// compiler makes vector code of the half vectors' square roots and divisions and of the
    /// lobe's products ([`powi_lanes`]: `powi`'s multiplications in its order).
    #[inline(always)]
    pub fn classic_reflectance_lanes<const N: usize>(
        &self,
        n: &[DVec3; N],
        wi: &[DVec3; N],
        wo: &[DVec3; N],
    ) -> Option<[DVec3; N]> {
        let k = match (&self.brdf, self.phong_exponent_int) {
            (None, Some(k)) => k,
            _ => return None,
        };
        let (kd, ks) = (self.diffuse, self.specular);
        let mut out = [DVec3::ZERO; N];
        if ks == DVec3::ZERO {
            for i in 0..N {
                out[i] = kd * n[i].dot(wi[i]);
            }
            return Some(out);
        }
        let soa =
            |v: &[DVec3; N]| -> [[f64; N]; 3] { std::array::from_fn(|a| std::array::from_fn(|i| v[i][a])) };
        let (n, wi, wo) = (soa(n), soa(wi), soa(wo));
        let (mut cos_i, mut cos_h) = ([0.0; N], [0.0; N]);
        for i in 0..N {
            // glam's `(wi + wo).normalize()`: times the reciprocal of the length.
            let h = [wi[0][i] + wo[0][i], wi[1][i] + wo[1][i], wi[2][i] + wo[2][i]];
            let recip = 1.0 / (h[0] * h[0] + h[1] * h[1] + h[2] * h[2]).sqrt();
            let h = [h[0] * recip, h[1] * recip, h[2] * recip];
            cos_h[i] = (n[0][i] * h[0] + n[1][i] * h[1] + n[2][i] * h[2]).max(0.0);
            cos_i[i] = n[0][i] * wi[0][i] + n[1][i] * wi[1][i] + n[2][i] * wi[2][i];
        }
        let lobe = powi_lanes(cos_h, k);
        for i in 0..N {
            out[i] = kd * cos_i[i] + ks * lobe[i];
        }
        Some(out)
    }

    /// F(β) of the Torrance–Sparrow BRDF (§7, §15 #17): the conductor Fresnel of the material's
    /// RefractionIndex and AbsorptionIndex when it has an absorption index, else Schlick's
    /// approximation with the BRDF's (2019) or the material's refractive index.
    fn torrance_sparrow_fresnel(&self, brdf: &Brdf, cos_beta: f64) -> f64 {
        if self.absorption_index > 0.0 {
            return fresnel_conductor(cos_beta, self.refraction_index, self.absorption_index);
        }
        let eta = brdf.refractive_index.unwrap_or(self.refraction_index);
        let r0 = ((eta - 1.0) / (eta + 1.0)).powi(2);
        r0 + (1.0 - r0) * (1.0 - cos_beta.clamp(0.0, 1.0)).powi(5)
    }
}

/// `x[i].powi(k)` of every lane: the square-and-multiply of `powi` (compiler-builtins'
/// `__powidf2`: the result starts at one, takes the base at each set bit of `|k|` from the
/// lowest, the base squared between bits, and the reciprocal for negative `k`), each step for
/// all lanes at once.
#[inline(always)]
pub fn powi_lanes<const N: usize>(mut x: [f64; N], k: i32) -> [f64; N] {
    let mut bits = k.unsigned_abs();
    let mut r = [1.0; N];
    loop {
        if bits & 1 != 0 {
            for i in 0..N {
                r[i] *= x[i];
            }
        }
        bits >>= 1;
        if bits == 0 {
            break;
        }
        for v in &mut x {
            *v *= *v;
        }
    }
    if k < 0 {
        for v in &mut r {
            *v = 1.0 / *v;
        }
    }
    r
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

/// A material's [`Material::reflectance`] when it has no specular lobe (`k_s = 0`, the course's
/// matte materials): a coefficient times the cosine, computed with the same operations.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Matte {
    /// `c`: the diffuse term as `reflectance` forms it.
    pub c: DVec3,
    /// `k_s · 0` (a zero, of `k_s`'s signs), added after the product by the original models.
    pub zero: DVec3,
    /// How `c` meets the cosine.
    pub form: MatteForm,
}

/// A material's [`Matte`] form where every material needs one, as the path lanes read it by
/// material: the form, or zeros and `none` for a material without one. A lane copies it and
/// tests `none` without a branch, where an `Option<Matte>` is matched with one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MatteSlot {
    pub matte: Matte,
    pub none: bool,
}

impl MatteSlot {
    pub const NONE: MatteSlot =
        MatteSlot { matte: Matte { c: DVec3::ZERO, zero: DVec3::ZERO, form: MatteForm::Plain }, none: true };
}

impl From<Option<Matte>> for MatteSlot {
    fn from(m: Option<Matte>) -> Self {
        m.map_or(MatteSlot::NONE, |matte| MatteSlot { matte, none: false })
    }
}

/// How a [`Matte`] material's coefficient meets the cosine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MatteForm {
    /// `c · cos θ`, whatever the cosine (the classic shading).
    Plain,
    /// `c · cos θ`, zero below the surface (or for a NaN cosine).
    Checked,
    /// `c · cos θ + zero`, zero below the surface.
    CheckedPlusZero,
}

impl Matte {
    /// [`Material::reflectance`] for a light from a direction of cosine `cos` to the normal.
    #[inline(always)]
    pub fn at(&self, cos: f64) -> DVec3 {
        match self.form {
            MatteForm::Plain => self.c * cos,
            _ if cos.is_nan() || cos <= 0.0 => DVec3::ZERO,
            MatteForm::Checked => self.c * cos,
            MatteForm::CheckedPlusZero => self.c * cos + self.zero,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn powi_lanes_takes_the_bits_of_powi() {
        let xs =
            [0.0, -0.0, 1e-300, 0.3, 0.999_999_9, 1.0, -0.7, 1.000_001, 2.5, f64::NAN, f64::INFINITY, 1e10];
        for k in [0, 1, 2, 3, 7, 8, 13, 64, 100, 255, 1000, 4096, -1, -3, -100, i32::MAX, i32::MIN] {
            let got = powi_lanes(xs, k);
            for (x, g) in xs.iter().zip(got) {
                let want = x.powi(std::hint::black_box(k));
                assert!(
                    g.to_bits() == want.to_bits() || (g.is_nan() && want.is_nan()),
                    "{x}^{k}: {g} vs {want}"
                );
            }
        }
    }

    #[test]
    fn classic_reflectance_lanes_are_reflectance_lane_by_lane() {
        let mut mat = Material {
            kind: MaterialKind::Plain,
            ambient: DVec3::ZERO,
            diffuse: DVec3::new(0.8, 0.1, 0.3),
            specular: DVec3::new(1.0, 0.5, 0.25),
            mirror: DVec3::ZERO,
            phong_exponent: 100.0,
            phong_exponent_int: Some(100),
            refraction_index: 1.0,
            absorption_index: 0.0,
            absorption: DVec3::ZERO,
            roughness: 0.0,
            brdf: None,
        };
        let unit = |x: f64, y: f64, z: f64| DVec3::new(x, y, z).normalize();
        let n = [
            unit(0.0, 1.0, 0.0),
            unit(0.1, 1.0, -0.2),
            unit(1.0, 0.0, 0.0),
            unit(0.0, 0.0, 1.0),
            unit(0.3, 0.3, 0.9),
        ];
        let wi = [
            unit(0.2, 1.0, 0.1),
            unit(-0.5, 0.4, 0.3),
            unit(-1.0, 0.2, 0.0),
            unit(0.0, 1.0, 0.0),
            unit(0.3, 0.3, 0.9),
        ];
        let wo = [
            unit(-0.2, 1.0, 0.4),
            unit(0.5, 0.9, 0.0),
            unit(0.7, 0.7, 0.0),
            unit(0.0, -1.0, 0.0),
            unit(-0.3, -0.3, -0.9),
        ];
        for (spec, k) in
            [(DVec3::new(1.0, 0.5, 0.25), 100), (DVec3::ONE, 1), (DVec3::ONE, 0), (DVec3::ZERO, 7)]
        {
            mat.specular = spec;
            mat.phong_exponent = k as f64;
            mat.phong_exponent_int = Some(k);
            let lanes = mat.classic_reflectance_lanes(&n, &wi, &wo).expect("a classic material");
            for i in 0..n.len() {
                let one = mat.reflectance(n[i], wi[i], wo[i]);
                assert_eq!(
                    lanes[i].to_array().map(f64::to_bits),
                    one.to_array().map(f64::to_bits),
                    "lane {i}, k {k}"
                );
            }
        }
        mat.phong_exponent_int = None;
        assert!(mat.classic_reflectance_lanes(&n, &wi, &wo).is_none(), "powf exponents go lane by lane");
    }

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

    /// A material with kd 0.5, ks 0.25, exponent 10 and the given BRDF.
    fn with_brdf(kind: BrdfKind, normalized: bool) -> Material {
        Material {
            kind: MaterialKind::Plain,
            ambient: DVec3::ZERO,
            diffuse: DVec3::splat(0.5),
            specular: DVec3::splat(0.25),
            mirror: DVec3::ZERO,
            phong_exponent: 10.0,
            phong_exponent_int: Some(10),
            refraction_index: 1.5,
            absorption_index: 0.0,
            absorption: DVec3::ZERO,
            roughness: 0.0,
            brdf: Some(Brdf { kind, normalized, kd_fresnel: false, refractive_index: None }),
        }
    }

    /// A unit vector in the xz plane at `deg` degrees from +z towards +x.
    fn at(deg: f64) -> DVec3 {
        let r = deg.to_radians();
        DVec3::new(r.sin(), 0.0, r.cos())
    }

    /// Worked angles: n = +z, wi 60° on one side, wo 40° on the other. Then α_r (wo against wi
    /// mirrored, at −60°) is 20°, α_h (the half vector, at 10°) is 10°, β (wo against the half
    /// vector) is 50° and θ_o is 40°. Each expected value is §7's formula written out with
    /// those angles, times cos θ_i.
    #[test]
    fn every_brdf_has_its_value_at_worked_angles() {
        use std::f64::consts::PI;
        let (n, wi, wo) = (DVec3::Z, at(60.0), at(-40.0));
        let c = |deg: f64| deg.to_radians().cos();
        let (kd, ks, p) = (0.5, 0.25, 10.0);
        let cos_i = c(60.0);
        let lobe_r = c(20.0).powi(10);
        let lobe_h = c(10.0).powi(10);
        let cases = [
            (BrdfKind::OriginalPhong, false, kd * cos_i + ks * lobe_r),
            (BrdfKind::ModifiedPhong, false, (kd + ks * lobe_r) * cos_i),
            (BrdfKind::ModifiedPhong, true, (kd / PI + ks * (p + 2.0) / (2.0 * PI) * lobe_r) * cos_i),
            (BrdfKind::OriginalBlinnPhong, false, kd * cos_i + ks * lobe_h),
            (BrdfKind::ModifiedBlinnPhong, false, (kd + ks * lobe_h) * cos_i),
            (BrdfKind::ModifiedBlinnPhong, true, (kd / PI + ks * (p + 8.0) / (8.0 * PI) * lobe_h) * cos_i),
        ];
        for (kind, normalized, want) in cases {
            let got = with_brdf(kind, normalized).reflectance(n, wi, wo);
            assert!(
                (got - DVec3::splat(want)).abs().max_element() < 1e-12,
                "{kind:?} {normalized}: {got} vs {want}"
            );
        }
        // Torrance–Sparrow with Schlick's Fresnel (η 1.5: R0 0.04). G = min(1, 2·cos10·cos40/cos50,
        // 2·cos10·cos60/cos50) = 1 here.
        let f = 0.04 + 0.96 * (1.0 - c(50.0)).powi(5);
        let d = (p + 2.0) / (2.0 * PI) * lobe_h;
        let spec = ks * d * f / (4.0 * cos_i * c(40.0));
        let ts = with_brdf(BrdfKind::TorranceSparrow, false);
        let got = ts.reflectance(n, wi, wo);
        assert!((got.x - (kd / PI + spec) * cos_i).abs() < 1e-12, "{got}");
        // kdfresnel scales the diffuse term by 1 − F.
        let mut ts_kd = ts.clone();
        ts_kd.brdf.as_mut().unwrap().kd_fresnel = true;
        let got = ts_kd.reflectance(n, wi, wo);
        assert!((got.x - (kd * (1.0 - f) / PI + spec) * cos_i).abs() < 1e-12, "{got}");
        // A material with an absorption index takes the conductor's Fresnel at cos β instead.
        let mut gold = ts.clone();
        gold.refraction_index = 0.37;
        gold.absorption_index = 2.82;
        let fc = fresnel_conductor(c(50.0), 0.37, 2.82);
        let got = gold.reflectance(n, wi, wo);
        let want = (kd / PI + ks * d * fc / (4.0 * cos_i * c(40.0))) * cos_i;
        assert!((got.x - want).abs() < 1e-12, "{got} vs {want}");
        assert!(fc > 0.5 && f < 0.1, "gold reflects far more than glass at 50°");
    }

    #[test]
    fn brdfs_are_zero_for_light_from_below_and_classic_shading_is_unchanged() {
        let (n, wo) = (DVec3::Z, at(-40.0));
        let below = DVec3::new(0.3, 0.0, -0.9539392014169456);
        for kind in [
            BrdfKind::OriginalPhong,
            BrdfKind::ModifiedPhong,
            BrdfKind::OriginalBlinnPhong,
            BrdfKind::ModifiedBlinnPhong,
            BrdfKind::TorranceSparrow,
        ] {
            for normalized in [false, true] {
                assert_eq!(with_brdf(kind, normalized).reflectance(n, below, wo), DVec3::ZERO, "{kind:?}");
            }
        }
        // No BRDF: kd·cos θ_i + ks·cos^p α_h (§6.2), which OriginalBlinnPhong equals.
        let mut classic = with_brdf(BrdfKind::OriginalBlinnPhong, false);
        let blinn = classic.reflectance(n, at(60.0), wo);
        classic.brdf = None;
        let plain = classic.reflectance(n, at(60.0), wo);
        assert!((plain - blinn).abs().max_element() < 1e-15, "{plain} vs {blinn}");
    }
}
