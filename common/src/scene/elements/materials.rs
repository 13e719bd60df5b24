//! The rules of `<Materials>` and `<BRDFs>`, with the 2019 untyped mirrors and dielectrics.

use crate::scene::records::{BrdfKind, BrdfRec, MaterialKind, MaterialRec, Vec3};
use crate::scene::tree::{Node, Parser, Result, Schema};

const MATERIALS: Schema = Schema { many: &["Material"], ..Schema::EMPTY };
const MATERIAL: Schema = Schema {
    single: &[
        "AmbientReflectance",
        "DiffuseReflectance",
        "SpecularReflectance",
        "MirrorReflectance",
        "PhongExponent",
        "RefractionIndex",
        "AbsorptionIndex",
        "AbsorptionCoefficient",
        "Roughness",
        "Transparency",
    ],
    attrs: &["id", "type", "degamma", "BRDF"],
    ..Schema::EMPTY
};
const BRDFS: Schema = Schema {
    many: &["OriginalPhong", "ModifiedPhong", "OriginalBlinnPhong", "ModifiedBlinnPhong", "TorranceSparrow"],
    ..Schema::EMPTY
};
const BRDF_KINDS: &[(&str, BrdfKind)] = &[
    ("OriginalPhong", BrdfKind::OriginalPhong),
    ("ModifiedPhong", BrdfKind::ModifiedPhong),
    ("OriginalBlinnPhong", BrdfKind::OriginalBlinnPhong),
    ("ModifiedBlinnPhong", BrdfKind::ModifiedBlinnPhong),
    ("TorranceSparrow", BrdfKind::TorranceSparrow),
];
const BRDF_PLAIN: Schema = Schema { single: &["Exponent"], attrs: &["id"], ..Schema::EMPTY };
const BRDF_MODIFIED: Schema = Schema { single: &["Exponent"], attrs: &["id", "normalized"], ..Schema::EMPTY };
const BRDF_TORRANCE_SPARROW: Schema =
    Schema { single: &["Exponent", "RefractiveIndex"], attrs: &["id", "kdfresnel"], ..Schema::EMPTY };

impl Parser<'_> {
    pub(super) fn materials(&mut self, block: &Node) -> Result<()> {
        self.check(block, &MATERIALS);
        for material in block.children_named("Material") {
            let material = self.material(material)?;
            self.out.materials.push(material);
        }
        Ok(())
    }

    pub(super) fn brdfs(&mut self, block: &Node) -> Result<()> {
        self.check(block, &BRDFS);
        for b in &block.children {
            if let Some(b) = self.brdf(b)? {
                self.out.brdfs.push(b);
            }
        }
        Ok(())
    }

    /// One entry of `<BRDFs>` (§7); `None` for elements that are not BRDFs (already warned
    /// about by the caller's check).
    pub(super) fn brdf(&mut self, n: &Node) -> Result<Option<BrdfRec>> {
        let Some(&(_, kind)) = BRDF_KINDS.iter().find(|(name, _)| *name == n.name) else { return Ok(None) };
        let schema = match kind {
            BrdfKind::ModifiedPhong | BrdfKind::ModifiedBlinnPhong => &BRDF_MODIFIED,
            BrdfKind::TorranceSparrow => &BRDF_TORRANCE_SPARROW,
            BrdfKind::OriginalPhong | BrdfKind::OriginalBlinnPhong => &BRDF_PLAIN,
        };
        self.check(n, schema);
        let exponent: f64 = self.required_number(n, "Exponent")?;
        if !(0.0..=1e6).contains(&exponent) {
            let e = n.child("Exponent").unwrap_or(n);
            return Err(self.err(e, format!("Exponent must be between 0 and 1000000, found {exponent}")));
        }
        let refractive_index: Option<f64> = self.optional_number(n, "RefractiveIndex")?;
        if let Some(eta) = refractive_index
            && (eta.is_nan() || eta <= 0.0)
        {
            let e = n.child("RefractiveIndex").unwrap_or(n);
            return Err(self.err(e, format!("RefractiveIndex must be positive, found {eta}")));
        }
        Ok(Some(BrdfRec {
            id: self.id(n, true)?,
            loc: n.loc(),
            kind,
            exponent,
            normalized: self.bool_attr(n, "normalized")?.unwrap_or(false),
            kd_fresnel: self.bool_attr(n, "kdfresnel")?.unwrap_or(false),
            refractive_index,
        }))
    }

    pub(super) fn material(&mut self, n: &Node) -> Result<MaterialRec> {
        self.check(n, &MATERIAL);
        let mut m = MaterialRec::new(self.id(n, true)?, n.loc());
        m.kind = match n.attr("type").map(str::trim) {
            None => MaterialKind::Plain,
            Some("mirror") => MaterialKind::Mirror,
            Some("conductor") => MaterialKind::Conductor,
            Some("dielectric") => MaterialKind::Dielectric,
            Some(other) => {
                return Err(self.err(
                    n,
                    format!("unknown material type \"{other}\" (expected mirror, conductor or dielectric, or no type)"),
                ));
            }
        };
        m.degamma = self.bool_attr(n, "degamma")?.unwrap_or(false);
        m.brdf = match n.attr("BRDF").map(str::trim) {
            None => None,
            Some("") => return Err(self.err(n, "attribute BRDF is empty; give the id of a <BRDFs> entry")),
            Some(id) => Some(id.to_string()),
        };

        let colours: [(&str, &mut Vec3); 5] = [
            ("AmbientReflectance", &mut m.ambient),
            ("DiffuseReflectance", &mut m.diffuse),
            ("SpecularReflectance", &mut m.specular),
            ("MirrorReflectance", &mut m.mirror),
            ("AbsorptionCoefficient", &mut m.absorption_coefficient),
        ];
        for (name, field) in colours {
            if let Some(v) = self.optional_numbers(n, name)? {
                *field = v;
            }
        }
        let scalars: [(&str, &mut f64); 4] = [
            ("PhongExponent", &mut m.phong_exponent),
            ("RefractionIndex", &mut m.refraction_index),
            ("AbsorptionIndex", &mut m.absorption_index),
            ("Roughness", &mut m.roughness),
        ];
        for (name, field) in scalars {
            if let Some(v) = self.optional_number(n, name)? {
                *field = v;
            }
        }

        let transparency: Option<Vec3> = self.optional_numbers(n, "Transparency")?;
        let nonzero = |v: &Vec3| v.iter().any(|&x| x != 0.0);
        if self.legacy {
            // 2019: no `type` attribute exists; a non-zero Transparency makes a dielectric
            // (§6.9) and a non-zero MirrorReflectance a mirror (§6.1).
            if transparency.as_ref().is_some_and(nonzero) {
                m.kind = MaterialKind::Dielectric;
            } else if nonzero(&m.mirror) {
                m.kind = MaterialKind::Mirror;
            }
        } else if let Some(t) = n.child("Transparency") {
            self.warn(t, "<Transparency> only has a meaning in 2019 scene files (materials without type); it is ignored");
        }
        // In 2020+ files an untyped MirrorReflectance is deliberately ignored (§6.1): kind stays Plain.
        Ok(m)
    }
}
