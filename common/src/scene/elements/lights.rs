//! The rules of `<Lights>`: ambient, point, area, directional, spot and environment lights.

use crate::scene::records::{
    AreaLightRec, DirectionalLightRec, EnvLightRec, EnvMapping, EnvSampler, ImageRec, PointLightRec,
    SpotLightRec,
};
use crate::scene::tree::{Node, Parser, Result, Schema, excerpt, one_of};

const LIGHTS: Schema = Schema {
    single: &["AmbientLight"],
    many: &["PointLight", "AreaLight", "DirectionalLight", "SpotLight", "SphericalDirectionalLight"],
    ..Schema::EMPTY
};
// Cameras and lights take `Transformations` in 2025 scenes (§10.4).
const DIRECTIONAL_LIGHT: Schema =
    Schema { single: &["Direction", "Radiance", "Transformations"], attrs: &["id"], ..Schema::EMPTY };
const SPOT_LIGHT: Schema = Schema {
    single: &["Position", "Direction", "Intensity", "CoverageAngle", "FalloffAngle", "Transformations"],
    attrs: &["id"],
    ..Schema::EMPTY
};
/// `EnvMapName` is the 2019 form of `ImageId`; `Sampler` and `type` are 2025 additions (Tessera
/// also reads `Sampler importance`).
const ENV_LIGHT: Schema =
    Schema { single: &["ImageId", "EnvMapName", "Sampler"], attrs: &["id", "type"], ..Schema::EMPTY };
const ENV_MAPPINGS: &[(&str, EnvMapping)] = &[("latlong", EnvMapping::LatLong), ("probe", EnvMapping::Probe)];
const ENV_SAMPLERS: &[(&str, EnvSampler)] = &[
    ("uniform", EnvSampler::Uniform),
    ("cosine", EnvSampler::Cosine),
    ("importance", EnvSampler::Importance),
];
const POINT_LIGHT: Schema =
    Schema { single: &["Position", "Intensity", "Transformations"], attrs: &["id"], ..Schema::EMPTY };
const AREA_LIGHT: Schema = Schema {
    single: &["Position", "Normal", "Size", "Radiance", "Transformations"],
    attrs: &["id"],
    ..Schema::EMPTY
};
/// Prefix of the image ids made for 2019 `<EnvMapName>` paths (followed by the light's number).
const ENV_MAP_IMAGE_ID: &str = "2019:envmap";

impl Parser<'_> {
    pub(super) fn lights(&mut self, lights: &Node) -> Result<()> {
        self.check(lights, &LIGHTS);
        if let Some(ambient) = self.optional_numbers(lights, "AmbientLight")? {
            self.out.ambient_light = ambient;
        }
        for n in lights.children_named("PointLight") {
            self.check(n, &POINT_LIGHT);
            let light = PointLightRec {
                id: self.id(n, false)?,
                loc: n.loc(),
                position: self.required_numbers(n, "Position")?,
                intensity: self.required_numbers(n, "Intensity")?,
                transforms: self.transform_refs(n)?,
            };
            self.out.point_lights.push(light);
        }
        for n in lights.children_named("AreaLight") {
            self.check(n, &AREA_LIGHT);
            let light = AreaLightRec {
                id: self.id(n, false)?,
                loc: n.loc(),
                position: self.required_numbers(n, "Position")?,
                normal: self.required_numbers(n, "Normal")?,
                size: self.required_number(n, "Size")?,
                radiance: self.required_numbers(n, "Radiance")?,
                transforms: self.transform_refs(n)?,
            };
            if light.normal == [0.0; 3] {
                return Err(self.err(n, "<Normal> is the zero vector; give the direction the light faces"));
            }
            if light.size <= 0.0 {
                return Err(self.err(n, format!("<Size> must be positive, found {}", light.size)));
            }
            self.out.area_lights.push(light);
        }
        for n in lights.children_named("DirectionalLight") {
            self.check(n, &DIRECTIONAL_LIGHT);
            let light = DirectionalLightRec {
                id: self.id(n, false)?,
                loc: n.loc(),
                direction: self.required_numbers(n, "Direction")?,
                radiance: self.required_numbers(n, "Radiance")?,
                transforms: self.transform_refs(n)?,
            };
            if light.direction == [0.0; 3] {
                return Err(
                    self.err(n, "<Direction> is the zero vector; give the direction the light travels in")
                );
            }
            self.out.directional_lights.push(light);
        }
        for n in lights.children_named("SpotLight") {
            self.check(n, &SPOT_LIGHT);
            let light = SpotLightRec {
                id: self.id(n, false)?,
                loc: n.loc(),
                position: self.required_numbers(n, "Position")?,
                direction: self.required_numbers(n, "Direction")?,
                intensity: self.required_numbers(n, "Intensity")?,
                coverage_angle: self.required_number(n, "CoverageAngle")?,
                falloff_angle: self.required_number(n, "FalloffAngle")?,
                transforms: self.transform_refs(n)?,
            };
            if light.direction == [0.0; 3] {
                return Err(
                    self.err(n, "<Direction> is the zero vector; give the axis the spot light points along")
                );
            }
            let (c, f) = (light.coverage_angle, light.falloff_angle);
            if !(c > 0.0 && c < 360.0) {
                return Err(self.err(
                    n,
                    format!("<CoverageAngle> must be between 0 and 360 degrees (the full apex angle of the cone), found {c}"),
                ));
            }
            if !(0.0..=c).contains(&f) {
                return Err(self.err(
                    n,
                    format!("<FalloffAngle> must be between 0 and <CoverageAngle> ({c}) degrees, found {f}: the full-power cone lies inside the covered cone"),
                ));
            }
            self.out.spot_lights.push(light);
        }
        for n in lights.children_named("SphericalDirectionalLight") {
            self.check(n, &ENV_LIGHT);
            let id = self.id(n, false)?;
            let image = match (n.child("ImageId"), n.child("EnvMapName")) {
                (Some(i), _) => self.id_ref(i, "an image id")?,
                (None, Some(legacy)) => {
                    // 2019: the map's path inline; give it an image record of its own.
                    let path = self.text(legacy, "an image file path")?.to_string();
                    let image_id = format!("{ENV_MAP_IMAGE_ID}{}", self.out.env_lights.len() + 1);
                    self.out.images.push(ImageRec { id: image_id.clone(), loc: legacy.loc(), path });
                    image_id
                }
                (None, None) => {
                    return Err(
                        self.err(n, "missing <ImageId>: name the <Image> that holds the environment map")
                    );
                }
            };
            let mapping = match n.attr("type").map(str::trim) {
                None => EnvMapping::LatLong,
                Some(t) => match ENV_MAPPINGS.iter().find(|(name, _)| *name == t) {
                    Some(&(_, m)) => m,
                    None => {
                        return Err(self.err(
                            n,
                            format!(
                                "attribute type must be {}, found \"{}\"",
                                one_of(ENV_MAPPINGS),
                                excerpt(t)
                            ),
                        ));
                    }
                },
            };
            let sampler = self.optional_keyword(n, "Sampler", ENV_SAMPLERS)?;
            self.out.env_lights.push(EnvLightRec { id, loc: n.loc(), image, mapping, sampler });
        }
        Ok(())
    }
}
